/* dev: 6-DOF controllers behind one seam.
 *
 * A transport moves raw HID reports (report ID first) between fracnav and a device; parsers turn
 * those bytes into normalized events; calibration turns events into motion. Every transport
 * (hidraw, libusb, spnav, keyboard, virtual, replay) fills a dev_transport. Transports that have no
 * raw reports of their own (spnav, keyboard) synthesize reports of a device-table row, so one parser
 * path serves them all.
 *
 * Threads: a dev_device belongs to one thread (the loop's input thread). The transport registry is
 * filled at start-up (before threads start) and read-only afterwards.
 *
 * Events (dev_event.h) follow HID's axis convention. */
#ifndef FN_DEV_H
#define FN_DEV_H

#include <stddef.h>
#include <stdint.h>

#include "dev_event.h"
#include "devtab.h"
#include "hotplug.h"

#define DEV_REPORT_MAX 64
#define DEV_DESC_MAX 4096
#define DEV_TRANSPORTS_MAX 16
#define DEV_REPLUG_MS 500       /* how often a lost device is looked for again */

typedef struct dev_handle dev_handle; /* a transport's open device, opaque */

typedef struct dev_info {
    char path[256];
    uint16_t vid, pid;
    char name[128];
    char serial[64];
    uint8_t desc[DEV_DESC_MAX]; /* HID report descriptor, when the transport can read it */
    size_t desc_len;
} dev_info;

/* What a transport is (dev_transport.caps): callers test these flags, never a transport's name. */
enum {
    DEV_CAP_TERMINAL = 1u << 0,  /* reads the terminal: its user leaves stdin (and raw mode) to it */
    DEV_CAP_RECORDING = 1u << 1  /* plays a recording: reads carry the recorded times, and the
                                  * recording's end is the device's end (dev_transport.finished) */
};

typedef struct dev_transport {
    const char *name; /* "hidraw", "libusb", "spnav", "keyboard", "virtual", "replay" */
    unsigned caps;    /* DEV_CAP_* */
    /* The 1-based button the device sends to ask for help on its keys (the keyboard's ? and h);
     * 0 = none. */
    uint8_t help_button;
    /* The synthetic device-table row (devtab_synthetic) its reports follow, for a transport that
     * makes reports of its own (spnav, keyboard); NULL = the row of the device's vid:pid. */
    const char *synthetic_row;
    /* Opens the device at path (transport-specific; NULL = the first one found). Returns 0 or a
     * negative FN_E* with fn_err_set() naming the path; FN_ENODEV when absent, FN_EIO when present
     * but not openable (permissions). */
    int (*open)(const char *path, dev_handle **out);
    /* Reads one report into buf. Returns its length, 0 on timeout, FN_ENODEV when the device went
     * away, another negative FN_E* on error. *t_us is the arrival time (monotonic microseconds;
     * on replay the recorded time). timeout_ms < 0 blocks, 0 polls. */
    int (*read)(dev_handle *h, uint8_t *buf, size_t cap, int timeout_ms, int64_t *t_us);
    /* Sends an output report (e.g. the LED, report 4). Returns bytes written or negative. */
    int (*write)(dev_handle *h, const uint8_t *buf, size_t len);
    /* Feature report get: buf[0] holds the report ID on entry. Returns length or negative. */
    int (*get_feature)(dev_handle *h, uint8_t *buf, size_t cap);
    int (*info)(dev_handle *h, dev_info *out);
    void (*close)(dev_handle *h);
    /* Optional (NULL = cannot list): fills up to cap supported devices, returns how many were
     * found (may exceed cap) or negative. */
    int (*enumerate)(dev_info *out, size_t cap);
    /* Optional: feature report set (buf[0] = report ID). Returns bytes written or negative. */
    int (*set_feature)(dev_handle *h, const uint8_t *buf, size_t len);
    /* Optional: the udev subsystem whose "add" events may bring a lost device back ("hidraw",
     * "usb"); NULL = the 500 ms poll alone. */
    const char *hotplug_subsystem;
    /* Says in one line what the transport offers here and now (`fracnav devices`), into buf.
     * Optional: dev_transport_describe() says it from the caps when NULL. */
    void (*describe)(char *buf, size_t cap);
    /* Optional: 1 once the handle has played all it had (a recording, a script), else 0. */
    int (*finished)(const dev_handle *h);
    /* Optional: keys typed elsewhere (a window), read as if typed where the device reads (the
     * keyboard's terminal). Any thread. Returns 0 or negative. */
    int (*feed_keys)(dev_handle *h, const char *bytes, size_t n);
} dev_transport;

/* Registry. The built-in transports (hidraw or libusb, spnav, keyboard) are always present;
 * others (the sim's virtual and replay) register themselves by name. The pointer must stay valid
 * for the process' life. Returns 0, FN_EINVAL for a duplicate name, FN_ENOMEM when full. */
int dev_transport_register(const dev_transport *t);
const dev_transport *dev_transport_find(const char *name);
/* The i-th transport (built-in first), NULL past the end. */
const dev_transport *dev_transport_at(size_t i);
/* The transport's one-line state (its describe, else one said from its caps) in buf; returns buf. */
const char *dev_transport_describe(const dev_transport *t, char *buf, size_t cap);

/* An opened controller: transport handle, device-table row, parser state and hotplug state. */
typedef struct dev_device dev_device;

/* Splits a spec that names one transport: a path ("/dev/hidraw3", "./node", "vdev/hidraw0": anything
 * with a '/' before its first ':', or an existing file that is not a transport's name) goes to the
 * hidapi transport; "NAME" or "NAME:ARG" to transport NAME with ARG (NULL when absent or empty).
 * "serial:S" to the transport and path of the connected controller with serial number S (arg then
 * points to a per-thread buffer, valid until the next call). Returns 0, FN_EINVAL naming the spec
 * (unknown transport) or FN_ENODEV (no such serial). "auto" is dev_open's. */
int dev_spec_resolve(const char *spec, const dev_transport **t, const char **arg);

/* Opens a controller by spec:
 *   "auto"           first supported HID device, else spacenavd, else the keyboard on a terminal
 *   "/path", "./p", "dir/p", an existing file
 *                    a hidraw node by path (no udev needed: works on a FUSE-served node)
 *   "NAME" "NAME:ARG" transport NAME (hidraw, libusb, spnav, keyboard, virtual, replay, ...) with
 *                    its argument (a path, a file, ...)
 *   "serial:S"       the enumerated device whose serial number is S
 * The hidapi transport enumerates udev's hidraw nodes and, in the hidraw build, those found through
 * FRACNAV_HIDRAW_PATH (colon-separated folders, their hidraw* nodes, or node paths): a FUSE-served
 * virtual device is then listed, found by "auto" and "serial:S", and picked up again after a replug.
 * Returns NULL with fn_err_msg() naming the spec and the cause; for a device present but not
 * openable the message names the udev rule to install. */
dev_device *dev_open(const char *spec);
void dev_close(dev_device *d);

/* Drains every pending report (waiting up to timeout_ms for the first; <0 blocks), folds them into
 * one event (DEV_LIVE; DEV_RECORDED: the first that changes something) and returns 1 when
 * anything changed, 0 when nothing did, negative on a hard error.
 * Unplug is not an error: it yields DEV_EV_UNPLUG once, then the device is looked for every
 * DEV_REPLUG_MS, and at once when the hotplug monitor announces a new device (same path, or same
 * vid:pid:serial), and DEV_EV_REPLUG when it returns; a device
 * with another vid:pid:serial at the old path is refused (DEV_EV_REFUSED). Allocates
 * nothing after dev_open. */
int dev_poll(dev_device *d, dev_event *ev, int timeout_ms);

/* How dev_poll reads a device. */
typedef enum dev_mode {
    DEV_LIVE = 0,         /* the default: every queued report folded into one event (stale motion
                           * never replays); an unplug closes the handle and the device is looked
                           * for until it returns */
    DEV_RECORDED = 1,     /* a recording: one event per report, at the recorded times; an unplug
                           * is the recording's (the handle stays open and its next report is the
                           * replug); DEV_EV_END once it played out */
    DEV_RECORDED_LOOP = 2 /* DEV_RECORDED, played again from the start (reopened at the reopen path
                           * of dev_open_handle) instead of ending: a replug */
} dev_mode;
/* Sets how dev_poll reads d, before the first dev_poll. */
void dev_set_mode(dev_device *d, dev_mode mode);
/* Unplugs so far (DEV_RECORDED: the recording's), and plays begun after the first
 * (DEV_RECORDED_LOOP; any thread). */
unsigned dev_unplugs(const dev_device *d);
unsigned dev_plays(dev_device *d);

/* Called by dev_poll with every raw report it reads, before parsing (recorders: `fracnav record`).
 * Runs on the polling thread; NULL removes it. */
typedef void (*dev_raw_hook)(void *ctx, const uint8_t *report, size_t len, int64_t t_us);
void dev_set_raw_hook(dev_device *d, dev_raw_hook hook, void *ctx);

/* Zero-offset calibration in the controller itself (the open controller's feature report 0x21,
 * firmware-spec/open-controller.md 5): rest = the mean normalized motion measured with the cap
 * released; the offsets become the controller's current ones plus rest (clamped to +-350). now
 * gets the offsets read back. Returns 0, 1 when the device keeps no offsets (not an open
 * controller), or negative naming the device. */
int dev_zero_offsets(dev_device *d, const float rest[6], int16_t now[6]);

/* LED on/off (output report 4). A device without an LED returns 0 and does nothing. */
int dev_set_led(dev_device *d, int on);
/* Battery 0..100 from the latest report 0x17, -1 unknown. */
int dev_battery(const dev_device *d);
/* 1 while the device is present. */
int dev_connected(const dev_device *d);
const devtab_row *dev_row(const dev_device *d);
const dev_info *dev_device_info(const dev_device *d);
const char *dev_transport_name(const dev_device *d);
/* The transport the device is open on (its caps, help button, ...). */
const dev_transport *dev_transport_of(const dev_device *d);
/* 1 when the device's input has a scripted or recorded end and has played it all (a virtual
 * device's script, a replay); 0 for a live device. */
int dev_finished(const dev_device *d);
/* Keys typed elsewhere (navigate's window) for a device that reads keys (the keyboard): they
 * act as if typed in its terminal, arrows as "\033[A".."\033[D". Any thread, while d is open (a
 * device that reads keys is never unplugged). Returns 0, FN_EINVAL when the device reads no keys,
 * or FN_EIO. */
int dev_feed_keys(dev_device *d, const char *bytes, size_t n);
/* Reports skipped because of an unknown ID or a wrong length. */
uint64_t dev_skipped(const dev_device *d);

/* Opens a device on an already opened transport handle (ownership of h passes to the device; it
 * is closed on failure too). `reopen` is the path used to look for it after an unplug. For
 * transports and tests that build a device themselves. */
dev_device *dev_open_handle(const dev_transport *t, dev_handle *h, const char *reopen);

/* The hotplug monitor used by devices opened from now on (default &hotplug_udev; tests stand in
 * for udev). NULL = none: lost devices are found by polling alone. */
void dev_set_hotplug(const hotplug_ops *ops);

#endif
