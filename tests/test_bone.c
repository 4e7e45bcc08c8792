/* The whole bone (bone_find) and the seeded growth of fragments (grow). */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "bone.h"
#include "err.h"
#include "grow.h"
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

/* A growth updated after one more seed gives the forest that growing all the seeds anew gives, and
 * a seed outside the domain or on another's voxel is refused. */
static void test_grow_incremental_matches_fresh(void **st)
{
    (void)st;
    enum { X = 40, Y = 24, Z = 20, N = X * Y * Z };
    static float hu[N];
    static uint8_t dom[N], first[N];
    unsigned r = 12345;
    for (int k = 0; k < Z; k++)
        for (int j = 0; j < Y; j++)
            for (int i = 0; i < X; i++) {
                size_t v = ((size_t)k * Y + j) * X + i;
                r = r * 1103515245u + 12345u;
                hu[v] = (float)(100 + (r >> 16) % 700);
                dom[v] = !(i == 20 && (j < 8 || k < 6)); /* a wall with a gap */
            }
    const int dim[3] = {X, Y, Z};
    const double sp[3] = {0.8, 0.8, 1.0};
    const size_t a = (10 * Y + 12) * X + 5, b = (10 * Y + 12) * X + 35, c = (3 * Y + 3) * X + 30;
    grow *g = grow_new(hu, dom, dim, sp);
    assert_non_null(g);
    assert_int_equal(grow_add_seed(g, a, 1), 0);
    assert_int_equal(grow_add_seed(g, b, 2), 0);
    assert_int_equal(grow_run(g), 0);
    memcpy(first, grow_labels(g), N);
    assert_int_equal(first[a], 1);
    assert_int_equal(first[b], 2);
    assert_int_equal(grow_add_seed(g, c, 3), 0);
    assert_int_equal(grow_run(g), 0);
    grow *fresh = grow_new(hu, dom, dim, sp);
    assert_int_equal(grow_add_seed(fresh, a, 1), 0);
    assert_int_equal(grow_add_seed(fresh, b, 2), 0);
    assert_int_equal(grow_add_seed(fresh, c, 3), 0);
    assert_int_equal(grow_run(fresh), 0);
    assert_memory_equal(grow_labels(g), grow_labels(fresh), N);
    size_t moved = 0;
    for (size_t v = 0; v < N; v++)
        moved += grow_labels(g)[v] != first[v];
    assert_true(moved > 0);
    assert_int_equal(grow_labels(g)[(10 * Y + 3) * X + 20], 0); /* the wall is outside the domain */
    assert_int_equal(grow_add_seed(g, (10 * Y + 3) * X + 20, 1), FN_EINVAL);
    assert_int_equal(grow_add_seed(g, a, 2), FN_EINVAL);
    assert_int_equal(grow_add_seed(g, N, 1), FN_EINVAL);
    assert_int_equal(grow_add_seed(g, b, 0), FN_EINVAL);
    grow_free(g);
    grow_free(fresh);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bone_only_ct_keeps_the_cancellous_interior),
        cmocka_unit_test(test_full_ct_keeps_the_threshold),
        cmocka_unit_test(test_grow_incremental_matches_fresh),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
