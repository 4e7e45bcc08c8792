/* reduce: the automatic VOI, pre-alignment, the optimizer driver, several fragments, ground-truth
 * errors and the case's "reduction" record (see reduce.h). */
#include "reduce.h"
#include "reduce_impl.h"

#include "case.h"
#include "err.h"
#include "fnclock.h"
#include "obb.h"
#include "powell.h"

#include <jansson.h>
#include <math.h>
#include <stdatomic.h>
#include <nlopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define PI 3.14159265358979323846
#define CELL_MM 2.0     /* the contact zone's coarse grid */
#define PUSH_STEP_MM 0.05
#define PUSH_MAX_MM 5.0
#define APPROACH_MM 10.0 /* the farthest a fragment slides into contact before the fit */
#define PLACED_MM 10.0  /* nearer than this to the assembly, a fragment counts as placed */
#define START_DEG 8.0   /* the first stage's extra starts: turned this much about each axis */
#define VOI_GROW 1.25      /* a contact zone this much larger (volume) than the fit's VOI: again */
#define VOI_GROW_STAGES 2  /* at most this many stages more for it */
#define HOP_ELONGATION 4.0 /* a long piece: its largest principal variance this many times the next */
#define HOP_DEG 3.0        /* a hop's turn */
#define HOP_MARGIN 1e-4    /* a hop of a piece that is not long must gain this much metric */
#define AMBIG_METRIC 0.002 /* a first-stage end this close in metric to the best is a rival */
#define MAX_STARTS_SEEN 16 /* the first stage's ends looked at for rivals */
#define COLLIDE_COST 1.0 /* more than any metric difference: the fit stays collision-free */

static const char *method_names[REDUCE_METHODS] = {"powell", "praxis", "sbplx", "bobyqa"};

const char *reduce_method_name(reduce_method m)
{
    return m >= 0 && m < REDUCE_METHODS ? method_names[m] : "?";
}

int reduce_method_parse(const char *s)
{
    for (int i = 0; s && i < REDUCE_METHODS; i++)
        if (!strcmp(s, method_names[i]))
            return i;
    return -1;
}

void reduce_defaults(reduce_opts *o)
{
    memset(o, 0, sizeof *o);
    o->method = REDUCE_PRAXIS;
    o->count = REDUCE_TRILINEAR;
    o->prealign = 1;
    o->tau_min = CASE_TAU_MIN;
    o->tau_max = CASE_TAU_MAX;
    o->tolerance_mm = 0.5;
    o->settle_mm = 0.25;
    o->xtol_mm = 0.01;
    o->max_eval = 4000;
    o->voi_max_mm = 0;
    o->band_mm = 1;
    o->trust_mm = 12;
    o->starts = 3;
    o->trust_deg = 18;
    o->coarse = 0;
    o->axis_scale = 1;
    o->hops = 3;
}

void reduce_result_free(reduce_result *r)
{
    if (r) {
        free(r->history);
        r->history = NULL;
        r->nhistory = 0;
    }
}

static double now_s(void)
{
    return (double)fnclock_now_us() * 1e-6;
}

/* ---- the contact zone ---------------------------------------------------------------------- */

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

typedef struct coarse {
    double lo[3];
    int dim[3];
    uint8_t *occ, *tmp;
} coarse;

static size_t cell_of(const coarse *g, const float *x)
{
    int c[3];
    for (int a = 0; a < 3; a++) {
        c[a] = (int)((x[a] - g->lo[a]) / CELL_MM);
        c[a] = c[a] < 0 ? 0 : c[a] >= g->dim[a] ? g->dim[a] - 1 : c[a];
    }
    return ((size_t)c[2] * g->dim[1] + c[1]) * g->dim[0] + c[0];
}

/* out = occupancy dilated by k cells along each axis (a box), by a sliding window count per line. */
static void dilate(const coarse *g, const uint8_t *in, uint8_t *out, int k)
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

int reduce_auto_voi(const frag *const *asm_, int nasm, const frag *moving, double delta_mm, double margin_mm,
                    double max_mm, reduce_voi *voi, double *contact_ml)
{
    cloud A = {0}, M = {0};
    coarse g = {0};
    uint8_t *occa = NULL, *occm = NULL, *dil = NULL, *mnear = NULL;
    int rc = 0;
    for (int f = 0; f < nasm && rc == 0; f++)
        rc = cloud_add(&A, asm_[f]);
    if (rc == 0)
        rc = cloud_add(&M, moving);
    if (rc == 0 && (!A.n || !M.n))
        rc = fn_err_set(FN_EINVAL, "reduce: a fragment has no voxel");
    if (rc == 0) {
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        const cloud *cs[2] = {&A, &M};
        for (int c = 0; c < 2; c++)
            for (size_t i = 0; i < cs[c]->n; i++)
                for (int a = 0; a < 3; a++) {
                    lo[a] = fmin(lo[a], cs[c]->p[3 * i + a]);
                    hi[a] = fmax(hi[a], cs[c]->p[3 * i + a]);
                }
        size_t n = 1;
        for (int a = 0; a < 3; a++) {
            g.lo[a] = lo[a] - CELL_MM;
            g.dim[a] = (int)((hi[a] - lo[a]) / CELL_MM) + 3;
            n *= (size_t)g.dim[a];
        }
        occa = calloc(n, 1), occm = calloc(n, 1), dil = malloc(n), g.tmp = malloc(n), mnear = malloc(M.n);
        if (n > ((size_t)1 << 28) || !occa || !occm || !dil || !g.tmp || !mnear)
            rc = fn_err_set(FN_ENOMEM, "reduce: out of memory for the contact grid (%zu cells)", n);
    }
    if (rc == 0) {
        for (size_t i = 0; i < A.n; i++)
            occa[cell_of(&g, A.p + 3 * i)] = 1;
        for (size_t i = 0; i < M.n; i++)
            occm[cell_of(&g, M.p + 3 * i)] = 1;
        rc = FN_EINVAL;
        for (double delta = delta_mm; delta <= 64 && rc == FN_EINVAL; delta *= 2) {
            int k = (int)ceil(delta / CELL_MM);
            double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
            double sum[3] = {0, 0, 0};
            size_t near_m = 0;
            for (int side = 0; side < 2; side++) {
                const cloud *c = side ? &A : &M;
                dilate(&g, side ? occm : occa, dil, k);
                for (size_t i = 0; i < c->n; i++) {
                    if (side == 0)
                        mnear[i] = dil[cell_of(&g, c->p + 3 * i)];
                    if (!dil[cell_of(&g, c->p + 3 * i)])
                        continue;
                    near_m += side == 0;
                    for (int a = 0; a < 3; a++) {
                        sum[a] += side == 0 ? c->p[3 * i + a] : 0;
                        lo[a] = fmin(lo[a], c->p[3 * i + a]);
                        hi[a] = fmax(hi[a], c->p[3 * i + a]);
                    }
                }
            }
            if (!near_m)
                continue;
            /* the centre of a capped VOI: the contact voxel nearest the contact's centroid (the
             * centroid of a curved contact line can lie in empty space) */
            double cen[3] = {sum[0] / (double)near_m, sum[1] / (double)near_m, sum[2] / (double)near_m}, dbest = INFINITY;
            const float *pick = NULL;
            for (size_t i = 0; i < M.n; i++) {
                const float *q = M.p + 3 * i;
                double d2 = (q[0] - cen[0]) * (q[0] - cen[0]) + (q[1] - cen[1]) * (q[1] - cen[1]) + (q[2] - cen[2]) * (q[2] - cen[2]);
                if (d2 < dbest && mnear[i]) {
                    dbest = d2;
                    pick = q;
                }
            }
            for (int a = 0; a < 3; a++)
                sum[a] = pick ? pick[a] * (double)near_m : sum[a];
            for (int a = 0; a < 3; a++) {
                voi->lo[a] = lo[a] - margin_mm;
                voi->hi[a] = hi[a] + margin_mm;
                if (max_mm > 0 && voi->hi[a] - voi->lo[a] > max_mm) { /* centred on the contact */
                    double c = sum[a] / (double)near_m;
                    c = fmin(fmax(c, voi->lo[a] + 0.5 * max_mm), voi->hi[a] - 0.5 * max_mm);
                    voi->lo[a] = c - 0.5 * max_mm;
                    voi->hi[a] = c + 0.5 * max_mm;
                }
            }
            if (contact_ml)
                *contact_ml = (double)near_m * moving->spacing[0] * moving->spacing[1] * moving->spacing[2] / 1000;
            rc = 0;
        }
        if (rc)
            fn_err_set(rc, "reduce: fragment %d comes nowhere near the fixed ones (64 mm)", moving->id);
    }
    free(A.p);
    free(M.p);
    free(occa);
    free(occm);
    free(dil);
    free(g.tmp);
    free(mnear);
    return rc;
}

static double voi_volume(const reduce_voi *v)
{
    return (v->hi[0] - v->lo[0]) * (v->hi[1] - v->lo[1]) * (v->hi[2] - v->lo[2]);
}

/* ---- collision ----------------------------------------------------------------------------- */

typedef struct pair_ctx {
    const frag *const *asm_;
    int nasm;
    frag *moving;
    obb_tree **trees; /* nasm + 1: the last is the moving fragment's */
    obb_query q;
    obb_cache *cache; /* nasm, for the queries of the optimizer (temporal coherence) */
} pair_ctx;

/* 1 collides, 0 free, <0 error; *sep: the smallest separation estimate over the assembly. The
 * yes or no is exact either way; a separation is asked without the caches, whose bound depends on
 * the queries before (a front answers with a looser one), so that it, and every step taken by it
 * (slide_to_contact), depends on the pose alone. */
static int collides(const pair_ctx *pc, const pose *mp, double *sep)
{
    pose mw = pose_compose(*mp, pc->moving->home);
    double s = INFINITY;
    int hit = 0;
    for (int f = 0; f < pc->nasm; f++) {
        pose aw = pose_compose(pc->asm_[f]->pose, pc->asm_[f]->home);
        obb_result r;
        obb_cache *cache = pc->cache && !sep ? &pc->cache[f] : NULL;
        int rc = obb_collide(pc->trees[f], &aw, pc->trees[pc->nasm], &mw, &pc->q, cache, &r);
        if (rc < 0)
            return rc;
        hit |= r.collides;
        s = fmin(s, r.separation_mm);
    }
    if (sep)
        *sep = s;
    return hit;
}

/* ---- pre-alignment ------------------------------------------------------------------------- */

static void axis_world(const frag *f, int col, double v[3])
{
    double a[3] = {f->axes[0][col], f->axes[1][col], f->axes[2][col]};
    pose_rotate(&f->pose, a, v);
}

static void centroid_world(const frag *f, double c[3])
{
    pose_apply(&f->pose, f->centroid, c);
}

/* The rotation taking unit a onto unit b. */
static pose rotation_onto(const double a[3], const double b[3])
{
    double ax[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    double s = sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2]), c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    if (s < 1e-12) {
        if (c > 0)
            return POSE_IDENTITY;
        double p[3] = {0, 0, 0}; /* any axis perpendicular to a */
        p[fabs(a[0]) < 0.6 ? 0 : 1] = 1;
        double d = p[0] * a[0] + p[1] * a[1] + p[2] * a[2];
        for (int i = 0; i < 3; i++)
            p[i] -= d * a[i];
        double n = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        for (int i = 0; i < 3; i++)
            p[i] /= n;
        return pose_from_axis_angle(p, PI);
    }
    for (int i = 0; i < 3; i++)
        ax[i] /= s;
    return pose_from_axis_angle(ax, atan2(s, c));
}

/* x -> rot (P(x) - c) + to: the pose P turned about point c and moved to `to`. */
static pose turned(const pose *P, const pose *rot, const double c[3], const double to[3])
{
    pose r = pose_compose(*rot, *P);
    double rc[3];
    pose_rotate(rot, c, rc);
    for (int a = 0; a < 3; a++)
        r.t[a] += to[a] - rc[a];
    return r;
}

/* The world box of a fragment's crop at its pose. */
static void world_box(const frag *f, const pose *p, double lo[3], double hi[3])
{
    pose w = pose_compose(*p, f->home);
    for (int a = 0; a < 3; a++) {
        lo[a] = INFINITY;
        hi[a] = -INFINITY;
    }
    for (int corner = 0; corner < 8; corner++) {
        double l[3], x[3];
        for (int a = 0; a < 3; a++)
            l[a] = (corner >> a & 1 ? f->dim[a] - 1 : 0) * f->spacing[a];
        pose_apply(&w, l, x);
        for (int a = 0; a < 3; a++) {
            lo[a] = fmin(lo[a], x[a]);
            hi[a] = fmax(hi[a], x[a]);
        }
    }
}

/* A candidate's score: the metric over the overlap of the two world boxes grown by 5 mm. */
static double candidate_score(const pair_ctx *pc, reduce_bricks *b, const pose *p, reduce_count mode,
                              double band, double gap)
{
    double alo[3], ahi[3], mlo[3], mhi[3];
    world_box(pc->asm_[0], &pc->asm_[0]->pose, alo, ahi);
    world_box(pc->moving, p, mlo, mhi);
    reduce_voi v;
    for (int a = 0; a < 3; a++) {
        v.lo[a] = fmax(alo[a], mlo[a]) - 5;
        v.hi[a] = fmin(ahi[a], mhi[a]) + 5;
        if (v.lo[a] >= v.hi[a])
            return INFINITY;
    }
    reduce_metric *m = reduce__metric_with(pc->asm_, pc->nasm, pc->moving, b, &v, mode, band, gap);
    if (!m)
        return INFINITY;
    double f = reduce_metric_eval(m, p, NULL);
    reduce_metric_free(m);
    return f;
}

/* Slides the candidate from far along `dir` (towards the fixed centroid) until it touches; 0 when
 * it never does (passes through empty space). Conservative advancement by the separation bound. */
static int slide_to_contact(const pair_ctx *pc, pose *p, const double dir[3], double span)
{
    double moved = 0, prev = -1, sep;
    while (moved < 2 * span) {
        pose cur = *p;
        for (int a = 0; a < 3; a++)
            cur.t[a] += moved * dir[a];
        int c = collides(pc, &cur, &sep);
        if (c < 0)
            return c;
        if (c && prev < 0)
            return 0; /* colliding from the start: no approach along this line */
        if (c) {
            double lo = prev, hi = moved; /* free at lo, colliding at hi: halve towards contact */
            for (int i = 0; i < 8; i++) {
                double mid = 0.5 * (lo + hi);
                pose t = *p;
                for (int a = 0; a < 3; a++)
                    t.t[a] += mid * dir[a];
                int cm = collides(pc, &t, NULL);
                if (cm < 0)
                    return cm;
                if (cm)
                    hi = mid;
                else
                    lo = mid;
            }
            for (int a = 0; a < 3; a++)
                p->t[a] += lo * dir[a];
            return 1;
        }
        prev = moved;
        moved += isfinite(sep) && sep > 0.1 ? sep : 0.1;
    }
    return 0;
}

static int prealign(const pair_ctx *pc, reduce_bricks *b, const reduce_opts *o, int *changed)
{
    const frag *fx = pc->asm_[0];
    frag *m = pc->moving;
    pose placed = m->pose, best = placed;
    double bestf = candidate_score(pc, b, &placed, o->count, o->band_mm, o->gap_mm);
    double af[3], am[3], cf[3], cm[3];
    axis_world(fx, 0, af);
    axis_world(m, 0, am);
    centroid_world(fx, cf);
    centroid_world(m, cm);
    double span = 2 * (sqrt(3 * fx->eigval[0]) + sqrt(3 * m->eigval[0])) + 10;
    *changed = 0;
    for (int sign = -1; sign <= 1; sign += 2) {
        double target[3] = {sign * af[0], sign * af[1], sign * af[2]};
        pose align = rotation_onto(am, target);
        for (int side = -1; side <= 1; side += 2)
            for (int step = 0; step < 12; step++) {
                pose turn = pose_from_axis_angle(af, step * PI / 6);
                pose rot = pose_compose(turn, align);
                double to[3], dir[3];
                for (int a = 0; a < 3; a++) {
                    to[a] = cf[a] + side * span * af[a];
                    dir[a] = -side * af[a];
                }
                pose cand = turned(&placed, &rot, cm, to);
                int rc = slide_to_contact(pc, &cand, dir, span);
                if (rc < 0)
                    return rc;
                if (!rc)
                    continue;
                double f = candidate_score(pc, b, &cand, o->count, o->band_mm, o->gap_mm);
                if (f < bestf) {
                    bestf = f;
                    best = cand;
                    *changed = 1;
                }
            }
    }
    m->pose = best;
    return 0;
}

/* ---- the fit ------------------------------------------------------------------------------- */

typedef struct fit {
    const reduce_metric *metric;
    pose start;
    double c[3];     /* rotation centre, world */
    double raxis[3][3]; /* the rotation parameters' axes (columns, world) */
    double ra[3];       /* and their scales, mm per radian */
    int evals;
    double best;
    double bestx[6];
    int improvements;
    double *hist;
    int nhist, caphist;
    const reduce_opts *o;
    int id;
    double t0;
    const pair_ctx *pc; /* non-NULL: a colliding pose costs COLLIDE_COST more */
    double xtol;        /* this stage's convergence step */
    pose placed;        /* where the hand left it: the trust region's centre */
    double moving_centroid[3]; /* home world */
    nlopt_opt opt;      /* the NLopt run in progress, for a cancel */
    int cancelled;
} fit;

/* 1 once the caller's cancel flag is set (remembered, and an NLopt run told to stop). */
static int cancel_seen(fit *F)
{
    if (!F->cancelled && F->o->cancel && atomic_load(F->o->cancel)) {
        F->cancelled = 1;
        if (F->opt)
            nlopt_force_stop(F->opt);
    }
    return F->cancelled;
}

static pose pose_of(const fit *F, const double *x)
{
    double rv[3] = {0, 0, 0}, zero[3] = {0, 0, 0}, to[3];
    for (int a = 0; a < 3; a++)
        for (int i = 0; i < 3; i++)
            rv[i] += x[3 + a] / F->ra[a] * F->raxis[i][a];
    pose rot = pose_from_rotvec(rv, zero);
    for (int a = 0; a < 3; a++)
        to[a] = F->c[a] + x[a];
    return turned(&F->start, &rot, F->c, to);
}

/* The rotation's axes and scales: the principal axes of the moving voxels in the VOI at the start,
 * each scaled by their RMS distance from it (o->axis_scale), or the world axes all scaled by the RMS
 * distance from the centroid; 5 to 500 mm. */
static void set_scale(fit *F, const reduce_metric *m)
{
    double S[3][3], val[3];
    reduce_metric_spread(m, &F->start, F->c, S);
    double tr = S[0][0] + S[1][1] + S[2][2];
    if (F->o->axis_scale) {
        frag_eigen_sym3(S, F->raxis, val);
        for (int a = 0; a < 3; a++)
            F->ra[a] = fmin(fmax(sqrt(fmax(tr - val[a], 0)), 5), 500);
    } else
        for (int a = 0; a < 3; a++) {
            for (int i = 0; i < 3; i++)
                F->raxis[i][a] = i == a;
            F->ra[a] = fmin(fmax(sqrt(tr), 5), 500);
        }
}

static void hist_add(fit *F, double f)
{
    if (F->nhist == F->caphist) {
        int nc = F->caphist ? 2 * F->caphist : 64;
        double *h = realloc(F->hist, (size_t)nc * sizeof *h);
        if (!h)
            return; /* the history is a report: a shorter one is no failure */
        F->hist = h;
        F->caphist = nc;
    }
    F->hist[F->nhist++] = f;
}

/* A wall around the placed pose: the fit refines a placement, it does not search the skull for
 * another one (a thin bone offers many poses that fill a VOI better than the fit does). */
static double trust_cost(const fit *F, const pose *p)
{
    double a[3], b[3], d2 = 0;
    pose_apply(p, F->moving_centroid, a);
    pose_apply(&F->placed, F->moving_centroid, b);
    for (int i = 0; i < 3; i++)
        d2 += (a[i] - b[i]) * (a[i] - b[i]);
    double et = sqrt(d2) - F->o->trust_mm, er = pose_angle_between(*p, F->placed) * 180 / PI - F->o->trust_deg;
    return (et > 0 ? 1 + et : 0) + (er > 0 ? 1 + er : 0);
}

/* 1 when p lies within 1 mm or 1 degree of the trust wall. */
static int at_wall(const fit *F, const pose *p)
{
    double a[3], b[3], d2 = 0;
    pose_apply(p, F->moving_centroid, a);
    pose_apply(&F->placed, F->moving_centroid, b);
    for (int i = 0; i < 3; i++)
        d2 += (a[i] - b[i]) * (a[i] - b[i]);
    return sqrt(d2) > F->o->trust_mm - 1 || pose_angle_between(*p, F->placed) * 180 / PI > F->o->trust_deg - 1;
}

static double objective(const double *x, void *ctx)
{
    fit *F = ctx;
    if (cancel_seen(F))
        return F->best < INFINITY ? F->best + 1 : COLLIDE_COST;
    pose p = pose_of(F, x);
    double f = reduce_metric_eval(F->metric, &p, NULL);
    if (F->pc && collides(F->pc, &p, NULL) > 0)
        f += COLLIDE_COST;
    f += trust_cost(F, &p);
    F->evals++;
    if (f < F->best) {
        F->best = f;
        memcpy(F->bestx, x, sizeof F->bestx);
    }
    return f;
}

/* The objective at a pose (the start of a fit). */
static double objective_at(fit *F, const pose *p)
{
    double f = reduce_metric_eval(F->metric, p, NULL) + trust_cost(F, p);
    if (F->pc && collides(F->pc, p, NULL) > 0)
        f += COLLIDE_COST;
    return f;
}

static int powell_iter(int iter, double f, void *ctx)
{
    fit *F = ctx;
    hist_add(F, f);
    if (cancel_seen(F))
        return 1;
    if (F->o->progress)
        F->o->progress(F->o->progress_ctx, F->id, iter, F->evals, f, now_s() - F->t0);
    return 0;
}

static double nlopt_objective(unsigned n, const double *x, double *grad, void *ctx)
{
    fit *F = ctx;
    double before = F->best, f = objective(x, ctx);
    if (F->best < before) {
        F->improvements++;
        hist_add(F, F->best);
        if (F->o->progress && F->improvements % 10 == 0)
            F->o->progress(F->o->progress_ctx, F->id, F->improvements, F->evals, F->best, now_s() - F->t0);
    }
    return f;
}

static int run_optimizer(fit *F, int *iterations)
{
    const reduce_opts *o = F->o;
    double x[6] = {0, 0, 0, 0, 0, 0};
    if (o->method == REDUCE_POWELL) {
        /* Restarts with fresh directions and other steps: the voxel metric has small ripples
         * that can hold a line search; a restart that gains nothing ends it. */
        static const double steps[] = {1, 3, 0.3};
        *iterations = 0;
        double fprev = INFINITY;
        for (int k = 0; k < 3; k++) {
            powell_opts po;
            powell_defaults(&po);
            po.step = steps[k];
            po.xtol = F->xtol;
            po.line_tol = F->xtol;
            po.ftol = 1e-9;
            po.max_eval = o->max_eval - F->evals;
            po.on_iter = powell_iter;
            po.iter_ctx = F;
            if (po.max_eval < 10)
                break;
            powell_stats st;
            int rc = powell_minimize(objective, F, x, 6, &po, &st);
            *iterations += st.iterations;
            if (rc)
                return rc;
            if (!(st.f < fprev - 1e-7) || F->cancelled)
                break;
            fprev = st.f;
        }
        return 0;
    }
    static const nlopt_algorithm alg[REDUCE_METHODS] = {NLOPT_LN_PRAXIS, NLOPT_LN_PRAXIS, NLOPT_LN_SBPLX,
                                                        NLOPT_LN_BOBYQA};
    nlopt_opt opt = nlopt_create(alg[o->method], 6);
    if (!opt)
        return fn_err_set(FN_ENOMEM, "reduce: NLopt could not make its optimizer");
    nlopt_set_min_objective(opt, nlopt_objective, F);
    nlopt_set_xtol_abs1(opt, F->xtol);
    nlopt_set_maxeval(opt, o->max_eval - F->evals > 10 ? o->max_eval - F->evals : 10);
    nlopt_set_initial_step1(opt, 2);
    if (o->method != REDUCE_PRAXIS) { /* PRAXIS takes no bounds */
        nlopt_set_lower_bounds1(opt, -40);
        nlopt_set_upper_bounds1(opt, 40);
    }
    double f;
    nlopt_srand(1); /* PRAXIS draws random numbers: the same case gives the same fit */
    F->opt = opt;
    nlopt_result res = nlopt_optimize(opt, x, &f);
    F->opt = NULL;
    nlopt_destroy(opt);
    if (res == NLOPT_FORCED_STOP && F->cancelled)
        res = NLOPT_SUCCESS;
    *iterations = F->improvements;
    if (res < 0 && res != NLOPT_ROUNDOFF_LIMITED)
        return fn_err_set(FN_EINVAL, "reduce: NLopt %s failed (code %d)", method_names[o->method], (int)res);
    return 0;
}

/* Pushes a colliding pose out by the smallest step (PUSH_STEP_MM up to PUSH_MAX_MM) along the
 * contact normal (from the assembly's bone in the VOI to the moving centroid) or a world axis.
 * 1 when *p is (now) free, 0 when no push frees it (*p unchanged), <0 on error. */
static int push_out(const pair_ctx *pc, const reduce_metric *m, double max_mm, pose *p, double *pushed)
{
    int c = collides(pc, p, NULL);
    if (c <= 0)
        return c < 0 ? c : 1;
    double cm[3], dir[7][3] = {{0}}, len = 0;
    pose_apply(p, pc->moving->centroid, cm);
    for (int a = 0; a < 3; a++) {
        dir[0][a] = cm[a] - m->fixed_centre[a];
        len += dir[0][a] * dir[0][a];
    }
    len = sqrt(len);
    for (int a = 0; a < 3; a++) {
        dir[0][a] = len > 0 ? dir[0][a] / len : 0;
        dir[1 + 2 * a][a] = 1;
        dir[2 + 2 * a][a] = -1;
    }
    for (double s = PUSH_STEP_MM; s <= max_mm + 1e-9; s += PUSH_STEP_MM)
        for (int d = len > 0 ? 0 : 1; d < 7; d++) {
            pose t = *p;
            for (int a = 0; a < 3; a++)
                t.t[a] += s * dir[d][a];
            if ((c = collides(pc, &t, NULL)) < 0)
                return c;
            if (!c) {
                *p = t;
                *pushed += s;
                return 1;
            }
        }
    return 0;
}

/* A result that collides is pushed out; failing that, the start (where the hand left it) stays.
 * A free one is then settled: pushed out up to settle_mm more until it is free at tolerance 0
 * (the loop's), and left where it is when that is not enough. */
static int resolve_collision(const pair_ctx *pc, const reduce_metric *m, double settle_mm, reduce_result *r)
{
    int c = push_out(pc, m, PUSH_MAX_MM, &r->end, &r->push_mm);
    if (c > 0 && settle_mm > 0 && pc->q.tolerance_mm > 0) {
        pair_ctx exact = *pc;
        exact.q.tolerance_mm = 0;
        exact.cache = NULL;
        c = push_out(&exact, m, settle_mm, &r->end, &r->push_mm);
        return c < 0 ? c : 0;
    }
    if (c != 0)
        return c < 0 ? c : 0;
    if ((c = collides(pc, &r->start, NULL)) < 0)
        return c;
    r->end = r->start;
    r->collides = c;
    return 0;
}

/* ---- the coarse level ---------------------------------------------------------------------- */

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

static void free_trees(obb_tree **t, int n)
{
    for (int i = 0; t && i < n; i++)
        obb_tree_free(t[i]);
    free(t);
}

double reduce_tolerance(const reduce_opts *o, const frag *const *f, int n)
{
    double smin = INFINITY;
    for (int i = 0; i < n; i++)
        for (int a = 0; a < 3; a++)
            smin = fmin(smin, f[i]->spacing[a]);
    return fmin(o->tolerance_mm, 0.45 * smin);
}

int reduce_pair(const frag *const *asm_, int nasm, frag *moving, const reduce_opts *o, reduce_result *r)
{
    if (!asm_ || nasm < 1 || !moving || !o || !r)
        return fn_err_set(FN_EINVAL, "reduce: no fragments");
    double t0 = now_s();
    memset(r, 0, sizeof *r);
    r->id = moving->id;
    r->placed = moving->pose;
    obb_params op = {o->tau_min, o->tau_max};
    const frag *mv = moving;
    double tol = fmin(reduce_tolerance(o, asm_, nasm), reduce_tolerance(o, &mv, 1));
    pair_ctx pc = {asm_, nasm, moving, calloc((size_t)nasm + 1, sizeof(obb_tree *)),
                   {.threshold = 0, .tolerance_mm = tol}, NULL};
    reduce_bricks *b = reduce__bricks_new(moving);
    reduce_metric *m = NULL;
    fit F = {0};
    frag *cf = NULL; /* the coarse level: nasm assembly fragments, then the moving one */
    const frag **cfp = NULL;
    int ncf = 0;
    reduce_bricks *cb = NULL;
    pc.cache = calloc((size_t)nasm, sizeof *pc.cache);
    int rc = pc.trees && b && pc.cache ? 0 : fn_err_set(FN_ENOMEM, "reduce: out of memory");
    for (int f = 0; f <= nasm && rc == 0; f++)
        if (!(pc.trees[f] = obb_tree_build(f < nasm ? asm_[f] : moving, &op)))
            rc = FN_ENOMEM;
    double sep = INFINITY;
    if (rc == 0 && o->prealign && (rc = collides(&pc, &moving->pose, &sep)) >= 0) {
        /* a fragment already placed near the others (by hand) keeps its placement */
        rc = sep > PLACED_MM ? prealign(&pc, b, o, &r->prealigned) : 0;
    }
    r->start = moving->pose;
    /* Two stages unless the VOI is given: the first over the contact zone where the hand left the
     * fragment, the second over the tighter zone where the first one ended. */
    F = (fit){.start = r->start, .best = INFINITY, .o = o, .id = moving->id, .t0 = t0, .placed = r->start};
    memcpy(F.moving_centroid, moving->centroid, sizeof F.moving_centroid);
    /* A fit that ends on the trust wall, or in collision, has wandered off (a wrong basin; the
     * true pose collides with nothing): a second attempt from the start turned about the other
     * principal axes, and, if that ends there too, a third with wider turns about every axis; the
     * best over the union of their VOIs wins. */
    pose ends[3], sends[MAX_STARTS_SEEN];
    double sf[MAX_STARTS_SEEN];
    int nsends = 0;
    reduce_voi vois[3];
    int attempts = 0;
    for (int attempt = 0; attempt < 3 && rc == 0 && !F.cancelled; attempt++) {
        if (attempt) {
            int c = at_wall(&F, &moving->pose) ? 1 : collides(&pc, &moving->pose, NULL);
            if (c <= 0) {
                rc = c;
                break;
            }
            moving->pose = r->start;
        }
        int nstage = o->has_voi ? 1 : 2;
        for (int stage = 0; stage < nstage && rc == 0 && !F.cancelled; stage++) {
            if (o->has_voi)
                r->voi = o->voi;
            else
                rc = reduce_auto_voi(asm_, nasm, moving, stage ? 2 : 3, 6, o->voi_max_mm, &r->voi, NULL);
            reduce_metric_free(m);
            m = NULL;
            int use_coarse = stage == 0 && !o->has_voi && o->coarse;
            if (rc == 0 && use_coarse && !cb) { /* the coarse level, made once */
                cf = calloc((size_t)nasm + 1, sizeof *cf);
                cfp = calloc((size_t)nasm, sizeof *cfp);
                rc = cf && cfp ? 0 : fn_err_set(FN_ENOMEM, "reduce: out of memory");
                for (int f = 0; f <= nasm && rc == 0; f++) {
                    rc = reduce__coarse_frag(f < nasm ? asm_[f] : moving, &cf[f]);
                    ncf += rc == 0;
                    if (f < nasm)
                        cfp[f] = &cf[f];
                }
                if (rc == 0 && !(cb = reduce__bricks_new(&cf[nasm])))
                    rc = FN_ENOMEM;
            }
            if (rc == 0 && use_coarse) {
                double cs = fmax(cf[0].spacing[0], fmax(cf[0].spacing[1], cf[0].spacing[2]));
                double band = o->band_mm > 0 ? fmax(o->band_mm, cs) : 0;
                if (!(m = reduce__metric_with(cfp, nasm, &cf[nasm], cb, &r->voi, o->count, band, o->gap_mm)))
                    rc = FN_EINVAL;
            } else if (rc == 0 && !(m = reduce__metric_with(asm_, nasm, moving, b, &r->voi, o->count, o->band_mm, o->gap_mm)))
                rc = FN_EINVAL;
            if (rc)
                break;
            if (stage == 0) { /* a fragment left apart first slides straight into contact */
                double cm[3], dir[3], len = 0;
                centroid_world(moving, cm);
                for (int a = 0; a < 3; a++) {
                    dir[a] = m->fixed_centre[a] - cm[a];
                    len += dir[a] * dir[a];
                }
                len = sqrt(len);
                for (int a = 0; a < 3 && len > 0; a++)
                    dir[a] /= len;
                if (len > 0 && (rc = slide_to_contact(&pc, &moving->pose, dir, APPROACH_MM)) < 0)
                    break;
                rc = 0;
            }
            F.metric = m;
            F.pc = stage >= (o->has_voi ? 0 : 1) ? &pc : NULL;
            F.xtol = F.pc ? o->xtol_mm : 5 * o->xtol_mm; /* the first of two stages stops coarser */
            pose base = moving->pose, best = base;
            double bestf = INFINITY;
            /* The first stage also starts from the base turned by START_DEG about each principal
             * axis: the metric's basin is narrow, and the best of these fits wins. */
            int nstarts = stage == 0 && o->starts > 1 ? o->starts : 1, k0 = 0;
            if (attempt == 1 && stage == 0) { /* the turns about the other two axes */
                k0 = nstarts > 1 ? nstarts : 1;
                nstarts = k0 + 4;
            } else if (attempt == 2 && stage == 0) { /* wider turns, about every axis */
                k0 = 1;
                nstarts = 7;
            }
            for (int k = k0; k < nstarts && rc == 0 && !F.cancelled; k++) {
                F.start = base;
                if (k > 0) {
                    double axis[3], cm[3];
                    axis_world(moving, (k - 1) / 2 % 3, axis);
                    double deg = (k % 2 ? 1 : -1) * (attempt == 2 ? 1.5 : 1) * START_DEG;
                    pose turn = pose_from_axis_angle(axis, deg * PI / 180);
                    centroid_world(moving, cm);
                    F.start = turned(&base, &turn, cm, cm);
                }
                F.best = INFINITY;
                F.improvements = 0;
                centroid_world(moving, F.c);
                set_scale(&F, m);
                double f0 = objective_at(&F, &F.start);
                hist_add(&F, f0);
                int it = 0;
                rc = run_optimizer(&F, &it);
                r->iterations += it;
                if (rc == 0 && stage == 0 && attempt == 0 && k < MAX_STARTS_SEEN) {
                    sends[k] = F.best < f0 ? pose_of(&F, F.bestx) : F.start;
                    sf[k] = fmin(F.best, f0);
                    nsends = k + 1;
                }
                if (rc == 0 && fmin(F.best, f0) < bestf) {
                    bestf = fmin(F.best, f0);
                    best = F.best < f0 ? pose_of(&F, F.bestx) : F.start;
                }
            }
            moving->pose = best;
            pose_normalize(&moving->pose);
            if (rc == 0 && !o->has_voi && stage == nstage - 1 && nstage < 2 + VOI_GROW_STAGES &&
                !F.cancelled) {
                /* The second stage's VOI is the contact zone where the first ended: a first stage
                 * off the fit touches along part of the fracture only, and the second then fits to
                 * that part. Where the zone at the end has grown, the fit goes again over it. */
                reduce_voi now;
                if (reduce_auto_voi(asm_, nasm, moving, 2, 6, o->voi_max_mm, &now, NULL) == 0 &&
                    voi_volume(&now) > VOI_GROW * voi_volume(&r->voi))
                    nstage++;
            }
        }
        if (rc == 0) {
            ends[attempts] = moving->pose;
            vois[attempts++] = r->voi;
        }
    }
    if (rc == 0 && attempts > 1) { /* compared over the union of the VOIs, collisions costed */
        reduce_voi u = vois[0];
        for (int i = 1; i < attempts; i++)
            for (int a = 0; a < 3; a++) {
                u.lo[a] = fmin(u.lo[a], vois[i].lo[a]);
                u.hi[a] = fmax(u.hi[a], vois[i].hi[a]);
            }
        reduce_metric *mu = reduce__metric_with(asm_, nasm, moving, b, &u, o->count, o->band_mm, o->gap_mm);
        if (!mu)
            rc = FN_EINVAL;
        double fbest = INFINITY;
        int w = attempts - 1;
        for (int i = 0; i < attempts && rc == 0; i++) {
            int c = collides(&pc, &ends[i], NULL);
            double fu = reduce_metric_eval(mu, &ends[i], NULL) + (c > 0 ? COLLIDE_COST : 0);
            rc = c < 0 ? c : 0;
            if (fu < fbest) {
                fbest = fu;
                w = i;
            }
        }
        reduce_metric_free(mu);
        moving->pose = ends[w];
        r->voi = vois[w];
        if (rc == 0 && w != attempts - 1) { /* the final metric is the winner's */
            reduce_metric_free(m);
            if (!(m = reduce__metric_with(asm_, nasm, moving, b, &r->voi, o->count, o->band_mm, o->gap_mm)))
                rc = FN_EINVAL;
        }
    }
    /* A rival: a start of the first stage that ends about as well as the best one (within
     * AMBIG_METRIC) but more than 1 degree or 1 mm from it. The metric has rival basins there, and
     * the fit may sit in the wrong one without touching the trust wall or colliding (bench reduce
     * --ct CT_pitch.nii.gz: 3.4 mm and 2.7 degrees off). */
    int ambiguous = 0, kb = 0;
    for (int k = 1; k < nsends; k++)
        if (sf[k] < sf[kb])
            kb = k;
    for (int k = 0; k < nsends && !ambiguous; k++)
        if (k != kb && sf[k] < sf[kb] + AMBIG_METRIC) {
            double a[3], c[3], d2 = 0;
            pose_apply(&sends[k], moving->centroid, a);
            pose_apply(&sends[kb], moving->centroid, c);
            for (int i = 0; i < 3; i++)
                d2 += (a[i] - c[i]) * (a[i] - c[i]);
            ambiguous = sqrt(d2) > 1 || pose_angle_between(sends[k], sends[kb]) * 180 / PI > 1;
        }
    r->rival = ambiguous;
    int is_long = moving->eigval[0] > HOP_ELONGATION * moving->eigval[1];
    if (rc == 0 && !F.cancelled && o->hops > 0 && (is_long || ambiguous)) {
        /* A long piece: a cut through a tube is nearly symmetric under a turn about its axis and
         * the metric ripples in the turns (bench reduce --ct long-bone: fits stopped 4-12 degrees
         * off, at a metric worse than that of the fit started at the truth). Hops: the fit again
         * from the result turned HOP_DEG either way about each principal axis of the piece, the
         * best kept (colliding poses costed), until a round gains nothing (o->hops rounds). */
        F.metric = m;
        F.pc = &pc;
        F.xtol = o->xtol_mm;
        pose cur = moving->pose;
        double fcur = objective_at(&F, &cur);
        /* Other pieces hop only where the first stage was ambiguous, and strictly: a hop's end is
         * taken only when it is free of collision (at the tolerance) and its metric alone beats the
         * current one by HOP_MARGIN. A fit that ends interpenetrating (to be pushed out) costs
         * COLLIDE_COST in the objective, and any free pose nearby would beat that: hopping everywhere
         * with the plain rule swapped such fits for worse poses (CT_pitch success 0.90 -> 0.80). */
        int strict = !is_long;
        double margin = strict ? HOP_MARGIN : 1e-7;
        if (strict)
            fcur = reduce_metric_eval(m, &cur, NULL);
        for (int round = 0; round < o->hops && rc == 0 && !F.cancelled; round++) {
            pose next = cur;
            double fnext = fcur;
            for (int h = 0; h < 6 && rc == 0 && !F.cancelled; h++) {
                double axis[3], cm[3];
                moving->pose = cur;
                axis_world(moving, h / 2, axis);
                centroid_world(moving, cm);
                pose turn = pose_from_axis_angle(axis, (h % 2 ? 1 : -1) * HOP_DEG * PI / 180);
                F.start = turned(&cur, &turn, cm, cm);
                moving->pose = F.start;
                F.best = INFINITY;
                F.improvements = 0;
                centroid_world(moving, F.c);
                set_scale(&F, m);
                double f0 = objective_at(&F, &F.start);
                int it = 0;
                rc = run_optimizer(&F, &it);
                r->iterations += it;
                double fb = fmin(F.best, f0);
                pose hp = F.best < f0 ? pose_of(&F, F.bestx) : F.start;
                if (rc == 0 && strict) {
                    int c = collides(&pc, &hp, NULL);
                    if (c < 0)
                        rc = c;
                    fb = c ? INFINITY : reduce_metric_eval(m, &hp, NULL);
                }
                if (rc == 0 && fb < fnext - margin) {
                    fnext = fb;
                    next = hp;
                }
            }
            if (!(fnext < fcur - margin))
                break;
            cur = next;
            r->hops++;
            pose_normalize(&cur);
            fcur = fnext;
        }
        moving->pose = cur;
    }
    if (rc == 0 && F.cancelled)
        rc = 1; /* the placed pose stays */
    if (rc == 0) {
        r->end = r->fitted = moving->pose;
        rc = resolve_collision(&pc, m, o->settle_mm, r);
    }
    if (rc == 0) {
        r->metric_start = reduce_metric_eval(m, &r->start, NULL); /* both over the final VOI */
        r->metric_end = reduce_metric_eval(m, &r->end, NULL);
        /* a fit never keeps an end worse than a free start */
        if (r->metric_end > r->metric_start && (rc = collides(&pc, &r->start, NULL)) == 0) {
            r->end = r->fitted = r->start;
            r->metric_end = r->metric_start;
            r->push_mm = 0;
            r->collides = 0;
        }
        rc = rc < 0 ? rc : 0;
    }
    if (rc == 0) {
        moving->pose = r->end;
        r->evaluations = F.evals;
        r->history = F.hist;
        r->nhistory = F.nhist;
        F.hist = NULL;
    } else {
        moving->pose = r->end = r->fitted = r->placed;
    }
    r->seconds = now_s() - t0;
    free(F.hist);
    reduce_metric_free(m);
    reduce__bricks_free(b);
    reduce__bricks_free(cb);
    for (int f = 0; f < ncf; f++)
        frag_free(&cf[f]);
    free(cf);
    free(cfp);
    free_trees(pc.trees, nasm + 1);
    free(pc.cache);
    return rc;
}

/* ---- several fragments --------------------------------------------------------------------- */

/* The second sweep's result joins the first's: the same placement, the later end, counts summed,
 * histories joined. */
static void merge_sweep(reduce_result *r, reduce_result *r2)
{
    double *h = realloc(r->history, (size_t)(r->nhistory + r2->nhistory + 1) * sizeof *h);
    if (h) {
        memcpy(h + r->nhistory, r2->history, (size_t)r2->nhistory * sizeof *h);
        r->history = h;
        r->nhistory += r2->nhistory;
    }
    r->fitted = r2->fitted;
    r->end = r2->end;
    r->voi = r2->voi;
    r->iterations += r2->iterations;
    r->evaluations += r2->evaluations;
    r->seconds += r2->seconds;
    r->metric_start = r2->metric_start;
    r->metric_end = r2->metric_end;
    r->push_mm += r2->push_mm;
    r->collides = r2->collides;
    r->rival |= r2->rival;
    r->hops += r2->hops;
    reduce_result_free(r2);
}

int reduce_case(planning_case *c, int fixed, const int *moving, int nmoving, const reduce_opts *o, reduce_result *r)
{
    if (!c || fixed < 0 || fixed >= c->nfrag || nmoving < 1 || !r)
        return fn_err_set(FN_EINVAL, "reduce: bad fixed fragment or nothing to move");
    const frag **asm_ = calloc((size_t)c->nfrag, sizeof *asm_);
    int *todo = calloc((size_t)c->nfrag, sizeof *todo);
    if (!asm_ || !todo) {
        free(asm_);
        free(todo);
        return fn_err_set(FN_ENOMEM, "reduce: out of memory");
    }
    int nasm = 1, left = nmoving, rc = 0;
    asm_[0] = &c->frag[fixed];
    for (int i = 0; i < nmoving; i++)
        todo[i] = moving ? moving[i] : i < fixed ? i : i + 1;
    for (int done = 0; done < nmoving && rc == 0; done++) {
        /* the fragment of largest contact with the assembly goes next */
        int pick = 0;
        double most = -1;
        for (int i = 0; i < left; i++) {
            reduce_voi v;
            double ml = 0;
            if (reduce_auto_voi(asm_, nasm, &c->frag[todo[i]], 3, 6, 0, &v, &ml) < 0)
                ml = 0;
            if (ml > most) {
                most = ml;
                pick = i;
            }
        }
        int mi = todo[pick];
        todo[pick] = todo[--left];
        rc = reduce_pair(asm_, nasm, &c->frag[mi], o, &r[done]);
        if (rc < 0)
            fn_err_wrap(rc, "fragment %d", c->frag[mi].id);
        asm_[nasm++] = &c->frag[mi];
    }
    /* A second sweep: each fragment again, now against all the others, so that a fragment fitted
     * early sees those that came after it (a chain of pieces does not pile up its errors). */
    reduce_opts again = *o;
    again.prealign = 0;
    const frag **others = nmoving > 1 && rc == 0 ? calloc((size_t)nasm, sizeof *others) : NULL;
    if (nmoving > 1 && rc == 0 && !others)
        rc = fn_err_set(FN_ENOMEM, "reduce: out of memory");
    for (int d = 0; others && d < nmoving && rc == 0; d++) {
        int mi = case_find(c, r[d].id), n2 = 0;
        for (int k = 0; k < nasm; k++)
            if (asm_[k] != &c->frag[mi])
                others[n2++] = asm_[k];
        reduce_result r2;
        rc = reduce_pair(others, n2, &c->frag[mi], &again, &r2);
        if (rc < 0) {
            fn_err_wrap(rc, "fragment %d", c->frag[mi].id);
            break;
        }
        merge_sweep(&r[d], &r2);
    }
    free(others);
    free(asm_);
    free(todo);
    return rc;
}

/* ---- ground truth -------------------------------------------------------------------------- */

int reduce_truth_errors(const planning_case *c, int fi, int mi, double *rot_deg, double *trans_mm, double *tre_mm)
{
    if (!c || !c->has_truth || fi < 0 || mi < 0 || fi >= c->nfrag || mi >= c->nfrag)
        return fn_err_set(FN_EINVAL, "reduce: the case has no ground truth");
    const frag *f = &c->frag[fi];
    pose want = pose_compose(f->pose, pose_compose(pose_inverse(c->truth[fi]), c->truth[mi]));
    reduce_errors(f, &c->frag[mi], &want, rot_deg, trans_mm, tre_mm);
    return 0;
}

void reduce_errors(const frag *f, const frag *m, const pose *want, double *rot_deg, double *trans_mm,
                   double *tre_mm)
{
    *rot_deg = pose_angle_between(m->pose, *want) * 180 / PI;
    double a[3], b[3];
    pose_apply(&m->pose, m->centroid, a);
    pose_apply(want, m->centroid, b);
    *trans_mm = sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
    /* fracture-surface voxels: in the true pose, within 1.5 voxels of the fixed fragment's bone */
    pose to_f = pose_inverse(pose_compose(f->pose, f->home));
    double s_all = 0, s_surf = 0;
    size_t n_all = 0, n_surf = 0, idx = 0;
    for (int k = 0; k < m->dim[2]; k++)
        for (int j = 0; j < m->dim[1]; j++)
            for (int i = 0; i < m->dim[0]; i++, idx++) {
                if (!m->prob[idx])
                    continue;
                int l[3] = {i, j, k};
                double h[3], x[3], y[3], fl[3];
                frag_voxel_world(m, l, h);
                pose_apply(&m->pose, h, x);
                pose_apply(want, h, y);
                double d2 = (x[0] - y[0]) * (x[0] - y[0]) + (x[1] - y[1]) * (x[1] - y[1]) + (x[2] - y[2]) * (x[2] - y[2]);
                s_all += d2;
                n_all++;
                pose_apply(&to_f, y, fl);
                int near = 0;
                for (int dz = -1; dz <= 1 && !near; dz++)
                    for (int dy = -1; dy <= 1 && !near; dy++)
                        for (int dx = -1; dx <= 1 && !near; dx++) {
                            int q[3] = {(int)floor(fl[0] / f->spacing[0] + 0.5) + dx,
                                        (int)floor(fl[1] / f->spacing[1] + 0.5) + dy,
                                        (int)floor(fl[2] / f->spacing[2] + 0.5) + dz};
                            if (q[0] >= 0 && q[1] >= 0 && q[2] >= 0 && q[0] < f->dim[0] && q[1] < f->dim[1] &&
                                q[2] < f->dim[2])
                                near = f->prob[((size_t)q[2] * f->dim[1] + q[1]) * f->dim[0] + q[0]] != 0;
                        }
                if (near) {
                    s_surf += d2;
                    n_surf++;
                }
            }
    *tre_mm = n_surf ? sqrt(s_surf / (double)n_surf) : n_all ? sqrt(s_all / (double)n_all) : 0;
}

/* ---- the case record ----------------------------------------------------------------------- */

static json_t *pose_obj(const pose *p)
{
    json_t *q = json_array(), *t = json_array();
    for (int i = 0; i < 4; i++)
        json_array_append_new(q, json_real(p->q[i]));
    for (int i = 0; i < 3; i++)
        json_array_append_new(t, json_real(p->t[i]));
    return json_pack("{s:o,s:o}", "q", q, "t", t);
}

static json_t *result_obj(const reduce_result *r)
{
    json_t *voi = json_array(), *h = json_array();
    for (int i = 0; i < 6; i++)
        json_array_append_new(voi, json_real(i < 3 ? r->voi.lo[i] : r->voi.hi[i - 3]));
    for (int i = 0; i < r->nhistory; i++)
        json_array_append_new(h, json_real(r->history[i]));
    return json_pack("{s:i,s:o,s:b,s:o,s:o,s:o,s:i,s:i,s:f,s:f,s:f,s:f,s:b,s:o}", "id", r->id, "voi_mm", voi,
                     "prealigned", r->prealigned, "placed", pose_obj(&r->placed), "start", pose_obj(&r->start),
                     "end", pose_obj(&r->end), "iterations", r->iterations, "evaluations", r->evaluations,
                     "seconds", r->seconds, "metric_start", r->metric_start, "metric_end", r->metric_end,
                     "push_mm", r->push_mm, "collides", r->collides, "history", h);
}

int reduce_store(planning_case *c, int fixed, const reduce_opts *o, const reduce_result *r, int n)
{
    json_t *extra = c->extra ? c->extra : json_object(), *frs = json_array();
    json_t *rec = json_pack("{s:s,s:s,s:i,s:b,s:f,s:f,s:o}", "method", reduce_method_name(o->method), "counting",
                            o->count == REDUCE_NEAREST ? "nearest" : "trilinear", "fixed", c->frag[fixed].id,
                            "prealign", o->prealign, "tolerance_mm", o->tolerance_mm, "gap_mm", o->gap_mm,
                            "fragments", frs);
    int ok = extra && rec && frs;
    for (int i = 0; i < n && ok; i++) {
        json_t *ro = result_obj(&r[i]);
        ok = ro && json_array_append_new(frs, ro) == 0;
    }
    if (ok)
        ok = json_object_set_new(extra, "reduction", rec) == 0;
    else
        json_decref(rec);
    if (!c->extra)
        c->extra = extra;
    if (!ok)
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for the case record");
    size_t npairs = (size_t)c->nfrag * (size_t)c->nfrag / 2 + 1;
    uint8_t *fitted = calloc((size_t)c->nfrag + 1, 1);
    case_overlap *pen = malloc(npairs * sizeof *pen);
    int rc = fitted && pen ? 0 : fn_err_set(FN_ENOMEM, "reduce: out of memory for the case record");
    for (int i = 0; i < n && rc == 0; i++) {
        int k = case_find(c, r[i].id);
        if (k >= 0)
            fitted[k] = 1;
    }
    if (rc == 0 && (rc = case_penetrating(c, fitted, pen, (int)npairs)) >= 0)
        rc = case_record_penetrating(c, pen, rc);
    free(fitted);
    free(pen);
    return rc;
}

int reduce_fit_one(const frag *const *others, int nothers, const frag *moving, const pose *start,
                   const reduce_opts *o, pose *out, reduce_result *r)
{
    if (!others || nothers < 1 || !moving || !start || !o || !out || !r)
        return fn_err_set(FN_EINVAL, "reduce: no fragments");
    frag m = *moving; /* a private copy: only its pose changes, its voxels are read */
    m.pose = *start;
    reduce_opts fo = *o;
    fo.prealign = 0;
    int rc = reduce_pair(others, nothers, &m, &fo, r);
    *out = rc == 0 ? r->end : *start;
    return rc;
}
