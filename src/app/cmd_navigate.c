/* fracnav navigate: steer a case's fragments with a 6-DOF controller, live, in a terminal. */
#include "cmd.h"

#include "navseed.h"
#include "navview.h"
#include "navwin.h"
#include "session.h"

#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav navigate CASE [--device auto|PATH|spnav|keyboard|SPEC] [options]\n\n"
            "Steer the case's fragments with a 6-DOF controller. Every move is collision-checked\n"
            "against every other fragment: a blocked move is limited to its free part or slides\n"
            "along the contact. A terminal view shows the selected fragment, its pose, the contact\n"
            "state, the loop rate and the latency. Every accepted pose goes to CASE/journal within\n"
            "50 ms; the case is saved on exit and on demand (with the fixed fragment, and a warning\n"
            "when fragments overlap), and an interrupted session can be recovered.\n\n"
            "  --device SPEC       auto (default: first controller, else spacenavd, else keyboard),\n"
            "                      a hidraw path, spnav, keyboard, serial:S, or a transport NAME:ARG\n"
            "                      (replay-realtime:FILE.fnrec plays a recording as a device,\n"
            "                      and navigate ends at its end; virtual:spacenavigator:script=FILE)\n"
            "  --loop              a recording (replay:, replay-realtime:) plays again from its start\n"
            "                      at its end, until q, Ctrl-C or --duration\n"
            "  --recover           start from the poses the journal holds beyond case.json\n"
            "  --discard-journal   start from case.json, emptying the journal\n"
            "                      (with neither, navigate asks on stdin before opening the device)\n"
            "  --config FILE       calibration in spnavrc syntax (default ~/.config/fracnav/spnavrc)\n"
            "  --frame F           camera (default), world or fragment\n"
            "  --pivot X Y Z       turn the first selected fragment about this point (world mm,\n"
            "                      LPS) instead of its centroid, until the selection changes\n"
            "  --tau-min T, --tau-max T   hierarchy thresholds instead of the case's (0 <= T_min\n"
            "                      <= T_max <= 1), saved into the case with the poses\n"
            "  --gap MM            bone lost at the fracture: the fit action (g, or button 12)\n"
            "                      leaves a gap of MM at the cut, as fracnav reduce --gap does\n"
            "                      (0 to 10, default 0)\n"
            "  --preview P         the live preview of the fit (a ghost at the fitted pose, its\n"
            "                      distance in mm and degrees in the view; v on/off, b or button 14\n"
            "                      accepts it as one undoable move): near (default: by itself\n"
            "                      within 3 mm of contact, not for the fragment that stays --\n"
            "                      with none fixed, the largest -- and on v), key (on v only)\n"
            "                      or off\n"
            "  --duration S        stop after S seconds (scripts, tests)\n"
            "  --view V            window (default when $DISPLAY is set and OpenGL 4.5 is there:\n"
            "                      the fragments drawn at their poses with a HUD; left drag orbits,\n"
            "                      right or middle drag pans, the wheel zooms, Ctrl+1..6 give the\n"
            "                      anterior, posterior, left, right, superior and inferior views,\n"
            "                      the window's other keys are F-keys, every other key typed there\n"
            "                      acts as in the terminal (with --device keyboard it steers),\n"
            "                      and the camera frame follows the view) or terminal; without a\n"
            "                      display or GL 4.5 the terminal view stays, with a line saying why\n"
            "  --mode M            the window's mode: iso (default on a GPU), dvr, mip or surface\n"
            "                      (default on software GL)\n"
            "  --layout L          the window's layout: 3d (default) or four-up (the 3D view large,\n"
            "                      the axial, coronal and sagittal slices below; they cut through\n"
            "                      the selected fragment's centroid at its pose, or where a click\n"
            "                      or the wheel over a slice puts them)\n"
            "  --camera VIEW       the window's first view: auto (default: framed on the selected\n"
            "                      fragment from the side where it is seen, again at each change of\n"
            "                      the selection; Ctrl+0), or anterior, posterior, left, right,\n"
            "                      superior, inferior\n"
            "  --overlay LIST      on the window's 3D view: hierarchy[:DEPTH], contacts, axes, voi,\n"
            "                      as fracnav render takes them\n"
            "  --screenshot FILE   the window as last drawn, as a PNG, at exit\n"
            "  --json              print a JSON summary on exit (as fracnav replay): standard\n"
            "                      output holds the JSON alone; the view goes to standard error\n"
            CMD_WAIT_HELP "\n"
            "The view (on standard error) is laid out for the terminal's width: warnings first,\n"
            "then the selected fragment, its contact (the gap is a lower bound measured at the\n"
            "pose shown), its move (mm right/left, anterior/posterior, inferior/superior) and its\n"
            "turn (degrees about those axes, world LPS), the\n"
            "frame and rates, and what the last key or button did. Off a terminal it is one line\n"
            "a second, and one at each warning or action.\n\n"
            "%s%s%s"
            "With --device keyboard (what auto picks without a controller) the keys steer instead:\n"
            "%s"
            "The camera frame looks from the patient's front (along +y, LPS), superior up.\n",
            navview_help(0), navwin_help(), navseed_help(), strchr(navview_help(1), '\n') + 1);
}

/* Set by the signal handler, which may run on another thread (the keyboard device raises SIGINT for
 * q on the input thread): a lock-free atomic, so the main thread reads it without a data race. */
static atomic_int quit;

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
    int json, again;
    cmd_tau tau;
    int have_pivot;
    double pivot[3];
    int view; /* NAVWIN_VIEW_* */
    navwin_look look;
    double gap_mm; /* --gap: the fit action's */
    int preview;   /* --preview: SESSION_PREVIEW_* */
    const char *screenshot;
} opts;

static int parse(int argc, char **argv, opts *o)
{
    memset(o, 0, sizeof *o);
    o->look = (navwin_look)NAVWIN_LOOK_DEFAULT;
    o->device = "auto";
    o->flags = SESSION_JOURNAL;
    o->preview = SESSION_PREVIEW_NEAR;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int rc;
        if (cmd_tau_option("navigate", a, v, &o->tau, &rc) || navwin_view_option("navigate", a, v, &o->view, &rc) ||
            navwin_look_option("navigate", a, v, &o->look, &rc)) {
            if (rc)
                return rc;
            i++;
        } else if (!strcmp(a, "--device") && v)
            o->device = argv[++i];
        else if (!strcmp(a, "--config") && v)
            o->config = argv[++i];
        else if (!strcmp(a, "--recover"))
            o->flags |= SESSION_RESUME;
        else if (!strcmp(a, "--discard-journal"))
            o->flags |= SESSION_DISCARD;
        else if (!strcmp(a, "--json"))
            o->json = 1;
        else if (!strcmp(a, "--loop"))
            o->again = 1;
        else if (!strcmp(a, "--screenshot")) {
            if (!v)
                return cmd_bad_value("navigate", a, v, "a PNG file to write");
            o->screenshot = argv[++i];
        }
        else if (!strcmp(a, "--gap")) {
            if (!cmd_number(v, &o->gap_mm) || !(o->gap_mm >= 0 && o->gap_mm <= 10))
                return cmd_bad_value("navigate", a, v, "a number of mm from 0 to 10");
            i++;
        }
        else if (!strcmp(a, "--preview")) {
            static const char *names[] = {"off", "near", "key"}; /* SESSION_PREVIEW_* */
            o->preview = -1;
            for (int m = 0; m < 3 && v; m++)
                if (!strcmp(v, names[m]))
                    o->preview = m;
            if (o->preview < 0)
                return cmd_bad_value("navigate", a, v, "near, key or off");
            i++;
        }
        else if (!strcmp(a, "--duration")) {
            if (!cmd_number(v, &o->duration) || !(o->duration > 0))
                return cmd_bad_value("navigate", a, v, "a number of seconds > 0");
            i++;
        }
        else if (!strcmp(a, "--pivot")) {
            if (cmd_parse_pivot("navigate", argc, argv, &i, o->pivot))
                return 2;
            o->have_pivot = 1;
        } else if (!strcmp(a, "--frame") && v) {
            if (session_frame_parse(argv[++i], &o->frame) < 0)
                return cmd_usage_error("navigate", "%s", fn_err_msg());
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
    if ((o->flags & SESSION_RESUME) && (o->flags & SESSION_DISCARD)) {
        fprintf(stderr, "fracnav navigate: --recover and --discard-journal exclude each other\n");
        return 2;
    }
    if (o->screenshot && o->view == NAVWIN_VIEW_TERMINAL)
        return cmd_usage_error("navigate", "--screenshot saves the window: it needs --view window");
    if (o->again && !session_spec_recording(o->device))
        return cmd_usage_error("navigate", "--loop plays a recording again: it needs --device "
                                           "replay:FILE or replay-realtime:FILE, not '%s'", o->device);
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
 * puts it in raw mode). No answer: session_open explains the two flags. The line is read byte by
 * byte so that no key meant for the keyboard device is swallowed by stdio's buffer. */
static void offer_recovery(opts *o)
{
    size_t n = session_journal_pending(o->dir);
    if (!n || (o->flags & (SESSION_RESUME | SESSION_DISCARD)) || !can_ask())
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
    o->flags |= (first == 'n' || first == 'N') ? SESSION_DISCARD : SESSION_RESUME;
}

#define ACK_SHOWN_US 5000000 /* an acknowledgement stays this long in the view */

/* The view on standard error: redrawn in place on a terminal, else a log line a second and one
 * at each change of the warnings or the acknowledgement. */
typedef struct view {
    session *k;
    session_dsource *ds; /* a live device (battery, refusals); NULL for a played recording */
    session_dsource *rec; /* a played recording; NULL for a live device */
    unsigned plays_seen;
    int keyboard;        /* the keyboard device steers: its keys are the help */
    int tty, help, lines; /* lines: the rows the terminal view holds at the screen's bottom */
    int rows;             /* the terminal's height when they were set aside */
    char ack[sizeof(((session_event *)0)->text)];
    int64_t ack_until_us, last_print_us;
    char logged[2048]; /* the warnings and acknowledgement of the last log line */
    int logged_help;   /* the help was on at the last log line */
    navwin *win;       /* --view window: the window; NULL for the terminal view alone */
    char fit[160];     /* the running fit's progress, shown in the view */
    char preview[160]; /* the live preview's figures, shown in the view */
    navseed seed;      /* the window's seed mode; Enter there ends the run to separate */
    const char *dir;   /* the case folder */
    int undo_edit;     /* undo with no move left to undo, and a separation to take back: the run
                        * ends to take it back */
} view;

static void acknowledge(view *v, const char *text)
{
    snprintf(v->ack, sizeof v->ack, "%s", text);
    v->ack_until_us = fnclock_now_us() + ACK_SHOWN_US;
}

/* A save request carried out by the session, or a fit started, refused or finished: said in the
 * view, and off a terminal also as a line of its own. */
static void saved(view *v, const session_event *ev)
{
    acknowledge(v, ev->text);
    if (!v->tty)
        fprintf(stderr, "%s%s\n", ev->result < 0 ? "fracnav navigate: " : "", ev->text);
}

/* One key, from the terminal or the window (27: Escape there): ? and h show or hide the keys, q
 * (and Escape) quits, the others go to the session. */
static void handle_key(view *v, int ch)
{
    if (ch == 'q' || ch == 27)
        quit = 1;
    loop_action a = session_key_action(ch);
    if (a == LOOP_ACT_HELP)
        v->help = !v->help;
    else if (a != LOOP_ACT_NONE)
        session_send_action(v->k, a); /* a full queue drops the key, as before */
}

/* Terminal keys. */
static void read_keys(view *v)
{
    char ch;
    while (read(STDIN_FILENO, &ch, 1) == 1)
        handle_key(v, ch);
}

/* A new action done by a key or a button: its acknowledgement (the keyboard device's help key
 * comes this way too). */
static void new_actions(view *v, const loop_scene *sc)
{
    if (sc->last_action == LOOP_ACT_HELP) {
        v->help = !v->help;
        return;
    }
    if (sc->last_action == LOOP_ACT_UNDO && sc->last_action_result == LOOP_IDLE && navseed_can_undo(v->dir)) {
        v->undo_edit = 1; /* the moves are all undone: the separation before them is next */
        return;
    }
    char text[256];
    navview_ack(sc, text, sizeof text);
    if (text[0])
        acknowledge(v, text);
}

/* --loop: each new play of the recording is acknowledged. */
static void new_plays(view *v)
{
    unsigned plays = v->rec ? session_source_plays(v->rec) : 0;
    if (plays == v->plays_seen)
        return;
    v->plays_seen = plays;
    char text[64];
    snprintf(text, sizeof text, "the recording plays again (play %u)", plays + 1);
    acknowledge(v, text);
}

static struct winsize terminal_size(void)
{
    struct winsize ws;
    if (ioctl(STDERR_FILENO, TIOCGWINSZ, &ws) != 0 || ws.ws_col == 0 || ws.ws_row == 0)
        ws.ws_col = 80, ws.ws_row = 24;
    return ws;
}

/* The help below the view (with the window's keys when it is open; appended to text at *len),
 * each line cut to the width. Returns the lines added. */
static int add_help(const view *v, int width, char *text, size_t cap, size_t *len)
{
    char all[4096];
    snprintf(all, sizeof all, "%s%s%s", navview_help(v->keyboard), v->win ? navwin_help() : "",
             v->win ? navseed_help() : "");
    const char *t = all;
    int n = 0;
    while (*t) {
        const char *end = strchr(t, '\n');
        int w = (int)(end - t) < width - 1 ? (int)(end - t) : width - 1;
        int k = snprintf(text + *len, cap - *len, "\n%.*s", w, t);
        if (k < 0 || (size_t)k >= cap - *len)
            break;
        *len += (size_t)k;
        n++;
        t = end + 1;
    }
    return n;
}

/* The view's n lines drawn in the bottom rows of the terminal, which the scroll region (the rows
 * above) leaves alone: what else is written to the terminal (a save's notes) scrolls up there and
 * never mixes with the view. The cursor stays in the region between draws (saved and restored
 * around each). */
static void draw_bottom(view *v, const char *text, int n, int rows)
{
    if (n > rows - 1) /* the region keeps a row */
        n = rows - 1;
    if (n != v->lines || rows != v->rows) {
        /* the old view's rows cleared, the whole screen scrolling again, and room made below the
         * cursor for the new view before the region is set above it */
        fputs("\0337", stderr);
        if (v->lines)
            fprintf(stderr, "\033[r\033[%d;1H\033[J", v->rows - v->lines + 1);
        fputs("\0338", stderr);
        for (int i = 0; i < n; i++)
            fputc('\n', stderr);
        fprintf(stderr, "\033[%dA\0337\033[1;%dr\0338", n, rows - n);
        v->lines = n;
        v->rows = rows;
    }
    fprintf(stderr, "\0337\033[%d;1H\033[J", rows - n + 1);
    for (int i = 0; i < n; i++) {
        const char *end = strchr(text, '\n');
        int len = end ? (int)(end - text) : (int)strlen(text);
        fprintf(stderr, "%s%.*s", i ? "\n" : "", len, text);
        text = end ? end + 1 : text + len;
    }
    fputs("\0338", stderr);
}

/* The terminal view ends: the whole screen scrolls again, and what follows goes below the view. */
static void end_bottom(view *v)
{
    if (!v->lines)
        return;
    fprintf(stderr, "\033[r\033[%d;1H\n", v->rows);
    v->lines = 0;
}

/* A key typed in the window: with the keyboard device it steers as in the terminal (the device
 * reads it, arrows as the terminal's escape sequences); otherwise it is a terminal key. Escape
 * quits either way. */
static void window_key(view *v, int k)
{
    static const char *arrow[] = {"\033[D", "\033[C", "\033[A", "\033[B"}; /* RENDER_KEY_LEFT.. */
    char c = (char)k;
    const char *bytes = k >= RENDER_KEY_LEFT && k <= RENDER_KEY_DOWN ? arrow[k - RENDER_KEY_LEFT]
                        : k > 0 && k < 128 && k != 27                ? &c
                                                                     : NULL;
    if (!v->keyboard || !v->ds || !bytes) {
        if (k > 0 && k < 128)
            handle_key(v, k);
    } else if (session_source_feed_keys(v->ds, bytes, bytes == &c ? 1 : strlen(bytes)) < 0)
        acknowledge(v, fn_err_msg());
}

/* What the view shows besides the scene (refused: room for the refusal). */
static navview_extra view_extra(view *v, char *refused, size_t cap)
{
    navview_extra x = {-1, NULL, NULL, session_frags(v->k), NULL, NULL};
    session_fit fs;
    session_fit_status(v->k, &fs);
    if (fs.running)
        snprintf(v->fit, sizeof v->fit, "fitting frag %d: iteration %d, metric %.4f, %.1f s",
                 fs.frag + 1, fs.iterations, fs.metric, fs.seconds);
    else if (fs.finished && fs.result == 0)
        snprintf(v->fit, sizeof v->fit, "fit of frag %d: metric %.4f -> %.4f, moved %.2f mm, turned %.2f deg",
                 fs.frag + 1, fs.metric_start, fs.metric, fs.moved_mm, fs.turned_deg);
    else if (fs.finished)
        snprintf(v->fit, sizeof v->fit, "fit of frag %d %s", fs.frag + 1, fs.result > 0 ? "cancelled" : "failed");
    else
        snprintf(v->fit, sizeof v->fit, "no fit run here yet (g fits)");
    x.fit = v->fit;
    session_preview ps;
    session_preview_status(v->k, &ps);
    session_preview_text(&ps, v->preview, sizeof v->preview);
    x.preview = v->preview;
    if (v->ds) {
        x.battery = session_dsource_battery(v->ds);
        if (session_dsource_refused(v->ds, refused, cap))
            x.refused = refused;
    }
    if (v->ack[0] && fnclock_now_us() < v->ack_until_us)
        x.ack = v->ack;
    if (navseed_status(&v->seed))
        x.ack = navseed_status(&v->seed);
    return x;
}

/* --view window: one frame of the window (when something changed) with the view's lines as its
 * HUD; keys typed there go to the seed mode, or act as terminal keys. A window that fails or is
 * closed ends the session like q. */
static void window_frame(view *v, const loop_scene *sc)
{
    char refused[512], device[256];
    navview_extra x = view_extra(v, refused, sizeof refused);
    snprintf(device, sizeof device, "%s%s", v->ds ? session_source_name(v->ds) : "a recording",
             x.battery >= 0 ? "" : ", battery unknown");
    int keys[NAVWIN_KEYS], closed = 0;
    char help[2048];
    snprintf(help, sizeof help, "%s%s", navview_help(v->keyboard), navseed_help());
    int n = navwin_show(v->win, sc, &x, device, v->help ? help : NULL, keys, NAVWIN_KEYS, &closed);
    if (n < 0) {
        fprintf(stderr, "fracnav navigate: the window: %s\n", fn_err_msg());
        quit = 1;
    }
    for (int i = 0; i < n; i++) {
        double at[3];
        if (keys[i] == NAVWIN_KEY_CLICK) {
            if (navwin_click_at(v->win, at) == 0)
                navseed_click(&v->seed, at);
        } else if (!navseed_key(&v->seed, keys[i]))
            window_key(v, keys[i]);
    }
    /* the split the seeds make, grown on the seed mode's worker, shown once it is done */
    if (navseed_preview(&v->seed, session_case(v->k), sc->pose, sc->nfrag) &&
        navwin_set_pieces(v->win, v->seed.pieces, v->seed.npieces, v->seed.prep) < 0) {
        fprintf(stderr, "fracnav navigate: the window: %s\n", fn_err_msg());
        quit = 1;
    }
    double marks[RENDER_MAX_MARKS][3];
    unsigned char mark_rgb[RENDER_MAX_MARKS][3];
    int nmarks = navseed_marks(&v->seed, marks, mark_rgb, RENDER_MAX_MARKS);
    navwin_set_marks(v->win, nmarks, (const double(*)[3])marks, (const unsigned char(*)[3])mark_rgb);
    if (closed)
        quit = 1;
}

static void draw(view *v, const loop_scene *sc)
{
    char refused[512], text[4096], sig[2048];
    navview_extra x = view_extra(v, refused, sizeof refused);
    int64_t now = fnclock_now_us();
    if (v->tty) {
        struct winsize ws = terminal_size();
        int n = navview_format(sc, &x, ws.ws_col, text, sizeof text);
        size_t len = strlen(text);
        if (v->help)
            n += add_help(v, ws.ws_col, text, sizeof text, &len);
        draw_bottom(v, text, n, ws.ws_row);
        v->last_print_us = now;
    } else {
        snprintf(sig, sizeof sig, "%d%d%d%d %.900s %.900s", sc->collision_on, sc->penetrating,
                 sc->device_present, sc->stats.journal_errors > 0, x.refused ? x.refused : "",
                 x.ack ? x.ack : "");
        if (now - v->last_print_us < 1000000 && !strcmp(sig, v->logged) && v->help == v->logged_help)
            return;
        snprintf(v->logged, sizeof v->logged, "%s", sig);
        navview_format(sc, &x, 0, text, sizeof text);
        fprintf(stderr, "%s\n", text);
        if (v->help && !v->logged_help)
            fprintf(stderr, "%s%s%s", navview_help(v->keyboard), v->win ? navwin_help() : "",
                    v->win ? navseed_help() : "");
        v->logged_help = v->help;
        v->last_print_us = now;
    }
    fflush(stderr);
}

/* One event from the session: actions are acknowledged, saves said; 1 at the source's end. */
static int handle(view *v, const session_event *ev)
{
    if (ev->kind == SESSION_EV_ACTION)
        new_actions(v, &ev->scene);
    else if (ev->kind == SESSION_EV_SAVED || ev->kind == SESSION_EV_FIT ||
             (ev->kind == SESSION_EV_PREVIEW && ev->text[0]))
        saved(v, ev);
    return ev->kind == SESSION_EV_END;
}

/* The main thread while the loop runs: keys, the session's events (saves on request), the view.
 * Returns when the user quits, at --duration, when a played recording has ended, or when the seed
 * mode's separation was accepted. */
static void ui(view *v, int keys, double duration)
{
    struct termios saved_tio;
    int raw = keys && isatty(STDIN_FILENO) && tcgetattr(STDIN_FILENO, &saved_tio) == 0;
    if (raw) {
        struct termios t = saved_tio;
        t.c_lflag &= (tcflag_t) ~(ICANON | ECHO);
        t.c_cc[VMIN] = 0;
        t.c_cc[VTIME] = 0;
        tcsetattr(STDIN_FILENO, TCSANOW, &t);
    }
    int64_t t0 = fnclock_now_us();
    int ended = 0;
    loop_scene sc = {0};
    session_event ev;
    while (!quit && !ended && !v->seed.accepted && !v->undo_edit &&
           (duration <= 0 || (double)(fnclock_now_us() - t0) < duration * 1e6)) {
        if (raw)
            read_keys(v);
        /* keys at least every 20 ms; the window at display rate (a frame when something changed) */
        if (session_wait_event(v->k, v->win ? 16 : 20, &ev) != SESSION_EV_NONE)
            ended = handle(v, &ev);
        new_plays(v);
        session_scene_read(v->k, &sc);
        if (!v->tty || fnclock_now_us() - v->last_print_us >= 100000)
            draw(v, &sc);
        if (v->win)
            window_frame(v, &sc);
    }
    if (raw)
        tcsetattr(STDIN_FILENO, TCSANOW, &saved_tio);
}

/* --view: the window when asked or by default with a display; without a display, GLFW or GL
 * 4.5 the terminal view stays, and a line says why. */
static void open_window(const opts *o, view *v)
{
    v->win = navwin_open_view("navigate", o->view, &o->look, "the terminal view stays", v->k, 1);
    if (v->win && v->tty)
        fprintf(stderr, "window: %s\n", navwin_gl_renderer(v->win));
}

/* The session runs src around ui() (and the window, once the loop runs: the loop prefaults the
 * pages of the libraries loaded when it starts, and GL's, tens of MB, are none of its business);
 * then it is stopped, the last events handled, the view drawn once more, the window's screenshot
 * saved, and the case saved. */
static int run(view *v, loop_source src, int keys, const opts *o)
{
    session *k = v->k;
    struct sigaction sa = {0}; /* before the input thread: the keyboard device's q raises SIGINT */
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    int rc = session_start(k, src);
    if (rc < 0)
        return rc;
    open_window(o, v);
    if (o->screenshot && !v->win)
        fprintf(stderr, "fracnav navigate: --screenshot %s: no window to save\n", o->screenshot);
    ui(v, keys, o->duration);
    rc = session_stop(k);
    session_event ev;
    while (session_wait_event(k, 0, &ev) != SESSION_EV_NONE)
        handle(v, &ev);
    if (session_ended(k))
        acknowledge(v, "end of the recording");
    loop_scene sc = {0};
    session_scene_read(k, &sc);
    v->last_print_us = 0;
    draw(v, &sc);
    if (v->tty)
        end_bottom(v);
    if (v->win && o->screenshot && navwin_save_screenshot(v->win, "navigate", o->screenshot) < 0)
        rc = rc ? rc : FN_EIO;
    navwin_close(v->win);
    v->win = NULL;
    navseed_free(&v->seed);
    v->seed.changed = 1; /* the preview again, in the next window */
    return rc == 0 ? session_save(k) : rc;
}

/* The seed mode's separation, or its undo, after the session saved its poses and closed
 * (navseed_separate, navseed_undo). A bad seed leaves the case as it was and is said in the view. */
static void separate(view *v, const char *dir)
{
    int nfrag = 0, made = v->undo_edit ? navseed_undo(dir, &nfrag) : navseed_separate(&v->seed, dir, &nfrag);
    char text[sizeof v->ack];
    if (v->undo_edit && made > 0)
        snprintf(text, sizeof text, "undo: the separation taken back, %d fragment%s; saved %s", nfrag,
                 nfrag == 1 ? "" : "s", dir);
    else if (v->undo_edit && made == 0)
        snprintf(text, sizeof text, "undo: the separation stays (the case was saved since)");
    else if (made >= 0)
        snprintf(text, sizeof text, "separated: %d new fragment%s, %d in all; saved %s (undo takes it back)", made,
                 made == 1 ? "" : "s", nfrag, dir);
    else
        snprintf(text, sizeof text, "not %s: %s", v->undo_edit ? "undone" : "separated", fn_err_msg());
    v->undo_edit = 0;
    fprintf(stderr, "%s%s\n", made < 0 ? "fracnav navigate: " : "", text);
    acknowledge(v, text);
}

/* One session over the case: opened, run (run()), saved and closed. *again: the seed mode asked
 * for a separation, or undo for its undo, done here; the caller opens the case again. 0 or FN_E*. */
static int navigate_once(const opts *o, view *v, const session_params *sp, session_dsource *ds, int played,
                         int *again)
{
    session *k = session_open(o->dir, sp);
    if (!k)
        return FN_EIO;
    if (session_resumed(k))
        fprintf(stderr, "recovered %zu journal records\n", session_resumed(k));
    session_drive_led(k, played ? NULL : ds);
    session_set_preview(k, o->preview);
    if (o->have_pivot)
        session_set_pivot(k, o->pivot);
    v->k = k;
    int rc = run(v, session_device_source(ds), played || !v->keyboard, o);
    if (rc == 0 && (v->seed.accepted || v->undo_edit)) {
        session_close(k);
        separate(v, o->dir);
        *again = !quit;
        return 0;
    }
    if (rc == 0 && o->json)
        rc = session_print_json(k, stdout, "navigate", played ? (long)session_source_unplugs(ds) : -1,
                                session_source_skipped(ds));
    else if (rc == 0)
        fprintf(stderr, "saved %s\n", o->dir);
    session_close(k);
    return rc;
}

int cmd_navigate(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    opts o;
    int wait = cmd_take_flag(&argc, argv, "--wait");
    int rc = parse(argc, argv, &o);
    if (rc)
        return rc;
    /* the case first: a missing one is the first thing to say, before any device */
    if (cmd_case_exists(o.dir) < 0 || (o.screenshot && cmd_out_file(o.screenshot, NULL) < 0)) {
        fprintf(stderr, "fracnav navigate: %s\n", fn_err_msg());
        return 1;
    }
    calib cal;
    if (session_calib_setup(&cal, o.config, 0, "fracnav navigate") < 0) {
        fprintf(stderr, "fracnav navigate: %s\n", fn_err_msg());
        return 1;
    }
    /* Held for the whole session: a second writer is refused, and the journal this session keeps
     * is never taken for an interrupted one. */
    caselock *lock = session_lock_case("navigate", o.dir, 1, wait);
    if (!lock)
        return 1;
    offer_recovery(&o);
    loop_config cfg;
    session_config_default(&cfg);
    cfg.frame = o.frame;
    view v = {0};
    v.tty = isatty(STDERR_FILENO);
    session_dsource *ds = session_source_open(o.device, &cal, o.again, &cfg);
    int played = ds && session_source_recording(ds);
    v.keyboard = ds && session_source_keyboard(ds);
    if (!ds) {
        fprintf(stderr, "fracnav navigate: %s\n", fn_err_msg());
        session_unlock(lock);
        return 1;
    }
    if (v.tty)
        fprintf(stderr, "loading %s and building its collision hierarchy...\n", o.dir);
    session_params sp = {cfg, o.flags, "navigate", cmd_tau_prepare, &o.tau, o.gap_mm};
    v.ds = played ? NULL : ds;
    v.rec = played ? ds : NULL;
    navseed_init(&v.seed);
    v.dir = o.dir;
    int nfrag, made = navseed_recover(o.dir, &nfrag);
    if (made < 0)
        fprintf(stderr, "fracnav navigate: %s: the separation a crash interrupted is not recovered (the case "
                "opens as it was saved; the file stays): %s\n", o.dir, fn_err_msg());
    else if (made)
        fprintf(stderr, "%s: recovered a separation interrupted by a crash: %d new fragment%s, %d in all\n", o.dir,
                made - 1, made == 2 ? "" : "s", nfrag);
    int again;
    do {
        again = 0;
        rc = navigate_once(&o, &v, &sp, ds, played, &again);
    } while (rc == 0 && again);
    if (rc < 0)
        fprintf(stderr, "fracnav navigate: %s\n", fn_err_msg());
    session_dsource_free(ds);
    session_unlock(lock);
    return rc < 0 ? 1 : 0;
}
