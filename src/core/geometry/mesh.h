/* mesh: triangle surfaces of a scalar grid at an iso level (marching tetrahedra).
 *
 * mesh_extract makes an indexed, closed surface (for printing, export and the renderer's surface
 * mode): every cube of the grid is split into the six tetrahedra around its main diagonal; the
 * grid is padded by one voxel below the level on every side (level - max(1, |level|), so bone touching the crop's border
 * is closed), every vertex lies on one grid edge and is shared by the triangles that cut that edge,
 * and every triangle turns counter-clockwise seen from outside (decided from the tetrahedron's
 * corners, not the interpolated positions, so it holds where those coincide). Inside is
 * value >= level. The surface, as indices, is a closed 2-manifold: every edge has exactly two
 * triangles, one in each direction. Positions of distinct vertices coincide only where a grid
 * value equals the level (a 0/1 mask at 0.5 never does).
 * mesh_smooth (Taubin's lambda|mu) and mesh_decimate (edge collapses under the link condition)
 * keep that: the mesh stays closed and manifold.
 *
 * Pure computation: no I/O, no global state; safe from any thread on distinct meshes. */
#ifndef FN_MESH_H
#define FN_MESH_H

/* An indexed triangle mesh. */
typedef struct mesh {
    float *v;  /* nv * 3 positions, mm; owned */
    int *tri;  /* nt * 3 vertex indices, counter-clockwise seen from outside; owned */
    long nv, nt;
} mesh;

/* The closed surface of {vals >= level} (see above), positions in local mm (voxel (0,0,0) at
 * the origin).
 * 0 or FN_ENOMEM (m then holds nothing); an empty set gives an empty mesh. */
int mesh_extract(const float *vals, const int dim[3], const double spacing[3], float level, mesh *m);
/* Taubin smoothing: iterations of a uniform Laplacian step by lambda (0.5) then by mu (-0.53),
 * which smooths the voxel steps without shrinking the whole. 0 or FN_ENOMEM (m unchanged). */
int mesh_smooth(mesh *m, int iterations, double lambda, double mu);
/* Keeps the outer surface (the part of largest positive volume) and the walls of cavities inside
 * (parts of negative volume); other parts, islands (voxels that touch the rest only at an edge or
 * a corner, which the surface leaves floating), go. Returns how many went, or FN_ENOMEM. */
long mesh_drop_islands(mesh *m);
/* Collapses the shortest edges (to their midpoints) until at most target triangles remain or no
 * edge can go without breaking the manifold (link condition) or flipping a triangle; never below
 * 4 triangles. Returns the triangle count, or FN_ENOMEM (m unchanged). */
long mesh_decimate(mesh *m, long target);
/* Volume enclosed (mm^3, positive for outward winding) and area (mm^2). */
double mesh_volume(const mesh *m);
double mesh_area(const mesh *m);
void mesh_free(mesh *m);

#endif
