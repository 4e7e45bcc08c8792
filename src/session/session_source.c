/* session: event sources -- a device's events (dev_poll: live, or a recording one report at a
 * time) through the calibration into loop events. */
#include "session_impl.h"

#include "err.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

struct session_dsource {
    dev_device *d;
    calib cal;
    _Atomic int movable; /* the selected fragment can move (session_drive_led; 1 until then) */
    int led;             /* the LED state last sent, -1 none yet */
    _Atomic int battery; /* 0..100, -1 unknown; read by the status line */
    pthread_mutex_t mu;  /* guards refused */
    char refused[512];   /* "" or the refusal's message, until the device comes back */
    int recording;       /* opened as a recording (session_source_open) */
};

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
    if (cal)
        s->cal = *cal;
    else
        calib_default(&s->cal);
    s->led = -1;
    atomic_init(&s->movable, 1);
    atomic_init(&s->battery, -1);
    pthread_mutex_init(&s->mu, NULL);
    return s;
}

session_dsource *session_recording_new(const dev_transport *tr, dev_handle *h, const calib *cal,
                                       const char *again)
{
    dev_device *d = dev_open_handle(tr, h, again);
    if (!d)
        return NULL;
    dev_set_mode(d, again ? DEV_RECORDED_LOOP : DEV_RECORDED);
    session_dsource *s = session_dsource_new(d, cal);
    if (s)
        s->recording = 1;
    return s;
}

/* The transport of a played recording (replay:FILE, replay-realtime:FILE) with its file in *file,
 * else NULL: a spec that names no recording, or none that resolves (dev_open says why). */
static const dev_transport *recording_spec(const char *spec, const char **file)
{
    const dev_transport *t;
    if (!strcmp(spec, "auto") || dev_spec_resolve(spec, &t, file) || !(t->caps & DEV_CAP_RECORDING)) {
        fn_err_clear();
        return NULL;
    }
    return t;
}

int session_spec_recording(const char *spec)
{
    const char *file;
    return recording_spec(spec, &file) != NULL;
}

session_dsource *session_source_open(const char *spec, const calib *cal, int again, loop_config *cfg)
{
    const char *file = NULL;
    const dev_transport *t = recording_spec(spec, &file);
    dev_device *d = dev_open(spec);
    if (!d)
        return NULL;
    if (t)
        dev_set_mode(d, again ? DEV_RECORDED_LOOP : DEV_RECORDED);
    loop_config_actions_at(cfg, devtab_key1_button(dev_row(d)));
    const dev_transport *tr = dev_transport_of(d);
    if (tr->help_button)
        cfg->button_action[tr->help_button - 1] = LOOP_ACT_HELP;
    session_dsource *s = session_dsource_new(d, cal);
    if (s)
        s->recording = t != NULL;
    return s;
}

int session_source_recording(const session_dsource *s)
{
    return s->recording;
}

int session_source_keyboard(const session_dsource *s)
{
    return (dev_transport_of(s->d)->caps & DEV_CAP_TERMINAL) != 0;
}

const char *session_source_name(const session_dsource *s)
{
    const devtab_row *row = dev_row(s->d);
    return row && row->name ? row->name : "?";
}

unsigned session_source_unplugs(const session_dsource *s)
{
    return dev_unplugs(s->d);
}

uint64_t session_source_skipped(const session_dsource *s)
{
    return dev_skipped(s->d);
}

unsigned session_source_plays(session_dsource *s)
{
    return dev_plays(s->d);
}

int session_source_feed_keys(session_dsource *s, const char *bytes, size_t n)
{
    return dev_feed_keys(s->d, bytes, n);
}

void session_dsource_free(session_dsource *s)
{
    if (!s)
        return;
    if (s->d && !s->recording)
        dev_set_led(s->d, 0); /* the LED says a fragment is held: not once the session is over */
    pthread_mutex_destroy(&s->mu);
    dev_close(s->d);
    free(s);
}

void session__led_movable(session_dsource *s, int movable)
{
    atomic_store_explicit(&s->movable, movable, memory_order_relaxed);
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
    if (de.flags & DEV_EV_END)
        return LOOP_SOURCE_END;
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
