/* fracnav segment: threshold + 26-connected components into a new case. */
#include "cmd.h"

#include "bone.h"
#include "case.h"
#include "caselock.h"
#include "err.h"
#include "fnclock.h"
#include "jsonw.h"
#include "morph.h"
#include "seg.h"
#include "volio.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav segment VOLUME -o CASE [--json] [options]\n\n"
            "Segment a CT into bone fragments and save them as a case folder (CASE/case.json,\n"
            "CASE/labels.nii.gz). Bone is every voxel >= the threshold; 26-connected components\n"
            "become fragments, largest first (ids 1..n). NaN and infinite voxels are never bone\n"
            "and are left out of auto thresholds; a volume with no finite voxel is refused.\n\n"
            "  -o, --output CASE          the case folder to write (created; a new case is built\n"
            "                             beside it and renamed into place, so a kill leaves no\n"
            "                             half-made folder)\n"
            "  --force                    replace CASE if it holds a case already (with its\n"
            "                             journal); a kill leaves the old case or the new one\n"
            CMD_WAIT_HELP
            CMD_THRESHOLD_HELP
            "  --min-volume ML            drop components under ML millilitres (default 0.5; 0.1\n"
            "                             with --whole-bone on a CT that holds only the bone,\n"
            "                             where a small component is a chip of bone)\n"
            "  --exclude-below-peak HU    drop components whose brightest voxel is under HU: the CT\n"
            "                             head holder (300-600 HU) goes with e.g. 1000\n"
            "  --keep N                   keep only the N largest components\n"
            "  --labels LABELMAP          take the fragments from a labelmap instead of the\n"
            "                             threshold: a NIfTI or NRRD on the CT's grid, label k =\n"
            "                             fragment k; or a 3D Slicer .seg.nrrd (one layer or\n"
            "                             multi-layer 4D): segment N (SegmentN_ keys) = fragment\n"
            "                             N+1 where its layer holds its LabelValue; a voxel in\n"
            "                             several segments goes to the first, and each pair's\n"
            "                             overlap is reported as a warning. The threshold then\n"
            "                             only shapes the probability maps\n"
            "  --whole-bone               the whole bone, cancellous interior included: on a CT\n"
            "                             that holds only the bone (0 elsewhere), every non-zero\n"
            "                             voxel connected to the threshold's cortex; on a full CT,\n"
            "                             the threshold's voxels; then --fill\n"
            "  --separate                 a real fracture CT to its bone and fragments: --whole-bone,\n"
            "                             then every bone is separated where it is broken\n"
            "                             (automatically), or from seeds:\n"
            CMD_SEEDS_HELP
            "                             (each point goes to the bone it lies in; a point on\n"
            "                             bone the mask missed grows the bone there)\n"
            "  --fill                     fill each fragment's enclosed interior (cancellous bone\n"
            "                             under the threshold inside the cortex), in 3D\n"
            "  --fill-slices              the same, also slice-wise along each axis (long bones,\n"
            "                             pieces; not a whole skull: its slices enclose the brain)\n"
            "  --ramp W                   probability map: 0.5 at the threshold rising to 1 at\n"
            "                             threshold + W/2 (default 200; 0 = 1 inside the mask);\n"
            "                             a voxel under the threshold that a fragment holds (its\n"
            "                             cancellous interior: --whole-bone, --fill, --labels)\n"
            "                             is 0.5, solid for the collision tests at tau_min 0.5\n"
            CMD_TAU_HELP
            "  --json                     one JSON object on stdout instead of the text: command,\n"
            "                             case, source, threshold, components (before filtering),\n"
            "                             fragments (id, voxels, volume_ml, peak, centroid_mm),\n"
            "                             filled_voxels (null without --fill),\n"
            "                             separated_fragments (new fragments; null without\n"
            "                             --separate), overlaps\n"
            "                             (fragment, other_fragment, voxels; null unless --labels\n"
            "                             is a .seg.nrrd),\n"
            "                             read_ms, segment_ms, fragments_ms, save_ms\n"
            "  --help                     this text\n");
}

typedef struct extra {
    const char *labels; /* --labels */
    int fill;           /* morph_fill's mode, 0: none */
    int whole_bone;     /* --whole-bone: bone_find instead of the threshold */
    int separate;       /* --separate: then case_separate_all */
    case_seed *seeds;   /* --seeds, --seed-file (malloc'd) */
    int nseeds;
} extra;

static int parse(int argc, char **argv, seg_params *p, cmd_case_args *c, extra *x)
{
    int rc;
    for (int i = 1; i < argc; i++) {
        if (cmd_case_arg("segment", argc, argv, &i, c, &rc)) {
            if (rc)
                return rc;
            continue;
        }
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        double d;
        if (cmd_seeds_option("segment", argc, argv, &i, &x->seeds, &x->nseeds, &rc)) {
            if (rc)
                return rc;
            continue;
        }
        if (!strcmp(a, "--separate")) {
            x->separate = x->whole_bone = 1;
            x->fill |= MORPH_FILL_3D;
            continue;
        }
        if (!strcmp(a, "--whole-bone")) {
            x->whole_bone = 1;
            x->fill |= MORPH_FILL_3D;
            continue;
        }
        if (!strcmp(a, "--fill")) {
            x->fill |= MORPH_FILL_3D;
            continue;
        }
        if (!strcmp(a, "--fill-slices")) {
            x->fill |= MORPH_FILL_3D | MORPH_FILL_SLICES;
            continue;
        }
        i++; /* every option takes a value; a missing one is reported by its branch */
        if (!strcmp(a, "--min-volume")) {
            if (!cmd_number(val, &d) || d < 0)
                return cmd_bad_value("segment", a, val, "a number of ml >= 0");
            p->min_volume_ml = p->min_volume_bone_only_ml = d;
        } else if (!strcmp(a, "--exclude-below-peak")) {
            if (!cmd_number(val, &d))
                return cmd_bad_value("segment", a, val, "a number (HU)");
            p->exclude_peak = 1;
            p->exclude_below_peak = d;
        } else if (!strcmp(a, "--keep")) {
            if (!cmd_number(val, &d) || !(d >= 1 && d <= 1e6 && d == (int)d))
                return cmd_bad_value("segment", a, val, "a whole number 1..1000000");
            p->keep = (int)d;
        } else if (!strcmp(a, "--labels")) {
            if (!val)
                return cmd_bad_value("segment", a, val, "a labelmap file (NIfTI, NRRD, .seg.nrrd)");
            x->labels = val;
        } else if (!strcmp(a, "--ramp")) {
            if (!cmd_number(val, &d) || d < 0)
                return cmd_bad_value("segment", a, val, "a number >= 0 (HU)");
            p->ramp = d;
        } else
            return cmd_usage_error("segment", "unknown option '%s'", a);
    }
    if (!c->in || !c->out)
        return cmd_usage_error("segment", "%s", "needs VOLUME and -o CASE");
    if (x->nseeds && !x->separate)
        return cmd_usage_error("segment", "%s", "--seeds and --seed-file go with --separate");
    if (x->separate && x->labels)
        return cmd_usage_error("segment", "%s", "--separate or --labels, not both");
    return cmd_tau_check("segment", &c->tau);
}

/* The brightest CT value of fragment i: the component's, or (after --separate made more fragments
 * than components) measured over its voxels. */
static double peak(const planning_case *c, const seg_result *r, int i)
{
    if (c->nfrag == r->ncomp)
        return r->comp[i].peak;
    float best = -INFINITY, id = (float)c->frag[i].id;
    size_t n = vol_count(c->labels);
    for (size_t v = 0; v < n; v++)
        if (c->labels->data[v] == id && c->ct->data[v] > best)
            best = c->ct->data[v];
    return best;
}

static void report(const planning_case *c, const seg_result *r, const char *labels)
{
    if (labels)
        printf("labels of %s: %d fragments\n", labels, c->nfrag);
    else
        printf("threshold %g: %d components, %d kept\n", r->threshold, r->raw_components, c->nfrag);
    for (int i = 0; i < c->nfrag; i++) {
        const frag *f = &c->frag[i];
        printf("  fragment %d: %zu voxels, %.2f ml, peak %g, centroid %.1f %.1f %.1f mm (LPS)\n",
               f->id, f->voxels, f->volume_ml, peak(c, r, i), f->centroid[0],
               f->centroid[1], f->centroid[2]);
    }
}

/* The overlaps of a .seg.nrrd's segments (null for any other source). */
static json_t *overlaps_json(const volio_segs *s)
{
    if (!s->segments)
        return json_null();
    json_t *a = json_array();
    for (int i = 0; a && i < s->noverlap; i++)
        json_array_append_new(a, json_pack("{s:i,s:i,s:I}", "fragment", s->overlap[i].fragment,
                                           "other_fragment", s->overlap[i].other, "voxels",
                                           (json_int_t)s->overlap[i].voxels));
    return a;
}

/* The .seg.nrrd's overlaps and unlisted voxels, as warnings on stderr. */
static void warn_segments(const volio_segs *s, const char *labels)
{
    for (int i = 0; i < s->noverlap; i++) {
        const volio_overlap *o = &s->overlap[i];
        fprintf(stderr, "fracnav segment: warning: %s: Segment%d and Segment%d overlap in %zu voxel%s: "
                        "given to fragment %d (the first segment), not fragment %d\n", labels,
                o->fragment - 1, o->other - 1, o->voxels, o->voxels == 1 ? "" : "s", o->fragment, o->other);
    }
    if (s->unlisted)
        fprintf(stderr, "fracnav segment: warning: %s: %zu voxels hold a value that no segment's "
                        "LabelValue lists; left as background\n", labels, s->unlisted);
}

static int report_json(const planning_case *c, const seg_result *r, const char *in, const char *out,
                       const double ms[4], long filled, int separated, const volio_segs *segs)
{
    json_t *o = jsonw_object("segment"), *frags = json_array();
    for (int i = 0; i < c->nfrag; i++) {
        const frag *f = &c->frag[i];
        json_array_append_new(frags, json_pack("{s:i,s:I,s:o,s:o,s:o}", "id", f->id, "voxels",
                                               (json_int_t)f->voxels, "volume_ml", jsonw_measure(f->volume_ml),
                                               "peak", jsonw_exact(peak(c, r, i)), "centroid_mm",
                                               jsonw_exact_array(f->centroid, 3)));
    }
    static const char *const steps[4] = {"read_ms", "segment_ms", "fragments_ms", "save_ms"};
    if (o) {
        jsonw_set(o, "case", jsonw_string(out));
        jsonw_set(o, "source", jsonw_string(in));
        jsonw_set(o, "threshold", jsonw_exact(r->threshold));
        jsonw_set(o, "components", json_integer(r->raw_components));
        jsonw_set(o, "fragments", frags);
        jsonw_set(o, "filled_voxels", filled >= 0 ? json_integer(filled) : json_null());
        jsonw_set(o, "separated_fragments", separated >= 0 ? json_integer(separated) : json_null());
        jsonw_set(o, "overlaps", overlaps_json(segs));
        for (int i = 0; i < 4; i++)
            jsonw_set(o, steps[i], jsonw_measure(ms[i]));
    } else
        json_decref(frags);
    return jsonw_print(o, stdout);
}

/* The case of the labels in the staging folder tmp, with --tau, --fill and --separate applied:
 * *filled voxels filled, *made fragments separated. NULL with fn_err. */
static planning_case *make_case(const char *tmp, const char *in, vol *ct, vol *labels, const seg_params *p,
                                const cmd_tau *tau, const extra *x, long *filled, int *made)
{
    planning_case *c = case_create(tmp, in, ct, labels, p);
    if (c)
        cmd_tau_apply(tau, &c->tau_min, &c->tau_max); /* checked by parse */
    for (int i = 0; c && x->fill && i < c->nfrag; i++) {
        long f = case_fill(c, c->frag[i].id, x->fill);
        if (f < 0) {
            case_free(c);
            c = NULL;
        } else
            *filled += f;
    }
    *made = c && x->separate ? case_separate_all(c, x->seeds, x->nseeds) : 0;
    if (*made < 0) {
        case_free(c);
        c = NULL;
    }
    return c;
}

/* What segment made, in words, with the times of its steps (ms: read, segmentation, fragments,
 * save). */
static void print_report(const planning_case *c, const seg_result *r, const extra *x, const char *out,
                         const double ms[4], long filled, int made)
{
    report(c, r, x->labels);
    if (x->fill)
        printf("filled %ld voxels of the fragments' enclosed interiors\n", filled);
    if (x->separate)
        printf("separated: %d new fragment%s (%s)\n", made, made == 1 ? "" : "s",
               x->nseeds ? "from seeds" : "automatically");
    printf("saved %s (read %.3f s, segmentation %.3f s, fragments %.3f s, save %.3f s)\n", out,
           ms[0] * 1e-3, ms[1] * 1e-3, ms[2] * 1e-3, ms[3] * 1e-3);
}

int cmd_segment(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    seg_params p;
    seg_defaults(&p);
    cmd_case_args args = {.threshold = &p.threshold, .threshold_auto = &p.threshold_auto};
    extra x = {0};
    int rc = parse(argc, argv, &p, &args, &x);
    if (rc) {
        free(x.seeds);
        return rc;
    }
    const char *in = args.in, *out = args.out;
    char tmp[4200];
    caselock *lock = cmd_lock_case("segment", out, 1, args.wait); /* a case there that --force replaces */
    if (!lock)
        return 1;
    cmd_warn_replaced_journal("segment", out, args.force);
    if (case_stage_begin(out, args.force, in, tmp, sizeof tmp) < 0) {
        free(x.seeds);
        fprintf(stderr, "fracnav segment: %s\n", fn_err_msg());
        caselock_release(lock);
        return 1;
    }
    int64_t t0 = fnclock_now_us();
    vol *ct = volio_read(in);
    int64_t t1 = fnclock_now_us();
    seg_result r = {0};
    volio_segs segs = {0};
    vol *imported = ct && x.labels ? volio_read_labels(x.labels, &segs) : NULL;
    int err = !ct || (x.labels && !imported);
    if (!err && x.labels && seg_from_labels(ct, imported, &p, &r) < 0) {
        fn_err_wrap(FN_EINVAL, "%s", x.labels);
        err = 1;
    }
    if (!err && !x.labels)
        err = (x.whole_bone ? bone_segment(ct, &p, &r) : seg_run(ct, &p, &r)) < 0;
    if (!err && !x.labels && x.whole_bone && bone_kind_of(ct) == BONE_ONLY_CT)
        p.min_volume_ml = p.min_volume_bone_only_ml; /* the floor used there, as case.json records it */
    if (!err)
        err = cmd_seg_found(ct, &p, &r, x.labels) < 0;
    if (err) {
        fprintf(stderr, "fracnav segment: %s\n", fn_err_msg());
        vol_free(ct);
        if (!r.labels)
            vol_free(imported);
        seg_result_free(&r);
        volio_segs_free(&segs);
        case_stage_abort(tmp);
        caselock_release(lock);
        free(x.seeds);
        return 1;
    }
    p.threshold = r.threshold;
    vol *labels = r.labels;
    r.labels = NULL;
    int64_t t2 = fnclock_now_us();
    long filled = 0;
    int made = 0;
    planning_case *c = make_case(tmp, in, ct, labels, &p, &args.tau, &x, &filled, &made);
    free(x.seeds);
    int64_t t3 = fnclock_now_us();
    if (!c || case_save(c) < 0 || case_stage_commit(tmp, out, args.force) < 0) {
        fprintf(stderr, "fracnav segment: %s\n", fn_err_msg());
        case_stage_abort(tmp);
        case_free(c);
        seg_result_free(&r);
        volio_segs_free(&segs);
        caselock_release(lock);
        return 1;
    }
    double ms[4] = {(double)(t1 - t0) * 1e-3, (double)(t2 - t1) * 1e-3, (double)(t3 - t2) * 1e-3,
                     (double)(fnclock_now_us() - t3) * 1e-3};
    if (r.nonfinite)
        fprintf(stderr, "fracnav segment: warning: %s: %zu voxels are NaN or infinite; left out of the "
                        "threshold and never bone\n", in, r.nonfinite);
    warn_segments(&segs, x.labels);
    if (args.json && (rc = report_json(c, &r, in, out, ms, x.fill ? filled : -1, x.separate ? made : -1, &segs)) < 0)
        fprintf(stderr, "fracnav segment: %s\n", fn_err_msg());
    else if (!args.json)
        print_report(c, &r, &x, out, ms, filled, made);
    case_free(c);
    seg_result_free(&r);
    volio_segs_free(&segs);
    caselock_release(lock);
    return rc < 0 ? 1 : 0;
}
