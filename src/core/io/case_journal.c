#include "case_journal.h"

#include "durable.h"
#include "err.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

void case_journal_bind(const planning_case *c, journal_bind *b)
{
    memset(b, 0, sizeof *b);
    snprintf(b->case_sha256, sizeof b->case_sha256, "%s", c->json_sha256);
    b->nfrag = c->nfrag < JOURNAL_MAX_FRAGS ? c->nfrag : JOURNAL_MAX_FRAGS;
    for (int i = 0; i < b->nfrag; i++)
        b->ids[i] = (uint16_t)c->frag[i].id;
}

static void ids_text(const journal_bind *b, char *out, size_t cap)
{
    size_t len = 0;
    out[0] = '\0';
    for (int i = 0; i < b->nfrag && len + 8 < cap; i++)
        len += (size_t)snprintf(out + len, cap - len, "%s%d", i ? "," : "", b->ids[i]);
    if (!b->nfrag)
        snprintf(out, cap, "none");
}

/* 1 when applying the records to c's poses changes none of them: c holds them already. */
static int already_saved(const planning_case *c, const journal_rec *recs, size_t n)
{
    pose *p = malloc(sizeof *p * (size_t)(c->nfrag ? c->nfrag : 1));
    if (!p)
        return 0;
    for (int i = 0; i < c->nfrag; i++)
        p[i] = c->frag[i].pose;
    int same = journal_final_poses(recs, n, c->nfrag, p) == 0;
    for (int i = 0; same && i < c->nfrag; i++)
        same = !memcmp(&p[i], &c->frag[i].pose, sizeof *p);
    free(p);
    return same;
}

/* Damage: the whole file aside, the good records before it kept as the journal. */
static int keep_damaged(const planning_case *c, journal_scan *s)
{
    char aside[4300];
    int rc = journal_set_aside(c->dir, "damaged", &s->bind, s->recs, s->n, aside, sizeof aside);
    if (rc < 0)
        return rc;
    fprintf(stderr, "fracnav: %s; the damaged journal is kept as %s", s->damage, aside);
    if (s->n)
        fprintf(stderr, "; the %zu records before the damage are kept in %s/journal\n", s->n, c->dir);
    else
        fprintf(stderr, "; no record precedes the damage\n");
    return 0;
}

static int refuse(const planning_case *c, journal_scan *s, const journal_bind *now)
{
    char aside[4300], was[400], is[400];
    int rc = journal_set_aside(c->dir, "mismatch", NULL, NULL, 0, aside, sizeof aside);
    if (rc < 0)
        return rc;
    ids_text(&s->bind, was, sizeof was);
    ids_text(now, is, sizeof is);
    fprintf(stderr, "fracnav: %s/journal was written for another state of the case (case.json "
                    "sha256 %.12s..., fragments %s; now %.12s..., fragments %s): its %zu poses are "
                    "not applied; it is kept as %s\n",
            c->dir, s->bind.case_sha256, was, now->case_sha256, is, s->n, aside);
    return 1;
}

int case_journal_check(const planning_case *c, journal_rec **recs, size_t *n)
{
    *recs = NULL;
    *n = 0;
    journal_scan s;
    int rc = journal_read(c->dir, &s);
    if (rc == FN_EFORMAT) { /* a bad header: nothing in it can be trusted */
        journal_scan_free(&s);
        snprintf(s.damage, sizeof s.damage, "%s", fn_err_msg());
        s.bind.nfrag = 0;
        return keep_damaged(c, &s);
    }
    if (rc < 0)
        return rc;
    if (s.damaged_at >= 0 && (rc = keep_damaged(c, &s)) < 0) {
        journal_scan_free(&s);
        return rc;
    }
    journal_bind now;
    case_journal_bind(c, &now);
    if (s.n == 0 || journal_bind_equal(&s.bind, &now)) {
        *recs = s.recs;
        *n = s.n;
        return 0;
    }
    int same_ids = s.bind.nfrag == now.nfrag &&
                   !memcmp(s.bind.ids, now.ids, sizeof now.ids[0] * (size_t)now.nfrag);
    if (same_ids && already_saved(c, s.recs, s.n)) {
        fprintf(stderr, "fracnav: the %zu poses in %s/journal are in case.json already (a save "
                        "ended before the journal was emptied): emptied it\n", s.n, c->dir);
        journal_scan_free(&s);
        return case_journal_remove(c);
    }
    rc = refuse(c, &s, &now);
    journal_scan_free(&s);
    return rc;
}

size_t case_journal_pending(const char *dir)
{
    char json[4200], sha[65];
    snprintf(json, sizeof json, "%s/case.json", dir);
    journal_scan s;
    if (durable_file_sha256(json, sha) < 0 || journal_read(dir, &s) < 0)
        return 0;
    size_t n = strcmp(s.bind.case_sha256, sha) ? 0 : s.n;
    journal_scan_free(&s);
    return n;
}

int case_journal_apply(planning_case *c, const journal_rec *recs, size_t n)
{
    pose *p = malloc(sizeof *p * (size_t)(c->nfrag ? c->nfrag : 1));
    if (!p)
        return fn_err_set(FN_ENOMEM, "case: out of memory");
    for (int i = 0; i < c->nfrag; i++)
        p[i] = c->frag[i].pose;
    int rc = journal_final_poses(recs, n, c->nfrag, p);
    for (int i = 0; rc == 0 && i < c->nfrag; i++)
        c->frag[i].pose = p[i];
    uint8_t *fixed = rc == 0 ? calloc((size_t)c->nfrag + 1, 1) : NULL;
    if (rc == 0 && !fixed)
        rc = FN_ENOMEM;
    for (int i = 0; fixed && i < c->nfrag; i++)
        fixed[i] = (uint8_t)case_is_fixed(c, i);
    for (size_t i = 0; fixed && i < n; i++)
        if (recs[i].kind == JOURNAL_FIX && recs[i].frag >= 0 && recs[i].frag < c->nfrag)
            fixed[recs[i].frag] = (uint8_t)(recs[i].flag != 0);
    if (fixed)
        case_set_fixed(c, fixed);
    free(fixed);
    free(p);
    return rc < 0 ? fn_err_wrap(rc, "%s/journal", c->dir) : 0;
}

int case_journal_remove(const planning_case *c)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/journal", c->dir);
    if (unlink(path) != 0 && errno != ENOENT)
        return fn_err_set(FN_EIO, "%s: cannot remove: %s", path, strerror(errno));
    return 0;
}
