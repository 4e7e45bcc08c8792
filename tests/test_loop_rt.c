/* Where the real-time loop and its input thread run. A report must not wake the loop on another
 * CPU (there the loop waits until that CPU's task leaves the kernel: milliseconds on a busy
 * machine): loop_realtime_priority keeps the loop's thread on one CPU, and the reader, though
 * started by an ordinary thread (as navigate starts it), moves to that CPU at a real-time
 * priority just below the loop's. Skipped where real-time priority is not granted.
 * And while a loop runs, khugepaged keeps out of the process (merging pages into a huge page, it
 * takes them away from a step for milliseconds); afterwards the process has it back. */
#define _GNU_SOURCE /* sched_getcpu, CPU_COUNT */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "loop.h"
#include "ring.h"

#include <pthread.h>
#include <sched.h>
#include <semaphore.h>
#include <stdatomic.h>
#include <string.h>
#include <sys/prctl.h>

#define EVENTS 40

typedef struct where {
    int cpu, policy, prio;
} where;

static where here(void)
{
    where w;
    struct sched_param sp;
    pthread_getschedparam(pthread_self(), &w.policy, &sp);
    w.prio = sp.sched_priority;
    w.cpu = sched_getcpu();
    return w;
}

static where loop_at, reader_at;
static atomic_int thp_off_in_step; /* PR_GET_THP_DISABLE seen by the last step */
static int loop_cpus; /* CPUs the loop's thread may run on */

/* A collider that never collides and records the thread that steps. */
static int query(void *ctx, int a, const pose *pa, int b, const pose *pb, double tol, void *cache,
                 loop_contact *out)
{
    loop_at = here();
    atomic_store(&thp_off_in_step, prctl(PR_GET_THP_DISABLE, 0, 0, 0, 0));
    out->collides = 0;
    out->separation_mm = 0; /* no shortcut: every step queries */
    return 0;
}

/* A source of EVENTS motion reports that records the thread that reads them. */
static int next(void *ctx, loop_event *ev, int timeout_ms)
{
    int *k = ctx;
    reader_at = here();
    if (*k == EVENTS)
        return LOOP_SOURCE_END;
    memset(ev, 0, sizeof *ev);
    ev->kind = LOOP_EV_MOTION;
    ev->t_us = 8000 * (int64_t)(*k)++;
    ev->motion[0] = 0.5f;
    return 1;
}

typedef struct runner {
    loop *L;
    ring *r;
    sem_t started;
    atomic_int go, granted;
    const atomic_int *stop;
    int rc;
} runner;

static void *loop_thread(void *arg)
{
    runner *ru = arg;
    atomic_store(&ru->granted, loop_realtime_priority() == 0);
    cpu_set_t set;
    pthread_getaffinity_np(pthread_self(), sizeof set, &set);
    loop_cpus = CPU_COUNT(&set);
    sem_post(&ru->started);
    while (atomic_load(&ru->go) == 0)
        sched_yield();
    if (atomic_load(&ru->granted) && ru->stop)
        ru->rc = loop_run(ru->L, ru->r, 1000, ru->stop);
    return NULL;
}

/* Two 2-voxel cubes 100 mm apart, the second fixed, under the recording collider. */
static loop *two_cubes(frag f[2])
{
    memset(f, 0, 2 * sizeof *f);
    for (int i = 0; i < 2; i++) {
        f[i].dim[0] = f[i].dim[1] = f[i].dim[2] = 2;
        f[i].spacing[0] = f[i].spacing[1] = f[i].spacing[2] = 1;
        f[i].home = f[i].pose = POSE_IDENTITY;
    }
    f[1].home.t[0] = 100;
    loop_collider col = {query, 0, NULL, NULL};
    uint8_t fixed[2] = {0, 1};
    loop *L = loop_new(f, 2, fixed, &col, NULL, NULL);
    assert_non_null(L);
    return L;
}

static void test_reader_follows_realtime_loop(void **st)
{
    frag f[2];
    loop *L = two_cubes(f);
    runner ru = {.L = L, .r = ring_new(sizeof(loop_event), 64)};
    assert_non_null(ru.r);
    sem_init(&ru.started, 0, 0);
    atomic_init(&ru.go, 0);
    atomic_init(&ru.granted, 0);
    pthread_t th;
    assert_int_equal(pthread_create(&th, NULL, loop_thread, &ru), 0);
    sem_wait(&ru.started);
    loop_reader *rd = NULL;
    int k = 0;
    if (atomic_load(&ru.granted)) { /* lockstep: each report waits until the loop took the last */
        rd = loop_reader_start((loop_source){next, &k}, ru.r, L, 1);
        assert_non_null(rd);
        ru.stop = loop_reader_done_flag(rd);
    }
    atomic_store(&ru.go, 1);
    pthread_join(th, NULL);
    int granted = atomic_load(&ru.granted);
    loop_reader_stop(rd);
    ring_free(ru.r);
    loop_free(L);
    sem_destroy(&ru.started);
    if (!granted)
        skip(); /* no CAP_SYS_NICE or rtprio limit here: nothing to check */

    assert_int_equal(ru.rc, 0);
    assert_int_equal(k, EVENTS);
    assert_int_equal(loop_cpus, 1);
    assert_int_equal(loop_at.policy, SCHED_FIFO);
    assert_int_equal(reader_at.cpu, loop_at.cpu);
    assert_int_equal(reader_at.policy, SCHED_FIFO);
    assert_int_equal(reader_at.prio, loop_at.prio - 1);
}

typedef struct plain {
    loop *L;
    ring *r;
    atomic_int stop;
    int rc;
} plain;

static void *plain_loop(void *arg)
{
    plain *p = arg;
    p->rc = loop_run(p->L, p->r, 1000, &p->stop);
    return NULL;
}

static void test_khugepaged_kept_out_while_running(void **st)
{
    assert_int_equal(prctl(PR_GET_THP_DISABLE, 0, 0, 0, 0), 0);
    frag f[2];
    plain p = {two_cubes(f), ring_new(sizeof(loop_event), 64), 0, 0};
    assert_non_null(p.r);
    atomic_init(&p.stop, 0);
    atomic_store(&thp_off_in_step, -1);
    pthread_t th;
    assert_int_equal(pthread_create(&th, NULL, plain_loop, &p), 0);
    loop_event ev = {.kind = LOOP_EV_MOTION, .t_us = 8000, .motion = {0.5f}};
    assert_int_equal(ring_push(p.r, &ev), 1);
    loop_notify(p.L);
    while (loop_events_done(p.L) < 1)
        sched_yield();
    atomic_store(&p.stop, 1);
    loop_notify(p.L);
    pthread_join(th, NULL);
    assert_int_equal(p.rc, 0);
    assert_int_equal(atomic_load(&thp_off_in_step), 1);
    assert_int_equal(prctl(PR_GET_THP_DISABLE, 0, 0, 0, 0), 0);
    ring_free(p.r);
    loop_free(p.L);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_khugepaged_kept_out_while_running),
        cmocka_unit_test(test_reader_follows_realtime_loop),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
