/* volio_nrrdhdr: a NRRD header read line by line, as teem will read it, and refused before teem
 * sees it when it names data files that are not plain files of the header's folder, or holds more
 * than teem can parse in good time. teem trusts a detached header: it prints the numbered form's
 * name with the header's own printf format into a buffer of fixed size, opens LIST entries
 * whatever they are (a FIFO blocks, /dev/urandom never ends), and adds key/value pairs in time
 * quadratic in their number (80,000 took 16 s), and comments as slowly (400,000 took 18 s). The files are looked at (realpath, stat), never
 * opened; one swapped between this check and teem's open (in a folder someone else may write to)
 * is not caught. */
#include "volio_impl.h"

#include "err.h"

#include <errno.h>
#include <limits.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <teem/nrrd.h>

/* Key/value and comment lines; a Slicer segment writes about ten keys. teem adds each in time
 * linear in those before it: 4,096 keys take 48 ms here, but under libFuzzer, whose hooks trace
 * every strcmp, 4,000 took 13 s and stopped CI's fuzz smoke at its 10 s timeout. The fuzz build
 * bounds them lower. */
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
#define MAX_KEYS 512
#define MAX_COMMENTS 512
#else
#define MAX_KEYS 4096
#define MAX_COMMENTS 4096 /* comment lines ('#'): teem keeps them as it keeps keys */
#endif
#define MAX_DATA_FILES 16384     /* and never more than the header's slices */
#define MAX_LINE 65536           /* characters in a header line */
#define MAX_FILE_NUMBER 999999999 /* |min|, |max| and |step| of the numbered form */

typedef struct scan {
    const char *path; /* the header, for messages */
    FILE *f;
    char *line;       /* the current line, NUL-terminated */
    int lineno;       /* 1-based */
    char dir[PATH_MAX]; /* the header's folder, links resolved */
    unsigned dim;     /* dimension: (0: not seen yet) */
    uint64_t slices;  /* the last axis' size (0: sizes not seen yet) */
    int keys;
    int comments;
    int labels;       /* read as a labelmap: segment numbers are bounded */
} scan;

/* The next line as airOneLine cuts it: ended by "\n", "\r", "\r\n" or the end of the file (teem
 * reads characters after the last line end as one more line). 1 when a line was read, 0 at the end
 * of the file, <0 on a line over MAX_LINE characters or one that holds a NUL byte: a header is text,
 * and teem's own line reader runs past the end of its buffer on a NUL in a LIST entry. */
static int next_line(scan *s)
{
    size_t n = 0;
    int c;
    while ((c = getc(s->f)) != EOF && c != '\n' && c != '\r') {
        if (n == MAX_LINE)
            return fn_err_set(FN_EFORMAT, "%s: line %d: over %d characters", s->path, s->lineno + 1,
                              MAX_LINE);
        if (c == '\0')
            return fn_err_set(FN_EFORMAT, "%s: line %d: a NUL byte at character %zu: a NRRD header is "
                              "text", s->path, s->lineno + 1, n + 1);
        s->line[n++] = (char)c;
    }
    if (c == EOF && n == 0)
        return 0;
    if (c == '\r' && (c = getc(s->f)) != '\n' && c != EOF)
        ungetc(c, s->f);
    s->line[n] = '\0';
    s->lineno++;
    return 1;
}

/* One data file, as written in the header: a regular file inside the header's folder, reached
 * without "..", and never opened here (opening a FIFO would block). */
static int check_file(const scan *s, const char *name, int lineno)
{
    if (!name[0])
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: an empty name", s->path, lineno);
    if (!strcmp(name, "-") || name[1] == ':')
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: '%.200s' is standard input or a drive, "
                          "not a file of the header's folder", s->path, lineno, name);
    for (const char *c = name; *c; c += strcspn(c, "/"), c += *c == '/')
        if (!strncmp(c, "..", 2) && (c[2] == '/' || c[2] == '\0'))
            return fn_err_set(FN_EFORMAT, "%s: line %d: data file: '%.200s' leaves the header's folder "
                              "(..)", s->path, lineno, name);
    char full[2 * PATH_MAX], real[PATH_MAX];
    const char *slash = strrchr(s->path, '/');
    if (name[0] == '/')
        snprintf(full, sizeof full, "%s", name);
    else if (slash)
        snprintf(full, sizeof full, "%.*s/%s", (int)(slash - s->path), s->path, name);
    else
        snprintf(full, sizeof full, "./%s", name);
    struct stat st;
    if (!realpath(full, real) || stat(real, &st) != 0)
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: '%.200s': %s", s->path, lineno, name,
                          strerror(errno));
    if (!S_ISREG(st.st_mode))
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: %.200s is not a regular file (a device "
                          "or FIFO?)", s->path, lineno, name);
    size_t n = strlen(s->dir);
    if (strncmp(real, s->dir, n) != 0 || (real[n] != '/' && strcmp(s->dir, "/") != 0))
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: '%.200s' is %.200s, outside the header's "
                          "folder", s->path, lineno, name, real);
    return 0;
}

/* The LIST and numbered forms give one file per slice (or slab): they need the dimension and
 * sizes before them, as teem does, and at most as many files as the last axis has slices. */
static int check_count(const scan *s, uint64_t files)
{
    if (!s->dim || !s->slices)
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: a list of files needs dimension and "
                          "sizes before it", s->path, s->lineno);
    if (files > s->slices || files > MAX_DATA_FILES)
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: %llu files, more than the %llu slices "
                          "(at most %d)", s->path, s->lineno, (unsigned long long)files,
                          (unsigned long long)s->slices, MAX_DATA_FILES);
    return 0;
}

/* A whole number of at most 9 digits (and a sign), the next blank-separated word of *p. */
static int file_number(const char **p, long *out)
{
    const char *c = *p + strspn(*p, " \t");
    char *end;
    errno = 0;
    long x = strtol(c, &end, 10);
    if (end == c || errno || x < -MAX_FILE_NUMBER || x > MAX_FILE_NUMBER || (*end && !strchr(" \t", *end)))
        return -1;
    *out = x;
    *p = end;
    return 0;
}

/* "data file: FMT MIN MAX STEP [DIM]": FMT holds exactly one %d, %Nd or %0Nd (N a digit) and no
 * other '%'; MIN, MAX and STEP (not 0, towards MAX) and the optional DIM are whole numbers. Every
 * name it gives is checked. */
static int numbered(const scan *s, const char *v)
{
    int flen = (int)strcspn(v, " \t");
    const char *pc = strchr(v, '%'), *c = pc + 1;
    int zero = *c == '0', width = 0;
    c += zero;
    if (*c >= '1' && *c <= '9')
        width = *c++ - '0';
    const char *rest = v + flen;
    long min, max, step, subdim;
    if (pc - v >= flen || *c != 'd' || strchr(pc + 1, '%'))
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: '%.200s': a numbered name holds exactly "
                          "one %%d, %%Nd or %%0Nd (N 1..9) and no other %%", s->path, s->lineno, v);
    if (file_number(&rest, &min) < 0 || file_number(&rest, &max) < 0 || file_number(&rest, &step) < 0 ||
        (rest[strspn(rest, " \t")] && file_number(&rest, &subdim) < 0) || rest[strspn(rest, " \t")])
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: '%.200s': the numbered form is FORMAT MIN "
                          "MAX STEP [DIMENSION], whole numbers of at most 9 digits", s->path,
                          s->lineno, v);
    if (step == 0 || (max - min) * step < 0)
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: step %ld does not lead from %ld to %ld",
                          s->path, s->lineno, step, min, max);
    int rc = check_count(s, (uint64_t)((max - min) / step + 1));
    for (long i = min; rc == 0 && (step > 0 ? i <= max : i >= max); i += step) {
        char name[PATH_MAX];
        snprintf(name, sizeof name, zero ? "%.*s%0*ld%.*s" : "%.*s%*ld%.*s", (int)(pc - v), v, width, i,
                 flen - (int)(c + 1 - v), c + 1);
        rc = check_file(s, name, s->lineno);
    }
    return rc;
}

/* "data file: LIST [DIM]": every line after it, to the end of the file, names one file. */
static int listed(scan *s)
{
    int rc = check_count(s, 0), at = s->lineno;
    uint64_t files = 0;
    while (rc == 0 && (rc = next_line(s)) > 0) {
        rc = check_count(s, ++files);
        if (rc == 0)
            rc = check_file(s, s->line, s->lineno);
    }
    if (rc == 0 && files == 0)
        rc = fn_err_set(FN_EFORMAT, "%s: line %d: data file: LIST names no file after it", s->path, at);
    return rc;
}

static int data_file(scan *s, const char *v)
{
    if (strchr(v, '%'))
        return numbered(s, v);
    if (!strncmp(v, "SKIPLIST", 8))
        return fn_err_set(FN_EFORMAT, "%s: line %d: data file: SKIPLIST is not supported (LIST is)",
                          s->path, s->lineno);
    if (!strncmp(v, "LIST", 4))
        return listed(s);
    return check_file(s, v, s->lineno);
}

int volio__segment_number(const char *key)
{
    if (strncmp(key, "Segment", 7) != 0)
        return -1;
    const char *d = key + 7;
    size_t nd = strspn(d, "0123456789");
    if (nd == 0 || d[nd] != '_')
        return -1;
    if (nd > 5)
        return -2;
    return atoi(d);
}

/* A key/value line: counted, and in a labelmap its segment number bounded. */
static int key_value(scan *s)
{
    if (++s->keys > MAX_KEYS)
        return fn_err_set(FN_EFORMAT, "%s: line %d: over %d key/value lines", s->path, s->lineno, MAX_KEYS);
    int seg = s->labels ? volio__segment_number(s->line) : -1;
    if (seg == -2 || seg >= VOLIO_MAX_SEGMENTS)
        return fn_err_set(FN_EFORMAT, "%s: line %d: %.40s: over %d segments", s->path, s->lineno, s->line,
                          VOLIO_MAX_SEGMENTS);
    return 0;
}

/* A comment line: counted, as teem adds each to the nrrd in time that grows with their number
 * (400,000 took 18 s). */
static int comment(scan *s)
{
    if (++s->comments > MAX_COMMENTS)
        return fn_err_set(FN_EFORMAT, "%s: line %d: over %d comment lines", s->path, s->lineno,
                          MAX_COMMENTS);
    return 0;
}

/* One header line (not a comment): its field as teem's own table names it. */
static int field(scan *s)
{
    char *colon = strstr(s->line, ": ");
    if (colon)
        *colon = '\0';
    int fld = colon ? airEnumVal(nrrdField, s->line) : nrrdField_unknown;
    if (fld == nrrdField_unknown)
        return strstr(s->line, ":=") ? key_value(s) : 0; /* else teem names the bad line */
    const char *v = colon + 2 + strspn(colon + 2, " \t");
    char *end;
    switch (fld) {
    case nrrdField_dimension:
        s->dim = (unsigned)strtoul(v, &end, 10);
        s->dim = end != v && s->dim <= NRRD_DIM_MAX ? s->dim : 0;
        return 0;
    case nrrdField_sizes:
        for (unsigned a = 0; a < s->dim; a++, v = end)
            s->slices = strtoull(v, &end, 10);
        return 0;
    case nrrdField_block_size:
        /* only for type block (not supported): teem 1.12 finds the mismatch after reading, then
         * leaks and closes the file it was asked to keep open */
        return fn_err_set(FN_EFORMAT, "%s: line %d: block size: only for type block, which is not "
                          "supported", s->path, s->lineno);
    case nrrdField_data_file:
        return data_file(s, v);
    default:
        return 0;
    }
}

int volio__nrrd_scan(const char *path, int labels)
{
    scan s = {.path = path, .labels = labels};
    const char *slash = strrchr(path, '/');
    char dir[PATH_MAX];
    snprintf(dir, sizeof dir, "%.*s", slash ? (int)(slash - path) + (slash == path) : 1,
             slash ? path : ".");
    if (!realpath(dir, s.dir))
        return 0; /* teem reports it */
    s.f = fopen(path, "rb");
    s.line = malloc(MAX_LINE + 1);
    int rc = 0;
    if (!s.line)
        rc = fn_err_set(FN_ENOMEM, "%s: out of memory", path);
    else if (s.f && (rc = next_line(&s)) > 0 && !strncmp(s.line, "NRRD", 4)) /* a bad magic line: refused */
        while (rc >= 0 && (rc = next_line(&s)) > 0 && s.line[0])
            rc = s.line[0] == '#' ? comment(&s) : field(&s);
    if (s.f)
        fclose(s.f);
    free(s.line);
    return rc < 0 ? rc : 0;
}
