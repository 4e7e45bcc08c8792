/* frag: a bone fragment, a crop of the labelled CT that can be moved rigidly.
 *
 * Local frame: mm, axis-aligned with the crop's voxels, voxel (i,j,k) centre at
 * (i*spacing[0], j*spacing[1], k*spacing[2]). home maps local mm to the world (LPS mm) where the
 * fragment was segmented; it is a proper rigid transform (segmentation flips a crop axis when the
 * source grid is left-handed). pose maps home world to current world; at load it is the identity.
 * So a local point x is at pose(home(x)) in the world. */
#ifndef FN_FRAG_H
#define FN_FRAG_H

#include "pose.h"

#include <stddef.h>
#include <stdint.h>

typedef struct frag {
    int id;                /* label value in labels.nii.gz, 1.. */
    char name[48];
    uint8_t rgb[3];
    int dim[3];            /* crop size in voxels */
    int origin[3];         /* source voxel index of the crop's first voxel (before any flip) */
    int flip[3];           /* 1 where the crop axis runs against the source axis */
    double spacing[3];     /* mm */
    pose home;             /* local mm -> home world */
    uint8_t *prob;         /* dim[0]*dim[1]*dim[2], collision probability * 255; 0 = outside; owned */
    size_t voxels;         /* voxels of this fragment (prob > 0) */
    double volume_ml;
    double centroid[3];    /* home world, mm */
    double axes[3][3];     /* principal axes as columns, home world, largest eigenvalue first */
    double eigval[3];      /* mm^2, descending */
    pose pose;             /* home world -> current world */
} frag;

struct vol;

/* The source-index bounding box [lo, hi] (inclusive) of label id. 0, or FN_EFORMAT when the label
 * has no voxel. */
int frag_label_box(const struct vol *labels, int id, int lo[3], int hi[3]);

/* Builds fragment `id` from a labelmap: the crop is the source-index box [lo, hi] (inclusive,
 * usually the label's bounding box) padded by one voxel on every side (it may reach outside the
 * grid; those voxels are 0). prob = seg_prob(ct value) where labels == id, at least
 * FRAG_PROB_LABELLED (a voxel labelled bone is bone at least as surely as one at the threshold: the
 * cancellous interior of a whole bone, a fill or an annotation, under the threshold, stays solid
 * for the collision tests at the default tau_min), 0 elsewhere; ct may be NULL (then 255 inside).
 * Fills stats (frag_stats), colour and name, pose = identity. 0 or FN_E*; on failure *f holds
 * nothing to free. */
#define FRAG_PROB_LABELLED 128 /* seg_prob at the threshold */
int frag_from_labels(frag *f, const struct vol *labels, const struct vol *ct, int id, const int lo[3],
                     const int hi[3], double threshold, double ramp);
/* Recomputes voxels, volume_ml, centroid, axes and eigval from prob (every voxel with prob > 0
 * counts once; centres in home world). */
void frag_stats(frag *f);
/* Whether world point x (LPS mm, the fragment at its pose) lies in a voxel of f (nearest crop
 * voxel, prob > 0). */
int frag_holds(const frag *f, const double x[3]);
/* Source voxel index of crop voxel l (undoing any flip). */
void frag_local_to_source(const frag *f, const int l[3], int s[3]);
/* Home-world position (LPS mm) of crop voxel l's centre. */
void frag_voxel_world(const frag *f, const int l[3], double w[3]);
/* A distinct colour per id (a fixed palette, then golden-ratio hues). */
void frag_colour(int id, uint8_t rgb[3]);
/* Eigen-decomposition of a symmetric 3x3 matrix by cyclic Jacobi: vec columns, val descending,
 * the first two columns' largest component positive, the third their cross product (det +1). */
void frag_eigen_sym3(const double a[3][3], double vec[3][3], double val[3]);
void frag_free(frag *f);

#endif
