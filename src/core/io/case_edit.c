/* Manual corrections of a case's labelmap. */
#include "case.h"

#include "err.h"
#include "morph.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* FN_EINVAL naming the missing id and listing the ones the case has. */
static int no_such(const planning_case *c, int id)
{
    char list[512] = "";
    size_t used = 0;
    for (int i = 0; i < c->nfrag && used + 16 < sizeof list; i++)
        used += (size_t)snprintf(list + used, sizeof list - used, "%s%d", i ? ", " : "", c->frag[i].id);
    return fn_err_set(FN_EINVAL, "no fragment %d (the case has %s)", id, c->nfrag ? list : "none");
}

static int need(const planning_case *c, int id)
{
    return case_find(c, id) < 0 ? no_such(c, id) : 0;
}

static int next_free_id(const planning_case *c)
{
    int next = 0;
    for (int i = 0; i < c->nfrag; i++)
        if (c->frag[i].id > next)
            next = c->frag[i].id;
    return next + 1;
}

static void relabel(planning_case *c, int from, int to)
{
    size_t n = vol_count(c->labels);
    for (size_t i = 0; i < n; i++)
        if (c->labels->data[i] == (float)from)
            c->labels->data[i] = (float)to;
}

int case_merge(planning_case *c, int a, int b)
{
    int rc = need(c, a);
    if (rc == 0)
        rc = need(c, b);
    if (rc < 0)
        return rc;
    if (a == b)
        return fn_err_set(FN_EINVAL, "cannot merge fragment %d with itself", a);
    relabel(c, b, a);
    return case_rebuild(c, 0, 0);
}

typedef int (*voxel_test)(const double w[3], const void *ctx);

/* Relabels to `to` every voxel of label id (any label when 0) whose world centre passes test. */
static long relabel_where(planning_case *c, int id, voxel_test test, const void *ctx, int to)
{
    long n = 0;
    size_t idx = 0;
    vol *l = c->labels;
    for (int k = 0; k < l->dim[2]; k++)
        for (int j = 0; j < l->dim[1]; j++)
            for (int i = 0; i < l->dim[0]; i++, idx++) {
                float v = l->data[idx];
                if (v == 0 || (id > 0 && v != (float)id))
                    continue;
                double ijk[3] = {i, j, k}, w[3];
                vol_index_to_world(l, ijk, w);
                if (test(w, ctx)) {
                    l->data[idx] = (float)to;
                    n++;
                }
            }
    return n;
}

struct plane {
    double p[3], n[3];
};

static int in_front(const double w[3], const void *ctx)
{
    const struct plane *pl = ctx;
    return (w[0] - pl->p[0]) * pl->n[0] + (w[1] - pl->p[1]) * pl->n[1] + (w[2] - pl->p[2]) * pl->n[2] > 0;
}

int case_split(planning_case *c, int id, const double p[3], const double n[3])
{
    int rc = need(c, id);
    if (rc < 0)
        return rc;
    if (!(n[0] * n[0] + n[1] * n[1] + n[2] * n[2] > 0))
        return fn_err_set(FN_EINVAL, "split: the plane's normal is zero");
    int next = next_free_id(c);
    if (next > 65535)
        return fn_err_set(FN_EINVAL, "split: no free label left");
    struct plane pl = {{p[0], p[1], p[2]}, {n[0], n[1], n[2]}};
    long moved = relabel_where(c, id, in_front, &pl, next);
    const frag *f = &c->frag[case_find(c, id)];
    if (moved == 0 || (size_t)moved == f->voxels) {
        relabel(c, next, id);
        return fn_err_set(FN_EINVAL, "split: the plane leaves all of fragment %d on one side", id);
    }
    rc = case_rebuild(c, next, id);
    return rc < 0 ? rc : next;
}

struct box {
    double lo[3], hi[3];
};

static int in_box(const double w[3], const void *ctx)
{
    const struct box *b = ctx;
    for (int a = 0; a < 3; a++)
        if (w[a] < b->lo[a] || w[a] > b->hi[a])
            return 0;
    return 1;
}

struct sphere {
    double c[3], r2;
};

static int in_sphere(const double w[3], const void *ctx)
{
    const struct sphere *s = ctx;
    double d[3] = {w[0] - s->c[0], w[1] - s->c[1], w[2] - s->c[2]};
    return d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= s->r2;
}

static long erase(planning_case *c, int id, voxel_test test, const void *ctx)
{
    if (id > 0 && need(c, id) < 0)
        return FN_EINVAL;
    long n = relabel_where(c, id, test, ctx, 0);
    int rc = case_rebuild(c, 0, 0);
    return rc < 0 ? rc : n;
}

long case_erase_box(planning_case *c, const double a[3], const double b[3], int id)
{
    struct box bx;
    for (int i = 0; i < 3; i++) {
        bx.lo[i] = fmin(a[i], b[i]);
        bx.hi[i] = fmax(a[i], b[i]);
    }
    return erase(c, id, in_box, &bx);
}

long case_erase_sphere(planning_case *c, const double centre[3], double radius, int id)
{
    if (!(radius > 0) || !isfinite(radius))
        return fn_err_set(FN_EINVAL, "erase-sphere: the radius must be a positive number");
    struct sphere s = {{centre[0], centre[1], centre[2]}, radius * radius};
    return erase(c, id, in_sphere, &s);
}

/* Flood fill from voxel `start` over unlabelled voxels >= threshold (26-connected), labelling them
 * `to`. The queue holds each voxel once, so it needs at most one slot per voxel. */
static long flood(planning_case *c, size_t start, double threshold, int to)
{
    vol *l = c->labels;
    const int nx = l->dim[0], ny = l->dim[1], nz = l->dim[2];
    if (vol_count(l) > UINT32_MAX)
        return fn_err_set(FN_ENOMEM, "grow: the volume has too many voxels");
    uint32_t *queue = malloc(vol_count(l) * sizeof *queue);
    if (!queue)
        return fn_err_set(FN_ENOMEM, "grow: out of memory");
    size_t head = 0, tail = 0;
    l->data[start] = (float)to;
    queue[tail++] = (uint32_t)start;
    while (head < tail) {
        size_t v = queue[head++];
        int i = (int)(v % (size_t)nx), j = (int)(v / (size_t)nx % (size_t)ny), k = (int)(v / ((size_t)nx * ny));
        for (int dk = -1; dk <= 1; dk++)
            for (int dj = -1; dj <= 1; dj++)
                for (int di = -1; di <= 1; di++) {
                    int a = i + di, b = j + dj, e = k + dk;
                    if (a < 0 || b < 0 || e < 0 || a >= nx || b >= ny || e >= nz)
                        continue;
                    size_t w = vol_idx(l, a, b, e);
                    if (l->data[w] == 0 && c->ct->data[w] >= threshold) {
                        l->data[w] = (float)to;
                        queue[tail++] = (uint32_t)w;
                    }
                }
    }
    free(queue);
    return (long)tail;
}

int case_grow(planning_case *c, const double seed[3], double threshold, int into)
{
    if (into > 0 && need(c, into) < 0)
        return FN_EINVAL;
    double ijk[3];
    vol_world_to_index(c->labels, seed, ijk);
    int s[3];
    for (int a = 0; a < 3; a++) {
        if (!(ijk[a] > -0.5 && ijk[a] < c->labels->dim[a] - 0.5))
            return fn_err_set(FN_EINVAL, "grow: the seed (%g, %g, %g) mm is outside the volume",
                              seed[0], seed[1], seed[2]);
        s[a] = (int)floor(ijk[a] + 0.5);
    }
    size_t start = vol_idx(c->labels, s[0], s[1], s[2]);
    if (c->labels->data[start] != 0)
        return fn_err_set(FN_EINVAL, "grow: the seed voxel (%d,%d,%d) belongs to fragment %g already",
                          s[0], s[1], s[2], (double)c->labels->data[start]);
    if (!(c->ct->data[start] >= threshold))
        return fn_err_set(FN_EINVAL, "grow: the seed voxel (%d,%d,%d) is %g, under the threshold %g",
                          s[0], s[1], s[2], (double)c->ct->data[start], threshold);
    int id = into > 0 ? into : next_free_id(c);
    if (id > 65535)
        return fn_err_set(FN_EINVAL, "grow: no free label left");
    long n = flood(c, start, threshold, id);
    if (n < 0)
        return (int)n;
    int rc = case_rebuild(c, 0, 0);
    return rc < 0 ? rc : id;
}

static int listed(const int *ids, int n, int id)
{
    for (int i = 0; i < n; i++)
        if (ids[i] == id)
            return 1;
    return 0;
}

static int keep_or_drop(planning_case *c, const int *ids, int n, int keep)
{
    for (int i = 0; i < n; i++) {
        int rc = need(c, ids[i]);
        if (rc < 0)
            return rc;
    }
    size_t count = vol_count(c->labels);
    for (size_t i = 0; i < count; i++) {
        int v = (int)c->labels->data[i];
        if (v && listed(ids, n, v) != keep)
            c->labels->data[i] = 0;
    }
    return case_rebuild(c, 0, 0);
}

int case_keep(planning_case *c, const int *ids, int n)
{
    return keep_or_drop(c, ids, n, 1);
}

int case_drop(planning_case *c, const int *ids, int n)
{
    return keep_or_drop(c, ids, n, 0);
}

int case_fix(planning_case *c, int id)
{
    if (id == 0) {
        c->fixed = -1;
        c->nfixed_also = 0;
        return 0;
    }
    int rc = need(c, id);
    if (rc < 0)
        return rc;
    c->fixed = case_find(c, id);
    c->nfixed_also = 0;
    return 0;
}

/* ---- fill and separate ------------------------------------------------------------------ */

/* Fragment id's voxels as a mask over its label box grown by one voxel on every side (voxels
 * beyond the grid are outside). lo: the box's first source index. */
static uint8_t *id_mask(const planning_case *c, int id, int lo[3], int dim[3])
{
    int hi[3];
    if (frag_label_box(c->labels, id, lo, hi) < 0)
        return NULL;
    size_t n = 1;
    for (int a = 0; a < 3; a++) {
        lo[a]--;
        dim[a] = hi[a] - lo[a] + 2;
        n *= (size_t)dim[a];
    }
    uint8_t *m = calloc(n, 1);
    if (!m) {
        fn_err_set(FN_ENOMEM, "out of memory for fragment %d's box (%zu voxels)", id, n);
        return NULL;
    }
    const vol *l = c->labels;
    for (int k = 0; k < dim[2]; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                int s[3] = {lo[0] + i, lo[1] + j, lo[2] + k};
                if (s[0] >= 0 && s[1] >= 0 && s[2] >= 0 && s[0] < l->dim[0] && s[1] < l->dim[1] && s[2] < l->dim[2])
                    m[((size_t)k * dim[1] + j) * dim[0] + i] = l->data[vol_idx(l, s[0], s[1], s[2])] == (float)id;
            }
    return m;
}

long case_fill(planning_case *c, int id, int mode)
{
    int rc = need(c, id);
    if (rc < 0)
        return rc;
    int lo[3], dim[3];
    uint8_t *m = id_mask(c, id, lo, dim);
    if (!m)
        return FN_ENOMEM;
    uint8_t *before = malloc((size_t)dim[0] * dim[1] * dim[2]);
    if (!before) {
        free(m);
        return fn_err_set(FN_ENOMEM, "fill: out of memory");
    }
    memcpy(before, m, (size_t)dim[0] * dim[1] * dim[2]);
    long filled = morph_fill(m, dim, mode), took = 0;
    for (int k = 0; k < dim[2] && filled > 0; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                size_t v = ((size_t)k * dim[1] + j) * dim[0] + i;
                if (!m[v] || before[v])
                    continue;
                size_t s = vol_idx(c->labels, lo[0] + i, lo[1] + j, lo[2] + k);
                if (c->labels->data[s] == 0) { /* another fragment's voxels inside stay its own */
                    c->labels->data[s] = (float)id;
                    took++;
                }
            }
    free(m);
    free(before);
    if (filled < 0)
        return filled;
    if (took && (rc = case_rebuild(c, 0, 0)) < 0)
        return rc;
    return took;
}

int case_separate(planning_case *c, int id, double erode_mm, const double (*seeds)[3], int nseeds, int *new_ids,
                  double *erode_used)
{
    int rc = need(c, id);
    if (rc < 0)
        return rc;
    int lo[3], dim[3];
    uint8_t *m = id_mask(c, id, lo, dim);
    if (!m)
        return FN_ENOMEM;
    size_t n = (size_t)dim[0] * dim[1] * dim[2];
    int32_t *lab = malloc(n * sizeof *lab);
    int (*sv)[3] = nseeds > 0 ? malloc((size_t)nseeds * sizeof *sv) : NULL;
    if (!lab || (nseeds > 0 && !sv))
        rc = fn_err_set(FN_ENOMEM, "separate: out of memory");
    for (int s = 0; s < nseeds && rc == 0; s++) {
        double ijk[3];
        vol_world_to_index(c->labels, seeds[s], ijk);
        for (int a = 0; a < 3; a++)
            sv[s][a] = (int)floor(ijk[a] + 0.5) - lo[a];
    }
    double vox = c->labels->spacing[0] * c->labels->spacing[1] * c->labels->spacing[2];
    size_t min_voxels = (size_t)fmax(8, 20 / vox); /* cores under 0.02 ml are noise */
    int pieces = rc == 0 ? morph_separate(m, dim, c->labels->spacing, erode_mm, (const int(*)[3])sv, nseeds,
                                          min_voxels, lab, erode_used)
                         : rc;
    if (pieces < 0)
        rc = pieces;
    else if (pieces < 2 && erode_mm > 0 && !nseeds)
        rc = fn_err_set(FN_EINVAL, "separate: fragment %d does not split at --erode %g mm (it leaves no two "
                        "cores of 0.02 ml): try another --erode, or one --seeds point per piece", id, erode_mm);
    else if (pieces < 2)
        rc = fn_err_set(FN_EINVAL, "separate: fragment %d does not split (no erosion leaves two cores of "
                        "0.02 ml; give --erode MM or one --seeds point per piece)", id);
    if (rc == 0) {
        /* the largest piece keeps id; each other becomes the next free id, inheriting id's pose */
        size_t *count = calloc((size_t)pieces + 1, sizeof *count);
        if (!count)
            rc = fn_err_set(FN_ENOMEM, "separate: out of memory");
        for (size_t v = 0; count && v < n; v++)
            count[lab[v]]++;
        int keep = 1;
        for (int p = 2; count && p <= pieces; p++)
            if (count[p] > count[keep])
                keep = p;
        int made = 0;
        for (int p = 1; count && p <= pieces && rc == 0; p++) {
            if (p == keep)
                continue;
            int next = next_free_id(c);
            if (next > 65535) {
                rc = fn_err_set(FN_EINVAL, "separate: no free label left");
                break;
            }
            for (int k = 0; k < dim[2]; k++)
                for (int j = 0; j < dim[1]; j++)
                    for (int i = 0; i < dim[0]; i++)
                        if (lab[((size_t)k * dim[1] + j) * dim[0] + i] == p)
                            c->labels->data[vol_idx(c->labels, lo[0] + i, lo[1] + j, lo[2] + k)] = (float)next;
            rc = case_rebuild(c, next, id);
            if (rc == 0 && new_ids)
                new_ids[made] = next;
            made++;
        }
        free(count);
        if (rc == 0)
            rc = made;
    }
    free(m);
    free(lab);
    free(sv);
    return rc;
}
