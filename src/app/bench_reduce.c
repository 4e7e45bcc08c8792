/* fracnav bench reduce: automatic reduction on synthetic fractures of the example CT, from starts
 * perturbed as a hand would leave them, per method: success rate, errors, time, metric cost. */
#include "bench.h"

#include "case.h"
#include "cmd.h"
#include "err.h"
#include "fracture.h"
#include "jsonw.h"
#include "obb.h"
#include "morph.h"
#include "reduce.h"
#include "seg.h"
#include "volio.h"

#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define MAX_CONFIGS 8

typedef struct opts {
    int seeds, starts, json, verbose;
    double max_mm, max_deg, band_mm, voi_max_mm, tolerance_mm, settle_mm, trust_mm, trust_deg;
    int fit_starts, coarse, axis_scale, no_polish, no_global_check;
    int pieces, threshold_auto, touching, suite, whole_bone, whole_case;
    int model;            /* fracture_params.model */
    int labels, intact;   /* --labels DIR, --intact DIR: workloads of the real bones in data_dir */
    const char *data_dir; /* NULL: $FRACNAV_DATA/pelvis-dev (the suite's) */
    double threshold, bone_loss_mm, gap_mm;
    int nconf;
    reduce_method method[MAX_CONFIGS];
    reduce_count count[MAX_CONFIGS];
    const char *ct;
} opts;

typedef struct sample {
    double rot, trans, tre, cpu_s, wall_s, metric_end, metric_truth, eval_cpu_s;
    int evals;
} sample;

/* A long bone, made here: a bowed shaft 154 mm long of elliptic section (semi-axes 10-14 mm by
 * 8-11 mm, flaring at the ends), a 3 mm textured cortex (1000-1400 HU) around a medullary canal
 * (40 HU), in soft tissue (-50 HU), on a 0.7 mm grid. Asymmetric enough that no turn about its
 * axis maps it onto itself. */
static vol *long_bone(void)
{
    const int nx = 220, ny = 60, nz = 56;
    vol *v = vol_new(nx, ny, nz);
    if (!v)
        return NULL;
    const double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, sp[3] = {0.7, 0.7, 0.7}, org[3] = {-77, -21, -19.6};
    vol_set_geometry(v, dir, sp, org);
    for (int i = 0; i < nx; i++) {
        double u = (i - 0.5 * nx) / (0.5 * nx), flare = u * u * u * u;
        double a = 10 + 4 * flare, b = 8 + 3 * flare;                 /* mm */
        double cy = 2.5 * sin(M_PI * (i / (double)nx)), cz = 1.5 * u; /* the bow, mm */
        for (int k = 0; k < nz; k++)
            for (int j = 0; j < ny; j++) {
                double y = (j - 0.5 * ny) * sp[1] - cy, z = (k - 0.5 * nz) * sp[2] - cz;
                double r = sqrt((y / a) * (y / a) + (z / b) * (z / b));
                double inner = 1 - 3 / (0.5 * (a + b)); /* 3 mm of cortex */
                float val = -50;
                if (r <= 1)
                    val = r >= inner ? (float)(1000 + (i * 7 + j * 13 + k * 3) % 400) : 40;
                v->data[vol_idx(v, i, j, k)] = val;
            }
    }
    v->src_type = VOL_I16;
    return v;
}

/* Mean time of one evaluation of a cubic VOI of n cells a side around the fracture, at the truth. */
static double eval_us(const frag *f, const frag *m, const pose *truth, const reduce_voi *zone, int n,
                      reduce_count mode)
{
    reduce_voi v;
    for (int a = 0; a < 3; a++) {
        double c = 0.5 * (zone->lo[a] + zone->hi[a]), h = 0.5 * n * f->spacing[a];
        v.lo[a] = c - h;
        v.hi[a] = c + h - 1e-6;
    }
    const frag *asm_[1] = {f};
    frag mm = *m;
    reduce_metric *me = reduce_metric_new(asm_, 1, &mm, &v, mode, 3);
    if (!me)
        return NAN;
    int reps = 200;
    double sink = 0, t0 = bench_cpu_us();
    for (int i = 0; i < reps; i++) {
        pose p = *truth;
        p.t[0] += 0.001 * i;
        sink += reduce_metric_eval(me, &p, NULL);
    }
    double us = (bench_cpu_us() - t0) / reps;
    reduce_metric_free(me);
    return isfinite(sink) ? us : NAN;
}

/* The moving piece's voxel grid (at pose p) against the fixed piece's: its turn about the fixed
 * piece's long axis and across it, in degrees, into turn[0] and turn[1]. The voxel count favours
 * poses where the grids line up: a fit whose turn across is near 0 while the truth's is not has
 * snapped to the fixed grid. */
static void grid_turn(const frag *f, const frag *m, const pose *p, double turn[2])
{
    double ax[3] = {f->axes[0][0], f->axes[1][0], f->axes[2][0]}, axg[3], rv[3], d = 0, c2 = 0;
    pose ginv = pose_inverse(f->home);
    pose_rotate(&ginv, ax, axg);
    pose rel = pose_compose(pose_inverse(pose_compose(f->pose, f->home)), pose_compose(*p, m->home));
    pose_to_rotvec(&rel, rv);
    for (int a = 0; a < 3; a++)
        d += rv[a] * axg[a];
    for (int a = 0; a < 3; a++)
        c2 += (rv[a] - d * axg[a]) * (rv[a] - d * axg[a]);
    turn[0] = fabs(d) * 180 / M_PI;
    turn[1] = sqrt(c2) * 180 / M_PI;
}

typedef struct config_stats {
    sample *s;
    int n;
    double eval_us;
    double separate_dice, separate_s; /* the touching workload's separation (in cs[0]) */
    double *case_cpu_s, *case_wall_s;  /* --whole-case: per case, every thread's CPU and the wall */
    int ncase, nskipped, ncase_back;   /* --whole-case: cases, pieces left out, cases all back */
} config_stats;

/* Touching pieces as a user meets them: the fractured CT thresholded (the component that holds
 * the pieces), separated (edit separate's morph_separate), and each true piece replaced in
 * fr->labels by the separated piece that matches it best; the worst of those Dice goes to cs. */
static int separate_pieces(fracture_result *fr, int pieces, config_stats *cs)
{
    size_t n = vol_count(fr->ct);
    uint8_t *mask = malloc(n);
    int32_t *comp = malloc(n * sizeof *comp), *lab = malloc(n * sizeof *lab);
    int rc = mask && comp && lab ? 0 : fn_err_set(FN_ENOMEM, "bench reduce: out of memory");
    int nc = 0, pick = 0, np = 0;
    if (rc == 0) {
        for (size_t i = 0; i < n; i++)
            mask[i] = fr->ct->data[i] >= fr->threshold;
        rc = nc = seg_components(mask, fr->ct->dim, comp);
    }
    if (rc > 0) { /* the component under piece 1's first voxel holds the pieces */
        for (size_t i = 0; i < n && !pick; i++)
            if (fr->labels->data[i] == 1 && comp[i])
                pick = comp[i];
        for (size_t i = 0; i < n; i++)
            mask[i] = comp[i] == pick && pick;
        double t0 = bench_cpu_us();
        rc = np = morph_separate(mask, fr->ct->dim, fr->ct->spacing, 0, NULL, 0, 27, lab, NULL);
        cs->separate_s += (bench_cpu_us() - t0) * 1e-6;
    }
    double worst = 1;
    int *match = rc > 0 ? calloc((size_t)pieces + 1, sizeof *match) : NULL;
    for (int id = 1; match && id <= pieces; id++) {
        double best = 0;
        for (int q = 1; q <= np; q++) {
            size_t both = 0, nt = 0, nq = 0;
            for (size_t i = 0; i < n; i++) {
                nt += fr->labels->data[i] == (float)id;
                nq += lab[i] == q;
                both += fr->labels->data[i] == (float)id && lab[i] == q;
            }
            double d = nt + nq ? 2.0 * (double)both / (double)(nt + nq) : 0;
            if (d > best) {
                best = d;
                match[id] = q;
            }
        }
        worst = fmin(worst, best);
    }
    if (match) {
        for (size_t i = 0; i < n; i++) {
            float v = 0;
            for (int id = 1; id <= pieces; id++)
                if (lab[i] && lab[i] == match[id])
                    v = (float)id;
            fr->labels->data[i] = v;
        }
        cs->separate_dice = fmin(cs->separate_dice, worst);
        for (int id = 1; id <= pieces && rc >= 0; id++)
            if (!match[id])
                rc = fn_err_set(FN_EINVAL, "bench reduce: piece %d found no separated piece", id);
    } else if (rc >= 0)
        rc = fn_err_set(FN_ENOMEM, "bench reduce: out of memory");
    free(match);
    free(mask);
    free(comp);
    free(lab);
    return rc < 0 ? rc : 0;
}

/* The fit's options for configuration k: reduce's defaults, no pre-alignment, what o sets. */
static void fit_opts(const opts *o, int k, reduce_opts *ro)
{
    reduce_defaults(ro);
    ro->method = o->method[k];
    ro->count = o->count[k];
    ro->prealign = 0;
    if (o->band_mm >= 0)
        ro->band_mm = o->band_mm;
    if (o->voi_max_mm >= 0)
        ro->voi_max_mm = o->voi_max_mm;
    if (o->tolerance_mm >= 0)
        ro->tolerance_mm = o->tolerance_mm;
    if (o->settle_mm >= 0)
        ro->settle_mm = o->settle_mm;
    if (o->trust_mm >= 0)
        ro->trust_mm = o->trust_mm;
    if (o->trust_deg >= 0)
        ro->trust_deg = o->trust_deg;
    if (o->fit_starts)
        ro->starts = o->fit_starts;
    if (o->coarse)
        ro->coarse = 1;
    ro->gap_mm = o->gap_mm;
    if (o->axis_scale)
        ro->axis_scale = o->axis_scale > 0;
    if (o->no_polish)
        ro->polish = 0;
    if (o->no_global_check)
        ro->global_check = 0;
}

/* --verbose: a fit's details on stderr (level 2: and the same fit started at the truth). m's pose
 * is borrowed and given back. */
static void verbose_fit(const frag *f, frag *m, const frag *const *asm_, int nasm, const pose *truth,
                        const reduce_opts *ro, const reduce_result *r, const sample *x, uint64_t seed, int s,
                        int level)
{
    double fr_, ft_, fre_;
    pose keep = m->pose;
    m->pose = r->fitted;
    reduce_errors(f, m, truth, &fr_, &ft_, &fre_);
    m->pose = keep;
    double sr, st, stre;
    m->pose = r->start;
    reduce_errors(f, m, truth, &sr, &st, &stre);
    m->pose = keep;
    fprintf(stderr, "  start error %.2f deg %.2f mm; fit moved %.2f deg\n", sr, st,
            pose_angle_between(r->fitted, r->start) * 180 / M_PI);
    {
        pose d = pose_compose(r->fitted, pose_inverse(*truth));
        double ax[3] = {m->axes[0][0], m->axes[1][0], m->axes[2][0]}, aw[3];
        pose_rotate(truth, ax, aw);
        double n = sqrt(d.q[1] * d.q[1] + d.q[2] * d.q[2] + d.q[3] * d.q[3]);
        fprintf(stderr, "  error axis . long axis %.2f\n",
                n > 0 ? fabs(d.q[1] * aw[0] + d.q[2] * aw[1] + d.q[3] * aw[2]) / n : 0);
    }
    fprintf(stderr, "  fitted %.3f deg %.3f mm; voi %.0fx%.0fx%.0f mm\n", fr_, ft_,
            r->voi.hi[0] - r->voi.lo[0],
            r->voi.hi[1] - r->voi.lo[1], r->voi.hi[2] - r->voi.lo[2]);
    double gf[2], gt[2];
    grid_turn(f, m, &r->fitted, gf);
    grid_turn(f, m, truth, gt);
    fprintf(stderr, "  grids: the moving grid turned %.2f deg about the long axis and %.2f across it"
            " from the fixed grid (the truth: %.2f, %.2f)\n", gf[0], gf[1], gt[0], gt[1]);
    reduce_metric *me = reduce_metric_new(asm_, 1, m, &r->voi, ro->count, ro->band_mm);
    double ft = me ? reduce_metric_eval(me, truth, NULL) : NAN;
    fprintf(stderr, "  fitted metric %.6f\n", me ? reduce_metric_eval(me, &r->fitted, NULL) : NAN);
    if (level > 1) { /* the same fit started at the truth: where the metric's own basin ends */
        reduce_result rt;
        m->pose = *truth;
        if (reduce_pair(asm_, nasm, m, ro, &rt) == 0) {
            double tr_, tt_, ttre_;
            reduce_errors(f, m, truth, &tr_, &tt_, &ttre_);
            fprintf(stderr, "  from the truth: %.3f deg %.3f mm, metric %.6f over its voi, %.6f over this fit's\n",
                    tr_, tt_, rt.metric_end, me ? reduce_metric_eval(me, &rt.end, NULL) : NAN);
            reduce_result_free(&rt);
        }
        m->pose = keep;
    }
    reduce_metric_free(me);
    fprintf(stderr, "seed %llu start %d %s/%s: %.3f deg %.3f mm tre %.3f, metric %.6f (truth %.6f),"
            " %d evals, %.3f s cpu, push %.2f\n", (unsigned long long)seed, s,
            reduce_method_name(ro->method), ro->count == REDUCE_NEAREST ? "nearest" : "trilinear",
            x->rot, x->trans, x->tre, r->metric_end, ft, r->evaluations, x->cpu_s, r->push_mm);
    fprintf(stderr, "  end pose q %.17g %.17g %.17g %.17g t %.17g %.17g %.17g\n", r->end.q[0],
            r->end.q[1], r->end.q[2], r->end.q[3], r->end.t[0], r->end.t[1], r->end.t[2]);
}

/* The fracture of seed as o's workload asks for it. */
static void fracture_opts(const opts *o, uint64_t seed, fracture_params *fp)
{
    fracture_defaults(fp);
    fp->seed = seed;
    fp->pieces = o->pieces;
    fp->bone_loss_mm = o->bone_loss_mm;
    fp->threshold = o->threshold;
    fp->threshold_auto = o->threshold_auto;
    fp->touching = o->touching;
    fp->whole_bone = o->whole_bone;
    fp->model = o->model;
}

static int run_case(const vol *ct, uint64_t seed, const opts *o, config_stats *cs, uint64_t *rng)
{
    fracture_params fp;
    fracture_opts(o, seed, &fp);
    fracture_result fr;
    int rc = fracture_make(ct, &fp, &fr);
    if (rc)
        return rc;
    if (o->touching && (rc = separate_pieces(&fr, o->pieces, cs)) < 0) {
        fracture_result_free(&fr);
        return rc;
    }
    /* piece 2 moves; piece 1 and any others stay at their true poses: the assembly */
    frag f = {0}, m = {0}, rest[8] = {{0}};
    frag *fs[10] = {&f, &m};
    for (int id = 3; id <= o->pieces; id++)
        fs[id - 1] = &rest[id - 3];
    for (int id = 1; id <= o->pieces && rc == 0; id++) {
        int lo[3], hi[3];
        rc = frag_label_box(fr.labels, id, lo, hi);
        if (rc == 0)
            rc = frag_from_labels(fs[id - 1], fr.labels, fr.ct, id, lo, hi, fr.threshold, 200);
        if (rc == 0)
            fs[id - 1]->pose = fr.truth[id - 1];
    }
    pose truth = fr.truth[1];
    fracture_result_free(&fr);
    obb_params op = {CASE_TAU_MIN, CASE_TAU_MAX};
    obb_tree *tf = rc == 0 ? obb_tree_build(&f, &op) : NULL, *tm = tf ? obb_tree_build(&m, &op) : NULL;
    if (rc == 0 && (!tf || !tm))
        rc = FN_ENOMEM;
    const frag *asm_[9] = {&f};
    int nasm = 1;
    for (int id = 3; id <= o->pieces; id++)
        asm_[nasm++] = fs[id - 1];
    reduce_voi zone;
    if (rc == 0) {
        m.pose = truth;
        rc = reduce_auto_voi(asm_, 1, &m, 2, 0, 0, &zone, NULL);
    }
    for (int k = 0; k < o->nconf && rc == 0; k++)
        if (!(cs[k].eval_us > 0))
            cs[k].eval_us = eval_us(&f, &m, &truth, &zone, 64, o->count[k]);
    for (int s = 0; s < o->starts && rc == 0; s++) {
        const double mm[2] = {0, o->max_mm}, deg[2] = {0, o->max_deg};
        pose start = bench_reduce_start(&f, tf, &m, tm, &truth, mm, deg, rng);
        for (int k = 0; k < o->nconf && rc == 0; k++) {
            reduce_opts ro;
            fit_opts(o, k, &ro);
            m.pose = start;
            reduce_result r;
            double c0 = bench_process_cpu_us();
            rc = reduce_pair(asm_, nasm, &m, &ro, &r);
            double c1 = bench_process_cpu_us();
            if (rc)
                break;
            sample *x = &cs[k].s[cs[k].n++];
            reduce_errors(&f, &m, &truth, &x->rot, &x->trans, &x->tre);
            x->cpu_s = (c1 - c0) * 1e-6;
            x->wall_s = r.seconds;
            x->evals = r.evaluations;
            x->eval_cpu_s = r.eval_cpu_s;
            x->metric_end = r.metric_end;
            if (o->verbose)
                verbose_fit(&f, &m, asm_, nasm, &truth, &ro, &r, x, seed, s, o->verbose);
            reduce_result_free(&r);
        }
    }
    obb_tree_free(tf);
    obb_tree_free(tm);
    frag_free(&f);
    frag_free(&m);
    for (int i = 0; i < 8; i++)
        frag_free(&rest[i]);
    return rc;
}

/* --whole-case: the fracture as `fracture` leaves it (every piece where its displacement left it),
 * reduced as `reduce CASE` reduces it: the case's fixed piece (else the largest) fixed, the pieces that touch another
 * moving (reduce_pick_moving), reduce_case on o's fit options. A sample per moving piece (its
 * errors from the truth, its evaluations; its seconds the case's, shared evenly); the case's CPU
 * (all threads) and wall seconds in cs. The case is made in a staging folder under $TMPDIR (else
 * /tmp), loaded from there as reduce loads it, and removed before the fits. */
static int run_whole_case(const vol *ct, uint64_t seed, const opts *o, config_stats *cs)
{
    fracture_params fp;
    fracture_opts(o, seed, &fp);
    const char *t = getenv("TMPDIR");
    char dir[4200], tmp[4300];
    snprintf(dir, sizeof dir, "%s/fracnav-bench-whole-%ld", t && *t ? t : "/tmp", (long)getpid());
    int rc = case_stage_begin(dir, 0, NULL, tmp, sizeof tmp);
    if (rc < 0)
        return rc;
    planning_case *c = fracture_make_case(ct, &fp, tmp);
    if (c) { /* the case as reduce CASE finds it: loaded from its folder */
        case_free(c);
        c = case_load(tmp);
    }
    /* the folder goes before the fits, so that a run killed during them (minutes) leaves none */
    case_stage_abort(tmp);
    int *mv = c ? calloc((size_t)c->nfrag, sizeof *mv) : NULL;
    int *skipped = c ? calloc((size_t)c->nfrag, sizeof *skipped) : NULL;
    reduce_result *res = c ? calloc((size_t)c->nfrag, sizeof *res) : NULL;
    rc = !c ? -1 : mv && skipped && res ? 0 : fn_err_set(FN_ENOMEM, "out of memory");
    for (int k = 0; k < o->nconf && rc == 0; k++) {
        int fixed = c->fixed >= 0 ? c->fixed : 0, nskipped = 0;
        for (int i = 0; i < c->nfrag; i++) {
            c->frag[i].pose = POSE_IDENTITY; /* where the fracture left it */
            if (c->fixed < 0 && c->frag[i].voxels > c->frag[fixed].voxels)
                fixed = i;
        }
        int nmv = reduce_pick_moving(c, fixed, mv, skipped, &nskipped);
        if (nmv < 1) {
            rc = nmv < 0 ? nmv : fn_err_set(FN_EINVAL, "bench reduce: seed %llu: no piece touches another",
                                             (unsigned long long)seed);
            break;
        }
        reduce_opts ro, def;
        fit_opts(o, k, &ro);
        reduce_defaults(&def);
        ro.prealign = def.prealign; /* as reduce CASE: a piece far from the others pre-aligned */
        ro.tau_min = c->tau_min;
        ro.tau_max = c->tau_max;
        memset(res, 0, (size_t)c->nfrag * sizeof *res);
        double c0 = bench_process_cpu_us(), w0 = bench_now_us();
        rc = reduce_case(c, fixed, mv, nmv, &ro, res);
        double c1 = bench_process_cpu_us(), w1 = bench_now_us();
        int back = 0;
        for (int i = 0; i < nmv && rc == 0; i++) {
            sample *x = &cs[k].s[cs[k].n++];
            rc = reduce_truth_errors(c, fixed, case_find(c, res[i].id), &x->rot, &x->trans, &x->tre);
            x->cpu_s = (c1 - c0) * 1e-6 / nmv;
            x->wall_s = (w1 - w0) * 1e-6 / nmv;
            x->evals = res[i].evaluations;
            x->eval_cpu_s = res[i].eval_cpu_s;
            x->metric_end = res[i].metric_end;
            back += x->rot <= 1 && x->trans <= 1;
            if (o->verbose)
                fprintf(stderr, "seed %llu piece %d: %.3f deg %.3f mm (tre %.3f), %d evals\n", (unsigned long long)seed,
                        res[i].id, x->rot, x->trans, x->tre, res[i].evaluations);
        }
        for (int i = 0; i < nmv; i++)
            reduce_result_free(&res[i]);
        cs[k].case_cpu_s[cs[k].ncase] = (c1 - c0) * 1e-6;
        cs[k].case_wall_s[cs[k].ncase] = (w1 - w0) * 1e-6;
        cs[k].ncase++;
        cs[k].nskipped += nskipped;
        cs[k].ncase_back += back == nmv;
        if (o->verbose)
            fprintf(stderr, "seed %llu: %d of %d pieces back, %.2f s cpu, %.2f s wall\n", (unsigned long long)seed,
                    back, nmv, (c1 - c0) * 1e-6, (w1 - w0) * 1e-6);
    }
    free(mv);
    free(skipped);
    free(res);
    case_free(c);
    return rc;
}

static json_t *config_json(const opts *o, int k, config_stats *cs)
{
    int n = cs->n, ok = 0;
    double *v = malloc((size_t)(n ? n : 1) * sizeof *v);
    json_t *j = json_object();
    if (!v || !j) {
        free(v);
        json_decref(j);
        return NULL;
    }
    for (int i = 0; i < n; i++)
        ok += cs->s[i].rot <= 1 && cs->s[i].trans <= 1;
    jsonw_set(j, "method", jsonw_string(reduce_method_name(o->method[k])));
    jsonw_set(j, "counting", jsonw_string(o->count[k] == REDUCE_NEAREST ? "nearest" : "trilinear"));
    jsonw_set(j, "runs", json_integer(n));
    jsonw_set(j, "success_rate", jsonw_measure(n ? (double)ok / n : NAN));
#define STAT(key, field, q)                                                                        \
    do {                                                                                           \
        for (int i = 0; i < n; i++)                                                                \
            v[i] = cs->s[i].field;                                                                 \
        jsonw_set(j, key, jsonw_measure(bench_quantile(v, n, q)));                                 \
    } while (0)
    STAT("median_rot_err_deg", rot, 0.5);
    STAT("median_trans_err_mm", trans, 0.5);
    STAT("median_tre_mm", tre, 0.5);
    STAT("p90_rot_err_deg", rot, 0.9);
    STAT("p90_trans_err_mm", trans, 0.9);
    STAT("median_seconds", cpu_s, 0.5);
    STAT("p90_seconds", cpu_s, 0.9);
    STAT("median_wall_seconds", wall_s, 0.5);
    STAT("median_evaluations", evals, 0.5);
#undef STAT
    jsonw_set(j, "metric_eval_us", jsonw_measure(cs->eval_us));
    double eval_s = 0, nevals = 0;
    for (int i = 0; i < n; i++) {
        eval_s += cs->s[i].eval_cpu_s;
        nevals += cs->s[i].evals;
    }
    jsonw_set(j, "fit_eval_mean_us", jsonw_measure(nevals > 0 ? eval_s / nevals * 1e6 : NAN));
    if (cs->ncase) { /* --whole-case: the runs are pieces; the seconds of whole cases */
        jsonw_set(j, "cases", json_integer(cs->ncase));
        jsonw_set(j, "cases_all_back", json_integer(cs->ncase_back));
        jsonw_set(j, "pieces_skipped", json_integer(cs->nskipped));
        jsonw_set(j, "median_case_seconds", jsonw_measure(bench_quantile(cs->case_cpu_s, cs->ncase, 0.5)));
        jsonw_set(j, "max_case_seconds", jsonw_measure(bench_quantile(cs->case_cpu_s, cs->ncase, 1)));
        jsonw_set(j, "median_case_wall_seconds", jsonw_measure(bench_quantile(cs->case_wall_s, cs->ncase, 0.5)));
    }
    free(v);
    return j;
}

static int usage(FILE *out, int rc)
{
    fprintf(out,
            "usage: fracnav bench reduce [--json] [--seeds N] [--starts N] [--method M[/nearest]...]\n\n"
            "Automatic reduction on synthetic two-piece fractures of the example CT (one per seed,\n"
            "made by fracture_make with its defaults), each from N starts: the true pose turned by up\n"
            "to --max-deg about the centroid and moved by up to --max-mm (collision-free, as a hand\n"
            "leaves it); no pre-alignment. Per method: success_rate (within 1 mm and 1 degree),\n"
            "median and p90 errors, median_seconds and p90_seconds (CPU time of the fit, every\n"
            "thread's: the global check's candidates run on reduce's threads; immune to a busy\n"
            "machine; median_wall_seconds beside it), metric_eval_us (one evaluation over a\n"
            "64^3 VOI at the fracture, one core) and fit_eval_mean_us beside it (the mean over the\n"
            "fits' own evaluations, over their VOIs; pooled too).\n\n"
            "  --seeds N        fractures (default 4)\n"
            "  --starts N       starts per fracture (default 5)\n"
            "  --max-mm MM      largest start translation (default 10)\n"
            "  --max-deg DEG    largest start rotation (default 15)\n"
            "  --method M       add a configuration: powell, praxis, sbplx, bobyqa, optionally\n"
            "                   /nearest (default: the four methods, trilinear, and powell/nearest;\n"
            "                   with --suite or --labels, reduce's default; --labels fits with the\n"
            "                   first configuration)\n"
            "  --band MM        the metric's band (default: reduce's, 1 mm; 0 = the paper's box)\n"
            "  --voi-max MM     the automatic VOI's longest side (default: reduce's, 0 = no limit)\n"
            "  --tolerance MM   the fit's collision tolerance (default: reduce's, 0.5; 0 = the loop's)\n"
            "  --settle MM      the result pushed out up to MM to be free at the loop's tolerance 0\n"
            "                   (default: reduce's, 0.25; 0 = not)\n"
            "  --fit-starts N   starts of each fit's first stage (default: reduce's, 3)\n"
            "  --trust-mm MM, --trust-deg DEG  the fit's trust region around its start (default:\n"
            "                   reduce's, 12 mm and 18 degrees)\n"
            "  --coarse         the first stage on coarse copies (reduce_opts.coarse; default off)\n"
            "  --axis-scale, --no-axis-scale  the rotation scaled per principal axis, or by one\n"
            "                   radius (reduce_opts.axis_scale; default: reduce's)\n"
            "  --no-polish      no polish on the nearest count after the fit (reduce_opts.polish;\n"
            "                   default on)\n"
            "  --no-global-check  the global stage only where the local fit runs into its\n"
            "                   trust wall, not after every fit (reduce_opts.global_check;\n"
            "                   default on)\n"
            "  --pieces K       pieces per fracture (default 2): piece 2 is fitted against piece 1\n"
            "                   and the others, all at their true poses\n"
            "  --whole-case     every piece left where the fracture left it, all reduced together as\n"
            "                   reduce CASE does (the case's fixed piece; a piece that touches nothing\n"
            "                   left out); --starts unused. The runs are pieces; beside them cases,\n"
            "                   cases_all_back, pieces_skipped, median_case_seconds and\n"
            "                   max_case_seconds (the process's CPU, every thread), and\n"
            "                   median_case_wall_seconds; median_seconds is a case's share per piece\n"
            "  --touching       the pieces left in contact (fracture --touching): the fractured CT\n"
            "                   is thresholded and separated (edit separate) first, and the fits\n"
            "                   use the separated pieces; separated_dice_min, separate_mean_s\n"
            "  --whole-bone     the bone fractured is segment --whole-bone's (fracture_params\n"
            "                   whole_bone: on a CT that holds only the bone, every non-zero voxel\n"
            "                   joined to the cortex), not the threshold's\n"
            "  --bone-loss MM   bone lost along each cut (default 0)\n"
            "  --gap MM         the fits leave a gap of MM at the cut (reduce --gap; default 0)\n"
            "  --threshold HU|auto|auto-bone  the fracture's bone threshold (default 300; for a\n"
            "                   CT not in HU, as tests/data/CT_pitch.nii.gz: auto-bone)\n"
            "  --ct FILE        the CT to fracture (default: the example CT); long-bone: a bowed\n"
            "                   shaft with a cortex and a medullary canal, made in memory; pitch:\n"
            "                   tests/data/CT_pitch.nii.gz (under $FRACNAV_SRC, else the source tree)\n"
            "  --model 2        the fractures made by the second model (fracture_model2: a bent\n"
            "                   zig-zag sheet, trilinear resampling, noise; two pieces)\n"
            "  --labels DIR     real annotated fragments instead (NNN_BONE.nii.gz and\n"
            "                   NNN_BONE_mask.nii.gz, label k = fragment k, as bench separate):\n"
            "                   in each fractured bone every fragment of 1 ml or more but the\n"
            "                   largest is moved off its CT pose by 3-10 mm and 5-15 degrees about\n"
            "                   its centroid (collision-free) and fitted back against the largest\n"
            "                   as reduce --fixed L --moving K --no-prealign does, --starts times\n"
            "                   (default 10; a piece's starts follow from its bone's name and\n"
            "                   label alone, whatever else DIR holds). JSON per bone and pooled:\n"
            "                   back_rate (within 1 mm and 1 degree of the CT pose), median/p90\n"
            "                   errors, median_seconds and p90_seconds (the fit's CPU), the starts'\n"
            "                   ranges, and, for the fits not back, whether the metric is better\n"
            "                   at the CT pose than at their end (failed_ct_better_count,\n"
            "                   failed_end_better_count), and how many ended farther off than they\n"
            "                   started (ended_farther_count); targets beside the pooled figures\n"
            "  --intact DIR     the intact bones of DIR (a mask of one label) fractured as above,\n"
            "                   --seeds fractures each\n"
            "  --suite          the workloads of docs/benchmarks.md in one run (the skull; the skull\n"
            "                   from starts up to 20 mm and 25 degrees; 3 pieces; 6 pieces; 3 and 6\n"
            "                   pieces as whole cases (--whole-case);\n"
            "                   touching; 1 mm lost with --gap 1; CT_pitch; the long bone; the\n"
            "                   skull fractured by the second model; the pelvic development set's\n"
            "                   intact bones fractured whole (--intact --whole-bone) and its real\n"
            "                   fragments (--labels), from --labels DIR or $FRACNAV_DATA/pelvis-dev,\n"
            "                   skipped with a word when it is not there), with the default method\n"
            "                   unless --method says; JSON: workloads (one object each, as without\n"
            "                   --suite, with its name) and pooled (per method, over every run but\n"
            "                   the real fragments'; metric_eval_us null)\n"
            "  --verbose        one line per run on stderr, after its details (start error, VOI,\n"
            "                   the turn of the moving piece's voxel grid from the fixed one's),\n"
            "                   then the end pose in full (to compare fits pose for pose); with\n"
            "                   --labels a line per fit and its start and end poses in full\n"
            "  --verbose-truth  that, and the same fit started at the true pose (where the\n"
            "                   metric's own basin ends; for the analysis of failures)\n"
            "  --json           one JSON object on stdout: command, ct, seeds, starts, max_mm,\n"
            "                   max_deg, pieces, model, bone_loss_mm, gap_mm, touching, whole_bone,\n"
            "                   whole_case,\n"
            "                   separated_dice_min,\n"
            "                   separate_mean_s (null unless --touching), default_method, methods (one per\n"
            "                   configuration)\n");
    return rc;
}

/* The options that set a field of opts to a constant. */
static const struct flag_opt {
    const char *name;
    size_t field; /* offsetof(opts, an int) */
    int value;
} flag_opts[] = {
    {"--json", offsetof(opts, json), 1},
    {"--verbose", offsetof(opts, verbose), 1},
    {"--verbose-truth", offsetof(opts, verbose), 2},
    {"--coarse", offsetof(opts, coarse), 1},
    {"--suite", offsetof(opts, suite), 1},
    {"--axis-scale", offsetof(opts, axis_scale), 1},
    {"--no-axis-scale", offsetof(opts, axis_scale), -1},
    {"--no-polish", offsetof(opts, no_polish), 1},
    {"--no-global-check", offsetof(opts, no_global_check), 1},
    {"--touching", offsetof(opts, touching), 1},
    {"--whole-bone", offsetof(opts, whole_bone), 1},
    {"--whole-case", offsetof(opts, whole_case), 1},
};

/* The options that take a number in lo..hi: a whole one into an int field, else into a double. */
static const struct number_opt {
    const char *name;
    size_t field; /* offsetof(opts, an int when whole, else a double) */
    int whole;
    double lo, hi;
    const char *accepted; /* what the message says it takes */
} number_opts[] = {
    {"--seeds", offsetof(opts, seeds), 1, 1, 1000, "a whole number 1..1000"},
    {"--starts", offsetof(opts, starts), 1, 1, 1000, "a whole number 1..1000"},
    {"--max-mm", offsetof(opts, max_mm), 0, 0, 90, "a number 0..90"},
    {"--max-deg", offsetof(opts, max_deg), 0, 0, 90, "a number 0..90"},
    {"--pieces", offsetof(opts, pieces), 1, 2, 10, "a whole number 2..10"},
    {"--bone-loss", offsetof(opts, bone_loss_mm), 0, 0, 10, "a number of mm 0..10"},
    {"--gap", offsetof(opts, gap_mm), 0, 0, 10, "a number of mm 0..10"},
    {"--band", offsetof(opts, band_mm), 0, 0, 100, "a number of mm 0..100"},
    {"--fit-starts", offsetof(opts, fit_starts), 1, 1, 7, "a whole number 1..7"},
    {"--tolerance", offsetof(opts, tolerance_mm), 0, 0, 10, "a number of mm 0..10"},
    {"--settle", offsetof(opts, settle_mm), 0, 0, 10, "a number of mm 0..10"},
    {"--trust-mm", offsetof(opts, trust_mm), 0, 0, 1000, "a number 0..1000"},
    {"--trust-deg", offsetof(opts, trust_deg), 0, 0, 1000, "a number 0..1000"},
    {"--voi-max", offsetof(opts, voi_max_mm), 0, 0, 1000, "a number of mm 0..1000"},
    {"--model", offsetof(opts, model), 1, 1, 2, "1 or 2"},
};

#define COUNT(t) (sizeof(t) / sizeof(t)[0])

/* A number option's value into its field. 0 or cmd_bad_value's code. */
static int parse_number(const struct number_opt *n, const char *val, opts *o)
{
    double d;
    if (!cmd_number(val, &d) || !(d >= n->lo && d <= n->hi && (!n->whole || d == (int)d)))
        return cmd_bad_value("bench reduce", n->name, val, n->accepted);
    if (n->whole)
        *(int *)(void *)((char *)o + n->field) = (int)d;
    else
        *(double *)(void *)((char *)o + n->field) = d;
    return 0;
}

/* --method M: one more configuration. 0 or cmd_bad_value's code. */
static int parse_method(const char *val, opts *o)
{
    char name[32];
    snprintf(name, sizeof name, "%s", val ? val : "");
    char *slash = strchr(name, '/');
    int nearest = slash && !strcmp(slash, "/nearest");
    if (slash)
        *slash = 0;
    int m = reduce_method_parse(name);
    if (m < 0 || (slash && !nearest) || o->nconf == MAX_CONFIGS)
        return cmd_bad_value("bench reduce", "--method", val,
                             "powell, praxis, sbplx or bobyqa, optionally /nearest (8 at most)");
    o->method[o->nconf] = (reduce_method)m;
    o->count[o->nconf++] = nearest ? REDUCE_NEAREST : REDUCE_TRILINEAR;
    return 0;
}

/* The options of neither table, each taking argv[*i + 1] (*i moved past it): 0, cmd_bad_value's
 * code, or -1 when argv[*i] is none of them. */
static int parse_other(int argc, char **argv, int *i, opts *o)
{
    const char *a = argv[*i], *val = *i + 1 < argc ? argv[*i + 1] : NULL;
    if (!strcmp(a, "--threshold")) {
        if (val && !strcmp(val, "auto"))
            o->threshold_auto = 1;
        else if (val && !strcmp(val, "auto-bone"))
            o->threshold_auto = 2;
        else if (!cmd_number(val, &o->threshold))
            return cmd_bad_value("bench reduce", a, val, "HU, auto or auto-bone");
    } else if (!strcmp(a, "--labels") || !strcmp(a, "--intact")) {
        if (!val)
            return cmd_bad_value("bench reduce", a, val, "a folder of NNN_BONE.nii.gz and NNN_BONE_mask.nii.gz");
        o->labels = a[2] == 'l';
        o->intact = a[2] == 'i';
        o->data_dir = val;
    } else if (!strcmp(a, "--ct")) {
        if (!val)
            return cmd_bad_value("bench reduce", a, val, "a volume file");
        o->ct = val;
    } else if (!strcmp(a, "--method")) {
        int rc = parse_method(val, o);
        if (rc)
            return rc;
    } else
        return -1;
    ++*i;
    return 0;
}

/* The options from argv[1] on, over what *o holds: the tables' first, then the others. */
static int parse_more(int argc, char **argv, opts *o)
{
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        size_t k;
        for (k = 0; k < COUNT(flag_opts) && strcmp(a, flag_opts[k].name); k++)
            ;
        if (k < COUNT(flag_opts)) {
            *(int *)(void *)((char *)o + flag_opts[k].field) = flag_opts[k].value;
            continue;
        }
        for (k = 0; k < COUNT(number_opts) && strcmp(a, number_opts[k].name); k++)
            ;
        int rc;
        if (k < COUNT(number_opts))
            rc = parse_number(&number_opts[k], i + 1 < argc ? argv[++i] : NULL, o);
        else if ((rc = parse_other(argc, argv, &i, o)) == -1)
            return cmd_usage_error("bench reduce", "unknown option '%s'", a);
        if (rc)
            return rc;
    }
    return 0;
}

static int parse(int argc, char **argv, opts *o)
{
    *o = (opts){.seeds = 4, .max_mm = 10, .max_deg = 15, .band_mm = -1, .voi_max_mm = -1,
                .tolerance_mm = -1, .settle_mm = -1, .trust_mm = -1, .trust_deg = -1, .pieces = 2, .threshold = 300, .model = 1};
    int rc = parse_more(argc, argv, o);
    if (rc)
        return rc;
    if (!o->nconf && (o->suite || o->labels)) { /* the default method alone, unless --method says */
        reduce_opts def;
        reduce_defaults(&def);
        o->method[0] = def.method;
        o->count[o->nconf++] = def.count;
    }
    if (!o->nconf) {
        for (int m = 0; m < REDUCE_METHODS; m++) {
            o->method[o->nconf] = (reduce_method)m;
            o->count[o->nconf++] = REDUCE_TRILINEAR;
        }
        o->method[o->nconf] = REDUCE_POWELL;
        o->count[o->nconf++] = REDUCE_NEAREST;
    }
    return 0;
}

/* Appends a workload's runs to the pool's (per configuration). */
static int pool_add(config_stats *pool, const config_stats *cs, int nconf)
{
    for (int k = 0; k < nconf; k++) {
        sample *s = realloc(pool[k].s, (size_t)(pool[k].n + cs[k].n + 1) * sizeof *s);
        if (!s)
            return fn_err_set(FN_ENOMEM, "out of memory");
        memcpy(s + pool[k].n, cs[k].s, (size_t)cs[k].n * sizeof *s);
        pool[k].s = s;
        pool[k].n += cs[k].n;
        pool[k].eval_us = NAN; /* one CT's figure: each workload has its own */
    }
    return 0;
}

/* --labels: the real annotated pieces of o->data_dir (bench_reduce_labels.c), fitted as the first
 * configuration says. */
static json_t *run_labels(const opts *o)
{
    reduce_opts ro;
    fit_opts(o, 0, &ro);
    json_t *root = bench_reduce_labels(o->data_dir, o->starts, &ro, o->verbose);
    if (root) {
        jsonw_set(root, "method", jsonw_string(reduce_method_name(ro.method)));
        jsonw_set(root, "counting", jsonw_string(ro.count == REDUCE_NEAREST ? "nearest" : "trilinear"));
    }
    return root;
}

/* One workload (o's CT, pieces, loss, ...): its JSON object, the runs also added to pool (may be
 * NULL). NULL with fn_err on failure. */
static json_t *run_workload(const opts *op, config_stats *pool)
{
    opts o = *op;
    if (!o.starts)
        o.starts = o.labels ? 10 : 5;
    if (o.labels)
        return run_labels(&o);
    char pitch[4200];
    if (o.ct && !strcmp(o.ct, "pitch")) {
        bench_pitch_path(pitch, sizeof pitch);
        o.ct = pitch;
    }
    const char *path = o.ct ? o.ct : cmd_example_ct();
    char *cts[BENCH_MAX_BONES] = {NULL}; /* --intact: the intact bones' CTs, malloc'd */
    int ncts = o.intact ? bench_labels_intact(o.data_dir, cts, BENCH_MAX_BONES) : 1;
    if (ncts < 1) {
        if (ncts == 0)
            fn_err_set(FN_EINVAL, "%s: no intact bone (a mask of one label)", o.data_dir);
        return NULL;
    }
    if (o.intact)
        path = o.data_dir;
    int rc = 0;
    config_stats cs[MAX_CONFIGS] = {0};
    cs[0].separate_dice = 1;
    for (int k = 0; k < o.nconf && o.whole_case; k++)
        cs[k].eval_us = NAN; /* no 64^3 figure: the fits of whole cases alone */
    for (int k = 0; k < o.nconf; k++) {
        /* --whole-case: a sample per piece, up to o.pieces - 1 a case */
        size_t n = (size_t)o.seeds * ncts * (o.whole_case ? (size_t)o.pieces : (size_t)o.starts);
        cs[k].s = calloc(n, sizeof *cs[k].s);
        cs[k].case_cpu_s = calloc((size_t)o.seeds * ncts, sizeof *cs[k].case_cpu_s);
        cs[k].case_wall_s = calloc((size_t)o.seeds * ncts, sizeof *cs[k].case_wall_s);
        if (!cs[k].s || !cs[k].case_cpu_s || !cs[k].case_wall_s)
            rc = fn_err_set(FN_ENOMEM, "out of memory");
    }
    uint64_t rng = 0x9e3779b97f4a7c15ull;
    for (int c = 0; c < ncts && rc == 0; c++) {
        const char *one = o.intact ? cts[c] : path;
        vol *ct = o.ct && !strcmp(o.ct, "long-bone") ? long_bone() : volio_read(one);
        rc = ct ? 0 : -1;
        for (int s = 0; s < o.seeds && rc == 0; s++) {
            rc = o.whole_case ? run_whole_case(ct, (uint64_t)s + 1, &o, cs)
                              : run_case(ct, (uint64_t)s + 1, &o, cs, &rng);
            if (rc)
                fn_err_wrap(rc, "%s, seed %d", one, s + 1);
        }
        vol_free(ct);
    }
    for (int c = 0; o.intact && c < ncts; c++)
        free(cts[c]);
    if (rc == 0 && pool)
        rc = pool_add(pool, cs, o.nconf);
    json_t *root = NULL;
    if (rc == 0) {
        json_t *rows = json_array();
        root = jsonw_object("bench reduce");
        for (int k = 0; k < o.nconf; k++)
            json_array_append_new(rows, config_json(&o, k, &cs[k]));
        jsonw_set(root, "ct", jsonw_string(path));
        jsonw_set(root, "seeds", json_integer(o.seeds));
        jsonw_set(root, "starts", o.whole_case ? json_null() : json_integer(o.starts));
        jsonw_set(root, "max_mm", jsonw_exact(o.max_mm));
        jsonw_set(root, "max_deg", jsonw_exact(o.max_deg));
        jsonw_set(root, "pieces", json_integer(o.pieces));
        jsonw_set(root, "touching", json_boolean(o.touching));
        jsonw_set(root, "whole_bone", json_boolean(o.whole_bone));
        jsonw_set(root, "whole_case", json_boolean(o.whole_case));
        jsonw_set(root, "model", json_integer(o.model));
        jsonw_set(root, "separated_dice_min", o.touching ? jsonw_measure(cs[0].separate_dice) : json_null());
        jsonw_set(root, "separate_mean_s", o.touching ? jsonw_measure(cs[0].separate_s / o.seeds) : json_null());
        jsonw_set(root, "bone_loss_mm", jsonw_exact(o.bone_loss_mm));
        jsonw_set(root, "gap_mm", jsonw_exact(o.gap_mm));
        reduce_opts def;
        reduce_defaults(&def);
        jsonw_set(root, "default_method", jsonw_string(reduce_method_name(def.method)));
        jsonw_set(root, "methods", rows);
    }
    for (int k = 0; k < o.nconf; k++) {
        free(cs[k].s);
        free(cs[k].case_cpu_s);
        free(cs[k].case_wall_s);
    }
    return root;
}

/* --suite: the workloads of the README's table, one after another, each with the options given
 * (seeds, starts, methods: by default the default method alone), and every run pooled but those of
 * the real annotated pieces. A workload of the real bones (data) gets the development set's folder
 * after its arguments: --labels DIR, else $FRACNAV_DATA/pelvis-dev; it is skipped, saying so, when
 * that folder is not there. */
static const struct {
    const char *name;
    char *args[6]; /* string literals, which parse_more only reads */
    int data;
} SUITE[] = {
    {"skull", {NULL}, 0},
    {"skull, starts up to 20 mm and 25 degrees", {"--max-mm", "20", "--max-deg", "25", NULL}, 0},
    {"skull, 3 pieces", {"--pieces", "3", NULL}, 0},
    {"skull, 6 pieces", {"--pieces", "6", NULL}, 0},
    {"skull, 3 pieces, whole case (every piece moved, reduce CASE)", {"--pieces", "3", "--whole-case", NULL}, 0},
    {"skull, 6 pieces, whole case (every piece moved, reduce CASE)", {"--pieces", "6", "--whole-case", NULL}, 0},
    {"skull, pieces left touching, separated first", {"--touching", NULL}, 0},
    {"skull, 1 mm of bone lost, the fit told (--gap 1)", {"--bone-loss", "1", "--gap", "1", NULL}, 0},
    {"CT_pitch (8-bit, 2.4 mm slices)", {"--ct", "pitch", "--threshold", "auto-bone", NULL}, 0},
    {"long bone made in memory", {"--ct", "long-bone", NULL}, 0},
    {"skull, second fracture model (bent zig-zag sheet, trilinear, noise)", {"--model", "2", NULL}, 0},
    /* The pelvic CTs hold only the bone, its cancellous interior at 40-70 HU and below 0: at 300 HU
     * the bone is a porous cortex, and no fit came back (0 of 9 fits, 3 bones); at 150 HU 0.85 of
     * 60. The bone a user's pieces come from is segment --whole-bone's, as here: 0.92 of 60. */
    {"pelvis, intact bones fractured whole (segment --whole-bone)", {"--whole-bone", "--intact", NULL}, 1},
    {"pelvis, real fragments moved off their CT pose", {"--labels", NULL}, 1},
};

static json_t *run_suite(const opts *o)
{
    config_stats pool[MAX_CONFIGS] = {0};
    json_t *root = jsonw_object("bench reduce"), *list = json_array();
    int ok = root && list;
    char data[4200];
    snprintf(data, sizeof data, "%s", o->data_dir ? o->data_dir : bench_labels_default_dir());
    for (size_t w = 0; ok && w < sizeof SUITE / sizeof SUITE[0]; w++) {
        opts wo = *o;
        wo.labels = wo.intact = 0;
        char *argv[8] = {"suite"};
        int argc = 1;
        while (SUITE[w].args[argc - 1])
            argv[argc] = SUITE[w].args[argc - 1], argc++;
        if (SUITE[w].data && access(data, R_OK) != 0) {
            fprintf(stderr, "bench reduce --suite: %s skipped: no development set at %s (--labels DIR)\n",
                    SUITE[w].name, data);
            json_t *one = json_object();
            jsonw_set(one, "workload", json_string(SUITE[w].name));
            jsonw_set(one, "skipped", jsonw_string("no development set (--labels DIR)"));
            json_array_append_new(list, one);
            continue;
        }
        if (SUITE[w].data)
            argv[argc++] = data;
        json_t *one = NULL;
        if (parse_more(argc, argv, &wo) == 0)
            one = run_workload(&wo, pool);
        if (!one) {
            fn_err_wrap(FN_EINVAL, "workload '%s'", SUITE[w].name);
            ok = 0;
            break;
        }
        fprintf(stderr, "bench reduce --suite: %s done\n", SUITE[w].name);
        json_object_set_new(one, "workload", json_string(SUITE[w].name));
        json_object_del(one, "command");
        json_array_append_new(list, one);
    }
    if (ok) {
        json_t *rows = json_array();
        for (int k = 0; k < o->nconf; k++)
            json_array_append_new(rows, config_json(o, k, &pool[k]));
        reduce_opts def;
        reduce_defaults(&def);
        jsonw_set(root, "default_method", jsonw_string(reduce_method_name(def.method)));
        jsonw_set(root, "workloads", list);
        jsonw_set(root, "pooled", rows);
    }
    for (int k = 0; k < o->nconf; k++)
        free(pool[k].s);
    if (!ok) {
        json_decref(root);
        json_decref(list);
        return NULL;
    }
    return root;
}

int bench_reduce(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv))
        return usage(stdout, 0);
    opts o;
    int rc = parse(argc, argv, &o);
    if (rc)
        return rc;
    json_t *root = o.suite ? run_suite(&o) : run_workload(&o, NULL);
    if (!root) {
        fprintf(stderr, "fracnav bench reduce: %s\n", fn_err_msg());
        return 1;
    }
    if (o.json)
        return jsonw_print(root, stdout) < 0 ? 1 : 0;
    char *text = jsonw_dumps(root);
    if (text)
        fputs(text, stdout);
    free(text);
    json_decref(root);
    return 0;
}
