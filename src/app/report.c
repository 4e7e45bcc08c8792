/* report: the HTML page of a case's plan (see report.h). */
#include "report.h"

#include "durable.h"
#include "err.h"
#include "export.h"
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
    static const render_view views[2] = {RENDER_ANTERIOR, RENDER_RIGHT};
    static const char *names[2] = {"anterior", "right"};
    for (int v = 0; v < 2 && !rc; v++)
        for (int s = 0; s < 2 && !rc; s++) {
            render_options o;
            render_options_default(&o, c->frag, c->nfrag);
            render_camera_standard(&o.camera, views[v], c->frag, c->nfrag);
            char path[4200];
            snprintf(path, sizeof path, "%s/%s-%s.png", dir, s ? "after" : "before", names[v]);
            rc = render_frame(r, s ? NULL : before, &o);
            if (!rc)
                rc = render_read_rgb(r, rgb);
            if (!rc)
                rc = picture_write_png(path, rgb, PIC, PIC);
            if (!rc && wrote)
                wrote(ctx, path);
        }
    free(rgb);
    render_close(r);
    return rc;
}

#ifdef FRACNAV_HAVE_PLPLOT
typedef struct plot_ctx {
    const planning_case *c;
    json_t **hist;
    int *ids;
    int n;
} plot_ctx;

static int draw_plot(durable_file *df, void *vctx)
{
    const char *tmp = df->tmp;
    const plot_ctx *p = vctx;
    double lo = INFINITY, hi = -INFINITY;
    size_t longest = 1;
    for (int k = 0; k < p->n; k++) {
        size_t n = json_array_size(p->hist[k]);
        longest = n > longest ? n : longest;
        for (size_t i = 0; i < n; i++) {
            double v = json_number_value(json_array_get(p->hist[k], i));
            lo = v < lo ? v : lo;
            hi = v > hi ? v : hi;
        }
    }
    /* a margin PLplot can tell from the values: 0.05 at 1e20 is lost and plenv aborts */
    double pad = 0.05 * fmax(hi > lo ? hi - lo : 1.0, 1e-3 * fmax(fabs(lo), fabs(hi)));
    plsdev("pngcairo");
    plsfnam(tmp);
    plspage(0, 0, 800, 480, 0, 0);
    plscolbg(255, 255, 255);
    plscol0(1, 0, 0, 0);
    plinit();
    plcol0(1);
    plenv(0, (double)(longest > 1 ? longest - 1 : 1), lo - pad, hi + pad, 0, 0);
    pllab("iteration", "metric (lower is better)", "the optimizer's convergence, per fragment");
    for (int k = 0; k < p->n; k++) {
        size_t n = json_array_size(p->hist[k]);
        double *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y);
        if (!x || !y) {
            free(x);
            free(y);
            plend();
            return fn_err_set(FN_ENOMEM, "out of memory for the plot");
        }
        for (size_t i = 0; i < n; i++) {
            x[i] = (double)i;
            y[i] = json_number_value(json_array_get(p->hist[k], i));
        }
        const frag *f = &p->c->frag[case_find(p->c, p->ids[k])];
        plscol0(2 + k % 13, f->rgb[0], f->rgb[1], f->rgb[2]);
        plcol0(2 + k % 13);
        plwidth(2);
        plline((PLINT)n, x, y);
        plptex((double)(n - 1), y[n - 1], 1, 0, 1.05, f->name);
        free(x);
        free(y);
    }
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

/* The convergence plot; 1 when drawn, 0 when there is nothing to plot (why in *why). */
static int plot(const planning_case *c, const char *dir, const char **why, report_wrote_fn wrote, void *ctx)
{
    json_t *hist[64];
    int ids[64], n = 0;
    for (int i = 0; i < c->nfrag && n < 64; i++) {
        json_t *e = record_of(c, c->frag[i].id), *h = e ? json_object_get(e, "history") : NULL;
        if (json_array_size(h) > 0 && !plottable(h)) {
            *why = "the case's reduction record holds a history value that is not a number within 1e30";
            return 0;
        }
        if (json_array_size(h) > 0) {
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
    plot_ctx p = {c, hist, ids, n};
    int rc = durable_replace(path, draw_plot, &p);
    if (rc)
        return rc;
    if (wrote)
        wrote(ctx, path);
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
    const double *overlap_ml, *contact_mm2, *gap_ml;
} page_ctx;

static void cell(FILE *fp, double v, const char *fmt)
{
    if (isfinite(v))
        fprintf(fp, fmt, v);
    else
        fputs("<td>&ndash;</td>", fp);
}

static int write_page(durable_file *df, void *vctx)
{
    const page_ctx *p = vctx;
    const planning_case *c = p->c;
    FILE *fp = durable_stream(df);
    if (!fp)
        return FN_EIO;
    fputs("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n<title>fracnav report</title>\n"
          "<style>body{font-family:sans-serif;margin:2em;max-width:1100px}img{border:1px solid #ccc;"
          "margin:4px}table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:3px 8px;"
          "text-align:right}th{background:#eee}td:first-child{text-align:left}</style>\n</head><body>\n"
          "<h1>fracnav: reduction report</h1>\n<p>Case <code>",
          fp);
    html_text(fp, c->dir);
    fputs("</code>, source <code>", fp);
    html_text(fp, c->source);
    fprintf(fp, "</code>: %d fragments; coordinates LPS mm.</p>\n", c->nfrag);
    fprintf(fp, "<h2>Before and after</h2>\n<p>Before: %s. After: the planned poses.</p>\n",
            p->reduced ? "the poses before the last automatic reduction" : "as segmented (home positions)");
    static const char *views[2] = {"anterior", "right"};
    if (!p->rendered) {
        fputs("<p>No renders: ", fp);
        html_text(fp, p->no_render);
        fputs("</p>\n", fp);
    }
    for (int v = 0; v < 2 && p->rendered; v++)
        fprintf(fp, "<div><img src=\"before-%s.png\" width=\"%d\" height=\"%d\" alt=\"before, %s\">"
                    "<img src=\"after-%s.png\" width=\"%d\" height=\"%d\" alt=\"after, %s\"></div>\n",
                views[v], PIC, PIC, views[v], views[v], PIC, PIC, views[v]);
    fputs("<h2>Convergence</h2>\n", fp);
    if (p->plotted)
        fputs("<img src=\"convergence.png\" width=\"800\" height=\"480\" alt=\"convergence plot\">\n", fp);
    else {
        fputs("<p>No plot: ", fp);
        html_text(fp, p->why);
        fputs(".</p>\n", fp);
    }
    fputs("<h2>Fragments</h2>\n<table><tr><th>fragment</th><th>move (mm)</th><th>turn (deg)</th>"
          "<th>contact (mm&sup2;)</th><th>gap (ml)</th><th>overlap (ml)</th>", fp);
    if (c->has_truth && c->fixed >= 0)
        fputs("<th>rotation error (deg)</th><th>translation error (mm)</th><th>TRE (mm)</th>", fp);
    fputs("</tr>\n", fp);
    for (int i = 0; i < c->nfrag; i++) {
        const frag *f = &c->frag[i];
        double a[3], b[3];
        pose_apply(&p->before[i], f->centroid, a);
        pose_apply(&f->pose, f->centroid, b);
        double move = sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
        double turn = pose_angle_between(p->before[i], f->pose) * 180 / M_PI;
        fprintf(fp, "<tr><td><span style=\"color:#%02x%02x%02x\">&#9632;</span> %d ", f->rgb[0], f->rgb[1],
                f->rgb[2], f->id);
        html_text(fp, f->name);
        fprintf(fp, "%s</td>", i == c->fixed ? " (fixed)" : "");
        cell(fp, move, "<td>%.2f</td>");
        cell(fp, turn, "<td>%.2f</td>");
        cell(fp, p->contact_mm2[i], "<td>%.1f</td>");
        cell(fp, p->gap_ml[i], "<td>%.3f</td>");
        cell(fp, p->overlap_ml[i], "<td>%.3f</td>");
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
    fputs("</table>\n<p>Move and turn: each fragment's centroid displacement and rotation from before to "
          "after. Contact: the faces its voxels share with another fragment's on the source grid, planned "
          "configuration. Gap: empty voxels within 2 mm of it and of another fragment. Overlap: voxels "
          "it shares with another fragment.",
          fp);
    if (c->has_truth)
        fputs(" Errors: the planned pose relative to the fixed fragment against the synthetic fracture's "
              "ground truth (TRE over the fracture surface).",
              fp);
    fputs("</p>\n<p id=\"images\">images: not checked (needs scripts)</p>\n"
          "<script>\nwindow.addEventListener('load', function () {\n"
          "  var im = document.images, ok = 0;\n"
          "  for (var i = 0; i < im.length; i++) if (im[i].complete && im[i].naturalWidth > 0) ok++;\n"
          "  document.getElementById('images').textContent = 'images: ' + ok + ' of ' + im.length + ' loaded';\n"
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
    page_ctx p = {c, before, before_poses(c, before), 0, 1, NULL, "", overlap_ml, contact, contact + c->nfrag};
    int rc = export_contacts(c, planned, 2.0, contact, contact + c->nfrag);
    if (!rc && (rc = render_pictures(c, before, dir, platform, wrote, ctx)) == FN_ENODEV) {
        /* No GL 4.5 here: the page goes without its renders and says why. */
        snprintf(p.no_render, sizeof p.no_render, "%s", fn_err_msg());
        fprintf(stderr, "fracnav export: the report has no renders: %s\n", p.no_render);
        p.rendered = 0;
        rc = 0;
    }
    if (!rc) {
        int r = plot(c, dir, &p.why, wrote, ctx);
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
    return rc;
}
