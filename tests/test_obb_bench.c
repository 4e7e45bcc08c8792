/* fracnav bench: the CLI's usage handling and a small collision benchmark end to end. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static void test_usage(void **st)
{
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "bench --help"), 0);
    assert_non_null(strstr(out, "collision"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "bench"), 2);
    free(out);
    assert_int_equal(tu_run_cli(&out, "bench nosuch"), 2);
    assert_non_null(strstr(out, "fracnav bench: unknown benchmark 'nosuch'"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "bench collision --poses many"), 2);
    assert_non_null(strstr(out, "not a number"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "bench collision --help"), 0);
    assert_non_null(strstr(out, "--poses"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "bench collision /nonexistent/ct.nii.gz --poses 4"), 1);
    assert_non_null(strstr(out, "fracnav bench collision:"));
    free(out);
}

/* A small tube of bone, fractured by the benchmark itself: every answer must match brute force. */
static void test_collision_on_small_bone(void **st)
{
    char *dir = tu_tmpdir("obbbench"), path[4200];
    snprintf(path, sizeof path, "%s/tube.nii.gz", dir);
    vol *v = vol_new(40, 40, 48);
    assert_non_null(v);
    for (int k = 0; k < 48; k++)
        for (int j = 0; j < 40; j++)
            for (int i = 0; i < 40; i++) {
                double r = hypot(i - 19.5, j - 19.5);
                v->data[vol_idx(v, i, j, k)] = k > 2 && k < 45 && r > 8 && r < 15 ? 1400.f : -1000.f;
            }
    assert_int_equal(volio_write(v, path, VOL_I16), 0);
    vol_free(v);
    char *out = NULL;
    int rc = tu_run_cli(&out, "bench collision '%s' --bone 300 --poses 40 --reps 1 --no-fcl --json",
                        path);
    if (rc != 0)
        fail_msg("bench failed (%d): %s", rc, out);
    json_t *j = json_loads(out, 0, NULL), *w = json_array_get(json_object_get(j, "workloads"), 0);
    if (!w)
        fail_msg("no workload in: %s", out);
    assert_int_equal(json_integer_value(json_object_get(w, "poses")), 40);
    assert_int_equal(json_integer_value(json_object_get(w, "false_negatives")), 0);
    assert_int_equal(json_integer_value(json_object_get(w, "false_positives")), 0);
    assert_int_equal(json_integer_value(json_object_get(w, "node_bytes")), 16);
    json_decref(j);
    free(out);
    tu_rmtree(dir);
    free(dir);
}

/* The pitch workload reads the CT_pitch the repository ships (tests/data/), from any folder and
 * without $FRACNAV_SRC: nothing beside the clone is needed. */
static void test_pitch_workload_from_the_repository(void **st)
{
    char *dir = tu_tmpdir("pitch"), *out = NULL, cwd[4096];
    char *src = getenv("FRACNAV_SRC") ? strdup(getenv("FRACNAV_SRC")) : NULL;
    unsetenv("FRACNAV_SRC");
    assert_non_null(getcwd(cwd, sizeof cwd));
    assert_int_equal(chdir(dir), 0);
    int rc = tu_run_cli(&out, "bench collision pitch --poses 4 --reps 1 --no-fcl --json");
    assert_int_equal(chdir(cwd), 0);
    if (src)
        setenv("FRACNAV_SRC", src, 1);
    free(src);
    if (rc != 0)
        fail_msg("bench collision pitch failed (%d): %s", rc, out);
    assert_non_null(strstr(out, "\"pitch\""));
    free(out);
    tu_rmtree(dir);
    free(dir);
}

/* bench reduce --suite (one fit per workload, a whole case of 3 and of 6 pieces: a minute or so):
 * every workload of the README's table in one object, each named and with its own runs, and the
 * runs pooled per method, with the default method alone; the pooled evaluation time is null (each
 * CT has its own). The workloads of the pelvic development set, given a folder that is not there,
 * are listed as skipped, with a word. */
static void test_reduce_suite_pools_every_workload(void **st)
{
    tu_example_ct(); /* the skull workloads: skipped (or failed under CI) without it */
    char *out = NULL;
    int rc = tu_run_cli(&out, "bench reduce --suite --seeds 1 --starts 1 --labels /nonexistent/pelvis-dev --json");
    /* stdout and stderr come together here: the JSON follows the progress lines ("... done") */
    const char *at = out && out[0] == '{' ? out : out ? strstr(out, "\n{") : NULL;
    json_error_t e;
    json_t *j = rc == 0 && at ? json_loads(at, 0, &e) : NULL;
    if (!j)
        fail_msg("bench reduce --suite: exit %d: %s", rc, out);
    if (!strstr(out, "pelvis, real fragments moved off their CT pose skipped: no development set at "
                     "/nonexistent/pelvis-dev"))
        fail_msg("no word of the skipped workloads:\n%s", out);
    free(out);
    static const char *const names[] = {"skull", "skull, starts up to 20 mm", "skull, 3 pieces", "skull, 6 pieces",
                                        "skull, 3 pieces, whole case", "skull, 6 pieces, whole case",
                                        "skull, pieces left touching", "skull, 1 mm of bone lost", "CT_pitch",
                                        "long bone", "skull, second fracture model", "pelvis, intact bones",
                                        "pelvis, real fragments"};
    const size_t nw = sizeof names / sizeof names[0], nskipped = 2;
    json_t *ws = json_object_get(j, "workloads"), *pooled = json_array_get(json_object_get(j, "pooled"), 0);
    assert_int_equal(json_array_size(ws), nw);
    json_int_t runs = 0;
    for (size_t i = 0; i < nw; i++) {
        json_t *w = json_array_get(ws, i), *m = json_object_get(w, "methods");
        const char *name = json_string_value(json_object_get(w, "workload"));
        if (!name || strncmp(name, names[i], strlen(names[i])))
            fail_msg("workload %zu is '%s', not '%s...'", i, name ? name : "(none)", names[i]);
        if (i >= nw - nskipped) {
            assert_non_null(json_string_value(json_object_get(w, "skipped")));
            continue;
        }
        assert_int_equal(json_array_size(m), 1);
        json_t *m0 = json_array_get(m, 0);
        json_int_t n = json_integer_value(json_object_get(m0, "runs"));
        if (strstr(names[i], "whole case")) {
            /* a whole case: a run per piece moved (K - 1 but those that touch nothing), and the
             * case's own seconds */
            json_int_t skipped = json_integer_value(json_object_get(m0, "pieces_skipped"));
            json_int_t k = json_integer_value(json_object_get(w, "pieces"));
            assert_true(k == 3 || k == 6);
            assert_int_equal(json_integer_value(json_object_get(m0, "cases")), 1);
            assert_int_equal(n + skipped, k - 1);
            assert_true(json_real_value(json_object_get(m0, "median_case_seconds")) > 0);
            assert_true(json_is_null(json_object_get(m0, "metric_eval_us")));
        } else
            assert_int_equal(n, 1);
        runs += n;
    }
    assert_string_equal(json_string_value(json_object_get(j, "command")), "bench reduce");
    assert_string_equal(json_string_value(json_object_get(pooled, "method")),
                        json_string_value(json_object_get(j, "default_method")));
    assert_int_equal(json_integer_value(json_object_get(pooled, "runs")), runs);
    assert_true(json_is_null(json_object_get(pooled, "metric_eval_us")));
    /* the fits' own evaluations pool: a figure over every run */
    assert_true(json_real_value(json_object_get(pooled, "fit_eval_mean_us")) > 0);
    json_decref(j);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_usage),
        cmocka_unit_test(test_collision_on_small_bone),
        cmocka_unit_test(test_pitch_workload_from_the_repository),
        cmocka_unit_test(test_reduce_suite_pools_every_workload),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
