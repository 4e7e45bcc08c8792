#include "seg.h"

#include "bone.h"

#include "err.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

void seg_defaults(seg_params *p)
{
    memset(p, 0, sizeof *p);
    p->threshold = 300;
    p->min_volume_ml = 0.5;
    p->min_volume_bone_only_ml = BONE_ONLY_MIN_ML;
    p->ramp = 200;
}

double seg_otsu_above(const vol *v, double floor_value)
{
    enum { BINS = 256 };
    size_t n = vol_count(v);
    double lo = INFINITY, hi = -INFINITY;
    for (size_t i = 0; i < n; i++) {
        double x = v->data[i];
        if (isfinite(x) && x >= floor_value && x < lo)
            lo = x;
        if (isfinite(x) && x >= floor_value && x > hi)
            hi = x;
    }
    if (!(hi > lo))
        return hi == lo ? lo : NAN; /* one value, or no finite voxel at all */
    /* In double: hi - lo of two floats near +-3e38 overflows float, not double. */
    double hist[BINS] = {0}, total = 0;
    double scale = (BINS - 1) / (hi - lo);
    for (size_t i = 0; i < n; i++) {
        double x = v->data[i];
        if (isfinite(x) && x >= floor_value) {
            double b = (x - lo) * scale;
            hist[b < BINS - 1 ? (int)b : BINS - 1] += 1;
            total += 1;
        }
    }
    double sum_all = 0;
    for (int b = 0; b < BINS; b++)
        sum_all += b * hist[b];
    /* Maximise the between-class variance w0 w1 (m0 - m1)^2 over the split after bin b. */
    double w0 = 0, sum0 = 0, best = -1;
    int split = 0;
    for (int b = 0; b < BINS - 1; b++) {
        w0 += hist[b];
        sum0 += b * hist[b];
        double w1 = total - w0;
        if (w0 == 0 || w1 == 0)
            continue;
        double d = sum0 / w0 - (sum_all - sum0) / w1;
        double between = w0 * w1 * d * d;
        if (between > best) {
            best = between;
            split = b;
        }
    }
    /* Voxels in bins above `split` are foreground: the threshold is the start of bin split+1. */
    return lo + (split + 1) / scale;
}

double seg_otsu(const vol *v)
{
    return seg_otsu_above(v, -INFINITY);
}

static int32_t uf_find(int32_t *parent, int32_t x)
{
    while (parent[x] != x) {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    return x;
}

static void uf_union(int32_t *parent, int32_t a, int32_t b)
{
    a = uf_find(parent, a);
    b = uf_find(parent, b);
    /* The smaller root wins, so every set's root is its first provisional label. */
    if (a < b)
        parent[b] = a;
    else if (b < a)
        parent[a] = b;
}

int seg_components(const uint8_t *mask, const int dim[3], int32_t *lab)
{
    const int nx = dim[0], ny = dim[1], nz = dim[2];
    const size_t n = (size_t)nx * ny * nz;
    size_t cap = 1024;
    int32_t *parent = malloc(cap * sizeof *parent);
    if (!parent)
        return fn_err_set(FN_ENOMEM, "segmentation: out of memory for labels");
    int32_t next = 1;
    parent[0] = 0;
    /* First pass: a provisional label per voxel, joined with the 13 already-visited neighbours. */
    for (int k = 0; k < nz; k++)
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++) {
                size_t idx = ((size_t)k * ny + j) * nx + i;
                lab[idx] = 0;
                if (!mask[idx])
                    continue;
                int32_t mine = 0;
                for (int dk = -1; dk <= 0; dk++)
                    for (int dj = -1; dj <= 1; dj++)
                        for (int di = -1; di <= 1; di++) {
                            if (dk == 0 && (dj > 0 || (dj == 0 && di >= 0)))
                                continue;
                            int a = i + di, b = j + dj, c = k + dk;
                            if (a < 0 || a >= nx || b < 0 || b >= ny || c < 0)
                                continue;
                            int32_t l = lab[((size_t)c * ny + b) * nx + a];
                            if (!l)
                                continue;
                            if (!mine)
                                mine = l;
                            else if (l != mine)
                                uf_union(parent, mine, l);
                        }
                if (!mine) {
                    if ((size_t)next == cap) {
                        if (cap > (size_t)INT32_MAX / 2) {
                            free(parent);
                            return fn_err_set(FN_ENOMEM, "segmentation: too many components");
                        }
                        int32_t *p = realloc(parent, 2 * cap * sizeof *p);
                        if (!p) {
                            free(parent);
                            return fn_err_set(FN_ENOMEM, "segmentation: out of memory for labels");
                        }
                        parent = p;
                        cap *= 2;
                    }
                    parent[next] = next;
                    mine = next++;
                }
                lab[idx] = mine;
            }
    /* Roots get consecutive final labels (stored negated) in order of first appearance. A parent
     * is never larger than its child, so it is already resolved when the child is reached. */
    int32_t nfinal = 0;
    for (int32_t l = 1; l < next; l++)
        parent[l] = parent[l] == l ? -(++nfinal) : parent[parent[l]];
    for (size_t i = 0; i < n; i++)
        if (lab[i])
            lab[i] = -parent[lab[i]];
    free(parent);
    return nfinal;
}

uint8_t seg_prob(float value, double threshold, double ramp)
{
    if (ramp <= 0)
        return 255;
    double p = 0.5 + (value - threshold) / ramp;
    double b = p * 255 + 0.5;
    if (b < 1)
        return 1;
    if (b > 255)
        return 255;
    return (uint8_t)b;
}

static int by_size_desc(const void *a, const void *b)
{
    const seg_component *x = a, *y = b;
    if (x->voxels != y->voxels)
        return x->voxels < y->voxels ? 1 : -1;
    return x->label - y->label;
}

/* Per-component size, peak and bounding box over raw labels 1..n. */
static seg_component *component_stats(const vol *v, const int32_t *lab, int n)
{
    seg_component *c = calloc((size_t)n + 1, sizeof *c);
    if (!c)
        return NULL;
    for (int l = 1; l <= n; l++) {
        c[l].label = l;
        c[l].peak = -INFINITY;
        for (int a = 0; a < 3; a++) {
            c[l].lo[a] = v->dim[a];
            c[l].hi[a] = -1;
        }
    }
    size_t idx = 0;
    for (int k = 0; k < v->dim[2]; k++)
        for (int j = 0; j < v->dim[1]; j++)
            for (int i = 0; i < v->dim[0]; i++, idx++) {
                if (!lab[idx])
                    continue;
                seg_component *s = &c[lab[idx]];
                s->voxels++;
                if (v->data[idx] > s->peak)
                    s->peak = v->data[idx];
                int ijk[3] = {i, j, k};
                for (int a = 0; a < 3; a++) {
                    if (ijk[a] < s->lo[a])
                        s->lo[a] = ijk[a];
                    if (ijk[a] > s->hi[a])
                        s->hi[a] = ijk[a];
                }
            }
    return c;
}

static int validate(const seg_params *p)
{
    if (!isfinite(p->threshold) || !isfinite(p->min_volume_ml) || p->min_volume_ml < 0)
        return fn_err_set(FN_EINVAL, "segmentation: threshold and min volume must be finite, "
                                     "min volume >= 0");
    if (p->keep < 0)
        return fn_err_set(FN_EINVAL, "segmentation: keep must be >= 0 (got %d)", p->keep);
    if (!isfinite(p->ramp) || p->ramp < 0)
        return fn_err_set(FN_EINVAL, "segmentation: ramp must be >= 0");
    return 0;
}

/* The threshold p asks for over v (Otsu's when auto), or NaN. Counts the non-finite voxels. */
static double threshold_of(const vol *v, const seg_params *p, size_t *nonfinite)
{
    size_t n = vol_count(v);
    *nonfinite = 0;
    for (size_t i = 0; i < n; i++)
        *nonfinite += !isfinite(v->data[i]);
    if (*nonfinite == n)
        return NAN;
    if (p->threshold_auto)
        return p->threshold_auto == 2 ? seg_otsu_above(v, seg_otsu(v)) : seg_otsu(v);
    return p->threshold;
}

double seg_threshold(const vol *v, const seg_params *p)
{
    size_t nonfinite;
    return threshold_of(v, p, &nonfinite);
}

static int run(const vol *v, const uint8_t *given, const seg_params *p, seg_result *out)
{
    memset(out, 0, sizeof *out);
    int rc = validate(p);
    if (rc < 0)
        return rc;
    size_t n = vol_count(v), nonfinite;
    double thr = threshold_of(v, p, &nonfinite);
    if (nonfinite == n)
        return fn_err_set(FN_EFORMAT, "segmentation: all %zu voxels are NaN or infinite: nothing to "
                                      "segment", n);
    if (!isfinite(thr))
        return fn_err_set(FN_EFORMAT, "segmentation: no threshold found (%zu of %zu voxels are NaN "
                                      "or infinite)", nonfinite, n);
    uint8_t *mask = given ? NULL : malloc(n);
    int32_t *lab = malloc(n * sizeof *lab);
    out->labels = vol_new(v->dim[0], v->dim[1], v->dim[2]);
    if ((!given && !mask) || !lab || !out->labels) {
        free(mask);
        free(lab);
        vol_free(out->labels);
        out->labels = NULL;
        return fn_err_set(FN_ENOMEM, "segmentation: out of memory for %zu voxels", n);
    }
    for (size_t i = 0; mask && i < n; i++)
        mask[i] = isfinite(v->data[i]) && v->data[i] >= thr; /* non-finite voxels are never bone */
    int ncomp = seg_components(given ? given : mask, v->dim, lab);
    free(mask);
    seg_component *c = ncomp >= 0 ? component_stats(v, lab, ncomp) : NULL;
    if (!c) {
        free(lab);
        vol_free(out->labels);
        out->labels = NULL;
        return ncomp < 0 ? ncomp : fn_err_set(FN_ENOMEM, "segmentation: out of memory");
    }
    double voxel_ml = v->spacing[0] * v->spacing[1] * v->spacing[2] / 1000.0;
    qsort(c + 1, (size_t)ncomp, sizeof *c, by_size_desc);
    /* newlabel[raw] = final label or 0 when filtered out */
    int32_t *newlabel = calloc((size_t)ncomp + 1, sizeof *newlabel);
    if (!newlabel) {
        free(c);
        free(lab);
        vol_free(out->labels);
        out->labels = NULL;
        return fn_err_set(FN_ENOMEM, "segmentation: out of memory");
    }
    int kept = 0;
    for (int r = 1; r <= ncomp; r++) {
        seg_component s = c[r];
        s.volume_ml = (double)s.voxels * voxel_ml;
        if (s.volume_ml < p->min_volume_ml || (p->exclude_peak && s.peak < p->exclude_below_peak) ||
            (p->keep > 0 && kept >= p->keep))
            continue;
        newlabel[s.label] = ++kept;
        s.label = kept;
        c[kept - 1] = s;
    }
    for (size_t i = 0; i < n; i++)
        out->labels->data[i] = (float)newlabel[lab[i]];
    memcpy(out->labels->affine, v->affine, sizeof v->affine);
    memcpy(out->labels->spacing, v->spacing, sizeof v->spacing);
    out->labels->src_type = VOL_U16;
    free(newlabel);
    free(lab);
    out->ncomp = kept;
    out->comp = c;
    out->threshold = thr;
    out->raw_components = ncomp;
    out->nonfinite = nonfinite;
    return 0;
}

int seg_run(const vol *v, const seg_params *p, seg_result *out)
{
    return run(v, NULL, p, out);
}

int seg_run_mask(const vol *v, const uint8_t *mask, const seg_params *p, seg_result *out)
{
    return run(v, mask, p, out);
}

void seg_result_free(seg_result *r)
{
    if (!r)
        return;
    vol_free(r->labels);
    free(r->comp);
    memset(r, 0, sizeof *r);
}

int seg_from_labels(const vol *v, vol *labels, const seg_params *p, seg_result *out)
{
    memset(out, 0, sizeof *out);
    for (int a = 0; a < 3; a++)
        if (labels->dim[a] != v->dim[a])
            return fn_err_set(FN_EINVAL, "labels: the labelmap is %dx%dx%d voxels, the CT %dx%dx%d (it must "
                              "lie on the CT's grid)", labels->dim[0], labels->dim[1], labels->dim[2], v->dim[0],
                              v->dim[1], v->dim[2]);
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++)
            if (fabs(labels->affine[r][c] - v->affine[r][c]) > 1e-3 * (c == 3 ? 10 : 1))
                return fn_err_set(FN_EINVAL, "labels: the labelmap's grid (affine row %d, column %d: %g) is not the "
                                  "CT's (%g)", r, c, labels->affine[r][c], v->affine[r][c]);
    size_t n = vol_count(v);
    int maxl = 0;
    for (size_t i = 0; i < n; i++) {
        float x = labels->data[i];
        if (!(x >= 0 && x <= 65535 && x == floorf(x)))
            return fn_err_set(FN_EFORMAT, "labels: voxel %zu holds %g; labels are whole numbers 0..65535", i,
                              (double)x);
        if ((int)x > maxl)
            maxl = (int)x;
    }
    double thr = p->threshold;
    if (p->threshold_auto)
        thr = p->threshold_auto == 2 ? seg_otsu_above(v, seg_otsu(v)) : seg_otsu(v);
    seg_component *all = calloc((size_t)maxl + 1, sizeof *all);
    if (!all)
        return fn_err_set(FN_ENOMEM, "labels: out of memory");
    for (int l = 0; l <= maxl; l++) {
        all[l].label = l;
        all[l].peak = -INFINITY;
        for (int a = 0; a < 3; a++) {
            all[l].lo[a] = INT32_MAX;
            all[l].hi[a] = -1;
        }
    }
    double vox_ml = v->spacing[0] * v->spacing[1] * v->spacing[2] / 1000;
    size_t i = 0;
    for (int z = 0; z < v->dim[2]; z++)
        for (int y = 0; y < v->dim[1]; y++)
            for (int x = 0; x < v->dim[0]; x++, i++) {
                seg_component *c = &all[(int)labels->data[i]];
                int q[3] = {x, y, z};
                c->voxels++;
                if (v->data[i] > c->peak)
                    c->peak = v->data[i];
                for (int a = 0; a < 3; a++) {
                    c->lo[a] = q[a] < c->lo[a] ? q[a] : c->lo[a];
                    c->hi[a] = q[a] > c->hi[a] ? q[a] : c->hi[a];
                }
            }
    int k = 0;
    for (int l = 1; l <= maxl; l++)
        if (all[l].voxels) {
            all[l].volume_ml = (double)all[l].voxels * vox_ml;
            all[k++] = all[l];
        }
    out->comp = all;
    out->ncomp = out->raw_components = k;
    out->threshold = thr;
    out->labels = labels;
    return 0;
}
