/* fracnav fracture: a synthetic fracture with ground truth, as a case. */
#include "cmd.h"

#include "case.h"
#include "caselock.h"
#include "err.h"
#include "fnclock.h"
#include "fracture.h"
#include "jsonw.h"
#include "volio.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav fracture VOLUME -o CASE --seed N [--json] [options]\n\n"
            "Make a synthetic fracture with known ground truth from a CT. The bone (the largest\n"
            "component over the threshold) is cut by rough, fractal surfaces (not planes) into\n"
            "connected pieces of at least 10%% of the bone each (1/(2K) for K > 6 pieces: 5%% for\n"
            "10), a thin layer of bone can be lost at the gap, and every piece but piece 1 is\n"
            "moved by a random rigid transform, outward from the bone's centre as in a\n"
            "comminuted fracture. CASE/source.nii.gz is the fractured CT in the displaced\n"
            "configuration; the case's fragments are segmented there (poses start at identity)\n"
            "and case.json's truth holds, per fragment, the pose that puts it back. The same seed\n"
            "and options give the same case, byte for byte, on every machine.\n\n"
            "  -o, --output CASE      the case folder to write (created; the case is built beside\n"
            "                         it and renamed into place, so a kill leaves no half-made\n"
            "                         folder)\n"
            "  --force                replace CASE if it holds a case already (with its journal);\n"
            "                         a kill leaves the old case or the new one\n"
            CMD_WAIT_HELP
            "  --seed N               the random seed (required)\n"
            "  --pieces K             number of pieces, 2..10 (default 2); a bone too small or\n"
            "                         thin to give K such pieces is an error that says so\n"
            "  --displace MM          how far each moved piece's centroid moves, away from the\n"
            "                         bone's centre (default 3); a piece that would land on\n"
            "                         another piece or on bright non-bone is moved on in steps of\n"
            "                         one voxel, in the outward direction that needs the fewest,\n"
            "                         so it can end farther: each fragment's distance is printed;\n"
            "                         one that lands past the CT's edge is kept whole (the grid\n"
            "                         grows to hold it, filled with the CT's lowest value)\n"
            "  --rotate DEG           rotation of each moved piece about its centroid (default 3)\n"
            "  --touching             each moved piece stays in contact with the bone: turned by\n"
            "                         --rotate, then pushed out only until it lands clear (a\n"
            "                         voxel apart; --displace is not used), as fragments lie in\n"
            "                         a real fracture CT: segmenting source.nii.gz joins them\n"
            "                         (see edit separate); the truth is kept as ever\n"
            "  --bone-loss MM         thickness of bone lost along each cut (default 0)\n"
            "  --roughness MM         RMS relief of the fracture surface (default 2; model 2: the\n"
            "                         zig-zag's amplitude)\n"
            "  --model 2              the second fracture model: two pieces, cut by a bent sheet\n"
            "                         with a zig-zag relief, the moved piece resampled trilinearly\n"
            "                         (partial volume at its edges, the fracture's included) and\n"
            "                         noise added to the CT (docs/reduction.md); no --touching or\n"
            "                         --bone-loss; a seed gives the same case on one machine\n"
            "                         (libm). Default: 1\n"
            "  --noise HU             model 2: the noise's standard deviation (default 20)\n"
            CMD_THRESHOLD_HELP
            "  --whole-bone           the bone cut is segment --whole-bone's, not the\n"
            "                         threshold's: on a CT that holds only the bone (0 outside),\n"
            "                         every non-zero voxel joined to the cortex, its cancellous\n"
            "                         interior included; the gaps left are then 0, not 40 HU\n"
            CMD_TAU_HELP
            "  --json                 one JSON object on stdout instead of the text: command, case,\n"
            "                         source, seed, pieces, threshold, fragments (id, voxels,\n"
            "                         volume_ml, displacement_mm and rotation_deg: what the truth\n"
            "                         undoes), read_ms, fracture_ms\n"
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
                {"--noise", &p->noise_hu, "a number of HU"}};
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++)
        if (!strcmp(opt, rows[i].name)) {
            *accepted = rows[i].accepted;
            return rows[i].field;
        }
    return NULL;
}

static int parse(int argc, char **argv, fracture_params *p, cmd_case_args *c)
{
    int have_seed = 0, rc;
    double *target;
    const char *accepted;
    for (int i = 1; i < argc; i++) {
        if (cmd_case_arg("fracture", argc, argv, &i, c, &rc)) {
            if (rc)
                return rc;
            continue;
        }
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        double d;
        if (!strcmp(a, "--touching") || !strcmp(a, "--whole-bone")) {
            *(a[2] == 't' ? &p->touching : &p->whole_bone) = 1;
            continue;
        }
        i++; /* every other option takes a value; a missing one is reported by its branch */
        if (!strcmp(a, "--seed")) {
            if (!cmd_number(val, &d) || !(d >= 0 && d < 9007199254740992.0 && d == (double)(uint64_t)d))
                return cmd_bad_value("fracture", a, val, "a whole number 0..2^53");
            p->seed = (uint64_t)d;
            have_seed = 1;
        } else if (!strcmp(a, "--model")) {
            if (!cmd_number(val, &d) || !(d == 1 || d == 2))
                return cmd_bad_value("fracture", a, val, "1 or 2");
            p->model = (int)d;
        } else if (!strcmp(a, "--pieces")) {
            if (!cmd_number(val, &d) || !(d >= 2 && d <= 10 && d == (int)d))
                return cmd_bad_value("fracture", a, val, "a whole number 2..10");
            p->pieces = (int)d;
        } else if (!(target = number_option(p, a, &accepted)))
            return cmd_usage_error("fracture", "unknown option '%s'", a);
        else if (!cmd_number(val, &d))
            return cmd_bad_value("fracture", a, val, accepted);
        else
            *target = d;
    }
    if (!c->in || !c->out || !have_seed)
        return cmd_usage_error("fracture", "%s", "needs VOLUME, -o CASE and --seed N");
    if (fracture_check(p) < 0 || cmd_tau_apply(&c->tau, &p->tau_min, &p->tau_max) < 0)
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

static int print_json(const planning_case *c, const fracture_params *p, const char *in, const char *out,
                      double read_ms, double fracture_ms)
{
    json_t *o = jsonw_object("fracture"), *frags = json_array();
    for (int i = 0; i < c->nfrag; i++) {
        const frag *f = &c->frag[i];
        double deg = pose_angle_between(c->truth[i], POSE_IDENTITY) * 180 / M_PI;
        json_array_append_new(frags, json_pack("{s:i,s:I,s:o,s:o,s:o}", "id", f->id, "voxels",
                                               (json_int_t)f->voxels, "volume_ml", jsonw_measure(f->volume_ml),
                                               "displacement_mm",
                                               jsonw_measure(fracture_truth_shift(&c->truth[i], f->centroid)),
                                               "rotation_deg", jsonw_measure(deg)));
    }
    if (o) {
        jsonw_set(o, "case", jsonw_string(out));
        jsonw_set(o, "source", jsonw_string(in));
        jsonw_set(o, "seed", json_integer((json_int_t)p->seed));
        jsonw_set(o, "pieces", json_integer(p->pieces));
        jsonw_set(o, "threshold", jsonw_exact(p->threshold));
        jsonw_set(o, "fragments", frags);
        jsonw_set(o, "read_ms", jsonw_measure(read_ms));
        jsonw_set(o, "fracture_ms", jsonw_measure(fracture_ms));
    } else
        json_decref(frags);
    return jsonw_print(o, stdout);
}

int cmd_fracture(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    fracture_params p;
    fracture_defaults(&p);
    cmd_case_args args = {.threshold = &p.threshold, .threshold_auto = &p.threshold_auto};
    int rc = parse(argc, argv, &p, &args);
    if (rc)
        return rc;
    const char *in = args.in, *out = args.out;
    char tmp[4200] = "";
    caselock *lock = cmd_lock_case("fracture", out, 1, args.wait); /* a case there that --force replaces */
    if (!lock)
        return 1;
    cmd_warn_replaced_journal("fracture", out, args.force);
    int64_t t0 = fnclock_now_us();
    vol *ct = case_stage_begin(out, args.force, NULL, tmp, sizeof tmp) == 0 ? volio_read(in) : NULL;
    int64_t t1 = fnclock_now_us();
    /* The whole case, source.nii.gz included, is written in tmp and renamed into place at once. */
    planning_case *c = ct ? fracture_make_case(ct, &p, tmp) : NULL;
    int64_t t2 = fnclock_now_us();
    if (!c || case_stage_commit(tmp, out, args.force) < 0) {
        fprintf(stderr, "fracnav fracture: %s\n", fn_err_msg());
        case_stage_abort(tmp);
        case_free(c);
        vol_free(ct);
        caselock_release(lock);
        return 1;
    }
    if (args.json && (rc = print_json(c, &p, in, out, (double)(t1 - t0) * 1e-3, (double)(t2 - t1) * 1e-3)) < 0)
        fprintf(stderr, "fracnav fracture: %s\n", fn_err_msg());
    else if (!args.json) {
        for (int i = 0; i < c->nfrag; i++)
            print_truth(&c->frag[i], &c->truth[i]);
        printf("saved %s\n", out);
    }
    case_free(c);
    vol_free(ct);
    caselock_release(lock);
    return rc < 0 ? 1 : 0;
}
