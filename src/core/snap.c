#include "snap.h"

#include "err.h"

#include <errno.h>
#include <math.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

int snap_write_png(const char *path, const uint8_t *rgb, int w, int h)
{
    char tmp[4200];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    FILE *f = fopen(tmp, "wb");
    if (!f)
        return fn_err_set(FN_EIO, "%s: cannot write: %s", tmp, strerror(errno));
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
    png_infop info = png ? png_create_info_struct(png) : NULL;
    if (!info || setjmp(png_jmpbuf(png))) {
        png_destroy_write_struct(&png, &info);
        fclose(f);
        unlink(tmp);
        return fn_err_set(FN_EIO, "%s: PNG encoding failed", path);
    }
    png_init_io(png, f);
    png_set_IHDR(png, info, (png_uint_32)w, (png_uint_32)h, 8, PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    for (int y = 0; y < h; y++)
        png_write_row(png, (png_const_bytep)(rgb + (size_t)y * (size_t)w * 3));
    png_write_end(png, NULL);
    png_destroy_write_struct(&png, &info);
    if (fflush(f) != 0 || fsync(fileno(f)) != 0 || fclose(f) != 0) {
        unlink(tmp);
        return fn_err_set(FN_EIO, "%s: write failed: %s", path, strerror(errno));
    }
    if (rename(tmp, path) != 0) {
        unlink(tmp);
        return fn_err_set(FN_EIO, "%s: cannot rename into place: %s", path, strerror(errno));
    }
    return 0;
}

/* The two in-plane axes for a view along `axis`, ordered so the picture is upright for axial CT. */
static void plane_axes(int axis, int *u, int *v)
{
    *u = axis == 0 ? 1 : 0;
    *v = axis == 2 ? 1 : 2;
}

int snap_labels_png(const vol *labels, const vol *ct, const uint8_t (*rgb)[3], int nlabels, int view_axis,
                    int from_end, const char *path)
{
    if (view_axis < 0 || view_axis > 2)
        return fn_err_set(FN_EINVAL, "%s: view axis %d is not 0, 1 or 2", path, view_axis);
    if (ct && memcmp(ct->dim, labels->dim, sizeof ct->dim) != 0)
        return fn_err_set(FN_EINVAL, "%s: CT and labels differ in size", path);
    int u, v;
    plane_axes(view_axis, &u, &v);
    const int *d = labels->dim;
    /* Square pixels in mm: the finer in-plane spacing sets the pixel size. */
    double px = fmin(labels->spacing[u], labels->spacing[v]);
    double wmm = d[u] * labels->spacing[u], hmm = d[v] * labels->spacing[v];
    while (fmax(wmm, hmm) / px < 512 && px > 1e-3)
        px /= 2;
    int w = (int)lround(wmm / px), h = (int)lround(hmm / px);
    uint8_t *img = calloc((size_t)w * (size_t)h, 3);
    if (!img)
        return fn_err_set(FN_ENOMEM, "%s: out of memory for a %dx%d picture", path, w, h);
    float lo = -200, hi = 1500;
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int idx[3];
            idx[u] = (int)(x * px / labels->spacing[u]);
            idx[v] = d[v] - 1 - (int)(y * px / labels->spacing[v]);
            float mip = lo;
            int hit = 0, depth = 0;
            for (int s = 0; s < d[view_axis]; s++) {
                idx[view_axis] = from_end ? d[view_axis] - 1 - s : s;
                size_t at = vol_idx(labels, idx[0], idx[1], idx[2]);
                int lab = (int)labels->data[at];
                if (!hit && lab > 0 && lab < nlabels) {
                    hit = lab;
                    depth = s;
                }
                if (ct && ct->data[at] > mip)
                    mip = ct->data[at];
            }
            uint8_t *p = img + ((size_t)y * (size_t)w + (size_t)x) * 3;
            if (hit) {
                double shade = 1.0 - 0.7 * depth / (double)d[view_axis];
                for (int c = 0; c < 3; c++)
                    p[c] = (uint8_t)lround(rgb[hit][c] * shade);
            } else {
                double g = ct ? (mip - lo) / (hi - lo) : 0;
                uint8_t gv = (uint8_t)lround(80 * fmin(fmax(g, 0), 1));
                p[0] = p[1] = p[2] = gv;
            }
        }
    }
    int rc = snap_write_png(path, img, w, h);
    free(img);
    return rc;
}
