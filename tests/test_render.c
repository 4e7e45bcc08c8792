/* The renderer through OSMesa (llvmpipe): every mode and layout against reference pictures
 * (tests/golden/render_*.png, 128x128, compared under a tolerance), every mode draws content,
 * interpenetrating fragments both show, a known pose moves the picture by the expected pixels, and
 * a GL older than 4.5 is refused with its version named, and (where Xvfb is installed) the GLFW
 * window draws what OSMesa draws.
 * FRACNAV_UPDATE_GOLDEN=1 rewrites the references (look at each before committing it). */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>
#include <jansson.h>

#include "case.h"
#include "err.h"
#include "frag.h"
#include "mesh.h"
#include "render.h"
#include "picture.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <math.h>
#include <pthread.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#define W 128
#define H 128
#define N 40
#define SMOOTH_MAX_ERR 7.5 /* test_surface_shading_is_smooth: grey levels, on average */

typedef struct scene {
    vol *ct, *labels;
    frag f[2];
    render *r;
    uint8_t rgb[W * H * 3];
} scene;

/* A ball of bone (HU rising smoothly to 1000 inside radius 10) and a box of bone, apart. */
static float ct_value(int i, int j, int k)
{
    double d = sqrt((i - 14.0) * (i - 14.0) + (j - 20.0) * (j - 20.0) + (k - 20.0) * (k - 20.0));
    double s = (10.0 - d) / 3.0 + 0.5;
    double ball = -1000.0 + 2000.0 * (s < 0 ? 0 : s > 1 ? 1 : s);
    int in_box = i >= 26 && i < 34 && j >= 16 && j < 24 && k >= 16 && k < 24;
    return (float)(in_box ? 900.0 : ball);
}

static int setup(void **st)
{
    scene *s = calloc(1, sizeof *s);
    s->ct = vol_new(N, N, N);
    s->labels = vol_new(N, N, N);
    for (int k = 0; k < N; k++)
        for (int j = 0; j < N; j++)
            for (int i = 0; i < N; i++) {
                float v = ct_value(i, j, k);
                size_t x = vol_idx(s->ct, i, j, k);
                s->ct->data[x] = v;
                s->labels->data[x] = v < 300 ? 0 : i < 24 ? 1 : 2;
            }
    for (int id = 1; id <= 2; id++) {
        int lo[3], hi[3];
        assert_int_equal(frag_label_box(s->labels, id, lo, hi), 0);
        assert_int_equal(frag_from_labels(&s->f[id - 1], s->labels, s->ct, id, lo, hi, 300, 200), 0);
    }
    s->r = render_open("osmesa", W, H);
    if (!s->r)
        fail_msg("render_open: %s", fn_err_msg());
    obb_params hp = {0.5, 0.95};
    assert_int_equal(render_set_scene(s->r, s->ct, s->f, 2, 300, &hp), 0);
    *st = s;
    return 0;
}

static int teardown(void **st)
{
    tu_end_all(); /* what a failed window test left running */
    scene *s = *st;
    render_close(s->r);
    frag_free(&s->f[0]);
    frag_free(&s->f[1]);
    vol_free(s->ct);
    vol_free(s->labels);
    free(s);
    return 0;
}

static void draw(scene *s, const pose *poses, const render_options *o)
{
    if (render_frame(s->r, poses, o))
        fail_msg("render_frame: %s", fn_err_msg());
    assert_int_equal(render_read_rgb(s->r, s->rgb), 0);
}

static int is_background(const uint8_t *p)
{
    return p[0] < 40 && p[1] < 40 && p[2] < 40;
}

static long content_pixels(const uint8_t *rgb)
{
    long n = 0;
    for (int i = 0; i < W * H; i++)
        n += !is_background(rgb + i * 3);
    return n;
}

/* Compares with tests/golden/render_NAME.png: a pixel differs when a channel is off by more than
 * 32; at most 1% of the pixels may differ. */
static void check_golden(const uint8_t *rgb, const char *name)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/tests/golden/render_%s.png", tu_src(), name);
    const char *update = getenv("FRACNAV_UPDATE_GOLDEN");
    if (update && !strcmp(update, "1")) {
        assert_int_equal(picture_write_png(path, rgb, W, H), 0);
        return;
    }
    png_image im = {.version = PNG_IMAGE_VERSION};
    if (!png_image_begin_read_from_file(&im, path))
        fail_msg("%s: cannot read the reference (FRACNAV_UPDATE_GOLDEN=1 makes it)", path);
    im.format = PNG_FORMAT_RGB;
    assert_int_equal(im.width, W);
    assert_int_equal(im.height, H);
    uint8_t *ref = malloc(PNG_IMAGE_SIZE(im));
    assert_true(png_image_finish_read(&im, NULL, ref, 0, NULL));
    long differ = 0;
    for (int i = 0; i < W * H; i++) {
        int d = 0;
        for (int c = 0; c < 3; c++)
            d |= abs(rgb[i * 3 + c] - ref[i * 3 + c]) > 32;
        differ += d;
    }
    free(ref);
    if (differ > W * H / 100)
        fail_msg("%s: %ld of %d pixels differ from the reference", name, differ, W * H);
}

static void options(scene *s, render_options *o, render_mode m)
{
    render_options_default(o, s->f, 2);
    o->mode = m;
}

static void test_every_mode_draws_and_matches(void **st)
{
    scene *s = *st;
    for (int m = RENDER_ISO; m <= RENDER_SURFACE; m++) {
        render_options o;
        options(s, &o, (render_mode)m);
        draw(s, NULL, &o);
        long n = content_pixels(s->rgb);
        if (n < 400)
            fail_msg("mode %s drew %ld pixels of content", render_mode_name((render_mode)m), n);
        check_golden(s->rgb, render_mode_name((render_mode)m));
    }
}

/* The headless GPU path: "egl" opens on a GPU's EGL device or is refused naming EGL (FN_ENODEV:
 * no GPU here, where this test was written: only that fallback has been seen), and "offscreen"
 * then falls back to OSMesa's llvmpipe; on a GPU it is not llvmpipe. */
static void test_offscreen_takes_egl_or_falls_back_to_osmesa(void **st)
{
    (void)st;
    render *egl = render_open("egl", 32, 32);
    char why[512];
    snprintf(why, sizeof why, "%s", egl ? "" : fn_err_msg());
    int gpu = egl != NULL;
    if (!gpu && !strstr(why, "egl"))
        fail_msg("render_open(egl) failed without naming EGL: %s", why);
    render_close(egl);
    render *r = render_open("offscreen", 32, 32);
    if (!r)
        fail_msg("render_open(offscreen): %s", fn_err_msg());
    int llvmpipe = strstr(render_gl_renderer(r), "llvmpipe") != NULL;
    print_message("offscreen: %s (egl: %s)\n", render_gl_renderer(r), gpu ? "a GPU" : why);
    assert_int_equal(llvmpipe, !gpu);
    render_close(r);
}

/* Software GL pays per triangle: the surface meshes hold at most 30% of the triangles of the
 * closed marching-tetrahedra surface of the same bone (mesh_extract over the whole CT; the ball
 * and the box are apart, so each crop holds the same surface), and the picture stays the
 * reference's (test_every_mode_draws_and_matches). */
static void test_surface_meshes_are_decimated(void **st)
{
    scene *s = *st;
    const int dim[3] = {N, N, N};
    const double sp[3] = {1, 1, 1};
    mesh m;
    assert_int_equal(mesh_extract(s->ct->data, dim, sp, 300.0f, &m), 0);
    long full = m.nt, drawn = render_surface_triangles(s->r);
    mesh_free(&m);
    if (drawn <= 0 || drawn > 0.3 * (double)full)
        fail_msg("the surface meshes hold %ld triangles; the full surface has %ld", drawn, full);
}

typedef struct prep_job {
    const scene *s;
    double iso_hu;
    render_prep *p;
} prep_job;

static void *prepare_on_a_thread(void *arg)
{
    prep_job *j = arg;
    j->p = render_prepare(j->s->ct, j->s->f, 2, j->iso_hu, 2);
    return NULL;
}

/* The seed mode's preview prepares its pieces' crops and meshes on its worker
 * (render_prepare) and the window uploads them (render_set_prepared): the picture is
 * render_set_fragments's, pixel for pixel; a preparation at another level is not used (the
 * same picture again), and more fragments than can be drawn are refused by count. */
static void test_prepared_fragments_draw_the_same(void **st)
{
    scene *s = *st;
    render_options o;
    options(s, &o, RENDER_SURFACE);
    assert_int_equal(render_set_fragments(s->r, s->ct, s->f, 2), 0);
    draw(s, NULL, &o);
    uint8_t *want = malloc(sizeof s->rgb);
    memcpy(want, s->rgb, sizeof s->rgb);
    long tri = render_surface_triangles(s->r);
    for (int other = 0; other < 2; other++) {
        prep_job j = {s, other ? 500.0 : render_iso_hu(s->r), NULL};
        pthread_t t;
        assert_int_equal(pthread_create(&t, NULL, prepare_on_a_thread, &j), 0);
        pthread_join(t, NULL);
        if (!j.p)
            fail_msg("render_prepare: %s", fn_err_msg());
        assert_int_equal(render_set_prepared(s->r, s->ct, s->f, 2, j.p), 0);
        render_prep_free(j.p);
        draw(s, NULL, &o);
        assert_int_equal(render_surface_triangles(s->r), tri);
        assert_memory_equal(s->rgb, want, sizeof s->rgb);
    }
    free(want);
    assert_null(render_prepare(s->ct, s->f, RENDER_MAX_FRAGS + 1, 300, 1));
    assert_non_null(strstr(fn_err_msg(), "at most"));
}

static void test_four_up_with_overlays_matches(void **st)
{
    scene *s = *st;
    render_options o;
    options(s, &o, RENDER_ISO);
    o.layout = RENDER_LAYOUT_FOUR_UP;
    o.overlays = RENDER_OVERLAY_HIERARCHY | RENDER_OVERLAY_AXES;
    o.hierarchy_depth = 2;
    draw(s, NULL, &o);
    check_golden(s->rgb, "four_up");
    options(s, &o, RENDER_SURFACE);
    render_camera_standard(&o.camera, RENDER_SUPERIOR, s->f, 2);
    o.overlays = RENDER_OVERLAY_AXES;
    draw(s, NULL, &o);
    check_golden(s->rgb, "surface_superior_axes");
}

/* Surface mode, four-up, the slices through fragment 2's centroid. */
static void four_up_through_b(scene *s, render_options *o)
{
    options(s, o, RENDER_SURFACE);
    o->layout = RENDER_LAYOUT_FOUR_UP;
    memcpy(o->slice_point, s->f[1].centroid, sizeof o->slice_point);
}

/* The seed mode's marks on the four-up slices: a mark on the slices' point shows on all three, a
 * square of its colour ringed in black at the pixel that render_slice_point_at maps to it; a mark
 * 10 mm above the axial plane shows on the coronal and sagittal slices only where they pass it,
 * never on the axial one; the 3D view is as without marks. */
static void test_four_up_marks_the_seeds(void **st)
{
    scene *s = *st;
    render_options o;
    four_up_through_b(s, &o);
    draw(s, NULL, &o);
    uint8_t *plain = malloc(sizeof s->rgb);
    assert_non_null(plain);
    memcpy(plain, s->rgb, sizeof s->rgb);
    o.nmarks = 2;
    memcpy(o.marks[0], o.slice_point, sizeof o.marks[0]);
    memcpy(o.marks[1], o.slice_point, sizeof o.marks[1]);
    o.marks[1][2] += 10;
    const uint8_t rgb[2][3] = {{20, 230, 40}, {240, 20, 200}};
    memcpy(o.mark_rgb, rgb, sizeof rgb);
    draw(s, NULL, &o);
    int rect[4][4];
    render_four_up_panes(W, H, 0, rect);
    for (int pane = 0; pane < 3; pane++)
        for (int m = 0; m < 2; m++) {
            const int *q = rect[pane];
            long seen = 0, ring = 0;
            int x0 = W, x1 = -1, y0 = H, y1 = -1;
            for (int y = q[1]; y < q[1] + q[3]; y++)
                for (int x = q[0]; x < q[0] + q[2]; x++) {
                    const uint8_t *p = s->rgb + (y * W + x) * 3;
                    if (p[0] != rgb[m][0] || p[1] != rgb[m][1] || p[2] != rgb[m][2])
                        continue;
                    seen++;
                    double w[3];
                    assert_int_equal(render_slice_point_at(s->r, &o, x + 0.5, y + 0.5, w), pane);
                    double d = 0;
                    for (int a = 0; a < 3; a++)
                        if (a != (pane == RENDER_PANE_AXIAL ? 2 : pane == RENDER_PANE_CORONAL ? 1 : 0))
                            d = fmax(d, fabs(w[a] - o.marks[m][a]));
                    double px_mm = 2 * o.camera.half_height / q[3];
                    if (d > (RENDER_MARK_PX / 2 + 1) * px_mm)
                        fail_msg("pane %d: mark %d's colour at (%d, %d), %.2f mm from it", pane, m, x, y, d);
                    x0 = x < x0 ? x : x0, x1 = x > x1 ? x : x1, y0 = y < y0 ? y : y0, y1 = y > y1 ? y : y1;
                }
            int want = m == 0 || pane != RENDER_PANE_AXIAL;
            if (want ? seen != RENDER_MARK_PX * RENDER_MARK_PX || x1 - x0 + 1 != RENDER_MARK_PX ||
                           y1 - y0 + 1 != RENDER_MARK_PX
                     : seen != 0)
                fail_msg("pane %d: mark %d drawn over %ld pixels", pane, m, seen);
            for (int y = y0 - 1; want && y <= y1 + 1; y++) /* the ring around the square: black */
                for (int x = x0 - 1; x <= x1 + 1; x++) {
                    const uint8_t *p = s->rgb + (y * W + x) * 3;
                    ring += (x < x0 || x > x1 || y < y0 || y > y1) && !p[0] && !p[1] && !p[2];
                }
            print_message("pane %d mark %d: %ld pixels, a ring of %ld black ones\n", pane, m, seen, ring);
            if (want && ring != 4 * (RENDER_MARK_PX + 1))
                fail_msg("pane %d: mark %d's black ring has %ld pixels", pane, m, ring);
        }
    /* the 3D view is as before */
    for (int y = rect[RENDER_PANE_3D][1]; y < rect[RENDER_PANE_3D][1] + rect[RENDER_PANE_3D][3]; y++)
        assert_memory_equal(s->rgb + (size_t)y * W * 3, plain + (size_t)y * W * 3, (size_t)W * 3);
    free(plain);
}

/* Four-up as 3D Slicer's "3D and three slices": the 3D view over the top two thirds, the slices
 * below. A pixel of the axial slice maps back to the world point it shows: the box's outline,
 * drawn there, centres where render_slice_point_at puts the box's centroid (a click there moves
 * the window's crosshair to it). */
static void test_four_up_pixel_to_world(void **st)
{
    scene *s = *st;
    render_options o;
    four_up_through_b(s, &o);
    draw(s, NULL, &o);
    int rect[4][4];
    render_four_up_panes(W, H, 0, rect);
    assert_true(rect[RENDER_PANE_3D][3] > H / 2 && rect[RENDER_PANE_3D][2] == W); /* the large 3D view */
    const int *q = rect[RENDER_PANE_AXIAL];
    double sx = 0, sy = 0, n = 0;
    for (int y = q[1]; y < q[1] + q[3]; y++)
        for (int x = q[0]; x < q[0] + q[2]; x++) {
            const uint8_t *p = s->rgb + (y * W + x) * 3;
            if (p[0] > 120 && (double)p[1] / p[0] < 0.7)
                sx += x + 0.5, sy += y + 0.5, n++;
        }
    if (n < 10)
        fail_msg("the axial slice shows %.0f pixels of the box", n);
    double world[3];
    assert_int_equal(render_slice_point_at(s->r, &o, sx / n, sy / n, world), RENDER_PANE_AXIAL);
    for (int a = 0; a < 2; a++)
        if (fabs(world[a] - s->f[1].centroid[a]) > 1.5)
            fail_msg("the box's outline centres at (%.1f, %.1f) mm, its centroid is (%.1f, %.1f)", world[0],
                     world[1], s->f[1].centroid[0], s->f[1].centroid[1]);
    assert_true(fabs(world[2] - s->f[1].centroid[2]) < 1e-9); /* on the slice's plane */
    assert_int_equal(render_slice_point_at(s->r, &o, W / 2, H / 4, world), -1); /* the 3D view */
}

/* Ball colour (230,216,190): g/r near 0.94; box colour (220,90,80): near 0.41. */
static void count_colours(const uint8_t *rgb, long *ball, long *box);

/* Seen from the right the ball hides the box; with the cut-away kept for the box, the ball's
 * surface in front of it is not drawn, and the box shows (render_fragment_pixels and the
 * picture). */
static void test_cutaway_shows_the_piece_in_hand(void **st)
{
    scene *s = *st;
    render_options o;
    options(s, &o, RENDER_SURFACE);
    render_camera_standard(&o.camera, RENDER_RIGHT, s->f, 2);
    long proj[2], vis[2], ball, box;
    assert_int_equal(render_fragment_pixels(s->r, NULL, &o, proj, vis), 0);
    if (!(proj[1] > 50 && vis[1] < proj[1] / 10))
        fail_msg("without the cut-away the box shows %ld of %ld pixels: it should be hidden", vis[1], proj[1]);
    o.cutaway = 2;
    assert_int_equal(render_fragment_pixels(s->r, NULL, &o, proj, vis), 0);
    if (vis[1] < proj[1] * 9 / 10)
        fail_msg("with the cut-away the box shows %ld of %ld pixels", vis[1], proj[1]);
    draw(s, NULL, &o);
    count_colours(s->rgb, &ball, &box);
    if (box < 50 || ball < 200)
        fail_msg("with the cut-away the picture shows %ld pixels of the box and %ld of the ball", box, ball);
}

/* The same in iso mode (the raycaster skips the other fragments' samples inside the cut): from
 * the right the box shows in under a tenth of its pixels without the cut-away, and in 90% or more
 * with it. */
static void test_cutaway_in_iso_shows_the_piece_in_hand(void **st)
{
    scene *s = *st;
    render_options o;
    options(s, &o, RENDER_ISO);
    render_camera_standard(&o.camera, RENDER_RIGHT, s->f, 2);
    long proj[2], ball, box;
    pose alone[2] = {POSE_IDENTITY, POSE_IDENTITY};
    alone[0].t[1] = 1000; /* the ball out of sight: the box's own pixels in iso */
    draw(s, alone, &o);
    count_colours(s->rgb, &ball, &proj[1]);
    o.cutaway = 0;
    draw(s, NULL, &o);
    count_colours(s->rgb, &ball, &box);
    if (!(proj[1] > 50 && box < proj[1] / 10))
        fail_msg("iso without the cut-away shows %ld of the box's %ld pixels: it should be hidden", box, proj[1]);
    o.cutaway = 2;
    draw(s, NULL, &o);
    count_colours(s->rgb, &ball, &box);
    if (box < proj[1] * 9 / 10 || ball < 200)
        fail_msg("iso with the cut-away shows %ld of the box's %ld pixels (and %ld of the ball)", box, proj[1],
                 ball);
}

static void count_colours(const uint8_t *rgb, long *ball, long *box)
{
    *ball = *box = 0;
    for (int i = 0; i < W * H; i++) {
        const uint8_t *p = rgb + i * 3;
        if (p[0] < 50)
            continue;
        double g = (double)p[1] / p[0];
        *ball += g > 0.8;
        *box += g < 0.6;
    }
}

/* The box is moved into the ball, its front face 2 mm in front of the ball's: from the front the
 * box shows inside the ball's outline and the ball around it, in every raycast mode and surface. */
static void test_interpenetrating_fragments_both_show(void **st)
{
    scene *s = *st;
    pose poses[2] = {POSE_IDENTITY, POSE_IDENTITY};
    poses[1].t[0] = -16;
    poses[1].t[1] = -8;
    const render_mode modes[] = {RENDER_ISO, RENDER_DVR, RENDER_SURFACE};
    for (int m = 0; m < 3; m++) {
        render_options o;
        options(s, &o, modes[m]);
        draw(s, poses, &o);
        long ball, box;
        count_colours(s->rgb, &ball, &box);
        if (ball < 100 || box < 100)
            fail_msg("%s: ball %ld pixels, box %ld: both should show", render_mode_name(modes[m]), ball, box);
        if (modes[m] == RENDER_ISO)
            check_golden(s->rgb, "interpenetrating");
    }
}

/* The contacts overlay in a raycast mode that shows no surface (dvr) outlines the colliding voxels
 * in yellow where the box is inside the ball, and draws nothing when the two are apart. */
static long yellow_pixels(const uint8_t *rgb)
{
    long n = 0;
    for (int i = 0; i < W * H; i++)
        n += rgb[i * 3] > 180 && rgb[i * 3 + 1] > 160 && rgb[i * 3 + 2] < 90;
    return n;
}

static void test_contacts_overlay_marks_colliding_voxels(void **st)
{
    scene *s = *st;
    render_options o;
    options(s, &o, RENDER_DVR);
    o.overlays = RENDER_OVERLAY_CONTACTS;
    draw(s, NULL, &o);
    assert_int_equal(yellow_pixels(s->rgb), 0);
    pose poses[2] = {POSE_IDENTITY, POSE_IDENTITY};
    poses[1].t[0] = -16;
    poses[1].t[1] = -8;
    draw(s, poses, &o);
    long n = yellow_pixels(s->rgb);
    if (n < 50)
        fail_msg("the contacts overlay drew %ld yellow pixels", n);
    check_golden(s->rgb, "contacts");
}

/* The contacts colour: red through orange (not yellow, not a fragment's palette colour). */
static int gap_red(const uint8_t *p)
{
    return p[0] > 150 && p[1] < 0.75 * p[0] && p[2] < 0.45 * p[0];
}

/* Its yellow (about 1.5 mm): not red, not a fragment's palette colour. */
static int gap_yellow(const uint8_t *p)
{
    return p[0] > 150 && p[1] >= 0.75 * p[0] && p[2] < 0.5 * p[0];
}

/* Two blocks of bone side by side along x (labels 1 and 3: beige and blue), touching face to face
 * at voxel x 20 (1 mm voxels at the origin); drawn WxW in surface mode with the contacts overlay at
 * B's pose b. Returns the red pixels and their mean column into *col; *legend: the red ones in the
 * legend's corner (bottom right), which the count leaves out. */
typedef struct blocks {
    vol *ct, *labels;
    frag f[2];
    render *r;
} blocks;
enum { BW = 256 };

static void blocks_open(blocks *b)
{
    b->ct = vol_new(N, N, N);
    b->labels = vol_new(N, N, N);
    for (int k = 0; k < N; k++)
        for (int j = 0; j < N; j++)
            for (int i = 0; i < N; i++) {
                int in = i >= 8 && i < 32 && j >= 12 && j < 28 && k >= 12 && k < 28;
                size_t x = vol_idx(b->ct, i, j, k);
                b->ct->data[x] = in ? 900.0f : -1000.0f;
                b->labels->data[x] = !in ? 0 : i < 20 ? 1 : 3;
            }
    for (int n = 0; n < 2; n++) {
        int lo[3], hi[3], id = n ? 3 : 1;
        assert_int_equal(frag_label_box(b->labels, id, lo, hi), 0);
        assert_int_equal(frag_from_labels(&b->f[n], b->labels, b->ct, id, lo, hi, 300, 200), 0);
    }
    b->r = render_open("osmesa", BW, BW);
    if (!b->r)
        fail_msg("render_open: %s", fn_err_msg());
    obb_params hp = {0.5, 0.95};
    assert_int_equal(render_set_scene(b->r, b->ct, b->f, 2, 300, &hp), 0);
}

static void blocks_close(blocks *b)
{
    render_close(b->r);
    frag_free(&b->f[0]);
    frag_free(&b->f[1]);
    vol_free(b->ct);
    vol_free(b->labels);
}

static long blocks_red(blocks *b, const render_options *o, double gap, uint8_t *rgb, double *col, long *legend)
{
    pose poses[2] = {POSE_IDENTITY, POSE_IDENTITY};
    poses[1].t[0] = gap;
    if (render_frame(b->r, poses, o))
        fail_msg("render_frame: %s", fn_err_msg());
    assert_int_equal(render_read_rgb(b->r, rgb), 0);
    long n = 0;
    double sum = 0;
    *legend = 0;
    for (int i = 0; i < BW * BW; i++) {
        if (!gap_red(rgb + i * 3))
            continue;
        if (i % BW > BW / 2 && i / BW > BW * 3 / 4) {
            ++*legend;
            continue;
        }
        n++;
        sum += i % BW;
    }
    *col = n ? sum / n : -1;
    return n;
}

/* Both facing surfaces turn red where the blocks touch, each seen through the other (the cut-away
 * kept for it), mostly yellow 1.5 mm apart, and keep their own colours 6 mm apart; from above,
 * red shows in a band along the fracture line only (within the 3 mm of the scale), not on the
 * blocks' far parts, in surface mode and in iso; the legend's bar shows at the bottom right.
 * Without the overlay nothing is red. */
static void test_contacts_colour_both_facing_surfaces(void **st)
{
    (void)st;
    blocks b;
    blocks_open(&b);
    uint8_t *rgb = malloc(BW * BW * 3);
    render_options o;
    render_options_default(&o, b.f, 2);
    o.mode = RENDER_SURFACE;
    o.overlays = RENDER_OVERLAY_CONTACTS;
    double col;
    long legend;
    for (int side = 0; side < 2; side++) { /* B's face seen from A's side, then A's from B's */
        render_camera_standard(&o.camera, side ? RENDER_LEFT : RENDER_RIGHT, b.f, 2);
        o.cutaway = side ? 1 : 2;
        long touching = blocks_red(&b, &o, 0, rgb, &col, &legend);
        long apart = blocks_red(&b, &o, 6, rgb, &col, &legend);
        long near = blocks_red(&b, &o, 1.5, rgb, &col, &legend), yellow = 0;
        for (int i = 0; i < BW * BW; i++)
            yellow += gap_yellow(rgb + i * 3) && !(i % BW > BW / 2 && i / BW > BW * 3 / 4);
        print_message("%s's facing surface: %ld red pixels touching, %ld 6 mm apart; 1.5 mm apart %ld red, %ld "
                      "yellow\n",
                      side ? "A" : "B", touching, apart, near, yellow);
        if (touching < 2000 || apart > 0 || yellow < 2000 || near * 3 > yellow) /* the rim, shaded darker, reads orange */
            fail_msg("%s's facing surface: %ld red pixels touching, %ld 6 mm apart; 1.5 mm apart %ld red, %ld yellow",
                     side ? "A" : "B", touching, apart, near, yellow);
        if (legend < 50)
            fail_msg("the legend's bar shows %ld red pixels", legend);
    }
    /* From above: the junction at world x 19.5, the blocks over x 7.5 .. 31.5; screen right is
     * world -x. */
    render_camera_standard(&o.camera, RENDER_SUPERIOR, b.f, 2);
    o.cutaway = 0;
    double px_mm = BW / (2 * o.camera.half_height);
    double junction = BW / 2.0 - (19.5 - o.camera.centre[0]) * px_mm;
    long top = blocks_red(&b, &o, 0, rgb, &col, &legend);
    long outside = 0;
    for (int i = 0; i < BW * BW; i++)
        outside += gap_red(rgb + i * 3) && fabs(i % BW - junction) > 3.0 * px_mm && !(i % BW > BW / 2 && i / BW > BW * 3 / 4);
    print_message("from above: %ld red pixels around column %.1f (the junction %.1f), %ld beyond 3 mm of it\n", top, col,
                  junction, outside);
    if (top < 100 || fabs(col - junction) > 1.5 * px_mm || outside > 0)
        fail_msg("from above: %ld red pixels around column %.1f (the junction %.1f), %ld beyond 3 mm of it", top, col,
                 junction, outside);
    /* The same in iso (the raycaster colours its hits): red along the junction only, the legend. */
    o.mode = RENDER_ISO;
    long iso = blocks_red(&b, &o, 0, rgb, &col, &legend), iso_outside = 0;
    for (int i = 0; i < BW * BW; i++)
        iso_outside += gap_red(rgb + i * 3) && fabs(i % BW - junction) > 3.0 * px_mm &&
                       !(i % BW > BW / 2 && i / BW > BW * 3 / 4);
    print_message("iso from above: %ld red pixels around column %.1f, %ld beyond 3 mm, legend %ld\n", iso, col,
                  iso_outside, legend);
    if (iso < 100 || fabs(col - junction) > 1.5 * px_mm || iso_outside > 0 || legend < 50)
        fail_msg("iso from above: %ld red pixels around column %.1f (the junction %.1f), %ld beyond 3 mm of it, "
                 "legend %ld",
                 iso, col, junction, iso_outside, legend);
    o.mode = RENDER_SURFACE;
    o.overlays = 0;
    if (blocks_red(&b, &o, 0, rgb, &col, &legend) + legend > 0)
        fail_msg("without the overlay %ld pixels are red", blocks_red(&b, &o, 0, rgb, &col, &legend) + legend);
    free(rgb);
    blocks_close(&b);
}

/* The VOI overlay outlines its box in cyan, where the box is. */
static void test_voi_overlay_outlines_the_box(void **st)
{
    scene *s = *st;
    render_options o;
    options(s, &o, RENDER_SURFACE);
    o.overlays = RENDER_OVERLAY_VOI;
    o.nvoi = 1;
    /* Around the ball (voxels 4..24 x, 10..30 y and z; 1 mm voxels at the origin). */
    const double box[6] = {4, 10, 10, 24, 30, 30};
    memcpy(o.voi[0], box, sizeof box);
    draw(s, NULL, &o);
    long cyan = 0;
    double sx = 0;
    for (int i = 0; i < W * H; i++)
        if (s->rgb[i * 3] < 120 && s->rgb[i * 3 + 1] > 200 && s->rgb[i * 3 + 2] > 200) {
            cyan++;
            sx += i % W;
        }
    if (cyan < 100)
        fail_msg("the VOI overlay drew %ld cyan pixels", cyan);
    if (sx / (double)cyan > W / 2.0)
        fail_msg("the VOI box is drawn on the right (column %.1f); the ball is on the left", sx / (double)cyan);
    check_golden(s->rgb, "voi");
}

/* The HUD: text over the frame, top left, in mixed case, a warning line in amber. */
static void test_hud_draws_text(void **st)
{
    scene *s = *st;
    render_options o;
    options(s, &o, RENDER_SURFACE);
    assert_int_equal(render_frame(s->r, NULL, &o), 0);
    assert_int_equal(render_hud(s->r, "frag 2/2 touching\nWARNING: collision checking OFF", 1), 0);
    assert_int_equal(render_read_rgb(s->r, s->rgb), 0);
    long white = 0, amber = 0, below = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            const uint8_t *p = s->rgb + (y * W + x) * 3;
            int w = p[0] > 200 && p[1] > 200 && p[2] > 200, a = p[0] > 200 && p[1] > 140 && p[1] < 220 && p[2] < 80;
            white += w && y < 12;
            amber += a && y >= 12 && y < 24;
            below += (w || a) && y >= 40 && x < 8;
        }
    if (white < 20 || amber < 20 || below)
        fail_msg("the HUD drew %ld white pixels in its first line, %ld amber in its second, %ld elsewhere",
                 white, amber, below);
    check_golden(s->rgb, "hud");
    /* Mixed case: n and N are two glyphs (the issue: "N/P" read where the keys are n/p). */
    uint8_t *capital = malloc((size_t)W * H * 3);
    assert_int_equal(render_frame(s->r, NULL, &o), 0);
    assert_int_equal(render_hud(s->r, "N", 2), 0);
    assert_int_equal(render_read_rgb(s->r, capital), 0);
    assert_int_equal(render_frame(s->r, NULL, &o), 0);
    assert_int_equal(render_hud(s->r, "n", 2), 0);
    assert_int_equal(render_read_rgb(s->r, s->rgb), 0);
    long differ = 0;
    for (int i = 0; i < W * H * 3; i++)
        differ += s->rgb[i] != capital[i];
    free(capital);
    if (differ < 10)
        fail_msg("n and N draw the same glyph (%ld bytes differ)", differ);
    /* g hangs below the line, as in print, where a's foot stands (at 5x7 a g on the line read as
     * 9: "9 fits", "9ap (mm)"). */
    int lowest[2];
    for (int k = 0; k < 2; k++) {
        assert_int_equal(render_frame(s->r, NULL, &o), 0);
        assert_int_equal(render_hud(s->r, k ? "g" : "a", 1), 0);
        assert_int_equal(render_read_rgb(s->r, s->rgb), 0);
        lowest[k] = -1;
        for (int y = 0; y < 16; y++)
            for (int x = 0; x < 12; x++)
                if (s->rgb[(y * W + x) * 3] > 200)
                    lowest[k] = y;
    }
    if (lowest[1] <= lowest[0])
        fail_msg("g's lowest row %d is not below a's (%d)", lowest[1], lowest[0]);
}

static void centroid(const uint8_t *rgb, double *cx, double *cy)
{
    double sx = 0, sy = 0, n = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++)
            if (!is_background(rgb + (y * W + x) * 3)) {
                sx += x;
                sy += y;
                n++;
            }
    assert_true(n > 0);
    *cx = sx / n;
    *cy = sy / n;
}

/* Anterior view: +x (patient left) is screen right, +z (superior) is up; a pose's translation of
 * d mm moves the ball by d * H / (2 * half_height) pixels, in every mode. */
static void test_pose_moves_picture_by_expected_pixels(void **st)
{
    scene *s = *st;
    for (int m = RENDER_ISO; m <= RENDER_SURFACE; m++) {
        render_options o;
        options(s, &o, (render_mode)m);
        pose poses[2] = {POSE_IDENTITY, POSE_IDENTITY};
        poses[1].t[0] = 200; /* the box out of the picture */
        double x0, y0, x1, y1;
        draw(s, poses, &o);
        centroid(s->rgb, &x0, &y0);
        poses[0].t[0] = 6;
        poses[0].t[2] = -4;
        draw(s, poses, &o);
        centroid(s->rgb, &x1, &y1);
        double px_per_mm = H / (2.0 * o.camera.half_height);
        if (fabs((x1 - x0) - 6 * px_per_mm) > 0.75 || fabs((y1 - y0) - 4 * px_per_mm) > 0.75)
            fail_msg("%s: moved (%.2f, %.2f) px, expected (%.2f, %.2f)", render_mode_name((render_mode)m),
                     x1 - x0, y1 - y0, 6 * px_per_mm, 4 * px_per_mm);
    }
}

/* navigate's live preview: the ghost (render_options.ghost) draws a fragment again, translucent, at
 * the fitted pose, over everything, in every mode. The box is moved out of the picture and its
 * ghost put back where it was segmented: the right of the picture (the ball's edge alone without
 * the ghost) shows it. */
static void test_ghost_draws_the_fitted_pose(void **st)
{
    scene *s = *st;
    for (int m = RENDER_ISO; m <= RENDER_SURFACE; m++) {
        render_options o;
        options(s, &o, (render_mode)m);
        pose poses[2] = {POSE_IDENTITY, POSE_IDENTITY};
        poses[1].t[0] = 200;
        long right[2];
        for (int g = 0; g < 2; g++) {
            o.ghost = g ? 2 : 0;
            o.ghost_pose = POSE_IDENTITY;
            draw(s, poses, &o);
            right[g] = 0;
            for (int i = 0; i < W * H; i++)
                right[g] += i % W > W / 2 + 4 && !is_background(s->rgb + i * 3);
        }
        if (right[1] < right[0] + 200)
            fail_msg("%s: %ld pixels on the right without the ghost, %ld with it", render_mode_name((render_mode)m),
                     right[0], right[1]);
    }
}

/* Late latching: render_frame_early with the poses then, render_frame_late with the newest, gives
 * the picture render_frame gives of the newest poses: when only the late fragment moved in
 * between (the split frame), when another one moved too (the whole frame again), and in a mode
 * that cannot split (iso: render_frame_late draws it all). The ball and the box overlap, so the
 * late fragment's depth test against the early one's is checked too. */
static void test_late_latching_draws_the_newest_poses(void **st)
{
    scene *s = *st;
    static uint8_t want[W * H * 3];
    const render_mode modes[2] = {RENDER_SURFACE, RENDER_ISO};
    for (int m = 0; m < 2; m++) {
        render_options o;
        options(s, &o, modes[m]);
        pose then[2] = {POSE_IDENTITY, POSE_IDENTITY}, newest[2] = {POSE_IDENTITY, POSE_IDENTITY};
        then[1].t[0] = -8;   /* the box half into the ball */
        newest[1].t[0] = -5; /* the late fragment (the box) moved on */
        newest[1].t[2] = 2;
        for (int other_moved = 0; other_moved < 2; other_moved++) {
            newest[0].t[1] = other_moved ? 3 : 0;
            newest[0].t[0] = other_moved ? 4 : 0;
            draw(s, newest, &o);
            memcpy(want, s->rgb, sizeof want);
            if (modes[m] == RENDER_SURFACE && !other_moved) {
                /* the early part is the ball alone: the frame is split */
                pose ball_alone[2] = {then[0], then[1]};
                ball_alone[1].t[0] = 200;
                draw(s, ball_alone, &o);
                long ball = content_pixels(s->rgb);
                assert_int_equal(render_frame_early(s->r, then, 1, &o), 0);
                assert_int_equal(render_read_rgb(s->r, s->rgb), 0);
                if (labs(content_pixels(s->rgb) - ball) > 20)
                    fail_msg("render_frame_early drew %ld pixels of content, the ball alone %ld",
                             content_pixels(s->rgb), ball);
            }
            assert_int_equal(render_frame_early(s->r, then, 1, &o), 0);
            if (render_frame_late(s->r, newest, &o))
                fail_msg("render_frame_late: %s", fn_err_msg());
            assert_int_equal(render_read_rgb(s->r, s->rgb), 0);
            long differ = 0;
            for (int i = 0; i < W * H * 3; i += 3)
                differ += abs(want[i] - s->rgb[i]) > 32 || abs(want[i + 1] - s->rgb[i + 1]) > 32 ||
                          abs(want[i + 2] - s->rgb[i + 2]) > 32;
            if (differ > W * H / 200)
                fail_msg("%s, %s: the late-latched frame differs from render_frame's in %ld pixels",
                         render_mode_name(modes[m]), other_moved ? "another fragment moved" : "only the late one",
                         differ);
            if (content_pixels(s->rgb) < 400)
                fail_msg("%s: the late-latched frame shows no fragments", render_mode_name(modes[m]));
        }
    }
}

static void test_gl_version_parse(void **st)
{
    int major = 0, minor = 0;
    assert_int_equal(render_parse_gl_version("4.5 (Core Profile) Mesa 22.3.6", &major, &minor), 0);
    assert_int_equal(major, 4);
    assert_int_equal(minor, 5);
    assert_int_equal(render_parse_gl_version("OpenGL ES 3.2 Mesa 22.3.6", &major, &minor), 0);
    assert_int_equal(major, 3);
    assert_int_equal(minor, 2);
    assert_int_equal(render_parse_gl_version("no version", &major, &minor), FN_EFORMAT);
}

/* Mesa told to offer GL 3.3 only: opening fails, naming 3.3 and the 4.5 it needs. In a child, so
 * the override cannot leak into the other tests; and before any test loads OSMesa into this
 * process (the child would inherit a Mesa that has read its environment already), so it stays
 * near the top of the list. */
static void test_old_gl_is_refused_with_its_version(void **st)
{
    int fds[2];
    assert_int_equal(pipe(fds), 0);
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        setenv("MESA_GL_VERSION_OVERRIDE", "3.3", 1);
        render *r = render_open("osmesa", 16, 16);
        const char *msg = r ? "opened" : fn_err_msg();
        ssize_t ignored = write(fds[1], msg, strlen(msg));
        (void)ignored;
        _exit(0);
    }
    close(fds[1]);
    char buf[1024] = "";
    size_t n = 0;
    ssize_t k;
    while (n < sizeof buf - 1 && (k = read(fds[0], buf + n, sizeof buf - 1 - n)) > 0)
        n += (size_t)k;
    close(fds[0]);
    int status;
    waitpid(pid, &status, 0);
    if (!strstr(buf, "4.5") || !strstr(buf, "3.3"))
        fail_msg("expected an error naming 4.5 and 3.3, got: %s", buf);
}

/* The share of fragment `id`'s projected pixels that `fracnav render CASE --json LOOK` shows
 * (visible_pixels / projected_pixels of its entry in "fragments"). */
static double shown_share(const char *case_dir, const char *dir, int id, const char *look)
{
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "render '%s' -o '%s/view.png' --size 256x256 --mode surface --fragment %d "
                                      "--json %s", case_dir, dir, id, look), 0);
    json_error_t e;
    const char *brace = strchr(out, '{'); /* after render's line on standard error */
    json_t *j = brace ? json_loads(brace, JSON_DISABLE_EOF_CHECK, &e) : NULL, *frags = j ? json_object_get(j, "fragments") : NULL;
    if (!json_is_array(frags))
        fail_msg("render --json printed no fragments array: %s", out);
    double share = -1;
    for (size_t i = 0; i < json_array_size(frags); i++) {
        json_t *f = json_array_get(frags, i);
        if (json_integer_value(json_object_get(f, "id")) != id)
            continue;
        json_int_t proj = json_integer_value(json_object_get(f, "projected_pixels"));
        json_int_t vis = json_integer_value(json_object_get(f, "visible_pixels"));
        assert_true(proj > 0 && vis >= 0 && vis <= proj);
        share = (double)vis / (double)proj;
    }
    json_decref(j);
    free(out);
    return share;
}

/* The issue: the default anterior camera looked at the face while the moving piece sat at the back
 * of the skull, mostly hidden. On the demo's fracture of the example CT (2 pieces, seed 1) and on a
 * 3-piece one, the default view (auto) shows each moving fragment at >= 50% of its projected
 * pixels; the anterior view hides fragment 2 (so the measure tells them apart), and shows 90% of
 * it with --cutaway on. */
static void test_auto_view_shows_the_moving_fragment(void **st)
{
    (void)st;
    const char *ct = tu_example_ct();
    char *dir = tu_tmpdir("autoview"), case_dir[4200];
    const int pieces[2] = {2, 3};
    for (int k = 0; k < 2; k++) {
        snprintf(case_dir, sizeof case_dir, "%s/f%d", dir, pieces[k]);
        char *out = NULL;
        assert_int_equal(tu_run_cli(&out, "fracture '%s' -o '%s' --seed 1 --pieces %d", ct, case_dir, pieces[k]), 0);
        free(out);
        for (int id = 2; id <= pieces[k]; id++) {
            double share = shown_share(case_dir, dir, id, "");
            if (share < 0.5)
                fail_msg("%d pieces: the default view shows %.0f%% of fragment %d", pieces[k], 100 * share, id);
        }
        double anterior = shown_share(case_dir, dir, 2, "--view anterior");
        if (anterior >= 0.5)
            fail_msg("%d pieces: the anterior view shows %.0f%% of fragment 2: the test tells nothing", pieces[k],
                     100 * anterior);
        double cut = shown_share(case_dir, dir, 2, "--view anterior --cutaway on");
        if (cut < 0.9)
            fail_msg("%d pieces: the anterior view with the cut-away shows %.0f%% of fragment 2", pieces[k],
                     100 * cut);
    }
    tu_rmtree(dir);
    free(dir);
}

/* A case of a hollow box of bone (A, fixed: 32 voxels a side, walls 4 thick) around a block (B,
 * 12 a side, 6 voxels of air around it): from every side A hides B. */
static void enclosed_case(const char *dir, char *case_dir, size_t cap)
{
    vol *v = vol_new(40, 40, 40);
    for (int k = 0; k < 40; k++)
        for (int j = 0; j < 40; j++)
            for (int i = 0; i < 40; i++) {
                int x[3] = {i, j, k}, outer = 1, inner = 1, block = 1;
                for (int a = 0; a < 3; a++) {
                    outer &= x[a] >= 4 && x[a] < 36;
                    inner &= x[a] >= 8 && x[a] < 32;
                    block &= x[a] >= 14 && x[a] < 26;
                }
                v->data[vol_idx(v, i, j, k)] = (outer && !inner) || block ? 1000 : -1000;
            }
    char path[4200];
    snprintf(path, sizeof path, "%s/enclosed.nii.gz", dir);
    assert_int_equal(volio_write(v, path, VOL_I16), 0);
    vol_free(v);
    snprintf(case_dir, cap, "%s/case", dir);
    tu_segment(path, case_dir, "--ramp 0");
    planning_case *c = case_load(case_dir);
    assert_non_null(c);
    assert_int_equal(c->nfrag, 2);
    int shell = c->frag[0].voxels > c->frag[1].voxels ? c->frag[0].id : c->frag[1].id;
    case_free(c);
    assert_int_equal(tu_run_cli(NULL, "edit '%s' fix %d", case_dir, shell), 0);
}

static uint8_t *read_png(const char *path, int *w, int *h);

/* The pixels of png in colour want, shaded (its channels' shares of their sum within 0.04 of
 * want's). */
static long pixels_coloured(const char *png, const uint8_t want[3])
{
    int w, h;
    uint8_t *rgb = read_png(png, &w, &h);
    long n = 0;
    for (long i = 0; i < (long)w * h; i++) {
        const uint8_t *p = rgb + i * 3;
        if (p[0] + p[1] + p[2] < 120)
            continue;
        double s = (double)(p[0] + p[1] + p[2]), t = (double)(want[0] + want[1] + want[2]);
        int near = 1;
        for (int c = 0; c < 3; c++)
            near &= fabs(p[c] / s - want[c] / t) < 0.04;
        n += near;
    }
    free(rgb);
    return n;
}

/* Nothing hides the piece in hand: in a hollow box the block is hidden from every side, yet the
 * auto view of render shows 90% of it (the cut-away on by default; under 10% with --cutaway off),
 * and the report's before and after pictures (iso, the auto view) show it. */
static void test_cutaway_shows_the_enclosed_piece(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("enclosed"), case_dir[4200], path[4400];
    enclosed_case(dir, case_dir, sizeof case_dir);
    planning_case *c = case_load(case_dir);
    assert_non_null(c);
    const frag *b = &c->frag[c->fixed == 0 ? 1 : 0];
    int block = b->id;
    uint8_t colour[3] = {b->rgb[0], b->rgb[1], b->rgb[2]};
    case_free(c);
    double shown = shown_share(case_dir, dir, block, ""), hidden = shown_share(case_dir, dir, block, "--cutaway off");
    if (shown < 0.9 || hidden >= 0.1)
        fail_msg("the auto view shows %.0f%% of the enclosed block, %.0f%% with --cutaway off", 100 * shown,
                 100 * hidden);
    char *out = NULL;
    int rc = tu_run_cli(&out, "export '%s' --report '%s/report' --platform osmesa", case_dir, dir);
    if (rc)
        fail_msg("export --report exited %d: %s", rc, out);
    free(out);
    const char *pics[2] = {"before", "after"};
    for (int k = 0; k < 2; k++) {
        snprintf(path, sizeof path, "%s/report/%s.png", dir, pics[k]);
        long n = pixels_coloured(path, colour);
        if (n < 500)
            fail_msg("the report's %s picture shows %ld pixels of the enclosed block", pics[k], n);
    }
    tu_rmtree(dir);
    free(dir);
}

/* Without Xvfb: a visible skip, or a failure under CI (where .ci/setup installs it). */
static void no_xvfb(void)
{
    if (getenv("CI") && *getenv("CI"))
        fail_msg("Xvfb is not installed (/usr/bin/Xvfb; package xvfb, in .ci/setup)");
    print_message("skipped: Xvfb is not installed (package xvfb)\n");
    skip();
}

/* The teardown of a test that starts processes: what a failed test left running (Xvfb, a
 * fracnav) is ended here, not at the end of the run. */
static int end_children(void **st)
{
    (void)st;
    tu_end_all();
    unsetenv("DISPLAY");
    return 0;
}

/* Starts Xvfb on a free display; its number comes back through -displayfd once it is ready.
 * Returns its pid (0 when Xvfb is not installed). */
static pid_t start_xvfb(int *display)
{
    if (access("/usr/bin/Xvfb", X_OK) != 0)
        return 0;
    int fds[2];
    assert_int_equal(pipe(fds), 0);
    pid_t parent = getpid(), pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        tu_in_child(parent);
        char fd[16];
        snprintf(fd, sizeof fd, "%d", fds[1]);
        close(fds[0]);
        execl("/usr/bin/Xvfb", "Xvfb", "-displayfd", fd, "-screen", "0", "1024x1024x24", "-nolisten", "tcp",
              (char *)NULL);
        _exit(127);
    }
    close(fds[1]);
    char buf[32] = "";
    size_t n = 0;
    ssize_t k;
    while (n < sizeof buf - 1 && (k = read(fds[0], buf + n, sizeof buf - 1 - n)) > 0) {
        n += (size_t)k;
        if (memchr(buf, '\n', n))
            break;
    }
    close(fds[0]);
    tu_adopt(pid); /* a failed test's teardown ends it (end_children) */
    if (sscanf(buf, "%d", display) != 1)
        fail_msg("Xvfb gave no display number");
    return pid;
}

/* The same frame through a GLFW window (on Xvfb, in a child so the window's GL stays apart from
 * OSMesa's) matches the offscreen one. */
static void test_window_matches_offscreen(void **st)
{
#if defined(__SANITIZE_THREAD__)
    /* The child draws with new threads after a fork of a process that runs llvmpipe's threads,
     * which ThreadSanitizer does not support: the plain and ASan stages run this test. */
    print_message("skipped under ThreadSanitizer: a window in a child forked from llvmpipe's threads\n");
    skip();
#endif
    scene *s = *st;
    int display;
    pid_t xvfb = start_xvfb(&display);
    if (!xvfb)
        no_xvfb();
    render_options o;
    options(s, &o, RENDER_ISO);
    o.layout = RENDER_LAYOUT_FOUR_UP;
    int fds[2];
    assert_int_equal(pipe(fds), 0);
    pid_t parent = getpid(), pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        tu_in_child(parent);
        char d[32];
        snprintf(d, sizeof d, ":%d", display);
        setenv("DISPLAY", d, 1);
        close(fds[0]);
        render *w = render_open("glfw", W, H);
        int ok = w && !render_set_scene(w, s->ct, s->f, 2, 300, NULL) && !render_frame(w, NULL, &o) &&
                 !render_read_rgb(w, s->rgb);
        if (!ok)
            fprintf(stderr, "window: %s\n", fn_err_msg());
        ssize_t ignored = ok ? write(fds[1], s->rgb, sizeof s->rgb) : 0;
        (void)ignored;
        render_close(w);
        _exit(ok ? 0 : 1);
    }
    close(fds[1]);
    static uint8_t win[W * H * 3];
    size_t n = 0;
    ssize_t k;
    while (n < sizeof win && (k = read(fds[0], win + n, sizeof win - n)) > 0)
        n += (size_t)k;
    close(fds[0]);
    int status;
    waitpid(pid, &status, 0);
    tu_end(xvfb, SIGTERM, "Xvfb");
    assert_int_equal(n, sizeof win);
    draw(s, NULL, &o);
    long differ = 0;
    for (int i = 0; i < W * H * 3; i++)
        differ += abs(win[i] - s->rgb[i]) > 32;
    if (differ > W * H / 100)
        fail_msg("the window's frame differs from OSMesa's in %ld channel values", differ);
}

/* How rough a surface-mode picture of a ball of bone looks (a binary CT, 1 mm voxels, radius
 * `radius` voxels in a grid of n^3): the residual of its red channel (0-255) against the shading
 * of the true sphere (render__mesh_fs: colour * (0.2 + 0.8 d) + 0.25 d^24, d the normal's share
 * towards the viewer), its mean absolute change from a pixel to the next right and down, over the
 * pixels within 0.9 of the outline's radius: voxel steps show as bands, a bias does not count. */
static double ball_shading_error(int n, double radius)
{
    vol *ct = vol_new(n, n, n), *labels = vol_new(n, n, n);
    double c = (n - 1) / 2.0;
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++) {
                int in = (i - c) * (i - c) + (j - c) * (j - c) + (k - c) * (k - c) <= radius * radius;
                ct->data[vol_idx(ct, i, j, k)] = in ? 1000.0f : -1000.0f;
                labels->data[vol_idx(labels, i, j, k)] = (float)in;
            }
    frag f;
    int lo[3], hi[3];
    assert_int_equal(frag_label_box(labels, 1, lo, hi), 0);
    assert_int_equal(frag_from_labels(&f, labels, ct, 1, lo, hi, 300, 200), 0);
    const int size = 256;
    render *r = render_open("osmesa", size, size);
    assert_non_null(r);
    assert_int_equal(render_set_scene(r, ct, &f, 1, 300, NULL), 0);
    render_options o;
    render_options_default(&o, &f, 1);
    o.mode = RENDER_SURFACE;
    uint8_t *rgb = malloc((size_t)size * size * 3);
    assert_int_equal(render_frame(r, NULL, &o), 0);
    assert_int_equal(render_read_rgb(r, rgb), 0);
    double sx = 0, sy = 0, area = 0, red = f.rgb[0] / 255.0;
    for (int y = 0; y < size; y++)
        for (int x = 0; x < size; x++)
            if (!is_background(rgb + ((size_t)y * size + (size_t)x) * 3))
                sx += x, sy += y, area++;
    double cx = sx / area, cy = sy / area, rpx = sqrt(area / M_PI), err = 0;
    long used = 0;
    for (int y = 0; y + 1 < size; y++)
        for (int x = 0; x + 1 < size; x++) {
            double res[3]; /* measured less the true sphere's shading, here and one pixel right, down */
            const int at[3][2] = {{x, y}, {x + 1, y}, {x, y + 1}};
            int inside = 1;
            for (int k = 0; k < 3; k++) {
                double rho = hypot(at[k][0] - cx, at[k][1] - cy) / rpx;
                inside &= rho < 0.9;
                double d = sqrt(rho < 1 ? 1 - rho * rho : 0), want = red * (0.2 + 0.8 * d) + 0.25 * pow(d, 24);
                res[k] = rgb[((size_t)at[k][1] * size + (size_t)at[k][0]) * 3] - 255.0 * (want > 1 ? 1 : want);
            }
            if (inside) {
                err += fabs(res[1] - res[0]) + fabs(res[2] - res[0]);
                used++;
            }
        }
    free(rgb);
    render_close(r);
    frag_free(&f);
    vol_free(ct);
    vol_free(labels);
    assert_true(used > 1000);
    return err / (double)used;
}

/* Surfaces look smooth: a ball's surface mesh, from a CT of bone or air alone (the voxel steps at
 * their sharpest), shades as the true sphere does: its mesh taken through block means (over 2^3
 * voxels, as the window's meshes of a whole CT are) with normals from the gradient of that grid.
 * Measured (test_render, llvmpipe): 6.1 grey levels; with every second voxel point-sampled
 * instead of the means, 11.6; with the mesh's own normals (the triangles' mean) instead of the
 * gradient's, 8.1. */
static void test_surface_shading_is_smooth(void **st)
{
    (void)st;
    double err = ball_shading_error(100, 44);
    print_message("ball of radius 44 voxels: rough by %.2f grey levels\n", err);
    if (err > SMOOTH_MAX_ERR)
        fail_msg("a ball of radius 44 voxels shades %.2f grey levels rougher than the true sphere (at most %.1f)",
                 err, SMOOTH_MAX_ERR);
}

/* The HUD is sized for the window: a taller window or a higher DPI gives larger text (one font
 * pixel per 384 rows, times the DPI's scale, 1..4), and a line of render_hud_columns characters
 * fits across the picture at each size, reaching near its right edge. */
static void test_hud_scale_follows_height_and_dpi(void **st)
{
    (void)st;
    assert_int_equal(render_hud_scale_for(384, 1), 1);
    assert_true(render_hud_scale_for(768, 1) > render_hud_scale_for(384, 1));
    assert_true(render_hud_scale_for(1536, 1) > render_hud_scale_for(768, 1));
    assert_true(render_hud_scale_for(768, 2) > render_hud_scale_for(768, 1));
    assert_true(render_hud_scale_for(384, 2) > render_hud_scale_for(384, 1));
    assert_int_equal(render_hud_scale_for(4000, 2), 4);
    const int sizes[3][2] = {{512, 384}, {800, 768}, {1280, 1152}};
    int last_scale = 0;
    for (int k = 0; k < 3; k++) {
        int w = sizes[k][0], h = sizes[k][1];
        render *r = render_open("osmesa", w, h);
        assert_non_null(r);
        int scale = render_hud_scale(r), cols = render_hud_columns(r);
        assert_int_equal(scale, render_hud_scale_for(h, 1));
        assert_true(scale > last_scale);
        last_scale = scale;
        char line[1024];
        memset(line, 'M', (size_t)cols);
        line[cols] = '\0';
        uint8_t *rgb = malloc((size_t)w * (size_t)h * 3);
        render_options o;
        memset(&o, 0, sizeof o);
        o.mode = RENDER_SURFACE;
        assert_int_equal(render_frame(r, NULL, &o), 0);
        assert_int_equal(render_hud(r, line, scale), 0);
        assert_int_equal(render_read_rgb(r, rgb), 0);
        int right = -1; /* the rightmost text pixel */
        for (int y = 0; y < 12 * scale; y++)
            for (int x = 0; x < w; x++) {
                const uint8_t *p = rgb + ((size_t)y * (size_t)w + (size_t)x) * 3;
                if (p[0] > 200 && p[1] > 200 && p[2] > 200 && x > right)
                    right = x;
            }
        free(rgb);
        render_close(r);
        /* the last M's right stroke, inside the picture with the box's margin */
        if (right < w - 6 * scale - 12 || right > w - 1 - scale)
            fail_msg("%dx%d at scale %d: a line of %d columns ends at pixel %d", w, h, scale, cols, right);
    }
}

/* A PNG file as RGB (malloc'd), its size in *w, *h. */
static uint8_t *read_png(const char *path, int *w, int *h)
{
    png_image im = {.version = PNG_IMAGE_VERSION};
    if (!png_image_begin_read_from_file(&im, path))
        fail_msg("%s: cannot read it", path);
    im.format = PNG_FORMAT_RGB;
    uint8_t *rgb = malloc(PNG_IMAGE_SIZE(im));
    assert_true(png_image_finish_read(&im, NULL, rgb, 0, NULL));
    *w = (int)im.width;
    *h = (int)im.height;
    return rgb;
}

/* The mean column of the content pixels below row y0 (-1 when none). */
static double content_column(const uint8_t *rgb, int w, int h, int y0)
{
    double sum = 0;
    long n = 0;
    for (int y = y0; y < h; y++)
        for (int x = 0; x < w; x++)
            if (!is_background(rgb + ((size_t)y * (size_t)w + (size_t)x) * 3)) {
                sum += x;
                n++;
            }
    return n ? sum / (double)n : -1;
}

#define WINDOW_HUD_ROWS 200 /* the HUD covers the window's top rows: compared below them */

/* The environment of a fracnav with its window on Xvfb's display: DISPLAY is set for the children
 * alone (this process draws through OSMesa), and under AddressSanitizer leak checking is off for
 * them (glfwTerminate unloads the GL driver, whose leaks then come from an unknown module that no
 * suppression can name; leak checking stays on everywhere else). Returns the ASAN_OPTIONS to
 * restore (window_env_end). */
static char *window_env_set(int display)
{
    char d[32];
    snprintf(d, sizeof d, ":%d", display);
    setenv("DISPLAY", d, 1);
    const char *asan = getenv("ASAN_OPTIONS");
    char *asan_saved = asan ? strdup(asan) : NULL, asan_child[1024];
    snprintf(asan_child, sizeof asan_child, "%s%sdetect_leaks=0", asan ? asan : "", asan && *asan ? ":" : "");
    setenv("ASAN_OPTIONS", asan_child, 1);
    return asan_saved;
}

/* Undoes window_env_set (asan_saved: what it returned), and stops Xvfb. */
static void window_env_end(pid_t xvfb, char *asan_saved)
{
    unsetenv("DISPLAY");
    if (asan_saved)
        setenv("ASAN_OPTIONS", asan_saved, 1);
    else
        unsetenv("ASAN_OPTIONS");
    free(asan_saved);
    tu_end(xvfb, SIGTERM, "Xvfb");
}

/* Runs `fracnav CMD` (cmd, already formatted) with its window on Xvfb's display (window_env_set),
 * then stops Xvfb. */
static int run_in_window(pid_t xvfb, int display, char **out, const char *cmd)
{
    char *asan_saved = window_env_set(display);
    int rc = tu_run_cli(out, "%s", cmd);
    window_env_end(xvfb, asan_saved);
    return rc;
}

/* What a window test compares, below the HUD (which covers the top left): DIR/shot.png (the
 * window's screenshot) against DIR/after.png, `fracnav render` of the case as the run saved it
 * (made here, surface mode at the window's size, with look: more options for render, such as the
 * view and the layout), and DIR/before.png (made by the test before the run). */
typedef struct window_vs_render {
    long differ;   /* pixels where the screenshot and the render differ */
    long content;  /* pixels of the screenshot that are not background */
    long moved;    /* pixels where before and after differ */
    double c0, c1; /* the content's mean column before and after */
} window_vs_render;

static window_vs_render compare_window(const char *dir, const char *case_dir, const char *look)
{
    char *out = NULL, path[4400];
    assert_int_equal(tu_run_cli(&out, "render '%s' -o '%s/after.png' --mode surface --size 768x768 --view anterior %s",
                                case_dir, dir, look), 0);
    free(out);
    int w, h, w1, h1, w2, h2;
    snprintf(path, sizeof path, "%s/shot.png", dir);
    uint8_t *shot = read_png(path, &w, &h);
    snprintf(path, sizeof path, "%s/before.png", dir);
    uint8_t *before = read_png(path, &w1, &h1);
    snprintf(path, sizeof path, "%s/after.png", dir);
    uint8_t *after = read_png(path, &w2, &h2);
    assert_int_equal(w, 768);
    assert_int_equal(h, 768);
    assert_int_equal(w2, w);
    assert_int_equal(h2, h);
    assert_int_equal(w1, w);
    assert_int_equal(h1, h);
    window_vs_render r = {0};
    for (int i = WINDOW_HUD_ROWS * w; i < w * h; i++) {
        int dd = 0, dm = 0;
        for (int c = 0; c < 3; c++) {
            dd |= abs(shot[i * 3 + c] - after[i * 3 + c]) > 32;
            dm |= abs(before[i * 3 + c] - after[i * 3 + c]) > 32;
        }
        r.differ += dd;
        r.moved += dm;
        r.content += !is_background(shot + i * 3);
    }
    r.c0 = content_column(before, w1, h1, WINDOW_HUD_ROWS);
    r.c1 = content_column(after, w, h, WINDOW_HUD_ROWS);
    free(shot);
    free(before);
    free(after);
    return r;
}

/* navigate --view window on Xvfb with a virtual controller that pushes right: the window opens,
 * the fragment moves right on screen (the camera frame follows the view), and the window's
 * screenshot matches `fracnav render` of the saved case (OSMesa) below the HUD. */
static void test_navigate_window_matches_render(void **st)
{
    (void)st;
#if defined(__SANITIZE_THREAD__)
    /* Xlib, GLX and Mesa's DRI driver lock with their own uninstrumented conventions, which
     * ThreadSanitizer misreads (lock-order inversions inside libX11, unlocks in libXi); the window
     * code is single-threaded, and the loop's threads are checked by the terminal view's tests. */
    print_message("skipped under ThreadSanitizer: Xlib's and GLX's own locking\n");
    skip();
#endif
    int display;
    pid_t xvfb = start_xvfb(&display);
    if (!xvfb)
        no_xvfb();
    char *dir = tu_tmpdir("navwin"), case_dir[4200], path[4400];
    tu_two_blocks_case(dir, case_dir, sizeof case_dir);
    snprintf(path, sizeof path, "%s/right.script", dir);
    const char *script = "wait 100 ms\ntranslate +x 6 mm over 0.6 s\n";
    tu_write_file(path, script, strlen(script));
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "render '%s' -o '%s/before.png' --mode surface --size 768x768 --view anterior",
                                case_dir, dir), 0);
    free(out);
    char cmd[9000];
    snprintf(cmd, sizeof cmd, "navigate '%s' --device virtual:spacenavigator:script='%s' --view window --camera anterior "
                              "--duration 3 --discard-journal --preview off --screenshot '%s/shot.png' </dev/null",
             case_dir, path, dir);
    int rc = run_in_window(xvfb, display, &out, cmd);
    if (rc != 0 || strstr(out, "no window"))
        fail_msg("navigate --view window: exit %d: %s", rc, out);
    free(out);
    window_vs_render r = compare_window(dir, case_dir, "");
    if (r.content < 1000)
        fail_msg("the window's screenshot shows no fragments (%ld content pixels)", r.content);
    if (r.differ > 768L * (768 - WINDOW_HUD_ROWS) / 100)
        fail_msg("the window's screenshot differs from the OSMesa render in %ld pixels", r.differ);
    if (!(r.c1 > r.c0 + 3))
        fail_msg("pushing right moved the picture from column %.1f to %.1f", r.c0, r.c1);
    tu_rmtree(dir);
    free(dir);
}

/* Whether an overlay shows in the window: DIR/plain.png is rendered with look_without (the
 * look of DIR/after.png, made by compare_window, without the overlay); of the pixels below the
 * HUD where the two renders differ (the overlay's own, *drawn), returns how many the screenshot
 * shows as after.png does rather than as plain.png. The overlay covers under 1% of the picture,
 * which compare_window's tolerance alone would let pass unseen. */
static long overlay_shown(const char *dir, const char *case_dir, const char *look_without, long *drawn)
{
    char *out = NULL, path[4400];
    assert_int_equal(tu_run_cli(&out, "render '%s' -o '%s/plain.png' --mode surface --size 768x768 --view anterior %s",
                                case_dir, dir, look_without), 0);
    free(out);
    int w[3], h[3];
    const char *name[3] = {"shot", "after", "plain"};
    uint8_t *img[3];
    for (int k = 0; k < 3; k++) {
        snprintf(path, sizeof path, "%s/%s.png", dir, name[k]);
        img[k] = read_png(path, &w[k], &h[k]);
        assert_int_equal(w[k], w[0]);
        assert_int_equal(h[k], h[0]);
    }
    long shown = 0;
    *drawn = 0;
    for (int i = WINDOW_HUD_ROWS * w[0]; i < w[0] * h[0]; i++) {
        int to_after = 0, to_plain = 0, differ = 0;
        for (int c = 0; c < 3; c++) {
            differ |= abs(img[1][i * 3 + c] - img[2][i * 3 + c]) > 32;
            to_after += abs(img[0][i * 3 + c] - img[1][i * 3 + c]);
            to_plain += abs(img[0][i * 3 + c] - img[2][i * 3 + c]);
        }
        *drawn += differ;
        shown += differ && to_after < to_plain;
    }
    for (int k = 0; k < 3; k++)
        free(img[k]);
    return shown;
}

/* Without xdotool: a visible skip, or a failure under CI (where .ci/setup installs it). */
static void no_xdotool(void)
{
    if (getenv("CI"))
        fail_msg("xdotool is not installed (/usr/bin/xdotool; package xdotool, in .ci/setup)");
    print_message("skipped: xdotool is not installed (package xdotool)\n");
    skip();
}

/* Xvfb for a test that drives navigate's window with xdotool (its display in *display). Skips,
 * saying why, under ThreadSanitizer (Xlib's and GLX's own locking), or where xdotool or Xvfb is
 * missing (a failure under CI). */
static pid_t xdotool_xvfb(int *display)
{
#if defined(__SANITIZE_THREAD__)
    print_message("skipped under ThreadSanitizer: Xlib's and GLX's own locking\n");
    skip();
#endif
    if (access("/usr/bin/xdotool", X_OK) != 0)
        no_xdotool();
    pid_t xvfb = start_xvfb(display);
    if (!xvfb)
        no_xvfb();
    return xvfb;
}

/* The pointer and the window's keys drive navigate's window (xdotool on Xvfb, through XTEST as a
 * hand would): a left drag of 180 pixels to the right orbits the view by 90 degrees, from the
 * anterior view to the right one, F3 gives the four-up layout (its slices through the selected
 * fragment's centroid), F4 the principal axes, and q quits. The screenshot must match `fracnav
 * render --view right --layout four-up --overlay axes` at that point, and differ from the
 * anterior view. The events arrive in order, so q comes after the drag and the keys. */
static void test_navigate_window_mouse_and_keys(void **st)
{
    (void)st;
    int display;
    pid_t xvfb = xdotool_xvfb(&display);
    char *dir = tu_tmpdir("navmouse"), case_dir[4200];
    tu_two_blocks_case(dir, case_dir, sizeof case_dir);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "render '%s' -o '%s/before.png' --mode surface --size 768x768 --view anterior "
                                      "--layout four-up --overlay axes --point 22.5,15.5,15.5",
                                case_dir, dir), 0);
    free(out);
    /* navigate in the background; xdotool waits for its window (at most 300 s: a navigate that
     * never opens one is killed), drags, types, and the shell waits for navigate to end. */
    char cmd[9000];
    snprintf(cmd, sizeof cmd,
             "navigate '%s' --device virtual:spacenavigator --view window --camera anterior --discard-journal "
             "--preview off --screenshot "
             "'%s/shot.png' </dev/null & nav=$!; "
             "if timeout 300 xdotool search --sync --onlyvisible --name '^fracnav$' >/dev/null; then "
             "xdotool mousemove 384 560 mousedown 1 mousemove_relative -- 180 0 mouseup 1 key F3 key F4 key q; "
             "else echo 'no fracnav window appeared'; kill $nav; fi; wait $nav",
             case_dir, dir);
    int rc = run_in_window(xvfb, display, &out, cmd);
    if (rc != 0 || strstr(out, "no window") || strstr(out, "no fracnav window"))
        fail_msg("navigate --view window driven by xdotool: exit %d: %s", rc, out);
    free(out);
    window_vs_render r = compare_window(dir, case_dir, "--view right --layout four-up --overlay axes "
                                                      "--point 22.5,15.5,15.5");
    if (r.content < 1000)
        fail_msg("the window's screenshot shows no fragments (%ld content pixels)", r.content);
    if (r.differ > 768L * (768 - WINDOW_HUD_ROWS) / 100)
        fail_msg("after the drag and F3, the window differs from render --view right --layout four-up in %ld "
                 "pixels", r.differ);
    if (r.moved < 1000)
        fail_msg("the right view differs from the anterior one in only %ld pixels", r.moved);
    long drawn, shown = overlay_shown(dir, case_dir, "--view right --layout four-up --point 22.5,15.5,15.5", &drawn);
    if (drawn < 50 || shown < drawn * 9 / 10)
        fail_msg("after F4, the window shows %ld of the axes' %ld pixels", shown, drawn);
    tu_rmtree(dir);
    free(dir);
}

/* The pixel of the axial pane of a 768x768 four-up window (anterior camera, slices through
 * `through`) that shows the world point nearest to `at`, into px. */
static void axial_pixel(const planning_case *c, const double through[3], const double at[3], int px[2])
{
    render *r = render_open("osmesa", 768, 768);
    assert_non_null(r);
    render_options o;
    render_options_default(&o, c->frag, c->nfrag);
    render_camera_standard(&o.camera, RENDER_ANTERIOR, c->frag, c->nfrag);
    o.layout = RENDER_LAYOUT_FOUR_UP;
    memcpy(o.slice_point, through, sizeof o.slice_point);
    int rect[4][4];
    render_four_up_panes(768, 768, 0, rect);
    const int *q = rect[RENDER_PANE_AXIAL];
    double best = 1e30, p[3];
    for (int y = q[1]; y < q[1] + q[3]; y++)
        for (int x = q[0]; x < q[0] + q[2]; x++) {
            assert_int_equal(render_slice_point_at(r, &o, x + 0.5, y + 0.5, p), RENDER_PANE_AXIAL);
            double d = hypot(p[0] - at[0], p[1] - at[1]);
            if (d < best)
                best = d, px[0] = x, px[1] = y;
        }
    render_close(r);
    assert_true(best < 1.0);
}

/* The world point (LPS mm) that pixel (x, y) of a 768x768 four-up window of case c (anterior
 * camera, slices through `through`) shows in a slice pane, into world; returns the pane. */
static int four_up_world(const planning_case *c, const double through[3], double x, double y, double world[3])
{
    render *r = render_open("osmesa", 768, 768);
    assert_non_null(r);
    render_options o;
    render_options_default(&o, c->frag, c->nfrag);
    render_camera_standard(&o.camera, RENDER_ANTERIOR, c->frag, c->nfrag);
    o.layout = RENDER_LAYOUT_FOUR_UP;
    memcpy(o.slice_point, through, sizeof o.slice_point);
    int pane = render_slice_point_at(r, &o, x, y, world);
    render_close(r);
    return pane;
}

/* A four-up navigate window (tu_two_blocks_case; edit: an edit of the case first, or NULL) on
 * Xvfb driven by xdotool (actions; then, when wait_for is not NULL, a wait for a line of
 * navigate's view holding it, the actions' effect on the session; then q): its screenshot must match `fracnav render` with look
 * (surface, 768x768), and of the pixels where that render differs from one with look_before (the
 * picture before the actions), show 90% or more as look's. */
static void four_up_window(const char *name, const char *edit, const char *nav, const char *actions,
                           const char *wait_for, const char *look, const char *look_before)
{
    int display;
    pid_t xvfb = xdotool_xvfb(&display);
    char *dir = tu_tmpdir(name), case_dir[4200], *out = NULL;
    tu_two_blocks_case(dir, case_dir, sizeof case_dir);
    if (edit)
        assert_int_equal(tu_run_cli(NULL, "edit '%s' %s", case_dir, edit), 0);
    assert_int_equal(tu_run_cli(&out, "render '%s' -o '%s/before.png' --mode surface --size 768x768 %s", case_dir,
                                dir, look_before), 0);
    free(out);
    char cmd[9000], wait[512] = "";
    if (wait_for) /* tail ends with navigate, or at its next line (one a second) after grep's match */
        snprintf(wait, sizeof wait, "tail -n +1 -f --pid=$nav '%s/view.txt' | grep -q -m1 '%s'; ", dir, wait_for);
    snprintf(cmd, sizeof cmd,
             "navigate '%s' --device virtual:spacenavigator --view window --layout four-up %s --discard-journal "
             "--preview off --screenshot '%s/shot.png' </dev/null 2>'%s/view.txt' & nav=$!; "
             "if timeout 300 xdotool search --sync --onlyvisible --name '^fracnav$' >/dev/null; then "
             "xdotool %s; %s xdotool key q; else echo 'no fracnav window appeared'; kill $nav; fi; wait $nav; "
             "rc=$?; cat '%s/view.txt'; exit $rc",
             case_dir, nav, dir, dir, actions, wait, dir);
    int rc = run_in_window(xvfb, display, &out, cmd);
    if (rc != 0 || strstr(out, "no window") || strstr(out, "no fracnav window"))
        fail_msg("navigate --view window driven by xdotool: exit %d: %s", rc, out);
    free(out);
    window_vs_render r = compare_window(dir, case_dir, look);
    if (r.content < 1000 || r.differ > 768L * (768 - WINDOW_HUD_ROWS) / 100)
        fail_msg("after '%s' the window differs from render %s in %ld pixels (%ld content)", actions, look,
                 r.differ, r.content);
    long drawn, shown = overlay_shown(dir, case_dir, look_before, &drawn);
    if (drawn < 50 || shown < drawn * 9 / 10)
        fail_msg("after '%s' the window shows %ld of the %ld pixels where render %s differs from %s", actions,
                 shown, drawn, look, look_before);
    tu_rmtree(dir);
    free(dir);
}

/* In four-up, the wheel over the axial slice moves it along z, a millimetre a step: seven steps
 * up from block B's centroid (z 15.5) put the slice at z 22.5, above B (z 10..21), and the window
 * shows render --point 22.5,15.5,22.5. */
static void test_navigate_window_wheel_scrolls_a_slice(void **st)
{
    (void)st;
    int rect[4][4];
    render_four_up_panes(768, 768, 0, rect);
    const int *q = rect[RENDER_PANE_AXIAL];
    char actions[256];
    snprintf(actions, sizeof actions, "mousemove %d %d click --repeat 7 --delay 50 4", q[0] + q[2] / 2,
             q[1] + q[3] / 2);
    four_up_window("navwheel", NULL, "--camera anterior", actions, NULL,
                   "--view anterior --layout four-up --point 22.5,15.5,22.5",
                   "--view anterior --layout four-up --point 22.5,15.5,15.5");
}

/* In four-up, a click on the axial slice over block A (x 4..15; B, at x 18..27, is selected)
 * moves the slices' point there: the sagittal slice then cuts through A, and the window shows
 * render --point at the clicked point. */
static void test_navigate_window_click_moves_the_crosshair(void **st)
{
    (void)st;
    const double b[3] = {22.5, 15.5, 15.5}; /* B's centroid: where the slices cut at first */
    char *dir = tu_tmpdir("navclick0"), case_dir[4200];
    tu_two_blocks_case(dir, case_dir, sizeof case_dir);
    planning_case *c = case_load(case_dir);
    assert_non_null(c);
    const double a_mid[3] = {9.5, 15.5, 15.5};
    int px[2];
    double at[3];
    axial_pixel(c, b, a_mid, px);
    assert_int_equal(four_up_world(c, b, px[0], px[1], at), RENDER_PANE_AXIAL);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
    char actions[256], look[256];
    snprintf(actions, sizeof actions, "mousemove %d %d click 1", px[0], px[1]);
    snprintf(look, sizeof look, "--view anterior --layout four-up --point %.6f,%.6f,%.6f", at[0], at[1], at[2]);
    four_up_window("navclick", NULL, "--camera anterior", actions, NULL, look,
                   "--view anterior --layout four-up --point 22.5,15.5,15.5");
}

/* In four-up, a left drag of the border between the 3D view and the slices (row 511 of 768: the
 * 3D view over two thirds) 128 pixels up resizes them: the 3D view takes half the height, as
 * render --split 0.5 draws it, and the view is not orbited. */
static void test_navigate_window_drags_the_four_up_border(void **st)
{
    (void)st;
    int rect[4][4];
    render_four_up_panes(768, 768, 0, rect);
    assert_int_equal(rect[RENDER_PANE_3D][3], 511);
    render_four_up_panes(768, 768, 0.5, rect);
    assert_int_equal(rect[RENDER_PANE_AXIAL][3], 384);
    four_up_window("navsplit", NULL, "--camera anterior", "mousemove 384 511 mousedown 1 mousemove_relative -- 0 -128 "
                   "mouseup 1", NULL, "--view anterior --layout four-up --split 0.5 --point 22.5,15.5,15.5",
                   "--view anterior --layout four-up --point 22.5,15.5,15.5");
}

/* With no fragment fixed, A (id 1) is selected first; n selects B (id 2): the auto camera frames
 * B (with what hides it cut away) and the slices move to B's centroid, as render --view auto
 * --fragment 2 --point 22.5,15.5,15.5 shows. */
static void test_navigate_window_follows_the_selection(void **st)
{
    (void)st;
    four_up_window("navselect", "fix 0", "--camera auto", "key n", "next: frag 2/2",
                   "--view auto --fragment 2 --layout four-up --point 22.5,15.5,15.5",
                   "--view auto --fragment 1 --layout four-up --point 9.5,15.5,15.5");
}

/* A navigate run in seed mode on Xvfb (xdotool), over tu_two_blocks_case: block B (fragment 2)
 * is what the seeds split. */
typedef struct seed_run {
    pid_t xvfb, nav;
    char *asan_saved, *dir;
    char case_dir[4200], shot[4300], out[4300];
    FILE *err;
    char seen[16384];
    long before; /* block B's voxels */
    int p1[2], p2[2]; /* the axial pixels of the seeds: 3 mm left and right of B's centroid */
} seed_run;

/* Starts Xvfb and navigate (four-up, anterior camera, its screenshot at the end to s->shot), block
 * B saved moved by b_moved mm along x first. Skips the test where there is no xdotool or Xvfb. */
static void seed_run_start(seed_run *s, const char *name, double b_moved)
{
    int display;
    s->xvfb = xdotool_xvfb(&display);
    s->dir = tu_tmpdir(name);
    s->seen[0] = '\0';
    tu_two_blocks_case(s->dir, s->case_dir, sizeof s->case_dir);
    planning_case *c = case_load(s->case_dir);
    assert_non_null(c);
    assert_int_equal(c->nfrag, 2);
    const double *b = c->frag[case_find(c, 2)].centroid;
    double left[3] = {b[0] - 3, b[1], b[2]}, right[3] = {b[0] + 3, b[1], b[2]};
    axial_pixel(c, b, left, s->p1);
    axial_pixel(c, b, right, s->p2);
    s->before = 0;
    for (size_t i = 0; i < vol_count(c->labels); i++)
        s->before += c->labels->data[i] == 2;
    c->frag[case_find(c, 2)].pose.t[0] = b_moved;
    assert_int_equal(case_save(c), 0);
    case_free(c);
    snprintf(s->shot, sizeof s->shot, "%s/shot.png", s->dir);
    snprintf(s->out, sizeof s->out, "%s/out.json", s->dir);
    s->asan_saved = window_env_set(display);
    /* navigate logs a line a second, so a wait for a line that never comes ends only with it:
     * --duration bounds each of its runs */
    char duration[32];
    snprintf(duration, sizeof duration, "%d", 10 * TU_WAIT_MAX_S);
    s->nav = tu_spawn_cli(s->out, &s->err, (char *[]){"navigate", s->case_dir, "--device", "virtual:spacenavigator",
                                                      "--view", "window", "--camera", "anterior", "--layout",
                                                      "four-up", "--discard-journal", "--screenshot", s->shot,
                                                      "--duration", duration, NULL});
}

/* Waits for a line of the view holding what (fails with the last lines seen, saying why). */
static void seed_run_wait(seed_run *s, const char *what, const char *why)
{
    if (!tu_wait_line(s->err, what, s->seen, sizeof s->seen))
        fail_msg("%s: %s", why, s->seen + (strlen(s->seen) > 2000 ? strlen(s->seen) - 2000 : 0));
}

/* F10, 1, a click on the axial slice in block B's left part, 2, a click in its right part: each
 * step waits for the view's line that shows it was taken (off a terminal, navigate logs a line at
 * each change), as a click and a key that arrive in one frame are not kept in order. */
static void seed_run_two_seeds(seed_run *s)
{
    char cmd[1024];
    snprintf(cmd, sizeof cmd, "timeout 300 xdotool search --sync --onlyvisible --name '^fracnav$' >/dev/null && "
             "xdotool key F10 key 1 mousemove %d %d click 1", s->p1[0], s->p1[1]);
    assert_int_equal(system(cmd), 0);
    seed_run_wait(s, "1 seed 1@", "no seed after F10, 1 and a click");
    assert_int_equal(system("xdotool key 2"), 0);
    /* the status's prefix, not "chosen": the first seed's preview may end in the same frame and
     * say its own word after it (seen under load) */
    seed_run_wait(s, "seed mode, piece 2:", "piece 2 not chosen");
    snprintf(cmd, sizeof cmd, "xdotool mousemove %d %d click 1", s->p2[0], s->p2[1]);
    assert_int_equal(system(cmd), 0);
    seed_run_wait(s, " 2@", "no second seed");
}

/* q in the (new) window: navigate ends and exits 0; Xvfb stops. */
static void seed_run_quit(seed_run *s)
{
    assert_int_equal(system("timeout 300 xdotool search --sync --onlyvisible --name '^fracnav$' >/dev/null && "
                            "xdotool key q"), 0);
    assert_int_equal(tu_end(s->nav, 0, "navigate"), 0);
    fclose(s->err);
    window_env_end(s->xvfb, s->asan_saved);
}

static void seed_run_free(seed_run *s)
{
    tu_rmtree(s->dir);
    free(s->dir);
}

/* Block B's voxels split between fragments 2 and 3 of the case at dir, each with a third or more. */
static void assert_b_split(const char *case_dir, long before)
{
    planning_case *c = case_load(case_dir);
    assert_non_null(c);
    assert_int_equal(c->nfrag, 3);
    long pieces[2] = {0, 0};
    for (size_t i = 0; i < vol_count(c->labels); i++)
        if (c->labels->data[i] == 2 || c->labels->data[i] == 3)
            pieces[c->labels->data[i] == 3]++;
    if (pieces[0] + pieces[1] != before || pieces[0] < before / 3 || pieces[1] < before / 3)
        fail_msg("block B (%ld voxels) split into %ld and %ld", before, pieces[0], pieces[1]);
    case_free(c);
}

/* Issue 25: the window's seed mode (xdotool on Xvfb). Two seeds of two pieces in block B, and
 * Enter separate B: navigate saves the case with B in two fragments, opens it again, and q ends
 * it. The case then holds three fragments, B's voxels split between its id and the new one. */
static void test_navigate_window_seed_mode_separates(void **st)
{
    (void)st;
    seed_run s;
    seed_run_start(&s, "navseed", 0);
    seed_run_two_seeds(&s);
    assert_int_equal(system("xdotool key Return"), 0);
    seed_run_wait(&s, "new fragment", "no separation after Enter");
    if (!strstr(s.seen, "separated: 1 new fragment, 3 in all"))
        fail_msg("not one new fragment: %s", s.seen + (strlen(s.seen) > 2000 ? strlen(s.seen) - 2000 : 0));
    /* the separated case opens in a new window (the old one is gone before the line above) */
    seed_run_quit(&s);
    assert_b_split(s.case_dir, s.before);
    seed_run_free(&s);
}

/* Two clicks in one frame (a quick hand on a slow frame) are two seeds, each at its own point:
 * both were given the last click's point. navigate is stopped (SIGSTOP) while xdotool queues F10,
 * 1, a click, 2 and another click, so that the window reads them all in its next frame. */
static void test_navigate_window_two_clicks_in_one_frame(void **st)
{
    (void)st;
    seed_run s;
    seed_run_start(&s, "navclicks", 0);
    assert_int_equal(system("timeout 300 xdotool search --sync --onlyvisible --name '^fracnav$' >/dev/null"), 0);
    seed_run_wait(&s, "frag ", "no view line from navigate");
    char cmd[1024];
    snprintf(cmd, sizeof cmd, "xdotool key F10 key 1 mousemove %d %d click 1 key 2 mousemove %d %d click 1",
             s.p1[0], s.p1[1], s.p2[0], s.p2[1]);
    assert_int_equal(kill(s.nav, SIGSTOP), 0);
    int rc = system(cmd);
    assert_int_equal(kill(s.nav, SIGCONT), 0);
    assert_int_equal(rc, 0);
    seed_run_wait(&s, " 2@(", "no second seed");
    const char *a = strstr(s.seen, " 1@("), *b = strstr(s.seen, " 2@(");
    assert_non_null(a);
    double p1[3], p2[3];
    assert_int_equal(sscanf(a, " 1@(%lf,%lf,%lf)", &p1[0], &p1[1], &p1[2]), 3);
    assert_int_equal(sscanf(b, " 2@(%lf,%lf,%lf)", &p2[0], &p2[1], &p2[2]), 3);
    if (!(fabs((p2[0] - p1[0]) - 6) <= 1.5 && fabs(p2[1] - p1[1]) <= 1.5 && fabs(p2[2] - p1[2]) <= 1.5))
        fail_msg("the seeds of two clicks 6 mm apart, read in one frame: (%g, %g, %g) and (%g, %g, %g)", p1[0], p1[1],
                 p1[2], p2[0], p2[1], p2[2]);
    seed_run_quit(&s);
    seed_run_free(&s);
}

/* Issue 25: the separation is an edit that undo takes back. After Enter separated block B, u (the
 * steering's undo) in the reopened window, with no move to undo, takes the separation back: the
 * case opens again with B whole, as fragment 2. */
static void test_navigate_window_seed_mode_undoes(void **st)
{
    (void)st;
    seed_run s;
    seed_run_start(&s, "navundo", 0);
    seed_run_two_seeds(&s);
    assert_int_equal(system("xdotool key Return"), 0);
    seed_run_wait(&s, "separated: 1 new fragment, 3 in all", "no separation after Enter");
    assert_int_equal(system("timeout 300 xdotool search --sync --onlyvisible --name '^fracnav$' >/dev/null && "
                            "xdotool key u"), 0);
    seed_run_wait(&s, "undo: the separation taken back, 2 fragments", "no undo of the separation after u");
    seed_run_quit(&s);
    planning_case *c = case_load(s.case_dir);
    assert_non_null(c);
    assert_int_equal(c->nfrag, 2);
    long b = 0;
    for (size_t i = 0; i < vol_count(c->labels); i++)
        b += c->labels->data[i] == 2;
    assert_int_equal(b, s.before);
    case_free(c);
    seed_run_free(&s);
}

/* Issue 25: a click on a fragment in the 3D view drops a seed too. In seed mode, a click on block
 * B's middle in the four-up's 3D pane (anterior view) drops seed 1 on B's front face: at B's
 * centroid across the view, 4-7 mm in front of it along the view (B is 12 mm deep). */
static void test_navigate_window_seed_mode_3d_click(void **st)
{
    (void)st;
    seed_run s;
    seed_run_start(&s, "nav3d", 0);
    planning_case *c = case_load(s.case_dir);
    assert_non_null(c);
    double b[3], right[3], d[3];
    memcpy(b, c->frag[case_find(c, 2)].centroid, sizeof b);
    render_camera cam;
    render_camera_standard(&cam, RENDER_ANTERIOR, c->frag, c->nfrag);
    case_free(c);
    int rect[4][4];
    render_four_up_panes(768, 768, 0, rect);
    const int *q = rect[RENDER_PANE_3D];
    for (int a = 0; a < 3; a++) {
        right[a] = cam.forward[(a + 1) % 3] * cam.up[(a + 2) % 3] - cam.forward[(a + 2) % 3] * cam.up[(a + 1) % 3];
        d[a] = b[a] - cam.centre[a];
    }
    double sx = (d[0] * right[0] + d[1] * right[1] + d[2] * right[2]) / (cam.half_height * q[2] / q[3]);
    double sy = (d[0] * cam.up[0] + d[1] * cam.up[1] + d[2] * cam.up[2]) / cam.half_height;
    char cmd[1024];
    snprintf(cmd, sizeof cmd, "timeout 300 xdotool search --sync --onlyvisible --name '^fracnav$' >/dev/null && "
             "xdotool key F10 mousemove %d %d click 1", (int)(q[0] + (sx + 1) / 2 * q[2]),
             (int)(q[1] + (1 - sy) / 2 * q[3]));
    assert_int_equal(system(cmd), 0);
    seed_run_wait(&s, "1 seed 1@(", "no seed after F10 and a click on block B in the 3D view");
    double at[3];
    if (sscanf(strstr(s.seen, "1 seed 1@(") + strlen("1 seed 1@("), "%lf,%lf,%lf", &at[0], &at[1], &at[2]) != 3)
        fail_msg("no seed point in: %s", s.seen);
    double across = 0, along = 0;
    for (int a = 0; a < 3; a++) {
        double e = at[a] - b[a], f = e * cam.forward[a];
        along += f;
        across += (e - f * cam.forward[a]) * (e - f * cam.forward[a]);
    }
    if (sqrt(across) > 1.5 || along > -4 || along < -7)
        fail_msg("the seed (%.0f, %.0f, %.0f) is not on B's front face (centroid %.1f, %.1f, %.1f)", at[0], at[1],
                 at[2], b[0], b[1], b[2]);
    seed_run_quit(&s);
    seed_run_free(&s);
}

/* Issue 25: a seed goes where the clicked voxel lies in the CT, whatever its fragment's pose.
 * With block B saved 5 mm along x from where it was segmented, a click on its middle in the axial
 * slice (which shows it moved) drops the seed at B's centroid in the CT, not 5 mm beside it. */
static void test_navigate_window_seed_on_a_moved_fragment(void **st)
{
    (void)st;
    seed_run s;
    seed_run_start(&s, "navmoved", 5);
    planning_case *c = case_load(s.case_dir);
    assert_non_null(c);
    double b[3], moved[3];
    memcpy(b, c->frag[case_find(c, 2)].centroid, sizeof b);
    memcpy(moved, b, sizeof b);
    moved[0] += 5;
    int px[2];
    axial_pixel(c, moved, moved, px);
    case_free(c);
    char cmd[1024];
    snprintf(cmd, sizeof cmd, "timeout 300 xdotool search --sync --onlyvisible --name '^fracnav$' >/dev/null && "
             "xdotool key F10 mousemove %d %d click 1", px[0], px[1]);
    assert_int_equal(system(cmd), 0);
    seed_run_wait(&s, "1 seed 1@(", "no seed after F10 and a click on moved block B's middle");
    double at[3];
    if (sscanf(strstr(s.seen, "1 seed 1@(") + strlen("1 seed 1@("), "%lf,%lf,%lf", &at[0], &at[1], &at[2]) != 3)
        fail_msg("no seed point in: %s", s.seen);
    if (fabs(at[0] - b[0]) > 1 || fabs(at[1] - b[1]) > 1 || fabs(at[2] - b[2]) > 1)
        fail_msg("the seed (%.0f, %.0f, %.0f) is not at B's centroid in the CT (%.1f, %.1f, %.1f)", at[0], at[1],
                 at[2], b[0], b[1], b[2]);
    seed_run_quit(&s);
    seed_run_free(&s);
}

/* The pixels of the axial pane of a 768x768 four-up screenshot within 2 of colour rgb. */
static long axial_pixels_of(const uint8_t *shot, const uint8_t rgb[3])
{
    int rect[4][4];
    render_four_up_panes(768, 768, 0, rect);
    const int *q = rect[RENDER_PANE_AXIAL];
    long n = 0;
    for (int y = q[1]; y < q[1] + q[3]; y++)
        for (int x = q[0]; x < q[0] + q[2]; x++) {
            const uint8_t *p = shot + ((size_t)y * 768 + (size_t)x) * 3;
            n += abs(p[0] - rgb[0]) <= 2 && abs(p[1] - rgb[1]) <= 2 && abs(p[2] - rgb[2]) <= 2;
        }
    return n;
}

/* Issue 25: the split is previewed in colour before Enter. After two seeds of two pieces in block
 * B the view says the preview makes 3 fragments, and the axial pane (the screenshot at q, before
 * any Enter) outlines both would-be pieces, each in its own colour: fragment 2's and that of the
 * new fragment 3, which the case does not hold. Quitting leaves the case unseparated. */
static void test_navigate_window_seed_mode_previews(void **st)
{
    (void)st;
    seed_run s;
    seed_run_start(&s, "navpreview", 0);
    seed_run_two_seeds(&s);
    seed_run_wait(&s, "preview: 3 fragments", "no preview of the split after two seeds");
    seed_run_quit(&s);
    int w, h;
    uint8_t *shot = read_png(s.shot, &w, &h), two[3], three[3];
    assert_int_equal(w, 768);
    assert_int_equal(h, 768);
    frag_colour(2, two);
    frag_colour(3, three);
    long n2 = axial_pixels_of(shot, two), n3 = axial_pixels_of(shot, three);
    free(shot);
    if (n2 < 50 || n3 < 50)
        fail_msg("the axial pane shows %ld pixels in fragment 2's colour and %ld in the new piece's", n2, n3);
    planning_case *c = case_load(s.case_dir);
    assert_non_null(c);
    assert_int_equal(c->nfrag, 2);
    case_free(c);
    seed_run_free(&s);
}

/* The issue: with --device keyboard the steering keys typed into the window did nothing, and the
 * window took letters a keyboard user steers with (l its layout, a its axes). Typed in the window
 * (xdotool), d pushes the selected fragment right on screen as it does in the terminal (the camera
 * frame follows the anterior view), and q quits and saves: the screenshot matches `fracnav render`
 * of the saved case, in the 3D layout (--preview off: render draws no ghost). l and a come first,
 * with x (stop all motion) between them: a key holds its axis until 150 ms after the last key
 * typed, so on a loaded machine, where the keys reach the window bunched, an a typed after the d's
 * had the last word on the x axis, and l's turn ran beside them (0.28 mm right and 0.26 degrees,
 * the picture 1.5 pixels left, beside two busy loops). Typed before them, the last word is d's;
 * bunched, the d's give one hold, 0.28 mm and 1.7 pixels right (beside a busy loop and ASan), not
 * twenty: the picture must move right by more than a pixel. */
static void test_navigate_window_keyboard_steers(void **st)
{
    (void)st;
    int display;
    pid_t xvfb = xdotool_xvfb(&display);
    char *dir = tu_tmpdir("navkeys"), case_dir[4200];
    tu_two_blocks_case(dir, case_dir, sizeof case_dir);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "render '%s' -o '%s/before.png' --mode surface --size 768x768 --view anterior", case_dir,
                                dir), 0);
    free(out);
    char cmd[9000];
    snprintf(cmd, sizeof cmd,
             "navigate '%s' --device keyboard:/dev/null --view window --camera anterior --discard-journal "
             "--preview off --screenshot "
             "'%s/shot.png' </dev/null & nav=$!; "
             "if timeout 300 xdotool search --sync --onlyvisible --name '^fracnav$' >/dev/null; then "
             "xdotool key --delay 40 l x a d d d d d d d d d d d d d d d d d d d d q; "
             "else echo 'no fracnav window appeared'; kill $nav; fi; wait $nav",
             case_dir, dir);
    int rc = run_in_window(xvfb, display, &out, cmd);
    if (rc != 0 || strstr(out, "no window") || strstr(out, "no fracnav window"))
        fail_msg("navigate --device keyboard --view window driven by xdotool: exit %d: %s", rc, out);
    free(out);
    window_vs_render r = compare_window(dir, case_dir, "");
    if (r.content < 1000)
        fail_msg("the window's screenshot shows no fragments (%ld content pixels)", r.content);
    if (r.differ > 768L * (768 - WINDOW_HUD_ROWS) / 100)
        fail_msg("after d typed in the window, it differs from the OSMesa render in %ld pixels (l or a "
                 "changed its look?)", r.differ);
    if (!(r.c1 > r.c0 + 1))
        fail_msg("d typed in the window moved the picture from column %.1f to %.1f", r.c0, r.c1);
    tu_rmtree(dir);
    free(dir);
}

/* The "pose_digest" of a replay's JSON in out ("" when there is none). */
static void pose_digest(const char *out, char digest[64])
{
    const char *p = strstr(out, "\"pose_digest\"");
    if (!p || sscanf(p, "\"pose_digest\": \"%63[0-9a-f]\"", digest) != 1)
        digest[0] = 0;
}

/* replay --realtime --view window on Xvfb: the window shows the replay, its screenshot at the end
 * matches `fracnav render` of the saved result (OSMesa) below the HUD, and the window changes
 * nothing: the pose digest is the headless replay's. */
static void test_replay_window_matches_render(void **st)
{
    (void)st;
#if defined(__SANITIZE_THREAD__)
    /* As test_navigate_window_matches_render: Xlib's and GLX's own locking. */
    print_message("skipped under ThreadSanitizer: Xlib's and GLX's own locking\n");
    skip();
#endif
    int display;
    pid_t xvfb = start_xvfb(&display);
    if (!xvfb)
        no_xvfb();
    char *dir = tu_tmpdir("replaywin"), case_dir[4200], rec[4200];
    char headless[64], live[64];
    tu_two_blocks_case(dir, case_dir, sizeof case_dir);
    snprintf(rec, sizeof rec, "%s/sim/recordings/head-on.fnrec", tu_src());
    char *out = NULL;
    unsetenv("DISPLAY");
    int rc = tu_run_cli(&out, "replay '%s' '%s' --json --no-journal", case_dir, rec);
    if (rc != 0)
        fail_msg("replay: exit %d: %s", rc, out);
    pose_digest(out, headless);
    free(out);
    assert_int_not_equal(headless[0], 0);
    assert_int_equal(tu_run_cli(&out, "render '%s' -o '%s/before.png' --mode surface --size 768x768 --view anterior",
                                case_dir, dir), 0);
    free(out);
    char cmd[9000];
    snprintf(cmd, sizeof cmd, "replay '%s' '%s' --realtime --view window --camera anterior --screenshot '%s/shot.png' --json --save "
                              "--no-journal </dev/null", case_dir, rec, dir);
    rc = run_in_window(xvfb, display, &out, cmd);
    if (rc != 0 || strstr(out, "no window"))
        fail_msg("replay --realtime --view window: exit %d: %s", rc, out);
    pose_digest(out, live);
    if (strcmp(live, headless))
        fail_msg("the pose digest with the window is '%s', headless '%s': %s", live, headless, out);
    free(out);
    window_vs_render r = compare_window(dir, case_dir, "");
    if (r.content < 1000)
        fail_msg("the window's screenshot shows no fragments (%ld content pixels)", r.content);
    if (r.moved < 500)
        fail_msg("the recording moved the fragment by only %ld pixels in the render", r.moved);
    if (r.differ > 768L * (768 - WINDOW_HUD_ROWS) / 100)
        fail_msg("the window's screenshot differs from the OSMesa render of the result in %ld pixels", r.differ);
    tu_rmtree(dir);
    free(dir);
}

/* replay --frames: one picture per --frame-ms of the recording's time, the fragment moving
 * between the first and the last; --realtime and a --frame-ms without --frames are refused, and
 * so are a window or a screenshot without --realtime. */
static void test_replay_frames(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("frames"), case_dir[4200], path[4400], *out = NULL;
    tu_two_blocks_case(dir, case_dir, sizeof case_dir);
    char rec[4200];
    snprintf(rec, sizeof rec, "%s/sim/recordings/head-on.fnrec", tu_src());
    int rc = tu_run_cli(&out, "replay '%s' '%s' --frames '%s/frames' --frame-ms 250 --no-journal", case_dir,
                        rec, dir);
    if (rc != 0)
        fail_msg("replay --frames: exit %d: %s", rc, out);
    long n = -1;
    const char *said = strstr(out, "replay: ");
    while (said && sscanf(said, "replay: %ld pictures", &n) != 1)
        said = strstr(said + 1, "replay: ");
    free(out);
    /* head-on.fnrec lasts about 2.3 s: 10 pictures at 250 ms, and the final one. */
    if (n < 8 || n > 12)
        fail_msg("replay --frames wrote %ld pictures; about 11 expected", n);
    int w, h, w2, h2;
    snprintf(path, sizeof path, "%s/frames/frame_00000.png", dir);
    uint8_t *first = read_png(path, &w, &h);
    snprintf(path, sizeof path, "%s/frames/frame_%05ld.png", dir, n - 1);
    uint8_t *last = read_png(path, &w2, &h2);
    assert_int_equal(w, 512);
    assert_int_equal(h, 512);
    assert_int_equal(w2, w);
    assert_int_equal(h2, h);
    long moved = 0, content = 0;
    for (int i = 0; i < w * h; i++) {
        moved += !is_background(first + i * 3) != !is_background(last + i * 3);
        content += !is_background(first + i * 3);
    }
    if (content < 500 || moved < 50)
        fail_msg("the pictures show %ld content pixels and %ld that changed", content, moved);
    snprintf(path, sizeof path, "%s/frames/frame_%05ld.png", dir, n);
    assert_int_not_equal(access(path, F_OK), 0);
    free(first);
    free(last);
    assert_int_equal(tu_run_cli(NULL, "replay '%s' '%s' --frames '%s/f2' --realtime", case_dir, rec, dir), 2);
    assert_int_equal(tu_run_cli(NULL, "replay '%s' '%s' --frame-ms 10", case_dir, rec), 2);
    /* The window shows a replay at its pace: --view window and --screenshot need --realtime. */
    assert_int_equal(tu_run_cli(NULL, "replay '%s' '%s' --view window", case_dir, rec), 2);
    assert_int_equal(tu_run_cli(NULL, "replay '%s' '%s' --screenshot '%s/s.png'", case_dir, rec, dir), 2);
    assert_int_equal(tu_run_cli(NULL, "replay '%s' '%s' --realtime --view terminal --screenshot '%s/s.png'",
                                case_dir, rec, dir), 2);
    assert_int_equal(tu_run_cli(NULL, "replay '%s' '%s' --realtime --view bogus", case_dir, rec), 2);
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const char *only = getenv("FRACNAV_TEST_ONLY"); /* a cmocka pattern: run those tests alone */
    if (only && *only)
        cmocka_set_test_filter(only);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_gl_version_parse),
        cmocka_unit_test(test_old_gl_is_refused_with_its_version),
        cmocka_unit_test(test_offscreen_takes_egl_or_falls_back_to_osmesa),
        cmocka_unit_test_setup_teardown(test_every_mode_draws_and_matches, setup, teardown),
        cmocka_unit_test_setup_teardown(test_surface_meshes_are_decimated, setup, teardown),
        cmocka_unit_test_setup_teardown(test_prepared_fragments_draw_the_same, setup, teardown),
        cmocka_unit_test_setup_teardown(test_four_up_with_overlays_matches, setup, teardown),
        cmocka_unit_test_setup_teardown(test_four_up_pixel_to_world, setup, teardown),
        cmocka_unit_test_setup_teardown(test_four_up_marks_the_seeds, setup, teardown),
        cmocka_unit_test_setup_teardown(test_cutaway_shows_the_piece_in_hand, setup, teardown),
        cmocka_unit_test_setup_teardown(test_cutaway_in_iso_shows_the_piece_in_hand, setup, teardown),
        cmocka_unit_test_setup_teardown(test_interpenetrating_fragments_both_show, setup, teardown),
        cmocka_unit_test_setup_teardown(test_contacts_overlay_marks_colliding_voxels, setup, teardown),
        cmocka_unit_test(test_contacts_colour_both_facing_surfaces),
        cmocka_unit_test_setup_teardown(test_voi_overlay_outlines_the_box, setup, teardown),
        cmocka_unit_test_setup_teardown(test_hud_draws_text, setup, teardown),
        cmocka_unit_test(test_hud_scale_follows_height_and_dpi),
        cmocka_unit_test(test_surface_shading_is_smooth),
        cmocka_unit_test_setup_teardown(test_pose_moves_picture_by_expected_pixels, setup, teardown),
        cmocka_unit_test_setup_teardown(test_late_latching_draws_the_newest_poses, setup, teardown),
        cmocka_unit_test_setup_teardown(test_ghost_draws_the_fitted_pose, setup, teardown),
        cmocka_unit_test_setup_teardown(test_window_matches_offscreen, setup, teardown),
        cmocka_unit_test_teardown(test_navigate_window_matches_render, end_children),
        cmocka_unit_test_teardown(test_navigate_window_mouse_and_keys, end_children),
        cmocka_unit_test_teardown(test_navigate_window_wheel_scrolls_a_slice, end_children),
        cmocka_unit_test_teardown(test_navigate_window_click_moves_the_crosshair, end_children),
        cmocka_unit_test_teardown(test_navigate_window_follows_the_selection, end_children),
        cmocka_unit_test_teardown(test_navigate_window_drags_the_four_up_border, end_children),
        cmocka_unit_test_teardown(test_navigate_window_keyboard_steers, end_children),
        cmocka_unit_test_teardown(test_navigate_window_seed_mode_separates, end_children),
        cmocka_unit_test_teardown(test_navigate_window_two_clicks_in_one_frame, end_children),
        cmocka_unit_test_teardown(test_replay_window_matches_render, end_children),
        cmocka_unit_test_teardown(test_replay_frames, end_children),
        cmocka_unit_test_teardown(test_auto_view_shows_the_moving_fragment, end_children),
        cmocka_unit_test_teardown(test_cutaway_shows_the_enclosed_piece, end_children),
        cmocka_unit_test_teardown(test_navigate_window_seed_mode_previews, end_children),
        cmocka_unit_test_teardown(test_navigate_window_seed_mode_undoes, end_children),
        cmocka_unit_test_teardown(test_navigate_window_seed_mode_3d_click, end_children),
        cmocka_unit_test_teardown(test_navigate_window_seed_on_a_moved_fragment, end_children),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
