/* navwin: the window of `fracnav navigate --view window` and `fracnav replay --realtime`. It
 * draws the case's fragments at the poses of a loop_scene (render.h, GLFW) with a HUD, turns the
 * pointer into the camera (left drag orbits, right or middle drag pans, the wheel zooms; in four-up
 * the wheel over a slice moves it and a click there puts the slices' point; Ctrl+1..6
 * give the anterior, posterior, left, right, superior and inferior views) and, when it steers
 * (navigate), keeps the loop's camera frame on the view (loop_set_camera), so "push right" moves
 * the fragment right on screen; a window that only watches (replay) leaves the loop's camera
 * alone, so the recording's moves stay the recorded ones. The window's own keys are F-keys and
 * Ctrl+digits, so that no letter, digit or arrow a keyboard user steers with is taken: every other
 * key typed in the window is handed back to the caller, which treats it as a terminal key. The commands share --view
 * (navwin_view_option) and the opening it decides (navwin_open_view).
 *
 * Threads: one thread opens, draws and closes a window (its GL context is current there); it only
 * reaches the session through the scenes it is given, session_scene_read and session_set_camera,
 * so the loop never waits.
 * Errors: NULL or FN_E* with fn_err naming the cause (no display, GLFW missing, GL < 4.5). */
#ifndef FN_NAVWIN_H
#define FN_NAVWIN_H

#include "navview.h"
#include "render.h"
#include "session.h"

typedef struct navwin navwin;

#define NAVWIN_KEYS 64 /* keys handed back per frame at most */

/* How the window draws: --mode, --layout and --overlay, as `fracnav render` takes them. In the
 * window, keys change them: F2 the next mode, F3 the layout, F4 the principal axes, F5 the
 * contacts, F6 the hierarchy's boxes (F7 and F8 a level up or down), F9 the VOI. */
typedef struct navwin_look {
    int mode;             /* render_mode, or -1: surface on software GL, iso on a GPU */
    render_layout layout; /* four-up: the slices cut through the selected fragment's centroid */
    unsigned overlays;    /* RENDER_OVERLAY_*; voi when the case has a reduction VOI */
    int hierarchy_depth;  /* root = 1 */
    int camera;           /* --camera: a render_view, or -1: auto (render_camera_auto on the
                           * selected fragment, again at each change of the selection) */
} navwin_look;
#define NAVWIN_LOOK_DEFAULT {-1, RENDER_LAYOUT_3D, 0, 3, -1}
/* When a is --mode, --layout, --overlay or --camera: parses val into *look and returns 1 with *rc 0, or
 * with *rc 2 after a usage error for `cmd` that names the option and the value. Other a: 0. */
int navwin_look_option(const char *cmd, const char *a, const char *val, navwin_look *look, int *rc);
/* The window's keys and pointer, for a help text (lines ending in '\n'). */
const char *navwin_help(void);

/* A w x h window over the fragments of k's case (k must outlive it), drawn as look says (NULL:
 * the default). steer: the session's camera frame follows the view (navigate); 0: the window
 * only watches (replay). */
navwin *navwin_open(session *k, int steer, int w, int h, const navwin_look *look);
void navwin_close(navwin *w);

/* --view window|terminal (NAVWIN_VIEW_AUTO when not given). */
enum { NAVWIN_VIEW_AUTO, NAVWIN_VIEW_WINDOW, NAVWIN_VIEW_TERMINAL };
/* When a is --view: parses val into *view and returns 1 with *rc 0, or with *rc 2 after printing
 * a usage error for `cmd` that names the option. Other a: 0. */
int navwin_view_option(const char *cmd, const char *a, const char *val, int *view, int *rc);
/* Whether --view asks for a window that can be tried: 1 unless it is NAVWIN_VIEW_TERMINAL (0) or
 * $DISPLAY is unset (0, after "fracnav CMD: no window ($DISPLAY is not set): WITHOUT" on stderr). */
int navwin_wanted(const char *cmd, int view, const char *without);
/* The window --view asks for: NULL for NAVWIN_VIEW_TERMINAL; for the others, a 768x768 window
 * (navwin_open) when $DISPLAY is set and GL 4.5 works, else NULL after one line on stderr,
 * "fracnav CMD: no window (WHY): WITHOUT" (e.g. without = "the terminal view stays"). */
navwin *navwin_open_view(const char *cmd, int view, const navwin_look *look, const char *without, session *k,
                         int steer);

/* Handles the window's input, then draws sc (when it, the camera, the look or hud changed since
 * the last frame) with hud's lines, what the last window key did, the frame time, and the report
 * to frame time: from the arrival of the first report a frame shows to that frame on screen, at
 * most (the worst of the last second; the bound is the arrival of the newest report in the frame
 * before, so it may exceed the truth by one report period). Up to cap typed keys go to keys (ASCII,
 * 27 for Escape, F1 as '?', the arrows and Ctrl+letters as RENDER_KEY_*, a click on a slice as
 * NAVWIN_KEY_CLICK, and one on the 3D view's fragments too); *close becomes 1 when the window was asked to close. Returns the keys stored, or FN_E*. */
int navwin_frame(navwin *w, const loop_scene *sc, const char *hud, int *keys, int cap, int *close);
/* navwin_frame with the HUD of the terminal view: navview_format's lines of sc and x, then
 * "device: DEVICE", then help (NULL: none) followed by navwin_help(). */
int navwin_show(navwin *w, const loop_scene *sc, const navview_extra *x, const char *device, const char *help,
                int *keys, int cap, int *close);
/* A click on a slice of the four-up layout moves the slices there and comes back among the keys
 * as NAVWIN_KEY_CLICK, in the order it came with them (a piece chosen by a key and then clicked
 * is chosen first, though both arrive in one frame); so does a click on a fragment's surface in
 * the 3D view. navwin_click_at, called once for each NAVWIN_KEY_CLICK in their order, gives each
 * its own world point (LPS mm; two clicks in one frame were both given the last one's), where it
 * lies in the CT: on a slice, the point clicked (on a fragment, mapped back from its pose to its
 * home); on the surface, the first voxel of a fragment's mask along the view's ray, in the
 * fragment's home. 0, or -1 when the frame handed back no click. */
#define NAVWIN_KEY_CLICK RENDER_KEY_CLICK
int navwin_click_at(navwin *w, double world[3]);
/* The seed mode's preview: the window draws pieces[0..n-1] (the fragments a split would make, each
 * at its own pose; they must outlive the next call) in place of the case's fragments, until it is
 * called again; n 0 draws the case's again. prep: their crops and meshes made off this thread
 * (render_prepare at the case's level; NULL: made here). 0 or FN_E*. */
int navwin_set_pieces(navwin *w, const frag *pieces, int n, const render_prep *prep);
/* The marks on the four-up slices (the seed mode's seeds; render_options' marks): n of them (at
 * most RENDER_MAX_MARKS; 0 none), drawn from the next frame. */
void navwin_set_marks(navwin *w, int n, const double (*at)[3], const unsigned char (*rgb)[3]);
/* The last frame drawn (HUD included) at the loop's newest scene, as a PNG file. 0 or FN_E*. */
int navwin_screenshot(navwin *w, const char *png);
/* navwin_screenshot, its failure said on stderr as "fracnav CMD: --screenshot PNG: WHY". */
int navwin_save_screenshot(navwin *w, const char *cmd, const char *png);
/* The mean time of the frames drawn so far, ms (0 before the first). */
double navwin_frame_ms(const navwin *w);
/* The renderer's name (GL_RENDERER). */
const char *navwin_gl_renderer(const navwin *w);

#endif
