#include "sim_replay.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "err.h"
#include "fnclock.h"
#include "script.h"
#include "simdev.h"

/* One handle type, two function sets: the replay's and the virtual device's. */
struct dev_handle {
    fnrec *owned;       /* the recording when the handle loaded or rendered it */
    const fnrec *rec;
    size_t pos;         /* next event */
    int realtime;
    double speed;
    int started;        /* realtime clock anchored */
    int64_t anchor_us;  /* monotonic time of the recording's t = 0 */
    int plugged;
    simdev dev;         /* virtual: LED and feature reports */
    char path[256];
};

static dev_handle *handle_new(const char *kind, const char *path)
{
    dev_handle *h = calloc(1, sizeof *h);
    if (!h) {
        fn_err_set(FN_ENOMEM, "out of memory for a %s device", kind);
        return NULL;
    }
    h->plugged = 1;
    h->speed = 1;
    snprintf(h->path, sizeof h->path, "%s", path);
    return h;
}

int sim_replay_open_rec(const fnrec *rec, const sim_replay_opts *o, dev_handle **out)
{
    *out = NULL;
    dev_handle *h = handle_new("replay", "<recording>");
    if (!h)
        return FN_ENOMEM;
    h->rec = rec;
    if (o) {
        h->realtime = o->realtime;
        h->speed = o->speed > 0 ? o->speed : 1;
    }
    *out = h;
    return 0;
}

int sim_replay_open_file(const char *path, const sim_replay_opts *o, dev_handle **out)
{
    *out = NULL;
    fnrec *r = fnrec_load(path);
    if (!r)
        return FN_EFORMAT;
    int rc = sim_replay_open_rec(r, o, out);
    if (rc) {
        fnrec_free(r);
        return rc;
    }
    (*out)->owned = r;
    snprintf((*out)->path, sizeof (*out)->path, "%s", path);
    return 0;
}

/* A replay needs its file: "replay" alone names none. */
static int open_fast(const char *path, dev_handle **out)
{
    *out = NULL;
    if (!path)
        return fn_err_set(FN_EINVAL, "replay: needs a recording (replay:FILE.fnrec)");
    return sim_replay_open_file(path, &(sim_replay_opts){0, 1}, out);
}

static int open_realtime(const char *path, dev_handle **out)
{
    *out = NULL;
    if (!path)
        return fn_err_set(FN_EINVAL, "replay-realtime: needs a recording (replay-realtime:FILE.fnrec)");
    return sim_replay_open_file(path, &(sim_replay_opts){1, 1}, out);
}

int sim_replay_finished(const dev_handle *h)
{
    return h->pos >= h->rec->n;
}

const fnrec_header *sim_replay_header(const dev_handle *h)
{
    return &h->rec->hdr;
}

/* Recording time of event i in the handle's monotonic clock. */
static int64_t due_us(const dev_handle *h, size_t i)
{
    return h->anchor_us + (int64_t)((double)h->rec->ev[i].t_us / h->speed);
}

/* Waits (realtime) until event pos is due or the timeout passes. Returns 1 when due. */
static int wait_due(dev_handle *h, int timeout_ms, int64_t start)
{
    if (!h->realtime)
        return 1;
    int64_t due = due_us(h, h->pos), now = fnclock_now_us();
    if (due <= now)
        return 1;
    if (timeout_ms == 0)
        return 0;
    int64_t limit = timeout_ms < 0 ? due : start + (int64_t)timeout_ms * 1000;
    fnclock_sleep_until(due < limit ? due : limit);
    return due <= limit;
}

/* Plays the next event: a report's length (copied into buf), 0 for an event that is no report,
 * FN_ENODEV for a disconnect. */
static int play_next(dev_handle *h, uint8_t *buf, size_t cap)
{
    const fnrec_event *e = &h->rec->ev[h->pos++];
    if (e->dir == FNREC_CONNECT) {
        h->plugged = 1;
    } else if (e->dir == FNREC_DISCONNECT) {
        h->plugged = 0;
        return fn_err_set(FN_ENODEV, "%s: device disconnected", h->path);
    } else if (e->dir == FNREC_IN && h->plugged) {
        size_t n = e->len < cap ? e->len : cap;
        memcpy(buf, e->data, n);
        return (int)n;
    }
    return 0;
}

static int disconnected(const dev_handle *h)
{
    return fn_err_set(FN_ENODEV, "%s: device disconnected", h->path);
}

/* The monotonic time of this read; a realtime handle anchors the recording's t = 0 at its first. */
static int64_t read_start(dev_handle *h)
{
    int64_t start = fnclock_now_us();
    if (h->realtime && !h->started) {
        h->started = 1;
        h->anchor_us = start - (h->rec->n ? (int64_t)((double)h->rec->ev[0].t_us / h->speed) : 0);
    }
    return start;
}

/* A replay: the recorded times; while unplugged it waits for the recorded replug; the end of the
 * recording is the device's end. */
static int replay_read(dev_handle *h, uint8_t *buf, size_t cap, int timeout_ms, int64_t *t_us)
{
    int64_t start = read_start(h);
    for (;;) {
        if (h->pos >= h->rec->n)
            return h->plugged ? fn_err_set(FN_ENODEV, "%s: device disconnected (end of recording)", h->path)
                              : disconnected(h);
        if (!wait_due(h, timeout_ms, start))
            return h->plugged ? 0 : disconnected(h);
        int64_t t = h->rec->ev[h->pos].t_us;
        int n = play_next(h, buf, cap);
        if (n > 0 && t_us)
            *t_us = t;
        if (n)
            return n;
    }
}

/* The virtual device: reports arrive now; unplugged, it is gone until its replug is due; once its
 * script is done it stays plugged in and silent. */
static int virtual_read(dev_handle *h, uint8_t *buf, size_t cap, int timeout_ms, int64_t *t_us)
{
    int64_t start = read_start(h);
    for (;;) {
        if (h->pos >= h->rec->n) {
            if (!h->plugged)
                return disconnected(h);
            fnclock_sleep_until(start + (int64_t)(timeout_ms < 0 ? 100 : timeout_ms) * 1000);
            return 0;
        }
        if (!h->plugged && due_us(h, h->pos) > fnclock_now_us())
            return disconnected(h);
        if (!wait_due(h, timeout_ms, start))
            return 0;
        int n = play_next(h, buf, cap);
        if (n > 0 && t_us)
            *t_us = fnclock_now_us();
        if (n)
            return n;
    }
}

static int replay_write(dev_handle *h, const uint8_t *buf, size_t len)
{
    if (!h->plugged)
        return disconnected(h);
    return len ? (int)len : fn_err_set(FN_EINVAL, "%s: empty output report", h->path);
}

static int virtual_write(dev_handle *h, const uint8_t *buf, size_t len)
{
    return h->plugged ? simdev_output(&h->dev, buf, len) : disconnected(h);
}

/* The last feature report with that ID recorded before the current position (else the first). */
static int replay_get_feature(dev_handle *h, uint8_t *buf, size_t cap)
{
    if (!h->plugged)
        return disconnected(h);
    const fnrec_event *hit = NULL;
    for (size_t i = 0; i < h->rec->n; i++) {
        const fnrec_event *e = &h->rec->ev[i];
        if (e->dir == FNREC_FEATURE && e->data[0] == buf[0] && (!hit || i < h->pos))
            hit = e;
    }
    if (!hit)
        return fn_err_set(FN_EINVAL, "%s: no feature report %u in the recording", h->path, buf[0]);
    size_t n = hit->len < cap ? hit->len : cap;
    memcpy(buf, hit->data, n);
    return (int)n;
}

static int virtual_get_feature(dev_handle *h, uint8_t *buf, size_t cap)
{
    return h->plugged ? simdev_get_feature(&h->dev, buf, cap) : disconnected(h);
}

static int replay_set_feature(dev_handle *h, const uint8_t *buf, size_t len)
{
    if (!h->plugged)
        return disconnected(h);
    return len ? (int)len : fn_err_set(FN_EINVAL, "%s: empty feature report", h->path);
}

static int virtual_set_feature(dev_handle *h, const uint8_t *buf, size_t len)
{
    return h->plugged ? simdev_set_feature(&h->dev, buf, len) : disconnected(h);
}

static int info(dev_handle *h, dev_info *out)
{
    const fnrec_header *hd = &h->rec->hdr;
    memset(out, 0, sizeof *out);
    snprintf(out->path, sizeof out->path, "%s", h->path);
    out->vid = hd->vid;
    out->pid = hd->pid;
    snprintf(out->name, sizeof out->name, "%s", hd->name);
    memcpy(out->desc, hd->desc, hd->desc_len);
    out->desc_len = hd->desc_len;
    return 0;
}

static void close_handle(dev_handle *h)
{
    if (h)
        fnrec_free(h->owned);
    free(h);
}

/* A recording plays as the device it was recorded from (its identity and descriptor), whatever
 * DEVICE says: a DEVICE that differs is ignored with a warning, as fracnav-sim serve --as is. */
static fnrec *played(const char *file, const char *named, const sim_profile **prof)
{
    fnrec *r = fnrec_load(file);
    if (!r)
        return NULL;
    char id[16];
    snprintf(id, sizeof id, "%04x:%04x", r->hdr.vid, r->hdr.pid);
    const sim_profile *p = sim_profile_find(id);
    fn_err_clear();
    if (named[0] && p != *prof)
        fprintf(stderr, "warning: virtual:%s:play=%s: %s ignored: the recording plays as the device it was "
                        "recorded from, %s (%s)\n", named, file, named, id, r->hdr.name);
    if (p)
        *prof = p;
    return r;
}

/* "DEVICE[:script=FILE|:play=FILE]" -> the recording the virtual device plays. */
static fnrec *virtual_source(const char *path, const sim_profile **prof)
{
    char dev[64];
    const char *colon = strchr(path, ':');
    size_t n = colon ? (size_t)(colon - path) : strlen(path);
    /* "046d:c626" is a device id, not DEVICE:option. */
    if (colon && n == 4 && strlen(path) >= 9 && (path[9] == '\0' || path[9] == ':')) {
        n = 9;
        colon = path[9] ? path + 9 : NULL;
    }
    if (n >= sizeof dev) {
        fn_err_set(FN_EINVAL, "virtual device '%s': device name too long", path);
        return NULL;
    }
    memcpy(dev, path, n);
    dev[n] = '\0';
    if (!(*prof = sim_profile_find(dev[0] ? dev : "spacenavigator")))
        return NULL;
    if (colon && !strncmp(colon, ":play=", 6))
        return played(colon + 6, dev, prof);
    script *s = NULL;
    if (colon && strncmp(colon, ":script=", 8)) {
        fn_err_set(FN_EINVAL, "virtual device '%s': expected DEVICE, DEVICE:script=FILE or "
                              "DEVICE:play=FILE", path);
        return NULL;
    }
    if (colon ? !(s = script_load(colon + 8)) : script_parse("", 0, "", &s) != 0)
        return NULL;
    fnrec *r = script_render(s, *prof);
    free(s);
    return r;
}

static int open_virtual(const char *path, dev_handle **out)
{
    *out = NULL;
    const sim_profile *p = NULL;
    fnrec *r = virtual_source(path ? path : "", &p);
    if (!r)
        return fn_err_wrap(FN_EINVAL, "virtual transport");
    dev_handle *h = handle_new("virtual", path ? path : "virtual");
    if (!h) {
        fnrec_free(r);
        return FN_ENOMEM;
    }
    h->owned = r;
    h->rec = r;
    h->realtime = 1;
    h->started = 1;
    h->anchor_us = fnclock_now_us();
    simdev_init(&h->dev, p);
    *out = h;
    return 0;
}

static void by_name(char *buf, size_t cap)
{
    snprintf(buf, cap, "opened by name (--device)");
}

const dev_transport sim_replay_transport = {
    .name = "replay", .caps = DEV_CAP_RECORDING, .open = open_fast, .read = replay_read,
    .write = replay_write, .get_feature = replay_get_feature, .set_feature = replay_set_feature,
    .info = info, .close = close_handle, .describe = by_name, .finished = sim_replay_finished};

const dev_transport sim_replay_realtime_transport = {
    .name = "replay-realtime", .caps = DEV_CAP_RECORDING, .open = open_realtime, .read = replay_read,
    .write = replay_write, .get_feature = replay_get_feature, .set_feature = replay_set_feature,
    .info = info, .close = close_handle, .describe = by_name, .finished = sim_replay_finished};

const dev_transport sim_virtual_transport = {
    .name = "virtual", .open = open_virtual, .read = virtual_read, .write = virtual_write,
    .get_feature = virtual_get_feature, .set_feature = virtual_set_feature, .info = info,
    .close = close_handle, .describe = by_name, .finished = sim_replay_finished};

int sim_register_transports(void)
{
    const dev_transport *all[] = {&sim_replay_transport, &sim_replay_realtime_transport,
                                  &sim_virtual_transport};
    for (size_t i = 0; i < sizeof all / sizeof *all; i++)
        if (!dev_transport_find(all[i]->name) && dev_transport_register(all[i]))
            return FN_ENOMEM;
    return 0;
}
