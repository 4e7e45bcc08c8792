/* export: a case's plan written for other tools (3D Slicer, ITK, printers), and the figures of the
 * planned configuration the report shows.
 *
 * Every file is written atomically: to a hidden temporary name in the same folder, fsync'd,
 * renamed over the target, and the folder fsync'd; a failure leaves any earlier file untouched.
 *
 * Conventions: world coordinates are LPS mm (as in the case). A fragment's pose P maps its home
 * position (as segmented) to its planned position.
 *  - ITK transforms (.tfm) are written in ITK's resampling direction: the transform maps a point of
 *    the fixed (planned) space back to the moving (home) space, so it is P^-1. An
 *    AffineTransform_double_3_3 maps x to A (x - c) + c + T; Parameters are A row by row then T,
 *    FixedParameters the centre c (the fragment's planned centroid). 3D Slicer reads it as such:
 *    a model or segmentation at home placed under the loaded transform shows at its planned place.
 *  - The planned labelmap is resampled on the source grid (nearest): a voxel takes the label of
 *    the fragment (at its pose) whose crop voxel nearest to it is bone; where two fragments claim
 *    one voxel the later fragment wins and both count it as overlap.
 *  - STL: binary, little-endian, one closed surface (mesh.h) per fragment at its pose (its outer
 *    surface and the walls of cavities inside; islands dropped: mesh_drop_islands), mm, LPS (or
 *    RAS: x and y negated, a turn that keeps the winding outward); the 80-byte header says
 *    "SPACE=LPS" or "SPACE=RAS", as 3D Slicer writes and reads it.
 * Threads: volio's rule (teem and nifticlib keep global state): one thread at a time.
 * Errors: 0 or FN_E* with the file named. */
#ifndef FN_EXPORT_H
#define FN_EXPORT_H

#include "case.h"

#include <stddef.h>

/* The planned labelmap on the source grid (see above). NULL with fn_err (FN_ENOMEM). */
vol *export_planned_labels(const planning_case *c);

/* The ITK transform of fragment i (see above). */
int export_tfm(const planning_case *c, int i, const char *path);
/* The planned labelmap as NIfTI (uint16 labels, sform and qform). */
int export_nifti(const vol *planned, const char *path);
/* A 3D Slicer segmentation (.seg.nrrd, one layer, gzip) of the planned labelmap with the case's
 * fragment names, colours and label values (Segment<N>_ID/_Name/_Color/_LabelValue/_Layer/_Extent). */
int export_seg_nrrd(const planning_case *c, const vol *planned, const char *path);

typedef struct export_stl_opts {
    int ras;          /* 1: RAS coordinates */
    int smooth;       /* Taubin iterations (0: none) */
    long decimate;    /* target triangles (0: all) */
} export_stl_opts;
/* The binary STL of fragment i at its pose; *triangles gets the count. */
int export_stl(const planning_case *c, int i, const export_stl_opts *o, const char *path, long *triangles);

/* Figures of the planned configuration per fragment (index order), on the planned labelmap:
 * contact area (faces shared with another fragment's voxels, mm^2), gap (background voxels within
 * gap_mm of both the fragment and another, ml). */
int export_contacts(const planning_case *c, const vol *planned, double gap_mm, double *contact_mm2, double *gap_ml);

#endif
