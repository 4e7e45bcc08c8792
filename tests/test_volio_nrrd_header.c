/* volio: NRRD headers that teem must not see. Detached data files (one name, LIST, numbered) are
 * regular files inside the header's folder, at most one a slice, and a numbered name is one
 * bounded integer conversion; key/value lines, comment lines and segments are bounded. Each hostile header is
 * read in a child, so that a crash or a hang inside teem fails the test by name. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* 4x4x4 unsigned char, 1 mm: the header up to (not including) its data file line. */
#define HEAD "NRRD0004\ntype: unsigned char\ndimension: 3\nsizes: 4 4 4\nspacings: 1 1 1\nencoding: raw\n"

/* Slice files s0.raw .. s3.raw (16 bytes each, slice k holds k + 1) and s000.raw .. s003.raw. */
static void write_slices(void)
{
    for (int k = 0; k < 4; k++) {
        unsigned char b[16];
        memset(b, k + 1, sizeof b);
        char name[32];
        snprintf(name, sizeof name, "s%d.raw", k);
        tu_write_file(tu_in_dir(name), b, sizeof b);
        snprintf(name, sizeof name, "s%03d.raw", k);
        tu_write_file(tu_in_dir(name), b, sizeof b);
    }
}

static void write_header(const char *name, const char *text)
{
    tu_write_file(tu_in_dir(name), text, strlen(text));
}

/* In a child: volio_read (labels: volio_read_labels) of path fails with a message that holds the
 * path and both words. Exit 0 when it does; a crash or a hang inside the reader fails the test. */
static void expect_refused(const char *path, int labels, const char *w1, const char *w2)
{
    fflush(NULL);
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        volio_segs segs;
        fn_err_clear();
        vol *v = labels ? volio_read_labels(path, &segs) : volio_read(path);
        const char *m = fn_err_msg();
        int ok = !v && strstr(m, path) && strstr(m, w1) && (!w2 || strstr(m, w2));
        if (!ok)
            fprintf(stderr, "%s: %s\n", path, v ? "was read" : m);
        _exit(ok ? 0 : 1);
    }
    char what[4400];
    snprintf(what, sizeof what, "reading %s%s", path, labels ? " as labels" : "");
    int status = tu_end(pid, 0, what);
    if (status != 0)
        fail_msg("%s: exit %d, expected a refusal naming '%s'", what, status, w1);
}

static void expect_both_refused(const char *path, const char *w1, const char *w2)
{
    expect_refused(path, 0, w1, w2);
    expect_refused(path, 1, w1, w2);
}

/* Reads path and checks slice k holds k + 1. */
static void expect_slices(const char *path)
{
    vol *v = volio_read(path);
    if (!v)
        fail_msg("%s", fn_err_msg());
    for (int k = 0; k < 4; k++)
        assert_true(v->data[k * 16] == (float)(k + 1) && v->data[k * 16 + 15] == (float)(k + 1));
    vol_free(v);
}

/* The reproductions: widths that overflow teem's name buffer, a second conversion, %n. */
static void test_numbered_names_bounded(void **st)
{
    write_slices();
    static const char *const bad[] = {
        "slice%0999999d.raw 0 3 1 2", "s%03d%s.raw 0 3 1 2", "s%5000d.raw 0 3 1 2", "s%d%n.raw 0 3 1 2",
        "s%n%d.raw 0 3 1 2",           "s%10d.raw 0 3 1 2",   "s%x.raw 0 3 1 2",     "s%%%d.raw 0 3 1 2",
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        char text[256];
        snprintf(text, sizeof text, HEAD "data file: %s\n", bad[i]);
        write_header("bad.nhdr", text);
        expect_both_refused(tu_in_dir("bad.nhdr"), "line 7: data file", "exactly one %d");
    }
    write_header("range.nhdr", HEAD "data file: s%d.raw 0 2147483647 1 2\n");
    expect_both_refused(tu_in_dir("range.nhdr"), "line 7: data file", "at most 9 digits");
    write_header("many.nhdr", HEAD "data file: s%d.raw 0 999 1 2\n");
    expect_both_refused(tu_in_dir("many.nhdr"), "1000 files, more than the 4 slices", NULL);
    write_header("step.nhdr", HEAD "data file: s%d.raw 3 0 1 2\n");
    expect_both_refused(tu_in_dir("step.nhdr"), "step 1 does not lead from 3 to 0", NULL);
    write_header("gap.nhdr", HEAD "data file: s%d.raw 1 4 1 2\n"); /* s4.raw is missing */
    expect_both_refused(tu_in_dir("gap.nhdr"), "'s4.raw'", "No such file");

    write_header("good.nhdr", HEAD "data file: s%03d.raw 0 3 1 2\n");
    expect_slices(tu_in_dir("good.nhdr"));
    write_header("good.nhdr", HEAD "data file: s%d.raw 3 0 -1\n");
    vol *v = volio_read(tu_in_dir("good.nhdr"));
    if (!v)
        fail_msg("%s", fn_err_msg());
    assert_true(v->data[0] == 4 && v->data[63] == 1); /* read from s3.raw down to s0.raw */
    vol_free(v);
}

/* LIST entries and single names: regular files of the header's folder only. */
static void test_data_files_regular_and_inside(void **st)
{
    write_slices();
    write_header("list.nhdr", HEAD "data file: LIST 2\ns0.raw\ns1.raw\ns2.raw\ns3.raw\n");
    expect_slices(tu_in_dir("list.nhdr"));
    char text[8400];
    snprintf(text, sizeof text, HEAD "data file: LIST\n%s\n%s/s1.raw\ns2.raw\ns3.raw\n", tu_in_dir("s0.raw"), tu_dir);
    write_header("absolute.nhdr", text); /* absolute names inside the folder */
    expect_slices(tu_in_dir("absolute.nhdr"));

    for (int k = 0; k < 4; k++) {
        char name[16];
        snprintf(name, sizeof name, "f%d.raw", k);
        assert_int_equal(mkfifo(tu_in_dir(name), 0600), 0);
    }
    write_header("fifos.nhdr", HEAD "data file: LIST\nf0.raw\nf1.raw\nf2.raw\nf3.raw\n");
    expect_both_refused(tu_in_dir("fifos.nhdr"), "line 8: data file: f0.raw is not a regular file", NULL);
    write_header("fifo.nhdr", HEAD "data file: f%d.raw 0 3 1\n");
    expect_both_refused(tu_in_dir("fifo.nhdr"), "line 7: data file: f0.raw is not a regular file", NULL);
    write_header("urandom.nhdr", HEAD "data file: LIST\ns0.raw\n/dev/urandom\ns2.raw\ns3.raw\n");
    expect_both_refused(tu_in_dir("urandom.nhdr"), "line 9: data file: /dev/urandom is not a regular file", NULL);
    write_header("passwd.nhdr", HEAD "data file: LIST\n/etc/passwd\ns1.raw\ns2.raw\ns3.raw\n");
    expect_both_refused(tu_in_dir("passwd.nhdr"), "line 8: data file: '/etc/passwd'", "outside the header's folder");
    write_header("passwd1.nhdr", HEAD "data file: /etc/passwd\n");
    expect_both_refused(tu_in_dir("passwd1.nhdr"), "line 7: data file: '/etc/passwd'", "outside");
    write_header("up.nhdr", HEAD "data file: LIST\ns0.raw\nx/../s1.raw\ns2.raw\ns3.raw\n");
    expect_both_refused(tu_in_dir("up.nhdr"), "line 9: data file: 'x/../s1.raw' leaves the header's folder", NULL);
    assert_int_equal(symlink("/etc/passwd", tu_in_dir("out.raw")), 0);
    write_header("link.nhdr", HEAD "data file: out.raw\n");
    expect_both_refused(tu_in_dir("link.nhdr"), "'out.raw' is /etc/passwd, outside", NULL);
    write_header("stdin.nhdr", HEAD "data file: LIST\n-\ns1.raw\ns2.raw\ns3.raw\n");
    expect_both_refused(tu_in_dir("stdin.nhdr"), "'-' is standard input", NULL);
    write_header("five.nhdr", HEAD "data file: LIST\ns0.raw\ns1.raw\ns2.raw\ns3.raw\ns0.raw\n");
    expect_both_refused(tu_in_dir("five.nhdr"), "line 12: data file: 5 files, more than the 4 slices", NULL);
    write_header("empty.nhdr", HEAD "data file: LIST\ns0.raw\n\ns2.raw\ns3.raw\n");
    expect_both_refused(tu_in_dir("empty.nhdr"), "line 9: data file: an empty name", NULL);
    write_header("nodim.nhdr", "NRRD0004\ntype: unsigned char\ndimension: 3\ndata file: LIST\ns0.raw\n");
    expect_both_refused(tu_in_dir("nodim.nhdr"), "needs dimension and sizes before it", NULL);
    write_header("skip.nhdr", HEAD "data file: SKIPLIST\n0 s0.raw\n");
    expect_both_refused(tu_in_dir("skip.nhdr"), "SKIPLIST is not supported", NULL);
    /* a line ends at "\r" for teem too: the name is "f0.raw", not "f0.raw\rs0.raw" */
    write_header("cr.nhdr", HEAD "data file: LIST\ns0.raw\rf0.raw\r\ns2.raw\ns3.raw\n");
    expect_both_refused(tu_in_dir("cr.nhdr"), "line 9: data file: f0.raw is not a regular file", NULL);
    write_header("datafile.nhdr", HEAD "DataFile: LIST\ns0.raw\ns1.raw\nf2.raw\ns3.raw\n");
    expect_both_refused(tu_in_dir("datafile.nhdr"), "f2.raw is not a regular file", NULL);
    /* the last entry needs no line end: teem reads it as a name too */
    write_header("noend.nhdr", HEAD "data file: LIST\ns0.raw\ns1.raw\ns2.raw\nf3.raw");
    expect_both_refused(tu_in_dir("noend.nhdr"), "line 11: data file: f3.raw is not a regular file", NULL);
}

/* CI's fuzz smoke found it: a NUL byte in a LIST entry after the last listed slice, with no line
 * end, ran teem's line reader past its buffer (ASan: heap-buffer-overflow in biffAddf). A header is
 * text: a NUL byte in any of its lines is refused by line and character. */
static void test_nul_in_header_refused(void **st)
{
    write_slices();
    static const char crash[] = HEAD "data file: LIST\ns0.raw\ns1.raw\ns2.raw\ns3.raw\ns0.\0\0\0\0\0raw'";
    tu_write_file(tu_in_dir("nul.nhdr"), crash, sizeof crash - 1);
    expect_both_refused(tu_in_dir("nul.nhdr"), "line 12: a NUL byte at character 4", "a NRRD header is text");
    static const char field[] = "NRRD0004\ntype: unsigned\0 char\ndimension: 3\n";
    tu_write_file(tu_in_dir("nulfield.nrrd"), field, sizeof field - 1);
    expect_both_refused(tu_in_dir("nulfield.nrrd"), "line 2: a NUL byte at character 15", NULL);
    /* in the magic line too (the scan passed such a header unread; teem reads "NRRD0004" up to the
     * NUL and went on to a numbered name whose width overran its buffer: fuzz_nrrd, CI) */
    static const char magic[] = "NRRD0004\0\0\0" "1\ntype: unsigned char\ndimension: 3\nsizes: 4 4 4\n"
                                "spacings: 1 1 1\nencoding: raw\ndata file: s%5000d.raw 0 3 1 2\n";
    tu_write_file(tu_in_dir("nulmagic.nrrd"), magic, sizeof magic - 1);
    expect_both_refused(tu_in_dir("nulmagic.nrrd"), "line 1: a NUL byte at character 9", NULL);
}

/* `segment --labels` reads its labelmap through the same check. */
static void test_labels_cli_refuses(void **st)
{
    write_slices();
    write_header("labels.nhdr", HEAD "data file: s%0999999d.raw 0 3 1 2\n");
    write_header("ct.nhdr", HEAD "data file: LIST\ns0.raw\ns1.raw\ns2.raw\ns3.raw\n");
    char *out = NULL;
    int rc = tu_run_cli(&out, "segment '%s/ct.nhdr' --labels '%s/labels.nhdr' -o '%s/case'", tu_dir, tu_dir, tu_dir);
    if (rc != 1 || !strstr(out, "exactly one %d"))
        fail_msg("exit %d: %s", rc, out ? out : "");
    free(out);
}

/* teem adds key/value pairs in quadratic time: 80,000 took 16 s. A header holds at most 4096,
 * at most 4096 comment lines, and a .seg.nrrd at most 256 segments. */
static void test_header_bounded(void **st)
{
    size_t cap = 200000, n = 0;
    char *h = malloc(cap);
    assert_non_null(h);
    n += (size_t)snprintf(h + n, cap - n, "%s", HEAD);
    for (int i = 0; i < 5000; i++)
        n += (size_t)snprintf(h + n, cap - n, "key%d:=%d\n", i, i);
    n += (size_t)snprintf(h + n, cap - n, "\n");
    tu_write_file(tu_in_dir("keys.nrrd"), h, n + 64);
    expect_both_refused(tu_in_dir("keys.nrrd"), "line 4103: over 4096 key/value lines", NULL);
    /* and comments as slowly: 400,000 took 18 s; at most 4096 */
    n = (size_t)snprintf(h, cap, "%s", HEAD);
    for (int i = 0; i < 5000; i++)
        n += (size_t)snprintf(h + n, cap - n, "# comment %d\n", i);
    n += (size_t)snprintf(h + n, cap - n, "\n");
    memset(h + n, 0, 64); /* the voxels */
    tu_write_file(tu_in_dir("comments.nrrd"), h, n + 64);
    expect_both_refused(tu_in_dir("comments.nrrd"), "line 4103: over 4096 comment lines", NULL);
    free(h);
    write_header("segs.nrrd", HEAD "Segment0_LabelValue:=1\nSegment256_LabelValue:=2\n\n");
    expect_refused(tu_in_dir("segs.nrrd"), 1, "line 8: Segment256_LabelValue:=2: over 256 segments", NULL);
    write_header("segs.nrrd", HEAD "Segment0_LabelValue:=1\nSegment123456_LabelValue:=2\n\n");
    expect_refused(tu_in_dir("segs.nrrd"), 1, "line 8: Segment123456_LabelValue:=2: over 256 segments", NULL);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_numbered_names_bounded, tu_dir_setup, tu_dir_teardown),
        cmocka_unit_test_setup_teardown(test_data_files_regular_and_inside, tu_dir_setup, tu_dir_teardown),
        cmocka_unit_test_setup_teardown(test_nul_in_header_refused, tu_dir_setup, tu_dir_teardown),
        cmocka_unit_test_setup_teardown(test_labels_cli_refuses, tu_dir_setup, tu_dir_teardown),
        cmocka_unit_test_setup_teardown(test_header_bounded, tu_dir_setup, tu_dir_teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
