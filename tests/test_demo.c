/* The README's first command ends in `fracnav demo`: it must work end to end on the example CT:
 * segment, fracture, navigate the shipped recording through the virtual device (FUSE, and without
 * it), reduce, export with the report, and say where the results are and what it measured. */
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
    /* the fracture, and the navigation: the push refused, no collision among the accepted poses */
    assert_non_null(strstr(out, "its true place is"));
    assert_non_null(strstr(out, "demo-approach.fnrec"));
    assert_non_null(strstr(out, "collisions in accepted poses: 0"));
    const char *r = strstr(out, " slid, ");
    long refused = 0;
    assert_non_null(r);
    assert_int_equal(sscanf(r, " slid, %ld refused", &refused), 1);
    assert_true(refused > 0);
    /* the reduction lands near the truth, and the summary names the results and the figures */
    const char *e = strstr(out, "error against the truth: ");
    double deg = 99, mm = 99;
    assert_non_null(e);
    assert_int_equal(sscanf(e, "error against the truth: %lf deg, %lf mm", &deg, &mm), 2);
    if (deg > 1.0 || mm > 1.0)
        fail_msg("the demo's reduction is %.2f deg, %.2f mm from the truth:\n%s", deg, mm, out);
    const char *figures[] = {"collision query:   mean", "loop rate:", "reduction:", "whole demo:",
                             "/export/report/index.html"};
    for (size_t i = 0; i < sizeof figures / sizeof figures[0]; i++)
        if (!strstr(out, figures[i]))
            fail_msg("the demo's summary lacks '%s':\n%s", figures[i], out);
    const char *files[] = {"case/case.json", "case/labels.nii.gz", "segmentation-anterior.png",
                           "fracture/case.json", "fracture-anterior.png", "navigate.json",
                           "frames/navigation-00.png", "frames/navigation-07.png",
                           "export/report/index.html", "export/report/convergence.png",
                           "export/report/before.png", "export/report/after.png",
                           "export/models/fragment-2.stl", "export/transforms/fragment-2.tfm",
                           "export/planned.seg.nrrd", "export/planned.nii.gz"};
    for (size_t i = 0; i < sizeof files / sizeof files[0]; i++) {
        char p[4200];
        snprintf(p, sizeof p, "%s/d/%s", dir, files[i]);
        if (access(p, R_OK) != 0)
            fail_msg("demo did not write %s", p);
    }
    /* the fracture case keeps the reduction */
    char p[4200];
    snprintf(p, sizeof p, "%s/d/fracture/case.json", dir);
    char *json = tu_slurp(p, NULL);
    assert_non_null(json);
    assert_non_null(strstr(json, "\"reduction\""));
    free(json);
    /* A second run over the same folder works too (the README's command is idempotent), here with
     * the recording played in-process; the hierarchy thresholds given go into both cases. --view
     * reaches navigate: without a display it says so, and the demo goes on headless. */
    free(out);
    const char *display = getenv("DISPLAY");
    char *display_saved = display ? strdup(display) : NULL;
    unsetenv("DISPLAY");
    rc = tu_run_cli(&out, "demo '%s' -o '%s/d' --no-fuse --tau-min 0.25 --tau-max 0.75 --view window", ct, dir);
    if (display_saved)
        setenv("DISPLAY", display_saved, 1);
    free(display_saved);
    if (rc != 0)
        fail_msg("second fracnav demo exited %d:\n%s", rc, out);
    assert_non_null(strstr(out, "fracnav navigate: no window ($DISPLAY is not set)"));
    assert_non_null(strstr(out, "replay-realtime"));
    assert_non_null(strstr(out, "collisions in accepted poses: 0"));
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
    char *out = NULL, *o = tu_tmpdir("demo-missing-ct"); /* empty: -o /tmp, with others' files, is refused */
    assert_int_equal(tu_run_cli(&out, "demo /nonexistent/ct.nii -o '%s'", o), 1);
    assert_non_null(strstr(out, "/nonexistent/ct.nii"));
    assert_null(strstr(out, ".ci/setup")); /* the user's own CT: .ci/setup cannot bring it */
    free(out);
    const char *data = getenv("FRACNAV_DATA");
    char *keep = data ? strdup(data) : NULL;
    setenv("FRACNAV_DATA", "/nonexistent-data", 1); /* the example CT, not fetched yet */
    assert_int_equal(tu_run_cli(&out, "demo -o '%s'", o), 1);
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
    assert_int_equal(tu_run_cli(&out, "demo --view bogus"), 2);
    assert_non_null(strstr(out, "--view: 'bogus' is not window or terminal"));
    free(out);
    tu_rmtree(o);
    free(o);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_demo_runs_the_workflow),
        cmocka_unit_test(test_demo_names_a_missing_ct),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
