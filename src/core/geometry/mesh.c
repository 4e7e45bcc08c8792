/* mesh: surface meshes by marching tetrahedra: each cube of the grid is split into the six
 * tetrahedra around its main diagonal (Kuhn's split, which neighbouring cubes share face for face,
 * so the surface has no cracks). The cases are computed, not tabled. */
#include "mesh.h"

#include "err.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* Corners as bits: x = 1, y = 2, z = 4; each tetrahedron walks from corner 0 to 7 along the axes. */
static const int tets[6][4] = {{0, 1, 3, 7}, {0, 2, 3, 7}, {0, 2, 6, 7},
                               {0, 4, 6, 7}, {0, 4, 5, 7}, {0, 1, 5, 7}};

/* ---- closed, indexed surfaces ---- */

typedef struct edge_map {
    uint64_t *key; /* key + 1; 0 = empty */
    int *val;
    size_t cap, n;
} edge_map;

static size_t hash64(uint64_t k)
{
    k ^= k >> 33;
    k *= 0xff51afd7ed558ccdULL;
    k ^= k >> 33;
    return (size_t)k;
}

static int map_grow(edge_map *h)
{
    size_t cap = h->cap ? h->cap * 2 : 1 << 16;
    uint64_t *key = calloc(cap, sizeof *key);
    int *val = malloc(cap * sizeof *val);
    if (!key || !val) {
        free(key);
        free(val);
        return FN_ENOMEM;
    }
    for (size_t i = 0; i < h->cap; i++)
        if (h->key[i]) {
            size_t j = hash64(h->key[i]) & (cap - 1);
            while (key[j])
                j = (j + 1) & (cap - 1);
            key[j] = h->key[i];
            val[j] = h->val[i];
        }
    free(h->key);
    free(h->val);
    h->key = key;
    h->val = val;
    h->cap = cap;
    return 0;
}

typedef struct builder {
    const float *vals;
    int dim[3], pdim[3]; /* grid, padded grid */
    double sp[3];
    float level, pad;
    edge_map map;
    float *v;
    int *tri;
    size_t nv, vcap, nt, tcap;
} builder;

/* The value at padded index (i, j, k): outside the grid, pad (below the level). */
static float pval(const builder *b, int i, int j, int k)
{
    i--, j--, k--;
    if (i < 0 || j < 0 || k < 0 || i >= b->dim[0] || j >= b->dim[1] || k >= b->dim[2])
        return b->pad;
    return b->vals[((size_t)k * (size_t)b->dim[1] + (size_t)j) * (size_t)b->dim[0] + (size_t)i];
}

/* The vertex on the edge from padded point p (index) to p + offset bits d (x 1, y 2, z 4). */
static int edge_vertex(builder *b, const int p[3], int d, float vp, float vq)
{
    uint64_t key = (((uint64_t)p[2] * (uint64_t)b->pdim[1] + (uint64_t)p[1]) * (uint64_t)b->pdim[0] +
                    (uint64_t)p[0]) * 8 + (uint64_t)d + 1;
    if ((b->map.n + 1) * 2 > b->map.cap && map_grow(&b->map))
        return FN_ENOMEM;
    size_t j = hash64(key) & (b->map.cap - 1);
    while (b->map.key[j]) {
        if (b->map.key[j] == key)
            return b->map.val[j];
        j = (j + 1) & (b->map.cap - 1);
    }
    if (b->nv == b->vcap) {
        size_t cap = b->vcap ? b->vcap * 2 : 4096;
        float *v = realloc(b->v, cap * 3 * sizeof *v);
        if (!v)
            return FN_ENOMEM;
        b->v = v;
        b->vcap = cap;
    }
    float s = vq != vp ? (b->level - vp) / (vq - vp) : 0.5f;
    for (int a = 0; a < 3; a++) {
        double x0 = (p[a] - 1) * b->sp[a], x1 = (p[a] - 1 + (d >> a & 1)) * b->sp[a];
        b->v[b->nv * 3 + (size_t)a] = (float)(x0 + s * (x1 - x0));
    }
    b->map.key[j] = key;
    b->map.val[j] = (int)b->nv;
    b->map.n++;
    return (int)b->nv++;
}

/* Adds triangle (x, y, z), turned by the orientation of its stand-in (mx, my, mz): the same
 * triangle with every vertex at its edge's midpoint (in corner bits), never degenerate, so the
 * winding follows the tetrahedron's combinatorics even where interpolated vertices coincide.
 * out: from an inside corner to an outside one. */
static int add_tri(builder *b, int x, int y, int z, const double mx[3], const double my[3], const double mz[3],
                   const double out[3])
{
    if (b->nt == b->tcap) {
        size_t cap = b->tcap ? b->tcap * 2 : 8192;
        int *t = realloc(b->tri, cap * 3 * sizeof *t);
        if (!t)
            return FN_ENOMEM;
        b->tri = t;
        b->tcap = cap;
    }
    double e1[3] = {my[0] - mx[0], my[1] - mx[1], my[2] - mx[2]}, e2[3] = {mz[0] - mx[0], mz[1] - mx[1], mz[2] - mx[2]};
    double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
    int *t = b->tri + b->nt * 3;
    t[0] = x;
    if (n[0] * out[0] + n[1] * out[1] + n[2] * out[2] > 0)
        t[1] = y, t[2] = z;
    else
        t[1] = z, t[2] = y;
    b->nt++;
    return 0;
}

static int extract_tet(builder *b, const int base[3], const int cn[4], const float val[4])
{
    int in[4], n_in = 0;
    for (int k = 0; k < 4; k++)
        n_in += in[k] = val[k] >= b->level;
    if (n_in == 0 || n_in == 4)
        return 0;
    int ins[4], outs[4], ni = 0, no = 0;
    for (int k = 0; k < 4; k++) {
        if (in[k])
            ins[ni++] = k;
        else
            outs[no++] = k;
    }
    /* The vertex on the tetrahedron's edge between corners ka (in) and kb (out). */
    int vid[4][4];
    for (int x = 0; x < ni; x++)
        for (int y = 0; y < no; y++) {
            int ca = cn[ins[x]], cb = cn[outs[y]];
            int lo = ca < cb ? ca : cb, hi = ca < cb ? cb : ca; /* lo is a subset of hi's bits */
            int p[3] = {base[0] + (lo & 1), base[1] + (lo >> 1 & 1), base[2] + (lo >> 2 & 1)};
            float vl = ca < cb ? val[ins[x]] : val[outs[y]], vh = ca < cb ? val[outs[y]] : val[ins[x]];
            int id = edge_vertex(b, p, lo ^ hi, vl, vh);
            if (id < 0)
                return id;
            vid[x][y] = id;
        }
    /* Midpoints of the cut edges in corner bits (the spacing's positive scale keeps orientation). */
    double mid[4][4][3], out[3];
    for (int x = 0; x < ni; x++)
        for (int y = 0; y < no; y++)
            for (int a = 0; a < 3; a++)
                mid[x][y][a] = 0.5 * ((cn[ins[x]] >> a & 1) + (cn[outs[y]] >> a & 1));
    for (int a = 0; a < 3; a++)
        out[a] = (cn[outs[0]] >> a & 1) - (cn[ins[0]] >> a & 1);
    if (ni == 1)
        return add_tri(b, vid[0][0], vid[0][1], vid[0][2], mid[0][0], mid[0][1], mid[0][2], out);
    if (no == 1)
        return add_tri(b, vid[0][0], vid[1][0], vid[2][0], mid[0][0], mid[1][0], mid[2][0], out);
    /* Quad: in0-out0, in0-out1, in1-out1, in1-out0. */
    int rc = add_tri(b, vid[0][0], vid[0][1], vid[1][1], mid[0][0], mid[0][1], mid[1][1], out);
    return rc ? rc : add_tri(b, vid[0][0], vid[1][1], vid[1][0], mid[0][0], mid[1][1], mid[1][0], out);
}

int mesh_extract(const float *vals, const int dim[3], const double spacing[3], float level, mesh *m)
{
    memset(m, 0, sizeof *m);
    builder b = {.vals = vals, .level = level, .pad = level - fmaxf(1.0f, fabsf(level))};
    for (int a = 0; a < 3; a++) {
        b.dim[a] = dim[a];
        b.pdim[a] = dim[a] + 2;
        b.sp[a] = spacing[a];
    }
    int rc = 0;
    for (int k = 0; k + 1 < b.pdim[2] && !rc; k++)
        for (int j = 0; j + 1 < b.pdim[1] && !rc; j++)
            for (int i = 0; i + 1 < b.pdim[0] && !rc; i++) {
                float cv[8];
                int any_in = 0, any_out = 0;
                for (int c = 0; c < 8; c++) {
                    cv[c] = pval(&b, i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1));
                    any_in |= cv[c] >= level;
                    any_out |= cv[c] < level;
                }
                if (!any_in || !any_out)
                    continue;
                const int base[3] = {i, j, k};
                for (int t = 0; t < 6 && !rc; t++) {
                    const float tv[4] = {cv[tets[t][0]], cv[tets[t][1]], cv[tets[t][2]], cv[tets[t][3]]};
                    rc = extract_tet(&b, base, tets[t], tv);
                }
            }
    free(b.map.key);
    free(b.map.val);
    if (rc) {
        free(b.v);
        free(b.tri);
        return fn_err_set(FN_ENOMEM, "mesh: out of memory extracting a surface (%zu triangles)", b.nt);
    }
    m->v = b.v;
    m->tri = b.tri;
    m->nv = (long)b.nv;
    m->nt = (long)b.nt;
    return 0;
}

void mesh_free(mesh *m)
{
    free(m->v);
    free(m->tri);
    memset(m, 0, sizeof *m);
}

/* Signed volume of triangle t's cone from the origin, times 6. */
static double tri_volume6(const mesh *m, long t)
{
    const float *a = m->v + (size_t)m->tri[t * 3] * 3, *b = m->v + (size_t)m->tri[t * 3 + 1] * 3,
                *c = m->v + (size_t)m->tri[t * 3 + 2] * 3;
    return a[0] * ((double)b[1] * c[2] - (double)b[2] * c[1]) - a[1] * ((double)b[0] * c[2] - (double)b[2] * c[0]) +
           a[2] * ((double)b[0] * c[1] - (double)b[1] * c[0]);
}

double mesh_volume(const mesh *m)
{
    double s = 0;
    for (long t = 0; t < m->nt; t++)
        s += tri_volume6(m, t);
    return s / 6;
}

double mesh_area(const mesh *m)
{
    double s = 0;
    for (long t = 0; t < m->nt; t++) {
        const float *a = m->v + (size_t)m->tri[t * 3] * 3, *b = m->v + (size_t)m->tri[t * 3 + 1] * 3,
                    *c = m->v + (size_t)m->tri[t * 3 + 2] * 3;
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
        s += 0.5 * sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    }
    return s;
}

/* Half-edge neighbours: for each vertex, the vertices after it in its triangles (in a closed
 * oriented manifold each neighbour once). CSR: start[nv + 1], nb[3 nt]. */
static int neighbours(const mesh *m, int **start_out, int **nb_out)
{
    int *start = calloc((size_t)m->nv + 1, sizeof *start), *nb = malloc((size_t)m->nt * 3 * sizeof *nb);
    if (!start || !nb) {
        free(start);
        free(nb);
        return FN_ENOMEM;
    }
    for (long t = 0; t < m->nt * 3; t++)
        start[m->tri[t] + 1]++;
    for (long v = 0; v < m->nv; v++)
        start[v + 1] += start[v];
    int *fill = malloc((size_t)m->nv * sizeof *fill);
    if (!fill) {
        free(start);
        free(nb);
        return FN_ENOMEM;
    }
    memcpy(fill, start, (size_t)m->nv * sizeof *fill);
    for (long t = 0; t < m->nt; t++)
        for (int e = 0; e < 3; e++)
            nb[fill[m->tri[t * 3 + e]]++] = m->tri[t * 3 + (e + 1) % 3];
    free(fill);
    *start_out = start;
    *nb_out = nb;
    return 0;
}

int mesh_smooth(mesh *m, int iterations, double lambda, double mu)
{
    if (m->nt == 0 || iterations <= 0)
        return 0;
    int *start, *nb;
    float *d = malloc((size_t)m->nv * 3 * sizeof *d);
    if (!d || neighbours(m, &start, &nb)) {
        free(d);
        return fn_err_set(FN_ENOMEM, "mesh: out of memory smoothing %ld vertices", m->nv);
    }
    for (int it = 0; it < iterations * 2; it++) {
        double f = it & 1 ? mu : lambda;
        for (long v = 0; v < m->nv; v++) {
            double s[3] = {0, 0, 0};
            int n = start[v + 1] - start[v];
            for (int e = start[v]; e < start[v + 1]; e++)
                for (int a = 0; a < 3; a++)
                    s[a] += m->v[(size_t)nb[e] * 3 + (size_t)a];
            for (int a = 0; a < 3; a++)
                d[v * 3 + a] = n ? (float)(f * (s[a] / n - m->v[v * 3 + a])) : 0.0f;
        }
        for (long k = 0; k < m->nv * 3; k++)
            m->v[k] += d[k];
    }
    free(d);
    free(start);
    free(nb);
    return 0;
}

/* ---- decimation: passes of independent edge collapses ---- */

typedef struct cand {
    float len;
    int a, b;
} cand;

static int cand_cmp(const void *x, const void *y)
{
    float a = ((const cand *)x)->len, b = ((const cand *)y)->len;
    return (a > b) - (a < b);
}

static void tri_normal(const float *v, const int *t, const int *sub, double n[3])
{
    const float *p[3];
    for (int e = 0; e < 3; e++)
        p[e] = v + (size_t)(t[e] == sub[0] ? sub[1] : t[e]) * 3;
    double e1[3] = {p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]};
    double e2[3] = {p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]};
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
}

/* Can edge (a, b) collapse to its midpoint? The link condition (a and b share exactly the two
 * vertices opposite the edge), and no triangle around a or b flips. vt/vstart: vertex -> triangles. */
static int can_collapse(const mesh *m, const int *vstart, const int *vt, int a, int b)
{
    int na = 0, ring[2][128], nr[2] = {0, 0};
    for (int s = 0; s < 2; s++) {
        int v = s ? b : a;
        for (int e = vstart[v]; e < vstart[v + 1]; e++) {
            const int *t = m->tri + (size_t)vt[e] * 3;
            for (int k = 0; k < 3; k++) {
                int w = t[k];
                if (w == a || w == b)
                    continue;
                int seen = 0;
                for (int q = 0; q < nr[s]; q++)
                    seen |= ring[s][q] == w;
                if (!seen) {
                    if (nr[s] == 128)
                        return 0;
                    ring[s][nr[s]++] = w;
                }
            }
        }
    }
    for (int x = 0; x < nr[0]; x++)
        for (int y = 0; y < nr[1]; y++)
            na += ring[0][x] == ring[1][y];
    if (na != 2 || nr[0] < 3 || nr[1] < 3)
        return 0;
    /* The midpoint in a scratch slot: the triangles that keep one of a, b must not flip. */
    float mid[3];
    for (int k = 0; k < 3; k++)
        mid[k] = 0.5f * (m->v[(size_t)a * 3 + k] + m->v[(size_t)b * 3 + k]);
    for (int s = 0; s < 2; s++) {
        int v = s ? b : a;
        for (int e = vstart[v]; e < vstart[v + 1]; e++) {
            const int *t = m->tri + (size_t)vt[e] * 3;
            if ((t[0] == a || t[1] == a || t[2] == a) && (t[0] == b || t[1] == b || t[2] == b))
                continue; /* goes away */
            double n0[3], n1[3];
            const int none[2] = {-1, -1};
            tri_normal(m->v, t, none, n0);
            float keep[3];
            memcpy(keep, m->v + (size_t)v * 3, sizeof keep);
            memcpy(m->v + (size_t)v * 3, mid, sizeof mid);
            tri_normal(m->v, t, none, n1);
            memcpy(m->v + (size_t)v * 3, keep, sizeof keep);
            double d = n0[0] * n1[0] + n0[1] * n1[1] + n0[2] * n1[2];
            double l0 = sqrt(n0[0] * n0[0] + n0[1] * n0[1] + n0[2] * n0[2]);
            double l1 = sqrt(n1[0] * n1[0] + n1[1] * n1[1] + n1[2] * n1[2]);
            if (l1 <= 1e-12 || d <= 0.2 * l0 * l1)
                return 0;
        }
    }
    return 1;
}

/* Removes the vertices no triangle uses (their order kept); fill is scratch for nv ints. */
static void drop_unused_vertices(mesh *m, int *fill)
{
    long nv = 0;
    for (long v = 0; v < m->nv; v++)
        fill[v] = -1;
    for (long t = 0; t < m->nt * 3; t++)
        fill[m->tri[t]] = 0;
    for (long v = 0; v < m->nv; v++)
        if (fill[v] == 0) { /* in index order: the slot nv <= v is free */
            fill[v] = (int)nv;
            memmove(m->v + nv * 3, m->v + (size_t)v * 3, 3 * sizeof *m->v);
            nv++;
        }
    for (long t = 0; t < m->nt * 3; t++)
        m->tri[t] = fill[m->tri[t]];
    m->nv = nv;
}

static int uf_root(int *parent, int v)
{
    while (parent[v] != v)
        v = parent[v] = parent[parent[v]];
    return v;
}

long mesh_drop_islands(mesh *m)
{
    int *parent = malloc((size_t)(m->nv ? m->nv : 1) * sizeof *parent);
    double *vol = calloc((size_t)(m->nv ? m->nv : 1), sizeof *vol);
    if (!parent || !vol) {
        free(parent), free(vol);
        return fn_err_set(FN_ENOMEM, "mesh: out of memory finding the parts of %ld triangles", m->nt);
    }
    for (long v = 0; v < m->nv; v++)
        parent[v] = (int)v;
    for (long t = 0; t < m->nt; t++)
        for (int e = 1; e < 3; e++) {
            int a = uf_root(parent, m->tri[t * 3]), b = uf_root(parent, m->tri[t * 3 + e]);
            parent[b] = a;
        }
    int outer = -1;
    for (long t = 0; t < m->nt; t++)
        vol[uf_root(parent, m->tri[t * 3])] += tri_volume6(m, t);
    for (long v = 0; v < m->nv; v++)
        if (parent[v] == v && vol[v] > 0 && (outer < 0 || vol[v] > vol[outer]))
            outer = (int)v;
    /* positive parts but the outer one are islands; negative ones are cavities' walls */
    long nt = 0, dropped = 0;
    for (long v = 0; v < m->nv; v++)
        dropped += parent[v] == v && vol[v] > 0 && v != outer;
    for (long t = 0; t < m->nt; t++) {
        int r = uf_root(parent, m->tri[t * 3]);
        if (r != outer && vol[r] > 0)
            continue;
        memmove(m->tri + nt * 3, m->tri + t * 3, 3 * sizeof *m->tri);
        nt++;
    }
    m->nt = nt;
    drop_unused_vertices(m, parent);
    free(parent), free(vol);
    return dropped;
}

long mesh_decimate(mesh *m, long target)
{
    if (target < 4)
        target = 4;
    while (m->nt > target) {
        int *vstart = calloc((size_t)m->nv + 1, sizeof *vstart), *vt = malloc((size_t)m->nt * 3 * sizeof *vt);
        int *fill = malloc((size_t)m->nv * sizeof *fill), *remap = malloc((size_t)m->nv * sizeof *remap);
        unsigned char *lock = calloc((size_t)m->nv, 1);
        cand *c = malloc((size_t)m->nt * 3 * sizeof *c);
        if (!vstart || !vt || !fill || !remap || !lock || !c) {
            free(vstart), free(vt), free(fill), free(remap), free(lock), free(c);
            return fn_err_set(FN_ENOMEM, "mesh: out of memory decimating %ld triangles", m->nt);
        }
        for (long t = 0; t < m->nt * 3; t++)
            vstart[m->tri[t] + 1]++;
        for (long v = 0; v < m->nv; v++)
            vstart[v + 1] += vstart[v];
        memcpy(fill, vstart, (size_t)m->nv * sizeof *fill);
        long nc = 0;
        for (long t = 0; t < m->nt; t++)
            for (int e = 0; e < 3; e++) {
                int a = m->tri[t * 3 + e], b = m->tri[t * 3 + (e + 1) % 3];
                vt[fill[a]++] = (int)t;
                if (a < b) { /* each edge once */
                    float d[3];
                    for (int k = 0; k < 3; k++)
                        d[k] = m->v[(size_t)a * 3 + k] - m->v[(size_t)b * 3 + k];
                    c[nc++] = (cand){d[0] * d[0] + d[1] * d[1] + d[2] * d[2], a, b};
                }
            }
        qsort(c, (size_t)nc, sizeof *c, cand_cmp);
        for (long v = 0; v < m->nv; v++)
            remap[v] = (int)v;
        long want = (m->nt - target + 1) / 2, done = 0;
        for (long k = 0; k < nc && done < want; k++) {
            int a = c[k].a, b = c[k].b;
            if (lock[a] || lock[b] || !can_collapse(m, vstart, vt, a, b))
                continue;
            for (int s = 0; s < 2; s++) { /* the one-rings change: lock them for this pass */
                int v = s ? b : a;
                for (int e = vstart[v]; e < vstart[v + 1]; e++)
                    for (int q = 0; q < 3; q++)
                        lock[m->tri[(size_t)vt[e] * 3 + (size_t)q]] = 1;
            }
            for (int q = 0; q < 3; q++)
                m->v[(size_t)a * 3 + (size_t)q] = 0.5f * (m->v[(size_t)a * 3 + (size_t)q] + m->v[(size_t)b * 3 + (size_t)q]);
            remap[b] = a;
            done++;
        }
        /* Rewrite the triangles; those that held both ends vanish; unused vertices go. */
        long nt = 0;
        for (long t = 0; t < m->nt; t++) {
            int x = remap[m->tri[t * 3]], y = remap[m->tri[t * 3 + 1]], z = remap[m->tri[t * 3 + 2]];
            if (x == y || y == z || x == z)
                continue;
            m->tri[nt * 3] = x, m->tri[nt * 3 + 1] = y, m->tri[nt * 3 + 2] = z;
            nt++;
        }
        m->nt = nt;
        drop_unused_vertices(m, fill);
        free(vstart), free(vt), free(fill), free(remap), free(lock), free(c);
        if (done == 0)
            break;
    }
    return m->nt;
}
