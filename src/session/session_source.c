/* session: event sources -- raw reports through the parser and calibration into loop events,
 * from a transport handle (recordings, the virtual device) or from a live device. */
#include "session_impl.h"

#include "devparse.h"
#include "err.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

/* Raw reports -> loop events (parser, then calibration). */
typedef struct session_decoder {
    devparse_state ps;
    calib cal;
} session_decoder;

struct session_tsource {
    const dev_transport *tr;
    dev_handle *h;
    session_decoder dec;
    int (*finished)(const dev_handle *h);
    const char *again;
    int unplugged, has_pending;
    loop_event pending;
    unsigned unplugs;
    _Atomic unsigned plays; /* plays begun after the first (again); read by the view */
};

struct session_dsource {
    dev_device *d;
    calib cal;
    _Atomic int movable; /* the selected fragment can move (session_drive_led; 1 until then) */
    int led;             /* the LED state last sent, -1 none yet */
    _Atomic int battery; /* 0..100, -1 unknown; read by the status line */
    pthread_mutex_t mu;  /* guards refused */
    char refused[512];   /* "" or the refusal's message, until the device comes back */
};

/* cal NULL: the default calibration. */
static void decoder_init(session_decoder *d, uint16_t vid, uint16_t pid, const calib *cal)
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

/* 1 when the report changed motion or buttons (ev filled), 0 to skip it. */
static int decode(session_decoder *d, const uint8_t *rep, size_t len, int64_t t_us, loop_event *ev)
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
            s->has_pending = decode(&s->dec, buf, (size_t)n, t_us, &s->pending);
            memset(ev, 0, sizeof *ev);
            ev->kind = LOOP_EV_REPLUG;
            ev->t_us = t_us;
            return 1;
        }
        if (decode(&s->dec, buf, (size_t)n, t_us, ev) == 1)
            return 1;
    }
}

session_tsource *session_tsource_new(const dev_transport *tr, dev_handle *h, uint16_t vid, uint16_t pid,
                                     const calib *cal, int (*finished)(const dev_handle *h), const char *again)
{
    session_tsource *s = calloc(1, sizeof *s);
    if (!s) {
        tr->close(h);
        fn_err_set(FN_ENOMEM, "out of memory for an event source");
        return NULL;
    }
    s->tr = tr;
    s->h = h;
    s->finished = finished;
    s->again = again;
    decoder_init(&s->dec, vid, pid, cal);
    atomic_init(&s->plays, 0);
    return s;
}

void session_tsource_free(session_tsource *s)
{
    if (!s)
        return;
    if (s->h)
        s->tr->close(s->h);
    free(s);
}

loop_source session_transport_source(session_tsource *s)
{
    loop_source src = {tsource_next, s};
    return src;
}

unsigned session_tsource_unplugs(const session_tsource *s)
{
    return s->unplugs;
}

uint64_t session_tsource_skipped(const session_tsource *s)
{
    return s->dec.ps.n_unknown_id + s->dec.ps.n_bad_len;
}

unsigned session_tsource_plays(session_tsource *s)
{
    return atomic_load(&s->plays);
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

session_dsource *session_dsource_new(dev_device *d, const calib *cal)
{
    session_dsource *s = calloc(1, sizeof *s);
    if (!s) {
        dev_close(d);
        fn_err_set(FN_ENOMEM, "out of memory for an event source");
        return NULL;
    }
    s->d = d;
    s->cal = *cal;
    s->led = -1;
    atomic_init(&s->movable, 1);
    atomic_init(&s->battery, -1);
    pthread_mutex_init(&s->mu, NULL);
    return s;
}

void session_dsource_free(session_dsource *s)
{
    if (!s)
        return;
    pthread_mutex_destroy(&s->mu);
    dev_close(s->d);
    free(s);
}

void session__led_movable(session_dsource *s, int movable)
{
    atomic_store_explicit(&s->movable, movable, memory_order_relaxed);
}

dev_device *session_dsource_device(session_dsource *s)
{
    return s->d;
}

int session_dsource_movable(session_dsource *s)
{
    return atomic_load_explicit(&s->movable, memory_order_relaxed);
}

int session_dsource_battery(session_dsource *s)
{
    return atomic_load(&s->battery);
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
