/* durable: atomic replace of a file, the journal's append-only file, temporaries swept, and the
 * sha256 that binds a case to its files (see durable.h). */
#define _GNU_SOURCE /* O_NOFOLLOW, O_DIRECTORY */
#include "durable.h"

#include "err.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* ---- sha256 (FIPS 180-4) ---- */

typedef struct sha256_ctx {
    uint32_t h[8];
    uint8_t buf[64];
    size_t fill;
    uint64_t bytes;
    int portable; /* 1: the portable rounds even where the SHA extensions are (durable__sha256_portable) */
} sha256_ctx;

static const uint32_t sha_k[64] = {
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
    0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
    0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
    0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
    0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
    0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
    0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
    0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2};

static uint32_t ror(uint32_t x, int n)
{
    return (x >> n) | (x << (32 - n));
}

static void sha_block(uint32_t h[8], const uint8_t *p)
{
    uint32_t w[64];
    for (int i = 0; i < 16; i++)
        w[i] = (uint32_t)p[4 * i] << 24 | (uint32_t)p[4 * i + 1] << 16 | (uint32_t)p[4 * i + 2] << 8 |
               p[4 * i + 3];
    for (int i = 16; i < 64; i++) {
        uint32_t s0 = ror(w[i - 15], 7) ^ ror(w[i - 15], 18) ^ (w[i - 15] >> 3);
        uint32_t s1 = ror(w[i - 2], 17) ^ ror(w[i - 2], 19) ^ (w[i - 2] >> 10);
        w[i] = w[i - 16] + s0 + w[i - 7] + s1;
    }
    uint32_t a = h[0], b = h[1], c = h[2], d = h[3], e = h[4], f = h[5], g = h[6], k = h[7];
    for (int i = 0; i < 64; i++) {
        uint32_t t1 = k + (ror(e, 6) ^ ror(e, 11) ^ ror(e, 25)) + ((e & f) ^ (~e & g)) + sha_k[i] + w[i];
        uint32_t t2 = (ror(a, 2) ^ ror(a, 13) ^ ror(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
        k = g;
        g = f;
        f = e;
        e = d + t1;
        d = c;
        c = b;
        b = a;
        a = t1 + t2;
    }
    h[0] += a, h[1] += b, h[2] += c, h[3] += d, h[4] += e, h[5] += f, h[6] += g, h[7] += k;
}

static void sha_init(sha256_ctx *s)
{
    static const uint32_t h0[8] = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
                                   0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
    memcpy(s->h, h0, sizeof h0);
    s->fill = 0;
    s->bytes = 0;
    s->portable = 0;
}

/* The x86 SHA extensions: the same rounds, four at a time (two sha256rnds2 per four), with the
 * state held as ABEF and CDGH. Chosen at run time where the processor has them (cpuid); the
 * portable sha_block elsewhere, and for a test that compares the two. */
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <cpuid.h>
#include <immintrin.h>

__attribute__((target("sha,sse4.1,ssse3"))) static void sha_blocks_x86(uint32_t h[8], const uint8_t *p, size_t n)
{
    const __m128i swap = _mm_set_epi64x(0x0c0d0e0f08090a0bLL, 0x0405060700010203LL); /* big-endian words */
    __m128i dcba = _mm_loadu_si128((const __m128i *)&h[0]), hgfe = _mm_loadu_si128((const __m128i *)&h[4]);
    __m128i cdab = _mm_shuffle_epi32(dcba, 0xB1), efgh = _mm_shuffle_epi32(hgfe, 0x1B);
    __m128i abef = _mm_alignr_epi8(cdab, efgh, 8), cdgh = _mm_blend_epi16(efgh, cdab, 0xF0);
    for (; n; n--, p += 64) {
        __m128i save0 = abef, save1 = cdgh, x[4];
        for (int g = 0; g < 16; g++) {
            __m128i w;
            if (g < 4)
                w = _mm_shuffle_epi8(_mm_loadu_si128((const __m128i *)(p + 16 * g)), swap);
            else { /* W[t-16] + s0(W[t-15]) + W[t-7], then + s1(W[t-2]) */
                __m128i t = _mm_add_epi32(_mm_sha256msg1_epu32(x[g & 3], x[(g + 1) & 3]),
                                          _mm_alignr_epi8(x[(g + 3) & 3], x[(g + 2) & 3], 4));
                w = _mm_sha256msg2_epu32(t, x[(g + 3) & 3]);
            }
            x[g & 3] = w;
            __m128i m = _mm_add_epi32(w, _mm_loadu_si128((const __m128i *)&sha_k[4 * g]));
            cdgh = _mm_sha256rnds2_epu32(cdgh, abef, m);
            abef = _mm_sha256rnds2_epu32(abef, cdgh, _mm_shuffle_epi32(m, 0x0E));
        }
        abef = _mm_add_epi32(abef, save0);
        cdgh = _mm_add_epi32(cdgh, save1);
    }
    __m128i feba = _mm_shuffle_epi32(abef, 0x1B), dchg = _mm_shuffle_epi32(cdgh, 0xB1);
    _mm_storeu_si128((__m128i *)&h[0], _mm_blend_epi16(feba, dchg, 0xF0));
    _mm_storeu_si128((__m128i *)&h[4], _mm_alignr_epi8(dchg, feba, 8));
}

static int sha_x86(void)
{
    static atomic_int have = -1; /* -1: not asked yet */
    int v = atomic_load(&have);
    if (v < 0) {
        unsigned a, b, c, d, b7 = 0;
        v = __get_cpuid(1, &a, &b, &c, &d) && (c & bit_SSE4_1) && (c & bit_SSSE3) &&
            __get_cpuid_count(7, 0, &a, &b7, &c, &d) && (b7 & (1u << 29)); /* leaf 7 EBX bit 29: SHA */
        atomic_store(&have, v);
    }
    return v;
}
#endif

/* n whole 64-byte blocks into s's state. */
static void sha_blocks(sha256_ctx *s, const uint8_t *p, size_t n)
{
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
    if (!s->portable && sha_x86()) {
        sha_blocks_x86(s->h, p, n);
        return;
    }
#endif
    for (; n; n--, p += 64)
        sha_block(s->h, p);
}

static void sha_update(sha256_ctx *s, const uint8_t *p, size_t n)
{
    s->bytes += n;
    if (s->fill) {
        size_t take = 64 - s->fill < n ? 64 - s->fill : n;
        memcpy(s->buf + s->fill, p, take);
        s->fill += take;
        p += take;
        n -= take;
        if (s->fill < 64)
            return;
        sha_blocks(s, s->buf, 1);
        s->fill = 0;
    }
    sha_blocks(s, p, n / 64);
    memcpy(s->buf, p + n / 64 * 64, n % 64);
    s->fill = n % 64;
}

static void sha_final(sha256_ctx *s, char hex[65])
{
    uint64_t bits = s->bytes * 8;
    uint8_t pad = 0x80, zero = 0, len[8];
    sha_update(s, &pad, 1);
    while (s->fill != 56)
        sha_update(s, &zero, 1);
    for (int i = 0; i < 8; i++)
        len[i] = (uint8_t)(bits >> (56 - 8 * i));
    sha_update(s, len, 8);
    for (int i = 0; i < 8; i++)
        snprintf(hex + 8 * i, 9, "%08x", s->h[i]);
}

void durable_sha256(const void *data, size_t len, char hex[65])
{
    sha256_ctx s;
    sha_init(&s);
    sha_update(&s, data, len);
    sha_final(&s, hex);
}

void durable__sha256_portable(const void *data, size_t len, char hex[65])
{
    sha256_ctx s;
    sha_init(&s);
    s.portable = 1;
    sha_update(&s, data, len);
    sha_final(&s, hex);
}

int durable_open_regular(const char *path, const char *what)
{
    /* O_NONBLOCK: opening a FIFO must not wait for a writer before it can be refused. */
    int fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0)
        return fn_err_set(FN_EIO, "%s: cannot open%s%s: %s", path, what ? " " : "", what ? what : "",
                          strerror(errno));
    struct stat sb;
    if (fstat(fd, &sb) != 0 || !S_ISREG(sb.st_mode)) {
        close(fd);
        return fn_err_set(FN_EIO, "%s: not a regular file (a folder, FIFO or device)%s%s", path,
                          what ? ": " : "", what ? what : "");
    }
    fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) & ~O_NONBLOCK);
    return fd;
}

int durable_file_sha256(const char *path, char hex[65])
{
    int fd = durable_open_regular(path, NULL);
    if (fd < 0)
        return fd;
    sha256_ctx s;
    sha_init(&s);
    uint8_t buf[1 << 16];
    ssize_t n;
    while ((n = read(fd, buf, sizeof buf)) != 0) {
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0) {
            int e = errno;
            close(fd);
            return fn_err_set(FN_EIO, "%s: read error: %s", path, strerror(e));
        }
        sha_update(&s, buf, (size_t)n);
    }
    close(fd);
    sha_final(&s, hex);
    return 0;
}

/* ---- atomic replace ---- */

static atomic_uint tmp_counter;

/* path split into its folder (".", "/" or the part before the last slash) and its last name. */
static int split_path(const char *path, char *dir, size_t cap, const char **name)
{
    const char *slash = strrchr(path, '/');
    *name = slash ? slash + 1 : path;
    if (!**name)
        return fn_err_set(FN_EINVAL, "%s: names a folder, not a file", path);
    int n = slash == path ? snprintf(dir, cap, "/")
                          : slash ? snprintf(dir, cap, "%.*s", (int)(slash - path), path)
                                  : snprintf(dir, cap, ".");
    return n < 0 || (size_t)n >= cap ? fn_err_set(FN_EINVAL, "%s: path too long", path) : 0;
}

/* 0 when path is missing or a regular file (not a link): what may be replaced. */
static int check_target(const char *path)
{
    struct stat sb;
    if (lstat(path, &sb) != 0)
        return errno == ENOENT ? 0 : fn_err_set(FN_EIO, "%s: %s", path, strerror(errno));
    if (S_ISLNK(sb.st_mode))
        return fn_err_set(FN_EIO, "%s is a symbolic link: fracnav neither writes through it nor "
                                  "replaces it; remove it or name another path", path);
    if (!S_ISREG(sb.st_mode))
        return fn_err_set(FN_EIO, "%s is not a regular file (a folder, FIFO or device): fracnav "
                                  "does not replace it", path);
    return 0;
}

/* 1 when f->tmp is still the regular file durable_create made. */
static int still_ours(const durable_file *f)
{
    struct stat sb;
    return lstat(f->tmp, &sb) == 0 && S_ISREG(sb.st_mode) && sb.st_dev == f->dev && sb.st_ino == f->ino;
}

/* The next temporary's name for path into f->tmp (durable_create's), after sweeping its folder. */
static int temp_name(durable_file *f, const char *path)
{
    char dir[4096];
    const char *name;
    f->fd = -1;
    f->tmp[0] = '\0';
    int rc = split_path(path, dir, sizeof dir, &name);
    if (rc < 0)
        return rc;
    durable_sweep(dir, 0);
    int n = snprintf(f->tmp, sizeof f->tmp, "%s/" DURABLE_TMP_TAG "%ld-%u-%s", dir, (long)getpid(),
                     atomic_fetch_add(&tmp_counter, 1), name);
    if (n < 0 || (size_t)n >= sizeof f->tmp) {
        f->tmp[0] = '\0';
        return fn_err_set(FN_EINVAL, "%s: path too long", path);
    }
    return 0;
}

int durable_create(durable_file *f, const char *path)
{
    int rc = temp_name(f, path);
    if (rc < 0)
        return rc;
    f->fd = open(f->tmp, O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
    struct stat sb;
    if (f->fd >= 0 && fstat(f->fd, &sb) == 0) {
        f->dev = sb.st_dev;
        f->ino = sb.st_ino;
        return 0;
    }
    rc = fn_err_set(FN_EIO, "%s: cannot create a temporary beside it (%s): %s", path, f->tmp,
                    strerror(errno));
    if (f->fd >= 0) { /* made, but not to be trusted */
        close(f->fd);
        unlink(f->tmp);
    }
    f->fd = -1;
    f->tmp[0] = '\0';
    return rc;
}

int durable_link(durable_file *f, const char *src, const char *path)
{
    struct stat sb;
    int rc = temp_name(f, path);
    if (rc < 0)
        return rc;
    if (lstat(src, &sb) != 0)
        rc = fn_err_set(FN_EIO, "%s: %s", src, strerror(errno));
    else if (!S_ISREG(sb.st_mode))
        rc = fn_err_set(FN_EIO, "%s is not a regular file (a link, a folder): not linked", src);
    else if (link(src, f->tmp) != 0)
        rc = fn_err_set(FN_EIO, "%s: cannot link %s beside it (%s): %s", path, src, f->tmp, strerror(errno));
    if (rc < 0) {
        f->tmp[0] = '\0';
        return rc;
    }
    f->dev = sb.st_dev;
    f->ino = sb.st_ino;
    return 0;
}

int durable_write_all(durable_file *f, const void *p, size_t n)
{
    const char *c = p;
    while (n) {
        ssize_t w = write(f->fd, c, n);
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0)
            return fn_err_set(FN_EIO, "%s: write failed: %s", f->tmp, w < 0 ? strerror(errno) : "no space");
        c += w;
        n -= (size_t)w;
    }
    return 0;
}

FILE *durable_stream(durable_file *f)
{
    int fd = dup(f->fd);
    FILE *fp = fd >= 0 ? fdopen(fd, "wb") : NULL;
    if (!fp) {
        fn_err_set(FN_EIO, "%s: %s", f->tmp, strerror(errno));
        if (fd >= 0)
            close(fd);
    }
    return fp;
}

int durable_seal(durable_file *f)
{
    if (!still_ours(f))
        return fn_err_set(FN_EIO, "%s: the temporary was replaced while it was written (a link or "
                                  "another file put in its place): not used", f->tmp);
    int rc = fsync(f->fd) != 0 ? fn_err_set(FN_EIO, "%s: fsync failed: %s", f->tmp, strerror(errno)) : 0;
    if (close(f->fd) != 0 && rc == 0)
        rc = fn_err_set(FN_EIO, "%s: close failed: %s", f->tmp, strerror(errno));
    f->fd = -1;
    return rc;
}

int durable_rename(durable_file *f, const char *path)
{
    int rc = check_target(path);
    if (rc == 0 && !still_ours(f))
        rc = fn_err_set(FN_EIO, "%s: the temporary %s is no longer the file written for it (a link "
                                "or another file put in its place): not used", path, f->tmp);
    if (rc == 0 && rename(f->tmp, path) != 0)
        rc = fn_err_set(FN_EIO, "%s: cannot put %s in its place: %s", path, f->tmp, strerror(errno));
    if (rc == 0)
        f->tmp[0] = '\0';
    return rc;
}

void durable_abort(durable_file *f)
{
    if (f->fd >= 0)
        close(f->fd);
    f->fd = -1;
    if (f->tmp[0] && still_ours(f))
        unlink(f->tmp);
    f->tmp[0] = '\0';
}

int durable_sync_path(const char *path)
{
    int fd = open(path, O_RDONLY | O_NOFOLLOW | O_CLOEXEC | O_NONBLOCK);
    if (fd < 0)
        return fn_err_set(FN_EIO, "%s: cannot open to sync: %s", path, strerror(errno));
    int rc = fsync(fd);
    int e = errno;
    close(fd);
    /* Some file systems cannot sync a folder (EINVAL): nothing more can be done there. */
    return rc && e != EINVAL ? fn_err_set(FN_EIO, "%s: fsync failed: %s", path, strerror(e)) : 0;
}

int durable_move(const char *from, const char *to)
{
    char dir[4096];
    const char *name;
    struct stat sb;
    int rc = split_path(to, dir, sizeof dir, &name);
    if (rc == 0 && (lstat(from, &sb) != 0 || !S_ISREG(sb.st_mode)))
        rc = fn_err_set(FN_EIO, "%s: not moved to %s: it is missing or not a regular file", from, to);
    if (rc == 0)
        rc = check_target(to);
    if (rc == 0 && rename(from, to) != 0)
        rc = fn_err_set(FN_EIO, "%s: cannot move to %s: %s", from, to, strerror(errno));
    return rc ? rc : durable_sync_path(dir);
}

/* A writer's message names the temporary file: name the target, the path the user gave, instead. */
static int name_target(int rc, const char *tmp, const char *path)
{
    char msg[1024];
    const char *m = fn_err_msg(), *at = strstr(m, tmp);
    if (!at)
        return rc;
    snprintf(msg, sizeof msg, "%.*s%s%s", (int)(at - m), m, path, at + strlen(tmp));
    return fn_err_set(rc, "%s", msg);
}

int durable_replace(const char *path, int (*write)(durable_file *f, void *ctx), void *ctx)
{
    char dir[4096];
    const char *name;
    durable_file f;
    int rc = split_path(path, dir, sizeof dir, &name);
    if (rc == 0)
        rc = check_target(path);
    if (rc == 0)
        rc = durable_create(&f, path);
    if (rc < 0)
        return rc;
    rc = write(&f, ctx);
    if (rc < 0)
        rc = name_target(rc, f.tmp, path);
    if (rc == 0)
        rc = durable_seal(&f);
    if (rc == 0)
        rc = durable_rename(&f, path);
    if (rc == 0)
        rc = durable_sync_path(dir);
    durable_abort(&f);
    return rc;
}

typedef struct bytes {
    const void *p;
    size_t n;
} bytes;

static int write_bytes(durable_file *f, void *ctx)
{
    const bytes *b = ctx;
    return durable_write_all(f, b->p, b->n);
}

int durable_replace_bytes(const char *path, const void *p, size_t n)
{
    bytes b = {p, n};
    return durable_replace(path, write_bytes, &b);
}

int durable_open_log(const char *path)
{
    int fd = open(path, O_WRONLY | O_CREAT | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC, 0644);
    if (fd < 0 && errno == ELOOP)
        return fn_err_set(FN_EIO, "%s is a symbolic link: fracnav does not write through it; remove "
                                  "it", path);
    if (fd < 0)
        return fn_err_set(FN_EIO, "%s: cannot open for writing: %s", path, strerror(errno));
    struct stat sb;
    if (fstat(fd, &sb) != 0 || !S_ISREG(sb.st_mode)) {
        close(fd);
        return fn_err_set(FN_EIO, "%s: not a regular file (a folder, FIFO or device): fracnav does "
                                  "not write to it", path);
    }
    fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) & ~O_NONBLOCK);
    return fd;
}

/* ---- leftovers ---- */

int durable_sweep(const char *dir, int all)
{
    DIR *d = opendir(dir);
    if (!d)
        return 0;
    size_t tl = strlen(DURABLE_TMP_TAG);
    int removed = 0;
    struct dirent *e;
    char p[8400];
    while ((e = readdir(d))) {
        if (strncmp(e->d_name, DURABLE_TMP_TAG, tl))
            continue;
        char *end;
        long pid = strtol(e->d_name + tl, &end, 10);
        if (*end != '-' || pid <= 0 || pid == (long)getpid())
            continue;
        if (!all && (kill((pid_t)pid, 0) == 0 || errno != ESRCH))
            continue;
        snprintf(p, sizeof p, "%s/%s", dir, e->d_name);
        struct stat sb;
        if (lstat(p, &sb) == 0 && !S_ISDIR(sb.st_mode) && unlink(p) == 0) {
            fprintf(stderr, "fracnav: removed %s, left by an interrupted run (pid %ld)\n", p, pid);
            removed++;
        }
    }
    closedir(d);
    return removed;
}

/* The folder that holds path, links resolved, into where (PATH_MAX). 0, or FN_EINVAL naming path
 * when that folder does not exist. */
static int holding_folder(const char *path, char *where)
{
    char resolved[PATH_MAX], parent[PATH_MAX];
    snprintf(parent, sizeof parent, "%s", realpath(path, resolved) ? resolved : path);
    size_t n = strlen(parent);
    while (n > 1 && parent[n - 1] == '/')
        parent[--n] = '\0';
    char *slash = strrchr(parent, '/');
    if (!slash)
        snprintf(parent, sizeof parent, ".");
    else if (slash == parent)
        parent[1] = '\0'; /* the root */
    else
        *slash = '\0';
    if (!realpath(parent, where))
        return fn_err_set(FN_EINVAL, "%s: its folder %s does not exist", path, parent);
    return 0;
}

int durable_out_of_case(const char *path)
{
    char where[PATH_MAX], json[PATH_MAX + 16];
    int rc = holding_folder(path, where);
    if (rc == 0)
        snprintf(json, sizeof json, "%s/" DURABLE_CASE_FILE, where);
    if (rc == 0 && access(json, F_OK) == 0)
        rc = fn_err_set(FN_EINVAL, "%s lies in the case folder %s, whose files only the case's own "
                                   "saves write: choose a path outside it", path, where);
    return rc;
}
