/* fracnav device-test: a live text view of a controller's axes and buttons, raw and calibrated. */
#include "cmd.h"

#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "calib.h"
#include "dev.h"
#include "err.h"

#define LINES_PER_S 10 /* when not on a terminal: at most this many lines a second */

static volatile sig_atomic_t stop;

static void on_signal(int sig)
{
    stop = 1;
}

static void usage(FILE *out)
{
    fprintf(out, "usage: fracnav device-test [--device SPEC] [--seconds S] [--config SPNAVRC]\n\n"
                 "Shows a controller's six axes (normalized, then calibrated), buttons, battery and\n"
                 "report rate, live, until Ctrl-C or S seconds. SPEC: auto (default), a hidraw path\n"
                 "such as /dev/hidraw0, serial:SN, spnav, keyboard, replay:FILE, ...\n"
                 "Calibration comes from ~/.config/fracnav/spnavrc, else /etc/spnavrc, or --config.\n");
}

static void show(FILE *out, const dev_event *ev, const float cal[6], int battery, double rate, int tty)
{
    static const char *const names[6] = {"x", "y", "z", "rx", "ry", "rz"};
    fprintf(out, "%s", tty ? "\r" : "");
    for (int i = 0; i < 6; i++)
        fprintf(out, "%s %+5.2f>%+5.2f ", names[i], ev->axis[i], cal[i]);
    fprintf(out, "| buttons %08x", ev->buttons);
    for (int i = 0; i < 6 && ev->keys[i]; i++)
        fprintf(out, "%s%u", i ? "," : " keys ", ev->keys[i]);
    if (battery >= 0)
        fprintf(out, " | battery %d%%", battery);
    fprintf(out, " | %.0f reports/s%s", rate, tty ? "   " : "\n");
    fflush(out);
}

static int parse_args(int argc, char **argv, const char **spec, double *seconds, const char **config)
{
    for (int i = 1; i < argc; i++) {
        char *end = NULL;
        if (!strcmp(argv[i], "--device") && i + 1 < argc)
            *spec = argv[++i];
        else if (!strcmp(argv[i], "--config") && i + 1 < argc)
            *config = argv[++i];
        else if (!strcmp(argv[i], "--seconds") && i + 1 < argc) {
            *seconds = strtod(argv[++i], &end);
            if (*end || !(*seconds > 0) || *seconds > 1e6) {
                fprintf(stderr, "fracnav device-test: --seconds wants a positive number, got '%s'\n", argv[i]);
                return 2;
            }
        } else {
            fprintf(stderr, "fracnav device-test: unknown or incomplete option '%s'\n", argv[i]);
            usage(stderr);
            return 2;
        }
    }
    return 0;
}

static int load_calib(calib *c, const char *config)
{
    char used[512], diag[2048];
    calib_default(c);
    int bad = calib_load(c, config, used, sizeof used, diag, sizeof diag);
    if (bad < 0) {
        fprintf(stderr, "fracnav device-test: %s\n", fn_err_msg());
        return 1;
    }
    if (bad)
        fprintf(stderr, "fracnav device-test: %d bad line(s) skipped:\n%s", bad, diag);
    if (used[0])
        printf("calibration: %s\n", used);
    return 0;
}

int cmd_device_test(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    const char *spec = "auto", *config = NULL;
    double seconds = 0;
    int rc = parse_args(argc, argv, &spec, &seconds, &config);
    calib c;
    if (rc || (rc = load_calib(&c, config)))
        return rc;
    dev_device *d = dev_open(spec);
    if (!d) {
        fprintf(stderr, "fracnav device-test: %s\n", fn_err_msg());
        return 1;
    }
    const dev_info *info = dev_device_info(d);
    printf("%s (%04x:%04x) via %s, %s format, %d buttons; %s\n", dev_row(d)->name, info->vid, info->pid,
           dev_transport_name(d), devtab_format_name(dev_row(d)->format), dev_row(d)->nbuttons,
           seconds > 0 ? "running" : "Ctrl-C to stop");
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    int tty = isatty(STDOUT_FILENO);
    int64_t start = dev_now_us(), end = seconds > 0 ? start + (int64_t)(seconds * 1e6) : INT64_MAX;
    int64_t last_line = 0, window = start;
    long reports = 0;
    double rate = 0;
    while (!stop && dev_now_us() < end) {
        dev_event ev;
        int r = dev_poll(d, &ev, 50);
        if (r < 0) {
            fprintf(stderr, "%sfracnav device-test: %s\n", tty ? "\n" : "", fn_err_msg());
            dev_close(d);
            return 1;
        }
        int64_t now = dev_now_us();
        if (now - window >= 1000000) {
            rate = (double)reports * 1e6 / (double)(now - window);
            reports = 0, window = now;
        }
        if (r == 0)
            continue;
        reports++;
        if (ev.flags & (DEV_EV_UNPLUG | DEV_EV_REPLUG))
            printf("%s%s\n", tty ? "\n" : "", ev.flags & DEV_EV_UNPLUG ? "unplugged: waiting for it to return"
                                                                         : "plugged in again");
        float cal[6];
        calib_buttons(&c, &ev, NULL, NULL);
        calib_apply(&c, ev.axis, cal);
        if (tty || now - last_line >= 1000000 / LINES_PER_S || (ev.flags & DEV_EV_BUTTON)) {
            show(stdout, &ev, cal, dev_battery(d), rate, tty);
            last_line = now;
        }
    }
    printf("%s%llu report(s) skipped (unknown ID or length)\n", tty ? "\n" : "",
           (unsigned long long)dev_skipped(d));
    dev_close(d);
    return 0;
}
