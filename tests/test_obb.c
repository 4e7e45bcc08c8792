/* OBB octree: the separating-axis test, the pruning rules, and the hierarchy against brute force. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "allocount.h"
#include "err.h"
#include "obb.h"

#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static uint64_t rng = 0x9e3779b97f4a7c15ull;

static double urand(void)
{
    rng ^= rng << 13, rng ^= rng >> 7, rng ^= rng << 17;
    return (double)(rng >> 11) / 9007199254740992.0;
}

static double srand1(void)
{
    return 2 * urand() - 1;
}

static frag *tfrag_new(int nx, int ny, int nz, double sx, double sy, double sz)
{
    frag *f = calloc(1, sizeof *f);
    f->dim[0] = nx, f->dim[1] = ny, f->dim[2] = nz;
    f->spacing[0] = sx, f->spacing[1] = sy, f->spacing[2] = sz;
    f->prob = calloc((size_t)nx * ny * nz, 1);
    f->home = f->pose = POSE_IDENTITY;
    snprintf(f->name, sizeof f->name, "test%dx%dx%d", nx, ny, nz);
    return f;
}

static void tfrag_free(frag *f)
{
    free(f->prob);
    free(f);
}

static uint8_t *at(frag *f, int i, int j, int k)
{
    return &f->prob[((size_t)k * f->dim[1] + j) * f->dim[0] + i];
}

static void fill(frag *f, int x0, int y0, int z0, int x1, int y1, int z1, uint8_t p)
{
    for (int k = z0; k <= z1; k++)
        for (int j = y0; j <= y1; j++)
            for (int i = x0; i <= x1; i++)
                *at(f, i, j, k) = p;
}

static pose random_rotation(void)
{
    double ax[3] = {srand1(), srand1(), srand1()};
    return pose_from_axis_angle(ax, M_PI * srand1());
}

/* Box corners projected on an axis: an independent check of the radius formulas. */
static void project(const double R[3][3], const double t[3], const double c[3], const double h[3],
                    const double L[3], double *lo, double *hi)
{
    *lo = INFINITY, *hi = -INFINITY;
    for (int v = 0; v < 8; v++) {
        double p[3], w[3];
        for (int i = 0; i < 3; i++)
            p[i] = c[i] + ((v >> i) & 1 ? h[i] : -h[i]);
        for (int i = 0; i < 3; i++)
            w[i] = R[i][0] * p[0] + R[i][1] * p[1] + R[i][2] * p[2] + t[i];
        double d = w[0] * L[0] + w[1] * L[1] + w[2] * L[2];
        *lo = fmin(*lo, d), *hi = fmax(*hi, d);
    }
}

/* 1 when some of the 15 axes separates the boxes by more than margin (-1: by less than -margin). */
static int separated_by_vertices(const double R[3][3], const double t[3], const double ca[3],
                                 const double ha[3], const double cb[3], const double hb[3],
                                 double margin, int *face_only)
{
    static const double I[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    double axes[15][3];
    int n = 0;
    for (int i = 0; i < 3; i++)
        memcpy(axes[n++], I[i], sizeof axes[0]);
    for (int j = 0; j < 3; j++)
        for (int i = 0; i < 3; i++)
            axes[n][i] = R[i][j];
    for (int j = 0; j < 3; j++, n++)
        for (int i = 0; i < 3; i++)
            axes[n][i] = R[i][j];
    n = 6;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++, n++) {
            double b[3] = {R[0][j], R[1][j], R[2][j]};
            axes[n][0] = I[i][1] * b[2] - I[i][2] * b[1];
            axes[n][1] = I[i][2] * b[0] - I[i][0] * b[2];
            axes[n][2] = I[i][0] * b[1] - I[i][1] * b[0];
        }
    static const double Id[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    static const double zero[3] = {0, 0, 0};
    int sep = 0, near = 0;
    *face_only = 0;
    for (int a = 0; a < 15; a++) {
        double len = sqrt(axes[a][0] * axes[a][0] + axes[a][1] * axes[a][1] + axes[a][2] * axes[a][2]);
        if (len < 1e-6)
            continue;
        double L[3] = {axes[a][0] / len, axes[a][1] / len, axes[a][2] / len}, l0, h0, l1, h1;
        project(Id, zero, ca, ha, L, &l0, &h0);
        project(R, t, cb, hb, L, &l1, &h1);
        double gap = fmax(l1 - h0, l0 - h1);
        if (gap > margin) {
            sep = 1;
            if (a < 6)
                *face_only = 1;
        } else if (gap > -margin) {
            near = 1;
        }
    }
    return sep ? 1 : near ? 0 : -1;
}

static void test_sat_touching_and_gaps(void **st)
{
    double R[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, t[3] = {0, 0, 0};
    double ca[3] = {0, 0, 0}, h[3] = {1, 1, 1}, gap;
    double touch[3] = {2, 0, 0}, apart[3] = {2.5, 0.3, 0}, deep[3] = {0.5, 0, 0};
    assert_int_equal(obb_box_overlap(R, t, ca, h, touch, h, &gap), 0); /* faces touching */
    assert_true(fabs(gap) < 1e-12);
    assert_int_equal(obb_box_overlap(R, t, ca, h, apart, h, &gap), 0);
    assert_true(fabs(gap - 0.5) < 1e-9);
    assert_int_equal(obb_box_overlap(R, t, ca, h, deep, h, &gap), 1);
    assert_true(fabs(gap + 1.5) < 1e-9); /* penetration depth 1.5 along x */
    /* B turned 45 degrees about z reaches sqrt(2) along x. */
    double c = cos(M_PI / 4), s = sin(M_PI / 4);
    double Rz[3][3] = {{c, -s, 0}, {s, c, 0}, {0, 0, 1}};
    double out[3] = {1 + sqrt(2) + 0.01, 0, 0}, in[3] = {1 + sqrt(2) - 0.01, 0, 0};
    assert_int_equal(obb_box_overlap(Rz, out, ca, h, (double[3]){0, 0, 0}, h, &gap), 0);
    assert_true(gap > 0.009 && gap < 0.011);
    assert_int_equal(obb_box_overlap(Rz, in, ca, h, (double[3]){0, 0, 0}, h, &gap), 1);
}

static void test_sat_random_against_vertices(void **st)
{
    int edge_cases = 0, checked = 0;
    for (int n = 0; n < 20000; n++) {
        pose p = random_rotation();
        double R[3][3], t[3] = {3 * srand1(), 3 * srand1(), 3 * srand1()};
        pose_to_matrix(&p, R);
        double ca[3] = {0, 0, 0}, cb[3] = {0, 0, 0}, gap;
        double ha[3] = {0.2 + urand(), 0.2 + urand(), 0.2 + urand()};
        double hb[3] = {0.2 + urand(), 0.2 + urand(), 0.2 + urand()};
        int face_only;
        int truth = separated_by_vertices(R, t, ca, ha, cb, hb, 1e-9, &face_only);
        if (truth == 0)
            continue; /* within rounding of touching: no claim */
        int got = obb_box_overlap(R, t, ca, ha, cb, hb, &gap);
        assert_int_equal(got, truth < 0);
        assert_true(got ? gap < 0 : gap > 0);
        checked++;
        if (truth > 0 && !face_only)
            edge_cases++; /* only an edge-edge axis separates */
    }
    assert_true(checked > 19000);
    assert_true(edge_cases > 50);
}

static obb_tree *build(frag *f, double tmin, double tmax)
{
    obb_params p = {tmin, tmax};
    obb_tree *t = obb_tree_build(f, &p);
    assert_non_null(t);
    return t;
}

static int is_leaf(const obb_node *n)
{
    return (n->info & 0x80000000u) != 0;
}

static void test_prune_solid_and_uncertain(void **st)
{
    frag *f = tfrag_new(4, 4, 4, 1, 1, 1);
    fill(f, 0, 0, 0, 1, 1, 1, 255);
    fill(f, 2, 2, 2, 3, 3, 3, 255);
    obb_tree *t = build(f, 0, 1);
    const obb_node *n = obb_tree_node_array(t);
    /* root + two solid octants */
    assert_int_equal(obb_tree_nodes(t), 3);
    assert_false(is_leaf(&n[0]));
    assert_int_equal((n[0].info >> 28) & 7, 1);
    assert_int_equal(n[0].info & 0xffffff, 1);
    assert_int_equal(n[0].hi[2], 3);
    assert_true(is_leaf(&n[1]) && is_leaf(&n[2]));
    assert_int_equal(n[1].info & 0xff, 255);
    assert_int_equal(n[1].hi[0] - n[1].lo[0], 1);
    obb_tree_free(t);

    /* p = 100 (0.39) is not solid under tau_max 1: eight voxel leaves */
    fill(f, 2, 2, 2, 3, 3, 3, 100);
    t = build(f, 0, 1);
    assert_int_equal(obb_tree_nodes(t), 11);
    obb_tree_free(t);
    /* ... but is solid when rho_min 0.39 > tau_max 0.3 */
    t = build(f, 0, 0.3);
    assert_int_equal(obb_tree_nodes(t), 3);
    assert_int_equal(obb_tree_node_array(t)[2].info & 0xff, 255);
    obb_tree_free(t);
    /* rho_max 0.39 < tau_min 0.5 drops the octant; the root's single child replaces it */
    t = build(f, 0.5, 1);
    assert_int_equal(obb_tree_nodes(t), 1);
    n = obb_tree_node_array(t);
    assert_true(is_leaf(&n[0]));
    assert_int_equal(n[0].hi[0], 1);
    obb_tree_free(t);
    /* one voxel short of solid: an inner node over 7 voxel leaves, rho_max bound 15 */
    fill(f, 2, 2, 2, 3, 3, 3, 0);
    *at(f, 1, 1, 1) = 0;
    t = build(f, 0, 1);
    assert_int_equal(obb_tree_nodes(t), 8);
    n = obb_tree_node_array(t);
    assert_int_equal((n[0].info >> 24) & 15, 15);
    assert_int_equal(((n[0].info >> 28) & 7) + 1, 7);
    assert_int_equal(n[0].hi[0], 1);
    obb_tree_free(t);
    tfrag_free(f);
}

static void test_prune_single_child_chain(void **st)
{
    frag *f = tfrag_new(8, 8, 8, 1, 1, 1);
    *at(f, 4, 6, 5) = 100;
    *at(f, 5, 6, 5) = 60;
    obb_tree *t = build(f, 0, 1);
    /* root(8^3) -> 4^3 -> 2^3 chain collapses onto the cell holding both voxels */
    assert_int_equal(obb_tree_nodes(t), 3);
    const obb_node *n = obb_tree_node_array(t);
    assert_int_equal(n[0].lo[0], 4);
    assert_int_equal(n[0].hi[0], 5);
    assert_int_equal(n[0].lo[1], 6);
    assert_int_equal(n[0].hi[1], 6);
    assert_int_equal((n[0].info >> 24) & 15, 6); /* ceil(100 * 15 / 255) */
    assert_int_equal(n[1].info & 0xff, 100);
    assert_int_equal(n[2].info & 0xff, 60);
    obb_tree_free(t);
    /* one voxel alone: the whole tree is that voxel */
    *at(f, 5, 6, 5) = 0;
    t = build(f, 0, 1);
    assert_int_equal(obb_tree_nodes(t), 1);
    assert_int_equal(obb_tree_node_array(t)[0].lo[2], 5);
    obb_tree_free(t);
    /* nothing left: an empty tree that never collides */
    t = build(f, 0.5, 1);
    assert_int_equal(obb_tree_nodes(t), 0);
    obb_result r;
    assert_int_equal(obb_collide(t, &POSE_IDENTITY, t, &POSE_IDENTITY, NULL, NULL, &r), 0);
    assert_false(r.collides);
    obb_tree_free(t);
    tfrag_free(f);
}

/* A random blob: a few balls of random probability, one solid block. */
static frag *random_frag(int maxdim, int aniso)
{
    int d[3];
    double s[3];
    for (int i = 0; i < 3; i++) {
        d[i] = 1 + (int)(urand() * maxdim);
        s[i] = aniso ? 0.5 + 1.5 * urand() : 1.0;
    }
    frag *f = tfrag_new(d[0], d[1], d[2], s[0], s[1], s[2]);
    int balls = 1 + (int)(urand() * 3);
    for (int b = 0; b < balls; b++) {
        double c[3] = {urand() * d[0], urand() * d[1], urand() * d[2]}, r = 1 + urand() * maxdim / 3;
        uint8_t p = urand() < 0.5 ? 255 : (uint8_t)(1 + urand() * 254);
        for (int k = 0; k < d[2]; k++)
            for (int j = 0; j < d[1]; j++)
                for (int i = 0; i < d[0]; i++) {
                    double x = i - c[0], y = j - c[1], z = k - c[2];
                    if (x * x + y * y + z * z < r * r && urand() < 0.9)
                        *at(f, i, j, k) = urand() < 0.8 ? p : (uint8_t)(urand() * 256);
                }
    }
    int lo[3], hi[3];
    for (int i = 0; i < 3; i++)
        lo[i] = (int)(urand() * d[i]), hi[i] = lo[i] + (int)(urand() * (d[i] - lo[i]));
    fill(f, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2], 255);
    if (urand() < 0.1) { /* a single-voxel fragment */
        memset(f->prob, 0, (size_t)d[0] * d[1] * d[2]);
        *at(f, d[0] / 2, d[1] / 2, d[2] / 2) = 255;
    }
    return f;
}

/* Every inner box holds its children's boxes and is the tightest such box; every solid block is
 * all certain bone (effective 255); every voxel leaf carries its voxel's effective probability. */
static void check_boxes(frag *f, const obb_tree *t, const obb_params *prm)
{
    const obb_node *n = obb_tree_node_array(t);
    for (size_t i = 0; i < obb_tree_nodes(t); i++) {
        if (is_leaf(&n[i])) {
            uint8_t p = (uint8_t)(n[i].info & 0xff);
            for (int k = n[i].lo[2]; k <= n[i].hi[2]; k++)
                for (int j = n[i].lo[1]; j <= n[i].hi[1]; j++)
                    for (int x = n[i].lo[0]; x <= n[i].hi[0]; x++)
                        assert_int_equal(obb_effective_prob(*at(f, x, j, k), prm), p);
            continue;
        }
        uint32_t first = n[i].info & 0xffffff, cnt = ((n[i].info >> 28) & 7) + 1;
        assert_true(cnt >= 2 && first > i && first + cnt <= obb_tree_nodes(t));
        for (int a = 0; a < 3; a++) {
            int lo = 65535, hi = 0;
            for (uint32_t c = first; c < first + cnt; c++)
                lo = n[c].lo[a] < lo ? n[c].lo[a] : lo, hi = n[c].hi[a] > hi ? n[c].hi[a] : hi;
            assert_int_equal(lo, n[i].lo[a]);
            assert_int_equal(hi, n[i].hi[a]);
        }
    }
}

static pose place(const frag *f, pose rot, const double at_mm[3])
{
    /* rotate about the crop centre, then put that centre at at_mm */
    double c[3], rc[3];
    for (int i = 0; i < 3; i++)
        c[i] = (f->dim[i] - 1) * f->spacing[i] / 2;
    pose_rotate(&rot, c, rc);
    for (int i = 0; i < 3; i++)
        rot.t[i] = at_mm[i] - rc[i];
    return rot;
}

static double radius(const frag *f)
{
    double r = 0;
    for (int i = 0; i < 3; i++)
        r += (f->dim[i] * f->spacing[i] / 2) * (f->dim[i] * f->spacing[i] / 2);
    return sqrt(r);
}

typedef struct tally {
    int poses, hits, misses;
} tally;

static void compare_pose(frag *fa, obb_tree *ta, frag *fb, obb_tree *tb, const obb_params *prm,
                         const pose *pa, const pose *pb, const obb_query *q, obb_cache *cache,
                         tally *tl)
{
    obb_result rt, rb;
    assert_int_equal(obb_collide(ta, pa, tb, pb, q, cache, &rt), 0);
    assert_int_equal(obb_collide_brute(fa, pa, fb, pb, prm, q, &rb), 0);
    if (rt.collides != rb.collides)
        fail_msg("tree says %d, brute force %d (dims %dx%dx%d vs %dx%dx%d)", rt.collides,
                 rb.collides, fa->dim[0], fa->dim[1], fa->dim[2], fb->dim[0], fb->dim[1], fb->dim[2]);
    if (q->want_pairs)
        assert_int_equal(rt.pairs_total, rb.pairs_total);
    if (rt.collides)
        assert_true(rt.separation_mm < 0);
    else
        assert_true(rt.separation_mm >= 0);
    tl->poses++;
    if (rt.collides)
        tl->hits++;
    else
        tl->misses++;
}

static void run_random(int frags, int poses_each, int maxdim, int aniso, double tmin, double tmax,
                       tally *tl)
{
    obb_params prm = {tmin, tmax};
    for (int n = 0; n < frags; n++) {
        frag *fa = random_frag(maxdim, aniso), *fb = random_frag(maxdim, aniso);
        obb_tree *ta = build(fa, tmin, tmax), *tb = build(fb, tmin, tmax);
        check_boxes(fa, ta, &prm);
        obb_cache cache;
        obb_cache_reset(&cache);
        double reach = radius(fa) + radius(fb);
        for (int k = 0; k < poses_each; k++) {
            double off[3] = {srand1(), srand1(), srand1()};
            double len = sqrt(off[0] * off[0] + off[1] * off[1] + off[2] * off[2]) + 1e-9;
            double dist = reach * (0.2 + 0.7 * urand()) / len;
            double cb[3] = {off[0] * dist, off[1] * dist, off[2] * dist}, o[3] = {0, 0, 0};
            pose pa = place(fa, random_rotation(), o), pb = place(fb, random_rotation(), cb);
            double smin = fmin(fmin(fa->spacing[0], fa->spacing[1]), fa->spacing[2]);
            smin = fmin(smin, fmin(fmin(fb->spacing[0], fb->spacing[1]), fb->spacing[2]));
            obb_query q = {.threshold = urand() < 0.5 ? 0 : urand() * 0.6,
                           .tolerance_mm = urand() < 0.5 ? 0 : 0.2 * smin * urand(),
                           .want_pairs = k % 4 == 0,
                           .order = k % 3 == 0 ? OBB_BREADTH_FIRST : OBB_DEPTH_FIRST,
                           .inner_axes = k % 5 == 0 ? 15 : 0};
            compare_pose(fa, ta, fb, tb, &prm, &pa, &pb, &q, k % 2 ? &cache : NULL, tl);
        }
        obb_tree_free(ta);
        obb_tree_free(tb);
        tfrag_free(fa);
        tfrag_free(fb);
    }
}

static void test_tree_matches_brute_force(void **st)
{
    tally tl = {0};
    run_random(40, 60, 14, 0, 0, 1, &tl);
    run_random(40, 60, 14, 1, 0, 1, &tl);
    run_random(20, 60, 12, 1, 0.3, 0.7, &tl);
    assert_true(tl.poses >= 6000);
    /* both answers must be well represented for the comparison to mean anything */
    assert_true(tl.hits > tl.poses / 5);
    assert_true(tl.misses > tl.poses / 5);
}

/* Small steps, as the navigation loop makes them: the cache's front and witness answer most
 * queries, and every answer still matches brute force. */
static void test_cache_follows_small_steps(void **st)
{
    static obb_cache cache;
    size_t reuses = 0;
    int poses = 0, hits = 0;
    for (int n = 0; n < 12; n++) {
        frag *fa = random_frag(14, 1), *fb = random_frag(14, 1);
        obb_params prm = {0, 1};
        obb_tree *ta = build(fa, 0, 1), *tb = build(fb, 0, 1);
        obb_cache_reset(&cache);
        double reach = radius(fa) + radius(fb), o[3] = {0, 0, 0}, dir[3];
        for (int i = 0; i < 3; i++)
            dir[i] = srand1() * reach / 2;
        pose pa = place(fa, random_rotation(), o), pb = place(fb, random_rotation(), dir);
        for (int k = 0; k < 150; k++) {
            double step = k % 25 == 0 ? 2.0 : 0.03;
            double ax[3] = {srand1(), srand1(), srand1()};
            pose turn = pose_from_axis_angle(ax, step * 0.02 * srand1());
            pb = pose_compose(turn, pb);
            for (int i = 0; i < 3; i++)
                pb.t[i] += step * srand1() - 0.02 * dir[i] / (reach + 1e-9);
            obb_query q = {.tolerance_mm = k % 40 < 20 ? 0 : 0.1, .threshold = k % 50 < 25 ? 0 : 0.3};
            tally tl = {0};
            compare_pose(fa, ta, fb, tb, &prm, &pa, &pb, &q, &cache, &tl);
            poses++;
            hits += tl.hits;
        }
        reuses += cache.reuses;
        obb_tree_free(ta);
        obb_tree_free(tb);
        tfrag_free(fa);
        tfrag_free(fb);
    }
    assert_true(reuses > (size_t)poses / 4);
    assert_true(hits > poses / 10 && hits < poses * 9 / 10);
}

/* The front follows the poses: a free answer from the front moves it to the pose queried, so the
 * same pose queried again tests no pair but the witnesses (its motion since is 0), and the next
 * small step searches only the pairs within that step of contact (a fitted fragment interlocked
 * along its whole fracture surface stepped by a front that stayed at an old pose: every step
 * searched the pairs within the whole way since, and then all again from the root). Along the
 * walk every answer matches brute force, and each free answer's separation is a true bound: B
 * moved by 0.9 of it does not collide. */
static void test_front_moves_with_the_pose(void **st)
{
    static obb_cache cache;
    int moved = 0, bounds = 0;
    for (int n = 0; n < 10; n++) {
        frag *fa = random_frag(14, 1), *fb = random_frag(14, 1);
        obb_params prm = {0, 1};
        obb_tree *ta = build(fa, 0, 1), *tb = build(fb, 0, 1);
        obb_cache_reset(&cache);
        double reach = radius(fa) + radius(fb), o[3] = {0, 0, 0}, dir[3];
        for (int i = 0; i < 3; i++)
            dir[i] = srand1() * reach / 2;
        pose pa = place(fa, random_rotation(), o), pb = place(fb, random_rotation(), dir);
        obb_query q = {.tolerance_mm = 0.1};
        for (int k = 0; k < 120; k++) {
            double ax[3] = {srand1(), srand1(), srand1()};
            pb = pose_compose(pose_from_axis_angle(ax, 0.0005 * srand1()), pb);
            for (int i = 0; i < 3; i++)
                pb.t[i] += 0.03 * srand1() - 0.02 * dir[i] / (reach + 1e-9);
            size_t reuses = cache.reuses;
            tally tl = {0};
            compare_pose(fa, ta, fb, tb, &prm, &pa, &pb, &q, &cache, &tl);
            /* answered from the front, which stays below the size that calls for a new one */
            int moves = cache.reuses == reuses + 1 && cache.front_valid &&
                        cache.front_n <= cache.front_made + cache.front_made / 2 + 64;
            obb_result r;
            assert_int_equal(obb_collide(ta, &pa, tb, &pb, &q, &cache, &r), 0);
            if (tl.hits || !moves)
                continue;
            assert_int_equal(r.collides, 0);
            assert_true(r.tests <= (size_t)cache.nwit);
            moved++;
            double u[3] = {srand1(), srand1(), srand1()}, len = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
            if (!(r.separation_mm > 0 && r.separation_mm < INFINITY && len > 0.1))
                continue;
            pose pm = pb;
            for (int i = 0; i < 3; i++)
                pm.t[i] += 0.9 * r.separation_mm * u[i] / len;
            obb_result rb;
            assert_int_equal(obb_collide_brute(fa, &pa, fb, &pm, &prm, &q, &rb), 0);
            assert_int_equal(rb.collides, 0);
            bounds++;
        }
        obb_tree_free(ta);
        obb_tree_free(tb);
        tfrag_free(fa);
        tfrag_free(fb);
    }
    print_message("%d free answers from a moved front, %d bounds checked\n", moved, bounds);
    assert_true(moved > 100);
    assert_true(bounds > 50);
}

/* A collision answer never depends on the queries before it. A walk of poses near contact (small
 * steps and jumps, as the loop and the optimizer make them) is queried in order with one cache, and
 * backwards after random warm-up queries with another: every yes or no equals brute force's, and
 * without a cache the whole answer (with the separation, which with a cache is a bound that
 * depends on the pairs its front kept) is the same bit for bit as before any other query. */
static void test_answers_ignore_history(void **st)
{
    static obb_cache warm, cold;
    enum { WALK = 60, WARM = 25 };
    int hits = 0, poses = 0;
    for (int n = 0; n < 10; n++) {
        frag *fa = random_frag(12, n % 2), *fb = random_frag(12, n % 2);
        obb_params prm = {0, 1};
        obb_tree *ta = build(fa, 0, 1), *tb = build(fb, 0, 1);
        double reach = radius(fa) + radius(fb), o[3] = {0, 0, 0}, at[3];
        for (int i = 0; i < 3; i++)
            at[i] = srand1() * reach / 2;
        pose pa = place(fa, random_rotation(), o), walk[WALK];
        walk[0] = place(fb, random_rotation(), at);
        for (int k = 1; k < WALK; k++) {
            double step = k % 15 == 0 ? 1.5 : 0.05, ax[3] = {srand1(), srand1(), srand1()};
            walk[k] = pose_compose(pose_from_axis_angle(ax, step * 0.03 * srand1()), walk[k - 1]);
            for (int i = 0; i < 3; i++)
                walk[k].t[i] += step * srand1() - 0.03 * at[i] / (reach + 1e-9);
        }
        obb_query q = {.tolerance_mm = n % 3 ? 0 : 0.2, .threshold = n % 4 == 3 ? 0.3 : 0};
        obb_result first[WALK];
        for (int k = 0; k < WALK; k++)
            assert_int_equal(obb_collide(ta, &pa, tb, &walk[k], &q, NULL, &first[k]), 0);
        obb_cache_reset(&warm);
        obb_cache_reset(&cold);
        for (int k = 0; k < WARM; k++) { /* warm-up: random poses, answers unused */
            double far[3] = {srand1() * reach, srand1() * reach, srand1() * reach};
            pose pw = place(fb, random_rotation(), far);
            obb_result rw;
            assert_int_equal(obb_collide(ta, &pa, tb, &pw, &q, &warm, &rw), 0);
        }
        for (int k = 0; k < WALK; k++) {
            int kw = WALK - 1 - k; /* the warm cache walks backwards */
            const pose *pk[2] = {&walk[k], &walk[kw]};
            obb_cache *ck[2] = {&cold, &warm};
            for (int w = 0; w < 2; w++) {
                obb_result rc, rf, rb;
                assert_int_equal(obb_collide(ta, &pa, tb, pk[w], &q, ck[w], &rc), 0);
                assert_int_equal(obb_collide(ta, &pa, tb, pk[w], &q, NULL, &rf), 0);
                assert_int_equal(obb_collide_brute(fa, &pa, fb, pk[w], &prm, &q, &rb), 0);
                if (rc.collides != rb.collides || rf.collides != rb.collides)
                    fail_msg("pose %d (%s cache): cached %d, from scratch %d, brute force %d", w ? kw : k,
                             w ? "warm" : "cold", rc.collides, rf.collides, rb.collides);
                if (memcmp(&rf, &first[w ? kw : k], sizeof rf))
                    fail_msg("pose %d: from scratch, separation %.9g after other queries, %.9g before",
                             w ? kw : k, rf.separation_mm, first[w ? kw : k].separation_mm);
                hits += rb.collides;
                poses++;
            }
        }
        obb_tree_free(ta);
        obb_tree_free(tb);
        tfrag_free(fa);
        tfrag_free(fb);
    }
    assert_true(hits > poses / 10 && hits < poses * 9 / 10);
}

static void test_pairs_listed(void **st)
{
    frag *a = tfrag_new(3, 3, 3, 1, 1, 1), *b = tfrag_new(3, 3, 3, 1, 1, 1);
    fill(a, 0, 0, 0, 2, 2, 2, 255);
    fill(b, 0, 0, 0, 2, 2, 2, 255);
    obb_tree *ta = build(a, 0, 1), *tb = build(b, 0, 1);
    /* B shifted by 2.5 voxels in x: only A's x=2 layer meets B's x=0 layer, half a voxel deep,
     * each A voxel its B neighbour at the same (y, z): 9 pairs */
    pose pb = POSE_IDENTITY;
    pb.t[0] = 2.5;
    obb_pair pairs[16];
    obb_query q = {.want_pairs = 1, .pairs = pairs, .max_pairs = 16};
    obb_result r;
    assert_int_equal(obb_collide(ta, &POSE_IDENTITY, tb, &pb, &q, NULL, &r), 0);
    assert_true(r.collides);
    assert_int_equal(r.pairs_total, 9);
    assert_int_equal(r.npairs, 9);
    for (size_t i = 0; i < r.npairs; i++) {
        assert_int_equal(pairs[i].a[0], 2);
        assert_int_equal(pairs[i].b[0], 0);
        assert_int_equal(pairs[i].a[1], pairs[i].b[1]);
    }
    assert_true(fabs(r.separation_mm + 0.5) < 1e-9);
    /* a tolerance of half the overlap still collides, a larger one does not */
    q.tolerance_mm = 0.2;
    assert_int_equal(obb_collide(ta, &POSE_IDENTITY, tb, &pb, &q, NULL, &r), 0);
    assert_true(r.collides);
    q.tolerance_mm = 0.25;
    assert_int_equal(obb_collide(ta, &POSE_IDENTITY, tb, &pb, &q, NULL, &r), 0);
    assert_false(r.collides); /* shrunk boxes touch exactly: no overlap */
    /* probability threshold: 1 * 1 reaches 0.9 */
    q.tolerance_mm = 0;
    q.threshold = 0.9;
    assert_int_equal(obb_collide(ta, &POSE_IDENTITY, tb, &pb, &q, NULL, &r), 0);
    assert_true(r.collides);
    /* touching faces do not collide: shift of exactly 3 */
    pb.t[0] = 3;
    assert_int_equal(obb_collide(ta, &POSE_IDENTITY, tb, &pb, NULL, NULL, &r), 0);
    assert_false(r.collides);
    assert_true(r.separation_mm >= 0 && r.separation_mm < 1e-5);
    obb_tree_free(ta);
    obb_tree_free(tb);
    tfrag_free(a);
    tfrag_free(b);
}

static void test_separation_is_a_lower_bound(void **st)
{
    int checked = 0;
    for (int n = 0; n < 30; n++) {
        frag *fa = random_frag(12, 1), *fb = random_frag(12, 1);
        obb_tree *ta = build(fa, 0, 1), *tb = build(fb, 0, 1);
        double reach = radius(fa) + radius(fb), o[3] = {0, 0, 0};
        for (int k = 0; k < 40; k++) {
            double dir[3] = {srand1(), srand1(), srand1()};
            double len = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]) + 1e-9;
            for (int i = 0; i < 3; i++)
                dir[i] /= len;
            double cb[3] = {dir[0] * reach * 0.6, dir[1] * reach * 0.6, dir[2] * reach * 0.6};
            pose pa = place(fa, random_rotation(), o), pb = place(fb, random_rotation(), cb);
            obb_result r;
            assert_int_equal(obb_collide(ta, &pa, tb, &pb, NULL, NULL, &r), 0);
            if (r.collides || !isfinite(r.separation_mm) || r.separation_mm <= 0)
                continue;
            /* A moved straight at B by just under the bound must still be clear */
            pose moved = pa;
            for (int i = 0; i < 3; i++)
                moved.t[i] += dir[i] * r.separation_mm * 0.999;
            obb_result rb;
            assert_int_equal(obb_collide_brute(fa, &moved, fb, &pb, NULL, NULL, &rb), 0);
            assert_false(rb.collides);
            checked++;
        }
        obb_tree_free(ta);
        obb_tree_free(tb);
        tfrag_free(fa);
        tfrag_free(fb);
    }
    assert_true(checked > 100);
}

static void test_bad_input(void **st)
{
    frag *f = tfrag_new(2, 2, 2, 1, 1, 1);
    obb_params bad = {0.8, 0.2};
    assert_null(obb_tree_build(f, &bad));
    assert_non_null(strstr(fn_err_msg(), "tau_min"));
    f->spacing[1] = 0;
    assert_null(obb_tree_build(f, NULL));
    assert_non_null(strstr(fn_err_msg(), "spacing[1]"));
    f->spacing[1] = 1;
    f->dim[2] = 70000;
    assert_null(obb_tree_build(f, NULL));
    assert_non_null(strstr(fn_err_msg(), "dim[2]"));
    f->dim[2] = 2;
    setenv("FRACNAV_MAX_BYTES", "16", 1); /* 8 voxels need 40 bytes */
    assert_null(obb_tree_build(f, NULL));
    assert_int_equal(strstr(fn_err_msg(), "test2x2x2") != NULL, 1);
    unsetenv("FRACNAV_MAX_BYTES");
    fill(f, 0, 0, 0, 1, 1, 1, 255);
    obb_tree *t = obb_tree_build(f, NULL);
    assert_non_null(t);
    obb_result r;
    obb_query q = {.tolerance_mm = 0.5};
    assert_int_equal(obb_collide(t, &POSE_IDENTITY, t, &POSE_IDENTITY, &q, NULL, &r), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "tolerance_mm"));
    q = (obb_query){.threshold = NAN};
    assert_int_equal(obb_collide(t, &POSE_IDENTITY, t, &POSE_IDENTITY, &q, NULL, &r), FN_EINVAL);
    pose nan = POSE_IDENTITY;
    nan.t[1] = NAN;
    assert_int_equal(obb_collide(t, &nan, t, &POSE_IDENTITY, NULL, NULL, &r), FN_EINVAL);
    obb_tree_free(t);
    tfrag_free(f);
}

/* Several threads query the same read-only trees at once, each with its own cache, in different
 * orders: every answer equals the one-thread answer, and no thread allocates while querying. */
#define MT_THREADS 4
#define MT_POSES 300

typedef struct mt_job {
    const obb_tree *ta, *tb;
    const pose *pa, *pb;
    const obb_query *q;
    obb_cache *cache;
    int offset;
    pthread_barrier_t *go, *done;
    obb_result r[MT_POSES];
    int rc;
} mt_job;

/* The same pairs in any order (a cache may find them in another order). */
static int same_pairs(const obb_pair *x, const obb_pair *y, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        size_t k = 0;
        while (k < n && memcmp(&x[i], &y[k], sizeof *x))
            k++;
        if (k == n)
            return 0;
    }
    return 1;
}

static void *mt_run(void *arg)
{
    mt_job *j = arg;
    pthread_barrier_wait(j->go);
    for (int k = 0; k < MT_POSES; k++) {
        int i = (k + j->offset) % MT_POSES;
        j->rc |= obb_collide(j->ta, &j->pa[i], j->tb, &j->pb[i], &j->q[i], j->cache, &j->r[i]);
    }
    pthread_barrier_wait(j->done);
    return NULL;
}

static void test_concurrent_queries_allocate_nothing(void **st)
{
    frag *fa = random_frag(20, 1), *fb = random_frag(20, 1);
    obb_tree *ta = build(fa, 0, 1), *tb = build(fb, 0, 1);
    static pose pa[MT_POSES], pb[MT_POSES];
    static obb_query q[MT_POSES];
    static obb_pair pairs[MT_THREADS + 1][MT_POSES][8];
    static obb_result want[MT_POSES];
    double reach = radius(fa) + radius(fb), o[3] = {0, 0, 0};
    int hits = 0;
    for (int i = 0; i < MT_POSES; i++) {
        double off[3] = {srand1(), srand1(), srand1()};
        double len = sqrt(off[0] * off[0] + off[1] * off[1] + off[2] * off[2]) + 1e-9;
        double d = reach * (0.2 + 0.7 * urand()) / len, cb[3] = {off[0] * d, off[1] * d, off[2] * d};
        pa[i] = place(fa, random_rotation(), o);
        pb[i] = place(fb, random_rotation(), cb);
        q[i] = (obb_query){.want_pairs = i % 3 == 0, .pairs = pairs[MT_THREADS][i], .max_pairs = 8,
                           .order = i % 2 ? OBB_BREADTH_FIRST : OBB_DEPTH_FIRST};
        assert_int_equal(obb_collide(ta, &pa[i], tb, &pb[i], &q[i], NULL, &want[i]), 0);
        hits += want[i].collides;
    }
    if (hits < MT_POSES / 10 || hits > MT_POSES * 9 / 10)
        fail_msg("%d of %d poses collide: too few of one answer to compare", hits, MT_POSES);
    pthread_barrier_t go, done;
    pthread_barrier_init(&go, NULL, MT_THREADS + 1);
    pthread_barrier_init(&done, NULL, MT_THREADS + 1);
    mt_job *job = calloc(MT_THREADS, sizeof *job);
    static obb_query tq[MT_THREADS][MT_POSES];
    pthread_t th[MT_THREADS];
    for (int t = 0; t < MT_THREADS; t++) {
        for (int i = 0; i < MT_POSES; i++)
            tq[t][i] = q[i], tq[t][i].pairs = pairs[t][i];
        job[t] = (mt_job){.ta = ta, .tb = tb, .pa = pa, .pb = pb, .q = tq[t],
                          .cache = calloc(1, sizeof(obb_cache)), .offset = t * 37, .go = &go, .done = &done};
        assert_int_equal(pthread_create(&th[t], NULL, mt_run, &job[t]), 0);
    }
    allocount_start();
    pthread_barrier_wait(&go);
    pthread_barrier_wait(&done);
    long allocs = allocount_stop();
    for (int t = 0; t < MT_THREADS; t++) {
        pthread_join(th[t], NULL);
        assert_int_equal(job[t].rc, 0);
        for (int i = 0; i < MT_POSES; i++) {
            const obb_result *g = &job[t].r[i], *w = &want[i];
            if (g->collides != w->collides || g->pairs_total != w->pairs_total ||
                g->npairs != w->npairs || !same_pairs(pairs[t][i], pairs[MT_THREADS][i], g->npairs))
                fail_msg("thread %d pose %d: collides %d pairs %zu, one thread said %d pairs %zu", t, i,
                         g->collides, g->pairs_total, w->collides, w->pairs_total);
        }
        free(job[t].cache);
    }
    if (allocount_available() && allocs)
        fail_msg("%ld heap allocations while %d threads queried", allocs, MT_THREADS);
    free(job);
    pthread_barrier_destroy(&go);
    pthread_barrier_destroy(&done);
    obb_tree_free(ta);
    obb_tree_free(tb);
    tfrag_free(fa);
    tfrag_free(fb);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sat_touching_and_gaps),
        cmocka_unit_test(test_sat_random_against_vertices),
        cmocka_unit_test(test_prune_solid_and_uncertain),
        cmocka_unit_test(test_prune_single_child_chain),
        cmocka_unit_test(test_tree_matches_brute_force),
        cmocka_unit_test(test_cache_follows_small_steps),
        cmocka_unit_test(test_pairs_listed),
        cmocka_unit_test(test_separation_is_a_lower_bound),
        cmocka_unit_test(test_bad_input),
        cmocka_unit_test(test_concurrent_queries_allocate_nothing),
        cmocka_unit_test(test_answers_ignore_history), /* last: it draws random numbers the others use */
        cmocka_unit_test(test_front_moves_with_the_pose), /* last: it draws from the shared random sequence */
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
