/* dev: the keyboard+mouse fallback for machines with no controller. Terminal keys (raw mode) and
 * terminal mouse events (xterm SGR reporting) become combined-format reports of the "keyboard"
 * device-table row:
 *   a/d or arrows left/right  -x/+x    w/s or arrows up/down  -y/+y (away/towards you)
 *   r/f  -z/+z (up/down)   i/k -rx/+rx   j/l -rz/+rz   u/o -ry/+ry
 *   1-9  buttons 1-9 (tap; 9 saves)    0 or m  button 10 (frame)    ? or h  button 11 (help)
 *   g  button 12 (fit the selected fragment to the others)
 *   v  button 13 (the live preview on/off)   b  button 14 (accept the preview)
 *   space or x: stop all motion   q  quit (as Ctrl-C: raises SIGINT)
 *   mouse: left drag rotates (rz, rx), middle drag rolls (ry), right drag moves (x, y), wheel z
 * The row has 14 buttons, sent in report 3. A terminal has no key-up: a key holds its axis for
 * KEY_HOLD_MS, and auto-repeat keeps it held.
 * "keyboard:FILE" reads the same bytes from FILE instead of the terminal (scripts, tests). Keys
 * typed in navigate's window come through a pipe (kb_feed_keys) and act the same. */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include "dev.h"
#include "devparse.h"
#include "err.h"
#include "fnclock.h"

#define KEY_HOLD_MS 150
#define KEY_LEVEL 250 /* of the row's 350: a brisk but controllable speed */

#define MOUSE_GAIN 70  /* per terminal cell dragged */
#define ESC_MAX 24

enum { PENDING_MOTION = 1, PENDING_BUTTONS = 2 };

static const char MOUSE_ON[] = "\033[?1002h\033[?1006h", MOUSE_OFF[] = "\033[?1006l\033[?1002l";

struct dev_handle {
    int fd, own_fd, raw_mode;
    int fd_done;        /* fd is at its end (a key file read to the end): only feed is read */
    int feed[2];        /* a pipe: keys typed elsewhere (a window, kb_feed_keys) */
    struct termios saved;
    int v[6];
    uint32_t buttons;
    int64_t release_us; /* when held axes and buttons drop back to zero */
    unsigned pending;   /* PENDING_*: reports still to send */
    char esc[ESC_MAX];  /* an escape sequence being read */
    size_t esc_len;
    int mx, my, mdown;  /* last mouse cell, and whether a drag is under way */
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
    if (pipe(h->feed) != 0) {
        int e = errno;
        if (h->own_fd)
            close(h->fd);
        free(h);
        return fn_err_set(FN_EIO, "keyboard: a pipe for the window's keys: %s", strerror(e));
    }
    for (int i = 0; i < 2; i++)
        fcntl(h->feed[i], F_SETFL, O_NONBLOCK), fcntl(h->feed[i], F_SETFD, FD_CLOEXEC);
    if (isatty(h->fd) && tcgetattr(h->fd, &h->saved) == 0) {
        struct termios t = h->saved;
        t.c_lflag &= (tcflag_t) ~(ICANON | ECHO);
        t.c_cc[VMIN] = 0;
        t.c_cc[VTIME] = 0;
        h->raw_mode = tcsetattr(h->fd, TCSANOW, &t) == 0;
        if (h->raw_mode && isatty(STDOUT_FILENO))
            (void)!write(STDOUT_FILENO, MOUSE_ON, sizeof MOUSE_ON - 1);
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

static int clamp_level(int v)
{
    return v > 350 ? 350 : v < -350 ? -350 : v;
}

/* One SGR mouse report "\033[<b;x;yM" (press/drag) or "...m" (release). */
static void apply_mouse(dev_handle *h, int b, int x, int y, int press)
{
    if (!press) {
        h->mdown = 0;
        return;
    }
    if (b == 64 || b == 65) { /* wheel: up lifts (-z), down pushes (+z) */
        h->v[2] = b == 64 ? -KEY_LEVEL : KEY_LEVEL;
        h->pending |= PENDING_MOTION;
        return;
    }
    int drag = (b & 32) && h->mdown, dx = drag ? x - h->mx : 0, dy = drag ? y - h->my : 0;
    h->mx = x, h->my = y, h->mdown = 1;
    if (!drag)
        return;
    switch (b & 3) {
    case 0: h->v[5] = clamp_level(dx * MOUSE_GAIN), h->v[3] = clamp_level(-dy * MOUSE_GAIN); break;
    case 1: h->v[4] = clamp_level(dx * MOUSE_GAIN); break;
    default: h->v[0] = clamp_level(dx * MOUSE_GAIN), h->v[1] = clamp_level(dy * MOUSE_GAIN); break;
    }
    h->pending |= PENDING_MOTION;
}

/* A finished escape sequence: arrows, or a mouse report. Anything else is ignored. */
static void apply_escape(dev_handle *h)
{
    const char *e = h->esc;
    char fin = e[h->esc_len - 1];
    int b, x, y;
    if (h->esc_len == 3 && strchr("ABCD", fin)) {
        int axis = fin == 'A' || fin == 'B' ? 1 : 0, sign = fin == 'B' || fin == 'C' ? 1 : -1;
        h->v[axis] = sign * KEY_LEVEL;
        h->pending |= PENDING_MOTION;
    } else if (e[2] == '<' && sscanf(e + 3, "%d;%d;%d", &b, &x, &y) == 3)
        apply_mouse(h, b, x, y, fin == 'M');
}

/* Collects "\033[" ... final byte; returns 1 while the byte belongs to a sequence. */
static int escape_byte(dev_handle *h, char c)
{
    if (c == '\033') {
        h->esc[0] = c;
        h->esc_len = 1;
        return 1;
    }
    if (!h->esc_len)
        return 0;
    if (h->esc_len == 1 && c != '[') {
        h->esc_len = 0;
        return 0;
    }
    h->esc[h->esc_len++] = c;
    if (h->esc_len >= 3 && ((c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || c == '~')) {
        h->esc[h->esc_len] = '\0';
        apply_escape(h);
        h->esc_len = 0;
    } else if (h->esc_len >= ESC_MAX - 1)
        h->esc_len = 0; /* too long to be ours: drop it */
    return 1;
}

static void apply_key(dev_handle *h, char c, int64_t now)
{
    h->release_us = now + KEY_HOLD_MS * 1000;
    if (escape_byte(h, c))
        return;
    int sign, a = key_axis(c, &sign);
    if (a >= 0) {
        h->v[a] = sign * KEY_LEVEL;
        h->pending |= PENDING_MOTION;
    } else if ((c >= '1' && c <= '9') || c == '0' || c == 'm') {
        h->buttons |= 1u << (c >= '1' && c <= '9' ? c - '1' : 9); /* 0 and m: button 10 */
        h->pending |= PENDING_BUTTONS;
    } else if (c == '?' || c == 'h') {
        h->buttons |= 1u << 10; /* navigate shows its keys */
        h->pending |= PENDING_BUTTONS;
    } else if (c == 'g' || c == 'v' || c == 'b') {
        h->buttons |= 1u << (c == 'g' ? 11 : c == 'v' ? 12 : 13); /* fit, preview, accept */
        h->pending |= PENDING_BUTTONS;
    } else if (c == 'q') {
        raise(SIGINT);
    } else if (c == ' ' || c == 'x') {
        memset(h->v, 0, sizeof h->v);
        h->pending |= PENDING_MOTION;
    }
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
    *t_us = fnclock_now_us();
    if (h->pending)
        return next_report(h, buf);
    if (held(h)) { /* wake up when the hold expires */
        int left_ms = h->release_us > *t_us ? (int)((h->release_us - *t_us + 999) / 1000) : 0;
        timeout_ms = timeout_ms < 0 || timeout_ms > left_ms ? left_ms : timeout_ms;
    }
    /* At the end of a key file only the feed is polled: the device waits like a quiet terminal. */
    struct pollfd p[2] = {{h->fd_done ? -1 : h->fd, POLLIN, 0}, {h->feed[0], POLLIN, 0}};
    ssize_t n = 0;
    if (poll(p, 2, timeout_ms) > 0)
        for (int f = 0; f < 2; f++) {
            char keys[32];
            ssize_t got = p[f].revents ? read(p[f].fd, keys, sizeof keys) : -1;
            h->fd_done |= f == 0 && got == 0;
            *t_us = fnclock_now_us();
            for (ssize_t i = 0; i < got; i++)
                apply_key(h, keys[i], *t_us);
            n += got > 0 ? got : 0;
        }
    *t_us = fnclock_now_us();
    if (n <= 0 && held(h) && *t_us >= h->release_us) {
        h->pending = (h->buttons ? PENDING_BUTTONS : 0) | PENDING_MOTION;
        h->buttons = 0;
        memset(h->v, 0, sizeof h->v);
    }
    return next_report(h, buf);
}

static int kb_feed_keys(dev_handle *h, const char *bytes, size_t n)
{
    ssize_t put = write(h->feed[1], bytes, n);
    if (put != (ssize_t)n)
        return fn_err_set(FN_EIO, "keyboard: %zu keys from the window were dropped: %s", n,
                          put < 0 ? strerror(errno) : "the pipe is full");
    return 0;
}

static int kb_info(dev_handle *h, dev_info *out)
{
    memset(out, 0, sizeof *out);
    strcpy(out->path, "keyboard");
    strcpy(out->name, "keyboard+mouse fallback (a/d w/s r/f, i/k j/l u/o, 0-9, m, q, mouse drag)");
    return 0;
}

static void kb_close(dev_handle *h)
{
    if (h->raw_mode) {
        if (isatty(STDOUT_FILENO))
            (void)!write(STDOUT_FILENO, MOUSE_OFF, sizeof MOUSE_OFF - 1);
        tcsetattr(h->fd, TCSANOW, &h->saved);
    }
    if (h->own_fd)
        close(h->fd);
    close(h->feed[0]);
    close(h->feed[1]);
    free(h);
}

static void kb_describe(char *buf, size_t cap)
{
    snprintf(buf, cap, "fallback on a terminal (--device keyboard)");
}

const dev_transport dev__keyboard_transport = {
    .name = "keyboard",
    .caps = DEV_CAP_TERMINAL,
    .help_button = 11,
    .synthetic_row = "keyboard",
    .open = kb_open,
    .read = kb_read,
    .info = kb_info,
    .close = kb_close,
    .describe = kb_describe,
    .feed_keys = kb_feed_keys,
};
