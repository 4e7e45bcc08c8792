/* obb internals shared by the collision query over the hierarchy (obb_query.c) and brute force
 * (obb_brute.c, which also defines obb__rel_make and obb__check_query): the one voxel-box test both
 * use, so that they agree bit for bit. The hierarchy's build (obb.c) needs none of it. Not a public
 * interface. */
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
    double Rs[3][3];       /* R scaled by B's half spacing: carries B's index sums into A's frame */
    double hsa[3], hsb[3]; /* half spacings, mm */
    double tol;            /* mm each box shrinks by */
    double inv_len[3][3]; /* 1 / |A_i x B_j|; 0 where degenerate (parallel edges: skipped) */
} obb__rel;

void obb__rel_make(obb__rel *rel, const pose *a_world, const double sa[3], const pose *b_world,
                   const double sb[3], double tol);

/* A's voxel index box [lo, hi]: centre and half-extents (mm, shrunk by tol) in A's frame. */
static inline void obb__box_a(const obb__rel *rel, const uint16_t lo[3], const uint16_t hi[3],
                              double ca[3], double ha[3])
{
    for (int i = 0; i < 3; i++) {
        ca[i] = (double)(lo[i] + hi[i]) * rel->hsa[i];
        ha[i] = (double)(hi[i] - lo[i]) * rel->hsa[i] + (rel->hsa[i] - rel->tol);
    }
}

/* B's voxel index box [lo, hi]: centre carried into A's frame (bt) and half-extents in B's frame.
 * Tree and brute force both place boxes through these two functions, so they agree bit for bit. */
static inline void obb__box_b(const obb__rel *rel, const uint16_t lo[3], const uint16_t hi[3],
                              double bt[3], double hb[3])
{
    double sum[3];
    for (int i = 0; i < 3; i++) {
        sum[i] = (double)(lo[i] + hi[i]);
        hb[i] = (double)(hi[i] - lo[i]) * rel->hsb[i] + (rel->hsb[i] - rel->tol);
    }
    for (int i = 0; i < 3; i++)
        bt[i] = rel->Rs[i][0] * sum[0] + rel->Rs[i][1] * sum[1] + rel->Rs[i][2] * sum[2] + rel->t[i];
}

/* A point cb of B's frame carried into A's frame: bt = R cb + t. */
static inline void obb__carry(const obb__rel *rel, const double cb[3], double bt[3])
{
    for (int i = 0; i < 3; i++)
        bt[i] = rel->R[i][0] * cb[0] + rel->R[i][1] * cb[1] + rel->R[i][2] * cb[2] + rel->t[i];
}

/* The 15-axis separating-axis test on the centre offset T = bt - ca (A's frame) and the
 * half-extents. exact: all 15 axes, |R| and slack 0, returns 1 when the open boxes overlap; else
 * |R| + eps and OBB__SLACK, the 9 edge axes only with edges, and returns 0 only when an axis
 * separates them by OBB__SLACK or more (so it never rejects what the exact test accepts). *gap (when non-NULL and full): the largest per-axis gap / |axis|,
 * a lower bound on the distance when apart, minus the smallest overlap depth when overlapping;
 * without full it stops at the first separating axis and gives that axis' gap. */
#if defined(__GNUC__)
#define OBB__INLINE static inline __attribute__((always_inline))
#else
#define OBB__INLINE static inline
#endif

OBB__INLINE int obb__sat(const obb__rel *rel, int exact, int edges, const double T[3],
                           const double ha[3], const double hb[3], int full, double *gap)
{
    const double(*R)[3] = rel->R, (*AR)[3] = exact ? rel->AR0 : rel->AR;
    double slack = exact ? 0 : OBB__SLACK;
    double best = -INFINITY, s;
#define AXIS(expr)                                                                                 \
    do {                                                                                           \
        s = (expr);                                                                                \
        if (s >= slack && !full) {                                                                 \
            if (gap)                                                                               \
                *gap = s;                                                                          \
            return 0;                                                                              \
        }                                                                                          \
        best = s > best ? s : best;                                                                \
    } while (0)
    for (int i = 0; i < 3; i++)
        AXIS(fabs(T[i]) - (ha[i] + hb[0] * AR[i][0] + hb[1] * AR[i][1] + hb[2] * AR[i][2]));
    for (int j = 0; j < 3; j++)
        AXIS(fabs(T[0] * R[0][j] + T[1] * R[1][j] + T[2] * R[2][j]) -
             (ha[0] * AR[0][j] + ha[1] * AR[1][j] + ha[2] * AR[2][j] + hb[j]));
    for (int i = 0; i < 3 && (edges || exact); i++) {
        int i1 = (i + 1) % 3, i2 = (i + 2) % 3;
        for (int j = 0; j < 3; j++) {
            double inv = rel->inv_len[i][j];
            if (inv == 0)
                continue;
            int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
            AXIS((fabs(T[i2] * R[i1][j] - T[i1] * R[i2][j]) -
                  (ha[i1] * AR[i2][j] + ha[i2] * AR[i1][j] + hb[j1] * AR[i][j2] +
                   hb[j2] * AR[i][j1])) * inv);
        }
    }
#undef AXIS
    if (gap)
        *gap = best;
    return best < slack;
}

/* Smallest integer probability product (pa*pb, bytes) that reaches the threshold. */
static inline int obb__threshold(double threshold)
{
    return (int)ceil(threshold * 65025.0);
}

int obb__check_query(const obb_query *q, const double sa[3], const double sb[3]);

#endif
