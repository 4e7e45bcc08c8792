/* session: event sources -- raw reports through the parser and calibration into loop events,
 * from a transport handle (recordings, the virtual device) or from a live device. */
#include "session.h"

#include "err.h"

#include <stdatomic.h>
#include <string.h>

void session_decoder_init(session_decoder *d, uint16_t vid, uint16_t pid, const calib *cal)
{
    devparse_init(&d->ps, devtab_find(vid, pid), 0);
    if (cal)
        d->cal = *cal;
    else
        calib_default(&d->cal);
}

/* A parsed device event -> a loop event, through calibration. */
static int from_dev_event(calib *cal, dev_event *de, loop_event *ev)
{
    if (!(de->flags & (DEV_EV_MOTION | DEV_EV_BUTTON)))
        return 0;
    uint32_t pressed, released;
    uint32_t buttons = calib_buttons(cal, de, &pressed, &released);
    float m[6];
    calib_apply(cal, de->axis, m);
    memset(ev, 0, sizeof *ev);
    ev->kind = LOOP_EV_MOTION;
    ev->t_us = de->t_us;
    ev->buttons = buttons;
    memcpy(ev->motion, m, sizeof m);
    return 1;
}

int session_decode(session_decoder *d, const uint8_t *rep, size_t len, int64_t t_us, loop_event *ev)
{
    dev_event de;
    if (!devparse_report(&d->ps, rep, len, t_us, &de))
        return 0;
    return from_dev_event(&d->cal, &de, ev);
}

/* The end of a recording with `again`: the same file from its start, as a replug. */
static int play_again(session_tsource *s, loop_event *ev)
{
    s->tr->close(s->h);
    s->h = NULL;
    int rc = s->tr->open(s->again, &s->h);
    if (rc < 0)
        return rc;
    devparse_state *ps = &s->dec.ps;
    uint64_t ok = ps->n_ok, unknown = ps->n_unknown_id, bad = ps->n_bad_len;
    devparse_init(ps, ps->row, ps->axis_max);
    ps->n_ok = ok, ps->n_unknown_id = unknown, ps->n_bad_len = bad;
    s->unplugged = 0;
    atomic_fetch_add(&s->plays, 1);
    memset(ev, 0, sizeof *ev);
    ev->kind = LOOP_EV_REPLUG;
    return 1;
}

static int tsource_next(void *ctx, loop_event *ev, int timeout_ms)
{
    session_tsource *s = ctx;
    uint8_t buf[DEV_REPORT_MAX];
    if (s->has_pending) {
        s->has_pending = 0;
        *ev = s->pending;
        return 1;
    }
    for (;;) {
        int64_t t_us = 0;
        int n = s->tr->read(s->h, buf, sizeof buf, timeout_ms, &t_us);
        if (n == FN_ENODEV) {
            if (s->finished && s->finished(s->h))
                return s->again ? play_again(s, ev) : LOOP_SOURCE_END;
            memset(ev, 0, sizeof *ev);
            ev->kind = LOOP_EV_UNPLUG;
            ev->t_us = t_us;
            s->unplugged = 1;
            s->unplugs++;
            return 1;
        }
        if (n <= 0)
            return n;
        if (s->unplugged) {
            /* The first report after an unplug: say the device is back, then give the report. */
            s->unplugged = 0;
            s->has_pending = session_decode(&s->dec, buf, (size_t)n, t_us, &s->pending);
            memset(ev, 0, sizeof *ev);
            ev->kind = LOOP_EV_REPLUG;
            ev->t_us = t_us;
            return 1;
        }
        if (session_decode(&s->dec, buf, (size_t)n, t_us, ev) == 1)
            return 1;
    }
}

loop_source session_transport_source(session_tsource *s)
{
    loop_source src = {tsource_next, s};
    return src;
}

/* A fragment is held while the cap is deflected and the selected fragment can move. */
static int holding(const session_dsource *s, const loop_event *ev)
{
    int deflected = 0;
    for (int a = 0; a < 6; a++)
        deflected |= ev->motion[a] != 0;
    return deflected && atomic_load_explicit(&s->movable, memory_order_relaxed);
}

static void update_led(session_dsource *s, int held)
{
    int on = calib_led(&s->cal, held);
    if (on != s->led && dev_set_led(s->d, on) >= 0)
        s->led = on;
}

void session_dsource_init(session_dsource *s, dev_device *d, const calib *cal)
{
    memset(s, 0, sizeof *s);
    s->d = d;
    s->cal = *cal;
    s->led = -1;
    atomic_init(&s->movable, 1);
    atomic_init(&s->battery, -1);
    pthread_mutex_init(&s->mu, NULL);
}

void session_dsource_destroy(session_dsource *s)
{
    pthread_mutex_destroy(&s->mu);
}

int session_dsource_refused(session_dsource *s, char *out, size_t cap)
{
    pthread_mutex_lock(&s->mu);
    snprintf(out, cap, "%s", s->refused);
    pthread_mutex_unlock(&s->mu);
    return out[0] != '\0';
}

/* Keeps (or, msg NULL, clears) the refusal for the view: fn_err_msg() is this thread's own. */
static void set_refused(session_dsource *s, const char *msg)
{
    pthread_mutex_lock(&s->mu);
    snprintf(s->refused, sizeof s->refused, "%s", msg ? msg : "");
    pthread_mutex_unlock(&s->mu);
}

static int dsource_next(void *ctx, loop_event *ev, int timeout_ms)
{
    session_dsource *s = ctx;
    dev_event de;
    int rc = dev_poll(s->d, &de, timeout_ms);
    if (rc <= 0)
        return rc;
    atomic_store(&s->battery, dev_battery(s->d));
    if (de.flags & DEV_EV_REFUSED)
        set_refused(s, fn_err_msg());
    if (de.flags & DEV_EV_REPLUG)
        set_refused(s, NULL);
    if (de.flags & (DEV_EV_UNPLUG | DEV_EV_REPLUG)) {
        memset(ev, 0, sizeof *ev);
        ev->kind = de.flags & DEV_EV_UNPLUG ? LOOP_EV_UNPLUG : LOOP_EV_REPLUG;
        ev->t_us = de.t_us;
        return 1;
    }
    rc = from_dev_event(&s->cal, &de, ev);
    if (rc == 1 && ev->kind == LOOP_EV_MOTION)
        update_led(s, holding(s, ev));
    return rc;
}

loop_source session_device_source(session_dsource *s)
{
    loop_source src = {dsource_next, s};
    return src;
}
