/* reduce: the methods' names, the defaults, the tuning table, and the errors against a ground
 * truth (see reduce.h). The stages are in reduce_voi.c, reduce_prealign.c, reduce_fit.c and
 * reduce_order.c. */
#include "reduce.h"
#include "reduce_impl.h"

#include "case.h"
#include "err.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846

const reduce_tuning reduce__tune = {
    .zone_cell_mm = 2.0,
    .zone_reach_mm = 64,
    .zone_delta_mm = {3, 2},
    .zone_margin_mm = 6,
    .zone_grow = 1.25,
    .zone_grow_stages = 2,
    .band_reach_mm = 1.5,
    .band_corner = 1.45,
    .tolerance_voxels = 0.45,
    .collide_cost = 1.0,
    .push_step_mm = 0.05,
    .push_max_mm = 5.0,
    .placed_mm = 10.0,
    .prealign_turn_deg = 30,
    .prealign_span_mm = 10,
    .prealign_box_mm = 5,
    .approach_mm = 10.0,
    .slide_step_mm = 0.1,
    .slide_halvings = 8,
    /* 5 mm: a small piece still turns by steps that move its surface; 500 mm: a huge one still
     * turns at all */
    .scale_min_mm = 5,
    .scale_max_mm = 500,
    .bound = 40,
    .nlopt_step = 2,
    /* the voxel metric has small ripples that can hold a line search: restarts with fresh
     * directions and other steps */
    .powell_step = {1, 3, 0.3},
    .gain = 1e-7,
    .first_xtol = 5,
    .global_deg = 15,
    .global_mm = 8,
    /* the fine level: on the coarse one (2x2x2 voxels a cell, its band a box of 26) the candidates
     * of real pelvic pieces ended 6-14 mm from the truth, none nearer (bench reduce --labels:
     * 0.933 -> 0.950 back on the fine level) */
    .global_coarse = 0,
    /* with the global check after every fit (bench reduce --labels --starts 40): 300 evaluations
     * 0.975 back, 200 0.975 at 12% less CPU, 150 0.958 */
    .global_evals = 200,
    .global_xtol_mm = 0.1,
    .global_keep = 2,
    .global_margin = 0.01,
    /* the metric's basin is narrow: the first stage also starts turned this much, the best wins */
    .start_deg = 8.0,
    .wide_starts = 1.5,
    .wall_mm = 1,
    .wall_deg = 1,
    /* bench reduce --ct CT_pitch.nii.gz: fits in a rival basin ended 3.4 mm and 2.7 degrees off */
    .rival_metric = 0.002,
    .rival_mm = 1,
    .rival_deg = 1,
    .hop_elongation = 4.0,
    .hop_deg = 3.0,
    .hop_mm = 1.5,
    /* bench reduce --labels (30 fits) and the skull (20), back_rate and success, median s: no hops
     * 0.77 0.19 s, 0.95 0.26 s; turns and moves, each fit to the end 0.93 0.47 s; capped at 60
     * evaluations 0.90 0.29 s, 0.95 0.43 s; moves only at 40: 0.90 0.21 s, 0.95 0.29 s; at 25:
     * 0.77; turns only at 60: 0.87. With the cancellous bone solid and the polish (2026-11-27):
     * moves only at 40 0.933 0.21 s, at 50 0.967 0.22 s, at 60 0.967 0.23 s (80-120: 0.967,
     * 0.25-0.28 s) */
    .hop_evals = 50,
    /* a strict margin for pieces that are not long: CT_pitch success 0.90 -> 0.95 */
    .hop_margin = 1e-4,
    .long_margin = 1e-7,
    /* the polish's steps (parameter units: about a millimetre of the fracture surface's motion)
     * and its sweeps at most per step; from 0.4 the demo's fit took 12 evaluations more to the
     * same pose */
    .polish_step = {0.2, 0.1, 0.05, 0.025},
    .polish_sweeps = 4,
    .polish_round = 2,
    /* the example CT's head holder lies 18 mm and more from the skull; the pieces of a fracture
     * (fracture, edit separate) lie within a voxel of each other somewhere */
    .touch_mm = 4,
};

static const char *method_names[REDUCE_METHODS] = {"powell", "praxis", "sbplx", "bobyqa"};

const char *reduce_method_name(reduce_method m)
{
    return m >= 0 && m < REDUCE_METHODS ? method_names[m] : "?";
}

int reduce_method_parse(const char *s)
{
    for (int i = 0; s && i < REDUCE_METHODS; i++)
        if (!strcmp(s, method_names[i]))
            return i;
    return -1;
}

void reduce_defaults(reduce_opts *o)
{
    memset(o, 0, sizeof *o);
    o->method = REDUCE_PRAXIS;
    o->count = REDUCE_TRILINEAR;
    o->prealign = 1;
    o->tau_min = CASE_TAU_MIN;
    o->tau_max = CASE_TAU_MAX;
    o->tolerance_mm = 0.5;
    o->settle_mm = 0.25;
    o->xtol_mm = 0.01;
    o->max_eval = 4000;
    o->voi_max_mm = 0;
    o->band_mm = 1;
    o->trust_mm = 12;
    o->starts = 3;
    o->trust_deg = 18;
    o->coarse = 0;
    o->axis_scale = 1;
    o->hops = 3;
    o->polish = 1;
    o->global_check = 1;
    o->threads = 2;
}

void reduce_result_free(reduce_result *r)
{
    if (r) {
        free(r->history);
        r->history = NULL;
        r->nhistory = 0;
    }
}

/* ---- ground truth -------------------------------------------------------------------------- */

int reduce_truth_errors(const planning_case *c, int fi, int mi, double *rot_deg, double *trans_mm, double *tre_mm)
{
    if (!c || !c->has_truth || fi < 0 || mi < 0 || fi >= c->nfrag || mi >= c->nfrag)
        return fn_err_set(FN_EINVAL, "reduce: the case has no ground truth");
    const frag *f = &c->frag[fi];
    pose want = pose_compose(f->pose, pose_compose(pose_inverse(c->truth[fi]), c->truth[mi]));
    reduce_errors(f, &c->frag[mi], &want, rot_deg, trans_mm, tre_mm);
    return 0;
}

void reduce_errors(const frag *f, const frag *m, const pose *want, double *rot_deg, double *trans_mm,
                   double *tre_mm)
{
    *rot_deg = pose_angle_between(m->pose, *want) * 180 / PI;
    double a[3], b[3];
    pose_apply(&m->pose, m->centroid, a);
    pose_apply(want, m->centroid, b);
    *trans_mm = sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
    /* fracture-surface voxels: in the true pose, within 1.5 voxels of the fixed fragment's bone.
     * Affine maps from m's crop index: D to the displacement between the two poses (mm), F to f's
     * crop index at the true pose. */
    pose at = pose_compose(m->pose, m->home), tw = pose_compose(*want, m->home);
    pose to_f = pose_compose(pose_inverse(pose_compose(f->pose, f->home)), tw);
    double Ra[3][3], Rw[3][3], Rf[3][3], D[3][3], dT[3], F[3][3], fT[3];
    pose_to_matrix(&at, Ra);
    pose_to_matrix(&tw, Rw);
    pose_to_matrix(&to_f, Rf);
    for (int r = 0; r < 3; r++) {
        for (int c = 0; c < 3; c++) {
            D[r][c] = (Ra[r][c] - Rw[r][c]) * m->spacing[c];
            F[r][c] = Rf[r][c] * m->spacing[c] / f->spacing[r];
        }
        dT[r] = at.t[r] - tw.t[r];
        fT[r] = to_f.t[r] / f->spacing[r] + 0.5; /* + 0.5: nearest voxel by floor */
    }
    double s_all = 0, s_surf = 0;
    size_t n_all = 0, n_surf = 0, idx = 0;
    const size_t sy = (size_t)f->dim[0], sz = (size_t)f->dim[0] * f->dim[1];
    for (int k = 0; k < m->dim[2]; k++)
        for (int j = 0; j < m->dim[1]; j++)
            for (int i = 0; i < m->dim[0]; i++, idx++) {
                if (!m->prob[idx])
                    continue;
                double d2 = 0;
                int q[3];
                for (int r = 0; r < 3; r++) {
                    double e = D[r][0] * i + D[r][1] * j + D[r][2] * k + dT[r];
                    d2 += e * e;
                    q[r] = (int)floor(F[r][0] * i + F[r][1] * j + F[r][2] * k + fT[r]);
                }
                s_all += d2;
                n_all++;
                int near = 0;
                for (int dz = -1; dz <= 1 && !near; dz++)
                    for (int dy = -1; dy <= 1 && !near; dy++)
                        for (int dx = -1; dx <= 1 && !near; dx++) {
                            int x = q[0] + dx, y = q[1] + dy, z = q[2] + dz;
                            if (x >= 0 && y >= 0 && z >= 0 && x < f->dim[0] && y < f->dim[1] && z < f->dim[2])
                                near = f->prob[(size_t)z * sz + (size_t)y * sy + (size_t)x] != 0;
                        }
                if (near) {
                    s_surf += d2;
                    n_surf++;
                }
            }
    *tre_mm = n_surf ? sqrt(s_surf / (double)n_surf) : n_all ? sqrt(s_all / (double)n_all) : 0;
}

double reduce_tolerance(const reduce_opts *o, const frag *const *f, int n)
{
    double smin = INFINITY;
    for (int i = 0; i < n; i++)
        for (int a = 0; a < 3; a++)
            smin = fmin(smin, f[i]->spacing[a]);
    return fmin(o->tolerance_mm, reduce__tune.tolerance_voxels * smin);
}
