/* simdev: the virtual 6-DOF controller's report generator.
 *
 * One generator serves every way the virtual device is reached (FUSE hidraw node, the in-process
 * "virtual" transport, scripts rendered to .fnrec): given the cap's deflection and the buttons, it
 * says which report the device sends in each period of its cadence, byte for byte.
 *
 * Behaviour (as the hardware, see firmware-spec/3dconnexion.md):
 * - split format (SpaceNavigator, 8 ms): one report per period, cycling ID1 (x y z), ID2 (rx ry rz);
 *   a button change inserts ID3 (bitmask) in the next period.
 * - combined format (SpaceMouse Wireless/Enterprise, 16 ms): ID1 with all six axes each period; a
 *   button change inserts ID3 (and, on the Enterprise, report 0x1C with key codes) in the next period.
 * - while the cap is deflected, motion reports go out every period (even when the values repeat);
 *   after release every motion report ID is sent with zeros three times, then silence.
 * - devices with a battery send report 0x17 (100 %) once after connecting.
 * - the open controller applies its settings (firmware-spec/open-controller.md 5, "The virtual
 *   device"): cadence_ms and idle_zeros of 0x22 set the cadence and the zeros after release, the
 *   offsets of 0x21 are subtracted from the deflection (then the noise floor of 2 units), and
 *   led_mode 1 lights the LED while the cap is deflected. The virtual cap has no drift: at rest it
 *   reads 0 on every axis and is silent whatever the offsets.
 * - output report 4 sets the LED; feature reports are stored and read back per report ID (the open
 *   controller's 0x20 is read-only and 0x21/0x22 refuse values out of range, as its spec says).
 * No allocation; a simdev is a plain value. */
#ifndef FN_SIMDEV_H
#define FN_SIMDEV_H

#include <stddef.h>
#include <stdint.h>

#include "devtab.h"

typedef enum simdev_format { SIMDEV_SPLIT, SIMDEV_COMBINED } simdev_format;

/* A device the simulator can impersonate: one per hardware row of the device table (devtab.h),
 * derived from the row; only the cadence, the short name and the report descriptor are the
 * simulator's own data. */
typedef struct sim_profile {
    const char *id;     /* short name for --as: "spacenavigator", "spacemouse-wireless", ... */
    uint16_t vid, pid;
    const char *name;   /* the name the kernel reports (HIDIOCGRAWNAME): the table name, or USB
                           manufacturer + " " + product where a spec gives the strings */
    const char *serial; /* default serial number (HIDIOCGRAWUNIQ), "FNSIM" + VID + PID */
    simdev_format format;
    int period_us;      /* report cadence */
    int nbuttons;       /* bits in the ID3 bitmask up to the highest real button */
    int keycodes;       /* also sends report 0x1C (up to 6 uint16 key codes) on button changes */
    int battery;        /* sends battery report 0x17 once after connecting (wireless, open) */
    int open;           /* the open controller (firmware-spec/open-controller.md): its exact
                           descriptor, 1-byte button report, feature reports 0x20-0x22 */
    const devtab_row *row; /* the device-table row it impersonates */
} sim_profile;

#define SIMDEV_ZERO_REPEATS 3
#define SIMDEV_SERIAL_MAX 33 /* 32 characters, as the open controller's spec allows */
#define SIMDEV_FEATURE_IDS 48
#define SIMDEV_FEATURE_LEN 16
#define SIMDEV_BUS_USB 0x03

/* The profiles, in device-table order; NULL past the end. Thread-safe. */
const sim_profile *sim_profile_at(size_t i);
/* By name ("spacenavigator", "spacepilot", see fracnav-sim list) or "vid:pid" in hex ("046d:c626");
 * NULL (and fn_err set) if unknown. */
const sim_profile *sim_profile_find(const char *id);
/* Writes the profile's HID report descriptor into out (cap >= 256). Returns its length. */
size_t sim_profile_descriptor(const sim_profile *p, uint8_t *out, size_t cap);
/* The length of input report id for this profile, 0 if the device has no such report. */
int sim_profile_report_len(const sim_profile *p, uint8_t id);

typedef struct simdev {
    const sim_profile *p;
    int16_t axes[6];      /* current deflection in counts, HID frame (+x right, +y toward user, +z down) */
    uint32_t buttons;     /* bit i = button i */
    uint32_t sent_buttons;
    int zeros_left;       /* zero motion reports still owed after release */
    int phase;            /* split: 0 = ID1 next, 1 = ID2 next */
    int keycode_pending;  /* Enterprise: 0x1C follows ID3 */
    int battery_pending;  /* report 0x17 goes out first after connecting */
    int led;              /* 0 off, 1 on */
    /* Settings the generator applies (the open controller's feature reports 0x21/0x22 set them;
     * other devices keep their defaults): */
    int period_us;        /* report cadence (0x22 cadence_ms) */
    int idle_zeros;       /* zero motion reports after release (0x22 idle_zeros) */
    int led_mode;         /* 1: the LED follows the cap, report 4 is ignored (0x22 led_mode) */
    int16_t offset[6];    /* subtracted from the deflection before reporting (0x21) */
    uint8_t feature[SIMDEV_FEATURE_IDS][SIMDEV_FEATURE_LEN];
    uint8_t feature_len[SIMDEV_FEATURE_IDS];
} simdev;

void simdev_init(simdev *d, const sim_profile *p);
/* Power cycle (replug): as simdev_init, but the open controller keeps its zero offsets (0x21 lives
 * in non-volatile memory; 0x22 settings are volatile). */
void simdev_replug(simdev *d);
/* Sets the deflection (clamped to +-350; what the sensor reads, before the offsets) and buttons from
 * now on. */
void simdev_set(simdev *d, const int16_t axes[6], uint32_t buttons);
/* The report the device sends in the current period, written to buf (cap >= 16). Returns its length,
 * or 0 when the device is silent this period. Call once per period. */
int simdev_next(simdev *d, uint8_t *buf, size_t cap);
/* The current report period in microseconds (the profile's, or as set by feature report 0x22). */
int simdev_period_us(const simdev *d);
/* Copies the settings (cadence, zeros, offsets, LED mode, feature reports) of src into d. */
void simdev_copy_settings(simdev *d, const simdev *src);
/* True when the device has nothing more to send until its state changes. */
int simdev_idle(const simdev *d);
/* An output report from the host (buf[0] = report ID). Returns len, or FN_EINVAL for an unknown one. */
int simdev_output(simdev *d, const uint8_t *buf, size_t len);
/* Feature get: buf[0] holds the ID on entry; fills the report. Returns its length or FN_EINVAL. */
int simdev_get_feature(simdev *d, uint8_t *buf, size_t cap);
/* Feature set: stores the report (buf[0] = ID). Returns len or FN_EINVAL. */
int simdev_set_feature(simdev *d, const uint8_t *buf, size_t len);

#endif
