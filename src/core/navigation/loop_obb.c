/* loop: the collision seam filled by the OBB octree (obb.h). */
#include "loop.h"

#include "err.h"
#include "obb.h"

#include <math.h>
#include <stdlib.h>

#define PAIRS_MAX 65536 /* voxel pairs summed for the overlap volume */

struct loop_obb {
    const frag *frags;
    int n;
    obb_query q;
    obb_tree *tree[LOOP_MAX_FRAGS];
    obb_pair *pairs; /* PAIRS_MAX, for overlap (the stepping thread only) */
};

loop_obb *loop_obb_new(const frag *frags, int n, const obb_params *params, const obb_query *q)
{
    if (!frags || n < 1 || n > LOOP_MAX_FRAGS) {
        fn_err_set(FN_EINVAL, "loop collider: need 1..%d fragments (got %d)", LOOP_MAX_FRAGS, n);
        return NULL;
    }
    loop_obb *o = calloc(1, sizeof *o);
    if (!o) {
        fn_err_set(FN_ENOMEM, "loop collider: out of memory");
        return NULL;
    }
    o->frags = frags;
    o->n = n;
    o->pairs = malloc(PAIRS_MAX * sizeof *o->pairs);
    if (!o->pairs) {
        fn_err_set(FN_ENOMEM, "loop collider: out of memory");
        free(o);
        return NULL;
    }
    if (q)
        o->q = *q;
    o->q.want_pairs = 0; /* the loop needs yes/no and the separation, never the pair list */
    for (int i = 0; i < n; i++) {
        o->tree[i] = obb_tree_build(&frags[i], params);
        if (!o->tree[i]) {
            fn_err_wrap(FN_EFORMAT, "fragment %d (%s)", frags[i].id, frags[i].name);
            loop_obb_free(o);
            return NULL;
        }
    }
    return o;
}

void loop_obb_free(loop_obb *o)
{
    if (!o)
        return;
    for (int i = 0; i < o->n; i++)
        obb_tree_free(o->tree[i]);
    free(o->pairs);
    free(o);
}

/* The loop's poses map home world -> world; a tree wants local mm -> world. */
static int query(void *ctx, int a, const pose *pa, int b, const pose *pb, double tolerance_mm,
                 void *cache, loop_contact *out)
{
    loop_obb *o = ctx;
    pose wa = pose_compose(*pa, o->frags[a].home), wb = pose_compose(*pb, o->frags[b].home);
    obb_query q = o->q;
    q.tolerance_mm = fmax(q.tolerance_mm, tolerance_mm);
    obb_result r;
    obb_cache *k = cache;
    size_t rebuilds = k ? k->rebuilds : 0;
    int rc = obb_collide(o->tree[a], &wa, o->tree[b], &wb, &q, k, &r);
    if (rc < 0)
        return rc;
    out->collides = r.collides;
    out->separation_mm = r.separation_mm;
    out->searched = !k || k->rebuilds != rebuilds;
    return 0;
}

/* The overlap's volume, summed over the colliding voxel pairs: each pair's intersection is taken
 * in A's frame against B's voxel's axis-aligned bounds there (exact for parallel grids, an
 * over-estimate that still varies smoothly with the pose for turned ones). Past the pair buffer
 * the sum is scaled up by the pairs found. */
static int overlap(void *ctx, int a, const pose *pa, int b, const pose *pb, double *mm3)
{
    loop_obb *o = ctx;
    pose wa = pose_compose(*pa, o->frags[a].home), wb = pose_compose(*pb, o->frags[b].home);
    obb_query q = o->q;
    q.want_pairs = 1;
    q.pairs = o->pairs;
    q.max_pairs = PAIRS_MAX;
    obb_result r;
    *mm3 = 0;
    int rc = obb_collide(o->tree[a], &wa, o->tree[b], &wb, &q, NULL, &r);
    if (rc < 0 || !r.npairs)
        return rc;
    pose rel = pose_compose(pose_inverse(wa), wb); /* B local -> A local */
    double R[3][3], hb[3];
    pose_to_matrix(&rel, R);
    const double *sa = o->frags[a].spacing, *sb = o->frags[b].spacing;
    for (int i = 0; i < 3; i++)
        hb[i] = 0.5 * (fabs(R[i][0]) * sb[0] + fabs(R[i][1]) * sb[1] + fabs(R[i][2]) * sb[2]);
    for (size_t k = 0; k < r.npairs; k++) {
        double lb[3], cb[3], v = 1;
        for (int i = 0; i < 3; i++)
            lb[i] = o->pairs[k].b[i] * sb[i];
        pose_apply(&rel, lb, cb);
        for (int i = 0; i < 3; i++) {
            double ca = o->pairs[k].a[i] * sa[i];
            v *= fmax(0, fmin(ca + 0.5 * sa[i], cb[i] + hb[i]) - fmax(ca - 0.5 * sa[i], cb[i] - hb[i]));
        }
        *mm3 += v;
    }
    *mm3 *= (double)r.pairs_total / (double)r.npairs;
    return 0;
}

loop_collider loop_obb_collider(loop_obb *o)
{
    loop_collider c = {query, sizeof(obb_cache), o, overlap};
    return c;
}
