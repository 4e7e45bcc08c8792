/* fracnav export (issue 16): every export read back by an independent reader, not our writers'
 * code: tests/export_read.py (its own ITK transform, NRRD and STL parsers, nibabel for NIfTI),
 * admesh for the STL models, and headless Chromium for the report's page. On a small synthetic
 * fracture (a tube broken in two by `fracnav fracture`, reduced by `fracnav reduce`). Outside CI a
 * missing reader skips its test and says so; under CI (.ci/setup installs them) it fails. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "err.h"
#include "durable.h"
#include "export.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static char *dir;
static char frac[4200], out[4200], reader[4200];
static const char *python = "/usr/bin/python3"; /* Debian's, with python3-numpy and python3-nibabel */

static int under_ci(void)
{
    return getenv("CI") && *getenv("CI");
}

/* A reader that is missing: a failure under CI, a visible skip elsewhere. */
static int missing(const char *what, const char *package)
{
    if (under_ci())
        fail_msg("%s is missing (Debian package %s; .ci/setup installs it)", what, package);
    fprintf(stderr, "[  SKIP    ] %s is missing (Debian package %s; run .ci/setup): skipped\n", what, package);
    skip();
    return 1;
}

static int have_python(const char *modules)
{
    char cmd[512];
    snprintf(cmd, sizeof cmd, "%s -c 'import %s' 2>/dev/null", python, modules);
    return access(python, X_OK) == 0 && system(cmd) == 0;
}

/* Runs a shell command, its stdout parsed as one JSON object (NULL: failed). */
static json_t *run_json(const char *fmt, ...)
{
    char cmd[16384];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(cmd, sizeof cmd, fmt, ap);
    va_end(ap);
    FILE *p = popen(cmd, "r");
    assert_non_null(p);
    size_t cap = 1 << 16, n = 0, got;
    char *buf = malloc(cap);
    while ((got = fread(buf + n, 1, cap - n - 1, p)) > 0) {
        n += got;
        if (cap - n < 2)
            buf = realloc(buf, cap *= 2);
    }
    buf[n] = 0;
    int st = pclose(p);
    json_error_t e;
    json_t *j = st == 0 ? json_loads(buf, 0, &e) : NULL;
    if (!j)
        fprintf(stderr, "%s\n-> exit %d, output:\n%s\n", cmd, st, buf);
    free(buf);
    return j;
}

static json_t *read_back(const char *kind, const char *path, const char *more)
{
    return run_json("'%s' '%s' %s '%s' %s", python, reader, kind, path, more ? more : "");
}

static int tube_wall(int i, int j, int k)
{
    double r = hypot(i - 19.5, j - 19.5);
    return k > 2 && k < 45 && r > 8 && r < 15;
}

static int setup(void **st)
{
    (void)st;
    dir = tu_tmpdir("export");
    char tube[4200];
    snprintf(tube, sizeof tube, "%s/tube.nii.gz", dir);
    snprintf(frac, sizeof frac, "%s/frac", dir);
    snprintf(out, sizeof out, "%s/out", dir);
    snprintf(reader, sizeof reader, "%s/tests/export_read.py", tu_src());
    vol *v = vol_new(40, 40, 48);
    assert_non_null(v);
    for (int k = 0; k < 48; k++)
        for (int j = 0; j < 40; j++)
            for (int i = 0; i < 40; i++)
                v->data[vol_idx(v, i, j, k)] = tube_wall(i, j, k) ? 1200.f : -1000.f;
    assert_int_equal(volio_write(v, tube, VOL_I16), 0);
    vol_free(v);
    char *o = NULL;
    int rc = tu_run_cli(&o, "fracture '%s' -o '%s' --seed 1", tube, frac);
    if (rc == 0) {
        free(o);
        rc = tu_run_cli(&o, "reduce '%s'", frac);
        /* Each piece's own move is said (the issue: "metric -0.722651 -> -0.722651" alone). */
        if (rc == 0 && !(strstr(o, "; moved ") && strstr(o, " mm (") && strstr(o, " deg;")))
            rc = -1;
    }
    if (rc != 0)
        fprintf(stderr, "%s\n", o);
    free(o);
    assert_int_equal(rc, 0);
    return 0;
}

static int teardown(void **st)
{
    (void)st;
    tu_rmtree(dir);
    free(dir);
    return 0;
}

static long file_size(const char *path)
{
    struct stat s;
    return stat(path, &s) == 0 ? (long)s.st_size : -1;
}

/* --all --json: the files named, with their sizes, and no temporary file left. */
static void test_all_json(void **st)
{
    (void)st;
    json_t *j = run_json("'%s' export '%s' --all '%s' --json 2>/dev/null", tu_fracnav(), frac, out);
    assert_non_null(j);
    assert_string_equal(json_string_value(json_object_get(j, "command")), "export");
    json_t *files = json_object_get(j, "files"), *f;
    size_t i;
    long total = 0;
    assert_int_equal(json_array_size(files), 2 + 2 + 1 + 1 + 5); /* tfm, stl, seg, nii, report */
    json_array_foreach(files, i, f) {
        const char *path = json_string_value(json_object_get(f, "path"));
        long size = (long)json_integer_value(json_object_get(f, "size_bytes"));
        assert_true(size > 0);
        assert_int_equal(file_size(path), size);
        total += size;
    }
    assert_int_equal(json_integer_value(json_object_get(j, "written_total_bytes")), total);
    assert_int_equal(json_integer_value(json_object_get(j, "files_written")), (json_int_t)json_array_size(files));
    json_decref(j);
    char *ls = NULL;
    assert_int_equal(tu_run_cli(&ls, "--version && find '%s' -name '.fracnav-tmp*'", out), 0);
    assert_null(strstr(ls, ".fracnav-tmp"));
    free(ls);
}

/* The ITK transform, parsed and applied by the reader, maps each fragment's planned points back
 * to home, as the inverse of the case's pose does (ITK's resampling direction). */
static void test_tfm_maps_as_the_pose(void **st)
{
    (void)st;
    if (access(python, X_OK) != 0 && missing("python3", "python3"))
        return;
    planning_case *c = case_load(frac);
    assert_non_null(c);
    int moved = 0;
    for (int i = 0; i < c->nfrag; i++) {
        const frag *f = &c->frag[i];
        moved += pose_distance(f->pose, POSE_IDENTITY) > 0.1;
        double home[4][3], planned[4][3];
        char args[2048] = "", path[4300];
        for (int p = 0; p < 4; p++) {
            for (int a = 0; a < 3; a++)
                home[p][a] = f->centroid[a] + (p == a + 1 ? 15.0 : 0.0);
            pose_apply(&f->pose, home[p], planned[p]);
            size_t n = strlen(args);
            snprintf(args + n, sizeof args - n, " %.17g,%.17g,%.17g", planned[p][0], planned[p][1], planned[p][2]);
        }
        snprintf(path, sizeof path, "%s/transforms/fragment-%d.tfm", out, f->id);
        json_t *j = read_back("tfm", path, args);
        assert_non_null(j);
        assert_int_equal(json_integer_value(json_object_get(j, "parameters")), 12);
        assert_int_equal(json_integer_value(json_object_get(j, "fixed_parameters")), 3);
        for (int p = 0; p < 4; p++)
            for (int a = 0; a < 3; a++) {
                double got = json_number_value(json_array_get(json_array_get(json_object_get(j, "points"), (size_t)p), (size_t)a));
                assert_true(fabs(got - home[p][a]) < 1e-6);
            }
        json_decref(j);
    }
    assert_true(moved >= 1); /* the reduction moved a fragment: the check is not the identity's */
    case_free(c);
}

/* NIfTI (nibabel) and .seg.nrrd (the reader's NRRD parser): the planned labelmap on the source
 * grid, the same voxels in both, Slicer's segment fields, each fragment about its volume. */
static void test_nifti_and_seg_nrrd(void **st)
{
    (void)st;
    if (!have_python("numpy, nibabel") && missing("python3 with numpy and nibabel", "python3-numpy python3-nibabel"))
        return;
    planning_case *c = case_load(frac);
    assert_non_null(c);
    char nii[4300], seg[4300];
    snprintf(nii, sizeof nii, "%s/planned.nii.gz", out);
    snprintf(seg, sizeof seg, "%s/planned.seg.nrrd", out);
    json_t *n = read_back("nifti", nii, NULL);
    assert_non_null(n);
    for (int a = 0; a < 3; a++)
        assert_int_equal(json_integer_value(json_array_get(json_object_get(n, "shape"), (size_t)a)), c->labels->dim[a]);
    /* RAS in the file: LPS with x and y negated. */
    json_t *aff = json_object_get(n, "affine");
    for (int r = 0; r < 3; r++)
        for (int k = 0; k < 4; k++) {
            double want = (r < 2 ? -1 : 1) * c->labels->affine[r][k];
            assert_true(fabs(json_number_value(json_array_get(json_array_get(aff, (size_t)r), (size_t)k)) - want) < 1e-4);
        }
    json_t *s = read_back("segnrrd", seg, nii);
    assert_non_null(s);
    assert_true(json_is_true(json_object_get(s, "equals_nifti")));
    assert_string_equal(json_string_value(json_object_get(s, "space")), "left-posterior-superior");
    assert_string_equal(json_string_value(json_object_get(s, "master")), "Binary labelmap");
    json_t *segs = json_object_get(s, "segments");
    assert_int_equal(json_array_size(segs), c->nfrag);
    for (int i = 0; i < c->nfrag; i++) {
        const frag *f = &c->frag[i];
        json_t *e = json_array_get(segs, (size_t)i);
        char idbuf[16];
        snprintf(idbuf, sizeof idbuf, "%d", f->id);
        assert_string_equal(json_string_value(json_object_get(e, "LabelValue")), idbuf);
        assert_string_equal(json_string_value(json_object_get(e, "Name")), f->name);
        assert_string_equal(json_string_value(json_object_get(e, "Layer")), "0");
        assert_true(json_is_true(json_object_get(e, "extent_holds_voxels")));
        double r, g, b;
        assert_int_equal(sscanf(json_string_value(json_object_get(e, "Color")), "%lf %lf %lf", &r, &g, &b), 3);
        assert_true(fabs(r - f->rgb[0] / 255.0) < 1e-3 && fabs(g - f->rgb[1] / 255.0) < 1e-3 && fabs(b - f->rgb[2] / 255.0) < 1e-3);
        long vox = (long)json_integer_value(json_object_get(json_object_get(n, "counts"), idbuf));
        assert_true(labs(vox - (long)f->voxels) <= (long)f->voxels / 20); /* resampled: within 5% */
        assert_int_equal(json_integer_value(json_object_get(e, "voxels")), vox);
    }
    json_decref(n);
    json_decref(s);
    case_free(c);
}

static json_t *stl_check(const char *path, double want_mm3)
{
    json_t *j = read_back("stl", path, NULL);
    assert_non_null(j);
    assert_true(json_is_true(json_object_get(j, "closed")));
    double v = json_number_value(json_object_get(j, "volume_mm3"));
    assert_true(fabs(v - want_mm3) < 0.15 * want_mm3);
    if (access("/usr/bin/admesh", X_OK) == 0) {
        char *o = NULL;
        char cmd[4400];
        snprintf(cmd, sizeof cmd, "/usr/bin/admesh '%s' 2>&1", path);
        FILE *p = popen(cmd, "r");
        assert_non_null(p);
        o = calloc(1, 1 << 16);
        size_t n = fread(o, 1, (1 << 16) - 1, p);
        o[n] = 0;
        pclose(p);
        int parts = -1, backwards = -1, fixed = -1, added = -1;
        char *q;
        if ((q = strstr(o, "Number of parts")))
            sscanf(strchr(q, ':') + 1, "%d", &parts);
        if ((q = strstr(o, "Backwards edges")))
            sscanf(strchr(q, ':') + 1, "%d", &backwards);
        if ((q = strstr(o, "Edges fixed")))
            sscanf(strchr(q, ':') + 1, "%d", &fixed);
        if ((q = strstr(o, "Facets added")))
            sscanf(strchr(q, ':') + 1, "%d", &added);
        if (parts != 1 || backwards != 0 || fixed != 0 || added != 0)
            fail_msg("admesh on %s: parts %d, backwards edges %d, edges fixed %d, facets added %d\n%s", path, parts,
                     backwards, fixed, added, o);
        free(o);
    } else if (under_ci()) {
        fail_msg("admesh is missing (.ci/setup installs it)");
    }
    return j;
}

/* STL: closed and consistently wound (the reader's edge count and admesh), the fragment's volume,
 * at its planned pose; --ras negates x and y; --smooth and --decimate keep the surface closed. */
static void test_stl_closed_in_mm(void **st)
{
    (void)st;
    if (!have_python("struct") && missing("python3", "python3"))
        return;
    planning_case *c = case_load(frac);
    assert_non_null(c);
    char path[8800], ras_dir[4300], small_dir[4300];
    snprintf(ras_dir, sizeof ras_dir, "%s/ras", dir);
    snprintf(small_dir, sizeof small_dir, "%s/small", dir);
    assert_int_equal(tu_run_cli(NULL, "export '%s' --stl '%s' --ras", frac, ras_dir), 0);
    assert_int_equal(tu_run_cli(NULL, "export '%s' --stl '%s' --smooth 10 --decimate 3000", frac, small_dir), 0);
    /* a target no closed, unfolded surface reaches is said, with the count reached */
    char tiny_dir[4300], *o = NULL;
    snprintf(tiny_dir, sizeof tiny_dir, "%s/tiny", dir);
    assert_int_equal(tu_run_cli(&o, "export '%s' --stl '%s' --decimate 4", frac, tiny_dir), 0);
    if (!strstr(o, "triangles, over --decimate 4: no edge collapses further"))
        fail_msg("%s", o);
    free(o);
    for (int i = 0; i < c->nfrag; i++) {
        const frag *f = &c->frag[i];
        double mm3 = f->volume_ml * 1000;
        snprintf(path, sizeof path, "%s/models/fragment-%d.stl", out, f->id);
        json_t *lps = stl_check(path, mm3);
        assert_non_null(strstr(json_string_value(json_object_get(lps, "header")), "SPACE=LPS"));
        /* Where the fragment is planned: its planned centroid inside the model's bounds. */
        double cen[3];
        pose_apply(&f->pose, f->centroid, cen);
        for (int a = 0; a < 3; a++) {
            assert_true(json_number_value(json_array_get(json_object_get(lps, "lo"), (size_t)a)) < cen[a]);
            assert_true(json_number_value(json_array_get(json_object_get(lps, "hi"), (size_t)a)) > cen[a]);
        }
        snprintf(path, sizeof path, "%s/fragment-%d.stl", ras_dir, f->id);
        json_t *ras = stl_check(path, mm3);
        assert_non_null(strstr(json_string_value(json_object_get(ras, "header")), "SPACE=RAS"));
        for (int a = 0; a < 3; a++) {
            double l = json_number_value(json_array_get(json_object_get(lps, a < 2 ? "hi" : "lo"), (size_t)a));
            double r = json_number_value(json_array_get(json_object_get(ras, "lo"), (size_t)a));
            assert_true(fabs((a < 2 ? -l : l) - r) < 1e-3);
        }
        snprintf(path, sizeof path, "%s/fragment-%d.stl", small_dir, f->id);
        json_t *sm = stl_check(path, mm3);
        assert_true(json_integer_value(json_object_get(sm, "triangles")) <= 3000);
        json_decref(lps);
        json_decref(ras);
        json_decref(sm);
    }
    case_free(c);
}

/* The report as headless Chromium loads it (--dump-dom, after the page's script ran), at a
 * window 1000 pixels wide. malloc'd. */
static char *chromium_dom(const char *html)
{
    char udd[4300], cmd[9000];
    snprintf(udd, sizeof udd, "%s/chromium-profile", dir);
    tu_rmtree(udd);
    snprintf(cmd, sizeof cmd,
             "timeout %d chromium --headless --no-sandbox --disable-gpu --no-first-run --disable-background-networking "
             "--disable-component-update --disable-sync --window-size=1000,1400 --user-data-dir='%s' --dump-dom "
             "'file://%s' 2>/dev/null",
             TU_WAIT_MAX_S, udd, html); /* the bound only stops a browser that never ends */
    FILE *p = popen(cmd, "r");
    assert_non_null(p);
    char *buf = calloc(1, 1 << 20);
    size_t n = fread(buf, 1, (1 << 20) - 1, p);
    buf[n] = 0;
    pclose(p);
    return buf;
}

/* The value of attribute name="..." in the DOM's text ("" when absent), into val. */
static const char *attribute(const char *dom, const char *name, char *val, size_t cap)
{
    char key[64];
    snprintf(key, sizeof key, "%s=\"", name);
    const char *m = strstr(dom, key);
    val[0] = 0;
    if (m) {
        m += strlen(key);
        size_t k = strcspn(m, "\"");
        snprintf(val, cap, "%.*s", (int)(k < cap - 1 ? k : cap - 1), m);
    }
    return val;
}

/* The report opens in headless Chromium: its pictures all load (the page's script counts the img
 * elements with naturalWidth > 0 into the body's data-images), its header names the case, the
 * CT, the date, the version and the method, nothing is wider than the window (data-overflow), and
 * a screenshot of it is a picture; with a picture gone, the count says so. The debug line
 * "images: 5 of 5 loaded" is not shown. */
static void test_report_in_chromium(void **st)
{
    (void)st;
    if (system("command -v chromium >/dev/null 2>&1") != 0 && missing("chromium", "chromium"))
        return;
    char html[4300], val[256], gone[4300], shot[4300], udd[4300];
    snprintf(html, sizeof html, "%s/report/index.html", out);
    char *page = tu_slurp(html, NULL);
    assert_non_null(page);
    assert_non_null(strstr(page, "convergence.png")); /* the case has a reduction with a history */
    assert_non_null(strstr(page, "TRE (mm)"));        /* and ground truth */
    free(page);
    char *dom = chromium_dom(html);
    assert_string_equal(attribute(dom, "data-images", val, sizeof val), "4 of 4 loaded");
    assert_string_equal(attribute(dom, "data-overflow", val, sizeof val), "no");
    const char *want[] = {"<th>case</th>", "<th>CT</th>", "voxels of", "<th>date</th>", "<th>fracnav</th>",
                          "<th>method</th>", "collision tolerance", "planned move", "gap (mm)"};
    for (size_t i = 0; i < sizeof want / sizeof *want; i++)
        if (!strstr(dom, want[i]))
            fail_msg("the report lacks '%s'", want[i]);
    assert_null(strstr(dom, ">images: "));
    free(dom);
    snprintf(shot, sizeof shot, "%s/report.png", dir);
    snprintf(udd, sizeof udd, "%s/chromium-shot", dir);
    char cmd[16000];
    snprintf(cmd, sizeof cmd,
             "timeout %d chromium --headless --no-sandbox --disable-gpu --no-first-run --hide-scrollbars "
             "--window-size=1000,1400 --user-data-dir='%s' --screenshot='%s' 'file://%s' >/dev/null 2>&1",
             TU_WAIT_MAX_S, udd, shot, html);
    assert_int_equal(system(cmd), 0);
    struct stat sb;
    assert_int_equal(stat(shot, &sb), 0);
    assert_true(sb.st_size > 10000); /* pictures and text, not a blank page */
    snprintf(gone, sizeof gone, "%s/report/convergence.png", out);
    assert_int_equal(unlink(gone), 0);
    dom = chromium_dom(html);
    assert_string_equal(attribute(dom, "data-images", val, sizeof val), "3 of 4 loaded");
    free(dom);
}

/* The convergence plot's dot and label mark the kept pose's metric (the record's metric_end), not
 * the last value of the history (a global stage's last candidate: "final 0.2589" for a fit that
 * ended at -0.7515); the page says it beside the plot. */
static void test_report_plot_marks_the_final_metric(void **st)
{
    (void)st;
    char cj[4300], html[4300], want[128];
    snprintf(cj, sizeof cj, "%s/case.json", frac);
    snprintf(html, sizeof html, "%s/report/index.html", out);
    json_t *root = json_load_file(cj, 0, NULL);
    assert_non_null(root);
    json_t *fr = json_object_get(json_object_get(root, "reduction"), "fragments");
    assert_true(json_array_size(fr) >= 1);
    char *page = tu_slurp(html, NULL);
    assert_non_null(page);
    size_t i;
    json_t *e;
    json_array_foreach(fr, i, e) {
        int id = (int)json_integer_value(json_object_get(e, "id"));
        snprintf(want, sizeof want, "<span data-fragment=\"%d\">%.4f</span>", id,
                 json_number_value(json_object_get(e, "metric_end")));
        if (!strstr(page, want))
            fail_msg("the report's plot does not mark fragment %d's final metric: no '%s'", id, want);
    }
    free(page);
    json_decref(root);
}

/* export --report-pdf: the report printed by headless Chromium is a PDF. */
static void test_report_pdf(void **st)
{
    (void)st;
    if (system("command -v chromium >/dev/null 2>&1") != 0 && missing("chromium", "chromium"))
        return;
    char rdir[4300], pdf[4300];
    snprintf(rdir, sizeof rdir, "%s/report-pdf", dir);
    snprintf(pdf, sizeof pdf, "%s/report.pdf", dir);
    char *o = NULL;
    int rc = tu_run_cli(&o, "export '%s' --report '%s' --report-pdf '%s'", frac, rdir, pdf);
    if (rc != 0)
        fail_msg("export --report-pdf exited %d:\n%s", rc, o);
    free(o);
    size_t n;
    char *head = tu_slurp(pdf, &n);
    assert_non_null(head);
    assert_true(n > 1000 && !memcmp(head, "%PDF", 4));
    free(head);
    assert_int_equal(tu_run_cli(&o, "export '%s' --report-pdf '%s'", frac, pdf), 2);
    assert_non_null(strstr(o, "--report DIR"));
    free(o);
}

/* Fragment 2 of the case in case_dir (a fracture with no move: the truth is where it is) moved by
 * mm away from fragment 1 (along the line between their centroids); the case's truth dropped
 * unless keep_truth; then export --json's fragments into gap[id - 1] (median, p95, max). */
static void gaps_moved(const char *case_dir, double mm, int keep_truth, double gap[2][3])
{
    planning_case *c = case_load(case_dir);
    assert_non_null(c);
    assert_int_equal(c->nfrag, 2);
    double d[3], len = 0;
    for (int a = 0; a < 3; a++) {
        d[a] = c->frag[1].centroid[a] - c->frag[0].centroid[a];
        len += d[a] * d[a];
    }
    c->frag[1].pose = POSE_IDENTITY;
    for (int a = 0; a < 3; a++)
        c->frag[1].pose.t[a] = mm * d[a] / sqrt(len);
    c->has_truth = c->has_truth && keep_truth;
    assert_int_equal(case_save(c), 0);
    case_free(c);
    char nii[4300];
    snprintf(nii, sizeof nii, "%s/planned.nii.gz", dir);
    json_t *j = run_json("'%s' export '%s' --nifti '%s' --force --json 2>/dev/null", tu_fracnav(), case_dir, nii);
    assert_non_null(j);
    json_t *frs = json_object_get(j, "fragments"), *f;
    size_t i;
    assert_int_equal(json_array_size(frs), 2);
    json_array_foreach(frs, i, f) {
        const char *keys[4] = {"gap_median_mm", "gap_p95_mm", "gap_max_mm", "overlap_ml"};
        for (int q = 0; q < 4; q++)
            assert_non_null(json_object_get(f, keys[q]));
        for (int q = 0; q < 3; q++)
            gap[i][q] = json_number_value(json_object_get(f, keys[q]));
    }
    json_decref(j);
}

/* The gap across the fracture, in mm (export --json), on a double-walled tube (walls at radii 8..12
 * and 15..19 voxels of 1 mm, joined by four ribs: a space between bone plates, as a skull's)
 * broken in two with no move. With the truth known (the faces the pieces share there are the
 * fracture surface) it is 0 at the truth (median, p95 and max), and about d with fragment 2 moved
 * d = 3 mm away: the median within 2..3.5 mm. Without the truth (faces along their normals to
 * another fragment) the median is 0 at the truth and about d moved; there faces across the space
 * between the walls count too. The report's old figures: "gap (ml)" 22.7 ml at the exact truth;
 * then in mm a max of 5 mm here and 4.79 mm on the example skull's fracture at its truth. */
static void test_gap_near_zero_at_the_truth(void **st)
{
    (void)st;
    char tube2[4300], truth[4300];
    snprintf(tube2, sizeof tube2, "%s/double-tube.nii.gz", dir);
    snprintf(truth, sizeof truth, "%s/at-truth", dir);
    vol *v = vol_new(48, 48, 48);
    assert_non_null(v);
    for (int k = 0; k < 48; k++)
        for (int j = 0; j < 48; j++)
            for (int i = 0; i < 48; i++) {
                double r = hypot(i - 24.0, j - 24.0);
                int wall = (r > 8 && r < 12) || (r > 15 && r < 19), rib = r >= 12 && r <= 15 && (abs(i - 24) < 2 || abs(j - 24) < 2);
                v->data[vol_idx(v, i, j, k)] = k > 3 && k < 45 && (wall || rib) ? 1200.f : -1000.f;
            }
    assert_int_equal(volio_write(v, tube2, VOL_I16), 0);
    vol_free(v);
    assert_int_equal(tu_run_cli(NULL, "fracture '%s' -o '%s' --seed 1 --displace 0 --rotate 0", tube2, truth), 0);
    for (int known = 1; known >= 0; known--) {
        double at[2][3], off[2][3];
        gaps_moved(truth, 0, known, at);
        gaps_moved(truth, 3, known, off);
        for (int i = 0; i < 2; i++) {
            print_message("truth %s, fragment %d: gap median %.2f p95 %.2f max %.2f mm at the truth; median %.2f p95 "
                          "%.2f max %.2f mm 3 mm off\n",
                          known ? "known" : "unknown", i + 1, at[i][0], at[i][1], at[i][2], off[i][0], off[i][1],
                          off[i][2]);
            if (!(at[i][0] == 0 && (!known || (at[i][1] == 0 && at[i][2] == 0))))
                fail_msg("truth %s: at the truth fragment %d's gap reads median %.2f, p95 %.2f, max %.2f mm",
                         known ? "known" : "unknown", i + 1, at[i][0], at[i][1], at[i][2]);
            if (!(off[i][0] >= 2 && off[i][0] <= 3.5))
                fail_msg("truth %s: 3 mm off fragment %d's gap median reads %.2f mm", known ? "known" : "unknown", i + 1,
                         off[i][0]);
        }
    }
}

/* Without a GL 4.5 context (here: the window platform and no display) the report still comes,
 * saying why it has no renders. */
static void test_report_without_renderer(void **st)
{
    (void)st;
    char *o = NULL, rdir[4300], html[4400];
    snprintf(rdir, sizeof rdir, "%s/report-no-gl", dir);
    const char *keep = getenv("DISPLAY");
    char *saved = keep ? strdup(keep) : NULL;
    unsetenv("DISPLAY");
    unsetenv("WAYLAND_DISPLAY");
    int rc = tu_run_cli(&o, "export '%s' --report '%s' --platform glfw", frac, rdir);
    if (saved)
        setenv("DISPLAY", saved, 1);
    free(saved);
    if (rc != 0)
        fail_msg("export --report without a display exited %d:\n%s", rc, o);
    assert_non_null(strstr(o, "the report has no renders"));
    free(o);
    snprintf(html, sizeof html, "%s/index.html", rdir);
    char *page = tu_slurp(html, NULL);
    assert_non_null(page);
    assert_non_null(strstr(page, "No renders: "));
    assert_null(strstr(page, "before.png"));
    assert_non_null(strstr(page, "convergence.png"));
    free(page);
}

/* A hostile reduction history never reaches PLplot as a window it refuses (it printed "PLPLOT
 * ERROR, ABORTING OPERATION" into export's output): a flat line at 1e20 is drawn, values that are
 * no number within 1e30 leave the plot out, saying why. */
static void test_report_hostile_history(void **st)
{
    (void)st;
    static const char *const hist[] = {"[1e20, 1e20]", "[1, 1e300]", "[1, \"x\"]"};
    char *d = tu_tmpdir("report-history"), cs[4300], cjson[4400], rdir[4400], html[4500];
    tu_two_blocks_case(d, cs, sizeof cs);
    snprintf(cjson, sizeof cjson, "%s/case.json", cs);
    for (size_t i = 0; i < sizeof hist / sizeof hist[0]; i++) {
        json_t *root = json_load_file(cjson, 0, NULL), *h = json_loads(hist[i], 0, NULL);
        assert_non_null(root);
        assert_non_null(h);
        json_object_set_new(root, "reduction",
                            json_pack("{s:[{s:i,s:o}]}", "fragments", "id", 1, "history", h));
        assert_int_equal(json_dump_file(root, cjson, JSON_INDENT(2)), 0);
        json_decref(root);
        snprintf(rdir, sizeof rdir, "%s/report-%zu", d, i);
        char *o = NULL;
        int rc = tu_run_cli(&o, "export '%s' --report '%s' --platform glfw", cs, rdir);
        if (rc != 0 || strstr(o, "PLPLOT") || strstr(o, "ABORTING"))
            fail_msg("history %s: exit %d:\n%s", hist[i], rc, o);
        free(o);
        snprintf(html, sizeof html, "%s/index.html", rdir);
        char *page = tu_slurp(html, NULL);
        assert_non_null(page);
        if (i == 0 ? !strstr(page, "convergence.png") : !strstr(page, "not a number within 1e30"))
            fail_msg("history %s: the page lacks its plot or why", hist[i]);
        free(page);
    }
    tu_rmtree(d);
    free(d);
}

/* Bad input: exit 2 naming the option; a failed write (a missing folder) exits 1 naming the file
 * and leaves the earlier export as it was. */
static void test_bad_input(void **st)
{
    (void)st;
    char *o = NULL, seg[4300];
    assert_int_equal(tu_run_cli(&o, "export '%s' --smooth lots --stl '%s'", frac, out), 2);
    assert_non_null(strstr(o, "--smooth"));
    free(o);
    assert_int_equal(tu_run_cli(&o, "export '%s'", frac), 2);
    assert_non_null(strstr(o, "nothing to export"));
    free(o);
    snprintf(seg, sizeof seg, "%s/keep.seg.nrrd", dir);
    assert_int_equal(tu_run_cli(NULL, "export '%s' --seg-nrrd '%s'", frac, seg), 0);
    size_t n0, n1;
    char *before = tu_slurp(seg, &n0);
    assert_int_equal(tu_run_cli(&o, "export '%s' --seg-nrrd '%s' --nifti '%s/no/such/folder/x.nii.gz'", frac, seg, dir), 1);
    assert_non_null(strstr(o, "no/such/folder"));
    free(o);
    char *after = tu_slurp(seg, &n1);
    assert_int_equal(n0, n1);
    assert_memory_equal(before, after, n0);
    free(before);
    free(after);
}

static int fails_naming_tmp(durable_file *f, void *ctx)
{
    (void)ctx;
    return fn_err_set(FN_EIO, "%s: cannot write this format", f->tmp);
}

/* A writer's error names the path the user gave, never the temporary file written first. */
static void test_error_names_the_target(void **st)
{
    (void)st;
    char path[4300];
    snprintf(path, sizeof path, "%s/cases", dir);
    assert_int_equal(durable_replace(path, fails_naming_tmp, NULL), FN_EIO);
    char want[4400];
    snprintf(want, sizeof want, "%s: cannot write this format", path);
    assert_string_equal(fn_err_msg(), want);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_all_json),
        cmocka_unit_test(test_tfm_maps_as_the_pose),
        cmocka_unit_test(test_nifti_and_seg_nrrd),
        cmocka_unit_test(test_stl_closed_in_mm),
        cmocka_unit_test(test_report_in_chromium),
        cmocka_unit_test(test_report_plot_marks_the_final_metric),
        cmocka_unit_test(test_report_pdf),
        cmocka_unit_test(test_gap_near_zero_at_the_truth),
        cmocka_unit_test(test_report_without_renderer),
        cmocka_unit_test(test_report_hostile_history),
        cmocka_unit_test(test_bad_input),
        cmocka_unit_test(test_error_names_the_target),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
