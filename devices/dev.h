/* dev: 6-DOF controllers behind one seam.
 *
 * A transport moves raw HID reports (report ID first) between fracnav and a device; parsers turn
 * those bytes into normalized events; calibration turns events into motion. Every transport
 * (hidraw, libusb, spnav, keyboard, virtual, replay) fills a dev_transport. Transports that have no
 * raw reports of their own (spnav, keyboard) synthesize reports of a device-table row, so one parser
 * path serves them all. */
#ifndef FN_DEV_H
#define FN_DEV_H

#include <stddef.h>
#include <stdint.h>

#define DEV_REPORT_MAX 64
#define DEV_DESC_MAX 4096

typedef struct dev_handle dev_handle; /* a transport's open device, opaque */

typedef struct dev_info {
    char path[256];
    uint16_t vid, pid;
    char name[128];
    char serial[64];
    uint8_t desc[DEV_DESC_MAX]; /* HID report descriptor, when the transport can read it */
    size_t desc_len;
} dev_info;

typedef struct dev_transport {
    const char *name; /* "hidraw", "libusb", "spnav", "keyboard", "virtual", "replay" */
    /* Opens the device at path (transport-specific; NULL = the first one found). */
    int (*open)(const char *path, dev_handle **out);
    /* Reads one report into buf. Returns its length, 0 on timeout, FN_ENODEV when the device went
     * away, another negative FN_E* on error. *t_us is the arrival time (monotonic microseconds;
     * on replay the recorded time). timeout_ms < 0 blocks, 0 polls. */
    int (*read)(dev_handle *h, uint8_t *buf, size_t cap, int timeout_ms, int64_t *t_us);
    /* Sends an output report (e.g. the LED, report 4). Returns bytes written or negative. */
    int (*write)(dev_handle *h, const uint8_t *buf, size_t len);
    /* Feature report get: buf[0] holds the report ID on entry. Returns length or negative. */
    int (*get_feature)(dev_handle *h, uint8_t *buf, size_t cap);
    int (*info)(dev_handle *h, dev_info *out);
    void (*close)(dev_handle *h);
} dev_transport;

#endif
