/* loop_run's timing with an injected clock (loop_set_clock): ticks at the period, no burst to
 * catch up after falling behind, an early wake-up drains events without counting a tick, and the
 * scene is republished while nothing moves. The fake clock's wait moves its time to the deadline
 * (or wherever the test says) and returns: nothing here sleeps. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "loop.h"
#include "ring.h"
#include "testutil.h"

#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#define PERIOD_US 1000
#define WAITS_MAX 256

typedef struct fake_clock {
    int64_t now;
    int waits, stop_after;
    int64_t deadline[WAITS_MAX]; /* what each wait was asked for */
    int jump_at;                 /* this wait oversleeps by jump_us (0: none) */
    int64_t jump_us;
    int push_at;                 /* this wait returns early with an action in the ring (0: none) */
    ring *r;
    atomic_int stop;
} fake_clock;

static int64_t fake_now(void *ctx)
{
    return ((fake_clock *)ctx)->now;
}

static void fake_wait(void *ctx, int64_t deadline_us)
{
    fake_clock *c = ctx;
    int w = ++c->waits;
    if (w <= WAITS_MAX)
        c->deadline[w - 1] = deadline_us;
    if (w == c->push_at) {
        loop_event ev;
        memset(&ev, 0, sizeof ev);
        ev.kind = LOOP_EV_ACTION;
        ev.action = LOOP_ACT_COLLISION;
        assert_true(ring_push(c->r, &ev));
    } else {
        c->now = deadline_us + (w == c->jump_at ? c->jump_us : 0);
    }
    if (w >= c->stop_after)
        atomic_store(&c->stop, 1);
}

typedef struct fixture {
    frag f[2];
    loop_obb *o;
    loop *L;
    ring *r;
    fake_clock clk;
} fixture;

static fixture *setup(int stop_after)
{
    fixture *x = calloc(1, sizeof *x);
    assert_non_null(x);
    int dim[3] = {4, 4, 4};
    double at[2][3] = {{0, 0, 0}, {40, 0, 0}};
    for (int i = 0; i < 2; i++)
        tu_box_frag(&x->f[i], i + 1, dim, at[i]);
    x->o = loop_obb_new(x->f, 2, NULL, NULL);
    assert_non_null(x->o);
    loop_collider col = loop_obb_collider(x->o);
    loop_config c;
    loop_config_default(&c);
    x->L = loop_new(x->f, 2, NULL, &col, &c, NULL);
    assert_non_null(x->L);
    x->r = ring_new(sizeof(loop_event), 16);
    assert_non_null(x->r);
    x->clk.now = 5000000; /* any start: only differences count */
    x->clk.stop_after = stop_after;
    x->clk.r = x->r;
    atomic_init(&x->clk.stop, 0);
    loop_set_clock(x->L, &(loop_clock){fake_now, fake_wait, &x->clk});
    return x;
}

static void teardown(fixture *x)
{
    ring_free(x->r);
    loop_free(x->L);
    loop_obb_free(x->o);
    free(x->f[0].prob);
    free(x->f[1].prob);
    free(x);
}

static int run(fixture *x)
{
    return loop_run(x->L, x->r, PERIOD_US, &x->clk.stop);
}

/* 100 waits of one period each: 100 ticks in 100 periods, each deadline one period after the last. */
static void ticks_at_the_period(void **st)
{
    (void)st;
    fixture *x = setup(100);
    int64_t start = x->clk.now;
    assert_int_equal(run(x), 0);
    assert_int_equal(x->clk.waits, 100);
    for (int i = 0; i < 100; i++)
        assert_int_equal(x->clk.deadline[i], start + (int64_t)(i + 1) * PERIOD_US);
    loop_stats s;
    loop_get_stats(x->L, &s);
    assert_true(fabs(s.tick_hz - 1e6 / PERIOD_US) < 1e-9); /* exact but for rounding */
    assert_true(s.step_hz == 0);
    teardown(x);
}

/* A wait that returns 10.5 periods late counts one tick, and the next deadline is a period after
 * that late tick: no burst of ticks to catch up. */
static void falls_behind_without_a_burst(void **st)
{
    (void)st;
    fixture *x = setup(20);
    x->clk.jump_at = 5;
    x->clk.jump_us = 10 * PERIOD_US + PERIOD_US / 2;
    assert_int_equal(run(x), 0);
    assert_int_equal(x->clk.waits, 20);
    int64_t late = x->clk.deadline[4] + x->clk.jump_us;
    assert_int_equal(x->clk.deadline[5], late + PERIOD_US);
    for (int i = 6; i < 20; i++)
        assert_int_equal(x->clk.deadline[i] - x->clk.deadline[i - 1], PERIOD_US);
    teardown(x);
}

/* An early return with an event in the ring (what loop_notify does) handles the event at once;
 * it is no tick, so the loop waits again for the same deadline. */
static void early_wake_drains_without_a_tick(void **st)
{
    (void)st;
    fixture *x = setup(10);
    x->clk.push_at = 3;
    loop_scene sc = {0};
    loop_scene_read(x->L, &sc);
    assert_int_equal(sc.collision_on, 1);
    assert_int_equal(run(x), 0);
    assert_int_equal(x->clk.deadline[3], x->clk.deadline[2]);
    assert_int_equal(x->clk.deadline[4] - x->clk.deadline[3], PERIOD_US);
    loop_stats s;
    loop_get_stats(x->L, &s);
    assert_int_equal(s.events, 1);
    assert_int_equal(loop_events_done(x->L), 1);
    assert_int_equal(loop_scene_read(x->L, &sc), 1);
    assert_int_equal(sc.collision_on, 0);
    assert_int_equal(sc.actions, 1);
    teardown(x);
}

/* While nothing moves, every 50th tick republishes the scene (fresh rates for the view). */
static void idle_loop_republishes_every_50_ticks(void **st)
{
    (void)st;
    fixture *x = setup(149);
    loop_scene sc = {0};
    loop_scene_read(x->L, &sc);
    uint64_t seq0 = sc.seq;
    assert_int_equal(run(x), 0);
    loop_scene_read(x->L, &sc);
    assert_int_equal(sc.seq - seq0, 2);
    assert_true(sc.stats.tick_hz > 0);
    teardown(x);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(ticks_at_the_period),
        cmocka_unit_test(falls_behind_without_a_burst),
        cmocka_unit_test(early_wake_drains_without_a_tick),
        cmocka_unit_test(idle_loop_republishes_every_50_ticks),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
