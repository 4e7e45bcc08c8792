/* Automatic reduction: principal axes of analytic shapes, the VOI metric against brute-force
 * counting, Powell's method on analytic functions, and small synthetic fractures (two and three
 * pieces) reduced within 1 mm and 1 degree, the result saved and reloaded. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "case_journal.h"
#include "journal.h"
#include "err.h"
#include "frag.h"
#include "fracture.h"
#include "powell.h"
#include "obb.h"
#include "reduce.h"
#include "reduce_impl.h"
#include "testutil.h"
#include "volio.h"

#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <stdatomic.h>
#include <string.h>

/* ---- principal axes ---- */

/* A solid 40x10x6 box turned about z by 30 degrees: its long axis is the turned x axis, its
 * eigenvalues those of a uniform box, (L^2 - 1) / 12 per side in voxel units. */
static void test_pca_box(void **st)
{
    frag f;
    int dim[3] = {40, 10, 6};
    double at[3] = {5, -3, 2};
    tu_box_frag(&f, 1, dim, at);
    double axis[3] = {0, 0, 1};
    pose turn = pose_from_axis_angle(axis, M_PI / 6);
    f.home = pose_compose(turn, f.home);
    frag_stats(&f);
    assert_int_equal(f.voxels, 40 * 10 * 6);
    double want[3] = {cos(M_PI / 6), sin(M_PI / 6), 0};
    double dot = fabs(f.axes[0][0] * want[0] + f.axes[1][0] * want[1] + f.axes[2][0] * want[2]);
    assert_true(dot > 1 - 1e-9);
    assert_true(fabs(f.eigval[0] - (40.0 * 40 - 1) / 12) < 1e-6);
    assert_true(fabs(f.eigval[1] - (10.0 * 10 - 1) / 12) < 1e-6);
    assert_true(fabs(f.eigval[2] - (6.0 * 6 - 1) / 12) < 1e-6);
    frag_free(&f);
}

/* A rod of voxels along the cube's diagonal: the long axis is (1,1,1)/sqrt(3). */
static void test_pca_diagonal_rod(void **st)
{
    frag f;
    int dim[3] = {30, 30, 30};
    double at[3] = {0, 0, 0};
    tu_box_frag(&f, 1, dim, at);
    memset(f.prob, 0, 30 * 30 * 30);
    for (int i = 0; i < 30; i++)
        f.prob[((size_t)i * 30 + i) * 30 + i] = 255;
    frag_stats(&f);
    double s = 1 / sqrt(3);
    assert_true(fabs(fabs(f.axes[0][0]) - s) < 1e-9 && fabs(fabs(f.axes[1][0]) - s) < 1e-9 &&
                fabs(fabs(f.axes[2][0]) - s) < 1e-9);
    assert_true(f.eigval[1] < 1e-9);
    frag_free(&f);
}

/* ---- the metric ---- */

/* A ball of radius r (voxel units) with a hole, so counts depend on the pose in every direction. */
static void ball_frag(frag *f, int id, int n, double r, const double at[3])
{
    int dim[3] = {n, n, n};
    tu_box_frag(f, id, dim, at);
    double c = (n - 1) / 2.0;
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++) {
                double x = i - c, y = j - c, z = k - c, d = sqrt(x * x + y * y + z * z);
                int hole = (x - 2) * (x - 2) + y * y + (z + 1) * (z + 1) < 9;
                f->prob[((size_t)k * n + j) * n + i] = d <= r && !hole ? 255 : 0;
            }
    f->spacing[2] = 1.25; /* anisotropic, as CT is */
    frag_stats(f);
}

static double urand(uint64_t *s)
{
    *s = *s * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*s >> 11) / 9007199254740992.0;
}

/* nasm 2: a third ball, turned and moved, joins the assembly (sampled on the first one's grid). */
static void check_metric(reduce_count mode, double band, int nasm)
{
    frag a, b, e;
    double at_a[3] = {0, 0, 0}, at_b[3] = {14, 2, -1}, at_e[3] = {8, 10, 6}, turn[3] = {0.3, -0.2, 0.5}, ec[3];
    ball_frag(&a, 1, 20, 9, at_a);
    ball_frag(&b, 2, 18, 8, at_b);
    ball_frag(&e, 3, 16, 7, at_e);
    e.pose = pose_from_rotvec(turn, (double[3]){0.4, -1.3, 0.7}); /* turned about its centroid */
    pose_rotate(&e.pose, e.centroid, ec);
    for (int k = 0; k < 3; k++)
        e.pose.t[k] += e.centroid[k] - ec[k];
    reduce_voi voi = {{3.3, -2.2, 0.4}, {27.1, 21.7, 24.9}};
    const frag *asm_[2] = {&a, &e};
    reduce_metric *m = reduce_metric_new(asm_, nasm, &b, &voi, mode, band);
    assert_non_null(m);
    uint64_t s = 7;
    for (int t = 0; t < 40; t++) {
        double rv[3], tr[3];
        for (int k = 0; k < 3; k++) {
            rv[k] = (urand(&s) - 0.5) * 0.6;
            tr[k] = (urand(&s) - 0.5) * 8;
        }
        pose p = pose_from_rotvec(rv, tr); /* turned about b's centroid, then moved by tr */
        double rc[3];
        pose_rotate(&p, b.centroid, rc);
        for (int k = 0; k < 3; k++)
            p.t[k] += b.centroid[k] - rc[k];
        if (t % 2) { /* the band made near p, as a fit makes it: the evaluation counts its voxels */
            double near_rv[3], near_t[3];
            for (int k = 0; k < 3; k++) {
                near_rv[k] = (urand(&s) - 0.5) * 0.02;
                near_t[k] = p.t[k] + (urand(&s) - 0.5) * 1.6;
            }
            pose ref = pose_compose(pose_from_rotvec(near_rv, (double[3]){0, 0, 0}), p);
            memcpy(ref.t, near_t, sizeof ref.t);
            assert_int_equal(reduce__metric_rebase(m, &ref), 0);
            size_t nv = 0;
            for (size_t r = 0; r < m->nband; r++)
                nv += m->band[r].len;
            assert_true(nv > 0 && (band == 0 || nasm > 1 || nv < m->b->voxels)); /* the band: a part */
        }
        reduce_counts fast, slow;
        double f = reduce_metric_eval(m, &p, &fast);
        double g = reduce_metric_brute(asm_, nasm, &b, &p, &voi, mode, band, &slow);
        assert_true(fast.n1 == slow.n1 && fast.nvoi == slow.nvoi);
        assert_true(slow.n2 > 0);
        if (mode == REDUCE_TRILINEAR) {
            assert_true(fabs(fast.n2 - slow.n2) < 1e-6 * (1 + slow.n2));
            assert_true(fabs(fast.ni - slow.ni) < 1e-6 * (1 + slow.ni));
            assert_true(fabs(f - g) < 1e-9);
            /* the fit's own evaluation (no counts asked for) interpolates the one score field */
            double h = reduce_metric_eval(m, &p, NULL);
            if (!(fabs(h - g) < 1e-9))
                fail_msg("trilinear metric without counts %.12f, brute force %.12f", h, g);
        } else { /* the same cells, but for a centre exactly between two (rounding differs) */
            assert_true(fabs(fast.n2 - slow.n2) <= 2 && fabs(fast.ni - slow.ni) <= 2);
        }
    }
    reduce_metric_free(m);
    frag_free(&a);
    frag_free(&b);
    frag_free(&e);
}

static void test_metric_trilinear_vs_brute(void **st)
{
    check_metric(REDUCE_TRILINEAR, 0, 1);
    check_metric(REDUCE_TRILINEAR, 2, 1);
    check_metric(REDUCE_TRILINEAR, 2, 2);
    check_metric(REDUCE_TRILINEAR, 1.3, 1); /* a face and its edge in-plane, not the slice's edges */
}

static void test_metric_nearest_vs_brute(void **st)
{
    check_metric(REDUCE_NEAREST, 0, 1);
    check_metric(REDUCE_NEAREST, 2, 1);
    check_metric(REDUCE_NEAREST, 2, 2);
    check_metric(REDUCE_NEAREST, 1.3, 1); /* a face and its edge in-plane, not the slice's edges */
}

/* ---- the contact zone ---- */

/* Every bone voxel of f at its pose, as float points, appended to p (n of them so far). */
static float *zone_points(const frag *f, float *p, size_t *n)
{
    p = realloc(p, (*n + f->voxels) * 3 * sizeof *p);
    assert_non_null(p);
    pose w = pose_compose(f->pose, f->home);
    for (int k = 0; k < f->dim[2]; k++)
        for (int j = 0; j < f->dim[1]; j++)
            for (int i = 0; i < f->dim[0]; i++)
                if (f->prob[((size_t)k * f->dim[1] + j) * f->dim[0] + i]) {
                    double l[3] = {i * f->spacing[0], j * f->spacing[1], k * f->spacing[2]}, x[3];
                    pose_apply(&w, l, x);
                    for (int a = 0; a < 3; a++)
                        p[3 * *n + a] = (float)x[a];
                    ++*n;
                }
    return p;
}

/* The distinct cells among c[0..n-1] (malloc'd, *nu of them). */
static int (*distinct_cells(int (*c)[3], size_t n, size_t *nu))[3]
{
    int(*u)[3] = malloc((n + 1) * sizeof *u);
    assert_non_null(u);
    *nu = 0;
    for (size_t i = 0; i < n; i++) {
        size_t q = 0;
        while (q < *nu && memcmp(u[q], c[i], sizeof u[q]))
            q++;
        if (q == *nu)
            memcpy(u[(*nu)++], c[i], sizeof u[0]);
    }
    return u;
}

/* reduce_auto_voi as reduce.h defines it, by brute force: on a grid of zone_cell_mm cells whose
 * corner lies a cell below both sides' points, a point is near the other side when one of its
 * points lies within ceil(delta / cell) cells along each axis; delta doubles from delta0 until some
 * are; the VOI is the box of the near points of both sides, grown by margin. 0, or -1 when no
 * delta up to zone_reach_mm finds any. */
static int brute_zone(const frag *const *asm_, int nasm, const frag *mv, double delta0, double margin,
                      reduce_voi *voi)
{
    size_t na = 0, nm = 0;
    float *A = NULL, *M = zone_points(mv, NULL, &nm);
    for (int f = 0; f < nasm; f++)
        A = zone_points(asm_[f], A, &na);
    const double cs = reduce__tune.zone_cell_mm;
    double lo[3] = {INFINITY, INFINITY, INFINITY};
    for (size_t i = 0; i < na + nm; i++)
        for (int a = 0; a < 3; a++) {
            double x = i < na ? A[3 * i + a] : M[3 * (i - na) + a];
            lo[a] = x < lo[a] ? x : lo[a];
        }
    int (*ca)[3] = malloc(na * sizeof *ca), (*cm)[3] = malloc(nm * sizeof *cm), rc = -1;
    assert_true(ca && cm);
    for (int a = 0; a < 3; a++)
        lo[a] -= cs; /* the grid's corner */
    for (size_t i = 0; i < na; i++)
        for (int a = 0; a < 3; a++)
            ca[i][a] = (int)((A[3 * i + a] - lo[a]) / cs);
    for (size_t i = 0; i < nm; i++)
        for (int a = 0; a < 3; a++)
            cm[i][a] = (int)((M[3 * i + a] - lo[a]) / cs);
    size_t nua, num;
    int(*ua)[3] = distinct_cells(ca, na, &nua), (*um)[3] = distinct_cells(cm, nm, &num);
    for (double delta = delta0; rc < 0 && delta <= reduce__tune.zone_reach_mm; delta *= 2) {
        int k = (int)ceil(delta / cs);
        double blo[3] = {INFINITY, INFINITY, INFINITY}, bhi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (int side = 0; side < 2; side++) { /* side 0: the moving points near the assembly */
            size_t n = side ? na : nm, no = side ? num : nua;
            int(*c)[3] = side ? ca : cm, (*co)[3] = side ? um : ua; /* near one of the other's cells */
            const float *P = side ? A : M;
            for (size_t i = 0; i < n; i++) {
                int near = 0;
                for (size_t q = 0; q < no && !near; q++)
                    near = abs(c[i][0] - co[q][0]) <= k && abs(c[i][1] - co[q][1]) <= k && abs(c[i][2] - co[q][2]) <= k;
                for (int a = 0; near && a < 3; a++) {
                    blo[a] = fmin(blo[a], P[3 * i + a]);
                    bhi[a] = fmax(bhi[a], P[3 * i + a]);
                }
                rc = near && side == 0 ? 0 : rc;
            }
        }
        for (int a = 0; rc == 0 && a < 3; a++) {
            voi->lo[a] = blo[a] - margin;
            voi->hi[a] = bhi[a] + margin;
        }
    }
    free(A), free(M), free(ca), free(cm), free(ua), free(um);
    return rc;
}

/* The contact zone (reduce_auto_voi, what every stage of a fit works over) against brute force,
 * bit for bit: the moving ball near the assembly, apart from it (the distance doubles), beyond
 * the assembly's lower corner (the grid's corner follows the moving piece), and turned; with one
 * and two pieces in the assembly. The zone looks only near the moving piece, brick by brick
 * (reduce_voi.c); this checks that it finds what a look at everything finds. */
static void test_auto_voi_vs_brute(void **st)
{
    frag a, b, e;
    double at_a[3] = {0, 0, 0}, at_b[3] = {14, 2, -1}, at_e[3] = {8, 10, 6}, turn[3] = {0.3, -0.2, 0.5};
    ball_frag(&a, 1, 20, 9, at_a);
    ball_frag(&b, 2, 18, 8, at_b);
    ball_frag(&e, 3, 16, 7, at_e);
    e.pose = pose_from_rotvec(turn, (double[3]){0.4, -1.3, 0.7});
    const frag *asm_[2] = {&a, &e};
    static const double moves[][6] = {
        {0, 0, 0, 0, 0, 0},          {0.2, -0.3, 0.1, 1.5, -0.5, 0.8}, /* touching */
        {0, 0, 0, 9, 4, -3},         {0.5, 0.1, -0.4, 21, -6, 2},      /* apart: 3 mm, then more */
        {0, 0, 0, -40, -30, -25},    {-0.3, 0.6, 0.2, -30, -4, -12},   /* below the corner */
        {1.2, -0.7, 0.4, -6, 3, 2},  {0, 0, 0, 55, 0, 0},              /* turned; far */
    };
    int found = 0;
    for (int nasm = 1; nasm <= 2; nasm++)
        for (size_t t = 0; t < sizeof moves / sizeof moves[0]; t++) {
            b.pose = pose_from_rotvec(moves[t], moves[t] + 3);
            for (int d = 0; d < 2; d++) {
                double delta = d ? 2 : 3, margin = d ? 0 : 6;
                reduce_voi want, got;
                int rw = brute_zone(asm_, nasm, &b, delta, margin, &want);
                int rg = reduce_auto_voi(asm_, nasm, &b, delta, margin, 0, &got, NULL);
                if (rw < 0) {
                    assert_int_equal(rg, FN_EINVAL);
                    continue;
                }
                assert_int_equal(rg, 0);
                found++;
                for (int k = 0; k < 3; k++)
                    if (got.lo[k] != want.lo[k] || got.hi[k] != want.hi[k])
                        fail_msg("move %zu, %d piece(s), delta %g: axis %d [%.9g, %.9g], brute force [%.9g, %.9g]", t,
                                 nasm, delta, k, got.lo[k], got.hi[k], want.lo[k], want.hi[k]);
            }
        }
    assert_true(found >= 24); /* most moves find a zone; the far one may not */
    frag_free(&a);
    frag_free(&b);
    frag_free(&e);
}

/* The trilinear count changes continuously: a tiny step changes it a tiny bit. */
static void test_metric_trilinear_is_continuous(void **st)
{
    frag a, b;
    double at_a[3] = {0, 0, 0}, at_b[3] = {14, 2, -1};
    ball_frag(&a, 1, 20, 9, at_a);
    ball_frag(&b, 2, 18, 8, at_b);
    reduce_voi voi = {{3.3, -2.2, 0.4}, {27.1, 21.7, 24.9}};
    const frag *asm_[1] = {&a};
    reduce_metric *m = reduce_metric_new(asm_, 1, &b, &voi, REDUCE_TRILINEAR, 0);
    pose p = POSE_IDENTITY;
    double prev = reduce_metric_eval(m, &p, NULL);
    for (int i = 1; i <= 200; i++) {
        p.t[0] = -0.01 * i;
        double f = reduce_metric_eval(m, &p, NULL);
        assert_true(fabs(f - prev) < 0.01);
        prev = f;
    }
    reduce_metric_free(m);
    frag_free(&a);
    frag_free(&b);
}

/* ---- Powell ---- */

static double rosenbrock(const double *x, void *ctx)
{
    (*(int *)ctx)++;
    return 100 * (x[1] - x[0] * x[0]) * (x[1] - x[0] * x[0]) + (1 - x[0]) * (1 - x[0]);
}

static void test_powell_rosenbrock(void **st)
{
    int calls = 0;
    double x[2] = {-1.2, 1};
    powell_opts o;
    powell_defaults(&o);
    o.xtol = 1e-7;
    o.line_tol = 1e-8;
    o.ftol = 1e-14;
    powell_stats s;
    assert_int_equal(powell_minimize(rosenbrock, &calls, x, 2, &o, &s), 0);
    assert_true(fabs(x[0] - 1) < 1e-3 && fabs(x[1] - 1) < 2e-3);
    assert_true(s.f < 1e-6);
    assert_int_equal(s.evaluations, calls);
}

/* A coupled 6-D quadratic (x - c)^T A (x - c) with A = B^T B + I. */
static double quadratic(const double *x, void *ctx)
{
    static const double B[6][6] = {{2, 1, 0, 0, 0.5, 0}, {0, 3, 1, 0, 0, 0},   {1, 0, 1, 2, 0, 0},
                                   {0, 0, 0, 1, 1, 0},   {0.5, 0, 0, 0, 2, 1}, {0, 1, 0, 0, 0, 4}};
    static const double c[6] = {1, -2, 3, 0.5, -1, 2};
    double f = 0;
    for (int i = 0; i < 6; i++) {
        double r = 0;
        for (int j = 0; j < 6; j++)
            r += B[i][j] * (x[j] - c[j]);
        f += r * r + (x[i] - c[i]) * (x[i] - c[i]);
    }
    (void)ctx;
    return f;
}

static void test_powell_quadratic(void **st)
{
    double x[6] = {0, 0, 0, 0, 0, 0};
    static const double c[6] = {1, -2, 3, 0.5, -1, 2};
    powell_opts o;
    powell_defaults(&o);
    o.xtol = 1e-8;
    o.line_tol = 1e-8;
    o.ftol = 1e-15;
    powell_stats s;
    assert_int_equal(powell_minimize(quadratic, NULL, x, 6, &o, &s), 0);
    for (int i = 0; i < 6; i++)
        assert_true(fabs(x[i] - c[i]) < 1e-4);
    assert_true(s.converged);
}

static void test_powell_bad_arguments(void **st)
{
    double x[2] = {0, 0};
    powell_opts o;
    powell_defaults(&o);
    o.step = 0;
    assert_int_equal(powell_minimize(rosenbrock, NULL, x, 2, &o, NULL), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "powell"));
}

/* ---- synthetic fractures ---- */


static planning_case *fractured_loss(const char *dir, int pieces, uint64_t seed, double loss_mm)
{
    return tu_ellipsoid_fracture(dir, pieces, seed, loss_mm);
}

static planning_case *fractured(const char *dir, int pieces, uint64_t seed)
{
    return fractured_loss(dir, pieces, seed, 0);
}

static void check_errors(const planning_case *c, int fixed, double mm, double deg)
{
    for (int i = 0; i < c->nfrag; i++) {
        if (i == fixed)
            continue;
        double rot, trans, tre;
        assert_int_equal(reduce_truth_errors(c, fixed, i, &rot, &trans, &tre), 0);
        if (!(rot <= deg && trans <= mm))
            fail_msg("fragment %d: %.3f deg, %.3f mm (TRE %.3f mm)", c->frag[i].id, rot, trans, tre);
    }
}

static void test_reduce_two_pieces(void **st)
{
    char *dir = tu_tmpdir("reduce2");
    planning_case *c = fractured(dir, 2, 3);
    reduce_opts o;
    reduce_defaults(&o);
    o.prealign = 0;
    reduce_result r[1];
    int mv[1] = {1};
    assert_int_equal(reduce_case(c, 0, mv, 1, &o, r), 0);
    check_errors(c, 0, 1, 1);
    assert_true(r[0].metric_end < r[0].metric_start);
    assert_true(r[0].nhistory >= 2);
    assert_int_equal(r[0].collides, 0);
    assert_true(r[0].eval_cpu_s > 0); /* the fit's own evaluations are timed */
    /* the result is stored and comes back from disk */
    assert_int_equal(case_set_reduction(c, 0, &o, r, 1), 0);
    assert_int_equal(case_save(c), 0);
    pose want = c->frag[1].pose;
    planning_case *back = case_load(dir);
    assert_non_null(back);
    assert_true(pose_angle_between(back->frag[1].pose, want) < 1e-9 && pose_distance(back->frag[1].pose, want) < 1e-9);
    json_t *red = json_object_get((json_t *)back->extra, "reduction");
    assert_non_null(red);
    assert_string_equal(json_string_value(json_object_get(red, "method")), reduce_method_name(o.method));
    json_t *fr = json_array_get(json_object_get(red, "fragments"), 0);
    assert_int_equal(json_integer_value(json_object_get(fr, "id")), 2);
    assert_int_equal((int)json_array_size(json_object_get(fr, "history")), r[0].nhistory);
    assert_int_equal((int)json_array_size(json_object_get(fr, "voi_mm")), 6);
    check_errors(back, 0, 1, 1);
    case_free(back);
    reduce_result_free(&r[0]);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* 1 mm of bone lost at the cut: the true pose leaves a gap, which the fit closes unless told of
 * it (without gap_mm: 1.1 mm off); told (reduce --gap 1), it lands within 1 mm and 1 degree. */
static void test_reduce_gap(void **st)
{
    char *dir = tu_tmpdir("reduce_gap");
    planning_case *c = fractured_loss(dir, 2, 3, 1);
    reduce_opts o;
    reduce_defaults(&o);
    o.prealign = 0;
    o.gap_mm = 1;
    reduce_result r[1];
    int mv[1] = {1};
    assert_int_equal(reduce_case(c, 0, mv, 1, &o, r), 0);
    check_errors(c, 0, 1, 1);
    assert_int_equal(r[0].collides, 0);
    reduce_result_free(&r[0]);
    case_free(c);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "reduce %s --gap -1", dir), 2);
    assert_non_null(strstr(out, "--gap"));
    free(out);
    tu_rmtree(dir);
    free(dir);
}

static void test_reduce_three_pieces(void **st)
{
    char *dir = tu_tmpdir("reduce3");
    planning_case *c = fractured(dir, 3, 5);
    reduce_opts o;
    reduce_defaults(&o);
    o.prealign = 0;
    reduce_result r[2];
    assert_int_equal(reduce_case(c, 0, NULL, 2, &o, r), 0);
    check_errors(c, 0, 1, 1);
    /* each piece's start and end metric say what the reduction did, not only its second sweep
     * (issue 27: "metric -0.722651 -> -0.722651" for pieces moved by 5-7 mm) */
    for (int i = 0; i < 2; i++)
        if (!(r[i].metric_end < r[i].metric_start - 0.01))
            fail_msg("piece %d: metric %.6f -> %.6f", i + 2, r[i].metric_start, r[i].metric_end);
    for (int i = 0; i < 2; i++)
        reduce_result_free(&r[i]);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* The second sweep fits pieces apart from each other at once: on two threads the same poses, to
 * the bit, as on one (a wave of two or more pieces among them). */
#define PAR_PIECES 5
#define PAR_SEED 2
static void test_reduce_parallel_pairs(void **st)
{
    char *dir = tu_tmpdir("reduce_par");
    char *dir2 = tu_tmpdir("reduce_par2");
    planning_case *c[2] = {fractured(dir, PAR_PIECES, PAR_SEED), fractured(dir2, PAR_PIECES, PAR_SEED)};
    reduce_result r[2][PAR_PIECES - 1];
    int widest = 0;
    for (int t = 0; t < 2; t++) {
        reduce_opts o;
        reduce_defaults(&o);
        o.prealign = 0;
        o.threads = t + 1;
        assert_int_equal(reduce_case(c[t], 0, NULL, PAR_PIECES - 1, &o, r[t]), 0);
    }
    for (int i = 0; i < PAR_PIECES - 1; i++) {
        assert_int_equal(r[0][i].id, r[1][i].id);
        assert_int_equal(r[0][i].evaluations, r[1][i].evaluations);
        assert_int_equal(r[0][i].wave, r[1][i].wave);
        widest = r[0][i].wave > widest ? r[0][i].wave : widest;
        reduce_result_free(&r[0][i]);
        reduce_result_free(&r[1][i]);
    }
    for (int f = 0; f < PAR_PIECES; f++)
        assert_memory_equal(&c[0]->frag[f].pose, &c[1]->frag[f].pose, sizeof(pose));
    assert_true(widest >= 2);
    case_free(c[0]);
    case_free(c[1]);
    tu_rmtree(dir);
    tu_rmtree(dir2);
    free(dir);
    free(dir2);
}

/* Every NLopt method runs and improves the metric. */
static void test_reduce_nlopt_methods(void **st)
{
    char *dir = tu_tmpdir("reduce_nlopt");
    planning_case *c = fractured(dir, 2, 3);
    pose placed = c->frag[1].pose;
    for (int m = REDUCE_PRAXIS; m < REDUCE_METHODS; m++) {
        reduce_opts o;
        reduce_defaults(&o);
        o.prealign = 0;
        o.method = (reduce_method)m;
        reduce_result r;
        c->frag[1].pose = placed;
        const frag *asm_[1] = {&c->frag[0]};
        assert_int_equal(reduce_pair(asm_, 1, &c->frag[1], &o, &r), 0);
        assert_true(r.metric_end < r.metric_start);
        assert_true(r.evaluations > 10);
        reduce_result_free(&r);
    }
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

typedef struct fit_watch {
    int calls, last_iter;
    atomic_int *cancel_at_first;
} fit_watch;

static void on_progress(void *ctx, int id, int iter, int evals, double f, double seconds)
{
    fit_watch *w = ctx;
    (void)id, (void)evals, (void)f, (void)seconds;
    w->calls++;
    w->last_iter = iter;
    if (w->cancel_at_first)
        atomic_store(w->cancel_at_first, 1);
}

/* The worker-thread API: from the hand's pose, against the others, with progress; the fragments
 * given are left as they were; a cancel returns 1 with the start pose. */
static void test_fit_one(void **st)
{
    char *dir = tu_tmpdir("reduce_fit_one");
    planning_case *c = fractured(dir, 2, 3);
    pose placed = c->frag[1].pose;
    const frag *others[1] = {&c->frag[0]};
    reduce_opts o;
    reduce_defaults(&o);
    o.prealign = 1; /* ignored: a session's fit starts where the hand left the fragment */
    fit_watch w = {0};
    atomic_int cancel = 0;
    o.progress = on_progress;
    o.progress_ctx = &w;
    o.cancel = &cancel;
    pose out;
    reduce_result r;
    assert_int_equal(reduce_fit_one(others, 1, &c->frag[1], &placed, &o, &out, &r), 0);
    assert_true(w.calls >= 1 && w.last_iter >= 1);
    assert_int_equal(r.prealigned, 0);
    assert_int_equal(r.collides, 0);
    assert_true(pose_distance(c->frag[1].pose, placed) < 1e-12); /* the caller's fragment untouched */
    c->frag[1].pose = out;
    check_errors(c, 0, 1, 1);
    reduce_result_free(&r);
    /* cancelled at the first progress report */
    w = (fit_watch){.cancel_at_first = &cancel};
    assert_int_equal(reduce_fit_one(others, 1, &c->frag[1], &placed, &o, &out, &r), 1);
    assert_int_equal(w.calls, 1);
    assert_true(pose_distance(out, placed) < 1e-12 && pose_angle_between(out, placed) < 1e-12);
    reduce_result_free(&r);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* reduce starts from the poses a navigation session left in CASE/journal (where the hand left
 * the fragment), saves the result, and empties the journal. */
static void test_cli_from_journal(void **st)
{
    char *dir = tu_tmpdir("reduce_journal"), *out = NULL;
    planning_case *c = fractured(dir, 2, 3);
    /* the hand left fragment 2 half way back: 2 mm and 2 degrees from its true pose */
    pose want = c->truth[1];
    double axis[3] = {0, 0.6, 0.8}, cw[3], rc2[3];
    pose turn = pose_from_axis_angle(axis, 2 * M_PI / 180), hand = pose_compose(turn, want);
    pose_apply(&want, c->frag[1].centroid, cw);
    pose_rotate(&turn, cw, rc2);
    for (int a = 0; a < 3; a++)
        hand.t[a] += cw[a] - rc2[a] + (a == 0 ? 2 : 0);
    journal_bind b;
    case_journal_bind(c, &b);
    journal *j = journal_open(dir, &b);
    if (!j)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(journal_append(j, JOURNAL_MOVE, 1, 1000, &hand, 1000), 0);
    assert_int_equal(journal_close(j), 0);
    case_free(c);
    int rc = tu_run_cli(&out, "reduce %s --no-prealign", dir);
    if (rc != 0 || !strstr(out, "journal"))
        fail_msg("rc %d: %s", rc, out);
    free(out);
    planning_case *back = case_load(dir);
    if (!back)
        fail_msg("%s", fn_err_msg());
    json_t *fr = json_array_get(json_object_get(json_object_get((json_t *)back->extra, "reduction"), "fragments"), 0);
    json_t *t = json_object_get(json_object_get(fr, "placed"), "t");
    for (int a = 0; a < 3; a++) /* the fit started where the journal left it */
        assert_true(fabs(json_real_value(json_array_get(t, a)) - hand.t[a]) < 1e-6);
    check_errors(back, 0, 1, 1);
    assert_int_equal(case_journal_pending(dir), 0);
    case_free(back);
    tu_rmtree(dir);
    free(dir);
}

/* The command: usage errors exit 2 naming the option, a missing case exits 1 naming it, and a
 * run prints one JSON object with the errors against the truth, and saves into -o. */
static void test_cli(void **st)
{
    char *dir = tu_tmpdir("reduce_cli"), *out = NULL, path[4200], cdir[4200], newcase[4200];
    snprintf(cdir, sizeof cdir, "%s/case", dir); /* -o beside it: never inside the case read */
    planning_case *c = fractured(cdir, 2, 3);
    case_free(c);
    assert_int_equal(tu_run_cli(&out, "reduce %s --method newton", cdir), 2);
    assert_non_null(strstr(out, "--method"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "reduce %s --voi 1 2 3", cdir), 2);
    assert_non_null(strstr(out, "--voi"));
    free(out);
    snprintf(path, sizeof path, "%s/none", dir);
    assert_int_equal(tu_run_cli(&out, "reduce %s", path), 1);
    assert_non_null(strstr(out, path));
    free(out);
    snprintf(newcase, sizeof newcase, "%s/reduced", dir);
    assert_int_equal(tu_run_cli(&out, "reduce %s --no-prealign --json -o %s 2>/dev/null", cdir, newcase), 0);
    json_error_t e;
    json_t *j = json_loads(out, 0, &e);
    if (!j)
        fail_msg("not JSON (%s): %s", e.text, out);
    assert_string_equal(json_string_value(json_object_get(j, "command")), "reduce");
    json_t *f = json_array_get(json_object_get(j, "fragments"), 0);
    assert_true(json_real_value(json_object_get(f, "rot_err_deg")) <= 1);
    assert_true(json_real_value(json_object_get(f, "trans_err_mm")) <= 1);
    assert_true(json_is_real(json_object_get(f, "tre_mm")) && json_is_integer(json_object_get(f, "evaluations")));
    assert_true(json_is_boolean(json_object_get(f, "single_answer")) && json_is_array(json_object_get(f, "candidates")));
    json_decref(j);
    free(out);
    planning_case *back = case_load(newcase);
    if (!back)
        fail_msg("%s", fn_err_msg());
    assert_non_null(json_object_get((json_t *)back->extra, "reduction"));
    check_errors(back, 0, 1, 1);
    case_free(back);
    tu_rmtree(dir);
    free(dir);
}

/* A navigation session's move, as its journal keeps it: fragment id of the case at cdir to pose p
 * (home -> world) at t_us. */
static void move_by_journal(const char *cdir, int id, const pose *p, int64_t t_us)
{
    planning_case *c = case_load(cdir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    journal_bind jb;
    case_journal_bind(c, &jb);
    journal *jn = journal_open(cdir, &jb);
    if (!jn)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(journal_append(jn, JOURNAL_MOVE, case_find(c, id), t_us, p, t_us), 0);
    assert_int_equal(journal_close(jn), 0);
    case_free(c);
}

/* `reduce CASE --no-prealign --json` (stderr into DIR/err): its JSON, or the test fails. */
static json_t *reduce_json(const char *cdir, const char *dir)
{
    char *out = NULL;
    int rc = tu_run_cli(&out, "reduce '%s' --no-prealign --json 2>'%s/err' | cat", cdir, dir);
    json_error_t e;
    json_t *j = rc == 0 ? json_loads(out, 0, &e) : NULL;
    if (!j)
        fail_msg("rc %d: %s", rc, out);
    free(out);
    return j;
}

/* Several pieces end to end, as a surgeon meets them: the example CT's 3-piece fracture of seed 4,
 * every piece where the fracture left it, reduced by `reduce CASE`, which places first the piece
 * whose fit gains most. The fit is chaotic at this scale: a placement a micrometre off, or the
 * float32 rounding of a NIfTI origin, can decide whether a piece comes back. So the case is reduced
 * four times, from where the fracture left the pieces and from placements 1, 2 and 3 um off (a
 * session's journal), and at least one run brings both pieces back within 1 mm and 1 degree.
 * Measured from nine such placements (0-8 um): both back in 7; with the order before (largest
 * contact where the hand left them) in none of the first three (one piece 17-41 degrees off). */
static void test_cli_three_pieces_of_the_skull(void **st)
{
#if defined(__SANITIZE_THREAD__)
    /* Four whole reductions of a skull in child processes: with one, test_reduce took 916 s under
     * ThreadSanitizer on two cores (bounded at 2,000). reduce_case's threads are checked there by
     * test_reduce_parallel_pairs; the plain and ASan stages run this test. */
    print_message("skipped under ThreadSanitizer: four whole reductions of the skull\n");
    skip();
#endif
    const char *ct = tu_example_ct();
    char *dir = tu_tmpdir("reduce_skull3"), *out = NULL, cdir[4200], odir[4300], said[4][200];
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    snprintf(odir, sizeof odir, "%s/reduced", dir);
    if (tu_run_cli(&out, "fracture %s -o %s --seed 4 --pieces 3", ct, cdir) != 0)
        fail_msg("fracture: %s", out);
    free(out);
    int all_back = 0;
    for (int run = 0; run < 4; run++) {
        pose off = POSE_IDENTITY; /* pieces 2 and 3 placed run um off where the fracture left them */
        off.t[0] = 1e-3 * run;
        off.t[1] = -1e-3 * run;
        for (int id = 2; run && id <= 3; id++)
            move_by_journal(cdir, id, &off, 1000 * run);
        if (tu_run_cli(&out, "reduce %s -o %s --force --json 2>/dev/null | cat", cdir, odir) != 0)
            fail_msg("reduce, run %d: %s", run, out);
        json_error_t e;
        json_t *j = json_loads(out, 0, &e), *frs = json_object_get(j, "fragments");
        if (!j)
            fail_msg("not JSON (%s): %s", e.text, out);
        assert_int_equal(json_array_size(frs), 2);
        int back = 0, at = 0;
        for (size_t i = 0; i < 2; i++) {
            json_t *f = json_array_get(frs, i);
            double rot = json_real_value(json_object_get(f, "rot_err_deg")),
                   trans = json_real_value(json_object_get(f, "trans_err_mm"));
            back += rot <= 1 && trans <= 1;
            at += snprintf(said[run] + at, sizeof said[run] - (size_t)at, " fragment %d %.3f deg %.3f mm;",
                           (int)json_integer_value(json_object_get(f, "id")), rot, trans);
        }
        all_back += back == 2;
        json_decref(j);
        free(out);
    }
    if (!all_back)
        fail_msg("no run brought both pieces back:\n as fractured:%s\n 1 um off:%s\n 2 um off:%s\n 3 um off:%s",
                 said[0], said[1], said[2], said[3]);
    tu_rmtree(dir);
    free(dir);
}

/* A piece that touches nothing in the CT (as a head holder, apart from the bone) is skipped when no
 * fragment is named, with a word, and fitted when --moving names it, or when the hand has brought
 * it next to another. Two blocks 3 mm apart (a fracture) and a third 30 mm beyond them. */
static void test_cli_skips_what_touches_nothing(void **st)
{
    char *dir = tu_tmpdir("reduce_skip"), *out = NULL, path[4200], cdir[4200];
    vol *v = vol_new(80, 32, 32);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = -1000;
    static const int box[3][6] = {{4, 16, 6, 26, 6, 26}, {18, 28, 10, 22, 10, 22}, {58, 70, 8, 20, 8, 20}};
    for (int b = 0; b < 3; b++)
        for (int k = box[b][4]; k < box[b][5]; k++)
            for (int j = box[b][2]; j < box[b][3]; j++)
                for (int i = box[b][0]; i < box[b][1]; i++)
                    v->data[vol_idx(v, i, j, k)] = 1000;
    snprintf(path, sizeof path, "%s/blocks.nii.gz", dir);
    assert_int_equal(volio_write(v, path, VOL_I16), 0);
    vol_free(v);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s' --min-volume 0 --ramp 0", path, cdir), 0);
    free(out);
    /* ids in scan order: the largest block (1) stays, the far one (2) touches nothing, 3 touches 1;
     * stderr goes to a file (tu_run_cli joins it to stdout) */
    int rc = tu_run_cli(&out, "reduce '%s' --no-prealign --json 2>'%s/err' | cat", cdir, dir);
    if (rc != 0)
        fail_msg("rc %d: %s", rc, out);
    json_error_t e;
    json_t *j = json_loads(out, 0, &e);
    if (!j)
        fail_msg("not JSON (%s): %s", e.text, out);
    json_t *frs = json_object_get(j, "fragments"), *sk = json_object_get(j, "skipped");
    assert_int_equal((int)json_array_size(frs), 1);
    assert_int_equal(json_integer_value(json_object_get(json_array_get(frs, 0), "id")), 3);
    assert_int_equal((int)json_array_size(sk), 1);
    assert_int_equal(json_integer_value(json_array_get(sk, 0)), 2);
    json_decref(j);
    free(out);
    char errpath[4300], said[512] = "";
    snprintf(errpath, sizeof errpath, "%s/err", dir);
    FILE *f = fopen(errpath, "r");
    assert_non_null(f);
    size_t n = fread(said, 1, sizeof said - 1, f);
    said[n] = 0;
    fclose(f);
    if (!strstr(said, "fragment 2 touches no other") || !strstr(said, "--moving 2"))
        fail_msg("no word of the skip: %s", said);
    /* asked for by name, it is fitted */
    assert_int_equal(tu_run_cli(&out, "reduce '%s' --moving 2 --no-prealign --json 2>/dev/null | cat", cdir), 0);
    j = json_loads(out, 0, &e);
    if (!j)
        fail_msg("not JSON (%s): %s", e.text, out);
    assert_int_equal(json_integer_value(json_object_get(json_array_get(json_object_get(j, "fragments"), 0), "id")), 2);
    assert_int_equal((int)json_array_size(json_object_get(j, "skipped")), 0);
    json_decref(j);
    free(out);
    /* brought by the hand to 2 mm from block 3 (a navigation session's journal), it is a piece to
     * fit, though it touches nothing in the CT */
    planning_case *c = case_load(cdir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    int i2 = case_find(c, 2), i3 = case_find(c, 3);
    pose hand = POSE_IDENTITY;
    double c3w[3]; /* block 3 where the fits above left it */
    pose_apply(&c->frag[i3].pose, c->frag[i3].centroid, c3w);
    for (int a = 0; a < 3; a++) /* block 2's centre 13 mm beyond block 3's, along x: 2 mm apart */
        hand.t[a] = c3w[a] + (a == 0 ? 13 : 0) - c->frag[i2].centroid[a];
    case_free(c);
    move_by_journal(cdir, 2, &hand, 1000);
    j = reduce_json(cdir, dir);
    frs = json_object_get(j, "fragments");
    int fitted2 = 0;
    for (size_t k = 0; k < json_array_size(frs); k++)
        fitted2 |= json_integer_value(json_object_get(json_array_get(frs, k), "id")) == 2;
    if (!fitted2 || json_array_size(json_object_get(j, "skipped")) != 0)
        fail_msg("block 2, moved next to block 3, not fitted: %s", json_dumps(j, 0));
    json_decref(j);
    /* the other way round, in a fresh case: block 3 dragged next to block 2, which no one moved (a
     * head holder a fragment was dragged to): block 2 stays out */
    snprintf(cdir, sizeof cdir, "%s/case2", dir);
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s' --min-volume 0 --ramp 0", path, cdir), 0);
    free(out);
    c = case_load(cdir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    hand = POSE_IDENTITY;
    for (int a = 0; a < 3; a++) /* block 3's centre 13 mm before block 2's, along x: 2 mm apart */
        hand.t[a] = c->frag[case_find(c, 2)].centroid[a] - (a == 0 ? 13 : 0) - c->frag[case_find(c, 3)].centroid[a];
    case_free(c);
    move_by_journal(cdir, 3, &hand, 1000);
    j = reduce_json(cdir, dir);
    sk = json_object_get(j, "skipped");
    if (json_array_size(sk) != 1 || json_integer_value(json_array_get(sk, 0)) != 2)
        fail_msg("block 2, which no one moved, not skipped: %s", json_dumps(j, 0));
    json_decref(j);
    tu_rmtree(dir);
    free(dir);
}

/* Pre-alignment (paper Fig. 5): a rod left far away and across brings its long axis onto the fixed
 * rod's and slides along it into contact, end to end. */
static void test_prealign_rods(void **st)
{
    frag a, b;
    int da[3] = {40, 8, 8}, db[3] = {30, 8, 8};
    double at_a[3] = {0, 0, 0}, at_b[3] = {40, 0, 0};
    tu_box_frag(&a, 1, da, at_a);
    tu_box_frag(&b, 2, db, at_b);
    frag_stats(&a);
    frag_stats(&b);
    double z[3] = {0, 0, 1}, c[3];
    pose turn = pose_from_axis_angle(z, M_PI / 2);
    pose_rotate(&turn, b.centroid, c);
    for (int k = 0; k < 3; k++) /* turned about its centroid, then moved 40 mm up in y */
        turn.t[k] = b.centroid[k] - c[k] + (k == 1 ? 40 : 0);
    b.pose = turn;
    reduce_opts o;
    reduce_defaults(&o);
    /* pre-alignment alone: two flat-ended boxes touch more side by side than end to end, and the
     * first stage's starts find both; the global check would take the side */
    o.global_check = 0;
    reduce_result r;
    const frag *asm_[1] = {&a};
    assert_int_equal(reduce_pair(asm_, 1, &b, &o, &r), 0);
    assert_int_equal(r.prealigned, 1);
    double ax[3];
    double bx[3] = {b.axes[0][0], b.axes[1][0], b.axes[2][0]};
    pose_rotate(&b.pose, bx, ax);
    assert_true(fabs(ax[0]) > 0.99);
    pose_apply(&b.pose, b.centroid, c);
    /* end to end on either side: centroids 35 mm apart along x, within a voxel or two */
    assert_true(fabs(fabs(c[0] - a.centroid[0]) - 35) < 2.5);
    assert_true(fabs(c[1] - a.centroid[1]) < 2.5 && fabs(c[2] - a.centroid[2]) < 2.5);
    assert_int_equal(r.collides, 0);
    reduce_result_free(&r);
    frag_free(&a);
    frag_free(&b);
}

/* A tube 100 mm long (elliptic section, semi-axes 7 by 6 mm, 2 mm of cortex around a canal,
 * slightly bowed) on a 0.7 mm grid: each piece of a cut is a long piece. */

static vol *tube(void)
{
    vol *v = vol_new(143, 30, 28);
    const double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, sp[3] = {0.7, 0.7, 0.7}, org[3] = {-50, -10.5, -9.8};
    vol_set_geometry(v, dir, sp, org);
    for (int k = 0; k < 28; k++)
        for (int j = 0; j < 30; j++)
            for (int i = 0; i < 143; i++) {
                double cy = 1.5 * sin(3.14159265 * i / 143.0), y = (j - 15) * 0.7 - cy, z = (k - 14) * 0.7;
                double r = sqrt((y / 7) * (y / 7) + (z / 6) * (z / 6));
                float bone = (float)(1000 + (i * 7 + j * 13 + k * 3) % 400);
                v->data[vol_idx(v, i, j, k)] = r <= 1 ? (r >= 1 - 2 / 6.5 ? bone : 40) : -50;
            }
    v->src_type = VOL_I16;
    return v;
}

/* The fit from a start turned deg about principal axis `axis` of piece 2 through its centroid
 * (true pose want), with o->hops = hops and o->global_check = global_check. */
/* m's pose want turned deg about its principal axis turn_axis (through its centroid) and moved mm
 * along its principal axis move_axis. */
static pose turned_moved(const frag *m, const pose *want, int turn_axis, double deg, int move_axis, double mm)
{
    double ax[3] = {m->axes[0][turn_axis], m->axes[1][turn_axis], m->axes[2][turn_axis]};
    double sx[3] = {m->axes[0][move_axis], m->axes[1][move_axis], m->axes[2][move_axis]};
    double aw[3], sw[3], cw[3], rc[3];
    pose_rotate(want, ax, aw);
    pose_rotate(want, sx, sw);
    pose_apply(want, m->centroid, cw);
    pose turn = pose_from_axis_angle(aw, deg * 3.14159265358979 / 180), start = pose_compose(turn, *want);
    pose_rotate(&turn, cw, rc);
    for (int a = 0; a < 3; a++)
        start.t[a] += cw[a] - rc[a] + mm * sw[a];
    return start;
}

static void fit_turned_about(const planning_case *c, const pose *want, int axis, double deg, int hops,
                             int global_check, reduce_result *r)
{
    const frag *m = &c->frag[1], *others[1] = {&c->frag[0]};
    pose start = turned_moved(m, want, axis, deg, axis, 0);
    reduce_opts o;
    reduce_defaults(&o);
    o.hops = hops;
    o.global_check = global_check;
    pose out;
    assert_int_equal(reduce_fit_one(others, 1, m, &start, &o, &out, r), 0);
    assert_int_equal(r->collides, 0);
}

/* The same about the long axis. */
static void fit_turned(const planning_case *c, const pose *want, double deg, int hops, reduce_result *r)
{
    fit_turned_about(c, want, 0, deg, hops, 1, r);
}

/* A piece that is not long hops strictly: the ellipsoid's piece of seed 8 has a rival basin, and
 * some of the starts below end two first-stage starts more than 1 degree apart at about the same
 * metric (which ones depends on the last bit of the metric's rounding: 2 of these 4 before the
 * metric's one-field count, all 4 after it). At the first that does, the candidates are kept; the
 * hops run (more evaluations than without them); a hop is kept only free of collision and better by
 * a margin, so the result is never worse than without hops, and where no round gained it is the
 * same pose. */
static void test_reduce_rival_hops(void **st)
{
    char *dir = tu_tmpdir("reduce_rival");
    planning_case *c = fractured(dir, 2, 8);
    assert_false(c->frag[1].eigval[0] > 4 * c->frag[1].eigval[1]);
    pose want = pose_compose(c->frag[0].pose, pose_compose(pose_inverse(c->truth[0]), c->truth[1]));
    static const struct {
        int axis;
        double deg;
    } turn[] = {{0, 12}, {2, -12}, {1, -8}, {1, 12}};
    int found = 0;
    for (size_t t = 0; t < sizeof turn / sizeof *turn && !found; t++) {
        reduce_result r0, r3;
        fit_turned_about(c, &want, turn[t].axis, turn[t].deg, 0, 0, &r0);
        fit_turned_about(c, &want, turn[t].axis, turn[t].deg, 3, 0, &r3);
        assert_int_equal(r0.hops, 0);
        if (!(r3.evaluations > r0.evaluations && r3.metric_end <= r0.metric_end + 1e-12))
            fail_msg("rival hops: metric %.6f (without %.6f), %d evaluations (without %d)", r3.metric_end,
                     r0.metric_end, r3.evaluations, r0.evaluations);
        if (r3.hops == 0) { /* the same pose (its quaternion compared as numbers: the angle between two
                             * equal ones, by acos near 1, can read 3e-8) */
            assert_true(pose_distance(r3.end, r0.end) < 1e-12);
            for (int k = 0; k < 4; k++)
                assert_true(fabs(r3.end.q[k] - r0.end.q[k]) < 1e-12);
        }
        if (r3.rival) {
            found = 1;
            /* no single answer: the candidates are kept, the best first, each with a metric */
            assert_true(r3.ncandidates >= 2);
            for (int i = 0; i < r3.ncandidates; i++)
                assert_true(isfinite(r3.candidate[i].metric) && r3.candidate[i].metric < 0);
            /* reduce's default: the global check after the local fit (more evaluations), which
             * ends free and no worse than where it started */
            reduce_result rg;
            fit_turned_about(c, &want, turn[t].axis, turn[t].deg, 3, 1, &rg);
            assert_true(rg.evaluations > r3.evaluations);
            assert_int_equal(rg.collides, 0);
            if (!(rg.metric_end <= rg.metric_start))
                fail_msg("rival basins, the global check: metric %.6f, at the start %.6f", rg.metric_end,
                         rg.metric_start);
            reduce_result_free(&rg);
        }
        reduce_result_free(&r0);
        reduce_result_free(&r3);
    }
    if (!found)
        fail_msg("no start of the ellipsoid's seed 8 ended in its rival basin");
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* The global check (reduce_opts.global_check): after a local fit that comes back, the candidates
 * are fitted (more evaluations) but none beats its end, so it stands: the same pose to the last
 * bit as without the check. From the ellipsoid's piece of seed 5 turned 10 degrees about each
 * principal axis (the fits of 25 degrees and 20 mm run into the trust wall, where the global stage
 * runs either way). */
static void test_reduce_global_check_keeps_a_good_fit(void **st)
{
    char *dir = tu_tmpdir("reduce_check");
    planning_case *c = fractured(dir, 2, 5);
    const frag *f = &c->frag[0];
    pose want = pose_compose(f->pose, pose_compose(pose_inverse(c->truth[0]), c->truth[1]));
    int back = 0;
    for (int axis = 0; axis < 3; axis++) {
        reduce_result r0, r1;
        fit_turned_about(c, &want, axis, axis == 1 ? -10 : 10, 3, 0, &r0);
        fit_turned_about(c, &want, axis, axis == 1 ? -10 : 10, 3, 1, &r1);
        if (!(r1.evaluations > r0.evaluations))
            fail_msg("about axis %d: %d evaluations with the check, %d without", axis, r1.evaluations,
                     r0.evaluations);
        if (!(r1.metric_end <= r1.metric_start))
            fail_msg("about axis %d: the check's fit ended at metric %.6f, worse than its start's %.6f", axis,
                     r1.metric_end, r1.metric_start);
        frag moved = c->frag[1];
        moved.pose = r0.end;
        double rot_deg, trans_mm, tre_mm;
        reduce_errors(f, &moved, &want, &rot_deg, &trans_mm, &tre_mm);
        if (rot_deg <= 1 && trans_mm <= 1) {
            back++;
            assert_true(pose_distance(r1.end, r0.end) < 1e-12);
            for (int k = 0; k < 4; k++)
                assert_true(fabs(r1.end.q[k] - r0.end.q[k]) < 1e-12);
        }
        reduce_result_free(&r0);
        reduce_result_free(&r1);
    }
    if (!back)
        fail_msg("no fit of the ellipsoid's seed 5 from 10 degrees came back without the check");
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* The global check brings back a fit that the local fit misses without hitting its wall: on the
 * ellipsoid's seed 14, from the truth turned 18-25 degrees and moved 15 mm (across the turn's
 * axis), the local fit alone stopped in another basin (2.9 degrees and 3.2 mm off, 8.0 and 3.9)
 * and the check's candidates found the fit (0.04 and 0.10 degrees). Every start that misses without
 * the check comes back with it, never at a worse metric than its start; and one at least misses
 * without it (else the test no longer shows the rescue: pick other starts). */
static void test_reduce_global_check_brings_back_a_missed_fit(void **st)
{
    char *dir = tu_tmpdir("reduce_rescue");
    planning_case *c = fractured(dir, 2, 14);
    const frag *m = &c->frag[1], *others[1] = {&c->frag[0]};
    pose want = pose_compose(c->frag[0].pose, pose_compose(pose_inverse(c->truth[0]), c->truth[1]));
    static const struct {
        int axis;
        double deg;
    } t[] = {{2, 18}, {0, 25}};
    int missed = 0;
    for (size_t i = 0; i < sizeof t / sizeof *t; i++) {
        int turn_axis = t[i].axis;
        pose start = turned_moved(m, &want, turn_axis, t[i].deg, (turn_axis + 1) % 3, 15);
        double rot[2], trans[2];
        for (int check = 0; check < 2; check++) {
            reduce_opts o;
            reduce_defaults(&o);
            o.global_check = check;
            reduce_result r;
            pose out;
            if (reduce_fit_one(others, 1, m, &start, &o, &out, &r) != 0)
                fail_msg("start %zu: %s", i, fn_err_msg());
            assert_true(r.metric_end <= r.metric_start);
            frag moved = c->frag[1];
            moved.pose = r.end;
            double tre;
            reduce_errors(&c->frag[0], &moved, &want, &rot[check], &trans[check], &tre);
            reduce_result_free(&r);
        }
        if (rot[0] > 1 || trans[0] > 1) {
            missed++;
            if (rot[1] > 1 || trans[1] > 1)
                fail_msg("start %zu (turned %g degrees about axis %d, moved 15 mm): %.2f degrees and %.2f mm off "
                         "without the check, %.2f and %.2f with it",
                         i, t[i].deg, turn_axis, rot[0], trans[0], rot[1], trans[1]);
        }
    }
    if (!missed)
        fail_msg("every start came back without the global check: the test no longer shows its rescue");
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* The global stage's candidates run on o->threads threads, each on a copy of the fit's state as it
 * was when they were made (under the global check, beside the local fit): the same fit, pose,
 * evaluations and history to the last bit, on 1, 2 or 3 threads; under the check (a start turned
 * 10 degrees) and without it, from a start 20 mm off (past the local fit's 12 mm wall). */
static void test_reduce_global_stage_same_on_any_threads(void **st)
{
    char *dir = tu_tmpdir("reduce_threads");
    planning_case *c = fractured(dir, 2, 5);
    const frag *m = &c->frag[1], *others[1] = {&c->frag[0]};
    pose want = pose_compose(c->frag[0].pose, pose_compose(pose_inverse(c->truth[0]), c->truth[1]));
    pose starts[2] = {turned_moved(m, &want, 0, 10, 0, 0), turned_moved(m, &want, 0, 0, 0, 20)};
    for (int k = 0; k < 2; k++) {
        reduce_result r[3];
        for (int t = 0; t < 3; t++) {
            reduce_opts o;
            reduce_defaults(&o);
            o.threads = t + 1;
            o.global_check = k == 0;
            pose out;
            if (reduce_fit_one(others, 1, m, &starts[k], &o, &out, &r[t]) != 0)
                fail_msg("start %d, %d threads: %s", k, t + 1, fn_err_msg());
        }
        for (int t = 1; t < 3; t++) {
            if (memcmp(&r[t].end, &r[0].end, sizeof r[0].end) || r[t].evaluations != r[0].evaluations ||
                r[t].iterations != r[0].iterations || r[t].nhistory != r[0].nhistory ||
                memcmp(r[t].history, r[0].history, (size_t)r[0].nhistory * sizeof *r[0].history))
                fail_msg("start %d: on %d threads the fit differs from one thread's (%d against %d evaluations, "
                         "%d against %d iterations, the end %g mm and %g degrees apart)",
                         k, t + 1, r[t].evaluations, r[0].evaluations, r[t].iterations, r[0].iterations,
                         pose_distance(r[t].end, r[0].end), pose_angle_between(r[t].end, r[0].end) * 57.29578);
        }
        for (int t = 0; t < 3; t++)
            reduce_result_free(&r[t]);
    }
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* A long piece hops (reduce_opts.hops): a fit of a tube's piece from 6-10 degrees about its axis
 * stops in a ripple of the metric; the hops go on from there to a better metric over the same
 * VOI (more evaluations). A piece that is not long hops too, strictly (test_reduce_rival_hops):
 * more evaluations, never a worse metric, and the same pose where no round gained. */
static void test_reduce_long_piece_hops(void **st)
{
    char *dir = tu_tmpdir("reduce_hops");
    vol *ct = tube();
    fracture_params p;
    fracture_defaults(&p);
    p.seed = 2;
    planning_case *c = fracture_make_case(ct, &p, dir);
    vol_free(ct);
    if (!c)
        fail_msg("%s", fn_err_msg());
    assert_true(c->frag[1].eigval[0] > 4 * c->frag[1].eigval[1]);
    pose want = pose_compose(c->frag[0].pose, pose_compose(pose_inverse(c->truth[0]), c->truth[1]));
    reduce_result r0, r3;
    /* where the fit stops short depends on the metric's rounding: the first of these turns whose fit
     * the hops improve (4 of the 4 before the one-field count, 3 of them after) */
    static const double deg[] = {6, 7, 9, 10};
    int gained = 0;
    for (size_t t = 0; t < sizeof deg / sizeof *deg && !gained; t++) {
        fit_turned(c, &want, deg[t], 0, &r0);
        fit_turned(c, &want, deg[t], 3, &r3);
        if (r3.metric_end > r0.metric_end + 1e-12)
            fail_msg("hops from %g degrees: metric %.6f, worse than without them (%.6f)", deg[t], r3.metric_end,
                     r0.metric_end);
        gained = r3.metric_end < r0.metric_end - 1e-6 && r3.evaluations > r0.evaluations;
        reduce_result_free(&r0);
        reduce_result_free(&r3);
    }
    if (!gained)
        fail_msg("hops: no fit of the tube's piece from 6-10 degrees about its axis was improved by them");
    case_free(c);
    tu_rmtree(dir);
    /* the ellipsoid's piece is not long */
    c = fractured(dir, 2, 3);
    assert_false(c->frag[1].eigval[0] > 4 * c->frag[1].eigval[1]);
    want = pose_compose(c->frag[0].pose, pose_compose(pose_inverse(c->truth[0]), c->truth[1]));
    fit_turned(c, &want, 6, 0, &r0);
    fit_turned(c, &want, 6, 3, &r3);
    if (!(r3.evaluations > r0.evaluations && r3.metric_end <= r0.metric_end + 1e-12))
        fail_msg("strict hops: metric %.6f (without %.6f), %d evaluations (without %d)", r3.metric_end,
                 r0.metric_end, r3.evaluations, r0.evaluations);
    if (r3.hops == 0)
        assert_true(pose_distance(r3.end, r0.end) < 1e-12 && pose_angle_between(r3.end, r0.end) < 1e-12);
    reduce_result_free(&r0);
    reduce_result_free(&r3);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* bench reduce's long bone: a bowed shaft 154 mm long of elliptic section (semi-axes 10-14 mm by
 * 8-11 mm), a 3 mm cortex around a canal, on a 0.7 mm grid. */
static vol *long_bone(void)
{
    const int nx = 220, ny = 60, nz = 56;
    vol *v = vol_new(nx, ny, nz);
    assert_non_null(v);
    const double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, sp[3] = {0.7, 0.7, 0.7}, org[3] = {-77, -21, -19.6};
    vol_set_geometry(v, dir, sp, org);
    for (int i = 0; i < nx; i++) {
        double u = (i - 0.5 * nx) / (0.5 * nx), flare = u * u * u * u;
        double a = 10 + 4 * flare, b = 8 + 3 * flare;
        double cy = 2.5 * sin(M_PI * (i / (double)nx)), cz = 1.5 * u;
        for (int k = 0; k < nz; k++)
            for (int j = 0; j < ny; j++) {
                double y = (j - 0.5 * ny) * sp[1] - cy, z = (k - 0.5 * nz) * sp[2] - cz;
                double r = sqrt((y / a) * (y / a) + (z / b) * (z / b)), inner = 1 - 3 / (0.5 * (a + b));
                v->data[vol_idx(v, i, j, k)] = r <= 1 ? (r >= inner ? (float)(1000 + (i * 7 + j * 13 + k * 3) % 400) : 40) : -50;
            }
    }
    v->src_type = VOL_I16;
    return v;
}

/* The metric's own minimum is the true pose when both pieces are the two sides of one voxel grid:
 * the long bone cut (fracture_make's cut, before the moved piece is turned and resampled), both
 * pieces at their true pose, fitted from there, stays there (bench reduce's 4 cuts of the long
 * bone: 0.01 to 0.02 degrees, 0.002 to 0.011 mm). bench reduce's fits from the truth leave it (up
 * to 2.8 degrees) for the moved piece's resampling, its voxel grid turned 3 degrees from the fixed
 * piece's: the count favours poses where the two grids line up (README, the long bone). */
static void test_reduce_stays_at_the_truth_on_one_grid(void **st)
{
    vol *ct = long_bone();
    fracture_params p;
    fracture_defaults(&p);
    for (uint64_t seed = 1; seed <= 4; seed += 2) {
        p.seed = seed;
        fracture_result fr;
        if (fracture_make(ct, &p, &fr) < 0)
            fail_msg("%s", fn_err_msg());
        frag f, m;
        int lo[3], hi[3];
        assert_int_equal(frag_label_box(fr.cut, 1, lo, hi), 0);
        assert_int_equal(frag_from_labels(&f, fr.cut, ct, 1, lo, hi, fr.threshold, 200), 0);
        assert_int_equal(frag_label_box(fr.cut, 2, lo, hi), 0);
        assert_int_equal(frag_from_labels(&m, fr.cut, ct, 2, lo, hi, fr.threshold, 200), 0);
        fracture_result_free(&fr);
        reduce_opts o;
        reduce_defaults(&o);
        const frag *others[1] = {&f};
        pose out;
        reduce_result r;
        assert_int_equal(reduce_fit_one(others, 1, &m, &POSE_IDENTITY, &o, &out, &r), 0);
        double rot, trans, tre;
        frag mo = m;
        mo.pose = out;
        reduce_errors(&f, &mo, &POSE_IDENTITY, &rot, &trans, &tre);
        if (!(rot < 0.05 && trans < 0.05))
            fail_msg("cut %d: the fit from the truth left it by %.3f deg, %.3f mm (tre %.3f)", (int)seed, rot,
                     trans, tre);
        /* a fit never keeps an end worse than its start */
        if (!(r.metric_end <= r.metric_start))
            fail_msg("cut %d: the fit from the truth ended at %.6f, worse than its start %.6f", (int)seed,
                     r.metric_end, r.metric_start);
        reduce_result_free(&r);
        frag_free(&f);
        frag_free(&m);
    }
    vol_free(ct);
}

/* The polish (reduce_opts.polish): the ellipsoid's fractures (fracture_make: the moved piece turned
 * and resampled, as a displaced piece segmented from a CT is), each fitted from 1.5 mm and 3
 * degrees off its truth. The trilinear count's blur overlaps the fixed bone there, and without the
 * polish the fit ends a few tenths of a degree and millimetre off; polished on the nearest count,
 * its fracture surface lies nearer the truth's (TRE 0.07-0.33 mm -> 0.02-0.24 mm). */
static void test_polish_keeps_a_resampled_piece_nearer(void **st)
{
    char *dir = tu_tmpdir("reduce_polish");
    double sum[2] = {0, 0};
    for (uint64_t seed = 1; seed <= 5; seed++) {
        planning_case *c = fractured(dir, 2, seed);
        const frag *f = &c->frag[0];
        pose want = pose_compose(f->pose, pose_compose(pose_inverse(c->truth[0]), c->truth[1]));
        double axis[3] = {0.6, 0.0, 0.8}, move[3] = {0.8, 0.0, 0.6}, cm[3], to[3];
        pose_apply(&want, c->frag[1].centroid, cm);
        for (int a = 0; a < 3; a++)
            to[a] = cm[a] + 1.5 * move[a];
        pose turn = pose_from_axis_angle(axis, 3 * M_PI / 180), start = reduce__turned(&want, &turn, cm, to);
        double rot[2], trans[2], tre[2];
        for (int polish = 0; polish < 2; polish++) {
            reduce_opts o;
            reduce_defaults(&o);
            assert_int_equal(o.polish, 1);
            o.polish = polish;
            const frag *others[1] = {f};
            pose out;
            reduce_result r;
            assert_int_equal(reduce_fit_one(others, 1, &c->frag[1], &start, &o, &out, &r), 0);
            assert_int_equal(r.collides, 0);
            /* the result's metric is the fit's own count (trilinear) again, not the polish's */
            reduce_metric *tm = reduce_metric_new(others, 1, &c->frag[1], &r.voi, REDUCE_TRILINEAR, o.band_mm);
            assert_non_null(tm);
            double want_end = reduce_metric_eval(tm, &out, NULL);
            if (!(fabs(want_end - r.metric_end) < 1e-9))
                fail_msg("seed %d: metric_end %.9f, the trilinear count there %.9f", (int)seed, r.metric_end, want_end);
            reduce_metric_free(tm);
            reduce_result_free(&r);
            frag mo = c->frag[1];
            mo.pose = out;
            reduce_errors(f, &mo, &want, &rot[polish], &trans[polish], &tre[polish]);
            sum[polish] += tre[polish];
        }
        print_message("seed %d: without the polish %.3f deg %.3f mm (TRE %.3f), with it %.3f deg %.3f mm (TRE %.3f)\n",
                      (int)seed, rot[0], trans[0], tre[0], rot[1], trans[1], tre[1]);
        if (!(tre[1] < tre[0] && rot[1] < 1 && trans[1] < 1))
            fail_msg("seed %d: polished %.3f deg %.3f mm, TRE %.3f mm against %.3f unpolished", (int)seed, rot[1],
                     trans[1], tre[1], tre[0]);
        case_free(c);
    }
    if (!(sum[1] < 0.6 * sum[0]))
        fail_msg("the polish: TRE summed over the fits %.3f mm, unpolished %.3f", sum[1], sum[0]);
    tu_rmtree(dir);
    free(dir);
}

/* A fit does not depend on what ran before it: with pre-alignment asked for but not run (the
 * piece is placed near the other by hand), reduce_pair makes one more collision query first, which
 * warmed the caches, and slide_to_contact stepped by the cached queries' (looser) separation, so
 * the two fits went different ways (the real pelvis 001_LI: metric -0.8117 against -0.8096). */
static void test_same_fit_with_or_without_prealign(void **st)
{
    char *dir = tu_tmpdir("reduce_paths");
    for (uint64_t seed = 3; seed <= 5; seed++) {
        planning_case *c = fractured(dir, 2, seed);
        const frag *asm_[1] = {&c->frag[0]};
        pose placed = c->frag[1].pose, end[2];
        double metric[2];
        for (int pre = 0; pre < 2; pre++) {
            reduce_opts o;
            reduce_defaults(&o);
            o.prealign = pre;
            reduce_result r;
            c->frag[1].pose = placed;
            assert_int_equal(reduce_pair(asm_, 1, &c->frag[1], &o, &r), 0);
            assert_int_equal(r.prealigned, 0);
            end[pre] = r.end;
            metric[pre] = r.metric_end;
            assert_true(r.metric_end <= r.metric_start);
            reduce_result_free(&r);
        }
        if (memcmp(&end[0], &end[1], sizeof end[0]) || metric[0] != metric[1])
            fail_msg("seed %d: with pre-alignment asked for, the fit ends %.4f deg, %.4f mm from the other "
                     "(metric %.6f against %.6f)", (int)seed, pose_angle_between(end[0], end[1]) * 180 / M_PI,
                     pose_distance(end[0], end[1]), metric[1], metric[0]);
        case_free(c);
    }
    tu_rmtree(dir);
    free(dir);
}

/* The same answer from any start (issue 28): ten random starts around one fracture of the
 * ellipsoid (seed 5), up to 20 mm and 25 degrees from the truth (redrawn while they collide, as a
 * hand never leaves them), all end within 1 mm and 1 degree of each other and of the truth, and
 * none ends at a worse metric than its start. Before the global stage most of them ended apart
 * (stopped at the 12 mm trust wall or in other basins). Not every fracture is there yet: from the
 * same starts, seed 3's pieces end apart in some of them (see docs/benchmarks.md). */
static void test_same_answer_from_any_start(void **st)
{
    char *dir = tu_tmpdir("reduce_any_start");
    planning_case *c = fractured(dir, 2, 5);
    const frag *f = &c->frag[0], *m = &c->frag[1], *others[1] = {f};
    pose want = pose_compose(f->pose, pose_compose(pose_inverse(c->truth[0]), c->truth[1]));
    obb_params op = {CASE_TAU_MIN, CASE_TAU_MAX};
    obb_tree *tf = obb_tree_build(f, &op), *tm = obb_tree_build(m, &op);
    assert_non_null(tf);
    assert_non_null(tm);
    pose fw = pose_compose(f->pose, f->home), end[10];
    uint64_t rng = 12345;
    for (int s = 0; s < 10; s++) {
        pose start = want;
        for (int tries = 0; tries < 100; tries++) {
            double u[7];
            for (int i = 0; i < 7; i++) {
                rng = rng * 6364136223846793005ULL + 1442695040888963407ULL;
                u[i] = (double)(rng >> 11) / 9007199254740992.0;
            }
            double axis[3] = {u[0] - 0.5, u[1] - 0.5, u[2] - 0.5}, dir3[3] = {u[3] - 0.5, u[4] - 0.5, u[5] - 0.5};
            double na = sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
            double nd = sqrt(dir3[0] * dir3[0] + dir3[1] * dir3[1] + dir3[2] * dir3[2]);
            double cw[3], rc[3];
            for (int a = 0; a < 3; a++)
                axis[a] /= na;
            pose rot = pose_from_axis_angle(axis, 25 * u[6] * M_PI / 180);
            start = pose_compose(rot, want);
            pose_apply(&want, m->centroid, cw);
            pose_rotate(&rot, cw, rc);
            for (int a = 0; a < 3; a++)
                start.t[a] += cw[a] - rc[a] + 20 * u[(a + 3 * s) % 7] * dir3[a] / nd;
            pose mw = pose_compose(start, m->home);
            obb_query q = {.threshold = 0, .tolerance_mm = 0};
            obb_result hit;
            if (obb_collide(tf, &fw, tm, &mw, &q, NULL, &hit) == 0 && !hit.collides)
                break;
        }
        reduce_opts o;
        reduce_defaults(&o);
        reduce_result r;
        assert_int_equal(reduce_fit_one(others, 1, m, &start, &o, &end[s], &r), 0);
        if (!(r.metric_end <= r.metric_start))
            fail_msg("start %d: the fit ended at metric %.6f, worse than its start's %.6f", s, r.metric_end,
                     r.metric_start);
        reduce_result_free(&r);
        frag moved = *m;
        moved.pose = end[s];
        double rot_deg, trans_mm, tre_mm;
        reduce_errors(f, &moved, &want, &rot_deg, &trans_mm, &tre_mm);
        if (!(rot_deg <= 1 && trans_mm <= 1))
            fail_msg("start %d: %.3f deg, %.3f mm from the truth", s, rot_deg, trans_mm);
        for (int k = 0; k < s; k++) {
            double x[3], y[3], d2 = 0;
            pose_apply(&end[k], m->centroid, x);
            pose_apply(&end[s], m->centroid, y);
            for (int a = 0; a < 3; a++)
                d2 += (x[a] - y[a]) * (x[a] - y[a]);
            if (!(sqrt(d2) <= 1 && pose_angle_between(end[k], end[s]) * 180 / M_PI <= 1))
                fail_msg("starts %d and %d end %.3f mm, %.3f deg apart", k, s, sqrt(d2),
                         pose_angle_between(end[k], end[s]) * 180 / M_PI);
        }
    }
    obb_tree_free(tf);
    obb_tree_free(tm);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

static void test_method_names(void **st)
{
    for (int m = 0; m < REDUCE_METHODS; m++)
        assert_int_equal(reduce_method_parse(reduce_method_name((reduce_method)m)), m);
    assert_int_equal(reduce_method_parse("newton"), -1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_pca_box),
        cmocka_unit_test(test_pca_diagonal_rod),
        cmocka_unit_test(test_metric_trilinear_vs_brute),
        cmocka_unit_test(test_metric_nearest_vs_brute),
        cmocka_unit_test(test_auto_voi_vs_brute),
        cmocka_unit_test(test_metric_trilinear_is_continuous),
        cmocka_unit_test(test_powell_rosenbrock),
        cmocka_unit_test(test_powell_quadratic),
        cmocka_unit_test(test_powell_bad_arguments),
        cmocka_unit_test(test_method_names),
        cmocka_unit_test(test_reduce_two_pieces),
        cmocka_unit_test(test_reduce_gap),
        cmocka_unit_test(test_reduce_three_pieces),
        cmocka_unit_test(test_reduce_parallel_pairs),
        cmocka_unit_test(test_reduce_nlopt_methods),
        cmocka_unit_test(test_fit_one),
        cmocka_unit_test(test_cli),
        cmocka_unit_test(test_cli_from_journal),
        cmocka_unit_test(test_cli_skips_what_touches_nothing),
        cmocka_unit_test(test_cli_three_pieces_of_the_skull),
        cmocka_unit_test(test_prealign_rods),
        cmocka_unit_test(test_reduce_long_piece_hops),
        cmocka_unit_test(test_reduce_rival_hops),
        cmocka_unit_test(test_reduce_global_check_keeps_a_good_fit),
        cmocka_unit_test(test_reduce_global_check_brings_back_a_missed_fit),
        cmocka_unit_test(test_reduce_global_stage_same_on_any_threads),
        cmocka_unit_test(test_reduce_stays_at_the_truth_on_one_grid),
        cmocka_unit_test(test_polish_keeps_a_resampled_piece_nearer),
        cmocka_unit_test(test_same_fit_with_or_without_prealign),
        cmocka_unit_test(test_same_answer_from_any_start),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
