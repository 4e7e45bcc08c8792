/* reduce_prealign: the geometry the stages share, the slide into contact, and the paper's
 * principal-axis pre-alignment (Fig. 5; see reduce.h). */
#include "reduce.h"
#include "reduce_impl.h"

#include <math.h>

#define PI 3.14159265358979323846

void reduce__axis_world(const frag *f, int col, double v[3])
{
    double a[3] = {f->axes[0][col], f->axes[1][col], f->axes[2][col]};
    pose_rotate(&f->pose, a, v);
}

void reduce__centroid_world(const frag *f, double c[3])
{
    pose_apply(&f->pose, f->centroid, c);
}

/* The rotation taking unit a onto unit b. */
static pose rotation_onto(const double a[3], const double b[3])
{
    double ax[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    double s = sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2]), c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    if (s < 1e-12) {
        if (c > 0)
            return POSE_IDENTITY;
        double p[3] = {0, 0, 0}; /* any axis perpendicular to a */
        p[fabs(a[0]) < 0.6 ? 0 : 1] = 1;
        double d = p[0] * a[0] + p[1] * a[1] + p[2] * a[2];
        for (int i = 0; i < 3; i++)
            p[i] -= d * a[i];
        double n = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        for (int i = 0; i < 3; i++)
            p[i] /= n;
        return pose_from_axis_angle(p, PI);
    }
    for (int i = 0; i < 3; i++)
        ax[i] /= s;
    return pose_from_axis_angle(ax, atan2(s, c));
}

pose reduce__turned(const pose *P, const pose *rot, const double c[3], const double to[3])
{
    pose r = pose_compose(*rot, *P);
    double rc[3];
    pose_rotate(rot, c, rc);
    for (int a = 0; a < 3; a++)
        r.t[a] += to[a] - rc[a];
    return r;
}

/* The world box of a fragment's crop at its pose. */
static void world_box(const frag *f, const pose *p, double lo[3], double hi[3])
{
    pose w = pose_compose(*p, f->home);
    for (int a = 0; a < 3; a++) {
        lo[a] = INFINITY;
        hi[a] = -INFINITY;
    }
    for (int corner = 0; corner < 8; corner++) {
        double l[3], x[3];
        for (int a = 0; a < 3; a++)
            l[a] = (corner >> a & 1 ? f->dim[a] - 1 : 0) * f->spacing[a];
        pose_apply(&w, l, x);
        for (int a = 0; a < 3; a++) {
            lo[a] = fmin(lo[a], x[a]);
            hi[a] = fmax(hi[a], x[a]);
        }
    }
}

/* The overlap of the two world boxes (the assembly's first fragment's and the moving one's at p),
 * grown by prealign_box_mm: 0, or -1 where they do not overlap. */
static int overlap_box(const reduce_collider *pc, const pose *p, reduce_voi *v)
{
    double alo[3], ahi[3], mlo[3], mhi[3];
    world_box(pc->asm_[0], &pc->asm_[0]->pose, alo, ahi);
    world_box(pc->moving, p, mlo, mhi);
    for (int a = 0; a < 3; a++) {
        v->lo[a] = fmax(alo[a], mlo[a]) - reduce__tune.prealign_box_mm;
        v->hi[a] = fmin(ahi[a], mhi[a]) + reduce__tune.prealign_box_mm;
        if (v->lo[a] >= v->hi[a])
            return -1;
    }
    return 0;
}

int reduce__slide_to_contact(const reduce_collider *pc, pose *p, const double dir[3], double span)
{
    const double step = reduce__tune.slide_step_mm;
    double moved = 0, prev = -1, sep;
    while (moved < 2 * span) {
        pose cur = *p;
        for (int a = 0; a < 3; a++)
            cur.t[a] += moved * dir[a];
        int c = reduce__collides(pc, &cur, &sep);
        if (c < 0)
            return c;
        if (c && prev < 0)
            return 0; /* colliding from the start: no approach along this line */
        if (c) {
            double lo = prev, hi = moved; /* free at lo, colliding at hi: halve towards contact */
            for (int i = 0; i < reduce__tune.slide_halvings; i++) {
                double mid = 0.5 * (lo + hi);
                pose t = *p;
                for (int a = 0; a < 3; a++)
                    t.t[a] += mid * dir[a];
                int cm = reduce__collides(pc, &t, NULL);
                if (cm < 0)
                    return cm;
                if (cm)
                    hi = mid;
                else
                    lo = mid;
            }
            for (int a = 0; a < 3; a++)
                p->t[a] += lo * dir[a];
            return 1;
        }
        prev = moved;
        moved += isfinite(sep) && sep > step ? sep : step;
    }
    return 0;
}

#define PREALIGN_MAX 64 /* the placed pose and 2 signs x 2 sides x 360 / prealign_turn_deg turns */

int reduce__prealign(const reduce_collider *pc, reduce_bricks *b, const reduce_opts *o, int *changed)
{
    const frag *fx = pc->asm_[0];
    frag *m = pc->moving;
    pose placed = m->pose, cand[PREALIGN_MAX];
    reduce_voi u = {{INFINITY, INFINITY, INFINITY}, {-INFINITY, -INFINITY, -INFINITY}}, v;
    int n = 0;
    if (overlap_box(pc, &placed, &v) == 0) {
        cand[n++] = placed;
        u = v;
    }
    const int first = n; /* cand[0] is the placed pose when it has an overlap */
    double af[3], am[3], cf[3], cm[3];
    reduce__axis_world(fx, 0, af);
    reduce__axis_world(m, 0, am);
    reduce__centroid_world(fx, cf);
    reduce__centroid_world(m, cm);
    double span = 2 * (sqrt(3 * fx->eigval[0]) + sqrt(3 * m->eigval[0])) + reduce__tune.prealign_span_mm;
    double per_turn = 180 / reduce__tune.prealign_turn_deg; /* PI / per_turn: one turn */
    int turns = (int)(2 * per_turn);
    *changed = 0;
    for (int sign = -1; sign <= 1; sign += 2) {
        double target[3] = {sign * af[0], sign * af[1], sign * af[2]};
        pose align = rotation_onto(am, target);
        for (int side = -1; side <= 1; side += 2)
            for (int step = 0; step < turns && n < PREALIGN_MAX; step++) {
                pose turn = pose_from_axis_angle(af, step * PI / per_turn);
                pose rot = pose_compose(turn, align);
                double to[3], dir[3];
                for (int a = 0; a < 3; a++) {
                    to[a] = cf[a] + side * span * af[a];
                    dir[a] = -side * af[a];
                }
                pose c = reduce__turned(&placed, &rot, cm, to);
                int rc = reduce__slide_to_contact(pc, &c, dir, span);
                if (rc < 0)
                    return rc;
                if (rc && overlap_box(pc, &c, &v) == 0) {
                    cand[n++] = c;
                    for (int a = 0; a < 3; a++) {
                        u.lo[a] = fmin(u.lo[a], v.lo[a]);
                        u.hi[a] = fmax(u.hi[a], v.hi[a]);
                    }
                }
            }
    }
    /* all of them scored over one VOI, the union of their boxes' overlaps (one metric, not one per
     * candidate: on the example skull that was 48 metrics, 15% of a fit), the placed pose first */
    int best = 0;
    reduce_metric *mu = n > first ? reduce__metric_with(pc->asm_, pc->nasm, m, b, &u, o->count, o->band_mm,
                                                        reduce__band_cut(o->band_mm), o->gap_mm)
                                  : NULL;
    double bestf = INFINITY;
    for (int i = 0; mu && i < n; i++) {
        double f = reduce_metric_eval(mu, &cand[i], NULL);
        if (f < bestf) {
            bestf = f;
            best = i;
        }
    }
    reduce_metric_free(mu);
    *changed = mu && best >= first;
    m->pose = *changed ? cand[best] : placed;
    return 0;
}
