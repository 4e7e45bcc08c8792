#include "vol.h"

#include "err.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define BUDGET_DEFAULT ((size_t)8 << 30)

/* FRACNAV_MAX_BYTES as a positive whole number of bytes: 1 and *out set, 0 when unset, -1 when
 * it is something else. */
static int budget_env(size_t *out)
{
    const char *s = getenv("FRACNAV_MAX_BYTES");
    if (!s || !*s)
        return 0;
    char *end;
    errno = 0;
    unsigned long long b = strtoull(s, &end, 10);
    if (*s == '-' || *end != '\0' || errno || b == 0 || b > SIZE_MAX)
        return -1;
    *out = (size_t)b;
    return 1;
}

size_t vol_budget(void)
{
    size_t b;
    return budget_env(&b) == 1 ? b : BUDGET_DEFAULT;
}

/* "1.5 GiB", "12.0 MiB" or "4000 bytes": small budgets read as what they are, not "0.0 GiB". */
static const char *human_bytes(double n, char *buf, size_t cap)
{
    if (n >= (double)(1 << 30))
        snprintf(buf, cap, "%.1f GiB", n / (1 << 30));
    else if (n >= (double)(1 << 20))
        snprintf(buf, cap, "%.1f MiB", n / (1 << 20));
    else
        snprintf(buf, cap, "%.0f bytes", n);
    return buf;
}

int vol_check_dims(const int64_t dim[3], size_t elem_bytes, const char *what)
{
    for (int a = 0; a < 3; a++)
        if (dim[a] <= 0 || dim[a] > (1 << 20))
            return fn_err_set(FN_EFORMAT, "%s: dimension %d is %lld (must be 1..%d)", what, a,
                              (long long)dim[a], 1 << 20);
    size_t budget = BUDGET_DEFAULT;
    if (budget_env(&budget) < 0)
        return fn_err_set(FN_EINVAL, "FRACNAV_MAX_BYTES is '%s': expected a whole number of bytes "
                                     "over 0 (e.g. 8589934592 for 8 GiB)", getenv("FRACNAV_MAX_BYTES"));
    size_t n = (size_t)dim[0];
    for (int a = 1; a < 3; a++) {
        if (n > SIZE_MAX / (size_t)dim[a])
            return fn_err_set(FN_ENOMEM, "%s: %lldx%lldx%lld voxels overflow", what,
                              (long long)dim[0], (long long)dim[1], (long long)dim[2]);
        n *= (size_t)dim[a];
    }
    char need[32], have[32];
    if (elem_bytes && n > budget / elem_bytes)
        return fn_err_set(FN_ENOMEM, "%s: %lldx%lldx%lld voxels need %s, over the memory budget of %s "
                                     "(FRACNAV_MAX_BYTES)",
                          what, (long long)dim[0], (long long)dim[1], (long long)dim[2],
                          human_bytes((double)n * (double)elem_bytes, need, sizeof need),
                          human_bytes((double)budget, have, sizeof have));
    return 0;
}

vol *vol_new(int nx, int ny, int nz)
{
    int64_t d[3] = {nx, ny, nz};
    if (vol_check_dims(d, sizeof(float), "volume") < 0)
        return NULL;
    vol *v = calloc(1, sizeof *v);
    if (!v) {
        fn_err_set(FN_ENOMEM, "volume: out of memory");
        return NULL;
    }
    v->dim[0] = nx;
    v->dim[1] = ny;
    v->dim[2] = nz;
    v->data = calloc(vol_count(v), sizeof(float));
    if (!v->data) {
        free(v);
        fn_err_set(FN_ENOMEM, "volume: out of memory for %dx%dx%d voxels", nx, ny, nz);
        return NULL;
    }
    static const double eye[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    static const double one[3] = {1, 1, 1}, zero[3] = {0, 0, 0};
    vol_set_geometry(v, eye, one, zero);
    v->src_type = VOL_F32;
    return v;
}

void vol_free(vol *v)
{
    if (!v)
        return;
    free(v->data);
    free(v);
}

void vol_set_geometry(vol *v, const double dir[3][3], const double spacing[3], const double origin[3])
{
    for (int r = 0; r < 3; r++) {
        for (int c = 0; c < 3; c++)
            v->affine[r][c] = dir[r][c] * spacing[c];
        v->affine[r][3] = origin[r];
    }
    memcpy(v->spacing, spacing, sizeof v->spacing);
}

void vol_index_to_world(const vol *v, const double ijk[3], double lps[3])
{
    for (int r = 0; r < 3; r++)
        lps[r] = v->affine[r][0] * ijk[0] + v->affine[r][1] * ijk[1] + v->affine[r][2] * ijk[2] +
                 v->affine[r][3];
}

void vol_world_to_index(const vol *v, const double lps[3], double ijk[3])
{
    double d[3] = {lps[0] - v->affine[0][3], lps[1] - v->affine[1][3], lps[2] - v->affine[2][3]};
    for (int c = 0; c < 3; c++) {
        double s2 = 0, dot = 0;
        for (int r = 0; r < 3; r++) {
            s2 += v->affine[r][c] * v->affine[r][c];
            dot += v->affine[r][c] * d[r];
        }
        ijk[c] = dot / s2;
    }
}

void vol_range(const vol *v, float *lo, float *hi)
{
    size_t n = vol_count(v);
    float a = INFINITY, b = -INFINITY;
    for (size_t i = 0; i < n; i++) {
        if (v->data[i] < a)
            a = v->data[i];
        if (v->data[i] > b)
            b = v->data[i];
    }
    *lo = a;
    *hi = b;
}

const char *vol_type_name(vol_type t)
{
    static const char *names[] = {"uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"};
    return (unsigned)t < sizeof names / sizeof names[0] ? names[t] : "unknown";
}
