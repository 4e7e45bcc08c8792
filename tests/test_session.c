#define _GNU_SOURCE /* CPU_COUNT, sched_getaffinity */
/* The navigation session in-process, on the two-blocks case (A fixed, B 2 mm beside it): poses
 * from recordings (contact, sliding, unplug, determinism), actions and their events, fix, undo
 * and redo, proposed poses landing as one undoable step or refused, saves on request and after,
 * reloading, journal recovery. Every wait is on the session's events. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "err.h"
#include "frag.h"
#include "fracture.h"
#include "reduce.h"
#include "vol.h"
#include "journal.h"
#include "navview.h"
#include "script.h"
#include "session.h"
#include "session_test.h"
#include "sim_replay.h"
#include "testutil.h"

#include <dirent.h>
#include <fcntl.h>
#include <jansson.h>
#include <math.h>
#include <pthread.h>
#include <sched.h>
#include <semaphore.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

static char *dir; /* the group's temp folder */
static char case_dir[4200];
static char *case_json; /* case.json as segmented, put back after each test */
static size_t case_json_len;

static int setup(void **st)
{
    (void)st;
    dir = tu_tmpdir("session");
    tu_two_blocks_case(dir, case_dir, sizeof case_dir);
    char path[4300];
    snprintf(path, sizeof path, "%s/case.json", case_dir);
    case_json = tu_slurp(path, &case_json_len);
    return case_json ? 0 : -1;
}

static int teardown(void **st)
{
    (void)st;
    tu_rmtree(dir);
    free(dir);
    free(case_json);
    return 0;
}

/* Each test starts from the case as segmented, with no journal. */
static int fresh_case(void **st)
{
    (void)st;
    char path[4300];
    snprintf(path, sizeof path, "%s/case.json", case_dir);
    tu_write_file(path, case_json, case_json_len);
    snprintf(path, sizeof path, "%s/journal", case_dir);
    remove(path);
    return 0;
}

static double fit_gap_mm; /* the next open_case's session_params.fit_gap_mm */

static session *open_case_at(const char *at, unsigned flags)
{
    session_params p = {.flags = flags, .command = "navigate", .fit_gap_mm = fit_gap_mm};
    loop_config_default(&p.cfg);
    p.cfg.check_invariant = 1;
    session *s = session_open(at, &p);
    if (!s)
        fail_msg("session_open: %s", fn_err_msg());
    return s;
}

static session *open_case(unsigned flags)
{
    return open_case_at(case_dir, flags);
}

/* ---- recordings ---- */

/* A motion script rendered for a SpaceNavigator, played as fast as the loop takes it (or through
 * the reader thread and loop_run with `mode`); returns the loop's statistics and B's pose. */
static void play(session *s, const char *text, int mode, loop_stats *out, pose *b)
{
    script *sc = NULL;
    assert_int_equal(script_parse(text, strlen(text), "test", &sc), 0);
    fnrec *rec = script_render(sc, sim_profile_find("spacenavigator"));
    free(sc);
    assert_non_null(rec);
    sim_replay_opts ro = {mode == SESSION_PLAY_REALTIME, 1};
    dev_handle *h;
    assert_int_equal(sim_replay_open_rec(rec, &ro, &h), 0);
    session_dsource *ds = session_recording_new(&sim_replay_transport, h, NULL, NULL);
    assert_non_null(ds);
    assert_int_equal(session_play(s, session_device_source(ds), mode), 0);
    session_dsource_free(ds);
    fnrec_free(rec);
    session_stats(s, out);
    *b = session_pose(s, 1);
}

/* A recording opened by its --device spec (session_source_open, as navigate and replay do) is
 * read one report per event, as one opened from its handle: the same poses, its unplug counted. */
static void test_source_by_spec(void **st)
{
    (void)st;
    char rec[4200], spec[4300];
    snprintf(rec, sizeof rec, "%s/sim/recordings/buttons.fnrec", tu_src());
    snprintf(spec, sizeof spec, "replay:%s", rec);
    if (!dev_transport_find("replay"))
        assert_int_equal(sim_register_transports(), 0);
    assert_true(session_spec_recording(spec));
    assert_false(session_spec_recording("auto"));
    loop_config cfg;
    loop_config_default(&cfg);
    session_dsource *ds = session_source_open(spec, NULL, 0, &cfg);
    assert_non_null(ds);
    assert_true(session_source_recording(ds));
    session *s = open_case(0);
    assert_int_equal(session_play(s, session_device_source(ds), SESSION_PLAY_FAST), 0);
    loop_stats a, b;
    session_stats(s, &a);
    assert_int_equal(session_source_unplugs(ds), 1);
    session_close(s);
    session_dsource_free(ds);
    dev_handle *h;
    assert_int_equal(sim_replay_open_file(rec, &(sim_replay_opts){0, 1}, &h), 0);
    ds = session_recording_new(&sim_replay_transport, h, NULL, NULL);
    s = open_case(0);
    assert_int_equal(session_play(s, session_device_source(ds), SESSION_PLAY_FAST), 0);
    session_stats(s, &b);
    session_close(s);
    session_dsource_free(ds);
    assert_true(a.steps > 0);
    assert_true(a.steps == b.steps && a.pose_digest == b.pose_digest);
}

/* Head-on into A: B stops at contact (never inside) and the rest of the push is refused; the same
 * recording gives the same poses bit for bit, through the reader thread and loop_run too. */
static void test_head_on_stops_at_contact_deterministic(void **st)
{
    (void)st;
    const char *text = "translate -x 4 mm over 0.4 s\n";
    loop_stats a, b, c;
    pose pa, pb, pc;
    session *s = open_case(0);
    play(s, text, SESSION_PLAY_FAST, &a, &pa);
    session_close(s);
    s = open_case(0);
    play(s, text, SESSION_PLAY_FAST, &b, &pb);
    session_close(s);
    s = open_case(0);
    play(s, text, SESSION_PLAY_REALTIME, &c, &pc);
    session_close(s);
    assert_int_equal(a.collisions_in_accepted, 0);
    assert_true(a.refused > 5);
    assert_true(a.steps == a.accepted + a.limited + a.slid + a.refused);
    assert_true(pa.t[0] < -1.9 && pa.t[0] >= -2.0); /* 2 mm gap: never the 4 mm asked for */
    assert_true(a.pose_digest == b.pose_digest);
    assert_true(a.pose_digest == c.pose_digest);
    assert_memory_equal(&pa, &pc, sizeof pa);
}

/* At a grazing angle B slides along A's face (world -y) instead of freezing at the contact. */
static void test_grazing_slides(void **st)
{
    (void)st;
    loop_stats a;
    pose p;
    session *s = open_case(0);
    play(s, "move x -6 mm y 3 mm over 0.6 s\n", SESSION_PLAY_FAST, &a, &p);
    session_close(s);
    assert_int_equal(a.collisions_in_accepted, 0);
    assert_true(a.slid > 10);
    assert_true(p.t[0] < -1.9 && p.t[0] >= -2.0);
    assert_true(p.t[1] < -2.5); /* device +y is towards the viewer: world -y */
}

/* Unplugged mid-recording: the pose stays where it was while the device is away, and moves again
 * after the replug. */
static void test_unplug_keeps_pose(void **st)
{
    (void)st;
    loop_stats a, b, c;
    pose before, gone, back;
    session *s = open_case(0);
    play(s, "translate +y 2 mm over 0.3 s\nunplug\n", SESSION_PLAY_FAST, &a, &before);
    session_close(s);
    s = open_case(0);
    play(s, "translate +y 2 mm over 0.3 s\nunplug\nwait 0.5 s\nreplug\nwait 0.2 s\n", SESSION_PLAY_FAST, &b, &gone);
    session_close(s);
    s = open_case(0);
    play(s, "translate +y 2 mm over 0.3 s\nunplug\nwait 0.5 s\nreplug\ntranslate +z 1 mm over 0.2 s\n",
         SESSION_PLAY_FAST, &c, &back);
    session_close(s);
    assert_true(a.pose_digest == b.pose_digest);
    assert_memory_equal(&before, &gone, sizeof before);
    assert_true(fabs(back.t[1] - gone.t[1]) < 1e-9);
    assert_true(back.t[2] < -0.8); /* device +z (down) is world -z */
}

/* ---- a running session ---- */

/* An in-process source that stays silent (the device at rest, unplugged) until told to end: the
 * test steers through actions and proposals alone. */
typedef struct quiet {
    sem_t tick;
    atomic_int end;
} quiet;

static int quiet_next(void *ctx, loop_event *ev, int timeout_ms)
{
    (void)ev;
    quiet *q = ctx;
    if (atomic_load(&q->end))
        return LOOP_SOURCE_END;
    struct timespec t;
    clock_gettime(CLOCK_REALTIME, &t);
    t.tv_nsec += (long)timeout_ms * 1000000L;
    t.tv_sec += t.tv_nsec / 1000000000L;
    t.tv_nsec %= 1000000000L;
    sem_timedwait(&q->tick, &t); /* woken at once by quiet_end */
    return atomic_load(&q->end) ? LOOP_SOURCE_END : 0;
}

static quiet Q;

/* A session on the case at `at`, running on the quiet source. */
static session *start_quiet_at(const char *at, unsigned flags)
{
    sem_init(&Q.tick, 0, 0);
    atomic_init(&Q.end, 0);
    session *s = open_case_at(at, flags);
    assert_int_equal(session_start(s, (loop_source){quiet_next, &Q}), 0);
    return s;
}

static session *start_quiet(unsigned flags)
{
    return start_quiet_at(case_dir, flags);
}

static void stop_quiet(session *s)
{
    assert_int_equal(session_stop(s), 0);
    sem_destroy(&Q.tick);
}

/* The next event of one of the kinds, skipping others; fails after TU_WAIT_MAX_S. */
static session_event *next_event(session *s, unsigned kinds)
{
    static session_event ev;
    for (;;) {
        session_event_kind k = session_wait_event(s, TU_WAIT_MAX_S * 1000, &ev);
        if (k == SESSION_EV_NONE)
            fail_msg("no session event of kinds %#x", kinds);
        if (k & kinds)
            return &ev;
    }
}

/* Sends an action and waits for its event; returns it. */
static session_event *act(session *s, loop_action a)
{
    assert_int_equal(session_send_action(s, a), 0);
    session_event *ev = next_event(s, SESSION_EV_ACTION);
    assert_int_equal(ev->action, a);
    return ev;
}

/* Proposes B at p and waits for the proposal's event; returns its result. */
static int propose(session *s, int fragment, const pose *p)
{
    uint64_t id = 0;
    assert_int_equal(session_propose_pose(s, fragment, p, &id), 0);
    session_event *ev = next_event(s, SESSION_EV_POSE);
    assert_true(ev->id == id);
    assert_int_equal(ev->frag, fragment);
    return ev->result;
}

static pose pose_of(session *s, int i)
{
    loop_scene sc = {0};
    session_scene_read(s, &sc);
    return sc.pose[i];
}

static pose moved_by(pose p, int axis, double mm)
{
    p.t[axis] += mm;
    return p;
}

/* Keys and actions: next/previous, fix, undo and redo of the fix, each acknowledged by an event
 * that carries the scene it was done in. */
static void test_actions_fix_undo_redo(void **st)
{
    (void)st;
    session *s = start_quiet(0);
    session_event ev;
    assert_int_equal(session_wait_event(s, 0, &ev), SESSION_EV_NONE); /* nothing done yet */
    assert_int_equal(session_key_action('f'), LOOP_ACT_FIX);
    assert_int_equal(session_key_action('q'), LOOP_ACT_NONE);
    assert_int_equal(session_send_action(s, LOOP_ACT_NONE), FN_EINVAL);
    session_event *e = act(s, LOOP_ACT_NEXT);
    assert_int_equal(e->scene.selected, 1); /* A is fixed: B stays the only one to select */
    e = act(s, LOOP_ACT_PREV);
    assert_int_equal(e->scene.selected, 1);
    e = act(s, LOOP_ACT_FIX);
    assert_int_equal(e->scene.fixed[1], 1);
    e = act(s, LOOP_ACT_UNDO);
    assert_int_equal(e->result, LOOP_ACCEPTED);
    assert_int_equal(e->scene.fixed[1], 0);
    e = act(s, LOOP_ACT_REDO);
    assert_int_equal(e->scene.fixed[1], 1);
    e = act(s, LOOP_ACT_REDO);
    assert_int_equal(e->result, LOOP_IDLE); /* nothing left to redo */
    stop_quiet(s);
    session_close(s);
}

static int led_says_fixed(void *ds)
{
    return session_dsource_movable(ds) == 0;
}

static int led_says_movable(void *ds)
{
    return session_dsource_movable(ds) == 1;
}

/* The session tells a device source, after every scene, whether the selected fragment can move:
 * its LED lights only while a movable one is held, and its input thread never reads the loop. */
static void test_session_pushes_movable_for_led(void **st)
{
    (void)st;
    calib cal;
    calib_default(&cal);
    session_dsource *ds = session_dsource_new(NULL, &cal);
    assert_non_null(ds);
    assert_int_equal(session_dsource_movable(ds), 1); /* until the session says otherwise */
    session *s = open_case(0);
    session_drive_led(s, ds);
    sem_init(&Q.tick, 0, 0);
    atomic_init(&Q.end, 0);
    assert_int_equal(session_start(s, (loop_source){quiet_next, &Q}), 0);
    assert_int_equal(act(s, LOOP_ACT_FIX)->scene.fixed[1], 1); /* B, the selected one, fixed */
    assert_true(tu_wait_for(led_says_fixed, ds, TU_WAIT_MAX_S));
    act(s, LOOP_ACT_UNDO);
    assert_true(tu_wait_for(led_says_movable, ds, TU_WAIT_MAX_S));
    stop_quiet(s);
    session_close(s);
    session_dsource_free(ds);
}

/* A proposed pose lands as one step: accepted when free, refused inside A (and for the fixed A),
 * undone and redone whole; with checking off, accepted anywhere. */
static void test_propose_pose_one_undoable_step(void **st)
{
    (void)st;
    session *s = start_quiet(0);
    pose home = pose_of(s, 1), up = moved_by(home, 2, 1.5), inside = moved_by(home, 0, -5);
    assert_int_equal(propose(s, 1, &up), LOOP_ACCEPTED);
    pose now = pose_of(s, 1);
    assert_memory_equal(&now, &up, sizeof up);
    assert_int_equal(propose(s, 1, &inside), LOOP_REFUSED);
    now = pose_of(s, 1);
    assert_memory_equal(&now, &up, sizeof up);
    pose a = moved_by(pose_of(s, 0), 2, 1);
    assert_int_equal(propose(s, 0, &a), LOOP_REFUSED); /* A is fixed */
    assert_int_equal(session_propose_pose(s, 2, &a, NULL), FN_EINVAL);
    session_event *e = act(s, LOOP_ACT_UNDO);
    assert_int_equal(e->result, LOOP_ACCEPTED);
    assert_memory_equal(&e->scene.pose[1], &home, sizeof home);
    e = act(s, LOOP_ACT_UNDO);
    assert_int_equal(e->result, LOOP_IDLE); /* the proposal was the only step */
    e = act(s, LOOP_ACT_REDO);
    assert_memory_equal(&e->scene.pose[1], &up, sizeof up);
    act(s, LOOP_ACT_COLLISION);
    assert_int_equal(propose(s, 1, &inside), LOOP_ACCEPTED);
    e = act(s, LOOP_ACT_COLLISION); /* back on, inside A: the scene warns */
    assert_int_equal(e->scene.penetrating, 1);
    stop_quiet(s);
    loop_stats stats;
    session_stats(s, &stats);
    assert_int_equal(stats.steps, 0); /* proposals are not motion steps */
    session_close(s);
}

/* Proposals from several threads at once all land, each with its own event. */
typedef struct proposer {
    session *s;
    pose p;
    int landed;
} proposer;

static void *propose_thread(void *arg)
{
    proposer *pr = arg;
    for (int i = 0; i < 10; i++) {
        while (session_propose_pose(pr->s, 1, &pr->p, NULL) == FN_EAGAIN)
            sched_yield(); /* the waiter has not caught up yet */
        pr->landed++;
    }
    return NULL;
}

static void test_propose_from_threads(void **st)
{
    (void)st;
    session *s = start_quiet(0);
    proposer pr[2] = {{s, moved_by(pose_of(s, 1), 2, 1), 0}, {s, moved_by(pose_of(s, 1), 2, 2), 0}};
    pthread_t th[2];
    for (int i = 0; i < 2; i++)
        assert_int_equal(pthread_create(&th[i], NULL, propose_thread, &pr[i]), 0);
    uint64_t last = 0;
    for (int n = 0; n < 20; n++) {
        session_event *e = next_event(s, SESSION_EV_POSE);
        assert_true(e->id == last + 1);
        last = e->id;
        assert_int_equal(e->result, LOOP_ACCEPTED);
    }
    for (int i = 0; i < 2; i++)
        pthread_join(th[i], NULL);
    assert_int_equal(pr[0].landed + pr[1].landed, 20);
    stop_quiet(s);
    session_close(s);
}

/* A journaled session: a proposal is in the journal at once; unsaved, it is offered again
 * (SESSION_RESUME) and recovered as one undo step; a save on request empties the journal, and
 * the case reopens at the saved pose. */
static void test_journal_recovery_and_save(void **st)
{
    (void)st;
    session *s = start_quiet(SESSION_JOURNAL);
    pose home = pose_of(s, 1), up = moved_by(home, 2, 2);
    assert_int_equal(propose(s, 1, &up), LOOP_ACCEPTED);
    stop_quiet(s);
    session_close(s); /* not saved: an interrupted session */
    assert_int_equal(session_journal_pending(case_dir), 1);
    session_params p = {.flags = SESSION_JOURNAL, .command = "navigate"};
    loop_config_default(&p.cfg);
    assert_null(session_open(case_dir, &p));
    assert_non_null(strstr(fn_err_msg(), "--recover"));

    s = start_quiet(SESSION_JOURNAL | SESSION_RESUME);
    assert_int_equal(session_resumed(s), 1);
    pose now = pose_of(s, 1);
    assert_memory_equal(&now, &up, sizeof up);
    session_event *e = act(s, LOOP_ACT_UNDO);
    assert_memory_equal(&e->scene.pose[1], &home, sizeof home);
    act(s, LOOP_ACT_REDO);
    act(s, LOOP_ACT_SAVE);
    e = next_event(s, SESSION_EV_SAVED);
    assert_int_equal(e->result, 0);
    assert_non_null(strstr(e->text, case_dir));
    assert_memory_equal(&e->scene.pose[1], &up, sizeof up);
    stop_quiet(s);
    assert_int_equal(session_journal_pending(case_dir), 0); /* the loop emptied it after the save */
    session_close(s);

    s = open_case(SESSION_JOURNAL);
    now = session_pose(s, 1);
    assert_true(fabs(now.t[2] - up.t[2]) < 1e-9);
    assert_int_equal(session_resumed(s), 0);
    session_close(s);
}

/* A save request made by the last events before the session stops is still carried out, and
 * session_save after it saves the final poses. */
static void test_save_at_stop(void **st)
{
    (void)st;
    session *s = start_quiet(SESSION_JOURNAL);
    pose up = moved_by(pose_of(s, 1), 1, 1);
    assert_int_equal(session_send_action(s, LOOP_ACT_SAVE), 0);
    assert_int_equal(session_propose_pose(s, 1, &up, NULL), 0);
    stop_quiet(s);
    session_event ev;
    int saved = 0;
    while (session_wait_event(s, 0, &ev) != SESSION_EV_NONE)
        saved |= ev.kind == SESSION_EV_SAVED && ev.result == 0;
    assert_true(saved);
    assert_int_equal(session_save(s), 0);
    session_close(s);
    s = open_case(0);
    pose now = session_pose(s, 1);
    assert_true(fabs(now.t[1] - up.t[1]) < 1e-9);
    session_close(s);
}

/* A client that never waits on events still has its save done and its fit landed: the session
 * carries them out on its own thread, and their events wait for it in order. */
static int case_holds(void *arg)
{
    const pose *want = arg;
    planning_case *c = case_load(case_dir);
    int ok = c && fabs(c->frag[1].pose.t[1] - want->t[1]) < 1e-9;
    case_free(c);
    return ok;
}

/* arg: {session, pose}: B stands elsewhere than at the pose. */
static int b_moved_from(void *arg)
{
    void **a = arg;
    pose now = pose_of(a[0], 1);
    return memcmp(&now, a[1], sizeof now) != 0;
}

static void test_actions_done_without_waiting(void **st)
{
    (void)st;
    session *s = start_quiet(SESSION_JOURNAL);
    pose hand = moved_by(moved_by(pose_of(s, 1), 1, 1.0), 2, -1.0);
    assert_int_equal(session_propose_pose(s, 1, &hand, NULL), 0);
    assert_int_equal(session_send_action(s, LOOP_ACT_SAVE), 0);
    assert_true(tu_wait_for_every(case_holds, &hand, TU_WAIT_MAX_S, 50000));
    assert_int_equal(session_send_action(s, LOOP_ACT_FIT), 0);
    assert_true(tu_wait_for(b_moved_from, (void *[]){s, &hand}, TU_WAIT_MAX_S));
    stop_quiet(s);
    unsigned kinds = 0;
    session_event ev;
    while (session_wait_event(s, 0, &ev) != SESSION_EV_NONE) {
        kinds |= (unsigned)ev.kind;
        if (ev.kind == SESSION_EV_SAVED)
            assert_int_equal(ev.result, 0);
    }
    assert_int_equal(kinds, SESSION_EV_POSE | SESSION_EV_ACTION | SESSION_EV_SAVED | SESSION_EV_FIT);
    session_close(s);
}

/* A source that ends says so once (SESSION_EV_END); the wake-up callback runs at publishes;
 * scenes are events only when subscribed. */
static atomic_int wakeups;

static void on_wakeup(void *ctx)
{
    (void)ctx;
    atomic_fetch_add(&wakeups, 1);
}

static int woken(void *arg)
{
    (void)arg;
    return atomic_load(&wakeups) > 0;
}

static void test_end_scene_and_wakeup(void **st)
{
    (void)st;
    sem_init(&Q.tick, 0, 0);
    atomic_init(&Q.end, 0);
    session *s = open_case(0);
    session_set_wakeup(s, on_wakeup, NULL);
    session_subscribe(s, SESSION_EV_SCENE | SESSION_EV_END);
    assert_int_equal(session_start(s, (loop_source){quiet_next, &Q}), 0);
    assert_int_equal(session_send_action(s, LOOP_ACT_FRAME), 0);
    session_event *e = next_event(s, SESSION_EV_SCENE);
    while (e->scene.actions == 0) /* the scene of open first, then the loop's */
        e = next_event(s, SESSION_EV_SCENE);
    assert_int_equal(e->scene.frame, LOOP_FRAME_WORLD);
    assert_true(tu_wait_for(woken, NULL, TU_WAIT_MAX_S)); /* called just after that publish */
    atomic_store(&Q.end, 1);
    sem_post(&Q.tick);
    next_event(s, SESSION_EV_END);
    assert_true(session_ended(s));
    stop_quiet(s);
    session_close(s);
}

/* Errors name their cause: a missing case, a second start, an action while nothing runs. */
static void test_open_errors(void **st)
{
    (void)st;
    session_params p = {.command = "replay"};
    loop_config_default(&p.cfg);
    assert_null(session_open("/nonexistent/case", &p));
    assert_non_null(strstr(fn_err_msg(), "/nonexistent/case"));
    session *s = start_quiet(0);
    assert_int_equal(session_start(s, (loop_source){quiet_next, &Q}), FN_EINVAL);
    stop_quiet(s);
    assert_int_equal(session_send_action(s, LOOP_ACT_NEXT), FN_EAGAIN); /* not running */
    session_close(s);
}

/* A session over bare fragments (benchmarks): it steers and stops at contact as a case's does,
 * but has nothing to save or summarize, and says so. */
static void test_fragments_without_case(void **st)
{
    (void)st;
    frag f[2];
    tu_box_frag(&f[0], 1, (const int[3]){10, 10, 10}, (const double[3]){0, 0, 0});
    tu_box_frag(&f[1], 2, (const int[3]){6, 6, 6}, (const double[3]){12, 2, 2}); /* 2 mm beside */
    uint8_t fixed[2] = {1, 0};
    loop_config cfg;
    loop_config_default(&cfg);
    cfg.check_invariant = 1;
    session *s = session_open_fragments(f, 2, fixed, (const double[2]){0.5, 0.95}, &cfg);
    assert_non_null(s);
    assert_null(session_case(s));
    loop_stats a;
    pose p;
    play(s, "translate -x 4 mm over 0.4 s\n", SESSION_PLAY_FAST, &a, &p);
    assert_true(p.t[0] < -1.9 && p.t[0] >= -2.0);
    assert_int_equal(a.collisions_in_accepted, 0);
    assert_int_equal(session_save(s), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "no case"));
    assert_int_equal(session_print_json(s, stdout, "test", -1, 0), FN_EINVAL);
    session_close(s);
    assert_null(session_open_fragments(f, 0, NULL, (const double[2]){0, 1}, &cfg));
    free(f[0].prob);
    free(f[1].prob);
}

/* The fit action (key g, loop button 12): the worker fits B from where the hand left it while the
 * loop runs on; the fitted pose lands as one proposal, accepted and clear of A, and undo puts B
 * back exactly where the hand left it, redo on the fit again. A fixed fragment is refused, with
 * the reason. */
static void test_fit_lands_as_one_undoable_step(void **st)
{
    (void)st;
    assert_int_equal(session_key_action('g'), LOOP_ACT_FIT);
    session *s = start_quiet(0);
    pose hand = moved_by(moved_by(pose_of(s, 1), 1, 1.0), 2, -1.0);
    assert_int_equal(propose(s, 1, &hand), LOOP_ACCEPTED);
    act(s, LOOP_ACT_FIT);
    session_event *e = next_event(s, SESSION_EV_FIT);
    assert_int_equal(e->result, 0);
    assert_int_equal(e->fit.frag, 1);
    assert_non_null(strstr(e->text, "fitting frag 2"));
    int fitted = 0, landed = 0;
    pose fit = hand;
    while (!fitted || !landed) {
        e = next_event(s, SESSION_EV_FIT | SESSION_EV_POSE);
        if (e->kind == SESSION_EV_FIT) {
            assert_int_equal(e->result, 0);
            assert_non_null(strstr(e->text, "fit: frag 2 moved"));
            assert_true(e->fit.evaluations > 0);
            assert_true(e->fit.metric <= e->fit.metric_start);
            fitted = 1;
        } else {
            assert_int_equal(e->frag, 1);
            assert_int_equal(e->result, LOOP_ACCEPTED);
            fit = e->scene.pose[1];
            assert_int_equal(e->scene.penetrating, 0);
            landed = 1;
        }
    }
    session_fit fs;
    session_fit_status(s, &fs);
    assert_int_equal(fs.running, 0);
    assert_int_equal(fs.finished, 1);
    e = act(s, LOOP_ACT_UNDO);
    assert_int_equal(e->result, LOOP_ACCEPTED);
    assert_memory_equal(&e->scene.pose[1], &hand, sizeof hand);
    e = act(s, LOOP_ACT_REDO);
    assert_memory_equal(&e->scene.pose[1], &fit, sizeof fit);
    act(s, LOOP_ACT_FIX);
    act(s, LOOP_ACT_FIT);
    e = next_event(s, SESSION_EV_FIT);
    assert_int_equal(e->result, FN_EINVAL);
    assert_non_null(strstr(e->text, "fixed"));
    stop_quiet(s);
    session_close(s);
}

/* Asks for the fit of fragment 2 and waits until its pose lands: returns that event (accepted). */
static session_event *fit_and_land(session *s)
{
    act(s, LOOP_ACT_FIT);
    session_event *e;
    do
        e = next_event(s, SESSION_EV_POSE | SESSION_EV_FIT);
    while (e->kind == SESSION_EV_FIT && e->result == 0 && !strstr(e->text, "fit: frag 2 moved"));
    if (e->kind == SESSION_EV_FIT) {
        if (e->result != 0)
            fail_msg("%s", e->text);
        e = next_event(s, SESSION_EV_POSE);
    }
    assert_int_equal(e->result, LOOP_ACCEPTED);
    return e;
}

/* Fits fragment 2 from the hand's pose (as test_fit_lands_as_one_undoable_step) in a session whose
 * fit leaves gap_mm; returns the pose that landed. */
static pose fit_with_gap(double gap_mm)
{
    fit_gap_mm = gap_mm;
    session *s = start_quiet(0);
    fit_gap_mm = 0;
    pose hand = moved_by(moved_by(pose_of(s, 1), 1, 1.0), 2, -1.0);
    assert_int_equal(propose(s, 1, &hand), LOOP_ACCEPTED);
    pose fit = fit_and_land(s)->scene.pose[1];
    stop_quiet(s);
    session_close(s);
    fresh_case(NULL);
    return fit;
}

/* navigate --gap: the fit action leaves the bone lost at the cut. The blocks' facing sides end
 * further apart, along x (the axis they face along), with a gap of 2 mm than without. */
static void test_fit_leaves_the_gap(void **st)
{
    (void)st;
    pose closed = fit_with_gap(0), gapped = fit_with_gap(2);
    print_message("fit ends at x %+.2f mm without a gap, %+.2f mm with 2 mm\n", closed.t[0], gapped.t[0]);
    if (!(gapped.t[0] > closed.t[0] + 1.0))
        fail_msg("with a 2 mm gap the fit ends at x %+.2f mm, without at %+.2f mm", gapped.t[0], closed.t[0]);
}

/* The fit action on a rough fracture (an ellipsoid cut by fracture_make, 1 mm voxels, the piece
 * left 4 mm and 5 degrees off as a hand would): near the truth the two sides' voxels interlock at
 * the loop's tolerance 0, so the fit checks its result at reduce's tolerance and the loop takes it
 * within that, inside by a fraction of a voxel (counted in `tolerated`). Fitted at tolerance 0,
 * as before, it ended pushed off the fit by millimetres (the example skull: 0.04 deg, 3.39 mm). */
static void test_fit_lands_on_a_rough_fracture(void **st)
{
    (void)st;
    char *fdir = tu_tmpdir("session_rough");
    planning_case *c = tu_ellipsoid_fracture(fdir, 2, 3, 0);
    session *s = start_quiet_at(fdir, 0);
    session_event *e = fit_and_land(s);
    c->frag[1].pose = e->scene.pose[1];
    loop_stats ls = e->scene.stats; /* the loop's own stats belong to its thread while it runs */
    stop_quiet(s);
    assert_int_equal(session_save(s), 0);
    session_close(s);
    /* saved where the fit left it, it opens inside by no more than the fit's tolerance: said so,
     * not warned of (case.json: "penetrating" within_fit_tolerance) */
    s = open_case_at(fdir, 0);
    loop_scene sc = {0};
    session_scene_read(s, &sc);
    char line[2048];
    navview_format(&sc, NULL, 0, line, sizeof line);
    print_message("reopened: %s\n", line);
    assert_int_equal(sc.penetrating, 1); /* this fracture's voxels interlock where the fit ends */
    if (!sc.tolerated || strstr(line, "PENETRATING") || !strstr(line, "within the fit's tolerance"))
        fail_msg("reopened where the fit left it, the view says: %s", line);
    session_close(s);
    double rot, trans, tre;
    assert_int_equal(reduce_truth_errors(c, 0, 1, &rot, &trans, &tre), 0);
    print_message("fit: %.3f deg, %.3f mm (TRE %.3f mm) from the truth; %llu tolerated\n", rot, trans, tre,
                  (unsigned long long)ls.tolerated);
    if (!(rot <= 1 && trans <= 1))
        fail_msg("the fit action ended %.3f deg, %.3f mm from the truth (TRE %.3f mm)", rot, trans, tre);
    case_free(c);
    tu_rmtree(fdir);
    free(fdir);
}

/* The entries of case.json's "penetrating" in dir that say within_fit_tolerance. */
static size_t fitted_entries(const char *dir)
{
    char path[4300];
    snprintf(path, sizeof path, "%s/case.json", dir);
    json_t *j = json_load_file(path, 0, NULL), *e;
    assert_non_null(j);
    size_t n = 0, i;
    json_array_foreach(json_object_get(j, "penetrating"), i, e)
        n += json_is_true(json_object_get(e, "within_fit_tolerance"));
    json_decref(j);
    return n;
}

/* session_save(s), its stderr (the save's notes and warnings) caught into a malloc'd string. */
static char *save_said(session *s, const char *dir)
{
    char path[4300];
    snprintf(path, sizeof path, "%s/save-stderr", dir);
    fflush(stderr);
    int keep = dup(2), fd = open(path, O_WRONLY | O_CREAT | O_TRUNC, 0600);
    assert_true(keep >= 0 && fd >= 0);
    dup2(fd, 2);
    close(fd);
    int rc = session_save(s);
    fflush(stderr);
    dup2(keep, 2);
    close(keep);
    if (rc != 0)
        fail_msg("session_save: %s", fn_err_msg());
    char *said = tu_slurp(path, NULL);
    assert_non_null(said);
    return said;
}

/* The case.json in dir's "penetrating" entry for fragments a and b (a json_t the caller
 * decrefs: the whole file), or NULL (and *file NULL) when there is none. */
static json_t *penetrating_entry(const char *dir, int a, int b, json_t **file)
{
    char path[4300];
    snprintf(path, sizeof path, "%s/case.json", dir);
    *file = json_load_file(path, 0, NULL);
    assert_non_null(*file);
    json_t *e;
    size_t i;
    json_array_foreach(json_object_get(*file, "penetrating"), i, e) {
        json_t *f = json_object_get(e, "fragments");
        if (json_integer_value(json_array_get(f, 0)) == a && json_integer_value(json_array_get(f, 1)) == b)
            return e;
    }
    json_decref(*file);
    *file = NULL;
    return NULL;
}

/* "Fitted" means where the fit left it. A fitted piece of a rough fracture (inside the other by a
 * fraction of a voxel, tolerated) is pushed about: its moves are checked as a free fragment's are,
 * at the fit's tolerance (no accepted pose deeper: the invariant check runs at it), without an
 * overlap volume measured per step (what made the loop ~20 times slower after a fit), and once it
 * has moved the view no longer says "fitted", and the save neither notes it as within the fit's
 * tolerance nor records it so in case.json. */
static void test_fitted_fragment_moved(void **st)
{
    (void)st;
    char *fdir = tu_tmpdir("session_fitted_moved");
    planning_case *c = tu_ellipsoid_fracture(fdir, 2, 3, 0);
    session *s = start_quiet_at(fdir, 0);
    pose fit = fit_and_land(s)->scene.pose[1];
    stop_quiet(s);
    assert_int_equal(session_save(s), 0);
    session_close(s);
    assert_int_equal(fitted_entries(fdir), 1);

    s = open_case_at(fdir, 0);
    loop_stats ls;
    pose after;
    play(s, "move x 9 mm over 0.6 s\nmove y 5 mm over 0.4 s\nmove z -5 mm over 0.4 s\n"
            "move x -4 mm y -4 mm over 0.4 s\n", SESSION_PLAY_FAST, &ls, &after);
    /* saved straight after the play (whose last state a scene shows only once published) */
    char *said = save_said(s, fdir);
    print_message("the save said: %s\n", said);
    json_t *e;
    size_t i;
    json_array_foreach(session_penetrating(s), i, e)
        assert_false(json_is_true(json_object_get(e, "within_fit_tolerance")));
    /* still inside fragment 1 within the fit's tolerance, which it holds since the fit: the
     * warning gives that reason and names the fragment moved, not "as the case was loaded" */
    json_t *file, *entry = penetrating_entry(fdir, 1, 2, &file);
    assert_non_null(entry);
    assert_false(json_is_true(json_object_get(entry, "within_fit_tolerance")));
    assert_true(json_number_value(json_object_get(entry, "overlap_ml")) > 0);
    json_decref(file);
    if (!strstr(said, "WARNING: saving a penetrating plan: fragments 1 and 2 overlap by") ||
        !strstr(said, "(fragment 2 moved after a fit left them so: inside within the fit's tolerance") ||
        strstr(said, "as the case was loaded") || strstr(said, "where a fit left them"))
        fail_msg("moved after the fit, the save said: %s", said);
    free(said);
    assert_int_equal(loop_measure(session__loop(s)), 0);
    loop_scene sc = {0};
    session_scene_read(s, &sc);
    char line[2048];
    navview_format(&sc, NULL, 0, line, sizeof line);
    print_message("moved %.2f mm: %s; %llu steps, %llu overlap measures, %llu queries\n",
                  hypot(hypot(after.t[0] - fit.t[0], after.t[1] - fit.t[1]), after.t[2] - fit.t[2]), line,
                  (unsigned long long)ls.steps, (unsigned long long)ls.overlaps,
                  (unsigned long long)ls.queries);
    assert_true(memcmp(&after, &fit, sizeof fit) != 0);
    assert_true(ls.accepted + ls.limited + ls.slid > 0);
    assert_int_equal(ls.collisions_in_accepted, 0);
    assert_int_equal(ls.overlaps, 0);
    if (sc.tolerated || strstr(line, "fitted") || strstr(line, "within the fit's tolerance"))
        fail_msg("moved off the fit, the view still says: %s", line);
    session_close(s);
    assert_int_equal(fitted_entries(fdir), 0);
    case_free(c);
    tu_rmtree(fdir);
    free(fdir);
}

/* One overlap figure: block B pushed 4 mm into A (2 mm apart: 2 mm inside, over B's 12x12 mm
 * face, parallel grids, so 0.288 ml exactly) is saved by a session and recorded by case_set_reduction
 * with the same overlap_ml, case_overlap_ml's. Before, the session summed its voxel pairs' boxes
 * (0.547 ml on the demo's reduced pose) and the report counted a resampled labelmap (0.142 ml). */
static void test_one_overlap_figure(void **st)
{
    (void)st;
    session *s = open_case(0);
    pose p[2] = {pose_of(s, 0), moved_by(pose_of(s, 1), 0, -4.0)};
    uint8_t fixed[2] = {1, 0};
    assert_int_equal(session_save_case(s, p, fixed), 0);
    json_t *e = json_array_get(session_penetrating(s), 0);
    assert_non_null(e);
    double saved = json_number_value(json_object_get(e, "overlap_ml"));
    assert_false(json_is_true(json_object_get(e, "within_fit_tolerance")));
    session_close(s);
    planning_case *c = case_load(case_dir);
    assert_non_null(c);
    double ml = case_overlap_ml(c, 0, 1);
    print_message("session %.6f ml, case_overlap_ml %.6f ml\n", saved, ml);
    assert_true(fabs(ml - 0.288) < 1e-9);
    assert_true(saved == ml);
    /* turned 10 degrees (grids no longer parallel), the session's figure is still the one */
    double axis[3] = {0, 0, 1}, c1[3];
    pose turn = pose_from_axis_angle(axis, 10 * M_PI / 180);
    pose_apply(&p[1], c->frag[1].centroid, c1);
    double rc1[3];
    pose_rotate(&turn, c1, rc1);
    for (int i = 0; i < 3; i++)
        turn.t[i] = c1[i] - rc1[i];
    c->frag[1].pose = p[1] = pose_compose(turn, p[1]);
    s = open_case(0);
    assert_int_equal(session_save_case(s, p, fixed), 0);
    double turned = json_number_value(json_object_get(json_array_get(session_penetrating(s), 0), "overlap_ml"));
    session_close(s);
    print_message("turned: session %.6f ml, case_overlap_ml %.6f ml\n", turned, case_overlap_ml(c, 0, 1));
    assert_true(turned == case_overlap_ml(c, 0, 1));
    reduce_opts o;
    reduce_defaults(&o);
    reduce_result r;
    memset(&r, 0, sizeof r);
    r.id = c->frag[1].id;
    assert_int_equal(case_set_reduction(c, 0, &o, &r, 1), 0);
    assert_int_equal(case_save(c), 0);
    case_free(c);
    char path[4300];
    snprintf(path, sizeof path, "%s/case.json", case_dir);
    json_t *j = json_load_file(path, 0, NULL);
    e = json_array_get(json_object_get(j, "penetrating"), 0);
    assert_non_null(e);
    assert_true(json_number_value(json_object_get(e, "overlap_ml")) == turned);
    assert_true(json_is_true(json_object_get(e, "within_fit_tolerance")));
    json_decref(j);
}

/* case.json's "fixed" in the case at case_dir. */
static json_t *saved_fixed(void)
{
    char path[4300];
    snprintf(path, sizeof path, "%s/case.json", case_dir);
    json_t *j = json_load_file(path, 0, NULL);
    assert_non_null(j);
    json_t *f = json_incref(json_object_get(j, "fixed"));
    json_decref(j);
    return f;
}

/* A second fixed fragment is saved (it was named in a warning and lost): B fixed beside A, saved,
 * reopens fixed; case.json's "fixed" lists both, A (the case's own) first. Unfixed again, undone
 * and redone like a move, it saves as the single id of before. */
static void test_second_fixed_fragment_saved(void **st)
{
    (void)st;
    session *s = start_quiet(0);
    session_event *e = act(s, LOOP_ACT_FIX);
    assert_int_equal(e->scene.selected, 1);
    assert_int_equal(e->scene.fixed[1], 1);
    stop_quiet(s);
    assert_int_equal(session_save(s), 0);
    session_close(s);
    json_t *f = saved_fixed();
    assert_true(json_is_array(f) && json_array_size(f) == 2);
    assert_int_equal(json_integer_value(json_array_get(f, 0)), 1);
    assert_int_equal(json_integer_value(json_array_get(f, 1)), 2);
    json_decref(f);

    s = start_quiet(0);
    loop_scene sc = {0};
    session_scene_read(s, &sc);
    assert_true(sc.fixed[0] && sc.fixed[1]);
    assert_int_equal(act(s, LOOP_ACT_FIX)->scene.fixed[sc.selected], 0);
    assert_int_equal(act(s, LOOP_ACT_UNDO)->scene.fixed[sc.selected], 1);
    assert_int_equal(act(s, LOOP_ACT_REDO)->scene.fixed[sc.selected], 0);
    stop_quiet(s);
    assert_int_equal(session_save(s), 0);
    session_close(s);
    f = saved_fixed();
    assert_true(json_is_integer(f) && json_integer_value(f) == 1);
    json_decref(f);
}

/* The redo of a fit on a rough fracture (inside the other piece within the fit's tolerance) goes
 * back to the fitted pose, "fitted" again: it is checked at the tolerance the pose held (it was
 * refused, "that pose collides now", checked at the loop's 0). */
static void test_redo_of_a_fit(void **st)
{
    (void)st;
    char *fdir = tu_tmpdir("session_redo_fit");
    planning_case *c = tu_ellipsoid_fracture(fdir, 2, 3, 0);
    session *s = start_quiet_at(fdir, 0);
    pose hand = pose_of(s, 1);
    session_event *e = fit_and_land(s);
    pose fit = e->scene.pose[1];
    assert_int_equal(e->scene.tolerated_frag[1], 1);
    e = act(s, LOOP_ACT_UNDO);
    assert_int_equal(e->result, LOOP_ACCEPTED);
    assert_memory_equal(&e->scene.pose[1], &hand, sizeof hand);
    assert_int_equal(e->scene.tolerated_frag[1], 0);
    e = act(s, LOOP_ACT_REDO);
    assert_int_equal(e->result, LOOP_ACCEPTED);
    assert_memory_equal(&e->scene.pose[1], &fit, sizeof fit);
    assert_int_equal(e->scene.tolerated_frag[1], 1);
    stop_quiet(s);
    session_close(s);
    case_free(c);
    tu_rmtree(fdir);
    free(fdir);
}

/* Near contact, the preview runs by itself for a piece to put back, not for the one that stays:
 * with no fragment fixed, the largest (as reduce keeps it), whose fit against a smaller piece
 * would move the bone to the piece. Asked (v), it runs for it too; the smaller piece, selected,
 * is previewed by itself. */
static void test_preview_leaves_the_piece_that_stays(void **st)
{
    (void)st;
    char *fdir = tu_tmpdir("session_preview_stays");
    planning_case *c = tu_ellipsoid_fracture(fdir, 2, 3, 0);
    assert_true(c->frag[0].voxels > c->frag[1].voxels);
    c->fixed = -1; /* a case as segment makes it: nothing fixed */
    c->nfixed_also = 0;
    c->frag[1].pose = c->truth[1]; /* in contact */
    assert_int_equal(case_save(c), 0);
    session *s = open_case_at(fdir, 0);
    session_set_preview(s, SESSION_PREVIEW_NEAR);
    sem_init(&Q.tick, 0, 0);
    atomic_init(&Q.end, 0);
    assert_int_equal(session_start(s, (loop_source){quiet_next, &Q}), 0);
    session_event *e = act(s, LOOP_ACT_COLLISION); /* off and on: scenes published near contact */
    e = act(s, LOOP_ACT_COLLISION);
    assert_int_equal(e->scene.selected, 0);
    assert_true(e->scene.collision_on && e->scene.separation_mm <= SESSION_PREVIEW_NEAR_MM);
    session_preview p;
    session_preview_status(s, &p);
    assert_int_equal(p.updates, 0);
    assert_false(p.shown);
    /* asked: the largest is previewed */
    act(s, LOOP_ACT_PREVIEW);
    for (session_preview_status(s, &p); !(p.asked && p.shown && p.frag == 0); session_preview_status(s, &p))
        next_event(s, SESSION_EV_PREVIEW | SESSION_EV_ACTION);
    act(s, LOOP_ACT_PREVIEW); /* off again: near contact only */
    for (session_preview_status(s, &p); p.asked; session_preview_status(s, &p))
        next_event(s, SESSION_EV_PREVIEW | SESSION_EV_ACTION);
    /* the smaller piece, selected: previewed by itself, near contact */
    e = act(s, LOOP_ACT_NEXT);
    assert_int_equal(e->scene.selected, 1);
    for (session_preview_status(s, &p); !(p.shown && p.frag == 1); session_preview_status(s, &p))
        next_event(s, SESSION_EV_PREVIEW | SESSION_EV_ACTION);
    assert_false(p.asked);
    stop_quiet(s);
    session_close(s);
    case_free(c);
    tu_rmtree(fdir);
    free(fdir);
}

/* The live preview (session.h): a recording steers the rough fracture's piece 2 most of the way to
 * its truth, at the hand's pace, then holds still. Near the contact the worker keeps fitting it
 * from where the hand holds it: its ghost converges within 1 mm and 1 degree of the truth while
 * the piece stays where the hand left it, the key b accepts it (one proposal at the fit's
 * tolerance, landing on the ghost), and undo puts the piece back in the hand's pose. */
static void test_preview_follows_and_accepts(void **st)
{
    (void)st;
    assert_int_equal(session_key_action('v'), LOOP_ACT_PREVIEW);
    assert_int_equal(session_key_action('b'), LOOP_ACT_ACCEPT);
    char *fdir = tu_tmpdir("session_preview");
    planning_case *c = tu_ellipsoid_fracture(fdir, 2, 3, 0);
    session *s = open_case_at(fdir, 0);
    session_set_preview(s, SESSION_PREVIEW_NEAR);
    /* the camera that makes the device's axes the world's, so the script can aim at the truth */
    session_set_camera(s, (const double[3]){1, 0, 0}, (const double[3]){0, 0, -1}, (const double[3]){0, -1, 0});
    double now[3], want[3], d[3];
    pose_apply(&c->frag[1].pose, c->frag[1].centroid, now);
    pose_apply(&c->truth[1], c->frag[1].centroid, want);
    for (int i = 0; i < 3; i++)
        d[i] = 0.7 * (want[i] - now[i]);
    char text[256];
    snprintf(text, sizeof text, "wait 0.2 s\nmove x %.3f mm y %.3f mm z %.3f mm over 1 s\nwait 0.5 s\n", d[0], d[1],
             d[2]);
    script *sc = NULL;
    assert_int_equal(script_parse(text, strlen(text), "test", &sc), 0);
    fnrec *rec = script_render(sc, sim_profile_find("spacenavigator"));
    free(sc);
    assert_non_null(rec);
    dev_handle *h;
    assert_int_equal(sim_replay_open_rec(rec, &(sim_replay_opts){1, 1}, &h), 0);
    session_dsource *ds = session_recording_new(&sim_replay_transport, h, NULL, NULL);
    assert_non_null(ds);
    assert_int_equal(session_start(s, session_device_source(ds)), 0);
    /* until the recording has played out and the ghost for where it left the piece converged */
    session_event *e;
    session_preview p;
    int ended = 0;
    for (;;) {
        e = next_event(s, SESSION_EV_END | SESSION_EV_PREVIEW);
        ended |= e->kind == SESSION_EV_END;
        session_preview_status(s, &p);
        if (ended && p.shown && p.converged && !memcmp(&p.hand, &e->scene.pose[1], sizeof(pose)))
            break;
    }
    pose hand = p.hand;
    print_message("preview: %u ghosts, %u dropped, last fit %.1f ms, ghost %.2f mm %.2f deg from the hand\n",
                  p.updates, p.dropped, p.fit_ms, p.moved_mm, p.turned_deg);
    double rot, trans, tre;
    c->frag[1].pose = hand;
    assert_int_equal(reduce_truth_errors(c, 0, 1, &rot, &trans, &tre), 0);
    print_message("the hand: %.3f deg, %.3f mm from the truth\n", rot, trans);
    assert_true(rot > 1 || trans > 1); /* the ghost has something to show */
    c->frag[1].pose = p.ghost;
    assert_int_equal(reduce_truth_errors(c, 0, 1, &rot, &trans, &tre), 0);
    print_message("the ghost: %.3f deg, %.3f mm from the truth\n", rot, trans);
    if (!(rot <= 1 && trans <= 1))
        fail_msg("the ghost converged %.3f deg, %.3f mm from the truth", rot, trans);
    assert_int_equal(p.frag, 1);
    assert_true(p.updates >= 2);
    /* accepted: one proposal landing on the ghost */
    assert_int_equal(session_send_action(s, LOOP_ACT_ACCEPT), 0);
    e = next_event(s, SESSION_EV_PREVIEW);
    while (!strstr(e->text, "accept"))
        e = next_event(s, SESSION_EV_PREVIEW);
    if (e->result != 0)
        fail_msg("%s", e->text);
    e = next_event(s, SESSION_EV_POSE);
    assert_int_equal(e->result, LOOP_ACCEPTED);
    assert_int_equal(e->frag, 1);
    assert_memory_equal(&e->scene.pose[1], &p.ghost, sizeof(pose));
    e = act(s, LOOP_ACT_UNDO);
    assert_int_equal(e->result, LOOP_ACCEPTED);
    assert_memory_equal(&e->scene.pose[1], &hand, sizeof hand);
    assert_int_equal(session_stop(s), 0);
    session_close(s);
    session_dsource_free(ds);
    fnrec_free(rec);
    case_free(c);
    tu_rmtree(fdir);
    free(fdir);
}

/* A session played on a real-time thread (bench loop --realtime plays on its loop's thread): the
 * preview's worker does not keep the policy and the CPU it inherits from that thread, where it
 * would share the loop's CPU under SCHED_FIFO (the loop then ran 17 steps a second for 124), but
 * runs under ordinary scheduling, at nice 19, on every CPU the process may use. */
struct rt_play {
    session *s;
    fnrec *rec;
    int rt, rc;
    atomic_int done;
};

static void *play_realtime(void *arg)
{
    struct rt_play *p = arg;
    p->rt = loop_realtime_priority() == 0;
    dev_handle *h;
    assert_int_equal(sim_replay_open_rec(p->rec, &(sim_replay_opts){1, 1}, &h), 0);
    session_dsource *ds = session_recording_new(&sim_replay_transport, h, NULL, NULL);
    p->rc = p->rt ? session_play(p->s, session_device_source(ds), SESSION_PLAY_LOCKSTEP) : 0;
    session_dsource_free(ds);
    atomic_store(&p->done, 1);
    return NULL;
}

/* Until a thread of this process runs at nice 19 (the preview's worker, once it has set its
 * priority; its id into *(pid_t *)arg) or the play has ended. */
static atomic_int *play_done;
static int nice_thread(void *arg)
{
    DIR *d = opendir("/proc/self/task");
    assert_non_null(d);
    for (struct dirent *e; (e = readdir(d));) {
        char path[300];
        snprintf(path, sizeof path, "/proc/self/task/%s/stat", e->d_name);
        FILE *f = e->d_name[0] != '.' ? fopen(path, "r") : NULL;
        char stat[1024] = "";
        if (f && !fgets(stat, sizeof stat, f))
            stat[0] = '\0';
        if (f)
            fclose(f);
        const char *end = strrchr(stat, ')'); /* after the name, which may hold spaces */
        long nice = 0;
        if (end && sscanf(end + 2, "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %*u %*u %*d %*d %*d %ld", &nice) == 1 &&
            nice == 19)
            *(pid_t *)arg = (pid_t)atoi(e->d_name);
    }
    closedir(d);
    return *(pid_t *)arg != 0 || atomic_load(play_done);
}

static void test_preview_worker_leaves_the_loops_cpu(void **st)
{
    (void)st;
    setenv("FRACNAV_PREVIEW_NICE", "19", 1); /* the worker's own share here (main sets 0); no thread yet */
    cpu_set_t allowed;
    assert_int_equal(sched_getaffinity(0, sizeof allowed, &allowed), 0);
    const char *text = "translate +y 1 mm over 3 s\n";
    script *sc = NULL;
    assert_int_equal(script_parse(text, strlen(text), "test", &sc), 0);
    struct rt_play p = {.s = open_case(0), .rec = script_render(sc, sim_profile_find("spacenavigator"))};
    free(sc);
    assert_non_null(p.rec);
    session_set_preview(p.s, SESSION_PREVIEW_ASKED);
    play_done = &p.done;
    pthread_t th;
    assert_int_equal(pthread_create(&th, NULL, play_realtime, &p), 0);
    pid_t worker = 0;
    assert_true(tu_wait_for(nice_thread, &worker, TU_WAIT_MAX_S));
    int policy = worker ? sched_getscheduler(worker) : -1;
    cpu_set_t cpus;
    CPU_ZERO(&cpus);
    if (worker)
        assert_int_equal(sched_getaffinity(worker, sizeof cpus, &cpus), 0);
    pthread_join(th, NULL);
    session_close(p.s);
    setenv("FRACNAV_PREVIEW_NICE", "0", 1);
    fnrec_free(p.rec);
    if (!p.rt)
        skip(); /* no real-time priority here (root or an rtprio limit grants it) */
    assert_int_equal(p.rc, 0);
    if (!worker)
        fail_msg("no thread at nice 19 while the session played with its preview");
    if (policy != SCHED_OTHER || CPU_COUNT(&cpus) != CPU_COUNT(&allowed))
        fail_msg("the preview's worker runs under policy %d (SCHED_OTHER is %d) on %d CPUs of %d", policy,
                 SCHED_OTHER, CPU_COUNT(&cpus), CPU_COUNT(&allowed));
}

/* Without a preview (the default) the keys are refused, with the reason. */
static void test_preview_off_refuses(void **st)
{
    (void)st;
    session *s = start_quiet(0);
    assert_int_equal(session_send_action(s, LOOP_ACT_PREVIEW), 0);
    session_event *e = next_event(s, SESSION_EV_PREVIEW);
    assert_int_equal(e->result, FN_EINVAL);
    assert_non_null(strstr(e->text, "has none"));
    session_preview p;
    session_preview_status(s, &p);
    assert_int_equal(p.asked, 0);
    assert_int_equal(p.shown, 0);
    assert_int_equal(session_send_action(s, LOOP_ACT_ACCEPT), 0);
    e = next_event(s, SESSION_EV_PREVIEW);
    assert_int_equal(e->result, FN_EINVAL);
    assert_non_null(strstr(e->text, "preview is off"));
    stop_quiet(s);
    session_close(s);
}

int main(void)
{
    /* the preview's worker at the test's own share: at nice 19, beside other tests under a
     * sanitizer, it got no fit done within the wait (docs/developer.md) */
    setenv("FRACNAV_PREVIEW_NICE", "0", 1);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup(test_head_on_stops_at_contact_deterministic, fresh_case),
        cmocka_unit_test_setup(test_grazing_slides, fresh_case),
        cmocka_unit_test_setup(test_unplug_keeps_pose, fresh_case),
        cmocka_unit_test_setup(test_source_by_spec, fresh_case),
        cmocka_unit_test_setup(test_actions_fix_undo_redo, fresh_case),
        cmocka_unit_test_setup(test_session_pushes_movable_for_led, fresh_case),
        cmocka_unit_test_setup(test_propose_pose_one_undoable_step, fresh_case),
        cmocka_unit_test_setup(test_fit_lands_as_one_undoable_step, fresh_case),
        cmocka_unit_test_setup(test_fit_leaves_the_gap, fresh_case),
        cmocka_unit_test(test_fit_lands_on_a_rough_fracture),
        cmocka_unit_test(test_fitted_fragment_moved),
        cmocka_unit_test_setup(test_one_overlap_figure, fresh_case),
        cmocka_unit_test_setup(test_second_fixed_fragment_saved, fresh_case),
        cmocka_unit_test(test_redo_of_a_fit),
        cmocka_unit_test_setup(test_propose_from_threads, fresh_case),
        cmocka_unit_test_setup(test_journal_recovery_and_save, fresh_case),
        cmocka_unit_test_setup(test_save_at_stop, fresh_case),
        cmocka_unit_test_setup(test_actions_done_without_waiting, fresh_case),
        cmocka_unit_test_setup(test_end_scene_and_wakeup, fresh_case),
        cmocka_unit_test_setup(test_open_errors, fresh_case),
        cmocka_unit_test(test_fragments_without_case),
        cmocka_unit_test(test_preview_follows_and_accepts),
        cmocka_unit_test(test_preview_leaves_the_piece_that_stays),
        cmocka_unit_test_setup(test_preview_off_refuses, fresh_case),
        cmocka_unit_test_setup(test_preview_worker_leaves_the_loops_cpu, fresh_case),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
