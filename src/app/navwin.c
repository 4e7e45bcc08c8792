/* navwin: the window of navigate and replay (see navwin.h). */
#include "navwin.h"

#include "cmd.h"
#include "render.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define ORBIT_DEG_PER_PX 0.5   /* a drag of 180 pixels turns the view by 90 degrees */
#define NOTE_SHOWN_US 2000000  /* what a window key did stays on the HUD this long */
#define R2F_WINDOW_US 1000000  /* the HUD's report-to-frame is the worst of this long */
#define BORDER_GRAB_PX 4       /* a left drag from this near four-up's border moves it */

struct navwin {
    render *r;
    session *k;
    int steer; /* the session's camera frame follows the view */
    const planning_case *c;
    int w, h;
    render_options o;
    int have_trees; /* the renderer holds the hierarchies (boxes, contacts) */
    int auto_view;  /* Ctrl+0: the camera frames the selected fragment (render_camera_auto) */
    int auto_for;   /* the fragment it was framed on; -1: frame it again */
    int slice_set;  /* a click or the wheel put the slices' point: it stays until the selection
                     * changes (else it follows the selected fragment's centroid) */
    int slice_for;  /* the selected fragment when it was put */
    /* the frame's clicks handed back (NAVWIN_KEY_CLICK), in order, LPS mm: a frame may take
     * several (two quick seeds), each with its own point */
    double click_world[RENDER_INPUT_CLICKS][3];
    int nclick_world, click_next;
    int drag_mode;  /* the left drag in progress: 0 none, 1 an orbit, 2 four-up's border */
    int nvoi;       /* the case's reduction VOI boxes (o.voi) */
    uint64_t drawn_seq;
    unsigned ghosts_seen; /* the live preview's updates drawn (session_preview.updates) */
    int split_preview;    /* the scene holds the seed mode's pieces (navwin_set_pieces) */
    int dirty;
    char hud[4096];
    char note[128]; /* what the last window key did, until note_until_us */
    int64_t note_until_us;
    double frame_ms_sum;
    long frames;
    double last_ms;
    int64_t prev_arrival_us;  /* the newest report in the last frame drawn */
    double r2f_ms, r2f_worst; /* the shown report-to-frame (worst of the last window), the current */
    int64_t r2f_since_us;
};

static void cross(const double a[3], const double b[3], double c[3])
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

static void normalize(double v[3])
{
    double n = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    if (n > 0)
        for (int a = 0; a < 3; a++)
            v[a] /= n;
}

/* Turns forward and up by angle (radians) about a unit axis (Rodrigues). */
static void turn(double v[3], const double k[3], double angle)
{
    double c = cos(angle), s = sin(angle), kv[3], d = k[0] * v[0] + k[1] * v[1] + k[2] * v[2];
    cross(k, v, kv);
    for (int a = 0; a < 3; a++)
        v[a] = v[a] * c + kv[a] * s + k[a] * d * (1 - c);
}

static void camera_to_loop(navwin *w)
{
    if (!w->steer)
        return;
    double right[3];
    cross(w->o.camera.forward, w->o.camera.up, right);
    session_set_camera(w->k, right, w->o.camera.up, w->o.camera.forward);
}

static void note(navwin *w, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void note(navwin *w, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(w->note, sizeof w->note, fmt, ap);
    va_end(ap);
    w->note_until_us = fnclock_now_us() + NOTE_SHOWN_US;
    w->dirty = 1;
}

/* The hierarchy and contacts overlays need the fragments' hierarchies: built once, when first
 * asked for. 0, or FN_E* with the overlays turned off. */
static int need_trees(navwin *w)
{
    if (w->have_trees || !(w->o.overlays & (RENDER_OVERLAY_HIERARCHY | RENDER_OVERLAY_CONTACTS)))
        return 0;
    obb_params hp = {w->c->tau_min, w->c->tau_max};
    int rc = render_set_hierarchies(w->r, w->c->frag, &hp);
    if (rc)
        w->o.overlays &= ~(unsigned)(RENDER_OVERLAY_HIERARCHY | RENDER_OVERLAY_CONTACTS);
    else
        w->have_trees = 1;
    return rc;
}

int navwin_look_option(const char *cmd, const char *a, const char *val, navwin_look *look, int *rc)
{
    *rc = 0;
    if (!strcmp(a, "--mode")) {
        render_mode m;
        if (render_mode_parse(val, &m))
            *rc = cmd_bad_value(cmd, a, val, "iso, dvr, mip or surface");
        else
            look->mode = (int)m;
    } else if (!strcmp(a, "--layout")) {
        if (render_layout_parse(val, &look->layout))
            *rc = cmd_bad_value(cmd, a, val, "3d or four-up");
    } else if (!strcmp(a, "--camera")) {
        render_view v;
        if (val && !strcmp(val, "auto"))
            look->camera = -1;
        else if (render_view_parse(val, &v))
            *rc = cmd_bad_value(cmd, a, val, "auto, anterior, posterior, left, right, superior or inferior");
        else
            look->camera = (int)v;
    } else if (!strcmp(a, "--overlay")) {
        if (!val)
            *rc = cmd_bad_value(cmd, a, val, "hierarchy[:DEPTH], contacts, axes, voi");
        else if (render_overlays_parse(val, &look->overlays, &look->hierarchy_depth))
            *rc = cmd_usage_error(cmd, "--overlay: %s", fn_err_msg());
    } else
        return 0;
    return 1;
}

const char *navwin_help(void)
{
    return "window: Ctrl+1..6 anterior, posterior, left, right, superior, inferior view\n"
           "  Ctrl+0 auto view: framed on the selected fragment, following the selection\n"
           "  F1 these keys  F2 mode  F3 layout (3D, four-up)  F4 axes  F5 contacts\n"
           "  F6 hierarchy boxes  F7/F8 their depth  F9 VOI   other keys as in the terminal\n"
           "  left drag orbits, right or middle drag pans, the wheel zooms; in four-up the\n"
           "  wheel over a slice moves it, a click on a slice moves the slices' crosshair,\n"
           "  a drag of the border above the slices resizes them\n"
           "  (in seed mode, F10, a click on a slice or on a fragment in 3D drops a seed)\n";
}

navwin *navwin_open(session *k, int steer, int width, int height, const navwin_look *look)
{
    static const navwin_look defaults = NAVWIN_LOOK_DEFAULT;
    const planning_case *c = session_case(k);
    if (!look)
        look = &defaults;
    if (c->nfrag > RENDER_MAX_FRAGS) {
        fn_err_set(FN_EINVAL, "the window draws at most %d fragments; the case has %d", RENDER_MAX_FRAGS,
                   c->nfrag);
        return NULL;
    }
    navwin *w = calloc(1, sizeof *w);
    if (!w) {
        fn_err_set(FN_ENOMEM, "out of memory for the window");
        return NULL;
    }
    w->r = render_open("glfw", width, height);
    if (!w->r) {
        free(w);
        return NULL;
    }
    w->k = k;
    w->steer = steer;
    w->c = c;
    w->w = width;
    w->h = height;
    w->dirty = 1;
    if (render_set_scene(w->r, c->ct, c->frag, c->nfrag, c->seg.threshold, NULL)) {
        navwin_close(w);
        return NULL;
    }
    render_options_default(&w->o, c->frag, c->nfrag);
    w->o.mode = look->mode >= 0 ? (render_mode)look->mode : render_default_mode(w->r);
    w->o.layout = look->layout;
    if (look->camera >= 0)
        render_camera_standard(&w->o.camera, (render_view)look->camera, c->frag, c->nfrag);
    w->auto_view = look->camera < 0;
    w->auto_for = -1;
    w->o.overlays = look->overlays;
    w->o.hierarchy_depth = look->hierarchy_depth;
    w->nvoi = cmd_case_voi(c, w->o.voi, RENDER_MAX_FRAGS);
    if ((w->o.overlays & RENDER_OVERLAY_VOI) && !w->nvoi) {
        w->o.overlays &= ~(unsigned)RENDER_OVERLAY_VOI;
        note(w, "no VOI: fracnav reduce defines one");
    }
    w->o.nvoi = w->nvoi;
    if (need_trees(w)) {
        navwin_close(w);
        return NULL;
    }
    camera_to_loop(w);
    return w;
}

int navwin_set_pieces(navwin *w, const frag *pieces, int n, const render_prep *prep)
{
    const frag *f = n > 0 ? pieces : w->c->frag;
    int nf = n > 0 ? n : w->c->nfrag;
    if (nf > RENDER_MAX_FRAGS)
        return fn_err_set(FN_EINVAL, "the window draws at most %d fragments; the split makes %d", RENDER_MAX_FRAGS,
                          nf);
    w->have_trees = 0;
    w->split_preview = n > 0;
    w->dirty = 1;
    int rc = n > 0 ? render_set_prepared(w->r, w->c->ct, f, nf, prep) : render_set_fragments(w->r, w->c->ct, f, nf);
    return rc ? rc : n > 0 ? 0 : need_trees(w);
}

void navwin_set_marks(navwin *w, int n, const double (*at)[3], const unsigned char (*rgb)[3])
{
    render_options *o = &w->o;
    n = n < 0 ? 0 : n > RENDER_MAX_MARKS ? RENDER_MAX_MARKS : n;
    size_t pts = (size_t)n * sizeof o->marks[0], cols = (size_t)n * sizeof o->mark_rgb[0];
    if (n == o->nmarks && (!n || (!memcmp(o->marks, at, pts) && !memcmp(o->mark_rgb, rgb, cols))))
        return;
    o->nmarks = n;
    if (n) {
        memcpy(o->marks, at, pts);
        memcpy(o->mark_rgb, rgb, cols);
    }
    w->dirty = 1;
}

void navwin_close(navwin *w)
{
    if (!w)
        return;
    render_close(w->r);
    free(w);
}

int navwin_view_option(const char *cmd, const char *a, const char *val, int *view, int *rc)
{
    if (strcmp(a, "--view"))
        return 0;
    *rc = 0;
    if (!val || (strcmp(val, "window") && strcmp(val, "terminal")))
        *rc = cmd_bad_value(cmd, a, val, "window or terminal");
    else
        *view = !strcmp(val, "window") ? NAVWIN_VIEW_WINDOW : NAVWIN_VIEW_TERMINAL;
    return 1;
}

int navwin_wanted(const char *cmd, int view, const char *without)
{
    const char *display = getenv("DISPLAY");
    if (view == NAVWIN_VIEW_TERMINAL)
        return 0;
    if (!display || !*display) {
        fprintf(stderr, "fracnav %s: no window ($DISPLAY is not set): %s\n", cmd, without);
        return 0;
    }
    return 1;
}

navwin *navwin_open_view(const char *cmd, int view, const navwin_look *look, const char *without, session *k,
                         int steer)
{
    if (!navwin_wanted(cmd, view, without))
        return NULL;
    navwin *w = navwin_open(k, steer, 768, 768, look);
    if (!w)
        fprintf(stderr, "fracnav %s: no window (%s): %s\n", cmd, fn_err_msg(), without);
    return w;
}

/* Turns an overlay on or off, and says so. */
static void toggle(navwin *w, unsigned bit, const char *name)
{
    w->o.overlays ^= bit;
    note(w, "%s %s", name, (w->o.overlays & bit) ? "on" : "off");
}

/* A key of the window's own (the look: F2-F9); 0 when k is none of them. */
static int look_key(navwin *w, int k)
{
    render_options *o = &w->o;
    switch (k - RENDER_KEY_F1 + 1) {
    case 2:
        o->mode = (render_mode)((o->mode + 1) % 4);
        note(w, "mode: %s", render_mode_name(o->mode));
        return 1;
    case 3:
        o->layout = o->layout == RENDER_LAYOUT_3D ? RENDER_LAYOUT_FOUR_UP : RENDER_LAYOUT_3D;
        note(w, "layout: %s", o->layout == RENDER_LAYOUT_3D ? "3D" : "four-up");
        return 1;
    case 4:
        toggle(w, RENDER_OVERLAY_AXES, "principal axes");
        return 1;
    case 5:
        toggle(w, RENDER_OVERLAY_CONTACTS, "contacts");
        break;
    case 6:
        toggle(w, RENDER_OVERLAY_HIERARCHY, "hierarchy boxes");
        break;
    case 7:
    case 8:
        o->hierarchy_depth += k == RENDER_KEY_F1 + 7 ? 1 : -1;
        o->hierarchy_depth = o->hierarchy_depth < 1 ? 1 : o->hierarchy_depth > 32 ? 32 : o->hierarchy_depth;
        o->overlays |= RENDER_OVERLAY_HIERARCHY;
        note(w, "hierarchy boxes at depth %d", o->hierarchy_depth);
        break;
    case 9:
        if (w->nvoi)
            toggle(w, RENDER_OVERLAY_VOI, "VOI");
        else
            note(w, "no VOI: fracnav reduce defines one");
        return 1;
    default:
        return 0;
    }
    if (need_trees(w))
        note(w, "no hierarchy: %s", fn_err_msg());
    return 1;
}

/* In four-up, the wheel over a slice moves that slice along its normal (a millimetre a step). 1
 * when it did. */
static int slice_wheel(navwin *w, const render_input *in)
{
    double p[3], n[3];
    int pane = w->o.layout == RENDER_LAYOUT_FOUR_UP && in->scroll != 0
                   ? render_slice_point_at(w->r, &w->o, in->x, in->y, p)
                   : -1;
    if (pane < 0)
        return 0;
    render_slice_normal(pane, n);
    for (int a = 0; a < 3; a++)
        w->o.slice_point[a] += n[a] * in->scroll;
    w->slice_set = 1;
    return 1;
}

/* In four-up, a left drag that starts on the border between the 3D view and the slices moves the
 * border (the rest of that drag too). 1 when this frame's drag did. */
static int border_drag(navwin *w, const render_input *in)
{
    const double *d = in->drag[0];
    int rect[4][4], resize = 0;
    render_four_up_panes(w->w, w->h, w->o.four_up_split, rect);
    if (d[0] != 0 || d[1] != 0) {
        double border = rect[RENDER_PANE_3D][3] + 0.5; /* the background row between the panes */
        if (!w->drag_mode)
            w->drag_mode = w->o.layout == RENDER_LAYOUT_FOUR_UP && fabs(in->press[1] - border) <= BORDER_GRAB_PX
                               ? 2
                               : 1;
        resize = w->drag_mode == 2;
    }
    if (resize) {
        double split = 1 - (double)rect[RENDER_PANE_AXIAL][3] / w->h + d[1] / w->h;
        w->o.four_up_split = fmin(RENDER_SPLIT_MAX, fmax(RENDER_SPLIT_MIN, split));
        w->dirty = 1;
    }
    if (!in->left_down)
        w->drag_mode = 0;
    return resize;
}

/* Per fragment of sc (the case's, at their poses there): the map from the world to its crop's
 * local mm. 0 when sc is not a scene of the case. */
static int to_locals(const navwin *w, const loop_scene *sc, pose *to_local)
{
    for (int i = 0; i < w->c->nfrag && sc->nfrag == w->c->nfrag; i++)
        to_local[i] = pose_inverse(pose_compose(sc->pose[i], w->c->frag[i].home));
    return sc->nfrag == w->c->nfrag;
}

/* The fragment whose mask holds world point at (to_local: to_locals'), or -1. */
static int frag_holding(const navwin *w, const pose *to_local, const double at[3])
{
    for (int i = 0; i < w->c->nfrag; i++) {
        const frag *f = &w->c->frag[i];
        double local[3];
        int l[3], in = 1;
        pose_apply(&to_local[i], at, local);
        for (int a = 0; a < 3; a++) {
            l[a] = (int)floor(local[a] / f->spacing[a] + 0.5);
            in &= l[a] >= 0 && l[a] < f->dim[a];
        }
        if (in && f->prob[((size_t)l[2] * f->dim[1] + l[1]) * f->dim[0] + l[0]])
            return i;
    }
    return -1;
}

/* World point at of fragment i at its pose in sc, where it lies in the CT (its home). */
static void home_of(const loop_scene *sc, int i, const double at[3], double home[3])
{
    pose back = pose_inverse(sc->pose[i]);
    pose_apply(&back, at, home);
}

/* In four-up, a click at xy on a slice puts the slices' point there, and in home the point where
 * it lies in the CT (a moved fragment's voxel at its home). 1 when it did. */
static int slice_click(navwin *w, const loop_scene *sc, const double xy[2], double home[3])
{
    double p[3];
    pose to_local[RENDER_MAX_FRAGS];
    if (w->o.layout != RENDER_LAYOUT_FOUR_UP || render_slice_point_at(w->r, &w->o, xy[0], xy[1], p) < 0)
        return 0;
    memcpy(w->o.slice_point, p, sizeof p);
    int i = to_locals(w, sc, to_local) ? frag_holding(w, to_local, p) : -1;
    if (i >= 0)
        home_of(sc, i, p, home);
    else
        memcpy(home, p, sizeof p);
    note(w, "slices through (%.1f, %.1f, %.1f) mm", p[0], p[1], p[2]);
    w->slice_set = 1;
    return 1;
}

/* The point of the fragments' surface that a click at xy on the 3D view (the whole window, or the
 * four-up's 3D pane) shows: along the camera's ray through xy, from the viewer, the first voxel
 * of a fragment's mask at its pose in sc, as a point of that fragment's home (the CT's grid,
 * where the seeds and the slices' CT are). 1 when the ray meets a fragment, 0 when not. */
static int surface_pick(const navwin *w, const loop_scene *sc, const double xy[2], double home[3])
{
    const planning_case *c = w->c;
    int q[4] = {0, 0, w->w, w->h}, rect[4][4];
    if (w->o.layout == RENDER_LAYOUT_FOUR_UP) {
        render_four_up_panes(w->w, w->h, w->o.four_up_split, rect);
        memcpy(q, rect[RENDER_PANE_3D], sizeof q);
    }
    pose to_local[RENDER_MAX_FRAGS];
    if (!to_locals(w, sc, to_local) || xy[0] < q[0] || xy[0] >= q[0] + q[2] || xy[1] < q[1] ||
        xy[1] >= q[1] + q[3])
        return 0;
    const render_camera *cam = &w->o.camera;
    double right[3], at[3], step = 1e30;
    cross(cam->forward, cam->up, right);
    double hh = cam->half_height, hw = hh * q[2] / q[3];
    double sx = 2.0 * (xy[0] - q[0]) / q[2] - 1, sy = 1 - 2.0 * (xy[1] - q[1]) / q[3];
    for (int i = 0; i < c->nfrag; i++)
        for (int a = 0; a < 3; a++)
            step = fmin(step, c->frag[i].spacing[a] / 2);
    for (double t = -cam->depth; t <= cam->depth; t += step) {
        for (int a = 0; a < 3; a++)
            at[a] = cam->centre[a] + right[a] * hw * sx + cam->up[a] * hh * sy + cam->forward[a] * t;
        int i = frag_holding(w, to_local, at);
        if (i >= 0) {
            home_of(sc, i, at, home);
            return 1;
        }
    }
    return 0;
}

int navwin_click_at(navwin *w, double world[3])
{
    if (w->nclick_world == 0)
        return -1;
    int i = w->click_next < w->nclick_world ? w->click_next++ : w->nclick_world - 1;
    memcpy(world, w->click_world[i], sizeof w->click_world[i]);
    return 0;
}

/* The pointer and the view keys (Ctrl+1..6) move the camera, the look keys (F2-F9) change the
 * look; F1 goes to the caller as '?', and every other key as it came. */
static int handle_input(navwin *w, const loop_scene *sc, const render_input *in, int *keys, int cap)
{
    render_camera *cam = &w->o.camera;
    int n = 0, moved = 0;
    w->nclick_world = w->click_next = 0;
    for (int i = 0; i < in->nkeys; i++) {
        int k = in->keys[i];
        if (k >= (RENDER_KEY_CTRL | '1') && k <= (RENDER_KEY_CTRL | '6')) {
            render_camera_standard(cam, (render_view)(k - (RENDER_KEY_CTRL | '1')), w->c->frag, w->c->nfrag);
            w->auto_view = 0;
            moved = 1;
        } else if (k == (RENDER_KEY_CTRL | '0')) {
            w->auto_view = 1;
            w->auto_for = -1;
            note(w, "view: auto (follows the selected fragment)");
        } else if (k >= RENDER_KEY_CLICK && k < RENDER_KEY_CLICK + in->nclicks) {
            /* handed back in its place among the keys: a key typed before it acts first */
            const double *xy = in->click[k - RENDER_KEY_CLICK];
            double spare[3]; /* never used: a frame holds at most RENDER_INPUT_CLICKS clicks */
            double *home = w->nclick_world < RENDER_INPUT_CLICKS ? w->click_world[w->nclick_world] : spare;
            if ((slice_click(w, sc, xy, home) || surface_pick(w, sc, xy, home)) && n < cap &&
                w->nclick_world < RENDER_INPUT_CLICKS) {
                keys[n++] = NAVWIN_KEY_CLICK;
                w->nclick_world++;
                moved = 1;
            }
        } else if (!look_key(w, k) && n < cap)
            keys[n++] = k == RENDER_KEY_F1 ? '?' : k;
    }
    double right[3];
    cross(cam->forward, cam->up, right);
    const double *orbit = in->drag[0];
    if (!border_drag(w, in) && (orbit[0] != 0 || orbit[1] != 0)) {
        w->auto_view = 0;
        /* Dragging right turns the scene to the right (the camera to its left), about up; dragging
         * down tips it towards the viewer, about right. */
        double up[3] = {cam->up[0], cam->up[1], cam->up[2]}, rad = ORBIT_DEG_PER_PX * M_PI / 180.0;
        turn(cam->forward, up, -orbit[0] * rad);
        turn(cam->forward, right, -orbit[1] * rad);
        turn(cam->up, right, -orbit[1] * rad);
        normalize(cam->forward);
        normalize(cam->up);
        moved = 1;
    }
    render_size(w->r, &w->w, &w->h);
    double mm_per_px = 2.0 * cam->half_height / w->h;
    for (int b = 1; b < 3; b++)
        if (in->drag[b][0] != 0 || in->drag[b][1] != 0) {
            for (int a = 0; a < 3; a++)
                cam->centre[a] += (-right[a] * in->drag[b][0] + cam->up[a] * in->drag[b][1]) * mm_per_px;
            moved = 1;
        }
    if (slice_wheel(w, in))
        moved = 1;
    else if (in->scroll != 0) {
        cam->half_height *= pow(0.9, in->scroll);
        moved = 1;
    }
    if (moved) {
        camera_to_loop(w);
        w->dirty = 1;
    }
    return n;
}

/* The HUD's text: hud's lines, what the last window key did, the frame and report-to-frame
 * times, the mode and the renderer. */
static void hud_text(const navwin *w, const char *hud, char *text, size_t cap)
{
    int noted = w->note[0] && fnclock_now_us() < w->note_until_us;
    char r2f[64] = "";
    if (w->r2f_ms > 0)
        snprintf(r2f, sizeof r2f, ", report to frame <= %.0f ms", w->r2f_ms);
    snprintf(text, cap, "%s%s%s\nframe %.1f ms%s\n%s on %s", hud, noted ? "\nwindow: " : "", noted ? w->note : "",
             w->last_ms, r2f, render_mode_name(w->o.mode), render_gl_renderer(w->r));
}

/* Draws the scene with the HUD's text into the back buffer, late latched (render_frame_early
 * with sc, then render_frame_late with the loop's newest scene, into *shown): a surface frame in
 * the 3D layout draws the moving fragment at the newest pose there is. In four-up the slices cut
 * through the selected fragment's centroid at its pose, or where a click or the wheel put them
 * (until the selection changes). */
static int draw(navwin *w, const loop_scene *sc, const char *text, loop_scene *shown)
{
    int n = w->c->nfrag;
    *shown = *sc;
    if (w->split_preview) { /* the pieces at their own poses, with no overlay that needs the case's */
        render_options o = w->o;
        o.overlays &= ~(unsigned)(RENDER_OVERLAY_HIERARCHY | RENDER_OVERLAY_CONTACTS);
        o.ghost = o.cutaway = 0;
        int rc = render_frame(w->r, NULL, &o);
        return rc ? rc : render_hud(w->r, text, render_hud_scale(w->r));
    }
    if (sc->nfrag == n) {
        int rc = render_frame_early(w->r, sc->pose, sc->selected, &w->o);
        if (rc)
            return rc;
        session_scene_read(w->k, shown);
    }
    int ok = shown->nfrag == n, sel = ok && shown->selected >= 0 && shown->selected < n ? shown->selected : 0;
    if (ok && w->slice_set && sel != w->slice_for)
        w->slice_set = 0;
    w->o.cutaway = ok && w->auto_view ? sel + 1 : 0; /* the auto view keeps the piece in hand in sight */
    if (ok && !w->slice_set) {
        pose_apply(&shown->pose[sel], w->c->frag[sel].centroid, w->o.slice_point);
        w->slice_for = sel;
    }
    int rc = render_frame_late(w->r, ok ? shown->pose : NULL, &w->o);
    return rc ? rc : render_hud(w->r, text, render_hud_scale(w->r));
}

/* After a frame shown at `shown`: the worst report-to-frame of the last R2F_WINDOW_US. */
static void report_to_frame(navwin *w, const loop_scene *sc, int64_t shown)
{
    int64_t newest = sc->stats.last_arrival_us;
    if (newest > w->prev_arrival_us && w->prev_arrival_us > 0) {
        double ms = (double)(shown - w->prev_arrival_us) / 1000.0;
        w->r2f_worst = ms > w->r2f_worst ? ms : w->r2f_worst;
    }
    w->prev_arrival_us = newest;
    if (shown - w->r2f_since_us >= R2F_WINDOW_US) {
        w->r2f_ms = w->r2f_worst;
        w->r2f_worst = 0;
        w->r2f_since_us = shown;
    }
}

/* In the auto view, the camera frames sc's selected fragment again when the selection changed
 * (render_camera_auto). 0 or FN_E*. */
static int follow_selection(navwin *w, const loop_scene *sc)
{
    if (!w->auto_view || w->split_preview || sc->nfrag != w->c->nfrag || sc->selected == w->auto_for)
        return 0;
    int rc = render_camera_auto(w->r, &w->o.camera, w->c->frag, w->c->nfrag, sc->pose, sc->selected);
    if (rc)
        return rc;
    w->auto_for = sc->selected;
    camera_to_loop(w);
    w->dirty = 1;
    return 0;
}

int navwin_frame(navwin *w, const loop_scene *sc, const char *hud, int *keys, int cap, int *close)
{
    render_input in;
    int rc = render_poll(w->r, &in);
    if (rc)
        return rc;
    *close = in.close;
    int w0 = w->w, h0 = w->h;
    int n = handle_input(w, sc, &in, keys, cap);
    w->dirty |= w->w != w0 || w->h != h0; /* resized */
    rc = follow_selection(w, sc);
    if (rc)
        return rc;
    if (w->note[0] && fnclock_now_us() >= w->note_until_us) {
        w->note[0] = 0;
        w->dirty = 1;
    }
    session_preview pv; /* its ghost, translucent at the fitted pose */
    session_preview_status(w->k, &pv);
    w->o.ghost = pv.shown && pv.frag >= 0 && pv.frag < w->c->nfrag ? pv.frag + 1 : 0;
    w->o.ghost_pose = pv.ghost;
    w->dirty |= pv.updates != w->ghosts_seen;
    w->ghosts_seen = pv.updates;
    if (!w->dirty && sc->seq == w->drawn_seq && !strcmp(hud, w->hud))
        return n;
    snprintf(w->hud, sizeof w->hud, "%s", hud);
    w->dirty = 0;
    char text[4400];
    hud_text(w, hud, text, sizeof text);
    int64_t t0 = fnclock_now_us();
    loop_scene shown;
    rc = draw(w, sc, text, &shown);
    if (!rc)
        rc = render_present(w->r);
    if (rc)
        return rc;
    w->drawn_seq = shown.seq;
    int64_t t1 = fnclock_now_us();
    report_to_frame(w, &shown, t1);
    w->last_ms = (double)(t1 - t0) / 1000.0;
    w->frame_ms_sum += w->last_ms;
    w->frames++;
    return n;
}

/* Appends src to dst (at *len, cap) with every line wrapped at the last space before cols
 * characters; a wrapped line goes on indented by four spaces. */
static void wrap(char *dst, size_t cap, size_t *len, const char *src, int cols)
{
    int col = 0;
    for (const char *p = src; *p && *len + 6 < cap; p++) {
        if (*p == '\n') {
            dst[(*len)++] = '\n';
            col = 0;
            continue;
        }
        if (*p == ' ' && col > 4 && col + 1 + (int)strcspn(p + 1, " \n") > cols) {
            memcpy(dst + *len, "\n    ", 5);
            *len += 5;
            col = 4;
            continue;
        }
        dst[(*len)++] = *p;
        col++;
    }
    dst[*len] = '\0';
}

int navwin_show(navwin *w, const loop_scene *sc, const navview_extra *x, const char *device, const char *help,
                int *keys, int cap, int *close)
{
    char view[4096], text[8192];
    int cols = render_hud_columns(w->r);
    navview_format(sc, x, cols + 1, view, sizeof view);
    size_t len = 0;
    text[0] = '\0';
    wrap(text, sizeof text, &len, view, cols);
    wrap(text, sizeof text, &len, "\ndevice: ", cols);
    wrap(text, sizeof text, &len, device, cols);
    if (help) {
        wrap(text, sizeof text, &len, "\n", cols);
        wrap(text, sizeof text, &len, help, cols);
        wrap(text, sizeof text, &len, navwin_help(), cols);
    }
    return navwin_frame(w, sc, text, keys, cap, close);
}

int navwin_save_screenshot(navwin *w, const char *cmd, const char *png)
{
    int rc = navwin_screenshot(w, png);
    if (rc < 0)
        fprintf(stderr, "fracnav %s: --screenshot %s: %s\n", cmd, png, fn_err_msg());
    return rc;
}

int navwin_screenshot(navwin *w, const char *png)
{
    /* After a swap the back buffer is undefined: draw the last frame again, then read it. */
    loop_scene sc = {0}, shown;
    session_scene_read(w->k, &sc);
    char text[4400];
    hud_text(w, w->hud, text, sizeof text);
    int rc = follow_selection(w, &sc); /* a selection changed since the last frame */
    if (!rc)
        rc = draw(w, &sc, text, &shown);
    return rc ? rc : cmd_write_png(w->r, png, w->w, w->h);
}

double navwin_frame_ms(const navwin *w)
{
    return w->frames ? w->frame_ms_sum / (double)w->frames : 0;
}

const char *navwin_gl_renderer(const navwin *w)
{
    return render_gl_renderer(w->r);
}
