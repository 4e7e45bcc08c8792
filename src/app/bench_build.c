/* fracnav bench build: hierarchy build time and memory against volume size (linear growth). */
#include "bench.h"

#include "cmd.h"
#include "err.h"
#include "jsonw.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A bone-like n^3 fragment: a thick-walled tube along z with a rough end, probabilities from a
 * ramp across the wall (solid cortex, uncertain rims), so every pruning rule has work to do. */
static int fill_bone(frag *f, int n)
{
    memset(f, 0, sizeof *f);
    snprintf(f->name, sizeof f->name, "tube %d^3", n);
    f->dim[0] = f->dim[1] = f->dim[2] = n;
    f->spacing[0] = f->spacing[1] = f->spacing[2] = 0.5;
    f->home = f->pose = POSE_IDENTITY;
    f->prob = calloc((size_t)n * n * n, 1);
    if (!f->prob)
        return fn_err_set(FN_ENOMEM, "out of memory for a %d^3 fragment", n);
    double c = (n - 1) / 2.0, ro = 0.48 * n, ri = 0.30 * n;
    for (int k = 0; k < n; k++)
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++) {
                double r = sqrt((i - c) * (i - c) + (j - c) * (j - c));
                double end = n * (0.9 + 0.05 * sin(i * 0.2) * cos(j * 0.15));
                if (r < ri || r > ro || k > end)
                    continue;
                double edge = fmin(r - ri, ro - r);
                size_t idx = ((size_t)k * n + j) * n + i;
                f->prob[idx] = edge > 2 ? 255 : (uint8_t)(128 + 60 * edge);
                f->voxels++;
            }
    return 0;
}

/* One size's figures; ns per voxel of the n^3 grid (the build visits every one). */
static json_t *size_json(const frag *f, int n, double build_ms, double cpu_ms, size_t nodes, int depth,
                         size_t bytes)
{
    double grid = (double)n * n * n;
    json_t *o = json_pack("{s:[iii],s:I}", "dim", n, n, n, "voxels", (json_int_t)f->voxels);
    if (!o)
        return NULL;
    json_object_set_new(o, "build_ms", jsonw_measure(build_ms));
    json_object_set_new(o, "build_cpu_ms", jsonw_measure(cpu_ms));
    json_object_set_new(o, "build_cpu_per_grid_voxel_ns", jsonw_measure(cpu_ms * 1e6 / grid));
    json_object_set_new(o, "nodes", json_integer((json_int_t)nodes));
    json_object_set_new(o, "depth", json_integer(depth));
    json_object_set_new(o, "tree_bytes", json_integer((json_int_t)bytes));
    json_object_set_new(o, "node_bytes", json_integer((json_int_t)sizeof(obb_node)));
    long rss = bench_peak_rss_kib();
    json_object_set_new(o, "rss_max_kib", rss > 0 ? json_integer(rss) : json_null());
    return o;
}

static int usage(FILE *out, int rc)
{
    fprintf(out, "usage: fracnav bench build [--json] [--reps R] [--max N] [--tau-min T] [--tau-max T]\n\n"
                 "Builds the hierarchy of bone-like fragments of 64^3 to 256^3 voxels and reports\n"
                 "the best of R builds (default 5) in wall and thread CPU time, nodes and tree bytes.\n"
                 "  --max N  the largest size (default 256): sizes up to N^3 only\n"
                 "  --json   one JSON object on stdout: {\"command\": \"bench build\", \"sizes\": [...]}\n"
                 "  --tau-min T, --tau-max T   hierarchy thresholds (default 0 and 1),\n"
                 "                             0 <= T_min <= T_max <= 1\n");
    return rc;
}

int bench_build(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv))
        return usage(stdout, 0);
    int json = 0, reps = 5, max = 256, rc;
    cmd_tau tau = {0};
    obb_params op = {0, 1};
    for (int i = 1; i < argc; i++) {
        char *end = NULL;
        if (cmd_tau_option("bench build", argv[i], i + 1 < argc ? argv[i + 1] : NULL, &tau, &rc)) {
            if (rc)
                return rc;
            i++;
        } else if (!strcmp(argv[i], "--json"))
            json = 1;
        else if (i + 1 < argc && !strcmp(argv[i], "--reps"))
            reps = (int)strtol(argv[++i], &end, 10);
        else if (!strcmp(argv[i], "--max")) {
            double d;
            const char *v = i + 1 < argc ? argv[++i] : NULL;
            if (!cmd_number(v, &d) || !(d >= 64 && d <= 256 && d == (int)d))
                return cmd_bad_value("bench build", "--max", v, "a whole number 64..256");
            max = (int)d;
        } else {
            fprintf(stderr, "fracnav bench build: unknown or incomplete option '%s'\n", argv[i]);
            return usage(stderr, 2);
        }
        if ((end && *end) || reps < 1 || reps > 100) {
            fprintf(stderr, "fracnav bench build: --reps needs 1..100\n");
            return 2;
        }
    }
    if (cmd_tau_apply(&tau, &op.tau_min, &op.tau_max) < 0)
        return cmd_usage_error("bench build", "%s", fn_err_msg());
    static const int sizes[] = {64, 96, 128, 160, 192, 224, 256};
    const int ns = (int)(sizeof sizes / sizeof sizes[0]);
    json_t *root = json ? jsonw_object("bench build") : NULL, *rows = json ? json_array() : NULL;
    if (json)
        jsonw_set(root, "sizes", rows);
    for (int s = 0; s < ns && sizes[s] <= max; s++) {
        frag f;
        if (fill_bone(&f, sizes[s])) {
            fprintf(stderr, "fracnav bench build: %s\n", fn_err_msg());
            json_decref(root);
            return 1;
        }
        double best = INFINITY, best_cpu = INFINITY;
        size_t nodes = 0, bytes = 0;
        int depth = 0;
        for (int r = 0; r < reps; r++) {
            double t0 = bench_now_us(), c0 = bench_cpu_us();
            obb_tree *t = obb_tree_build(&f, &op);
            double dt = (bench_now_us() - t0) / 1000, dc = (bench_cpu_us() - c0) / 1000;
            best_cpu = dc < best_cpu ? dc : best_cpu;
            if (!t) {
                fprintf(stderr, "fracnav bench build: %s\n", fn_err_msg());
                frag_free(&f);
                json_decref(root);
                return 1;
            }
            best = dt < best ? dt : best;
            nodes = obb_tree_nodes(t), bytes = obb_tree_bytes(t), depth = obb_tree_depth(t);
            obb_tree_free(t);
        }
        double vox = (double)sizes[s] * sizes[s] * sizes[s];
        if (json)
            json_array_append_new(rows, size_json(&f, sizes[s], best, best_cpu, nodes, depth, bytes));
        else
            printf("%3d^3: %9zu bone voxels, build %8.3f ms wall, %8.3f ms cpu (%.2f ns/voxel), "
                   "%8zu nodes, %9zu bytes\n",
                   sizes[s], f.voxels, best, best_cpu, best_cpu * 1e6 / vox, nodes, bytes);
        frag_free(&f);
    }
    if (json && jsonw_print(root, stdout) < 0) {
        fprintf(stderr, "fracnav bench build: %s\n", fn_err_msg());
        return 1;
    }
    return 0;
}
