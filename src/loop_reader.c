/* loop: the input thread that drains a source into the loop's ring. */
#include "loop_impl.h"

#include "err.h"

#include <pthread.h>
#include <stdlib.h>
#include <time.h>

struct loop_reader {
    loop_source src;
    ring *r;
    loop *L;
    int lockstep;
    uint64_t pushed, base; /* lockstep: events pushed; the loop's count at start */
    atomic_int stop, done;
    int errors;
    pthread_t thread;
};

static void push(loop_reader *rd, loop_event *ev)
{
    struct timespec nap = {0, 20000}; /* sleep, not spin: the loop needs the core more */
    while (rd->lockstep && loop_events_done(rd->L) - rd->base < rd->pushed && !atomic_load(&rd->stop))
        nanosleep(&nap, NULL);
    rd->pushed++;
    if (ev->arrival_us == 0)
        ev->arrival_us = loop_now_us();
    ring_push(rd->r, ev);
    if (rd->L)
        loop_notify(rd->L);
}

/* Waits up to 10 ms for an event, then takes every event already waiting without waiting. */
static void *reader_main(void *arg)
{
    loop_reader *rd = arg;
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
