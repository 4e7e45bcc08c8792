/* The second fracture model (fracture_model2): on a small textured ellipsoid made here, the moved
 * piece keeps its volume within the partial volume of its edge, the truth puts it back, a seed
 * gives the same case, the fracture's edge shows partial volume, the noise has the asked spread,
 * and what the model cannot do is refused. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "err.h"
#include "fracture.h"
#include "testutil.h"
#include "vol.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* An ellipsoid (semi-axes 24, 14, 12 mm) of 700-1100 HU in -50 HU, 1 mm voxels, with room around
 * it for the moved piece. */
static vol *ellipsoid(void)
{
    vol *v = vol_new(72, 48, 44);
    assert_non_null(v);
    const double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, sp[3] = {1, 1, 1}, org[3] = {-10, 4, 2};
    vol_set_geometry(v, dir, sp, org);
    for (int k = 0; k < 44; k++)
        for (int j = 0; j < 48; j++)
            for (int i = 0; i < 72; i++) {
                double x = (i - 35.5) / 24, y = (j - 23.5) / 14, z = (k - 21.5) / 12;
                v->data[vol_idx(v, i, j, k)] =
                    x * x + y * y + z * z <= 1 ? (float)(700 + (i * 7 + j * 13 + k * 3) % 400) : -50.f;
            }
    v->src_type = VOL_I16;
    return v;
}

static void params(fracture_params *p, uint64_t seed, double noise)
{
    fracture_defaults(p);
    p->model = 2;
    p->seed = seed;
    p->displace_mm = 4;
    p->rotate_deg = 6;
    p->noise_hu = noise;
}

static size_t count(const vol *v, float value)
{
    size_t n = 0;
    for (size_t i = 0; i < vol_count(v); i++)
        n += v->data[i] == value;
    return n;
}

static void test_volume_and_truth(void **st)
{
    vol *ct = ellipsoid();
    fracture_params p;
    params(&p, 3, 0);
    fracture_result r;
    if (fracture_make(ct, &p, &r) < 0)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(r.pieces, 2);
    size_t before = count(r.cut, 2), after = count(r.labels, 2);
    assert_true(before > 1000);
    /* nearest-free resampling: the piece's voxel count moves only by its edge's partial volume */
    assert_true(fabs((double)after - (double)before) < 0.03 * (double)before);
    assert_int_equal(count(r.labels, 1), count(r.cut, 1)); /* piece 1 stays */
    /* the truth: identity for piece 1; piece 2's displaced voxels go back onto piece 2 */
    assert_true(r.truth[0].q[0] == 1 && r.truth[0].t[0] == 0);
    pose back = pose_compose(r.truth[1], r.moved[1]);
    assert_true(fabs(fabs(back.q[0]) - 1) < 1e-12 && fabs(back.t[0]) + fabs(back.t[1]) + fabs(back.t[2]) < 1e-9);
    double centroid[3] = {0, 0, 0};
    for (int k = 0; k < r.cut->dim[2]; k++)
        for (int j = 0; j < r.cut->dim[1]; j++)
            for (int i = 0; i < r.cut->dim[0]; i++)
                if (r.cut->data[vol_idx(r.cut, i, j, k)] == 2) {
                    double ijk[3] = {i, j, k}, w[3];
                    vol_index_to_world(r.cut, ijk, w);
                    for (int a = 0; a < 3; a++)
                        centroid[a] += w[a] / (double)before;
                }
    double cm[3];
    pose_apply(&r.moved[1], centroid, cm);
    assert_true(fracture_truth_shift(&r.truth[1], cm) >= 4 - 1e-6); /* displace_mm, and any push on */
    size_t home = 0;
    for (int k = 0; k < r.labels->dim[2]; k++)
        for (int j = 0; j < r.labels->dim[1]; j++)
            for (int i = 0; i < r.labels->dim[0]; i++) {
                if (r.labels->data[vol_idx(r.labels, i, j, k)] != 2)
                    continue;
                double ijk[3] = {i, j, k}, w[3], b[3], s[3];
                vol_index_to_world(r.labels, ijk, w);
                pose_apply(&r.truth[1], w, b);
                vol_world_to_index(r.cut, b, s);
                int q[3] = {(int)floor(s[0] + 0.5), (int)floor(s[1] + 0.5), (int)floor(s[2] + 0.5)};
                home += q[0] >= 0 && q[1] >= 0 && q[2] >= 0 && q[0] < r.cut->dim[0] && q[1] < r.cut->dim[1] &&
                        q[2] < r.cut->dim[2] && r.cut->data[vol_idx(r.cut, q[0], q[1], q[2])] == 2;
            }
    assert_true((double)home >= 0.97 * (double)after);
    /* partial volume: values between the fill (40 HU) and the bone's lowest (700) where the piece
     * meets what it left, which nearest-neighbour resampling never writes */
    size_t mixed = 0;
    for (size_t i = 0; i < vol_count(r.ct); i++)
        mixed += r.ct->data[i] > 100 && r.ct->data[i] < 600;
    assert_true(mixed > 100);
    fracture_result_free(&r);
    vol_free(ct);
}

static void test_deterministic_by_seed(void **st)
{
    vol *ct = ellipsoid();
    fracture_params p;
    fracture_result a, b, c;
    params(&p, 5, 20);
    assert_int_equal(fracture_make(ct, &p, &a), 0);
    assert_int_equal(fracture_make(ct, &p, &b), 0);
    p.seed = 6;
    assert_int_equal(fracture_make(ct, &p, &c), 0);
    for (int d = 0; d < 3; d++) /* the ellipsoid has room around it: the grid does not grow */
        assert_true(a.ct->dim[d] == ct->dim[d] && c.ct->dim[d] == ct->dim[d]);
    size_t bytes = vol_count(a.ct) * sizeof(float);
    assert_memory_equal(a.ct->data, b.ct->data, bytes);
    assert_memory_equal(a.labels->data, b.labels->data, bytes);
    assert_memory_equal(&a.truth[1], &b.truth[1], sizeof(pose));
    assert_memory_not_equal(a.labels->data, c.labels->data, bytes);
    /* the noise: about 20 HU of spread far from the bone (x < 6 mm in voxels 0..3) */
    double s = 0, s2 = 0;
    size_t n = 0;
    for (int k = 0; k < ct->dim[2]; k++)
        for (int j = 0; j < ct->dim[1]; j++)
            for (int i = 0; i < 4; i++) {
                double d = a.ct->data[vol_idx(a.ct, i, j, k)] - ct->data[vol_idx(ct, i, j, k)];
                s += d;
                s2 += d * d;
                n++;
            }
    double mean = s / (double)n, sd = sqrt(s2 / (double)n - mean * mean);
    assert_true(fabs(mean) < 1.5 && sd > 18 && sd < 22);
    fracture_result_free(&a);
    fracture_result_free(&b);
    fracture_result_free(&c);
    vol_free(ct);
}

static void test_refuses_what_it_cannot(void **st)
{
    vol *ct = ellipsoid();
    fracture_params p;
    fracture_result r;
    params(&p, 1, 0);
    p.pieces = 3;
    assert_int_equal(fracture_make(ct, &p, &r), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "two pieces"));
    params(&p, 1, 0);
    p.model = 3;
    assert_int_equal(fracture_check(&p), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "model"));
    vol_free(ct);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_volume_and_truth),
        cmocka_unit_test(test_deterministic_by_seed),
        cmocka_unit_test(test_refuses_what_it_cannot),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
