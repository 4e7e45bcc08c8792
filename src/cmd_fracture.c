/* fracnav fracture: a synthetic fracture with ground truth, as a case. */
#include "cmd.h"

#include "case.h"
#include "err.h"
#include "fracture.h"
#include "volio.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav fracture VOLUME -o CASE --seed N [options]\n\n"
            "Make a synthetic fracture with known ground truth from a CT. The bone (the largest\n"
            "component over the threshold) is cut by rough, fractal surfaces (not planes), a thin\n"
            "layer of bone can be lost at the gap, and every piece but the largest is moved by a\n"
            "random rigid transform. CASE/source.nii.gz is the fractured CT in the displaced\n"
            "configuration; the case's fragments are segmented there (poses start at identity)\n"
            "and case.json's truth holds, per fragment, the pose that puts it back. The same\n"
            "seed and options give the same case, byte for byte, on every machine.\n\n"
            "  -o, --output CASE      the case folder to write (created if missing)\n"
            "  --seed N               the random seed (required)\n"
            "  --pieces K             number of pieces, 2..16 (default 2)\n"
            "  --displace MM          translation of each moved piece (default 3)\n"
            "  --rotate DEG           rotation of each moved piece about its centroid (default 3)\n"
            "  --bone-loss MM         thickness of bone lost along each cut (default 0)\n"
            "  --roughness MM         RMS relief of the fracture surface (default 2)\n"
            "  --threshold HU         bone threshold (default 300)\n"
            CMD_TAU_HELP
            "  --help                 this text\n");
}

static int parse(int argc, char **argv, fracture_params *p, const char **in, const char **out)
{
    int have_seed = 0, rc;
    cmd_tau tau = {0};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        double d;
        if (a[0] != '-') {
            if (*in)
                return cmd_usage_error("fracture", "unexpected argument '%s'", a);
            *in = a;
            continue;
        }
        if (!val)
            return cmd_usage_error("fracture", "%s needs a value", a);
        i++;
        if (!strcmp(a, "-o") || !strcmp(a, "--output")) {
            *out = val;
            continue;
        }
        if (cmd_tau_option("fracture", a, val, &tau, &rc)) {
            if (rc)
                return rc;
            continue;
        }
        if (!cmd_number(val, &d))
            return cmd_usage_error("fracture", "%s needs a number", a);
        if (!strcmp(a, "--seed") && d >= 0 && d < 9007199254740992.0 && d == (double)(uint64_t)d) {
            p->seed = (uint64_t)d;
            have_seed = 1;
        } else if (!strcmp(a, "--pieces") && d == (int)d)
            p->pieces = (int)d;
        else if (!strcmp(a, "--displace"))
            p->displace_mm = d;
        else if (!strcmp(a, "--rotate"))
            p->rotate_deg = d;
        else if (!strcmp(a, "--bone-loss"))
            p->bone_loss_mm = d;
        else if (!strcmp(a, "--roughness"))
            p->roughness_mm = d;
        else if (!strcmp(a, "--threshold"))
            p->threshold = d;
        else
            return cmd_usage_error("fracture", "bad option or value near '%s'", a);
    }
    if (!*in || !*out || !have_seed)
        return cmd_usage_error("fracture", "%s", "needs VOLUME, -o CASE and --seed N");
    if (fracture_check(p) < 0 || cmd_tau_apply(&tau, &p->tau_min, &p->tau_max) < 0)
        return cmd_usage_error("fracture", "%s", fn_err_msg());
    return 0;
}

/* How far the truth moves the fragment's centroid, and by what angle. */
static void print_truth(const frag *f, const pose *truth)
{
    double back[3], d2 = 0;
    pose_apply(truth, f->centroid, back);
    for (int a = 0; a < 3; a++)
        d2 += (back[a] - f->centroid[a]) * (back[a] - f->centroid[a]);
    printf("fragment %d: %zu voxels; its truth moves the centroid %.2f mm and turns it %.2f deg\n",
           f->id, f->voxels, sqrt(d2), pose_angle_between(*truth, POSE_IDENTITY) * 180 / M_PI);
}

int cmd_fracture(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    fracture_params p;
    fracture_defaults(&p);
    const char *in = NULL, *out = NULL;
    int rc = parse(argc, argv, &p, &in, &out);
    if (rc)
        return rc;
    vol *ct = volio_read(in);
    fcase *c = ct ? fracture_make_case(ct, &p, out) : NULL;
    if (!c) {
        fprintf(stderr, "fracnav fracture: %s\n", fn_err_msg());
        vol_free(ct);
        return 1;
    }
    for (int i = 0; i < c->nfrag; i++)
        print_truth(&c->frag[i], &c->truth[i]);
    printf("saved %s\n", out);
    case_free(c);
    vol_free(ct);
    return rc;
}
