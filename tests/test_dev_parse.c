/* The report parser and the device table: every row parsed from a synthetic report of its format,
 * format chosen by length, bad reports counted and skipped. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <string.h>

#include "devparse.h"
#include "devtab.h"
#include "loop.h"

static int near(float a, float b)
{
    return fabsf(a - b) < 1e-5f;
}

/* Sends the motion of a row's format; expects the axes normalized by 350 and clamped. */
static void motion_for_row(const devtab_row *row)
{
    devparse_state st;
    devparse_init(&st, row, 0);
    dev_event ev;
    uint8_t buf[16];
    int t[3] = {175, -350, 700}, r[3] = {-70, 35, 0}, all[6] = {175, -350, 700, -70, 35, 0};
    if (row->format == DEVTAB_COMBINED) {
        assert_int_equal(devparse_report(&st, buf, devparse_make_combined(buf, all), 1000, &ev), 1);
    } else {
        assert_int_equal(devparse_report(&st, buf, devparse_make_split(buf, 1, t), 1000, &ev), 1);
        assert_true(near(ev.axis[0], 0.5f) && near(ev.axis[3], 0.0f));
        assert_int_equal(devparse_report(&st, buf, devparse_make_split(buf, 2, r), 9000, &ev), 1);
        assert_int_equal(ev.dt_us, 8000);
    }
    const float want[6] = {0.5f, -1.0f, 1.0f, -0.2f, 0.1f, 0.0f}; /* 700 clamps to 1 */
    for (int i = 0; i < 6; i++)
        assert_true(near(ev.axis[i], want[i]));
    assert_true(ev.flags & DEV_EV_MOTION);
}

/* Presses the row's last real button (raw bit = highest bit of the mask): packed to nbuttons-1. */
static void buttons_for_row(const devtab_row *row)
{
    devparse_state st;
    devparse_init(&st, row, 0);
    int top = 31;
    while (!(row->button_mask >> top & 1))
        top--;
    uint8_t buf[8];
    dev_event ev;
    assert_int_equal(devparse_report(&st, buf, devparse_make_buttons(buf, 1u << top), 5, &ev), 1);
    assert_int_equal(ev.buttons, 1u << (row->nbuttons - 1));
    assert_int_equal(ev.pressed, ev.buttons);
    assert_int_equal(devparse_report(&st, buf, devparse_make_buttons(buf, 0), 6, &ev), 1);
    assert_int_equal(ev.buttons, 0);
    assert_int_equal(ev.released, 1u << (row->nbuttons - 1));
}

static void test_every_row(void **s)
{
    size_t n;
    const devtab_row *rows = devtab_rows(&n);
    assert_true(n >= 23);
    for (size_t i = 0; i < n; i++) {
        assert_non_null(rows[i].name);
        assert_int_equal(__builtin_popcount(rows[i].button_mask), rows[i].nbuttons);
        motion_for_row(&rows[i]);
        buttons_for_row(&rows[i]);
        if (!(rows[i].flags & DEVTAB_F_SYNTH))
            assert_ptr_equal(devtab_find(rows[i].vid, rows[i].pid), &rows[i]);
    }
}

static void test_every_devices_md_id(void **s)
{
    static const uint16_t ids[][2] = {
        {0x046d, 0xc626}, {0x046d, 0xc628}, {0x046d, 0xc627}, {0x046d, 0xc625}, {0x046d, 0xc629},
        {0x046d, 0xc62b}, {0x046d, 0xc603}, {0x046d, 0xc605}, {0x046d, 0xc606}, {0x046d, 0xc621},
        {0x046d, 0xc623}, {0x046d, 0xc640}, {0x256f, 0xc62e}, {0x256f, 0xc62f}, {0x256f, 0xc631},
        {0x256f, 0xc632}, {0x256f, 0xc633}, {0x256f, 0xc635}, {0x256f, 0xc638}, {0x256f, 0xc63a},
        {0x256f, 0xc652}, {DEVTAB_OPEN_VID, DEVTAB_OPEN_PID}};
    for (size_t i = 0; i < sizeof ids / sizeof ids[0]; i++)
        assert_non_null(devtab_find(ids[i][0], ids[i][1]));
    static const uint16_t not6dof[] = {0xc650, 0xc651, 0xc654, 0xc655, 0xc656, 0xc657, 0xc658, 0xc664, 0xc668, 0xc665,
                                           0xc62c, 0xc641};
    for (size_t i = 0; i < sizeof not6dof / sizeof not6dof[0]; i++)
        assert_null(devtab_find(0x256f, not6dof[i]));
    assert_int_equal(devtab_find(0x046d, 0xc62b)->nbuttons, 15);
    assert_int_equal(devtab_find(0x256f, 0xc635)->format, DEVTAB_SPLIT); /* 256f with the old format */
}

/* A split-format row that receives a 13-byte report decodes it as combined: length decides. */
static void test_length_not_vendor(void **s)
{
    devparse_state st;
    devparse_init(&st, devtab_find(0x046d, 0xc626), 0);
    uint8_t buf[16];
    int v[6] = {0, 0, 0, 0, 0, 350};
    dev_event ev;
    assert_int_equal(devparse_report(&st, buf, devparse_make_combined(buf, v), 1, &ev), 1);
    assert_true(near(ev.axis[5], 1.0f));
    devparse_init(&st, devtab_find(0x256f, 0xc62e), 0);
    int t[3] = {35, 0, 0};
    assert_int_equal(devparse_report(&st, buf, devparse_make_split(buf, 1, t), 1, &ev), 1);
    assert_true(near(ev.axis[0], 0.1f));
}

static void test_split_keeps_last_of_each(void **s)
{
    devparse_state st;
    devparse_init(&st, NULL, 0);
    uint8_t buf[8];
    dev_event ev;
    int t[3] = {35, 70, 105}, r[3] = {-35, -70, -105}, t2[3] = {0, 0, 350};
    devparse_report(&st, buf, devparse_make_split(buf, 1, t), 0, &ev);
    devparse_report(&st, buf, devparse_make_split(buf, 2, r), 8000, &ev);
    devparse_report(&st, buf, devparse_make_split(buf, 1, t2), 16000, &ev);
    const float want[6] = {0, 0, 1, -0.1f, -0.2f, -0.3f};
    for (int i = 0; i < 6; i++)
        assert_true(near(ev.axis[i], want[i]));
}

static void test_bad_reports_counted(void **s)
{
    devparse_state st;
    devparse_init(&st, devtab_find(0x046d, 0xc626), 0);
    dev_event ev;
    const uint8_t id9[] = {9, 1, 2, 3}, short1[] = {1, 0, 0, 0}, long2[] = {2, 0, 0, 0, 0, 0, 0, 0},
                  bat_bad[] = {0x17, 101}, keys_even[] = {0x1C, 1, 0, 2}, one[] = {3};
    assert_int_equal(devparse_report(&st, id9, sizeof id9, 0, &ev), 0);
    assert_int_equal(devparse_report(&st, short1, sizeof short1, 0, &ev), 0);
    assert_int_equal(devparse_report(&st, long2, sizeof long2, 0, &ev), 0);
    assert_int_equal(devparse_report(&st, bat_bad, sizeof bat_bad, 0, &ev), 0);
    assert_int_equal(devparse_report(&st, keys_even, sizeof keys_even, 0, &ev), 0);
    assert_int_equal(devparse_report(&st, one, sizeof one, 0, &ev), 0);
    assert_int_equal(devparse_report(&st, NULL, 0, 0, &ev), 0);
    assert_int_equal(st.n_unknown_id, 2);
    assert_int_equal(st.n_bad_len, 5);
    assert_int_equal(st.n_ok, 0);
    for (int i = 0; i < 6; i++)
        assert_int_equal(st.raw[i], 0);
}

static void test_battery_and_keys(void **s)
{
    devparse_state st;
    devparse_init(&st, devtab_find(0x256f, 0xc633), 0);
    dev_event ev;
    const uint8_t bat[] = {0x17, 87}, keys[] = {0x1C, 29, 0, 13, 0, 0, 0};
    assert_int_equal(devparse_report(&st, bat, sizeof bat, 0, &ev), 1);
    assert_int_equal(ev.battery, 87);
    assert_int_equal(ev.flags, DEV_EV_BATTERY);
    assert_int_equal(devparse_report(&st, keys, sizeof keys, 1, &ev), 1);
    assert_int_equal(ev.keys[0], 29);
    assert_int_equal(ev.keys[1], 13);
    assert_int_equal(ev.keys[2], 0);
    assert_int_equal(ev.battery, 87);
}

/* Enterprise keys that exist only in report 0x1C are buttons (table data): ENTER, V3, SPACE press
 * and release like any button, alongside report 3's bits; other devices keep codes as codes. */
static void test_enterprise_keys_are_buttons(void **s)
{
    devparse_state st;
    devparse_init(&st, devtab_find(0x256f, 0xc633), 0);
    dev_event ev;
    int enter = devtab_key_button(36), v3 = devtab_key_button(105), space = devtab_key_button(176);
    assert_true(enter >= 0 && v3 >= 0 && space >= 0);
    assert_true(enter != v3 && v3 != space && enter != space);
    const uint8_t id3[] = {3, 1, 0, 0, 0}, down[] = {0x1C, 36, 0, 105, 0, 176, 0}, up[] = {0x1C, 105, 0};
    assert_int_equal(devparse_report(&st, id3, sizeof id3, 0, &ev), 1);
    assert_int_equal(devparse_report(&st, down, sizeof down, 1, &ev), 1);
    assert_int_equal(ev.pressed, 1u << enter | 1u << v3 | 1u << space);
    assert_int_equal(ev.buttons, 1u | 1u << enter | 1u << v3 | 1u << space);
    assert_int_equal(devparse_report(&st, up, sizeof up, 2, &ev), 1);
    assert_int_equal(ev.released, 1u << enter | 1u << space);
    assert_int_equal(ev.buttons, 1u | 1u << v3);
    /* Every key code of the table has its own button within the row's 31. */
    size_t n;
    const devtab_key *k = devtab_keys(&n);
    uint32_t seen = 0;
    for (size_t i = 0; i < n; i++) {
        assert_true(k[i].button < devtab_find(0x256f, 0xc633)->nbuttons);
        assert_false(seen >> k[i].button & 1);
        seen |= 1u << k[i].button;
    }
    devparse_init(&st, devtab_find(0x256f, 0xc62e), 0); /* SpaceMouse Wireless: codes only */
    assert_int_equal(devparse_report(&st, down, sizeof down, 1, &ev), 1);
    assert_int_equal(ev.buttons, 0);
    assert_int_equal(ev.keys[0], 36);
}

/* The SpaceMouse Pro reports 15 buttons on sparse bits: bit 12 is its 7th button. */
static void test_sparse_buttons(void **s)
{
    devparse_state st;
    devparse_init(&st, devtab_find(0x046d, 0xc62b), 0);
    uint8_t buf[8];
    dev_event ev;
    devparse_report(&st, buf, devparse_make_buttons(buf, 1u << 12 | 1u << 3), 0, &ev);
    assert_int_equal(ev.buttons, 1u << 6); /* bit 3 is not a button of this device */
}

/* One pause clamp: after a pause an event's dt_us is what the loop integrates a report over. */
static void test_one_pause_clamp(void **s)
{
    devparse_state st;
    devparse_init(&st, NULL, 0);
    uint8_t buf[16];
    int v[6] = {35, 0, 0, 0, 0, 0};
    dev_event ev;
    devparse_report(&st, buf, devparse_make_combined(buf, v), 0, &ev);
    devparse_report(&st, buf, devparse_make_combined(buf, v), 5000000, &ev); /* 5 s pause */
    loop_config c;
    loop_config_default(&c);
    assert_int_equal(ev.dt_us, c.dt_max_us);
}

static void test_merge_and_dt_clamp(void **s)
{
    devparse_state st;
    devparse_init(&st, NULL, 0);
    uint8_t buf[16];
    int v[6] = {35, 0, 0, 0, 0, 0}, w[6] = {70, 0, 0, 0, 0, 0};
    dev_event a, b;
    devparse_report(&st, buf, devparse_make_combined(buf, v), 0, &a);
    devparse_report(&st, buf, devparse_make_combined(buf, w), 5000000, &b); /* 5 s pause */
    assert_int_equal(b.dt_us, DEV_DT_MAX_US);
    devparse_report(&st, buf, devparse_make_buttons(buf, 1), 5000001, &b);
    devparse_merge(&a, &b);
    assert_true(near(a.axis[0], 0.2f));
    assert_int_equal(a.flags, DEV_EV_MOTION | DEV_EV_BUTTON);
    assert_int_equal(a.pressed, 1);
}

static void test_descriptor_axis_max(void **s)
{
    devparse_state st;
    devparse_init(&st, NULL, 2047); /* a 12-bit controller's descriptor */
    uint8_t buf[16];
    int v[6] = {2047, -1023, 0, 0, 0, 0};
    dev_event ev;
    devparse_report(&st, buf, devparse_make_combined(buf, v), 0, &ev);
    assert_true(near(ev.axis[0], 1.0f) && fabsf(ev.axis[1] + 0.5f) < 1e-3f);
}

static void test_open_features(void **s)
{
    uint8_t buf[16];
    devparse_open_info info = {1, 0, 3, 8, 350}, back;
    assert_int_equal(devparse_open_info_make(buf, &info), 7);
    assert_int_equal(devparse_open_info_parse(buf, 7, &back), 0);
    assert_int_equal(back.axis_max, 350);
    assert_int_equal(back.cadence_ms, 8);
    assert_true(devparse_open_info_parse(buf, 6, &back) < 0);
    int16_t z[6] = {3, -2, 1, 0, 0, -5}, zb[6];
    assert_int_equal(devparse_open_zero_make(buf, z), 13);
    assert_int_equal(devparse_open_zero_parse(buf, 13, zb), 0);
    assert_memory_equal(z, zb, sizeof z);
    buf[1] = 0xff, buf[2] = 0x7f; /* 32767: out of range */
    assert_true(devparse_open_zero_parse(buf, 13, zb) < 0);
    devparse_open_settings set = {8, 3, 0}, sb;
    devparse_open_settings_make(buf, &set);
    assert_int_equal(devparse_open_settings_parse(buf, 4, &sb), 0);
    assert_int_equal(sb.idle_zeros, 3);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_every_row),           cmocka_unit_test(test_every_devices_md_id),
        cmocka_unit_test(test_length_not_vendor),   cmocka_unit_test(test_split_keeps_last_of_each),
        cmocka_unit_test(test_bad_reports_counted), cmocka_unit_test(test_battery_and_keys),
        cmocka_unit_test(test_enterprise_keys_are_buttons),
        cmocka_unit_test(test_sparse_buttons),      cmocka_unit_test(test_merge_and_dt_clamp),
        cmocka_unit_test(test_one_pause_clamp),
        cmocka_unit_test(test_descriptor_axis_max), cmocka_unit_test(test_open_features),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
