/* session: the live preview. A worker thread at the lowest priority keeps fitting the selected
 * fragment from where the hand holds it (session.h, "the live preview"); its result is the ghost,
 * which LOOP_ACT_ACCEPT proposes through the loop as the fit action's result is. The loop thread
 * never waits for it: the worker reads the published scenes (lock-free) and fits struct copies of
 * the fragments (sharing their voxels, which nothing writes while a case is open); the loop only
 * posts prev_wake when it publishes (session_run.c). */
#include "session_impl.h"

#include "err.h"
#include "fnclock.h"
#include "reduce.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#define STALE_MM 0.5   /* a fit that began where the hand has since left by more is dropped */
#define STALE_DEG 0.5
#define STILL_MM 0.02  /* a fit from the ghost that moves it less has converged */
#define STILL_DEG 0.02

void session_set_preview(session *s, int mode)
{
    s->preview_mode = mode;
}

void session_preview_status(session *s, session_preview *out)
{
    pthread_mutex_lock(&s->prev_mu);
    *out = s->prev;
    out->asked = atomic_load(&s->prev_asked);
    pthread_mutex_unlock(&s->prev_mu);
}

void session_preview_text(const session_preview *p, char *buf, size_t cap)
{
    if (p->shown)
        snprintf(buf, cap, "preview of frag %d: %.2f mm, %.2f deg away%s", p->frag + 1, p->moved_mm, p->turned_deg,
                 p->converged ? " (b accepts)" : ", fitting");
    else
        snprintf(buf, cap, "%s", p->asked ? "preview on: fitting" : "");
}

/* 1 when sc still holds the poses at[] (the selected fragment sel within the stale limits, the
 * others exactly) with sel selected. */
static int fresh(const session *s, const loop_scene *sc, int sel, const pose *at)
{
    if (sc->selected != sel)
        return 0;
    for (int i = 0; i < s->nfrag; i++)
        if (i != sel && memcmp(&sc->pose[i], &at[i], sizeof(pose)) != 0)
            return 0;
    double mm, deg;
    session__pose_change(s->c ? &s->c->frag[sel] : &s->frags[sel], &at[sel], &sc->pose[sel], &mm, &deg);
    return mm <= STALE_MM && deg <= STALE_DEG;
}

/* 1 when fragment sel is the one that stays as reduce keeps it (no fragment fixed in sc: the
 * largest). Near contact alone it is not previewed: its fit against a smaller piece moves the
 * bone to the piece (a real ilium's ghost 9.8 mm off, fitted to a 0.19 ml chip). */
static int stays(const session *s, const loop_scene *sc, int sel)
{
    const frag *f = s->c ? s->c->frag : s->frags;
    for (int i = 0; i < s->nfrag; i++)
        if (sc->fixed[i] || f[i].voxels > f[sel].voxels)
            return 0;
    return 1;
}

/* 1 when the scene's selected fragment is to be previewed. */
static int wanted(const session *s, const loop_scene *sc)
{
    int sel = sc->selected;
    if (s->nfrag < 2 || sel < 0 || sel >= s->nfrag || sc->fixed[sel])
        return 0;
    if (atomic_load(&s->prev_asked))
        return 1;
    return s->preview_mode == SESSION_PREVIEW_NEAR && sc->collision_on && !isnan(sc->separation_mm) &&
           sc->separation_mm <= SESSION_PREVIEW_NEAR_MM && !stays(s, sc, sel);
}

/* The running fit's context: its fragment and the poses it began at. */
typedef struct preview_fit {
    session *s;
    int sel;
    pose at[LOOP_MAX_FRAGS]; /* every fragment's pose when the fit began */
    loop_scene sc; /* scratch for the staleness check */
} preview_fit;

/* After each iteration: a fit the hand has made stale is cancelled. */
static void on_progress(void *ctx, int id, int iter, int evals, double f, double seconds)
{
    (void)id, (void)iter, (void)evals, (void)f, (void)seconds;
    preview_fit *pf = ctx;
    loop_scene_read(pf->s->L, &pf->sc);
    if (!fresh(pf->s, &pf->sc, pf->sel, pf->at))
        atomic_store(&pf->s->prev_cancel, 1);
}

static void publish(session *s, const session_preview *p, const pose *at, double tolerance_mm)
{
    pthread_mutex_lock(&s->prev_mu);
    unsigned updates = s->prev.updates + 1, dropped = s->prev.dropped;
    s->prev = *p;
    s->prev.updates = updates;
    s->prev.dropped = dropped;
    if (at)
        memcpy(s->prev_at, at, sizeof(pose) * (size_t)s->nfrag);
    s->prev_tolerance_mm = tolerance_mm;
    pthread_mutex_unlock(&s->prev_mu);
    sem_post(&s->wake);
    if (s->wakeup)
        s->wakeup(s->wakeup_ctx);
}

/* One fit of the scene's selected fragment, from the ghost when it is fresh (the hand held still
 * or nearly), else from the hand; publishes the ghost or counts the fit as dropped. Returns 1
 * when another fit from the result should follow (not converged). */
static int fit_once(session *s, preview_fit *pf, const loop_scene *sc)
{
    pose *at = pf->at;
    int sel = sc->selected;
    session_preview old;
    pthread_mutex_lock(&s->prev_mu);
    old = s->prev;
    int warm = old.shown && old.frag == sel && fresh(s, sc, sel, s->prev_at);
    pthread_mutex_unlock(&s->prev_mu);
    if (warm && old.converged && !memcmp(&old.hand, &sc->pose[sel], sizeof(pose)))
        return 0; /* nothing moved since it converged */
    const frag *src = s->c ? s->c->frag : s->frags;
    const frag *others[LOOP_MAX_FRAGS];
    int n = 0;
    pthread_mutex_lock(&s->frag_mu); /* a save may be writing their poses */
    for (int i = 0; i < s->nfrag; i++) {
        s->prev_frags[i] = src[i];
        s->prev_frags[i].pose = sc->pose[i];
        at[i] = sc->pose[i];
        if (i != sel)
            others[n++] = &s->prev_frags[i];
    }
    pthread_mutex_unlock(&s->frag_mu);
    reduce_opts o;
    reduce_defaults(&o);
    o.tau_min = s->tau[0];
    o.tau_max = s->tau[1];
    o.gap_mm = s->fit_gap_mm; /* tolerance: reduce's, as the fit action's (session_fit.c) */
    o.starts = 1;
    o.hops = 0;
    o.polish = 0; /* a ghost at the hand's pace: the polish's tenths of a millimetre wait for the fit action */
    o.global_check = 0; /* and so does the global check (it doubles a fit's CPU) */
    o.threads = 1; /* beside the real-time loop: one worker, at its lower priority */
    o.max_eval = SESSION_PREVIEW_EVALS;
    o.progress = on_progress;
    o.progress_ctx = pf;
    o.cancel = &s->prev_cancel;
    pf->sel = sel;
    atomic_store(&s->prev_cancel, 0);
    pose from = warm ? old.ghost : sc->pose[sel], out = from;
    reduce_result r;
    memset(&r, 0, sizeof r);
    int64_t t0 = fnclock_now_us();
    int rc = reduce_fit_one(others, n, &s->prev_frags[sel], &from, &o, &out, &r);
    double ms = (double)(fnclock_now_us() - t0) / 1000.0;
    double metric = r.metric_end;
    reduce_result_free(&r);
    loop_scene_read(s->L, &pf->sc);
    if (rc != 0 || !fresh(s, &pf->sc, sel, at)) {
        pthread_mutex_lock(&s->prev_mu);
        s->prev.dropped += rc >= 0; /* a failure (FN_E*) is not the hand's doing */
        pthread_mutex_unlock(&s->prev_mu);
        return 0;
    }
    session_preview p = {0};
    p.shown = 1;
    p.frag = sel;
    p.ghost = out;
    p.hand = at[sel];
    p.metric = metric;
    p.fit_ms = ms;
    double step_mm, step_deg;
    session__pose_change(&s->prev_frags[sel], &from, &out, &step_mm, &step_deg);
    p.converged = warm && step_mm < STILL_MM && step_deg < STILL_DEG;
    session__pose_change(&s->prev_frags[sel], &at[sel], &out, &p.moved_mm, &p.turned_deg);
    others[n] = &s->prev_frags[sel];
    publish(s, &p, at, reduce_tolerance(&o, others, n + 1));
    return !p.converged;
}

static void *preview_thread(void *arg)
{
    session *s = arg;
    /* The lowest share of the normal class (nice 19): the hand comes first, yet the ghost still
     * advances on a busy machine, where SCHED_IDLE starved it (two busy loops beside the suite: no
     * ghost in 30 s). Explicitly so: started by session_play's thread, which may be the loop's
     * under SCHED_FIFO (bench loop --realtime), it would share the loop's CPU and policy.
     * FRACNAV_PREVIEW_NICE (0..19) sets another share: the tests under ThreadSanitizer, beside
     * other tests on two cores, got no ghost in 150 s at 19. */
    const char *nice = getenv("FRACNAV_PREVIEW_NICE");
    loop_background_priority(nice && *nice ? atoi(nice) : 19);
    preview_fit pf = {.s = s};
    loop_scene sc = {0};
    int again = 1; /* the first look needs no publish */
    while (!atomic_load(&s->prev_stop)) {
        if (!again)
            while (sem_wait(&s->prev_wake) != 0 && errno == EINTR)
                ;
        while (sem_trywait(&s->prev_wake) == 0)
            ; /* one look serves every publish so far */
        if (atomic_load(&s->prev_stop))
            break;
        loop_scene_read(s->L, &sc);
        if (wanted(s, &sc)) {
            again = fit_once(s, &pf, &sc);
            continue;
        }
        again = 0;
        session_preview cur;
        session_preview_status(s, &cur);
        if (cur.shown) {
            cur.shown = 0;
            cur.converged = 0;
            publish(s, &cur, NULL, 0);
        }
    }
    return NULL;
}

int session__preview_start(session *s)
{
    if (s->preview_mode == SESSION_PREVIEW_OFF)
        return 0;
    atomic_store(&s->prev_stop, 0);
    while (sem_trywait(&s->prev_wake) == 0)
        ;
    if (pthread_create(&s->prev_th, NULL, preview_thread, s) != 0)
        return fn_err_set(FN_EIO, "cannot start the preview's worker thread");
    s->prev_joinable = 1;
    atomic_store(&s->prev_run, 1);
    return 0;
}

void session__preview_join(session *s)
{
    if (!s->prev_joinable)
        return;
    atomic_store(&s->prev_run, 0);
    atomic_store(&s->prev_stop, 1);
    atomic_store(&s->prev_cancel, 1);
    sem_post(&s->prev_wake);
    pthread_join(s->prev_th, NULL);
    s->prev_joinable = 0;
}

int session__preview_ghost(session *s, const loop_scene *sc, session_preview *p, double *tolerance_mm)
{
    pthread_mutex_lock(&s->prev_mu);
    *p = s->prev;
    int ok = p->shown && p->frag == sc->selected && fresh(s, sc, p->frag, s->prev_at);
    *tolerance_mm = s->prev_tolerance_mm;
    pthread_mutex_unlock(&s->prev_mu);
    return ok;
}

int session__preview_event(session *s, session_event *ev)
{
    const loop_scene *sc = &s->scene;
    if (sc->preview_requests != s->seen_previews) {
        unsigned presses = sc->preview_requests - s->seen_previews;
        s->seen_previews = sc->preview_requests;
        if (presses % 2 && s->preview_mode != SESSION_PREVIEW_OFF)
            atomic_store(&s->prev_asked, !atomic_load(&s->prev_asked));
        if (s->prev_joinable)
            sem_post(&s->prev_wake);
        ev->result = s->preview_mode == SESSION_PREVIEW_OFF ? FN_EINVAL : 0;
        snprintf(ev->text, sizeof ev->text, "%s",
                 ev->result < 0 ? "preview refused: this session has none"
                 : atomic_load(&s->prev_asked) ? "preview on"
                 : s->preview_mode == SESSION_PREVIEW_NEAR ? "preview near contact only"
                                                           : "preview off");
    } else {
        pthread_mutex_lock(&s->prev_mu);
        int news = s->prev.updates != s->previews_told;
        s->previews_told = s->prev.updates;
        pthread_mutex_unlock(&s->prev_mu);
        if (!news)
            return 0;
    }
    ev->kind = SESSION_EV_PREVIEW;
    session_preview_status(s, &ev->preview);
    return 1;
}
