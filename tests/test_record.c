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
#include "script.h"
#include "simdev.h"
#include "testutil.h"

#define HANG_S TU_WAIT_MAX_S /* a wait still unmet after this long never ends */

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

static void pause_ms(int ms)
{
    nanosleep(&(struct timespec){0, ms * 1000000L}, NULL);
}

/* Starts `fracnav record ARGS...` with stderr to err_fd (stdout to /dev/null). */
static pid_t start_record(int err_fd, const char *first, ...)
{
    const char *bin = getenv("FRACNAV_BIN");
    char *argv[16] = {(char *)(bin ? bin : "fracnav"), "record"};
    int n = 2;
    va_list ap;
    va_start(ap, first);
    for (const char *a = first; a && n < 15; a = va_arg(ap, const char *))
        argv[n++] = (char *)a;
    va_end(ap);
    argv[n] = NULL;
    pid_t pid = fork();
    if (pid == 0) {
        int null = open("/dev/null", O_WRONLY);
        dup2(null, 1);
        dup2(err_fd, 2);
        execv(argv[0], argv);
        _exit(127);
    }
    return pid;
}


static size_t count_in(const fnrec *r)
{
    size_t n = 0;
    for (size_t i = 0; i < r->n; i++)
        n += r->ev[i].dir == FNREC_IN;
    return n;
}

static fnrec *rendered(const char *script_path, const char *device)
{
    script *s = script_load(script_path);
    assert_non_null(s);
    fnrec *r = script_render(s, sim_profile_find(device));
    free(s);
    assert_non_null(r);
    return r;
}

/* Without --seconds, record ends with the virtual device's script, having all of its reports. */
static void test_record_stops_at_script_end(void **st)
{
    const char *scr = write_script("s.script", "translate -y 3 mm over 0.2 s\npress 1\nrelease\n");
    const char *rec = path_in("s.fnrec"), *log = path_in("s.log");
    char dev[700];
    snprintf(dev, sizeof dev, "virtual:spacenavigator:script=%s", scr);
    int fd = open(log, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    pid_t pid = start_record(fd, "-o", rec, "--device", dev, NULL);
    close(fd);
    assert_int_equal(tu_wait_exit(pid, "record of a virtual script"), 0);
    char *text = tu_slurp(log, NULL);
    assert_non_null(strstr(text, "end of the virtual device's script"));
    free(text);
    fnrec *want = rendered(scr, "spacenavigator"), *got = fnrec_load(rec);
    assert_non_null(got);
    assert_int_equal(count_in(got), count_in(want));
    fnrec_free(want);
    fnrec_free(got);
}

/* Ctrl-C mid-recording: exit 0, says so, and the file holds what was recorded. */
static void test_record_ctrl_c_keeps_what_it_has(void **st)
{
    const char *scr = write_script("long.script", "translate +x 40 mm over 60 s\n");
    const char *rec = path_in("c.fnrec"), *log = path_in("c.log");
    char dev[700];
    snprintf(dev, sizeof dev, "virtual:spacenavigator:script=%s", scr);
    int fd = open(log, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    pid_t pid = start_record(fd, "-o", rec, "--device", dev, NULL);
    close(fd);
    size_t lines = 0;
    for (int i = 0; i < HANG_S * 100 && lines < 20; i++) { /* until 20 reports are on disk */
        char *text = tu_slurp(rec, NULL);
        lines = 0;
        for (const char *p = text; p && (p = strstr(p, " in ")); p++)
            lines++;
        free(text);
        if (lines < 20)
            pause_ms(10);
    }
    assert_true(lines >= 20);
    kill(pid, SIGINT);
    assert_int_equal(tu_wait_exit(pid, "record after Ctrl-C"), 0);
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
    pid_t pid = start_record(slave, "-o", rec, "--device", dev, "--seconds", "30", NULL); /* ends with the script */
    close(slave);
    char text[8192];
    size_t n = 0;
    ssize_t got;
    while (n < sizeof text - 1 && (got = read(master, text + n, sizeof text - 1 - n)) > 0)
        n += (size_t)got; /* EIO once the child, the last holder of the terminal, is gone */
    text[n] = '\0';
    close(master);
    assert_int_equal(tu_wait_exit(pid, "record on a terminal"), 0);
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
    fnrec *r = rendered(scr, "spacenavigator");
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
