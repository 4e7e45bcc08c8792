/* sheet: where a bone looks broken: a thin band of lower HU between two brighter ones.
 *
 * A fracture line in a CT is a thin sheet darker than the bone on both sides of it (the gap, or
 * the partial volume of two cortical edges pressed together). On the CT smoothed by a Gaussian of
 * SHEET_SIGMA_MM, the Hessian there has one large positive eigenvalue (the curvature across the
 * sheet) and two small ones (along it): Descoteaux et al.'s sheetness, taken for dark sheets. Its
 * strength is reported in HU/mm^2: lambda3 * exp(-(lambda2 / lambda3)^2 / (2 * 0.5^2)) where
 * lambda3 > 0 is the eigenvalue of largest magnitude and lambda2 the next, where the smoothed CT
 * SHEET_VALLEY_MM away on both sides along lambda3's eigenvector is brighter (a valley, not the
 * flank of a bright cortex or plate, which curves the same way), else 0. Voxels outside
 * the domain count as the value 0 (the background of a bone-only CT, or the box around a
 * fragment), so a gap between two fragments is a dark sheet too.
 *
 * Boxes as grow.h. OS-free, no global state. */
#ifndef FN_SHEET_H
#define FN_SHEET_H

#include <stdint.h>

#define SHEET_SIGMA_MM 1.0  /* the scale of a fracture line */
#define SHEET_VALLEY_MM 1.5 /* a sheet is darker than the smoothed CT this far on both sides */

/* The sheetness (HU/mm^2, >= 0) of each domain voxel of the box into out (one float per voxel,
 * 0 outside the domain). 0 or FN_ENOMEM. */
int sheet_map(const float *values, const uint8_t *domain, const int dim[3], const double sp[3], float *out);

#endif
