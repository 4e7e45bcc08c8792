/* One way to load the calibration a command runs with (calib_setup): navigate, replay and
 * device-test report bad lines alike, and differ only in which files they may read. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "calib.h"
#include "err.h"
#include "testutil.h"

static char *dir;
static char named[512];

static int setup(void **st)
{
    (void)st;
    dir = tu_tmpdir("calsetup");
    char home[600], rc[700];
    snprintf(home, sizeof home, "%s/home", dir);
    snprintf(rc, sizeof rc, "%s/.config/fracnav/spnavrc", home);
    char sub[700];
    snprintf(sub, sizeof sub, "mkdir -p %s/.config/fracnav", home);
    if (system(sub))
        return -1;
    tu_write_file(rc, "sensitivity = 2\n", 16);
    setenv("HOME", home, 1);
    setenv("FRACNAV_SYSCONFDIR", dir, 1);
    snprintf(named, sizeof named, "%s/named.rc", dir);
    const char *text = "sensitivity = 3\nno-such-key = 1\ndead-zone = x\n";
    tu_write_file(named, text, strlen(text));
    return 0;
}

static int teardown(void **st)
{
    (void)st;
    tu_rmtree(dir);
    free(dir);
    return 0;
}

/* Bad lines: one header naming who and how many, then one line per bad line; the good ones hold. */
static void test_bad_lines_reported_once(void **st)
{
    (void)st;
    char *text = NULL;
    size_t len = 0;
    FILE *err = open_memstream(&text, &len);
    calib c;
    char used[4096];
    assert_int_equal(calib_setup(&c, named, 0, err, "fracnav navigate", used, sizeof used), 0);
    fclose(err);
    assert_string_equal(used, named);
    assert_true(c.sens == 3.0f);
    assert_int_equal(strncmp(text, "fracnav navigate: 2 bad line(s) skipped:\n", 41), 0);
    assert_non_null(strstr(text, "named.rc:2:"));
    assert_non_null(strstr(text, "named.rc:3:"));
    free(text);
}

/* No path: the user's file, unless the command reads named files only (replay). */
static void test_which_files(void **st)
{
    (void)st;
    calib c;
    char used[4096];
    assert_int_equal(calib_setup(&c, NULL, 0, stderr, "t", used, sizeof used), 0);
    assert_true(c.sens == 2.0f);
    assert_non_null(strstr(used, "/home/.config/fracnav/spnavrc"));
    assert_int_equal(calib_setup(&c, NULL, CALIB_NAMED_ONLY, stderr, "t", used, sizeof used), 0);
    assert_true(c.sens == 1.0f);
    assert_string_equal(used, "");
}

/* A named file that is missing is an error naming it, unless it is about to be written. */
static void test_missing_named_file(void **st)
{
    (void)st;
    calib c;
    char missing[600], used[4096] = "x";
    snprintf(missing, sizeof missing, "%s/missing.rc", dir);
    assert_true(calib_setup(&c, missing, 0, stderr, "t", used, sizeof used) < 0);
    assert_non_null(strstr(fn_err_msg(), "missing.rc"));
    assert_int_equal(calib_setup(&c, missing, CALIB_NEW_OK, stderr, "t", used, sizeof used), 0);
    assert_string_equal(used, "");
    assert_true(c.sens == 1.0f);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bad_lines_reported_once),
        cmocka_unit_test(test_which_files),
        cmocka_unit_test(test_missing_named_file),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
