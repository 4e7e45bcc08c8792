/* fracnav replay: a .fnrec recording through the navigation loop, deterministic, JSON summary. */
#include "cmd.h"

#include "framedump.h"
#include "navwin.h"
#include "session.h"

#include <libgen.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav replay CASE FILE.fnrec [--realtime [--view window|terminal]\n"
            "                      [--screenshot FILE.png]] [--json] [options]\n\n"
            "Play a recording of a 6-DOF controller through the navigation loop on CASE: every report\n"
            "is parsed, calibrated and stepped (collision-checked against every other fragment), and\n"
            "every accepted pose is appended to CASE/journal (kept if the run is killed, for\n"
            "--recover; emptied when it finishes, unless it continued from the journal with\n"
            "--recover and did not --save). Stepping uses only the recorded\n"
            "timestamps, so the same case and recording give the same poses and pose_digest on every\n"
            "run and machine, with or without the window. A recording's save and fit buttons do\n"
            "nothing here (--save saves at the end). Prints a summary (with --json the object alone\n"
            "on stdout, labelled \"command\": \"replay\", as navigate --json; see docs/formats.md,\n"
            "\"Machine output\"):\n"
            "  events, steps        events handled; motion steps (accepted + limited + slid + refused)\n"
            "  accepted, limited, slid, refused   outcomes of the steps\n"
            "  collisions_in_accepted   accepted poses found colliding on re-check (always 0)\n"
            "  unchecked            poses taken while collision checking was off\n"
            "  escaping             poses taken inside another fragment, none deeper (checking\n"
            "                       turned back on while penetrating)\n"
            "  queries, dropped     pair collision queries; events lost to a full input ring (0\n"
            "                       unless the loop fell behind)\n"
            "  queries_from_scratch   the queries that searched from scratch (their pair's\n"
            "                       cache of no use: the costly ones)\n"
            "  journal_errors       failed journal writes\n"
            "  loop_hz, tick_hz     steps and loop timer ticks per second of wall time (tick_hz:\n"
            "                       null without --realtime, where no timer runs)\n"
            "  latency_p50_us, latency_p99_us, latency_max_us   report arrival to accepted pose\n"
            "  query_mean_us, query_max_us   time of a pair collision query\n"
            "  skipped_reports      device reports of an unknown ID or a wrong length, skipped\n"
            "  unplugs              device unplugs seen (null in navigate)\n"
            "  resumed_from_journal records applied by --recover\n"
            "  journal_records      records left in CASE/journal\n"
            "  final_poses          per fragment: id, name, fixed, q (w x y z), t (mm)\n"
            "  pose_digest          FNV-1a 64 over every accepted pose in order (hex)\n"
            "  penetrating          with --save: the fragment pairs that overlap in the saved\n"
            "                       poses (collision checking was off) and overlap_ml; null\n"
            "                       without --save\n\n"
            "  --realtime          pace the reports at recorded speed through the input thread and\n"
            "                      the live loop (default: as fast as possible, one thread)\n"
            "  --view V            with --realtime: window (default when $DISPLAY is set and OpenGL\n"
            "                      4.5 is there: the fragments drawn live at the loop's poses with\n"
            "                      navigate's HUD; the pointer and Ctrl+1..6 move the view, never the\n"
            "                      fragments; q, Escape or closing it closes the window and the\n"
            "                      replay runs on to its end) or terminal (no window); without a\n"
            "                      display or GL 4.5 there is no window, and a line says why\n"
            "  --screenshot FILE   the window at the end (the final poses), as a PNG\n"
            "  --json              print the summary as JSON\n"
            "  --recover           start from the poses the journal holds beyond case.json (a\n"
            "                      journal of another state of the case is kept aside as\n"
            "                      CASE/journal.mismatch.N and never applied; a damaged one as\n"
            "                      CASE/journal.damaged.N, keeping the records before the damage)\n"
            "  --discard-journal   start from case.json, emptying the journal\n"
            "  --no-journal        do not write CASE/journal\n"
            "  --save              save the final poses into the case (and empty the journal)\n"
            CMD_WAIT_HELP
            "  --frame F           camera (default), world or fragment\n"
            "  --pivot X Y Z       turn the first selected fragment about this point (world mm,\n"
            "                      LPS) instead of its centroid, until the selection changes\n"
            "  --config FILE       calibration in spnavrc syntax (default: none, sensitivity 1)\n"
            "  --tau-min T, --tau-max T   hierarchy thresholds instead of the case's (0 <= T_min\n"
            "                      <= T_max <= 1); --save keeps them in the case\n"
            "  --frames DIR        draw the fragments (anterior, 512x512, headless) at the loop's\n"
            "                      poses once per --frame-ms of the recording's time into\n"
            "                      DIR/frame_NNNNN.png (the last one: the final poses); not with\n"
            "                      --realtime\n"
            "  --force             --frames into a folder holding other files (those named\n"
            "                      frame_NNNNN.png are replaced); without it only an empty folder\n"
            "                      or one holding an earlier replay's frames alone is taken\n"
            "  --frame-ms N        the recording's milliseconds per picture (default 40)\n"
            "  --mode M            how the window and --frames draw: iso (default for --frames and\n"
            "                      on a GPU), dvr, mip or surface (the window's default on\n"
            "                      software GL); the window's F2 key changes it\n"
            "  --layout L          3d (default) or four-up (slices through the selected fragment's\n"
            "                      centroid); the window's F3 key changes it\n"
            "  --camera VIEW       the window's first view: auto (default), or anterior, posterior,\n"
            "                      left, right, superior, inferior, as navigate takes it\n"
            "  --overlay LIST      hierarchy[:DEPTH], contacts, axes, voi, as fracnav render takes\n"
            "                      them; the window's F6, F5, F4 and F9 keys turn them on and off\n"
            "  --help              this text\n");
}

typedef struct opts {
    const char *dir, *rec, *config;
    int realtime, json, no_journal, save, force;
    unsigned flags;
    loop_frame frame;
    cmd_tau tau;
    int have_pivot;
    double pivot[3];
    const char *frames; /* --frames DIR */
    double frame_ms;
    int view; /* NAVWIN_VIEW_* */
    navwin_look look;
    const char *screenshot;
} opts;

static int parse(int argc, char **argv, opts *o)
{
    memset(o, 0, sizeof *o);
    o->look = (navwin_look)NAVWIN_LOOK_DEFAULT;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        int rc;
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (cmd_tau_option("replay", a, v, &o->tau, &rc) || navwin_view_option("replay", a, v, &o->view, &rc) ||
            navwin_look_option("replay", a, v, &o->look, &rc)) {
            if (rc)
                return rc;
            i++;
        } else if (!strcmp(a, "--realtime"))
            o->realtime = 1;
        else if (!strcmp(a, "--json"))
            o->json = 1;
        else if (!strcmp(a, "--recover") || !strcmp(a, "--resume"))
            o->flags |= SESSION_RESUME;
        else if (!strcmp(a, "--discard-journal"))
            o->flags |= SESSION_DISCARD;
        else if (!strcmp(a, "--no-journal"))
            o->no_journal = 1;
        else if (!strcmp(a, "--save"))
            o->save = 1;
        else if (!strcmp(a, "--force"))
            o->force = 1;
        else if (!strcmp(a, "--frame") && i + 1 < argc) {
            if (session_frame_parse(argv[++i], &o->frame) < 0)
                return cmd_usage_error("replay", "%s", fn_err_msg());
        } else if (!strcmp(a, "--pivot")) {
            if (cmd_parse_pivot("replay", argc, argv, &i, o->pivot))
                return 2;
            o->have_pivot = 1;
        } else if (!strcmp(a, "--config") && i + 1 < argc)
            o->config = argv[++i];
        else if (!strcmp(a, "--frames")) {
            if (i + 1 >= argc)
                return cmd_bad_value("replay", a, NULL, "a folder for the pictures");
            o->frames = argv[++i];
        } else if (!strcmp(a, "--screenshot")) {
            if (!v)
                return cmd_bad_value("replay", a, v, "a PNG file to write");
            o->screenshot = argv[++i];
        } else if (!strcmp(a, "--frame-ms")) {
            if (!cmd_number(v, &o->frame_ms) || !(o->frame_ms >= 1) || o->frame_ms > 3600000)
                return cmd_bad_value("replay", a, v, "milliseconds from 1 to 3600000");
            i++;
        }
        else if (a[0] == '-' || (o->dir && o->rec)) {
            fprintf(stderr, "fracnav replay: unexpected argument '%s' (see fracnav replay --help)\n", a);
            return 2;
        } else if (!o->dir)
            o->dir = a;
        else
            o->rec = a;
    }
    if (!o->dir || !o->rec) {
        fprintf(stderr, "fracnav replay: need CASE and FILE.fnrec (see fracnav replay --help)\n");
        return 2;
    }
    if ((o->flags & SESSION_RESUME) && (o->flags & SESSION_DISCARD)) {
        fprintf(stderr, "fracnav replay: --recover and --discard-journal exclude each other\n");
        return 2;
    }
    if (o->frames && o->realtime)
        return cmd_usage_error("replay", "--frames draws the recording's time, not the wall clock's: "
                                         "leave out --realtime");
    if (o->view == NAVWIN_VIEW_WINDOW && !o->realtime)
        return cmd_usage_error("replay", "--view window shows the replay live: it needs --realtime");
    if (o->screenshot && (!o->realtime || o->view == NAVWIN_VIEW_TERMINAL))
        return cmd_usage_error("replay", "--screenshot saves the window: it needs --realtime (and --view window)");
    if (o->force && !o->frames)
        return cmd_usage_error("replay", "--force goes with --frames DIR");
    if (o->frame_ms && !o->frames)
        return cmd_usage_error("replay", "--frame-ms sets the pace of --frames DIR, which is missing");
    if (!o->frame_ms)
        o->frame_ms = 40;
    if (!o->no_journal)
        o->flags |= SESSION_JOURNAL;
    return 0;
}

/* --frames: a picture before each event that passes a frame's time (session_play_each), the
 * final one at the end. */
typedef struct frames {
    framedump *fd;
    session *k;
} frames;

static int frame_before(void *ctx, int64_t t_us)
{
    frames *f = ctx;
    return t_us < 0 ? framedump_finish(f->fd, f->k) : framedump_before(f->fd, f->k, t_us);
}

/* --realtime with a window: the session runs the recording on its threads (as navigate does)
 * while this thread draws the window at display rate, until the recording's end; then the
 * final poses are drawn and --screenshot saved. The window only watches: its keys and pointer
 * move the view, never the fragments, and closing it leaves the replay running. The poses are
 * those of session_play's, event for event. */
static int play_live(session *k, loop_source src, const opts *o)
{
    int rc = session_start(k, src);
    if (rc < 0)
        return rc;
    /* Opened once the loop runs, as navigate's: the loop prefaults the libraries loaded when it
     * starts, and GL's are none of its business. */
    const char *without = "the replay runs on without one";
    navwin *win = navwin_open_view("replay", o->view, &o->look, without, k, 0);
    if (o->screenshot && !win)
        fprintf(stderr, "fracnav replay: --screenshot %s: no window to save\n", o->screenshot);
    char copy[4096], device[4200];
    snprintf(copy, sizeof copy, "%s", o->rec);
    snprintf(device, sizeof device, "the recording %s", basename(copy));
    navview_extra x = {-1, NULL, NULL, session_frags(k), NULL, NULL};
    loop_scene sc = {0};
    session_event ev;
    for (int ended = 0, last = 0; !last;) {
        last = ended; /* one frame more after the end: the poses the loop reached */
        if (!ended && session_wait_event(k, win ? 16 : 100, &ev) == SESSION_EV_END) {
            ended = 1;
            rc = session_stop(k);
            while (session_wait_event(k, 0, &ev) != SESSION_EV_NONE)
                ;
        }
        if (!win)
            continue;
        session_scene_read(k, &sc);
        int keys[NAVWIN_KEYS], closed = 0, quit = 0;
        int n = navwin_show(win, &sc, &x, device, NULL, keys, NAVWIN_KEYS, &closed);
        if (n < 0)
            fprintf(stderr, "fracnav replay: the window: %s; %s\n", fn_err_msg(), without);
        for (int i = 0; i < n; i++)
            quit |= keys[i] == 'q' || keys[i] == 27;
        if (n < 0 || ((closed || quit) && !last)) {
            navwin_close(win);
            win = NULL;
            if (o->screenshot)
                fprintf(stderr, "fracnav replay: --screenshot %s: the window was closed before the end\n",
                        o->screenshot);
        }
    }
    if (win && o->screenshot && navwin_save_screenshot(win, "replay", o->screenshot) < 0)
        rc = rc ? rc : FN_EIO;
    navwin_close(win);
    return rc;
}

/* Plays the recording: with --frames, pictures along; with --realtime, a window if one opens;
 * else session_play. 0 or negative. */
static int run(session *k, session_dsource *ds, const opts *o, framedump *fd)
{
    int rc;
    loop_source src = session_device_source(ds);
    if (fd) {
        rc = session_play_each(k, src, frame_before, &(frames){fd, k});
    } else if (o->realtime && navwin_wanted("replay", o->view, "the replay runs on without one")) {
        rc = play_live(k, src, o);
    } else {
        if (o->screenshot) /* asked for, but no display */
            fprintf(stderr, "fracnav replay: --screenshot %s: no window to save\n", o->screenshot);
        rc = session_play(k, src, o->realtime ? SESSION_PLAY_REALTIME : SESSION_PLAY_FAST);
    }
    if (fd && rc == 0)
        fprintf(stderr, "fracnav replay: %ld pictures in %s\n", framedump_count(fd), o->frames);
    framedump_close(fd);
    return rc;
}

/* After the play (rc its result): the journal synced, the case saved (--save) or the journal
 * emptied, the summary printed. 0 or negative. */
static int finish(session *k, session_dsource *ds, const opts *o, int rc)
{
    if (rc == 0)
        rc = session_journal_sync(k);
    if (rc == 0 && o->save && (rc = session_save(k)) == 0)
        fprintf(stderr, "fracnav replay: saved the final poses of %d fragments in %s/case.json\n",
                session_nfrag(k), o->dir);
    else if (rc == 0 && !session_resumed(k))
        rc = session_journal_truncate(k); /* finished: the poses are in the summary, the case unchanged */
    if (rc < 0) {
        fprintf(stderr, "fracnav replay: %s\n", fn_err_msg());
    } else if (o->json) {
        rc = session_print_json(k, stdout, "replay", (long)session_source_unplugs(ds),
                                session_source_skipped(ds));
        if (rc < 0)
            fprintf(stderr, "fracnav replay: %s\n", fn_err_msg());
    } else {
        loop_stats s;
        session_stats(k, &s);
        printf("%llu steps: %llu accepted, %llu limited, %llu slid, %llu refused; collisions in "
               "accepted poses: %llu; latency p99 %.0f us; pose digest %016llx\n",
               (unsigned long long)s.steps, (unsigned long long)s.accepted,
               (unsigned long long)s.limited, (unsigned long long)s.slid,
               (unsigned long long)s.refused, (unsigned long long)s.collisions_in_accepted,
               s.latency_p99_us, (unsigned long long)s.pose_digest);
    }
    return rc;
}

/* What --frames writes (framedump: frame_NNNNN.png): an earlier replay's frames, replaced. */
static int own_frame(const char *name)
{
    size_t n = strlen(name), digits = strspn(name + (n > 6 ? 6 : n), "0123456789");
    return n > 10 && !strncmp(name, "frame_", 6) && digits >= 5 && !strcmp(name + 6 + digits, ".png");
}

int cmd_replay(int argc, char **argv)
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
    /* --frames replaces the frames a replay drew there before; other files only with --force */
    if ((o.screenshot && cmd_out_file(o.screenshot, NULL) < 0) ||
        (o.frames && cmd_out_folder_own(o.frames, o.force, own_frame) < 0)) {
        fprintf(stderr, "fracnav replay: %s\n", fn_err_msg());
        return 1;
    }
    calib cal;
    if (session_calib_setup(&cal, o.config, 1, "fracnav replay") < 0) {
        fprintf(stderr, "fracnav replay: %s\n", fn_err_msg());
        return 1;
    }
    /* Exclusive when it writes the journal or the case, for the whole run. */
    int writes = !o.no_journal || o.save || (o.flags & SESSION_DISCARD);
    caselock *lock = session_lock_case("replay", o.dir, writes, wait);
    if (!lock)
        return 1;
    loop_config cfg;
    session_config_default(&cfg);
    char spec[4200];
    snprintf(spec, sizeof spec, "%s:%s", o.realtime ? "replay-realtime" : "replay", o.rec);
    session_dsource *ds = session_source_open(spec, &cal, 0, &cfg);
    if (!ds) {
        fprintf(stderr, "fracnav replay: %s\n", fn_err_msg());
        session_unlock(lock);
        return 1;
    }
    /* A replay saves only at its end (--save) and never fits: with the window its session
     * would carry those buttons out mid-run, and the results would depend on the view. */
    for (size_t b = 0; b < sizeof cfg.button_action; b++)
        if (cfg.button_action[b] == LOOP_ACT_SAVE || cfg.button_action[b] == LOOP_ACT_FIT)
            cfg.button_action[b] = LOOP_ACT_NONE;
    cfg.frame = o.frame;
    cfg.check_invariant = 1;
    session_params sp = {cfg, o.flags, "replay", cmd_tau_prepare, &o.tau, 0};
    session *k = session_open(o.dir, &sp);
    if (!k) {
        fprintf(stderr, "fracnav replay: %s\n", fn_err_msg());
        session_dsource_free(ds);
        session_unlock(lock);
        return 1;
    }
    fprintf(stderr, "fracnav replay: stepping %s on %s\n", o.rec, o.dir);
    if (o.have_pivot)
        session_set_pivot(k, o.pivot);
    framedump *fd = NULL;
    if (o.frames && !(fd = framedump_open(o.frames, session_case(k), o.frame_ms, 512, 512, &o.look))) {
        fprintf(stderr, "fracnav replay: %s\n", fn_err_msg());
        session_close(k);
        session_dsource_free(ds);
        session_unlock(lock);
        return 1;
    }
    rc = run(k, ds, &o, fd);
    rc = finish(k, ds, &o, rc);
    session_close(k);
    session_dsource_free(ds);
    session_unlock(lock);
    return rc < 0 ? 1 : 0;
}
