/* render: cameras and one frame's drawing (raycast or surface, slices, overlays). */
#include "render_impl.h"

#include "err.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static const float BG[3] = {0.08f, 0.09f, 0.11f};
enum { UNIT_OCC = RENDER_MAX_FRAGS, UNIT_TF, UNIT_CT, UNIT_NEAR, UNIT_FAR, UNIT_DIST };

/* ---- 4x4 row-major doubles, sent to GL transposed (column-major) ---- */

typedef double mat4[4][4];

static void mat4_from_pose(mat4 m, const pose *p)
{
    double r[3][3];
    pose_to_matrix(p, r);
    memset(m, 0, sizeof(mat4));
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            m[i][j] = r[i][j];
        m[i][3] = p->t[i];
    }
    m[3][3] = 1;
}

static void mat4_to_gl(const mat4 m, float out[16])
{
    for (int c = 0; c < 4; c++)
        for (int r = 0; r < 4; r++)
            out[c * 4 + r] = (float)m[r][c];
}

static void cross3(const double a[3], const double b[3], double c[3])
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* ---- cameras ---- */

static const struct {
    const char *name;
    double forward[3], up[3];
} views[] = {
    [RENDER_ANTERIOR] = {"anterior", {0, 1, 0}, {0, 0, 1}},
    [RENDER_POSTERIOR] = {"posterior", {0, -1, 0}, {0, 0, 1}},
    [RENDER_LEFT] = {"left", {-1, 0, 0}, {0, 0, 1}},
    [RENDER_RIGHT] = {"right", {1, 0, 0}, {0, 0, 1}},
    [RENDER_SUPERIOR] = {"superior", {0, 0, -1}, {0, -1, 0}},
    [RENDER_INFERIOR] = {"inferior", {0, 0, 1}, {0, -1, 0}},
};

int render_view_parse(const char *s, render_view *v)
{
    for (size_t i = 0; i < sizeof views / sizeof views[0]; i++)
        if (s && !strcmp(s, views[i].name)) {
            *v = (render_view)i;
            return 0;
        }
    return fn_err_set(FN_EINVAL, "'%s' is not a view (anterior, posterior, left, right, superior, "
                                 "inferior)", s ? s : "");
}

static const char *const mode_names[] = {"iso", "dvr", "mip", "surface"};

int render_mode_parse(const char *s, render_mode *m)
{
    for (int i = 0; i < 4; i++)
        if (s && !strcmp(s, mode_names[i])) {
            *m = (render_mode)i;
            return 0;
        }
    return fn_err_set(FN_EINVAL, "'%s' is not a mode (iso, dvr, mip, surface)", s ? s : "");
}

const char *render_mode_name(render_mode m)
{
    return (unsigned)m < 4 ? mode_names[m] : "?";
}

int render_overlays_parse(const char *s, unsigned *overlays, int *depth)
{
    char buf[256];
    if (!s || !*s || strlen(s) >= sizeof buf)
        return fn_err_set(FN_EINVAL, "'%s' is not a list of overlays (hierarchy[:DEPTH], contacts, axes, voi)",
                          s ? s : "");
    strcpy(buf, s);
    char *save = NULL;
    for (char *tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
        char *end;
        if (!strcmp(tok, "axes"))
            *overlays |= RENDER_OVERLAY_AXES;
        else if (!strcmp(tok, "hierarchy"))
            *overlays |= RENDER_OVERLAY_HIERARCHY;
        else if (!strncmp(tok, "hierarchy:", 10)) {
            long d = strtol(tok + 10, &end, 10);
            if (end == tok + 10 || *end || d < 1 || d > 32)
                return fn_err_set(FN_EINVAL, "'%s': the hierarchy's depth is a whole number from 1 to 32", tok);
            *overlays |= RENDER_OVERLAY_HIERARCHY;
            *depth = (int)d;
        } else if (!strcmp(tok, "contacts"))
            *overlays |= RENDER_OVERLAY_CONTACTS;
        else if (!strcmp(tok, "voi"))
            *overlays |= RENDER_OVERLAY_VOI;
        else
            return fn_err_set(FN_EINVAL, "'%s' is not an overlay (hierarchy[:DEPTH], contacts, axes, voi)", tok);
    }
    return 0;
}

int render_layout_parse(const char *s, render_layout *l)
{
    if (s && !strcmp(s, "3d"))
        *l = RENDER_LAYOUT_3D;
    else if (s && !strcmp(s, "four-up"))
        *l = RENDER_LAYOUT_FOUR_UP;
    else
        return fn_err_set(FN_EINVAL, "'%s' is not a layout (3d, four-up)", s ? s : "");
    return 0;
}

void render_camera_standard(render_camera *c, render_view v, const frag *frags, int nfrag)
{
    double lo[3] = {1e30, 1e30, 1e30}, hi[3] = {-1e30, -1e30, -1e30};
    for (int i = 0; i < nfrag; i++)
        for (int b = 0; b < 8; b++) {
            double x[3], w[3];
            for (int a = 0; a < 3; a++)
                x[a] = ((b >> a & 1) ? frags[i].dim[a] - 0.5 : -0.5) * frags[i].spacing[a];
            pose_apply(&frags[i].home, x, w);
            for (int a = 0; a < 3; a++) {
                lo[a] = w[a] < lo[a] ? w[a] : lo[a];
                hi[a] = w[a] > hi[a] ? w[a] : hi[a];
            }
        }
    double r2 = 0;
    for (int a = 0; a < 3; a++) {
        c->centre[a] = nfrag ? 0.5 * (lo[a] + hi[a]) : 0;
        r2 += nfrag ? 0.25 * (hi[a] - lo[a]) * (hi[a] - lo[a]) : 1;
        c->forward[a] = views[v].forward[a];
        c->up[a] = views[v].up[a];
    }
    c->half_height = 1.02 * sqrt(r2);
    c->depth = 2.0 * sqrt(r2) + 50.0; /* room for fragments moved away from home */
}

void render_options_default(render_options *o, const frag *frags, int nfrag)
{
    memset(o, 0, sizeof *o);
    o->mode = RENDER_ISO;
    o->layout = RENDER_LAYOUT_3D;
    render_camera_standard(&o->camera, RENDER_ANTERIOR, frags, nfrag);
    memcpy(o->slice_point, o->camera.centre, sizeof o->slice_point);
    if (nfrag > 0)
        pose_apply(&frags[0].pose, frags[0].centroid, o->slice_point);
    o->hierarchy_depth = 3;
}

/* clip = vp * world; world = inv * ndc (orthographic, so both are affine). */
static void camera_mats(const render_camera *c, double aspect, mat4 vp, mat4 inv)
{
    double right[3], hh = c->half_height, hw = hh * aspect, dp = c->depth;
    cross3(c->forward, c->up, right);
    const double *rows[3] = {right, c->up, c->forward};
    double scale[3] = {hw, hh, dp};
    memset(vp, 0, sizeof(mat4));
    memset(inv, 0, sizeof(mat4));
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++) {
            vp[i][j] = rows[i][j] / scale[i];
            inv[j][i] = rows[i][j] * scale[i];
        }
        vp[i][3] = -dot3(rows[i], c->centre) / scale[i];
        inv[i][3] = c->centre[i];
    }
    vp[3][3] = inv[3][3] = 1;
}

/* ---- per-fragment matrices ---- */

static pose frag_world(const render *r, int i, const pose *poses)
{
    return pose_compose(poses ? poses[i] : r->frag[i].pose, r->frag[i].home);
}

static void frag_mats(const render *r, int i, const pose *poses, float model[16], float w2t[16],
                      float nmat[9])
{
    pose m = frag_world(r, i, poses);
    pose inv = pose_inverse(m);
    mat4 a, b;
    mat4_from_pose(a, &m);
    mat4_to_gl(a, model);
    mat4_from_pose(b, &inv);
    const render_frag *f = &r->frag[i];
    for (int k = 0; k < 3; k++) {
        for (int j = 0; j < 4; j++)
            b[k][j] *= f->local_to_tc[k];
        b[k][3] += 0.5 / f->dim[k];
    }
    mat4_to_gl(b, w2t);
    for (int c = 0; c < 3; c++)
        for (int rr = 0; rr < 3; rr++)
            nmat[c * 3 + rr] = (float)(a[rr][c] / f->spacing[c]);
}

static int loc(const render *r, unsigned prog, const char *name)
{
    return r->gl.GetUniformLocation(prog, name);
}

/* Binds the fragments' volumes to units 0.. and sets the uniforms both volume programs share. */
static void set_frag_uniforms(render *r, unsigned prog, int ray, const pose *poses, const int vp[4])
{
    float w2t[RENDER_MAX_FRAGS][16], nmat[RENDER_MAX_FRAGS][9], col[RENDER_MAX_FRAGS][3], model[16];
    float occ_scale[RENDER_MAX_FRAGS][3];
    int units[RENDER_MAX_FRAGS], occ_info[RENDER_MAX_FRAGS][4];
    for (int i = 0; i < RENDER_MAX_FRAGS; i++)
        units[i] = i;
    for (int i = 0; i < r->nfrag; i++) {
        const render_frag *f = &r->frag[i];
        frag_mats(r, i, poses, model, w2t[i], nmat[i]);
        for (int a = 0; a < 3; a++) {
            col[i][a] = f->rgb[a];
            occ_scale[i][a] = (float)f->dim[a] / RENDER_BLOCK;
            occ_info[i][a] = f->occ_dim[a];
        }
        occ_info[i][3] = f->occ_z;
        r->gl.ActiveTexture(GL_TEXTURE0 + (unsigned)i);
        r->gl.BindTexture(GL_TEXTURE_3D, f->tex);
    }
    if (!ray) /* the raycaster has its count compiled in */
        r->gl.Uniform1i(loc(r, prog, "nfrag"), r->nfrag);
    r->gl.Uniform4f(loc(r, prog, "viewport"), (float)vp[0], (float)vp[1], (float)vp[2], (float)vp[3]);
    r->gl.Uniform1iv(loc(r, prog, "vol"), ray ? (r->nfrag ? r->nfrag : 1) : RENDER_MAX_FRAGS, units);
    r->gl.Uniform3fv(loc(r, prog, "bg"), 1, BG);
    if (r->nfrag == 0)
        return;
    r->gl.UniformMatrix4fv(loc(r, prog, "w2t"), r->nfrag, GL_FALSE, &w2t[0][0]);
    r->gl.Uniform3fv(loc(r, prog, "colour"), r->nfrag, &col[0][0]);
    if (!ray)
        return;
    r->gl.UniformMatrix3fv(loc(r, prog, "nmat"), r->nfrag, GL_FALSE, &nmat[0][0]);
    r->gl.Uniform3fv(loc(r, prog, "occ_scale"), r->nfrag, &occ_scale[0][0]);
    r->gl.Uniform4iv(loc(r, prog, "occ_info"), r->nfrag, &occ_info[0][0]);
}

/* ---- the 3D view ---- */

/* Whether a frame of o shows the contacts overlay as a colour on the surfaces: in surface mode,
 * and in iso where the GL has a texture unit for every fragment's distance map besides the
 * raycaster's; else the colliding voxels are tinted. */
static int gap_colour(const render *r, const render_options *o)
{
    if (!(o->overlays & RENDER_OVERLAY_CONTACTS) || !r->nfrag || !r->frag[0].dist_tex)
        return 0;
    int units = 0;
    r->gl.GetIntegerv(GL_MAX_TEXTURE_IMAGE_UNITS, &units);
    return o->mode == RENDER_SURFACE || (o->mode == RENDER_ISO && UNIT_DIST + r->nfrag <= units);
}

/* The contacts colour's uniforms of program p (bound, GAP_GLSL's): the distance maps of every
 * fragment but skip (-1: none) at their poses, bound to units unit0.., and their w2t. */
static void gap_uniforms(render *r, unsigned p, const pose *poses, int skip, int unit0)
{
    float w2t[RENDER_MAX_FRAGS][16], box[RENDER_MAX_FRAGS][3], off[RENDER_MAX_FRAGS], model[16], nmat[9];
    int units[RENDER_MAX_FRAGS], n = 0;
    for (int i = 0; i < r->nfrag; i++) {
        if (i == skip)
            continue;
        const render_frag *f = &r->frag[i];
        frag_mats(r, i, poses, model, w2t[n], nmat);
        double least = f->spacing[0];
        for (int a = 0; a < 3; a++) {
            box[n][a] = (float)(f->dim[a] * f->spacing[a]);
            least = f->spacing[a] < least ? f->spacing[a] : least;
        }
        off[n] = (float)(0.5 * least);
        units[n] = unit0 + n;
        r->gl.ActiveTexture(GL_TEXTURE0 + (unsigned)(unit0 + n));
        r->gl.BindTexture(GL_TEXTURE_3D, f->dist_tex);
        n++;
    }
    r->gl.Uniform1iv(loc(r, p, "dist"), n, units);
    r->gl.UniformMatrix4fv(loc(r, p, "w2t"), n, GL_FALSE, &w2t[0][0]);
    r->gl.Uniform3fv(loc(r, p, "box_mm"), n, &box[0][0]);
    r->gl.Uniform1fv(loc(r, p, "dist_off"), n, off);
    r->gl.Uniform3fv(loc(r, p, "ramp"), 2, &render__gap_ramp[0][0]);
    r->gl.Uniform1f(loc(r, p, "gap_scale"), (float)RENDER_GAP_SCALE_MM);
}


/* The cut-away kept for fragment `keep` at poses (render__mesh_fs's cut and cut_front): its
 * centroid, the radius (3/8 of its crop's diagonal), and how far in front of the centroid (along
 * forward, negative) its crop's nearest corner lies: only what lies in front of that is cut. */
static void cutaway(const render *r, int keep, const pose *poses, const double forward[3], float cut[4],
                    float *front)
{
    const render_frag *f = &r->frag[keep];
    const pose *at = poses ? &poses[keep] : &f->pose;
    pose m = frag_world(r, keep, poses);
    double c[3], d2 = 0, near = 0;
    pose_apply(at, f->centroid, c);
    for (int b = 0; b < 8; b++) {
        double x[3], w[3];
        for (int a = 0; a < 3; a++)
            x[a] = ((b >> a & 1) ? f->dim[a] - 0.5 : -0.5) * f->spacing[a];
        pose_apply(&m, x, w);
        double along = (w[0] - c[0]) * forward[0] + (w[1] - c[1]) * forward[1] + (w[2] - c[2]) * forward[2];
        near = along < near ? along : near;
    }
    for (int a = 0; a < 3; a++) {
        cut[a] = (float)c[a];
        d2 += 0.25 * (f->dim[a] * f->spacing[a]) * (f->dim[a] * f->spacing[a]);
    }
    cut[3] = (float)(0.75 * sqrt(d2));
    *front = (float)near;
}

/* The cut-away's uniforms (cut, cut_front) of program p (bound) for the fragment drawn, `drawn`
 * (-1: the raycaster, which draws them all and keeps cut_keep's): none when o keeps no fragment
 * or keeps the one drawn. */
static void cutaway_uniforms(render *r, unsigned p, const pose *poses, const render_options *o, int drawn)
{
    float cut[4] = {0, 0, 0, 0}, front = 0;
    int keep = o->cutaway - 1;
    if (keep >= 0 && keep < r->nfrag && keep != drawn)
        cutaway(r, keep, poses, o->camera.forward, cut, &front);
    r->gl.Uniform4fv(loc(r, p, "cut"), 1, cut);
    r->gl.Uniform1f(loc(r, p, "cut_front"), front);
    if (drawn < 0)
        r->gl.Uniform1i(loc(r, p, "cut_keep"), cut[3] > 0 ? keep : -1);
}

/* Each fragment's span of occupied bricks into span_tex (within the viewport and scissor already
 * set), then one ray per pixel through the spans. */
static int draw_raycast(render *r, const pose *poses, const render_options *o, const int vp[4],
                        const mat4 vpm, const mat4 inv)
{
    unsigned pd = r->prog_depth;
    float m[16], vpf[16], model[16], w2t[16], nmat[9];
    if (r->nfrag == 0)
        return 0;
    unsigned p;
    int cut = o->cutaway >= 1 && o->cutaway <= r->nfrag;
    int gaps = gap_colour(r, o), rc = render__ray_program(r, o->mode, gaps, cut, &p);
    if (rc)
        return rc;
    mat4_to_gl(vpm, vpf);
    r->gl.UseProgram(pd);
    r->gl.UniformMatrix4fv(loc(r, pd, "vp"), 1, GL_FALSE, vpf);
    r->gl.BindFramebuffer(GL_FRAMEBUFFER, r->span_fbo);
    r->gl.Enable(GL_BLEND);
    for (int k = 0; k < 2; k++) {
        r->gl.BlendEquation(k ? GL_MAX : GL_MIN);
        r->gl.Uniform1f(loc(r, pd, "fill"), k ? 0.0f : 1.0f);
        r->gl.ClearColor(k ? 0.0f : 1.0f, k ? 0.0f : 1.0f, k ? 0.0f : 1.0f, k ? 0.0f : 1.0f);
        for (int layer = 0; layer < r->span_layers; layer++) {
            r->gl.FramebufferTextureLayer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, r->span_tex[k], 0, layer);
            r->gl.Clear(GL_COLOR_BUFFER_BIT);
            for (int i = layer * 4; i < r->nfrag && i < layer * 4 + 4; i++) {
                frag_mats(r, i, poses, model, w2t, nmat);
                r->gl.UniformMatrix4fv(loc(r, pd, "model"), 1, GL_FALSE, model);
                r->gl.Uniform1i(loc(r, pd, "comp"), i & 3);
                r->gl.BindVertexArray(r->frag[i].proxy_vao);
                r->gl.DrawArrays(GL_TRIANGLES, 0, r->frag[i].proxy_vertices);
            }
        }
    }
    r->gl.BlendEquation(GL_FUNC_ADD);
    r->gl.Disable(GL_BLEND);
    r->gl.BindFramebuffer(GL_FRAMEBUFFER, 0);
    r->gl.ClearColor(BG[0], BG[1], BG[2], 1);
    /* The bricks once more, depth only, into the target's depth buffer (cleared to 1 at the
     * frame's start); the ray's triangle lies at depth 1 and passes only where it is greater, so
     * llvmpipe's early depth test skips the blocks of pixels that no brick covers (they keep the
     * frame's clear colour, the background the shader would have written) before any of the
     * shader runs: it has no branches that skip, so such a ray paid for a whole march, its
     * bisection and its shading. */
    r->gl.ColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
    r->gl.Enable(GL_DEPTH_TEST);
    r->gl.DepthFunc(GL_LESS);
    for (int i = 0; i < r->nfrag; i++) {
        frag_mats(r, i, poses, model, w2t, nmat);
        r->gl.UniformMatrix4fv(loc(r, pd, "model"), 1, GL_FALSE, model);
        r->gl.BindVertexArray(r->frag[i].proxy_vao);
        r->gl.DrawArrays(GL_TRIANGLES, 0, r->frag[i].proxy_vertices);
    }
    r->gl.ColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    for (int k = 0; k < 2; k++) {
        r->gl.ActiveTexture(GL_TEXTURE0 + UNIT_NEAR + (unsigned)k);
        r->gl.BindTexture(GL_TEXTURE_2D_ARRAY, r->span_tex[k]);
    }
    r->gl.UseProgram(p);
    set_frag_uniforms(r, p, 1, poses, vp);
    r->gl.ActiveTexture(GL_TEXTURE0 + UNIT_OCC);
    r->gl.BindTexture(GL_TEXTURE_3D, r->occ_tex);
    r->gl.ActiveTexture(GL_TEXTURE0 + UNIT_TF);
    r->gl.BindTexture(GL_TEXTURE_1D, r->tf_tex);
    r->gl.Uniform1i(loc(r, p, "occ"), UNIT_OCC);
    r->gl.Uniform1i(loc(r, p, "tf"), UNIT_TF);
    mat4_to_gl(inv, m);
    r->gl.UniformMatrix4fv(loc(r, p, "inv_vp"), 1, GL_FALSE, m);
    r->gl.Uniform2f(loc(r, p, "tf_range"), (float)(r->iso_hu - 500), (float)(r->iso_hu + 1500));
    r->gl.Uniform1f(loc(r, p, "iso"), (float)r->iso_hu);
    r->gl.Uniform1f(loc(r, p, "step_fine"), (float)r->min_spacing);
    r->gl.Uniform1f(loc(r, p, "step_coarse"), (float)(0.9 * RENDER_BLOCK * r->min_spacing));
    /* From a point outside every occupied (dilated) block, no voxel of a label is within 3.5
     * voxels, so no sample reaches the level within 2.5. */
    r->gl.Uniform1f(loc(r, p, "entry_skip"), (float)(2.5 * r->min_spacing));
    r->gl.Uniform1i(loc(r, p, "near_depth"), UNIT_NEAR);
    r->gl.Uniform1i(loc(r, p, "far_depth"), UNIT_FAR);
    cutaway_uniforms(r, p, poses, o, -1);
    if (gaps)
        gap_uniforms(r, p, poses, -1, UNIT_DIST);
    r->gl.DepthFunc(GL_GREATER);
    r->gl.DepthMask(GL_FALSE);
    r->gl.BindVertexArray(r->vao_empty);
    r->gl.DrawArrays(GL_TRIANGLES, 0, 3);
    r->gl.DepthMask(GL_TRUE);
    r->gl.DepthFunc(GL_LESS);
    r->gl.Disable(GL_DEPTH_TEST);
    r->gl.Clear(GL_DEPTH_BUFFER_BIT); /* back to the frame's clear, for what follows */
    return 0;
}


/* The meshes of the fragments i with (only < 0 or i == only) and i != skip, shaded, or with ids
 * in their flat id colours (render__id_fs). A pass over them all (only < 0) starts on a clear depth
 * buffer; a pass over one (render_frame_late's) draws into the depth of the pass before. */
static void draw_meshes(render *r, const pose *poses, const render_options *o, const mat4 vp, int only, int skip,
                        int ids)
{
    int gaps = !ids && (o->overlays & RENDER_OVERLAY_CONTACTS) && r->prog_gaps;
    unsigned p = ids ? r->prog_id : gaps ? r->prog_gaps : r->prog_mesh;
    float m[16], w2t[16], nmat[9], fw[3];
    r->gl.UseProgram(p);
    mat4_to_gl(vp, m);
    r->gl.UniformMatrix4fv(loc(r, p, "vp"), 1, GL_FALSE, m);
    for (int a = 0; a < 3; a++)
        fw[a] = (float)o->camera.forward[a];
    r->gl.Uniform3fv(loc(r, p, "forward"), 1, fw);
    r->gl.Enable(GL_DEPTH_TEST);
    if (only < 0)
        r->gl.Clear(GL_DEPTH_BUFFER_BIT);
    /* The meshes are closed and wound counter-clockwise from outside: half their triangles face
     * away and are dropped before rasterizing. */
    r->gl.Enable(GL_CULL_FACE);
    r->gl.CullFace(GL_BACK);
    for (int i = 0; i < r->nfrag; i++) {
        if ((only >= 0 && i != only) || i == skip)
            continue;
        frag_mats(r, i, poses, m, w2t, nmat);
        r->gl.UniformMatrix4fv(loc(r, p, "model"), 1, GL_FALSE, m);
        float id[3] = {(float)(i + 1) / 255.0f, 0, 0};
        cutaway_uniforms(r, p, poses, o, i);
        r->gl.Uniform3fv(loc(r, p, "colour"), 1, ids ? id : r->frag[i].rgb);
        if (gaps)
            gap_uniforms(r, p, poses, i, 0);
        r->gl.BindVertexArray(r->frag[i].mesh_vao);
        r->gl.DrawElements(GL_TRIANGLES, (int)(r->frag[i].mesh_triangles * 3), GL_UNSIGNED_INT, (void *)0);
    }
    r->gl.Disable(GL_CULL_FACE);
    r->gl.Disable(GL_DEPTH_TEST);
}

static void draw_surface(render *r, const pose *poses, const render_options *o, const mat4 vp, int only, int skip)
{
    draw_meshes(r, poses, o, vp, only, skip, 0);
}

/* ---- overlays ---- */

typedef struct line_buf {
    float *v;
    size_t n, cap; /* vertices */
} line_buf;

static int line_push(line_buf *b, const double p[3], const float c[3])
{
    if (b->n == b->cap) {
        size_t cap = b->cap ? b->cap * 2 : 1024;
        float *v = realloc(b->v, cap * 6 * sizeof *v);
        if (!v)
            return FN_ENOMEM;
        b->v = v;
        b->cap = cap;
    }
    float *o = b->v + b->n++ * 6;
    for (int a = 0; a < 3; a++) {
        o[a] = (float)p[a];
        o[3 + a] = c[a];
    }
    return 0;
}

static int box_edges(line_buf *b, const double lo[3], const double hi[3], const float c[3])
{
    int rc = 0;
    for (int e = 0; e < 12 && !rc; e++) {
        int axis = e / 4, u = (axis + 1) % 3, v = (axis + 2) % 3;
        double p[3], q[3];
        p[axis] = lo[axis];
        q[axis] = hi[axis];
        p[u] = q[u] = (e & 1) ? hi[u] : lo[u];
        p[v] = q[v] = (e & 2) ? hi[v] : lo[v];
        rc = line_push(b, p, c);
        if (!rc)
            rc = line_push(b, q, c);
    }
    return rc;
}

/* Nodes at `want` depth, and leaves above it, so the boxes cover the fragment. */
static int collect_boxes(line_buf *b, const obb_node *nodes, const double sp[3], uint32_t idx,
                         int depth, int want, const float c[3])
{
    const obb_node *n = &nodes[idx];
    int leaf = (n->info >> 31) & 1;
    if (depth == want || leaf) {
        double lo[3], hi[3];
        for (int a = 0; a < 3; a++) {
            lo[a] = (n->lo[a] - 0.5) * sp[a];
            hi[a] = (n->hi[a] + 0.5) * sp[a];
        }
        return box_edges(b, lo, hi, c);
    }
    uint32_t first = n->info & 0xFFFFFFu, count = ((n->info >> 28) & 7u) + 1;
    int rc = 0;
    for (uint32_t k = 0; k < count && !rc; k++)
        rc = collect_boxes(b, nodes, sp, first + k, depth + 1, want, c);
    return rc;
}

static int ensure_boxes(render *r, render_frag *f, int depth)
{
    if (f->box_vao && f->box_depth == depth)
        return 0;
    line_buf b = {0};
    float c[3];
    for (int a = 0; a < 3; a++)
        c[a] = 0.5f + 0.5f * f->rgb[a];
    int rc = obb_tree_nodes(f->tree) ? collect_boxes(&b, obb_tree_node_array(f->tree), f->spacing, 0, 1,
                                                    depth, c)
                                      : 0;
    if (rc) {
        free(b.v);
        return fn_err_set(FN_ENOMEM, "render: out of memory for the hierarchy's boxes");
    }
    if (!f->box_vao) {
        r->gl.GenVertexArrays(1, &f->box_vao);
        r->gl.GenBuffers(1, &f->box_vbo);
        r->gl.BindVertexArray(f->box_vao);
        r->gl.BindBuffer(GL_ARRAY_BUFFER, f->box_vbo);
        r->gl.VertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), (void *)0);
        r->gl.VertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), (void *)(3 * sizeof(float)));
        r->gl.EnableVertexAttribArray(0);
        r->gl.EnableVertexAttribArray(1);
    }
    r->gl.BindBuffer(GL_ARRAY_BUFFER, f->box_vbo);
    r->gl.BufferData(GL_ARRAY_BUFFER, (GLsizeiptr)(b.n * 6 * sizeof(float)), b.v, GL_STATIC_DRAW);
    f->box_vertices = (int)b.n;
    f->box_depth = depth;
    free(b.v);
    return 0;
}

/* Lines already in world mm (the line program bound): streamed through the shared line buffer. */
static void draw_world_lines(render *r, const line_buf *b)
{
    static const float id[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    if (!b->n)
        return;
    r->gl.UniformMatrix4fv(loc(r, r->prog_line, "model"), 1, GL_FALSE, id);
    r->gl.BindVertexArray(r->line_vao);
    r->gl.BindBuffer(GL_ARRAY_BUFFER, r->line_vbo);
    r->gl.BufferData(GL_ARRAY_BUFFER, (GLsizeiptr)(b->n * 6 * sizeof(float)), b->v, GL_STREAM_DRAW);
    r->gl.DrawArrays(GL_LINES, 0, (int)b->n);
}

/* Each fragment's principal axes at its current pose: red, green, blue for the largest first. */
static int draw_axes(render *r, const pose *poses)
{
    static const float colours[3][3] = {{1, 0.2f, 0.2f}, {0.2f, 1, 0.2f}, {0.3f, 0.5f, 1}};
    line_buf b = {0};
    int rc = 0;
    for (int i = 0; i < r->nfrag && !rc; i++) {
        const render_frag *f = &r->frag[i];
        const pose *p = poses ? &poses[i] : &f->pose;
        for (int k = 0; k < 3 && !rc; k++) {
            double len = 2.0 * sqrt(f->eigval[k] > 0 ? f->eigval[k] : 0), a[3], c[3], wa[3], wc[3];
            for (int d = 0; d < 3; d++) {
                a[d] = f->centroid[d] - len * f->axes[d][k];
                c[d] = f->centroid[d] + len * f->axes[d][k];
            }
            pose_apply(p, a, wa);
            pose_apply(p, c, wc);
            rc = line_push(&b, wa, colours[k]);
            if (!rc)
                rc = line_push(&b, wc, colours[k]);
        }
    }
    if (!rc)
        draw_world_lines(r, &b);
    free(b.v);
    return rc ? fn_err_set(FN_ENOMEM, "render: out of memory for the axes overlay") : 0;
}

/* One voxel's box outline at world placement m. */
static int voxel_box(line_buf *b, const pose *m, const uint16_t v[3], const double sp[3], const float c[3])
{
    int rc = 0;
    for (int e = 0; e < 12 && !rc; e++) {
        int axis = e / 4, u = (axis + 1) % 3, w = (axis + 2) % 3;
        double p[2][3], q[3];
        for (int end = 0; end < 2; end++) {
            double l[3];
            l[axis] = (v[axis] + (end ? 0.5 : -0.5)) * sp[axis];
            l[u] = (v[u] + ((e & 1) ? 0.5 : -0.5)) * sp[u];
            l[w] = (v[w] + ((e & 2) ? 0.5 : -0.5)) * sp[w];
            pose_apply(m, l, q);
            memcpy(p[end], q, sizeof q);
        }
        rc = line_push(b, p[0], c);
        if (!rc)
            rc = line_push(b, p[1], c);
    }
    return rc;
}

/* One voxel's box as 12 triangles at world placement m (the contact tint). */
static int voxel_solid(line_buf *b, const pose *m, const uint16_t v[3], const double sp[3], const float c[3])
{
    static const int quad[6] = {0, 1, 3, 0, 3, 2};
    int rc = 0;
    for (int f = 0; f < 6 && !rc; f++) {
        int axis = f / 2, u = (axis + 1) % 3, w = (axis + 2) % 3;
        for (int k = 0; k < 6 && !rc; k++) {
            double l[3], q[3];
            l[axis] = (v[axis] + ((f & 1) ? 0.5 : -0.5)) * sp[axis];
            l[u] = (v[u] + ((quad[k] & 1) ? 0.5 : -0.5)) * sp[u];
            l[w] = (v[w] + ((quad[k] & 2) ? 0.5 : -0.5)) * sp[w];
            pose_apply(m, l, q);
            rc = line_push(b, q, c);
        }
    }
    return rc;
}

/* Both voxels of every colliding voxel pair, for every pair of fragments: a translucent tint,
 * then outlines. */
static int draw_contacts(render *r, const pose *poses)
{
    static const float yellow[3] = {1, 0.9f, 0.1f};
    obb_pair *pairs = malloc(RENDER_MAX_CONTACTS * sizeof *pairs);
    line_buf b = {0}, tint = {0};
    int rc = pairs ? 0 : FN_ENOMEM;
    for (int i = 0; i < r->nfrag && !rc; i++)
        for (int j = i + 1; j < r->nfrag && !rc; j++) {
            pose wi = frag_world(r, i, poses), wj = frag_world(r, j, poses);
            obb_query q = {.want_pairs = 1, .pairs = pairs, .max_pairs = RENDER_MAX_CONTACTS};
            obb_result res;
            rc = obb_collide(r->frag[i].tree, &wi, r->frag[j].tree, &wj, &q, NULL, &res);
            for (size_t k = 0; k < res.npairs && !rc; k++) {
                rc = voxel_box(&b, &wi, pairs[k].a, r->frag[i].spacing, yellow);
                if (!rc)
                    rc = voxel_box(&b, &wj, pairs[k].b, r->frag[j].spacing, yellow);
                if (!rc)
                    rc = voxel_solid(&tint, &wi, pairs[k].a, r->frag[i].spacing, yellow);
                if (!rc)
                    rc = voxel_solid(&tint, &wj, pairs[k].b, r->frag[j].spacing, yellow);
            }
        }
    if (!rc && tint.n) {
        static const float id[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
        r->gl.UniformMatrix4fv(loc(r, r->prog_line, "model"), 1, GL_FALSE, id);
        r->gl.Uniform1f(loc(r, r->prog_line, "alpha"), 0.45f);
        r->gl.Enable(GL_BLEND);
        r->gl.BlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
        r->gl.BindVertexArray(r->line_vao);
        r->gl.BindBuffer(GL_ARRAY_BUFFER, r->line_vbo);
        r->gl.BufferData(GL_ARRAY_BUFFER, (GLsizeiptr)(tint.n * 6 * sizeof(float)), tint.v, GL_STREAM_DRAW);
        r->gl.DrawArrays(GL_TRIANGLES, 0, (int)tint.n);
        r->gl.Disable(GL_BLEND);
        r->gl.Uniform1f(loc(r, r->prog_line, "alpha"), 1.0f);
    }
    free(tint.v);
    if (!rc)
        draw_world_lines(r, &b);
    free(b.v);
    free(pairs);
    if (rc == FN_ENOMEM)
        return fn_err_set(FN_ENOMEM, "render: out of memory for the contacts overlay");
    return rc;
}

/* The VOI boxes (world mm) in cyan. */
static int draw_voi(render *r, const render_options *o)
{
    static const float cyan[3] = {0.2f, 0.95f, 1.0f};
    line_buf b = {0};
    int rc = 0;
    for (int i = 0; i < o->nvoi && i < RENDER_MAX_FRAGS && !rc; i++)
        rc = box_edges(&b, o->voi[i], o->voi[i] + 3, cyan);
    if (!rc)
        draw_world_lines(r, &b);
    free(b.v);
    return rc ? fn_err_set(FN_ENOMEM, "render: out of memory for the VOI overlay") : 0;
}

/* The ghost (render_options.ghost): the fragment's mesh again at ghost_pose, translucent, over
 * everything, so it shows in every mode. */
static void draw_ghost(render *r, const pose *poses, const render_options *o, const mat4 vp)
{
    int g = o->ghost - 1;
    pose at[RENDER_MAX_FRAGS];
    memcpy(at, poses, sizeof(pose) * (size_t)r->nfrag);
    at[g] = o->ghost_pose;
    unsigned p = r->prog_mesh;
    float m[16], w2t[16], nmat[9], fw[3], cut[4] = {0, 0, 0, 0};
    static const float light[3] = {0.85f, 0.95f, 1.0f};
    r->gl.UseProgram(p);
    mat4_to_gl(vp, m);
    r->gl.UniformMatrix4fv(loc(r, p, "vp"), 1, GL_FALSE, m);
    for (int a = 0; a < 3; a++)
        fw[a] = (float)o->camera.forward[a];
    r->gl.Uniform3fv(loc(r, p, "forward"), 1, fw);
    frag_mats(r, g, at, m, w2t, nmat);
    r->gl.UniformMatrix4fv(loc(r, p, "model"), 1, GL_FALSE, m);
    r->gl.Uniform4fv(loc(r, p, "cut"), 1, cut);
    r->gl.Uniform1f(loc(r, p, "cut_front"), 0);
    r->gl.Uniform3fv(loc(r, p, "colour"), 1, light);
    r->gl.Uniform1f(loc(r, p, "alpha"), 0.35f);
    r->gl.Enable(GL_BLEND);
    r->gl.BlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
    r->gl.Enable(GL_CULL_FACE);
    r->gl.CullFace(GL_BACK);
    r->gl.BindVertexArray(r->frag[g].mesh_vao);
    r->gl.DrawElements(GL_TRIANGLES, (int)(r->frag[g].mesh_triangles * 3), GL_UNSIGNED_INT, (void *)0);
    r->gl.Disable(GL_CULL_FACE);
    r->gl.Disable(GL_BLEND);
    r->gl.Uniform1f(loc(r, p, "alpha"), 1.0f);
}

static int draw_overlays(render *r, const pose *poses, const render_options *o, const mat4 vp)
{
    unsigned p = r->prog_line;
    float m[16], w2t[16], nmat[9];
    r->gl.UseProgram(p);
    mat4_to_gl(vp, m);
    r->gl.UniformMatrix4fv(loc(r, p, "vp"), 1, GL_FALSE, m);
    r->gl.Uniform1i(loc(r, p, "use_tint"), 0);
    r->gl.Uniform1f(loc(r, p, "alpha"), 1.0f);
    int rc = 0;
    if ((o->overlays & (RENDER_OVERLAY_HIERARCHY | RENDER_OVERLAY_CONTACTS)) && r->nfrag && !r->frag[0].tree)
        return fn_err_set(FN_EINVAL, "render: the hierarchy and contacts overlays need the scene's "
                                     "hierarchies (render_set_scene without hp)");
    if (o->overlays & RENDER_OVERLAY_HIERARCHY)
        for (int i = 0; i < r->nfrag && !rc; i++) {
            render_frag *f = &r->frag[i];
            rc = ensure_boxes(r, f, o->hierarchy_depth);
            frag_mats(r, i, poses, m, w2t, nmat);
            r->gl.UniformMatrix4fv(loc(r, p, "model"), 1, GL_FALSE, m);
            r->gl.BindVertexArray(f->box_vao);
            r->gl.DrawArrays(GL_LINES, 0, f->box_vertices);
        }
    if (!rc && (o->overlays & RENDER_OVERLAY_CONTACTS) && !gap_colour(r, o))
        rc = draw_contacts(r, poses);
    if (!rc && (o->overlays & RENDER_OVERLAY_AXES))
        rc = draw_axes(r, poses);
    if (!rc && (o->overlays & RENDER_OVERLAY_VOI))
        rc = draw_voi(r, o);
    if (!rc && poses && o->ghost > 0 && o->ghost <= r->nfrag)
        draw_ghost(r, poses, o, vp);
    return rc;
}

static int draw_3d(render *r, const pose *poses, const render_options *o, const int vp[4])
{
    mat4 m, inv;
    camera_mats(&o->camera, (double)vp[2] / vp[3], m, inv);
    int rc = 0, gaps = gap_colour(r, o);
    if (gaps && o->mode == RENDER_SURFACE && r->nfrag > 1)
        rc = render__gaps_program(r);
    if (!rc && o->mode == RENDER_SURFACE)
        draw_surface(r, poses, o, m, -1, -1);
    else if (!rc)
        rc = draw_raycast(r, poses, o, vp, m, inv);
    rc = rc ? rc : draw_overlays(r, poses, o, m);
    if (!rc && gaps) {
        rc = render__gap_legend(r, vp);
        r->gl.Viewport(vp[0], vp[1], vp[2], vp[3]);
        r->gl.Scissor(vp[0], vp[1], vp[2], vp[3]);
        r->gl.Enable(GL_SCISSOR_TEST);
    }
    return rc;
}

/* ---- slices ---- */

static const struct {
    double u[3], v[3], n[3];
} planes[3] = {
    {{1, 0, 0}, {0, -1, 0}, {0, 0, 1}}, /* axial: anterior up, patient left on the right */
    {{1, 0, 0}, {0, 0, 1}, {0, 1, 0}},  /* coronal */
    {{0, 1, 0}, {0, 0, 1}, {1, 0, 0}},  /* sagittal: as seen from the patient's left */
};

static void draw_slice(render *r, const pose *poses, const render_options *o, int which, const int vp[4])
{
    unsigned p = r->prog_slice;
    r->gl.UseProgram(p);
    set_frag_uniforms(r, p, 0, poses, vp);
    double hh = o->camera.half_height, hw = hh * vp[2] / vp[3];
    float centre[3], u[3], v[3], m[16];
    double off = dot3(planes[which].n, o->slice_point) - dot3(planes[which].n, o->camera.centre);
    for (int a = 0; a < 3; a++) {
        centre[a] = (float)(o->camera.centre[a] + off * planes[which].n[a]);
        u[a] = (float)(planes[which].u[a] * hw);
        v[a] = (float)(planes[which].v[a] * hh);
    }
    r->gl.Uniform3fv(loc(r, p, "centre"), 1, centre);
    r->gl.Uniform3fv(loc(r, p, "axis_u"), 1, u);
    r->gl.Uniform3fv(loc(r, p, "axis_v"), 1, v);
    r->gl.Uniform1i(loc(r, p, "have_ct"), r->have_ct);
    r->gl.Uniform2f(loc(r, p, "window"), -500.0f, 1300.0f);
    r->gl.Uniform1f(loc(r, p, "iso"), (float)r->iso_hu);
    r->gl.ActiveTexture(GL_TEXTURE0 + UNIT_CT);
    r->gl.BindTexture(GL_TEXTURE_3D, r->ct_tex);
    r->gl.Uniform1i(loc(r, p, "ct"), UNIT_CT);
    mat4_to_gl(r->ct_w2t, m);
    r->gl.UniformMatrix4fv(loc(r, p, "ct_w2t"), 1, GL_FALSE, m);
    r->gl.BindVertexArray(r->vao_empty);
    r->gl.DrawArrays(GL_TRIANGLES, 0, 3);
}

/* The marks near slice `which` (o->marks within RENDER_MARK_MM of its plane), each a square of
 * RENDER_MARK_PX pixels in its colour ringed in black, drawn by clearing scissor boxes inside the
 * pane's viewport vp (the inverse of render_slice_point_at). */
static void draw_marks(render *r, const render_options *o, int which, const int vp[4])
{
    double hh = o->camera.half_height, hw = hh * vp[2] / vp[3];
    double off = dot3(planes[which].n, o->slice_point) - dot3(planes[which].n, o->camera.centre);
    for (int m = 0; m < o->nmarks && m < RENDER_MAX_MARKS; m++) {
        const double *x = o->marks[m];
        if (!(fabs(dot3(planes[which].n, x) - dot3(planes[which].n, o->slice_point)) <= RENDER_MARK_MM))
            continue;
        double d[3];
        for (int a = 0; a < 3; a++)
            d[a] = x[a] - (o->camera.centre[a] + off * planes[which].n[a]);
        double sx = dot3(d, planes[which].u) / hw, sy = dot3(d, planes[which].v) / hh;
        if (!(fabs(sx) <= 1 && fabs(sy) <= 1))
            continue;
        int cx = vp[0] + (int)floor((sx + 1) / 2 * vp[2]), cy = vp[1] + (int)floor((sy + 1) / 2 * vp[3]);
        for (int ring = 1; ring >= 0; ring--) {
            int half = RENDER_MARK_PX / 2 + ring, box[4] = {cx - half, cy - half, 2 * half + 1, 2 * half + 1};
            for (int a = 0; a < 2; a++) { /* inside the pane */
                int lo = box[a] > vp[a] ? box[a] : vp[a], hi = box[a] + box[a + 2];
                hi = hi < vp[a] + vp[a + 2] ? hi : vp[a] + vp[a + 2];
                box[a] = lo;
                box[a + 2] = hi - lo;
            }
            if (box[2] <= 0 || box[3] <= 0)
                break;
            r->gl.Scissor(box[0], box[1], box[2], box[3]);
            const unsigned char *c = o->mark_rgb[m];
            r->gl.ClearColor(ring ? 0 : c[0] / 255.0f, ring ? 0 : c[1] / 255.0f, ring ? 0 : c[2] / 255.0f, 1);
            r->gl.Clear(GL_COLOR_BUFFER_BIT);
        }
    }
    r->gl.Scissor(vp[0], vp[1], vp[2], vp[3]);
    r->gl.ClearColor(BG[0], BG[1], BG[2], 1);
}

/* ---- frames ---- */

static void set_viewport(render *r, const int vp[4])
{
    r->gl.Viewport(vp[0], vp[1], vp[2], vp[3]);
    r->gl.Scissor(vp[0], vp[1], vp[2], vp[3]);
}

/* The start of every frame: the whole target cleared, scissored to the viewport. */
static void frame_start(render *r)
{
    r->gl.Enable(GL_SCISSOR_TEST);
    int full[4] = {0, 0, r->w, r->h};
    set_viewport(r, full);
    r->gl.ClearColor(BG[0], BG[1], BG[2], 1);
    r->gl.Clear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
}

/* The end of every frame: GL state back, and its errors. */
static int frame_end(render *r, int rc)
{
    r->gl.Disable(GL_SCISSOR_TEST);
    r->gl.BindVertexArray(0);
    r->gl.UseProgram(0);
    unsigned e = r->gl.GetError();
    if (!rc && e != GL_NO_ERROR)
        rc = fn_err_set(e == GL_OUT_OF_MEMORY ? FN_ENOMEM : FN_ENODEV, "render: GL error 0x%04x drawing a frame", e);
    return rc;
}

void render_four_up_panes(int w, int h, double split, int rect[4][4])
{
    /* The 3D view over `split` of the height (0: two thirds); the slices side by side below it,
     * one pixel of background between the panes. */
    split = split <= 0 ? 0 : split < RENDER_SPLIT_MIN ? RENDER_SPLIT_MIN : split > RENDER_SPLIT_MAX ? RENDER_SPLIT_MAX : split;
    int hs = split > 0 ? (int)lround(h * (1 - split)) : h / 3, w3 = w / 3;
    const int panes[4][4] = {{0, h - hs, w3 - 1, hs}, {w3, h - hs, w3 - 1, hs}, {2 * w3, h - hs, w - 2 * w3, hs},
                             {0, 0, w, h - hs - 1}};
    memcpy(rect, panes, sizeof panes);
}

/* Pane v of the four-up layout as a GL viewport (origin at the bottom left). */
static void pane_viewport(const render *r, const render_options *o, int v, int vp[4])
{
    int rect[4][4];
    render_four_up_panes(r->w, r->h, o->four_up_split, rect);
    vp[0] = rect[v][0];
    vp[1] = r->h - rect[v][1] - rect[v][3];
    vp[2] = rect[v][2];
    vp[3] = rect[v][3];
}

void render_slice_normal(int pane, double n[3])
{
    memcpy(n, planes[pane].n, 3 * sizeof *n);
}

int render_slice_point_at(const render *r, const render_options *o, double x, double y, double world[3])
{
    int rect[4][4];
    render_four_up_panes(r->w, r->h, o->four_up_split, rect);
    for (int s = 0; s < 3; s++) {
        const int *q = rect[s];
        if (x < q[0] || x >= q[0] + q[2] || y < q[1] || y >= q[1] + q[3])
            continue;
        /* As draw_slice: the pane's centre is the camera's centre moved onto the plane. */
        double hh = o->camera.half_height, hw = hh * q[2] / q[3];
        double sx = 2.0 * (x - q[0]) / q[2] - 1, sy = 1 - 2.0 * (y - q[1]) / q[3];
        double off = dot3(planes[s].n, o->slice_point) - dot3(planes[s].n, o->camera.centre);
        for (int a = 0; a < 3; a++)
            world[a] = o->camera.centre[a] + off * planes[s].n[a] + planes[s].u[a] * hw * sx + planes[s].v[a] * hh * sy;
        return s;
    }
    return -1;
}

int render_frame(render *r, const pose *poses, const render_options *o)
{
    r->early_late = -1;
    if ((unsigned)o->mode > RENDER_SURFACE)
        return fn_err_set(FN_EINVAL, "render: mode %d is not one of iso, dvr, mip, surface", (int)o->mode);
    frame_start(r);
    int rc = 0, full[4] = {0, 0, r->w, r->h};
    if (o->layout == RENDER_LAYOUT_3D) {
        rc = draw_3d(r, poses, o, full);
    } else {
        int vp[4];
        for (int s = 0; s < 3; s++) {
            pane_viewport(r, o, s, vp);
            set_viewport(r, vp);
            draw_slice(r, poses, o, s, vp);
            draw_marks(r, o, s, vp);
        }
        pane_viewport(r, o, RENDER_PANE_3D, vp);
        set_viewport(r, vp);
        rc = draw_3d(r, poses, o, vp);
    }
    return frame_end(r, rc);
}

/* Whether a frame of o can be split: surface meshes in the 3D layout, and no contacts (a pair's). */
static int splits(const render_options *o)
{
    return o->mode == RENDER_SURFACE && o->layout == RENDER_LAYOUT_3D && !(o->overlays & RENDER_OVERLAY_CONTACTS);
}

int render_frame_early(render *r, const pose *poses, int late, const render_options *o)
{
    r->early_late = -1;
    if (!poses || late < 0 || late >= r->nfrag || !splits(o))
        return 0;
    mat4 m, inv;
    camera_mats(&o->camera, (double)r->w / r->h, m, inv);
    frame_start(r);
    draw_surface(r, poses, o, m, -1, late);
    int rc = frame_end(r, 0);
    r->gl.Flush(); /* the GL rasterizes these while the caller reads the newest pose */
    if (!rc) {
        r->early_late = late;
        memcpy(r->early_pose, poses, (size_t)r->nfrag * sizeof *poses);
    }
    return rc;
}

int render_frame_late(render *r, const pose *poses, const render_options *o)
{
    int late = r->early_late, same = late >= 0 && poses && splits(o);
    for (int i = 0; same && i < r->nfrag; i++)
        same = i == late || !memcmp(&poses[i], &r->early_pose[i], sizeof poses[i]);
    if (!same)
        return render_frame(r, poses, o);
    r->early_late = -1;
    mat4 m, inv;
    camera_mats(&o->camera, (double)r->w / r->h, m, inv);
    r->gl.Enable(GL_SCISSOR_TEST);
    draw_surface(r, poses, o, m, late, -1);
    return frame_end(r, draw_overlays(r, poses, o, m));
}

int render_read_rgb(render *r, uint8_t *rgb)
{
    size_t row = (size_t)r->w * 3;
    uint8_t *tmp = malloc(row * (size_t)r->h);
    if (!tmp)
        return fn_err_set(FN_ENOMEM, "render: out of memory reading a %dx%d frame", r->w, r->h);
    r->gl.PixelStorei(GL_PACK_ALIGNMENT, 1);
    r->gl.ReadPixels(0, 0, r->w, r->h, GL_RGB, GL_UNSIGNED_BYTE, tmp);
    for (int y = 0; y < r->h; y++)
        memcpy(rgb + (size_t)y * row, tmp + (size_t)(r->h - 1 - y) * row, row);
    free(tmp);
    unsigned e = r->gl.GetError();
    return e == GL_NO_ERROR ? 0 : fn_err_set(FN_ENODEV, "render: GL error 0x%04x reading the frame", e);
}

int render_present(render *r)
{
    return r->plat->present(r);
}

/* One pass of fragment ids through cam (all fragments, or `only`), counted per fragment into n
 * (zeroed first). id: room for w * h bytes. */
static int id_pass(render *r, const pose *poses, const render_options *o, int only, uint8_t *id, long *n)
{
    const render_camera *cam = &o->camera;
    mat4 vp, inv;
    camera_mats(cam, (double)r->w / r->h, vp, inv);
    int full[4] = {0, 0, r->w, r->h};
    set_viewport(r, full);
    r->gl.ClearColor(0, 0, 0, 1);
    r->gl.Clear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
    draw_meshes(r, poses, o, vp, only, -1, 1);
    r->gl.PixelStorei(GL_PACK_ALIGNMENT, 1);
    r->gl.ReadPixels(0, 0, r->w, r->h, GL_RED, GL_UNSIGNED_BYTE, id);
    memset(n, 0, (size_t)r->nfrag * sizeof *n);
    for (size_t k = 0; k < (size_t)r->w * (size_t)r->h; k++)
        if (id[k] && id[k] <= r->nfrag)
            n[id[k] - 1]++;
    return frame_end(r, 0);
}

int render_fragment_pixels(render *r, const pose *poses, const render_options *o, long *projected, long *visible)
{
    uint8_t *id = malloc((size_t)r->w * (size_t)r->h);
    if (!id)
        return fn_err_set(FN_ENOMEM, "render: out of memory counting a %dx%d frame's pixels", r->w, r->h);
    long n[RENDER_MAX_FRAGS];
    int rc = id_pass(r, poses, o, -1, id, visible);
    for (int i = 0; i < r->nfrag && !rc; i++) {
        rc = id_pass(r, poses, o, i, id, n);
        projected[i] = n[i];
    }
    free(id);
    return rc;
}

/* The camera looking along f (unit) at centre: up is superior, or anterior when f is nearly along
 * the body's axis. */
static void look_along(render_camera *c, const double f[3])
{
    double up[3] = {0, 0, 1}, d;
    if (fabs(f[2]) > 0.9)
        up[1] = -1, up[2] = 0;
    d = up[0] * f[0] + up[1] * f[1] + up[2] * f[2];
    double n = 0;
    for (int a = 0; a < 3; a++) {
        c->forward[a] = f[a];
        c->up[a] = up[a] - d * f[a];
        n += c->up[a] * c->up[a];
    }
    for (int a = 0; a < 3; a++)
        c->up[a] /= sqrt(n);
}

int render_camera_auto(render *r, render_camera *c, const frag *frags, int nfrag, const pose *poses, int selected)
{
    render_camera_standard(c, RENDER_ANTERIOR, frags, nfrag);
    if (selected < 0 || selected >= nfrag || nfrag != r->nfrag)
        return 0;
    const frag *s = &frags[selected];
    const pose *ps = poses ? &poses[selected] : &s->pose;
    double centre[3], normal[3] = {0, -1, 0}, radius = 0, best_d2 = HUGE_VAL;
    pose_apply(ps, s->centroid, centre);
    for (int b = 0; b < 8; b++) { /* the crop's corners: how far the fragment reaches */
        double x[3], w[3], d2 = 0;
        for (int a = 0; a < 3; a++)
            x[a] = ((b >> a & 1) ? s->dim[a] - 0.5 : -0.5) * s->spacing[a];
        pose_apply(&s->home, x, w);
        pose_apply(ps, w, x);
        for (int a = 0; a < 3; a++)
            d2 += (x[a] - centre[a]) * (x[a] - centre[a]);
        radius = sqrt(d2) > radius ? sqrt(d2) : radius;
    }
    for (int i = 0; i < nfrag; i++) { /* the contact normal: from the nearest other piece to this one */
        double o[3], d2 = 0;
        if (i == selected)
            continue;
        pose_apply(poses ? &poses[i] : &frags[i].pose, frags[i].centroid, o);
        for (int a = 0; a < 3; a++)
            d2 += (centre[a] - o[a]) * (centre[a] - o[a]);
        if (d2 < best_d2 && d2 > 0)
            for (int a = 0; a < 3; a++)
                normal[a] = (centre[a] - o[a]) / sqrt(d2);
        best_d2 = d2 < best_d2 ? d2 : best_d2;
    }
    double shift = 0;
    for (int a = 0; a < 3; a++)
        shift += (centre[a] - c->centre[a]) * (centre[a] - c->centre[a]);
    c->depth += sqrt(shift);
    memcpy(c->centre, centre, sizeof centre);
    c->half_height = 1.1 * radius;
    /* Candidates: the six named views, the fragment's principal axes both ways (at its pose), and
     * the view from its own side onto the others. */
    double cand[13][3];
    int nc = 0;
    for (int v = 0; v < 6; v++, nc++)
        memcpy(cand[nc], views[v].forward, sizeof cand[nc]);
    for (int k = 0; k < 3; k++)
        for (int sign = -1; sign <= 1; sign += 2, nc++) {
            double ax[3] = {s->axes[0][k], s->axes[1][k], s->axes[2][k]};
            pose_rotate(ps, ax, cand[nc]);
            for (int a = 0; a < 3; a++)
                cand[nc][a] *= sign;
        }
    for (int a = 0; a < 3; a++)
        cand[nc][a] = -normal[a];
    nc++;
    uint8_t *id = malloc((size_t)r->w * (size_t)r->h);
    if (!id)
        return fn_err_set(FN_ENOMEM, "render: out of memory choosing a view at %dx%d", r->w, r->h);
    long vis[RENDER_MAX_FRAGS], proj[RENDER_MAX_FRAGS];
    double best = -1, best_f[3];
    int rc = 0;
    render_options o = {0}; /* no cut-away: the view itself must show the fragment */
    for (int k = 0; k < nc && !rc; k++) {
        look_along(c, cand[k]);
        o.camera = *c;
        rc = id_pass(r, poses, &o, -1, id, vis);
        if (!rc)
            rc = id_pass(r, poses, &o, selected, id, proj);
        /* Seen whole counts most; then seeing the fracture from the side (across the normal). */
        double seen = proj[selected] ? (double)vis[selected] / (double)proj[selected] : 0;
        double across = 1 - fabs(cand[k][0] * normal[0] + cand[k][1] * normal[1] + cand[k][2] * normal[2]);
        double score = seen + 0.1 * across;
        if (!rc && score > best + 1e-9) {
            best = score;
            memcpy(best_f, cand[k], sizeof best_f);
        }
    }
    free(id);
    if (!rc)
        look_along(c, best_f);
    return rc;
}
