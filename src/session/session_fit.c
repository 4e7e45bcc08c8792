/* session: the reduction worker. LOOP_ACT_FIT fits the selected fragment to the others on a
 * thread of its own (reduce_fit_one, from where the hand left it); the owner's thread proposes its
 * result when it sees the fit end (session_run.c), so it lands through the loop as one proposal:
 * accepted, journaled, one undo step. The loop thread never waits for
 * it: the worker works on struct copies of the fragments (sharing their voxels, which nothing
 * writes while a case is open) at the poses of the scene the request was seen in. */
#include "session_impl.h"

#include "err.h"
#include "reduce.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static void on_progress(void *ctx, int id, int iter, int evals, double f, double seconds)
{
    (void)id;
    session *s = ctx;
    pthread_mutex_lock(&s->fit_mu);
    if (s->fit.iterations == 0 && s->fit.evaluations == 0)
        s->fit.metric_start = f;
    s->fit.iterations = iter;
    s->fit.evaluations = evals;
    s->fit.metric = f;
    s->fit.seconds = seconds;
    pthread_mutex_unlock(&s->fit_mu);
}

void session__pose_change(const frag *f, const pose *a, const pose *b, double *mm, double *deg)
{
    double ca[3], cb[3];
    pose_apply(a, f->centroid, ca);
    pose_apply(b, f->centroid, cb);
    *mm = sqrt((ca[0] - cb[0]) * (ca[0] - cb[0]) + (ca[1] - cb[1]) * (ca[1] - cb[1]) +
               (ca[2] - cb[2]) * (ca[2] - cb[2]));
    double d = fabs(a->q[0] * b->q[0] + a->q[1] * b->q[1] + a->q[2] * b->q[2] + a->q[3] * b->q[3]);
    *deg = 2.0 * acos(d > 1.0 ? 1.0 : d) * 180.0 / M_PI;
}

static void *fit_thread(void *arg)
{
    session *s = arg;
    const frag *others[LOOP_MAX_FRAGS];
    int n = 0;
    for (int i = 0; i < s->nfrag; i++)
        if (i != s->fit_sel)
            others[n++] = &s->fit_frags[i];
    reduce_opts o;
    reduce_defaults(&o);
    o.tau_min = s->tau[0];
    o.tau_max = s->tau[1];
    /* o.tolerance_mm stays reduce's (0.5 mm, at most 0.45 voxel): at the loop's 0 the voxel
     * surfaces of a fit near the truth interlock, and the result would be pushed off it by
     * millimetres (the skull: 3.4 mm); the loop takes the result within it (session__propose) */
    o.gap_mm = s->fit_gap_mm;
    o.threads = 1; /* the fit runs beside the real-time loop: the global check's candidates on this
                    * worker alone, the other core the loop's */
    o.progress = on_progress;
    o.progress_ctx = s;
    o.cancel = &s->fit_cancel;
    pose out = s->fit_start;
    reduce_result r;
    memset(&r, 0, sizeof r);
    int rc = reduce_fit_one(others, n, &s->fit_frags[s->fit_sel], &s->fit_start, &o, &out, &r);
    char why[256] = "";
    if (rc < 0)
        snprintf(why, sizeof why, "%s", fn_err_msg());
    double mm = 0, deg = 0;
    session__pose_change(&s->fit_frags[s->fit_sel], &s->fit_start, &out, &mm, &deg);
    pthread_mutex_lock(&s->fit_mu);
    s->fit.running = 0;
    s->fit.result = rc;
    s->fit.iterations = r.iterations;
    s->fit.evaluations = r.evaluations;
    s->fit.metric_start = r.metric_start;
    s->fit.metric = r.metric_end;
    s->fit.seconds = r.seconds;
    s->fit.moved_mm = rc == 0 ? mm : 0;
    s->fit.turned_deg = rc == 0 ? deg : 0;
    s->fit.finished++;
    s->fit_out = out;
    others[n] = &s->fit_frags[s->fit_sel];
    s->fit_tolerance_mm = reduce_tolerance(&o, others, n + 1);
    snprintf(s->fit_why, sizeof s->fit_why, "%s", why);
    pthread_mutex_unlock(&s->fit_mu);
    reduce_result_free(&r);
    sem_post(&s->wake);
    if (s->wakeup)
        s->wakeup(s->wakeup_ctx);
    return NULL;
}

void session_fit_status(session *s, session_fit *out)
{
    pthread_mutex_lock(&s->fit_mu);
    *out = s->fit;
    pthread_mutex_unlock(&s->fit_mu);
}

static void refuse(session_event *ev, int rc, const char *fmt, int fragment)
{
    ev->result = rc;
    snprintf(ev->text, sizeof ev->text, fmt, fragment);
}

void session__fit_start(session *s, session_event *ev)
{
    const loop_scene *sc = &s->scene;
    int sel = sc->selected;
    ev->kind = SESSION_EV_FIT;
    session_fit_status(s, &ev->fit);
    if (ev->fit.running)
        return refuse(ev, FN_EAGAIN, "fit refused: frag %d is still being fitted", ev->fit.frag + 1);
    if (!atomic_load(&s->running))
        return refuse(ev, FN_EAGAIN, "fit refused: the session has stopped (frag %d)", sel + 1);
    if (s->nfrag < 2)
        return refuse(ev, FN_EINVAL, "fit refused: frag %d has no other fragment to fit to", sel + 1);
    if (sel < 0 || sel >= s->nfrag || sc->fixed[sel])
        return refuse(ev, FN_EINVAL, "fit refused: frag %d is fixed; select a movable one", sel + 1);
    session__fit_join(s);
    const frag *src = s->c ? s->c->frag : s->frags;
    for (int i = 0; i < s->nfrag; i++) {
        s->fit_frags[i] = src[i];
        s->fit_frags[i].pose = sc->pose[i];
    }
    s->fit_sel = sel;
    s->fit_start = sc->pose[sel];
    atomic_store(&s->fit_cancel, 0);
    pthread_mutex_lock(&s->fit_mu);
    unsigned finished = s->fit.finished;
    memset(&s->fit, 0, sizeof s->fit);
    s->fit.running = 1;
    s->fit.frag = sel;
    s->fit.finished = finished;
    ev->fit = s->fit;
    pthread_mutex_unlock(&s->fit_mu);
    if (pthread_create(&s->fit_th, NULL, fit_thread, s) != 0) {
        pthread_mutex_lock(&s->fit_mu);
        s->fit.running = 0;
        pthread_mutex_unlock(&s->fit_mu);
        return refuse(ev, FN_EIO, "fit refused: cannot start the worker thread (frag %d)", sel + 1);
    }
    s->fit_joinable = 1;
    ev->result = 0;
    snprintf(ev->text, sizeof ev->text, "fitting frag %d to the others...", sel + 1);
}

int session__fit_finished(session *s, session_event *ev, pose *fitted, double *tolerance_mm)
{
    pthread_mutex_lock(&s->fit_mu);
    int news = s->fit.finished != s->fits_told;
    if (news) {
        s->fits_told = s->fit.finished;
        *fitted = s->fit_out;
        *tolerance_mm = s->fit_tolerance_mm;
        ev->fit = s->fit;
        ev->result = s->fit.result;
        if (s->fit.result == 0)
            snprintf(ev->text, sizeof ev->text,
                     "fit: frag %d moved %.2f mm, turned %.2f deg (metric %.4f -> %.4f, %d "
                     "iterations, %.2f s)",
                     s->fit.frag + 1, s->fit.moved_mm, s->fit.turned_deg, s->fit.metric_start,
                     s->fit.metric, s->fit.iterations, s->fit.seconds);
        else if (s->fit.result == 1)
            snprintf(ev->text, sizeof ev->text, "fit of frag %d cancelled", s->fit.frag + 1);
        else
            snprintf(ev->text, sizeof ev->text, "fit of frag %d failed: %s", s->fit.frag + 1,
                     s->fit_why);
    }
    pthread_mutex_unlock(&s->fit_mu);
    if (news)
        ev->kind = SESSION_EV_FIT;
    return news;
}

void session__fit_join(session *s)
{
    if (!s->fit_joinable)
        return;
    atomic_store(&s->fit_cancel, 1);
    pthread_join(s->fit_th, NULL);
    s->fit_joinable = 0;
}
