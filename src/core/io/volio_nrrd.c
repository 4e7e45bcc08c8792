/* volio_nrrd: NRRD (.nrrd, .nhdr + detached data) through teem. The header is loaded first
 * without data so dims are checked against the data file and the memory budget before teem
 * allocates. Also 3D Slicer segmentations (.seg.nrrd, one layer or a 4D multi-layer file) for
 * volio_read_labels: their segment keys are checked with the header, before the data is read. */
#include "volio_impl.h"

#include "err.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
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
static int check_size(NrrdIoState *nio, const char *path, int64_t dim[3], int layers, vol_type t,
                      int inflate)
{
    for (int a = 0; a < 3; a++)
        if (dim[a] <= 0 || dim[a] > (1 << 20))
            return 0; /* vol_check_dims names these */
    uint64_t count = (uint64_t)dim[0] * (uint64_t)dim[1] * (uint64_t)dim[2];
    if (count > UINT64_MAX / 16 / (uint64_t)layers)
        return 0; /* far over any memory budget: vol_check_dims names it */
    count *= (uint64_t)layers; /* values: a multi-layer file holds `layers` a voxel */
    uint64_t bytes = count * volio__type_size(t);
    struct stat st;
    char sizes[96]; /* "X Y Z" or "X Y Z in L layers" */
    snprintf(sizes, sizeof sizes, layers > 1 ? "%lld %lld %lld in %d layers" : "%lld %lld %lld",
             (long long)dim[0], (long long)dim[1], (long long)dim[2], layers);
    if (!nio->dataFile)
        return 0; /* several data files: teem checks each as it reads */
    if (fstat(fileno(nio->dataFile), &st) != 0 || !S_ISREG(st.st_mode))
        return fn_err_set(FN_EFORMAT, "%s: data file: not a regular file (a device or FIFO?)", path);
    const NrrdEncoding *enc = nio->encoding;
    if (nio->byteSkip < 0) {
        if (enc != nrrdEncodingRaw)
            return fn_err_set(FN_EFORMAT, "%s: byte skip: -1 needs raw encoding, not %s", path, enc->name);
        if ((uint64_t)st.st_size < bytes)
            return fn_err_set(FN_EFORMAT, "%s: sizes %s of %s need %llu data bytes (raw), the data file "
                              "has %llu", path, sizes, vol_type_name(t), (unsigned long long)bytes,
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
        return fn_err_set(FN_EFORMAT, "%s: sizes %s of %s need %llu data bytes (%s), the %s %llu", path,
                          sizes, vol_type_name(t), (unsigned long long)need, enc->name, unit,
                          (unsigned long long)avail);
    return 0;
}

/* Index-to-LPS from space directions and origin, or from spacings (and axis mins) when there is no
 * space. Nothing is made up: a field that is present must be finite (spacings also positive); a
 * volume with neither space directions nor spacings is refused. `seen` is teem's per-field flags. */
static int geometry(const Nrrd *n, const int *seen, const char *path, unsigned ax0, vol *v)
{
    const NrrdAxisInfo *axis = n->axis + ax0; /* the space axes (a multi-layer .seg.nrrd: 1..3) */
    double a[3][3], org[3] = {0, 0, 0}, flip[3] = {1, 1, 1};
    if (n->spaceDim == 0) {
        static const double eye[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
        double sp[3];
        if (!seen[nrrdField_spacings])
            return fn_err_set(FN_EFORMAT, "%s: spacings: missing, and no space directions either: "
                              "the voxel size is unknown", path);
        for (int c = 0; c < 3; c++) {
            double s = axis[c].spacing, m = axis[c].min;
            if (!(isfinite(s) && s > 0))
                return fn_err_set(FN_EFORMAT, "%s: spacings: axis %d is %g, must be a positive number "
                                  "of mm", path, c + (int)ax0, s);
            if (seen[nrrdField_axis_mins] && !isfinite(m))
                return fn_err_set(FN_EFORMAT, "%s: axis mins: axis %d is %g, must be finite", path,
                                  c + (int)ax0, m);
            sp[c] = s;
            org[c] = seen[nrrdField_axis_mins] ? m : 0.0;
        }
        int rc = volio__check_spacing(sp, path, "spacings");
        if (rc == 0)
            vol_set_geometry(v, eye, sp, org);
        return rc;
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
            a[r][c] = flip[r] * axis[c].spaceDirection[r];
            if (!isfinite(a[r][c]))
                return fn_err_set(FN_EFORMAT, "%s: space directions: axis %d is missing or not finite", path,
                                  c + (int)ax0);
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

/* A .seg.nrrd's segment keys, checked with the header. */
typedef struct seg_keys {
    int n;      /* segments (Segment0.. Segment<n-1>); 0: no segment keys */
    int layers; /* 1 for a 3D file, else the first axis' size */
    int *layer, *value;
} seg_keys;

static void seg_keys_free(seg_keys *k)
{
    free(k->layer);
    free(k->value);
    memset(k, 0, sizeof *k);
}

/* A whole number lo..hi written in a key's value (blanks around it allowed), else -1. */
static int whole_number(const char *s, long lo, long hi, long *out)
{
    char *end;
    double x = strtod(s, &end);
    if (end == s || end[strspn(end, " \t\r\n")] != '\0' || !(x >= (double)lo && x <= (double)hi) ||
        x != floor(x))
        return -1;
    *out = (long)x;
    return 0;
}

/* SegmentN_KEY's value (teem's copy: free it), or NULL when absent. */
static char *segment_value(const Nrrd *n, int seg, const char *key)
{
    char name[64];
    snprintf(name, sizeof name, "Segment%d_%s", seg, key);
    return nrrdKeyValueGet(n, name);
}

/* Reads and checks the segment keys of a header with `layers` layers into k (k->n 0: none). */
static int segment_keys(const Nrrd *n, const char *path, int layers, seg_keys *k)
{
    memset(k, 0, sizeof *k);
    k->layers = layers;
    int count = 0, rc = 0;
    for (unsigned i = 0; i < nrrdKeyValueSize(n); i++) { /* segment numbers: bounded by the scan */
        char *key = NULL, *val = NULL;
        nrrdKeyValueIndex(n, &key, &val, i);
        int seg = key ? volio__segment_number(key) : -1;
        if (seg + 1 > count)
            count = seg + 1;
        free(key);
        free(val);
    }
    if (count == 0)
        return layers > 1 ? fn_err_set(FN_EFORMAT, "%s: dimension: 4 without Segment<N>_ keys: not a 3D "
                                       "Slicer segmentation (.seg.nrrd), the only 4D labelmap read",
                                       path)
                          : 0;
    k->layer = malloc((size_t)count * sizeof *k->layer);
    k->value = malloc((size_t)count * sizeof *k->value);
    if (!k->layer || !k->value) {
        seg_keys_free(k);
        return fn_err_set(FN_ENOMEM, "%s: out of memory for %d segments", path, count);
    }
    k->n = count;
    for (int s = 0; s < count && rc == 0; s++) {
        char *lv = segment_value(n, s, "LabelValue"), *ly = segment_value(n, s, "Layer");
        long value = 0, layer = 0;
        if (!lv)
            rc = fn_err_set(FN_EFORMAT, "%s: Segment%d_LabelValue: missing (every segment needs the "
                            "label value that marks it in its layer)", path, s);
        else if (whole_number(lv, 1, INT32_MAX, &value) < 0)
            rc = fn_err_set(FN_EFORMAT, "%s: Segment%d_LabelValue: '%s' is not a whole number >= 1", path,
                            s, lv);
        else if (!ly && layers > 1)
            rc = fn_err_set(FN_EFORMAT, "%s: Segment%d_Layer: missing (in a file of %d layers every "
                            "segment needs its layer)", path, s, layers);
        else if (ly && whole_number(ly, 0, layers - 1, &layer) < 0)
            rc = fn_err_set(FN_EFORMAT, "%s: Segment%d_Layer: '%s' is no layer of this file: it has %d "
                            "layer%s (0..%d)", path, s, ly, layers, layers == 1 ? "" : "s", layers - 1);
        k->layer[s] = (int)layer;
        k->value[s] = (int)value;
        for (int o = 0; o < s && rc == 0; o++)
            if (k->layer[o] == k->layer[s] && k->value[o] == k->value[s])
                rc = fn_err_set(FN_EFORMAT, "%s: Segment%d_LabelValue: %ld in layer %ld is Segment%d's "
                                "too", path, s, value, layer, o);
        free(lv);
        free(ly);
    }
    if (rc < 0)
        seg_keys_free(k);
    return rc;
}

/* A 4D header's first axis must list layers: kind list (or none) and no space direction. */
static int layer_axis(const Nrrd *n, const char *path)
{
    const NrrdAxisInfo *a = &n->axis[0];
    if (a->kind != nrrdKindList && a->kind != nrrdKindUnknown)
        return fn_err_set(FN_EFORMAT, "%s: kinds: axis 0 is %s; a 4D .seg.nrrd's first axis lists its "
                          "layers (list)", path, airEnumStr(nrrdKind, a->kind));
    if (n->spaceDim > 0 && isfinite(a->spaceDirection[0]))
        return fn_err_set(FN_EFORMAT, "%s: space directions: axis 0 has one; a 4D .seg.nrrd's first axis "
                          "lists its layers (none)", path);
    if (a->size < 1 || a->size > VOLIO_MAX_SEGMENTS)
        return fn_err_set(FN_EFORMAT, "%s: sizes: %zu layers (must be 1..%d)", path, a->size,
                          VOLIO_MAX_SEGMENTS);
    return 0;
}

/* Loads only the header and checks dims, type, data size and geometry. With k (volio_read_labels)
 * a 4D segmentation is allowed too and the segment keys are read into k (free with
 * seg_keys_free; left empty on failure); without, only a 3D volume. */
static int precheck(const char *path, seg_keys *k)
{
    if (k)
        memset(k, 0, sizeof *k);
    if (volio__nrrd_scan(path, k != NULL) < 0)
        return FN_EFORMAT;
    Nrrd *n = nrrdNew();
    NrrdIoState *nio = nrrdIoStateNew();
    int rc = 0;
    vol_type t;
    nio->skipData = 1;
    nio->keepNrrdDataFileOpen = 1;
    if (nrrdLoad(n, path, nio)) {
        nio->dataFile = NULL; /* teem may have closed it already (see block size in volio_nrrdhdr.c) */
        rc = teem_error(FN_EFORMAT, path, "header");
    } else if (n->dim != 3 && !(k && n->dim == 4)) {
        rc = fn_err_set(FN_EFORMAT, "%s: dimension: %u, only 3D volumes are supported%s", path, n->dim,
                        k ? " (and 4D 3D Slicer segmentations)" : "");
    } else if (type_of_nt(n->type, &t) < 0) {
        rc = fn_err_set(FN_EFORMAT, "%s: type: %s is not supported (u8 i8 u16 i16 u32 i32 f32 f64)",
                        path, airEnumStr(nrrdType, n->type));
    } else {
        unsigned ax0 = n->dim - 3; /* the first space axis */
        rc = ax0 ? layer_axis(n, path) : 0;
        int layers = ax0 ? (int)n->axis[0].size : 1;
        if (rc == 0 && k)
            rc = segment_keys(n, path, layers, k);
        int64_t dim[3];
        for (int a = 0; a < 3; a++)
            dim[a] = n->axis[a + ax0].size > (size_t)INT64_MAX ? -1 : (int64_t)n->axis[a + ax0].size;
        char what[4200];
        snprintf(what, sizeof what, "%s: sizes", path);
        vol geo; /* the geometry is checked here too, so a bad one costs no data read */
        /* Held at once: the file's values (every layer) and the float volume made of them. */
        size_t per_voxel = sizeof(float) + (size_t)layers * volio__type_size(t);
        if (rc == 0)
            rc = check_size(nio, path, dim, layers, t, 0);
        if (rc == 0)
            rc = vol_check_dims(dim, per_voxel, what);
        if (rc == 0)
            rc = geometry(n, nio->seen, path, ax0, &geo);
        if (rc == 0 && nio->encoding == nrrdEncodingGzip)
            rc = check_size(nio, path, dim, layers, t, 1);
        if (rc < 0 && k)
            seg_keys_free(k);
    }
    if (nio->dataFile)
        fclose(nio->dataFile);
    nio->dataFile = NULL;
    nrrdIoStateNix(nio);
    nrrdNuke(n);
    return rc;
}

/* Loads the data of a header precheck passed; NULL with fn_err set on failure. */
static Nrrd *load(const char *path, NrrdIoState **nio)
{
    Nrrd *n = nrrdNew();
    *nio = nrrdIoStateNew();
    if (!n || !*nio) {
        fn_err_set(FN_ENOMEM, "%s: out of memory", path);
    } else if (nrrdLoad(n, path, *nio)) {
        teem_error(FN_EFORMAT, path, "data");
    } else
        return n;
    nrrdIoStateNix(*nio);
    *nio = NULL;
    nrrdNuke(n);
    return NULL;
}

/* A 3D volume whose header precheck passed. */
static vol *read_volume(const char *path)
{
    NrrdIoState *nio;
    Nrrd *n = load(path, &nio);
    if (!n)
        return NULL;
    vol_type t = VOL_F32;
    type_of_nt(n->type, &t);
    vol *v = vol_new((int)n->axis[0].size, (int)n->axis[1].size, (int)n->axis[2].size);
    if (v && geometry(n, nio->seen, path, 0, v) < 0) {
        vol_free(v);
        v = NULL;
    }
    if (v) {
        volio__to_float(n->data, t, vol_count(v), 1.0, 0.0, v->data);
        v->src_type = t;
    }
    nrrdIoStateNix(nio);
    nrrdNuke(n);
    return v;
}

vol *volio__read_nrrd(const char *path)
{
    return precheck(path, NULL) < 0 ? NULL : read_volume(path);
}

/* Value i of a teem array of type nt (one of `types`). */
static double value_at(const void *d, int nt, size_t i)
{
    switch (nt) {
    case nrrdTypeUChar: return ((const uint8_t *)d)[i];
    case nrrdTypeChar: return ((const int8_t *)d)[i];
    case nrrdTypeUShort: return ((const uint16_t *)d)[i];
    case nrrdTypeShort: return ((const int16_t *)d)[i];
    case nrrdTypeUInt: return ((const uint32_t *)d)[i];
    case nrrdTypeInt: return ((const int32_t *)d)[i];
    case nrrdTypeFloat: return ((const float *)d)[i];
    default: return ((const double *)d)[i];
    }
}

/* The segments of a layer, by label value: entries (value, segment), sorted. */
typedef struct seg_entry {
    int layer, value, seg;
} seg_entry;

static int by_layer_value(const void *a, const void *b)
{
    const seg_entry *x = a, *y = b;
    if (x->layer != y->layer)
        return x->layer < y->layer ? -1 : 1;
    return x->value < y->value ? -1 : x->value > y->value;
}

/* The segment that layer l's value x marks, or -1: a binary search over e[lo..hi). */
static int segment_of(const seg_entry *e, int lo, int hi, double x)
{
    const int end = hi;
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (e[mid].value < x)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < end && e[lo].value == x ? e[lo].seg : -1;
}

/* Voxel counts per (fragment, other) pair of segments, in an open-addressing table. */
typedef struct pair_table {
    uint32_t *key; /* fragment index << 16 | other index, + 1; 0 = empty */
    size_t *count, cap, n;
} pair_table;

static int pair_add(pair_table *t, int a, int b)
{
    if (2 * (t->n + 1) > t->cap) {
        size_t cap = t->cap ? 2 * t->cap : 64;
        pair_table g = {calloc(cap, sizeof *g.key), calloc(cap, sizeof *g.count), cap, 0};
        if (!g.key || !g.count) {
            free(g.key);
            free(g.count);
            return -1;
        }
        for (size_t i = 0; i < t->cap; i++)
            if (t->key[i]) {
                size_t h = (t->key[i] * 2654435761u) & (cap - 1);
                while (g.key[h])
                    h = (h + 1) & (cap - 1);
                g.key[h] = t->key[i];
                g.count[h] = t->count[i];
                g.n++;
            }
        free(t->key);
        free(t->count);
        *t = g;
    }
    uint32_t key = ((uint32_t)a << 16 | (uint32_t)b) + 1;
    size_t h = (key * 2654435761u) & (t->cap - 1);
    while (t->key[h] && t->key[h] != key)
        h = (h + 1) & (t->cap - 1);
    if (!t->key[h]) {
        t->key[h] = key;
        t->n++;
    }
    t->count[h]++;
    return 0;
}

static int by_pair(const void *a, const void *b)
{
    const volio_overlap *x = a, *y = b;
    if (x->fragment != y->fragment)
        return x->fragment < y->fragment ? -1 : 1;
    return x->other < y->other ? -1 : x->other > y->other;
}

/* Fragments from a loaded segmentation: segment s -> s + 1 where its layer holds its value, the
 * lowest s where several do; the overlaps and unlisted voxels go to segs. */
static int map_segments(const Nrrd *n, const seg_keys *k, const char *path, vol *v, volio_segs *segs)
{
    const int L = k->layers;
    const size_t count = vol_count(v);
    seg_entry *e = malloc((size_t)k->n * sizeof *e);
    int *first = malloc(((size_t)L + 1) * sizeof *first), *hit = malloc((size_t)L * sizeof *hit);
    pair_table pairs = {0};
    int rc = 0;
    if (!e || !first || !hit) {
        rc = fn_err_set(FN_ENOMEM, "%s: out of memory for %d segments", path, k->n);
        goto out;
    }
    for (int s = 0; s < k->n; s++)
        e[s] = (seg_entry){k->layer[s], k->value[s], s};
    qsort(e, (size_t)k->n, sizeof *e, by_layer_value);
    for (int l = 0, at = 0; l <= L; l++) {
        while (at < k->n && e[at].layer < l)
            at++;
        first[l] = at;
    }
    for (size_t i = 0; i < count; i++) {
        int nhit = 0, win = -1, unlisted = 0;
        for (int l = 0; l < L; l++) {
            double x = value_at(n->data, n->type, i * (size_t)L + (size_t)l);
            if (x == 0)
                continue;
            int s = first[l] < first[l + 1] ? segment_of(e, first[l], first[l + 1], x) : -1;
            if (s < 0) {
                unlisted = 1;
                continue;
            }
            hit[nhit++] = s;
            if (win < 0 || s < win)
                win = s;
        }
        v->data[i] = (float)(win + 1);
        segs->unlisted += unlisted && win < 0;
        for (int h = 0; h < nhit; h++)
            if (hit[h] != win && pair_add(&pairs, win, hit[h]) < 0) {
                rc = fn_err_set(FN_ENOMEM, "%s: out of memory counting overlaps", path);
                goto out;
            }
    }
    segs->overlap = pairs.n ? malloc(pairs.n * sizeof *segs->overlap) : NULL;
    if (pairs.n && !segs->overlap) {
        rc = fn_err_set(FN_ENOMEM, "%s: out of memory counting overlaps", path);
        goto out;
    }
    for (size_t i = 0; i < pairs.cap; i++)
        if (pairs.key[i]) {
            uint32_t key = pairs.key[i] - 1;
            segs->overlap[segs->noverlap++] =
                (volio_overlap){(int)(key >> 16) + 1, (int)(key & 0xffff) + 1, pairs.count[i]};
        }
    if (segs->noverlap)
        qsort(segs->overlap, (size_t)segs->noverlap, sizeof *segs->overlap, by_pair);
    segs->segments = k->n;
    segs->layers = L;
out:
    free(e);
    free(first);
    free(hit);
    free(pairs.key);
    free(pairs.count);
    return rc;
}

vol *volio__read_nrrd_labels(const char *path, volio_segs *segs)
{
    seg_keys k;
    if (precheck(path, &k) < 0)
        return NULL;
    if (k.n == 0)
        return read_volume(path); /* no segment keys: a plain labelmap */
    NrrdIoState *nio;
    Nrrd *n = load(path, &nio);
    vol *v = NULL;
    if (n) {
        unsigned ax0 = n->dim - 3;
        v = vol_new((int)n->axis[ax0].size, (int)n->axis[ax0 + 1].size, (int)n->axis[ax0 + 2].size);
        if (v && (geometry(n, nio->seen, path, ax0, v) < 0 || map_segments(n, &k, path, v, segs) < 0)) {
            vol_free(v);
            free(segs->overlap); /* not volio_segs_free: volio.c calls this file, not the reverse */
            memset(segs, 0, sizeof *segs);
            v = NULL;
        }
        if (v)
            v->src_type = VOL_U16;
        nrrdIoStateNix(nio);
        nrrdNuke(n);
    }
    seg_keys_free(&k);
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
