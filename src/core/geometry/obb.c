/* obb: the two-stage hierarchy build (bottom-up min/max/box pyramid, top-down breadth-first prune). */
#include "obb.h"

#include "err.h"
#include "platform.h"
#include "vol.h"

#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define MAX_LEVELS 18
#define MAX_NODES (1u << 24)
#define EXPANDED 255 /* level mark of a level-1 node whose voxels are already out */

struct obb_tree {
    obb_node *nodes;
    size_t n;
    double spacing[3];
    int depth;
    obb_params params;
};

/* A pyramid cell (16 bytes): the min and max effective probability of its voxels, a mask of its
 * bone children (bit dz*4 + dy*2 + dx) and, from level 2 up, the tight box of its bone voxels
 * (level 1 boxes follow from the mask). */
typedef struct cell {
    uint8_t mn, mx, mask, pad;
    union {
        uint8_t vox[8];  /* level 1, mixed cells only: the effective voxel values by child bit */
        uint16_t box[6]; /* levels >= 2, bone cells only: lo, hi */
    };
} cell;

typedef struct level {
    int dim[3];
    cell *cell; /* one cache line holds what the top-down pass needs of a cell */
} level;

typedef struct builder {
    const uint8_t *prob;
    uint8_t lut[256];
    uint8_t lo_off[256], hi_off[256]; /* level-1 box offsets from the mask: bit i = axis i */
    level lv[MAX_LEVELS];
    int top;
    obb_node *nodes;
    uint8_t *lvl;    /* per emitted node: its pyramid level (its cell is lo >> level), EXPANDED
                      * once its voxels are out; unset for voxel leaves */
    size_t n, cap;
    size_t bone;     /* bone voxels: the tree has fewer than 2 * bone nodes */
    int depth;       /* deepest node so far (root = 1) */
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

static size_t cidx(const level *L, const uint16_t c[3])
{
    return ((size_t)c[2] * (size_t)L->dim[1] + c[1]) * (size_t)L->dim[0] + c[0];
}

/* One level-1 cell from its (up to) 8 voxels: rows[dz*2+dy] (NULL when outside the crop), x the
 * first voxel's column, two voxels when pair. */
static uint8_t cell1(const builder *b, const uint8_t *const rows[4], size_t x, int pair, cell *out)
{
    uint8_t lo = 255, hi = 0, m = 0;
    for (int r = 0; r < 4; r++) {
        if (!rows[r])
            continue;
        for (int dx = 0; dx <= pair; dx++) {
            uint8_t e = b->lut[rows[r][x + dx]];
            lo = e < lo ? e : lo;
            hi = e > hi ? e : hi;
            m |= e ? (uint8_t)(1u << (r * 2 + dx)) : 0;
            out->vox[r * 2 + dx] = e;
        }
    }
    out->mn = lo, out->mx = hi, out->mask = m;
    return m;
}

static uint64_t load8(const uint8_t *p)
{
    uint64_t v;
    memcpy(&v, p, sizeof v);
    return v;
}

/* Level 1 from the voxels. Runs of 4 cells whose 32 voxels are all air (or all certain bone, when
 * that maps to 255) are settled by word compares: most of a crop is one or the other. */
static void level1(builder *b)
{
    level *L = &b->lv[1];
    const int *d0 = b->lv[0].dim;
    size_t nx = (size_t)L->dim[0], full = (size_t)d0[0] / 8;
    int solid_fast = b->lut[255] == 255;
    for (int ck = 0; ck < L->dim[2]; ck++)
        for (int cj = 0; cj < L->dim[1]; cj++) {
            size_t row = ((size_t)ck * L->dim[1] + cj) * nx;
            const uint8_t *rows[4];
            int present = 1;
            for (int r = 0; r < 4; r++) {
                int z = 2 * ck + (r >> 1), y = 2 * cj + (r & 1);
                rows[r] = z < d0[2] && y < d0[1] ? b->prob + ((size_t)z * d0[1] + y) * d0[0] : NULL;
                present &= rows[r] != NULL;
            }
            for (size_t g = 0; g < nx; g++) {
                if (present && (g & 3) == 0 && g / 4 < full) {
                    uint64_t w[4], any = 0, all = ~0ull;
                    for (int r = 0; r < 4; r++)
                        w[r] = load8(rows[r] + 2 * g), any |= w[r], all &= w[r];
                    if (any == 0 || (solid_fast && all == ~0ull)) {
                        for (int q = 0; q < 4; q++) {
                            cell *o = &L->cell[row + g + q];
                            o->mn = o->mx = o->mask = any ? 255 : 0;
                        }
                        b->bone += any ? 32 : 0;
                        g += 3;
                        continue;
                    }
                }
                uint8_t m = cell1(b, rows, 2 * g, 2 * g + 1 < (size_t)d0[0], &L->cell[row + g]);
                b->bone += (size_t)__builtin_popcount(m);
            }
        }
}

/* Tight box of the cell at coordinates c of level l, in voxel indices. */
static void cell_box(const builder *b, int l, const uint16_t c[3], uint16_t lo[3], uint16_t hi[3])
{
    if (l == 0) {
        memcpy(lo, c, 3 * sizeof *c);
        memcpy(hi, c, 3 * sizeof *c);
    } else if (l == 1) {
        uint8_t m = b->lv[1].cell[cidx(&b->lv[1], c)].mask, lo_o = b->lo_off[m], hi_o = b->hi_off[m];
        for (int i = 0; i < 3; i++) {
            lo[i] = (uint16_t)(2 * c[i] + ((lo_o >> i) & 1));
            hi[i] = (uint16_t)(2 * c[i] + ((hi_o >> i) & 1));
        }
    } else {
        const uint16_t *box = b->lv[l].cell[cidx(&b->lv[l], c)].box;
        memcpy(lo, box, 3 * sizeof *lo);
        memcpy(hi, box + 3, 3 * sizeof *hi);
    }
}

/* Coordinates of child `bit` of cell c. */
static void child(const uint16_t c[3], int bit, uint16_t out[3])
{
    out[0] = (uint16_t)(2 * c[0] + (bit & 1));
    out[1] = (uint16_t)(2 * c[1] + ((bit >> 1) & 1));
    out[2] = (uint16_t)(2 * c[2] + ((bit >> 2) & 1));
}

/* The box offsets of a level-1 cell from its occupancy mask. */
static void mask_tables(builder *b)
{
    static const uint8_t low[3] = {0x55, 0x33, 0x0f}; /* bits of the lower half on each axis */
    for (int m = 0; m < 256; m++) {
        b->lo_off[m] = b->hi_off[m] = 0;
        for (int i = 0; i < 3; i++) {
            b->lo_off[m] |= (uint8_t)(((m & low[i]) ? 0 : 1) << i);
            b->hi_off[m] |= (uint8_t)(((m & (uint8_t)~low[i]) ? 1 : 0) << i);
        }
    }
}

/* Widens box by the tight box of child cell k (coordinates cc) of level l - 1. */
static void add_child_box(const builder *b, int l, const cell *k, const uint16_t cc[3],
                          uint16_t box[6])
{
    uint16_t lo[3], hi[3];
    if (l - 1 == 1) {
        uint8_t lo_o = b->lo_off[k->mask], hi_o = b->hi_off[k->mask];
        for (int i = 0; i < 3; i++) {
            lo[i] = (uint16_t)(2 * cc[i] + ((lo_o >> i) & 1));
            hi[i] = (uint16_t)(2 * cc[i] + ((hi_o >> i) & 1));
        }
    } else {
        memcpy(lo, k->box, sizeof lo);
        memcpy(hi, k->box + 3, sizeof hi);
    }
    for (int i = 0; i < 3; i++) {
        box[i] = lo[i] < box[i] ? lo[i] : box[i];
        box[3 + i] = hi[i] > box[3 + i] ? hi[i] : box[3 + i];
    }
}

/* Levels >= 2 from the level below: min, max and bone-child mask, row by row; the tight box is the
 * clipped cell when solid, else the union of the children's boxes (unused when empty). */
static void level_up(builder *b, int l)
{
    level *L = &b->lv[l];
    const level *C = &b->lv[l - 1];
    const int *d0 = b->lv[0].dim;
    size_t idx = 0;
    uint16_t c[3];
    for (c[2] = 0; c[2] < L->dim[2]; c[2]++)
        for (c[1] = 0; c[1] < L->dim[1]; c[1]++) {
            const cell *rows[4] = {NULL, NULL, NULL, NULL};
            for (int r = 0; r < 4; r++) {
                int z = 2 * c[2] + (r >> 1), y = 2 * c[1] + (r & 1);
                if (z >= C->dim[2] || y >= C->dim[1])
                    continue;
                size_t base = ((size_t)z * C->dim[1] + y) * C->dim[0];
                rows[r] = C->cell + base;
            }
            for (c[0] = 0; c[0] < L->dim[0]; c[0]++, idx++) {
                uint8_t mn = 255, mx = 0, mask = 0;
                int x0 = 2 * c[0], pair = x0 + 1 < C->dim[0];
                for (int r = 0; r < 4; r++) {
                    if (!rows[r])
                        continue;
                    for (int dx = 0; dx <= pair; dx++) {
                        uint8_t a = rows[r][x0 + dx].mn, z = rows[r][x0 + dx].mx;
                        mn = a < mn ? a : mn;
                        mx = z > mx ? z : mx;
                        mask |= z ? (uint8_t)(1u << (r * 2 + dx)) : 0;
                    }
                }
                cell *o = &L->cell[idx];
                o->mn = mn, o->mx = mx, o->mask = mask;
                uint16_t *box = o->box;
                if (!mx)
                    continue;
                if (mn != 255) {
                    box[0] = box[1] = box[2] = UINT16_MAX;
                    box[3] = box[4] = box[5] = 0;
                    for (int r = 0; r < 4; r++)
                        for (int dx = 0; dx <= pair && rows[r]; dx++) {
                            const cell *k = &rows[r][x0 + dx];
                            uint16_t cc[3] = {(uint16_t)(x0 + dx), (uint16_t)(2 * c[1] + (r & 1)),
                                              (uint16_t)(2 * c[2] + (r >> 1))};
                            if (k->mx)
                                add_child_box(b, l, k, cc, box);
                        }
                    continue;
                }
                for (int i = 0; i < 3; i++) {
                    int lo = c[i] << l, hi = ((c[i] + 1) << l) - 1;
                    box[i] = (uint16_t)lo;
                    box[3 + i] = (uint16_t)(hi < d0[i] ? hi : d0[i] - 1);
                }
            }
        }
}

static uint8_t cell_mx(const builder *b, int l, const uint16_t c[3])
{
    return l == 0 ? b->lut[b->prob[cidx(&b->lv[0], c)]] : b->lv[l].cell[cidx(&b->lv[l], c)].mx;
}

/* Follows single-child chains down: a cell with one bone child is replaced by that child. Landing
 * on a voxel, *p0 gets its effective value (from the level-1 cell: no read of the map). */
static void collapse(const builder *b, int *l, uint16_t c[3], uint8_t *p0)
{
    while (*l > 0) {
        const cell *k = &b->lv[*l].cell[cidx(&b->lv[*l], c)];
        uint8_t m = k->mask;
        if (k->mn == 255 || (m & (m - 1)))
            return;
        int bit = 0;
        while (!(m >> bit & 1))
            bit++;
        if (*l == 1)
            *p0 = k->vox[bit];
        child(c, bit, c);
        (*l)--;
    }
}

/* Room for cap nodes (capped at MAX_NODES); untouched pages of a generous guess cost nothing. */
static int reserve(builder *b, size_t cap)
{
    if (cap > MAX_NODES)
        cap = MAX_NODES;
    if (b->n == cap)
        return fn_err_set(FN_ENOMEM, "the hierarchy needs more than %u nodes", MAX_NODES);
    obb_node *nn = realloc(b->nodes, cap * sizeof *nn);
    if (nn)
        b->nodes = nn, platform_huge_pages(nn, cap * sizeof *nn);
    uint8_t *np = realloc(b->lvl, cap);
    if (np)
        b->lvl = np;
    if (!nn || !np)
        return fn_err_set(FN_ENOMEM, "out of memory for %zu hierarchy nodes", cap);
    b->cap = cap;
    return 0;
}

static int grow(builder *b)
{
    return reserve(b, b->cap ? 2 * b->cap : 1024);
}

/* Appends the node of cell c at level l (p0: a voxel's effective value). */
static int emit(builder *b, int l, const uint16_t c[3], uint8_t p0, int depth)
{
    int rc = b->n == b->cap ? grow(b) : 0;
    if (rc)
        return rc;
    obb_node *o = &b->nodes[b->n];
    cell_box(b, l, c, o->lo, o->hi);
    if (l == 0) {
        o->info = 0x80000000u | p0;
    } else {
        const cell *k = &b->lv[l].cell[cidx(&b->lv[l], c)];
        o->info = k->mn == 255 ? 0x80000000u | 255u : (uint32_t)((k->mx * 15 + 254) / 255) << 24;
    }
    b->lvl[b->n++] = (uint8_t)l;
    b->depth = depth > b->depth ? depth : b->depth;
    return 0;
}

/* The pyramid cell of emitted node i at level l: its box lies inside the cell. */
static void node_cell(const builder *b, size_t i, int l, uint16_t c[3])
{
    for (int k = 0; k < 3; k++)
        c[k] = (uint16_t)(b->nodes[i].lo[k] >> l);
}

/* Gives inner level-1 node i (at depth) its voxel children, as leaves (nothing below them). */
static int emit_voxels(builder *b, size_t i, int depth)
{
    uint16_t pc[3];
    node_cell(b, i, 1, pc);
    const cell *k = &b->lv[1].cell[cidx(&b->lv[1], pc)];
    size_t first = b->n;
    b->depth = depth + 1 > b->depth ? depth + 1 : b->depth;
    for (int bit = 0; bit < 8; bit++) {
        if (!(k->mask >> bit & 1))
            continue;
        int rc = b->n == b->cap ? grow(b) : 0;
        if (rc)
            return rc;
        obb_node *o = &b->nodes[b->n++];
        child(pc, bit, o->lo);
        memcpy(o->hi, o->lo, sizeof o->hi);
        o->info = 0x80000000u | k->vox[bit];
    }
    b->nodes[i].info |= (uint32_t)first | (uint32_t)(b->n - first - 1) << 28;
    b->lvl[i] = EXPANDED;
    return 0;
}

/* Emits the bone children of inner node i (level >= 2) contiguously, and right away the voxels
 * of those that are inner level-1 nodes, while their cells are still in cache. */
static int emit_children(builder *b, size_t i, int depth)
{
    int l = b->lvl[i];
    uint16_t pc[3];
    node_cell(b, i, l, pc);
    uint8_t m = b->lv[l].cell[cidx(&b->lv[l], pc)].mask;
    size_t first = b->n;
    int rc = 0;
    for (int bit = 0; bit < 8 && rc == 0; bit++) {
        if (!(m >> bit & 1))
            continue;
        int cl = l - 1;
        uint16_t cc[3];
        uint8_t p0 = 0;
        child(pc, bit, cc);
        collapse(b, &cl, cc, &p0);
        rc = emit(b, cl, cc, p0, depth + 1);
    }
    size_t last = b->n;
    b->nodes[i].info |= (uint32_t)first | (uint32_t)(last - first - 1) << 28;
    for (size_t j = first; j < last && rc == 0; j++)
        if (!(b->nodes[j].info & 0x80000000u) && b->lvl[j] == 1)
            rc = emit_voxels(b, j, depth + 1);
    return rc;
}

/* Stage two: breadth-first from the root; children of each inner node are emitted contiguously.
 * Nodes [end of depth d - 1, end of depth d) are those of depth d (and voxel leaves below them). */
static int prune(builder *b)
{
    int l = b->top;
    uint16_t c[3] = {0, 0, 0};
    uint8_t p0 = b->lut[b->prob[0]];
    if (!cell_mx(b, l, c))
        return 0;
    collapse(b, &l, c, &p0);
    int rc = emit(b, l, c, p0, 1), depth = 1;
    size_t end = b->n;
    for (size_t i = 0; rc == 0 && i < b->n; i++) {
        if (i == end)
            depth++, end = b->n;
        if ((b->nodes[i].info & 0x80000000u) || b->lvl[i] == EXPANDED)
            continue;
        rc = b->lvl[i] == 1 ? emit_voxels(b, i, depth) : emit_children(b, i, depth);
    }
    return rc;
}

static int alloc_levels(builder *b, const int d0[3])
{
    int d[3] = {d0[0], d0[1], d0[2]};
    memcpy(b->lv[0].dim, d0, sizeof b->lv[0].dim);
    b->top = 0;
    while (d[0] > 1 || d[1] > 1 || d[2] > 1) {
        int l = ++b->top;
        for (int i = 0; i < 3; i++)
            d[i] = (d[i] + 1) / 2, b->lv[l].dim[i] = d[i];
        size_t n = cells(d);
        level *L = &b->lv[l];
        L->cell = malloc(n * sizeof *L->cell);
        platform_huge_pages(L->cell, n * sizeof *L->cell);
        if (!L->cell)
            return fn_err_set(FN_ENOMEM, "out of memory for the hierarchy pyramid (%zu cells)", n);
    }
    return 0;
}

static void builder_free(builder *b)
{
    for (int l = 1; l < MAX_LEVELS; l++) {
        free(b->lv[l].cell);
    }
    free(b->lvl);
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
    /* the pyramid and the nodes take under 5 bytes per voxel: check the budget first */
    int64_t d[3] = {f->dim[0], f->dim[1], f->dim[2]};
    int rc = vol_check_dims(d, 5, "hierarchy of the fragment");
    return rc ? fn_err_wrap(rc, "fragment '%s'", f->name) : 0;
}

obb_tree *obb_tree_build(const frag *f, const obb_params *params)
{
    obb_params p = params ? *params : (obb_params){0, 1};
    if (check_input(f, &p))
        return NULL;
    builder b = {.prob = f->prob};
    for (int v = 0; v < 256; v++)
        b.lut[v] = obb_effective_prob((uint8_t)v, &p);
    mask_tables(&b);
    obb_tree *t = calloc(1, sizeof *t);
    int rc = t ? alloc_levels(&b, f->dim) : fn_err_set(FN_ENOMEM, "out of memory for a tree");
    if (rc == 0) {
        if (b.top >= 1)
            level1(&b);
        for (int l = 2; l <= b.top; l++)
            level_up(&b, l);
        rc = b.bone ? reserve(&b, 2 * b.bone) : 0;
        if (rc == 0)
            rc = prune(&b);
        t->depth = b.depth;
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
