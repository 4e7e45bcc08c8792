/* loop: the collision seam filled by the OBB octree (obb.h). */
#include "loop.h"

#include "err.h"
#include "obb.h"

#include <stdlib.h>

struct loop_obb {
    const frag *frags;
    int n;
    obb_query q;
    obb_tree *tree[LOOP_MAX_FRAGS];
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
    free(o);
}

/* The loop's poses map home world -> world; a tree wants local mm -> world. */
static int query(void *ctx, int a, const pose *pa, int b, const pose *pb, void *cache,
                 loop_contact *out)
{
    loop_obb *o = ctx;
    pose wa = pose_compose(*pa, o->frags[a].home), wb = pose_compose(*pb, o->frags[b].home);
    obb_result r;
    int rc = obb_collide(o->tree[a], &wa, o->tree[b], &wb, &o->q, cache, &r);
    if (rc < 0)
        return rc;
    out->collides = r.collides;
    out->separation_mm = r.separation_mm;
    return 0;
}

loop_collider loop_obb_collider(loop_obb *o)
{
    loop_collider c = {query, sizeof(obb_cache), o};
    return c;
}
