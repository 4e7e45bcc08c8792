/* split: the automatic separation of a bone where it is truly broken.
 *
 * A real fracture leaves two fragments that, beside a thin contact, face each other across a
 * narrow gap (background in a CT that holds only the bone) or meet along a fracture line (a thin
 * band darker than the bone on both sides: sheet.h); an intact bone is continuous across any cut.
 * So:
 * 1. the bone is over-segmented into regions grown (grow) from seeds spread over its thick parts
 *    (farthest-point sampling of the voxels at least SPLIT_DEEP_MM deep), a step into a voxel
 *    costing 1 + sheetness / SPLIT_BARRIER_HU times more, so cuts run along fracture lines;
 * 2. for each pair of regions that touch: the surface voxels of one that see the other across the
 *    background within SPLIT_GAP_MM (rays along the 26 directions: facing), the faces where they
 *    touch (contact) and those of them on a fracture line (sheetness >= SPLIT_SHEET_HU: broken);
 * 3. the pairs with the most (facing + broken) for their contact (SPLIT_TRIES of them, at least
 *    SPLIT_FACING_MIN) are tried in turn: the bone is grown again from those two seeds alone, and
 *    the two halves are the fragments when the cut between them is broken (facing + broken >=
 *    SPLIT_BROKEN_MIN * contact) and narrow for the smaller half (contact <= SPLIT_NECK_MAX *
 *    its voxels^(2/3)), and the smaller holds SPLIT_MIN_ML and SPLIT_MIN_SHARE of the bone;
 * 4. the halves kept are grown again, each from its own deepest voxel (the seeds of step 1 lie
 *    anywhere in the thick of them; a seed deep in each fragment places the cut best).
 * Measured on real pelvic bones (docs/benchmarks.md), neither test alone keeps every intact bone
 * whole: a sacrum faces itself across its foramina, an ilium's wing is thin; together they do.
 * One split into two per call; a caller that splits the pieces again in turn ends with
 * split_rejoin, which joins two pieces whose cut alone is neither broken nor narrow (a cut kept
 * for the gap of a third piece beside it: the joint between a sacrum and its ilium).
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
#define SPLIT_SHEET_HU 30.0 /* a contact face with this sheetness (HU/mm^2) or more lies on a fracture line */
#define SPLIT_BARRIER_HU 30.0 /* a growth step into a voxel costs 1 + its sheetness / this times more */
#define SPLIT_FACING_MIN 0.25 /* pairs of regions broken less (for their contact) are not tried */
#define SPLIT_BROKEN_MIN 0.5 /* halves are fragments when facing + broken >= this * contact */
#define SPLIT_NECK_MAX 1.0  /* and their contact (voxel faces) <= this * (smaller half's voxels)^(2/3) */
#define SPLIT_TRIES 3       /* pairs tried as halves, best first */
#define SPLIT_MIN_ML 2.0    /* the smaller half holds at least this much bone, so the contact's
                             * crumbs never come off as fragments */
#define SPLIT_MIN_SHARE 0.03 /* and at least this share of the bone being split */

/* Splits the domain (non-zero voxels) of the box into fragments: lab gets 1..n per voxel of the
 * domain, 0 elsewhere. Returns n (1: whole), or FN_ENOMEM. */
int split_auto(const float *values, const uint8_t *domain, const int dim[3], const double sp[3], int32_t *lab);

/* The pieces 1..n of lab over the domain, made by splits in turn, joined again where the cut
 * between two of them alone is no break (the test of step 3): a cut kept for the gap a third piece
 * faced across (a joint beside it) is undone once that piece has come off. join[1..n] gets the
 * piece each joins (the lowest of its group; itself when none). 0, or FN_ENOMEM. */
int split_rejoin(const float *values, const uint8_t *domain, const int dim[3], const double sp[3],
                 const int32_t *lab, int n, int *join);

#endif
