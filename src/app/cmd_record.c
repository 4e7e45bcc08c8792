/* fracnav record: raw reports from a controller (real or virtual) into a .fnrec file. */
#include "cmd.h"

#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "dev.h"
#include "devparse.h"
#include "devtab.h"
#include "err.h"
#include "fnclock.h"
#include "fnrec.h"
#include "sim_replay.h"
#include "simdev.h"

#define SLICE_MS 50    /* read timeout: how quickly SIGINT and --seconds are noticed */
#define RETRY_US 100000 /* how often a lost device is looked for again */
#define PROGRESS_US 200000 /* how often the progress line is redrawn on a terminal */

/* Set by the signal handler, which may run on another thread (the keyboard device raises SIGINT for
 * q on the input thread): a lock-free atomic, so the main thread reads it without a data race. */
static atomic_int stop;

static void on_signal(int sig)
{
    stop = sig;
}

static void usage(FILE *f)
{
    fprintf(f, "usage: fracnav record -o FILE.fnrec [--device SPEC] [--seconds S] [--wait-replug]\n"
               "\n"
               "Records every raw report of a 6-DOF controller, with its arrival time, into FILE.fnrec\n"
               "(sim/FNREC.md). Each line is flushed as it is written. It stops after S seconds, on\n"
               "Ctrl-C (keeping what was recorded), at the end of a script or recording, and when the\n"
               "device goes away (recorded as a disconnect). On a terminal it shows its progress.\n"
               "\n"
               "  -o FILE.fnrec   the recording to write (required)\n"
               "  --device SPEC   a hidraw node (/dev/hidraw3, or one served by fracnav-sim), or\n"
               "                  TRANSPORT:ARG (hidraw:PATH, virtual:spacenavigator:script=FILE,\n"
               "                  replay:FILE.fnrec, ...); default: the first supported HID device\n"
               "  --seconds S     stop after S seconds (default: no limit)\n"
               "  --wait-replug   when the device goes away, wait for it to return and record on\n"
               "                  (until S seconds or Ctrl-C) instead of stopping\n"
               "\n"
               "Timestamps keep the device's report cadence: reports that arrive faster than the\n"
               "device can send them (a slow reader's backlog, fracnav-sim --fast) are spaced at it.\n");
}

typedef struct recorder {
    const dev_transport *t;
    const char *arg; /* the transport's path, NULL = first found */
    dev_handle *h;
    fnrec_writer *w;
    int64_t base_us; /* monotonic time of t = 0 (0 for replays, whose times are recorded ones) */
    int64_t end_us;  /* deadline, 0 = none */
    int64_t last_t;
    int64_t written_us;  /* recording time of the last event written */
    int64_t cadence_us;  /* the device's report period: reports are never closer (0 = unknown) */
    int64_t last_report; /* recording time of the last input report */
    int wait_replug, tty, squeezed;
    int64_t start_us, next_progress;
    const char *out;
    unsigned long reports;
} recorder;

static int resolve(const char *spec, recorder *r)
{
    return dev_spec_resolve(spec, &r->t, &r->arg);
}

static int is_replay(const recorder *r)
{
    return (r->t->caps & DEV_CAP_RECORDING) != 0;
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

/* Writes one event at monotonic time t_us. Recording time never goes back, and a pause longer
 * than the format allows (FNREC_MAX_GAP_US: a long wait for a replug) is shortened to it. */
static int put(recorder *r, fnrec_dir dir, int64_t t_us, const uint8_t *b, int n)
{
    fnrec_event e = {.t_us = t_us - r->base_us, .dir = dir, .len = (uint8_t)n};
    if (e.t_us < r->written_us)
        e.t_us = r->written_us;
    if (e.t_us - r->written_us > FNREC_MAX_GAP_US) {
        r->base_us += e.t_us - r->written_us - FNREC_MAX_GAP_US;
        e.t_us = r->written_us + FNREC_MAX_GAP_US;
    }
    if (n)
        memcpy(e.data, b, (size_t)n);
    r->written_us = e.t_us;
    return fnrec_writer_event(r->w, &e);
}

/* An input report arriving at t_us. A device sends at most one report per period of its cadence
 * (the USB polling interval), so reports that arrive closer together (a backlog drained at once,
 * or fracnav-sim --fast, which sends as fast as they are read) are put at the cadence: the
 * recording replays at the device's own pace. */
static int put_report(recorder *r, int64_t t_us, const uint8_t *b, int n)
{
    int64_t t = t_us - r->base_us;
    if (r->cadence_us && r->reports > 1 && t < r->last_report + r->cadence_us) {
        /* jitter of a few ms is normal; half a period early is not */
        if (t < r->last_report + r->cadence_us / 2 && !r->squeezed++)
            fprintf(stderr, "%sfracnav record: reports arrive faster than the device's %.0f ms cadence "
                            "(a backlog, or fracnav-sim --fast): their times follow the cadence\n",
                    r->tty ? "\n" : "", (double)r->cadence_us / 1000);
        t = r->last_report + r->cadence_us;
    }
    r->last_report = t;
    return put(r, FNREC_IN, t + r->base_us, b, n);
}

/* The device's report period: the open controller says it (feature report 0x22, cadence_ms), the
 * others have the period of their table row (the simulator's profile). 0 when unknown. */
static int64_t cadence_of(recorder *r, const fnrec_header *hd)
{
    uint8_t buf[DEV_REPORT_MAX] = {DEVPARSE_FEAT_SETTINGS};
    const devtab_row *row = devtab_find(hd->vid, hd->pid);
    if (row && (row->flags & DEVTAB_F_OPEN) && r->t->get_feature && r->t->get_feature(r->h, buf, sizeof buf) >= 2 &&
        buf[0] == DEVPARSE_FEAT_SETTINGS && buf[1])
        return (int64_t)buf[1] * 1000;
    char id[16];
    snprintf(id, sizeof id, "%04x:%04x", hd->vid, hd->pid);
    const sim_profile *p = row ? sim_profile_find(id) : NULL;
    fn_err_clear();
    return p ? p->period_us : 0;
}

static void progress(recorder *r, int last)
{
    int64_t now = fnclock_now_us();
    if (!r->tty || (!last && now < r->next_progress))
        return;
    r->next_progress = now + PROGRESS_US;
    fprintf(stderr, "\rrecording %s: %lu reports, %.1f s%s", r->out, r->reports,
            (double)(now - r->start_us) / 1e6, last ? "\n" : "   ");
}

static int time_left(const recorder *r)
{
    return !stop && (!r->end_us || fnclock_now_us() < r->end_us);
}

/* After an unplug: looks for the device again until it returns or time is up. */
static int reconnect(recorder *r)
{
    while (time_left(r)) {
        int64_t next = fnclock_now_us() + RETRY_US;
        if (r->t->open(r->arg, &r->h) == 0) {
            fprintf(stderr, "fracnav record: device reconnected\n");
            return put(r, FNREC_CONNECT, fnclock_now_us(), NULL, 0);
        }
        while (time_left(r) && fnclock_now_us() < next)
            fnclock_sleep_us(10000);
    }
    return 0;
}

/* The device went away: a replay goes on after a recorded unplug until its end; any other device
 * stops the recording, unless --wait-replug asks to wait for it. 1 = stop. */
static int unplugged(recorder *r, int *rc)
{
    fprintf(stderr, "%sfracnav record: device disconnected (%s)%s\n", r->tty ? "\n" : "", fn_err_msg(),
            r->wait_replug || is_replay(r) ? "" : ": recording stopped (--wait-replug waits for it)");
    if (is_replay(r)) {
        if (r->t->finished && r->t->finished(r->h))
            return 1;
        *rc = put(r, FNREC_DISCONNECT, r->last_t, NULL, 0);
        return *rc != 0;
    }
    r->t->close(r->h);
    r->h = NULL;
    *rc = put(r, FNREC_DISCONNECT, fnclock_now_us(), NULL, 0);
    return *rc != 0 || !r->wait_replug;
}

static int record_loop(recorder *r)
{
    uint8_t buf[DEV_REPORT_MAX];
    while (time_left(r)) {
        progress(r, 0);
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
            int rc = is_replay(r) ? put(r, FNREC_IN, t, buf, n) : put_report(r, t, buf, n);
            if (rc)
                return rc;
        } else if (n == FN_ENODEV && stop) {
            break; /* the read was interrupted by Ctrl-C: no unplug */
        } else if (n == 0 && r->t->finished && r->t->finished(r->h)) {
            fprintf(stderr, "%sfracnav record: end of the virtual device's script\n", r->tty ? "\n" : "");
            return 0;
        } else if (n == FN_ENODEV) {
            int rc = 0;
            if (unplugged(r, &rc))
                return rc;
        } else if (n < 0) {
            return n;
        }
    }
    return 0;
}

static int parse_args(int argc, char **argv, recorder *r, const char **device, double *seconds)
{
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--wait-replug")) {
            r->wait_replug = 1;
            continue;
        }
        if (strcmp(a, "-o") && strcmp(a, "--device") && strcmp(a, "--seconds"))
            return cmd_usage_error("record", "unknown option '%s'", a);
        if (!v)
            return cmd_usage_error("record", "%s needs a value", a);
        i++;
        if (!strcmp(a, "-o")) {
            r->out = v;
        } else if (!strcmp(a, "--device")) {
            *device = v;
        } else if (!cmd_number(v, seconds) || !(*seconds > 0 && *seconds < 1e7)) {
            return cmd_usage_error("record", "--seconds wants a positive number, got '%s'", v);
        }
    }
    if (!r->out)
        return cmd_usage_error("record", "-o FILE.fnrec is required");
    return 0;
}

int cmd_record(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    const char *device = NULL;
    double seconds = 0;
    recorder r = {0};
    int rc = parse_args(argc, argv, &r, &device, &seconds);
    if (rc)
        return rc;
    if (cmd_out_file(r.out, NULL) < 0) {
        fprintf(stderr, "fracnav record: -o %s\n", fn_err_msg());
        return 1;
    }
    /* From the start: a Ctrl-C as soon as the device is open still ends in a whole recording. */
    struct sigaction sa = {.sa_handler = on_signal};
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    if (resolve(device, &r) || r.t->open(r.arg, &r.h)) {
        fprintf(stderr, "fracnav record: %s\n", fn_err_msg());
        return 1;
    }
    r.start_us = fnclock_now_us();
    r.base_us = is_replay(&r) ? 0 : r.start_us;
    r.end_us = seconds > 0 ? fnclock_now_us() + (int64_t)(seconds * 1e6) : 0;
    r.tty = isatty(STDERR_FILENO);
    fnrec_header hd;
    header_of(&r, &hd);
    r.cadence_us = is_replay(&r) ? 0 : cadence_of(&r, &hd);
    if (!(r.w = fnrec_writer_open(r.out, &hd)) || put(&r, FNREC_CONNECT, r.base_us, NULL, 0)) {
        fprintf(stderr, "fracnav record: %s\n", fn_err_msg());
        r.t->close(r.h);
        fnrec_writer_close(r.w);
        return 1;
    }
    rc = record_loop(&r);
    progress(&r, 1);
    if (rc)
        fprintf(stderr, "fracnav record: %s\n", fn_err_msg());
    if (r.h)
        r.t->close(r.h);
    if (fnrec_writer_close(r.w) && !rc) {
        fprintf(stderr, "fracnav record: %s\n", fn_err_msg());
        rc = FN_EIO;
    }
    fprintf(stderr, "fracnav record: %lu reports written to %s%s\n", r.reports, r.out,
            stop == SIGINT ? " (stopped by Ctrl-C)" : "");
    return rc ? 1 : 0;
}
