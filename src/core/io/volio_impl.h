/* volio internals shared by volio.c (dispatch) and the format files volio_*.c; not for other
 * modules. Each format is one table row (volio.c): its extensions, reader and writer. */
#ifndef FN_VOLIO_IMPL_H
#define FN_VOLIO_IMPL_H

#include "volio.h"

#include <stddef.h>

/* One format: the file name's ending (lower case; matched case-insensitively), its reader and
 * its writer (NULL: read only). Readers and writers behave as volio_read and volio_write. */
typedef struct volio_format {
    const char *ext;
    vol *(*read)(const char *path);
    int (*write)(const vol *v, const char *path, vol_type type);
} volio_format;

vol *volio__read_inv3(const char *path);
vol *volio__read_nifti(const char *path);
vol *volio__read_nrrd(const char *path);
/* volio_read_labels for a NRRD (.nrrd, .nhdr); segs is zeroed by the caller. */
vol *volio__read_nrrd_labels(const char *path, volio_segs *segs);
/* volio_nrrdhdr.c */
/* Segments a .seg.nrrd may hold (and layers): a Slicer segmentation has tens. */
#define VOLIO_MAX_SEGMENTS 256
/* Reads path's NRRD header as teem will and refuses, naming the line, what teem must not see:
 * data files (single, LIST or numbered) that are not regular files inside the header's folder or
 * outnumber its slices, a numbered name that is not one bounded integer conversion, over 4096
 * key/value lines, a block size, and with `labels` segment numbers of VOLIO_MAX_SEGMENTS or more.
 * 0 also when path cannot be opened or is no NRRD (teem reports those). */
int volio__nrrd_scan(const char *path, int labels);
/* N of a key "Segment<N>_...", or -1 ("Segmentation_..." and every other key); -2 when N has
 * more digits than any segment number may. */
int volio__segment_number(const char *key);
/* A DICOM series folder (not a table row: a folder has no extension). */
vol *volio__read_dicom(const char *dir);
int volio__write_nifti(const vol *v, const char *path, vol_type type);
int volio__write_nrrd(const vol *v, const char *path, vol_type type);

/* volio_convert.c */
/* 0 if the columns of m (index axes) are finite, non-zero and orthogonal within 1e-4, else
 * FN_EFORMAT naming path and field. */
int volio__check_axes(const double m[3][3], const char *path, const char *field);
/* Voxel sizes a file may give, in mm: a micron to a metre (at 1e15 mm a contact search adding
 * 0.1 mm never moves). */
#define VOLIO_MIN_SPACING_MM 1e-3
#define VOLIO_MAX_SPACING_MM 1e3
/* 0 if every spacing is in VOLIO_MIN_SPACING_MM..VOLIO_MAX_SPACING_MM, else FN_EFORMAT naming
 * path, field and axis. */
int volio__check_spacing(const double sp[3], const char *path, const char *field);
/* Sets v's geometry from the index-to-LPS matrix a (columns: index axes, mm) and the origin:
 * checked as volio__check_axes and volio__check_spacing do, then split into direction cosines and
 * spacings. */
int volio__set_affine(vol *v, const double a[3][3], const double origin[3], const char *path,
                      const char *field);
size_t volio__type_size(vol_type t);
/* n values of type t (native byte order) -> float, as slope * x + inter (slope 1, inter 0 = as is). */
void volio__to_float(const void *src, vol_type t, size_t n, double slope, double inter, float *dst);
/* n floats -> type t (native byte order), rounding to nearest and clamping for integer types. */
void volio__from_float(const float *src, size_t n, vol_type t, void *dst);

#endif
