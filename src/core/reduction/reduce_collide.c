/* reduce_collide: the moving fragment against the assembly during a fit: the hierarchies, the
 * query, and the push of a colliding result out of collision (see reduce_impl.h). */
#include "reduce.h"
#include "reduce_impl.h"

#include "err.h"

#include <math.h>
#include <stdlib.h>

int reduce__collider_open(reduce_collider *c, const frag *const *asm_, int nasm, frag *moving,
                          const reduce_opts *o)
{
    const frag *mv = moving;
    double tol = fmin(reduce_tolerance(o, asm_, nasm), reduce_tolerance(o, &mv, 1));
    *c = (reduce_collider){asm_, nasm, moving, calloc((size_t)nasm + 1, sizeof(obb_tree *)),
                           {.threshold = 0, .tolerance_mm = tol},
                           calloc((size_t)nasm, sizeof *c->cache)};
    if (!c->trees || !c->cache)
        return fn_err_set(FN_ENOMEM, "reduce: out of memory");
    obb_params op = {o->tau_min, o->tau_max};
    for (int f = 0; f <= nasm; f++)
        if (!(c->trees[f] = obb_tree_build(f < nasm ? asm_[f] : moving, &op)))
            return FN_ENOMEM;
    return 0;
}

void reduce__collider_close(reduce_collider *c)
{
    for (int i = 0; c->trees && i <= c->nasm; i++)
        obb_tree_free(c->trees[i]);
    free(c->trees);
    free(c->cache);
    c->trees = NULL;
    c->cache = NULL;
}

/* The yes or no is exact either way; a separation is asked without the caches, whose bound depends
 * on the queries before (a front answers with a looser one), so that it, and every step taken by it
 * (the slide to contact), depends on the pose alone. */
int reduce__collides(const reduce_collider *c, const pose *mp, double *sep)
{
    pose mw = pose_compose(*mp, c->moving->home);
    double s = INFINITY;
    int hit = 0;
    for (int f = 0; f < c->nasm; f++) {
        pose aw = pose_compose(c->asm_[f]->pose, c->asm_[f]->home);
        obb_result r;
        obb_cache *cache = c->cache && !sep ? &c->cache[f] : NULL;
        int rc = obb_collide(c->trees[f], &aw, c->trees[c->nasm], &mw, &c->q, cache, &r);
        if (rc < 0)
            return rc;
        hit |= r.collides;
        s = fmin(s, r.separation_mm);
    }
    if (sep)
        *sep = s;
    return hit;
}

/* Pushes a colliding pose out by the smallest step (push_step_mm up to max_mm) along the contact
 * normal (from the assembly's bone in the VOI to the moving centroid) or a world axis. 1 when *p
 * is (now) free, 0 when no push frees it (*p unchanged), <0 on error. */
static int push_out(const reduce_collider *pc, const reduce_metric *m, double max_mm, pose *p, double *pushed)
{
    int c = reduce__collides(pc, p, NULL);
    if (c <= 0)
        return c < 0 ? c : 1;
    double cm[3], dir[7][3] = {{0}}, len = 0;
    pose_apply(p, pc->moving->centroid, cm);
    for (int a = 0; a < 3; a++) {
        dir[0][a] = cm[a] - m->fixed_centre[a];
        len += dir[0][a] * dir[0][a];
    }
    len = sqrt(len);
    for (int a = 0; a < 3; a++) {
        dir[0][a] = len > 0 ? dir[0][a] / len : 0;
        dir[1 + 2 * a][a] = 1;
        dir[2 + 2 * a][a] = -1;
    }
    const double step = reduce__tune.push_step_mm;
    for (double s = step; s <= max_mm + 1e-9; s += step)
        for (int d = len > 0 ? 0 : 1; d < 7; d++) {
            pose t = *p;
            for (int a = 0; a < 3; a++)
                t.t[a] += s * dir[d][a];
            if ((c = reduce__collides(pc, &t, NULL)) < 0)
                return c;
            if (!c) {
                *p = t;
                *pushed += s;
                return 1;
            }
        }
    return 0;
}

int reduce__resolve_collision(const reduce_collider *pc, const reduce_metric *m, double settle_mm,
                              reduce_result *r)
{
    int c = push_out(pc, m, reduce__tune.push_max_mm, &r->end, &r->push_mm);
    if (c > 0 && settle_mm > 0 && pc->q.tolerance_mm > 0) {
        reduce_collider exact = *pc;
        exact.q.tolerance_mm = 0;
        exact.cache = NULL;
        c = push_out(&exact, m, settle_mm, &r->end, &r->push_mm);
        return c < 0 ? c : 0;
    }
    if (c != 0)
        return c < 0 ? c : 0;
    if ((c = reduce__collides(pc, &r->start, NULL)) < 0)
        return c;
    r->end = r->start;
    r->collides = c;
    return 0;
}
