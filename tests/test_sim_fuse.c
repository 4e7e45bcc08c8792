/* The virtual device end to end: fracnav-sim serves a hidraw node through FUSE, and fracnav record
 * (real libhidapi-hidraw underneath) reads it. Needs /dev/fuse and root (CI has both). Every server
 * is stopped and every mount undone, also when a test fails. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <linux/hidraw.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "dev.h"
#include "devtab.h"
#include "err.h"
#include "fnrec.h"
#include "simdev.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

static char *workdir;
static char mnt[512];

static int64_t now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

static const char *server_log(void)
{
    static char log[600];
    snprintf(log, sizeof log, "%s/server.log", workdir);
    return log;
}

/* Stops a server as Ctrl-C does: it must exit 0. */
static void stop_server(pid_t pid)
{
    int rc = tu_end(pid, SIGTERM, "fracnav-sim after SIGTERM");
    tu_unmount(mnt);
    assert_int_equal(rc, 0);
}

static int setup(void **st)
{
    if (access("/dev/fuse", R_OK | W_OK)) {
        fprintf(stderr, "no usable /dev/fuse: the FUSE tests need it (CI has it)\n");
        return -1;
    }
    workdir = tu_tmpdir("simfuse");
    snprintf(mnt, sizeof mnt, "%s/mnt", workdir);
    return mkdir(mnt, 0755);
}

static int teardown(void **st)
{
    tu_end_all();
    tu_unmount(mnt);
    tu_rmtree(workdir);
    free(workdir);
    return 0;
}

static char *path_in(const char *name)
{
    static char p[4][700];
    static int k;
    k = (k + 1) % 4;
    snprintf(p[k], sizeof p[k], "%s/%s", workdir, name);
    return p[k];
}

static const char *write_script(const char *name, const char *text)
{
    const char *p = path_in(name);
    tu_write_file(p, text, strlen(text));
    return p;
}

/* The input reports of a recording, in order, as one comparable list. */
static size_t inputs(const fnrec *r, fnrec_event *out, size_t cap)
{
    size_t n = 0;
    for (size_t i = 0; i < r->n && n < cap; i++)
        if (r->ev[i].dir == FNREC_IN) {
            out[n] = r->ev[i];
            out[n++].t_us = 0;
        }
    return n;
}

static void assert_same_reports(const fnrec *want, const fnrec *got, const char *what)
{
    static fnrec_event a[4096], b[4096];
    size_t na = inputs(want, a, 4096), nb = inputs(got, b, 4096);
    if (na != nb)
        fail_msg("%s: %zu reports expected, %zu recorded", what, na, nb);
    for (size_t i = 0; i < na; i++)
        if (a[i].len != b[i].len || memcmp(a[i].data, b[i].data, a[i].len))
            fail_msg("%s: report %zu differs", what, i);
}

/* What a recording being written holds so far (fracnav record flushes every line). */
typedef struct rec_state {
    int connects, disconnects, ins, ins_since_connect;
} rec_state;

static rec_state rec_read(const char *path)
{
    rec_state st = {0};
    char *text = tu_slurp(path, NULL), *line = text ? strstr(text, "\nevents\n") : NULL;
    for (line = line ? line + 8 : NULL; line && *line; line++) {
        char *end = strchr(line, '\n'), *dir = end ? memchr(line, ' ', (size_t)(end - line)) : NULL;
        if (!end)
            break; /* a line still being written */
        line = end;
        if (!dir)
            continue;
        if (!strncmp(dir, " in ", 4))
            st.ins++, st.ins_since_connect++;
        else if (!strncmp(dir, " connect\n", 9))
            st.connects++, st.ins_since_connect = 0;
        else if (!strncmp(dir, " disconnect\n", 12))
            st.disconnects++;
    }
    free(text);
    return st;
}

/* A recording to wait for: at least these many of each, read from path. */
typedef struct rec_wait {
    const char *path;
    rec_state at_least;
} rec_wait;

static int rec_reached(void *arg)
{
    const rec_wait *w = arg;
    rec_state st = rec_read(w->path);
    return st.connects >= w->at_least.connects && st.disconnects >= w->at_least.disconnects &&
           st.ins >= w->at_least.ins && st.ins_since_connect >= w->at_least.ins_since_connect;
}

/* Waits until the recording at path holds at least what `want` says; fails the test if it never
 * does (the bound is for a broken product, not a time the test relies on). */
static void await_recording(const char *path, rec_state want)
{
    rec_wait w = {path, want};
    if (!tu_wait_for(rec_reached, &w, TU_WAIT_MAX_S)) {
        rec_state st = rec_read(path);
        fail_msg("%s: %d connects, %d disconnects, %d reports (%d since the last connect), want at "
                 "least %d, %d, %d (%d)", path, st.connects, st.disconnects, st.ins, st.ins_since_connect,
                 want.connects, want.disconnects, want.ins, want.ins_since_connect);
    }
}

/* fracnav record -o rec --device DEV in the background, its output into log. It records until
 * finish_recording stops it (the --seconds given is only a bound for a test that failed), through
 * unplugs too (--wait-replug). */
static pid_t record_in_background(const char *rec, const char *dev, const char *log)
{
    return tu_spawn_cli(log, NULL, (char *[]){"record", "-o", (char *)rec, "--device", (char *)dev, "--seconds",
                                              "600", "--wait-replug", NULL});
}

static const char *node_path(void)
{
    static char node[600];
    snprintf(node, sizeof node, "%s/hidraw0", mnt);
    return node;
}

/* Stops the background recorder as Ctrl-C does, stops the server (0: none left), and loads what
 * the recorder wrote; the recorder must have exited 0. */
static fnrec *finish_recording(pid_t recp, pid_t srv, const char *rec)
{
    int rc = tu_end(recp, SIGINT, "fracnav record after SIGINT");
    if (srv)
        stop_server(srv);
    if (rc != 0)
        fail_msg("fracnav record ended with status %d", rc);
    fnrec *r = fnrec_load(rec);
    assert_non_null(r);
    return r;
}

/* Serves a script as DEVICE, records it with fracnav record until every report the script renders
 * to is in, and checks that the recording holds exactly those, in order, with the device's
 * identity. (The cadence in time is fracnav-sim bench's to measure, not a test's.) */
static void serve_and_record(const char *device, const char *text)
{
    const char *scr = write_script("motion.script", text);
    const char *served = path_in("served.fnrec"), *rec = path_in("rec.fnrec"), *out = path_in("record.log");
    unlink(rec); /* the last device's, when called in turn */
    pid_t srv = tu_serve(mnt, server_log(), "--as", device, "--script", scr, "--start-on-read", "--log", served, NULL);
    fnrec *want = tu_render_script(scr, device);
    static fnrec_event scratch[4096];
    pid_t recp = record_in_background(rec, node_path(), out);
    await_recording(rec, (rec_state){.connects = 1, .ins = (int)inputs(want, scratch, 4096)});
    fnrec *got = finish_recording(recp, srv, rec), *log = fnrec_load(served);
    if (!log)
        fail_msg("%s", fn_err_msg());
    assert_same_reports(want, got, device);
    assert_same_reports(log, got, device);
    const sim_profile *p = sim_profile_find(device);
    assert_int_equal(got->hdr.vid, p->vid);
    assert_int_equal(got->hdr.pid, p->pid);
    assert_string_equal(got->hdr.name, p->name);
    assert_int_equal(got->hdr.desc_len, want->hdr.desc_len);
    assert_memory_equal(got->hdr.desc, want->hdr.desc, want->hdr.desc_len);
    assert_string_equal(got->hdr.format, want->hdr.format);
    for (size_t i = 1; i < got->n; i++) /* arrival times in order */
        assert_true(got->ev[i].t_us >= got->ev[i - 1].t_us);
    fnrec_free(got);
    fnrec_free(log);
    fnrec_free(want);
}

static void test_end_to_end_spacenavigator(void **st)
{
    serve_and_record("spacenavigator", "translate +x 10 mm over 0.3 s\npress 1\nwait 30 ms\nrelease\n"
                                       "rotate z -15 deg over 0.4 s\n");
}

/* Every hardware row of the device table, served as --as VID:PID, through the same path. */
static void test_every_device_format(void **st)
{
    size_t nrows;
    const devtab_row *rows = devtab_rows(&nrows);
    for (size_t i = 0; i < nrows; i++) {
        if (rows[i].flags & DEVTAB_F_SYNTH)
            continue;
        char vidpid[16];
        snprintf(vidpid, sizeof vidpid, "%04x:%04x", rows[i].vid, rows[i].pid);
        serve_and_record(vidpid, "press 2\nmove y -4 mm rx 3 deg over 0.1 s\nrelease\nwait 20 ms\n");
    }
    serve_and_record("spacemouse-enterprise", "press 2\nmove y -4 mm over 0.1 s\nrelease\n");
}

static size_t count_dir(const fnrec *r, fnrec_dir d, size_t from)
{
    size_t n = 0;
    for (size_t i = from; i < r->n; i++)
        n += r->ev[i].dir == d;
    return n;
}

/* Killing the server mid-stream: the recorder says "device disconnected", does not crash, and
 * picks the device up again when a new server serves it. Each step waits for the recording to
 * show the one before; the script outlasts any machine's load. */
static void test_server_killed_then_back(void **st)
{
    const char *scr = write_script("long.script", "translate +y 400 mm over 900 s\n");
    const char *rec = path_in("rec.fnrec"), *log = path_in("record.log");
    pid_t srv = tu_serve(mnt, server_log(), "--script", scr, "--start-on-read", NULL);
    pid_t recp = record_in_background(rec, node_path(), log);
    await_recording(rec, (rec_state){.connects = 1, .ins = 11});
    tu_end(srv, SIGKILL, "fracnav-sim");
    tu_unmount(mnt);
    await_recording(rec, (rec_state){.disconnects = 1});
    srv = tu_serve(mnt, server_log(), "--script", scr, "--start-on-read", NULL);
    await_recording(rec, (rec_state){.connects = 2, .ins_since_connect = 11});
    fnrec *r = finish_recording(recp, srv, rec);
    char *out = tu_slurp(log, NULL);
    assert_non_null(out);
    if (!strstr(out, "device disconnected") || !strstr(out, "device reconnected"))
        fail_msg("recorder output: %s", out);
    free(out);
    size_t cut = 0;
    while (cut < r->n && r->ev[cut].dir != FNREC_DISCONNECT)
        cut++;
    assert_true(cut < r->n);
    assert_true(count_dir(r, FNREC_IN, 0) - count_dir(r, FNREC_IN, cut) > 10); /* before the kill */
    assert_int_equal(count_dir(r, FNREC_CONNECT, cut), 1);
    assert_true(count_dir(r, FNREC_IN, cut) > 10);                        /* after the return */
    fnrec_free(r);
}

/* SIGUSR1 unplugs the device (readers get the disconnect), the next SIGUSR1 plugs it back. */
static void test_unplug_replug_on_signal(void **st)
{
    const char *scr = write_script("long.script", "translate +z 300 mm over 900 s\n");
    const char *rec = path_in("rec.fnrec"), *log = path_in("record.log");
    pid_t srv = tu_serve(mnt, server_log(), "--script", scr, "--start-on-read", NULL);
    pid_t recp = record_in_background(rec, node_path(), log);
    await_recording(rec, (rec_state){.connects = 1, .ins = 11});
    kill(srv, SIGUSR1);
    await_recording(rec, (rec_state){.disconnects = 1});
    kill(srv, SIGUSR1);
    await_recording(rec, (rec_state){.connects = 2, .ins_since_connect = 11});
    fnrec *r = finish_recording(recp, srv, rec);
    assert_int_equal(count_dir(r, FNREC_DISCONNECT, 0), 1);
    assert_int_equal(count_dir(r, FNREC_CONNECT, 0), 2);
    size_t cut = 0;
    while (r->ev[cut].dir != FNREC_DISCONNECT)
        cut++;
    assert_true(count_dir(r, FNREC_IN, cut) > 10);
    fnrec_free(r);
}

/* A wireless device replugged by SIGUSR1 or by a control line sends its battery report 0x17 again
 * after enumeration (firmware-spec 7), as a scripted replug does. */
static void test_live_replug_sends_battery(void **st)
{
    const char *scr = write_script("long.script", "translate +z 300 mm over 900 s\n");
    const char *fifo = path_in("control"), *rec = path_in("rec.fnrec"), *log = path_in("record.log");
    pid_t srv = tu_serve(mnt, server_log(), "--as", "spacemouse-wireless", "--script", scr, "--start-on-read",
                             "--control", fifo, NULL);
    pid_t recp = record_in_background(rec, node_path(), log);
    await_recording(rec, (rec_state){.connects = 1, .ins = 3});
    kill(srv, SIGUSR1);
    await_recording(rec, (rec_state){.disconnects = 1});
    kill(srv, SIGUSR1);
    await_recording(rec, (rec_state){.connects = 2, .ins_since_connect = 3});
    FILE *f = fopen(fifo, "w");
    assert_non_null(f);
    fputs("unplug\n", f);
    fflush(f);
    await_recording(rec, (rec_state){.disconnects = 2});
    fputs("replug\n", f);
    fclose(f);
    await_recording(rec, (rec_state){.connects = 3, .ins_since_connect = 3});
    fnrec *r = finish_recording(recp, srv, rec);
    assert_int_equal(count_dir(r, FNREC_CONNECT, 0), 3);
    /* After every connect, the first report is the battery's. */
    for (size_t i = 0; i < r->n; i++) {
        if (r->ev[i].dir != FNREC_CONNECT)
            continue;
        size_t k = i + 1;
        while (k < r->n && r->ev[k].dir != FNREC_IN)
            k++;
        if (k == r->n || r->ev[k].data[0] != 0x17 || r->ev[k].data[1] != 100)
            fail_msg("connect at event %zu: no battery report first (see %s)", i, rec);
    }
    fnrec_free(r);
}

/* A string ioctl on the node, as hidraw answers it. */
static const char *raw_string(const char *node, unsigned long req)
{
    static char s[64];
    memset(s, 0, sizeof s);
    int fd = open(node, O_RDONLY | O_NONBLOCK);
    assert_true(fd >= 0);
    if (ioctl(fd, req, s) < 0)
        fail_msg("ioctl on %s: %s", node, strerror(errno));
    close(fd);
    return s;
}

/* Without --serial the node serves a stable default of the spec's length (8-32 characters), and
 * HIDIOCGRAWNAME is what usbhid makes of the device's strings. */
static void test_serial_and_name(void **st)
{
    char node[600];
    snprintf(node, sizeof node, "%s/hidraw0", mnt);
    pid_t srv = tu_serve(mnt, server_log(), "--as", "1209:0001", NULL);
    const char *sn = raw_string(node, HIDIOCGRAWUNIQ(64));
    assert_string_equal(sn, "FNSIM12090001");
    assert_string_equal(raw_string(node, HIDIOCGRAWNAME(64)), "fracnav fracnav open 6-DOF controller");
    stop_server(srv);
    srv = tu_serve(mnt, server_log(), "--as", "spacepilot", NULL);
    assert_string_equal(raw_string(node, HIDIOCGRAWNAME(64)), "3Dconnexion SpacePilot");
    stop_server(srv);
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "'%s' serve --mount '%s' --serial 'a b' 2>&1", tu_sim(), mnt);
    FILE *p = popen(cmd, "r");
    char line[256] = "";
    if (!fgets(line, sizeof line, p))
        line[0] = '\0';
    assert_int_equal(WEXITSTATUS(pclose(p)), 2);
    assert_non_null(strstr(line, "--serial 'a b'"));
}

/* Through the real hidapi: identity, read timeouts, LED output and feature reports. */
static void test_hidapi_led_feature_timeout(void **st)
{
    const char *served = path_in("served.fnrec");
    pid_t srv = tu_serve(mnt, server_log(), "--as", "open-controller", "--start-on-read", "--log", served, "--serial",
                             "OC-12345678", NULL);
    const dev_transport *t = dev_transport_find("hidraw");
    assert_non_null(t);
    char node[600];
    snprintf(node, sizeof node, "%s/hidraw0", mnt);
    dev_handle *h;
    if (t->open(node, &h))
        fail_msg("%s", fn_err_msg());
    dev_info info;
    assert_int_equal(t->info(h, &info), 0);
    assert_int_equal(info.vid, 0x1209);
    assert_int_equal(info.pid, 0x0001);
    /* usbhid's name: manufacturer + " " + product of the spec's string descriptors. */
    assert_string_equal(info.name, "fracnav fracnav open 6-DOF controller");
    assert_string_equal(raw_string(node, HIDIOCGRAWUNIQ(64)), "OC-12345678");
    uint8_t want[DEV_DESC_MAX];
    size_t wn = sim_profile_descriptor(sim_profile_find("open-controller"), want, sizeof want);
    assert_int_equal(info.desc_len, wn);
    assert_memory_equal(info.desc, want, wn);
    uint8_t buf[64];
    int64_t tr;
    assert_int_equal(t->read(h, buf, sizeof buf, 60000, &tr), 2); /* battery after connecting */
    assert_int_equal(buf[0], 0x17);
    int64_t t0 = now_us();
    assert_int_equal(t->read(h, buf, sizeof buf, 60, &tr), 0); /* idle: silence, then timeout */
    assert_true(now_us() - t0 >= 50000);
    assert_int_equal(t->write(h, (const uint8_t[]){4, 1}, 2), 2);
    uint8_t f[16] = {0x20};
    assert_int_equal(t->get_feature(h, f, sizeof f), 7);
    assert_memory_equal(f, ((const uint8_t[]){0x20, 1, 1, 0, 8, 0x5E, 0x01}), 7);
    uint8_t off[13] = {0x21, 5, 0, 0xfb, 0xff};
    assert_int_equal(t->set_feature(h, off, sizeof off), 13);
    memset(f, 0, sizeof f);
    f[0] = 0x21;
    assert_int_equal(t->get_feature(h, f, sizeof f), 13);
    assert_memory_equal(f, off, 13);
    uint8_t bad[13] = {0x21, 0xff, 0x7f}; /* 32767: out of range, refused */
    assert_true(t->set_feature(h, bad, sizeof bad) < 0);
    t->close(h);
    stop_server(srv);
    char *log = tu_slurp(served, NULL);
    assert_non_null(strstr(log, " out 0401\n"));
    assert_non_null(strstr(log, " feature 2105"));          /* a set */
    assert_non_null(strstr(log, " feature 20010100085e01\n")); /* a get, as the device answered */
    free(log);
}

/* The x of the next motion report (ID 1) on the node; fails when none comes. */
static int16_t next_motion_x(const dev_transport *t, dev_handle *h)
{
    uint8_t buf[64];
    int64_t tr;
    for (;;) {
        int n = t->read(h, buf, sizeof buf, 60000, &tr);
        if (n <= 0)
            fail_msg("no report from the node: %d", n);
        if (buf[0] == 1)
            return (int16_t)(buf[1] | buf[2] << 8);
    }
}

/* The open controller's settings, set through hidapi before the script starts, shape what is served:
 * 0x22 cadence 20 ms and one zero report, 0x21 an offset of +10 on x. A control line played after
 * 0x22 is set back to 8 ms follows that too. */
static void test_open_controller_settings_applied(void **st)
{
    const char *scr = write_script("x.script", "translate +x 4 mm over 0.3 s\n");
    const char *fifo = path_in("control");
    pid_t srv = tu_serve(mnt, server_log(), "--as", "open-controller", "--script", scr, "--start-on-read", "--control",
                             fifo, NULL);
    const dev_transport *t = dev_transport_find("hidraw");
    char node[600];
    snprintf(node, sizeof node, "%s/hidraw0", mnt);
    dev_handle *h;
    if (t->open(node, &h))
        fail_msg("%s", fn_err_msg());
    assert_int_equal(t->set_feature(h, (const uint8_t[]){0x22, 20, 1, 0}, 4), 4);
    uint8_t off[13] = {0x21, 10, 0};
    assert_int_equal(t->set_feature(h, off, sizeof off), 13);
    /* The move, then its one zero report at rest: 13 periods of 20 ms inside the 0.3 s (the first
     * one the battery's), not the 36 of the default 8 ms. Counted in the device's periods, so the
     * machine's load does not change them. */
    int motion = 0, zeros = 0;
    while (!zeros) {
        int16_t x = next_motion_x(t, h);
        if (x == 0) {
            zeros++;
            continue;
        }
        /* 4 mm / 0.3 s = 13.3 mm/s = 93.3 counts, less the offset */
        if (x < 83 || x > 84)
            fail_msg("motion report x = %d, want 83..84 (93.3 counts - offset 10)", x);
        motion++;
    }
    assert_int_equal(motion, 300 / 20 - 1 - 1);
    assert_int_equal(t->set_feature(h, (const uint8_t[]){0x22, 8, 2, 0}, 4), 4);
    FILE *f = fopen(fifo, "w");
    assert_non_null(f);
    fputs("translate -y 2 mm over 0.16 s\n", f);
    fclose(f);
    uint8_t buf[64];
    int64_t tr;
    motion = zeros = 0;
    while (zeros < 2) { /* the move, then two zero reports at rest */
        int n = t->read(h, buf, sizeof buf, 60000, &tr);
        assert_true(n > 0);
        if (buf[0] != 1)
            continue;
        int16_t y = (int16_t)(buf[3] | buf[4] << 8), x = (int16_t)(buf[1] | buf[2] << 8);
        zeros += y == 0;
        motion += y != 0;
        assert_true(y == 0 ? x == 0 : x == -10); /* the offset, while deflected */
    }
    assert_int_equal(motion, 160 / 8 - 1);
    t->close(h);
    stop_server(srv);
}

/* A recording played through FUSE (--play) is recorded back unchanged; --fast plays it as fast as
 * the reader takes it, --exit-at-end stops the server once all of it was read. */
static void test_play_recording(void **st)
{
    const char *scr = write_script("s.script", "translate -x 5 mm over 0.2 s\npress 1\nrelease\n");
    fnrec *want = tu_render_script(scr, "spacemouse-wireless");
    const char *file = path_in("play.fnrec"), *rec = path_in("rec.fnrec");
    assert_int_equal(fnrec_save(want, file), 0);
    pid_t srv = tu_serve(mnt, server_log(), "--play", file, "--fast", "--exit-at-end", NULL);
    pid_t recp = record_in_background(rec, node_path(), path_in("record.log"));
    int rc = tu_end(srv, 0, "fracnav-sim --exit-at-end"); /* it leaves by itself once everything was read */
    tu_unmount(mnt);
    assert_int_equal(rc, 0);
    await_recording(rec, (rec_state){.disconnects = 1}); /* the recorder saw it go */
    fnrec *got = finish_recording(recp, 0, rec);
    assert_same_reports(want, got, "--play --fast");
    assert_int_equal(got->hdr.pid, 0xc62e);
    fnrec_free(got);
    fnrec_free(want);
}

/* FRACNAV_HIDRAW_PATH puts the FUSE-served node (which udev does not know) into enumeration: fracnav
 * devices lists it with its serial number and --device serial:SN opens it. The motion is played
 * through the control FIFO once the recorder is connected: `devices` reads the node too. */
static void test_serial_selects_fuse_node(void **st)
{
    const char *rec = path_in("sn.fnrec"), *fifo = path_in("control");
    pid_t srv = tu_serve(mnt, server_log(), "--as", "spacemouse-wireless", "--serial", "FNTESTSN01", "--control", fifo, NULL);
    char *out = NULL, env[1300];
    assert_int_equal(tu_run_cli(&out, "devices"), 0);
    assert_null(strstr(out, node_path())); /* not udev's: not listed without the variable */
    free(out);
    snprintf(env, sizeof env, "%s/nowhere:%s", workdir, mnt); /* a missing entry is skipped */
    setenv("FRACNAV_HIDRAW_PATH", env, 1);
    assert_int_equal(tu_run_cli(&out, "devices --json"), 0);
    assert_non_null(strstr(out, node_path()));
    assert_non_null(strstr(out, "\"serial\": \"FNTESTSN01\""));
    free(out);
    assert_int_equal(tu_run_cli(&out, "record -o '%s' --device serial:FNTESTSN02 --seconds 0.3", rec), 1);
    assert_non_null(strstr(out, "no connected controller has serial number 'FNTESTSN02'"));
    free(out);
    pid_t recp = record_in_background(rec, "serial:FNTESTSN01", path_in("record.log"));
    unsetenv("FRACNAV_HIDRAW_PATH");
    await_recording(rec, (rec_state){.connects = 1});
    FILE *f = fopen(fifo, "w");
    assert_non_null(f);
    fputs("translate -x 5 mm over 0.2 s\n", f);
    fclose(f);
    await_recording(rec, (rec_state){.ins = 6});
    fnrec *got = finish_recording(recp, srv, rec);
    assert_int_equal(got->hdr.pid, 0xc62e);
    assert_true(got->n > 5);
    fnrec_free(got);
}

/* Script lines written to the control FIFO play in turn on the live device; buttons carry over. */
static void test_control_fifo(void **st)
{
    const char *fifo = path_in("control"), *rec = path_in("rec.fnrec"), *log = path_in("record.log");
    pid_t srv = tu_serve(mnt, server_log(), "--as", "spacenavigator", "--control", fifo, NULL);
    pid_t recp = record_in_background(rec, node_path(), log);
    await_recording(rec, (rec_state){.connects = 1});
    FILE *f = fopen(fifo, "w");
    assert_non_null(f);
    fputs("press 2\ntranslate -z 4 mm over 0.2 s\nnonsense\nrelease\n", f);
    fclose(f);
    if (!tu_wait_for_text(rec, " in 030000\n", TU_WAIT_MAX_S)) /* the release */
        fail_msg("no release recorded in %s", rec);
    fnrec *r = finish_recording(recp, srv, rec);
    /* press 2, motion along -z (ID1 with z = -140 counts, ID2), the zeros, then the release. */
    int stage = 0;
    size_t motion = 0;
    for (size_t i = 0; i < r->n; i++) {
        const fnrec_event *e = &r->ev[i];
        if (e->dir != FNREC_IN)
            continue;
        if (stage == 0 && e->data[0] == 3 && e->data[1] == 2)
            stage = 1;
        else if (stage == 1 && e->data[0] == 1 && (int16_t)(e->data[5] | e->data[6] << 8) == -140)
            motion++;
        else if (stage == 1 && motion && e->data[0] == 3 && e->data[1] == 0)
            stage = 2;
    }
    assert_int_equal(stage, 2);
    assert_true(motion >= 10);
    fnrec_free(r);
}

/* Options that do not apply to a command are usage errors naming them; --as with --play is a
 * warning (the recording's identity is served); a missing mount point is named as missing. */
static void test_sim_cli_option_checks(void **st)
{
    char *out;
    assert_int_equal(tu_run_sim(&out, "serve --mount '%s' -o x.fnrec", mnt), 2);
    assert_non_null(strstr(out, "option '-o' does not apply to serve"));
    free(out);
    assert_int_equal(tu_run_sim(&out, "serve --mount '%s' --seconds 3", mnt), 2);
    assert_non_null(strstr(out, "option '--seconds' does not apply to serve"));
    free(out);
    assert_int_equal(tu_run_sim(&out, "render --script x --log y -o z"), 2);
    assert_non_null(strstr(out, "option '--log' does not apply to render"));
    free(out);
    assert_int_equal(tu_run_sim(&out, "bench --fast"), 2);
    assert_non_null(strstr(out, "option '--fast' does not apply to bench"));
    free(out);
    fnrec *r = tu_render_script(write_script("s.script", "press 1\n"), "spacemouse-wireless");
    const char *file = path_in("w.fnrec");
    assert_int_equal(fnrec_save(r, file), 0);
    fnrec_free(r);
    assert_int_equal(tu_run_sim(&out, "serve --mount '%s/nowhere' --as spacenavigator --play '%s'", mnt,
                             file), 1);
    assert_non_null(strstr(out, "warning: --as spacenavigator ignored"));
    assert_non_null(strstr(out, "256f:c62e"));
    assert_non_null(strstr(out, "nowhere does not exist"));
    free(out);
    assert_int_equal(tu_run_sim(&out, "serve --mount '%s'", file), 1);
    assert_non_null(strstr(out, "is not a directory"));
    free(out);
}

/* Without root or FUSE permission, serve says what it needs and exits 1 (as the user nobody). */
static void test_serve_unprivileged(void **st)
{
    struct stat fs;
    if (geteuid() != 0 || access("/usr/bin/setpriv", X_OK) || stat("/dev/fuse", &fs)) {
        print_message("skipped: needs root and setpriv to run as nobody\n");
        skip();
    }
    if (fs.st_mode & S_IROTH && fs.st_mode & S_IWOTH) {
        print_message("skipped: /dev/fuse is open to every user here, so nobody may serve\n");
        skip();
    }
    assert_int_equal(chmod(workdir, 0755), 0);
    assert_int_equal(chmod(mnt, 0777), 0);
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "setpriv --reuid=nobody --regid=nogroup --clear-groups '%s' serve "
                              "--mount '%s' 2>&1", tu_sim(), mnt);
    FILE *p = popen(cmd, "r");
    char text[1024] = "";
    size_t n = fread(text, 1, sizeof text - 1, p);
    text[n] = '\0';
    assert_int_equal(WEXITSTATUS(pclose(p)), 1);
    if (!strstr(text, "/dev/fuse") || !strstr(text, "run as root"))
        fail_msg("unprivileged serve said: %s", text);
}

static void test_cli_usage_and_errors(void **st)
{
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "record --help"), 0);
    assert_non_null(strstr(out, "usage: fracnav record"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "record"), 2);
    assert_non_null(strstr(out, "fracnav record: -o"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "record -o '%s' --device /nonexistent/hidraw9 --seconds 1",
                                path_in("x.fnrec")), 1);
    assert_non_null(strstr(out, "fracnav record: "));
    assert_non_null(strstr(out, "/nonexistent/hidraw9"));
    free(out);
    char cmd[2048];
    snprintf(cmd, sizeof cmd, "'%s' serve 2>&1", tu_sim());
    FILE *p = popen(cmd, "r");
    char line[256] = "";
    if (!fgets(line, sizeof line, p))
        line[0] = '\0';
    assert_int_equal(WEXITSTATUS(pclose(p)), 2);
    assert_non_null(strstr(line, "--mount DIR is required"));
}

/* Whether the server's log at path holds the LED going on, then off. */
static int led_on_then_off(void *path)
{
    char *text = tu_slurp(path, NULL), *on = text ? strstr(text, " out 0401\n") : NULL;
    int off = on && strstr(on, " out 0400\n");
    free(text);
    return off;
}

/* Navigation through the real driver path: the LED goes on while the fragment is held (the cap
 * deflected, a movable fragment selected) and off again after, as output reports on the node. */
static void test_navigate_lights_led_while_held(void **st)
{
    vol *v = vol_new(32, 24, 24);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = -1000;
    for (int k = 4; k < 20; k++)
        for (int j = 4; j < 20; j++)
            for (int i = 3; i < 28; i++)
                if (i < 12 || i > 15)
                    v->data[vol_idx(v, i, j, k)] = 1000; /* two blocks 4 mm apart */
    const char *ct = path_in("blocks.nii.gz");
    assert_int_equal(volio_write(v, ct, VOL_I16), 0);
    vol_free(v);
    char casedir[700];
    snprintf(casedir, sizeof casedir, "%s", path_in("ledcase"));
    assert_int_equal(tu_run_cli(NULL, "segment '%s' -o '%s' --min-volume 0 --ramp 0", ct, casedir), 0);
    assert_int_equal(tu_run_cli(NULL, "edit '%s' fix 1", casedir), 0);
    const char *script = write_script("led.script", "wait 200 ms\ntranslate +z 1 mm over 0.3 s\nwait 400 ms\n");
    const char *log = path_in("led.fnrec"), *nav_log = path_in("navigate.log");
    pid_t pid = tu_serve(mnt, server_log(), "--script", script, "--start-on-read", "--log", log, NULL);
    pid_t nav = tu_spawn_cli(nav_log, NULL, (char *[]){"navigate", casedir, "--device", (char *)node_path(), NULL});
    int seen = tu_wait_for(led_on_then_off, (void *)log, TU_WAIT_MAX_S);
    int rc = tu_end(nav, SIGTERM, "navigate after SIGTERM"); /* Ctrl-C: saves and exits 0 */
    char *out = tu_slurp(nav_log, NULL);
    if (!seen || rc != 0)
        fail_msg("navigate (status %d, LED off %s): %s", rc, seen ? "seen" : "never seen", out);
    free(out);
    stop_server(pid);
    fnrec *r = fnrec_load(log);
    assert_non_null(r);
    int on_at = -1, off_at = -1;
    for (size_t i = 0; i < r->n; i++) {
        const fnrec_event *e = &r->ev[i];
        if (e->dir != FNREC_OUT || e->len < 2 || e->data[0] != 4)
            continue;
        if (e->data[1] == 1 && on_at < 0)
            on_at = (int)i;
        if (e->data[1] == 0 && on_at >= 0)
            off_at = (int)i;
    }
    fnrec_free(r);
    if (on_at < 0 || off_at < on_at)
        fail_msg("LED reports in %s: on at event %d, off at %d", log, on_at, off_at);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_end_to_end_spacenavigator, setup, teardown),
        cmocka_unit_test_setup_teardown(test_every_device_format, setup, teardown),
        cmocka_unit_test_setup_teardown(test_server_killed_then_back, setup, teardown),
        cmocka_unit_test_setup_teardown(test_unplug_replug_on_signal, setup, teardown),
        cmocka_unit_test_setup_teardown(test_hidapi_led_feature_timeout, setup, teardown),
        cmocka_unit_test_setup_teardown(test_serial_and_name, setup, teardown),
        cmocka_unit_test_setup_teardown(test_live_replug_sends_battery, setup, teardown),
        cmocka_unit_test_setup_teardown(test_open_controller_settings_applied, setup, teardown),
        cmocka_unit_test_setup_teardown(test_play_recording, setup, teardown),
        cmocka_unit_test_setup_teardown(test_control_fifo, setup, teardown),
        cmocka_unit_test_setup_teardown(test_serial_selects_fuse_node, setup, teardown),
        cmocka_unit_test_setup_teardown(test_cli_usage_and_errors, setup, teardown),
        cmocka_unit_test_setup_teardown(test_sim_cli_option_checks, setup, teardown),
        cmocka_unit_test_setup_teardown(test_serve_unprivileged, setup, teardown),
        cmocka_unit_test_setup_teardown(test_navigate_lights_led_while_held, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
