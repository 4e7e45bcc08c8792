/* The transport seam: registry, spec strings, queue draining, unplug and replug, LED, through a
 * fake transport defined here (the way the sim's virtual and replay transports plug in). */
#define _GNU_SOURCE /* dl_iterate_phdr */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <link.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "dev.h"
#include "devparse.h"
#include "err.h"
#include "testutil.h"

/* The fake device: a queue of reports, a "plugged" switch, the last output report. */
static struct {
    uint8_t q[128][16];
    size_t qlen[128], head, tail;
    int plugged, opens;
    uint8_t out[8];
    size_t out_len;
    char serial[16];
    char path[16]; /* where the device is now ("" = anywhere) */
    uint16_t vid, pid;
    uint8_t info20[8]; /* feature report 0x20 the device answers (open controller) */
    int info20_len;
    int played_out; /* a recording's end: reads say unplugged, finished says so */
} fake;

struct dev_handle {
    int id;
};

static void push(const uint8_t *r, size_t n)
{
    memcpy(fake.q[fake.tail % 128], r, n);
    fake.qlen[fake.tail++ % 128] = n;
}

static int f_open(const char *path, dev_handle **out)
{
    if (!fake.plugged || (path && fake.path[0] && strcmp(path, "any") && strcmp(path, fake.path)))
        return fn_err_set(FN_ENODEV, "fake: %s not plugged", path ? path : "(first)");
    *out = calloc(1, sizeof **out);
    fake.opens++;
    return 0;
}

static int f_read(dev_handle *h, uint8_t *buf, size_t cap, int timeout_ms, int64_t *t_us)
{
    if (!fake.plugged)
        return FN_ENODEV;
    if (fake.head == fake.tail)
        return 0;
    size_t n = fake.qlen[fake.head % 128];
    memcpy(buf, fake.q[fake.head++ % 128], n);
    *t_us = (int64_t)fake.head * 8000;
    return (int)n;
}

static int f_write(dev_handle *h, const uint8_t *buf, size_t len)
{
    memcpy(fake.out, buf, len);
    fake.out_len = len;
    return (int)len;
}

static int f_info(dev_handle *h, dev_info *out)
{
    memset(out, 0, sizeof *out);
    strcpy(out->path, fake.path[0] ? fake.path : "fake0");
    out->vid = fake.vid, out->pid = fake.pid;
    strcpy(out->serial, fake.serial);
    return 0;
}

static int f_enum(dev_info *out, size_t cap)
{
    if (!fake.plugged || cap == 0)
        return 0;
    dev_handle h;
    f_info(&h, out);
    return 1;
}

static int f_get_feature(dev_handle *h, uint8_t *buf, size_t cap)
{
    if (buf[0] != 0x20 || !fake.info20_len)
        return fn_err_set(FN_EIO, "fake: feature report %u: broken pipe", buf[0]);
    memcpy(buf, fake.info20, (size_t)fake.info20_len);
    return fake.info20_len;
}

static void f_close(dev_handle *h)
{
    free(h);
}

static int f_finished(const dev_handle *h)
{
    return fake.played_out;
}

static const dev_transport fake_transport = {
    .name = "fake", .open = f_open, .read = f_read, .write = f_write, .info = f_info, .close = f_close,
    .get_feature = f_get_feature, .finished = f_finished,
    .enumerate = f_enum, .hotplug_subsystem = "fake"};

static void reset_fake(void)
{
    memset(&fake, 0, sizeof fake);
    fake.plugged = 1;
    strcpy(fake.serial, "SN1");
    fake.vid = 0x046d, fake.pid = 0xc626; /* a SpaceNavigator: split format, LED */
}

/* Pulls the fake device's cable: the next poll reports the unplug. */
static void pull_cable(dev_device *d, dev_event *ev)
{
    fake.plugged = 0;
    assert_int_equal(dev_poll(d, ev, 0), 1);
    assert_true(ev->flags & DEV_EV_UNPLUG);
}

/* Polls for up to 2 s (the device is looked for every DEV_REPLUG_MS); 1 once it is back. */
static int replugged(dev_device *d, dev_event *ev)
{
    for (int i = 0; i < 20; i++)
        if (dev_poll(d, ev, 100) == 1 && (ev->flags & DEV_EV_REPLUG))
            return 1;
    return 0;
}

static void test_registry(void **s)
{
    assert_non_null(dev_transport_find("hidraw") ? dev_transport_find("hidraw") : dev_transport_find("libusb"));
    assert_non_null(dev_transport_find("spnav"));
    assert_non_null(dev_transport_find("keyboard"));
    if (!dev_transport_find("fake"))
        assert_int_equal(dev_transport_register(&fake_transport), 0);
    assert_ptr_equal(dev_transport_find("fake"), &fake_transport);
    assert_int_equal(dev_transport_register(&fake_transport), FN_EINVAL); /* duplicate name */
    dev_transport nameless = {0};
    assert_int_equal(dev_transport_register(&nameless), FN_EINVAL);
    size_t n = 0;
    while (dev_transport_at(n))
        n++;
    assert_true(n >= 4);
    assert_null(dev_open("nosuch:thing"));
    assert_non_null(strstr(fn_err_msg(), "unknown transport 'nosuch'"));
}

static size_t hook_reports, hook_bytes;

static void count_raw(void *ctx, const uint8_t *report, size_t len, int64_t t_us)
{
    hook_reports++;
    hook_bytes += len;
    assert_ptr_equal(ctx, &hook_reports);
}

/* A burst of queued motion is drained in one poll; only the newest state counts. */
static void test_drain_newest_state(void **s)
{
    reset_fake();
    dev_device *d = dev_open("fake:any");
    assert_non_null(d);
    assert_string_equal(dev_row(d)->name, "3Dconnexion SpaceNavigator");
    uint8_t r[16];
    for (int i = 1; i <= 60; i++) {
        int t[3] = {i, 0, 0}, rot[3] = {0, 0, -i};
        push(r, devparse_make_split(r, 1, t));
        push(r, devparse_make_split(r, 2, rot));
    }
    const uint8_t junk[] = {0x42, 1, 2};
    push(junk, sizeof junk);
    dev_set_raw_hook(d, count_raw, &hook_reports);
    dev_event ev;
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    assert_int_equal(hook_reports, 121); /* every raw report, the skipped one too */
    assert_int_equal(hook_bytes, 120 * 7 + 3);
    assert_true(fabsf(ev.axis[0] - 60 / 350.0f) < 1e-6f);
    assert_true(fabsf(ev.axis[5] + 60 / 350.0f) < 1e-6f);
    assert_int_equal(fake.head, fake.tail); /* nothing stale left behind */
    assert_int_equal(dev_skipped(d), 1);
    assert_int_equal(dev_poll(d, &ev, 0), 0);
    dev_close(d);
}

static void test_unplug_replug(void **s)
{
    reset_fake();
    dev_device *d = dev_open("fake:any");
    assert_non_null(d);
    uint8_t r[16];
    int t[3] = {100, 0, 0};
    push(r, devparse_make_split(r, 1, t));
    push(r, devparse_make_buttons(r, 1));
    dev_event ev;
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    assert_int_equal(ev.buttons, 1);
    fake.plugged = 0; /* cable pulled */
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    assert_true(ev.flags & DEV_EV_UNPLUG);
    assert_int_equal(ev.released, 1); /* held buttons are released */
    for (int i = 0; i < 6; i++)
        assert_true(ev.axis[i] == 0.0f); /* and motion stops: the loop keeps the last pose */
    assert_false(dev_connected(d));
    assert_int_equal(dev_poll(d, &ev, 0), 0); /* quiet while gone */
    fake.plugged = 1;
    int replugged = 0;
    for (int i = 0; i < 20 && !replugged; i++) /* looked for every DEV_REPLUG_MS */
        replugged = dev_poll(d, &ev, 100) == 1 && (ev.flags & DEV_EV_REPLUG);
    assert_true(replugged);
    assert_true(dev_connected(d));
    push(r, devparse_make_split(r, 1, t));
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    assert_true(ev.axis[0] > 0.28f);
    dev_close(d);
}

/* A recording travels dev_poll too, unfolded: one event per report at its own time, the
 * recorded unplug (the handle kept) and replug (then the report that came with it), the end. */
static void test_recorded_one_event_per_report(void **s)
{
    reset_fake();
    dev_device *d = dev_open("fake:any");
    assert_non_null(d);
    dev_set_mode(d, DEV_RECORDED);
    uint8_t r[16];
    for (int i = 1; i <= 3; i++)
        push(r, devparse_make_split(r, 1, (int[3]){35 * i, 0, 0}));
    dev_event ev;
    for (int i = 1; i <= 3; i++) {
        assert_int_equal(dev_poll(d, &ev, 0), 1);
        assert_true(fabsf(ev.axis[0] - 0.1f * (float)i) < 1e-6f);
        assert_true(ev.t_us == 8000 * i);
    }
    fake.plugged = 0;
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    assert_int_equal(ev.flags, DEV_EV_UNPLUG);
    assert_int_equal(dev_poll(d, &ev, 0), 0); /* still away: said once */
    assert_int_equal(dev_unplugs(d), 1);
    fake.plugged = 1;
    push(r, devparse_make_split(r, 1, (int[3]){0, 70, 0}));
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    assert_int_equal(ev.flags, DEV_EV_REPLUG);
    assert_true(ev.t_us == 32000);
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    assert_true(fabsf(ev.axis[1] - 0.2f) < 1e-6f);
    assert_int_equal(fake.opens, 1); /* the recording's handle was kept */
    fake.plugged = 0;
    fake.played_out = 1;
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    assert_int_equal(ev.flags, DEV_EV_END);
    assert_int_equal(dev_unplugs(d), 1);
    dev_close(d);
}

static void test_led_and_serial(void **s)
{
    reset_fake();
    strcpy(fake.serial, "ABC123");
    dev_device *d = dev_open("serial:ABC123");
    assert_non_null(d);
    assert_string_equal(dev_transport_name(d), "fake");
    assert_string_equal(dev_device_info(d)->serial, "ABC123");
    assert_int_equal(dev_set_led(d, 1), 0);
    assert_int_equal(fake.out_len, 2);
    assert_int_equal(fake.out[0], 4);
    assert_int_equal(fake.out[1], 1);
    dev_set_led(d, 0);
    assert_int_equal(fake.out[1], 0);
    assert_int_equal(dev_battery(d), -1);
    dev_close(d);
    assert_null(dev_open("serial:NOPE"));
    assert_non_null(strstr(fn_err_msg(), "NOPE"));
}

static int find_hidapi(struct dl_phdr_info *info, size_t size, void *ctx)
{
    const char *want = ctx;
    return strstr(info->dlpi_name, want) != NULL;
}

/* The build option picks the library really linked: the transport's name and the loaded hidapi
 * agree, and the other backend's name explains the option. */
static void test_hidapi_backend_linked(void **s)
{
    int libusb = dev_transport_find("libusb") != NULL;
    assert_int_equal(libusb, dev_transport_find("hidraw") == NULL);
    assert_int_equal(dl_iterate_phdr(find_hidapi, libusb ? "libhidapi-libusb" : "libhidapi-hidraw"), 1);
    assert_int_equal(dl_iterate_phdr(find_hidapi, libusb ? "libhidapi-hidraw" : "libhidapi-libusb"), 0);
    assert_null(dev_open(libusb ? "hidraw" : "libusb"));
    assert_non_null(strstr(fn_err_msg(), libusb ? "-DFRACNAV_HIDAPI_LIBUSB=OFF" : "-DFRACNAV_HIDAPI_LIBUSB=ON"));
}

/* The hidraw transport opens by path: a missing node and a node that is not a hidraw device give
 * errors that name the path. */
static void test_hidraw_path_errors(void **s)
{
    assert_null(dev_open("/nonexistent/hidraw9"));
    assert_non_null(strstr(fn_err_msg(), "/nonexistent/hidraw9"));
    char *dir = tu_tmpdir("seam");
    char path[4200];
    snprintf(path, sizeof path, "%s/hidraw0", dir);
    tu_write_file(path, "x", 1);
    assert_null(dev_open(path));
    assert_non_null(strstr(fn_err_msg(), path));
    /* Relative spellings reach the same check (hidapi 0.13.1 crashes on a plain file otherwise). */
    char cwd[4200], sub[4300];
    assert_non_null(getcwd(cwd, sizeof cwd));
    snprintf(sub, sizeof sub, "%s/vdev", dir);
    assert_int_equal(mkdir(sub, 0700), 0);
    snprintf(sub, sizeof sub, "%s/vdev/hidraw1", dir);
    tu_write_file(sub, "x", 1);
    assert_int_equal(chdir(dir), 0);
    static const char *const specs[][2] = {
        {"./hidraw0", "./hidraw0"}, {"hidraw:hidraw0", "hidraw0"}, {"hidraw0", "hidraw0"},
        {"vdev/hidraw1", "vdev/hidraw1"}, {"vdev/nothing", "vdev/nothing"}};
    for (size_t i = 0; i < sizeof specs / sizeof specs[0]; i++) {
        char spec[64];
        snprintf(spec, sizeof spec, "%s", specs[i][0]);
        if (!strncmp(spec, "hidraw:", 7) && !dev_transport_find("hidraw"))
            memcpy(spec, "libusb", 6); /* the libusb build's transport of the same seam */
        assert_null(dev_open(spec));
        if (!strstr(fn_err_msg(), specs[i][1]) || strstr(fn_err_msg(), "unknown transport"))
            fail_msg("%s: %s", spec, fn_err_msg());
    }
    assert_int_equal(chdir(cwd), 0);
    tu_rmtree(dir);
    free(dir);
}

/* A node the user may not open names the udev rule to install (as an unprivileged user: root
 * opens anything). */
static void test_unopenable_node_names_udev_rule(void **s)
{
    if (!dev_transport_find("hidraw")) {
        print_message("skipped: no hidraw transport in this (libusb) build; "
                      "test_libusb_open_failure_names_udev_rule covers it\n");
        skip();
    }
    char *dir = tu_tmpdir("perm"), path[4200];
    assert_int_equal(chmod(dir, 0755), 0);
    snprintf(path, sizeof path, "%s/hidraw5", dir);
    tu_write_file(path, "x", 1);
    assert_int_equal(chmod(path, 0), 0);
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        if (getuid() == 0 && (setgid(65534) || setuid(65534)))
            _exit(3);
        /* outside /dev no udev rule can help: the message says it is this path's permission */
        int ok = !dev_open(path) && strstr(fn_err_msg(), "permission problem on this path") &&
                 !strstr(fn_err_msg(), "udev/70-fracnav.rules") && strstr(fn_err_msg(), path);
        if (!ok)
            fprintf(stderr, "message: %s\n", fn_err_msg());
        _exit(ok ? 0 : 1);
    }
    int st = 0;
    assert_int_equal(waitpid(pid, &st, 0), pid);
    assert_true(WIFEXITED(st));
    assert_int_equal(WEXITSTATUS(st), 0);
    tu_rmtree(dir);
    free(dir);
}

/* The libusb build: a device hidapi cannot open gets the same udev hint. */
static void test_libusb_open_failure_names_udev_rule(void **s)
{
    if (!dev_transport_find("libusb")) {
        print_message("skipped: no libusb transport in this (hidraw) build; "
                      "test_unopenable_node_names_udev_rule covers it\n");
        skip();
    }
    assert_null(dev_open("libusb:9-9:1.0"));
    assert_non_null(strstr(fn_err_msg(), "udev/70-fracnav.rules"));
    assert_non_null(strstr(fn_err_msg(), "9-9:1.0"));
}

/* The keyboard fallback, fed from a file: keys become motion, then it returns to rest. */
static void test_keyboard_keys(void **s)
{
    char *dir = tu_tmpdir("kbd");
    char path[4200], spec[4300];
    snprintf(path, sizeof path, "%s/keys", dir);
    tu_write_file(path, "dl3", 3);
    snprintf(spec, sizeof spec, "keyboard:%s", path);
    dev_device *d = dev_open(spec);
    assert_non_null(d);
    dev_event ev;
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    assert_true(ev.axis[0] > 0.5f && ev.axis[5] > 0.5f);
    assert_int_equal(ev.buttons, 1u << 2);
    int rest = 0;
    for (int i = 0; i < 50 && !rest; i++)
        if (dev_poll(d, &ev, 50) == 1)
            rest = ev.axis[0] == 0.0f && ev.buttons == 0;
    assert_true(rest);
    dev_close(d);
    tu_rmtree(dir);
    free(dir);
}

/* Terminal mouse (SGR reports) and arrow keys through the same fallback. */
static void test_keyboard_mouse(void **s)
{
    char *dir = tu_tmpdir("mouse");
    char path[4200], spec[4300];
    snprintf(path, sizeof path, "%s/events", dir);
    /* left press at (10,10), drag to (12,9): rz +2 cells, rx +1 cell; then right-arrow; wheel */
    const char ev1[] = "\033[<0;10;10M\033[<32;12;9M\033[C\033[<65;12;9M\033[<0;12;9m";
    tu_write_file(path, ev1, sizeof ev1 - 1);
    snprintf(spec, sizeof spec, "keyboard:%s", path);
    dev_device *d = dev_open(spec);
    assert_non_null(d);
    dev_event ev;
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    const float want[6] = {250, 0, 250, 70, 0, 140};
    for (int i = 0; i < 6; i++)
        if (fabsf(ev.axis[i] - want[i] / 350.0f) > 1e-6f)
            fail_msg("axis %d: %g, want %g", i, ev.axis[i] * 350.0f, want[i]);
    dev_close(d);
    tu_rmtree(dir);
    free(dir);
}

/* Replugged under another name (a new hidraw number): found again by vid:pid:serial. */
static void test_replug_elsewhere(void **s)
{
    reset_fake();
    strcpy(fake.path, "fake0");
    dev_device *d = dev_open("fake:fake0");
    assert_non_null(d);
    dev_event ev;
    pull_cable(d, &ev);
    strcpy(fake.path, "fake7");
    fake.plugged = 1;
    assert_true(replugged(d, &ev));
    assert_true(dev_connected(d));
    dev_close(d);
}

/* Another controller plugged in at the old path is not adopted: it is reported once, and the
 * original is still picked up when it returns. */
static void test_replug_other_device_refused(void **s)
{
    reset_fake();
    strcpy(fake.path, "fake0");
    dev_device *d = dev_open("fake:fake0");
    assert_non_null(d);
    dev_event ev;
    pull_cable(d, &ev);
    strcpy(fake.serial, "SN2");
    fake.plugged = 1;
    int refused = 0, replug = 0;
    for (int i = 0; i < 15; i++)
        if (dev_poll(d, &ev, 100) == 1) {
            refused += !!(ev.flags & DEV_EV_REFUSED);
            replug |= !!(ev.flags & DEV_EV_REPLUG);
        }
    assert_int_equal(refused, 1); /* reported once, not on every retry */
    assert_false(replug);
    assert_false(dev_connected(d));
    assert_non_null(strstr(fn_err_msg(), "SN2"));
    assert_non_null(strstr(fn_err_msg(), "SN1"));
    strcpy(fake.serial, "SN1");
    for (int i = 0; i < 20 && !replug; i++)
        replug = dev_poll(d, &ev, 100) == 1 && (ev.flags & DEV_EV_REPLUG);
    assert_true(replug);
    assert_true(dev_connected(d));
    dev_close(d);
}

/* The open controller's protocol (feature 0x20) is checked when it is opened: version 1 opens,
 * another version or no answer is refused with a message naming the device and what it said. */
static void test_open_controller_protocol(void **s)
{
    reset_fake();
    fake.vid = DEVTAB_OPEN_VID, fake.pid = DEVTAB_OPEN_PID;
    const uint8_t v1[7] = {0x20, 1, 1, 0, 8, 0x5E, 0x01};
    memcpy(fake.info20, v1, 7);
    fake.info20_len = 7;
    dev_device *d = dev_open("fake");
    assert_non_null(d);
    dev_close(d);
    fake.info20[1] = 2;
    assert_null(dev_open("fake"));
    assert_non_null(strstr(fn_err_msg(), "fake0 (fracnav open 6-DOF controller)"));
    assert_non_null(strstr(fn_err_msg(), "protocol 2"));
    fake.info20_len = 0;
    assert_null(dev_open("fake"));
    assert_non_null(strstr(fn_err_msg(), "feature report 0x20"));
    reset_fake(); /* a 3Dconnexion device is never asked */
    d = dev_open("fake");
    assert_non_null(d);
    dev_close(d);
}

/* A stand-in for udev: one byte in a pipe is one "add" event. */
static struct {
    int pipe[2], opens, closes;
    char subsystem[16];
} hp;

struct hotplug_monitor {
    int fd;
};

static hotplug_monitor *hp_open(const char *subsystem)
{
    static hotplug_monitor m;
    snprintf(hp.subsystem, sizeof hp.subsystem, "%s", subsystem);
    hp.opens++;
    m.fd = hp.pipe[0];
    return &m;
}

static int hp_fd(hotplug_monitor *m)
{
    return m->fd;
}

static int hp_added(hotplug_monitor *m)
{
    char c[16];
    return read(m->fd, c, sizeof c) > 0;
}

static void hp_close(hotplug_monitor *m)
{
    hp.closes++;
}

static hotplug_monitor *hp_open_fails(const char *subsystem)
{
    hp.opens++;
    return NULL;
}

static const hotplug_ops fake_hotplug = {hp_open, hp_fd, hp_added, hp_close};
static const hotplug_ops failing_hotplug = {hp_open_fails, hp_fd, hp_added, hp_close};

/* An "add" event brings the device back at once, without waiting for the next scheduled look;
 * an add seen while the device was still there does not count. */
static void test_hotplug_add_wakes_reopen(void **s)
{
    reset_fake();
    memset(&hp, 0, sizeof hp);
    assert_int_equal(pipe2(hp.pipe, O_NONBLOCK), 0);
    dev_set_hotplug(&fake_hotplug);
    dev_device *d = dev_open("fake");
    assert_non_null(d);
    assert_string_equal(hp.subsystem, "fake");
    assert_int_equal(write(hp.pipe[1], "a", 1), 1); /* another device, while ours is there */
    dev_event ev;
    pull_cable(d, &ev);
    fake.plugged = 1;
    assert_int_equal(dev_poll(d, &ev, 0), 0); /* no announcement yet: next look is DEV_REPLUG_MS away */
    assert_int_equal(write(hp.pipe[1], "a", 1), 1);
    assert_int_equal(dev_poll(d, &ev, 0), 1);
    assert_true(ev.flags & DEV_EV_REPLUG);
    dev_close(d);
    assert_int_equal(hp.closes, 1);
    close(hp.pipe[0]);
    close(hp.pipe[1]);
    dev_set_hotplug(&hotplug_udev);
}

/* A monitor that cannot start (no udev, a container without netlink) is no error: polling finds
 * the device. */
static void test_hotplug_unavailable_falls_back(void **s)
{
    reset_fake();
    memset(&hp, 0, sizeof hp);
    dev_set_hotplug(&failing_hotplug);
    dev_device *d = dev_open("fake");
    assert_non_null(d);
    assert_int_equal(hp.opens, 1);
    dev_event ev;
    pull_cable(d, &ev);
    fake.plugged = 1;
    assert_true(replugged(d, &ev));
    dev_close(d);
    assert_int_equal(hp.closes, 0);
    dev_set_hotplug(&hotplug_udev);
}

/* The real libudev monitor starts or declines cleanly, and never blocks when nothing happened. */
static void test_hotplug_udev_monitor(void **s)
{
    hotplug_monitor *m = hotplug_udev.open("hidraw");
    if (!m) {
        print_message("skipped: no udev monitor here (no libudev or no netlink): dev_poll polls\n");
        skip();
    }
    assert_true(hotplug_udev.fd(m) >= 0);
    hotplug_udev.added(m);
    assert_int_equal(hotplug_udev.added(m), 0);
    hotplug_udev.close(m);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_registry),       cmocka_unit_test(test_drain_newest_state),
        cmocka_unit_test(test_unplug_replug),  cmocka_unit_test(test_led_and_serial),
        cmocka_unit_test(test_recorded_one_event_per_report),
        cmocka_unit_test(test_hidraw_path_errors), cmocka_unit_test(test_keyboard_keys),
        cmocka_unit_test(test_keyboard_mouse),     cmocka_unit_test(test_replug_elsewhere),
        cmocka_unit_test(test_replug_other_device_refused),
        cmocka_unit_test(test_hidapi_backend_linked),
        cmocka_unit_test(test_unopenable_node_names_udev_rule),
        cmocka_unit_test(test_libusb_open_failure_names_udev_rule),
        cmocka_unit_test(test_open_controller_protocol),
        cmocka_unit_test(test_hotplug_add_wakes_reopen),
        cmocka_unit_test(test_hotplug_unavailable_falls_back),
        cmocka_unit_test(test_hotplug_udev_monitor),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
