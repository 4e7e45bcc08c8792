/* loop: statistics, the scene buffer a renderer reads, and the fixed-rate driver. */
#define _GNU_SOURCE /* CPU affinity: sched_getcpu, pthread_setaffinity_np */
#include "loop_impl.h"

#include "err.h"
#include "fnclock.h"
#include "journal.h"

#include <errno.h>
#include <link.h>
#include <pthread.h>
#include <sched.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <semaphore.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <time.h>
#include <unistd.h>

#define FNV_OFFSET 0xcbf29ce484222325ull
#define FNV_PRIME 0x100000001b3ull

/* The monotonic clock; its wait ends at the deadline or at loop_notify, whichever is first
 * (sem_timedwait counts in CLOCK_REALTIME: fnclock carries the time left over). */
static int64_t mono_now_us(void *ctx)
{
    (void)ctx;
    return fnclock_now_us();
}

static void mono_wait_until(void *ctx, int64_t deadline_us)
{
    loop *L = ctx;
    if (deadline_us > fnclock_now_us()) {
        struct timespec until = fnclock_realtime_deadline(deadline_us);
        while (sem_timedwait(&L->wake, &until) != 0 && errno == EINTR)
            ;
    }
    while (sem_trywait(&L->wake) == 0)
        ; /* one wake-up serves every event pushed so far */
}

void loop_set_clock(loop *L, const loop_clock *c)
{
    L->clock = c ? *c : (loop_clock){mono_now_us, mono_wait_until, L};
    loop_reset_timing(L);
}

int64_t loop__now_us(const loop *L)
{
    return L->clock.now_us(L->clock.ctx);
}

void loop_stats_init(loop *L)
{
    L->st.pose_digest = FNV_OFFSET;
    for (int b = 0; b < LOOP_SCENE_BUFS; b++)
        atomic_init(&L->refs[b], 0);
    atomic_init(&L->latest, 0);
    sem_init(&L->wake, 0, 0);
    atomic_init(&L->done, 0);
    atomic_init(&L->rt_cpu, -1);
    loop_set_clock(L, NULL);
    loop_publish(L);
}

void loop_reset_timing(loop *L)
{
    memset(L->hist, 0, sizeof L->hist);
    L->hist_over = 0;
    L->lat_max = 0;
    L->st.latency_samples = 0;
    L->st.latency_p50_us = L->st.latency_p99_us = L->st.latency_max_us = 0;
    L->q_sum_ns = L->q_max_ns = 0;
    L->st.queries = 0;
    L->win_start_us = loop__now_us(L);
    L->pct_at_us = 0;
    L->win_steps = L->win_ticks = 0;
}

void loop_stats_query(loop *L, int64_t ns)
{
    L->st.queries++;
    L->q_sum_ns += (double)ns;
    if (ns > L->q_max_ns)
        L->q_max_ns = (double)ns;
}

/* FNV-1a 64 over the fragment index (u32 LE) and the 7 doubles' bytes (LE): the same on every
 * machine with IEEE doubles. */
void loop_stats_pose(loop *L, int s, const pose *p)
{
    uint64_t h = L->st.pose_digest;
    unsigned char b[4 + 56];
    for (int i = 0; i < 4; i++)
        b[i] = (unsigned char)((uint32_t)s >> (8 * i));
    const double *v[7] = {&p->q[0], &p->q[1], &p->q[2], &p->q[3], &p->t[0], &p->t[1], &p->t[2]};
    for (int k = 0; k < 7; k++) {
        uint64_t u;
        memcpy(&u, v[k], 8);
        for (int i = 0; i < 8; i++)
            b[4 + 8 * k + i] = (unsigned char)(u >> (8 * i));
    }
    for (size_t i = 0; i < sizeof b; i++)
        h = (h ^ b[i]) * FNV_PRIME;
    L->st.pose_digest = h;
}

void loop_stats_outcome(loop *L, int outcome)
{
    L->st.steps++;
    L->win_steps++;
    if (outcome == LOOP_ACCEPTED)
        L->st.accepted++;
    else if (outcome == LOOP_LIMITED)
        L->st.limited++;
    else if (outcome == LOOP_SLID)
        L->st.slid++;
    else if (outcome == LOOP_REFUSED)
        L->st.refused++;
}

void loop_stats_latency(loop *L, int64_t us)
{
    if (us < 0)
        us = 0;
    if (us < LOOP_HIST_BINS)
        L->hist[us]++;
    else
        L->hist_over++;
    if ((double)us > L->lat_max)
        L->lat_max = (double)us;
    L->st.latency_samples++;
}

/* The latency below which a fraction q of the samples lie (bin upper edge). */
static double percentile(const loop *L, double q)
{
    uint64_t want = (uint64_t)ceil(q * (double)L->st.latency_samples), seen = 0;
    for (int i = 0; i < LOOP_HIST_BINS; i++) {
        seen += L->hist[i];
        if (seen >= want && want > 0)
            return i + 1 > L->lat_max ? L->lat_max : i + 1;
    }
    return L->lat_max;
}

static void refresh_rates(loop *L, int64_t now)
{
    double secs = (double)(now - L->win_start_us) * 1e-6;
    L->st.step_hz = secs > 0 ? (double)L->win_steps / secs : 0;
    L->st.tick_hz = secs > 0 ? (double)L->win_ticks / secs : 0;
    L->st.query_us_mean = L->st.queries ? L->q_sum_ns / (double)L->st.queries * 1e-3 : 0;
    L->st.query_us_max = L->q_max_ns * 1e-3;
    L->st.latency_p50_us = percentile(L, 0.50);
    L->st.latency_p99_us = percentile(L, 0.99);
    L->st.latency_max_us = L->lat_max;
    L->pct_at_us = now;
}

void loop_get_stats(loop *L, loop_stats *out)
{
    refresh_rates(L, loop__now_us(L));
    *out = L->st;
}

/* A buffer no reader holds and that is not the newest; -1 when readers hold them all. */
static int free_buffer(loop *L)
{
    int newest = atomic_load(&L->latest);
    for (int k = 1; k < LOOP_SCENE_BUFS; k++) {
        int b = (newest + k) % LOOP_SCENE_BUFS;
        if (atomic_load(&L->refs[b]) == 0)
            return b;
    }
    return -1;
}

void loop_publish(loop *L)
{
    int64_t now = loop__now_us(L);
    if (now - L->pct_at_us >= 100000) /* percentiles cost a histogram walk: 10 Hz is plenty */
        refresh_rates(L, now);
    int b = free_buffer(L);
    if (b < 0)
        return; /* never wait for readers: the next publish carries this state too */
    loop_scene *s = &L->buf[b];
    s->seq = ++L->pub_seq;
    s->nfrag = L->n;
    s->selected = L->selected;
    s->collision_on = L->collision_on;
    s->trans_only = L->trans_only;
    s->rot_only = L->rot_only;
    s->device_present = L->device_present;
    s->save_requests = L->save_requests;
    s->frame = L->cfg.frame;
    s->last_outcome = L->last_outcome;
    s->penetrating = L->collision_on && L->in_collision;
    s->separation_mm = !L->collision_on ? NAN : L->in_collision ? L->pen : L->gap_valid ? L->gap : NAN;
    s->actions = L->actions;
    s->last_action = (loop_action)L->last_action;
    s->last_action_result = L->last_action_result;
    s->stats = L->st;
    memcpy(s->pose, L->pose, sizeof(pose) * (size_t)L->n);
    memcpy(s->fixed, L->fixed, (size_t)L->n);
    atomic_store(&L->latest, b);
}

/* Pins the newest buffer: after the pin it must still be the newest, else the writer may have
 * picked it for filling (it was not pinned when the writer looked) and the reader tries again. */
int loop_scene_read(loop *L, loop_scene *out)
{
    uint64_t had = out->seq;
    for (;;) {
        int b = atomic_load(&L->latest);
        atomic_fetch_add(&L->refs[b], 1);
        if (atomic_load(&L->latest) == b) {
            *out = L->buf[b];
            atomic_fetch_sub(&L->refs[b], 1);
            break;
        }
        atomic_fetch_sub(&L->refs[b], 1);
    }
    return out->seq != had;
}

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
        L->clock.wait_until(L->clock.ctx, next);
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
    int rc = run_until(L, r, period_us, stop);
    announce_cpu(L, 0);
    hold_huge_pages(0);
    return rc;
}
