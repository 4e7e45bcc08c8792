/* ring: the single-producer / single-consumer queue between the input thread and the loop: order,
 * capacity, drops when full, and two threads at once. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "ring.h"

#include <pthread.h>

static void test_ring_spsc_order_and_full(void **st)
{
    (void)st;
    ring *r = ring_new(sizeof(uint64_t), 5);
    assert_non_null(r);
    assert_int_equal(ring_capacity(r), 8);
    uint64_t v = 0, out;
    for (v = 0; v < 8; v++)
        assert_int_equal(ring_push(r, &v), 1);
    assert_int_equal(ring_push(r, &v), 0);
    assert_int_equal(ring_dropped(r), 1);
    for (uint64_t k = 0; k < 8; k++) {
        assert_int_equal(ring_pop(r, &out), 1);
        assert_true(out == k);
    }
    assert_int_equal(ring_pop(r, &out), 0);
    ring_free(r);
    assert_null(ring_new(0, 4));
}

static void *producer(void *arg)
{
    ring *r = arg;
    for (uint64_t v = 0; v < 200000;)
        if (ring_push(r, &v))
            v++;
    return NULL;
}

static void test_ring_two_threads(void **st)
{
    (void)st;
    ring *r = ring_new(sizeof(uint64_t), 64);
    pthread_t th;
    pthread_create(&th, NULL, producer, r);
    uint64_t want = 0, got;
    while (want < 200000)
        if (ring_pop(r, &got)) {
            assert_true(got == want);
            want++;
        }
    pthread_join(th, NULL);
    assert_int_equal(ring_count(r), 0);
    ring_free(r);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_ring_spsc_order_and_full),
        cmocka_unit_test(test_ring_two_threads),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
