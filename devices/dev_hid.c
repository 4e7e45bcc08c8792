/* dev: the hidapi transport. Built against hidapi.h; the build links libhidapi-hidraw (default,
 * transport "hidraw") or libhidapi-libusb (FRACNAV_HIDAPI_LIBUSB, transport "libusb"): one ABI. */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <hidapi/hidapi.h>
#include <linux/hidraw.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <unistd.h>
#include <wchar.h>

#include "dev.h"
#include "devtab.h"
#include "err.h"
#include "fnclock.h"

#ifdef FRACNAV_HIDAPI_LIBUSB
#define HID_NAME "libusb"
#define IS_HIDRAW 0 /* paths are libusb's "bus-port:config.interface", not files */
#define SUBSYSTEM "usb"
#else
#define HID_NAME "hidraw"
#define IS_HIDRAW 1
#define SUBSYSTEM "hidraw"
#endif

#define UDEV_HINT "install the udev rule: sudo cp udev/70-fracnav.rules /etc/udev/rules.d/ && " \
                  "sudo udevadm control --reload && sudo udevadm trigger (see udev/README.md)"

struct dev_handle {
    hid_device *dev;
    char path[256];
};

static int init_once(void)
{
    static int done;
    if (!done && hid_init() != 0)
        return fn_err_set(FN_EIO, "hidapi (%s): hid_init failed", HID_NAME);
    done = 1;
    return 0;
}

static void narrow(char *out, size_t cap, const wchar_t *w)
{
    size_t i = 0;
    for (; w && w[i] && i + 1 < cap; i++)
        out[i] = w[i] >= 32 && w[i] < 127 ? (char)w[i] : '?';
    out[i] = '\0';
}

/* A supported device's 6-DOF collection (receivers expose several), or any device whose
 * descriptor declares a multi-axis controller (a product id the table does not know yet). */
static int wanted(const struct hid_device_info *e)
{
    int multi_axis = e->usage_page == 1 && e->usage == 8;
    if (!devtab_find(e->vendor_id, e->product_id))
        return multi_axis;
    return e->usage_page == 0 || multi_axis;
}

static int hidraw_info(const char *path, dev_info *out);

/* A node found outside udev's list is listed when the device table knows it or its descriptor
 * opens with a multi-axis controller collection (Usage Page Generic Desktop, Usage 8), or when this
 * user may not open it (identity unknown: opening it names the permission problem). */
static int add_node(const char *path, dev_info *out, size_t cap, int n)
{
    dev_info d;
    memset(&d, 0, sizeof d);
    snprintf(d.path, sizeof d.path, "%s", path);
    int rc = hidraw_info(path, &d), denied = rc != 0 && (errno == EACCES || errno == EPERM);
    if (rc != 0 && !denied)
        return n; /* not a hidraw node */
    if (denied) { /* listed all the same, so that opening it says why it cannot be used */
        for (int k = 0; k < n && (size_t)k < cap; k++)
            if (!strcmp(out[k].path, path))
                return n;
        if ((size_t)n < cap)
            out[n] = d;
        return n + 1;
    }
    static const uint8_t multi_axis[] = {0x05, 0x01, 0x09, 0x08};
    if (!devtab_find(d.vid, d.pid) && !(d.desc_len >= 4 && !memcmp(d.desc, multi_axis, 4)))
        return n;
    for (int k = 0; k < n && (size_t)k < cap; k++)
        if (!strcmp(out[k].path, path))
            return n;
    if ((size_t)n < cap)
        out[n] = d;
    return n + 1;
}

/* FRACNAV_HIDRAW_PATH: colon-separated folders (their hidraw* nodes, by name) or node paths that
 * hidraw nodes outside udev's view live in, such as fracnav-sim's FUSE-served virtual device. */
static int extra_nodes(dev_info *out, size_t cap, int n)
{
    const char *env = getenv("FRACNAV_HIDRAW_PATH");
    char list[4096], path[512];
    snprintf(list, sizeof list, "%s", env ? env : "");
    for (char *save = NULL, *e = strtok_r(list, ":", &save); e; e = strtok_r(NULL, ":", &save)) {
        struct dirent **names;
        int m = scandir(e, &names, NULL, alphasort);
        if (m < 0 && (errno == EACCES || errno == EPERM)) { /* a folder or node this user may not read */
            dev_info *d = (size_t)n < cap ? &out[n] : NULL;
            if (d) {
                memset(d, 0, sizeof *d);
                snprintf(d->path, sizeof d->path, "%s", e);
            }
            n++;
            continue;
        }
        if (m < 0) { /* not a folder: a node path */
            n = add_node(e, out, cap, n);
            continue;
        }
        for (int i = 0; i < m; i++) {
            if (!strncmp(names[i]->d_name, "hidraw", 6)) {
                snprintf(path, sizeof path, "%s/%s", e, names[i]->d_name);
                n = add_node(path, out, cap, n);
            }
            free(names[i]);
        }
        free(names);
    }
    return n;
}

static int hid_enum(dev_info *out, size_t cap)
{
    if (init_once())
        return FN_EIO;
    struct hid_device_info *list = hid_enumerate(0, 0);
    int n = 0;
    for (struct hid_device_info *e = list; e; e = e->next) {
        if (!wanted(e))
            continue;
        if ((size_t)n < cap) {
            dev_info *d = &out[n];
            memset(d, 0, sizeof *d);
            snprintf(d->path, sizeof d->path, "%s", e->path);
            d->vid = e->vendor_id;
            d->pid = e->product_id;
            narrow(d->name, sizeof d->name, e->product_string);
            narrow(d->serial, sizeof d->serial, e->serial_number);
        }
        n++;
    }
    hid_free_enumeration(list);
    return IS_HIDRAW ? extra_nodes(out, cap, n) : n;
}

/* Checks a node before hidapi sees it (every path, relative ones too): hidapi 0.13.1 crashes in
 * hid_open_path on a file that is not a hidraw node. Absent -> FN_ENODEV; not ours to open -> FN_EIO naming the udev rule. */
static int check_node(const char *path)
{
    /* access() first: a folder this user may not enter (a FUSE mount of another user's) would
     * otherwise say only "Is a directory" */
    int fd = access(path, R_OK | W_OK) && (errno == EACCES || errno == EPERM) ? -1
                                                                              : open(path, O_RDWR | O_CLOEXEC | O_NONBLOCK);
    if (fd < 0) {
        int e = errno;
        if (e == ENOENT || e == ENODEV || e == ENXIO)
            return fn_err_set(FN_ENODEV, "%s: %s", path, strerror(e));
        if ((e == EACCES || e == EPERM) && !strncmp(path, "/dev/", 5))
            return fn_err_set(FN_EIO, "%s: %s: %s", path, strerror(e), UDEV_HINT);
        if (e == EACCES || e == EPERM) /* no udev rule reaches a node outside /dev (a FUSE mount) */
            return fn_err_set(FN_EIO, "%s: %s: a permission problem on this path, which no udev rule "
                              "covers: this user may not open it (a FUSE mount such as fracnav-sim's is "
                              "open only to the user who mounted it): run fracnav as that user, or serve "
                              "it as this one", path, strerror(e));
        return fn_err_set(FN_EIO, "%s: %s", path, strerror(e));
    }
    int size = 0, rc = ioctl(fd, HIDIOCGRDESCSIZE, &size);
    close(fd);
    if (rc != 0)
        return fn_err_set(FN_EIO, "%s: not a hidraw device (HIDIOCGRDESCSIZE fails)", path);
    return 0;
}

static int hid_open_dev(const char *path, dev_handle **out)
{
    if (init_once())
        return FN_EIO;
    dev_info first;
    if (!path) {
        int n = hid_enum(&first, 1);
        if (n <= 0)
            return fn_err_set(FN_ENODEV, "no supported 6-DOF HID device found (%s)", HID_NAME);
        path = first.path;
    }
    int rc = IS_HIDRAW ? check_node(path) : 0;
    if (rc)
        return rc;
    if (!IS_HIDRAW && path[0] == '/')
        return fn_err_set(FN_EINVAL, "%s: the libusb build opens USB paths (BUS-PORT:CONFIG.INTERFACE, as "
                          "'fracnav devices' lists them); a hidraw node needs the default hidraw build", path);
    hid_device *dev = hid_open_path(path);
    if (!dev && IS_HIDRAW)
        return fn_err_set(FN_EIO, "%s: hidapi (%s) cannot open it: %ls", path, HID_NAME, hid_error(NULL));
    if (!dev) /* libusb: absent and not permitted look alike (hid_error says little in 0.13.1) */
        return fn_err_set(FN_EIO, "%s: hidapi (%s) cannot open it (%ls); if it is plugged in, %s", path,
                          HID_NAME, hid_error(NULL), UDEV_HINT);
    dev_handle *h = calloc(1, sizeof *h);
    if (!h) {
        hid_close(dev);
        return fn_err_set(FN_ENOMEM, "%s: out of memory", path);
    }
    h->dev = dev;
    snprintf(h->path, sizeof h->path, "%s", path);
    *out = h;
    return 0;
}

static int hid_read_dev(dev_handle *h, uint8_t *buf, size_t cap, int timeout_ms, int64_t *t_us)
{
    int n = hid_read_timeout(h->dev, buf, cap, timeout_ms);
    *t_us = fnclock_now_us();
    if (n < 0)
        return fn_err_set(FN_ENODEV, "%s: read failed: %ls", h->path, hid_error(h->dev));
    return n;
}

static int hid_write_dev(dev_handle *h, const uint8_t *buf, size_t len)
{
    int n = hid_write(h->dev, buf, len);
    return n < 0 ? fn_err_set(FN_EIO, "%s: write of report %u failed: %ls", h->path, buf[0], hid_error(h->dev))
                 : n;
}

static int hid_get_feature_dev(dev_handle *h, uint8_t *buf, size_t cap)
{
    int n = hid_get_feature_report(h->dev, buf, cap);
    return n < 0 ? fn_err_set(FN_EIO, "%s: feature report %u: %ls", h->path, buf[0], hid_error(h->dev)) : n;
}

static int hid_set_feature_dev(dev_handle *h, const uint8_t *buf, size_t len)
{
    int n = hid_send_feature_report(h->dev, buf, len);
    return n < 0 ? fn_err_set(FN_EIO, "%s: feature report %u: %ls", h->path, buf[0], hid_error(h->dev)) : n;
}

/* A hidraw node answers these ioctls itself (a FUSE-served node too), with no udev involved. */
static int hidraw_info(const char *path, dev_info *out)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK);
    if (fd < 0)
        return -1;
    struct hidraw_devinfo ri;
    int size = 0, ok = ioctl(fd, HIDIOCGRAWINFO, &ri) == 0;
    if (ok) {
        out->vid = (uint16_t)ri.vendor;
        out->pid = (uint16_t)ri.product;
    }
    char name[sizeof out->name] = "";
    if (ioctl(fd, HIDIOCGRAWNAME(sizeof name - 1), name) >= 0 && !out->name[0])
        snprintf(out->name, sizeof out->name, "%s", name);
    char uniq[sizeof out->serial] = "";
    if (ioctl(fd, HIDIOCGRAWUNIQ(sizeof uniq - 1), uniq) >= 0 && !out->serial[0])
        snprintf(out->serial, sizeof out->serial, "%s", uniq);
    struct hidraw_report_descriptor *rd = malloc(sizeof *rd);
    if (rd && ioctl(fd, HIDIOCGRDESCSIZE, &size) == 0 && size > 0 && size <= HID_MAX_DESCRIPTOR_SIZE &&
        (size_t)size <= sizeof out->desc) {
        rd->size = (uint32_t)size;
        if (ioctl(fd, HIDIOCGRDESC, rd) == 0) {
            memcpy(out->desc, rd->value, (size_t)size);
            out->desc_len = (size_t)size;
        }
    }
    free(rd);
    close(fd);
    return ok ? 0 : -1;
}

static int hid_info_dev(dev_handle *h, dev_info *out)
{
    memset(out, 0, sizeof *out);
    snprintf(out->path, sizeof out->path, "%s", h->path);
    struct hid_device_info *i = hid_get_device_info(h->dev);
    if (i) {
        out->vid = i->vendor_id;
        out->pid = i->product_id;
        narrow(out->name, sizeof out->name, i->product_string);
        narrow(out->serial, sizeof out->serial, i->serial_number);
    }
    int raw = IS_HIDRAW ? hidraw_info(h->path, out) : -1;
    return i || raw == 0 ? 0 : fn_err_set(FN_EIO, "%s: no device information", h->path);
}

static void hid_close_dev(dev_handle *h)
{
    hid_close(h->dev);
    free(h);
}

static void hid_describe(char *buf, size_t cap)
{
    snprintf(buf, cap, "enumerates devices");
}

const dev_transport dev__hid_transport = {
    .name = HID_NAME,
    .describe = hid_describe,
    .open = hid_open_dev,
    .read = hid_read_dev,
    .write = hid_write_dev,
    .get_feature = hid_get_feature_dev,
    .set_feature = hid_set_feature_dev,
    .info = hid_info_dev,
    .close = hid_close_dev,
    .enumerate = hid_enum,
    .hotplug_subsystem = SUBSYSTEM,
};
