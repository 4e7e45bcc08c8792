#include "fracture.h"
#include "fracture_impl.h"

#include "case.h"
#include "err.h"
#include "frag.h"
#include "bone.h"
#include "seg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

void fracture_defaults(fracture_params *p)
{
    memset(p, 0, sizeof *p);
    p->seed = 1;
    p->pieces = 2;
    p->displace_mm = 3;
    p->rotate_deg = 3;
    p->roughness_mm = 2;
    p->wavelength_mm = 16;
    p->threshold = 300;
    p->fill = 40;
    p->model = 1;
    p->noise_hu = 20;
    p->tau_min = CASE_TAU_MIN;
    p->tau_max = CASE_TAU_MAX;
}

uint64_t fracture_rng_next(uint64_t *state)
{
    uint64_t z = (*state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

double fracture_rng_uniform(uint64_t *state)
{
    return (double)(fracture_rng_next(state) >> 11) * (1.0 / 9007199254740992.0);
}

static double lattice(uint64_t seed, int64_t x, int64_t y, int64_t z)
{
    uint64_t s = seed ^ ((uint64_t)x * 0x8da6b343ull) ^ ((uint64_t)y * 0xd8163841ull) ^
                 ((uint64_t)z * 0xcb1ab31full);
    return fracture_rng_uniform(&s) * 2 - 1;
}

static double smooth(double t)
{
    return t * t * (3 - 2 * t);
}

static double value_noise(uint64_t seed, const double p[3])
{
    double fl[3] = {floor(p[0]), floor(p[1]), floor(p[2])};
    int64_t c[3] = {(int64_t)fl[0], (int64_t)fl[1], (int64_t)fl[2]};
    double w[3] = {smooth(p[0] - fl[0]), smooth(p[1] - fl[1]), smooth(p[2] - fl[2])};
    double acc = 0;
    for (int corner = 0; corner < 8; corner++) {
        int dx = corner & 1, dy = (corner >> 1) & 1, dz = corner >> 2;
        double wt = (dx ? w[0] : 1 - w[0]) * (dy ? w[1] : 1 - w[1]) * (dz ? w[2] : 1 - w[2]);
        acc += wt * lattice(seed, c[0] + dx, c[1] + dy, c[2] + dz);
    }
    return acc;
}

double fracture_fbm(uint64_t seed, const double x[3])
{
    double p[3] = {x[0], x[1], x[2]}, amp = 1, sum = 0, norm = 0;
    for (int octave = 0; octave < 4; octave++) {
        sum += amp * value_noise(seed + (uint64_t)octave * 0x632be59bd9b4e019ull, p);
        norm += amp;
        amp *= 0.5;
        for (int a = 0; a < 3; a++)
            p[a] = p[a] * 2 + 17.25;
    }
    /* Octave-normalised value noise has a standard deviation of about 0.23: scale it to ~1. */
    return sum / norm * 4.3;
}

/* sin and cos of x in [-pi, pi] by Taylor series: the same bits on every machine, unlike libm. */
static void det_sincos(double x, double *s, double *c)
{
    double term_s = x, term_c = 1, ss = 0, cc = 0;
    for (int n = 0; n < 20; n++) {
        ss += term_s;
        cc += term_c;
        term_s *= -x * x / ((2 * n + 2) * (2 * n + 3));
        term_c *= -x * x / ((2 * n + 1) * (2 * n + 2));
    }
    *s = ss;
    *c = cc;
}

static void random_unit(uint64_t *rng, double u[3])
{
    for (;;) {
        double r2 = 0;
        for (int a = 0; a < 3; a++) {
            u[a] = fracture_rng_uniform(rng) * 2 - 1;
            r2 += u[a] * u[a];
        }
        if (r2 > 1e-4 && r2 <= 1) {
            double r = sqrt(r2);
            for (int a = 0; a < 3; a++)
                u[a] /= r;
            return;
        }
    }
}

static void normalize3(double v[3])
{
    double r = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int a = 0; a < 3; a++)
        v[a] /= r;
}

/* Bounding box of label id in lab; 0 if present. */
struct cut {
    double point[3], normal[3];
    uint64_t noise_seed;
    double rough, wavelength;
};

/* Signed distance-like value of world point x to the rough surface: > 0 on the piece's side. */
static double cut_side(const struct cut *c, const double x[3])
{
    double d = 0, q[3];
    for (int a = 0; a < 3; a++) {
        d += (x[a] - c->point[a]) * c->normal[a];
        q[a] = x[a] / c->wavelength;
    }
    return d + c->rough * fracture_fbm(c->noise_seed, q);
}

/* What a cut makes of each voxel of a piece's box. */
enum { SIDE_NONE, SIDE_STAYS, SIDE_NEW, SIDE_LOST };

/* Classifies the voxels of label `from` in box [lo, hi] (side[], box order): the positive side
 * of the cut is new, bone within loss/2 of the surface is lost. */
static void cut_classify(const vol *lab, int from, const struct cut *c, const int lo[3],
                         const int hi[3], double loss, uint8_t *side)
{
    size_t b = 0;
    for (int k = lo[2]; k <= hi[2]; k++)
        for (int j = lo[1]; j <= hi[1]; j++)
            for (int i = lo[0]; i <= hi[0]; i++, b++) {
                side[b] = SIDE_NONE;
                if (lab->data[vol_idx(lab, i, j, k)] != (float)from)
                    continue;
                double ijk[3] = {i, j, k}, x[3];
                vol_index_to_world(lab, ijk, x);
                double s = cut_side(c, x);
                side[b] = loss > 0 && s > -loss / 2 && s <= loss / 2 ? SIDE_LOST
                          : s > 0                                  ? SIDE_NEW
                                                                   : SIDE_STAYS;
            }
}

/* Islands of side `which` (all but its largest 26-connected part) go to side `to`. */
static int cut_islands(uint8_t *side, const int bdim[3], int which, int to, uint8_t *mask,
                       int32_t *comp)
{
    size_t n = (size_t)bdim[0] * bdim[1] * bdim[2];
    for (size_t b = 0; b < n; b++)
        mask[b] = side[b] == which;
    int nc = seg_components(mask, bdim, comp);
    if (nc < 0)
        return nc;
    size_t *count = calloc((size_t)nc + 1, sizeof *count);
    if (!count)
        return fn_err_set(FN_ENOMEM, "out of memory");
    for (size_t b = 0; b < n; b++)
        count[comp[b]]++;
    int32_t big = 1;
    for (int32_t c = 2; c <= nc; c++)
        if (count[c] > count[big])
            big = c;
    for (size_t b = 0; b < n; b++)
        if (comp[b] && comp[b] != big)
            side[b] = (uint8_t)to;
    free(count);
    return 0;
}

/* Makes each side one piece: a rough surface leaves islands of one side in the other, which
 * would lock the pieces together. They join the other side; what is still loose is lost. */
static int cut_connect(uint8_t *side, const int bdim[3])
{
    size_t n = (size_t)bdim[0] * bdim[1] * bdim[2];
    uint8_t *mask = malloc(n);
    int32_t *comp = malloc(n * sizeof *comp);
    int rc = mask && comp ? 0 : fn_err_set(FN_ENOMEM, "out of memory");
    if (rc == 0)
        rc = cut_islands(side, bdim, SIDE_NEW, SIDE_STAYS, mask, comp);
    if (rc == 0)
        rc = cut_islands(side, bdim, SIDE_STAYS, SIDE_NEW, mask, comp);
    if (rc == 0)
        rc = cut_islands(side, bdim, SIDE_NEW, SIDE_LOST, mask, comp);
    free(mask);
    free(comp);
    return rc;
}

static void cut_count(const uint8_t *side, size_t n, size_t kept[2])
{
    kept[0] = kept[1] = 0;
    for (size_t b = 0; b < n; b++)
        if (side[b] == SIDE_STAYS || side[b] == SIDE_NEW)
            kept[side[b] == SIDE_NEW]++;
}

/* Applies side[] to the box: new voxels become label `to`; lost bone becomes background and
 * `fill` in ct. */
static void cut_write(vol *lab, vol *ct, int to, const uint8_t *side, const int lo[3],
                      const int hi[3], double fill)
{
    size_t b = 0;
    for (int k = lo[2]; k <= hi[2]; k++)
        for (int j = lo[1]; j <= hi[1]; j++)
            for (int i = lo[0]; i <= hi[0]; i++, b++) {
                size_t idx = vol_idx(lab, i, j, k);
                if (side[b] == SIDE_NEW)
                    lab->data[idx] = (float)to;
                else if (side[b] == SIDE_LOST) {
                    lab->data[idx] = 0;
                    ct->data[idx] = (float)fill;
                }
            }
}

static int piece_stats(const vol *lab, int id, frag *f)
{
    int lo[3], hi[3];
    if (frag_label_box(lab, id, lo, hi) < 0)
        return fn_err_set(FN_EINVAL, "piece %d is empty", id);
    return frag_from_labels(f, lab, NULL, id, lo, hi, 0, 0);
}

/* A piece keeps at least 1/share_divisor of the bone: 10 pieces of 10% each would all have to be
 * cut exactly, so beyond 6 pieces the share is 1/(2 pieces). */
static int share_divisor(int pieces)
{
    return pieces > 6 ? 2 * pieces : 10;
}

size_t fracture_min_piece(size_t bone_voxels, int pieces)
{
    int d = share_divisor(pieces);
    return (bone_voxels + (size_t)d - 1) / (size_t)d;
}

/* Splits the largest piece so far with a random rough cut; its smaller side becomes piece `to`.
 * Both sides keep at least min_piece voxels (fracture_min_piece), or the cut is refused. */
static int make_cut(vol *lab, vol *ct, int to, uint64_t *rng, const fracture_params *p,
                    size_t min_piece, double normal_out[3])
{
    int from = 1;
    size_t best = 0;
    for (int id = 1; id < to; id++) {
        int lo[3], hi[3];
        if (frag_label_box(lab, id, lo, hi) < 0)
            continue;
        size_t n = 0;
        for (int k = lo[2]; k <= hi[2]; k++)
            for (int j = lo[1]; j <= hi[1]; j++)
                for (int i = lo[0]; i <= hi[0]; i++)
                    n += lab->data[vol_idx(lab, i, j, k)] == (float)id;
        if (n > best) {
            best = n;
            from = id;
        }
    }
    double pct = 100.0 / share_divisor(p->pieces);
    if (best < 2 * min_piece)
        return fn_err_set(FN_EINVAL, "cannot cut piece %d: the largest piece so far "
                          "(%zu voxels) is under twice the smallest piece allowed (%.3g%% of the "
                          "bone, %zu voxels); ask for fewer --pieces", to, best, pct, min_piece);
    frag f;
    int rc = piece_stats(lab, from, &f);
    if (rc < 0)
        return rc;
    int lo[3], hi[3], bdim[3];
    frag_label_box(lab, from, lo, hi);
    for (int a = 0; a < 3; a++)
        bdim[a] = hi[a] - lo[a] + 1;
    size_t nbox = (size_t)bdim[0] * bdim[1] * bdim[2];
    uint8_t *side = malloc(nbox);
    if (!side) {
        frag_free(&f);
        return fn_err_set(FN_ENOMEM, "out of memory");
    }
    for (int attempt = 0; attempt < 32 && rc == 0; attempt++) {
        struct cut c = {.rough = p->roughness_mm, .wavelength = p->wavelength_mm};
        double u1 = fracture_rng_uniform(rng) * 2 - 1, u2 = fracture_rng_uniform(rng) * 2 - 1;
        double off = (fracture_rng_uniform(rng) * 2 - 1) * 0.6 * sqrt(f.eigval[0]);
        c.noise_seed = fracture_rng_next(rng);
        for (int a = 0; a < 3; a++) {
            c.normal[a] = f.axes[a][0] + 0.5 * (u1 * f.axes[a][1] + u2 * f.axes[a][2]);
            c.point[a] = f.centroid[a] + off * f.axes[a][0];
        }
        normalize3(c.normal);
        size_t kept[2];
        cut_classify(lab, from, &c, lo, hi, p->bone_loss_mm, side);
        cut_count(side, nbox, kept);
        if (kept[0] < min_piece || kept[1] < min_piece)
            continue;
        rc = cut_connect(side, bdim);
        cut_count(side, nbox, kept);
        if (rc < 0 || kept[0] < min_piece || kept[1] < min_piece)
            continue;
        if (kept[1] > kept[0]) {
            /* The new piece is always the smaller side. */
            for (size_t b = 0; b < nbox; b++)
                if (side[b] == SIDE_NEW || side[b] == SIDE_STAYS)
                    side[b] = side[b] == SIDE_NEW ? SIDE_STAYS : SIDE_NEW;
            for (int a = 0; a < 3; a++)
                c.normal[a] = -c.normal[a];
        }
        cut_write(lab, ct, to, side, lo, hi, p->fill);
        memcpy(normal_out, c.normal, sizeof c.normal);
        free(side);
        frag_free(&f);
        return 0;
    }
    free(side);
    if (rc < 0) {
        frag_free(&f);
        return rc;
    }
    frag_free(&f);
    return fn_err_set(FN_EINVAL, "no cut of piece %d (%zu voxels) leaves both sides at "
                      "least %.3g%% of the bone (%zu voxels) in 32 tries: the bone is too thin or "
                      "irregular for %d pieces; ask for fewer --pieces", from, best, pct, min_piece,
                      p->pieces);
}

/* The random part of a piece's motion: a rotation about its centroid (returned) and the
 * direction it moves in, `out` (away from the bone's centre) perturbed. */
static pose random_motion(uint64_t *rng, const double centroid[3], const double out[3],
                          const fracture_params *p, double dir[3])
{
    double axis[3], pert[3], s, c;
    random_unit(rng, axis);
    random_unit(rng, pert);
    double half = p->rotate_deg * (3.14159265358979323846 / 360.0);
    det_sincos(half, &s, &c);
    pose m = {{c, s * axis[0], s * axis[1], s * axis[2]}, {0, 0, 0}};
    for (int a = 0; a < 3; a++)
        dir[a] = out[a] + 0.5 * pert[a];
    normalize3(dir);
    double rc[3];
    pose_rotate(&m, centroid, rc);
    for (int a = 0; a < 3; a++)
        m.t[a] = centroid[a] - rc[a];
    return m;
}

/* Whether a moved piece may not land on output voxel idx: another piece is there already, or a
 * bright object that is not bone (obstacle: the head holder, >= threshold but in no piece). */
static int occupied(const vol *out_lab, const vol *obstacle, size_t idx, int id)
{
    float l = out_lab->data[idx];
    return (l != 0 && l != (float)id) || obstacle->data[idx] != 0;
}

void fracture__moved_box(const vol *cut, int id, pose m, const vol *out_lab, int spare, int olo[3], int ohi[3])
{
    int lo[3], hi[3];
    frag_label_box(cut, id, lo, hi);
    double blo[3] = {INFINITY, INFINITY, INFINITY}, bhi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int corner = 0; corner < 8; corner++) {
        double ijk[3] = {corner & 1 ? hi[0] : lo[0], corner & 2 ? hi[1] : lo[1],
                         corner & 4 ? hi[2] : lo[2]};
        double w[3], mw[3], oi[3];
        vol_index_to_world(cut, ijk, w);
        pose_apply(&m, w, mw);
        vol_world_to_index(out_lab, mw, oi);
        for (int a = 0; a < 3; a++) {
            blo[a] = fmin(blo[a], oi[a]);
            bhi[a] = fmax(bhi[a], oi[a]);
        }
    }
    for (int a = 0; a < 3; a++) {
        olo[a] = (int)floor(blo[a]) - spare;
        ohi[a] = (int)ceil(bhi[a]) + spare;
    }
}

/* Resamples piece `id` of cut (home: cut and src_ct on the input grid) moved by m into
 * out_lab/out_ct (output grid, nearest neighbour). Counts voxels that would land where `occupied`
 * says no (past the grid's edge there is nothing: fit_grid makes room there before apply);
 * writes only when apply, and without apply stops at the first such voxel (returns 1). */
static size_t place_piece(const vol *cut, const vol *src_ct, const vol *obstacle, vol *out_lab,
                          vol *out_ct, int id, pose m, int apply)
{
    int olo[3], ohi[3];
    fracture__moved_box(cut, id, m, out_lab, 1, olo, ohi);
    for (int a = 0; a < 3; a++) {
        olo[a] = olo[a] < 0 ? 0 : olo[a];
        ohi[a] = ohi[a] > out_lab->dim[a] - 1 ? out_lab->dim[a] - 1 : ohi[a];
    }
    pose inv = pose_inverse(m);
    size_t conflicts = 0;
    for (int k = olo[2]; k <= ohi[2]; k++)
        for (int j = olo[1]; j <= ohi[1]; j++)
            for (int i = olo[0]; i <= ohi[0]; i++) {
                double ijk[3] = {i, j, k}, y[3], x[3], s[3];
                vol_index_to_world(out_lab, ijk, y);
                pose_apply(&inv, y, x);
                vol_world_to_index(cut, x, s);
                int si[3];
                int inside = 1;
                for (int a = 0; a < 3; a++) {
                    si[a] = (int)floor(s[a] + 0.5);
                    inside &= si[a] >= 0 && si[a] < cut->dim[a];
                }
                if (!inside)
                    continue;
                size_t from = vol_idx(cut, si[0], si[1], si[2]);
                if (cut->data[from] != (float)id)
                    continue;
                size_t to = vol_idx(out_lab, i, j, k);
                if (occupied(out_lab, obstacle, to, id)) {
                    if (!apply)
                        return 1; /* the push-out loop only asks whether there is any */
                    conflicts++;
                    continue;
                }
                if (apply) {
                    out_lab->data[to] = (float)id;
                    out_ct->data[to] = src_ct->data[from];
                }
            }
    return conflicts;
}

vol *fracture__padded(const vol *v, const int lo[3], const int hi[3], float value)
{
    vol *c = vol_new(v->dim[0] + lo[0] + hi[0], v->dim[1] + lo[1] + hi[1], v->dim[2] + lo[2] + hi[2]);
    if (!c)
        return NULL;
    for (size_t i = 0; i < vol_count(c); i++)
        c->data[i] = value;
    for (int k = 0; k < v->dim[2]; k++)
        for (int j = 0; j < v->dim[1]; j++)
            memcpy(&c->data[vol_idx(c, lo[0], j + lo[1], k + lo[2])], &v->data[vol_idx(v, 0, j, k)],
                   (size_t)v->dim[0] * sizeof(float));
    double first[3] = {-lo[0], -lo[1], -lo[2]};
    memcpy(c->affine, v->affine, sizeof v->affine);
    for (int a = 0; a < 3; a++) {
        c->affine[a][3] = v->affine[a][3];
        for (int b = 0; b < 3; b++)
            c->affine[a][3] += v->affine[a][b] * first[b];
    }
    memcpy(c->spacing, v->spacing, sizeof v->spacing);
    c->src_type = v->src_type;
    return c;
}

int fracture_check(const fracture_params *p)
{
    const struct {
        const char *name;
        double value, lo, hi;
        const char *unit;
    } rows[] = {{"pieces", p->pieces, 2, 10, ""},
                {"displace", p->displace_mm, 0, 200, " mm"},
                {"rotate", p->rotate_deg, 0, 180, " deg"},
                {"bone loss", p->bone_loss_mm, 0, 20, " mm"},
                {"roughness", p->roughness_mm, 0, 50, " mm"},
                {"wavelength", p->wavelength_mm, 0.5, 1000, " mm"},
                {"model", p->model, 1, 2, ""},
                {"noise", p->noise_hu, 0, 10000, " HU"}};
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++)
        if (!(rows[i].value >= rows[i].lo && rows[i].value <= rows[i].hi))
            return fn_err_set(FN_EINVAL, "%s must be %g..%g%s (got %g)", rows[i].name, rows[i].lo,
                              rows[i].hi, rows[i].unit, rows[i].value);
    if (!isfinite(p->threshold) || !isfinite(p->fill))
        return fn_err_set(FN_EINVAL, "fracture threshold and fill must be finite");
    return 0;
}

/* Candidate directions of a piece's move, in order of preference: dir (out, perturbed), the
 * normal of the cut that made the piece (away from the piece it was cut from), the mean of that
 * normal and out, then out tilted by 30 and 60 degrees toward 8 azimuths, then 8 across out:
 * none leads back toward the bone's centre. */
enum { PUSH_DIRS = 27 };

static void push_dirs(const double dir[3], const double out[3], const double normal[3],
                      double d[PUSH_DIRS][3])
{
    /* e1, e2: a basis across out, from the world axis least aligned with it. */
    int least = 0;
    for (int a = 1; a < 3; a++)
        if (fabs(out[a]) < fabs(out[least]))
            least = a;
    double ax[3] = {0, 0, 0}, e1[3], e2[3];
    ax[least] = 1;
    for (int a = 0; a < 3; a++)
        e1[a] = ax[a] - out[least] * out[a];
    normalize3(e1);
    for (int a = 0; a < 3; a++)
        e2[a] = out[(a + 1) % 3] * e1[(a + 2) % 3] - out[(a + 2) % 3] * e1[(a + 1) % 3];
    const double h = 0.70710678118654752440;
    const double tilt[2] = {0.57735026918962576451, 1.7320508075688772935}; /* tan 30, tan 60 */
    const double az[8][2] = {{1, 0}, {h, h}, {0, 1}, {-h, h}, {-1, 0}, {-h, -h}, {0, -1}, {h, -h}};
    /* The normal, where it does not lead back toward the centre. */
    double along = normal[0] * out[0] + normal[1] * out[1] + normal[2] * out[2];
    for (int a = 0; a < 3; a++) {
        d[0][a] = dir[a];
        d[1][a] = along >= 0 ? normal[a] : dir[a];
        d[2][a] = normal[a] + out[a];
    }
    normalize3(d[2]);
    for (int t = 0; t < 3; t++)
        for (int k = 0; k < 8; k++) {
            double *v = d[3 + t * 8 + k];
            for (int a = 0; a < 3; a++)
                v[a] = t < 2 ? out[a] + tilt[t] * (az[k][0] * e1[a] + az[k][1] * e2[a])
                             : az[k][0] * e1[a] + az[k][1] * e2[a];
            normalize3(v);
        }
}

/* A moved piece's voxels, forward-mapped into the output grid (index coordinates), for a fast
 * search of the push that clears it; place_piece's exact test has the last word. */
struct push {
    double *q; /* n index triples */
    size_t n;
    const vol *cut, *src_ct, *obstacle;
    vol *out_lab, *out_ct;
    int id;
    pose turned; /* the piece's rotation about its centroid, before any push */
};

/* The turned piece pushed by len mm along d. */
static pose pushed(const struct push *pp, double len, const double d[3])
{
    pose t = pp->turned;
    for (int a = 0; a < 3; a++)
        t.t[a] += len * d[a];
    return t;
}

/* 1 if the piece moved by s*dq (index units) lands clear; 0 on another piece. Past the grid's
 * edge there is nothing to land on: the grid grows to hold the piece (fit_grid). */
static int push_clear(const struct push *pp, double s, const double dq[3])
{
    const int *dim = pp->out_lab->dim;
    for (size_t v = 0; v < pp->n; v++) {
        int si[3], inside = 1;
        for (int a = 0; a < 3; a++) {
            si[a] = (int)floor(pp->q[3 * v + a] + s * dq[a] + 0.5);
            inside &= si[a] >= 0 && si[a] < dim[a];
        }
        if (inside && occupied(pp->out_lab, pp->obstacle, vol_idx(pp->out_lab, si[0], si[1], si[2]), pp->id))
            return 0;
    }
    return 1;
}

/* The piece's voxels moved by m, as output index coordinates; 0 or FN_ENOMEM. */
static int push_init(struct push *pp, int id, pose m)
{
    const vol *cut = pp->cut;
    int lo[3], hi[3];
    frag_label_box(cut, id, lo, hi);
    size_t cap = (size_t)(hi[0] - lo[0] + 1) * (size_t)(hi[1] - lo[1] + 1) *
                 (size_t)(hi[2] - lo[2] + 1);
    pp->q = malloc(cap * 3 * sizeof *pp->q);
    if (!pp->q)
        return fn_err_set(FN_ENOMEM, "out of memory");
    pp->n = 0;
    for (int k = lo[2]; k <= hi[2]; k++)
        for (int j = lo[1]; j <= hi[1]; j++)
            for (int i = lo[0]; i <= hi[0]; i++) {
                if (cut->data[vol_idx(cut, i, j, k)] != (float)id)
                    continue;
                double ijk[3] = {i, j, k}, w[3], mw[3];
                vol_index_to_world(cut, ijk, w);
                pose_apply(&m, w, mw);
                vol_world_to_index(pp->out_lab, mw, &pp->q[3 * pp->n++]);
            }
    return 0;
}

/* The shortest move, displace_mm and then steps of one voxel (up to max_steps), along one of
 * push_dirs that lands the piece clear; *move (the direction) and *steps set and 0, or FN_EINVAL
 * saying why none does. */
static int push_search(const struct push *pp, const double dir[3], const double out[3],
                       const double normal[3], double displace, double step, int max_steps,
                       double move[3], int *steps)
{
    double d[PUSH_DIRS][3], o[3] = {0, 0, 0}, oq[3];
    push_dirs(dir, out, normal, d);
    vol_world_to_index(pp->out_lab, o, oq);
    int best = -1;
    for (int c = 0; c < PUSH_DIRS; c++) {
        double x[3], dq[3];
        for (int a = 0; a < 3; a++)
            x[a] = step * d[c][a];
        vol_world_to_index(pp->out_lab, x, dq);
        for (int a = 0; a < 3; a++)
            dq[a] -= oq[a];
        /* A later direction must do strictly better: the first ones point straighter out. */
        int limit = best < 0 ? max_steps : best - 1;
        for (int s = 0; s <= limit; s++)
            if (push_clear(pp, displace / step + s, dq) &&
                place_piece(pp->cut, pp->src_ct, pp->obstacle, pp->out_lab, pp->out_ct, pp->id,
                            pushed(pp, displace + s * step, d[c]), 0) == 0) {
                best = s;
                memcpy(move, d[c], sizeof d[c]);
                break;
            }
        if (best == 0)
            break;
    }
    if (best < 0)
        return fn_err_set(FN_EINVAL, "piece %d cannot be placed clear of the others "
                          "within %.1f mm of --displace", pp->id, max_steps * step);
    *steps = best;
    return 0;
}

/* Grows the output grids (r->ct, r->labels and *obstacle) where piece `id` moved by m would reach
 * past their edge, so that a piece pushed out of the scanned field is kept whole. The new voxels
 * are `outside` in the CT (its lowest value: nothing scanned), 0 in the others. */
static int fit_grid(fracture_result *r, vol **obstacle, int id, pose m, float outside)
{
    int olo[3], ohi[3], lo[3], hi[3], grow = 0;
    fracture__moved_box(r->cut, id, m, r->labels, 1, olo, ohi);
    for (int a = 0; a < 3; a++) {
        lo[a] = olo[a] < 0 ? -olo[a] : 0;
        hi[a] = ohi[a] >= r->labels->dim[a] ? ohi[a] - r->labels->dim[a] + 1 : 0;
        grow |= lo[a] | hi[a];
    }
    if (!grow)
        return 0;
    vol *g[3] = {fracture__padded(r->ct, lo, hi, outside), fracture__padded(r->labels, lo, hi, 0),
                 fracture__padded(*obstacle, lo, hi, 0)};
    vol **slot[3] = {&r->ct, &r->labels, obstacle};
    int ok = g[0] && g[1] && g[2];
    for (int v = 0; v < 3; v++) {
        vol_free(ok ? *slot[v] : g[v]);
        if (ok)
            *slot[v] = g[v];
    }
    return ok ? 0 : fn_err_wrap(FN_ENOMEM, "piece %d lands past the CT's edge, and the "
                                "grid grown to hold it does not fit", id);
}

/* Moves piece id (turned by m, the random part of its motion) on in voxel steps, the shortest push
 * out of push_dirs, until it lands on no other piece; grows the grid where it lands past it. */
static int displace_piece(fracture_result *r, const vol *src_ct, vol **obstacle, int id, pose m,
                          const double push[3][3], double displace, int max_steps, float outside)
{
    double step = fmin(src_ct->spacing[0], fmin(src_ct->spacing[1], src_ct->spacing[2])), move[3] = {0, 0, 0};
    int steps = 0;
    struct push pp = {.cut = r->cut, .src_ct = src_ct, .obstacle = *obstacle, .out_lab = r->labels,
                      .out_ct = r->ct, .id = id, .turned = m};
    int rc = push_init(&pp, id, m);
    if (rc == 0)
        rc = push_search(&pp, push[0], push[1], push[2], displace, step, max_steps, move, &steps);
    free(pp.q);
    if (rc == 0)
        rc = fit_grid(r, obstacle, id, m = pushed(&pp, displace + steps * step, move), outside);
    if (rc < 0)
        return rc;
    place_piece(r->cut, src_ct, *obstacle, r->labels, r->ct, id, m, 1);
    r->moved[id - 1] = m;
    r->truth[id - 1] = pose_inverse(m);
    return 0;
}

/* Moves pieces 2..n (cut on src_ct's grid), each away from the bone's centre, turned, then pushed
 * on until it lands clear (displace_piece). */
static int displace_pieces(fracture_result *r, const vol *src_ct, uint64_t *rng, const fracture_params *p,
                           const double centre[3], double (*normals)[3], float outside)
{
    const int none[3] = {0, 0, 0};
    vol *obstacle = fracture__padded(r->cut, none, none, 0);
    if (!obstacle)
        return fn_err_set(FN_ENOMEM, "out of memory");
    for (size_t i = 0; i < vol_count(src_ct); i++) {
        float v = src_ct->data[i];
        obstacle->data[i] = r->cut->data[i] == 0 && isfinite(v) && v >= r->threshold;
        r->labels->data[i] = r->cut->data[i] == 1 ? 1 : 0;
        if (r->cut->data[i] > 1)
            r->ct->data[i] = (float)p->fill;
    }
    double step = fmin(src_ct->spacing[0], fmin(src_ct->spacing[1], src_ct->spacing[2]));
    double displace = p->touching ? 0 : p->displace_mm; /* touching: the first clear place */
    r->truth[0] = r->moved[0] = POSE_IDENTITY;
    int rc = 0;
    for (int id = 2; id <= r->pieces && rc == 0; id++) {
        frag f;
        if ((rc = piece_stats(r->cut, id, &f)) < 0)
            break;
        double out[3], dist = 0, push[3][3];
        for (int a = 0; a < 3; a++) {
            out[a] = f.centroid[a] - centre[a];
            dist += out[a] * out[a];
        }
        /* A piece around the centre has no outward direction: its cut's normal leads out. */
        if (sqrt(dist) < step)
            memcpy(out, normals[id - 2], sizeof out);
        normalize3(out);
        /* push: the direction it moves in, out, and its cut's normal */
        pose m = random_motion(rng, f.centroid, out, p, push[0]);
        memcpy(push[1], out, sizeof out);
        memcpy(push[2], normals[id - 2], sizeof out);
        /* A push as long as the piece is wide clears it in any direction that leads out. */
        int max_steps = (int)ceil(4 * sqrt(f.eigval[0]) / step) + 2;
        frag_free(&f);
        rc = displace_piece(r, src_ct, &obstacle, id, m, push, displace, max_steps, outside);
    }
    vol_free(obstacle);
    return rc;
}

int fracture__bone(const vol *ct, const fracture_params *p, seg_result *seg)
{
    seg_params sp;
    seg_defaults(&sp);
    sp.threshold = p->threshold;
    sp.threshold_auto = p->threshold_auto;
    sp.min_volume_ml = sp.min_volume_bone_only_ml = 0;
    sp.keep = 1;
    return p->whole_bone ? bone_segment(ct, &sp, seg) : seg_run(ct, &sp, seg);
}

int fracture__model1(const vol *ct, const fracture_params *p, fracture_result *out)
{
    memset(out, 0, sizeof *out);
    int rc = fracture_check(p);
    if (rc < 0)
        return rc;
    seg_result seg;
    rc = fracture__bone(ct, p, &seg);
    if (rc < 0)
        return rc;
    if (seg.ncomp < 1) {
        float lo, hi;
        vol_range(ct, &lo, &hi);
        rc = fn_err_set(FN_EINVAL, "no bone at or above %g%s: the CT's values run from %g to "
                        "%g; give another --threshold", seg.threshold, p->threshold_auto ? " (Otsu's)" : "",
                        (double)lo, (double)hi);
        seg_result_free(&seg);
        return rc;
    }
    out->threshold = seg.threshold;
    out->cut = seg.labels;
    seg.labels = NULL;
    seg_result_free(&seg);
    frag bone;
    rc = piece_stats(out->cut, 1, &bone);
    if (rc < 0) {
        fracture_result_free(out);
        return rc;
    }
    /* Smaller pieces are crumbs, not fragments. */
    size_t min_piece = fracture_min_piece(bone.voxels, p->pieces);
    double centre[3] = {bone.centroid[0], bone.centroid[1], bone.centroid[2]};
    frag_free(&bone);
    out->pieces = p->pieces;
    const int none[3] = {0, 0, 0};
    out->ct = fracture__padded(ct, none, none, 0);
    vol *work_ct = fracture__padded(ct, none, none, 0);
    out->labels = fracture__padded(out->cut, none, none, 0);
    out->truth = calloc((size_t)p->pieces, sizeof *out->truth);
    out->moved = calloc((size_t)p->pieces, sizeof *out->moved);
    double(*normals)[3] = calloc((size_t)p->pieces, sizeof *normals);
    if (!out->ct || !work_ct || !out->labels || !out->truth || !out->moved || !normals) {
        rc = fn_err_set(FN_ENOMEM, "out of memory");
        goto done;
    }
    uint64_t rng = p->seed;
    for (int id = 2; id <= p->pieces && rc == 0; id++)
        rc = make_cut(out->cut, work_ct, id, &rng, p, min_piece, normals[id - 2]);
    if (rc == 0) {
        /* The output starts from the CT after bone loss. */
        memcpy(out->ct->data, work_ct->data, vol_count(ct) * sizeof(float));
        float lowest, highest;
        vol_range(ct, &lowest, &highest);
        rc = displace_pieces(out, work_ct, &rng, p, centre, normals, lowest);
    }
done:
    vol_free(work_ct);
    free(normals);
    if (rc < 0)
        fracture_result_free(out);
    return rc;
}

void fracture_result_free(fracture_result *r)
{
    if (!r)
        return;
    vol_free(r->ct);
    vol_free(r->labels);
    vol_free(r->cut);
    free(r->truth);
    free(r->moved);
    memset(r, 0, sizeof *r);
}

double fracture_truth_shift(const pose *truth, const double centroid[3])
{
    double back[3], d2 = 0;
    pose_apply(truth, centroid, back);
    for (int a = 0; a < 3; a++)
        d2 += (back[a] - centroid[a]) * (back[a] - centroid[a]);
    return sqrt(d2);
}
