/* navseed: the window's seed mode (see navseed.h). */
#include "navseed.h"

#include "case_journal.h"
#include "err.h"
#include "fnclock.h"
#include "render.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define KEY_F10 (RENDER_KEY_F1 + 9)

void navseed_init(navseed *s)
{
    memset(s, 0, sizeof *s);
    s->piece = 1;
}

static void drop_preview(navseed *s)
{
    for (int i = 0; i < s->npieces; i++)
        frag_free(&s->pieces[i]);
    free(s->pieces);
    s->pieces = NULL;
    s->npieces = 0;
}

void navseed_free(navseed *s)
{
    drop_preview(s);
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
        describe(s, "click a slice (four-up, F3) to drop a seed");
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

int navseed_preview(navseed *s, const planning_case *c, const pose *poses)
{
    if (!s->changed)
        return 0;
    s->changed = 0;
    int had = s->npieces;
    drop_preview(s);
    if (!s->on || !s->n)
        return had > 0;
    int64_t t0 = fnclock_now_us();
    int n = case_separate_preview(c, poses, s->seed, s->n, &s->pieces);
    char what[300];
    if (n >= 0) {
        s->npieces = n;
        snprintf(what, sizeof what, "preview: %d fragment%s (%.0f ms), Enter accepts", n, n == 1 ? "" : "s",
                 (double)(fnclock_now_us() - t0) / 1000.0);
    } else
        snprintf(what, sizeof what, "no preview: %s", fn_err_msg());
    describe(s, what);
    return 1;
}

const char *navseed_status(const navseed *s)
{
    return s->on ? s->status : NULL;
}

const char *navseed_help(void)
{
    return "  F10 seed mode (separates fragments): then 1-9 the piece, a click on a slice drops\n"
           "  its seed, Backspace takes the last seed back (the split is previewed in colour\n"
           "  after each), Enter separates (saves the case)\n";
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

int navseed_separate(navseed *s, const char *dir, int *nfrag)
{
    s->accepted = 0;
    planning_case *c = case_load(dir);
    int made = c ? navseed_apply(s, c) : FN_EIO;
    if (made >= 0 && (case_save(c) < 0 || case_journal_remove(c) < 0))
        made = FN_EIO;
    *nfrag = c ? c->nfrag : 0;
    case_free(c);
    return made;
}
