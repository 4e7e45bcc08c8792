/* The loop on real OBB octrees: small voxel fragments, every accepted pose checked by brute force. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "loop.h"
#include "navview.h"
#include "obb.h"
#include "testutil.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Fragment 0: a 6^3 voxel cube (1 mm) at the origin. Fragment 1: a fixed 30x30x4 slab whose first
 * voxel centre is at (-12, -12, 8): its lower face is the plane z = 7.5. */
static void make(frag f[2])
{
    int dims[2][3] = {{6, 6, 6}, {30, 30, 4}};
    double at[2][3] = {{0, 0, 0}, {-12, -12, 8}};
    for (int i = 0; i < 2; i++)
        tu_box_frag(&f[i], i + 1, dims[i], at[i]);
}

static int brute_collides(const frag f[2], const pose *p0)
{
    pose w0 = pose_compose(*p0, f[0].home), w1 = f[1].home;
    obb_result r;
    assert_int_equal(obb_collide_brute(&f[0], &w0, &f[1], &w1, NULL, NULL, &r), 0);
    return r.collides;
}

/* Highest z reached by the cube's voxel-box corners. */
static double top_z(const frag *f, const pose *p)
{
    double m = -INFINITY;
    for (int c = 0; c < 8; c++) {
        double x[3], w[3];
        for (int a = 0; a < 3; a++)
            x[a] = ((c >> a & 1) ? f->dim[a] - 0.5 : -0.5) + f->home.t[a];
        pose_apply(p, x, w);
        m = fmax(m, w[2]);
    }
    return m;
}

static void drive(const float m[6], int steps, frag f[2], loop_stats *s, pose *end, int *collided)
{
    loop_obb *o = loop_obb_new(f, 2, NULL, NULL);
    assert_non_null(o);
    loop_collider col = loop_obb_collider(o);
    loop_config c;
    loop_config_default(&c);
    c.frame = LOOP_FRAME_WORLD;
    c.trans_mm_s = 50;
    c.rot_deg_s = 60;
    c.check_invariant = 1;
    uint8_t fixed[2] = {0, 1};
    loop *L = loop_new(f, 2, fixed, &col, &c, NULL);
    assert_non_null(L);
    loop_event e;
    memset(&e, 0, sizeof e);
    e.kind = LOOP_EV_MOTION;
    memcpy(e.motion, m, sizeof e.motion);
    *collided = 0;
    for (int k = 0; k < steps; k++) {
        e.t_us = 8000 * (int64_t)k;
        assert_true(loop_feed(L, &e) >= 0);
        pose p = loop_pose(L, 0);
        *collided += brute_collides(f, &p);
    }
    loop_get_stats(L, s);
    *end = loop_pose(L, 0);
    loop_free(L);
    loop_obb_free(o);
}

static void test_head_on_against_slab(void **st)
{
    frag f[2];
    make(f);
    float m[6] = {0, 0, 1, 0, 0, 0}; /* +z at 50 mm/s: 0.4 mm a report */
    loop_stats s;
    pose end;
    int collided;
    drive(m, 60, f, &s, &end, &collided);
    assert_int_equal(collided, 0);
    assert_int_equal(s.collisions_in_accepted, 0);
    double gap = 7.5 - top_z(&f[0], &end);
    assert_true(gap >= -1e-9 && gap < 0.05);
    assert_true(s.refused > 30);
    frag_free(&f[0]);
    frag_free(&f[1]);
}

static void test_grazing_slides_under_slab(void **st)
{
    frag f[2];
    make(f);
    float m[6] = {0.4f, 0.2f, 1, 0, 0, 0};
    loop_stats s;
    pose end;
    int collided;
    drive(m, 60, f, &s, &end, &collided);
    assert_int_equal(collided, 0);
    assert_int_equal(s.collisions_in_accepted, 0);
    assert_true(s.slid > 30);
    /* Pressed against the slab it still travels along it: ~0.16 mm x per report. */
    assert_true(end.t[0] > 0.8 * 60 * 0.16);
    assert_true(end.t[1] > 0.8 * 60 * 0.08);
    assert_true(7.5 - top_z(&f[0], &end) < 0.05);
    frag_free(&f[0]);
    frag_free(&f[1]);
}

static void test_turning_into_slab(void **st)
{
    frag f[2];
    make(f);
    float m[6] = {0, 0, 0.3f, 0.8f, 0.5f, 0};
    loop_stats s;
    pose end;
    int collided;
    drive(m, 120, f, &s, &end, &collided);
    assert_int_equal(collided, 0);
    assert_int_equal(s.collisions_in_accepted, 0);
    assert_true(s.limited + s.slid + s.refused > 0);
    frag_free(&f[0]);
    frag_free(&f[1]);
}

/* Pushes the cube k reports with motion m; returns the refusals. Brute force measures the depth:
 * *deepest gets the highest top_z reached. */
static int push(loop *L, const frag f[2], float mz, float mx, int k, int64_t *t, double *deepest)
{
    loop_event e = {.kind = LOOP_EV_MOTION};
    e.motion[0] = mx;
    e.motion[2] = mz;
    int refused = 0;
    for (int i = 0; i < k; i++) {
        e.t_us = (*t += 8000);
        int rc = loop_feed(L, &e);
        assert_true(rc >= 0);
        refused += rc == LOOP_REFUSED;
        pose p = loop_pose(L, 0);
        *deepest = fmax(*deepest, top_z(&f[0], &p));
    }
    return refused;
}

/* Collision checking turned back on with the cube 1.2 mm inside the slab: the status says so at
 * once, a push deeper is refused, a slide along it and a pull out are taken (counted as escaping
 * while inside), and once out the contact is checked as before. */
static void test_checking_back_on_inside(void **st)
{
    frag f[2];
    make(f);
    loop_obb *o = loop_obb_new(f, 2, NULL, NULL);
    loop_collider col = loop_obb_collider(o);
    loop_config c;
    loop_config_default(&c);
    c.frame = LOOP_FRAME_WORLD;
    c.trans_mm_s = 50;
    c.check_invariant = 1;
    uint8_t fixed[2] = {0, 1};
    loop *L = loop_new(f, 2, fixed, &col, &c, NULL);
    int64_t t = 0;
    double top = -INFINITY;
    loop_action_do(L, LOOP_ACT_COLLISION);
    push(L, f, 1, 0, 8, &t, &top); /* 3.2 mm up: the top face at 8.7, the slab's at 7.5 */
    assert_true(fabs(top - 8.7) < 1e-9);
    assert_int_equal(loop_action_do(L, LOOP_ACT_COLLISION), LOOP_IDLE);
    loop_publish(L);
    loop_scene sc = {0};
    loop_scene_read(L, &sc);
    assert_int_equal(sc.penetrating, 1);
    assert_true(sc.separation_mm < 0);
    char line[512];
    navview_format(&sc, NULL, 0, line, sizeof line);
    assert_non_null(strstr(line, "PENETRATING"));
    /* Deeper: every step refused, the depth stays. */
    assert_int_equal(push(L, f, 1, 0, 10, &t, &top), 10);
    assert_true(fabs(top - 8.7) < 1e-9);
    /* Along the slab at the same depth: taken. */
    assert_int_equal(push(L, f, 0, 1, 5, &t, &top), 0);
    pose p = loop_pose(L, 0);
    assert_true(p.t[0] > 1.9);
    assert_true(fabs(top - 8.7) < 1e-9);
    /* A push that is mostly sideways but also deeper: refused. */
    assert_int_equal(push(L, f, 0.2f, 1, 3, &t, &top), 3);
    /* Out: taken, and free again. */
    assert_int_equal(push(L, f, -1, 0, 8, &t, &top), 0);
    p = loop_pose(L, 0);
    assert_true(top_z(&f[0], &p) < 7.5);
    loop_publish(L);
    loop_scene_read(L, &sc);
    assert_int_equal(sc.penetrating, 0);
    loop_stats s;
    loop_get_stats(L, &s);
    assert_true(s.escaping >= 5);
    /* Checked as before: up to the contact, never into it. */
    push(L, f, 1, 0, 20, &t, &top);
    p = loop_pose(L, 0);
    assert_false(brute_collides(f, &p));
    assert_true(7.5 - top_z(&f[0], &p) < 0.05);
    loop_get_stats(L, &s);
    assert_int_equal(s.collisions_in_accepted, 0);
    assert_int_equal(s.unchecked, 8);
    loop_free(L);
    loop_obb_free(o);
    frag_free(&f[0]);
    frag_free(&f[1]);
}

/* A fitted fragment (inside the slab by 0.7 mm, held at a fit's tolerance of 0.4 mm) is
 * measured where it stands when the case opens (loop_measure, from scratch): the search that
 * measured it is kept as its pair's cache, so the first step against the slab answers from it
 * and searches nothing from scratch (a search at a fit's tolerance, where the two surfaces
 * interlock, cost a replay's worst step). Tolerated after a first measure, as bench loop
 * --fitted does: measured again at the hold, not left inside as if checking had been off. */
static void test_fitted_first_step_searches_nothing(void **st)
{
    frag f[2];
    make(f);
    loop_obb *o = loop_obb_new(f, 2, NULL, NULL);
    loop_collider col = loop_obb_collider(o);
    loop_config c;
    loop_config_default(&c);
    c.frame = LOOP_FRAME_WORLD;
    c.check_invariant = 1;
    uint8_t fixed[2] = {0, 1};
    loop *L = loop_new(f, 2, fixed, &col, &c, NULL);
    pose p = {{1, 0, 0, 0}, {0, 0, 2.7}}; /* the cube's top face at 8.2, the slab's lower face at 7.5 */
    loop_set_pose(L, 0, p);
    assert_int_equal(loop_measure(L), 0);
    loop_tolerate(L, 0, 0.4);
    assert_int_equal(loop_measure(L), 0);
    loop_scene sc = {0};
    loop_scene_read(L, &sc);
    assert_int_equal(sc.penetrating, 1);
    assert_int_equal(sc.tolerated_frag[0], 1);
    loop_stats s;
    loop_get_stats(L, &s);
    assert_int_equal(s.queries, 0); /* measuring is not stepping */
    loop_event e = {.kind = LOOP_EV_MOTION, .t_us = 8000};
    e.motion[0] = 1; /* 0.4 mm along the slab: more than the 0.1 mm gap at the hold */
    assert_int_equal(loop_feed(L, &e), LOOP_ACCEPTED);
    loop_get_stats(L, &s);
    assert_true(s.queries >= 1);
    assert_int_equal(s.searches, 0);
    assert_int_equal(s.escaping, 0);
    assert_int_equal(s.collisions_in_accepted, 0);
    assert_true(loop_pose(L, 0).t[0] > 0.39);
    loop_free(L);
    loop_obb_free(o);
    frag_free(&f[0]);
    frag_free(&f[1]);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_head_on_against_slab),
        cmocka_unit_test(test_grazing_slides_under_slab),
        cmocka_unit_test(test_turning_into_slab),
        cmocka_unit_test(test_checking_back_on_inside),
        cmocka_unit_test(test_fitted_first_step_searches_nothing),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
