/* reduce: automatic fracture reduction. The VOI metric of the paper, principal-axis pre-alignment,
 * and the optimizer driver (our Powell, or NLopt's PRAXIS, SBPLX, BOBYQA) that fits one moving
 * fragment to a fixed assembly, then every fragment of a case in contact-area order.
 *
 * The metric (paper section 6): over a VOI, (2 n_I - n_1 - n_2) / n_VOI, with n_1 the assembly's
 * voxels in the VOI, n_2 the moving fragment's, n_I those of both. Lower is better: the VOI filled,
 * overlap penalised. Counting grid: the VOI cells are the cells of the first assembly fragment's
 * own voxel grid (at its current pose) whose index box bounds the VOI's world box (reduce_voi_cells),
 * so the fixed fragment enters exactly, never resampled; other assembly fragments are sampled there
 * (nearest). Each moving voxel (prob > 0) is carried into that grid by the poses and counted there:
 *  - nearest: at the cell nearest its centre;
 *  - trilinear (partial volume): with the trilinear weights of the eight cells around it, so
 *    n_2 and n_I change continuously with the pose and line searches do not stall on plateaus.
 * The band (band_mm > 0): only the VOI cells within band_mm of the assembly's bone (per axis, a
 * box of whole cells, less those farther than 1.45 band_mm: the box's corners on 1 mm slices)
 * count, for n_VOI and n_2 alike. A box VOI around a thin bone (a skull) is
 * mostly empty, and the paper's count then prefers any pose that crams more of the moving
 * fragment into that space over the fit; the band keeps the count to where the fragments meet.
 * band_mm = 0 is the paper's box.
 * The gap (reduce_opts.gap_mm > 0, for bone lost at the cut): the VOI cells within gap_mm
 * (Euclidean) of the assembly's bone count as its bone (for n_1, n_I and the band), so the true
 * pose, which leaves that gap, scores as a fit that touches; without it the metric closes the gap
 * (bench reduce --bone-loss 1: translation error about the loss).
 * A moving voxel counts in units of the grid's voxel volume (the ratio of the two voxel volumes;
 * 1 for fragments of one CT). Empty space is skipped by 8^3 bricks of the moving fragment, each
 * with its runs of bone voxels along i, culled against the VOI by a bounding sphere. The fit counts
 * on a band: the moving voxels that lay near the counted cells where it made the band (remade as
 * the search moves); a brick that has moved farther than the band allows counts all its runs, so
 * an evaluation is exact at any pose and costs the band's voxels near the fracture.
 *
 * Parameters of the fit (6): translation in world mm, and the rotation vector about the moving
 * fragment's centroid (at the start pose) in the principal axes of its voxels in the VOI, each
 * component times the RMS distance of those voxels from that axis, so a unit step of either kind
 * moves the fracture surface about 1 mm (reduce_opts.axis_scale).
 *
 * Threads: a reduce_metric is read-only once made; evaluations from several threads are safe.
 * Errors: see err.h. */
#ifndef FN_REDUCE_H
#define FN_REDUCE_H

#include "frag.h"
#include "pose.h"

#include <stdatomic.h>
#include <stddef.h>

struct obb_tree;
struct planning_case;

typedef enum { REDUCE_POWELL, REDUCE_PRAXIS, REDUCE_SBPLX, REDUCE_BOBYQA, REDUCE_METHODS } reduce_method;
typedef enum { REDUCE_TRILINEAR, REDUCE_NEAREST } reduce_count;

/* "powell", "praxis", "sbplx", "bobyqa"; and back (-1 unknown). */
const char *reduce_method_name(reduce_method m);
int reduce_method_parse(const char *s);

/* A box in world LPS mm, lo < hi on every axis. */
typedef struct reduce_voi {
    double lo[3], hi[3];
} reduce_voi;

/* The VOI cells: the index box [c0, c1] (inclusive) of grid's voxel grid (at grid's current pose)
 * that bounds the world box: c0 = ceil, c1 = floor of the corners' indices. 0, or FN_EINVAL when
 * the box holds no cell centre. */
int reduce_voi_cells(const frag *grid, const reduce_voi *voi, int c0[3], int c1[3]);

typedef struct reduce_counts {
    double n1, n2, ni, nvoi;
} reduce_counts;

static inline double reduce_counts_metric(const reduce_counts *c)
{
    return c->nvoi > 0 ? (2 * c->ni - c->n1 - c->n2) / c->nvoi : 0;
}

typedef struct reduce_metric reduce_metric;
/* The metric of moving against the assembly asm_[0..nasm-1] (asm_[0] gives the grid) over voi, at
 * their current poses (the moving fragment's pose is given per evaluation). The fragments must
 * outlive it only during the call: it copies what it needs. NULL with fn_err (FN_EINVAL: empty VOI
 * or no fragment, FN_ENOMEM). */
reduce_metric *reduce_metric_new(const frag *const *asm_, int nasm, const frag *moving,
                                 const reduce_voi *voi, reduce_count mode, double band_mm);
void reduce_metric_free(reduce_metric *m);
/* The metric with the moving fragment at pose p (home world -> world). Allocates nothing. */
double reduce_metric_eval(const reduce_metric *m, const pose *p, reduce_counts *counts);
/* Moving voxels (prob > 0) carried into the VOI at pose p (nearest), and their RMS distance from
 * point c (world mm); for the parameter scale. */
double reduce_metric_radius(const reduce_metric *m, const pose *p, const double c[3]);
/* Their second moments about c: S[a][b] = mean of (x_a - c_a)(x_b - c_b) (mm^2; zeros when none). */
void reduce_metric_spread(const reduce_metric *m, const pose *p, const double c[3], double S[3][3]);
/* The same counts by brute force: every voxel of the moving fragment carried through each pose in
 * turn (pose_apply), every VOI cell of the grid visited. Slow: for tests. */
double reduce_metric_brute(const frag *const *asm_, int nasm, const frag *moving, const pose *p,
                           const reduce_voi *voi, reduce_count mode, double band_mm, reduce_counts *counts);

/* The contact zone of moving (at its pose) with the assembly: the world box around the voxels of
 * either side that lie within delta_mm of the other, grown by margin_mm. delta doubles (from
 * delta_mm up to 64 mm) until some voxel is that close. *contact_ml: the moving fragment's volume
 * within the final delta (the order of reduction follows it). max_mm > 0: a side longer than
 * that is cut to max_mm around the centroid of the moving fragment's contact voxels. 0, or FN_EINVAL when nothing comes
 * within 64 mm, or FN_ENOMEM. */
int reduce_auto_voi(const frag *const *asm_, int nasm, const frag *moving, double delta_mm,
                    double margin_mm, double max_mm, reduce_voi *voi, double *contact_ml);

typedef void (*reduce_progress_fn)(void *ctx, int id, int iter, int evals, double f, double seconds);

#define REDUCE_THREADS_MAX 16

typedef struct reduce_opts {
    reduce_method method;
    reduce_count count;
    int prealign;        /* 1: principal-axis pre-alignment: the local fit's start for a fragment
                          * more than 10 mm from the assembly (nearer, it counts as placed by
                          * hand), and one of the global stage's candidates (near or far) */
    int has_voi;         /* 1: voi below for every fragment; 0: automatic (reduce_auto_voi) */
    reduce_voi voi;
    double tau_min, tau_max; /* the hierarchy's thresholds (the case's) */
    double tolerance_mm; /* collision tolerance of the final check (obb.h); at most 0.45 times the
                          * smallest voxel spacing is used. At 0 a fit near the truth of a rough
                          * fracture interlocks its voxels with the other side's and is pushed off
                          * by millimetres (bench reduce --tolerance 0: skull 0.95 -> 0.00, 2.9 mm) */
    double settle_mm;    /* then the result is pushed out up to this far to be free at tolerance
                          * 0 (the loop's: navigate then finds it touching, not inside), and
                          * left where it is when that is not enough (0: not tried) */
    double xtol_mm;      /* convergence: a step that moves the surface less than this (5 times
                          * that in the first of two stages) */
    int max_eval;        /* evaluations per fragment (every stage and attempt together) */
    double voi_max_mm;   /* automatic VOI: the longest side (reduce_auto_voi's max_mm) */
    double band_mm;      /* the metric's band (default 1 mm; 0: the whole box) */
    double gap_mm;       /* bone lost at the cut (0: none): the fit leaves this gap (see above);
                          * bench reduce --bone-loss 1 --gap 1: success 0.55 -> 0.95 */
    int starts;          /* the first stage's starts: the start, then turned +-8 degrees about
                          * the principal axes in turn; the best fit wins */
    int axis_scale;      /* 1 (default): the rotation is scaled per principal axis of the moving
                          * voxels in the VOI (about each axis by their RMS distance from it), so a
                          * unit step about a long bone's shaft moves its surface as far as one
                          * about a cross axis (bench reduce, long bone: success 0.30 -> 0.55, skull
                          * unchanged); 0: one radius for all three (the RMS distance from the
                          * centroid) */
    int polish;          /* 1: the result polished on the nearest count (the fit's last stage) */
    int global_check;    /* 1: after the local fit, the global stage's candidates are fitted too
                          * (as after a fit that ran into the trust wall), and refined only where
                          * one beats the local fit's end over the union of their contact zones;
                          * else the local fit stands as it was. On a broad fracture surface the
                          * metric has a plateau of sliding contact around a narrow basin at the
                          * truth, and a local fit stops on it (see docs/reduction.md). Not for a
                          * long piece (see hops): a cut through a tube is nearly symmetric under
                          * a turn about its axis, and the candidates stray (bench reduce --ct
                          * long-bone: 0.70 -> 0.50). 0: the global stage only after the wall */
    int hops;            /* up to this many rounds of hops after the fit, the best kept while a
                          * round gains. A long piece (largest principal variance over 4 times the
                          * next): the fit again from the result turned 3 degrees either way about
                          * each of its principal axes, colliding poses costed (bench reduce --ct
                          * long-bone: success 0.55 -> 0.75). Any other piece, strictly: from the
                          * result moved 1.5 mm either way along each axis, short fits (50
                          * evaluations each), the best refined, kept only free of collision and
                          * better in metric alone by 1e-4 (the real pelvic pieces of bench reduce
                          * --labels: back_rate 0.77 -> 0.90; 50 evaluations, not 40: 0.93 ->
                          * 0.97); 0: none */
    int coarse;          /* 1: the first stage (automatic VOI) fits coarse copies of the fragments
                          * (2 voxels a cell per axis where the spacing is finest). Off by default:
                          * in `bench reduce` its flatter metric led fits astray (success 0.25
                          * against 0.90 for PRAXIS) */
    double trust_mm, trust_deg; /* the local fit stays this close to the start (centroid distance
                          * and rotation angle); one that ends on this wall hands over to the
                          * global stage, which has none (0: no wall, no hand-over) */
    int threads;         /* reduce_case fits the pieces of a first-sweep round, and those of a
                          * second-sweep wave (no bone within about 4 mm of each other), at
                          * once, and reduce_pair the global stage's candidates and a hop
                          * round's moves, on up to this many threads (1 .. REDUCE_THREADS_MAX;
                          * default 2, the machine's cores); the same poses on any number */
    reduce_progress_fn progress; /* after each iteration; may be NULL. Called on the thread that
                          * runs the fit (several at once in reduce_case), never for the global
                          * stage's candidates or the hops' moves (they report none) */
    void *progress_ctx;
    const atomic_int *cancel; /* may be NULL; once another thread sets it non-zero, the fit stops
                          * within one metric evaluation and returns 1 with the placed pose */
} reduce_opts;

/* PRAXIS (the most successful in `fracnav bench reduce`), trilinear, a 1 mm band, pre-alignment on
 * (a global candidate),
 * no gap, automatic VOI of any size, 3 first-stage starts, rotation scaled per principal axis, 3
 * rounds of hops, the polish, no coarse stage, trust 12 mm / 18 degrees, tau 0.5/0.95,
 * tolerance 0.5 mm, xtol 0.01 mm, 4000 evaluations (all stages, attempts and hops together). */
void reduce_defaults(reduce_opts *o);

/* The collision tolerance a fit of these fragments works at: o->tolerance_mm, at most 0.45 times
 * the smallest voxel spacing among them (the query takes tolerances below half a voxel). */
double reduce_tolerance(const reduce_opts *o, const frag *const *f, int n);

/* An answer of a fit that did not find a single one: a pose and its metric over the final VOI. */
#define REDUCE_CANDIDATES_MAX 16
typedef struct reduce_candidate {
    pose pose;
    double metric;
} reduce_candidate;

typedef struct reduce_result {
    int id;               /* the moving fragment's label */
    pose placed;          /* its pose before (as the user left it) */
    pose start;           /* after pre-alignment (= placed without it) */
    pose fitted;          /* what the optimizer found, before any push out of collision */
    pose end;             /* the result */
    reduce_voi voi;
    int prealigned;       /* 1: pre-alignment chose the local fit's start, or the result came from
                           * the global stage's pre-aligned candidate */
    int iterations;       /* Powell: iterations; NLopt: improvements of the best value */
    int evaluations;
    double eval_cpu_s;    /* thread CPU seconds those evaluations spent in the metric (their VOIs) */
    double seconds;
    double metric_start;  /* at start, over voi (several fragments: at the first sweep's start,
                           * over that sweep's VOI) */
    double metric_end;
    double push_mm;       /* how far the collision check pushed the result out (0: not at all) */
    int collides;         /* 1 only when no collision-free pose could be found (then end = start) */
    int rival;            /* 1: a first-stage start ended in a rival basin (see reduce_opts.hops),
                           * or another kept candidate of the global stage ended as good (within
                           * 0.002 over the union of their VOIs) but apart: no single answer wins */
    int ncandidates;      /* when rival: the global stage's winner and its rivals, else the best
                           * first-stage end, then every rival one, with their metrics over the
                           * final VOI; 0 otherwise (or when the fit failed) */
    reduce_candidate candidate[REDUCE_CANDIDATES_MAX];
    int hops;             /* rounds of hops that gained (each moved the result) */
    int wave;             /* reduce_case with several moving: the fragments of its second-sweep
                           * wave, fitted at once with it (itself included) */
    double *history;      /* metric per iteration, nhistory values; malloc'd */
    int nhistory;
} reduce_result;

void reduce_result_free(reduce_result *r);

/* Pre-alignment (paper Fig. 5), a candidate of reduce_pair's global stage: the moving fragment's
 * long axis onto the assembly's first fragment's (both signs), its centroid on that axis, slid along
 * it (from either end) to contact by the collision query and turned about it in 30 degree steps; the
 * candidate of best metric, unless the placed pose beats them, all scored over one VOI: the union
 * of each one's overlap of the two boxes. */

/* Fits moving (from its current pose, pre-aligned first when o->prealign and it lies more than
 * 10 mm from the assembly) to the assembly. The local fit: with an automatic VOI, two
 * stages: the optimizer over the contact zone where the fragment starts, then again over the
 * tighter zone where that ended, with colliding poses refused (costed), and again (up to twice
 * more) while the zone where it ended is over a quarter larger (volume) than the VOI it was fitted
 * over; a given VOI gets one stage, with that refusal. A fit that ends on the trust wall (within
 * 1 mm or 1 degree) or colliding is tried again from the start turned 8 degrees about the other
 * two principal axes, then 12 degrees about all three; but when the first ends on the wall, the
 * global stage instead: candidate starts (the start, it turned 15 degrees and moved 8 mm either
 * way about and along each principal axis, and the pre-alignment when o->prealign) fitted briefly
 * (at once, on o->threads threads), the best one or two refined as above without the wall, the end of best metric over the union of
 * their VOIs the result (rivals: see reduce_result). The piece then hops (o->hops). A result that still collides beyond the tolerance is
 * pushed out along the contact normal (up to 5 mm), else the start is kept; a free one is settled
 * (o->settle_mm). A result whose metric is worse than the start's (over the final VOI) is not
 * kept when the start is free. Sets moving->pose = r->end.
 * 0, 1 when o->cancel was set (then moving->pose = r->end = the placed pose), or FN_E*. */
int reduce_pair(const frag *const *asm_, int nasm, frag *moving, const reduce_opts *o, reduce_result *r);

/* For a worker thread of a navigation session: fits one moving fragment from *start (where the
 * hand left it; no pre-alignment, whatever o->prealign says) against others[0..nothers-1] at their
 * poses, with o->progress called (on this thread) after each iteration and o->cancel polled at
 * every evaluation. *out: the fitted pose, never colliding with the others beyond the tolerance
 * (else *start, see reduce_pair); r: its record (free with reduce_result_free).
 * Ownership and threads: the fragments are only read. moving->pose is not used or changed (the
 * fit works on a copy). The caller keeps the fragments' voxels (prob) alive and unchanged, and
 * others' poses unchanged, for the whole call: a session passes copies of its frag structs taken
 * under its lock (struct copies sharing prob suffice, prob is never written while a case is
 * open). Several fits may run at once on different threads (the messages of err.h are
 * per thread). Allocates; never call it from the real-time loop's step.
 * Returns 0, 1 when cancelled (*out = *start), or FN_E*. */
int reduce_fit_one(const frag *const *others, int nothers, const frag *moving, const pose *start,
                   const reduce_opts *o, pose *out, reduce_result *r);

/* The fragments to move when none is named: every one but fixed (index) that has bone within
 * about 4 mm of another fragment's in the CT (every pose the identity, as segmented), or that the
 * hand moved (its pose is not the identity) to within that of another. One that touches nothing in
 * the CT and that no one moved next to another (a CT's head holder, which lies apart from the
 * bone) is left out. mv and
 * skipped (indices) have room for c->nfrag. Returns the number put in mv (*nskipped: the number
 * skipped), or FN_E*. */
int reduce_pick_moving(const struct planning_case *c, int fixed, int *mv, int *skipped, int *nskipped);

/* Reduces the case's fragments: fixed (index) stays, the moving ones (indices; NULL = all others)
 * are fitted one by one against the growing assembly: each round fits every piece still to place
 * (those apart from the piece placed last keep their fit) and the one whose fit gained most joins;
 * then each again against all the others (docs/reduction.md, step 6). r has room for nmoving
 * results, zeroed (filled in the order placed; on a failure only those placed). Sets their poses.
 * 0 or FN_E*. */
int reduce_case(struct planning_case *c, int fixed, const int *moving, int nmoving, const reduce_opts *o,
                reduce_result *r);

/* With ground truth: the errors of fragment mi's pose relative to fixed fi against the truth:
 * rotation (degrees), the moving centroid's displacement (mm), and the RMS displacement (TRE, mm)
 * over its fracture-surface voxels (within 1.5 voxels of the fixed fragment in the true pose; all
 * its voxels when none). 0 or FN_EINVAL (no truth). */
int reduce_truth_errors(const struct planning_case *c, int fi, int mi, double *rot_deg, double *trans_mm,
                        double *tre_mm);

/* The errors of m's pose against want (its true pose, for f where it is now): as above. */
void reduce_errors(const frag *f, const frag *m, const pose *want, double *rot_deg, double *trans_mm,
                   double *tre_mm);

#endif
