/* fnclock: the one monotonic clock of the program, and the ways to wait on it.
 *
 * Every time stamp (device reports, journal records, the loop's ticks, the simulator's playback)
 * is microseconds of CLOCK_MONOTONIC: it never jumps with the wall clock. POSIX waits that take
 * an absolute CLOCK_REALTIME time (sem_timedwait, pthread_cond_timedwait with default
 * attributes) get one from fnclock_realtime_deadline. All functions are thread-safe. */
#ifndef FN_FNCLOCK_H
#define FN_FNCLOCK_H

#include <stdint.h>
#include <time.h>

/* The longest interval one motion report acts over: after a pause (a stall, a replug) motion
 * resumes from there and never jumps. The one pause clamp: the loop's (loop_config.dt_max_us by
 * default) and the device events' (dev_event.dt_us). */
#define FNCLOCK_PAUSE_MAX_US 20000

/* Monotonic time in microseconds, and in nanoseconds (for measuring short work). */
int64_t fnclock_now_us(void);
int64_t fnclock_now_ns(void);
/* CPU time the calling thread has used, in nanoseconds: immune to being descheduled. */
int64_t fnclock_thread_cpu_ns(void);
/* CPU time the whole process has used (all its threads, a library's too), in nanoseconds. */
int64_t fnclock_process_cpu_ns(void);

/* t moved by us microseconds (either sign), with tv_nsec kept in 0..999999999. */
struct timespec fnclock_add_us(struct timespec t, int64_t us);
/* A time of us microseconds as a timespec (fnclock_add_us from zero). */
struct timespec fnclock_timespec(int64_t us);
/* The CLOCK_REALTIME instant as far from now as the monotonic deadline_us is (now when it has
 * passed): the absolute timeout sem_timedwait and pthread_cond_timedwait want. */
struct timespec fnclock_realtime_deadline(int64_t deadline_us);
/* Sleeps until the monotonic time deadline_us (returns at once when it has passed), through
 * signals. */
void fnclock_sleep_until(int64_t deadline_us);
/* Sleeps for us microseconds (fnclock_sleep_until from now). */
void fnclock_sleep_us(int64_t us);

#endif
