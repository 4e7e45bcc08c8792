/* volio: read and write volumes. Readers fill vol (src/vol.h) in LPS mm.
 *
 * Formats, chosen by the path's extension (case-insensitive):
 *   .nii .nii.gz  NIfTI-1/2 via nifticlib: sform preferred, else qform, else pixdim; RAS is
 *                 converted to LPS by negating the affine's first two rows; scl_slope/scl_inter
 *                 applied. Types u8 i8 u16 i16 u32 i32 f32 f64.
 *   .nrrd .nhdr   NRRD via teem: space directions/origin honoured; space RAS, LPS or
 *                 scanner-xyz (taken as LPS, as ITK does); no space -> spacings only.
 *   .inv3         InVesalius 3 project (gzip'd tar: main.plist + raw little-endian matrix).
 *   a directory   a DICOM series, converted by running dcm2niix into a temporary folder.
 *
 * Geometry: oblique direction cosines are kept; a sheared grid (direction columns not orthogonal
 * within 1e-4) is refused, naming the file and the field (sform, qform, space directions).
 *
 * InVesalius orientation: main.plist's matrix has shape (nk, nj, ni) and spacing (si, sj, sk).
 * InVesalius keeps no origin or direction cosines, so the reader places the volume in LPS with
 * voxel 0 at the origin and an axis-aligned grid given by the plist `orientation` key
 * (1 axial, 2 coronal, 3 sagittal; the values of InVesalius' constants):
 *   axial:    i -> L, j -> P, k -> S   (the DICOM display order of axial slices)
 *   coronal:  i -> L, j -> S, k -> P
 *   sagittal: i -> P, j -> S, k -> L
 * so anatomy lands on the right LPS axes and the grid is a rotation (det +1) of index space.
 *
 * Bad input: headers are checked against the file size and the memory budget (vol_check_dims)
 * before any voxel buffer is allocated; every error names the file and the field or offset.
 * Thread safety: none of these keep state, but nifticlib and teem print to stderr (silenced where
 * they allow it); call them from one thread at a time. */
#ifndef FN_VOLIO_H
#define FN_VOLIO_H

#include "vol.h"

/* Reads PATH by extension (see above). Returns a new volume (free with vol_free) or NULL with
 * fn_err set: "PATH: <field>: <cause>". */
vol *volio_read(const char *path);

/* Writes V to PATH (.nii .nii.gz .nrrd .nhdr; .nhdr also writes a .raw data file beside it),
 * converting voxels to TYPE: integer types round to nearest and clamp to the type's range.
 * NIfTI gets sform and qform (code 1, scanner) in RAS; NRRD gets space LPS with directions.
 * Returns 0 or a negative FN_E* code with fn_err set. */
int volio_write(const vol *v, const char *path, vol_type type);

#endif
