/* The durable-file module (durable.h) and the writers that use it: links planted in a case folder,
 * under the old temporary names, under any temporary name, as case.json or as the journal, are
 * never written through; the save succeeds without following them or refuses naming the path. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "durable.h"
#include "err.h"
#include "fnrec.h"
#include "journal.h"
#include "testutil.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define OUTSIDE "outside file: must never change\n"

/* dir/outside: a file that no planted link may let a save write. */
static void make_outside(const char *dir, char *path, size_t cap)
{
    snprintf(path, cap, "%s/outside", dir);
    tu_write_file(path, OUTSIDE, strlen(OUTSIDE));
}

static void assert_outside_intact(const char *path)
{
    size_t n;
    char *s = tu_slurp(path, &n);
    assert_non_null(s);
    assert_true(n == strlen(OUTSIDE) && !memcmp(s, OUTSIDE, n));
    free(s);
}

static void plant(const char *target, const char *dir, const char *name)
{
    char p[8400];
    snprintf(p, sizeof p, "%s/%s", dir, name);
    if (symlink(target, p) != 0)
        fail_msg("symlink %s: %s", p, strerror(errno));
}

static int is_regular(const char *path)
{
    struct stat sb;
    return lstat(path, &sb) == 0 && S_ISREG(sb.st_mode);
}

static void test_replace_writes_and_leaves_no_temporary(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("durable"), path[4200];
    snprintf(path, sizeof path, "%s/a.txt", dir);
    assert_int_equal(durable_replace_bytes(path, "one\n", 4), 0);
    assert_int_equal(durable_replace_bytes(path, "two\n", 4), 0);
    size_t n;
    char *s = tu_slurp(path, &n);
    assert_true(n == 4 && !memcmp(s, "two\n", 4));
    free(s);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "--version && ls -A '%s'", dir), 0);
    assert_null(strstr(out, DURABLE_TMP_TAG));
    free(out);
    tu_rmtree(dir);
    free(dir);
}

/* The sha256 that binds a case to its files: FIPS 180-4's examples, and the processor's SHA
 * extensions (where it has them) against the portable rounds at every length around a block's
 * edges, in one call and read from a file in pieces. */
static void test_sha256_known_answers(void **st)
{
    (void)st;
    static const struct {
        const char *msg;
        const char *hex;
    } kat[] = {
        {"", "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"},
        {"abc", "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"},
        {"abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq",
         "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1"},
    };
    char hex[65], ref[65];
    for (size_t i = 0; i < sizeof kat / sizeof kat[0]; i++) {
        durable_sha256(kat[i].msg, strlen(kat[i].msg), hex);
        assert_string_equal(hex, kat[i].hex);
        durable__sha256_portable(kat[i].msg, strlen(kat[i].msg), hex);
        assert_string_equal(hex, kat[i].hex);
    }
    size_t big = 1000000;
    unsigned char *a = malloc(big);
    assert_non_null(a);
    memset(a, 'a', big);
    durable_sha256(a, big, hex); /* a million 'a's */
    assert_string_equal(hex, "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
    uint32_t x = 12345;
    for (size_t i = 0; i < big; i++) {
        x = x * 1664525u + 1013904223u;
        a[i] = (unsigned char)(x >> 24);
    }
    char *dir = tu_tmpdir("durable"), path[4200];
    snprintf(path, sizeof path, "%s/bytes", dir);
    size_t lens[] = {1, 55, 56, 63, 64, 65, 119, 120, 127, 128, 129, 4095, 65536, 65537, 200003, 1000000};
    for (size_t i = 0; i < sizeof lens / sizeof lens[0]; i++) {
        durable_sha256(a, lens[i], hex);
        durable__sha256_portable(a, lens[i], ref);
        assert_string_equal(hex, ref);
        tu_write_file(path, (const char *)a, lens[i]);
        assert_int_equal(durable_file_sha256(path, hex), 0);
        assert_string_equal(hex, ref);
    }
    tu_rmtree(dir);
    free(dir);
    free(a);
}

/* A target that is a link, or not a regular file, is refused by name; the link's file is untouched. */
static void test_link_target_refused(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("durable"), outside[4200], path[4200];
    make_outside(dir, outside, sizeof outside);
    plant(outside, dir, "link.txt");
    snprintf(path, sizeof path, "%s/link.txt", dir);
    assert_int_equal(durable_replace_bytes(path, "x", 1), FN_EIO);
    assert_non_null(strstr(fn_err_msg(), path));
    assert_non_null(strstr(fn_err_msg(), "symbolic link"));
    assert_outside_intact(outside);
    snprintf(path, sizeof path, "%s/sub", dir);
    assert_int_equal(mkdir(path, 0755), 0);
    assert_int_equal(durable_replace_bytes(path, "x", 1), FN_EIO);
    assert_non_null(strstr(fn_err_msg(), "not a regular file"));
    tu_rmtree(dir);
    free(dir);
}

/* Every temporary name this process could use next is a planted link: the create fails (O_EXCL,
 * O_NOFOLLOW), naming the path, and nothing is written through. */
static void test_planted_temporaries_never_written(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("durable"), outside[4200], path[4200], name[200];
    make_outside(dir, outside, sizeof outside);
    for (int k = 0; k < 256; k++) {
        snprintf(name, sizeof name, DURABLE_TMP_TAG "%ld-%d-a.txt", (long)getpid(), k);
        plant(outside, dir, name);
    }
    snprintf(path, sizeof path, "%s/a.txt", dir);
    assert_int_equal(durable_replace_bytes(path, "x", 1), FN_EIO);
    assert_non_null(strstr(fn_err_msg(), path));
    assert_outside_intact(outside);
    tu_rmtree(dir);
    free(dir);
}

/* The old fixed temporary names of a case save, planted as links out of the case: edit succeeds,
 * writes neither outside file, and case.json and labels.nii.gz stay regular files. */
static void test_edit_ignores_planted_old_temporaries(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("durable"), cdir[4200], out1[4200], out2[4200], p[8400];
    tu_two_blocks_case(dir, cdir, sizeof cdir);
    make_outside(dir, out1, sizeof out1);
    snprintf(out2, sizeof out2, "%s/outside2", dir);
    tu_write_file(out2, OUTSIDE, strlen(OUTSIDE));
    plant(out1, cdir, ".case.json.tmp");
    plant(out2, cdir, ".labels.tmp.nii.gz");
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "edit '%s' fix 2", cdir), 0);
    free(out);
    assert_outside_intact(out1);
    assert_outside_intact(out2);
    snprintf(p, sizeof p, "%s/case.json", cdir);
    assert_true(is_regular(p));
    snprintf(p, sizeof p, "%s/labels.nii.gz", cdir);
    assert_true(is_regular(p));
    planning_case *c = case_load(cdir);
    assert_non_null(c);
    assert_int_equal(c->frag[c->fixed].id, 2);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* Fragment 1's x translation in the case at cdir. */
static double frag1_x(const char *cdir)
{
    planning_case *c = case_load(cdir);
    assert_non_null(c);
    double x = c->frag[1].pose.t[0];
    case_free(c);
    return x;
}

/* Plants (or, with rm, removes) a link to target at every temporary name of NAME in cdir that
 * this process could use next. */
static void plant_temporaries(const char *target, const char *cdir, const char *name, int rm)
{
    char t[300], p[8400];
    for (int k = 0; k < 1024; k++) {
        snprintf(t, sizeof t, DURABLE_TMP_TAG "%ld-%d-%s", (long)getpid(), k, name);
        snprintf(p, sizeof p, "%s/%s", cdir, t);
        if (rm)
            assert_int_equal(unlink(p), 0);
        else
            plant(target, cdir, t);
    }
}

/* An undo puts the step's files back through temporaries of its own (durable_link): links planted
 * under the old fixed names (.case.json.undo, .labels.nii.gz.undo) are not followed, and links
 * planted at every temporary name it could use refuse the undo, naming the path; either way no
 * outside file is written, and case.json and labels.nii.gz stay regular files. */
static void test_undo_never_follows_planted_temporaries(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("durable"), cdir[4200], out1[4200], p[8400];
    tu_two_blocks_case(dir, cdir, sizeof cdir);
    make_outside(dir, out1, sizeof out1);
    double before = frag1_x(cdir);
    planning_case *c = case_load(cdir);
    assert_non_null(c);
    c->frag[1].pose.t[0] += 5; /* an undoable edit: fragment 1 moved 5 mm */
    assert_int_equal(case_save_undoable(c), 0);
    case_free(c);
    plant(out1, cdir, ".case.json.undo");
    plant(out1, cdir, ".labels.nii.gz.undo");
    plant_temporaries(out1, cdir, "labels.nii.gz", 0);
    assert_int_equal(case_undo(cdir), FN_EIO);
    assert_non_null(strstr(fn_err_msg(), "labels.nii.gz"));
    assert_outside_intact(out1);
    assert_true(frag1_x(cdir) == before + 5);
    plant_temporaries(out1, cdir, "labels.nii.gz", 1);
    assert_int_equal(case_undo(cdir), 1);
    assert_outside_intact(out1);
    assert_true(frag1_x(cdir) == before);
    snprintf(p, sizeof p, "%s/case.json", cdir);
    assert_true(is_regular(p));
    snprintf(p, sizeof p, "%s/labels.nii.gz", cdir);
    assert_true(is_regular(p));
    tu_rmtree(dir);
    free(dir);
}

/* case.json itself a link out of the case: the save refuses, naming it; the outside copy is
 * untouched. */
static void test_edit_refuses_linked_case_json(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("durable"), cdir[4200], json[4300], copy[4300];
    tu_two_blocks_case(dir, cdir, sizeof cdir);
    snprintf(json, sizeof json, "%s/case.json", cdir);
    snprintf(copy, sizeof copy, "%s/case-copy.json", dir);
    size_t n;
    char *text = tu_slurp(json, &n);
    tu_write_file(copy, text, n);
    assert_int_equal(unlink(json), 0);
    assert_int_equal(symlink(copy, json), 0);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "edit '%s' fix 2", cdir), 1);
    assert_non_null(strstr(out, json));
    assert_non_null(strstr(out, "symbolic link"));
    free(out);
    size_t m;
    char *now = tu_slurp(copy, &m);
    assert_true(m == n && !memcmp(now, text, n));
    free(now);
    free(text);
    tu_rmtree(dir);
    free(dir);
}

/* A journal that links out of the case is neither read nor written through (replay and navigate
 * open it with journal_open). */
static void test_linked_journal_refused(void **st)
{
    (void)st;
    static const journal_bind b = {"1111111111111111111111111111111111111111111111111111111111111111",
                                   1, {1}};
    char *dir = tu_tmpdir("durable"), outside[4200];
    make_outside(dir, outside, sizeof outside);
    plant(outside, dir, "journal");
    assert_null(journal_open(dir, &b));
    assert_non_null(strstr(fn_err_msg(), "journal is a symbolic link"));
    assert_outside_intact(outside);
    tu_rmtree(dir);
    free(dir);
}

/* A recording (fracnav record -o) is written in place as it comes, but never through a link. */
static void test_recording_not_written_through_link(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("durable"), outside[4200], path[4200];
    make_outside(dir, outside, sizeof outside);
    plant(outside, dir, "rec.fnrec");
    snprintf(path, sizeof path, "%s/rec.fnrec", dir);
    fnrec_header h = {.version = FNREC_VERSION, .vid = 0x46d, .pid = 0xc62b, .name = "x",
                      .format = "split", .source = "test"};
    assert_null(fnrec_writer_open(path, &h));
    assert_non_null(strstr(fn_err_msg(), "symbolic link"));
    assert_outside_intact(outside);
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sha256_known_answers),
        cmocka_unit_test(test_replace_writes_and_leaves_no_temporary),
        cmocka_unit_test(test_link_target_refused),
        cmocka_unit_test(test_planted_temporaries_never_written),
        cmocka_unit_test(test_edit_ignores_planted_old_temporaries),
        cmocka_unit_test(test_edit_refuses_linked_case_json),
        cmocka_unit_test(test_undo_never_follows_planted_temporaries),
        cmocka_unit_test(test_linked_journal_refused),
        cmocka_unit_test(test_recording_not_written_through_link),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
