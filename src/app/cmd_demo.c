/* fracnav demo: the whole workflow on the example CT, with pictures. */
#include "case.h"
#include "cmd.h"
#include "err.h"
#include "fnrec.h"
#include "fnclock.h"
#include "fracture.h"
#include "script.h"
#include "seg.h"
#include "snap.h"
#include "vol.h"
#include "volio.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <stdint.h>
#include <sys/stat.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav demo [CT] [-o DIR] [--tau-min T] [--tau-max T]\n\n"
            "Runs fracnav's workflow on a CT (default: the example skull CT that .ci/setup caches,\n"
            "$FRACNAV_DATA/Cranium.inv3 or /var/cache/fracnav/Cranium.inv3) and writes its results to\n"
            "DIR (default ./fracnav-demo):\n"
            "  1. segments the bone at 300 HU into fragments (26-connected components) and saves the\n"
            "     case in DIR/case; fragments that never reach 1000 HU (the CT head holder) are shown\n"
            "     but marked as not bone;\n"
            "  2. renders the fragments, each in its colour, seen from the front, the right and below:\n"
            "     DIR/segmentation-{front,right,below}.png;\n"
            "  3. breaks the skull in two along a rough fractal surface and displaces one piece by a\n"
            "     known rigid transform: a synthetic fracture with ground truth, DIR/fracture\n"
            "     (picture: DIR/fracture-right.png);\n"
            "  4. renders a scripted 3D-mouse session with the virtual SpaceNavigator (push the loose\n"
            "     piece head-on into the other, then back off; DIR/head-on.fnrec) and replays it\n"
            "     through the collision-checked navigation loop, as `fracnav replay` does.\n\n"
            "  -o DIR                     where the results go (default ./fracnav-demo)\n" CMD_TAU_HELP
            "                             (kept in both cases the demo saves)\n");
}

static int fail(const char *what)
{
    fprintf(stderr, "fracnav demo: %s%s%s\n", what ? what : "", what ? ": " : "", fn_err_msg());
    return 1;
}

/* Step 1: segmentation, saved as a case. Takes ownership of ct. */
static fcase *segment(const char *ct_path, vol *ct, const char *dir, const cmd_tau *tau)
{
    seg_params sp;
    seg_defaults(&sp);
    sp.threshold = 300;
    int64_t t0 = fnclock_now_us();
    seg_result sr;
    if (seg_run(ct, &sp, &sr) < 0) {
        vol_free(ct);
        return NULL;
    }
    double t_seg = (double)(fnclock_now_us() - t0) * 1e-6;
    printf("1. segmentation at %.0f HU: %d components, %d kept (>= %.2f ml) in %.0f ms\n", sr.threshold,
           sr.raw_components, sr.ncomp, sp.min_volume_ml, t_seg * 1e3);
    vol *labels = sr.labels;
    sr.labels = NULL;
    char casedir[4200];
    snprintf(casedir, sizeof casedir, "%s/case", dir);
    fcase *c = case_create(casedir, ct_path, ct, labels, &sp);
    if (!c) {
        seg_result_free(&sr);
        return NULL;
    }
    printf("   %-3s %8s %7s %7s  %-22s %-20s %s\n", "id", "voxels", "ml", "peak HU", "centroid (LPS mm)",
           "long axis", "kind");
    for (int i = 0; i < sr.ncomp && i < c->nfrag; i++) {
        const seg_component *sc = &sr.comp[i];
        const frag *f = &c->frag[case_find(c, sc->label)];
        printf("   %-3d %8zu %7.1f %7.0f  %6.1f %6.1f %6.1f    %5.2f %5.2f %5.2f    %s\n", sc->label, sc->voxels,
               sc->volume_ml, sc->peak, f->centroid[0], f->centroid[1], f->centroid[2], f->axes[0][0],
               f->axes[1][0], f->axes[2][0], sc->peak < 1000 ? "not bone (peak < 1000 HU: head holder)" : "bone");
    }
    seg_result_free(&sr);
    cmd_tau_apply(tau, &c->tau_min, &c->tau_max); /* checked with the options */
    if (case_save(c) < 0) {
        case_free(c);
        return NULL;
    }
    printf("   saved the case in %s (case.json, labels.nii.gz)\n", casedir);
    return c;
}

/* Step 2: pictures of the labelled fragments. */
static int pictures(const fcase *c, const char *dir)
{
    int maxid = 0;
    for (int i = 0; i < c->nfrag; i++)
        if (c->frag[i].id > maxid)
            maxid = c->frag[i].id;
    uint8_t(*rgb)[3] = calloc((size_t)maxid + 1, sizeof *rgb);
    if (!rgb)
        return fn_err_set(FN_ENOMEM, "out of memory");
    for (int i = 0; i < c->nfrag; i++)
        memcpy(rgb[c->frag[i].id], c->frag[i].rgb, 3);
    /* On the example CT's grid (i to the left, j to the front, k up) these views keep the
     * patient's handedness: from the right (low i), the front (high j) and the feet (low k). */
    static const char *names[3] = {"right", "front", "below"};
    static const int from_end[3] = {0, 1, 0};
    int rc = 0;
    printf("2. pictures:");
    for (int axis = 0; axis < 3 && rc == 0; axis++) {
        char path[4200];
        snprintf(path, sizeof path, "%s/segmentation-%s.png", dir, names[axis]);
        rc = snap_labels_png(c->labels, c->ct, (const uint8_t(*)[3])rgb, maxid + 1, axis, from_end[axis], path);
        if (rc == 0)
            printf(" %s", path);
    }
    printf("\n");
    free(rgb);
    return rc;
}

/* Step 3: a synthetic fracture of the segmented CT, with its ground truth. */
static int fracture(const fcase *seg, const char *dir, const cmd_tau *tau)
{
    fracture_params fp;
    fracture_defaults(&fp);
    cmd_tau_apply(tau, &fp.tau_min, &fp.tau_max);
    char casedir[4200], png[4200];
    snprintf(casedir, sizeof casedir, "%s/fracture", dir);
    int64_t t0 = fnclock_now_us();
    fcase *c = fracture_make_case(seg->ct, &fp, casedir);
    if (!c)
        return -1;
    printf("3. synthetic fracture (seed %llu) in %.1f s, saved in %s:\n", (unsigned long long)fp.seed,
           (double)(fnclock_now_us() - t0) * 1e-6, casedir);
    for (int i = 0; i < c->nfrag; i++) {
        const frag *f = &c->frag[i];
        pose t = c->truth[i];
        printf("   fragment %d: %zu voxels%s; ground truth moves its centroid back %.2f mm and turns it "
               "%.2f deg\n", f->id, f->voxels, i == c->fixed ? " (fixed)" : "",
               fracture_truth_shift(&t, f->centroid), pose_angle_between(t, POSE_IDENTITY) * 57.29577951308232);
    }
    uint8_t rgb[3][3] = {{0, 0, 0}};
    for (int i = 0; i < c->nfrag && c->frag[i].id < 3; i++)
        memcpy(rgb[c->frag[i].id], c->frag[i].rgb, 3);
    snprintf(png, sizeof png, "%s/fracture-right.png", dir);
    int rc = snap_labels_png(c->labels, c->ct, (const uint8_t(*)[3])rgb, 3, 0, 0, png);
    if (rc == 0)
        printf("   picture: %s\n", png);
    case_free(c);
    return rc;
}

/* Step 4: a scripted session on the virtual SpaceNavigator, replayed through the loop. */
static const char head_on[] = "wait 100 ms\n"
                              "translate -x 30 mm over 1.5 s\n"
                              "wait 200 ms\n"
                              "translate +x 5 mm over 0.5 s\n";

static int session(const char *dir)
{
    char rec[4200], casedir[4200];
    snprintf(rec, sizeof rec, "%s/head-on.fnrec", dir);
    snprintf(casedir, sizeof casedir, "%s/fracture", dir);
    script *s = NULL;
    int rc = script_parse(head_on, sizeof head_on - 1, "demo script", &s);
    if (rc < 0)
        return rc;
    fnrec *r = script_render(s, sim_profile_find("spacenavigator"));
    free(s);
    if (!r)
        return -1;
    rc = fnrec_save(r, rec);
    fnrec_free(r);
    if (rc < 0)
        return rc;
    printf("4. a scripted session on the virtual SpaceNavigator (%s), replayed on the fracture:\n   ", rec);
    fflush(stdout);
    char *args[] = {"replay", casedir, rec, "--no-journal", NULL};
    return cmd_replay(4, args) == 0 ? 0 : fn_err_set(FN_EINVAL, "the replay failed");
}

int cmd_demo(int argc, char **argv)
{
    const char *ct_path = NULL, *dir = "fracnav-demo";
    cmd_tau tau = {0};
    int rc;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(argv[i], "-o") && i + 1 < argc) {
            dir = argv[++i];
        } else if (cmd_tau_option("demo", argv[i], i + 1 < argc ? argv[i + 1] : NULL, &tau, &rc)) {
            if (rc)
                return rc;
            i++;
        } else if (argv[i][0] == '-' || ct_path) {
            fprintf(stderr, "fracnav demo: unexpected argument '%s'\n", argv[i]);
            usage(stderr);
            return 2;
        } else {
            ct_path = argv[i];
        }
    }
    if ((rc = cmd_tau_check("demo", &tau)) != 0)
        return rc;
    int example = !ct_path; /* only the example CT comes from .ci/setup */
    if (example)
        ct_path = cmd_example_ct();
    if (mkdir(dir, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "fracnav demo: cannot create %s: %s\n", dir, strerror(errno));
        return 1;
    }
    int64_t t0 = fnclock_now_us();
    vol *ct = volio_read(ct_path);
    if (!ct) {
        fprintf(stderr, "fracnav demo: %s\n%s", fn_err_msg(),
                example ? "(the example CT comes with the README's first command, .ci/setup)\n" : "");
        return 1;
    }
    printf("fracnav demo on %s\n0. CT: %dx%dx%d voxels, %.3fx%.3fx%.3f mm, read in %.0f ms\n", ct_path,
           ct->dim[0], ct->dim[1], ct->dim[2], ct->spacing[0], ct->spacing[1], ct->spacing[2],
           (double)(fnclock_now_us() - t0) * 1e-3);
    fcase *c = segment(ct_path, ct, dir, &tau);
    if (!c)
        return fail("segmentation");
    rc = pictures(c, dir);
    if (rc < 0) {
        case_free(c);
        return fail("pictures");
    }
    rc = fracture(c, dir, &tau);
    case_free(c);
    if (rc < 0)
        return fail("fracture");
    if (session(dir) < 0)
        return fail("session");
    printf("\nNext: steer it yourself with `fracnav navigate %s/fracture` (a 3D mouse, or --device "
           "keyboard).\n", dir);
    return 0;
}
