/* case: a planning case on disk, a folder holding case.json and labels.nii.gz.
 *
 * case.json (written through jansson) holds the format version, the source volume (path, sha256,
 * geometry), the segmentation parameters, every fragment (id, name, colour, voxels, volume,
 * bounding box, centroid, principal axes, pose), the fixed fragment, the hierarchy thresholds
 * tau_min/tau_max, the sha256 of labels.nii.gz, and any ground truth. labels.nii.gz is the
 * labelmap on the source grid. A source path inside the case folder is stored relative to it.
 *
 * Saves are atomic per file (temporary file, fsync, rename, fsync of the folder): a failed save
 * leaves the previous case untouched. Before the renames, the labels the on-disk case.json names
 * are kept as labels.prev.nii.gz (a hard link); then labels.nii.gz is renamed before case.json,
 * and labels.prev.nii.gz is removed once both are in place. After a crash between the two renames,
 * case_load finds that labels.nii.gz does not match case.json's checksum but labels.prev.nii.gz
 * does, puts the previous labels back and says so on stderr: the case loads as it was last saved.
 * Without hard links (or at a first save) no previous labels are kept and such a crash is an
 * FN_EMISMATCH at load. */
#ifndef FN_CASE_H
#define FN_CASE_H

#include "frag.h"
#include "pose.h"
#include "seg.h"
#include "vol.h"

#include <stdint.h>

#define CASE_VERSION 1

#define CASE_FIXED_MAX 64 /* fixed fragments a case records */
#define CASE_TAU_MIN 0.5  /* a new case's tau_min and tau_max */
#define CASE_TAU_MAX 0.95

typedef struct planning_case {
    char dir[4096];          /* the case folder */
    char source[4096];       /* source volume path (absolute, or as given) */
    char sha256[65];         /* of the source volume file */
    char json_sha256[65];    /* of case.json as last loaded or saved ("" before): what a journal
                              * is bound to */
    char labels_sha256[65];  /* of labels.nii.gz as last loaded or saved ("" before) */
    uint64_t labels_sum[2];  /* a checksum of labels' values then: a save whose labels still have
                              * it, with that file still in the folder, writes case.json alone */
    vol *ct;                 /* the source volume, owned */
    vol *labels;             /* labelmap on the source grid (float label values), owned */
    int nfrag;
    frag *frag;              /* frag[i].id is its label; prob maps, centroid, axes ready after load */
    int fixed;               /* index of the fixed fragment, -1 none (reduce's, the report's) */
    int nfixed_also;         /* fragments fixed besides it (a session fixed several), by id */
    int fixed_also[CASE_FIXED_MAX];
    double tau_min, tau_max; /* hierarchy thresholds (collision probability) */
    int has_truth;
    pose *truth;             /* when has_truth: per fragment, the pose that restores it (home -> true) */
    seg_params seg;          /* how the labels were made; seg.threshold/ramp shape the prob maps */
    void *extra;             /* case.json's other top-level members (a jansson json_t object, owned,
                              * may be NULL): other modules keep theirs here (VOIs, optimisation
                              * results) and they survive load and save unchanged. "reduction"
                              * (case_set_reduction): method, counting, fixed, prealign,
                              * tolerance_mm, fragments[] {id, voi_mm [6], prealigned, placed,
                              * start, end ({q [4], t [3]}), iterations, evaluations, seconds,
                              * metric_start, metric_end, push_mm, collides, history [metric per
                              * iteration: the convergence plot]} */
} planning_case;

/* A new case in folder dir (not yet saved) over the source volume file `source`, already read into
 * ct; takes ownership of ct and labels. Builds every fragment present in labels (ids = label values,
 * ascending), poses identity, no fixed fragment, no truth. NULL with fn_err on failure (ct and labels
 * are freed then too). */
planning_case *case_create(const char *dir, const char *source, vol *ct, vol *labels, const seg_params *sp);

/* A whole case folder written aside and put in place in one step (segment, fracture), so that a
 * kill at any moment leaves the old case or the new one at dir, never a mix or a half-made folder.
 * case_stage_begin checks dir (missing, empty, or a case folder when force; keep, when not NULL,
 * must not lie inside a folder it would replace), removes what killed runs left, and creates the
 * hidden sibling folder tmp (PARENT/.NAME.new-PID) to build the case in. case_stage_commit syncs
 * every file of tmp and renames it to dir; an existing case is exchanged with it atomically
 * (renameat2 RENAME_EXCHANGE) and then removed. A new case has no lock (caselock.h): when another
 * process saved a case at dir after case_stage_begin found none, case_stage_commit without force
 * refuses (FN_EINVAL, saying so), and its rename never lands on a folder that holds files, so of
 * two writers of one new case the second is refused and the first's case kept. With force it is
 * exchanged as a case found at begin. case_stage_abort removes tmp after a failure.
 * 0 or FN_E* with a message naming the folder. */
int case_stage_begin(const char *dir, int force, const char *keep, char *tmp, size_t cap);
int case_stage_commit(const char *tmp, const char *dir, int force);
void case_stage_abort(const char *tmp);

/* Reads dir/case.json, dir/labels.nii.gz and the source volume. Checks the version, the source's
 * sha256 and geometry, and the labels checksum; each mismatch is an FN_EMISMATCH error that says
 * what differs. A damaged case.json gets FN_EFORMAT naming the file and the field. */
planning_case *case_load(const char *dir);

/* Writes labels.nii.gz and case.json atomically (creates dir if missing). 0 or FN_E*. */
int case_save(planning_case *c);
void case_free(planning_case *c);

/* Edits that can be taken back (the window's separation). case_save_undoable keeps the case as it
 * is on disk (case.json and labels.nii.gz, hard links, no copy) as the newest undo step,
 * CASE/undo.N.case.json and CASE/undo.N.labels.nii.gz, then saves c (case_save) and links the
 * case it saved into the step. case_undo puts the newest step back in place as case_save would
 * save it (labels, then case.json; a crash between leaves the case as it was, the step whole) and
 * removes the step: 1, or 0 when there is none to undo. case_undo_steps: the newest step's N, 0
 * when none. A step equal to the case as it is (a crash before the save, or after an undo's
 * renames) is dropped, never applied; a step whose edit's case.json or labels are no longer the
 * case's (a save since: an edit, a fit, moved poses; or a crash before they were linked) is not
 * undone, so nothing saved later is lost. The caller holds the case's lock and removes its
 * journal (bound to the case.json that was). FN_E* naming the file. */
int case_save_undoable(planning_case *c);
int case_undo(const char *dir);
int case_undo_steps(const char *dir);

/* Rebuilds the fragments from c->labels after an edit: fragments keep their pose, name, colour and
 * truth by id; fragment new_id (when > 0) inherits pose and truth from parent_id (a split), other
 * new ids get identity; ids that vanished are removed (the fixed index follows its fragment or
 * becomes -1). Labels must be integers 0..65535. 0 or FN_E*. */
int case_rebuild(planning_case *c, int new_id, int parent_id);

/* Index of the fragment with label id, or -1. */
int case_find(const planning_case *c, int id);

/* Whether fragment i (index) is fixed: c->fixed or one of fixed_also. */
int case_is_fixed(const planning_case *c, int i);
/* Fixes the fragments flagged in fixed (per index; at most CASE_FIXED_MAX): c->fixed stays while
 * it is among them, else becomes the first; the others go to fixed_also. */
void case_set_fixed(planning_case *c, const uint8_t *fixed);

/* The overlap of fragments a and b (indices) at their poses: the volume (ml) in which their bone
 * voxels (obb.h's effective probability > 0 under the case's tau) overlap, sampled at 27 points
 * per voxel of a. The one overlap figure: navigate's and reduce's saves, case.json's
 * "penetrating" and the report use it. */
double case_overlap_ml(const planning_case *c, int a, int b);

typedef struct case_overlap {
    int a, b;   /* fragment indices, a < b */
    double ml;  /* case_overlap_ml */
    int fitted; /* fitted[a] || fitted[b]: a fit left them so, within its tolerance */
} case_overlap;

/* The pairs that interpenetrate at the case's poses (obb_collide at tolerance 0, as the loop
 * checks), with their overlap; the first max go to out (may be NULL). fitted: per fragment (NULL
 * = none). Returns how many, or FN_E*. */
int case_penetrating(const planning_case *c, const uint8_t *fitted, case_overlap *out, int max);
/* Records o[0..n-1] as case.json's "penetrating" ({"fragments": [id, id], "overlap_ml",
 * "within_fit_tolerance"}), or removes it when n is 0. 0 or FN_ENOMEM. */
int case_record_penetrating(planning_case *c, const case_overlap *o, int n);

/* Edits. Each changes c->labels and rebuilds the fragments (case_rebuild); the caller saves.
 * A bad id is FN_EINVAL naming it and listing the ids the case has. Volumes: world LPS mm. */
/* Fragment b joins fragment a (b's voxels take label a). */
int case_merge(planning_case *c, int a, int b);
/* The voxels of id on the side of the plane (point p, normal n) that n points to become a new
 * fragment (the next free id, returned); it inherits id's pose and truth. */
int case_split(planning_case *c, int id, const double p[3], const double n[3]);
/* Voxel centres inside the box (any two opposite corners) or sphere become background; only those
 * of fragment id when id > 0. Returns the number of voxels erased. */
long case_erase_box(planning_case *c, const double a[3], const double b[3], int id);
long case_erase_sphere(planning_case *c, const double centre[3], double radius, int id);
/* Region growing: the unlabelled voxels >= threshold 26-connected to the voxel nearest `seed`
 * join fragment `into` (0: a new fragment, the next free id). Returns the fragment's id; FN_EINVAL
 * when the seed is outside the grid, labelled already, or below the threshold. */
int case_grow(planning_case *c, const double seed[3], double threshold, int into);
/* Keeps only, or drops, the listed fragments. */
int case_keep(planning_case *c, const int *ids, int n);
int case_drop(planning_case *c, const int *ids, int n);
/* Makes id the fixed fragment, the only one (0: none). */
int case_fix(planning_case *c, int id);
/* Fragment id's enclosed interior (morph_fill's mode: MORPH_FILL_3D and/or MORPH_FILL_SLICES; the
 * cancellous bone below the threshold inside the cortex) joins it; voxels of other fragments stay
 * theirs. Returns the voxels added. */
long case_fill(planning_case *c, int id, int mode);
/* Separates fragment id into the pieces that touch in it (morph_separate: erosion by erode_mm, or
 * the smallest that splits it when erode_mm <= 0, then a marker-based watershed on the distance map
 * inside the fragment). The largest piece keeps id; every other one becomes a new fragment (the
 * next free id, written to new_ids, room for as many pieces as can be) inheriting id's pose and
 * truth. *erode_used (may be NULL): the erosion that split it. Returns the number of new fragments
 * (>= 1), FN_EINVAL when it does not split, or FN_E*. */
int case_separate(planning_case *c, int id, double erode_mm, int *new_ids, double *erode_used);

/* A labelled point for case_separate_seeds: world LPS mm, and the piece it marks (1..254), or 0
 * for "not bone". */
typedef struct case_seed {
    double at[3];
    int piece;
} case_seed;

/* Separates fragment id from labelled seeds (grow: a competitive growth that follows the CT's
 * intensities, inside the fragment). Each piece that wins voxels becomes a fragment (the largest
 * keeps id, the others new ids as case_separate); voxels won by a not-bone seed leave the case.
 * A piece's seed outside the fragment, on bone the mask missed (non-zero on a CT that holds only
 * the bone, >= the case's threshold on a full CT), grows the fragment over that connected bone
 * first. Returns the number of new fragments (0 when one piece wins all), or FN_EINVAL naming the
 * point (world mm) and why: outside the CT, in another fragment, not bone, two pieces in one
 * voxel, a bad piece number. */
int case_separate_seeds(planning_case *c, int id, const case_seed *seeds, int n, int *new_ids);

/* Separates fragment id where the bone is truly broken. Returns the new fragments (0 when it is
 * whole), or FN_E*. */
int case_separate_auto(planning_case *c, int id, int *new_ids);

/* Separates every fragment automatically (case_separate_auto, again on each piece it makes until
 * none splits; seeds NULL, n 0), or from seeds:
 * each seed goes to the fragment it lies in (one on no fragment to the largest), and each
 * fragment with seeds is separated from them (case_separate_seeds). Returns the new fragments
 * made, or FN_E* (a seed's error names the point). */
int case_separate_all(planning_case *c, const case_seed *seeds, int n);

/* A live preview of case_separate_all(c, seeds, n) from seeds of pieces 1..254 on c's fragments
 * (the window's seed mode): case_preview_update grows the split and gives the fragments it would
 * make, in *shown (n of them, returned; valid until the next update or case_preview_free): each
 * fragment with seeds as its pieces, the largest keeping its id and colour and the others the ids
 * and colours case_separate_all would give them, and the others as they are; all at the pose of
 * the fragment they come from (poses[i] for c's fragment i; NULL: their own). When the seeds
 * extend those of the last update, only the new ones grow (grow.h's incremental update); else the
 * growth starts anew. c must outlive p, unchanged. FN_EINVAL naming the seed (world mm) that is
 * outside the CT or on no fragment (Enter would grow the bone there; the preview does not), or
 * FN_ENOMEM. */
typedef struct case_preview case_preview;
case_preview *case_preview_new(const planning_case *c);
void case_preview_free(case_preview *p);
int case_preview_update(case_preview *p, const pose *poses, const case_seed *seeds, int n, const frag **shown);

/* A seed file's text: one seed per line, "PIECE X Y Z" (PIECE 1..254, or "none" for not bone;
 * world LPS mm), blank lines and # comments skipped. Returns the count and *out (malloc'd), or
 * FN_EFORMAT naming `name` and the line. */
int case_seeds_parse(const char *text, const char *name, case_seed **out);

struct reduce_opts;
struct reduce_result;
/* Stores n results of reduce_case (reduce.h), fitted with o against fragment index fixed, in
 * c->extra as "reduction" (see extra above), replacing an earlier one, and the pairs the fitted
 * poses leave inside each other as "penetrating" (case_penetrating; within_fit_tolerance where a
 * fitted fragment is one of them). Implemented with the reduction (reduction/case_reduction.c),
 * which knows reduce_result. 0 or FN_E*. */
int case_set_reduction(planning_case *c, int fixed, const struct reduce_opts *o, const struct reduce_result *r,
                       int n);

#endif
