/* split: the automatic separation of a bone where it is truly broken.
 *
 * A real fracture leaves two fragments that touch over a thin contact and, beside it, face each
 * other across a narrow gap (background in a CT that holds only the bone); an intact bone faces
 * itself across such a gap far less than it holds together. So:
 * 1. the bone is over-segmented into regions grown (grow) from seeds spread over its thick parts
 *    (farthest-point sampling of the voxels at least SPLIT_DEEP_MM deep);
 * 2. for each pair of regions that touch, the surface voxels of one that see the other across the
 *    background within SPLIT_GAP_MM (rays along the 26 directions) are counted, against the faces
 *    where they touch;
 * 3. the pairs that face most for their contact (SPLIT_TRIES of them, at least SPLIT_FACING_MIN)
 *    are tried in turn: the bone is grown again from those two seeds alone, and the two halves
 *    are the fragments when they face each other across the gap more than they touch, and the
 *    smaller holds SPLIT_MIN_ML of bone or more.
 * An intact bone's halves touch over their whole cross-section and face little: it stays whole.
 * One split into two per call.
 *
 * Boxes as grow.h. OS-free, no global state. */
#ifndef FN_SPLIT_H
#define FN_SPLIT_H

#include <stddef.h>
#include <stdint.h>

#define SPLIT_DEEP_MM 2.0   /* seeds lie at least this deep in the bone */
#define SPLIT_SPACING_MM 20.0 /* and at least this far apart */
#define SPLIT_SEEDS 16      /* at most this many */
#define SPLIT_GAP_MM 5.0    /* a gap between fragments is at most this wide */
#define SPLIT_FACING_MIN 0.25 /* pairs of regions facing less (for their contact) are not tried */
#define SPLIT_TRIES 3       /* pairs tried as halves, best first */
#define SPLIT_MIN_ML 2.0    /* the smaller half holds at least this much bone, so the contact's
                             * crumbs never come off as fragments */

/* Splits the domain (non-zero voxels) of the box into fragments: lab gets 1..n per voxel of the
 * domain, 0 elsewhere. Returns n (1: whole), or FN_ENOMEM. */
int split_auto(const float *values, const uint8_t *domain, const int dim[3], const double sp[3], int32_t *lab);

#endif
