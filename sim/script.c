#include "script.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "simfile.h"

#define MAX_TOKENS 32

typedef struct tokens {
    char *t[MAX_TOKENS];
    int n;
} tokens;

typedef struct pctx {
    const char *name;
    int line;
} pctx;

static int bad(const pctx *c, const char *fmt, const char *arg)
{
    char what[160];
    snprintf(what, sizeof what, fmt, arg);
    return fn_err_set(FN_EFORMAT, "%s:%d: %s", c->name, c->line, what);
}

static int number(const char *s, double *v)
{
    char *end;
    errno = 0;
    *v = strtod(s, &end);
    return end == s || *end || errno || !isfinite(*v) ? -1 : 0;
}

/* "T s" or "T ms" at tokens i, i+1; seconds into *sec. */
static int duration(const pctx *c, const tokens *tk, int i, double *sec)
{
    if (i + 1 >= tk->n || number(tk->t[i], sec))
        return bad(c, "expected a duration like '2 s' or '500 ms' at '%s'",
                   i < tk->n ? tk->t[i] : "end of line");
    const char *u = tk->t[i + 1];
    if (!strcmp(u, "ms"))
        *sec /= 1000;
    else if (strcmp(u, "s"))
        return bad(c, "unknown time unit '%s' (use s or ms)", u);
    if (*sec < 0 || *sec > SCRIPT_MAX_SECONDS)
        return bad(c, "duration out of range 0..3600 s%s", "");
    return i + 2 == tk->n ? 0 : bad(c, "unexpected '%s' after the duration", tk->t[i + 2]);
}

static int axis_index(const char *s)
{
    static const char *names[] = {"x", "y", "z", "rx", "ry", "rz"};
    for (int i = 0; i < 6; i++)
        if (!strcmp(s, names[i]))
            return i;
    return -1;
}

/* One "AXIS AMOUNT UNIT" triple at i (AXIS may carry a sign: +x, -z). rot: 1 for rotate (AXIS x
 * means rx), 0 for translate, -1 for move (AXIS names the axis fully). */
static int axis_amount(const pctx *c, const tokens *tk, int i, int rot, double amount[6])
{
    if (i + 2 >= tk->n)
        return bad(c, "expected AXIS AMOUNT UNIT (e.g. 'x 20 mm'), line ends early%s", "");
    const char *a = tk->t[i];
    double sign = 1;
    if (*a == '+' || *a == '-')
        sign = *a++ == '-' ? -1 : 1;
    int ax = axis_index(a);
    if (ax < 0 || (rot >= 0 && ax >= 3))
        return bad(c, "unknown axis '%s' (x y z; move also takes rx ry rz)", tk->t[i]);
    if (rot == 1)
        ax += 3;
    double v;
    if (number(tk->t[i + 1], &v))
        return bad(c, "expected a number, got '%s'", tk->t[i + 1]);
    const char *want = ax < 3 ? "mm" : "deg";
    if (strcmp(tk->t[i + 2], want))
        return bad(c, ax < 3 ? "translation is in mm, got '%s'" : "rotation is in deg, got '%s'",
                   tk->t[i + 2]);
    amount[ax] += sign * v;
    return 0;
}

static int motion(const pctx *c, const tokens *tk, int i, int rot, script_step *st)
{
    double amount[6] = {0};
    int over = -1;
    for (int k = i; k < tk->n; k++)
        if (!strcmp(tk->t[k], "over")) {
            over = k;
            break;
        }
    if (over < 0)
        return bad(c, "motion needs 'over DURATION' (e.g. 'over 2 s')%s", "");
    if (rot == 1 && i < over && !strcmp(tk->t[i], "about"))
        i++;
    int rc = 0;
    for (int k = i; k < over && !rc; k += 3)
        rc = over - k < 3 ? bad(c, "expected AXIS AMOUNT UNIT before 'over'%s", "")
                          : axis_amount(c, tk, k, rot, amount);
    if (rc || (rc = duration(c, tk, over + 1, &st->seconds)))
        return rc;
    if (i == over)
        return bad(c, "motion names no axis%s", "");
    if (st->seconds <= 0)
        return bad(c, "a motion takes a positive time%s", "");
    st->op = SCRIPT_MOVE;
    for (int a = 0; a < 6; a++) {
        st->speed[a] = amount[a] / st->seconds;
        double full = a < 3 ? SCRIPT_MM_PER_S_FULL : SCRIPT_DEG_PER_S_FULL;
        if (fabs(st->speed[a]) > full * (1 + 1e-9)) {
            char msg[160];
            snprintf(msg, sizeof msg, "%.4g %s/s is faster than full deflection (%g %s/s): take "
                     "more time", fabs(st->speed[a]), a < 3 ? "mm" : "deg", full, a < 3 ? "mm" : "deg");
            return bad(c, "%s", msg);
        }
    }
    return 0;
}

static int buttons(const pctx *c, const tokens *tk, script_step *st)
{
    st->mask = 0;
    for (int k = 1; k < tk->n; k++) {
        char *end;
        long b = strtol(tk->t[k], &end, 10);
        if (*end || end == tk->t[k] || b < 1 || b > 32)
            return bad(c, "button must be a number 1..32, got '%s'", tk->t[k]);
        st->mask |= 1u << (b - 1);
    }
    if (!st->mask) {
        if (st->op == SCRIPT_PRESS)
            return bad(c, "press needs a button number%s", "");
        st->mask = 0xffffffffu;
    }
    return 0;
}

static int parse_line(const pctx *c, tokens *tk, script_step *st)
{
    memset(st, 0, sizeof *st);
    st->line = c->line;
    if (!strcmp(tk->t[0], "hold")) {
        st->hold = 1;
        memmove(tk->t, tk->t + 1, (size_t)--tk->n * sizeof *tk->t);
        if (!tk->n || (strcmp(tk->t[0], "translate") && strcmp(tk->t[0], "rotate") &&
                       strcmp(tk->t[0], "move")))
            return bad(c, "'hold' goes before translate, rotate or move%s", "");
    }
    const char *w = tk->t[0];
    if (!strcmp(w, "translate"))
        return motion(c, tk, 1, 0, st);
    if (!strcmp(w, "rotate"))
        return motion(c, tk, 1, 1, st);
    if (!strcmp(w, "move"))
        return motion(c, tk, 1, -1, st);
    if (!strcmp(w, "press") || !strcmp(w, "release")) {
        st->op = w[0] == 'p' ? SCRIPT_PRESS : SCRIPT_RELEASE;
        return buttons(c, tk, st);
    }
    if (!strcmp(w, "wait")) {
        st->op = SCRIPT_WAIT;
        return duration(c, tk, 1, &st->seconds);
    }
    if (!strcmp(w, "unplug") || !strcmp(w, "replug")) {
        st->op = w[0] == 'u' ? SCRIPT_UNPLUG : SCRIPT_REPLUG;
        return tk->n == 1 ? 0 : bad(c, "'%s' takes no arguments", w);
    }
    return bad(c, "unknown command '%s' (translate, rotate, move, press, release, wait, unplug, "
                  "replug)", w);
}

static int split_tokens(const pctx *c, char *s, tokens *tk)
{
    tk->n = 0;
    char *hash = strchr(s, '#');
    if (hash)
        *hash = '\0';
    for (char *p = strtok(s, " \t\r"); p; p = strtok(NULL, " \t\r")) {
        if (tk->n == MAX_TOKENS)
            return bad(c, "too many words on one line%s", "");
        tk->t[tk->n++] = p;
    }
    return 0;
}

int script_parse(const char *text, size_t len, const char *name, script **out)
{
    *out = NULL;
    script *s = calloc(1, sizeof *s);
    if (!s)
        return fn_err_set(FN_ENOMEM, "out of memory for a script");
    pctx c = {name ? name : "<script>", 0};
    char line[1024];
    size_t pos = 0;
    int rc = 0;
    while (pos < len && !rc) {
        const char *nl = memchr(text + pos, '\n', len - pos);
        size_t n = nl ? (size_t)(nl - text - pos) : len - pos;
        c.line++;
        tokens tk;
        if (n >= sizeof line)
            rc = bad(&c, "line longer than %s characters", "1023");
        else if (memchr(text + pos, '\0', n))
            rc = bad(&c, "NUL byte in a text file%s", "");
        else {
            memcpy(line, text + pos, n);
            line[n] = '\0';
            rc = split_tokens(&c, line, &tk);
            if (!rc && tk.n) {
                if (s->n == SCRIPT_MAX_STEPS)
                    rc = bad(&c, "more than %s commands", "4096");
                else
                    rc = parse_line(&c, &tk, &s->step[s->n++]);
            }
        }
        pos += n + (nl != NULL);
    }
    if (rc) {
        free(s);
        return rc;
    }
    *out = s;
    return 0;
}

script *script_load(const char *path)
{
    char *buf;
    size_t n;
    if (simfile_read(path, 1 << 20, "1 MiB", &buf, &n))
        return NULL;
    script *s = NULL;
    script_parse(buf, n, path, &s);
    free(buf);
    return s;
}

void script_header(const sim_profile *p, fnrec_header *h)
{
    memset(h, 0, sizeof *h);
    h->version = FNREC_VERSION;
    h->vid = p->vid;
    h->pid = p->pid;
    snprintf(h->name, sizeof h->name, "%s", p->name);
    snprintf(h->format, sizeof h->format, "%s", p->format == SIMDEV_SPLIT ? "split" : "combined");
    snprintf(h->source, sizeof h->source, "virtual:%s (simulated device, not hardware)", p->id);
    h->desc_len = sim_profile_descriptor(p, h->desc, sizeof h->desc);
}

/* Rendering state: the device, the clock on its cadence grid, the dithered deflection. */
typedef struct render {
    fnrec *rec;
    simdev dev;
    int64_t next_tick;
    double level[6], carry[6];
    int plugged;
} render;

static int emit(render *r, int64_t t, fnrec_dir dir, const uint8_t *b, int n)
{
    fnrec_event e = {.t_us = t, .dir = dir, .len = (uint8_t)n};
    if (n)
        memcpy(e.data, b, (size_t)n);
    return fnrec_append(r->rec, &e);
}

/* The deflection for one tick: the target level plus the carried rounding error. */
static void dither(const render *r, int16_t out[6])
{
    for (int a = 0; a < 6; a++)
        out[a] = (int16_t)(r->level[a] == 0 ? 0 : round(r->level[a] + r->carry[a]));
}

/* The carry moves on only for the axes the report just sent carried. */
static void commit_carry(render *r, const int16_t sent[6], const uint8_t *report, int n)
{
    int first = 0, count = 6;
    if (n == 0 || report[0] > 2)
        return;
    if (r->dev.p->format == SIMDEV_SPLIT)
        first = report[0] == 1 ? 0 : 3, count = 3;
    for (int a = first; a < first + count; a++)
        r->carry[a] = r->level[a] == 0 ? 0 : r->level[a] + r->carry[a] - sent[a];
}

/* Runs the device's periods up to (not including) t_end. */
static int run_until(render *r, int64_t t_end)
{
    for (; r->next_tick < t_end; r->next_tick += simdev_period_us(&r->dev)) {
        int16_t a[6];
        dither(r, a);
        simdev_set(&r->dev, a, r->dev.buttons);
        uint8_t buf[64];
        int n = simdev_next(&r->dev, buf, sizeof buf);
        commit_carry(r, a, buf, n);
        int rc = n && r->plugged ? emit(r, r->next_tick, FNREC_IN, buf, n) : 0;
        if (rc)
            return rc;
    }
    return 0;
}

static void set_level(render *r, const double speed[6])
{
    for (int a = 0; a < 6; a++) {
        double full = a < 3 ? SCRIPT_MM_PER_S_FULL : SCRIPT_DEG_PER_S_FULL;
        r->level[a] = speed ? speed[a] / full * SCRIPT_FULL_COUNTS : 0;
        if (!speed)
            r->carry[a] = 0;
    }
}

static int render_step(render *r, const script_step *st, int64_t *now)
{
    int rc = 0;
    switch (st->op) {
    case SCRIPT_MOVE:
        set_level(r, st->speed);
        *now += llround(st->seconds * 1e6);
        rc = run_until(r, *now);
        if (!st->hold)
            set_level(r, NULL);
        break;
    case SCRIPT_WAIT:
        *now += llround(st->seconds * 1e6);
        rc = run_until(r, *now);
        break;
    case SCRIPT_PRESS:
    case SCRIPT_RELEASE:
        r->dev.buttons = st->op == SCRIPT_PRESS ? r->dev.buttons | st->mask : r->dev.buttons & ~st->mask;
        break;
    case SCRIPT_UNPLUG:
        if (r->plugged && !(rc = emit(r, *now, FNREC_DISCONNECT, NULL, 0)))
            r->plugged = 0;
        break;
    case SCRIPT_REPLUG:
        if (!r->plugged && !(rc = emit(r, *now, FNREC_CONNECT, NULL, 0))) {
            uint32_t held = r->dev.buttons;
            simdev_replug(&r->dev); /* power-on: volatile settings reset */
            r->dev.buttons = held;
            r->plugged = 1;
        }
        break;
    }
    return rc;
}

static fnrec *render_script(const script *s, const sim_profile *p, const simdev *live, uint32_t *held)
{
    fnrec_header h;
    script_header(p, &h);
    render r = {.rec = fnrec_new(&h), .plugged = 1};
    if (!r.rec)
        return NULL;
    simdev_init(&r.dev, p);
    if (live)
        simdev_copy_settings(&r.dev, live);
    r.next_tick = simdev_period_us(&r.dev);
    int64_t now = 0;
    int rc = 0;
    if (held) { /* a continuation: connected for a while, these buttons down */
        r.dev.battery_pending = 0;
        r.dev.buttons = r.dev.sent_buttons = *held;
    } else {
        rc = emit(&r, 0, FNREC_CONNECT, NULL, 0);
    }
    for (size_t i = 0; i < s->n && !rc; i++) {
        rc = render_step(&r, &s->step[i], &now);
        if (rc)
            fn_err_wrap(rc, "script line %d", s->step[i].line);
    }
    set_level(&r, NULL);
    for (int k = 0; k < 16 && !rc && !simdev_idle(&r.dev); k++) /* the zeros after release */
        rc = run_until(&r, r.next_tick + 1);
    if (rc) {
        fnrec_free(r.rec);
        return NULL;
    }
    if (held)
        *held = r.dev.buttons;
    return r.rec;
}

fnrec *script_render(const script *s, const sim_profile *p)
{
    return render_script(s, p, NULL, NULL);
}

fnrec *script_render_live(const script *s, const simdev *live)
{
    return render_script(s, live->p, live, NULL);
}

fnrec *script_render_more(const script *s, const simdev *live, uint32_t *held)
{
    return render_script(s, live->p, live, held);
}
