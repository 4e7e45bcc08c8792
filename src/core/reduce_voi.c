/* reduce_voi: the automatic VOI, the contact zone of a moving fragment with the assembly (see
 * reduce_auto_voi in reduce.h), on a coarse occupancy grid of both sides' bone. */
#include "reduce.h"
#include "reduce_impl.h"

#include "err.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* Bone voxels as world points. */
typedef struct cloud {
    float *p; /* xyz world */
    size_t n;
} cloud;

static int cloud_add(cloud *c, const frag *f)
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

/* The two sides and their occupancy on a grid of zone_cell_mm cells. */
typedef struct zone {
    cloud A, M;       /* the assembly's bone, the moving fragment's */
    double lo[3];
    int dim[3];
    uint8_t *occa, *occm, *dil, *tmp;
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

/* out = occupancy dilated by k cells along each axis (a box), by a sliding window count per line. */
static void dilate(const zone *g, const uint8_t *in, uint8_t *out, int k)
{
    size_t n = (size_t)g->dim[0] * g->dim[1] * g->dim[2];
    memcpy(out, in, n);
    size_t stride[3] = {1, (size_t)g->dim[0], (size_t)g->dim[0] * g->dim[1]};
    for (int a = 0; a < 3; a++) {
        memcpy(g->tmp, out, n);
        int len = g->dim[a];
        for (size_t base = 0; base < n; base++) {
            /* lines start where the coordinate along a is 0 */
            if ((base / stride[a]) % (size_t)len)
                continue;
            int count = 0;
            for (int i = 0; i < k && i < len; i++)
                count += g->tmp[base + (size_t)i * stride[a]];
            for (int i = 0; i < len; i++) {
                if (i + k < len)
                    count += g->tmp[base + (size_t)(i + k) * stride[a]];
                if (i - k - 1 >= 0)
                    count -= g->tmp[base + (size_t)(i - k - 1) * stride[a]];
                out[base + (size_t)i * stride[a]] = count > 0;
            }
        }
    }
}

static void zone_free(zone *g)
{
    free(g->A.p);
    free(g->M.p);
    free(g->occa);
    free(g->occm);
    free(g->dil);
    free(g->tmp);
    free(g->mnear);
}

/* Both sides' points and the grid around them, a cell beyond the points. 0 or FN_E* (free g either
 * way). */
static int zone_open(zone *g, const frag *const *asm_, int nasm, const frag *moving)
{
    const double cell = reduce__tune.zone_cell_mm;
    int rc = 0;
    for (int f = 0; f < nasm && rc == 0; f++)
        rc = cloud_add(&g->A, asm_[f]);
    if (rc == 0)
        rc = cloud_add(&g->M, moving);
    if (rc == 0 && (!g->A.n || !g->M.n))
        rc = fn_err_set(FN_EINVAL, "reduce: a fragment has no voxel");
    if (rc)
        return rc;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    const cloud *cs[2] = {&g->A, &g->M};
    for (int c = 0; c < 2; c++)
        for (size_t i = 0; i < cs[c]->n; i++)
            for (int a = 0; a < 3; a++) {
                lo[a] = fmin(lo[a], cs[c]->p[3 * i + a]);
                hi[a] = fmax(hi[a], cs[c]->p[3 * i + a]);
            }
    size_t n = 1;
    for (int a = 0; a < 3; a++) {
        g->lo[a] = lo[a] - cell;
        g->dim[a] = (int)((hi[a] - lo[a]) / cell) + 3;
        n *= (size_t)g->dim[a];
    }
    g->occa = calloc(n, 1), g->occm = calloc(n, 1), g->dil = malloc(n), g->tmp = malloc(n);
    g->mnear = malloc(g->M.n);
    if (n > ((size_t)1 << 28) || !g->occa || !g->occm || !g->dil || !g->tmp || !g->mnear)
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for the contact grid (%zu cells)", n);
    for (size_t i = 0; i < g->A.n; i++)
        g->occa[cell_of(g, g->A.p + 3 * i)] = 1;
    for (size_t i = 0; i < g->M.n; i++)
        g->occm[cell_of(g, g->M.p + 3 * i)] = 1;
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
        const cloud *c = side ? &g->A : &g->M;
        dilate(g, side ? g->occm : g->occa, g->dil, k);
        for (size_t i = 0; i < c->n; i++) {
            if (side == 0)
                g->mnear[i] = g->dil[cell_of(g, c->p + 3 * i)];
            if (!g->dil[cell_of(g, c->p + 3 * i)])
                continue;
            *near_m += side == 0;
            for (int a = 0; a < 3; a++) {
                sum[a] += side == 0 ? c->p[3 * i + a] : 0;
                lo[a] = fmin(lo[a], c->p[3 * i + a]);
                hi[a] = fmax(hi[a], c->p[3 * i + a]);
            }
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
    zone g = {0};
    int rc = zone_open(&g, asm_, nasm, moving);
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
    zone g = {0};
    int rc = zone_open(&g, others, n, moving);
    if (rc == 0) {
        size_t near_m;
        reduce_voi v;
        zone_at(&g, mm, 0, 0, &v, &near_m);
        rc = near_m > 0;
    }
    zone_free(&g);
    return rc;
}
