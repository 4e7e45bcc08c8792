/* mesh (src/core/geometry/mesh.h): closed, consistently wound surfaces for export and printing. A ball's
 * surface is one closed 2-manifold (every directed edge once and its reverse once, Euler
 * characteristic 2) enclosing about the ball's volume; bone touching the grid's border is closed
 * too; Taubin smoothing keeps the volume and decimation keeps the surface closed. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "mesh.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static int cmp(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return (x > y) - (x < y);
}

/* Every directed edge once and its reverse once: a closed, consistently wound 2-manifold. Returns
 * the number of undirected edges, or -1. */
static long closed_edges(const mesh *m)
{
    long ne = m->nt * 3;
    uint64_t *e = malloc((size_t)ne * sizeof *e);
    assert_non_null(e);
    for (long t = 0; t < m->nt; t++)
        for (int k = 0; k < 3; k++)
            e[t * 3 + k] = (uint64_t)m->tri[t * 3 + k] << 32 | (uint32_t)m->tri[t * 3 + (k + 1) % 3];
    long bad = 0;
    /* sorted, then each one's reverse looked up */
    qsort(e, (size_t)ne, sizeof *e, cmp);
    for (long i = 0; i < ne; i++) {
        if (i + 1 < ne && e[i] == e[i + 1])
            bad++;
        uint64_t r = e[i] << 32 | e[i] >> 32;
        if (!bsearch(&r, e, (size_t)ne, sizeof *e, cmp))
            bad++;
    }
    free(e);
    return bad ? -1 : ne / 2;
}


static float *ball(const int dim[3], double r, const double c[3])
{
    float *v = malloc((size_t)dim[0] * dim[1] * dim[2] * sizeof *v);
    for (int k = 0; k < dim[2]; k++)
        for (int j = 0; j < dim[1]; j++)
            for (int i = 0; i < dim[0]; i++)
                v[((size_t)k * dim[1] + j) * dim[0] + i] =
                    hypot(hypot(i - c[0], j - c[1]), k - c[2]) <= r ? 1.0f : 0.0f;
    return v;
}

static void check_sphere_like(const mesh *m, double want_mm3, double tol)
{
    long ne = closed_edges(m);
    assert_true(ne > 0);
    assert_int_equal(m->nv - ne + m->nt, 2); /* Euler: a sphere */
    double v = mesh_volume(m);
    assert_true(v > 0); /* outward winding */
    assert_true(fabs(v - want_mm3) < tol * want_mm3);
}

static void test_ball_is_closed(void **st)
{
    (void)st;
    const int dim[3] = {24, 24, 24};
    const double sp[3] = {1.0, 1.0, 1.0}, c[3] = {11.5, 11.5, 11.5};
    float *v = ball(dim, 8, c);
    mesh m;
    assert_int_equal(mesh_extract(v, dim, sp, 0.5f, &m), 0);
    check_sphere_like(&m, 4.0 / 3 * M_PI * 512, 0.1);
    double vol0 = mesh_volume(&m);
    assert_int_equal(mesh_smooth(&m, 20, 0.5, -0.53), 0);
    check_sphere_like(&m, 4.0 / 3 * M_PI * 512, 0.1);
    assert_true(fabs(mesh_volume(&m) - vol0) < 0.05 * vol0); /* Taubin: no shrinking */
    long before = m.nt;
    assert_true(mesh_decimate(&m, before / 4) <= before / 4);
    check_sphere_like(&m, 4.0 / 3 * M_PI * 512, 0.15);
    mesh_free(&m);
    free(v);
}

/* Bone filling the grid up to its border: the padded border closes it; anisotropic spacing. */
static void test_border_is_closed(void **st)
{
    (void)st;
    const int dim[3] = {6, 5, 4};
    const double sp[3] = {0.5, 1.0, 2.0};
    float v[120];
    for (int i = 0; i < 120; i++)
        v[i] = 1000.0f;
    v[0] = 300.0f; /* exactly on the level: inside (>= level) */
    mesh m;
    assert_int_equal(mesh_extract(v, dim, sp, 300.0f, &m), 0);
    assert_true(closed_edges(&m) > 0);
    assert_int_equal(m.nv - closed_edges(&m) + m.nt, 2);
    /* The box of voxel centres grown by half a voxel on every side. */
    assert_true(fabs(mesh_volume(&m) - 6 * 0.5 * 5 * 1.0 * 4 * 2.0) < 0.5 * 6 * 0.5 * 5 * 4 * 2.0);
    for (long i = 0; i < m.nv; i++)
        for (int a = 0; a < 3; a++) {
            assert_true(m.v[i * 3 + a] >= -sp[a] && m.v[i * 3 + a] <= dim[a] * sp[a]);
        }
    mesh_free(&m);
}

static void test_empty(void **st)
{
    (void)st;
    const int dim[3] = {3, 3, 3};
    const double sp[3] = {1, 1, 1};
    float v[27] = {0};
    mesh m;
    assert_int_equal(mesh_extract(v, dim, sp, 0.5f, &m), 0);
    assert_int_equal(m.nt, 0);
    assert_int_equal(mesh_decimate(&m, 10), 0);
    mesh_free(&m);
}

/* A 6^3 block with a one-voxel cavity, and (islands) a voxel touching it at a corner only and
 * one apart: the islands go, the outer surface and the cavity's wall stay (two spheres, Euler 4),
 * as the same block meshed without the islands. */
static void test_islands_dropped(void **st)
{
    (void)st;
    const int dim[3] = {12, 12, 12};
    const double sp[3] = {1, 1, 1};
    float *v = calloc(12 * 12 * 12, sizeof *v);
    assert_non_null(v);
    for (int k = 2; k < 8; k++)
        for (int j = 2; j < 8; j++)
            for (int i = 2; i < 8; i++)
                v[(k * 12 + j) * 12 + i] = i == 4 && j == 4 && k == 4 ? 0.0f : 1.0f;
    mesh want, m;
    assert_int_equal(mesh_extract(v, dim, sp, 0.5f, &want), 0);
    v[(1 * 12 + 8) * 12 + 8] = 1;  /* (8, 8, 1): a corner of (7, 7, 2) */
    v[(10 * 12 + 1) * 12 + 10] = 1; /* (10, 1, 10): apart */
    assert_int_equal(mesh_extract(v, dim, sp, 0.5f, &m), 0);
    assert_true(m.nt > want.nt);
    assert_true(mesh_drop_islands(&m) >= 1);
    assert_int_equal(m.nt, want.nt);
    long ne = closed_edges(&m);
    assert_true(ne > 0);
    assert_int_equal(m.nv - ne + m.nt, 4);
    assert_true(fabs(mesh_volume(&m) - mesh_volume(&want)) < 1e-9);
    mesh_free(&m);
    mesh_free(&want);
    free(v);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_ball_is_closed),
        cmocka_unit_test(test_border_is_closed),
        cmocka_unit_test(test_empty),
        cmocka_unit_test(test_islands_dropped),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
