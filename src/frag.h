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

#endif
