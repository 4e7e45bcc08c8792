/* navwin: the window of navigate and replay (see navwin.h). */
#include "navwin.h"

#include "cmd.h"
#include "err.h"
#include "fnclock.h"
#include "render.h"
#include "picture.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct navwin {
    render *r;
    loop *L;
    int steer; /* the loop's camera frame follows the view */
    const planning_case *c;
    int w, h;
    render_options o;
    uint64_t drawn_seq;
    int dirty;
    char hud[4096];
    double frame_ms_sum;
    long frames;
    double last_ms;
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
    loop_set_camera(w->L, right, w->o.camera.up, w->o.camera.forward);
}

navwin *navwin_open(const planning_case *c, loop *L, int steer, int width, int height)
{
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
    w->L = L;
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
    /* Software GL rasterizes meshes far faster than it casts rays: surface is its interactive
     * mode. */
    const char *rn = render_gl_renderer(w->r);
    w->o.mode = strstr(rn, "llvmpipe") || strstr(rn, "softpipe") ? RENDER_SURFACE : RENDER_ISO;
    camera_to_loop(w);
    return w;
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

navwin *navwin_open_view(const char *cmd, int view, const char *without, const planning_case *c, loop *L,
                         int steer)
{
    if (!navwin_wanted(cmd, view, without))
        return NULL;
    navwin *w = navwin_open(c, L, steer, 768, 768);
    if (!w)
        fprintf(stderr, "fracnav %s: no window (%s): %s\n", cmd, fn_err_msg(), without);
    return w;
}

/* The pointer and the view keys move the camera; other keys go to the caller. */
static int handle_input(navwin *w, const render_input *in, int *keys, int cap)
{
    render_camera *cam = &w->o.camera;
    int n = 0, moved = 0;
    for (int i = 0; i < in->nkeys; i++) {
        int k = in->keys[i];
        if (k >= '1' && k <= '6') {
            render_camera_standard(cam, (render_view)(k - '1'), w->c->frag, w->c->nfrag);
            moved = 1;
        } else if (n < cap)
            keys[n++] = k;
    }
    double right[3];
    cross(cam->forward, cam->up, right);
    const double *orbit = in->drag[0];
    if (orbit[0] != 0 || orbit[1] != 0) {
        /* Dragging right turns the scene to the right (the camera to its left), about up; dragging
         * down tips it towards the viewer, about right. */
        double up[3] = {cam->up[0], cam->up[1], cam->up[2]};
        turn(cam->forward, up, -orbit[0] * 0.01);
        turn(cam->forward, right, -orbit[1] * 0.01);
        turn(cam->up, right, -orbit[1] * 0.01);
        normalize(cam->forward);
        normalize(cam->up);
        moved = 1;
    }
    double mm_per_px = 2.0 * cam->half_height / w->h;
    for (int b = 1; b < 3; b++)
        if (in->drag[b][0] != 0 || in->drag[b][1] != 0) {
            for (int a = 0; a < 3; a++)
                cam->centre[a] += (-right[a] * in->drag[b][0] + cam->up[a] * in->drag[b][1]) * mm_per_px;
            moved = 1;
        }
    if (in->scroll != 0) {
        cam->half_height *= pow(0.9, in->scroll);
        moved = 1;
    }
    if (moved) {
        camera_to_loop(w);
        w->dirty = 1;
    }
    return n;
}

int navwin_frame(navwin *w, const loop_scene *sc, const char *hud, int *keys, int cap, int *close)
{
    render_input in;
    int rc = render_poll(w->r, &in);
    if (rc)
        return rc;
    *close = in.close;
    int n = handle_input(w, &in, keys, cap);
    if (!w->dirty && sc->seq == w->drawn_seq && !strcmp(hud, w->hud))
        return n;
    snprintf(w->hud, sizeof w->hud, "%s", hud);
    w->drawn_seq = sc->seq;
    w->dirty = 0;
    char text[4200];
    snprintf(text, sizeof text, "%s\nframe %.1f ms (%s, %s)", hud, w->last_ms, render_mode_name(w->o.mode),
             render_gl_renderer(w->r));
    int64_t t0 = fnclock_now_us();
    rc = render_frame(w->r, sc->pose, &w->o);
    if (!rc)
        rc = render_hud(w->r, text, w->w >= 900 ? 2 : 1);
    if (!rc)
        rc = render_present(w->r);
    if (rc)
        return rc;
    w->last_ms = (double)(fnclock_now_us() - t0) / 1000.0;
    w->frame_ms_sum += w->last_ms;
    w->frames++;
    return n;
}

int navwin_show(navwin *w, const loop_scene *sc, const navview_extra *x, const char *device, const char *help,
                int *keys, int cap, int *close)
{
    char text[4096];
    navview_format(sc, x, 100, text, sizeof text);
    size_t len = strlen(text);
    snprintf(text + len, sizeof text - len, "\ndevice: %s", device);
    if (help) {
        len = strlen(text);
        snprintf(text + len, sizeof text - len, "\n%s", help);
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
    uint8_t *rgb = malloc((size_t)w->w * (size_t)w->h * 3);
    if (!rgb)
        return fn_err_set(FN_ENOMEM, "out of memory for a %dx%d screenshot", w->w, w->h);
    /* After a swap the back buffer is undefined: draw the last frame again, then read it. */
    loop_scene sc = {0};
    loop_scene_read(w->L, &sc);
    char text[4200];
    snprintf(text, sizeof text, "%s\nframe %.1f ms (%s, %s)", w->hud, w->last_ms, render_mode_name(w->o.mode),
             render_gl_renderer(w->r));
    int rc = render_frame(w->r, sc.pose, &w->o);
    if (!rc)
        rc = render_hud(w->r, text, w->w >= 900 ? 2 : 1);
    if (!rc)
        rc = render_read_rgb(w->r, rgb);
    if (!rc)
        rc = picture_write_png(png, rgb, w->w, w->h);
    free(rgb);
    return rc;
}

double navwin_frame_ms(const navwin *w)
{
    return w->frames ? w->frame_ms_sum / (double)w->frames : 0;
}

const char *navwin_gl_renderer(const navwin *w)
{
    return render_gl_renderer(w->r);
}
