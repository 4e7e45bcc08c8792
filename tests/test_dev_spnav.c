/* The spnav transport against a fake spacenavd on $SPNAV_SOCKET, protocols v0 and v1: the real
 * libspnav client negotiates, events become reports in the HID frame, the LED request, and the
 * fake_daemon going away is an unplug. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include "dev.h"
#include "err.h"
#include "testutil.h"

#define PROTO_V1_REQUEST 0x7faa5501 /* REQ_TAG | REQ_CHANGE_PROTO | version 1 */
#define REQ_SET_LED 0x7faa3012      /* REQ_TAG | REQ_SCFG_LED */

typedef struct fake_daemon {
    char path[100];
    int listen_fd, v1;
    int led_seen;    /* v1: the LED state the client asked for, -1 none */
    const char *why; /* NULL: the daemon saw what a libspnav client must send; else what went wrong */
    int brief;       /* v1, one motion event, then hang up (an unplug) */
    int hangup[2];   /* the test writes a byte when the daemon may hang up (the unplug it waits for) */
} fake_daemon;

static int read_full(int fd, void *buf, size_t n)
{
    size_t got = 0;
    while (got < n) {
        ssize_t r = read(fd, (char *)buf + got, n - got);
        if (r <= 0)
            return -1;
        got += (size_t)r;
    }
    return 0;
}

static int send_event(int fd, int32_t a, int32_t b, int32_t c, int32_t d, int32_t e, int32_t f, int32_t g,
                      int32_t h)
{
    int32_t ev[8] = {a, b, c, d, e, f, g, h};
    return write(fd, ev, sizeof ev) == (ssize_t)sizeof ev ? 0 : -1;
}

/* The daemon's side of a session; returns NULL when the client behaved, else what it did not do.
 * No cmocka assert here: they belong to the test's thread, which reads dm->why after the join. */
static const char *serve_client(fake_daemon *dm, int c)
{
    int32_t hello = 0;
    if (read_full(c, &hello, 4) || hello != PROTO_V1_REQUEST)
        return "no protocol v1 request from the client";
    if (dm->v1) {
        if (write(c, &hello, 4) != 4) /* the echo selects v1 */
            return "could not answer the protocol request";
    } else {
        float sens = 0; /* an old spacenavd stays silent; libspnav then restores sensitivity 1.0 */
        if (read_full(c, &sens, 4) || sens != 1.0f)
            return "no sensitivity 1.0 from a v0 client";
    }
    if (send_event(c, 0, 100, -50, 25, 10, 20, -30, 8)) /* motion, spacenavd's frame */
        return "could not send the motion event";
    if (dm->brief)
        return NULL;
    if (send_event(c, 1, 3, 1, 0, 0, 0, 0, 0) || send_event(c, 2, 3, 0, 0, 0, 0, 0, 0)) /* button 3 */
        return "could not send the button events";
    if (!dm->v1)
        return NULL;
    int32_t rq[8];
    if (read_full(c, rq, sizeof rq) || rq[0] != REQ_SET_LED)
        return "no LED request from a v1 client";
    dm->led_seen = rq[1];
    rq[6] = 0; /* status ok */
    return write(c, rq, sizeof rq) == (ssize_t)sizeof rq ? NULL : "could not answer the LED request";
}

static void *daemon_main(void *arg)
{
    fake_daemon *dm = arg;
    int c = accept(dm->listen_fd, NULL, NULL);
    dm->why = c < 0 ? "accept failed" : serve_client(dm, c);
    char go;
    if (read(dm->hangup[0], &go, 1) != 1 && !dm->why) /* what the client reads, it reads before this */
        dm->why = "the test did not say when to hang up";
    unlink(dm->path);
    if (c >= 0)
        close(c);
    return NULL;
}

/* Lets the daemon hang up: the client sees an unplug. */
static void hang_up(fake_daemon *dm)
{
    assert_int_equal(write(dm->hangup[1], "x", 1), 1);
}

/* Joins the daemon thread and checks, on the test's thread, what it saw. */
static void stop_daemon(fake_daemon *dm, pthread_t th)
{
    pthread_join(th, NULL);
    close(dm->listen_fd);
    close(dm->hangup[0]);
    close(dm->hangup[1]);
    if (dm->why)
        fail_msg("fake spacenavd: %s", dm->why);
}

static void start_daemon(fake_daemon *dm, const char *dir, int v1, int brief, pthread_t *th)
{
    memset(dm, 0, sizeof *dm);
    dm->v1 = v1;
    dm->brief = brief;
    dm->led_seen = -1;
    assert_int_equal(pipe(dm->hangup), 0);
    snprintf(dm->path, sizeof dm->path, "%s/spnav.sock", dir);
    struct sockaddr_un a = {.sun_family = AF_UNIX};
    snprintf(a.sun_path, sizeof a.sun_path, "%s", dm->path);
    dm->listen_fd = socket(AF_UNIX, SOCK_STREAM, 0);
    assert_true(dm->listen_fd >= 0);
    assert_int_equal(bind(dm->listen_fd, (struct sockaddr *)&a, sizeof a), 0);
    assert_int_equal(listen(dm->listen_fd, 1), 0);
    setenv("SPNAV_SOCKET", dm->path, 1);
    assert_int_equal(pthread_create(th, NULL, daemon_main, dm), 0);
}

static void run_session(int v1)
{
    char *dir = tu_tmpdir("spnav");
    fake_daemon dm;
    pthread_t th;
    start_daemon(&dm, dir, v1, 0, &th);
    dev_device *d = dev_open("spnav");
    assert_non_null(d);
    assert_string_equal(dev_row(d)->name, "spnav");
    assert_non_null(strstr(dev_device_info(d)->name, v1 ? "protocol v1" : "protocol v0"));
    dev_event ev;
    float axis[6] = {0};
    uint32_t pressed = 0, released = 0;
    int motion = 0;
    for (int i = 0; i < 300 && !(pressed && released); i++) /* up to a minute, for a loaded machine */
        if (dev_poll(d, &ev, 200) == 1) {
            if (ev.flags & DEV_EV_MOTION)
                memcpy(axis, ev.axis, sizeof axis), motion = 1;
            pressed |= ev.pressed, released |= ev.released;
        }
    assert_true(motion);
    /* spacenavd (x, y, z, rx, ry, rz) = HID (x, -z, -y, rx, -rz, -ry) */
    const float want[6] = {100, -25, 50, 10, 30, -20};
    for (int i = 0; i < 6; i++)
        if (fabsf(axis[i] - want[i] / 350.0f) > 1e-6f)
            fail_msg("axis %d: %g, want %g", i, axis[i] * 350.0f, want[i]);
    assert_int_equal(pressed, 1u << 3);
    assert_int_equal(released, 1u << 3);
    assert_int_equal(dev_set_led(d, 1), 0);
    hang_up(&dm);
    int gone = 0;
    for (int i = 0; i < 300 && !gone; i++)
        gone = dev_poll(d, &ev, 200) == 1 && (ev.flags & DEV_EV_UNPLUG);
    assert_true(gone);
    dev_close(d);
    stop_daemon(&dm, th);
    assert_int_equal(dm.led_seen, v1 ? 1 : -1);
    tu_rmtree(dir);
    free(dir);
}

static void test_protocol_v1(void **s)
{
    run_session(1);
}

static void test_protocol_v0(void **s)
{
    run_session(0);
}

static void wait_for(dev_device *d, unsigned flag)
{
    dev_event ev;
    int seen = 0;
    for (int i = 0; i < 600 && !seen; i++) /* up to a minute, for a loaded machine */
        seen = dev_poll(d, &ev, 100) == 1 && (ev.flags & flag);
    if (!seen)
        fail_msg("no event with flag %#x", flag);
}

/* spacenavd restarts (socket gone, then back): "spnav" finds it again at the same socket, and the
 * environment is left as it was. */
static void test_replug(void **s)
{
    char *dir = tu_tmpdir("spnavre");
    fake_daemon dm;
    pthread_t th;
    start_daemon(&dm, dir, 1, 1, &th);
    dev_device *d = dev_open("spnav");
    assert_non_null(d);
    assert_string_equal(dev_device_info(d)->path, dm.path);
    wait_for(d, DEV_EV_MOTION);
    hang_up(&dm);
    wait_for(d, DEV_EV_UNPLUG);
    stop_daemon(&dm, th);
    start_daemon(&dm, dir, 1, 1, &th);
    wait_for(d, DEV_EV_REPLUG);
    wait_for(d, DEV_EV_MOTION);
    assert_string_equal(getenv("SPNAV_SOCKET"), dm.path);
    dev_close(d);
    hang_up(&dm);
    stop_daemon(&dm, th);
    tu_rmtree(dir);
    free(dir);
}

/* An explicit socket that is not there: a clear error, and $SPNAV_SOCKET untouched. */
static void test_bad_socket_leaves_env(void **s)
{
    setenv("SPNAV_SOCKET", "/run/elsewhere.sock", 1);
    assert_null(dev_open("spnav:/nonexistent/spnav.sock"));
    assert_non_null(strstr(fn_err_msg(), "/nonexistent/spnav.sock"));
    assert_null(strstr(fn_err_msg(), "spnav: spacenavd")); /* the name once, from the spec */
    assert_string_equal(getenv("SPNAV_SOCKET"), "/run/elsewhere.sock");
}

static void test_no_daemon(void **s)
{
    setenv("SPNAV_SOCKET", "/nonexistent/spnav.sock", 1);
    assert_null(dev_open("spnav"));
    assert_non_null(strstr(fn_err_msg(), "spacenavd is not running"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_protocol_v1),
        cmocka_unit_test(test_protocol_v0),
        cmocka_unit_test(test_no_daemon),
        cmocka_unit_test(test_replug),
        cmocka_unit_test(test_bad_socket_leaves_env),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
