/* framedump: `fracnav replay --frames DIR`: one picture per N ms of a recording's time, drawn
 * headless (render.h through OSMesa) at the session's poses, as DIR/frame_NNNNN.png.
 *
 * Frame k shows the poses after every event stamped up to t0 + k * N ms (t0: the first event's
 * stamp), so a pause in the recording repeats its picture, and the last frame shows the final
 * poses. Single thread (the one that steps the session: session_play_each). Errors: NULL or FN_E* with fn_err naming
 * the file or the cause. */
#ifndef FN_FRAMEDUMP_H
#define FN_FRAMEDUMP_H

#include "navwin.h"
#include "session.h"

#include <stdint.h>

typedef struct framedump framedump;

/* Creates dir (it may exist) and an offscreen renderer of c's fragments (w x h, anterior view)
 * drawn as look says (its mode -1: iso; in four-up the slices cut through the selected fragment's
 * centroid at its pose); frame_ms > 0. */
framedump *framedump_open(const char *dir, const planning_case *c, double frame_ms, int w, int h,
                          const navwin_look *look);
/* Before k steps an event stamped t_us: writes the frames due before it (session_pose). */
int framedump_before(framedump *d, const session *k, int64_t t_us);
/* After the last event: the final frame. */
int framedump_finish(framedump *d, const session *k);
/* Frames written so far. */
long framedump_count(const framedump *d);
void framedump_close(framedump *d);

#endif
