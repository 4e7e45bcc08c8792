/* session internals shared by session.c (open, close, saves), session_run.c (threads, actions,
 * events) and session_json.c (machine output); not for other modules. Functions: session__. */
#ifndef FN_SESSION_IMPL_H
#define FN_SESSION_IMPL_H

#include "session.h"

#include "case.h"
#include "caselock.h"
#include "dev.h"
#include "journal.h"

#include <jansson.h>
#include <pthread.h>
#include <semaphore.h>
#include <stdatomic.h>

#define SESSION_QUEUE 128 /* events waiting for session_wait_event (full: the oldest is dropped) */

struct session {
    planning_case *c; /* NULL: session_open_fragments */
    const frag *frags;
    int nfrag;
    double tau[2];
    double fit_gap_mm; /* session_params' */
    loop_obb *obb;
    json_t *penetrating; /* at the last save */
    loop *L;
    journal *jr;
    size_t resumed; /* journal records applied at open */
    char dir[4096];

    ring *in, *ctl;         /* the reader's events; actions, saves and proposals from clients */
    pthread_mutex_t push_mu; /* ctl has one producer at a time */
    pthread_mutex_t frag_mu; /* the case's fragments: a save writes their poses while the
                              * preview's worker copies them */
    pose saved[LOOP_MAX_FRAGS]; /* the poses of the last save while running (loop_set_saved) */
    loop_reader *rd;
    pthread_t th;
    int built; /* the mutex and semaphore exist */
    atomic_int running; /* read by senders on any thread */
    int loop_rc, ended;
    atomic_int stop;
    sem_t wake; /* posted at every publish */
    session_dsource *led; /* session_drive_led's: told after every scene */
    void (*wakeup)(void *ctx);
    void *wakeup_ctx;

    /* Events are derived from the scenes by the event thread while the session runs (by the
     * owner's thread when it does not): saves and fits happen there, whoever waits. */
    pthread_t ev_th;
    int ev_running;       /* owner's thread */
    atomic_int ev_stop;
    atomic_uint kinds;
    loop_scene scene; /* the newest scene the deriving thread read */
    uint64_t seen_seq;
    unsigned seen_actions, seen_saves;
    int end_told;
    uint64_t derived_proposals;    /* proposals whose event was derived */
    uint64_t proposed;             /* under push_mu */
    atomic_ullong seen_proposals;  /* proposals whose event the client took (or was dropped) */
    int proposal_frag[LOOP_PROPOSALS_KEPT]; /* under push_mu */
    pthread_mutex_t ev_mu;         /* guards the queue and the pending scene */
    sem_t ev_ready;                /* posted when an event is queued */
    session_event queue[SESSION_QUEUE];
    int qhead, qn;
    session_event scene_ev; /* the newest SESSION_EV_SCENE, given when the queue is empty */
    int scene_pending;

    /* the reduction worker (session_fit.c) */
    pthread_t fit_th;
    int fit_joinable;      /* owner's thread */
    atomic_int fit_cancel;
    pthread_mutex_t fit_mu; /* guards fit */
    session_fit fit;
    unsigned seen_fits;    /* the scene's fit_requests handled */
    unsigned fits_told;    /* fits finished whose event was derived */
    int fit_sel;           /* the worker's fragment, and its copies of the fragments at the */
    pose fit_start;        /* scene's poses (struct copies sharing the voxels) */
    frag fit_frags[LOOP_MAX_FRAGS];
    char fit_why[256];     /* a failed fit's message (under fit_mu) */
    pose fit_out;          /* the finished fit's pose (under fit_mu) */
    double fit_tolerance_mm; /* the collision tolerance the fit checked it at (under fit_mu) */

    /* the live preview (session_preview.c) */
    int preview_mode;       /* SESSION_PREVIEW_* */
    pthread_t prev_th;
    atomic_int prev_joinable; /* written on the owner's thread, read on the event thread too (which
                               * starts before the worker) */
    sem_t prev_wake;        /* posted at every publish while the worker runs */
    atomic_int prev_run;    /* the worker runs (on_publish posts prev_wake) */
    atomic_int prev_stop, prev_cancel, prev_asked;
    pthread_mutex_t prev_mu; /* guards prev, prev_at, prev_tolerance_mm */
    session_preview prev;
    pose prev_at[LOOP_MAX_FRAGS]; /* every fragment's pose when the ghost's fit began */
    double prev_tolerance_mm;
    unsigned seen_previews, seen_accepts; /* the scene's preview and accept requests handled */
    unsigned previews_told;  /* prev.updates whose event was derived */
    frag prev_frags[LOOP_MAX_FRAGS]; /* the worker's copies (sharing the voxels) */
};

/* Frees everything session_open built (no thread may run). */
void session__free(session *s);

/* LOOP_ACT_FIT seen in the scene: starts the worker on the selected fragment, or says why not;
 * fills ev (SESSION_EV_FIT). The deriving thread (the event thread, or the owner's). */
void session__fit_start(session *s, session_event *ev);
/* A fit that finished since the last call: fills ev (SESSION_EV_FIT), *fitted (its pose, to
 * propose when ev->result is 0) and *tolerance_mm (the collision tolerance it was checked at) and
 * returns 1; else 0. */
int session__fit_finished(session *s, session_event *ev, pose *fitted, double *tolerance_mm);
/* session_propose_pose with the tolerance its proposer checked the pose at (loop_event). */
int session__propose(session *s, int fragment, const pose *p, double tolerance_mm, uint64_t *id);
/* Cancels a running fit and joins the worker. Owner's thread. */
void session__fit_join(session *s);

/* How far b moves frag f's centroid from where a put it (mm), and the angle between them (deg). */
void session__pose_change(const frag *f, const pose *a, const pose *b, double *mm, double *deg);
/* Starts the preview's worker (mode not OFF) or does nothing. session_start. 0 or FN_E*. */
int session__preview_start(session *s);
/* Stops the preview's worker and joins it. Owner's thread. */
void session__preview_join(session *s);
/* The preview's next event, if any: a key's toggle, a new ghost. 1 when ev was filled. Owner's
 * thread, s->scene the newest. */
int session__preview_event(session *s, session_event *ev);
/* The ghost (*p) and the tolerance its fit checked it at; 1 when it is fresh for sc (its fragment
 * selected and where the fit began, within the stale limits). Any thread. */
int session__preview_ghost(session *s, const loop_scene *sc, session_preview *p, double *tolerance_mm);

/* Tells ds whether the selected fragment can move (session_drive_led's push). Any thread. */
void session__led_movable(session_dsource *ds, int movable);

#endif
