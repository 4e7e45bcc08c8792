#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "pose.h"

#include <math.h>

static void test_compose_inverse(void **st)
{
    double ax[3] = {0.3, -0.5, 0.8};
    pose a = pose_from_axis_angle(ax, 0.7);
    a.t[0] = 4, a.t[1] = -2, a.t[2] = 9;
    pose id = pose_compose(pose_inverse(a), a);
    assert_true(pose_angle_between(id, POSE_IDENTITY) < 1e-9);
    assert_true(pose_distance(id, POSE_IDENTITY) < 1e-9);
    double x[3] = {1, 2, 3}, y[3], z[3];
    pose_apply(&a, x, y);
    pose ai = pose_inverse(a);
    pose_apply(&ai, y, z);
    for (int i = 0; i < 3; i++)
        assert_true(fabs(z[i] - x[i]) < 1e-12);
}

static void test_rotation_about_z(void **st)
{
    double z[3] = {0, 0, 1}, x[3] = {1, 0, 0}, y[3];
    pose p = pose_from_axis_angle(z, M_PI / 2);
    pose_apply(&p, x, y);
    assert_true(fabs(y[0]) < 1e-12 && fabs(y[1] - 1) < 1e-12 && fabs(y[2]) < 1e-12);
    double r[3][3];
    pose_to_matrix(&p, r);
    pose back = pose_from_matrix(r, NULL);
    assert_true(pose_angle_between(back, p) < 1e-9);
}

/* pose_to_rotvec undoes pose_from_rotvec, and q and -q give the same rotation vector. */
static void test_rotvec_round_trip(void **st)
{
    double rv[3] = {0.3, -0.5, 0.8}, back[3];
    pose p = pose_from_rotvec(rv, NULL);
    double a = pose_to_rotvec(&p, back);
    assert_true(fabs(a - sqrt(0.98)) < 1e-12);
    for (int i = 0; i < 3; i++)
        assert_true(fabs(back[i] - rv[i]) < 1e-12);
    for (int i = 0; i < 4; i++)
        p.q[i] = -p.q[i];
    pose_to_rotvec(&p, back);
    for (int i = 0; i < 3; i++)
        assert_true(fabs(back[i] - rv[i]) < 1e-12);
    assert_true(pose_to_rotvec(&POSE_IDENTITY, back) == 0 && back[0] == 0 && back[1] == 0 && back[2] == 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_compose_inverse),
        cmocka_unit_test(test_rotation_about_z),
        cmocka_unit_test(test_rotvec_round_trip),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
