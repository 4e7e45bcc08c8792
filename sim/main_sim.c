/* fracnav-sim: serves the virtual 6-DOF controller as a hidraw node through FUSE.
 *
 * One thread, one poll loop over the FUSE channel, a timer (the report cadence) and a signalfd.
 * Reads that find no report are not answered until one arrives (the kernel keeps them waiting),
 * so blocking reads, poll() wake-ups and timeouts in the reader behave as on a real hidraw node;
 * nothing in a request handler ever blocks. */
#define FUSE_USE_VERSION 35

#include <ctype.h>
#include <errno.h>
#include <fcntl.h>
#include <fuse_lowlevel.h>
#include <inttypes.h>
#include <linux/hidraw.h>
#include <poll.h>
#include <signal.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/signalfd.h>
#include <sys/stat.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#include "bench_sim.h"
#include "err.h"
#include "fnrec.h"
#include "script.h"
#include "simdev.h"

#define NODE_INO 2
#define NODE_NAME "hidraw0"
#define QUEUE_LEN 64 /* reports the kernel queues per hidraw reader */
#define PENDING_MAX 4

typedef struct reader {
    struct reader *next;
    uint8_t q[QUEUE_LEN][DEV_REPORT_MAX];
    uint8_t qlen[QUEUE_LEN];
    int head, count;
    fuse_req_t pending[PENDING_MAX]; /* reads waiting for a report */
    size_t pending_size[PENDING_MAX];
    int npending;
    struct fuse_pollhandle *ph;
    int dead;   /* opened before an unplug */
    int active; /* has read or polled: a reader, not a probe that only asks for ioctls */
} reader;

typedef struct server {
    struct fuse_session *se;
    const sim_profile *p;
    fnrec *rec;           /* what the device plays */
    script *script;       /* its script, rendered again when playback starts (NULL: --play) */
    size_t pos;
    int started, start_on_read, fast, exit_at_end;
    int64_t t0_us;        /* monotonic time of the recording's t = 0 */
    int plugged;
    simdev dev;           /* LED and feature reports */
    fnrec_header id;      /* identity served: descriptor, name, vid/pid */
    const char *serial;   /* HIDIOCGRAWUNIQ */
    reader *readers;
    int timer_fd, sig_fd;
    int ctl_fd, ctl_keep;  /* --control FIFO: read end, and a write end that keeps it from EOF */
    char ctl_line[1024];
    size_t ctl_len;
    uint32_t ctl_buttons;  /* buttons held down by control commands */
    fnrec_writer *log;    /* --log: every event served */
    int64_t log_t0;
    uint64_t served, dropped;
} server;

static server S;

static int64_t mono_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

static void log_event(fnrec_dir dir, const uint8_t *b, size_t n)
{
    if (!S.log)
        return;
    fnrec_event e = {.t_us = mono_us() - S.log_t0, .dir = dir, .len = (uint8_t)n};
    if (n)
        memcpy(e.data, b, n);
    if (fnrec_writer_event(S.log, &e)) {
        fprintf(stderr, "fracnav-sim: %s (log stopped)\n", fn_err_msg());
        fnrec_writer_close(S.log);
        S.log = NULL;
    }
}

/* ---- readers: the per-open queue of the hidraw node ---- */

static void notify_poll(reader *r)
{
    if (r->ph) {
        fuse_lowlevel_notify_poll(r->ph);
        fuse_pollhandle_destroy(r->ph);
        r->ph = NULL;
    }
}

static void reply_report(fuse_req_t req, size_t size, const uint8_t *b, size_t n)
{
    fuse_reply_buf(req, (const char *)b, n < size ? n : size);
}

static void drop_pending(reader *r, int i)
{
    r->npending--;
    memmove(&r->pending[i], &r->pending[i + 1], (size_t)(r->npending - i) * sizeof *r->pending);
    memmove(&r->pending_size[i], &r->pending_size[i + 1],
            (size_t)(r->npending - i) * sizeof *r->pending_size);
}

static void pump(void);

/* A report reaches every open reader: a waiting read gets it at once, else it is queued; a full
 * queue drops the new report, as hidraw does. */
static void deliver(const uint8_t *b, size_t n)
{
    S.served++;
    log_event(FNREC_IN, b, n);
    for (reader *r = S.readers; r; r = r->next) {
        if (r->dead || (!r->active && S.dev.battery_pending))
            continue; /* a reader opened after a live replug gets the power-on reports first */
        if (r->npending) {
            fuse_req_t req = r->pending[0];
            size_t size = r->pending_size[0];
            drop_pending(r, 0);
            reply_report(req, size, b, n);
        } else if (r->count < QUEUE_LEN) {
            int slot = (r->head + r->count++) % QUEUE_LEN;
            memcpy(r->q[slot], b, n);
            r->qlen[slot] = (uint8_t)n;
        } else {
            S.dropped++;
        }
        notify_poll(r);
    }
}

static void kill_readers(void)
{
    for (reader *r = S.readers; r; r = r->next) {
        r->dead = 1;
        while (r->npending) {
            fuse_req_t req = r->pending[0];
            drop_pending(r, 0);
            fuse_reply_err(req, EIO);
        }
        notify_poll(r);
    }
}

/* A device powering on sends its power-on reports (battery 0x17) after enumeration, that is once
 * someone has the node open and reading: a live replug owes them to the next active reader. */
static void power_on_reports(void)
{
    int any = 0;
    for (reader *r = S.readers; r; r = r->next)
        any |= !r->dead && r->active;
    uint8_t b[DEV_REPORT_MAX];
    int n;
    while (any && S.plugged && S.dev.battery_pending && (n = simdev_next(&S.dev, b, sizeof b)) > 0)
        deliver(b, (size_t)n);
}

/* live: by SIGUSR1 or a control line; a replug in the recording already holds its own reports. */
static void set_plugged(int on, int live)
{
    if (on == S.plugged)
        return;
    S.plugged = on;
    if (!on) {
        kill_readers();
        log_event(FNREC_DISCONNECT, NULL, 0);
    } else {
        simdev_replug(&S.dev);
        S.dev.battery_pending = live && S.dev.battery_pending;
        log_event(FNREC_CONNECT, NULL, 0);
    }
    fprintf(stderr, "fracnav-sim: %s\n", on ? "replugged" : "unplugged");
}

/* ---- the playback clock ---- */

static void arm_timer(int64_t at_us)
{
    struct itimerspec it = {{0, 0}, {0, 0}};
    if (at_us > 0) {
        it.it_value.tv_sec = at_us / 1000000;
        it.it_value.tv_nsec = (long)(at_us % 1000000) * 1000;
    }
    timerfd_settime(S.timer_fd, TFD_TIMER_ABSTIME, &it, NULL);
}

static int room_for_fast(void)
{
    int any = 0;
    for (reader *r = S.readers; r; r = r->next)
        if (!r->dead && r->active) {
            if (r->count >= QUEUE_LEN)
                return 0;
            any = 1;
        }
    return any;
}

static int queues_empty(void)
{
    for (reader *r = S.readers; r; r = r->next)
        if (!r->dead && r->active && r->count)
            return 0;
    return 1;
}

/* A script plays on the device as the host has set it up by now (open controller: 0x21, 0x22). */
static void start_playback(void)
{
    fnrec *r = S.script ? script_render_live(S.script, &S.dev) : NULL;
    if (r) {
        fnrec_free(S.rec);
        S.rec = r;
    }
    S.started = 1;
    S.t0_us = mono_us() + 1000;
    pump();
}

/* Plays every event that is due; arms the timer for the next one. In --fast mode events go out
 * as fast as the readers take them. */
static void pump(void)
{
    if (!S.started)
        return;
    int64_t now = mono_us();
    while (S.pos < S.rec->n) {
        const fnrec_event *e = &S.rec->ev[S.pos];
        if (S.fast ? !room_for_fast() : S.t0_us + e->t_us > now)
            break;
        S.pos++;
        if (e->dir == FNREC_IN && S.plugged)
            deliver(e->data, e->len);
        else if (e->dir == FNREC_CONNECT)
            set_plugged(1, 0);
        else if (e->dir == FNREC_DISCONNECT)
            set_plugged(0, 0);
    }
    if (S.pos < S.rec->n && !S.fast)
        arm_timer(S.t0_us + S.rec->ev[S.pos].t_us);
    else if (S.pos >= S.rec->n && S.exit_at_end && queues_empty())
        fuse_session_exit(S.se);
}

/* ---- FUSE operations ---- */

static void node_attr(struct stat *st, fuse_ino_t ino)
{
    memset(st, 0, sizeof *st);
    st->st_ino = ino;
    st->st_mode = ino == FUSE_ROOT_ID ? S_IFDIR | 0755 : S_IFREG | 0666;
    st->st_nlink = ino == FUSE_ROOT_ID ? 2 : 1;
}

static void op_lookup(fuse_req_t req, fuse_ino_t parent, const char *name)
{
    if (parent != FUSE_ROOT_ID || strcmp(name, NODE_NAME) || !S.plugged) {
        fuse_reply_err(req, ENOENT);
        return;
    }
    struct fuse_entry_param e = {.ino = NODE_INO, .attr_timeout = 0, .entry_timeout = 0};
    node_attr(&e.attr, NODE_INO);
    fuse_reply_entry(req, &e);
}

static void op_getattr(fuse_req_t req, fuse_ino_t ino, struct fuse_file_info *fi)
{
    struct stat st;
    if (ino != FUSE_ROOT_ID && ino != NODE_INO) {
        fuse_reply_err(req, ENOENT);
        return;
    }
    node_attr(&st, ino);
    fuse_reply_attr(req, &st, 0);
}

static void op_readdir(fuse_req_t req, fuse_ino_t ino, size_t size, off_t off,
                       struct fuse_file_info *fi)
{
    char buf[512];
    size_t n = 0;
    struct stat st;
    const char *names[] = {".", "..", NODE_NAME};
    int count = S.plugged ? 3 : 2;
    for (int i = (int)off; i < count; i++) {
        node_attr(&st, i == 2 ? NODE_INO : FUSE_ROOT_ID);
        size_t need = fuse_add_direntry(req, buf + n, sizeof buf - n, names[i], &st, i + 1);
        if (need > sizeof buf - n || n + need > size)
            break;
        n += need;
    }
    fuse_reply_buf(req, buf, n);
}

static void op_open(fuse_req_t req, fuse_ino_t ino, struct fuse_file_info *fi)
{
    if (ino != NODE_INO || !S.plugged) {
        fuse_reply_err(req, ino == NODE_INO ? ENODEV : EISDIR);
        return;
    }
    reader *r = calloc(1, sizeof *r);
    if (!r) {
        fuse_reply_err(req, ENOMEM);
        return;
    }
    r->next = S.readers;
    S.readers = r;
    fi->fh = (uint64_t)(uintptr_t)r;
    fi->direct_io = 1;
    fi->nonseekable = 1;
    fuse_reply_open(req, fi);
}

/* The first read or poll of a reader starts --start-on-read playback and lets --fast go on. */
static void reader_active(reader *r)
{
    if (r->active)
        return;
    r->active = 1;
    power_on_reports();
    if (S.start_on_read && !S.started)
        start_playback();
    else if (S.fast)
        pump();
}

static void op_release(fuse_req_t req, fuse_ino_t ino, struct fuse_file_info *fi)
{
    reader *r = (reader *)(uintptr_t)fi->fh;
    for (reader **pp = &S.readers; *pp; pp = &(*pp)->next)
        if (*pp == r) {
            *pp = r->next;
            break;
        }
    while (r->npending) {
        fuse_req_t q = r->pending[0];
        drop_pending(r, 0);
        fuse_reply_err(q, EIO);
    }
    if (r->ph)
        fuse_pollhandle_destroy(r->ph);
    free(r);
    fuse_reply_err(req, 0);
}

static void on_interrupt(fuse_req_t req, void *data)
{
    reader *r = data;
    for (int i = 0; i < r->npending; i++)
        if (r->pending[i] == req) {
            drop_pending(r, i);
            fuse_reply_err(req, EINTR);
            return;
        }
}

static void op_read(fuse_req_t req, fuse_ino_t ino, size_t size, off_t off, struct fuse_file_info *fi)
{
    reader *r = (reader *)(uintptr_t)fi->fh;
    reader_active(r);
    if (r->dead) {
        fuse_reply_err(req, EIO);
    } else if (r->count) {
        int slot = r->head;
        r->head = (r->head + 1) % QUEUE_LEN;
        r->count--;
        reply_report(req, size, r->q[slot], r->qlen[slot]);
        if (S.fast || S.exit_at_end)
            pump();
    } else if ((fi->flags & O_NONBLOCK) || r->npending == PENDING_MAX) {
        fuse_reply_err(req, EAGAIN);
    } else {
        r->pending[r->npending] = req;
        r->pending_size[r->npending++] = size;
        fuse_req_interrupt_func(req, on_interrupt, r);
    }
}

static void op_write(fuse_req_t req, fuse_ino_t ino, const char *buf, size_t size, off_t off,
                     struct fuse_file_info *fi)
{
    reader *r = (reader *)(uintptr_t)fi->fh;
    if (r->dead) {
        fuse_reply_err(req, EIO);
        return;
    }
    log_event(FNREC_OUT, (const uint8_t *)buf, size > DEV_REPORT_MAX ? DEV_REPORT_MAX : size);
    if (simdev_output(&S.dev, (const uint8_t *)buf, size) < 0)
        fuse_reply_err(req, EPIPE); /* the device stalls an unknown report */
    else
        fuse_reply_write(req, size);
}

static void op_poll(fuse_req_t req, fuse_ino_t ino, struct fuse_file_info *fi,
                    struct fuse_pollhandle *ph)
{
    reader *r = (reader *)(uintptr_t)fi->fh;
    reader_active(r);
    if (ph) {
        if (r->ph)
            fuse_pollhandle_destroy(r->ph);
        r->ph = ph;
    }
    unsigned ev = POLLOUT | POLLWRNORM;
    if (r->count)
        ev |= POLLIN | POLLRDNORM;
    if (r->dead)
        ev |= POLLERR | POLLHUP;
    fuse_reply_poll(req, ev);
}

/* Copies a string the way hidraw does: NUL included, cut to the caller's size. */
static void reply_string(fuse_req_t req, const char *s, size_t cap)
{
    size_t n = strlen(s) + 1;
    if (n > cap)
        n = cap;
    fuse_reply_ioctl(req, (int)n, s, n);
}

static void feature_ioctl(fuse_req_t req, int set, const void *in, size_t in_sz, size_t out_sz)
{
    uint8_t buf[DEV_REPORT_MAX] = {0};
    size_t n = in_sz < sizeof buf ? in_sz : sizeof buf;
    if (n == 0) {
        fuse_reply_err(req, EINVAL);
        return;
    }
    memcpy(buf, in, n);
    int rc = set ? simdev_set_feature(&S.dev, buf, n) : simdev_get_feature(&S.dev, buf, n);
    if (rc < 0) {
        fuse_reply_err(req, EPIPE);
        return;
    }
    log_event(FNREC_FEATURE, buf, (size_t)rc); /* the report as set, or as the device answered */
    fuse_reply_ioctl(req, rc, buf, out_sz < sizeof buf ? out_sz : sizeof buf);
}

static void op_ioctl(fuse_req_t req, fuse_ino_t ino, unsigned int cmd, void *arg,
                     struct fuse_file_info *fi, unsigned flags, const void *in_buf, size_t in_bufsz,
                     size_t out_bufsz)
{
    reader *r = (reader *)(uintptr_t)fi->fh;
    if (flags & FUSE_IOCTL_COMPAT || _IOC_TYPE(cmd) != 'H') {
        fuse_reply_err(req, ENOTTY);
        return;
    }
    if (r->dead) {
        fuse_reply_err(req, ENODEV);
        return;
    }
    size_t sz = _IOC_SIZE(cmd);
    switch (_IOC_NR(cmd)) {
    case _IOC_NR(HIDIOCGRDESCSIZE): {
        int n = (int)S.id.desc_len;
        fuse_reply_ioctl(req, 0, &n, sizeof n);
        return;
    }
    case _IOC_NR(HIDIOCGRDESC): {
        static struct hidraw_report_descriptor d;
        d.size = (uint32_t)S.id.desc_len;
        memcpy(d.value, S.id.desc, S.id.desc_len);
        fuse_reply_ioctl(req, 0, &d, sizeof d < out_bufsz ? sizeof d : out_bufsz);
        return;
    }
    case _IOC_NR(HIDIOCGRAWINFO): {
        struct hidraw_devinfo di = {SIMDEV_BUS_USB, (int16_t)S.id.vid, (int16_t)S.id.pid};
        fuse_reply_ioctl(req, 0, &di, sizeof di);
        return;
    }
    case _IOC_NR(HIDIOCGRAWNAME(0)):
        reply_string(req, S.id.name, sz);
        return;
    case _IOC_NR(HIDIOCGRAWPHYS(0)):
        reply_string(req, "fracnav-sim/input0", sz);
        return;
    case _IOC_NR(HIDIOCGRAWUNIQ(0)):
        reply_string(req, S.serial, sz);
        return;
    case _IOC_NR(HIDIOCGFEATURE(0)):
    case _IOC_NR(HIDIOCSFEATURE(0)):
        feature_ioctl(req, _IOC_NR(cmd) == _IOC_NR(HIDIOCSFEATURE(0)), in_buf, in_bufsz, out_bufsz);
        return;
    }
    fuse_reply_err(req, EINVAL);
}

static const struct fuse_lowlevel_ops ops = {
    .lookup = op_lookup,
    .getattr = op_getattr,
    .readdir = op_readdir,
    .open = op_open,
    .release = op_release,
    .read = op_read,
    .write = op_write,
    .poll = op_poll,
    .ioctl = op_ioctl,
};

/* ---- the loop ---- */

static int handle_signal(void)
{
    struct signalfd_siginfo si;
    if (read(S.sig_fd, &si, sizeof si) != (ssize_t)sizeof si)
        return 0;
    if (si.ssi_signo == SIGUSR1) {
        set_plugged(!S.plugged, 1);
        return 0;
    }
    return 1; /* SIGINT, SIGTERM, SIGHUP: stop */
}

/* ---- the control FIFO: script lines played at once ---- */

/* A control line plays its script now, or after what is still playing; the buttons held carry
 * over from one line to the next. */
static void control_command(const char *line)
{
    script *sc = NULL;
    if (script_parse(line, strlen(line), "control", &sc)) {
        fprintf(stderr, "fracnav-sim: %s\n", fn_err_msg());
        return;
    }
    fnrec *r = NULL;
    if (sc->n == 1 && (sc->step[0].op == SCRIPT_UNPLUG || sc->step[0].op == SCRIPT_REPLUG))
        set_plugged(sc->step[0].op == SCRIPT_REPLUG, 1);
    else if (sc->n && !(r = script_render_more(sc, &S.dev, &S.ctl_buttons)))
        fprintf(stderr, "fracnav-sim: %s\n", fn_err_msg());
    free(sc);
    if (r && S.started && S.pos < S.rec->n) { /* still playing: queue it after the rest */
        int64_t at = S.rec->ev[S.rec->n - 1].t_us;
        for (size_t i = 0; i < r->n; i++) {
            r->ev[i].t_us += at;
            if (fnrec_append(S.rec, &r->ev[i]))
                fprintf(stderr, "fracnav-sim: %s\n", fn_err_msg());
        }
        fnrec_free(r);
    } else if (r) {
        fnrec_free(S.rec);
        S.rec = r;
        S.pos = 0;
        S.started = 1;
        S.t0_us = mono_us();
        pump();
    }
}

static void control_input(void)
{
    ssize_t n = read(S.ctl_fd, S.ctl_line + S.ctl_len, sizeof S.ctl_line - 1 - S.ctl_len);
    if (n <= 0)
        return;
    S.ctl_len += (size_t)n;
    char *nl;
    while ((nl = memchr(S.ctl_line, '\n', S.ctl_len))) {
        *nl = '\0';
        fn_err_clear();
        control_command(S.ctl_line);
        S.ctl_len -= (size_t)(nl + 1 - S.ctl_line);
        memmove(S.ctl_line, nl + 1, S.ctl_len);
    }
    if (S.ctl_len == sizeof S.ctl_line - 1) {
        fprintf(stderr, "fracnav-sim: control line too long, dropped\n");
        S.ctl_len = 0;
    }
}

static int open_control(const char *path)
{
    struct stat st;
    if (stat(path, &st) ? mkfifo(path, 0600) : !S_ISFIFO(st.st_mode) ? (errno = EEXIST, -1) : 0) {
        fprintf(stderr, "fracnav-sim serve: cannot make the control FIFO %s: %s\n", path,
                strerror(errno));
        return -1;
    }
    S.ctl_fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    S.ctl_keep = open(path, O_WRONLY | O_NONBLOCK | O_CLOEXEC);
    if (S.ctl_fd < 0 || S.ctl_keep < 0) {
        fprintf(stderr, "fracnav-sim serve: cannot open the control FIFO %s: %s\n", path,
                strerror(errno));
        return -1;
    }
    return 0;
}

static int serve_loop(void)
{
    struct fuse_buf fbuf = {0};
    struct pollfd pf[4] = {{fuse_session_fd(S.se), POLLIN, 0}, {S.timer_fd, POLLIN, 0},
                           {S.sig_fd, POLLIN, 0}, {S.ctl_fd, POLLIN, 0}};
    int rc = 0;
    while (!fuse_session_exited(S.se)) {
        if (poll(pf, 4, -1) < 0) {
            if (errno == EINTR)
                continue;
            rc = -errno;
            break;
        }
        if (pf[2].revents && handle_signal())
            break;
        if (pf[3].revents)
            control_input();
        if (pf[1].revents) {
            uint64_t ticks;
            if (read(S.timer_fd, &ticks, sizeof ticks) < 0 && errno != EAGAIN)
                break;
            pump();
        }
        if (pf[0].revents) {
            int n = fuse_session_receive_buf(S.se, &fbuf);
            if (n == -EINTR || n == -EAGAIN)
                continue;
            if (n <= 0) { /* unmounted from outside (fusermount3 -u) */
                rc = n;
                break;
            }
            fuse_session_process_buf(S.se, &fbuf);
        }
    }
    free(fbuf.mem);
    return rc;
}

static int block_signals(void)
{
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGTERM);
    sigaddset(&set, SIGHUP);
    sigaddset(&set, SIGUSR1);
    sigprocmask(SIG_BLOCK, &set, NULL);
    /* A shell starts background jobs with SIGINT ignored; ignored signals never reach a signalfd. */
    signal(SIGINT, SIG_DFL);
    signal(SIGTERM, SIG_DFL);
    signal(SIGHUP, SIG_DFL);
    signal(SIGPIPE, SIG_IGN);
    S.sig_fd = signalfd(-1, &set, SFD_CLOEXEC | SFD_NONBLOCK);
    S.timer_fd = timerfd_create(CLOCK_MONOTONIC, TFD_CLOEXEC | TFD_NONBLOCK);
    return S.sig_fd < 0 || S.timer_fd < 0 ? -1 : 0;
}

/* Says plainly why FUSE cannot be used, before libfuse says it less plainly. */
static int check_fuse_access(const char *mount)
{
    struct stat st;
    if (stat(mount, &st)) {
        fprintf(stderr, "fracnav-sim serve: mount point %s %s\n", mount,
                errno == ENOENT ? "does not exist (mkdir it first)" : strerror(errno));
        return -1;
    }
    if (!S_ISDIR(st.st_mode)) {
        fprintf(stderr, "fracnav-sim serve: mount point %s is not a directory\n", mount);
        return -1;
    }
    if (access("/dev/fuse", R_OK | W_OK)) {
        fprintf(stderr, "fracnav-sim serve: cannot use /dev/fuse (%s): serving the virtual device "
                        "needs FUSE: run as root, or give this user read/write access to /dev/fuse "
                        "(fuse3 package); without FUSE use the in-process transport "
                        "'virtual:DEVICE' instead\n", strerror(errno));
        return -1;
    }
    if (geteuid() != 0 && access("/usr/bin/fusermount3", X_OK) && access("/bin/fusermount3", X_OK)) {
        fprintf(stderr, "fracnav-sim serve: not root and no fusermount3: mounting needs root or the "
                        "fuse3 package's setuid fusermount3\n");
        return -1;
    }
    return 0;
}

static void teardown(const char *mount)
{
    kill_readers(); /* waiting reads end with EIO, as on a real unplug */
    fuse_session_unmount(S.se);
    fuse_session_destroy(S.se);
    while (S.readers) {
        reader *r = S.readers;
        S.readers = r->next;
        free(r);
    }
    fprintf(stderr, "fracnav-sim: unmounted %s (%" PRIu64 " reports served, %" PRIu64
                    " dropped by full reader queues)\n", mount, S.served, S.dropped);
}

static int serve(const char *mount, const char *control)
{
    if (check_fuse_access(mount) || (control && open_control(control)))
        return 1;
    if (block_signals()) {
        fprintf(stderr, "fracnav-sim serve: cannot create the signal or timer descriptor: %s\n",
                strerror(errno));
        return 1;
    }
    char *argv[] = {"fracnav-sim", "-o", "fsname=fracnav-sim,subtype=hidraw", NULL};
    struct fuse_args args = FUSE_ARGS_INIT(3, argv);
    S.se = fuse_session_new(&args, &ops, sizeof ops, NULL);
    fuse_opt_free_args(&args);
    if (!S.se || fuse_session_mount(S.se, mount)) {
        fprintf(stderr, "fracnav-sim serve: cannot mount FUSE on %s (need root or FUSE permission; "
                        "is something already mounted there?)\n", mount);
        if (S.se)
            fuse_session_destroy(S.se);
        return 1;
    }
    fprintf(stderr, "fracnav-sim: serving %s (%04x:%04x) at %s/" NODE_NAME "\n", S.id.name, S.id.vid,
            S.id.pid, mount);
    S.log_t0 = mono_us();
    if (!S.start_on_read)
        start_playback();
    int rc = serve_loop();
    teardown(mount);
    return rc < 0 ? 1 : 0;
}

/* ---- command line ---- */

static void usage(FILE *f)
{
    fprintf(f,
            "usage: fracnav-sim serve --mount DIR [--as DEVICE] [--play FILE.fnrec | --script FILE]\n"
            "                         [--start-on-read] [--fast] [--exit-at-end] [--log FILE.fnrec]\n"
            "                         [--control FIFO] [--serial SN]\n"
            "       fracnav-sim render [--as DEVICE] --script FILE -o FILE.fnrec\n"
            "       fracnav-sim list\n"
            "       fracnav-sim bench [--mount DIR] [--seconds S]\n"
            "\n"
            "serve    serves the virtual device as DIR/" NODE_NAME " through FUSE until SIGINT/SIGTERM\n"
            "         (then unmounts). SIGUSR1 unplugs it, the next SIGUSR1 plugs it back.\n"
            "         --as DEVICE      device to impersonate, by name or VID:PID (default\n"
            "                          spacenavigator; list shows every row of the table)\n"
            "         --play FILE      play a recording (its identity replaces --as)\n"
            "         --script FILE    play a motion script (see sim/script.h)\n"
            "         --start-on-read  start playing when the node is first read or polled\n"
            "         --fast           play as fast as the readers read (implies --start-on-read)\n"
            "         --exit-at-end    unmount and exit once the playback is over and read\n"
            "         --log FILE       write every report served to a .fnrec file\n"
            "         --control FIFO   script lines written to this FIFO (made if absent) play in\n"
            "                          turn, as soon as possible: echo 'press 1' > FIFO\n"
            "         --serial SN      serial number served (HIDIOCGRAWUNIQ; 8-32 characters;\n"
            "                          default FNSIM + VID + PID)\n"
            "render   writes the reports a script produces on DEVICE to a .fnrec file\n"
            "list     prints the devices the simulator can impersonate\n"
            "bench    measures report throughput (as fast as possible) and timing jitter (at the\n"
            "         8 ms cadence, S seconds, default 2) through FUSE and hidapi; prints JSON\n");
}

static int list_devices(void)
{
    for (size_t i = 0; sim_profile_at(i); i++) {
        const sim_profile *p = sim_profile_at(i);
        printf("%-34s %04x:%04x  %-8s %2d ms  %2d button bits  %s\n", p->id, p->vid, p->pid,
               devtab_format_name(p->row->format), p->period_us / 1000, p->nbuttons,
               p->name);
    }
    return 0;
}

typedef struct opts {
    const char *mount, *as, *play, *script, *out, *log, *seconds, *control, *serial;
} opts;

enum { SERVE = 1, RENDER = 2, BENCH = 4 };

/* Each option and the commands it applies to: any other is a usage error that names it. */
static const struct option_def {
    const char *name;
    unsigned cmds;
    size_t field; /* offsetof(opts, ...) for options with a value, else SIZE_MAX */
    int *flag;
} option_defs[] = {
    {"--mount", SERVE | BENCH, offsetof(opts, mount), NULL},
    {"--as", SERVE | RENDER, offsetof(opts, as), NULL},
    {"--play", SERVE, offsetof(opts, play), NULL},
    {"--script", SERVE | RENDER, offsetof(opts, script), NULL},
    {"-o", RENDER, offsetof(opts, out), NULL},
    {"--log", SERVE, offsetof(opts, log), NULL},
    {"--seconds", BENCH, offsetof(opts, seconds), NULL},
    {"--control", SERVE, offsetof(opts, control), NULL},
    {"--serial", SERVE, offsetof(opts, serial), NULL},
    {"--start-on-read", SERVE, SIZE_MAX, &S.start_on_read},
    {"--fast", SERVE, SIZE_MAX, &S.fast},
    {"--exit-at-end", SERVE, SIZE_MAX, &S.exit_at_end},
};

static unsigned command_bit(const char *cmd)
{
    return !strcmp(cmd, "serve") ? SERVE : !strcmp(cmd, "render") ? RENDER : BENCH;
}

/* firmware-spec/open-controller.md, 1: a serial number is 8-32 characters. */
static int serial_ok(const char *s)
{
    size_t n = strlen(s);
    if (n < 8 || n >= SIMDEV_SERIAL_MAX)
        return 0;
    for (; *s; s++)
        if (!isalnum((unsigned char)*s) && *s != '-' && *s != '_')
            return 0;
    return 1;
}

static int parse_opts(int argc, char **argv, opts *o)
{
    unsigned cmd = command_bit(argv[1]);
    for (int i = 2; i < argc; i++) {
        const char *a = argv[i];
        const struct option_def *d = NULL;
        for (size_t k = 0; k < sizeof option_defs / sizeof *option_defs && !d; k++)
            d = !strcmp(a, option_defs[k].name) ? &option_defs[k] : NULL;
        if (!d) {
            fprintf(stderr, "fracnav-sim %s: unknown option '%s'\n", argv[1], a);
            return -1;
        }
        if (!(d->cmds & cmd)) {
            fprintf(stderr, "fracnav-sim %s: option '%s' does not apply to %s (--help)\n", argv[1], a,
                    argv[1]);
            return -1;
        }
        if (d->flag) {
            *d->flag = 1;
            continue;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "fracnav-sim %s: %s needs a value\n", argv[1], a);
            return -1;
        }
        *(const char **)((char *)o + d->field) = argv[++i];
    }
    S.start_on_read |= S.fast;
    if (o->serial && !serial_ok(o->serial)) {
        fprintf(stderr, "fracnav-sim %s: --serial '%s': want 8 to 32 letters, digits, '-' or '_'\n",
                argv[1], o->serial);
        return -1;
    }
    if (o->play && o->script) {
        fprintf(stderr, "fracnav-sim %s: --play and --script exclude each other\n", argv[1]);
        return -1;
    }
    return 0;
}

/* The recording the device plays: a file, a rendered script, or nothing (an idle device). */
static fnrec *load_source(const opts *o)
{
    if (o->play)
        return fnrec_load(o->play);
    if (o->script ? !(S.script = script_load(o->script)) : script_parse("", 0, "", &S.script) != 0)
        return NULL;
    return script_render(S.script, S.p);
}

static int setup(const opts *o)
{
    if (!(S.p = sim_profile_find(o->as ? o->as : "spacenavigator")) || !(S.rec = load_source(o)))
        return -1;
    if (o->play) {
        char id[16];
        snprintf(id, sizeof id, "%04x:%04x", S.rec->hdr.vid, S.rec->hdr.pid);
        const sim_profile *p = sim_profile_find(id);
        if (o->as && p != S.p)
            fprintf(stderr, "fracnav-sim serve: warning: --as %s ignored: %s plays as the device it was "
                            "recorded from, %s (%s)\n", o->as, o->play, id, S.rec->hdr.name);
        S.p = p ? p : S.p;
        S.id = S.rec->hdr;
    } else {
        script_header(S.p, &S.id);
    }
    simdev_init(&S.dev, S.p);
    S.dev.battery_pending = 0; /* the source holds the power-on reports */
    S.serial = o->serial ? o->serial : S.p->serial;
    S.plugged = 1;
    if (o->log && !(S.log = fnrec_writer_open(o->log, &S.id)))
        return -1;
    return 0;
}

int main(int argc, char **argv)
{
    if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
        usage(argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    const char *cmd = argv[1];
    for (int i = 2; i < argc; i++)
        if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            usage(stdout);
            return 0;
        }
    if (!strcmp(cmd, "list"))
        return list_devices();
    opts o = {0};
    S.sig_fd = S.timer_fd = S.ctl_fd = S.ctl_keep = -1;
    if (strcmp(cmd, "serve") && strcmp(cmd, "render") && strcmp(cmd, "bench")) {
        fprintf(stderr, "fracnav-sim: unknown command '%s' (serve, render, list, bench; --help)\n", cmd);
        return 2;
    }
    if (parse_opts(argc, argv, &o))
        return 2;
    if (!strcmp(cmd, "bench")) {
        double secs = o.seconds ? atof(o.seconds) : 2.0;
        if (!(secs >= 0.1 && secs <= 600)) {
            fprintf(stderr, "fracnav-sim bench: --seconds wants 0.1 to 600\n");
            return 2;
        }
        return bench_sim_run(o.mount, secs);
    }
    if (!strcmp(cmd, "render") ? !o.script || !o.out : !o.mount) {
        fprintf(stderr, "fracnav-sim %s: %s is required\n", cmd,
                !strcmp(cmd, "render") ? "--script FILE and -o FILE" : "--mount DIR");
        return 2;
    }
    int rc = 1;
    if (setup(&o))
        fprintf(stderr, "fracnav-sim %s: %s\n", cmd, fn_err_msg());
    else if (!strcmp(cmd, "render"))
        rc = fnrec_save(S.rec, o.out) ? (fprintf(stderr, "fracnav-sim render: %s\n", fn_err_msg()), 1) : 0;
    else
        rc = serve(o.mount, o.control);
    if (S.log && fnrec_writer_close(S.log))
        fprintf(stderr, "fracnav-sim: %s\n", fn_err_msg());
    fnrec_free(S.rec);
    free(S.script);
    if (S.sig_fd >= 0)
        close(S.sig_fd);
    if (S.timer_fd >= 0)
        close(S.timer_fd);
    if (S.ctl_fd >= 0)
        close(S.ctl_fd);
    if (S.ctl_keep >= 0)
        close(S.ctl_keep);
    return rc;
}
