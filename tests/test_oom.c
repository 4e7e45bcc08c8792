/* Out of memory on every loading path: the Nth allocation of the project's own code fails, for
 * every N along the path that loads a volume (NIfTI, NRRD, InVesalius), a case, a recording and a
 * controller configuration. Each must return a clean error with a message (or succeed where it can
 * do without), never crash; under AddressSanitizer, LeakSanitizer then checks that nothing leaked.
 * See failalloc.h for what is and is not covered (third-party libraries keep the real allocator). */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "calib.h"
#include "case.h"
#include "err.h"
#include "failalloc.h"
#include "fnrec.h"
#include "seg.h"
#include "testutil.h"
#include "volio.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* One loading path: returns the loaded object (non-NULL) or NULL with fn_err_msg() set. */
typedef void *(*load_fn)(const char *path);
typedef void (*free_fn)(void *obj);

/* Fails allocation 1, 2, 3, ... of load(path) until a run completes without reaching the armed
 * failure. Returns how many allocations the path made. */
static long fail_each(load_fn load, free_fn release, const char *path)
{
    for (long n = 1; n < 200000; n++) {
        fn_err_clear();
        failalloc_arm(n);
        void *obj = load(path);
        int injected = failalloc_disarm();
        if (obj)
            release(obj);
        if (!injected) {
            assert_non_null(obj); /* the path itself must work with memory to spare */
            return n - 1;
        }
        if (!obj && !strcmp(fn_err_msg(), "no error recorded"))
            fail_msg("%s: allocation %ld failed and the load returned no error message", path, n);
    }
    fail_msg("%s: more than 200000 allocations", path);
    return 0;
}

static void *load_vol(const char *path)
{
    return volio_read(path);
}

static void free_vol(void *v)
{
    vol_free(v);
}

static void *load_case(const char *dir)
{
    return case_load(dir);
}

static void free_case(void *c)
{
    case_free(c);
}

static void *load_fnrec(const char *path)
{
    return fnrec_load(path);
}

static void free_fnrec(void *r)
{
    fnrec_free(r);
}

static calib loaded_calib;

static void *load_calib(const char *path)
{
    calib_default(&loaded_calib);
    char used[256], diag[512];
    int rc = calib_load(&loaded_calib, path, used, sizeof used, diag, sizeof diag);
    return rc < 0 ? NULL : &loaded_calib;
}

static void free_nothing(void *p)
{
    (void)p;
}

/* Two bone blocks, int16, 1.5 mm voxels. */
static vol *small_ct(void)
{
    vol *v = vol_new(20, 14, 10);
    double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, sp[3] = {1.5, 1.5, 1.5}, org[3] = {0, 0, 0};
    vol_set_geometry(v, dir, sp, org);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = -1000;
    for (int k = 2; k < 8; k++)
        for (int j = 2; j < 12; j++) {
            for (int i = 2; i < 8; i++)
                v->data[vol_idx(v, i, j, k)] = 800;
            for (int i = 11; i < 18; i++)
                v->data[vol_idx(v, i, j, k)] = 1000;
        }
    return v;
}

static void test_volumes(void **st)
{
    char *dir = tu_tmpdir("oom-vol");
    vol *v = small_ct();
    const char *names[] = {"ct.nii.gz", "ct.nii", "ct.nrrd"};
    for (size_t i = 0; i < sizeof names / sizeof *names; i++) {
        char p[512];
        snprintf(p, sizeof p, "%s/%s", dir, names[i]);
        assert_int_equal(volio_write(v, p, VOL_I16), 0);
        long n = fail_each(load_vol, free_vol, p);
        print_message("%s: %ld allocations, each failed once\n", names[i], n);
        assert_true(n > 0);
    }
    vol_free(v);
    tu_rmtree(dir);
    free(dir);
}

static void test_inv3(void **st)
{
    const char *ct = tu_example_ct();
    if (access(ct, R_OK) != 0)
        skip();
    long n = fail_each(load_vol, free_vol, ct);
    print_message("Cranium.inv3: %ld allocations, each failed once\n", n);
    assert_true(n > 0);
}

static void test_case(void **st)
{
    char *dir = tu_tmpdir("oom-case");
    char src[512], cdir[512];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    vol *ct = small_ct();
    assert_int_equal(volio_write(ct, src, VOL_I16), 0);
    seg_params p;
    seg_defaults(&p);
    seg_result r;
    assert_int_equal(seg_run(ct, &p, &r), 0);
    vol *labels = r.labels;
    r.labels = NULL;
    seg_result_free(&r);
    planning_case *c = case_create(cdir, src, ct, labels, &p);
    assert_non_null(c);
    assert_int_equal(case_save(c), 0);
    case_free(c);
    long n = fail_each(load_case, free_case, cdir);
    print_message("case: %ld allocations, each failed once\n", n);
    assert_true(n > 0);
    tu_rmtree(dir);
    free(dir);
}

static void test_recording(void **st)
{
    const char *src = tu_src();
    char p[512];
    snprintf(p, sizeof p, "%s/sim/recordings/buttons.fnrec", src);
    long n = fail_each(load_fnrec, free_fnrec, p);
    print_message("buttons.fnrec: %ld allocations, each failed once\n", n);
    assert_true(n > 0);
}

static void test_config(void **st)
{
    char *dir = tu_tmpdir("oom-rc");
    char p[512];
    snprintf(p, sizeof p, "%s/spnavrc", dir);
    const char *rc = "# mine\nsensitivity = 1.5\ndeadzone = 4\ninvert-rot = yes\nbnact1 = fix\n"
                     "not-a-key = 3\n";
    tu_write_file(p, rc, strlen(rc));
    fail_each(load_calib, free_nothing, p);
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_volumes),
        cmocka_unit_test(test_inv3),
        cmocka_unit_test(test_case),
        cmocka_unit_test(test_recording),
        cmocka_unit_test(test_config),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
