/* morph: binary-mask operations for fragments that touch or are hollow: filling the enclosed
 * interior, and separating a mask into pieces (marker-based watershed on the distance map).
 *
 * Masks are uint8 volumes (non-zero = inside) of dim[0] x dim[1] x dim[2] voxels, index
 * (k * dim[1] + j) * dim[0] + i, with voxel spacing sp (mm). OS-free, no global state: calls on
 * different masks may run on different threads at once. */
#ifndef FN_MORPH_H
#define FN_MORPH_H

#include <stddef.h>
#include <stdint.h>

typedef enum { MORPH_FILL_3D = 1, MORPH_FILL_SLICES = 2 } morph_fill_mode;

/* Sets the voxels outside the mask that the outside cannot reach: in 3D (6-connected from the
 * box's border) when mode has MORPH_FILL_3D, and in every slice along each of the three axes
 * (4-connected from the slice's border) when it has MORPH_FILL_SLICES (that also fills a canal
 * open at its ends, and a skull's cranial cavity: use it on long bones and pieces). Returns the
 * number of voxels filled, or FN_ENOMEM. */
long morph_fill(uint8_t *mask, const int dim[3], int mode);

/* The distance (mm) of each inside voxel to the nearest outside voxel (the box's border counts as
 * outside), by a two-pass chamfer over the 26-neighbourhood with the true step lengths; 0 outside.
 * dist has one float per voxel. */
void morph_distance(const uint8_t *mask, const int dim[3], const double sp[3], float *dist);

/* The exact Euclidean distance (mm) from each voxel's centre to the nearest inside voxel's
 * centre: 0 inside, INFINITY everywhere when the mask is empty (the lower envelope of parabolas of
 * Felzenszwalb and Huttenlocher, one axis after another). dist has one float per voxel. 0 or
 * FN_ENOMEM. */
int morph_distance_to(const uint8_t *mask, const int dim[3], const double sp[3], float *dist);

/* Separates the mask into pieces. Markers: one per seed (seeds: nseeds voxel indices (i, j, k),
 * each inside the mask) when nseeds > 0; else the 26-connected cores left by eroding to distance >
 * erode_mm (erode_mm > 0), or, with erode_mm <= 0, by the smallest erosion (in steps of min(sp) /
 * 2) that leaves two cores or more, each of at least min_voxels voxels and 5% of the largest core
 * (smaller cores are dropped: crumbs of thin parts). The markers then grow back over the mask, the
 * deepest voxels first (a priority flood on the distance map, 26-connected): a marker-based
 * watershed. lab: one int32 per voxel, 0 outside the mask, 1..n the piece; a part of the mask no
 * marker reaches (another component) gets a piece of its own. *erode_used: the erosion (mm) that
 * split it (0 with seeds). Returns the number of pieces n (1 when no erosion splits it), FN_EINVAL
 * (a seed outside the mask, naming it), or FN_ENOMEM. */
int morph_separate(const uint8_t *mask, const int dim[3], const double sp[3], double erode_mm,
                   const int (*seeds)[3], int nseeds, size_t min_voxels, int32_t *lab, double *erode_used);

#endif
