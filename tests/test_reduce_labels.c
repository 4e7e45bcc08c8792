/* bench reduce --labels on a tiny labelled CT made here (no shared data): a bone of two annotated
 * fragments, interlocked by a wavy cut, and an intact bone. The starts stay in their ranges (3-10
 * mm, 5-15 degrees off the CT pose), the intact bone is named and left alone (and is the one
 * --intact fractures), a bone's starts do not depend on what else the folder holds, bad folders are
 * refused with their name. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "reduce.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

static char *dir;

/* A block of bone (1000 HU, 0 outside as in the development set's CTs) on a 1 mm grid; label 1
 * below a wavy cut across x, label 2 beyond it (about 5 ml), or label 1 everywhere (intact). */
static void write_bone_in(const char *folder, const char *name, int fractured)
{
    const int nx = 48, ny = 32, nz = 32;
    vol *ct = vol_new(nx, ny, nz), *lab = vol_new(nx, ny, nz);
    assert_non_null(ct);
    assert_non_null(lab);
    for (int k = 0; k < nz; k++)
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++) {
                int in = i >= 6 && i < 42 && j >= 6 && j < 26 && k >= 6 && k < 26;
                double cut = 27 + 2.5 * sin(j * 0.7) + 2 * cos(k * 0.55 + 1);
                ct->data[vol_idx(ct, i, j, k)] = in ? (float)(1000 + (i * 7 + j * 13 + k * 3) % 300) : 0.f;
                lab->data[vol_idx(lab, i, j, k)] = !in ? 0.f : fractured && i >= cut ? 2.f : 1.f;
            }
    char path[4300];
    snprintf(path, sizeof path, "%s/%s.nii.gz", folder, name);
    assert_int_equal(volio_write(ct, path, VOL_I16), 0);
    snprintf(path, sizeof path, "%s/%s_mask.nii.gz", folder, name);
    assert_int_equal(volio_write(lab, path, VOL_I16), 0);
    vol_free(ct);
    vol_free(lab);
}

static void write_bone(const char *name, int fractured)
{
    write_bone_in(dir, name, fractured);
}

static int setup(void **st)
{
    dir = tu_tmpdir("reducelabels");
    write_bone("001_XB", 1);
    write_bone("002_XB", 0);
    return 0;
}

static int teardown(void **st)
{
    tu_rmtree(dir);
    free(dir);
    return 0;
}

static double num(const json_t *o, const char *key)
{
    json_t *v = json_object_get(o, key);
    if (!json_is_number(v))
        fail_msg("\"%s\" is not a number", key);
    return json_number_value(v);
}

static void test_starts_in_range(void **st)
{
    char *out = NULL, json_path[4300];
    snprintf(json_path, sizeof json_path, "%s/out.json", dir);
    int rc = tu_run_cli(&out, "bench reduce --labels '%s' --starts 4 --json > '%s'", dir, json_path);
    if (rc != 0)
        fail_msg("bench reduce --labels: exit %d\n%s", rc, out);
    free(out);
    json_error_t je;
    json_t *j = json_load_file(json_path, 0, &je);
    assert_non_null(j);
    assert_string_equal(json_string_value(json_object_get(j, "command")), "bench reduce");
    json_t *bones = json_object_get(j, "bones"), *intact = json_object_get(j, "intact");
    assert_int_equal(json_array_size(bones), 1);
    assert_int_equal(json_array_size(intact), 1);
    assert_string_equal(json_string_value(json_array_get(intact, 0)), "002_XB");
    json_t *b = json_array_get(bones, 0), *mv = json_object_get(b, "moving");
    assert_string_equal(json_string_value(json_object_get(b, "bone")), "001_XB");
    assert_int_equal(json_integer_value(json_object_get(b, "fixed")), 1);
    assert_int_equal(json_array_size(mv), 1);
    assert_int_equal(json_integer_value(json_object_get(json_array_get(mv, 0), "label")), 2);
    assert_true(json_integer_value(json_object_get(json_array_get(mv, 0), "contact_faces")) >= 20 * 20);
    assert_int_equal(json_integer_value(json_object_get(b, "runs")), 4);
    /* 6 significant digits in the JSON */
    assert_true(num(b, "start_trans_min_mm") >= 3 - 1e-4 && num(b, "start_trans_max_mm") <= 10 + 1e-4);
    assert_true(num(b, "start_rot_min_deg") >= 5 - 1e-4 && num(b, "start_rot_max_deg") <= 15 + 1e-4);
    assert_true(num(b, "start_trans_max_mm") > num(b, "start_trans_min_mm"));
    double back = num(b, "back_rate");
    assert_true(back >= 0 && back <= 1);
    /* every fit not back is counted on one side of the CT pose's metric */
    json_int_t failed = json_integer_value(json_object_get(b, "failed_ct_better_count")) +
                        json_integer_value(json_object_get(b, "failed_end_better_count"));
    assert_true(fabs((double)failed - (1 - back) * 4) < 1e-3);
    json_int_t farther = json_integer_value(json_object_get(b, "ended_farther_count"));
    assert_true(farther >= 0 && farther <= 4);
    assert_int_equal(json_integer_value(json_object_get(json_object_get(j, "pooled"), "runs")), 4);
    assert_true(num(json_object_get(j, "targets"), "back_rate") == 0.95);
    reduce_opts def;
    reduce_defaults(&def);
    assert_string_equal(json_string_value(json_object_get(j, "method")), reduce_method_name(def.method));
    json_decref(j);
}

/* --intact: only the bone of one label is fractured (model 1) and fitted. */
static void test_intact_bones_fractured(void **st)
{
    char *out = NULL, json_path[4300];
    snprintf(json_path, sizeof json_path, "%s/intact.json", dir);
    int rc = tu_run_cli(&out, "bench reduce --intact '%s' --seeds 1 --starts 2 --method praxis --json > '%s'", dir,
                        json_path);
    if (rc != 0)
        fail_msg("bench reduce --intact: exit %d\n%s", rc, out);
    free(out);
    json_t *j = json_load_file(json_path, 0, NULL);
    assert_non_null(j);
    assert_string_equal(json_string_value(json_object_get(j, "ct")), dir);
    json_t *m = json_array_get(json_object_get(j, "methods"), 0);
    assert_int_equal(json_integer_value(json_object_get(m, "runs")), 2); /* one bone, 1 seed x 2 starts */
    json_decref(j);
}

/* The figures of one bone in a folder of several, and in a folder of its own. */
static json_t *bone_in(const char *folder, const char *name)
{
    char *out = NULL, json_path[4300];
    snprintf(json_path, sizeof json_path, "%s/out.json", folder);
    int rc = tu_run_cli(&out, "bench reduce --labels '%s' --starts 2 --json > '%s'", folder, json_path);
    if (rc != 0)
        fail_msg("bench reduce --labels %s: exit %d\n%s", folder, rc, out);
    free(out);
    json_t *j = json_load_file(json_path, 0, NULL), *bones = json_object_get(j, "bones"), *b = NULL;
    assert_non_null(j);
    for (size_t i = 0; i < json_array_size(bones); i++)
        if (!strcmp(json_string_value(json_object_get(json_array_get(bones, i), "bone")), name))
            b = json_incref(json_array_get(bones, i));
    json_decref(j);
    if (!b)
        fail_msg("no bone %s in the figures of %s", name, folder);
    return b;
}

/* A bone's starts are its own: the same whatever else the folder holds (they were drawn from one
 * sequence over the folder, so a bone's figures depended on the bones before it). */
static void test_starts_do_not_depend_on_the_folder(void **st)
{
    char alone[4300], two[4300];
    snprintf(alone, sizeof alone, "%s/alone", dir);
    snprintf(two, sizeof two, "%s/two", dir);
    assert_int_equal(mkdir(alone, 0755), 0);
    assert_int_equal(mkdir(two, 0755), 0);
    write_bone_in(alone, "001_XB", 1);
    write_bone_in(two, "000_XA", 1); /* listed first: its starts are drawn first */
    write_bone_in(two, "001_XB", 1);
    json_t *a = bone_in(alone, "001_XB"), *b = bone_in(two, "001_XB");
    const char *keys[] = {"start_rot_min_deg", "start_rot_max_deg", "start_trans_min_mm", "start_trans_max_mm",
                          "back_rate"};
    for (size_t k = 0; k < sizeof keys / sizeof *keys; k++)
        if (num(a, keys[k]) != num(b, keys[k]))
            fail_msg("001_XB's %s: %g alone, %g beside 000_XA", keys[k], num(a, keys[k]), num(b, keys[k]));
    json_decref(a);
    json_decref(b);
}

static void test_bad_folder(void **st)
{
    char *out = NULL;
    int rc = tu_run_cli(&out, "bench reduce --labels '%s/none' --json", dir);
    assert_int_equal(rc, 1);
    if (!strstr(out, "/none"))
        fail_msg("the error does not name the folder:\n%s", out);
    free(out);
    rc = tu_run_cli(&out, "bench reduce --labels");
    assert_int_equal(rc, 2);
    free(out);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_starts_in_range),
        cmocka_unit_test(test_intact_bones_fractured),
        cmocka_unit_test(test_starts_do_not_depend_on_the_folder),
        cmocka_unit_test(test_bad_folder),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
