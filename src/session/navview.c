#include "navview.h"

#include "err.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#define FIELD_MAX 512
#define FIELDS_MAX 24
#define GAP "   " /* between fields on a terminal line */

/* The fields of the view, each starting a group (a new terminal line) or not. */
typedef struct fields {
    char text[FIELDS_MAX][FIELD_MAX];
    int group[FIELDS_MAX]; /* 1: starts a new line on a terminal */
    int n;
} fields;

static void add(fields *f, int new_group, const char *fmt, ...) FN_PRINTF(3, 4);
static void add(fields *f, int new_group, const char *fmt, ...)
{
    if (f->n == FIELDS_MAX)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(f->text[f->n], FIELD_MAX, fmt, ap);
    va_end(ap);
    f->group[f->n++] = new_group;
}

double navview_rotation(const pose *p, double axis[3])
{
    double s = sqrt(p->q[1] * p->q[1] + p->q[2] * p->q[2] + p->q[3] * p->q[3]);
    if (s < 1e-12) {
        axis[0] = 1, axis[1] = axis[2] = 0;
        return 0;
    }
    double rv[3], a = pose_to_rotvec(p, rv);
    for (int i = 0; i < 3; i++)
        axis[i] = rv[i] / a;
    return a * 180 / M_PI;
}

static void warnings(const loop_scene *s, const navview_extra *x, fields *f)
{
    const char *w[] = {s->collision_on ? NULL : "COLLISION CHECKING OFF",
                       s->penetrating && !s->tolerated ? "PENETRATING" : NULL,
                       s->device_present ? NULL : "DEVICE UNPLUGGED",
                       s->stats.journal_errors ? "JOURNAL WRITE FAILED" : NULL};
    char line[FIELD_MAX] = "";
    size_t len = 0;
    for (size_t i = 0; i < sizeof w / sizeof w[0]; i++)
        if (w[i])
            len += (size_t)snprintf(line + len, sizeof line - len, "%s%s", len ? " | " : "WARNING: ", w[i]);
    if (len)
        add(f, 1, "%s", line);
    if (x && x->refused)
        add(f, 1, "WARNING: another controller, not taken: %s", x->refused);
}

static void contact(const loop_scene *s, fields *f)
{
    static const char *outcome[] = {"at rest", "moved", "stopped at the contact", "sliding along the contact",
                                    "blocked"};
    double g = s->separation_mm;
    if (!s->collision_on)
        add(f, 0, "contact not checked");
    else if (s->penetrating && s->tolerated)
        add(f, 0, "fitted: inside by ~%.2f mm, within the fit's tolerance", g < 0 ? -g : 0);
    else if (s->penetrating)
        add(f, 0, "inside another fragment by ~%.2f mm", g < 0 ? -g : 0);
    else if (isnan(g))
        add(f, 0, "gap not measured");
    else if (g < 0.005)
        add(f, 0, "touching");
    else if (isinf(g))
        add(f, 0, "clear");
    else
        add(f, 0, "clear, gap >= %.2f mm", g);
    add(f, 0, "last move: %s", outcome[s->last_outcome]);
}

/* v, less what would print as -0.00. */
static double shown(double v)
{
    return fabs(v) < 0.005 ? 0 : v;
}

/* "12.30 left": a distance along one anatomical axis (LPS: +x left, +y posterior, +z superior). */
static void along(char *buf, size_t cap, double v, int axis)
{
    static const char *name[3][3] = {{"right", "L/R", "left"}, {"anterior", "A/P", "posterior"},
                                     {"inferior", "S/I", "superior"}};
    v = shown(v);
    snprintf(buf, cap, "%.2f %s", fabs(v), name[axis][v > 0 ? 2 : v < 0 ? 0 : 1]);
}

void navview_move_text(const double d[3], char *buf, size_t cap)
{
    char a[3][32];
    for (int i = 0; i < 3; i++)
        along(a[i], sizeof a[i], d[i], i);
    snprintf(buf, cap, "%s, %s, %s mm", a[0], a[1], a[2]);
}

void navview_turn_text(const pose *p, char *buf, size_t cap)
{
    double axis[3], deg = navview_rotation(p, axis);
    if (deg < 0.005)
        snprintf(buf, cap, "not turned");
    else
        snprintf(buf, cap, "turned %.2f deg: L/R %+.2f, A/P %+.2f, S/I %+.2f", deg, shown(axis[0] * deg),
                 shown(axis[1] * deg), shown(axis[2] * deg));
}

static void pose_fields(const loop_scene *s, const navview_extra *x, fields *f)
{
    const pose *p = &s->pose[s->selected];
    double d[3];
    if (x && x->frags) {
        const double *c = x->frags[s->selected].centroid;
        pose_apply(p, c, d);
        for (int i = 0; i < 3; i++)
            d[i] -= c[i];
    } else {
        memcpy(d, p->t, sizeof d);
    }
    char move[128], turn[128];
    navview_move_text(d, move, sizeof move);
    navview_turn_text(p, turn, sizeof turn);
    add(f, 1, "%s%s", x && x->frags ? "moved " : "", move);
    add(f, 0, "%s", turn);
}

static void fill(const loop_scene *s, const navview_extra *x, fields *f)
{
    static const char *frame[] = {"camera", "world", "fragment"};
    f->n = 0;
    warnings(s, x, f);
    add(f, 1, "frag %d/%d%s", s->selected + 1, s->nfrag, s->fixed[s->selected] ? " (fixed)" : "");
    contact(s, f);
    pose_fields(s, x, f);
    add(f, 1, "%s frame%s%s", frame[s->frame], s->trans_only ? ", translation only" : "",
        s->rot_only ? ", rotation only" : "");
    if (x && x->battery >= 0)
        add(f, 0, "battery %d%%", x->battery);
    add(f, 0, "%.0f steps/s", s->stats.step_hz);
    add(f, 0, "latency p99 %.0f us", s->stats.latency_p99_us);
    add(f, 0, "query %.0f us", s->stats.query_us_mean);
    if (x && x->fit)
        add(f, 1, "%s", x->fit);
    if (x && x->preview && x->preview[0])
        add(f, 1, "%s", x->preview);
    if (x && x->ack)
        add(f, 1, "> %s", x->ack);
    add(f, !(x && x->ack), "? or h: keys");
}

/* Appends text to buf at *len (keeping the NUL); 0 when it did not fit. */
static int put(char *buf, size_t cap, size_t *len, const char *text, size_t n)
{
    if (*len + n + 1 > cap)
        return 0;
    memcpy(buf + *len, text, n);
    *len += n;
    buf[*len] = '\0';
    return 1;
}

/* The packing state of navview_format. */
typedef struct packer {
    char *buf;
    size_t cap, len, line_start;
    int lines, width, full;
} packer;

static void newline(packer *p)
{
    if (p->full || !put(p->buf, p->cap, &p->len, "\n", 1)) {
        p->full = 1;
        return;
    }
    p->line_start = p->len;
    p->lines++;
}

/* One field onto the current line, or the next; a field wider than a line is wrapped at spaces
 * (or cut, for a word longer than a line). */
static void place(packer *p, const char *t, int new_group)
{
    size_t room = (size_t)p->width - 1, used = p->len - p->line_start, n = strlen(t);
    if (used && (new_group || used + strlen(GAP) + n > room)) {
        newline(p);
        used = 0;
    } else if (used) {
        p->full |= !put(p->buf, p->cap, &p->len, GAP, strlen(GAP));
        used += strlen(GAP);
    }
    while (!p->full && n) {
        size_t take = n <= room - used ? n : room - used;
        if (take < n) { /* break at the last space that fits */
            size_t sp = take;
            while (sp > 0 && t[sp] != ' ')
                sp--;
            take = sp > 0 ? sp : take;
        }
        p->full |= !put(p->buf, p->cap, &p->len, t, take);
        t += take, n -= take;
        while (n && *t == ' ')
            t++, n--;
        if (n) {
            newline(p);
            used = 0;
        }
    }
}

int navview_format(const loop_scene *s, const navview_extra *x, int width, char *buf, size_t cap)
{
    fields f;
    fill(s, x, &f);
    buf[0] = '\0';
    if (width <= 0) {
        size_t len = 0;
        for (int i = 0; i < f.n; i++)
            if (!(i && !put(buf, cap, &len, " | ", 3)) && !put(buf, cap, &len, f.text[i], strlen(f.text[i])))
                break;
        return 1;
    }
    if (width < 8)
        width = 8;
    packer p = {buf, cap, 0, 0, 1, width, 0};
    for (int i = 0; i < f.n && !p.full; i++)
        place(&p, f.text[i], f.group[i]);
    return p.lines;
}

void navview_ack(const loop_scene *s, char *buf, size_t cap)
{
    static const char *frame[] = {"camera", "world", "fragment"};
    int sel = s->selected + 1, r = s->last_action_result;
    switch (s->last_action) {
    case LOOP_ACT_NEXT:
    case LOOP_ACT_PREV: {
        int movable = 0;
        for (int i = 0; i < s->nfrag; i++)
            movable += !s->fixed[i];
        snprintf(buf, cap, "%s: frag %d/%d%s", s->last_action == LOOP_ACT_NEXT ? "next" : "previous", sel,
                 s->nfrag, !movable ? " (every fragment is fixed)" : movable == 1 ? " (the only one not fixed)" : "");
        break;
    }
    case LOOP_ACT_FIX:
        snprintf(buf, cap, s->fixed[s->selected] ? "frag %d fixed" : "frag %d free to move", sel);
        break;
    case LOOP_ACT_COLLISION:
        snprintf(buf, cap, "collision checking %s", s->collision_on ? "on" : "OFF: moves are not checked");
        break;
    case LOOP_ACT_TRANS_ONLY:
        snprintf(buf, cap, "translation only %s", s->trans_only ? "on" : "off");
        break;
    case LOOP_ACT_ROT_ONLY:
        snprintf(buf, cap, "rotation only %s", s->rot_only ? "on" : "off");
        break;
    case LOOP_ACT_UNDO:
    case LOOP_ACT_REDO: {
        const char *what = s->last_action == LOOP_ACT_UNDO ? "undo" : "redo";
        if (r == LOOP_ACCEPTED)
            snprintf(buf, cap, "%s: one move of a fragment %s", what,
                     s->last_action == LOOP_ACT_UNDO ? "taken back" : "done again");
        else if (r == LOOP_REFUSED)
            snprintf(buf, cap, "%s refused: that pose collides now", what);
        else
            snprintf(buf, cap, "nothing to %s", what);
        break;
    }
    case LOOP_ACT_SAVE:
        snprintf(buf, cap, "saving...");
        break;
    case LOOP_ACT_FRAME:
        snprintf(buf, cap, "frame: %s", frame[s->frame]);
        break;
    case LOOP_ACT_FIT:
        snprintf(buf, cap, "fit: frag %d to the others", s->selected + 1);
        break;
    default:
        buf[0] = '\0';
        break;
    }
}

const char *navview_help(int keyboard)
{
    if (keyboard)
        return "keys (the keyboard steers, typed in the terminal or the window):\n"
               "  arrows or a/d w/s  move in x and y        r/f  up/down\n"
               "  i/k j/l u/o        rotate                 space or x  stop\n"
               "  1 next  2 previous  3 fix  4 collision  5 translation only  6 rotation only\n"
               "  7 undo  8 redo  9 save  0 or m frame  g fit  v preview  b accept it\n"
               "  q quit (saves)  ? or h keys\n"
               "  terminal mouse: left drag rotates, middle rolls, right moves, wheel up/down\n"
               "Ctrl-C quits and saves.\n";
    return "keys beside a controller: n/p next/previous fragment   f fix or unfix\n"
           "  c collision checking on/off   t translation only   r rotation only\n"
           "  u undo   y redo   m frame   s save   g fit to the others   q quit (saves)\n"
           "  v preview the fit on/off (on by itself near contact)   b accept the preview\n"
           "  ? or h these keys\n"
           "controller buttons: 1 next  2 previous  3 fix  4 collision  5 translation only\n"
           "  6 rotation only  7 undo  8 redo  9 save  10 frame  12 fit  13 preview\n"
           "  14 accept the preview (SpaceMouse\n"
           "  Enterprise: its keys labelled 1-10; spnavrc's bnmapN moves them, bnmapN = 11\n"
           "  puts fit on N)\n"
           "Ctrl-C quits and saves.\n";
}
