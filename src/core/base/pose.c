#include "pose.h"

#include <math.h>

static void qmul(const double a[4], const double b[4], double r[4])
{
    double w = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    double x = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    double y = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    double z = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
    r[0] = w;
    r[1] = x;
    r[2] = y;
    r[3] = z;
}

void pose_rotate(const pose *p, const double x[3], double y[3])
{
    /* v' = v + 2w (u x v) + 2 u x (u x v), u = (qx,qy,qz) */
    const double *q = p->q;
    double cx = q[2] * x[2] - q[3] * x[1];
    double cy = q[3] * x[0] - q[1] * x[2];
    double cz = q[1] * x[1] - q[2] * x[0];
    double dx = q[2] * cz - q[3] * cy;
    double dy = q[3] * cx - q[1] * cz;
    double dz = q[1] * cy - q[2] * cx;
    y[0] = x[0] + 2 * (q[0] * cx + dx);
    y[1] = x[1] + 2 * (q[0] * cy + dy);
    y[2] = x[2] + 2 * (q[0] * cz + dz);
}

void pose_apply(const pose *p, const double x[3], double y[3])
{
    double r[3];
    pose_rotate(p, x, r);
    y[0] = r[0] + p->t[0];
    y[1] = r[1] + p->t[1];
    y[2] = r[2] + p->t[2];
}

pose pose_compose(pose b, pose a)
{
    pose r;
    qmul(b.q, a.q, r.q);
    pose_rotate(&b, a.t, r.t);
    for (int i = 0; i < 3; i++)
        r.t[i] += b.t[i];
    pose_normalize(&r);
    return r;
}

pose pose_inverse(pose p)
{
    pose r = {{p.q[0], -p.q[1], -p.q[2], -p.q[3]}, {0, 0, 0}};
    double t[3];
    pose_rotate(&r, p.t, t);
    for (int i = 0; i < 3; i++)
        r.t[i] = -t[i];
    return r;
}

void pose_to_matrix(const pose *p, double r[3][3])
{
    double w = p->q[0], x = p->q[1], y = p->q[2], z = p->q[3];
    r[0][0] = 1 - 2 * (y * y + z * z);
    r[0][1] = 2 * (x * y - w * z);
    r[0][2] = 2 * (x * z + w * y);
    r[1][0] = 2 * (x * y + w * z);
    r[1][1] = 1 - 2 * (x * x + z * z);
    r[1][2] = 2 * (y * z - w * x);
    r[2][0] = 2 * (x * z - w * y);
    r[2][1] = 2 * (y * z + w * x);
    r[2][2] = 1 - 2 * (x * x + y * y);
}

pose pose_from_matrix(const double m[3][3], const double t[3])
{
    pose p;
    double tr = m[0][0] + m[1][1] + m[2][2];
    if (tr > 0) {
        double s = sqrt(tr + 1.0) * 2;
        p.q[0] = 0.25 * s;
        p.q[1] = (m[2][1] - m[1][2]) / s;
        p.q[2] = (m[0][2] - m[2][0]) / s;
        p.q[3] = (m[1][0] - m[0][1]) / s;
    } else if (m[0][0] > m[1][1] && m[0][0] > m[2][2]) {
        double s = sqrt(1.0 + m[0][0] - m[1][1] - m[2][2]) * 2;
        p.q[0] = (m[2][1] - m[1][2]) / s;
        p.q[1] = 0.25 * s;
        p.q[2] = (m[0][1] + m[1][0]) / s;
        p.q[3] = (m[0][2] + m[2][0]) / s;
    } else if (m[1][1] > m[2][2]) {
        double s = sqrt(1.0 + m[1][1] - m[0][0] - m[2][2]) * 2;
        p.q[0] = (m[0][2] - m[2][0]) / s;
        p.q[1] = (m[0][1] + m[1][0]) / s;
        p.q[2] = 0.25 * s;
        p.q[3] = (m[1][2] + m[2][1]) / s;
    } else {
        double s = sqrt(1.0 + m[2][2] - m[0][0] - m[1][1]) * 2;
        p.q[0] = (m[1][0] - m[0][1]) / s;
        p.q[1] = (m[0][2] + m[2][0]) / s;
        p.q[2] = (m[1][2] + m[2][1]) / s;
        p.q[3] = 0.25 * s;
    }
    for (int i = 0; i < 3; i++)
        p.t[i] = t ? t[i] : 0;
    pose_normalize(&p);
    return p;
}

pose pose_from_axis_angle(const double axis[3], double angle)
{
    double n = sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
    pose p = POSE_IDENTITY;
    if (n == 0)
        return p;
    double s = sin(angle / 2) / n;
    p.q[0] = cos(angle / 2);
    p.q[1] = axis[0] * s;
    p.q[2] = axis[1] * s;
    p.q[3] = axis[2] * s;
    pose_normalize(&p);
    return p;
}

pose pose_from_rotvec(const double rv[3], const double t[3])
{
    double a = sqrt(rv[0] * rv[0] + rv[1] * rv[1] + rv[2] * rv[2]);
    pose p = POSE_IDENTITY;
    if (a > 0)
        p = pose_from_axis_angle(rv, a);
    for (int i = 0; i < 3; i++)
        p.t[i] = t ? t[i] : 0;
    return p;
}

double pose_to_rotvec(const pose *p, double rv[3])
{
    double w = fabs(p->q[0]) > 1 ? 1 : fabs(p->q[0]), sgn = p->q[0] < 0 ? -1 : 1;
    double s = sqrt(p->q[1] * p->q[1] + p->q[2] * p->q[2] + p->q[3] * p->q[3]);
    double a = 2 * atan2(s, w); /* q and -q are the same turn: the one of angle <= pi */
    for (int i = 0; i < 3; i++)
        rv[i] = s > 0 ? sgn * p->q[i + 1] / s * a : 0;
    return a;
}

void pose_normalize(pose *p)
{
    double n = sqrt(p->q[0] * p->q[0] + p->q[1] * p->q[1] + p->q[2] * p->q[2] + p->q[3] * p->q[3]);
    if (n == 0) {
        p->q[0] = 1;
        p->q[1] = p->q[2] = p->q[3] = 0;
        return;
    }
    double s = p->q[0] < 0 ? -1 / n : 1 / n;
    for (int i = 0; i < 4; i++)
        p->q[i] *= s;
}

double pose_angle_between(pose a, pose b)
{
    double d = fabs(a.q[0] * b.q[0] + a.q[1] * b.q[1] + a.q[2] * b.q[2] + a.q[3] * b.q[3]);
    if (d > 1)
        d = 1;
    return 2 * acos(d);
}

double pose_distance(pose a, pose b)
{
    double d0 = a.t[0] - b.t[0], d1 = a.t[1] - b.t[1], d2 = a.t[2] - b.t[2];
    return sqrt(d0 * d0 + d1 * d1 + d2 * d2);
}
