/* reduce_order: several fragments of a case (reduce_case, see reduce.h): fitted one by one against
 * the growing assembly, the one of largest contact first, then each again against all the others. */
#include "reduce.h"
#include "reduce_impl.h"

#include "case.h"
#include "err.h"

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
    r->metric_start = r2->metric_start;
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

/* The second sweep: each fragment again, now against all the others (no pre-alignment), so that a
 * fragment fitted early sees those that came after it (a chain of pieces does not pile up its
 * errors). 0 or FN_E*. */
static int second_sweep(planning_case *c, const frag **asm_, int nasm, int nmoving, const reduce_opts *o,
                        reduce_result *r)
{
    reduce_opts again = *o;
    again.prealign = 0;
    const frag **others = calloc((size_t)nasm, sizeof *others);
    if (!others)
        return fn_err_set(FN_ENOMEM, "reduce: out of memory");
    int rc = 0;
    for (int d = 0; d < nmoving && rc == 0; d++) {
        int mi = case_find(c, r[d].id), n2 = 0;
        for (int k = 0; k < nasm; k++)
            if (asm_[k] != &c->frag[mi])
                others[n2++] = asm_[k];
        reduce_result r2;
        rc = reduce_pair(others, n2, &c->frag[mi], &again, &r2);
        if (rc < 0) {
            fn_err_wrap(rc, "fragment %d", c->frag[mi].id);
            break;
        }
        merge_sweep(&r[d], &r2);
    }
    free(others);
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
