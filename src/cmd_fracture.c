/* fracnav fracture: a synthetic fracture with ground truth, as a case. */
#include "cmd.h"

#include "case.h"
#include "case_journal.h"
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
            "  -o, --output CASE      the case folder to write (created; the case is built beside\n"
            "                         it and renamed into place, so a kill leaves no half-made\n"
            "                         folder)\n"
            "  --force                replace CASE if it holds a case already (with its journal);\n"
            "                         a kill leaves the old case or the new one\n"
            "  --seed N               the random seed (required)\n"
            "  --pieces K             number of pieces, 2..16 (default 2)\n"
            "  --displace MM          how far each moved piece's centroid moves (default 3); a piece\n"
            "                         that would land on another piece or on bright non-bone is\n"
            "                         pushed on along its cut's normal in 1 mm steps, so it can end\n"
            "                         farther: each fragment's distance is printed\n"
            "  --rotate DEG           rotation of each moved piece about its centroid (default 3)\n"
            "  --bone-loss MM         thickness of bone lost along each cut (default 0)\n"
            "  --roughness MM         RMS relief of the fracture surface (default 2)\n"
            "  --threshold HU         bone threshold (default 300)\n"
            CMD_TAU_HELP
            "  --help                 this text\n");
}

/* The fracture_params field of a plain-number option and what it accepts, or NULL. Ranges are
 * fracture_check's. */
static double *number_option(fracture_params *p, const char *opt, const char **accepted)
{
    const struct {
        const char *name;
        double *field;
        const char *accepted;
    } rows[] = {{"--displace", &p->displace_mm, "a number of mm"},
                {"--rotate", &p->rotate_deg, "a number of degrees"},
                {"--bone-loss", &p->bone_loss_mm, "a number of mm"},
                {"--roughness", &p->roughness_mm, "a number of mm"},
                {"--threshold", &p->threshold, "a number (HU)"}};
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++)
        if (!strcmp(opt, rows[i].name)) {
            *accepted = rows[i].accepted;
            return rows[i].field;
        }
    return NULL;
}

static int parse(int argc, char **argv, fracture_params *p, const char **in, const char **out,
                 int *force)
{
    int have_seed = 0, rc;
    double *target;
    const char *accepted;
    cmd_tau tau = {0};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        double d;
        if (!strcmp(a, "--force")) {
            *force = 1;
            continue;
        }
        if (a[0] != '-') {
            if (*in)
                return cmd_usage_error("fracture", "unexpected argument '%s'", a);
            *in = a;
            continue;
        }
        i++; /* every option takes a value; a missing one is reported by its branch */
        if (!strcmp(a, "-o") || !strcmp(a, "--output")) {
            if (!val)
                return cmd_bad_value("fracture", a, val, "a folder");
            *out = val;
        } else if (cmd_tau_option("fracture", a, val, &tau, &rc)) {
            if (rc)
                return rc;
        } else if (!strcmp(a, "--seed")) {
            if (!cmd_number(val, &d) || !(d >= 0 && d < 9007199254740992.0 && d == (double)(uint64_t)d))
                return cmd_bad_value("fracture", a, val, "a whole number 0..2^53");
            p->seed = (uint64_t)d;
            have_seed = 1;
        } else if (!strcmp(a, "--pieces")) {
            if (!cmd_number(val, &d) || !(d >= 2 && d <= 16 && d == (int)d))
                return cmd_bad_value("fracture", a, val, "a whole number 2..16");
            p->pieces = (int)d;
        } else if (!(target = number_option(p, a, &accepted)))
            return cmd_usage_error("fracture", "unknown option '%s'", a);
        else if (!cmd_number(val, &d))
            return cmd_bad_value("fracture", a, val, accepted);
        else
            *target = d;
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
    printf("fragment %d: %zu voxels; ground truth moves its centroid back %.2f mm and turns it %.2f deg\n",
           f->id, f->voxels, fracture_truth_shift(truth, f->centroid),
           pose_angle_between(*truth, POSE_IDENTITY) * 180 / M_PI);
}

/* --force replaces a case with its journal: poses it holds beyond case.json go too. */
static void warn_journal(const char *dir, int force)
{
    size_t n = force ? case_journal_pending(dir) : 0;
    if (n)
        fprintf(stderr, "fracnav fracture: warning: %s/journal holds %zu poses not saved in "
                        "case.json; they go with the case this replaces\n", dir, n);
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
    int force = 0;
    int rc = parse(argc, argv, &p, &in, &out, &force);
    if (rc)
        return rc;
    char tmp[4200] = "";
    warn_journal(out, force);
    vol *ct = case_stage_begin(out, force, NULL, tmp, sizeof tmp) == 0 ? volio_read(in) : NULL;
    /* The whole case, source.nii.gz included, is written in tmp and renamed into place at once. */
    fcase *c = ct ? fracture_make_case(ct, &p, tmp) : NULL;
    if (!c || case_stage_commit(tmp, out) < 0) {
        fprintf(stderr, "fracnav fracture: %s\n", fn_err_msg());
        case_stage_abort(tmp);
        case_free(c);
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
