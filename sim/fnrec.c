#include "fnrec.h"

#include <errno.h>
#include <inttypes.h>
#include <limits.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "durable.h"
#include "err.h"
#include "simfile.h"
#include "hiddesc.h"

#define LINE_MAX_CHARS (2 * DEV_DESC_MAX + 64)

static const char *dir_names[] = {"in", "out", "feature", "connect", "disconnect"};

const char *fnrec_dir_name(fnrec_dir d)
{
    return (unsigned)d < sizeof dir_names / sizeof *dir_names ? dir_names[d] : "?";
}

/* ---- reader: a pure function over bytes ---- */

typedef struct cursor {
    const char *name;
    int line;
} cursor;

static int bad(const cursor *c, const char *what)
{
    return fn_err_set(FN_EFORMAT, "%s:%d: %s", c->name, c->line, what);
}

static int hexval(char ch)
{
    if (ch >= '0' && ch <= '9')
        return ch - '0';
    if (ch >= 'a' && ch <= 'f')
        return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F')
        return ch - 'A' + 10;
    return -1;
}

/* Hex digits (no separators) of length n into out; returns the byte count or -1. */
static long parse_hex(const char *s, size_t n, uint8_t *out, size_t cap)
{
    if (n % 2 || n / 2 > cap)
        return -1;
    for (size_t i = 0; i < n; i += 2) {
        int hi = hexval(s[i]), lo = hexval(s[i + 1]);
        if (hi < 0 || lo < 0)
            return -1;
        out[i / 2] = (uint8_t)(hi << 4 | lo);
    }
    return (long)(n / 2);
}

static int parse_id16(const char *s, size_t n, uint16_t *out)
{
    uint8_t b[2];
    if (n != 4 || parse_hex(s, 4, b, 2) != 2)
        return -1;
    *out = (uint16_t)(b[0] << 8 | b[1]);
    return 0;
}

static int is_word(const char *s, size_t n, const char *w)
{
    return strlen(w) == n && memcmp(s, w, n) == 0;
}

enum { HAVE_VID = 1, HAVE_PID = 2, HAVE_NAME = 4, HAVE_FORMAT = 8, HAVE_DESC = 16, HAVE_SOURCE = 32 };

static int header_line(const cursor *c, const char *s, size_t n, fnrec_header *h, unsigned *have)
{
    const char *sp = memchr(s, ' ', n);
    if (!sp && !is_word(s, n, "descriptor")) /* only the descriptor may be empty */
        return bad(c, "header line needs 'KEY VALUE' (or 'events' to end the header)");
    size_t kn = sp ? (size_t)(sp - s) : n, vn = sp ? n - kn - 1 : 0;
    const char *v = sp ? sp + 1 : s + n;
    unsigned bit;
    if (is_word(s, kn, "vid") || is_word(s, kn, "pid")) {
        bit = s[0] == 'v' ? HAVE_VID : HAVE_PID;
        if (parse_id16(v, vn, bit == HAVE_VID ? &h->vid : &h->pid))
            return bad(c, "vid/pid must be 4 hex digits");
    } else if (is_word(s, kn, "name") || is_word(s, kn, "source")) {
        bit = s[0] == 'n' ? HAVE_NAME : HAVE_SOURCE;
        char *dst = bit == HAVE_NAME ? h->name : h->source;
        if (vn >= sizeof h->name)
            return bad(c, "name/source longer than 127 bytes");
        for (size_t i = 0; i < vn; i++)
            if ((unsigned char)v[i] < 0x20 && v[i] != '\t')
                return bad(c, "control character in name/source");
        memcpy(dst, v, vn);
        dst[vn] = '\0';
    } else if (is_word(s, kn, "format")) {
        bit = HAVE_FORMAT;
        if (!is_word(v, vn, "split") && !is_word(v, vn, "combined"))
            return bad(c, "format must be 'split' or 'combined'");
        memcpy(h->format, v, vn);
        h->format[vn] = '\0';
    } else if (is_word(s, kn, "descriptor")) {
        bit = HAVE_DESC;
        if (vn % 2)
            return bad(c, "descriptor has an odd number of hex digits: each byte is two");
        long got = parse_hex(v, vn, h->desc, sizeof h->desc);
        if (got < 0)
            return bad(c, "descriptor must be up to 4096 bytes of hex digits");
        h->desc_len = (size_t)got;
    } else {
        return bad(c, "unknown header key (expected vid, pid, name, format, source, descriptor)");
    }
    if (*have & bit)
        return bad(c, "header key given twice");
    *have |= bit;
    return 0;
}

static int event_line(const cursor *c, const char *s, size_t n, int64_t prev, fnrec_event *e)
{
    size_t i = 0;
    int64_t t = 0;
    if (n == 0 || s[0] < '0' || s[0] > '9')
        return bad(c, "event line must start with a timestamp in microseconds");
    for (; i < n && s[i] >= '0' && s[i] <= '9'; i++) {
        if (t > (INT64_MAX - 9) / 10)
            return bad(c, "timestamp too large");
        t = t * 10 + (s[i] - '0');
    }
    if (i == n || s[i] != ' ')
        return bad(c, "timestamp must be followed by one space and a direction");
    if (t < prev)
        return bad(c, "timestamp goes backwards");
    if (t - prev > FNREC_MAX_GAP_US)
        return fn_err_set(FN_EFORMAT, "%s:%d: timestamp %" PRId64 " us is %.0f s after the event before it; "
                          "a recording's events are at most %d s apart", c->name, c->line, t,
                          (double)(t - prev) / 1e6, (int)(FNREC_MAX_GAP_US / 1000000));
    const char *d = s + ++i;
    const char *sp = memchr(d, ' ', n - i);
    size_t dn = sp ? (size_t)(sp - d) : n - i;
    int dir = -1;
    for (int k = 0; k <= FNREC_DISCONNECT; k++)
        if (is_word(d, dn, dir_names[k]))
            dir = k;
    if (dir < 0)
        return bad(c, "direction must be in, out, feature, connect or disconnect");
    memset(e, 0, sizeof *e);
    e->t_us = t;
    e->dir = (fnrec_dir)dir;
    if (dir >= FNREC_CONNECT) {
        if (sp)
            return bad(c, "connect/disconnect take no bytes");
        return 0;
    }
    if (!sp)
        return bad(c, "report bytes missing (hex, report ID first)");
    size_t digits = n - (size_t)(sp + 1 - s);
    if (digits % 2)
        return fn_err_set(FN_EFORMAT, "%s:%d: odd number of hex digits (%zu): each byte is two",
                          c->name, c->line, digits);
    long got = parse_hex(sp + 1, digits, e->data, sizeof e->data);
    if (got <= 0)
        return bad(c, "report must be 1 to 64 bytes of hex digits with no spaces");
    e->len = (uint8_t)got;
    return 0;
}

static int check_header(const cursor *c, unsigned have)
{
    static const struct { unsigned bit; const char *key; } need[] = {
        {HAVE_VID, "vid"}, {HAVE_PID, "pid"}, {HAVE_NAME, "name"},
        {HAVE_FORMAT, "format"}, {HAVE_DESC, "descriptor"}};
    for (size_t i = 0; i < sizeof need / sizeof *need; i++)
        if (!(have & need[i].bit))
            return fn_err_set(FN_EFORMAT, "%s:%d: header lacks '%s'", c->name, c->line, need[i].key);
    return 0;
}

static int first_line(const cursor *c, const char *s, size_t n, fnrec_header *h)
{
    size_t len = c->name ? strlen(c->name) : 0;
    if ((n < 7 || memcmp(s, "fnrec ", 6) != 0) && len > 7 && !strcmp(c->name + len - 7, ".script"))
        return bad(c, "a motion script, not a .fnrec recording: render it first with "
                      "`fracnav-sim render --script FILE -o FILE.fnrec`");
    if (n < 7 || memcmp(s, "fnrec ", 6) != 0)
        return bad(c, "not a .fnrec file (first line must be 'fnrec VERSION')");
    if (!is_word(s + 6, n - 6, "1"))
        return bad(c, "unsupported fnrec version (this reader knows version 1)");
    h->version = FNREC_VERSION;
    return 0;
}

/* A last line without its newline is a torn write when it does not parse, or when it is an input
 * report shorter than the descriptor declares (the hex was cut at a byte boundary). Returns the
 * reason, or NULL when the line is whole and is kept. */
static const char *torn(const fnrec_header *h, int rc, const fnrec_event *e, char *why, size_t cap)
{
    if (rc) {
        snprintf(why, cap, "%s", fn_err_msg());
        fn_err_clear();
        return why;
    }
    hiddesc d;
    const hiddesc_report *rep;
    if (e->dir != FNREC_IN || !h->desc_len || hiddesc_parse(h->desc, h->desc_len, &d) ||
        !(rep = hiddesc_find(&d, HIDDESC_INPUT, e->data[0])) || rep->len <= e->len) {
        fn_err_clear();
        return NULL;
    }
    snprintf(why, cap, "input report %u has %u of its %zu bytes", e->data[0], e->len, rep->len);
    return why;
}

int fnrec_parse(const char *text, size_t len, const char *name, fnrec **out)
{
    *out = NULL;
    fnrec_header hdr;
    memset(&hdr, 0, sizeof hdr);
    fnrec *r = NULL;
    cursor c = {name ? name : "<recording>", 0};
    unsigned have = 0;
    int in_events = 0, rc = 0;
    size_t pos = 0;
    while (pos < len && rc == 0) {
        const char *s = text + pos;
        const char *nl = memchr(s, '\n', len - pos);
        size_t n = nl ? (size_t)(nl - s) : len - pos;
        pos += n + (nl != NULL);
        c.line++;
        if (n && s[n - 1] == '\r')
            n--;
        if (n > LINE_MAX_CHARS)
            rc = bad(&c, "line too long");
        else if (memchr(s, '\0', n))
            rc = bad(&c, "NUL byte in a text file");
        else if (c.line == 1)
            rc = first_line(&c, s, n, &hdr);
        else if (n == 0 || s[0] == '#')
            continue;
        else if (!in_events && is_word(s, n, "events")) {
            if ((rc = check_header(&c, have)) == 0) {
                in_events = 1;
                if (!(r = fnrec_new(&hdr)))
                    rc = FN_ENOMEM;
            }
        } else if (!in_events)
            rc = header_line(&c, s, n, &hdr, &have);
        else {
            fnrec_event e;
            rc = event_line(&c, s, n, r->n ? r->ev[r->n - 1].t_us : 0, &e);
            if (!nl && torn(&hdr, rc, &e, r->torn_why, sizeof r->torn_why)) {
                r->torn_line = c.line; /* an interrupted write: left out, not an error */
                rc = 0;
                break;
            }
            if (rc == 0 && (rc = fnrec_append(r, &e)) != 0)
                rc = fn_err_wrap(rc, "%s:%d", c.name, c.line);
        }
    }
    if (rc == 0 && c.line == 0)
        rc = fn_err_set(FN_EFORMAT, "%s: empty file, not a recording", c.name);
    if (rc == 0 && !in_events)
        rc = fn_err_set(FN_EFORMAT, "%s:%d: header not ended by an 'events' line", c.name, c.line);
    if (rc) {
        fnrec_free(r);
        return rc;
    }
    *out = r;
    return 0;
}

fnrec *fnrec_load(const char *path)
{
    /* At most every event at its longest line, plus a header. */
    const size_t cap = (size_t)FNREC_MAX_EVENTS * 160 + 3 * LINE_MAX_CHARS;
    char too_big[64], *buf;
    size_t n;
    snprintf(too_big, sizeof too_big, "any recording of %u events", FNREC_MAX_EVENTS);
    if (simfile_read(path, cap, too_big, &buf, &n))
        return NULL;
    fnrec *r = NULL;
    if (fnrec_parse(buf, n, path, &r) == 0 && r->torn_line)
        fprintf(stderr, "warning: %s:%d: last line cut short (%s): left out, as an interrupted "
                        "recording's\n", path, r->torn_line, r->torn_why);
    free(buf);
    return r;
}

fnrec *fnrec_new(const fnrec_header *hdr)
{
    fnrec *r = calloc(1, sizeof *r);
    if (!r) {
        fn_err_set(FN_ENOMEM, "out of memory for a recording");
        return NULL;
    }
    r->hdr = *hdr;
    return r;
}

int fnrec_append(fnrec *r, const fnrec_event *e)
{
    if (e->len > DEV_REPORT_MAX)
        return fn_err_set(FN_EINVAL, "report of %u bytes exceeds %d", e->len, DEV_REPORT_MAX);
    if (r->n && e->t_us < r->ev[r->n - 1].t_us)
        return fn_err_set(FN_EINVAL, "timestamp goes backwards");
    if (r->n >= FNREC_MAX_EVENTS)
        return fn_err_set(FN_ENOMEM, "more than %u events", FNREC_MAX_EVENTS);
    if ((r->n & (r->n - 1)) == 0 && r->n >= 64) { /* grow at powers of two */
        fnrec_event *nev = realloc(r->ev, 2 * r->n * sizeof *nev);
        if (!nev)
            return fn_err_set(FN_ENOMEM, "out of memory for %zu events", 2 * r->n);
        r->ev = nev;
    } else if (!r->ev) {
        if (!(r->ev = malloc(64 * sizeof *r->ev)))
            return fn_err_set(FN_ENOMEM, "out of memory for events");
    }
    r->ev[r->n++] = *e;
    return 0;
}

void fnrec_free(fnrec *r)
{
    if (r)
        free(r->ev);
    free(r);
}

/* ---- writer ---- */

struct fnrec_writer {
    FILE *f;
    int owned;
    char path[256];
};

static int put_hex(FILE *f, const uint8_t *b, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (fprintf(f, "%02x", b[i]) < 0)
            return -1;
    return 0;
}

static int clean_text(const char *s)
{
    for (; *s; s++)
        if (*s == '\n' || *s == '\r')
            return 0;
    return 1;
}

static int write_header(FILE *f, const fnrec_header *h)
{
    if (fprintf(f, "fnrec %d\nvid %04x\npid %04x\nname %s\nformat %s\n", FNREC_VERSION, h->vid,
                h->pid, h->name, h->format) < 0)
        return -1;
    if (h->source[0] && fprintf(f, "source %s\n", h->source) < 0)
        return -1;
    if (fputs("descriptor ", f) < 0 || put_hex(f, h->desc, h->desc_len) || fputs("\nevents\n", f) < 0)
        return -1;
    return fflush(f);
}

fnrec_writer *fnrec_writer_stream(FILE *f, const fnrec_header *h)
{
    if (!clean_text(h->name) || !clean_text(h->source) || h->desc_len > sizeof h->desc ||
        (strcmp(h->format, "split") && strcmp(h->format, "combined"))) {
        fn_err_set(FN_EINVAL, "recording header: name/source with a newline, descriptor too "
                              "long, or format not split/combined");
        return NULL;
    }
    fnrec_writer *w = calloc(1, sizeof *w);
    if (!w) {
        fn_err_set(FN_ENOMEM, "out of memory for a writer");
        return NULL;
    }
    w->f = f;
    snprintf(w->path, sizeof w->path, "<stream>");
    if (write_header(f, h)) {
        fn_err_set(FN_EIO, "%s: cannot write the header: %s", w->path, strerror(errno));
        free(w);
        return NULL;
    }
    return w;
}

fnrec_writer *fnrec_writer_open(const char *path, const fnrec_header *h)
{
    /* Written as it is recorded (a kill keeps what came before it), so in place, never through
     * a link nor into a FIFO or device. */
    int fd = durable_open_log(path);
    if (fd < 0)
        return NULL;
    FILE *f = ftruncate(fd, 0) == 0 ? fdopen(fd, "w") : NULL;
    if (!f) {
        fn_err_set(FN_EIO, "%s: cannot create: %s", path, strerror(errno));
        close(fd);
        return NULL;
    }
    fnrec_writer *w = fnrec_writer_stream(f, h);
    if (!w) {
        fclose(f);
        fn_err_wrap(FN_EIO, "%s", path);
        return NULL;
    }
    w->owned = 1;
    snprintf(w->path, sizeof w->path, "%s", path);
    return w;
}

int fnrec_writer_event(fnrec_writer *w, const fnrec_event *e)
{
    if (e->t_us < 0 || e->len > DEV_REPORT_MAX || (unsigned)e->dir > FNREC_DISCONNECT ||
        (e->dir < FNREC_CONNECT && e->len == 0))
        return fn_err_set(FN_EINVAL, "%s: event with bad time, direction or length", w->path);
    int bad = fprintf(w->f, "%" PRId64 " %s", e->t_us, fnrec_dir_name(e->dir)) < 0;
    if (!bad && e->dir < FNREC_CONNECT)
        bad = fputc(' ', w->f) == EOF || put_hex(w->f, e->data, e->len);
    if (bad || fputc('\n', w->f) == EOF || fflush(w->f))
        return fn_err_set(FN_EIO, "%s: write failed: %s", w->path, strerror(errno));
    return 0;
}

int fnrec_writer_close(fnrec_writer *w)
{
    if (!w)
        return 0;
    int rc = 0;
    if (fflush(w->f) || (w->owned && fsync(fileno(w->f)) && errno != EINVAL))
        rc = fn_err_set(FN_EIO, "%s: flush failed: %s", w->path, strerror(errno));
    if (w->owned && fclose(w->f) && !rc)
        rc = fn_err_set(FN_EIO, "%s: close failed: %s", w->path, strerror(errno));
    free(w);
    return rc;
}

int fnrec_save(const fnrec *r, const char *path)
{
    fnrec_writer *w = fnrec_writer_open(path, &r->hdr);
    if (!w)
        return FN_EIO;
    int rc = 0;
    for (size_t i = 0; i < r->n && rc == 0; i++)
        rc = fnrec_writer_event(w, &r->ev[i]);
    int rc2 = fnrec_writer_close(w);
    return rc ? rc : rc2;
}
