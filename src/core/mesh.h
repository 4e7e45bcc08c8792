/* mesh: triangle surfaces of a scalar grid at an iso level (marching tetrahedra).
 *
 * mesh_build is the renderer's triangle soup: every cube of the (strided) grid split into the six
 * tetrahedra around its main diagonal; vertices are not shared and the grid's border is not closed.
 * Pure computation: no I/O, no global state; safe from any thread. */
#ifndef FN_MESH_H
#define FN_MESH_H

/* Marching tetrahedra over a masked scalar grid: vals is dim[0]*dim[1]*dim[2] (i fastest),
 * spacing in mm; every stride[a] voxels along axis a. Triangles as 6 floats per vertex (position
 * in local mm, voxel (0,0,0) at the origin; outward normal), malloc'd into *out (the caller
 * frees it); returns the triangle count or FN_ENOMEM. */
long mesh_build(const float *vals, const int dim[3], const double spacing[3], float level,
                const int stride[3], float **out);

#endif
