/* fracture_impl: what the two fracture models (fracture.c, fracture_model2.c) share inside the
 * reduction target. */
#ifndef FN_FRACTURE_IMPL_H
#define FN_FRACTURE_IMPL_H

#include "vol.h"

/* v on a grid grown by lo[a] voxels before and hi[a] after along each axis (0 0: a copy); the new
 * voxels hold `value`, the old ones keep their world positions. NULL with fn_err. */
vol *fracture__padded(const vol *v, const int lo[3], const int hi[3], float value);

#endif
