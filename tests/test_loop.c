/* The navigation loop against a small exact test collider: box fragments (their 8 crop corners)
 * against a fixed half-space "wall" fragment. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "fnclock.h"
#include "loop.h"
#include "navview.h"
#include "ring.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <string.h>

/* Fragment 0: a box of dim*spacing mm with its first voxel centre at `at`. Fragment 1: the wall,
 * everything with x > wall_x (home world). */
typedef struct world {
    frag f[3];
    double wall_x;
    double bumps; /* > 0: the wall's face is a sawtooth in y with teeth this high (mm) */
    int queries;
    int loose; /* > 0: a gap is reported as a bound on the motion (over the teeth's slope too),
                * divided by 1 + (the queries its pair's cache has seen, less one) % loose: a
                * looser bound that depends on the queries before, as an OBB cache's front gives
                * (the yes or no stays exact) */
} world;

static void make_box(frag *f, int id, const double at[3], int nx, int ny, int nz)
{
    memset(f, 0, sizeof *f);
    f->id = id;
    f->dim[0] = nx, f->dim[1] = ny, f->dim[2] = nz;
    f->spacing[0] = f->spacing[1] = f->spacing[2] = 1;
    f->home = POSE_IDENTITY;
    f->pose = POSE_IDENTITY;
    for (int i = 0; i < 3; i++)
        f->home.t[i] = at[i];
    f->centroid[0] = at[0] + (nx - 1) / 2.0;
    f->centroid[1] = at[1] + (ny - 1) / 2.0;
    f->centroid[2] = at[2] + (nz - 1) / 2.0;
}

/* Height of the sawtooth at y: rises over 4 mm, drops back. */
static double tooth(double bumps, double y)
{
    double u = y / 4 - floor(y / 4);
    return bumps * u;
}

/* Largest world x over the voxel-box corners of f at pose p, less the wall's relief there. */
static double max_x_rough(const frag *f, const pose *p, double bumps)
{
    double m = -INFINITY;
    for (int c = 0; c < 8; c++) {
        double x[3], h[3], w[3];
        for (int a = 0; a < 3; a++)
            x[a] = ((c >> a & 1) ? f->dim[a] - 0.5 : -0.5) * f->spacing[a];
        pose_apply(&f->home, x, h);
        pose_apply(p, h, w);
        m = fmax(m, w[0] + tooth(bumps, w[1]));
    }
    return m;
}

/* Largest world x over the voxel-box corners of f at pose p. */
static double max_x(const frag *f, const pose *p)
{
    double m = -INFINITY;
    for (int c = 0; c < 8; c++) {
        double x[3], h[3], w[3];
        for (int a = 0; a < 3; a++)
            x[a] = ((c >> a & 1) ? f->dim[a] - 0.5 : -0.5) * f->spacing[a];
        pose_apply(&f->home, x, h);
        pose_apply(p, h, w);
        if (w[0] > m)
            m = w[0];
    }
    return m;
}

static int wall_query(void *ctx, int a, const pose *pa, int b, const pose *pb, double tol, void *cache,
                      loop_contact *out)
{
    world *w = ctx;
    w->queries++;
    int seen = ++*(int *)cache; /* per-pair cache memory is writable and ours */
    if (b != 1 && a != 1) {
        out->collides = 0;
        out->separation_mm = INFINITY;
        return 0;
    }
    int mover = a == 1 ? b : a;
    const pose *pm = a == 1 ? pb : pa;
    double sep = w->wall_x - (w->bumps > 0 ? max_x_rough(&w->f[mover], pm, w->bumps) : max_x(&w->f[mover], pm));
    /* loose: a bound on how far the box may move, over the teeth's slope (bumps / 4) too */
    double slope = sqrt(1 + w->bumps * w->bumps / 16);
    out->separation_mm = sep > 0 && w->loose > 0 ? sep / slope / (1 + (seen - 1) % w->loose) : sep;
    out->collides = sep < 0;
    return 0;
}

static loop *make_loop(world *w, loop_config *cfg)
{
    double at0[3] = {0, 0, 0}, at1[3] = {20, -50, -50}, at2[3] = {-40, 0, 0};
    make_box(&w->f[0], 1, at0, 5, 5, 5);  /* spans x -0.5..4.5 */
    make_box(&w->f[1], 2, at1, 10, 100, 100);
    make_box(&w->f[2], 3, at2, 3, 3, 3);
    w->wall_x = 10;
    w->bumps = 0;
    w->queries = 0;
    w->loose = 0;
    uint8_t fixed[3] = {0, 1, 0};
    loop_collider col = {wall_query, sizeof(int), w, NULL};
    loop *L = loop_new(w->f, 3, fixed, &col, cfg, NULL);
    assert_non_null(L);
    return L;
}

static void world_config(loop_config *c)
{
    loop_config_default(c);
    c->frame = LOOP_FRAME_WORLD;
    c->trans_mm_s = 100;
    c->rot_deg_s = 90;
    c->check_invariant = 1;
}

static loop_event motion(int64_t t_us, double tx, double ty, double tz, double rx, double ry, double rz)
{
    loop_event e;
    memset(&e, 0, sizeof e);
    e.kind = LOOP_EV_MOTION;
    e.t_us = t_us;
    float m[6] = {(float)tx, (float)ty, (float)tz, (float)rx, (float)ry, (float)rz};
    memcpy(e.motion, m, sizeof m);
    return e;
}

static void test_rotation_about_centroid_is_exact(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    loop_event e = motion(1000, 0, 0, 0, 0, 0, 0);
    assert_int_equal(loop_feed(L, &e), LOOP_IDLE); /* at rest: only sets the clock */
    e = motion(11000, 0, 0, 0, 0, 0, 1);           /* 10 ms at 90 deg/s: 0.9 deg about +z */
    assert_int_equal(loop_feed(L, &e), LOOP_ACCEPTED);
    pose p = loop_pose(L, 0);
    double cen[3];
    pose_apply(&p, w.f[0].centroid, cen);
    for (int i = 0; i < 3; i++)
        assert_true(fabs(cen[i] - w.f[0].centroid[i]) < 1e-12);
    double z[3] = {0, 0, 1};
    pose want = pose_from_axis_angle(z, 0.9 * M_PI / 180);
    assert_true(pose_angle_between(p, want) < 1e-12);
    /* A point 1 mm right of the centroid ends up rotated by exactly 0.9 deg about it. */
    double x[3] = {w.f[0].centroid[0] + 1, w.f[0].centroid[1], w.f[0].centroid[2]}, y[3];
    pose_apply(&p, x, y);
    assert_true(fabs(y[0] - w.f[0].centroid[0] - cos(0.9 * M_PI / 180)) < 1e-12);
    assert_true(fabs(y[1] - w.f[0].centroid[1] - sin(0.9 * M_PI / 180)) < 1e-12);
    loop_free(L);
}

static void test_user_pivot_stays_put(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    double piv[3] = {-5, 3, 1};
    loop_set_pivot(L, piv);
    loop_event e = motion(0, 0, 0, 0, 0.3, -0.5, 0.2);
    for (int k = 0; k < 20; k++, e.t_us += 8000)
        loop_feed(L, &e);
    pose p = loop_pose(L, 0);
    double y[3];
    pose_apply(&p, piv, y);
    for (int i = 0; i < 3; i++)
        assert_true(fabs(y[i] - piv[i]) < 1e-9);
    assert_true(pose_angle_between(p, POSE_IDENTITY) > 0.1);
    loop_free(L);
}

static void test_frames_and_dt_clamp(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    c.frame = LOOP_FRAME_CAMERA;
    loop *L = make_loop(&w, &c);
    /* Camera: device +y (towards the user) moves the fragment anteriorly (world -y), device +z
     * (down) moves it inferiorly (world -z). 8 ms at 100 mm/s = 0.8 mm. */
    loop_event e = motion(0, 0, 0.5, 0.25, 0, 0, 0);
    assert_int_equal(loop_feed(L, &e), LOOP_ACCEPTED); /* the first report: 8 ms (dt_first_us) */
    e.t_us = 8000;
    assert_int_equal(loop_feed(L, &e), LOOP_ACCEPTED);
    pose p = loop_pose(L, 0);
    assert_true(fabs(p.t[0]) < 1e-12 && fabs(p.t[1] + 0.8) < 1e-6 && fabs(p.t[2] + 0.4) < 1e-6);
    /* A 5 s pause integrates only dt_max (20 ms): 2 mm, not 500. */
    e = motion(5008000, 0, 0.5, 0, 0, 0, 0);
    loop_feed(L, &e);
    p = loop_pose(L, 0);
    assert_true(fabs(p.t[1] + 0.8 + 1.0) < 1e-6);
    loop_free(L);

    /* Fragment frame: the fragment turned 90 deg about z; its local x is world +y. */
    world_config(&c);
    c.frame = LOOP_FRAME_FRAGMENT;
    L = make_loop(&w, &c);
    double z[3] = {0, 0, 1};
    loop_set_pose(L, 0, pose_from_axis_angle(z, M_PI / 2));
    e = motion(0, 0, 0, 0, 0, 0, 0);
    loop_feed(L, &e);
    e = motion(10000, 1, 0, 0, 0, 0, 0);
    loop_feed(L, &e);
    p = loop_pose(L, 0);
    assert_true(fabs(p.t[0]) < 1e-9 && fabs(p.t[1] - 1.0) < 1e-9);
    loop_free(L);

    /* The camera frame follows the view (loop_set_camera): seen from the patient's left (looking
     * along -x, superior up), screen right is posterior (+y) and towards the viewer is +x. */
    world_config(&c);
    c.frame = LOOP_FRAME_CAMERA;
    L = make_loop(&w, &c);
    const double right[3] = {0, 1, 0}, up[3] = {0, 0, 1}, fwd[3] = {-1, 0, 0};
    loop_set_camera(L, right, up, fwd);
    e = motion(0, 0, 0, 0, 0, 0, 0);
    loop_feed(L, &e);
    e = motion(10000, 1, 0.5, 0, 0, 0, 0);
    loop_feed(L, &e);
    p = loop_pose(L, 0);
    assert_true(fabs(p.t[1] - 1.0) < 1e-9 && fabs(p.t[0] - 0.5) < 1e-9 && fabs(p.t[2]) < 1e-9);
    loop_free(L);
}

/* Pushes fragment 0 with constant motion for n reports 8 ms apart. */
static void push(loop *L, loop_event e, int n, int64_t *t)
{
    for (int k = 0; k < n; k++) {
        e.t_us = *t;
        *t += 8000;
        int rc = loop_feed(L, &e);
        assert_true(rc >= 0);
    }
}

static void test_head_on_stops_at_contact_and_refuses(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    int64_t t = 0;
    push(L, motion(0, 1, 0, 0, 0, 0, 0), 100, &t); /* 0.8 mm a step towards x = 10 */
    loop_stats s;
    loop_get_stats(L, &s);
    pose p = loop_pose(L, 0);
    double gap = w.wall_x - max_x(&w.f[0], &p);
    assert_true(gap >= 0);
    assert_true(gap < 0.8 / 64 + 0.02); /* bisection gets within 2^-6 of a step */
    assert_int_equal(s.collisions_in_accepted, 0);
    assert_true(s.limited >= 1);
    /* From contact on, every push straight into the wall is refused and moves nothing. */
    uint64_t refused = s.refused;
    push(L, motion(0, 1, 0, 0, 0, 0, 0), 10, &t);
    loop_get_stats(L, &s);
    assert_int_equal(s.refused, refused + 10);
    assert_true(pose_distance(p, loop_pose(L, 0)) == 0);
    assert_int_equal(s.steps, s.accepted + s.limited + s.slid + s.refused);
    loop_free(L);
}

static void test_grazing_slides_along_wall(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    int64_t t = 0;
    /* Mostly into the wall, a little along it (+y). */
    push(L, motion(0, 1, 0.3, 0, 0, 0, 0), 100, &t);
    loop_stats s;
    loop_get_stats(L, &s);
    pose p = loop_pose(L, 0);
    assert_true(w.wall_x - max_x(&w.f[0], &p) >= 0);
    assert_int_equal(s.collisions_in_accepted, 0);
    assert_true(s.slid > 50);
    /* It kept moving along the wall: 100 steps of 0.24 mm in y, nearly all of it. */
    assert_true(p.t[1] > 0.9 * 100 * 0.24);
    loop_free(L);
}

/* A rough wall (a sawtooth whose teeth face the motion): sliding along it means riding over the
 * teeth, backing off a little at each; the fragment must not stop at the first tooth. */
static void test_grazing_rides_over_rough_wall(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    w.bumps = 0.6;
    int64_t t = 0;
    push(L, motion(0, 1, 0.3, 0, 0, 0, 0), 150, &t);
    loop_stats s;
    loop_get_stats(L, &s);
    pose p = loop_pose(L, 0);
    assert_true(w.wall_x - max_x_rough(&w.f[0], &p, w.bumps) >= 0);
    assert_int_equal(s.collisions_in_accepted, 0);
    if (!(p.t[1] > 3 * 4.0))
        fail_msg("stopped at y %g x %g (slid %d refused %d limited %d)", p.t[1], p.t[0], (int)s.slid, (int)s.refused, (int)s.limited); /* past three teeth */
    loop_free(L);
}

static uint64_t hist_rng = 0x243f6a8885a308d3ull; /* this test's own draws */
static double hist_uniform(void) /* [-1, 1) */
{
    hist_rng = hist_rng * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(hist_rng >> 11) * 0x1.0p-52 - 1;
}

/* A report into the rough wall (x) or back from it, more often into it, and less along it, in +y
 * (up the teeth's slopes: the test collider's gap bounds such moves, and a slide's climb backs off
 * in x, the push) and z: contacts made, ridden along and left. */
static loop_event random_push(int64_t t_us)
{
    double x = (hist_uniform() < -0.4 ? -1 : 1) * (0.8 + 0.2 * hist_uniform());
    return motion(t_us, x, 0.3 + 0.25 * hist_uniform(), 0.5 * hist_uniform(), 0, 0, 0);
}

/* The poses the loop takes never depend on the queries it made before, though the gaps its
 * collider reports do (a looser bound after other queries, as an OBB cache's front gives): a loop
 * that first moves through a random history and is put back where a fresh one starts takes the
 * same poses as the fresh one for the same reports, bit for bit, sliding over a rough wall where
 * a step's query budget (max_tries) runs out. Before, a candidate the carried gap proved free
 * cost no query, so the budget ran out at a point that depended on the gaps reported before. */
static void test_steps_ignore_history(void **st)
{
    enum { TRIALS = 20, HISTORY = 40, STEPS = 150 };
    int differ = 0, budget_steps = 0;
    for (int trial = 0; trial < TRIALS; trial++) {
        world wf, ww;
        loop_config c;
        world_config(&c);
        loop *fresh = make_loop(&wf, &c), *warm = make_loop(&ww, &c);
        wf.bumps = ww.bumps = 0.6;
        wf.loose = ww.loose = 4;
        pose start = loop_pose(fresh, 0);
        int64_t tf = 0, tw = 0;
        for (int k = 0; k < HISTORY; k++, tw += 8000) {
            loop_event e = random_push(tw);
            assert_true(loop_feed(warm, &e) >= 0);
        }
        loop_set_pose(warm, 0, start);
        for (int k = 0; k < STEPS; k++, tf += 8000, tw += 8000) {
            loop_event e = random_push(tf);
            int before = wf.queries;
            assert_true(loop_feed(fresh, &e) >= 0);
            budget_steps += wf.queries - before >= c.max_tries; /* the invariant check's included */
            e.t_us = tw;
            assert_true(loop_feed(warm, &e) >= 0);
            pose pf = loop_pose(fresh, 0), pw = loop_pose(warm, 0);
            if (!(wf.wall_x - max_x_rough(&wf.f[0], &pf, wf.bumps) >= 0)) {
                loop_stats ls;
                loop_get_stats(fresh, &ls);
                fail_msg("trial %d step %d: sep %g, collisions_in_accepted %llu, motion %g %g %g", trial, k,
                         wf.wall_x - max_x_rough(&wf.f[0], &pf, wf.bumps), (unsigned long long)ls.collisions_in_accepted,
                         e.motion[0], e.motion[1], e.motion[2]);
            }
            if (memcmp(&pf, &pw, sizeof pf)) {
                print_message("trial %d step %d: y %.9f x %.9f fresh, y %.9f x %.9f after a history\n", trial, k,
                              pf.t[1], pf.t[0], pw.t[1], pw.t[0]);
                differ++;
                break;
            }
        }
        loop_free(fresh);
        loop_free(warm);
    }
    print_message("%d steps made max_tries queries or more\n", budget_steps);
    assert_true(budget_steps > 0);
    if (differ)
        fail_msg("%d of %d trials took other poses after a history of queries", differ, TRIALS);
}

static void test_rotation_into_wall_slides_or_stops(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    int64_t t = 0;
    /* Park 1 mm from the wall, then spin about y and push: corners swing into the wall. */
    loop_set_pose(L, 0, (pose){{1, 0, 0, 0}, {4.5, 0, 0}});
    push(L, motion(0, 0.2, 0, 0, 0, 1, 0), 200, &t);
    loop_stats s;
    loop_get_stats(L, &s);
    pose p = loop_pose(L, 0);
    assert_true(w.wall_x - max_x(&w.f[0], &p) >= 0);
    assert_int_equal(s.collisions_in_accepted, 0);
    assert_true(s.limited + s.slid + s.refused > 0);
    loop_free(L);
}

static void test_undo_redo_gestures(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    int64_t t = 0;
    push(L, motion(0, 0, 1, 0, 0, 0, 0), 5, &t); /* gesture 1: 4 steps of 0.8 mm in y */
    push(L, motion(0, 0, 0, 0, 0, 0, 0), 1, &t); /* release */
    pose g1 = loop_pose(L, 0);
    push(L, motion(0, 0, 0, 1, 0, 0, 0), 5, &t); /* gesture 2: in z */
    pose g2 = loop_pose(L, 0);
    assert_true(fabs(g1.t[1] - 4.0) < 1e-9 && fabs(g2.t[2] - 4.0) < 1e-9);
    assert_int_equal(loop_action_do(L, LOOP_ACT_UNDO), LOOP_ACCEPTED);
    assert_true(pose_distance(loop_pose(L, 0), g1) == 0);
    assert_int_equal(loop_action_do(L, LOOP_ACT_UNDO), LOOP_ACCEPTED);
    assert_true(pose_distance(loop_pose(L, 0), POSE_IDENTITY) == 0);
    assert_int_equal(loop_action_do(L, LOOP_ACT_UNDO), LOOP_IDLE); /* nothing left */
    assert_int_equal(loop_action_do(L, LOOP_ACT_REDO), LOOP_ACCEPTED);
    assert_int_equal(loop_action_do(L, LOOP_ACT_REDO), LOOP_ACCEPTED);
    assert_true(pose_distance(loop_pose(L, 0), g2) == 0);
    /* Undo once, then a new gesture: the redo history is gone. */
    loop_action_do(L, LOOP_ACT_UNDO);
    push(L, motion(0, -1, 0, 0, 0, 0, 0), 3, &t);
    assert_int_equal(loop_action_do(L, LOOP_ACT_REDO), LOOP_IDLE);
    loop_free(L);
}

static loop_event proposal(int i, pose p)
{
    loop_event e;
    memset(&e, 0, sizeof e);
    e.kind = LOOP_EV_POSE;
    e.frag = i;
    e.pose = p;
    return e;
}

/* A proposed pose is one step of its own: taken whole when free, refused inside the wall or for
 * a fixed fragment, undone alone (the gesture before it stays), and counted in the scene. */
static void test_proposed_pose_one_undo_step(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    int64_t t = 0;
    push(L, motion(0, 0, 1, 0, 0, 0, 0), 3, &t); /* a gesture, still going on */
    pose g = loop_pose(L, 0), free_p = g, inside = g;
    free_p.t[2] += 3;
    inside.t[0] += 8; /* x up to 12.5: through the wall at 10 */
    loop_event e = proposal(0, free_p);
    assert_int_equal(loop_feed(L, &e), LOOP_ACCEPTED);
    assert_true(pose_distance(loop_pose(L, 0), free_p) == 0);
    e = proposal(0, inside);
    assert_int_equal(loop_feed(L, &e), LOOP_REFUSED);
    e = proposal(1, POSE_IDENTITY); /* the wall is fixed */
    assert_int_equal(loop_feed(L, &e), LOOP_REFUSED);
    e = proposal(7, free_p);
    assert_int_equal(loop_feed(L, &e), LOOP_REFUSED);
    assert_int_equal(loop_action_do(L, LOOP_ACT_UNDO), LOOP_ACCEPTED);
    assert_true(pose_distance(loop_pose(L, 0), g) == 0); /* back to the gesture's end */
    assert_int_equal(loop_action_do(L, LOOP_ACT_UNDO), LOOP_ACCEPTED);
    assert_true(pose_distance(loop_pose(L, 0), POSE_IDENTITY) == 0);
    loop_publish(L);
    loop_scene sc = {0};
    loop_scene_read(L, &sc);
    assert_true(sc.proposals == 4);
    assert_int_equal(sc.proposal_result[1], LOOP_ACCEPTED);
    assert_int_equal(sc.proposal_result[2], LOOP_REFUSED);
    loop_action_do(L, LOOP_ACT_COLLISION); /* off: any pose is taken */
    e = proposal(0, inside);
    assert_int_equal(loop_feed(L, &e), LOOP_ACCEPTED);
    loop_free(L);
}

static void test_undo_refused_when_it_would_collide(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    int64_t t = 0;
    push(L, motion(0, 0, 1, 0, 0, 0, 0), 3, &t);
    push(L, motion(0, 0, 0, 0, 0, 0, 0), 1, &t);
    /* The wall moves over the fragment's old place; undoing into it must be refused. */
    w.wall_x = -5;
    assert_int_equal(loop_action_do(L, LOOP_ACT_UNDO), LOOP_REFUSED);
    loop_free(L);
}

static void test_controls(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    /* next/prev skip the fixed wall (fragment 1). */
    assert_int_equal(loop_selected(L), 0);
    loop_action_do(L, LOOP_ACT_NEXT);
    assert_int_equal(loop_selected(L), 2);
    loop_action_do(L, LOOP_ACT_PREV);
    assert_int_equal(loop_selected(L), 0);
    /* A device button press maps to an action (button 0 = next), only on the press. */
    loop_event e = motion(0, 0, 0, 0, 0, 0, 0);
    e.buttons = 1;
    loop_feed(L, &e);
    e.t_us = 8000;
    loop_feed(L, &e);
    assert_int_equal(loop_selected(L), 2);
    loop_action_do(L, LOOP_ACT_NEXT);
    /* Fixed: motion does nothing. */
    loop_action_do(L, LOOP_ACT_FIX);
    assert_true(loop_fixed(L, 0));
    int64_t t = 16000;
    push(L, motion(0, 0, 1, 0, 0, 0, 0), 3, &t);
    assert_true(pose_distance(loop_pose(L, 0), POSE_IDENTITY) == 0);
    loop_action_do(L, LOOP_ACT_FIX);
    /* Rotation only: translation input is ignored. */
    loop_action_do(L, LOOP_ACT_ROT_ONLY);
    push(L, motion(0, 0, 1, 0, 0, 0, 0.5), 3, &t);
    pose p = loop_pose(L, 0);
    double cen[3];
    pose_apply(&p, w.f[0].centroid, cen);
    assert_true(fabs(cen[1] - w.f[0].centroid[1]) < 1e-9);
    assert_true(pose_angle_between(p, POSE_IDENTITY) > 0);
    loop_action_do(L, LOOP_ACT_ROT_ONLY);
    /* Collision checking off: the fragment goes into the wall, the scene warns, and those poses
     * are counted as unchecked. */
    loop_action_do(L, LOOP_ACT_COLLISION);
    push(L, motion(0, 1, 0, 0, 0, 0, 0), 30, &t);
    p = loop_pose(L, 0);
    assert_true(max_x(&w.f[0], &p) > w.wall_x);
    loop_publish(L);
    loop_scene sc = {0};
    loop_scene_read(L, &sc);
    assert_int_equal(sc.collision_on, 0);
    char line[512];
    navview_format(&sc, NULL, 0, line, sizeof line);
    assert_non_null(strstr(line, "COLLISION CHECKING OFF"));
    loop_stats s;
    loop_get_stats(L, &s);
    assert_true(s.unchecked >= 20);
    /* Back on while inside: it may be pulled out, and once free it is checked again. */
    loop_action_do(L, LOOP_ACT_COLLISION);
    push(L, motion(0, -1, 0, 0, 0, 0, 0), 40, &t);
    p = loop_pose(L, 0);
    assert_true(max_x(&w.f[0], &p) < w.wall_x);
    push(L, motion(0, 1, 0, 0, 0, 0, 0), 60, &t);
    p = loop_pose(L, 0);
    assert_true(max_x(&w.f[0], &p) <= w.wall_x);
    loop_get_stats(L, &s);
    assert_int_equal(s.collisions_in_accepted, 0);
    loop_free(L);
}

static void test_unplug_keeps_pose_and_time_restarts(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    int64_t t = 0;
    push(L, motion(0, 0, 1, 0, 0, 0, 0), 4, &t);
    pose before = loop_pose(L, 0);
    loop_event u = {.kind = LOOP_EV_UNPLUG, .t_us = t};
    assert_int_equal(loop_feed(L, &u), LOOP_IDLE);
    loop_publish(L);
    loop_scene sc = {0};
    loop_scene_read(L, &sc);
    assert_int_equal(sc.device_present, 0);
    assert_true(pose_distance(sc.pose[0], before) == 0);
    /* Back after 3 s: the first report counts as one report period (8 ms), not 3 s. */
    u.kind = LOOP_EV_REPLUG;
    loop_feed(L, &u);
    t += 3000000;
    push(L, motion(0, 0, 1, 0, 0, 0, 0), 1, &t);
    assert_true(fabs(pose_distance(loop_pose(L, 0), before) - 0.8) < 1e-9);
    push(L, motion(0, 0, 1, 0, 0, 0, 0), 1, &t);
    assert_true(fabs(pose_distance(loop_pose(L, 0), before) - 1.6) < 1e-9);
    loop_free(L);
}

/* The same events give the same digest; a different event gives another. */
static uint64_t run_script(double wiggle)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    int64_t t = 0;
    for (int k = 0; k < 300; k++) {
        loop_event e = motion(t, 0.9, sin(k * 0.05) + wiggle, 0.2 * cos(k * 0.03), 0.1, 0.3, -0.2);
        t += 8000;
        loop_feed(L, &e);
    }
    loop_stats s;
    loop_get_stats(L, &s);
    assert_int_equal(s.collisions_in_accepted, 0);
    loop_free(L);
    return s.pose_digest;
}

static void test_digest_deterministic(void **st)
{
    uint64_t a = run_script(0), b = run_script(0), c = run_script(0.001);
    assert_true(a == b);
    assert_true(a != c);
}

static void test_drain_publishes_scene(void **st)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    ring *r = ring_new(sizeof(loop_event), 64);
    loop_scene sc = {0};
    loop_scene_read(L, &sc);
    uint64_t seq0 = sc.seq;
    for (int k = 0; k < 10; k++) {
        loop_event e = motion(k * 8000, 0, 1, 0, 0, 0, 0);
        e.arrival_us = fnclock_now_us();
        ring_push(r, &e);
    }
    assert_int_equal(loop_drain(L, r), 10);
    assert_int_equal(loop_scene_read(L, &sc), 1);
    assert_true(sc.seq > seq0);
    assert_true(fabs(sc.pose[0].t[1] - 8.0) < 1e-9); /* world frame: 10 steps of 0.8 mm */
    assert_int_equal(sc.stats.steps, 10);
    assert_int_equal(sc.stats.latency_samples, 10);
    assert_int_equal(loop_scene_read(L, &sc), 0); /* nothing newer */
    ring_free(r);
    loop_free(L);
}

/* A source of n motion events 8 ms apart, then the end. */
typedef struct counted {
    int n, sent;
    loop *L;   /* when set: reads taken before loop_run started are counted in early */
    int early;
} counted;

static int counted_next(void *ctx, loop_event *ev, int timeout_ms)
{
    counted *c = ctx;
    if (c->L && !loop_running(c->L))
        c->early++;
    if (c->sent == c->n)
        return LOOP_SOURCE_END;
    *ev = motion(8000 * (int64_t)c->sent++, 0, 0, 0.5, 0, 0, 0);
    return 1;
}

typedef struct viewer {
    loop *L;
    atomic_int stop;
    int reads, fresh, torn;
} viewer;

/* A renderer: reads scenes as fast as it can while the loop runs; each must be consistent: the
 * counted source moves 0.4 mm along z per step, all free, so the pose and the step count of one
 * scene agree (a scene torn between two publishes does not). */
static void *view(void *arg)
{
    viewer *v = arg;
    loop_scene sc = {0};
    uint64_t last = 0;
    while (!atomic_load(&v->stop) || !v->fresh) { /* a starved viewer still reads the last one */
        v->fresh += loop_scene_read(v->L, &sc);
        if (sc.seq < last || sc.nfrag != 3 || sc.stats.steps != sc.stats.accepted ||
            fabs(sc.pose[0].t[2] - 0.4 * (double)sc.stats.steps) > 1e-6)
            v->torn++;
        last = sc.seq;
        v->reads++;
    }
    return NULL;
}

/* The live arrangement: input thread -> ring -> loop_run, nviews renderers reading meanwhile
 * (navigate reads from its UI thread and, for the LED, from the input thread). */
static void run_with_viewers(int nviews)
{
    world w;
    loop_config c;
    world_config(&c);
    loop *L = make_loop(&w, &c);
    ring *r = ring_new(sizeof(loop_event), 16);
    counted src = {2000, 0, L, 0};
    viewer v[3];
    pthread_t th[3];
    for (int i = 0; i < nviews; i++) {
        v[i] = (viewer){.L = L};
        atomic_init(&v[i].stop, 0);
        pthread_create(&th[i], NULL, view, &v[i]);
    }
    loop_reader *rd = loop_reader_start((loop_source){counted_next, &src}, r, L, 1);
    assert_non_null(rd);
    assert_int_equal(loop_run(L, r, 1000, loop_reader_done_flag(rd)), 0);
    assert_int_equal(loop_reader_stop(rd), 0);
    /* The reader waited for the loop's start (its pages mapped): no report waited in the ring
     * meanwhile, which the first one's latency would have counted (milliseconds). */
    assert_int_equal(src.early, 0);
    for (int i = 0; i < nviews; i++) {
        atomic_store(&v[i].stop, 1);
        pthread_join(th[i], NULL);
    }
    loop_stats s;
    loop_get_stats(L, &s);
    assert_int_equal(s.events, 2000);
    assert_int_equal(s.steps, 2000);
    assert_int_equal(s.dropped, 0);
    assert_int_equal(s.latency_samples, 2000);
    pose p = loop_pose(L, 0);
    assert_true(fabs(p.t[2] - 2000 * 0.4) < 1e-6); /* 0.5 * 100 mm/s * 8 ms a step */
    for (int i = 0; i < nviews; i++) {
        assert_true(v[i].fresh > 0);
        assert_int_equal(v[i].torn, 0);
    }
    loop_scene last = {0};
    loop_scene_read(L, &last);
    assert_int_equal(last.stats.steps, 2000); /* the last publish reached the readers */
    ring_free(r);
    loop_free(L);
}

static void test_threads_reader_loop_renderer(void **st)
{
    run_with_viewers(1);
}

/* Several readers at once (navigate has two: UI and LED): none ever sees a torn scene. */
static void test_scene_concurrent_readers(void **st)
{
    run_with_viewers(3);
}

static void test_bad_arguments(void **st)
{
    world w;
    memset(&w, 0, sizeof w);
    loop_collider col = {wall_query, sizeof(int), &w, NULL};
    assert_null(loop_new(w.f, 0, NULL, &col, NULL, NULL));
    assert_non_null(strstr(fn_err_msg(), "fragments"));
    assert_null(loop_new(w.f, 2, NULL, NULL, NULL, NULL));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_rotation_about_centroid_is_exact),
        cmocka_unit_test(test_user_pivot_stays_put),
        cmocka_unit_test(test_frames_and_dt_clamp),
        cmocka_unit_test(test_head_on_stops_at_contact_and_refuses),
        cmocka_unit_test(test_grazing_slides_along_wall),
        cmocka_unit_test(test_grazing_rides_over_rough_wall),
        cmocka_unit_test(test_steps_ignore_history),
        cmocka_unit_test(test_rotation_into_wall_slides_or_stops),
        cmocka_unit_test(test_undo_redo_gestures),
        cmocka_unit_test(test_proposed_pose_one_undo_step),
        cmocka_unit_test(test_undo_refused_when_it_would_collide),
        cmocka_unit_test(test_controls),
        cmocka_unit_test(test_unplug_keeps_pose_and_time_restarts),
        cmocka_unit_test(test_digest_deterministic),
        cmocka_unit_test(test_drain_publishes_scene),
        cmocka_unit_test(test_threads_reader_loop_renderer),
        cmocka_unit_test(test_scene_concurrent_readers),
        cmocka_unit_test(test_bad_arguments),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
