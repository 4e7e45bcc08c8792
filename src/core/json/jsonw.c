/* jsonw: one writer for every command's --json output (jsonw.h). */
#include "jsonw.h"

#include "err.h"

#include <errno.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

json_t *jsonw_object(const char *command)
{
    json_t *o = json_object();
    if (o && jsonw_set(o, "command", jsonw_string(command)) < 0) {
        json_decref(o);
        return NULL;
    }
    return o;
}

json_t *jsonw_exact(double v)
{
    return isfinite(v) ? json_real(v) : json_null();
}

json_t *jsonw_measure(double v)
{
    if (!isfinite(v))
        return json_null();
    char s[40];
    snprintf(s, sizeof s, "%.*g", JSONW_DIGITS, v);
    return json_real(strtod(s, NULL));
}

json_t *jsonw_exact_array(const double *v, size_t n)
{
    json_t *a = json_array();
    for (size_t i = 0; a && i < n; i++)
        if (json_array_append_new(a, jsonw_exact(v[i])) < 0) {
            json_decref(a);
            return NULL;
        }
    return a;
}

json_t *jsonw_string(const char *s)
{
    json_t *j = json_string(s);
    if (j || !s)
        return j;
    char *copy = strdup(s); /* not UTF-8: keep what is plain ASCII */
    if (!copy)
        return NULL;
    for (char *c = copy; *c; c++)
        if ((unsigned char)*c >= 0x80)
            *c = '?';
    j = json_string(copy);
    free(copy);
    return j;
}

int jsonw_set(json_t *o, const char *key, json_t *v)
{
    return json_object_set_new(o, key, v) == 0 ? 0 : fn_err_set(FN_ENOMEM, "out of memory for JSON '%s'", key);
}

/* ---- writing ---- */

typedef struct buf {
    char *s;
    size_t len, cap;
    int oom;
} buf;

static void put(buf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void put(buf *b, const char *fmt, ...)
{
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        int n = b->oom ? 0 : vsnprintf(b->s + b->len, b->cap - b->len, fmt, ap);
        va_end(ap);
        if (b->oom || n < 0 || (size_t)n < b->cap - b->len) {
            b->len += n > 0 ? (size_t)n : 0;
            return;
        }
        size_t cap = (b->cap + (size_t)n) * 2;
        char *s = realloc(b->s, cap);
        if (!s) {
            b->oom = 1;
            return;
        }
        b->s = s, b->cap = cap;
    }
}

/* The shortest %.Ng that reads back as v, with a '.' or an exponent so that it stays a real. */
static void put_real(buf *b, double v)
{
    if (!isfinite(v)) {
        put(b, "null");
        return;
    }
    char s[40];
    int p;
    for (p = 1; p < 17; p++) {
        snprintf(s, sizeof s, "%.*g", p, v);
        if (strtod(s, NULL) == v)
            break;
    }
    int e = (int)floor(log10(fabs(v)));
    if (v != 0 && e >= p && e < 16) /* 300, not %g's 3e+02: the same digits without an exponent */
        snprintf(s, sizeof s, "%.0f", v);
    else
        snprintf(s, sizeof s, "%.*g", p, v);
    put(b, "%s%s", s, strpbrk(s, ".e") ? "" : ".0");
}

static void put_string(buf *b, const char *s)
{
    put(b, "\"");
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\')
            put(b, "\\%c", c);
        else if (c == '\n')
            put(b, "\\n");
        else if (c == '\t')
            put(b, "\\t");
        else if (c < 0x20 || c == 0x7f)
            put(b, "\\u%04x", c);
        else
            put(b, "%c", c);
    }
    put(b, "\"");
}

static int is_plain(json_t *v)
{
    return !json_is_object(v) && !json_is_array(v);
}

static void put_value(buf *b, json_t *v, int depth);

static void newline(buf *b, int depth)
{
    put(b, "\n%*s", 2 * depth, "");
}

static void put_array(buf *b, json_t *a, int depth)
{
    size_t n = json_array_size(a), i;
    int inline_ = 1;
    for (i = 0; i < n; i++)
        inline_ &= is_plain(json_array_get(a, i));
    put(b, "[");
    for (i = 0; i < n; i++) {
        if (inline_)
            put(b, "%s", i ? ", " : "");
        else {
            put(b, "%s", i ? "," : "");
            newline(b, depth + 1);
        }
        put_value(b, json_array_get(a, i), depth + 1);
    }
    if (!inline_ && n)
        newline(b, depth);
    put(b, "]");
}

static void put_object(buf *b, json_t *o, int depth)
{
    const char *key;
    json_t *v;
    int first = 1;
    put(b, "{");
    json_object_foreach(o, key, v) {
        put(b, "%s", first ? "" : ",");
        newline(b, depth + 1);
        put_string(b, key);
        put(b, ": ");
        put_value(b, v, depth + 1);
        first = 0;
    }
    if (!first)
        newline(b, depth);
    put(b, "}");
}

static void put_value(buf *b, json_t *v, int depth)
{
    switch (json_typeof(v)) {
    case JSON_OBJECT: put_object(b, v, depth); break;
    case JSON_ARRAY: put_array(b, v, depth); break;
    case JSON_STRING: put_string(b, json_string_value(v)); break;
    case JSON_INTEGER: put(b, "%" JSON_INTEGER_FORMAT, json_integer_value(v)); break;
    case JSON_REAL: put_real(b, json_real_value(v)); break;
    case JSON_TRUE: put(b, "true"); break;
    case JSON_FALSE: put(b, "false"); break;
    case JSON_NULL: put(b, "null"); break;
    }
}

char *jsonw_dumps(json_t *root)
{
    buf b = {malloc(1024), 0, 1024, 0};
    b.oom = !b.s;
    put_value(&b, root, 0);
    put(&b, "\n");
    if (b.oom) {
        free(b.s);
        return NULL;
    }
    return b.s;
}

int jsonw_print(json_t *root, FILE *out)
{
    char *s = root ? jsonw_dumps(root) : NULL;
    json_decref(root);
    if (!s)
        return fn_err_set(FN_ENOMEM, "out of memory for the JSON output");
    int ok = fputs(s, out) >= 0 && fflush(out) == 0;
    free(s);
    return ok ? 0 : fn_err_set(FN_EIO, "cannot write the JSON output: %s", strerror(errno));
}
