/* fracnav record as a user runs it on the in-process devices (no FUSE needed): it ends at the end
 * of a script, keeps what it has on Ctrl-C, shows progress only on a terminal; and the virtual
 * device says when a recording's device replaces the one named. Every wait is on an event (the
 * child's exit, a file's content); the bounds only catch a hang. */
#define _GNU_SOURCE
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "err.h"
#include "fnrec.h"
#include "testutil.h"

static char *dir;

static int setup(void **st)
{
    dir = tu_tmpdir("record");
    return 0;
}

static int teardown(void **st)
{
    tu_rmtree(dir);
    free(dir);
    return 0;
}

static const char *path_in(const char *name)
{
    static char p[4][600];
    static int k;
    k = (k + 1) % 4;
    snprintf(p[k], sizeof p[k], "%s/%s", dir, name);
    return p[k];
}

static const char *write_script(const char *name, const char *text)
{
    const char *p = path_in(name);
    tu_write_file(p, text, strlen(text));
    return p;
}

static size_t count_in(const fnrec *r)
{
    size_t n = 0;
    for (size_t i = 0; i < r->n; i++)
        n += r->ev[i].dir == FNREC_IN;
    return n;
}

/* Without --seconds, record ends with the virtual device's script, having all of its reports. */
static void test_record_stops_at_script_end(void **st)
{
    const char *scr = write_script("s.script", "translate -y 3 mm over 0.2 s\npress 1\nrelease\n");
    const char *rec = path_in("s.fnrec"), *log = path_in("s.log");
    char dev[700];
    snprintf(dev, sizeof dev, "virtual:spacenavigator:script=%s", scr);
    pid_t pid = tu_spawn_cli(log, NULL, (char *[]){"record", "-o", (char *)rec, "--device", dev, NULL});
    assert_int_equal(tu_end(pid, 0, "record of a virtual script"), 0);
    char *text = tu_slurp(log, NULL);
    assert_non_null(strstr(text, "end of the virtual device's script"));
    free(text);
    fnrec *want = tu_render_script(scr, "spacenavigator"), *got = fnrec_load(rec);
    assert_non_null(got);
    assert_int_equal(count_in(got), count_in(want));
    fnrec_free(want);
    fnrec_free(got);
}

/* At least 20 input reports are in the recording at path. */
static int twenty_reports(void *path)
{
    char *text = tu_slurp(path, NULL);
    size_t lines = 0;
    for (const char *p = text; p && (p = strstr(p, " in ")); p++)
        lines++;
    free(text);
    return lines >= 20;
}

/* Ctrl-C mid-recording: exit 0, says so, and the file holds what was recorded. */
static void test_record_ctrl_c_keeps_what_it_has(void **st)
{
    const char *scr = write_script("long.script", "translate +x 40 mm over 60 s\n");
    const char *rec = path_in("c.fnrec"), *log = path_in("c.log");
    char dev[700];
    snprintf(dev, sizeof dev, "virtual:spacenavigator:script=%s", scr);
    pid_t pid = tu_spawn_cli(log, NULL, (char *[]){"record", "-o", (char *)rec, "--device", dev, NULL});
    assert_true(tu_wait_for(twenty_reports, (void *)rec, TU_WAIT_MAX_S));
    assert_int_equal(tu_end(pid, SIGINT, "record after Ctrl-C"), 0);
    char *text = tu_slurp(log, NULL);
    assert_non_null(strstr(text, "(stopped by Ctrl-C)"));
    free(text);
    fnrec *got = fnrec_load(rec);
    assert_non_null(got);
    assert_true(count_in(got) >= 20);
    fnrec_free(got);
}

/* On a terminal, stderr shows live progress (reports, seconds); into a pipe or file, it does not. */
static void test_record_progress_on_terminal(void **st)
{
    const char *scr = write_script("p.script", "translate -y 3 mm over 0.6 s\n");
    const char *rec = path_in("p.fnrec");
    char dev[700];
    snprintf(dev, sizeof dev, "virtual:spacenavigator:script=%s", scr);
    int master = posix_openpt(O_RDWR | O_NOCTTY);
    assert_true(master >= 0 && grantpt(master) == 0 && unlockpt(master) == 0);
    int slave = open(ptsname(master), O_RDWR | O_NOCTTY);
    assert_true(slave >= 0);
    /* It ends with the script; the terminal stays open here until it has, so what it wrote waits. */
    pid_t pid = tu_spawn_cli(ptsname(master), NULL, (char *[]){"record", "-o", (char *)rec, "--device", dev,
                                                               "--seconds", "30", NULL});
    assert_int_equal(tu_end(pid, 0, "record on a terminal"), 0);
    close(slave);
    char text[8192];
    size_t n = 0;
    ssize_t got;
    while (n < sizeof text - 1 && (got = read(master, text + n, sizeof text - 1 - n)) > 0)
        n += (size_t)got; /* EIO once the child, the last holder of the terminal, is gone */
    text[n] = '\0';
    close(master);
    if (!strstr(text, "\rrecording ") || !strstr(text, " reports, ") || !strstr(text, " s"))
        fail_msg("no progress line on the terminal: '%s'", text);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "record -o '%s' --device '%s' --seconds 30", rec, dev), 0);
    assert_null(strstr(out, "\rrecording "));
    assert_non_null(strstr(out, "reports written to"));
    free(out);
}

/* virtual:DEVICE:play=F plays F's device, not DEVICE: it says so, as fracnav-sim serve does. */
static void test_virtual_play_warns_of_its_device(void **st)
{
    const char *scr = write_script("w.script", "translate +x 2 mm over 0.1 s\n");
    const char *rec = path_in("w.fnrec"), *rec2 = path_in("w2.fnrec");
    fnrec *r = tu_render_script(scr, "spacenavigator");
    assert_int_equal(fnrec_save(r, rec), 0);
    fnrec_free(r);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "record -o '%s' --device 'virtual:open-controller:play=%s' --seconds 30", rec2, rec),
                     0);
    if (!strstr(out, "warning: ") || !strstr(out, "open-controller ignored") || !strstr(out, "046d:c626"))
        fail_msg("no warning that the recording's device is served: %s", out);
    free(out);
    fnrec *got = fnrec_load(rec2);
    assert_non_null(got);
    assert_int_equal(got->hdr.pid, 0xc626);
    fnrec_free(got);
    assert_int_equal(tu_run_cli(&out, "record -o '%s' --device 'virtual:spacenavigator:play=%s' --seconds 30", rec2, rec),
                     0);
    assert_null(strstr(out, "warning: "));
    free(out);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_record_stops_at_script_end),
        cmocka_unit_test(test_record_ctrl_c_keeps_what_it_has),
        cmocka_unit_test(test_record_progress_on_terminal),
        cmocka_unit_test(test_virtual_play_warns_of_its_device),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
