/* pose: rigid transforms as a unit quaternion + translation, in double precision.
 *
 * A pose maps a point x to R(q) x + t. A fragment's pose maps its home world position (LPS mm,
 * as segmented) to its current world position; at load every pose is the identity. */
#ifndef FN_POSE_H
#define FN_POSE_H

typedef struct pose {
    double q[4]; /* w, x, y, z; unit */
    double t[3]; /* mm */
} pose;

static const pose POSE_IDENTITY = {{1, 0, 0, 0}, {0, 0, 0}};

/* a then b: the result maps x to b(a(x)). */
pose pose_compose(pose b, pose a);
pose pose_inverse(pose p);
void pose_apply(const pose *p, const double x[3], double y[3]);
/* rotation only */
void pose_rotate(const pose *p, const double x[3], double y[3]);
/* Row-major 3x3 rotation matrix. */
void pose_to_matrix(const pose *p, double r[3][3]);
/* From a rotation matrix (orthonormal) and translation. */
pose pose_from_matrix(const double r[3][3], const double t[3]);
/* Rotation of `angle` radians about unit `axis`, no translation. */
pose pose_from_axis_angle(const double axis[3], double angle);
/* Rotation vector (axis * angle, radians) + translation. */
pose pose_from_rotvec(const double rv[3], const double t[3]);
/* p's rotation as a rotation vector (axis * angle, radians, the angle in 0..pi); returns the angle. */
double pose_to_rotvec(const pose *p, double rv[3]);
/* Renormalises q and makes w >= 0 so equal rotations compare equal. */
void pose_normalize(pose *p);
/* Angle of the relative rotation between a and b (radians) and the distance between t's (mm). */
double pose_angle_between(pose a, pose b);
double pose_distance(pose a, pose b);

#endif
