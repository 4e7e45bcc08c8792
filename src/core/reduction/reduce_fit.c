/* reduce_fit: the fit of one moving fragment to a fixed assembly (reduce_pair, reduce_fit_one; see
 * reduce.h), a sequence of named stages over one state (fit_state):
 *  1. open:     the hierarchies and the query, the moving fragment's bricks;
 *  2. local:    attempts from where the hand left the piece, each a sequence of stages over a
 *               contact zone (the approach, then the starts), within the trust region; another
 *               only after one that ended colliding (or a retry on the trust wall);
 *  3. global:   where the first attempt ended on the wall, or after every local fit
 *               (reduce_opts.global_check, a piece not long): candidate starts (the placed pose,
 *               it turned and moved about its principal axes, the pre-alignment) each fitted
 *               briefly (on o->threads threads, beside the local fit under the check:
 *               cand_launch, cand_collect), ranked by their metric over one VOI, the best kept
 *               (and a second where about as good), each refined as above but without the wall;
 *               after a local fit that did not end on the wall, only those that beat its end
 *               there;
 *  4. winner:   the attempts' ends compared over the union of their VOIs (rivals among them kept);
 *  5. rivals:   whether the first stage's starts ended in rival basins;
 *  6. hops:     the fit again from turns (a long piece) or moves (on o->threads threads:
 *               hop_moves) of the result, the best kept;
 *  7. finish:   the result pushed out of collision, its metrics and history.
 * Every number they are tuned by is in the table reduce__tune (reduce_impl.h, reduce.c). */
#include "reduce.h"
#include "reduce_impl.h"

#include "err.h"
#include "fnclock.h"
#include "powell.h"

#include <math.h>
#include <nlopt.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846
#define ATTEMPTS 3 /* the start; turns about the other axes; wider turns about all three */
#define GLOBAL_CANDIDATES 14 /* the placed pose, six turns of it, six shifts, the pre-aligned pose */
#define ENDS (ATTEMPTS - 1 + ATTEMPTS * REDUCE_GLOBAL_KEEP_MAX) /* the local retries' and the refinements' */
#define FROM_LOCAL (-2) /* attempt_from of the local fit's ends (keep_pa is -1 or a kept index) */
#define HOP_TURNS 6 /* a hop round: either way about each of the three principal axes */

static double now_s(void)
{
    return (double)fnclock_now_us() * 1e-6;
}

/* ---- the objective: the metric over six parameters, with the optimizers' bookkeeping --------- */

typedef struct objective {
    reduce_metric *metric;
    pose start;
    double c[3];     /* rotation centre, world */
    double raxis[3][3]; /* the rotation parameters' axes (columns, world) */
    double ra[3];       /* and their scales, mm per radian */
    int evals;
    int64_t eval_ns;    /* thread CPU time in the metric over those evaluations */
    double best;
    double bestx[6];
    int improvements;
    double *hist;
    int nhist, caphist;
    const reduce_opts *o;
    int id;
    double t0;
    const reduce_collider *pc; /* non-NULL: a colliding pose costs reduce__tune.collide_cost more */
    double xtol;        /* this stage's convergence step */
    int nowall;         /* 1: no trust wall (the global stage and its refinements) */
    int cap;            /* > 0: this run stops after this many evaluations */
    pose placed;        /* where the hand left it: the trust region's centre */
    double moving_centroid[3]; /* home world */
    nlopt_opt opt;      /* the NLopt run in progress, for a cancel */
    int cancelled;
} objective;

/* 1 once the caller's cancel flag is set (remembered, and an NLopt run told to stop). */
static int cancel_seen(objective *ob)
{
    if (!ob->cancelled && ob->o->cancel && atomic_load(ob->o->cancel)) {
        ob->cancelled = 1;
        if (ob->opt)
            nlopt_force_stop(ob->opt);
    }
    return ob->cancelled;
}

static pose pose_of(const objective *ob, const double *x)
{
    double rv[3] = {0, 0, 0}, zero[3] = {0, 0, 0}, to[3];
    for (int a = 0; a < 3; a++)
        for (int i = 0; i < 3; i++)
            rv[i] += x[3 + a] / ob->ra[a] * ob->raxis[i][a];
    pose rot = pose_from_rotvec(rv, zero);
    for (int a = 0; a < 3; a++)
        to[a] = ob->c[a] + x[a];
    return reduce__turned(&ob->start, &rot, ob->c, to);
}

/* The rotation's axes and scales: the principal axes of the moving voxels in the VOI at the start,
 * each scaled by their RMS distance from it (o->axis_scale), or the world axes all scaled by the RMS
 * distance from the centroid; clamped to the table's scale_min_mm .. scale_max_mm. */
static void set_scale(objective *ob, const reduce_metric *m)
{
    const reduce_tuning *T = &reduce__tune;
    double S[3][3], val[3];
    reduce_metric_spread(m, &ob->start, ob->c, S);
    double tr = S[0][0] + S[1][1] + S[2][2];
    if (ob->o->axis_scale) {
        frag_eigen_sym3(S, ob->raxis, val);
        for (int a = 0; a < 3; a++)
            ob->ra[a] = fmin(fmax(sqrt(fmax(tr - val[a], 0)), T->scale_min_mm), T->scale_max_mm);
    } else
        for (int a = 0; a < 3; a++) {
            for (int i = 0; i < 3; i++)
                ob->raxis[i][a] = i == a;
            ob->ra[a] = fmin(fmax(sqrt(tr), T->scale_min_mm), T->scale_max_mm);
        }
}

static void hist_add(objective *ob, double f)
{
    if (ob->nhist == ob->caphist) {
        int nc = ob->caphist ? 2 * ob->caphist : 64;
        double *h = realloc(ob->hist, (size_t)nc * sizeof *h);
        if (!h)
            return; /* the history is a report: a shorter one is no failure */
        ob->hist = h;
        ob->caphist = nc;
    }
    ob->hist[ob->nhist++] = f;
}

/* A wall around the placed pose for the local fit (reduce_opts.trust_mm, trust_deg): a fit that
 * runs into it has left the basin where the hand put the piece (a thin bone offers many poses that
 * fill a VOI better than the fit does), and the global stage takes over, without it. */
static double trust_cost(const objective *ob, const pose *p)
{
    if (ob->o->trust_mm <= 0 || ob->nowall)
        return 0;
    double a[3], b[3], d2 = 0;
    pose_apply(p, ob->moving_centroid, a);
    pose_apply(&ob->placed, ob->moving_centroid, b);
    for (int i = 0; i < 3; i++)
        d2 += (a[i] - b[i]) * (a[i] - b[i]);
    double et = sqrt(d2) - ob->o->trust_mm, er = pose_angle_between(*p, ob->placed) * 180 / PI - ob->o->trust_deg;
    return (et > 0 ? 1 + et : 0) + (er > 0 ? 1 + er : 0);
}

/* 1 when p lies within wall_mm or wall_deg of the trust wall. */
static int at_wall(const objective *ob, const pose *p)
{
    if (ob->o->trust_mm <= 0 || ob->nowall)
        return 0;
    double a[3], b[3], d2 = 0;
    pose_apply(p, ob->moving_centroid, a);
    pose_apply(&ob->placed, ob->moving_centroid, b);
    for (int i = 0; i < 3; i++)
        d2 += (a[i] - b[i]) * (a[i] - b[i]);
    return sqrt(d2) > ob->o->trust_mm - reduce__tune.wall_mm ||
           pose_angle_between(*p, ob->placed) * 180 / PI > ob->o->trust_deg - reduce__tune.wall_deg;
}

static double cost(const double *x, void *ctx)
{
    objective *ob = ctx;
    if (cancel_seen(ob))
        return ob->best < INFINITY ? ob->best + 1 : reduce__tune.collide_cost;
    pose p = pose_of(ob, x);
    int64_t t = fnclock_thread_cpu_ns();
    double f = reduce_metric_eval(ob->metric, &p, NULL);
    ob->eval_ns += fnclock_thread_cpu_ns() - t;
    if (ob->pc && reduce__collides(ob->pc, &p, NULL) > 0)
        f += reduce__tune.collide_cost;
    f += trust_cost(ob, &p);
    ob->evals++;
    if (f < ob->best) {
        ob->best = f;
        memcpy(ob->bestx, x, sizeof ob->bestx);
        /* the band follows the search (exact without it, and slower); failing, it stays where it was */
        if (reduce__metric_drifted(ob->metric, &p))
            (void)reduce__metric_rebase(ob->metric, &p);
    }
    return f;
}

/* The cost at a pose (the start of a fit). */
static double cost_at(objective *ob, const pose *p)
{
    double f = reduce_metric_eval(ob->metric, p, NULL) + trust_cost(ob, p);
    if (ob->pc && reduce__collides(ob->pc, p, NULL) > 0)
        f += reduce__tune.collide_cost;
    return f;
}

static int powell_iter(int iter, double f, void *ctx)
{
    objective *ob = ctx;
    hist_add(ob, f);
    if (cancel_seen(ob))
        return 1;
    if (ob->o->progress)
        ob->o->progress(ob->o->progress_ctx, ob->id, iter, ob->evals, f, now_s() - ob->t0);
    return 0;
}

static double nlopt_cost(unsigned n, const double *x, double *grad, void *ctx)
{
    objective *ob = ctx;
    double before = ob->best, f = cost(x, ctx);
    if (ob->best < before) {
        ob->improvements++;
        hist_add(ob, ob->best);
        if (ob->o->progress && ob->improvements % 10 == 0)
            ob->o->progress(ob->o->progress_ctx, ob->id, ob->improvements, ob->evals, ob->best, now_s() - ob->t0);
    }
    return f;
}

static int run_optimizer(objective *ob, int *iterations)
{
    const reduce_opts *o = ob->o;
    double x[6] = {0, 0, 0, 0, 0, 0};
    int left = ob->cap > 0 ? ob->cap : o->max_eval - ob->evals;
    if (o->method == REDUCE_POWELL) {
        /* Restarts (the table's powell_step); a restart that gains nothing ends it. */
        *iterations = 0;
        double fprev = INFINITY;
        int evals0 = ob->evals;
        for (int k = 0; k < 3; k++) {
            powell_opts po;
            powell_defaults(&po);
            po.step = reduce__tune.powell_step[k];
            po.xtol = ob->xtol;
            po.line_tol = ob->xtol;
            po.ftol = 1e-9;
            po.max_eval = left - (ob->evals - evals0);
            po.on_iter = powell_iter;
            po.iter_ctx = ob;
            if (po.max_eval < 10)
                break;
            powell_stats st;
            int rc = powell_minimize(cost, ob, x, 6, &po, &st);
            *iterations += st.iterations;
            if (rc)
                return rc;
            if (!(st.f < fprev - reduce__tune.gain) || ob->cancelled)
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
    nlopt_set_min_objective(opt, nlopt_cost, ob);
    nlopt_set_xtol_abs1(opt, ob->xtol);
    nlopt_set_maxeval(opt, left > 10 ? left : 10);
    nlopt_set_initial_step1(opt, reduce__tune.nlopt_step);
    if (o->method != REDUCE_PRAXIS) { /* PRAXIS takes no bounds */
        nlopt_set_lower_bounds1(opt, -reduce__tune.bound);
        nlopt_set_upper_bounds1(opt, reduce__tune.bound);
    }
    double f;
    nlopt_srand(1); /* PRAXIS draws random numbers: the same case gives the same fit */
    ob->opt = opt;
    nlopt_result res = nlopt_optimize(opt, x, &f);
    ob->opt = NULL;
    nlopt_destroy(opt);
    if (res == NLOPT_FORCED_STOP && ob->cancelled)
        res = NLOPT_SUCCESS;
    *iterations = ob->improvements;
    if (res < 0 && res != NLOPT_ROUNDOFF_LIMITED)
        return fn_err_set(FN_EINVAL, "reduce: NLopt %s failed (code %d)", reduce_method_name(o->method), (int)res);
    return 0;
}


/* ---- the state and its stages ---------------------------------------------------------------- */

/* Coarse copies (reduce_opts.coarse): the assembly's nasm fragments, then the moving one. */
typedef struct level {
    frag *frag;
    const frag **asm_;
    int nfrag;             /* made so far (to free) */
    reduce_bricks *bricks; /* the moving copy's */
} level;

typedef struct fit_state {
    const frag *const *asm_;
    int nasm;
    frag *moving;          /* its pose moves through the stages */
    const reduce_opts *o;
    reduce_result *r;
    reduce_collider col;
    reduce_bricks *bricks; /* the moving fragment's, for every metric of the fit */
    reduce_cloud asm_pts;  /* the assembly's bone, for every contact zone of the fit (made once) */
    level coarse;
    reduce_metric *metric; /* the current stage's */
    objective obj;
    /* the global stage: the candidates kept, best first, and which was the pre-aligned one */
    pose keep[REDUCE_GLOBAL_KEEP_MAX];
    int nkeep, keep_pa, refine; /* refine: the kept candidate being refined */
    int global_evals;
    /* attempts: where each ended, over which VOI, from which kept candidate */
    pose attempt_end[ENDS];
    reduce_voi attempt_voi[ENDS];
    int attempt_from[ENDS];
    int attempts;
    pose rival_end[ENDS]; /* the winner's end, then the ends of other kept candidates as good */
    int nrival_ends;
    /* the first attempt's first-stage starts: where each ended and its cost (for rivals) */
    pose start_end[REDUCE_STARTS_SEEN];
    double start_cost[REDUCE_STARTS_SEEN];
    int nstart_ends;
    int rival_of[REDUCE_STARTS_SEEN]; /* the best of them, then the rivals (indices) */
    int nrival_of;
    int retry_evals; /* the local retries' evaluations where the global stage took over: not counted
                      * against o->max_eval (as the global stage's are not) */
} fit_state;

static int stage_open(fit_state *s, const frag *const *asm_, int nasm, frag *moving, const reduce_opts *o,
                      reduce_result *r)
{
    double t0 = now_s();
    *s = (fit_state){.asm_ = asm_, .nasm = nasm, .moving = moving, .o = o, .r = r};
    s->obj.t0 = t0;
    memset(r, 0, sizeof *r);
    r->id = moving->id;
    r->start = r->placed = moving->pose;
    int rc = reduce__collider_open(&s->col, asm_, nasm, moving, o);
    s->bricks = reduce__bricks_new(moving);
    return rc == 0 && !s->bricks ? fn_err_set(FN_ENOMEM, "reduce: out of memory") : rc;
}

/* A piece apart from the assembly is pre-aligned (the paper's remedy for a far start); one nearer
 * than placed_mm was placed by hand and keeps its placement. The local fit's start, and the centre
 * of its trust region, is the result. */
static int stage_start(fit_state *s)
{
    double sep = INFINITY;
    int rc = 0;
    if (s->o->prealign && (rc = reduce__collides(&s->col, &s->moving->pose, &sep)) >= 0)
        rc = sep > reduce__tune.placed_mm ? reduce__prealign(&s->col, s->bricks, s->o, &s->r->prealigned) : 0;
    s->r->start = s->moving->pose;
    objective *ob = &s->obj;
    *ob = (objective){.start = s->r->start, .best = INFINITY, .o = s->o, .id = s->moving->id, .t0 = ob->t0,
                      .placed = s->r->start};
    memcpy(ob->moving_centroid, s->moving->centroid, sizeof ob->moving_centroid);
    s->keep[0] = s->r->start;
    s->nkeep = 1;
    s->keep_pa = -1;
    return rc;
}

static int level_open(fit_state *s)
{
    level *L = &s->coarse;
    L->frag = calloc((size_t)s->nasm + 1, sizeof *L->frag);
    L->asm_ = calloc((size_t)s->nasm, sizeof *L->asm_);
    int rc = L->frag && L->asm_ ? 0 : fn_err_set(FN_ENOMEM, "reduce: out of memory");
    for (int f = 0; f <= s->nasm && rc == 0; f++) {
        rc = reduce__coarse_frag(f < s->nasm ? s->asm_[f] : s->moving, &L->frag[f]);
        L->nfrag += rc == 0;
        if (f < s->nasm)
            L->asm_[f] = &L->frag[f];
    }
    if (rc == 0 && !(L->bricks = reduce__bricks_new(&L->frag[s->nasm])))
        rc = FN_ENOMEM;
    return rc;
}

static void level_close(level *L)
{
    reduce__bricks_free(L->bricks);
    for (int f = 0; f < L->nfrag; f++)
        frag_free(&L->frag[f]);
    free(L->frag);
    free(L->asm_);
}

/* The contact zone where the piece is now (reduce_auto_voi with delta_mm, the table's margin). */
static int zone_voi(fit_state *s, double delta_mm, reduce_voi *voi)
{
    int rc = 0;
    if (!s->asm_pts.p)
        rc = reduce__cloud_new(&s->asm_pts, s->asm_, s->nasm);
    return rc ? rc : reduce__zone_voi(&s->asm_pts, s->moving, s->bricks, delta_mm, reduce__tune.zone_margin_mm,
                                      s->o->voi_max_mm, voi, NULL);
}

/* The fit's metric over voi on the voxel grid itself (the options' count, band and gap): NULL with
 * fn_err. */
static reduce_metric *fine_metric(const fit_state *s, const reduce_voi *voi)
{
    const reduce_opts *o = s->o;
    return reduce__metric_with(s->asm_, s->nasm, s->moving, s->bricks, voi, o->count, o->band_mm,
                               reduce__band_cut(o->band_mm), o->gap_mm);
}

/* A stage's VOI (given, or the contact zone where the piece is now) and its metric, on the coarse
 * level in the first stage when coarse (and the VOI is automatic). */
static int stage_metric(fit_state *s, int stage, int coarse)
{
    const reduce_opts *o = s->o;
    const reduce_tuning *T = &reduce__tune;
    int rc = 0;
    if (o->has_voi)
        s->r->voi = o->voi;
    else
        rc = zone_voi(s, T->zone_delta_mm[stage ? 1 : 0], &s->r->voi);
    reduce_metric_free(s->metric);
    s->metric = NULL;
    int use_coarse = stage == 0 && !o->has_voi && coarse;
    if (rc == 0 && use_coarse && !s->coarse.bricks) /* made once */
        rc = level_open(s);
    if (rc == 0 && use_coarse) {
        const level *L = &s->coarse;
        double cs = fmax(L->frag[0].spacing[0], fmax(L->frag[0].spacing[1], L->frag[0].spacing[2]));
        double band = o->band_mm > 0 ? fmax(o->band_mm, cs) : 0;
        s->metric = reduce__metric_with(L->asm_, s->nasm, &L->frag[s->nasm], L->bricks, &s->r->voi, o->count, band, 0,
                                        o->gap_mm);
    } else if (rc == 0)
        s->metric = fine_metric(s, &s->r->voi);
    return rc == 0 && !s->metric ? FN_EINVAL : rc;
}

/* A piece left apart first slides straight into contact, towards the assembly's bone in the VOI. */
static int stage_approach(fit_state *s)
{
    double cm[3], dir[3], len = 0;
    reduce__centroid_world(s->moving, cm);
    for (int a = 0; a < 3; a++) {
        dir[a] = s->metric->fixed_centre[a] - cm[a];
        len += dir[a] * dir[a];
    }
    len = sqrt(len);
    for (int a = 0; a < 3 && len > 0; a++)
        dir[a] /= len;
    int rc = len > 0 ? reduce__slide_to_contact(&s->col, &s->moving->pose, dir, reduce__tune.approach_mm) : 0;
    return rc < 0 ? rc : 0;
}

/* One run of the optimizer from s->obj.start, turning about centre c: *end and *f its best (the
 * start when nothing beat it). record_start: the start's cost goes into the history. */
static int fit_from(fit_state *s, const double c[3], int record_start, pose *end, double *f)
{
    objective *ob = &s->obj;
    ob->best = INFINITY;
    ob->improvements = 0;
    memcpy(ob->c, c, sizeof ob->c);
    if (reduce__metric_rebase(s->metric, &ob->start) < 0)
        return FN_ENOMEM;
    set_scale(ob, ob->metric);
    double f0 = cost_at(ob, &ob->start);
    if (record_start)
        hist_add(ob, f0);
    int it = 0;
    int rc = run_optimizer(ob, &it);
    s->r->iterations += it;
    *f = fmin(ob->best, f0);
    *end = ob->best < f0 ? pose_of(ob, ob->bestx) : ob->start;
    return rc;
}

/* 1 when poses a and b of the moving piece lie farther apart than rival_mm (its centroid) or
 * rival_deg: distinct answers. */
static int apart(const fit_state *s, const pose *a, const pose *b)
{
    double x[3], y[3], d2 = 0;
    pose_apply(a, s->moving->centroid, x);
    pose_apply(b, s->moving->centroid, y);
    for (int i = 0; i < 3; i++)
        d2 += (x[i] - y[i]) * (x[i] - y[i]);
    return sqrt(d2) > reduce__tune.rival_mm || pose_angle_between(*a, *b) * 180 / PI > reduce__tune.rival_deg;
}

static void voi_join(reduce_voi *u, const reduce_voi *v)
{
    for (int a = 0; a < 3; a++) {
        u->lo[a] = fmin(u->lo[a], v->lo[a]);
        u->hi[a] = fmax(u->hi[a], v->hi[a]);
    }
}

/* ---- fits on the side: copies of the fit's state for other threads ------------------------- */

/* What a fit on a copy spent, added to the fit's in order once the threads are joined. */
typedef struct side_spent {
    double *hist;
    int nhist, evals, iterations, cancelled;
    int64_t eval_ns;
} side_spent;

/* *tmpl a copy of s for other threads, with copies of its moving piece (mv, sharing the voxels:
 * only its pose changes) and result (r): collision queries without the caches (which change no
 * answer), no metric, coarse level or history of its own. */
static void side_template(fit_state *tmpl, const fit_state *s, frag *mv, reduce_result *r)
{
    *tmpl = *s;
    *mv = *s->moving;
    *r = *s->r;
    tmpl->moving = tmpl->col.moving = mv;
    tmpl->r = r;
    tmpl->col.cache = NULL;
    tmpl->metric = NULL;
    tmpl->coarse = (level){0};
    tmpl->obj.hist = NULL;
    tmpl->obj.nhist = tmpl->obj.caphist = tmpl->obj.evals = 0;
    tmpl->obj.eval_ns = 0;
    tmpl->obj.opt = NULL;
    tmpl->obj.cancelled = 0;
}

/* A thread's own copy of the fit's state, over its own options, moving piece and result (t points
 * into the struct: made in place, never copied). */
typedef struct side {
    fit_state t;
    reduce_opts o;
    frag mv;
    reduce_result r;
} side;

/* sd made from tmpl; its options are tmpl's without progress, which is called on the fit's own
 * thread alone (reduce.h). */
static void side_state(side *sd, const fit_state *tmpl)
{
    sd->t = *tmpl;
    sd->o = *tmpl->o;
    sd->o.progress = NULL;
    sd->t.o = &sd->o;
    sd->mv = *tmpl->moving;
    sd->r = *tmpl->r;
    sd->t.moving = sd->t.col.moving = &sd->mv;
    sd->t.r = &sd->r;
}

/* A new fit on sd: the template's objective, no iterations yet. */
static void side_begin(side *sd, const fit_state *tmpl)
{
    sd->t.obj = tmpl->obj;
    sd->t.obj.o = &sd->o;
    sd->r.iterations = 0;
}

/* What the last fit on t spent (its history now sp's). */
static void side_take(side_spent *sp, const fit_state *t)
{
    sp->hist = t->obj.hist;
    sp->nhist = t->obj.nhist;
    sp->evals = t->obj.evals;
    sp->eval_ns = t->obj.eval_ns;
    sp->iterations = t->r->iterations;
    sp->cancelled = t->obj.cancelled;
}

/* sp added to the fit s (its evaluations to *evals), its history freed. */
static void side_merge(fit_state *s, side_spent *sp, int *evals)
{
    for (int k = 0; k < sp->nhist; k++)
        hist_add(&s->obj, sp->hist[k]);
    free(sp->hist);
    sp->hist = NULL;
    *evals += sp->evals;
    s->obj.eval_ns += sp->eval_ns;
    s->r->iterations += sp->iterations;
    s->obj.cancelled |= sp->cancelled;
}

/* Up to o->threads - 1 threads (and fewer than n) started on fn(arg): their number. */
static int side_threads(pthread_t *th, int n, const reduce_opts *o, void *(*fn)(void *), void *arg)
{
    int nth = 0;
    while (nth + 1 < o->threads && nth + 1 < n && nth < REDUCE_THREADS_MAX &&
           pthread_create(&th[nth], NULL, fn, arg) == 0)
        nth++;
    return nth;
}

/* The global stage's candidate starts: the placed pose, it turned global_deg either way about each
 * of the piece's principal axes and moved global_mm either way along each, and, when o->prealign,
 * the last (*pa: its index, else -1) stands for the paper's pre-alignment: a worker makes it
 * (cand_prealign), first of all, so that its 48 slides do not hold up the others. Returns their
 * number. */
static int global_candidates(fit_state *s, pose *cand, int *pa)
{
    pose base = s->moving->pose;
    double cm[3];
    reduce__centroid_world(s->moving, cm);
    int n = 0;
    cand[n++] = base;
    for (int h = 0; h < 6; h++) {
        double axis[3];
        reduce__axis_world(s->moving, h / 2, axis);
        pose turn = pose_from_axis_angle(axis, (h % 2 ? 1 : -1) * reduce__tune.global_deg * PI / 180);
        cand[n++] = reduce__turned(&base, &turn, cm, cm);
        cand[n] = base;
        for (int a = 0; a < 3; a++)
            cand[n].t[a] += (h % 2 ? 1 : -1) * reduce__tune.global_mm * axis[a];
        n++;
    }
    *pa = -1;
    if (s->o->prealign) {
        *pa = n;
        cand[n++] = base;
    }
    return n;
}

/* One candidate fitted briefly: over the contact zone where it lies (on the coarse level when the
 * table says), slid into contact, a few evaluations, collisions not costed. 0, or <0 when it has
 * no contact zone (it is then dropped). */
static int global_fit(fit_state *s, const pose *cand, pose *end)
{
    objective *ob = &s->obj;
    s->moving->pose = *cand;
    int rc = stage_metric(s, 0, reduce__tune.global_coarse);
    if (rc == 0)
        rc = stage_approach(s);
    if (rc == 0) {
        double c[3], f;
        ob->metric = s->metric;
        ob->pc = NULL;
        ob->xtol = reduce__tune.global_xtol_mm;
        ob->cap = reduce__tune.global_evals;
        ob->start = s->moving->pose;
        reduce__centroid_world(s->moving, c);
        rc = fit_from(s, c, 0, end, &f);
        ob->cap = 0;
    }
    return rc;
}

/* One global candidate's fit, on a private copy of the fit's state (the moving piece's pose, the
 * candidate's metric and contact grid, the objective, collision queries without the caches), so
 * that the candidates run on o->threads threads, beside the local fit when the global check is
 * on, and each ends exactly where it would alone (the caches change no answer of a query, only
 * its speed). */
typedef struct cand_fit {
    pose start, end;
    reduce_voi v;   /* the contact zone where it ended */
    int rc;         /* 0; <0: no contact zone or not fitted (dropped), or FN_ENOMEM */
    side_spent sp;
} cand_fit;

/* The global stage's candidates and their fits: the state they start from (taken when they were
 * made; the workers copy it, never the fit's own, which the local fit goes on changing), the
 * threads. */
typedef struct cand_wave {
    fit_state tmpl;
    frag mv;           /* the moving piece at the placed pose (tmpl.moving) */
    reduce_result r;   /* tmpl.r */
    pose cand[GLOBAL_CANDIDATES];
    cand_fit c[GLOBAL_CANDIDATES];
    int n, pa;         /* pa: the pre-aligned candidate's index, or -1 */
    atomic_int next, stop;
    pthread_t th[REDUCE_THREADS_MAX];
    int nth;
} cand_wave;

/* The pre-aligned candidate (reduce__prealign from the placed pose, on the worker's copy): 0 and
 * *start set, or -1 where the pre-alignment kept the placed pose or failed (the candidate is
 * dropped, as if it had never been made). */
static int cand_prealign(fit_state *t, const pose *placed, pose *start)
{
    t->moving->pose = *placed;
    int changed = 0, rc = reduce__prealign(&t->col, t->bricks, t->o, &changed);
    *start = t->moving->pose;
    t->moving->pose = *placed;
    return rc == 0 && changed ? 0 : -1;
}

static void *cand_worker(void *arg)
{
    cand_wave *w = arg;
    side sd;
    fit_state *t = &sd.t;
    side_state(&sd, &w->tmpl);
    for (int k; (k = atomic_fetch_add(&w->next, 1)) < w->n;) {
        int i = w->pa < 0 ? k : k == 0 ? w->pa : k - 1; /* the pre-alignment first */
        cand_fit *c = &w->c[i];
        c->rc = -1;
        if (atomic_load(&w->stop))
            continue; /* the fit failed: the rest dropped */
        if (sd.o.cancel && atomic_load(sd.o.cancel)) { /* cancelled: the rest dropped */
            c->sp.cancelled = 1;
            continue;
        }
        side_begin(&sd, &w->tmpl);
        if (i == w->pa && (c->rc = cand_prealign(t, &w->mv.pose, &c->start)) != 0)
            continue;
        c->rc = global_fit(t, &c->start, &c->end);
        if (c->rc == 0 && !sd.o.has_voi) {
            sd.mv.pose = c->end;
            c->rc = zone_voi(t, reduce__tune.zone_delta_mm[1], &c->v);
        }
        side_take(&c->sp, t);
    }
    reduce_metric_free(t->metric);
    level_close(&t->coarse);
    return NULL;
}

/* The candidates made where the piece is now (global_candidates) and handed to o->threads - 1
 * worker threads (cand_worker), which start on them at once; cand_collect joins them. 0 or
 * FN_E* (no thread started then). */
static int cand_launch(fit_state *s, cand_wave *w)
{
    int rc = s->asm_pts.p ? 0 : reduce__cloud_new(&s->asm_pts, s->asm_, s->nasm);
    if (rc == 0 && !s->o->has_voi)
        rc = reduce__cloud_grid(&s->asm_pts); /* shared, read-only */
    if (rc)
        return rc;
    w->n = global_candidates(s, w->cand, &w->pa);
    memset(w->c, 0, sizeof w->c);
    for (int i = 0; i < w->n; i++)
        w->c[i].start = w->cand[i];
    side_template(&w->tmpl, s, &w->mv, &w->r);
    w->tmpl.obj.nowall = 1;
    atomic_store(&w->next, 0);
    atomic_store(&w->stop, 0);
    w->nth = side_threads(w->th, w->n, s->o, cand_worker, w);
    return 0;
}

/* This thread fits the candidates left (none when stop: the fit failed), the workers are joined,
 * and the candidates' evaluations, iterations and histories are added to the fit's, in their
 * order. 0 or FN_ENOMEM. */
static int cand_collect(fit_state *s, cand_wave *w, int stop)
{
    if (stop)
        atomic_store(&w->stop, 1);
    cand_worker(w);
    for (int t = 0; t < w->nth; t++)
        pthread_join(w->th[t], NULL);
    int rc = 0;
    s->global_evals = 0;
    for (int i = 0; i < w->n; i++) {
        cand_fit *c = &w->c[i];
        side_merge(s, &c->sp, &s->global_evals);
        if (c->rc == FN_ENOMEM && rc == 0)
            rc = fn_err_set(FN_ENOMEM, "reduce: out of memory for the global stage");
    }
    return rc;
}

/* The local fit stands (the global check found nothing better): the piece back at the last local
 * attempt's end, over that attempt's VOI and metric, as stage_winner expects them (the metric the
 * local fit ended with when it is over that VOI: the candidates ran on copies). */
static int local_stands(fit_state *s)
{
    int last = s->attempts - 1;
    s->nkeep = 0;
    s->keep_pa = -1;
    s->moving->pose = s->attempt_end[last];
    if (s->metric && !memcmp(&s->r->voi, &s->attempt_voi[last], sizeof s->r->voi))
        return 0;
    s->r->voi = s->attempt_voi[last];
    reduce_metric_free(s->metric);
    s->metric = fine_metric(s, &s->r->voi);
    return s->metric ? 0 : FN_EINVAL;
}

/* The global stage: every candidate fitted briefly, their ends scored by the metric over the union
 * of the contact zones where they ended (the same cells for all), the best kept, and the next
 * distinct one too when it scores within global_margin of it. Where the local fit left ends off
 * the wall (the global check), a candidate is kept only if it beats the best of them over those
 * cells; if none does, the local fit stands (local_stands) and nothing is refined. Measured (bench
 * reduce --labels --starts 40, every candidate refined): 94 of 120 checks found none better, and in
 * none of those did the refinement bring back a fit that the local fit had missed. Its
 * evaluations do not count against o->max_eval (they are reported with the others). */
static int stage_global(fit_state *s, const cand_wave *w)
{
    const reduce_tuning *T = &reduce__tune;
    objective *ob = &s->obj;
    pose end[GLOBAL_CANDIDATES], base = s->moving->pose;
    double score[GLOBAL_CANDIDATES];
    int pa = w->pa, n = w->n, nok = 0;
    reduce_voi u = {{INFINITY, INFINITY, INFINITY}, {-INFINITY, -INFINITY, -INFINITY}};
    for (int i = 0; i < n; i++) {
        end[i] = w->c[i].end;
        score[i] = INFINITY;
        if (w->c[i].rc == 0) {
            score[i] = 0;
            nok++;
            if (!s->o->has_voi)
                voi_join(&u, &w->c[i].v);
        }
    }
    if (!ob->cancelled && nok == 0 && s->attempts > 0)
        return local_stands(s);
    if (ob->cancelled || nok == 0) {
        s->keep[0] = base; /* nothing ranked: the fit goes on from the placed pose */
        s->nkeep = 1;
        s->keep_pa = -1;
        return 0;
    }
    reduce_metric *mu = fine_metric(s, s->o->has_voi ? &s->o->voi : &u);
    if (!mu)
        return FN_EINVAL;
    for (int i = 0; i < n; i++)
        if (score[i] == 0)
            score[i] = reduce_metric_eval(mu, &end[i], NULL);
    double local = INFINITY; /* the local fit's best end there (none: every end was on the wall) */
    for (int i = 0; i < s->attempts; i++)
        local = fmin(local, reduce_metric_eval(mu, &s->attempt_end[i], NULL));
    reduce_metric_free(mu);
    int best = 0;
    for (int i = 1; i < n; i++)
        if (score[i] < score[best])
            best = i;
    if (!(score[best] < local))
        return local_stands(s);
    s->keep[0] = end[best];
    s->nkeep = 1;
    s->keep_pa = best == pa ? 0 : -1;
    while (s->nkeep < T->global_keep) {
        int next = -1;
        for (int i = 0; i < n; i++) {
            int distinct = score[i] < score[best] + T->global_margin && score[i] < local;
            for (int k = 0; k < s->nkeep && distinct; k++)
                distinct = apart(s, &end[i], &s->keep[k]);
            if (distinct && (next < 0 || score[i] < score[next]))
                next = i;
        }
        if (next < 0)
            break;
        if (next == pa)
            s->keep_pa = s->nkeep;
        s->keep[s->nkeep++] = end[next];
    }
    return 0;
}

/* The starts of a stage, [*k0, *n): 0 the base, k > 0 the base turned start_deg about principal
 * axis (k - 1) / 2 % 3, either way. The first stage starts o->starts times; a second attempt
 * turns about the other two axes, a third wider about all three; a later stage starts once. */
static void start_range(const reduce_opts *o, int stage, int attempt, int *k0, int *n)
{
    *k0 = 0;
    *n = stage == 0 && o->starts > 1 ? o->starts : 1;
    if (attempt == 1 && stage == 0) {
        *k0 = *n > 1 ? *n : 1;
        *n = *k0 + 4;
    } else if (attempt == 2 && stage == 0) {
        *k0 = 1;
        *n = 7;
    }
}

/* The starts of one stage, each fitted; the piece moves to the best end. The first stage stops
 * coarser and refuses no collision; later ones (and a given VOI's one) cost a colliding pose. */
static int stage_starts(fit_state *s, int stage, int attempt)
{
    const reduce_opts *o = s->o;
    objective *ob = &s->obj;
    ob->metric = s->metric;
    ob->pc = stage >= (o->has_voi ? 0 : 1) ? &s->col : NULL;
    ob->xtol = ob->pc ? o->xtol_mm : reduce__tune.first_xtol * o->xtol_mm;
    pose base = s->moving->pose, best = base;
    double bestf = INFINITY;
    int k0, nstarts, rc = 0;
    start_range(o, stage, attempt, &k0, &nstarts);
    for (int k = k0; k < nstarts && rc == 0 && !ob->cancelled; k++) {
        ob->start = base;
        if (k > 0) {
            double axis[3], cm[3];
            reduce__axis_world(s->moving, (k - 1) / 2 % 3, axis);
            double deg = (k % 2 ? 1 : -1) * (attempt == 2 ? reduce__tune.wide_starts : 1) * reduce__tune.start_deg;
            pose turn = pose_from_axis_angle(axis, deg * PI / 180);
            reduce__centroid_world(s->moving, cm);
            ob->start = reduce__turned(&base, &turn, cm, cm);
        }
        double c[3], f;
        pose end;
        reduce__centroid_world(s->moving, c);
        rc = fit_from(s, c, 1, &end, &f);
        if (rc == 0 && stage == 0 && attempt == 0 && s->refine == 0 && k < REDUCE_STARTS_SEEN) {
            s->start_end[k] = end;
            s->start_cost[k] = f;
            s->nstart_ends = k + 1;
        }
        if (rc == 0 && f < bestf) {
            bestf = f;
            best = end;
        }
    }
    s->moving->pose = best;
    pose_normalize(&s->moving->pose);
    return rc;
}

static double voi_volume(const reduce_voi *v)
{
    return (v->hi[0] - v->lo[0]) * (v->hi[1] - v->lo[1]) * (v->hi[2] - v->lo[2]);
}

/* 1 when the contact zone where the piece ended is zone_grow times larger than the VOI it was fitted
 * over: a first stage off the fit touches along part of the fracture only, and the next stage then
 * fits to that part; where the zone has grown, the fit goes again over it. */
static int zone_grew(fit_state *s)
{
    reduce_voi now;
    return zone_voi(s, reduce__tune.zone_delta_mm[1], &now) == 0 &&
           voi_volume(&now) > reduce__tune.zone_grow * voi_volume(&s->r->voi);
}

/* One attempt: two stages unless the VOI is given (the first over the contact zone where the hand
 * left the piece, the second over the tighter zone where the first ended), and up to
 * zone_grow_stages more while the zone grows. */
static int attempt_stages(fit_state *s, int attempt)
{
    const reduce_opts *o = s->o;
    int nstage = o->has_voi ? 1 : 2, rc = 0;
    for (int stage = 0; stage < nstage && rc == 0 && !s->obj.cancelled; stage++) {
        if ((rc = stage_metric(s, stage, o->coarse)) != 0)
            break;
        if (stage == 0 && (rc = stage_approach(s)) != 0)
            break;
        rc = stage_starts(s, stage, attempt);
        if (rc == 0 && !o->has_voi && stage == nstage - 1 && nstage < 2 + reduce__tune.zone_grow_stages &&
            !s->obj.cancelled && zone_grew(s))
            nstage++;
    }
    return rc;
}

/* Each kept candidate refined (after the global stage): attempts from it. A fit that ends in
 * collision has wandered off (a wrong basin; the true pose collides with nothing): another
 * attempt from the candidate, turned otherwise. */
static int stage_attempts(fit_state *s)
{
    int rc = 0;
    for (s->refine = 0; s->refine < s->nkeep && rc == 0 && !s->obj.cancelled; s->refine++)
        for (int attempt = 0; attempt < ATTEMPTS && rc == 0 && !s->obj.cancelled; attempt++) {
            if (attempt) {
                int c = at_wall(&s->obj, &s->moving->pose) ? 1 : reduce__collides(&s->col, &s->moving->pose, NULL);
                if (c <= 0) {
                    rc = c;
                    break;
                }
            }
            s->moving->pose = s->keep[s->refine];
            rc = attempt_stages(s, attempt);
            if (rc == 0) {
                s->attempt_end[s->attempts] = s->moving->pose;
                s->attempt_from[s->attempts] = s->refine;
                s->attempt_voi[s->attempts++] = s->r->voi;
            }
        }
    return rc;
}

/* The local fit: attempts from where the hand left the piece, within the trust region; another
 * after one that ended colliding or on the trust wall (up to three; the winner: stage_winner).
 * When the first ends on the wall, the piece has left the basin the hand put it in: 1, and the
 * global stage takes over, its refined candidates ranked with the retries' ends that stayed off
 * the wall (the ends on it are dropped). Else 0, or <0 on error. Measured (bench reduce --suite,
 * 20 fits a workload): handing over after a colliding first attempt too lost fits that those
 * retries find (CT_pitch 0.90 -> 0.70, 3 pieces 1.00 -> 0.85); handing over only where all three
 * ended on the wall or colliding kept retries that stood in wrong basins (starts up to 20 mm:
 * 0.25, against 0.55 with this rule). Handing over with no retries lost real pieces that they
 * bring back (bench reduce --labels, 005_RI alone, 20 starts: 0.75, 0.85 with them; the retries'
 * evaluations must not eat the global stage's budget: with them counted, the far starts fell from
 * 0.55 to 0.40). */
static int stage_local(fit_state *s)
{
    int rc = 0, walled = 0, evals1 = 0;
    for (int attempt = 0; attempt < ATTEMPTS && rc == 0 && !s->obj.cancelled; attempt++) {
        if (attempt) {
            int wall = at_wall(&s->obj, &s->moving->pose);
            int c = wall ? 1 : reduce__collides(&s->col, &s->moving->pose, NULL);
            if (attempt == 1) {
                walled = wall;
                evals1 = s->obj.evals;
            }
            if (c <= 0) {
                rc = c;
                break;
            }
        }
        s->moving->pose = s->r->start;
        rc = attempt_stages(s, attempt);
        if (rc == 0) {
            s->attempt_end[s->attempts] = s->moving->pose;
            s->attempt_from[s->attempts] = FROM_LOCAL;
            s->attempt_voi[s->attempts++] = s->r->voi;
        }
    }
    if (rc == 0 && walled) {
        int n = 0; /* an end on the wall left the basin: no answer */
        for (int i = 0; i < s->attempts; i++)
            if (!at_wall(&s->obj, &s->attempt_end[i])) {
                s->attempt_end[n] = s->attempt_end[i];
                s->attempt_from[n] = s->attempt_from[i];
                s->attempt_voi[n++] = s->attempt_voi[i];
            }
        s->attempts = n;
        s->retry_evals = s->obj.evals - evals1;
        s->obj.evals = evals1;
        s->moving->pose = s->r->start;
        return 1;
    }
    return rc;
}

/* Several attempts: the end of best metric over the union of their VOIs wins, collisions costed;
 * the final metric is then the winner's. The free ends of other kept candidates that score within
 * rival_metric of the winner but lie apart from it are rival answers (s->rival_end). */
static int stage_winner(fit_state *s)
{
    s->nrival_ends = 0;
    if (s->attempts < 2) {
        s->r->prealigned |= s->attempts == 1 && s->keep_pa == 0;
        return 0;
    }
    reduce_voi u = s->attempt_voi[0];
    for (int i = 1; i < s->attempts; i++)
        voi_join(&u, &s->attempt_voi[i]);
    reduce_metric *mu = fine_metric(s, &u);
    int rc = mu ? 0 : FN_EINVAL, w = s->attempts - 1;
    double fbest = INFINITY, fu[ENDS];
    for (int i = 0; i < s->attempts && rc == 0; i++) {
        int c = reduce__collides(&s->col, &s->attempt_end[i], NULL);
        fu[i] = reduce_metric_eval(mu, &s->attempt_end[i], NULL) + (c > 0 ? reduce__tune.collide_cost : 0);
        rc = c < 0 ? c : 0;
        if (fu[i] < fbest) {
            fbest = fu[i];
            w = i;
        }
    }
    reduce_metric_free(mu);
    s->moving->pose = s->attempt_end[w];
    s->r->voi = s->attempt_voi[w];
    s->r->prealigned |= s->attempt_from[w] == s->keep_pa;
    for (int i = 0; i < s->attempts && rc == 0; i++) {
        int distinct = s->attempt_from[i] != s->attempt_from[w] && fu[i] < fbest + reduce__tune.rival_metric;
        for (int k = 0; k < s->nrival_ends && distinct; k++)
            distinct = apart(s, &s->attempt_end[i], &s->rival_end[k]);
        if (distinct && s->nrival_ends == 0)
            s->rival_end[s->nrival_ends++] = s->attempt_end[w];
        if (distinct && apart(s, &s->attempt_end[i], &s->attempt_end[w]))
            s->rival_end[s->nrival_ends++] = s->attempt_end[i];
    }
    s->nrival_ends -= s->nrival_ends == 1; /* the winner alone: no rival */
    if (rc == 0 && w != s->attempts - 1) {
        reduce_metric_free(s->metric);
        if (!(s->metric = fine_metric(s, &s->r->voi)))
            rc = FN_EINVAL;
    }
    return rc;
}

/* A rival: a start of the first stage that ends about as well as the best one (within
 * rival_metric) but farther than rival_mm or rival_deg from it. The metric has rival basins
 * there, and the fit may sit in the wrong one without touching the trust wall or colliding. The
 * winner's rivals among the kept candidates (stage_winner) count too. */
static void stage_rivals(fit_state *s)
{
    const reduce_tuning *T = &reduce__tune;
    int best = 0;
    for (int k = 1; k < s->nstart_ends; k++)
        if (s->start_cost[k] < s->start_cost[best])
            best = k;
    s->nrival_of = 0;
    for (int k = 0; k < s->nstart_ends; k++)
        if (k != best && s->start_cost[k] < s->start_cost[best] + T->rival_metric &&
            apart(s, &s->start_end[k], &s->start_end[best])) {
            s->rival_of[0] = best;
            s->rival_of[++s->nrival_of] = k;
        }
    s->nrival_of += s->nrival_of > 0;
    s->r->rival = s->nrival_of > 0 || s->nrival_ends > 0;
}

/* With rivals, the candidates, each with its metric over the final VOI (beside metric_end): the
 * winner and its rivals among the kept candidates, else the best first-stage end and the rival
 * ones. */
static void keep_candidates(fit_state *s)
{
    reduce_result *r = s->r;
    r->ncandidates = s->nrival_ends ? s->nrival_ends : s->nrival_of;
    for (int i = 0; i < r->ncandidates; i++) {
        r->candidate[i].pose = s->nrival_ends ? s->rival_end[i] : s->start_end[s->rival_of[i]];
        r->candidate[i].metric = reduce_metric_eval(s->metric, &r->candidate[i].pose, NULL);
    }
}

/* 1 for a long piece: its largest principal variance hop_elongation times the next. */
static int piece_is_long(const fit_state *s)
{
    return s->moving->eigval[0] > reduce__tune.hop_elongation * s->moving->eigval[1];
}

/* One round of hops from cur (cost fcur); *next, *fnext: the best end that beats fnext by margin
 * (left as they are when none does). Not strict (a long piece): the fit again from cur turned
 * hop_deg either way about each principal axis of the piece. strict: from cur moved hop_mm either
 * way along each, each hop a short fit (the first stage's coarser step, first_xtol, and at most
 * hop_evals evaluations), the best one then fitted to the full step from where it stopped; an end
 * counts only free of collision, by its metric alone. */
/* Hop h's start: the pose cur turned hop_deg either way about a principal axis (h < HOP_TURNS), or
 * moved hop_mm either way along one; *c its centroid (world). s->moving->pose is left there. */
static pose hop_start(fit_state *s, const pose *cur, int h, double c[3])
{
    const reduce_tuning *T = &reduce__tune;
    double axis[3], cm[3], sign = h % 2 ? 1 : -1;
    pose start = *cur;
    s->moving->pose = *cur;
    reduce__axis_world(s->moving, h % HOP_TURNS / 2, axis);
    reduce__centroid_world(s->moving, cm);
    if (h < HOP_TURNS) { /* a turn */
        pose turn = pose_from_axis_angle(axis, sign * T->hop_deg * PI / 180);
        start = reduce__turned(cur, &turn, cm, cm);
    } else /* a move */
        for (int a = 0; a < 3; a++)
            start.t[a] += sign * T->hop_mm * axis[a];
    s->moving->pose = start;
    reduce__centroid_world(s->moving, c);
    return start;
}

/* One strict hop's fit (hop_moves), on a private copy of the fit's state as the global stage's
 * candidates run: where it ended, and its metric there (a colliding end: INFINITY). */
typedef struct hop_fit {
    pose start, end;
    double c[3], f;
    int rc;
    side_spent sp;
} hop_fit;

typedef struct hop_wave {
    fit_state tmpl;  /* the fit's state at the round's start */
    const reduce_metric *shared; /* its metric, read-only while the moves run */
    frag mv;
    reduce_result r;
    hop_fit h[HOP_TURNS];
    atomic_int next;
    pthread_t th[REDUCE_THREADS_MAX];
    int nth;
} hop_wave;

static void *hop_worker(void *arg)
{
    hop_wave *w = arg;
    side sd;
    fit_state *t = &sd.t;
    side_state(&sd, &w->tmpl);
    t->metric = reduce__metric_share(w->shared); /* a band of its own */
    for (int i; (i = atomic_fetch_add(&w->next, 1)) < HOP_TURNS;) {
        hop_fit *h = &w->h[i];
        if (!t->metric) {
            h->rc = FN_ENOMEM;
            continue;
        }
        if (sd.o.cancel && atomic_load(sd.o.cancel)) {
            h->sp.cancelled = 1;
            continue;
        }
        side_begin(&sd, &w->tmpl);
        t->obj.metric = t->metric;
        t->obj.pc = &t->col;
        t->obj.start = h->start;
        sd.mv.pose = h->start;
        h->rc = fit_from(t, h->c, 0, &h->end, &h->f);
        if (h->rc == 0) {
            int hit = reduce__collides(&t->col, &h->end, NULL);
            h->rc = hit < 0 ? hit : 0;
            h->f = hit ? INFINITY : reduce_metric_eval(t->metric, &h->end, NULL);
        }
        side_take(&h->sp, t);
    }
    reduce_metric_free(t->metric);
    return NULL;
}

/* A strict round's six moves, each fitted briefly (s->obj's step and cap), on o->threads threads
 * (hop_worker: each move on its own copy of the state, with a band of its own and collision
 * queries without the caches, so each ends where it would alone); their evaluations, iterations
 * and histories are added to the fit's in their order, and the best that beats *fbest by margin
 * (colliding ends never) goes into *best, *fbest. 0 or <0. */
static int hop_moves(fit_state *s, const pose *cur, double margin, pose *best, double *fbest)
{
    hop_wave *w = calloc(1, sizeof *w);
    if (!w)
        return fn_err_set(FN_ENOMEM, "reduce: out of memory for the hops");
    for (int i = 0; i < HOP_TURNS; i++)
        w->h[i].start = hop_start(s, cur, HOP_TURNS + i, w->h[i].c);
    s->moving->pose = *cur;
    side_template(&w->tmpl, s, &w->mv, &w->r);
    w->shared = s->metric;
    atomic_store(&w->next, 0);
    w->nth = side_threads(w->th, HOP_TURNS, s->o, hop_worker, w);
    hop_worker(w);
    for (int i = 0; i < w->nth; i++)
        pthread_join(w->th[i], NULL);
    int rc = 0;
    for (int i = 0; i < HOP_TURNS; i++) {
        hop_fit *h = &w->h[i];
        int cancelled = h->sp.cancelled;
        side_merge(s, &h->sp, &s->obj.evals);
        if (rc == 0 && h->rc < 0)
            rc = h->rc;
        if (rc == 0 && !cancelled && h->f < *fbest - margin) {
            *fbest = h->f;
            *best = h->end;
        }
    }
    free(w);
    return rc;
}

static int hop_round(fit_state *s, const pose *cur, int strict, double margin, pose *next, double *fnext)
{
    const reduce_tuning *T = &reduce__tune;
    objective *ob = &s->obj;
    double xtol = ob->xtol, fbest = *fnext;
    pose best = *cur;
    int rc = 0;
    if (strict) { /* moves */
        ob->xtol = T->first_xtol * xtol;
        ob->cap = T->hop_evals;
        rc = hop_moves(s, cur, margin, &best, &fbest);
    }
    for (int h = 0; !strict && h < HOP_TURNS && rc == 0 && !ob->cancelled; h++) { /* turns */
        double c[3], fb;
        pose hp;
        ob->start = hop_start(s, cur, h, c);
        rc = fit_from(s, c, 0, &hp, &fb);
        if (rc == 0 && fb < fbest - margin) {
            fbest = fb;
            best = hp;
        }
    }
    ob->xtol = xtol;
    ob->cap = 0;
    if (rc == 0 && strict && fbest < *fnext - margin && !ob->cancelled) { /* the best, to the full step */
        double c[3], fb;
        pose hp;
        ob->start = best;
        s->moving->pose = best;
        reduce__centroid_world(s->moving, c);
        if ((rc = fit_from(s, c, 0, &hp, &fb)) == 0) {
            best = hp;
            fbest = reduce_metric_eval(s->metric, &hp, NULL);
            int hit = reduce__collides(&s->col, &hp, NULL);
            if (hit < 0)
                rc = hit;
            else if (hit)
                fbest = INFINITY;
        }
    }
    if (rc == 0 && fbest < *fnext - margin) {
        *fnext = fbest;
        *next = best;
    }
    return rc;
}

/* Hops: the fit again from turns or moves of its result, the best kept while a round gains (up to
 * o->hops rounds). A long piece: a cut through a tube is nearly symmetric under a turn about its
 * axis and the metric ripples in the turns (bench reduce --ct long-bone: fits stopped 4-12 degrees
 * off); it hops by turns, colliding poses costed. Any other piece: the metric's basin on a real
 * fracture surface is narrow and rippled, and a fit can stop a degree or two and a millimetre or
 * two off, where the true pose scores better (bench reduce --labels, the pelvic development set's
 * real pieces: 5 of the 7 fits not back stopped so); it hops by short moves, strictly (see
 * hop_round): a fit that ends interpenetrating (to be pushed out) costs collide_cost, and any free
 * pose nearby would beat that (hopping with the plain rule: CT_pitch success 0.90 -> 0.80). Measured
 * (docs/benchmarks.md): back_rate 0.77 -> 0.90 for 10-30% more CPU a fit. */
static int stage_hops(fit_state *s)
{
    const reduce_opts *o = s->o;
    objective *ob = &s->obj;
    int is_long = piece_is_long(s);
    if (ob->cancelled || o->hops <= 0)
        return 0;
    ob->metric = s->metric;
    ob->pc = &s->col;
    ob->xtol = o->xtol_mm;
    pose cur = s->moving->pose;
    double fcur = cost_at(ob, &cur); /* its collision query also primes the cache */
    int strict = !is_long, rc = 0;
    double margin = strict ? reduce__tune.hop_margin : reduce__tune.long_margin;
    if (strict)
        fcur = reduce_metric_eval(s->metric, &cur, NULL);
    for (int round = 0; round < o->hops && rc == 0 && !ob->cancelled; round++) {
        pose next = cur;
        double fnext = fcur;
        rc = hop_round(s, &cur, strict, margin, &next, &fnext);
        if (!(fnext < fcur - margin))
            break;
        cur = next;
        s->r->hops++;
        pose_normalize(&cur);
        fcur = fnext;
    }
    s->moving->pose = cur;
    return rc;
}

/* The polish: the result moved to the best pose nearby by the count at the nearest cell
 * (REDUCE_NEAREST) over the final VOI, collisions costed, by a compass search (each parameter
 * stepped either way, polish_step halving down the table, up to polish_sweeps sweeps a step).
 * The trilinear count the fit runs on is smooth but blurs the moved piece over eight cells, and
 * where its voxel grid is turned from the fixed piece's (a displaced piece segmented from the CT)
 * that blur overlaps the fixed bone at the true pose: the fit's optimum then lies a few tenths of
 * a millimetre along the fracture surface from it, a degree or more where the surface is flat
 * (bench reduce --intact: 001_SA's fourth fracture, fits from the truth ended 1.2 degrees off).
 * The nearest count has no blur (at the true pose the two pieces share no cell) but is piecewise
 * constant, which stalls the line searches; from the fit's end, a compass search suffices. Not for
 * a tube: a long piece (see piece_is_long) whose cross-section is round (second principal variance
 * under polish_round times the third) is nearly symmetric under a turn about its axis, and there
 * the nearest count's steps, where the two grids line up, lead the turn (bench reduce --ct
 * long-bone, variances 1.5-1.6 times: success 0.55 -> 0.40 with the polish). A flat long piece is
 * polished (the sacrum's fracture above: 2.5 times). Measured (docs/benchmarks.md): the skull's
 * median errors 0.147 degrees / 0.120 mm -> 0.017 / 0.020, the intact pelvic bones' success 0.92
 * -> 1.00. */
static int stage_polish(fit_state *s)
{
    const reduce_opts *o = s->o;
    const reduce_tuning *T = &reduce__tune;
    objective *ob = &s->obj;
    const double *ev = s->moving->eigval;
    if (ob->cancelled || !o->polish || !s->metric || (piece_is_long(s) && ev[1] < T->polish_round * ev[2]))
        return 0;
    reduce_metric *mn = s->metric; /* the final VOI's, counted nearest for the polish */
    reduce_count fit_count = reduce__metric_count(mn, REDUCE_NEAREST);
    ob->metric = mn;
    ob->pc = &s->col;
    ob->start = s->moving->pose;
    ob->best = INFINITY;
    double x[6] = {0};
    reduce__centroid_world(s->moving, ob->c);
    int rc = reduce__metric_rebase(mn, &ob->start) < 0 ? FN_ENOMEM : 0;
    if (rc == 0) {
        set_scale(ob, mn);
        double f = cost(x, ob);
        for (int l = 0; l < REDUCE_POLISH_STEPS && !ob->cancelled; l++)
            for (int sweep = 0, gained = 1; gained && sweep < T->polish_sweeps && !ob->cancelled; sweep++) {
                gained = 0;
                for (int d = 0; d < 12; d++) {
                    double y[6];
                    memcpy(y, x, sizeof y);
                    y[d / 2] += (d % 2 ? 1 : -1) * T->polish_step[l];
                    double fy = cost(y, ob);
                    if (fy < f) {
                        f = fy;
                        memcpy(x, y, sizeof x);
                        gained = 1;
                    }
                }
            }
        s->moving->pose = pose_of(ob, x);
        pose_normalize(&s->moving->pose);
    }
    reduce__metric_count(mn, fit_count);
    return rc;
}

/* The result: out of collision (reduce__resolve_collision), with both metrics over the final VOI,
 * or, on failure or cancel, the placed pose. */
static int stage_finish(fit_state *s, int rc)
{
    reduce_result *r = s->r;
    if (rc == 0 && s->obj.cancelled)
        rc = 1;
    if (rc == 0) {
        r->end = r->fitted = s->moving->pose;
        rc = reduce__resolve_collision(&s->col, s->metric, s->o->settle_mm, r);
    }
    if (rc == 0) {
        r->metric_start = reduce_metric_eval(s->metric, &r->start, NULL); /* both over the final VOI */
        r->metric_end = reduce_metric_eval(s->metric, &r->end, NULL);
        /* a fit never keeps an end worse than a free start */
        if (r->metric_end > r->metric_start && (rc = reduce__collides(&s->col, &r->start, NULL)) == 0) {
            r->end = r->fitted = r->start;
            r->metric_end = r->metric_start;
            r->push_mm = 0;
            r->collides = 0;
        }
        rc = rc < 0 ? rc : 0;
    }
    if (rc == 0) {
        s->moving->pose = r->end;
        keep_candidates(s);
        r->evaluations = s->obj.evals + s->global_evals + s->retry_evals;
        r->eval_cpu_s = (double)s->obj.eval_ns * 1e-9;
        r->history = s->obj.hist;
        r->nhistory = s->obj.nhist;
        s->obj.hist = NULL;
    } else {
        s->moving->pose = r->end = r->fitted = r->placed;
    }
    r->seconds = now_s() - s->obj.t0;
    return rc;
}

static void stage_close(fit_state *s)
{
    free(s->obj.hist);
    reduce_metric_free(s->metric);
    reduce__bricks_free(s->bricks);
    reduce__cloud_free(&s->asm_pts);
    level_close(&s->coarse);
    reduce__collider_close(&s->col);
}

int reduce_pair(const frag *const *asm_, int nasm, frag *moving, const reduce_opts *o, reduce_result *r)
{
    if (!asm_ || nasm < 1 || !moving || !o || !r)
        return fn_err_set(FN_EINVAL, "reduce: no fragments");
    fit_state s;
    cand_wave w;
    int rc = stage_open(&s, asm_, nasm, moving, o, r), launched = 0;
    if (rc == 0)
        rc = stage_start(&s);
    /* the global check, around where the hand left the piece (not for a long piece: see
     * reduce_opts.global_check): its candidates start on the other threads beside the local fit */
    int check = rc == 0 && o->global_check && !piece_is_long(&s);
    if (check && (rc = cand_launch(&s, &w)) == 0)
        launched = 1;
    if (rc == 0)
        rc = stage_local(&s);
    if (rc == 0 && check && !s.obj.cancelled)
        rc = 1;
    if (rc == 1 && !launched && (rc = cand_launch(&s, &w)) == 0) { /* the wall, without the check */
        launched = 1;
        rc = 1;
    }
    if (launched) {
        int rc2 = cand_collect(&s, &w, rc < 0);
        rc = rc < 0 ? rc : rc2 < 0 ? rc2 : rc;
    }
    if (rc == 1) {
        s.moving->pose = s.r->start;
        s.obj.nowall = 1;
        rc = stage_global(&s, &w);
        if (rc == 0)
            rc = stage_attempts(&s);
    }
    if (rc == 0)
        rc = stage_winner(&s);
    stage_rivals(&s);
    if (rc == 0)
        rc = stage_hops(&s);
    if (rc == 0)
        rc = stage_polish(&s);
    rc = stage_finish(&s, rc);
    stage_close(&s);
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
