/* export: ITK transforms, NIfTI and 3D Slicer labelmaps, STL models and contact figures of a
 * case's planned configuration (see export.h). */
#include "export.h"

#include "durable.h"
#include "err.h"
#include "mesh.h"
#include "volio.h"

#include <teem/nrrd.h>

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* world -> crop index of fragment f at its pose: idx = M [w; 1]. */
static void world_to_crop(const frag *f, double m[3][4])
{
    pose p = pose_inverse(pose_compose(f->pose, f->home));
    double r[3][3];
    pose_to_matrix(&p, r);
    for (int a = 0; a < 3; a++) {
        for (int k = 0; k < 3; k++)
            m[a][k] = r[a][k] / f->spacing[a];
        m[a][3] = p.t[a] / f->spacing[a];
    }
}

vol *export_planned_labels(const planning_case *c)
{
    const vol *src = c->labels;
    vol *out = vol_new(src->dim[0], src->dim[1], src->dim[2]);
    if (!out)
        return NULL;
    memcpy(out->affine, src->affine, sizeof out->affine);
    memcpy(out->spacing, src->spacing, sizeof out->spacing);
    out->src_type = VOL_U16;
    for (int fi = 0; fi < c->nfrag; fi++) {
        const frag *f = &c->frag[fi];
        /* The crop's box at its pose, in source indices. */
        pose wp = pose_compose(f->pose, f->home);
        int lo[3] = {INT32_MAX, INT32_MAX, INT32_MAX}, hi[3] = {INT32_MIN, INT32_MIN, INT32_MIN};
        for (int b = 0; b < 8; b++) {
            double l[3], w[3], ijk[3];
            for (int a = 0; a < 3; a++)
                l[a] = ((b >> a & 1) ? f->dim[a] - 0.5 : -0.5) * f->spacing[a];
            pose_apply(&wp, l, w);
            vol_world_to_index(src, w, ijk);
            for (int a = 0; a < 3; a++) {
                int fl = (int)floor(ijk[a]), ce = (int)ceil(ijk[a]);
                lo[a] = fl < lo[a] ? fl : lo[a];
                hi[a] = ce > hi[a] ? ce : hi[a];
            }
        }
        for (int a = 0; a < 3; a++) {
            lo[a] = lo[a] < 0 ? 0 : lo[a];
            hi[a] = hi[a] >= src->dim[a] ? src->dim[a] - 1 : hi[a];
        }
        double m[3][4], g[3][4]; /* source index -> crop index */
        world_to_crop(f, m);
        for (int a = 0; a < 3; a++)
            for (int k = 0; k < 4; k++) {
                g[a][k] = k < 3 ? 0 : m[a][3];
                for (int q = 0; q < 3; q++)
                    g[a][k] += m[a][q] * src->affine[q][k];
            }
        for (int k = lo[2]; k <= hi[2]; k++)
            for (int j = lo[1]; j <= hi[1]; j++)
                for (int i = lo[0]; i <= hi[0]; i++) {
                    int l[3];
                    for (int a = 0; a < 3; a++)
                        l[a] = (int)lround(g[a][0] * i + g[a][1] * j + g[a][2] * k + g[a][3]);
                    if (l[0] < 0 || l[1] < 0 || l[2] < 0 || l[0] >= f->dim[0] || l[1] >= f->dim[1] ||
                        l[2] >= f->dim[2])
                        continue;
                    if (!f->prob[((size_t)l[2] * (size_t)f->dim[1] + (size_t)l[1]) * (size_t)f->dim[0] + (size_t)l[0]])
                        continue;
                    out->data[vol_idx(out, i, j, k)] = (float)f->id;
                }
    }
    return out;
}

/* ---- ITK transform ---- */

int export_tfm(const planning_case *c, int i, const char *path)
{
    const frag *f = &c->frag[i];
    pose inv = pose_inverse(f->pose); /* planned -> home: ITK's resampling direction */
    double a[3][3], cen[3], tr[3];
    pose_to_matrix(&inv, a);
    pose_apply(&f->pose, f->centroid, cen); /* the centre: the planned centroid */
    for (int r = 0; r < 3; r++) /* A (x - c) + c + T = A x + b  =>  T = b - c + A c */
        tr[r] = inv.t[r] - cen[r] + a[r][0] * cen[0] + a[r][1] * cen[1] + a[r][2] * cen[2];
    char text[2048];
    snprintf(text, sizeof text,
             "#Insight Transform File V1.0\n"
             "#Transform 0\n"
             "Transform: AffineTransform_double_3_3\n"
             "Parameters: %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n"
             "FixedParameters: %.17g %.17g %.17g\n",
             a[0][0], a[0][1], a[0][2], a[1][0], a[1][1], a[1][2], a[2][0], a[2][1], a[2][2], tr[0], tr[1],
             tr[2], cen[0], cen[1], cen[2]);
    return durable_replace_bytes(path, text, strlen(text));
}

/* ---- NIfTI and 3D Slicer segmentation ---- */

typedef struct vol_ctx {
    const planning_case *c;
    const vol *v;
} vol_ctx;

static int write_nifti(durable_file *f, void *ctx)
{
    return volio_write(((vol_ctx *)ctx)->v, f->tmp, VOL_U16);
}

int export_nifti(const vol *planned, const char *path)
{
    vol_ctx x = {NULL, planned};
    return durable_replace(path, write_nifti, &x);
}

static int teem_fail(int code, const char *path, const char *what)
{
    char *e = biffGetDone(NRRD);
    size_t n = e ? strlen(e) : 0;
    while (n && e[n - 1] == '\n')
        e[--n] = 0;
    fn_err_set(code, "%s: %s: %s", path, what, e ? e : "teem failed");
    free(e);
    return code;
}

static int write_seg(durable_file *df, void *ctx)
{
    const char *tmp = df->tmp;
    const vol_ctx *x = ctx;
    const vol *v = x->v;
    const planning_case *c = x->c;
    size_t count = vol_count(v);
    uint16_t *buf = malloc(count * sizeof *buf);
    int(*ext)[6] = malloc((size_t)(c->nfrag ? c->nfrag : 1) * sizeof *ext);
    if (!buf || !ext) {
        free(buf);
        free(ext);
        return fn_err_set(FN_ENOMEM, "%s: out of memory", tmp);
    }
    for (int fi = 0; fi < c->nfrag; fi++)
        for (int a = 0; a < 3; a++)
            ext[fi][2 * a] = INT32_MAX, ext[fi][2 * a + 1] = -1;
    for (int k = 0; k < v->dim[2]; k++)
        for (int j = 0; j < v->dim[1]; j++)
            for (int i = 0; i < v->dim[0]; i++) {
                size_t o = vol_idx(v, i, j, k);
                buf[o] = (uint16_t)v->data[o];
                int fi = buf[o] ? case_find(c, buf[o]) : -1;
                if (fi < 0)
                    continue;
                const int ijk[3] = {i, j, k};
                for (int a = 0; a < 3; a++) {
                    ext[fi][2 * a] = ijk[a] < ext[fi][2 * a] ? ijk[a] : ext[fi][2 * a];
                    ext[fi][2 * a + 1] = ijk[a] > ext[fi][2 * a + 1] ? ijk[a] : ext[fi][2 * a + 1];
                }
            }
    Nrrd *n = nrrdNew();
    NrrdIoState *nio = nrrdIoStateNew();
    double dirs[3][NRRD_SPACE_DIM_MAX], origin[3];
    for (int col = 0; col < 3; col++)
        for (int r = 0; r < 3; r++)
            dirs[col][r] = v->affine[r][col];
    for (int r = 0; r < 3; r++)
        origin[r] = v->affine[r][3];
    nio->encoding = nrrdEncodingGzip->available() ? nrrdEncodingGzip : nrrdEncodingRaw;
    int rc = 0;
    if (nrrdWrap_va(n, buf, nrrdTypeUShort, 3, (size_t)v->dim[0], (size_t)v->dim[1], (size_t)v->dim[2]) ||
        nrrdSpaceSet(n, nrrdSpaceLeftPosteriorSuperior) || nrrdSpaceOriginSet(n, origin)) {
        rc = teem_fail(FN_EINVAL, tmp, "header");
    } else {
        nrrdAxisInfoSet_va(n, nrrdAxisInfoSpaceDirection, dirs[0], dirs[1], dirs[2]);
        nrrdAxisInfoSet_va(n, nrrdAxisInfoKind, nrrdKindDomain, nrrdKindDomain, nrrdKindDomain);
        char key[64], val[256];
        nrrdKeyValueAdd(n, "Segmentation_MasterRepresentation", "Binary labelmap");
        nrrdKeyValueAdd(n, "Segmentation_ContainedRepresentationNames", "Binary labelmap|");
        nrrdKeyValueAdd(n, "Segmentation_ReferenceImageExtentOffset", "0 0 0");
        for (int fi = 0; fi < c->nfrag; fi++) {
            const frag *f = &c->frag[fi];
#define KV(suffix, ...)                                                                           \
    do {                                                                                          \
        snprintf(key, sizeof key, "Segment%d_" suffix, fi);                                       \
        snprintf(val, sizeof val, __VA_ARGS__);                                                   \
        nrrdKeyValueAdd(n, key, val);                                                             \
    } while (0)
            KV("ID", "Segment_%d", f->id);
            KV("Name", "%s", f->name[0] ? f->name : "fragment");
            KV("NameAutoGenerated", "0");
            KV("Color", "%.6g %.6g %.6g", f->rgb[0] / 255.0, f->rgb[1] / 255.0, f->rgb[2] / 255.0);
            KV("ColorAutoGenerated", "0");
            KV("LabelValue", "%d", f->id);
            KV("Layer", "0");
            if (ext[fi][1] < 0)
                KV("Extent", "0 -1 0 -1 0 -1");
            else
                KV("Extent", "%d %d %d %d %d %d", ext[fi][0], ext[fi][1], ext[fi][2], ext[fi][3], ext[fi][4],
                   ext[fi][5]);
            KV("Tags", "fracnav.planned:1|");
#undef KV
        }
        if (nrrdSave(tmp, n, nio))
            rc = teem_fail(FN_EIO, tmp, "write");
    }
    nrrdIoStateNix(nio);
    nrrdNix(n);
    free(buf);
    free(ext);
    return rc;
}

int export_seg_nrrd(const planning_case *c, const vol *planned, const char *path)
{
    vol_ctx x = {c, planned};
    return durable_replace(path, write_seg, &x);
}

/* ---- STL ---- */

typedef struct stl_ctx {
    const mesh *m;
    const char *header;
} stl_ctx;

static void put_f32(unsigned char *p, float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    for (int k = 0; k < 4; k++)
        p[k] = (unsigned char)(u >> (8 * k));
}

static int write_stl(durable_file *f, void *ctx)
{
    const stl_ctx *x = ctx;
    const mesh *m = x->m;
    FILE *fp = durable_stream(f);
    if (!fp)
        return FN_EIO;
    unsigned char head[84] = {0};
    snprintf((char *)head, 80, "%s", x->header);
    for (int k = 0; k < 4; k++)
        head[80 + k] = (unsigned char)((uint32_t)m->nt >> (8 * k));
    int bad = fwrite(head, 1, 84, fp) != 84;
    for (long t = 0; t < m->nt && !bad; t++) {
        unsigned char rec[50] = {0};
        const float *p[3];
        for (int e = 0; e < 3; e++)
            p[e] = m->v + (size_t)m->tri[t * 3 + e] * 3;
        double e1[3], e2[3], n[3];
        for (int a = 0; a < 3; a++)
            e1[a] = p[1][a] - p[0][a], e2[a] = p[2][a] - p[0][a];
        n[0] = e1[1] * e2[2] - e1[2] * e2[1];
        n[1] = e1[2] * e2[0] - e1[0] * e2[2];
        n[2] = e1[0] * e2[1] - e1[1] * e2[0];
        double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (int a = 0; a < 3; a++)
            put_f32(rec + 4 * a, len > 0 ? (float)(n[a] / len) : 0.0f);
        for (int e = 0; e < 3; e++)
            for (int a = 0; a < 3; a++)
                put_f32(rec + 12 + 12 * e + 4 * a, p[e][a]);
        bad = fwrite(rec, 1, 50, fp) != 50;
    }
    bad |= fclose(fp) != 0;
    return bad ? fn_err_set(FN_EIO, "%s: write failed", f->tmp) : 0;
}

int export_stl(const planning_case *c, int i, const export_stl_opts *o, const char *path, long *triangles)
{
    const frag *f = &c->frag[i];
    size_t n = (size_t)f->dim[0] * (size_t)f->dim[1] * (size_t)f->dim[2];
    float *mask = malloc(n * sizeof *mask);
    if (!mask)
        return fn_err_set(FN_ENOMEM, "%s: out of memory for fragment %d's mask", path, f->id);
    for (size_t k = 0; k < n; k++)
        mask[k] = f->prob[k] ? 1.0f : 0.0f;
    mesh m;
    int rc = mesh_extract(mask, f->dim, f->spacing, 0.5f, &m);
    free(mask);
    if (rc == 0 && mesh_drop_islands(&m) < 0)
        rc = FN_ENOMEM;
    if (rc == 0 && o->smooth > 0)
        rc = mesh_smooth(&m, o->smooth, 0.5, -0.53);
    if (rc == 0 && o->decimate > 0 && m.nt > o->decimate) {
        long r = mesh_decimate(&m, o->decimate);
        rc = r < 0 ? (int)r : 0;
    }
    if (rc) {
        mesh_free(&m);
        return fn_err_wrap(rc, "%s", path);
    }
    pose wp = pose_compose(f->pose, f->home);
    for (long v = 0; v < m.nv; v++) {
        double l[3] = {m.v[v * 3], m.v[v * 3 + 1], m.v[v * 3 + 2]}, w[3];
        pose_apply(&wp, l, w);
        if (o->ras)
            w[0] = -w[0], w[1] = -w[1];
        for (int a = 0; a < 3; a++)
            m.v[v * 3 + a] = (float)w[a];
    }
    char header[96];
    /* 3D Slicer reads the coordinate system from "SPACE=" in the header. */
    snprintf(header, sizeof header, "fracnav fragment %d, mm, SPACE=%s", f->id, o->ras ? "RAS" : "LPS");
    stl_ctx x = {&m, header};
    rc = durable_replace(path, write_stl, &x);
    if (triangles)
        *triangles = m.nt;
    mesh_free(&m);
    return rc;
}

/* ---- contact figures ---- */

/* Box dilation of a 0/1 mask by r[a] voxels along each axis (separable running counts). */
static int dilate(unsigned char *m, const int d[3], const int r[3])
{
    int longest = d[0] > d[1] ? d[0] : d[1];
    longest = longest > d[2] ? longest : d[2];
    unsigned char *line = malloc((size_t)longest);
    if (!line)
        return FN_ENOMEM;
    size_t stride[3] = {1, (size_t)d[0], (size_t)d[0] * (size_t)d[1]};
    for (int a = 0; a < 3; a++) {
        int b = (a + 1) % 3, c = (a + 2) % 3;
        for (int y = 0; y < d[c]; y++)
            for (int x = 0; x < d[b]; x++) {
                size_t base = (size_t)x * stride[b] + (size_t)y * stride[c];
                for (int t = 0; t < d[a]; t++)
                    line[t] = m[base + (size_t)t * stride[a]];
                int cnt = 0;
                for (int t = 0; t < r[a] && t < d[a]; t++)
                    cnt += line[t];
                for (int t = 0; t < d[a]; t++) {
                    if (t + r[a] < d[a])
                        cnt += line[t + r[a]];
                    if (t - r[a] - 1 >= 0)
                        cnt -= line[t - r[a] - 1];
                    m[base + (size_t)t * stride[a]] = cnt > 0;
                }
            }
    }
    free(line);
    return 0;
}

int export_contacts(const planning_case *c, const vol *planned, double gap_mm, double *contact_mm2, double *gap_ml)
{
    const vol *v = planned;
    const double *s = v->spacing;
    const double face[3] = {s[1] * s[2], s[0] * s[2], s[0] * s[1]};
    for (int fi = 0; fi < c->nfrag; fi++)
        contact_mm2[fi] = gap_ml[fi] = 0;
    for (int k = 0; k < v->dim[2]; k++)
        for (int j = 0; j < v->dim[1]; j++)
            for (int i = 0; i < v->dim[0]; i++) {
                int l = (int)v->data[vol_idx(v, i, j, k)];
                if (!l)
                    continue;
                const int nb[3][3] = {{i + 1, j, k}, {i, j + 1, k}, {i, j, k + 1}};
                for (int a = 0; a < 3; a++) {
                    if (nb[a][a] >= v->dim[a])
                        continue;
                    int m = (int)v->data[vol_idx(v, nb[a][0], nb[a][1], nb[a][2])];
                    if (m && m != l) {
                        int x = case_find(c, l), y = case_find(c, m);
                        if (x >= 0)
                            contact_mm2[x] += face[a];
                        if (y >= 0)
                            contact_mm2[y] += face[a];
                    }
                }
            }
    int r[3];
    for (int a = 0; a < 3; a++)
        r[a] = (int)ceil(gap_mm / s[a]);
    for (int fi = 0; fi < c->nfrag; fi++) {
        int id = c->frag[fi].id, lo[3] = {INT32_MAX, INT32_MAX, INT32_MAX}, hi[3] = {-1, -1, -1};
        for (int k = 0; k < v->dim[2]; k++)
            for (int j = 0; j < v->dim[1]; j++)
                for (int i = 0; i < v->dim[0]; i++)
                    if ((int)v->data[vol_idx(v, i, j, k)] == id) {
                        const int ijk[3] = {i, j, k};
                        for (int a = 0; a < 3; a++) {
                            lo[a] = ijk[a] < lo[a] ? ijk[a] : lo[a];
                            hi[a] = ijk[a] > hi[a] ? ijk[a] : hi[a];
                        }
                    }
        if (hi[0] < 0)
            continue;
        int d[3];
        for (int a = 0; a < 3; a++) {
            lo[a] = lo[a] - r[a] < 0 ? 0 : lo[a] - r[a];
            hi[a] = hi[a] + r[a] >= v->dim[a] ? v->dim[a] - 1 : hi[a] + r[a];
            d[a] = hi[a] - lo[a] + 1;
        }
        size_t n = (size_t)d[0] * (size_t)d[1] * (size_t)d[2];
        unsigned char *mf = malloc(n), *mo = malloc(n);
        if (!mf || !mo) {
            free(mf);
            free(mo);
            return fn_err_set(FN_ENOMEM, "out of memory measuring gaps");
        }
        size_t q = 0;
        for (int k = lo[2]; k <= hi[2]; k++)
            for (int j = lo[1]; j <= hi[1]; j++)
                for (int i = lo[0]; i <= hi[0]; i++, q++) {
                    int l = (int)v->data[vol_idx(v, i, j, k)];
                    mf[q] = l == id;
                    mo[q] = l && l != id;
                }
        int rc = dilate(mf, d, r);
        rc = rc ? rc : dilate(mo, d, r);
        if (rc) {
            free(mf);
            free(mo);
            return fn_err_set(FN_ENOMEM, "out of memory measuring gaps");
        }
        size_t gap = 0;
        q = 0;
        for (int k = lo[2]; k <= hi[2]; k++)
            for (int j = lo[1]; j <= hi[1]; j++)
                for (int i = lo[0]; i <= hi[0]; i++, q++)
                    gap += mf[q] && mo[q] && v->data[vol_idx(v, i, j, k)] == 0;
        gap_ml[fi] = (double)gap * s[0] * s[1] * s[2] * 1e-3;
        free(mf);
        free(mo);
    }
    return 0;
}
