/* Transports say what they are: capabilities, help key and state line in the transport table, so
 * no caller tests a transport's name; the replay and the virtual device are two function sets. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dev.h"
#include "err.h"
#include "sim_replay.h"
#include "testutil.h"

static int setup(void **st)
{
    (void)st;
    return sim_register_transports();
}

/* Only the keyboard reads the terminal and has a help key; only the replays are recordings. */
static void test_caps_by_transport(void **st)
{
    (void)st;
    int terminals = 0, recordings = 0;
    for (size_t i = 0; dev_transport_at(i); i++) {
        const dev_transport *t = dev_transport_at(i);
        int is_keyboard = !strcmp(t->name, "keyboard");
        int is_replay = !strcmp(t->name, "replay") || !strcmp(t->name, "replay-realtime");
        assert_int_equal(!!(t->caps & DEV_CAP_TERMINAL), is_keyboard);
        assert_int_equal(!!(t->caps & DEV_CAP_RECORDING), is_replay);
        assert_int_equal(t->help_button, is_keyboard ? 11 : 0);
        if (t->caps & DEV_CAP_RECORDING)
            assert_non_null(t->finished);
        terminals += is_keyboard;
        recordings += is_replay;
    }
    assert_int_equal(terminals, 1);
    assert_int_equal(recordings, 2);
    assert_non_null(dev_transport_find("virtual")->finished);
}

/* A transport that makes its own reports says which synthetic row they follow; the row is data,
 * not the transport's name. */
static void test_synthetic_rows(void **st)
{
    (void)st;
    const char *names[] = {"spnav", "keyboard"};
    for (size_t i = 0; i < 2; i++) {
        const dev_transport *t = dev_transport_find(names[i]);
        assert_non_null(t->synthetic_row);
        const devtab_row *row = devtab_synthetic(t->synthetic_row);
        assert_non_null(row);
        assert_true(row->flags & DEVTAB_F_SYNTH);
    }
    assert_null(dev_transport_find("replay")->synthetic_row);
}

/* Every backend describes itself; one without describe gets a line from what it offers. */
static void test_describe(void **st)
{
    (void)st;
    char buf[320];
    for (size_t i = 0; dev_transport_at(i); i++) {
        const dev_transport *t = dev_transport_at(i);
        assert_non_null(t->describe);
        buf[0] = '\0';
        assert_ptr_equal(dev_transport_describe(t, buf, sizeof buf), buf);
        assert_true(strlen(buf) > 0);
    }
    dev_transport_describe(dev_transport_find("keyboard"), buf, sizeof buf);
    assert_string_equal(buf, "fallback on a terminal (--device keyboard)");
    dev_transport_describe(dev_transport_find("replay"), buf, sizeof buf);
    assert_string_equal(buf, "opened by name (--device)");
    dev_transport bare = {.name = "bare"};
    assert_string_equal(dev_transport_describe(&bare, buf, sizeof buf), "opened by name (--device)");
}

/* "replay" with no file names what it needs instead of opening a null path. */
static void test_replay_needs_file(void **st)
{
    (void)st;
    const char *names[] = {"replay", "replay-realtime"};
    for (size_t i = 0; i < 2; i++) {
        dev_handle *h = (dev_handle *)1;
        assert_int_equal(dev_transport_find(names[i])->open(NULL, &h), FN_EINVAL);
        assert_null(h);
        assert_non_null(strstr(fn_err_msg(), ":FILE.fnrec"));
    }
    assert_null(dev_open("replay"));
    assert_non_null(strstr(fn_err_msg(), "replay:FILE.fnrec"));
}

/* The same recording through both function sets: the replay keeps the recorded times and ends at
 * the recording's end; the virtual device stamps arrival and stays plugged in, silent. */
static void test_two_function_sets(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("caps");
    char rec[512], spec[600];
    snprintf(rec, sizeof rec, "%s/r.fnrec", dir);
    const char *text = "fnrec 1\nvid 256f\npid c62e\nname test\nformat combined\nsource test\ndescriptor 00\nevents\n"
                       "0 connect\n0 in 010a0000000000000000000000\n";
    tu_write_file(rec, text, strlen(text));
    const dev_transport *rp = dev_transport_find("replay"), *vt = dev_transport_find("virtual");
    dev_handle *h;
    uint8_t buf[64];
    int64_t t = -1;
    if (rp->open(rec, &h))
        fail_msg("%s", fn_err_msg());
    assert_int_equal(rp->read(h, buf, sizeof buf, 0, &t), 13);
    assert_int_equal(t, 0);
    assert_true(rp->finished(h));
    assert_int_equal(rp->read(h, buf, sizeof buf, 0, &t), FN_ENODEV);
    assert_non_null(strstr(fn_err_msg(), "end of recording"));
    rp->close(h);
    snprintf(spec, sizeof spec, "spacemouse-wireless:play=%s", rec);
    if (vt->open(spec, &h))
        fail_msg("%s", fn_err_msg());
    assert_int_equal(vt->read(h, buf, sizeof buf, 0, &t), 13);
    assert_true(t > 0);
    assert_true(vt->finished(h));
    assert_int_equal(vt->read(h, buf, sizeof buf, 0, &t), 0);
    vt->close(h);
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_caps_by_transport),
        cmocka_unit_test(test_synthetic_rows),
        cmocka_unit_test(test_describe),
        cmocka_unit_test(test_replay_needs_file),
        cmocka_unit_test(test_two_function_sets),
    };
    return cmocka_run_group_tests(tests, setup, NULL);
}
