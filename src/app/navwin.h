/* navwin: the window of `fracnav navigate --view window`. It draws the case's fragments at the
 * poses of a loop_scene (render.h, GLFW) with a HUD, turns the pointer into the camera (left drag
 * orbits, right or middle drag pans, the wheel zooms; keys 1-6 give the anterior, posterior,
 * left, right, superior and inferior views) and keeps the loop's camera frame on the view
 * (loop_set_camera), so "push right" moves the fragment right on screen. Every other key typed in
 * the window is handed back to the caller, which treats it as a terminal key.
 *
 * Threads: one thread opens, draws and closes a window (its GL context is current there); it only
 * reads the loop through the scenes it is given and loop_set_camera, so the loop never waits.
 * Errors: NULL or FN_E* with fn_err naming the cause (no display, GLFW missing, GL < 4.5). */
#ifndef FN_NAVWIN_H
#define FN_NAVWIN_H

#include "case.h"
#include "loop.h"

typedef struct navwin navwin;

#define NAVWIN_KEYS 64 /* keys handed back per frame at most */

/* A w x h window over c's fragments (c and L must outlive it). */
navwin *navwin_open(const planning_case *c, loop *L, int w, int h);
void navwin_close(navwin *w);

/* Handles the window's input, then draws sc (when it, the camera or hud changed since the last
 * frame) with hud's lines and the frame time. Up to cap typed keys go to keys (ASCII, 27 for
 * Escape); *close becomes 1 when the window was asked to close. Returns the keys stored, or FN_E*. */
int navwin_frame(navwin *w, const loop_scene *sc, const char *hud, int *keys, int cap, int *close);
/* The last frame drawn (HUD included) as a PNG file. 0 or FN_E*. */
int navwin_screenshot(navwin *w, const char *png);
/* The mean time of the frames drawn so far, ms (0 before the first). */
double navwin_frame_ms(const navwin *w);
/* The renderer's name (GL_RENDERER). */
const char *navwin_gl_renderer(const navwin *w);

#endif
