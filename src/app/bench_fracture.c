/* fracnav bench fracture: how often `fracture` makes the fracture asked for, per seed and number
 * of pieces, with the defaults otherwise (issue 23: seeds 1-100 with the defaults all made; up to
 * 10 pieces, 95 of 100). Each run is fracture_make on the CT in memory (what `fracnav fracture`
 * does before it writes the case). */
#include "bench.h"

#include "cmd.h"
#include "err.h"
#include "fracture.h"
#include "jsonw.h"
#include "vol.h"
#include "volio.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_COUNTS 9 /* pieces 2..10 */

typedef struct opts {
    const char *ct;
    int json, first, last;
    int pieces[MAX_COUNTS], ncounts;
} opts;

static int usage(FILE *out, int rc)
{
    fprintf(out, "usage: fracnav bench fracture [--json] [--ct FILE] [--seeds A-B] [--pieces LIST]\n\n"
                 "Fractures the CT once per seed and number of pieces, the other options at their\n"
                 "defaults, and reports how many were made (made_pct), the seeds that failed with\n"
                 "their errors and the time per fracture, beside the targets: every seed made with 2\n"
                 "pieces (the defaults), 95%% with more.\n"
                 "  --ct FILE     the CT (default: the example CT, $FRACNAV_DATA/Cranium.inv3 or\n"
                 "                /var/cache/fracnav/Cranium.inv3)\n"
                 "  --seeds A-B   the seeds, A to B (default 1-100); N alone: 1-N\n"
                 "  --pieces LIST numbers of pieces, 2..10, comma-separated (default 2,8,10)\n"
                 "  --json        one JSON object on stdout: {\"command\": \"bench fracture\", ...}\n");
    return rc;
}

/* "A-B" or "N" (1-N) into o->first, o->last. */
static int parse_seeds(const char *v, opts *o)
{
    char *end = NULL;
    long a = v ? strtol(v, &end, 10) : -1, b;
    if (end && end != v && *end == '-')
        b = strtol(end + 1, &end, 10);
    else
        b = a, a = 1;
    if (!end || end == v || *end || a < 0 || b < a || b - a >= 100000)
        return cmd_bad_value("bench fracture", "--seeds", v, "A-B (0 <= A <= B) or N");
    o->first = (int)a;
    o->last = (int)b;
    return 0;
}

static int parse_pieces(const char *v, opts *o)
{
    char buf[256], *save = NULL;
    snprintf(buf, sizeof buf, "%s", v ? v : "");
    o->ncounts = 0;
    for (char *t = strtok_r(buf, ",", &save); t; t = strtok_r(NULL, ",", &save)) {
        char *end;
        long k = strtol(t, &end, 10);
        if (*end || k < 2 || k > 10 || o->ncounts == MAX_COUNTS)
            return cmd_bad_value("bench fracture", "--pieces", v, "whole numbers 2..10, comma-separated");
        o->pieces[o->ncounts++] = (int)k;
    }
    return o->ncounts ? 0 : cmd_bad_value("bench fracture", "--pieces", v, "whole numbers 2..10, comma-separated");
}

static int parse(int argc, char **argv, opts *o)
{
    *o = (opts){.first = 1, .last = 100, .pieces = {2, 8, 10}, .ncounts = 3};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int rc = 0;
        if (!strcmp(a, "--json"))
            o->json = 1;
        else if (!strcmp(a, "--ct") && v)
            o->ct = argv[++i];
        else if (!strcmp(a, "--seeds"))
            rc = parse_seeds(v, o), i++;
        else if (!strcmp(a, "--pieces"))
            rc = parse_pieces(v, o), i++;
        else {
            fprintf(stderr, "fracnav bench fracture: unknown or incomplete option '%s'\n", a);
            return usage(stderr, 2);
        }
        if (rc)
            return rc;
    }
    return 0;
}

/* The target for k pieces: issue 23's (every seed with the defaults, 95 of 100 with more). */
static double target_pct(int k)
{
    return k == 2 ? 100 : 95;
}

/* Every seed with k pieces: one object with the figures, the failed seeds and their errors. */
static json_t *run_count(const vol *ct, const opts *o, int k)
{
    int runs = o->last - o->first + 1, made = 0;
    double *ms = malloc(sizeof *ms * (size_t)runs);
    json_t *failed = json_array(), *r = json_object();
    if (!ms || !failed || !r) {
        free(ms);
        json_decref(failed);
        json_decref(r);
        return NULL;
    }
    for (int s = o->first; s <= o->last; s++) {
        fracture_params p;
        fracture_defaults(&p);
        p.seed = (uint64_t)s;
        p.pieces = k;
        fracture_result fr;
        double t0 = bench_now_us();
        int rc = fracture_make(ct, &p, &fr);
        ms[s - o->first] = (bench_now_us() - t0) * 1e-3;
        if (rc == 0) {
            made++;
            fracture_result_free(&fr);
        } else {
            json_array_append_new(failed, json_pack("{s:i,s:s}", "seed", s, "error", fn_err_msg()));
            fprintf(stderr, "bench fracture: %d pieces, seed %d failed: %s\n", k, s, fn_err_msg());
        }
    }
    fprintf(stderr, "bench fracture: %d pieces, seeds %d-%d: %d of %d made\n", k, o->first, o->last, made, runs);
    double pct = 100.0 * made / runs;
    json_object_set_new(r, "pieces", json_integer(k));
    json_object_set_new(r, "runs", json_integer(runs));
    json_object_set_new(r, "made", json_integer(made));
    json_object_set_new(r, "made_pct", jsonw_measure(pct));
    json_object_set_new(r, "failed", failed);
    json_object_set_new(r, "fracture_median_ms", jsonw_measure(bench_quantile(ms, runs, 0.5)));
    json_object_set_new(r, "fracture_max_ms", jsonw_measure(bench_quantile(ms, runs, 1)));
    json_object_set_new(r, "targets", json_pack("{s:o}", "made_pct", jsonw_measure(target_pct(k))));
    json_object_set_new(r, "target_met", json_boolean(pct >= target_pct(k)));
    free(ms);
    return r;
}

static void print_text(const json_t *counts)
{
    size_t i, j;
    json_t *c, *f;
    json_array_foreach(counts, i, c) {
        printf("%lld pieces: %lld of %lld made (%.0f%%, target %.0f%%: %s), median %.0f ms",
               json_integer_value(json_object_get(c, "pieces")), json_integer_value(json_object_get(c, "made")),
               json_integer_value(json_object_get(c, "runs")), json_real_value(json_object_get(c, "made_pct")),
               json_real_value(json_object_get(json_object_get(c, "targets"), "made_pct")),
               json_is_true(json_object_get(c, "target_met")) ? "met" : "not met",
               json_real_value(json_object_get(c, "fracture_median_ms")));
        json_array_foreach(json_object_get(c, "failed"), j, f)
            printf("%s seed %lld", j ? "," : "; failed:", json_integer_value(json_object_get(f, "seed")));
        printf("\n");
    }
}

int bench_fracture(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv))
        return usage(stdout, 0);
    opts o;
    int rc = parse(argc, argv, &o);
    if (rc)
        return rc;
    const char *path = o.ct ? o.ct : cmd_example_ct();
    vol *ct = volio_read(path);
    if (!ct) {
        fprintf(stderr, "fracnav bench fracture: %s\n", fn_err_msg());
        return 1;
    }
    json_t *root = jsonw_object("bench fracture"), *counts = json_array();
    for (int i = 0; i < o.ncounts && counts; i++) {
        json_t *c = run_count(ct, &o, o.pieces[i]);
        if (!c || json_array_append_new(counts, c) < 0) {
            json_decref(counts);
            counts = NULL;
        }
    }
    vol_free(ct);
    if (!root || !counts) {
        fprintf(stderr, "fracnav bench fracture: out of memory\n");
        json_decref(root);
        json_decref(counts);
        return 1;
    }
    jsonw_set(root, "ct", jsonw_string(path));
    jsonw_set(root, "seed_first", json_integer(o.first));
    jsonw_set(root, "seed_last", json_integer(o.last));
    jsonw_set(root, "counts", counts);
    if (o.json)
        return jsonw_print(root, stdout) ? 1 : 0;
    print_text(counts);
    json_decref(root);
    return 0;
}
