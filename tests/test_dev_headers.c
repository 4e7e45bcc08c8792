/* The event has its own header: calibration and the parser need dev_event, not the transport
 * seam, so including them does not pull in dev.h (checked at compile time below). */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <string.h>

#include "calib.h"
#include "devparse.h"

#ifdef FN_DEV_H
#error "calib.h or devparse.h includes the transport header dev.h: dev_event.h is all they need"
#endif

/* An event folded from two keeps the newest axes and both edges: usable with these headers alone. */
static void test_event_alone(void **st)
{
    (void)st;
    dev_event a, b;
    memset(&a, 0, sizeof a);
    memset(&b, 0, sizeof b);
    a.flags = DEV_EV_BUTTON;
    a.pressed = a.buttons = 1;
    b.flags = DEV_EV_MOTION;
    b.buttons = 1;
    b.axis[0] = 0.5f;
    b.t_us = 10;
    devparse_merge(&a, &b);
    assert_true(a.flags & DEV_EV_MOTION);
    assert_true(a.flags & DEV_EV_BUTTON);
    assert_int_equal(a.pressed, 1);
    assert_true(a.axis[0] == 0.5f);
    assert_true(DEV_DT_MAX_US > 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(test_event_alone)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
