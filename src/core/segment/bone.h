/* bone: the whole bone of a CT, its cancellous interior included.
 *
 * A threshold that keeps the cortex (250-300 HU) leaves out the cancellous interior, which on
 * real pelvic CTs reaches down to 40-70 HU and in fatty marrow below 0. Two kinds of CT:
 * - a bone-only CT (a bone cut out of its CT: everything outside it is exactly 0, as in the
 *   PENGWIN/FracSegNet data): the bone is every non-zero voxel 26-connected to the cortex (the
 *   hysteresis of two thresholds, the lower one being "not the background");
 * - a full CT (air at -1000 HU, soft tissue at 0-100 HU, as in the skull): soft tissue and
 *   cancellous bone share their HU, so the bone is the threshold's voxels; what the cortex
 *   encloses is added by filling (morph_fill), as `segment --fill` does.
 * OS-free, no global state. */
#ifndef FN_BONE_H
#define FN_BONE_H

#include "seg.h"
#include "vol.h"

#include <stdint.h>

typedef enum { BONE_FULL_CT = 0, BONE_ONLY_CT = 1 } bone_kind;

/* BONE_ONLY_CT when at least half of v's voxels are exactly 0 and almost none (under 1 in 1000)
 * is below -200 HU (no air: the background was cut away); else BONE_FULL_CT. */
bone_kind bone_kind_of(const vol *v);

/* The bone of v as a mask (one byte per voxel, 1 = bone): for a bone-only CT, the non-zero
 * finite voxels 26-connected to a voxel >= threshold; for a full CT, the finite voxels >=
 * threshold. Returns the kind found, or FN_ENOMEM. */
int bone_find(const vol *v, double threshold, uint8_t *mask);

/* The smallest component kept of a CT that holds only the bone (seg_params.min_volume_bone_only_ml
 * by default). Such a CT holds no noise: a small component of it is a chip of bone, a fragment of
 * its own (PENGWIN/FracSegNet 005_RI: a 0.19 ml fragment annotated by hand, which the full CT's
 * 0.5 ml dropped), while the specks of the development set's intact bones are 0.06 ml at most. */
#define BONE_ONLY_MIN_ML 0.1

/* seg_run over bone_find's mask at p's threshold: the whole bones as fragments, components under
 * p->min_volume_ml dropped (p->min_volume_bone_only_ml on a CT that holds only the bone). */
int bone_segment(const vol *v, const seg_params *p, seg_result *out);

#endif
