/* volio: the voxel conversions and geometry checks every format shares. */
#include "volio_impl.h"

#include "err.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

int volio__check_axes(const double m[3][3], const char *path, const char *field)
{
    double len[3];
    for (int c = 0; c < 3; c++) {
        len[c] = sqrt(m[0][c] * m[0][c] + m[1][c] * m[1][c] + m[2][c] * m[2][c]);
        if (!isfinite(len[c]) || len[c] <= 0)
            return fn_err_set(FN_EFORMAT, "%s: %s: axis %d has no length (%g mm)", path, field, c,
                              len[c]);
    }
    for (int a = 0; a < 3; a++)
        for (int b = a + 1; b < 3; b++) {
            double cosab = (m[0][a] * m[0][b] + m[1][a] * m[1][b] + m[2][a] * m[2][b]) /
                           (len[a] * len[b]);
            if (fabs(cosab) > 1e-4)
                return fn_err_set(FN_EFORMAT,
                                  "%s: %s: sheared grid, axes %d and %d are %.4f degrees from "
                                  "orthogonal (gantry tilt?); resample it first",
                                  path, field, a, b, fabs(90.0 - acos(cosab) * 180.0 / M_PI));
        }
    return 0;
}

int volio__check_spacing(const double sp[3], const char *path, const char *field)
{
    for (int c = 0; c < 3; c++)
        if (!(sp[c] >= VOLIO_MIN_SPACING_MM && sp[c] <= VOLIO_MAX_SPACING_MM))
            return fn_err_set(FN_EFORMAT, "%s: %s: axis %d is %g mm, outside a micron to a metre "
                              "(%g..%g mm)", path, field, c, sp[c], VOLIO_MIN_SPACING_MM,
                              VOLIO_MAX_SPACING_MM);
    return 0;
}

int volio__set_affine(vol *v, const double a[3][3], const double origin[3], const char *path,
                      const char *field)
{
    int rc = volio__check_axes(a, path, field);
    if (rc < 0)
        return rc;
    double dir[3][3], sp[3];
    for (int c = 0; c < 3; c++)
        sp[c] = sqrt(a[0][c] * a[0][c] + a[1][c] * a[1][c] + a[2][c] * a[2][c]);
    if ((rc = volio__check_spacing(sp, path, field)) < 0)
        return rc;
    for (int c = 0; c < 3; c++) {
        for (int r = 0; r < 3; r++)
            dir[r][c] = a[r][c] / sp[c];
    }
    vol_set_geometry(v, dir, sp, origin);
    return 0;
}

size_t volio__type_size(vol_type t)
{
    static const size_t size[] = {1, 1, 2, 2, 4, 4, 4, 8};
    return (unsigned)t <= VOL_F64 ? size[t] : 0;
}

#define TO_FLOAT(T)                                                                        \
    do {                                                                                   \
        const T *s = src;                                                                  \
        if (scaled)                                                                        \
            for (size_t i = 0; i < n; i++)                                                 \
                dst[i] = (float)(slope * (double)s[i] + inter);                            \
        else                                                                               \
            for (size_t i = 0; i < n; i++)                                                 \
                dst[i] = (float)s[i];                                                      \
    } while (0)

void volio__to_float(const void *src, vol_type t, size_t n, double slope, double inter, float *dst)
{
    int scaled = slope != 1.0 || inter != 0.0;
    switch (t) {
    case VOL_U8: TO_FLOAT(uint8_t); break;
    case VOL_I8: TO_FLOAT(int8_t); break;
    case VOL_U16: TO_FLOAT(uint16_t); break;
    case VOL_I16: TO_FLOAT(int16_t); break;
    case VOL_U32: TO_FLOAT(uint32_t); break;
    case VOL_I32: TO_FLOAT(int32_t); break;
    case VOL_F32: TO_FLOAT(float); break;
    case VOL_F64: TO_FLOAT(double); break;
    }
}

/* Round to nearest and clamp into [lo, hi]; NaN becomes 0. */
static double clamp_round(float x, double lo, double hi)
{
    if (isnan(x))
        return 0;
    double r = nearbyint((double)x);
    return r < lo ? lo : r > hi ? hi : r;
}

#define FROM_FLOAT_INT(T, LO, HI)                                                          \
    do {                                                                                   \
        T *d = dst;                                                                        \
        for (size_t i = 0; i < n; i++)                                                     \
            d[i] = (T)clamp_round(src[i], (double)(LO), (double)(HI));                     \
    } while (0)

void volio__from_float(const float *src, size_t n, vol_type t, void *dst)
{
    switch (t) {
    case VOL_U8: FROM_FLOAT_INT(uint8_t, 0, UINT8_MAX); break;
    case VOL_I8: FROM_FLOAT_INT(int8_t, INT8_MIN, INT8_MAX); break;
    case VOL_U16: FROM_FLOAT_INT(uint16_t, 0, UINT16_MAX); break;
    case VOL_I16: FROM_FLOAT_INT(int16_t, INT16_MIN, INT16_MAX); break;
    case VOL_U32: FROM_FLOAT_INT(uint32_t, 0, UINT32_MAX); break;
    case VOL_I32: FROM_FLOAT_INT(int32_t, INT32_MIN, INT32_MAX); break;
    case VOL_F32: memcpy(dst, src, n * sizeof(float)); break;
    case VOL_F64: {
        double *d = dst;
        for (size_t i = 0; i < n; i++)
            d[i] = src[i];
        break;
    }
    }
}
