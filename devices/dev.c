#include "dev.h"

#include <math.h>
#include <poll.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "devparse.h"
#include "err.h"
#include "fnclock.h"
#include "hiddesc.h"

/* The built-in transports (dev_hid.c, dev_spnav.c, dev_keyboard.c). */
extern const dev_transport dev__hid_transport, dev__spnav_transport, dev__keyboard_transport;

#define DRAIN_MAX 256 /* reports folded per poll: bounds the work when a source never runs dry */

static const dev_transport *registry[DEV_TRANSPORTS_MAX] = {
    &dev__hid_transport, &dev__spnav_transport, &dev__keyboard_transport};
static size_t n_registered = 3;
static const hotplug_ops *hotplug = &hotplug_udev;

struct dev_device {
    const dev_transport *t;
    dev_handle *h; /* NULL while unplugged */
    dev_info info;
    const devtab_row *row;
    devparse_state ps;
    char reopen[256];
    int64_t next_try_us;
    int refused; /* the last reopen found another device at the path (reported once) */
    const hotplug_ops *hp;
    hotplug_monitor *mon; /* NULL: no monitor, polling alone */
    dev_raw_hook hook;
    void *hook_ctx;
    dev_mode mode;
    unsigned unplugs;
    _Atomic unsigned plays; /* DEV_RECORDED_LOOP: plays begun after the first */
    int rec_unplugged;      /* DEV_RECORDED: the recording's unplug, until its next report */
    int has_pending;        /* the report that came with the replug, given next */
    dev_event pending;
};

int dev_transport_register(const dev_transport *t)
{
    if (!t || !t->name || !t->open || !t->read || !t->close)
        return fn_err_set(FN_EINVAL, "dev_transport_register: transport without a name, open, read or close");
    if (dev_transport_find(t->name))
        return fn_err_set(FN_EINVAL, "dev_transport_register: transport '%s' already registered", t->name);
    if (n_registered == DEV_TRANSPORTS_MAX)
        return fn_err_set(FN_ENOMEM, "dev_transport_register: no room for '%s' (%d transports)", t->name,
                          DEV_TRANSPORTS_MAX);
    registry[n_registered++] = t;
    return 0;
}

const dev_transport *dev_transport_find(const char *name)
{
    for (size_t i = 0; i < n_registered; i++)
        if (!strcmp(registry[i]->name, name))
            return registry[i];
    return NULL;
}

const dev_transport *dev_transport_at(size_t i)
{
    return i < n_registered ? registry[i] : NULL;
}

const char *dev_transport_describe(const dev_transport *t, char *buf, size_t cap)
{
    if (t->describe)
        t->describe(buf, cap);
    else
        snprintf(buf, cap, "%s", t->enumerate ? "enumerates devices" : "opened by name (--device)");
    return buf;
}

/* The open controller says its protocol in feature report 0x20; fracnav speaks protocol 1 only.
 * A transport with no feature reports to give (a recording: FN_EINVAL) is taken as it is. */
static int check_protocol(dev_device *d)
{
    if (!(d->row->flags & DEVTAB_F_OPEN) || !d->t->get_feature)
        return 0;
    const char *where = d->info.path[0] ? d->info.path : d->t->name;
    uint8_t buf[DEV_REPORT_MAX] = {DEVPARSE_FEAT_INFO};
    int n = d->t->get_feature(d->h, buf, sizeof buf);
    if (n == FN_EINVAL)
        return 0;
    if (n < 0)
        return fn_err_wrap(n, "%s (%s): cannot read the protocol version (feature report 0x20)", where,
                           d->row->name);
    devparse_open_info oi;
    if (n >= 2 && buf[0] == DEVPARSE_FEAT_INFO && buf[1] != 1)
        return fn_err_set(FN_EFORMAT, "%s (%s): firmware speaks protocol %u; fracnav speaks protocol 1 "
                          "(firmware-spec/open-controller.md): update the firmware or fracnav", where,
                          d->row->name, buf[1]);
    if (devparse_open_info_parse(buf, (size_t)n, &oi))
        return fn_err_wrap(FN_EFORMAT, "%s (%s)", where, d->row->name);
    return 0;
}

/* The device-table row for what the transport says it is; the descriptor's logical maximum wins. */
static int identify(dev_device *d)
{
    memset(&d->info, 0, sizeof d->info);
    if (d->t->info && d->t->info(d->h, &d->info) < 0)
        memset(&d->info, 0, sizeof d->info);
    d->row = devtab_find(d->info.vid, d->info.pid);
    if (!d->row && d->t->synthetic_row)
        d->row = devtab_synthetic(d->t->synthetic_row);
    hiddesc desc;
    int axis_max = 0;
    if (d->info.desc_len && hiddesc_parse(d->info.desc, d->info.desc_len, &desc) == 0)
        axis_max = hiddesc_axis_max(&desc);
    if (!d->row && axis_max > 0)
        d->row = devtab_synthetic("generic"); /* a new product id that reports like a 6-DOF device */
    if (!d->row)
        return fn_err_set(FN_ENODEV, "%s: %04x:%04x is not a supported 6-DOF controller (no device-table row)",
                          d->info.path[0] ? d->info.path : d->t->name, d->info.vid, d->info.pid);
    devparse_init(&d->ps, d->row, axis_max);
    return check_protocol(d);
}

dev_device *dev_open_handle(const dev_transport *t, dev_handle *h, const char *reopen)
{
    dev_device *d = calloc(1, sizeof *d);
    if (!d) {
        t->close(h);
        fn_err_set(FN_ENOMEM, "dev_open: out of memory");
        return NULL;
    }
    d->t = t;
    d->h = h;
    atomic_init(&d->plays, 0);
    snprintf(d->reopen, sizeof d->reopen, "%s", reopen ? reopen : "");
    if (identify(d)) {
        dev_close(d);
        return NULL;
    }
    if (!d->reopen[0])
        snprintf(d->reopen, sizeof d->reopen, "%s", d->info.path);
    if (hotplug && t->hotplug_subsystem && (d->mon = hotplug->open(t->hotplug_subsystem)))
        d->hp = hotplug;
    return d;
}

void dev_set_hotplug(const hotplug_ops *ops)
{
    hotplug = ops;
}

static dev_device *open_on(const dev_transport *t, const char *arg, const char *spec)
{
    dev_handle *h = NULL;
    int rc = t->open(arg, &h);
    if (rc) {
        fn_err_wrap(rc, "device '%s'", spec);
        return NULL;
    }
    return dev_open_handle(t, h, arg);
}

/* The transport and path of the connected controller with this serial number (path: a buffer of
 * this thread's, valid until the next call). */
static int find_serial(const char *serial, const char *spec, const dev_transport **t, const char **path)
{
    static _Thread_local char found_path[sizeof ((dev_info *)0)->path];
    dev_info found[16];
    if (!*serial)
        return fn_err_set(FN_EINVAL, "device '%s': serial: needs a serial number (fracnav devices lists them)",
                          spec);
    for (size_t i = 0; dev_transport_at(i); i++) {
        int n = dev_transport_at(i)->enumerate ? dev_transport_at(i)->enumerate(found, 16) : 0;
        for (int k = 0; k < n && k < 16; k++)
            if (!strcmp(found[k].serial, serial)) {
                *t = dev_transport_at(i);
                snprintf(found_path, sizeof found_path, "%s", found[k].path);
                *path = found_path;
                return 0;
            }
    }
    return fn_err_set(FN_ENODEV, "device '%s': no connected controller has serial number '%s' (fracnav "
                      "devices lists them; nodes outside /dev need FRACNAV_HIDRAW_PATH)", spec, serial);
}

static dev_device *open_auto(void)
{
    dev_device *d = open_on(&dev__hid_transport, NULL, "auto");
    if (d)
        return d;
    d = open_on(&dev__spnav_transport, NULL, "auto");
    if (d)
        return d;
    if (isatty(STDIN_FILENO))
        return open_on(&dev__keyboard_transport, NULL, "auto");
    fn_err_set(FN_ENODEV, "device 'auto': no 6-DOF controller found (no supported HID device, no "
                          "spacenavd, no terminal for the keyboard fallback)");
    return NULL;
}

static int is_path(const char *spec)
{
    const char *colon = strchr(spec, ':'), *slash = strchr(spec, '/');
    if (slash && (!colon || slash < colon))
        return 1;
    return !colon && !dev_transport_find(spec) && access(spec, F_OK) == 0;
}

int dev_spec_resolve(const char *spec, const dev_transport **t, const char **arg)
{
    *t = &dev__hid_transport;
    *arg = spec;
    if (!spec || is_path(spec))
        return 0;
    if (!strncmp(spec, "serial:", 7))
        return find_serial(spec + 7, spec, t, arg);
    char name[32];
    const char *colon = strchr(spec, ':');
    size_t n = colon ? (size_t)(colon - spec) : strlen(spec);
    if (n >= sizeof name)
        return fn_err_set(FN_EINVAL, "device '%s': unknown transport (a path, auto, serial:S, or a transport name)",
                          spec);
    memcpy(name, spec, n);
    name[n] = '\0';
    if (!(*t = dev_transport_find(name)) && (!strcmp(name, "libusb") || !strcmp(name, "hidraw")))
        return fn_err_set(FN_EINVAL, "device '%s': this fracnav is built with hidapi's %s backend; %s needs a "
                          "build configured with -DFRACNAV_HIDAPI_LIBUSB=%s", spec, dev__hid_transport.name, name,
                          strcmp(name, "libusb") ? "OFF" : "ON");
    if (!*t)
        return fn_err_set(FN_EINVAL, "device '%s': unknown transport '%s' (a path, auto, serial:S, or a transport name)",
                          spec, name);
    *arg = colon && colon[1] ? colon + 1 : NULL;
    return 0;
}

dev_device *dev_open(const char *spec)
{
    if (!spec || !*spec || !strcmp(spec, "auto"))
        return open_auto();
    const dev_transport *t;
    const char *arg;
    if (dev_spec_resolve(spec, &t, &arg))
        return NULL;
    return open_on(t, arg, spec);
}

void dev_close(dev_device *d)
{
    if (!d)
        return;
    if (d->h)
        d->t->close(d->h);
    if (d->mon)
        d->hp->close(d->mon);
    free(d);
}

/* The device went away: report it once, with motion and buttons released. */
static void lost(dev_device *d, dev_event *ev)
{
    d->t->close(d->h);
    d->h = NULL;
    d->next_try_us = fnclock_now_us() + DEV_REPLUG_MS * 1000;
    if (d->mon)
        d->hp->added(d->mon); /* what was added while the device was there does not bring it back */
    memset(d->ps.raw, 0, sizeof d->ps.raw);
    uint32_t was = d->ps.buttons;
    d->ps.buttons = d->ps.id3_buttons = d->ps.key_buttons = 0;
    memset(d->ps.keys, 0, sizeof d->ps.keys);
    memset(ev, 0, sizeof *ev);
    ev->t_us = fnclock_now_us();
    d->unplugs++;
    ev->flags = DEV_EV_UNPLUG | DEV_EV_MOTION | (was ? DEV_EV_BUTTON : 0);
    ev->released = was;
    ev->battery = -1;
}

/* Whether the handle is the device that was lost. A transport without identities (spnav,
 * keyboard: vid 0) always matches. */
static int same_device(dev_device *d, dev_handle *h)
{
    dev_info now;
    if (!d->info.vid || !d->t->info || d->t->info(h, &now) < 0)
        return !d->info.vid;
    if (now.vid == d->info.vid && now.pid == d->info.pid && !strcmp(now.serial, d->info.serial))
        return 1;
    fn_err_set(FN_ENODEV, "%s: %04x:%04x serial '%s' is not the device that was unplugged (%04x:%04x serial "
               "'%s'): still waiting for it", now.path[0] ? now.path : d->reopen, now.vid, now.pid, now.serial,
               d->info.vid, d->info.pid, d->info.serial);
    return 0;
}

/* Same path first; else the same vid:pid:serial wherever it reappeared (a replugged device may get
 * another hidraw number; devices without a serial number match on vid:pid). Returns 1 found, 0 not
 * found, -1 another device at the old path. */
static int try_reopen(dev_device *d)
{
    dev_handle *h = NULL;
    int other = 0;
    if (d->t->open(d->reopen[0] ? d->reopen : NULL, &h) == 0) {
        if (same_device(d, h)) {
            d->h = h;
            return 1;
        }
        d->t->close(h);
        other = 1;
    }
    dev_info found[16];
    int n = d->t->enumerate && d->info.vid ? d->t->enumerate(found, 16) : 0;
    for (int k = 0; k < n && k < 16; k++)
        if (found[k].vid == d->info.vid && found[k].pid == d->info.pid &&
            !strcmp(found[k].serial, d->info.serial) && d->t->open(found[k].path, &h) == 0) {
            d->h = h;
            snprintf(d->reopen, sizeof d->reopen, "%.255s", found[k].path);
            return 1;
        }
    return other ? -1 : 0;
}

/* Waits (up to timeout_ms) until the next scheduled look or a hotplug "add"; 1 when it is time to
 * look for the device. */
static int time_to_look(dev_device *d, int timeout_ms)
{
    int64_t wait_us = d->next_try_us - fnclock_now_us();
    if (wait_us <= 0)
        return 1;
    if (timeout_ms >= 0 && wait_us > (int64_t)timeout_ms * 1000)
        wait_us = (int64_t)timeout_ms * 1000;
    if (d->mon) {
        struct pollfd p = {d->hp->fd(d->mon), POLLIN, 0};
        if (poll(&p, 1, (int)((wait_us + 999) / 1000)) > 0 && d->hp->added(d->mon))
            return 1;
    } else if (wait_us > 0) {
        usleep((useconds_t)wait_us);
    }
    return fnclock_now_us() >= d->next_try_us;
}

static int poll_unplugged(dev_device *d, dev_event *ev, int timeout_ms)
{
    if (!time_to_look(d, timeout_ms))
        return 0;
    d->next_try_us = fnclock_now_us() + DEV_REPLUG_MS * 1000;
    int found = try_reopen(d);
    if (found <= 0) {
        int report = found < 0 && !d->refused;
        d->refused = found < 0;
        if (!report)
            return 0;
        memset(ev, 0, sizeof *ev);
        ev->t_us = fnclock_now_us();
        ev->flags = DEV_EV_REFUSED;
        ev->battery = -1;
        return 1;
    }
    d->refused = 0;
    int battery = d->ps.battery;
    devparse_init(&d->ps, d->row, d->ps.axis_max);
    d->ps.battery = battery;
    memset(ev, 0, sizeof *ev);
    ev->t_us = fnclock_now_us();
    ev->flags = DEV_EV_REPLUG;
    ev->battery = battery;
    return 1;
}

/* A recording that played out: DEV_RECORDED_LOOP opens it again from its start, as a replug. */
static int recording_end(dev_device *d, dev_event *ev)
{
    memset(ev, 0, sizeof *ev);
    ev->battery = -1;
    if (d->mode != DEV_RECORDED_LOOP) {
        ev->flags = DEV_EV_END;
        return 1;
    }
    d->t->close(d->h);
    d->h = NULL;
    int rc = d->t->open(d->reopen, &d->h);
    if (rc < 0)
        return fn_err_wrap(rc, "%s: playing it again", d->reopen);
    devparse_state *ps = &d->ps;
    uint64_t ok = ps->n_ok, unknown = ps->n_unknown_id, bad = ps->n_bad_len;
    devparse_init(ps, ps->row, ps->axis_max);
    ps->n_ok = ok, ps->n_unknown_id = unknown, ps->n_bad_len = bad;
    d->rec_unplugged = 0;
    atomic_fetch_add(&d->plays, 1);
    ev->flags = DEV_EV_REPLUG;
    return 1;
}

/* A recording's unplug: the handle stays open; its next report is the replug. */
static int recorded_unplug(dev_device *d, dev_event *ev, int64_t t_us)
{
    if (d->t->finished && d->t->finished(d->h))
        return recording_end(d, ev);
    if (d->rec_unplugged)
        return 0; /* still away (a paced replay waits for its replug): said once */
    memset(ev, 0, sizeof *ev);
    ev->t_us = t_us;
    ev->flags = DEV_EV_UNPLUG;
    ev->battery = -1;
    d->rec_unplugged = 1;
    d->unplugs++;
    return 1;
}

/* The first report after a recording's unplug: the replug now, the report's event next. */
static int recorded_replug(dev_device *d, const uint8_t *rep, size_t len, int64_t t_us, dev_event *ev)
{
    d->rec_unplugged = 0;
    d->has_pending = devparse_report(&d->ps, rep, len, t_us, &d->pending);
    memset(ev, 0, sizeof *ev);
    ev->t_us = t_us;
    ev->flags = DEV_EV_REPLUG;
    ev->battery = d->ps.battery;
    return 1;
}

int dev_poll(dev_device *d, dev_event *ev, int timeout_ms)
{
    if (!d->h)
        return poll_unplugged(d, ev, timeout_ms);
    if (d->has_pending) {
        d->has_pending = 0;
        *ev = d->pending;
        return 1;
    }
    int live = d->mode == DEV_LIVE;
    uint8_t buf[DEV_REPORT_MAX];
    int got = 0;
    for (int i = 0; i < DRAIN_MAX && (live || !got); i++) {
        int64_t t_us = 0;
        int n = d->t->read(d->h, buf, sizeof buf, i == 0 || !live ? timeout_ms : 0, &t_us);
        if (n == FN_ENODEV && !live)
            return recorded_unplug(d, ev, t_us);
        if (n == FN_ENODEV) { /* keep the edges of what came before the unplug */
            dev_event u;
            lost(d, &u);
            if (got)
                devparse_merge(ev, &u);
            else
                *ev = u;
            return 1;
        }
        if (n < 0)
            return n;
        if (n == 0)
            break;
        if (d->hook)
            d->hook(d->hook_ctx, buf, (size_t)n, t_us);
        if (d->rec_unplugged)
            return recorded_replug(d, buf, (size_t)n, t_us, ev);
        dev_event e;
        if (!devparse_report(&d->ps, buf, (size_t)n, t_us, &e))
            continue;
        if (got)
            devparse_merge(ev, &e);
        else
            *ev = e;
        got = 1;
    }
    return got;
}

void dev_set_mode(dev_device *d, dev_mode mode)
{
    d->mode = mode;
}

unsigned dev_unplugs(const dev_device *d)
{
    return d->unplugs;
}

unsigned dev_plays(dev_device *d)
{
    return atomic_load(&d->plays);
}

int dev_zero_offsets(dev_device *d, const float rest[6], int16_t now[6])
{
    if (!(d->row->flags & DEVTAB_F_OPEN))
        return 1;
    if (!d->h || !d->t->get_feature || !d->t->set_feature)
        return fn_err_set(FN_EIO, "%s: cannot reach the controller's zero offsets (feature report 0x21)",
                          d->info.path[0] ? d->info.path : d->t->name);
    uint8_t buf[DEV_REPORT_MAX] = {DEVPARSE_FEAT_ZERO};
    int16_t z[6];
    int n = d->t->get_feature(d->h, buf, sizeof buf);
    if (n < 0 || devparse_open_zero_parse(buf, (size_t)(n < 0 ? 0 : n), z))
        return fn_err_wrap(n < 0 ? n : FN_EFORMAT, "%s: reading zero offsets", d->info.path);
    for (int i = 0; i < 6; i++) { /* the firmware already subtracts z: the rest it reports is on top */
        long v = lroundf(rest[i] * (float)d->ps.axis_max) + z[i];
        z[i] = (int16_t)(v < -350 ? -350 : v > 350 ? 350 : v);
    }
    size_t len = devparse_open_zero_make(buf, z);
    int rc = d->t->set_feature(d->h, buf, len);
    if (rc < 0)
        return fn_err_wrap(rc, "%s: writing zero offsets", d->info.path);
    buf[0] = DEVPARSE_FEAT_ZERO;
    n = d->t->get_feature(d->h, buf, sizeof buf);
    if (n < 0 || devparse_open_zero_parse(buf, (size_t)(n < 0 ? 0 : n), now))
        return fn_err_wrap(n < 0 ? n : FN_EFORMAT, "%s: reading zero offsets back", d->info.path);
    return 0;
}

void dev_set_raw_hook(dev_device *d, dev_raw_hook hook, void *ctx)
{
    d->hook = hook;
    d->hook_ctx = ctx;
}

int dev_set_led(dev_device *d, int on)
{
    if (!(d->row->flags & DEVTAB_F_LED) || !d->h || !d->t->write)
        return 0;
    uint8_t rep[2] = {4, on ? 1 : 0};
    int rc = d->t->write(d->h, rep, sizeof rep);
    return rc < 0 ? rc : 0;
}

int dev_battery(const dev_device *d)
{
    return d->ps.battery;
}

int dev_connected(const dev_device *d)
{
    return d->h != NULL;
}

const devtab_row *dev_row(const dev_device *d)
{
    return d->row;
}

const dev_info *dev_device_info(const dev_device *d)
{
    return &d->info;
}

const char *dev_transport_name(const dev_device *d)
{
    return d->t->name;
}

const dev_transport *dev_transport_of(const dev_device *d)
{
    return d->t;
}

int dev_finished(const dev_device *d)
{
    return d->h && d->t->finished && d->t->finished(d->h);
}

int dev_feed_keys(dev_device *d, const char *bytes, size_t n)
{
    if (!d->t->feed_keys || !d->h)
        return fn_err_set(FN_EINVAL, "%s: this device reads no keys", d->t->name);
    return d->t->feed_keys(d->h, bytes, n);
}

uint64_t dev_skipped(const dev_device *d)
{
    return d->ps.n_unknown_id + d->ps.n_bad_len;
}
