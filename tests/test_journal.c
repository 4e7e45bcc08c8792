/* The pose journal: format, torn tails, flush timing, a real crash, recovery. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "journal.h"
#include "loop.h"
#include "testutil.h"

#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

static pose pose_n(int k)
{
    pose p = POSE_IDENTITY;
    p.t[0] = k;
    p.t[1] = -0.5 * k;
    return p;
}

static long file_size(const char *dir)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/journal", dir);
    struct stat sb;
    return stat(path, &sb) == 0 ? (long)sb.st_size : -1;
}

static void test_append_read_back(void **st)
{
    char *dir = tu_tmpdir("journal");
    journal *j = journal_open(dir);
    assert_non_null(j);
    for (int k = 0; k < 10; k++) {
        pose p = pose_n(k);
        assert_int_equal(journal_append(j, JOURNAL_MOVE, k % 2, 1000 * k, &p, 0), 0);
    }
    assert_int_equal(journal_close(j), 0);
    assert_int_equal(file_size(dir), JOURNAL_HEADER_SIZE + 10 * JOURNAL_RECORD_SIZE);
    journal_rec *r;
    size_t n;
    long torn;
    assert_int_equal(journal_read(dir, &r, &n, &torn), 0);
    assert_int_equal(n, 10);
    assert_int_equal(torn, -1);
    assert_true(r[9].seq == 10 && r[9].frag == 1 && r[9].t_us == 9000 && r[9].p.t[0] == 9);
    pose fin[2] = {POSE_IDENTITY, POSE_IDENTITY};
    assert_int_equal(journal_final_poses(r, n, 2, fin), 0);
    assert_true(fin[0].t[0] == 8 && fin[1].t[0] == 9);
    assert_int_equal(journal_final_poses(r, n, 1, fin), FN_EFORMAT);
    assert_non_null(strstr(fn_err_msg(), "record 2"));
    free(r);
    /* Reopening continues the numbering. */
    j = journal_open(dir);
    pose p = pose_n(42);
    journal_append(j, JOURNAL_UNDO, 0, 1, &p, 0);
    assert_int_equal(journal_count(j), 11);
    journal_close(j);
    journal_read(dir, &r, &n, NULL);
    assert_true(n == 11 && r[10].seq == 11 && r[10].kind == JOURNAL_UNDO);
    free(r);
    tu_rmtree(dir);
    free(dir);
}

static void test_torn_tail_is_cut(void **st)
{
    char *dir = tu_tmpdir("journal");
    journal *j = journal_open(dir);
    for (int k = 0; k < 5; k++) {
        pose p = pose_n(k);
        journal_append(j, JOURNAL_MOVE, 0, k, &p, 0);
    }
    journal_close(j);
    char path[4200];
    snprintf(path, sizeof path, "%s/journal", dir);
    /* A crash in the middle of the 5th record, and a flipped byte in the 4th. */
    assert_int_equal(truncate(path, JOURNAL_HEADER_SIZE + 4 * JOURNAL_RECORD_SIZE + 30), 0);
    FILE *f = fopen(path, "r+b");
    fseek(f, JOURNAL_HEADER_SIZE + 3 * JOURNAL_RECORD_SIZE + 40, SEEK_SET);
    fputc(0x5a, f);
    fclose(f);
    journal_rec *r;
    size_t n;
    long torn;
    assert_int_equal(journal_read(dir, &r, &n, &torn), 0);
    assert_int_equal(n, 3);
    assert_int_equal(torn, JOURNAL_HEADER_SIZE + 3 * JOURNAL_RECORD_SIZE);
    free(r);
    j = journal_open(dir);
    pose p = pose_n(7);
    journal_append(j, JOURNAL_MOVE, 0, 7, &p, 0);
    journal_close(j);
    assert_int_equal(journal_read(dir, &r, &n, &torn), 0);
    assert_true(n == 4 && torn == -1 && r[3].seq == 4 && r[3].p.t[0] == 7);
    free(r);
    tu_rmtree(dir);
    free(dir);
}

static void test_bad_header_names_file(void **st)
{
    char *dir = tu_tmpdir("journal");
    char path[4200];
    snprintf(path, sizeof path, "%s/journal", dir);
    tu_write_file(path, "not a journal at all", 20);
    journal_rec *r;
    size_t n;
    assert_int_equal(journal_read(dir, &r, &n, NULL), FN_EFORMAT);
    assert_non_null(strstr(fn_err_msg(), path));
    assert_non_null(strstr(fn_err_msg(), "offset 0"));
    assert_null(journal_open(dir));
    /* A missing journal is simply empty. */
    unlink(path);
    assert_int_equal(journal_read(dir, &r, &n, NULL), 0);
    assert_int_equal(n, 0);
    tu_rmtree(dir);
    free(dir);
}

static void test_flush_interval_and_truncate(void **st)
{
    char *dir = tu_tmpdir("journal");
    journal *j = journal_open(dir);
    pose p = pose_n(1);
    journal_append(j, JOURNAL_MOVE, 0, 0, &p, 1000000);
    assert_int_equal(file_size(dir), JOURNAL_HEADER_SIZE); /* buffered */
    journal_tick(j, 1000000 + 49999);
    assert_int_equal(file_size(dir), JOURNAL_HEADER_SIZE);
    journal_tick(j, 1000000 + 50000); /* 50 ms later it is on disk */
    assert_int_equal(file_size(dir), JOURNAL_HEADER_SIZE + JOURNAL_RECORD_SIZE);
    assert_int_equal(journal_truncate(j), 0);
    assert_int_equal(file_size(dir), JOURNAL_HEADER_SIZE);
    assert_int_equal(journal_count(j), 0);
    journal_close(j);
    tu_rmtree(dir);
    free(dir);
}

/* A child appends a record every millisecond of the journal's clock (the clock that drives the
 * flush, given here, so the machine's load does not change what is tested) and is killed (SIGKILL,
 * no cleanup) right after its last append: the journal on disk holds every record in order, up to
 * within 100 ms of that last one (journal.h: a kill loses the last 50-100 ms). */
static void test_crash_loses_at_most_100ms(void **st)
{
    char *dir = tu_tmpdir("journal");
    const int last = 300; /* records, 1 ms apart */
    pid_t pid = fork();
    if (pid == 0) {
        journal *j = journal_open(dir);
        for (int k = 0; k <= last; k++) {
            pose p = pose_n(k);
            journal_append(j, JOURNAL_MOVE, 0, 1000 * k, &p, 1000 * k);
        }
        raise(SIGKILL);
    }
    int status;
    waitpid(pid, &status, 0);
    assert_true(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL);
    journal_rec *r;
    size_t n;
    assert_int_equal(journal_read(dir, &r, &n, NULL), 0);
    assert_true(n > 10);
    if (1000 * last - r[n - 1].t_us > 100000)
        fail_msg("the journal on disk ends %lld us before the kill", (long long)(1000 * last - r[n - 1].t_us));
    for (size_t i = 0; i < n; i++)
        assert_true(r[i].seq == i + 1 && r[i].p.t[0] == (double)i && r[i].t_us == 1000 * (int64_t)i);
    free(r);
    tu_rmtree(dir);
    free(dir);
}

/* The loop writes every accepted pose; the journal replays to the loop's final poses. */
static int free_query(void *ctx, int a, const pose *pa, int b, const pose *pb, void *cache,
                      loop_contact *out)
{
    out->collides = 0;
    out->separation_mm = 1e9;
    return 0;
}

static void test_loop_journals_every_accepted_pose(void **st)
{
    char *dir = tu_tmpdir("journal");
    journal *j = journal_open(dir);
    frag f[2];
    memset(f, 0, sizeof f);
    for (int i = 0; i < 2; i++) {
        f[i].dim[0] = f[i].dim[1] = f[i].dim[2] = 2;
        f[i].spacing[0] = f[i].spacing[1] = f[i].spacing[2] = 1;
        f[i].home = f[i].pose = POSE_IDENTITY;
    }
    loop_collider col = {free_query, 0, NULL, NULL};
    loop *L = loop_new(f, 2, NULL, &col, NULL, j);
    loop_event e;
    memset(&e, 0, sizeof e);
    e.kind = LOOP_EV_MOTION;
    e.motion[0] = 0.5f;
    e.motion[4] = 0.25f;
    for (int k = 0; k < 30; k++) {
        e.t_us = 8000 * k;
        e.motion[0] = k == 5 ? 0.0f : 0.5f; /* a release: two gestures on fragment 0 */
        e.motion[4] = k == 5 ? 0.0f : 0.25f;
        loop_feed(L, &e);
        if (k == 14)
            loop_action_do(L, LOOP_ACT_NEXT);
    }
    loop_action_do(L, LOOP_ACT_UNDO);
    loop_stats s;
    loop_get_stats(L, &s);
    journal_close(j);
    journal_rec *r;
    size_t n;
    journal_read(dir, &r, &n, NULL);
    assert_int_equal(n, s.accepted + 1);
    assert_int_equal(r[n - 1].kind, JOURNAL_UNDO);
    assert_int_equal(r[0].kind, JOURNAL_START);
    pose fin[2] = {POSE_IDENTITY, POSE_IDENTITY};
    journal_final_poses(r, n, 2, fin);
    for (int i = 0; i < 2; i++) {
        pose lp = loop_pose(L, i);
        assert_memory_equal(&fin[i], &lp, sizeof(pose));
    }
    /* A fresh loop recovers the poses and the undo history from the journal alone. */
    loop *R = loop_new(f, 2, NULL, &col, NULL, NULL);
    assert_int_equal(loop_recover(R, r, n), 0);
    for (int i = 0; i < 2; i++) {
        pose a = loop_pose(L, i), b = loop_pose(R, i);
        assert_memory_equal(&a, &b, sizeof(pose));
    }
    /* Three gestures (two on fragment 0, one on 1), one already undone: two undos are left. */
    int undos = 0;
    while (loop_action_do(R, LOOP_ACT_UNDO) == LOOP_ACCEPTED)
        undos++;
    assert_int_equal(undos, 2);
    for (int i = 0; i < 2; i++) {
        pose b = loop_pose(R, i);
        assert_memory_equal(&POSE_IDENTITY, &b, sizeof(pose));
    }
    assert_int_equal(loop_action_do(R, LOOP_ACT_REDO), LOOP_ACCEPTED);
    journal_rec bad = r[0];
    bad.frag = 5;
    assert_int_equal(loop_recover(R, &bad, 1), FN_EFORMAT);
    loop_free(R);
    free(r);
    loop_free(L);
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_append_read_back),
        cmocka_unit_test(test_torn_tail_is_cut),
        cmocka_unit_test(test_bad_header_names_file),
        cmocka_unit_test(test_flush_interval_and_truncate),
        cmocka_unit_test(test_crash_loses_at_most_100ms),
        cmocka_unit_test(test_loop_journals_every_accepted_pose),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
