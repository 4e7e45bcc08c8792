/* fnclock: the monotonic clock and its conversions. */
#include "fnclock.h"

#include <errno.h>

#define US_PER_S 1000000
#define NS_PER_US 1000
#define NS_PER_S 1000000000L

int64_t fnclock_now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * NS_PER_S + ts.tv_nsec;
}

int64_t fnclock_now_us(void)
{
    return fnclock_now_ns() / NS_PER_US;
}

static int64_t clock_ns(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return (int64_t)ts.tv_sec * NS_PER_S + ts.tv_nsec;
}

int64_t fnclock_thread_cpu_ns(void)
{
    return clock_ns(CLOCK_THREAD_CPUTIME_ID);
}

int64_t fnclock_process_cpu_ns(void)
{
    return clock_ns(CLOCK_PROCESS_CPUTIME_ID);
}

/* Whole seconds first, then the nanoseconds carried into 0..NS_PER_S-1 (C division truncates
 * towards zero, so a negative remainder borrows a second). */
struct timespec fnclock_add_us(struct timespec t, int64_t us)
{
    int64_t sec = (int64_t)t.tv_sec + us / US_PER_S;
    int64_t nsec = (int64_t)t.tv_nsec + (us % US_PER_S) * NS_PER_US;
    if (nsec >= NS_PER_S) {
        nsec -= NS_PER_S;
        sec++;
    } else if (nsec < 0) {
        nsec += NS_PER_S;
        sec--;
    }
    return (struct timespec){.tv_sec = (time_t)sec, .tv_nsec = (long)nsec};
}

struct timespec fnclock_timespec(int64_t us)
{
    return fnclock_add_us((struct timespec){0, 0}, us);
}

struct timespec fnclock_realtime_deadline(int64_t deadline_us)
{
    int64_t left = deadline_us - fnclock_now_us();
    struct timespec now;
    clock_gettime(CLOCK_REALTIME, &now);
    return left > 0 ? fnclock_add_us(now, left) : now;
}

void fnclock_sleep_us(int64_t us)
{
    fnclock_sleep_until(fnclock_now_us() + us);
}

void fnclock_sleep_until(int64_t deadline_us)
{
    struct timespec ts = fnclock_timespec(deadline_us);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR)
        ;
}
