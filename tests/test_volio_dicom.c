/* volio: DICOM folders through dcm2niix. The test writes a tiny oblique CT series itself
 * (Part 10, explicit VR little endian) and checks that every voxel read back sits, in LPS, on the
 * pixel the series put there, with its rescaled value; then the error paths. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#define ROWS 6
#define COLS 8
#define SLICES 4
#define ROW_SP 0.5   /* mm between rows, along the column direction */
#define COL_SP 0.75  /* mm between columns, along the row direction */
#define SLICE_SP 2.0
#define TILT (20 * M_PI / 180)

static const double row_dir[3] = {1, 0, 0};
static double col_dir[3], normal[3];
static const double pos0[3] = {-3.0, 5.0, 40.0};

typedef struct {
    unsigned char *b;
    size_t n;
} buf;

static void put(buf *t, const void *d, size_t n)
{
    t->b = realloc(t->b, t->n + n);
    memcpy(t->b + t->n, d, n);
    t->n += n;
}

static void put16(buf *t, unsigned v)
{
    unsigned char b[2] = {(unsigned char)v, (unsigned char)(v >> 8)};
    put(t, b, 2);
}

static void put32(buf *t, unsigned long v)
{
    unsigned char b[4] = {(unsigned char)v, (unsigned char)(v >> 8), (unsigned char)(v >> 16), (unsigned char)(v >> 24)};
    put(t, b, 4);
}

/* One explicit-VR element; strings are padded to even length (NUL for UI, space otherwise). */
static void elem(buf *t, unsigned group, unsigned el, const char *vr, const void *val, size_t len)
{
    int pad = len & 1, longform = !strcmp(vr, "OB") || !strcmp(vr, "OW");
    put16(t, group);
    put16(t, el);
    put(t, vr, 2);
    if (longform) {
        put16(t, 0);
        put32(t, (unsigned long)(len + pad));
    } else {
        put16(t, (unsigned)(len + pad));
    }
    put(t, val, len);
    if (pad)
        put(t, !strcmp(vr, "UI") ? "\0" : " ", 1);
}

static void str(buf *t, unsigned g, unsigned e, const char *vr, const char *s)
{
    elem(t, g, e, vr, s, strlen(s));
}

static void us(buf *t, unsigned g, unsigned e, unsigned v)
{
    unsigned char b[2] = {(unsigned char)v, (unsigned char)(v >> 8)};
    elem(t, g, e, "US", b, 2);
}

static int16_t pixel(int slice, int row, int col)
{
    return (int16_t)(100 * slice + 10 * row + col);
}

static void write_slice(const char *dir, int s)
{
    char sop[64], txt[256], path[4300];
    snprintf(sop, sizeof sop, "1.2.826.0.1.3680043.99.1.%d", s + 1);
    buf meta = {0}, t = {0};
    static const unsigned char version[2] = {0, 1};
    elem(&meta, 2, 1, "OB", version, 2);
    str(&meta, 2, 2, "UI", "1.2.840.10008.5.1.4.1.1.2");
    str(&meta, 2, 3, "UI", sop);
    str(&meta, 2, 0x10, "UI", "1.2.840.10008.1.2.1");
    str(&meta, 2, 0x12, "UI", "1.2.826.0.1.3680043.99");
    put(&t, (unsigned char[128]){0}, 128);
    put(&t, "DICM", 4);
    unsigned char gl[4] = {(unsigned char)meta.n, (unsigned char)(meta.n >> 8), 0, 0};
    elem(&t, 2, 0, "UL", gl, 4);
    put(&t, meta.b, meta.n);
    str(&t, 8, 8, "CS", "ORIGINAL\\PRIMARY\\AXIAL");
    str(&t, 8, 0x16, "UI", "1.2.840.10008.5.1.4.1.1.2");
    str(&t, 8, 0x18, "UI", sop);
    str(&t, 8, 0x20, "DA", "20260101");
    str(&t, 8, 0x30, "TM", "120000");
    str(&t, 8, 0x60, "CS", "CT");
    str(&t, 0x10, 0x10, "PN", "Test^Volio");
    snprintf(txt, sizeof txt, "%g", SLICE_SP);
    str(&t, 0x18, 0x50, "DS", txt);
    str(&t, 0x20, 0xD, "UI", "1.2.826.0.1.3680043.99.2");
    str(&t, 0x20, 0xE, "UI", "1.2.826.0.1.3680043.99.3");
    str(&t, 0x20, 0x11, "IS", "1");
    snprintf(txt, sizeof txt, "%d", s + 1);
    str(&t, 0x20, 0x13, "IS", txt);
    snprintf(txt, sizeof txt, "%.6f\\%.6f\\%.6f", pos0[0] + s * SLICE_SP * normal[0],
             pos0[1] + s * SLICE_SP * normal[1], pos0[2] + s * SLICE_SP * normal[2]);
    str(&t, 0x20, 0x32, "DS", txt);
    snprintf(txt, sizeof txt, "%.6f\\%.6f\\%.6f\\%.6f\\%.6f\\%.6f", row_dir[0], row_dir[1], row_dir[2],
             col_dir[0], col_dir[1], col_dir[2]);
    str(&t, 0x20, 0x37, "DS", txt);
    us(&t, 0x28, 2, 1);
    str(&t, 0x28, 4, "CS", "MONOCHROME2");
    us(&t, 0x28, 0x10, ROWS);
    us(&t, 0x28, 0x11, COLS);
    snprintf(txt, sizeof txt, "%g\\%g", ROW_SP, COL_SP);
    str(&t, 0x28, 0x30, "DS", txt);
    us(&t, 0x28, 0x100, 16);
    us(&t, 0x28, 0x101, 16);
    us(&t, 0x28, 0x102, 15);
    us(&t, 0x28, 0x103, 1);
    str(&t, 0x28, 0x1052, "DS", "-1024");
    str(&t, 0x28, 0x1053, "DS", "1");
    int16_t px[ROWS * COLS];
    for (int r = 0; r < ROWS; r++)
        for (int c = 0; c < COLS; c++)
            px[r * COLS + c] = pixel(s, r, c);
    elem(&t, 0x7FE0, 0x10, "OW", px, sizeof px);
    snprintf(path, sizeof path, "%s/IM%04d.dcm", dir, s);
    tu_write_file(path, t.b, t.n);
    free(meta.b);
    free(t.b);
}

static void test_oblique_series(void **st)
{
    col_dir[0] = 0, col_dir[1] = cos(TILT), col_dir[2] = -sin(TILT);
    normal[0] = 0, normal[1] = sin(TILT), normal[2] = cos(TILT); /* row x col */
    char *dir = tu_tmpdir("dicom");
    for (int s = 0; s < SLICES; s++)
        write_slice(dir, s);
    vol *v = volio_read(dir);
    if (!v)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(vol_count(v), ROWS * COLS * SLICES);
    size_t checked = 0;
    for (int k = 0; k < v->dim[2]; k++)
        for (int j = 0; j < v->dim[1]; j++)
            for (int i = 0; i < v->dim[0]; i++) {
                double ijk[3] = {i, j, k}, w[3], rel[3];
                vol_index_to_world(v, ijk, w);
                for (int a = 0; a < 3; a++)
                    rel[a] = w[a] - pos0[a];
                double c = (rel[0] * row_dir[0] + rel[1] * row_dir[1] + rel[2] * row_dir[2]) / COL_SP;
                double r = (rel[0] * col_dir[0] + rel[1] * col_dir[1] + rel[2] * col_dir[2]) / ROW_SP;
                double s = (rel[0] * normal[0] + rel[1] * normal[1] + rel[2] * normal[2]) / SLICE_SP;
                int ci = (int)lround(c), ri = (int)lround(r), si = (int)lround(s);
                if (fabs(c - ci) > 1e-3 || fabs(r - ri) > 1e-3 || fabs(s - si) > 1e-3)
                    fail_msg("voxel %d %d %d is at col %g row %g slice %g, off the DICOM grid", i, j, k, c, r, s);
                assert_true(ci >= 0 && ci < COLS && ri >= 0 && ri < ROWS && si >= 0 && si < SLICES);
                float want = (float)(pixel(si, ri, ci) - 1024);
                if (v->data[vol_idx(v, i, j, k)] != want)
                    fail_msg("voxel %d %d %d (col %d row %d slice %d): %g, expected %g", i, j, k, ci, ri, si,
                             v->data[vol_idx(v, i, j, k)], want);
                checked++;
            }
    assert_int_equal(checked, ROWS * COLS * SLICES);
    vol_free(v);
    tu_rmtree(dir);
    free(dir);
}

static void test_errors(void **st)
{
    char *dir = tu_tmpdir("dicom-bad");
    fn_err_clear();
    assert_null(volio_read(dir));
    assert_non_null(strstr(fn_err_msg(), dir));
    assert_non_null(strstr(fn_err_msg(), "no DICOM series found"));
    char p[4300];
    snprintf(p, sizeof p, "%s/junk.dcm", dir);
    tu_write_file(p, "not dicom", 9);
    assert_null(volio_read(dir));
    assert_non_null(strstr(fn_err_msg(), "no DICOM series found"));
    /* without dcm2niix on PATH */
    const char *old = getenv("PATH");
    char *saved = old ? strdup(old) : NULL;
    setenv("PATH", "/nonexistent", 1);
    vol *v = volio_read(dir);
    if (saved)
        setenv("PATH", saved, 1);
    free(saved);
    assert_null(v);
    assert_non_null(strstr(fn_err_msg(), "dcm2niix"));
    assert_non_null(strstr(fn_err_msg(), "install"));
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_oblique_series),
        cmocka_unit_test(test_errors),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
