/* What a user sees for bad options of segment, fracture and edit: the option, the value and what
 * is accepted, exit 2 for usage errors. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "script.h"
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
    char *out;
    if (tu_run_cli(&out, "segment '%s' -o '%s' --min-volume 0", f->ct, f->cdir) != 0)
        fail_msg("segment failed: %s", out);
    free(out);
    *st = f;
    return 0;
}

static int teardown(void **st)
{
    struct fixture *f = *st;
    tu_rmtree(f->tmp);
    free(f->tmp);
    free(f);
    return 0;
}

/* Runs `fracnav CMD ARGS`, expects exit status rc and `want` in the output. */
static void expect(int rc, const char *want, const char *fmt, ...)
{
    char args[8192], *out = NULL;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(args, sizeof args, fmt, ap);
    va_end(ap);
    int got = tu_run_cli(&out, "%s", args);
    if (got != rc || !strstr(out, want))
        fail_msg("fracnav %s: exit %d (want %d), output lacks \"%s\":\n%s", args, got, rc, want, out);
    free(out);
}

static void test_segment(void **st)
{
    struct fixture *f = *st;
    const char *o = f->tmp;
    expect(2, "fracnav segment: --threshold: 'abc' is not a number (HU), 'auto' or 'auto-bone'",
           "segment '%s' -o '%s/s' --threshold abc", f->ct, o);
    expect(2, "fracnav segment: unknown option '--bogus'", "segment '%s' -o '%s/s' --bogus", f->ct, o);
    expect(2, "fracnav segment: unknown option '--bogus'", "segment '%s' -o '%s/s' --bogus 3", f->ct, o);
    expect(2, "--threshold needs a value", "segment '%s' -o '%s/s' --threshold", f->ct, o);
    expect(2, "--min-volume: '-1' is not a number of ml >= 0", "segment '%s' -o '%s/s' --min-volume -1", f->ct, o);
    expect(2, "--keep: '1.5' is not a whole number", "segment '%s' -o '%s/s' --keep 1.5", f->ct, o);
    expect(2, "--ramp: 'wide' is not a number >= 0", "segment '%s' -o '%s/s' --ramp wide", f->ct, o);
    expect(0, "1 kept", "segment '%s' -o '%s/s' --threshold auto-bone --ramp 0", f->ct, o);
    /* No bone is an error that says what was found, and leaves no case. */
    expect(1, "no bone: the volume's values run from -1000 to 1200, none at or above the threshold 1500",
           "segment '%s' -o '%s/none' --threshold 1500", f->ct, o);
    expect(1, "none of the 1 components reaches --min-volume 5 ml",
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
    expect(1, "labels.nii.gz holds no label over 0", "segment '%s' -o '%s/none' --labels '%s'", f->ct, o, lab);
}

static void test_fracture(void **st)
{
    struct fixture *f = *st;
    const char *o = f->tmp;
    expect(2, "fracnav fracture: --threshold: 'abc' is not a number (HU)",
           "fracture '%s' -o '%s/f' --seed 1 --threshold abc", f->ct, o);
    expect(2, "fracnav fracture: unknown option '--bogus'", "fracture '%s' -o '%s/f' --seed 1 --bogus", f->ct, o);
    expect(2, "--seed: '-3' is not a whole number", "fracture '%s' -o '%s/f' --seed -3", f->ct, o);
    expect(2, "--seed needs a value", "fracture '%s' -o '%s/f' --seed", f->ct, o);
    expect(2, "--rotate: 'x' is not a number of degrees", "fracture '%s' -o '%s/f' --seed 1 --rotate x", f->ct, o);
    /* No module prefix doubled after the command's. */
    expect(2, "fracnav fracture: --pieces: '11' is not a whole number 2..10",
           "fracture '%s' -o '%s/f' --seed 1 --pieces 11", f->ct, o);
    expect(2, "fracnav fracture: bone loss must be 0..20 mm (got 25) (see",
           "fracture '%s' -o '%s/f' --seed 1 --bone-loss 25", f->ct, o);
    /* The threshold given, and the CT's range, not 0. */
    expect(1, "no bone at or above 1500: the CT's values run from -1000 to 1200",
           "fracture '%s' -o '%s/f' --seed 1 --threshold 1500", f->ct, o);
    /* demo takes --threshold too, for steps 1 and 2. */
    expect(1, "fracnav demo: segmentation: no bone: the volume's values run from -1000 to 1200, none at or above "
              "the threshold 1500", "demo '%s' -o '%s/d' --threshold 1500 --no-fuse", f->ct, o);
}

static void test_edit(void **st)
{
    struct fixture *f = *st;
    expect(2, "fracnav edit: erase-sphere R: '-5' is not a radius > 0 mm", "edit '%s' erase-sphere 0 0 0 -5", f->cdir);
    expect(2, "erase-box: unknown option or extra argument '--bogus'", "edit '%s' erase-box 0 0 0 1 1 1 --bogus", f->cdir);
    expect(2, "--id: 'x' is not a fragment id", "edit '%s' erase-sphere 0 0 0 5 --id x", f->cdir);
    expect(2, "--id needs a value", "edit '%s' erase-sphere 0 0 0 5 --id", f->cdir);
    expect(2, "grow: unknown option '--bogus'", "edit '%s' grow 0 0 0 --bogus", f->cdir);
    expect(2, "--threshold: 'abc' is not a number (HU)", "edit '%s' grow 0 0 0 --threshold abc", f->cdir);
    expect(0, "1 fragment left\n", "edit '%s' keep 1", f->cdir);
    /* the --erode given is named, not asked for */
    expect(1, "fragment 1 does not split at --erode 0.5 mm", "edit '%s' separate 1 --erode 0.5", f->cdir);
}

/* What a case cannot give is a runtime error (1) that says why, before any device or drawing. */
static void test_case_errors(void **st)
{
    struct fixture *f = *st;
    expect(1, "has 1 fragment: none to fit against another", "reduce '%s'", f->cdir);
    expect(1, "--point 1e+06,0,0 lies outside the CT (24x24x24 voxels)",
           "render '%s' -o '%s/p.png' --point 1e6,0,0 --layout four-up", f->cdir, f->tmp);
    expect(1, "fracnav navigate: /nonexistent is not a case", "navigate /nonexistent </dev/null");
    expect(0, "pre-alignment, then PRAXIS (or Powell)", "--help");
}

/* Bad values name the option and the value, not "unexpected argument". */
static void test_bad_values(void **st)
{
    struct fixture *f = *st;
    expect(2, "fracnav navigate: --duration: '-1' is not a number of seconds > 0",
           "navigate '%s' --duration -1", f->cdir);
    expect(2, "--duration needs a value", "navigate '%s' --duration", f->cdir);
    expect(2, "fracnav bench loop: --repeat: '0' is not a whole number 1..10000", "bench loop --repeat 0");
    expect(2, "fracnav bench build: --max: '32' is not a whole number 64..256", "bench build --max 32");
    /* a zero normal is a usage error (2), and the case stays as it was */
    expect(2, "split --plane: the normal NX NY NZ ('0 0 0') is zero", "edit '%s' split 1 --plane 12 12 12 0 0 0",
           f->cdir);
    expect(0, "1 fragment left\n", "edit '%s' keep 1", f->cdir);
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
    const char *text = "translate +x 1 mm over 0.1 s\n";
    script *s = NULL;
    assert_int_equal(script_parse(text, strlen(text), "nudge", &s), 0);
    fnrec *r = script_render(s, sim_profile_find("spacenavigator"));
    assert_non_null(r);
    assert_int_equal(fnrec_save(r, rec), 0);
    fnrec_free(r);
    free(s);
    expect(0, "is fragment 2", "edit '%s' split 1 --plane 12 12 12 1 0 0", f->cdir); /* steering needs two */
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
        cmocka_unit_test_setup_teardown(test_segment, setup, teardown),
        cmocka_unit_test_setup_teardown(test_fracture, setup, teardown),
        cmocka_unit_test_setup_teardown(test_edit, setup, teardown),
        cmocka_unit_test_setup_teardown(test_case_errors, setup, teardown),
        cmocka_unit_test_setup_teardown(test_bad_values, setup, teardown),
        cmocka_unit_test_setup_teardown(test_replay_save_says_so, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
