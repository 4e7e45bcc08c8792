#include "calib.h"

#include <math.h>
#include <string.h>

#include "devtab.h"

#define SENS_STEP 1.25f

void calib_default(calib *c)
{
    memset(c, 0, sizeof *c);
    c->sens = c->sens_t = c->sens_r = c->sens_base = 1.0f;
    for (int i = 0; i < 6; i++) {
        c->sens_axis[i] = 1.0f;
        c->dead[i] = 0.01f;
        c->map[i] = (int8_t)i;
    }
    c->cubic_mix = 0.7f;
    for (int i = 0; i < CALIB_BUTTONS; i++)
        c->bnmap[i] = (int8_t)i;
    c->led = 2;
}

/* Rescaling dead zone: 0 up to d, then linear to 1 at full deflection -- continuous at d. */
static float dead_zone(float v, float d)
{
    float a = fabsf(v);
    if (a <= d)
        return 0.0f;
    float r = (a - d) / (1.0f - d);
    r = r > 1.0f ? 1.0f : r;
    return v < 0 ? -r : r;
}

void calib_apply(const calib *c, const float in[6], float out[6])
{
    float x[6], y[6];
    for (int i = 0; i < 6; i++)
        x[i] = in[i] - c->zero[i];
    for (int i = 0; i < 6; i++)
        y[i] = c->map[i] >= 0 && c->map[i] < 6 ? x[c->map[i]] : 0.0f;
    if (c->swap_yz) {
        float t = y[1];
        y[1] = y[2], y[2] = t;
        t = y[4];
        y[4] = y[5], y[5] = t;
    }
    int best = -1;
    for (int i = 0; i < 6; i++) {
        float v = dead_zone(c->invert >> i & 1 ? -y[i] : y[i], c->dead[i]);
        if (c->response == CALIB_CUBIC)
            v = (1.0f - c->cubic_mix) * v + c->cubic_mix * v * v * v;
        if ((c->lock == CALIB_LOCK_TRANSLATION && i >= 3) || (c->lock == CALIB_LOCK_ROTATION && i < 3))
            v = 0.0f;
        if (v != 0.0f && (best < 0 || fabsf(v) > fabsf(y[best])))
            best = i;
        y[i] = v;
    }
    for (int i = 0; i < 6; i++) {
        float s = c->sens * (i < 3 ? c->sens_t : c->sens_r) * c->sens_axis[i];
        out[i] = c->dominant && i != best ? 0.0f : y[i] * s;
    }
}

static void toggle_lock(calib *c, calib_lock l)
{
    c->lock = c->lock == l ? CALIB_LOCK_NONE : l;
}

void calib_do(calib *c, calib_action a, const float raw[6])
{
    switch (a) {
    case CALIB_ACT_SENS_UP: c->sens *= SENS_STEP; break;
    case CALIB_ACT_SENS_DOWN: c->sens /= SENS_STEP; break;
    case CALIB_ACT_SENS_RESET: c->sens = c->sens_base; break;
    case CALIB_ACT_DISABLE_ROTATION: toggle_lock(c, CALIB_LOCK_TRANSLATION); break;
    case CALIB_ACT_DISABLE_TRANSLATION: toggle_lock(c, CALIB_LOCK_ROTATION); break;
    case CALIB_ACT_DOMINANT: c->dominant = !c->dominant; break;
    case CALIB_ACT_ZERO:
        if (raw)
            memcpy(c->zero, raw, sizeof c->zero);
        break;
    default: break;
    }
}

void calib_zero_from(calib *c, const float (*samples)[6], size_t n)
{
    for (int i = 0; i < 6; i++) {
        double s = 0;
        for (size_t k = 0; k < n; k++)
            s += samples[k][i];
        c->zero[i] = n ? (float)(s / (double)n) : 0.0f;
    }
}

/* Enterprise key codes that act like spacenavd button actions (firmware-spec/3dconnexion.md).
 * A key that is also a button (devtab_keys: 27) loses its built-in action once the user binds
 * that button (bnactN or bnmapN). */
static calib_action key_action(const calib *c, uint16_t code)
{
    int b = devtab_key_button(code);
    if (b >= 0 && (c->bnact[b] != CALIB_ACT_NONE || c->bnmap[b] != b))
        return CALIB_ACT_NONE;
    switch (code) {
    case 27: return CALIB_ACT_DISABLE_TRANSLATION; /* "rotate": rotation only */
    case 28: return CALIB_ACT_DISABLE_ROTATION;    /* "pan/zoom": translation only */
    case 29: return CALIB_ACT_DOMINANT;
    case 30: return CALIB_ACT_SENS_UP;
    case 31: return CALIB_ACT_SENS_DOWN;
    default: return CALIB_ACT_NONE;
    }
}

static int held(const uint16_t keys[6], uint16_t code)
{
    for (int i = 0; i < 6; i++)
        if (keys[i] == code)
            return 1;
    return 0;
}

static uint32_t remap(const calib *c, uint32_t bits)
{
    uint32_t out = 0;
    for (int i = 0; i < CALIB_BUTTONS; i++)
        if (bits >> i & 1 && c->bnact[i] == CALIB_ACT_NONE && c->bnmap[i] >= 0 && c->bnmap[i] < 32)
            out |= 1u << c->bnmap[i];
    return out;
}

uint32_t calib_buttons(calib *c, const dev_event *ev, uint32_t *pressed, uint32_t *released)
{
    for (int i = 0; i < CALIB_BUTTONS; i++)
        if (ev->pressed >> i & 1 && c->bnact[i] != CALIB_ACT_NONE)
            calib_do(c, c->bnact[i], ev->axis);
    for (int i = 0; i < 6; i++)
        if (ev->keys[i] && !held(c->keys_held, ev->keys[i]))
            calib_do(c, key_action(c, ev->keys[i]), ev->axis);
    memcpy(c->keys_held, ev->keys, sizeof c->keys_held);
    if (pressed)
        *pressed = remap(c, ev->pressed);
    if (released)
        *released = remap(c, ev->released);
    return remap(c, ev->buttons);
}

int calib_led(const calib *c, int holding)
{
    return c->led == 2 ? holding != 0 : c->led != 0;
}
