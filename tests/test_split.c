/* split and sheet: the automatic split of a bone where it is truly broken, and the fracture-line
 * measure it follows. Bone-only CTs made here (0 outside the bone, 1 mm voxels). */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "sheet.h"
#include "split.h"

#include <stdlib.h>

#define NX 72
#define NY 26
#define NZ 26

static const int dim[3] = {NX, NY, NZ};
static const double sp[3] = {1, 1, 1};

static size_t at(int i, int j, int k)
{
    return ((size_t)k * NY + j) * NX + i;
}

/* A bar x in [3, 69), y and z in [3, 23): a 2 mm cortex of 900 HU around a 60-70 HU interior.
 * kind 0: intact; 1: broken at x = 36, the two pieces pressed together over their whole
 * cross-section (no gap, no neck), each closed by its cortex, a 1 mm band of 20 HU between them;
 * 2: intact with a 1 mm plate of 900 HU across it at x = 36 (dense bone inside, not a break). */
static void bar(int kind, float *hu, uint8_t *mask)
{
    for (int k = 0; k < NZ; k++)
        for (int j = 0; j < NY; j++)
            for (int i = 0; i < NX; i++) {
                int in = i >= 3 && i < 69 && j >= 3 && j < 23 && k >= 3 && k < 23;
                int rim = i < 5 || i >= 67 || j < 5 || j >= 21 || k < 5 || k >= 21;
                int near = i >= 34 && i <= 38, line = i == 36;
                float v = rim ? 900 : 60 + (float)((i + 2 * j + 3 * k) % 11);
                if (kind == 1 && near)
                    v = line ? 20 : 900;
                if (kind == 2 && line)
                    v = 900;
                hu[at(i, j, k)] = in ? v : 0;
                mask[at(i, j, k)] = (uint8_t)in;
            }
}

/* The fracture line is a sheet; the flank of a dense plate, which curves the same way, is not. */
static void test_sheet_valley_not_flank(void **st)
{
    (void)st;
    float *hu = malloc(NX * NY * NZ * sizeof *hu), *sheet = malloc(NX * NY * NZ * sizeof *sheet);
    uint8_t *mask = malloc(NX * NY * NZ);
    bar(1, hu, mask);
    assert_int_equal(sheet_map(hu, mask, dim, sp, sheet), 0);
    assert_true(sheet[at(36, 13, 13)] >= SPLIT_SHEET_HU);
    assert_true(sheet[at(20, 13, 13)] < SPLIT_SHEET_HU); /* the interior */
    bar(2, hu, mask);
    assert_int_equal(sheet_map(hu, mask, dim, sp, sheet), 0);
    for (int i = 30; i <= 42; i++)
        assert_true(sheet[at(i, 13, 13)] < SPLIT_SHEET_HU);
    free(hu);
    free(sheet);
    free(mask);
}

/* Pieces pressed together with no neck split at the line; the intact bar, and the bar with a
 * dense plate, stay whole. */
static void test_split_pressed_pieces(void **st)
{
    (void)st;
    float *hu = malloc(NX * NY * NZ * sizeof *hu);
    uint8_t *mask = malloc(NX * NY * NZ);
    int32_t *lab = malloc(NX * NY * NZ * sizeof *lab);
    bar(1, hu, mask);
    assert_int_equal(split_auto(hu, mask, dim, sp, lab), 2);
    for (int k = 3; k < 23; k++)
        for (int j = 3; j < 23; j++)
            for (int i = 3; i < 69; i++)
                if (i != 36) /* the line goes to either piece */
                    assert_int_equal(lab[at(i, j, k)], lab[at(i < 36 ? 3 : 68, 3, 3)]);
    assert_int_not_equal(lab[at(3, 3, 3)], lab[at(68, 3, 3)]);
    for (int kind = 0; kind <= 2; kind += 2) {
        bar(kind, hu, mask);
        assert_int_equal(split_auto(hu, mask, dim, sp, lab), 1);
        assert_int_equal(lab[at(3, 3, 3)], 1);
        assert_int_equal(lab[at(68, 22, 22)], 1);
    }
    free(hu);
    free(mask);
    free(lab);
}

/* Pieces made by splits in turn: A and B, halves of one intact bar (a wide cut through sound
 * bone), and C, a bone across a 2 mm joint from B. A cut kept for the joint's gap (B with C faced
 * A across it) is undone: A and B join; C stays apart. Halves of the broken bar stay apart. */
static void test_rejoin_cut_beside_joint(void **st)
{
    (void)st;
    float *hu = malloc(NX * NY * NZ * sizeof *hu);
    uint8_t *mask = malloc(NX * NY * NZ);
    int32_t *lab = malloc(NX * NY * NZ * sizeof *lab);
    int join[4];
    bar(0, hu, mask);
    for (size_t v = 0; v < NX * NY * NZ; v++) {
        int i = (int)(v % NX);
        if (i == 52 || i == 53) /* the joint */
            hu[v] = 0, mask[v] = 0;
        else if (mask[v] && (i == 50 || i == 51 || i == 54 || i == 55)) /* the cortices facing across it */
            hu[v] = 900;
        lab[v] = !mask[v] ? 0 : i < 40 ? 1 : i < 52 ? 2 : 3;
    }
    assert_int_equal(split_rejoin(hu, mask, dim, sp, lab, 3, join), 0);
    assert_int_equal(join[1], 1);
    assert_int_equal(join[2], 1);
    assert_int_equal(join[3], 3);
    bar(1, hu, mask);
    for (size_t v = 0; v < NX * NY * NZ; v++)
        lab[v] = !mask[v] ? 0 : (int)(v % NX) < 36 ? 1 : 2;
    assert_int_equal(split_rejoin(hu, mask, dim, sp, lab, 2, join), 0);
    assert_int_equal(join[2], 2);
    free(hu);
    free(mask);
    free(lab);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sheet_valley_not_flank),
        cmocka_unit_test(test_split_pressed_pieces),
        cmocka_unit_test(test_rejoin_cut_beside_joint),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
