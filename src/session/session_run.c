/* session: running -- the loop thread and the reader, actions and proposals in, events out. */
#include "session_impl.h"

#include "err.h"
#include "fnclock.h"

#include <errno.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* Proposals may run this far ahead of their events (the scene keeps LOOP_PROPOSALS_KEPT). */
#define PROPOSALS_AHEAD (LOOP_PROPOSALS_KEPT - 8)

static void *event_thread(void *arg);

static void on_publish(void *ctx)
{
    session *s = ctx;
    if (s->led) /* on the publishing thread: the loop's state is this thread's to read */
        session__led_movable(s->led, !loop_fixed(s->L, loop_selected(s->L)));
    sem_post(&s->wake);
    if (atomic_load(&s->prev_run)) /* the preview's worker looks at the new scene */
        sem_post(&s->prev_wake);
    if (s->wakeup)
        s->wakeup(s->wakeup_ctx);
}

static void *loop_thread(void *arg)
{
    session *s = arg;
    loop_realtime_priority(); /* best effort: without it the loop still runs, just less steadily */
    s->loop_rc = loop_run(s->L, s->in, 1000, &s->stop);
    return NULL;
}

int session_play_each(session *s, loop_source src, int (*each)(void *ctx, int64_t t_us), void *ctx)
{
    loop_reset_timing(s->L);
    loop_event ev;
    for (;;) {
        int rc = src.next(src.ctx, &ev, 0);
        s->ended = rc == LOOP_SOURCE_END;
        if (rc == LOOP_SOURCE_END)
            return each ? each(ctx, -1) : 0;
        if (rc < 0)
            return rc;
        if (rc == 0)
            continue;
        if (each && (rc = each(ctx, ev.t_us)) < 0)
            return rc;
        ev.arrival_us = fnclock_now_us();
        rc = loop_feed(s->L, &ev);
        if (rc < 0)
            return rc;
    }
}

int session_play(session *s, loop_source src, int mode)
{
    if (mode == SESSION_PLAY_FAST)
        return session_play_each(s, src, NULL, NULL);
    loop_reset_timing(s->L);
    loop_reader *rd = loop_reader_start(src, s->in, s->L, mode == SESSION_PLAY_LOCKSTEP);
    if (!rd)
        return FN_EIO;
    int preview = s->preview_mode != SESSION_PREVIEW_OFF;
    if (preview)
        loop_set_publish_hook(s->L, on_publish, s); /* wakes the preview's worker */
    int rc = session__preview_start(s);
    if (rc == 0)
        rc = loop_run(s->L, s->in, 1000, loop_reader_done_flag(rd));
    session__preview_join(s);
    if (preview)
        loop_set_publish_hook(s->L, NULL, NULL);
    loop_reader_stop(rd);
    s->ended = 1;
    return rc;
}

int session_start(session *s, loop_source src)
{
    if (atomic_load(&s->running))
        return fn_err_set(FN_EINVAL, "the session is already running");
    atomic_store(&s->stop, 0);
    loop_reset_timing(s->L);
    s->ended = 0;
    s->end_told = 0;
    loop_set_publish_hook(s->L, on_publish, s);
    s->rd = loop_reader_start(src, s->in, s->L, 0);
    if (!s->rd)
        return FN_EIO;
    if (pthread_create(&s->th, NULL, loop_thread, s) != 0) {
        loop_reader_stop(s->rd);
        s->rd = NULL;
        return fn_err_set(FN_EIO, "cannot start the loop thread");
    }
    atomic_store(&s->running, 1);
    atomic_store(&s->ev_stop, 0);
    if (pthread_create(&s->ev_th, NULL, event_thread, s) != 0) {
        session_stop(s);
        return fn_err_set(FN_EIO, "cannot start the session's event thread");
    }
    s->ev_running = 1;
    int rc = session__preview_start(s);
    if (rc < 0)
        session_stop(s);
    return rc;
}

int session_ended(session *s)
{
    return s->rd ? loop_reader_done(s->rd) : s->ended;
}

/* Pushes one event onto the control ring (any thread) and wakes the loop. */
static int push_control(session *s, const loop_event *ev)
{
    if (!atomic_load(&s->running))
        return fn_err_set(FN_EAGAIN, "the session is not running");
    int ok = ring_push(s->ctl, ev);
    if (ok)
        loop_notify(s->L);
    return ok ? 0 : fn_err_set(FN_EAGAIN, "the loop's control queue is full");
}

int session_send_action(session *s, loop_action a)
{
    if (a <= LOOP_ACT_NONE || a >= LOOP_ACT_COUNT)
        return fn_err_set(FN_EINVAL, "action %d: not an action (1..%d)", (int)a, LOOP_ACT_COUNT - 1);
    loop_event ev = {0};
    ev.kind = LOOP_EV_ACTION;
    ev.action = (int32_t)a;
    pthread_mutex_lock(&s->push_mu);
    int rc = push_control(s, &ev);
    pthread_mutex_unlock(&s->push_mu);
    return rc;
}

loop_action session_key_action(int ch)
{
    switch (ch) {
    case 'n': return LOOP_ACT_NEXT;
    case 'p': return LOOP_ACT_PREV;
    case 'f': return LOOP_ACT_FIX;
    case 'c': return LOOP_ACT_COLLISION;
    case 't': return LOOP_ACT_TRANS_ONLY;
    case 'r': return LOOP_ACT_ROT_ONLY;
    case 'u': return LOOP_ACT_UNDO;
    case 'y': return LOOP_ACT_REDO;
    case 'm': return LOOP_ACT_FRAME;
    case 's': return LOOP_ACT_SAVE;
    case '?':
    case 'h': return LOOP_ACT_HELP;
    case 'g': return LOOP_ACT_FIT;
    case 'v': return LOOP_ACT_PREVIEW;
    case 'b': return LOOP_ACT_ACCEPT;
    default: return LOOP_ACT_NONE;
    }
}

int session_propose_pose(session *s, int fragment, const pose *p, uint64_t *id)
{
    return session__propose(s, fragment, p, 0, id);
}

int session__propose(session *s, int fragment, const pose *p, double tolerance_mm, uint64_t *id)
{
    if (fragment < 0 || fragment >= s->nfrag)
        return fn_err_set(FN_EINVAL, "fragment %d: the session has %d (0..%d)", fragment, s->nfrag,
                          s->nfrag - 1);
    loop_event ev = {0};
    ev.kind = LOOP_EV_POSE;
    ev.frag = fragment;
    ev.pose = *p;
    ev.tolerance_mm = tolerance_mm;
    pthread_mutex_lock(&s->push_mu);
    int rc = 0;
    if (s->proposed - atomic_load(&s->seen_proposals) >= PROPOSALS_AHEAD)
        rc = fn_err_set(FN_EAGAIN, "%d proposals await their events: wait on the session's events",
                        PROPOSALS_AHEAD);
    if (rc == 0)
        rc = push_control(s, &ev);
    if (rc == 0) {
        s->proposed++;
        s->proposal_frag[s->proposed % LOOP_PROPOSALS_KEPT] = fragment;
        if (id)
            *id = s->proposed;
    }
    pthread_mutex_unlock(&s->push_mu);
    return rc;
}

int session_scene_read(session *s, loop_scene *out)
{
    return loop_scene_read(s->L, out);
}

void session_set_camera(session *s, const double right[3], const double up[3], const double forward[3])
{
    loop_set_camera(s->L, right, up, forward);
}

void session_subscribe(session *s, unsigned kinds)
{
    atomic_store(&s->kinds, kinds);
}

void session_drive_led(session *s, session_dsource *ds)
{
    s->led = ds;
}

void session_set_wakeup(session *s, void (*fn)(void *ctx), void *ctx)
{
    s->wakeup = fn;
    s->wakeup_ctx = ctx;
}

/* A save request: the scene's poses into the case while the loop runs on; the loop then empties
 * the journal of what the case now holds. */
static void save_request(session *s, session_event *ev)
{
    const loop_scene *sc = &s->scene;
    int rc = session_save_case(s, sc->pose, sc->fixed);
    ev->kind = SESSION_EV_SAVED;
    ev->result = rc;
    if (rc < 0)
        snprintf(ev->text, sizeof ev->text, "save failed: %.1000s", fn_err_msg());
    else
        snprintf(ev->text, sizeof ev->text, "saved %.1000s", s->dir);
    if (rc < 0 || !atomic_load(&s->running))
        return;
    memcpy(s->saved, sc->pose, sizeof(pose) * (size_t)s->nfrag);
    loop_event saved = {.kind = LOOP_EV_SAVED};
    pthread_mutex_lock(&s->push_mu);
    push_control(s, &saved); /* full: the journal keeps more than it needs, nothing is lost */
    pthread_mutex_unlock(&s->push_mu);
}

/* LOOP_ACT_ACCEPT: the preview's ghost proposed, as the fit action's result is, when it is fresh
 * for the scene; ev (SESSION_EV_PREVIEW) says what was done. */
static void accept_preview(session *s, session_event *ev)
{
    const loop_scene *sc = &s->scene;
    double tol;
    ev->kind = SESSION_EV_PREVIEW;
    if (!session__preview_ghost(s, sc, &ev->preview, &tol)) {
        ev->result = FN_EINVAL;
        snprintf(ev->text, sizeof ev->text, "accept refused: no preview of frag %d where it is now%s",
                 sc->selected + 1, s->preview_mode == SESSION_PREVIEW_OFF ? " (the preview is off)" : "");
        return;
    }
    const session_preview *p = &ev->preview;
    ev->result = session__propose(s, p->frag, &p->ghost, tol, NULL);
    if (ev->result < 0)
        snprintf(ev->text, sizeof ev->text, "accept of frag %d not applied: %.1000s", p->frag + 1, fn_err_msg());
    else
        snprintf(ev->text, sizeof ev->text, "accepted: frag %d moved %.2f mm, turned %.2f deg to the preview",
                 p->frag + 1, p->moved_mm, p->turned_deg);
}

/* The next event the newest scene holds, in order: proposals, actions, saves, the end, the scene.
 * 1 when ev was filled. On the deriving thread. */
static int derive(session *s, session_event *ev)
{
    const loop_scene *sc = &s->scene;
    pose fitted;
    double fit_tol;
    memset(ev, 0, offsetof(session_event, scene));
    if (sc->proposals > s->derived_proposals) {
        ev->kind = SESSION_EV_POSE;
        ev->id = ++s->derived_proposals;
        ev->result = sc->proposal_result[ev->id % LOOP_PROPOSALS_KEPT];
        pthread_mutex_lock(&s->push_mu);
        ev->frag = s->proposal_frag[ev->id % LOOP_PROPOSALS_KEPT];
        pthread_mutex_unlock(&s->push_mu);
    } else if (sc->actions != s->seen_actions) {
        ev->kind = SESSION_EV_ACTION;
        ev->count = sc->actions - s->seen_actions;
        ev->action = sc->last_action;
        ev->result = sc->last_action_result;
        s->seen_actions = sc->actions;
    } else if (sc->fit_requests != s->seen_fits) {
        s->seen_fits = sc->fit_requests;
        session__fit_start(s, ev);
    } else if (session__fit_finished(s, ev, &fitted, &fit_tol)) {
        /* the fit checked its result at reduce's tolerance: the loop takes it within that */
        if (ev->result == 0 && session__propose(s, ev->fit.frag, &fitted, fit_tol, NULL) < 0) {
            ev->result = FN_EAGAIN;
            snprintf(ev->text, sizeof ev->text, "fit of frag %d not applied: %.1000s",
                     ev->fit.frag + 1, fn_err_msg());
        }
    } else if (sc->accept_requests != s->seen_accepts) {
        s->seen_accepts = sc->accept_requests;
        accept_preview(s, ev);
    } else if (session__preview_event(s, ev)) {
        /* filled */
    } else if (sc->save_requests != s->seen_saves) {
        s->seen_saves = sc->save_requests;
        save_request(s, ev);
    } else if (!s->end_told && session_ended(s)) {
        s->end_told = 1;
        ev->kind = SESSION_EV_END;
    } else if (sc->seq != s->seen_seq) {
        s->seen_seq = sc->seq;
        ev->kind = SESSION_EV_SCENE;
    } else
        return 0;
    ev->scene = *sc;
    return 1;
}

/* A POSE event leaves the queue: its proposal no longer holds the proposer back. */
static void pose_told(session *s, const session_event *ev)
{
    if (ev->kind == SESSION_EV_POSE)
        atomic_store(&s->seen_proposals, ev->id);
}

/* Queues ev for session_wait_event, under ev_mu: actions in a row merge, a scene replaces the
 * pending one, a full queue drops its oldest event (a client that never waits loses nothing but
 * events). 1 when the client has something new. */
static int enqueue(session *s, const session_event *ev)
{
    if (!(atomic_load(&s->kinds) & (unsigned)ev->kind)) {
        pose_told(s, ev);
        return 0;
    }
    if (ev->kind == SESSION_EV_SCENE) {
        s->scene_ev = *ev;
        s->scene_pending = 1;
        return 1;
    }
    session_event *last = s->qn ? &s->queue[(s->qhead + s->qn - 1) % SESSION_QUEUE] : NULL;
    if (last && last->kind == SESSION_EV_ACTION && ev->kind == SESSION_EV_ACTION) {
        unsigned count = last->count + ev->count;
        *last = *ev;
        last->count = count;
        return 1;
    }
    if (s->qn == SESSION_QUEUE) {
        pose_told(s, &s->queue[s->qhead]);
        s->qhead = (s->qhead + 1) % SESSION_QUEUE;
        s->qn--;
    }
    s->queue[(s->qhead + s->qn++) % SESSION_QUEUE] = *ev;
    return 1;
}

/* Reads the newest scene and queues what it holds: saves and fits are carried out here. On the
 * deriving thread; 1 when something was queued. */
static int collect(session *s)
{
    loop_scene_read(s->L, &s->scene);
    session_event ev;
    int news = 0;
    while (derive(s, &ev)) {
        pthread_mutex_lock(&s->ev_mu);
        news |= enqueue(s, &ev);
        pthread_mutex_unlock(&s->ev_mu);
    }
    return news;
}

/* Waits for a post of sem until deadline_us (monotonic; < 0: no limit). */
static void wait_post(sem_t *sem, int64_t deadline_us)
{
    if (deadline_us < 0) {
        while (sem_wait(sem) != 0 && errno == EINTR)
            ;
    } else if (deadline_us > fnclock_now_us()) {
        struct timespec until = fnclock_realtime_deadline(deadline_us);
        while (sem_timedwait(sem, &until) != 0 && errno == EINTR)
            ;
    }
    while (sem_trywait(sem) == 0)
        ; /* one wake-up serves every post so far */
}

/* The event thread: at every publish (and every fit's end), derives the events and tells the
 * client, so that saves and fits happen whether or not it waits. */
static void *event_thread(void *arg)
{
    session *s = arg;
    while (!atomic_load(&s->ev_stop)) {
        wait_post(&s->wake, -1);
        if (collect(s)) {
            sem_post(&s->ev_ready);
            if (s->wakeup)
                s->wakeup(s->wakeup_ctx);
        }
    }
    return NULL;
}

static void stop_event_thread(session *s)
{
    if (!s->ev_running)
        return;
    atomic_store(&s->ev_stop, 1);
    sem_post(&s->wake);
    pthread_join(s->ev_th, NULL);
    s->ev_running = 0;
}

/* The oldest queued event (then the pending scene) into ev; 1 when there was one. */
static int pop(session *s, session_event *ev)
{
    pthread_mutex_lock(&s->ev_mu);
    int got = 1;
    if (s->qn > 0) {
        *ev = s->queue[s->qhead];
        s->qhead = (s->qhead + 1) % SESSION_QUEUE;
        s->qn--;
        pose_told(s, ev);
    } else if (s->scene_pending) {
        *ev = s->scene_ev;
        s->scene_pending = 0;
    } else
        got = 0;
    pthread_mutex_unlock(&s->ev_mu);
    return got;
}

session_event_kind session_wait_event(session *s, int timeout_ms, session_event *ev)
{
    int64_t deadline = timeout_ms < 0 ? -1 : fnclock_now_us() + (int64_t)timeout_ms * 1000;
    for (;;) {
        if (!s->ev_running)
            collect(s); /* no event thread (session_play, stopped): the owner derives */
        if (pop(s, ev))
            return ev->kind;
        if (deadline >= 0 && fnclock_now_us() >= deadline)
            break;
        if (!atomic_load(&s->running) && deadline < 0)
            break; /* nothing will ever come */
        wait_post(s->ev_running ? &s->ev_ready : &s->wake, deadline);
    }
    memset(ev, 0, sizeof *ev);
    return SESSION_EV_NONE;
}

int session_stop(session *s)
{
    if (!atomic_load(&s->running))
        return 0;
    stop_event_thread(s);
    session__fit_join(s); /* a fit's proposal would land in no loop */
    session__preview_join(s);
    s->ended = loop_reader_done(s->rd);
    loop_reader_stop(s->rd);
    s->rd = NULL;
    atomic_store(&s->stop, 1);
    loop_notify(s->L);
    pthread_join(s->th, NULL);
    atomic_store(&s->running, 0);
    loop_set_publish_hook(s->L, NULL, NULL);
    loop_publish(s->L);
    collect(s); /* the last events: their save requests carried out now */
    return s->loop_rc;
}

void session_close(session *s)
{
    if (!s)
        return;
    session_stop(s);
    session__free(s);
}
