/* fracnav devices and fracnav device-test, as a user runs them. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "testutil.h"

static void test_devices_none_connected(void **s)
{
    char *out;
    /* No controller on a CI machine: says so and succeeds. */
    assert_int_equal(tu_run_cli(&out, "devices"), 0);
    if (!strstr(out, "/dev/hidraw")) /* a machine with a real controller lists it instead */
        assert_non_null(strstr(out, "no 6-DOF controller connected"));
    assert_non_null(strstr(out, "transports:"));
    assert_non_null(strstr(out, "spnav"));
    assert_non_null(strstr(out, "keyboard"));
    free(out);
}

static void test_devices_json(void **s)
{
    char *out;
    assert_int_equal(tu_run_cli(&out, "devices --json --device /nonexistent/hidraw7 2>/dev/null"), 0);
    json_error_t err;
    json_t *root = json_loads(out, 0, &err);
    if (!root)
        fail_msg("not JSON (%s): %s", err.text, out);
    json_t *devs = json_object_get(root, "devices"), *trs = json_object_get(root, "transports");
    assert_true(json_is_array(devs) && json_is_array(trs));
    assert_true(json_array_size(trs) >= 3);
    json_t *last = json_array_get(devs, json_array_size(devs) - 1);
    assert_string_equal(json_string_value(json_object_get(last, "path")), "/nonexistent/hidraw7");
    const char *why = json_string_value(json_object_get(last, "error"));
    assert_true(strstr(why, "No such file") || strstr(why, "libusb build opens USB paths"));
    json_decref(root);
    free(out);
}

static void test_usage_errors(void **s)
{
    char *out;
    assert_int_equal(tu_run_cli(&out, "devices --bogus"), 2);
    assert_non_null(strstr(out, "fracnav devices: unknown or incomplete option '--bogus'"));
    free(out);
    assert_int_equal(tu_run_cli(NULL, "devices --help"), 0);
    assert_int_equal(tu_run_cli(NULL, "device-test --help"), 0);
    assert_int_equal(tu_run_cli(&out, "device-test --seconds -1"), 2);
    free(out);
    assert_int_equal(tu_run_cli(&out, "device-test --device --seconds 0.3"), 2); /* no SPEC: not '--seconds' */
    assert_non_null(strstr(out, "--device wants a value, got option --seconds"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "devices --device"), 2);
    assert_non_null(strstr(out, "--device wants a SPEC"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "devices --device a --device b --device c --device d --device e --device f "
                                      "--device g --device h --device i"), 2);
    assert_non_null(strstr(out, "at most 8 --device options"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "devices"), 0); /* the transport column fits the longest name */
    assert_non_null(strstr(out, "  replay-realtime  opened by name"));
    assert_null(strstr(out, "spnav: spacenavd")); /* the transport is named once */
    free(out);
    assert_int_equal(tu_run_cli(&out, "device-test --device /nonexistent/hidraw3 --seconds 1"), 1);
    assert_non_null(strstr(out, "fracnav device-test: device '/nonexistent/hidraw3'"));
    free(out);
}

/* A plain file given as a device, spelled relatively, is refused with a message: no crash. */
static void test_regular_file_as_device(void **s)
{
    char *dir = tu_tmpdir("devfile"), path[4200], cwd[4200], *out;
    snprintf(path, sizeof path, "%s/regfile", dir);
    tu_write_file(path, "x", 1);
    assert_non_null(getcwd(cwd, sizeof cwd));
    assert_int_equal(chdir(dir), 0); /* the CLI runs in the file's folder */
    static const char *const specs[] = {"./regfile", "hidraw:regfile", "regfile"};
    for (size_t i = 0; i < 3; i++) {
        assert_int_equal(tu_run_cli(&out, "device-test --device %s --seconds 0.1", specs[i]), 1);
        assert_non_null(strstr(out, "regfile"));
        free(out);
    }
    assert_int_equal(tu_run_cli(&out, "devices --device ./regfile"), 0);
    assert_non_null(strstr(out, "cannot open"));
    assert_non_null(strstr(out, "./regfile  (not opened)\n")); /* no made-up 0000:0000 id */
    assert_non_null(strstr(out, "transport hidraw") ? strstr(out, "transport hidraw") : strstr(out, "transport libusb"));
    assert_null(strstr(out, "0000:0000"));
    assert_null(strstr(out, "transport ?"));
    free(out);
    assert_int_equal(chdir(cwd), 0);
    tu_rmtree(dir);
    free(dir);
}

/* The keyboard fallback fed from a file: the live view shows the keys' motion and button. */
static void test_device_test_keyboard(void **s)
{
    char *dir = tu_tmpdir("devcli"), path[4200], rc[4200], *out;
    snprintf(path, sizeof path, "%s/keys", dir);
    tu_write_file(path, "d4", 2);
    snprintf(rc, sizeof rc, "%s/spnavrc", dir);
    tu_write_file(rc, "sensitivity = 2\ndead-zone = 0\nnonsense\n", 39);
    assert_int_equal(tu_run_cli(&out, "device-test --device keyboard:%s --seconds 0.4 --config %s", path, rc), 0);
    assert_non_null(strstr(out, "via keyboard"));
    assert_non_null(strstr(out, "x +0.71>+1.43")); /* 250/350 normalized, then sensitivity 2 */
    assert_non_null(strstr(out, "| - reports/s")); /* the rate is not measured in the first second */
    assert_null(strstr(out, "| 0 reports/s"));
    assert_null(strstr(out, "0000:0000"));
    assert_non_null(strstr(out, "buttons B4"));
    assert_non_null(strstr(out, "1 bad line(s) skipped"));
    assert_non_null(strstr(out, "spnavrc:3:"));
    free(out);
    tu_rmtree(dir);
    free(dir);
}

/* A cap that rests off centre: --calibrate-zero measures it and saves it as the zero offset. */
static void test_calibrate_zero_saves_config(void **s)
{
    char *dir = tu_tmpdir("devzero"), keys[4200], rc[4200], *out;
    snprintf(keys, sizeof keys, "%s/keys", dir);
    tu_write_file(keys, "d", 1); /* +x held for 150 ms of the 1 s window (wall time: under load,
                                  * any share of it) */
    snprintf(rc, sizeof rc, "%s/spnavrc", dir);
    assert_int_equal(tu_run_cli(&out, "device-test --device keyboard:%s --calibrate-zero --config %s", keys, rc), 0);
    assert_non_null(strstr(out, "saved to"));
    free(out);
    char *text = tu_slurp(rc, NULL);
    assert_non_null(text);
    const char *z = strstr(text, "zero-offset0 = ");
    assert_non_null(z);
    double v = atof(z + 15);
    assert_true(v >= 0 && v <= 0.715); /* about 0.71 x 0.15 s / 1 s on a quiet machine; the key's
                                        * level (250 of 350) at the most */
    assert_non_null(strstr(text, "zero-offset1 = 0\n"));
    free(text);
    tu_rmtree(dir);
    free(dir);
}

/* An open controller keeps its zero offsets itself: --calibrate-zero writes feature report 0x21
 * (offset = the measured rest, in counts) and the host file gets 0, not a second correction. */
static void test_calibrate_zero_open_controller(void **s)
{
    char *dir = tu_tmpdir("devzero"), scr[4200], rc[4200], *out;
    snprintf(scr, sizeof scr, "%s/hold.script", dir);
    tu_write_file(scr, "translate +x 20 mm over 3 s\n", 28); /* 70 counts on x, held */
    snprintf(rc, sizeof rc, "%s/spnavrc", dir);
    assert_int_equal(tu_run_cli(&out, "device-test --device virtual:open-controller:script=%s --calibrate-zero "
                                      "--config %s", scr, rc), 0);
    const char *fw = strstr(out, "controller zero offsets (feature report 0x21) now ");
    if (!fw)
        fail_msg("%s", out);
    int z[6];
    assert_int_equal(sscanf(fw + 50, "%d %d %d %d %d %d", &z[0], &z[1], &z[2], &z[3], &z[4], &z[5]), 6);
    assert_true(z[0] > 10 && z[0] <= 70);
    for (int i = 1; i < 6; i++)
        assert_int_equal(z[i], 0);
    free(out);
    char *text = tu_slurp(rc, NULL);
    assert_non_null(strstr(text, "zero-offset0 = 0\n"));
    free(text);
    tu_rmtree(dir);
    free(dir);
}

/* --calibrate-zero --config F keeps every line of F it does not change (comments, blank lines,
 * spacenavd's own keys, lines it does not know), as spacenavd's config writer does. */
static void test_calibrate_zero_keeps_user_lines(void **s)
{
    char *dir = tu_tmpdir("devzero"), keys[4200], rc[4200], *out;
    snprintf(keys, sizeof keys, "%s/keys", dir);
    tu_write_file(keys, "d", 1);
    snprintf(rc, sizeof rc, "%s/spnavrc", dir);
    const char *mine = "# my SpaceMouse, tuned for the OR\n"
                       "sensitivity = 1.5   # a bit faster\n"
                       "\n"
                       "grab = false\n"
                       "nonsense here\n"
                       "frobnicate = 7\n"
                       "zero-offset0 = 0.9 # measured last week\n";
    tu_write_file(rc, mine, strlen(mine));
    assert_int_equal(tu_run_cli(&out, "device-test --device keyboard:%s --calibrate-zero --config %s", keys, rc), 0);
    free(out);
    char *text = tu_slurp(rc, NULL);
    assert_non_null(text);
    assert_non_null(strstr(text, "# my SpaceMouse, tuned for the OR\nsensitivity = 1.5   # a bit faster\n\n"
                                 "grab = false\nnonsense here\nfrobnicate = 7\nzero-offset0 = "));
    assert_non_null(strstr(text, " # measured last week\n"));
    assert_null(strstr(text, "zero-offset0 = 0.9")); /* above the key's level: replaced */
    const char *z = strstr(text, "zero-offset0 = ");
    double v = atof(z + 15);
    assert_true(v >= 0 && v <= 0.715);
    assert_non_null(strstr(text, "zero-offset1 = 0\n")); /* keys the file lacked are appended */
    assert_null(strstr(strstr(text, "\nsensitivity = ") + 1, "\nsensitivity = ")); /* set once, not twice */
    free(text);
    tu_rmtree(dir);
    free(dir);
}

/* device-test names buttons: the Enterprise's keys by their labels from the device table, other
 * devices' buttons as B1, B2, ...; never as a hex mask or a raw key code. */
static void test_device_test_button_names(void **s)
{
    char *dir = tu_tmpdir("devnames"), scr[4200], *out;
    snprintf(scr, sizeof scr, "%s/keys.script", dir);
    const char *keys = "press 1 13 4\nwait 60 ms\nrelease 13\nwait 60 ms\nrelease\nwait 60 ms\n";
    tu_write_file(scr, keys, strlen(keys)); /* codes 1 MENU, 13 "1", 36 ENTER (button 4) */
    assert_int_equal(tu_run_cli(&out, "device-test --device virtual:spacemouse-enterprise:script=%s --seconds 600",
                                scr), 0);
    /* A loaded machine may fold the presses and releases read in one poll into one line: what
     * counts is that every key is named as pressed, then as released, and no mask is shown. */
    const char *pressed = strstr(out, "(pressed MENU,ENTER,1)");
    const char *released = strstr(out, "(released MENU,ENTER,1)");
    if (!released) {
        const char *one = strstr(out, "(released 1)"), *rest = strstr(out, "(released MENU,ENTER)");
        released = one && rest ? (one > rest ? one : rest) : NULL;
    }
    if (!pressed || !released || released < pressed || strstr(out, "00000"))
        fail_msg("Enterprise keys not named: %s", out);
    free(out);
    const char *two = "press 2\nwait 60 ms\nrelease\nwait 60 ms\n";
    tu_write_file(scr, two, strlen(two));
    assert_int_equal(tu_run_cli(&out, "device-test --device virtual:spacenavigator:script=%s --seconds 600", scr), 0);
    pressed = strstr(out, "(pressed B2)");
    released = strstr(out, "(released B2)");
    if (!pressed || !released || released < pressed)
        fail_msg("SpaceNavigator buttons not named: %s", out);
    free(out);
    tu_rmtree(dir);
    free(dir);
}

/* Output and exit status of `fracnav-sim ARGS` (beside fracnav in the build; skips when not built). */
static int sim_cli(char **out, const char *args)
{
    char cmd[8300];
    snprintf(cmd, sizeof cmd, "'%s' %s 2>&1", tu_sim(), args);
    FILE *f = popen(cmd, "r");
    size_t n = 0, cap = 16384;
    *out = calloc(1, cap);
    n = fread(*out, 1, cap - 1, f);
    (*out)[n] = '\0';
    return WEXITSTATUS(pclose(f));
}

/* out: read after the call that fills it has run (an argument's order of evaluation is not). */
static void expect_hint(int rc, char **out, const char *hint)
{
    if (rc != 2 || !strstr(*out, hint))
        fail_msg("exit %d, want 2 and '%s': %s", rc, hint, *out);
    free(*out);
}

/* --help and --version say what the commands take; every usage error ends with the same hint. */
static void test_help_version_and_hints(void **s)
{
    char *out;
    assert_int_equal(tu_run_cli(&out, "--help"), 0);
    assert_non_null(strstr(out, "fracnav --version"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "--version"), 0);
    assert_true(!strncmp(out, "fracnav ", 8));
    free(out);
    assert_int_equal(tu_run_cli(&out, "record --help"), 0);
    assert_true(strstr(out, "  -o FILE.fnrec ") && strstr(out, "  --device SPEC ") && strstr(out, "  --seconds S ") &&
                strstr(out, "  --wait-replug "));
    free(out);
    assert_int_equal(tu_run_cli(&out, "device-test --help"), 0);
    assert_true(strstr(out, "  --device SPEC ") && strstr(out, "  --seconds S ") && strstr(out, "  --config SPNAVRC ") &&
                strstr(out, "  --calibrate-zero "));
    free(out);
    expect_hint(tu_run_cli(&out, "record --bogus"), &out, "(see fracnav record --help)");
    expect_hint(tu_run_cli(&out, "record"), &out, "(see fracnav record --help)");
    expect_hint(tu_run_cli(&out, "devices --bogus"), &out, "(see fracnav devices --help)");
    expect_hint(tu_run_cli(&out, "device-test --bogus"), &out, "(see fracnav device-test --help)");
    expect_hint(tu_run_cli(&out, "bogus"), &out, "(see fracnav --help)");
}

/* The same of fracnav-sim; skipped, saying so, where it is not built (no libfuse3). */
static void test_sim_help_version_and_hints(void **s)
{
    char *out;
    assert_int_equal(sim_cli(&out, "--version"), 0);
    assert_true(!strncmp(out, "fracnav-sim ", 12));
    free(out);
    assert_int_equal(sim_cli(&out, "serve --help"), 0);
    assert_true(strstr(out, "usage: fracnav-sim serve") && strstr(out, "--exit-at-end") && !strstr(out, "render"));
    free(out);
    assert_int_equal(sim_cli(&out, "list --help"), 0);
    assert_true(strstr(out, "usage: fracnav-sim list") && !strstr(out, "serve"));
    free(out);
    assert_int_equal(sim_cli(&out, "--help"), 0);
    assert_true(strstr(out, "fracnav-sim --version") && strstr(out, "fracnav-sim render"));
    free(out);
    expect_hint(sim_cli(&out, "serve --bogus"), &out, "(see fracnav-sim serve --help)");
    expect_hint(sim_cli(&out, "render -o x"), &out, "(see fracnav-sim render --help)");
    expect_hint(sim_cli(&out, "bench --seconds x"), &out, "(see fracnav-sim bench --help)");
    expect_hint(sim_cli(&out, "bogus"), &out, "(see fracnav-sim --help)");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_devices_none_connected),
        cmocka_unit_test(test_devices_json),
        cmocka_unit_test(test_usage_errors),
        cmocka_unit_test(test_regular_file_as_device),
        cmocka_unit_test(test_device_test_keyboard),
        cmocka_unit_test(test_calibrate_zero_saves_config),
        cmocka_unit_test(test_calibrate_zero_open_controller),
        cmocka_unit_test(test_calibrate_zero_keeps_user_lines),
        cmocka_unit_test(test_device_test_button_names),
        cmocka_unit_test(test_help_version_and_hints),
        cmocka_unit_test(test_sim_help_version_and_hints),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
