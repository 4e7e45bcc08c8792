#include "fracture.h"

#include "case.h"
#include "err.h"
#include "frag.h"
#include "seg.h"
#include "volio.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

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

/* Voxels of label `from` on the positive side of the cut: counted, or relabelled `to` when
 * apply (then bone within loss/2 of the surface becomes background and `fill` in ct). */
static size_t cut_apply(vol *lab, vol *ct, int from, int to, const struct cut *c, const int lo[3],
                        const int hi[3], double loss, double fill, int apply)
{
    size_t n = 0;
    for (int k = lo[2]; k <= hi[2]; k++)
        for (int j = lo[1]; j <= hi[1]; j++)
            for (int i = lo[0]; i <= hi[0]; i++) {
                size_t idx = vol_idx(lab, i, j, k);
                if (lab->data[idx] != (float)from)
                    continue;
                double ijk[3] = {i, j, k}, x[3];
                vol_index_to_world(lab, ijk, x);
                double s = cut_side(c, x);
                if (s > 0)
                    n++;
                if (!apply)
                    continue;
                if (s > -loss / 2 && s <= loss / 2 && loss > 0) {
                    lab->data[idx] = 0;
                    ct->data[idx] = (float)fill;
                } else if (s > 0) {
                    lab->data[idx] = (float)to;
                }
            }
    return n;
}

static int piece_stats(const vol *lab, int id, frag *f)
{
    int lo[3], hi[3];
    if (frag_label_box(lab, id, lo, hi) < 0)
        return fn_err_set(FN_EINVAL, "fracture: piece %d is empty", id);
    return frag_from_labels(f, lab, NULL, id, lo, hi, 0, 0);
}

/* Splits the largest piece so far with a random rough cut; its smaller side becomes piece `to`. */
static int make_cut(vol *lab, vol *ct, int to, uint64_t *rng, const fracture_params *p,
                    double normal_out[3])
{
    int from = 1;
    size_t best = 0;
    for (int id = 1; id < to; id++) {
        frag f;
        if (piece_stats(lab, id, &f) < 0)
            continue;
        if (f.voxels > best) {
            best = f.voxels;
            from = id;
        }
        frag_free(&f);
    }
    frag f;
    int rc = piece_stats(lab, from, &f);
    if (rc < 0)
        return rc;
    int lo[3], hi[3];
    frag_label_box(lab, from, lo, hi);
    for (int attempt = 0; attempt < 32; attempt++) {
        struct cut c = {.rough = p->roughness_mm, .wavelength = p->wavelength_mm};
        double u1 = fracture_rng_uniform(rng) * 2 - 1, u2 = fracture_rng_uniform(rng) * 2 - 1;
        double off = (fracture_rng_uniform(rng) * 2 - 1) * 0.6 * sqrt(f.eigval[0]);
        c.noise_seed = fracture_rng_next(rng);
        for (int a = 0; a < 3; a++) {
            c.normal[a] = f.axes[a][0] + 0.5 * (u1 * f.axes[a][1] + u2 * f.axes[a][2]);
            c.point[a] = f.centroid[a] + off * f.axes[a][0];
        }
        normalize3(c.normal);
        size_t pos = cut_apply(lab, ct, from, to, &c, lo, hi, 0, 0, 0);
        if (pos * 2 > f.voxels) {
            /* The new piece is always the smaller side. */
            for (int a = 0; a < 3; a++)
                c.normal[a] = -c.normal[a];
            c.rough = -c.rough;
            pos = f.voxels - pos;
        }
        if (pos < f.voxels / 10)
            continue;
        cut_apply(lab, ct, from, to, &c, lo, hi, p->bone_loss_mm, p->fill, 1);
        memcpy(normal_out, c.normal, sizeof c.normal);
        frag_free(&f);
        return 0;
    }
    frag_free(&f);
    return fn_err_set(FN_EINVAL, "fracture: no cut of piece %d leaves both sides over 10%% of it "
                                 "(bone too small or thin?)", from);
}

/* The random rigid motion of a piece: rotation about its centroid, translation away from the
 * fixed bone (along `out`, perturbed). */
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
        m.t[a] = centroid[a] - rc[a] + p->displace_mm * dir[a];
    return m;
}

/* Resamples piece `id` of cut (on the original grid) moved by m into out_lab/out_ct (nearest
 * neighbour). Counts voxels that would land on another piece or on a bright object that is not
 * bone (the head holder: >= threshold in src_ct but in no piece); writes only when apply, and
 * without apply stops at the first such voxel (returns 1). */
static size_t place_piece(const vol *cut, const vol *src_ct, vol *out_lab, vol *out_ct, int id,
                          pose m, double threshold, int apply)
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
    int olo[3], ohi[3];
    for (int a = 0; a < 3; a++) {
        olo[a] = (int)fmax(0, floor(blo[a]) - 1);
        ohi[a] = (int)fmin(out_lab->dim[a] - 1, ceil(bhi[a]) + 1);
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
                int other = out_lab->data[to] != 0 && out_lab->data[to] != (float)id;
                if (other || (cut->data[to] == 0 && src_ct->data[to] >= threshold)) {
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

static vol *vol_clone(const vol *v)
{
    vol *c = vol_new(v->dim[0], v->dim[1], v->dim[2]);
    if (!c)
        return NULL;
    memcpy(c->data, v->data, vol_count(v) * sizeof(float));
    memcpy(c->affine, v->affine, sizeof v->affine);
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
    } rows[] = {{"pieces", p->pieces, 2, 16, ""},
                {"displace", p->displace_mm, 0, 200, " mm"},
                {"rotate", p->rotate_deg, 0, 180, " deg"},
                {"bone loss", p->bone_loss_mm, 0, 20, " mm"},
                {"roughness", p->roughness_mm, 0, 50, " mm"},
                {"wavelength", p->wavelength_mm, 0.5, 1000, " mm"}};
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++)
        if (!(rows[i].value >= rows[i].lo && rows[i].value <= rows[i].hi))
            return fn_err_set(FN_EINVAL, "%s must be %g..%g%s (got %g)", rows[i].name, rows[i].lo,
                              rows[i].hi, rows[i].unit, rows[i].value);
    if (!isfinite(p->threshold) || !isfinite(p->fill))
        return fn_err_set(FN_EINVAL, "fracture threshold and fill must be finite");
    return 0;
}

/* Moves pieces 2..n, pushing each out along its cut normal until it lands on no other piece. */
static int displace_pieces(fracture_result *r, const vol *ct, uint64_t *rng,
                           const fracture_params *p, double (*normals)[3])
{
    size_t n = vol_count(ct);
    for (size_t i = 0; i < n; i++) {
        r->labels->data[i] = r->cut->data[i] == 1 ? 1 : 0;
        if (r->cut->data[i] > 1)
            r->ct->data[i] = (float)p->fill;
    }
    r->truth[0] = r->moved[0] = POSE_IDENTITY;
    for (int id = 2; id <= r->pieces; id++) {
        frag f;
        int rc = piece_stats(r->cut, id, &f);
        if (rc < 0)
            return rc;
        double dir[3];
        pose m = random_motion(rng, f.centroid, normals[id - 2], p, dir);
        frag_free(&f);
        int push = 0;
        while (place_piece(r->cut, ct, r->labels, r->ct, id, m, p->threshold, 0) > 0) {
            if (++push > 100)
                return fn_err_set(FN_EINVAL, "fracture: piece %d cannot be placed clear of the "
                                             "others", id);
            for (int a = 0; a < 3; a++)
                m.t[a] += normals[id - 2][a];
        }
        place_piece(r->cut, ct, r->labels, r->ct, id, m, p->threshold, 1);
        r->moved[id - 1] = m;
        r->truth[id - 1] = pose_inverse(m);
    }
    return 0;
}

int fracture_make(const vol *ct, const fracture_params *p, fracture_result *out)
{
    memset(out, 0, sizeof *out);
    int rc = fracture_check(p);
    if (rc < 0)
        return rc;
    seg_params sp;
    seg_defaults(&sp);
    sp.threshold = p->threshold;
    sp.min_volume_ml = 0;
    sp.keep = 1;
    seg_result seg;
    rc = seg_run(ct, &sp, &seg);
    if (rc < 0)
        return rc;
    if (seg.ncomp < 1) {
        seg_result_free(&seg);
        return fn_err_set(FN_EINVAL, "fracture: no bone at or above %g", p->threshold);
    }
    out->cut = seg.labels;
    seg.labels = NULL;
    seg_result_free(&seg);
    out->pieces = p->pieces;
    out->ct = vol_clone(ct);
    vol *work_ct = vol_clone(ct);
    out->labels = vol_clone(out->cut);
    out->truth = calloc((size_t)p->pieces, sizeof *out->truth);
    out->moved = calloc((size_t)p->pieces, sizeof *out->moved);
    double(*normals)[3] = calloc((size_t)p->pieces, sizeof *normals);
    if (!out->ct || !work_ct || !out->labels || !out->truth || !out->moved || !normals) {
        rc = fn_err_set(FN_ENOMEM, "fracture: out of memory");
        goto done;
    }
    uint64_t rng = p->seed;
    for (int id = 2; id <= p->pieces && rc == 0; id++)
        rc = make_cut(out->cut, work_ct, id, &rng, p, normals[id - 2]);
    if (rc == 0) {
        /* The output starts from the CT after bone loss. */
        memcpy(out->ct->data, work_ct->data, vol_count(ct) * sizeof(float));
        rc = displace_pieces(out, work_ct, &rng, p, normals);
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

fcase *fracture_make_case(const vol *ct, const fracture_params *p, const char *dir)
{
    fracture_result r;
    if (fracture_make(ct, p, &r) < 0)
        return NULL;
    char src[4200];
    snprintf(src, sizeof src, "%s/source.nii.gz", dir);
    vol_type t = ct->src_type == VOL_F64 ? VOL_F32 : ct->src_type;
    fcase *c = NULL;
    if (mkdir(dir, 0755) != 0 && errno != EEXIST)
        fn_err_set(FN_EIO, "%s: cannot create the case folder: %s", dir, strerror(errno));
    else if (volio_write(r.ct, src, t) == 0) {
        seg_params sp;
        seg_defaults(&sp);
        sp.threshold = p->threshold;
        sp.min_volume_ml = 0;
        c = case_create(dir, src, r.ct, r.labels, &sp);
        r.ct = r.labels = NULL;
    }
    if (c) {
        /* Fragment ids are piece numbers; a piece pushed off the grid entirely has no fragment. */
        c->has_truth = 1;
        for (int i = 0; i < c->nfrag; i++)
            c->truth[i] = r.truth[c->frag[i].id - 1];
        c->fixed = case_find(c, 1);
        c->tau_min = p->tau_min;
        c->tau_max = p->tau_max;
        if (case_save(c) < 0) {
            case_free(c);
            c = NULL;
        }
    }
    fracture_result_free(&r);
    return c;
}
