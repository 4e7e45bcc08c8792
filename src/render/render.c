/* render: the handle, GL setup, scene upload and frame drawing (see render.h). */
#include "render_impl.h"

#include "err.h"
#include "morph.h"

#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---- GL setup ---- */

static int gl_load(render *r)
{
    char name[64];
#define RENDER_GL_LOAD(type, fn)                                                                   \
    snprintf(name, sizeof name, "gl%s", #fn);                                                      \
    r->gl.fn = (type)r->plat->proc(r, name);                                                       \
    if (!r->gl.fn)                                                                                 \
        return fn_err_set(FN_ENODEV, "render (%s): the GL lacks %s", r->plat->name, name);
    RENDER_GL_FUNCS(RENDER_GL_LOAD)
#undef RENDER_GL_LOAD
    return 0;
}

int render_parse_gl_version(const char *s, int *major, int *minor)
{
    for (const char *p = s; p && *p; p++)
        if (*p >= '0' && *p <= '9' && sscanf(p, "%d.%d", major, minor) == 2)
            return 0;
    return fn_err_set(FN_EFORMAT, "GL_VERSION '%s' holds no version number", s ? s : "(null)");
}

static int check_version(render *r)
{
    const char *v = (const char *)r->gl.GetString(GL_VERSION);
    const char *rn = (const char *)r->gl.GetString(GL_RENDERER);
    snprintf(r->version, sizeof r->version, "%s", v ? v : "unknown");
    snprintf(r->renderer, sizeof r->renderer, "%s", rn ? rn : "unknown");
    int major = 0, minor = 0;
    if (render_parse_gl_version(r->version, &major, &minor))
        return FN_ENODEV;
    if (major < 4 || (major == 4 && minor < 5))
        return fn_err_set(FN_ENODEV,
                          "render (%s): OpenGL 4.5 core is needed, this GL is %s (%s); install Mesa 20 "
                          "or later (libosmesa6, libgl1-mesa-dri) or a newer GPU driver",
                          r->plat->name, r->version, r->renderer);
    return 0;
}

static unsigned compile(render *r, unsigned kind, const char *src, const char *what)
{
    unsigned s = r->gl.CreateShader(kind);
    r->gl.ShaderSource(s, 1, &src, NULL);
    r->gl.CompileShader(s);
    int ok = 0;
    r->gl.GetShaderiv(s, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        char log[2048] = "";
        r->gl.GetShaderInfoLog(s, sizeof log, NULL, log);
        fn_err_set(FN_ENODEV, "render: the %s shader does not compile: %s", what, log);
        r->gl.DeleteShader(s);
        return 0;
    }
    return s;
}

static unsigned program(render *r, const char *vs_src, const char *fs_src, const char *what)
{
    unsigned vs = compile(r, GL_VERTEX_SHADER, vs_src, what);
    unsigned fs = vs ? compile(r, GL_FRAGMENT_SHADER, fs_src, what) : 0;
    if (!fs) {
        if (vs)
            r->gl.DeleteShader(vs);
        return 0;
    }
    unsigned p = r->gl.CreateProgram();
    r->gl.AttachShader(p, vs);
    r->gl.AttachShader(p, fs);
    r->gl.LinkProgram(p);
    r->gl.DeleteShader(vs);
    r->gl.DeleteShader(fs);
    int ok = 0;
    r->gl.GetProgramiv(p, GL_LINK_STATUS, &ok);
    if (!ok) {
        char log[2048] = "";
        r->gl.GetProgramInfoLog(p, sizeof log, NULL, log);
        fn_err_set(FN_ENODEV, "render: the %s program does not link: %s", what, log);
        r->gl.DeleteProgram(p);
        return 0;
    }
    return p;
}

/* The program of vs and head followed by body (its fragment shader). 0 with fn_err on failure. */
static unsigned program_with_head(render *r, const char *vs, const char *head, const char *body, const char *what)
{
    size_t n = strlen(head) + strlen(body) + 1;
    char *src = malloc(n);
    if (!src) {
        fn_err_set(FN_ENOMEM, "render: out of memory");
        return 0;
    }
    snprintf(src, n, "%s%s", head, body);
    unsigned p = program(r, vs, src, what);
    free(src);
    return p;
}

/* The raycaster for the scene's fragments in mode m (render__ray_fs after its header), compiled
 * once per scene and mode. 0 or FN_E*. */
int render__ray_program(render *r, render_mode m, int gaps, int cut, unsigned *prog)
{
    cut = gaps || (cut && m == RENDER_ISO); /* the cut costs every iso sample: compiled in only when asked */
    unsigned *p = gaps ? &r->prog_ray_gaps : cut ? &r->prog_ray_cut : &r->prog_ray[m];
    if (!*p) {
        char head[128];
        snprintf(head, sizeof head,
                 "#version 450 core\n#define NF %d\n#define mode %d\n#define GAPS %d\n#define CUT %d\n",
                 r->nfrag < 1 ? 1 : r->nfrag, gaps ? 0 : (int)m, gaps, cut);
        *p = program_with_head(r, render__ray_vs, head, render__ray_fs, gaps ? "contacts raycast" : "raycast");
    }
    *prog = *p;
    return *p ? 0 : FN_ENODEV;
}

int render__gaps_program(render *r)
{
    if (r->prog_gaps)
        return 0;
    char head[64];
    snprintf(head, sizeof head, "#version 450 core\n#define NF %d\n", r->nfrag - 1);
    r->prog_gaps = program_with_head(r, render__mesh_vs, head, render__mesh_fs, "contacts surface");
    return r->prog_gaps ? 0 : FN_ENODEV;
}

static int gl_setup(render *r)
{
    r->prog_slice = program(r, render__quad_vs, render__slice_fs, "slice");
    r->prog_mesh = r->prog_slice ? program_with_head(r, render__mesh_vs, "#version 450 core\n#define NF 0\n",
                                                     render__mesh_fs, "surface")
                                 : 0;
    r->prog_line = r->prog_mesh ? program(r, render__line_vs, render__line_fs, "overlay") : 0;
    r->prog_depth = r->prog_line ? program(r, render__proxy_vs, render__depth_fs, "depth") : 0;
    r->prog_hud = r->prog_depth ? program(r, render__quad_vs, render__hud_fs, "hud") : 0;
    r->prog_id = r->prog_hud ? program(r, render__mesh_vs, render__id_fs, "fragment ids") : 0;
    if (!r->prog_id)
        return FN_ENODEV;
    r->gl.GenVertexArrays(1, &r->vao_empty);
    r->gl.GenVertexArrays(1, &r->line_vao);
    r->gl.GenBuffers(1, &r->line_vbo);
    r->gl.BindVertexArray(r->line_vao);
    r->gl.BindBuffer(GL_ARRAY_BUFFER, r->line_vbo);
    r->gl.VertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), (void *)0);
    r->gl.VertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), (void *)(3 * sizeof(float)));
    r->gl.EnableVertexAttribArray(0);
    r->gl.EnableVertexAttribArray(1);
    r->gl.BindVertexArray(0);
    r->gl.GenFramebuffers(1, &r->span_fbo);
    return 0;
}

static const render_platform *pick_platform(const char *name)
{
    if (!name) {
        const char *d = getenv("DISPLAY");
        name = d && *d && render__glfw.available ? "glfw" : "offscreen";
    }
    if (!strcmp(name, "offscreen"))
        name = render__egl_gpu() ? "egl" : "osmesa";
    if (!strcmp(name, "osmesa"))
        return &render__osmesa;
    if (!strcmp(name, "egl"))
        return &render__egl;
    if (!strcmp(name, "glfw"))
        return &render__glfw;
    return NULL;
}

render *render_open(const char *platform, int w, int h)
{
    if (w < 1 || h < 1 || w > 16384 || h > 16384) {
        fn_err_set(FN_EINVAL, "render: size %dx%d is not 1..16384 on each side", w, h);
        return NULL;
    }
    const render_platform *p = pick_platform(platform);
    if (!p) {
        fn_err_set(FN_EINVAL, "render: unknown platform '%s' (offscreen, osmesa, egl or glfw)", platform);
        return NULL;
    }
    render *r = calloc(1, sizeof *r);
    if (!r) {
        fn_err_set(FN_ENOMEM, "render: out of memory");
        return NULL;
    }
    r->plat = p;
    r->early_late = -1;
    r->w = w;
    r->h = h;
    if (p->open(r, w, h) || gl_load(r) || check_version(r) || gl_setup(r)) {
        render_close(r);
        return NULL;
    }
    return r;
}

const char *render_gl_renderer(const render *r)
{
    return r->renderer;
}

void render_size(const render *r, int *w, int *h)
{
    *w = r->w;
    *h = r->h;
}

render_mode render_default_mode(const render *r)
{
    return strstr(r->renderer, "llvmpipe") || strstr(r->renderer, "softpipe") ? RENDER_SURFACE : RENDER_ISO;
}

const char *render_gl_version(const render *r)
{
    return r->version;
}

/* ---- scene ---- */

static void frag_release(render *r, render_frag *f)
{
    if (f->tex)
        r->gl.DeleteTextures(1, &f->tex);
    if (f->mesh_vbo)
        r->gl.DeleteBuffers(1, &f->mesh_vbo);
    if (f->mesh_ibo)
        r->gl.DeleteBuffers(1, &f->mesh_ibo);
    if (f->mesh_vao)
        r->gl.DeleteVertexArrays(1, &f->mesh_vao);
    if (f->box_vbo)
        r->gl.DeleteBuffers(1, &f->box_vbo);
    if (f->proxy_vbo)
        r->gl.DeleteBuffers(1, &f->proxy_vbo);
    if (f->proxy_vao)
        r->gl.DeleteVertexArrays(1, &f->proxy_vao);
    if (f->box_vao)
        r->gl.DeleteVertexArrays(1, &f->box_vao);
    if (f->dist_tex)
        r->gl.DeleteTextures(1, &f->dist_tex);
    obb_tree_free(f->tree);
    memset(f, 0, sizeof *f);
}

static void scene_release(render *r)
{
    for (int i = 0; i < r->nfrag; i++)
        frag_release(r, &r->frag[i]);
    r->nfrag = 0;
    unsigned *tex[] = {&r->occ_tex, &r->tf_tex, &r->ct_tex, &r->span_tex[0], &r->span_tex[1]};
    for (size_t i = 0; i < sizeof tex / sizeof tex[0]; i++)
        if (*tex[i]) {
            r->gl.DeleteTextures(1, tex[i]);
            *tex[i] = 0;
        }
    r->have_ct = 0;
    for (int m = 0; m < 3; m++)
        if (r->prog_ray[m]) {
            r->gl.DeleteProgram(r->prog_ray[m]);
            r->prog_ray[m] = 0;
        }
    unsigned *scene_progs[] = {&r->prog_gaps, &r->prog_ray_gaps, &r->prog_ray_cut};
    for (int i = 0; i < 3; i++)
        if (*scene_progs[i]) {
            r->gl.DeleteProgram(*scene_progs[i]);
            *scene_progs[i] = 0;
        }
}

void render_close(render *r)
{
    if (!r)
        return;
    if (r->gl.DeleteTextures) {
        scene_release(r);
        unsigned progs[] = {r->prog_slice, r->prog_mesh, r->prog_line, r->prog_depth, r->prog_hud, r->prog_id};
        for (int i = 0; i < 6; i++)
            if (progs[i])
                r->gl.DeleteProgram(progs[i]);
        if (r->line_vbo)
            r->gl.DeleteBuffers(1, &r->line_vbo);
        if (r->span_fbo)
            r->gl.DeleteFramebuffers(1, &r->span_fbo);
        if (r->hud_tex)
            r->gl.DeleteTextures(1, &r->hud_tex);
        unsigned vaos[] = {r->vao_empty, r->line_vao};
        for (int i = 0; i < 2; i++)
            if (vaos[i])
                r->gl.DeleteVertexArrays(1, &vaos[i]);
    }
    if (r->plat_state)
        r->plat->close(r);
    free(r);
}

/* The masked CT crop of f: HU inside the label (at least iso_hu), under iso_hu elsewhere. */
static float *masked_crop(const frag *f, const vol *ct, double iso_hu)
{
    size_t n = (size_t)f->dim[0] * (size_t)f->dim[1] * (size_t)f->dim[2];
    float *v = malloc(n * sizeof *v);
    if (!v)
        return NULL;
    /* Outside the label the CT keeps its own values up to just under the level, so the surface
     * and its gradient follow the CT where the label ends at tissue or air, and another
     * fragment's bone (or the head holder) stays invisible. */
    const float lo = (float)iso_hu, below = (float)(iso_hu - RENDER_OUTSIDE_MARGIN);
    size_t idx = 0;
    for (int k = 0; k < f->dim[2]; k++)
        for (int j = 0; j < f->dim[1]; j++) {
            /* a row of the crop is a row of the CT, run one way or the other (a flip) */
            int l[3] = {0, j, k}, s[3], last[3];
            frag_local_to_source(f, l, s);
            l[0] = f->dim[0] - 1;
            frag_local_to_source(f, l, last);
            int step = last[0] >= s[0] ? 1 : -1;
            int row = ct && s[1] >= 0 && s[2] >= 0 && s[1] < ct->dim[1] && s[2] < ct->dim[2];
            const float *src = row ? ct->data + vol_idx(ct, 0, s[1], s[2]) : NULL;
            for (int i = 0, x0 = s[0]; i < f->dim[0]; i++, idx++, x0 += step) {
                int in_ct = row && x0 >= 0 && x0 < ct->dim[0];
                float x = in_ct ? src[x0] : RENDER_OUTSIDE_HU;
                if (f->prob[idx])
                    x = in_ct && x >= lo ? x : lo + 500.0f;
                else
                    x = x < below ? x : below;
                v[idx] = x;
            }
        }
    return v;
}

static void tex3d_params(render *r, int filter)
{
    r->gl.TexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MIN_FILTER, filter);
    r->gl.TexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MAG_FILTER, filter);
    r->gl.TexParameteri(GL_TEXTURE_3D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    r->gl.TexParameteri(GL_TEXTURE_3D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    r->gl.TexParameteri(GL_TEXTURE_3D, GL_TEXTURE_WRAP_R, GL_CLAMP_TO_EDGE);
}

/* vals averaged over blocks of s^3 voxels (each value first clamped to the level +- 600 HU, so
 * that dense bone does not outweigh its surroundings): a grid of d (out) cells, malloc'd; NULL
 * when out of memory. A surface through the averages is smooth where one through every s-th
 * voxel is stepped (aliasing). */
static float *block_means(const float *vals, const int dim[3], int s, float level, int d[3])
{
    for (int a = 0; a < 3; a++)
        d[a] = (dim[a] + s - 1) / s;
    float *m = calloc((size_t)d[0] * (size_t)d[1] * (size_t)d[2], sizeof *m);
    if (!m)
        return NULL;
    for (int k = 0; k < d[2]; k++)
        for (int j = 0; j < d[1]; j++)
            for (int i = 0; i < d[0]; i++) {
                double sum = 0;
                int n = 0;
                for (int z = k * s; z < (k + 1) * s && z < dim[2]; z++)
                    for (int y = j * s; y < (j + 1) * s && y < dim[1]; y++)
                        for (int x = i * s; x < (i + 1) * s && x < dim[0]; x++, n++) {
                            float v = vals[((size_t)z * (size_t)dim[1] + (size_t)y) * (size_t)dim[0] + (size_t)x];
                            sum += v < level - 600 ? level - 600 : v > level + 600 ? level + 600 : v;
                        }
                m[((size_t)k * (size_t)d[1] + (size_t)j) * (size_t)d[0] + (size_t)i] = (float)(sum / n);
            }
    return m;
}

/* The grid g (d cells of sp mm, cell (0,0,0) at the origin) at p mm: its value's gradient by
 * central differences, interpolated trilinearly, into out. */
static void grid_gradient(const float *g, const int d[3], const double sp[3], const float p[3], double out[3])
{
    int c0[3];
    double f[3];
    for (int a = 0; a < 3; a++) {
        double x = p[a] / sp[a];
        x = x < 0 ? 0 : x > d[a] - 1 ? d[a] - 1 : x;
        c0[a] = (int)x < d[a] - 1 ? (int)x : (d[a] > 1 ? d[a] - 2 : 0);
        f[a] = x - c0[a];
        out[a] = 0;
    }
    for (int corner = 0; corner < 8; corner++) {
        int c[3];
        double w = 1;
        for (int a = 0; a < 3; a++) {
            int hi = corner >> a & 1;
            c[a] = c0[a] + hi < d[a] ? c0[a] + hi : d[a] - 1;
            w *= hi ? f[a] : 1 - f[a];
        }
        for (int a = 0; a < 3; a++) {
            int lo[3] = {c[0], c[1], c[2]}, up[3] = {c[0], c[1], c[2]};
            lo[a] = c[a] > 0 ? c[a] - 1 : 0;
            up[a] = c[a] < d[a] - 1 ? c[a] + 1 : d[a] - 1;
            float vl = g[((size_t)lo[2] * (size_t)d[1] + (size_t)lo[1]) * (size_t)d[0] + (size_t)lo[0]];
            float vu = g[((size_t)up[2] * (size_t)d[1] + (size_t)up[1]) * (size_t)d[0] + (size_t)up[0]];
            out[a] += w * (vu - vl) / (up[a] > lo[a] ? (up[a] - lo[a]) * sp[a] : 1);
        }
    }
}

/* m's vertices, 6 floats each: the position shifted by off mm, and the outward unit normal
 * against the gradient of the grid g it was extracted from (see grid_gradient), which is smooth
 * where the triangles' own normals show the voxel steps. malloc'd, NULL when out of memory. */
static float *mesh_vertices(const mesh *m, const float *g, const int d[3], const double sp[3], const double off[3])
{
    float *v = malloc((size_t)(m->nv ? m->nv : 1) * 6 * sizeof *v);
    if (!v)
        return NULL;
    for (long i = 0; i < m->nv; i++) {
        float *o = v + (size_t)i * 6;
        const float *p = m->v + (size_t)i * 3;
        double n[3];
        grid_gradient(g, d, sp, p, n);
        double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (int a = 0; a < 3; a++) {
            o[a] = (float)(p[a] + off[a]);
            o[3 + a] = len > 0 ? (float)(-n[a] / len) : 0;
        }
    }
    return v;
}

/* What a fragment's upload computes before any GL call (render_prepare can make it on another
 * thread): its masked crop and its surface mesh's triangles and vertices. */
typedef struct frag_prep {
    float *vals;  /* masked_crop */
    mesh m;       /* its triangles (m.tri, m.nt; m.nv vertices) */
    float *verts; /* mesh_vertices */
} frag_prep;

struct render_prep {
    double iso_hu;
    int nfrag;
    frag_prep f[RENDER_MAX_FRAGS];
};

static void frag_prep_free(frag_prep *p)
{
    free(p->vals);
    free(p->verts);
    mesh_free(&p->m);
    memset(p, 0, sizeof *p);
}

/* f's crop and mesh at iso_hu. 0 or FN_ENOMEM (p then holds nothing). */
static int frag_prep_make(frag_prep *p, const frag *f, const vol *ct, double iso_hu)
{
    memset(p, 0, sizeof *p);
    p->vals = masked_crop(f, ct, iso_hu);
    if (!p->vals)
        return fn_err_set(FN_ENOMEM, "render: out of memory for fragment %d's %dx%dx%d crop", f->id, f->dim[0],
                          f->dim[1], f->dim[2]);
    /* Cells of about 0.5M voxels at most. Where that takes blocks of s^3 voxels, the mesh follows
     * their means. The closed surface is then decimated by RENDER_MESH_KEEP (its shortest edges,
     * the slivers that marching tetrahedra leaves, go first): software GL pays per triangle. */
    double voxels = (double)f->dim[0] * f->dim[1] * f->dim[2];
    int s = (int)ceil(cbrt(voxels / (1 << 19)));
    s = s < 1 ? 1 : s;
    int d[3];
    double sp[3], off[3];
    for (int a = 0; a < 3; a++) {
        sp[a] = f->spacing[a] * s;
        off[a] = 0.5 * (s - 1) * f->spacing[a]; /* a block's mean stands for its centre */
    }
    float *means = s > 1 ? block_means(p->vals, f->dim, s, (float)iso_hu, d) : NULL;
    if (s > 1 && !means) {
        frag_prep_free(p);
        return fn_err_set(FN_ENOMEM, "render: out of memory for a surface mesh's grid");
    }
    const float *g = means ? means : p->vals;
    if (!means)
        memcpy(d, f->dim, sizeof d);
    int rc = mesh_extract(g, d, sp, (float)iso_hu, &p->m);
    if (rc) {
        free(means);
        frag_prep_free(p);
        return rc;
    }
    long nt = mesh_decimate(&p->m, (long)((double)p->m.nt * RENDER_MESH_KEEP));
    p->verts = nt < 0 ? NULL : mesh_vertices(&p->m, g, d, sp, off);
    free(means);
    if (!p->verts) {
        frag_prep_free(p);
        return nt < 0 ? (int)nt : fn_err_set(FN_ENOMEM, "render: out of memory for a surface mesh");
    }
    return 0;
}

typedef struct prep_share {
    render_prep *p;
    const vol *ct;
    const frag *frags;
    int nfrag, first, step, rc;
} prep_share;

/* Fragments first, first + step, ... of a preparation; the first error kept. */
static void *prep_some(void *arg)
{
    prep_share *s = arg;
    for (int i = s->first; i < s->nfrag && s->rc == 0; i += s->step)
        s->rc = frag_prep_make(&s->p->f[i], &s->frags[i], s->ct, s->p->iso_hu);
    return NULL;
}

render_prep *render_prepare(const vol *ct, const frag *frags, int nfrag, double iso_hu, int threads)
{
    if (nfrag < 0 || nfrag > RENDER_MAX_FRAGS) {
        fn_err_set(FN_EINVAL, "render: %d fragments, at most %d can be drawn", nfrag, RENDER_MAX_FRAGS);
        return NULL;
    }
    render_prep *p = calloc(1, sizeof *p);
    if (!p) {
        fn_err_set(FN_ENOMEM, "render: out of memory for a scene's preparation");
        return NULL;
    }
    p->iso_hu = iso_hu;
    p->nfrag = nfrag; /* each f[i] holds nothing until made (frag_prep_free takes that) */
    threads = threads < 1 ? 1 : threads > RENDER_PREP_THREADS ? RENDER_PREP_THREADS : threads;
    threads = threads > nfrag ? (nfrag > 0 ? nfrag : 1) : threads;
    prep_share share[RENDER_PREP_THREADS];
    pthread_t tid[RENDER_PREP_THREADS];
    int started[RENDER_PREP_THREADS] = {0}, rc = 0;
    for (int t = 0; t < threads; t++) {
        share[t] = (prep_share){p, ct, frags, nfrag, t, threads, 0};
        started[t] = t > 0 && pthread_create(&tid[t], NULL, prep_some, &share[t]) == 0;
    }
    for (int t = 0; t < threads; t++)
        if (!started[t]) /* this thread's share, and any whose thread did not start */
            prep_some(&share[t]);
    for (int t = 0; t < threads; t++) {
        if (started[t])
            pthread_join(tid[t], NULL);
        if (share[t].rc && !rc) {
            rc = share[t].rc;
            if (started[t]) /* fn_err is per thread: said again here */
                fn_err_set(rc, "render: out of memory preparing the fragments' crops and meshes");
        }
    }
    if (rc) {
        render_prep_free(p);
        return NULL;
    }
    return p;
}

void render_prep_free(render_prep *p)
{
    if (!p)
        return;
    for (int i = 0; i < p->nfrag; i++)
        frag_prep_free(&p->f[i]);
    free(p);
}

double render_iso_hu(const render *r)
{
    return r->iso_hu;
}

static int upload_mesh(render *r, render_frag *rf, const frag_prep *p)
{
    const mesh m = p->m;
    const float *v = p->verts;
    rf->mesh_triangles = m.nt;
    r->gl.GenVertexArrays(1, &rf->mesh_vao);
    r->gl.GenBuffers(1, &rf->mesh_vbo);
    r->gl.GenBuffers(1, &rf->mesh_ibo);
    r->gl.BindVertexArray(rf->mesh_vao);
    r->gl.BindBuffer(GL_ARRAY_BUFFER, rf->mesh_vbo);
    r->gl.BufferData(GL_ARRAY_BUFFER, (GLsizeiptr)m.nv * 6 * (GLsizeiptr)sizeof(float), v, GL_STATIC_DRAW);
    r->gl.BindBuffer(GL_ELEMENT_ARRAY_BUFFER, rf->mesh_ibo);
    r->gl.BufferData(GL_ELEMENT_ARRAY_BUFFER, (GLsizeiptr)m.nt * 3 * (GLsizeiptr)sizeof(int), m.tri,
                     GL_STATIC_DRAW);
    r->gl.VertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), (void *)0);
    r->gl.VertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, 6 * sizeof(float), (void *)(3 * sizeof(float)));
    r->gl.EnableVertexAttribArray(0);
    r->gl.EnableVertexAttribArray(1);
    r->gl.BindVertexArray(0);
    return 0;
}

/* Occupancy of f's 4^3 blocks (any voxel in the mask), dilated by one block so that trilinear
 * samples near a block's face and coarse steps of under a block's width never miss data. */
static uint8_t *occupancy(const frag *f, const int od[3])
{
    size_t n = (size_t)od[0] * (size_t)od[1] * (size_t)od[2];
    uint8_t *raw = calloc(n, 1), *dil = calloc(n, 1);
    if (!raw || !dil) {
        free(raw);
        free(dil);
        return NULL;
    }
    size_t idx = 0;
    for (int k = 0; k < f->dim[2]; k++)
        for (int j = 0; j < f->dim[1]; j++)
            for (int i = 0; i < f->dim[0]; i++, idx++)
                if (f->prob[idx])
                    raw[((size_t)(k / RENDER_BLOCK) * (size_t)od[1] + (size_t)(j / RENDER_BLOCK)) * (size_t)od[0] +
                        (size_t)(i / RENDER_BLOCK)] = 1;
    for (int k = 0; k < od[2]; k++)
        for (int j = 0; j < od[1]; j++)
            for (int i = 0; i < od[0]; i++) {
                int any = 0;
                for (int c = -1; c <= 1; c++)
                    for (int b = -1; b <= 1; b++)
                        for (int a = -1; a <= 1; a++) {
                            int x = i + a, y = j + b, z = k + c;
                            if (x >= 0 && y >= 0 && z >= 0 && x < od[0] && y < od[1] && z < od[2])
                                any |= raw[((size_t)z * (size_t)od[1] + (size_t)y) * (size_t)od[0] + (size_t)x];
                        }
                dil[((size_t)k * (size_t)od[1] + (size_t)j) * (size_t)od[0] + (size_t)i] = (uint8_t)any;
            }
    free(raw);
    return dil;
}

/* f's crop and mesh: prep's when given (made for f at r's level), else made here. */
static int upload_fragment(render *r, render_frag *rf, const frag *f, const vol *ct, const frag_prep *prep)
{
    memcpy(rf->dim, f->dim, sizeof rf->dim);
    memcpy(rf->spacing, f->spacing, sizeof rf->spacing);
    rf->home = f->home;
    rf->pose = f->pose;
    for (int a = 0; a < 3; a++) {
        rf->local_to_tc[a] = 1.0 / (f->spacing[a] * f->dim[a]);
        rf->rgb[a] = f->rgb[a] / 255.0f;
        rf->occ_dim[a] = (f->dim[a] + RENDER_BLOCK - 1) / RENDER_BLOCK;
        rf->centroid[a] = f->centroid[a];
        rf->eigval[a] = f->eigval[a];
        for (int b = 0; b < 3; b++)
            rf->axes[a][b] = f->axes[a][b];
    }
    frag_prep own;
    if (!prep) {
        int rc = frag_prep_make(&own, f, ct, r->iso_hu);
        if (rc)
            return rc;
    }
    const frag_prep *p = prep ? prep : &own;
    r->gl.GenTextures(1, &rf->tex);
    r->gl.BindTexture(GL_TEXTURE_3D, rf->tex);
    tex3d_params(r, GL_LINEAR);
    r->gl.PixelStorei(GL_UNPACK_ALIGNMENT, 1);
    r->gl.TexImage3D(GL_TEXTURE_3D, 0, GL_R16F, f->dim[0], f->dim[1], f->dim[2], 0, GL_RED, GL_FLOAT, p->vals);
    int rc = upload_mesh(r, rf, p);
    if (!prep)
        frag_prep_free(&own);
    return rc;
}

/* The raycaster's proxy for rf: the boundary faces of its occupied bricks (RENDER_PROXY_BLOCKS^3
 * blocks of the dilated occupancy g), as triangles in local mm clamped to the texture's box. */
static int upload_proxy(render *r, render_frag *rf, const uint8_t *g)
{
    const int *od = rf->occ_dim, B = RENDER_PROXY_BLOCKS;
    int pd[3];
    for (int a = 0; a < 3; a++)
        pd[a] = (od[a] + B - 1) / B;
    size_t n = (size_t)pd[0] * (size_t)pd[1] * (size_t)pd[2];
    uint8_t *occ = calloc(n ? n : 1, 1);
    if (!occ)
        return fn_err_set(FN_ENOMEM, "render: out of memory for the raycaster's bricks");
    for (int k = 0; k < od[2]; k++)
        for (int j = 0; j < od[1]; j++)
            for (int i = 0; i < od[0]; i++)
                if (g[((size_t)k * (size_t)od[1] + (size_t)j) * (size_t)od[0] + (size_t)i])
                    occ[((size_t)(k / B) * (size_t)pd[1] + (size_t)(j / B)) * (size_t)pd[0] + (size_t)(i / B)] = 1;
#define PROXY_AT(x, y, z)                                                                          \
    ((x) >= 0 && (y) >= 0 && (z) >= 0 && (x) < pd[0] && (y) < pd[1] && (z) < pd[2] &&             \
     occ[((size_t)(z) * (size_t)pd[1] + (size_t)(y)) * (size_t)pd[0] + (size_t)(x)])
    size_t faces = 0;
    for (int pass = 0; pass < 2; pass++) {
        float *v = NULL;
        if (pass == 1) {
            v = malloc((faces ? faces : 1) * 6 * 3 * sizeof *v);
            if (!v) {
                free(occ);
                return fn_err_set(FN_ENOMEM, "render: out of memory for the raycaster's bricks");
            }
        }
        size_t nv = 0;
        for (int z = 0; z < pd[2]; z++)
            for (int y = 0; y < pd[1]; y++)
                for (int x = 0; x < pd[0]; x++) {
                    if (!PROXY_AT(x, y, z))
                        continue;
                    int c[3] = {x, y, z};
                    double lo[3], hi[3];
                    for (int a = 0; a < 3; a++) {
                        double l = (double)c[a] * B * RENDER_BLOCK - 0.5, h = l + B * RENDER_BLOCK;
                        lo[a] = l * rf->spacing[a];
                        hi[a] = (h < rf->dim[a] - 0.5 ? h : rf->dim[a] - 0.5) * rf->spacing[a];
                    }
                    for (int f = 0; f < 6; f++) {
                        int axis = f / 2, side = f & 1, nb[3] = {x, y, z};
                        nb[axis] += side ? 1 : -1;
                        if (PROXY_AT(nb[0], nb[1], nb[2]))
                            continue;
                        if (pass == 0) {
                            faces++;
                            continue;
                        }
                        int u = (axis + 1) % 3, w = (axis + 2) % 3;
                        static const int quad[6][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 0}, {1, 1}, {0, 1}};
                        for (int q = 0; q < 6; q++, nv++) {
                            v[nv * 3 + axis] = (float)(side ? hi[axis] : lo[axis]);
                            v[nv * 3 + u] = (float)(quad[q][0] ? hi[u] : lo[u]);
                            v[nv * 3 + w] = (float)(quad[q][1] ? hi[w] : lo[w]);
                        }
                    }
                }
#undef PROXY_AT
        if (pass == 1) {
            r->gl.GenVertexArrays(1, &rf->proxy_vao);
            r->gl.GenBuffers(1, &rf->proxy_vbo);
            r->gl.BindVertexArray(rf->proxy_vao);
            r->gl.BindBuffer(GL_ARRAY_BUFFER, rf->proxy_vbo);
            r->gl.BufferData(GL_ARRAY_BUFFER, (GLsizeiptr)(nv * 3 * sizeof(float)), v, GL_STATIC_DRAW);
            r->gl.VertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 3 * sizeof(float), (void *)0);
            r->gl.EnableVertexAttribArray(0);
            r->gl.BindVertexArray(0);
            rf->proxy_vertices = (int)nv;
            free(v);
        }
    }
    free(occ);
    return 0;
}

/* The per-fragment brick spans (span_tex), one layer per 4 fragments. */
static int upload_spans(render *r, int nfrag)
{
    r->span_layers = nfrag < 1 ? 1 : (nfrag + 3) / 4;
    r->gl.GenTextures(2, r->span_tex);
    r->gl.BindFramebuffer(GL_FRAMEBUFFER, r->span_fbo);
    unsigned st = GL_FRAMEBUFFER_COMPLETE;
    for (int i = 0; i < 2; i++) {
        r->gl.BindTexture(GL_TEXTURE_2D_ARRAY, r->span_tex[i]);
        r->gl.TexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
        r->gl.TexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
        r->gl.TexImage3D(GL_TEXTURE_2D_ARRAY, 0, GL_RGBA16F, r->w, r->h, r->span_layers, 0, GL_RGBA,
                         GL_FLOAT, NULL);
        r->gl.FramebufferTextureLayer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, r->span_tex[i], 0, 0);
        if (st == GL_FRAMEBUFFER_COMPLETE)
            st = r->gl.CheckFramebufferStatus(GL_FRAMEBUFFER);
    }
    r->gl.BindFramebuffer(GL_FRAMEBUFFER, 0);
    if (st != GL_FRAMEBUFFER_COMPLETE)
        return fn_err_set(FN_ENODEV, "render (%s): the brick span framebuffer is incomplete (0x%04x)",
                          r->plat->name, st);
    return 0;
}

/* All fragments' occupancy grids stacked along z in one R8UI texture (one texture unit). */
static int upload_occupancy(render *r, const frag *frags)
{
    int od[3] = {1, 1, 0};
    for (int i = 0; i < r->nfrag; i++) {
        render_frag *rf = &r->frag[i];
        od[0] = rf->occ_dim[0] > od[0] ? rf->occ_dim[0] : od[0];
        od[1] = rf->occ_dim[1] > od[1] ? rf->occ_dim[1] : od[1];
        rf->occ_z = od[2];
        od[2] += rf->occ_dim[2];
    }
    od[2] = od[2] ? od[2] : 1;
    size_t plane = (size_t)od[0] * (size_t)od[1];
    uint8_t *all = calloc(plane * (size_t)od[2], 1);
    if (!all)
        return fn_err_set(FN_ENOMEM, "render: out of memory for occupancy grids");
    for (int i = 0; i < r->nfrag; i++) {
        render_frag *rf = &r->frag[i];
        uint8_t *g = occupancy(&frags[i], rf->occ_dim);
        if (!g) {
            free(all);
            return fn_err_set(FN_ENOMEM, "render: out of memory for occupancy grids");
        }
        for (int k = 0; k < rf->occ_dim[2]; k++)
            for (int j = 0; j < rf->occ_dim[1]; j++)
                memcpy(all + (size_t)(rf->occ_z + k) * plane + (size_t)j * (size_t)od[0],
                       g + ((size_t)k * (size_t)rf->occ_dim[1] + (size_t)j) * (size_t)rf->occ_dim[0],
                       (size_t)rf->occ_dim[0]);
        int rc = upload_proxy(r, rf, g);
        free(g);
        if (rc) {
            free(all);
            return rc;
        }
    }
    r->gl.GenTextures(1, &r->occ_tex);
    r->gl.BindTexture(GL_TEXTURE_3D, r->occ_tex);
    tex3d_params(r, GL_NEAREST);
    r->gl.TexImage3D(GL_TEXTURE_3D, 0, GL_R8UI, od[0], od[1], od[2], 0, GL_RED_INTEGER, GL_UNSIGNED_BYTE, all);
    free(all);
    return 0;
}

/* The DVR transfer function over [iso - 500, iso + 1500] HU: transparent below the bone level,
 * then rising opacity and brightness. */
static void upload_tf(render *r)
{
    float tf[256][4];
    for (int i = 0; i < 256; i++) {
        double hu = r->iso_hu - 500 + 2000.0 * i / 255.0;
        double a = (hu - (r->iso_hu - 100)) / 800.0;
        a = a < 0 ? 0 : a > 1 ? 1 : a;
        float grey = (float)(0.55 + 0.45 * a);
        tf[i][0] = tf[i][1] = tf[i][2] = grey;
        tf[i][3] = (float)(0.35 * a);
    }
    r->gl.GenTextures(1, &r->tf_tex);
    r->gl.BindTexture(GL_TEXTURE_1D, r->tf_tex);
    r->gl.TexParameteri(GL_TEXTURE_1D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    r->gl.TexParameteri(GL_TEXTURE_1D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    r->gl.TexParameteri(GL_TEXTURE_1D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    r->gl.TexImage1D(GL_TEXTURE_1D, 0, GL_RGBA16F, 256, 0, GL_RGBA, GL_FLOAT, tf);
}

static int upload_ct(render *r, const vol *ct)
{
    r->gl.GenTextures(1, &r->ct_tex);
    r->gl.BindTexture(GL_TEXTURE_3D, r->ct_tex);
    tex3d_params(r, GL_LINEAR);
    r->gl.TexImage3D(GL_TEXTURE_3D, 0, GL_R16F, ct->dim[0], ct->dim[1], ct->dim[2], 0, GL_RED, GL_FLOAT,
                     ct->data);
    /* world -> index is the inverse of the orthogonal affine: A^T / spacing^2 for the 3x3. */
    memset(r->ct_w2t, 0, sizeof r->ct_w2t);
    for (int a = 0; a < 3; a++) {
        double s2 = ct->spacing[a] * ct->spacing[a];
        double off = 0;
        for (int b = 0; b < 3; b++) {
            double m = ct->affine[b][a] / s2 / ct->dim[a];
            r->ct_w2t[a][b] = m;
            off -= m * ct->affine[b][3];
        }
        r->ct_w2t[a][3] = off + 0.5 / ct->dim[a];
    }
    r->ct_w2t[3][3] = 1;
    r->have_ct = 1;
    return 0;
}

static int gl_check(render *r, const char *what)
{
    unsigned e = r->gl.GetError();
    if (e == GL_OUT_OF_MEMORY)
        return fn_err_set(FN_ENOMEM, "render: GL out of memory %s", what);
    if (e != GL_NO_ERROR)
        return fn_err_set(FN_ENODEV, "render: GL error 0x%04x %s", e, what);
    return 0;
}

/* The contacts overlay's distance map of f (render_frag.dist_tex) and the hierarchy of both
 * overlays, when rf has them not yet. 0 or FN_ENOMEM. */
static int upload_contacts(render *r, render_frag *rf, const frag *f, const obb_params *hp)
{
    if (!rf->tree && !(rf->tree = obb_tree_build(f, hp)))
        return fn_err_set(FN_ENOMEM, "render: out of memory for fragment %d's hierarchy", f->id);
    if (rf->dist_tex)
        return 0;
    size_t n = (size_t)f->dim[0] * (size_t)f->dim[1] * (size_t)f->dim[2];
    float *d = malloc((n ? n : 1) * sizeof *d);
    if (!d || morph_distance_to(f->prob, f->dim, f->spacing, d)) {
        free(d);
        return fn_err_set(FN_ENOMEM, "render: out of memory for fragment %d's distance map", f->id);
    }
    for (size_t i = 0; i < n; i++)
        d[i] = d[i] < RENDER_DIST_MAX_MM ? d[i] : (float)RENDER_DIST_MAX_MM;
    r->gl.GenTextures(1, &rf->dist_tex);
    r->gl.BindTexture(GL_TEXTURE_3D, rf->dist_tex);
    tex3d_params(r, GL_LINEAR);
    r->gl.PixelStorei(GL_UNPACK_ALIGNMENT, 1);
    r->gl.TexImage3D(GL_TEXTURE_3D, 0, GL_R16F, f->dim[0], f->dim[1], f->dim[2], 0, GL_RED, GL_FLOAT, d);
    free(d);
    return gl_check(r, "uploading a distance map");
}

/* render_set_scene; keep_ct: the CT texture stays as it is (render_set_fragments). */
static int set_scene(render *r, const vol *ct, const frag *frags, int nfrag, double iso_hu, const obb_params *hp,
                     int keep_ct, const render_prep *prep)
{
    if (nfrag < 0 || nfrag > RENDER_MAX_FRAGS)
        return fn_err_set(FN_EINVAL, "render: %d fragments, at most %d can be drawn", nfrag,
                          RENDER_MAX_FRAGS);
    unsigned kept = keep_ct && r->have_ct ? r->ct_tex : 0;
    r->ct_tex = kept ? 0 : r->ct_tex; /* not deleted with the scene */
    scene_release(r);
    r->early_late = -1;
    r->iso_hu = iso_hu;
    r->min_spacing = 1e30;
    int rc = 0;
    for (int i = 0; i < nfrag && !rc; i++) {
        r->nfrag = i + 1;
        rc = upload_fragment(r, &r->frag[i], &frags[i], ct, prep ? &prep->f[i] : NULL);
        for (int a = 0; a < 3; a++)
            r->min_spacing = frags[i].spacing[a] < r->min_spacing ? frags[i].spacing[a] : r->min_spacing;
        if (!rc && hp)
            rc = upload_contacts(r, &r->frag[i], &frags[i], hp);
    }
    if (!rc)
        rc = upload_occupancy(r, frags);
    if (!rc)
        rc = upload_spans(r, nfrag);
    if (!rc) {
        upload_tf(r);
        if (kept) {
            r->ct_tex = kept;
            r->have_ct = 1;
        } else if (ct)
            rc = upload_ct(r, ct);
    }
    if (!rc)
        rc = gl_check(r, "uploading the scene");
    if (rc) {
        r->ct_tex = kept ? kept : r->ct_tex; /* deleted with the rest */
        scene_release(r);
    }
    return rc;
}

int render_set_scene(render *r, const vol *ct, const frag *frags, int nfrag, double iso_hu,
                     const obb_params *hp)
{
    return set_scene(r, ct, frags, nfrag, iso_hu, hp, 0, NULL);
}

int render_set_fragments(render *r, const vol *ct, const frag *frags, int nfrag)
{
    return set_scene(r, ct, frags, nfrag, r->iso_hu, NULL, 1, NULL);
}

int render_set_prepared(render *r, const vol *ct, const frag *frags, int nfrag, const render_prep *p)
{
    int fits = p && p->nfrag == nfrag && p->iso_hu == r->iso_hu; /* else made here, as without it */
    return set_scene(r, ct, frags, nfrag, r->iso_hu, NULL, 1, fits ? p : NULL);
}

int render_set_hierarchies(render *r, const frag *frags, const obb_params *hp)
{
    int rc = 0;
    for (int i = 0; i < r->nfrag && !rc; i++)
        rc = upload_contacts(r, &r->frag[i], &frags[i], hp);
    return rc;
}

long render_surface_triangles(const render *r)
{
    long n = 0;
    for (int i = 0; i < r->nfrag; i++)
        n += r->frag[i].mesh_triangles;
    return n;
}
