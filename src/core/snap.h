/* snap: quick software pictures of a segmentation, written as PNG (no GL needed).
 *
 * snap_labels_png renders a labelmap as seen along one volume axis: each pixel shows the first
 * labelled voxel on its ray, in that label's colour, shaded by depth, over a grey maximum-intensity
 * projection of the CT (when ct is given). Pixels are resampled to square millimetres. */
#ifndef FN_SNAP_H
#define FN_SNAP_H

#include "vol.h"

#include <stdint.h>

/* rgb[label] for labels 0..nlabels-1 (0 = background, unused). view_axis 0, 1 or 2 is the voxel
 * axis looked along; from_end = 1 looks from the axis's high end towards index 0. The picture is
 * scaled up by a whole factor until its longer side reaches 512 pixels. ct may be NULL; when given
 * it must have the labels' dimensions.
 * Returns 0 or a negative FN_E* code with fn_err set (file name included). */
int snap_labels_png(const vol *labels, const vol *ct, const uint8_t (*rgb)[3], int nlabels, int view_axis,
                    int from_end, const char *path);

/* Writes an 8-bit RGB image (w*h*3 bytes, rows top to bottom) to path, atomically. */
int snap_write_png(const char *path, const uint8_t *rgb, int w, int h);

#endif
