/* loop: the real-time navigation loop. Device motion in, collision-checked fragment poses out.
 *
 * Events (device motion already calibrated by the input side -- devices' calib_apply --, buttons,
 * unplug/replug) arrive through a ring (ring.h) filled by an input thread (loop_reader_*), or are
 * fed one by one (loop_feed) for deterministic replay.
 * Each motion event is one step:
 *   twist   = motion * (trans_mm_s, rot_deg_s), mapped from device axes to the world through the
 *             frame (camera by default, world or fragment on request), translation/rotation locks;
 *   dt      = report time since the previous report (dt_first_us for the first one), clamped to
 *             dt_max_us (a pause never jumps);
 *   candidate = rotate the selected fragment by twist.w*dt about its pivot (the centroid, or a
 *             user pivot), then translate by twist.v*dt;
 *   query   = the collider against every other fragment (per-pair caches);
 *   outcome = ACCEPTED (free), LIMITED (largest free fraction of the step, by bisection), SLID
 *             (limited, then the rest of the step split into translation alone, rotation alone
 *             and each world axis of the translation, each advanced as far as it stays free, and
 *             on a rough contact the tangential part once more with a small back-off from the
 *             push: the fragment slides along the contact instead of freezing), or REFUSED
 *             (nothing of the step is free). A step queries at most max_tries candidate poses;
 *             the separation estimate of the last query skips queries for moves that provably
 *             stay clear.
 * No accepted pose collides; with check_invariant every accepted pose is re-queried from scratch
 * (no cache, no shortcuts) and a collision is counted in collisions_in_accepted (always 0).
 * With collision checking off, poses are accepted unchecked (counted in `unchecked`). Turned back
 * on, the selected fragment is queried at once; while it interpenetrates another the scene says
 * so (penetrating, separation_mm < 0) and a move is accepted only when it frees the fragment or
 * does not deepen the overlap (the collider's overlap volume, else its penetration estimate;
 * counted in `escaping`, those poses are not invariant-checked), else refused; once free,
 * normal checking resumes.
 * Stepping depends only on event contents and report timestamps, never on the wall clock, so the
 * same events give the same poses bit for bit (pose_digest).
 *
 * Frames. Device axes are the HID ones: +x right, +y towards the user, +z down. The default camera
 * stands in front of the patient looking posteriorly (along world +y, LPS), patient superior (+z)
 * up on screen and patient left (+x) to the right: device x -> world +x, device y (towards the
 * user = towards the viewer) -> world -y, device z (down) -> world -z.
 * World frame: device axes are world LPS axes. Fragment frame: device axes are the fragment's
 * current local axes.
 *
 * Controls are actions (from keys or mapped device buttons): next/prev fragment, fix/unfix the
 * selected fragment, collision checking on/off (the scene carries the warning flag), translation-
 * only and rotation-only toggles, undo/redo of whole gestures (a gesture ends when the device
 * returns to rest or the selection changes), save request.
 *
 * A pose proposal (LOOP_EV_POSE, e.g. from the reduction worker through the control ring) moves
 * one movable fragment to a given pose as one step of its own: with checking on it is queried
 * there and refused when it collides (or the fragment is fixed, or out of range). A proposer may
 * give a tolerance of its own (tolerance_mm > 0: the reduction's fit, whose voxel surfaces
 * interlock at the loop's tolerance 0, so that a fit within tenths of a millimetre of the truth
 * touches inside by a fraction of a voxel): the pose is then queried at that tolerance, and one
 * inside another at 0 but free at it is accepted as `tolerated` (counted so; the scene's
 * `tolerated` until the fragment moves). The fragment then holds that tolerance: its pairs are
 * queried at it, so the moves after it are checked, limited and slid as usual but may not go
 * deeper than the fit's tolerance, at the cost of an ordinary query; once it stands free at 0
 * (queried where it rests) the hold ends. Accepted, a proposal is journaled (JOURNAL_START) and
 * one undo step, apart from the gestures before and after it; undo and redo give a pose back the
 * tolerance it was left with. Its result is in the scene (proposals, proposal_result); it is not
 * a motion step (not in steps).
 *
 * Threads and memory: loop_new allocates everything; loop_feed, loop_drain and loop_run allocate
 * nothing. One thread steps a loop; renderers read it through loop_scene_read from any number of
 * threads at once without ever blocking the stepping thread (pinned scene buffers, lock-free). */
#ifndef FN_LOOP_H
#define FN_LOOP_H

#include "frag.h"
#include "pose.h"
#include "ring.h"

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#define LOOP_MAX_FRAGS 64

typedef enum { LOOP_FRAME_CAMERA, LOOP_FRAME_WORLD, LOOP_FRAME_FRAGMENT } loop_frame;

enum { LOOP_EV_MOTION = 1, LOOP_EV_ACTION, LOOP_EV_UNPLUG, LOOP_EV_REPLUG, LOOP_EV_SAVED, LOOP_EV_POSE };

/* Results of the latest LOOP_EV_POSE proposals the scene keeps (by proposal number). */
#define LOOP_PROPOSALS_KEPT 64

typedef enum {
    LOOP_ACT_NONE,
    LOOP_ACT_NEXT,       /* select the next movable fragment */
    LOOP_ACT_PREV,
    LOOP_ACT_FIX,        /* fix/unfix the selected fragment (journaled; an undo step) */
    LOOP_ACT_COLLISION,  /* collision checking on/off */
    LOOP_ACT_TRANS_ONLY, /* toggle: translation only */
    LOOP_ACT_ROT_ONLY,   /* toggle: rotation only */
    LOOP_ACT_UNDO,
    LOOP_ACT_REDO,
    LOOP_ACT_SAVE,       /* counts in the scene's save_requests; the application saves */
    LOOP_ACT_FRAME,      /* cycle camera -> world -> fragment frame */
    LOOP_ACT_HELP,       /* show or hide the keys: the application's view (the scene's last_action) */
    LOOP_ACT_FIT,        /* fit the selected fragment to the others: counts in the scene's
                          * fit_requests; the application's reduction worker fits (session.h) */
    LOOP_ACT_PREVIEW,    /* the live preview of the fit on/off: counts in preview_requests */
    LOOP_ACT_ACCEPT,     /* move the selected fragment to the preview's ghost: counts in
                          * accept_requests; the application proposes the pose (session.h) */
    LOOP_ACT_COUNT
} loop_action;

typedef enum { LOOP_IDLE, LOOP_ACCEPTED, LOOP_LIMITED, LOOP_SLID, LOOP_REFUSED } loop_outcome;

/* One ring item. */
typedef struct loop_event {
    int64_t t_us;       /* report timestamp: device clock (monotonic live, recorded on replay) */
    int64_t arrival_us; /* monotonic time fracnav read the report; the latency's start; 0 = none */
    int32_t kind;       /* LOOP_EV_* */
    int32_t action;     /* LOOP_EV_ACTION: a loop_action */
    uint32_t buttons;   /* LOOP_EV_MOTION: button state; new presses map through button_action */
    float motion[6];    /* LOOP_EV_MOTION: calibrated, -1..1: tx ty tz rx ry rz, device axes */
    int32_t frag;       /* LOOP_EV_POSE: the fragment (0-based) proposed to move to pose */
    pose pose;          /* LOOP_EV_POSE: home world -> current world */
    double tolerance_mm; /* LOOP_EV_POSE: > 0: the proposer found the pose free at this collision
                          * tolerance (the loop's is 0); 0: the loop's query decides */
} loop_event;

/* Result of one pair query. */
typedef struct loop_contact {
    int collides;
    double separation_mm; /* > 0: a lower bound on the gap; <= 0 touching or penetrating */
    int searched; /* 1: the query searched from scratch, its cache of no use (for statistics) */
} loop_contact;

/* The collision seam: a table the application fills (loop_obb.c wraps the OBB octree). */
typedef struct loop_collider {
    /* Fragment a at pose pa (home world -> current world) against b at pb, each voxel shrunk by
     * tolerance_mm (0: the loop's own; > 0: a fit's, while the pair stands where a fit left it).
     * cache is cache_bytes of memory for this ordered pair, zeroed whenever it held another
     * pair's (the loop keeps one per fragment b, for the last fragment moved against it), or NULL.
     * Returns 0 or a negative FN_E*. Must not allocate; called only from the stepping thread. */
    int (*query)(void *ctx, int a, const pose *pa, int b, const pose *pb, double tolerance_mm,
                 void *cache, loop_contact *out);
    size_t cache_bytes;
    void *ctx;
    /* Optional (NULL: the query's penetration estimate stands in): an estimate of the volume (mm^3)
     * in which a at pa and b at pb overlap; 0 when apart. Used only while a fragment is inside
     * another, so it may cost more than a query. Stepping thread only. */
    int (*overlap)(void *ctx, int a, const pose *pa, int b, const pose *pb, double *mm3);
} loop_collider;

typedef struct loop_config {
    double trans_mm_s;      /* translation speed at full deflection */
    double rot_deg_s;       /* rotation speed at full deflection */
    loop_frame frame;
    int64_t dt_max_us;      /* longest report interval integrated (pause clamp) */
    int64_t dt_first_us;    /* what the first report after start or a replug integrates */
    int bisect_iters;       /* bisection depth of a limited step (fraction resolution 2^-n) */
    int slide_iters;        /* bisection depth of each slide component */
    int max_tries;          /* candidate poses tried per step at most, each proved free by the
                             * separation shortcut or queried (bounds the step's time; counting
                             * both keeps the step's poses independent of the queries before) */
    int check_invariant;    /* re-query accepted poses from scratch; on by default in debug builds */
    uint8_t button_action[32]; /* device button i pressed -> loop_action (0 = none) */
} loop_config;

typedef struct loop_stats {
    uint64_t events, steps, accepted, limited, slid, refused;
    uint64_t collisions_in_accepted; /* accepted poses found colliding by the invariant check */
    uint64_t unchecked;              /* poses accepted while collision checking was off */
    uint64_t escaping;               /* poses accepted while still interpenetrating after checking
                                      * came back on, each no deeper than the one before */
    uint64_t tolerated;              /* proposals accepted inside another fragment, within the
                                      * tolerance their proposer checked (a fit) */
    uint64_t queries;                /* pair queries (the invariant check's not counted) */
    uint64_t searches;               /* of those, the ones that searched from scratch (their
                                      * pair's cache of no use: the costly ones) */
    uint64_t overlaps;               /* overlap volumes measured (escaping moves: costly) */
    double query_us_mean, query_us_max;
    double step_hz;                  /* steps per second of wall time, since the last reset */
    double tick_hz;                  /* loop_run timer ticks per second (period_us apart) */
    double latency_p50_us, latency_p99_us, latency_max_us; /* report arrival -> pose accepted */
    uint64_t latency_samples;
    int64_t last_arrival_us;         /* when the newest motion report stepped arrived (its
                                      * arrival_us; 0: none yet): a renderer's report-to-frame */
    uint64_t dropped;                /* events lost to a full ring */
    uint64_t journal_errors;         /* journal writes that failed (disk full, I/O error) */
    uint64_t pose_digest;            /* FNV-1a 64 over every accepted (frag, q, t) in order */
} loop_stats;

/* What a renderer sees: one consistent state after a step. */
typedef struct loop_scene {
    uint64_t seq; /* increases with every publish */
    int nfrag, selected;
    int collision_on; /* 0: checking is off -- show a warning */
    int penetrating;  /* checking is on but the selected fragment is inside another: warn */
    int tolerated;    /* ... unless this is 1: it is inside by no more than a fit's tolerance (a
                       * fit put it there, or the plan was loaded so: loop_tolerate) */
    int trans_only, rot_only, device_present;
    unsigned save_requests; /* LOOP_ACT_SAVE presses so far: the application saves when it grows */
    unsigned fit_requests;  /* LOOP_ACT_FIT presses so far: the application fits when it grows */
    unsigned preview_requests, accept_requests; /* LOOP_ACT_PREVIEW, LOOP_ACT_ACCEPT presses so far */
    loop_frame frame;
    loop_outcome last_outcome;
    /* The selected fragment's contact at the pose in this scene: > 0 a lower bound on its gap to
     * every other fragment, 0 touching, < 0 penetrating (minus the depth estimate); NAN when
     * checking is off. Queried from scratch where it stands after a selection change or an undo
     * and once the device comes to rest; while it moves, the bound the step found (the
     * separation shortcut's or the pair caches': still a bound for this pose, if a loose one). */
    double separation_mm;
    unsigned actions;        /* controls done by events (keys, buttons) so far */
    loop_action last_action; /* the latest of them, and what loop_action_do returned for it */
    int last_action_result;  /* (undo/redo: LOOP_ACCEPTED, LOOP_REFUSED, LOOP_IDLE = none left) */
    /* LOOP_EV_POSE proposals handled so far; the result of proposal k (1-based) is
     * proposal_result[k % LOOP_PROPOSALS_KEPT] (LOOP_ACCEPTED or LOOP_REFUSED) while k is among
     * the last LOOP_PROPOSALS_KEPT. */
    uint64_t proposals;
    uint8_t proposal_result[LOOP_PROPOSALS_KEPT];
    loop_stats stats;
    pose pose[LOOP_MAX_FRAGS];
    uint8_t fixed[LOOP_MAX_FRAGS];
    uint8_t tolerated_frag[LOOP_MAX_FRAGS]; /* per fragment: marked as `tolerated` says (whether
                                             * inside or not) */
    uint8_t held_frag[LOOP_MAX_FRAGS]; /* per fragment: holds a fit's tolerance (may stand inside
                                        * another by up to it), moved since the fit or not */
    uint8_t fit_ended_by[LOOP_MAX_FRAGS]; /* per fragment: 1 + the fragment whose move ended its
                                           * `tolerated` mark (itself or another), 0: none since */
} loop_scene;

typedef struct loop loop;

/* Defaults. Buttons 1-10 (bits 0-9) act: next, previous, fix, collision, translation only,
 * rotation only, undo, redo, save, frame; button 12 (bit 11) fits, 13 the live preview on/off,
 * 14 accepts it (button 11 is the keyboard device's help). */
void loop_config_default(loop_config *c);
/* Moves the fourteen default button actions to start at bit first (a device whose numbered keys 1-10
 * are not its first buttons: devtab_key1_button); the bits below act no more. */
void loop_config_actions_at(loop_config *c, int first);

/* A loop over n fragments (1..LOOP_MAX_FRAGS), starting at their current poses. frags must stay
 * valid for the loop's life (centroid, home, dim, spacing are read). fixed: n flags or NULL.
 * journal: NULL or an open journal (journal.h) that receives every accepted pose; not owned.
 * NULL with fn_err on bad arguments or OOM. */
struct journal;
loop *loop_new(const frag *frags, int n, const uint8_t *fixed, const loop_collider *col,
               const loop_config *cfg, struct journal *journal);
void loop_free(loop *L);

/* One event: an action, an unplug/replug, or a motion step. Returns the step's loop_outcome
 * (LOOP_IDLE for non-motion events or no motion), or a negative FN_E* from the collider. */
int loop_feed(loop *L, const loop_event *ev);
/* A second ring of loop_events (actions from the application's thread, e.g. terminal keys),
 * drained before the input ring. NULL: none. Set it before the loop runs. */
void loop_set_controls(loop *L, ring *ctl);
/* Feeds every event waiting in the control ring and in r, then publishes the scene. Returns
 * events handled or negative. */
int loop_drain(loop *L, ring *r);
/* The loop: drains r and publishes at every loop_notify and at least every period_us, until
 * *stop becomes nonzero (then drains once more). Run it on its own thread. Returns 0 or the first
 * collider error. Before the first step it maps every page a step may touch -- its thread's
 * stack, the code and tables of the program and its libraries -- so that no step waits on a
 * first-touch page fault; under loop_realtime_priority it tells the loop's reader its CPU.
 * While any loop runs, the process is kept out of khugepaged's reach (PR_SET_THP_DISABLE: a
 * merge into a huge page takes the pages away from a step for milliseconds; huge pages made
 * before stay); the last loop to stop restores what was there before. */
int loop_run(loop *L, ring *r, int64_t period_us, const atomic_int *stop);

/* Direct controls (the same as the actions, for the application's own thread when not running). */
int loop_action_do(loop *L, loop_action a);
/* The camera frame follows a view: the camera looks along forward (unit, world LPS) with up
 * (unit, orthogonal) up on screen and right = forward x up to the right; device x then moves to
 * the right on screen, device y towards the viewer and device z down. The default is the camera
 * in front of the patient (right +x, up +z, forward +y). Any thread, at any time, without
 * blocking the stepping thread (which takes it at its next step). */
void loop_set_camera(loop *L, const double right[3], const double up[3], const double forward[3]);
/* A user pivot (world mm, current pose) for the selected fragment; NULL returns to the centroid. */
void loop_set_pivot(loop *L, const double world[3]);
/* Recovery: applies journal records (journal.h) in order -- poses, and the undo/redo history they
 * imply -- without writing them again. FN_EFORMAT (naming the record) for a fragment index out
 * of range. */
struct journal_rec;
int loop_recover(loop *L, const struct journal_rec *recs, size_t n);
/* Where the application keeps the poses it last saved (n poses; it owns them). After a save it
 * writes them there, then sends LOOP_EV_SAVED through the control ring: the loop empties the
 * journal and appends the poses that have moved since (so a later crash offers only those). */
void loop_set_saved(loop *L, const pose *saved);
/* Queries the selected fragment where it stands (when its contact is not known) and publishes,
 * so that the scene shows the contact before the first event; loop_feed does the same after each
 * event. Before the loop runs, or on its thread. 0 or the collider's error. */
int loop_measure(loop *L);
/* Moves a fragment without collision checking (recovery, loading): no journal, no stats. */
void loop_set_pose(loop *L, int i, pose p);
/* Marks fragment i, as loaded, as inside another by no more than a fit's tolerance_mm (a plan
 * that fracnav reduce left so): the scene says `tolerated` rather than warn until it moves, and it
 * holds that tolerance as a proposal's does (above). Before the loop runs. */
void loop_tolerate(loop *L, int i, double tolerance_mm);

pose loop_pose(const loop *L, int i);
int loop_selected(const loop *L);
int loop_fixed(const loop *L, int i);
void loop_get_stats(loop *L, loop_stats *out);
/* Restarts the rate and latency windows (counters and digest stay). */
void loop_reset_timing(loop *L);

/* Publishes the current state to the scene buffer (loop_drain/loop_run do it themselves). */
void loop_publish(loop *L);
/* Calls fn(ctx) after every publish, on the publishing thread (the stepping one while the loop
 * runs): it must return at once and allocate nothing (e.g. sem_post, a wake-up). NULL: none. Set
 * it before the loop runs. */
void loop_set_publish_hook(loop *L, void (*fn)(void *ctx), void *ctx);
/* Copies the newest published scene. Never blocks the loop; any thread, several at once (up to
 * 6 readers inside it at the same instant never delay a publish; more may make one wait for the
 * next). Returns 1 when its seq differs from the one out held on entry (zero out before the
 * first read), else 0; out holds the newest either way. */
int loop_scene_read(loop *L, loop_scene *out);
/* Asks the OS to run the calling thread (the one that will call loop_run) under SCHED_FIFO at a
 * modest priority, so other processes do not preempt a step, and keeps it on the CPU it is on,
 * where the loop's reader joins it (loop_reader_start). Needs CAP_SYS_NICE (root, or an rtprio
 * limit); returns 0, or FN_EINVAL when not allowed (the loop then runs as before). Safe:
 * loop_run sleeps between events and a step's work is bounded (max_tries). */
int loop_realtime_priority(void);
/* Runs the calling thread, a worker beside the loop (the live preview's), under ordinary
 * scheduling at nice `nice` (19: the lowest priority) on every CPU, whatever it inherited from the
 * thread that started it: one started by a loop_realtime_priority thread would otherwise share the
 * loop's CPU under SCHED_FIFO, and the loop would wait for it. Best effort. */
void loop_background_priority(int nice);

/* The loop's clock: what loop_run ticks by and the rates, latencies and journal stamps count in.
 * The default is the monotonic clock (fnclock_now_us, which also stamps the reader's arrival_us),
 * and loop_run waits on it until its next tick or an earlier loop_notify. An injected wait_until
 * replaces that wait: it returns at deadline_us (on now_us's clock) or earlier, and loop_run then
 * drains the rings; NULL keeps the monotonic wait, so now_us must then be that clock too. A test
 * injects a clock whose wait moves its time to the deadline and returns, so loop_run's timing
 * runs without sleeping. Both are called on the stepping thread only. */
typedef struct loop_clock {
    int64_t (*now_us)(void *ctx);
    void (*wait_until)(void *ctx, int64_t deadline_us);
    void *ctx;
} loop_clock;
/* Sets the clock (NULL: the monotonic one) and restarts the timing windows. Before the loop runs. */
void loop_set_clock(loop *L, const loop_clock *c);

/* Input seam: where events come from (a device through calibration, a recording, a script). */
typedef struct loop_source {
    /* Waits up to timeout_ms for the next event. Returns 1 (ev filled, arrival_us may be left 0),
     * 0 nothing yet, LOOP_SOURCE_END when no more will ever come, or another negative FN_E*.
     * A device that goes away yields LOOP_EV_UNPLUG, and LOOP_EV_REPLUG when it is back. */
    int (*next)(void *ctx, loop_event *ev, int timeout_ms);
    void *ctx;
} loop_source;
#define LOOP_SOURCE_END (-100)

/* Input thread: takes every event the source has (draining it) into r, stamps arrival_us and
 * wakes the loop (loop_notify). lockstep: wait until the loop has finished the previous event
 * before pushing the next (benchmarks: no queueing delay in the latency; needs L). While L runs
 * under loop_realtime_priority, the thread moves to the loop's CPU at the next lower SCHED_FIFO
 * priority: a report then wakes the loop on a CPU this thread holds, not on another one, where
 * the loop could wait milliseconds for a task inside the kernel; and this thread never delays a
 * step. With L, the thread reads nothing before loop_run has started (loop_running): a report
 * that came earlier waits in the device's buffer instead of in the ring while the loop maps its
 * pages (milliseconds, which the first report's latency would count). */
typedef struct loop_reader loop_reader;
loop_reader *loop_reader_start(loop_source src, ring *r, loop *L, int lockstep);
/* 1 once the source has ended (all its events are in the ring). */
int loop_reader_done(loop_reader *rd);
/* The same as a flag loop_run can stop on. */
const atomic_int *loop_reader_done_flag(loop_reader *rd);
/* Stops and joins the thread. Returns the source's errors (not unplugs) seen. */
int loop_reader_stop(loop_reader *rd);
/* Events the loop has finished (any thread). */
uint64_t loop_events_done(const loop *L);
/* 1 while loop_run steps: past its start (stack and code mapped, CPU announced), before its
 * return (any thread). */
int loop_running(const loop *L);
/* Wakes a loop_run waiting for its next tick (any thread). */
void loop_notify(loop *L);

/* The collider over OBB octrees (loop_obb.c): one tree per fragment, built at loop_obb_new with
 * params (NULL = {0, 1}); queries with q (NULL = threshold 0, tolerance 0). The frags must
 * outlive it. NULL with fn_err when a tree cannot be built (the message names the fragment). */
struct obb_params;
struct obb_query;
typedef struct loop_obb loop_obb;
loop_obb *loop_obb_new(const frag *frags, int n, const struct obb_params *params,
                       const struct obb_query *q);
void loop_obb_free(loop_obb *o);
/* A collider table bound to o (valid while o lives). */
loop_collider loop_obb_collider(loop_obb *o);

#endif
