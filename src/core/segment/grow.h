/* grow: competitive growth of labelled seeds over a bone mask, following its shape and intensities.
 *
 * An image-foresting transform (Falcao et al.) with an additive path cost, the method behind 3D
 * Slicer's "Grow from seeds" (FastGrowCut): every voxel of the domain takes the label of the seed
 * it reaches most cheaply along 6-connected paths inside the domain. A step into voxel q costs its
 * length (mm) / (depth(q) + GROW_DEPTH_MM) * (1 + |difference of the two values| /
 * GROW_CONTRAST_HU), depth being the distance to the domain's surface: paths run cheaply through
 * the thick of a fragment and dearly through the thin contact where two real fragments touch, and
 * pay for crossing a cortical edge. The depth term is what separates real pelvic fragments (an
 * intensity term alone, or a watershed on the depth, does worse: docs/benchmarks.md). Adding a seed later
 * (grow_add_seed then grow_run) only revisits the voxels the new seed wins: costs only fall, so a
 * Dijkstra from the new seed bounded by the costs already known gives the same forest as growing
 * all seeds anew.
 *
 * Volumes are boxes of dim[0] x dim[1] x dim[2] voxels, index (k * dim[1] + j) * dim[0] + i. The
 * handle keeps pointers to values and domain: they must outlive it, unchanged. OS-free; a handle
 * is used by one thread at a time. */
#ifndef FN_GROW_H
#define FN_GROW_H

#include <stddef.h>
#include <stdint.h>

#define GROW_CONTRAST_HU 300.0 /* a 300 HU step doubles a step's cost */
#define GROW_DEPTH_MM 0.5      /* keeps the surface's voxels (depth ~0) finite in cost */
#define GROW_MAX_LABEL 255    /* labels are 1..255 */

typedef struct grow grow;

/* A growth over the voxels where domain != 0, with values (HU) and voxel spacing sp (mm). NULL
 * with fn_err (FN_ENOMEM, or FN_EINVAL for a box of more than UINT32_MAX - 1 voxels). */
grow *grow_new(const float *values, const uint8_t *domain, const int dim[3], const double sp[3]);
void grow_free(grow *g);

/* Multiplies the cost of every step into voxel q by w[q] (>= 1; one float per voxel of the box),
 * before the first grow_run: a barrier where w is high. */
void grow_weigh(grow *g, const float *w);

/* Seeds voxel v (an index into the box, inside the domain) with label 1..GROW_MAX_LABEL; grows at
 * the next grow_run. 0, or FN_EINVAL: outside the box or the domain, a bad label, or a voxel
 * seeded already with another label. */
int grow_add_seed(grow *g, size_t v, int label);

/* Takes every seed back (a growth with none, its depths kept): cheaper than a new handle. */
void grow_clear(grow *g);

/* Grows the seeds added since the last run (all of them at the first). 0 or FN_ENOMEM. */
int grow_run(grow *g);

/* Per voxel of the box: the label that won it, 0 outside the domain or where no seed reaches. */
const uint8_t *grow_labels(const grow *g);

#endif
