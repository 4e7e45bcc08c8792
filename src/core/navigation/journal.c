#include "journal.h"

#include "durable.h"
#include "err.h"
#include "vol.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#define MAGIC "FNJOURNAL2\n"
#define HEADER_CRC_AT 252
#define READ_CHUNK 256 /* records read at a time */
#define BUF_RECORDS 256

struct journal {
    int fd;
    char path[4096];
    journal_bind bind;
    uint64_t seq, count;
    int64_t oldest_us;
    size_t used;
    unsigned char buf[BUF_RECORDS * JOURNAL_RECORD_SIZE];
};

static void put32(unsigned char *b, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        b[i] = (unsigned char)(v >> (8 * i));
}

static void put64(unsigned char *b, uint64_t v)
{
    for (int i = 0; i < 8; i++)
        b[i] = (unsigned char)(v >> (8 * i));
}

static uint32_t get32(const unsigned char *b)
{
    uint32_t v = 0;
    for (int i = 3; i >= 0; i--)
        v = v << 8 | b[i];
    return v;
}

static uint64_t get64(const unsigned char *b)
{
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--)
        v = v << 8 | b[i];
    return v;
}

static void putf(unsigned char *b, double d)
{
    uint64_t v;
    memcpy(&v, &d, 8);
    put64(b, v);
}

static double getf(const unsigned char *b)
{
    uint64_t v = get64(b);
    double d;
    memcpy(&d, &v, 8);
    return d;
}

static void encode(unsigned char *b, const journal_rec *r)
{
    put32(b, r->kind);
    put32(b + 4, (uint32_t)r->frag);
    put64(b + 8, r->seq);
    put64(b + 16, (uint64_t)r->t_us);
    for (int i = 0; i < 4; i++)
        putf(b + 24 + 8 * i, r->p.q[i]);
    for (int i = 0; i < 3; i++)
        putf(b + 56 + 8 * i, r->p.t[i]);
    put32(b + 80, r->flag);
    put32(b + 84, (uint32_t)crc32(0, b, 84));
}

/* Decodes the record at b, the one after `prev` (NULL for the first); NULL when it is good, else
 * why not (into why). */
static const char *decode(const unsigned char *b, const journal_rec *prev, int nfrag, journal_rec *r,
                          char *why, size_t cap)
{
    if (get32(b + 84) != (uint32_t)crc32(0, b, 84))
        return "bad CRC (a torn or overwritten record)";
    r->kind = get32(b);
    r->frag = (int32_t)get32(b + 4);
    r->seq = get64(b + 8);
    r->t_us = (int64_t)get64(b + 16);
    for (int i = 0; i < 4; i++)
        r->p.q[i] = getf(b + 24 + 8 * i);
    for (int i = 0; i < 3; i++)
        r->p.t[i] = getf(b + 56 + 8 * i);
    r->flag = get32(b + 80);
    double n2 = 0;
    int finite = 1;
    for (int i = 0; i < 4; i++) {
        n2 += r->p.q[i] * r->p.q[i];
        finite &= isfinite(r->p.q[i]) && (i == 3 || isfinite(r->p.t[i]));
    }
    if (r->kind < JOURNAL_MOVE || r->kind > JOURNAL_FIX)
        snprintf(why, cap, "unknown kind %u", r->kind);
    else if (r->flag > (r->kind == JOURNAL_FIX))
        snprintf(why, cap, "flag %u where %s expected", r->flag, r->kind == JOURNAL_FIX ? "0 or 1" : "0");
    else if (r->frag < 0 || r->frag >= nfrag)
        snprintf(why, cap, "fragment index %d, the journal's case has %d", r->frag, nfrag);
    else if (prev && r->seq != prev->seq + 1)
        snprintf(why, cap, "sequence number %llu after %llu", (unsigned long long)r->seq,
                 (unsigned long long)prev->seq);
    else if (!finite)
        snprintf(why, cap, "a pose that is not finite (NaN or infinite)");
    else if (fabs(n2 - 1) > 1e-6)
        snprintf(why, cap, "a quaternion that is not of unit length (|q|^2 = %g)", n2);
    else
        return NULL;
    return why;
}

static void header(unsigned char h[JOURNAL_HEADER_SIZE], const journal_bind *b)
{
    memset(h, 0, JOURNAL_HEADER_SIZE);
    memcpy(h, MAGIC, 11);
    put32(h + 12, JOURNAL_RECORD_SIZE);
    memcpy(h + 16, b->case_sha256, 64);
    put32(h + 80, (uint32_t)b->nfrag);
    for (int i = 0; i < b->nfrag && i < JOURNAL_MAX_FRAGS; i++) {
        h[84 + 2 * i] = (unsigned char)(b->ids[i] & 0xff);
        h[85 + 2 * i] = (unsigned char)(b->ids[i] >> 8);
    }
    put32(h + HEADER_CRC_AT, (uint32_t)crc32(0, h, HEADER_CRC_AT));
}

/* The header's binding, or FN_EFORMAT naming what is wrong with it. */
static int read_header(const unsigned char *h, size_t len, const char *name, journal_bind *b)
{
    memset(b, 0, sizeof *b);
    if (len < JOURNAL_HEADER_SIZE || memcmp(h, MAGIC, 12) != 0 || get32(h + 12) != JOURNAL_RECORD_SIZE)
        return fn_err_set(FN_EFORMAT, "%s: offset 0: not a fracnav journal of this version (bad "
                                      "header)", name);
    if (get32(h + HEADER_CRC_AT) != (uint32_t)crc32(0, h, HEADER_CRC_AT))
        return fn_err_set(FN_EFORMAT, "%s: offset 0: the header's CRC is wrong", name);
    uint32_t n = get32(h + 80);
    if (n > JOURNAL_MAX_FRAGS)
        return fn_err_set(FN_EFORMAT, "%s: offset 80: %u fragments, at most %d", name, n,
                          JOURNAL_MAX_FRAGS);
    memcpy(b->case_sha256, h + 16, 64);
    b->nfrag = (int)n;
    for (uint32_t i = 0; i < n; i++)
        b->ids[i] = (uint16_t)(h[84 + 2 * i] | h[85 + 2 * i] << 8);
    return 0;
}

static int write_all(int fd, const unsigned char *b, size_t n, const char *path)
{
    while (n > 0) {
        ssize_t w = write(fd, b, n);
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0)
            return fn_err_set(FN_EIO, "%s: write failed: %s", path, strerror(errno));
        b += w;
        n -= (size_t)w;
    }
    return 0;
}

static void journal_path(const char *dir, char *out, size_t cap)
{
    snprintf(out, cap, "%s/journal", dir);
}

void journal_scan_free(journal_scan *s)
{
    free(s->recs);
    s->recs = NULL;
    s->n = 0;
}

int journal_bind_equal(const journal_bind *a, const journal_bind *b)
{
    return !strcmp(a->case_sha256, b->case_sha256) && a->nfrag == b->nfrag &&
           !memcmp(a->ids, b->ids, sizeof a->ids[0] * (size_t)a->nfrag);
}

static void scan_init(journal_scan *s)
{
    memset(s, 0, sizeof *s);
    s->damaged_at = -1;
}

/* Decodes the whole records in buf (at file offset off) onto s; 1 when it stopped at damage. */
static int scan_records(journal_scan *s, const uint8_t *buf, size_t len, size_t off, const char *name,
                        size_t cap)
{
    char why[160];
    for (size_t at = 0; at + JOURNAL_RECORD_SIZE <= len; at += JOURNAL_RECORD_SIZE) {
        const char *bad = s->n == cap ? "more records than the memory budget holds"
                                      : decode(buf + at, s->n ? &s->recs[s->n - 1] : NULL,
                                               s->bind.nfrag, &s->recs[s->n], why, sizeof why);
        if (bad) {
            s->damaged_at = (long)(off + at);
            snprintf(s->damage, sizeof s->damage, "%s: record %zu at offset %zu: %s", name, s->n + 1,
                     off + at, bad);
            return 1;
        }
        s->n++;
    }
    return 0;
}

static void partial_tail(journal_scan *s, size_t off, size_t bytes, const char *name)
{
    s->damaged_at = (long)off;
    snprintf(s->damage, sizeof s->damage, "%s: record %zu at offset %zu: only %zu of its %d bytes "
             "(cut short)", name, s->n + 1, off, bytes, JOURNAL_RECORD_SIZE);
}

/* Room for `more` records, bounded by cap. */
static int grow(journal_scan *s, size_t *have, size_t more, size_t cap, const char *name)
{
    size_t want = s->n + more < cap ? s->n + more : cap;
    if (want <= *have)
        return 0;
    size_t n = *have ? *have : 64;
    while (n < want)
        n *= 2;
    n = n < cap ? n : cap;
    journal_rec *r = realloc(s->recs, n * sizeof *r);
    if (!r)
        return fn_err_set(FN_ENOMEM, "%s: out of memory for %zu records", name, n);
    s->recs = r;
    *have = n;
    return 0;
}

static size_t record_cap(void)
{
    size_t cap = vol_budget() / sizeof(journal_rec);
    return cap ? cap : 1;
}

int journal_parse(const uint8_t *buf, size_t len, const char *name, journal_scan *s)
{
    scan_init(s);
    if (len == 0)
        return 0;
    int rc = read_header(buf, len, name, &s->bind);
    size_t body = len - JOURNAL_HEADER_SIZE, have = 0, cap = record_cap();
    if (rc == 0)
        rc = grow(s, &have, body / JOURNAL_RECORD_SIZE + 1, cap, name);
    if (rc < 0) {
        journal_scan_free(s);
        return rc;
    }
    if (!scan_records(s, buf + JOURNAL_HEADER_SIZE, body, JOURNAL_HEADER_SIZE, name, cap) &&
        body % JOURNAL_RECORD_SIZE)
        partial_tail(s, JOURNAL_HEADER_SIZE + s->n * JOURNAL_RECORD_SIZE, body % JOURNAL_RECORD_SIZE,
                     name);
    return 0;
}

static ssize_t read_full(int fd, uint8_t *b, size_t n)
{
    size_t done = 0;
    while (done < n) {
        ssize_t r = read(fd, b + done, n - done);
        if (r < 0 && errno == EINTR)
            continue;
        if (r < 0)
            return -1;
        if (r == 0)
            break;
        done += (size_t)r;
    }
    return (ssize_t)done;
}

static int read_fd(int fd, const char *path, journal_scan *s)
{
    uint8_t h[JOURNAL_HEADER_SIZE];
    ssize_t got = read_full(fd, h, sizeof h);
    if (got < 0)
        return fn_err_set(FN_EIO, "%s: read failed: %s", path, strerror(errno));
    if (got == 0)
        return 0;
    int rc = read_header(h, (size_t)got, path, &s->bind);
    size_t have = 0, cap = record_cap(), off = JOURNAL_HEADER_SIZE;
    uint8_t chunk_buf[READ_CHUNK * JOURNAL_RECORD_SIZE];
    while (rc == 0) {
        got = read_full(fd, chunk_buf, sizeof chunk_buf);
        if (got < 0)
            return fn_err_set(FN_EIO, "%s: read failed at offset %zu: %s", path, off, strerror(errno));
        if ((rc = grow(s, &have, (size_t)got / JOURNAL_RECORD_SIZE, cap, path)) < 0)
            break;
        if (scan_records(s, chunk_buf, (size_t)got, off, path, cap))
            break;
        if (got % JOURNAL_RECORD_SIZE) {
            partial_tail(s, off + (size_t)got / JOURNAL_RECORD_SIZE * JOURNAL_RECORD_SIZE,
                         (size_t)got % JOURNAL_RECORD_SIZE, path);
            break;
        }
        if ((size_t)got < sizeof chunk_buf)
            break;
        off += (size_t)got;
    }
    return rc;
}

int journal_read(const char *case_dir, journal_scan *s)
{
    char path[4096];
    journal_path(case_dir, path, sizeof path);
    scan_init(s);
    int fd = open(path, O_RDONLY | O_NONBLOCK | O_NOFOLLOW | O_CLOEXEC);
    if (fd < 0 && errno == ELOOP)
        return fn_err_set(FN_EIO, "%s is a symbolic link: fracnav neither reads nor writes a journal "
                                  "through one; remove it", path);
    if (fd < 0)
        return errno == ENOENT ? 0 : fn_err_set(FN_EIO, "%s: cannot open: %s", path, strerror(errno));
    struct stat sb;
    int rc = fstat(fd, &sb) != 0 || !S_ISREG(sb.st_mode)
                 ? fn_err_set(FN_EIO, "%s: not a regular file", path)
                 : read_fd(fd, path, s);
    close(fd);
    if (rc < 0)
        journal_scan_free(s);
    return rc;
}

int journal_final_poses(const journal_rec *recs, size_t n, int nfrag, pose *poses)
{
    for (size_t i = 0; i < n; i++) {
        int f = recs[i].frag;
        if (f < 0 || f >= nfrag)
            return fn_err_set(FN_EFORMAT, "journal record %zu (seq %llu): fragment %d, the case has %d",
                              i + 1, (unsigned long long)recs[i].seq, f, nfrag);
        poses[f] = recs[i].p;
    }
    return 0;
}

journal *journal_open(const char *case_dir, const journal_bind *b)
{
    journal_scan sc;
    if (journal_read(case_dir, &sc) < 0)
        return NULL;
    uint64_t last = sc.n ? sc.recs[sc.n - 1].seq : 0;
    size_t n = sc.n;
    int rc = 0;
    if (sc.damaged_at >= 0)
        rc = fn_err_set(FN_EFORMAT, "%s", sc.damage);
    else if (n && !journal_bind_equal(&sc.bind, b))
        rc = fn_err_set(FN_EMISMATCH, "%s/journal: its %zu records extend another state of the case",
                        case_dir, n);
    journal_scan_free(&sc);
    journal *j = rc == 0 ? calloc(1, sizeof *j) : NULL;
    if (rc == 0 && !j)
        fn_err_set(FN_ENOMEM, "%s/journal: out of memory", case_dir);
    if (!j)
        return NULL;
    journal_path(case_dir, j->path, sizeof j->path);
    j->bind = *b;
    j->fd = durable_open_log(j->path);
    if (j->fd < 0) {
        free(j);
        return NULL;
    }
    off_t end = (off_t)JOURNAL_HEADER_SIZE + (off_t)n * JOURNAL_RECORD_SIZE;
    rc = n == 0 ? journal_truncate(j)
                : lseek(j->fd, end, SEEK_SET) < 0
                      ? fn_err_set(FN_EIO, "%s: seek: %s", j->path, strerror(errno))
                      : 0;
    if (rc < 0) {
        close(j->fd);
        free(j);
        return NULL;
    }
    j->seq = last;
    j->count = n;
    return j;
}

int journal_flush(journal *j)
{
    if (j->used == 0)
        return 0;
    int rc = write_all(j->fd, j->buf, j->used, j->path);
    j->used = 0;
    return rc;
}

static int append(journal *j, const journal_rec *r, int64_t now_us);

int journal_append(journal *j, uint32_t kind, int frag, int64_t t_us, const pose *p, int64_t now_us)
{
    journal_rec r = {kind, frag, ++j->seq, t_us, *p, 0};
    return append(j, &r, now_us);
}

int journal_append_fix(journal *j, int frag, int64_t t_us, const pose *p, int fixed, int64_t now_us)
{
    journal_rec r = {JOURNAL_FIX, frag, ++j->seq, t_us, *p, fixed != 0};
    return append(j, &r, now_us);
}

static int append(journal *j, const journal_rec *r, int64_t now_us)
{
    if (j->used == 0)
        j->oldest_us = now_us;
    encode(j->buf + j->used, r);
    j->used += JOURNAL_RECORD_SIZE;
    j->count++;
    if (j->used == sizeof j->buf)
        return journal_flush(j);
    return journal_tick(j, now_us);
}

int journal_tick(journal *j, int64_t now_us)
{
    return j->used && now_us - j->oldest_us >= JOURNAL_FLUSH_US ? journal_flush(j) : 0;
}

int journal_sync(journal *j)
{
    int rc = journal_flush(j);
    if (rc == 0 && fsync(j->fd) != 0)
        rc = fn_err_set(FN_EIO, "%s: fsync: %s", j->path, strerror(errno));
    return rc;
}

void journal_rebind(journal *j, const journal_bind *b)
{
    j->bind = *b;
}

int journal_truncate(journal *j)
{
    j->used = 0;
    unsigned char h[JOURNAL_HEADER_SIZE];
    header(h, &j->bind);
    if (ftruncate(j->fd, 0) != 0 || lseek(j->fd, 0, SEEK_SET) < 0)
        return fn_err_set(FN_EIO, "%s: truncate: %s", j->path, strerror(errno));
    j->count = 0;
    return write_all(j->fd, h, sizeof h, j->path);
}

typedef struct journal_text {
    const journal_bind *b;
    const journal_rec *recs;
    size_t n;
} journal_text;

static int write_records(durable_file *f, void *ctx)
{
    const journal_text *x = ctx;
    unsigned char h[JOURNAL_HEADER_SIZE], rec[JOURNAL_RECORD_SIZE];
    header(h, x->b);
    int rc = durable_write_all(f, h, sizeof h);
    for (size_t i = 0; rc == 0 && i < x->n; i++) {
        encode(rec, &x->recs[i]);
        rc = durable_write_all(f, rec, sizeof rec);
    }
    return rc;
}

int journal_set_aside(const char *case_dir, const char *tag, const journal_bind *b,
                      const journal_rec *recs, size_t n, char *aside, size_t cap)
{
    char path[4096];
    journal_path(case_dir, path, sizeof path);
    int k = 1;
    for (; k <= 9999; k++) {
        snprintf(aside, cap, "%s.%s.%d", path, tag, k);
        if (access(aside, F_OK) != 0)
            break;
    }
    if (k > 9999)
        return fn_err_set(FN_EIO, "%s: %s.1 to .9999 all exist: remove old ones", path, tag);
    int rc = durable_move(path, aside);
    if (rc < 0)
        return rc;
    journal_text x = {b, recs, n};
    return n ? durable_replace(path, write_records, &x) : 0;
}

uint64_t journal_count(const journal *j)
{
    return j->count;
}

int journal_close(journal *j)
{
    if (!j)
        return 0;
    int rc = journal_flush(j);
    close(j->fd);
    free(j);
    return rc;
}
