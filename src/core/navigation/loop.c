/* loop: stepping, collision outcomes, controls, undo/redo. Statistics and the scene buffer are in
 * loop_stats.c, the driver (loop_run, loop_drain) in loop_run.c, the input thread in loop_reader.c. */
#include "loop_impl.h"

#include "err.h"
#include "fnclock.h"
#include "journal.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define SAFETY_MM 0.01 /* the separation shortcut keeps this much distance in hand */
#define CLIMB 0.5      /* backing away per unit of tangential motion when riding over a bump */
#define OVERLAP_EPS_MM3 1e-6 /* rounding in the overlap sum: a sideways move is not deeper */

/* How an accepted pose was checked: not at all (checking off), found free, or found still
 * interpenetrating but no deeper than before (pulled out after checking came back on). */
enum { LOOP_UNCHECKED, LOOP_CHECKED, LOOP_ESCAPING, LOOP_TOLERATED };
/* Which cache a query uses: the pair's, or a zeroed scratch (from scratch), forgotten after or
 * kept as the pair's (what a query from scratch leaves is what a cached one would have). */
enum { PAIR_CACHE = 0, FRESH = 1, FRESH_KEPT = 2 };
static void accept_pose(loop *L, int s, pose p, int64_t t_us, uint32_t kind, int checked);
static void undo_push(loop *L, int s);

void loop_config_default(loop_config *c)
{
    memset(c, 0, sizeof *c);
    c->trans_mm_s = 50; /* sim/script.h: SCRIPT_MM_PER_S_FULL */
    c->rot_deg_s = 45;  /* SCRIPT_DEG_PER_S_FULL */
    c->frame = LOOP_FRAME_CAMERA;
    c->dt_max_us = FNCLOCK_PAUSE_MAX_US;
    c->dt_first_us = 8000; /* the SpaceNavigator's report period */
    c->bisect_iters = 6;
    c->slide_iters = 2;
    c->max_tries = 12;
#ifdef NDEBUG
    c->check_invariant = 0;
#else
    c->check_invariant = 1;
#endif
    static const uint8_t map[] = {LOOP_ACT_NEXT,       LOOP_ACT_PREV,     LOOP_ACT_FIX,
                                  LOOP_ACT_COLLISION,  LOOP_ACT_TRANS_ONLY, LOOP_ACT_ROT_ONLY,
                                  LOOP_ACT_UNDO,       LOOP_ACT_REDO,     LOOP_ACT_SAVE,
                                  LOOP_ACT_FRAME,      LOOP_ACT_NONE,     LOOP_ACT_FIT,
                                  LOOP_ACT_PREVIEW,    LOOP_ACT_ACCEPT};
    memcpy(c->button_action, map, sizeof map);
}

void loop_config_actions_at(loop_config *c, int first)
{
    uint8_t acts[14];
    if (first <= 0 || first > 32 - (int)sizeof acts)
        return;
    memcpy(acts, c->button_action, sizeof acts);
    memset(c->button_action, 0, sizeof acts);
    memcpy(c->button_action + first, acts, sizeof acts);
}

/* Writes a zero into every page of [p, p+n) (calloc'd or scratch memory), so that the step never
 * takes a first-touch page fault there: the kernel maps fresh memory only when it is first
 * written. Volatile: the compiler must not drop stores of the zeros calloc already promises. */
void loop__prefault(void *p, size_t n)
{
    volatile unsigned char *b = p;
    for (size_t i = 0; i < n; i += 4096)
        b[i] = 0;
    if (n)
        b[n - 1] = 0;
}

/* Device axes -> world for the camera frame (loop.h: the camera in front of the patient). */
static const double CAMERA[3][3] = {{1, 0, 0}, {0, -1, 0}, {0, 0, -1}};

void loop_set_camera(loop *L, const double right[3], const double up[3], const double forward[3])
{
    /* Device x -> right, device y (towards the user) -> -forward, device z (down) -> -up. */
    unsigned s = atomic_load_explicit(&L->cam_seq, memory_order_relaxed);
    atomic_store_explicit(&L->cam_seq, s + 1, memory_order_relaxed);
    atomic_thread_fence(memory_order_release);
    for (int i = 0; i < 3; i++) {
        atomic_store_explicit(&L->cam[i * 3 + 0], right[i], memory_order_relaxed);
        atomic_store_explicit(&L->cam[i * 3 + 1], -forward[i], memory_order_relaxed);
        atomic_store_explicit(&L->cam[i * 3 + 2], -up[i], memory_order_relaxed);
    }
    atomic_store_explicit(&L->cam_seq, s + 2, memory_order_release);
}

/* The camera frame's matrix as loop_set_camera last left it (a consistent copy). */
void loop__camera(const loop *L, double R[3][3])
{
    for (;;) {
        unsigned s0 = atomic_load_explicit(&L->cam_seq, memory_order_acquire);
        for (int i = 0; i < 9; i++)
            R[i / 3][i % 3] = atomic_load_explicit(&L->cam[i], memory_order_relaxed);
        atomic_thread_fence(memory_order_acquire);
        if (!(s0 & 1) && atomic_load_explicit(&L->cam_seq, memory_order_relaxed) == s0)
            return;
    }
}

/* Largest distance from the centroid to a corner of the fragment's crop (home world mm). */
static double frag_radius(const frag *f)
{
    double r = 0;
    for (int c = 0; c < 8; c++) {
        double x[3], y[3];
        for (int a = 0; a < 3; a++)
            x[a] = ((c >> a & 1) ? f->dim[a] - 0.5 : -0.5) * f->spacing[a];
        pose_apply(&f->home, x, y);
        double d = sqrt((y[0] - f->centroid[0]) * (y[0] - f->centroid[0]) +
                        (y[1] - f->centroid[1]) * (y[1] - f->centroid[1]) +
                        (y[2] - f->centroid[2]) * (y[2] - f->centroid[2]));
        if (d > r)
            r = d;
    }
    return r;
}

loop *loop_new(const frag *frags, int n, const uint8_t *fixed, const loop_collider *col,
               const loop_config *cfg, struct journal *jr)
{
    if (!frags || n < 1 || n > LOOP_MAX_FRAGS || !col || !col->query) {
        fn_err_set(FN_EINVAL, "loop: need 1..%d fragments and a collider (got %d)", LOOP_MAX_FRAGS, n);
        return NULL;
    }
    loop *L = calloc(1, sizeof *L);
    size_t cb = col->cache_bytes ? col->cache_bytes : 1;
    unsigned char *caches = calloc((size_t)n + 1, cb); /* a slot per other fragment, and a scratch */
    if (!L || !caches) {
        free(L);
        free(caches);
        fn_err_set(FN_ENOMEM, "loop: out of memory for %d fragments", n);
        return NULL;
    }
    if (sem_init(&L->wake, 0, 0) != 0) {
        fn_err_set(FN_EINVAL, "loop: no semaphore for its wake-up: %s", strerror(errno));
        free(L);
        free(caches);
        return NULL;
    }
    loop__prefault(L, sizeof *L);
    loop__prefault(caches, ((size_t)n + 1) * cb);
    L->frags = frags;
    L->n = n;
    for (int i = 0; i < 9; i++)
        atomic_init(&L->cam[i], CAMERA[i / 3][i % 3]);
    atomic_init(&L->cam_seq, 0u);
    L->col = *col;
    L->cache_stride = cb;
    L->caches = caches;
    L->scratch = caches + (size_t)n * cb;
    for (int j = 0; j < n; j++)
        L->slot[j] = caches + (size_t)j * cb;
    if (cfg)
        L->cfg = *cfg;
    else
        loop_config_default(&L->cfg);
    L->jr = jr;
    L->collision_on = 1;
    L->device_present = 1;
    for (int i = 0; i < n; i++) {
        L->pose[i] = frags[i].pose;
        L->fixed[i] = fixed ? fixed[i] != 0 : 0;
        L->radius[i] = frag_radius(&frags[i]);
    }
    L->selected = 0;
    if (L->fixed[0])
        loop_action_do(L, LOOP_ACT_NEXT);
    atomic_init(&L->done, 0);
    atomic_init(&L->rt_cpu, -1);
    atomic_init(&L->running, 0);
    loop__stats_init(L);
    L->at_rest = 1;
    return L;
}

void loop_free(loop *L)
{
    if (!L)
        return;
    sem_destroy(&L->wake);
    free(L->caches);
    free(L);
}

/* ---- collision ---- */

/* The tolerance pair (s, j) is queried at: the larger of the two fragments' holds. */
static double pair_hold(const loop *L, int s, int j)
{
    return fmax(L->hold_mm[s], L->hold_mm[j]);
}

/* Does fragment s stand, or may it stand, inside another within a fit's tolerance? */
static int held(const loop *L, int s)
{
    for (int j = 0; j < L->n; j++)
        if (j != s && pair_hold(L, s, j) > 0)
            return 1;
    return 0;
}

/* Fragment s at p against every other, each pair at its hold (or at 0: strict). Returns 1
 * colliding, 0 free, or a negative FN_E*; *sep gets the smallest separation seen. fresh: FRESH
 * or FRESH_KEPT, a zeroed scratch cache instead of the pair's (always FRESH when strict: the
 * pair's cache serves the pair's hold); FRESH_KEPT: the scratch becomes the pair's cache after,
 * so that the next step at this pose finds the front of the search it made. */
static int collide_at(loop *L, int s, const pose *p, int fresh, int strict, double *sep)
{
    *sep = INFINITY;
    if (strict)
        fresh = FRESH;
    for (int j = 0; j < L->n; j++) {
        if (j == s)
            continue;
        unsigned char *cache = L->slot[j];
        if (fresh) {
            memset(L->scratch, 0, L->cache_stride);
            cache = L->scratch;
        } else if (L->cache_mover[j] != s + 1) { /* the slot held the pair of another mover */
            memset(cache, 0, L->cache_stride);
            L->cache_mover[j] = (uint8_t)(s + 1);
        }
        loop_contact c = {0, INFINITY, 0};
        int64_t t0 = fresh ? 0 : fnclock_now_ns();
        int rc = L->col.query(L->col.ctx, s, p, j, &L->pose[j], strict ? 0 : pair_hold(L, s, j), cache, &c);
        if (!fresh) { /* the invariant check's queries are not part of the loop's cost */
            loop__stats_query(L, fnclock_now_ns() - t0);
            L->st.searches += c.searched != 0;
        }
        if (rc < 0)
            return rc;
        if (fresh == FRESH_KEPT) {
            L->scratch = L->slot[j];
            L->slot[j] = cache;
            L->cache_mover[j] = (uint8_t)(s + 1);
        }
        if (c.separation_mm < *sep)
            *sep = c.separation_mm;
        if (c.collides)
            return 1;
    }
    return 0;
}

static int collide_all(loop *L, int s, const pose *p, int fresh, double *sep)
{
    return collide_at(L, s, p, fresh, 0, sep);
}

/* ---- motion ---- */

static double norm3(const double v[3])
{
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

/* start moved by the fraction f of (rotation r about pivot c, then translation d). */
static pose moved(const pose *start, const double c[3], const double d[3], const double r[3], double f)
{
    double rv[3] = {r[0] * f, r[1] * f, r[2] * f}, zero[3] = {0, 0, 0};
    pose rot = pose_from_rotvec(rv, zero), delta;
    double rc[3];
    pose_rotate(&rot, c, rc);
    delta = rot;
    for (int i = 0; i < 3; i++)
        delta.t[i] = c[i] - rc[i] + d[i] * f;
    return pose_compose(delta, *start);
}

/* A bound on how far any point of fragment s moves under the fraction f of (d, r) about c. */
static double motion_bound(const loop *L, int s, const double c[3], const double d[3],
                           const double r[3], double f)
{
    double cen[3];
    pose_apply(&L->pose[s], L->frags[s].centroid, cen);
    double arm[3] = {cen[0] - c[0], cen[1] - c[1], cen[2] - c[2]};
    return f * (norm3(d) + norm3(r) * (norm3(arm) + L->radius[s]));
}

/* Is the fraction f of the motion free? Uses the last separation as a shortcut when it proves the
 * move free; otherwise queries. Returns 1 free (with *cand and *sep), 0 colliding, or negative.
 * Every candidate counts against the step's budget (max_tries), proved free by the shortcut or
 * queried: the gap a cached query reports depends on the queries before it (obb.h), so were the
 * shortcut free of charge, where the budget runs out, and the pose the step ends at, would too;
 * this way the step's poses follow from the yes or no answers alone. */
static int try_move(loop *L, int s, const pose *start, double gap, const double c[3],
                    const double d[3], const double r[3], double f, pose *cand, double *sep)
{
    *cand = moved(start, c, d, r, f);
    if (L->tries >= L->cfg.max_tries)
        return 0; /* out of budget: treat as blocked, the step ends with what it has */
    L->tries++;
    double b = motion_bound(L, s, c, d, r, f);
    if (gap - b > SAFETY_MM) {
        *sep = gap - b;
        return 1;
    }
    int rc = collide_all(L, s, cand, 0, sep);
    return rc < 0 ? rc : !rc;
}

/* Advances *cur by as much of (d, r) as stays free: the whole of it, or the largest fraction found
 * by bisection down to 2^-iters. The smallest fraction is tried right after the whole, so a move
 * straight into a contact costs two queries. Moves the pivot c along. Returns the fraction taken. */
static double advance(loop *L, int s, pose *cur, double *gap, double c[3], const double d[3],
                      const double r[3], int iters, int *err)
{
    pose cand, best = *cur;
    double sep, best_sep = *gap, lo = 0, hi = 1, least = ldexp(1, -iters);
    int rc = try_move(L, s, cur, *gap, c, d, r, 1, &cand, &sep);
    if (rc == 1) {
        best = cand, best_sep = sep, lo = 1;
    } else if (rc == 0 && iters > 0) {
        rc = try_move(L, s, cur, *gap, c, d, r, least, &cand, &sep);
        if (rc == 1) {
            best = cand, best_sep = sep, lo = least;
            for (int k = 1; k < iters && rc >= 0; k++) {
                double mid = 0.5 * (lo + hi);
                rc = try_move(L, s, cur, *gap, c, d, r, mid, &cand, &sep);
                if (rc == 1)
                    best = cand, best_sep = sep, lo = mid;
                else
                    hi = mid;
            }
        }
    }
    if (rc < 0) {
        *err = rc;
        return 0;
    }
    *cur = best;
    *gap = best_sep;
    for (int i = 0; i < 3; i++)
        c[i] += d[i] * lo;
    return lo;
}

static int nonzero_axes(const double v[3])
{
    return (v[0] != 0) + (v[1] != 0) + (v[2] != 0);
}

/* Each world axis of the translation t, as far as it goes. Then, on a rough contact where
 * asperities block even the tangential part: the largest part left, other than the main push
 * (the largest axis of t), once more while backing away from the push by CLIMB of its length --
 * the fragment rides over the bumps instead of freezing. Returns 1 when anything moved. */
static int slide_axes(loop *L, int s, pose *cur, double *gap, double c[3], const double t[3],
                      int *err)
{
    static const double zero[3] = {0, 0, 0};
    double left[3] = {0, 0, 0};
    int moved_any = 0, push = 0, along = -1;
    for (int a = 0; a < 3 && !*err; a++) {
        double axis[3] = {0, 0, 0};
        axis[a] = t[a];
        if (fabs(t[a]) > fabs(t[push]))
            push = a;
        if (t[a] == 0)
            continue;
        double f = advance(L, s, cur, gap, c, axis, zero, L->cfg.slide_iters, err);
        moved_any |= f > 0;
        left[a] = t[a] * (1 - f);
    }
    for (int a = 0; a < 3; a++)
        if (a != push && left[a] != 0 && (along < 0 || fabs(left[a]) > fabs(left[along])))
            along = a;
    if (*err || along < 0)
        return moved_any;
    double climb[3] = {0, 0, 0};
    climb[along] = left[along];
    climb[push] = (t[push] > 0 ? -1 : 1) * CLIMB * fabs(left[along]);
    return advance(L, s, cur, gap, c, climb, zero, L->cfg.slide_iters, err) > 0 || moved_any;
}

/* The rest of a blocked step, in parts: the translation alone (when the step also turns), then
 * its world axes (slide_axes), then the rotation alone. Translation first: sliding along a
 * contact is mostly translation, and the step's query budget may not reach the last parts.
 * Returns 1 when any part moved. */
static int slide(loop *L, int s, pose *cur, double *gap, double c[3], const double d[3],
                 const double r[3], int *err)
{
    static const double zero[3] = {0, 0, 0};
    double t[3];
    memcpy(t, d, sizeof t);
    int moved_any = 0, turns = norm3(r) > 0;
    if (turns && norm3(t) > 0) {
        double f = advance(L, s, cur, gap, c, t, zero, L->cfg.slide_iters, err);
        for (int i = 0; i < 3; i++)
            t[i] *= 1 - f;
        moved_any |= f > 0;
    }
    if (!*err && nonzero_axes(t) >= 2)
        moved_any |= slide_axes(L, s, cur, gap, c, t, err);
    if (!*err && turns && (norm3(d) > 0))
        moved_any |= advance(L, s, cur, gap, c, zero, r, L->cfg.slide_iters, err) > 0;
    return moved_any;
}

/* Fragment s at p: its overlap with every other (0 without the collider's overlap measure). */
static int overlap_all(loop *L, int s, const pose *p, double *sum)
{
    *sum = 0;
    for (int j = 0; j < L->n && L->col.overlap; j++) {
        double mm3 = 0;
        int rc = j == s ? 0 : L->col.overlap(L->col.ctx, s, p, j, &L->pose[j], &mm3);
        if (rc < 0)
            return rc;
        L->st.overlaps += j != s;
        *sum += mm3;
    }
    return 0;
}

/* Queries fragment s where it stands: the gap, or that it interpenetrates and how deep. fresh
 * (FRESH_KEPT): from scratch (not in the statistics), whose bound on the gap is the collider's
 * best for this pose, its caches kept as the pairs' for the next step; the pair caches' may be
 * carried over from earlier poses. A held fragment is
 * also queried at 0: inside there but free at its hold, it is shown penetrating (in_collision)
 * while its gap at the hold stays valid, so that it moves as a free one does; free at 0, its
 * hold ends. */
static int refresh_contact(loop *L, int s, int fresh)
{
    double sep, sep0;
    int rc = collide_all(L, s, &L->pose[s], fresh, &sep);
    if (rc < 0)
        return rc;
    int inside = rc;
    if (rc == 0 && held(L, s)) {
        inside = collide_at(L, s, &L->pose[s], 1, 1, &sep0);
        if (inside < 0)
            return inside;
        if (!inside)
            L->hold_mm[s] = 0;
    }
    L->in_collision = inside;
    L->gap_valid = !rc;
    L->gap_fresh = !rc && fresh;
    L->gap = rc ? 0 : sep;
    L->pen = rc ? fmin(sep, 0) : inside ? fmin(sep0, 0) : 0;
    return rc ? overlap_all(L, s, &L->pose[s], &L->overlap) : 0;
}

/* Fragment s interpenetrates another (checking was off). The whole move is taken if it frees the
 * fragment or does not deepen the overlap; otherwise it is refused. */
static int escape(loop *L, int s, const pose *cand, int64_t t_us)
{
    double sep, ov = 0;
    int rc = collide_all(L, s, cand, 0, &sep);
    if (rc == 1) {
        int orc = overlap_all(L, s, cand, &ov);
        rc = orc < 0 ? orc : rc;
    }
    if (rc < 0)
        return rc;
    if (rc == 0) {
        accept_pose(L, s, *cand, t_us, JOURNAL_MOVE, LOOP_CHECKED);
        L->in_collision = 0;
        L->gap_valid = 1;
        L->gap = sep;
        return LOOP_ACCEPTED;
    }
    if (L->col.overlap ? ov > L->overlap + OVERLAP_EPS_MM3 : sep < L->pen)
        return LOOP_REFUSED;
    accept_pose(L, s, *cand, t_us, JOURNAL_MOVE, LOOP_ESCAPING);
    L->pen = fmin(sep, 0);
    L->overlap = ov;
    return LOOP_ACCEPTED;
}

/* Moves the selected fragment by (d, r) about pivot c under collision checking. */
static int move(loop *L, int s, double c[3], const double d[3], const double r[3], int64_t t_us)
{
    pose start = L->pose[s], cur = start;
    if (!L->collision_on) {
        accept_pose(L, s, moved(&start, c, d, r, 1), t_us, JOURNAL_MOVE, LOOP_UNCHECKED);
        return LOOP_ACCEPTED;
    }
    if (!L->gap_valid && !L->in_collision) {
        int rc = refresh_contact(L, s, 0);
        if (rc < 0)
            return rc;
    }
    if (L->in_collision && !L->gap_valid) {
        pose cand = moved(&start, c, d, r, 1);
        return escape(L, s, &cand, t_us);
    }
    double gap = L->gap;
    int err = 0;
    double f = advance(L, s, &cur, &gap, c, d, r, L->cfg.bisect_iters, &err);
    if (err)
        return err;
    if (f == 1) {
        accept_pose(L, s, cur, t_us, JOURNAL_MOVE, LOOP_CHECKED);
        L->gap = gap;
        return LOOP_ACCEPTED;
    }
    double rd[3], rr[3];
    for (int i = 0; i < 3; i++)
        rd[i] = d[i] * (1 - f), rr[i] = r[i] * (1 - f);
    int slid = slide(L, s, &cur, &gap, c, rd, rr, &err);
    if (err)
        return err;
    if (!slid && f == 0)
        return LOOP_REFUSED;
    accept_pose(L, s, cur, t_us, JOURNAL_MOVE, LOOP_CHECKED);
    L->gap = gap;
    return slid ? LOOP_SLID : LOOP_LIMITED;
}

static void accept_pose(loop *L, int s, pose p, int64_t t_us, uint32_t kind, int checked)
{
    if (kind == JOURNAL_MOVE && !L->gesture_saved) {
        /* The first pose a gesture changes: undo comes back here. */
        undo_push(L, s);
        L->gesture_saved = 1;
        kind = JOURNAL_START;
    }
    L->pose[s] = p;
    L->gap_fresh = 0;
    L->verify_frag = s;
    /* "fitted" holds until the fragment moves, or another that may stand inside it (held) or
     * that it stood inside (a plan loaded so marks both of a pair: loop_tolerate) */
    if (checked != LOOP_TOLERATED)
        for (int j = 0, was = L->tolerated[s]; j < L->n; j++)
            if (L->tolerated[j] && (was || L->hold_mm[s] > 0 || L->hold_mm[j] > 0)) {
                L->tolerated[j] = 0;
                L->fit_ended_by[j] = (uint8_t)(s + 1);
            }
    L->tolerated[s] = checked == LOOP_TOLERATED;
    if (L->tolerated[s])
        L->fit_ended_by[s] = 0;
    if (checked == LOOP_UNCHECKED || checked == LOOP_ESCAPING)
        L->hold_mm[s] = 0; /* not checked at the hold: it no longer bounds how deep it is */
    if (checked != LOOP_CHECKED)
        L->gap_valid = 0;
    loop__stats_pose(L, s, &p);
    if (L->jr && journal_append(L->jr, kind, s, t_us, &p, loop__now_us(L)) < 0)
        L->st.journal_errors++;
    if (checked == LOOP_UNCHECKED)
        L->st.unchecked++;
    else if (checked == LOOP_ESCAPING)
        L->st.escaping++;
    else if (checked == LOOP_TOLERATED)
        L->st.tolerated++;
    else if (L->cfg.check_invariant)
        L->verify = 1;
}

/* The invariant, checked from scratch (fresh caches, no separation shortcut) after the step's
 * latency has been taken, so checking does not distort the measurement. */
static void verify(loop *L)
{
    if (!L->verify)
        return;
    L->verify = 0;
    int s = L->verify_frag;
    double sep;
    if (collide_all(L, s, &L->pose[s], 1, &sep) == 1)
        L->st.collisions_in_accepted++;
}

/* Device motion -> world displacement and rotation vector over dt. */
static void twist(const loop *L, int s, const float m[6], double dt, double d[3], double r[3])
{
    double v[3], w[3], R[3][3];
    for (int i = 0; i < 3; i++) {
        v[i] = L->rot_only ? 0 : m[i] * L->cfg.trans_mm_s * dt;
        w[i] = L->trans_only ? 0 : m[3 + i] * L->cfg.rot_deg_s * (M_PI / 180) * dt;
    }
    if (L->cfg.frame == LOOP_FRAME_WORLD) {
        memcpy(d, v, sizeof v);
        memcpy(r, w, sizeof w);
        return;
    }
    if (L->cfg.frame == LOOP_FRAME_FRAGMENT) {
        pose local = pose_compose(L->pose[s], L->frags[s].home);
        pose_to_matrix(&local, R);
    } else {
        loop__camera(L, R);
    }
    for (int i = 0; i < 3; i++) {
        d[i] = R[i][0] * v[0] + R[i][1] * v[1] + R[i][2] * v[2];
        r[i] = R[i][0] * w[0] + R[i][1] * w[1] + R[i][2] * w[2];
    }
}

/* The device is at rest (or the selection changed): the next move starts a new undo step. */
static void gesture_end(loop *L)
{
    L->gesture_saved = 0;
}

static void pivot_world(const loop *L, int s, double c[3])
{
    pose_apply(&L->pose[s], L->have_pivot ? L->pivot_home : L->frags[s].centroid, c);
}


static int step(loop *L, const loop_event *ev)
{
    /* A report's motion acts over the time since the previous report; the first one (at start,
     * after a replug) over one nominal report period. */
    int64_t gap = L->have_last_t ? ev->t_us - L->last_t : L->cfg.dt_first_us;
    double dt = (double)(gap < 0 ? 0 : gap > L->cfg.dt_max_us ? L->cfg.dt_max_us : gap) * 1e-6;
    L->last_t = ev->t_us;
    L->have_last_t = 1;
    int s = L->selected;
    double d[3], r[3];
    twist(L, s, ev->motion, dt, d, r);
    if (norm3(d) == 0 && norm3(r) == 0) {
        int still = 1;
        for (int i = 0; i < 6; i++)
            still &= ev->motion[i] == 0;
        if (still)
            gesture_end(L);
        L->at_rest = still;
        return LOOP_IDLE;
    }
    L->at_rest = 0;
    if (L->fixed[s])
        return LOOP_IDLE;
    double c[3];
    pivot_world(L, s, c);
    L->tries = 0;
    int out = move(L, s, c, d, r, ev->t_us);
    if (out > 0)
        loop__stats_outcome(L, out);
    return out;
}

/* The application saved the poses in L->saved: the journal holds only what is newer. */
static void journal_saved(loop *L)
{
    if (!L->jr || !L->saved)
        return;
    int bad = journal_truncate(L->jr) < 0;
    for (int i = 0; i < L->n; i++)
        if (memcmp(&L->pose[i], &L->saved[i], sizeof(pose)) != 0)
            bad |= journal_append(L->jr, JOURNAL_MOVE, i, L->last_t, &L->pose[i], loop__now_us(L)) < 0;
    L->st.journal_errors += (uint64_t)bad;
}

/* After an event: the scene shows the contact state of the pose it shows. The selected fragment
 * is queried where it stands, from scratch, when its gap is unknown (new selection, undo) or once
 * the device is at rest after a move: while it moves, the gap is carried over by the separation
 * shortcut and the pair caches, a lower bound that can shrink with every move, even away from
 * the contact. */
static int settle(loop *L)
{
    if (!L->collision_on || (L->in_collision && !L->gap_valid) ||
        (L->gap_valid && (L->gap_fresh || !L->at_rest)))
        return 0;
    return refresh_contact(L, L->selected, FRESH_KEPT);
}

/* Fragment s at p, holding hold_mm there: free at its hold (1 inside at 0 but free at the hold:
 * *how = LOOP_TOLERATED, else LOOP_CHECKED), 0 colliding, or negative. The hold is set on
 * success, kept as it was otherwise. */
static int free_within(loop *L, int s, const pose *p, double hold_mm, int *how)
{
    double was = L->hold_mm[s], sep;
    L->hold_mm[s] = hold_mm;
    int rc = collide_all(L, s, p, 0, &sep), inside = 0;
    if (rc == 0 && held(L, s))
        inside = collide_at(L, s, p, 1, 1, &sep);
    if (rc != 0 || inside < 0) {
        L->hold_mm[s] = was;
        return rc < 0 ? rc : inside < 0 ? inside : 0;
    }
    if (!inside)
        L->hold_mm[s] = 0;
    *how = inside ? LOOP_TOLERATED : LOOP_CHECKED;
    return 1;
}

/* A proposed pose for fragment i: one undo step of its own, taken whole or refused. */
static int propose(loop *L, int i, const pose *p, double tolerance_mm)
{
    int out = LOOP_REFUSED;
    if (i >= 0 && i < L->n && !L->fixed[i]) {
        int how = LOOP_UNCHECKED, rc = 1;
        if (L->collision_on)
            rc = free_within(L, i, p, tolerance_mm > 0 ? tolerance_mm : 0, &how);
        if (rc < 0)
            return rc;
        if (rc == 1) {
            gesture_end(L);
            accept_pose(L, i, *p, L->last_t, JOURNAL_MOVE, how);
            gesture_end(L);
            L->gap_valid = L->in_collision = 0; /* the selected one's contact may have changed */
            out = LOOP_ACCEPTED;
        }
    }
    L->proposals++;
    L->proposal_result[L->proposals % LOOP_PROPOSALS_KEPT] = (uint8_t)out;
    return out;
}

/* A control from an event (a key or a button): done and remembered for the scene. */
static int act(loop *L, loop_action a)
{
    int rc = loop_action_do(L, a);
    L->actions++;
    L->last_action = (int)a;
    L->last_action_result = rc;
    return rc;
}

int loop_feed(loop *L, const loop_event *ev)
{
    L->st.events++;
    int out = LOOP_IDLE;
    switch (ev->kind) {
    case LOOP_EV_MOTION: {
        L->device_present = 1;
        uint32_t pressed = ev->buttons & ~L->buttons;
        L->buttons = ev->buttons;
        for (int b = 0; b < 32; b++)
            if (pressed >> b & 1 && L->cfg.button_action[b])
                act(L, (loop_action)L->cfg.button_action[b]);
        out = step(L, ev);
        break;
    }
    case LOOP_EV_ACTION:
        out = act(L, (loop_action)ev->action);
        break;
    case LOOP_EV_SAVED:
        journal_saved(L);
        break;
    case LOOP_EV_POSE:
        out = propose(L, ev->frag, &ev->pose, ev->tolerance_mm);
        break;
    case LOOP_EV_UNPLUG:
    case LOOP_EV_REPLUG:
        /* The pose stays; the next report after a replug starts a fresh time base. */
        L->device_present = ev->kind == LOOP_EV_REPLUG;
        L->have_last_t = 0;
        gesture_end(L);
        L->buttons = 0;
        L->at_rest = 1;
        break;
    default:
        break;
    }
    if (ev->kind == LOOP_EV_MOTION && ev->arrival_us > 0) {
        loop__stats_latency(L, loop__now_us(L) - ev->arrival_us);
        L->st.last_arrival_us = ev->arrival_us;
    }
    verify(L);
    if (out > 0)
        L->last_outcome = (loop_outcome)out;
    int rc = out < 0 ? 0 : settle(L);
    return rc < 0 ? rc : out;
}

/* ---- controls ---- */

static void select_next(loop *L, int dir)
{
    int any_free = 0;
    for (int i = 0; i < L->n; i++)
        any_free |= !L->fixed[i];
    int s = L->selected;
    for (int k = 0; k < L->n; k++) {
        s = (s + dir + L->n) % L->n;
        if (!L->fixed[s] || !any_free)
            break;
    }
    if (s != L->selected) {
        L->selected = s;
        L->have_pivot = 0;
        L->gap_valid = L->in_collision = 0;
        gesture_end(L);
    }
}

/* Restores one saved pose, unless it collides now at the tolerance it held there. Returns 1
 * when restored. */
static int restore(loop *L, const loop_undo *u, uint32_t kind)
{
    int how = LOOP_UNCHECKED;
    if (L->collision_on) {
        int rc = free_within(L, u->frag, &u->p, u->hold_mm, &how);
        if (rc != 1)
            return rc;
    }
    accept_pose(L, u->frag, u->p, L->last_t, kind, how == LOOP_UNCHECKED ? how : LOOP_CHECKED);
    L->tolerated[u->frag] = (uint8_t)(u->tolerated && how == LOOP_TOLERATED);
    if (L->tolerated[u->frag])
        L->fit_ended_by[u->frag] = 0;
    L->gap_valid = 0;
    L->in_collision = 0;
    gesture_end(L);
    return 1;
}

/* Drops the top of one undo/redo stack and pushes `back` (the pose being left) on the other. */
static void shift(int *nfrom, loop_undo *to, int *nto, loop_undo back)
{
    if (*nfrom > 0)
        (*nfrom)--;
    if (*nto == LOOP_UNDO_MAX) {
        memmove(to, to + 1, (LOOP_UNDO_MAX - 1) * sizeof *to);
        (*nto)--;
    }
    to[(*nto)++] = back;
}

/* Fixes or frees fragment s, journaled (JOURNAL_FIX) like a pose. */
static void set_fixed(loop *L, int s, int fixed)
{
    L->fixed[s] = (uint8_t)(fixed != 0);
    if (L->jr && journal_append_fix(L->jr, s, L->last_t, &L->pose[s], fixed, loop__now_us(L)) < 0)
        L->st.journal_errors++;
}

/* An undo step that gives fragment s its fixed flag back. */
static void push_fix(loop *L, int s)
{
    undo_push(L, s);
    L->undo[L->nundo - 1].fix = 1 + L->fixed[s];
}

static int undo_redo(loop *L, int redo)
{
    loop_undo *from = redo ? L->redo : L->undo, *to = redo ? L->undo : L->redo;
    int *nfrom = redo ? &L->nredo : &L->nundo, *nto = redo ? &L->nundo : &L->nredo;
    if (*nfrom == 0)
        return LOOP_IDLE;
    loop_undo u = from[*nfrom - 1];
    if (u.fix) {
        loop_undo back = {u.frag, L->pose[u.frag], 1 + L->fixed[u.frag], 0, 0};
        set_fixed(L, u.frag, u.fix - 1);
        shift(nfrom, to, nto, back);
        return LOOP_ACCEPTED;
    }
    loop_undo back = {u.frag, L->pose[u.frag], 0, L->hold_mm[u.frag], L->tolerated[u.frag]};
    int rc = restore(L, &u, redo ? JOURNAL_REDO : JOURNAL_UNDO);
    verify(L);
    if (rc <= 0)
        return rc < 0 ? rc : LOOP_REFUSED;
    shift(nfrom, to, nto, back);
    return LOOP_ACCEPTED;
}

static void undo_push(loop *L, int s)
{
    if (L->nundo == LOOP_UNDO_MAX) {
        memmove(L->undo, L->undo + 1, (LOOP_UNDO_MAX - 1) * sizeof *L->undo);
        L->nundo--;
    }
    L->undo[L->nundo++] = (loop_undo){s, L->pose[s], 0, L->hold_mm[s], L->tolerated[s]};
    L->nredo = 0;
}

int loop_action_do(loop *L, loop_action a)
{
    switch (a) {
    case LOOP_ACT_NEXT:
    case LOOP_ACT_PREV:
        select_next(L, a == LOOP_ACT_NEXT ? 1 : -1);
        return LOOP_IDLE;
    case LOOP_ACT_FIX:
        gesture_end(L);
        push_fix(L, L->selected);
        set_fixed(L, L->selected, !L->fixed[L->selected]);
        return LOOP_IDLE;
    case LOOP_ACT_COLLISION: {
        /* Back on: look at once, so a fragment left inside another shows the warning now. */
        L->collision_on = !L->collision_on;
        L->gap_valid = L->in_collision = 0;
        int rc = L->collision_on ? refresh_contact(L, L->selected, 0) : 0;
        return rc < 0 ? rc : LOOP_IDLE;
    }
    case LOOP_ACT_TRANS_ONLY:
        L->trans_only = !L->trans_only;
        L->rot_only = 0;
        return LOOP_IDLE;
    case LOOP_ACT_ROT_ONLY:
        L->rot_only = !L->rot_only;
        L->trans_only = 0;
        return LOOP_IDLE;
    case LOOP_ACT_UNDO:
    case LOOP_ACT_REDO:
        return undo_redo(L, a == LOOP_ACT_REDO);
    case LOOP_ACT_SAVE:
        L->save_requests++;
        return LOOP_IDLE;
    case LOOP_ACT_FIT:
        L->fit_requests++;
        return LOOP_IDLE;
    case LOOP_ACT_PREVIEW:
        L->preview_requests++;
        return LOOP_IDLE;
    case LOOP_ACT_ACCEPT:
        L->accept_requests++;
        return LOOP_IDLE;
    case LOOP_ACT_FRAME:
        L->cfg.frame = (loop_frame)((L->cfg.frame + 1) % 3);
        return LOOP_IDLE;
    case LOOP_ACT_HELP: /* the application's view shows the keys: only remembered (act) */
    default:
        return LOOP_IDLE;
    }
}

int loop_recover(loop *L, const journal_rec *recs, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        const journal_rec *r = &recs[i];
        if (r->frag < 0 || r->frag >= L->n)
            return fn_err_set(FN_EFORMAT, "journal record %zu (seq %llu): fragment %d, the case has %d",
                              i + 1, (unsigned long long)r->seq, r->frag, L->n);
        loop_undo before = {r->frag, L->pose[r->frag], 0, 0, 0};
        if (r->kind == JOURNAL_FIX) {
            push_fix(L, r->frag);
            L->fixed[r->frag] = (uint8_t)r->flag;
        } else if (r->kind == JOURNAL_START)
            undo_push(L, r->frag);
        else if (r->kind == JOURNAL_UNDO)
            shift(&L->nundo, L->redo, &L->nredo, before);
        else if (r->kind == JOURNAL_REDO)
            shift(&L->nredo, L->undo, &L->nundo, before);
        L->pose[r->frag] = r->p;
    }
    L->gap_valid = L->in_collision = 0;
    gesture_end(L);
    return 0;
}

int loop_measure(loop *L)
{
    int rc = settle(L);
    loop_publish(L);
    return rc;
}

void loop_set_pivot(loop *L, const double world[3])
{
    L->have_pivot = world != NULL;
    if (world) {
        pose inv = pose_inverse(L->pose[L->selected]);
        pose_apply(&inv, world, L->pivot_home);
    }
}

void loop_set_saved(loop *L, const pose *saved)
{
    L->saved = saved;
}

void loop_set_pose(loop *L, int i, pose p)
{
    if (i >= 0 && i < L->n) {
        L->pose[i] = p;
        L->gap_valid = L->in_collision = 0;
        L->tolerated[i] = 0;
        L->fit_ended_by[i] = 0;
        L->hold_mm[i] = 0;
    }
}

void loop_tolerate(loop *L, int i, double tolerance_mm)
{
    if (i >= 0 && i < L->n && tolerance_mm > 0) {
        L->tolerated[i] = 1;
        L->fit_ended_by[i] = 0;
        L->hold_mm[i] = tolerance_mm;
        L->gap_valid = L->in_collision = 0; /* measured at the hold from now on */
    }
}

pose loop_pose(const loop *L, int i)
{
    return L->pose[i];
}

int loop_selected(const loop *L)
{
    return L->selected;
}

int loop_fixed(const loop *L, int i)
{
    return L->fixed[i];
}
