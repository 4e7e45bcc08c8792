/* volio: round trips through every writable format, the example CT, the oblique CT_pitch, and
 * fracnav info. */
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
#include <nifti1.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

/* A 5x4x3 volume on an oblique grid (rotated 20 deg about z, then 10 deg about x) with values
 * that exercise rounding and clamping. */
static vol *oblique_volume(void)
{
    vol *v = vol_new(5, 4, 3);
    assert_non_null(v);
    double cz = cos(20 * M_PI / 180), sz = sin(20 * M_PI / 180);
    double cx = cos(10 * M_PI / 180), sx = sin(10 * M_PI / 180);
    double rz[3][3] = {{cz, -sz, 0}, {sz, cz, 0}, {0, 0, 1}}, rx[3][3] = {{1, 0, 0}, {0, cx, -sx}, {0, sx, cx}};
    double dir[3][3];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            dir[r][c] = rx[r][0] * rz[0][c] + rx[r][1] * rz[1][c] + rx[r][2] * rz[2][c];
    const double sp[3] = {0.7, 1.25, 2.5}, org[3] = {-12.5, 40.25, 7};
    vol_set_geometry(v, dir, sp, org);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = (float)((double)i * 7.3 - 40.0);
    v->data[0] = 1e6f;  /* clamps to the top of every integer type */
    v->data[1] = -1e6f; /* and to the bottom */
    v->data[2] = 2.5f;  /* rounds to even: 2 */
    return v;
}

static float stored_value(float x, vol_type t)
{
    static const double lo[] = {0, -128, 0, -32768, 0, -2147483648.0};
    static const double hi[] = {255, 127, 65535, 32767, 4294967295.0, 2147483647.0};
    if (t == VOL_F32 || t == VOL_F64)
        return x;
    double r = nearbyint(x);
    return (float)(r < lo[t] ? lo[t] : r > hi[t] ? hi[t] : r);
}

static void assert_affine_near(const vol *a, const vol *b, double tol)
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++)
            if (fabs(a->affine[r][c] - b->affine[r][c]) > tol)
                fail_msg("affine[%d][%d]: %.9g vs %.9g", r, c, a->affine[r][c], b->affine[r][c]);
}

static void round_trip(const char *ext, vol_type t, double tol)
{
    char *dir = tu_tmpdir("volio");
    char path[4200];
    snprintf(path, sizeof path, "%s/v%s", dir, ext);
    vol *v = oblique_volume();
    if (volio_write(v, path, t) != 0)
        fail_msg("write %s as %s: %s", path, vol_type_name(t), fn_err_msg());
    vol *w = volio_read(path);
    if (!w)
        fail_msg("read %s: %s", path, fn_err_msg());
    assert_int_equal(w->dim[0], 5);
    assert_int_equal(w->dim[1], 4);
    assert_int_equal(w->dim[2], 3);
    assert_int_equal(w->src_type, t);
    for (size_t i = 0; i < vol_count(v); i++)
        if (w->data[i] != stored_value(v->data[i], t))
            fail_msg("%s %s voxel %zu: %g, expected %g", ext, vol_type_name(t), i, w->data[i],
                     stored_value(v->data[i], t));
    assert_affine_near(v, w, tol);
    for (int a = 0; a < 3; a++)
        assert_true(fabs(w->spacing[a] - v->spacing[a]) < tol);
    vol_free(v);
    vol_free(w);
    tu_rmtree(dir);
    free(dir);
}

static void test_round_trip_nii_all_types(void **st)
{
    for (int t = VOL_U8; t <= VOL_F64; t++)
        round_trip(".nii", (vol_type)t, 1e-4); /* NIfTI keeps float32 geometry */
}

static void test_round_trip_nrrd_all_types(void **st)
{
    for (int t = VOL_U8; t <= VOL_F64; t++)
        round_trip(".nrrd", (vol_type)t, 1e-9);
}

static void test_round_trip_compressed_and_detached(void **st)
{
    round_trip(".nii.gz", VOL_I16, 1e-4);
    round_trip(".nii.gz", VOL_F32, 1e-4);
    round_trip(".nhdr", VOL_U16, 1e-9);
    round_trip(".nhdr", VOL_F64, 1e-9);
}

static vol *read_text_nrrd(const char *dir, const char *name, const char *header)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    size_t hl = strlen(header);
    unsigned char *b = calloc(1, hl + 8);
    memcpy(b, header, hl);
    tu_write_file(path, b, hl + 8); /* 2x2x2 uint8 of zeros */
    free(b);
    vol *v = volio_read(path);
    if (!v)
        fail_msg("%s: %s", name, fn_err_msg());
    return v;
}

#define HEAD2 "NRRD0004\ntype: uchar\ndimension: 3\nencoding: raw\nsizes: 2 2 2\n"

static void test_nrrd_spaces(void **st)
{
    char *dir = tu_tmpdir("spaces");
    static const double lps[3][4] = {{-1, 0, 0, -10}, {0, -2, 0, -20}, {0, 0, 3, 30}};
    vol *v = read_text_nrrd(dir, "ras.nrrd", HEAD2 "space: right-anterior-superior\n"
                            "space directions: (1,0,0) (0,2,0) (0,0,3)\nspace origin: (10,20,30)\n\n");
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++)
            assert_true(v->affine[r][c] == lps[r][c]);
    vol_free(v);
    v = read_text_nrrd(dir, "scanner.nrrd", HEAD2 "space: scanner-xyz\n"
                       "space directions: (-1,0,0) (0,-2,0) (0,0,3)\nspace origin: (-10,-20,30)\n\n");
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++)
            assert_true(v->affine[r][c] == lps[r][c]);
    vol_free(v);
    v = read_text_nrrd(dir, "bare.nrrd", HEAD2 "spacings: 2 3 4\n\n");
    assert_true(v->affine[0][0] == 2 && v->affine[1][1] == 3 && v->affine[2][2] == 4);
    assert_true(v->affine[0][1] == 0 && v->affine[0][3] == 0);
    vol_free(v);
    tu_rmtree(dir);
    free(dir);
}

/* A qform-only NIfTI (no sform): a rotation of 30 degrees about z, read as LPS. */
static void test_nifti_qform_only(void **st)
{
    nifti_1_header h;
    memset(&h, 0, sizeof h);
    h.sizeof_hdr = 348;
    h.dim[0] = 3, h.dim[1] = h.dim[2] = h.dim[3] = 2;
    h.dim[4] = h.dim[5] = h.dim[6] = h.dim[7] = 1;
    h.datatype = DT_UINT8, h.bitpix = 8;
    h.pixdim[0] = 1, h.pixdim[1] = 0.5f, h.pixdim[2] = 1.5f, h.pixdim[3] = 2.5f;
    h.vox_offset = 352;
    h.qform_code = 1;
    double th = 30 * M_PI / 180;
    h.quatern_d = (float)sin(th / 2);
    h.qoffset_x = 5, h.qoffset_y = -6, h.qoffset_z = 7;
    memcpy(h.magic, "n+1", 4);
    unsigned char b[360] = {0};
    memcpy(b, &h, sizeof h);
    char *dir = tu_tmpdir("qform");
    char path[4200];
    snprintf(path, sizeof path, "%s/q.nii", dir);
    tu_write_file(path, b, sizeof b);
    vol *v = volio_read(path);
    if (!v)
        fail_msg("%s", fn_err_msg());
    const double ras[3][4] = {{0.5 * cos(th), -1.5 * sin(th), 0, 5}, {0.5 * sin(th), 1.5 * cos(th), 0, -6},
                              {0, 0, 2.5, 7}};
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++)
            assert_true(fabs(v->affine[r][c] - (r < 2 ? -ras[r][c] : ras[r][c])) < 1e-5);
    vol_free(v);
    tu_rmtree(dir);
    free(dir);
}

/* The written qform alone (sform_code zeroed) gives the same geometry, for a right-handed grid
 * and for a left-handed one like the InVesalius layout (qfac -1). */
static void test_nifti_qform_written(void **st)
{
    char *dir = tu_tmpdir("qfac");
    char path[4200];
    snprintf(path, sizeof path, "%s/q.nii", dir);
    for (int left = 0; left < 2; left++) {
        vol *v = oblique_volume();
        if (left)
            for (int r = 0; r < 3; r++)
                v->affine[r][1] = -v->affine[r][1];
        assert_int_equal(volio_write(v, path, VOL_F32), 0);
        size_t n;
        char *b = tu_slurp(path, &n);
        assert_non_null(b);
        nifti_1_header h;
        memcpy(&h, b, sizeof h);
        assert_int_equal(h.qform_code, 1);
        assert_int_equal(h.sform_code, 1);
        assert_true(h.pixdim[0] == (left ? -1.0f : 1.0f));
        h.sform_code = 0;
        memcpy(b, &h, sizeof h);
        tu_write_file(path, b, n);
        free(b);
        vol *w = volio_read(path);
        assert_non_null(w);
        assert_affine_near(v, w, 1e-4);
        vol_free(w);
        vol_free(v);
    }
    tu_rmtree(dir);
    free(dir);
}

static void test_unknown_extension(void **st)
{
    vol *v = oblique_volume();
    assert_int_equal(volio_write(v, "/tmp/x.png", VOL_U8), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "/tmp/x.png"));
    assert_non_null(strstr(fn_err_msg(), "(use .nii, .nii.gz, .nrrd or .nhdr)"));
    /* .inv3 is read only */
    assert_int_equal(volio_write(v, "/tmp/x.inv3", VOL_U8), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "cannot write this format"));
    vol_free(v);
    assert_null(volio_read("/nonexistent/dir/file.nii"));
    assert_non_null(strstr(fn_err_msg(), "/nonexistent/dir/file.nii"));
    char *dir = tu_tmpdir("volio_ext");
    char path[4200];
    snprintf(path, sizeof path, "%s/x.PNG", dir);
    tu_write_file(path, "x", 1);
    assert_null(volio_read(path));
    assert_non_null(strstr(fn_err_msg(), "unknown volume format (expected .nii, .nii.gz, .nrrd, "
                                         ".nhdr, .inv3 or a DICOM folder)"));
    tu_rmtree(dir);
    free(dir);
}

static void test_example_ct_header(void **st)
{
    vol *v = volio_read(tu_example_ct());
    if (!v)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(v->dim[0], 256); /* ni */
    assert_int_equal(v->dim[1], 256); /* nj */
    assert_int_equal(v->dim[2], 108); /* nk: the slices */
    assert_int_equal(v->src_type, VOL_I16);
    assert_true(fabs(v->spacing[0] - 0.957) < 1e-3 && fabs(v->spacing[1] - 0.957) < 1e-3);
    assert_true(fabs(v->spacing[2] - 1.5) < 1e-9);
    /* i -> L, j -> A (LPS -y), k -> S: see volio.h */
    assert_true(v->affine[0][0] > 0 && v->affine[1][1] < 0 && v->affine[2][2] > 0);
    float lo, hi;
    vol_range(v, &lo, &hi);
    assert_true(lo == -1024.0f);
    assert_true(hi > 2900.0f && hi <= 3033.0f);
    vol_free(v);
}

/* CT_pitch's sform (RAS) as stored in its header, read here with zlib only. */
static void pitch_sform(double srow[3][4], int dim[3])
{
    gzFile gz = gzopen(tu_test_data("CT_pitch.nii.gz"), "rb");
    assert_non_null(gz);
    unsigned char h[348];
    assert_int_equal(gzread(gz, h, sizeof h), (int)sizeof h);
    gzclose(gz);
    for (int a = 0; a < 3; a++) {
        int16_t d;
        memcpy(&d, h + 42 + 2 * a, 2);
        dim[a] = d;
    }
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++) {
            float f;
            memcpy(&f, h + 280 + 16 * r + 4 * c, 4);
            srow[r][c] = f;
        }
}

static void test_ct_pitch_geometry(void **st)
{
    vol *v = volio_read(tu_test_data("CT_pitch.nii.gz"));
    if (!v)
        fail_msg("%s", fn_err_msg());
    double srow[3][4];
    int dim[3];
    pitch_sform(srow, dim);
    for (int a = 0; a < 3; a++)
        assert_int_equal(v->dim[a], dim[a]);
    /* direction columns are orthonormal */
    double d[3][3];
    for (int c = 0; c < 3; c++)
        for (int r = 0; r < 3; r++)
            d[c][r] = v->affine[r][c] / v->spacing[c];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) {
            double dot = d[a][0] * d[b][0] + d[a][1] * d[b][1] + d[a][2] * d[b][2];
            assert_true(fabs(dot - (a == b)) < 1e-5);
        }
    /* a pure pitch about the left-right axis, by the header's angle (16.5 degrees) */
    assert_true(fabs(fabs(d[0][0]) - 1) < 1e-6);
    double pitch = atan2(fabs(d[2][1]), d[2][2]) * 180 / M_PI;
    double want = atan2(fabs(srow[1][2]), srow[2][2]) * 180 / M_PI;
    assert_true(fabs(pitch - want) < 1e-3);
    assert_true(pitch > 16.0 && pitch < 17.0);
    /* every corner voxel lands where the sform, converted to LPS, puts it */
    for (int corner = 0; corner < 8; corner++) {
        double ijk[3] = {corner & 1 ? dim[0] - 1 : 0, corner & 2 ? dim[1] - 1 : 0, corner & 4 ? dim[2] - 1 : 0};
        double lps[3];
        vol_index_to_world(v, ijk, lps);
        for (int r = 0; r < 3; r++) {
            double ras = srow[r][0] * ijk[0] + srow[r][1] * ijk[1] + srow[r][2] * ijk[2] + srow[r][3];
            assert_true(fabs(lps[r] - (r < 2 ? -ras : ras)) < 1e-3);
        }
    }
    /* and a round trip through NRRD keeps geometry and data */
    char *dir = tu_tmpdir("pitch");
    char path[4200];
    snprintf(path, sizeof path, "%s/pitch.nrrd", dir);
    assert_int_equal(volio_write(v, path, v->src_type), 0);
    vol *w = volio_read(path);
    assert_non_null(w);
    assert_affine_near(v, w, 1e-9);
    assert_memory_equal(v->data, w->data, vol_count(v) * sizeof(float));
    vol_free(w);
    vol_free(v);
    tu_rmtree(dir);
    free(dir);
}

static void test_cli_info(void **st)
{
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "info --help"), 0);
    assert_non_null(strstr(out, "usage: fracnav info"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "info"), 2);
    free(out);
    assert_int_equal(tu_run_cli(&out, "info --bogus x.nii"), 2);
    free(out);
    assert_int_equal(tu_run_cli(&out, "info '%s' --json", tu_test_data("CT_pitch.nii.gz")), 0);
    assert_non_null(strstr(out, "\"dim\": [175, 248, 58]"));
    assert_non_null(strstr(out, "\"type\": \"uint8\""));
    assert_non_null(strstr(out, "\"space\": \"LPS\""));
    free(out);
    assert_int_equal(tu_run_cli(&out, "info '%s'", tu_test_data("CT_pitch.nii.gz")), 0);
    assert_non_null(strstr(out, "dimensions:  175 x 248 x 58"));
    assert_non_null(strstr(out, "index to world (LPS mm)"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "info /nonexistent.nii.gz"), 1);
    assert_non_null(strstr(out, "fracnav info: /nonexistent.nii.gz: "));
    free(out);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_round_trip_nii_all_types),
        cmocka_unit_test(test_round_trip_nrrd_all_types),
        cmocka_unit_test(test_round_trip_compressed_and_detached),
        cmocka_unit_test(test_nrrd_spaces),
        cmocka_unit_test(test_nifti_qform_only),
        cmocka_unit_test(test_nifti_qform_written),
        cmocka_unit_test(test_unknown_extension),
        cmocka_unit_test(test_example_ct_header),
        cmocka_unit_test(test_ct_pitch_geometry),
        cmocka_unit_test(test_cli_info),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
