/* calib: the spnavrc reader and writer. */
#include "calib.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include "durable.h"
#include "err.h"

#define RC_MAX_BYTES (1 << 20)
#define RAW_FULL_SCALE 350.0f /* spacenavd's dead zones are in device units of a +-350 axis */

static const char *const action_names[CALIB_ACT_COUNT] = {
    [CALIB_ACT_SENS_UP] = "sensitivity-up",
    [CALIB_ACT_SENS_DOWN] = "sensitivity-down",
    [CALIB_ACT_SENS_RESET] = "sensitivity-reset",
    [CALIB_ACT_DISABLE_ROTATION] = "disable-rotation",
    [CALIB_ACT_DISABLE_TRANSLATION] = "disable-translation",
    [CALIB_ACT_DOMINANT] = "dominant-axis",
    [CALIB_ACT_ZERO] = "calibrate-zero",
};

const char *calib_action_name(calib_action a)
{
    return a > CALIB_ACT_NONE && a < CALIB_ACT_COUNT ? action_names[a] : NULL;
}

int calib_action_parse(const char *name)
{
    if (!strcmp(name, "none"))
        return CALIB_ACT_NONE;
    for (int a = 1; a < CALIB_ACT_COUNT; a++)
        if (!strcmp(name, action_names[a]))
            return a;
    return -1;
}

typedef struct diag {
    char *buf;
    size_t cap, used;
    const char *fname;
    int bad;
} diag;

static void FN_PRINTF(3, 4) bad_line(diag *d, int line, const char *fmt, ...)
{
    d->bad++;
    if (!d->buf || d->cap == 0 || d->used + 1 >= d->cap)
        return;
    int n = snprintf(d->buf + d->used, d->cap - d->used, "%s:%d: ", d->fname, line);
    if (n > 0 && d->used + (size_t)n < d->cap) {
        d->used += (size_t)n;
        va_list ap;
        va_start(ap, fmt);
        n = vsnprintf(d->buf + d->used, d->cap - d->used, fmt, ap);
        va_end(ap);
        if (n > 0)
            d->used += (size_t)n;
        if (d->used + 1 < d->cap)
            d->buf[d->used++] = '\n', d->buf[d->used] = '\0';
    }
    if (d->used >= d->cap)
        d->used = d->cap - 1;
}

static int parse_float(const char *s, float lo, float hi, float *out)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (end == s || *end || errno || !(v >= lo && v <= hi))
        return -1;
    *out = (float)v;
    return 0;
}

static int parse_bool(const char *s)
{
    static const char *const yes[] = {"true", "yes", "on", "1"}, *const no[] = {"false", "no", "off", "0"};
    for (int i = 0; i < 4; i++) {
        if (!strcasecmp(s, yes[i]))
            return 1;
        if (!strcasecmp(s, no[i]))
            return 0;
    }
    return -1;
}

static int parse_index(const char *s, int max)
{
    if (!isdigit((unsigned char)s[0]) || (s[1] && (!isdigit((unsigned char)s[1]) || s[2])))
        return -1;
    int v = atoi(s);
    return v < max ? v : -1;
}

/* "xyz" subset -> bits 0..2. */
static int parse_axes(const char *s)
{
    int bits = 0;
    for (; *s; s++) {
        const char *p = strchr("xyz", tolower((unsigned char)*s));
        if (!p)
            return -1;
        bits |= 1 << (p - "xyz");
    }
    return bits;
}

static int axis_suffix(const char *rest)
{
    if (!*rest)
        return 3; /* all three */
    if (rest[0] == '-' && rest[1] && strchr("xyz", rest[1]) && !rest[2])
        return (int)(strchr("xyz", rest[1]) - "xyz");
    return -1;
}

/* spacenavd-only keys: accepted so users' files stay valid, no effect here. */
static int ignored_key(const char *k)
{
    static const char *const keys[] = {"grab", "device-id", "repeat-interval", "serial", "kbmap"};
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++)
        if (!strncmp(k, keys[i], strlen(keys[i])))
            return 1;
    return 0;
}

static int sens_key(calib *c, const char *k, const char *v)
{
    float f;
    if (parse_float(v, 0.0f, 1000.0f, &f))
        return -2;
    if (!strcmp(k, "sensitivity")) {
        c->sens = c->sens_base = f;
        return 0;
    }
    int rot = !strncmp(k, "sensitivity-rotation", 20);
    if (!rot && strncmp(k, "sensitivity-translation", 23))
        return -1;
    int ax = axis_suffix(k + (rot ? 20 : 23));
    if (ax < 0)
        return -1;
    if (ax == 3)
        *(rot ? &c->sens_r : &c->sens_t) = f;
    else
        c->sens_axis[ax + (rot ? 3 : 0)] = f;
    return 0;
}

static int dead_key(calib *c, const char *k, const char *v)
{
    int i = k[9] ? parse_index(k + 9, 6) : 6;
    float f;
    if (i < 0)
        return -1;
    if (parse_float(v, 0.0f, 0.9f * RAW_FULL_SCALE, &f))
        return -2;
    for (int a = i == 6 ? 0 : i; a < (i == 6 ? 6 : i + 1); a++)
        c->dead[a] = f / RAW_FULL_SCALE;
    return 0;
}

static int invert_key(calib *c, const char *k, const char *v)
{
    int b = parse_axes(v), shift = k[7] == 'r' ? 3 : 0;
    if (b < 0)
        return -2;
    c->invert = (uint8_t)((c->invert & ~(7 << shift)) | b << shift);
    return 0;
}

/* axismapN = M: device axis N drives output M (spacenavd's meaning). The map stays a permutation:
 * the device axis that drove M takes N's old output, so a partial map ("axismap0 = 2" alone) is a
 * swap, never one axis on two outputs with another on none; a full map reads as in spacenavd. */
static void assign_axis(calib *c, int in, int out)
{
    for (int o = 0; o < 6; o++)
        if (c->map[o] == in) {
            c->map[o] = c->map[out];
            break;
        }
    c->map[out] = (int8_t)in;
}

/* axismapN = M, bnmapN = M, bnactN = action. */
static int map_key(calib *c, const char *k, const char *v)
{
    int ax = k[0] == 'a', i = parse_index(k + (ax ? 7 : 5), ax ? 6 : CALIB_BUTTONS);
    if (i < 0)
        return -1;
    int m = ax ? parse_index(v, 6) : k[2] == 'm' ? parse_index(v, CALIB_BUTTONS) : calib_action_parse(v);
    if (m < 0)
        return -2;
    if (ax)
        assign_axis(c, i, m);
    else if (k[2] == 'm')
        c->bnmap[i] = (int8_t)m;
    else
        c->bnact[i] = (calib_action)m;
    return 0;
}

static int bool_key(calib *c, const char *k, const char *v)
{
    int b = parse_bool(v);
    if (b < 0)
        return -2;
    calib_lock l = k[8] == 'r' ? CALIB_LOCK_TRANSLATION : CALIB_LOCK_ROTATION;
    if (k[0] == 's')
        c->swap_yz = b;
    else if (k[1] == 'o')
        c->dominant = b;
    else if (b)
        c->lock = l;
    else if (c->lock == l)
        c->lock = CALIB_LOCK_NONE;
    return 0;
}

static int misc_key(calib *c, const char *k, const char *v)
{
    if (!strcmp(k, "led")) {
        int b = !strcasecmp(v, "auto") ? 2 : parse_bool(v);
        return b < 0 ? -2 : (c->led = b, 0);
    }
    if (!strcmp(k, "response")) {
        if (strcmp(v, "linear") && strcmp(v, "cubic"))
            return -2;
        c->response = v[0] == 'c' ? CALIB_CUBIC : CALIB_LINEAR;
        return 0;
    }
    if (!strcmp(k, "cubic-mix"))
        return parse_float(v, 0.0f, 1.0f, &c->cubic_mix) ? -2 : 0;
    int i = strncmp(k, "zero-offset", 11) ? -1 : parse_index(k + 11, 6);
    if (i >= 0)
        return parse_float(v, -1.0f, 1.0f, &c->zero[i]) ? -2 : 0;
    return ignored_key(k) ? 0 : -1;
}

/* One key = value. Returns 0, -1 unknown key, -2 bad value. */
static int apply_key(calib *c, const char *k, const char *v)
{
    if (!strncmp(k, "sensitivity", 11))
        return sens_key(c, k, v);
    if (!strncmp(k, "dead-zone", 9))
        return dead_key(c, k, v);
    if (!strcmp(k, "invert-rot") || !strcmp(k, "invert-trans"))
        return invert_key(c, k, v);
    if (!strncmp(k, "axismap", 7) || !strncmp(k, "bnmap", 5) || !strncmp(k, "bnact", 5))
        return map_key(c, k, v);
    if (!strcmp(k, "swap-yz") || !strcmp(k, "dominant-axis") || !strcmp(k, "disable-rotation") ||
        !strcmp(k, "disable-translation"))
        return bool_key(c, k, v);
    return misc_key(c, k, v);
}

static char *trim(char *s)
{
    while (isspace((unsigned char)*s))
        s++;
    char *e = s + strlen(s);
    while (e > s && isspace((unsigned char)e[-1]))
        *--e = '\0';
    return s;
}

static void parse_line(calib *c, char *line, int n, diag *d)
{
    char *hash = strchr(line, '#');
    if (hash)
        *hash = '\0';
    char *s = trim(line);
    if (!*s)
        return;
    char *eq = strchr(s, '=');
    if (!eq) {
        bad_line(d, n, "expected 'key = value', got '%.60s'", s);
        return;
    }
    *eq = '\0';
    char *k = trim(s), *v = trim(eq + 1);
    int rc = *v ? apply_key(c, k, v) : -2;
    if (rc == -1)
        bad_line(d, n, "unknown key '%.60s' (skipped)", k);
    else if (rc == -2)
        bad_line(d, n, "bad value '%.60s' for '%.60s' (skipped)", v, k);
}

int calib_parse_spnavrc(calib *c, const char *text, size_t len, const char *fname, char *diagbuf,
                        size_t cap)
{
    diag d = {diagbuf, cap, 0, fname ? fname : "spnavrc", 0};
    if (diagbuf && cap)
        diagbuf[0] = '\0';
    char line[512];
    size_t pos = 0;
    for (int n = 1; pos < len; n++) {
        size_t e = pos;
        while (e < len && text[e] != '\n')
            e++;
        size_t l = e - pos;
        if (l >= sizeof line || memchr(text + pos, '\0', l))
            bad_line(&d, n, "line too long or holds a NUL byte (skipped)");
        else {
            memcpy(line, text + pos, l);
            line[l] = '\0';
            parse_line(c, line, n, &d);
        }
        pos = e + 1;
    }
    return d.bad;
}

static int read_file(const char *path, char **out, size_t *len)
{
    /* O_NONBLOCK: opening a FIFO must not wait for a writer; it is refused below */
    int fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0)
        return errno == ENOENT ? FN_ENODEV : fn_err_set(FN_EIO, "%s: %s", path, strerror(errno));
    struct stat st;
    FILE *f = NULL;
    if (fstat(fd, &st) || !S_ISREG(st.st_mode) || st.st_size > RC_MAX_BYTES || !(f = fdopen(fd, "rb"))) {
        close(fd);
        return fn_err_set(FN_EIO, "%s: not a regular file under %d bytes", path, RC_MAX_BYTES);
    }
    char *buf = malloc((size_t)st.st_size + 1);
    if (!buf) {
        fclose(f);
        return fn_err_set(FN_ENOMEM, "%s: out of memory", path);
    }
    *len = fread(buf, 1, (size_t)st.st_size, f);
    int err = ferror(f);
    fclose(f);
    if (err) {
        free(buf);
        return fn_err_set(FN_EIO, "%s: read error", path);
    }
    *out = buf;
    return 0;
}

int calib_load(calib *c, const char *path, char *used, size_t used_cap, char *diagbuf, size_t cap)
{
    char home_rc[512] = "";
    const char *home = getenv("HOME");
    if (home && *home)
        snprintf(home_rc, sizeof home_rc, "%s/.config/fracnav/spnavrc", home);
    char sys_rc[512];
    const char *etc = getenv("FRACNAV_SYSCONFDIR"); /* tests and relocated installs */
    snprintf(sys_rc, sizeof sys_rc, "%s/spnavrc", etc && *etc ? etc : "/etc");
    const char *cands[] = {path, path ? NULL : home_rc, path ? NULL : sys_rc};
    if (used && used_cap)
        used[0] = '\0';
    if (diagbuf && cap)
        diagbuf[0] = '\0';
    for (size_t i = 0; i < 3; i++) {
        if (!cands[i] || !cands[i][0])
            continue;
        char *text = NULL;
        size_t len = 0;
        int rc = read_file(cands[i], &text, &len);
        if (rc == FN_ENODEV && !path)
            continue;
        if (rc == FN_ENODEV)
            return fn_err_set(FN_EIO, "%s: no such file", path);
        if (rc)
            return rc;
        if (used && used_cap)
            snprintf(used, used_cap, "%s", cands[i]);
        int bad = calib_parse_spnavrc(c, text, len, cands[i], diagbuf, cap);
        free(text);
        return bad;
    }
    return 0;
}

int calib_setup(calib *c, const char *path, unsigned flags, FILE *err, const char *who, char *used,
                size_t used_cap)
{
    char bad_lines[2048] = "", where[4096] = "";
    calib_default(c);
    if (used && used_cap)
        used[0] = '\0';
    if (!path && (flags & CALIB_NAMED_ONLY))
        return 0;
    if (path && (flags & CALIB_NEW_OK) && access(path, F_OK) != 0)
        return 0;
    int bad = calib_load(c, path, where, sizeof where, bad_lines, sizeof bad_lines);
    if (bad < 0)
        return bad;
    if (bad)
        fprintf(err, "%s: %d bad line(s) skipped:\n%s", who, bad, bad_lines);
    if (used && used_cap)
        snprintf(used, used_cap, "%s", where);
    return 0;
}

static void FN_PRINTF(3, 4) put(char *out, size_t cap, const char *fmt, ...)
{
    size_t used = strlen(out);
    if (used + 1 >= cap)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(out + used, cap - used, fmt, ap);
    va_end(ap);
}

/* The shortest %g text (6 digits when they do, up to 9) of a value that parse_float reads and
 * then divides by scale (1, or RAW_FULL_SCALE for dead zones) back into exactly v: v * scale, or
 * a float next to it when the product rounds off. So a value written and read again calibrates
 * exactly as before (the fuzz harness checks). */
static const char *num_scaled(float v, float scale, char buf[32])
{
    float w = v * scale, tries[3] = {w, nextafterf(w, -INFINITY), nextafterf(w, INFINITY)};
    for (int k = 0; k < 3; k++)
        for (int digits = 6; digits <= 9; digits++) {
            snprintf(buf, 32, "%.*g", digits, (double)tries[k]);
            if ((float)strtod(buf, NULL) / scale == v)
                return buf;
        }
    snprintf(buf, 32, "%.9g", (double)w);
    return buf;
}

static const char *num(float v, char buf[32])
{
    return num_scaled(v, 1.0f, buf);
}

size_t calib_format_spnavrc(const calib *c, char *out, size_t cap)
{
    char a[32], b[32];
    static const char *const lock[] = {"false", "true"};
    if (!cap)
        return 0;
    out[0] = '\0';
    put(out, cap, "# fracnav calibration (spacenavd spnavrc syntax)\nsensitivity = %s\n", num(c->sens_base, a));
    put(out, cap, "sensitivity-translation = %s\nsensitivity-rotation = %s\n", num(c->sens_t, a), num(c->sens_r, b));
    for (int i = 0; i < 6; i++)
        put(out, cap, "sensitivity-%s-%c = %s\n", i < 3 ? "translation" : "rotation", "xyz"[i % 3],
            num(c->sens_axis[i], a));
    for (int i = 0; i < 6; i++)
        put(out, cap, "dead-zone%d = %s\n", i, num_scaled(c->dead[i], RAW_FULL_SCALE, a));
    for (int r = 0; r < 2; r++) {
        if (!(c->invert >> 3 * r & 7))
            continue;
        put(out, cap, "invert-%s = ", r ? "rot" : "trans");
        for (int i = 0; i < 3; i++)
            if (c->invert >> (3 * r + i) & 1)
                put(out, cap, "%c", "xyz"[i]);
        put(out, cap, "\n");
    }
    put(out, cap, "swap-yz = %s\n", lock[!!c->swap_yz]);
    for (int i = 0; i < 6; i++)
        if (c->map[i] >= 0)
            put(out, cap, "axismap%d = %d\n", c->map[i], i);
    for (int i = 0; i < CALIB_BUTTONS; i++) {
        if (c->bnmap[i] >= 0 && c->bnmap[i] != i)
            put(out, cap, "bnmap%d = %d\n", i, c->bnmap[i]);
        if (c->bnact[i] != CALIB_ACT_NONE)
            put(out, cap, "bnact%d = %s\n", i, calib_action_name(c->bnact[i]));
    }
    put(out, cap, "led = %s\nresponse = %s\ncubic-mix = %s\n", c->led == 2 ? "auto" : lock[!!c->led],
        c->response == CALIB_CUBIC ? "cubic" : "linear", num(c->cubic_mix, a));
    put(out, cap, "dominant-axis = %s\ndisable-rotation = %s\ndisable-translation = %s\n",
        lock[!!c->dominant], lock[c->lock == CALIB_LOCK_TRANSLATION], lock[c->lock == CALIB_LOCK_ROTATION]);
    for (int i = 0; i < 6; i++)
        put(out, cap, "zero-offset%d = %s\n", i, num(c->zero[i], a));
    return strlen(out);
}

static int default_path(char *out, size_t cap)
{
    const char *home = getenv("HOME");
    if (!home || !*home)
        return fn_err_set(FN_EIO, "calibration: $HOME is not set: give a file to save to");
    char dir[512];
    snprintf(dir, sizeof dir, "%s/.config", home);
    mkdir(dir, 0755);
    snprintf(dir, sizeof dir, "%s/.config/fracnav", home);
    if (mkdir(dir, 0755) && errno != EEXIST)
        return fn_err_set(FN_EIO, "%s: %s", dir, strerror(errno));
    snprintf(out, cap, "%s/spnavrc", dir);
    return 0;
}

/* A growing text buffer for the merge. */
typedef struct text {
    char *s;
    size_t n, cap;
    int oom;
} text;

static void add(text *t, const char *s, size_t n)
{
    if (t->oom)
        return;
    if (t->n + n + 1 > t->cap) {
        size_t cap = (t->n + n + 1) * 2;
        char *ns = realloc(t->s, cap);
        if (!ns) {
            t->oom = 1;
            return;
        }
        t->s = ns, t->cap = cap;
    }
    memcpy(t->s + t->n, s, n);
    t->n += n;
    t->s[t->n] = '\0';
}

/* The key of a "key = value" line (s, n: the line without its newline), trimmed, into key; its
 * value (trimmed, before any '#') into val. 0 when the line is not of that form. */
static int split_line(const char *s, size_t n, char *key, char *val, size_t cap)
{
    char line[512];
    if (n >= sizeof line || memchr(s, '\0', n))
        return 0;
    memcpy(line, s, n);
    line[n] = '\0';
    char *hash = strchr(line, '#'), *eq;
    if (hash)
        *hash = '\0';
    if (!(eq = strchr(line, '=')))
        return 0;
    *eq = '\0';
    snprintf(key, cap, "%s", trim(line));
    snprintf(val, cap, "%s", trim(eq + 1));
    return key[0] != '\0';
}

/* The new line of `key` in fresh (calib_format_spnavrc's text, one "key = value" a line): its
 * index, or -1 when fresh has no such key. */
static int fresh_index(char (*keys)[64], int n, const char *key)
{
    for (int i = 0; i < n; i++)
        if (!strcmp(keys[i], key))
            return i;
    return -1;
}

/* One line of the old file: kept as it is, unless it sets a key whose value changes (rewritten,
 * its comment kept), or a key fracnav knows that the new settings leave at its default (commented
 * out, so the file still means what c says). */
static void merge_line(text *t, const char *s, size_t n, char (*keys)[64], char (*vals)[64], int nk,
                       unsigned char *done)
{
    char key[64], val[512], probe_key[64];
    if (!split_line(s, n, key, val, sizeof key < sizeof val ? sizeof key : sizeof val)) {
        add(t, s, n);
        return;
    }
    int i = fresh_index(keys, nk, key);
    const char *hash = memchr(s, '#', n);
    if (i >= 0) {
        done[i] = 1;
        if (!strcmp(vals[i], val)) {
            add(t, s, n);
            return;
        }
        char line[200];
        int m = snprintf(line, sizeof line, "%s = %s%s", key, vals[i], hash ? " " : "");
        add(t, line, (size_t)m);
        if (hash)
            add(t, hash, n - (size_t)(hash - s));
        return;
    }
    calib probe;
    calib_default(&probe);
    snprintf(probe_key, sizeof probe_key, "%s", key);
    if (apply_key(&probe, probe_key, val) != 0 || ignored_key(key)) { /* not ours, or a bad line: the user's */
        add(t, s, n);
        return;
    }
    add(t, "# ", 2);
    add(t, s, n);
}

/* Keys calib_format_spnavrc writes at most: 36 settings, 32 bnmap and 32 bnact lines. */
#define FRESH_KEYS 104

int calib_merge_spnavrc(const calib *c, const char *old, size_t old_len, char **out, size_t *out_len)
{
    char keys[FRESH_KEYS][64], vals[FRESH_KEYS][64], fresh[8192];
    unsigned char done[FRESH_KEYS] = {0};
    int nk = 0;
    calib_format_spnavrc(c, fresh, sizeof fresh);
    for (char *save = NULL, *l = strtok_r(fresh, "\n", &save); l && nk < FRESH_KEYS; l = strtok_r(NULL, "\n", &save))
        if (split_line(l, strlen(l), keys[nk], vals[nk], 64))
            nk++;
    text t = {0};
    add(&t, "", 0);
    for (size_t pos = 0; pos < old_len;) {
        const char *nl = memchr(old + pos, '\n', old_len - pos);
        size_t n = nl ? (size_t)(nl - (old + pos)) : old_len - pos;
        merge_line(&t, old + pos, n, keys, vals, nk, done);
        add(&t, "\n", 1);
        pos += n + 1;
    }
    static const char head[] = "# fracnav calibration (spacenavd spnavrc syntax)\n";
    if (old_len == 0)
        add(&t, head, sizeof head - 1);
    for (int i = 0; i < nk; i++)
        if (!done[i]) {
            char line[200];
            int m = snprintf(line, sizeof line, "%s = %s\n", keys[i], vals[i]);
            add(&t, line, (size_t)m);
        }
    if (t.oom) {
        free(t.s);
        return fn_err_set(FN_ENOMEM, "calibration: out of memory merging the settings");
    }
    *out = t.s;
    *out_len = t.n;
    return 0;
}

int calib_save(const calib *c, const char *path, char *used, size_t used_cap)
{
    char def[600];
    if (!path) {
        if (default_path(def, sizeof def))
            return FN_EIO;
        path = def;
    }
    char *old = NULL, *merged = NULL;
    size_t old_len = 0, n = 0;
    int rc = read_file(path, &old, &old_len);
    if (rc && rc != FN_ENODEV)
        return rc;
    rc = calib_merge_spnavrc(c, old ? old : "", old_len, &merged, &n);
    free(old);
    if (rc)
        return rc;
    rc = durable_replace_bytes(path, merged, n);
    free(merged);
    if (rc)
        return fn_err_wrap(rc, "cannot save the calibration");
    if (used && used_cap)
        snprintf(used, used_cap, "%s", path);
    return 0;
}
