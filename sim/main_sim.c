/* fracnav-sim: the virtual 6-DOF controller's command line: serve (hidfuse.h), render, list,
 * bench (bench_sim.h). */
#include <ctype.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_sim.h"
#include "durable.h"
#include "err.h"
#include "fnclock.h"
#include "fnrec.h"
#include "hidfuse.h"
#include "script.h"
#include "simdev.h"

/* ---- command line ---- */

/* "fracnav-sim SUB: MESSAGE (see fracnav-sim SUB --help)" on stderr, as fracnav's commands say it;
 * returns 2, the usage exit. */
static int FN_PRINTF(2, 3) sim_usage_error(const char *sub, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "fracnav-sim %s: ", sub);
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, " (see fracnav-sim %s --help)\n", sub);
    va_end(ap);
    return 2;
}

/* Each subcommand's help: its usage line and what it does. */
static const struct sub_help {
    const char *name, *synopsis, *text;
} sub_help[] = {
    {"serve",
     "fracnav-sim serve --mount DIR [--as DEVICE] [--play FILE.fnrec | --script FILE]\n"
     "                         [--start-on-read] [--fast] [--exit-at-end] [--log FILE.fnrec]\n"
     "                         [--control FIFO] [--serial SN]\n",
     "Serves the virtual device as DIR/" HIDFUSE_NODE " through FUSE until SIGINT/SIGTERM (then\n"
     "unmounts). SIGUSR1 unplugs it, the next SIGUSR1 plugs it back. A DIR that is already a mount\n"
     "point (another server's, or one starting at once) is refused; a killed server's dead mount\n"
     "there is removed first.\n"
     "  --mount DIR      the folder to serve the node in (required)\n"
     "  --as DEVICE      device to impersonate, by name or VID:PID (default spacenavigator;\n"
     "                   fracnav-sim list shows every row of the table)\n"
     "  --play FILE      play a recording (its identity replaces --as)\n"
     "  --script FILE    play a motion script (see sim/FNREC.md)\n"
     "  --start-on-read  start playing when the node is first read or polled\n"
     "  --fast           play as fast as the readers read (implies --start-on-read); fracnav\n"
     "                   record keeps the device's cadence in its timestamps all the same\n"
     "  --exit-at-end    unmount and exit once the playback is over and read\n"
     "  --log FILE       write every report served to a .fnrec file (not in a case folder)\n"
     "  --control FIFO   script lines written to this FIFO (made if absent) play in turn, as\n"
     "                   soon as possible: echo 'press 1' > FIFO\n"
     "  --serial SN      serial number served (HIDIOCGRAWUNIQ; 8-32 characters; default\n"
     "                   FNSIM + VID + PID)\n"},
    {"render", "fracnav-sim render [--as DEVICE] --script FILE -o FILE.fnrec\n",
     "Writes the reports a motion script produces on DEVICE (default spacenavigator) to a .fnrec\n"
     "file (never one in a case folder, whose files only fracnav's saves write).\n"},
    {"list", "fracnav-sim list\n", "Prints the devices the simulator can impersonate.\n"},
    {"bench", "fracnav-sim bench [--mount DIR] [--seconds S]\n",
     "Measures report throughput (as fast as possible) and timing jitter (at the 8 ms cadence,\n"
     "S seconds, 0.1 to 600, default 2) through FUSE and hidapi; prints one JSON object:\n"
      "command, path, throughput (reports, report_hz), cadence (device, period_us, reports,\n"
      "deviation_mean_us/p99_us/max_us, drift_us).\n"},
};

#define N_SUBS (sizeof sub_help / sizeof *sub_help)

/* sub: one subcommand's help, NULL for all of them. */
static void usage(FILE *f, const char *sub)
{
    for (size_t i = 0; i < N_SUBS; i++)
        if (!sub || !strcmp(sub, sub_help[i].name))
            fprintf(f, "%s%s", i && !sub ? "       " : "usage: ", sub_help[i].synopsis);
    if (!sub)
        fprintf(f, "       fracnav-sim --version\n\n"
                   "The virtual 6-DOF controller of fracnav (fracnav-sim SUBCOMMAND --help for each).\n");
    for (size_t i = 0; i < N_SUBS; i++)
        if (!sub || !strcmp(sub, sub_help[i].name))
            fprintf(f, "\n%s%s%s", sub ? "" : sub_help[i].name, sub ? "" : ":\n", sub_help[i].text);
}

static int list_devices(void)
{
    for (size_t i = 0; sim_profile_at(i); i++) {
        const sim_profile *p = sim_profile_at(i);
        printf("%-34s %04x:%04x  %-8s %2d ms  %2d button bits  %s\n", p->id, p->vid, p->pid,
               devtab_format_name(p->row->format), p->period_us / 1000, p->nbuttons,
               p->name);
    }
    return 0;
}

typedef struct opts {
    const char *mount, *as, *play, *script, *out, *log, *seconds, *control, *serial;
    int start_on_read, fast, exit_at_end;
} opts;

enum { SERVE = 1, RENDER = 2, BENCH = 4 };

/* Each option and the commands it applies to: any other is a usage error that names it. */
static const struct option_def {
    const char *name;
    unsigned cmds;
    size_t field; /* offsetof(opts, ...): a const char * for options with a value, else an int flag */
    int is_flag;
} option_defs[] = {
    {"--mount", SERVE | BENCH, offsetof(opts, mount), 0},
    {"--as", SERVE | RENDER, offsetof(opts, as), 0},
    {"--play", SERVE, offsetof(opts, play), 0},
    {"--script", SERVE | RENDER, offsetof(opts, script), 0},
    {"-o", RENDER, offsetof(opts, out), 0},
    {"--log", SERVE, offsetof(opts, log), 0},
    {"--seconds", BENCH, offsetof(opts, seconds), 0},
    {"--control", SERVE, offsetof(opts, control), 0},
    {"--serial", SERVE, offsetof(opts, serial), 0},
    {"--start-on-read", SERVE, offsetof(opts, start_on_read), 1},
    {"--fast", SERVE, offsetof(opts, fast), 1},
    {"--exit-at-end", SERVE, offsetof(opts, exit_at_end), 1},
};

static unsigned command_bit(const char *cmd)
{
    return !strcmp(cmd, "serve") ? SERVE : !strcmp(cmd, "render") ? RENDER : BENCH;
}

/* firmware-spec/open-controller.md, 1: a serial number is 8-32 characters. */
static int serial_ok(const char *s)
{
    size_t n = strlen(s);
    if (n < 8 || n >= SIMDEV_SERIAL_MAX)
        return 0;
    for (; *s; s++)
        if (!isalnum((unsigned char)*s) && *s != '-' && *s != '_')
            return 0;
    return 1;
}

static int parse_opts(int argc, char **argv, opts *o)
{
    unsigned cmd = command_bit(argv[1]);
    for (int i = 2; i < argc; i++) {
        const char *a = argv[i];
        const struct option_def *d = NULL;
        for (size_t k = 0; k < sizeof option_defs / sizeof *option_defs && !d; k++)
            d = !strcmp(a, option_defs[k].name) ? &option_defs[k] : NULL;
        if (!d) {
            return sim_usage_error(argv[1], "unknown option '%s'", a);
        }
        if (!(d->cmds & cmd)) {
            return sim_usage_error(argv[1], "option '%s' does not apply to %s", a, argv[1]);
        }
        if (d->is_flag) {
            *(int *)((char *)o + d->field) = 1;
            continue;
        }
        if (i + 1 >= argc) {
            return sim_usage_error(argv[1], "%s needs a value", a);
        }
        *(const char **)((char *)o + d->field) = argv[++i];
    }
    o->start_on_read |= o->fast;
    if (o->serial && !serial_ok(o->serial)) {
        return sim_usage_error(argv[1], "--serial '%s': want 8 to 32 letters, digits, '-' or '_'", o->serial);
    }
    if (o->play && o->script) {
        return sim_usage_error(argv[1], "--play and --script exclude each other");
    }
    return 0;
}

/* The recording the device plays: a file, a rendered script, or nothing (an idle device). */
static fnrec *load_source(const opts *o, hidfuse_source *src)
{
    if (o->play)
        return fnrec_load(o->play);
    if (o->script ? !(src->script = script_load(o->script)) : script_parse("", 0, "", &src->script) != 0)
        return NULL;
    return script_render(src->script, src->p);
}

/* The device and what it plays; a recording plays as the device it was recorded from. */
static int setup(const opts *o, hidfuse_source *src)
{
    memset(src, 0, sizeof *src);
    if (!(src->p = sim_profile_find(o->as ? o->as : "spacenavigator")) || !(src->rec = load_source(o, src)))
        return -1;
    if (o->play) {
        char id[16];
        snprintf(id, sizeof id, "%04x:%04x", src->rec->hdr.vid, src->rec->hdr.pid);
        const sim_profile *p = sim_profile_find(id);
        if (o->as && p != src->p)
            fprintf(stderr, "fracnav-sim serve: warning: --as %s ignored: %s plays as the device it was "
                            "recorded from, %s (%s)\n", o->as, o->play, id, src->rec->hdr.name);
        src->p = p ? p : src->p;
        src->id = src->rec->hdr;
    } else {
        script_header(src->p, &src->id);
    }
    src->serial = o->serial ? o->serial : src->p->serial;
    src->start_on_read = o->start_on_read;
    src->fast = o->fast;
    src->exit_at_end = o->exit_at_end;
    /* a recording is never written into a case folder, as fracnav's own outputs */
    if (o->log && (durable_out_of_case(o->log) < 0 || !(src->log = fnrec_writer_open(o->log, &src->id))))
        return -1;
    return 0;
}

int main(int argc, char **argv)
{
    if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help") || !strcmp(argv[1], "help")) {
        usage(argc < 2 ? stderr : stdout, NULL);
        return argc < 2 ? 2 : 0;
    }
    if (!strcmp(argv[1], "--version")) {
        printf("fracnav-sim %s\n", FRACNAV_VERSION);
        return 0;
    }
    const char *cmd = argv[1];
    if (strcmp(cmd, "serve") && strcmp(cmd, "render") && strcmp(cmd, "bench") && strcmp(cmd, "list")) {
        fprintf(stderr, "fracnav-sim: unknown command '%s': serve, render, list or bench (see fracnav-sim "
                        "--help)\n", cmd);
        return 2;
    }
    for (int i = 2; i < argc; i++)
        if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            usage(stdout, cmd);
            return 0;
        }
    if (!strcmp(cmd, "list"))
        return argc > 2 ? sim_usage_error(cmd, "unexpected argument '%s'", argv[2]) : list_devices();
    opts o = {0};
    if (parse_opts(argc, argv, &o))
        return 2; /* said by parse_opts */
    if (!strcmp(cmd, "bench")) {
        char *end = NULL;
        double secs = o.seconds ? strtod(o.seconds, &end) : 2.0;
        if ((end && (*end || end == o.seconds)) || !(secs >= 0.1 && secs <= 600))
            return sim_usage_error(cmd, "--seconds wants a number from 0.1 to 600, got '%s'", o.seconds);
        return bench_sim_run(o.mount, secs);
    }
    if (!strcmp(cmd, "render") ? !o.script || !o.out : !o.mount) {
        return sim_usage_error(cmd, "%s is required", !strcmp(cmd, "render") ? "--script FILE and -o FILE"
                                                                            : "--mount DIR");
    }
    hidfuse_source src;
    if (o.out && durable_out_of_case(o.out) < 0) { /* render -o, before the work */
        fprintf(stderr, "fracnav-sim %s: %s\n", cmd, fn_err_msg());
        return 1;
    }
    if (setup(&o, &src)) {
        fprintf(stderr, "fracnav-sim %s: %s\n", cmd, fn_err_msg());
        fnrec_free(src.rec);
        free(src.script);
        return 1;
    }
    if (strcmp(cmd, "render"))
        return hidfuse_serve(o.mount, o.control, &src);
    int rc = fnrec_save(src.rec, o.out) ? (fprintf(stderr, "fracnav-sim render: %s\n", fn_err_msg()), 1) : 0;
    fnrec_free(src.rec);
    free(src.script);
    return rc;
}
