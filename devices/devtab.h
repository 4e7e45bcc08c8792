/* devtab: the 6-DOF device table. Every supported controller is one row of data: identity, report
 * format, buttons and axis quirks. Code never tests a vendor or product id; it looks up a row.
 *
 * The table is static and read-only; row pointers stay valid for the life of the process and may
 * be shared between threads. */
#ifndef FN_DEVTAB_H
#define FN_DEVTAB_H

#include <stddef.h>
#include <stdint.h>

/* The open controller of firmware-spec/open-controller.md (pid.codes VID, test PID range: a build
 * that ships gets its own PID and adds one row). */
#define DEVTAB_OPEN_VID 0x1209
#define DEVTAB_OPEN_PID 0x0001

/* Motion report formats. The parser chooses by report length, never by this field: it documents
 * what the device sends (for `fracnav devices`) and which reports a transport must synthesize. */
typedef enum devtab_format {
    DEVTAB_SPLIT = 1,    /* ID1 x y z (7 bytes) + ID2 rx ry rz (7 bytes) */
    DEVTAB_COMBINED = 2, /* ID1 x y z rx ry rz (13 bytes) */
    DEVTAB_LEGACY = 3    /* older USB models: treated as split, layout unverified */
} devtab_format;

/* Row flags. */
enum {
    DEVTAB_F_LED = 1u << 0,      /* output report 4 drives an LED */
    DEVTAB_F_BATTERY = 1u << 1,  /* sends report 0x17 (battery percent) */
    DEVTAB_F_KEYCODES = 1u << 2, /* sends report 0x1C key codes (Enterprise) */
    DEVTAB_F_RECEIVER = 1u << 3, /* wireless receiver: several HID collections, one is 6-DOF */
    DEVTAB_F_OPEN = 1u << 4,     /* the open controller: calibration feature reports */
    DEVTAB_F_SYNTH = 1u << 5     /* not hardware: a transport's synthesized device (spnav, keyboard) */
};

typedef struct devtab_row {
    uint16_t vid, pid;
    const char *name;
    devtab_format format;
    uint8_t nbuttons;     /* buttons the device has (after the mask below) */
    uint32_t button_mask; /* bits of report 3 that are real buttons; they are packed to 0..n-1 */
    uint8_t axis_invert;  /* bit i: negate axis i (tx ty tz rx ry rz) to reach the HID convention */
    int16_t axis_max;     /* logical maximum when the descriptor is not available (350) */
    unsigned flags;       /* DEVTAB_F_* */
    const char *alias;    /* short name ("spacenavigator": fracnav-sim --as, virtual:NAME), NULL =
                           * the name's slug ("spacemouse-plus-xt-usb") */
    const char *usb_vendor; /* USB manufacturer string where the name does not begin with it (the
                             * kernel names a device manufacturer + " " + product), else NULL */
} devtab_row;

/* A key code of report 0x1C (rows with DEVTAB_F_KEYCODES) and the button number it is reported
 * as, so such keys are buttons like any other (bnmapN, bnactN, the loop's buttons). */
typedef struct devtab_key {
    uint16_t code;
    uint8_t button; /* bit in dev_event.buttons */
    const char *name;
} devtab_key;

/* The key-code table; *n receives its length. */
const devtab_key *devtab_keys(size_t *n);
/* The button of a key code, -1 when the code is not a button (it still reaches dev_event.keys). */
int devtab_key_button(uint16_t code);
/* The label of a key code ("ENTER", "ESC", "1".."12", "MENU", "FIT", ...), NULL when the table has
 * no such code. */
const char *devtab_key_name(uint16_t code);
/* The name of button bit `button` of a device: the label of its key on rows with DEVTAB_F_KEYCODES
 * (the Enterprise: "ENTER", "FIT", ...); else "B1", "B2", ... (button + 1), written into buf. */
const char *devtab_button_name(const devtab_row *row, int button, char *buf, size_t cap);
/* The button bit of the key labelled "1": on rows with DEVTAB_F_KEYCODES (the Enterprise) that of
 * key code 13 (12), where its numbered keys 1-10 start; 0 on every other row (or NULL). */
int devtab_key1_button(const devtab_row *row);

/* The whole table (hardware rows first, then the synthetic rows). *n receives the row count. */
const devtab_row *devtab_rows(size_t *n);
/* The row for vid:pid, or NULL when the device is not a supported 6-DOF controller. */
const devtab_row *devtab_find(uint16_t vid, uint16_t pid);
/* A synthetic row by name ("spnav", "keyboard", "generic"), NULL if absent. */
const devtab_row *devtab_synthetic(const char *name);
/* "split", "combined", "legacy". */
const char *devtab_format_name(devtab_format f);

#endif
