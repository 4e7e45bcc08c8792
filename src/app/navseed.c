/* navseed: the window's seed mode (see navseed.h). */
#include "navseed.h"

#include "case_journal.h"
#include "cmd.h"
#include "durable.h"
#include "err.h"
#include "fnclock.h"
#include "render.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define KEY_F10 (RENDER_KEY_F1 + 9)
/* The pieces' crops and meshes are made on the worker and one more thread (the machine of the
 * benchmarks has two cores; the window's thread only uploads them). */
#define NAVSEED_PREP_THREADS 2

void navseed_init(navseed *s)
{
    memset(s, 0, sizeof *s);
    s->piece = 1;
}

void navseed_free(navseed *s)
{
    if (s->running)
        pthread_join(s->worker, NULL);
    s->running = 0;
    free(s->job_poses);
    s->job_poses = NULL;
    s->job_nposes = 0;
    case_preview_free(s->preview);
    s->preview = NULL;
    render_prep_free(s->job_prep);
    render_prep_free(s->prep);
    s->job_prep = s->prep = NULL;
    /* a job that ended unseen is dropped with its preview: its pieces were the preview's */
    atomic_store(&s->done, 0);
    s->job_pieces = NULL;
    s->job_result = 0;
    s->pieces = NULL;
    s->npieces = 0;
    s->nmarked = 0;
}

static void describe(navseed *s, const char *what)
{
    size_t len = (size_t)snprintf(s->status, sizeof s->status, "seed mode, piece %d: %s; %d seed%s", s->piece,
                                  what, s->n, s->n == 1 ? "" : "s");
    for (int i = 0; i < s->n && len < sizeof s->status; i++)
        len += (size_t)snprintf(s->status + len, sizeof s->status - len, "%s%d@(%.0f,%.0f,%.0f)", i ? " " : " ",
                                s->seed[i].piece, s->seed[i].at[0], s->seed[i].at[1], s->seed[i].at[2]);
}

int navseed_key(navseed *s, int k)
{
    if (k == KEY_F10) {
        s->on = !s->on;
        s->changed = 1;
        describe(s, "click a slice (four-up, F3) or a fragment to drop a seed");
        return 1;
    }
    if (!s->on)
        return 0;
    if (k >= '1' && k <= '9') {
        s->piece = k - '0';
        describe(s, "chosen");
    } else if (k == '\b' || k == 127) {
        s->n -= s->n > 0;
        s->changed = 1;
        describe(s, "last seed taken back");
    } else if (k == '\r' || k == '\n') {
        s->accepted = s->n > 0;
        describe(s, s->n ? "separating" : "no seed to separate from");
    } else
        return 0;
    return 1;
}

void navseed_click(navseed *s, const double world[3])
{
    if (!s->on)
        return;
    if (s->n == NAVSEED_MAX) {
        describe(s, "no room for more seeds");
        return;
    }
    memcpy(s->seed[s->n].at, world, sizeof s->seed[s->n].at);
    s->seed[s->n++].piece = s->piece;
    s->changed = 1;
    describe(s, "seed dropped");
}

/* The worker: one case_preview_update over the job, and the pieces' crops and meshes for the
 * window (at the case's level, the window's; without them the window makes them itself). */
static void *grow_job(void *arg)
{
    navseed *s = arg;
    int64_t t0 = fnclock_now_us();
    if (!s->preview)
        s->preview = case_preview_new(s->job_case);
    s->job_result = s->preview ? case_preview_update(s->preview, s->job_poses, s->job_seed, s->job_n, &s->job_pieces)
                               : FN_ENOMEM;
    s->job_prep = s->job_result > 0 ? render_prepare(s->job_case->ct, s->job_pieces, s->job_result,
                                                     s->job_case->seg.threshold, NAVSEED_PREP_THREADS)
                                    : NULL;
    s->job_ms = (double)(fnclock_now_us() - t0) / 1000.0;
    snprintf(s->job_error, sizeof s->job_error, "%s", s->job_result < 0 ? fn_err_msg() : "");
    atomic_store(&s->done, 1);
    return NULL;
}

/* The seeds' colours in the preview just taken (on the caller's thread, no job running): each
 * seed's piece's, white where none holds it. navseed_marks reads these, never the pieces, which
 * the next job overwrites while it runs. */
static void colour_marks(navseed *s)
{
    for (int i = 0; i < s->n; i++) {
        s->marked[i] = s->seed[i];
        memset(s->mark_rgb[i], 255, sizeof s->mark_rgb[i]);
        for (int k = 0; k < s->npieces; k++)
            if (frag_holds(&s->pieces[k], s->seed[i].at)) {
                memcpy(s->mark_rgb[i], s->pieces[k].rgb, sizeof s->mark_rgb[i]);
                break;
            }
    }
    s->nmarked = s->n;
}

/* A job for the seeds as they are, on the worker (or here when no thread can start). */
static void start_job(navseed *s, const planning_case *c, const pose *poses, int nposes)
{
    if (nposes != c->nfrag)
        poses = NULL; /* no scene of this case yet */
    pose *p = poses && nposes != s->job_nposes ? realloc(s->job_poses, (size_t)nposes * sizeof *p) : s->job_poses;
    if (poses && p) {
        memcpy(p, poses, (size_t)nposes * sizeof *p);
        s->job_poses = p;
        s->job_nposes = nposes;
    }
    if (!poses || !p) {
        free(s->job_poses);
        s->job_poses = NULL;
        s->job_nposes = 0;
    }
    s->job_case = c;
    memcpy(s->job_seed, s->seed, (size_t)s->n * sizeof *s->seed);
    s->job_n = s->n;
    atomic_store(&s->done, 0);
    s->running = 1;
    if (pthread_create(&s->worker, NULL, grow_job, s) != 0) {
        s->running = 0;
        grow_job(s);
    }
}

int navseed_preview(navseed *s, const planning_case *c, const pose *poses, int nposes)
{
    int shown = 0;
    render_prep_free(s->prep); /* uploaded by now */
    s->prep = NULL;
    if (s->running && !atomic_load(&s->done))
        return 0;
    if (s->running) {
        pthread_join(s->worker, NULL);
        s->running = 0;
    }
    if (atomic_exchange(&s->done, 0)) {
        char what[400];
        s->npieces = s->job_result > 0 ? s->job_result : 0;
        s->pieces = s->job_pieces;
        s->prep = s->job_prep;
        s->job_prep = NULL;
        if (s->job_result >= 0)
            snprintf(what, sizeof what, "preview: %d fragment%s (%.0f ms), Enter accepts", s->job_result,
                     s->job_result == 1 ? "" : "s", s->job_ms);
        else
            snprintf(what, sizeof what, "no preview: %s", s->job_error);
        describe(s, what);
        colour_marks(s);
        shown = 1;
    }
    /* the next job waits a frame: until then the caller uploads these pieces, which the worker
     * would overwrite (case_preview_update) */
    if (!s->changed || shown)
        return shown;
    s->changed = 0;
    if (s->on && s->n) {
        start_job(s, c, poses, nposes);
        return shown;
    }
    shown |= s->npieces > 0;
    s->npieces = 0;
    return shown;
}

int navseed_marks(const navseed *s, double (*at)[3], unsigned char (*rgb)[3], int cap)
{
    int n = s->on ? (s->n < cap ? s->n : cap) : 0;
    for (int i = 0; i < n; i++) {
        memcpy(at[i], s->seed[i].at, sizeof at[i]);
        int same = i < s->nmarked && !memcmp(&s->marked[i], &s->seed[i], sizeof s->seed[i]);
        if (same)
            memcpy(rgb[i], s->mark_rgb[i], sizeof rgb[i]);
        else
            memset(rgb[i], 255, sizeof rgb[i]);
    }
    return n;
}

const char *navseed_status(const navseed *s)
{
    return s->on ? s->status : NULL;
}

const char *navseed_help(void)
{
    return "  F10 seed mode (separates fragments): then 1-9 the piece, a click on a slice or on\n"
           "  a fragment in 3D drops its seed (marked on the slices in its piece's colour),\n"
           "  Backspace takes the last seed back (the split is previewed in colour after each),\n"
           "  Enter separates (saves it; undo takes it back)\n";
}

int navseed_apply(navseed *s, planning_case *c)
{
    int rc = case_separate_all(c, s->seed, s->n);
    if (rc >= 0) {
        char what[64];
        snprintf(what, sizeof what, "separated, %d new fragment%s", rc, rc == 1 ? "" : "s");
        s->n = 0;
        describe(s, what);
    } else
        describe(s, fn_err_msg());
    return rc;
}

/* CASE/separation: the seeds of an accepted separation (case_seeds_parse's lines) under a line
 * naming the case.json they apply to, written before the separation and removed once the
 * separated case is saved, so that a crash in between leaves the case intact and the separation
 * to recover (navseed_recover). */
static void pending_path(const char *dir, char *path, size_t cap)
{
    snprintf(path, cap, "%s/separation", dir);
}

static int write_pending(const navseed *s, const planning_case *c, const char *path)
{
    char text[128 + NAVSEED_MAX * 128];
    size_t len = (size_t)snprintf(text, sizeof text, "# fracnav navigate: a separation of case.json sha256 %s\n",
                                  c->json_sha256);
    for (int i = 0; i < s->n; i++)
        len += (size_t)snprintf(text + len, sizeof text - len, "%d %.17g %.17g %.17g\n", s->seed[i].piece,
                                s->seed[i].at[0], s->seed[i].at[1], s->seed[i].at[2]);
    return durable_replace_bytes(path, text, len);
}

int navseed_separate(navseed *s, const char *dir, int *nfrag)
{
    s->accepted = 0;
    char pending[4200];
    pending_path(dir, pending, sizeof pending);
    planning_case *c = case_load(dir);
    int made = c ? write_pending(s, c, pending) : FN_EIO;
    if (made == 0)
        made = navseed_apply(s, c);
    if (made >= 0 && (case_save_undoable(c) < 0 || case_journal_remove(c) < 0)) {
        made = FN_EIO;
        describe(s, fn_err_msg());
    }
    if (c)
        unlink(pending);
    *nfrag = c ? c->nfrag : 0;
    case_free(c);
    return made;
}

int navseed_recover(const char *dir, int *nfrag)
{
    char pending[4200], path[4300], sha[65];
    pending_path(dir, pending, sizeof pending);
    if (access(pending, F_OK) != 0)
        return 0;
    snprintf(path, sizeof path, "%s/case.json", dir);
    char *text = cmd_read_seed_file(pending);
    const char *bound = text ? strstr(text, "sha256 ") : NULL;
    case_seed *seeds = NULL;
    int n = bound && durable_file_sha256(path, sha) == 0 && !strncmp(bound + 7, sha, 64)
                ? case_seeds_parse(text, pending, &seeds) : 0;
    free(text);
    int made = n < 0 ? n : 0;
    if (n > NAVSEED_MAX) { /* not written by navigate: kept, for the user to look at */
        free(seeds);
        return fn_err_set(FN_EINVAL, "%s: %d seeds, more than a separation in the window takes (%d)",
                          pending, n, NAVSEED_MAX);
    }
    if (n > 0) {
        navseed s;
        navseed_init(&s);
        memcpy(s.seed, seeds, (size_t)n * sizeof *seeds);
        s.n = n;
        made = navseed_separate(&s, dir, nfrag);
    } else if (n == 0)
        unlink(pending); /* a separation saved before a crash, or none to recover */
    free(seeds);
    return made < 0 ? made : n > 0 ? made + 1 : 0;
}

int navseed_can_undo(const char *dir)
{
    return case_undo_steps(dir) > 0;
}

int navseed_undo(const char *dir, int *nfrag)
{
    int rc = case_undo(dir);
    planning_case *c = rc > 0 ? case_load(dir) : NULL;
    if (rc > 0 && (!c || case_journal_remove(c) < 0))
        rc = FN_EIO;
    *nfrag = c ? c->nfrag : 0;
    case_free(c);
    return rc;
}
