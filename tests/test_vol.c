/* vol: the memory budget and dimension checks every reader goes through, and the index/world
 * mapping of a volume. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "vol.h"

#include <math.h>

static void test_vol_budget_refuses_huge(void **st)
{
    (void)st;
    int64_t d[3] = {100000, 100000, 100000};
    assert_int_equal(vol_check_dims(d, 4, "huge.nii"), FN_ENOMEM);
    int64_t neg[3] = {10, -1, 10};
    assert_int_equal(vol_check_dims(neg, 4, "neg.nii"), FN_EFORMAT);
}

static void test_index_world_round_trip(void **st)
{
    (void)st;
    vol *v = vol_new(4, 5, 6);
    assert_non_null(v);
    double ijk[3] = {1, 2, 3}, w[3], back[3];
    vol_index_to_world(v, ijk, w);
    vol_world_to_index(v, w, back);
    for (int a = 0; a < 3; a++)
        assert_true(fabs(back[a] - ijk[a]) < 1e-12);
    vol_free(v);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_vol_budget_refuses_huge),
        cmocka_unit_test(test_index_world_round_trip),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
