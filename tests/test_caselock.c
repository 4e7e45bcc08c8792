/* The lock on a case (caselock.h): a second writer is refused at once, naming the holder's
 * command and pid; --wait waits and then completes; readers share; two writers started together
 * never lose an edit; navigate holds the lock for its whole session; reduce -o holds its output,
 * and the benchmarks hold the case they open. Every wait is on an event (a
 * pipe, a line in a file, a child's exit). */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "caselock.h"
#include "err.h"
#include "testutil.h"

#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

struct fixture {
    char *dir;
    char cdir[4200];
};

static int setup(void **st)
{
    struct fixture *f = calloc(1, sizeof *f);
    f->dir = tu_tmpdir("caselock");
    tu_two_blocks_case(f->dir, f->cdir, sizeof f->cdir);
    *st = f;
    return 0;
}

/* A child process that holds dir's lock (exclusive or shared) until *release is closed. */
typedef struct holder {
    pid_t pid;
    int release;
} holder;

static holder hold(const char *dir, int exclusive)
{
    int ready[2], go[2];
    assert_int_equal(pipe(ready), 0);
    assert_int_equal(pipe(go), 0);
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        close(ready[0]);
        close(go[1]);
        caselock *l = caselock_take(dir, exclusive, 0);
        char c = l ? 'y' : 'n';
        if (write(ready[1], &c, 1) != 1 || read(go[0], &c, 1) < 0)
            _exit(2);
        caselock_release(l);
        _exit(0);
    }
    close(ready[1]);
    close(go[0]);
    fcntl(go[1], F_SETFD, FD_CLOEXEC); /* a CLI started later must not keep the holder waiting */
    char c = 0;
    assert_int_equal(read(ready[0], &c, 1), 1); /* the child has the lock */
    close(ready[0]);
    assert_int_equal(c, 'y');
    return (holder){pid, go[1]};
}

static void let_go(holder *h)
{
    close(h->release);
    assert_int_equal(tu_end(h->pid, 0, "lock holder"), 0);
}

static int fixed_id(const char *cdir)
{
    planning_case *c = case_load(cdir);
    if (!c)
        fail_msg("the case no longer loads: %s", fn_err_msg());
    int id = c->fixed >= 0 ? c->frag[c->fixed].id : 0;
    case_free(c);
    return id;
}

static long voxels_of(const char *cdir, int id)
{
    planning_case *c = case_load(cdir);
    if (!c)
        fail_msg("the case no longer loads: %s", fn_err_msg());
    int i = case_find(c, id);
    long n = i >= 0 ? (long)c->frag[i].voxels : -1;
    case_free(c);
    return n;
}

static void test_second_writer_refused_naming_holder(void **st)
{
    struct fixture *f = *st;
    holder h = hold(f->cdir, 1);
    char *out = NULL, pid[64];
    snprintf(pid, sizeof pid, "(pid %ld)", (long)h.pid);
    assert_int_equal(tu_run_cli(&out, "edit '%s' fix 2", f->cdir), 1);
    assert_non_null(strstr(out, f->cdir));
    assert_non_null(strstr(out, "is in use by `test_caselock"));
    assert_non_null(strstr(out, pid));
    assert_non_null(strstr(out, "--wait"));
    free(out);
    /* a reader is refused too while a writer holds the case */
    assert_int_equal(tu_run_cli(&out, "export '%s' --tfm '%s/tfm'", f->cdir, f->dir), 1);
    assert_non_null(strstr(out, pid));
    free(out);
    let_go(&h);
    assert_int_equal(fixed_id(f->cdir), 1);
    assert_int_equal(tu_run_cli(NULL, "edit '%s' fix 2", f->cdir), 0);
    assert_int_equal(fixed_id(f->cdir), 2);
}

static void test_readers_share_writers_wait(void **st)
{
    struct fixture *f = *st;
    holder h = hold(f->cdir, 0);
    char *out = NULL, log[4300];
    assert_int_equal(tu_run_cli(&out, "export '%s' --tfm '%s/tfm'", f->cdir, f->dir), 0);
    free(out);
    /* a writer with --wait says it waits, and completes once the reader is gone */
    snprintf(log, sizeof log, "%s/edit.out", f->dir);
    pid_t pid = tu_spawn_cli(log, NULL, (char *[]){"edit", f->cdir, "fix", "2", "--wait", NULL});
    assert_true(tu_wait_for_text(log, "waiting for it", TU_WAIT_MAX_S));
    assert_int_equal(fixed_id(f->cdir), 1);
    let_go(&h);
    assert_int_equal(tu_end(pid, 0, "edit --wait"), 0);
    assert_int_equal(fixed_id(f->cdir), 2);
}

/* Two edits started together: with --wait both land; without, one may be refused (saying so),
 * and every edit that reported success is in the case, which always loads. */
static void test_two_writers_never_lose_an_edit(void **st)
{
    struct fixture *f = *st;
    long before = voxels_of(f->cdir, 1);
    for (int wait = 1; wait >= 0; wait--) {
        char log1[4300], log2[4300], r[32];
        snprintf(log1, sizeof log1, "%s/a.out", f->dir);
        snprintf(log2, sizeof log2, "%s/b.out", f->dir);
        snprintf(r, sizeof r, "%d", wait ? 3 : 5);
        char *w = wait ? (char *)"--wait" : NULL;
        pid_t a = tu_spawn_cli(log1, NULL, (char *[]){"edit", f->cdir, "fix", wait ? (char *)"2" : (char *)"1", w, NULL});
        pid_t b = tu_spawn_cli(log2, NULL, (char *[]){"edit", f->cdir, "erase-sphere", "9", "15", "15", r,
                                                      "--id", "1", w, NULL});
        int ra = tu_end(a, 0, "edit fix"), rb = tu_end(b, 0, "edit erase-sphere");
        char *oa = tu_slurp(log1, NULL), *ob = tu_slurp(log2, NULL);
        if (wait)
            assert_true(ra == 0 && rb == 0);
        assert_true(ra == 0 || (ra == 1 && strstr(oa, "is in use by")));
        assert_true(rb == 0 || (rb == 1 && strstr(ob, "is in use by")));
        free(oa);
        free(ob);
        if (ra == 0)
            assert_int_equal(fixed_id(f->cdir), wait ? 2 : 1);
        long now = voxels_of(f->cdir, 1);
        if (rb == 0)
            assert_true(now < before);
        before = now;
    }
}

static void json_sha(const char *cdir, char out[65])
{
    planning_case *c = tu_case_load(cdir);
    memcpy(out, c->json_sha256, 65);
    case_free(c);
}

/* reduce -o OUT --force writes OUT: while another process holds OUT, it is refused, naming the
 * holder, and OUT is as it was. */
static void test_reduce_out_locked(void **st)
{
    struct fixture *f = *st;
    char out_dir[4300], before[65], after[65], pid[64];
    snprintf(out_dir, sizeof out_dir, "%s/reduced", f->dir);
    assert_int_equal(tu_run_cli(NULL, "reduce '%s' -o '%s'", f->cdir, out_dir), 0);
    json_sha(out_dir, before);
    holder h = hold(out_dir, 1);
    snprintf(pid, sizeof pid, "(pid %ld)", (long)h.pid);
    char *out = NULL;
    int rc = tu_run_cli(&out, "reduce '%s' -o '%s' --force --gap 0.5", f->cdir, out_dir);
    if (rc != 1 || !strstr(out, out_dir) || !strstr(out, "is in use by") || !strstr(out, pid))
        fail_msg("reduce -o a held case: exit %d, expected a refusal naming the holder: %s", rc, out ? out : "");
    free(out);
    json_sha(out_dir, after);
    assert_string_equal(after, before);
    let_go(&h);
}

/* The benchmarks that open a case hold it too: bench loop --case as navigate does (it reads the
 * journal as a session does: a live one half-written must not be set aside), bench collision
 * shared, as render. While a writer holds the case both are refused, naming it, and its journal is
 * left as it is. */
static void test_benchmarks_lock_the_case(void **st)
{
    struct fixture *f = *st;
    char journal[4300], pid[64];
    snprintf(journal, sizeof journal, "%s/journal", f->cdir);
    static const char live[] = "FNJ1 a record being written"; /* as navigate's, half-written */
    tu_write_file(journal, live, sizeof live - 1);
    holder h = hold(f->cdir, 1);
    snprintf(pid, sizeof pid, "(pid %ld)", (long)h.pid);
    static const char *const bench[2] = {"bench loop --repeat 1 --case", "bench collision --poses 2 --reps 1 --no-fcl"};
    for (int k = 0; k < 2; k++) {
        char *out = NULL;
        int rc = tu_run_cli(&out, "%s '%s'", bench[k], f->cdir);
        if (rc != 1 || !strstr(out, "is in use by") || !strstr(out, pid) || !strstr(out, "--wait"))
            fail_msg("%s of a held case: exit %d, expected a refusal naming the holder: %s", bench[k], rc,
                     out ? out : "");
        free(out);
        size_t n = 0;
        char *j = tu_slurp(journal, &n);
        if (!j || n != sizeof live - 1 || memcmp(j, live, n))
            fail_msg("%s touched the held case's journal", bench[k]);
        free(j);
    }
    let_go(&h);
    unlink(journal);
    h = hold(f->cdir, 0); /* a reader: bench collision shares the case with it */
    assert_int_equal(tu_run_cli(NULL, "bench collision --poses 2 --reps 1 --no-fcl '%s'", f->cdir), 0);
    let_go(&h);
}

/* navigate holds the lock for its whole session: a second navigate (or any writer) is refused,
 * naming it. */
static void test_navigate_holds_the_case(void **st)
{
    struct fixture *f = *st;
    char keys[4300], spec[4400], log[4300];
    snprintf(keys, sizeof keys, "%s/keys", f->dir);
    snprintf(spec, sizeof spec, "keyboard:%s", keys);
    snprintf(log, sizeof log, "%s/nav.out", f->dir);
    tu_write_file(keys, "0", 1);
    pid_t pid = tu_spawn_cli(log, NULL, (char *[]){"navigate", f->cdir, "--device", spec, "--json", NULL});
    assert_true(tu_wait_for_text(log, "| world", TU_WAIT_MAX_S)); /* the session runs */
    char *out = NULL, who[64];
    snprintf(who, sizeof who, "(pid %ld)", (long)pid);
    assert_int_equal(tu_run_cli(&out, "navigate '%s' --device '%s' --duration 0.3", f->cdir, spec), 1);
    assert_non_null(strstr(out, "is in use by `fracnav navigate"));
    assert_non_null(strstr(out, who));
    assert_null(strstr(out, "interrupted"));
    free(out);
    kill(pid, SIGTERM); /* Ctrl-C: it saves and exits 0 */
    assert_int_equal(tu_end(pid, 0, "navigate"), 0);
    assert_int_equal(tu_run_cli(NULL, "edit '%s' fix 2", f->cdir), 0);
}

/* The lock file itself planted as a link out of the case: refused by name, never written. */
static void test_linked_lock_file_refused(void **st)
{
    struct fixture *f = *st;
    char outside[4300], lock[4400];
    snprintf(outside, sizeof outside, "%s/outside", f->dir);
    tu_write_file(outside, "x\n", 2);
    snprintf(lock, sizeof lock, "%s/" CASELOCK_FILE, f->cdir);
    unlink(lock);
    assert_int_equal(symlink(outside, lock), 0);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "edit '%s' fix 2", f->cdir), 1);
    assert_non_null(strstr(out, lock));
    free(out);
    size_t n;
    char *s = tu_slurp(outside, &n);
    assert_true(n == 2 && !memcmp(s, "x\n", 2));
    free(s);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_second_writer_refused_naming_holder, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_readers_share_writers_wait, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_two_writers_never_lose_an_edit, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_reduce_out_locked, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_benchmarks_lock_the_case, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_navigate_holds_the_case, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_linked_lock_file_refused, setup, tu_fixture_teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
