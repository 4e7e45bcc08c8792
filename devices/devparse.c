#include "devparse.h"

#include <string.h>

#include "err.h"

enum { ID_MOTION = 1, ID_ROTATION = 2, ID_BUTTONS = 3, ID_BATTERY = 0x17, ID_KEYS = 0x1C };

void devparse_init(devparse_state *st, const devtab_row *row, int axis_max)
{
    memset(st, 0, sizeof *st);
    st->row = row;
    st->axis_max = axis_max > 0 ? axis_max : row && row->axis_max > 0 ? row->axis_max : 350;
    st->battery = -1;
    st->last_motion_us = -1;
}

static int16_t le16(const uint8_t *p)
{
    return (int16_t)(uint16_t)(p[0] | p[1] << 8);
}

/* Packs the bits of raw selected by mask into consecutive low bits (SpaceMouse Pro's sparse map). */
static uint32_t pack_bits(uint32_t raw, uint32_t mask)
{
    uint32_t out = 0;
    int k = 0;
    for (int i = 0; i < 32; i++)
        if (mask >> i & 1)
            out |= (raw >> i & 1u) << k++;
    return out;
}

static void fill_event(const devparse_state *st, int64_t t_us, dev_event *ev)
{
    memset(ev, 0, sizeof *ev);
    ev->t_us = t_us;
    for (int i = 0; i < 6; i++) {
        float v = (float)st->raw[i] / (float)st->axis_max;
        ev->axis[i] = v > 1.0f ? 1.0f : v < -1.0f ? -1.0f : v;
    }
    ev->buttons = st->buttons;
    memcpy(ev->keys, st->keys, sizeof ev->keys);
    ev->battery = st->battery;
}

static void set_axes(devparse_state *st, int first, int n, const uint8_t *p)
{
    uint8_t inv = st->row ? st->row->axis_invert : 0;
    for (int i = first; i < first + n; i++, p += 2) {
        int v = le16(p);
        st->raw[i] = (int16_t)(inv >> i & 1 ? (v == -32768 ? 32767 : -v) : v);
    }
}

static int motion(devparse_state *st, const uint8_t *buf, size_t len, int64_t t_us, dev_event *ev)
{
    if (buf[0] == ID_MOTION && len == 13)
        set_axes(st, 0, 6, buf + 1);
    else if (buf[0] == ID_MOTION && len == 7)
        set_axes(st, 0, 3, buf + 1);
    else if (buf[0] == ID_ROTATION && len == 7)
        set_axes(st, 3, 3, buf + 1);
    else
        return 0;
    int64_t dt = st->last_motion_us < 0 ? 0 : t_us - st->last_motion_us;
    st->last_motion_us = t_us;
    fill_event(st, t_us, ev);
    ev->flags = DEV_EV_MOTION;
    ev->dt_us = dt < 0 ? 0 : dt > DEV_DT_MAX_US ? DEV_DT_MAX_US : dt;
    return 1;
}

/* Sets the button state from its two sources and writes the event with the edges. */
static int button_event(devparse_state *st, int64_t t_us, dev_event *ev)
{
    uint32_t now = st->id3_buttons | st->key_buttons, old = st->buttons;
    st->buttons = now;
    fill_event(st, t_us, ev);
    ev->flags = DEV_EV_BUTTON;
    ev->pressed = now & ~old;
    ev->released = old & ~now;
    return 1;
}

static int buttons(devparse_state *st, const uint8_t *buf, size_t len, int64_t t_us, dev_event *ev)
{
    uint32_t raw = 0;
    for (size_t i = 1; i < len && i <= 4; i++)
        raw |= (uint32_t)buf[i] << 8 * (i - 1);
    st->id3_buttons = st->row ? pack_bits(raw, st->row->button_mask) : raw;
    return button_event(st, t_us, ev);
}

static int keys(devparse_state *st, const uint8_t *buf, size_t len, int64_t t_us, dev_event *ev)
{
    int as_buttons = st->row && (st->row->flags & DEVTAB_F_KEYCODES);
    memset(st->keys, 0, sizeof st->keys);
    st->key_buttons = 0;
    for (size_t i = 0; i < (len - 1) / 2; i++) {
        st->keys[i] = (uint16_t)le16(buf + 1 + 2 * i);
        int b = as_buttons ? devtab_key_button(st->keys[i]) : -1;
        if (b >= 0)
            st->key_buttons |= 1u << b;
    }
    return button_event(st, t_us, ev);
}

int devparse_report(devparse_state *st, const uint8_t *buf, size_t len, int64_t t_us, dev_event *ev)
{
    int ok = 0, known = 1;
    if (!buf || len < 1)
        known = 0;
    else if (buf[0] == ID_MOTION || buf[0] == ID_ROTATION)
        ok = motion(st, buf, len, t_us, ev);
    else if (buf[0] == ID_BUTTONS)
        ok = len >= 2 && len <= 13 ? buttons(st, buf, len, t_us, ev) : 0;
    else if (buf[0] == ID_KEYS)
        ok = len >= 3 && len <= 13 && len % 2 == 1 ? keys(st, buf, len, t_us, ev) : 0;
    else if (buf[0] == ID_BATTERY && len == 2 && buf[1] <= 100) {
        st->battery = buf[1];
        fill_event(st, t_us, ev);
        ev->flags = DEV_EV_BATTERY;
        ok = 1;
    } else
        known = buf[0] == ID_BATTERY;
    if (ok)
        st->n_ok++;
    else if (known)
        st->n_bad_len++;
    else
        st->n_unknown_id++;
    return ok;
}

void devparse_merge(dev_event *a, const dev_event *b)
{
    unsigned flags = a->flags | b->flags;
    uint32_t pressed = a->pressed | b->pressed, released = a->released | b->released;
    int64_t dt = a->dt_us + b->dt_us;
    *a = *b;
    a->flags = flags;
    a->pressed = pressed;
    a->released = released;
    a->dt_us = dt > DEV_DT_MAX_US ? DEV_DT_MAX_US : dt;
}

static void put16(uint8_t *p, int v)
{
    v = v > 32767 ? 32767 : v < -32768 ? -32768 : v;
    p[0] = (uint8_t)(v & 0xff);
    p[1] = (uint8_t)((unsigned)v >> 8 & 0xff);
}

size_t devparse_make_combined(uint8_t *buf, const int v[6])
{
    buf[0] = ID_MOTION;
    for (int i = 0; i < 6; i++)
        put16(buf + 1 + 2 * i, v[i]);
    return 13;
}

size_t devparse_make_split(uint8_t *buf, int id, const int v[3])
{
    buf[0] = (uint8_t)id;
    for (int i = 0; i < 3; i++)
        put16(buf + 1 + 2 * i, v[i]);
    return 7;
}

size_t devparse_make_buttons(uint8_t *buf, uint32_t bits)
{
    buf[0] = ID_BUTTONS;
    for (int i = 0; i < 4; i++)
        buf[1 + i] = (uint8_t)(bits >> 8 * i);
    return 5;
}

size_t devparse_reports(const devtab_row *row, devparse_spec *out, size_t cap)
{
    devparse_spec all[12];
    size_t n = 0;
    if (row->format == DEVTAB_COMBINED)
        all[n++] = (devparse_spec){0, ID_MOTION, 13};
    else {
        all[n++] = (devparse_spec){0, ID_MOTION, 7};
        all[n++] = (devparse_spec){0, ID_ROTATION, 7};
    }
    if (row->nbuttons) {
        int top = 0; /* highest raw bit used, for the report length */
        for (int i = 0; i < 32; i++)
            if (row->button_mask >> i & 1)
                top = i + 1;
        all[n++] = (devparse_spec){0, ID_BUTTONS, 1 + (size_t)(top + 7) / 8};
    }
    if (row->flags & DEVTAB_F_BATTERY)
        all[n++] = (devparse_spec){0, ID_BATTERY, 2};
    if (row->flags & DEVTAB_F_KEYCODES)
        all[n++] = (devparse_spec){0, ID_KEYS, 13};
    if (row->flags & DEVTAB_F_LED)
        all[n++] = (devparse_spec){1, 4, 2};
    if (row->flags & DEVTAB_F_OPEN) {
        all[n++] = (devparse_spec){2, DEVPARSE_FEAT_INFO, 7};
        all[n++] = (devparse_spec){2, DEVPARSE_FEAT_ZERO, 13};
        all[n++] = (devparse_spec){2, DEVPARSE_FEAT_SETTINGS, 4};
    }
    for (size_t i = 0; i < n && i < cap; i++)
        out[i] = all[i];
    return n;
}

static int feature_check(const uint8_t *buf, size_t len, uint8_t id, size_t want)
{
    if (len != want || buf[0] != id)
        return fn_err_set(FN_EFORMAT, "feature report 0x%02x: expected %zu bytes with ID 0x%02x, got %zu bytes "
                          "with ID 0x%02x", id, want, id, len, len ? buf[0] : 0);
    return 0;
}

int devparse_open_info_parse(const uint8_t *buf, size_t len, devparse_open_info *out)
{
    if (feature_check(buf, len, DEVPARSE_FEAT_INFO, 7))
        return FN_EFORMAT;
    *out = (devparse_open_info){buf[1], buf[2], buf[3], buf[4], le16(buf + 5)};
    if (out->protocol != 1 || out->cadence_ms == 0 || out->axis_max <= 0)
        return fn_err_set(FN_EFORMAT, "feature report 0x20: protocol %u (want 1), cadence %u ms, axis max %d: "
                          "not a valid open controller", out->protocol, out->cadence_ms, out->axis_max);
    return 0;
}

size_t devparse_open_info_make(uint8_t *buf, const devparse_open_info *in)
{
    buf[0] = DEVPARSE_FEAT_INFO;
    buf[1] = in->protocol, buf[2] = in->fw_major, buf[3] = in->fw_minor, buf[4] = in->cadence_ms;
    put16(buf + 5, in->axis_max);
    return 7;
}

int devparse_open_zero_parse(const uint8_t *buf, size_t len, int16_t zero[6])
{
    if (feature_check(buf, len, DEVPARSE_FEAT_ZERO, 13))
        return FN_EFORMAT;
    for (int i = 0; i < 6; i++) {
        zero[i] = le16(buf + 1 + 2 * i);
        if (zero[i] < -350 || zero[i] > 350)
            return fn_err_set(FN_EFORMAT, "feature report 0x21: zero offset of axis %d is %d (outside -350..350, "
                              "offset %d)", i, zero[i], 1 + 2 * i);
    }
    return 0;
}

size_t devparse_open_zero_make(uint8_t *buf, const int16_t zero[6])
{
    buf[0] = DEVPARSE_FEAT_ZERO;
    for (int i = 0; i < 6; i++)
        put16(buf + 1 + 2 * i, zero[i] < -350 ? -350 : zero[i] > 350 ? 350 : zero[i]);
    return 13;
}

int devparse_open_settings_parse(const uint8_t *buf, size_t len, devparse_open_settings *out)
{
    if (feature_check(buf, len, DEVPARSE_FEAT_SETTINGS, 4))
        return FN_EFORMAT;
    *out = (devparse_open_settings){buf[1], buf[2], buf[3]};
    if (out->cadence_ms == 0 || out->led_mode > 1)
        return fn_err_set(FN_EFORMAT, "feature report 0x22: cadence %u ms (offset 1) or LED mode %u (offset 3) "
                          "out of range", out->cadence_ms, out->led_mode);
    return 0;
}

size_t devparse_open_settings_make(uint8_t *buf, const devparse_open_settings *in)
{
    buf[0] = DEVPARSE_FEAT_SETTINGS;
    buf[1] = in->cadence_ms, buf[2] = in->idle_zeros, buf[3] = in->led_mode;
    return 4;
}
