/* fracnav navigate: steer a case's fragments with a 6-DOF controller, live, in a terminal. */
#include "cmd.h"

#include "cmd_loopkit.h"
#include "err.h"

#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav navigate CASE [--device auto|PATH|spnav|keyboard|SPEC] [options]\n\n"
            "Steer the case's fragments with a 6-DOF controller. Every move is collision-checked\n"
            "against every other fragment: a blocked move is limited to its free part or slides\n"
            "along the contact. A terminal line shows the selected fragment, its pose, the contact\n"
            "state, the loop rate and the latency. Every accepted pose goes to CASE/journal at once;\n"
            "the case is saved on exit and on demand, and an interrupted session can be recovered.\n\n"
            "  --device SPEC       auto (default: first controller, else spacenavd, else keyboard),\n"
            "                      a hidraw path, spnav, keyboard, serial:S, or a transport NAME:ARG\n"
            "                      (replay-realtime:FILE.fnrec plays a recording as a device;\n"
            "                      virtual:spacenavigator:script=FILE)\n"
            "  --recover           start from the poses the journal holds beyond case.json\n"
            "  --discard-journal   start from case.json, emptying the journal\n"
            "                      (with neither, navigate asks on stdin before opening the device)\n"
            "  --config FILE       calibration in spnavrc syntax (default ~/.config/fracnav/spnavrc)\n"
            "  --frame F           camera (default), world or fragment\n"
            "  --pivot X Y Z       turn the first selected fragment about this point (world mm,\n"
            "                      LPS) instead of its centroid, until the selection changes\n"
            "  --tau-min T, --tau-max T   hierarchy thresholds instead of the case's (0 <= T_min\n"
            "                      <= T_max <= 1), saved into the case with the poses\n"
            "  --duration S        stop after S seconds (scripts, tests)\n"
            "  --json              print a JSON summary on exit (as fracnav replay)\n\n"
            "keys (when the controller is not the keyboard): n/p next/previous fragment, f fix or\n"
            "unfix, c collision checking on/off, t translation only, r rotation only, u undo, y redo,\n"
            "m frame, s save, q quit. Controller buttons: 1 next, 2 previous, 3 fix, 4 collision,\n"
            "5 translation only, 6 rotation only, 7 undo, 8 redo, 9 save, 10 frame (on the SpaceMouse\n"
            "Enterprise: its keys labelled 1-10; spnavrc's bnmapN moves them).\n"
            "With --device keyboard (what auto picks without a controller) the keys steer instead:\n"
            "  arrows or a/d w/s  move in x and y        r/f  up/down\n"
            "  i/k j/l u/o        rotate                 space or x  stop\n"
            "  1 next  2 previous  3 fix  4 collision  5 translation only  6 rotation only\n"
            "  7 undo  8 redo  9 save  0 or m frame  q quit (saves)\n"
            "  mouse: left drag rotates, middle drag rolls, right drag moves, wheel up/down\n"
            "Ctrl-C quits and saves, whatever the device.\n"
            "The camera frame looks from the patient's front (along +y, LPS), superior up.\n");
}

static volatile sig_atomic_t quit;

static void on_signal(int sig)
{
    (void)sig;
    quit = 1;
}

typedef struct opts {
    const char *dir, *device, *config;
    unsigned flags;
    loop_frame frame;
    double duration;
    int json;
    cmd_tau tau;
    int have_pivot;
    double pivot[3];
} opts;

static int parse(int argc, char **argv, opts *o)
{
    memset(o, 0, sizeof *o);
    o->device = "auto";
    o->flags = LOOPKIT_JOURNAL;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int rc;
        if (cmd_tau_option("navigate", a, v, &o->tau, &rc)) {
            if (rc)
                return rc;
            i++;
        } else if (!strcmp(a, "--device") && v)
            o->device = argv[++i];
        else if (!strcmp(a, "--config") && v)
            o->config = argv[++i];
        else if (!strcmp(a, "--recover"))
            o->flags |= LOOPKIT_RESUME;
        else if (!strcmp(a, "--discard-journal"))
            o->flags |= LOOPKIT_DISCARD;
        else if (!strcmp(a, "--json"))
            o->json = 1;
        else if (!strcmp(a, "--duration") && v && atof(v) > 0)
            o->duration = atof(argv[++i]);
        else if (!strcmp(a, "--pivot")) {
            if (loopkit_parse_pivot("navigate", argc, argv, &i, o->pivot))
                return 2;
            o->have_pivot = 1;
        } else if (!strcmp(a, "--frame") && v) {
            if (loopkit_parse_frame("navigate", argv[++i], &o->frame))
                return 2;
        } else if (a[0] == '-' || o->dir) {
            fprintf(stderr, "fracnav navigate: unexpected argument '%s' (see fracnav navigate --help)\n", a);
            return 2;
        } else
            o->dir = a;
    }
    if (!o->dir) {
        fprintf(stderr, "fracnav navigate: need CASE (see fracnav navigate --help)\n");
        return 2;
    }
    if ((o->flags & LOOPKIT_RESUME) && (o->flags & LOOPKIT_DISCARD)) {
        fprintf(stderr, "fracnav navigate: --recover and --discard-journal exclude each other\n");
        return 2;
    }
    return 0;
}

/* Whether stdin can answer a question: a terminal, a pipe or a file (not /dev/null). */
static int can_ask(void)
{
    struct stat st;
    return isatty(STDIN_FILENO) ||
           (fstat(STDIN_FILENO, &st) == 0 && (S_ISFIFO(st.st_mode) || S_ISREG(st.st_mode)));
}

/* An unsaved journal: ask on stdin, before any device takes the terminal (the keyboard device
 * puts it in raw mode). No answer: loopkit_open explains the two flags. The line is read byte by
 * byte so that no key meant for the keyboard device is swallowed by stdio's buffer. */
static void offer_recovery(opts *o)
{
    size_t n = loopkit_journal_pending(o->dir);
    if (!n || (o->flags & (LOOPKIT_RESUME | LOOPKIT_DISCARD)) || !can_ask())
        return;
    fprintf(stderr, "%s/journal holds %zu poses not saved in the case (an interrupted session).\n"
                    "Recover them? [Y/n] ", o->dir, n);
    char first = 0, ch;
    ssize_t got;
    while ((got = read(STDIN_FILENO, &ch, 1)) == 1 && ch != '\n')
        if (!first)
            first = ch;
    if (got != 1 && !first)
        return;
    o->flags |= (first == 'n' || first == 'N') ? LOOPKIT_DISCARD : LOOPKIT_RESUME;
}

static loop_action key_action(int ch)
{
    switch (ch) {
    case 'n': return LOOP_ACT_NEXT;
    case 'p': return LOOP_ACT_PREV;
    case 'f': return LOOP_ACT_FIX;
    case 'c': return LOOP_ACT_COLLISION;
    case 't': return LOOP_ACT_TRANS_ONLY;
    case 'r': return LOOP_ACT_ROT_ONLY;
    case 'u': return LOOP_ACT_UNDO;
    case 'y': return LOOP_ACT_REDO;
    case 'm': return LOOP_ACT_FRAME;
    case 's': return LOOP_ACT_SAVE;
    default: return LOOP_ACT_NONE;
    }
}

typedef struct runner {
    loop *L;
    ring *in;
    atomic_int stop;
    int rc;
} runner;

static void *loop_thread(void *arg)
{
    runner *r = arg;
    loop_realtime_priority(); /* best effort: without it the loop still runs, just less steadily */
    r->rc = loop_run(r->L, r->in, 1000, &r->stop);
    return NULL;
}

/* Saves the poses of the latest scene while the loop keeps running, then has the loop empty the
 * journal of what the case now holds (saved: the loop_set_saved array). */
static void save_scene(loopkit *k, const loop_scene *sc, pose *saved, ring *ctl)
{
    for (int i = 0; i < k->c->nfrag; i++)
        k->c->frag[i].pose = sc->pose[i];
    if (case_save(k->c) < 0) {
        fprintf(stderr, "\nfracnav navigate: save failed: %s\n", fn_err_msg());
        return;
    }
    fprintf(stderr, "\nsaved %s\n", k->dir_name);
    memcpy(saved, sc->pose, sizeof(pose) * (size_t)k->c->nfrag);
    loop_event ev = {.kind = LOOP_EV_SAVED};
    if (ring_push(ctl, &ev))
        loop_notify(k->L);
}

/* Terminal keys -> actions on the control ring (q quits). */
static void read_keys(loop *L, ring *ctl)
{
    char ch;
    while (read(STDIN_FILENO, &ch, 1) == 1) {
        if (ch == 'q')
            quit = 1;
        loop_event ev = {0};
        ev.kind = LOOP_EV_ACTION;
        ev.action = key_action(ch);
        if (ev.action != LOOP_ACT_NONE && ring_push(ctl, &ev))
            loop_notify(L);
    }
}

/* Cuts the status line to the terminal's width, so it rewrites itself in place instead of wrapping. */
static void fit_to_terminal(char *line)
{
    struct winsize ws;
    if (ioctl(STDOUT_FILENO, TIOCGWINSZ, &ws) == 0 && ws.ws_col > 1 && strlen(line) >= ws.ws_col)
        line[ws.ws_col - 1] = '\0';
}

/* The main thread while the loop runs: keys, saves on request, the status line. */
static void ui(loopkit *k, loopkit_dsource *ds, ring *ctl, pose *saved_poses, int keys,
               double duration)
{
    struct termios saved;
    int raw = keys && isatty(STDIN_FILENO) && tcgetattr(STDIN_FILENO, &saved) == 0;
    if (raw) {
        struct termios t = saved;
        t.c_lflag &= (tcflag_t) ~(ICANON | ECHO);
        t.c_cc[VMIN] = 0;
        t.c_cc[VTIME] = 0;
        tcsetattr(STDIN_FILENO, TCSANOW, &t);
    }
    int tty = isatty(STDOUT_FILENO);
    int64_t t0 = loop_now_us(), last_print = 0;
    unsigned saves_seen = 0;
    loop_scene sc = {0};
    while (!quit && (duration <= 0 || (double)(loop_now_us() - t0) < duration * 1e6)) {
        if (raw)
            read_keys(k->L, ctl);
        loop_scene_read(k->L, &sc);
        if (sc.save_requests != saves_seen) {
            saves_seen = sc.save_requests;
            save_scene(k, &sc, saved_poses, ctl);
        }
        int64_t now = loop_now_us();
        if (now - last_print >= (tty ? 100000 : 1000000)) {
            char line[512];
            loop_scene_format(&sc, line, sizeof line);
            size_t len = strlen(line);
            int battery = atomic_load(&ds->battery);
            if (battery >= 0 && len < sizeof line)
                snprintf(line + len, sizeof line - len, " | battery %d%%", battery);
            if (tty)
                fit_to_terminal(line);
            printf(tty ? "\r\033[K%s" : "%s\n", line);
            fflush(stdout);
            last_print = now;
        }
        struct timespec nap = {0, 20000000};
        nanosleep(&nap, NULL);
    }
    if (raw)
        tcsetattr(STDIN_FILENO, TCSANOW, &saved);
    if (tty)
        printf("\n");
}

/* Input thread and loop thread around ui(); then the loop is stopped and the case saved.
 * saved_poses outlives the loop thread, which reads it on LOOP_EV_SAVED. */
static int run(loopkit *k, loopkit_dsource *ds, int keys, double duration)
{
    pose saved_poses[LOOP_MAX_FRAGS] = {0}; /* written by each save before the loop reads it */
    loop_set_saved(k->L, saved_poses);
    ring *in = ring_new(sizeof(loop_event), 1024), *ctl = ring_new(sizeof(loop_event), 64);
    runner run = {k->L, in, 0, 0};
    atomic_init(&run.stop, 0);
    loop_set_controls(k->L, ctl);
    /* Before the reader starts: the keyboard device's q raises SIGINT from the reader thread. */
    struct sigaction sa = {0};
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    loop_reader *rd = in && ctl ? loop_reader_start(loopkit_device_source(ds), in, k->L, 0) : NULL;
    pthread_t th;
    int rc = 0;
    if (!rd || pthread_create(&th, NULL, loop_thread, &run) != 0) {
        rc = rd ? fn_err_set(FN_EIO, "cannot start the loop thread") : FN_EIO;
        loop_reader_stop(rd);
    } else {
        ui(k, ds, ctl, saved_poses, keys, duration);
        loop_reader_stop(rd);
        atomic_store(&run.stop, 1);
        loop_notify(k->L);
        pthread_join(th, NULL);
        rc = run.rc;
        if (rc == 0)
            rc = loopkit_save(k);
    }
    loop_set_controls(k->L, NULL);
    loop_set_saved(k->L, NULL);
    ring_free(in);
    ring_free(ctl);
    return rc;
}

int cmd_navigate(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    opts o;
    int rc = parse(argc, argv, &o);
    if (rc)
        return rc;
    loopkit_dsource ds = {0};
    calib_default(&ds.cal);
    char used[4096], diag[2048] = "";
    if (calib_load(&ds.cal, o.config, used, sizeof used, diag, sizeof diag) < 0) {
        fprintf(stderr, "fracnav navigate: %s\n", fn_err_msg());
        return 1;
    }
    fputs(diag, stderr);
    offer_recovery(&o);
    ds.d = dev_open(o.device);
    if (!ds.d) {
        fprintf(stderr, "fracnav navigate: %s\n", fn_err_msg());
        return 1;
    }
    int keys = strcmp(dev_transport_name(ds.d), "keyboard") != 0;
    loop_config cfg;
    loop_config_default(&cfg);
    loop_config_actions_at(&cfg, devtab_key1_button(dev_row(ds.d)));
    cfg.frame = o.frame;
    loopkit k;
    rc = loopkit_open(&k, o.dir, &cfg, o.flags, "navigate", &o.tau);
    if (rc == 0) {
        if (k.resumed)
            fprintf(stderr, "recovered %zu journal records\n", k.resumed);
        ds.L = k.L;
        if (o.have_pivot)
            loop_set_pivot(k.L, o.pivot);
        ds.led = -1;
        atomic_init(&ds.battery, -1);
        rc = run(&k, &ds, keys, o.duration);
        dev_set_led(ds.d, 0);
        if (rc == 0 && o.json)
            loopkit_print_json(&k, stdout, -1, dev_skipped(ds.d));
        else if (rc == 0)
            fprintf(stderr, "saved %s\n", o.dir);
        loopkit_close(&k);
    }
    if (rc < 0)
        fprintf(stderr, "fracnav navigate: %s\n", fn_err_msg());
    dev_close(ds.d);
    return rc < 0 ? 1 : 0;
}
