/* report: an HTML page of a case's plan, for any browser: renders before and after the
 * reduction (the renderer, offscreen), the optimizer's convergence plot (PLplot's pngcairo device),
 * and per fragment the move, the contact area, the remaining gap and overlap volumes, and the
 * errors against the ground truth when the case has one.
 *
 * "Before" is each fragment's pose before the case's last automatic reduction (the "reduction"
 * record of case.json: "placed"); without a record, its home position (as segmented). "After" is
 * its current pose. The convergence plot needs the record's "history" values: without them the
 * page says there is no plot. Where the renderer cannot open (no GL 4.5: FN_ENODEV) the page says
 * so instead of showing renders, and a warning goes to stderr. Every file (index.html, before-*.png, after-*.png, convergence.png)
 * is written atomically into dir (created when missing).
 *
 * Threads: the caller's thread only (GL context, PLplot's global state). Errors: 0 or FN_E* with
 * the file named. */
#ifndef FN_REPORT_H
#define FN_REPORT_H

#include "case.h"

typedef void (*report_wrote_fn)(void *ctx, const char *path);

/* The gap across a fragment's fracture surface in its planned pose (planned labelmap), per face.
 * With ground truth the fracture surface is known: the faces its voxels share with another
 * fragment's when every fragment is at its truth; each is carried to the planned pose, and its gap
 * is the distance from there to the nearest other fragment (an exact distance map, less the half
 * voxel from a face to the voxel centres; 0 inside another). At the truth: 0 mm. Without it:
 * from every face of its voxels that borders another voxel, the empty space along the face's
 * normal up to another fragment's voxel; faces that meet none within REPORT_GAP_REACH_MM (the
 * bone's outer surfaces) do not count, but faces across a cavity or the air beside the fracture
 * line from the other piece do (the example skull's fracture at its truth: max 4.79 mm). */
#define REPORT_GAP_REACH_MM 5.0
typedef struct report_gap {
    double median_mm, p95_mm, max_mm; /* NAN when no face meets another fragment */
    long faces;                       /* the faces measured */
} report_gap;
/* Per fragment (index order) into gaps. 0 or FN_ENOMEM. */
int report_gaps(const planning_case *c, const vol *planned, report_gap *gaps);

/* planned: export_planned_labels(c); overlap_ml: per fragment, the sum of its pairs' overlaps
 * (case_penetrating, case_overlap_ml). platform: render_open's (NULL: osmesa). wrote,
 * when given, is called with each file's path once it is in place. */
int report_write(const planning_case *c, const vol *planned, const double *overlap_ml, const char *dir,
                 const char *platform, report_wrote_fn wrote, void *ctx);

#endif
