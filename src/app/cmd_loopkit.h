/* loopkit: what `fracnav replay`, `fracnav navigate` and `fracnav bench loop` share: a case opened
 * for steering (fragments, OBB collider, loop, journal, recovery) and the event sources that feed
 * the loop from a device (dev_poll + calibration) or from a transport's raw reports (recordings,
 * the virtual device: parser + calibration, one event per report, deterministic). */
#ifndef FN_CMD_LOOPKIT_H
#define FN_CMD_LOOPKIT_H

#include "calib.h"
#include "case.h"
#include "cmd.h"
#include "dev.h"
#include "devparse.h"
#include "journal.h"
#include "loop.h"

#include <jansson.h>
#include <pthread.h>
#include <stdio.h>

enum {
    LOOPKIT_JOURNAL = 1, /* append accepted poses to CASE/journal */
    LOOPKIT_RESUME = 2,  /* start from case.json + the journal's unsaved poses */
    LOOPKIT_DISCARD = 4  /* start from case.json, emptying the journal */
};

typedef struct loopkit {
    fcase *c;
    loop_obb *obb;
    loop_obb *check; /* the saver's own collider (the loop thread owns obb's scratch), made at need */
    json_t *penetrating; /* at the last save: [{"fragments": [A, B], "overlap_ml": V}, ...] */
    loop *L;
    journal *jr;
    size_t resumed; /* journal records applied at open */
    char dir_name[4096];
} loopkit;

/* Loads the case, reconciles its journal (case_journal_check: damage and journals of another case
 * state are kept aside, never applied) and builds everything. A journal holding unsaved poses
 * without LOOPKIT_RESUME or LOOPKIT_DISCARD is an error (FN_EMISMATCH) whose message says how many
 * and what to do; `cmd` names the command for that advice; LOOPKIT_RESUME with a journal that was
 * refused is an error too. tau: --tau-min/--tau-max over the case's (NULL: none); they
 * go into k->c, so a save keeps them. 0 or FN_E* (k is then empty). */
int loopkit_open(loopkit *k, const char *dir, const loop_config *cfg, unsigned flags, const char *cmd,
                 const cmd_tau *tau);
/* Unsaved records in DIR/journal that extend DIR/case.json (0 when none, unreadable, damaged or
 * bound to another case state). */
size_t loopkit_journal_pending(const char *dir);
/* Copies the loop's poses and fixed fragments into the case, saves it atomically, then empties
 * the journal. */
int loopkit_save(loopkit *k);
/* Saves the case with these poses and fixed flags (k->c->nfrag of each; a scene's, while the loop
 * runs) and binds the journal to the new case.json. Fragments that interpenetrate (collision
 * checking was off) are not refused but said: a warning on stderr naming them and their overlap,
 * k->penetrating for --json, and case.json's "penetrating" member (absent when none) for later
 * commands. case.json has one fixed fragment: the case's own when it is still fixed, else the
 * first fixed one; others fixed are named in a warning. 0 or FN_E*. */
int loopkit_save_case(loopkit *k, const pose *poses, const uint8_t *fixed);
/* After the case was saved (k->c->json_sha256 is the new case.json): the journal's next truncation
 * binds it to that case.json. */
void loopkit_rebind(loopkit *k);
void loopkit_close(loopkit *k);

/* Final poses and statistics as the JSON object of `command` (replay's and navigate's summary;
 * the members are listed in `fracnav replay --help`) on out; unplugs < 0: null (not counted).
 * skipped: reports of an unknown ID or a wrong length that the parser skipped. 0 or FN_E*. */
int loopkit_print_json(const loopkit *k, FILE *out, const char *command, long unplugs, uint64_t skipped);
/* The loop statistics' members of that object (bench loop's too), labelled `command`; NULL when
 * out of memory. */
json_t *loopkit_stats_json(const char *command, const loop_stats *s);

/* --pivot X Y Z (world mm): argv[*i] is --pivot; parses the three numbers after it into out and
 * moves *i past them. 0, or a usage error for `cmd` (returns 2). */
int loopkit_parse_pivot(const char *cmd, int argc, char **argv, int *i, double out[3]);

/* --frame NAME: camera, world or fragment. 0, or a usage error for `cmd` (returns 2). */
int loopkit_parse_frame(const char *cmd, const char *name, loop_frame *out);

/* Raw reports -> loop events (parser, then calibration). */
typedef struct loopkit_decoder {
    devparse_state ps;
    calib cal;
} loopkit_decoder;
void loopkit_decoder_init(loopkit_decoder *d, uint16_t vid, uint16_t pid, const calib *cal);
/* 1 when the report changed motion or buttons (ev filled), 0 to skip it. */
int loopkit_decode(loopkit_decoder *d, const uint8_t *rep, size_t len, int64_t t_us, loop_event *ev);

/* A loop_source over an open transport handle: every report is one event; a read that says the
 * device went away is an unplug (or the end, when `finished` says so, e.g. sim_replay_finished).
 * With `again` set, the end opens tr at `again` once more and plays it from the start (navigate
 * --loop): the loop gets LOOP_EV_REPLUG, so the recording's clock starting over is no jump. */
typedef struct loopkit_tsource {
    const dev_transport *tr;
    dev_handle *h;
    loopkit_decoder dec;
    int (*finished)(const dev_handle *h);
    const char *again;
    int unplugged, has_pending;
    loop_event pending;
    unsigned unplugs;
    _Atomic unsigned plays; /* plays begun after the first (again); read by the view */
} loopkit_tsource;
loop_source loopkit_transport_source(loopkit_tsource *s);

/* A loop_source over an opened device (live): dev_poll folds what is queued into one event. On
 * its (input) thread it also drives the LED -- lit while a fragment is held: the cap deflected
 * with a movable fragment selected (the `led` setting can force it on or off) -- and publishes
 * for the view the battery level and, while another controller sits at the device's path, why
 * it was not taken (dev_poll's DEV_EV_REFUSED). */
typedef struct loopkit_dsource {
    dev_device *d;
    calib cal;
    loop *L;            /* for the selected fragment's state; NULL: holding = cap deflected */
    int led;            /* the LED state last sent, -1 none yet */
    _Atomic int battery; /* 0..100, -1 unknown; read by the status line */
    pthread_mutex_t mu; /* guards refused */
    char refused[512];  /* "" or the refusal's message, until the device comes back */
} loopkit_dsource;
/* Sets up s for device d (not owned) with calibration cal. */
void loopkit_dsource_init(loopkit_dsource *s, dev_device *d, const calib *cal);
void loopkit_dsource_destroy(loopkit_dsource *s);
loop_source loopkit_device_source(loopkit_dsource *s);
/* Copies the refusal's message (any thread); 0 when there is none. */
int loopkit_dsource_refused(loopkit_dsource *s, char *out, size_t cap);

#endif
