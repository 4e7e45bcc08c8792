#include "split.h"

#include "err.h"
#include "grow.h"
#include "morph.h"
#include "sheet.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Up to SPLIT_SEEDS voxels at least SPLIT_DEEP_MM deep, each the farthest from those before it
 * (the first the deepest), at least SPLIT_SPACING_MM apart. Returns their count. */
static int spread_seeds(const float *depth, const int dim[3], const double sp[3], size_t n, float *far2,
                        size_t *seeds)
{
    size_t deepest = 0;
    for (size_t v = 0; v < n; v++) {
        far2[v] = depth[v] >= SPLIT_DEEP_MM ? INFINITY : -1;
        deepest = depth[v] > depth[deepest] ? v : deepest;
    }
    int k = 0;
    seeds[k++] = deepest;
    while (k < SPLIT_SEEDS) {
        size_t s = seeds[k - 1], best = 0;
        double c[3] = {(double)(s % (size_t)dim[0]), (double)(s / (size_t)dim[0] % (size_t)dim[1]),
                       (double)(s / ((size_t)dim[0] * dim[1]))};
        float top = -1;
        size_t v = 0;
        for (int z = 0; z < dim[2]; z++)
            for (int y = 0; y < dim[1]; y++)
                for (int x = 0; x < dim[0]; x++, v++) {
                    if (far2[v] < 0)
                        continue;
                    double d[3] = {(x - c[0]) * sp[0], (y - c[1]) * sp[1], (z - c[2]) * sp[2]};
                    float d2 = (float)(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                    if (d2 < far2[v])
                        far2[v] = d2;
                    if (far2[v] > top) {
                        top = far2[v];
                        best = v;
                    }
                }
        if (top < SPLIT_SPACING_MM * SPLIT_SPACING_MM)
            break;
        seeds[k++] = best;
    }
    return k;
}

/* facing[a * stride + b]: surface voxels of region a that see region b across the background
 * within SPLIT_GAP_MM; contact[a * stride + b]: voxel faces between a and b; broken[a * stride + b]:
 * those of them on a fracture line (the sheetness of either voxel >= SPLIT_SHEET_HU). */
static void region_graph(const uint8_t *domain, const uint8_t *label, const float *sheet, const int dim[3],
                         const double sp[3], int stride, size_t *facing, size_t *contact, size_t *broken)
{
    const long st[3] = {1, dim[0], (long)dim[0] * dim[1]};
    uint8_t seen[GROW_MAX_LABEL + 1];
    size_t v = 0;
    for (int z = 0; z < dim[2]; z++)
        for (int y = 0; y < dim[1]; y++)
            for (int x = 0; x < dim[0]; x++, v++) {
                int a = label[v];
                if (!a)
                    continue;
                int p[3] = {x, y, z}, surface = 0;
                for (int ax = 0; ax < 3; ax++)
                    for (int s = -1; s <= 1; s += 2) {
                        int q = p[ax] + s;
                        if (q < 0 || q >= dim[ax]) {
                            surface = 1;
                            continue;
                        }
                        size_t w = (size_t)((long)v + s * st[ax]);
                        if (!domain[w])
                            surface = 1;
                        else if (s > 0 && label[w] && label[w] != a) {
                            contact[a * stride + label[w]]++;
                            contact[label[w] * stride + a]++;
                            if (fmaxf(sheet[v], sheet[w]) >= SPLIT_SHEET_HU) {
                                broken[a * stride + label[w]]++;
                                broken[label[w] * stride + a]++;
                            }
                        }
                    }
                if (!surface)
                    continue;
                memset(seen, 0, sizeof seen);
                for (int d = 0; d < 27; d++) {
                    int dd[3] = {d % 3 - 1, d / 3 % 3 - 1, d / 9 - 1};
                    double len = sqrt(dd[0] * dd[0] * sp[0] * sp[0] + dd[1] * dd[1] * sp[1] * sp[1] +
                                      dd[2] * dd[2] * sp[2] * sp[2]);
                    if (d == 13)
                        continue;
                    for (int t = 1; t * len <= SPLIT_GAP_MM; t++) {
                        int q[3] = {x + t * dd[0], y + t * dd[1], z + t * dd[2]};
                        if (q[0] < 0 || q[1] < 0 || q[2] < 0 || q[0] >= dim[0] || q[1] >= dim[1] || q[2] >= dim[2])
                            break;
                        size_t w = ((size_t)q[2] * dim[1] + q[1]) * dim[0] + q[0];
                        if (!domain[w])
                            continue;
                        if (t > 1 && label[w] && label[w] != a && !seen[label[w]]) {
                            seen[label[w]] = 1;
                            facing[a * stride + label[w]]++;
                        }
                        break;
                    }
                }
            }
}

/* The two halves of *g grown again, each from its own deepest voxel (its distance map into dist):
 * the seeds the split found lie anywhere in the thick of the halves, and a seed deep in each
 * fragment places the cut best (docs/benchmarks.md). *g becomes the new growth. */
static int regrow_from_cores(const float *values, const uint8_t *domain, const int dim[3], const double sp[3],
                             const float *weight, float *dist, grow **g)
{
    size_t n = (size_t)dim[0] * dim[1] * dim[2], deepest[2] = {0, 0};
    uint8_t *half = malloc(n);
    if (!half)
        return fn_err_set(FN_ENOMEM, "split: out of memory for %zu voxels", n);
    for (int h = 0; h < 2; h++) {
        for (size_t v = 0; v < n; v++)
            half[v] = grow_labels(*g)[v] == h + 1;
        morph_distance(half, dim, sp, dist);
        for (size_t v = 0; v < n; v++)
            deepest[h] = dist[v] > dist[deepest[h]] ? v : deepest[h];
    }
    free(half);
    grow *r = grow_new(values, domain, dim, sp);
    if (!r)
        return FN_ENOMEM;
    grow_weigh(r, weight);
    int rc = grow_add_seed(r, deepest[0], 1);
    if (rc == 0)
        rc = grow_add_seed(r, deepest[1], 2);
    if (rc == 0)
        rc = grow_run(r);
    grow_free(*g);
    *g = r;
    return rc;
}

int split_auto(const float *values, const uint8_t *domain, const int dim[3], const double sp[3], int32_t *lab)
{
    size_t n = (size_t)dim[0] * dim[1] * dim[2];
    float *depth = malloc(n * sizeof *depth), *far2 = malloc(n * sizeof *far2);
    if (!depth || !far2) {
        free(depth);
        free(far2);
        return fn_err_set(FN_ENOMEM, "split: out of memory for %zu voxels", n);
    }
    morph_distance(domain, dim, sp, depth);
    size_t seeds[SPLIT_SEEDS];
    int k = spread_seeds(depth, dim, sp, n, far2, seeds);
    /* the depth and the seeds' distances are done with: their room holds the sheetness, and the
     * growth's barrier on fracture lines */
    float *sheet = depth, *weight = far2;
    int rc = sheet_map(values, domain, dim, sp, sheet);
    for (size_t v = 0; v < n; v++)
        weight[v] = 1 + sheet[v] / (float)SPLIT_BARRIER_HU;
    grow *g = k > 1 && rc == 0 ? grow_new(values, domain, dim, sp) : NULL;
    if (g)
        grow_weigh(g, weight);
    rc = rc == 0 && k > 1 && !g ? FN_ENOMEM : rc;
    for (int s = 0; g && s < k && rc == 0; s++)
        rc = grow_add_seed(g, seeds[s], s + 1);
    if (g && rc == 0)
        rc = grow_run(g);
    int stride = k + 1;
    size_t *facing = calloc((size_t)stride * stride, sizeof *facing), *contact = calloc((size_t)stride * stride,
                                                                                         sizeof *contact);
    size_t *broken = calloc((size_t)stride * stride, sizeof *broken);
    if (rc == 0 && (!facing || !contact || !broken))
        rc = fn_err_set(FN_ENOMEM, "split: out of memory");
    if (g && rc == 0) {
        const uint8_t *label = grow_labels(g);
        region_graph(domain, label, sheet, dim, sp, stride, facing, contact, broken);
    }
    /* The pairs of regions whose cut is most broken (facing + broken) for their contact, best first:
     * grown again from those two seeds alone, two halves are the fragments when the cut between
     * them is broken and narrow (split.h). */
    int pair[SPLIT_TRIES][2] = {{0}};
    double ratio[SPLIT_TRIES] = {0};
    for (int a = 1; g && a <= k; a++)
        for (int b = a + 1; b <= k; b++) {
            size_t c = contact[a * stride + b], f = facing[a * stride + b] + facing[b * stride + a];
            double r = c ? (double)(f + broken[a * stride + b]) / (double)c : 0;
            for (int t = 0; t < SPLIT_TRIES; t++)
                if (r >= SPLIT_FACING_MIN && r > ratio[t]) {
                    memmove(&ratio[t + 1], &ratio[t], (size_t)(SPLIT_TRIES - 1 - t) * sizeof *ratio);
                    memmove(&pair[t + 1], &pair[t], (size_t)(SPLIT_TRIES - 1 - t) * sizeof *pair);
                    ratio[t] = r;
                    pair[t][0] = a;
                    pair[t][1] = b;
                    break;
                }
        }
    int pieces = 1;
    for (int t = 0; t < SPLIT_TRIES && pair[t][0] && rc == 0 && pieces == 1; t++) {
        grow_free(g);
        g = grow_new(values, domain, dim, sp);
        if (g)
            grow_weigh(g, weight);
        rc = !g ? FN_ENOMEM : grow_add_seed(g, seeds[pair[t][0] - 1], 1);
        if (rc == 0)
            rc = grow_add_seed(g, seeds[pair[t][1] - 1], 2);
        if (rc == 0)
            rc = grow_run(g);
        memset(facing, 0, (size_t)stride * stride * sizeof *facing);
        memset(contact, 0, (size_t)stride * stride * sizeof *contact);
        memset(broken, 0, (size_t)stride * stride * sizeof *broken);
        if (rc == 0)
            region_graph(domain, grow_labels(g), sheet, dim, sp, stride, facing, contact, broken);
        size_t c = contact[1 * stride + 2], f = facing[1 * stride + 2] + facing[2 * stride + 1], br = broken[1 * stride + 2];
        size_t half[3] = {0, 0, 0};
        for (size_t v = 0; rc == 0 && v < n; v++)
            half[grow_labels(g)[v]]++;
        size_t small = half[1] < half[2] ? half[1] : half[2];
        double small_ml = (double)small * sp[0] * sp[1] * sp[2] / 1000, neck = (double)c / pow((double)small, 2.0 / 3);
        pieces = rc == 0 && f + br >= SPLIT_BROKEN_MIN * (double)c && neck <= SPLIT_NECK_MAX && small_ml >= SPLIT_MIN_ML &&
                         (double)small >= SPLIT_MIN_SHARE * (double)(half[1] + half[2])
                     ? 2
                     : 1;
    }
    if (pieces == 2 && rc == 0)
        rc = regrow_from_cores(values, domain, dim, sp, weight, sheet, &g);
    for (size_t v = 0; v < n && rc == 0; v++)
        lab[v] = !domain[v] ? 0 : pieces == 2 ? grow_labels(g)[v] : 1;
    grow_free(g);
    free(depth);
    free(far2);
    free(broken);
    free(facing);
    free(contact);
    return rc < 0 ? rc : pieces;
}

int split_rejoin(const float *values, const uint8_t *domain, const int dim[3], const double sp[3],
                 const int32_t *lab, int n, int *join)
{
    size_t nv = (size_t)dim[0] * dim[1] * dim[2], stride = (size_t)n + 1;
    float *sheet = malloc(nv * sizeof *sheet);
    uint8_t *label = malloc(nv);
    size_t *facing = calloc(stride * stride, sizeof *facing), *contact = calloc(stride * stride, sizeof *contact);
    size_t *broken = calloc(stride * stride, sizeof *broken), *count = calloc(stride, sizeof *count);
    int rc = sheet && label && facing && contact && broken && count && n < GROW_MAX_LABEL
                 ? 0
                 : fn_err_set(FN_ENOMEM, "split: out of memory for %zu voxels", nv);
    if (rc == 0)
        rc = sheet_map(values, domain, dim, sp, sheet);
    for (size_t v = 0; rc == 0 && v < nv; v++) {
        label[v] = (uint8_t)(domain[v] ? lab[v] : 0);
        count[label[v]]++;
    }
    if (rc == 0)
        region_graph(domain, label, sheet, dim, sp, (int)stride, facing, contact, broken);
    for (int a = 1; a <= n; a++)
        join[a] = a;
    /* each piece joins the lowest piece it reaches over cuts that are neither broken nor narrow */
    for (int a = 1; rc == 0 && a <= n; a++)
        for (int b = a + 1; b <= n; b++) {
            size_t i = (size_t)a * stride + b, j = (size_t)b * stride + a;
            size_t small = count[a] < count[b] ? count[a] : count[b];
            if (!contact[i] || facing[i] + facing[j] + broken[i] >= SPLIT_BROKEN_MIN * (double)contact[i] ||
                (double)contact[i] <= SPLIT_NECK_MAX * pow((double)small, 2.0 / 3))
                continue;
            int ra = join[a], rb = join[b], lo = ra < rb ? ra : rb, hi = ra < rb ? rb : ra;
            for (int p = 1; p <= n; p++)
                join[p] = join[p] == hi ? lo : join[p];
        }
    free(sheet);
    free(label);
    free(facing);
    free(contact);
    free(broken);
    free(count);
    return rc;
}
