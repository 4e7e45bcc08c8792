/* dev: the spnav transport, a client of a running spacenavd through libspnav. spacenavd already
 * owns the device and sends events; they are turned back into combined-format reports of the
 * "spnav" device-table row (HID frame), so one parser path serves every transport. */
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>

#include "dev.h"
#include "devparse.h"
#include "err.h"
#include "fnclock.h"

static void spnav_describe(char *buf, size_t cap);

#ifdef FRACNAV_HAVE_SPNAV
#include <spnav.h>

#define DEFAULT_SOCKET "/var/run/spnav.sock"

struct dev_handle {
    uint32_t buttons;
    int proto;
    char socket[256]; /* the bare socket path: what dev_info reports and a replug reopens */
};

static int open_count; /* libspnav keeps one connection per process */

/* libspnav reads $SPNAV_SOCKET when it connects: set it for that call only, so a failed or
 * explicit open leaves the caller's environment as it was. */
static int connect_to(const char *sock)
{
    const char *was = getenv("SPNAV_SOCKET");
    char old[256];
    int had = was != NULL && strlen(was) < sizeof old;
    if (had)
        snprintf(old, sizeof old, "%s", was);
    if (setenv("SPNAV_SOCKET", sock, 1))
        return -1;
    int rc = spnav_open();
    if (had)
        setenv("SPNAV_SOCKET", old, 1);
    else
        unsetenv("SPNAV_SOCKET");
    return rc;
}

static int spnav_open_dev(const char *path, dev_handle **out)
{
    if (open_count)
        return fn_err_set(FN_EIO, "spnav: already connected (libspnav allows one connection)");
    const char *env = getenv("SPNAV_SOCKET");
    const char *sock = path && *path ? path : env && *env ? env : DEFAULT_SOCKET;
    struct stat st;
    /* Look before connecting: libspnav leaks a little on each failed open. */
    if (stat(sock, &st) || !S_ISSOCK(st.st_mode))
        return fn_err_set(FN_ENODEV, "spacenavd is not running (no socket at %s)", sock);
    dev_handle *h = calloc(1, sizeof *h);
    if (!h)
        return fn_err_set(FN_ENOMEM, "spnav: out of memory");
    snprintf(h->socket, sizeof h->socket, "%s", sock);
    if (strlen(sock) >= sizeof h->socket || connect_to(sock) == -1) {
        free(h);
        return fn_err_set(FN_ENODEV, "cannot connect to spacenavd at %s", sock);
    }
    h->proto = spnav_protocol();
    open_count = 1;
    *out = h;
    return 0;
}

/* spacenavd's frame is (x, -z, -y, rx, -rz, -ry) of HID's: undo it. */
static size_t motion_report(uint8_t *buf, const spnav_event *e)
{
    int v[6] = {e->motion.x, -e->motion.z, -e->motion.y, e->motion.rx, -e->motion.rz, -e->motion.ry};
    return devparse_make_combined(buf, v);
}

static int daemon_gone(void)
{
    char c;
    ssize_t n = recv(spnav_fd(), &c, 1, MSG_PEEK | MSG_DONTWAIT);
    return n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR);
}

static int spnav_read_dev(dev_handle *h, uint8_t *buf, size_t cap, int timeout_ms, int64_t *t_us)
{
    if (cap < 13)
        return fn_err_set(FN_EINVAL, "spnav: report buffer under 13 bytes");
    for (;;) {
        struct pollfd p = {spnav_fd(), POLLIN, 0};
        int r = poll(&p, 1, timeout_ms);
        *t_us = fnclock_now_us();
        if (r < 0 && errno == EINTR)
            continue;
        if (r <= 0)
            return r == 0 ? 0 : fn_err_set(FN_EIO, "spnav: poll: %s", strerror(errno));
        if (daemon_gone())
            return fn_err_set(FN_ENODEV, "spnav: spacenavd closed the connection");
        spnav_event e;
        int type = spnav_poll_event(&e);
        if (type == SPNAV_EVENT_MOTION)
            return (int)motion_report(buf, &e);
        if (type == SPNAV_EVENT_BUTTON && e.button.bnum >= 0 && e.button.bnum < 32) {
            uint32_t bit = 1u << e.button.bnum;
            h->buttons = e.button.press ? h->buttons | bit : h->buttons & ~bit;
            return (int)devparse_make_buttons(buf, h->buttons);
        }
        timeout_ms = 0; /* a device or config event: look for the next one without waiting */
    }
}

/* The LED needs protocol v1 (a request to the daemon); under v0 it is silently absent. */
static int spnav_write_dev(dev_handle *h, const uint8_t *buf, size_t len)
{
    if (len == 2 && buf[0] == 4 && h->proto < 1)
        return 0;
    if (len == 2 && buf[0] == 4)
        return spnav_cfg_set_led(buf[1] ? 1 : 0) == -1 ? fn_err_set(FN_EIO, "spnav: LED request refused") : 2;
    return fn_err_set(FN_EINVAL, "spnav: output report %u not supported (protocol v%d)", len ? buf[0] : 0,
                      h->proto);
}

static int spnav_info_dev(dev_handle *h, dev_info *out)
{
    memset(out, 0, sizeof *out);
    snprintf(out->path, sizeof out->path, "%s", h->socket);
    snprintf(out->name, sizeof out->name, "spacenavd (protocol v%d)", h->proto);
    return 0;
}

static void spnav_close_dev(dev_handle *h)
{
    spnav_close();
    open_count = 0;
    free(h);
}

const dev_transport dev__spnav_transport = {
    .name = "spnav",
    .synthetic_row = "spnav",
    .describe = spnav_describe,
    .open = spnav_open_dev,
    .read = spnav_read_dev,
    .write = spnav_write_dev,
    .info = spnav_info_dev,
    .close = spnav_close_dev,
};

#else

static int spnav_open_dev(const char *path, dev_handle **out)
{
    return fn_err_set(FN_ENODEV, "spnav: fracnav was built without libspnav (install libspnav-dev)");
}

static int spnav_read_dev(dev_handle *h, uint8_t *buf, size_t cap, int timeout_ms, int64_t *t_us)
{
    return FN_ENODEV;
}

static void spnav_close_dev(dev_handle *h)
{
}

const dev_transport dev__spnav_transport = {
    .name = "spnav",
    .synthetic_row = "spnav",
    .describe = spnav_describe,
    .open = spnav_open_dev,
    .read = spnav_read_dev,
    .close = spnav_close_dev,
};

#endif

/* Whether spacenavd answers now: the state `fracnav devices` shows. */
static void spnav_describe(char *buf, size_t cap)
{
    dev_handle *h = NULL;
    int rc = spnav_open_dev(NULL, &h);
    if (rc == 0)
        spnav_close_dev(h);
    snprintf(buf, cap, "%s", rc == 0 ? "spacenavd running" : fn_err_msg());
}
