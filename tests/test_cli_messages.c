/* What a user sees for bad options of segment, fracture and edit: the option, the value and what
 * is accepted, exit 2 for usage errors. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "testutil.h"
#include "volio.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

struct fixture {
    char *tmp;
    char ct[4200], cdir[4200];
};

/* One 8x8x8 block of bone (1200) in a 24^3 CT of -1000, and its segmented case. */
static int setup(void **st)
{
    struct fixture *f = calloc(1, sizeof *f);
    f->tmp = tu_tmpdir("cli-msg");
    snprintf(f->ct, sizeof f->ct, "%s/ct.nii.gz", f->tmp);
    snprintf(f->cdir, sizeof f->cdir, "%s/case", f->tmp);
    vol *v = vol_new(24, 24, 24);
    for (int k = 0; k < 24; k++)
        for (int j = 0; j < 24; j++)
            for (int i = 0; i < 24; i++)
                v->data[vol_idx(v, i, j, k)] = i >= 8 && i < 16 && j >= 8 && j < 16 && k >= 8 && k < 16 ? 1200 : -1000;
    if (volio_write(v, f->ct, VOL_I16) < 0)
        fail_msg("%s", fn_err_msg());
    vol_free(v);
    tu_segment(f->ct, f->cdir, "");
    *st = f;
    return 0;
}

static void test_segment(void **st)
{
    struct fixture *f = *st;
    const char *o = f->tmp;
    tu_expect_cli(2, "fracnav segment: --threshold: 'abc' is not a number (HU), 'auto' or 'auto-bone'",
                  "segment '%s' -o '%s/s' --threshold abc", f->ct, o);
    tu_expect_cli(2, "fracnav segment: unknown option '--bogus'", "segment '%s' -o '%s/s' --bogus", f->ct, o);
    tu_expect_cli(2, "fracnav segment: unknown option '--bogus'", "segment '%s' -o '%s/s' --bogus 3", f->ct, o);
    tu_expect_cli(2, "--threshold needs a value", "segment '%s' -o '%s/s' --threshold", f->ct, o);
    tu_expect_cli(2, "--min-volume: '-1' is not a number of ml >= 0",
                  "segment '%s' -o '%s/s' --min-volume -1", f->ct, o);
    tu_expect_cli(2, "--keep: '1.5' is not a whole number", "segment '%s' -o '%s/s' --keep 1.5", f->ct, o);
    tu_expect_cli(2, "--ramp: 'wide' is not a number >= 0", "segment '%s' -o '%s/s' --ramp wide", f->ct, o);
    tu_expect_cli(0, "1 kept", "segment '%s' -o '%s/s' --threshold auto-bone --ramp 0", f->ct, o);
    /* No bone is an error that says what was found, and leaves no case. */
    tu_expect_cli(1, "no bone: the volume's values run from -1000 to 1200, none at or above the threshold 1500",
                  "segment '%s' -o '%s/none' --threshold 1500", f->ct, o);
    tu_expect_cli(1, "none of the 1 components reaches --min-volume 5 ml",
                  "segment '%s' -o '%s/none' --min-volume 5", f->ct, o);
    char none[4300];
    snprintf(none, sizeof none, "%s/none", o);
    assert_int_not_equal(access(none, F_OK), 0);
    /* --labels uses no threshold, and says so. */
    char lab[4300], *out = NULL;
    snprintf(lab, sizeof lab, "%s/labels.nii.gz", o);
    vol *v = volio_read(f->ct);
    assert_non_null(v);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = v->data[i] > 0 ? 3 : 0;
    assert_int_equal(volio_write(v, lab, VOL_U8), 0);
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s/l' --labels '%s'", f->ct, o, lab), 0);
    if (!strstr(out, "labels of ") || strstr(out, "threshold"))
        fail_msg("%s", out);
    free(out);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = 0;
    assert_int_equal(volio_write(v, lab, VOL_U8), 0);
    vol_free(v);
    tu_expect_cli(1, "labels.nii.gz holds no label over 0", "segment '%s' -o '%s/none' --labels '%s'", f->ct, o, lab);
}

static void test_fracture(void **st)
{
    struct fixture *f = *st;
    const char *o = f->tmp;
    tu_expect_cli(2, "fracnav fracture: --threshold: 'abc' is not a number (HU)",
                  "fracture '%s' -o '%s/f' --seed 1 --threshold abc", f->ct, o);
    tu_expect_cli(2, "fracnav fracture: unknown option '--bogus'",
                  "fracture '%s' -o '%s/f' --seed 1 --bogus", f->ct, o);
    tu_expect_cli(2, "--seed: '-3' is not a whole number", "fracture '%s' -o '%s/f' --seed -3", f->ct, o);
    tu_expect_cli(2, "--seed needs a value", "fracture '%s' -o '%s/f' --seed", f->ct, o);
    tu_expect_cli(2, "--rotate: 'x' is not a number of degrees",
                  "fracture '%s' -o '%s/f' --seed 1 --rotate x", f->ct, o);
    /* No module prefix doubled after the command's. */
    tu_expect_cli(2, "fracnav fracture: --pieces: '11' is not a whole number 2..10",
                  "fracture '%s' -o '%s/f' --seed 1 --pieces 11", f->ct, o);
    tu_expect_cli(2, "fracnav fracture: bone loss must be 0..20 mm (got 25) (see",
                  "fracture '%s' -o '%s/f' --seed 1 --bone-loss 25", f->ct, o);
    /* The threshold given, and the CT's range, not 0. */
    tu_expect_cli(1, "no bone at or above 1500: the CT's values run from -1000 to 1200",
                  "fracture '%s' -o '%s/f' --seed 1 --threshold 1500", f->ct, o);
    /* One prefix: the command's, not "fracnav fracture: fracture: ...". */
    tu_expect_cli(1, "fracnav fracture: no bone at or above 1500",
                  "fracture '%s' -o '%s/f' --seed 1 --threshold 1500", f->ct, o);
    /* demo takes --threshold too, for steps 1 and 2. */
    tu_expect_cli(1,
                  "fracnav demo: segmentation: no bone: the volume's values run from -1000 to 1200, none at or "
                  "above the threshold 1500",
                  "demo '%s' -o '%s/d' --threshold 1500 --no-fuse", f->ct, o);
}

static void test_edit(void **st)
{
    struct fixture *f = *st;
    tu_expect_cli(2, "fracnav edit: erase-sphere R: '-5' is not a radius > 0 mm",
                  "edit '%s' erase-sphere 0 0 0 -5", f->cdir);
    tu_expect_cli(2, "erase-box: unknown option or extra argument '--bogus'",
                  "edit '%s' erase-box 0 0 0 1 1 1 --bogus", f->cdir);
    tu_expect_cli(2, "--id: 'x' is not a fragment id", "edit '%s' erase-sphere 0 0 0 5 --id x", f->cdir);
    tu_expect_cli(2, "--id needs a value", "edit '%s' erase-sphere 0 0 0 5 --id", f->cdir);
    tu_expect_cli(2, "grow: unknown option '--bogus'", "edit '%s' grow 0 0 0 --bogus", f->cdir);
    tu_expect_cli(2, "--threshold: 'abc' is not a number (HU)", "edit '%s' grow 0 0 0 --threshold abc", f->cdir);
    tu_expect_cli(0, "1 fragment left\n", "edit '%s' keep 1", f->cdir);
    /* the --erode given is named, not asked for */
    tu_expect_cli(1, "fragment 1 does not split at --erode 0.5 mm", "edit '%s' separate 1 --erode 0.5", f->cdir);
}

/* What a case cannot give is a runtime error (1) that says why, before any device or drawing. */
static void test_case_errors(void **st)
{
    struct fixture *f = *st;
    tu_expect_cli(1, "has 1 fragment: none to fit against another", "reduce '%s'", f->cdir);
    tu_expect_cli(1, "--point 1e+06,0,0 lies outside the CT (24x24x24 voxels)",
                  "render '%s' -o '%s/p.png' --point 1e6,0,0 --layout four-up", f->cdir, f->tmp);
    tu_expect_cli(1, "fracnav navigate: /nonexistent is not a case", "navigate /nonexistent </dev/null");
    /* a case folder where a volume is wanted: named as such, not "no DICOM series found" */
    tu_expect_cli(1, "a fracnav case folder (it holds case.json), not a volume or a DICOM folder", "info '%s'",
                  f->cdir);
    tu_expect_cli(1, "case.json (usually", "segment '%s' -o '%s/again'", f->cdir, f->tmp);
    tu_expect_cli(0, "pre-alignment, then PRAXIS (or Powell)", "--help");
}

/* Bad values name the option and the value, not "unexpected argument". */
static void test_bad_values(void **st)
{
    struct fixture *f = *st;
    tu_expect_cli(2, "fracnav navigate: --duration: '-1' is not a number of seconds > 0",
                  "navigate '%s' --duration -1", f->cdir);
    tu_expect_cli(2, "--duration needs a value", "navigate '%s' --duration", f->cdir);
    tu_expect_cli(2, "fracnav bench loop: --repeat: '0' is not a whole number 1..10000", "bench loop --repeat 0");
    tu_expect_cli(2, "fracnav bench build: --max: '32' is not a whole number 64..256", "bench build --max 32");
    /* a zero normal is a usage error (2), and the case stays as it was */
    tu_expect_cli(2, "split --plane: the normal NX NY NZ ('0 0 0') is zero", "edit '%s' split 1 --plane 12 12 12 0 0 0",
                  f->cdir);
    tu_expect_cli(0, "1 fragment left\n", "edit '%s' keep 1", f->cdir);
}

/* What a command writes on stderr alone (stdout thrown away), and its exit status in *rc. */
static char *stderr_of(int *rc, const char *fmt, ...)
{
    char args[8192], cmd[8800];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(args, sizeof args, fmt, ap);
    va_end(ap);
    snprintf(cmd, sizeof cmd, "'%s' %s 2>&1 >/dev/null", tu_fracnav(), args);
    FILE *p = popen(cmd, "r");
    assert_non_null(p);
    char *out = calloc(1, 65536);
    size_t n = fread(out, 1, 65535, p);
    out[n] = '\0';
    int stt = pclose(p);
    *rc = WIFEXITED(stt) ? WEXITSTATUS(stt) : -1;
    return out;
}

/* replay --save says on stderr what it saved (stdout keeps the summary). */
static void test_replay_save_says_so(void **st)
{
    struct fixture *f = *st;
    char rec[4300];
    snprintf(rec, sizeof rec, "%s/nudge.fnrec", f->tmp);
    tu_write_recording(rec, "spacenavigator", "translate +x 1 mm over 0.1 s\n");
    tu_expect_cli(0, "is fragment 2", "edit '%s' split 1 --plane 12 12 12 1 0 0", f->cdir); /* steering needs two */
    int rc;
    char *err = stderr_of(&rc, "replay '%s' '%s' --save --json", f->cdir, rec);
    char want[4400];
    snprintf(want, sizeof want, "fracnav replay: saved the final poses of 2 fragments in %s/case.json", f->cdir);
    if (rc != 0 || !strstr(err, want))
        fail_msg("exit %d, stderr lacks \"%s\":\n%s", rc, want, err);
    free(err);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_segment, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_fracture, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_edit, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_case_errors, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_bad_values, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_replay_save_says_so, setup, tu_fixture_teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
