/* navseed: the window's seed mode, which separates fragments from a click per piece (3D Slicer's
 * "Grow from seeds"). F10 enters and leaves it; while it is on, a digit 1-9 chooses the piece the
 * next seed marks, a click on a slice of the four-up layout or on a fragment's surface in the 3D
 * view drops a seed there (NAVWIN_KEY_CLICK), Backspace takes the last seed back, and Enter
 * accepts: the caller then separates every fragment that holds seeds (navseed_apply,
 * case_separate_all's competitive growth). After each seed and each Backspace, navseed_preview
 * grows the pieces the seeds would make, for the window to show in their colours before Enter.
 * While it is on, the digits are its own, not the steering keys'.
 *
 * The separation is saved as an undoable edit (navseed_undo takes it back) and survives a crash
 * (navseed_recover).
 *
 * Threads: the window's (the caller's); the preview grows on a worker of its own
 * (navseed_preview). Errors: navseed_apply returns FN_E* with fn_err naming the seed's world
 * point. */
#ifndef FN_NAVSEED_H
#define FN_NAVSEED_H

#include "case.h"

#include <pthread.h>
#include <stdatomic.h>

struct render_prep; /* render.h */

#define NAVSEED_MAX 64 /* seeds at most; more are refused with a note */

typedef struct navseed {
    int on;       /* seed mode is on */
    int piece;    /* the piece the next seed marks, 1..9 */
    int n;        /* seeds dropped */
    case_seed seed[NAVSEED_MAX];
    int accepted; /* Enter was pressed with seeds: the caller clears it and separates */
    int changed;  /* the seeds changed since the last navseed_preview */
    case_preview *preview;
    const frag *pieces; /* the preview: the fragments the seeds would make (npieces, 0: none),
                         * valid until the next job starts (the frame after they were shown) */
    int npieces;
    case_seed marked[NAVSEED_MAX]; /* the seeds when the preview was taken, nmarked of them, */
    unsigned char mark_rgb[NAVSEED_MAX][3]; /* and the colour of the piece that held each */
    int nmarked;
    struct render_prep *prep; /* their crops and meshes, made on the worker (NULL: none made), valid
                         * until the next navseed_preview: navwin_set_pieces uploads them */
    /* The preview's growth runs on a worker thread, a job at a time: while running, the worker
     * alone touches preview and the job's fields, until it sets done. */
    pthread_t worker;
    int running;
    atomic_int done;
    const planning_case *job_case;
    case_seed job_seed[NAVSEED_MAX];
    int job_n, job_nposes;
    pose *job_poses;      /* malloc'd, job_nposes; NULL: the fragments' own */
    int job_result;       /* case_preview_update's */
    const frag *job_pieces;
    struct render_prep *job_prep; /* render_prepare of job_pieces at the case's level (the window's) */
    double job_ms;
    char job_error[256];
    char status[512];
} navseed;

void navseed_init(navseed *s);
/* Waits for the preview's worker and frees the preview (before its case goes), with a job that
 * ended unseen: the next navseed_preview starts from none. */
void navseed_free(navseed *s);
/* A key typed in the window (navwin_frame's codes). Returns 1 when it was seed mode's (F10 always;
 * digits, Backspace and Enter while it is on), 0 when it goes on as before. */
int navseed_key(navseed *s, int k);
/* A click on a slice or the surface (NAVWIN_KEY_CLICK at world, LPS mm): drops a seed of the
 * current piece there while seed mode is on. */
void navseed_click(navseed *s, const double world[3]);
/* The preview of the split, called at every frame: when the seeds changed, a worker thread grows
 * the fragments Enter would make of c (case_preview_update: after a new seed only its growth is
 * updated; each piece at its parent's pose of poses, nposes of them; NULL: their own), and when it
 * is done, s->pieces become them (their crops and meshes made there too, s->prep), or none when
 * seed mode is off, has no seed or a seed is bad (the status says why). The window never waits for the growth; c must stay the same until
 * navseed_free, and only its labels, CT and fragments' voxels are read off the caller's thread.
 * Returns 1 when s->pieces changed, 0 when not. */
int navseed_preview(navseed *s, const planning_case *c, const pose *poses, int nposes);
/* The seeds as marks for the window's slices (at most cap): each at its point, in the colour of
 * the previewed piece that holds it, white where none does (no preview yet, or a seed the
 * preview left out). The count; 0 while seed mode is off. */
int navseed_marks(const navseed *s, double (*at)[3], unsigned char (*rgb)[3], int cap);
/* One line for the HUD while seed mode is on (the piece, the seeds and the keys); NULL when off. */
const char *navseed_status(const navseed *s);
/* The seed mode's keys, for a help text (lines ending in '\n'). */
const char *navseed_help(void);
/* Separates c's fragments from the seeds (case_separate_all) and empties the seed list. Returns
 * the new fragments made, or FN_E* (the seeds are kept, so the user can take the bad one back). */
int navseed_apply(navseed *s, planning_case *c);
/* The accepted separation of the case folder dir, after its session saved its poses and closed:
 * the seeds written to DIR/separation (durably, naming the case.json they apply to), the case
 * loaded again, separated (navseed_apply) and saved as an undoable edit (case_save_undoable:
 * navseed_undo takes it back), the journal (bound to the case.json that was) removed, and
 * DIR/separation removed; the caller still holds the case's lock. A crash before the save leaves
 * the case as it was and DIR/separation for navseed_recover. Clears accepted. Returns the new
 * fragments made (and *nfrag the case's count) or FN_E*; a bad seed leaves the case as it was. */
int navseed_separate(navseed *s, const char *dir, int *nfrag);
/* A separation that a crash interrupted (DIR/separation naming the case.json as it is): done now
 * (navseed_separate). Returns 1 + the new fragments made when there was one, 0 when none (a
 * DIR/separation of another case.json, which a crash after the save left, is removed), or FN_E*. */
int navseed_recover(const char *dir, int *nfrag);
/* Whether dir's case has a separation to take back (case_undo_steps). */
int navseed_can_undo(const char *dir);
/* Takes the last separation back (case_undo) and removes the journal, after the session saved
 * and closed. 1 (and *nfrag the case's count), 0 when there was none, or FN_E*. */
int navseed_undo(const char *dir, int *nfrag);

#endif
