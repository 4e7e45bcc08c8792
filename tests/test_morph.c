/* morph and the case edits on it: filling enclosed interiors, separating touching pieces. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "err.h"
#include "morph.h"
#include "seg.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define NX 48
#define NY 38
#define NZ 38

static size_t at(int i, int j, int k)
{
    return ((size_t)k * NY + j) * NX + i;
}

/* Two blocks that touch over part of a face, as pieces of a fracture do: A =
 * [3,23)^3, B = [23,43) x [15,35) x [15,35) (the contact is 8 x 8 of their 20 x
 * 20 faces). truth: 1 in A, 2 in B. */
static void touching_blocks(uint8_t *mask, int *truth)
{
    for (int k = 0; k < NZ; k++)
        for (int j = 0; j < NY; j++)
            for (int i = 0; i < NX; i++) {
                int a = i >= 3 && i < 23 && j >= 3 && j < 23 && k >= 3 && k < 23;
                int b = i >= 23 && i < 43 && j >= 15 && j < 35 && k >= 15 && k < 35;
                mask[at(i, j, k)] = a || b;
                truth[at(i, j, k)] = a ? 1 : b ? 2 : 0;
            }
}

/* The best Dice of each truth piece against the pieces of lab. */
static void check_dice(const int32_t *lab, int pieces, const int *truth, double want)
{
    for (int t = 1; t <= 2; t++) {
        double best = 0;
        for (int p = 1; p <= pieces; p++) {
            size_t both = 0, nt = 0, np = 0;
            for (size_t v = 0; v < (size_t)NX * NY * NZ; v++) {
                nt += truth[v] == t;
                np += lab[v] == p;
                both += truth[v] == t && lab[v] == p;
            }
            best = fmax(best, 2.0 * (double)both / (double)(nt + np));
        }
        if (!(best >= want))
            fail_msg("truth piece %d: best Dice %.3f < %.2f", t, best, want);
    }
}

static void test_separate_by_erosion(void **st)
{
    (void)st;
    static uint8_t mask[NX * NY * NZ];
    static int truth[NX * NY * NZ];
    static int32_t lab[NX * NY * NZ];
    touching_blocks(mask, truth);
    /* one component as the threshold leaves it */
    assert_int_equal(seg_components(mask, (int[3]){NX, NY, NZ}, lab), 1);
    double used = -1;
    int n = morph_separate(mask, (int[3]){NX, NY, NZ}, (double[3]){1, 1, 1}, 0, NULL, 0, 8, lab, &used);
    assert_int_equal(n, 2);
    assert_true(used > 0);
    check_dice(lab, n, truth, 0.85);
    /* every voxel of the mask, and none other, belongs to a piece */
    for (size_t v = 0; v < (size_t)NX * NY * NZ; v++)
        assert_int_equal(lab[v] != 0, mask[v] != 0);
}

static void test_separate_by_seeds(void **st)
{
    (void)st;
    static uint8_t mask[NX * NY * NZ];
    static int truth[NX * NY * NZ];
    static int32_t lab[NX * NY * NZ];
    touching_blocks(mask, truth);
    const int seeds[2][3] = {{12, 12, 12}, {34, 26, 26}};
    int n = morph_separate(mask, (int[3]){NX, NY, NZ}, (double[3]){1, 1, 1}, 0, seeds, 2, 8, lab, NULL);
    assert_int_equal(n, 2);
    check_dice(lab, n, truth, 0.85);
    /* a seed outside the mask is named */
    const int bad[2][3] = {{12, 12, 12}, {1, 1, 1}};
    assert_int_equal(morph_separate(mask, (int[3]){NX, NY, NZ}, (double[3]){1, 1, 1}, 0, bad, 2, 8, lab, NULL),
                     FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "seed 2"));
}

/* A single block does not split. */
static void test_separate_one_block(void **st)
{
    (void)st;
    static uint8_t mask[NX * NY * NZ];
    static int32_t lab[NX * NY * NZ];
    memset(mask, 0, sizeof mask);
    for (int k = 4; k < 20; k++)
        for (int j = 4; j < 20; j++)
            for (int i = 4; i < 30; i++)
                mask[at(i, j, k)] = 1;
    assert_int_equal(morph_separate(mask, (int[3]){NX, NY, NZ}, (double[3]){1, 1, 1}, 0, NULL, 0, 8, lab, NULL), 1);
}

/* A closed shell fills in 3D; a tube open at both ends only slice-wise. */
static void test_fill(void **st)
{
    (void)st;
    static uint8_t mask[NX * NY * NZ];
    memset(mask, 0, sizeof mask);
    long inside = 0;
    for (int k = 4; k < 24; k++)
        for (int j = 4; j < 24; j++)
            for (int i = 4; i < 24; i++) {
                int shell = i < 6 || i >= 22 || j < 6 || j >= 22 || k < 6 || k >= 22;
                mask[at(i, j, k)] = (uint8_t)shell;
                inside += !shell;
            }
    assert_int_equal(morph_fill(mask, (int[3]){NX, NY, NZ}, MORPH_FILL_3D), inside);
    for (int k = 4; k < 24; k++)
        for (int j = 4; j < 24; j++)
            for (int i = 4; i < 24; i++)
                assert_int_equal(mask[at(i, j, k)], 1);
    /* the tube: along i, open at both ends */
    memset(mask, 0, sizeof mask);
    long lumen = 0;
    for (int k = 4; k < 24; k++)
        for (int j = 4; j < 24; j++)
            for (int i = 2; i < 44; i++) {
                int wall = j < 6 || j >= 22 || k < 6 || k >= 22;
                mask[at(i, j, k)] = (uint8_t)wall;
                lumen += !wall;
            }
    assert_int_equal(morph_fill(mask, (int[3]){NX, NY, NZ}, MORPH_FILL_3D), 0);
    assert_int_equal(morph_fill(mask, (int[3]){NX, NY, NZ}, MORPH_FILL_SLICES), lumen);
}

/* The distance map: a slab 9 voxels thick has its deepest voxel 5 voxels from
 * the outside. */
static void test_distance(void **st)
{
    (void)st;
    static uint8_t mask[NX * NY * NZ];
    static float d[NX * NY * NZ];
    memset(mask, 0, sizeof mask);
    for (int k = 0; k < NZ; k++)
        for (int j = 0; j < NY; j++)
            for (int i = 10; i < 19; i++)
                mask[at(i, j, k)] = 1;
    morph_distance(mask, (int[3]){NX, NY, NZ}, (double[3]){0.5, 1, 1}, d);
    assert_true(fabs(d[at(14, 14, 14)] - 2.5) < 1e-5);
    assert_true(fabs(d[at(10, 14, 14)] - 0.5) < 1e-5);
    assert_true(d[at(9, 14, 14)] == 0);
}

/* The exact distance to a mask: against brute force over a scatter of inside voxels on an
 * anisotropic grid, and INFINITY everywhere for an empty mask. */
static void test_distance_to(void **st)
{
    (void)st;
    enum { X = 13, Y = 9, Z = 7 };
    const double sp[3] = {0.5, 1.0, 1.5};
    static uint8_t mask[X * Y * Z];
    static float d[X * Y * Z];
    memset(mask, 0, sizeof mask);
    assert_int_equal(morph_distance_to(mask, (int[3]){X, Y, Z}, sp, d), 0);
    assert_true(isinf(d[0]) && isinf(d[X * Y * Z - 1]));
    unsigned seed = 7;
    for (int n = 0; n < 6; n++) {
        seed = seed * 1103515245u + 12345u;
        mask[(seed >> 8) % (X * Y * Z)] = 1;
    }
    assert_int_equal(morph_distance_to(mask, (int[3]){X, Y, Z}, sp, d), 0);
    for (int v = 0; v < X * Y * Z; v++) {
        double best = INFINITY;
        for (int u = 0; u < X * Y * Z; u++)
            if (mask[u]) {
                double dx = (v % X - u % X) * sp[0], dy = (v / X % Y - u / X % Y) * sp[1],
                       dz = (v / (X * Y) - u / (X * Y)) * sp[2];
                best = fmin(best, sqrt(dx * dx + dy * dy + dz * dz));
            }
        if (fabs(d[v] - best) > 1e-4)
            fail_msg("voxel %d: distance %g, brute force %g", v, d[v], best);
    }
}

/* Through the case: the two blocks segmented as one fragment separate into two;
 * a hollow one fills. */
static void test_case_separate_and_fill(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("morph"), src[4200];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    vol *ct = vol_new(NX, NY, NZ), *labels = vol_new(NX, NY, NZ);
    static uint8_t mask[NX * NY * NZ];
    static int truth[NX * NY * NZ];
    touching_blocks(mask, truth);
    for (size_t v = 0; v < vol_count(ct); v++) {
        ct->data[v] = mask[v] ? 1000 : -1000;
        labels->data[v] = mask[v] ? 1 : 0;
    }
    seg_params sp;
    seg_defaults(&sp);
    assert_int_equal(volio_write(ct, src, VOL_I16), 0);
    planning_case *c = case_create(dir, src, ct, labels, &sp);
    if (!c)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(c->nfrag, 1);
    int news[4];
    assert_int_equal(case_separate(c, 1, 0, news, NULL), 1);
    assert_int_equal(c->nfrag, 2);
    assert_int_equal(news[0], 2);
    static int32_t lab[NX * NY * NZ];
    for (size_t v = 0; v < vol_count(c->labels); v++)
        lab[v] = (int32_t)c->labels->data[v];
    check_dice(lab, 2, truth, 0.85);
    /* separate again: a single block does not split, and says so */
    assert_int_equal(case_separate(c, 2, 0, news, NULL), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "does not split"));
    /* hollow out block A's core (label 0), then fill it back */
    long hole = 0;
    for (int k = 7; k < 19; k++)
        for (int j = 7; j < 19; j++)
            for (int i = 7; i < 19; i++)
                if (c->labels->data[at(i, j, k)] != 0) {
                    c->labels->data[at(i, j, k)] = 0;
                    hole++;
                }
    int keep = (int)c->labels->data[at(4, 4, 4)];
    assert_int_equal(case_rebuild(c, 0, 0), 0);
    size_t before = c->frag[case_find(c, keep)].voxels;
    assert_int_equal(case_fill(c, keep, MORPH_FILL_3D), hole);
    assert_int_equal(c->frag[case_find(c, keep)].voxels, before + (size_t)hole);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* The touching blocks as one fragment of a full CT (1000 HU, air -1000), with a loose bone voxel
 * run (x 44..46 at y = z = 20, joined to no fragment) and its case in dir. */
static planning_case *blocks_case(const char *dir, int *truth)
{
    char src[4200];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    vol *ct = vol_new(NX, NY, NZ), *labels = vol_new(NX, NY, NZ);
    static uint8_t mask[NX * NY * NZ];
    touching_blocks(mask, truth);
    for (size_t v = 0; v < vol_count(ct); v++) {
        ct->data[v] = mask[v] ? 1000 : -1000;
        labels->data[v] = mask[v] ? 1 : 0;
    }
    for (int i = 43; i < 47; i++)
        ct->data[at(i, 20, 20)] = 1000;
    seg_params sp;
    seg_defaults(&sp);
    assert_int_equal(volio_write(ct, src, VOL_I16), 0);
    planning_case *c = case_create(dir, src, ct, labels, &sp);
    if (!c)
        fail_msg("%s", fn_err_msg());
    return c;
}

/* Seeded separation: one seed per block splits them; a seed on bone the fragment missed grows it
 * there; bad seeds are refused naming the point in world mm (the grid is world = index here). */
static void test_case_separate_seeds(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("morph-seeds");
    static int truth[NX * NY * NZ];
    planning_case *c = blocks_case(dir, truth);
    int news[4];
    /* the same point twice, as two pieces: refused, not "2 pieces" of which one is empty */
    case_seed twice[2] = {{{10, 10, 10}, 1}, {{10, 10, 10}, 2}};
    assert_int_equal(case_separate_seeds(c, 1, twice, 2, news), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "(10.0, 10.0, 10.0) and (10.0, 10.0, 10.0) mm fall in one voxel"));
    case_seed outside[2] = {{{10, 10, 10}, 1}, {{10, 10, -7}, 2}};
    assert_int_equal(case_separate_seeds(c, 1, outside, 2, news), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "the seed (10.0, 10.0, -7.0) mm is outside the CT (its voxel centres span "
                                         "(0.0, 0.0, 0.0) to (47.0, 37.0, 37.0) mm"));
    case_seed air[2] = {{{10, 10, 10}, 1}, {{1, 1, 1}, 2}};
    assert_int_equal(case_separate_seeds(c, 1, air, 2, news), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "the seed (1.0, 1.0, 1.0) mm is outside fragment 1, and the CT there "
                                         "(-1000) is under the case's bone threshold 300"));
    assert_int_equal(c->nfrag, 1);
    /* one seed per block, and one on the loose bone run: the run joins the piece that reaches it */
    case_seed good[3] = {{{10, 10, 10}, 1}, {{33, 25, 25}, 2}, {{45, 20, 20}, 2}};
    assert_int_equal(case_separate_seeds(c, 1, good, 3, news), 1);
    assert_int_equal(c->nfrag, 2);
    assert_int_equal(news[0], 2);
    static int32_t lab[NX * NY * NZ];
    for (size_t v = 0; v < vol_count(c->labels); v++)
        lab[v] = (int32_t)c->labels->data[v];
    check_dice(lab, 2, truth, 0.95);
    assert_int_equal(lab[at(45, 20, 20)], lab[at(33, 25, 25)]);
    /* B and the run are the larger piece: B keeps id 1, A is fragment 2 */
    assert_int_equal(lab[at(33, 25, 25)], 1);
    /* a seed in another fragment is refused by name */
    case_seed other[2] = {{{33, 25, 25}, 1}, {{10, 10, 10}, 2}};
    assert_int_equal(case_separate_seeds(c, 1, other, 2, news), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "the seed (10.0, 10.0, 10.0) mm lies in fragment 2, not in fragment 1"));
    /* a not-bone seed takes its part away; one piece left: no new fragment */
    size_t before = c->frag[case_find(c, 2)].voxels;
    case_seed trim[2] = {{{10, 10, 10}, 1}, {{4, 4, 4}, 0}};
    assert_int_equal(case_separate_seeds(c, 2, trim, 2, news), 0);
    assert_true(c->frag[case_find(c, 2)].voxels < before);
    assert_true(c->labels->data[at(4, 4, 4)] == 0);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

static void test_seed_file(void **st)
{
    (void)st;
    case_seed *s;
    assert_int_equal(case_seeds_parse("# pieces\n1 10 20 30\n\n1 -1.5 2 3e1 # again\nnone 0 0 0\n2 5 5 5\n",
                                      "seeds.txt", &s), 4);
    assert_int_equal(s[0].piece, 1);
    assert_true(s[1].at[0] == -1.5 && s[1].at[2] == 30);
    assert_int_equal(s[2].piece, 0);
    assert_int_equal(s[3].piece, 2);
    free(s);
    static const struct {
        const char *text, *want;
    } bad[] = {
        {"1 2 3\n", "seeds.txt: line 1: expected PIECE X Y Z"},
        {"1 2 3 4\n0 1 2 3\n", "seeds.txt: line 2: expected PIECE X Y Z"},
        {"\n\n1.5 1 2 3\n", "seeds.txt: line 3:"},
        {"1 2 3 4 5\n", "seeds.txt: line 1:"},
        {"255 2 3 4\n", "seeds.txt: line 1:"},
        {"1 nan 3 4\n", "seeds.txt: line 1:"},
        {"# nothing\n", "seeds.txt: no seed in the file"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        if (case_seeds_parse(bad[i].text, "seeds.txt", &s) != FN_EFORMAT || !strstr(fn_err_msg(), bad[i].want))
            fail_msg("case %zu: %s", i, fn_err_msg());
        assert_null(s);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_separate_by_erosion),
        cmocka_unit_test(test_separate_by_seeds),
        cmocka_unit_test(test_separate_one_block),
        cmocka_unit_test(test_fill),
        cmocka_unit_test(test_distance),
        cmocka_unit_test(test_distance_to),
        cmocka_unit_test(test_case_separate_and_fill),
        cmocka_unit_test(test_case_separate_seeds),
        cmocka_unit_test(test_seed_file),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
