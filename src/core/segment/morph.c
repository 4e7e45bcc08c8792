/* morph: filling enclosed interiors and separating touching pieces (see
 * morph.h). */
#include "morph.h"

#include "err.h"
#include "seg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define NONE UINT32_MAX

/* Breadth-first (6-connected) over the voxels where mask == 0, from the voxels
 * queued and marked in seen. */
static void reach(const uint8_t *mask, uint8_t *seen, uint32_t *queue, size_t tail, const int *ext,
                  const size_t *stride)
{
    size_t head = 0;
    while (head < tail) {
        size_t v = queue[head++];
        for (int a = 0; a < 3; a++) {
            int c = (int)(v / stride[a] % (size_t)ext[a]);
            if (c > 0 && !mask[v - stride[a]] && !seen[v - stride[a]]) {
                seen[v - stride[a]] = 1;
                queue[tail++] = (uint32_t)(v - stride[a]);
            }
            if (c + 1 < ext[a] && !mask[v + stride[a]] && !seen[v + stride[a]]) {
                seen[v + stride[a]] = 1;
                queue[tail++] = (uint32_t)(v + stride[a]);
            }
        }
    }
}

long morph_fill(uint8_t *mask, const int dim[3], int mode)
{
    size_t n = (size_t)dim[0] * dim[1] * dim[2];
    if (n >= NONE)
        return fn_err_set(FN_ENOMEM, "fill: the box has too many voxels (%zu)", n);
    uint8_t *seen = calloc(n ? n : 1, 1);
    uint32_t *queue = malloc((n ? n : 1) * sizeof *queue);
    if (!seen || !queue) {
        free(seen);
        free(queue);
        return fn_err_set(FN_ENOMEM, "fill: out of memory for %zu voxels", n);
    }
    const size_t stride[3] = {1, (size_t)dim[0], (size_t)dim[0] * dim[1]};
    long filled = 0;
    if (mode & MORPH_FILL_3D) {
        size_t tail = 0;
        for (int k = 0; k < dim[2]; k++)
            for (int j = 0; j < dim[1]; j++)
                for (int i = 0; i < dim[0]; i++) {
                    size_t v = (size_t)k * stride[2] + (size_t)j * stride[1] + (size_t)i;
                    int border = !i || !j || !k || i == dim[0] - 1 || j == dim[1] - 1 || k == dim[2] - 1;
                    if (border && !mask[v]) {
                        seen[v] = 1;
                        queue[tail++] = (uint32_t)v;
                    }
                }
        reach(mask, seen, queue, tail, dim, stride);
        for (size_t v = 0; v < n; v++)
            if (!mask[v] && !seen[v]) {
                mask[v] = 1;
                filled++;
            }
    }
    if (mode & MORPH_FILL_SLICES)
        for (int a = 0; a < 3; a++) {
            int u = (a + 1) % 3, w = (a + 2) % 3;
            int ext[2] = {dim[u], dim[w]};
            size_t st[2] = {stride[u], stride[w]};
            for (int s = 0; s < dim[a]; s++) {
                size_t base = (size_t)s * stride[a], tail = 0;
                for (int y = 0; y < ext[1]; y++)
                    for (int x = 0; x < ext[0]; x++) {
                        size_t v = base + (size_t)x * st[0] + (size_t)y * st[1];
                        seen[v] = 0;
                    }
                for (int y = 0; y < ext[1]; y++)
                    for (int x = 0; x < ext[0]; x++) {
                        size_t v = base + (size_t)x * st[0] + (size_t)y * st[1];
                        if ((!x || !y || x == ext[0] - 1 || y == ext[1] - 1) && !mask[v]) {
                            seen[v] = 1;
                            queue[tail++] = (uint32_t)v;
                        }
                    }
                /* 4-connected within the slice: coordinates from the strides directly
                 */
                size_t head = 0;
                while (head < tail) {
                    size_t v = queue[head++], rel = v - base;
                    int c[2] = {(int)(rel / st[0] % (size_t)ext[0]), (int)(rel / st[1] % (size_t)ext[1])};
                    for (int b = 0; b < 2; b++) {
                        if (c[b] > 0 && !mask[v - st[b]] && !seen[v - st[b]]) {
                            seen[v - st[b]] = 1;
                            queue[tail++] = (uint32_t)(v - st[b]);
                        }
                        if (c[b] + 1 < ext[b] && !mask[v + st[b]] && !seen[v + st[b]]) {
                            seen[v + st[b]] = 1;
                            queue[tail++] = (uint32_t)(v + st[b]);
                        }
                    }
                }
                for (int y = 0; y < ext[1]; y++)
                    for (int x = 0; x < ext[0]; x++) {
                        size_t v = base + (size_t)x * st[0] + (size_t)y * st[1];
                        if (!mask[v] && !seen[v]) {
                            mask[v] = 1;
                            filled++;
                        }
                    }
            }
        }
    free(seen);
    free(queue);
    return filled;
}

void morph_distance(const uint8_t *mask, const int dim[3], const double sp[3], float *dist)
{
    const int nx = dim[0], ny = dim[1], nz = dim[2];
    size_t n = (size_t)nx * ny * nz;
    for (size_t v = 0; v < n; v++)
        dist[v] = mask[v] ? INFINITY : 0;
    for (int pass = 0; pass < 2; pass++) {
        int s = pass ? -1 : 1;
        for (int kk = 0; kk < nz; kk++)
            for (int jj = 0; jj < ny; jj++)
                for (int ii = 0; ii < nx; ii++) {
                    int i = pass ? nx - 1 - ii : ii, j = pass ? ny - 1 - jj : jj, k = pass ? nz - 1 - kk : kk;
                    size_t v = ((size_t)k * ny + j) * nx + i;
                    if (!mask[v])
                        continue;
                    float d = dist[v];
                    /* the 13 neighbours that come before in this pass's order */
                    for (int dk = -1; dk <= 0; dk++)
                        for (int dj = -1; dj <= 1; dj++)
                            for (int di = -1; di <= 1; di++) {
                                if (dk == 0 && (dj > 0 || (dj == 0 && di >= 0)))
                                    continue;
                                int a = i + s * di, b = j + s * dj, c = k + s * dk;
                                float w = (float)sqrt(di * di * sp[0] * sp[0] + dj * dj * sp[1] * sp[1] +
                                                      dk * dk * sp[2] * sp[2]);
                                float cand;
                                if (a < 0 || b < 0 || c < 0 || a >= nx || b >= ny || c >= nz)
                                    cand = w;
                                else
                                    cand = dist[((size_t)c * ny + b) * nx + a] + w;
                                if (cand < d)
                                    d = cand;
                            }
                    dist[v] = d;
                }
    }
}

/* One line of n squared distances (stride apart) through the lower envelope of their parabolas
 * s2 * (q - p)^2 + f[p]: f, v (n each) and z (n + 1) are scratch. Infinite entries are no sites. */
static void envelope_line(float *d, size_t stride, int n, double s2, double *f, int *v, double *z)
{
    int k = -1;
    for (int q = 0; q < n; q++) {
        f[q] = d[(size_t)q * stride];
        if (isinf(f[q]))
            continue;
        double x = -INFINITY;
        while (k >= 0) {
            x = ((f[q] + s2 * q * q) - (f[v[k]] + s2 * v[k] * v[k])) / (2 * s2 * (q - v[k]));
            if (x > z[k])
                break;
            k--;
        }
        k++;
        v[k] = q;
        z[k] = k ? x : -INFINITY;
        z[k + 1] = INFINITY;
    }
    for (int q = 0, j = 0; q < n && k >= 0; q++) {
        while (z[j + 1] < q)
            j++;
        d[(size_t)q * stride] = (float)(s2 * (q - v[j]) * (q - v[j]) + f[v[j]]);
    }
}

int morph_distance_to(const uint8_t *mask, const int dim[3], const double sp[3], float *dist)
{
    size_t n = (size_t)dim[0] * (size_t)dim[1] * (size_t)dim[2];
    int most = dim[0] > dim[1] ? dim[0] : dim[1];
    most = most > dim[2] ? most : dim[2];
    double *f = malloc((size_t)most * sizeof *f), *z = malloc(((size_t)most + 1) * sizeof *z);
    int *v = malloc((size_t)most * sizeof *v);
    if (!f || !z || !v) {
        free(f);
        free(z);
        free(v);
        return fn_err_set(FN_ENOMEM, "out of memory for a distance map of %dx%dx%d voxels", dim[0], dim[1], dim[2]);
    }
    for (size_t i = 0; i < n; i++)
        dist[i] = mask[i] ? 0.0f : INFINITY;
    const size_t stride[3] = {1, (size_t)dim[0], (size_t)dim[0] * (size_t)dim[1]};
    for (int a = 0; a < 3; a++) {
        int u = a ? 0 : 1, w = a == 2 ? 1 : 2; /* the other two axes */
        for (int j = 0; j < dim[w]; j++)
            for (int i = 0; i < dim[u]; i++)
                envelope_line(dist + (size_t)i * stride[u] + (size_t)j * stride[w], stride[a], dim[a],
                              sp[a] * sp[a], f, v, z);
    }
    for (size_t i = 0; i < n; i++)
        dist[i] = sqrtf(dist[i]);
    free(f);
    free(z);
    free(v);
    return 0;
}

/* The cores: components of dist > e, those of fewer than min_voxels voxels or
 * under 5% of the largest dropped, numbered 1..returned count in lab (0
 * elsewhere). core: scratch of one byte per voxel. */
static int cores(const float *dist, size_t n, const int dim[3], double e, size_t min_voxels, uint8_t *core,
                 int32_t *lab)
{
    for (size_t v = 0; v < n; v++)
        core[v] = dist[v] > e;
    int nc = seg_components(core, dim, lab);
    if (nc <= 0)
        return nc;
    size_t *count = calloc((size_t)nc + 1, sizeof *count);
    int32_t *map = calloc((size_t)nc + 1, sizeof *map);
    if (!count || !map) {
        free(count);
        free(map);
        return fn_err_set(FN_ENOMEM, "separate: out of memory");
    }
    for (size_t v = 0; v < n; v++)
        count[lab[v]]++;
    size_t largest = 0;
    for (int c = 1; c <= nc; c++)
        largest = count[c] > largest ? count[c] : largest;
    /* a core under 5% of the largest is a crumb of a thin part, not a piece */
    size_t least = min_voxels > largest / 20 ? min_voxels : largest / 20;
    int kept = 0;
    for (int c = 1; c <= nc; c++)
        map[c] = count[c] >= least ? ++kept : 0;
    for (size_t v = 0; v < n; v++)
        lab[v] = map[lab[v]];
    free(count);
    free(map);
    return kept;
}

/* One marker per seed (voxel coordinates of the box), numbered 1..nseeds in lab. nseeds, or
 * FN_EINVAL naming a seed outside the mask. */
static int seed_markers(const uint8_t *mask, const int dim[3], const int (*seeds)[3], int nseeds, int32_t *lab)
{
    int nm = 0;
    for (int s = 0; s < nseeds; s++) {
        const int *q = seeds[s];
        int in = q[0] >= 0 && q[1] >= 0 && q[2] >= 0 && q[0] < dim[0] && q[1] < dim[1] && q[2] < dim[2];
        size_t v = in ? ((size_t)q[2] * dim[1] + q[1]) * dim[0] + q[0] : 0;
        if (!in || !mask[v])
            return fn_err_set(FN_EINVAL,
                              "separate: seed %d (voxel %d, %d, %d of the fragment's "
                              "box) is not in the fragment",
                              s + 1, q[0], q[1], q[2]);
        lab[v] = ++nm;
    }
    return nm;
}

/* The markers of the least erosion (steps of half the finest spacing) that splits the mask in
 * two or more cores; none (lab all 0) when no erosion does. Their number, or negative; *used:
 * the erosion. */
static int eroded_markers(const float *dist, size_t n, const int dim[3], const double sp[3], double dmax,
                          size_t min_voxels, uint8_t *core, int32_t *lab, double *used)
{
    double step = 0.5 * fmin(sp[0], fmin(sp[1], sp[2]));
    int nm = 0;
    for (double e = step; e < dmax; e += step) {
        nm = cores(dist, n, dim, e, min_voxels, core, lab);
        if (nm < 0)
            return nm;
        if (nm >= 2) {
            *used = e;
            return nm;
        }
        if (nm == 0)
            break;
    }
    memset(lab, 0, n * sizeof *lab); /* no erosion splits it: one piece */
    return 0;
}

/* Grows the markers of lab inside mask by a priority flood from the deepest voxels (levels of
 * 1/8 of the finest spacing). next: scratch of one uint32_t per voxel. 0 or FN_ENOMEM. */
static int flood(const uint8_t *mask, const int dim[3], const double sp[3], const float *dist, double dmax,
                 int32_t *lab, uint32_t *next)
{
    size_t n = (size_t)dim[0] * dim[1] * dim[2];
    double q = fmin(sp[0], fmin(sp[1], sp[2])) / 8;
    int L = (int)(dmax / q) + 2;
    uint32_t *head = malloc((size_t)L * sizeof *head);
    if (!head)
        return fn_err_set(FN_ENOMEM, "separate: out of memory");
    for (int l = 0; l < L; l++)
        head[l] = NONE;
    for (size_t v = 0; v < n; v++)
        if (lab[v]) {
            int l = (int)(dist[v] / q);
            next[v] = head[l];
            head[l] = (uint32_t)v;
        }
    const size_t stride[3] = {1, (size_t)dim[0], (size_t)dim[0] * dim[1]};
    for (int cur = L - 1; cur >= 0;) {
        if (head[cur] == NONE) {
            cur--;
            continue;
        }
        size_t v = head[cur];
        head[cur] = next[v];
        int c[3] = {(int)(v % (size_t)dim[0]), (int)(v / stride[1] % (size_t)dim[1]), (int)(v / stride[2])};
        for (int dk = -1; dk <= 1; dk++)
            for (int dj = -1; dj <= 1; dj++)
                for (int di = -1; di <= 1; di++) {
                    int x = c[0] + di, y = c[1] + dj, z = c[2] + dk;
                    if (x < 0 || y < 0 || z < 0 || x >= dim[0] || y >= dim[1] || z >= dim[2])
                        continue;
                    size_t w = (size_t)z * stride[2] + (size_t)y * stride[1] + (size_t)x;
                    if (!mask[w] || lab[w])
                        continue;
                    lab[w] = lab[v];
                    int l = (int)(dist[w] / q);
                    l = l < cur ? l : cur;
                    next[w] = head[l];
                    head[l] = (uint32_t)w;
                }
    }
    free(head);
    return 0;
}

int morph_separate(const uint8_t *mask, const int dim[3], const double sp[3], double erode_mm, const int (*seeds)[3],
                   int nseeds, size_t min_voxels, int32_t *lab, double *erode_used)
{
    size_t n = (size_t)dim[0] * dim[1] * dim[2];
    if (n >= NONE)
        return fn_err_set(FN_ENOMEM, "separate: the box has too many voxels (%zu)", n);
    float *dist = malloc((n ? n : 1) * sizeof *dist);
    uint8_t *core = malloc(n ? n : 1);
    uint32_t *next = malloc((n ? n : 1) * sizeof *next);
    int rc = dist && core && next ? 0 : fn_err_set(FN_ENOMEM, "separate: out of memory for %zu voxels", n);
    int nm = 0, nr = 0;
    double used = 0, dmax = 0;
    if (rc == 0) {
        morph_distance(mask, dim, sp, dist);
        for (size_t v = 0; v < n; v++)
            dmax = fmax(dmax, dist[v]);
        memset(lab, 0, n * sizeof *lab);
        if (nseeds > 0) {
            rc = nm = seed_markers(mask, dim, seeds, nseeds, lab);
        } else if (erode_mm > 0) {
            used = erode_mm;
            rc = nm = cores(dist, n, dim, erode_mm, min_voxels, core, lab);
        } else
            rc = nm = eroded_markers(dist, n, dim, sp, dmax, min_voxels, core, lab, &used);
    }
    if (rc >= 0)
        rc = flood(mask, dim, sp, dist, dmax, lab, next);
    if (rc >= 0) {
        /* parts of the mask no marker reached: pieces of their own */
        for (size_t v = 0; v < n; v++)
            core[v] = mask[v] && !lab[v];
        int32_t *rest = (int32_t *)next; /* same size, no longer needed */
        nr = seg_components(core, dim, rest);
        if (nr < 0)
            rc = nr;
        for (size_t v = 0; v < n && nr > 0; v++)
            if (core[v])
                lab[v] = nm + rest[v];
        if (erode_used)
            *erode_used = used;
    }
    free(dist);
    free(core);
    free(next);
    return rc < 0 ? rc : nm + (nr > 0 ? nr : 0);
}
