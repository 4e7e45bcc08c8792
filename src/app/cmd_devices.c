/* fracnav devices: the connected 6-DOF controllers and the transports available. */
#include "cmd.h"

#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dev.h"
#include "devtab.h"
#include "err.h"
#include "fnclock.h"
#include "jsonw.h"

#define LIST_MAX 32
#define EXTRA_MAX 8 /* --device options */
#define BATTERY_WAIT_MS 120 /* wireless devices report 0x17 soon after open */

typedef struct found {
    dev_info info;
    const char *transport;
    const devtab_row *row;
    int battery;
    char error[320]; /* why it cannot be opened, "" if it can */
} found;

static void usage(FILE *out)
{
    fprintf(out, "usage: fracnav devices [--json] [--device SPEC]...\n\n"
                 "Lists the connected 6-DOF controllers (path, USB id, name, report format, buttons,\n"
                 "battery) and the transports available. Enumeration sees real USB/Bluetooth devices;\n"
                 "--device adds one it cannot see (a hidraw path, spnav, keyboard, replay:FILE, ...).\n"
                 "A device that cannot be opened is listed with the reason: for a /dev node, the udev\n"
                 "rule to install; for a node elsewhere (a FUSE mount), the permission problem.\n\n"
                 "  --json          one JSON object: command, devices (path, usb_id, transport, name,\n"
                 "                  format, buttons, battery_pct, serial, error), transports\n"
                 "  --device SPEC   also probe this device (repeatable, up to 8 times)\n\n"
                 "environment:\n"
                 "  FRACNAV_HIDRAW_PATH   colon-separated folders (their hidraw* nodes) or node paths\n"
                 "                        enumerated besides the system's, e.g. the mount point of\n"
                 "                        fracnav-sim serve; auto and serial:SN find them too\n");
}

/* Opens the device briefly: for the battery, and to find out whether the user may open it. */
static void probe(found *f, const char *spec)
{
    f->battery = -1;
    fn_err_clear();
    dev_device *d = dev_open(spec);
    if (!d) {
        snprintf(f->error, sizeof f->error, "%s", fn_err_msg());
        const dev_transport *t;
        const char *arg;
        if (!f->transport && dev_spec_resolve(spec, &t, &arg) == 0) /* known even when it failed */
            f->transport = t->name;
        return;
    }
    if (!f->info.path[0])
        f->info = *dev_device_info(d);
    f->row = dev_row(d);
    f->transport = dev_transport_name(d);
    dev_event ev;
    int64_t end = fnclock_now_us() + BATTERY_WAIT_MS * 1000;
    while ((f->row->flags & DEVTAB_F_BATTERY) && dev_battery(d) < 0 && fnclock_now_us() < end)
        if (dev_poll(d, &ev, 20) < 0)
            break;
    f->battery = dev_battery(d);
    dev_close(d);
}

static size_t enumerate_all(found *list, size_t cap)
{
    size_t n = 0;
    dev_info infos[LIST_MAX];
    for (size_t t = 0; dev_transport_at(t); t++) {
        const dev_transport *tr = dev_transport_at(t);
        int k = tr->enumerate ? tr->enumerate(infos, LIST_MAX) : 0;
        for (int i = 0; i < k && i < LIST_MAX && n < cap; i++) {
            found *f = &list[n++];
            memset(f, 0, sizeof *f);
            f->info = infos[i];
            f->transport = tr->name;
            f->row = devtab_find(infos[i].vid, infos[i].pid);
            char spec[300];
            snprintf(spec, sizeof spec, "%s:%.255s", tr->name, infos[i].path);
            probe(f, spec);
        }
    }
    return n;
}

static json_t *device_json(const found *f)
{
    char id[16];
    snprintf(id, sizeof id, "%04x:%04x", f->info.vid, f->info.pid);
    json_t *o = json_pack("{s:o, s:s, s:s, s:o}", "path", jsonw_string(f->info.path), "usb_id", id, "transport",
                          f->transport ? f->transport : "", "name",
                          jsonw_string(f->row && f->row->vid ? f->row->name : f->info.name));
    json_object_set_new(o, "format", f->row ? json_string(devtab_format_name(f->row->format)) : json_null());
    json_object_set_new(o, "buttons", f->row ? json_integer(f->row->nbuttons) : json_null());
    json_object_set_new(o, "battery_pct", f->battery >= 0 ? json_integer(f->battery) : json_null());
    json_object_set_new(o, "serial", jsonw_string(f->info.serial));
    json_object_set_new(o, "error", f->error[0] ? jsonw_string(f->error) : json_null());
    return o;
}

static int print_json(const found *list, size_t n)
{
    json_t *root = jsonw_object("devices"), *devs = json_array(), *trs = json_array();
    for (size_t i = 0; i < n; i++)
        json_array_append_new(devs, device_json(&list[i]));
    char buf[320];
    for (size_t t = 0; dev_transport_at(t); t++)
        json_array_append_new(trs, json_pack("{s:s, s:s}", "name", dev_transport_at(t)->name, "state",
                                             dev_transport_describe(dev_transport_at(t), buf, sizeof buf)));
    json_object_set_new(root, "devices", devs);
    json_object_set_new(root, "transports", trs);
    if (jsonw_print(root, stdout) == 0)
        return 0;
    fprintf(stderr, "fracnav devices: %s\n", fn_err_msg());
    return 1;
}

static void print_text(const found *list, size_t n)
{
    if (n == 0)
        printf("no 6-DOF controller connected\n");
    for (size_t i = 0; i < n; i++) {
        const found *f = &list[i];
        const char *name = f->row && f->row->vid ? f->row->name : f->info.name;
        if (f->info.vid || f->info.pid)
            printf("%s  %04x:%04x  %s\n", f->info.path, f->info.vid, f->info.pid, name);
        else /* nothing known but the spec: say so rather than print a zero id */
            printf("%s  %s\n", f->info.path, f->error[0] ? "(not opened)" : name);
        if (f->row)
            printf("    format %s, %d buttons", devtab_format_name(f->row->format), f->row->nbuttons);
        if (f->battery >= 0)
            printf(", battery %d%%", f->battery);
        if (f->info.serial[0])
            printf(", serial %s", f->info.serial);
        if (f->transport)
            printf("%s    transport %s\n", f->row ? "\n" : "", f->transport);
        else if (f->row)
            printf("\n");
        if (f->error[0])
            printf("    cannot open: %s\n", f->error);
    }
    char buf[320];
    int width = 0;
    for (size_t t = 0; dev_transport_at(t); t++)
        if ((int)strlen(dev_transport_at(t)->name) > width)
            width = (int)strlen(dev_transport_at(t)->name);
    printf("transports:\n");
    for (size_t t = 0; dev_transport_at(t); t++)
        printf("  %-*s  %s\n", width, dev_transport_at(t)->name,
               dev_transport_describe(dev_transport_at(t), buf, sizeof buf));
}

int cmd_devices(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    int json = 0;
    const char *extra[EXTRA_MAX];
    size_t n_extra = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--json"))
            json = 1;
        else if (!strcmp(argv[i], "--device")) {
            if (i + 1 >= argc || !strncmp(argv[i + 1], "--", 2))
                return cmd_usage_error("devices", "--device wants a SPEC%s%s", i + 1 < argc ? ", got option " : "",
                                       i + 1 < argc ? argv[i + 1] : "");
            if (n_extra == EXTRA_MAX)
                return cmd_usage_error("devices", "at most %d --device options (the %dth is '%s')", EXTRA_MAX,
                                       EXTRA_MAX + 1, argv[i + 1]);
            extra[n_extra++] = argv[++i];
        } else {
            return cmd_usage_error("devices", "unknown or incomplete option '%s'", argv[i]);
        }
    }
    found *list = calloc(LIST_MAX, sizeof *list);
    if (!list) {
        fprintf(stderr, "fracnav devices: out of memory\n");
        return 1;
    }
    size_t n = enumerate_all(list, LIST_MAX);
    for (size_t i = 0; i < n_extra && n < LIST_MAX; i++) {
        found *f = &list[n++];
        probe(f, extra[i]);
        if (!f->info.path[0])
            snprintf(f->info.path, sizeof f->info.path, "%s", extra[i]);
    }
    int rc = 0;
    if (json)
        rc = print_json(list, n);
    else
        print_text(list, n);
    free(list);
    return rc;
}
