/* render: pictures of a case's fragments at their current poses, through OpenGL 4.5 core.
 *
 * One renderer behind this header. It draws into a GL context that a platform gives it: OSMesa
 * (llvmpipe, offscreen; libOSMesa is loaded with dlopen only then, since it exports its own GL
 * symbols) or a GLFW window when a display exists. Every GL function is reached through a pointer
 * that the platform resolves, so one binary serves both.
 *
 * What it draws (render_frame):
 *  - a single-pass raycaster over up to RENDER_MAX_FRAGS fragments, each a 3D texture of its CT crop
 *    masked by its label, placed by its own model matrix (home then pose) and drawn in its colour:
 *    iso (first hit, bisection refinement, gradient shading at the hit only), dvr (a 1D transfer
 *    function over HU, front-to-back, early ray termination) and mip. Empty space is skipped with a
 *    per-fragment occupancy grid of 4^3-voxel blocks. Rays step through all fragments together in
 *    world space, so interpenetrating fragments show where each is in front;
 *  - surface: per-fragment triangle meshes (marching tetrahedra over the masked CT at the iso level,
 *    decimated to a quarter of their triangles, normals from the CT's gradient; built once at
 *    render_set_scene, moved by the pose), rasterized with depth;
 *  - slice views (axial, coronal, sagittal through a point): the CT in grey, every fragment's
 *    outline (and a light fill) at its current pose in its colour; with the 3D view they make the
 *    four-up layout (render_four_up_panes: the 3D view large on top, the three slices below);
 *  - overlays on the 3D view: the hierarchy's boxes at a depth, the principal axes, the contacts
 *    (the gap to the other fragments as a colour on the surfaces, or the colliding voxel pairs
 *    tinted), the reduction's VOI boxes;
 *  - a HUD: lines of text over the frame (render_hud).
 *
 * Coordinates: world = patient LPS mm. The 3D camera is orthographic; a translation of d mm across
 * the view moves a fragment by d * height / (2 * half_height) pixels.
 *
 * Threads: a render handle belongs to the thread that opened it (its GL context is current there).
 * Errors: see err.h; every failure leaves a message naming the cause. */
#ifndef FN_RENDER_H
#define FN_RENDER_H

#include "frag.h"
#include "obb.h"
#include "pose.h"
#include "vol.h"

#include <stdint.h>

#define RENDER_MAX_FRAGS 16
#define RENDER_MAX_MARKS 64

typedef struct render render;

typedef enum { RENDER_ISO, RENDER_DVR, RENDER_MIP, RENDER_SURFACE } render_mode;
typedef enum { RENDER_LAYOUT_3D, RENDER_LAYOUT_FOUR_UP } render_layout;
typedef enum {
    RENDER_ANTERIOR, RENDER_POSTERIOR, RENDER_LEFT, RENDER_RIGHT, RENDER_SUPERIOR, RENDER_INFERIOR
} render_view;

/* An orthographic camera: it looks along forward (unit) with up (unit, orthogonal to forward)
 * through centre; half_height mm of the world fill half the picture's height; depth mm on either
 * side of centre are inside the clip range. Screen right = forward x up. */
typedef struct render_camera {
    double centre[3], forward[3], up[3];
    double half_height, depth;
} render_camera;

/* Overlays on the 3D view. HIERARCHY and CONTACTS need the hierarchies (render_set_scene's hp,
 * or render_set_hierarchies, which also build each fragment's distance map): in surface and iso
 * mode CONTACTS colours every surface point by its gap to the nearest other fragment (its distance
 * map, less half a voxel) from red at 0 through yellow at 1.5 mm to the fragment's own colour
 * at 3 mm and beyond, and draws the legend (the bar and its mm) at the 3D view's bottom right
 * (iso needs a texture unit per fragment beyond the raycaster's 21: up to 11 fragments on
 * llvmpipe's 32); in dvr and mip, and in iso beyond that, it tints the contact region (a translucent yellow over both voxels of
 * every colliding voxel pair, obb_collide, up to RENDER_MAX_CONTACTS per fragment pair, at the
 * frame's poses) and outlines those voxels. VOI outlines the options' VOI boxes (world mm) in
 * cyan. */
enum {
    RENDER_OVERLAY_HIERARCHY = 1, RENDER_OVERLAY_AXES = 2, RENDER_OVERLAY_CONTACTS = 4,
    RENDER_OVERLAY_VOI = 8
};
#define RENDER_MAX_CONTACTS 4096

typedef struct render_options {
    render_mode mode;
    render_layout layout;
    render_camera camera;
    double slice_point[3];  /* world mm: where the slice views cut (four-up) */
    unsigned overlays;      /* RENDER_OVERLAY_* */
    int hierarchy_depth;    /* the depth of the boxes drawn (root = 1) */
    int nvoi;               /* RENDER_OVERLAY_VOI: boxes lo x y z, hi x y z (world mm) */
    int cutaway;            /* 0: none; i + 1: in surface and iso mode, the other fragments in
                             * front of fragment i (nearer the viewer than its crop's nearest
                             * corner, within a cylinder of 3/8 of its crop's diagonal around the
                             * line from its centroid to the viewer) are cut away, so the piece
                             * in hand is always seen (dvr and mip draw them all) */
    double voi[RENDER_MAX_FRAGS][6];
    int ghost;              /* 0: none; i + 1: on the 3D view, fragment i's surface drawn again at
                             * ghost_pose, translucent and light, over everything (navigate's live
                             * preview of the fit) */
    pose ghost_pose;
    double four_up_split;   /* four-up: the 3D view's share of the height, RENDER_SPLIT_MIN..MAX
                             * (0: two thirds) */
    int nmarks;             /* four-up: points marked on the slices (the seed mode's seeds), each
                             * a square of RENDER_MARK_PX pixels in mark_rgb ringed in black, on
                             * every slice whose plane passes within RENDER_MARK_MM of it */
    double marks[RENDER_MAX_MARKS][3]; /* world mm */
    unsigned char mark_rgb[RENDER_MAX_MARKS][3];
} render_options;
#define RENDER_MARK_PX 7
#define RENDER_MARK_MM 2.0
#define RENDER_SPLIT_MIN 0.25
#define RENDER_SPLIT_MAX 0.9

/* Opens a GL 4.5 core context of w x h pixels. platform: "osmesa" (offscreen, llvmpipe), "egl"
 * (offscreen on a GPU's EGL device, no display needed; FN_ENODEV where there is none),
 * "offscreen" (egl where a GPU's EGL device is there, else osmesa), "glfw" (a window; needs a
 * display and a build with GLFW) or NULL (glfw when $DISPLAY is set and GLFW was built in, else
 * offscreen). A GL older than 4.5 is FN_ENODEV with a message naming the version found and what
 * to install. NULL with fn_err on failure. */
render *render_open(const char *platform, int w, int h);
void render_close(render *r);
/* GL_RENDERER and GL_VERSION of the context (valid while r is open). */
const char *render_gl_renderer(const render *r);
const char *render_gl_version(const render *r);
/* The interactive mode for r's GL: surface on software GL (llvmpipe, softpipe), which rasterizes
 * meshes far faster than it casts rays; iso on a GPU. */
render_mode render_default_mode(const render *r);

/* Uploads the scene: the fragments' masked CT crops, occupancy grids, meshes (iso_hu is the
 * surface level: values >= iso_hu are bone) and, when hp is given, their hierarchies (and distance maps) for the box
 * overlay. ct gives the grey of the slice views and the values of the crops; ct may be NULL (the
 * crops then hold iso_hu + 500 inside, and slices show no grey). At most RENDER_MAX_FRAGS
 * fragments (FN_EINVAL names the count). Replaces any previous scene. 0 or FN_E*. */
int render_set_scene(render *r, const vol *ct, const frag *frags, int nfrag, double iso_hu,
                     const obb_params *hp);
/* Replaces the scene's fragments (as render_set_scene, without hierarchies), keeping the CT
 * texture and the surface level that render_set_scene uploaded: ct must be that same volume,
 * unchanged (its values fill the crops). For a scene whose fragments change over one CT (the seed
 * mode's preview): the CT is not uploaded again. 0 or FN_E*. */
int render_set_fragments(render *r, const vol *ct, const frag *frags, int nfrag);
/* render_set_fragments in two halves, so that the slow one stays off the window's thread (the
 * seed mode's preview: its worker prepares the pieces it grew). render_prepare, on any thread, no
 * GL: the fragments' masked crops of ct and their surface meshes at level iso_hu (render_iso_hu
 * of the render they are for), on up to `threads` threads (1..RENDER_PREP_THREADS: the caller's
 * and threads - 1 of its own, a fragment each in turn); NULL with fn_err (FN_EINVAL: more than
 * RENDER_MAX_FRAGS, or FN_ENOMEM). render_set_prepared, on r's thread: render_set_fragments with p's crops and meshes
 * (p made from these frags and ct; one made at another level or for another count is not used,
 * and the fragments are then prepared here). p stays the caller's. */
typedef struct render_prep render_prep;
#define RENDER_PREP_THREADS 8
render_prep *render_prepare(const vol *ct, const frag *frags, int nfrag, double iso_hu, int threads);
void render_prep_free(render_prep *p);
double render_iso_hu(const render *r);
int render_set_prepared(render *r, const vol *ct, const frag *frags, int nfrag, const render_prep *p);
/* Builds the hierarchies and distance maps of the scene's fragments (frags as given to
 * render_set_scene) for the hierarchy and contacts overlays, when render_set_scene was given none
 * (a window that turns those overlays on later). 0 or FN_ENOMEM. */
int render_set_hierarchies(render *r, const frag *frags, const obb_params *hp);
/* Triangles of the surface meshes of the scene. */
long render_surface_triangles(const render *r);

/* Draws one frame with fragment i at poses[i] (NULL: each fragment's own pose). 0 or FN_E*
 * (FN_EINVAL: the hierarchy or contacts overlay without hierarchies). */
int render_frame(render *r, const pose *poses, const render_options *o);
/* A frame in two parts, for the least delay from a pose to the picture that shows it ("late
 * latching"): render_frame_early draws every fragment but `late` at poses and hands that work to
 * the GL (glFlush), which rasterizes it while the caller reads the newest poses; render_frame_late
 * then draws fragment `late` at its newest pose, and the overlays, over it. The split needs surface
 * mode, the 3D layout, no contacts overlay, and poses (not NULL) whose other entries are the early
 * ones: otherwise render_frame_early draws nothing and render_frame_late draws the whole frame
 * (render_frame). Same options for both. 0 or FN_E*, as render_frame. */
int render_frame_early(render *r, const pose *poses, int late, const render_options *o);
int render_frame_late(render *r, const pose *poses, const render_options *o);
/* Reads the last frame as 8-bit RGB, rows top to bottom (w*h*3 bytes). Waits for the frame. */
int render_read_rgb(render *r, uint8_t *rgb);
/* Shows the last frame in the window (no-op offscreen). */
int render_present(render *r);

/* Text over the last frame, top left, on a dark translucent box: lines separated by '\n', in a
 * built-in 5x7 font (capitals and small letters; bytes outside ASCII as '?') scaled by `scale`
 * (1..4) pixels per font pixel; a line holding "WARNING" or "OFF" is drawn in amber. Call after
 * render_frame, before render_read_rgb or render_present. 0 or FN_E*. */
int render_hud(render *r, const char *text, int scale);
/* The HUD's scale for r: one font pixel per 384 rows of the picture, times the window's content
 * scale (its DPI over 96; 1 offscreen), 1..4. */
int render_hud_scale(const render *r);
/* The same for a picture of `height` rows on a display of dpi_scale (its DPI over 96). */
int render_hud_scale_for(int height, double dpi_scale);
/* The characters of a HUD line that fit across r at render_hud_scale. */
int render_hud_columns(const render *r);

/* Input that reached the window since the last call (nothing offscreen). */
#define RENDER_INPUT_KEYS 64
#define RENDER_INPUT_CLICKS 8
/* Enter and Backspace come as '\r' and '\b'. A click comes as RENDER_KEY_CLICK where it
 * happened among the keys, so a key typed before it in the same frame is handled first. Keys beyond ASCII in render_input.keys: F1..F12
 * (RENDER_KEY_F1 + n - 1 for Fn), the arrows, and Ctrl with a digit or a letter (RENDER_KEY_CTRL | '1', RENDER_KEY_CTRL | 'a'). The F-keys and
 * the arrows come again while held (key repeat). */
enum {
    RENDER_KEY_ESCAPE = 27,
    RENDER_KEY_F1 = 0x100,
    RENDER_KEY_LEFT = 0x110, RENDER_KEY_RIGHT, RENDER_KEY_UP, RENDER_KEY_DOWN,
    RENDER_KEY_CLICK = 0x120, /* + i: the frame's left click i (at render_input.click[i]), in its
                               * place among the keys */
    RENDER_KEY_CTRL = 0x200
};
typedef struct render_input {
    int keys[RENDER_INPUT_KEYS]; /* characters typed (ASCII) and RENDER_KEY_*, in order */
    int nkeys;
    double drag[3][2]; /* the pointer's movement in pixels (x right, y down) while the left, right
                        * or middle button was held */
    double scroll;     /* wheel steps, positive away from the user */
    double x, y;       /* the pointer, pixels from the top left */
    int nclicks;       /* the left button was pressed and released without a drag, at click[i] */
    int left_down;     /* the left button is held now */
    double press[2];   /* with a left drag: where the left button went down */
    double click[RENDER_INPUT_CLICKS][2];
    int close;         /* the window was asked to close */
} render_input;
int render_poll(render *r, render_input *in);

/* The standard camera for view v fitted to the fragments at their home positions (so poses move
 * pictures, not the camera). */
void render_camera_standard(render_camera *c, render_view v, const frag *frags, int nfrag);
/* The auto view (`--view auto`): the camera that frames fragment `selected` at poses[selected]
 * (NULL: each fragment's own pose) with its surroundings, looking from the side where it is seen
 * best: of the six named views, its principal axes both ways and the view from its side onto the
 * nearest other fragment, the one where the largest share of its projected pixels is visible
 * (render_fragment_pixels), ties going to a view across the line between the two (the fracture
 * seen from the side). r must hold the scene of frags (render_set_scene). Draws into the frame
 * (call before render_frame). A selected out of range gives the anterior view. 0 or FN_E*. */
int render_camera_auto(render *r, render_camera *c, const frag *frags, int nfrag, const pose *poses, int selected);
/* What a picture through o's camera shows of each fragment of r's scene (at poses; NULL: their
 * own), drawn as the surface meshes (with o's cut-away): projected[i] the pixels fragment i covers
 * drawn alone, visible[i] those where it is the front-most (arrays of r's fragment count). Draws
 * into the frame (call it after reading a frame, or before drawing one). 0 or FN_E*. */
int render_fragment_pixels(render *r, const pose *poses, const render_options *o, long *projected, long *visible);
/* Defaults: iso, 3D layout, anterior camera over the fragments, slice point at the first
 * fragment's home centroid, no overlay, hierarchy depth 3. */
void render_options_default(render_options *o, const frag *frags, int nfrag);

/* The four-up layout of a w x h picture, as 3D Slicer's "3D and three slices": the 3D view over
 * the top `split` of the height (render_options.four_up_split, clamped to RENDER_SPLIT_MIN..MAX;
 * 0: two thirds), the axial, coronal and sagittal slices side by side below it. rect[pane] =
 * {x, y, width, height}, pixels from the top left. */
enum { RENDER_PANE_AXIAL, RENDER_PANE_CORONAL, RENDER_PANE_SAGITTAL, RENDER_PANE_3D };
void render_four_up_panes(int w, int h, double split, int rect[4][4]);
/* The world point (mm) that pixel (x, y) (from the top left) of r's four-up frame of o shows in
 * its slice pane, into world; returns the pane (RENDER_PANE_AXIAL..SAGITTAL), or -1 when (x, y)
 * is in the 3D view or between the panes. */
int render_slice_point_at(const render *r, const render_options *o, double x, double y, double world[3]);
/* The unit normal of a slice pane's plane (axial: z, coronal: y, sagittal: x). */
void render_slice_normal(int pane, double n[3]);
/* The size of r's frame (a resized window's, since the last render_poll). */
void render_size(const render *r, int *w, int *h);

/* Names to and from the enums: 0 on success, FN_EINVAL for an unknown name. */
int render_mode_parse(const char *s, render_mode *m);
int render_view_parse(const char *s, render_view *v);
int render_layout_parse(const char *s, render_layout *l);
/* "hierarchy:3,axes,contacts,voi" (comma-separated; DEPTH 1..32) into *overlays' bits (added to
 * those set) and *depth (when given). 0, or FN_EINVAL naming the item that is wrong. */
int render_overlays_parse(const char *s, unsigned *overlays, int *depth);
const char *render_mode_name(render_mode m);

/* Parses a GL_VERSION string ("4.5 (Core Profile) Mesa 22.3.6", "OpenGL ES 3.2 ...") into
 * major.minor. 0, or FN_EFORMAT when it holds no version. */
int render_parse_gl_version(const char *s, int *major, int *minor);

#endif
