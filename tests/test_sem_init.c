/* A wake-up semaphore that cannot be made: loop_new and session_open_fragments return NULL with a
 * message that names it, rather than run with a semaphore that was never set up. sem_init is
 * wrapped (-Wl,--wrap=sem_init, tests/CMakeLists.txt) so that it can be made to fail. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "frag.h"
#include "loop.h"
#include "session.h"
#include "testutil.h"

#include <errno.h>
#include <semaphore.h>
#include <stdlib.h>
#include <string.h>

int __real_sem_init(sem_t *sem, int pshared, unsigned value);
int __wrap_sem_init(sem_t *sem, int pshared, unsigned value);

static int refuse; /* sem_init fails while set */

int __wrap_sem_init(sem_t *sem, int pshared, unsigned value)
{
    if (refuse) {
        errno = ENOSYS;
        return -1;
    }
    return __real_sem_init(sem, pshared, value);
}

static int apart(void *ctx, int a, const pose *pa, int b, const pose *pb, double tol_mm, void *cache, loop_contact *out)
{
    out->collides = 0;
    out->separation_mm = 100;
    return 0;
}

static void two_boxes(frag f[2])
{
    tu_box_frag(&f[0], 1, (const int[3]){4, 4, 4}, (const double[3]){0, 0, 0});
    tu_box_frag(&f[1], 2, (const int[3]){4, 4, 4}, (const double[3]){20, 0, 0});
}

static void test_loop_without_semaphore(void **st)
{
    frag f[2];
    two_boxes(f);
    loop_collider col = {.query = apart};
    refuse = 1;
    loop *L = loop_new(f, 2, NULL, &col, NULL, NULL);
    refuse = 0;
    assert_null(L);
    if (!strstr(fn_err_msg(), "semaphore"))
        fail_msg("loop_new said: %s", fn_err_msg());
    L = loop_new(f, 2, NULL, &col, NULL, NULL); /* and with one, as ever */
    assert_non_null(L);
    loop_free(L);
    free(f[0].prob);
    free(f[1].prob);
}

static void test_session_without_semaphore(void **st)
{
    frag f[2];
    two_boxes(f);
    loop_config cfg;
    loop_config_default(&cfg);
    refuse = 1;
    session *s = session_open_fragments(f, 2, NULL, (const double[2]){0.5, 0.95}, &cfg);
    refuse = 0;
    assert_null(s);
    if (!strstr(fn_err_msg(), "semaphore"))
        fail_msg("session_open_fragments said: %s", fn_err_msg());
    s = session_open_fragments(f, 2, NULL, (const double[2]){0.5, 0.95}, &cfg);
    assert_non_null(s);
    session_close(s);
    free(f[0].prob);
    free(f[1].prob);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_loop_without_semaphore),
        cmocka_unit_test(test_session_without_semaphore),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
