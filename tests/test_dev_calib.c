/* Calibration maths and the spnavrc reader. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "calib.h"
#include "devparse.h"
#include "err.h"
#include "testutil.h"

static float one_axis(const calib *c, int axis, float v)
{
    float in[6] = {0}, out[6];
    in[axis] = v;
    calib_apply(c, in, out);
    return out[axis];
}

/* No jump at the threshold: the output leaves 0 continuously and still reaches 1. */
static void test_dead_zone_continuous(void **s)
{
    calib c;
    calib_default(&c);
    c.dead[0] = 0.1f;
    assert_true(one_axis(&c, 0, 0.1f) == 0.0f);
    assert_true(one_axis(&c, 0, 0.05f) == 0.0f);
    float just = one_axis(&c, 0, 0.1001f);
    assert_true(just > 0.0f && just < 1e-3f);
    assert_true(fabsf(one_axis(&c, 0, 1.0f) - 1.0f) < 1e-6f);
    assert_true(fabsf(one_axis(&c, 0, -1.0f) + 1.0f) < 1e-6f);
    float prev = 0;
    for (int i = 0; i <= 1000; i++) { /* monotone, and small steps in give small steps out */
        float v = one_axis(&c, 0, (float)i / 1000.0f);
        assert_true(v >= prev && v - prev < 0.0012f);
        prev = v;
    }
}

static void test_dominant_axis(void **s)
{
    calib c;
    calib_default(&c);
    c.dominant = 1;
    float in[6] = {0.3f, -0.5f, 0.1f, 0.45f, 0, 0}, out[6];
    calib_apply(&c, in, out);
    for (int i = 0; i < 6; i++)
        assert_true(i == 1 ? out[i] < -0.4f : out[i] == 0.0f);
    c.lock = CALIB_LOCK_ROTATION; /* rotation only: the largest rotation wins */
    calib_apply(&c, in, out);
    for (int i = 0; i < 6; i++)
        assert_true(i == 3 ? out[i] > 0.4f : out[i] == 0.0f);
}

static void test_locks_settings_and_buttons(void **s)
{
    calib c;
    calib_default(&c);
    float in[6] = {0.5f, 0.5f, 0.5f, 0.5f, 0.5f, 0.5f}, out[6];
    c.lock = CALIB_LOCK_TRANSLATION;
    calib_apply(&c, in, out);
    assert_true(out[0] > 0 && out[3] == 0.0f && out[5] == 0.0f);
    c.lock = CALIB_LOCK_NONE;
    c.bnact[1] = CALIB_ACT_DISABLE_TRANSLATION;
    dev_event ev = {0};
    ev.buttons = ev.pressed = 1u << 1 | 1u << 0;
    uint32_t pressed;
    uint32_t state = calib_buttons(&c, &ev, &pressed, NULL);
    assert_int_equal(state, 1u); /* the action button is consumed, button 0 passes */
    assert_int_equal(pressed, 1u);
    assert_int_equal(c.lock, CALIB_LOCK_ROTATION);
    calib_apply(&c, in, out);
    assert_true(out[0] == 0.0f && out[4] > 0);
    calib_buttons(&c, &ev, NULL, NULL); /* pressing again toggles back */
    assert_int_equal(c.lock, CALIB_LOCK_NONE);
    /* Enterprise key 29 toggles dominant once per press, not per report while held. */
    dev_event k = {0};
    k.keys[0] = 29;
    calib_buttons(&c, &k, NULL, NULL);
    calib_buttons(&c, &k, NULL, NULL);
    assert_int_equal(c.dominant, 1);
}

/* An Enterprise-only key (ENTER) is bnmap'ed and bnact'ed like any button; binding the ROTATE
 * key's button replaces its built-in action. */
static void test_enterprise_key_bindings(void **s)
{
    calib c;
    calib_default(&c);
    int enter = devtab_key_button(36), rot = devtab_key_button(27);
    char text[160];
    snprintf(text, sizeof text, "bnmap%d = 2\nbnact%d = dominant-axis\n", enter, rot);
    assert_int_equal(calib_parse_spnavrc(&c, text, strlen(text), "rc", NULL, 0), 0);
    devparse_state st;
    devparse_init(&st, devtab_find(0x256f, 0xc633), 0);
    dev_event ev;
    const uint8_t down[] = {0x1C, 36, 0, 27, 0};
    assert_int_equal(devparse_report(&st, down, sizeof down, 0, &ev), 1);
    uint32_t pressed;
    assert_int_equal(calib_buttons(&c, &ev, &pressed, NULL), 1u << 2); /* ENTER -> button 2 */
    assert_int_equal(pressed, 1u << 2);
    assert_int_equal(c.dominant, 1);                 /* ROTATE's button bound: dominant-axis */
    assert_int_equal(c.lock, CALIB_LOCK_NONE);       /* ... instead of rotation only */
}

/* axismapN = M sends device axis N to output M; a partial map swaps (every input drives exactly
 * one output, as a full spacenavd map would), and a full map in any line order reads the same. */
static void test_axismap_is_a_permutation(void **s)
{
    calib c;
    calib_default(&c);
    const char *partial = "axismap0 = 2\n";
    assert_int_equal(calib_parse_spnavrc(&c, partial, strlen(partial), "rc", NULL, 0), 0);
    for (int i = 0; i < 6; i++)
        c.dead[i] = 0;
    float in[6] = {0.1f, 0.2f, 0.3f, 0.4f, 0.5f, 0.6f}, out[6];
    calib_apply(&c, in, out);
    const float want[6] = {0.3f, 0.2f, 0.1f, 0.4f, 0.5f, 0.6f};
    for (int i = 0; i < 6; i++)
        assert_float_equal(out[i], want[i], 1e-6);
    const char *full[2] = {"axismap0 = 1\naxismap1 = 2\naxismap2 = 0\naxismap3 = 5\naxismap4 = 3\naxismap5 = 4\n",
                           "axismap5 = 4\naxismap2 = 0\naxismap4 = 3\naxismap1 = 2\naxismap3 = 5\naxismap0 = 1\n"};
    for (int f = 0; f < 2; f++) {
        calib_default(&c);
        assert_int_equal(calib_parse_spnavrc(&c, full[f], strlen(full[f]), "rc", NULL, 0), 0);
        const int8_t want_map[6] = {2, 0, 1, 4, 5, 3}; /* output i takes device axis want_map[i] */
        assert_memory_equal(c.map, want_map, 6);
    }
    char text[2048];
    calib_format_spnavrc(&c, text, sizeof text); /* and it round-trips */
    calib d;
    calib_default(&d);
    assert_int_equal(calib_parse_spnavrc(&d, text, strlen(text), "rc", NULL, 0), 0);
    assert_memory_equal(d.map, c.map, 6);
}

/* With no file named: the user's ~/.config/fracnav/spnavrc, else the system's spnavrc. */
static void test_load_falls_back_to_system_file(void **s)
{
    char *dir = tu_tmpdir("rcload"), home[4200], etc[4200], f[4300], used[512], diag[256];
    snprintf(home, sizeof home, "%s/home", dir);
    snprintf(etc, sizeof etc, "%s/etc", dir);
    assert_int_equal(mkdir(home, 0700), 0);
    assert_int_equal(mkdir(etc, 0700), 0);
    snprintf(f, sizeof f, "%s/spnavrc", etc);
    tu_write_file(f, "sensitivity = 3\n", 16);
    char *old_home = getenv("HOME") ? strdup(getenv("HOME")) : NULL;
    setenv("HOME", home, 1);
    setenv("FRACNAV_SYSCONFDIR", etc, 1);
    calib c;
    calib_default(&c);
    assert_int_equal(calib_load(&c, NULL, used, sizeof used, diag, sizeof diag), 0);
    assert_string_equal(used, f);
    assert_float_equal(c.sens, 3.0f, 1e-6);
    snprintf(f, sizeof f, "%s/.config", home);
    assert_int_equal(mkdir(f, 0700), 0);
    snprintf(f, sizeof f, "%s/.config/fracnav", home);
    assert_int_equal(mkdir(f, 0700), 0);
    snprintf(f, sizeof f, "%s/.config/fracnav/spnavrc", home);
    tu_write_file(f, "sensitivity = 0.5\n", 18);
    calib_default(&c);
    assert_int_equal(calib_load(&c, NULL, used, sizeof used, diag, sizeof diag), 0);
    assert_string_equal(used, f); /* the user's file wins */
    assert_float_equal(c.sens, 0.5f, 1e-6);
    unsetenv("FRACNAV_SYSCONFDIR");
    if (old_home)
        setenv("HOME", old_home, 1);
    free(old_home);
    tu_rmtree(dir);
    free(dir);
}

/* In a child (opening a FIFO would block the test): calib_load(path) is refused as not a
 * regular file. */
static void expect_rc_refused(const char *path, const char *what)
{
    fflush(NULL);
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        calib c;
        calib_default(&c);
        char used[512], diag[256];
        int rc = calib_load(&c, path, used, sizeof used, diag, sizeof diag);
        int ok = rc < 0 && strstr(fn_err_msg(), "not a regular file");
        if (!ok)
            fprintf(stderr, "%s: rc %d: %s\n", what, rc, fn_err_msg());
        _exit(ok ? 0 : 1);
    }
    if (tu_end(pid, 0, what) != 0)
        fail_msg("%s: not refused as not a regular file", what);
}

/* A FIFO or a device as the config (given, or the default path linked to one) is refused at once:
 * a FIFO hung replay and navigate, /dev/zero was read as an empty config. */
static void test_load_refuses_fifo_and_device(void **s)
{
    char *dir = tu_tmpdir("rcfifo"), fifo[4300], f[4300];
    snprintf(fifo, sizeof fifo, "%s/fifo", dir);
    assert_int_equal(mkfifo(fifo, 0600), 0);
    expect_rc_refused(fifo, "--config FIFO");
    expect_rc_refused("/dev/zero", "--config /dev/zero");
    char *old_home = getenv("HOME") ? strdup(getenv("HOME")) : NULL;
    setenv("HOME", dir, 1);
    snprintf(f, sizeof f, "%s/.config", dir);
    assert_int_equal(mkdir(f, 0700), 0);
    snprintf(f, sizeof f, "%s/.config/fracnav", dir);
    assert_int_equal(mkdir(f, 0700), 0);
    snprintf(f, sizeof f, "%s/.config/fracnav/spnavrc", dir);
    assert_int_equal(symlink(fifo, f), 0);
    expect_rc_refused(NULL, "default spnavrc linked to a FIFO");
    if (old_home)
        setenv("HOME", old_home, 1);
    free(old_home);
    tu_rmtree(dir);
    free(dir);
}

static void test_mapping_invert_swap_sensitivity(void **s)
{
    calib c;
    calib_default(&c);
    for (int i = 0; i < 6; i++)
        c.dead[i] = 0;
    c.map[0] = 2, c.map[2] = 0;  /* x <- z, z <- x */
    c.invert = 1u << 1 | 1u << 3; /* -y, -rx */
    c.swap_yz = 1;
    c.sens = 2, c.sens_r = 0.5f, c.sens_axis[5] = 3;
    float in[6] = {0.1f, 0.2f, 0.3f, 0.4f, 0.5f, 0.6f}, out[6];
    calib_apply(&c, in, out);
    /* after map: 0.3 0.2 0.1 | 0.4 0.5 0.6; swap: 0.3 0.1 0.2 | 0.4 0.6 0.5; invert y, rx */
    const float want[6] = {0.6f, -0.2f, 0.4f, -0.4f, 0.6f, 1.5f};
    for (int i = 0; i < 6; i++)
        assert_true(fabsf(out[i] - want[i]) < 1e-6f);
}

static void test_cubic_and_zero_offset(void **s)
{
    calib c;
    calib_default(&c);
    c.dead[0] = 0;
    c.response = CALIB_CUBIC;
    c.cubic_mix = 1;
    assert_true(fabsf(one_axis(&c, 0, 0.5f) - 0.125f) < 1e-6f);
    assert_true(fabsf(one_axis(&c, 0, 1.0f) - 1.0f) < 1e-6f);
    calib_default(&c);
    const float drift[3][6] = {{0.02f, 0, 0, 0, 0, -0.03f}, {0.04f, 0, 0, 0, 0, -0.03f}, {0.03f, 0, 0, 0, 0, -0.03f}};
    calib_zero_from(&c, drift, 3);
    float out[6];
    calib_apply(&c, drift[2], out);
    for (int i = 0; i < 6; i++)
        assert_true(out[i] == 0.0f); /* the drifting rest position reads as zero */
    float v[6] = {0.03f, 0, 0, 0, 0, 0};
    c.zero[0] = 0;
    calib_do(&c, CALIB_ACT_ZERO, v);
    assert_true(c.zero[0] == 0.03f);
    calib_do(&c, CALIB_ACT_SENS_UP, NULL);
    assert_true(c.sens > 1.0f);
    calib_do(&c, CALIB_ACT_SENS_RESET, NULL);
    assert_true(c.sens == 1.0f);
    assert_int_equal(calib_led(&c, 1), 1); /* auto: lit while a fragment is held */
    assert_int_equal(calib_led(&c, 0), 0);
    c.led = 0;
    assert_int_equal(calib_led(&c, 1), 0);
}

static const char rc_text[] =
    "# a user's spacenavd file\n"
    "sensitivity = 2.5\n"
    "sensitivity-rotation-y = 0.5\n"
    "dead-zone = 10\n"
    "dead-zone3 = 35\n"
    "invert-rot = yz\n"
    "swap-yz = true\n"
    "bnact0 = dominant-axis\n"
    "bnmap1 = 5   # trailing comment\n"
    "led = off\n"
    "grab = false\n"
    "this line has no equals\n"
    "sensitivity = fast\n"
    "dead-zone9 = 3\n"
    "colour = blue\n"
    "axismap0 = 2\n"
    "disable-rotation = yes\n"
    "response = cubic\n";

static void test_spnavrc_reader(void **s)
{
    calib c;
    calib_default(&c);
    char diag[1024];
    int bad = calib_parse_spnavrc(&c, rc_text, strlen(rc_text), "spnavrc", diag, sizeof diag);
    assert_int_equal(bad, 4);
    assert_non_null(strstr(diag, "spnavrc:12: expected 'key = value'"));
    assert_non_null(strstr(diag, "spnavrc:13: bad value 'fast' for 'sensitivity'"));
    assert_non_null(strstr(diag, "spnavrc:14: unknown key 'dead-zone9'"));
    assert_non_null(strstr(diag, "spnavrc:15: unknown key 'colour'"));
    assert_true(c.sens == 2.5f); /* the bad line kept the good value */
    assert_true(c.sens_axis[4] == 0.5f);
    assert_true(fabsf(c.dead[0] - 10 / 350.0f) < 1e-6f && fabsf(c.dead[3] - 0.1f) < 1e-6f);
    assert_int_equal(c.invert, 1u << 4 | 1u << 5);
    assert_int_equal(c.swap_yz, 1);
    assert_int_equal(c.bnact[0], CALIB_ACT_DOMINANT);
    assert_int_equal(c.bnmap[1], 5);
    assert_int_equal(c.led, 0);
    assert_int_equal(c.map[2], 0);
    assert_int_equal(c.lock, CALIB_LOCK_TRANSLATION);
    assert_int_equal(c.response, CALIB_CUBIC);
    /* What we write reads back to the same calibration, with no bad line. */
    char text[8192];
    size_t n = calib_format_spnavrc(&c, text, sizeof text);
    calib d;
    calib_default(&d);
    assert_int_equal(calib_parse_spnavrc(&d, text, n, "written", diag, sizeof diag), 0);
    assert_true(d.sens == c.sens && d.invert == c.invert && d.lock == c.lock && d.map[2] == 0);
    assert_true(fabsf(d.dead[3] - c.dead[3]) < 1e-6f && d.bnact[0] == c.bnact[0]);
}

static void test_spnavrc_hostile(void **s)
{
    calib c;
    calib_default(&c);
    char big[3000];
    memset(big, 'a', sizeof big);
    big[sizeof big - 1] = '\n';
    char diag[64]; /* too small: truncated, still NUL-terminated */
    assert_int_equal(calib_parse_spnavrc(&c, big, sizeof big, "x", diag, sizeof diag), 1);
    assert_true(strlen(diag) < sizeof diag);
    const char nul[] = "sensitivity = 3\0\nled = on\n";
    assert_int_equal(calib_parse_spnavrc(&c, nul, sizeof nul - 1, "x", NULL, 0), 1);
    assert_true(c.led == 1 && c.sens == 1.0f);
    assert_int_equal(calib_parse_spnavrc(&c, "dead-zone = -1\nsensitivity = nan\nbnmap99 = 1\n", 44, "x", NULL, 0), 3);
}

static void test_load_falls_back(void **s)
{
    char *dir = tu_tmpdir("calib");
    char *old = getenv("HOME") ? strdup(getenv("HOME")) : NULL;
    setenv("HOME", dir, 1);
    calib c;
    calib_default(&c);
    char used[512], diag[512], path[4096];
    int rc = calib_load(&c, NULL, used, sizeof used, diag, sizeof diag);
    assert_true(rc >= 0); /* no user file: /etc/spnavrc or defaults */
    snprintf(path, sizeof path, "%s/.config", dir);
    mkdir(path, 0700);
    snprintf(path, sizeof path, "%s/.config/fracnav", dir);
    mkdir(path, 0700);
    snprintf(path, sizeof path, "%s/.config/fracnav/spnavrc", dir);
    tu_write_file(path, "sensitivity = 4\nbogus\n", 22);
    calib_default(&c);
    assert_int_equal(calib_load(&c, NULL, used, sizeof used, diag, sizeof diag), 1);
    assert_string_equal(used, path);
    assert_true(c.sens == 4.0f);
    assert_non_null(strstr(diag, ":2:"));
    assert_true(calib_load(&c, "/nonexistent/spnavrc", used, sizeof used, NULL, 0) < 0);
    if (old) {
        setenv("HOME", old, 1);
        free(old);
    }
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_dead_zone_continuous),
        cmocka_unit_test(test_dominant_axis),
        cmocka_unit_test(test_locks_settings_and_buttons),
        cmocka_unit_test(test_enterprise_key_bindings),
        cmocka_unit_test(test_axismap_is_a_permutation),
        cmocka_unit_test(test_load_falls_back_to_system_file),
        cmocka_unit_test(test_load_refuses_fifo_and_device),
        cmocka_unit_test(test_mapping_invert_swap_sensitivity),
        cmocka_unit_test(test_cubic_and_zero_offset),
        cmocka_unit_test(test_spnavrc_reader),
        cmocka_unit_test(test_spnavrc_hostile),
        cmocka_unit_test(test_load_falls_back),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
