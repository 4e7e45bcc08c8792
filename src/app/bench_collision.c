/* fracnav bench collision: the OBB octree query against brute force and FCL on fractured bones.
 *
 * Workloads: synthetic two-piece fractures (fracture_make) of the example skull CT, of
 * tests/data/CT_pitch.nii.gz (shipped in the repository) and of a synthetic long bone, or the first two fragments of a
 * saved case. Poses: half near contact (contact found by bisection along a random direction from
 * the fitted pose, then moved by at most 2 voxels and 3 degrees), half clearly apart or deeply
 * colliding. Every contender gets the same poses; timings are the best of --reps runs per pose
 * (the machines are shared), then mean, p99 and max over poses.
 *
 * JSON ({"command": "bench collision", "workloads": [...]}), per workload: fragments (dim, voxels);
 * build_ms and nodes for both fragments together (best of 3 builds each);
 * query_* the tree without a cache; query_near_* its near-contact half; query_coherent_* a pose
 * 0.05 voxel and 0.05 degree from a near-contact one, the pair cache warm from that one (the loop's
 * case); false_negatives/false_positives against brute force over all of those; box_tests_* the
 * box tests per query; brute_query_*; fcl_octree_* (octomap OcTree at the finest spacing, both
 * fragments' build time) and fcl_mesh_* (OBBRSS BVH of the exposed voxel faces), null without FCL;
 * *_disagree: FCL answers that differ
 * from brute force (its geometry only approximates the voxel boxes); speedup_* = FCL / tree. */
#include "bench.h"

#include "case.h"
#include "caselock.h"
#include "cmd.h"
#include "err.h"
#include "fracture.h"
#include "jsonw.h"
#include "seg.h"
#include "volio.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

typedef struct opts {
    int poses, reps, json, fcl, wait;
    unsigned long long seed;
    double threshold, tolerance, bone;
    obb_params tau;
} opts;

typedef struct work {
    char name[64];
    frag a, b;
    pose fit_b; /* B's pose where it fits A: the contact configuration */
} work;

typedef struct stats {
    double mean, p99, max;
} stats;

static unsigned long long rng_state;

static double urand(void)
{
    rng_state ^= rng_state << 13, rng_state ^= rng_state >> 7, rng_state ^= rng_state << 17;
    return (double)(rng_state >> 11) / 9007199254740992.0;
}

static void unit_vector(double v[3])
{
    double n;
    do {
        for (int i = 0; i < 3; i++)
            v[i] = 2 * urand() - 1;
        n = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    } while (n < 1e-3 || n > 1);
    for (int i = 0; i < 3; i++)
        v[i] /= n;
}

/* ---- workloads ---- */

/* Cuts ct's bone in two (fracture_make); A = piece 1 (fixed), B = piece 2 fitted back. */
static int work_from_ct(work *w, const vol *ct, double bone, double ramp)
{
    fracture_params fp;
    fracture_defaults(&fp);
    fp.threshold = bone;
    fracture_result fr;
    int rc = fracture_make(ct, &fp, &fr);
    if (rc)
        return rc;
    frag *f[2] = {&w->a, &w->b};
    for (int id = 1; id <= 2 && rc == 0; id++) {
        int lo[3], hi[3];
        rc = frag_label_box(fr.labels, id, lo, hi);
        if (rc == 0)
            rc = frag_from_labels(f[id - 1], fr.labels, fr.ct, id, lo, hi, bone, ramp);
    }
    if (rc == 0)
        w->fit_b = fr.truth[1];
    fracture_result_free(&fr);
    return rc;
}

static int work_from_file(work *w, const char *path, double bone, double ramp)
{
    vol *ct = volio_read(path);
    if (!ct)
        return FN_EIO;
    int rc = work_from_ct(w, ct, bone, ramp);
    vol_free(ct);
    return rc ? fn_err_wrap(rc, "%s", path) : 0;
}

/* A long bone: a hollow cylinder with a thick cortical wall, flaring towards both ends. */
static int work_long_bone(work *w)
{
    vol *v = vol_new(192, 192, 240);
    if (!v)
        return FN_ENOMEM;
    static const double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    const double sp[3] = {0.3, 0.3, 0.5}, org[3] = {0, 0, 0};
    vol_set_geometry(v, dir, sp, org);
    for (int k = 0; k < v->dim[2]; k++) {
        double z = (k - v->dim[2] / 2.0) * sp[2], flare = 1 + 0.25 * (z / 60) * (z / 60);
        double ro = 17 * flare, ri = 10 * flare;
        for (int j = 0; j < v->dim[1]; j++)
            for (int i = 0; i < v->dim[0]; i++) {
                double x = (i - 96) * sp[0], y = (j - 96) * sp[1], r = sqrt(x * x + y * y);
                float hu = r < ri ? 40.f : r < ro ? 1500.f : r < ro + 8 ? 20.f : -1000.f;
                if (k < 6 || k >= v->dim[2] - 6)
                    hu = -1000.f;
                v->data[vol_idx(v, i, j, k)] = hu;
            }
    }
    int rc = work_from_ct(w, v, 300, 200);
    vol_free(v);
    return rc ? fn_err_wrap(rc, "long bone") : 0;
}

/* A case's first two fragments, read under its shared lock (caselock.h), as render reads it. */
static int work_from_case(work *w, const char *dir, int wait)
{
    caselock *lock = caselock_take(dir, 0, wait);
    planning_case *c = lock ? case_load(dir) : NULL;
    caselock_release(lock);
    if (!c)
        return FN_EIO;
    int rc = 0;
    if (c->nfrag < 2) {
        rc = fn_err_set(FN_EINVAL, "%s: needs two fragments, has %d", dir, c->nfrag);
    } else {
        int ia = c->fixed >= 0 ? c->fixed : 0, ib = ia == 0 ? 1 : 0;
        w->a = c->frag[ia], w->b = c->frag[ib];
        c->frag[ia].prob = c->frag[ib].prob = NULL; /* taken over */
        w->fit_b = c->has_truth ? pose_compose(c->truth[ib], w->b.pose) : w->b.pose;
        w->a.pose = POSE_IDENTITY;
    }
    case_free(c);
    return rc;
}

static int work_load(work *w, const char *name, const opts *o)
{
    char path[4200];
    struct stat st;
    memset(w, 0, sizeof *w);
    snprintf(w->name, sizeof w->name, "%s", name);
    if (!strcmp(name, "skull"))
        return work_from_file(w, cmd_example_ct(), 300, 200);
    if (!strcmp(name, "pitch")) {
        bench_pitch_path(path, sizeof path);
        if (access(path, R_OK) != 0)
            return fn_err_set(FN_EIO, "workload pitch: %s: %s (it ships in the repository's tests/data/: "
                              "set FRACNAV_SRC to the repository's root)", path, strerror(errno));
        return work_from_file(w, path, o->bone > 0 ? o->bone : 130, 40);
    }
    if (!strcmp(name, "longbone"))
        return work_long_bone(w);
    if (stat(name, &st) == 0 && S_ISDIR(st.st_mode))
        return work_from_case(w, name, o->wait);
    if (stat(name, &st) == 0)
        return work_from_file(w, name, o->bone > 0 ? o->bone : 300, 200);
    return fn_err_set(FN_EINVAL, "'%s' is neither a workload (skull, pitch, longbone, all), a case "
                                 "folder nor a volume file", name);
}

static void work_free(work *w)
{
    frag_free(&w->a);
    frag_free(&w->b);
}

/* ---- poses ---- */

typedef struct posed {
    pose b;   /* B's pose (home world -> current world) */
    int near; /* 1: within 2 voxels and 3 degrees of contact */
} posed;

static pose world_of(const frag *f, const pose *p)
{
    return pose_compose(*p, f->home);
}

static int tree_hits(const obb_tree *ta, const pose *aw, const frag *fb, const obb_tree *tb,
                     const pose *pb, const obb_query *q)
{
    pose bw = world_of(fb, pb);
    obb_result r;
    return obb_collide(ta, aw, tb, &bw, q, NULL, &r) == 0 && r.collides;
}

/* p moved by rotation `rot` about world point c, then by t. */
static pose about(const pose *p, const pose *rot, const double c[3], const double t[3])
{
    pose to = POSE_IDENTITY, back = POSE_IDENTITY;
    double rc[3];
    pose_rotate(rot, c, rc);
    for (int i = 0; i < 3; i++)
        to.t[i] = c[i] - rc[i] + t[i];
    back = pose_compose(to, *rot);
    return pose_compose(back, *p);
}

static pose small_rotation(double max_deg)
{
    double ax[3];
    unit_vector(ax);
    return pose_from_axis_angle(ax, max_deg * M_PI / 180 * urand());
}

static pose shifted(const pose *base, const double d[3], double s)
{
    pose p = *base;
    for (int i = 0; i < 3; i++)
        p.t[i] += s * d[i];
    return p;
}

/* Contact along d from base: B collides at s_in and is clear at s_out (bisected to 0.1 um);
 * returns 0 when no colliding start was found. */
static int contact(const obb_tree *ta, const pose *aw, const frag *fb, const obb_tree *tb,
                   const pose *base, const double d[3], const obb_query *q, double *s_in,
                   double *s_out)
{
    double in = 0, out = 1;
    pose p = shifted(base, d, in);
    while (!tree_hits(ta, aw, fb, tb, &p, q) && in > -64) {
        in = in == 0 ? -0.5 : 2 * in;
        p = shifted(base, d, in);
    }
    if (!tree_hits(ta, aw, fb, tb, &p, q))
        return 0;
    for (p = shifted(base, d, out); tree_hits(ta, aw, fb, tb, &p, q) && out < 4096;)
        p = shifted(base, d, out *= 2);
    for (int it = 0; it < 40 && out - in > 1e-4; it++) {
        double mid = (in + out) / 2;
        p = shifted(base, d, mid);
        if (tree_hits(ta, aw, fb, tb, &p, q))
            in = mid;
        else
            out = mid;
    }
    *s_in = in, *s_out = out;
    return 1;
}

static int make_poses(const work *w, const obb_tree *ta, const obb_tree *tb, const opts *o,
                      const obb_query *q, posed *ps)
{
    pose aw = world_of(&w->a, &w->a.pose);
    double vox = fmin(fmin(w->b.spacing[0], w->b.spacing[1]), w->b.spacing[2]);
    double c[3];
    pose_apply(&w->fit_b, w->b.centroid, c);
    int n = 0, tries = 0;
    while (n < o->poses && tries++ < 20 * o->poses) {
        double d[3], zero[3] = {0, 0, 0}, s_in, s_out;
        pose rot = small_rotation(10), base = about(&w->fit_b, &rot, c, zero);
        unit_vector(d);
        if (!contact(ta, &aw, &w->b, tb, &base, d, q, &s_in, &s_out))
            continue;
        int near = n % 2 == 0;
        double s, jitter[3] = {0, 0, 0};
        pose r2 = POSE_IDENTITY;
        if (near) {
            unit_vector(jitter);
            double m = 2 * vox * cbrt(urand());
            for (int i = 0; i < 3; i++)
                jitter[i] *= m;
            r2 = small_rotation(3);
            s = s_out;
        } else if (n % 4 == 1) {
            s = s_out + 2 * vox + urand() * 20; /* apart */
        } else {
            s = s_in - 2 * vox - urand() * 10; /* deep */
        }
        double t[3] = {s * d[0] + jitter[0], s * d[1] + jitter[1], s * d[2] + jitter[2]};
        double cc[3];
        pose_apply(&base, w->b.centroid, cc);
        ps[n].b = about(&base, &r2, cc, t);
        ps[n].near = near;
        n++;
    }
    return n;
}

/* ---- measuring ---- */

static int cmp_double(const void *x, const void *y)
{
    double a = *(const double *)x, b = *(const double *)y;
    return a < b ? -1 : a > b;
}

static stats summarize(const double *v, int n)
{
    stats s = {0, 0, 0};
    if (n <= 0)
        return s;
    double *c = malloc((size_t)n * sizeof *c);
    if (!c)
        return s;
    memcpy(c, v, (size_t)n * sizeof *c);
    qsort(c, (size_t)n, sizeof *c, cmp_double);
    for (int i = 0; i < n; i++)
        s.mean += c[i] / n;
    int k = (int)ceil(0.99 * n) - 1;
    s.p99 = c[k < 0 ? 0 : k];
    s.max = c[n - 1];
    free(c);
    return s;
}

typedef struct results {
    int poses, near, colliding, fn, fp;
    double build_ms, tree_bytes;
    size_t nodes, voxels_a, voxels_b;
    double *tree_us, *near_us, *brute_us, *oct_us, *mesh_us, *coh_us;
    int nnear, ncoh, oct_disagree, mesh_disagree, have_fcl;
    double oct_build_ms, mesh_build_ms;
    size_t oct_cells, mesh_tris;
    double tests_mean, tests_max;
} results;

static double best_build(const frag *f, const obb_params *p, obb_tree **out)
{
    double best = INFINITY;
    for (int r = 0; r < 3; r++) {
        double t0 = bench_now_us();
        obb_tree *t = obb_tree_build(f, p);
        double dt = bench_now_us() - t0;
        best = dt < best ? dt : best;
        if (!t)
            return -1;
        if (r < 2)
            obb_tree_free(t);
        else
            *out = t;
    }
    return best / 1000;
}

#ifdef FRACNAV_HAVE_FCL
static void run_fcl(const work *w, const opts *o, const posed *ps, const int *truth, results *res)
{
    pose aw = world_of(&w->a, &w->a.pose);
    bench_fcl *g[4] = {NULL, NULL, NULL, NULL};
    double t0 = bench_now_us();
    g[0] = bench_fcl_octree(&w->a, &o->tau);
    g[1] = g[0] ? bench_fcl_octree(&w->b, &o->tau) : NULL;
    res->oct_build_ms = (bench_now_us() - t0) / 1000;
    t0 = bench_now_us();
    g[2] = g[1] ? bench_fcl_mesh(&w->a, &o->tau) : NULL;
    g[3] = g[2] ? bench_fcl_mesh(&w->b, &o->tau) : NULL;
    res->mesh_build_ms = (bench_now_us() - t0) / 1000;
    if (!g[3]) {
        fprintf(stderr, "fracnav bench collision: FCL skipped: %s\n", fn_err_msg());
    } else {
        res->have_fcl = 1;
        res->oct_cells = bench_fcl_size(g[0]) + bench_fcl_size(g[1]);
        res->mesh_tris = bench_fcl_size(g[2]) + bench_fcl_size(g[3]);
        for (int i = 0; i < res->poses; i++) {
            pose bw = world_of(&w->b, &ps[i].b);
            for (int m = 0; m < 2; m++) {
                double best = INFINITY;
                int hit = 0;
                for (int r = 0; r < o->reps; r++) {
                    double t1 = bench_now_us();
                    hit = bench_fcl_collide(g[2 * m], &aw, g[2 * m + 1], &bw);
                    double dt = bench_now_us() - t1;
                    best = dt < best ? dt : best;
                }
                (m ? res->mesh_us : res->oct_us)[i] = best;
                if (hit != truth[i])
                    (*(m ? &res->mesh_disagree : &res->oct_disagree))++;
            }
        }
    }
    for (int i = 0; i < 4; i++)
        bench_fcl_free(g[i]);
}
#endif

/* The navigation loop's case: a pose queried just after a slightly different one, with the pair's
 * cache warm from that query. Checked against brute force like every other answer. */
static void coherent(const work *w, const obb_tree *ta, const obb_tree *tb, const pose *aw,
                     const pose *pb, const obb_query *q, const opts *o, results *res)
{
    double vox = fmin(fmin(w->b.spacing[0], w->b.spacing[1]), w->b.spacing[2]), t[3];
    pose bw = world_of(&w->b, pb), rot = small_rotation(0.05), near;
    unit_vector(t);
    for (int i = 0; i < 3; i++)
        t[i] *= 0.05 * vox;
    double c[3];
    pose_apply(pb, w->b.centroid, c);
    near = about(pb, &rot, c, t);
    pose bw2 = world_of(&w->b, &near);
    obb_cache warm, cache;
    obb_result r, rb;
    obb_cache_reset(&warm);
    obb_collide(ta, aw, tb, &bw, q, &warm, &r);
    double best = INFINITY;
    for (int k = 0; k < o->reps; k++) {
        cache = warm;
        double t0 = bench_now_us();
        obb_collide(ta, aw, tb, &bw2, q, &cache, &r);
        double dt = bench_now_us() - t0;
        best = dt < best ? dt : best;
    }
    obb_collide_brute(&w->a, aw, &w->b, &bw2, &o->tau, q, &rb);
    res->fn += rb.collides && !r.collides;
    res->fp += !rb.collides && r.collides;
    res->coh_us[res->ncoh++] = best;
}

static int measure(const work *w, const opts *o, results *res)
{
    obb_tree *ta = NULL, *tb = NULL;
    double ba = best_build(&w->a, &o->tau, &ta), bb = ba < 0 ? -1 : best_build(&w->b, &o->tau, &tb);
    if (ba < 0 || bb < 0) {
        obb_tree_free(ta);
        return FN_ENOMEM;
    }
    res->build_ms = ba + bb;
    res->nodes = obb_tree_nodes(ta) + obb_tree_nodes(tb);
    res->tree_bytes = (double)(obb_tree_bytes(ta) + obb_tree_bytes(tb));
    res->voxels_a = w->a.voxels, res->voxels_b = w->b.voxels;
    obb_query q = {.threshold = o->threshold, .tolerance_mm = o->tolerance};
    posed *ps = calloc((size_t)o->poses, sizeof *ps);
    int *truth = calloc((size_t)o->poses, sizeof *truth);
    size_t n5 = (size_t)o->poses * sizeof(double);
    res->tree_us = malloc(n5), res->near_us = malloc(n5), res->brute_us = malloc(n5);
    res->oct_us = calloc(1, n5), res->mesh_us = calloc(1, n5), res->coh_us = malloc(n5);
    if (!ps || !truth || !res->tree_us || !res->near_us || !res->brute_us || !res->oct_us ||
        !res->mesh_us || !res->coh_us) {
        free(ps), free(truth), obb_tree_free(ta), obb_tree_free(tb);
        return fn_err_set(FN_ENOMEM, "out of memory for %d poses", o->poses);
    }
    pose aw0 = world_of(&w->a, &w->a.pose), bw0 = world_of(&w->b, &w->fit_b);
    obb_result r0;
    if (obb_collide(ta, &aw0, tb, &bw0, &q, NULL, &r0)) {
        free(ps), free(truth), obb_tree_free(ta), obb_tree_free(tb);
        return FN_EINVAL;
    }
    res->poses = make_poses(w, ta, tb, o, &q, ps);
    pose aw = world_of(&w->a, &w->a.pose);
    double tests = 0;
    for (int i = 0; i < res->poses; i++) {
        pose bw = world_of(&w->b, &ps[i].b);
        obb_result rt, rb;
        double best = INFINITY;
        for (int r = 0; r < o->reps; r++) {
            double t0 = bench_now_us();
            obb_collide(ta, &aw, tb, &bw, &q, NULL, &rt);
            double dt = bench_now_us() - t0;
            best = dt < best ? dt : best;
        }
        tests += (double)rt.tests;
        res->tests_max = fmax(res->tests_max, (double)rt.tests);
        res->tree_us[i] = best;
        if (ps[i].near)
            res->near_us[res->nnear++] = best;
        double t0 = bench_now_us();
        obb_collide_brute(&w->a, &aw, &w->b, &bw, &o->tau, &q, &rb);
        res->brute_us[i] = bench_now_us() - t0;
        truth[i] = rb.collides;
        res->colliding += rb.collides;
        res->near += ps[i].near;
        res->fn += rb.collides && !rt.collides;
        res->fp += !rb.collides && rt.collides;
        if (ps[i].near)
            coherent(w, ta, tb, &aw, &ps[i].b, &q, o, res);
    }
    res->tests_mean = res->poses ? tests / res->poses : 0;
#ifdef FRACNAV_HAVE_FCL
    if (o->fcl)
        run_fcl(w, o, ps, truth, res);
#endif
    free(ps);
    free(truth);
    obb_tree_free(ta);
    obb_tree_free(tb);
    return 0;
}

static void results_free(results *r)
{
    free(r->tree_us), free(r->near_us), free(r->brute_us), free(r->oct_us), free(r->mesh_us);
    free(r->coh_us);
}

/* ---- output ---- */

static void put(json_t *o, const char *key, json_t *v)
{
    json_object_set_new(o, key, v);
}

/* A statistic over n samples: null without samples (no near-contact pose, no FCL). */
static json_t *over(double v, int n)
{
    return jsonw_measure(n > 0 ? v : JSONW_NA);
}

static json_t *frag_json(const frag *f)
{
    return json_pack("{s:[iii],s:I}", "dim", f->dim[0], f->dim[1], f->dim[2], "voxels", (json_int_t)f->voxels);
}

/* One workload's figures; the FCL ones are null when FCL did not run. */
static json_t *workload_json(const work *w, const results *r)
{
    stats t = summarize(r->tree_us, r->poses), nr = summarize(r->near_us, r->nnear);
    stats b = summarize(r->brute_us, r->poses), oc = summarize(r->oct_us, r->poses);
    stats me = summarize(r->mesh_us, r->poses), co = summarize(r->coh_us, r->ncoh);
    int fcl = r->have_fcl ? r->poses : 0;
    json_t *o = json_pack("{s:s,s:i,s:i,s:i,s:[oo]}", "workload", w->name, "poses", r->poses,
                          "near_contact_poses", r->near, "colliding_poses", r->colliding, "fragments",
                          frag_json(&w->a), frag_json(&w->b));
    if (!o)
        return NULL;
    put(o, "build_ms", jsonw_measure(r->build_ms));
    put(o, "nodes", json_integer((json_int_t)r->nodes));
    put(o, "node_bytes", json_integer((json_int_t)sizeof(obb_node)));
    put(o, "tree_bytes", json_integer((json_int_t)r->tree_bytes));
    put(o, "query_mean_us", over(t.mean, r->poses));
    put(o, "query_p99_us", over(t.p99, r->poses));
    put(o, "query_max_us", over(t.max, r->poses));
    put(o, "query_near_mean_us", over(nr.mean, r->nnear));
    put(o, "query_near_max_us", over(nr.max, r->nnear));
    put(o, "box_tests_mean", over(r->tests_mean, r->poses));
    put(o, "box_tests_max", over(r->tests_max, r->poses));
    put(o, "coherent_poses", json_integer(r->ncoh));
    put(o, "query_coherent_mean_us", over(co.mean, r->ncoh));
    put(o, "query_coherent_max_us", over(co.max, r->ncoh));
    put(o, "false_negatives", json_integer(r->fn));
    put(o, "false_positives", json_integer(r->fp));
    put(o, "brute_query_mean_us", over(b.mean, r->poses));
    put(o, "brute_query_max_us", over(b.max, r->poses));
    put(o, "fcl_octree_build_ms", over(r->oct_build_ms, fcl));
    put(o, "fcl_octree_cells", r->have_fcl ? json_integer((json_int_t)r->oct_cells) : json_null());
    put(o, "fcl_octree_query_mean_us", over(oc.mean, fcl));
    put(o, "fcl_octree_query_p99_us", over(oc.p99, fcl));
    put(o, "fcl_octree_query_max_us", over(oc.max, fcl));
    put(o, "fcl_octree_disagree", r->have_fcl ? json_integer(r->oct_disagree) : json_null());
    put(o, "fcl_mesh_build_ms", over(r->mesh_build_ms, fcl));
    put(o, "fcl_mesh_triangles", r->have_fcl ? json_integer((json_int_t)r->mesh_tris) : json_null());
    put(o, "fcl_mesh_query_mean_us", over(me.mean, fcl));
    put(o, "fcl_mesh_query_max_us", over(me.max, fcl));
    put(o, "fcl_mesh_disagree", r->have_fcl ? json_integer(r->mesh_disagree) : json_null());
    put(o, "speedup_vs_fcl_octree_mean", over(oc.mean / t.mean, fcl));
    put(o, "speedup_vs_fcl_octree_max", over(oc.max / t.max, fcl));
    put(o, "speedup_vs_fcl_mesh_mean", over(me.mean / t.mean, fcl));
    return o;
}

static void print_text(const work *w, const results *r)
{
    stats t = summarize(r->tree_us, r->poses), nr = summarize(r->near_us, r->nnear);
    stats b = summarize(r->brute_us, r->poses), oc = summarize(r->oct_us, r->poses);
    stats me = summarize(r->mesh_us, r->poses);
    printf("%s: A %dx%dx%d (%zu voxels), B %dx%dx%d (%zu voxels)\n", w->name, w->a.dim[0],
           w->a.dim[1], w->a.dim[2], r->voxels_a, w->b.dim[0], w->b.dim[1], w->b.dim[2],
           r->voxels_b);
    printf("  build %.2f ms for both, %zu nodes of %zu bytes\n", r->build_ms, r->nodes,
           sizeof(obb_node));
    printf("  %d poses (%d near contact, %d colliding): tree mean %.2f us, p99 %.2f, max %.2f "
           "(near: mean %.2f, max %.2f)\n",
           r->poses, r->near, r->colliding, t.mean, t.p99, t.max, nr.mean, nr.max);
    stats co = summarize(r->coh_us, r->ncoh);
    printf("  after a 0.05-voxel, 0.05-degree step with the pair cache warm: mean %.2f us, max %.2f "
           "(%d poses)\n",
           co.mean, co.max, r->ncoh);
    printf("  false negatives %d, false positives %d; brute force mean %.0f us\n", r->fn, r->fp,
           b.mean);
    if (r->have_fcl)
        printf("  FCL octree: build %.0f ms, mean %.1f us, max %.1f us (%d disagree); "
               "FCL OBBRSS mesh: build %.0f ms, mean %.1f us, max %.1f us (%d disagree)\n",
               r->oct_build_ms, oc.mean, oc.max, r->oct_disagree, r->mesh_build_ms, me.mean, me.max,
               r->mesh_disagree);
}

static int usage(FILE *out, int rc)
{
    fprintf(out,
            "usage: fracnav bench collision [CASE] [--poses N] [--json] [options]\n\n"
            "Times the OBB octree collision query against brute force (the ground truth) and FCL\n"
            "(octomap octree and OBBRSS mesh of the exposed voxel faces) on the same poses.\n\n"
            "CASE: skull (default: a synthetic fracture of the example CT), pitch\n"
            "      (tests/data/CT_pitch.nii.gz under $FRACNAV_SRC, else under the source tree\n"
            "      fracnav was built from), longbone (synthetic), all (the three),\n"
            "      a case folder (its first two fragments, read under the case's shared\n"
            "      lock), or a volume file to fracture.\n"
            "  --poses N        poses per workload (default 1000; half near contact)\n"
            "  --json           one JSON object on stdout: {\"command\": \"bench collision\",\n"
            "                   \"workloads\": [one per workload]}\n"
            "  --reps R         timed runs per pose, the best counts (default 3)\n"
            "  --seed S         pose generator seed (default 1)\n"
            "  --threshold P    probability product needed to collide (default 0)\n"
            "  --tolerance MM   overlap that still counts as touching (default 0)\n"
            "  --tau-min T, --tau-max T   hierarchy thresholds (default 0, 1)\n"
            "  --bone V         bone threshold for a volume file or pitch (HU or raw units)\n"
            "  --no-fcl         skip the FCL contenders\n"
            "  --wait           a case folder another command writes: wait for it (else\n"
            "                   refused, naming that command)\n"
            "Exit status: 0, 1 on failure or any false answer, 2 on usage errors.\n");
    return rc;
}

static int parse(int argc, char **argv, opts *o, const char **which)
{
    *o = (opts){.poses = 1000, .reps = 3, .fcl = 1, .seed = 1, .tau = {0, 1}};
    *which = "skull";
    cmd_tau tau = {0};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        int more = i + 1 < argc, rc;
        char *end = NULL;
        if (cmd_tau_option("bench collision", a, more ? argv[i + 1] : NULL, &tau, &rc)) {
            if (rc)
                return rc;
            i++;
        } else if (!strcmp(a, "--json"))
            o->json = 1;
        else if (!strcmp(a, "--no-fcl"))
            o->fcl = 0;
        else if (!strcmp(a, "--wait"))
            o->wait = 1;
        else if (a[0] != '-')
            *which = a;
        else if (more && !strcmp(a, "--poses"))
            o->poses = (int)strtol(argv[++i], &end, 10);
        else if (more && !strcmp(a, "--reps"))
            o->reps = (int)strtol(argv[++i], &end, 10);
        else if (more && !strcmp(a, "--seed"))
            o->seed = strtoull(argv[++i], &end, 10);
        else if (more && !strcmp(a, "--threshold"))
            o->threshold = strtod(argv[++i], &end);
        else if (more && !strcmp(a, "--tolerance"))
            o->tolerance = strtod(argv[++i], &end);
        else if (more && !strcmp(a, "--bone"))
            o->bone = strtod(argv[++i], &end);
        else {
            fprintf(stderr, "fracnav bench collision: unknown or incomplete option '%s'\n", a);
            return 2;
        }
        if (end && *end) {
            fprintf(stderr, "fracnav bench collision: %s: '%s' is not a number\n", a, argv[i]);
            return 2;
        }
    }
    if (o->poses < 2 || o->poses > 1000000 || o->reps < 1 || o->reps > 100) {
        fprintf(stderr, "fracnav bench collision: --poses must be 2..1000000, --reps 1..100\n");
        return 2;
    }
    if (cmd_tau_apply(&tau, &o->tau.tau_min, &o->tau.tau_max) < 0)
        return cmd_usage_error("bench collision", "%s", fn_err_msg());
    return 0;
}

int bench_collision(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv))
        return usage(stdout, 0);
    opts o;
    const char *which;
    int rc = parse(argc, argv, &o, &which);
    if (rc)
        return usage(stderr, rc);
    const char *all[] = {"skull", "pitch", "longbone"};
    int nw = strcmp(which, "all") ? 1 : 3, bad = 0;
    json_t *root = o.json ? jsonw_object("bench collision") : NULL, *rows = o.json ? json_array() : NULL;
    if (o.json)
        jsonw_set(root, "workloads", rows);
    for (int k = 0; k < nw; k++) {
        work w;
        results r = {0};
        rng_state = 0x9e3779b97f4a7c15ull ^ (o.seed * 0xbf58476d1ce4e5b9ull) ^ (unsigned long long)k;
        if (work_load(&w, nw > 1 ? all[k] : which, &o) || measure(&w, &o, &r)) {
            fprintf(stderr, "fracnav bench collision: %s\n", fn_err_msg());
            work_free(&w);
            results_free(&r);
            json_decref(root);
            return 1;
        }
        if (o.json)
            json_array_append_new(rows, workload_json(&w, &r));
        else
            print_text(&w, &r);
        bad += r.fn + r.fp;
        work_free(&w);
        results_free(&r);
    }
    if (o.json && jsonw_print(root, stdout) < 0) {
        fprintf(stderr, "fracnav bench collision: %s\n", fn_err_msg());
        return 1;
    }
    return bad ? 1 : 0;
}
