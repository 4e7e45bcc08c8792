/* The report queue of one hidraw reader as fracnav-sim serve emulates it (reportq.h): 64 reports,
 * the new report dropped when full, a waiting read served first, EAGAIN, interrupts, unplug. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <poll.h>
#include <string.h>

#include "reportq.h"

static reportq q; /* 4 KiB: not on the test's stack */

static void push_id(uint8_t id, size_t n)
{
    uint8_t b[DEV_REPORT_MAX] = {id};
    reportq_waiter w;
    reportq_push(&q, b, n, &w);
}

/* Reports come out in order; the 65th is dropped, not the oldest; a read is cut to its size. */
static void test_fifo_and_drop(void **st)
{
    (void)st;
    reportq_init(&q);
    uint8_t b[DEV_REPORT_MAX] = {0};
    reportq_waiter w;
    for (int i = 0; i < REPORTQ_LEN; i++) {
        b[0] = (uint8_t)i;
        assert_int_equal(reportq_push(&q, b, 7, &w), REPORTQ_QUEUED);
    }
    b[0] = 0xee;
    assert_int_equal(reportq_push(&q, b, 7, &w), REPORTQ_DROPPED);
    assert_int_equal(q.dropped, 1);
    uint8_t out[DEV_REPORT_MAX];
    size_t len;
    assert_int_equal(reportq_read(&q, NULL, 64, 0, out, &len), REPORTQ_REPORT);
    assert_int_equal(len, 7);
    assert_int_equal(out[0], 0);
    assert_int_equal(reportq_read(&q, NULL, 3, 0, out, &len), REPORTQ_REPORT);
    assert_int_equal(len, 3);
    assert_int_equal(out[0], 1);
    for (int i = 2; i < REPORTQ_LEN; i++) {
        assert_int_equal(reportq_read(&q, NULL, 64, 0, out, &len), REPORTQ_REPORT);
        assert_int_equal(out[0], i);
    }
    assert_int_equal(reportq_read(&q, NULL, 64, 1, out, &len), REPORTQ_AGAIN);
    push_id(0x42, 13); /* room again after the reads */
    assert_int_equal(reportq_read(&q, NULL, 64, 1, out, &len), REPORTQ_REPORT);
    assert_int_equal(out[0], 0x42);
}

/* An empty queue: a blocking read waits and the next report is handed to it, not queued; at most
 * REPORTQ_WAITERS wait, oldest first; the next gets EAGAIN. */
static void test_waiting_reads(void **st)
{
    (void)st;
    reportq_init(&q);
    int req[REPORTQ_WAITERS + 1];
    uint8_t out[DEV_REPORT_MAX];
    size_t len;
    for (int i = 0; i < REPORTQ_WAITERS; i++)
        assert_int_equal(reportq_read(&q, &req[i], 10 + (size_t)i, 0, out, &len), REPORTQ_WAIT);
    assert_int_equal(reportq_read(&q, &req[REPORTQ_WAITERS], 64, 0, out, &len), REPORTQ_AGAIN);
    assert_int_equal(reportq_poll_events(&q), POLLOUT | POLLWRNORM);
    uint8_t b[DEV_REPORT_MAX] = {1};
    reportq_waiter w;
    assert_int_equal(reportq_push(&q, b, 13, &w), REPORTQ_HANDED);
    assert_ptr_equal(w.req, &req[0]);
    assert_int_equal(reportq_cut(13, w.size), 10);
    assert_int_equal(q.count, 0);
    assert_int_equal(reportq_cancel(&q, &req[2]), 1); /* interrupted */
    assert_int_equal(reportq_cancel(&q, &req[2]), 0);
    assert_int_equal(reportq_push(&q, b, 13, &w), REPORTQ_HANDED);
    assert_ptr_equal(w.req, &req[1]);
    assert_int_equal(reportq_push(&q, b, 13, &w), REPORTQ_HANDED);
    assert_ptr_equal(w.req, &req[3]);
    assert_int_equal(reportq_push(&q, b, 13, &w), REPORTQ_QUEUED);
    assert_int_equal(reportq_poll_events(&q), POLLOUT | POLLWRNORM | POLLIN | POLLRDNORM);
}

/* After an unplug: waiting reads are taken to be failed, reads get EIO, nothing is queued. */
static void test_dead_reader(void **st)
{
    (void)st;
    reportq_init(&q);
    int req[2];
    uint8_t out[DEV_REPORT_MAX];
    size_t len;
    assert_int_equal(reportq_read(&q, &req[0], 64, 0, out, &len), REPORTQ_WAIT);
    assert_int_equal(reportq_read(&q, &req[1], 64, 0, out, &len), REPORTQ_WAIT);
    reportq_kill(&q);
    reportq_waiter w;
    assert_int_equal(reportq_take_waiter(&q, &w), 1);
    assert_ptr_equal(w.req, &req[0]);
    assert_int_equal(reportq_take_waiter(&q, &w), 1);
    assert_ptr_equal(w.req, &req[1]);
    assert_int_equal(reportq_take_waiter(&q, &w), 0);
    uint8_t b[DEV_REPORT_MAX] = {1};
    assert_int_equal(reportq_push(&q, b, 13, &w), REPORTQ_DEAD);
    assert_int_equal(q.count, 0);
    assert_int_equal(reportq_read(&q, &req[0], 64, 0, out, &len), REPORTQ_EIO);
    assert_true(reportq_poll_events(&q) & POLLHUP);
    assert_true(reportq_poll_events(&q) & POLLERR);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_fifo_and_drop),
        cmocka_unit_test(test_waiting_reads),
        cmocka_unit_test(test_dead_reader),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
