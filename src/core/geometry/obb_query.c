/* obb: the collision query between two hierarchies (separating-axis tests, depth- or breadth-first). */
#include "obb.h"

#include "err.h"
#include "obb_impl.h"

#include <math.h>
#include <string.h>

#define LEAF 0x80000000u
#define STACK 512  /* > 1 + 7 * (2 * 17 levels): a split pushes at most 8 pairs */
#define QUEUE 2048 /* breadth-first ring; a pair that finds it full is searched depth-first */

typedef struct npair {
    obb_node a, b;
} npair;

typedef struct ctx {
    obb__rel rel;
    double Rt[3][3], ARt[3][3]; /* R and |R| + eps transposed: B's axes in A's frame */
    const obb_node *na, *nb;
    double sa[3], sb[3], tol;
    int thr, want_pairs, edges;
    const obb_query *q;
    obb_result *r;
    obb_cache *cache;
    int rec, overflow; /* recording the front into cache; it did not fit */
    double lowered;    /* the front's lowered when the recorded pairs are used */
    double best_gap, pen;
} ctx;

static int is_leaf(const obb_node *n)
{
    return (n->info & LEAF) != 0;
}

static int is_voxel(const obb_node *n)
{
    return is_leaf(n) && n->lo[0] == n->hi[0] && n->lo[1] == n->hi[1] && n->lo[2] == n->hi[2];
}

/* Upper bound of the node's effective probability byte. */
static int pmax(const obb_node *n)
{
    return is_leaf(n) ? (int)(n->info & 0xff) : (int)((n->info >> 24) & 0xf) * 17;
}

static double volume(const obb_node *n, const double s[3])
{
    return (n->hi[0] - n->lo[0] + 1.0) * s[0] * (n->hi[1] - n->lo[1] + 1.0) * s[1] *
           (n->hi[2] - n->lo[2] + 1.0) * s[2];
}

/* The children of n: inner nodes point at their stored children, the octants of a solid block
 * are made on the fly in buf. */
static int split(const obb_node *n, const obb_node *all, obb_node buf[8], const obb_node **out)
{
    if (!is_leaf(n)) {
        *out = all + (n->info & 0xffffffu);
        return (int)((n->info >> 28) & 7u) + 1;
    }
    uint16_t mid[3];
    int halves[3];
    for (int i = 0; i < 3; i++) {
        halves[i] = n->hi[i] > n->lo[i] ? 2 : 1;
        mid[i] = (uint16_t)(n->lo[i] + (n->hi[i] - n->lo[i] + 1) / 2);
    }
    int k = 0;
    for (int z = 0; z < halves[2]; z++)
        for (int y = 0; y < halves[1]; y++)
            for (int x = 0; x < halves[0]; x++) {
                int h[3] = {x, y, z};
                obb_node *o = &buf[k++];
                *o = *n;
                for (int i = 0; i < 3; i++) {
                    if (halves[i] == 1)
                        continue;
                    if (h[i])
                        o->lo[i] = mid[i];
                    else
                        o->hi[i] = (uint16_t)(mid[i] - 1);
                }
            }
    *out = buf;
    return k;
}

/* Adds a colliding voxel pair to the cache's witnesses, unless it is one of them. */
static void keep_witness(obb_cache *k, const obb_node *a, const obb_node *b)
{
    for (int i = 0; i < k->nwit; i++)
        if (!memcmp(&k->wa[i], a, sizeof *a) && !memcmp(&k->wb[i], b, sizeof *b))
            return;
    k->wa[k->wnext] = *a, k->wb[k->wnext] = *b;
    k->wnext = (k->wnext + 1) % OBB_WITNESSES;
    k->nwit += k->nwit < OBB_WITNESSES;
}

static void record(ctx *c, const obb_node *a, const obb_node *b, double gap)
{
    obb_result *r = c->r;
    if (c->want_pairs && r->npairs < c->q->max_pairs) {
        obb_pair *p = &c->q->pairs[r->npairs++];
        memcpy(p->a, a->lo, sizeof p->a);
        memcpy(p->b, b->lo, sizeof p->b);
    }
    r->pairs_total++;
    r->collides = 1;
    c->pen = gap < c->pen ? gap : c->pen;
    if (c->cache)
        keep_witness(c->cache, a, b);
}

static void box_a(const ctx *c, const obb_node *a, double ca[3], double ha[3])
{
    obb__box_a(&c->rel, a->lo, a->hi, ca, ha);
}

/* B's box with its centre carried into A's frame. */
static void box_b(const ctx *c, const obb_node *b, double bt[3], double hb[3])
{
    obb__box_b(&c->rel, b->lo, b->hi, bt, hb);
}

/* Books a rejected pair: into the front when recording, and into the separation bound (refined
 * over all axes only when its first-axis gap could lower the minimum). */
static void rejected(ctx *c, const obb_node *a, const obb_node *b, int exact, double gap)
{
    if (c->rec) {
        if (c->cache->front_n < OBB_FRONT_MAX)
            c->cache->front[c->cache->front_n++] = (obb_front_pair){*a, *b, gap + c->lowered};
        else
            c->overflow = 1;
    }
    if (gap < c->best_gap) {
        double ca[3], ha[3], bt[3], hb[3];
        box_a(c, a, ca, ha);
        box_b(c, b, bt, hb);
        double T[3] = {bt[0] - ca[0], bt[1] - ca[1], bt[2] - ca[2]};
        obb__sat(&c->rel, exact, c->edges, T, ha, hb, 1, &gap);
        c->best_gap = gap < c->best_gap ? gap : c->best_gap;
    }
}

/* Tests one pair. Returns 1 when it must be split, 0 when it is settled: rejected (its gap
 * lowers the separation bound) or a colliding voxel pair (recorded). Voxel pairs get the exact
 * test, inner pairs the conservative one; a first-axis gap is a valid bound, refined over all 15
 * axes only when it could lower the minimum. */
static int test(ctx *c, const obb_node *a, const double ca[3], const double ha[3],
                const obb_node *b, const double bt[3], const double hb[3], int exact,
                double *dist2)
{
    if (c->thr && pmax(a) * pmax(b) < c->thr)
        return 0;
    double T[3] = {bt[0] - ca[0], bt[1] - ca[1], bt[2] - ca[2]}, gap;
    c->r->tests++;
    int hit = exact      ? obb__sat(&c->rel, 1, 1, T, ha, hb, 0, &gap)
              : c->edges ? obb__sat(&c->rel, 0, 1, T, ha, hb, 0, &gap)
                         : obb__sat(&c->rel, 0, 0, T, ha, hb, 0, &gap);
    if (hit) {
        *dist2 = T[0] * T[0] + T[1] * T[1] + T[2] * T[2];
        if (!exact)
            return 1;
        obb__sat(&c->rel, 1, 1, T, ha, hb, 1, &gap);
        record(c, a, b, gap);
        return 0;
    }
    rejected(c, a, b, exact, gap);
    return 0;
}

/* An inner pair of an expansion, as the kept node sees it: a child point x (child frame, mm) lies
 * at M x + d from the kept centre (kept axes); the kept centre is co in the child frame and
 * reaches r along the child axes. Precomputed once per expansion, so that each child's own three
 * face axes cost a subtraction each and are tried first. */
typedef struct kept {
    const double (*M)[3], (*AM)[3]; /* child frame -> kept frame: R or R^T, and |M| + eps */
    double h[3], d[3], co[3], r[3];
    double hs[3]; /* the children's half spacing */
} kept;

static void kept_make(const ctx *c, int split_b, const double cen[3], const double h[3], kept *k)
{
    k->M = split_b ? c->rel.R : c->Rt;
    k->AM = split_b ? c->rel.AR : c->ARt;
    for (int i = 0; i < 3; i++) {
        k->h[i] = h[i];
        k->hs[i] = split_b ? c->rel.hsb[i] : c->rel.hsa[i];
        /* A kept: d = t - ca; B kept: d = -R^T bt (bt = B's centre in A's frame) */
        k->d[i] = split_b ? c->rel.t[i] - cen[i]
                          : -(c->rel.R[0][i] * cen[0] + c->rel.R[1][i] * cen[1] +
                              c->rel.R[2][i] * cen[2]);
    }
    for (int j = 0; j < 3; j++) {
        k->co[j] = -(k->M[0][j] * k->d[0] + k->M[1][j] * k->d[1] + k->M[2][j] * k->d[2]);
        k->r[j] = k->h[0] * k->AM[0][j] + k->h[1] * k->AM[1][j] + k->h[2] * k->AM[2][j];
    }
}

/* The conservative six-face-axis test of child n against the kept node (same bound and slack as
 * obb__sat's inner test, only the order of the sums differs, far below OBB__SLACK). Returns 0
 * when rejected (booked), else 1: the pair must be split (*dist2: squared centre distance), or,
 * exact (a voxel pair), it needs the exact test. A voxel pair it rejects is apart by about
 * OBB__SLACK on some axis, so the exact test would reject it as well. */
static int test_inner(ctx *c, const kept *k, const obb_node *n, const obb_node *a,
                      const obb_node *b, int exact, double *dist2)
{
    if (c->thr && pmax(a) * pmax(b) < c->thr)
        return 0;
    c->r->tests += !exact;
    double cc[3], hc[3], u[3], s = -INFINITY;
    for (int i = 0; i < 3; i++) {
        cc[i] = (double)(n->lo[i] + n->hi[i]) * k->hs[i];
        hc[i] = (double)(n->hi[i] - n->lo[i]) * k->hs[i] + (k->hs[i] - c->tol);
        u[i] = cc[i] - k->co[i];
    }
    for (int i = 0; i < 3 && s < OBB__SLACK; i++)
        s = fabs(u[i]) - (hc[i] + k->r[i]);
    for (int i = 0; i < 3 && s < OBB__SLACK; i++)
        s = fabs(k->M[i][0] * cc[0] + k->M[i][1] * cc[1] + k->M[i][2] * cc[2] + k->d[i]) -
            (k->h[i] + hc[0] * k->AM[i][0] + hc[1] * k->AM[i][1] + hc[2] * k->AM[i][2]);
    if (s >= OBB__SLACK) {
        c->r->tests += exact;
        rejected(c, a, b, exact, s);
        return 0;
    }
    *dist2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
    return 1;
}

static int test_pair(ctx *c, const npair *p)
{
    double ca[3], ha[3], bt[3], hb[3];
    box_a(c, &p->a, ca, ha);
    box_b(c, &p->b, bt, hb);
    double dist2;
    return test(c, &p->a, ca, ha, &p->b, bt, hb, is_voxel(&p->a) && is_voxel(&p->b), &dist2);
}

static int done(const ctx *c)
{
    return c->r->collides && !c->want_pairs;
}

/* Asks for the children of inner node n: a pushed pair is split later, its nodes' children are
 * mostly out of cache by then. */
static void prefetch_kids(const obb_node *n, const obb_node *all)
{
    if (is_leaf(n))
        return;
    const obb_node *k = all + (n->info & 0xffffffu);
    __builtin_prefetch(k);
    __builtin_prefetch(k + 7);
}

/* Splits the larger node of p (never a voxel) and appends each child pair that needs splitting to
 * out (room for 8), the pair with the nearest centres last so depth-first search tends to meet a
 * collision early. The kept node's box is computed once. */
static void expand(ctx *c, const npair *p, npair *out, int *n)
{
    int va = is_voxel(&p->a), vb = is_voxel(&p->b);
    int split_b = va ? 1 : vb ? 0 : volume(&p->b, c->sb) > volume(&p->a, c->sa);
    obb_node buf[8];
    const obb_node *kid;
    double ca[3], ha[3], bt[3], hb[3], key[8];
    int k = split(split_b ? &p->b : &p->a, split_b ? c->nb : c->na, buf, &kid), first = *n;
    kept kp;
    if (split_b)
        box_a(c, &p->a, ca, ha);
    else
        box_b(c, &p->b, bt, hb);
    kept_make(c, split_b, split_b ? ca : bt, split_b ? ha : hb, &kp);
    for (int i = 0; i < k && !done(c); i++) {
        const obb_node *a = split_b ? &p->a : &kid[i], *b = split_b ? &kid[i] : &p->b;
        int exact = (split_b ? va : vb) && is_voxel(&kid[i]);
        double d;
        if (!c->edges && !test_inner(c, &kp, &kid[i], a, b, exact, &d))
            continue;
        if (exact || c->edges) {
            if (split_b)
                box_b(c, b, bt, hb);
            else
                box_a(c, a, ca, ha);
            if (!test(c, a, ca, ha, b, bt, hb, exact, &d))
                continue;
        }
        int j = *n - first;
        for (; j > 0 && key[j - 1] < d; j--) {
            key[j] = key[j - 1];
            out[first + j] = out[first + j - 1];
        }
        key[j] = d;
        out[first + j] = (npair){*a, *b};
        prefetch_kids(split_b ? b : a, split_b ? c->nb : c->na);
        (*n)++;
    }
}

/* Pairs on the stack have passed their test and wait to be split. */
static void depth_first(ctx *c, const npair *start)
{
    npair stack[STACK];
    int n = 0;
    stack[n++] = *start;
    while (n > 0 && !done(c)) {
        npair p = stack[--n];
        expand(c, &p, stack, &n);
    }
}

static void breadth_first(ctx *c, const npair *start)
{
    npair ring[QUEUE];
    size_t head = 0, count = 1;
    ring[0] = *start;
    while (count > 0 && !done(c)) {
        npair p = ring[head], kids[8];
        head = (head + 1) % QUEUE;
        count--;
        int k = 0;
        expand(c, &p, kids, &k);
        for (int i = 0; i < k; i++) {
            if (count < QUEUE)
                ring[(head + count++) % QUEUE] = kids[i];
            else
                depth_first(c, &kids[i]);
        }
    }
}

void obb_cache_reset(obb_cache *c)
{
    if (c)
        memset(c, 0, sizeof *c);
}

static int check_args(const obb_tree *a, const pose *aw, const obb_tree *b, const pose *bw,
                      const obb_query *q, obb_result *r)
{
    if (!a || !b || !aw || !bw || !r)
        return fn_err_set(FN_EINVAL, "obb_collide: NULL tree, pose or result");
    for (int i = 0; i < 4; i++)
        if (!isfinite(aw->q[i]) || !isfinite(bw->q[i]) || (i < 3 && (!isfinite(aw->t[i]) ||
                                                                     !isfinite(bw->t[i]))))
            return fn_err_set(FN_EINVAL, "obb_collide: pose has a non-finite value");
    return q ? obb__check_query(q, obb_tree_spacing(a), obb_tree_spacing(b)) : 0;
}

/* How far any point of B's root box moved, relative to A, since the front's reference pose. */
static double motion_bound(const ctx *c, const obb_cache *k)
{
    const obb_node *root = &c->nb[0];
    double cb[3], d[3], rb = 0, fro = 0;
    for (int i = 0; i < 3; i++) {
        double h = ((root->hi[i] - root->lo[i]) * 0.5 + 0.5) * c->sb[i];
        cb[i] = (root->lo[i] + root->hi[i]) * 0.5 * c->sb[i];
        rb += h * h;
    }
    for (int i = 0; i < 3; i++) {
        d[i] = c->rel.t[i] - k->ref_t[i];
        for (int j = 0; j < 3; j++) {
            double e = c->rel.R[i][j] - k->ref_R[i][j];
            d[i] += e * cb[j];
            fro += e * e;
        }
    }
    /* |(R - R0) y| <= 2 sin(angle / 2) |y| = ||R - R0||_F / sqrt(2) |y| */
    double move = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) + sqrt(fro / 2) * sqrt(rb);
    return move * (1 + 1e-9) + 1e-9;
}

static int front_fits(const ctx *c, const obb_cache *k, const obb_tree *a, const obb_tree *b)
{
    return k->front_valid && k->ta == a && k->tb == b && k->threshold == c->q->threshold &&
           k->tolerance_mm == c->q->tolerance_mm && k->inner_axes == c->q->inner_axes;
}

/* Moves the front to the pose queried: the first n0 pairs are the front at the reference pose,
 * those after them what the search of its near pairs (gap within delta) rejected, at this pose.
 * Each near pair gives way to one of the new ones (or to a kept one from the end); the kept pairs
 * are delta closer at worst (lowered). */
static void front_move(const ctx *c, obb_cache *k, size_t n0, double delta)
{
    size_t end = k->front_n;
    for (size_t i = n0; i-- > 0;)
        if (k->front[i].gap - k->lowered - OBB__SLACK <= delta)
            k->front[i] = k->front[--end];
    k->front_n = end;
    k->lowered = c->lowered;
    memcpy(k->ref_R, c->rel.R, sizeof k->ref_R);
    memcpy(k->ref_t, c->rel.t, sizeof k->ref_t);
}

/* Answers from the front when few of its pairs can have closed their gap; 0 when not worth it.
 * Free, it moves the front here (front_move) when what the near pairs' search rejected fits;
 * colliding, the front stays as it was. */
static int from_front(ctx *c, obb_cache *k)
{
    double delta = motion_bound(c, k), rest = INFINITY;
    size_t near = 0, n0 = k->front_n;
    for (size_t i = 0; i < n0; i++)
        near += k->front[i].gap - k->lowered - OBB__SLACK <= delta;
    if (near > n0 / 4 + 16 || n0 > k->front_made + k->front_made / 2 + 64)
        return 0; /* a search from the root is cheaper, or makes a tighter front */
    c->rec = 1;
    c->lowered = k->lowered + delta;
    for (size_t i = 0; i < n0 && !done(c); i++) {
        const obb_front_pair *f = &k->front[i];
        double gap = f->gap - k->lowered - OBB__SLACK;
        npair p = {f->a, f->b};
        if (gap > delta)
            rest = fmin(rest, gap - delta);
        else if (test_pair(c, &p))
            depth_first(c, &p);
    }
    c->rec = 0;
    if (c->r->collides || c->overflow)
        k->front_n = n0;
    else
        front_move(c, k, n0, delta);
    k->reuses++;
    c->best_gap = fmin(c->best_gap, rest + OBB__SLACK);
    return 1;
}

static void search(ctx *c, obb_cache *k, const obb_tree *a, const obb_tree *b)
{
    if (k && !c->want_pairs) {
        k->front_valid = 0;
        k->front_n = 0;
        k->ta = a, k->tb = b;
        k->threshold = c->q->threshold, k->tolerance_mm = c->q->tolerance_mm;
        k->inner_axes = c->q->inner_axes;
        k->lowered = 0;
        k->rebuilds++;
        memcpy(k->ref_R, c->rel.R, sizeof k->ref_R);
        memcpy(k->ref_t, c->rel.t, sizeof k->ref_t);
        c->rec = 1;
    }
    npair root = {c->na[0], c->nb[0]};
    if (test_pair(c, &root)) {
        if (c->q->order == OBB_BREADTH_FIRST)
            breadth_first(c, &root);
        else
            depth_first(c, &root);
    }
    if (c->rec) {
        k->front_valid = !c->r->collides && !c->overflow;
        k->front_made = k->front_n;
    }
    c->rec = 0;
}

int obb_collide(const obb_tree *a, const pose *a_world, const obb_tree *b, const pose *b_world,
                const obb_query *q, obb_cache *cache, obb_result *r)
{
    int rc = check_args(a, a_world, b, b_world, q, r);
    if (rc)
        return rc;
    static const obb_query none = {0};
    ctx c = {.na = obb_tree_node_array(a), .nb = obb_tree_node_array(b), .q = q ? q : &none,
             .r = r, .cache = cache, .best_gap = INFINITY, .pen = 0};
    memset(r, 0, sizeof *r);
    c.thr = obb__threshold(c.q->threshold);
    c.tol = c.q->tolerance_mm;
    c.want_pairs = c.q->want_pairs;
    c.edges = c.q->inner_axes == 15;
    memcpy(c.sa, obb_tree_spacing(a), sizeof c.sa);
    memcpy(c.sb, obb_tree_spacing(b), sizeof c.sb);
    if (!obb_tree_nodes(a) || !obb_tree_nodes(b)) {
        r->separation_mm = INFINITY;
        return 0;
    }
    obb__rel_make(&c.rel, a_world, c.sa, b_world, c.sb, c.tol);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            c.Rt[i][j] = c.rel.R[j][i], c.ARt[i][j] = c.rel.AR[j][i];
    if (cache && cache->nwit && !c.want_pairs) {
        for (int i = 0; i < cache->nwit && !done(&c); i++) {
            npair w = {cache->wa[i], cache->wb[i]};
            test_pair(&c, &w);
        }
        if (done(&c)) {
            r->separation_mm = c.pen;
            return 0;
        }
        c.best_gap = INFINITY; /* the witnesses' gaps say nothing about the other pairs */
    }
    int answered = cache && !c.want_pairs && front_fits(&c, cache, a, b) && from_front(&c, cache);
    if (!answered)
        search(&c, cache, a, b);
    if (r->collides)
        r->separation_mm = c.pen;
    else
        r->separation_mm = c.best_gap > OBB__SLACK ? c.best_gap - OBB__SLACK : 0;
    return 0;
}
