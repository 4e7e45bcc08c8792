/* volio: read and write volumes. Readers fill vol (vol.h) in LPS mm; src_type is the file's
 * voxel type, data is float after any rescale.
 *
 * Formats, chosen by the path's extension (case-insensitive):
 *   .nii .nii.gz  NIfTI-1 (single file), the header parsed here then converted by nifticlib:
 *                 sform preferred, else qform, else pixdim;
 *                 RAS is converted to LPS by negating the affine's first two rows; scl_slope and
 *                 scl_inter applied (slope 0 = none). 3D only (dim[4..7] must be 1). Types u8 i8
 *                 u16 i16 u32 i32 f32 f64. NIfTI-2 and .hdr/.img pairs are refused clearly.
 *   .nrrd .nhdr   NRRD via teem: space directions/origin honoured; space RAS, LAS, LPS or
 *                 scanner-xyz (LPS by definition); a bare "space dimension: 3" is taken as LPS,
 *                 as ITK does; no space at all -> spacings (and axis mins as origin), axis-aligned.
 *                 Encodings raw, gzip, ascii, hex (bzip2's size cannot be bounded: refused).
 *   .inv3         InVesalius 3 project (gzip'd tar: main.plist + raw little-endian matrix).
 *   a directory   one DICOM series, converted by running dcm2niix into a private folder under
 *                 $TMPDIR that is removed afterwards; for gantry tilt, dcm2niix's resampled
 *                 (_Tilt_) output is read, not the sheared one.
 *
 * Geometry: oblique direction cosines are kept; a sheared grid (direction columns not orthogonal
 * within 1e-4) is refused, naming the file and the field (sform, qform, space directions).
 *
 * InVesalius orientation: main.plist's matrix has shape (nk, nj, ni) and spacing (si, sj, sk).
 * The project keeps no origin or direction cosines. InVesalius always stores the matrix in the
 * axial layout: it flips every DICOM slice's rows on import (VTK keeps images bottom-up) and
 * restacks coronal and sagittal series into axial order, so the plist `orientation` key (1 axial,
 * 2 coronal, 3 sagittal; 0 axial in the oldest files) only records how the series was acquired.
 * The reader therefore uses one mapping for every orientation value, with voxel 0 at the origin:
 *   i -> L (+x), j -> A (-y), k -> S (+z)      affine = diag(si, -sj, sk)
 * Checked on the example CT: the face and frontal sinuses are at high j, the head holder (behind a
 * supine head) at low j, the vertex at high k. Left/right cannot be seen in a skull; it follows
 * the DICOM column direction (patient left), which InVesalius does not flip. An orientation key of
 * another value is refused.
 *
 * Bad input: only regular files are read (FIFOs and devices are refused before they are opened).
 * Headers are checked against what the file can hold and the memory budget (vol_check_dims)
 * before any voxel buffer is allocated: raw data its size, NRRD hex 2 characters a byte, ascii
 * 2 a value, NRRD gzip what it really inflates to (counted up to what is needed, nothing kept),
 * .nii.gz at most 1032 times its size; NIfTI header extensions are never read (over 64 MiB in a
 * .nii.gz: refused); an .inv3 holds at most 4096 tar entries. Short data is an error, never zero-filled. Geometry is never made up: a
 * NaN/infinite pixdim, quaternion, qoffset or srow (NIfTI), or spacing, axis min or space origin
 * (NRRD), a spacing <= 0, or a NRRD with neither space directions nor spacings is refused naming
 * the field; the one fallback is the NIfTI standard's qfac 0 -> 1, with a warning on stderr. Every
 * error names the file and the field or offset.
 * Thread safety: nifticlib and teem keep global state (debug level, error chains): call volio
 * from one thread at a time. */
#ifndef FN_VOLIO_H
#define FN_VOLIO_H

#include "vol.h"

/* Reads PATH by extension (see above). Returns a new volume (free with vol_free) or NULL with
 * fn_err set: "PATH: <field>: <cause>". */
vol *volio_read(const char *path);

/* Two segments of a 3D Slicer .seg.nrrd that hold the same voxels: `voxels` of them went to
 * fragment `fragment` (the earlier segment's) and not to `other` (the later one's). */
typedef struct volio_overlap {
    int fragment, other;
    size_t voxels;
} volio_overlap;

/* What volio_read_labels found besides the labelmap. */
typedef struct volio_segs {
    int segments;           /* SegmentN entries; 0: a labelmap without them (label k = fragment k) */
    int layers;             /* the .seg.nrrd's layers (1 for a 3D file; 0 without segments) */
    size_t unlisted;        /* voxels holding a value no segment lists: left as background */
    int noverlap;
    volio_overlap *overlap; /* noverlap entries by fragment, then other; owned */
} volio_segs;

/* Reads a labelmap of fragments for `segment --labels`. A NRRD (.nrrd, .nhdr) with 3D Slicer
 * segment keys (Segment<N>_LabelValue, Segment<N>_Layer, ...: a .seg.nrrd) is mapped by them:
 * segment N becomes fragment N + 1 wherever its layer holds its label value. Such a file is 3D
 * (one layer; Layer may be absent, meaning 0) or 4D, "multi-layer": the first axis (kind list or
 * none, no space direction) indexes the layers, the other three are space. A voxel that several
 * segments hold goes to the first of them (lowest N); the overlaps are counted per pair in
 * segs->overlap. Refused, naming the file and the key or field: a 4D NRRD without segment keys,
 * a missing or malformed LabelValue (whole number >= 1), a 4D file's missing Layer, a Layer out of
 * range, two segments with one label value in one layer, more than 65535 segments or layers; the
 * size, encoding and memory checks are those of volio_read, over all the layers, before any data
 * is read. Any other file (a NRRD without segment keys, NIfTI, ...) is read as volio_read does,
 * voxel values as they are (label k = fragment k), with segs->segments 0. Returns the labelmap
 * (free with vol_free; segs: volio_segs_free) or NULL with fn_err set. */
vol *volio_read_labels(const char *path, volio_segs *segs);
void volio_segs_free(volio_segs *segs);

/* Writes V to PATH (.nii .nii.gz .nrrd .nhdr; .nhdr also writes a .raw data file beside it),
 * converting voxels to TYPE: integer types round to nearest (ties to even) and clamp to the
 * type's range, NaN becomes 0. NIfTI gets sform and qform (code 1, scanner) in RAS; NRRD gets
 * space LPS with directions, raw encoding. A sheared affine is refused. Overwrites PATH in place
 * (callers that need atomic saves write a temporary name and rename). Returns 0 or a negative
 * FN_E* code with fn_err set. */
int volio_write(const vol *v, const char *path, vol_type type);

#endif
