/* dev_event: the normalized event every 6-DOF controller's reports become (devparse.h), whatever
 * the transport (dev.h); what calibration (calib.h) and the loop take in.
 *
 * Axis convention of every event: HID's right-handed frame, +x right, +y towards the user, +z down;
 * rx ry rz are rotations about those axes (right-hand rule). Values are normalized by the
 * device's logical maximum and clamped to [-1, 1]. A plain value: no pointers, copied freely. */
#ifndef FN_DEV_EVENT_H
#define FN_DEV_EVENT_H

#include "fnclock.h"

#include <stdint.h>

#define DEV_DT_MAX_US FNCLOCK_PAUSE_MAX_US /* dt after a pause is clamped to this, as in the loop */

/* What changed in an event (flags). */
enum {
    DEV_EV_MOTION = 1u << 0,  /* axis values changed (or a zero report arrived) */
    DEV_EV_BUTTON = 1u << 1,  /* buttons or key codes changed */
    DEV_EV_BATTERY = 1u << 2, /* battery level reported */
    DEV_EV_UNPLUG = 1u << 3,  /* the device went away: hold the last pose */
    DEV_EV_REPLUG = 1u << 4,  /* the device is back */
    DEV_EV_REFUSED = 1u << 5, /* another device (vid:pid:serial) sits where the lost one was: not
                               * adopted, still waiting; fn_err_msg() names both. Once per refusal. */
    DEV_EV_END = 1u << 6      /* a recording played out (DEV_RECORDED): nothing more will come */
};

/* A normalized event: the device's whole input state after the reports it folds in. */
typedef struct dev_event {
    int64_t t_us;      /* arrival time of the newest report folded in (monotonic microseconds) */
    int64_t dt_us;     /* time since the previous motion, clamped to [0, DEV_DT_MAX_US] */
    unsigned flags;    /* DEV_EV_* */
    float axis[6];     /* tx ty tz rx ry rz in [-1, 1], HID frame (see above) */
    uint32_t buttons;  /* bit i = button i (packed by the row's button mask) */
    uint32_t pressed;  /* buttons that went down in this event */
    uint32_t released; /* buttons that went up in this event */
    uint16_t keys[6];  /* key codes held (report 0x1C), 0 = none */
    int battery;       /* 0..100, -1 unknown */
} dev_event;

#endif
