#include "grow.h"

#include "err.h"
#include "morph.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct item {
    float cost;
    uint32_t v;
} item;

struct grow {
    const float *values;
    const uint8_t *domain;
    int dim[3];
    double step[3];
    size_t n;
    float *cost;    /* the cheapest path cost known, INFINITY before any */
    float *thin;    /* per voxel: 1 / (its depth in mm + GROW_DEPTH_MM) */
    uint8_t *label;
    item *heap;     /* a binary min-heap on cost, with stale entries skipped when popped */
    size_t len, cap;
};

grow *grow_new(const float *values, const uint8_t *domain, const int dim[3], const double sp[3])
{
    size_t n = (size_t)dim[0] * dim[1] * dim[2];
    if (n >= UINT32_MAX) {
        fn_err_set(FN_EINVAL, "grow: the box has too many voxels (%zu)", n);
        return NULL;
    }
    grow *g = calloc(1, sizeof *g);
    if (g) {
        g->cost = malloc((n ? n : 1) * sizeof *g->cost);
        g->label = calloc(n ? n : 1, 1);
        g->cap = 4096;
        g->heap = malloc(g->cap * sizeof *g->heap);
    }
    if (!g || !g->cost || !g->label || !g->heap) {
        grow_free(g);
        fn_err_set(FN_ENOMEM, "grow: out of memory for %zu voxels", n);
        return NULL;
    }
    g->thin = malloc((n ? n : 1) * sizeof *g->thin);
    if (!g->thin) {
        grow_free(g);
        fn_err_set(FN_ENOMEM, "grow: out of memory for %zu voxels", n);
        return NULL;
    }
    morph_distance(domain, dim, sp, g->thin);
    for (size_t i = 0; i < n; i++)
        g->thin[i] = 1 / (g->thin[i] + (float)GROW_DEPTH_MM);
    g->values = values;
    g->domain = domain;
    g->n = n;
    for (int a = 0; a < 3; a++) {
        g->dim[a] = dim[a];
        g->step[a] = sp[a];
    }
    for (size_t i = 0; i < n; i++)
        g->cost[i] = INFINITY;
    return g;
}

void grow_free(grow *g)
{
    if (!g)
        return;
    free(g->cost);
    free(g->thin);
    free(g->label);
    free(g->heap);
    free(g);
}

static int push(grow *g, float cost, uint32_t v)
{
    if (g->len == g->cap) {
        item *h = realloc(g->heap, 2 * g->cap * sizeof *h);
        if (!h)
            return fn_err_set(FN_ENOMEM, "grow: out of memory for the queue (%zu entries)", 2 * g->cap);
        g->heap = h;
        g->cap *= 2;
    }
    size_t i = g->len++;
    while (i > 0 && g->heap[(i - 1) / 2].cost > cost) {
        g->heap[i] = g->heap[(i - 1) / 2];
        i = (i - 1) / 2;
    }
    g->heap[i] = (item){cost, v};
    return 0;
}

static item pop(grow *g)
{
    item top = g->heap[0], last = g->heap[--g->len];
    size_t i = 0;
    for (;;) {
        size_t c = 2 * i + 1;
        if (c >= g->len)
            break;
        if (c + 1 < g->len && g->heap[c + 1].cost < g->heap[c].cost)
            c++;
        if (g->heap[c].cost >= last.cost)
            break;
        g->heap[i] = g->heap[c];
        i = c;
    }
    g->heap[i] = last;
    return top;
}

void grow_clear(grow *g)
{
    for (size_t i = 0; i < g->n; i++)
        g->cost[i] = INFINITY;
    memset(g->label, 0, g->n);
    g->len = 0;
}

int grow_add_seed(grow *g, size_t v, int label)
{
    if (v >= g->n || !g->domain[v])
        return fn_err_set(FN_EINVAL, "grow: voxel %zu of the box is outside the domain", v);
    if (label < 1 || label > GROW_MAX_LABEL)
        return fn_err_set(FN_EINVAL, "grow: label %d is not 1..%d", label, GROW_MAX_LABEL);
    if (g->cost[v] == 0 && g->label[v] != label)
        return fn_err_set(FN_EINVAL, "grow: voxel %zu is seeded with label %d already", v, g->label[v]);
    g->cost[v] = 0;
    g->label[v] = (uint8_t)label;
    return push(g, 0, (uint32_t)v);
}

int grow_run(grow *g)
{
    const int nx = g->dim[0], ny = g->dim[1], nz = g->dim[2];
    const long stride[3] = {1, nx, (long)nx * ny};
    const float step[3] = {(float)g->step[0], (float)g->step[1], (float)g->step[2]}, contrast = 1 / GROW_CONTRAST_HU;
    while (g->len) {
        item it = pop(g);
        if (it.cost > g->cost[it.v])
            continue; /* a cheaper path reached it after this entry was queued */
        size_t v = it.v;
        int c[3] = {(int)(v % (size_t)nx), (int)(v / (size_t)nx % (size_t)ny), (int)(v / ((size_t)nx * ny))};
        float here = g->values[v];
        for (int a = 0; a < 3; a++)
            for (int s = -1; s <= 1; s += 2) {
                int to = c[a] + s;
                if (to < 0 || to >= (a == 0 ? nx : a == 1 ? ny : nz))
                    continue;
                size_t q = (size_t)((long)v + s * stride[a]);
                if (!g->domain[q])
                    continue;
                float cost = it.cost + step[a] * g->thin[q] * (1 + fabsf(g->values[q] - here) * contrast);
                if (cost < g->cost[q]) {
                    g->cost[q] = cost;
                    g->label[q] = g->label[v];
                    if (push(g, cost, (uint32_t)q) < 0)
                        return FN_ENOMEM;
                }
            }
    }
    return 0;
}

void grow_weigh(grow *g, const float *w)
{
    for (size_t i = 0; i < g->n; i++)
        g->thin[i] *= w[i];
}

const uint8_t *grow_labels(const grow *g)
{
    return g->label;
}
