/* reduce_voi: the automatic VOI, the contact zone of a moving fragment with the assembly (see
 * reduce_auto_voi in reduce.h), on a coarse occupancy grid of both sides' bone. */
#include "reduce.h"
#include "reduce_impl.h"

#include "err.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* Adds f's bone voxels at its pose. */
static int cloud_add(reduce_cloud *c, const frag *f)
{
    float *p = realloc(c->p, (c->n + f->voxels + 1) * 3 * sizeof *p);
    if (!p)
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for fragment %d's voxels", f->id);
    c->p = p;
    pose w = pose_compose(f->pose, f->home);
    size_t cap = c->n + f->voxels;
    for (int k = 0; k < f->dim[2]; k++)
        for (int j = 0; j < f->dim[1]; j++) {
            const uint8_t *row = f->prob + ((size_t)k * f->dim[1] + j) * f->dim[0];
            for (int i = 0; i < f->dim[0]; i++) {
                uint64_t eight;
                while (i + 8 <= f->dim[0] && (memcpy(&eight, row + i, 8), eight == 0))
                    i += 8; /* most of a crop is empty */
                if (i >= f->dim[0] || !row[i] || c->n >= cap)
                    continue;
                double l[3] = {i * f->spacing[0], j * f->spacing[1], k * f->spacing[2]}, x[3];
                pose_apply(&w, l, x);
                for (int a = 0; a < 3; a++)
                    c->p[3 * c->n + a] = (float)x[a];
                c->n++;
            }
        }
    return 0;
}

/* The box of points p[0..n-1] joined to lo, hi (finite points: plain comparisons do fmin's work). */
static void box_add(const float *p, size_t n, double lo[3], double hi[3])
{
    for (size_t i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) {
            double x = p[3 * i + a];
            lo[a] = x < lo[a] ? x : lo[a];
            hi[a] = x > hi[a] ? x : hi[a];
        }
}

/* The contact zone works on a grid of zone_cell_mm cells whose corner lies a cell below the lower
 * corner of both sides' bone: at the moving piece's pose, so that the zone depends on the poses
 * alone. A zone does not fill that grid: it finds the assembly's points near the moving piece in an
 * index made once per fit (reduce_cloud_grid), and the moving voxels near the assembly brick by
 * brick, and works on the cells within its reach of those (zone_at).
 *
 * The index: the assembly's points sorted by their cell (by row, a row the cells along x at one y
 * and z, then along the row) on a fixed grid around them (the box of the points grown by
 * GRID_MARGIN cells), and which blocks of GRID_BLOCK cells a side hold a point, as a summed-volume
 * table. */
#define GRID_MARGIN 2
#define GRID_BLOCK 4
struct reduce_cloud_grid {
    double lo[3];
    int dim[3];
    uint32_t *row;  /* per row (y + z dim[1]), its first point in p; dim[1] dim[2] + 1 */
    float *p;       /* the points, cell by cell */
    uint16_t *x;    /* and each one's cell along its row */
    int bdim[3];    /* blocks along each axis */
    uint32_t *bsat; /* the blocks that hold a point, summed over [0, b) (bdim + 1 a side) */
};

static void grid_free(reduce_cloud_grid *g)
{
    if (g) {
        free(g->row);
        free(g->p);
        free(g->x);
        free(g->bsat);
        free(g);
    }
}

int reduce__cloud_new(reduce_cloud *c, const frag *const *asm_, int nasm)
{
    *c = (reduce_cloud){.lo = {INFINITY, INFINITY, INFINITY}, .hi = {-INFINITY, -INFINITY, -INFINITY}};
    int rc = 0;
    for (int f = 0; f < nasm && rc == 0; f++)
        rc = cloud_add(c, asm_[f]);
    if (rc == 0)
        box_add(c->p, c->n, c->lo, c->hi);
    return rc;
}

void reduce__cloud_free(reduce_cloud *c)
{
    free(c->p);
    grid_free(c->grid);
    *c = (reduce_cloud){0};
}

/* The index's cell of world point x along axis a (clamped). */
static int index_cell(const reduce_cloud_grid *ag, double x, int a)
{
    double c = floor((x - ag->lo[a]) / reduce__tune.zone_cell_mm); /* clamped before it is an int */
    return c < 0 ? 0 : c >= ag->dim[a] ? ag->dim[a] - 1 : (int)c;
}

int reduce__cloud_grid(reduce_cloud *A)
{
    if (A->grid)
        return 0;
    if (!A->n)
        return fn_err_set(FN_EINVAL, "reduce: a fragment has no voxel");
    const double cs = reduce__tune.zone_cell_mm;
    reduce_cloud_grid *ag = calloc(1, sizeof *ag);
    if (!ag)
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for the contact grid");
    size_t nb = 1;
    for (int a = 0; a < 3; a++) {
        ag->lo[a] = A->lo[a] - GRID_MARGIN * cs;
        ag->dim[a] = (int)((A->hi[a] - A->lo[a]) / cs) + 1 + 2 * GRID_MARGIN;
        ag->bdim[a] = (ag->dim[a] + GRID_BLOCK - 1) / GRID_BLOCK;
        nb *= (size_t)ag->bdim[a] + 1;
    }
    size_t rows = (size_t)ag->dim[1] * ag->dim[2], nx = (size_t)ag->dim[0];
    /* sorted by x, then (stable) by row: by cell */
    uint32_t *row = malloc((A->n + 1) * sizeof *row), *byx = malloc((A->n + 1) * sizeof *byx);
    uint16_t *xs = malloc((A->n + 1) * sizeof *xs);
    uint32_t *next = calloc((rows > nx ? rows : nx) + 1, sizeof *next);
    ag->row = calloc(rows + 1, sizeof *ag->row);
    ag->p = malloc((A->n + 1) * 3 * sizeof *ag->p);
    ag->x = malloc((A->n + 1) * sizeof *ag->x);
    ag->bsat = calloc(nb, sizeof *ag->bsat);
    if (!row || !byx || !xs || !next || !ag->row || !ag->p || !ag->x || !ag->bsat || ag->dim[0] > 65535) {
        free(row), free(byx), free(xs), free(next);
        grid_free(ag);
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for the contact grid (%zu points)", A->n);
    }
    const size_t sy = (size_t)ag->bdim[0] + 1, sz = sy * ((size_t)ag->bdim[1] + 1);
    for (size_t i = 0; i < A->n; i++) {
        int c[3];
        for (int a = 0; a < 3; a++)
            c[a] = index_cell(ag, A->p[3 * i + a], a);
        row[i] = (uint32_t)((size_t)c[2] * ag->dim[1] + c[1]);
        xs[i] = (uint16_t)c[0];
        next[c[0] + 1]++;
        ag->row[row[i] + 1]++;
        size_t blk = (size_t)(c[2] / GRID_BLOCK + 1) * sz + (size_t)(c[1] / GRID_BLOCK + 1) * sy;
        ag->bsat[blk + (size_t)(c[0] / GRID_BLOCK) + 1] = 1;
    }
    for (size_t x = 0; x < nx; x++)
        next[x + 1] += next[x];
    for (size_t i = 0; i < A->n; i++)
        byx[next[xs[i]]++] = (uint32_t)i;
    for (size_t r = 0; r < rows; r++)
        ag->row[r + 1] += ag->row[r];
    memcpy(next, ag->row, rows * sizeof *next);
    for (size_t q = 0; q < A->n; q++) {
        uint32_t i = byx[q], at = next[row[i]]++;
        memcpy(ag->p + 3 * (size_t)at, A->p + 3 * (size_t)i, 3 * sizeof *ag->p);
        ag->x[at] = xs[i];
    }
    free(row), free(byx), free(xs), free(next);
    reduce__sat_sum(ag->bsat, ag->bdim);
    A->grid = ag;
    return 0;
}

/* Blocks of the index holding a point among those that the world box [w0, w1] touches. */
static uint32_t index_points_near(const reduce_cloud_grid *ag, const double w0[3], const double w1[3])
{
    int lo[3], hi[3];
    for (int a = 0; a < 3; a++) {
        lo[a] = index_cell(ag, w0[a], a) / GRID_BLOCK;
        hi[a] = index_cell(ag, w1[a], a) / GRID_BLOCK;
    }
    return reduce__sat_count(ag->bsat, ag->bdim, lo, hi);
}

/* One contact zone's work: the moving piece (its bricks) at its pose, the grid's corner, and the
 * cells, points and flags of one delta (zone_at). */
typedef struct zone {
    const reduce_cloud *A;  /* the assembly's bone (borrowed; its index made) */
    const reduce_bricks *b; /* the moving fragment's (borrowed, or own) */
    reduce_bricks *own;
    pose w;                 /* the moving crop's mm -> world */
    float (*bw)[4];         /* per brick: its centre (world) and a radius that holds its voxels */
    double lo[3];           /* the grid's corner */
    float *mp;              /* the moving voxels a zone carries, world; nm of them */
    size_t nm, capm;
    int (*mc)[3];           /* their cells */
    uint8_t *mnear;         /* 1 where near the assembly at the delta tried */
    uint32_t *ai;           /* the assembly's points in the zone's cells (in its index), na of them */
    size_t na, capa;
    uint32_t *ac;           /* and their cells there */
    uint8_t *occ, *dil, *tmp; /* the zone's cells (zone_at), cap of them */
    size_t cap;
} zone;

static void zone_free(zone *g)
{
    reduce__bricks_free(g->own);
    free(g->bw);
    free(g->mp);
    free(g->mc);
    free(g->mnear);
    free(g->ai);
    free(g->ac);
    free(g->occ);
    free(g->dil);
    free(g->tmp);
}

/* The grid's cell of a point, as (int)((x - lo) / cell): the grid's corner lies a cell below every
 * point, so the cell is positive. */
static void cell_of(const zone *g, const float *x, int c[3])
{
    for (int a = 0; a < 3; a++)
        c[a] = (int)((x[a] - g->lo[a]) / reduce__tune.zone_cell_mm);
}

/* Grows *cap (and the arrays of n elements of size each in arr) to hold need. 0 or FN_ENOMEM. */
static int grow(void **arr[], const size_t size[], int n, size_t *cap, size_t need)
{
    if (need <= *cap)
        return 0;
    size_t nc = need + need / 2 + 1024;
    for (int i = 0; i < n; i++) {
        void *q = realloc(*arr[i], nc * size[i]);
        if (!q)
            return fn_err_set(FN_ENOMEM, "reduce: out of memory for the contact zone (%zu points)", need);
        *arr[i] = q;
    }
    *cap = nc;
    return 0;
}

/* The moving voxels of brick bi at the pose appended to g->mp (room made). 0 or FN_ENOMEM. */
static int carry_brick(zone *g, int bi)
{
    const reduce_bricks *b = g->b;
    const reduce_brick *br = &b->brick[bi];
    size_t n = 0;
    for (int q = br->first; q < br->first + br->n; q++)
        n += b->run[q].len;
    void **arr[] = {(void **)&g->mp, (void **)&g->mc, (void **)&g->mnear};
    const size_t size[] = {3 * sizeof *g->mp, sizeof *g->mc, 1};
    if (grow(arr, size, 3, &g->capm, g->nm + n) < 0)
        return FN_ENOMEM;
    for (int q = br->first; q < br->first + br->n; q++) {
        const reduce_run *run = &b->run[q];
        for (int i = run->i0; i < run->i0 + run->len; i++, g->nm++) {
            double l[3] = {i * b->spacing[0], run->j * b->spacing[1], run->k * b->spacing[2]}, x[3];
            pose_apply(&g->w, l, x);
            for (int a = 0; a < 3; a++)
                g->mp[3 * g->nm + a] = (float)x[a];
        }
    }
    return 0;
}

/* The moving piece's bricks at its pose, and the grid's corner: a cell below the lower corner of
 * the assembly's points and of every moving voxel (those of the bricks that may reach below the
 * assembly's corner are carried to find it). b: the moving fragment's bricks, or NULL (made
 * here). 0 or FN_E* (free g either way). */
static int zone_open(zone *g, reduce_cloud *A, const frag *moving, const reduce_bricks *b)
{
    g->A = A;
    if (!b && !(b = g->own = reduce__bricks_new(moving)))
        return FN_ENOMEM;
    g->b = b;
    if (!A->n || !b->voxels)
        return fn_err_set(FN_EINVAL, "reduce: a fragment has no voxel");
    int rc = reduce__cloud_grid(A);
    if (rc)
        return rc;
    g->w = pose_compose(moving->pose, moving->home);
    if (!(g->bw = malloc(((size_t)b->nbrick + 1) * sizeof *g->bw)))
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for the moving piece's bricks");
    double lo[3] = {A->lo[0], A->lo[1], A->lo[2]}, hi[3];
    for (int bi = 0; bi < b->nbrick && rc == 0; bi++) {
        const reduce_brick *br = &b->brick[bi];
        double l[3] = {br->c[0] * b->spacing[0], br->c[1] * b->spacing[1], br->c[2] * b->spacing[2]}, x[3];
        pose_apply(&g->w, l, x);
        for (int a = 0; a < 3; a++)
            g->bw[bi][a] = (float)x[a];
        g->bw[bi][3] = br->r_mm + 0.01f; /* and the float rounding of both */
        int low = 0;
        for (int a = 0; a < 3; a++)
            low |= x[a] - g->bw[bi][3] < A->lo[a];
        if (low) { /* its voxels, for the corner */
            g->nm = 0;
            rc = carry_brick(g, bi);
            box_add(g->mp, g->nm, lo, hi);
        }
    }
    g->nm = 0;
    for (int a = 0; a < 3; a++)
        g->lo[a] = lo[a] - reduce__tune.zone_cell_mm;
    return rc;
}

/* The zone's moving voxels at k cells (g->mp and their cells g->mc): those of every brick that
 * comes, within (k + 1) cells, near a block of the index that holds assembly bone (a voxel nearer
 * than k cells on the grid lies within that of a point). 0 or FN_ENOMEM. */
static int zone_moving(zone *g, int k)
{
    const double reach = (k + 1) * reduce__tune.zone_cell_mm;
    g->nm = 0;
    for (int bi = 0; bi < g->b->nbrick; bi++) {
        double w0[3], w1[3];
        for (int a = 0; a < 3; a++) {
            w0[a] = g->bw[bi][a] - g->bw[bi][3] - reach;
            w1[a] = g->bw[bi][a] + g->bw[bi][3] + reach;
        }
        size_t n0 = g->nm;
        if (index_points_near(g->A->grid, w0, w1) && carry_brick(g, bi) < 0)
            return FN_ENOMEM;
        for (size_t i = n0; i < g->nm; i++)
            cell_of(g, g->mp + 3 * i, g->mc[i]);
    }
    return 0;
}

/* The assembly's points in the cells r0 .. r0 + rd - 1 (g->ai, their cells g->ac), from the rows of
 * the index that those cells touch, and their occupancy over those cells (g->occ). 0 or FN_ENOMEM. */
static int zone_assembly(zone *g, const int r0[3], const int rd[3])
{
    const reduce_cloud_grid *ag = g->A->grid;
    const double cs = reduce__tune.zone_cell_mm;
    int i0[3], i1[3];
    for (int a = 0; a < 3; a++) { /* the index's cells the zone's cells touch, a cell more each way */
        i0[a] = index_cell(ag, g->lo[a] + r0[a] * cs, a) - 1;
        i1[a] = index_cell(ag, g->lo[a] + (r0[a] + rd[a]) * cs, a) + 1;
        i0[a] = i0[a] < 0 ? 0 : i0[a];
        i1[a] = i1[a] >= ag->dim[a] ? ag->dim[a] - 1 : i1[a];
    }
    memset(g->occ, 0, (size_t)rd[0] * rd[1] * rd[2]);
    g->na = 0;
    for (int z = i0[2]; z <= i1[2]; z++)
        for (int y = i0[1]; y <= i1[1]; y++) {
            size_t row = (size_t)z * ag->dim[1] + y;
            uint32_t p0 = ag->row[row], p1 = ag->row[row + 1];
            while (p0 < p1 && ag->x[p0] < i0[0]) /* the row's points from cell i0[0] to i1[0] */
                p0++;
            while (p1 > p0 && ag->x[p1 - 1] > i1[0])
                p1--;
            void **arr[] = {(void **)&g->ai, (void **)&g->ac};
            const size_t size[] = {sizeof *g->ai, sizeof *g->ac};
            if (grow(arr, size, 2, &g->capa, g->na + (p1 - p0)) < 0)
                return FN_ENOMEM;
            for (uint32_t i = p0; i < p1; i++) {
                int c[3], in = 1;
                cell_of(g, ag->p + 3 * (size_t)i, c);
                for (int a = 0; a < 3; a++) {
                    c[a] -= r0[a];
                    in = in && c[a] >= 0 && c[a] < rd[a];
                }
                if (!in)
                    continue;
                uint32_t at = (uint32_t)(((size_t)c[2] * rd[1] + c[1]) * rd[0] + c[0]);
                g->occ[at] = 1;
                g->ai[g->na] = i;
                g->ac[g->na++] = at;
            }
        }
    return 0;
}

/* The centre of a capped VOI, times the count near_m: the contact voxel nearest the contact's
 * centroid sum / near_m (the centroid of a curved contact line can lie in empty space). */
static void contact_centre(const zone *g, double sum[3], size_t near_m)
{
    double cen[3] = {sum[0] / (double)near_m, sum[1] / (double)near_m, sum[2] / (double)near_m}, dbest = INFINITY;
    const float *pick = NULL;
    for (size_t i = 0; i < g->nm; i++) {
        const float *q = g->mp + 3 * i;
        double d2 = (q[0] - cen[0]) * (q[0] - cen[0]) + (q[1] - cen[1]) * (q[1] - cen[1]) + (q[2] - cen[2]) * (q[2] - cen[2]);
        if (d2 < dbest && g->mnear[i]) {
            dbest = d2;
            pick = q;
        }
    }
    for (int a = 0; a < 3; a++)
        sum[a] = pick ? pick[a] * (double)near_m : sum[a];
}

/* The zone at one delta: the box of either side's points within delta of the other's bone (k
 * cells on the grid, a box), grown by margin_mm and capped at max_mm around the contact; *near_m:
 * the moving side's count of such points (0: none, and voi unchanged). Both sides are taken on the
 * cells within k of the moving voxels near the assembly (r0, rd) alone: a moving voxel's dilated
 * assembly reads no cell beyond them, and the dilated moving side is empty beyond them. 0 or
 * FN_ENOMEM. */
static int zone_at(zone *g, double delta, double margin_mm, double max_mm, reduce_voi *voi, size_t *near_m)
{
    int k = (int)ceil(delta / reduce__tune.zone_cell_mm), r0[3], rd[3];
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    double sum[3] = {0, 0, 0};
    *near_m = 0;
    int rc = zone_moving(g, k);
    if (rc || !g->nm)
        return rc;
    int m0[3] = {INT32_MAX, INT32_MAX, INT32_MAX}, m1[3] = {0, 0, 0};
    for (size_t i = 0; i < g->nm; i++)
        for (int a = 0; a < 3; a++) {
            m0[a] = g->mc[i][a] < m0[a] ? g->mc[i][a] : m0[a];
            m1[a] = g->mc[i][a] > m1[a] ? g->mc[i][a] : m1[a];
        }
    size_t n = 1;
    for (int a = 0; a < 3; a++) {
        r0[a] = m0[a] - k > 0 ? m0[a] - k : 0;
        rd[a] = m1[a] + k + 1 - r0[a];
        n *= (size_t)rd[a];
    }
    if (n > g->cap) {
        free(g->occ), free(g->dil), free(g->tmp);
        g->occ = malloc(n), g->dil = malloc(n), g->tmp = malloc(n);
        g->cap = g->occ && g->dil && g->tmp ? n : 0;
        if (!g->cap)
            return fn_err_set(FN_ENOMEM, "reduce: out of memory for the contact zone (%zu cells)", n);
    }
    /* the moving side: its voxels near the assembly's bone */
    if ((rc = zone_assembly(g, r0, rd)) != 0)
        return rc;
    reduce__dilate_box(g->occ, g->dil, g->tmp, rd, (int[3]){k, k, k});
    for (size_t i = 0; i < g->nm; i++) {
        const int *c = g->mc[i];
        uint8_t near = g->mnear[i] = g->dil[((size_t)(c[2] - r0[2]) * rd[1] + (size_t)(c[1] - r0[1])) * rd[0] +
                                             (size_t)(c[0] - r0[0])];
        if (!near)
            continue;
        ++*near_m;
        for (int a = 0; a < 3; a++)
            sum[a] += g->mp[3 * i + a];
        box_add(g->mp + 3 * i, 1, lo, hi);
    }
    if (!*near_m)
        return 0; /* nothing near: the zone is not made */
    /* the assembly's side: its points near the moving bone */
    memset(g->occ, 0, n);
    for (size_t i = 0; i < g->nm; i++) {
        const int *c = g->mc[i];
        g->occ[((size_t)(c[2] - r0[2]) * rd[1] + (size_t)(c[1] - r0[1])) * rd[0] + (size_t)(c[0] - r0[0])] = 1;
    }
    reduce__dilate_box(g->occ, g->dil, g->tmp, rd, (int[3]){k, k, k});
    for (size_t i = 0; i < g->na; i++)
        if (g->dil[g->ac[i]])
            box_add(g->A->grid->p + 3 * (size_t)g->ai[i], 1, lo, hi);
    contact_centre(g, sum, *near_m);
    for (int a = 0; a < 3; a++) {
        voi->lo[a] = lo[a] - margin_mm;
        voi->hi[a] = hi[a] + margin_mm;
        if (max_mm > 0 && voi->hi[a] - voi->lo[a] > max_mm) { /* centred on the contact */
            double c = sum[a] / (double)*near_m;
            c = fmin(fmax(c, voi->lo[a] + 0.5 * max_mm), voi->hi[a] - 0.5 * max_mm);
            voi->lo[a] = c - 0.5 * max_mm;
            voi->hi[a] = c + 0.5 * max_mm;
        }
    }
    return 0;
}

int reduce_auto_voi(const frag *const *asm_, int nasm, const frag *moving, double delta_mm, double margin_mm,
                    double max_mm, reduce_voi *voi, double *contact_ml)
{
    reduce_cloud A;
    int rc = reduce__cloud_new(&A, asm_, nasm);
    if (rc == 0)
        rc = reduce__zone_voi(&A, moving, NULL, delta_mm, margin_mm, max_mm, voi, contact_ml);
    reduce__cloud_free(&A);
    return rc;
}

int reduce__zone_voi(reduce_cloud *A, const frag *moving, const reduce_bricks *b, double delta_mm, double margin_mm,
                     double max_mm, reduce_voi *voi, double *contact_ml)
{
    zone g = {0};
    int rc = zone_open(&g, A, moving, b), found = 0;
    for (double delta = delta_mm; rc == 0 && !found && delta <= reduce__tune.zone_reach_mm; delta *= 2) {
        size_t near_m;
        rc = zone_at(&g, delta, margin_mm, max_mm, voi, &near_m);
        found = rc == 0 && near_m > 0;
        if (found && contact_ml)
            *contact_ml = (double)near_m * moving->spacing[0] * moving->spacing[1] * moving->spacing[2] / 1000;
    }
    if (rc == 0 && !found)
        rc = fn_err_set(FN_EINVAL, "reduce: fragment %d comes nowhere near the fixed ones (%g mm)", moving->id,
                        reduce__tune.zone_reach_mm);
    zone_free(&g);
    return rc;
}

int reduce__touches(const frag *const *others, int n, const frag *moving, double mm)
{
    reduce_cloud A;
    zone g = {0};
    int rc = reduce__cloud_new(&A, others, n);
    if (rc == 0)
        rc = zone_open(&g, &A, moving, NULL);
    if (rc == 0) {
        size_t near_m;
        reduce_voi v;
        rc = zone_at(&g, mm, 0, 0, &v, &near_m);
        rc = rc ? rc : near_m > 0;
    }
    zone_free(&g);
    reduce__cloud_free(&A);
    return rc;
}
