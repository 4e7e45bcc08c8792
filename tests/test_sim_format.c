/* The sim's pure parts: .fnrec reader/writer, scripts rendered into reports, replay. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <signal.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "devparse.h"
#include "devtab.h"
#include "err.h"
#include "fnrec.h"
#include "hiddesc.h"
#include "script.h"
#include "sim_replay.h"
#include "simdev.h"
#include "testutil.h"

static fnrec *render(const char *text, const char *device)
{
    script *s = NULL;
    assert_int_equal(script_parse(text, strlen(text), "test", &s), 0);
    fnrec *r = script_render(s, sim_profile_find(device));
    free(s);
    assert_non_null(r);
    return r;
}

static size_t count_dir(const fnrec *r, fnrec_dir d)
{
    size_t n = 0;
    for (size_t i = 0; i < r->n; i++)
        n += r->ev[i].dir == d;
    return n;
}

static int16_t le16(const uint8_t *b)
{
    return (int16_t)(b[0] | b[1] << 8);
}

/* Writing a recording and reading it back gives the same header and events. */
static void test_fnrec_round_trip(void **st)
{
    fnrec *r = render("translate +x 10 mm over 0.3 s\npress 2\nwait 20 ms\nrelease\nunplug\nreplug\n",
                      "spacenavigator");
    char *dir = tu_tmpdir("fnrec");
    char path[512];
    snprintf(path, sizeof path, "%s/a.fnrec", dir);
    assert_int_equal(fnrec_save(r, path), 0);
    fnrec *back = fnrec_load(path);
    assert_non_null(back);
    assert_int_equal(back->n, r->n);
    assert_memory_equal(back->ev, r->ev, r->n * sizeof *r->ev);
    assert_int_equal(back->hdr.vid, 0x046d);
    assert_int_equal(back->hdr.pid, 0xc626);
    assert_string_equal(back->hdr.name, r->hdr.name);
    assert_string_equal(back->hdr.format, "split");
    assert_non_null(strstr(back->hdr.source, "virtual"));
    assert_int_equal(back->hdr.desc_len, r->hdr.desc_len);
    assert_memory_equal(back->hdr.desc, r->hdr.desc, r->hdr.desc_len);
    assert_int_equal(count_dir(back, FNREC_DISCONNECT), 1);
    assert_int_equal(count_dir(back, FNREC_CONNECT), 2);
    fnrec_free(back);
    fnrec_free(r);
    tu_rmtree(dir);
    free(dir);
}

/* An interrupted recording (a line cut short) loses only that line, which is named; a last line
 * that is whole but lacks its newline (a file written by hand) is kept. */
static void test_fnrec_truncated_loses_last_line_only(void **st)
{
    fnrec *r = render("translate +y 5 mm over 0.2 s\n", "spacemouse-wireless");
    char *dir = tu_tmpdir("fnrec");
    char path[512];
    snprintf(path, sizeof path, "%s/a.fnrec", dir);
    assert_int_equal(fnrec_save(r, path), 0);
    size_t len;
    char *text = tu_slurp(path, &len);
    int last_line = 0;
    for (size_t i = 0; i < len; i++)
        last_line += text[i] == '\n';
    /* Cut inside the last event line at a byte boundary: what is left parses as a report, but
     * shorter than the descriptor's 13 bytes; cut at an odd digit it does not parse. */
    for (size_t cut = 5; cut <= 6; cut++) {
        fnrec *part = NULL;
        assert_int_equal(fnrec_parse(text, len - cut, "cut.fnrec", &part), 0);
        assert_int_equal(part->n, r->n - 1);
        assert_int_equal(part->torn_line, last_line);
        assert_true(part->torn_why[0] != '\0');
        fnrec_free(part);
    }
    /* Only the newline missing: the line is whole and kept. */
    fnrec *whole = NULL;
    assert_int_equal(fnrec_parse(text, len - 1, "whole.fnrec", &whole), 0);
    assert_int_equal(whole->n, r->n);
    assert_int_equal(whole->torn_line, 0);
    assert_memory_equal(whole->ev, r->ev, r->n * sizeof *r->ev);
    fnrec_free(whole);
    free(text);
    fnrec_free(r);
    tu_rmtree(dir);
    free(dir);
}

static void expect_error(const char *text, const char *line, const char *what)
{
    fnrec *r = NULL;
    assert_int_equal(fnrec_parse(text, strlen(text), "bad.fnrec", &r), FN_EFORMAT);
    assert_null(r);
    const char *msg = fn_err_msg();
    if (!strstr(msg, line) || !strstr(msg, what))
        fail_msg("error '%s' should name '%s' and say '%s'", msg, line, what);
}

#define HDR "fnrec 1\nvid 046d\npid c626\nname X\nformat split\ndescriptor 0501\n"

static void test_fnrec_malformed(void **st)
{
    expect_error("", "bad.fnrec", "empty");
    expect_error("hello\n", "bad.fnrec:1:", "not a .fnrec");
    fnrec *r = NULL; /* a script given where a recording belongs: says how to render it */
    const char *scr = "translate +x 1 mm over 1 s\n";
    assert_int_equal(fnrec_parse(scr, strlen(scr), "move.script", &r), FN_EFORMAT);
    assert_non_null(strstr(fn_err_msg(), "move.script:1: a motion script"));
    assert_non_null(strstr(fn_err_msg(), "fracnav-sim render"));
    expect_error("fnrec 9\n", "bad.fnrec:1:", "version");
    expect_error("fnrec 1\nvid 46d\n", "bad.fnrec:2:", "4 hex digits");
    expect_error("fnrec 1\nvid 046d\nvid 046d\n", "bad.fnrec:3:", "twice");
    expect_error("fnrec 1\ncolour red\n", "bad.fnrec:2:", "unknown header key");
    expect_error("fnrec 1\nvid 046d\nevents\n", "bad.fnrec:3:", "lacks 'pid'");
    expect_error("fnrec 1\nvid 046d\npid c626\nname X\nformat diagonal\n", "bad.fnrec:5:", "split");
    expect_error(HDR, "bad.fnrec:6:", "not ended");
    expect_error(HDR "events\nabc in 01\n", "bad.fnrec:8:", "timestamp");
    expect_error(HDR "events\n10 in 0100\n5 in 0100\n", "bad.fnrec:9:", "backwards");
    expect_error(HDR "events\n10 sideways 01\n", "bad.fnrec:8:", "direction");
    expect_error(HDR "events\n10 in\n", "bad.fnrec:8:", "missing");
    expect_error(HDR "events\n10 in 0g\n", "bad.fnrec:8:", "hex");
    expect_error(HDR "events\n10 in 010\n", "bad.fnrec:8:", "odd number of hex digits (3)");
    expect_error("fnrec 1\ndescriptor 050\n", "bad.fnrec:2:", "odd number of hex digits");
    expect_error(HDR "events\n10 connect 01\n", "bad.fnrec:8:", "no bytes");
    expect_error(HDR "events\n99999999999999999999 in 01\n", "bad.fnrec:8:", "too large");
    char big[300];
    memset(big, 'a', sizeof big);
    snprintf(big, sizeof big, HDR "events\n1 in %0130d\n", 0);
    expect_error(big, "bad.fnrec:8:", "1 to 64 bytes");
    static const char nul[] = "fnrec 1\nvid 046d\0\n";
    assert_int_equal(fnrec_parse(nul, sizeof nul - 1, "bad.fnrec", &r), FN_EFORMAT);
    assert_non_null(strstr(fn_err_msg(), "bad.fnrec:2: NUL"));
    /* Comments, blank lines, CRLF and an empty descriptor are fine. */
    const char *ok = "fnrec 1\r\n# made by hand\r\nvid 046d\npid c626\nname X\nformat combined\n"
                     "descriptor\n\nevents\n0 connect\n8000 in 01000000000000000000000000\n";
    assert_int_equal(fnrec_parse(ok, strlen(ok), "ok.fnrec", &r), 0);
    assert_int_equal(r->n, 2);
    assert_int_equal(r->hdr.desc_len, 0);
    assert_int_equal(r->ev[1].len, 13);
    fnrec_free(r);
    /* Written by hand without a final newline: the last line counts. */
    const char *hand = HDR "events\n0 connect\n8000 in 0102";
    assert_int_equal(fnrec_parse(hand, strlen(hand), "hand.fnrec", &r), 0);
    assert_int_equal(r->n, 2);
    assert_int_equal(r->ev[1].len, 2);
    fnrec_free(r);
    const char *junk = HDR "events\n0 connect\n8000 in 01x";
    assert_int_equal(fnrec_parse(junk, strlen(junk), "junk.fnrec", &r), 0);
    assert_int_equal(r->n, 1);
    assert_int_equal(r->torn_line, 9);
    fnrec_free(r);
    assert_null(fnrec_load("/nonexistent/x.fnrec"));
    assert_non_null(strstr(fn_err_msg(), "/nonexistent/x.fnrec"));
}

/* Issue 17: a recording past 2^20 events names its line and the cause once; a timestamp far in
 * the future (which would hold a real-time replay for days) is refused with its line named. */
static void test_fnrec_limits(void **st)
{
    size_t cap = strlen(HDR "events\n") + ((size_t)FNREC_MAX_EVENTS + 2) * 16;
    char *text = malloc(cap);
    assert_non_null(text);
    size_t n = (size_t)snprintf(text, cap, HDR "events\n");
    for (size_t i = 0; i <= FNREC_MAX_EVENTS; i++)
        n += (size_t)snprintf(text + n, cap - n, "%zu in 0100\n", i);
    fnrec *r = NULL;
    assert_true(fnrec_parse(text, n, "long.fnrec", &r) < 0);
    assert_null(r);
    char want[64];
    snprintf(want, sizeof want, "long.fnrec:%u: more than %u events", FNREC_MAX_EVENTS + 8, FNREC_MAX_EVENTS);
    if (!strstr(fn_err_msg(), want) || strstr(fn_err_msg(), "long.fnrec:1048584: long.fnrec"))
        fail_msg("'%s' should say '%s', once", fn_err_msg(), want);
    free(text);
    expect_error(HDR "events\n0 connect\n8000 in 0100\n999999999999 in 0100\n", "bad.fnrec:10:",
                 "at most 3600 s apart");
    expect_error(HDR "events\n3600000001 connect\n", "bad.fnrec:8:", "at most 3600 s apart");
    const char *ok = HDR "events\n0 connect\n3600000000 in 0100\n";
    assert_int_equal(fnrec_parse(ok, strlen(ok), "ok.fnrec", &r), 0);
    fnrec_free(r);
    /* and through the command line: a real-time replay of it stops at once, naming the line */
    char *dir = tu_tmpdir("fnrecgap"), path[512], *out = NULL;
    snprintf(path, sizeof path, "%s/future.fnrec", dir);
    const char *future = HDR "events\n0 connect\n8000 in 0100\n9000000000000000 in 0100\n";
    tu_write_file(path, future, strlen(future));
    assert_int_equal(tu_run_cli(&out, "device-test --device replay-realtime:%s --seconds 20", path), 1);
    assert_non_null(strstr(out, "future.fnrec:10:"));
    free(out);
    tu_rmtree(dir);
    free(dir);
}

/* Split format: ID1/ID2 alternate every 8 ms; after release each is sent three times with zeros,
 * then nothing; the counts follow SCRIPT_FULL_COUNTS / SCRIPT_MM_PER_S_FULL. */
static void test_script_split_cadence_and_release(void **st)
{
    fnrec *r = render("translate +x 20 mm over 2 s\n", "spacenavigator");
    const fnrec_event *e = r->ev;
    assert_int_equal(e[0].dir, FNREC_CONNECT);
    int want = (int)lround(10.0 / SCRIPT_MM_PER_S_FULL * SCRIPT_FULL_COUNTS); /* 10 mm/s */
    size_t moving = 0, zeros = 0;
    for (size_t i = 1; i < r->n; i++) {
        assert_int_equal(e[i].t_us - e[i - 1].t_us, i == 1 ? 8000 : 8000);
        assert_int_equal(e[i].len, 7);
        assert_int_equal(e[i].data[0], i % 2 ? 1 : 2);
        int16_t x = le16(e[i].data + 1);
        if (e[i].data[0] == 1 && x) {
            assert_int_equal(x, want);
            assert_int_equal(zeros, 0);
            moving++;
        } else if (e[i].t_us >= 2000000) {
            zeros++;
        }
    }
    assert_int_equal(moving, 2000000 / 16000 - 1 + 1);
    assert_int_equal(zeros, 2 * SIMDEV_ZERO_REPEATS);
    assert_true(r->ev[r->n - 1].t_us < 2000000 + 8000 * 7);
    fnrec_free(r);
}

/* Combined format: one 13-byte report per 16 ms; buttons go out as report 3 in the next period. */
static void test_script_combined_and_buttons(void **st)
{
    fnrec *r = render("rotate about z -15 deg over 1 s\npress 1\nwait 50 ms\nrelease 1\nwait 50 ms\n",
                      "spacemouse-wireless");
    double sum = 0;
    size_t nmotion = 0, nbutton = 0;
    assert_int_equal(r->ev[1].data[0], 0x17); /* battery, once after connecting */
    assert_int_equal(r->ev[1].data[1], 100);
    for (size_t i = 2; i < r->n; i++) {
        const fnrec_event *e = &r->ev[i];
        assert_int_equal(e->t_us % 16000, 0);
        if (e->data[0] == 1) {
            assert_int_equal(e->len, 13);
            sum += le16(e->data + 11);
            nmotion++;
        } else {
            assert_int_equal(e->data[0], 3);
            assert_int_equal(e->len, 3);
            assert_int_equal(e->data[1], nbutton == 0 ? 1 : 0);
            nbutton++;
        }
    }
    assert_int_equal(nbutton, 2);
    /* -15 deg/s: the dithered counts average to the exact speed over the move. */
    double want = -15.0 / SCRIPT_DEG_PER_S_FULL * SCRIPT_FULL_COUNTS;
    assert_true(fabs(sum / (nmotion - SIMDEV_ZERO_REPEATS) - want) < 0.05);
    fnrec_free(r);
}

/* The Enterprise follows report 3 with report 0x1C key codes, those of the device table's key
 * list (devtab_keys): button 1 is MENU (code 1), button 13 the key "1" (code 13), button 4 ENTER
 * (code 36, a key that exists only in 0x1C). */
static void test_script_enterprise_keycodes(void **st)
{
    fnrec *r = render("press 1 13 4\nwait 40 ms\n", "spacemouse-enterprise");
    assert_int_equal(r->n, 3);
    assert_int_equal(r->ev[1].data[0], 3);
    assert_int_equal(r->ev[2].data[0], 0x1C);
    assert_int_equal(le16(r->ev[2].data + 1), 1);
    assert_int_equal(le16(r->ev[2].data + 3), 13);
    assert_int_equal(le16(r->ev[2].data + 5), 36);
    assert_int_equal(le16(r->ev[2].data + 7), 0);
    fnrec_free(r);
}

static void expect_script_error(const char *text, const char *what)
{
    script *s = NULL;
    assert_int_equal(script_parse(text, strlen(text), "bad.script", &s), FN_EFORMAT);
    assert_null(s);
    if (!strstr(fn_err_msg(), what) || !strstr(fn_err_msg(), "bad.script:"))
        fail_msg("script error '%s' should say '%s'", fn_err_msg(), what);
}

static void test_script_errors(void **st)
{
    expect_script_error("translate +x 20 mm\n", "over");
    expect_script_error("translate +w 20 mm over 1 s\n", "unknown axis");
    expect_script_error("translate x 20 cm over 1 s\n", "mm");
    expect_script_error("rotate z 20 mm over 1 s\n", "deg");
    expect_script_error("translate x 200 mm over 1 s\n", "faster than full deflection");
    expect_script_error("wait 1 fortnight\n", "unit");
    expect_script_error("wait\n", "duration");
    expect_script_error("press 99\n", "1..32");
    expect_script_error("dance\n", "unknown command");
    expect_script_error("# fine\n\nunplug now\n", "bad.script:3:");
    script *s = NULL;
    const char *ok = "hold move x 1 mm rz 2 deg over 100 ms # both\nrelease\n";
    assert_int_equal(script_parse(ok, strlen(ok), "ok", &s), 0);
    assert_int_equal(s->n, 2);
    assert_true(s->step[0].hold);
    assert_true(fabs(s->step[0].speed[0] - 10) < 1e-9 && fabs(s->step[0].speed[5] - 20) < 1e-9);
    free(s);
}

/* Every profile's descriptor parses and declares the reports the generator sends. */
static void check_profile(const sim_profile *p)
{
    uint8_t desc[DEV_DESC_MAX];
    size_t n = sim_profile_descriptor(p, desc, sizeof desc);
    hiddesc d;
    if (hiddesc_parse(desc, n, &d))
        fail_msg("%s: %s", p->id, fn_err_msg());
    for (int id = 1; id < 0x20; id++) {
        int len = sim_profile_report_len(p, (uint8_t)id);
        const hiddesc_report *rep = hiddesc_find(&d, HIDDESC_INPUT, (uint8_t)id);
        if (len && !(rep && rep->len == (size_t)len))
            fail_msg("%s: input report %d (%d bytes) not declared", p->id, id, len);
    }
    assert_int_equal(hiddesc_axis_max(&d), 350);
    assert_non_null(hiddesc_find(&d, HIDDESC_OUTPUT, 4));
}

/* Every hardware row of the device table can be impersonated, by VID:PID and by name: the profile
 * carries the row's identity, and a rendered move and button press parse back, through the row,
 * to the same motion and button on this row's own report format. */
static void test_every_devtab_row_is_impersonable(void **st)
{
    size_t nrows, seen = 0;
    const devtab_row *rows = devtab_rows(&nrows);
    for (size_t i = 0; i < nrows; i++) {
        const devtab_row *row = &rows[i];
        if (row->flags & DEVTAB_F_SYNTH)
            continue;
        char vidpid[16];
        snprintf(vidpid, sizeof vidpid, "%04x:%04x", row->vid, row->pid);
        const sim_profile *p = sim_profile_find(vidpid);
        if (!p)
            fail_msg("%s (%s) cannot be impersonated: %s", vidpid, row->name, fn_err_msg());
        seen++;
        assert_ptr_equal(p->row, row);
        assert_ptr_equal(sim_profile_find(p->id), p);
        size_t ln = strlen(p->name), lr = strlen(row->name); /* [manufacturer " "] product */
        assert_true(ln >= lr && !strcmp(p->name + ln - lr, row->name));
        assert_int_equal(p->format == SIMDEV_COMBINED, row->format == DEVTAB_COMBINED);
        assert_int_equal(p->battery, (row->flags & DEVTAB_F_BATTERY) != 0);
        assert_int_equal(p->keycodes, (row->flags & DEVTAB_F_KEYCODES) != 0);
        check_profile(p);
        /* The row's highest real button, pressed during a move along +y. */
        int top = 0;
        for (int b = 0; b < 32; b++)
            top = row->button_mask >> b & 1 ? b : top;
        char text[128];
        snprintf(text, sizeof text, "press %d\nmove y 2 mm over 0.1 s\nrelease\n", top + 1);
        fnrec *r = render(text, vidpid);
        assert_int_equal(r->hdr.vid, row->vid);
        assert_int_equal(r->hdr.pid, row->pid);
        devparse_state ps;
        devparse_init(&ps, row, 350);
        dev_event ev;
        uint32_t buttons_seen = 0;
        int moved = 0, battery = 0;
        for (size_t k = 0; k < r->n; k++) {
            const fnrec_event *e = &r->ev[k];
            if (e->dir != FNREC_IN)
                continue;
            if (!devparse_report(&ps, e->data, e->len, e->t_us, &ev))
                fail_msg("%s: report %02x (%u bytes) refused by the parser", vidpid, e->data[0], e->len);
            buttons_seen |= ps.buttons;
            moved |= ps.raw[1] == 140; /* 20 mm/s of the 50 mm/s at 350 counts */
            battery |= e->data[0] == 0x17;
        }
        assert_int_equal(buttons_seen, 1u << (row->nbuttons - 1)); /* packed: the last button */
        assert_true(moved);
        assert_int_equal(battery, p->battery);
        fnrec_free(r);
    }
    size_t nprof = 0;
    while (sim_profile_at(nprof))
        nprof++;
    assert_int_equal(nprof, seen);
    assert_null(sim_profile_find("ffff:0001"));
    assert_non_null(strstr(fn_err_msg(), "ffff:0001"));
}

/* The open controller's descriptor is firmware-spec/open-controller.desc.hex byte for byte. */
static void test_open_controller_descriptor_is_the_spec(void **st)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/firmware-spec/open-controller.desc.hex", tu_src());
    size_t len;
    char *text = tu_slurp(path, &len);
    assert_non_null(text);
    uint8_t spec[1024];
    size_t n = 0;
    for (char *line = strtok(text, "\n"); line; line = strtok(NULL, "\n")) {
        char *hash = strchr(line, '#');
        if (hash)
            *hash = '\0';
        for (char *tok = strtok_r(line, " \t", &hash); tok; tok = strtok_r(NULL, " \t", &hash))
            spec[n++] = (uint8_t)strtoul(tok, NULL, 16);
    }
    free(text);
    uint8_t desc[DEV_DESC_MAX];
    size_t got = sim_profile_descriptor(sim_profile_find("open-controller"), desc, sizeof desc);
    assert_int_equal(got, n);
    assert_memory_equal(desc, spec, n);
}

/* LED output and feature reports on the generator. */
static void test_led_and_features(void **st)
{
    simdev d;
    simdev_init(&d, sim_profile_find("spacenavigator"));
    assert_int_equal(simdev_output(&d, (const uint8_t[]){4, 1}, 2), 2);
    assert_int_equal(d.led, 1);
    assert_true(simdev_output(&d, (const uint8_t[]){9, 1}, 2) < 0);
    uint8_t f[16] = {5};
    int n = simdev_get_feature(&d, f, sizeof f);
    assert_true(n > 1);
    assert_int_equal(f[0], 5);
    assert_int_equal(simdev_set_feature(&d, (const uint8_t[]){5, 9, 8, 7, 6}, 5), 5);
    memset(f, 0, sizeof f);
    f[0] = 5;
    assert_int_equal(simdev_get_feature(&d, f, sizeof f), 5);
    assert_int_equal(f[1], 9);
    f[0] = 30;
    assert_true(simdev_get_feature(&d, f, sizeof f) < 0);
    /* Idle device: silent. */
    uint8_t buf[64];
    assert_int_equal(simdev_next(&d, buf, sizeof buf), 0);
}

/* The open controller acts on 0x22 (LED mode, cadence, zeros) and 0x21 (offsets, noise floor);
 * a replug restores the volatile settings and keeps the non-volatile offsets. */
static void test_open_controller_settings(void **st)
{
    simdev d;
    simdev_init(&d, sim_profile_find("open-controller"));
    assert_int_equal(simdev_period_us(&d), 8000);
    assert_int_equal(simdev_set_feature(&d, (const uint8_t[]){0x22, 12, 0, 1}, 4), 4);
    assert_true(simdev_set_feature(&d, (const uint8_t[]){0x22, 0, 3, 0}, 4) < 0); /* cadence 0 */
    assert_int_equal(simdev_period_us(&d), 12000);
    uint8_t off[13] = {0x21, 0xfe, 0xff, 5, 0}; /* x -2, y +5 */
    assert_int_equal(simdev_set_feature(&d, off, sizeof off), 13);
    uint8_t buf[64];
    simdev_next(&d, buf, sizeof buf); /* battery */
    assert_int_equal(simdev_output(&d, (const uint8_t[]){4, 1}, 2), 2);
    assert_int_equal(d.led, 0); /* LED mode 1: report 4 is ignored */
    simdev_set(&d, (const int16_t[6]){100, 6, 0, 0, 0, 0}, 0);
    assert_int_equal(d.led, 1);
    assert_int_equal(simdev_next(&d, buf, sizeof buf), 13);
    assert_int_equal(le16(buf + 1), 102);
    assert_int_equal(le16(buf + 3), 0); /* 6 - 5 = 1: inside the noise floor */
    simdev_set(&d, (const int16_t[6]){0}, 0);
    assert_int_equal(d.led, 0);
    assert_int_equal(simdev_next(&d, buf, sizeof buf), 0); /* idle_zeros 0: silence at once */
    simdev_replug(&d);
    assert_int_equal(simdev_period_us(&d), 8000);
    assert_int_equal(d.offset[1], 5);
    memset(buf, 0, sizeof buf);
    buf[0] = 0x21;
    assert_int_equal(simdev_get_feature(&d, buf, sizeof buf), 13);
    assert_memory_equal(buf, off, 13);
}

/* Replaying a recording into the parser twice gives the same events, bit for bit; a recorded
 * unplug reads as FN_ENODEV once and the replay goes on. */
static void test_replay_deterministic(void **st)
{
    fnrec *r = render("move x 5 mm ry -3 deg over 0.3 s\npress 1\nwait 30 ms\nunplug\nwait 40 ms\n"
                      "replug\nrelease\ntranslate -z 2 mm over 0.1 s\n", "spacenavigator");
    dev_event ev[2][512];
    size_t nev[2] = {0, 0};
    int unplugs[2] = {0, 0};
    for (int run = 0; run < 2; run++) {
        dev_handle *h;
        assert_int_equal(sim_replay_open_rec(r, NULL, &h), 0);
        devparse_state ps;
        devparse_init(&ps, devtab_find(0x046d, 0xc626), 350);
        uint8_t buf[64];
        int64_t t;
        int n;
        while (!sim_replay_finished(h) || (n = 0)) {
            n = sim_replay_transport.read(h, buf, sizeof buf, 0, &t);
            if (n == FN_ENODEV) {
                unplugs[run]++;
                continue;
            }
            assert_true(n > 0);
            if (devparse_report(&ps, buf, (size_t)n, t, &ev[run][nev[run]]))
                nev[run]++;
        }
        assert_int_equal(sim_replay_transport.read(h, buf, sizeof buf, 0, &t), FN_ENODEV);
        sim_replay_transport.close(h);
    }
    assert_int_equal(unplugs[0], 1);
    assert_int_equal(unplugs[1], 1);
    assert_int_equal(nev[0], nev[1]);
    assert_true(nev[0] > 40);
    assert_memory_equal(ev[0], ev[1], nev[0] * sizeof ev[0][0]);
    fnrec *again = render("move x 5 mm ry -3 deg over 0.3 s\npress 1\nwait 30 ms\nunplug\nwait 40 ms\n"
                          "replug\nrelease\ntranslate -z 2 mm over 0.1 s\n", "spacenavigator");
    assert_int_equal(again->n, r->n);
    assert_memory_equal(again->ev, r->ev, r->n * sizeof *r->ev);
    fnrec_free(again);
    fnrec_free(r);
}

static int64_t now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

/* --realtime keeps the recorded cadence: every report arrives in order and never before its
 * recorded time, and a read that does not wait finds nothing before that time. How close to it
 * they arrive depends on the machine's load: fracnav-sim bench measures it. The default replays at
 * once: every read that does not wait gets the next report. */
static void test_replay_realtime_pacing(void **st)
{
    fnrec *r = render("translate +x 6 mm over 0.6 s\n", "spacenavigator");
    int64_t span = r->ev[r->n - 1].t_us - r->ev[0].t_us;
    assert_true(span >= 600000);
    dev_handle *h;
    assert_int_equal(sim_replay_open_rec(r, &(sim_replay_opts){.realtime = 1}, &h), 0);
    uint8_t buf[64];
    int64_t t, t0 = 0, last_t = -1, start = now_us();
    int n, count = 0;
    assert_int_equal(sim_replay_realtime_transport.read(h, buf, sizeof buf, 0, &t), 0); /* not yet */
    while ((n = sim_replay_realtime_transport.read(h, buf, sizeof buf, 100, &t)) >= 0) {
        if (n == 0)
            continue;
        t0 = count ? t0 : t;
        assert_true(now_us() - start + 2000 >= t - t0); /* never before its time */
        assert_true(t >= last_t);
        last_t = t;
        count++;
    }
    sim_replay_realtime_transport.close(h);
    assert_int_equal(count, (int)r->n - 1);
    assert_true(now_us() - start + 2000 >= span - r->ev[1].t_us);
    assert_int_equal(sim_replay_open_rec(r, NULL, &h), 0);
    count = 0;
    while ((n = sim_replay_transport.read(h, buf, sizeof buf, 0, &t)) > 0)
        count++;
    assert_int_equal(count, (int)r->n - 1);
    sim_replay_transport.close(h);
    fnrec_free(r);
}

/* The in-process virtual transport plays a script at the cadence, through the registry. */
static void test_virtual_transport(void **st)
{
    char *dir = tu_tmpdir("virt");
    char path[512], spec[600];
    snprintf(path, sizeof path, "%s/s.script", dir);
    const char *text = "translate +x 5 mm over 0.1 s\n";
    tu_write_file(path, text, strlen(text));
    assert_int_equal(sim_register_transports(), 0);
    assert_int_equal(sim_register_transports(), 0);
    const dev_transport *t = dev_transport_find("virtual");
    assert_non_null(t);
    snprintf(spec, sizeof spec, "spacemouse-wireless:script=%s", path);
    dev_handle *h;
    assert_int_equal(t->open(spec, &h), 0);
    dev_info info;
    assert_int_equal(t->info(h, &info), 0);
    assert_int_equal(info.pid, 0xc62e);
    assert_true(info.desc_len > 0);
    uint8_t buf[64];
    int64_t tt;
    int n, count = 0;
    while ((n = t->read(h, buf, sizeof buf, 200, &tt)) > 0) {
        assert_int_equal(n, buf[0] == 0x17 ? 2 : 13);
        count += buf[0] == 1;
    }
    assert_int_equal(n, 0); /* silent after the script, still plugged in */
    /* Six periods of motion (the first one carries the battery report), then the zeros. */
    assert_int_equal(count, 100000 / 16000 - 1 + SIMDEV_ZERO_REPEATS);
    assert_int_equal(t->write(h, (const uint8_t[]){4, 1}, 2), 2);
    t->close(h);
    assert_true(t->open("no-such-device", &h) < 0);
    assert_non_null(strstr(fn_err_msg(), "no-such-device"));
    tu_rmtree(dir);
    free(dir);
}

/* The shipped recordings are labelled virtual and are exactly what their scripts render to. */
static void test_shipped_recordings(void **st)
{
    const char *names[] = {"head-on", "grazing-slide", "buttons", "demo-approach"};
    const char *src = tu_src();
    for (size_t i = 0; i < sizeof names / sizeof *names; i++) {
        char path[1024], spath[1024], id[16];
        snprintf(path, sizeof path, "%s/sim/recordings/%s.fnrec", src, names[i]);
        snprintf(spath, sizeof spath, "%s/sim/recordings/%s.script", src, names[i]);
        fnrec *r = fnrec_load(path);
        if (!r)
            fail_msg("%s", fn_err_msg());
        assert_int_equal(strncmp(r->hdr.source, "virtual:", 8), 0);
        assert_non_null(strstr(r->hdr.source, "simulated"));
        snprintf(id, sizeof id, "%04x:%04x", r->hdr.vid, r->hdr.pid);
        script *s = script_load(spath);
        assert_non_null(s);
        fnrec *again = script_render(s, sim_profile_find(id));
        assert_non_null(again);
        assert_int_equal(again->n, r->n);
        assert_memory_equal(again->ev, r->ev, r->n * sizeof *r->ev);
        fnrec_free(again);
        fnrec_free(r);
        free(s);
    }
}

static size_t inputs_equal(const fnrec *a, const fnrec *b)
{
    size_t i = 0, j = 0, same = 0;
    for (;; i++, j++) {
        while (i < a->n && a->ev[i].dir != FNREC_IN)
            i++;
        while (j < b->n && b->ev[j].dir != FNREC_IN)
            j++;
        if (i == a->n || j == b->n)
            return i == a->n && j == b->n ? same : (size_t)-1;
        if (a->ev[i].len != b->ev[j].len || memcmp(a->ev[i].data, b->ev[j].data, a->ev[i].len))
            return (size_t)-1;
        same++;
    }
}

/* Whether the recording being written at path holds n input reports. */
typedef struct recorded_ins {
    const char *path;
    size_t n;
} recorded_ins;

static int holds_ins(void *arg)
{
    const recorded_ins *w = arg;
    char *text = tu_slurp(w->path, NULL);
    size_t n = 0;
    for (const char *p = text; p && (p = strstr(p, " in ")) && strchr(p, '\n'); p++)
        n++; /* whole lines only */
    free(text);
    return n >= w->n;
}

/* fracnav record works on the in-process transports too: the virtual device (for machines without
 * FUSE) and a replay, which gives back the recording's reports and timestamps. */
static void test_record_cli_virtual_and_replay(void **st)
{
    char *dir = tu_tmpdir("reccli");
    char scr[512], rec[512], rec2[512], *out = NULL;
    snprintf(scr, sizeof scr, "%s/s.script", dir);
    snprintf(rec, sizeof rec, "%s/v.fnrec", dir);
    snprintf(rec2, sizeof rec2, "%s/r.fnrec", dir);
    const char *text = "translate -y 3 mm over 0.15 s\npress 1\nrelease\n";
    tu_write_file(scr, text, strlen(text));
    /* Recorded until Ctrl-C, once every report the script renders to is in. */
    fnrec *want = render(text, "spacenavigator");
    char spec[600];
    snprintf(spec, sizeof spec, "virtual:spacenavigator:script=%s", scr);
    pid_t pid = tu_spawn_cli(NULL, NULL, (char *[]){"record", "-o", (char *)rec, "--device", spec, "--seconds", "600",
                                                    NULL});
    recorded_ins all = {rec, 0};
    for (size_t i = 0; i < want->n; i++)
        all.n += want->ev[i].dir == FNREC_IN;
    int complete = tu_wait_for(holds_ins, &all, TU_WAIT_MAX_S);
    int status = tu_end(pid, SIGINT, "record after Ctrl-C");
    assert_true(complete);
    assert_int_equal(status, 0);
    int rc;
    fnrec *got = fnrec_load(rec);
    assert_non_null(got);
    assert_true(inputs_equal(want, got) > 20 && inputs_equal(want, got) != (size_t)-1);
    assert_int_equal(got->hdr.pid, 0xc626);
    assert_non_null(strstr(got->hdr.source, "virtual:"));
    rc = tu_run_cli(&out, "record -o '%s' --device 'replay:%s'", rec2, rec);
    if (rc)
        fail_msg("%s", out);
    free(out);
    fnrec *again = fnrec_load(rec2);
    assert_non_null(again);
    assert_true(inputs_equal(got, again) != (size_t)-1);
    for (size_t i = 1; i < again->n; i++) /* recorded times come back as they were */
        assert_int_equal(again->ev[i].t_us, got->ev[i].t_us);
    fnrec_free(again);
    fnrec_free(got);
    fnrec_free(want);
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_fnrec_round_trip),
        cmocka_unit_test(test_fnrec_truncated_loses_last_line_only),
        cmocka_unit_test(test_fnrec_malformed),
        cmocka_unit_test(test_fnrec_limits),
        cmocka_unit_test(test_script_split_cadence_and_release),
        cmocka_unit_test(test_script_combined_and_buttons),
        cmocka_unit_test(test_script_enterprise_keycodes),
        cmocka_unit_test(test_script_errors),
        cmocka_unit_test(test_every_devtab_row_is_impersonable),
        cmocka_unit_test(test_open_controller_descriptor_is_the_spec),
        cmocka_unit_test(test_led_and_features),
        cmocka_unit_test(test_open_controller_settings),
        cmocka_unit_test(test_replay_deterministic),
        cmocka_unit_test(test_replay_realtime_pacing),
        cmocka_unit_test(test_virtual_transport),
        cmocka_unit_test(test_shipped_recordings),
        cmocka_unit_test(test_record_cli_virtual_and_replay),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
