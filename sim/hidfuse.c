/* hidfuse: the virtual 6-DOF controller served as a hidraw node through FUSE (see hidfuse.h).
 *
 * One thread, one poll loop over the FUSE channel, a timer (the report cadence) and a signalfd.
 * Reads that find no report are not answered until one arrives (the kernel keeps them waiting),
 * so blocking reads, poll() wake-ups and timeouts in the reader behave as on a real hidraw node;
 * nothing in a request handler ever blocks. The server's state reaches the handlers as FUSE's
 * userdata; each reader's queue is a reportq. */
#define FUSE_USE_VERSION 35

#include "hidfuse.h"

#include <errno.h>
#include <fcntl.h>
#include <fuse_lowlevel.h>
#include <inttypes.h>
#include <limits.h>
#include <linux/hidraw.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/ioctl.h>
#include <sys/mount.h>
#include <sys/signalfd.h>
#include <sys/stat.h>
#include <sys/timerfd.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "err.h"
#include "fnclock.h"
#include "reportq.h"

#define NODE_INO 2

/* One open of the node. */
typedef struct reader {
    struct reader *next;
    reportq q;
    struct fuse_pollhandle *ph;
    int active; /* has read or polled: a reader, not a probe that only asks for ioctls */
} reader;

typedef struct hidfuse_server {
    struct fuse_session *se;
    hidfuse_source src;   /* the device and what it plays (src.rec is replaced as it plays) */
    size_t pos;
    int started;
    int64_t t0_us;        /* monotonic time of the recording's t = 0 */
    int plugged;
    simdev dev;           /* LED and feature reports */
    reader *readers;
    int timer_fd, sig_fd;
    int ctl_fd, ctl_keep;  /* --control FIFO: read end, and a write end that keeps it from EOF */
    char ctl_line[1024];
    size_t ctl_len;
    uint32_t ctl_buttons;  /* buttons held down by control commands */
    int64_t log_t0;
    uint64_t served, dropped;
    struct hidraw_report_descriptor rdesc; /* HIDIOCGRDESC's answer (4 KiB: not on the stack) */
} hidfuse_server;

static void log_event(hidfuse_server *srv, fnrec_dir dir, const uint8_t *b, size_t n)
{
    if (!srv->src.log)
        return;
    fnrec_event e = {.t_us = fnclock_now_us() - srv->log_t0, .dir = dir, .len = (uint8_t)n};
    if (n)
        memcpy(e.data, b, n);
    if (fnrec_writer_event(srv->src.log, &e)) {
        fprintf(stderr, "fracnav-sim: %s (log stopped)\n", fn_err_msg());
        fnrec_writer_close(srv->src.log);
        srv->src.log = NULL;
    }
}

/* ---- readers: the per-open queue of the hidraw node (reportq) ---- */

static void notify_poll(reader *r)
{
    if (r->ph) {
        fuse_lowlevel_notify_poll(r->ph);
        fuse_pollhandle_destroy(r->ph);
        r->ph = NULL;
    }
}

/* Answers every read still waiting on r with err. */
static void fail_waiters(reader *r, int err)
{
    reportq_waiter w;
    while (reportq_take_waiter(&r->q, &w))
        fuse_reply_err(w.req, err);
}

static void pump(hidfuse_server *srv);

/* A report reaches one reader: a waiting read gets it at once, else it is queued; a full queue
 * drops the new report, as hidraw does. */
static void deliver_to(hidfuse_server *srv, reader *r, const uint8_t *b, size_t n)
{
    reportq_waiter w;
    reportq_fate fate = reportq_push(&r->q, b, n, &w);
    if (fate == REPORTQ_DEAD)
        return;
    if (fate == REPORTQ_HANDED)
        fuse_reply_buf(w.req, (const char *)b, reportq_cut(n, w.size));
    srv->dropped += fate == REPORTQ_DROPPED;
    notify_poll(r);
}

/* A report reaches every open reader. */
static void deliver(hidfuse_server *srv, const uint8_t *b, size_t n)
{
    srv->served++;
    log_event(srv, FNREC_IN, b, n);
    for (reader *r = srv->readers; r; r = r->next)
        if (r->active || !srv->dev.battery_pending) /* after a live replug, the power-on reports first */
            deliver_to(srv, r, b, n);
}

static void kill_readers(hidfuse_server *srv)
{
    for (reader *r = srv->readers; r; r = r->next) {
        reportq_kill(&r->q);
        fail_waiters(r, EIO);
        notify_poll(r);
    }
}

/* A device powering on sends its power-on reports (battery 0x17) after enumeration, that is once
 * someone has the node open and reading: a live replug owes them to the next active reader. */
static void power_on_reports(hidfuse_server *srv)
{
    int any = 0;
    for (reader *r = srv->readers; r; r = r->next)
        any |= !r->q.dead && r->active;
    uint8_t b[DEV_REPORT_MAX];
    int n;
    while (any && srv->plugged && srv->dev.battery_pending && (n = simdev_next(&srv->dev, b, sizeof b)) > 0)
        deliver(srv, b, (size_t)n);
}

/* live: by SIGUSR1 or a control line; a replug in the recording already holds its own reports. */
static void set_plugged(hidfuse_server *srv, int on, int live)
{
    if (on == srv->plugged)
        return;
    srv->plugged = on;
    if (!on) {
        kill_readers(srv);
        log_event(srv, FNREC_DISCONNECT, NULL, 0);
    } else {
        simdev_replug(&srv->dev);
        srv->dev.battery_pending = live && srv->dev.battery_pending;
        log_event(srv, FNREC_CONNECT, NULL, 0);
    }
    fprintf(stderr, "fracnav-sim: %s\n", on ? "replugged" : "unplugged");
}

/* ---- the playback clock ---- */

static void arm_timer(hidfuse_server *srv, int64_t at_us)
{
    struct itimerspec it = {{0, 0}, {0, 0}};
    if (at_us > 0)
        it.it_value = fnclock_timespec(at_us);
    timerfd_settime(srv->timer_fd, TFD_TIMER_ABSTIME, &it, NULL);
}

static int room_for_fast(hidfuse_server *srv)
{
    int any = 0;
    for (reader *r = srv->readers; r; r = r->next)
        if (!r->q.dead && r->active) {
            if (r->q.count >= REPORTQ_LEN)
                return 0;
            any = 1;
        }
    return any;
}

static int queues_empty(hidfuse_server *srv)
{
    for (reader *r = srv->readers; r; r = r->next)
        if (!r->q.dead && r->active && r->q.count)
            return 0;
    return 1;
}

/* A script plays on the device as the host has set it up by now (open controller: 0x21, 0x22). */
static void start_playback(hidfuse_server *srv)
{
    fnrec *r = srv->src.script ? script_render_live(srv->src.script, &srv->dev) : NULL;
    if (r) {
        fnrec_free(srv->src.rec);
        srv->src.rec = r;
    }
    srv->started = 1;
    srv->t0_us = fnclock_now_us() + 1000;
    pump(srv);
}

/* Plays every event that is due; arms the timer for the next one. In --fast mode events go out
 * as fast as the readers take them. */
static void pump(hidfuse_server *srv)
{
    if (!srv->started)
        return;
    int64_t now = fnclock_now_us();
    while (srv->pos < srv->src.rec->n) {
        const fnrec_event *e = &srv->src.rec->ev[srv->pos];
        if (srv->src.fast ? !room_for_fast(srv) : srv->t0_us + e->t_us > now)
            break;
        srv->pos++;
        if (e->dir == FNREC_IN && srv->plugged)
            deliver(srv, e->data, e->len);
        else if (e->dir == FNREC_CONNECT)
            set_plugged(srv, 1, 0);
        else if (e->dir == FNREC_DISCONNECT)
            set_plugged(srv, 0, 0);
    }
    if (srv->pos < srv->src.rec->n && !srv->src.fast)
        arm_timer(srv, srv->t0_us + srv->src.rec->ev[srv->pos].t_us);
    else if (srv->pos >= srv->src.rec->n && srv->src.exit_at_end && queues_empty(srv))
        fuse_session_exit(srv->se);
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
    hidfuse_server *srv = fuse_req_userdata(req);
    if (parent != FUSE_ROOT_ID || strcmp(name, HIDFUSE_NODE) || !srv->plugged) {
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
    hidfuse_server *srv = fuse_req_userdata(req);
    char buf[512];
    size_t n = 0;
    struct stat st;
    const char *names[] = {".", "..", HIDFUSE_NODE};
    int count = srv->plugged ? 3 : 2;
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
    hidfuse_server *srv = fuse_req_userdata(req);
    if (ino != NODE_INO || !srv->plugged) {
        fuse_reply_err(req, ino == NODE_INO ? ENODEV : EISDIR);
        return;
    }
    reader *r = calloc(1, sizeof *r);
    if (!r) {
        fuse_reply_err(req, ENOMEM);
        return;
    }
    r->next = srv->readers;
    srv->readers = r;
    fi->fh = (uint64_t)(uintptr_t)r;
    fi->direct_io = 1;
    fi->nonseekable = 1;
    fuse_reply_open(req, fi);
}

/* A wireless device's battery level for a reader that came after the power-on report went out
 * (to no one, or to earlier readers): each program that opens the node learns the level, as each
 * one that opens the in-process virtual device does (`devices`, then `device-test`). */
static void battery_for_late_reader(hidfuse_server *srv, reader *r)
{
    simdev now = srv->dev;
    uint8_t b[DEV_REPORT_MAX];
    now.battery_pending = 1;
    int n = simdev_next(&now, b, sizeof b);
    if (n > 0 && b[0] == 0x17)
        deliver_to(srv, r, b, (size_t)n);
}

/* The first read or poll of a reader starts --start-on-read playback and lets --fast go on. */
static void reader_active(hidfuse_server *srv, reader *r)
{
    if (r->active)
        return;
    r->active = 1;
    int owed = srv->dev.battery_pending;
    power_on_reports(srv);
    /* A reader after the power-on reports gets the level; before them, they carry it. */
    if (srv->src.p->battery && srv->plugged && srv->started && !owed)
        battery_for_late_reader(srv, r);
    if (srv->src.start_on_read && !srv->started)
        start_playback(srv);
    else if (srv->src.fast)
        pump(srv);
}

static void op_release(fuse_req_t req, fuse_ino_t ino, struct fuse_file_info *fi)
{
    hidfuse_server *srv = fuse_req_userdata(req);
    reader *r = (reader *)(uintptr_t)fi->fh;
    for (reader **pp = &srv->readers; *pp; pp = &(*pp)->next)
        if (*pp == r) {
            *pp = r->next;
            break;
        }
    fail_waiters(r, EIO);
    if (r->ph)
        fuse_pollhandle_destroy(r->ph);
    free(r);
    fuse_reply_err(req, 0);
}

static void on_interrupt(fuse_req_t req, void *data)
{
    reader *r = data;
    if (reportq_cancel(&r->q, req))
        fuse_reply_err(req, EINTR);
}

static void op_read(fuse_req_t req, fuse_ino_t ino, size_t size, off_t off, struct fuse_file_info *fi)
{
    hidfuse_server *srv = fuse_req_userdata(req);
    reader *r = (reader *)(uintptr_t)fi->fh;
    reader_active(srv, r);
    uint8_t buf[DEV_REPORT_MAX];
    size_t len = 0;
    switch (reportq_read(&r->q, req, size, (fi->flags & O_NONBLOCK) != 0, buf, &len)) {
    case REPORTQ_REPORT:
        fuse_reply_buf(req, (const char *)buf, len);
        if (srv->src.fast || srv->src.exit_at_end)
            pump(srv);
        break;
    case REPORTQ_WAIT:
        fuse_req_interrupt_func(req, on_interrupt, r);
        break;
    case REPORTQ_AGAIN:
        fuse_reply_err(req, EAGAIN);
        break;
    case REPORTQ_EIO:
        fuse_reply_err(req, EIO);
        break;
    }
}

static void op_write(fuse_req_t req, fuse_ino_t ino, const char *buf, size_t size, off_t off,
                     struct fuse_file_info *fi)
{
    hidfuse_server *srv = fuse_req_userdata(req);
    reader *r = (reader *)(uintptr_t)fi->fh;
    if (r->q.dead) {
        fuse_reply_err(req, EIO);
        return;
    }
    log_event(srv, FNREC_OUT, (const uint8_t *)buf, size > DEV_REPORT_MAX ? DEV_REPORT_MAX : size);
    if (simdev_output(&srv->dev, (const uint8_t *)buf, size) < 0)
        fuse_reply_err(req, EPIPE); /* the device stalls an unknown report */
    else
        fuse_reply_write(req, size);
}

static void op_poll(fuse_req_t req, fuse_ino_t ino, struct fuse_file_info *fi,
                    struct fuse_pollhandle *ph)
{
    hidfuse_server *srv = fuse_req_userdata(req);
    reader *r = (reader *)(uintptr_t)fi->fh;
    reader_active(srv, r);
    if (ph) {
        if (r->ph)
            fuse_pollhandle_destroy(r->ph);
        r->ph = ph;
    }
    fuse_reply_poll(req, reportq_poll_events(&r->q));
}

/* Copies a string the way hidraw does: NUL included, cut to the caller's size. */
static void reply_string(fuse_req_t req, const char *s, size_t cap)
{
    size_t n = strlen(s) + 1;
    if (n > cap)
        n = cap;
    fuse_reply_ioctl(req, (int)n, s, n);
}

static void feature_ioctl(hidfuse_server *srv, fuse_req_t req, int set, const void *in, size_t in_sz,
                          size_t out_sz)
{
    uint8_t buf[DEV_REPORT_MAX] = {0};
    size_t n = in_sz < sizeof buf ? in_sz : sizeof buf;
    if (n == 0) {
        fuse_reply_err(req, EINVAL);
        return;
    }
    memcpy(buf, in, n);
    int rc = set ? simdev_set_feature(&srv->dev, buf, n) : simdev_get_feature(&srv->dev, buf, n);
    if (rc < 0) {
        fuse_reply_err(req, EPIPE);
        return;
    }
    log_event(srv, FNREC_FEATURE, buf, (size_t)rc); /* the report as set, or as the device answered */
    fuse_reply_ioctl(req, rc, buf, out_sz < sizeof buf ? out_sz : sizeof buf);
}

static void op_ioctl(fuse_req_t req, fuse_ino_t ino, unsigned int cmd, void *arg,
                     struct fuse_file_info *fi, unsigned flags, const void *in_buf, size_t in_bufsz,
                     size_t out_bufsz)
{
    hidfuse_server *srv = fuse_req_userdata(req);
    reader *r = (reader *)(uintptr_t)fi->fh;
    if (flags & FUSE_IOCTL_COMPAT || _IOC_TYPE(cmd) != 'H') {
        fuse_reply_err(req, ENOTTY);
        return;
    }
    if (r->q.dead) {
        fuse_reply_err(req, ENODEV);
        return;
    }
    size_t sz = _IOC_SIZE(cmd);
    switch (_IOC_NR(cmd)) {
    case _IOC_NR(HIDIOCGRDESCSIZE): {
        int n = (int)srv->src.id.desc_len;
        fuse_reply_ioctl(req, 0, &n, sizeof n);
        return;
    }
    case _IOC_NR(HIDIOCGRDESC): {
        struct hidraw_report_descriptor *d = &srv->rdesc;
        d->size = (uint32_t)srv->src.id.desc_len;
        memcpy(d->value, srv->src.id.desc, srv->src.id.desc_len);
        fuse_reply_ioctl(req, 0, d, sizeof *d < out_bufsz ? sizeof *d : out_bufsz);
        return;
    }
    case _IOC_NR(HIDIOCGRAWINFO): {
        struct hidraw_devinfo di = {SIMDEV_BUS_USB, (int16_t)srv->src.id.vid, (int16_t)srv->src.id.pid};
        fuse_reply_ioctl(req, 0, &di, sizeof di);
        return;
    }
    case _IOC_NR(HIDIOCGRAWNAME(0)):
        reply_string(req, srv->src.id.name, sz);
        return;
    case _IOC_NR(HIDIOCGRAWPHYS(0)):
        reply_string(req, "fracnav-sim/input0", sz);
        return;
    case _IOC_NR(HIDIOCGRAWUNIQ(0)):
        reply_string(req, srv->src.serial, sz);
        return;
    case _IOC_NR(HIDIOCGFEATURE(0)):
    case _IOC_NR(HIDIOCSFEATURE(0)):
        feature_ioctl(srv, req, _IOC_NR(cmd) == _IOC_NR(HIDIOCSFEATURE(0)), in_buf, in_bufsz, out_bufsz);
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

static int handle_signal(hidfuse_server *srv)
{
    struct signalfd_siginfo si;
    if (read(srv->sig_fd, &si, sizeof si) != (ssize_t)sizeof si)
        return 0;
    if (si.ssi_signo == SIGUSR1) {
        set_plugged(srv, !srv->plugged, 1);
        return 0;
    }
    return 1; /* SIGINT, SIGTERM, SIGHUP: stop */
}

/* ---- the control FIFO: script lines played at once ---- */

/* A control line plays its script now, or after what is still playing; the buttons held carry
 * over from one line to the next. */
static void control_command(hidfuse_server *srv, const char *line)
{
    script *sc = NULL;
    if (script_parse(line, strlen(line), "control", &sc)) {
        fprintf(stderr, "fracnav-sim: %s\n", fn_err_msg());
        return;
    }
    fnrec *r = NULL;
    if (sc->n == 1 && (sc->step[0].op == SCRIPT_UNPLUG || sc->step[0].op == SCRIPT_REPLUG))
        set_plugged(srv, sc->step[0].op == SCRIPT_REPLUG, 1);
    else if (sc->n && !(r = script_render_more(sc, &srv->dev, &srv->ctl_buttons)))
        fprintf(stderr, "fracnav-sim: %s\n", fn_err_msg());
    free(sc);
    if (r && srv->started && srv->pos < srv->src.rec->n) { /* still playing: queue it after the rest */
        int64_t at = srv->src.rec->ev[srv->src.rec->n - 1].t_us;
        for (size_t i = 0; i < r->n; i++) {
            r->ev[i].t_us += at;
            if (fnrec_append(srv->src.rec, &r->ev[i]))
                fprintf(stderr, "fracnav-sim: %s\n", fn_err_msg());
        }
        fnrec_free(r);
    } else if (r) {
        fnrec_free(srv->src.rec);
        srv->src.rec = r;
        srv->pos = 0;
        srv->started = 1;
        srv->t0_us = fnclock_now_us();
        pump(srv);
    }
}

static void control_input(hidfuse_server *srv)
{
    ssize_t n = read(srv->ctl_fd, srv->ctl_line + srv->ctl_len, sizeof srv->ctl_line - 1 - srv->ctl_len);
    if (n <= 0)
        return;
    srv->ctl_len += (size_t)n;
    char *nl;
    while ((nl = memchr(srv->ctl_line, '\n', srv->ctl_len))) {
        *nl = '\0';
        fn_err_clear();
        control_command(srv, srv->ctl_line);
        srv->ctl_len -= (size_t)(nl + 1 - srv->ctl_line);
        memmove(srv->ctl_line, nl + 1, srv->ctl_len);
    }
    if (srv->ctl_len == sizeof srv->ctl_line - 1) {
        fprintf(stderr, "fracnav-sim: control line too long, dropped\n");
        srv->ctl_len = 0;
    }
}

static int open_control(hidfuse_server *srv, const char *path)
{
    struct stat st;
    if (stat(path, &st) ? mkfifo(path, 0600) : !S_ISFIFO(st.st_mode) ? (errno = EEXIST, -1) : 0) {
        fprintf(stderr, "fracnav-sim serve: cannot make the control FIFO %s: %s\n", path,
                strerror(errno));
        return -1;
    }
    srv->ctl_fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    srv->ctl_keep = open(path, O_WRONLY | O_NONBLOCK | O_CLOEXEC);
    if (srv->ctl_fd < 0 || srv->ctl_keep < 0) {
        fprintf(stderr, "fracnav-sim serve: cannot open the control FIFO %s: %s\n", path,
                strerror(errno));
        return -1;
    }
    return 0;
}

static int serve_loop(hidfuse_server *srv)
{
    struct fuse_buf fbuf = {0};
    struct pollfd pf[4] = {{fuse_session_fd(srv->se), POLLIN, 0}, {srv->timer_fd, POLLIN, 0},
                           {srv->sig_fd, POLLIN, 0}, {srv->ctl_fd, POLLIN, 0}};
    int rc = 0;
    while (!fuse_session_exited(srv->se)) {
        if (poll(pf, 4, -1) < 0) {
            if (errno == EINTR)
                continue;
            rc = -errno;
            break;
        }
        if (pf[2].revents && handle_signal(srv))
            break;
        if (pf[3].revents)
            control_input(srv);
        if (pf[1].revents) {
            uint64_t ticks;
            if (read(srv->timer_fd, &ticks, sizeof ticks) < 0 && errno != EAGAIN)
                break;
            pump(srv);
        }
        if (pf[0].revents) {
            int n = fuse_session_receive_buf(srv->se, &fbuf);
            if (n == -EINTR || n == -EAGAIN)
                continue;
            if (n <= 0) { /* unmounted from outside (fusermount3 -u) */
                rc = n;
                break;
            }
            fuse_session_process_buf(srv->se, &fbuf);
        }
    }
    free(fbuf.mem);
    return rc;
}

static int block_signals(hidfuse_server *srv)
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
    srv->sig_fd = signalfd(-1, &set, SFD_CLOEXEC | SFD_NONBLOCK);
    srv->timer_fd = timerfd_create(CLOCK_MONOTONIC, TFD_CLOEXEC | TFD_NONBLOCK);
    return srv->sig_fd < 0 || srv->timer_fd < 0 ? -1 : 0;
}

/* mountinfo writes a space, tab, newline and backslash in a path as \ooo (octal). */
static void unescape_octal(char *s)
{
    char *o = s;
    for (; *s; s++, o++) {
        if (s[0] == '\\' && s[1] >= '0' && s[1] <= '3' && s[2] >= '0' && s[2] <= '7' && s[3] >= '0' &&
            s[3] <= '7') {
            *o = (char)((s[1] - '0') * 64 + (s[2] - '0') * 8 + (s[3] - '0'));
            s += 3;
        } else {
            *o = *s;
        }
    }
    *o = '\0';
}

/* dir with its parent's links resolved, dir's own name kept: realpath(dir) fails on a dead FUSE
 * mount (its root answers ENOTCONN), which must still be found in mountinfo. */
static int resolve_parent(const char *dir, char *out)
{
    char copy[PATH_MAX], parent[PATH_MAX];
    snprintf(copy, sizeof copy, "%s", dir);
    size_t n = strlen(copy);
    while (n > 1 && copy[n - 1] == '/')
        copy[--n] = '\0';
    char *slash = strrchr(copy, '/');
    const char *base = slash ? slash + 1 : copy;
    if (!strcmp(base, ".") || !strcmp(base, "..") || !*base)
        return realpath(dir, out) ? 0 : -1;
    if (slash)
        *slash = '\0';
    if (!realpath(slash ? (copy[0] ? copy : "/") : ".", parent))
        return -1;
    return snprintf(out, PATH_MAX, "%s/%s", strcmp(parent, "/") ? parent : "", base) < PATH_MAX ? 0 : -1;
}

/* The file system type already mounted at dir ("fuse.hidraw" for another fracnav-sim), into type;
 * 0 when dir is no mount point. */
static int mounted_at(const char *dir, char *type, size_t cap)
{
    char want[PATH_MAX], line[2 * PATH_MAX], point[PATH_MAX], fstype[64];
    FILE *f = resolve_parent(dir, want) == 0 ? fopen("/proc/self/mountinfo", "r") : NULL;
    int found = 0;
    while (f && !found && fgets(line, sizeof line, f)) {
        const char *sep = strstr(line, " - "); /* optional fields end here; the type follows */
        if (sscanf(line, "%*s %*s %*s %*s %4095s", point) != 1 || !sep || sscanf(sep + 3, "%63s", fstype) != 1)
            continue;
        unescape_octal(point);
        if ((found = !strcmp(point, want)))
            snprintf(type, cap, "%s", fstype);
    }
    if (f)
        fclose(f);
    return found;
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
    char type[64];
    if (mounted_at(mount, type, sizeof type)) { /* mounting over it would hide what is served there */
        fprintf(stderr, "fracnav-sim serve: %s is already a mount point (%s)%s: stop what serves it, or "
                        "unmount it (fusermount3 -u %s), or serve at another folder\n", mount, type,
                !strcmp(type, "fuse.hidraw") ? ", served by another fracnav-sim" : "", mount);
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

static void teardown(hidfuse_server *srv, const char *mount)
{
    kill_readers(srv); /* waiting reads end with EIO, as on a real unplug */
    fuse_session_unmount(srv->se);
    fuse_session_destroy(srv->se);
    while (srv->readers) {
        reader *r = srv->readers;
        srv->readers = r->next;
        free(r);
    }
    fprintf(stderr, "fracnav-sim: unmounted %s (%" PRIu64 " reports served, %" PRIu64
                    " dropped by full reader queues)\n", mount, srv->served, srv->dropped);
}

extern char **environ; /* for posix_spawnp */

/* A mount of ours whose server was killed (its root answers ENOTCONN) refused every later serve
 * until fusermount3 -u: it is removed (lazily, as fusermount3 -u -z does). */
static void clean_dead_mount(const char *mount)
{
    struct stat st;
    char type[64];
    if (stat(mount, &st) == 0 || errno != ENOTCONN || !mounted_at(mount, type, sizeof type) ||
        strcmp(type, "fuse.hidraw"))
        return;
    int ok = umount2(mount, MNT_DETACH) == 0;
    if (!ok) { /* not root: through the setuid helper */
        char dir[PATH_MAX];
        snprintf(dir, sizeof dir, "%s", mount);
        char *argv[] = {"fusermount3", "-u", "-z", dir, NULL};
        pid_t pid;
        int status;
        ok = posix_spawnp(&pid, "fusermount3", NULL, NULL, argv, environ) == 0 &&
             waitpid(pid, &status, 0) == pid && WIFEXITED(status) && WEXITSTATUS(status) == 0;
    }
    fprintf(stderr, "fracnav-sim serve: %s a dead mount of a killed fracnav-sim at %s\n",
            ok ? "removed" : "cannot remove", mount);
}

static int serve(hidfuse_server *srv, const char *mount, const char *control)
{
    if (check_fuse_access(mount) || (control && open_control(srv, control)))
        return 1;
    if (block_signals(srv)) {
        fprintf(stderr, "fracnav-sim serve: cannot create the signal or timer descriptor: %s\n",
                strerror(errno));
        return 1;
    }
    char *argv[] = {"fracnav-sim", "-o", "fsname=fracnav-sim,subtype=hidraw", NULL};
    struct fuse_args args = FUSE_ARGS_INIT(3, argv);
    srv->se = fuse_session_new(&args, &ops, sizeof ops, srv);
    fuse_opt_free_args(&args);
    if (!srv->se || fuse_session_mount(srv->se, mount)) {
        fprintf(stderr, "fracnav-sim serve: cannot mount FUSE on %s (need root or FUSE permission; "
                        "is something already mounted there?)\n", mount);
        if (srv->se)
            fuse_session_destroy(srv->se);
        return 1;
    }
    fprintf(stderr, "fracnav-sim: serving %s (%04x:%04x) at %s/" HIDFUSE_NODE "\n", srv->src.id.name,
            srv->src.id.vid, srv->src.id.pid, mount);
    srv->log_t0 = fnclock_now_us();
    if (!srv->src.start_on_read)
        start_playback(srv);
    int rc = serve_loop(srv);
    teardown(srv, mount);
    return rc < 0 ? 1 : 0;
}


/* What the server holds: the source's recording, script and log, and its descriptors. */
static void release(hidfuse_server *srv)
{
    if (srv->src.log && fnrec_writer_close(srv->src.log))
        fprintf(stderr, "fracnav-sim: %s\n", fn_err_msg());
    fnrec_free(srv->src.rec);
    free(srv->src.script);
    int fds[] = {srv->sig_fd, srv->timer_fd, srv->ctl_fd, srv->ctl_keep};
    for (size_t i = 0; i < sizeof fds / sizeof *fds; i++)
        if (fds[i] >= 0)
            close(fds[i]);
}

int hidfuse_serve(const char *mount, const char *control, const hidfuse_source *src)
{
    hidfuse_server srv = {.src = *src, .plugged = 1, .timer_fd = -1, .sig_fd = -1, .ctl_fd = -1,
                          .ctl_keep = -1};
    simdev_init(&srv.dev, src->p);
    srv.dev.battery_pending = 0; /* the source holds the power-on reports */
    clean_dead_mount(mount);
    /* The folder's own inode, locked until the server ends: the check that nothing is mounted
     * there and the mount are one step for every fracnav-sim (two started at once both mounted).
     * One started after the mount opens the mounted root instead, and check_fuse_access refuses
     * it. A folder that cannot be opened is left to check_fuse_access to explain. */
    int lock = open(mount, O_RDONLY | O_DIRECTORY | O_CLOEXEC), rc = 1;
    if (lock >= 0 && flock(lock, LOCK_EX | LOCK_NB))
        fprintf(stderr, "fracnav-sim serve: another fracnav-sim is mounting at %s: stop it, or serve at "
                        "another folder\n", mount);
    else
        rc = serve(&srv, mount, control);
    if (lock >= 0)
        close(lock);
    release(&srv);
    return rc;
}
