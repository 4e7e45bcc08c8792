/* volio: the malformed-file battery. Every bad file must give NULL and an error that names the
 * file and the field, without crashing or allocating what the header claims. */
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
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>
#include <zlib.h>

/* Reading path must fail with a message holding the path and every one of the words. */
static void expect_error(const char *path, const char *w1, const char *w2)
{
    fn_err_clear();
    vol *v = volio_read(path);
    if (v) {
        vol_free(v);
        fail_msg("%s was read, expected an error about '%s'", path, w1);
    }
    const char *m = fn_err_msg();
    if (!strstr(m, path) || !strstr(m, w1) || (w2 && !strstr(m, w2)))
        fail_msg("error for %s lacks '%s'/'%s': %s", path, w1, w2 ? w2 : "", m);
}

static void write_gz(const char *path, const void *data, size_t n)
{
    gzFile gz = gzopen(path, "wb");
    assert_non_null(gz);
    assert_int_equal(gzwrite(gz, data, (unsigned)n), (int)n);
    assert_int_equal(gzclose(gz), Z_OK);
}

/* ---- NIfTI ---- */

static nifti_1_header good_header(int nx, int ny, int nz, int dt, int bitpix)
{
    nifti_1_header h;
    memset(&h, 0, sizeof h);
    h.sizeof_hdr = 348;
    h.dim[0] = 3, h.dim[1] = (short)nx, h.dim[2] = (short)ny, h.dim[3] = (short)nz;
    h.dim[4] = h.dim[5] = h.dim[6] = h.dim[7] = 1;
    h.datatype = (short)dt;
    h.bitpix = (short)bitpix;
    h.pixdim[0] = 1, h.pixdim[1] = h.pixdim[2] = h.pixdim[3] = 1;
    h.vox_offset = 352;
    h.sform_code = 1;
    h.srow_x[0] = h.srow_y[1] = h.srow_z[2] = 1;
    memcpy(h.magic, "n+1", 4);
    return h;
}

/* Header, 4 extension bytes, then data_bytes of a pattern. */
static void write_nii(const char *path, const nifti_1_header *h, size_t data_bytes, int gz)
{
    size_t n = 352 + data_bytes;
    unsigned char *b = calloc(1, n);
    memcpy(b, h, sizeof *h);
    for (size_t i = 352; i < n; i++)
        b[i] = (unsigned char)(i * 37);
    if (gz)
        write_gz(path, b, n);
    else
        tu_write_file(path, b, n);
    free(b);
}

static void test_nifti_battery(void **st)
{
    nifti_1_header h = good_header(4, 4, 4, DT_INT16, 16);
    const char *p = tu_in_dir("good.nii");
    write_nii(p, &h, 128, 0);
    vol *v = volio_read(p);
    assert_non_null(v); /* the baseline is fine */
    vol_free(v);

    p = tu_in_dir("short_header.nii");
    tu_write_file(p, &h, 100);
    expect_error(p, "header truncated", NULL);

    h = good_header(4, 4, 4, DT_INT16, 16);
    memcpy(h.magic, "xyz", 4);
    write_nii(p = tu_in_dir("magic.nii"), &h, 128, 0);
    expect_error(p, "magic", NULL);

    h = good_header(4, 4, 4, DT_INT16, 16);
    h.sizeof_hdr = 1234;
    write_nii(p = tu_in_dir("sizeof.nii"), &h, 128, 0);
    expect_error(p, "sizeof_hdr", NULL);

    h = good_header(4, -4, 4, DT_INT16, 16);
    write_nii(p = tu_in_dir("negative.nii"), &h, 128, 0);
    expect_error(p, "dim[2] = -4", NULL);

    h = good_header(30000, 30000, 30000, DT_UINT8, 8);
    write_nii(p = tu_in_dir("lying.nii"), &h, 64, 0);
    expect_error(p, "data truncated", NULL);
    write_nii(p = tu_in_dir("lying.nii.gz"), &h, 64, 1);
    expect_error(p, "more than a", "can hold");

    h = good_header(4, 4, 4, DT_INT16, 16);
    write_nii(p = tu_in_dir("truncated.nii"), &h, 100, 0);
    expect_error(p, "data truncated", NULL);
    write_nii(p = tu_in_dir("truncated.nii.gz"), &h, 100, 1);
    expect_error(p, "data truncated", NULL);

    h = good_header(4, 4, 4, 32 /* complex64 */, 64);
    write_nii(p = tu_in_dir("complex.nii"), &h, 512, 0);
    expect_error(p, "datatype 32", NULL);

    h = good_header(4, 4, 4, DT_INT16, 16);
    h.dim[0] = 4, h.dim[4] = 3;
    write_nii(p = tu_in_dir("4d.nii"), &h, 384, 0);
    expect_error(p, "dim[4] = 3", "3D");

    h = good_header(4, 4, 4, DT_INT16, 16);
    h.vox_offset = 1e12f;
    write_nii(p = tu_in_dir("far_offset.nii"), &h, 128, 0);
    expect_error(p, "vox_offset is 1e+12, too large", "beyond the end of the file");
    h.vox_offset = 100;
    write_nii(p = tu_in_dir("near_offset.nii"), &h, 128, 0);
    expect_error(p, "vox_offset is 100, must be at least 348", NULL);

    h = good_header(4, 4, 4, DT_INT16, 16);
    h.srow_x[1] = 0.5f; /* the j axis leans into x: shear */
    write_nii(p = tu_in_dir("shear.nii"), &h, 128, 0);
    expect_error(p, "sform", "sheared");
}

static void test_nifti_budget(void **st)
{
    nifti_1_header h = good_header(20, 20, 20, DT_FLOAT32, 32);
    const char *p = tu_in_dir("honest.nii");
    write_nii(p, &h, 32000, 0);
    setenv("FRACNAV_MAX_BYTES", "10000", 1);
    fn_err_clear();
    vol *v = volio_read(p);
    unsetenv("FRACNAV_MAX_BYTES");
    assert_null(v);
    assert_non_null(strstr(fn_err_msg(), "memory budget"));
    assert_non_null(strstr(fn_err_msg(), p));
    /* A small budget reads as what it is, not "0.0 GiB". */
    if (!strstr(fn_err_msg(), "need 64000 bytes, over the memory budget of 10000 bytes"))
        fail_msg("budget message: %s", fn_err_msg());

    /* A budget that is not a number is an error that names the variable, not the default. */
    char *out = NULL;
    setenv("FRACNAV_MAX_BYTES", "8G", 1);
    v = volio_read(p);
    int rc = tu_run_cli(&out, "info '%s'", p);
    setenv("FRACNAV_MAX_BYTES", "3000000", 1);
    vol *big = vol_new(1000, 1000, 1);
    unsetenv("FRACNAV_MAX_BYTES");
    assert_null(v);
    assert_int_equal(rc, 1);
    if (!strstr(out, "FRACNAV_MAX_BYTES is '8G'"))
        fail_msg("bad budget message: %s", out);
    free(out);
    assert_null(big);
    if (!strstr(fn_err_msg(), "need 3.8 MiB, over the memory budget of 2.9 MiB"))
        fail_msg("MiB budget message: %s", fn_err_msg());
}

static void test_nifti_corrupt_gzip(void **st)
{
    vol *v = vol_new(32, 32, 32);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = (float)((i * 2654435761u) % 4096);
    const char *p = tu_in_dir("corrupt.nii.gz");
    assert_int_equal(volio_write(v, p, VOL_I16), 0);
    vol_free(v);
    size_t n;
    unsigned char *b = (unsigned char *)tu_slurp(p, &n);
    assert_true(n > 1000);
    memset(b + n / 2, 0xA5, 64);
    tu_write_file(p, b, n);
    expect_error(p, ": ", NULL);
    b[3] = 0xE0; /* reserved gzip header flags */
    tu_write_file(p, b, n);
    expect_error(p, "gzip", NULL);
    free(b);
}

/* ---- InVesalius ---- */

typedef struct {
    unsigned char *b;
    size_t n, cap;
} buf;

static void put(buf *t, const void *d, size_t n)
{
    if (t->n + n > t->cap) { /* doubling: thousands of entries stay fast under ASan */
        t->cap = 2 * (t->n + n);
        t->b = realloc(t->b, t->cap);
    }
    memcpy(t->b + t->n, d, n);
    t->n += n;
}

/* One tar entry of the given type ('0' file, '5' folder, '2' symlink). */
static void tar_add_typed(buf *t, const char *name, const void *data, size_t size, char type)
{
    unsigned char h[512] = {0};
    snprintf((char *)h, 100, "%s", name);
    snprintf((char *)h + 100, 8, "%07o", 0644);
    snprintf((char *)h + 124, 12, "%011o", (unsigned)size);
    snprintf((char *)h + 136, 12, "%011o", 0u);
    h[156] = (unsigned char)type;
    if (type == '2')
        snprintf((char *)h + 157, 100, "main.plist");
    memcpy(h + 257, "ustar", 6);
    memcpy(h + 263, "00", 2);
    memset(h + 148, ' ', 8);
    unsigned sum = 0;
    for (int i = 0; i < 512; i++)
        sum += h[i];
    snprintf((char *)h + 148, 8, "%06o", sum);
    put(t, h, 512);
    put(t, data, size);
    static const unsigned char zero[512];
    put(t, zero, (512 - size % 512) % 512);
}

static void tar_add(buf *t, const char *name, const void *data, size_t size)
{
    tar_add_typed(t, name, data, size, '0');
}

static char *plist_text(const char *shape, const char *dtype, const char *orientation)
{
    char *s = malloc(4096);
    snprintf(s, 4096,
             "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
             "<!DOCTYPE plist PUBLIC \"-//Apple Computer//DTD PLIST 1.0//EN\" \"x\">\n"
             "<plist version=\"1.0\">\n<dict>\n\t<key>matrix</key>\n\t<dict>\n"
             "\t\t<key>dtype</key>\n\t\t<string>%s</string>\n"
             "\t\t<key>filename</key>\n\t\t<string>matrix.dat</string>\n"
             "\t\t<key>shape</key>\n\t\t<array>%s</array>\n\t</dict>\n"
             "\t<key>orientation</key>\n\t<integer>%s</integer>\n"
             "\t<key>spacing</key>\n\t<array><real>0.5</real><real>0.5</real><real>2.0</real></array>\n"
             "\t<key>empty</key>\n\t<dict/>\n\t<key>flag</key>\n\t<true/>\n"
             "</dict>\n</plist>\n",
             dtype, shape, orientation);
    return s;
}

#define SHAPE_234 "<integer>2</integer><integer>3</integer><integer>4</integer>"

/* An .inv3 of a 4x3x2 (i j k) int16 volume whose voxel n holds n - 10. */
static void write_inv3(const char *path, const char *plist, int matrix_first, size_t matrix_bytes, int zip)
{
    int16_t m[24];
    for (int i = 0; i < 24; i++)
        m[i] = (int16_t)(i - 10);
    buf t = {0};
    if (matrix_first)
        tar_add(&t, "tmpdir/matrix.dat", m, matrix_bytes);
    if (plist)
        tar_add(&t, "tmpdir/main.plist", plist, strlen(plist));
    if (!matrix_first)
        tar_add(&t, "tmpdir/matrix.dat", m, matrix_bytes);
    static const unsigned char end[1024];
    put(&t, end, sizeof end);
    if (zip)
        write_gz(path, t.b, t.n);
    else
        tu_write_file(path, t.b, t.n);
    free(t.b);
}

static void test_inv3_small_project(void **st)
{
    char *pl = plist_text(SHAPE_234, "int16", "1");
    for (int first = 0; first < 2; first++) {
        const char *p = tu_in_dir(first ? "matrix_first.inv3" : "plist_first.inv3");
        write_inv3(p, pl, first, 48, 1);
        vol *v = volio_read(p);
        if (!v)
            fail_msg("%s", fn_err_msg());
        assert_int_equal(v->dim[0], 4);
        assert_int_equal(v->dim[1], 3);
        assert_int_equal(v->dim[2], 2);
        assert_int_equal(v->src_type, VOL_I16);
        for (int i = 0; i < 24; i++)
            assert_true(v->data[i] == (float)(i - 10));
        assert_true(v->affine[0][0] == 0.5 && v->affine[1][1] == -0.5 && v->affine[2][2] == 2.0);
        vol_free(v);
    }
    free(pl);
}

/* `tar czf x.inv3 somefolder` puts the folder's own entry first; links may sit among the files. */
static void test_inv3_folder_and_link_entries(void **st)
{
    int16_t m[24];
    for (int i = 0; i < 24; i++)
        m[i] = (int16_t)(i - 10);
    char *pl = plist_text(SHAPE_234, "int16", "1");
    buf t = {0};
    tar_add_typed(&t, "tmpdir/", "", 0, '5');
    tar_add_typed(&t, "tmpdir/link.plist", "", 0, '2');
    tar_add(&t, "tmpdir/main.plist", pl, strlen(pl));
    tar_add_typed(&t, "tmpdir/sub/", "", 0, '5');
    tar_add(&t, "tmpdir/matrix.dat", m, sizeof m);
    static const unsigned char end[1024];
    put(&t, end, sizeof end);
    const char *p = tu_in_dir("folder_first.inv3");
    write_gz(p, t.b, t.n);
    free(t.b);
    free(pl);
    vol *v = volio_read(p);
    if (!v)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(v->dim[0] * v->dim[1] * v->dim[2], 24);
    for (int i = 0; i < 24; i++)
        assert_true(v->data[i] == (float)(i - 10));
    vol_free(v);
}

/* An .inv3 whose matrix is followed by 1 MiB of another file, as in real projects (surfaces,
 * masks): far more than zlib inflates ahead, so the gzip check at the end is not reached by chance. */
static void write_inv3_with_tail(const char *path, const char *mode)
{
    int16_t m[24];
    for (int i = 0; i < 24; i++)
        m[i] = (int16_t)(i - 10);
    char *pl = plist_text(SHAPE_234, "int16", "1");
    size_t tail_n = 1 << 20;
    char *tail = malloc(tail_n);
    memset(tail, 'x', tail_n);
    buf t = {0};
    tar_add(&t, "tmpdir/main.plist", pl, strlen(pl));
    tar_add(&t, "tmpdir/matrix.dat", m, sizeof m);
    tar_add(&t, "tmpdir/surface_0.vtp", tail, tail_n);
    static const unsigned char end[1024];
    put(&t, end, sizeof end);
    gzFile gz = gzopen(path, mode);
    assert_non_null(gz);
    assert_int_equal(gzwrite(gz, t.b, (unsigned)t.n), (int)t.n);
    assert_int_equal(gzclose(gz), Z_OK);
    free(t.b);
    free(tail);
    free(pl);
}

/* Finds needle in hay; the index of its first byte, or fails the test. */
static size_t find_bytes(const unsigned char *hay, size_t n, const void *needle, size_t len)
{
    for (size_t i = 0; i + len <= n; i++)
        if (!memcmp(hay + i, needle, len))
            return i;
    fail_msg("pattern not found");
    return 0;
}

/* A damaged byte that still inflates (in a stored block, or in the CRC itself) is caught by the
 * gzip check at the stream's end, not read as plausible voxels. */
static void test_inv3_crc_checked(void **st)
{
    const char *p = tu_in_dir("crc.inv3");
    write_inv3_with_tail(p, "wb0"); /* level 0: the voxels lie in the file as they are */
    vol *v = volio_read(p);
    if (!v)
        fail_msg("%s", fn_err_msg()); /* the baseline is fine */
    vol_free(v);
    size_t n;
    unsigned char *b = (unsigned char *)tu_slurp(p, &n);
    const int16_t voxels[3] = {0, 1, 2};
    b[find_bytes(b, n, voxels, sizeof voxels) + 2] ^= 0x40;
    tu_write_file(p, b, n);
    expect_error(p, "corrupt gzip data", "incorrect data check");
    free(b);

    write_inv3_with_tail(p, "wb"); /* compressed: flip a bit of the stored CRC32 */
    b = (unsigned char *)tu_slurp(p, &n);
    b[n - 8] ^= 0x01;
    tu_write_file(p, b, n);
    expect_error(p, "corrupt gzip data", NULL);
    free(b);
}

static void test_inv3_battery(void **st)
{
    const char *p = tu_in_dir("bad.inv3");
    char *pl;

    write_inv3(p, NULL, 0, 48, 1);
    expect_error(p, "no main.plist", NULL);

    write_inv3(p, pl = plist_text("<integer>2</integer><integer>3</integer>", "int16", "1"), 0, 48, 1);
    expect_error(p, "matrix.shape", NULL);
    free(pl);

    write_inv3(p, pl = plist_text("<integer>2</integer><integer>-3</integer><integer>4</integer>", "int16", "1"), 0, 48, 1);
    expect_error(p, "matrix.shape", "dimension");
    free(pl);

    write_inv3(p, pl = plist_text("<integer>100000</integer><integer>100000</integer><integer>100000</integer>",
                                  "int16", "1"), 0, 48, 1);
    expect_error(p, "matrix.shape", "memory budget");
    free(pl);

    write_inv3(p, pl = plist_text("<integer>2</integer><integer>3</integer><integer>5</integer>", "int16", "1"), 0, 48, 1);
    expect_error(p, "matrix.dat is 48 bytes", "needs 60");
    free(pl);

    write_inv3(p, pl = plist_text(SHAPE_234, "complex128", "1"), 0, 48, 1);
    expect_error(p, "matrix.dtype", NULL);
    free(pl);

    write_inv3(p, pl = plist_text(SHAPE_234, "int16", "7"), 0, 48, 1);
    expect_error(p, "orientation", NULL);
    free(pl);

    write_inv3(p, "<plist><dict><key>matrix</key><dict></plist>", 0, 48, 1);
    expect_error(p, "main.plist: offset", NULL);

    write_gz(p, "not a tar archive at all, just text", 35);
    expect_error(p, "truncated", NULL);
    char junk[2048];
    memset(junk, 'x', sizeof junk);
    write_gz(p, junk, sizeof junk);
    expect_error(p, "bad checksum", NULL);
}

static void test_inv3_damaged_archive(void **st)
{
    const char *p = tu_in_dir("damaged.inv3");
    char *pl = plist_text(SHAPE_234, "int16", "1");
    write_inv3(p, pl, 0, 48, 1);
    free(pl);
    size_t n;
    unsigned char *b = (unsigned char *)tu_slurp(p, &n);
    tu_write_file(p, b, n / 2);
    expect_error(p, "truncated", NULL);
    tu_write_file(p, b, 20); /* inside the first deflate block */
    expect_error(p, "truncated", NULL);
    b[3] = 0xE0;
    tu_write_file(p, b, n);
    expect_error(p, "corrupt gzip", NULL);
    free(b);
}

/* ---- NRRD ---- */

static void write_nrrd(const char *path, const char *header, size_t data_bytes)
{
    size_t hl = strlen(header);
    unsigned char *b = calloc(1, hl + data_bytes + 1);
    memcpy(b, header, hl);
    tu_write_file(path, b, hl + data_bytes);
    free(b);
}

#define NRRD_HEAD "NRRD0004\ntype: short\ndimension: 3\nendian: little\nencoding: raw\n"

static void test_nrrd_battery(void **st)
{
    const char *p = tu_in_dir("good.nrrd");
    write_nrrd(p, NRRD_HEAD "sizes: 4 4 4\nspace: left-posterior-superior\n"
                  "space directions: (1,0,0) (0,1,0) (0,0,1)\nspace origin: (0,0,0)\n\n", 128);
    vol *v = volio_read(p);
    assert_non_null(v);
    vol_free(v);

    write_nrrd(p = tu_in_dir("magic.nrrd"), "NRRX0004\ntype: short\ndimension: 3\nsizes: 4 4 4\n\n", 128);
    expect_error(p, "header", NULL);

    write_nrrd(p = tu_in_dir("truncated.nrrd"), NRRD_HEAD "sizes: 4 4 4\n\n", 100);
    expect_error(p, "the data file has 100", NULL);

    write_nrrd(p = tu_in_dir("lying.nrrd"), NRRD_HEAD "sizes: 100000 100000 100000\n\n", 100);
    expect_error(p, "need", "data file has 100");

    write_nrrd(p = tu_in_dir("negative.nrrd"), NRRD_HEAD "sizes: 4 -4 4\n\n", 128);
    expect_error(p, "header", NULL);

    write_nrrd(p = tu_in_dir("4d.nrrd"), "NRRD0004\ntype: short\ndimension: 4\nendian: little\n"
                                      "encoding: raw\nsizes: 2 2 2 2\n\n", 32);
    expect_error(p, "dimension: 4", NULL);

    write_nrrd(p = tu_in_dir("shear.nrrd"), NRRD_HEAD "sizes: 4 4 4\nspace: left-posterior-superior\n"
                                         "space directions: (1,0,0) (0.5,1,0) (0,0,1)\n\n", 128);
    expect_error(p, "space directions", "sheared");

    write_nrrd(p = tu_in_dir("llong.nrrd"), "NRRD0004\ntype: long long\ndimension: 3\nendian: little\n"
                                         "encoding: raw\nsizes: 2 2 2\n\n", 64);
    expect_error(p, "type", "not supported");

    write_nrrd(p = tu_in_dir("missing.nhdr"), NRRD_HEAD "sizes: 4 4 4\ndata file: missing.raw\n", 0);
    expect_error(p, "missing.raw", NULL);

    write_nrrd(p = tu_in_dir("budget.nrrd"), NRRD_HEAD "sizes: 20 20 20\n\n", 16000);
    setenv("FRACNAV_MAX_BYTES", "10000", 1);
    expect_error(p, "memory budget", NULL);
    unsetenv("FRACNAV_MAX_BYTES");
}

/* Random byte damage to small valid files of each format: every read either succeeds or fails
 * with a message naming the file; under ASan this also proves nothing is overrun. */
static void mutate_and_read(const char *path, const unsigned char *orig, size_t n, size_t span, int gz)
{
    unsigned char *b = malloc(n);
    uint32_t seed = 12345;
    for (int round = 0; round < 300; round++) {
        memcpy(b, orig, n);
        for (int k = 0; k < 1 + round % 4; k++) {
            seed = seed * 1664525u + 1013904223u;
            size_t at = (seed >> 8) % span;
            seed = seed * 1664525u + 1013904223u;
            b[at] = round % 3 ? (unsigned char)(seed >> 24) : (unsigned char)(b[at] ^ (1u << (seed % 8)));
        }
        size_t len = round % 7 == 6 ? (seed >> 4) % n : n; /* sometimes truncated too */
        if (gz)
            write_gz(path, b, len);
        else
            tu_write_file(path, b, len);
        fn_err_clear();
        vol *v = volio_read(path);
        if (v)
            vol_free(v);
        else if (!strstr(fn_err_msg(), path))
            fail_msg("round %d: error without the file name: %s", round, fn_err_msg());
    }
    free(b);
}

static void test_mutations(void **st)
{
    setenv("FRACNAV_MAX_BYTES", "1000000", 1);
    nifti_1_header h = good_header(4, 4, 4, DT_INT16, 16);
    unsigned char nii[352 + 128] = {0};
    memcpy(nii, &h, sizeof h);
    mutate_and_read(tu_in_dir("m.nii"), nii, sizeof nii, 352, 0);

    char *pl = plist_text(SHAPE_234, "int16", "1");
    const char *p = tu_in_dir("m.inv3");
    write_inv3(p, pl, 0, 48, 0); /* a plain tar: zlib reads it as is, so the damage hits the parsers */
    free(pl);
    size_t n;
    unsigned char *tar = (unsigned char *)tu_slurp(p, &n);
    mutate_and_read(p, tar, n, 512 + 1024, 0);
    mutate_and_read(p, tar, n, n, 1);
    free(tar);

    const char *head = NRRD_HEAD "sizes: 4 4 4\nspace: left-posterior-superior\n"
                       "space directions: (1,0,0) (0,1,0) (0,0,1)\nspace origin: (0,0,0)\n\n";
    unsigned char nrrd[512] = {0};
    size_t hl = strlen(head);
    memcpy(nrrd, head, hl);
    mutate_and_read(tu_in_dir("m.nrrd"), nrrd, hl + 128, hl, 0);
    unsetenv("FRACNAV_MAX_BYTES");
}

/* ---- hostile input: geometry, encodings and files that get around the memory budget ---- */

/* How much reading path raises the peak RSS (KiB), in a child process so that the test's own
 * history does not hide it; *ok is 1 when the read succeeded. */
static long child_peak_kib(const char *path, int *ok)
{
    int fd[2];
    assert_int_equal(pipe(fd), 0);
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        struct rusage before, after;
        getrusage(RUSAGE_SELF, &before);
        vol *v = volio_read(path);
        getrusage(RUSAGE_SELF, &after);
        long kib = after.ru_maxrss - before.ru_maxrss;
        ssize_t w = write(fd[1], &kib, sizeof kib);
        _exit(v && w == (ssize_t)sizeof kib ? 0 : 1);
    }
    close(fd[1]);
    long kib = -1;
    assert_int_equal(read(fd[0], &kib, sizeof kib), (int)sizeof kib);
    close(fd[0]);
    int status = 0;
    assert_int_equal(waitpid(pid, &status, 0), pid);
    *ok = WIFEXITED(status) && WEXITSTATUS(status) == 0;
    return kib;
}

static void test_nrrd_error_after_open_no_double_free(void **st)
{
    /* teem closes the file on this error; the reader used to fclose it a second time */
    const char *p = tu_in_dir("blocksize.nrrd");
    const char *h = "NRRD0004\ntype: uint8\nblock size: 4\ndimension: 3\nsizes: 2 4 3\nendian: little\n"
                    "encoding: raw\n\n";
    tu_write_file(p, h, strlen(h));
    expect_error(p, "block size: only for type block", NULL);
}

static void test_nrrd_geometry_not_made_up(void **st)
{
    static const struct {
        const char *fields, *w1, *w2;
    } bad[] = {
        {"spacings: nan 1 1\n", "spacings: axis 0 is nan", NULL},
        {"spacings: 1 -1 1\n", "spacings: axis 1 is -1", NULL},
        {"spacings: 1 1 0\n", "axis 2 spacing (0) invalid", NULL}, /* teem's own check */
        {"", "spacings: missing", "no space directions"},
        {"spacings: 1 1 1\naxis mins: 0 nan 0\n", "axis mins: axis 1 is nan", NULL},
        {"space: left-posterior-superior\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n"
         "space origin: (nan,nan,nan)\n", "space origin: component 0 is nan", NULL},
    };
    char head[512];
    const char *p = tu_in_dir("geo.nrrd");
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        snprintf(head, sizeof head, NRRD_HEAD "sizes: 4 4 4\n%s\n", bad[i].fields);
        write_nrrd(p, head, 128);
        expect_error(p, bad[i].w1, bad[i].w2);
    }
    /* What is there is used; an absent origin is 0, as ITK and Slicer read it. */
    write_nrrd(p, NRRD_HEAD "sizes: 4 4 4\nspacings: 0.5 1 2\naxis mins: 1 2 3\n\n", 128);
    vol *v = volio_read(p);
    assert_non_null(v);
    assert_true(v->spacing[0] == 0.5 && v->spacing[2] == 2 && v->affine[1][3] == 2);
    vol_free(v);
    write_nrrd(p, NRRD_HEAD "sizes: 4 4 4\nspace: left-posterior-superior\n"
                  "space directions: (1,0,0) (0,1,0) (0,0,3)\n\n", 128);
    v = volio_read(p);
    assert_non_null(v);
    assert_true(v->spacing[2] == 3 && v->affine[0][3] == 0);
    vol_free(v);
}

static void test_nifti_geometry_not_made_up(void **st)
{
    const char *p = tu_in_dir("geo.nii");
    nifti_1_header h;
    /* no sform, no qform: pixdim gives the spacing and must be a positive number */
    const float bad_pixdim[] = {NAN, INFINITY, 0, -1};
    for (int i = 0; i < 4; i++) {
        h = good_header(4, 4, 4, DT_INT16, 16);
        h.sform_code = 0;
        h.pixdim[1 + i % 3] = bad_pixdim[i];
        write_nii(p, &h, 128, 0);
        char want[64];
        snprintf(want, sizeof want, "pixdim[%d] is %g", 1 + i % 3, bad_pixdim[i]);
        expect_error(p, want, "no sform or qform");
    }
    /* qform: the quaternion, offsets, pixdim and qfac */
    h = good_header(4, 4, 4, DT_INT16, 16);
    h.sform_code = 0;
    h.qform_code = 1;
    h.quatern_b = NAN;
    write_nii(p, &h, 128, 0);
    expect_error(p, "qform: quatern_b is nan", NULL);
    h.quatern_b = 0;
    h.qoffset_y = -INFINITY;
    write_nii(p, &h, 128, 0);
    expect_error(p, "qform: qoffset_y is -inf", NULL);
    h.qoffset_y = 0;
    h.pixdim[2] = 0;
    write_nii(p, &h, 128, 0);
    expect_error(p, "qform: pixdim[2] is 0", NULL);
    h.pixdim[2] = 1;
    h.pixdim[0] = NAN;
    write_nii(p, &h, 128, 0);
    expect_error(p, "pixdim[0] (qfac) is nan", NULL);
    h.pixdim[0] = 0; /* the standard: qfac 0 is taken as 1 */
    h.pixdim[3] = 2.5f;
    write_nii(p, &h, 128, 0);
    vol *v = volio_read(p);
    assert_non_null(v);
    assert_true(v->spacing[2] == 2.5 && v->affine[2][2] == 2.5);
    vol_free(v);
    /* sform */
    h = good_header(4, 4, 4, DT_INT16, 16);
    h.srow_y[3] = NAN;
    write_nii(p, &h, 128, 0);
    expect_error(p, "sform: srow_y[3] is nan", NULL);
}

#define FLOAT_HEAD(sizes, enc) "NRRD0004\ntype: float\ndimension: 3\nsizes: " sizes "\nspacings: 1 1 1\n" \
                               "endian: little\nencoding: " enc "\n\n"

/* Text encodings need 2 characters a voxel at least (hex: 2 a byte); a gzip stream must really
 * inflate to the data (trailing junk is not data). Each is refused before a voxel is allocated. */
static void test_nrrd_encodings_hold_what_they_claim(void **st)
{
    const char *p = tu_in_dir("enc.nrrd");
    write_nrrd(p, FLOAT_HEAD("100 100 100", "ascii") "0 1 2 3\n", 0);
    expect_error(p, "need 1999999 data bytes (ASCII)", "has 8");
    write_nrrd(p, FLOAT_HEAD("1000 1000 1000", "ascii") "0 1 2 3\n", 0);
    expect_error(p, "need 1999999999 data bytes (ASCII)", NULL);
    write_nrrd(p, FLOAT_HEAD("1000 1000 1000", "hex") "00000000\n", 0);
    expect_error(p, "need 8000000000 data bytes (hex)", NULL);
    write_nrrd(p, FLOAT_HEAD("2 2 1", "ascii") "0 1.5 2 -3\n", 0);
    vol *v = volio_read(p);
    assert_non_null(v);
    assert_true(v->data[1] == 1.5f && v->data[3] == -3);
    vol_free(v);

    /* gzip: two members are read as one stream; junk after the data is not data */
    float data[1000];
    for (int i = 0; i < 1000; i++)
        data[i] = (float)i;
    const char *head = FLOAT_HEAD("10 10 10", "gzip");
    write_nrrd(p, head, 0);
    for (int half = 0; half < 2; half++) {
        gzFile gz = gzopen(p, "ab");
        assert_int_equal(gzwrite(gz, data + 500 * half, 2000), 2000);
        assert_int_equal(gzclose(gz), Z_OK);
    }
    v = volio_read(p);
    if (!v)
        fail_msg("two gzip members: %s", fn_err_msg());
    assert_true(v->data[999] == 999);
    vol_free(v);
    write_nrrd(p, FLOAT_HEAD("100 100 100", "gzip"), 0);
    gzFile gz = gzopen(p, "ab");
    assert_int_equal(gzwrite(gz, data, 1000), 1000);
    assert_int_equal(gzclose(gz), Z_OK);
    FILE *f = fopen(p, "ab");
    for (int i = 0; i < 8192; i++)
        fputc((i * 7919) & 0xff, f);
    fclose(f);
    expect_error(p, "need 4000000 data bytes (gzip)", "inflate to 1000");
    write_nrrd(p, FLOAT_HEAD("1000 1000 1000", "gzip"), 100);
    expect_error(p, "need 4000000000 data bytes (gzip)", "can inflate to at most 103200");

    write_nrrd(p, "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nspacings: 1 1 1\nendian: little\n"
                  "encoding: gzip\nbyte skip: -1\n\n", 64);
    expect_error(p, "byte skip", "raw");
    write_nrrd(p, FLOAT_HEAD("2 2 2", "bzip2"), 64);
    expect_error(p, "encoding", "not supported");
}

/* volio_read_labels must fail with a message holding the path and the words. */
static void expect_labels_error(const char *path, const char *w1, const char *w2)
{
    volio_segs segs;
    fn_err_clear();
    vol *v = volio_read_labels(path, &segs);
    if (v) {
        vol_free(v);
        volio_segs_free(&segs);
        fail_msg("%s was read, expected an error about '%s'", path, w1);
    }
    assert_int_equal(segs.segments, 0);
    assert_null(segs.overlap);
    const char *m = fn_err_msg();
    if (!strstr(m, path) || !strstr(m, w1) || (w2 && !strstr(m, w2)))
        fail_msg("error for %s lacks '%s'/'%s': %s", path, w1, w2 ? w2 : "", m);
}

#define SEG4_HEAD(type, sizes, enc) "NRRD0004\ntype: " type "\ndimension: 4\nsizes: " sizes "\n" \
    "spacings: nan 1 1 1\nkinds: list domain domain domain\nendian: little\nencoding: " enc "\n"      \
    "Segment0_LabelValue:=1\nSegment0_Layer:=0\nSegment1_LabelValue:=1\nSegment1_Layer:=1\n\n"

/* A multi-layer .seg.nrrd is checked as a 3D NRRD is, over all its layers, before its data is
 * read: the data file's size, what gzip really inflates to and the memory budget (the file's
 * values and the float volume, held at once); its layer axis must be one. */
static void test_seg_nrrd_checked_before_reading(void **st)
{
    const char *p = tu_in_dir("layers.seg.nrrd");
    write_nrrd(p, SEG4_HEAD("unsigned short", "2 20 20 20", "raw"), 32000);
    volio_segs segs;
    vol *v = volio_read_labels(p, &segs);
    if (!v)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(segs.segments, 2);
    assert_int_equal(segs.layers, 2);
    assert_true(v->dim[0] == 20 && v->dim[2] == 20 && v->spacing[0] == 1);
    vol_free(v);
    volio_segs_free(&segs);
    /* 8000 voxels of 2 u16 values and a float: 64000 bytes; one layer would need 48000 */
    setenv("FRACNAV_MAX_BYTES", "50000", 1);
    expect_labels_error(p, "memory budget", NULL);
    write_nrrd(p, "NRRD0004\ntype: unsigned short\ndimension: 3\nsizes: 20 20 20\nspacings: 1 1 1\n"
                  "endian: little\nencoding: raw\nSegment0_LabelValue:=1\n\n", 16000);
    v = volio_read_labels(p, &segs);
    if (!v)
        fail_msg("%s", fn_err_msg());
    vol_free(v);
    volio_segs_free(&segs);
    unsetenv("FRACNAV_MAX_BYTES");

    write_nrrd(p, SEG4_HEAD("unsigned short", "2 20 20 20", "raw"), 16000);
    expect_labels_error(p, "sizes 20 20 20 in 2 layers of uint16 need 32000 data bytes (raw)", "has 16000");
    write_nrrd(p, SEG4_HEAD("unsigned char", "3 1000 1000 1000", "gzip"), 100);
    expect_labels_error(p, "need 3000000000 data bytes (gzip)", "can inflate to at most 103200");
    unsigned char noise[4000]; /* hardly compressible: passes the cheap ratio check */
    for (int i = 0; i < 4000; i++)
        noise[i] = (unsigned char)((i * 7919 + (i >> 3) * 104729) >> 3);
    write_nrrd(p, SEG4_HEAD("unsigned char", "2 30 30 30", "gzip"), 0);
    gzFile gz = gzopen(p, "ab");
    assert_int_equal(gzwrite(gz, noise, sizeof noise), (int)sizeof noise);
    assert_int_equal(gzclose(gz), Z_OK);
    expect_labels_error(p, "need 54000 data bytes (gzip)", "gzip data inflate to 4000");
    write_nrrd(p, SEG4_HEAD("unsigned char", "70000 2 2 2", "raw"), 560000);
    expect_labels_error(p, "70000 layers", NULL);
    write_nrrd(p, "NRRD0004\ntype: unsigned char\ndimension: 4\nsizes: 2 2 2 2\nspacings: 1 1 1 1\n"
                  "kinds: domain domain domain domain\nencoding: raw\nSegment0_LabelValue:=1\n"
                  "Segment0_Layer:=0\n\n", 16);
    expect_labels_error(p, "kinds: axis 0 is domain", NULL);
    write_nrrd(p, "NRRD0004\ntype: unsigned char\ndimension: 4\nsizes: 2 2 2 2\nspacings: 1 1 1 1\n"
                  "encoding: raw\nSegment0_LabelValue:=0\nSegment0_Layer:=0\n\n", 16);
    expect_labels_error(p, "Segment0_LabelValue: '0' is not a whole number >= 1", NULL);
    write_nrrd(p, "NRRD0004\ntype: unsigned char\ndimension: 4\nsizes: 2 2 2 2\nspacings: 1 1 1 1\n"
                  "encoding: raw\nSegment0_LabelValue:=1\nSegment0_Layer:=0\nSegment123456_Layer:=0\n\n", 16);
    expect_labels_error(p, "line 9: Segment123456_Layer:=0: over 256 segments", NULL);
    /* volio_read still reads 3D only */
    write_nrrd(p, SEG4_HEAD("unsigned char", "2 2 2 2", "raw"), 16);
    expect_error(p, "dimension: 4, only 3D volumes are supported", NULL);
}

/* Only regular files are read: a FIFO would block the open, /dev/zero never ends. */
static void test_only_regular_files(void **st)
{
    const char *p = tu_in_dir("zero.nii");
    assert_int_equal(symlink("/dev/zero", p), 0);
    expect_error(p, "not a regular file", NULL);
    p = tu_in_dir("fifo.nrrd");
    assert_int_equal(mkfifo(p, 0600), 0);
    expect_error(p, "not a regular file", NULL);
    p = tu_in_dir("zero.nhdr");
    write_nrrd(p, NRRD_HEAD "sizes: 4 4 4\nspacings: 1 1 1\ndata file: /dev/zero\n", 0);
    expect_error(p, "data file", "not a regular file");
    assert_int_equal(mkfifo(tu_in_dir("fifo.raw"), 0600), 0);
    p = tu_in_dir("fifo.nhdr");
    write_nrrd(p, NRRD_HEAD "sizes: 4 4 4\nspacings: 1 1 1\ndata file: fifo.raw\n", 0);
    expect_error(p, "data file", "fifo.raw is not a regular file");
    /* a link to a regular file is fine */
    nifti_1_header h = good_header(4, 4, 4, DT_INT16, 16);
    char real[4300];
    snprintf(real, sizeof real, "%s", tu_in_dir("real.nii"));
    write_nii(real, &h, 128, 0);
    assert_int_equal(symlink(real, p = tu_in_dir("link.nii")), 0);
    vol *v = volio_read(p);
    assert_non_null(v);
    vol_free(v);
}

/* A 48 MiB header extension (a few dozen KB of .nii.gz) is skipped, never read into memory; one
 * over 64 MiB in a .nii.gz is refused from the header alone (skipping it would inflate it all). */
static void test_nifti_extension_not_read(void **st)
{
    const size_t ext = (size_t)48 << 20;
    nifti_1_header h = good_header(4, 4, 4, DT_INT16, 16);
    h.vox_offset = (float)(352 + ext);
    const char *p = tu_in_dir("ext.nii.gz");
    gzFile gz = gzopen(p, "wb1");
    assert_non_null(gz);
    unsigned char chunk[1 << 16] = {0};
    int32_t esize = (int32_t)ext, ecode = 4; /* one extension filling the space before the data */
    assert_int_equal(gzwrite(gz, &h, sizeof h), (int)sizeof h);
    chunk[0] = 1;
    assert_int_equal(gzwrite(gz, chunk, 4), 4);
    chunk[0] = 0;
    assert_int_equal(gzwrite(gz, &esize, 4), 4);
    assert_int_equal(gzwrite(gz, &ecode, 4), 4);
    for (size_t done = 8; done < ext; done += sizeof chunk)
        assert_true(gzwrite(gz, chunk, (unsigned)(ext - done < sizeof chunk ? ext - done : sizeof chunk)) > 0);
    assert_int_equal(gzwrite(gz, chunk, 128), 128);
    assert_int_equal(gzclose(gz), Z_OK);
    int ok = 0;
    long kib = child_peak_kib(p, &ok);
    assert_true(ok);
    if (kib > 32 * 1024)
        fail_msg("reading %s peaked at %ld KiB", p, kib);
    h.vox_offset = (float)(100 << 20);
    write_nii(p, &h, 128, 1);
    expect_error(p, "vox_offset is 104857600: header extensions over 64 MiB", NULL);
}

/* The number of tar entries is bounded: each one read before main.plist used to cost 4 KiB
 * (70,000 of them, 434 KB of .inv3, took 266 MB). A project with many files still reads. */
static void test_inv3_entries_bounded(void **st)
{
    char *pl = plist_text(SHAPE_234, "int16", "1");
    int16_t m[24] = {0};
    for (int many = 0; many < 2; many++) {
        buf t = {0};
        char name[64];
        for (int i = 0; i < (many ? 5000 : 300); i++) {
            snprintf(name, sizeof name, "tmpdir/surface_%d.vtp", i);
            tar_add(&t, name, "x", 1);
        }
        tar_add(&t, "tmpdir/matrix.dat", m, sizeof m);
        tar_add(&t, "tmpdir/main.plist", pl, strlen(pl));
        static const unsigned char end[1024];
        put(&t, end, sizeof end);
        const char *p = tu_in_dir("many.inv3");
        write_gz(p, t.b, t.n);
        free(t.b);
        if (many) {
            expect_error(p, "more than 4096 entries", NULL);
        } else {
            vol *v = volio_read(p);
            if (!v)
                fail_msg("300 files: %s", fn_err_msg());
            vol_free(v);
        }
    }
    free(pl);
}

/* What the NIfTI-1 standard forbids is refused by name, never read as something else: nifticlib
 * reads a NaN scl_slope or an infinite scl_inter as 0 (unscaled voxels), and a vox_offset of
 * 349.5 read the voxels shifted. */
static void test_nifti_scaling_and_offset_refused(void **st)
{
    const char *p = tu_in_dir("scl.nii");
    nifti_1_header h = good_header(4, 4, 4, DT_INT16, 16);
    h.scl_slope = NAN;
    write_nii(p, &h, 128, 0);
    expect_error(p, "scl_slope is nan", NULL);
    h.scl_slope = 2;
    h.scl_inter = INFINITY;
    write_nii(p, &h, 128, 0);
    expect_error(p, "scl_inter is inf", NULL);
    h.scl_slope = 0; /* no scaling: the intercept is unused */
    write_nii(p, &h, 128, 0);
    vol *v = volio_read(p);
    if (!v)
        fail_msg("%s", fn_err_msg());
    vol_free(v);
    h.scl_slope = 2;
    h.scl_inter = 10;
    write_nii(p, &h, 128, 0);
    v = volio_read(p);
    if (!v)
        fail_msg("%s", fn_err_msg());
    int16_t first = (int16_t)((352 * 37 & 0xff) | (353 * 37 & 0xff) << 8);
    assert_true(v->data[0] == 2.0f * first + 10);
    vol_free(v);
    h = good_header(4, 4, 4, DT_INT16, 16);
    h.vox_offset = 349.5f;
    write_nii(p, &h, 128, 0);
    expect_error(p, "vox_offset is 349.5, must be a whole number of bytes", NULL);
}

/* Spacings outside a micron to a metre are refused at read time, naming the field: at 1e15 mm
 * reduce's contact search never finished. */
static void test_spacing_physical_range(void **st)
{
    const char *p = tu_in_dir("huge.nrrd");
    write_nrrd(p, NRRD_HEAD "sizes: 4 4 4\nspacings: 1 1e15 1\n\n", 128);
    expect_error(p, "spacings: axis 1 is 1e+15 mm, outside a micron to a metre", NULL);
    write_nrrd(p, NRRD_HEAD "sizes: 4 4 4\nspacings: 1 1 0.0001\n\n", 128);
    expect_error(p, "spacings: axis 2 is 0.0001 mm", NULL);
    write_nrrd(p, NRRD_HEAD "sizes: 4 4 4\nspace: left-posterior-superior\n"
                  "space directions: (1e15,0,0) (0,1,0) (0,0,1)\n\n", 128);
    expect_error(p, "space directions: axis 0 is 1e+15 mm", NULL);
    write_nrrd(p, NRRD_HEAD "sizes: 4 4 4\nspacings: 0.001 1000 0.5\n\n", 128);
    vol *v = volio_read(p);
    if (!v)
        fail_msg("a micron and a metre are in range: %s", fn_err_msg());
    vol_free(v);
    p = tu_in_dir("huge.nii");
    nifti_1_header h = good_header(4, 4, 4, DT_INT16, 16);
    h.sform_code = 0;
    h.pixdim[3] = 1e15f;
    write_nii(p, &h, 128, 0);
    expect_error(p, "pixdim", "axis 2 is 1e+15 mm");
    h = good_header(4, 4, 4, DT_INT16, 16);
    h.srow_x[0] = 2e3f;
    write_nii(p, &h, 128, 0);
    expect_error(p, "sform", "axis 0 is 2000 mm");
}

/* info on a volume whose every voxel is NaN has no range: it says so (null in --json). */
static void test_info_all_nan(void **st)
{
    const char *p = tu_in_dir("nan.nrrd");
    float nan[8];
    for (int i = 0; i < 8; i++)
        nan[i] = NAN;
    const char *head = "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nspacings: 1 1 1\n"
                       "endian: little\nencoding: raw\n\n";
    unsigned char b[256];
    memcpy(b, head, strlen(head));
    memcpy(b + strlen(head), nan, sizeof nan);
    tu_write_file(p, b, strlen(head) + sizeof nan);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "info '%s'", p), 0);
    if (!strstr(out, "range:       none (every voxel is NaN)") || strstr(out, "inf"))
        fail_msg("got: %s", out);
    free(out);
    out = NULL;
    assert_int_equal(tu_run_cli(&out, "info '%s' --json", p), 0);
    if (!strstr(out, "\"range\": null"))
        fail_msg("got: %s", out);
    free(out);
}

static void test_cli_reports_bad_file(void **st)
{
    const char *p = tu_in_dir("cli.nii");
    nifti_1_header h = good_header(4, 4, 4, DT_INT16, 16);
    memcpy(h.magic, "xyz", 4);
    write_nii(p, &h, 128, 0);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "info '%s'", p), 1);
    char want[4400];
    snprintf(want, sizeof want, "fracnav info: %s: magic", p);
    if (!strstr(out, want))
        fail_msg("got: %s", out);
    free(out);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_nifti_battery),
        cmocka_unit_test(test_nifti_budget),
        cmocka_unit_test(test_nifti_corrupt_gzip),
        cmocka_unit_test(test_inv3_small_project),
        cmocka_unit_test(test_inv3_battery),
        cmocka_unit_test(test_inv3_folder_and_link_entries),
        cmocka_unit_test(test_inv3_crc_checked),
        cmocka_unit_test(test_inv3_damaged_archive),
        cmocka_unit_test(test_nrrd_battery),
        cmocka_unit_test(test_mutations),
        cmocka_unit_test(test_nrrd_error_after_open_no_double_free),
        cmocka_unit_test(test_nrrd_geometry_not_made_up),
        cmocka_unit_test(test_nifti_geometry_not_made_up),
        cmocka_unit_test(test_nrrd_encodings_hold_what_they_claim),
        cmocka_unit_test(test_seg_nrrd_checked_before_reading),
        cmocka_unit_test(test_only_regular_files),
        cmocka_unit_test(test_nifti_extension_not_read),
        cmocka_unit_test(test_inv3_entries_bounded),
        cmocka_unit_test(test_nifti_scaling_and_offset_refused),
        cmocka_unit_test(test_spacing_physical_range),
        cmocka_unit_test(test_info_all_nan),
        cmocka_unit_test(test_cli_reports_bad_file),
    };
    return cmocka_run_group_tests(tests, tu_dir_setup, tu_dir_teardown);
}
