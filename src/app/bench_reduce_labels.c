/* fracnav bench reduce --labels: fits on real fracture surfaces. The fragments annotated by hand
 * (label k = fragment k, read as `segment CT --labels MASK` reads them) lie at their CT pose, where
 * they interlock exactly; each smaller fragment is moved off it as a hand would leave it and fitted
 * back as `reduce --fixed L --moving K --no-prealign` fits it (L: the largest fragment). */
#include "bench.h"

#include "case.h"
#include "err.h"
#include "fracture.h"
#include "jsonw.h"
#include "obb.h"
#include "reduce.h"
#include "seg.h"
#include "volio.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Fragments under this volume are chips of a comminuted edge, not pieces a surgeon reduces. */
#define MIN_PIECE_ML 1.0
/* The hand's starts: how far off the CT pose (the "as a hand would leave it"). */
static const double START_MM[2] = {3, 10}, START_DEG[2] = {5, 15};
/* The targets printed beside the pooled figures. */
#define TARGET_BACK_RATE 0.95
#define TARGET_MEDIAN_S 0.5

typedef struct fit {
    double rot, trans, tre, cpu_s; /* from the CT pose at the end; the fit's CPU seconds (every thread) */
    double start_rot, start_trans; /* the start's offset from the CT pose */
    double metric_ct, metric_end;  /* over the fit's final VOI, at the CT pose and at the end */
} fit;

typedef struct fits {
    fit *f;
    int n, cap;
} fits;

static int fits_add(fits *s, const fit *x)
{
    if (s->n == s->cap) {
        int cap = s->cap ? 2 * s->cap : 64;
        fit *f = realloc(s->f, (size_t)cap * sizeof *f);
        if (!f)
            return fn_err_set(FN_ENOMEM, "bench reduce: out of memory");
        s->f = f;
        s->cap = cap;
    }
    s->f[s->n++] = *x;
    return 0;
}

static int back(const fit *x)
{
    return x->rot <= 1 && x->trans <= 1;
}

/* The figures of fits s[0..n-1] into j. */
static void fits_json(json_t *j, const fits *s)
{
    int n = s->n, nback = 0, nfail = 0, ct_better = 0, farther = 0;
    double *v = malloc((size_t)(n ? n : 1) * sizeof *v);
    if (!v)
        return;
    for (int i = 0; i < n; i++) {
        nback += back(&s->f[i]);
        farther += s->f[i].trans > s->f[i].start_trans || s->f[i].rot > s->f[i].start_rot;
        if (!back(&s->f[i])) {
            nfail++;
            ct_better += s->f[i].metric_ct < s->f[i].metric_end;
        }
    }
    jsonw_set(j, "runs", json_integer(n));
    jsonw_set(j, "back_rate", jsonw_measure(n ? (double)nback / n : NAN));
#define STAT(key, field, q)                                                                        \
    do {                                                                                           \
        for (int i = 0; i < n; i++)                                                                \
            v[i] = s->f[i].field;                                                                  \
        jsonw_set(j, key, jsonw_measure(bench_quantile(v, n, q)));                                 \
    } while (0)
    STAT("median_rot_err_deg", rot, 0.5);
    STAT("p90_rot_err_deg", rot, 0.9);
    STAT("median_trans_err_mm", trans, 0.5);
    STAT("p90_trans_err_mm", trans, 0.9);
    STAT("median_tre_mm", tre, 0.5);
    STAT("median_seconds", cpu_s, 0.5);
    STAT("p90_seconds", cpu_s, 0.9);
    STAT("start_rot_min_deg", start_rot, 0);
    STAT("start_rot_max_deg", start_rot, 1);
    STAT("start_trans_min_mm", start_trans, 0);
    STAT("start_trans_max_mm", start_trans, 1);
#undef STAT
    /* Where a fit did not come back: is the CT pose better by the metric than where it ended (the
     * optimizer missed it) or worse (the metric's best lies elsewhere)? */
    for (int i = 0; i < n; i++)
        v[i] = s->f[i].metric_end - s->f[i].metric_ct;
    jsonw_set(j, "metric_end_minus_ct_median", jsonw_measure(bench_quantile(v, n, 0.5)));
    jsonw_set(j, "failed_ct_better_count", json_integer(ct_better));
    jsonw_set(j, "failed_end_better_count", json_integer(nfail - ct_better));
    /* fits that ended farther from the CT pose than they started (in mm or in degrees) */
    jsonw_set(j, "ended_farther_count", json_integer(farther));
    free(v);
}

/* Voxel faces between labels a and b. */
static long contact_faces(const vol *l, float a, float b)
{
    long faces = 0;
    for (int k = 0; k < l->dim[2]; k++)
        for (int j = 0; j < l->dim[1]; j++)
            for (int i = 0; i < l->dim[0]; i++) {
                float x = l->data[vol_idx(l, i, j, k)];
                if (x != a && x != b)
                    continue;
                float other = x == a ? b : a;
                faces += (i + 1 < l->dim[0] && l->data[vol_idx(l, i + 1, j, k)] == other) +
                         (j + 1 < l->dim[1] && l->data[vol_idx(l, i, j + 1, k)] == other) +
                         (k + 1 < l->dim[2] && l->data[vol_idx(l, i, j, k + 1)] == other);
            }
    return faces;
}

/* A bone's CT and its annotation, read as segment --labels reads them. */
typedef struct bone {
    vol *ct;
    seg_result seg; /* seg.labels: the annotation; seg.comp: its labels, ascending */
    seg_params p;
} bone;

static int bone_read(const char *dir, const char *name, bone *b)
{
    char path[4200];
    memset(b, 0, sizeof *b);
    seg_defaults(&b->p);
    snprintf(path, sizeof path, "%s/%s.nii.gz", dir, name);
    b->ct = volio_read(path);
    snprintf(path, sizeof path, "%s/%s_mask.nii.gz", dir, name);
    volio_segs segs = {0};
    vol *labels = b->ct ? volio_read_labels(path, &segs) : NULL;
    volio_segs_free(&segs);
    if (!labels || seg_from_labels(b->ct, labels, &b->p, &b->seg) < 0) {
        vol_free(labels);
        vol_free(b->ct);
        b->ct = NULL;
        return fn_err_wrap(FN_EINVAL, "%s", path);
    }
    return 0;
}

static void bone_free(bone *b)
{
    vol_free(b->ct);
    seg_result_free(&b->seg);
}

static int piece(const bone *b, int label, frag *f)
{
    int lo[3], hi[3];
    int rc = frag_label_box(b->seg.labels, label, lo, hi);
    return rc < 0 ? rc : frag_from_labels(f, b->seg.labels, b->ct, label, lo, hi, b->seg.threshold, b->p.ramp);
}

/* The starts' sequence of one piece: from its bone's name and its label alone, so that a bone's
 * starts are the same whatever else the folder holds (a folder of one bone reproduces its figures
 * in the whole set's), and --starts N begins with the starts of any smaller N. */
static uint64_t piece_seed(const char *name, int label)
{
    uint64_t h = 0xcbf29ce484222325ull; /* FNV-1a */
    for (const unsigned char *c = (const unsigned char *)name; *c; c++)
        h = (h ^ *c) * 0x100000001b3ull;
    h ^= (uint64_t)label;
    return fracture_rng_next(&h); /* splitmix64: nearby names and labels far apart */
}

/* Fits moving (at its CT pose) back from `starts` hand-like starts against fixed; into out. */
static int fit_piece(const frag *fixed, frag *moving, int starts, const reduce_opts *ro, const char *name,
                     int verbose, fits *out)
{
    obb_params op = {ro->tau_min, ro->tau_max};
    obb_tree *tf = obb_tree_build(fixed, &op), *tm = tf ? obb_tree_build(moving, &op) : NULL;
    int rc = tf && tm ? 0 : fn_err_set(FN_ENOMEM, "bench reduce: out of memory");
    const frag *asm_[1] = {fixed};
    const pose ct = POSE_IDENTITY;
    uint64_t seed = piece_seed(name, moving->id), *rng = &seed;
    for (int s = 0; s < starts && rc == 0; s++) {
        fit x;
        pose start = bench_reduce_start(fixed, tf, moving, tm, &ct, START_MM, START_DEG, rng);
        moving->pose = start;
        reduce_errors(fixed, moving, &ct, &x.start_rot, &x.start_trans, &x.tre);
        reduce_result r;
        double c0 = bench_process_cpu_us();
        rc = reduce_pair(asm_, 1, moving, ro, &r);
        x.cpu_s = (bench_process_cpu_us() - c0) * 1e-6;
        if (rc < 0)
            break;
        reduce_errors(fixed, moving, &ct, &x.rot, &x.trans, &x.tre);
        reduce_metric *me = reduce_metric_new(asm_, 1, moving, &r.voi, ro->count, ro->band_mm);
        x.metric_ct = me ? reduce_metric_eval(me, &ct, NULL) : NAN;
        x.metric_end = me ? reduce_metric_eval(me, &r.end, NULL) : NAN;
        reduce_metric_free(me);
        reduce_result_free(&r);
        if (verbose) {
            fprintf(stderr, "%s fragment %d start %d: from %.2f deg %.2f mm to %.3f deg %.3f mm, metric %.6f "
                            "(CT pose %.6f), %.3f s\n", name, moving->id, s, x.start_rot, x.start_trans, x.rot,
                    x.trans, x.metric_end, x.metric_ct, x.cpu_s);
            const pose *p[2] = {&start, &moving->pose};
            for (int e = 0; e < 2; e++)
                fprintf(stderr, "  %s pose q %.17g %.17g %.17g %.17g t %.17g %.17g %.17g\n", e ? "end" : "start",
                        p[e]->q[0], p[e]->q[1], p[e]->q[2], p[e]->q[3], p[e]->t[0], p[e]->t[1], p[e]->t[2]);
        }
        rc = fits_add(out, &x);
    }
    obb_tree_free(tf);
    obb_tree_free(tm);
    return rc < 0 ? rc : 0;
}

/* One bone: its pieces fitted (fits joined to all), its JSON object into *obj (NULL: intact). */
static int run_bone(const char *dir, const char *name, int starts, const reduce_opts *ro, int verbose, fits *all,
                    json_t **obj)
{
    bone b;
    *obj = NULL;
    int rc = bone_read(dir, name, &b);
    if (rc < 0 || b.seg.ncomp < 2) {
        bone_free(&b);
        return rc;
    }
    int big = 0; /* the largest fragment stays, as reduce --fixed */
    for (int c = 1; c < b.seg.ncomp; c++)
        if (b.seg.comp[c].voxels > b.seg.comp[big].voxels)
            big = c;
    int fixed_label = b.seg.comp[big].label;
    frag fixed = {0};
    rc = piece(&b, fixed_label, &fixed);
    fits mine = {0};
    json_t *moved = json_array(), *chips = json_array();
    for (int c = 0; c < b.seg.ncomp && rc == 0; c++) {
        const seg_component *k = &b.seg.comp[c];
        if (c == big)
            continue;
        if (k->volume_ml < MIN_PIECE_ML) {
            json_array_append_new(chips, json_integer(k->label));
            continue;
        }
        frag m = {0};
        if ((rc = piece(&b, k->label, &m)) == 0)
            rc = fit_piece(&fixed, &m, starts, ro, name, verbose, &mine);
        frag_free(&m);
        json_t *one = json_object();
        jsonw_set(one, "label", json_integer(k->label));
        jsonw_set(one, "volume_ml", jsonw_measure(k->volume_ml));
        jsonw_set(one, "contact_faces", json_integer(contact_faces(b.seg.labels, (float)fixed_label, (float)k->label)));
        json_array_append_new(moved, one);
    }
    frag_free(&fixed);
    bone_free(&b);
    for (int i = 0; i < mine.n && rc == 0; i++)
        rc = fits_add(all, &mine.f[i]);
    if (rc == 0) {
        *obj = json_object();
        jsonw_set(*obj, "bone", jsonw_string(name));
        jsonw_set(*obj, "fixed", json_integer(fixed_label));
        jsonw_set(*obj, "moving", moved);
        jsonw_set(*obj, "chips_left_out", chips);
        fits_json(*obj, &mine);
    } else {
        json_decref(moved);
        json_decref(chips);
    }
    free(mine.f);
    return rc;
}

json_t *bench_reduce_labels(const char *dir, int starts, const reduce_opts *ro, int verbose)
{
    char *names[BENCH_MAX_BONES];
    int n = bench_list_bones(dir, names), rc = n;
    if (n == 0)
        rc = fn_err_set(FN_EINVAL, "bench reduce: no NNN_BONE_mask.nii.gz in %s", dir);
    json_t *bones = json_array(), *intact = json_array();
    fits all = {0};
    for (int i = 0; i < n; i++) {
        json_t *one = NULL;
        if (rc >= 0) {
            rc = run_bone(dir, names[i], starts, ro, verbose, &all, &one);
            if (rc < 0)
                fn_err_wrap(rc, "bench reduce --labels: %s", names[i]);
        }
        if (one)
            json_array_append_new(bones, one);
        else if (rc >= 0)
            json_array_append_new(intact, jsonw_string(names[i]));
        free(names[i]);
    }
    json_t *root = NULL;
    if (rc >= 0) {
        root = jsonw_object("bench reduce");
        jsonw_set(root, "labels", jsonw_string(dir));
        jsonw_set(root, "starts", json_integer(starts));
        jsonw_set(root, "start_min_mm", jsonw_exact(START_MM[0]));
        jsonw_set(root, "start_max_mm", jsonw_exact(START_MM[1]));
        jsonw_set(root, "start_min_deg", jsonw_exact(START_DEG[0]));
        jsonw_set(root, "start_max_deg", jsonw_exact(START_DEG[1]));
        jsonw_set(root, "bones", bones);
        jsonw_set(root, "intact", intact);
        json_t *pooled = json_object(), *targets = json_object();
        fits_json(pooled, &all);
        jsonw_set(targets, "back_rate", jsonw_exact(TARGET_BACK_RATE));
        jsonw_set(targets, "median_seconds", jsonw_exact(TARGET_MEDIAN_S));
        jsonw_set(root, "pooled", pooled);
        jsonw_set(root, "targets", targets);
    } else {
        json_decref(bones);
        json_decref(intact);
    }
    free(all.f);
    return root;
}

/* Whether the annotation at path holds one label (an intact bone): 1, 0, or FN_E*. */
static int one_label(const char *path)
{
    volio_segs segs = {0};
    vol *l = volio_read_labels(path, &segs);
    volio_segs_free(&segs);
    if (!l)
        return fn_err_wrap(FN_EINVAL, "%s", path);
    float first = 0;
    int one = 1;
    for (size_t i = 0; i < vol_count(l) && one; i++)
        if (l->data[i] != 0) {
            one = !first || l->data[i] == first;
            first = l->data[i];
        }
    vol_free(l);
    return one && first != 0;
}

int bench_labels_intact(const char *dir, char **paths, int max)
{
    char *names[BENCH_MAX_BONES];
    int n = bench_list_bones(dir, names), got = 0, rc = n;
    for (int i = 0; i < n; i++) {
        char path[4200];
        snprintf(path, sizeof path, "%s/%s_mask.nii.gz", dir, names[i]);
        if (rc >= 0 && (rc = one_label(path)) == 1 && got < max) {
            snprintf(path, sizeof path, "%s/%s.nii.gz", dir, names[i]);
            if (!(paths[got++] = strdup(path)))
                rc = fn_err_set(FN_ENOMEM, "bench reduce: out of memory");
        }
        free(names[i]);
    }
    if (rc < 0) {
        while (got > 0)
            free(paths[--got]);
        return rc;
    }
    return got;
}

const char *bench_labels_default_dir(void)
{
    static char path[4200];
    const char *d = getenv("FRACNAV_DATA");
    snprintf(path, sizeof path, "%s/pelvis-dev", d && *d ? d : "/var/cache/fracnav");
    return path;
}
