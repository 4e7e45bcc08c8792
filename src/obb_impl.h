/* obb internals shared by the hierarchy (obb.c) and brute force (obb_brute.c): the one voxel-box
 * test both use, so that they agree bit for bit. Not a public interface. */
#ifndef FN_OBB_IMPL_H
#define FN_OBB_IMPL_H

#include "obb.h"

#include <math.h>

#define OBB__EPS 1e-9   /* Gottschalk's epsilon added to |R| against degenerate edge axes */
#define OBB__SLACK 1e-6 /* mm: inner boxes reject only beyond this, far above rounding error */

/* Relative placement of B's local mm frame in A's: x_A = R x_B + t. AR = |R| + eps for inner boxes,
 * AR0 = |R| for the exact voxel test (so faces that touch exactly do not overlap). */
typedef struct obb__rel {
    double R[3][3], AR[3][3], AR0[3][3], t[3];
    double inv_len[3][3]; /* 1 / |A_i x B_j|; 0 where degenerate (parallel edges: skipped) */
} obb__rel;

void obb__rel_make(obb__rel *rel, const pose *a_world, const pose *b_world);

/* Centre and half-extents (mm, shrunk by tol) of the voxel index box [lo, hi] with spacing s. */
static inline void obb__box(const uint16_t lo[3], const uint16_t hi[3], const double s[3],
                            double tol, double c[3], double h[3])
{
    for (int i = 0; i < 3; i++) {
        c[i] = (double)(lo[i] + hi[i]) * 0.5 * s[i];
        h[i] = ((double)(hi[i] - lo[i]) * 0.5 + 0.5) * s[i] - tol;
    }
}

/* The 15-axis separating-axis test. B's centre cb is in B's frame. exact: |R| and slack 0, returns 1
 * when the open boxes overlap; else |R| + eps and OBB__SLACK, returns 0 only when an axis separates
 * them by OBB__SLACK or more (never rejects what the exact test accepts). *gap (when non-NULL and full): the largest
 * per-axis gap / |axis|, a lower bound on the distance when apart, minus the smallest overlap depth
 * when overlapping; without full it stops at the first separating axis and gives that axis' gap. */
int obb__sat(const obb__rel *rel, int exact, const double ca[3], const double ha[3],
             const double cb[3], const double hb[3], int full, double *gap);

/* Smallest integer probability product (pa*pb, bytes) that reaches the threshold. */
static inline int obb__threshold(double threshold)
{
    return (int)ceil(threshold * 65025.0);
}

int obb__check_query(const obb_query *q, const double sa[3], const double sb[3]);

#endif
