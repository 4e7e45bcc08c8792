/* The README's first command ends in `fracnav demo`: it must work end to end on the example CT. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "testutil.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static void test_demo_runs_the_workflow(void **st)
{
    const char *ct = tu_example_ct();
    char *dir = tu_tmpdir("demo");
    char *out = NULL;
    int rc = tu_run_cli(&out, "demo '%s' -o '%s/d'", ct, dir);
    if (rc != 0)
        fail_msg("fracnav demo exited %d:\n%s", rc, out);
    /* the skull and the two halves of the head holder */
    assert_non_null(strstr(out, "3 kept"));
    assert_non_null(strstr(out, "403557"));
    assert_non_null(strstr(out, "head holder"));
    /* the fracture and the replay, with no collision among the accepted poses */
    assert_non_null(strstr(out, "ground truth moves its centroid back"));
    assert_non_null(strstr(out, "collisions in accepted poses: 0"));
    const char *files[] = {"case/case.json", "case/labels.nii.gz", "segmentation-front.png",
                           "segmentation-right.png", "segmentation-below.png", "fracture/case.json",
                           "fracture-right.png", "head-on.fnrec"};
    for (size_t i = 0; i < sizeof files / sizeof files[0]; i++) {
        char p[4200];
        snprintf(p, sizeof p, "%s/d/%s", dir, files[i]);
        if (access(p, R_OK) != 0)
            fail_msg("demo did not write %s", p);
    }
    /* A second run over the same folder works too (the README's command is idempotent); the
     * hierarchy thresholds given go into both cases. */
    free(out);
    rc = tu_run_cli(&out, "demo '%s' -o '%s/d' --tau-min 0.25 --tau-max 0.75", ct, dir);
    if (rc != 0)
        fail_msg("second fracnav demo exited %d:\n%s", rc, out);
    free(out);
    const char *cases[] = {"case", "fracture"};
    for (size_t i = 0; i < 2; i++) {
        char p[4200];
        snprintf(p, sizeof p, "%s/d/%s/case.json", dir, cases[i]);
        char *json = tu_slurp(p, NULL);
        assert_non_null(json);
        if (!strstr(json, "\"tau_min\": 0.25") || !strstr(json, "\"tau_max\": 0.75"))
            fail_msg("%s does not keep --tau-min 0.25 --tau-max 0.75:\n%s", p, json);
        free(json);
    }
    assert_int_equal(tu_run_cli(&out, "demo '%s' -o '%s/d' --tau-max 1.5", ct, dir), 2);
    assert_non_null(strstr(out, "--tau-max: '1.5' is not a number from 0 to 1"));
    free(out);
    tu_rmtree(dir);
    free(dir);
}

static void test_demo_names_a_missing_ct(void **st)
{
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "demo /nonexistent/ct.nii -o /tmp"), 1);
    assert_non_null(strstr(out, "/nonexistent/ct.nii"));
    assert_null(strstr(out, ".ci/setup")); /* the user's own CT: .ci/setup cannot bring it */
    free(out);
    const char *data = getenv("FRACNAV_DATA");
    char *keep = data ? strdup(data) : NULL;
    setenv("FRACNAV_DATA", "/nonexistent-data", 1); /* the example CT, not fetched yet */
    assert_int_equal(tu_run_cli(&out, "demo -o /tmp"), 1);
    if (keep)
        setenv("FRACNAV_DATA", keep, 1);
    else
        unsetenv("FRACNAV_DATA");
    free(keep);
    assert_non_null(strstr(out, "/nonexistent-data/Cranium.inv3"));
    assert_non_null(strstr(out, ".ci/setup"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "demo --bogus"), 2);
    free(out);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_demo_runs_the_workflow),
        cmocka_unit_test(test_demo_names_a_missing_ct),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
