/* fracnav-sim serve against fracnav's commands, as a user meets them: a recording that ends with
 * the server, a --fast server recorded at the device's cadence, a wireless model's battery in every
 * program that opens the node, a second server on a served folder refused (also when two start at
 * once), a killed server's dead mount removed by the next, and a node this user may not open named
 * as a permission problem. Needs /dev/fuse and root (CI has both); the tests skip
 * visibly without them. Waits are on events (a node appearing, a child's exit); bounds only catch
 * a hang. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <jansson.h>
#include <libgen.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "err.h"
#include "fnrec.h"
#include "simdev.h"
#include "testutil.h"

static char *workdir;
static char mnt[512];
static pid_t server;

static char *path_in(const char *name)
{
    static char p[16][700];
    static int k;
    k = (k + 1) % 16;
    snprintf(p[k], sizeof p[k], "%s/%s", workdir, name);
    return p[k];
}

static void stop_server(void)
{
    if (server > 0) {
        tu_end(server, SIGTERM, "fracnav-sim after SIGTERM");
        server = 0;
    }
    tu_unmount(mnt);
}

static int setup(void **st)
{
    if (access("/dev/fuse", R_OK | W_OK) || geteuid() != 0)
        return 0; /* each test skips, saying why */
    workdir = tu_tmpdir("simserve");
    snprintf(mnt, sizeof mnt, "%s/mnt", workdir);
    return mkdir(mnt, 0755);
}

static int teardown(void **st)
{
    if (!workdir)
        return 0;
    tu_end_all();
    server = 0;
    tu_unmount(mnt);
    tu_rmtree(workdir);
    free(workdir);
    workdir = NULL;
    return 0;
}

static void need_fuse(void)
{
    if (!workdir) {
        print_message("skipped: needs root and a usable /dev/fuse (CI has both)\n");
        skip();
    }
}

static const char *write_script(const char *name, const char *text)
{
    const char *p = path_in(name);
    tu_write_file(p, text, strlen(text));
    return p;
}

/* The input reports of r: how many, and the span of their timestamps. */
static size_t inputs(const fnrec *r, int64_t *span)
{
    size_t n = 0;
    int64_t first = -1, last = 0;
    for (size_t i = 0; i < r->n; i++)
        if (r->ev[i].dir == FNREC_IN) {
            first = first < 0 ? r->ev[i].t_us : first;
            last = r->ev[i].t_us;
            n++;
        }
    *span = n ? last - first : 0;
    return n;
}

/* Records the node in the background, without --seconds unless given; returns its exit status. */
static int record_node(const char *rec, const char *seconds)
{
    char dev[600];
    snprintf(dev, sizeof dev, "%s/hidraw0", mnt);
    char *args[] = {"record", "-o", (char *)rec, "--device", dev, seconds ? "--seconds" : NULL, (char *)seconds, NULL};
    return tu_end(tu_spawn_cli(path_in("record.log"), NULL, args), 0, "fracnav record");
}

/* A server that exits at the end of its script ends the recording: no wait for a replug. */
static void test_record_ends_when_server_exits(void **st)
{
    need_fuse();
    const char *scr = write_script("s.script", "translate +x 5 mm over 0.3 s\npress 1\nrelease\n");
    const char *rec = path_in("end.fnrec");
    server = tu_serve(mnt, path_in("server.log"), "--script", scr, "--start-on-read", "--exit-at-end", NULL);
    assert_int_equal(record_node(rec, NULL), 0);
    assert_int_equal(tu_end(server, 0, "fracnav-sim --exit-at-end"), 0);
    server = 0;
    tu_unmount(mnt);
    char *log = tu_slurp(path_in("record.log"), NULL);
    assert_non_null(strstr(log, "device disconnected"));
    assert_non_null(strstr(log, "recording stopped"));
    free(log);
    fnrec *want = tu_render_script(scr, "spacenavigator"), *got = fnrec_load(rec);
    assert_non_null(got);
    int64_t span;
    assert_int_equal(inputs(got, &span), inputs(want, &span));
    assert_int_equal(got->ev[got->n - 1].dir, FNREC_DISCONNECT);
    fnrec_free(want);
    fnrec_free(got);
}

/* fracnav-sim --fast sends as fast as the reports are read; the recording still keeps the
 * device's 8 ms cadence, so it replays as the motion it was, not compressed to nothing. */
static void test_record_from_fast_keeps_cadence(void **st)
{
    need_fuse();
    const char *scr = write_script("f.script", "translate +x 10 mm over 0.5 s\nrotate z 10 deg over 0.3 s\n");
    const char *rec = path_in("fast.fnrec");
    server = tu_serve(mnt, path_in("server.log"), "--script", scr, "--fast", "--exit-at-end", NULL);
    assert_int_equal(record_node(rec, "20"), 0); /* ends with the server, well before 20 s */
    assert_int_equal(tu_end(server, 0, "fracnav-sim --fast --exit-at-end"), 0);
    server = 0;
    tu_unmount(mnt);
    fnrec *want = tu_render_script(scr, "spacenavigator"), *got = fnrec_load(rec);
    assert_non_null(got);
    int64_t want_span, got_span;
    size_t n = inputs(got, &got_span);
    assert_int_equal(n, inputs(want, &want_span));
    if (got_span < want_span * 9 / 10)
        fail_msg("%zu reports span %lld us; the device's cadence gives %lld us", n, (long long)got_span,
                 (long long)want_span);
    fnrec_free(want);
    fnrec_free(got);
}

static int json_battery(const char *node)
{
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "devices --json --device '%s' 2>/dev/null", node), 0);
    json_error_t err;
    json_t *root = json_loads(out, 0, &err);
    if (!root)
        fail_msg("not JSON (%s): %s", err.text, out);
    free(out);
    json_t *devs = json_object_get(root, "devices");
    json_t *b = json_object_get(json_array_get(devs, json_array_size(devs) - 1), "battery_pct");
    int v = json_is_integer(b) ? (int)json_integer_value(b) : -1;
    json_decref(root);
    return v;
}

/* A wireless model served by fracnav-sim: every program that opens the node learns the battery
 * level, as with the in-process virtual device, not only the first one after a replug. */
static void test_wireless_battery_for_every_open(void **st)
{
    need_fuse();
    char node[600], *out = NULL;
    snprintf(node, sizeof node, "%s/hidraw0", mnt);
    server = tu_serve(mnt, path_in("server.log"), "--as", "spacemouse-wireless", NULL);
    assert_int_equal(json_battery(node), 100);
    assert_int_equal(json_battery(node), 100);
    assert_int_equal(tu_run_cli(&out, "device-test --device '%s' --seconds 0.3", node), 0);
    if (!strstr(out, "battery 100%"))
        fail_msg("device-test shows no battery: %s", out);
    free(out);
    assert_int_equal(tu_run_cli(&out, "devices --device 'virtual:spacemouse-wireless'"), 0);
    assert_non_null(strstr(out, "battery 100%")); /* as the in-process device */
    free(out);
    stop_server();
}

/* A second server on a folder already served is refused, and the first one serves on. */
static void test_second_serve_on_same_folder_refused(void **st)
{
    need_fuse();
    server = tu_serve(mnt, path_in("server.log"), "--as", "spacepilot", NULL);
    char *argv[] = {(char *)tu_sim(), "serve", "--mount", mnt, "--as", "spacenavigator", NULL};
    assert_int_equal(tu_end(tu_spawn(argv, path_in("second.log"), NULL), 0, "a second fracnav-sim on the folder"), 1);
    char *log = tu_slurp(path_in("second.log"), NULL);
    if (!strstr(log, "already a mount point") || !strstr(log, "another fracnav-sim"))
        fail_msg("second serve said: %s", log);
    free(log);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "devices --device '%s/hidraw0'", mnt), 0);
    assert_non_null(strstr(out, "SpacePilot")); /* still the first server's device */
    free(out);
    stop_server();
}

/* Mounts at mnt in this process' mountinfo (a second mount stacks over the first). */
static int mounts_at_mnt(void)
{
    char want[PATH_MAX], line[2 * PATH_MAX], point[PATH_MAX];
    if (!realpath(workdir, want))
        return -1;
    strncat(want, "/mnt", sizeof want - strlen(want) - 1);
    FILE *f = fopen("/proc/self/mountinfo", "r");
    int n = 0;
    while (f && fgets(line, sizeof line, f))
        n += sscanf(line, "%*s %*s %*s %*s %4095s", point) == 1 && !strcmp(point, want);
    if (f)
        fclose(f);
    return n;
}

/* Servers a and b started at once: one has exited (its status kept), or both mounted. */
typedef struct race {
    pid_t pid[2];
    int status[2], exited;
} race;

static int one_exited_or_both_mounted(void *arg)
{
    race *r = arg;
    for (int i = 0; i < 2 && r->exited < 0; i++)
        if (waitpid(r->pid[i], &r->status[i], WNOHANG) == r->pid[i])
            r->exited = i;
    return r->exited >= 0 || mounts_at_mnt() >= 2;
}

static int node_served(void *arg)
{
    struct stat st;
    char node[600];
    snprintf(node, sizeof node, "%s/hidraw0", mnt);
    return stat(node, &st) == 0;
}

/* The server r->pid[0] serves its node, or has exited (its status kept). */
static int served_or_exited(void *arg)
{
    race *r = arg;
    if (waitpid(r->pid[0], &r->status[0], WNOHANG) == r->pid[0])
        r->exited = 0;
    return r->exited >= 0 || node_served(NULL);
}

/* Two servers started at once on one folder: the check and the mount are one step, so one mounts
 * and the other is refused (both mounted in 1 of 5 tries before). */
static void test_two_serves_at_once_one_mounts(void **st)
{
    need_fuse();
    for (int round = 0; round < 10; round++) {
        char *argv[] = {(char *)tu_sim(), "serve", "--mount", mnt, "--as", "spacepilot", NULL};
        race r = {.exited = -1};
        r.pid[0] = tu_spawn(argv, path_in("a.log"), NULL);
        r.pid[1] = tu_spawn(argv, path_in("b.log"), NULL);
        assert_true(tu_wait_for(one_exited_or_both_mounted, &r, TU_WAIT_MAX_S));
        int mounted = mounts_at_mnt();
        if (r.exited < 0 || mounted > 1) {
            kill(r.pid[0], SIGKILL);
            kill(r.pid[1], SIGKILL);
            waitpid(r.pid[0], NULL, 0);
            waitpid(r.pid[1], NULL, 0);
            tu_unmount(mnt);
            fail_msg("round %d: both servers mounted (%d mounts at %s)", round, mounted, mnt);
        }
        assert_true(WIFEXITED(r.status[r.exited]) && WEXITSTATUS(r.status[r.exited]) == 1);
        server = r.pid[1 - r.exited];
        assert_true(tu_wait_for(node_served, NULL, TU_WAIT_MAX_S));
        assert_int_equal(mounts_at_mnt(), 1);
        stop_server();
    }
}

/* A killed server leaves a dead mount (its root answers ENOTCONN): the next server removes it and
 * serves, where before every later serve was refused until fusermount3 -u. */
static void test_dead_mount_removed(void **st)
{
    need_fuse();
    server = tu_serve(mnt, path_in("server.log"), "--as", "spacepilot", NULL);
    tu_end(server, SIGKILL, "fracnav-sim after SIGKILL");
    server = 0;
    struct stat sb;
    assert_true(stat(mnt, &sb) != 0 && errno == ENOTCONN);
    char *argv[] = {(char *)tu_sim(), "serve", "--mount", mnt, "--as", "spacenavigator", NULL};
    race r = {.pid = {tu_spawn(argv, path_in("again.log"), NULL)}, .exited = -1};
    assert_true(tu_wait_for(served_or_exited, &r, TU_WAIT_MAX_S));
    char *log = tu_slurp(path_in("again.log"), NULL);
    if (r.exited >= 0 || !strstr(log, "removed a dead mount"))
        fail_msg("the next server: %s", log ? log : "");
    free(log);
    server = r.pid[0];
    assert_int_equal(mounts_at_mnt(), 1);
    stop_server();
}

/* A node this user may not open (a FUSE mount of root's, as the user nobody): the message says it
 * is a permission problem on that path, not "no controller" and not the udev rule. */
static void test_node_without_permission(void **st)
{
    need_fuse();
    if (access("/usr/bin/setpriv", X_OK)) {
        print_message("skipped: needs setpriv to run as nobody\n");
        skip();
    }
    assert_int_equal(chmod(workdir, 0755), 0);
    server = tu_serve(mnt, path_in("server.log"), NULL);
    char cmd[2000], text[4096];
    snprintf(cmd, sizeof cmd, "setpriv --reuid=nobody --regid=nogroup --clear-groups env HOME=/nonexistent "
                              "'%s' device-test --device '%s/hidraw0' --seconds 0.3 2>&1", tu_fracnav(), mnt);
    FILE *p = popen(cmd, "r");
    size_t n = fread(text, 1, sizeof text - 1, p);
    text[n] = '\0';
    int rc = WEXITSTATUS(pclose(p));
    if (rc == 126 || rc == 127) {
        print_message("skipped: the user nobody cannot run this build's fracnav here: %s\n", text);
        stop_server();
        skip();
    }
    assert_int_equal(rc, 1);
    if (!strstr(text, "permission problem on this path") || strstr(text, "udev/70-fracnav.rules"))
        fail_msg("device-test as nobody said: %s", text);
    snprintf(cmd, sizeof cmd, "setpriv --reuid=nobody --regid=nogroup --clear-groups env HOME=/nonexistent "
                              "FRACNAV_HIDRAW_PATH='%s' '%s' devices 2>&1", mnt, tu_fracnav());
    p = popen(cmd, "r");
    n = fread(text, 1, sizeof text - 1, p);
    text[n] = '\0';
    assert_int_equal(WEXITSTATUS(pclose(p)), 0);
    if (strstr(text, "no 6-DOF controller connected") || !strstr(text, "permission problem on this path"))
        fail_msg("devices as nobody said: %s", text);
    stop_server();
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_record_ends_when_server_exits, setup, teardown),
        cmocka_unit_test_setup_teardown(test_record_from_fast_keeps_cadence, setup, teardown),
        cmocka_unit_test_setup_teardown(test_wireless_battery_for_every_open, setup, teardown),
        cmocka_unit_test_setup_teardown(test_second_serve_on_same_folder_refused, setup, teardown),
        cmocka_unit_test_setup_teardown(test_two_serves_at_once_one_mounts, setup, teardown),
        cmocka_unit_test_setup_teardown(test_dead_mount_removed, setup, teardown),
        cmocka_unit_test_setup_teardown(test_node_without_permission, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
