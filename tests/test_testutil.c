/* The tests' process helper (testutil.h): the wait bound and its multiplier, a line waited for on a
 * child's standard error, a child ended by a signal or by itself, and every child left over ended
 * at once. The waits are on events (a line, the end of a stream, a child's exit). */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "testutil.h"

#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>

/* 30 s times $FRACNAV_TEST_SLOW; an unset, empty, zero or negative multiplier counts as 1. */
static void test_wait_bound_scales(void **st)
{
    char *keep = getenv("FRACNAV_TEST_SLOW");
    keep = keep ? strdup(keep) : NULL;
    unsetenv("FRACNAV_TEST_SLOW");
    assert_int_equal(TU_WAIT_MAX_S, 30);
    setenv("FRACNAV_TEST_SLOW", "5", 1);
    assert_int_equal(TU_WAIT_MAX_S, 150);
    setenv("FRACNAV_TEST_SLOW", "0.5", 1);
    assert_int_equal(TU_WAIT_MAX_S, 15);
    setenv("FRACNAV_TEST_SLOW", "", 1);
    assert_int_equal(TU_WAIT_MAX_S, 30);
    setenv("FRACNAV_TEST_SLOW", "-2", 1);
    assert_int_equal(TU_WAIT_MAX_S, 30);
    if (keep)
        setenv("FRACNAV_TEST_SLOW", keep, 1);
    else
        unsetenv("FRACNAV_TEST_SLOW");
    free(keep);
}

/* The line with the needle is found, what came before it is kept, the rest reads to the end of
 * the stream, and the child's own exit status comes back. */
static void test_line_then_exit_status(void **st)
{
    FILE *err;
    pid_t pid = tu_spawn((char *[]){"/bin/sh", "-c", "echo one >&2; echo two >&2; printf tail >&2; exit 3", NULL},
                         NULL, &err);
    char seen[256] = "";
    assert_true(tu_wait_line(err, "two", seen, sizeof seen));
    assert_string_equal(seen, "one\ntwo\n");
    assert_false(tu_wait_line(err, "\001", seen, sizeof seen)); /* the end of the stream */
    assert_string_equal(seen, "one\ntwo\ntail");
    fclose(err);
    assert_int_equal(tu_end(pid, 0, "sh"), 3);
}

/* A line that never comes ends the wait at the bound (here 1.5 s), not at the child's end. */
static void test_line_that_never_comes(void **st)
{
    setenv("FRACNAV_TEST_SLOW", "0.05", 1);
    FILE *err;
    pid_t pid = tu_spawn((char *[]){"/bin/sh", "-c", "echo waiting >&2; exec sleep 600", NULL}, NULL, &err);
    char seen[256] = "";
    assert_false(tu_wait_line(err, "never", seen, sizeof seen));
    assert_string_equal(seen, "waiting\n");
    assert_int_equal(tu_end(pid, SIGKILL, "sleep"), 128 + SIGKILL);
    fclose(err);
    unsetenv("FRACNAV_TEST_SLOW");
}

/* What a failed test leaves running, tu_end_all ends and reaps. */
static void test_end_all(void **st)
{
    pid_t a = tu_spawn((char *[]){"/bin/sleep", "600", NULL}, "/dev/null", NULL);
    pid_t b = tu_spawn((char *[]){"/bin/sleep", "600", NULL}, "/dev/null", NULL);
    tu_end_all();
    assert_int_equal(waitpid(a, NULL, WNOHANG), -1); /* already reaped */
    assert_int_equal(errno, ECHILD);
    assert_int_equal(waitpid(b, NULL, WNOHANG), -1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_wait_bound_scales),
        cmocka_unit_test(test_line_then_exit_status),
        cmocka_unit_test(test_line_that_never_comes),
        cmocka_unit_test(test_end_all),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
