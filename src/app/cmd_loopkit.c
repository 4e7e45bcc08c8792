#include "cmd_loopkit.h"

#include "cmd.h"

#include "case_journal.h"
#include "err.h"
#include "jsonw.h"
#include "obb.h"

#include <errno.h>
#include <inttypes.h>
#include <jansson.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

size_t loopkit_journal_pending(const char *dir)
{
    return case_journal_pending(dir);
}

/* The journal reconciled with the case (case_journal_check); *recs, *n: what --recover applies. */
static int check_journal(loopkit *k, unsigned flags, const char *cmd, journal_rec **recs, size_t *n)
{
    const char *dir = k->dir_name;
    if (flags & LOOPKIT_DISCARD) {
        char path[4200]; /* removed, not parsed: a damaged journal must not block a fresh start */
        snprintf(path, sizeof path, "%s/journal", dir);
        if (unlink(path) != 0 && errno != ENOENT)
            return fn_err_set(FN_EIO, "%s: cannot remove: %s", path, strerror(errno));
        return 0;
    }
    int rc = case_journal_check(k->c, recs, n);
    if (rc == 1 && (flags & LOOPKIT_RESUME))
        return fn_err_set(FN_EMISMATCH, "%s/journal does not extend this case.json, so --recover "
                                        "has nothing to apply (it was kept aside, see above); run "
                                        "again without --recover to start from case.json", dir);
    if (rc >= 0 && *n && !(flags & LOOPKIT_RESUME))
        return fn_err_set(FN_EMISMATCH,
                          "%s/journal holds %zu poses not saved in case.json (an interrupted session): "
                          "run `fracnav %s` with --recover to continue from them, or --discard-journal "
                          "to start from case.json",
                          dir, *n, cmd);
    return rc < 0 ? rc : 0;
}

int loopkit_open(loopkit *k, const char *dir, const loop_config *cfg, unsigned flags, const char *cmd,
                 const cmd_tau *tau)
{
    memset(k, 0, sizeof *k);
    snprintf(k->dir_name, sizeof k->dir_name, "%s", dir);
    k->c = case_load(dir);
    if (!k->c)
        return FN_EIO;
    journal_rec *recs = NULL;
    size_t pending = 0;
    int rc = check_journal(k, flags, cmd, &recs, &pending);
    if (rc == 0 && k->c->nfrag > LOOP_MAX_FRAGS)
        rc = fn_err_set(FN_EINVAL, "%s: %d fragments, the loop steers at most %d", dir, k->c->nfrag,
                        LOOP_MAX_FRAGS);
    if (rc == 0 && k->c->nfrag < 2)
        rc = fn_err_set(FN_EINVAL, "%s: %d fragment(s); steering needs at least two", dir, k->c->nfrag);
    if (rc == 0 && tau)
        rc = cmd_tau_apply(tau, &k->c->tau_min, &k->c->tau_max);
    if (rc == 0) {
        obb_params op = {k->c->tau_min, k->c->tau_max};
        k->obb = loop_obb_new(k->c->frag, k->c->nfrag, &op, NULL);
        if (!k->obb)
            rc = FN_EFORMAT;
    }
    if (rc == 0 && (flags & LOOPKIT_JOURNAL)) {
        journal_bind b;
        case_journal_bind(k->c, &b);
        k->jr = journal_open(dir, &b);
        if (!k->jr)
            rc = FN_EIO;
    }
    if (rc == 0) {
        uint8_t fixed[LOOP_MAX_FRAGS] = {0};
        if (k->c->fixed >= 0 && k->c->fixed < k->c->nfrag)
            fixed[k->c->fixed] = 1;
        loop_collider col = loop_obb_collider(k->obb);
        k->L = loop_new(k->c->frag, k->c->nfrag, fixed, &col, cfg, k->jr);
        if (!k->L)
            rc = FN_ENOMEM;
    }
    if (rc == 0 && pending) {
        rc = loop_recover(k->L, recs, pending);
        k->resumed = rc == 0 ? pending : 0;
        if (rc < 0)
            fn_err_wrap(rc, "%s/journal", dir);
    }
    free(recs);
    if (rc == 0)
        rc = loop_measure(k->L);
    if (rc < 0)
        loopkit_close(k);
    return rc;
}

void loopkit_rebind(loopkit *k)
{
    if (!k->jr)
        return;
    journal_bind b;
    case_journal_bind(k->c, &b);
    journal_rebind(k->jr, &b);
}

/* The pairs that overlap at the case's poses, into k->penetrating and case.json's "penetrating". */
static int check_penetration(loopkit *k)
{
    fcase *c = k->c;
    if (!k->check) {
        obb_params op = {c->tau_min, c->tau_max};
        if (!(k->check = loop_obb_new(c->frag, c->nfrag, &op, NULL)))
            return FN_EFORMAT;
    }
    loop_collider col = loop_obb_collider(k->check);
    json_t *list = json_array();
    int rc = 0;
    for (int a = 0; rc == 0 && a < c->nfrag; a++)
        for (int b = a + 1; rc == 0 && b < c->nfrag; b++) {
            loop_contact ct;
            double mm3 = 0;
            rc = col.query(col.ctx, a, &c->frag[a].pose, b, &c->frag[b].pose, NULL, &ct);
            if (rc < 0 || !ct.collides)
                continue;
            rc = col.overlap(col.ctx, a, &c->frag[a].pose, b, &c->frag[b].pose, &mm3);
            json_array_append_new(list, json_pack("{s:[i,i],s:f}", "fragments", c->frag[a].id,
                                                  c->frag[b].id, "overlap_ml", mm3 / 1000));
            fprintf(stderr, "\nWARNING: saving a penetrating plan: fragments %d and %d overlap by "
                            "%.3f ml (moved while collision checking was off)\n",
                    c->frag[a].id, c->frag[b].id, mm3 / 1000);
        }
    json_decref(k->penetrating);
    k->penetrating = list;
    if (!c->extra)
        c->extra = json_object();
    if (json_array_size(list))
        json_object_set(c->extra, "penetrating", list);
    else
        json_object_del(c->extra, "penetrating");
    return rc;
}

/* case.json keeps one fixed fragment: the case's own while it stays fixed, else the first. */
static void take_fixed(loopkit *k, const uint8_t *fixed)
{
    fcase *c = k->c;
    if (c->fixed < 0 || !fixed[c->fixed]) {
        c->fixed = -1;
        for (int i = 0; i < c->nfrag && c->fixed < 0; i++)
            if (fixed[i])
                c->fixed = i;
    }
    for (int i = 0; i < c->nfrag; i++)
        if (fixed[i] && i != c->fixed)
            fprintf(stderr, "\nfracnav: fragment %d is fixed here too, but case.json records one "
                            "fixed fragment (%d)\n", c->frag[i].id, c->frag[c->fixed].id);
}

int loopkit_save_case(loopkit *k, const pose *poses, const uint8_t *fixed)
{
    for (int i = 0; i < k->c->nfrag; i++)
        k->c->frag[i].pose = poses[i];
    take_fixed(k, fixed);
    int rc = check_penetration(k);
    if (rc == 0)
        rc = case_save(k->c);
    if (rc == 0)
        loopkit_rebind(k);
    return rc;
}

int loopkit_save(loopkit *k)
{
    pose poses[LOOP_MAX_FRAGS];
    uint8_t fixed[LOOP_MAX_FRAGS];
    for (int i = 0; i < k->c->nfrag; i++) {
        poses[i] = loop_pose(k->L, i);
        fixed[i] = (uint8_t)loop_fixed(k->L, i);
    }
    int rc = loopkit_save_case(k, poses, fixed);
    if (rc == 0 && k->jr)
        rc = journal_truncate(k->jr);
    return rc;
}

void loopkit_close(loopkit *k)
{
    loop_free(k->L);
    if (k->jr)
        journal_close(k->jr);
    loop_obb_free(k->obb);
    loop_obb_free(k->check);
    json_decref(k->penetrating);
    case_free(k->c);
    memset(k, 0, sizeof *k);
}

static json_t *count(uint64_t n)
{
    return json_integer((json_int_t)n);
}

/* The loop's statistics under the keys every command uses for them (bench loop too). */
static void put_stats(json_t *j, const loop_stats *s)
{
    static const char *const counts[] = {"events", "steps", "accepted", "limited", "slid", "refused",
                                         "collisions_in_accepted", "unchecked", "escaping", "queries",
                                         "dropped", "journal_errors"};
    const uint64_t values[] = {s->events, s->steps, s->accepted, s->limited, s->slid, s->refused,
                               s->collisions_in_accepted, s->unchecked, s->escaping, s->queries,
                               s->dropped, s->journal_errors};
    for (size_t i = 0; i < sizeof counts / sizeof counts[0]; i++)
        json_object_set_new(j, counts[i], count(values[i]));
    int timed = s->latency_samples > 0, queried = s->queries > 0;
    json_object_set_new(j, "loop_hz", jsonw_measure(s->step_hz));
    json_object_set_new(j, "tick_hz", jsonw_measure(s->tick_hz > 0 ? s->tick_hz : JSONW_NA));
    json_object_set_new(j, "latency_p50_us", jsonw_measure(timed ? s->latency_p50_us : JSONW_NA));
    json_object_set_new(j, "latency_p99_us", jsonw_measure(timed ? s->latency_p99_us : JSONW_NA));
    json_object_set_new(j, "latency_max_us", jsonw_measure(timed ? s->latency_max_us : JSONW_NA));
    json_object_set_new(j, "query_mean_us", jsonw_measure(queried ? s->query_us_mean : JSONW_NA));
    json_object_set_new(j, "query_max_us", jsonw_measure(queried ? s->query_us_max : JSONW_NA));
}

json_t *loopkit_stats_json(const char *command, const loop_stats *s)
{
    json_t *j = jsonw_object(command);
    if (j)
        put_stats(j, s);
    return j;
}

int loopkit_print_json(const loopkit *k, FILE *out, const char *command, long unplugs, uint64_t skipped)
{
    loop_stats s;
    loop_get_stats(k->L, &s);
    char digest[17];
    snprintf(digest, sizeof digest, "%016" PRIx64, s.pose_digest);
    json_t *poses = json_array();
    for (int i = 0; i < k->c->nfrag; i++) {
        pose p = loop_pose(k->L, i);
        json_t *o = json_object();
        json_object_set_new(o, "id", json_integer(k->c->frag[i].id));
        json_object_set_new(o, "name", jsonw_string(k->c->frag[i].name));
        json_object_set_new(o, "fixed", json_boolean(loop_fixed(k->L, i)));
        json_object_set_new(o, "q", jsonw_exact_array(p.q, 4));
        json_object_set_new(o, "t", jsonw_exact_array(p.t, 3));
        json_array_append_new(poses, o);
    }
    json_t *j = loopkit_stats_json(command, &s);
    if (j) {
        json_object_set_new(j, "skipped_reports", count(skipped));
        json_object_set_new(j, "unplugs", unplugs >= 0 ? json_integer(unplugs) : json_null());
        json_object_set_new(j, "resumed_from_journal", count(k->resumed));
        json_object_set_new(j, "journal_records", count(k->jr ? journal_count(k->jr) : 0));
        json_object_set_new(j, "final_poses", poses);
        json_object_set_new(j, "pose_digest", json_string(digest));
        json_object_set(j, "penetrating", k->penetrating ? k->penetrating : json_null());
    } else
        json_decref(poses);
    return jsonw_print(j, out);
}

void loopkit_decoder_init(loopkit_decoder *d, uint16_t vid, uint16_t pid, const calib *cal)
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

int loopkit_decode(loopkit_decoder *d, const uint8_t *rep, size_t len, int64_t t_us, loop_event *ev)
{
    dev_event de;
    if (!devparse_report(&d->ps, rep, len, t_us, &de))
        return 0;
    return from_dev_event(&d->cal, &de, ev);
}

/* The end of a recording with `again`: the same file from its start, as a replug. */
static int play_again(loopkit_tsource *s, loop_event *ev)
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
    loopkit_tsource *s = ctx;
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
            s->has_pending = loopkit_decode(&s->dec, buf, (size_t)n, t_us, &s->pending);
            memset(ev, 0, sizeof *ev);
            ev->kind = LOOP_EV_REPLUG;
            ev->t_us = t_us;
            return 1;
        }
        if (loopkit_decode(&s->dec, buf, (size_t)n, t_us, ev) == 1)
            return 1;
    }
}

int loopkit_parse_pivot(const char *cmd, int argc, char **argv, int *i, double out[3])
{
    for (int a = 0; a < 3; a++)
        if (*i + 1 + a >= argc || !cmd_number(argv[*i + 1 + a], &out[a]))
            return cmd_usage_error(cmd, "--pivot needs three numbers X Y Z (world mm)");
    *i += 3;
    return 0;
}

int loopkit_parse_frame(const char *cmd, const char *name, loop_frame *out)
{
    static const char *names[] = {[LOOP_FRAME_CAMERA] = "camera", [LOOP_FRAME_WORLD] = "world",
                                  [LOOP_FRAME_FRAGMENT] = "fragment"};
    for (int f = 0; f < (int)(sizeof names / sizeof names[0]); f++)
        if (names[f] && !strcmp(name, names[f])) {
            *out = (loop_frame)f;
            return 0;
        }
    return cmd_usage_error(cmd, "--frame %s: use camera, world or fragment", name);
}

loop_source loopkit_transport_source(loopkit_tsource *s)
{
    loop_source src = {tsource_next, s};
    return src;
}

/* A fragment is held while the cap is deflected and the selected fragment can move. */
static int holding(const loopkit_dsource *s, const loop_event *ev)
{
    int deflected = 0;
    for (int a = 0; a < 6; a++)
        deflected |= ev->motion[a] != 0;
    if (!deflected || !s->L)
        return deflected;
    loop_scene sc = {0};
    loop_scene_read(s->L, &sc);
    return !sc.fixed[sc.selected];
}

static void update_led(loopkit_dsource *s, int held)
{
    int on = calib_led(&s->cal, held);
    if (on != s->led && dev_set_led(s->d, on) >= 0)
        s->led = on;
}

void loopkit_dsource_init(loopkit_dsource *s, dev_device *d, const calib *cal)
{
    memset(s, 0, sizeof *s);
    s->d = d;
    s->cal = *cal;
    s->led = -1;
    atomic_init(&s->battery, -1);
    pthread_mutex_init(&s->mu, NULL);
}

void loopkit_dsource_destroy(loopkit_dsource *s)
{
    pthread_mutex_destroy(&s->mu);
}

int loopkit_dsource_refused(loopkit_dsource *s, char *out, size_t cap)
{
    pthread_mutex_lock(&s->mu);
    snprintf(out, cap, "%s", s->refused);
    pthread_mutex_unlock(&s->mu);
    return out[0] != '\0';
}

/* Keeps (or, msg NULL, clears) the refusal for the view: fn_err_msg() is this thread's own. */
static void set_refused(loopkit_dsource *s, const char *msg)
{
    pthread_mutex_lock(&s->mu);
    snprintf(s->refused, sizeof s->refused, "%s", msg ? msg : "");
    pthread_mutex_unlock(&s->mu);
}

static int dsource_next(void *ctx, loop_event *ev, int timeout_ms)
{
    loopkit_dsource *s = ctx;
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

loop_source loopkit_device_source(loopkit_dsource *s)
{
    loop_source src = {dsource_next, s};
    return src;
}
