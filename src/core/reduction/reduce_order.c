/* reduce_order: several fragments of a case (reduce_case, see reduce.h): fitted one by one against
 * the growing assembly, the one of largest contact first, then each again against all the others,
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

/* The index into todo[0..left-1] of the fragment of largest contact with the assembly. */
static int largest_contact(planning_case *c, const frag **asm_, int nasm, const int *todo, int left)
{
    int pick = 0;
    double most = -1;
    for (int i = 0; i < left; i++) {
        reduce_voi v;
        double ml = 0;
        if (reduce_auto_voi(asm_, nasm, &c->frag[todo[i]], reduce__tune.order_delta_mm, reduce__tune.order_margin_mm,
                            0, &v, &ml) < 0)
            ml = 0;
        if (ml > most) {
            most = ml;
            pick = i;
        }
    }
    return pick;
}

/* The first sweep: each fragment of todo fitted against the assembly asm_ (which it then joins),
 * the one of largest contact first; *nasm grows. 0 or FN_E*. */
static int first_sweep(planning_case *c, const frag **asm_, int *nasm, int *todo, int nmoving, const reduce_opts *o,
                       reduce_result *r)
{
    int left = nmoving, rc = 0;
    for (int done = 0; done < nmoving && rc == 0; done++) {
        int pick = largest_contact(c, asm_, *nasm, todo, left);
        int mi = todo[pick];
        todo[pick] = todo[--left];
        rc = reduce_pair(asm_, *nasm, &c->frag[mi], o, &r[done]);
        if (rc < 0)
            fn_err_wrap(rc, "fragment %d", c->frag[mi].id);
        asm_[(*nasm)++] = &c->frag[mi];
    }
    return rc;
}

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

/* A wave of the second sweep: fragments apart from each other, each fitted on a private copy (a
 * struct copy sharing the voxels) against all the others at their poses before the wave, so that
 * the fits depend on nothing another one changes and give the same poses on any number of threads. */
typedef struct wave {
    const planning_case *c;
    const frag **asm_;
    int nasm;
    const reduce_opts *o;
    const reduce_result *r;
    const int *d;      /* its fragments' places in r */
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
        const frag *f = &w->c->frag[case_find(w->c, w->r[w->d[i]].id)];
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

/* Runs the wave on up to o->threads threads (this one among them; fewer when a thread cannot be
 * made), then moves its fragments and merges their fits in order. 0, 1 (cancelled) or FN_E*. */
static int wave_run(wave *w, planning_case *c, reduce_result *r)
{
    pthread_t th[REDUCE_THREADS_MAX];
    int nth = 0;
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
        if (w->rc[i] < 0) {
            reduce_result_free(&w->r2[i]);
            continue;
        }
        c->frag[case_find(c, w->moving[i].id)].pose = w->moving[i].pose;
        merge_sweep(&r[w->d[i]], &w->r2[i]);
        r[w->d[i]].wave = w->n;
    }
    return rc;
}

/* 1 when fragments a and b lie farther apart than the table's touch_mm, 0 when not, or FN_E*. */
static int apart(const frag *a, const frag *b)
{
    const frag *o[1] = {b};
    int t = reduce__touches(o, 1, a, reduce__tune.touch_mm);
    return t < 0 ? t : !t;
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
    wave w = {.c = c, .asm_ = asm_, .nasm = nasm, .o = &again, .r = r};
    int *d = calloc((size_t)nmoving, sizeof *d), *done = calloc((size_t)nmoving, sizeof *done);
    w.moving = calloc((size_t)nmoving, sizeof *w.moving);
    w.r2 = calloc((size_t)nmoving, sizeof *w.r2);
    w.rc = calloc((size_t)nmoving, sizeof *w.rc);
    w.msg = calloc((size_t)nmoving, sizeof *w.msg);
    int rc = d && done && w.moving && w.r2 && w.rc && w.msg ? 0 : fn_err_set(FN_ENOMEM, "reduce: out of memory");
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
        for (int i = 0; i < w.n; i++)
            done[d[i]] = 1;
        w.d = d;
        atomic_store(&w.next, 0);
        if (rc == 0)
            rc = wave_run(&w, c, r);
    }
    free(d);
    free(done);
    free(w.moving);
    free(w.r2);
    free(w.rc);
    free(w.msg);
    return rc;
}

int reduce_case(planning_case *c, int fixed, const int *moving, int nmoving, const reduce_opts *o, reduce_result *r)
{
    if (!c || fixed < 0 || fixed >= c->nfrag || nmoving < 1 || !r)
        return fn_err_set(FN_EINVAL, "reduce: bad fixed fragment or nothing to move");
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
        int n = 0;
        for (int k = 0; k < c->nfrag; k++)
            if (k != i)
                others[n++] = &home[k];
        rc = reduce__touches(others, n, &home[i], reduce__tune.touch_mm);
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
