#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "snap.h"
#include "testutil.h"

#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Reads back a PNG written by snap and returns the pixel at (x, y). */
static void read_pixel(const char *path, int x, int y, int *w, int *h, uint8_t out[3])
{
    png_image im = {.version = PNG_IMAGE_VERSION};
    assert_true(png_image_begin_read_from_file(&im, path));
    im.format = PNG_FORMAT_RGB;
    uint8_t *buf = malloc(PNG_IMAGE_SIZE(im));
    assert_true(png_image_finish_read(&im, NULL, buf, 0, NULL));
    *w = (int)im.width;
    *h = (int)im.height;
    for (int c = 0; c < 3; c++)
        out[c] = buf[((size_t)y * im.width + (size_t)x) * 3 + c];
    free(buf);
}

static void test_labels_are_drawn_in_their_colour(void **st)
{
    vol *lab = vol_new(20, 10, 6);
    assert_non_null(lab);
    /* anisotropic: 0.5 mm in i, 1 mm in j and k */
    lab->spacing[0] = 0.5;
    for (int k = 0; k < 6; k++)
        for (int j = 0; j < 10; j++)
            for (int i = 0; i < 10; i++)
                lab->data[vol_idx(lab, i, j, k)] = 1; /* left half: label 1 */
    lab->data[vol_idx(lab, 15, 5, 3)] = 2;
    const uint8_t rgb[3][3] = {{0, 0, 0}, {200, 100, 0}, {0, 0, 250}};
    char *dir = tu_tmpdir("snap");
    char path[4200];
    snprintf(path, sizeof path, "%s/view.png", dir);
    assert_int_equal(snap_labels_png(lab, NULL, rgb, 3, 2, 0, path), 0);
    int w, h;
    uint8_t px[3];
    read_pixel(path, 40, 40, &w, &h, px);
    /* 10 mm x 10 mm at 0.5 mm pixels is 20x20, halved until 512 pixels: 640x640 */
    assert_int_equal(w, 640);
    assert_int_equal(h, 640);
    assert_int_equal(px[0], 200); /* label 1 seen at depth 0: full colour */
    assert_int_equal(px[1], 100);
    read_pixel(path, 639, 639, &w, &h, px);
    assert_int_equal(px[0], 0); /* background */
    /* Looking from either end of k shows the nearer of two labels on one ray. */
    lab->data[vol_idx(lab, 15, 5, 0)] = 1;
    read_pixel(path, 490, 300, &w, &h, px);
    assert_int_equal(px[2], 163); /* before: label 2 alone on that ray, at depth 3 of 6: 250 x 0.65 */
    assert_int_equal(snap_labels_png(lab, NULL, rgb, 3, 2, 0, path), 0);
    read_pixel(path, 490, 300, &w, &h, px);
    assert_int_equal(px[0], 200); /* from k = 0: label 1 at depth 0 */
    assert_int_equal(snap_labels_png(lab, NULL, rgb, 3, 2, 1, path), 0);
    read_pixel(path, 490, 300, &w, &h, px);
    assert_int_equal(px[0], 0); /* from the high end: label 2 at k = 3, in front */
    assert_true(px[2] > 100 && px[2] < 250);
    assert_int_equal(snap_labels_png(lab, NULL, rgb, 3, 5, 0, path), FN_EINVAL);
    vol_free(lab);
    tu_rmtree(dir);
    free(dir);
}

static void test_unwritable_path_names_the_file(void **st)
{
    uint8_t px[3] = {1, 2, 3};
    assert_int_equal(snap_write_png("/nonexistent-dir/x.png", px, 1, 1), FN_EIO);
    assert_non_null(strstr(fn_err_msg(), "/nonexistent-dir/x.png"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_labels_are_drawn_in_their_colour),
        cmocka_unit_test(test_unwritable_path_names_the_file),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
