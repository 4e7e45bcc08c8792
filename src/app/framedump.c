/* framedump: pictures of a replay (see framedump.h). */
#include "framedump.h"

#include "cmd.h"
#include "err.h"
#include "render.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

struct framedump {
    char dir[4096];
    const planning_case *c;
    render *r;
    render_options o;
    int w, h;
    int64_t step_us, next_us;
    int started;
    long count;
};

framedump *framedump_open(const char *dir, const planning_case *c, double frame_ms, int w, int h,
                          const navwin_look *look)
{
    if (mkdir(dir, 0777) != 0 && errno != EEXIST) {
        fn_err_set(FN_EIO, "--frames %s: cannot make the folder: %s", dir, strerror(errno));
        return NULL;
    }
    if (c->nfrag > RENDER_MAX_FRAGS) {
        fn_err_set(FN_EINVAL, "--frames: the case has %d fragments; at most %d can be drawn", c->nfrag,
                   RENDER_MAX_FRAGS);
        return NULL;
    }
    framedump *d = calloc(1, sizeof *d);
    if (!d) {
        fn_err_set(FN_ENOMEM, "--frames: out of memory");
        return NULL;
    }
    snprintf(d->dir, sizeof d->dir, "%s", dir);
    d->c = c;
    d->w = w;
    d->h = h;
    d->step_us = (int64_t)(frame_ms * 1000.0 + 0.5);
    d->step_us = d->step_us < 1 ? 1 : d->step_us;
    render_options_default(&d->o, c->frag, c->nfrag);
    d->o.mode = look->mode >= 0 ? (render_mode)look->mode : RENDER_ISO;
    d->o.layout = look->layout;
    d->o.overlays = look->overlays;
    d->o.hierarchy_depth = look->hierarchy_depth;
    if ((d->o.overlays & RENDER_OVERLAY_VOI) && !(d->o.nvoi = cmd_case_voi(c, d->o.voi, RENDER_MAX_FRAGS))) {
        fn_err_set(FN_EINVAL, "--overlay voi: the case holds no reduction VOI (fracnav reduce defines one)");
        framedump_close(d);
        return NULL;
    }
    obb_params hp = {c->tau_min, c->tau_max};
    int trees = (d->o.overlays & (RENDER_OVERLAY_HIERARCHY | RENDER_OVERLAY_CONTACTS)) != 0;
    d->r = render_open("osmesa", w, h);
    if (!d->r || render_set_scene(d->r, c->ct, c->frag, c->nfrag, c->seg.threshold, trees ? &hp : NULL)) {
        framedump_close(d);
        return NULL;
    }
    return d;
}

static int write_frame(framedump *d, const session *k)
{
    pose poses[RENDER_MAX_FRAGS];
    for (int i = 0; i < d->c->nfrag; i++)
        poses[i] = session_pose(k, i);
    int sel = session_selected(k);
    sel = sel >= 0 && sel < d->c->nfrag ? sel : 0;
    pose_apply(&poses[sel], d->c->frag[sel].centroid, d->o.slice_point); /* four-up cuts there */
    char path[4200];
    snprintf(path, sizeof path, "%s/frame_%05ld.png", d->dir, d->count);
    int rc = render_frame(d->r, poses, &d->o);
    if (!rc)
        rc = cmd_write_png(d->r, path, d->w, d->h);
    if (!rc)
        d->count++;
    return rc;
}

int framedump_before(framedump *d, const session *k, int64_t t_us)
{
    if (!d->started) {
        d->started = 1;
        d->next_us = t_us; /* frame 0: the poses before the first event */
    }
    int rc = 0;
    while (!rc && d->next_us < t_us) {
        rc = write_frame(d, k);
        d->next_us += d->step_us;
    }
    return rc;
}

int framedump_finish(framedump *d, const session *k)
{
    return write_frame(d, k);
}

long framedump_count(const framedump *d)
{
    return d->count;
}

void framedump_close(framedump *d)
{
    if (!d)
        return;
    render_close(d->r);
    free(d);
}
