/* render internals: the GL function table, the platform seam and the handle. */
#ifndef FN_RENDER_IMPL_H
#define FN_RENDER_IMPL_H

#include "mesh.h"
#include "render.h"

#include <GL/glcorearb.h>

/* Every GL function the renderer calls; the platform resolves each by name ("gl" + NAME). */
#define RENDER_GL_FUNCS(X)                                                                        \
    X(PFNGLGETSTRINGPROC, GetString) X(PFNGLGETINTEGERVPROC, GetIntegerv)                          \
    X(PFNGLGETERRORPROC, GetError) X(PFNGLVIEWPORTPROC, Viewport) X(PFNGLENABLEPROC, Enable)       \
    X(PFNGLDISABLEPROC, Disable) X(PFNGLCLEARPROC, Clear) X(PFNGLCLEARCOLORPROC, ClearColor)       \
    X(PFNGLSCISSORPROC, Scissor) X(PFNGLREADPIXELSPROC, ReadPixels)                                \
    X(PFNGLPIXELSTOREIPROC, PixelStorei) X(PFNGLFINISHPROC, Finish) X(PFNGLFLUSHPROC, Flush)       \
    X(PFNGLGENTEXTURESPROC, GenTextures) X(PFNGLDELETETEXTURESPROC, DeleteTextures)                \
    X(PFNGLBINDTEXTUREPROC, BindTexture) X(PFNGLACTIVETEXTUREPROC, ActiveTexture)                  \
    X(PFNGLTEXIMAGE3DPROC, TexImage3D) X(PFNGLTEXIMAGE1DPROC, TexImage1D)                          \
    X(PFNGLTEXPARAMETERIPROC, TexParameteri) X(PFNGLCREATESHADERPROC, CreateShader)                \
    X(PFNGLSHADERSOURCEPROC, ShaderSource) X(PFNGLCOMPILESHADERPROC, CompileShader)                \
    X(PFNGLGETSHADERIVPROC, GetShaderiv) X(PFNGLGETSHADERINFOLOGPROC, GetShaderInfoLog)            \
    X(PFNGLDELETESHADERPROC, DeleteShader) X(PFNGLCREATEPROGRAMPROC, CreateProgram)                \
    X(PFNGLATTACHSHADERPROC, AttachShader) X(PFNGLLINKPROGRAMPROC, LinkProgram)                    \
    X(PFNGLGETPROGRAMIVPROC, GetProgramiv) X(PFNGLGETPROGRAMINFOLOGPROC, GetProgramInfoLog)        \
    X(PFNGLUSEPROGRAMPROC, UseProgram) X(PFNGLDELETEPROGRAMPROC, DeleteProgram)                    \
    X(PFNGLGETUNIFORMLOCATIONPROC, GetUniformLocation) X(PFNGLUNIFORM1IPROC, Uniform1i)            \
    X(PFNGLUNIFORM1FPROC, Uniform1f) X(PFNGLUNIFORM1IVPROC, Uniform1iv) X(PFNGLUNIFORM1FVPROC, Uniform1fv)                            \
    X(PFNGLUNIFORM2FPROC, Uniform2f) X(PFNGLUNIFORM3FVPROC, Uniform3fv)                            \
    X(PFNGLUNIFORM4FPROC, Uniform4f) X(PFNGLUNIFORM4IVPROC, Uniform4iv)                            \
    X(PFNGLUNIFORM4FVPROC, Uniform4fv)                                                             \
    X(PFNGLUNIFORMMATRIX4FVPROC, UniformMatrix4fv) X(PFNGLUNIFORMMATRIX3FVPROC, UniformMatrix3fv)  \
    X(PFNGLGENVERTEXARRAYSPROC, GenVertexArrays) X(PFNGLBINDVERTEXARRAYPROC, BindVertexArray)      \
    X(PFNGLDELETEVERTEXARRAYSPROC, DeleteVertexArrays) X(PFNGLGENBUFFERSPROC, GenBuffers)          \
    X(PFNGLBINDBUFFERPROC, BindBuffer) X(PFNGLBUFFERDATAPROC, BufferData)                          \
    X(PFNGLDELETEBUFFERSPROC, DeleteBuffers) X(PFNGLVERTEXATTRIBPOINTERPROC, VertexAttribPointer)  \
    X(PFNGLENABLEVERTEXATTRIBARRAYPROC, EnableVertexAttribArray) X(PFNGLDRAWARRAYSPROC, DrawArrays)    \
    X(PFNGLDEPTHFUNCPROC, DepthFunc) X(PFNGLDEPTHMASKPROC, DepthMask) X(PFNGLCLEARDEPTHPROC, ClearDepth) \
    X(PFNGLTEXIMAGE2DPROC, TexImage2D) X(PFNGLGENFRAMEBUFFERSPROC, GenFramebuffers)                 \
    X(PFNGLDELETEFRAMEBUFFERSPROC, DeleteFramebuffers) X(PFNGLBINDFRAMEBUFFERPROC, BindFramebuffer) \
    X(PFNGLFRAMEBUFFERTEXTURELAYERPROC, FramebufferTextureLayer) X(PFNGLDRAWBUFFERPROC, DrawBuffer) \
    X(PFNGLBLENDEQUATIONPROC, BlendEquation) X(PFNGLDRAWELEMENTSPROC, DrawElements) \
    X(PFNGLCULLFACEPROC, CullFace) X(PFNGLBLENDFUNCPROC, BlendFunc) X(PFNGLCOLORMASKPROC, ColorMask) \
    X(PFNGLCHECKFRAMEBUFFERSTATUSPROC, CheckFramebufferStatus)

typedef struct render_gl {
#define RENDER_GL_MEMBER(type, name) type name;
    RENDER_GL_FUNCS(RENDER_GL_MEMBER)
#undef RENDER_GL_MEMBER
} render_gl;

/* A platform gives the renderer a current GL 4.5 core context. open leaves fn_err on failure
 * (0 or FN_E*); proc resolves "glXxx" (NULL when missing); present shows the frame (window) or
 * does nothing (offscreen); close frees what open made. */
typedef struct render_platform {
    const char *name;
    int available; /* built in */
    int (*open)(render *r, int w, int h);
    void *(*proc)(render *r, const char *name);
    int (*present)(render *r);
    int (*poll)(render *r, render_input *in); /* NULL: no input (offscreen) */
    float (*content_scale)(const render *r);      /* NULL: 1 (offscreen) */
    void (*close)(render *r);
} render_platform;

extern const render_platform render__osmesa;
extern const render_platform render__glfw; /* not available when built without GLFW */
extern const render_platform render__egl;  /* a GPU's EGL device, headless */
/* Whether a GPU's EGL device is there (libEGL loads and lists a device that is not software). */
int render__egl_gpu(void);

/* GPU resources of one fragment. */
typedef struct render_frag {
    unsigned tex;          /* R16F 3D texture: the masked CT crop (masked_crop) */
    int dim[3], occ_dim[3], occ_z;
    double local_to_tc[3]; /* texture coordinate = local mm * this + 0.5 / dim */
    pose home, pose; /* as segmented; the pose given at render_set_scene */
    double spacing[3];
    float rgb[3];
    unsigned mesh_vao, mesh_vbo, mesh_ibo; /* welded: unique vertices and 32-bit indices */
    long mesh_triangles;
    unsigned proxy_vao, proxy_vbo; /* the occupied bricks' boundary faces, local mm (triangles) */
    int proxy_vertices;
    obb_tree *tree;            /* for the box overlay; NULL without one */
    unsigned dist_tex;         /* with the tree, R16F 3D: the distance (mm) from each voxel of the
                                * crop to the fragment's nearest voxel, up to RENDER_DIST_MAX_MM */
    unsigned box_vao, box_vbo; /* the boxes' edges at box_depth, local mm */
    int box_depth, box_vertices;
    double centroid[3], axes[3][3], eigval[3];
} render_frag;

#define RENDER_OUTSIDE_HU (-1024.0f) /* outside the CT */
#define RENDER_OUTSIDE_MARGIN 100.0   /* outside the label: at most iso - this */
#define RENDER_BLOCK 4
#define RENDER_PROXY_BLOCKS 1 /* a raycaster's brick is this many blocks along each axis */
#define RENDER_MESH_KEEP 0.25/* the share of a surface mesh's triangles kept by decimation */
#define RENDER_DIST_MAX_MM 16.0 /* the distance maps hold at most this: far beyond the gap scale */
#define RENDER_GAP_SCALE_MM 3.0 /* the contacts colour: red at 0, yellow at half, none from this */

struct render {
    const render_platform *plat;
    void *plat_state;
    int w, h;
    render_gl gl;
    char renderer[256], version[256];
    unsigned prog_ray[3]; /* per raycast mode, compiled for the scene on first use (0: not yet) */
    unsigned prog_gaps;   /* the surface with the contacts colour, the same way */
    unsigned prog_ray_gaps; /* iso with the contacts colour and the cut-away, the same way */
    unsigned prog_ray_cut;  /* iso with the cut-away (render_options.cutaway), the same way */
    unsigned prog_slice, prog_mesh, prog_line, prog_depth, prog_hud, prog_id;
    unsigned hud_tex;
    unsigned vao_empty, line_vao, line_vbo;
    /* Per fragment, the nearest and farthest depth of its occupied bricks: 2D array textures of
     * w x h RGBA16F, fragment i in layer i / 4, channel i % 4 (made per scene). */
    unsigned span_fbo, span_tex[2];
    int span_layers;
    unsigned occ_tex, tf_tex, ct_tex;
    int have_ct;
    double ct_w2t[4][4]; /* world -> CT texture coordinates */
    int nfrag;
    render_frag frag[RENDER_MAX_FRAGS];
    double iso_hu, min_spacing;
    /* render_frame_early's part of the frame: the fragment left for render_frame_late (-1: no
     * early part drawn) and the poses the others were drawn at. */
    int early_late;
    pose early_pose[RENDER_MAX_FRAGS];
};

/* GLSL sources (render_shader.c). */
extern const char *const render__ray_fs, *const render__ray_vs, *const render__quad_vs, *const render__proxy_vs,
    *const render__depth_fs, *const render__hud_fs, *const render__slice_fs,
    *const render__mesh_vs, *const render__mesh_fs, *const render__id_fs, *const render__line_vs, *const render__line_fs;

/* Text as render_hud draws it, its box's top-left corner at pixel (x, y) from the frame's top left.
 * render__text_size gives the box's size. Leaves the scissor test off. 0 or FN_E*. */
int render__text(render *r, const char *text, int scale, int x, int y);
void render__text_size(const char *text, int scale, int *w, int *h);
/* The contacts colour's ramp: the colours at 0 and at RENDER_GAP_SCALE_MM / 2 (render_hud.c). */
extern const float render__gap_ramp[2][3];
/* The contacts colour's legend at the bottom right of viewport vp (GL's, from the bottom left):
 * its label, the bar and its mm, at render_hud_scale. Leaves the scissor test off. 0 or FN_E*. */
int render__gap_legend(render *r, const int vp[4]);

/* The raycaster for mode m, gaps (iso with the contacts colour) and cut (iso with the cut-away),
 * compiled for the scene when it is not yet (r->prog_ray[m], prog_ray_gaps, which cuts too, or
 * prog_ray_cut), into *prog (render.c). 0 or FN_E*. */
int render__ray_program(render *r, render_mode m, int gaps, int cut, unsigned *prog);
/* Compiles r->prog_gaps for the scene (of 2 fragments or more) when it is not yet (render.c). 0
 * or FN_E*. */
int render__gaps_program(render *r);

#endif
