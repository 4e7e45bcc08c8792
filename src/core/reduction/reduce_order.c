/* reduce_order: several fragments of a case (reduce_case, see reduce.h): fitted one by one against
 * the growing assembly, the one whose fit gains most first, then each again against all the others,
 * those apart from each other at once on o->threads threads. */
#include "reduce.h"
#include "reduce_impl.h"

#include "case.h"
#include "err.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The second sweep's result joins the first's: the same placement, the later end, counts summed,
 * histories joined. */
static void merge_sweep(reduce_result *r, reduce_result *r2)
{
    double *h = realloc(r->history, (size_t)(r->nhistory + r2->nhistory + 1) * sizeof *h);
    if (h) {
        memcpy(h + r->nhistory, r2->history, (size_t)r2->nhistory * sizeof *h);
        r->history = h;
        r->nhistory += r2->nhistory;
    }
    r->fitted = r2->fitted;
    r->end = r2->end;
    r->voi = r2->voi;
    r->iterations += r2->iterations;
    r->evaluations += r2->evaluations;
    r->eval_cpu_s += r2->eval_cpu_s;
    r->seconds += r2->seconds;
    /* metric_start stays the first sweep's: the metric where the hand left the piece, so that
     * "start -> end" says what the whole reduction did (the second sweep's start is the first's
     * end: printed alone it read "-0.7227 -> -0.7227" for a piece moved 6 mm) */
    r->metric_end = r2->metric_end;
    r->push_mm += r2->push_mm;
    r->collides = r2->collides;
    r->rival |= r2->rival;
    if (r2->ncandidates) { /* the last fit's answers */
        r->ncandidates = r2->ncandidates;
        memcpy(r->candidate, r2->candidate, sizeof r->candidate);
    }
    r->hops += r2->hops;
    reduce_result_free(r2);
}

/* Fits at once: fragments fi[0..n-1] of the case, each fitted on a private copy (a struct copy
 * sharing the voxels) against the assembly asm_ less itself, so that the fits depend on nothing
 * another one changes and give the same poses on any number of threads. A wave of the second sweep
 * (fragments apart from each other, against all the others), or the first sweep's round (every
 * fragment still to place, against the assembly so far). */
typedef struct wave {
    const planning_case *c;
    const frag **asm_;
    int nasm;
    const reduce_opts *o;
    const int *fi;     /* n: the fragments' places in c->frag */
    int n;
    frag *moving;      /* n: the private copies */
    reduce_result *r2; /* n: their fits */
    int *rc;           /* n */
    char (*msg)[256];  /* n: a failed fit's message (err.h's are per thread) */
    atomic_int next;
} wave;

static void *wave_worker(void *arg)
{
    wave *w = arg;
    const frag **others = calloc((size_t)w->nasm, sizeof *others);
    for (int i; (i = atomic_fetch_add(&w->next, 1)) < w->n;) {
        const frag *f = &w->c->frag[w->fi[i]];
        int n2 = 0;
        for (int k = 0; others && k < w->nasm; k++)
            if (w->asm_[k] != f)
                others[n2++] = w->asm_[k];
        w->moving[i] = *f;
        w->rc[i] = others ? reduce_pair(others, n2, &w->moving[i], w->o, &w->r2[i])
                          : fn_err_set(FN_ENOMEM, "reduce: out of memory");
        if (w->rc[i] < 0)
            snprintf(w->msg[i], sizeof w->msg[i], "fragment %d: %s", f->id, fn_err_msg());
    }
    free(others);
    return NULL;
}

/* Runs the fits on up to o->threads threads (this one among them; fewer when a thread cannot be
 * made). 0, or the first failure's FN_E* (its message set; the failed fits' results freed), or 1
 * when a fit was cancelled. */
static int wave_fit(wave *w)
{
    pthread_t th[REDUCE_THREADS_MAX];
    int nth = 0;
    atomic_store(&w->next, 0);
    while (nth + 1 < w->o->threads && nth + 1 < w->n && nth < REDUCE_THREADS_MAX &&
           pthread_create(&th[nth], NULL, wave_worker, w) == 0)
        nth++;
    wave_worker(w);
    for (int t = 0; t < nth; t++)
        pthread_join(th[t], NULL);
    int rc = 0;
    for (int i = 0; i < w->n; i++) {
        if (rc == 0 && w->rc[i] < 0)
            rc = fn_err_set(w->rc[i], "%s", w->msg[i]);
        else if (rc == 0)
            rc = w->rc[i];
        if (w->rc[i] < 0)
            reduce_result_free(&w->r2[i]);
    }
    return rc;
}

/* The arrays of a wave of up to n fits. 0 or FN_ENOMEM. */
static int wave_alloc(wave *w, int n)
{
    w->moving = calloc((size_t)n, sizeof *w->moving);
    w->r2 = calloc((size_t)n, sizeof *w->r2);
    w->rc = calloc((size_t)n, sizeof *w->rc);
    w->msg = calloc((size_t)n, sizeof *w->msg);
    return w->moving && w->r2 && w->rc && w->msg ? 0 : fn_err_set(FN_ENOMEM, "reduce: out of memory");
}

static void wave_free(wave *w)
{
    free(w->moving);
    free(w->r2);
    free(w->rc);
    free(w->msg);
}

/* 1 when fragments a and b lie farther apart than the table's touch_mm, 0 when not, or FN_E*. */
static int apart(const frag *a, const frag *b)
{
    const frag *o[1] = {b};
    int t = reduce__touches(o, 1, a, reduce__tune.touch_mm);
    return t < 0 ? t : !t;
}

/* A fit's counts added to another's: the same piece fitted again, its earlier fit dropped. */
static void add_spent(reduce_result *to, const reduce_result *from)
{
    to->iterations += from->iterations;
    to->evaluations += from->evaluations;
    to->eval_cpu_s += from->eval_cpu_s;
    to->seconds += from->seconds;
}

/* The first sweep, best first. Every fragment still to place (todo[0..left-1]) is fitted against
 * the assembly asm_, at once on o->threads threads, and the one whose fit gained most (metric at
 * its start minus at its end) joins it at its fitted pose; *nasm grows. A fit that gains nothing
 * is a piece that touches no piece of the assembly where it truly lies (its metric is flat there):
 * fitted first, it stays where the hand left it and the pieces after it fit against it. The fits
 * of the others stand, unless the piece that joined lies within touch_mm of them (where they
 * started or were fitted): then they are made again in the next round, and what the dropped fit
 * spent is added to the piece's result. r[k]: the k-th piece to join. 0, 1 (cancelled) or FN_E*. */
static int first_sweep(planning_case *c, const frag **asm_, int *nasm, int *todo, int nmoving, const reduce_opts *o,
                       reduce_result *r)
{
    wave w = {.c = c, .asm_ = asm_, .o = o};
    int *fi = calloc((size_t)nmoving, sizeof *fi), *valid = calloc((size_t)nmoving, sizeof *valid);
    frag *fitted = calloc((size_t)nmoving, sizeof *fitted);
    reduce_result *fit = calloc((size_t)nmoving, sizeof *fit), *spent = calloc((size_t)nmoving, sizeof *spent);
    int rc = wave_alloc(&w, nmoving);
    if (rc == 0 && !(fi && valid && fitted && fit && spent))
        rc = fn_err_set(FN_ENOMEM, "reduce: out of memory");
    int left = nmoving;
    for (int done = 0; done < nmoving && rc == 0; done++) {
        /* the round: the pieces without a standing fit */
        w.n = 0;
        w.nasm = *nasm;
        for (int i = 0; i < left; i++)
            if (!valid[i])
                fi[w.n++] = todo[i];
        w.fi = fi;
        rc = wave_fit(&w);
        for (int i = 0, k = 0; i < left; i++) {
            if (valid[i])
                continue;
            if (w.rc[k] >= 0) {
                fitted[i] = w.moving[k];
                fit[i] = w.r2[k];
                valid[i] = 1;
            }
            k++;
        }
        if (rc != 0)
            break;
        int pick = 0;
        for (int i = 1; i < left; i++)
            if (fit[i].metric_start - fit[i].metric_end > fit[pick].metric_start - fit[pick].metric_end)
                pick = i;
        int mi = todo[pick];
        c->frag[mi].pose = fitted[pick].pose;
        r[done] = fit[pick];
        add_spent(&r[done], &spent[pick]);
        asm_[(*nasm)++] = &c->frag[mi];
        left--;
        todo[pick] = todo[left];
        fitted[pick] = fitted[left];
        fit[pick] = fit[left];
        spent[pick] = spent[left];
        valid[pick] = valid[left];
        /* the fits the new piece may change are made again */
        for (int i = 0; i < left && rc == 0; i++) {
            int a = apart(&c->frag[mi], &fitted[i]), b = a > 0 ? apart(&c->frag[mi], &c->frag[todo[i]]) : a;
            if (a < 0 || b < 0)
                rc = a < 0 ? a : b;
            else if (!(a && b)) {
                add_spent(&spent[i], &fit[i]);
                reduce_result_free(&fit[i]);
                valid[i] = 0;
            }
        }
    }
    for (int i = 0; i < left; i++)
        if (valid[i])
            reduce_result_free(&fit[i]);
    /* pieces not placed (a failure or a cancel) keep where the hand left them */
    free(fi);
    free(valid);
    free(fitted);
    free(fit);
    free(spent);
    wave_free(&w);
    return rc;
}

/* The second sweep: each fragment again, now against all the others (no pre-alignment), so that a
 * fragment fitted early sees those that came after it (a chain of pieces does not pile up its
 * errors). In waves: in the first sweep's order, each wave the next fragment not yet fitted and
 * every later one apart from all in the wave. 0 or FN_E*. */
static int second_sweep(planning_case *c, const frag **asm_, int nasm, int nmoving, const reduce_opts *o,
                        reduce_result *r)
{
    reduce_opts again = *o;
    again.prealign = 0;
    wave w = {.c = c, .asm_ = asm_, .nasm = nasm, .o = &again};
    int *d = calloc((size_t)nmoving, sizeof *d), *done = calloc((size_t)nmoving, sizeof *done);
    int *fi = calloc((size_t)nmoving, sizeof *fi);
    int rc = wave_alloc(&w, nmoving);
    if (rc == 0 && !(d && done && fi))
        rc = fn_err_set(FN_ENOMEM, "reduce: out of memory");
    for (int d0 = 0; d0 < nmoving && rc == 0; d0++) {
        if (done[d0])
            continue;
        w.n = 0;
        d[w.n++] = d0;
        for (int e = d0 + 1; e < nmoving && rc == 0; e++) {
            const frag *fe = &c->frag[case_find(c, r[e].id)];
            int ok = !done[e];
            for (int i = 0; i < w.n && ok > 0; i++)
                ok = apart(fe, &c->frag[case_find(c, r[d[i]].id)]);
            if (ok > 0)
                d[w.n++] = e;
            rc = ok < 0 ? ok : 0;
        }
        if (rc != 0)
            break;
        for (int i = 0; i < w.n; i++) {
            done[d[i]] = 1;
            fi[i] = case_find(c, r[d[i]].id);
        }
        w.fi = fi;
        rc = wave_fit(&w);
        /* the wave's fragments move and their fits join the first sweep's, in order */
        for (int i = 0; i < w.n; i++) {
            if (w.rc[i] < 0)
                continue;
            c->frag[fi[i]].pose = w.moving[i].pose;
            merge_sweep(&r[d[i]], &w.r2[i]);
            r[d[i]].wave = w.n;
        }
    }
    free(d);
    free(done);
    free(fi);
    wave_free(&w);
    return rc;
}

int reduce_case(planning_case *c, int fixed, const int *moving, int nmoving, const reduce_opts *o, reduce_result *r)
{
    if (!c || fixed < 0 || fixed >= c->nfrag || nmoving < 1 || !r)
        return fn_err_set(FN_EINVAL, "reduce: bad fixed fragment or nothing to move");
    /* several pieces: no global check after each local fit, in either sweep (bench reduce
     * --suite, the whole cases: with it for rival basins, no piece more back, and twice the CPU;
     * see docs/reduction.md) */
    reduce_opts several = *o;
    several.global_check &= nmoving == 1;
    o = &several;
    const frag **asm_ = calloc((size_t)c->nfrag, sizeof *asm_);
    int *todo = calloc((size_t)c->nfrag, sizeof *todo);
    int nasm = 1, rc = asm_ && todo ? 0 : fn_err_set(FN_ENOMEM, "reduce: out of memory");
    if (rc == 0) {
        asm_[0] = &c->frag[fixed];
        for (int i = 0; i < nmoving; i++)
            todo[i] = moving ? moving[i] : i < fixed ? i : i + 1;
        rc = first_sweep(c, asm_, &nasm, todo, nmoving, o, r);
    }
    if (rc == 0 && nmoving > 1)
        rc = second_sweep(c, asm_, nasm, nmoving, o, r);
    free(asm_);
    free(todo);
    return rc;
}

/* Whether fragment i of the case, in set (the case's fragments, each at the pose the caller gave
 * it), has bone within touch_mm of another's: 1, 0 or FN_E*. others has room for c->nfrag. */
static int touches_another(const planning_case *c, const frag *set, int i, const frag **others)
{
    int n = 0;
    for (int k = 0; k < c->nfrag; k++)
        if (k != i)
            others[n++] = &set[k];
    return reduce__touches(others, n, &set[i], reduce__tune.touch_mm);
}

int reduce_pick_moving(const planning_case *c, int fixed, int *mv, int *skipped, int *nskipped)
{
    frag *home = calloc((size_t)c->nfrag, sizeof *home);
    const frag **others = calloc((size_t)c->nfrag, sizeof *others);
    int rc = home && others ? 0 : fn_err_set(FN_ENOMEM, "reduce: out of memory"), nmv = 0;
    for (int i = 0; i < c->nfrag && rc == 0; i++) {
        home[i] = c->frag[i]; /* a struct copy sharing the voxels, at the CT pose */
        home[i].pose = POSE_IDENTITY;
    }
    *nskipped = 0;
    for (int i = 0; i < c->nfrag && rc == 0; i++) {
        if (i == fixed || case_is_fixed(c, i))
            continue;
        rc = touches_another(c, home, i, others);
        /* where the hand left them: a piece the hand moved next to another is one to fit,
         * wherever the fracture had thrown it (a piece no one moved, as a head holder, stays
         * out though another was dragged next to it) */
        int moved = pose_distance(c->frag[i].pose, POSE_IDENTITY) > 0 ||
                    pose_angle_between(c->frag[i].pose, POSE_IDENTITY) > 0;
        if (rc == 0 && moved)
            rc = touches_another(c, c->frag, i, others);
        if (rc > 0)
            mv[nmv++] = i;
        else if (rc == 0)
            skipped[(*nskipped)++] = i;
        rc = rc < 0 ? rc : 0;
    }
    free(home);
    free(others);
    return rc < 0 ? rc : nmv;
}
