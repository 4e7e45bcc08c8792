/* mesh: surface meshes by marching tetrahedra: each cube of the (strided) grid is split into the six
 * tetrahedra around its main diagonal (Kuhn's split, which neighbouring cubes share face for face,
 * so the surface has no cracks). The cases are computed, not tabled. Normals come from the grid's
 * central differences, interpolated like the positions. */
#include "mesh.h"

#include "err.h"

#include <stdlib.h>
#include <string.h>

/* Corners as bits: x = 1, y = 2, z = 4; each tetrahedron walks from corner 0 to 7 along the axes. */
static const int tets[6][4] = {{0, 1, 3, 7}, {0, 2, 3, 7}, {0, 2, 6, 7},
                               {0, 4, 6, 7}, {0, 4, 5, 7}, {0, 1, 5, 7}};

typedef struct mesh_buf {
    float *v;
    size_t n, cap; /* floats */
} mesh_buf;

typedef struct corner {
    float p[3], g[3], val;
} corner;

static int push_vertex(mesh_buf *m, const corner *a, const corner *b, float level)
{
    if (m->n + 6 > m->cap) {
        size_t cap = m->cap ? m->cap * 2 : 6 * 4096;
        float *v = realloc(m->v, cap * sizeof *v);
        if (!v)
            return FN_ENOMEM;
        m->v = v;
        m->cap = cap;
    }
    float den = b->val - a->val;
    float s = den != 0.0f ? (level - a->val) / den : 0.5f;
    float *o = m->v + m->n;
    for (int k = 0; k < 3; k++) {
        o[k] = a->p[k] + s * (b->p[k] - a->p[k]);
        o[3 + k] = -(a->g[k] + s * (b->g[k] - a->g[k])); /* outward: against the gradient */
    }
    m->n += 6;
    return 0;
}

/* One tetrahedron: a triangle when one corner differs from the other three, a quad when two do. */
static int march_tet(mesh_buf *m, const corner *c[4], float level)
{
    int in[4], n_in = 0;
    for (int k = 0; k < 4; k++)
        n_in += in[k] = c[k]->val >= level;
    if (n_in == 0 || n_in == 4)
        return 0;
    int a[4], na = 0, b[4], nb = 0; /* a: the minority side */
    int minority = n_in <= 2 ? 1 : 0;
    for (int k = 0; k < 4; k++) {
        if (in[k] == minority)
            a[na++] = k;
        else
            b[nb++] = k;
    }
    int rc = 0;
    if (na == 1) {
        for (int k = 0; k < 3 && !rc; k++)
            rc = push_vertex(m, c[a[0]], c[b[k]], level);
        return rc;
    }
    /* Quad a0b0, a0b1, a1b1, a1b0 as two triangles. */
    const int q[6][2] = {{0, 0}, {0, 1}, {1, 1}, {0, 0}, {1, 1}, {1, 0}};
    for (int k = 0; k < 6 && !rc; k++)
        rc = push_vertex(m, c[a[q[k][0]]], c[b[q[k][1]]], level);
    return rc;
}

static float at(const float *vals, const int dim[3], int i, int j, int k)
{
    i = i < 0 ? 0 : i >= dim[0] ? dim[0] - 1 : i;
    j = j < 0 ? 0 : j >= dim[1] ? dim[1] - 1 : j;
    k = k < 0 ? 0 : k >= dim[2] ? dim[2] - 1 : k;
    return vals[((size_t)k * (size_t)dim[1] + (size_t)j) * (size_t)dim[0] + (size_t)i];
}

static void make_corner(corner *c, const float *vals, const int dim[3], const double sp[3], int i,
                        int j, int k, const int s[3])
{
    int ijk[3] = {i, j, k};
    c->val = at(vals, dim, i, j, k);
    for (int a = 0; a < 3; a++) {
        int lo[3] = {i, j, k}, hi[3] = {i, j, k};
        lo[a] -= s[a];
        hi[a] += s[a];
        c->p[a] = (float)(ijk[a] * sp[a]);
        c->g[a] = (at(vals, dim, hi[0], hi[1], hi[2]) - at(vals, dim, lo[0], lo[1], lo[2])) /
                  (float)(2.0 * s[a] * sp[a]);
    }
}

long mesh_build(const float *vals, const int dim[3], const double spacing[3], float level,
                const int stride[3], float **out)
{
    mesh_buf m = {0};
    const int s[3] = {stride[0] < 1 ? 1 : stride[0], stride[1] < 1 ? 1 : stride[1],
                      stride[2] < 1 ? 1 : stride[2]};
    for (int k = 0; k + s[2] < dim[2]; k += s[2])
        for (int j = 0; j + s[1] < dim[1]; j += s[1])
            for (int i = 0; i + s[0] < dim[0]; i += s[0]) {
                float lo = 1e30f, hi = -1e30f;
                for (int b = 0; b < 8; b++) {
                    float v = at(vals, dim, i + (b & 1) * s[0], j + (b >> 1 & 1) * s[1], k + (b >> 2 & 1) * s[2]);
                    lo = v < lo ? v : lo;
                    hi = v > hi ? v : hi;
                }
                if (hi < level || lo >= level)
                    continue;
                corner c[8];
                for (int b = 0; b < 8; b++)
                    make_corner(&c[b], vals, dim, spacing, i + (b & 1) * s[0], j + (b >> 1 & 1) * s[1],
                                k + (b >> 2 & 1) * s[2], s);
                for (int t = 0; t < 6; t++) {
                    const corner *tc[4] = {&c[tets[t][0]], &c[tets[t][1]], &c[tets[t][2]], &c[tets[t][3]]};
                    if (march_tet(&m, tc, level)) {
                        free(m.v);
                        return fn_err_set(FN_ENOMEM, "mesh: out of memory building a surface mesh");
                    }
                }
            }
    *out = m.v;
    return (long)(m.n / 18);
}
