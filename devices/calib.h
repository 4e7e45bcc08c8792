/* calib: calibration of normalized 6-DOF input, in one place, plus its configuration in spacenavd's
 * spnavrc syntax (so users keep their settings).
 *
 * calib_apply() order, per event: zero offset -> axis map / swap-yz -> invert -> dead zone
 * (rescaling: continuous, 0 at the threshold, 1 at full deflection) -> response (linear or cubic)
 * -> sensitivity (global x translation|rotation x per axis) -> locks -> dominant axis.
 * Everything is plain data: copy a calib freely; calib_apply allocates nothing. */
#ifndef FN_CALIB_H
#define FN_CALIB_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "dev_event.h"

#define CALIB_BUTTONS 32

typedef enum calib_lock { CALIB_LOCK_NONE = 0, CALIB_LOCK_TRANSLATION = 1, CALIB_LOCK_ROTATION = 2 } calib_lock;
/* CALIB_LOCK_TRANSLATION = translation only (rotation disabled); ROTATION = rotation only. */

typedef enum calib_action {
    CALIB_ACT_NONE = 0,
    CALIB_ACT_SENS_UP,
    CALIB_ACT_SENS_DOWN,
    CALIB_ACT_SENS_RESET,
    CALIB_ACT_DISABLE_ROTATION,    /* toggles translation-only */
    CALIB_ACT_DISABLE_TRANSLATION, /* toggles rotation-only */
    CALIB_ACT_DOMINANT,            /* toggles dominant-axis mode */
    CALIB_ACT_ZERO,                /* takes the current input as the zero offset */
    CALIB_ACT_COUNT
} calib_action;

typedef enum calib_response { CALIB_LINEAR = 0, CALIB_CUBIC = 1 } calib_response;

typedef struct calib {
    float sens;            /* global */
    float sens_t, sens_r;  /* translation, rotation */
    float sens_axis[6];    /* per axis */
    float dead[6];         /* dead zone per axis, fraction of full scale [0, 0.9] */
    calib_response response;
    float cubic_mix;       /* cubic response: out = (1-k) x + k x^3, k in [0, 1] */
    uint8_t invert;        /* bit i: negate output axis i */
    int8_t map[6];         /* output axis i takes input axis map[i] (-1: none) */
    int swap_yz;           /* swap y and z (and ry, rz) after the map */
    int dominant;          /* keep only the largest axis */
    calib_lock lock;
    float zero[6];         /* subtracted before everything (drift), normalized units */
    int8_t bnmap[CALIB_BUTTONS];  /* device button i reported as button bnmap[i] (-1: dropped) */
    calib_action bnact[CALIB_BUTTONS]; /* action of device button i (instead of a button) */
    int led;               /* 0 off, 1 on, 2 auto (on while a fragment is held) */
    float sens_base;       /* what sensitivity-reset returns to (the configured value) */
    uint16_t keys_held[6]; /* key codes seen last (edge detection for report 0x1C) */
} calib;

/* Defaults: sensitivity 1, no dead zone beyond 0.01 per axis, linear, identity map, no locks,
 * LED auto. */
void calib_default(calib *c);

/* Applies the calibration to normalized input (HID frame) -> out (HID frame, scaled by
 * sensitivity, may exceed 1 when sensitivity > 1). Pure. */
void calib_apply(const calib *c, const float in[6], float out[6]);

/* Handles the button edges of ev: bound actions are performed on press (and the bit cleared from
 * the returned set), other buttons are remapped through bnmap. Enterprise keys arrive as buttons
 * (devtab_keys); key codes 27 (rotate toggle; unless its button is bound), 28 (pan/zoom toggle),
 * 29 (dominant), 30 (+), 31 (-) also act by themselves. Returns the remapped button state;
 * *pressed and *released (each may be NULL) receive its remapped edges. CALIB_ACT_ZERO, bound to a
 * button, takes ev's axes (the uncalibrated input) as the zero offset. */
uint32_t calib_buttons(calib *c, const dev_event *ev, uint32_t *pressed, uint32_t *released);

/* Performs one action (also callable from a GUI or key binding). raw: current input, for ZERO. */
void calib_do(calib *c, calib_action a, const float raw[6]);

/* Zero-offset calibration: averages n samples of input taken with the cap released. */
void calib_zero_from(calib *c, const float (*samples)[6], size_t n);

/* Parses spnavrc text (len bytes, need not be NUL-terminated) into c, starting from its current
 * values. Bad lines are skipped; each is described as "FILE:LINE: message\n" appended to diag
 * (NUL-terminated, truncated to cap; may be NULL). Returns the number of bad lines. Pure. */
int calib_parse_spnavrc(calib *c, const char *text, size_t len, const char *fname, char *diag,
                        size_t cap);

/* Loads the user's configuration: path if non-NULL, else ~/.config/fracnav/spnavrc ($HOME), else
 * /etc/spnavrc ($FRACNAV_SYSCONFDIR/spnavrc when that is set). A missing file is fine (defaults,
 * returns 0); *used receives the path read (or ""). Returns the number of bad lines, or FN_EIO for
 * an unreadable named file. */
int calib_load(calib *c, const char *path, char *used, size_t used_cap, char *diag, size_t cap);

/* calib_setup flags. */
enum {
    CALIB_NAMED_ONLY = 1u << 0, /* no path: the defaults, not the user's files (a replay gives the
                                 * same poses on every machine) */
    CALIB_NEW_OK = 1u << 1      /* a named file that does not exist yet is fine: it is about to be
                                 * written (device-test --calibrate-zero) */
};

/* The calibration a command runs with, loaded the one way every command loads it: the defaults,
 * then calib_load's file (path, else the user's unless CALIB_NAMED_ONLY). Bad lines are skipped
 * and said on err as "WHO: N bad line(s) skipped:" followed by one "FILE:LINE: message" line each.
 * *used receives the path read ("" for none; may be NULL). Returns 0, or negative with fn_err_msg()
 * naming the file that cannot be read. */
int calib_setup(calib *c, const char *path, unsigned flags, FILE *err, const char *who, char *used,
                size_t used_cap);

/* The text of an spnavrc file old (old_len bytes) updated to say c, as spacenavd's writer does:
 * every line is kept as it is (comments, blank lines, unknown keys, bad lines, spacenavd-only
 * keys), except a line setting a key whose value c changes (rewritten, its trailing comment kept)
 * and a line of a known key that c leaves at its default (commented out); keys the file lacks are
 * appended. *out is malloc'd (NUL-terminated; free it). Pure. Returns 0 or FN_ENOMEM. */
int calib_merge_spnavrc(const calib *c, const char *old, size_t old_len, char **out, size_t *out_len);

/* Saves c in spnavrc syntax to path, or to ~/.config/fracnav/spnavrc (made if missing) when path
 * is NULL; atomically (temporary file, fsync, rename), so a crash never leaves a broken file. An
 * existing file is merged (calib_merge_spnavrc): the user's comments, blank lines and lines fracnav
 * does not know are kept. *used receives the path. Returns 0 or FN_EIO naming the file. */
int calib_save(const calib *c, const char *path, char *used, size_t used_cap);

/* Writes c in spnavrc syntax (every key set, so the file round-trips). Returns bytes written
 * (excluding the NUL; truncated to cap). */
size_t calib_format_spnavrc(const calib *c, char *out, size_t cap);

/* Whether the LED should be lit: the `led` setting (on, off, or auto = while a fragment is held).
 * The loop calls dev_set_led(d, calib_led(c, holding)) when either changes. */
int calib_led(const calib *c, int holding);

/* Action names in spnavrc ("sensitivity-up", ...), NULL for none; and back (-1 unknown). */
const char *calib_action_name(calib_action a);
int calib_action_parse(const char *name);

#endif
