/* fracture: synthetic fractures with known ground truth, made from a real CT.
 *
 * The bone (the largest component at `threshold`, or at Otsu's when threshold_auto; with
 * whole_bone, the largest of bone_find's whole bone, as `segment --whole-bone` finds it) is cut
 * pieces-1 times; each cut splits the currently largest piece with a rough surface: a plane
 * (normal near the piece's main axis, through a point near its centroid) displaced along its
 * normal by fractal value noise (fBm, 4 octaves). The new piece of a cut is its smaller side.
 * Each side is made one connected piece (islands the rough surface leaves join the other side)
 * and keeps at least fracture_min_piece voxels, or the cut is tried again (32 times, then an
 * error). bone_loss_mm of bone around each cut is replaced by `fill` (soft tissue). Piece 1
 * (what is left of the first piece) stays fixed; every other piece is moved by a random rigid
 * transform: rotation of rotate_deg about its centroid, translation of displace_mm outward from
 * the bone's centre (perturbed), and, while it would land on another piece or on bright non-bone,
 * on in steps of one voxel (the smallest spacing) along the outward direction that clears it in
 * the fewest steps. It is resampled (nearest neighbour) into the output CT, which shows the
 * DISPLACED configuration; where a piece left, `fill` is written. The displaced labels are built
 * from the pieces, not re-segmented, so touching pieces stay apart. A piece that lands past the
 * grid's edge is kept whole: the grid grows to hold it (new voxels: the CT's lowest value), and
 * where a piece lands never depends on the grid's size.
 * truth[i] maps piece i+1's displaced position back to where it belongs (identity for piece 1).
 *
 * Randomness comes only from splitmix64 seeded with `seed`, and the arithmetic uses + - * / and
 * sqrt (own polynomial sin/cos), so one seed gives the same case on every IEEE-754 machine. */
#ifndef FN_FRACTURE_H
#define FN_FRACTURE_H

#include "pose.h"
#include "vol.h"

#include <stddef.h>
#include <stdint.h>

typedef struct fracture_params {
    uint64_t seed;
    int pieces;           /* 2..10 */
    double displace_mm;   /* translation of each moved piece before any push-out */
    double rotate_deg;    /* rotation of each moved piece about its centroid */
    double bone_loss_mm;  /* thickness of the bone layer lost at each cut; 0 none */
    double roughness_mm;  /* RMS of the surface's displacement along its normal */
    double wavelength_mm; /* of the coarsest noise octave */
    double threshold;     /* bone threshold (HU), unless threshold_auto */
    int threshold_auto;   /* seg_params' meaning: 1 Otsu, 2 Otsu over the brighter class */
    int whole_bone;       /* 1: the bone is bone_find's (segment --whole-bone: on a CT that holds
                           * only the bone, its cancellous interior too), not the threshold's;
                           * on such a CT, fill is then 0 (its outside) */
    double fill;          /* value written where bone was removed or left (soft tissue, HU) */
    double tau_min, tau_max; /* the case's hierarchy thresholds */
    int touching;         /* 1: each moved piece is turned and then pushed out only as far as it
                           * must to land clear, so it stays in contact (a voxel apart, one
                           * component at the threshold) with the piece it was cut from;
                           * displace_mm is then not used */
    int model;            /* 1: the rough plane above (fracture.c); 2: fracture_model2 */
    double noise_hu;      /* model 2: standard deviation of the noise added to the CT (HU) */
} fracture_params;

typedef struct fracture_result {
    vol *ct;      /* the fractured CT (displaced configuration), on the input grid or, where a
                   * moved piece landed past its edge, that grid grown (same spacing and
                   * directions, whole voxels added before or after); owned */
    vol *labels;  /* pieces 1..n in the displaced configuration, on the same grid; owned */
    vol *cut;     /* pieces 1..n before displacement (after bone loss), on the input grid; owned */
    int pieces;
    double threshold; /* the bone threshold used (Otsu's when threshold_auto) */
    pose *truth;  /* pieces entries: displaced (home) world -> original world; owned */
    pose *moved;  /* pieces entries: the applied displacement (original -> displaced); owned */
} fracture_result;

/* Defaults: 2 pieces, 3 mm, 3 degrees, no bone loss, roughness 2 mm, wavelength 16 mm, 300 HU
 * (threshold_auto 0), fill 40 HU, seed 1, model 1 (noise 20 HU for model 2). */
void fracture_defaults(fracture_params *p);
/* 0 if the parameters are in range, else FN_EINVAL saying which. */
int fracture_check(const fracture_params *p);
/* 0 and *out filled (free with fracture_result_free), or a negative FN_E* code. p->model 2 makes
 * it fracture_model2's. */
int fracture_make(const vol *ct, const fracture_params *p, fracture_result *out);
/* The second fracture model (fracture_model2.c), so that what is measured on synthetic fractures
 * is not tuned to one generator. Two pieces (p->pieces must be 2; no touching, no bone loss):
 *  - the cut: a bent sheet (random curvatures of up to 1/(3 L) along two tangents, L the RMS
 *    extent of the bone along its main axis) across the main axis (tilted, through a point near
 *    the centroid), with a zig-zag relief (triangle waves of amplitude roughness_mm, period
 *    wavelength_mm along one tangent, half that amplitude and 0.6 the period along the other)
 *    and three sinusoids of 0.3 the amplitude in random directions; islands of the new (smaller)
 *    piece join piece 1, islands of piece 1 stay in the CT unlabelled (crumbs);
 *  - the move: piece 2 turned by rotate_deg about its centroid (random axis), moved displace_mm
 *    away from piece 1 across the cut (the sheet's normal, perturbed), then on a voxel at a time
 *    until it lands on no
 *    piece or bright non-bone; where it lands past the grid's edge the grid grows (as model 1's);
 *  - the resampling: trilinear; each output voxel mixes piece 2's values (weight o, the share of
 *    its trilinear weights on piece 2) with what lies there (1 - o), so the fracture's edge shows
 *    partial volume, and is labelled 2 where o >= 0.5;
 *  - noise: Gaussian (a sum of four uniforms), noise_hu, on every voxel.
 * truth and moved as fracture_make's; cut holds the pieces before the move. Deterministic for a
 * seed (on one machine: it uses libm's sin). 0 or FN_E*. */
int fracture_model2(const vol *ct, const fracture_params *p, fracture_result *out);
void fracture_result_free(fracture_result *r);
/* The fewest voxels a piece of a bone of bone_voxels keeps: 10% of them, or 1/(2 pieces) beyond 6
 * pieces (5% for 10), so that the last cuts still have room. */
size_t fracture_min_piece(size_t bone_voxels, int pieces);
/* How far truth moves a point (a fragment's centroid, in mm): the one measure of a piece's
 * displacement that fracnav prints (a pose's translation alone depends on where the origin is). */
double fracture_truth_shift(const pose *truth, const double centroid[3]);

struct planning_case;
/* The whole thing as a saved case: fractures ct, writes dir/source.nii.gz (ct's voxel type), makes
 * the case over it (fragment i = piece i, poses identity, fixed = piece 1, truth set) and saves it.
 * Returns the case (free with case_free) or NULL with fn_err. ct is not consumed. */
struct planning_case *fracture_make_case(const vol *ct, const fracture_params *p, const char *dir);

/* The deterministic pieces, exposed for tests: splitmix64 step, uniform [0,1), and fBm value
 * noise at point x (in noise-lattice units), scaled to a standard deviation of about 1. */
uint64_t fracture_rng_next(uint64_t *state);
double fracture_rng_uniform(uint64_t *state);
double fracture_fbm(uint64_t seed, const double x[3]);

#endif
