/* seg: threshold segmentation of a CT into bone fragments.
 *
 * A voxel is bone when its value is finite and >= threshold (HU for CT; raw units for scaled
 * data, or Otsu's threshold when asked for "auto"). Bone voxels are grouped into 26-connected components with a
 * two-pass union-find labelling (linear in the voxel count). Components are then filtered: below
 * min_volume_ml, or whose peak value stays under exclude_below_peak (the CT head holder lies at
 * 300-600 HU while bone peaks far higher), are dropped; keep > 0 keeps only the largest ones.
 * Surviving components are labelled 1..n, largest first, in a float labelmap on the source grid. */
#ifndef FN_SEG_H
#define FN_SEG_H

#include "vol.h"

#include <stddef.h>

typedef struct seg_params {
    double threshold;          /* bone when value >= threshold (in a case: the one used) */
    int threshold_auto;        /* 1: Otsu's threshold over the volume's histogram; 2: Otsu again
                                * over the brighter class (bone within tissue, for head CT) */
    double min_volume_ml;      /* components smaller than this are dropped */
    double min_volume_bone_only_ml; /* bone_segment on a CT that holds only the bone: this instead
                                * (bone.h, BONE_ONLY_MIN_ML by default) */
    int exclude_peak;          /* 1: apply exclude_below_peak */
    double exclude_below_peak; /* components whose maximum value is below this are dropped */
    int keep;                  /* > 0: keep only the `keep` largest components */
    double ramp;               /* width of the opacity ramp for probability maps; 0 = 1 inside */
} seg_params;

/* One surviving component. */
typedef struct seg_component {
    int label;          /* 1.. in the labelmap */
    size_t voxels;
    double volume_ml;
    float peak;         /* maximum value inside */
    int lo[3], hi[3];   /* inclusive bounding box, voxel indices */
} seg_component;

typedef struct seg_result {
    vol *labels;        /* on the source grid, values 0 (background) or 1..ncomp; owned */
    int ncomp;
    seg_component *comp; /* ncomp entries, largest first; owned */
    double threshold;   /* the threshold used (Otsu's when auto) */
    int raw_components; /* components before filtering */
    size_t nonfinite;   /* NaN or infinite voxels: left out of the histogram and never bone */
} seg_result;

/* Defaults: 300 HU, min 0.5 ml, no exclusion, keep all, ramp 200. */
void seg_defaults(seg_params *p);

/* Otsu's threshold over a 256-bin histogram of the range of the volume's finite voxels (NaN and
 * infinite ones are left out); NaN when no voxel is finite. */
double seg_otsu(const vol *v);
/* The same over the finite voxels >= floor_value only. */
double seg_otsu_above(const vol *v, double floor_value);

/* 26-connected components of the voxels where mask != 0, written to lab (0 background, 1..n in
 * scan order of their first voxel). Returns n, or a negative FN_E* code. lab has count entries. */
int seg_components(const uint8_t *mask, const int dim[3], int32_t *lab);

/* Segments v. Returns 0 and fills *out (free with seg_result_free), or a negative FN_E* code.
 * Non-finite voxels are counted (out->nonfinite) and never bone; a volume with no finite voxel,
 * or one where Otsu finds no threshold, is refused (FN_EFORMAT). */
int seg_run(const vol *v, const seg_params *p, seg_result *out);
/* The same over a bone mask made elsewhere (bone_find: one byte per voxel of v, non-zero = bone)
 * instead of the threshold; the threshold is still worked out (out->threshold). */
int seg_run_mask(const vol *v, const uint8_t *mask, const seg_params *p, seg_result *out);
/* The threshold p gives for v (Otsu's when auto); NaN when none. */
double seg_threshold(const vol *v, const seg_params *p);
void seg_result_free(seg_result *r);

/* Fragments that another tool made: labels (a labelmap on v's grid: same dims, affine within
 * 1 micrometre per index and 10 micrometres of origin; whole numbers 0..65535, label k =
 * fragment k) becomes out->labels (on success out owns it, seg_result_free frees it; on failure
 * the caller still does); out->comp lists the labels present, ascending, with their
 * voxels, volume, peak and box; the threshold (p's, or Otsu's when auto) shapes the probability
 * maps only. 0, FN_EINVAL (another grid) or FN_EFORMAT (a value that is no label), naming it. */
int seg_from_labels(const vol *v, vol *labels, const seg_params *p, seg_result *out);

/* The probability byte (probability * 255) of a bone voxel of value `value` under the opacity
 * ramp: p = clamp(0.5 + (value - threshold) / ramp, 1/255, 1), so 0.5 at the threshold and 1 at
 * threshold + ramp/2; ramp <= 0 gives 255 everywhere inside. Never 0 for a fragment voxel. */
uint8_t seg_prob(float value, double threshold, double ramp);

#endif
