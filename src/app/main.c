/* fracnav: the command-line front end, a dispatcher: each subcommand lives in cmd_<name>.c, the
 * helpers they share in cmd.c. */
#include "cmd.h"
#include "platform.h"
#include "sim_replay.h"

#include <stdio.h>
#include <string.h>

struct command {
    const char *name;
    int (*run)(int, char **);
    const char *help;
};

#define CMD_ROW(n, h) {#n, cmd_##n, h},
static const struct command commands[] = {CMD_LIST(CMD_ROW)};
#undef CMD_ROW

static void usage(FILE *out)
{
    fprintf(out, "usage: fracnav COMMAND [ARGS]   (fracnav COMMAND --help for each)\n"
                 "       fracnav --version        prints the version\n\n"
                 "Plan bone-fracture reductions: segment a CT into fragments, steer them with a\n"
                 "6-DOF controller under collision checking, and save the plan.\n\ncommands:\n");
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++) {
        char name[32];
        snprintf(name, sizeof name, "%s", commands[i].name);
        for (char *c = name; *c; c++)
            if (*c == '_')
                *c = '-';
        fprintf(out, "  %-12s %s\n", name, commands[i].help);
    }
}

int main(int argc, char **argv)
{
    /* malloc kept from faulting in every large array afresh: `reduce` on the demo's case took
     * about 9,500 page faults, 1,700 with it (docs/benchmarks.md) */
    platform_tune_malloc(argv);
    /* The virtual device and recordings are devices like any other: --device virtual:..., replay:... */
    sim_register_transports();
    if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help") || !strcmp(argv[1], "help")) {
        usage(stdout);
        return argc < 2 ? 2 : 0;
    }
    if (!strcmp(argv[1], "--version")) {
        printf("fracnav %s\n", FRACNAV_VERSION);
        return 0;
    }
    char want[64];
    snprintf(want, sizeof want, "%s", argv[1]);
    for (char *c = want; *c; c++)
        if (*c == '-')
            *c = '_';
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
        if (!strcmp(want, commands[i].name))
            return commands[i].run(argc - 1, argv + 1);
    fprintf(stderr, "fracnav: unknown command '%s' (see fracnav --help)\n", argv[1]);
    return 2;
}
