#include "hiddesc.h"

#include <string.h>

#include "err.h"

#define STACK_MAX 8
#define LOCAL_MAX 32

typedef struct globals {
    uint16_t page;
    int32_t lmin, lmax;
    uint32_t size, count;
    uint8_t id;
} globals;

typedef struct walker {
    globals g, stack[STACK_MAX];
    int depth, sp;
    uint32_t usage[LOCAL_MAX];
    size_t n_usage;
    uint32_t umin, umax;
    int have_range;
    hiddesc *out;
} walker;

static uint32_t item_u(const uint8_t *p, int n)
{
    uint32_t v = 0;
    for (int i = 0; i < n; i++)
        v |= (uint32_t)p[i] << 8 * i;
    return v;
}

static int32_t item_s(const uint8_t *p, int n)
{
    uint32_t v = item_u(p, n);
    if (n == 1)
        return (int8_t)v;
    if (n == 2)
        return (int16_t)v;
    return (int32_t)v;
}

static uint32_t full_usage(const walker *w, uint32_t u, int n)
{
    return n == 4 ? u : (uint32_t)w->g.page << 16 | (u & 0xffff);
}

static hiddesc_report *slot(walker *w, hiddesc_kind kind, size_t off)
{
    hiddesc *d = w->out;
    for (size_t i = 0; i < d->n; i++)
        if (d->report[i].kind == kind && d->report[i].id == w->g.id)
            return &d->report[i];
    if (d->n == HIDDESC_REPORTS_MAX) {
        fn_err_set(FN_EFORMAT, "HID descriptor: more than %d reports (offset %zu)", HIDDESC_REPORTS_MAX, off);
        return NULL;
    }
    hiddesc_report *r = &d->report[d->n++];
    memset(r, 0, sizeof *r);
    r->kind = kind;
    r->id = w->g.id;
    r->usage_page = w->g.page;
    r->logical_min = INT32_MAX;
    r->logical_max = INT32_MIN;
    return r;
}

static uint32_t usage_at(const walker *w, uint32_t i)
{
    if (w->have_range && w->umin <= w->umax) {
        uint32_t u = w->umin + i;
        return u > w->umax ? w->umax : u;
    }
    if (!w->n_usage)
        return 0;
    return w->usage[i < w->n_usage ? i : w->n_usage - 1];
}

static int main_field(walker *w, hiddesc_kind kind, uint32_t flags, size_t off)
{
    hiddesc_report *r = slot(w, kind, off);
    if (!r)
        return FN_EFORMAT;
    uint64_t bits = (uint64_t)w->g.size * w->g.count + r->bits;
    if (bits > 8 * (HIDDESC_REPORT_BYTES_MAX - 1))
        return fn_err_set(FN_EFORMAT, "HID descriptor: %s report %u longer than %d bytes (offset %zu)",
                          hiddesc_kind_name(kind), r->id, HIDDESC_REPORT_BYTES_MAX, off);
    r->bits = (uint32_t)bits;
    r->len = (r->bits + 7) / 8 + (r->id ? 1 : 0);
    if (flags & 1) /* constant: padding */
        return 0;
    int32_t lmin = w->g.lmin, lmax = w->g.lmax;
    if (lmin >= 0 && lmax < 0) /* a positive maximum written without its sign byte */
        lmax = (int32_t)((uint32_t)lmax & 0x7fffffff);
    if (lmin < r->logical_min)
        r->logical_min = lmin;
    if (lmax > r->logical_max)
        r->logical_max = lmax;
    uint32_t n = (flags & 2) ? w->g.count : 1;
    for (uint32_t i = 0; i < n && r->n_usages < HIDDESC_USAGES_MAX; i++)
        r->usages[r->n_usages++] = usage_at(w, i);
    return 0;
}

static int main_item(walker *w, int tag, uint32_t v, size_t off)
{
    int rc = 0;
    switch (tag) {
    case 0x8: rc = main_field(w, HIDDESC_INPUT, v, off); break;
    case 0x9: rc = main_field(w, HIDDESC_OUTPUT, v, off); break;
    case 0xB: rc = main_field(w, HIDDESC_FEATURE, v, off); break;
    case 0xA:
        if (w->depth == 0 && v == 1 && !w->out->top_usage_page) {
            uint32_t u = usage_at(w, 0);
            w->out->top_usage_page = (uint16_t)(u >> 16);
            w->out->top_usage = (uint16_t)u;
        }
        if (++w->depth > 32)
            return fn_err_set(FN_EFORMAT, "HID descriptor: collections nested too deep (offset %zu)", off);
        break;
    case 0xC:
        if (--w->depth < 0)
            return fn_err_set(FN_EFORMAT, "HID descriptor: End Collection without Collection (offset %zu)", off);
        break;
    default: break;
    }
    w->n_usage = 0;
    w->have_range = 0;
    return rc;
}

static int global_item(walker *w, int tag, const uint8_t *p, int n, size_t off)
{
    uint32_t u = item_u(p, n);
    switch (tag) {
    case 0x0: w->g.page = (uint16_t)u; break;
    case 0x1: w->g.lmin = item_s(p, n); break;
    case 0x2: w->g.lmax = item_s(p, n); break;
    case 0x7:
        if (u > 32)
            return fn_err_set(FN_EFORMAT, "HID descriptor: Report Size %u over 32 (offset %zu)", u, off);
        w->g.size = u;
        break;
    case 0x8:
        if (u == 0 || u > 255)
            return fn_err_set(FN_EFORMAT, "HID descriptor: Report ID %u out of 1..255 (offset %zu)", u, off);
        w->g.id = (uint8_t)u;
        break;
    case 0x9:
        if (u > 8 * HIDDESC_REPORT_BYTES_MAX)
            return fn_err_set(FN_EFORMAT, "HID descriptor: Report Count %u too large (offset %zu)", u, off);
        w->g.count = u;
        break;
    case 0xA:
        if (w->sp == STACK_MAX)
            return fn_err_set(FN_EFORMAT, "HID descriptor: Push overflows the stack (offset %zu)", off);
        w->stack[w->sp++] = w->g;
        break;
    case 0xB:
        if (w->sp == 0)
            return fn_err_set(FN_EFORMAT, "HID descriptor: Pop without Push (offset %zu)", off);
        w->g = w->stack[--w->sp];
        break;
    default: break;
    }
    return 0;
}

static void local_item(walker *w, int tag, const uint8_t *p, int n)
{
    uint32_t u = full_usage(w, item_u(p, n), n);
    if (tag == 0x0 && w->n_usage < LOCAL_MAX)
        w->usage[w->n_usage++] = u;
    else if (tag == 0x1)
        w->umin = u, w->have_range = 1;
    else if (tag == 0x2)
        w->umax = u, w->have_range = 1;
}

int hiddesc_parse(const uint8_t *desc, size_t len, hiddesc *out)
{
    static const walker zero;
    walker w = zero;
    memset(out, 0, sizeof *out);
    w.out = out;
    size_t i = 0;
    while (i < len) {
        uint8_t b = desc[i];
        if (b == 0xFE) { /* long item: skip its data */
            if (len - i < 3 || len - i - 3 < desc[i + 1])
                return fn_err_set(FN_EFORMAT, "HID descriptor: truncated long item at offset %zu", i);
            i += 3 + (size_t)desc[i + 1];
            continue;
        }
        int n = (b & 3) == 3 ? 4 : b & 3, type = b >> 2 & 3, tag = b >> 4;
        if (len - i - 1 < (size_t)n)
            return fn_err_set(FN_EFORMAT, "HID descriptor: truncated item 0x%02x at offset %zu", b, i);
        const uint8_t *p = desc + i + 1;
        int rc = 0;
        if (type == 0)
            rc = main_item(&w, tag, item_u(p, n), i);
        else if (type == 1)
            rc = global_item(&w, tag, p, n, i);
        else if (type == 2)
            local_item(&w, tag, p, n);
        if (rc)
            return rc;
        i += 1 + (size_t)n;
    }
    if (w.depth != 0)
        return fn_err_set(FN_EFORMAT, "HID descriptor: %d collection(s) not closed at the end (offset %zu)",
                          w.depth, len);
    for (size_t k = 0; k < out->n; k++)
        if (out->report[k].logical_min > out->report[k].logical_max)
            out->report[k].logical_min = out->report[k].logical_max = 0;
    return 0;
}

const hiddesc_report *hiddesc_find(const hiddesc *d, hiddesc_kind kind, uint8_t id)
{
    for (size_t i = 0; i < d->n; i++)
        if (d->report[i].kind == kind && d->report[i].id == id)
            return &d->report[i];
    return NULL;
}

int hiddesc_axis_max(const hiddesc *d)
{
    const hiddesc_report *r = hiddesc_find(d, HIDDESC_INPUT, 1);
    return r && r->logical_max > 0 ? (int)r->logical_max : 0;
}

const char *hiddesc_kind_name(hiddesc_kind k)
{
    return k == HIDDESC_INPUT ? "input" : k == HIDDESC_OUTPUT ? "output" : "feature";
}
