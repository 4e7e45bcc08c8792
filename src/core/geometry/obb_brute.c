/* obb: the separating-axis test shared by all paths, and the brute-force reference query. */
#include "obb.h"

#include "err.h"
#include "obb_impl.h"

#include <string.h>

#define BRICK 8
#define MARGIN 1e-6 /* mm added to every pruning box: pruning must never drop a real pair */

void obb__rel_make(obb__rel *rel, const pose *a_world, const double sa[3], const pose *b_world,
                   const double sb[3], double tol)
{
    pose ab = pose_compose(pose_inverse(*a_world), *b_world);
    pose_to_matrix(&ab, rel->R);
    memcpy(rel->t, ab.t, sizeof rel->t);
    for (int i = 0; i < 3; i++)
        rel->hsa[i] = 0.5 * sa[i], rel->hsb[i] = 0.5 * sb[i];
    rel->tol = tol;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double r = rel->R[i][j], l2 = 1 - r * r;
            rel->AR0[i][j] = fabs(r);
            rel->AR[i][j] = fabs(r) + OBB__EPS;
            rel->Rs[i][j] = r * (0.5 * sb[j]);
            rel->inv_len[i][j] = l2 > 1e-12 ? 1 / sqrt(l2) : 0;
        }
}

int obb_box_overlap(const double R[3][3], const double t[3], const double ca[3], const double ha[3],
                    const double cb[3], const double hb[3], double *gap)
{
    double m[3][3];
    memcpy(m, R, sizeof m);
    pose p = pose_from_matrix(m, t), id = POSE_IDENTITY;
    obb__rel rel;
    static const double unit[3] = {1, 1, 1};
    obb__rel_make(&rel, &id, unit, &p, unit, 0);
    double bt[3], T[3];
    obb__carry(&rel, cb, bt);
    for (int i = 0; i < 3; i++)
        T[i] = bt[i] - ca[i];
    return obb__sat(&rel, 1, 1, T, ha, hb, 1, gap);
}

int obb__check_query(const obb_query *q, const double sa[3], const double sb[3])
{
    if (!(q->threshold >= 0 && q->threshold <= 1))
        return fn_err_set(FN_EINVAL, "obb query: threshold %g is outside [0,1]", q->threshold);
    double half = 0.5 * fmin(fmin(fmin(sa[0], sa[1]), sa[2]), fmin(fmin(sb[0], sb[1]), sb[2]));
    if (!(q->tolerance_mm >= 0 && q->tolerance_mm < half))
        return fn_err_set(FN_EINVAL,
                          "obb query: tolerance_mm %g must be >= 0 and below half the smallest "
                          "voxel spacing (%g mm)",
                          q->tolerance_mm, half);
    if (q->want_pairs && !q->pairs && q->max_pairs)
        return fn_err_set(FN_EINVAL, "obb query: want_pairs with max_pairs %zu but no pairs buffer",
                          q->max_pairs);
    if (q->inner_axes != 0 && q->inner_axes != 6 && q->inner_axes != 15)
        return fn_err_set(FN_EINVAL, "obb query: inner_axes %d is not 0, 6 or 15", q->inner_axes);
    if (q->order != OBB_DEPTH_FIRST && q->order != OBB_BREADTH_FIRST)
        return fn_err_set(FN_EINVAL, "obb query: order %d is neither depth- nor breadth-first",
                          q->order);
    return 0;
}

static int check_frag(const frag *f, const char *which)
{
    if (!f || !f->prob)
        return fn_err_set(FN_EINVAL, "obb_collide_brute: fragment %s missing", which);
    for (int i = 0; i < 3; i++)
        if (f->dim[i] < 1 || f->dim[i] > UINT16_MAX || !(f->spacing[i] > 0) ||
            !isfinite(f->spacing[i]))
            return fn_err_set(FN_EFORMAT, "fragment '%s': bad dim[%d] %d or spacing[%d] %g",
                              f->name, i, f->dim[i], i, f->spacing[i]);
    return 0;
}

typedef struct brute {
    const frag *a, *b;
    obb__rel rel;
    uint8_t lut[256];
    int thr, want_pairs;
    double tol, ha[3], hb[3];
    const obb_query *q;
    obb_result *r;
} brute;

/* B's box [lo, hi] misses A's whole crop when its A-frame bounding box does. */
static int outside_a(const brute *c, const uint16_t lo[3], const uint16_t hi[3])
{
    double hb[3], bt[3];
    obb__box_b(&c->rel, lo, hi, bt, hb);
    for (int i = 0; i < 3; i++) {
        const double *AR = c->rel.AR[i], x = bt[i];
        double e = AR[0] * hb[0] + AR[1] * hb[1] + AR[2] * hb[2] + MARGIN;
        double s = c->a->spacing[i], alo = -c->ha[i], ahi = (c->a->dim[i] - 1) * s + c->ha[i];
        if (x + e <= alo || x - e >= ahi)
            return 1;
    }
    return 0;
}

/* Every A voxel whose box can meet B voxel vb; returns 1 when the query is settled. */
static int test_voxel(brute *c, const uint16_t vb[3], int eb)
{
    double hb[3], bt[3], e[3];
    int lo[3], hi[3];
    obb__box_b(&c->rel, vb, vb, bt, hb);
    for (int i = 0; i < 3; i++) {
        const double *AR = c->rel.AR[i], s = c->a->spacing[i];
        e[i] = AR[0] * hb[0] + AR[1] * hb[1] + AR[2] * hb[2] + c->ha[i] + MARGIN;
        lo[i] = (int)fmax(floor((bt[i] - e[i]) / s), 0);
        hi[i] = (int)fmin(ceil((bt[i] + e[i]) / s), c->a->dim[i] - 1);
    }
    const int *d = c->a->dim;
    for (int k = lo[2]; k <= hi[2]; k++)
        for (int j = lo[1]; j <= hi[1]; j++)
            for (int i = lo[0]; i <= hi[0]; i++) {
                int ea = c->lut[c->a->prob[((size_t)k * d[1] + j) * d[0] + i]];
                if (!ea || ea * eb < c->thr)
                    continue;
                uint16_t va[3] = {(uint16_t)i, (uint16_t)j, (uint16_t)k};
                double ca[3], ha[3], T[3], gap;
                obb__box_a(&c->rel, va, va, ca, ha);
                for (int a = 0; a < 3; a++)
                    T[a] = bt[a] - ca[a];
                c->r->tests++;
                if (!obb__sat(&c->rel, 1, 1, T, ha, hb, 1, &gap))
                    continue;
                obb_result *r = c->r;
                if (c->want_pairs && r->npairs < c->q->max_pairs) {
                    obb_pair *p = &c->q->pairs[r->npairs++];
                    memcpy(p->a, va, sizeof va);
                    memcpy(p->b, vb, sizeof p->b);
                }
                r->pairs_total++;
                r->separation_mm = r->collides && r->separation_mm < gap ? r->separation_mm : gap;
                r->collides = 1;
                if (!c->want_pairs)
                    return 1;
            }
    return 0;
}

/* B in bricks of 8^3: a brick whose box misses A's crop is skipped whole. */
static void scan_b(brute *c)
{
    const int *d = c->b->dim;
    for (int bz = 0; bz < d[2]; bz += BRICK)
        for (int by = 0; by < d[1]; by += BRICK)
            for (int bx = 0; bx < d[0]; bx += BRICK) {
                uint16_t lo[3] = {(uint16_t)bx, (uint16_t)by, (uint16_t)bz}, hi[3];
                for (int i = 0; i < 3; i++)
                    hi[i] = (uint16_t)(lo[i] + BRICK - 1 < d[i] - 1 ? lo[i] + BRICK - 1 : d[i] - 1);
                if (outside_a(c, lo, hi))
                    continue;
                for (int k = lo[2]; k <= hi[2]; k++)
                    for (int j = lo[1]; j <= hi[1]; j++)
                        for (int i = lo[0]; i <= hi[0]; i++) {
                            int eb = c->lut[c->b->prob[((size_t)k * d[1] + j) * d[0] + i]];
                            uint16_t vb[3] = {(uint16_t)i, (uint16_t)j, (uint16_t)k};
                            if (eb && test_voxel(c, vb, eb))
                                return;
                        }
            }
}

int obb_collide_brute(const frag *a, const pose *a_world, const frag *b, const pose *b_world,
                      const obb_params *params, const obb_query *q, obb_result *r)
{
    static const obb_query none = {0};
    obb_params p = params ? *params : (obb_params){0, 1};
    int rc = check_frag(a, "A");
    if (rc || (rc = check_frag(b, "B")))
        return rc;
    if (!a_world || !b_world || !r)
        return fn_err_set(FN_EINVAL, "obb_collide_brute: NULL pose or result");
    if (!(p.tau_min >= 0 && p.tau_min <= p.tau_max && p.tau_max <= 1))
        return fn_err_set(FN_EINVAL, "obb params: need 0 <= tau_min (%g) <= tau_max (%g) <= 1",
                          p.tau_min, p.tau_max);
    if (q && (rc = obb__check_query(q, a->spacing, b->spacing)))
        return rc;
    brute c = {.a = a, .b = b, .q = q ? q : &none, .r = r};
    memset(r, 0, sizeof *r);
    for (int v = 0; v < 256; v++)
        c.lut[v] = obb_effective_prob((uint8_t)v, &p);
    c.thr = obb__threshold(c.q->threshold);
    c.tol = c.q->tolerance_mm;
    c.want_pairs = c.q->want_pairs;
    for (int i = 0; i < 3; i++)
        c.ha[i] = 0.5 * a->spacing[i] - c.tol, c.hb[i] = 0.5 * b->spacing[i] - c.tol;
    obb__rel_make(&c.rel, a_world, a->spacing, b_world, b->spacing, c.tol);
    scan_b(&c);
    if (!r->collides)
        r->separation_mm = NAN;
    return 0;
}
