/* loop: the driver -- draining the rings, the fixed-rate run with its waits, and what keeps a
 * step from waiting on the OS (real-time priority, prefaulted pages, khugepaged held off: the
 * platform seam's). */
#include "loop_impl.h"

#include "err.h"
#include "fnclock.h"
#include "journal.h"
#include "platform.h"

#include <errno.h>
#include <semaphore.h>
#include <time.h>

void loop_set_controls(loop *L, ring *ctl)
{
    L->ctl = ctl;
}

int loop_drain(loop *L, ring *r)
{
    loop_event ev;
    int n = 0;
    while ((L->ctl && ring_pop(L->ctl, &ev)) || ring_pop(r, &ev)) {
        int rc = loop_feed(L, &ev);
        atomic_store_explicit(&L->done, L->st.events, memory_order_release);
        if (rc < 0)
            return rc;
        n++;
    }
    L->st.dropped = ring_dropped(r);
    if (n)
        loop_publish(L);
    return n;
}

int loop_realtime_priority(void)
{
    return platform_rt_priority();
}

void loop_background_priority(int nice)
{
    platform_background_priority(nice);
}

/* Tells the reader where the loop runs: on one CPU under SCHED_FIFO, or not real-time (-1). */
static void announce_cpu(loop *L, int on)
{
    int prio, cpu = on ? platform_rt_cpu(&prio) : -1;
    L->rt_prio = cpu >= 0 ? prio : 0;
    atomic_store(&L->rt_cpu, cpu);
}

int loop_running(const loop *L)
{
    return atomic_load(&L->running);
}

uint64_t loop_events_done(const loop *L)
{
    return atomic_load_explicit(&L->done, memory_order_acquire);
}

void loop_notify(loop *L)
{
    sem_post(&L->wake);
}

/* Writes the stack pages a step may reach, below the caller's frame, so that the first step
 * into a contact (the deepest collision queries) takes no first-touch page fault. */
static __attribute__((noinline)) void prefault_stack(void)
{
    unsigned char pages[LOOP_STACK_PREFAULT];
    loop__prefault(pages, sizeof pages);
}

/* Waits on the monotonic clock until deadline_us, or until loop_notify, whichever is first
 * (sem_timedwait counts in CLOCK_REALTIME: fnclock carries the time left over). */
static void wait_for_notify(loop *L, int64_t deadline_us)
{
    if (deadline_us > fnclock_now_us()) {
        struct timespec until = fnclock_realtime_deadline(deadline_us);
        while (sem_timedwait(&L->wake, &until) != 0 && errno == EINTR)
            ;
    }
    while (sem_trywait(&L->wake) == 0)
        ; /* one wake-up serves every event pushed so far */
}

static int run_until(loop *L, ring *r, int64_t period_us, const atomic_int *stop)
{
    unsigned idle = 0;
    int64_t next = loop__now_us(L);
    while (!atomic_load(stop)) {
        int rc = loop_drain(L, r);
        if (rc < 0)
            return rc;
        int64_t now = loop__now_us(L);
        if (now >= next) { /* a timer tick (not an early wake-up for an event) */
            L->win_ticks++;
            next += period_us;
            if (next < now)
                next = now + period_us; /* fell behind: do not try to catch up in a burst */
            if (L->jr && journal_tick(L->jr, now) < 0)
                L->st.journal_errors++;
            if (rc == 0 && ++idle % 50 == 0)
                loop_publish(L); /* keep the rates in the scene fresh while nothing moves */
        }
        if (L->clock.wait_until)
            L->clock.wait_until(L->clock.ctx, next);
        else
            wait_for_notify(L, next);
    }
    int rc = loop_drain(L, r);
    return rc < 0 ? rc : 0;
}

int loop_run(loop *L, ring *r, int64_t period_us, const atomic_int *stop)
{
    /* khugepaged, merging pages into a huge page, takes the range away while it copies it: a step
     * that reads there would wait for it. While any loop runs, it is kept away. */
    platform_hold_huge_pages(1);
    prefault_stack();
    platform_prefault_code();
    announce_cpu(L, 1);
    atomic_store(&L->running, 1);
    int rc = run_until(L, r, period_us, stop);
    atomic_store(&L->running, 0);
    announce_cpu(L, 0);
    platform_hold_huge_pages(0);
    return rc;
}
