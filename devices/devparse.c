#include "devparse.h"

#include <string.h>

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

static int buttons(devparse_state *st, const uint8_t *buf, size_t len, int64_t t_us, dev_event *ev)
{
    uint32_t raw = 0;
    for (size_t i = 1; i < len && i <= 4; i++)
        raw |= (uint32_t)buf[i] << 8 * (i - 1);
    uint32_t now = st->row ? pack_bits(raw, st->row->button_mask) : raw, old = st->buttons;
    st->buttons = now;
    fill_event(st, t_us, ev);
    ev->flags = DEV_EV_BUTTON;
    ev->pressed = now & ~old;
    ev->released = old & ~now;
    return 1;
}

static int keys(devparse_state *st, const uint8_t *buf, size_t len, int64_t t_us, dev_event *ev)
{
    memset(st->keys, 0, sizeof st->keys);
    for (size_t i = 0; i < (len - 1) / 2; i++)
        st->keys[i] = (uint16_t)le16(buf + 1 + 2 * i);
    fill_event(st, t_us, ev);
    ev->flags = DEV_EV_BUTTON;
    return 1;
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
