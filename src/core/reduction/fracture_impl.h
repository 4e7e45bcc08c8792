/* fracture_impl: what the fracture files (fracture.c: model 1 and the shared parts,
 * fracture_model2.c, fracture_make.c: the entry) share inside the reduction target. */
#ifndef FN_FRACTURE_IMPL_H
#define FN_FRACTURE_IMPL_H

#include "fracture.h"
#include "vol.h"

struct seg_result;

/* v on a grid grown by lo[a] voxels before and hi[a] after along each axis (0 0: a copy); the new
 * voxels hold `value`, the old ones keep their world positions. NULL with fn_err. */
vol *fracture__padded(const vol *v, const int lo[3], const int hi[3], float value);

/* The box of out_lab's voxel indices (spare voxels to spare, not clamped to its grid) that piece
 * `id` of cut moved by m may reach (the moved corners of the piece's label box). */
void fracture__moved_box(const vol *cut, int id, pose m, const vol *out_lab, int spare, int olo[3], int ohi[3]);

/* The bone p cuts, as seg_run's result of one component (the largest): at p's threshold, or
 * bone_find's whole bone when p->whole_bone. 0 or a negative FN_E* code. */
int fracture__bone(const vol *ct, const fracture_params *p, struct seg_result *seg);

/* Model 1 (fracture.c): fracture_make for p->model 1. */
int fracture__model1(const vol *ct, const fracture_params *p, fracture_result *out);

#endif
