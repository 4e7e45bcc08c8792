/* session: opening a case for steering (journal reconciled, collider, loop), accessors, saves. */
#include "session_impl.h"
#include "session_test.h"

#include "case_journal.h"
#include "err.h"
#include "obb.h"
#include "reduce.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

size_t session_journal_pending(const char *dir)
{
    return case_journal_pending(dir);
}

/* The journal reconciled with the case (case_journal_check); *recs, *n: what --recover applies. */
static int check_journal(session *s, unsigned flags, const char *cmd, journal_rec **recs, size_t *n)
{
    const char *dir = s->dir;
    if (flags & SESSION_DISCARD) {
        char path[4200]; /* removed, not parsed: a damaged journal must not block a fresh start */
        snprintf(path, sizeof path, "%s/journal", dir);
        if (unlink(path) != 0 && errno != ENOENT)
            return fn_err_set(FN_EIO, "%s: cannot remove: %s", path, strerror(errno));
        return 0;
    }
    int rc = case_journal_check(s->c, recs, n);
    if (rc == 1 && (flags & SESSION_RESUME))
        return fn_err_set(FN_EMISMATCH, "%s/journal does not extend this case.json, so --recover "
                                        "has nothing to apply (it was kept aside, see above); run "
                                        "again without --recover to start from case.json", dir);
    if (rc >= 0 && *n && !(flags & SESSION_RESUME))
        return fn_err_set(FN_EMISMATCH,
                          "%s/journal holds %zu poses not saved in case.json (an interrupted session): "
                          "run `fracnav %s` with --recover to continue from them, or --discard-journal "
                          "to start from case.json",
                          dir, *n, cmd ? cmd : "navigate");
    return rc < 0 ? rc : 0;
}

/* The parts every session has: rings, the wake-up, the collider over s->frags. */
static int build_common(session *s)
{
    atomic_init(&s->stop, 0);
    atomic_init(&s->running, 0);
    atomic_init(&s->seen_proposals, 0);
    atomic_init(&s->ev_stop, 0);
    atomic_init(&s->kinds, ~0u & ~(unsigned)SESSION_EV_SCENE);
    if (sem_init(&s->wake, 0, 0) != 0)
        return fn_err_set(FN_EINVAL, "session: no semaphore for its wake-up: %s", strerror(errno));
    if (sem_init(&s->ev_ready, 0, 0) != 0) {
        sem_destroy(&s->wake);
        return fn_err_set(FN_EINVAL, "session: no semaphore for its events: %s", strerror(errno));
    }
    pthread_mutex_init(&s->push_mu, NULL);
    pthread_mutex_init(&s->frag_mu, NULL);
    if (sem_init(&s->prev_wake, 0, 0) != 0) {
        sem_destroy(&s->wake);
        sem_destroy(&s->ev_ready);
        return fn_err_set(FN_EINVAL, "session: no semaphore for its preview: %s", strerror(errno));
    }
    pthread_mutex_init(&s->ev_mu, NULL);
    pthread_mutex_init(&s->fit_mu, NULL);
    pthread_mutex_init(&s->prev_mu, NULL);
    s->fit.frag = -1;
    s->prev.frag = -1;
    s->built = 1;
    s->in = ring_new(sizeof(loop_event), 1024);
    s->ctl = ring_new(sizeof(loop_event), 64);
    if (!s->in || !s->ctl)
        return FN_ENOMEM;
    obb_params op = {s->tau[0], s->tau[1]};
    s->obb = loop_obb_new(s->frags, s->nfrag, &op, NULL);
    return s->obb ? 0 : FN_EFORMAT;
}

/* The loop over the fragments, wired to the session's rings and saved poses. */
static int build_loop(session *s, const uint8_t *fixed, const loop_config *cfg)
{
    loop_collider col = loop_obb_collider(s->obb);
    s->L = loop_new(s->frags, s->nfrag, fixed, &col, cfg, s->jr);
    if (!s->L)
        return FN_ENOMEM;
    loop_set_controls(s->L, s->ctl);
    loop_set_saved(s->L, s->saved);
    return 0;
}

static session *alloc_session(void)
{
    session *s = calloc(1, sizeof *s);
    if (!s)
        fn_err_set(FN_ENOMEM, "out of memory for a session");
    return s;
}

/* The fragments that stand where a fit left them are inside the others by no more than its
 * tolerance: the loop says so rather than warn. They are those at fracnav reduce's end pose (its
 * record, not moved since by the journal), and, when the journal moved nothing, the pairs a
 * session saved as overlapping within a fit's tolerance ("penetrating", within_fit_tolerance). */
static void tolerate_reduced(session *s)
{
    json_t *red = json_object_get(s->c->extra, "reduction");
    reduce_opts o;
    reduce_defaults(&o);
    if (json_is_number(json_object_get(red, "tolerance_mm")))
        o.tolerance_mm = json_number_value(json_object_get(red, "tolerance_mm"));
    const frag *all[LOOP_MAX_FRAGS];
    for (int i = 0; i < s->nfrag; i++)
        all[i] = &s->frags[i];
    double tol = reduce_tolerance(&o, all, s->nfrag);
    json_t *pen = json_object_get(s->c->extra, "penetrating"), *e;
    size_t n;
    json_array_foreach(pen, n, e) {
        if (s->resumed || !json_is_true(json_object_get(e, "within_fit_tolerance")))
            continue;
        json_t *ids = json_object_get(e, "fragments");
        for (size_t a = 0; a < 2; a++)
            loop_tolerate(s->L, case_find(s->c, (int)json_integer_value(json_array_get(ids, a))), tol);
    }
    json_t *frs = json_object_get(red, "fragments"), *fr;
    size_t k;
    json_array_foreach(frs, k, fr) {
        int i = case_find(s->c, (int)json_integer_value(json_object_get(fr, "id")));
        json_t *end = json_object_get(fr, "end"), *q = json_object_get(end, "q"), *t = json_object_get(end, "t");
        if (i < 0 || json_array_size(q) != 4 || json_array_size(t) != 3)
            continue;
        pose now = loop_pose(s->L, i);
        double d = 0;
        for (int a = 0; a < 4; a++)
            d = fmax(d, fabs(json_number_value(json_array_get(q, (size_t)a)) - now.q[a]));
        for (int a = 0; a < 3; a++)
            d = fmax(d, fabs(json_number_value(json_array_get(t, (size_t)a)) - now.t[a]));
        if (d < 1e-9)
            loop_tolerate(s->L, i, tol);
    }
}

/* Everything after the case is loaded; s->c set. */
static int open_case(session *s, const session_params *p)
{
    journal_rec *recs = NULL;
    size_t pending = 0;
    planning_case *c = s->c;
    int rc = check_journal(s, p->flags, p->command, &recs, &pending);
    if (rc == 0 && c->nfrag > LOOP_MAX_FRAGS)
        rc = fn_err_set(FN_EINVAL, "%s: %d fragments, the loop steers at most %d", s->dir, c->nfrag,
                        LOOP_MAX_FRAGS);
    if (rc == 0 && c->nfrag < 1) /* one is enough: the window's seed mode separates it */
        rc = fn_err_set(FN_EINVAL, "%s: no fragment to steer", s->dir);
    if (rc == 0 && p->prepare)
        rc = p->prepare(p->prepare_ctx, c);
    s->frags = c->frag;
    s->nfrag = c->nfrag;
    s->tau[0] = c->tau_min;
    s->tau[1] = c->tau_max;
    s->fit_gap_mm = p->fit_gap_mm;
    if (rc == 0)
        rc = build_common(s);
    if (rc == 0 && (p->flags & SESSION_JOURNAL)) {
        journal_bind b;
        case_journal_bind(c, &b);
        if (!(s->jr = journal_open(s->dir, &b)))
            rc = FN_EIO;
    }
    if (rc == 0) {
        uint8_t fixed[LOOP_MAX_FRAGS] = {0};
        for (int i = 0; i < c->nfrag; i++)
            fixed[i] = (uint8_t)case_is_fixed(c, i);
        rc = build_loop(s, fixed, &p->cfg);
    }
    if (rc == 0 && pending) {
        rc = loop_recover(s->L, recs, pending);
        s->resumed = rc == 0 ? pending : 0;
        if (rc < 0)
            fn_err_wrap(rc, "%s/journal", s->dir);
    }
    free(recs);
    if (rc == 0)
        tolerate_reduced(s);
    return rc == 0 ? loop_measure(s->L) : rc;
}

session *session_open(const char *dir, const session_params *p)
{
    session *s = alloc_session();
    if (!s)
        return NULL;
    snprintf(s->dir, sizeof s->dir, "%s", dir);
    s->c = case_load(dir);
    if (!s->c || open_case(s, p) < 0) {
        session__free(s);
        return NULL;
    }
    return s;
}

session *session_open_fragments(const frag *frags, int n, const uint8_t *fixed, const double tau[2],
                                const loop_config *cfg)
{
    if (n < 1 || n > LOOP_MAX_FRAGS) {
        fn_err_set(FN_EINVAL, "%d fragments: a session steers 1..%d", n, LOOP_MAX_FRAGS);
        return NULL;
    }
    session *s = alloc_session();
    if (!s)
        return NULL;
    s->frags = frags;
    s->nfrag = n;
    s->tau[0] = tau[0];
    s->tau[1] = tau[1];
    int rc = build_common(s);
    if (rc == 0)
        rc = build_loop(s, fixed, cfg);
    if (rc == 0)
        rc = loop_measure(s->L);
    if (rc < 0) {
        session__free(s);
        return NULL;
    }
    return s;
}

void session__free(session *s)
{
    loop_free(s->L);
    if (s->jr)
        journal_close(s->jr);
    loop_obb_free(s->obb);
    json_decref(s->penetrating);
    case_free(s->c);
    ring_free(s->in);
    ring_free(s->ctl);
    if (s->built) {
        pthread_mutex_destroy(&s->push_mu);
        pthread_mutex_destroy(&s->frag_mu);
        pthread_mutex_destroy(&s->fit_mu);
        pthread_mutex_destroy(&s->ev_mu);
        pthread_mutex_destroy(&s->prev_mu);
        sem_destroy(&s->wake);
        sem_destroy(&s->ev_ready);
        sem_destroy(&s->prev_wake);
    }
    free(s);
}

void session_config_default(loop_config *cfg)
{
    loop_config_default(cfg);
}

int session_frame_parse(const char *name, loop_frame *out)
{
    static const char *names[] = {[LOOP_FRAME_CAMERA] = "camera", [LOOP_FRAME_WORLD] = "world",
                                  [LOOP_FRAME_FRAGMENT] = "fragment"};
    for (int f = 0; f < (int)(sizeof names / sizeof names[0]); f++)
        if (names[f] && !strcmp(name, names[f])) {
            *out = (loop_frame)f;
            return 0;
        }
    return fn_err_set(FN_EINVAL, "--frame %s: use camera, world or fragment", name);
}

int session_calib_setup(calib *cal, const char *config, int named_only, const char *who)
{
    return calib_setup(cal, config, named_only ? CALIB_NAMED_ONLY : 0, stderr, who, NULL, 0);
}

caselock *session_lock_case(const char *command, const char *dir, int exclusive, int wait)
{
    caselock *l = caselock_take(dir, exclusive, wait);
    if (!l)
        fprintf(stderr, "fracnav %s: %s\n", command, fn_err_msg());
    return l;
}

void session_unlock(caselock *lock)
{
    caselock_release(lock);
}

loop *session__loop(session *s)
{
    return s->L;
}

void session_set_pivot(session *s, const double world[3])
{
    loop_set_pivot(s->L, world);
}

void session_stats(session *s, loop_stats *out)
{
    loop_get_stats(s->L, out);
}

int session_tolerate(session *s, int i, double tolerance_mm)
{
    loop_tolerate(s->L, i, tolerance_mm);
    return loop_measure(s->L);
}

pose session_pose(const session *s, int i)
{
    return loop_pose(s->L, i);
}

int session_selected(const session *s)
{
    return loop_selected(s->L);
}

planning_case *session_case(session *s)
{
    return s->c;
}

const frag *session_frags(const session *s)
{
    return s->frags;
}

int session_nfrag(const session *s)
{
    return s->nfrag;
}

size_t session_resumed(const session *s)
{
    return s->resumed;
}

const char *session_dir(const session *s)
{
    return s->dir;
}

json_t *session_penetrating(const session *s)
{
    return s->penetrating;
}

static void rebind(session *s)
{
    if (!s->jr)
        return;
    journal_bind b;
    case_journal_bind(s->c, &b);
    journal_rebind(s->jr, &b);
}

/* Why fragments a and b (indices) overlap, not where a fit left them, into why: the loop refuses
 * every move into another fragment while it checks, except within a fit's tolerance, which a
 * fragment holds after the fit until it rests free. */
static void penetration_why(const planning_case *c, const loop_scene *sc, int a, int b, char *why, size_t cap)
{
    if (sc->held_frag[a] || sc->held_frag[b]) {
        /* the fragment whose move ended the pair's "fitted" mark (else the one holding) */
        int by = (sc->fit_ended_by[b] ? sc->fit_ended_by[b] : sc->fit_ended_by[a]) - 1;
        if (by < 0)
            by = sc->held_frag[b] ? b : a;
        snprintf(why, cap, "fragment %d moved after a fit left them so: inside within the fit's "
                 "tolerance, but no longer where the fit left them", c->frag[by].id);
    } else
        snprintf(why, cap, "%s", sc->stats.unchecked ? "moved while collision checking was off"
                                                     : "as the case was loaded");
}

/* The pairs that overlap at the case's poses, into s->penetrating and case.json's "penetrating". */
static int check_penetration(session *s)
{
    planning_case *c = s->c;
    loop_scene sc;
    loop_scene_read(s->L, &sc);
    char why[256];
    case_overlap o[LOOP_MAX_FRAGS * (LOOP_MAX_FRAGS - 1) / 2];
    int n = case_penetrating(c, sc.tolerated_frag, o, (int)(sizeof o / sizeof o[0]));
    int rc = n < 0 ? n : case_record_penetrating(c, o, n);
    if (rc < 0)
        return rc;
    for (int k = 0; k < n; k++) {
        int a = c->frag[o[k].a].id, b = c->frag[o[k].b].id;
        /* a fit (reduce, or the fit action) left one of them there: inside by no more than its
         * tolerance, where the voxel surfaces of the two sides interlock */
        if (o[k].fitted)
            fprintf(stderr, "\nnote: fragments %d and %d overlap by %.3f ml where a fit left them: "
                            "within its tolerance (0.5 mm, at most 0.45 voxel)\n", a, b, o[k].ml);
        else {
            penetration_why(c, &sc, o[k].a, o[k].b, why, sizeof why);
            fprintf(stderr, "\nWARNING: saving a penetrating plan: fragments %d and %d overlap by "
                            "%.3f ml (%s)\n", a, b, o[k].ml, why);
        }
    }
    json_t *list = json_object_get(c->extra, "penetrating");
    json_decref(s->penetrating);
    s->penetrating = list ? json_incref(list) : json_array();
    return 0;
}

int session_save_case(session *s, const pose *poses, const uint8_t *fixed)
{
    if (!s->c)
        return fn_err_set(FN_EINVAL, "this session has no case to save (fragments only)");
    pthread_mutex_lock(&s->frag_mu);
    for (int i = 0; i < s->c->nfrag; i++)
        s->c->frag[i].pose = poses[i];
    pthread_mutex_unlock(&s->frag_mu);
    case_set_fixed(s->c, fixed);
    int rc = check_penetration(s);
    if (rc == 0)
        rc = case_save(s->c);
    if (rc == 0)
        rebind(s);
    return rc;
}

int session_save(session *s)
{
    pose poses[LOOP_MAX_FRAGS];
    uint8_t fixed[LOOP_MAX_FRAGS];
    loop_publish(s->L); /* the scene the save reads (fitted marks, why) is this state's: a
                         * session_play publishes only as often as it is read */
    for (int i = 0; i < s->nfrag; i++) {
        poses[i] = loop_pose(s->L, i);
        fixed[i] = (uint8_t)loop_fixed(s->L, i);
    }
    int rc = session_save_case(s, poses, fixed);
    if (rc == 0 && s->jr)
        rc = journal_truncate(s->jr);
    return rc;
}

int session_journal_sync(session *s)
{
    return s->jr ? journal_sync(s->jr) : 0;
}

int session_journal_truncate(session *s)
{
    return s->jr ? journal_truncate(s->jr) : 0;
}
