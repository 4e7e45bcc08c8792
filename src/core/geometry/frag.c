#include "frag.h"

#include "err.h"
#include "seg.h"
#include "vol.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void frag_free(frag *f)
{
    if (!f)
        return;
    free(f->prob);
    f->prob = NULL;
}

void frag_colour(int id, uint8_t rgb[3])
{
    static const uint8_t palette[][3] = {
        {230, 216, 190}, {220, 90, 80},  {80, 160, 220}, {110, 190, 90},  {240, 180, 60},
        {170, 110, 200}, {70, 200, 190}, {230, 120, 170}, {150, 150, 70}, {120, 120, 230},
    };
    const int np = (int)(sizeof palette / sizeof palette[0]);
    if (id >= 1 && id <= np) {
        memcpy(rgb, palette[id - 1], 3);
        return;
    }
    /* Golden-ratio hue steps keep later colours apart; HSV with s = 0.6, v = 0.9. */
    double h = (double)id * 0.6180339887498949;
    h = (h - floor(h)) * 6;
    int sector = (int)h;
    double f = h - sector, v = 0.9, p = v * 0.4, q = v * (1 - 0.6 * f), t = v * (1 - 0.6 * (1 - f));
    double c[6][3] = {{v, t, p}, {q, v, p}, {p, v, t}, {p, q, v}, {t, p, v}, {v, p, q}};
    for (int a = 0; a < 3; a++)
        rgb[a] = (uint8_t)(c[sector % 6][a] * 255 + 0.5);
}

void frag_local_to_source(const frag *f, const int l[3], int s[3])
{
    for (int a = 0; a < 3; a++)
        s[a] = f->origin[a] + (f->flip[a] ? f->dim[a] - 1 - l[a] : l[a]);
}

void frag_voxel_world(const frag *f, const int l[3], double w[3])
{
    double x[3] = {l[0] * f->spacing[0], l[1] * f->spacing[1], l[2] * f->spacing[2]};
    pose_apply(&f->home, x, w);
}

/* home = [D F | world(corner)], D the grid's direction cosines, F the flips, corner the source
 * index that crop voxel 0 maps to. A left-handed grid gets axis 0 flipped so home is proper. */
static void set_home(frag *f, const vol *g)
{
    double d[3][3];
    for (int c = 0; c < 3; c++)
        for (int r = 0; r < 3; r++)
            d[r][c] = g->affine[r][c] / g->spacing[c];
    double det = d[0][0] * (d[1][1] * d[2][2] - d[1][2] * d[2][1]) -
                 d[0][1] * (d[1][0] * d[2][2] - d[1][2] * d[2][0]) +
                 d[0][2] * (d[1][0] * d[2][1] - d[1][1] * d[2][0]);
    f->flip[0] = det < 0;
    f->flip[1] = f->flip[2] = 0;
    double corner[3], t[3];
    for (int a = 0; a < 3; a++) {
        corner[a] = f->origin[a] + (f->flip[a] ? f->dim[a] - 1 : 0);
        f->spacing[a] = g->spacing[a];
    }
    for (int c = 0; c < 3; c++)
        if (f->flip[c])
            for (int r = 0; r < 3; r++)
                d[r][c] = -d[r][c];
    vol_index_to_world(g, corner, t);
    f->home = pose_from_matrix(d, t);
}

int frag_label_box(const vol *lab, int id, int lo[3], int hi[3])
{
    for (int a = 0; a < 3; a++) {
        lo[a] = lab->dim[a];
        hi[a] = -1;
    }
    size_t idx = 0;
    for (int k = 0; k < lab->dim[2]; k++)
        for (int j = 0; j < lab->dim[1]; j++)
            for (int i = 0; i < lab->dim[0]; i++, idx++) {
                if (lab->data[idx] != (float)id)
                    continue;
                int ijk[3] = {i, j, k};
                for (int a = 0; a < 3; a++) {
                    if (ijk[a] < lo[a])
                        lo[a] = ijk[a];
                    if (ijk[a] > hi[a])
                        hi[a] = ijk[a];
                }
            }
    return hi[0] >= 0 ? 0 : fn_err_set(FN_EFORMAT, "label %d has no voxel", id);
}

int frag_from_labels(frag *f, const vol *labels, const vol *ct, int id, const int lo[3],
                     const int hi[3], double threshold, double ramp)
{
    memset(f, 0, sizeof *f);
    int64_t dim[3];
    for (int a = 0; a < 3; a++) {
        if (lo[a] > hi[a] || lo[a] < 0 || hi[a] >= labels->dim[a])
            return fn_err_set(FN_EINVAL, "fragment %d: empty or out-of-grid box on axis %d", id, a);
        f->origin[a] = lo[a] - 1;
        dim[a] = (int64_t)hi[a] - lo[a] + 3;
        f->dim[a] = (int)dim[a];
    }
    int rc = vol_check_dims(dim, 1, "fragment crop");
    if (rc < 0)
        return rc;
    f->prob = calloc((size_t)dim[0] * (size_t)dim[1] * (size_t)dim[2], 1);
    if (!f->prob)
        return fn_err_set(FN_ENOMEM, "fragment %d: out of memory for its crop", id);
    f->id = id;
    snprintf(f->name, sizeof f->name, "fragment %d", id);
    frag_colour(id, f->rgb);
    f->pose = POSE_IDENTITY;
    set_home(f, labels);
    /* row by row: along i the source index steps by one, backwards where axis 0 is flipped */
    int step = f->flip[0] ? -1 : 1;
    for (int k = 0; k < f->dim[2]; k++)
        for (int j = 0; j < f->dim[1]; j++) {
            int l[3] = {0, j, k}, s[3];
            frag_local_to_source(f, l, s);
            if (s[1] < 0 || s[2] < 0 || s[1] >= labels->dim[1] || s[2] >= labels->dim[2])
                continue;
            uint8_t *row = f->prob + ((size_t)k * f->dim[1] + j) * f->dim[0];
            for (int i = 0, x = s[0]; i < f->dim[0]; i++, x += step) {
                if (x < 0 || x >= labels->dim[0])
                    continue;
                size_t si = vol_idx(labels, x, s[1], s[2]);
                if (labels->data[si] == (float)id) {
                    uint8_t p = ct ? seg_prob(ct->data[si], threshold, ramp) : 255;
                    row[i] = p < FRAG_PROB_LABELLED ? FRAG_PROB_LABELLED : p;
                }
            }
        }
    frag_stats(f);
    return 0;
}

static void jacobi_rotate(double a[3][3], double v[3][3], int p, int q)
{
    if (a[p][q] == 0)
        return;
    double theta = (a[q][q] - a[p][p]) / (2 * a[p][q]);
    double t = (theta >= 0 ? 1 : -1) / (fabs(theta) + sqrt(theta * theta + 1));
    double c = 1 / sqrt(t * t + 1), s = t * c;
    for (int k = 0; k < 3; k++) {
        double akp = a[k][p], akq = a[k][q];
        a[k][p] = c * akp - s * akq;
        a[k][q] = s * akp + c * akq;
    }
    for (int k = 0; k < 3; k++) {
        double apk = a[p][k], aqk = a[q][k];
        a[p][k] = c * apk - s * aqk;
        a[q][k] = s * apk + c * aqk;
    }
    for (int k = 0; k < 3; k++) {
        double vkp = v[k][p], vkq = v[k][q];
        v[k][p] = c * vkp - s * vkq;
        v[k][q] = s * vkp + c * vkq;
    }
}

void frag_eigen_sym3(const double in[3][3], double vec[3][3], double val[3])
{
    double a[3][3], v[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    memcpy(a, in, sizeof a);
    for (int sweep = 0; sweep < 50; sweep++) {
        double off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        double diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
        if (off <= 1e-30 * diag || off == 0)
            break;
        jacobi_rotate(a, v, 0, 1);
        jacobi_rotate(a, v, 0, 2);
        jacobi_rotate(a, v, 1, 2);
    }
    int order[3] = {0, 1, 2};
    for (int i = 0; i < 3; i++)
        for (int j = i + 1; j < 3; j++)
            if (a[order[j]][order[j]] > a[order[i]][order[i]]) {
                int t = order[i];
                order[i] = order[j];
                order[j] = t;
            }
    for (int c = 0; c < 2; c++) {
        int big = 0;
        for (int r = 1; r < 3; r++)
            if (fabs(v[r][order[c]]) > fabs(v[big][order[c]]))
                big = r;
        double sign = v[big][order[c]] < 0 ? -1 : 1;
        for (int r = 0; r < 3; r++)
            vec[r][c] = sign * v[r][order[c]];
    }
    vec[0][2] = vec[1][0] * vec[2][1] - vec[2][0] * vec[1][1];
    vec[1][2] = vec[2][0] * vec[0][1] - vec[0][0] * vec[2][1];
    vec[2][2] = vec[0][0] * vec[1][1] - vec[1][0] * vec[0][1];
    for (int c = 0; c < 3; c++)
        val[c] = a[order[c]][order[c]];
}

void frag_stats(frag *f)
{
    /* Sums relative to the crop centre keep the covariance well conditioned. */
    double c0[3] = {0.5 * (f->dim[0] - 1), 0.5 * (f->dim[1] - 1), 0.5 * (f->dim[2] - 1)};
    double s1[3] = {0}, s2[3][3] = {{0}};
    size_t n = 0, li = 0;
    for (int k = 0; k < f->dim[2]; k++)
        for (int j = 0; j < f->dim[1]; j++)
            for (int i = 0; i < f->dim[0]; i++, li++) {
                if (!f->prob[li])
                    continue;
                double x[3] = {(i - c0[0]) * f->spacing[0], (j - c0[1]) * f->spacing[1],
                               (k - c0[2]) * f->spacing[2]};
                n++;
                for (int a = 0; a < 3; a++) {
                    s1[a] += x[a];
                    for (int b = 0; b < 3; b++)
                        s2[a][b] += x[a] * x[b];
                }
            }
    f->voxels = n;
    f->volume_ml = (double)n * f->spacing[0] * f->spacing[1] * f->spacing[2] / 1000.0;
    double mean[3] = {0}, cov[3][3] = {{0}};
    if (n) {
        for (int a = 0; a < 3; a++)
            mean[a] = s1[a] / (double)n;
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++)
                cov[a][b] = s2[a][b] / (double)n - mean[a] * mean[b];
    }
    double local[3] = {mean[0] + c0[0] * f->spacing[0], mean[1] + c0[1] * f->spacing[1],
                       mean[2] + c0[2] * f->spacing[2]};
    pose_apply(&f->home, local, f->centroid);
    /* Covariance in home world: R cov R^T. */
    double r[3][3], rc[3][3], w[3][3];
    pose_to_matrix(&f->home, r);
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            rc[a][b] = r[a][0] * cov[0][b] + r[a][1] * cov[1][b] + r[a][2] * cov[2][b];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            w[a][b] = rc[a][0] * r[b][0] + rc[a][1] * r[b][1] + rc[a][2] * r[b][2];
    frag_eigen_sym3(w, f->axes, f->eigval);
}

int frag_holds(const frag *f, const double x[3])
{
    pose to_local = pose_inverse(pose_compose(f->pose, f->home));
    double l[3];
    pose_apply(&to_local, x, l);
    long v[3];
    for (int a = 0; a < 3; a++) {
        v[a] = lround(l[a] / f->spacing[a]);
        if (!(v[a] >= 0 && v[a] < f->dim[a]))
            return 0;
    }
    return f->prob[((size_t)v[2] * (size_t)f->dim[1] + (size_t)v[1]) * (size_t)f->dim[0] + (size_t)v[0]] > 0;
}
