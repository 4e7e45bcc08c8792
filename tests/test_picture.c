#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "picture.h"
#include "testutil.h"

#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Reads back a PNG written by picture_write_png and returns the pixel at (x, y). */
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

/* What picture_write_png writes reads back, pixel for pixel, through libpng. */
static void test_pixels_read_back(void **st)
{
    (void)st;
    const int W = 7, H = 5;
    uint8_t rgb[7 * 5 * 3];
    for (int i = 0; i < W * H * 3; i++)
        rgb[i] = (uint8_t)(i * 37 + 11);
    char *dir = tu_tmpdir("picture");
    char path[4200];
    snprintf(path, sizeof path, "%s/view.png", dir);
    assert_int_equal(picture_write_png(path, rgb, W, H), 0);
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int w, h;
            uint8_t px[3];
            read_pixel(path, x, y, &w, &h, px);
            assert_int_equal(w, W);
            assert_int_equal(h, H);
            assert_memory_equal(px, rgb + ((size_t)y * W + (size_t)x) * 3, 3);
        }
    tu_rmtree(dir);
    free(dir);
}

static void test_unwritable_path_names_the_file(void **st)
{
    uint8_t px[3] = {1, 2, 3};
    assert_int_equal(picture_write_png("/nonexistent-dir/x.png", px, 1, 1), FN_EIO);
    assert_non_null(strstr(fn_err_msg(), "/nonexistent-dir/x.png"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_pixels_read_back),
        cmocka_unit_test(test_unwritable_path_names_the_file),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
