/* The real-time step allocates nothing: motion into and along contact on real OBB octrees, with the
 * journal on, the scene published and read, actions and undo/redo, all fed through the ring.
 * Nor does it touch a page for the first time: a first-touch page fault stalls the step (the
 * kernel zeroes or maps the page), so after loop_new and a few free steps on the loop's own
 * thread, stepping into and along a contact costs no page fault in the process. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "allocount.h"
#include "fnclock.h"
#include "journal.h"
#include "loop.h"
#include "ring.h"
#include "testutil.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

/* Fragment 0: a movable 8^3 cube at the origin; fragment 1: a fixed 24x24x4 slab just above it. */
static void make(frag f[2])
{
    int dims[2][3] = {{8, 8, 8}, {24, 24, 4}};
    double at[2][3] = {{0, 0, 0}, {-8, -8, 10}};
    for (int i = 0; i < 2; i++)
        tu_box_frag(&f[i], i + 1, dims[i], at[i]);
}

static loop_event motion(int k, float tx, float tz, float ry)
{
    loop_event e;
    memset(&e, 0, sizeof e);
    e.kind = LOOP_EV_MOTION;
    e.t_us = 8000 * (int64_t)k;
    e.arrival_us = fnclock_now_us();
    e.motion[0] = tx, e.motion[2] = tz, e.motion[4] = ry;
    return e;
}

static loop_event action(int k, loop_action a)
{
    loop_event e;
    memset(&e, 0, sizeof e);
    e.kind = LOOP_EV_ACTION;
    e.action = a;
    e.t_us = 8000 * (int64_t)k;
    return e;
}

static void test_steps_allocate_nothing(void **st)
{
    if (!allocount_available())
        skip(); /* AddressSanitizer owns malloc */
    frag f[2];
    make(f);
    char *dir = tu_tmpdir("loopalloc");
    journal_bind bind = {"", 2, {1, 2}};
    journal *jr = journal_open(dir, &bind);
    assert_non_null(jr);
    loop_obb *o = loop_obb_new(f, 2, NULL, NULL);
    assert_non_null(o);
    loop_collider col = loop_obb_collider(o);
    loop_config c;
    loop_config_default(&c);
    c.frame = LOOP_FRAME_WORLD;
    c.check_invariant = 1;
    uint8_t fixed[2] = {0, 1};
    loop *L = loop_new(f, 2, fixed, &col, &c, jr);
    assert_non_null(L);
    ring *r = ring_new(sizeof(loop_event), 1024);
    assert_non_null(r);
    loop_scene sc;

    allocount_start();
    int k = 0;
    for (int i = 0; i < 150; i++, k++) { /* up into the slab: free, then limited and refused */
        loop_event e = motion(k, 0, 1, 0);
        ring_push(r, &e);
        loop_drain(L, r);
        loop_publish(L);
        loop_scene_read(L, &sc);
    }
    for (int i = 0; i < 150; i++, k++) { /* along it while pressing up, tilting: sliding */
        loop_event e = motion(k, 1, 0.5f, 0.2f);
        loop_feed(L, &e);
    }
    loop_action acts[] = {LOOP_ACT_UNDO, LOOP_ACT_UNDO, LOOP_ACT_REDO, LOOP_ACT_TRANS_ONLY,
                          LOOP_ACT_TRANS_ONLY, LOOP_ACT_FRAME, LOOP_ACT_SAVE};
    for (size_t i = 0; i < sizeof acts / sizeof *acts; i++, k++) {
        loop_event e = action(k, acts[i]);
        loop_feed(L, &e);
    }
    for (int i = 0; i < 100; i++, k++) {
        loop_event e = motion(k, -1, 0.5f, -0.3f);
        loop_feed(L, &e);
    }
    for (int i = 0; i < 20; i++, k++) { /* proposed poses (the reduction worker's): taken or refused */
        loop_event e = {.kind = LOOP_EV_POSE, .t_us = k, .frag = 0, .pose = loop_pose(L, 0)};
        e.pose.t[1] += (i % 2 ? 5.0 : -0.1);
        ring_push(r, &e);
        loop_drain(L, r);
    }
    long allocs = allocount_stop();

    loop_stats s;
    loop_get_stats(L, &s);
    assert_true(s.accepted > 0 && s.refused + s.limited > 0 && s.slid > 0);
    assert_int_equal(s.collisions_in_accepted, 0);
    if (allocs)
        fail_msg("%ld heap allocations in %d loop steps", allocs, k);
    ring_free(r);
    loop_free(L);
    loop_obb_free(o);
    assert_int_equal(journal_close(jr), 0);
    free(f[0].prob);
    free(f[1].prob);
    tu_rmtree(dir);
    free(dir);
}

typedef struct runner {
    loop *L;
    ring *r;
    atomic_int stop;
    int rc;
} runner;

static void *run_loop(void *arg)
{
    runner *ru = arg;
    ru->rc = loop_run(ru->L, ru->r, 1000, &ru->stop);
    return NULL;
}

/* Hands one event to the running loop and waits until the loop has finished it. */
static void feed_running(runner *ru, const loop_event *e)
{
    uint64_t want = loop_events_done(ru->L) + 1;
    assert_int_equal(ring_push(ru->r, e), 1);
    loop_notify(ru->L);
    while (loop_events_done(ru->L) < want)
        sched_yield();
}

static long minor_faults(void)
{
    struct rusage u;
    getrusage(RUSAGE_SELF, &u);
    return u.ru_minflt + u.ru_majflt;
}

static void test_steps_touch_no_new_page(void **st)
{
    if (!allocount_available())
        skip(); /* AddressSanitizer maps shadow pages as it goes */
    frag f[2];
    make(f);
    char *dir = tu_tmpdir("loopfault");
    journal_bind bind = {"", 2, {1, 2}};
    journal *jr = journal_open(dir, &bind);
    assert_non_null(jr);
    loop_obb *o = loop_obb_new(f, 2, NULL, NULL);
    assert_non_null(o);
    loop_collider col = loop_obb_collider(o);
    loop_config c;
    loop_config_default(&c);
    c.frame = LOOP_FRAME_WORLD;
    uint8_t fixed[2] = {0, 1};
    loop *L = loop_new(f, 2, fixed, &col, &c, jr);
    assert_non_null(L);
    runner ru = {L, ring_new(sizeof(loop_event), 1024), 0, 0};
    assert_non_null(ru.r);
    atomic_init(&ru.stop, 0);
    pthread_t th;
    assert_int_equal(pthread_create(&th, NULL, run_loop, &ru), 0);
    int k = 0;
    for (int i = 0; i < 3; i++, k++) { /* warm-up: free steps, away from the slab */
        loop_event e = motion(k, 0, -0.2f, 0);
        feed_running(&ru, &e);
    }

    long before = minor_faults();
    for (int i = 0; i < 200; i++, k++) { /* up into the slab, then along it, tilting */
        loop_event e = i < 120 ? motion(k, 0, 1, 0) : motion(k, 1, 0.5f, 0.2f);
        feed_running(&ru, &e);
    }
    loop_action acts[] = {LOOP_ACT_UNDO, LOOP_ACT_UNDO, LOOP_ACT_REDO, LOOP_ACT_SAVE};
    for (size_t i = 0; i < sizeof acts / sizeof *acts; i++, k++) {
        loop_event e = action(k, acts[i]);
        feed_running(&ru, &e);
    }
    long faults = minor_faults() - before;

    atomic_store(&ru.stop, 1);
    loop_notify(L);
    pthread_join(th, NULL);
    assert_int_equal(ru.rc, 0);
    loop_stats s;
    loop_get_stats(L, &s);
    assert_true(s.accepted > 0 && s.refused + s.limited + s.slid > 0);
    if (faults)
        fail_msg("%ld page faults in %d loop steps after warm-up", faults, k - 3);
    ring_free(ru.r);
    loop_free(L);
    loop_obb_free(o);
    assert_int_equal(journal_close(jr), 0);
    free(f[0].prob);
    free(f[1].prob);
    tu_rmtree(dir);
    free(dir);
}

/* A collider whose cache remembers the pair it was given for: a pair must never find another pair's
 * state in its cache (only zeros, or its own). */
typedef struct pair_mark {
    int a, b, set;
} pair_mark;

static int foreign; /* queries that found another pair's mark */

static int marking(void *ctx, int a, const pose *pa, int b, const pose *pb, double tol_mm,
                   void *cache, loop_contact *out)
{
    pair_mark *m = cache;
    if (m->set && (m->a != a || m->b != b))
        foreign++;
    *m = (pair_mark){a, b, 1};
    out->collides = 0;
    out->separation_mm = 0.01; /* close: every step queries */
    return 0;
}

/* The pair caches grow with the fragments, not with their pairs: 16 fragments with 1 MiB caches
 * ask for about 17 MiB (a slot per fragment and a scratch), not 257 MiB (n*n). Each fragment in
 * turn moves against the others, and no pair is handed another's cache. */
static void test_pair_caches_grow_with_fragments(void **st)
{
    enum { N = 16 };
    const size_t cb = 1u << 20;
    frag f[N];
    for (int i = 0; i < N; i++)
        tu_box_frag(&f[i], i + 1, (const int[3]){2, 2, 2}, (const double[3]){10.0 * i, 0, 0});
    loop_collider col = {.query = marking, .cache_bytes = cb};
    allocount_start();
    loop *L = loop_new(f, N, NULL, &col, NULL, NULL);
    long long asked = allocount_bytes();
    allocount_stop();
    assert_non_null(L);
    if (allocount_available() && asked > (long long)(N + 4) * (long long)cb)
        fail_msg("loop_new asked for %lld bytes for %d fragments with %zu-byte caches", asked, N, cb);
    foreign = 0;
    for (int k = 0; k < 3 * N; k++) {
        loop_event e = motion(2 * k, 0.1f, 0, 0);
        assert_true(loop_feed(L, &e) >= 0);
        e = action(2 * k + 1, LOOP_ACT_NEXT);
        assert_true(loop_feed(L, &e) >= 0);
    }
    loop_stats stats;
    loop_get_stats(L, &stats);
    assert_true(stats.queries > (uint64_t)N * (N - 1));
    assert_int_equal(foreign, 0);
    loop_free(L);
    for (int i = 0; i < N; i++)
        free(f[i].prob);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_steps_touch_no_new_page), /* first: nothing has run the step yet */
        cmocka_unit_test(test_steps_allocate_nothing),
        cmocka_unit_test(test_pair_caches_grow_with_fragments),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
