/* fracnav record: raw reports from a controller (real or virtual) into a .fnrec file. */
#include "cmd.h"

#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "dev.h"
#include "devtab.h"
#include "err.h"
#include "fnrec.h"
#include "sim_replay.h"

#define SLICE_MS 50    /* read timeout: how quickly SIGINT and --seconds are noticed */
#define RETRY_US 100000 /* how often a lost device is looked for again */

static volatile sig_atomic_t stop;

static void on_signal(int sig)
{
    stop = sig;
}

static void usage(FILE *f)
{
    fprintf(f, "usage: fracnav record -o FILE.fnrec [--device SPEC] [--seconds S]\n"
               "\n"
               "Records every raw report of a 6-DOF controller, with its arrival time, until Ctrl-C\n"
               "or S seconds. Each line is flushed as it is written. A device that goes away is\n"
               "recorded as a disconnect and picked up again when it returns.\n"
               "  SPEC  a hidraw node (/dev/hidraw3, or one served by fracnav-sim), or TRANSPORT:ARG\n"
               "        (hidraw:PATH, virtual:spacenavigator:script=FILE, replay:FILE.fnrec, ...);\n"
               "        default: the first supported HID device.\n");
}

typedef struct recorder {
    const dev_transport *t;
    const char *arg; /* the transport's path, NULL = first found */
    dev_handle *h;
    fnrec_writer *w;
    int64_t base_us; /* monotonic time of t = 0 (0 for replays, whose times are recorded ones) */
    int64_t end_us;  /* deadline, 0 = none */
    int64_t last_t;
    unsigned long reports;
} recorder;

static int resolve(const char *spec, recorder *r)
{
    return dev_spec_resolve(spec, &r->t, &r->arg);
}

static int is_replay(const recorder *r)
{
    return !strncmp(r->t->name, "replay", 6);
}

static void header_of(recorder *r, fnrec_header *hd)
{
    dev_info info;
    memset(hd, 0, sizeof *hd);
    memset(&info, 0, sizeof info);
    if (r->t->info)
        r->t->info(r->h, &info);
    hd->vid = info.vid;
    hd->pid = info.pid;
    snprintf(hd->name, sizeof hd->name, "%s", info.name[0] ? info.name : "unknown device");
    for (char *c = hd->name; *c; c++)
        if (*c == '\n' || *c == '\r')
            *c = ' ';
    const devtab_row *row = devtab_find(info.vid, info.pid);
    snprintf(hd->format, sizeof hd->format, "%s",
             row && row->format != DEVTAB_COMBINED ? "split" : "combined");
    snprintf(hd->source, sizeof hd->source, "%s:%.100s", r->t->name,
             info.path[0] ? info.path : r->arg ? r->arg : "first device");
    memcpy(hd->desc, info.desc, info.desc_len);
    hd->desc_len = info.desc_len;
}

static int put(recorder *r, fnrec_dir dir, int64_t t_us, const uint8_t *b, int n)
{
    fnrec_event e = {.t_us = t_us - r->base_us, .dir = dir, .len = (uint8_t)n};
    if (e.t_us < 0)
        e.t_us = 0;
    if (n)
        memcpy(e.data, b, (size_t)n);
    return fnrec_writer_event(r->w, &e);
}

static int time_left(const recorder *r)
{
    return !stop && (!r->end_us || dev_now_us() < r->end_us);
}

/* After an unplug: looks for the device again until it returns or time is up. */
static int reconnect(recorder *r)
{
    while (time_left(r)) {
        int64_t next = dev_now_us() + RETRY_US;
        if (r->t->open(r->arg, &r->h) == 0) {
            fprintf(stderr, "fracnav record: device reconnected\n");
            return put(r, FNREC_CONNECT, dev_now_us(), NULL, 0);
        }
        while (time_left(r) && dev_now_us() < next)
            nanosleep(&(struct timespec){0, 10000000}, NULL);
    }
    return 0;
}

static int record_loop(recorder *r)
{
    uint8_t buf[DEV_REPORT_MAX];
    while (time_left(r)) {
        if (!r->h) {
            int rc = reconnect(r);
            if (rc || !r->h)
                return rc;
        }
        int64_t t = r->last_t;
        int n = r->t->read(r->h, buf, sizeof buf, SLICE_MS, &t);
        if (n > 0) {
            r->reports++;
            r->last_t = t;
            int rc = put(r, FNREC_IN, t, buf, n);
            if (rc)
                return rc;
        } else if (n == FN_ENODEV && stop) {
            break; /* the read was interrupted by Ctrl-C: no unplug */
        } else if (n == FN_ENODEV) {
            fprintf(stderr, "fracnav record: device disconnected (%s)\n", fn_err_msg());
            if (is_replay(r)) { /* a replay goes on after a recorded unplug, until its end */
                if (sim_replay_finished(r->h))
                    return 0;
                int rc = put(r, FNREC_DISCONNECT, r->last_t, NULL, 0);
                if (rc)
                    return rc;
                continue;
            }
            r->t->close(r->h);
            r->h = NULL;
            int rc = put(r, FNREC_DISCONNECT, dev_now_us(), NULL, 0);
            if (rc)
                return rc;
        } else if (n < 0) {
            return n;
        }
    }
    return 0;
}

static int parse_args(int argc, char **argv, const char **out, const char **device, double *seconds)
{
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "-o") && strcmp(a, "--device") && strcmp(a, "--seconds")) {
            fprintf(stderr, "fracnav record: unknown option '%s' (see --help)\n", a);
            return 2;
        }
        if (!v) {
            fprintf(stderr, "fracnav record: %s needs a value\n", a);
            return 2;
        }
        i++;
        if (!strcmp(a, "-o")) {
            *out = v;
        } else if (!strcmp(a, "--device")) {
            *device = v;
        } else {
            char *end;
            *seconds = strtod(v, &end);
            if (*end || end == v || !(*seconds > 0 && *seconds < 1e7)) {
                fprintf(stderr, "fracnav record: --seconds wants a positive number, got '%s'\n", v);
                return 2;
            }
        }
    }
    if (!*out) {
        fprintf(stderr, "fracnav record: -o FILE.fnrec is required (see --help)\n");
        return 2;
    }
    return 0;
}

int cmd_record(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    const char *out = NULL, *device = NULL;
    double seconds = 0;
    int rc = parse_args(argc, argv, &out, &device, &seconds);
    if (rc)
        return rc;
    /* From the start: a Ctrl-C as soon as the device is open still ends in a whole recording. */
    struct sigaction sa = {.sa_handler = on_signal};
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    recorder r = {0};
    if (resolve(device, &r) || r.t->open(r.arg, &r.h)) {
        fprintf(stderr, "fracnav record: %s\n", fn_err_msg());
        return 1;
    }
    r.base_us = is_replay(&r) ? 0 : dev_now_us();
    r.end_us = seconds > 0 ? dev_now_us() + (int64_t)(seconds * 1e6) : 0;
    fnrec_header hd;
    header_of(&r, &hd);
    if (!(r.w = fnrec_writer_open(out, &hd)) || put(&r, FNREC_CONNECT, r.base_us, NULL, 0)) {
        fprintf(stderr, "fracnav record: %s\n", fn_err_msg());
        r.t->close(r.h);
        fnrec_writer_close(r.w);
        return 1;
    }
    rc = record_loop(&r);
    if (rc)
        fprintf(stderr, "fracnav record: %s\n", fn_err_msg());
    if (r.h)
        r.t->close(r.h);
    if (fnrec_writer_close(r.w) && !rc) {
        fprintf(stderr, "fracnav record: %s\n", fn_err_msg());
        rc = FN_EIO;
    }
    fprintf(stderr, "fracnav record: %lu reports written to %s\n", r.reports, out);
    return rc ? 1 : 0;
}
