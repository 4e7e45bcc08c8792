/* fracnav export: a case's plan for other tools (ITK/3D Slicer transforms, segmentations, NIfTI,
 * STL models for printing) and an HTML report. */
#define _XOPEN_SOURCE 700 /* nftw: removing Chromium's profile folder */
#include "cmd.h"

#include "case.h"
#include "caselock.h"
#include "err.h"
#include "durable.h"
#include "export.h"
#include "jsonw.h"
#include "report.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <fcntl.h>
#include <ftw.h>
#include <limits.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav export CASE [--tfm DIR] [--seg-nrrd FILE] [--nifti FILE] [--stl DIR]\n"
            "                      [--ras] [--smooth N] [--decimate TRIANGLES] [--report DIR]\n"
            "                      [--report-pdf FILE] [--all DIR] [--platform osmesa|glfw] [--force]\n"
            "                      [--json] [--recover] [--wait]\n\n"
            "Writes the case's plan (every fragment at its current, planned pose) for other tools.\n"
            "Every file is written atomically (a temporary file, synced, then renamed). Coordinates\n"
            "are LPS mm unless said otherwise. Every path is checked before anything is written: a\n"
            "folder must be missing or empty (or --force), and nothing goes into a case folder or\n"
            "onto the case's source volume.\n\n"
            "  --tfm DIR          one ITK transform per fragment, DIR/fragment-ID.tfm\n"
            "                     (AffineTransform_double_3_3), in ITK's resampling direction: it maps\n"
            "                     a planned point back to where the fragment was segmented. In 3D Slicer,\n"
            "                     load it and put the fragment's model or segment under it: it moves to\n"
            "                     its planned place\n"
            "  --seg-nrrd FILE    a 3D Slicer segmentation (.seg.nrrd) of the planned configuration:\n"
            "                     the fragments' names, colours and label values\n"
            "  --nifti FILE       the planned labelmap (.nii or .nii.gz, uint16 labels) on the source\n"
            "                     grid\n"
            "  --stl DIR          one binary STL per fragment at its planned pose, DIR/fragment-ID.stl:\n"
            "                     a closed surface, mm: the outer surface and the walls of cavities\n"
            "                     inside (bone touching the rest only at a voxel's edge or corner,\n"
            "                     which would float apart, is left out)\n"
            "  --ras              STL coordinates in RAS (x and y negated) instead of LPS\n"
            "  --smooth N         N Taubin smoothing iterations of the STL surfaces (default 0)\n"
            "  --decimate T       down to T triangles per STL surface (edge collapses that keep it\n"
            "                     closed and unfolded; where none is left above T, a warning says\n"
            "                     how many remain; default: all)\n"
            "  --report DIR       DIR/index.html (works offline): the case, CT, date, version,\n"
            "                     method and tolerance; before and after pictures from the auto view\n"
            "                     and a CT slice with the planned outlines; per fragment the planned\n"
            "                     move in anatomical terms, the fit's metric, the gap across the\n"
            "                     fracture (median, 95%%, max mm), overlap, contact, errors against any\n"
            "                     ground truth; the convergence plot, one line per stage or attempt\n"
            "  --report-pdf FILE  the report (with --report or --all) printed to a PDF by headless\n"
            "                     Chromium (package chromium)\n"
            "  --all DIR          all of them: DIR/transforms, DIR/planned.seg.nrrd,\n"
            "                     DIR/planned.nii.gz, DIR/models, DIR/report\n"
            "  --platform P       the report's renderer: osmesa (default) or glfw\n"
            "  --force            write into folders that hold files already (files of the same\n"
            "                     names are replaced, others left alone)\n"
            "  --json             one JSON object: the files written and their sizes, and per\n"
            "                     fragment gap_median_mm, gap_p95_mm, gap_max_mm and overlap_ml\n"
            CMD_RECOVER_HELP
            CMD_WAIT_HELP
            "  --help             this text\n");
}

typedef struct export_args {
    const char *dir, *tfm, *seg, *nifti, *stl, *report, *all, *platform, *pdf;
    export_stl_opts stl_o;
    int json, force;
} export_args;

typedef struct written {
    json_t *files, *fragments; /* --json: the files, and the fragments' figures */
    long n;
    long long bytes;
    int json;
} written;

static void wrote(void *ctx, const char *path)
{
    written *w = ctx;
    struct stat st;
    long long size = stat(path, &st) == 0 ? (long long)st.st_size : 0;
    w->n++;
    w->bytes += size;
    if (w->files) {
        json_t *o = json_object();
        jsonw_set(o, "path", jsonw_string(path));
        jsonw_set(o, "size_bytes", json_integer(size));
        json_array_append_new(w->files, o);
    }
    if (!w->json)
        printf("  %s (%lld bytes)\n", path, size);
}

static int parse_count(const char *s, long lo, long hi, long *out)
{
    double d;
    if (!cmd_number(s, &d) || d != (long)d || d < (double)lo || d > (double)hi)
        return 0;
    *out = (long)d;
    return 1;
}

static int parse_args(int argc, char **argv, export_args *a)
{
    for (int i = 1; i < argc; i++) {
        const char *opt = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        const char **slot = !strcmp(opt, "--tfm")        ? &a->tfm
                            : !strcmp(opt, "--seg-nrrd") ? &a->seg
                            : !strcmp(opt, "--nifti")    ? &a->nifti
                            : !strcmp(opt, "--stl")      ? &a->stl
                            : !strcmp(opt, "--report")   ? &a->report
                            : !strcmp(opt, "--all")      ? &a->all
                            : !strcmp(opt, "--report-pdf") ? &a->pdf
                                                         : NULL;
        long n;
        if (slot) {
            if (!val || !*val)
                return cmd_bad_value("export", opt, NULL, opt[2] == 's' && opt[3] == 'e' ? "a file" : "a folder");
            *slot = val;
            i++;
        } else if (!strcmp(opt, "--ras")) {
            a->stl_o.ras = 1;
        } else if (!strcmp(opt, "--json")) {
            a->json = 1;
        } else if (!strcmp(opt, "--force")) {
            a->force = 1;
        } else if (!strcmp(opt, "--smooth")) {
            if (!parse_count(val, 0, 1000, &n))
                return cmd_bad_value("export", opt, val, "a whole number of iterations, 0 to 1000");
            a->stl_o.smooth = (int)n;
            i++;
        } else if (!strcmp(opt, "--decimate")) {
            if (!parse_count(val, 4, 1000000000, &n))
                return cmd_bad_value("export", opt, val, "a whole number of triangles, at least 4");
            a->stl_o.decimate = n;
            i++;
        } else if (!strcmp(opt, "--platform")) {
            if (!val || (strcmp(val, "osmesa") && strcmp(val, "glfw")))
                return cmd_bad_value("export", opt, val, "osmesa or glfw");
            a->platform = val;
            i++;
        } else if (opt[0] == '-') {
            return cmd_usage_error("export", "unknown option '%s'", opt);
        } else {
            if (a->dir)
                return cmd_usage_error("export", "one CASE only ('%s' and '%s' given)", a->dir, opt);
            a->dir = opt;
        }
    }
    if (!a->dir)
        return cmd_usage_error("export", "CASE is missing");
    if (a->pdf && !a->report && !a->all)
        return cmd_usage_error("export", "--report-pdf prints the report: give --report DIR or --all DIR");
    if (!a->tfm && !a->seg && !a->nifti && !a->stl && !a->report && !a->all)
        return cmd_usage_error("export", "nothing to export: give --tfm, --seg-nrrd, --nifti, --stl, --report "
                                         "or --all");
    return 0;
}

static int make_dir(const char *dir)
{
    if (mkdir(dir, 0777) != 0 && errno != EEXIST)
        return fn_err_set(FN_EIO, "%s: cannot create the folder: %s", dir, strerror(errno));
    struct stat st;
    if (stat(dir, &st) != 0 || !S_ISDIR(st.st_mode))
        return fn_err_set(FN_EIO, "%s: not a folder", dir);
    return 0;
}

static int ends_with(const char *s, const char *tail)
{
    size_t n = strlen(s), t = strlen(tail);
    return n > t && !strcmp(s + n - t, tail);
}

/* Every output path, before anything is written (cmd_out_file, cmd_out_folder), and the formats
 * the names ask for. */
static int check_outputs(const planning_case *c, const export_args *a)
{
    const char *folders[4] = {a->all, a->tfm, a->stl, a->report};
    int rc = 0;
    for (int i = 0; i < 4 && rc == 0; i++)
        if (folders[i])
            rc = cmd_out_folder(folders[i], a->force);
    if (rc == 0 && a->nifti && !ends_with(a->nifti, ".nii") && !ends_with(a->nifti, ".nii.gz"))
        rc = fn_err_set(FN_EINVAL, "--nifti %s: a NIfTI file's name ends in .nii or .nii.gz", a->nifti);
    if (rc == 0 && a->seg && !ends_with(a->seg, ".nrrd"))
        rc = fn_err_set(FN_EINVAL, "--seg-nrrd %s: a 3D Slicer segmentation's name ends in .seg.nrrd",
                        a->seg);
    if (rc == 0 && a->nifti)
        rc = cmd_out_file(a->nifti, c);
    if (rc == 0 && a->seg)
        rc = cmd_out_file(a->seg, c);
    if (rc == 0 && a->pdf)
        rc = cmd_out_file(a->pdf, c);
    return rc;
}

/* --json: per fragment the gap across its fracture (report_gaps) and its overlap. */
static int fragment_figures(const planning_case *c, const vol *planned, const double *overlap, json_t *out)
{
    report_gap *g = malloc((size_t)(c->nfrag ? c->nfrag : 1) * sizeof *g);
    int rc = g ? report_gaps(c, planned, g) : fn_err_set(FN_ENOMEM, "out of memory");
    for (int i = 0; i < c->nfrag && !rc; i++) {
        json_t *o = json_object();
        jsonw_set(o, "id", json_integer(c->frag[i].id));
        jsonw_set(o, "gap_median_mm", jsonw_measure(g[i].median_mm));
        jsonw_set(o, "gap_p95_mm", jsonw_measure(g[i].p95_mm));
        jsonw_set(o, "gap_max_mm", jsonw_measure(g[i].max_mm));
        jsonw_set(o, "overlap_ml", jsonw_measure(overlap[i]));
        json_array_append_new(out, o);
    }
    free(g);
    return rc;
}

static int remove_entry(const char *path, const struct stat *st, int flag, struct FTW *ftw)
{
    (void)st, (void)flag, (void)ftw;
    return remove(path);
}

/* Prints the page at the absolute path ctx into tmp with headless Chromium (its own profile in a
 * temporary folder, removed after). */
static int print_page(durable_file *f, void *ctx)
{
    const char *tmp = f->tmp;
    char profile[] = "/tmp/fracnav-chromium-XXXXXX", url[PATH_MAX + 16], pdf[sizeof f->tmp + 32], udd[64];
    if (!mkdtemp(profile))
        return fn_err_set(FN_EIO, "--report-pdf: a folder for Chromium's profile: %s", strerror(errno));
    snprintf(url, sizeof url, "file://%s", (const char *)ctx);
    snprintf(pdf, sizeof pdf, "--print-to-pdf=%s", tmp);
    snprintf(udd, sizeof udd, "--user-data-dir=%s", profile);
    pid_t pid = fork();
    if (pid == 0) {
        int null = open("/dev/null", O_RDWR);
        dup2(null, STDIN_FILENO), dup2(null, STDOUT_FILENO), dup2(null, STDERR_FILENO);
        execlp("chromium", "chromium", "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               "--no-pdf-header-footer", udd, pdf, url, (char *)NULL);
        _exit(127);
    }
    int status = 0;
    if (pid < 0 || waitpid(pid, &status, 0) < 0)
        status = -1;
    nftw(profile, remove_entry, 16, FTW_DEPTH | FTW_PHYS);
    struct stat st;
    if (WIFEXITED(status) && WEXITSTATUS(status) == 127)
        return fn_err_set(FN_ENODEV, "--report-pdf: chromium is not installed (apt-get install chromium)");
    if (status != 0 || stat(tmp, &st) != 0 || st.st_size == 0)
        return fn_err_set(FN_EIO, "--report-pdf: chromium printed no PDF of %s (status %#x)", url, status);
    return 0;
}

/* FILE.pdf: the report in dir printed by headless Chromium, written atomically. */
static int report_pdf(const char *dir, const char *pdf)
{
    char html[PATH_MAX + 16], abs[PATH_MAX];
    if (!realpath(dir, abs))
        return fn_err_set(FN_EIO, "--report-pdf: %s: %s", dir, strerror(errno));
    snprintf(html, sizeof html, "%s/index.html", abs);
    return durable_replace(pdf, print_page, html);
}

static int run(const planning_case *c, const export_args *a, written *w)
{
    char buf[5][4200];
    const char *tfm = a->tfm, *seg = a->seg, *nifti = a->nifti, *stl = a->stl, *report = a->report;
    int rc = 0;
    if (a->all) {
        if ((rc = make_dir(a->all)) != 0)
            return rc;
        snprintf(buf[0], sizeof buf[0], "%s/transforms", a->all);
        snprintf(buf[1], sizeof buf[1], "%s/planned.seg.nrrd", a->all);
        snprintf(buf[2], sizeof buf[2], "%s/planned.nii.gz", a->all);
        snprintf(buf[3], sizeof buf[3], "%s/models", a->all);
        snprintf(buf[4], sizeof buf[4], "%s/report", a->all);
        tfm = tfm ? tfm : buf[0];
        seg = seg ? seg : buf[1];
        nifti = nifti ? nifti : buf[2];
        stl = stl ? stl : buf[3];
        report = report ? report : buf[4];
    }
    char path[4300];
    if (tfm) {
        rc = make_dir(tfm);
        for (int i = 0; i < c->nfrag && !rc; i++) {
            snprintf(path, sizeof path, "%s/fragment-%d.tfm", tfm, c->frag[i].id);
            if ((rc = export_tfm(c, i, path)) == 0)
                wrote(w, path);
        }
    }
    if (!rc && stl) {
        rc = make_dir(stl);
        for (int i = 0; i < c->nfrag && !rc; i++) {
            snprintf(path, sizeof path, "%s/fragment-%d.stl", stl, c->frag[i].id);
            long nt = 0;
            if ((rc = export_stl(c, i, &a->stl_o, path, &nt)) == 0)
                wrote(w, path);
            if (rc == 0 && a->stl_o.decimate && nt > a->stl_o.decimate)
                fprintf(stderr, "fracnav export: %s: %ld triangles, over --decimate %ld: no edge collapses "
                                "further without opening or folding the surface\n", path, nt, a->stl_o.decimate);
        }
    }
    if (rc || (!seg && !nifti && !report && !w->fragments))
        return rc;
    size_t npairs = (size_t)c->nfrag * (size_t)c->nfrag / 2 + 1;
    double *overlap = calloc((size_t)c->nfrag + 1, sizeof *overlap);
    case_overlap *pen = malloc(npairs * sizeof *pen);
    int n = overlap && pen ? case_penetrating(c, NULL, pen, (int)npairs) : fn_err_set(FN_ENOMEM, "out of memory");
    for (int k = 0; k < n; k++) {
        overlap[pen[k].a] += pen[k].ml;
        overlap[pen[k].b] += pen[k].ml;
    }
    free(pen);
    vol *planned = n >= 0 ? export_planned_labels(c) : NULL;
    if (!planned) {
        free(overlap);
        return -1;
    }
    if (seg && (rc = export_seg_nrrd(c, planned, seg)) == 0)
        wrote(w, seg);
    if (!rc && nifti && (rc = export_nifti(planned, nifti)) == 0)
        wrote(w, nifti);
    if (!rc && report)
        rc = report_write(c, planned, overlap, report, a->platform, wrote, w);
    if (!rc && report && a->pdf && (rc = report_pdf(report, a->pdf)) == 0)
        wrote(w, a->pdf);
    if (!rc && w->fragments)
        rc = fragment_figures(c, planned, overlap, w->fragments);
    vol_free(planned);
    free(overlap);
    return rc;
}

int cmd_export(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    export_args a = {0};
    int wait = cmd_take_flag(&argc, argv, "--wait"), recover = cmd_take_flag(&argc, argv, "--recover");
    int rc = parse_args(argc, argv, &a);
    if (rc)
        return rc;
    caselock *lock = cmd_lock_case("export", a.dir, recover, wait);
    if (!lock)
        return 1;
    planning_case *c = case_load(a.dir);
    if (c && cmd_journal_poses("export", c, recover) < 0) {
        case_free(c);
        c = NULL;
    }
    caselock_release(lock); /* what is exported is the case as loaded */
    if (!c) {
        fprintf(stderr, "fracnav export: %s\n", fn_err_msg());
        return 1;
    }
    written w = {a.json ? json_array() : NULL, a.json ? json_array() : NULL, 0, 0, a.json};
    rc = c->nfrag > 0 ? 0 : fn_err_set(FN_EINVAL, "%s holds no fragment (its labelmap labels no voxel): "
                                       "nothing to export, nothing written", a.dir);
    if (!rc)
        rc = check_outputs(c, &a);
    if (!rc && !a.json)
        printf("fracnav export: %s (%d fragments)\n", a.dir, c->nfrag);
    if (!rc)
        rc = run(c, &a, &w);
    if (rc) {
        fprintf(stderr, "fracnav export: %s\n", fn_err_msg());
        json_decref(w.files);
        json_decref(w.fragments);
        case_free(c);
        return 1;
    }
    if (a.json) {
        json_t *o = jsonw_object("export");
        if (o) {
            jsonw_set(o, "case", jsonw_string(a.dir));
            jsonw_set(o, "files", w.files);
            jsonw_set(o, "fragments", w.fragments);
            jsonw_set(o, "files_written", json_integer(w.n));
            jsonw_set(o, "written_total_bytes", json_integer(w.bytes));
        } else {
            json_decref(w.files);
            json_decref(w.fragments);
        }
        rc = jsonw_print(o, stdout) ? 1 : 0;
    } else {
        printf("%ld files, %lld bytes\n", w.n, w.bytes);
    }
    case_free(c);
    return rc;
}
