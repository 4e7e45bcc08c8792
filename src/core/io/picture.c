#include "picture.h"

#include "durable.h"
#include "err.h"

#include <errno.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

typedef struct png_ctx {
    const uint8_t *rgb;
    int w, h;
} png_ctx;

static int write_png(durable_file *df, void *ctx)
{
    const png_ctx *x = ctx;
    FILE *f = durable_stream(df);
    if (!f)
        return FN_EIO;
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
    png_infop info = png ? png_create_info_struct(png) : NULL;
    if (!info || setjmp(png_jmpbuf(png))) {
        png_destroy_write_struct(&png, &info);
        fclose(f);
        return fn_err_set(FN_EIO, "%s: PNG encoding failed", df->tmp);
    }
    png_init_io(png, f);
    png_set_IHDR(png, info, (png_uint_32)x->w, (png_uint_32)x->h, 8, PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    for (int y = 0; y < x->h; y++)
        png_write_row(png, (png_const_bytep)(x->rgb + (size_t)y * (size_t)x->w * 3));
    png_write_end(png, NULL);
    png_destroy_write_struct(&png, &info);
    return fclose(f) != 0 ? fn_err_set(FN_EIO, "%s: write failed: %s", df->tmp, strerror(errno)) : 0;
}

int picture_write_png(const char *path, const uint8_t *rgb, int w, int h)
{
    png_ctx x = {rgb, w, h};
    return durable_replace(path, write_png, &x);
}

/* The two in-plane axes for a view along `axis`, ordered so the picture is upright for axial CT. */
