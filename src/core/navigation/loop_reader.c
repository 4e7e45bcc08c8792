/* loop: the input thread that drains a source into the loop's ring. */
#include "fnclock.h"
#include "loop_impl.h"

#include "err.h"
#include "platform.h"

#include <pthread.h>
#include <stdlib.h>

struct loop_reader {
    loop_source src;
    ring *r;
    loop *L;
    int lockstep;
    int cpu; /* the real-time loop's CPU this thread follows (-1: none) */
    uint64_t pushed, base; /* lockstep: events pushed; the loop's count at start */
    atomic_int stop, done;
    int errors;
    pthread_t thread;
};

/* Runs this thread where a real-time loop runs: on its CPU, one priority step below it. A report
 * then wakes the loop on the CPU this thread holds, and the loop takes it over at once. Woken on
 * another CPU, the loop would wait there until that CPU's task left the kernel: milliseconds on
 * a busy machine whose kernel does not preempt kernel code. Below the loop's priority, this
 * thread can never hold the loop up, and it still goes before every ordinary task. */
static void follow_loop(loop_reader *rd)
{
    int cpu = atomic_load(&rd->L->rt_cpu);
    if (cpu == rd->cpu)
        return;
    rd->cpu = cpu;
    if (cpu >= 0)
        platform_rt_follow(cpu, rd->L->rt_prio > 1 ? rd->L->rt_prio - 1 : 1);
}

static void push(loop_reader *rd, loop_event *ev)
{
    while (rd->lockstep && loop_events_done(rd->L) - rd->base < rd->pushed && !atomic_load(&rd->stop))
        fnclock_sleep_us(20); /* sleep, not spin: the loop needs the core more */
    if (rd->L)
        follow_loop(rd);
    rd->pushed++;
    if (ev->arrival_us == 0)
        ev->arrival_us = fnclock_now_us();
    ring_push(rd->r, ev);
    if (rd->L)
        loop_notify(rd->L);
}

/* Waits until the loop runs (or this thread is stopped): the loop's start maps its pages, and a
 * report pushed meanwhile would wait for that in the ring. */
static void await_loop(loop_reader *rd)
{
    while (rd->L && !loop_running(rd->L) && !atomic_load(&rd->stop))
        fnclock_sleep_us(50);
}

/* Waits up to 10 ms for an event, then takes every event already waiting without waiting. */
static void *reader_main(void *arg)
{
    loop_reader *rd = arg;
    await_loop(rd);
    while (!atomic_load(&rd->stop)) {
        int timeout = 10;
        for (;;) {
            loop_event ev = {0};
            int rc = rd->src.next(rd->src.ctx, &ev, timeout);
            if (rc == 1) {
                push(rd, &ev);
                timeout = 0;
                continue;
            }
            if (rc == LOOP_SOURCE_END) {
                atomic_store(&rd->done, 1);
                if (rd->L)
                    loop_notify(rd->L);
                return NULL;
            }
            if (rc < 0)
                rd->errors++;
            break;
        }
    }
    return NULL;
}

loop_reader *loop_reader_start(loop_source src, ring *r, loop *L, int lockstep)
{
    loop_reader *rd = calloc(1, sizeof *rd);
    if (!rd) {
        fn_err_set(FN_ENOMEM, "loop reader: out of memory");
        return NULL;
    }
    rd->src = src;
    rd->r = r;
    rd->L = L;
    rd->lockstep = lockstep && L;
    rd->cpu = -1;
    rd->base = L ? loop_events_done(L) : 0;
    atomic_init(&rd->stop, 0);
    atomic_init(&rd->done, 0);
    if (pthread_create(&rd->thread, NULL, reader_main, rd) != 0) {
        free(rd);
        fn_err_set(FN_EIO, "loop reader: cannot start the input thread");
        return NULL;
    }
    return rd;
}

int loop_reader_done(loop_reader *rd)
{
    return atomic_load(&rd->done);
}

const atomic_int *loop_reader_done_flag(loop_reader *rd)
{
    return &rd->done;
}

int loop_reader_stop(loop_reader *rd)
{
    if (!rd)
        return 0;
    atomic_store(&rd->stop, 1);
    pthread_join(rd->thread, NULL);
    int errors = rd->errors;
    free(rd);
    return errors;
}
