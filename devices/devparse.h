/* devparse: raw HID reports -> normalized events. Pure functions over bytes, no I/O.
 *
 * Accepted reports (firmware-spec/3dconnexion.md and open-controller.md):
 *   ID 1, 7 bytes   translation x y z (int16 LE); split format
 *   ID 2, 7 bytes   rotation rx ry rz; split format
 *   ID 1, 13 bytes  x y z rx ry rz; combined format
 *   ID 3, 2..13     button bitmask (LE, first 4 bytes used), packed by the row's button mask
 *   ID 0x17, 2      battery percent 0..100
 *   ID 0x1C, 3..13 odd   up to 6 uint16 key codes held; on rows with DEVTAB_F_KEYCODES they are
 *                  also buttons (devtab_keys)
 * The format is chosen by length, never by vendor. Anything else is counted and skipped. Split
 * devices deliver translation and rotation in separate reports: the state keeps the last of each. */
#ifndef FN_DEVPARSE_H
#define FN_DEVPARSE_H

#include <stddef.h>
#include <stdint.h>

#include "dev_event.h"
#include "devtab.h"

typedef struct devparse_state {
    const devtab_row *row; /* NULL = no button packing, axis_max 350 */
    int axis_max;          /* logical maximum used to normalize (from the descriptor or the row) */
    int16_t raw[6];        /* last raw axis values */
    uint32_t buttons;      /* packed: report 3's bits | key_buttons */
    uint32_t id3_buttons;  /* report 3's bits, packed */
    uint32_t key_buttons;  /* buttons of the held 0x1C key codes (devtab_keys) */
    uint16_t keys[6];
    int battery;           /* -1 unknown */
    int64_t last_motion_us; /* -1 before the first motion */
    uint64_t n_ok, n_unknown_id, n_bad_len;
} devparse_state;

/* Starts a state for a row (may be NULL) and a logical maximum (<= 0: the row's, else 350). */
void devparse_init(devparse_state *st, const devtab_row *row, int axis_max);

/* Folds one report (report ID first) that arrived at t_us into the state and, when it was
 * accepted, writes the resulting state into ev (flags = what changed, pressed/released = edges of
 * this report) and returns 1. Returns 0 for a skipped report (the counters say why). Never reads
 * past len; any bytes are safe. */
int devparse_report(devparse_state *st, const uint8_t *buf, size_t len, int64_t t_us, dev_event *ev);

/* Merges event b (later) into a (earlier) so one event can stand for a drained queue: state from
 * b, flags and edges accumulated, dt summed and clamped. */
void devparse_merge(dev_event *a, const dev_event *b);

/* Synthesis for transports without raw reports (spnav, keyboard, sim): writes the report into buf
 * (cap >= 13) and returns its length. Values are raw logical units (clamped to int16). */
size_t devparse_make_combined(uint8_t *buf, const int v[6]);
size_t devparse_make_split(uint8_t *buf, int id, const int v[3]);
size_t devparse_make_buttons(uint8_t *buf, uint32_t bits);

/* The reports the parser and the device layer accept for a row: input reports (by the row's
 * format and flags), output report 4 (LED rows), the open controller's feature reports. This is
 * what firmware-spec's descriptor must declare, exactly (tests/test_dev_spec.c). */
typedef struct devparse_spec {
    int kind;   /* 0 input, 1 output, 2 feature (hiddesc_kind values) */
    uint8_t id;
    size_t len; /* bytes on the wire, report ID included */
} devparse_spec;
size_t devparse_reports(const devtab_row *row, devparse_spec *out, size_t cap);

/* The open controller's feature reports (firmware-spec/open-controller.md). */
enum { DEVPARSE_FEAT_INFO = 0x20, DEVPARSE_FEAT_ZERO = 0x21, DEVPARSE_FEAT_SETTINGS = 0x22 };
typedef struct devparse_open_info {
    uint8_t protocol, fw_major, fw_minor, cadence_ms;
    int16_t axis_max;
} devparse_open_info;
typedef struct devparse_open_settings {
    uint8_t cadence_ms; /* 1..255, default 8 */
    uint8_t idle_zeros; /* zero reports after release, default 3 */
    uint8_t led_mode;   /* 0 host-controlled (report 4), 1 lit while the cap is deflected */
} devparse_open_settings;
/* Parse (return 0 or FN_EFORMAT naming the report and field) and build (return the length). */
int devparse_open_info_parse(const uint8_t *buf, size_t len, devparse_open_info *out);
size_t devparse_open_info_make(uint8_t *buf, const devparse_open_info *in);
int devparse_open_zero_parse(const uint8_t *buf, size_t len, int16_t zero[6]);
size_t devparse_open_zero_make(uint8_t *buf, const int16_t zero[6]);
int devparse_open_settings_parse(const uint8_t *buf, size_t len, devparse_open_settings *out);
size_t devparse_open_settings_make(uint8_t *buf, const devparse_open_settings *in);

#endif
