/* fracture_model2: the second fracture model (see fracture.h), written apart from fracture.c's so
 * that a benchmark does not tune the fit to one generator: another cut surface, another way of
 * moving the piece into the CT, and noise. */
#include "fracture.h"
#include "fracture_impl.h"

#include "err.h"
#include "frag.h"
#include "seg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The cut: a bent sheet through point (normal n, tangents t1, t2), curvatures k1, k2 along the
 * tangents, a zig-zag (triangle wave) of amplitude amp along t1 (period len) and half that along
 * t2 (period 0.6 len), and three sinusoids of 0.3 amp and wavelength len/3 in random directions. */
struct sheet {
    double point[3], n[3], t1[3], t2[3], k1, k2, amp, len, phase[2];
    double wave[3][3], wave_phase[3];
};

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void unit3(uint64_t *rng, double u[3])
{
    double r2;
    do {
        for (int a = 0; a < 3; a++)
            u[a] = 2 * fracture_rng_uniform(rng) - 1;
        r2 = dot3(u, u);
    } while (r2 < 1e-4 || r2 > 1);
    for (int a = 0; a < 3; a++)
        u[a] /= sqrt(r2);
}

/* In [-1, 1], period 1. */
static double zigzag(double x)
{
    return 4 * fabs(x - floor(x + 0.5)) - 1;
}

/* > 0 on the new piece's side of the sheet. */
static double sheet_side(const struct sheet *s, const double x[3])
{
    double r[3] = {x[0] - s->point[0], x[1] - s->point[1], x[2] - s->point[2]};
    double u = dot3(r, s->t1), v = dot3(r, s->t2), h = dot3(r, s->n);
    double relief = s->amp * (zigzag(u / s->len + s->phase[0]) + 0.5 * zigzag(v / (0.6 * s->len) + s->phase[1]));
    for (int w = 0; w < 3; w++)
        relief += 0.3 * s->amp * sin(2 * M_PI * 3 * dot3(r, s->wave[w]) / s->len + s->wave_phase[w]);
    return h - 0.5 * (s->k1 * u * u + s->k2 * v * v) - relief;
}

static void sheet_draw(uint64_t *rng, const frag *bone, const fracture_params *p, struct sheet *s)
{
    double len = sqrt(bone->eigval[0]), off = (2 * fracture_rng_uniform(rng) - 1) * 0.4 * len;
    double tilt1 = (2 * fracture_rng_uniform(rng) - 1) * 0.6, tilt2 = (2 * fracture_rng_uniform(rng) - 1) * 0.6;
    for (int a = 0; a < 3; a++) {
        s->n[a] = bone->axes[a][0] + tilt1 * bone->axes[a][1] + tilt2 * bone->axes[a][2];
        s->point[a] = bone->centroid[a] + off * bone->axes[a][0];
    }
    double nn = sqrt(dot3(s->n, s->n)), a1[3] = {bone->axes[0][1], bone->axes[1][1], bone->axes[2][1]};
    for (int a = 0; a < 3; a++)
        s->n[a] /= nn;
    double d = dot3(a1, s->n); /* t1: the second axis made normal to n; t2 = n x t1 */
    for (int a = 0; a < 3; a++)
        s->t1[a] = a1[a] - d * s->n[a];
    double n1 = sqrt(dot3(s->t1, s->t1));
    for (int a = 0; a < 3; a++)
        s->t1[a] /= n1;
    s->t2[0] = s->n[1] * s->t1[2] - s->n[2] * s->t1[1];
    s->t2[1] = s->n[2] * s->t1[0] - s->n[0] * s->t1[2];
    s->t2[2] = s->n[0] * s->t1[1] - s->n[1] * s->t1[0];
    s->k1 = (2 * fracture_rng_uniform(rng) - 1) / (3 * len);
    s->k2 = (2 * fracture_rng_uniform(rng) - 1) / (3 * len);
    s->amp = p->roughness_mm;
    s->len = p->wavelength_mm;
    s->phase[0] = fracture_rng_uniform(rng);
    s->phase[1] = fracture_rng_uniform(rng);
    for (int w = 0; w < 3; w++) {
        unit3(rng, s->wave[w]);
        s->wave_phase[w] = 2 * M_PI * fracture_rng_uniform(rng);
    }
}

/* Keeps the largest 26-connected component of the voxels of lab equal to `keep` and gives the
 * rest `to`; the count kept, or FN_ENOMEM. */
static long keep_largest(vol *lab, float keep, float to)
{
    size_t n = vol_count(lab);
    uint8_t *mask = malloc(n);
    int32_t *comp = malloc(n * sizeof *comp);
    long rc = mask && comp ? 0 : fn_err_set(FN_ENOMEM, "out of memory");
    int nc = 0;
    if (rc == 0) {
        for (size_t i = 0; i < n; i++)
            mask[i] = lab->data[i] == keep;
        rc = nc = seg_components(mask, lab->dim, comp);
    }
    size_t *size = rc >= 0 ? calloc((size_t)nc + 1, sizeof *size) : NULL;
    if (rc >= 0 && !size)
        rc = fn_err_set(FN_ENOMEM, "out of memory");
    if (size) {
        for (size_t i = 0; i < n; i++)
            size[comp[i]]++;
        int big = 1;
        for (int c = 2; c <= nc; c++)
            big = size[c] > size[big] ? c : big;
        for (size_t i = 0; i < n; i++)
            if (comp[i] && comp[i] != big)
                lab->data[i] = to;
        rc = nc ? (long)size[big] : 0;
    }
    free(size);
    free(mask);
    free(comp);
    return rc;
}

/* Cuts the bone (is_bone) into cut's 1 and 2, 2 the smaller side, each one piece of at least
 * min_piece voxels: islands of the new piece join piece 1; islands of piece 1 are left out of
 * both (crumbs: label 0, still bone in the CT). normal: the sheet's, toward piece 2. */
static int model2_cut(vol *cut, const uint8_t *is_bone, uint64_t *rng, const frag *bone, const fracture_params *p,
                      size_t min_piece, double normal[3])
{
    size_t n = vol_count(cut);
    for (int attempt = 0; attempt < 32; attempt++) {
        struct sheet s;
        sheet_draw(rng, bone, p, &s);
        size_t side[3] = {0};
        for (int k = 0; k < cut->dim[2]; k++)
            for (int j = 0; j < cut->dim[1]; j++)
                for (int i = 0; i < cut->dim[0]; i++) {
                    size_t v = vol_idx(cut, i, j, k);
                    double ijk[3] = {i, j, k}, w[3];
                    if (!is_bone[v]) {
                        cut->data[v] = 0;
                        continue;
                    }
                    vol_index_to_world(cut, ijk, w);
                    cut->data[v] = sheet_side(&s, w) > 0 ? 2 : 1;
                    side[(int)cut->data[v]]++;
                }
        for (int a = 0; a < 3; a++) /* toward the new piece */
            normal[a] = side[2] > side[1] ? -s.n[a] : s.n[a];
        if (side[2] > side[1])
            for (size_t v = 0; v < n; v++)
                cut->data[v] = cut->data[v] != 0 ? 3 - cut->data[v] : 0;
        long moved = keep_largest(cut, 2, 1), stays = moved >= 0 ? keep_largest(cut, 1, 0) : moved;
        if (stays < 0)
            return (int)stays;
        if ((size_t)moved >= min_piece && (size_t)stays >= min_piece)
            return 0;
    }
    return fn_err_set(FN_EINVAL, "model 2: no cut leaves both pieces at least %zu voxels in 32 "
                      "tries: the bone is too thin or irregular", min_piece);
}

/* Piece 2's voxel centres (in its box lo..hi) carried by m onto the input grid (nearest): 1 when
 * one lands on piece 1 or on bright non-bone (obstacle), else 0. Past the grid there is nothing. */
static int lands_badly(const vol *cut, const uint8_t *obstacle, const pose *m, const int lo[3], const int hi[3])
{
    for (int k = lo[2]; k <= hi[2]; k++)
        for (int j = lo[1]; j <= hi[1]; j++)
            for (int i = lo[0]; i <= hi[0]; i++) {
                if (cut->data[vol_idx(cut, i, j, k)] != 2)
                    continue;
                double ijk[3] = {i, j, k}, w[3], mw[3], o[3];
                vol_index_to_world(cut, ijk, w);
                pose_apply(m, w, mw);
                vol_world_to_index(cut, mw, o);
                int q[3], inside = 1;
                for (int a = 0; a < 3; a++) {
                    q[a] = (int)floor(o[a] + 0.5);
                    inside &= q[a] >= 0 && q[a] < cut->dim[a];
                }
                if (!inside)
                    continue;
                size_t v = vol_idx(cut, q[0], q[1], q[2]);
                if (cut->data[v] == 1 || obstacle[v])
                    return 1;
            }
    return 0;
}

/* Piece 2's move: turned by rotate_deg about its centroid, moved displace_mm away from piece 1
 * across the cut (normal, perturbed), then on in steps of one voxel until it lands clear
 * (lands_badly); another draw when it does not within a bone's length; 0 or FN_EINVAL. */
static int model2_motion(const vol *cut, const uint8_t *obstacle, uint64_t *rng, const frag *bone,
                         const double normal[3], const fracture_params *p, pose *m)
{
    frag f;
    int lo[3], hi[3], rc = frag_label_box(cut, 2, lo, hi);
    if (rc == 0)
        rc = frag_from_labels(&f, cut, NULL, 2, lo, hi, 0, 0);
    if (rc < 0)
        return rc;
    double step = fmin(cut->spacing[0], fmin(cut->spacing[1], cut->spacing[2]));
    int max_steps = (int)ceil(4 * sqrt(bone->eigval[0]) / step);
    for (int attempt = 0; attempt < 8; attempt++) {
        double axis[3], pert[3], out[3], rc_[3];
        unit3(rng, axis);
        unit3(rng, pert);
        for (int a = 0; a < 3; a++)
            out[a] = normal[a] + 0.5 * pert[a];
        double d = sqrt(dot3(out, out));
        *m = pose_from_axis_angle(axis, p->rotate_deg * M_PI / 180);
        pose_rotate(m, f.centroid, rc_);
        for (int a = 0; a < 3; a++) {
            out[a] /= d;
            m->t[a] = f.centroid[a] - rc_[a] + p->displace_mm * out[a];
        }
        for (int s = 0; s <= max_steps; s++) {
            if (!lands_badly(cut, obstacle, m, lo, hi)) {
                frag_free(&f);
                return 0;
            }
            for (int a = 0; a < 3; a++)
                m->t[a] += step * out[a];
        }
    }
    frag_free(&f);
    return fn_err_set(FN_EINVAL, "model 2: the moved piece found no clear place in 8 draws");
}

/* Piece 2 of cut (values from src) carried by m into out_ct/out_lab: each output voxel takes the
 * trilinear weights of the eight source voxels around its preimage; o, the weight that falls on
 * piece 2, mixes the piece's value with what is there (partial volume at every edge of the piece,
 * the fracture's included), and the voxel is labelled 2 where o >= 0.5. */
static void model2_resample(const vol *cut, const vol *src, const pose *m, vol *out_ct, vol *out_lab)
{
    int olo[3], ohi[3];
    fracture__moved_box(cut, 2, *m, out_ct, 2, olo, ohi);
    for (int a = 0; a < 3; a++) {
        olo[a] = olo[a] < 0 ? 0 : olo[a];
        ohi[a] = ohi[a] > out_ct->dim[a] - 1 ? out_ct->dim[a] - 1 : ohi[a];
    }
    pose inv = pose_inverse(*m);
    for (int k = olo[2]; k <= ohi[2]; k++)
        for (int j = olo[1]; j <= ohi[1]; j++)
            for (int i = olo[0]; i <= ohi[0]; i++) {
                double ijk[3] = {i, j, k}, y[3], x[3], s[3];
                vol_index_to_world(out_ct, ijk, y);
                pose_apply(&inv, y, x);
                vol_world_to_index(cut, x, s);
                int c[3];
                double f[3], occ = 0, val = 0;
                for (int a = 0; a < 3; a++) {
                    c[a] = (int)floor(s[a]);
                    f[a] = s[a] - c[a];
                }
                for (int corner = 0; corner < 8; corner++) {
                    int q[3] = {c[0] + (corner & 1), c[1] + (corner >> 1 & 1), c[2] + (corner >> 2)};
                    if (q[0] < 0 || q[1] < 0 || q[2] < 0 || q[0] >= cut->dim[0] || q[1] >= cut->dim[1] ||
                        q[2] >= cut->dim[2])
                        continue;
                    size_t v = vol_idx(cut, q[0], q[1], q[2]);
                    if (cut->data[v] != 2)
                        continue;
                    double w = (corner & 1 ? f[0] : 1 - f[0]) * (corner & 2 ? f[1] : 1 - f[1]) *
                               (corner & 4 ? f[2] : 1 - f[2]);
                    occ += w;
                    val += w * src->data[v];
                }
                if (occ <= 0)
                    continue;
                size_t v = vol_idx(out_ct, i, j, k);
                out_ct->data[v] = (float)(val + (1 - occ) * out_ct->data[v]);
                if (occ >= 0.5 && out_lab->data[v] == 0)
                    out_lab->data[v] = 2;
            }
}

/* Gaussian noise of standard deviation sd on every voxel (the sum of four uniforms, scaled). */
static void add_noise(vol *v, double sd, uint64_t *rng)
{
    if (sd <= 0)
        return;
    for (size_t i = 0; i < vol_count(v); i++) {
        double g = 0;
        for (int r = 0; r < 4; r++)
            g += fracture_rng_uniform(rng);
        v->data[i] += (float)((g - 2) * sd * 1.7320508075688772); /* the sum's SD is sqrt(1/3) */
    }
}

int fracture_model2(const vol *ct, const fracture_params *p, fracture_result *out)
{
    memset(out, 0, sizeof *out);
    int rc = fracture_check(p);
    if (rc < 0)
        return rc;
    if (p->pieces != 2 || p->touching || p->bone_loss_mm > 0)
        return fn_err_set(FN_EINVAL, "fracture model 2 makes two pieces, apart, with no bone lost "
                          "(not --pieces %d%s%s)", p->pieces, p->touching ? ", --touching" : "",
                          p->bone_loss_mm > 0 ? ", --bone-loss" : "");
    seg_result seg;
    if ((rc = fracture__bone(ct, p, &seg)) < 0)
        return rc;
    out->threshold = seg.threshold;
    out->cut = seg.labels;
    seg.labels = NULL;
    int ncomp = seg.ncomp;
    seg_result_free(&seg);
    size_t n = vol_count(ct);
    uint8_t *is_bone = malloc(n), *obstacle = malloc(n);
    frag bone = {0};
    int lo[3], hi[3];
    if (ncomp < 1)
        rc = fn_err_set(FN_EINVAL, "model 2: no bone at or above %g", out->threshold);
    else if (!is_bone || !obstacle)
        rc = fn_err_set(FN_ENOMEM, "out of memory");
    else if ((rc = frag_label_box(out->cut, 1, lo, hi)) == 0)
        rc = frag_from_labels(&bone, out->cut, NULL, 1, lo, hi, 0, 0);
    uint64_t rng = p->seed ^ 0x6d6f64656c320000ull; /* not model 1's sequence for the same seed */
    pose m = POSE_IDENTITY;
    double normal[3];
    if (rc == 0) {
        for (size_t i = 0; i < n; i++) {
            is_bone[i] = out->cut->data[i] != 0;
            obstacle[i] = !is_bone[i] && isfinite(ct->data[i]) && ct->data[i] >= out->threshold;
        }
        rc = model2_cut(out->cut, is_bone, &rng, &bone, p, fracture_min_piece(bone.voxels, 2), normal);
    }
    if (rc == 0)
        rc = model2_motion(out->cut, obstacle, &rng, &bone, normal, p, &m);
    out->pieces = 2;
    int grow_lo[3] = {0, 0, 0}, grow_hi[3] = {0, 0, 0};
    if (rc == 0) { /* where the piece lands past the grid's edge, the grid grows to hold it */
        int olo[3], ohi[3];
        fracture__moved_box(out->cut, 2, m, ct, 2, olo, ohi);
        for (int a = 0; a < 3; a++) {
            grow_lo[a] = olo[a] < 0 ? -olo[a] : 0;
            grow_hi[a] = ohi[a] >= ct->dim[a] ? ohi[a] - ct->dim[a] + 1 : 0;
        }
    }
    float lowest, highest;
    vol_range(ct, &lowest, &highest);
    out->ct = rc == 0 ? fracture__padded(ct, grow_lo, grow_hi, lowest) : NULL;
    out->labels = out->ct ? fracture__padded(out->cut, grow_lo, grow_hi, 0) : NULL;
    out->truth = calloc(2, sizeof *out->truth);
    out->moved = calloc(2, sizeof *out->moved);
    if (rc == 0 && (!out->labels || !out->truth || !out->moved))
        rc = fn_err_set(FN_ENOMEM, "out of memory");
    if (rc == 0) {
        for (int k = 0; k < ct->dim[2]; k++)
            for (int j = 0; j < ct->dim[1]; j++)
                for (int i = 0; i < ct->dim[0]; i++)
                    if (out->cut->data[vol_idx(ct, i, j, k)] == 2) {
                        size_t o = vol_idx(out->ct, i + grow_lo[0], j + grow_lo[1], k + grow_lo[2]);
                        out->ct->data[o] = (float)p->fill;
                        out->labels->data[o] = 0;
                    }
        model2_resample(out->cut, ct, &m, out->ct, out->labels);
        add_noise(out->ct, p->noise_hu, &rng);
        out->truth[0] = out->moved[0] = POSE_IDENTITY;
        out->moved[1] = m;
        out->truth[1] = pose_inverse(m);
    }
    frag_free(&bone);
    free(is_bone);
    free(obstacle);
    if (rc < 0)
        fracture_result_free(out);
    return rc;
}
