/* loop internals shared by loop.c (stepping), loop_stats.c (statistics, scenes), loop_run.c (the
 * driver) and loop_reader.c (the input thread); not for other modules. Functions: loop__ names. */
#ifndef FN_LOOP_IMPL_H
#define FN_LOOP_IMPL_H

#include "loop.h"

#include <stdatomic.h>

#include <semaphore.h>

#define LOOP_UNDO_MAX 256
#define LOOP_SCENE_BUFS 8
#define LOOP_STACK_PREFAULT (128 * 1024) /* stack a step may use: the queries' pair stacks */
#define LOOP_HIST_BINS 10000 /* 1 us bins; later latencies land in the overflow count */

typedef struct loop_undo {
    int frag;
    pose p;
    int fix; /* 0: a pose step (p); 1 + flag: a fix step, back to fixed[frag] = flag */
    double hold_mm; /* a pose step: the tolerance the fragment held there (hold_mm) */
    int tolerated;  /* ... and whether it stood where a fit left it */
} loop_undo;

struct loop {
    const frag *frags;
    int n;
    pose pose[LOOP_MAX_FRAGS];
    uint8_t fixed[LOOP_MAX_FRAGS];
    double radius[LOOP_MAX_FRAGS]; /* centroid to farthest crop corner, mm */
    loop_collider col;
    /* The pair caches: one slot per other fragment j, holding the pair (mover, j) of the last
     * fragment that moved against j (cache_mover: 1 + its index, 0 none), so memory grows with n,
     * not n*n (64 fragments: 10 MB, not 672); one scratch for fresh queries. slot[j] points
     * into caches; a query from scratch that the pair's cache may keep (settle) swaps its slot
     * with the scratch. */
    size_t cache_stride;
    unsigned char *caches, *scratch, *slot[LOOP_MAX_FRAGS];
    uint8_t cache_mover[LOOP_MAX_FRAGS];
    loop_config cfg;
    struct journal *jr;
    ring *ctl; /* actions from the application's thread */
    const pose *saved; /* loop_set_saved */

    int selected, collision_on, trans_only, rot_only, device_present;
    /* The camera frame's device -> world matrix, row major (loop_set_camera, any thread): a
     * seqlock over atomics, so the stepping thread reads it without a lock or a data race. */
    atomic_uint cam_seq;
    _Atomic double cam[9];
    unsigned save_requests;
    unsigned fit_requests;
    unsigned preview_requests, accept_requests;
    int have_pivot;
    double pivot_home[3];
    int have_last_t;
    int64_t last_t;
    uint32_t buttons;
    int gesture_saved; /* this gesture's undo checkpoint is taken */
    int gap_valid, in_collision; /* in_collision: the selected fragment interpenetrates another */
    int gap_fresh; /* gap comes from a query from scratch at the current pose (settle) */
    int at_rest;      /* the last motion event was all zero (or the device went away) */
    unsigned actions; /* controls done, for the scene's acknowledgement */
    int last_action, last_action_result;
    int tries; /* candidates queried in this step */
    int verify, verify_frag; /* an accepted pose awaits the invariant check */
    double gap; /* selected fragment's separation lower bound at its current pose */
    double pen; /* in_collision: the collider's (negative) penetration estimate there */
    double overlap; /* in_collision: the overlap volume there (loop_collider.overlap) */
    loop_outcome last_outcome;

    loop_undo undo[LOOP_UNDO_MAX], redo[LOOP_UNDO_MAX];
    int nundo, nredo;

    loop_stats st;
    uint32_t hist[LOOP_HIST_BINS];
    uint64_t hist_over;
    double lat_max, q_sum_ns, q_max_ns;
    int64_t win_start_us, pct_at_us;
    uint64_t win_steps, win_ticks;

    /* Scene buffers for any number of readers: `latest` names the newest; a reader pins a buffer
     * (refs) before copying it, and the writer only fills a buffer that is neither the newest nor
     * pinned. With LOOP_SCENE_BUFS - 2 readers at once the writer always finds one. */
    loop_scene buf[LOOP_SCENE_BUFS];
    atomic_int refs[LOOP_SCENE_BUFS];
    atomic_int latest;
    uint64_t pub_seq;
    sem_t wake;          /* loop_notify -> loop_run */
    atomic_int rt_cpu;   /* the CPU loop_run runs on under SCHED_FIFO (-1: not), for the reader */
    int rt_prio;         /* its priority, written before rt_cpu */
    atomic_int running;  /* loop_run is past its start (pages mapped): the reader may read */
    uint8_t tolerated[LOOP_MAX_FRAGS]; /* where a fit left it, not moved since (the scene's label) */
    uint8_t fit_ended_by[LOOP_MAX_FRAGS]; /* 1 + the fragment whose move ended `tolerated` (0: none) */
    /* > 0: the fragment may stand inside another by up to this fit's tolerance: its pairs are
     * queried at it until it rests free at 0 (loop.h, proposals) */
    double hold_mm[LOOP_MAX_FRAGS];
    atomic_ullong done; /* events finished, for other threads */
    loop_clock clock;   /* loop_set_clock; wait_until NULL: loop_run waits for loop_notify */
    uint64_t proposals; /* LOOP_EV_POSE handled, and their latest results */
    uint8_t proposal_result[LOOP_PROPOSALS_KEPT];
    void (*on_publish)(void *ctx); /* loop_set_publish_hook */
    void *on_publish_ctx;
};

/* Writes every page of p..p+n (first-touch faults taken now, not in a step). */
void loop__prefault(void *p, size_t n);
/* The camera frame's device -> world matrix (loop_set_camera). */
void loop__camera(const loop *L, double R[3][3]);
/* Now on the loop's clock (loop_set_clock). */
int64_t loop__now_us(const loop *L);
void loop__stats_init(loop *L);
void loop__stats_query(loop *L, int64_t ns);
void loop__stats_pose(loop *L, int s, const pose *p);
void loop__stats_outcome(loop *L, int outcome);
void loop__stats_latency(loop *L, int64_t us);

#endif
