/* fracnav bench render: frame times of the renderer per mode, for 1 and 3 fragments of a synthetic
 * three-piece fracture of the example CT, and the surface meshes' triangle count. */
#include "bench.h"
#include "cmd.h"

#include "err.h"
#include "fracture.h"
#include "jsonw.h"
#include "render.h"
#include "seg.h"
#include "volio.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static void usage(FILE *out)
{
    fprintf(out, "usage: fracnav bench render [--json] [--frames N] [--size WxH] [--ct FILE]\n"
                 "                            [--platform osmesa|glfw]\n\n"
                 "Frame time of every mode (iso, dvr, mip, surface) for 1 and 3 fragments of a\n"
                 "three-piece synthetic fracture (seed 1) of the example CT, each frame with the\n"
                 "fragments turned a little further, read back to memory.\n\n"
                 "  --json         one JSON object: command, gl_renderer, gl_version, results\n"
                 "                 (mode, fragments, width, height, frame_mean_ms, frame_p99_ms,\n"
                 "                 frame_hz, frame_cpu_mean_ms: CPU time of the whole process,\n"
                 "                 llvmpipe's threads included), surface_triangles (3 fragments), and the loop's figures\n"
                 "                 while rendering (null: the window is not wired into the loop yet)\n"
                 "  --frames N     timed frames per case after one warm-up frame (default 10)\n"
                 "  --size WxH     pixels (default 512x512)\n"
                 "  --ct FILE      the CT to fracture (default %s)\n"
                 "  --platform P   osmesa (default) or glfw\n",
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
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
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

/* Times `frames` frames of mode with the first nfrag fragments; fills one result object. */
static int time_case(render *r, const frag *f, int nfrag, render_mode mode, int frames, int w, int h,
                     uint8_t *rgb, json_t *results)
{
    render_options o;
    render_options_default(&o, f, nfrag);
    o.mode = mode;
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
        jsonw_set(o2, "fragments", json_integer(nfrag));
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

static int run(const char *ct_path, const char *platform, int w, int h, int frames, int json)
{
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
        rc = render_set_scene(r, ct, f, counts[c], 300.0, NULL);
        triangles = render_surface_triangles(r);
        for (int m = RENDER_ISO; m <= RENDER_SURFACE && !rc; m++)
            rc = time_case(r, f, counts[c], (render_mode)m, frames, w, h, rgb, results);
    }
    if (!rc) {
        jsonw_set(o, "gl_renderer", jsonw_string(render_gl_renderer(r)));
        jsonw_set(o, "gl_version", jsonw_string(render_gl_version(r)));
        jsonw_set(o, "results", results);
        results = NULL;
        jsonw_set(o, "surface_triangles", json_integer(triangles));
        const char *loop_keys[] = {"loop_hz_alone", "loop_hz_rendering", "latency_p99_us_alone",
                                   "latency_p99_us_rendering", "report_to_frame_p99_ms"};
        for (size_t i = 0; i < sizeof loop_keys / sizeof loop_keys[0]; i++)
            jsonw_set(o, loop_keys[i], jsonw_measure(JSONW_NA));
        double load[1];
        if (getloadavg(load, 1) == 1)
            fprintf(stderr, "bench render: load average %.1f over the last minute\n", load[0]);
        if (json)
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
    double frames = 10;
    const char *ct = cmd_example_ct(), *platform = "osmesa";
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
        } else if (!strcmp(a, "--platform")) {
            if (!val || (strcmp(val, "osmesa") && strcmp(val, "glfw")))
                return cmd_bad_value("bench render", a, val, "osmesa or glfw");
            platform = val;
        } else
            return cmd_usage_error("bench render", "unknown option '%s'", a);
        i++;
    }
    int rc = run(ct, platform, w, h, (int)frames, json);
    if (rc) {
        fprintf(stderr, "fracnav bench render: %s\n", fn_err_msg());
        return 1;
    }
    return 0;
}
