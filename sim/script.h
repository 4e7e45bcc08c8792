/* script: scripted motion for the virtual device.
 *
 * A script is text, one command per line ('#' starts a comment):
 *   translate +x 20 mm over 2 s      (axes x y z, sign optional; device frame, see simdev.h)
 *   rotate z -15 deg over 1 s        (about x y z)
 *   move x 10 mm y -5 mm rz 3 deg over 0.5 s   (several axes at once)
 *   press 1          release 1          release          (buttons numbered from 1; bare = all)
 *   wait 0.5 s       unplug             replug
 * Motion commands hold a constant deflection for the given time, then let go (the device then sends
 * its zeros); "hold" before a motion keeps the cap deflected into the next command.
 *
 * Units -> counts. The loop, at its default sensitivity (1.0), moves a fragment at
 * SCRIPT_MM_PER_S_FULL mm/s (translation) and SCRIPT_DEG_PER_S_FULL deg/s (rotation) when an axis
 * reads SCRIPT_FULL_COUNTS, linearly in between: counts = speed / full_speed * SCRIPT_FULL_COUNTS.
 * A move of D over T seconds is rendered as the speed D/T; the counts are quantized per report with
 * the rounding error carried forward, so the integral over the move is exact to one count-period. */
#ifndef FN_SCRIPT_H
#define FN_SCRIPT_H

#include <stddef.h>
#include <stdint.h>

#include "fnrec.h"
#include "simdev.h"

#define SCRIPT_FULL_COUNTS 350
#define SCRIPT_MM_PER_S_FULL 50.0
#define SCRIPT_DEG_PER_S_FULL 45.0
#define SCRIPT_MAX_STEPS 4096
#define SCRIPT_MAX_SECONDS 3600.0

typedef enum script_op {
    SCRIPT_MOVE,    /* axes speeds for a duration */
    SCRIPT_PRESS,   /* buttons |= mask */
    SCRIPT_RELEASE, /* buttons &= ~mask */
    SCRIPT_WAIT,
    SCRIPT_UNPLUG,
    SCRIPT_REPLUG
} script_op;

typedef struct script_step {
    script_op op;
    double speed[6];   /* MOVE: mm/s for x y z, deg/s for rx ry rz (device frame) */
    double seconds;    /* MOVE, WAIT */
    unsigned mask;     /* PRESS, RELEASE */
    int hold;          /* MOVE: keep the deflection after the move (no release) */
    int line;
} script_step;

typedef struct script {
    script_step step[SCRIPT_MAX_STEPS];
    size_t n;
} script;

/* Parses a script. name is used in messages ("NAME:LINE: ..."). Returns 0 or FN_EFORMAT/FN_ENOMEM;
 * *out is a new script (free()) or NULL. */
int script_parse(const char *text, size_t len, const char *name, script **out);
/* Reads and parses a file; NULL on failure. */
script *script_load(const char *path);
/* Renders the script into the reports profile p sends at its cadence, from a connect event at 0 to
 * the last report. Deterministic. NULL on failure (e.g. a speed above full deflection). */
fnrec *script_render(const script *s, const sim_profile *p);
/* As script_render, on a device whose settings (cadence, zeros, offsets: the open controller's
 * feature reports) are those of live: what a served device plays once the host has set them. */
fnrec *script_render_live(const script *s, const simdev *live);
/* Renders s as the continuation of a session on the device live (its profile and settings): it is
 * already connected and idle with the buttons *held down, so there is no connect event and no
 * power-on report; times start at 0 = now. *held becomes the buttons held at the end. For live
 * control (fracnav-sim --control). */
fnrec *script_render_more(const script *s, const simdev *live, uint32_t *held);
/* Fills hdr with profile p's identity, source "virtual:<id>". */
void script_header(const sim_profile *p, fnrec_header *hdr);

#endif
