#include "sheet.h"

#include "err.h"

#include <math.h>
#include <stdlib.h>

/* Convolves f along axis ax (voxel step in mm) with a Gaussian of SHEET_SIGMA_MM, in place; line
 * and out hold one line each. */
static void blur_axis(float *f, const int dim[3], double step, int ax, float *line, float *out)
{
    const long st[3] = {1, dim[0], (long)dim[0] * dim[1]};
    int r = (int)ceil(3 * SHEET_SIGMA_MM / step);
    float w[64];
    r = r > 31 ? 31 : r;
    double sum = 0;
    for (int t = -r; t <= r; t++)
        sum += w[t + r] = (float)exp(-0.5 * (t * step / SHEET_SIGMA_MM) * (t * step / SHEET_SIGMA_MM));
    for (int t = 0; t <= 2 * r; t++)
        w[t] = (float)(w[t] / sum);
    int a1 = (ax + 1) % 3, a2 = (ax + 2) % 3;
    for (int p = 0; p < dim[a2]; p++)
        for (int q = 0; q < dim[a1]; q++) {
            long base = p * st[a2] + q * st[a1];
            for (int t = 0; t < dim[ax]; t++)
                line[t] = f[base + t * st[ax]];
            for (int t = 0; t < dim[ax]; t++) {
                float acc = 0;
                for (int u = -r; u <= r; u++) {
                    int s = t + u;
                    if (s >= 0 && s < dim[ax])
                        acc += w[u + r] * line[s];
                }
                out[t] = acc;
            }
            for (int t = 0; t < dim[ax]; t++)
                f[base + t * st[ax]] = out[t];
        }
}

/* The eigenvalues of the symmetric matrix (a b c / b d e / c e f), by the trigonometric closed form. */
static void eigenvalues(double a, double b, double c, double d, double e, double f, double l[3])
{
    double p1 = b * b + c * c + e * e, q = (a + d + f) / 3;
    if (p1 < 1e-12) {
        l[0] = a, l[1] = d, l[2] = f;
        return;
    }
    double p2 = (a - q) * (a - q) + (d - q) * (d - q) + (f - q) * (f - q) + 2 * p1, p = sqrt(p2 / 6);
    double B[6] = {(a - q) / p, b / p, c / p, (d - q) / p, e / p, (f - q) / p};
    double r = (B[0] * (B[3] * B[5] - B[4] * B[4]) - B[1] * (B[1] * B[5] - B[4] * B[2]) +
                B[2] * (B[1] * B[4] - B[3] * B[2])) / 2;
    double phi = r <= -1 ? M_PI / 3 : r >= 1 ? 0 : acos(r) / 3;
    l[0] = q + 2 * p * cos(phi);
    l[2] = q + 2 * p * cos(phi + 2 * M_PI / 3);
    l[1] = 3 * q - l[0] - l[2];
}

/* The smoothed value s at the point p (voxel coordinates), trilinear, clamped to the box. */
static double at(const float *s, const int dim[3], const double p[3])
{
    int i0[3];
    double f[3];
    for (int a = 0; a < 3; a++) {
        double c = fmin(fmax(p[a], 0), dim[a] - 1);
        i0[a] = (int)c < dim[a] - 1 ? (int)c : dim[a] - 2;
        i0[a] = i0[a] < 0 ? 0 : i0[a];
        f[a] = dim[a] > 1 ? c - i0[a] : 0;
    }
    double sum = 0;
    for (int d = 0; d < 8; d++) {
        int q[3] = {i0[0] + (d & 1), i0[1] + (d >> 1 & 1), i0[2] + (d >> 2)};
        double w = 1;
        for (int a = 0; a < 3; a++) {
            q[a] = q[a] < dim[a] ? q[a] : dim[a] - 1;
            w *= d >> a & 1 ? f[a] : 1 - f[a];
        }
        sum += w * s[((size_t)q[2] * dim[1] + q[1]) * dim[0] + q[0]];
    }
    return sum;
}

/* The unit eigenvector of the symmetric h for its eigenvalue l: the longest cross product of two
 * rows of h - l I. 0 when they are all (nearly) parallel. */
static int eigenvector(const double h[3][3], double l, double n[3])
{
    double m[3][3], best = 0;
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            m[a][b] = h[a][b] - (a == b ? l : 0);
    for (int r = 0; r < 3; r++) {
        const double *u = m[r], *w = m[(r + 1) % 3];
        double c[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
        double len = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
        if (len > best) {
            best = len;
            for (int a = 0; a < 3; a++)
                n[a] = c[a];
        }
    }
    if (!(best > 0))
        return 0;
    for (int a = 0; a < 3; a++)
        n[a] /= sqrt(best);
    return 1;
}

int sheet_map(const float *values, const uint8_t *domain, const int dim[3], const double sp[3], float *out)
{
    size_t n = (size_t)dim[0] * dim[1] * dim[2];
    int longest = dim[0] > dim[1] ? dim[0] : dim[1];
    longest = longest > dim[2] ? longest : dim[2];
    float *s = malloc(n * sizeof *s), *line = malloc(2 * (size_t)longest * sizeof *line);
    if (!s || !line) {
        free(s);
        free(line);
        return fn_err_set(FN_ENOMEM, "sheet: out of memory for %zu voxels", n);
    }
    for (size_t v = 0; v < n; v++)
        s[v] = domain[v] ? values[v] : 0;
    for (int ax = 0; ax < 3; ax++)
        blur_axis(s, dim, sp[ax], ax, line, line + longest);
    const long st[3] = {1, dim[0], (long)dim[0] * dim[1]};
    size_t v = 0;
    for (int z = 0; z < dim[2]; z++)
        for (int y = 0; y < dim[1]; y++)
            for (int x = 0; x < dim[0]; x++, v++) {
                out[v] = 0;
                if (!domain[v] || x == 0 || y == 0 || z == 0 || x == dim[0] - 1 || y == dim[1] - 1 ||
                    z == dim[2] - 1)
                    continue;
                double h[3][3];
                for (int a = 0; a < 3; a++)
                    for (int b = a; b < 3; b++) {
                        if (a == b)
                            h[a][a] = (s[v + st[a]] - 2 * s[v] + s[v - st[a]]) / (sp[a] * sp[a]);
                        else
                            h[a][b] = h[b][a] = (s[v + st[a] + st[b]] - s[v + st[a] - st[b]] - s[v - st[a] + st[b]] +
                                                 s[v - st[a] - st[b]]) / (4 * sp[a] * sp[b]);
                    }
                double l[3];
                eigenvalues(h[0][0], h[0][1], h[0][2], h[1][1], h[1][2], h[2][2], l);
                /* by magnitude: l3 the largest (l[0] or l[2]), l2 the next */
                double l3 = fabs(l[2]) > fabs(l[0]) ? l[2] : l[0], l1 = fabs(l[2]) > fabs(l[0]) ? l[0] : l[2];
                double l2 = fabs(l[1]) > fabs(l1) ? l[1] : l1;
                double nrm[3], lo[3], hi[3];
                if (!(l3 > 0) || !eigenvector(h, l3, nrm))
                    continue;
                for (int a = 0; a < 3; a++) {
                    double c = a == 0 ? x : a == 1 ? y : z, d = SHEET_VALLEY_MM * nrm[a] / sp[a];
                    lo[a] = c - d;
                    hi[a] = c + d;
                }
                /* a valley: brighter on both sides across it, not the flank of a bright plate */
                if (at(s, dim, lo) > s[v] && at(s, dim, hi) > s[v])
                    out[v] = (float)(l3 * exp(-(l2 / l3) * (l2 / l3) * 2));
            }
    free(s);
    free(line);
    return 0;
}
