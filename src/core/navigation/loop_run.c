/* loop: the driver -- draining the rings, the fixed-rate run with its waits, and what keeps a
 * step from waiting on the OS (real-time priority, prefaulted pages, khugepaged held off). */
#define _GNU_SOURCE /* CPU affinity: sched_getcpu, pthread_setaffinity_np */
#include "loop_impl.h"

#include "err.h"
#include "fnclock.h"
#include "journal.h"

#include <errno.h>
#include <link.h>
#include <pthread.h>
#include <sched.h>
#include <semaphore.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <time.h>
#include <unistd.h>

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
    struct sched_param sp = {.sched_priority = 10};
    int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
    if (rc != 0)
        return fn_err_set(FN_EINVAL, "real-time priority not granted: %s", strerror(rc));
    int cpu = sched_getcpu();
    cpu_set_t one;
    CPU_ZERO(&one);
    if (cpu >= 0)
        CPU_SET(cpu, &one);
    if (cpu < 0 || (rc = pthread_setaffinity_np(pthread_self(), sizeof one, &one)) != 0)
        return fn_err_set(FN_EINVAL, "real-time priority granted, but the thread cannot be kept on "
                                     "CPU %d: %s", cpu, strerror(cpu < 0 ? errno : rc));
    return 0;
}

/* Tells the reader where the loop runs: on one CPU under SCHED_FIFO, or not real-time (-1). */
static void announce_cpu(loop *L, int on)
{
    int policy = SCHED_OTHER;
    struct sched_param sp = {0};
    on = on && pthread_getschedparam(pthread_self(), &policy, &sp) == 0 && policy == SCHED_FIFO;
    L->rt_prio = sp.sched_priority;
    atomic_store(&L->rt_cpu, on ? sched_getcpu() : -1);
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

/* Maps every page of one loaded object (the program, libm, libc, zlib, ...) into the page
 * tables, so that the first step that runs some code or reads some table (the first rotation's
 * sincos, the journal's CRC) takes no page fault. Where the kernel lacks MADV_POPULATE_READ
 * (before 5.14), readable pages are read instead. */
static int prefault_object(struct dl_phdr_info *info, size_t size, void *unused)
{
    (void)size;
    (void)unused;
    uintptr_t page = (uintptr_t)sysconf(_SC_PAGESIZE);
    for (int i = 0; i < info->dlpi_phnum; i++) {
        const ElfW(Phdr) *ph = &info->dlpi_phdr[i];
        if (ph->p_type != PT_LOAD || ph->p_memsz == 0)
            continue;
        uintptr_t lo = (info->dlpi_addr + ph->p_vaddr) & ~(page - 1);
        uintptr_t hi = info->dlpi_addr + ph->p_vaddr + ph->p_memsz;
        if (madvise((void *)lo, hi - lo, MADV_POPULATE_READ) == 0 || errno != EINVAL ||
            !(ph->p_flags & PF_R))
            continue;
        for (uintptr_t a = lo; a < hi; a += page)
            (void)*(volatile const unsigned char *)a;
    }
    return 0;
}

/* khugepaged, when it merges a process's pages into a huge page, takes the range away while it
 * copies it: a step that reads there waits for it (a page fault of milliseconds). While any loop
 * runs, the process's memory is kept out of its reach (huge pages made before stay huge); the
 * last loop to stop gives it back, unless it was kept out before. */
static pthread_mutex_t thp_lock = PTHREAD_MUTEX_INITIALIZER;
static int thp_holds, thp_was_off;

static void hold_huge_pages(int on)
{
    pthread_mutex_lock(&thp_lock);
    if (on && thp_holds++ == 0) {
        thp_was_off = prctl(PR_GET_THP_DISABLE, 0, 0, 0, 0) == 1;
        if (!thp_was_off)
            prctl(PR_SET_THP_DISABLE, 1, 0, 0, 0);
    } else if (!on && --thp_holds == 0 && !thp_was_off) {
        prctl(PR_SET_THP_DISABLE, 0, 0, 0, 0);
    }
    pthread_mutex_unlock(&thp_lock);
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
    hold_huge_pages(1);
    prefault_stack();
    dl_iterate_phdr(prefault_object, NULL);
    announce_cpu(L, 1);
    atomic_store(&L->running, 1);
    int rc = run_until(L, r, period_us, stop);
    atomic_store(&L->running, 0);
    announce_cpu(L, 0);
    hold_huge_pages(0);
    return rc;
}
