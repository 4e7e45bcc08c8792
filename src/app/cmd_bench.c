/* fracnav bench: dispatches to the benchmarks (bench_*.c). */
#include "bench.h"
#include "cmd.h"

#include <stdio.h>
#include <string.h>

static const struct {
    const char *name;
    int (*run)(int, char **);
    const char *help;
} benches[] = {
    {"collision", bench_collision, "OBB octree query vs brute force and FCL on fractured bones"},
    {"build", bench_build, "hierarchy build time and memory against volume size"},
    {"loop", bench_loop, "navigation loop rate and latency"},
    {"fracture", bench_fracture, "fractures made per seed and number of pieces, against the targets"},
    {"reduce", bench_reduce, "automatic reduction per method: success rate, errors, time"},
    {"separate", bench_separate, "bone and fragments of real fracture CTs against hand annotations"},
    {"render", bench_render, "renderer frame time per mode (OpenGL 4.5, OSMesa offscreen)"},
};

static void usage(FILE *out)
{
    fprintf(out, "usage: fracnav bench NAME [ARGS]   (fracnav bench NAME --help for each)\n\n"
                 "Benchmarks; --json prints one JSON object on stdout.\n\nbenchmarks:\n");
    for (size_t i = 0; i < sizeof benches / sizeof benches[0]; i++)
        fprintf(out, "  %-10s %s\n", benches[i].name, benches[i].help);
}

int cmd_bench(int argc, char **argv)
{
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    if (!strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
        usage(stdout);
        return 0;
    }
    for (size_t i = 0; i < sizeof benches / sizeof benches[0]; i++)
        if (!strcmp(argv[1], benches[i].name))
            return benches[i].run(argc - 1, argv + 1);
    fprintf(stderr, "fracnav bench: unknown benchmark '%s'\n", argv[1]);
    usage(stderr);
    return 2;
}
