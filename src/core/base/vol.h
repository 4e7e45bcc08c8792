/* vol: a scalar 3D image on a regular grid, placed in patient space (LPS, millimetres).
 *
 * Voxels are stored as float in the source units (HU for CT, after any NIfTI/DICOM rescale),
 * i fastest, then j, then k. Voxel (i,j,k) has its centre at world = affine * [i j k 1]^T.
 * The upper 3x3 of the affine is direction cosines times spacing: orthogonal columns
 * (oblique grids are fine), never sheared (readers refuse or resample shear). */
#ifndef FN_VOL_H
#define FN_VOL_H

#include <stddef.h>
#include <stdint.h>

typedef enum {
    VOL_U8, VOL_I8, VOL_U16, VOL_I16, VOL_U32, VOL_I32, VOL_F32, VOL_F64
} vol_type;

typedef struct vol {
    int dim[3];            /* voxels along i, j, k */
    double spacing[3];     /* mm, the column norms of the affine's 3x3 */
    double affine[3][4];   /* index -> LPS mm */
    vol_type src_type;     /* the voxel type of the file it came from */
    float *data;           /* dim[0]*dim[1]*dim[2] values, owned */
} vol;

/* Bytes a volume may take: FRACNAV_MAX_BYTES from the environment (whole bytes), else 8 GiB (also
 * when the variable is malformed: vol_check_dims reports that). */
size_t vol_budget(void);
/* Checks dims are positive, the voxel count does not overflow, and count*elem_bytes fits the
 * budget. `what` names the file/field for the message. Returns 0 or FN_EFORMAT/FN_ENOMEM, or
 * FN_EINVAL when FRACNAV_MAX_BYTES is set but not a whole number of bytes over 0. */
int vol_check_dims(const int64_t dim[3], size_t elem_bytes, const char *what);

/* A zero-filled volume with identity spacing and affine; NULL (with fn_err) on bad dims or OOM. */
vol *vol_new(int nx, int ny, int nz);
void vol_free(vol *v);
/* Sets the affine from direction cosines (columns, unit), spacing and the origin (voxel 0 centre). */
void vol_set_geometry(vol *v, const double dir[3][3], const double spacing[3], const double origin[3]);

static inline size_t vol_count(const vol *v)
{
    return (size_t)v->dim[0] * (size_t)v->dim[1] * (size_t)v->dim[2];
}
static inline size_t vol_idx(const vol *v, int i, int j, int k)
{
    return ((size_t)k * (size_t)v->dim[1] + (size_t)j) * (size_t)v->dim[0] + (size_t)i;
}
/* world = affine * [i j k 1] */
void vol_index_to_world(const vol *v, const double ijk[3], double lps[3]);
/* The inverse, for orthogonal affines. */
void vol_world_to_index(const vol *v, const double lps[3], double ijk[3]);
/* Minimum and maximum voxel value, NaN left out; lo > hi (+inf, -inf) when every voxel is NaN. */
void vol_range(const vol *v, float *lo, float *hi);
const char *vol_type_name(vol_type t);

#endif
