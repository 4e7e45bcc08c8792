/* fracnav reduce: automatic reduction of a case's fragments (pre-alignment + optimizer). */
#include "cmd.h"

#include "case.h"
#include "caselock.h"
#include "case_journal.h"
#include "err.h"
#include "fnclock.h"
#include "jsonw.h"
#include "navview.h"
#include "reduce.h"

#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav reduce CASE [--fixed ID] [--moving ID...] [--method M] [--voi X0 Y0 Z0 X1 Y1 Z1]\n"
            "                      [--no-prealign] [--json] [-o NEWCASE] [options]\n\n"
            "Fit the fragments back together: the fixed fragment stays; a moving one left more\n"
            "than 10 mm from the others is pre-aligned first (principal axes, slid to contact);\n"
            "each is then optimized on the VOI metric (2 n_I - n_1 - n_2) / n_VOI, one at a time\n"
            "against the growing assembly, the one whose fit gains most first. After the fit of a\n"
            "lone moving piece (not a long one), and wherever a fit runs into its limit (12 mm or\n"
            "18 degrees from the start), a global stage fits candidate starts briefly (turned and\n"
            "moved about the start, and pre-aligned), on both cores, and refines one only where\n"
            "it beats that fit, with no such limit. The result never leaves fragments colliding\n"
            "beyond the tolerance. Poses, VOIs and the convergence history are saved in the case\n"
            "(atomic save). Poses that a navigation session left in CASE/journal are applied\n"
            "first (the fit starts where the hand left the fragments) and the journal is emptied\n"
            "once the case is saved. docs/reduction.md has the details and the measured accuracy.\n\n"
            "  --fixed ID             the fragment that stays (default: the case's fixed one, else\n"
            "                         the largest)\n"
            "  --moving ID...         the fragments to fit (default: all others that touch another\n"
            "                         in the CT or that the hand moved next to one; any other, as\n"
            "                         a CT's head holder, is skipped with a word, and --moving\n"
            "                         still fits it)\n"
            "  --method M             powell (ours), praxis, sbplx or bobyqa (NLopt); default: praxis,\n"
            "                         the most successful in `fracnav bench reduce`\n"
            "  --voi X0 Y0 Z0 X1 Y1 Z1  the VOI box, world LPS mm (default: automatic, around the\n"
            "                         contact zone of each fragment)\n"
            "  --no-prealign          no pre-alignment (without it, a fragment more than 10 mm from\n"
            "                         the others is pre-aligned first, a nearer one starts where it\n"
            "                         is; and the global stage tries it as one of its candidates)\n"
            "  --nearest              count voxels at the nearest cell instead of trilinear weights\n"
            "  --tolerance MM         collision tolerance of the result (default 0.5)\n"
            "  --gap MM               bone lost at the fracture: the fit leaves a gap of MM between\n"
            "                         the fragments instead of closing it (default 0; counted in\n"
            "                         whole voxels: less than a voxel spacing leaves none)\n"
            CMD_TAU_HELP
            "  -o, --output NEWCASE   save into a new case folder (the source stays where it is):\n"
            "                         missing or empty, or a case that --force replaces, never in\n"
            "                         or around CASE; checked before the fit\n"
            "  --force                with -o: replace the case NEWCASE holds (with its journal)\n"
            "  --json                 one JSON object on stdout: command, case, method, fixed,\n"
            "                         fragments (id, iterations, evaluations, seconds, metric_start,\n"
            "                         metric_end, push_mm, prealigned, voi_mm, single_answer and,\n"
            "                         when false, candidates (q, t, metric: the fit's distinct\n"
            "                         answers, as good within 0.002), and with ground truth\n"
            "                         rot_err_deg, trans_err_mm, tre_mm), skipped, seconds\n"
            CMD_WAIT_HELP
            "  --help                 this text\n");
}

typedef struct args {
    const char *dir, *out;
    int fixed_id;
    int moving[256], nmoving;
    int json, force;
    cmd_tau tau;
    reduce_opts o;
} args;

static int parse(int argc, char **argv, args *A)
{
    int rc;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        double d;
        if (!strcmp(a, "--json"))
            A->json = 1;
        else if (!strcmp(a, "--force"))
            A->force = 1;
        else if (!strcmp(a, "--no-prealign"))
            A->o.prealign = 0;
        else if (!strcmp(a, "--nearest"))
            A->o.count = REDUCE_NEAREST;
        else if (a[0] != '-') {
            if (A->dir)
                return cmd_usage_error("reduce", "unexpected argument '%s'", a);
            A->dir = a;
        } else if (!strcmp(a, "-o") || !strcmp(a, "--output")) {
            if (!val)
                return cmd_bad_value("reduce", a, val, "a folder");
            A->out = argv[++i];
        } else if (cmd_tau_option("reduce", a, val, &A->tau, &rc)) {
            if (rc)
                return rc;
            i++;
        } else if (!strcmp(a, "--fixed")) {
            if (!cmd_number(val, &d) || !(d >= 1 && d <= 65535 && d == (int)d))
                return cmd_bad_value("reduce", a, val, "a fragment id");
            A->fixed_id = (int)d;
            i++;
        } else if (!strcmp(a, "--moving")) {
            if (!cmd_number(val, &d))
                return cmd_bad_value("reduce", a, val, "one or more fragment ids");
            while (i + 1 < argc && cmd_number(argv[i + 1], &d)) {
                if (!(d >= 1 && d <= 65535 && d == (int)d) || A->nmoving == 256)
                    return cmd_bad_value("reduce", a, argv[i + 1], "a fragment id (up to 256 of them)");
                A->moving[A->nmoving++] = (int)d;
                i++;
            }
        } else if (!strcmp(a, "--method")) {
            int m = reduce_method_parse(val);
            if (m < 0)
                return cmd_bad_value("reduce", a, val, "powell, praxis, sbplx or bobyqa");
            A->o.method = (reduce_method)m;
            i++;
        } else if (!strcmp(a, "--tolerance")) {
            if (!cmd_number(val, &d) || !(d >= 0 && d <= 10))
                return cmd_bad_value("reduce", a, val, "a number of mm from 0 to 10");
            A->o.tolerance_mm = d;
            i++;
        } else if (!strcmp(a, "--gap")) {
            if (!cmd_number(val, &d) || !(d >= 0 && d <= 10))
                return cmd_bad_value("reduce", a, val, "a number of mm from 0 to 10");
            A->o.gap_mm = d;
            i++;
        } else if (!strcmp(a, "--voi")) {
            double v[6];
            for (int k = 0; k < 6; k++)
                if (i + 1 + k >= argc || !cmd_number(argv[i + 1 + k], &v[k]))
                    return cmd_bad_value("reduce", a, i + 1 + k < argc ? argv[i + 1 + k] : NULL,
                                         "six numbers X0 Y0 Z0 X1 Y1 Z1 (world LPS mm)");
            for (int k = 0; k < 3; k++) {
                A->o.voi.lo[k] = fmin(v[k], v[k + 3]);
                A->o.voi.hi[k] = fmax(v[k], v[k + 3]);
                if (A->o.voi.lo[k] == A->o.voi.hi[k])
                    return cmd_usage_error("reduce", "--voi: the box is flat on axis %d", k);
            }
            A->o.has_voi = 1;
            i += 6;
        } else
            return cmd_usage_error("reduce", "unknown option '%s'", a);
    }
    if (!A->dir)
        return cmd_usage_error("reduce", "%s", "needs CASE");
    if (A->force && !A->out)
        return cmd_usage_error("reduce", "%s", "--force goes with -o NEWCASE");
    return cmd_tau_check("reduce", &A->tau);
}

/* Fragment indices: the fixed one and the moving ones; skipped: those left out by default (they
 * touch nothing). 0, or 2 after a usage error, or 1 when the case has no fragment to move. */
static int pick(const planning_case *c, const args *A, int *fixed, int *mv, int *nmv, int *skipped, int *nskipped)
{
    if (A->fixed_id) {
        if ((*fixed = case_find(c, A->fixed_id)) < 0)
            return cmd_usage_error("reduce", "--fixed: the case has no fragment %d", A->fixed_id);
    } else if (c->fixed >= 0) {
        *fixed = c->fixed;
    } else {
        *fixed = 0;
        for (int i = 1; i < c->nfrag; i++)
            if (c->frag[i].voxels > c->frag[*fixed].voxels)
                *fixed = i;
    }
    *nmv = 0;
    if (A->nmoving) {
        for (int k = 0; k < A->nmoving; k++) {
            int i = case_find(c, A->moving[k]);
            if (i < 0)
                return cmd_usage_error("reduce", "--moving: the case has no fragment %d", A->moving[k]);
            if (i == *fixed)
                return cmd_usage_error("reduce", "--moving: fragment %d is the fixed one", A->moving[k]);
            for (int j = 0; j < *nmv; j++)
                if (mv[j] == i)
                    return cmd_usage_error("reduce", "--moving: fragment %d is given twice", A->moving[k]);
            mv[(*nmv)++] = i;
        }
    } else {
        int n = reduce_pick_moving(c, *fixed, mv, skipped, nskipped);
        if (n < 0) {
            fprintf(stderr, "fracnav reduce: %s\n", fn_err_msg());
            return 1;
        }
        *nmv = n;
        for (int k = 0; k < *nskipped; k++)
            fprintf(stderr, "fracnav reduce: fragment %d touches no other fragment in the CT, and no one "
                    "moved it next to one: skipped (--moving %d fits it)\n",
                    c->frag[skipped[k]].id, c->frag[skipped[k]].id);
    }
    if (!*nmv) { /* the case's content, not the command line: a runtime error */
        if (*nskipped)
            fprintf(stderr, "fracnav reduce: %s: no fragment touches another in the CT or was moved next to "
                    "one; --moving ID names the ones to fit\n", c->dir);
        else
            fprintf(stderr, "fracnav reduce: %s has %d fragment%s: none to fit against another\n", c->dir,
                    c->nfrag, c->nfrag == 1 ? "" : "s");
        return 1;
    }
    return 0;
}

static void progress(void *ctx, int id, int iter, int evals, double f, double seconds)
{
    fprintf(stderr, "\rfragment %d: iteration %d, %d evaluations, metric %.6f, %.2f s   ", id, iter, evals, f,
            seconds);
    fflush(stderr);
}

static json_t *voi_json(const reduce_voi *v)
{
    double b[6] = {v->lo[0], v->lo[1], v->lo[2], v->hi[0], v->hi[1], v->hi[2]};
    return jsonw_exact_array(b, 6);
}

/* No single answer: the candidates, each a pose and its metric over the final VOI. */
static json_t *candidates_json(const reduce_result *r)
{
    json_t *list = json_array();
    for (int i = 0; list && i < r->ncandidates; i++) {
        json_t *o = json_object();
        jsonw_set(o, "q", jsonw_exact_array(r->candidate[i].pose.q, 4));
        jsonw_set(o, "t", jsonw_exact_array(r->candidate[i].pose.t, 3));
        jsonw_set(o, "metric", jsonw_exact(r->candidate[i].metric));
        json_array_append_new(list, o);
    }
    return list;
}

static json_t *result_json(const planning_case *c, int fixed, const reduce_result *r)
{
    json_t *o = json_object();
    if (!o)
        return NULL;
    double rot = JSONW_NA, trans = JSONW_NA, tre = JSONW_NA;
    if (c->has_truth)
        reduce_truth_errors(c, fixed, case_find(c, r->id), &rot, &trans, &tre);
    jsonw_set(o, "id", json_integer(r->id));
    jsonw_set(o, "prealigned", json_boolean(r->prealigned));
    jsonw_set(o, "voi_mm", voi_json(&r->voi));
    jsonw_set(o, "iterations", json_integer(r->iterations));
    jsonw_set(o, "evaluations", json_integer(r->evaluations));
    jsonw_set(o, "seconds", jsonw_measure(r->seconds));
    jsonw_set(o, "metric_start", jsonw_exact(r->metric_start));
    jsonw_set(o, "metric_end", jsonw_exact(r->metric_end));
    jsonw_set(o, "push_mm", jsonw_measure(r->push_mm));
    jsonw_set(o, "collides", json_boolean(r->collides));
    jsonw_set(o, "single_answer", json_boolean(!r->rival));
    jsonw_set(o, "candidates", candidates_json(r));
    jsonw_set(o, "rot_err_deg", jsonw_measure(rot));
    jsonw_set(o, "trans_err_mm", jsonw_measure(trans));
    jsonw_set(o, "tre_mm", jsonw_measure(tre));
    return o;
}

static int report(const planning_case *c, const args *A, int fixed, const reduce_result *r, int n, const int *skipped,
                  int nskipped, double seconds)
{
    if (!A->json) {
        for (int i = 0; i < n; i++) {
            /* The piece's own move: a multi-fragment fit can move pieces a lot for a metric that
             * hardly changes (the issue: "metric -0.722651 -> -0.722651"). */
            const double *cen = c->frag[case_find(c, r[i].id)].centroid;
            double a[3], b[3], d[3];
            pose_apply(&r[i].placed, cen, a);
            pose_apply(&r[i].end, cen, b);
            for (int k = 0; k < 3; k++)
                d[k] = b[k] - a[k];
            char move[128];
            navview_move_text(d, move, sizeof move);
            printf("fragment %d: metric %.6f -> %.6f; moved %.2f mm (%s), turned %.2f deg; %d iterations, "
                   "%d evaluations, %.3f s%s",
                   r[i].id, r[i].metric_start, r[i].metric_end, sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]), move,
                   pose_angle_between(r[i].placed, r[i].end) * 180 / M_PI, r[i].iterations, r[i].evaluations,
                   r[i].seconds, r[i].prealigned ? ", pre-aligned" : "");
            double rot, trans, tre;
            if (c->has_truth && reduce_truth_errors(c, fixed, case_find(c, r[i].id), &rot, &trans, &tre) == 0)
                printf("; error %.3f deg, %.3f mm, TRE %.3f mm", rot, trans, tre);
            if (r[i].collides)
                printf("; no collision-free fit: left where it started");
            if (r[i].rival)
                printf("; no single answer wins: %d candidates in distinct basins (--json lists them)",
                       r[i].ncandidates);
            printf("\n");
        }
        printf("saved %s\n", c->dir);
        return 0;
    }
    json_t *o = jsonw_object("reduce"), *frs = json_array();
    for (int i = 0; o && frs && i < n; i++)
        json_array_append_new(frs, result_json(c, fixed, &r[i]));
    if (o && frs) {
        jsonw_set(o, "case", jsonw_string(c->dir));
        jsonw_set(o, "method", jsonw_string(reduce_method_name(A->o.method)));
        jsonw_set(o, "counting", jsonw_string(A->o.count == REDUCE_NEAREST ? "nearest" : "trilinear"));
        jsonw_set(o, "fixed", json_integer(c->frag[fixed].id));
        jsonw_set(o, "fragments", frs);
        json_t *sk = json_array();
        for (int k = 0; k < nskipped; k++)
            json_array_append_new(sk, json_integer(c->frag[skipped[k]].id));
        jsonw_set(o, "skipped", sk);
        jsonw_set(o, "seconds", jsonw_measure(seconds));
    } else
        json_decref(frs);
    return jsonw_print(o, stdout);
}

/* -o: the new folder (its staged copy), with the source kept where it is (an absolute path). */
static int retarget(planning_case *c, const char *out)
{
    char abs[PATH_MAX];
    if (!realpath(c->source, abs))
        return fn_err_set(FN_EIO, "%s: cannot resolve the source path", c->source);
    if (snprintf(c->source, sizeof c->source, "%s", abs) >= (int)sizeof c->source ||
        snprintf(c->dir, sizeof c->dir, "%s", out) >= (int)sizeof c->dir)
        return fn_err_set(FN_EINVAL, "-o: path too long");
    return 0;
}

/* The results into the case, saved in place (its journal then removed) or, with -o, through the
 * staging folder tmp into A->out. 0 or negative. */
static int store(planning_case *c, const args *A, int fixed, const reduce_result *res, int nmv, const char *tmp)
{
    int err = case_set_reduction(c, fixed, &A->o, res, nmv);
    if (err == 0 && A->out)
        err = retarget(c, tmp);
    if (err == 0)
        err = case_save(c);
    if (err == 0 && A->out && (err = case_stage_commit(tmp, A->out, A->force)) == 0)
        snprintf(c->dir, sizeof c->dir, "%s", A->out);
    if (err == 0 && !A->out) /* case.json holds the journal's poses now */
        err = case_journal_remove(c);
    return err;
}

int cmd_reduce(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    args A = {0};
    reduce_defaults(&A.o);
    int wait = cmd_take_flag(&argc, argv, "--wait");
    int rc = parse(argc, argv, &A);
    if (rc)
        return rc;
    if (A.out && cmd_out_case(A.out, A.dir) < 0) {
        fprintf(stderr, "fracnav reduce: %s\n", fn_err_msg());
        return 1;
    }
    caselock *lock = cmd_lock_case("reduce", A.dir, !A.out, wait); /* -o: the case is only read */
    /* -o: a case there that --force replaces is written, so held as edit holds its case */
    caselock *out_lock = lock && A.out ? cmd_lock_case("reduce", A.out, 1, wait) : NULL;
    planning_case *c = lock && (out_lock || !A.out) ? case_load(A.dir) : NULL;
    if (!c) {
        if (lock && (out_lock || !A.out))
            fprintf(stderr, "fracnav reduce: %s\n", fn_err_msg());
        caselock_release(out_lock);
        caselock_release(lock);
        return 1;
    }
    int fixed, mv[256 + 1], nmv, nskipped = 0;
    char tmp[4200] = "";
    int *mvp = A.nmoving ? mv : malloc((size_t)c->nfrag * sizeof *mvp);
    int *skipped = malloc((size_t)c->nfrag * sizeof *skipped);
    reduce_result *res = NULL;
    if (!mvp || !skipped) {
        fprintf(stderr, "fracnav reduce: out of memory\n");
        if (mvp != mv)
            free(mvp);
        free(skipped);
        case_free(c);
        caselock_release(out_lock);
        caselock_release(lock);
        return 1;
    }
    if (cmd_journal_poses("reduce", c, 1) < 0) { /* the poses a session left are where the hand left them */
        fprintf(stderr, "fracnav reduce: %s\n", fn_err_msg());
        rc = 1;
        goto done;
    }
    if ((rc = pick(c, &A, &fixed, mvp, &nmv, skipped, &nskipped)) != 0)
        goto done;
    /* -o is built aside and put in place at once, as segment and fracture do */
    if (A.out && case_stage_begin(A.out, A.force, c->source, tmp, sizeof tmp) < 0) {
        fprintf(stderr, "fracnav reduce: %s\n", fn_err_msg());
        rc = 1;
        goto done;
    }
    if (cmd_tau_apply(&A.tau, &c->tau_min, &c->tau_max) < 0) {
        rc = cmd_usage_error("reduce", "%s", fn_err_msg());
        goto done;
    }
    A.o.tau_min = c->tau_min;
    A.o.tau_max = c->tau_max;
    if (isatty(STDERR_FILENO))
        A.o.progress = progress;
    res = calloc((size_t)nmv, sizeof *res);
    int64_t t0 = fnclock_now_us();
    int err = res ? reduce_case(c, fixed, mvp, nmv, &A.o, res) : fn_err_set(FN_ENOMEM, "out of memory");
    int64_t t1 = fnclock_now_us();
    if (A.o.progress)
        fprintf(stderr, "\n");
    if (err == 0)
        err = store(c, &A, fixed, res, nmv, tmp);
    if (err < 0) {
        fprintf(stderr, "fracnav reduce: %s\n", fn_err_msg());
        if (A.out)
            case_stage_abort(tmp);
        rc = 1;
        goto done;
    }
    double secs = (double)(t1 - t0) * 1e-6;
    if (report(c, &A, fixed, res, nmv, skipped, nskipped, secs) < 0) {
        fprintf(stderr, "fracnav reduce: %s\n", fn_err_msg());
        rc = 1;
    }
done:
    for (int i = 0; res && i < nmv; i++)
        reduce_result_free(&res[i]);
    free(res);
    if (mvp != mv)
        free(mvp);
    free(skipped);
    case_free(c);
    caselock_release(out_lock);
    caselock_release(lock);
    return rc;
}
