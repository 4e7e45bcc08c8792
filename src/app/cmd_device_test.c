/* fracnav device-test: a live text view of a controller's axes and buttons, raw and calibrated. */
#include "cmd.h"

#include <math.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "calib.h"
#include "dev.h"
#include "err.h"
#include "fnclock.h"

#define LINES_PER_S 10 /* when not on a terminal: at most this many lines a second */

/* Set by the signal handler, which may run on another thread (the keyboard device raises SIGINT for
 * q on the input thread): a lock-free atomic, so the main thread reads it without a data race. */
static atomic_int stop;

static void on_signal(int sig)
{
    stop = 1;
}

static void usage(FILE *out)
{
    fprintf(out, "usage: fracnav device-test [--device SPEC] [--seconds S] [--config SPNAVRC]\n"
                 "                           [--calibrate-zero]\n\n"
                 "Shows a controller's six axes (normalized, then calibrated), buttons by name, battery\n"
                 "and report rate, live, until Ctrl-C or S seconds.\n\n"
                 "  --device SPEC     auto (default), a hidraw path such as /dev/hidraw0, serial:SN,\n"
                 "                    spnav, keyboard, replay:FILE, virtual:DEVICE, ...\n"
                 "  --seconds S       stop after S seconds (with --calibrate-zero: measure S seconds)\n"
                 "  --config SPNAVRC  the calibration to show (and save to); default\n"
                 "                    ~/.config/fracnav/spnavrc, else /etc/spnavrc\n"
                 "  --calibrate-zero  with the cap released, measure the rest position for S seconds\n"
                 "                    (default 1) and save it as the zero offset (against drift) to\n"
                 "                    --config, or ~/.config/fracnav/spnavrc, keeping the file's other\n"
                 "                    lines and comments; an open controller stores it itself (feature\n"
                 "                    report 0x21) and the file gets 0\n");
}

static void count_report(void *ctx, const uint8_t *report, size_t len, int64_t t_us)
{
    ++*(long *)ctx;
}

/* The names of the buttons set in mask ("ENTER,FIT", "B1,B2"), "-" for none. */
static void button_names(FILE *out, const devtab_row *row, uint32_t mask)
{
    char buf[16];
    int any = 0;
    for (int b = 0; b < 32; b++)
        if (mask >> b & 1)
            fprintf(out, "%s%s", any++ ? "," : "", devtab_button_name(row, b, buf, sizeof buf));
    if (!any)
        fputc('-', out);
}

static void show(FILE *out, const devtab_row *row, const dev_event *ev, const float cal[6], int battery,
                 double rate, int tty)
{
    static const char *const names[6] = {"x", "y", "z", "rx", "ry", "rz"};
    fprintf(out, "%s", tty ? "\r" : "");
    for (int i = 0; i < 6; i++)
        fprintf(out, "%s %+5.2f>%+5.2f ", names[i], ev->axis[i], cal[i]);
    fprintf(out, "| buttons ");
    button_names(out, row, ev->buttons);
    if (ev->pressed) {
        fprintf(out, " (pressed ");
        button_names(out, row, ev->pressed);
        fputc(')', out);
    }
    if (ev->released) {
        fprintf(out, " (released ");
        button_names(out, row, ev->released);
        fputc(')', out);
    }
    for (int i = 0, shown = 0; i < 6 && ev->keys[i]; i++) { /* key codes that are no button */
        if (devtab_key_button(ev->keys[i]) >= 0)
            continue;
        const char *name = devtab_key_name(ev->keys[i]);
        fprintf(out, "%s", shown++ ? "," : " | keys ");
        if (name)
            fputs(name, out);
        else
            fprintf(out, "code %u", ev->keys[i]);
    }
    if (battery >= 0)
        fprintf(out, " | battery %d%%", battery);
    if (rate < 0) /* the first second: not measured yet */
        fprintf(out, " | - reports/s%s", tty ? "   " : "\n");
    else
        fprintf(out, " | %.0f reports/s%s", rate, tty ? "   " : "\n");
    fflush(out);
}

typedef struct opts {
    const char *spec, *config;
    double seconds;
    int zero;
} opts;

/* The value of option argv[*i]: the next argument, unless there is none or it is another option. */
static const char *value_of(int argc, char **argv, int *i)
{
    if (*i + 1 >= argc || !strncmp(argv[*i + 1], "--", 2)) {
        cmd_usage_error("device-test", "%s wants a value%s%s", argv[*i], *i + 1 < argc ? ", got option " : "",
                        *i + 1 < argc ? argv[*i + 1] : "");
        return NULL;
    }
    return argv[++*i];
}

static int parse_args(int argc, char **argv, opts *o)
{
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = NULL;
        int valued = !strcmp(a, "--device") || !strcmp(a, "--config") || !strcmp(a, "--seconds");
        if (valued && !(v = value_of(argc, argv, &i)))
            return 2;
        if (!strcmp(a, "--calibrate-zero"))
            o->zero = 1;
        else if (!strcmp(a, "--device"))
            o->spec = v;
        else if (!strcmp(a, "--config"))
            o->config = v;
        else if (!strcmp(a, "--seconds")) {
            if (!cmd_number(v, &o->seconds) || !(o->seconds > 0) || o->seconds > 1e6)
                return cmd_usage_error("device-test", "--seconds wants a positive number, got '%s'", v);
        } else {
            return cmd_usage_error("device-test", "unknown or incomplete option '%s'", a);
        }
    }
    return 0;
}

/* new_ok: a named file that does not exist yet is fine (it is about to be written). */
static int load_calib(calib *c, const char *config, int new_ok)
{
    char used[4096];
    unsigned flags = new_ok ? CALIB_NEW_OK : 0;
    if (calib_setup(c, config, flags, stderr, "fracnav device-test", used, sizeof used) < 0) {
        fprintf(stderr, "fracnav device-test: %s\n", fn_err_msg());
        return 1;
    }
    if (used[0])
        printf("calibration: %s\n", used);
    return 0;
}

/* Time-weighted mean of the input state over the window: the rest position a drifting cap reports. */
static int calibrate_zero(dev_device *d, calib *c, double seconds, const char *config)
{
    double sum[6] = {0}, total = 0;
    float state[6] = {0};
    int64_t prev = fnclock_now_us(), end = prev + (int64_t)((seconds > 0 ? seconds : 1.0) * 1e6);
    printf("keep the cap released: measuring the rest position for %.1f s\n", seconds > 0 ? seconds : 1.0);
    while (!stop && prev < end) {
        dev_event ev;
        int r = dev_poll(d, &ev, 10);
        if (r < 0) {
            fprintf(stderr, "fracnav device-test: %s\n", fn_err_msg());
            return 1;
        }
        int64_t now = fnclock_now_us();
        for (int i = 0; i < 6; i++)
            sum[i] += state[i] * (double)(now - prev);
        total += (double)(now - prev);
        prev = now;
        if (r == 1 && (ev.flags & DEV_EV_MOTION))
            memcpy(state, ev.axis, sizeof state);
    }
    for (int i = 0; i < 6; i++)
        c->zero[i] = total > 0 ? (float)(sum[i] / total) : 0.0f;
    int16_t fw[6];
    int rc = dev_zero_offsets(d, c->zero, fw);
    if (rc < 0) {
        fprintf(stderr, "fracnav device-test: %s\n", fn_err_msg());
        return 1;
    }
    if (rc == 0) { /* the controller now corrects itself: the host must not subtract it again */
        printf("controller zero offsets (feature report 0x21) now %d %d %d %d %d %d\n", fw[0], fw[1], fw[2],
               fw[3], fw[4], fw[5]);
        memset(c->zero, 0, sizeof c->zero);
    }
    char used[600];
    if (calib_save(c, config, used, sizeof used)) {
        fprintf(stderr, "fracnav device-test: %s\n", fn_err_msg());
        return 1;
    }
    printf("zero offsets %+.4f %+.4f %+.4f %+.4f %+.4f %+.4f saved to %s\n", c->zero[0], c->zero[1],
           c->zero[2], c->zero[3], c->zero[4], c->zero[5], used);
    return 0;
}

static int live_view(dev_device *d, calib *c, double seconds)
{
    int tty = isatty(STDOUT_FILENO);
    int64_t start = fnclock_now_us(), end = seconds > 0 ? start + (int64_t)(seconds * 1e6) : INT64_MAX;
    int64_t last_line = 0, window = start;
    long reports = 0; /* raw reports, counted as they are read */
    double rate = -1; /* reports/s over the last whole second, -1 before the first */
    dev_set_raw_hook(d, count_report, &reports);
    while (!stop && fnclock_now_us() < end) {
        dev_event ev;
        int r = dev_poll(d, &ev, 50);
        if (r < 0) {
            fprintf(stderr, "%sfracnav device-test: %s\n", tty ? "\n" : "", fn_err_msg());
            return 1;
        }
        int64_t now = fnclock_now_us();
        if (now - window >= 1000000) {
            rate = (double)reports * 1e6 / (double)(now - window);
            reports = 0, window = now;
        }
        if (r == 0 && dev_finished(d)) /* a virtual device's script has played out */
            break;
        if (r == 0)
            continue;
        if (ev.flags & DEV_EV_REFUSED) {
            printf("%s%s\n", tty ? "\n" : "", fn_err_msg());
            continue;
        }
        if (ev.flags & (DEV_EV_UNPLUG | DEV_EV_REPLUG))
            printf("%s%s\n", tty ? "\n" : "", ev.flags & DEV_EV_UNPLUG ? "unplugged: waiting for it to return"
                                                                         : "plugged in again");
        float cal[6];
        calib_buttons(c, &ev, NULL, NULL);
        calib_apply(c, ev.axis, cal);
        if (tty || now - last_line >= 1000000 / LINES_PER_S || (ev.flags & DEV_EV_BUTTON)) {
            show(stdout, dev_row(d), &ev, cal, dev_battery(d), rate, tty);
            last_line = now;
        }
    }
    printf("%s%llu report(s) skipped (unknown ID or length)\n", tty ? "\n" : "",
           (unsigned long long)dev_skipped(d));
    return 0;
}

int cmd_device_test(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    opts o = {"auto", NULL, 0, 0};
    int rc = parse_args(argc, argv, &o);
    calib c;
    if (rc || (rc = load_calib(&c, o.config, o.zero)))
        return rc;
    dev_device *d = dev_open(o.spec);
    if (!d) {
        fprintf(stderr, "fracnav device-test: %s\n", fn_err_msg());
        return 1;
    }
    const dev_info *info = dev_device_info(d);
    char id[16] = "";
    if (info->vid || info->pid)
        snprintf(id, sizeof id, " (%04x:%04x)", info->vid, info->pid);
    printf("%s%s via %s, %s format, %d buttons; %s\n", dev_row(d)->name, id, dev_transport_name(d),
           devtab_format_name(dev_row(d)->format), dev_row(d)->nbuttons,
           o.seconds > 0 || o.zero ? "running" : "Ctrl-C to stop");
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    rc = o.zero ? calibrate_zero(d, &c, o.seconds, o.config) : live_view(d, &c, o.seconds);
    dev_close(d);
    return rc;
}
