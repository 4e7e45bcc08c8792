/* volio_nifti: NIfTI-1 (.nii, .nii.gz) through nifticlib. The header is checked here byte by byte
 * first, so that bad files get an error naming the field and nifticlib never allocates for a
 * header that lies. */
#include "volio_impl.h"

#include "err.h"
#include "platform.h"

#include <errno.h>
#include <math.h>
#include <nifti1_io.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <zlib.h>

#define HDR_SIZE 348
#define DEFLATE_MAX_RATIO 1032 /* zlib's best case: no .gz can hold more than this per byte */
#define EXT_MAX_GZ (64 << 20)  /* header extensions are skipped, but in a .gz only by inflating */

static const struct {
    int dt;
    vol_type type;
} types[] = {{DT_UINT8, VOL_U8},   {DT_INT8, VOL_I8},   {DT_UINT16, VOL_U16},   {DT_INT16, VOL_I16},
             {DT_UINT32, VOL_U32}, {DT_INT32, VOL_I32}, {DT_FLOAT32, VOL_F32}, {DT_FLOAT64, VOL_F64}};

static int type_of_dt(int dt, vol_type *t)
{
    for (size_t i = 0; i < sizeof types / sizeof types[0]; i++)
        if (types[i].dt == dt) {
            *t = types[i].type;
            return 0;
        }
    return -1;
}

static int dt_of_type(vol_type t)
{
    for (size_t i = 0; i < sizeof types / sizeof types[0]; i++)
        if (types[i].type == t)
            return types[i].dt;
    return DT_UNKNOWN;
}

static int32_t get32(const unsigned char *p, int swap)
{
    uint32_t u = swap ? (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | p[3]
                      : (uint32_t)p[3] << 24 | (uint32_t)p[2] << 16 | (uint32_t)p[1] << 8 | p[0];
    return (int32_t)u;
}

static int16_t get16(const unsigned char *p, int swap)
{
    return (int16_t)(swap ? (uint16_t)(p[0] << 8 | p[1]) : (uint16_t)(p[1] << 8 | p[0]));
}

/* Checks the raw header bytes: size, magic, dims, datatype; fills dim[1..3] and the needed data bytes. */
static int check_header(const unsigned char *h, size_t n, const char *path, int64_t dim[3], uint64_t *bytes,
                        uint64_t *vox_offset)
{
    if (n < HDR_SIZE)
        return fn_err_set(FN_EFORMAT, "%s: header truncated: %zu of %d bytes", path, n, HDR_SIZE);
    int swap = get32(h, 0) != HDR_SIZE;
    int32_t size = get32(h, swap);
    if (size == 540 || get32(h, !swap) == 540)
        return fn_err_set(FN_EFORMAT, "%s: sizeof_hdr: NIfTI-2 is not supported, save as NIfTI-1", path);
    if (size != HDR_SIZE)
        return fn_err_set(FN_EFORMAT, "%s: sizeof_hdr is %d, not 348 (not a NIfTI-1 file)", path, (int)get32(h, 0));
    if (memcmp(h + 344, "n+1", 4) != 0)
        return fn_err_set(FN_EFORMAT, "%s: magic is not \"n+1\" (a .hdr/.img pair or not NIfTI)", path);
    int ndim = get16(h + 40, swap);
    if (ndim < 1 || ndim > 7)
        return fn_err_set(FN_EFORMAT, "%s: dim[0] = %d, must be 1..7", path, ndim);
    for (int a = 1; a <= 7; a++) {
        int d = a <= ndim ? get16(h + 40 + 2 * a, swap) : 1;
        if (d < 1)
            return fn_err_set(FN_EFORMAT, "%s: dim[%d] = %d, must be positive", path, a, d);
        if (a > 3 && d != 1)
            return fn_err_set(FN_EFORMAT, "%s: dim[%d] = %d: only 3D volumes are supported", path, a, d);
        if (a <= 3)
            dim[a - 1] = d;
    }
    vol_type t;
    int dt = get16(h + 70, swap);
    if (type_of_dt(dt, &t) < 0)
        return fn_err_set(FN_EFORMAT, "%s: datatype %d (%s) is not supported (u8 i8 u16 i16 u32 i32 f32 f64)",
                          path, dt, nifti_datatype_string(dt));
    union { int32_t i; float f; } off = {get32(h + 108, swap)};
    if (!(off.f >= HDR_SIZE))
        return fn_err_set(FN_EFORMAT, "%s: vox_offset is %g, must be at least 348", path, off.f);
    if (off.f > 1e9)
        return fn_err_set(FN_EFORMAT, "%s: vox_offset is %g, too large: the data would start beyond "
                                      "the end of the file (over 1e9 bytes in)", path, off.f);
    if (off.f != floorf(off.f))
        return fn_err_set(FN_EFORMAT, "%s: vox_offset is %g, must be a whole number of bytes", path, off.f);
    *vox_offset = (uint64_t)off.f;
    *bytes = (uint64_t)dim[0] * (uint64_t)dim[1] * (uint64_t)dim[2] * volio__type_size(t);
    return 0;
}

static float getf(const unsigned char *h, size_t off, int swap)
{
    union { int32_t i; float f; } u = {get32(h + off, swap)};
    return u.f;
}

#define FIELD(f) offsetof(nifti_1_header, f)

/* 0 if every float of n starting at off is finite, else the index of the first bad one + 1. */
static int first_bad(const unsigned char *h, size_t off, int n, int swap, float *bad)
{
    for (int i = 0; i < n; i++) {
        *bad = getf(h, off + 4 * (size_t)i, swap);
        if (!isfinite(*bad))
            return i + 1;
    }
    return 0;
}

/* The fields the geometry will come from (sform if sform_code > 0, else qform if qform_code > 0,
 * else pixdim) must be usable: nifticlib would silently turn a NaN quaternion into identity and a
 * NaN, infinite, zero or negative pixdim into 1 mm. The only fallback kept is the standard's own:
 * qfac (pixdim[0]) 0 is taken as 1, with a warning. */
static int check_geometry_fields(const unsigned char *h, const char *path)
{
    int swap = get32(h, 0) != HDR_SIZE, i;
    float bad;
    if (get16(h + FIELD(sform_code), swap) > 0) {
        static const char *row[] = {"srow_x", "srow_y", "srow_z"};
        for (int r = 0; r < 3; r++)
            if ((i = first_bad(h, FIELD(srow_x) + 16 * (size_t)r, 4, swap, &bad)))
                return fn_err_set(FN_EFORMAT, "%s: sform: %s[%d] is %g, must be finite", path, row[r],
                                  i - 1, bad);
        return 0;
    }
    int qform = get16(h + FIELD(qform_code), swap) > 0;
    if (qform) {
        static const char *q[] = {"quatern_b", "quatern_c", "quatern_d", "qoffset_x", "qoffset_y",
                                  "qoffset_z"};
        if ((i = first_bad(h, FIELD(quatern_b), 6, swap, &bad)))
            return fn_err_set(FN_EFORMAT, "%s: qform: %s is %g, must be finite", path, q[i - 1], bad);
        float qfac = getf(h, FIELD(pixdim), swap);
        if (!isfinite(qfac))
            return fn_err_set(FN_EFORMAT, "%s: qform: pixdim[0] (qfac) is %g, must be 1 or -1", path, qfac);
        if (qfac == 0)
            fprintf(stderr, "fracnav: warning: %s: pixdim[0] (qfac) is 0, taken as 1 as the NIfTI-1 "
                            "standard says\n", path);
    }
    for (int a = 1; a <= 3; a++) {
        float d = getf(h, FIELD(pixdim) + 4 * (size_t)a, swap);
        if (!(isfinite(d) && d > 0))
            return fn_err_set(FN_EFORMAT, "%s: %s: pixdim[%d] is %g, must be a positive number of mm",
                              path, qform ? "qform" : "pixdim (no sform or qform)", a, d);
    }
    return 0;
}

/* nifticlib reads a non-finite scl_slope or scl_inter as 0 (no scaling): the voxels would be read
 * unscaled without a word. A slope of 0 means no scaling, and then the intercept is unused. */
static int check_scaling(const unsigned char *h, const char *path)
{
    int swap = get32(h, 0) != HDR_SIZE;
    float slope = getf(h, FIELD(scl_slope), swap), inter = getf(h, FIELD(scl_inter), swap);
    if (!isfinite(slope))
        return fn_err_set(FN_EFORMAT, "%s: scl_slope is %g, must be finite (0: no scaling)", path, slope);
    if (slope != 0 && !isfinite(inter))
        return fn_err_set(FN_EFORMAT, "%s: scl_inter is %g, must be finite", path, inter);
    return 0;
}

/* Reads the header (through zlib, so .nii and .nii.gz alike) into h and checks it against the
 * file's size and the memory budget. */
static int precheck(const char *path, unsigned char h[HDR_SIZE])
{
    struct stat st;
    gzFile gz = gzopen(path, "rb");
    if (!gz || stat(path, &st) != 0) {
        if (gz)
            gzclose(gz);
        return fn_err_set(FN_EIO, "%s: cannot open: %s", path, strerror(errno ? errno : EIO));
    }
    int got = gzread(gz, h, HDR_SIZE);
    int zerr = Z_OK;
    const char *zmsg = gzerror(gz, &zerr);
    int direct = gzdirect(gz);
    int rc = got < 0 ? fn_err_set(FN_EFORMAT, "%s: header: corrupt gzip data: %s", path, zmsg) : 0;
    gzclose(gz);
    int64_t dim[3];
    uint64_t bytes = 0, off = 0;
    if (rc < 0 || (rc = check_header(h, (size_t)got, path, dim, &bytes, &off)) < 0 ||
        (rc = check_geometry_fields(h, path)) < 0 || (rc = check_scaling(h, path)) < 0)
        return rc;
    if (!direct && off > HDR_SIZE + EXT_MAX_GZ)
        return fn_err_set(FN_EFORMAT, "%s: vox_offset is %llu: header extensions over %d MiB in a .nii.gz "
                          "are not supported (all of it would be inflated to reach the data)", path,
                          (unsigned long long)off, EXT_MAX_GZ >> 20);
    uint64_t have = (uint64_t)st.st_size;
    if (direct && have < off + bytes)
        return fn_err_set(FN_EFORMAT, "%s: data truncated: dim %lldx%lldx%lld needs %llu bytes from "
                          "vox_offset %llu, the file has %llu", path, (long long)dim[0], (long long)dim[1],
                          (long long)dim[2], (unsigned long long)bytes, (unsigned long long)off,
                          (unsigned long long)(have > off ? have - off : 0));
    if (!direct && have < (off + bytes) / DEFLATE_MAX_RATIO)
        return fn_err_set(FN_EFORMAT, "%s: dim %lldx%lldx%lld needs %llu bytes, more than a %llu-byte "
                          ".gz can hold", path, (long long)dim[0], (long long)dim[1], (long long)dim[2],
                          (unsigned long long)bytes, (unsigned long long)have);
    char what[4200];
    snprintf(what, sizeof what, "%s: dim", path);
    return vol_check_dims(dim, sizeof(float) + (size_t)(bytes / ((uint64_t)dim[0] * dim[1] * dim[2])), what);
}

/* The index-to-RAS matrix nifticlib derived (sform if coded, else qform, else pixdim) in LPS. */
static int geometry(const nifti_image *nim, const char *path, vol *v)
{
    const char *field = nim->sform_code > 0 ? "sform" : nim->qform_code > 0 ? "qform" : "pixdim";
    const mat44 *m = nim->sform_code > 0 ? &nim->sto_xyz : &nim->qto_xyz;
    double a[3][3], org[3];
    for (int r = 0; r < 3; r++) {
        double s = r < 2 ? -1.0 : 1.0; /* RAS -> LPS */
        for (int c = 0; c < 3; c++)
            a[r][c] = s * m->m[r][c];
        org[r] = s * m->m[r][3];
        if (!isfinite(org[r]))
            return fn_err_set(FN_EFORMAT, "%s: %s: offset is not finite", path, field);
    }
    return volio__set_affine(v, a, org, path, field);
}

/* Reads the voxels through zlib (nifticlib zero-fills short data silently), swapping to host
 * order and applying scl_slope/scl_inter. */
static int load_data(const nifti_image *nim, const char *path, vol_type t, vol *v)
{
    size_t es = volio__type_size(t), n = vol_count(v);
    int swap = nim->byteorder != nifti_short_order() && es > 1;
    double slope = nim->scl_slope, inter = nim->scl_inter;
    if (slope == 0) { /* non-finite values were refused with the header */
        slope = 1;
        inter = 0;
    }
    gzFile gz = gzopen(path, "rb");
    if (!gz)
        return fn_err_set(FN_EIO, "%s: cannot open: %s", path, strerror(errno ? errno : ENOMEM));
    platform_huge_pages(v->data, n * sizeof(float));
    gzbuffer(gz, 1 << 17);
    _Alignas(8) unsigned char buf[1 << 16];
    int rc = gzseek(gz, nim->iname_offset, SEEK_SET) == nim->iname_offset
                 ? 0
                 : fn_err_set(FN_EFORMAT, "%s: data truncated before vox_offset %d", path, nim->iname_offset);
    for (size_t done = 0; rc == 0 && done < n;) {
        size_t m = n - done < sizeof buf / es ? n - done : sizeof buf / es;
        if (gzread(gz, buf, (unsigned)(m * es)) != (int)(m * es)) {
            int zerr = Z_OK;
            const char *zmsg = gzerror(gz, &zerr);
            rc = zerr != Z_OK && zerr != Z_BUF_ERROR
                     ? fn_err_set(FN_EFORMAT, "%s: data: corrupt gzip data near voxel %zu: %s", path, done, zmsg)
                     : fn_err_set(FN_EFORMAT, "%s: data truncated: %dx%dx%d %s from vox_offset %d, "
                                  "the data ends before voxel %zu", path, v->dim[0], v->dim[1], v->dim[2],
                                  vol_type_name(t), nim->iname_offset, done + m);
            break;
        }
        if (swap)
            nifti_swap_Nbytes(m, (int)es, buf);
        volio__to_float(buf, t, m, slope, inter, v->data + done);
        done += m;
    }
    gzclose(gz);
    return rc;
}

vol *volio__read_nifti(const char *path)
{
    nifti_set_debug_level(0);
    nifti_1_header hdr;
    if (precheck(path, (unsigned char *)&hdr) < 0)
        return NULL;
    /* From the checked header, not nifti_image_read: that one also reads the header extensions
     * whole, whatever size they claim (1 GB in a 1 MB .nii.gz); they are not used here. */
    nifti_image *nim = nifti_convert_nhdr2nim(hdr, path);
    if (!nim) {
        fn_err_set(FN_EFORMAT, "%s: header: nifticlib refused it (inconsistent fields)", path);
        return NULL;
    }
    vol_type t = VOL_F32;
    type_of_dt(nim->datatype, &t);
    /* Axes beyond dim[0] are 1 (some writers leave them 0, which nifticlib keeps). */
    vol *v = vol_new(nim->nx, nim->ndim >= 2 ? nim->ny : 1, nim->ndim >= 3 ? nim->nz : 1);
    if (!v)
        fn_err_wrap(FN_EFORMAT, "%s: dim", path);
    if (!v || geometry(nim, path, v) < 0 || load_data(nim, path, t, v) < 0) {
        vol_free(v);
        v = NULL;
    } else {
        v->src_type = t;
    }
    nifti_image_free(nim);
    return v;
}

/* sform and qform from the volume's LPS affine, in RAS. */
static void set_geometry(nifti_image *nim, const vol *v)
{
    mat44 m;
    memset(&m, 0, sizeof m);
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++)
            m.m[r][c] = (float)((r < 2 ? -1.0 : 1.0) * v->affine[r][c]);
    m.m[3][3] = 1;
    nim->sto_xyz = m;
    nim->sto_ijk = nifti_mat44_inverse(m);
    nim->sform_code = NIFTI_XFORM_SCANNER_ANAT;
    float dx, dy, dz;
    nifti_mat44_to_quatern(m, &nim->quatern_b, &nim->quatern_c, &nim->quatern_d, &nim->qoffset_x,
                           &nim->qoffset_y, &nim->qoffset_z, &dx, &dy, &dz, &nim->qfac);
    nim->qto_xyz = nifti_quatern_to_mat44(nim->quatern_b, nim->quatern_c, nim->quatern_d, nim->qoffset_x,
                                          nim->qoffset_y, nim->qoffset_z, (float)v->spacing[0],
                                          (float)v->spacing[1], (float)v->spacing[2], nim->qfac);
    nim->qto_ijk = nifti_mat44_inverse(nim->qto_xyz);
    nim->qform_code = NIFTI_XFORM_SCANNER_ANAT;
    nim->dx = nim->pixdim[1] = (float)v->spacing[0];
    nim->dy = nim->pixdim[2] = (float)v->spacing[1];
    nim->dz = nim->pixdim[3] = (float)v->spacing[2];
    nim->xyz_units = NIFTI_UNITS_MM;
}

int volio__write_nifti(const vol *v, const char *path, vol_type type)
{
    FILE *probe = fopen(path, "wb"); /* nifticlib's writer reports nothing: find errors first */
    if (!probe)
        return fn_err_set(FN_EIO, "%s: cannot write: %s", path, strerror(errno));
    fclose(probe);
    nifti_set_debug_level(0);
    nifti_image *nim = nifti_simple_init_nim();
    if (!nim)
        return fn_err_set(FN_ENOMEM, "%s: out of memory", path);
    nim->ndim = nim->dim[0] = 3;
    nim->nx = nim->dim[1] = v->dim[0];
    nim->ny = nim->dim[2] = v->dim[1];
    nim->nz = nim->dim[3] = v->dim[2];
    nim->nvox = vol_count(v);
    nim->datatype = dt_of_type(type);
    nifti_datatype_sizes(nim->datatype, &nim->nbyper, &nim->swapsize);
    set_geometry(nim, v);
    nim->scl_slope = 0; /* no scaling: the voxels are stored as they are */
    nim->nifti_type = NIFTI_FTYPE_NIFTI1_1;
    if (nifti_set_filenames(nim, path, 0, 1) != 0) {
        nifti_image_free(nim);
        return fn_err_set(FN_EINVAL, "%s: not a NIfTI file name", path);
    }
    nifti_set_iname_offset(nim);
    nim->data = malloc(nim->nvox * (size_t)nim->nbyper);
    if (!nim->data) {
        nifti_image_free(nim);
        return fn_err_set(FN_ENOMEM, "%s: out of memory", path);
    }
    volio__from_float(v->data, nim->nvox, type, nim->data);
    nifti_image_write(nim);
    nifti_image_free(nim);
    struct stat st;
    if (stat(path, &st) != 0 || st.st_size < (nifti_is_gzfile(path) ? 18 : HDR_SIZE))
        return fn_err_set(FN_EIO, "%s: write failed (disk full?)", path);
    return 0;
}
