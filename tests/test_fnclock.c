/* The clock helper: microsecond arithmetic on timespecs (the carry spacenavd once got wrong),
 * absolute deadlines for POSIX waits, and sleeping until a monotonic time. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "fnclock.h"

#include <errno.h>
#include <semaphore.h>

static void expect_ts(struct timespec t, long long sec, long nsec)
{
    assert_int_equal((long long)t.tv_sec, sec);
    assert_int_equal(t.tv_nsec, nsec);
}

static void add_carries_into_seconds(void **state)
{
    (void)state;
    expect_ts(fnclock_add_us((struct timespec){5, 999999000}, 1), 6, 0);
    expect_ts(fnclock_add_us((struct timespec){5, 999999999}, 1), 6, 999);
    expect_ts(fnclock_add_us((struct timespec){5, 500000000}, 2500000), 8, 0);
    expect_ts(fnclock_add_us((struct timespec){5, 0}, 999999), 5, 999999000);
    expect_ts(fnclock_add_us((struct timespec){5, 0}, 0), 5, 0);
}

static void add_borrows_for_negative_amounts(void **state)
{
    (void)state;
    expect_ts(fnclock_add_us((struct timespec){5, 0}, -1), 4, 999999000);
    expect_ts(fnclock_add_us((struct timespec){5, 250000000}, -1250000), 4, 0);
    expect_ts(fnclock_add_us((struct timespec){5, 0}, -2000001), 2, 999999000);
}

static void timespec_from_microseconds(void **state)
{
    (void)state;
    expect_ts(fnclock_timespec(0), 0, 0);
    expect_ts(fnclock_timespec(1), 0, 1000);
    expect_ts(fnclock_timespec(1000000), 1, 0);
    expect_ts(fnclock_timespec(1234567890123), 1234567, 890123000);
}

static void clocks_agree_and_never_go_back(void **state)
{
    (void)state;
    int64_t a = fnclock_now_us(), ns = fnclock_now_ns(), b = fnclock_now_us();
    assert_true(a <= ns / 1000 && ns / 1000 <= b);
    int64_t t = fnclock_thread_cpu_ns(), p = fnclock_process_cpu_ns();
    assert_true(t >= 0);
    assert_true(p >= t); /* the process's CPU time holds this thread's */
}

/* A deadline already passed times out at once; the waiter is not left hanging. */
static void passed_deadline_times_out_at_once(void **state)
{
    (void)state;
    sem_t s;
    sem_init(&s, 0, 0);
    struct timespec until = fnclock_realtime_deadline(fnclock_now_us() - 5000000);
    assert_int_equal(sem_timedwait(&s, &until), -1);
    assert_int_equal(errno, ETIMEDOUT);
    sem_post(&s);
    until = fnclock_realtime_deadline(fnclock_now_us() + 1000);
    assert_int_equal(sem_timedwait(&s, &until), 0); /* a post still wakes it */
    sem_destroy(&s);
}

/* A future deadline lies ahead of the realtime clock by the time left, give or take what passed
 * between the readings. */
static void future_deadline_is_ahead_by_the_time_left(void **state)
{
    (void)state;
    struct timespec before;
    clock_gettime(CLOCK_REALTIME, &before);
    struct timespec until = fnclock_realtime_deadline(fnclock_now_us() + 3000000), after;
    clock_gettime(CLOCK_REALTIME, &after);
    int64_t ahead_us = ((int64_t)until.tv_sec - before.tv_sec) * 1000000 +
                       (until.tv_nsec - before.tv_nsec) / 1000;
    int64_t between_us = ((int64_t)after.tv_sec - before.tv_sec) * 1000000 +
                         (after.tv_nsec - before.tv_nsec) / 1000;
    assert_true(ahead_us >= 3000000 - between_us - 1 && ahead_us <= 3000000 + between_us + 1);
    assert_true(until.tv_nsec >= 0 && until.tv_nsec < 1000000000);
}

static void sleep_until_does_not_return_early(void **state)
{
    (void)state;
    int64_t deadline = fnclock_now_us() + 2000;
    fnclock_sleep_until(deadline);
    assert_true(fnclock_now_us() >= deadline);
    fnclock_sleep_until(0); /* long passed: returns at once */
    int64_t before = fnclock_now_us();
    fnclock_sleep_us(1000);
    assert_true(fnclock_now_us() - before >= 1000);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(add_carries_into_seconds),
        cmocka_unit_test(add_borrows_for_negative_amounts),
        cmocka_unit_test(timespec_from_microseconds),
        cmocka_unit_test(clocks_agree_and_never_go_back),
        cmocka_unit_test(passed_deadline_times_out_at_once),
        cmocka_unit_test(future_deadline_is_ahead_by_the_time_left),
        cmocka_unit_test(sleep_until_does_not_return_early),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
