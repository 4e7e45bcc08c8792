/* Machine output (README "Machine output"): every command's --json prints one object and nothing
 * else on stdout, labelled with the command, with keys <measure>_<statistic>_<unit> (rates _hz),
 * times and rates as reals, the same key and type for the same measure in every command, and null
 * where a figure does not apply. Each command runs on small volumes this test writes. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "err.h"
#include "jsonw.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <fcntl.h>
#include <jansson.h>
#include <libgen.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

static char *dir;
static char blocks[4200], tube[4200], case_dir[4200], tube_case[4200], frac_dir[4200], rec[4200];

/* Every object seen, per command, for the checks across commands. */
#define MAX_OUT 32
static json_t *outputs[MAX_OUT];
static const char *labels[MAX_OUT];
static int n_out;

static const char *const UNITS[] = {"ns", "us", "ms", "s", "hz", "mm", "ml", "deg", "pct", "kib", "bytes"};
static const char *const TIMED[] = {"ns", "us", "ms", "s", "hz"};
static const char *const STATS[] = {"mean", "max", "min", "p50", "p99", "median"};
/* Scalars without a unit that are not counts: intensities in the volume's own units. */
static const char *const UNITLESS[] = {"threshold", "peak"};
/* Names replaced by the convention: none may come back. */
static const char *const RETIRED[] = {"benchmark", "bench", "step_hz", "query_us_mean", "query_us_max",
                                      "bytes_per_node", "peak_rss_kib", "ns_per_voxel", "battery",
                                      "spacing", "dims_a", "voxels_a", "reports_per_s", "brute_mean_us",
                                      "fcl_octree_mean_us"};

static int in(const char *s, const char *const *set, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!strcmp(s, set[i]))
            return 1;
    return 0;
}
#define IN(s, set) in(s, set, sizeof set / sizeof set[0])

static void write_ct(const char *path, int nx, int ny, int nz, int (*bone)(int, int, int))
{
    vol *v = vol_new(nx, ny, nz);
    assert_non_null(v);
    for (int k = 0; k < nz; k++)
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++)
                v->data[vol_idx(v, i, j, k)] = bone(i, j, k) ? 1200.f : -1000.f;
    assert_int_equal(volio_write(v, path, VOL_I16), 0);
    vol_free(v);
}

/* Two blocks 2 mm apart along x (a case to steer). */
static int two_blocks(int i, int j, int k)
{
    return (i >= 4 && i < 16 && j >= 6 && j < 26 && k >= 6 && k < 26) ||
           (i >= 18 && i < 28 && j >= 10 && j < 22 && k >= 10 && k < 22);
}

/* A thick tube along z (a bone to fracture). */
static int tube_wall(int i, int j, int k)
{
    double r = hypot(i - 19.5, j - 19.5);
    return k > 2 && k < 45 && r > 8 && r < 15;
}

static int setup(void **st)
{
    dir = tu_tmpdir("jsonschema");
    snprintf(blocks, sizeof blocks, "%s/blocks.nii.gz", dir);
    snprintf(tube, sizeof tube, "%s/tube.nii.gz", dir);
    snprintf(case_dir, sizeof case_dir, "%s/case", dir);
    snprintf(tube_case, sizeof tube_case, "%s/tubecase", dir);
    snprintf(frac_dir, sizeof frac_dir, "%s/frac", dir);
    snprintf(rec, sizeof rec, "%s/push.fnrec", dir);
    write_ct(blocks, 40, 32, 32, two_blocks);
    write_ct(tube, 40, 40, 48, tube_wall);
    tu_write_recording(rec, "spacenavigator", "translate -x 4 mm over 0.3 s\n");
    return 0;
}

static int teardown(void **st)
{
    for (int i = 0; i < n_out; i++)
        json_decref(outputs[i]);
    tu_rmtree(dir);
    free(dir);
    return 0;
}

/* Runs `PROGRAM ARGS` with stdin from /dev/null and stderr to a file; stdout must parse WHOLE as
 * one JSON object labelled `command`. The object is kept for the checks across commands. */
static json_t *run_json(const char *program, const char *command, const char *fmt, ...)
{
    char args[8192], cmd[17000], err_path[4300];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(args, sizeof args, fmt, ap);
    va_end(ap);
    snprintf(err_path, sizeof err_path, "%s/stderr", dir);
    snprintf(cmd, sizeof cmd, "'%s' %s < /dev/null 2>'%s'", program, args, err_path);
    FILE *p = popen(cmd, "r");
    assert_non_null(p);
    size_t cap = 1 << 16, n = 0, got;
    char *out = malloc(cap);
    while ((got = fread(out + n, 1, cap - n - 1, p)) > 0)
        if ((n += got) + 1 == cap)
            out = realloc(out, cap *= 2);
    out[n] = '\0';
    int st = pclose(p);
    char *err = tu_slurp(err_path, NULL);
    if (!WIFEXITED(st) || WEXITSTATUS(st) != 0)
        fail_msg("%s %s: exit %d\nstdout:\n%s\nstderr:\n%s", program, args, WEXITSTATUS(st), out, err);
    json_error_t je;
    json_t *j = json_loads(out, 0, &je); /* no JSON_DISABLE_EOF_CHECK: nothing else may follow */
    if (!json_is_object(j))
        fail_msg("%s %s: stdout is not one JSON object (%s, line %d):\n%s", program, args, je.text, je.line, out);
    const char *label = json_string_value(json_object_get(j, "command"));
    if (!label || strcmp(label, command))
        fail_msg("%s %s: \"command\" is %s, want \"%s\"", program, args, label ? label : "missing", command);
    free(out);
    free(err);
    assert_true(n_out < MAX_OUT);
    outputs[n_out] = j;
    labels[n_out++] = command;
    return j;
}

static json_t *fracnav(const char *command, const char *fmt, ...)
{
    char args[8192];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(args, sizeof args, fmt, ap);
    va_end(ap);
    return run_json(tu_fracnav(), command, "%s", args);
}

/* Why key breaks the convention, or NULL. Tokens split on '_': a unit only last; a statistic last
 * or just before the unit; a scalar real carries a unit or a statistic (or is an intensity); a time
 * or a rate is a real (or null), never an integer. */
static const char *bad_key(const char *key, const json_t *v)
{
    size_t len = strlen(key);
    if (!len || key[0] < 'a' || key[0] > 'z' || key[len - 1] == '_' || strstr(key, "__"))
        return "not snake_case";
    for (const char *c = key; *c; c++)
        if (!((*c >= 'a' && *c <= 'z') || (*c >= '0' && *c <= '9') || *c == '_'))
            return "not snake_case";
    if (IN(key, RETIRED))
        return "a retired name";
    char buf[256], *tok[32];
    int n = 0;
    snprintf(buf, sizeof buf, "%s", key);
    for (char *t = strtok(buf, "_"); t && n < 32; t = strtok(NULL, "_"))
        tok[n++] = t;
    int unit_last = n > 1 && IN(tok[n - 1], UNITS);
    for (int i = 0; i < n; i++) {
        if (n > 1 && IN(tok[i], UNITS) && i != n - 1)
            return "a unit before the end (<measure>_<statistic>_<unit>)";
        if (i > 0 && IN(tok[i], STATS) && !(i == n - 1 || (i == n - 2 && unit_last)))
            return "a statistic not just before the unit";
    }
    if (json_is_real(v) && !unit_last && !(n > 1 && IN(tok[n - 1], STATS)) && !IN(key, UNITLESS))
        return "a real without a unit";
    if (unit_last && IN(tok[n - 1], TIMED) && json_is_integer(v))
        return "a time or rate printed as an integer";
    return NULL;
}

/* Checks every key of j (and of the objects it holds); where names where they are. */
static void check_keys(const json_t *j, const char *where)
{
    if (json_is_array(j)) {
        for (size_t i = 0; i < json_array_size(j); i++)
            check_keys(json_array_get(j, i), where);
        return;
    }
    if (!json_is_object(j))
        return;
    const char *key;
    json_t *v;
    json_object_foreach((json_t *)j, key, v) {
        const char *why = bad_key(key, v);
        if (why)
            fail_msg("%s: key \"%s\" is %s", where, key, why);
        check_keys(v, where);
    }
}

/* The keys of every object seen: the same key has the same JSON type everywhere, and no two keys
 * hold the same words in another order (query_us_mean beside query_mean_us). */
typedef struct seen {
    char key[64], sorted[64], where[64];
    json_type type;
} seen;
static seen keys[1024];
static int n_keys;

static void sort_words(const char *key, char *out, size_t cap)
{
    char buf[64], *w[16];
    int n = 0;
    snprintf(buf, sizeof buf, "%s", key);
    for (char *t = strtok(buf, "_"); t && n < 16; t = strtok(NULL, "_"))
        w[n++] = t;
    for (int a = 0; a < n; a++)
        for (int b = a + 1; b < n; b++)
            if (strcmp(w[b], w[a]) < 0) {
                char *t = w[a];
                w[a] = w[b], w[b] = t;
            }
    out[0] = '\0';
    for (int i = 0; i < n; i++)
        snprintf(out + strlen(out), cap - strlen(out), "%s%s", i ? " " : "", w[i]);
}

static void collect(const json_t *j, const char *where)
{
    if (json_is_array(j)) {
        for (size_t i = 0; i < json_array_size(j); i++)
            collect(json_array_get(j, i), where);
        return;
    }
    if (!json_is_object(j))
        return;
    const char *key;
    json_t *v;
    json_object_foreach((json_t *)j, key, v) {
        collect(v, where);
        char sorted[64];
        sort_words(key, sorted, sizeof sorted);
        int i;
        for (i = 0; i < n_keys; i++) {
            if (!strcmp(keys[i].sorted, sorted) && strcmp(keys[i].key, key))
                fail_msg("\"%s\" (%s) and \"%s\" (%s) name one measure two ways", key, where, keys[i].key,
                         keys[i].where);
            if (!strcmp(keys[i].key, key))
                break;
        }
        if (json_is_null(v))
            continue;
        json_type type = json_is_boolean(v) ? JSON_TRUE : json_typeof(v);
        if (i == n_keys) {
            assert_true(n_keys < 1024);
            snprintf(keys[i].key, sizeof keys[i].key, "%s", key);
            snprintf(keys[i].sorted, sizeof keys[i].sorted, "%s", sorted);
            snprintf(keys[i].where, sizeof keys[i].where, "%s", where);
            keys[i].type = type;
            n_keys++;
        } else if (keys[i].type != type)
            fail_msg("\"%s\" has one type in %s and another in %s", key, keys[i].where, where);
    }
}

static void check(const json_t *j, const char *command)
{
    check_keys(j, command);
    collect(j, command);
}

/* ---- the writer ---- */

static char *dump_one(json_t *v)
{
    json_t *o = json_object();
    json_object_set_new(o, "x", v);
    char *s = jsonw_dumps(o);
    json_decref(o);
    return s;
}

static void expect_dump(json_t *v, const char *want)
{
    char *s = dump_one(v), line[256];
    snprintf(line, sizeof line, "{\n  \"x\": %s\n}\n", want);
    if (strcmp(s, line))
        fail_msg("wrote\n%s\nwant\n%s", s, line);
    free(s);
}

/* Measures carry 6 significant digits, exact figures read back bit for bit, reals stay reals,
 * figures that do not apply are null, strings are escaped. */
static void test_writer(void **st)
{
    expect_dump(jsonw_measure(1234.56789), "1234.57");
    expect_dump(jsonw_measure(178), "178.0");
    expect_dump(jsonw_measure(0.000123456789), "0.000123457");
    expect_dump(jsonw_measure(JSONW_NA), "null");
    expect_dump(jsonw_exact(INFINITY), "null");
    expect_dump(jsonw_exact(0.1), "0.1");
    expect_dump(jsonw_exact(-2.0), "-2.0");
    expect_dump(jsonw_exact(300), "300.0"); /* not 3e+02 */
    expect_dump(jsonw_measure(1234567), "1234570.0");
    expect_dump(jsonw_exact(-1.5e-7), "-1.5e-07");
    expect_dump(jsonw_exact(1e20), "1e+20");
    double third = 1.0 / 3;
    char *s = dump_one(jsonw_exact(third));
    json_t *back = json_loads(s, 0, NULL);
    assert_true(json_real_value(json_object_get(back, "x")) == third);
    json_decref(back);
    free(s);
    expect_dump(json_pack("[iii]", 1, 2, 3), "[1, 2, 3]");
    expect_dump(jsonw_string("a\"b\\c\n\x01"), "\"a\\\"b\\\\c\\n\\u0001\"");
    expect_dump(jsonw_string("caf\xc3\xa9"), "\"caf\xc3\xa9\"");
    expect_dump(jsonw_string("caf\xc3\xa9 \xff"), "\"caf?? ?\""); /* not UTF-8: ASCII kept */
    json_t *o = jsonw_object("x y");
    char *t = jsonw_dumps(o);
    assert_string_equal(t, "{\n  \"command\": \"x y\"\n}\n");
    free(t);
    json_decref(o);
}

/* The convention itself: what the check refuses. */
static void test_key_check(void **st)
{
    json_t *r = json_real(1), *i = json_integer(1);
    assert_null(bad_key("query_mean_us", r));
    assert_null(bad_key("latency_p99_us", r));
    assert_null(bad_key("loop_hz", r));
    assert_null(bad_key("box_tests_mean", r));
    assert_null(bad_key("steps", i));
    assert_non_null(bad_key("query_us_mean", r));
    assert_non_null(bad_key("step_hz", r));
    assert_non_null(bad_key("latency_p99_us", i));
    assert_non_null(bad_key("queryMeanUs", r));
    assert_non_null(bad_key("spacing", r));
    assert_non_null(bad_key("benchmark", i));
    json_decref(r);
    json_decref(i);
}

/* ---- the commands ---- */

static void test_volume_commands(void **st)
{
    json_t *j = fracnav("info", "info '%s' --json", blocks);
    assert_true(json_is_array(json_object_get(j, "spacing_mm")));
    check(j, "info");
    j = fracnav("segment", "segment '%s' -o '%s' --min-volume 0 --ramp 0 --json", blocks, case_dir);
    assert_int_equal(json_array_size(json_object_get(j, "fragments")), 2);
    assert_string_equal(json_string_value(json_object_get(j, "case")), case_dir);
    check(j, "segment");
    j = fracnav("edit", "edit '%s' fix 1 --json", case_dir);
    assert_int_equal(json_integer_value(json_object_get(j, "fixed_fragment")), 1);
    check(j, "edit");
    json_t *t = fracnav("segment", "segment '%s' -o '%s' --min-volume 0 --json", tube, tube_case);
    json_t *c = json_object_get(json_array_get(json_object_get(t, "fragments"), 0), "centroid_mm");
    j = fracnav("edit", "edit '%s' split 1 --plane %.17g %.17g %.17g 0 0 1 --json", tube_case,
                json_real_value(json_array_get(c, 0)), json_real_value(json_array_get(c, 1)),
                json_real_value(json_array_get(c, 2)));
    assert_int_equal(json_integer_value(json_object_get(j, "new_fragment")), 2);
    assert_int_equal(json_array_size(json_object_get(j, "fragments")), 2);
    check(j, "edit");
    j = fracnav("edit", "edit '%s' fill 1 --slices --json", tube_case);
    assert_true(json_is_integer(json_object_get(j, "filled_voxels")));
    check(j, "edit");
    j = fracnav("edit", "edit '%s' merge 1 2 --json", case_dir);
    check(j, "edit");
    j = fracnav("edit", "edit '%s' separate 1 --json", case_dir);
    assert_int_equal(json_array_size(json_object_get(j, "new_fragments")), 1);
    assert_true(json_is_real(json_object_get(j, "erode_mm")));
    assert_int_equal(json_array_size(json_object_get(j, "fragments")), 2);
    check(j, "edit");
    j = fracnav("fracture", "fracture '%s' -o '%s' --seed 1 --json", tube, frac_dir);
    assert_int_equal(json_array_size(json_object_get(j, "fragments")), 2);
    assert_true(json_is_real(json_object_get(json_array_get(json_object_get(j, "fragments"), 1), "displacement_mm")));
    check(j, "fracture");
    j = fracnav("export", "export '%s' --tfm '%s/tfm' --stl '%s/stl' --json", frac_dir, dir, dir);
    assert_int_equal(json_array_size(json_object_get(j, "files")), 4);
    assert_true(json_is_integer(json_object_get(j, "written_total_bytes")));
    check(j, "export");
}

/* replay, navigate and bench loop: one set of keys for the loop's figures. */
static void test_loop_commands(void **st)
{
    static const char *const loop_keys[] = {"steps", "accepted", "refused", "loop_hz", "tick_hz",
                                            "latency_p50_us", "latency_p99_us", "latency_max_us",
                                            "query_mean_us", "query_max_us", "dropped"};
    json_t *r = fracnav("replay", "replay '%s' '%s' --no-journal --json", case_dir, rec);
    assert_true(json_is_null(json_object_get(r, "tick_hz"))); /* as fast as possible: no timer */
    assert_true(json_is_real(json_object_get(r, "latency_p99_us")));
    check(r, "replay");
    char keys_file[4300];
    snprintf(keys_file, sizeof keys_file, "%s/nokeys", dir);
    tu_write_file(keys_file, "", 0);
    json_t *n = fracnav("navigate", "navigate '%s' --device 'keyboard:%s' --duration 0.3 --json", case_dir,
                        keys_file);
    assert_true(json_is_null(json_object_get(n, "unplugs"))); /* not counted live */
    check(n, "navigate");
    json_t *b = fracnav("bench loop", "bench loop --case '%s' --repeat 1 --json", case_dir);
    check(b, "bench loop");
    assert_true(json_is_null(json_object_get(b, "preview_updates_count")));
    /* issue 23's figures for every workload, fitted or not: p99 <= 200 us, max <= 1,000 us */
    json_t *t = json_object_get(b, "targets");
    assert_true(json_real_value(json_object_get(t, "latency_p99_us")) == 200);
    assert_true(json_real_value(json_object_get(t, "latency_max_us")) == 1000);
    /* with the live preview beside, at the hand's pace: its counts too */
    json_t *p = fracnav("bench loop", "bench loop --case '%s' --repeat 1 --realtime --preview --json", case_dir);
    check(p, "bench loop");
    assert_true(json_is_true(json_object_get(p, "preview")));
    assert_true(json_is_integer(json_object_get(p, "preview_updates_count")));
    assert_true(json_is_integer(json_object_get(p, "preview_dropped_count")));
    for (size_t i = 0; i < sizeof loop_keys / sizeof loop_keys[0]; i++) {
        assert_non_null(json_object_get(r, loop_keys[i]));
        assert_non_null(json_object_get(n, loop_keys[i]));
        assert_non_null(json_object_get(b, loop_keys[i]));
    }
}

static void test_bench_and_devices(void **st)
{
    json_t *j = fracnav("bench collision", "bench collision '%s' --bone 300 --poses 10 --reps 1 --no-fcl --json", tube);
    json_t *w = json_array_get(json_object_get(j, "workloads"), 0);
    assert_int_equal(json_integer_value(json_object_get(w, "false_negatives")), 0);
    assert_true(json_is_null(json_object_get(w, "fcl_octree_query_mean_us"))); /* --no-fcl */
    check(j, "bench collision");
    /* two seeds of the tube, two pieces: the rate per number of pieces beside its target */
    j = fracnav("bench fracture", "bench fracture --ct '%s' --seeds 2 --pieces 2 --json", tube);
    json_t *c = json_array_get(json_object_get(j, "counts"), 0);
    assert_int_equal(json_integer_value(json_object_get(c, "pieces")), 2);
    assert_int_equal(json_integer_value(json_object_get(c, "runs")), 2);
    assert_true(json_is_real(json_object_get(c, "made_pct")));
    assert_true(json_is_array(json_object_get(c, "failed")));
    assert_true(json_real_value(json_object_get(json_object_get(c, "targets"), "made_pct")) == 100);
    check(j, "bench fracture");
    j = fracnav("bench build", "bench build --reps 1 --max 64 --json");
    assert_int_equal(json_array_size(json_object_get(j, "sizes")), 1);
    check(j, "bench build");
    j = fracnav("devices", "devices --device /nonexistent/hidraw7 --json");
    check(j, "devices");
}

/* bench render (the example CT, small and short): frame figures per case and the loop's alone
 * and while rendering. */
static void test_bench_render(void **st)
{
    (void)st;
    const char *ct = tu_example_ct();
    json_t *j = fracnav("bench render", "bench render --json --frames 1 --size 64x64 --loop-s 0.3 --ct '%s'", ct);
    check(j, "bench render");
    json_t *res = json_object_get(j, "results");
    assert_int_equal(json_array_size(res), 8);
    for (size_t i = 0; i < json_array_size(res); i++) {
        json_t *r = json_array_get(res, i);
        assert_true(json_is_real(json_object_get(r, "frame_mean_ms")));
        assert_true(json_is_real(json_object_get(r, "frame_hz")));
    }
    static const char *const keys[] = {"loop_alone_hz", "loop_rendering_hz", "latency_alone_p99_us",
                                       "latency_rendering_p99_us", "report_to_frame_p99_ms"};
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++)
        if (!json_is_real(json_object_get(j, keys[i])))
            fail_msg("bench render: %s is not a number", keys[i]);
    assert_true(json_is_integer(json_object_get(j, "surface_triangles")));
    /* The window's mode on this GL: surface on llvmpipe (OSMesa), named for the figures beside it. */
    assert_string_equal(json_string_value(json_object_get(j, "default_mode")), "surface");
}

/* fracnav-sim bench, where FUSE can be served (the simulator is built beside fracnav). */
static void test_sim_bench(void **st)
{
    const char *sim = tu_sim();
    if (access("/dev/fuse", R_OK | W_OK) != 0) {
        fprintf(stderr, "SKIP: fracnav-sim bench needs /dev/fuse\n");
        skip();
    }
    json_t *j = run_json(sim, "fracnav-sim bench", "bench --seconds 0.2");
    assert_true(json_is_real(json_object_get(json_object_get(j, "throughput"), "report_hz")));
    check(j, "fracnav-sim bench");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_writer),
        cmocka_unit_test(test_key_check),
        cmocka_unit_test(test_volume_commands),
        cmocka_unit_test(test_loop_commands),
        cmocka_unit_test(test_bench_and_devices),
        cmocka_unit_test(test_bench_render),
        cmocka_unit_test(test_sim_bench),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
