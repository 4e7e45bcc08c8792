#include "journal.h"

#include "err.h"
#include "vol.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#define MAGIC "FNJOURNAL1\n"
#define BUF_RECORDS 256

struct journal {
    int fd;
    char path[4096];
    uint64_t seq, count;
    int64_t flush_us, oldest_us;
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
    put32(b + 80, 0);
    put32(b + 84, (uint32_t)crc32(0, b, 84));
}

/* Returns 1 when b holds a record with a good CRC and kind. */
static int decode(const unsigned char *b, journal_rec *r)
{
    if (get32(b + 84) != (uint32_t)crc32(0, b, 84))
        return 0;
    r->kind = get32(b);
    r->frag = (int32_t)get32(b + 4);
    r->seq = get64(b + 8);
    r->t_us = (int64_t)get64(b + 16);
    for (int i = 0; i < 4; i++)
        r->p.q[i] = getf(b + 24 + 8 * i);
    for (int i = 0; i < 3; i++)
        r->p.t[i] = getf(b + 56 + 8 * i);
    return r->kind >= JOURNAL_MOVE && r->kind <= JOURNAL_START;
}

static void header(unsigned char h[JOURNAL_HEADER_SIZE])
{
    memset(h, 0, JOURNAL_HEADER_SIZE);
    memcpy(h, MAGIC, 11);
    put32(h + 12, JOURNAL_RECORD_SIZE);
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

int journal_parse(const uint8_t *buf, size_t len, const char *name, journal_rec **recs, size_t *n,
                  long *torn_at)
{
    *recs = NULL;
    *n = 0;
    if (torn_at)
        *torn_at = -1;
    if (len == 0)
        return 0;
    unsigned char want[JOURNAL_HEADER_SIZE];
    header(want);
    if (len < JOURNAL_HEADER_SIZE || memcmp(buf, want, JOURNAL_HEADER_SIZE) != 0)
        return fn_err_set(FN_EFORMAT, "%s: offset 0: not a fracnav journal (bad header)", name);
    size_t whole = (len - JOURNAL_HEADER_SIZE) / JOURNAL_RECORD_SIZE;
    if (whole > 0) {
        *recs = malloc(whole * sizeof **recs);
        if (!*recs)
            return fn_err_set(FN_ENOMEM, "%s: out of memory for %zu records", name, whole);
    }
    size_t off = JOURNAL_HEADER_SIZE;
    while (off + JOURNAL_RECORD_SIZE <= len && decode(buf + off, &(*recs)[*n])) {
        (*n)++;
        off += JOURNAL_RECORD_SIZE;
    }
    if (off < len && torn_at)
        *torn_at = (long)off;
    return 0;
}

int journal_read(const char *case_dir, journal_rec **recs, size_t *n, long *torn_at)
{
    char path[4096];
    journal_path(case_dir, path, sizeof path);
    *recs = NULL;
    *n = 0;
    if (torn_at)
        *torn_at = -1;
    FILE *f = fopen(path, "rb");
    if (!f)
        return errno == ENOENT ? 0 : fn_err_set(FN_EIO, "%s: cannot open: %s", path, strerror(errno));
    struct stat sb;
    int rc = fstat(fileno(f), &sb) == 0 ? 0 : fn_err_set(FN_EIO, "%s: %s", path, strerror(errno));
    size_t len = rc == 0 ? (size_t)sb.st_size : 0;
    if (rc == 0 && len > vol_budget())
        rc = fn_err_set(FN_ENOMEM, "%s: %zu bytes, over the memory budget", path, len);
    uint8_t *buf = rc == 0 ? malloc(len ? len : 1) : NULL;
    if (rc == 0 && !buf)
        rc = fn_err_set(FN_ENOMEM, "%s: out of memory for %zu bytes", path, len);
    if (rc == 0 && fread(buf, 1, len, f) != len)
        rc = fn_err_set(FN_EIO, "%s: read failed", path);
    fclose(f);
    if (rc == 0)
        rc = journal_parse(buf, len, path, recs, n, torn_at);
    free(buf);
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

journal *journal_open(const char *case_dir)
{
    journal_rec *recs;
    size_t n;
    long torn;
    if (journal_read(case_dir, &recs, &n, &torn) < 0)
        return NULL;
    uint64_t last = n ? recs[n - 1].seq : 0;
    free(recs);
    journal *j = calloc(1, sizeof *j);
    if (!j) {
        fn_err_set(FN_ENOMEM, "%s/journal: out of memory", case_dir);
        return NULL;
    }
    journal_path(case_dir, j->path, sizeof j->path);
    j->fd = open(j->path, O_WRONLY | O_CREAT | O_CLOEXEC, 0644);
    if (j->fd < 0) {
        fn_err_set(FN_EIO, "%s: cannot open for writing: %s", j->path, strerror(errno));
        free(j);
        return NULL;
    }
    /* Keep the valid records, cut a torn tail, write a header into an empty file. */
    off_t end = (off_t)JOURNAL_HEADER_SIZE + (off_t)n * JOURNAL_RECORD_SIZE;
    int rc = 0;
    if (n == 0) {
        unsigned char h[JOURNAL_HEADER_SIZE];
        header(h);
        rc = ftruncate(j->fd, 0) == 0 ? write_all(j->fd, h, sizeof h, j->path)
                                      : fn_err_set(FN_EIO, "%s: truncate: %s", j->path, strerror(errno));
    } else if ((torn >= 0 && ftruncate(j->fd, end) != 0) || lseek(j->fd, end, SEEK_SET) < 0) {
        rc = fn_err_set(FN_EIO, "%s: cannot cut the torn tail at offset %ld: %s", j->path, torn,
                        strerror(errno));
    }
    if (rc < 0) {
        close(j->fd);
        free(j);
        return NULL;
    }
    j->seq = last;
    j->count = n;
    j->flush_us = 50000;
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

int journal_append(journal *j, uint32_t kind, int frag, int64_t t_us, const pose *p, int64_t now_us)
{
    journal_rec r = {kind, frag, ++j->seq, t_us, *p};
    if (j->used == 0)
        j->oldest_us = now_us;
    encode(j->buf + j->used, &r);
    j->used += JOURNAL_RECORD_SIZE;
    j->count++;
    if (j->used == sizeof j->buf)
        return journal_flush(j);
    return journal_tick(j, now_us);
}

int journal_tick(journal *j, int64_t now_us)
{
    return j->used && now_us - j->oldest_us >= j->flush_us ? journal_flush(j) : 0;
}

int journal_sync(journal *j)
{
    int rc = journal_flush(j);
    if (rc == 0 && fsync(j->fd) != 0)
        rc = fn_err_set(FN_EIO, "%s: fsync: %s", j->path, strerror(errno));
    return rc;
}

int journal_truncate(journal *j)
{
    j->used = 0;
    unsigned char h[JOURNAL_HEADER_SIZE];
    header(h);
    if (ftruncate(j->fd, 0) != 0 || lseek(j->fd, 0, SEEK_SET) < 0)
        return fn_err_set(FN_EIO, "%s: truncate: %s", j->path, strerror(errno));
    j->count = 0;
    return write_all(j->fd, h, sizeof h, j->path);
}

uint64_t journal_count(const journal *j)
{
    return j->count;
}

void journal_set_flush_us(journal *j, int64_t flush_us)
{
    j->flush_us = flush_us;
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
