/* fracnav bench build: hierarchy build time and memory against volume size (linear growth). */
#include "bench.h"

#include "cmd.h"
#include "err.h"

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

static int usage(FILE *out, int rc)
{
    fprintf(out, "usage: fracnav bench build [--json] [--reps R] [--tau-min T] [--tau-max T]\n\n"
                 "Builds the hierarchy of bone-like fragments of 64^3 to 256^3 voxels and reports\n"
                 "the best of R builds (default 5) in wall and thread CPU time, nodes and tree bytes.\n"
                 "  --tau-min T, --tau-max T   hierarchy thresholds (default 0 and 1),\n"
                 "                             0 <= T_min <= T_max <= 1\n");
    return rc;
}

int bench_build(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv))
        return usage(stdout, 0);
    int json = 0, reps = 5, rc;
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
        else {
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
    if (json)
        printf("{\"sizes\": [\n");
    for (int s = 0; s < ns; s++) {
        frag f;
        if (fill_bone(&f, sizes[s])) {
            fprintf(stderr, "fracnav bench build: %s\n", fn_err_msg());
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
                return 1;
            }
            best = dt < best ? dt : best;
            nodes = obb_tree_nodes(t), bytes = obb_tree_bytes(t), depth = obb_tree_depth(t);
            obb_tree_free(t);
        }
        double vox = (double)sizes[s] * sizes[s] * sizes[s];
        if (json)
            printf("  {\"n\": %d, \"voxels\": %.0f, \"bone_voxels\": %zu, \"build_ms\": %.3f, "
                   "\"build_cpu_ms\": %.3f, \"ns_per_voxel\": %.3f, \"nodes\": %zu, \"depth\": %d, \"tree_bytes\": %zu, "
                   "\"bytes_per_node\": %zu, \"peak_rss_kib\": %ld}%s\n",
                   sizes[s], vox, f.voxels, best, best_cpu, best_cpu * 1e6 / vox, nodes, depth, bytes,
                   sizeof(obb_node), bench_peak_rss_kib(), s == ns - 1 ? "" : ",");
        else
            printf("%3d^3: %9zu bone voxels, build %8.3f ms wall, %8.3f ms cpu (%.2f ns/voxel), "
                   "%8zu nodes, %9zu bytes\n",
                   sizes[s], f.voxels, best, best_cpu, best_cpu * 1e6 / vox, nodes, bytes);
        frag_free(&f);
    }
    if (json)
        printf("]}\n");
    return 0;
}
