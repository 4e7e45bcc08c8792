/* reduce_voi: the automatic VOI, the contact zone of a moving fragment with the assembly (see
 * reduce_auto_voi in reduce.h), on a coarse occupancy grid of both sides' bone. */
#include "reduce.h"
#include "reduce_impl.h"

#include "err.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

static int cloud_add(reduce_cloud *c, const frag *f)
{
    float *p = realloc(c->p, (c->n + f->voxels + 1) * 3 * sizeof *p);
    if (!p)
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for fragment %d's voxels", f->id);
    c->p = p;
    pose w = pose_compose(f->pose, f->home);
    size_t idx = 0, cap = c->n + f->voxels;
    for (int k = 0; k < f->dim[2]; k++)
        for (int j = 0; j < f->dim[1]; j++)
            for (int i = 0; i < f->dim[0]; i++, idx++) {
                if (!f->prob[idx] || c->n >= cap)
                    continue;
                double l[3] = {i * f->spacing[0], j * f->spacing[1], k * f->spacing[2]}, x[3];
                pose_apply(&w, l, x);
                for (int a = 0; a < 3; a++)
                    c->p[3 * c->n + a] = (float)x[a];
                c->n++;
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

/* The assembly's points on the last contact grid: a fit makes many zones, and while the moving
 * piece lies above the assembly's lower corner the grid's corner is the same each time. The grid is
 * made GRID_SLACK cells longer on each axis than that zone needed, and a later zone with that corner
 * that fits in it takes it as it is: the cells beyond the points are empty, so the zone is the same
 * bit for bit. */
#define GRID_SLACK 16
struct reduce_cloud_grid {
    double lo[3];
    int dim[3];
    uint32_t *cell; /* each point's cell */
    uint8_t *occ;   /* 1 where a point lies */
};

static void grid_free(reduce_cloud_grid *g)
{
    if (g) {
        free(g->cell);
        free(g->occ);
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

void reduce__cloud_grid_free(reduce_cloud *c)
{
    grid_free(c->grid);
    c->grid = NULL;
}

void reduce__cloud_free(reduce_cloud *c)
{
    free(c->p);
    grid_free(c->grid);
    *c = (reduce_cloud){0};
}

/* The two sides and their occupancy on a grid of zone_cell_mm cells. */
typedef struct zone {
    const reduce_cloud *A; /* the assembly's bone (borrowed) */
    reduce_cloud M;        /* the moving fragment's */
    const uint32_t *cell_a; /* each point's cell (A's: A->grid's) */
    uint32_t *cell_m;
    double lo[3];
    int dim[3];
    const uint8_t *occa; /* A->grid's */
    uint8_t *occm, *dil, *tmp;
    uint8_t *mnear;   /* per moving point: 1 when near the assembly at the delta tried */
} zone;

static size_t cell_of(const zone *g, const float *x)
{
    int c[3];
    for (int a = 0; a < 3; a++) {
        c[a] = (int)((x[a] - g->lo[a]) / reduce__tune.zone_cell_mm);
        c[a] = c[a] < 0 ? 0 : c[a] >= g->dim[a] ? g->dim[a] - 1 : c[a];
    }
    return ((size_t)c[2] * g->dim[1] + c[1]) * g->dim[0] + c[0];
}

static void zone_free(zone *g)
{
    free(g->M.p);
    free(g->cell_m);
    free(g->occm);
    free(g->dil);
    free(g->tmp);
    free(g->mnear);
}

/* The moving side's points and the grid around both sides, a cell beyond the points. 0 or FN_E*
 * (free g either way). */
static int zone_open(zone *g, reduce_cloud *A, const frag *moving)
{
    const double cell = reduce__tune.zone_cell_mm;
    g->A = A;
    int rc = cloud_add(&g->M, moving);
    if (rc == 0 && (!A->n || !g->M.n))
        rc = fn_err_set(FN_EINVAL, "reduce: a fragment has no voxel");
    if (rc)
        return rc;
    double lo[3] = {A->lo[0], A->lo[1], A->lo[2]}, hi[3] = {A->hi[0], A->hi[1], A->hi[2]};
    box_add(g->M.p, g->M.n, lo, hi);
    size_t n = 1;
    int same = A->grid != NULL;
    for (int a = 0; a < 3; a++) {
        g->lo[a] = lo[a] - cell;
        g->dim[a] = (int)((hi[a] - lo[a]) / cell) + 3;
        same = same && A->grid->lo[a] == g->lo[a] && A->grid->dim[a] >= g->dim[a];
    }
    for (int a = 0; a < 3; a++) {
        g->dim[a] = same ? A->grid->dim[a] : g->dim[a] + GRID_SLACK;
        n *= (size_t)g->dim[a];
    }
    if (n > ((size_t)1 << 28))
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for the contact grid (%zu cells)", n);
    if (!same) { /* the assembly's points on this grid, kept for the next zone */
        reduce_cloud_grid *ag = calloc(1, sizeof *ag);
        if (ag) {
            ag->occ = calloc(n, 1);
            ag->cell = malloc(A->n * sizeof *ag->cell);
        }
        if (!ag || !ag->occ || !ag->cell) {
            grid_free(ag);
            return fn_err_set(FN_ENOMEM, "reduce: out of memory for the contact grid (%zu cells)", n);
        }
        memcpy(ag->lo, g->lo, sizeof ag->lo);
        memcpy(ag->dim, g->dim, sizeof ag->dim);
        for (size_t i = 0; i < A->n; i++)
            ag->occ[ag->cell[i] = (uint32_t)cell_of(g, A->p + 3 * i)] = 1;
        grid_free(A->grid);
        A->grid = ag;
    }
    g->occa = A->grid->occ;
    g->cell_a = A->grid->cell;
    g->occm = calloc(n, 1), g->dil = malloc(n), g->tmp = malloc(n);
    g->mnear = malloc(g->M.n);
    g->cell_m = malloc(g->M.n * sizeof *g->cell_m);
    if (!g->occm || !g->dil || !g->tmp || !g->mnear || !g->cell_m)
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for the contact grid (%zu cells)", n);
    for (size_t i = 0; i < g->M.n; i++)
        g->occm[g->cell_m[i] = (uint32_t)cell_of(g, g->M.p + 3 * i)] = 1;
    return 0;
}

/* The centre of a capped VOI, times the count near_m: the contact voxel nearest the contact's
 * centroid sum / near_m (the centroid of a curved contact line can lie in empty space). */
static void contact_centre(const zone *g, double sum[3], size_t near_m)
{
    double cen[3] = {sum[0] / (double)near_m, sum[1] / (double)near_m, sum[2] / (double)near_m}, dbest = INFINITY;
    const float *pick = NULL;
    for (size_t i = 0; i < g->M.n; i++) {
        const float *q = g->M.p + 3 * i;
        double d2 = (q[0] - cen[0]) * (q[0] - cen[0]) + (q[1] - cen[1]) * (q[1] - cen[1]) + (q[2] - cen[2]) * (q[2] - cen[2]);
        if (d2 < dbest && g->mnear[i]) {
            dbest = d2;
            pick = q;
        }
    }
    for (int a = 0; a < 3; a++)
        sum[a] = pick ? pick[a] * (double)near_m : sum[a];
}

/* The zone at one delta: the box of either side's points within delta of the other's bone, grown
 * by margin_mm and capped at max_mm around the contact; *near_m: the moving side's count of such
 * points (0: none, and voi unchanged). */
static void zone_at(zone *g, double delta, double margin_mm, double max_mm, reduce_voi *voi, size_t *near_m)
{
    int k = (int)ceil(delta / reduce__tune.zone_cell_mm);
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    double sum[3] = {0, 0, 0};
    *near_m = 0;
    for (int side = 0; side < 2; side++) {
        const reduce_cloud *c = side ? g->A : &g->M;
        const uint32_t *cell = side ? g->cell_a : g->cell_m;
        if (side == 1 && !*near_m)
            return; /* nothing near: the zone is not made */
        reduce__dilate_box(side ? g->occm : g->occa, g->dil, g->tmp, g->dim, (int[3]){k, k, k});
        for (size_t i = 0; i < c->n; i++) {
            uint8_t near = g->dil[cell[i]];
            if (side == 0)
                g->mnear[i] = near;
            if (!near)
                continue;
            *near_m += side == 0;
            for (int a = 0; a < 3; a++)
                sum[a] += side == 0 ? c->p[3 * i + a] : 0;
            box_add(c->p + 3 * i, 1, lo, hi);
        }
    }
    if (!*near_m)
        return;
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
}

int reduce_auto_voi(const frag *const *asm_, int nasm, const frag *moving, double delta_mm, double margin_mm,
                    double max_mm, reduce_voi *voi, double *contact_ml)
{
    reduce_cloud A;
    int rc = reduce__cloud_new(&A, asm_, nasm);
    if (rc == 0)
        rc = reduce__zone_voi(&A, moving, delta_mm, margin_mm, max_mm, voi, contact_ml);
    reduce__cloud_free(&A);
    return rc;
}

int reduce__zone_voi(reduce_cloud *A, const frag *moving, double delta_mm, double margin_mm, double max_mm,
                     reduce_voi *voi, double *contact_ml)
{
    zone g = {0};
    int rc = zone_open(&g, A, moving);
    if (rc == 0) {
        rc = FN_EINVAL;
        for (double delta = delta_mm; delta <= reduce__tune.zone_reach_mm && rc == FN_EINVAL; delta *= 2) {
            size_t near_m;
            zone_at(&g, delta, margin_mm, max_mm, voi, &near_m);
            if (!near_m)
                continue;
            if (contact_ml)
                *contact_ml = (double)near_m * moving->spacing[0] * moving->spacing[1] * moving->spacing[2] / 1000;
            rc = 0;
        }
        if (rc)
            fn_err_set(rc, "reduce: fragment %d comes nowhere near the fixed ones (%g mm)", moving->id,
                       reduce__tune.zone_reach_mm);
    }
    zone_free(&g);
    return rc;
}

int reduce__touches(const frag *const *others, int n, const frag *moving, double mm)
{
    reduce_cloud A;
    zone g = {0};
    int rc = reduce__cloud_new(&A, others, n);
    if (rc == 0)
        rc = zone_open(&g, &A, moving);
    if (rc == 0) {
        size_t near_m;
        reduce_voi v;
        zone_at(&g, mm, 0, 0, &v, &near_m);
        rc = near_m > 0;
    }
    zone_free(&g);
    reduce__cloud_free(&A);
    return rc;
}
