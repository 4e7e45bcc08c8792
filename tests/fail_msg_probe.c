/* Fails on purpose with a 3,000-character message that ends in a marker: the ctest
 * fail_msg_shows_the_whole_message passes only when the marker reaches the output, so a
 * fail_msg that cuts the message (cmocka's own, about 1,000 characters) is caught. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "testutil.h"

#include <string.h>

static void test_long_failure(void **st)
{
    (void)st;
    char text[3001];
    memset(text, 'x', sizeof text - 1);
    text[sizeof text - 1] = '\0';
    for (size_t i = 0; i < sizeof text - 1; i += 100)
        text[i] = '\n';
    fail_msg("a long command output:%s\nTHE-END-OF-THE-MESSAGE", text);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(test_long_failure)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
