/* obb: the two-stage hierarchy build (bottom-up min/max/box pyramid, top-down breadth-first prune). */
#include "obb.h"

#include "err.h"
#include "obb_impl.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

#define MAX_LEVELS 18
#define MAX_NODES (1u << 24)

struct obb_tree {
    obb_node *nodes;
    size_t n;
    double spacing[3];
    int depth;
    obb_params params;
};

/* One pyramid level: per cell the min and max effective probability and the tight box of its bone
 * voxels. Level 1 keeps an 8-bit occupancy mask instead of a box (its box follows from the mask). */
typedef struct level {
    int dim[3];
    uint8_t *mn, *mx, *mask;
    uint16_t (*box)[6];
} level;

typedef struct builder {
    const uint8_t *prob;
    uint8_t lut[256];
    level lv[MAX_LEVELS];
    int top;
    obb_node *nodes;
    uint32_t *cell;  /* per emitted node: its cell index in its level */
    uint8_t *lvl;    /* per emitted node: its level */
    uint8_t *dep;    /* per emitted node: its depth */
    size_t n, cap;
} builder;

uint8_t obb_effective_prob(uint8_t p, const obb_params *params)
{
    double lo = params ? params->tau_min : 0, hi = params ? params->tau_max : 1;
    double v = p / 255.0;
    if (p == 0 || v < lo)
        return 0;
    if (p == 255 || v > hi)
        return 255;
    return p;
}

static size_t cells(const int d[3])
{
    return (size_t)d[0] * (size_t)d[1] * (size_t)d[2];
}

/* Level 1 from the voxels, row by row so the inner loop streams memory. */
static void level1(builder *b, const int d0[3])
{
    level *L = &b->lv[1];
    size_t nx = (size_t)L->dim[0];
    memset(L->mn, 255, cells(L->dim));
    memset(L->mx, 0, cells(L->dim));
    memset(L->mask, 0, cells(L->dim));
    for (int ck = 0; ck < L->dim[2]; ck++)
        for (int cj = 0; cj < L->dim[1]; cj++) {
            size_t row = ((size_t)ck * L->dim[1] + cj) * nx;
            uint8_t *mn = L->mn + row, *mx = L->mx + row, *mk = L->mask + row;
            for (int dz = 0; dz < 2 && 2 * ck + dz < d0[2]; dz++)
                for (int dy = 0; dy < 2 && 2 * cj + dy < d0[1]; dy++) {
                    const uint8_t *src =
                        b->prob + ((size_t)(2 * ck + dz) * d0[1] + (2 * cj + dy)) * (size_t)d0[0];
                    uint8_t bit = (uint8_t)(1u << (dz * 4 + dy * 2));
                    for (size_t ci = 0; ci < nx; ci++) {
                        uint8_t e = b->lut[src[2 * ci]];
                        uint8_t lo = mn[ci] < e ? mn[ci] : e, hi = mx[ci] > e ? mx[ci] : e;
                        uint8_t m = e ? bit : 0;
                        if (2 * ci + 1 < (size_t)d0[0]) {
                            uint8_t f = b->lut[src[2 * ci + 1]];
                            lo = lo < f ? lo : f;
                            hi = hi > f ? hi : f;
                            m |= f ? (uint8_t)(bit << 1) : 0;
                        }
                        mn[ci] = lo, mx[ci] = hi, mk[ci] |= m;
                    }
                }
        }
}

/* Tight box of cell idx (coordinates c) at level l, in voxel indices. */
static void cell_box(const builder *b, int l, size_t idx, const int c[3], uint16_t lo[3],
                     uint16_t hi[3])
{
    if (l == 0) {
        for (int i = 0; i < 3; i++)
            lo[i] = hi[i] = (uint16_t)c[i];
    } else if (l == 1) {
        static const uint8_t low[3] = {0x55, 0x33, 0x0f}; /* bits of the lower half on each axis */
        uint8_t m = b->lv[1].mask[idx];
        for (int i = 0; i < 3; i++) {
            lo[i] = (uint16_t)(2 * c[i] + ((m & low[i]) ? 0 : 1));
            hi[i] = (uint16_t)(2 * c[i] + ((m & (uint8_t)~low[i]) ? 1 : 0));
        }
    } else {
        memcpy(lo, b->lv[l].box[idx], 3 * sizeof(uint16_t));
        memcpy(hi, b->lv[l].box[idx] + 3, 3 * sizeof(uint16_t));
    }
}

static uint8_t cell_mn(const builder *b, int l, size_t idx)
{
    return l == 0 ? b->lut[b->prob[idx]] : b->lv[l].mn[idx];
}

static uint8_t cell_mx(const builder *b, int l, size_t idx)
{
    return l == 0 ? b->lut[b->prob[idx]] : b->lv[l].mx[idx];
}

static void coords(const level *L, size_t idx, int c[3])
{
    c[0] = (int)(idx % (size_t)L->dim[0]);
    c[1] = (int)(idx / (size_t)L->dim[0] % (size_t)L->dim[1]);
    c[2] = (int)(idx / ((size_t)L->dim[0] * (size_t)L->dim[1]));
}

/* Lists the bone children (cell indices at level l-1) of cell idx at level l; returns the count. */
static int children(const builder *b, int l, size_t idx, size_t out[8])
{
    const level *C = &b->lv[l - 1];
    int c[3], n = 0;
    coords(&b->lv[l], idx, c);
    for (int dz = 0; dz < 2; dz++)
        for (int dy = 0; dy < 2; dy++)
            for (int dx = 0; dx < 2; dx++) {
                int x = 2 * c[0] + dx, y = 2 * c[1] + dy, z = 2 * c[2] + dz;
                if (x >= C->dim[0] || y >= C->dim[1] || z >= C->dim[2])
                    continue;
                size_t k = ((size_t)z * C->dim[1] + y) * C->dim[0] + x;
                if (cell_mx(b, l - 1, k))
                    out[n++] = k;
            }
    return n;
}

/* Levels >= 2 from the level below: min, max and the union of the children's boxes. */
static void level_up(builder *b, int l)
{
    level *L = &b->lv[l];
    for (size_t idx = 0; idx < cells(L->dim); idx++) {
        int c[3];
        coords(L, idx, c);
        const level *C = &b->lv[l - 1];
        uint8_t mn = 255, mx = 0;
        uint16_t box[6] = {UINT16_MAX, UINT16_MAX, UINT16_MAX, 0, 0, 0};
        for (int dz = 0; dz < 2; dz++)
            for (int dy = 0; dy < 2; dy++)
                for (int dx = 0; dx < 2; dx++) {
                    int cc[3] = {2 * c[0] + dx, 2 * c[1] + dy, 2 * c[2] + dz};
                    if (cc[0] >= C->dim[0] || cc[1] >= C->dim[1] || cc[2] >= C->dim[2])
                        continue;
                    size_t k = ((size_t)cc[2] * C->dim[1] + cc[1]) * C->dim[0] + cc[0];
                    mn = C->mn[k] < mn ? C->mn[k] : mn;
                    if (!C->mx[k])
                        continue;
                    mx = C->mx[k] > mx ? C->mx[k] : mx;
                    uint16_t lo[3], hi[3];
                    cell_box(b, l - 1, k, cc, lo, hi);
                    for (int i = 0; i < 3; i++) {
                        box[i] = lo[i] < box[i] ? lo[i] : box[i];
                        box[3 + i] = hi[i] > box[3 + i] ? hi[i] : box[3 + i];
                    }
                }
        L->mn[idx] = mn, L->mx[idx] = mx;
        memcpy(L->box[idx], box, sizeof box);
    }
}

/* Follows single-child chains down: a cell with one bone child is replaced by that child. */
static void collapse(const builder *b, int *l, size_t *idx)
{
    size_t kid[8];
    while (*l > 0 && cell_mn(b, *l, *idx) != 255 && children(b, *l, *idx, kid) == 1) {
        *idx = kid[0];
        (*l)--;
    }
}

static int emit(builder *b, int l, size_t idx, uint8_t depth)
{
    if (b->n == b->cap) {
        size_t cap = b->cap ? 2 * b->cap : 1024;
        if (cap > MAX_NODES)
            cap = MAX_NODES;
        if (b->n == cap)
            return fn_err_set(FN_ENOMEM, "the hierarchy needs more than %u nodes", MAX_NODES);
        obb_node *nn = realloc(b->nodes, cap * sizeof *nn);
        if (nn)
            b->nodes = nn;
        uint32_t *nc = realloc(b->cell, cap * sizeof *nc);
        if (nc)
            b->cell = nc;
        uint8_t *nl = realloc(b->lvl, cap), *nd = nl ? realloc(b->dep, cap) : NULL;
        if (nl)
            b->lvl = nl;
        if (nd)
            b->dep = nd;
        if (!nn || !nc || !nl || !nd)
            return fn_err_set(FN_ENOMEM, "out of memory for %zu hierarchy nodes", cap);
        b->cap = cap;
    }
    obb_node *o = &b->nodes[b->n];
    int c[3];
    coords(&b->lv[l], idx, c);
    cell_box(b, l, idx, c, o->lo, o->hi);
    uint8_t mn = cell_mn(b, l, idx), mx = cell_mx(b, l, idx);
    if (l == 0 || mn == 255)
        o->info = 0x80000000u | mx;
    else
        o->info = (uint32_t)((mx * 15 + 254) / 255) << 24;
    b->cell[b->n] = (uint32_t)idx;
    b->lvl[b->n] = (uint8_t)l;
    b->dep[b->n] = depth;
    b->n++;
    return 0;
}

/* Stage two: breadth-first from the root; children of each inner node are emitted contiguously. */
static int prune(builder *b, int *depth)
{
    int l = b->top;
    size_t idx = 0;
    *depth = 0;
    if (!cell_mx(b, l, idx))
        return 0;
    collapse(b, &l, &idx);
    int rc = emit(b, l, idx, 1);
    for (size_t i = 0; rc == 0 && i < b->n; i++) {
        *depth = b->dep[i] > *depth ? b->dep[i] : *depth;
        if (b->nodes[i].info & 0x80000000u)
            continue;
        size_t kid[8];
        int nk = children(b, b->lvl[i], b->cell[i], kid);
        size_t first = b->n;
        if (first >= MAX_NODES)
            return fn_err_set(FN_ENOMEM, "the hierarchy needs more than %u nodes", MAX_NODES);
        for (int k = 0; k < nk && rc == 0; k++) {
            int cl = b->lvl[i] - 1;
            size_t ci = kid[k];
            collapse(b, &cl, &ci);
            rc = emit(b, cl, ci, (uint8_t)(b->dep[i] + 1));
        }
        b->nodes[i].info |= (uint32_t)first | (uint32_t)(nk - 1) << 28;
    }
    return rc;
}

static int alloc_levels(builder *b, const int d0[3])
{
    int d[3] = {d0[0], d0[1], d0[2]};
    b->lv[0].dim[0] = d[0], b->lv[0].dim[1] = d[1], b->lv[0].dim[2] = d[2];
    b->top = 0;
    while (d[0] > 1 || d[1] > 1 || d[2] > 1) {
        int l = ++b->top;
        for (int i = 0; i < 3; i++)
            d[i] = (d[i] + 1) / 2, b->lv[l].dim[i] = d[i];
        size_t n = cells(d);
        b->lv[l].mn = malloc(n);
        b->lv[l].mx = malloc(n);
        if (l == 1)
            b->lv[l].mask = malloc(n);
        else
            b->lv[l].box = malloc(n * sizeof *b->lv[l].box);
        if (!b->lv[l].mn || !b->lv[l].mx || (l == 1 ? !b->lv[l].mask : !b->lv[l].box))
            return fn_err_set(FN_ENOMEM, "out of memory for the hierarchy pyramid (%zu cells)", n);
    }
    return 0;
}

static void builder_free(builder *b)
{
    for (int l = 1; l < MAX_LEVELS; l++) {
        free(b->lv[l].mn);
        free(b->lv[l].mx);
        free(b->lv[l].mask);
        free(b->lv[l].box);
    }
    free(b->cell);
    free(b->lvl);
    free(b->dep);
}

static int check_input(const frag *f, const obb_params *p)
{
    if (!f || !f->prob)
        return fn_err_set(FN_EINVAL, "obb_tree_build: no fragment or no probability map");
    for (int i = 0; i < 3; i++) {
        if (f->dim[i] < 1 || f->dim[i] > UINT16_MAX)
            return fn_err_set(FN_EFORMAT, "fragment '%s': dim[%d] = %d is outside 1..65535",
                              f->name, i, f->dim[i]);
        if (!(f->spacing[i] > 0) || !isfinite(f->spacing[i]))
            return fn_err_set(FN_EFORMAT, "fragment '%s': spacing[%d] = %g is not a positive size",
                              f->name, i, f->spacing[i]);
    }
    if (!(p->tau_min >= 0 && p->tau_min <= p->tau_max && p->tau_max <= 1))
        return fn_err_set(FN_EINVAL, "obb params: need 0 <= tau_min (%g) <= tau_max (%g) <= 1",
                          p->tau_min, p->tau_max);
    return 0;
}

obb_tree *obb_tree_build(const frag *f, const obb_params *params)
{
    obb_params p = params ? *params : (obb_params){0, 1};
    if (check_input(f, &p))
        return NULL;
    builder b = {.prob = f->prob};
    for (int v = 0; v < 256; v++)
        b.lut[v] = obb_effective_prob((uint8_t)v, &p);
    obb_tree *t = calloc(1, sizeof *t);
    int rc = t ? alloc_levels(&b, f->dim) : fn_err_set(FN_ENOMEM, "out of memory for a tree");
    if (rc == 0) {
        if (b.top >= 1)
            level1(&b, f->dim);
        for (int l = 2; l <= b.top; l++)
            level_up(&b, l);
        rc = prune(&b, &t->depth);
    }
    builder_free(&b);
    if (rc) {
        fn_err_wrap(rc, "fragment '%s'", f->name);
        free(b.nodes);
        free(t);
        return NULL;
    }
    obb_node *shrunk = b.n ? realloc(b.nodes, b.n * sizeof *shrunk) : NULL;
    t->nodes = shrunk ? shrunk : b.nodes;
    if (!b.n) {
        free(b.nodes);
        t->nodes = NULL;
    }
    t->n = b.n;
    t->params = p;
    memcpy(t->spacing, f->spacing, sizeof t->spacing);
    return t;
}

void obb_tree_free(obb_tree *t)
{
    if (!t)
        return;
    free(t->nodes);
    free(t);
}

size_t obb_tree_nodes(const obb_tree *t)
{
    return t ? t->n : 0;
}

const obb_node *obb_tree_node_array(const obb_tree *t)
{
    return t ? t->nodes : NULL;
}

const double *obb_tree_spacing(const obb_tree *t)
{
    return t->spacing;
}

int obb_tree_depth(const obb_tree *t)
{
    return t ? t->depth : 0;
}

size_t obb_tree_bytes(const obb_tree *t)
{
    return t ? sizeof *t + t->n * sizeof(obb_node) : 0;
}
