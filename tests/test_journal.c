/* The pose journal: format, binding, damage of every kind, flush timing, a real crash, recovery. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "journal.h"
#include "loop.h"
#include "testutil.h"

#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
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

static const journal_bind BIND = {"1111111111111111111111111111111111111111111111111111111111111111",
                                  2, {1, 2}};

static journal *open_bound(const char *dir)
{
    journal *j = journal_open(dir, &BIND);
    if (!j)
        fail_msg("%s", fn_err_msg());
    return j;
}

/* A journal of n moves of fragment k % 2 to pose_n(k). */
static void write_moves(const char *dir, int n)
{
    journal *j = open_bound(dir);
    for (int k = 0; k < n; k++) {
        pose p = pose_n(k);
        assert_int_equal(journal_append(j, JOURNAL_MOVE, k % 2, 1000 * k, &p, 0), 0);
    }
    assert_int_equal(journal_close(j), 0);
}

static void scan(const char *dir, journal_scan *s)
{
    if (journal_read(dir, s) < 0)
        fail_msg("%s", fn_err_msg());
}

static void test_append_read_back(void **st)
{
    char *dir = tu_tmpdir("journal");
    write_moves(dir, 10);
    assert_int_equal(file_size(dir), JOURNAL_HEADER_SIZE + 10 * JOURNAL_RECORD_SIZE);
    journal_scan s;
    scan(dir, &s);
    assert_int_equal(s.n, 10);
    assert_int_equal(s.damaged_at, -1);
    assert_true(journal_bind_equal(&s.bind, &BIND));
    journal_rec *r = s.recs;
    assert_true(r[9].seq == 10 && r[9].frag == 1 && r[9].t_us == 9000 && r[9].p.t[0] == 9);
    pose fin[2] = {POSE_IDENTITY, POSE_IDENTITY};
    assert_int_equal(journal_final_poses(r, s.n, 2, fin), 0);
    assert_true(fin[0].t[0] == 8 && fin[1].t[0] == 9);
    assert_int_equal(journal_final_poses(r, s.n, 1, fin), FN_EFORMAT);
    assert_non_null(strstr(fn_err_msg(), "record 2"));
    journal_scan_free(&s);
    /* Reopening continues the numbering. */
    journal *j = open_bound(dir);
    pose p = pose_n(42);
    journal_append(j, JOURNAL_UNDO, 0, 1, &p, 0);
    assert_int_equal(journal_count(j), 11);
    journal_close(j);
    scan(dir, &s);
    assert_true(s.n == 11 && s.recs[10].seq == 11 && s.recs[10].kind == JOURNAL_UNDO);
    journal_scan_free(&s);
    /* Records of another case state are not appended to. */
    journal_bind other = BIND;
    other.ids[1] = 3;
    assert_null(journal_open(dir, &other));
    assert_non_null(strstr(fn_err_msg(), "another state"));
    tu_rmtree(dir);
    free(dir);
}

static void put_byte(const char *dir, long off, int byte)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/journal", dir);
    FILE *f = fopen(path, "r+b");
    fseek(f, off, SEEK_SET);
    fputc(byte, f);
    fclose(f);
}

/* A record rewritten with a valid CRC: the damage only the field checks can see. */
static void rewrite_record(const char *dir, int index, const journal_rec *r)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/journal", dir);
    size_t len;
    uint8_t *buf = (uint8_t *)tu_slurp(path, &len);
    journal_scan s;
    assert_int_equal(journal_parse(buf, len, "x", &s), 0);
    s.recs[index] = *r;
    char aside[4300];
    assert_int_equal(journal_set_aside(dir, "t", &s.bind, s.recs, s.n, aside, sizeof aside), 0);
    unlink(aside);
    journal_scan_free(&s);
    free(buf);
}

/* Every kind of damage: the good records before it, and where and what it is. */
static void expect_damage(const char *dir, size_t good, const char *what)
{
    journal_scan s;
    scan(dir, &s);
    assert_int_equal(s.n, good);
    assert_int_equal(s.damaged_at, JOURNAL_HEADER_SIZE + (long)good * JOURNAL_RECORD_SIZE);
    char where[160];
    snprintf(where, sizeof where, "record %zu at offset %ld", good + 1, s.damaged_at);
    if (!strstr(s.damage, where) || !strstr(s.damage, what) || !strstr(s.damage, dir))
        fail_msg("expected '%s' and '%s' in: %s", where, what, s.damage);
    journal_scan_free(&s);
}

/* Cut short, a flipped byte, a bad first record: each found where it is. */
static void test_damage_is_located(void **st)
{
    char *dir = tu_tmpdir("journal");
    char path[4200];
    snprintf(path, sizeof path, "%s/journal", dir);
    write_moves(dir, 5);
    assert_int_equal(truncate(path, JOURNAL_HEADER_SIZE + 4 * JOURNAL_RECORD_SIZE + 30), 0);
    expect_damage(dir, 4, "cut short");
    put_byte(dir, JOURNAL_HEADER_SIZE + 3 * JOURNAL_RECORD_SIZE + 40, 0x5a);
    expect_damage(dir, 3, "bad CRC");
    put_byte(dir, JOURNAL_HEADER_SIZE + 10, 0x5a); /* the first record */
    expect_damage(dir, 0, "bad CRC");
    assert_null(journal_open(dir, &BIND)); /* damage is resolved (kept aside) before appending */
    assert_non_null(strstr(fn_err_msg(), "record 1 at offset"));
    tu_rmtree(dir);
    free(dir);
}

/* Records with a good CRC whose fields cannot be: each is damage, named like case.json's errors. */
static void test_bad_fields_are_damage(void **st)
{
    static const char *what[] = {"unknown kind 9", "fragment index 2", "not finite", "unit length",
                                 "sequence number"};
    for (int c = 0; c < 5; c++) {
        char *dir = tu_tmpdir("journal");
        write_moves(dir, 4);
        journal_scan s;
        scan(dir, &s);
        journal_rec r = s.recs[c == 0 ? 0 : 2];
        journal_scan_free(&s);
        if (c == 0)
            r.kind = 9;
        else if (c == 1)
            r.frag = 2;
        else if (c == 2)
            r.p.t[1] = NAN;
        else if (c == 3)
            r.p.q[0] = 2;
        else
            r.seq = 7;
        rewrite_record(dir, c == 0 ? 0 : 2, &r);
        expect_damage(dir, c == 0 ? 0 : 2, what[c]);
        tu_rmtree(dir);
        free(dir);
    }
}

/* A 2 GiB sparse journal (good records, then a hole): read up to the hole and no further. */
static void test_huge_sparse_journal_is_bounded(void **st)
{
    char *dir = tu_tmpdir("journal");
    char path[4200];
    snprintf(path, sizeof path, "%s/journal", dir);
    write_moves(dir, 3);
    assert_int_equal(truncate(path, 2147483648L), 0);
    struct rusage before, after;
    getrusage(RUSAGE_SELF, &before);
    expect_damage(dir, 3, "bad CRC");
    getrusage(RUSAGE_SELF, &after);
    assert_true(after.ru_maxrss - before.ru_maxrss < 16 * 1024); /* kB */
    tu_rmtree(dir);
    free(dir);
}

/* Damage kept aside as a file; the good records before it stay as the journal. */
static void test_set_aside_keeps_the_damaged_file(void **st)
{
    char *dir = tu_tmpdir("journal");
    write_moves(dir, 6);
    put_byte(dir, JOURNAL_HEADER_SIZE + 4 * JOURNAL_RECORD_SIZE + 3, 0x77);
    long size = file_size(dir);
    journal_scan s;
    scan(dir, &s);
    char aside[4300], want[4300];
    assert_int_equal(journal_set_aside(dir, "damaged", &s.bind, s.recs, s.n, aside, sizeof aside), 0);
    journal_scan_free(&s);
    snprintf(want, sizeof want, "%s/journal.damaged.1", dir);
    assert_string_equal(aside, want);
    struct stat sb;
    assert_int_equal(stat(aside, &sb), 0);
    assert_int_equal(sb.st_size, size);
    scan(dir, &s);
    assert_true(s.n == 4 && s.damaged_at == -1 && journal_bind_equal(&s.bind, &BIND));
    journal_scan_free(&s);
    journal *j = open_bound(dir); /* and appending goes on after them */
    pose p = pose_n(9);
    journal_append(j, JOURNAL_MOVE, 1, 0, &p, 0);
    journal_close(j);
    scan(dir, &s);
    assert_true(s.n == 5 && s.recs[4].seq == 5);
    journal_scan_free(&s);
    tu_rmtree(dir);
    free(dir);
}

static void test_bad_header_names_file(void **st)
{
    char *dir = tu_tmpdir("journal");
    char path[4200];
    snprintf(path, sizeof path, "%s/journal", dir);
    tu_write_file(path, "not a journal at all", 20);
    journal_scan s;
    assert_int_equal(journal_read(dir, &s), FN_EFORMAT);
    assert_non_null(strstr(fn_err_msg(), path));
    assert_non_null(strstr(fn_err_msg(), "offset 0"));
    assert_null(journal_open(dir, &BIND));
    /* A missing journal is simply empty. */
    unlink(path);
    assert_int_equal(journal_read(dir, &s), 0);
    assert_int_equal(s.n, 0);
    tu_rmtree(dir);
    free(dir);
}

static void test_flush_interval_and_truncate(void **st)
{
    char *dir = tu_tmpdir("journal");
    journal *j = open_bound(dir);
    pose p = pose_n(1);
    journal_append(j, JOURNAL_MOVE, 0, 0, &p, 1000000);
    assert_int_equal(file_size(dir), JOURNAL_HEADER_SIZE); /* buffered */
    journal_tick(j, 1000000 + 49999);
    assert_int_equal(file_size(dir), JOURNAL_HEADER_SIZE);
    journal_tick(j, 1000000 + 50000); /* 50 ms later it is on disk */
    assert_int_equal(file_size(dir), JOURNAL_HEADER_SIZE + JOURNAL_RECORD_SIZE);
    journal_bind saved = BIND;
    memset(saved.case_sha256, '2', 64);
    journal_rebind(j, &saved);
    assert_int_equal(journal_truncate(j), 0);
    assert_int_equal(file_size(dir), JOURNAL_HEADER_SIZE);
    assert_int_equal(journal_count(j), 0);
    journal_close(j);
    journal_scan s;
    scan(dir, &s);
    assert_true(journal_bind_equal(&s.bind, &saved));
    journal_scan_free(&s);
    tu_rmtree(dir);
    free(dir);
}

/* A child appends a record per millisecond of its (simulated) clock and is killed (SIGKILL, no
 * cleanup) right after record K: what is on disk reaches to within the flush interval (50 ms, 50
 * records) of it, and every record on disk is whole. */
static void test_crash_loses_at_most_the_flush_interval(void **st)
{
    char *dir = tu_tmpdir("journal");
    enum { K = 777 };
    pid_t pid = fork();
    if (pid == 0) {
        journal *j = journal_open(dir, &BIND);
        for (int k = 0;; k++) {
            pose p = pose_n(k);
            journal_append(j, JOURNAL_MOVE, 0, 1000 * k, &p, 1000 * k);
            if (k == K)
                raise(SIGKILL);
        }
    }
    int status;
    waitpid(pid, &status, 0);
    assert_true(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL);
    journal_scan s;
    scan(dir, &s);
    assert_int_equal(s.damaged_at, -1);
    assert_true(s.n >= K + 1 - 50 && s.n <= K + 1);
    for (size_t i = 0; i < s.n; i++)
        assert_true(s.recs[i].seq == i + 1 && s.recs[i].p.t[0] == (double)i);
    journal_scan_free(&s);
    tu_rmtree(dir);
    free(dir);
}

/* The loop writes every accepted pose; the journal replays to the loop's final poses. */
static int free_query(void *ctx, int a, const pose *pa, int b, const pose *pb, double tol, void *cache,
                      loop_contact *out)
{
    out->collides = 0;
    out->separation_mm = 1e9;
    return 0;
}

static void test_loop_journals_every_accepted_pose(void **st)
{
    char *dir = tu_tmpdir("journal");
    journal *j = open_bound(dir);
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
    journal_scan sc;
    scan(dir, &sc);
    journal_rec *r = sc.recs;
    size_t n = sc.n;
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
    /* Fixing a fragment is journaled, and recovered. */
    j = open_bound(dir);
    loop *F = loop_new(f, 2, NULL, &col, NULL, j);
    assert_int_equal(loop_action_do(F, LOOP_ACT_FIX), LOOP_IDLE);
    assert_true(loop_fixed(F, 0));
    assert_int_equal(loop_action_do(F, LOOP_ACT_UNDO), LOOP_ACCEPTED); /* undoable, */
    assert_false(loop_fixed(F, 0));
    assert_int_equal(loop_action_do(F, LOOP_ACT_REDO), LOOP_ACCEPTED); /* and redone */
    assert_true(loop_fixed(F, 0));
    loop_free(F);
    journal_close(j);
    journal_scan fs;
    scan(dir, &fs);
    assert_true(fs.n == n + 3 && fs.recs[n].kind == JOURNAL_FIX && fs.recs[n].frag == 0 &&
                fs.recs[n].flag == 1 && fs.recs[n + 1].flag == 0 && fs.recs[n + 2].flag == 1);
    loop *G = loop_new(f, 2, NULL, &col, NULL, NULL);
    assert_int_equal(loop_recover(G, fs.recs, fs.n), 0);
    assert_true(loop_fixed(G, 0) && !loop_fixed(G, 1));
    assert_int_equal(loop_action_do(G, LOOP_ACT_UNDO), LOOP_ACCEPTED); /* recovered history too */
    assert_false(loop_fixed(G, 0));
    loop_free(G);
    journal_scan_free(&fs);
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
        cmocka_unit_test(test_damage_is_located),
        cmocka_unit_test(test_bad_fields_are_damage),
        cmocka_unit_test(test_huge_sparse_journal_is_bounded),
        cmocka_unit_test(test_set_aside_keeps_the_damaged_file),
        cmocka_unit_test(test_bad_header_names_file),
        cmocka_unit_test(test_flush_interval_and_truncate),
        cmocka_unit_test(test_crash_loses_at_most_the_flush_interval),
        cmocka_unit_test(test_loop_journals_every_accepted_pose),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
