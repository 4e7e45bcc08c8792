/* hotplug: wakes a lost device's reopen as soon as the system announces a new device.
 *
 * dev_poll looks for a lost device every DEV_REPLUG_MS; a monitor lets it look at once when the
 * system says a device was added (libudev's "add" events, sent after udev applied the rules, so
 * the node is already accessible). A monitor that cannot start (no udev, no netlink in a
 * container, a FUSE-served node udev never sees) is not an error: polling alone finds the device.
 * Monitors are a seam (hotplug_ops) so tests can stand in for udev.
 *
 * Threads: a monitor belongs to the thread that polls its device. */
#ifndef FN_HOTPLUG_H
#define FN_HOTPLUG_H

typedef struct hotplug_monitor hotplug_monitor;

typedef struct hotplug_ops {
    /* Starts watching the subsystem ("hidraw", "usb"). NULL when it cannot (fall back to polling). */
    hotplug_monitor *(*open)(const char *subsystem);
    /* A descriptor that becomes readable when events are pending. */
    int (*fd)(hotplug_monitor *m);
    /* Reads every pending event; 1 when an "add" was among them, else 0. Never blocks. */
    int (*added)(hotplug_monitor *m);
    void (*close)(hotplug_monitor *m);
} hotplug_ops;

/* libudev's netlink monitor (its open returns NULL when fracnav was built without libudev). */
extern const hotplug_ops hotplug_udev;

#endif
