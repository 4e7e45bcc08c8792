/* loop: statistics, the timing windows on the loop's clock, and the scene buffer a renderer
 * reads. */
#include "loop_impl.h"

#include "fnclock.h"

#include <math.h>
#include <string.h>

#define FNV_OFFSET 0xcbf29ce484222325ull
#define FNV_PRIME 0x100000001b3ull

/* The monotonic clock; loop_run waits on it for loop_notify (wait_until NULL). */
static int64_t mono_now_us(void *ctx)
{
    (void)ctx;
    return fnclock_now_us();
}

void loop_set_clock(loop *L, const loop_clock *c)
{
    L->clock = c ? *c : (loop_clock){mono_now_us, NULL, NULL};
    loop_reset_timing(L);
}

int64_t loop__now_us(const loop *L)
{
    return L->clock.now_us(L->clock.ctx);
}

void loop__stats_init(loop *L)
{
    L->st.pose_digest = FNV_OFFSET;
    for (int b = 0; b < LOOP_SCENE_BUFS; b++)
        atomic_init(&L->refs[b], 0);
    atomic_init(&L->latest, 0);
    loop_set_clock(L, NULL);
    loop_publish(L);
}

void loop_reset_timing(loop *L)
{
    memset(L->hist, 0, sizeof L->hist);
    L->hist_over = 0;
    L->lat_max = 0;
    L->st.latency_samples = 0;
    L->st.latency_p50_us = L->st.latency_p99_us = L->st.latency_max_us = 0;
    L->q_sum_ns = L->q_max_ns = 0;
    L->st.queries = L->st.searches = 0;
    L->win_start_us = loop__now_us(L);
    L->pct_at_us = 0;
    L->win_steps = L->win_ticks = 0;
}

void loop__stats_query(loop *L, int64_t ns)
{
    L->st.queries++;
    L->q_sum_ns += (double)ns;
    if (ns > L->q_max_ns)
        L->q_max_ns = (double)ns;
}

/* FNV-1a 64 over the fragment index (u32 LE) and the 7 doubles' bytes (LE): the same on every
 * machine with IEEE doubles. */
void loop__stats_pose(loop *L, int s, const pose *p)
{
    uint64_t h = L->st.pose_digest;
    unsigned char b[4 + 56];
    for (int i = 0; i < 4; i++)
        b[i] = (unsigned char)((uint32_t)s >> (8 * i));
    const double *v[7] = {&p->q[0], &p->q[1], &p->q[2], &p->q[3], &p->t[0], &p->t[1], &p->t[2]};
    for (int k = 0; k < 7; k++) {
        uint64_t u;
        memcpy(&u, v[k], 8);
        for (int i = 0; i < 8; i++)
            b[4 + 8 * k + i] = (unsigned char)(u >> (8 * i));
    }
    for (size_t i = 0; i < sizeof b; i++)
        h = (h ^ b[i]) * FNV_PRIME;
    L->st.pose_digest = h;
}

void loop__stats_outcome(loop *L, int outcome)
{
    L->st.steps++;
    L->win_steps++;
    if (outcome == LOOP_ACCEPTED)
        L->st.accepted++;
    else if (outcome == LOOP_LIMITED)
        L->st.limited++;
    else if (outcome == LOOP_SLID)
        L->st.slid++;
    else if (outcome == LOOP_REFUSED)
        L->st.refused++;
}

void loop__stats_latency(loop *L, int64_t us)
{
    if (us < 0)
        us = 0;
    if (us < LOOP_HIST_BINS)
        L->hist[us]++;
    else
        L->hist_over++;
    if ((double)us > L->lat_max)
        L->lat_max = (double)us;
    L->st.latency_samples++;
}

/* The latency below which a fraction q of the samples lie (bin upper edge). */
static double percentile(const loop *L, double q)
{
    uint64_t want = (uint64_t)ceil(q * (double)L->st.latency_samples), seen = 0;
    for (int i = 0; i < LOOP_HIST_BINS; i++) {
        seen += L->hist[i];
        if (seen >= want && want > 0)
            return i + 1 > L->lat_max ? L->lat_max : i + 1;
    }
    return L->lat_max;
}

static void refresh_rates(loop *L, int64_t now)
{
    double secs = (double)(now - L->win_start_us) * 1e-6;
    L->st.step_hz = secs > 0 ? (double)L->win_steps / secs : 0;
    L->st.tick_hz = secs > 0 ? (double)L->win_ticks / secs : 0;
    L->st.query_us_mean = L->st.queries ? L->q_sum_ns / (double)L->st.queries * 1e-3 : 0;
    L->st.query_us_max = L->q_max_ns * 1e-3;
    L->st.latency_p50_us = percentile(L, 0.50);
    L->st.latency_p99_us = percentile(L, 0.99);
    L->st.latency_max_us = L->lat_max;
    L->pct_at_us = now;
}

void loop_get_stats(loop *L, loop_stats *out)
{
    refresh_rates(L, loop__now_us(L));
    *out = L->st;
}

/* A buffer no reader holds and that is not the newest; -1 when readers hold them all. */
static int free_buffer(loop *L)
{
    int newest = atomic_load(&L->latest);
    for (int k = 1; k < LOOP_SCENE_BUFS; k++) {
        int b = (newest + k) % LOOP_SCENE_BUFS;
        if (atomic_load(&L->refs[b]) == 0)
            return b;
    }
    return -1;
}

void loop_publish(loop *L)
{
    int64_t now = loop__now_us(L);
    if (now - L->pct_at_us >= 100000) /* percentiles cost a histogram walk: 10 Hz is plenty */
        refresh_rates(L, now);
    int b = free_buffer(L);
    if (b < 0)
        return; /* never wait for readers: the next publish carries this state too */
    loop_scene *s = &L->buf[b];
    s->seq = ++L->pub_seq;
    s->nfrag = L->n;
    s->selected = L->selected;
    s->collision_on = L->collision_on;
    s->trans_only = L->trans_only;
    s->rot_only = L->rot_only;
    s->device_present = L->device_present;
    s->save_requests = L->save_requests;
    s->fit_requests = L->fit_requests;
    s->preview_requests = L->preview_requests;
    s->accept_requests = L->accept_requests;
    s->frame = L->cfg.frame;
    s->last_outcome = L->last_outcome;
    s->penetrating = L->collision_on && L->in_collision;
    s->tolerated = s->penetrating && L->tolerated[L->selected];
    memcpy(s->tolerated_frag, L->tolerated, (size_t)L->n);
    for (int i = 0; i < L->n; i++)
        s->held_frag[i] = L->hold_mm[i] > 0;
    memcpy(s->fit_ended_by, L->fit_ended_by, (size_t)L->n);
    s->separation_mm = !L->collision_on ? NAN : L->in_collision ? L->pen : L->gap_valid ? L->gap : NAN;
    s->actions = L->actions;
    s->last_action = (loop_action)L->last_action;
    s->last_action_result = L->last_action_result;
    s->stats = L->st;
    memcpy(s->pose, L->pose, sizeof(pose) * (size_t)L->n);
    memcpy(s->fixed, L->fixed, (size_t)L->n);
    s->proposals = L->proposals;
    memcpy(s->proposal_result, L->proposal_result, sizeof s->proposal_result);
    atomic_store(&L->latest, b);
    if (L->on_publish)
        L->on_publish(L->on_publish_ctx);
}

void loop_set_publish_hook(loop *L, void (*fn)(void *ctx), void *ctx)
{
    L->on_publish = fn;
    L->on_publish_ctx = ctx;
}

/* Pins the newest buffer: after the pin it must still be the newest, else the writer may have
 * picked it for filling (it was not pinned when the writer looked) and the reader tries again. */
int loop_scene_read(loop *L, loop_scene *out)
{
    uint64_t had = out->seq;
    for (;;) {
        int b = atomic_load(&L->latest);
        atomic_fetch_add(&L->refs[b], 1);
        if (atomic_load(&L->latest) == b) {
            *out = L->buf[b];
            atomic_fetch_sub(&L->refs[b], 1);
            break;
        }
        atomic_fetch_sub(&L->refs[b], 1);
    }
    return out->seq != had;
}
