/* reduce_metric: the VOI metric (see reduce.h), fast and by brute force, and the coarse copies of
 * fragments it can be made over. */
#include "reduce.h"
#include "reduce_impl.h"

#include "err.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define BRICK 8

reduce_count reduce__metric_count(reduce_metric *m, reduce_count mode)
{
    reduce_count was = m->mode;
    m->mode = mode;
    return was;
}

int reduce_voi_cells(const frag *grid, const reduce_voi *voi, int c0[3], int c1[3])
{
    pose inv = pose_inverse(pose_compose(grid->pose, grid->home));
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int corner = 0; corner < 8; corner++) {
        double w[3], l[3];
        for (int a = 0; a < 3; a++)
            w[a] = corner >> a & 1 ? voi->hi[a] : voi->lo[a];
        pose_apply(&inv, w, l);
        for (int a = 0; a < 3; a++) {
            lo[a] = fmin(lo[a], l[a] / grid->spacing[a]);
            hi[a] = fmax(hi[a], l[a] / grid->spacing[a]);
        }
    }
    for (int a = 0; a < 3; a++) {
        if (!(voi->lo[a] < voi->hi[a]) || !isfinite(lo[a]) || !isfinite(hi[a]) || hi[a] - lo[a] > 4096)
            return fn_err_set(FN_EINVAL, "VOI: bad box on axis %d (%g .. %g mm)", a, voi->lo[a], voi->hi[a]);
        c0[a] = (int)ceil(lo[a] - 1e-9);
        c1[a] = (int)floor(hi[a] + 1e-9);
        if (c1[a] < c0[a])
            return fn_err_set(FN_EINVAL, "VOI: the box holds no voxel centre on axis %d", a);
    }
    return 0;
}

/* Each assembly fragment's world -> crop mm pose, for bone_at: malloc'd, NULL with fn_err. */
static pose *crop_poses(const frag *const *asm_, int nasm)
{
    pose *inv = malloc((size_t)nasm * sizeof *inv);
    if (!inv)
        fn_err_set(FN_ENOMEM, "reduce metric: out of memory");
    for (int f = 0; inv && f < nasm; f++)
        inv[f] = pose_inverse(pose_compose(asm_[f]->pose, asm_[f]->home));
    return inv;
}

/* The assembly's bone at world point w: 1 when some fragment has a bone voxel nearest to it (inv:
 * their crop_poses). */
static int bone_at(const frag *const *asm_, int nasm, const pose *inv, const double w[3])
{
    for (int f = 0; f < nasm; f++) {
        const frag *g = asm_[f];
        double l[3];
        pose_apply(&inv[f], w, l);
        int idx[3], in = 1;
        for (int a = 0; a < 3 && in; a++) {
            idx[a] = (int)floor(l[a] / g->spacing[a] + 0.5);
            in = idx[a] >= 0 && idx[a] < g->dim[a];
        }
        if (in && g->prob[((size_t)idx[2] * g->dim[1] + idx[1]) * g->dim[0] + idx[0]])
            return 1;
    }
    return 0;
}

/* Bone of the VOI cell (i, j, k) (0-based in the VOI): the grid fragment's own voxel when it has
 * one there, else the others sampled. */
static int cell_bone(const frag *const *asm_, int nasm, const pose *inv, const int c0[3], int i, int j, int k)
{
    const frag *g = asm_[0];
    int l[3] = {c0[0] + i, c0[1] + j, c0[2] + k};
    if (l[0] >= 0 && l[1] >= 0 && l[2] >= 0 && l[0] < g->dim[0] && l[1] < g->dim[1] && l[2] < g->dim[2] &&
        g->prob[((size_t)l[2] * g->dim[1] + l[1]) * g->dim[0] + l[0]])
        return 1;
    if (nasm < 2)
        return 0;
    double h[3], w[3], x[3] = {l[0] * g->spacing[0], l[1] * g->spacing[1], l[2] * g->spacing[2]};
    pose_apply(&g->home, x, h);
    pose_apply(&g->pose, h, w);
    return bone_at(asm_ + 1, nasm - 1, inv + 1, w);
}

void reduce__bricks_free(reduce_bricks *b)
{
    if (b) {
        free(b->brick);
        free(b->run);
        free(b);
    }
}

static int push_run(reduce_bricks *b, size_t *cap, int i0, int len, int j, int k)
{
    if (b->nrun == *cap) {
        size_t nc = *cap ? 2 * *cap : 1024;
        reduce_run *r = realloc(b->run, nc * sizeof *r);
        if (!r)
            return FN_ENOMEM;
        b->run = r;
        *cap = nc;
    }
    b->run[b->nrun++] = (reduce_run){(uint16_t)i0, (uint16_t)len, (uint16_t)j, (uint16_t)k};
    return 0;
}

reduce_bricks *reduce__bricks_new(const frag *m)
{
    reduce_bricks *b = calloc(1, sizeof *b);
    int nb[3];
    for (int a = 0; a < 3; a++)
        nb[a] = (m->dim[a] + BRICK - 1) / BRICK;
    size_t total = (size_t)nb[0] * nb[1] * nb[2], cap = 0;
    if (!b || m->dim[0] > 65535 || m->dim[1] > 65535 || m->dim[2] > 65535 ||
        !(b->brick = calloc(total ? total : 1, sizeof *b->brick))) {
        reduce__bricks_free(b);
        fn_err_set(FN_ENOMEM, "reduce: out of memory for the bricks of fragment %d", m->id);
        return NULL;
    }
    for (int a = 0; a < 3; a++)
        b->spacing[a] = m->spacing[a];
    b->home = m->home;
    double half = 0.5 * BRICK * sqrt(m->spacing[0] * m->spacing[0] + m->spacing[1] * m->spacing[1] +
                                     m->spacing[2] * m->spacing[2]);
    for (int bk = 0; bk < nb[2]; bk++)
        for (int bj = 0; bj < nb[1]; bj++)
            for (int bi = 0; bi < nb[0]; bi++) {
                reduce_brick *br = &b->brick[b->nbrick];
                br->first = b->nrun;
                int i1 = bi * BRICK + BRICK < m->dim[0] ? bi * BRICK + BRICK : m->dim[0];
                for (int k = bk * BRICK; k < bk * BRICK + BRICK && k < m->dim[2]; k++)
                    for (int j = bj * BRICK; j < bj * BRICK + BRICK && j < m->dim[1]; j++) {
                        const uint8_t *row = m->prob + ((size_t)k * m->dim[1] + j) * m->dim[0];
                        for (int i = bi * BRICK; i < i1;) {
                            if (!row[i]) {
                                i++;
                                continue;
                            }
                            int s = i;
                            while (i < i1 && row[i])
                                i++;
                            if (push_run(b, &cap, s, i - s, j, k) < 0) {
                                reduce__bricks_free(b);
                                fn_err_set(FN_ENOMEM, "reduce: out of memory for the runs of fragment %d", m->id);
                                return NULL;
                            }
                            b->voxels += (size_t)(i - s);
                        }
                    }
                br->n = (int)(b->nrun - br->first);
                if (br->n == 0)
                    continue;
                br->c[0] = (float)(bi * BRICK + 0.5 * (BRICK - 1));
                br->c[1] = (float)(bj * BRICK + 0.5 * (BRICK - 1));
                br->c[2] = (float)(bk * BRICK + 0.5 * (BRICK - 1));
                br->r_mm = (float)half;
                b->nbrick++;
            }
    return b;
}

/* The band's per-brick arrays (reduce__metric_rebase fills them). 0 or FN_ENOMEM. */
static int band_arrays(reduce_metric *m, const reduce_bricks *b)
{
    m->band_x = malloc((size_t)b->nbrick * sizeof *m->band_x + 1);
    m->band_first = malloc(((size_t)b->nbrick + 1) * sizeof *m->band_first);
    return m->band_x && m->band_first ? 0 : FN_ENOMEM;
}

reduce_metric *reduce__metric_share(const reduce_metric *m)
{
    reduce_metric *c = malloc(sizeof *c);
    if (c) {
        *c = *m;
        c->shared = 1;
        c->own_bricks = 0;
        c->band_ref = 0;
        c->band = NULL;
        c->nband = c->capband = 0;
    }
    if (!c || band_arrays(c, m->b) < 0) {
        reduce_metric_free(c);
        fn_err_set(FN_ENOMEM, "reduce metric: out of memory for a copy of the band");
        return NULL;
    }
    return c;
}

void reduce_metric_free(reduce_metric *m)
{
    if (m) {
        if (!m->shared) {
            free(m->cell);
            free(m->score);
            free(m->near);
            free(m->bsum);
            free(m->reach);
        }
        free(m->band_x);
        free(m->band_first);
        free(m->band);
        if (m->own_bricks)
            reduce__bricks_free(m->b);
        free(m);
    }
}

/* The band: per axis, the number of cells within band_mm (0: the whole box counts). */
static void band_cells(const double sg[3], double band_mm, int k[3])
{
    for (int a = 0; a < 3; a++)
        k[a] = band_mm > 0 ? (int)floor(band_mm / sg[a] + 1e-9) : -1;
}

double reduce__band_cut(double band_mm)
{
    return reduce__tune.band_corner * band_mm;
}

/* The largest whole number of cells a, spacing s, with (a s)^2 <= q (q >= 0; 1e-9 of slack, so a
 * ball's surface cells count as the brute force's test does). */
static int ball_reach(double q, double s)
{
    if (q < 0)
        return -1;
    int a = (int)floor(sqrt(q) / s);
    while ((a + 1) * s * (a + 1) * s <= q + 1e-9)
        a++;
    while (a > 0 && a * s * a * s > q + 1e-9)
        a--;
    return a;
}

static void or_bytes(uint8_t *dst, const uint8_t *src, size_t n);

static int imin(int a, int b)
{
    return a < b ? a : b;
}

/* v[cell] = 1 where some bone cell of bone[] lies within r mm (Euclidean, on the grid's spacing
 * sg: |(a sg0, b sg1, c sg2)| <= r for the offset a, b, c in cells) and, with cap, within cap[]
 * cells on each axis; v and bone span d[0]*d[1]*d[2] cells. Separable: each row dilated along i
 * by every reach that occurs (x[a], radius a), then for each offset (b, c) of the ball's disc in j
 * and k the row of reach a(b, c) ORed in, shifted, whole rows at a time. FN_ENOMEM or 0. */
static int dilate_ball(const uint8_t *bone, uint8_t *v, const int d[3], const double sg[3], double r, const int *cap)
{
    const size_t n = (size_t)d[0] * d[1] * d[2], row = (size_t)d[0];
    const double r2 = r * r;
    const int big = 1 << 20, c0 = cap ? cap[0] : big, c1 = cap ? cap[1] : big, c2 = cap ? cap[2] : big;
    const int kx = imin(ball_reach(r2, sg[0]), c0), kz = imin(ball_reach(r2, sg[2]), c2);
    uint8_t *x = malloc(n * (size_t)(kx + 1));
    if (!x)
        return FN_ENOMEM;
    for (size_t q = 0; q < n; q++)
        x[q] = bone[q] != 0;
    for (int a = 1; a <= kx; a++) { /* x[a]: x[a - 1] grown by one cell either way along i */
        const uint8_t *p = x + (size_t)(a - 1) * n;
        uint8_t *o = x + (size_t)a * n;
        memcpy(o, p, n);
        for (size_t q = 0; q < n; q += row) {
            or_bytes(o + q + 1, p + q, row - 1);
            or_bytes(o + q, p + q + 1, row - 1);
        }
    }
    memset(v, 0, n);
    for (int c = -kz; c <= kz; c++) {
        double qz = r2 - (c * sg[2]) * (c * sg[2]);
        int ky = imin(ball_reach(qz, sg[1]), c1);
        for (int b = -ky; b <= ky; b++) {
            int a = imin(ball_reach(qz - (b * sg[1]) * (b * sg[1]), sg[0]), c0);
            if (a < 0)
                continue;
            const uint8_t *src = x + (size_t)a * n;
            for (int z = c < 0 ? -c : 0; z < d[2] && z + c < d[2]; z++)
                for (int y = b < 0 ? -b : 0; y < d[1] && y + b < d[1]; y++)
                    or_bytes(v + ((size_t)z * d[1] + y) * row, src + ((size_t)(z + c) * d[1] + y + b) * row, row);
        }
    }
    free(x);
    return 0;
}

/* dst |= src over n bytes, eight at a time. */
static void or_bytes(uint8_t *dst, const uint8_t *src, size_t n)
{
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        uint64_t a, b;
        memcpy(&a, dst + i, 8);
        memcpy(&b, src + i, 8);
        a |= b;
        memcpy(dst + i, &a, 8);
    }
    for (; i < n; i++)
        dst[i] |= src[i];
}

/* out |= t shifted by r lines either way, in blocks of len lines of inner elements each (an axis
 * with the axes below it: the lines of a block are contiguous, whichever the axis). */
static void or_shifted(uint8_t *out, const uint8_t *t, size_t outer, int len, size_t inner, int r)
{
    if (r >= len)
        return;
    size_t n = (size_t)(len - r) * inner, sh = (size_t)r * inner, block = (size_t)len * inner;
    for (size_t o = 0; o < outer; o++) {
        or_bytes(out + o * block, t + o * block + sh, n);
        or_bytes(out + o * block + sh, t + o * block, n);
    }
}

void reduce__dilate_box(const uint8_t *in, uint8_t *out, uint8_t *tmp, const int d[3], const int k[3])
{
    size_t n = (size_t)d[0] * d[1] * d[2], inner = 1;
    for (size_t i = 0; i < n; i++)
        out[i] = in[i] != 0;
    for (int a = 0; a < 3; a++) {
        size_t outer = n / inner / (size_t)d[a];
        /* a box of radius c grown by a step s <= c + 1 either way is a box of radius c + s: radii
         * 1, 3, 7, ... up to k in about log2(k) whole-line passes */
        for (int c = 0, s; c < k[a]; c += s) {
            s = c + 1 < k[a] - c ? c + 1 : k[a] - c;
            memcpy(tmp, out, n);
            or_shifted(out, tmp, outer, d[a], inner, s);
        }
        inner *= (size_t)d[a];
    }
}

/* v[cell] = 1 where some bone cell of bone[] lies within k cells on every axis (a box); v and bone
 * span d[0]*d[1]*d[2] cells. */
static int dilate_box(const uint8_t *bone, uint8_t *v, const int d[3], const int k[3])
{
    uint8_t *tmp = malloc((size_t)d[0] * d[1] * d[2]);
    if (!tmp)
        return FN_ENOMEM;
    reduce__dilate_box(bone, v, tmp, d, k);
    free(tmp);
    return 0;
}

/* Which blocks of the padded raster hold a counted cell, as a summed-volume table, so that a
 * brick whose reach holds none (the moving bone far from the fixed bone) is skipped in O(1). */
static int block_table(reduce_metric *m)
{
    const int B = REDUCE_BLOCK;
    for (int a = 0; a < 3; a++)
        m->nb[a] = (m->D[a] + B - 1) / B;
    size_t s0 = (size_t)m->nb[0] + 1, s1 = (size_t)m->nb[1] + 1;
    m->bsum = calloc(s0 * s1 * ((size_t)m->nb[2] + 1), sizeof *m->bsum);
    if (!m->bsum)
        return FN_ENOMEM;
    for (int k = 0; k < m->D[2]; k++)
        for (int j = 0; j < m->D[1]; j++)
            for (int i = 0; i < m->D[0]; i++)
                if (m->cell[((size_t)k * m->D[1] + j) * m->D[0] + i] & REDUCE_CELL_V)
                    m->bsum[((size_t)(k / B + 1) * s1 + (size_t)(j / B + 1)) * s0 + (size_t)(i / B + 1)] = 1;
    reduce__sat_sum(m->bsum, m->nb);
    return 0;
}

void reduce__sat_sum(uint32_t *t, const int nb[3])
{
    size_t s0 = (size_t)nb[0] + 1, s1 = (size_t)nb[1] + 1;
    for (int k = 1; k <= nb[2]; k++) /* prefix sums along each axis in turn */
        for (int j = 1; j <= nb[1]; j++)
            for (int i = 1; i <= nb[0]; i++) {
                uint32_t *c = &t[((size_t)k * s1 + (size_t)j) * s0 + (size_t)i];
                *c += c[-1];
            }
    for (int k = 1; k <= nb[2]; k++)
        for (int j = 1; j <= nb[1]; j++)
            for (int i = 1; i <= nb[0]; i++)
                t[((size_t)k * s1 + (size_t)j) * s0 + (size_t)i] += t[((size_t)k * s1 + (size_t)(j - 1)) * s0 + (size_t)i];
    for (int k = 1; k <= nb[2]; k++)
        for (int j = 1; j <= nb[1]; j++)
            for (int i = 1; i <= nb[0]; i++)
                t[((size_t)k * s1 + (size_t)j) * s0 + (size_t)i] += t[((size_t)(k - 1) * s1 + (size_t)j) * s0 + (size_t)i];
}

uint32_t reduce__sat_count(const uint32_t *t, const int nb[3], const int lo[3], const int hi[3])
{
    size_t s0 = (size_t)nb[0] + 1, s1 = (size_t)nb[1] + 1;
#define S(i, j, k) t[((size_t)(k) * s1 + (size_t)(j)) * s0 + (size_t)(i)]
    int a0 = lo[0], a1 = hi[0] + 1, b0 = lo[1], b1 = hi[1] + 1, c0 = lo[2], c1 = hi[2] + 1;
    return S(a1, b1, c1) - S(a0, b1, c1) - S(a1, b0, c1) - S(a1, b1, c0) + S(a0, b0, c1) + S(a0, b1, c0) +
           S(a1, b0, c0) - S(a0, b0, c0);
#undef S
}

/* Counted blocks among blocks [lo, hi] (inclusive). */
static uint32_t blocks_counted(const reduce_metric *m, const int lo[3], const int hi[3])
{
    return reduce__sat_count(m->bsum, m->nb, lo, hi);
}

/* bone[] |= fragment f's bone sampled (nearest) at the VOI cells (c0: the first, d per axis, in
 * the grid fragment g's crop), over the cells its crop box reaches: what cell_bone finds there, by
 * one affine map from a cell to f's voxel index instead of poses per cell. */
static void sample_into(const frag *g, const frag *f, const int c0[3], const int d[3], uint8_t *bone)
{
    pose P = pose_compose(pose_inverse(pose_compose(f->pose, f->home)), pose_compose(g->pose, g->home)), Q;
    double R[3][3], A[3][3], b[3], lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    pose_to_matrix(&P, R);
    for (int a = 0; a < 3; a++) {
        b[a] = P.t[a] / f->spacing[a];
        for (int c = 0; c < 3; c++) {
            A[a][c] = R[a][c] * g->spacing[c] / f->spacing[a];
            b[a] += A[a][c] * c0[c];
        }
    }
    Q = pose_inverse(P); /* f's crop box into the VOI's cells, for the range to sample */
    for (int corner = 0; corner < 8; corner++) {
        double l[3], x[3];
        for (int a = 0; a < 3; a++)
            l[a] = ((corner >> a & 1) ? f->dim[a] - 0.5 : -0.5) * f->spacing[a];
        pose_apply(&Q, l, x);
        for (int a = 0; a < 3; a++) {
            lo[a] = fmin(lo[a], x[a] / g->spacing[a] - c0[a]);
            hi[a] = fmax(hi[a], x[a] / g->spacing[a] - c0[a]);
        }
    }
    int r0[3], r1[3];
    for (int a = 0; a < 3; a++) {
        r0[a] = lo[a] < 0 ? 0 : (int)lo[a];
        r1[a] = hi[a] > d[a] - 1 ? d[a] - 1 : (int)ceil(hi[a]);
        if (r1[a] < r0[a])
            return;
    }
    for (int k = r0[2]; k <= r1[2]; k++)
        for (int j = r0[1]; j <= r1[1]; j++) {
            uint8_t *row = bone + ((size_t)k * d[1] + j) * d[0];
            for (int i = r0[0]; i <= r1[0]; i++) {
                if (row[i])
                    continue;
                int v[3], in = 1;
                for (int a = 0; a < 3 && in; a++) {
                    v[a] = (int)floor(A[a][0] * i + A[a][1] * j + A[a][2] * k + b[a] + 0.5);
                    in = v[a] >= 0 && v[a] < f->dim[a];
                }
                row[i] = in && f->prob[((size_t)v[2] * f->dim[1] + v[1]) * f->dim[0] + v[0]];
            }
        }
}

/* The assembly's bone on the VOI cells (cell_bone for each, 0 or 1): the grid fragment's own
 * voxels, then each other fragment sampled where the grid has none. */
static void voi_bone(const frag *const *asm_, int nasm, const int c0[3], const int d[3], uint8_t *bone)
{
    const frag *g = asm_[0];
    /* the cells along i inside g's crop, [i0, i1) */
    int i0 = c0[0] < 0 ? -c0[0] : 0, i1 = g->dim[0] - c0[0] < d[0] ? g->dim[0] - c0[0] : d[0];
    for (int k = 0; k < d[2]; k++)
        for (int j = 0; j < d[1]; j++) {
            uint8_t *row = bone + ((size_t)k * d[1] + j) * d[0];
            int l1 = c0[1] + j, l2 = c0[2] + k;
            memset(row, 0, (size_t)d[0]);
            if (l1 < 0 || l2 < 0 || l1 >= g->dim[1] || l2 >= g->dim[2])
                continue;
            const uint8_t *src = g->prob + ((size_t)l2 * g->dim[1] + l1) * g->dim[0];
            for (int i = i0; i < i1; i++)
                row[i] = src[c0[0] + i] != 0;
        }
    for (int f = 1; f < nasm; f++)
        sample_into(g, asm_[f], c0, d, bone);
}

/* The VOI's cells in the grid fragment g (c0 and its size d), with a border of one (D), and g's
 * spacing. 0 or reduce_voi_cells' error. */
static int metric_grid(reduce_metric *m, const frag *g, const reduce_voi *voi)
{
    int c1[3];
    if (reduce_voi_cells(g, voi, m->c0, c1) < 0)
        return -1;
    for (int a = 0; a < 3; a++) {
        m->d[a] = c1[a] - m->c0[a] + 1;
        m->D[a] = m->d[a] + 2;
        m->sg[a] = g->spacing[a];
    }
    return 0;
}

/* The assembly's bone on the VOI's cells (voi_bone), its cells counted (m->n1) and their index sums
 * (sum, for the fixed centre); with gap_mm > 0, the bone grown by the gap (what was lost counts as
 * the assembly's) and counted again. 0 or FN_ENOMEM. */
static int metric_bone(reduce_metric *m, const frag *const *asm_, int nasm, double gap_mm, uint8_t *bone,
                       double sum[3])
{
    size_t nv = (size_t)m->d[0] * m->d[1] * m->d[2];
    voi_bone(asm_, nasm, m->c0, m->d, bone);
    /* whole numbers, exact in any order */
    int64_t n1 = 0, si = 0, sj = 0, sk = 0;
    const uint8_t *row = bone;
    for (int k = 0; k < m->d[2]; k++)
        for (int j = 0; j < m->d[1]; j++, row += m->d[0]) {
            int64_t n = 0, s = 0;
            for (int i = 0; i < m->d[0]; i++) {
                n += row[i];
                s += row[i] ? i : 0;
            }
            n1 += n, si += s, sj += n * j, sk += n * k;
        }
    m->n1 += (double)n1;
    sum[0] += (double)si, sum[1] += (double)sj, sum[2] += (double)sk;
    if (gap_mm > 0) { /* the gap left where bone was lost counts as the assembly's */
        uint8_t *gb = malloc(nv);
        if (!gb)
            return fn_err_set(FN_ENOMEM, "reduce metric: out of memory for the gap");
        if (dilate_ball(bone, gb, m->d, m->sg, gap_mm, NULL) < 0) {
            free(gb);
            return fn_err_set(FN_ENOMEM, "reduce metric: out of memory for the gap");
        }
        memcpy(bone, gb, nv);
        free(gb);
        m->n1 = 0;
        for (size_t q = 0; q < nv; q++)
            m->n1 += bone[q];
    }
    return 0;
}

/* The band around the bone (in: every cell when there is none), then each cell's flags (in the
 * band, bone) into m->cell inside its border, and the band's cells counted (m->nvoi). 0 or
 * FN_ENOMEM. */
static int metric_cells(reduce_metric *m, const uint8_t *bone, uint8_t *in, double band_mm, double cut_mm)
{
    size_t nv = (size_t)m->d[0] * m->d[1] * m->d[2];
    int kb[3];
    band_cells(m->sg, band_mm, kb);
    if (kb[0] < 0)
        memset(in, 1, nv);
    else if (cut_mm > 0 ? dilate_ball(bone, in, m->d, m->sg, cut_mm, kb) < 0 : dilate_box(bone, in, m->d, kb) < 0)
        return fn_err_set(FN_ENOMEM, "reduce metric: out of memory for the band");
    const int d0 = m->d[0];
    const size_t sy = (size_t)m->D[0], sz = sy * m->D[1];
    size_t idx = 0, nvoi = 0;
    for (int k = 0; k < m->d[2]; k++)
        for (int j = 0; j < m->d[1]; j++, idx += (size_t)d0) {
            const size_t row = (size_t)(k + 1) * sz + (size_t)(j + 1) * sy + 1;
            uint8_t *restrict cell = m->cell + row;
            int8_t *restrict score = m->score + row;
            const uint8_t *bo = bone + idx, *bi = in + idx;
            for (int i = 0; i < d0; i++) {
                int b = bo[i] != 0, v = bi[i] != 0;
                cell[i] = (uint8_t)((v ? REDUCE_CELL_V : 0) | (b ? REDUCE_CELL_A : 0));
                score[i] = (int8_t)(b ? 1 : v ? -1 : 0);
                nvoi += (size_t)v;
            }
        }
    m->nvoi += (double)nvoi;
    /* near: a score among the cell and its next along each axis, by three shifted ORs over the
     * whole raster (the bits of a last cell on an axis, which wrap, are never read: an evaluation
     * reads the cell before a voxel, never the last of the border) */
    size_t N = sz * m->D[2];
    uint8_t *t = malloc(N + 8);
    if (!t)
        return fn_err_set(FN_ENOMEM, "reduce metric: out of memory for the band");
    for (size_t q = 0; q < N; q++)
        t[q] = m->score[q] != 0;
    memset(t + N, 0, 8);
    or_bytes(t, t + 1, N - 1);
    or_bytes(t, t + sy, N - sy);
    or_bytes(t, t + sz, N - sz);
    for (size_t q = 0; q < N; q += 8) {
        uint64_t x;
        memcpy(&x, t + q, 8);
        m->near[q >> 3] = (uint8_t)((x * 0x0102040810204080ull) >> 56);
    }
    free(t);
    return 0;
}

/* The band's reach (the band grown by band_k cells) and the brick tables (block_table). 0 or
 * FN_ENOMEM. */
static int metric_reach(reduce_metric *m, const reduce_bricks *b, const uint8_t *in)
{
    size_t nv = (size_t)m->d[0] * m->d[1] * m->d[2];
    for (int a = 0; a < 3; a++) {
        m->band_k[a] = (int)ceil(reduce__tune.band_reach_mm / m->sg[a]) + 2;
        m->band_slack[a] = m->band_k[a] - 1.5;
    }
    m->reach = malloc(nv);
    int rc = m->reach && band_arrays(m, b) == 0 ? dilate_box(in, m->reach, m->d, m->band_k) : FN_ENOMEM;
    if (rc < 0 || block_table(m) < 0)
        return fn_err_set(FN_ENOMEM, "reduce metric: out of memory for the band");
    return 0;
}

/* The grid's poses, the fixed centre (the bone's centroid, sum: its cells' index sums; the VOI's
 * centre without bone) in world mm, and a moving voxel's volume in grid voxels. */
static void metric_place(reduce_metric *m, const frag *g, const frag *moving, const double sum[3])
{
    m->grid_inv = pose_inverse(pose_compose(g->pose, g->home));
    m->grid_world = pose_compose(g->pose, g->home);
    double l[3];
    for (int a = 0; a < 3; a++)
        l[a] = m->n1 > 0 ? (m->c0[a] + sum[a] / m->n1) * m->sg[a] : (m->c0[a] + 0.5 * (m->d[a] - 1)) * m->sg[a];
    pose_apply(&m->grid_world, l, m->fixed_centre);
    m->w = moving->spacing[0] * moving->spacing[1] * moving->spacing[2] / (m->sg[0] * m->sg[1] * m->sg[2]);
}

reduce_metric *reduce__metric_with(const frag *const *asm_, int nasm, const frag *moving, reduce_bricks *b,
                                   const reduce_voi *voi, reduce_count mode, double band_mm, double cut_mm,
                                   double gap_mm)
{
    if (!asm_ || nasm < 1 || !moving || !voi) {
        fn_err_set(FN_EINVAL, "reduce metric: no fragment or VOI");
        return NULL;
    }
    reduce_metric *m = calloc(1, sizeof *m);
    if (!m) {
        fn_err_set(FN_ENOMEM, "reduce metric: out of memory");
        return NULL;
    }
    m->mode = mode;
    m->b = b;
    const frag *g = asm_[0];
    if (metric_grid(m, g, voi) < 0) {
        free(m);
        return NULL;
    }
    size_t nv = (size_t)m->d[0] * m->d[1] * m->d[2];
    m->cell = calloc((size_t)m->D[0] * m->D[1] * m->D[2], sizeof *m->cell);
    m->score = calloc((size_t)m->D[0] * m->D[1] * m->D[2], sizeof *m->score);
    m->near = calloc(((size_t)m->D[0] * m->D[1] * m->D[2] + 7) / 8, sizeof *m->near);
    uint8_t *bone = calloc(nv, 1), *in = malloc(nv);
    double sum[3] = {0, 0, 0};
    int rc = 0;
    if (!m->cell || !m->score || !m->near || !bone || !in)
        rc = fn_err_set(FN_ENOMEM, "reduce metric: out of memory for a %dx%dx%d VOI", m->d[0], m->d[1], m->d[2]);
    if (rc == 0)
        rc = metric_bone(m, asm_, nasm, gap_mm, bone, sum);
    if (rc == 0)
        rc = metric_cells(m, bone, in, band_mm, cut_mm);
    if (rc == 0)
        rc = metric_reach(m, b, in);
    free(bone);
    free(in);
    if (rc < 0) {
        reduce_metric_free(m);
        return NULL;
    }
    metric_place(m, g, moving, sum);
    if (reduce__metric_rebase(m, &moving->pose) < 0) {
        reduce_metric_free(m);
        return NULL;
    }
    return m;
}

reduce_metric *reduce_metric_new(const frag *const *asm_, int nasm, const frag *moving, const reduce_voi *voi,
                                 reduce_count mode, double band_mm)
{
    if (!moving) {
        fn_err_set(FN_EINVAL, "reduce metric: no moving fragment");
        return NULL;
    }
    reduce_bricks *b = reduce__bricks_new(moving);
    if (!b)
        return NULL;
    reduce_metric *m = reduce__metric_with(asm_, nasm, moving, b, voi, mode, band_mm, reduce__band_cut(band_mm), 0);
    if (!m)
        reduce__bricks_free(b);
    else
        m->own_bricks = 1;
    return m;
}

/* Moving crop index -> VOI cell coordinates (0 = the first VOI cell): x = M u + T. */
static void carry(const reduce_metric *m, const pose *p, double M[3][3], double T[3])
{
    pose rel = pose_compose(m->grid_inv, pose_compose(*p, m->b->home));
    double R[3][3];
    pose_to_matrix(&rel, R);
    for (int a = 0; a < 3; a++) {
        for (int c = 0; c < 3; c++)
            M[a][c] = R[a][c] * m->b->spacing[c] / m->sg[a];
        T[a] = rel.t[a] / m->sg[a] - m->c0[a];
    }
}

/* The VOI cell coordinates of a point u of the moving crop (index units). */
static void carried(double M[3][3], const double T[3], const float u[3], double x[3])
{
    for (int a = 0; a < 3; a++)
        x[a] = M[a][0] * u[0] + M[a][1] * u[1] + M[a][2] * u[2] + T[a];
}

/* Whether a brick whose centre lies at VOI cell coordinates x can weigh a counted cell when its
 * voxels move pad cells more: its bounding sphere reaches a counted block. */
static int brick_visible(const reduce_metric *m, const reduce_brick *br, const double x[3], int pad)
{
    double smin = fmin(m->sg[0], fmin(m->sg[1], m->sg[2])), r = br->r_mm / smin + 1 + pad;
    int lo[3], hi[3];
    for (int a = 0; a < 3; a++) {
        if (x[a] < -r || x[a] > m->d[a] - 1 + r)
            return 0;
        /* padded cells x - r - 1 .. x + r + 2 hold every cell a voxel of the brick can weigh */
        int p0 = (int)floor(x[a] - r), p1 = (int)ceil(x[a] + r) + 2;
        p0 = p0 < 0 ? 0 : p0;
        p1 = p1 > m->D[a] - 1 ? m->D[a] - 1 : p1;
        lo[a] = p0 / REDUCE_BLOCK;
        hi[a] = p1 / REDUCE_BLOCK;
    }
    return blocks_counted(m, lo, hi) > 0;
}

/* Whether a run from x with len voxels can weigh a counted cell when its voxels move pad cells
 * more (the block table again, at the run's reach): most runs of a visible brick lie away from the
 * fixed bone. */
static int run_visible(const reduce_metric *m, const double x[3], const double step[3], int len, int pad)
{
    int lo[3], hi[3];
    for (int a = 0; a < 3; a++) {
        double e = x[a] + (len - 1) * step[a], l = fmin(x[a], e), h = fmax(x[a], e);
        if (h <= -1 - pad || l >= m->d[a] + pad)
            return 0;
        int p0 = (int)floor(l) - pad, p1 = (int)floor(h) + 2 + pad; /* padded cells floor(l)+1 .. floor(h)+2 */
        p0 = p0 < 0 ? 0 : p0;
        p1 = p1 > m->D[a] - 1 ? m->D[a] - 1 : p1;
        lo[a] = p0 / REDUCE_BLOCK;
        hi[a] = p1 / REDUCE_BLOCK;
    }
    return blocks_counted(m, lo, hi) > 0;
}

/* What is done with one run of moving voxels: its first voxel at VOI cell coordinates x, the next
 * ones step apart. */
typedef void run_fn(const reduce_metric *m, const reduce_run *run, const double x[3], const double step[3], void *acc);

/* How far (VOI cells along each axis) a brick's centre may move from the band's reference pose with
 * its band runs still exact, at the carry M. */
static void band_reach(const reduce_metric *m, double M[3][3], double reach[3])
{
    for (int a = 0; a < 3; a++) {
        /* a voxel of a brick lies (BRICK - 1) / 2 voxels or less from its centre along each crop axis */
        double turn = 0;
        for (int c = 0; c < 3; c++)
            turn += fabs(M[a][c] - m->band_M[a][c]);
        reach[a] = m->band_ref ? m->band_slack[a] - 0.5 * (BRICK - 1) * turn : -1;
    }
}

int reduce__metric_drifted(const reduce_metric *m, const pose *p)
{
    double M[3][3], T[3], reach[3];
    carry(m, p, M, T);
    band_reach(m, M, reach);
    for (int bi = 0; bi < m->b->nbrick; bi++) {
        if (m->band_first[bi + 1] == m->band_first[bi])
            continue;
        double x[3];
        carried(M, T, m->b->brick[bi].c, x);
        for (int a = 0; a < 3; a++)
            if (fabs(x[a] - m->band_x[bi][a]) > 0.5 * reach[a])
                return 1;
    }
    return 0;
}

/* Every run of moving voxels at pose p that can lie in the VOI, handed to fn. counted: only the
 * runs that can weigh a counted cell, and, for the bricks that moved less than the band's reach from
 * its reference pose, only their band runs (reduce__metric_rebase). Inlined into each caller, so
 * that fn, a constant there, is called directly (inlined too) for each of the ~3,000 short runs of
 * an evaluation of the skull's fit. */
static inline __attribute__((always_inline)) void walk_runs(const reduce_metric *m, const pose *p, int counted,
                                                            run_fn *fn, void *acc)
{
    double M[3][3], T[3], step[3], reach[3];
    carry(m, p, M, T);
    band_reach(m, M, reach);
    for (int a = 0; a < 3; a++) {
        step[a] = M[a][0];
        reach[a] = counted ? reach[a] : -1;
    }
    for (int bi = 0; bi < m->b->nbrick; bi++) {
        const reduce_brick *br = &m->b->brick[bi];
        double x[3];
        carried(M, T, br->c, x);
        const reduce_run *run = m->b->run + br->first;
        int n = br->n, cull = counted;
        if (fabs(x[0] - m->band_x[bi][0]) <= reach[0] && fabs(x[1] - m->band_x[bi][1]) <= reach[1] &&
            fabs(x[2] - m->band_x[bi][2]) <= reach[2]) {
            run = m->band + m->band_first[bi];
            n = m->band_first[bi + 1] - m->band_first[bi];
            cull = 0;
        } else if (!brick_visible(m, br, x, 0))
            continue;
        for (int r = 0; r < n; r++) {
            double u[3] = {run[r].i0, run[r].j, run[r].k}, x0[3];
            for (int a = 0; a < 3; a++)
                x0[a] = M[a][0] * u[0] + M[a][1] * u[1] + M[a][2] * u[2] + T[a];
            if (!cull || run_visible(m, x0, step, run[r].len, 0))
                fn(m, &run[r], x0, step, acc);
        }
    }
}

/* n_2 and n_I of a run (acc: the two sums), nearest or trilinear. */
static void run_counts(const reduce_metric *m, const reduce_run *run, const double x0[3], const double step[3],
                       void *acc)
{
    const int len = run->len;
    const int d0 = m->d[0], d1 = m->d[1], d2 = m->d[2];
    const size_t sy = (size_t)m->D[0], sz = (size_t)m->D[0] * m->D[1];
    double x = x0[0], y = x0[1], z = x0[2], s2 = 0, si = 0;
    if (m->mode == REDUCE_NEAREST) {
        for (int n = 0; n < len; n++, x += step[0], y += step[1], z += step[2]) {
            if (!(x >= -0.5 && y >= -0.5 && z >= -0.5 && x < d0 - 0.5 && y < d1 - 0.5 && z < d2 - 0.5))
                continue;
            int i = (int)(x + 0.5), j = (int)(y + 0.5), k = (int)(z + 0.5);
            uint8_t c = m->cell[(size_t)(k + 1) * sz + (size_t)(j + 1) * sy + (size_t)(i + 1)];
            s2 += c & REDUCE_CELL_V;
            si += c >> 1;
        }
    } else
        for (int n = 0; n < len; n++, x += step[0], y += step[1], z += step[2]) {
            if (!(x > -1 && y > -1 && z > -1 && x < d0 && y < d1 && z < d2))
                continue;
            int i = (int)(x + 1) - 1, j = (int)(y + 1) - 1, k = (int)(z + 1) - 1;
            const uint8_t *c = m->cell + (size_t)(k + 1) * sz + (size_t)(j + 1) * sy + (size_t)(i + 1);
            unsigned c00 = c[0] | c[1] << 2, c10 = c[sy] | c[sy + 1] << 2; /* a cell and the next along i */
            unsigned c01 = c[sz] | c[sz + 1] << 2, c11 = c[sz + sy] | c[sz + sy + 1] << 2;
            if (!(c00 | c10 | c01 | c11))
                continue;
            float fx = (float)(x - i), fy = (float)(y - j), fz = (float)(z - k), e[2][2][2];
            unsigned q[2][2] = {{c00, c10}, {c01, c11}};
            for (int b = 0; b < 2; b++) /* e[bit][z][y]: v or a interpolated along i */
                for (int a = 0; a < 2; a++)
                    for (int bit = 0; bit < 2; bit++) {
                        float lo = (float)(q[b][a] >> bit & 1), hi = (float)(q[b][a] >> (bit + 2) & 1);
                        e[bit][b][a] = lo + fx * (hi - lo);
                    }
            float v0 = e[0][0][0] + fy * (e[0][0][1] - e[0][0][0]), v1 = e[0][1][0] + fy * (e[0][1][1] - e[0][1][0]);
            float a0 = e[1][0][0] + fy * (e[1][0][1] - e[1][0][0]), a1 = e[1][1][0] + fy * (e[1][1][1] - e[1][1][0]);
            s2 += v0 + fz * (v1 - v0);
            si += a0 + fz * (a1 - a0);
        }
    double *sum = acc;
    sum[0] += s2;
    sum[1] += si;
}

/* The numerator's sum of a run, trilinear (acc: one sum): the score field interpolated at each
 * voxel, as run_counts' two sums would give 2 s_I - s_2, in half its work. */
static void run_score(const reduce_metric *m, const reduce_run *run, const double x0[3], const double step[3],
                      void *acc)
{
    const int len = run->len;
    const int d0 = m->d[0], d1 = m->d[1], d2 = m->d[2];
    const size_t sy = (size_t)m->D[0], sz = (size_t)m->D[0] * m->D[1];
    double x = x0[0], y = x0[1], z = x0[2];
    double s = 0;
    for (int n = 0; n < len; n++, x += step[0], y += step[1], z += step[2]) {
        if (!(x > -1 && y > -1 && z > -1 && x < d0 && y < d1 && z < d2))
            continue;
        int i = (int)(x + 1) - 1, j = (int)(y + 1) - 1, k = (int)(z + 1) - 1;
        const size_t at = (size_t)(k + 1) * sz + (size_t)(j + 1) * sy + (size_t)(i + 1);
        if (!(m->near[at >> 3] >> (at & 7) & 1))
            continue;
        const int8_t *c = m->score + at;
        int g000 = c[0], g100 = c[1], g010 = c[sy], g110 = c[sy + 1];
        int g001 = c[sz], g101 = c[sz + 1], g011 = c[sz + sy], g111 = c[sz + sy + 1];
        float fx = (float)(x - i), fy = (float)(y - j), fz = (float)(z - k);
        float a00 = (float)g000 + fx * (float)(g100 - g000), a10 = (float)g010 + fx * (float)(g110 - g010);
        float a01 = (float)g001 + fx * (float)(g101 - g001), a11 = (float)g011 + fx * (float)(g111 - g011);
        float b0 = a00 + fy * (a10 - a00), b1 = a01 + fy * (a11 - a01);
        s += b0 + fz * (b1 - b0);
    }
    *(double *)acc += s;
}

double reduce_metric_eval(const reduce_metric *m, const pose *p, reduce_counts *counts)
{
    double sum[2] = {0, 0};
    if (m->mode == REDUCE_NEAREST || counts) {
        walk_runs(m, p, 1, run_counts, sum);
        reduce_counts c = {m->n1, sum[0] * m->w, sum[1] * m->w, m->nvoi};
        if (counts)
            *counts = c;
        return reduce_counts_metric(&c);
    }
    walk_runs(m, p, 1, run_score, sum);
    return m->nvoi > 0 ? (sum[0] * m->w - m->n1) / m->nvoi : 0;
}

/* Whether a voxel at VOI cell coordinates x lies within band_k cells (per axis) of a counted cell. */
static int in_reach(const reduce_metric *m, const double x[3])
{
    int c[3];
    for (int a = 0; a < 3; a++) {
        c[a] = (int)floor(x[a] + 0.5);
        if (c[a] < -m->band_k[a] || c[a] > m->d[a] - 1 + m->band_k[a])
            return 0;
        c[a] = c[a] < 0 ? 0 : c[a] > m->d[a] - 1 ? m->d[a] - 1 : c[a]; /* no nearer a cell inside */
    }
    return m->reach[((size_t)c[2] * m->d[1] + c[1]) * m->d[0] + c[0]];
}

static int push_band(reduce_metric *m, int i0, int len, int j, int k)
{
    if (m->nband == m->capband) {
        size_t nc = m->capband ? 2 * m->capband : 1024;
        reduce_run *r = realloc(m->band, nc * sizeof *r);
        if (!r)
            return FN_ENOMEM;
        m->band = r;
        m->capband = nc;
    }
    m->band[m->nband++] = (reduce_run){(uint16_t)i0, (uint16_t)len, (uint16_t)j, (uint16_t)k};
    return 0;
}

int reduce__metric_rebase(reduce_metric *m, const pose *ref)
{
    double M[3][3], T[3];
    carry(m, ref, M, T);
    memcpy(m->band_M, M, sizeof M);
    m->band_ref = 0;
    m->nband = 0;
    int pad = m->band_k[0] > m->band_k[1] ? m->band_k[0] : m->band_k[1];
    pad = pad > m->band_k[2] ? pad : m->band_k[2];
    for (int bi = 0; bi < m->b->nbrick; bi++) {
        const reduce_brick *br = &m->b->brick[bi];
        double *x = m->band_x[bi];
        carried(M, T, br->c, x);
        m->band_first[bi] = m->nband;
        int near = brick_visible(m, br, x, pad);
        for (int q = br->first; near && q < br->first + br->n; q++) {
            const reduce_run *run = &m->b->run[q];
            double u[3] = {run->i0, run->j, run->k}, y[3];
            for (int a = 0; a < 3; a++)
                y[a] = M[a][0] * u[0] + M[a][1] * u[1] + M[a][2] * u[2] + T[a];
            if (!run_visible(m, y, (double[3]){M[0][0], M[1][0], M[2][0]}, run->len, pad))
                continue;
            for (int n = 0, s = -1; n <= run->len; n++) { /* s: the first kept voxel of a sub-run */
                int keep = n < run->len && in_reach(m, y);
                if (keep && s < 0)
                    s = n;
                if (!keep && s >= 0) {
                    if (push_band(m, run->i0 + s, n - s, run->j, run->k) < 0)
                        return fn_err_set(FN_ENOMEM, "reduce metric: out of memory for the band");
                    s = -1;
                }
                for (int a = 0; a < 3; a++)
                    y[a] += M[a][0];
            }
        }
    }
    m->band_first[m->b->nbrick] = m->nband;
    m->band_ref = 1;
    return 0;
}

double reduce_metric_radius(const reduce_metric *m, const pose *p, const double c[3])
{
    double S[3][3];
    reduce_metric_spread(m, p, c, S);
    return sqrt(S[0][0] + S[1][1] + S[2][2]);
}

/* The scatter of a run's voxels inside the VOI about a centre (acc: a spread). */
typedef struct spread {
    double c[3], s[3][3];
    size_t n;
} spread;

static void run_spread(const reduce_metric *m, const reduce_run *run, const double x0[3], const double step[3],
                       void *acc)
{
    spread *sp = acc;
    for (int k = 0; k < run->len; k++) {
        double x[3], l[3], w[3];
        for (int a = 0; a < 3; a++)
            x[a] = x0[a] + k * step[a];
        if (x[0] < -0.5 || x[1] < -0.5 || x[2] < -0.5 || x[0] >= m->d[0] - 0.5 || x[1] >= m->d[1] - 0.5 ||
            x[2] >= m->d[2] - 0.5)
            continue;
        for (int a = 0; a < 3; a++)
            l[a] = (x[a] + m->c0[a]) * m->sg[a];
        pose_apply(&m->grid_world, l, w);
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++)
                sp->s[a][b] += (w[a] - sp->c[a]) * (w[b] - sp->c[b]);
        sp->n++;
    }
}

void reduce_metric_spread(const reduce_metric *m, const pose *p, const double c[3], double S[3][3])
{
    spread sp = {{c[0], c[1], c[2]}, {{0}}, 0};
    walk_runs(m, p, 0, run_spread, &sp);
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            S[a][b] = sp.n ? sp.s[a][b] / (double)sp.n : 0;
}

/* Brute force's band: a bone cell within k cells on every axis (k[0] < 0: no band) and within
 * band_corner * band_mm (Euclidean, on the spacing sg), looked for cell by cell. */
static int in_band(const frag *const *asm_, int nasm, const pose *inv, const int c0[3], const int d[3], const int k[3],
                   const double sg[3], double band_mm, int i, int j, int l)
{
    if (k[0] < 0)
        return 1;
    const double r = reduce__band_cut(band_mm);
    for (int z = l - k[2]; z <= l + k[2]; z++)
        for (int y = j - k[1]; y <= j + k[1]; y++)
            for (int x = i - k[0]; x <= i + k[0]; x++) {
                double q = ((x - i) * sg[0]) * ((x - i) * sg[0]) + ((y - j) * sg[1]) * ((y - j) * sg[1]) +
                           ((z - l) * sg[2]) * ((z - l) * sg[2]);
                if (x >= 0 && y >= 0 && z >= 0 && x < d[0] && y < d[1] && z < d[2] && q <= r * r + 1e-9 &&
                    cell_bone(asm_, nasm, inv, c0, x, y, z))
                    return 1;
            }
    return 0;
}

double reduce_metric_brute(const frag *const *asm_, int nasm, const frag *moving, const pose *p,
                           const reduce_voi *voi, reduce_count mode, double band_mm, reduce_counts *counts)
{
    const frag *g = asm_[0];
    int c0[3], c1[3], d[3];
    if (reduce_voi_cells(g, voi, c0, c1) < 0)
        return NAN;
    for (int a = 0; a < 3; a++)
        d[a] = c1[a] - c0[a] + 1;
    pose *inv = crop_poses(asm_, nasm);
    if (!inv)
        return NAN;
    double n1 = 0, n2 = 0, ni = 0, nvoi = 0;
    int kb[3];
    band_cells(g->spacing, band_mm, kb);
    for (int k = 0; k < d[2]; k++)
        for (int j = 0; j < d[1]; j++)
            for (int i = 0; i < d[0]; i++) {
                n1 += cell_bone(asm_, nasm, inv, c0, i, j, k);
                nvoi += in_band(asm_, nasm, inv, c0, d, kb, g->spacing, band_mm, i, j, k);
            }
    pose ginv_pose = pose_inverse(g->pose), ginv_home = pose_inverse(g->home);
    for (int k = 0; k < moving->dim[2]; k++)
        for (int j = 0; j < moving->dim[1]; j++)
            for (int i = 0; i < moving->dim[0]; i++) {
                if (!moving->prob[((size_t)k * moving->dim[1] + j) * moving->dim[0] + i])
                    continue;
                double l[3] = {i * moving->spacing[0], j * moving->spacing[1], k * moving->spacing[2]};
                double h[3], w[3], gh[3], gl[3], x[3];
                pose_apply(&moving->home, l, h);
                pose_apply(p, h, w);
                pose_apply(&ginv_pose, w, gh);
                pose_apply(&ginv_home, gh, gl);
                for (int a = 0; a < 3; a++)
                    x[a] = gl[a] / g->spacing[a] - c0[a];
                if (mode == REDUCE_NEAREST) {
                    int c[3], in = 1;
                    for (int a = 0; a < 3; a++) {
                        c[a] = (int)floor(x[a] + 0.5);
                        in &= c[a] >= 0 && c[a] < d[a];
                    }
                    if (in && in_band(asm_, nasm, inv, c0, d, kb, g->spacing, band_mm, c[0], c[1], c[2])) {
                        n2 += 1;
                        ni += cell_bone(asm_, nasm, inv, c0, c[0], c[1], c[2]);
                    }
                    continue;
                }
                /* Trilinear: the eight cells around x, each weighted, inside the VOI only. */
                int b[3];
                for (int a = 0; a < 3; a++)
                    b[a] = (int)floor(x[a]);
                for (int corner = 0; corner < 8; corner++) {
                    double wgt = 1;
                    int c[3], in = 1;
                    for (int a = 0; a < 3; a++) {
                        c[a] = b[a] + (corner >> a & 1);
                        wgt *= corner >> a & 1 ? x[a] - b[a] : 1 - (x[a] - b[a]);
                        in &= c[a] >= 0 && c[a] < d[a];
                    }
                    if (!in || !in_band(asm_, nasm, inv, c0, d, kb, g->spacing, band_mm, c[0], c[1], c[2]))
                        continue;
                    n2 += wgt;
                    ni += wgt * cell_bone(asm_, nasm, inv, c0, c[0], c[1], c[2]);
                }
            }
    free(inv);
    double w = moving->spacing[0] * moving->spacing[1] * moving->spacing[2] /
               (g->spacing[0] * g->spacing[1] * g->spacing[2]);
    reduce_counts c = {n1, n2 * w, ni * w, nvoi};
    if (counts)
        *counts = c;
    return reduce_counts_metric(&c);
}

/* A coarse copy of f for the first stage: 2x2x2 (or 2 in-plane where a slice is already thick) voxels
 * per cell, bone where at least half of them are; same id, pose, centroid and axes (home world). 0
 * or FN_ENOMEM (*c then holds nothing to free). */
int reduce__coarse_frag(const frag *f, frag *c)
{
    *c = *f;
    int s[3];
    double smin = fmin(f->spacing[0], fmin(f->spacing[1], f->spacing[2]));
    for (int a = 0; a < 3; a++) {
        s[a] = f->spacing[a] < 1.5 * smin + 1e-9 ? 2 : 1;
        c->dim[a] = (f->dim[a] + s[a] - 1) / s[a];
        c->spacing[a] = f->spacing[a] * s[a];
    }
    int need = s[0] * s[1] * s[2] / 2;
    pose shift = POSE_IDENTITY;
    for (int a = 0; a < 3; a++)
        shift.t[a] = 0.5 * (s[a] - 1) * f->spacing[a];
    c->home = pose_compose(f->home, shift);
    c->prob = calloc((size_t)c->dim[0] * c->dim[1] * c->dim[2], 1);
    if (!c->prob)
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for fragment %d's coarse copy", f->id);
    c->voxels = 0;
    for (int k = 0; k < c->dim[2]; k++)
        for (int j = 0; j < c->dim[1]; j++)
            for (int i = 0; i < c->dim[0]; i++) {
                int n = 0;
                for (int dk = 0; dk < s[2]; dk++)
                    for (int dj = 0; dj < s[1]; dj++)
                        for (int di = 0; di < s[0]; di++) {
                            int x = i * s[0] + di, y = j * s[1] + dj, z = k * s[2] + dk;
                            if (x < f->dim[0] && y < f->dim[1] && z < f->dim[2])
                                n += f->prob[((size_t)z * f->dim[1] + y) * f->dim[0] + x] != 0;
                        }
                if (n >= need) {
                    c->prob[((size_t)k * c->dim[1] + j) * c->dim[0] + i] = 255;
                    c->voxels++;
                }
            }
    return 0;
}
