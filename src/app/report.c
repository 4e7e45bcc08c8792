/* report: the HTML page of a case's plan (see report.h). */
#include "report.h"

#include "cmd.h"
#include "durable.h"
#include "err.h"
#include "export.h"
#include "morph.h"
#include "navview.h"
#include "reduce.h"
#include "render.h"
#include "picture.h"

#include <jansson.h>

#ifdef FRACNAV_HAVE_PLPLOT
#include <plplot.h>
#endif

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#define PIC 480

/* The reduction record's entry for fragment id (NULL: none). */
static json_t *record_of(const planning_case *c, int id)
{
    json_t *red = c->extra ? json_object_get(c->extra, "reduction") : NULL;
    json_t *frs = red ? json_object_get(red, "fragments") : NULL, *e;
    size_t k;
    json_array_foreach(frs, k, e) {
        json_t *jid = json_object_get(e, "id");
        if (json_is_integer(jid) && json_integer_value(jid) == id)
            return e;
    }
    return NULL;
}

static int pose_of(json_t *o, pose *p)
{
    json_t *q = json_object_get(o, "q"), *t = json_object_get(o, "t");
    if (json_array_size(q) != 4 || json_array_size(t) != 3)
        return 0;
    for (int i = 0; i < 4; i++)
        p->q[i] = json_number_value(json_array_get(q, (size_t)i));
    for (int i = 0; i < 3; i++)
        p->t[i] = json_number_value(json_array_get(t, (size_t)i));
    pose_normalize(p);
    return 1;
}

/* Before-reduction poses; returns 1 when the case has a reduction record. */
static int before_poses(const planning_case *c, pose *before)
{
    int have = c->extra && json_object_get(c->extra, "reduction");
    for (int i = 0; i < c->nfrag; i++) {
        json_t *e = record_of(c, c->frag[i].id);
        if (!have)
            before[i] = POSE_IDENTITY;
        else if (!e || !pose_of(json_object_get(e, "placed"), &before[i]))
            before[i] = c->frag[i].pose;
    }
    return have;
}

/* The moving fragment the pictures frame: the first that is not fixed. */
static int moving(const planning_case *c)
{
    for (int i = 0; i < c->nfrag; i++)
        if (i != c->fixed)
            return i;
    return 0;
}

static int save_picture(render *r, const char *dir, const char *name, report_wrote_fn wrote, void *ctx)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/%s.png", dir, name);
    int rc = cmd_write_png(r, path, PIC, PIC);
    if (!rc && wrote)
        wrote(ctx, path);
    return rc;
}

/* before.png and after.png through the auto view of the moving fragment at its poses before (so
 * both show it from the same side), the fragments in front of it cut away, and slice.png: the axial slice of the CT through its planned
 * centroid with every fragment's planned outline (the four-up layout's axial pane). */
static int render_pictures(const planning_case *c, const pose *before, const char *dir, const char *platform,
                           report_wrote_fn wrote, void *ctx)
{
    if (c->nfrag > RENDER_MAX_FRAGS)
        return fn_err_set(FN_EINVAL, "the report draws at most %d fragments (%d in the case)", RENDER_MAX_FRAGS,
                          c->nfrag);
    render *r = render_open(platform ? platform : "osmesa", PIC, PIC);
    if (!r)
        return FN_ENODEV;
    uint8_t *rgb = malloc((size_t)PIC * PIC * 3);
    int rc = rgb ? render_set_scene(r, c->ct, c->frag, c->nfrag, c->seg.threshold, NULL)
                 : fn_err_set(FN_ENOMEM, "out of memory for a picture");
    render_options o;
    render_options_default(&o, c->frag, c->nfrag);
    int sel = moving(c);
    if (!rc)
        rc = render_camera_auto(r, &o.camera, c->frag, c->nfrag, before, sel);
    o.cutaway = sel + 1; /* nothing hides the moving piece */
    for (int s = 0; s < 2 && !rc; s++) {
        rc = render_frame(r, s ? NULL : before, &o);
        if (!rc)
            rc = save_picture(r, dir, s ? "after" : "before", wrote, ctx);
    }
    render_close(r);
    /* The slice: a four-up frame whose axial pane is PIC x PIC, cut down to that pane. */
    const int bw = 3 * (PIC + 1), bh = 3 * PIC;
    int rect[4][4];
    render_four_up_panes(bw, bh, 0, rect);
    r = rc ? NULL : render_open(platform ? platform : "osmesa", bw, bh);
    if (!rc && !r)
        rc = FN_ENODEV;
    uint8_t *big = rc ? NULL : malloc((size_t)bw * bh * 3);
    if (!rc && !big)
        rc = fn_err_set(FN_ENOMEM, "out of memory for the slice");
    if (!rc)
        rc = render_set_scene(r, c->ct, c->frag, c->nfrag, c->seg.threshold, NULL);
    if (!rc) {
        o.layout = RENDER_LAYOUT_FOUR_UP;
        render_camera_standard(&o.camera, RENDER_ANTERIOR, c->frag, c->nfrag); /* the whole CT */
        pose_apply(&c->frag[sel].pose, c->frag[sel].centroid, o.slice_point);
        rc = render_frame(r, NULL, &o);
    }
    if (!rc)
        rc = render_read_rgb(r, big);
    if (!rc) {
        char path[4200];
        snprintf(path, sizeof path, "%s/slice.png", dir);
        const int *q = rect[RENDER_PANE_AXIAL];
        for (int y = 0; y < PIC; y++)
            memcpy(rgb + (size_t)y * PIC * 3, big + ((size_t)(q[1] + y) * bw + (size_t)q[0]) * 3, (size_t)PIC * 3);
        rc = picture_write_png(path, rgb, PIC, PIC);
        if (!rc && wrote)
            wrote(ctx, path);
    }
    free(big);
    free(rgb);
    render_close(r);
    return rc;
}

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* Appends g to *d (n values, *cap floats, grown as needed). 0 or FN_ENOMEM. */
static int push_gap(float **d, size_t *cap, long n, float g)
{
    if ((size_t)n == *cap) {
        size_t c2 = *cap ? *cap * 2 : 4096;
        float *grown = realloc(*d, c2 * sizeof *grown);
        if (!grown)
            return fn_err_set(FN_ENOMEM, "out of memory measuring gaps");
        *d = grown, *cap = c2;
    }
    (*d)[n] = g;
    return 0;
}

/* dist (one value per voxel of v) at world point w, trilinearly; NAN outside the grid. */
static double sample(const vol *v, const float *dist, const double w[3])
{
    double x[3], f[3], s = 0;
    int c0[3];
    vol_world_to_index(v, w, x);
    for (int a = 0; a < 3; a++) {
        if (!(x[a] >= 0 && x[a] <= v->dim[a] - 1))
            return NAN;
        c0[a] = (int)x[a] < v->dim[a] - 1 ? (int)x[a] : (v->dim[a] > 1 ? v->dim[a] - 2 : 0);
        f[a] = x[a] - c0[a];
    }
    for (int corner = 0; corner < 8; corner++) {
        double wt = 1;
        int c[3];
        for (int a = 0; a < 3; a++) {
            int hi = corner >> a & 1;
            c[a] = c0[a] + hi < v->dim[a] ? c0[a] + hi : v->dim[a] - 1;
            wt *= hi ? f[a] : 1 - f[a];
        }
        s += wt * dist[vol_idx(v, c[0], c[1], c[2])];
    }
    return s;
}

/* With ground truth, fragment fi's fracture surface is known: the faces its voxels share with
 * another fragment's when every fragment is at its truth (truth: that labelmap). Each such face's
 * centre is carried to fi's planned pose, and its gap is the distance from there to the nearest
 * other fragment in the planned labelmap v (dist, interpolated), less the half voxel from a
 * face to the voxel centres; 0 where it lies inside another. Into *d from index 0; returns how
 * many, or FN_ENOMEM. */
static long truth_gaps(const planning_case *c, int fi, const vol *truth, const vol *v, const float *dist,
                       float **d, size_t *cap)
{
    int id = c->frag[fi].id;
    pose move = pose_compose(c->frag[fi].pose, pose_inverse(c->truth[fi])); /* true -> planned */
    long n = 0;
    for (int k = 0; k < truth->dim[2]; k++)
        for (int j = 0; j < truth->dim[1]; j++)
            for (int i = 0; i < truth->dim[0]; i++) {
                if ((int)truth->data[vol_idx(truth, i, j, k)] != id)
                    continue;
                for (int f = 0; f < 6; f++) {
                    int a = f / 2, step = f % 2 ? 1 : -1, u[3] = {i, j, k};
                    u[a] += step;
                    if (u[a] < 0 || u[a] >= truth->dim[a])
                        continue;
                    int l = (int)truth->data[vol_idx(truth, u[0], u[1], u[2])];
                    if (!l || l == id)
                        continue;
                    double x[3] = {i, j, k}, w[3], p[3];
                    x[a] += 0.5 * step;
                    vol_index_to_world(truth, x, w);
                    pose_apply(&move, w, p);
                    double g = sample(v, dist, p) - 0.5 * v->spacing[a];
                    if (isnan(g))
                        continue;
                    if (push_gap(d, cap, n, (float)(g > 1e-6 ? g : 0))) /* rounding at the truth */
                        return FN_ENOMEM;
                    n++;
                }
            }
    return n;
}

/* Without ground truth, fragment id's gaps in the planned labelmap v: from every face of its
 * voxels that borders a voxel not its own, the empty voxels crossed along the face's normal before
 * another fragment's voxel, within REPORT_GAP_REACH_MM (faces that meet none do not count: the
 * bone's outer surfaces). A face across a cavity or the air beside the fracture line from the
 * other piece counts too. Into *d from index 0; returns how many, or FN_ENOMEM. */
static long face_gaps(const vol *v, int id, float **d, size_t *cap)
{
    int reach[3];
    for (int a = 0; a < 3; a++)
        reach[a] = (int)floor(REPORT_GAP_REACH_MM / v->spacing[a]) + 1;
    long n = 0;
    for (int k = 0; k < v->dim[2]; k++)
        for (int j = 0; j < v->dim[1]; j++)
            for (int i = 0; i < v->dim[0]; i++) {
                if ((int)v->data[vol_idx(v, i, j, k)] != id)
                    continue;
                for (int f = 0; f < 6; f++) {
                    int a = f / 2, step = f % 2 ? 1 : -1, p[3] = {i, j, k};
                    for (int t = 1; t <= reach[a]; t++) {
                        p[a] += step;
                        if (p[a] < 0 || p[a] >= v->dim[a])
                            break;
                        int l = (int)v->data[vol_idx(v, p[0], p[1], p[2])];
                        if (l == id)
                            break;
                        if (!l)
                            continue;
                        if (push_gap(d, cap, n, (float)((t - 1) * v->spacing[a])))
                            return FN_ENOMEM;
                        n++;
                        break;
                    }
                }
            }
    return n;
}

/* The labelmap with every fragment at its truth (export_planned_labels of those poses). */
static vol *truth_labels(const planning_case *c)
{
    planning_case t = *c;
    frag *f = malloc((size_t)(c->nfrag ? c->nfrag : 1) * sizeof *f);
    if (!f) {
        fn_err_set(FN_ENOMEM, "out of memory measuring gaps");
        return NULL;
    }
    for (int i = 0; i < c->nfrag; i++) {
        f[i] = c->frag[i]; /* the same voxels, at the truth */
        f[i].pose = c->truth[i];
    }
    t.frag = f;
    vol *v = export_planned_labels(&t);
    free(f);
    return v;
}

int report_gaps(const planning_case *c, const vol *planned, report_gap *gaps)
{
    size_t nv = vol_count(planned);
    float *d = NULL, *dist = NULL;
    uint8_t *others = NULL;
    vol *truth = NULL;
    size_t cap = 0;
    int rc = 0;
    if (c->has_truth && (!(dist = malloc(nv * sizeof *dist)) || !(others = malloc(nv)) || !(truth = truth_labels(c))))
        rc = fn_err_set(FN_ENOMEM, "out of memory measuring gaps");
    for (int fi = 0; fi < c->nfrag && !rc; fi++) {
        int id = c->frag[fi].id;
        long n = 0;
        if (truth) { /* the others' distance map in the planned poses */
            for (size_t i = 0; i < nv; i++)
                others[i] = planned->data[i] != 0 && (int)planned->data[i] != id;
            n = morph_distance_to(others, planned->dim, planned->spacing, dist);
            n = n ? n : truth_gaps(c, fi, truth, planned, dist, &d, &cap);
        } else
            n = face_gaps(planned, id, &d, &cap);
        if (n < 0) {
            rc = (int)n;
            break;
        }
        report_gap *g = &gaps[fi];
        g->faces = n;
        g->median_mm = g->p95_mm = g->max_mm = NAN;
        if (!n)
            continue;
        qsort(d, (size_t)n, sizeof *d, cmp_float);
        g->median_mm = d[(n - 1) / 2];
        g->p95_mm = d[(long)ceil(0.95 * (double)n) - 1];
        g->max_mm = d[n - 1];
    }
    vol_free(truth);
    free(d);
    free(dist);
    free(others);
    return rc;
}

#ifdef FRACNAV_HAVE_PLPLOT
typedef struct plot_ctx {
    const planning_case *c;
    json_t **hist;
    int *ids;
    int n;
    double lo, hi;    /* the metric axis (plot_range) */
    const double *fin; /* per fragment: the record's metric_end, where the dot goes */
} plot_ctx;

/* The metric history's runs: a rise starts a new one (each stage and attempt of the fit starts
 * over from its own start, while within one the best so far only falls). */
static int next_run(json_t *h, size_t from, size_t *end)
{
    size_t n = json_array_size(h), e = from + 1;
    while (e < n && json_number_value(json_array_get(h, e)) <= json_number_value(json_array_get(h, e - 1)))
        e++;
    *end = e;
    return from < n;
}

static int draw_plot(durable_file *df, void *vctx)
{
    const char *tmp = df->tmp;
    const plot_ctx *p = vctx;
    double lo = p->lo, hi = p->hi;
    size_t longest = 1;
    for (int k = 0; k < p->n; k++) {
        size_t n = json_array_size(p->hist[k]);
        longest = n > longest ? n : longest;
    }
    /* a margin PLplot can tell from the values: 0.05 at 1e20 is lost and plenv aborts */
    double pad = 0.05 * fmax(hi > lo ? hi - lo : 1.0, 1e-3 * fmax(fabs(lo), fabs(hi)));
    plsdev("pngcairo");
    plsfnam(tmp);
    plspage(0, 0, 800, 480, 0, 0);
    plscolbg(255, 255, 255);
    plscol0(1, 0, 0, 0);
    plinit();
    pladv(0);
    plcol0(1);
    /* The plot on the left; each fragment's label in the margin on the right, off the curves. */
    plvpor(0.10, 0.68, 0.12, 0.90);
    plwind(0, (double)longest * 1.03, lo - pad, hi + pad);
    plbox("bcnst", 0, 0, "bcnstv", 0, 0);
    pllab("iteration", "metric (lower is better)", "the fit's convergence: one line per stage or attempt");
    for (int k = 0; k < p->n; k++) {
        json_t *h = p->hist[k];
        size_t n = json_array_size(h), from = 0, end;
        double *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y);
        if (!x || !y) {
            free(x);
            free(y);
            plend();
            return fn_err_set(FN_ENOMEM, "out of memory for the plot");
        }
        for (size_t i = 0; i < n; i++) {
            x[i] = (double)i;
            y[i] = json_number_value(json_array_get(h, i));
        }
        const frag *f = &p->c->frag[case_find(p->c, p->ids[k])];
        plscol0(2 + k % 13, f->rgb[0], f->rgb[1], f->rgb[2]);
        plcol0(2 + k % 13);
        plwidth(2);
        int runs = 0;
        for (; next_run(h, from, &end); from = end, runs++) {
            pllsty(1 + runs % 8);
            plline((PLINT)(end - from), x + from, y + from);
        }
        pllsty(1);
        plssym(0, 2.5);
        double fin = p->fin[k];
        plpoin(1, &x[n - 1], &fin, 17); /* the final metric: the kept pose's, not the last run's */
        char label[160];
        plmtex("rv", 1.0, 1.0 - 0.12 * k - 0.04, 0, f->name);
        snprintf(label, sizeof label, "%d run%s, final %.4f", runs, runs == 1 ? "" : "s", fin);
        plmtex("rv", 1.0, 1.0 - 0.12 * k - 0.09, 0, label);
        free(x);
        free(y);
    }
    plcol0(1);
    plmtex("rv", 1.0, 0.19, 0, "dot: the final metric, after");
    plmtex("rv", 1.0, 0.14, 0, "the polish (nearest count);");
    plmtex("rv", 1.0, 0.09, 0, "a dashed line: a later run;");
    plmtex("rv", 1.0, 0.04, 0, "runs above the start: cut");
    plend();
    struct stat st;
    return stat(tmp, &st) == 0 && st.st_size > 0 ? 0 : fn_err_set(FN_EIO, "%s: PLplot wrote nothing", tmp);
}
#endif

/* 1 when every value of a history is a number PLplot can place (|v| <= 1e30). */
static int plottable(json_t *h)
{
    size_t i;
    json_t *v;
    json_array_foreach(h, i, v) {
        if (!json_is_number(v) || !(fabs(json_number_value(v)) <= 1e30))
            return 0;
    }
    return 1;
}

#ifdef FRACNAV_HAVE_PLPLOT
/* The metric axis: from the lowest value to the highest first value or final metric. A later run
 * that starts above them (a global stage's candidate far from the answer, +0.3 where the fit runs
 * from -0.7 to -0.8) is cut at the top instead of squeezing the fit into a flat line. */
static void plot_range(json_t **hist, const double *fin, int n, double *lo, double *hi)
{
    *lo = INFINITY;
    *hi = -INFINITY;
    for (int k = 0; k < n; k++) {
        size_t i;
        json_t *v;
        json_array_foreach(hist[k], i, v)
            *lo = fmin(*lo, json_number_value(v));
        *lo = fmin(*lo, fin[k]);
        *hi = fmax(*hi, fmax(json_number_value(json_array_get(hist[k], 0)), fin[k]));
    }
}
#endif

/* The convergence plot; 1 when drawn, 0 when there is nothing to plot (why in *why). fin gets
 * each plotted fragment's final metric (the record's metric_end; the last value without one), ids
 * their ids, *nplot how many. */
static int plot(const planning_case *c, const char *dir, const char **why, report_wrote_fn wrote, void *ctx,
                int *ids, double *fin, int *nplot)
{
    json_t *hist[64];
    int n = 0;
    *nplot = 0;
    for (int i = 0; i < c->nfrag && n < 64; i++) {
        json_t *e = record_of(c, c->frag[i].id), *h = e ? json_object_get(e, "history") : NULL;
        if (json_array_size(h) > 0 && !plottable(h)) {
            *why = "the case's reduction record holds a history value that is not a number within 1e30";
            return 0;
        }
        if (json_array_size(h) > 0) {
            json_t *m1 = json_object_get(e, "metric_end");
            double last = json_number_value(json_array_get(h, json_array_size(h) - 1));
            fin[n] = json_is_number(m1) && fabs(json_number_value(m1)) <= 1e30 ? json_number_value(m1) : last;
            hist[n] = h;
            ids[n++] = c->frag[i].id;
        }
    }
    if (!n) {
        *why = c->extra && json_object_get(c->extra, "reduction")
                   ? "the case's reduction record holds no convergence history"
                   : "the case has not been reduced (fracnav reduce)";
        return 0;
    }
#ifdef FRACNAV_HAVE_PLPLOT
    char path[4200];
    snprintf(path, sizeof path, "%s/convergence.png", dir);
    plot_ctx p = {c, hist, ids, n, 0, 0, fin};
    plot_range(hist, fin, n, &p.lo, &p.hi);
    int rc = durable_replace(path, draw_plot, &p);
    if (rc)
        return rc;
    if (wrote)
        wrote(ctx, path);
    *nplot = n;
    return 1;
#else
    (void)dir, (void)wrote, (void)ctx;
    *why = "this fracnav was built without PLplot (libplplot-dev)";
    return 0;
#endif
}

static void html_text(FILE *fp, const char *s)
{
    for (; *s; s++) {
        if (*s == '<')
            fputs("&lt;", fp);
        else if (*s == '>')
            fputs("&gt;", fp);
        else if (*s == '&')
            fputs("&amp;", fp);
        else
            fputc(*s, fp);
    }
}

typedef struct page_ctx {
    const planning_case *c;
    const pose *before;
    int reduced, plotted, rendered;
    const char *why;
    char no_render[512]; /* why there are no renders (rendered = 0) */
    const double *overlap_ml, *contact_mm2;
    const report_gap *gaps;
    int plot_ids[64], nplot; /* the plotted fragments and their final metrics */
    double plot_fin[64];
} page_ctx;

static void cell(FILE *fp, double v, const char *fmt)
{
    if (isfinite(v))
        fprintf(fp, fmt, v);
    else
        fputs("<td>&ndash;</td>", fp);
}

/* The header: the case, the CT, the date, fracnav's version, the fit's method and tolerance. */
static void header(FILE *fp, const planning_case *c)
{
    const char *name = strrchr(c->dir, '/');
    name = name && name[1] ? name + 1 : c->dir;
    fputs("<h1>Fracture reduction plan: ", fp);
    html_text(fp, name);
    fputs("</h1>\n<table class=\"head\"><tr><th>case</th><td><code>", fp);
    html_text(fp, c->dir);
    fputs("</code></td></tr>\n<tr><th>CT</th><td><code>", fp);
    html_text(fp, c->source);
    fputs("</code>", fp);
    if (c->ct)
        fprintf(fp, ", %d x %d x %d voxels of %.3f x %.3f x %.3f mm", c->ct->dim[0], c->ct->dim[1], c->ct->dim[2],
                c->ct->spacing[0], c->ct->spacing[1], c->ct->spacing[2]);
    time_t now = time(NULL);
    char date[32];
    strftime(date, sizeof date, "%Y-%m-%d %H:%M UTC", gmtime(&now));
    json_t *red = c->extra ? json_object_get(c->extra, "reduction") : NULL;
    const char *method = json_string_value(json_object_get(red, "method"));
    json_t *tol = json_object_get(red, "tolerance_mm");
    fprintf(fp, "</td></tr>\n<tr><th>date</th><td>%s</td></tr>\n<tr><th>fracnav</th><td>%s</td></tr>\n"
                "<tr><th>method</th><td>",
            date, FRACNAV_VERSION);
    if (method) {
        html_text(fp, method);
        if (json_is_number(tol))
            fprintf(fp, ", collision tolerance %.2f mm", json_number_value(tol));
    } else
        fputs("not reduced (fracnav reduce)", fp);
    fprintf(fp, "</td></tr>\n<tr><th>fragments</th><td>%d%s; coordinates LPS mm</td></tr>\n</table>\n", c->nfrag,
            c->has_truth ? ", with the synthetic fracture's ground truth" : "");
}

/* One fragment's row: its planned move and turn in anatomical terms, the fit's metric, the gap
 * and overlap, the errors against the truth. */
static void fragment_row(FILE *fp, const page_ctx *p, int i)
{
    const planning_case *c = p->c;
    const frag *f = &c->frag[i];
    double a[3], b[3], d[3];
    pose_apply(&p->before[i], f->centroid, a);
    pose_apply(&f->pose, f->centroid, b);
    for (int k = 0; k < 3; k++)
        d[k] = b[k] - a[k];
    pose rel = pose_compose(f->pose, pose_inverse(p->before[i]));
    char move[128], turn[128];
    navview_move_text(d, move, sizeof move);
    navview_turn_text(&rel, turn, sizeof turn);
    fprintf(fp, "<tr><td><span style=\"color:#%02x%02x%02x\">&#9632;</span> %d ", f->rgb[0], f->rgb[1], f->rgb[2],
            f->id);
    html_text(fp, f->name);
    fprintf(fp, "%s</td><td>%s</td><td>%s</td>", i == c->fixed ? " (fixed)" : "", move, turn);
    json_t *e = record_of(c, f->id);
    json_t *m0 = json_object_get(e, "metric_start"), *m1 = json_object_get(e, "metric_end");
    if (json_is_number(m0) && json_is_number(m1))
        fprintf(fp, "<td>%.4f &rarr; %.4f</td>", json_number_value(m0), json_number_value(m1));
    else
        fputs("<td>&ndash;</td>", fp);
    const report_gap *g = &p->gaps[i];
    cell(fp, g->median_mm, "<td>%.2f</td>");
    cell(fp, g->p95_mm, "<td>%.2f</td>");
    cell(fp, g->max_mm, "<td>%.2f</td>");
    cell(fp, p->overlap_ml[i], "<td>%.3f</td>");
    cell(fp, p->contact_mm2[i], "<td>%.0f</td>");
    if (c->has_truth && c->fixed >= 0) {
        double rot = NAN, tr = NAN, tre = NAN;
        if (i != c->fixed)
            reduce_truth_errors(c, c->fixed, i, &rot, &tr, &tre);
        cell(fp, rot, "<td>%.2f</td>");
        cell(fp, tr, "<td>%.2f</td>");
        cell(fp, tre, "<td>%.2f</td>");
    }
    fputs("</tr>\n", fp);
}

static int write_page(durable_file *df, void *vctx)
{
    const page_ctx *p = vctx;
    const planning_case *c = p->c;
    FILE *fp = durable_stream(df);
    if (!fp)
        return FN_EIO;
    fputs("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n<title>fracnav report</title>\n"
          "<style>body{font-family:sans-serif;margin:1.5em;max-width:1000px}img{border:1px solid #ccc;"
          "margin:4px;max-width:100%;height:auto}table{border-collapse:collapse;margin:0.5em 0}"
          "td,th{border:1px solid #bbb;padding:3px 6px;text-align:right;font-size:90%}th{background:#eee}"
          "td:first-child,.head td{text-align:left}.head th{text-align:left}"
          ".pics{display:flex;flex-wrap:wrap}.pics figure{margin:0 8px 8px 0;width:320px}"
          ".pics img{width:320px}figcaption{font-size:85%}"
          "@media print{body{margin:0}h2{page-break-after:avoid}}</style>\n</head><body>\n",
          fp);
    header(fp, c);
    fprintf(fp, "<h2>Before and after</h2>\n<p>Before: %s. After: the planned poses. Seen from the side "
                "where the moving fragment shows best (the auto view).</p>\n",
            p->reduced ? "the poses before the last automatic reduction" : "as segmented (home positions)");
    if (!p->rendered) {
        fputs("<p>No renders: ", fp);
        html_text(fp, p->no_render);
        fputs("</p>\n", fp);
    } else
        fprintf(fp, "<div class=\"pics\"><figure><img src=\"before.png\" width=\"%d\" height=\"%d\" alt=\"before\">"
                    "<figcaption>before</figcaption></figure><figure><img src=\"after.png\" width=\"%d\" "
                    "height=\"%d\" alt=\"after\"><figcaption>after (planned)</figcaption></figure><figure>"
                    "<img src=\"slice.png\" width=\"%d\" height=\"%d\" alt=\"axial slice\"><figcaption>axial CT "
                    "slice through the moving fragment, planned outlines</figcaption></figure></div>\n",
                PIC, PIC, PIC, PIC, PIC, PIC);
    fputs("<h2>Fragments</h2>\n<table><tr><th rowspan=\"2\">fragment</th><th rowspan=\"2\">planned move</th>"
          "<th rowspan=\"2\">planned turn</th><th rowspan=\"2\">fit metric</th><th colspan=\"3\">gap (mm)</th>"
          "<th rowspan=\"2\">overlap (ml)</th><th rowspan=\"2\">contact (mm&sup2;)</th>",
          fp);
    int truth = c->has_truth && c->fixed >= 0;
    if (truth)
        fputs("<th colspan=\"3\">error against the truth</th>", fp);
    fputs("</tr>\n<tr><th>median</th><th>95%</th><th>max</th>", fp);
    if (truth)
        fputs("<th>rotation (deg)</th><th>translation (mm)</th><th>TRE (mm)</th>", fp);
    fputs("</tr>\n", fp);
    for (int i = 0; i < c->nfrag; i++)
        fragment_row(fp, p, i);
    fprintf(fp, "</table>\n<p>Planned move and turn: from before to after, of the fragment's centroid, in mm "
                "right/left, anterior/posterior and inferior/superior, and degrees about those axes (right-handed "
                "about left, posterior, superior). Fit metric: the reduction's voxel metric at its start and end "
                "(lower is better). Gap: across the fracture surface in the planned poses; with ground truth from "
                "each face the fragment shares with another at the truth, to the nearest other fragment; else "
                "from each face of the fragment's voxels along its normal to another fragment's voxel (faces "
                "that meet none within %.0f mm do not count). Overlap: the volume it shares with another fragment. Contact: the faces "
                "its voxels share with another fragment's.",
            REPORT_GAP_REACH_MM);
    if (c->has_truth)
        fputs(" Errors: the planned pose relative to the fixed fragment against the synthetic fracture's "
              "ground truth (TRE over the fracture surface).",
              fp);
    fputs("</p>\n<h2>Convergence</h2>\n", fp);
    if (p->plotted) {
        fputs("<img src=\"convergence.png\" width=\"800\" height=\"480\" alt=\"convergence plot\">\n", fp);
        fputs("<p class=\"plot-final\">Final metric (the dot):", fp);
        for (int k = 0; k < p->nplot; k++)
            fprintf(fp, "%s fragment %d <span data-fragment=\"%d\">%.4f</span>", k ? ";" : "", p->plot_ids[k],
                    p->plot_ids[k], p->plot_fin[k]);
        fputs(". A run that starts above the fit's start is cut at the top.</p>\n", fp);
    } else {
        fputs("<p>No plot: ", fp);
        html_text(fp, p->why);
        fputs(".</p>\n", fp);
    }
    /* For tests: how many pictures loaded and whether anything is wider than the window, on the
     * body's data-images and data-overflow (not shown). */
    fputs("<script>\nwindow.addEventListener('load', function () {\n"
          "  var im = document.images, ok = 0;\n"
          "  for (var i = 0; i < im.length; i++) if (im[i].complete && im[i].naturalWidth > 0) ok++;\n"
          "  document.body.setAttribute('data-images', ok + ' of ' + im.length + ' loaded');\n"
          "  var wide = document.documentElement.scrollWidth > window.innerWidth;\n"
          "  document.body.setAttribute('data-overflow', wide ? 'yes' : 'no');\n"
          "});\n</script>\n</body></html>\n",
          fp);
    return fclose(fp) == 0 ? 0 : fn_err_set(FN_EIO, "%s: write failed", df->tmp);
}

int report_write(const planning_case *c, const vol *planned, const double *overlap_ml, const char *dir,
                 const char *platform, report_wrote_fn wrote, void *ctx)
{
    if (mkdir(dir, 0777) != 0 && errno != EEXIST)
        return fn_err_set(FN_EIO, "%s: cannot create the report folder: %s", dir, strerror(errno));
    pose *before = malloc((size_t)(c->nfrag ? c->nfrag : 1) * sizeof *before);
    double *contact = malloc((size_t)(c->nfrag ? c->nfrag : 1) * 2 * sizeof *contact);
    if (!before || !contact) {
        free(before);
        free(contact);
        return fn_err_set(FN_ENOMEM, "out of memory for the report");
    }
    report_gap *gaps = malloc((size_t)(c->nfrag ? c->nfrag : 1) * sizeof *gaps);
    page_ctx p = {c, before, before_poses(c, before), 0, 1, NULL, "", overlap_ml, contact, gaps, {0}, 0, {0}};
    int rc = gaps ? export_contacts(c, planned, 2.0, contact, contact + c->nfrag)
                  : fn_err_set(FN_ENOMEM, "out of memory for the report");
    if (!rc)
        rc = report_gaps(c, planned, gaps);
    if (!rc && (rc = render_pictures(c, before, dir, platform, wrote, ctx)) == FN_ENODEV) {
        /* No GL 4.5 here: the page goes without its renders and says why. */
        snprintf(p.no_render, sizeof p.no_render, "%s", fn_err_msg());
        fprintf(stderr, "fracnav export: the report has no renders: %s\n", p.no_render);
        p.rendered = 0;
        rc = 0;
    }
    if (!rc) {
        int r = plot(c, dir, &p.why, wrote, ctx, p.plot_ids, p.plot_fin, &p.nplot);
        rc = r < 0 ? r : 0;
        p.plotted = r > 0;
    }
    if (!rc) {
        char path[4200];
        snprintf(path, sizeof path, "%s/index.html", dir);
        rc = durable_replace(path, write_page, &p);
        if (!rc && wrote)
            wrote(ctx, path);
    }
    free(before);
    free(contact);
    free(gaps);
    return rc;
}
