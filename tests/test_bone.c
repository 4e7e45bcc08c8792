/* The whole bone (bone_find) and the seeded growth of fragments (grow). */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "bone.h"
#include "err.h"
#include "testutil.h"
#include "vol.h"

#include <stdlib.h>
#include <string.h>

/* A bone cut out of its CT (0 outside) when background is 0, else inside a full CT: a box shell
 * of cortex (700 HU, 2 voxels thick, x/y/z 5..24) around a cancellous interior of 50 HU with a
 * fatty -40 HU core and one voxel of exactly 0; apart from it, a loose 50 HU blob (no cortex). */
static vol *shell_ct(float background)
{
    vol *v = vol_new(34, 30, 30);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = background;
    for (int k = 5; k < 25; k++)
        for (int j = 5; j < 25; j++)
            for (int i = 5; i < 25; i++) {
                int shell = i < 7 || j < 7 || k < 7 || i > 22 || j > 22 || k > 22;
                v->data[vol_idx(v, i, j, k)] = shell ? 700 : (i > 12 && i < 17 && j > 12 && j < 17) ? -40 : 50;
            }
    v->data[vol_idx(v, 10, 10, 10)] = 0;
    for (int k = 10; k < 14; k++)
        for (int j = 10; j < 14; j++)
            for (int i = 28; i < 32; i++)
                v->data[vol_idx(v, i, j, k)] = 50;
    return v;
}

static size_t count(const uint8_t *m, size_t n)
{
    size_t c = 0;
    for (size_t i = 0; i < n; i++)
        c += m[i] != 0;
    return c;
}

static void test_bone_only_ct_keeps_the_cancellous_interior(void **st)
{
    (void)st;
    vol *v = shell_ct(0);
    uint8_t *m = malloc(vol_count(v));
    assert_int_equal(bone_kind_of(v), BONE_ONLY_CT);
    assert_int_equal(bone_find(v, 300, m), BONE_ONLY_CT);
    /* The whole box but its one 0 voxel (the fill takes that); not the loose blob. */
    assert_int_equal(count(m, vol_count(v)), 20 * 20 * 20 - 1);
    assert_int_equal(m[vol_idx(v, 14, 14, 14)], 1);
    assert_int_equal(m[vol_idx(v, 10, 10, 10)], 0);
    assert_int_equal(m[vol_idx(v, 30, 12, 12)], 0);
    free(m);
    vol_free(v);
}

static void test_full_ct_keeps_the_threshold(void **st)
{
    (void)st;
    vol *v = shell_ct(-1000);
    uint8_t *m = malloc(vol_count(v));
    assert_int_equal(bone_kind_of(v), BONE_FULL_CT);
    assert_int_equal(bone_find(v, 300, m), BONE_FULL_CT);
    /* Soft tissue shares the interior's HU in a full CT: only the cortex is bone by intensity. */
    assert_int_equal(count(m, vol_count(v)), 20 * 20 * 20 - 16 * 16 * 16);
    free(m);
    vol_free(v);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bone_only_ct_keeps_the_cancellous_interior),
        cmocka_unit_test(test_full_ct_keeps_the_threshold),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
