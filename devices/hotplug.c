/* hotplug: the libudev monitor behind hotplug_ops. */
#include "hotplug.h"

#include <stdlib.h>
#include <string.h>

#ifdef FRACNAV_HAVE_UDEV
#include <libudev.h>

struct hotplug_monitor {
    struct udev *udev;
    struct udev_monitor *mon;
};

static void udev_close(hotplug_monitor *m)
{
    if (m->mon)
        udev_monitor_unref(m->mon);
    if (m->udev)
        udev_unref(m->udev);
    free(m);
}

/* The "udev" source: events after udevd ran the rules (permissions set), not the kernel's raw ones. */
static hotplug_monitor *udev_open(const char *subsystem)
{
    hotplug_monitor *m = calloc(1, sizeof *m);
    if (!m)
        return NULL;
    m->udev = udev_new();
    m->mon = m->udev ? udev_monitor_new_from_netlink(m->udev, "udev") : NULL;
    if (!m->mon || udev_monitor_filter_add_match_subsystem_devtype(m->mon, subsystem, NULL) < 0 ||
        udev_monitor_enable_receiving(m->mon) < 0 || udev_monitor_get_fd(m->mon) < 0) {
        udev_close(m);
        return NULL;
    }
    return m;
}

static int udev_fd(hotplug_monitor *m)
{
    return udev_monitor_get_fd(m->mon);
}

static int udev_added(hotplug_monitor *m)
{
    int add = 0;
    struct udev_device *dev;
    while ((dev = udev_monitor_receive_device(m->mon)) != NULL) { /* the socket is non-blocking */
        const char *action = udev_device_get_action(dev);
        add |= action && !strcmp(action, "add");
        udev_device_unref(dev);
    }
    return add;
}

#else

struct hotplug_monitor {
    int unused;
};

static hotplug_monitor *udev_open(const char *subsystem)
{
    return NULL;
}

static int udev_fd(hotplug_monitor *m)
{
    return -1;
}

static int udev_added(hotplug_monitor *m)
{
    return 0;
}

static void udev_close(hotplug_monitor *m)
{
}

#endif

const hotplug_ops hotplug_udev = {.open = udev_open, .fd = udev_fd, .added = udev_added, .close = udev_close};
