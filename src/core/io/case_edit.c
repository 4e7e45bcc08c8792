/* Manual corrections of a case's labelmap. */
#include "case.h"

#include "bone.h"
#include "err.h"
#include "grow.h"
#include "morph.h"
#include "split.h"

#include <math.h>
#include <stddef.h>
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

/* Flood fill from voxel `start` over unlabelled voxels >= threshold, and not exactly 0 when
 * skip_zero (26-connected), labelling them `to`. The queue holds each voxel once, so it needs at
 * most one slot per voxel. */
static long flood(planning_case *c, size_t start, double threshold, int skip_zero, int to)
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
                    float x = c->ct->data[w];
                    if (l->data[w] == 0 && x >= threshold && !(skip_zero && x == 0)) {
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
    long n = flood(c, start, threshold, 0, id);
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

/* Puts the pieces of fragment id found in its box (lab over the box at lo, dim: 1..pieces, 0 for a
 * voxel left as it is, -1 for one that is not bone) into the labelmap: the largest piece keeps
 * id, each other one becomes the next free id, inheriting id's pose. Returns the new ids made. */
static int store_pieces(planning_case *c, int id, const int32_t *lab, const int lo[3], const int dim[3], int pieces,
                        int *new_ids)
{
    size_t n = (size_t)dim[0] * dim[1] * dim[2];
    size_t *count = calloc((size_t)pieces + 1, sizeof *count);
    if (!count)
        return fn_err_set(FN_ENOMEM, "separate: out of memory");
    for (size_t v = 0; v < n; v++)
        if (lab[v] > 0)
            count[lab[v]]++;
    int keep = 1;
    for (int p = 2; p <= pieces; p++)
        if (count[p] > count[keep])
            keep = p;
    int made = 0, rc = 0;
    for (int p = -1; p <= pieces && rc == 0; p++) {
        if (p == 0 || p == keep || (p > 0 && !count[p]))
            continue;
        int next = p < 0 ? 0 : next_free_id(c);
        if (next > 65535)
            return fn_err_set(FN_EINVAL, "separate: no free label left");
        for (int k = 0; k < dim[2]; k++)
            for (int j = 0; j < dim[1]; j++)
                for (int i = 0; i < dim[0]; i++)
                    if (lab[((size_t)k * dim[1] + j) * dim[0] + i] == p)
                        c->labels->data[vol_idx(c->labels, lo[0] + i, lo[1] + j, lo[2] + k)] = (float)next;
        rc = case_rebuild(c, next, id);
        if (rc == 0 && p > 0 && new_ids)
            new_ids[made++] = next;
    }
    free(count);
    return rc < 0 ? rc : made;
}

int case_separate(planning_case *c, int id, double erode_mm, int *new_ids, double *erode_used)
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
    if (!lab)
        rc = fn_err_set(FN_ENOMEM, "separate: out of memory");
    double vox = c->labels->spacing[0] * c->labels->spacing[1] * c->labels->spacing[2];
    size_t min_voxels = (size_t)fmax(8, 20 / vox); /* cores under 0.02 ml are noise */
    int pieces = rc == 0 ? morph_separate(m, dim, c->labels->spacing, erode_mm, NULL, 0, min_voxels, lab,
                                          erode_used)
                         : rc;
    if (pieces < 0)
        rc = pieces;
    else if (pieces < 2 && erode_mm > 0)
        rc = fn_err_set(FN_EINVAL, "separate: fragment %d does not split at --erode %g mm (it leaves no two "
                        "cores of 0.02 ml): try another --erode, or --seeds", id, erode_mm);
    else if (pieces < 2)
        rc = fn_err_set(FN_EINVAL, "separate: fragment %d does not split (no erosion leaves two cores of "
                        "0.02 ml; give --erode MM, or --seeds)", id);
    if (rc == 0)
        rc = store_pieces(c, id, lab, lo, dim, pieces, new_ids);
    free(m);
    free(lab);
    return rc;
}

/* ---- seeded separation -------------------------------------------------------------------- */

/* The CT's values over a fragment's box (id_mask's), 0 outside the mask; NULL when out of memory. */
static float *box_values(const planning_case *c, const uint8_t *m, const int lo[3], const int dim[3])
{
    float *hu = malloc((size_t)dim[0] * dim[1] * dim[2] * sizeof *hu);
    for (int k = 0; hu && k < dim[2]; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++) {
                size_t b = ((size_t)k * dim[1] + j) * dim[0] + i;
                hu[b] = m[b] ? c->ct->data[vol_idx(c->ct, lo[0] + i, lo[1] + j, lo[2] + k)] : 0;
            }
    return hu;
}

/* The voxel of seed s on the grid (its nearest centre), or FN_EINVAL naming the point. */
static int seed_voxel(const planning_case *c, const case_seed *s, int v[3])
{
    const vol *l = c->labels;
    double ijk[3];
    vol_world_to_index(l, s->at, ijk);
    for (int a = 0; a < 3; a++) {
        if (!(ijk[a] > -0.5 && ijk[a] < l->dim[a] - 0.5)) {
            double first[3] = {0, 0, 0}, last[3] = {l->dim[0] - 1, l->dim[1] - 1, l->dim[2] - 1}, w0[3], w1[3];
            vol_index_to_world(l, first, w0);
            vol_index_to_world(l, last, w1);
            return fn_err_set(FN_EINVAL, "separate: the seed (%.1f, %.1f, %.1f) mm is outside the CT (its voxel "
                              "centres span (%.1f, %.1f, %.1f) to (%.1f, %.1f, %.1f) mm, LPS)", s->at[0], s->at[1],
                              s->at[2], w0[0], w0[1], w0[2], w1[0], w1[1], w1[2]);
        }
        v[a] = (int)floor(ijk[a] + 0.5);
    }
    return 0;
}

/* A seed of a piece on an unlabelled voxel: the bone mask is short there, so the bone connected to
 * it (non-zero voxels on a bone-only CT, voxels >= the case's threshold on a full CT) joins
 * fragment id; FN_EINVAL saying why not when the voxel is not bone, or lies in another fragment. */
/* 0 when the unlabelled voxel `at` of seed s is bone the mask missed (non-zero on a bone-only CT,
 * >= the case's threshold on a full CT), else FN_EINVAL saying why it is not bone. */
static int seed_on_bone(const planning_case *c, const case_seed *s, size_t at, bone_kind kind, int id)
{
    float hu = c->ct->data[at];
    double thr = c->seg.threshold;
    if (kind == BONE_ONLY_CT && !(isfinite(hu) && hu != 0))
        return fn_err_set(FN_EINVAL, "separate: the seed (%.1f, %.1f, %.1f) mm is outside the bone: the CT holds "
                          "only the bone, and is %g there", s->at[0], s->at[1], s->at[2], (double)hu);
    if (kind == BONE_FULL_CT && !(hu >= thr)) {
        char where[64] = "on no fragment";
        if (id > 0)
            snprintf(where, sizeof where, "outside fragment %d", id);
        return fn_err_set(FN_EINVAL, "separate: the seed (%.1f, %.1f, %.1f) mm is %s, and the CT there (%g) is "
                          "under the case's bone threshold %g: not bone to grow from", s->at[0], s->at[1],
                          s->at[2], where, (double)hu, thr);
    }
    return 0;
}

static int take_seed_bone(planning_case *c, int id, const case_seed *s, size_t at, bone_kind kind)
{
    float here = c->labels->data[at];
    if (here == (float)id || s->piece == 0)
        return 0;
    if (here != 0)
        return fn_err_set(FN_EINVAL, "separate: the seed (%.1f, %.1f, %.1f) mm lies in fragment %g, not in "
                          "fragment %d", s->at[0], s->at[1], s->at[2], (double)here, id);
    int rc = seed_on_bone(c, s, at, kind, id);
    if (rc < 0)
        return rc;
    long n = kind == BONE_ONLY_CT ? flood(c, at, -INFINITY, 1, id) : flood(c, at, c->seg.threshold, 0, id);
    return n < 0 ? (int)n : 0;
}

/* Checks the seeds and grows the bone to those outside fragment id; vox gets their voxels. */
static int place_seeds(planning_case *c, int id, const case_seed *seeds, int n, size_t *vox)
{
    bone_kind kind = bone_kind_of(c->ct);
    for (int s = 0; s < n; s++) {
        int v[3];
        if (seeds[s].piece < 0 || seeds[s].piece >= GROW_MAX_LABEL)
            return fn_err_set(FN_EINVAL, "separate: the seed (%.1f, %.1f, %.1f) mm names piece %d (pieces are "
                              "1..%d, 0 for not bone)", seeds[s].at[0], seeds[s].at[1], seeds[s].at[2],
                              seeds[s].piece, GROW_MAX_LABEL - 1);
        int rc = seed_voxel(c, &seeds[s], v);
        if (rc < 0)
            return rc;
        vox[s] = vol_idx(c->labels, v[0], v[1], v[2]);
        for (int t = 0; t < s; t++)
            if (vox[t] == vox[s] && seeds[t].piece != seeds[s].piece)
                return fn_err_set(FN_EINVAL, "separate: the seeds (%.1f, %.1f, %.1f) and (%.1f, %.1f, %.1f) mm "
                                  "fall in one voxel but name different pieces (%d and %d)", seeds[t].at[0],
                                  seeds[t].at[1], seeds[t].at[2], seeds[s].at[0], seeds[s].at[1], seeds[s].at[2],
                                  seeds[t].piece, seeds[s].piece);
        if ((rc = take_seed_bone(c, id, &seeds[s], vox[s], kind)) < 0)
            return rc;
    }
    return 0;
}

int case_separate_seeds(planning_case *c, int id, const case_seed *seeds, int n, int *new_ids)
{
    int rc = need(c, id);
    if (rc < 0)
        return rc;
    if (n < 1)
        return fn_err_set(FN_EINVAL, "separate: no seed given");
    size_t *vox = malloc((size_t)n * sizeof *vox);
    if (!vox)
        return fn_err_set(FN_ENOMEM, "separate: out of memory");
    rc = place_seeds(c, id, seeds, n, vox);
    int lo[3], dim[3];
    uint8_t *m = rc == 0 ? id_mask(c, id, lo, dim) : NULL;
    size_t nb = m ? (size_t)dim[0] * dim[1] * dim[2] : 0;
    float *hu = m ? box_values(c, m, lo, dim) : NULL;
    int32_t *lab = m ? malloc(nb * sizeof *lab) : NULL;
    if (rc == 0 && (!hu || !lab))
        rc = fn_err_set(FN_ENOMEM, "separate: out of memory for fragment %d's box", id);
    grow *g = rc == 0 ? grow_new(hu, m, dim, c->labels->spacing) : NULL;
    if (rc == 0 && !g)
        rc = FN_ENOMEM;
    int pieces = 0;
    for (int s = 0; rc == 0 && s < n; s++) {
        size_t at = vox[s], i = at % (size_t)c->labels->dim[0], j = at / (size_t)c->labels->dim[0] %
                    (size_t)c->labels->dim[1], k = at / ((size_t)c->labels->dim[0] * c->labels->dim[1]);
        size_t b = ((k - (size_t)lo[2]) * (size_t)dim[1] + (j - (size_t)lo[1])) * (size_t)dim[0] + (i - (size_t)lo[0]);
        if (c->labels->data[at] != (float)id)
            continue; /* a not-bone seed outside the fragment: nothing to take away there */
        rc = grow_add_seed(g, b, seeds[s].piece ? seeds[s].piece : GROW_MAX_LABEL);
        pieces = seeds[s].piece > pieces ? seeds[s].piece : pieces;
    }
    if (rc == 0)
        rc = grow_run(g);
    if (rc == 0) {
        const uint8_t *won = grow_labels(g);
        for (size_t b = 0; b < nb; b++)
            lab[b] = won[b] == GROW_MAX_LABEL ? -1 : won[b];
        rc = store_pieces(c, id, lab, lo, dim, pieces, new_ids);
    }
    grow_free(g);
    free(vox);
    free(m);
    free(hu);
    free(lab);
    return rc;
}

/* One field of a seed line: a finite number. */
static int seed_number(const char **p, double *out)
{
    char *end;
    *out = strtod(*p, &end);
    if (end == *p || !isfinite(*out))
        return 0;
    *p = end;
    return 1;
}

int case_seeds_parse(const char *text, const char *name, case_seed **out)
{
    *out = NULL;
    int n = 0, cap = 0, line = 0;
    for (const char *p = text; *p;) {
        const char *eol = strchr(p, '\n'), *next = eol ? eol + 1 : p + strlen(p);
        char buf[512];
        size_t len = (size_t)(next - p);
        line++;
        if (len >= sizeof buf) {
            free(*out);
            *out = NULL;
            return fn_err_set(FN_EFORMAT, "%s: line %d: longer than %zu bytes", name, line, sizeof buf - 1);
        }
        memcpy(buf, p, len);
        buf[len] = '\0';
        p = next;
        char *hash = strchr(buf, '#');
        if (hash)
            *hash = '\0';
        const char *q = buf + strspn(buf, " \t\r\n");
        if (!*q)
            continue;
        case_seed s;
        double piece;
        int ok = 1;
        if (!strncmp(q, "none", 4) && strchr(" \t", q[4])) {
            s.piece = 0;
            q += 4;
        } else if ((ok = seed_number(&q, &piece) && piece >= 1 && piece < GROW_MAX_LABEL && piece == floor(piece)))
            s.piece = (int)piece;
        for (int a = 0; ok && a < 3; a++)
            ok = seed_number(&q, &s.at[a]);
        if (!ok || q[strspn(q, " \t\r\n")]) {
            buf[strcspn(buf, "\r\n")] = '\0'; /* the line as written, without its end */
            free(*out);
            *out = NULL;
            return fn_err_set(FN_EFORMAT, "%s: line %d: expected PIECE X Y Z (PIECE 1..%d or none, world LPS "
                              "mm), got '%.60s'", name, line, GROW_MAX_LABEL - 1, buf + strspn(buf, " \t"));
        }
        if (n == cap) {
            cap = cap ? 2 * cap : 16;
            case_seed *m = cap <= 1 << 20 ? realloc(*out, (size_t)cap * sizeof *m) : NULL;
            if (!m) {
                free(*out);
                *out = NULL;
                return fn_err_set(FN_ENOMEM, "%s: line %d: too many seeds", name, line);
            }
            *out = m;
        }
        (*out)[n++] = s;
    }
    if (!n)
        return fn_err_set(FN_EFORMAT, "%s: no seed in the file (lines of PIECE X Y Z)", name);
    return n;
}

/* The pieces ids[0..n-1] over their joint box: lab gets i + 1 on ids[i]'s voxels, m the mask of
 * them all, hu the CT there (0 elsewhere). 0 or FN_ENOMEM. */
static int pieces_box(const planning_case *c, const int *ids, int n, int lo[3], int dim[3], int32_t **lab,
                      uint8_t **m, float **hu)
{
    int hi[3];
    for (int i = 0; i < n; i++) {
        int l[3], h[3];
        if (frag_label_box(c->labels, ids[i], l, h) < 0)
            return FN_EFORMAT;
        for (int a = 0; a < 3; a++) {
            lo[a] = i == 0 || l[a] < lo[a] ? l[a] : lo[a];
            hi[a] = i == 0 || h[a] > hi[a] ? h[a] : hi[a];
        }
    }
    size_t nv = 1;
    for (int a = 0; a < 3; a++) /* one voxel more on every side, as id_mask */
        nv *= (size_t)(dim[a] = hi[a] - --lo[a] + 2);
    *lab = malloc(nv * sizeof **lab);
    *m = malloc(nv);
    *hu = malloc(nv * sizeof **hu);
    if (!*lab || !*m || !*hu)
        return fn_err_set(FN_ENOMEM, "separate: out of memory for a box of %zu voxels", nv);
    size_t b = 0;
    for (int k = 0; k < dim[2]; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++, b++) {
                int s[3] = {lo[0] + i, lo[1] + j, lo[2] + k};
                int in = s[0] >= 0 && s[1] >= 0 && s[2] >= 0 && s[0] < c->labels->dim[0] &&
                         s[1] < c->labels->dim[1] && s[2] < c->labels->dim[2];
                size_t v = in ? vol_idx(c->labels, s[0], s[1], s[2]) : 0;
                (*lab)[b] = 0;
                for (int p = 0; in && p < n; p++)
                    (*lab)[b] = c->labels->data[v] == (float)ids[p] ? p + 1 : (*lab)[b];
                (*m)[b] = (*lab)[b] > 0;
                (*hu)[b] = (*m)[b] ? c->ct->data[vol_idx(c->ct, s[0], s[1], s[2])] : 0;
            }
    return 0;
}

/* case_separate_auto on fragment id, then on each of its pieces, until none splits; then the
 * pieces whose cut alone is no break are joined again (split_rejoin). Returns the new fragments
 * left. */
static int separate_auto_all(planning_case *c, int id)
{
    int todo[GROW_MAX_LABEL], ntodo = 0, made = 0, news[2], ids[GROW_MAX_LABEL] = {id};
    todo[ntodo++] = id;
    while (ntodo > 0) {
        int at = todo[--ntodo], rc = case_separate_auto(c, at, news);
        if (rc < 0)
            return rc;
        for (int i = 0; i < rc && ntodo + 2 <= GROW_MAX_LABEL && made + 1 < GROW_MAX_LABEL - 1; i++) {
            todo[ntodo++] = at;
            todo[ntodo++] = news[i];
            ids[++made] = news[i];
        }
    }
    if (made < 2)
        return made;
    int lo[3], dim[3], join[GROW_MAX_LABEL + 1], joined = 0;
    int32_t *lab = NULL;
    uint8_t *m = NULL;
    float *hu = NULL;
    int rc = pieces_box(c, ids, made + 1, lo, dim, &lab, &m, &hu);
    if (rc == 0)
        rc = split_rejoin(hu, m, dim, c->labels->spacing, lab, made + 1, join);
    for (int p = 1; rc == 0 && p <= made + 1; p++)
        if (join[p] != p && (rc = case_merge(c, ids[join[p] - 1], ids[p - 1])) == 0)
            joined++;
    free(lab);
    free(m);
    free(hu);
    return rc < 0 ? rc : made - joined;
}

int case_separate_all(planning_case *c, const case_seed *seeds, int n)
{
    int made = 0, nfrag = c->nfrag, *ids = malloc(((size_t)nfrag + 1) * sizeof *ids), news[GROW_MAX_LABEL];
    case_seed *group = malloc(((size_t)n + 1) * sizeof *group);
    if (!ids || !group) {
        free(ids);
        free(group);
        return fn_err_set(FN_ENOMEM, "separate: out of memory");
    }
    for (int f = 0; f < nfrag; f++)
        ids[f] = c->frag[f].id;
    int rc = 0, biggest = 0;
    for (int f = 1; f < nfrag; f++)
        if (c->frag[f].voxels > c->frag[biggest].voxels)
            biggest = f;
    for (int s = 0; s < n && rc == 0; s++) {
        int v[3];
        rc = seed_voxel(c, &seeds[s], v);
    }
    for (int f = 0; f < nfrag && rc >= 0; f++) {
        int m = 0;
        /* Each seed goes to the fragment it lies in; one on no fragment to the largest, which grows
         * over the bone there (or says why it cannot). */
        for (int s = 0; s < n; s++) {
            int v[3];
            seed_voxel(c, &seeds[s], v);
            float l = c->labels->data[vol_idx(c->labels, v[0], v[1], v[2])];
            if (l == (float)ids[f] || (l == 0 && f == biggest))
                group[m++] = seeds[s];
        }
        if (n == 0)
            rc = separate_auto_all(c, ids[f]);
        else if (m > 0)
            rc = case_separate_seeds(c, ids[f], group, m, news);
        made += rc > 0 ? rc : 0;
    }
    free(ids);
    free(group);
    return rc < 0 ? rc : made;
}

/* ---- the seeded separation's live preview ---------------------------------------------- */

/* One fragment with seeds: its box, its growth, and the pieces it grew into. */
typedef struct preview_part {
    int lo[3], dim[3];
    uint8_t *m;     /* id_mask */
    float *hu;      /* box_values */
    grow *g;
    vol *won, *ct;  /* the box's labels as grown and its CT, on the box's grid (lo its first voxel) */
    frag *pieces;   /* per piece label 1..GROW_MAX_LABEL - 1 that won voxels, the largest first */
    int npieces, dirty;
} preview_part;

struct case_preview {
    const planning_case *c;
    bone_kind kind;     /* c's CT's (bone_kind_of): what a seed off every fragment lies on */
    preview_part *part; /* per fragment index; part[i].m NULL: no seed there yet */
    case_seed *seeds;   /* those grown so far */
    int nseeds, cap;
    frag *out;          /* the fragments shown: pieces and shallow copies of the others */
};

case_preview *case_preview_new(const planning_case *c)
{
    case_preview *p = calloc(1, sizeof *p);
    if (p) {
        p->c = c;
        p->kind = bone_kind_of(c->ct);
        p->part = calloc((size_t)c->nfrag + 1, sizeof *p->part);
        p->out = malloc(((size_t)c->nfrag * GROW_MAX_LABEL + 1) * sizeof *p->out);
    }
    if (!p || !p->part || !p->out) {
        case_preview_free(p);
        fn_err_set(FN_ENOMEM, "separate: out of memory for the preview");
        return NULL;
    }
    return p;
}

static void part_pieces_free(preview_part *t)
{
    for (int i = 0; i < t->npieces; i++)
        frag_free(&t->pieces[i]);
    free(t->pieces);
    t->pieces = NULL;
    t->npieces = 0;
}

void case_preview_free(case_preview *p)
{
    if (!p)
        return;
    for (int i = 0; p->part && i < p->c->nfrag; i++) {
        preview_part *t = &p->part[i];
        part_pieces_free(t);
        grow_free(t->g);
        free(t->m);
        free(t->hu);
        vol_free(t->won);
        vol_free(t->ct);
    }
    free(p->part);
    free(p->seeds);
    free(p->out);
    free(p);
}

/* A vol over the box of t on c's grid, values filled by the caller. */
static vol *box_vol(const planning_case *c, const preview_part *t)
{
    vol *v = vol_new(t->dim[0], t->dim[1], t->dim[2]);
    if (!v)
        return NULL;
    memcpy(v->spacing, c->labels->spacing, sizeof v->spacing);
    memcpy(v->affine, c->labels->affine, sizeof v->affine);
    for (int r = 0; r < 3; r++)
        for (int a = 0; a < 3; a++)
            v->affine[r][3] += c->labels->affine[r][a] * t->lo[a];
    return v;
}

/* Fragment index f's box, mask, values and growth, made at its first seed. */
static int part_open(const planning_case *c, preview_part *t, int f)
{
    t->m = id_mask(c, c->frag[f].id, t->lo, t->dim);
    t->hu = t->m ? box_values(c, t->m, t->lo, t->dim) : NULL;
    t->g = t->hu ? grow_new(t->hu, t->m, t->dim, c->labels->spacing) : NULL;
    t->won = t->g ? box_vol(c, t) : NULL;
    t->ct = t->won ? box_vol(c, t) : NULL;
    if (!t->ct)
        return fn_err_set(FN_ENOMEM, "separate: out of memory for fragment %d's preview", c->frag[f].id);
    for (int k = 0; k < t->dim[2]; k++)
        for (int j = 0; j < t->dim[1]; j++)
            for (int i = 0; i < t->dim[0]; i++) {
                int s[3] = {t->lo[0] + i, t->lo[1] + j, t->lo[2] + k}, in = 1;
                for (int a = 0; a < 3; a++)
                    in &= s[a] >= 0 && s[a] < c->ct->dim[a];
                t->ct->data[vol_idx(t->ct, i, j, k)] = in ? c->ct->data[vol_idx(c->ct, s[0], s[1], s[2])] : 0;
            }
    return 0;
}

/* The pieces of t after its growth: one fragment per piece label that won voxels, the largest
 * first. */
static int part_pieces(const planning_case *c, preview_part *t)
{
    part_pieces_free(t);
    const uint8_t *won = grow_labels(t->g);
    size_t n = vol_count(t->won), count[GROW_MAX_LABEL + 1] = {0};
    for (size_t v = 0; v < n; v++) {
        t->won->data[v] = won[v];
        count[won[v]]++;
    }
    t->pieces = calloc(GROW_MAX_LABEL, sizeof *t->pieces);
    if (!t->pieces)
        return fn_err_set(FN_ENOMEM, "separate: out of memory for the preview");
    int keep = 1;
    for (int l = 2; l < GROW_MAX_LABEL; l++)
        keep = count[l] > count[keep] ? l : keep;
    for (int k = 0; k < GROW_MAX_LABEL; k++) {
        int l = k == 0 ? keep : k, lo[3], hi[3];
        if ((k > 0 && l == keep) || !count[l] || frag_label_box(t->won, l, lo, hi) < 0)
            continue;
        frag *f = &t->pieces[t->npieces];
        int rc = frag_from_labels(f, t->won, t->ct, l, lo, hi, c->seg.threshold, c->seg.ramp);
        if (rc < 0)
            return rc;
        t->npieces++;
        for (int a = 0; a < 3; a++)
            f->origin[a] += t->lo[a];
    }
    return 0;
}

int case_preview_update(case_preview *p, const pose *poses, const case_seed *seeds, int n, const frag **shown)
{
    const planning_case *c = p->c;
    int grown = n >= p->nseeds && (p->nseeds == 0 || !memcmp(seeds, p->seeds, (size_t)p->nseeds * sizeof *seeds))
                    ? p->nseeds : 0;
    if (n > p->cap) {
        case_seed *more = realloc(p->seeds, (size_t)n * sizeof *more);
        if (!more)
            return fn_err_set(FN_ENOMEM, "separate: out of memory for the preview's seeds");
        p->seeds = more;
        p->cap = n;
    }
    if (!grown)
        for (int i = 0; i < c->nfrag; i++) {
            if (p->part[i].g)
                grow_clear(p->part[i].g);
            part_pieces_free(&p->part[i]);
        }
    int rc = 0;
    for (int s = grown; s < n && rc == 0; s++) {
        int v[3];
        if ((rc = seed_voxel(c, &seeds[s], v)) < 0)
            break;
        float l = c->labels->data[vol_idx(c->labels, v[0], v[1], v[2])];
        int f = l > 0 ? case_find(c, (int)l) : -1;
        if (f < 0 && seeds[s].piece >= 1 && (rc = seed_on_bone(c, &seeds[s], vol_idx(c->labels, v[0], v[1], v[2]),
                                                              p->kind, 0)) < 0)
            break; /* not bone: Enter refuses it so too */
        if (f < 0 || seeds[s].piece < 1 || seeds[s].piece >= GROW_MAX_LABEL) {
            rc = fn_err_set(FN_EINVAL, "separate: the seed (%.1f, %.1f, %.1f) mm is %s", seeds[s].at[0],
                            seeds[s].at[1], seeds[s].at[2],
                            f < 0 ? "on no fragment, on bone the mask missed (Enter grows the fragment to it)"
                                  : "of no piece 1..254");
            break;
        }
        preview_part *t = &p->part[f];
        if (!t->m && (rc = part_open(c, t, f)) < 0)
            break;
        size_t b = ((size_t)(v[2] - t->lo[2]) * t->dim[1] + (size_t)(v[1] - t->lo[1])) * t->dim[0] +
                   (size_t)(v[0] - t->lo[0]);
        if (grow_add_seed(t->g, b, seeds[s].piece) < 0)
            rc = fn_err_set(FN_EINVAL, "separate: the seed (%.1f, %.1f, %.1f) mm falls in the voxel of a seed of "
                            "another piece", seeds[s].at[0], seeds[s].at[1], seeds[s].at[2]);
        t->dirty = 1;
    }
    int m = 0, next = next_free_id(c);
    for (int i = 0; i < c->nfrag && rc == 0; i++) {
        preview_part *t = &p->part[i];
        const pose *at = poses ? &poses[i] : &c->frag[i].pose;
        if (t->dirty && (rc = grow_run(t->g)) == 0)
            rc = part_pieces(c, t);
        t->dirty = 0;
        if (!t->npieces) { /* shallow: shown, never freed here; its pose (the last member, which a
                            * session's save may be writing) not read */
            memcpy(&p->out[m], &c->frag[i], offsetof(frag, pose));
            p->out[m++].pose = *at;
        }
        for (int k = 0; k < t->npieces; k++) {
            frag *f = &t->pieces[k];
            f->id = k == 0 ? c->frag[i].id : next++;
            frag_colour(f->id, f->rgb);
            f->pose = *at; /* placed as the fragment it comes from */
            p->out[m++] = *f;
        }
    }
    if (rc < 0) { /* a bad seed: the next update starts anew */
        p->nseeds = 0;
        return rc;
    }
    memcpy(p->seeds, seeds, (size_t)n * sizeof *seeds);
    p->nseeds = n;
    *shown = p->out;
    return m;
}

int case_separate_auto(planning_case *c, int id, int *new_ids)
{
    int rc = need(c, id);
    if (rc < 0)
        return rc;
    int lo[3], dim[3];
    uint8_t *m = id_mask(c, id, lo, dim);
    float *hu = m ? box_values(c, m, lo, dim) : NULL;
    int32_t *lab = hu ? malloc((size_t)dim[0] * dim[1] * dim[2] * sizeof *lab) : NULL;
    if (!lab)
        rc = fn_err_set(FN_ENOMEM, "separate: out of memory for fragment %d's box", id);
    int pieces = rc == 0 ? split_auto(hu, m, dim, c->labels->spacing, lab) : rc;
    rc = pieces < 2 ? (pieces < 0 ? pieces : 0) : store_pieces(c, id, lab, lo, dim, pieces, new_ids);
    free(m);
    free(hu);
    free(lab);
    return rc;
}
