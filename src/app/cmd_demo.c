/* fracnav demo: the whole workflow on the example CT: segment, fracture, navigate a shipped
 * recording through the virtual device and the real driver path, reduce, export, report. */
#include "case.h"
#include "cmd.h"
#include "err.h"
#include "fnclock.h"
#include "fnrec.h"
#include "fracture.h"
#include "journal.h"
#include "navwin.h"
#include "render.h"
#include "seg.h"
#include "vol.h"
#include "volio.h"

#include <errno.h>
#include <fcntl.h>
#include <jansson.h>
#include <libgen.h>
#include <limits.h>
#include <math.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#define RECORDING "demo-approach.fnrec"

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav demo [CT] [-o DIR] [--recording FILE.fnrec] [--no-fuse]\n"
            "                    [--view window|terminal] [--threshold HU|auto|auto-bone]\n"
            "                    [--tau-min T] [--tau-max T]\n\n"
            "Runs fracnav's whole workflow on a CT (default: the example skull CT that .ci/setup\n"
            "caches, $FRACNAV_DATA/Cranium.inv3 or /var/cache/fracnav/Cranium.inv3) and writes its\n"
            "results to DIR (default ./fracnav-demo):\n"
            "  1. segments the bone at 300 HU (or --threshold) into fragments and saves the case\n"
            "     in DIR/case (picture: DIR/segmentation-anterior.png, drawn by the renderer);\n"
            "  2. breaks the skull in two along a rough fractal surface and displaces one piece by a\n"
            "     known rigid transform: a synthetic fracture with ground truth, DIR/fracture\n"
            "     (picture: DIR/fracture-anterior.png);\n"
            "  3. serves the virtual SpaceNavigator (fracnav-sim, through FUSE) playing the shipped\n"
            "     recording " RECORDING " and steers the loose piece with it through\n"
            "     `fracnav navigate` and the real hidraw driver: lifted, turned and pushed towards\n"
            "     its place, the push refused where the fracture surfaces meet (without FUSE, the\n"
            "     recording plays in-process: replay-realtime:); navigate shows it live, in its\n"
            "     window when a display exists (else on standard error), and the renderer draws 8\n"
            "     frames of it headless from the poses navigate journalled:\n"
            "     DIR/frames/navigation-00.png .. -07.png;\n"
            "  4. runs the automatic reduction (`fracnav reduce`) and measures it against the truth;\n"
            "  5. exports everything (`fracnav export --all DIR/export`): ITK transforms, a 3D Slicer\n"
            "     segmentation, a NIfTI labelmap, STL models and the report DIR/export/report/index.html;\n"
            "  6. prints where the results are and the figures measured: collision query time, loop\n"
            "     rate, reduction error and time.\n\n"
            "  -o DIR                     where the results go (default ./fracnav-demo; a run\n"
            "                             replaces an earlier demo's there; never a case folder)\n"
            "  --force                    -o into a folder holding other files too (without it,\n"
            "                             only an empty folder or an earlier demo's is taken)\n"
            "  --recording FILE           the navigation recording (default: the shipped\n"
            "                             sim/recordings/" RECORDING ")\n"
            "  --no-fuse                  play the recording in-process, not through fracnav-sim\n"
            "  --view V                   navigate's view: window (default when $DISPLAY is set and\n"
            "                             OpenGL 4.5 is there) or terminal (standard error alone)\n"
            CMD_THRESHOLD_HELP "                             (for segmentation and fracture alike)\n" CMD_TAU_HELP
            "                             (kept in both cases the demo saves)\n");
}

static int fail(const char *what)
{
    if (what && !strncmp(fn_err_msg(), what, strlen(what)))
        what = NULL; /* the message names the step already */
    fprintf(stderr, "fracnav demo: %s%s%s\n", what ? what : "", what ? ": " : "", fn_err_msg());
    return 1;
}

/* This program's path, and the folder it is in. */
static int self_path(char *exe, size_t cap, char *dir, size_t dcap)
{
    ssize_t n = readlink("/proc/self/exe", exe, cap - 1);
    if (n <= 0)
        return -1;
    exe[n] = 0;
    char copy[PATH_MAX];
    snprintf(copy, sizeof copy, "%s", exe);
    snprintf(dir, dcap, "%s", dirname(copy));
    return 0;
}

static int is_file(const char *p)
{
    struct stat st;
    return stat(p, &st) == 0 && S_ISREG(st.st_mode);
}

/* The shipped recording: $FRACNAV_SRC/sim/recordings, the source tree this was built from, then
 * the installed share/fracnav/recordings beside bin/. */
static char *find_recording(const char *bindir)
{
    static char path[PATH_MAX + 64];
    const char *src = getenv("FRACNAV_SRC");
    if (src && *src) {
        snprintf(path, sizeof path, "%s/sim/recordings/" RECORDING, src);
        if (is_file(path))
            return path;
    }
    snprintf(path, sizeof path, "%s/sim/recordings/" RECORDING, FRACNAV_SOURCE_DIR);
    if (is_file(path))
        return path;
    snprintf(path, sizeof path, "%s/../share/fracnav/recordings/" RECORDING, bindir);
    return is_file(path) ? path : NULL;
}

/* Runs argv with stdin from /dev/null, stdout into out_path and stderr into err_path (NULL:
 * inherited); returns the pid, or -1. */
static pid_t spawn(char *const argv[], const char *out_path, const char *err_path)
{
    fflush(stdout);
    fflush(stderr);
    pid_t pid = fork();
    if (pid != 0)
        return pid;
    int in = open("/dev/null", O_RDONLY);
    if (in >= 0)
        dup2(in, 0);
    if (out_path) {
        int fd = open(out_path, O_WRONLY | O_CREAT | O_TRUNC | O_NOFOLLOW, 0644);
        if (fd >= 0)
            dup2(fd, 1);
    }
    if (err_path) {
        int fd = open(err_path, O_WRONLY | O_CREAT | O_TRUNC | O_NOFOLLOW, 0644);
        if (fd >= 0)
            dup2(fd, 2);
    }
    execvp(argv[0], argv);
    fprintf(stderr, "fracnav demo: cannot run %s: %s\n", argv[0], strerror(errno));
    _exit(127);
}

static int wait_status(pid_t pid)
{
    int st;
    while (waitpid(pid, &st, 0) < 0)
        if (errno != EINTR)
            return -1;
    return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

typedef void (*watch_fn)(void *ctx);

/* Runs a fracnav command with --json; its object (NULL: it failed, and its stderr was shown).
 * live: its standard error (navigate's view) goes to ours as it comes, not to DIR/NAME.log.
 * watch, when given, is called every 20 ms while the command runs. */
static json_t *fracnav_json(char *exe, const char *dir, const char *name, char *const args[], int live,
                            watch_fn watch, void *ctx)
{
    char *argv[24] = {exe};
    int n = 1;
    for (; args[n - 1] && n < 22; n++)
        argv[n] = args[n - 1];
    argv[n++] = "--json";
    argv[n] = NULL;
    char out[PATH_MAX], err[PATH_MAX];
    snprintf(out, sizeof out, "%s/%s.json", dir, name);
    snprintf(err, sizeof err, "%s/%s.log", dir, name);
    pid_t pid = spawn(argv, out, live ? NULL : err);
    for (;;) { /* until it ends (left to be reaped below) */
        siginfo_t si;
        memset(&si, 0, sizeof si);
        if (!watch || pid <= 0 || waitid(P_PID, (id_t)pid, &si, WEXITED | WNOHANG | WNOWAIT) != 0 ||
            si.si_pid == pid)
            break;
        watch(ctx);
        usleep(20000);
    }
    int st = pid > 0 ? wait_status(pid) : -1;
    json_error_t e;
    json_t *j = st == 0 ? json_load_file(out, 0, &e) : NULL;
    if (!j) {
        fn_err_set(FN_EINVAL, "`fracnav %s` failed (exit %d%s%s)", args[0], st, live ? "" : "; its messages are in ",
                   live ? "" : err);
        FILE *fp = live ? NULL : fopen(err, "r");
        if (fp) {
            char line[512];
            while (fgets(line, sizeof line, fp))
                fprintf(stderr, "   | %s", line);
            fclose(fp);
        }
    }
    return j;
}

static double num(json_t *o, const char *key)
{
    json_t *v = json_object_get(o, key);
    return json_is_number(v) ? json_number_value(v) : NAN;
}

/* A picture of a case at its poses by the renderer (iso surfaces, anterior view). */
static int picture(const planning_case *c, render_view view, const char *path)
{
    const int w = 512, h = 512;
    if (c->nfrag > RENDER_MAX_FRAGS)
        return fn_err_set(FN_EINVAL, "%d fragments: the renderer draws at most %d", c->nfrag, RENDER_MAX_FRAGS);
    render *r = render_open("osmesa", w, h);
    if (!r)
        return FN_ENODEV;
    int rc = render_set_scene(r, c->ct, c->frag, c->nfrag, c->seg.threshold, NULL);
    render_options o;
    render_options_default(&o, c->frag, c->nfrag);
    render_camera_standard(&o.camera, view, c->frag, c->nfrag);
    if (!rc)
        rc = render_frame(r, NULL, &o);
    if (!rc)
        rc = cmd_write_png(r, path, w, h);
    render_close(r);
    return rc;
}

/* --threshold, for steps 1 and 2. */
typedef struct demo_threshold {
    double value;
    int automatic;
} demo_threshold;

/* Step 1: segmentation, saved as a case. Takes ownership of ct. */
static planning_case *segment(const char *ct_path, vol *ct, const char *dir, const cmd_tau *tau,
                              const demo_threshold *thr)
{
    seg_params sp;
    seg_defaults(&sp);
    sp.threshold = thr->value;
    sp.threshold_auto = thr->automatic;
    int64_t t0 = fnclock_now_us();
    seg_result sr;
    if (seg_run(ct, &sp, &sr) < 0 || cmd_seg_found(ct, &sp, &sr, NULL) < 0) {
        seg_result_free(&sr);
        vol_free(ct);
        return NULL;
    }
    double t_seg = (double)(fnclock_now_us() - t0) * 1e-6;
    printf("1. segmentation at %.0f HU: %d components, %d kept (>= %.2f ml) in %.0f ms\n", sr.threshold,
           sr.raw_components, sr.ncomp, sp.min_volume_ml, t_seg * 1e3);
    vol *labels = sr.labels;
    sr.labels = NULL;
    char casedir[PATH_MAX], png[PATH_MAX];
    snprintf(casedir, sizeof casedir, "%s/case", dir);
    planning_case *c = case_create(casedir, ct_path, ct, labels, &sp);
    if (!c) {
        seg_result_free(&sr);
        return NULL;
    }
    for (int i = 0; i < sr.ncomp && i < c->nfrag; i++) {
        const seg_component *sc = &sr.comp[i];
        printf("   fragment %d: %zu voxels, %.1f ml, peak %.0f HU: %s\n", sc->label, sc->voxels, sc->volume_ml,
               sc->peak, sc->peak < 1000 ? "not bone (the CT head holder)" : "bone");
    }
    seg_result_free(&sr);
    cmd_tau_apply(tau, &c->tau_min, &c->tau_max); /* checked with the options */
    if (case_save(c) < 0) {
        case_free(c);
        return NULL;
    }
    snprintf(png, sizeof png, "%s/segmentation-anterior.png", dir);
    if (picture(c, RENDER_ANTERIOR, png) < 0) {
        case_free(c);
        return NULL;
    }
    printf("   saved the case in %s; picture %s\n", casedir, png);
    return c;
}

/* Step 2: a synthetic fracture of the segmented CT, with its ground truth. */
static int fracture(const planning_case *seg, const char *dir, const cmd_tau *tau,
                    const demo_threshold *thr)
{
    fracture_params fp;
    fracture_defaults(&fp);
    fp.threshold = thr->value;
    fp.threshold_auto = thr->automatic;
    cmd_tau_apply(tau, &fp.tau_min, &fp.tau_max);
    char casedir[PATH_MAX], png[PATH_MAX];
    snprintf(casedir, sizeof casedir, "%s/fracture", dir);
    int64_t t0 = fnclock_now_us();
    planning_case *c = fracture_make_case(seg->ct, &fp, casedir);
    if (!c)
        return -1;
    printf("2. synthetic fracture (seed %llu) in %.1f s, saved in %s:\n", (unsigned long long)fp.seed,
           (double)(fnclock_now_us() - t0) * 1e-6, casedir);
    for (int i = 0; i < c->nfrag; i++) {
        const frag *f = &c->frag[i];
        pose t = c->truth[i];
        printf("   fragment %d: %zu voxels%s; its true place is %.2f mm and %.2f deg away\n", f->id, f->voxels,
               i == c->fixed ? " (fixed)" : "", fracture_truth_shift(&t, f->centroid),
               pose_angle_between(t, POSE_IDENTITY) * 57.29577951308232);
    }
    snprintf(png, sizeof png, "%s/fracture-anterior.png", dir);
    int rc = picture(c, RENDER_ANTERIOR, png);
    if (rc == 0)
        printf("   picture: %s\n", png);
    case_free(c);
    return rc;
}

/* Waits (bounded) for a file to appear; 1 when it did. */
static int wait_file(const char *path, pid_t server)
{
    for (int i = 0; i < 2000; i++) { /* 20 s at most: FUSE mounts in milliseconds */
        struct stat st;
        if (stat(path, &st) == 0)
            return 1;
        if (waitpid(server, NULL, WNOHANG) == server)
            return 0;
        usleep(10000);
    }
    return 0;
}

/* Navigate's journal as it grows (it is emptied when navigate saves at its end): the accepted
 * poses of the session, for the frames. */
typedef struct journal_watch {
    char path[PATH_MAX + 16];
    journal_scan best;
} journal_watch;

static void watch_journal(void *ctx)
{
    journal_watch *w = ctx;
    size_t len = 0, cap = 0;
    uint8_t *buf = NULL;
    FILE *fp = fopen(w->path, "rb");
    if (!fp)
        return;
    for (;;) {
        if (len == cap) {
            uint8_t *b = realloc(buf, cap = cap ? cap * 2 : 1 << 16);
            if (!b)
                break;
            buf = b;
        }
        size_t got = fread(buf + len, 1, cap - len, fp);
        if (!got)
            break;
        len += got;
    }
    fclose(fp);
    journal_scan s;
    if (buf && journal_parse(buf, len, w->path, &s) == 0) {
        if (s.n > w->best.n) {
            journal_scan_free(&w->best);
            w->best = s;
        } else {
            journal_scan_free(&s);
        }
    }
    free(buf);
}

/* Frames of the navigation, drawn headless from the poses navigate journalled: nframes pictures
 * evenly over the session's report time. c: the case as it was before navigation. */
static int frames(const planning_case *c, const journal_scan *j, const char *dir, int nframes)
{
    if (j->n == 0 || c->nfrag > RENDER_MAX_FRAGS)
        return 0;
    char fdir[PATH_MAX], path[PATH_MAX + 32];
    snprintf(fdir, sizeof fdir, "%s/frames", dir);
    if (mkdir(fdir, 0777) != 0 && errno != EEXIST)
        return fn_err_set(FN_EIO, "%s: %s", fdir, strerror(errno));
    const int w = 384, h = 384;
    pose *p = malloc((size_t)c->nfrag * sizeof *p);
    render *r = p ? render_open("osmesa", w, h) : NULL;
    int rc = !p ? fn_err_set(FN_ENOMEM, "out of memory for the frames") : r ? 0 : FN_ENODEV;
    if (!rc)
        rc = render_set_scene(r, c->ct, c->frag, c->nfrag, c->seg.threshold, NULL);
    render_options o;
    render_options_default(&o, c->frag, c->nfrag);
    render_camera_standard(&o.camera, RENDER_RIGHT, c->frag, c->nfrag);
    for (int i = 0; i < c->nfrag && !rc; i++)
        p[i] = c->frag[i].pose;
    int64_t t0 = j->recs[0].t_us, t1 = j->recs[j->n - 1].t_us;
    size_t next = 0;
    for (int f = 0; f < nframes && !rc; f++) {
        int64_t t = t0 + (nframes > 1 ? (t1 - t0) * f / (nframes - 1) : 0);
        for (; next < j->n && j->recs[next].t_us <= t; next++)
            if (j->recs[next].frag >= 0 && j->recs[next].frag < c->nfrag)
                p[j->recs[next].frag] = j->recs[next].p;
        snprintf(path, sizeof path, "%s/navigation-%02d.png", fdir, f);
        rc = render_frame(r, p, &o);
        if (!rc)
            rc = cmd_write_png(r, path, w, h);
    }
    if (!rc)
        printf("   frames (headless, from the poses navigate journalled): %s/navigation-00.png .. -%02d.png\n", fdir,
               nframes - 1);
    render_close(r);
    free(p);
    return rc;
}

/* Step 3: the shipped recording through the virtual device and navigate. The navigate summary. */
static json_t *navigate(char *exe, const char *bindir, const char *dir, char *rec, int no_fuse, int view)
{
    char casedir[PATH_MAX], mnt[PATH_MAX], node[PATH_MAX + 16], sim[PATH_MAX + 32], dur[32], dev[PATH_MAX + 128];
    snprintf(casedir, sizeof casedir, "%s/fracture", dir);
    fnrec *r = fnrec_load(rec);
    if (!r) {
        fn_err_wrap(FN_EIO, "the demo's recording");
        return NULL;
    }
    double seconds = r->n ? (double)r->ev[r->n - 1].t_us * 1e-6 : 0;
    fnrec_free(r);
    snprintf(dur, sizeof dur, "%.1f", seconds + 1.0);
    pid_t server = -1;
    const char *how = NULL;
    if (!no_fuse) {
        snprintf(sim, sizeof sim, "%s/sim/fracnav-sim", bindir);
        if (!is_file(sim))
            snprintf(sim, sizeof sim, "%s/fracnav-sim", bindir);
        snprintf(mnt, sizeof mnt, "%s/device", dir);
        snprintf(node, sizeof node, "%s/hidraw0", mnt);
        mkdir(mnt, 0777);
        char log[PATH_MAX];
        snprintf(log, sizeof log, "%s/fracnav-sim.log", dir);
        char *argv[] = {sim, "serve", "--mount", mnt, "--play", rec, "--start-on-read", NULL};
        if (is_file(sim) && (server = spawn(argv, NULL, log)) > 0 && wait_file(node, server)) {
            snprintf(dev, sizeof dev, "%s", node);
            how = "served by fracnav-sim through FUSE, read by the hidraw driver";
        } else {
            if (server > 0) {
                kill(server, SIGTERM);
                wait_status(server);
                server = -1;
            }
            printf("   (no FUSE here: see %s; the recording plays in-process instead)\n", log);
        }
    }
    if (!how) {
        snprintf(dev, sizeof dev, "replay-realtime:%s", rec);
        how = "played in-process at its own pace (replay-realtime)";
    }
    printf("3. navigation: the recording %s (%.1f s), %s:\n", rec, seconds, how);
    fflush(stdout);
    planning_case *before = case_load(casedir); /* the poses the frames start from */
    journal_watch w;
    memset(&w, 0, sizeof w);
    snprintf(w.path, sizeof w.path, "%s/journal", casedir);
    char *args[] = {"navigate", casedir, "--device", dev, "--discard-journal", "--duration", dur, NULL, NULL, NULL};
    if (view != NAVWIN_VIEW_AUTO) { /* else navigate's own default: the window with a display */
        args[7] = "--view";
        args[8] = view == NAVWIN_VIEW_WINDOW ? "window" : "terminal";
    }
    json_t *j = before ? fracnav_json(exe, dir, "navigate", args, 1, watch_journal, &w) : NULL;
    if (server > 0) {
        kill(server, SIGTERM);
        wait_status(server);
    }
    if (j && frames(before, &w.best, dir, 8) < 0) {
        json_decref(j);
        j = NULL;
    }
    journal_scan_free(&w.best);
    case_free(before);
    return j;
}

/* The navigation's line: its steps and the loop's figures. */
static void print_navigation(json_t *nav)
{
    printf("   %lld steps: %lld accepted, %lld limited, %lld slid, %lld refused; collisions in accepted poses: "
           "%lld; loop %.0f Hz, collision query mean %.2f us (max %.1f us), latency p99 %.0f us\n",
           json_integer_value(json_object_get(nav, "steps")), json_integer_value(json_object_get(nav, "accepted")),
           json_integer_value(json_object_get(nav, "limited")), json_integer_value(json_object_get(nav, "slid")),
           json_integer_value(json_object_get(nav, "refused")),
           json_integer_value(json_object_get(nav, "collisions_in_accepted")), num(nav, "loop_hz"),
           num(nav, "query_mean_us"), num(nav, "query_max_us"), num(nav, "latency_p99_us"));
}

/* The closing lines: where the results are, the figures measured, what to do next. */
static void print_results(const char *dir, const char *exdir, const char *casedir, json_t *nav, json_t *red,
                          json_t *fr, double total)
{
    printf("\n6. results in %s:\n"
           "   the report:        %s/report/index.html\n"
           "   3D Slicer:         %s/planned.seg.nrrd, %s/transforms/fragment-ID.tfm\n"
           "   labelmap:          %s/planned.nii.gz\n"
           "   models (printing): %s/models/fragment-ID.stl\n"
           "   cases:             %s/case (segmented), %s (fractured, navigated, reduced)\n"
           "figures measured (on this machine, noisy when it is shared):\n"
           "   collision query:   mean %.2f us, max %.1f us\n"
           "   loop rate:         %.0f Hz (paced by the device's reports; latency p99 %.0f us)\n"
           "   reduction:         %.2f s; error %.2f deg, %.2f mm, TRE %.2f mm\n"
           "   whole demo:        %.1f s\n",
           dir, exdir, exdir, exdir, exdir, exdir, dir, casedir, num(nav, "query_mean_us"), num(nav, "query_max_us"),
           num(nav, "loop_hz"), num(nav, "latency_p99_us"), num(red, "seconds"), num(fr, "rot_err_deg"),
           num(fr, "trans_err_mm"), num(fr, "tre_mm"), total);
    printf("\nNext: open the report in a browser, or steer it yourself with `fracnav navigate %s` (a 3D "
           "mouse, or --device keyboard).\n", casedir);
}

/* What the command line asks for. */
typedef struct demo_opts {
    const char *ct_path, *dir;
    char *rec;
    cmd_tau tau;
    demo_threshold thr;
    int no_fuse, view, force;
} demo_opts;

/* Reads the arguments into o; 0, 2 (usage) or -1 (--help printed). */
static int parse(int argc, char **argv, demo_opts *o)
{
    int rc;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            usage(stdout);
            return -1;
        } else if (!strcmp(argv[i], "-o") && i + 1 < argc) {
            o->dir = argv[++i];
        } else if (!strcmp(argv[i], "--recording") && i + 1 < argc) {
            o->rec = argv[++i];
        } else if (!strcmp(argv[i], "--no-fuse")) {
            o->no_fuse = 1;
        } else if (!strcmp(argv[i], "--force")) {
            o->force = 1;
        } else if (cmd_tau_option("demo", argv[i], i + 1 < argc ? argv[i + 1] : NULL, &o->tau, &rc) ||
                   cmd_threshold_option("demo", argv[i], i + 1 < argc ? argv[i + 1] : NULL, &o->thr.value,
                                        &o->thr.automatic, &rc) ||
                   navwin_view_option("demo", argv[i], i + 1 < argc ? argv[i + 1] : NULL, &o->view, &rc)) {
            if (rc)
                return rc;
            i++;
        } else if (argv[i][0] == '-' || o->ct_path) {
            fprintf(stderr, "fracnav demo: unexpected argument '%s'\n", argv[i]);
            usage(stderr);
            return 2;
        } else {
            o->ct_path = argv[i];
        }
    }
    return 0;
}

/* What a demo writes in DIR (its steps' folders, pictures, outputs and logs, and a staged case
 * an interrupted step left): an earlier demo's results, which a run replaces. */
static int own_result(const char *name)
{
    static const char *const names[] = {"case", "fracture", "frames", "device", "export",
                                        "segmentation-anterior.png", "fracture-anterior.png",
                                        "fracnav-sim.log", "navigate.json", "navigate.log",
                                        "reduce.json", "reduce.log", "export.json", "export.log"};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        size_t n = strlen(names[i]);
        if (!strcmp(name, names[i]) || /* or staged: .NAME.new-PID (case_stage_begin) */
            (name[0] == '.' && !strncmp(name + 1, names[i], n) && !strncmp(name + 1 + n, ".new-", 5)))
            return 1;
    }
    return !strncmp(name, ".fracnav-tmp-", 13); /* a file being written (durable) */
}

int cmd_demo(int argc, char **argv)
{
    demo_opts o = {.dir = "fracnav-demo", .thr = {300, 0}, .view = NAVWIN_VIEW_AUTO};
    int rc = parse(argc, argv, &o);
    if (rc)
        return rc < 0 ? 0 : rc;
    const char *ct_path = o.ct_path, *dir = o.dir;
    char *rec = o.rec;
    cmd_tau tau = o.tau;
    demo_threshold thr = o.thr;
    if ((rc = cmd_tau_check("demo", &tau)) != 0)
        return rc;
    /* a run replaces the results an earlier demo left in DIR, never a case's files; other
     * files only with --force */
    if (cmd_out_folder_own(dir, o.force, own_result) < 0) {
        fprintf(stderr, "fracnav demo: -o %s\n", fn_err_msg());
        return 1;
    }
    char exe[PATH_MAX], bindir[PATH_MAX / 2];
    if (self_path(exe, sizeof exe, bindir, sizeof bindir) != 0) {
        fprintf(stderr, "fracnav demo: cannot find this program (/proc/self/exe): %s\n", strerror(errno));
        return 1;
    }
    if (!rec && !(rec = find_recording(bindir))) {
        fprintf(stderr, "fracnav demo: the shipped recording " RECORDING " is missing (looked in "
                        "$FRACNAV_SRC/sim/recordings, %s/sim/recordings and %s/../share/fracnav/recordings); "
                        "give one with --recording\n", FRACNAV_SOURCE_DIR, bindir);
        return 1;
    }
    int example = !ct_path; /* only the example CT comes from .ci/setup */
    if (example)
        ct_path = cmd_example_ct();
    if (mkdir(dir, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "fracnav demo: cannot create %s: %s\n", dir, strerror(errno));
        return 1;
    }
    int64_t t0 = fnclock_now_us();
    vol *ct = volio_read(ct_path);
    if (!ct) {
        fprintf(stderr, "fracnav demo: %s\n%s", fn_err_msg(),
                example ? "(the example CT comes with the README's first command, .ci/setup)\n" : "");
        return 1;
    }
    printf("fracnav demo on %s\n0. CT: %dx%dx%d voxels, %.3fx%.3fx%.3f mm, read in %.0f ms\n", ct_path,
           ct->dim[0], ct->dim[1], ct->dim[2], ct->spacing[0], ct->spacing[1], ct->spacing[2],
           (double)(fnclock_now_us() - t0) * 1e-3);
    planning_case *c = segment(ct_path, ct, dir, &tau, &thr);
    if (!c)
        return fail("segmentation");
    rc = fracture(c, dir, &tau, &thr);
    case_free(c);
    if (rc < 0)
        return fail("fracture");

    json_t *nav = navigate(exe, bindir, dir, rec, o.no_fuse, o.view);
    if (!nav)
        return fail("navigation");
    print_navigation(nav);

    char casedir[PATH_MAX], exdir[PATH_MAX];
    snprintf(casedir, sizeof casedir, "%s/fracture", dir);
    snprintf(exdir, sizeof exdir, "%s/export", dir);
    printf("4. automatic reduction (fracnav reduce):\n");
    char *rargs[] = {"reduce", casedir, NULL};
    json_t *red = fracnav_json(exe, dir, "reduce", rargs, 0, NULL, NULL);
    if (!red) {
        json_decref(nav);
        return fail("reduction");
    }
    json_t *fr = json_array_get(json_object_get(red, "fragments"), 0);
    printf("   fragment %lld: %lld evaluations in %.2f s; error against the truth: %.2f deg, %.2f mm "
           "(TRE %.2f mm)\n",
           json_integer_value(json_object_get(fr, "id")), json_integer_value(json_object_get(fr, "evaluations")),
           num(red, "seconds"), num(fr, "rot_err_deg"), num(fr, "trans_err_mm"), num(fr, "tre_mm"));

    printf("5. export (fracnav export --all %s):\n", exdir);
    char *eargs[] = {"export", casedir, "--all", exdir, "--smooth", "10", "--decimate", "200000", "--force", NULL};
    json_t *ex = fracnav_json(exe, dir, "export", eargs, 0, NULL, NULL);
    if (!ex) {
        json_decref(nav);
        json_decref(red);
        return fail("export");
    }
    printf("   %lld files, %.1f MB\n", json_integer_value(json_object_get(ex, "files_written")),
           (double)json_integer_value(json_object_get(ex, "written_total_bytes")) / 1e6);

    print_results(dir, exdir, casedir, nav, red, fr, (double)(fnclock_now_us() - t0) * 1e-6);
    json_decref(nav);
    json_decref(red);
    json_decref(ex);
    return 0;
}
