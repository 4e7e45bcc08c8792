/* dev: the keyboard fallback for machines with no controller. Terminal keys (raw mode) become
 * combined-format reports of the "keyboard" device-table row:
 *   a/d  -x/+x    w/s  -y/+y (away/towards you)   r/f  -z/+z (up/down)
 *   i/k  -rx/+rx  j/l  -rz/+rz                    u/o  -ry/+ry
 *   1-8  buttons 0-7 (tap)      space or x: stop all motion
 * A terminal has no key-up: a key holds its axis for KEY_HOLD_MS, and auto-repeat keeps it held.
 * "keyboard:FILE" reads the keys from FILE instead of the terminal (scripts, tests). */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include "dev.h"
#include "devparse.h"
#include "err.h"

#define KEY_HOLD_MS 150
#define KEY_LEVEL 250 /* of the row's 350: a brisk but controllable speed */

enum { PENDING_MOTION = 1, PENDING_BUTTONS = 2 };

struct dev_handle {
    int fd, own_fd, raw_mode;
    struct termios saved;
    int v[6];
    uint32_t buttons;
    int64_t release_us; /* when held axes and buttons drop back to zero */
    unsigned pending;   /* PENDING_*: reports still to send */
};

static int kb_open(const char *path, dev_handle **out)
{
    dev_handle *h = calloc(1, sizeof *h);
    if (!h)
        return fn_err_set(FN_ENOMEM, "keyboard: out of memory");
    h->fd = path ? open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK) : STDIN_FILENO;
    if (h->fd < 0) {
        int e = errno;
        free(h);
        return fn_err_set(e == ENOENT ? FN_ENODEV : FN_EIO, "keyboard: %s: %s", path, strerror(e));
    }
    h->own_fd = path != NULL;
    if (!path && !isatty(h->fd)) {
        free(h);
        return fn_err_set(FN_ENODEV, "keyboard: standard input is not a terminal");
    }
    if (isatty(h->fd) && tcgetattr(h->fd, &h->saved) == 0) {
        struct termios t = h->saved;
        t.c_lflag &= (tcflag_t) ~(ICANON | ECHO);
        t.c_cc[VMIN] = 0;
        t.c_cc[VTIME] = 0;
        h->raw_mode = tcsetattr(h->fd, TCSANOW, &t) == 0;
    }
    *out = h;
    return 0;
}

/* Key -> axis (0..5) and direction; -1 when the key moves nothing. */
static int key_axis(char c, int *sign)
{
    static const char neg[] = "awruji", pos[] = "dsfklo";
    static const int axis[] = {0, 1, 2, 3, 5, 4};
    const char *p = strchr(neg, c), *q = strchr(pos, c);
    if (c && p) {
        *sign = -1;
        return axis[p - neg];
    }
    if (c && q) {
        *sign = 1;
        return axis[q - pos];
    }
    return -1;
}

static void apply_key(dev_handle *h, char c, int64_t now)
{
    int sign, a = key_axis(c, &sign);
    if (a >= 0) {
        h->v[a] = sign * KEY_LEVEL;
        h->pending |= PENDING_MOTION;
    } else if (c >= '1' && c <= '8') {
        h->buttons |= 1u << (c - '1');
        h->pending |= PENDING_BUTTONS;
    } else if (c == ' ' || c == 'x') {
        memset(h->v, 0, sizeof h->v);
        h->pending |= PENDING_MOTION;
    }
    h->release_us = now + KEY_HOLD_MS * 1000;
}

/* Sends what changed, one report per call: motion first, then buttons. */
static int next_report(dev_handle *h, uint8_t *buf)
{
    if (h->pending & PENDING_MOTION) {
        h->pending &= ~PENDING_MOTION;
        return (int)devparse_make_combined(buf, h->v);
    }
    if (h->pending & PENDING_BUTTONS) {
        h->pending &= ~PENDING_BUTTONS;
        return (int)devparse_make_buttons(buf, h->buttons);
    }
    return 0;
}

static int held(const dev_handle *h)
{
    return h->buttons || h->v[0] || h->v[1] || h->v[2] || h->v[3] || h->v[4] || h->v[5];
}

static int kb_read(dev_handle *h, uint8_t *buf, size_t cap, int timeout_ms, int64_t *t_us)
{
    if (cap < 13)
        return fn_err_set(FN_EINVAL, "keyboard: report buffer under 13 bytes");
    *t_us = dev_now_us();
    if (h->pending)
        return next_report(h, buf);
    if (held(h)) { /* wake up when the hold expires */
        int left_ms = h->release_us > *t_us ? (int)((h->release_us - *t_us + 999) / 1000) : 0;
        timeout_ms = timeout_ms < 0 || timeout_ms > left_ms ? left_ms : timeout_ms;
    }
    struct pollfd p = {h->fd, POLLIN, 0};
    char keys[32];
    ssize_t n = poll(&p, 1, timeout_ms) > 0 ? read(h->fd, keys, sizeof keys) : 0;
    if (n == 0 && p.revents && timeout_ms != 0) /* end of a key file: wait like a quiet terminal */
        usleep((useconds_t)(timeout_ms < 0 ? 10 : timeout_ms) * 1000);
    *t_us = dev_now_us();
    for (ssize_t i = 0; i < n; i++)
        apply_key(h, keys[i], *t_us);
    if (n <= 0 && held(h) && *t_us >= h->release_us) {
        h->pending = (h->buttons ? PENDING_BUTTONS : 0) | PENDING_MOTION;
        h->buttons = 0;
        memset(h->v, 0, sizeof h->v);
    }
    return next_report(h, buf);
}

static int kb_info(dev_handle *h, dev_info *out)
{
    memset(out, 0, sizeof *out);
    strcpy(out->path, "keyboard");
    strcpy(out->name, "keyboard fallback (a/d w/s r/f, i/k j/l u/o, 1-8)");
    return 0;
}

static void kb_close(dev_handle *h)
{
    if (h->raw_mode)
        tcsetattr(h->fd, TCSANOW, &h->saved);
    if (h->own_fd)
        close(h->fd);
    free(h);
}

const dev_transport dev__keyboard_transport = {
    .name = "keyboard", .open = kb_open, .read = kb_read, .info = kb_info, .close = kb_close};
