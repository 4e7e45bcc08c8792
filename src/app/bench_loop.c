/* fracnav bench loop: the navigation loop's rate and report-to-pose latency near contact.
 *
 * Workload: a two-piece synthetic fracture (fracture_make, seed 1) of the example CT (about
 * 148x178x106 and 145x92x100 voxel fragments, in contact along a rough fracture surface), piece 1
 * fixed, probability maps and hierarchy thresholds as `fracnav fracture` gives a case. Input: a motion script (pushing piece 2 into piece 1 and along it, turning it) rendered
 * by the virtual device's generator into SpaceNavigator reports, replayed as fast as the loop takes
 * them: the input thread hands over one report, stamps it, and waits until the loop has taken it
 * (no queueing in the latency). The loop runs as in `navigate`: its own thread, woken per event.
 * --fitted: piece 2 fitted first (reduce_fit_one, as navigate's fit action), so that it starts
 * inside piece 1 within the fit's tolerance, as a case that `reduce` left; the loop measures it
 * there as a session that opens such a case does, and the script starts with the motion of
 * `fracnav demo`'s recording (APPROACH), as `replay` of it on a reduced case: lifted off the fit,
 * turned and pushed home, its first steps taken with the pair caches the opening left.
 * --preview: navigate's live preview fits beside the loop (its worker at nice 19), so that its
 * cost to the hand shows in the loop's figures. */
#include "cmd.h"
#include "bench.h"
#include "caselock.h"

#include "err.h"
#include "fracture.h"
#include "jsonw.h"
#include "reduce.h"
#include "script.h"
#include "seg.h"
#include "session.h"
#include "sim_replay.h"
#include "volio.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char SCRIPT[] = "move y 10 mm x 3 mm over 2 s\n"
                             "move x -6 mm y 4 mm rz 3 deg over 2 s\n"
                             "move z 4 mm y 3 mm rx 2 deg over 2 s\n"
                             "move x 4 mm y 2 mm z -3 mm ry 2 deg over 2 s\n"
                             "move y 6 mm rz -3 deg over 1 s\n";

/* The motion of sim/recordings/demo-approach.script (the demo's recording), played first by
 * --fitted: a replay of that recording on a reduced case is what this workload stands for. */
static const char APPROACH[] = "wait 100 ms\n"
                               "translate -y 3 mm over 0.5 s\n"
                               "rotate z +2.4 deg over 0.4 s\n"
                               "rotate y +1.7 deg over 0.4 s\n"
                               "rotate x +0.4 deg over 0.2 s\n"
                               "translate -x 1.2 mm over 0.3 s\n"
                               "translate +z 1.4 mm over 0.3 s\n"
                               "translate +y 10 mm over 1.2 s\n";

static void usage(FILE *out)
{
    fprintf(out, "usage: fracnav bench loop [--json] [--ct FILE [--fitted] | --case DIR [--wait]] [--preview]\n"
                 "                        [--realtime] [--repeat N]\n\n"
                 "Drive the navigation loop near contact as fast as the (virtual) device's reports\n"
                 "can be fed, and report loop_hz (steps per second), latency_p50/p99/max_us (report\n"
                 "read -> accepted pose), outcomes and collision query time.\n\n"
                 "  --json        one JSON object on stdout (\"command\": \"bench loop\"; the keys\n"
                 "                of fracnav replay --json, with workload, fragments, wall_s,\n"
                 "                loop_thread_sched_fifo, targets and the preview's members)\n"
                 "  --ct FILE     CT to fracture (default: the example CT, $FRACNAV_DATA/Cranium.inv3\n"
                 "                or /var/cache/fracnav/Cranium.inv3)\n"
                 "  --fitted      fit piece 2 to piece 1 first (as navigate's fit action): the\n"
                 "                loop starts where a fit left it, inside within the fit's tolerance,\n"
                 "                and the script starts with the motion of the demo's recording\n"
                 "                (sim/recordings/demo-approach.script), as replay of it on a\n"
                 "                reduced case\n"
                 "  --case DIR    steer an existing case instead (its journal is left alone),\n"
                 "                holding it as navigate does: refused while another command\n"
                 "                holds it\n"
                 "  --wait        with --case: wait for the case while another command holds it\n"
                 "  --preview     run navigate's live preview beside the loop (its worker fits the\n"
                 "                moving piece near contact, at nice 19): the loop's figures with it;\n"
                 "                preview_updates_count, preview_updates_mean_hz, preview_dropped_count\n"
                 "  --realtime    feed the reports at the recording's pace (9 s a play), as a hand\n"
                 "                gives them, instead of as fast as the loop takes them\n"
                 "  --repeat N    play the 9 s motion script N times (default 10)\n"
                 "  --tau-min T, --tau-max T   hierarchy thresholds (default: the case's, or a new\n"
                 "                case's 0.5 and 0.95), 0 <= T_min <= T_max <= 1\n");
}

/* Two fragments from a fracture of the CT at path. */
static int fragments_from_ct(const char *path, frag f[2])
{
    vol *ct = volio_read(path);
    if (!ct)
        return FN_EIO;
    fracture_params fp;
    fracture_defaults(&fp);
    seg_params sp; /* probability maps as `fracnav fracture` makes them */
    seg_defaults(&sp);
    fracture_result fr;
    int rc = fracture_make(ct, &fp, &fr);
    vol_free(ct);
    if (rc < 0)
        return fn_err_wrap(rc, "%s", path);
    for (int id = 1; id <= 2 && rc == 0; id++) {
        int lo[3], hi[3];
        rc = frag_label_box(fr.labels, id, lo, hi);
        if (rc == 0)
            rc = frag_from_labels(&f[id - 1], fr.labels, fr.ct, id, lo, hi, fp.threshold, sp.ramp);
    }
    fracture_result_free(&fr);
    return rc;
}

/* Fits f[1] to f[0] as navigate's fit action does; *tolerance_mm: the fit's. */
static int fit_piece(frag f[2], double tau_min, double tau_max, double *tolerance_mm)
{
    reduce_opts o;
    reduce_defaults(&o);
    o.tau_min = tau_min;
    o.tau_max = tau_max;
    const frag *both[2] = {&f[0], &f[1]};
    reduce_result r;
    memset(&r, 0, sizeof r);
    pose out;
    int rc = reduce_fit_one(both, 1, &f[1], &f[1].pose, &o, &out, &r);
    reduce_result_free(&r);
    if (rc == 0)
        f[1].pose = out;
    *tolerance_mm = reduce_tolerance(&o, both, 2);
    return rc < 0 ? rc : 0;
}

/* The script repeat times, after APPROACH when fitted. */
static fnrec *render(int repeat, int fitted)
{
    size_t one = strlen(SCRIPT), first = fitted ? strlen(APPROACH) : 0;
    char *text = malloc(first + one * (size_t)repeat + 1);
    if (!text)
        return NULL;
    memcpy(text, APPROACH, first);
    for (int i = 0; i < repeat; i++)
        memcpy(text + first + one * (size_t)i, SCRIPT, one);
    text[first + one * (size_t)repeat] = '\0';
    script *s = NULL;
    fnrec *rec = NULL;
    if (script_parse(text, strlen(text), "bench-loop script", &s) == 0)
        rec = script_render(s, sim_profile_find("spacenavigator"));
    free(s);
    free(text);
    return rec;
}

/* Runs the recording through reader thread -> ring -> loop_run, in lockstep. */
static int realtime; /* the loop thread got SCHED_FIFO */
static int preview;  /* --preview */
static int paced;    /* --realtime */

static int drive(session *k, const fnrec *rec, double *wall_s)
{
    sim_replay_opts ro = {paced, 1};
    dev_handle *h;
    if (sim_replay_open_rec(rec, &ro, &h) < 0)
        return FN_EIO;
    session_dsource *ds = session_recording_new(&sim_replay_transport, h, NULL, NULL);
    if (!ds)
        return FN_ENOMEM;
    realtime = loop_realtime_priority() == 0;
    double t0 = bench_now_us();
    int rc = session_play(k, session_device_source(ds), SESSION_PLAY_LOCKSTEP);
    *wall_s = (bench_now_us() - t0) * 1e-6;
    session_dsource_free(ds);
    return rc;
}

static json_t *fragments_json(const frag *f, int nfrag)
{
    json_t *a = json_array();
    for (int i = 0; i < nfrag; i++)
        json_array_append_new(a, json_pack("{s:[iii],s:I}", "dim", f[i].dim[0], f[i].dim[1], f[i].dim[2],
                                           "voxels", (json_int_t)f[i].voxels));
    return a;
}

static int print(session *k, const loop_stats *s, double wall_s, const frag *f, int nfrag, const char *case_dir,
                 int fitted, int json)
{
    session_preview pv;
    session_preview_status(k, &pv);
    if (!json) {
        printf("loop: %.0f steps/s, latency p50 %.0f us, p99 %.0f us, max %.0f us; %llu steps "
               "(%llu free, %llu limited, %llu slid, %llu refused); query mean %.1f us\n",
               s->step_hz, s->latency_p50_us, s->latency_p99_us, s->latency_max_us,
               (unsigned long long)s->steps, (unsigned long long)s->accepted,
               (unsigned long long)s->limited, (unsigned long long)s->slid,
               (unsigned long long)s->refused, s->query_us_mean);
        if (preview)
            printf("preview: %u ghosts (%.1f a second), %u fits dropped as stale\n", pv.updates,
                   pv.updates / wall_s, pv.dropped);
        return 0;
    }
    json_t *j = session_stats_json("bench loop", s);
    if (j) {
        char what[4200];
        snprintf(what, sizeof what, "%s%s%s, script pushing the selected fragment into and along the others",
                 case_dir ? "the case " : "two-piece fracture of the CT, piece 1 fixed",
                 case_dir ? case_dir : "", fitted ? ", piece 2 fitted first, the demo's approach played first" : "");
        json_object_set_new(j, "workload", jsonw_string(what));
        json_object_set_new(j, "fragments", fragments_json(f, nfrag));
        json_object_set_new(j, "loop_thread_sched_fifo", json_boolean(realtime));
        json_object_set_new(j, "wall_s", jsonw_measure(wall_s));
        json_object_set_new(j, "realtime", json_boolean(paced));
        json_object_set_new(j, "preview", json_boolean(preview));
        json_object_set_new(j, "preview_updates_count", preview ? json_integer(pv.updates) : json_null());
        json_object_set_new(j, "preview_updates_mean_hz", preview ? jsonw_measure(pv.updates / wall_s) : json_null());
        json_object_set_new(j, "preview_dropped_count", preview ? json_integer(pv.dropped) : json_null());
        /* loop_hz at least, the latencies at most: issue 23's figures, fitted or not */
        json_object_set_new(j, "targets", json_pack("{s:o,s:o,s:o}", "loop_hz", jsonw_measure(1000),
                                                    "latency_p99_us", jsonw_measure(200),
                                                    "latency_max_us", jsonw_measure(1000)));
    }
    return jsonw_print(j, stdout);
}

/* The case's loop driven by rec, with the case's exclusive lock held (caselock.h): its journal is
 * read and reconciled as a session does, never while navigate writes it. 0 or FN_E*. */
static int run_case(const char *dir, const loop_config *cfg, cmd_tau *tau, const fnrec *rec, int wait, int json)
{
    caselock *lock = caselock_take(dir, 1, wait);
    if (!lock)
        return FN_EAGAIN; /* fn_err names the case and its holder */
    session_params sp = {*cfg, SESSION_RESUME, "bench loop", cmd_tau_prepare, tau, 0};
    session *k = session_open(dir, &sp);
    if (k)
        session_set_preview(k, preview ? SESSION_PREVIEW_NEAR : SESSION_PREVIEW_OFF);
    double wall = 0;
    int rc = k ? drive(k, rec, &wall) : FN_EIO;
    if (k) {
        loop_stats s;
        session_stats(k, &s);
        if (rc == 0)
            rc = print(k, &s, wall, session_frags(k), session_nfrag(k), dir, 0, json);
    }
    session_close(k);
    caselock_release(lock);
    return rc;
}

int bench_loop(int argc, char **argv)
{
    int json = 0, repeat = 10, fitted = 0, wait = 0, rc;
    const char *ct = NULL, *case_dir = NULL;
    cmd_tau tau = {0};
    for (int i = 1; i < argc; i++) {
        if (cmd_tau_option("bench loop", argv[i], i + 1 < argc ? argv[i + 1] : NULL, &tau, &rc)) {
            if (rc)
                return rc;
            i++;
        } else if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(argv[i], "--json"))
            json = 1;
        else if (!strcmp(argv[i], "--ct") && i + 1 < argc)
            ct = argv[++i];
        else if (!strcmp(argv[i], "--fitted"))
            fitted = 1;
        else if (!strcmp(argv[i], "--preview"))
            preview = 1;
        else if (!strcmp(argv[i], "--realtime"))
            paced = 1;
        else if (!strcmp(argv[i], "--case") && i + 1 < argc)
            case_dir = argv[++i];
        else if (!strcmp(argv[i], "--wait"))
            wait = 1;
        else if (!strcmp(argv[i], "--repeat")) {
            double d;
            const char *v = i + 1 < argc ? argv[++i] : NULL;
            if (!cmd_number(v, &d) || !(d >= 1 && d <= 10000 && d == (int)d))
                return cmd_bad_value("bench loop", "--repeat", v, "a whole number 1..10000");
            repeat = (int)d;
        } else {
            fprintf(stderr, "fracnav bench loop: unexpected argument '%s' (see --help)\n", argv[i]);
            return 2;
        }
    }
    if (fitted && case_dir) {
        fprintf(stderr, "fracnav bench loop: --fitted fits the fracture of --ct, not a case (reduce it instead)\n");
        return 2;
    }
    if (!ct && !case_dir)
        ct = cmd_example_ct();
    if (!case_dir && cmd_tau_check("bench loop", &tau))
        return 2;
    loop_config cfg;
    loop_config_default(&cfg);
    cfg.check_invariant = 0; /* a benchmark of the loop as it runs in release builds */
    fnrec *rec = render(repeat, fitted);
    if (!rec) {
        fprintf(stderr, "fracnav bench loop: %s\n", fn_err_msg());
        return 1;
    }
    double wall = 0;
    loop_stats s;
    if (case_dir) {
        rc = run_case(case_dir, &cfg, &tau, rec, wait, json);
    } else {
        frag f[2];
        memset(f, 0, sizeof f);
        rc = fragments_from_ct(ct, f);
        double op[2] = {CASE_TAU_MIN, CASE_TAU_MAX};
        cmd_tau_apply(&tau, &op[0], &op[1]); /* checked above */
        uint8_t fixed[2] = {1, 0};
        double tol = 0;
        if (rc == 0 && fitted)
            rc = fit_piece(f, op[0], op[1], &tol);
        session *k = rc == 0 ? session_open_fragments(f, 2, fixed, op, &cfg) : NULL;
        if (rc == 0 && !k)
            rc = FN_EFORMAT;
        if (rc == 0 && fitted) /* as a session opening a reduced case: held, then measured */
            rc = session_tolerate(k, 1, tol);
        if (rc == 0) {
            session_set_preview(k, preview ? SESSION_PREVIEW_NEAR : SESSION_PREVIEW_OFF);
            rc = drive(k, rec, &wall);
            session_stats(k, &s);
            if (rc == 0)
                rc = print(k, &s, wall, f, 2, NULL, fitted, json);
        }
        session_close(k);
        frag_free(&f[0]);
        frag_free(&f[1]);
    }
    fnrec_free(rec);
    if (rc < 0)
        fprintf(stderr, "fracnav bench loop: %s\n", fn_err_msg());
    return rc < 0 ? 1 : 0;
}
