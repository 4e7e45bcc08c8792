/* volio_nrrd: NRRD (.nrrd, .nhdr + detached data) through teem. The header is loaded first
 * without data so dims are checked against the data file and the memory budget before teem
 * allocates. */
#include "volio_impl.h"

#include "err.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <teem/nrrd.h>
#include <zlib.h>

#define DEFLATE_MAX_RATIO 1032

static const struct {
    int nt;
    vol_type type;
} types[] = {{nrrdTypeUChar, VOL_U8},  {nrrdTypeChar, VOL_I8}, {nrrdTypeUShort, VOL_U16},
             {nrrdTypeShort, VOL_I16}, {nrrdTypeUInt, VOL_U32}, {nrrdTypeInt, VOL_I32},
             {nrrdTypeFloat, VOL_F32}, {nrrdTypeDouble, VOL_F64}};

static int type_of_nt(int nt, vol_type *t)
{
    for (size_t i = 0; i < sizeof types / sizeof types[0]; i++)
        if (types[i].nt == nt) {
            *t = types[i].type;
            return 0;
        }
    return -1;
}

/* teem's error chain, deepest cause last: keep that line without its "[nrrd] func: " prefix. */
static int teem_error(int code, const char *path, const char *what)
{
    char *e = biffGetDone(NRRD);
    const char *cause = "unknown error";
    if (e) {
        char *end = e + strlen(e);
        while (end > e && (end[-1] == '\n' || end[-1] == ' '))
            *--end = '\0';
        char *line = strrchr(e, '\n');
        line = line ? line + 1 : e;
        while (*line == ' ')
            line++;
        char *colon = line[0] == '[' ? strstr(line, ": ") : NULL;
        cause = colon ? colon + 2 : line;
    }
    fn_err_set(code, "%s: %s: %s", path, what, cause);
    free(e);
    return code;
}

/* Bytes a gzip stream holds from the current position of f, counted up to `need` (concatenated
 * members are followed, as teem does; junk after the last member ends the count). Only what is
 * counted is held: a 4 MB file that claims gigabytes is refused before anything is allocated. */
static uint64_t gzip_holds(FILE *f, uint64_t need)
{
    z_stream z;
    memset(&z, 0, sizeof z);
    if (inflateInit2(&z, 15 + 16) != Z_OK)
        return 0;
    unsigned char in[1 << 14], out[1 << 16];
    uint64_t got = 0;
    int zr = Z_OK;
    while (got < need && zr != Z_DATA_ERROR && zr != Z_MEM_ERROR && zr != Z_NEED_DICT) {
        if (z.avail_in == 0) {
            z.avail_in = (uInt)fread(in, 1, sizeof in, f);
            z.next_in = in;
            if (z.avail_in == 0)
                break;
        }
        z.next_out = out;
        z.avail_out = sizeof out;
        zr = inflate(&z, Z_NO_FLUSH);
        got += sizeof out - z.avail_out;
        if (zr == Z_BUF_ERROR && z.avail_in == 0)
            zr = Z_OK; /* wants more input */
        if (zr == Z_STREAM_END) {
            if (z.avail_in == 0) {
                z.avail_in = (uInt)fread(in, 1, sizeof in, f);
                z.next_in = in;
            }
            if (z.avail_in < 2 || z.next_in[0] != 0x1f || z.next_in[1] != 0x8b)
                break; /* the end, or junk after the last member */
            inflateReset(&z);
            zr = Z_OK;
        }
    }
    inflateEnd(&z);
    return got;
}

/* Bytes of data the header promises, against what the (first) data file can hold in its
 * encoding: raw 1:1, hex 2 characters a byte, ascii at least 2 a value (a digit and a
 * separator), gzip 1032 a byte or, with `inflate`, what it really inflates to (slow: done after
 * the cheaper checks). The data file must be a regular file. */
static int check_size(NrrdIoState *nio, const char *path, int64_t dim[3], vol_type t, int inflate)
{
    for (int a = 0; a < 3; a++)
        if (dim[a] <= 0 || dim[a] > (1 << 20))
            return 0; /* vol_check_dims names these */
    uint64_t count = (uint64_t)dim[0] * (uint64_t)dim[1] * (uint64_t)dim[2];
    uint64_t bytes = count * volio__type_size(t);
    struct stat st;
    if (!nio->dataFile)
        return 0; /* several data files: teem checks each as it reads */
    if (fstat(fileno(nio->dataFile), &st) != 0 || !S_ISREG(st.st_mode))
        return fn_err_set(FN_EFORMAT, "%s: data file: not a regular file (a device or FIFO?)", path);
    const NrrdEncoding *enc = nio->encoding;
    if (nio->byteSkip < 0) {
        if (enc != nrrdEncodingRaw)
            return fn_err_set(FN_EFORMAT, "%s: byte skip: -1 needs raw encoding, not %s", path, enc->name);
        if ((uint64_t)st.st_size < bytes)
            return fn_err_set(FN_EFORMAT, "%s: sizes %lld %lld %lld of %s need %llu data bytes (raw), "
                              "the data file has %llu", path, (long long)dim[0], (long long)dim[1],
                              (long long)dim[2], vol_type_name(t), (unsigned long long)bytes,
                              (unsigned long long)st.st_size);
        return 0;
    }
    if (enc != nrrdEncodingRaw && enc != nrrdEncodingGzip && enc != nrrdEncodingAscii &&
        enc != nrrdEncodingHex)
        return fn_err_set(FN_EFORMAT, "%s: encoding: %s is not supported (raw, gzip, ascii, hex): its "
                          "size cannot be checked before reading", path, enc->name);
    long at = ftell(nio->dataFile);
    uint64_t avail = at >= 0 && (uint64_t)st.st_size > (uint64_t)at ? (uint64_t)st.st_size - (uint64_t)at : 0;
    uint64_t need = enc == nrrdEncodingRaw ? bytes : enc == nrrdEncodingHex ? 2 * bytes : 2 * count - 1;
    const char *unit = "data file has";
    if (enc == nrrdEncodingGzip) {
        need = bytes + (uint64_t)nio->byteSkip; /* skipped inside the inflated stream */
        if (avail >= need / DEFLATE_MAX_RATIO && !inflate)
            return 0;
        avail = inflate ? gzip_holds(nio->dataFile, need) : avail * DEFLATE_MAX_RATIO;
        unit = inflate ? "gzip data inflate to" : "gzip data can inflate to at most";
    }
    if (avail < need)
        return fn_err_set(FN_EFORMAT, "%s: sizes %lld %lld %lld of %s need %llu data bytes (%s), the "
                          "%s %llu", path, (long long)dim[0], (long long)dim[1], (long long)dim[2],
                          vol_type_name(t), (unsigned long long)need, enc->name, unit,
                          (unsigned long long)avail);
    return 0;
}

/* Index-to-LPS from space directions and origin, or from spacings (and axis mins) when there is no
 * space. Nothing is made up: a field that is present must be finite (spacings also positive); a
 * volume with neither space directions nor spacings is refused. `seen` is teem's per-field flags. */
static int geometry(const Nrrd *n, const int *seen, const char *path, vol *v)
{
    double a[3][3], org[3] = {0, 0, 0}, flip[3] = {1, 1, 1};
    if (n->spaceDim == 0) {
        static const double eye[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
        double sp[3];
        if (!seen[nrrdField_spacings])
            return fn_err_set(FN_EFORMAT, "%s: spacings: missing, and no space directions either: "
                              "the voxel size is unknown", path);
        for (int c = 0; c < 3; c++) {
            double s = n->axis[c].spacing, m = n->axis[c].min;
            if (!(isfinite(s) && s > 0))
                return fn_err_set(FN_EFORMAT, "%s: spacings: axis %d is %g, must be a positive number "
                                  "of mm", path, c, s);
            if (seen[nrrdField_axis_mins] && !isfinite(m))
                return fn_err_set(FN_EFORMAT, "%s: axis mins: axis %d is %g, must be finite", path, c, m);
            sp[c] = s;
            org[c] = seen[nrrdField_axis_mins] ? m : 0.0;
        }
        vol_set_geometry(v, eye, sp, org);
        return 0;
    }
    switch (n->space) {
    case nrrdSpaceRightAnteriorSuperior: flip[0] = flip[1] = -1; break;
    case nrrdSpaceLeftAnteriorSuperior: flip[1] = -1; break;
    case nrrdSpaceLeftPosteriorSuperior:
    case nrrdSpaceScannerXYZ:
    case nrrdSpaceUnknown: break; /* a bare "space dimension: 3" is read as LPS, like ITK */
    default:
        return fn_err_set(FN_EFORMAT, "%s: space: %s is not supported (RAS, LAS, LPS, scanner-xyz)",
                          path, airEnumStr(nrrdSpace, n->space));
    }
    if (n->spaceDim != 3)
        return fn_err_set(FN_EFORMAT, "%s: space dimension: %u, must be 3", path, n->spaceDim);
    for (int c = 0; c < 3; c++)
        for (int r = 0; r < 3; r++) {
            a[r][c] = flip[r] * n->axis[c].spaceDirection[r];
            if (!isfinite(a[r][c]))
                return fn_err_set(FN_EFORMAT, "%s: space directions: axis %d is missing or not finite", path, c);
        }
    /* An absent origin puts voxel 0 at 0 (as ITK and Slicer do); a present one must be finite. */
    for (int r = 0; r < 3 && seen[nrrdField_space_origin]; r++) {
        if (!isfinite(n->spaceOrigin[r]))
            return fn_err_set(FN_EFORMAT, "%s: space origin: component %d is %g, must be finite", path,
                              r, n->spaceOrigin[r]);
        org[r] = flip[r] * n->spaceOrigin[r];
    }
    return volio__set_affine(v, a, org, path, "space directions");
}

/* A detached header's one data file (data file: NAME, relative to the header's folder) must be
 * a regular file before teem opens it: opening a FIFO would block. The LIST and numbered forms
 * are left to teem (and to check_size, which checks the first file it opened). */
static int data_file_regular(const char *path, const char *v)
{
    v += strspn(v, " \t");
    int n = (int)strcspn(v, "\r\n");
    if (n == 0 || memchr(v, ' ', (size_t)n) || (n == 4 && !strncmp(v, "LIST", 4)))
        return 0;
    char name[8200];
    const char *slash = strrchr(path, '/');
    if (v[0] == '/' || !slash)
        snprintf(name, sizeof name, "%.*s", n, v);
    else
        snprintf(name, sizeof name, "%.*s/%.*s", (int)(slash - path), path, n, v);
    struct stat st;
    if (stat(name, &st) == 0 && !S_ISREG(st.st_mode))
        return fn_err_set(FN_EFORMAT, "%s: data file: %s is not a regular file (a device or FIFO?)",
                          path, name);
    return 0;
}

/* Header lines that must be refused before teem reads them: a data file that is not a regular
 * file, and a block size (only for type block, not supported: teem 1.12 finds the mismatch only
 * after reading, then leaks and closes the file it was asked to keep open). */
static int prescan(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return 0; /* teem reports it */
    char line[4096];
    int rc = 0;
    while (rc == 0 && fgets(line, sizeof line, f) && line[0] != '\n' && strcmp(line, "\r\n") != 0) {
        if (!strncasecmp(line, "data file:", 10) || !strncasecmp(line, "datafile:", 9))
            rc = data_file_regular(path, strchr(line, ':') + 1);
        else if (!strncasecmp(line, "block size:", 11) || !strncasecmp(line, "blocksize:", 10))
            rc = fn_err_set(FN_EFORMAT, "%s: block size: only for type block, which is not supported", path);
    }
    fclose(f);
    return rc;
}

/* Loads only the header and checks dims, type, data size and geometry. */
static int precheck(const char *path)
{
    if (prescan(path) < 0)
        return FN_EFORMAT;
    Nrrd *n = nrrdNew();
    NrrdIoState *nio = nrrdIoStateNew();
    int rc = 0;
    vol_type t;
    nio->skipData = 1;
    nio->keepNrrdDataFileOpen = 1;
    if (nrrdLoad(n, path, nio)) {
        nio->dataFile = NULL; /* teem may have closed it already (see prescan) */
        rc = teem_error(FN_EFORMAT, path, "header");
    } else if (n->dim != 3) {
        rc = fn_err_set(FN_EFORMAT, "%s: dimension: %u, only 3D volumes are supported", path, n->dim);
    } else if (type_of_nt(n->type, &t) < 0) {
        rc = fn_err_set(FN_EFORMAT, "%s: type: %s is not supported (u8 i8 u16 i16 u32 i32 f32 f64)",
                        path, airEnumStr(nrrdType, n->type));
    } else {
        int64_t dim[3];
        for (int a = 0; a < 3; a++)
            dim[a] = n->axis[a].size > (size_t)INT64_MAX ? -1 : (int64_t)n->axis[a].size;
        char what[4200];
        snprintf(what, sizeof what, "%s: sizes", path);
        vol geo; /* the geometry is checked here too, so a bad one costs no data read */
        rc = check_size(nio, path, dim, t, 0);
        if (rc == 0)
            rc = vol_check_dims(dim, sizeof(float) + volio__type_size(t), what);
        if (rc == 0)
            rc = geometry(n, nio->seen, path, &geo);
        if (rc == 0 && nio->encoding == nrrdEncodingGzip)
            rc = check_size(nio, path, dim, t, 1);
    }
    if (nio->dataFile)
        fclose(nio->dataFile);
    nio->dataFile = NULL;
    nrrdIoStateNix(nio);
    nrrdNuke(n);
    return rc;
}

vol *volio__read_nrrd(const char *path)
{
    if (precheck(path) < 0)
        return NULL;
    Nrrd *n = nrrdNew();
    NrrdIoState *nio = nrrdIoStateNew();
    vol *v = NULL;
    vol_type t = VOL_F32;
    if (!n || !nio) {
        fn_err_set(FN_ENOMEM, "%s: out of memory", path);
        goto out;
    }
    if (nrrdLoad(n, path, nio)) {
        teem_error(FN_EFORMAT, path, "data");
        goto out;
    }
    type_of_nt(n->type, &t);
    v = vol_new((int)n->axis[0].size, (int)n->axis[1].size, (int)n->axis[2].size);
    if (!v)
        goto out;
    if (geometry(n, nio->seen, path, v) < 0) {
        vol_free(v);
        v = NULL;
        goto out;
    }
    volio__to_float(n->data, t, vol_count(v), 1.0, 0.0, v->data);
    v->src_type = t;
out:
    nrrdIoStateNix(nio);
    nrrdNuke(n);
    return v;
}

int volio__write_nrrd(const vol *v, const char *path, vol_type type)
{
    int nt = nrrdTypeUnknown;
    for (size_t i = 0; i < sizeof types / sizeof types[0]; i++)
        if (types[i].type == type)
            nt = types[i].nt;
    size_t count = vol_count(v);
    void *buf = malloc(count * volio__type_size(type));
    if (!buf)
        return fn_err_set(FN_ENOMEM, "%s: out of memory", path);
    volio__from_float(v->data, count, type, buf);
    Nrrd *n = nrrdNew();
    NrrdIoState *nio = nrrdIoStateNew();
    int rc = 0;
    double dirs[3][NRRD_SPACE_DIM_MAX], origin[3];
    for (int c = 0; c < 3; c++)
        for (int r = 0; r < 3; r++)
            dirs[c][r] = v->affine[r][c];
    for (int r = 0; r < 3; r++)
        origin[r] = v->affine[r][3];
    nio->encoding = nrrdEncodingRaw;
    if (nrrdWrap_va(n, buf, nt, 3, (size_t)v->dim[0], (size_t)v->dim[1], (size_t)v->dim[2]) ||
        nrrdSpaceSet(n, nrrdSpaceLeftPosteriorSuperior) || nrrdSpaceOriginSet(n, origin)) {
        rc = teem_error(FN_EINVAL, path, "header");
    } else {
        nrrdAxisInfoSet_va(n, nrrdAxisInfoSpaceDirection, dirs[0], dirs[1], dirs[2]);
        nrrdAxisInfoSet_va(n, nrrdAxisInfoKind, nrrdKindDomain, nrrdKindDomain, nrrdKindDomain);
        if (nrrdSave(path, n, nio))
            rc = teem_error(FN_EIO, path, "write");
    }
    nrrdIoStateNix(nio);
    nrrdNix(n);
    free(buf);
    return rc;
}
