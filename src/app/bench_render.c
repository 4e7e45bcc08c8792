/* fracnav bench render: frame times of the renderer per mode, for 1 and 3 fragments of a synthetic
 * three-piece fracture of the example CT, and the surface meshes' triangle count. */
#include "bench.h"
#include "cmd.h"

#include "err.h"
#include "fnclock.h"
#include "fracture.h"
#include "loop.h"
#include "jsonw.h"
#include "render.h"
#include "seg.h"
#include "volio.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define MIN_LOOP_FRAMES 5 /* frames drawn while the loop runs, at the least */

static void usage(FILE *out)
{
    fprintf(out, "usage: fracnav bench render [--json] [--frames N] [--size WxH] [--ct FILE]\n"
                 "                            [--platform P] [--loop-s S] [--mode M]\n"
                 "                            [--overlay LIST]\n\n"
                 "Frame time of every mode (iso, dvr, mip, surface) for 1 and 3 fragments of a\n"
                 "three-piece synthetic fracture (seed 1) of the example CT, each frame with the\n"
                 "fragments turned a little further, read back to memory.\n\n"
                 "  --json         one JSON object: command, gl_renderer, gl_version, default_mode\n"
                 "                 (the window's: surface on software GL, iso on a GPU), results\n"
                 "                 (mode, fragment_count, width, height, frame_mean_ms, frame_p99_ms,\n"
                 "                 frame_hz, frame_cpu_mean_ms: CPU time of the whole process,\n"
                 "                 llvmpipe's threads included), surface_triangles (3 fragments), and the\n"
                 "                 navigation loop over the 3 fragments fed 1000 reports a second on\n"
                 "                 its own thread: loop_alone_hz and latency_alone_p99_us for S seconds\n"
                 "                 alone, loop_rendering_hz and latency_rendering_p99_us for S seconds\n"
                 "                 while this thread draws its scenes in surface mode as fast as it\n"
                 "                 can with late latching as the window does (the other fragments\n"
                 "                 first, then the moving one at its newest pose), and\n"
                 "                 report_to_frame_p99_ms: from a report's arrival to the end of\n"
                 "                 the first frame that shows its pose (read back), beside\n"
                 "                 frame_looping_mean_ms, the frame period then; the same two for\n"
                 "                 S more seconds drawing each frame whole after one read:\n"
                 "                 report_to_frame_one_pass_p99_ms, frame_looping_one_pass_mean_ms\n"
                 "  --frames N     timed frames per case after one warm-up frame (default 10)\n"
                 "  --size WxH     pixels (default 512x512)\n"
                 "  --ct FILE      the CT to fracture (default %s)\n"
                 "  --platform P   offscreen (default: egl on a GPU, else osmesa), osmesa, egl\n"
                 "                 or glfw\n"
                 "  --loop-s S     seconds of each loop phase (default 3)\n"
                 "  --mode M       time only mode M (iso, dvr, mip or surface)\n"
                 "  --overlay LIST contacts, axes or both (comma-separated): every timed frame\n"
                 "                 with these overlays, as render draws them (contacts: the gap\n"
                 "                 in colour in surface mode); the JSON's \"overlay\" names them\n"
                 "                 (null: none)\n",
            cmd_example_ct());
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* CPU time of the whole process (llvmpipe's threads included): on a shared, loaded machine the
 * figure that says what a frame costs. */
static double process_cpu_ms(void)
{
    return (double)fnclock_process_cpu_ns() * 1e-6;
}

/* Three pieces of ct's bone as fragments; *n = how many were built. */
static int make_frags(const vol *ct, frag f[3], int *n)
{
    fracture_params fp;
    fracture_defaults(&fp);
    fp.pieces = 3;
    fracture_result fr;
    int rc = fracture_make(ct, &fp, &fr);
    if (rc)
        return rc;
    seg_params sp;
    seg_defaults(&sp);
    *n = 0;
    for (int id = 1; id <= 3 && !rc; id++) {
        int lo[3], hi[3];
        rc = frag_label_box(fr.labels, id, lo, hi);
        if (!rc)
            rc = frag_from_labels(&f[id - 1], fr.labels, fr.ct, id, lo, hi, fp.threshold, sp.ramp);
        if (!rc)
            (*n)++;
    }
    fracture_result_free(&fr);
    return rc;
}

/* ---- the loop alone and while rendering ---- */

#define SYNTH_PERIOD_US 1000
#define SYNTH_MAX 200000

/* A controller of 1000 reports a second: x swings back and forth once a second. arrival[i] is
 * when report i was made (the loop's reader stamps it right after). */
typedef struct synth {
    atomic_int active; /* reports flow only while set (a phase runs, past the loop's start) */
    int was_active;    /* the rest belongs to the reader's thread */
    int64_t next_us, t0_us;
    int64_t *arrival;
    atomic_long n;
} synth;

static int synth_next(void *ctx, loop_event *ev, int timeout_ms)
{
    synth *s = ctx;
    if (!atomic_load(&s->active)) {
        s->was_active = 0;
        fnclock_sleep_us(1000);
        return 0;
    }
    int64_t now = fnclock_now_us();
    if (!s->was_active) {
        s->was_active = 1;
        s->next_us = now;
    }
    if (now < s->next_us) {
        int64_t wait = s->next_us - now;
        if (wait > (int64_t)timeout_ms * 1000) {
            fnclock_sleep_us((int64_t)timeout_ms * 1000);
            return 0;
        }
        fnclock_sleep_us(wait);
        now = fnclock_now_us();
    }
    s->next_us = (s->next_us + SYNTH_PERIOD_US > now ? s->next_us : now) + SYNTH_PERIOD_US;
    memset(ev, 0, sizeof *ev);
    ev->kind = LOOP_EV_MOTION;
    ev->t_us = now;
    ev->motion[0] = (float)(0.5 * sin(2 * M_PI * (double)(now - s->t0_us) * 1e-6));
    long i = atomic_load(&s->n);
    if (i < SYNTH_MAX)
        s->arrival[i] = now;
    atomic_store(&s->n, i + 1);
    return 1;
}

typedef struct loop_thread_arg {
    loop *L;
    ring *in;
    atomic_int stop;
    int rc;
} loop_thread_arg;

static void *loop_thread(void *arg)
{
    loop_thread_arg *a = arg;
    loop_realtime_priority(); /* as navigate: best effort */
    a->rc = loop_run(a->L, a->in, 1000, &a->stop);
    return NULL;
}

static double p99_of(double *v, size_t n)
{
    if (!n)
        return JSONW_NA;
    qsort(v, n, sizeof *v, cmp_double);
    return v[(size_t)(0.99 * (double)(n - 1) + 0.5)];
}

/* Starts loop_run on its own thread, waits for its first publish (past the prefaulting of
 * loop_run's start, which is not what is measured), then lets reports flow. */
static int phase_start(loop *L, synth *sy, loop_thread_arg *a, pthread_t *th)
{
    loop_scene sc = {0};
    loop_scene_read(L, &sc);
    uint64_t seq = sc.seq;
    atomic_store(&a->stop, 0);
    if (pthread_create(th, NULL, loop_thread, a) != 0)
        return fn_err_set(FN_EIO, "bench render: cannot start the loop thread");
    for (int k = 0; k < 100000 && sc.seq == seq; k++) {
        fnclock_sleep_us(1000);
        loop_scene_read(L, &sc);
    }
    atomic_store(&sy->active, 1);
    return 0;
}

/* Stops the reports, lets the loop finish them, stops it; its figures over the phase into st. */
static int phase_end(loop *L, synth *sy, loop_thread_arg *a, pthread_t th, int64_t t0, loop_stats *st,
                     uint64_t steps0, double *hz)
{
    atomic_store(&sy->active, 0);
    int64_t t1 = fnclock_now_us();
    fnclock_sleep_us(20000);
    atomic_store(&a->stop, 1);
    loop_notify(L);
    pthread_join(th, NULL);
    loop_get_stats(L, st);
    *hz = t1 > t0 ? (double)(st->steps - steps0) * 1e6 / (double)(t1 - t0) : JSONW_NA;
    return a->rc;
}

/* What one rendering phase measured. */
typedef struct phase_out {
    loop_stats st;
    double hz, r2f_p99_ms, frame_mean_ms;
    size_t frames;
} phase_out;

/* One phase of `secs` while r draws the loop's scenes in surface mode as fast as it can, each
 * frame read back; split: late latching (render_frame_early with the scene then, render_frame_late
 * with the newest), else the whole frame after one read. From the frames' ends and the reports'
 * arrivals: report i is in a frame once the frame's scene counts more than i events. */
static int render_phase(render *r, const frag *f, int nfrag, loop *L, synth *sy, loop_thread_arg *a, double secs,
                        int split, uint8_t *rgb, int64_t *f_done, long *f_events, size_t fcap, double *lat,
                        phase_out *po)
{
    render_options ro;
    render_options_default(&ro, f, nfrag);
    ro.mode = RENDER_SURFACE;
    loop_stats before;
    loop_get_stats(L, &before);
    loop_reset_timing(L);
    pthread_t th;
    int rc = phase_start(L, sy, a, &th);
    if (rc)
        return rc;
    long first_report = atomic_load(&sy->n);
    int64_t t0 = fnclock_now_us(), end = t0 + (int64_t)(secs * 1e6);
    loop_scene sc = {0};
    int drc = 0;
    size_t nf = 0;
    /* --loop-s, but at least MIN_LOOP_FRAMES frames: a slow machine (or a sanitizer build) still
     * sees reports reach frames */
    while (!drc && nf < fcap && (fnclock_now_us() < end || nf < MIN_LOOP_FRAMES)) {
        loop_scene_read(L, &sc);
        if (split) {
            drc = render_frame_early(r, sc.pose, sc.selected, &ro);
            loop_scene_read(L, &sc);
            if (!drc)
                drc = render_frame_late(r, sc.pose, &ro);
        } else
            drc = render_frame(r, sc.pose, &ro);
        if (!drc)
            drc = render_read_rgb(r, rgb);
        f_done[nf] = fnclock_now_us();
        f_events[nf++] = (long)sc.stats.events;
    }
    long last_report = atomic_load(&sy->n);
    rc = phase_end(L, sy, a, th, t0, &po->st, before.steps, &po->hz);
    if (drc)
        return drc;
    size_t nl = 0, k = 0;
    for (long i = first_report; i < last_report && i < SYNTH_MAX; i++) {
        while (k < nf && f_events[k] <= i)
            k++;
        if (k == nf)
            break;
        lat[nl++] = (double)(f_done[k] - sy->arrival[i]) / 1000.0;
    }
    po->r2f_p99_ms = p99_of(lat, nl);
    po->frames = nf;
    po->frame_mean_ms = nf > 1 ? (double)(f_done[nf - 1] - f_done[0]) / 1000.0 / (double)(nf - 1) : JSONW_NA;
    return rc;
}

/* The loop over f (3 fragments) on its own thread: `secs` alone, then `secs` while r draws its
 * scenes (surface mode) with late latching, as the window does, then `secs` drawing each frame
 * whole after one read. Each phase is its own loop_run, its timing restarted before it starts
 * (loop_reset_timing and loop_get_stats only while the loop is stopped). Sets the figures in o. */
static int measure_loop(render *r, const frag *f, int nfrag, double secs, uint8_t *rgb, json_t *o)
{
    loop_obb *ob = loop_obb_new(f, nfrag, NULL, NULL);
    if (!ob)
        return FN_ENOMEM;
    loop_collider col = loop_obb_collider(ob);
    loop_config cfg;
    loop_config_default(&cfg);
    loop *L = loop_new(f, nfrag, NULL, &col, &cfg, NULL);
    ring *in = ring_new(sizeof(loop_event), 4096);
    synth sy = {0};
    atomic_init(&sy.active, 0);
    atomic_init(&sy.n, 0);
    sy.arrival = malloc(SYNTH_MAX * sizeof *sy.arrival);
    size_t fcap = 100000;
    int64_t *f_done = malloc(fcap * sizeof *f_done);
    long *f_events = malloc(fcap * sizeof *f_events);
    double *lat = malloc(SYNTH_MAX * sizeof *lat);
    int rc = L && in && sy.arrival && f_done && f_events && lat ? 0 : FN_ENOMEM;
    loop_thread_arg a = {L, in, 0, 0};
    atomic_init(&a.stop, 0);
    pthread_t th;
    loop_reader *rd = NULL;
    if (!rc) {
        sy.t0_us = fnclock_now_us();
        loop_source src = {synth_next, &sy};
        rd = loop_reader_start(src, in, L, 0);
        if (!rd)
            rc = fn_err_set(FN_EIO, "bench render: cannot start the loop's reader");
    }
    loop_stats alone = {0};
    double alone_hz = JSONW_NA;
    phase_out late = {0}, whole = {0};
    if (!rc) {
        loop_get_stats(L, &alone);
        uint64_t steps0 = alone.steps;
        loop_reset_timing(L);
        rc = phase_start(L, &sy, &a, &th);
        if (!rc) {
            int64_t t0 = fnclock_now_us();
            fnclock_sleep_us((int64_t)(secs * 1e6));
            rc = phase_end(L, &sy, &a, th, t0, &alone, steps0, &alone_hz);
        }
    }
    if (!rc)
        rc = render_phase(r, f, nfrag, L, &sy, &a, secs, 1, rgb, f_done, f_events, fcap, lat, &late);
    if (!rc)
        rc = render_phase(r, f, nfrag, L, &sy, &a, secs, 0, rgb, f_done, f_events, fcap, lat, &whole);
    loop_reader_stop(rd);
    if (!rc) {
        jsonw_set(o, "loop_alone_hz", jsonw_measure(alone_hz));
        jsonw_set(o, "latency_alone_p99_us", jsonw_measure(alone.latency_p99_us));
        jsonw_set(o, "loop_rendering_hz", jsonw_measure(late.hz));
        jsonw_set(o, "latency_rendering_p99_us", jsonw_measure(late.st.latency_p99_us));
        jsonw_set(o, "report_to_frame_p99_ms", jsonw_measure(late.r2f_p99_ms));
        jsonw_set(o, "frames_while_looping", json_integer((json_int_t)late.frames));
        jsonw_set(o, "frame_looping_mean_ms", jsonw_measure(late.frame_mean_ms));
        jsonw_set(o, "report_to_frame_one_pass_p99_ms", jsonw_measure(whole.r2f_p99_ms));
        jsonw_set(o, "frame_looping_one_pass_mean_ms", jsonw_measure(whole.frame_mean_ms));
        fprintf(stderr, "bench render: loop alone %.0f Hz p99 %.0f us; while rendering %.0f Hz p99 %.0f us, "
                        "%zu frames of %.1f ms, report to frame p99 %.1f ms (%.2f frames); one pass: "
                        "frames of %.1f ms, report to frame p99 %.1f ms (%.2f frames)\n",
                alone_hz, alone.latency_p99_us, late.hz, late.st.latency_p99_us, late.frames, late.frame_mean_ms,
                late.r2f_p99_ms, late.r2f_p99_ms / late.frame_mean_ms, whole.frame_mean_ms, whole.r2f_p99_ms,
                whole.r2f_p99_ms / whole.frame_mean_ms);
    }
    if (rc == FN_ENOMEM)
        fn_err_set(FN_ENOMEM, "bench render: out of memory for the loop");
    free(lat);
    free(f_events);
    free(f_done);
    free(sy.arrival);
    ring_free(in);
    loop_free(L);
    loop_obb_free(ob);
    return rc;
}

/* Times `frames` frames of mode with the first nfrag fragments; fills one result object. */
static int time_case(render *r, const frag *f, int nfrag, render_mode mode, unsigned overlays, int frames, int w,
                     int h, uint8_t *rgb, json_t *results)
{
    render_options o;
    render_options_default(&o, f, nfrag);
    o.mode = mode;
    o.overlays = overlays;
    pose poses[3];
    double *ms = malloc((size_t)frames * sizeof *ms), cpu = 0;
    if (!ms)
        return fn_err_set(FN_ENOMEM, "bench render: out of memory");
    int rc = 0;
    for (int k = -1; k < frames && !rc; k++) {
        for (int i = 0; i < nfrag; i++) {
            const double axis[3] = {0, 0, 1};
            pose turn = pose_from_axis_angle(axis, 0.002 * (k + 1) * (i + 1));
            poses[i] = turn;
        }
        double t0 = bench_now_us(), c0 = process_cpu_ms();
        rc = render_frame(r, poses, &o);
        if (!rc)
            rc = render_read_rgb(r, rgb);
        if (k >= 0) {
            ms[k] = (bench_now_us() - t0) / 1000.0;
            cpu += process_cpu_ms() - c0;
        }
    }
    if (!rc) {
        double sum = 0;
        for (int k = 0; k < frames; k++)
            sum += ms[k];
        qsort(ms, (size_t)frames, sizeof *ms, cmp_double);
        double mean = sum / frames, p99 = ms[(size_t)(0.99 * (frames - 1) + 0.5)];
        json_t *o2 = json_object();
        jsonw_set(o2, "mode", json_string(render_mode_name(mode)));
        jsonw_set(o2, "fragment_count", json_integer(nfrag));
        jsonw_set(o2, "width", json_integer(w));
        jsonw_set(o2, "height", json_integer(h));
        jsonw_set(o2, "frame_mean_ms", jsonw_measure(mean));
        jsonw_set(o2, "frame_p99_ms", jsonw_measure(p99));
        jsonw_set(o2, "frame_hz", jsonw_measure(1000.0 / mean));
        jsonw_set(o2, "frame_cpu_mean_ms", jsonw_measure(cpu / frames));
        json_array_append_new(results, o2);
        fprintf(stderr, "bench render: %-7s %d fragment(s) %dx%d: %.1f ms mean, %.1f ms p99, %.1f ms CPU\n",
                render_mode_name(mode), nfrag, w, h, mean, p99, cpu / frames);
    }
    free(ms);
    return rc;
}

/* only: the one mode timed, or -1 for every mode; overlay: --overlay's list (NULL: none), parsed
 * into overlays. */
static int run(const char *ct_path, const char *platform, int w, int h, int frames, int json, double loop_s,
               int only, const char *overlay, unsigned overlays)
{
    const obb_params hp = {0.5, 0.95};
    vol *ct = volio_read(ct_path);
    if (!ct)
        return FN_EIO;
    frag f[3];
    memset(f, 0, sizeof f);
    int n = 0;
    int rc = make_frags(ct, f, &n);
    render *r = rc ? NULL : render_open(platform, w, h);
    uint8_t *rgb = malloc((size_t)w * (size_t)h * 3);
    json_t *o = jsonw_object("bench render"), *results = json_array();
    if (!rc && !r)
        rc = FN_ENODEV;
    if (!rc && (!rgb || !o || !results))
        rc = fn_err_set(FN_ENOMEM, "bench render: out of memory");
    long triangles = 0;
    const int counts[2] = {1, 3};
    for (int c = 0; c < 2 && !rc; c++) {
        rc = render_set_scene(r, ct, f, counts[c], 300.0, overlays ? &hp : NULL);
        triangles = render_surface_triangles(r);
        for (int m = RENDER_ISO; m <= RENDER_SURFACE && !rc; m++)
            if (only < 0 || m == only)
                rc = time_case(r, f, counts[c], (render_mode)m, overlays, frames, w, h, rgb, results);
    }
    if (!rc) {
        jsonw_set(o, "gl_renderer", jsonw_string(render_gl_renderer(r)));
        jsonw_set(o, "default_mode", jsonw_string(render_mode_name(render_default_mode(r))));
        jsonw_set(o, "gl_version", jsonw_string(render_gl_version(r)));
        jsonw_set(o, "overlay", overlay ? json_string(overlay) : json_null());
        jsonw_set(o, "results", results);
        results = NULL;
        jsonw_set(o, "surface_triangles", json_integer(triangles));
        rc = measure_loop(r, f, n, loop_s, rgb, o);
        double load[1];
        if (getloadavg(load, 1) == 1)
            fprintf(stderr, "bench render: load average %.1f over the last minute\n", load[0]);
        if (json && !rc)
            rc = jsonw_print(o, stdout);
        else
            json_decref(o);
        o = NULL;
    }
    json_decref(o);
    json_decref(results);
    free(rgb);
    render_close(r);
    for (int i = 0; i < 3; i++)
        frag_free(&f[i]);
    vol_free(ct);
    return rc;
}

int bench_render(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    int json = 0, w = 512, h = 512;
    double frames = 10, loop_s = 3;
    const char *ct = cmd_example_ct(), *platform = "offscreen";
    render_mode mode = RENDER_ISO;
    int only = -1, depth = 3;
    unsigned overlays = 0;
    const char *overlay = NULL;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        char tail;
        if (!strcmp(a, "--json")) {
            json = 1;
            continue;
        }
        if (!strcmp(a, "--frames")) {
            if (!cmd_number(val, &frames) || frames < 1 || frames > 100000 || frames != (int)frames)
                return cmd_bad_value("bench render", a, val, "a whole number from 1 to 100000");
        } else if (!strcmp(a, "--size")) {
            if (!val || sscanf(val, "%dx%d%c", &w, &h, &tail) != 2 || w < 16 || h < 16 || w > 8192 ||
                h > 8192)
                return cmd_bad_value("bench render", a, val, "WxH, 16 to 8192 pixels each");
        } else if (!strcmp(a, "--ct")) {
            if (!val)
                return cmd_bad_value("bench render", a, val, "a volume file");
            ct = val;
        } else if (!strcmp(a, "--loop-s")) {
            if (!cmd_number(val, &loop_s) || !(loop_s >= 0.1) || loop_s > 3600)
                return cmd_bad_value("bench render", a, val, "seconds from 0.1 to 3600");
        } else if (!strcmp(a, "--platform")) {
            if (!val || (strcmp(val, "offscreen") && strcmp(val, "osmesa") && strcmp(val, "egl") &&
                         strcmp(val, "glfw")))
                return cmd_bad_value("bench render", a, val, "offscreen, osmesa, egl or glfw");
            platform = val;
        } else if (!strcmp(a, "--mode")) {
            if (render_mode_parse(val, &mode))
                return cmd_bad_value("bench render", a, val, "iso, dvr, mip or surface");
            only = (int)mode;
        } else if (!strcmp(a, "--overlay")) {
            if (!val || render_overlays_parse(val, &overlays, &depth) ||
                (overlays & (RENDER_OVERLAY_VOI | RENDER_OVERLAY_HIERARCHY)))
                return cmd_bad_value("bench render", a, val, "contacts, axes, or both");
            overlay = val;
        } else
            return cmd_usage_error("bench render", "unknown option '%s'", a);
        i++;
    }
    int rc = run(ct, platform, w, h, (int)frames, json, loop_s, only, overlay, overlays);
    if (rc) {
        fprintf(stderr, "fracnav bench render: %s\n", fn_err_msg());
        return 1;
    }
    return 0;
}
