/* fracnav replay and navigate end to end on a small two-block case: the options, the JSON summary,
 * crash recovery through the journal after a kill, saves on exit, the keyboard device. What the
 * session does in-process (contact, sliding, unplug, saves on request) is in test_session.c. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case_journal.h"
#include "fnclock.h"
#include "journal.h"
#include "loop.h"
#include "pose.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <jansson.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

static char case_dir[4200];

/* The two-blocks case of tu_two_blocks_case in tu_dir (the group's folder): B is the one that moves. */
static int setup(void **st)
{
    tu_dir_setup(st);
    tu_two_blocks_case(tu_dir, case_dir, sizeof case_dir);
    return 0;
}

/* Renders a motion script for the device `as` into tu_dir/NAME.fnrec; returns the path (static). */
static const char *recording_as(const char *as, const char *name, const char *text)
{
    static char path[4200];
    snprintf(path, sizeof path, "%s/%s.fnrec", tu_dir, name);
    tu_write_recording(path, as, text);
    return path;
}

/* The same for a SpaceNavigator. */
static const char *recording(const char *name, const char *text)
{
    return recording_as("spacenavigator", name, text);
}

/* Runs `fracnav replay CASE REC ARGS --json` and parses the JSON it prints. */
static json_t *replay(const char *rec, const char *args, int want_rc)
{
    char *out = NULL;
    int rc = tu_run_cli(&out, "replay '%s' '%s' --json %s", case_dir, rec, args);
    if (rc != want_rc)
        fprintf(stderr, "%s\n", out);
    assert_int_equal(rc, want_rc);
    json_error_t err;
    const char *brace = strchr(out, '{'); /* stderr's progress line comes first */
    json_t *j = want_rc == 0 && brace ? json_loads(brace, 0, &err) : NULL;
    if (want_rc == 0 && !j)
        fail_msg("replay printed no JSON: %s", out);
    free(out);
    return j;
}

static double num(json_t *j, const char *key)
{
    json_t *v = json_object_get(j, key);
    assert_non_null(v);
    return json_number_value(v);
}

/* Fragment B's translation (final_poses[1].t[axis]). */
static double moved_t(json_t *j, int axis)
{
    json_t *p = json_array_get(json_object_get(j, "final_poses"), 1);
    return json_number_value(json_array_get(json_object_get(p, "t"), (size_t)axis));
}

static size_t journal_count_on_disk(void)
{
    journal_scan s;
    assert_int_equal(journal_read(case_dir, &s), 0);
    journal_scan_free(&s);
    return s.n;
}

/* Whether the journal on disk reaches *(int64_t *)arg microseconds of recorded time. */
static int journal_spans(void *arg)
{
    journal_scan s;
    if (journal_read(case_dir, &s))
        return 0;
    int spans = s.n > 0 && s.recs[s.n - 1].t_us - s.recs[0].t_us >= *(int64_t *)arg;
    journal_scan_free(&s);
    return spans;
}

static void test_replay_help_and_usage(void **st)
{
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "replay --help"), 0);
    assert_non_null(strstr(out, "pose_digest"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "replay '%s'", case_dir), 2);
    assert_non_null(strstr(out, "fracnav replay:"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "replay '%s' /nonexistent.fnrec", case_dir), 1);
    assert_non_null(strstr(out, "/nonexistent.fnrec"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "navigate --help"), 0);
    assert_non_null(strstr(out, "--recover"));
    free(out);
}

/* The loop's rate, ring overflow and skipped device reports are in the summary: a recording with
 * one report of an unknown ID and one of a wrong length counts both and steps the rest. */
static void test_replay_json_rates_and_skips(void **st)
{
    char *text = tu_slurp(recording("skips", "translate +x 1 mm over 0.1 s\n"), NULL);
    char *at = strstr(text, "0 connect\n"), path[4300];
    assert_non_null(at);
    at += strlen("0 connect\n");
    snprintf(path, sizeof path, "%s/skips.fnrec", tu_dir);
    FILE *f = fopen(path, "w");
    fprintf(f, "%.*s1000 in 09000000000000\n2000 in 0174ff0000\n%s", (int)(at - text), text, at);
    fclose(f);
    free(text);
    json_t *j = replay(path, "--no-journal", 0);
    assert_true(num(j, "skipped_reports") == 2);
    assert_true(num(j, "steps") > 0);
    assert_true(num(j, "dropped") == 0);
    assert_true(num(j, "loop_hz") > 0);
    assert_true(json_is_null(json_object_get(j, "tick_hz"))); /* as fast as possible: no timer ticks */
    assert_true(num(j, "escaping") == 0);
    json_decref(j);
}

/* Replayed twice with the journal on (the default): a run that finished leaves no unsaved poses
 * behind, so the second run starts as the first did and gives the same digest. */
static void test_replay_twice_with_journal(void **st)
{
    const char *rec = recording("twice", "translate -x 4 mm over 0.2 s\n");
    json_t *a = replay(rec, "", 0), *b = replay(rec, "", 0);
    assert_true(num(a, "accepted") + num(a, "limited") > 0);
    assert_string_equal(json_string_value(json_object_get(a, "pose_digest")),
                        json_string_value(json_object_get(b, "pose_digest")));
    assert_int_equal(journal_count_on_disk(), 0);
    json_decref(a);
    json_decref(b);
}

/* The shipped grazing recording on the case `fracnav demo` steers (the example CT's synthetic
 * fracture, seed 1): pressed onto the other fragment, the moving one slides along it. */
static void test_shipped_grazing_slides_on_example(void **st)
{
    char ex[4300], rec[4300], *out = NULL;
    snprintf(ex, sizeof ex, "%s/example", tu_dir);
    int rc = tu_run_cli(&out, "fracture '%s' -o '%s' --seed 1", tu_example_ct(), ex);
    if (rc != 0)
        fprintf(stderr, "%s\n", out);
    free(out);
    assert_int_equal(rc, 0);
    snprintf(rec, sizeof rec, "%s/sim/recordings/grazing-slide.fnrec", tu_src());
    rc = tu_run_cli(&out, "replay '%s' '%s' --json --no-journal", ex, rec);
    assert_int_equal(rc, 0);
    json_t *j = json_loads(strchr(out, '{'), 0, NULL);
    free(out);
    assert_non_null(j);
    assert_int_equal(num(j, "collisions_in_accepted"), 0);
    assert_true(num(j, "slid") > 0);
    assert_true(num(j, "slid") > num(j, "refused"));
    json_decref(j);
    tu_rmtree(ex);
}

/* Killed mid-replay (SIGKILL) once the journal on disk holds 300 ms of its motion: the next
 * start refuses to silently drop those poses, and --recover starts from the last of them. The
 * recording stays plugged in long after its motion, so the kill is mid-replay however slow the
 * machine is. */
static void test_crash_recovery(void **st)
{
    const char *rec = recording("long", "translate +z 3 mm over 1.5 s\ntranslate -z 3 mm over 1.5 s\n"
                                        "wait 600 s\nunplug\n");
    char cmd[9000];
    FILE *err;
    pid_t pid = tu_spawn_cli(NULL, &err, (char *[]){"replay", case_dir, (char *)rec, "--realtime",
                                                    "--discard-journal", NULL});
    char line[1024] = "";
    assert_true(tu_wait_line(err, "\n", line, sizeof line));
    assert_non_null(strstr(line, "stepping"));
    int64_t span = 300000;
    int midway = tu_wait_for(journal_spans, &span, TU_WAIT_MAX_S);
    int status = tu_end(pid, SIGKILL, "replay, killed");
    fclose(err);
    assert_true(midway);
    assert_int_equal(status, 128 + SIGKILL);

    journal_scan s;
    assert_int_equal(journal_read(case_dir, &s), 0);
    journal_rec *r = s.recs;
    size_t n = s.n;
    assert_true(n > 20);
    pose last = r[n - 1].p;
    free(r);

    const char *idle = recording("idle", "wait 0.1 s\n");
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "replay '%s' '%s'", case_dir, idle), 1);
    assert_non_null(strstr(out, "--recover"));
    free(out);
    json_t *j = replay(idle, "--recover", 0);
    assert_true(num(j, "resumed_from_journal") == (double)n);
    for (int a = 0; a < 3; a++)
        assert_true(moved_t(j, a) == last.t[a]);
    json_decref(j);
    /* A damaged journal is named and kept aside; --discard-journal starts over from case.json. */
    snprintf(cmd, sizeof cmd, "%s/journal", case_dir);
    tu_write_file(cmd, "garbage, not a journal", 22);
    assert_int_equal(tu_run_cli(&out, "replay '%s' '%s'", case_dir, idle), 0);
    assert_non_null(strstr(out, "journal.damaged.1"));
    free(out);
    snprintf(cmd, sizeof cmd, "%s/journal.damaged.1", case_dir);
    unlink(cmd);
    snprintf(cmd, sizeof cmd, "%s/journal", case_dir);
    tu_write_file(cmd, "garbage, not a journal", 22);
    j = replay(idle, "--discard-journal", 0);
    assert_true(num(j, "resumed_from_journal") == 0);
    assert_true(moved_t(j, 2) == 0);
    json_decref(j);
    unlink(cmd);
}

/* The environment of a running fracnav (/proc/PID/environ) as one string, its entries joined by
 * '\n'; its name (/proc/PID/comm) into comm. */
static char *running_env(pid_t pid, char *comm, size_t ncomm)
{
    char path[64];
    snprintf(path, sizeof path, "/proc/%d/environ", (int)pid);
    FILE *f = fopen(path, "r"); /* its size is 0 to stat: read to the end */
    assert_non_null(f);
    size_t len = 1, cap = 1 << 16;
    char *env = malloc(cap);
    assert_non_null(env);
    env[0] = '\n';
    for (size_t got; len < cap - 1 && (got = fread(env + len, 1, cap - 1 - len, f)) > 0;)
        len += got;
    fclose(f);
    env[len] = '\0';
    for (size_t i = 0; i < len; i++)
        env[i] = env[i] ? env[i] : '\n';
    snprintf(path, sizeof path, "/proc/%d/comm", (int)pid);
    f = fopen(path, "r");
    assert_non_null(f);
    assert_non_null(fgets(comm, (int)ncomm, f));
    fclose(f);
    return env;
}

/* fracnav runs with glibc's malloc tuned (platform_tune_malloc: executed again at its start with
 * GLIBC_TUNABLES, under its own name), and leaves a user's own malloc tunables alone. A replay that
 * stays plugged in is running once it says it is stepping: its environment is read there. */
static void test_malloc_tunables(void **st)
{
    (void)st;
    const char *rec = recording("still", "wait 600 s\nunplug\n");
    for (int own = 0; own < 2; own++) {
        const char *was = getenv("GLIBC_TUNABLES");
        char *saved = was ? strdup(was) : NULL;
        if (own)
            setenv("GLIBC_TUNABLES", "glibc.malloc.hugetlb=0", 1);
        else
            unsetenv("GLIBC_TUNABLES");
        FILE *err;
        pid_t pid = tu_spawn_cli(NULL, &err, (char *[]){"replay", case_dir, (char *)rec, "--realtime",
                                                        "--no-journal", NULL});
        if (saved)
            setenv("GLIBC_TUNABLES", saved, 1);
        else
            unsetenv("GLIBC_TUNABLES");
        free(saved);
        char line[1024] = "", comm[64] = "";
        int up = tu_wait_line(err, "stepping", line, sizeof line);
        char *env = up ? running_env(pid, comm, sizeof comm) : NULL;
        tu_end(pid, SIGTERM, "replay");
        fclose(err);
        assert_true(up);
        /* glibc cuts the variable it parsed at its first ':' in place, so its first tunable is
         * what /proc shows */
        const char *want = own ? "\nGLIBC_TUNABLES=glibc.malloc.hugetlb=0\n" : "\nGLIBC_TUNABLES=glibc.malloc.hugetlb=1";
        if (!strstr(env, want))
            fail_msg("%s not in the environment of a running fracnav:\n%s", want + 1, env);
        assert_string_equal(comm, "fracnav\n");
        free(env);
    }
}

/* navigate with a recording played as a live device (real time): the terminal view shows the
 * state, and once it shows the frame key pressed after the move (the loop takes events in order),
 * Ctrl-C (SIGTERM here) saves the case with the moved pose and empties the journal. The recording
 * stays plugged in and silent long after. (How far the move goes depends on when the reports
 * arrive: on a starved machine the loop carries the last motion on between late reports.) */
static void test_navigate_saves_on_exit(void **st)
{
    const char *rec = recording_as("spaceexplorer", "nav", "translate +z 1 mm over 0.3 s\nwait 100 ms\n"
                                   "press 10\nwait 50 ms\nrelease 10\nwait 600 s\nunplug\n");
    char spec[4300], outp[4300], path[4300];
    snprintf(spec, sizeof spec, "replay-realtime:%s", rec);
    snprintf(outp, sizeof outp, "%s/nav.out", tu_dir);
    snprintf(path, sizeof path, "%s/case.json", case_dir);
    size_t len;
    char *before = tu_slurp(path, &len);
    pid_t pid = tu_spawn_cli(outp, NULL, (char *[]){"navigate", case_dir, "--device", spec, "--json", NULL});
    int shown = tu_wait_for_text(outp, "| world", TU_WAIT_MAX_S); /* a status line, once a second */
    int status = tu_end(pid, SIGTERM, "navigate after SIGTERM");
    char *out = tu_slurp(outp, NULL);
    if (!shown)
        fail_msg("navigate never showed the frame key's effect: %s", out);
    assert_int_equal(status, 0);
    assert_non_null(strstr(out, "frag 2/2"));
    assert_non_null(strstr(out, "steps/s"));
    json_t *j = json_loads(strchr(out, '{'), JSON_DISABLE_EOF_CHECK, NULL);
    assert_non_null(j);
    assert_true(num(j, "steps") > 10);
    double tz = moved_t(j, 2);
    if (!(tz < -0.4)) /* about 0.87 mm at once; a loaded machine's late reports go more or less far */
        fail_msg("navigate moved fragment 2 to z %g, want it well down: %s", tz, out);
    json_decref(j);
    free(out);
    assert_int_equal(journal_count_on_disk(), 0);
    char *text = tu_slurp(path, NULL);
    json_t *c = json_loads(text, 0, NULL);
    free(text);
    json_t *f2 = json_array_get(json_object_get(c, "fragments"), 1);
    double saved = json_number_value(json_array_get(json_object_get(json_object_get(f2, "pose"), "t"), 2));
    assert_true(fabs(saved - tz) < 1e-9);
    json_decref(c);
    tu_write_file(path, before, len); /* back to where it was, for the other tests */
    free(before);
}

/* Writes one journal record that puts fragment B (index 1) at p: an interrupted session. */
static void interrupted_at(pose p)
{
    planning_case *c = case_load(case_dir);
    assert_non_null(c);
    journal_bind b;
    case_journal_bind(c, &b);
    case_free(c);
    journal *jr = journal_open(case_dir, &b);
    assert_non_null(jr);
    assert_int_equal(journal_append(jr, JOURNAL_START, 1, 0, &p, 0), 0);
    assert_int_equal(journal_close(jr), 0);
}

/* navigate through the keyboard device (keys from an empty file), answering the recovery question
 * on stdin; returns its JSON summary. */
static json_t *navigate_answering(const char *answer)
{
    char keys[4300], ans[4300];
    snprintf(keys, sizeof keys, "%s/nokeys", tu_dir);
    snprintf(ans, sizeof ans, "%s/answer", tu_dir);
    tu_write_file(keys, "", 0);
    tu_write_file(ans, answer, strlen(answer));
    char *out = NULL;
    int rc = tu_run_cli(&out, "navigate '%s' --device 'keyboard:%s' --duration 0.3 --json < '%s'",
                        case_dir, keys, ans);
    if (rc != 0)
        fprintf(stderr, "%s\n", out);
    assert_int_equal(rc, 0);
    assert_non_null(strstr(out, "Recover them?"));
    json_t *j = json_loads(strchr(out, '{'), JSON_DISABLE_EOF_CHECK, NULL);
    assert_non_null(j);
    free(out);
    return j;
}

/* With the keyboard as the device (what `auto` picks without a controller) navigate still asks
 * about an interrupted session: "n" starts from case.json, "y" from the journal's poses. */
static void test_navigate_keyboard_offers_recovery(void **st)
{
    pose moved = POSE_IDENTITY;
    moved.t[2] = 7.25;
    interrupted_at(moved);
    json_t *j = navigate_answering("n\n");
    assert_true(num(j, "resumed_from_journal") == 0);
    pose home;
    json_t *b = json_array_get(json_object_get(j, "final_poses"), 1);
    for (int a = 0; a < 4; a++)
        home.q[a] = json_number_value(json_array_get(json_object_get(b, "q"), (size_t)a));
    for (int a = 0; a < 3; a++)
        home.t[a] = moved_t(j, a);
    assert_true(home.t[2] != 7.25);
    assert_int_equal(journal_count_on_disk(), 0);
    json_decref(j);
    interrupted_at(moved);
    j = navigate_answering("y\n");
    assert_true(num(j, "resumed_from_journal") == 1);
    assert_true(moved_t(j, 2) == 7.25);
    json_decref(j);
    interrupted_at(home); /* back to where it was, for the other tests */
    json_decref(navigate_answering("Y\n"));
}

/* navigate --device keyboard fed KEYS from a file, all it prints into tu_dir/keys.out; stopped by
 * SIGTERM (Ctrl-C: it saves and exits 0) once that output holds `until` (NULL: it must stop by
 * itself). Returns what it printed. */
static char *navigate_keys(const char *keys, const char *until)
{
    char path[4300], spec[4400], outp[4300];
    snprintf(path, sizeof path, "%s/keys", tu_dir);
    snprintf(outp, sizeof outp, "%s/keys.out", tu_dir);
    snprintf(spec, sizeof spec, "keyboard:%s", path);
    tu_write_file(path, keys, strlen(keys));
    pid_t pid = tu_spawn_cli(outp, NULL, (char *[]){"navigate", case_dir, "--device", spec, "--json", NULL});
    int shown = !until || tu_wait_for_text(outp, until, TU_WAIT_MAX_S);
    int status = tu_end(pid, until ? SIGTERM : 0, "navigate with keys");
    char *out = tu_slurp(outp, NULL);
    if (!shown)
        fail_msg("navigate with keys '%s' never printed '%s': %s", keys, until, out);
    if (status != 0)
        fail_msg("navigate with keys '%s' ended with status %d: %s", keys, status, out);
    return out;
}

/* The keyboard device reaches what the controller's buttons 9 and 10 do, and quits. */
static void test_navigate_keyboard_save_frame_quit(void **st)
{
    free(navigate_keys("0", "| world")); /* in a status line (once a second off a terminal) */
    free(navigate_keys("9", "saved ")); /* on demand: --json prints no exit message */
    char *out = navigate_keys("q", NULL); /* no --duration: only the quit ends it */
    assert_non_null(strchr(out, '{'));
    free(out);
}

/* --pivot: the selected fragment turns about the given point (which stays where it is), not
 * about its centroid. */
static void test_replay_pivot(void **st)
{
    char path[4300];
    snprintf(path, sizeof path, "%s/case.json", case_dir);
    char *text = tu_slurp(path, NULL);
    json_t *c = json_loads(text, 0, NULL);
    free(text);
    json_t *f1 = json_array_get(json_object_get(c, "fragments"), 1), *pj = json_object_get(f1, "pose");
    double home[3], p[3];
    pose p0; /* where B starts (earlier tests may leave it a little off home) */
    for (int a = 0; a < 3; a++) {
        home[a] = json_number_value(json_array_get(json_object_get(f1, "centroid"), (size_t)a));
        p0.t[a] = json_number_value(json_array_get(json_object_get(pj, "t"), (size_t)a));
    }
    for (int a = 0; a < 4; a++)
        p0.q[a] = json_number_value(json_array_get(json_object_get(pj, "q"), (size_t)a));
    json_decref(c);
    pose_apply(&p0, home, p);
    p[0] += 10; /* away from A */
    const char *rec = recording("turn", "move rz 10 deg over 0.3 s\n");
    char args[256];
    snprintf(args, sizeof args, "--no-journal --pivot %.17g %.17g %.17g", p[0], p[1], p[2]);
    json_t *about = replay(rec, args, 0), *centroid = replay(rec, "--no-journal", 0);
    assert_true(num(about, "refused") == 0);
    json_t *b = json_array_get(json_object_get(about, "final_poses"), 1);
    pose q;
    for (int a = 0; a < 4; a++)
        q.q[a] = json_number_value(json_array_get(json_object_get(b, "q"), (size_t)a));
    for (int a = 0; a < 3; a++)
        q.t[a] = moved_t(about, a);
    assert_true(pose_angle_between(q, p0) > 0.1);
    double at[3], p_home[3];
    pose inv = pose_inverse(p0);
    pose_apply(&inv, p, p_home);
    pose_apply(&q, p_home, at); /* the pivot's point of B stays where it was */
    for (int a = 0; a < 3; a++)
        assert_true(fabs(at[a] - p[a]) < 1e-6);
    assert_true(fabs(moved_t(about, 1) - moved_t(centroid, 1)) > 0.5);
    json_decref(about);
    json_decref(centroid);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "replay '%s' '%s' --pivot 1 2", case_dir, rec), 2);
    assert_non_null(strstr(out, "--pivot"));
    free(out);
}

/* A member of DIR/case.json. */
static double case_number(const char *case_path, const char *key)
{
    char path[4300];
    snprintf(path, sizeof path, "%s/case.json", case_path);
    char *text = tu_slurp(path, NULL);
    assert_non_null(text);
    json_t *c = json_loads(text, 0, NULL);
    free(text);
    double v = json_number_value(json_object_get(c, key));
    json_decref(c);
    return v;
}

/* --tau-min/--tau-max: stored by segment, checked everywhere with the option named, overridden
 * by replay and kept in the case by --save. */
static void test_tau_options(void **st)
{
    char tc[4300], vol_path[4300], *out = NULL;
    snprintf(tc, sizeof tc, "%s/taucase", tu_dir);
    snprintf(vol_path, sizeof vol_path, "%s/blocks.nii.gz", tu_dir);
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s' --min-volume 0 --tau-min 0.3", vol_path, tc), 0);
    free(out);
    assert_true(case_number(tc, "tau_min") == 0.3);
    assert_true(case_number(tc, "tau_max") == 0.95);
    const char *bad[] = {"--tau-min 1.5", "--tau-max -0.1", "--tau-min abc", "--tau-min 0.9 --tau-max 0.4"};
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s' %s", vol_path, tc, bad[i]), 2);
        assert_non_null(strstr(out, strchr(bad[i], '-') ? "--tau-m" : "tau"));
        free(out);
        assert_int_equal(tu_run_cli(&out, "fracture '%s' -o '%s/f' --seed 1 %s", vol_path, tu_dir, bad[i]), 2);
        assert_non_null(strstr(out, "--tau-m"));
        free(out);
    }
    assert_int_equal(tu_run_cli(&out, "replay '%s' '%s' --tau-max 2", tc, recording("tau", "wait 0.1 s\n")), 2);
    assert_non_null(strstr(out, "--tau-max: '2' is not a number from 0 to 1"));
    free(out);
    /* Below the case's tau_min (0.3): named, nothing changed. */
    assert_int_equal(tu_run_cli(&out, "replay '%s' '%s' --tau-max 0.2", tc, recording("tau", "wait 0.1 s\n")), 1);
    assert_non_null(strstr(out, "--tau-max"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "replay '%s' '%s' --tau-min 0.1 --save", tc, recording("tau", "wait 0.1 s\n")), 0);
    free(out);
    assert_true(case_number(tc, "tau_min") == 0.1);
    assert_int_equal(tu_run_cli(&out, "bench build --tau-min 0.7 --tau-max 0.6"), 2);
    assert_non_null(strstr(out, "--tau-min"));
    free(out);
}

/* Whether fragment B (final_poses[1]) ended fixed. */
static int b_fixed(json_t *j)
{
    return json_is_true(json_object_get(json_array_get(json_object_get(j, "final_poses"), 1), "fixed"));
}

/* On the SpaceMouse Enterprise the actions of buttons 1-10 sit on its keys labelled 1-10 (key codes
 * 13-22, buttons 13-22), not on MENU, FIT and the view keys that come first in its numbering. */
static void test_enterprise_numbered_keys_act(void **st)
{
    json_t *j = replay(recording_as("spacemouse-enterprise", "ent3", "press 15\nwait 50 ms\nrelease\n"),
                       "--no-journal", 0); /* the key labelled 3: fix */
    assert_true(b_fixed(j));
    json_decref(j);
    j = replay(recording_as("spacemouse-enterprise", "entT", "press 3\nwait 50 ms\nrelease\n"),
               "--no-journal", 0); /* T, a view key: no action */
    assert_false(b_fixed(j));
    json_decref(j);
    j = replay(recording_as("spacemouse-pro-wireless", "pro3", "press 3\nwait 50 ms\nrelease\n"),
               "--no-journal", 0); /* other devices: button 3 fixes */
    assert_true(b_fixed(j));
    json_decref(j);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_replay_help_and_usage),
        cmocka_unit_test(test_replay_twice_with_journal),
        cmocka_unit_test(test_replay_json_rates_and_skips),
        cmocka_unit_test(test_shipped_grazing_slides_on_example),
        cmocka_unit_test(test_crash_recovery),
        cmocka_unit_test(test_malloc_tunables),
        cmocka_unit_test(test_navigate_saves_on_exit),
        cmocka_unit_test(test_navigate_keyboard_offers_recovery),
        cmocka_unit_test(test_navigate_keyboard_save_frame_quit),
        cmocka_unit_test(test_tau_options),
        cmocka_unit_test(test_replay_pivot),
        cmocka_unit_test(test_enterprise_numbered_keys_act),
    };
    return cmocka_run_group_tests(tests, setup, tu_dir_teardown);
}
