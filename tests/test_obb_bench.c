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

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_usage),
        cmocka_unit_test(test_collision_on_small_bone),
        cmocka_unit_test(test_pitch_workload_from_the_repository),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
