#include "case.h"

#include "durable.h"
#include "err.h"
#include "obb.h"

#include <errno.h>
#include <fcntl.h>
#include <jansson.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define LABEL_MAX 65535

/* ---- fragments ---- */

int case_find(const planning_case *c, int id)
{
    for (int i = 0; i < c->nfrag; i++)
        if (c->frag[i].id == id)
            return i;
    return -1;
}

#define OVERLAP_SAMPLES 3 /* per axis and voxel */

/* Index of b's voxel holding sample point x (continuous index); -1 outside b's crop. */
static long voxel_at(const frag *b, const double x[3])
{
    long l[3];
    for (int i = 0; i < 3; i++) {
        l[i] = lround(x[i]);
        if (l[i] < 0 || l[i] >= b->dim[i])
            return -1;
    }
    return (l[2] * b->dim[1] + l[1]) * (long)b->dim[0] + l[0];
}

/* A's voxel index -> B's continuous voxel index at their poses (G, 3x4), and how far (in B's voxels)
 * a point of one of A's voxels can lie from its centre's image (*reach, at least 1). */
static void index_map(const frag *A, const frag *B, double G[3][4], double *reach)
{
    pose wa = pose_compose(A->pose, A->home), wb = pose_compose(B->pose, B->home);
    pose rel = pose_compose(pose_inverse(wb), wa); /* a's local mm -> b's local mm */
    double R[3][3];
    pose_to_matrix(&rel, R);
    for (int i = 0; i < 3; i++) {
        for (int k = 0; k < 3; k++)
            G[i][k] = R[i][k] * A->spacing[k] / B->spacing[i];
        G[i][3] = rel.t[i] / B->spacing[i];
    }
    *reach = 1;
    for (int i = 0; i < 3; i++)
        *reach = fmax(*reach, 0.5 * (fabs(G[i][0]) + fabs(G[i][1]) + fabs(G[i][2])) + 1);
}

/* The box [lo, hi] of A's voxel indices whose voxels can reach into B's crop at their poses: B's box
 * widened by reach, its corners taken back into A's indices, clipped to A's crop. 0 when empty. */
static int reach_box(const frag *A, const frag *B, int lo[3], int hi[3])
{
    double G[3][4], reach;
    index_map(A, B, G, &reach);
    pose wa = pose_compose(A->pose, A->home), wb = pose_compose(B->pose, B->home);
    pose back = pose_compose(pose_inverse(wa), wb); /* b's local mm -> a's local mm */
    double Ri[3][3];
    pose_to_matrix(&back, Ri);
    for (int i = 0; i < 3; i++) {
        lo[i] = A->dim[i];
        hi[i] = -1;
    }
    for (int corner = 0; corner < 8; corner++) {
        double bmm[3];
        for (int r = 0; r < 3; r++)
            bmm[r] = ((corner >> r & 1) ? B->dim[r] - 1 + reach : -reach) * B->spacing[r];
        for (int i = 0; i < 3; i++) {
            double x = (Ri[i][0] * bmm[0] + Ri[i][1] * bmm[1] + Ri[i][2] * bmm[2] + back.t[i]) / A->spacing[i];
            int f = (int)fmax(-1, fmin(A->dim[i], floor(x))), e = (int)fmax(-1, fmin(A->dim[i], ceil(x)));
            lo[i] = f < lo[i] ? f : lo[i];
            hi[i] = e > hi[i] ? e : hi[i];
        }
    }
    int some = 1;
    for (int i = 0; i < 3; i++) {
        lo[i] = lo[i] < 0 ? 0 : lo[i];
        hi[i] = hi[i] > A->dim[i] - 1 ? A->dim[i] - 1 : hi[i];
        some &= lo[i] <= hi[i];
    }
    return some;
}

/* Per voxel of f: 1 when a voxel that solid[] counts lies within rad cells along every axis (a box
 * dilation, one axis at a time by running counts). malloc'd; NULL when out of memory. */
static uint8_t *solid_near(const frag *f, const uint8_t solid[256], int rad)
{
    const int *d = f->dim;
    size_t n = (size_t)d[0] * d[1] * d[2];
    uint8_t *v = malloc(n), *t = malloc(n);
    if (!v || !t) {
        free(v);
        free(t);
        return NULL;
    }
    for (size_t q = 0; q < n; q++)
        v[q] = solid[f->prob[q]];
    size_t stride = 1;
    for (int a = 0; a < 3; a++) { /* along axis a: t[x] = any v within rad of x on its line */
        size_t len = (size_t)d[a], lines = n / len;
        for (size_t l = 0; l < lines; l++) {
            size_t base = l % stride + l / stride * stride * len; /* the line's first element */
            int count = 0;
            for (size_t x = 0; x < len + (size_t)rad; x++) {
                if (x < len)
                    count += v[base + x * stride];
                if (x >= (size_t)(2 * rad + 1))
                    count -= v[base + (x - 2 * (size_t)rad - 1) * stride];
                if (x >= (size_t)rad)
                    t[base + (x - (size_t)rad) * stride] = count > 0;
            }
        }
        uint8_t *sw = v;
        v = t;
        t = sw;
        stride *= len;
    }
    free(t);
    return v;
}

double case_overlap_ml(const planning_case *c, int a, int b)
{
    const frag *A = &c->frag[a], *B = &c->frag[b];
    obb_params op = {c->tau_min, c->tau_max};
    double G[3][4], reach; /* a's voxel index -> b's continuous voxel index */
    index_map(A, B, G, &reach);
    /* Only a's voxels whose centres land in b's box widened by reach can count (reach_box). */
    int lo[3], hi[3];
    if (!reach_box(A, B, lo, hi))
        return 0;
    uint8_t solid[256]; /* obb_effective_prob(p) != 0, by table */
    for (int v = 0; v < 256; v++)
        solid[v] = obb_effective_prob((uint8_t)v, &op) != 0;
    /* near[q]: some solid voxel of b within rad cells (a box) of b's cell q. A sample lies within
     * reach of its voxel centre's image, and lands in the b voxel nearest it: within reach + 1 cells
     * of the b cell nearest that centre. An a voxel whose nearest cell has none is skipped (NULL
     * near, out of memory: none is). */
    int rad = (int)ceil(reach) + 1;
    uint8_t *near_b = solid_near(B, solid, rad);
    long hits = 0;
    for (int k = lo[2]; k <= hi[2]; k++)
        for (int j = lo[1]; j <= hi[1]; j++)
            for (int i = lo[0]; i <= hi[0]; i++) {
                uint8_t p = A->prob[((size_t)k * (size_t)A->dim[1] + (size_t)j) * (size_t)A->dim[0] + (size_t)i];
                if (!solid[p])
                    continue;
                double ctr[3];
                int near = 1;
                for (int r = 0; r < 3; r++) {
                    ctr[r] = G[r][0] * i + G[r][1] * j + G[r][2] * k + G[r][3];
                    near &= ctr[r] > -reach && ctr[r] < B->dim[r] - 1 + reach;
                }
                if (!near)
                    continue;
                if (near_b) {
                    long q = voxel_at(B, ctr);
                    if (q >= 0 && !near_b[q])
                        continue;
                }
                for (int s = 0; s < OVERLAP_SAMPLES * OVERLAP_SAMPLES * OVERLAP_SAMPLES; s++) {
                    double o[3] = {s % OVERLAP_SAMPLES, s / OVERLAP_SAMPLES % OVERLAP_SAMPLES,
                                   s / (OVERLAP_SAMPLES * OVERLAP_SAMPLES)}, x[3];
                    for (int q = 0; q < 3; q++)
                        o[q] = (o[q] + 0.5) / OVERLAP_SAMPLES - 0.5;
                    for (int r = 0; r < 3; r++)
                        x[r] = ctr[r] + G[r][0] * o[0] + G[r][1] * o[1] + G[r][2] * o[2];
                    long v = voxel_at(B, x);
                    hits += v >= 0 && solid[B->prob[v]];
                }
            }
    free(near_b);
    double voxel_ml = A->spacing[0] * A->spacing[1] * A->spacing[2] * 1e-3;
    return (double)hits * voxel_ml / (OVERLAP_SAMPLES * OVERLAP_SAMPLES * OVERLAP_SAMPLES);
}

/* The part of f in its index box [lo, hi] as a fragment of its own (dim, spacing, name and prob: what
 * a hierarchy is built from) into *s, and its local mm -> world pose (f's shifted by lo) into *w.
 * 0 or FN_ENOMEM. */
static int sub_crop(const frag *f, const int lo[3], const int hi[3], frag *s, pose *w)
{
    memset(s, 0, sizeof *s);
    s->id = f->id;
    snprintf(s->name, sizeof s->name, "%s", f->name);
    size_t n = 1;
    for (int a = 0; a < 3; a++) {
        s->dim[a] = hi[a] - lo[a] + 1;
        s->spacing[a] = f->spacing[a];
        n *= (size_t)s->dim[a];
    }
    if (!(s->prob = malloc(n)))
        return fn_err_set(FN_ENOMEM, "out of memory for the overlap check of fragment %d", f->id);
    for (int k = 0; k < s->dim[2]; k++)
        for (int j = 0; j < s->dim[1]; j++)
            memcpy(s->prob + ((size_t)k * s->dim[1] + j) * s->dim[0],
                   f->prob + ((size_t)(k + lo[2]) * f->dim[1] + (size_t)(j + lo[1])) * f->dim[0] + lo[0],
                   (size_t)s->dim[0]);
    pose shift = POSE_IDENTITY;
    for (int a = 0; a < 3; a++)
        shift.t[a] = lo[a] * f->spacing[a];
    *w = pose_compose(pose_compose(f->pose, f->home), shift);
    return 0;
}

/* Whether fragments a and b interpenetrate at their poses (obb_collide at tolerance 0), over the
 * parts of each that can reach into the other's crop (reach_box): after a fit the pieces touch
 * along a fracture, and hierarchies of those parts cost a fraction of the whole fragments'. 1, 0
 * or FN_E*. */
static int pair_collides(const planning_case *c, int a, int b)
{
    const frag *A = &c->frag[a], *B = &c->frag[b];
    int la[3], ha[3], lb[3], hb[3];
    if (!reach_box(A, B, la, ha) || !reach_box(B, A, lb, hb))
        return 0;
    obb_params op = {c->tau_min, c->tau_max};
    frag sa, sb;
    pose wa, wb;
    int rc = sub_crop(A, la, ha, &sa, &wa);
    if (rc == 0 && (rc = sub_crop(B, lb, hb, &sb, &wb)) < 0)
        free(sa.prob);
    if (rc < 0)
        return rc;
    obb_tree *ta = obb_tree_build(&sa, &op), *tb = ta ? obb_tree_build(&sb, &op) : NULL;
    obb_result r;
    if (!ta || !tb)
        rc = fn_err_wrap(FN_EFORMAT, "fragments %d and %d", A->id, B->id);
    else if ((rc = obb_collide(ta, &wa, tb, &wb, NULL, NULL, &r)) == 0)
        rc = r.collides != 0;
    obb_tree_free(ta);
    obb_tree_free(tb);
    free(sa.prob);
    free(sb.prob);
    return rc;
}

int case_penetrating(const planning_case *c, const uint8_t *fitted, case_overlap *out, int max)
{
    int rc = 0, n = 0;
    for (int a = 0; rc == 0 && a < c->nfrag; a++)
        for (int b = a + 1; rc == 0 && b < c->nfrag; b++) {
            int hit = pair_collides(c, a, b);
            if (hit <= 0) {
                rc = hit;
                continue;
            }
            if (out && n < max)
                out[n] = (case_overlap){a, b, case_overlap_ml(c, a, b), fitted && (fitted[a] || fitted[b])};
            n++;
        }
    return rc < 0 ? rc : n;
}

int case_record_penetrating(planning_case *c, const case_overlap *o, int n)
{
    json_t *list = json_array();
    if (!c->extra)
        c->extra = json_object();
    for (int k = 0; list && k < n; k++)
        json_array_append_new(list, json_pack("{s:[i,i],s:f,s:b}", "fragments", c->frag[o[k].a].id,
                                              c->frag[o[k].b].id, "overlap_ml", o[k].ml,
                                              "within_fit_tolerance", o[k].fitted));
    if (!list || !c->extra || (n ? json_object_set(c->extra, "penetrating", list) : 0) != 0) {
        json_decref(list);
        return fn_err_set(FN_ENOMEM, "out of memory for case.json's penetrating");
    }
    if (!n)
        json_object_del(c->extra, "penetrating");
    json_decref(list);
    return 0;
}

int case_is_fixed(const planning_case *c, int i)
{
    if (i < 0 || i >= c->nfrag)
        return 0;
    int fixed = i == c->fixed;
    for (int k = 0; k < c->nfixed_also && !fixed; k++)
        fixed = c->fixed_also[k] == c->frag[i].id;
    return fixed;
}

void case_set_fixed(planning_case *c, const uint8_t *fixed)
{
    if (c->fixed < 0 || c->fixed >= c->nfrag || !fixed[c->fixed]) {
        c->fixed = -1;
        for (int i = 0; i < c->nfrag && c->fixed < 0; i++)
            if (fixed[i])
                c->fixed = i;
    }
    c->nfixed_also = 0;
    for (int i = 0; i < c->nfrag && c->nfixed_also < CASE_FIXED_MAX; i++)
        if (fixed[i] && i != c->fixed)
            c->fixed_also[c->nfixed_also++] = c->frag[i].id;
}

/* One pass over the labels: each voxel a whole number 0..LABEL_MAX (else FN_EFORMAT naming the
 * voxel), and the bounding box of every label 1..LABEL_MAX (lo/hi have LABEL_MAX+1 rows; hi[l][0]
 * < 0 = absent). The background is most of a CT: it costs one comparison a voxel. */
static int label_boxes(const vol *labels, int (*lo)[3], int (*hi)[3])
{
    for (int l = 0; l <= LABEL_MAX; l++)
        for (int a = 0; a < 3; a++) {
            lo[l][a] = INT_MAX;
            hi[l][a] = -1;
        }
    const float *v = labels->data;
    for (int k = 0; k < labels->dim[2]; k++)
        for (int j = 0; j < labels->dim[1]; j++, v += labels->dim[0])
            for (int i = 0; i < labels->dim[0]; i++) {
                if (v[i] == 0)
                    continue;
                int l = v[i] > 0 && v[i] <= LABEL_MAX ? (int)v[i] : -1;
                if (l < 0 || (float)l != v[i])
                    return fn_err_set(FN_EFORMAT, "labels: voxel (%d,%d,%d) holds %g, not a label 0..%d", i, j,
                                      k, (double)v[i], LABEL_MAX);
                int ijk[3] = {i, j, k};
                for (int a = 0; a < 3; a++) {
                    if (ijk[a] < lo[l][a])
                        lo[l][a] = ijk[a];
                    if (ijk[a] > hi[l][a])
                        hi[l][a] = ijk[a];
                }
            }
    return 0;
}

static void inherit(frag *f, pose *truth, const planning_case *old, int from_id, int keep_looks)
{
    int i = case_find(old, from_id);
    if (i < 0)
        return;
    f->pose = old->frag[i].pose;
    if (keep_looks) {
        memcpy(f->name, old->frag[i].name, sizeof f->name);
        memcpy(f->rgb, old->frag[i].rgb, sizeof f->rgb);
    }
    if (old->has_truth)
        *truth = old->truth[i];
}

int case_rebuild(planning_case *c, int new_id, int parent_id)
{
    int rc = 0;
    int(*lo)[3] = malloc((LABEL_MAX + 1) * sizeof *lo);
    int(*hi)[3] = malloc((LABEL_MAX + 1) * sizeof *hi);
    frag *nf = NULL;
    pose *nt = NULL;
    if (!lo || !hi) {
        rc = fn_err_set(FN_ENOMEM, "case: out of memory");
        goto done;
    }
    if ((rc = label_boxes(c->labels, lo, hi)) < 0)
        goto done;
    int n = 0;
    for (int l = 1; l <= LABEL_MAX; l++)
        n += hi[l][0] >= 0;
    nf = calloc(n ? (size_t)n : 1, sizeof *nf);
    nt = calloc(n ? (size_t)n : 1, sizeof *nt);
    if (!nf || !nt) {
        rc = fn_err_set(FN_ENOMEM, "case: out of memory for %d fragments", n);
        goto done;
    }
    int fixed_id = c->fixed >= 0 && c->fixed < c->nfrag ? c->frag[c->fixed].id : -1, built = 0;
    for (int l = 1; l <= LABEL_MAX && rc == 0; l++) {
        if (hi[l][0] < 0)
            continue;
        rc = frag_from_labels(&nf[built], c->labels, c->ct, l, lo[l], hi[l], c->seg.threshold,
                              c->seg.ramp);
        if (rc < 0)
            break;
        nt[built] = POSE_IDENTITY;
        if (l == new_id)
            inherit(&nf[built], &nt[built], c, parent_id, 0);
        else
            inherit(&nf[built], &nt[built], c, l, 1);
        built++;
    }
    if (rc < 0) {
        for (int i = 0; i < built; i++)
            frag_free(&nf[i]);
        goto done;
    }
    for (int i = 0; i < c->nfrag; i++)
        frag_free(&c->frag[i]);
    free(c->frag);
    free(c->truth);
    c->frag = nf;
    c->truth = nt;
    c->nfrag = n;
    nf = NULL;
    nt = NULL;
    c->fixed = case_find(c, fixed_id);
    int kept = 0; /* fixed ids that vanished go */
    for (int k = 0; k < c->nfixed_also; k++)
        if (case_find(c, c->fixed_also[k]) >= 0)
            c->fixed_also[kept++] = c->fixed_also[k];
    c->nfixed_also = kept;
done:
    free(lo);
    free(hi);
    free(nf);
    free(nt);
    return rc;
}

planning_case *case_create(const char *dir, const char *source, vol *ct, vol *labels, const seg_params *sp)
{
    planning_case *c = calloc(1, sizeof *c);
    if (!c) {
        vol_free(ct);
        vol_free(labels);
        fn_err_set(FN_ENOMEM, "case: out of memory");
        return NULL;
    }
    c->ct = ct;
    c->labels = labels;
    c->fixed = -1;
    c->tau_min = CASE_TAU_MIN;
    c->tau_max = CASE_TAU_MAX;
    c->seg = *sp;
    if (strlen(dir) >= sizeof c->dir || strlen(source) >= sizeof c->source) {
        fn_err_set(FN_EINVAL, "case: folder or source path too long");
        case_free(c);
        return NULL;
    }
    strcpy(c->dir, dir);
    strcpy(c->source, source);
    for (int a = 0; a < 3; a++)
        if (ct->dim[a] != labels->dim[a]) {
            fn_err_set(FN_EINVAL, "case: labels are %dx%dx%d but %s is %dx%dx%d", labels->dim[0],
                       labels->dim[1], labels->dim[2], source, ct->dim[0], ct->dim[1], ct->dim[2]);
            case_free(c);
            return NULL;
        }
    if (durable_file_sha256(source, c->sha256) < 0 || case_rebuild(c, 0, 0) < 0) {
        case_free(c);
        return NULL;
    }
    return c;
}

void case_free(planning_case *c)
{
    if (!c)
        return;
    for (int i = 0; i < c->nfrag; i++)
        frag_free(&c->frag[i]);
    free(c->frag);
    free(c->truth);
    vol_free(c->ct);
    vol_free(c->labels);
    json_decref(c->extra);
    free(c);
}
