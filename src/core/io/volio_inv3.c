/* volio_inv3: InVesalius 3 projects (.inv3): a gzip'd tar holding main.plist (XML) and the raw
 * little-endian voxel matrix it names. The tar headers and the plist are parsed here. */
#include "volio_impl.h"

#include "err.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#define PLIST_MAX (1 << 20) /* main.plist is ~1.5 KB; anything far bigger is not a project */
#define NODE_MAX 4096
#define DEPTH_MAX 32
#define NAME_MAX_LEN 4096
#define FILENAME_LEN 256 /* matrix.filename, a plain file name */
#define ENTRIES_MAX 4096 /* a project holds a few dozen files; more is not one */

/* ---- plist: a tree of nodes over the XML bytes ---- */

enum { P_DICT, P_ARRAY, P_STRING, P_INT, P_REAL, P_BOOL, P_OTHER };

typedef struct {
    int type;
    const char *key, *text; /* key: the dict key naming this node; text: its content */
    size_t keylen, textlen;
    int child, next; /* first child and next sibling, -1 for none */
} pnode;

typedef struct {
    const char *s;
    size_t len, pos;
    pnode *nodes;
    int n;
    const char *err; /* what went wrong, at pos */
} plist;

static void skip_space(plist *p)
{
    for (;;) {
        while (p->pos < p->len && strchr(" \t\r\n", p->s[p->pos]))
            p->pos++;
        const char *open = p->pos + 4 <= p->len && !memcmp(p->s + p->pos, "<!--", 4)   ? "-->"
                           : p->pos + 2 <= p->len && (!memcmp(p->s + p->pos, "<?", 2) ||
                                                      !memcmp(p->s + p->pos, "<!", 2)) ? ">"
                                                                                       : NULL;
        if (!open)
            return;
        const char *end = NULL;
        size_t olen = strlen(open);
        for (size_t i = p->pos + 2; i + olen <= p->len; i++)
            if (!memcmp(p->s + i, open, olen)) {
                end = p->s + i;
                break;
            }
        p->pos = end ? (size_t)(end - p->s) + olen : p->len;
    }
}

/* Reads "<name>" or "<name/>" or "<name attr...>" at pos; returns 1 if self-closing, 0 if open,
 * -1 on error. */
static int read_tag(plist *p, char *name, size_t cap)
{
    skip_space(p);
    if (p->pos >= p->len || p->s[p->pos] != '<') {
        p->err = "expected a tag";
        return -1;
    }
    size_t i = ++p->pos, n = 0;
    while (i < p->len && !strchr(" \t\r\n/>", p->s[i]) && n + 1 < cap)
        name[n++] = p->s[i++];
    name[n] = '\0';
    while (i < p->len && p->s[i] != '>')
        i++;
    if (i >= p->len) {
        p->err = "unterminated tag";
        return -1;
    }
    p->pos = i + 1;
    return p->s[i - 1] == '/';
}

static int expect_close(plist *p, const char *name)
{
    char got[32];
    skip_space(p);
    size_t at = p->pos;
    if (at + 2 > p->len || memcmp(p->s + at, "</", 2) != 0) {
        p->err = "expected a closing tag";
        return -1;
    }
    size_t n = 0, i = at + 2;
    while (i < p->len && p->s[i] != '>' && n + 1 < sizeof got)
        got[n++] = p->s[i++];
    got[n] = '\0';
    if (i >= p->len || strcmp(got, name) != 0) {
        p->pos = at;
        p->err = "mismatched closing tag";
        return -1;
    }
    p->pos = i + 1;
    return 0;
}

/* Text up to the next '<'; the closing tag must follow. */
static int read_text(plist *p, const char *name, const char **text, size_t *len)
{
    size_t start = p->pos;
    while (p->pos < p->len && p->s[p->pos] != '<')
        p->pos++;
    *text = p->s + start;
    *len = p->pos - start;
    return expect_close(p, name);
}

static int parse_value(plist *p, int depth);

static int new_node(plist *p, int type)
{
    if (p->n >= NODE_MAX) {
        p->err = "too many elements";
        return -1;
    }
    pnode *nd = &p->nodes[p->n];
    memset(nd, 0, sizeof *nd);
    nd->type = type;
    nd->child = nd->next = -1;
    return p->n++;
}

/* Parses children until </name>; dicts read a <key> before each value. */
static int parse_children(plist *p, int self, const char *name, int depth)
{
    int is_dict = !strcmp(name, "dict"), last = -1;
    for (;;) {
        skip_space(p);
        if (p->pos + 2 <= p->len && !memcmp(p->s + p->pos, "</", 2))
            return expect_close(p, name);
        const char *key = NULL;
        size_t keylen = 0;
        if (is_dict) {
            char tag[32];
            if (read_tag(p, tag, sizeof tag) != 0 || strcmp(tag, "key") != 0) {
                p->err = p->err ? p->err : "expected <key> in <dict>";
                return -1;
            }
            if (read_text(p, "key", &key, &keylen) < 0)
                return -1;
        }
        int c = parse_value(p, depth + 1);
        if (c < 0)
            return -1;
        p->nodes[c].key = key;
        p->nodes[c].keylen = keylen;
        if (last < 0)
            p->nodes[self].child = c;
        else
            p->nodes[last].next = c;
        last = c;
    }
}

static int parse_value(plist *p, int depth)
{
    char tag[32];
    if (depth > DEPTH_MAX) {
        p->err = "nested too deeply";
        return -1;
    }
    int selfclose = read_tag(p, tag, sizeof tag);
    if (selfclose < 0)
        return -1;
    int type = !strcmp(tag, "dict")                               ? P_DICT
               : !strcmp(tag, "array")                            ? P_ARRAY
               : !strcmp(tag, "string")                           ? P_STRING
               : !strcmp(tag, "integer")                          ? P_INT
               : !strcmp(tag, "real")                             ? P_REAL
               : !strcmp(tag, "true") || !strcmp(tag, "false")    ? P_BOOL
               : !strcmp(tag, "date") || !strcmp(tag, "data")     ? P_OTHER
                                                                  : -1;
    if (type < 0) {
        p->err = "unknown element";
        return -1;
    }
    int self = new_node(p, type);
    if (self < 0 || selfclose)
        return self;
    if (type == P_DICT || type == P_ARRAY)
        return parse_children(p, self, tag, depth) < 0 ? -1 : self;
    if (type == P_BOOL)
        return expect_close(p, tag) < 0 ? -1 : self;
    return read_text(p, tag, &p->nodes[self].text, &p->nodes[self].textlen) < 0 ? -1 : self;
}

/* Parses the document; returns the root value's node or -1 with p->err set. */
static int plist_parse(plist *p)
{
    char tag[32];
    if (read_tag(p, tag, sizeof tag) != 0 || strcmp(tag, "plist") != 0) {
        p->err = p->err ? p->err : "expected <plist>";
        return -1;
    }
    int root = parse_value(p, 0);
    if (root < 0 || expect_close(p, "plist") < 0)
        return -1;
    return root;
}

static int dict_get(const plist *p, int dict, const char *key)
{
    if (dict < 0 || p->nodes[dict].type != P_DICT)
        return -1;
    size_t n = strlen(key);
    for (int c = p->nodes[dict].child; c >= 0; c = p->nodes[c].next)
        if (p->nodes[c].keylen == n && !memcmp(p->nodes[c].key, key, n))
            return c;
    return -1;
}

/* Copies a node's text, trimmed, into buf; 0 if it fits. */
static int node_text(const plist *p, int nd, char *buf, size_t cap)
{
    const char *t = p->nodes[nd].text;
    size_t n = p->nodes[nd].textlen;
    while (n && strchr(" \t\r\n", *t))
        t++, n--;
    while (n && strchr(" \t\r\n", t[n - 1]))
        n--;
    if (n >= cap)
        return -1;
    if (n) /* an empty element (<string/>) has no text at all */
        memcpy(buf, t, n);
    buf[n] = '\0';
    return 0;
}

static int node_number(const plist *p, int nd, double *out)
{
    char buf[64], *end;
    if (nd < 0 || (p->nodes[nd].type != P_INT && p->nodes[nd].type != P_REAL) ||
        node_text(p, nd, buf, sizeof buf) < 0 || !buf[0])
        return -1;
    errno = 0;
    *out = strtod(buf, &end);
    return *end || errno || !isfinite(*out) ? -1 : 0;
}

/* Reads exactly 3 numbers from an array node. */
static int node_triple(const plist *p, int nd, double out[3])
{
    if (nd < 0 || p->nodes[nd].type != P_ARRAY)
        return -1;
    int c = p->nodes[nd].child, n = 0;
    for (; c >= 0 && n < 3; c = p->nodes[c].next, n++)
        if (node_number(p, c, &out[n]) < 0)
            return -1;
    return n == 3 && c < 0 ? 0 : -1;
}

/* ---- what the reader needs from main.plist ---- */

typedef struct {
    char filename[FILENAME_LEN];
    int64_t shape[3]; /* nk, nj, ni */
    double spacing[3];
    vol_type type;
} inv3_info;

static int dtype_of(const char *s, vol_type *t)
{
    static const char *names[] = {"uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"};
    for (int i = 0; i <= VOL_F64; i++)
        if (!strcmp(s, names[i])) {
            *t = (vol_type)i;
            return 0;
        }
    return -1;
}

static int orientation_ok(const plist *p, int nd)
{
    char buf[32];
    double v;
    if (nd < 0)
        return 1;
    if (p->nodes[nd].type == P_STRING)
        return node_text(p, nd, buf, sizeof buf) == 0 &&
               (!strcmp(buf, "AXIAL") || !strcmp(buf, "CORONAL") || !strcmp(buf, "SAGITAL") ||
                !strcmp(buf, "SAGITTAL"));
    return node_number(p, nd, &v) == 0 && v == floor(v) && v >= 0 && v <= 3;
}

static int read_info(char *text, size_t len, const char *path, inv3_info *info)
{
    pnode *nodes = malloc(NODE_MAX * sizeof *nodes);
    if (!nodes)
        return fn_err_set(FN_ENOMEM, "%s: main.plist: out of memory", path);
    plist p = {text, len, 0, nodes, 0, NULL};
    int rc = 0, root = plist_parse(&p);
    char buf[64];
    if (root < 0) {
        rc = fn_err_set(FN_EFORMAT, "%s: main.plist: offset %zu: %s", path, p.pos, p.err);
        goto out;
    }
    int matrix = dict_get(&p, root, "matrix");
    int fname = dict_get(&p, matrix, "filename"), dtype = dict_get(&p, matrix, "dtype");
    double shape[3];
    if (matrix < 0 || p.nodes[matrix].type != P_DICT) {
        rc = fn_err_set(FN_EFORMAT, "%s: main.plist: no 'matrix' dictionary", path);
    } else if (fname < 0 || p.nodes[fname].type != P_STRING ||
               node_text(&p, fname, info->filename, sizeof info->filename) < 0 ||
               !info->filename[0] || strchr(info->filename, '/')) {
        rc = fn_err_set(FN_EFORMAT, "%s: main.plist: matrix.filename missing or not a plain file name", path);
    } else if (dtype < 0 || node_text(&p, dtype, buf, sizeof buf) < 0 || dtype_of(buf, &info->type) < 0) {
        rc = fn_err_set(FN_EFORMAT, "%s: main.plist: matrix.dtype missing or unsupported (uint8..float64)", path);
    } else if (node_triple(&p, dict_get(&p, matrix, "shape"), shape) < 0) {
        rc = fn_err_set(FN_EFORMAT, "%s: main.plist: matrix.shape must be 3 integers", path);
    } else if (node_triple(&p, dict_get(&p, root, "spacing"), info->spacing) < 0) {
        rc = fn_err_set(FN_EFORMAT, "%s: main.plist: spacing must be 3 numbers", path);
    } else if (volio__check_spacing(info->spacing, path, "main.plist: spacing") < 0) {
        rc = FN_EFORMAT; /* the message names the axis */
    } else if (!orientation_ok(&p, dict_get(&p, root, "orientation"))) {
        rc = fn_err_set(FN_EFORMAT, "%s: main.plist: orientation must be 0-3 or AXIAL/CORONAL/SAGITAL", path);
    } else {
        for (int a = 0; a < 3; a++) {
            if (shape[a] != floor(shape[a]) || shape[a] < -1e12 || shape[a] > 1e12) {
                rc = fn_err_set(FN_EFORMAT, "%s: main.plist: matrix.shape[%d] = %g is not an integer", path, a, shape[a]);
                break;
            }
            info->shape[a] = (int64_t)shape[a];
        }
    }
out:
    free(nodes);
    return rc;
}

/* ---- the tar stream ---- */

typedef struct {
    gzFile gz;
    const char *path;
} stream;

/* got < 0: zlib's error; else a short read. */
static int gz_fail(stream *s, int64_t at, const char *what, size_t want, int got)
{
    int zerr = Z_OK;
    const char *m = gzerror(s->gz, &zerr);
    if (got < 0 || (zerr != Z_OK && zerr != Z_BUF_ERROR))
        return fn_err_set(FN_EFORMAT, "%s: corrupt gzip data reading %s near offset %lld of the tar: %s",
                          s->path, what, (long long)at, m);
    return fn_err_set(FN_EFORMAT, "%s: truncated: %s at offset %lld needs %zu bytes, got %d",
                      s->path, what, (long long)at, want, got);
}

static int stream_read(stream *s, void *buf, size_t n, const char *what)
{
    z_off_t at = gztell(s->gz);
    int got = gzread(s->gz, buf, (unsigned)n);
    return (size_t)got == n ? 0 : gz_fail(s, at, what, n, got);
}

static int64_t octal(const unsigned char *f, size_t n)
{
    if (f[0] & 0x80) { /* GNU base-256 for sizes of 8 GiB and more */
        int64_t v = f[0] & 0x3f;
        for (size_t i = 1; i < n; i++) {
            if (v > (INT64_MAX >> 8))
                return -1;
            v = (v << 8) | f[i];
        }
        return v;
    }
    int64_t v = 0;
    size_t i = 0;
    while (i < n && f[i] == ' ')
        i++;
    for (; i < n && f[i] >= '0' && f[i] <= '7'; i++) {
        if (v > (INT64_MAX >> 3))
            return -1;
        v = v * 8 + (f[i] - '0');
    }
    return (i < n && f[i] && f[i] != ' ') ? -1 : v;
}

static int checksum_ok(const unsigned char h[512])
{
    int64_t want = octal(h + 148, 8);
    int64_t sum = 0;
    for (int i = 0; i < 512; i++)
        sum += (i >= 148 && i < 156) ? ' ' : h[i];
    return want == sum;
}

static const char *base_name(const char *p)
{
    const char *s = strrchr(p, '/');
    return s ? s + 1 : p;
}

/* Reads the matrix entry (at the current position, size bytes) into a new volume. */
static vol *read_matrix(stream *s, const inv3_info *info, int64_t size)
{
    int64_t dim[3] = {info->shape[2], info->shape[1], info->shape[0]};
    char what[4200];
    snprintf(what, sizeof what, "%s: main.plist: matrix.shape", s->path);
    if (vol_check_dims(dim, sizeof(float), what) < 0)
        return NULL;
    size_t es = volio__type_size(info->type), n = (size_t)dim[0] * (size_t)dim[1] * (size_t)dim[2];
    if ((uint64_t)size / es != n || (uint64_t)size % es) {
        fn_err_set(FN_EFORMAT, "%s: %s is %lld bytes, but main.plist's matrix.shape %lldx%lldx%lld "
                               "of %s needs %llu", s->path, info->filename, (long long)size,
                   (long long)info->shape[0], (long long)info->shape[1], (long long)info->shape[2],
                   vol_type_name(info->type), (unsigned long long)n * es);
        return NULL;
    }
    vol *v = vol_new((int)dim[0], (int)dim[1], (int)dim[2]);
    if (!v)
        return NULL;
    _Alignas(8) unsigned char buf[1 << 16];
    const uint16_t one = 1;
    int swap = *(const unsigned char *)&one == 0; /* the file is little-endian, the host may not be */
    for (size_t done = 0; done < n;) {
        size_t m = n - done < sizeof buf / es ? n - done : sizeof buf / es;
        if (stream_read(s, buf, m * es, info->filename) < 0) {
            vol_free(v);
            return NULL;
        }
        for (size_t i = 0; swap && i < m; i++)
            for (size_t b = 0; b < es / 2; b++) {
                unsigned char t = buf[i * es + b];
                buf[i * es + b] = buf[i * es + es - 1 - b];
                buf[i * es + es - 1 - b] = t;
            }
        volio__to_float(buf, info->type, m, 1.0, 0.0, v->data + done);
        done += m;
    }
    const double dir[3][3] = {{1, 0, 0}, {0, -1, 0}, {0, 0, 1}}, origin[3] = {0, 0, 0};
    vol_set_geometry(v, dir, info->spacing, origin);
    v->src_type = info->type;
    return v;
}

typedef struct {
    char name[NAME_MAX_LEN];
    int64_t off, size;
} entry;

/* The header at the current position: name (GNU/pax long names followed), size, data offset.
 * Returns 1 for a regular file, 2 for any other entry (folder, link, device: the caller skips it),
 * 0 for the end of the archive, -1 on error. */
static int next_entry(stream *s, entry *e)
{
    unsigned char h[512];
    char longname[NAME_MAX_LEN] = "";
    for (;;) {
        int64_t at = gztell(s->gz);
        int got = gzread(s->gz, h, sizeof h);
        int zerr = Z_OK;
        gzerror(s->gz, &zerr);
        if (got == 0 && zerr == Z_OK)
            return 0; /* a tar without its end blocks: accept, as GNU tar does */
        if (got != (int)sizeof h)
            return gz_fail(s, at, "a tar header", sizeof h, got);
        int zero = 1;
        for (int i = 0; i < 512 && zero; i++)
            zero = !h[i];
        if (zero)
            return 0;
        if (!checksum_ok(h))
            return fn_err_set(FN_EFORMAT, "%s: tar header at offset %lld: bad checksum (not an "
                                          "InVesalius project?)", s->path, (long long)at);
        int64_t size = octal(h + 124, 12);
        if (size < 0)
            return fn_err_set(FN_EFORMAT, "%s: tar header at offset %lld: bad size field",
                              s->path, (long long)at);
        char type = (char)h[156];
        if (type == 'L' || type == 'x') {
            char meta[NAME_MAX_LEN];
            if (size >= (int64_t)sizeof meta)
                return fn_err_set(FN_EFORMAT, "%s: tar header at offset %lld: %lld-byte long name",
                                  s->path, (long long)at, (long long)size);
            if (stream_read(s, meta, (size_t)size, "a tar long name") < 0 ||
                gzseek(s->gz, (512 - size % 512) % 512, SEEK_CUR) < 0)
                return -1;
            meta[size] = '\0';
            const char *pp = type == 'L' ? meta : strstr(meta, " path=");
            if (pp) {
                pp += type == 'L' ? 0 : 6;
                size_t n = strcspn(pp, "\n");
                snprintf(longname, sizeof longname, "%.*s", (int)n, pp);
            }
            continue;
        }
        if (longname[0])
            snprintf(e->name, sizeof e->name, "%s", longname);
        else if (!memcmp(h + 257, "ustar", 5) && h[345])
            snprintf(e->name, sizeof e->name, "%.155s/%.100s", (const char *)h + 345, (const char *)h);
        else
            snprintf(e->name, sizeof e->name, "%.100s", (const char *)h);
        e->off = at + 512;
        e->size = size;
        return type == '0' || type == '\0' || type == '7' ? 1 : 2;
    }
}

/* Inflates the rest of the stream: zlib checks the gzip CRC32 and length only at its end, and a
 * damaged byte can inflate to plausible voxels that nothing else would catch. */
static int check_to_end(stream *s)
{
    unsigned char buf[1 << 16];
    for (;;) {
        z_off_t at = gztell(s->gz);
        int got = gzread(s->gz, buf, sizeof buf);
        int zerr = Z_OK;
        gzerror(s->gz, &zerr);
        if (zerr == Z_BUF_ERROR)
            return fn_err_set(FN_EFORMAT, "%s: truncated: the gzip stream ends early, after offset "
                                          "%lld of the tar", s->path, (long long)gztell(s->gz));
        if (got < 0 || zerr != Z_OK)
            return gz_fail(s, at, "the archive's end (gzip check)", sizeof buf, -1);
        if (got == 0)
            return 0;
    }
}

/* Moves to an offset of the tar; seeking past a truncated end reads as truncation. */
static int skip_to(stream *s, int64_t off)
{
    if (gzseek(s->gz, (z_off_t)off, SEEK_SET) != (z_off_t)off)
        return gz_fail(s, off, "the next tar entry", 1, 0);
    return 0;
}

/* A regular file met before main.plist: only what finding the matrix later needs. */
typedef struct {
    char base[FILENAME_LEN]; /* a longer name cannot be the matrix */
    int64_t off, size;
} seen_entry;

static vol *scan(stream *s)
{
    entry e;
    char *plist_text = NULL;
    inv3_info info;
    int have_info = 0, r;
    seen_entry *seen = NULL; /* regular files before main.plist: the matrix may come first */
    size_t nseen = 0, capseen = 0, nentries = 0;
    vol *v = NULL;
    while ((r = next_entry(s, &e)) != 0) {
        if (r < 0)
            goto out;
        if (++nentries > ENTRIES_MAX) {
            fn_err_set(FN_EFORMAT, "%s: tar entry at offset %lld: more than %d entries (not an "
                                   "InVesalius project?)", s->path, (long long)e.off - 512, ENTRIES_MAX);
            goto out;
        }
        int64_t end = e.off + (e.size + 511) / 512 * 512;
        const char *bn = base_name(e.name);
        if (r == 1 && !have_info && !strcmp(bn, "main.plist")) {
            if (e.size > PLIST_MAX) {
                fn_err_set(FN_EFORMAT, "%s: main.plist is %lld bytes (over 1 MiB)", s->path, (long long)e.size);
                goto out;
            }
            plist_text = malloc((size_t)e.size + 1);
            if (!plist_text) {
                fn_err_set(FN_ENOMEM, "%s: out of memory", s->path);
                goto out;
            }
            if (stream_read(s, plist_text, (size_t)e.size, "main.plist") < 0 ||
                read_info(plist_text, (size_t)e.size, s->path, &info) < 0)
                goto out;
            have_info = 1;
            for (size_t i = 0; i < nseen; i++)
                if (!strcmp(seen[i].base, info.filename)) {
                    if (skip_to(s, seen[i].off) == 0)
                        v = read_matrix(s, &info, seen[i].size);
                    goto check;
                }
        } else if (r == 1 && have_info && !strcmp(bn, info.filename)) {
            v = read_matrix(s, &info, e.size);
            goto check;
        } else if (r == 1 && !have_info && strlen(bn) < sizeof seen->base) {
            if (nseen == capseen) {
                size_t cap = capseen ? capseen * 2 : 16;
                seen_entry *ns = realloc(seen, cap * sizeof *ns);
                if (!ns) {
                    fn_err_set(FN_ENOMEM, "%s: out of memory", s->path);
                    goto out;
                }
                seen = ns;
                capseen = cap;
            }
            memcpy(seen[nseen].base, bn, strlen(bn) + 1);
            seen[nseen].off = e.off;
            seen[nseen++].size = e.size;
        }
        if (skip_to(s, end) < 0)
            goto out;
    }
    if (!have_info)
        fn_err_set(FN_EFORMAT, "%s: no main.plist in the archive (not an InVesalius project)", s->path);
    else
        fn_err_set(FN_EFORMAT, "%s: main.plist: matrix.filename '%s' is not in the archive",
                   s->path, info.filename);
    goto out;
check:
    if (v && check_to_end(s) < 0) {
        vol_free(v);
        v = NULL;
    }
out:
    free(plist_text);
    free(seen);
    return v;
}

vol *volio__read_inv3(const char *path)
{
    stream s = {gzopen(path, "rb"), path};
    if (!s.gz) {
        fn_err_set(FN_EIO, "%s: cannot open: %s", path, strerror(errno ? errno : ENOMEM));
        return NULL;
    }
    gzbuffer(s.gz, 1 << 17);
    vol *v = scan(&s);
    gzclose(s.gz);
    return v;
}
