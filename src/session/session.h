/* session: the navigation session, a library in mpv's manner. One handle holds a case opened for
 * steering -- fragments, OBB collider, loop, journal, recovery -- and runs it from an event source
 * (a device, a recording, the virtual device); clients send actions, propose poses, read scenes
 * and wait on events. `fracnav navigate`, `replay` and `bench loop`, the window and the reduction
 * worker are its clients; the terminal view (navview) is one of its views.
 *
 * Life: session_open (or session_open_fragments) -> session_start (threads) or session_play (the
 * caller's thread) with a loop_source -> session_wait_event / session_send_action /
 * session_propose_pose / session_scene_read -> session_stop -> session_save -> session_close.
 *
 * Threads. session_start runs the source's reader thread, the loop thread (loop_run, under
 * real-time priority when granted) and the session's event thread. Then:
 *  - session_send_action, session_propose_pose and session_scene_read may be called from any
 *    thread, several at once;
 *  - session_wait_event, session_ended and session_stop from one client thread (the one that
 *    owns the handle), never two at once;
 *  - the event thread carries out save requests (LOOP_ACT_SAVE, a button or a key), starts fits
 *    (LOOP_ACT_FIT) and proposes an accepted preview (LOOP_ACT_ACCEPT) as they come, whether or
 *    not the client waits, and queues their events; while it runs, the case (session_case) is its
 *    to write: read it before session_start or after session_stop;
 *  - the wake-up callback (session_set_wakeup) runs on the loop thread, the event thread, the fit
 *    worker's or the live preview's;
 *  - a fit runs on a worker thread of the session's own, the live preview's fits on another
 *    (session_set_preview).
 * Everything else (open, play, save, close, the JSON helpers) belongs to the owner's thread while
 * no loop thread runs.
 *
 * Errors: functions return 0 or a negative FN_E* (err.h) with fn_err_msg() naming the cause (the
 * file, the journal record, the option); constructors return NULL with fn_err set.
 *
 * Ownership: the session owns its case, collider, loop, journal and rings; a loop_source's
 * context stays the caller's and must outlive session_stop. Pointers it returns (session_case,
 * session_frags) live until session_close. */
#ifndef FN_SESSION_H
#define FN_SESSION_H

/* The session's API is made of these: its errors are err.h's (FN_E*, fn_err_msg), its times
 * fnclock's, a source reads through a calibration (calib.h), it runs a loop (loop.h: its
 * configuration, actions and scenes) over a case (case.h: what the window draws). Its clients
 * include nothing else of the layers below. */
#include "calib.h"
#include "case.h"
#include "err.h"
#include "fnclock.h"
#include "loop.h"

#include <stdio.h>

struct json_t; /* jansson's */
/* The lower layers' handles that pass through the session's API without clients looking in. */
typedef struct dev_device dev_device; /* dev.h */
typedef struct dev_transport dev_transport;
typedef struct dev_handle dev_handle;
typedef struct caselock caselock;     /* caselock.h */

typedef struct session session;

enum {
    SESSION_JOURNAL = 1, /* append accepted poses to CASE/journal */
    SESSION_RESUME = 2,  /* start from case.json + the journal's unsaved poses */
    SESSION_DISCARD = 4  /* start from case.json, emptying the journal */
};

/* What session_open needs beyond the case folder. */
typedef struct session_params {
    loop_config cfg;
    unsigned flags;      /* SESSION_* */
    const char *command; /* names the command in advice ("run `fracnav navigate` with --recover") */
    /* NULL, or called with the loaded case before its collider is built (e.g. the CLI's
     * --tau-min/--tau-max over the case's, which a save then keeps). 0 or FN_E*. */
    int (*prepare)(void *ctx, planning_case *c);
    void *prepare_ctx;
    double fit_gap_mm; /* the fit action leaves this gap at the cut (reduce_opts.gap_mm; 0: none) */
} session_params;

/* ---- around a session: what a command needs before it opens one ---- */

/* The loop's defaults (loop_config_default), for session_params.cfg. */
void session_config_default(loop_config *cfg);
/* The motion frame a name gives (--frame): camera, world or fragment. 0, or FN_EINVAL with fn_err
 * "--frame NAME: use camera, world or fragment". */
int session_frame_parse(const char *name, loop_frame *out);
/* The calibration a command's source reads through (session_source_open), loaded as every command
 * loads it (calib_setup): the defaults, then the file config, else (unless named_only) the user's
 * ~/.config/fracnav/spnavrc; bad lines are said on stderr, "WHO: N bad line(s) skipped: ...".
 * 0, or negative with fn_err naming the file that cannot be read. */
int session_calib_setup(calib *cal, const char *config, int named_only, const char *who);
/* The case's lock (caselock_take: exclusive for a command that writes the case; wait: for another
 * holder), held for as long as the command steers it, across its sessions (navigate opens one again
 * after a separation in the window): a second writer is refused, and the journal the session keeps
 * is never taken for an interrupted one. NULL after printing "fracnav COMMAND: why" on stderr. */
caselock *session_lock_case(const char *command, const char *dir, int exclusive, int wait);
/* Releases it (NULL: nothing). */
void session_unlock(caselock *lock);

/* Loads the case, reconciles its journal (case_journal_check: damage and journals of another case
 * state are kept aside, never applied) and builds everything. A journal holding unsaved poses
 * without SESSION_RESUME or SESSION_DISCARD is an error (FN_EMISMATCH) whose message says how many
 * and what to do; SESSION_RESUME with a journal that was refused is an error too. The case needs
 * 2..LOOP_MAX_FRAGS fragments. NULL with fn_err. */
session *session_open(const char *dir, const session_params *p);
/* A session over fragments without a case (benchmarks): no journal, nothing to save (session_save
 * says so). frags (n of them) must outlive the session; fixed: n flags or NULL; tau: {min, max}
 * of the hierarchy. NULL with fn_err. */
session *session_open_fragments(const frag *frags, int n, const uint8_t *fixed, const double tau[2],
                                const loop_config *cfg);
/* Stops what runs (session_stop) and frees everything. NULL is fine. */
void session_close(session *s);

/* Unsaved records in DIR/journal that extend DIR/case.json (0 when none, unreadable, damaged or
 * bound to another case state): what session_open would need SESSION_RESUME or SESSION_DISCARD for. */
size_t session_journal_pending(const char *dir);

/* The case (NULL for session_open_fragments), its fragments and their number, the journal
 * records applied at open, the case folder ("" without a case). Valid until session_close. */
planning_case *session_case(session *s);
const frag *session_frags(const session *s);
int session_nfrag(const session *s);
size_t session_resumed(const session *s);
const char *session_dir(const session *s);

/* A pivot for the selected fragment's rotations (loop_set_pivot: world mm; NULL: its centroid),
 * and the loop's statistics (loop_get_stats). While the loop does not run. */
void session_set_pivot(session *s, const double world[3]);
void session_stats(session *s, loop_stats *out);
/* Marks fragment i as inside another by no more than a fit's tolerance_mm (loop_tolerate: a plan
 * that fracnav reduce left so), then measures the selected fragment where it stands, as opening a
 * reduced case does (loop_measure). Before the loop runs. 0 or the collider's error. */
int session_tolerate(session *s, int i, double tolerance_mm);
/* Fragment i's pose and the selected fragment, now: while the loop does not run, or from
 * session_play_each's callback. */
pose session_pose(const session *s, int i);
int session_selected(const session *s);

/* ---- running ---- */

enum {
    SESSION_PLAY_FAST = 0,     /* the caller's thread reads and steps, as fast as the source gives */
    SESSION_PLAY_REALTIME = 1, /* reader thread -> ring -> loop_run on the caller's thread */
    SESSION_PLAY_LOCKSTEP = 2  /* as REALTIME, the reader waiting for each event to be stepped
                                * (benchmarks: no queueing in the latency) */
};
/* Runs src through the loop on the calling thread until it ends (LOOP_SOURCE_END), then returns:
 * replay and benchmarks. REALTIME and LOCKSTEP run the live preview's worker beside it when
 * session_set_preview asked for one (bench loop --preview; its ghosts are not accepted). 0 or the
 * first source or collider error. */
int session_play(session *s, loop_source src, int mode);

/* As session_play(SESSION_PLAY_FAST) on the calling thread, calling each(ctx, t_us) before every
 * event is stepped (t_us: its time) and once after the end (t_us < 0): e.g. pictures of the poses
 * (session_pose) at a recording's times. A negative return stops the play with it. 0 or the
 * first error. */
int session_play_each(session *s, loop_source src, int (*each)(void *ctx, int64_t t_us), void *ctx);

/* Starts the reader thread on src, the loop thread and the event thread (the loop's rate and
 * latency windows restarted, as session_play does); returns at once. 0 or FN_E*. */
int session_start(session *s, loop_source src);
/* 1 once a started source has ended (all its events are in the loop's ring). Owner's thread. */
int session_ended(session *s);
/* Stops the reader and the loop thread (the loop steps what was already read), publishes the
 * last scene and carries out save requests not yet carried out (their SESSION_EV_SAVED events
 * wait for session_wait_event). Returns 0 or the loop thread's first collider error. Not running:
 * 0. Owner's thread. */
int session_stop(session *s);

/* Sends an action, as a key or a button does (LOOP_ACT_*), to the running loop. Any thread.
 * 0, FN_EINVAL for an action out of range, FN_EAGAIN when the control queue is full (the loop
 * is far behind) or the loop is not running. */
int session_send_action(session *s, loop_action a);
/* The action of a terminal key (n p f c t r u y m s g v b, ? and h for help), LOOP_ACT_NONE for other
 * keys: what the terminal and the window send for the same key. q (quit) is the client's. */
loop_action session_key_action(int ch);

/* Proposes that fragment frag move to pose p (home world -> current world), from any thread (the
 * reduction worker). It lands through the loop thread as one step of its own: accepted whole,
 * journaled and one undo step, or refused when it collides while checking is on (or the fragment
 * is fixed). *id (may be NULL) gets the proposal's number, which its SESSION_EV_POSE event
 * carries. 0, FN_EINVAL (frag out of range), FN_EAGAIN (not running, or LOOP_PROPOSALS_KEPT - 8
 * proposals await their events: wait on events first). One sent while session_stop runs may be
 * dropped without an event. */
int session_propose_pose(session *s, int fragment, const pose *p, uint64_t *id);

/* ---- scenes and events ---- */

/* The newest scene (loop_scene_read). Any thread. 1 when its seq differs from out's on entry. */
int session_scene_read(session *s, loop_scene *out);
/* The camera frame of the device's motion (loop_set_camera: the view's right, up and forward in
 * world coordinates), so that "push right" moves the fragment right on screen. Any thread. */
void session_set_camera(session *s, const double right[3], const double up[3], const double forward[3]);

typedef enum {
    SESSION_EV_NONE = 0,   /* the wait timed out */
    SESSION_EV_SCENE = 1,  /* a new scene was published (only when subscribed: session_subscribe) */
    SESSION_EV_ACTION = 2, /* an action was done: action, result (several between two waits: the
                            * latest, count = how many) */
    SESSION_EV_SAVED = 4,  /* a save request was carried out: result 0 or FN_E*, text "saved DIR"
                            * or the error's message */
    SESSION_EV_POSE = 8,   /* a proposal landed: id, frag, result LOOP_ACCEPTED or LOOP_REFUSED */
    SESSION_EV_END = 16,   /* the source ended (a recording played out); once */
    SESSION_EV_FIT = 32,   /* a fit (LOOP_ACT_FIT) started, was refused, or finished: fit, result
                            * (started: 0; refused or failed: FN_E*; cancelled: 1), text */
    SESSION_EV_PREVIEW = 64 /* the live preview changed: a new ghost, the ghost gone, the preview
                            * asked on or off (LOOP_ACT_PREVIEW), or an accept (LOOP_ACT_ACCEPT:
                            * result 0, its pose proposed: a SESSION_EV_POSE follows; FN_E*
                            * refused); preview, text */
} session_event_kind;

/* The reduction worker's state (session_fit_status; SESSION_EV_FIT events carry it). */
typedef struct session_fit {
    int running;           /* 1 while the worker fits */
    int frag;              /* the fragment being (or last) fitted; -1 before the first fit */
    int iterations, evaluations;
    double metric_start, metric; /* the VOI metric (reduce.h; lower is better) at the start and now */
    double seconds;        /* since the fit started */
    int result;            /* once finished: 0 fitted (its pose proposed: a SESSION_EV_POSE
                            * follows), 1 cancelled, FN_E* failed (text says why) */
    double moved_mm, turned_deg; /* finished: how far the fit moves the centroid, and turns */
    unsigned finished;     /* fits finished so far */
} session_fit;

/* The live preview's state (session_preview_status; SESSION_EV_PREVIEW events carry it). */
typedef struct session_preview {
    int asked;             /* 1: on by LOOP_ACT_PREVIEW, whether near or not */
    int shown;             /* 1: a ghost for the selected fragment where the hand holds it now */
    int frag;              /* the ghost's fragment (-1: none yet) */
    pose ghost;            /* where the fit puts it (home world -> world) */
    pose hand;             /* the hand's pose it was fitted from */
    double moved_mm, turned_deg; /* from the hand to the ghost: centroid distance, rotation */
    double metric;         /* the VOI metric at the ghost (reduce.h; lower is better) */
    int converged;         /* 1: a fit from the ghost no longer moves it: no more fits until
                            * the hand or another fragment moves */
    double fit_ms;         /* the last fit's wall time */
    unsigned updates;      /* ghosts published so far */
    unsigned dropped;      /* fits dropped because the hand moved on while they ran */
} session_preview;

typedef struct session_event {
    session_event_kind kind;
    loop_action action; /* ACTION */
    int result;         /* ACTION: loop_action_do's; SAVED: 0 or FN_E*; POSE: loop_outcome */
    unsigned count;     /* ACTION: actions done since the previous ACTION event */
    uint64_t id;        /* POSE: session_propose_pose's id */
    int frag;           /* POSE: the fragment */
    char text[1100];    /* SAVED, FIT */
    session_fit fit;    /* FIT */
    session_preview preview; /* PREVIEW */
    loop_scene scene;   /* every event: the scene it was seen in (SAVED: the one saved) */
} session_event;

/* The event kinds session_wait_event returns (an OR of SESSION_EV_*; others are dropped, save
 * requests are carried out all the same). The default: all but SESSION_EV_SCENE. Any thread. */
void session_subscribe(session *s, unsigned kinds);
/* Waits up to timeout_ms (0: does not wait, < 0: no limit) for the next event, into ev; returns
 * its kind, SESSION_EV_NONE on timeout. Events wait in a queue of 128 in order
 * (actions in a row merged into one, scenes into the newest); when it is full the oldest is
 * dropped, so a client that never waits loses events but no save or fit. Without a running
 * session (session_play, after session_stop) the events of the last scene are derived here, and
 * its save requests carried out. Owner's thread. */
session_event_kind session_wait_event(session *s, int timeout_ms, session_event *ev);
/* fn(ctx) is called on the loop thread whenever a scene is published, on the event thread when
 * events were queued, on the fit worker's thread when a fit ends and on the preview's when its
 * ghost changes: for a client with its own event loop (glfwPostEmptyEvent). It must return at
 * once. NULL: none.
 * Before session_start. */
void session_set_wakeup(session *s, void (*fn)(void *ctx), void *ctx);

/* ---- the reduction worker ---- */

/* LOOP_ACT_FIT (the key g, loop button 12, bindable with spnavrc's bnmapN like the other
 * actions) fits the selected fragment to all the others where they are now, from where the hand
 * left it (reduce_fit_one: no pre-alignment), on a thread of its own, while the loop runs on.
 * The fitted pose then lands through the loop as one proposal (session_propose_pose): accepted
 * and journaled as one undo step, so undo takes it back to the hand-placed pose; refused when it
 * collides (it never should: the fit keeps clear of the others). One fit at a time; a fixed or
 * lone fragment is refused with a SESSION_EV_FIT that says why. session_stop cancels a running
 * fit. The request is seen, and the worker started, by the session's event thread. */

/* The worker's state now (any thread). */
void session_fit_status(session *s, session_fit *out);

/* ---- the live preview ---- */

/* While the selected movable fragment is near another (a gap of at most SESSION_PREVIEW_NEAR_MM,
 * collision checking on; not the largest when no fragment is fixed: the one reduce keeps) or the
 * preview is asked on (LOOP_ACT_PREVIEW: the key v, loop button
 * 13), a worker thread of its own, at the lowest normal priority (nice 19), keeps fitting it
 * (reduce_fit_one, a cheap fit: one start, no hops, SESSION_PREVIEW_EVALS evaluations) from where
 * the hand holds it, then again from its own result while the hand holds still, until a fit no
 * longer moves it. Each result is the ghost (session_preview_status, SESSION_EV_PREVIEW); a fit
 * that the hand (or an action) has made stale -- the fragment moved over 0.5 mm or 0.5 degree
 * from where the fit began, another one moved, another selected -- is cancelled and dropped. The
 * worker reads the loop's scenes (lock-free) and works on copies; the loop thread only posts its
 * semaphore at each publish. LOOP_ACT_ACCEPT (the key b, loop button 14) proposes the ghost's
 * pose as the fit action's does (session_propose_pose at the fit's tolerance): one journaled
 * move, one undo step. */
#define SESSION_PREVIEW_NEAR_MM 3.0
#define SESSION_PREVIEW_EVALS 200
enum {
    SESSION_PREVIEW_OFF = 0,  /* no worker (the default; LOOP_ACT_PREVIEW is refused) */
    SESSION_PREVIEW_NEAR = 1, /* near contact, or asked */
    SESSION_PREVIEW_ASKED = 2 /* only when asked (LOOP_ACT_PREVIEW) */
};
/* The preview's mode (SESSION_PREVIEW_*). Before session_start or session_play. */
void session_set_preview(session *s, int mode);
/* The preview's state now (any thread). */
void session_preview_status(session *s, session_preview *out);
/* What the views show of p (the terminal's line, the window's HUD): "preview of frag 2: 1.20 mm,
 * 3.40 deg away (b accepts)", "... fitting" before it converges, "preview on: fitting" while asked
 * with no ghost yet; "" when there is nothing to show. */
void session_preview_text(const session_preview *p, char *buf, size_t cap);

/* ---- saving ---- */

/* Copies the loop's poses and fixed fragments into the case, saves it atomically, then empties
 * the journal. The loop must not be running (after session_stop or session_play). 0 or FN_E*. */
int session_save(session *s);
/* Saves the case with these poses and fixed flags (nfrag of each; a scene's, while the loop runs)
 * and binds the journal to the new case.json. Fragments that interpenetrate (collision checking
 * was off) are not refused but said: a warning on stderr naming them and their overlap,
 * session_penetrating for --json, and case.json's "penetrating" member (absent when none) for
 * later commands. case.json records every fixed fragment (case_set_fixed: the case's own first
 * while it stays fixed). Owner's thread. 0 or FN_E*. */
int session_save_case(session *s, const pose *poses, const uint8_t *fixed);
/* At the last save: [{"fragments": [A, B], "overlap_ml": V}, ...]; NULL before any save. Owned
 * by the session. */
struct json_t *session_penetrating(const session *s);
/* Writes out the journal's buffered records and fsyncs it (no journal: 0). Loop not running. */
int session_journal_sync(session *s);
/* Empties the journal (no journal: 0). Loop not running. */
int session_journal_truncate(session *s);

/* ---- machine output ---- */

/* Final poses and statistics as the JSON object of `command` (replay's and navigate's summary;
 * the members are listed in `fracnav replay --help`) on out; unplugs < 0: null (not counted).
 * skipped: reports of an unknown ID or a wrong length that the parser skipped. 0 or FN_E*. */
int session_print_json(session *s, FILE *out, const char *command, long unplugs, uint64_t skipped);
/* The loop statistics' members of that object (bench loop's too), labelled `command`; NULL when
 * out of memory. */
struct json_t *session_stats_json(const char *command, const loop_stats *st);

/* ---- event sources ---- */

/* A loop_source over an opened device d (the source owns it: session_dsource_free closes it),
 * through cal (NULL: the default calibration): dev_poll reads it as its mode says (dev_set_mode:
 * a live device's queued reports folded into one event, a recording's one event per report). On
 * its (input) thread it also drives the LED -- lit while a fragment is held: the cap deflected with a movable fragment
 * selected (the session pushes which: session_drive_led; the `led` setting can force it on or
 * off) -- and publishes for the view the battery level and, while another controller sits at the
 * device's path, why it was not taken (dev_poll's DEV_EV_REFUSED). It never reads the loop. NULL
 * with fn_err (d closed) when out of memory. */
typedef struct session_dsource session_dsource;
session_dsource *session_dsource_new(dev_device *d, const calib *cal);
/* The same over a recording: an open handle h of a recording transport tr (e.g. sim's replay),
 * read by dev_poll in DEV_RECORDED mode (one event per report, the recorded unplugs and replugs,
 * the end of the source when it played out). With again set, the end opens tr at again once more
 * and plays it from the start (navigate --loop; DEV_RECORDED_LOOP): the loop gets LOOP_EV_REPLUG,
 * so the recording's clock starting over is no jump (a recording in memory: bench loop, the
 * tests). The source owns h from here. NULL with fn_err (h closed). */
session_dsource *session_recording_new(const dev_transport *tr, dev_handle *h, const calib *cal,
                                       const char *again);
/* Turns a live device's LED off, closes the device and frees ds. NULL is fine. */
void session_dsource_free(session_dsource *ds);
loop_source session_device_source(session_dsource *ds);
/* Opens the event source a --device spec names (dev_open's specs): a recording (a transport that
 * plays one, e.g. replay:FILE, replay-realtime:FILE) read one report per event (DEV_RECORDED; with
 * again, played again from its start at its end: DEV_RECORDED_LOOP), or a live device, its
 * queued reports folded (DEV_LIVE), both through cal (NULL: the default calibration). Sets cfg's
 * button actions for the device (loop_config_actions_at at its key-1 button, its transport's
 * help button). NULL with fn_err naming the spec and the cause. */
session_dsource *session_source_open(const char *spec, const calib *cal, int again, loop_config *cfg);
/* 1 when spec names a recording (a transport that plays one and resolves), else 0. */
int session_spec_recording(const char *spec);
/* 1 when the source plays a recording (session_source_open's); 1 when it reads the terminal's
 * keys (the keyboard: its keys are the help); the device's name ("?" unknown). */
int session_source_recording(const session_dsource *ds);
int session_source_keyboard(const session_dsource *ds);
const char *session_source_name(const session_dsource *ds);
/* For the summary, once the source stopped: unplugs read so far (a recording's), reports skipped
 * (an unknown ID or a wrong length); plays begun after the first (any thread). */
unsigned session_source_unplugs(const session_dsource *ds);
uint64_t session_source_skipped(const session_dsource *ds);
unsigned session_source_plays(session_dsource *ds);
/* Keys typed elsewhere (a window) for a source that reads keys (dev_feed_keys). Any thread. */
int session_source_feed_keys(session_dsource *ds, const char *bytes, size_t n);
/* The battery level, 0..100, -1 unknown (any thread). */
int session_dsource_battery(session_dsource *ds);
/* 1 while the selected fragment can move, as the session last said (session_drive_led; 1 until
 * then): the LED lights while the cap is deflected and this holds. Any thread. */
int session_dsource_movable(session_dsource *ds);
/* Copies the refusal's message (any thread); 0 when there is none. */
int session_dsource_refused(session_dsource *ds, char *out, size_t cap);
/* After every scene, s tells ds whether its selected fragment can move (for ds's LED). Before
 * session_start; ds must outlive session_stop. NULL: none. */
void session_drive_led(session *s, session_dsource *ds);

#endif
