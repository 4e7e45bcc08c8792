/* navview: what `fracnav navigate` shows of a navigation session, as text laid out for a terminal.
 *
 * The scene (loop_scene_read) becomes fields in order of importance -- warnings, the selected
 * fragment and its contact, its pose in the patient's anatomical terms (how far its centroid moved
 * in mm right or left, anterior or posterior, inferior or superior: "moved 2.00 left, 0.50
 * posterior, 0.00 S/I mm"; its rotation in degrees and its rotation vector's parts about the L/R,
 * A/P and S/I axes, right-handed about left, posterior and superior, world LPS), the
 * frame, locks and rates, then the acknowledgement of the latest action -- packed into lines no
 * wider than the terminal, so that nothing is cut: a narrow terminal gets more lines. Off a
 * terminal the same fields make one line for a log. Pure functions: no I/O, no allocation. */
#ifndef FN_NAVVIEW_H
#define FN_NAVVIEW_H

#include "frag.h"
#include "loop.h"

#include <stddef.h>

/* What the view shows beside the scene. */
typedef struct navview_extra {
    int battery;         /* 0..100; -1 unknown (not shown) */
    const char *refused; /* NULL, or why the controller now at the device's path was not taken */
    const char *ack;     /* NULL, or the acknowledgement of the latest action (navview_ack) */
    const frag *frags;   /* the scene's fragments: the view shows how far the selected one's
                          * centroid has moved; NULL: the pose's translation */
    const char *fit;     /* NULL, or the running fit's progress ("fitting frag 2: ...") */
    const char *preview; /* NULL or "", or the live preview's figures (session_preview_text) */
} navview_extra;

/* The view of s for a terminal `width` columns wide: lines of at most width - 1 columns (the last
 * column stays free, so a line never wraps), separated by '\n', no trailing newline. width <= 0:
 * one line, the fields joined by " | " (a log). Returns the number of lines; buf (cap >= 1) is
 * cut short, at a line's end, when it is too small. */
int navview_format(const loop_scene *s, const navview_extra *x, int width, char *buf, size_t cap);

/* What s->last_action did, for the user: "next: frag 2/3", "undo: frag 2 back", "nothing to
 * undo", "collision checking OFF", ... */
void navview_ack(const loop_scene *s, char *buf, size_t cap);

/* The rotation of p as an angle in degrees (0..180) about a unit axis (x when there is none). */
double navview_rotation(const pose *p, double axis[3]);
/* A move d (world LPS, mm) in anatomical terms: "2.00 left, 0.50 posterior, 0.00 S/I mm". */
void navview_move_text(const double d[3], char *buf, size_t cap);
/* p's rotation in anatomical terms: "turned 3.00 deg: L/R +0.50, A/P -2.90, S/I +0.00" (the
 * rotation vector's parts, right-handed about left, posterior and superior), or "not turned". */
void navview_turn_text(const pose *p, char *buf, size_t cap);

/* The keys and controller buttons and what each does, one per line (lines of at most 79
 * columns). keyboard: the keys of --device keyboard, which steer instead. */
const char *navview_help(int keyboard);

#endif
