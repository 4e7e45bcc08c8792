/* Nothing overwritten without asking: every command that writes a case or a folder refuses an
 * existing case without --force and a folder holding other files, no output of any command lands
 * in a case folder or on the case's source volume, and each is checked before the work (the
 * message names the user's path). */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "testutil.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

struct fixture {
    char *tmp;
    char ct[4200], cdir[4200], other[4200], junk[4200];
};

/* Two blocks (tu_two_blocks_case) as case/, a second case other/, and junk/ holding a file. */
static int setup(void **st)
{
    struct fixture *f = calloc(1, sizeof *f);
    f->tmp = tu_tmpdir("out-paths");
    tu_two_blocks_case(f->tmp, f->cdir, sizeof f->cdir);
    snprintf(f->ct, sizeof f->ct, "%s/blocks.nii.gz", f->tmp);
    snprintf(f->other, sizeof f->other, "%s/other", f->tmp);
    snprintf(f->junk, sizeof f->junk, "%s/junk", f->tmp);
    tu_segment(f->ct, f->other, "");
    assert_int_equal(mkdir(f->junk, 0755), 0);
    char keep[4300];
    snprintf(keep, sizeof keep, "%s/notes.txt", f->junk);
    tu_write_file(keep, "mine\n", 5);
    *st = f;
    return 0;
}

/* A file's bytes, to see that a refused command left it as it was. */
static char *bytes(const char *dir, const char *name, size_t *n)
{
    char p[4400];
    snprintf(p, sizeof p, "%s/%s", dir, name);
    char *b = tu_slurp(p, n);
    assert_non_null(b);
    return b;
}

static void same_bytes(const char *dir, const char *name, const char *before, size_t n0)
{
    size_t n1;
    char *after = bytes(dir, name, &n1);
    assert_int_equal(n0, n1);
    assert_memory_equal(before, after, n0);
    free(after);
}

/* The cases still load: nothing of theirs was written. */
static void cases_load(const struct fixture *f)
{
    const char *dirs[2] = {f->cdir, f->other};
    for (int i = 0; i < 2; i++) {
        case_free(tu_case_load(dirs[i]));
    }
}

/* segment and fracture: an existing case needs --force; a folder with other files is refused. */
static void test_segment_and_fracture(void **st)
{
    struct fixture *f = *st;
    size_t n;
    char *json = bytes(f->other, "case.json", &n);
    tu_expect_cli(1, "holds a case already; --force replaces it", "segment '%s' -o '%s'", f->ct, f->other);
    tu_expect_cli(1, "holds a case already; --force replaces it", "fracture '%s' -o '%s' --seed 1", f->ct, f->other);
    tu_expect_cli(1, "a folder with files but no case.json", "segment '%s' -o '%s' --force", f->ct, f->junk);
    tu_expect_cli(1, "a folder with files but no case.json", "fracture '%s' -o '%s' --seed 1", f->ct, f->junk);
    same_bytes(f->other, "case.json", json, n);
    free(json);
    cases_load(f);
}

/* reduce -o: the same rules, checked before the fit; --force replaces the case; never a case
 * inside the case being read, nor that case or a folder around it. */
static void test_reduce(void **st)
{
    struct fixture *f = *st;
    size_t n;
    char *json = bytes(f->other, "case.json", &n), out[4300];
    tu_expect_cli(1, "holds a case already; --force replaces it", "reduce '%s' -o '%s'", f->cdir, f->other);
    same_bytes(f->other, "case.json", json, n);
    free(json);
    tu_expect_cli(1, "a folder with files but no case.json", "reduce '%s' -o '%s' --force", f->cdir, f->junk);
    tu_expect_cli(2, "--force goes with -o NEWCASE", "reduce '%s' --force", f->cdir);
    /* a new case never inside the case being read, nor on it or around it */
    snprintf(out, sizeof out, "%s/sub", f->cdir);
    char want[9000];
    snprintf(want, sizeof want, "-o %s lies inside the case being read (%s)", out, f->cdir);
    tu_expect_cli(1, want, "reduce '%s' -o '%s'", f->cdir, out);
    assert_int_equal(access(out, F_OK), -1);
    snprintf(want, sizeof want, "-o %s/ is the case being read (%s)", f->cdir, f->cdir);
    tu_expect_cli(1, want, "reduce '%s' -o '%s/' --force", f->cdir, f->cdir);
    snprintf(want, sizeof want, "-o %s holds the case being read (%s)", f->tmp, f->cdir);
    tu_expect_cli(1, want, "reduce '%s' -o '%s' --force", f->cdir, f->tmp);
    snprintf(out, sizeof out, "%s/reduced", f->tmp);
    tu_expect_cli(0, "saved", "reduce '%s' -o '%s'", f->cdir, out);
    tu_expect_cli(0, "saved", "reduce '%s' -o '%s' --force", f->cdir, out);
    cases_load(f);
    planning_case *c = tu_case_load(out);
    assert_int_equal(c->nfrag, 2);
    case_free(c);
    tu_rmtree(out);
}

/* export: no file lands in a case folder or on the source volume; folders are empty or --force;
 * a name that is not the format says so, naming the user's path. */
static void test_export(void **st)
{
    struct fixture *f = *st;
    size_t n;
    char *src = tu_slurp(f->ct, &n), out[4300];
    tu_expect_cli(1, "labels.nii.gz lies in the case folder",
                  "export '%s' --nifti '%s/labels.nii.gz'", f->cdir, f->cdir);
    tu_expect_cli(1, "lies in the case folder", "export '%s' --seg-nrrd '%s/planned.seg.nrrd'", f->cdir, f->other);
    tu_expect_cli(1, "is the source volume of the case", "export '%s' --nifti '%s'", f->cdir, f->ct);
    tu_expect_cli(1, "--seg-nrrd x.json: a 3D Slicer segmentation's name ends in .seg.nrrd",
                  "export '%s' --seg-nrrd x.json", f->cdir);
    tu_expect_cli(1, "--nifti cases: a NIfTI file's name ends in .nii or .nii.gz",
                  "export '%s' --nifti cases", f->cdir);
    tu_expect_cli(1, "is a case folder", "export '%s' --tfm '%s'", f->cdir, f->other);
    tu_expect_cli(1, "is a case folder", "export '%s' --all '%s'", f->cdir, f->cdir);
    tu_expect_cli(1, "lies in the case folder", "export '%s' --stl '%s/models'", f->cdir, f->cdir);
    tu_expect_cli(1, "holds files already (notes.txt): --force", "export '%s' --tfm '%s'", f->cdir, f->junk);
    /* nothing of a refused export was written, not even its other outputs */
    snprintf(out, sizeof out, "%s/fresh", f->tmp);
    tu_expect_cli(1, "holds files already", "export '%s' --tfm '%s' --stl '%s'", f->cdir, out, f->junk);
    assert_int_not_equal(access(out, F_OK), 0);
    tu_expect_cli(0, "fragment-1.tfm", "export '%s' --tfm '%s' --force", f->cdir, f->junk);
    tu_expect_cli(0, "fragment-2.tfm", "export '%s' --tfm '%s'", f->cdir, out);
    tu_expect_cli(1, "holds files already", "export '%s' --tfm '%s'", f->cdir, out);
    same_bytes(f->tmp, "blocks.nii.gz", src, n);
    free(src);
    cases_load(f);
}

/* render -o: a folder, or a file in a case folder, is refused before anything is drawn. */
static void test_render(void **st)
{
    struct fixture *f = *st;
    tu_expect_cli(1, "fracnav render: -o", "render '%s' -o '%s'", f->cdir, f->junk);
    tu_expect_cli(1, "is a folder: name a file", "render '%s' -o '%s'", f->cdir, f->junk);
    tu_expect_cli(1, "x.png lies in the case folder", "render '%s' -o '%s/x.png'", f->cdir, f->other);
    tu_expect_cli(1, "does not exist", "render '%s' -o '%s/no/such/x.png'", f->cdir, f->tmp);
    cases_load(f);
}

/* record, replay, navigate and demo: their outputs are checked before any device, recording or
 * step. */
static void test_record_replay_navigate(void **st)
{
    struct fixture *f = *st;
    tu_expect_cli(1, "journal lies in the case folder", "record -o '%s/journal' --device bogus:", f->cdir);
    tu_expect_cli(1, "is a case folder", "replay '%s' /nonexistent.fnrec --frames '%s'", f->cdir, f->other);
    tu_expect_cli(1, "x.png lies in the case folder", "navigate '%s' --screenshot '%s/x.png' --device bogus:", f->cdir,
                  f->other);
    tu_expect_cli(1, "fracnav demo: -o", "demo '%s' -o '%s' --no-fuse", f->ct, f->other);
    tu_expect_cli(1, "is a case folder", "demo '%s' -o '%s' --no-fuse", f->ct, f->other);
    cases_load(f);
}

/* fracnav-sim render -o and serve --log: no recording lands in a case folder (checked before the
 * work, as fracnav's own outputs; serve's before its mount point, so no FUSE is needed). */
static void test_sim_outputs(void **st)
{
    struct fixture *f = *st;
    tu_sim(); /* skips, saying so, where fracnav-sim is not built */
    char script[4300], mnt[4300], *out = NULL;
    snprintf(script, sizeof script, "%s/m.script", f->tmp);
    tu_write_file(script, "press 1\n", 8);
    snprintf(mnt, sizeof mnt, "%s/nowhere", f->tmp); /* never served: the check comes first */
    size_t n;
    char *labels = bytes(f->cdir, "labels.nii.gz", &n);
    int rc = tu_run_sim(&out, "render --script '%s' -o '%s/labels.nii.gz'", script, f->cdir);
    if (rc != 1 || !strstr(out, "labels.nii.gz lies in the case folder"))
        fail_msg("fracnav-sim render -o CASE/labels.nii.gz: exit %d: %s", rc, out);
    free(out);
    same_bytes(f->cdir, "labels.nii.gz", labels, n);
    free(labels);
    rc = tu_run_sim(&out, "serve --mount '%s' --script '%s' --log '%s/x.fnrec'", mnt, script, f->other);
    if (rc != 1 || !strstr(out, "x.fnrec lies in the case folder"))
        fail_msg("fracnav-sim serve --log CASE/x.fnrec: exit %d: %s", rc, out);
    free(out);
    char x[4400];
    snprintf(x, sizeof x, "%s/x.fnrec", f->other);
    assert_int_not_equal(access(x, F_OK), 0);
    cases_load(f);
}

/* A folder holding the named entries (a name ending in / is a folder), made fresh under tmp. */
static void folder_with(const char *tmp, const char *name, const char *const *entries, int n, char *out, size_t cap)
{
    snprintf(out, cap, "%s/%s", tmp, name);
    assert_int_equal(mkdir(out, 0755), 0);
    for (int i = 0; i < n; i++) {
        char p[4400];
        snprintf(p, sizeof p, "%s/%s", out, entries[i]);
        size_t len = strlen(p);
        if (p[len - 1] == '/')
            assert_int_equal(mkdir(p, 0755), 0);
        else
            tu_write_file(p, "x", 1);
    }
}

/* replay --frames and demo -o, like every other command: a folder holding other files is refused
 * without --force (before, both wrote into it); a folder holding only their own earlier output is
 * taken (a replay's frames, a demo's results: the README's demo command runs again), and --force
 * takes any. Each accepted run here stops at a later step (no recording; no bone), past the check. */
static void test_replay_frames_and_demo_folders(void **st)
{
    struct fixture *f = *st;
    char frames[4300], demo[4300];
    tu_expect_cli(1, "fracnav replay: ", "replay '%s' /nonexistent.fnrec --frames '%s'", f->cdir, f->junk);
    tu_expect_cli(1, "holds files already (", "replay '%s' /nonexistent.fnrec --frames '%s'",
                  f->cdir, f->junk);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "replay '%s' /nonexistent.fnrec --frames '%s' --force", f->cdir, f->junk), 1);
    if (strstr(out, "holds files already") || !strstr(out, "nonexistent.fnrec"))
        fail_msg("replay --frames --force: %s", out);
    free(out);
    static const char *const old_frames[] = {"frame_00000.png", "frame_00001.png", "frame_123456.png"};
    folder_with(f->tmp, "frames", old_frames, 3, frames, sizeof frames);
    assert_int_equal(tu_run_cli(&out, "replay '%s' /nonexistent.fnrec --frames '%s'", f->cdir, frames), 1);
    if (strstr(out, "holds files already") || !strstr(out, "nonexistent.fnrec"))
        fail_msg("replay --frames into an earlier replay's frames: %s", out);
    free(out);
    tu_expect_cli(2, "--force goes with --frames DIR", "replay '%s' /nonexistent.fnrec --force", f->cdir);

    tu_expect_cli(1, "fracnav demo: -o", "demo '%s' -o '%s' --no-fuse", f->ct, f->junk);
    tu_expect_cli(1, "holds files already (", "demo '%s' -o '%s' --no-fuse", f->ct, f->junk);
    static const char *const earlier[] = {"case/", "fracture/", "frames/", "export/", "segmentation-anterior.png",
                                          "fracture-anterior.png", "navigate.json", "reduce.json", "reduce.log",
                                          "export.json", "export.log", ".fracture.new-123"};
    folder_with(f->tmp, "demo", earlier, 12, demo, sizeof demo);
    const char *dirs[2] = {demo, f->junk};
    for (int i = 0; i < 2; i++) {
        assert_int_equal(tu_run_cli(&out, "demo '%s' -o '%s' --no-fuse --threshold 5000%s", f->ct, dirs[i],
                                    i ? " --force" : ""), 1);
        if (strstr(out, "holds files already") || !strstr(out, "no bone"))
            fail_msg("demo -o %s: %s", dirs[i], out);
        free(out);
    }
    size_t n;
    free(bytes(f->junk, "notes.txt", &n));
    cases_load(f);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_segment_and_fracture),
        cmocka_unit_test(test_reduce),
        cmocka_unit_test(test_export),
        cmocka_unit_test(test_render),
        cmocka_unit_test(test_record_replay_navigate),
        cmocka_unit_test(test_sim_outputs),
        cmocka_unit_test(test_replay_frames_and_demo_folders),
    };
    return cmocka_run_group_tests(tests, setup, tu_fixture_teardown);
}
