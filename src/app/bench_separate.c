/* fracnav bench separate: bone and fragments of real fracture CTs against hand annotations. */
#include "bench.h"

#include "bone.h"
#include "case.h"
#include "cmd.h"
#include "err.h"
#include "grow.h"
#include "jsonw.h"
#include "morph.h"
#include "volio.h"

#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_PIECES 64

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav bench separate [--json] [--pelvis] DIR\n\n"
            "Bone and fragments of real fracture CTs against fragments annotated by hand. DIR holds\n"
            "pairs NNN_BONE.nii.gz (the CT) and NNN_BONE_mask.nii.gz (label k = fragment k, on the\n"
            "CT's grid), as the PENGWIN/FracSegNet data. Each CT is segmented as `segment CT -o CASE\n"
            "--separate` does, automatically, and again from one seed per annotated fragment at its\n"
            "deepest voxel (`--separate --seeds`). Per bone: bone_dice (the union of the fragments\n"
            "against the annotated union), fragment_dice_min and fragment_dice_median (each\n"
            "annotated fragment against the fragment that matches it best) and fragments_found,\n"
            "for both modes; split_seconds (the automatic separation), separate_seconds (the\n"
            "seeded one), regrow_seconds (the growth updated after one more seed in the largest\n"
            "fragment), preview_seconds (the window's seed mode: its preview updated after the\n"
            "click of the last fragment's seed, growth and pieces; null for one fragment), all in\n"
            "CPU seconds of the thread (a busy machine does not inflate them).\n"
            "Then the pooled figures beside their targets.\n\n"
            "  --json     one JSON object on stdout\n"
            "  --pelvis   per patient NNN, its bones' CTs added into one (a full pelvis) and scored\n"
            "             against the annotated fragments of them all, as one bone NNN_pelvis\n"
            "  --help     this text\n");
}

static int by_name(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

int bench_list_bones(const char *dir, char **names)
{
    DIR *d = opendir(dir);
    if (!d) {
        fn_err_set(FN_EIO, "cannot open the folder %s: %s", dir, strerror(errno));
        return -1;
    }
    int n = 0;
    for (struct dirent *e; (e = readdir(d)) && n < BENCH_MAX_BONES;) {
        size_t len = strlen(e->d_name), tail = strlen("_mask.nii.gz");
        if (len > tail && !strcmp(e->d_name + len - tail, "_mask.nii.gz"))
            names[n++] = strndup(e->d_name, len - tail);
    }
    closedir(d);
    qsort(names, (size_t)n, sizeof *names, by_name);
    return n;
}

/* A copy of v; NULL (with fn_err) when out of memory. */
static vol *vol_copy(const vol *v)
{
    vol *c = vol_new(v->dim[0], v->dim[1], v->dim[2]);
    if (c) {
        memcpy(c->spacing, v->spacing, sizeof c->spacing);
        memcpy(c->affine, v->affine, sizeof c->affine);
        c->src_type = v->src_type;
        memcpy(c->data, v->data, vol_count(v) * sizeof *v->data);
    }
    return c;
}

/* The CT (a copy of ct; path names it) segmented into its whole bones, as segment --separate does
 * before separating. */
static planning_case *whole_bone_case(const vol *ct_in, const char *path)
{
    vol *ct = vol_copy(ct_in);
    seg_params p;
    seg_defaults(&p);
    seg_result r = {0};
    if (!ct || bone_segment(ct, &p, &r) < 0) {
        vol_free(ct);
        return NULL;
    }
    p.threshold = r.threshold;
    vol *labels = r.labels;
    r.labels = NULL;
    seg_result_free(&r);
    planning_case *c = case_create("(bench separate)", path, ct, labels, &p);
    for (int f = 0; c && f < c->nfrag; f++)
        if (case_fill(c, c->frag[f].id, MORPH_FILL_3D) < 0) {
            case_free(c);
            return NULL;
        }
    return c;
}

typedef struct truth {
    vol *labels;
    int n;                    /* annotated fragments */
    int label[MAX_PIECES];    /* their label values */
    size_t voxels[MAX_PIECES];
    size_t deepest[MAX_PIECES]; /* the voxel farthest from the fragment's surface */
    float *depth;             /* per voxel: its distance (mm) to its fragment's surface */
} truth;

/* The annotated fragments (a copy of labels; path names them), their sizes, depth and deepest
 * voxels. */
static int read_truth(const vol *labels, const char *path, truth *t)
{
    memset(t, 0, sizeof *t);
    t->labels = vol_copy(labels);
    if (!t->labels)
        return -1;
    vol *l = t->labels;
    size_t n = vol_count(l);
    uint8_t *m = malloc(n);
    t->depth = calloc(n, sizeof *t->depth);
    float *d = malloc(n * sizeof *d);
    if (!m || !t->depth || !d) {
        free(m);
        free(d);
        return fn_err_set(FN_ENOMEM, "bench separate: out of memory");
    }
    uint8_t *present = calloc(65536, 1);
    if (!present) {
        free(m);
        free(d);
        return fn_err_set(FN_ENOMEM, "bench separate: out of memory");
    }
    for (size_t i = 0; i < n; i++) {
        float x = l->data[i];
        if (!(x >= 0 && x <= 65535 && x == floorf(x))) {
            free(present);
            free(m);
            free(d);
            return fn_err_set(FN_EFORMAT, "%s: voxel %zu holds %g; labels are whole numbers 0..65535", path, i,
                              (double)x);
        }
        present[(int)x] = 1;
    }
    for (int k = 1; k <= 65535 && t->n < MAX_PIECES; k++) {
        if (!present[k])
            continue;
        size_t count = 0;
        for (size_t i = 0; i < n; i++)
            count += (m[i] = l->data[i] == (float)k);
        morph_distance(m, l->dim, l->spacing, d);
        size_t best = 0;
        for (size_t i = 0; i < n; i++)
            if (m[i]) {
                t->depth[i] = d[i];
                if (d[i] > d[best])
                    best = i;
            }
        t->label[t->n] = k;
        t->voxels[t->n] = count;
        t->deepest[t->n++] = best;
    }
    free(present);
    free(m);
    free(d);
    return 0;
}

static void voxel_world(const vol *v, size_t i, double w[3])
{
    double ijk[3] = {(double)(i % (size_t)v->dim[0]), (double)(i / (size_t)v->dim[0] % (size_t)v->dim[1]),
                     (double)(i / ((size_t)v->dim[0] * v->dim[1]))};
    vol_index_to_world(v, ijk, w);
}

typedef struct scores {
    double dice_min, dice_median;
    double dice[MAX_PIECES]; /* per annotated fragment, in the order of their labels */
    int n, found;
} scores;

static int by_value(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Each annotated fragment against the case's fragment that matches it best. */
static scores score(const planning_case *c, const truth *t)
{
    size_t n = vol_count(t->labels), *inter = calloc((size_t)t->n * (size_t)(c->nfrag + 1), sizeof *inter);
    double dice[MAX_PIECES];
    scores s = {.dice_min = NAN, .dice_median = NAN, .n = t->n, .found = c->nfrag};
    if (!inter)
        return s;
    for (size_t i = 0; i < n; i++) {
        float a = t->labels->data[i], b = c->labels->data[i];
        if (a == 0 || b == 0)
            continue;
        int k = 0, f = case_find(c, (int)b);
        while (k < t->n && t->label[k] != (int)a)
            k++;
        if (k < t->n && f >= 0)
            inter[(size_t)k * (size_t)(c->nfrag + 1) + (size_t)f]++;
    }
    for (int k = 0; k < t->n; k++) {
        dice[k] = 0;
        for (int f = 0; f < c->nfrag; f++)
            dice[k] = fmax(dice[k], 2.0 * (double)inter[(size_t)k * (size_t)(c->nfrag + 1) + (size_t)f] /
                                        (double)(t->voxels[k] + c->frag[f].voxels));
    }
    free(inter);
    memcpy(s.dice, dice, (size_t)t->n * sizeof *dice);
    qsort(dice, (size_t)t->n, sizeof *dice, by_value);
    s.dice_min = dice[0];
    s.dice_median = t->n % 2 ? dice[t->n / 2] : (dice[t->n / 2 - 1] + dice[t->n / 2]) / 2;
    return s;
}

static double bone_dice(const planning_case *c, const truth *t)
{
    size_t n = vol_count(t->labels), a = 0, b = 0, both = 0;
    for (size_t i = 0; i < n; i++) {
        int x = c->labels->data[i] != 0, y = t->labels->data[i] != 0;
        a += (size_t)x;
        b += (size_t)y;
        both += (size_t)(x && y);
    }
    return a + b ? 2.0 * (double)both / (double)(a + b) : NAN;
}

/* The growth of the seeds over the whole bone, then updated after one more seed: a deep voxel of
 * the largest annotated fragment far from its first seed. Returns the update's seconds. */
static double regrow_seconds(const planning_case *c, const truth *t)
{
    const vol *l = c->labels;
    size_t n = vol_count(l);
    uint8_t *domain = malloc(n);
    float *hu = malloc(n * sizeof *hu);
    grow *g = NULL;
    double s = NAN;
    if (domain && hu) {
        for (size_t i = 0; i < n; i++) {
            domain[i] = l->data[i] != 0;
            hu[i] = c->ct->data[i];
        }
        g = grow_new(hu, domain, l->dim, l->spacing);
    }
    int big = 0;
    for (int k = 1; k < t->n; k++)
        big = t->voxels[k] > t->voxels[big] ? k : big;
    int rc = g ? 0 : -1;
    for (int k = 0; k < t->n && rc == 0; k++)
        if (domain[t->deepest[k]])
            rc = grow_add_seed(g, t->deepest[k], k + 1);
    size_t extra = t->deepest[big];
    double w0[3], w[3], best = -1;
    voxel_world(l, t->deepest[big], w0);
    for (size_t i = 0; rc == 0 && i < n; i++) {
        if (t->labels->data[i] != (float)t->label[big] || !domain[i] || t->depth[i] <= best)
            continue;
        voxel_world(l, i, w);
        if ((w[0] - w0[0]) * (w[0] - w0[0]) + (w[1] - w0[1]) * (w[1] - w0[1]) + (w[2] - w0[2]) * (w[2] - w0[2]) >
            40 * 40) {
            best = t->depth[i];
            extra = i;
        }
    }
    if (rc == 0 && grow_run(g) == 0 && grow_add_seed(g, extra, big + 1) == 0) {
        double t0 = bench_cpu_us();
        if (grow_run(g) == 0)
            s = (bench_cpu_us() - t0) * 1e-6;
    }
    grow_free(g);
    free(domain);
    free(hu);
    return s;
}

/* The window's seed mode (case_preview_update, as navseed's worker calls it): the seeds clicked in
 * turn, each click's update timed; a seed the preview refuses (one where the bone was missed,
 * which only Enter grows to) is left out with a word. Returns the seconds of the last click that
 * added a fragment to at least one other (NAN when there was none). */
static double preview_seconds(const planning_case *c, const case_seed *seeds, int n)
{
    case_preview *p = case_preview_new(c);
    case_seed kept[MAX_PIECES];
    const frag *shown;
    double s = NAN;
    for (int k = 0, m = 0; p && k < n; k++) {
        kept[m] = seeds[k];
        double t0 = bench_cpu_us();
        if (case_preview_update(p, NULL, kept, m + 1, &shown) >= 0) {
            if (++m > 1)
                s = (bench_cpu_us() - t0) * 1e-6;
            continue;
        }
        fprintf(stderr, "bench separate: preview: %s; left out\n", fn_err_msg());
        if (m > 0 && case_preview_update(p, NULL, kept, m, &shown) < 0) /* the next click grows on these */
            break;
    }
    case_preview_free(p);
    return s;
}

typedef struct bone_result {
    char name[256];
    int annotated;
    double bone_dice, split_s, separate_s, regrow_s, preview_s;
    scores automatic, seeded;
} bone_result;

/* ct (named path) and its annotation labels (named mask) scored as the bone name. */
static int run_bone(const vol *ct, const char *path, const vol *labels, const char *mask, const char *name,
                    bone_result *r)
{
    memset(r, 0, sizeof *r);
    snprintf(r->name, sizeof r->name, "%s", name);
    truth t;
    if (read_truth(labels, mask, &t) < 0)
        return -1;
    r->annotated = t.n;
    planning_case *c = whole_bone_case(ct, path);
    int rc = c ? 0 : -1;
    if (rc == 0) {
        r->bone_dice = bone_dice(c, &t);
        double t0 = bench_cpu_us();
        rc = case_separate_all(c, NULL, 0);
        r->split_s = (bench_cpu_us() - t0) * 1e-6;
        r->automatic = score(c, &t);
        case_free(c);
    }
    c = rc >= 0 ? whole_bone_case(ct, path) : NULL;
    case_seed seeds[MAX_PIECES];
    for (int k = 0; k < t.n; k++) {
        voxel_world(t.labels, t.deepest[k], seeds[k].at);
        seeds[k].piece = k + 1;
    }
    if (c) {
        r->regrow_s = regrow_seconds(c, &t);
        r->preview_s = preview_seconds(c, seeds, t.n);
        double t0 = bench_cpu_us();
        rc = case_separate_all(c, seeds, t.n);
        r->separate_s = (bench_cpu_us() - t0) * 1e-6;
        r->seeded = score(c, &t);
        case_free(c);
    }
    vol_free(t.labels);
    free(t.depth);
    return c ? rc : -1;
}

/* The CT and annotation of bones[0..n-1] in dir: the CTs added into one (each holds only its bone,
 * 0 elsewhere), the labels of each bone after those of the bones before it. */
static int read_bones(const char *dir, char *const *bones, int n, vol **ct, vol **labels)
{
    *ct = *labels = NULL;
    int offset = 0;
    for (int b = 0; b < n; b++) {
        char path[4200], mask[4200];
        snprintf(path, sizeof path, "%s/%s.nii.gz", dir, bones[b]);
        snprintf(mask, sizeof mask, "%s/%s_mask.nii.gz", dir, bones[b]);
        volio_segs segs = {0};
        vol *c = volio_read(path), *l = c ? volio_read_labels(mask, &segs) : NULL;
        volio_segs_free(&segs);
        if (!l) {
            vol_free(c);
            return -1;
        }
        if (!*ct) {
            *ct = c;
            *labels = l;
        } else if (memcmp(c->dim, (*ct)->dim, sizeof c->dim) || memcmp(l->dim, c->dim, sizeof c->dim)) {
            vol_free(c);
            vol_free(l);
            return fn_err_set(FN_EFORMAT, "%s: its grid (%dx%dx%d) is not the grid of %s", path, c->dim[0],
                              c->dim[1], c->dim[2], bones[0]);
        } else {
            for (size_t i = 0; i < vol_count(c); i++) {
                (*ct)->data[i] = (*ct)->data[i] != 0 ? (*ct)->data[i] : c->data[i];
                (*labels)->data[i] = l->data[i] != 0 ? l->data[i] + (float)offset : (*labels)->data[i];
            }
            vol_free(c);
            vol_free(l);
        }
        float lo, hi;
        vol_range(*labels, &lo, &hi);
        offset = (int)hi;
    }
    return 0;
}

/* The bones names[0..n-1] of dir scored one by one, or (pelvis) those of each patient NNN added
 * into one, as the bone NNN_pelvis. Returns the bones scored, or -1. */
static int run_all(const char *dir, char **names, int n, int pelvis, bone_result *r)
{
    int done = 0;
    for (int i = 0; i < n;) {
        int m = 1;
        while (pelvis && i + m < n && !strncmp(names[i], names[i + m], strcspn(names[i], "_") + 1))
            m++;
        char name[256], path[4200], mask[4200];
        snprintf(name, sizeof name, pelvis ? "%.*s_pelvis" : "%.*s", pelvis ? (int)strcspn(names[i], "_") : 248,
                 names[i]);
        /* the case's source (its sha256 is taken, nothing else): the first bone's CT */
        snprintf(path, sizeof path, "%s/%s.nii.gz", dir, names[i]);
        snprintf(mask, sizeof mask, pelvis ? "%s/%.*s_*_mask.nii.gz" : "%s/%.*s_mask.nii.gz", dir,
                 pelvis ? (int)strcspn(names[i], "_") : 255, names[i]);
        fprintf(stderr, "bench separate: %s\n", name);
        vol *ct, *labels;
        int rc = read_bones(dir, names + i, m, &ct, &labels);
        if (rc == 0)
            rc = run_bone(ct, path, labels, mask, name, &r[done++]);
        vol_free(ct);
        vol_free(labels);
        if (rc < 0)
            return -1;
        i += m;
    }
    return done;
}

static json_t *scores_json(const scores *s)
{
    json_t *each = json_array();
    for (int k = 0; k < s->n; k++)
        json_array_append_new(each, jsonw_measure(s->dice[k]));
    return json_pack("{s:o,s:o,s:o,s:i}", "fragment_dice_min", jsonw_measure(s->dice_min), "fragment_dice_median",
                     jsonw_measure(s->dice_median), "fragment_dice", each, "fragments_found", s->found);
}

static json_t *bone_json(const bone_result *r)
{
    return json_pack("{s:s,s:i,s:o,s:o,s:o,s:o,s:o,s:o,s:o}", "bone", r->name, "fragments_annotated", r->annotated,
                     "bone_dice", jsonw_measure(r->bone_dice), "automatic", scores_json(&r->automatic), "seeded",
                     scores_json(&r->seeded), "split_seconds", jsonw_measure(r->split_s), "separate_seconds",
                     jsonw_measure(r->separate_s), "regrow_seconds", jsonw_measure(r->regrow_s),
                     "preview_seconds", jsonw_measure(r->preview_s));
}

typedef struct pooled {
    double bone_dice_min, auto_min, seeded_min, split_max, separate_max, regrow_max, preview_max;
    int intact, intact_whole;
} pooled;

static pooled pool(const bone_result *r, int n)
{
    pooled p = {INFINITY, INFINITY, INFINITY, 0, 0, 0, 0, 0, 0};
    for (int i = 0; i < n; i++) {
        p.bone_dice_min = fmin(p.bone_dice_min, r[i].bone_dice);
        p.split_max = fmax(p.split_max, r[i].split_s);
        p.separate_max = fmax(p.separate_max, r[i].separate_s);
        p.regrow_max = fmax(p.regrow_max, r[i].regrow_s);
        if (isfinite(r[i].preview_s))
            p.preview_max = fmax(p.preview_max, r[i].preview_s);
        p.seeded_min = fmin(p.seeded_min, r[i].seeded.dice_min);
        if (r[i].annotated > 1)
            p.auto_min = fmin(p.auto_min, r[i].automatic.dice_min);
        else {
            p.intact++;
            p.intact_whole += r[i].automatic.found == 1;
        }
    }
    return p;
}

static json_t *pooled_json(const pooled *p)
{
    return json_pack("{s:o,s:o,s:o,s:i,s:i,s:o,s:o,s:o,s:o}", "bone_dice_min", jsonw_measure(p->bone_dice_min),
                     "automatic_fragment_dice_min", isfinite(p->auto_min) ? jsonw_measure(p->auto_min) : json_null(),
                     "seeded_fragment_dice_min", jsonw_measure(p->seeded_min), "intact_bones", p->intact,
                     "intact_bones_whole", p->intact_whole, "split_seconds_max", jsonw_measure(p->split_max),
                     "separate_seconds_max", jsonw_measure(p->separate_max),
                     "regrow_seconds_max", jsonw_measure(p->regrow_max), "preview_seconds_max",
                     jsonw_measure(p->preview_max));
}

static json_t *targets_json(void)
{
    return json_pack("{s:f,s:f,s:f,s:s,s:f,s:f,s:f}", "bone_dice_min", 0.97, "automatic_fragment_dice_min", 0.85,
                     "seeded_fragment_dice_min", 0.95, "intact_bones_whole", "all", "separate_seconds_max", 1.0,
                     "regrow_seconds_max", 0.2, "preview_seconds_max", 0.2);
}

static void print_text(const bone_result *r, int n, const pooled *p)
{
    printf("%-8s %5s %9s %-22s %-22s %8s %8s %8s %9s\n", "bone", "parts", "bone_dice", "automatic min/med/found",
           "seeded min/med/found", "split_s", "sep_s", "regrow_s", "preview_s");
    for (int i = 0; i < n; i++)
        printf("%-8s %5d %9.4f %7.3f %6.3f %6d   %7.3f %6.3f %6d   %8.3f %8.3f %8.3f %9.3f\n", r[i].name, r[i].annotated,
               r[i].bone_dice, r[i].automatic.dice_min, r[i].automatic.dice_median, r[i].automatic.found,
               r[i].seeded.dice_min, r[i].seeded.dice_median, r[i].seeded.found, r[i].split_s, r[i].separate_s,
               r[i].regrow_s, r[i].preview_s);
    printf("pooled (target): bone Dice min %.4f (>= 0.97), automatic fragment Dice min %.3f (>= 0.85), intact "
           "bones whole %d of %d (all), seeded fragment Dice min %.3f (>= 0.95), separate max %.3f s (<= 1), "
           "regrow max %.3f s (<= 0.2), preview max %.3f s (<= 0.2)\n", p->bone_dice_min, p->auto_min, p->intact_whole,
           p->intact, p->seeded_min, p->separate_max, p->regrow_max, p->preview_max);
}

int bench_separate(int argc, char **argv)
{
    int json = 0, pelvis = 0;
    const char *dir = NULL;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            usage(stdout);
            return 0;
        }
        if (!strcmp(argv[i], "--json"))
            json = 1;
        else if (!strcmp(argv[i], "--pelvis"))
            pelvis = 1;
        else if (argv[i][0] != '-' && !dir)
            dir = argv[i];
        else
            return cmd_usage_error("bench separate", "unknown or extra argument '%s'", argv[i]);
    }
    if (!dir)
        return cmd_usage_error("bench separate", "%s", "give the folder of NNN_BONE.nii.gz and "
                               "NNN_BONE_mask.nii.gz pairs (e.g. the PENGWIN/FracSegNet data)");
    char *names[BENCH_MAX_BONES];
    int n = bench_list_bones(dir, names);
    if (n == 0)
        fn_err_set(FN_EINVAL, "bench separate: no NNN_BONE_mask.nii.gz in %s", dir);
    bone_result *r = n > 0 ? calloc((size_t)n, sizeof *r) : NULL;
    int rc = r ? run_all(dir, names, n, pelvis, r) : -1;
    for (int i = 0; i < (n > 0 ? n : 0); i++)
        free(names[i]);
    n = rc;
    if (rc < 0) {
        fprintf(stderr, "fracnav bench separate: %s\n", fn_err_msg());
        free(r);
        return 1;
    }
    pooled p = pool(r, n);
    if (json) {
        json_t *o = jsonw_object("bench separate"), *bones = json_array();
        for (int i = 0; i < n; i++)
            json_array_append_new(bones, bone_json(&r[i]));
        jsonw_set(o, "folder", jsonw_string(dir));
        jsonw_set(o, "bones", bones);
        jsonw_set(o, "pooled", pooled_json(&p));
        jsonw_set(o, "targets", targets_json());
        rc = jsonw_print(o, stdout);
    } else
        print_text(r, n, &p);
    free(r);
    return rc < 0 ? 1 : 0;
}
