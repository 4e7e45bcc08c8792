/* Synthetic fractures: ground truth restores the moved pieces, the surface is rough, bone loss
 * opens a gap, and one seed gives one case, byte for byte. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "err.h"
#include "frag.h"
#include "fracture.h"
#include "morph.h"
#include "seg.h"
#include "testutil.h"
#include "volio.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A textured ellipsoidal "bone" (semi-axes 24, 15, 13 mm) on an oblique, left-handed 1 mm grid. */
static vol *bone(void)
{
    vol *v = vol_new(64, 44, 40);
    double c = 0.96, s = 0.28;
    const double dir[3][3] = {{c, 0, s}, {0, -1, 0}, {-s, 0, c}};
    double sp[3] = {1, 1, 1}, org[3] = {-30, 20, 5};
    vol_set_geometry(v, dir, sp, org);
    for (int k = 0; k < 40; k++)
        for (int j = 0; j < 44; j++)
            for (int i = 0; i < 64; i++) {
                double x = (i - 31.5) / 24, y = (j - 21.5) / 15, z = (k - 19.5) / 13;
                int in = x * x + y * y + z * z <= 1;
                v->data[vol_idx(v, i, j, k)] = in ? (float)(700 + (i * 7 + j * 13 + k * 3) % 400) : -50;
            }
    v->src_type = VOL_I16;
    return v;
}

static size_t count_label(const vol *l, int id)
{
    size_t n = 0;
    for (size_t i = 0; i < vol_count(l); i++)
        n += l->data[i] == (float)id;
    return n;
}

/* The voxel of v nearest world point x (asserting that x is within half a voxel of its centre,
 * inside v's grid). */
static size_t nearest_voxel(const vol *v, const double x[3])
{
    double s[3];
    int si[3];
    vol_world_to_index(v, x, s);
    for (int a = 0; a < 3; a++) {
        si[a] = (int)floor(s[a] + 0.5);
        assert_true(fabs(s[a] - si[a]) <= 0.5 + 1e-9);
        assert_true(si[a] >= 0 && si[a] < v->dim[a]);
    }
    return vol_idx(v, si[0], si[1], si[2]);
}

/* Every displaced voxel of a moved piece, sent through its truth, lands on that piece in the cut
 * (nearest voxel, so exactly) and carries the original CT value there. The output grid may have
 * grown past ct's (the cut's). */
static void check_truth(const vol *ct, const fracture_result *r)
{
    size_t idx = 0, checked = 0;
    const vol *l = r->labels;
    for (int k = 0; k < l->dim[2]; k++)
        for (int j = 0; j < l->dim[1]; j++)
            for (int i = 0; i < l->dim[0]; i++, idx++) {
                int id = (int)l->data[idx];
                if (id < 1)
                    continue;
                double y[3], x[3], ijk[3] = {i, j, k};
                vol_index_to_world(l, ijk, y);
                pose_apply(&r->truth[id - 1], y, x);
                assert_true(r->cut->data[nearest_voxel(r->cut, x)] == (float)id);
                assert_true(r->ct->data[idx] == ct->data[nearest_voxel(ct, x)]);
                checked++;
            }
    assert_true(checked > 1000);
}

static void test_truth_restores_pieces(void **st)
{
    vol *ct = bone();
    fracture_params p;
    fracture_defaults(&p);
    p.seed = 42;
    p.pieces = 3;
    p.displace_mm = 4;
    p.rotate_deg = 5;
    fracture_result r;
    if (fracture_make(ct, &p, &r) < 0)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(r.pieces, 3);
    check_truth(ct, &r);
    for (int id = 1; id <= 3; id++) {
        size_t before = count_label(r.cut, id), after = count_label(r.labels, id);
        assert_true(before > 1000);
        /* Nearest-neighbour resampling keeps the piece's size within a few percent. */
        assert_true(fabs((double)after - (double)before) < 0.05 * (double)before);
    }
    assert_true(pose_angle_between(r.truth[0], POSE_IDENTITY) == 0);
    for (int id = 2; id <= 3; id++)
        assert_true(fabs(pose_angle_between(r.truth[id - 1], POSE_IDENTITY) - 5 * M_PI / 180) < 1e-9);
    /* Where a moved piece was and nothing landed, the fill value (soft tissue) is written. */
    size_t filled = 0;
    for (size_t i = 0; i < vol_count(ct); i++)
        filled += r.cut->data[i] > 1 && r.labels->data[i] == 0 && r.ct->data[i] == 40;
    assert_true(filled > 0);
    fracture_result_free(&r);
    vol_free(ct);
}

/* --touching: the moved pieces stay in contact (the threshold joins them into one component), the
 * truth still restores them, and separate (morph) splits them back, each piece matched with Dice
 * >= 0.85. */
static void test_touching_pieces_separate(void **st)
{
    vol *ct = bone();
    fracture_params p;
    fracture_defaults(&p);
    p.seed = 7;
    p.pieces = 2;
    p.rotate_deg = 4;
    p.touching = 1;
    fracture_result r;
    if (fracture_make(ct, &p, &r) < 0)
        fail_msg("%s", fn_err_msg());
    check_truth(ct, &r);
    size_t n = vol_count(r.ct);
    uint8_t *mask = malloc(n);
    int32_t *lab = malloc(n * sizeof *lab);
    assert_non_null(mask);
    assert_non_null(lab);
    for (size_t i = 0; i < n; i++)
        mask[i] = r.ct->data[i] >= r.threshold;
    assert_int_equal(seg_components(mask, r.ct->dim, lab), 1);
    int pieces = morph_separate(mask, r.ct->dim, r.ct->spacing, 0, NULL, 0, 8, lab, NULL);
    assert_int_equal(pieces, 2);
    for (int id = 1; id <= 2; id++) {
        double best = 0;
        for (int q = 1; q <= pieces; q++) {
            size_t both = 0, nt = 0, np = 0;
            for (size_t i = 0; i < n; i++) {
                nt += r.labels->data[i] == (float)id;
                np += lab[i] == q;
                both += r.labels->data[i] == (float)id && lab[i] == q;
            }
            best = fmax(best, 2.0 * (double)both / (double)(nt + np));
        }
        if (!(best >= 0.85))
            fail_msg("piece %d: best Dice %.3f", id, best);
    }
    free(mask);
    free(lab);
    fracture_result_free(&r);
    vol_free(ct);
}

/* RMS distance of the interface voxels of piece 2 (touching piece 1) from their best plane. */
static double interface_rms(const vol *cut)
{
    double s1[3] = {0}, s2[3][3] = {{0}};
    size_t n = 0;
    for (int k = 1; k < cut->dim[2] - 1; k++)
        for (int j = 1; j < cut->dim[1] - 1; j++)
            for (int i = 1; i < cut->dim[0] - 1; i++) {
                if (cut->data[vol_idx(cut, i, j, k)] != 2)
                    continue;
                int touch = cut->data[vol_idx(cut, i - 1, j, k)] == 1 ||
                            cut->data[vol_idx(cut, i + 1, j, k)] == 1 ||
                            cut->data[vol_idx(cut, i, j - 1, k)] == 1 ||
                            cut->data[vol_idx(cut, i, j + 1, k)] == 1 ||
                            cut->data[vol_idx(cut, i, j, k - 1)] == 1 ||
                            cut->data[vol_idx(cut, i, j, k + 1)] == 1;
                if (!touch)
                    continue;
                double ijk[3] = {i, j, k}, w[3];
                vol_index_to_world(cut, ijk, w);
                n++;
                for (int a = 0; a < 3; a++) {
                    s1[a] += w[a];
                    for (int b = 0; b < 3; b++)
                        s2[a][b] += w[a] * w[b];
                }
            }
    assert_true(n > 100);
    double cov[3][3], vec[3][3], val[3];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            cov[a][b] = s2[a][b] / n - s1[a] / n * s1[b] / n;
    frag_eigen_sym3(cov, vec, val);
    return sqrt(val[2]);
}

static void test_surface_is_rough(void **st)
{
    vol *ct = bone();
    fracture_params p;
    fracture_defaults(&p);
    p.seed = 5;
    fracture_result r;
    assert_int_equal(fracture_make(ct, &p, &r), 0);
    double rough = interface_rms(r.cut);
    fracture_result_free(&r);
    p.roughness_mm = 0;
    assert_int_equal(fracture_make(ct, &p, &r), 0);
    double flat = interface_rms(r.cut);
    fracture_result_free(&r);
    /* A planar cut's voxelised interface deviates well under a voxel; the rough one by far more. */
    if (!(flat < 0.6 && rough > 1.0 && rough > 2 * flat))
        fail_msg("interface RMS: rough %.3f mm, flat %.3f mm", rough, flat);
    vol_free(ct);
}

static void test_bone_loss_opens_a_gap(void **st)
{
    vol *ct = bone();
    fracture_params p;
    fracture_defaults(&p);
    p.seed = 9;
    p.bone_loss_mm = 2;
    fracture_result r;
    assert_int_equal(fracture_make(ct, &p, &r), 0);
    size_t bone_voxels = 0, cut_voxels = 0;
    for (size_t i = 0; i < vol_count(ct); i++) {
        bone_voxels += ct->data[i] >= 300;
        cut_voxels += r.cut->data[i] > 0;
    }
    assert_true(cut_voxels < bone_voxels - 200);
    /* No voxel of one piece touches the other through a face. */
    for (int k = 0; k < ct->dim[2]; k++)
        for (int j = 0; j < ct->dim[1]; j++)
            for (int i = 0; i + 1 < ct->dim[0]; i++) {
                float a = r.cut->data[vol_idx(ct, i, j, k)], b = r.cut->data[vol_idx(ct, i + 1, j, k)];
                assert_false(a > 0 && b > 0 && a != b);
            }
    check_truth(ct, &r);
    fracture_result_free(&r);
    vol_free(ct);
}

static void test_same_seed_same_case(void **st)
{
    /* splitmix64's published first output for state 0. */
    uint64_t s = 0;
    assert_true(fracture_rng_next(&s) == 0xe220a8397b1dcdafull);
    char *dir = tu_tmpdir("fracture"), src[4200];
    snprintf(src, sizeof src, "%s/bone.nii.gz", dir);
    vol *ct = bone();
    if (volio_write(ct, src, VOL_I16) < 0)
        fail_msg("%s", fn_err_msg());
    vol_free(ct);
    char *out;
    const char *runs[3][2] = {{"a", "11"}, {"b", "11"}, {"c", "12"}};
    for (int i = 0; i < 3; i++) {
        int rc = tu_run_cli(&out, "fracture '%s' -o '%s/%s' --seed %s --bone-loss 1", src, dir,
                            runs[i][0], runs[i][1]);
        if (rc != 0)
            fail_msg("fracture failed (%d): %s", rc, out);
        free(out);
    }
    char pa[4300], pb[4300], pc[4300];
    size_t na, nb, nc;
    snprintf(pa, sizeof pa, "%s/a/case.json", dir);
    snprintf(pb, sizeof pb, "%s/b/case.json", dir);
    snprintf(pc, sizeof pc, "%s/c/case.json", dir);
    char *ja = tu_slurp(pa, &na), *jb = tu_slurp(pb, &nb), *jc = tu_slurp(pc, &nc);
    assert_true(na == nb && !memcmp(ja, jb, na));
    assert_false(na == nc && !memcmp(ja, jc, na));
    /* The case loads, the fixed fragment is 1, and truth is stored per fragment. */
    snprintf(pa, sizeof pa, "%s/a", dir);
    planning_case *c = case_load(pa);
    if (!c)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(c->nfrag, 2);
    assert_int_equal(c->frag[c->fixed].id, 1);
    assert_int_equal(c->has_truth, 1);
    assert_true(pose_angle_between(c->truth[1], POSE_IDENTITY) > 0.04);
    assert_non_null(strstr(ja, "\"path\": \"source.nii.gz\""));
    case_free(c);
    free(ja);
    free(jb);
    free(jc);
    assert_int_equal(tu_run_cli(&out, "fracture '%s' -o '%s/d' --seed 1 --pieces 1", src, dir), 2);
    assert_non_null(strstr(out, "fracnav fracture: --pieces: '1' is not a whole number 2..10"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "fracture '%s' -o '%s/d'", src, dir), 2);
    free(out);
    tu_rmtree(dir);
    free(dir);
}

/* `fracnav fracture` prints, per fragment, how far its truth moves its centroid: the figure the
 * demo prints too, and at least --displace (push-out only adds to it, as --help says). */
static void test_cli_prints_centroid_shift(void **st)
{
    char *dir = tu_tmpdir("fracture"), src[4200], cdir[4300], *out;
    snprintf(src, sizeof src, "%s/bone.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/c", dir);
    vol *ct = bone();
    if (volio_write(ct, src, VOL_I16) < 0)
        fail_msg("%s", fn_err_msg());
    vol_free(ct);
    int rc = tu_run_cli(&out, "fracture '%s' -o '%s' --seed 3 --displace 4", src, cdir);
    if (rc != 0)
        fail_msg("fracture failed (%d): %s", rc, out);
    const char *line = strstr(out, "fragment 2:");
    double mm = -1, deg = -1;
    assert_non_null(line);
    const char *at = strstr(line, "ground truth moves its centroid back ");
    assert_non_null(at);
    assert_int_equal(sscanf(at, "ground truth moves its centroid back %lf mm and turns it %lf deg", &mm, &deg), 2);
    planning_case *c = case_load(cdir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    int k = case_find(c, 2);
    assert_true(k >= 0);
    assert_true(fabs(mm - fracture_truth_shift(&c->truth[k], c->frag[k].centroid)) < 0.006);
    assert_true(mm > 4 - 0.5);
    assert_true(fabs(deg - 3) < 0.006);
    case_free(c);
    free(out);
    assert_int_equal(tu_run_cli(&out, "fracture --help"), 0);
    assert_non_null(strstr(out, "moved on in steps of\n                         one voxel"));
    free(out);
    tu_rmtree(dir);
    free(dir);
}

/* A micro-CT of a small skeleton, as uint8: 0.1 mm voxels (14 x 6 x 6 mm), air 5, soft tissue
 * 100..119 in an ellipsoidal body, and two bones at 200..239: a "femur" 9 mm long (a rod of radius
 * 0.9 mm with knobs of 1.3 mm at its ends: the largest, *bone_voxels of them) and a small round
 * bone apart from it. */
static vol *micro_skeleton(size_t *bone_voxels)
{
    vol *v = vol_new(140, 60, 60);
    const double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    double sp[3] = {0.1, 0.1, 0.1}, org[3] = {-7, -3, -3};
    vol_set_geometry(v, dir, sp, org);
    *bone_voxels = 0;
    for (int k = 0; k < 60; k++)
        for (int j = 0; j < 60; j++)
            for (int i = 0; i < 140; i++) {
                double x = (i - 69.5) / 65, y = (j - 29.5) / 27, z = (k - 29.5) / 27;
                double r = hypot(j - 29.5, k - 29.5), e0 = hypot(i - 25, r), e1 = hypot(i - 115, r);
                int femur = (i >= 25 && i <= 115 && r <= 9) || e0 <= 13 || e1 <= 13;
                int pebble = hypot(i - 70, hypot(j - 49, k - 29.5)) <= 4;
                float val = 5;
                if (femur || pebble)
                    val = (float)(200 + (i * 7 + j * 13 + k * 3) % 40);
                else if (x * x + y * y + z * z <= 1)
                    val = (float)(100 + (i * 5 + j * 3 + k * 11) % 20);
                *bone_voxels += femur;
                v->data[vol_idx(v, i, j, k)] = val;
            }
    v->src_type = VOL_U8;
    return v;
}

/* Centroid (world) of label id in l. */
static void label_centroid(const vol *l, int id, double c[3])
{
    double s[3] = {0, 0, 0};
    size_t n = 0, idx = 0;
    for (int k = 0; k < l->dim[2]; k++)
        for (int j = 0; j < l->dim[1]; j++)
            for (int i = 0; i < l->dim[0]; i++, idx++) {
                if (l->data[idx] != (float)id)
                    continue;
                double ijk[3] = {i, j, k}, w[3];
                vol_index_to_world(l, ijk, w);
                for (int a = 0; a < 3; a++)
                    s[a] += w[a];
                n++;
            }
    for (int a = 0; a < 3; a++)
        c[a] = s[a] / (double)n;
}

/* Every piece keeps at least its share of the bone (fracture_min_piece: 10%, 1/(2K) beyond 6
 * pieces), and every moved piece goes outward from the bone's
 * centre (or across) by --displace plus at most `slack_mm` of push-out. */
static void check_pieces(const fracture_result *r, size_t bone_voxels, double displace, double slack_mm)
{
    double centre[3] = {0, 0, 0};
    size_t n = 0, idx = 0;
    for (int k = 0; k < r->cut->dim[2]; k++)
        for (int j = 0; j < r->cut->dim[1]; j++)
            for (int i = 0; i < r->cut->dim[0]; i++, idx++) {
                if (r->cut->data[idx] <= 0)
                    continue;
                double ijk[3] = {i, j, k}, w[3];
                vol_index_to_world(r->cut, ijk, w);
                for (int a = 0; a < 3; a++)
                    centre[a] += w[a];
                n++;
            }
    for (int a = 0; a < 3; a++)
        centre[a] /= (double)n;
    for (int id = 1; id <= r->pieces; id++) {
        size_t home = count_label(r->cut, id), placed = count_label(r->labels, id);
        size_t least = fracture_min_piece(bone_voxels, r->pieces);
        if (home < least || placed < least * 9 / 10)
            fail_msg("piece %d: %zu voxels at home, %zu placed, of a bone of %zu", id, home, placed,
                     bone_voxels);
        if (id == 1)
            continue;
        double c[3], back[3], outward = 0;
        label_centroid(r->cut, id, c);
        pose_apply(&r->moved[id - 1], c, back);
        double shift = fracture_truth_shift(&r->truth[id - 1], back), dist = 0;
        for (int a = 0; a < 3; a++) {
            outward += (back[a] - c[a]) * (c[a] - centre[a]);
            dist += (c[a] - centre[a]) * (c[a] - centre[a]);
        }
        /* outward: the cosine of the move with the way out; 0 is across it (a piece in the middle
         * may only get out sideways) */
        outward /= shift * sqrt(dist);
        if (shift > displace + slack_mm || outward < -1e-9)
            fail_msg("piece %d moved %.2f mm (--displace %.2f, up to %.2f more allowed), %s", id,
                     shift, displace, slack_mm, outward > 0 ? "outward" : "not outward");
    }
}

/* A micro-CT of a small skeleton (0.1 mm voxels): pieces of a useful size, pushed out in voxel
 * steps, not millimetres; a bone too small for the pieces asked is an error that says why. */
static void test_micro_ct(void **st)
{
    size_t bone_voxels;
    vol *ct = micro_skeleton(&bone_voxels);
    fracture_params p;
    fracture_defaults(&p);
    p.threshold = 160;
    p.roughness_mm = 0.3;
    p.wavelength_mm = 3;
    /* Turned in place, a piece runs into the other at the rough interface: it is pushed out by a
     * few voxels, not by whole millimetres. */
    fracture_result r;
    p.displace_mm = 0;
    p.rotate_deg = 8;
    for (uint64_t seed = 1; seed <= 3; seed++) {
        p.seed = seed;
        if (fracture_make(ct, &p, &r) < 0)
            fail_msg("%s", fn_err_msg());
        double c[3], back[3];
        label_centroid(r.cut, 2, c);
        pose_apply(&r.moved[1], c, back);
        double shift = fracture_truth_shift(&r.truth[1], back);
        if (!(shift < 0.8))
            fail_msg("seed %llu: turned in place, piece 2 was pushed %.2f mm", (unsigned long long)seed, shift);
        fracture_result_free(&r);
    }
    p.displace_mm = 0.4;
    p.rotate_deg = 2;
    for (int pieces = 2; pieces <= 4; pieces++)
        for (uint64_t seed = 1; seed <= 3; seed++) {
            p.pieces = pieces;
            p.seed = seed;
            if (fracture_make(ct, &p, &r) < 0)
                fail_msg("%d pieces, seed %llu: %s", pieces, (unsigned long long)seed, fn_err_msg());
            check_truth(ct, &r);
            check_pieces(&r, bone_voxels, p.displace_mm, 2);
            fracture_result_free(&r);
        }
    vol_free(ct);
    /* two voxels of bone: no third piece */
    ct = vol_new(4, 4, 4);
    ct->data[vol_idx(ct, 1, 1, 1)] = ct->data[vol_idx(ct, 2, 1, 1)] = 200;
    p.pieces = 10;
    assert_true(fracture_make(ct, &p, &r) < 0);
    if (!strstr(fn_err_msg(), "5% of the bone") || !strstr(fn_err_msg(), "fewer --pieces"))
        fail_msg("%s", fn_err_msg());
    vol_free(ct);
}

/* A piece pushed past the CT's edge is kept whole: the grid grows to hold it (the new voxels are
 * the CT's lowest value, nothing scanned), and the truth still restores every voxel. */
static void test_piece_past_edge_grows_grid(void **st)
{
    size_t bone_voxels;
    vol *ct = micro_skeleton(&bone_voxels);
    fracture_params p;
    fracture_defaults(&p);
    p.threshold = 160;
    p.roughness_mm = 0.3;
    p.wavelength_mm = 3;
    p.displace_mm = 8;
    for (uint64_t seed = 1; seed <= 3; seed++) {
        p.seed = seed;
        fracture_result r;
        if (fracture_make(ct, &p, &r) < 0)
            fail_msg("seed %llu: %s", (unsigned long long)seed, fn_err_msg());
        assert_true(vol_count(r.labels) > vol_count(ct));
        assert_true(vol_count(r.ct) == vol_count(r.labels) && vol_count(r.cut) == vol_count(ct));
        check_truth(ct, &r);
        for (int id = 1; id <= 2; id++) {
            size_t home = count_label(r.cut, id), placed = count_label(r.labels, id);
            if (fabs((double)placed - (double)home) > 0.05 * (double)home)
                fail_msg("seed %llu, piece %d: %zu voxels at home, %zu placed", (unsigned long long)seed,
                         id, home, placed);
        }
        size_t outside = 0;
        for (size_t i = 0; i < vol_count(r.ct); i++)
            outside += r.ct->data[i] == 5 && r.labels->data[i] == 0;
        assert_true(outside > vol_count(r.ct) - vol_count(ct));
        fracture_result_free(&r);
    }
    vol_free(ct);
}

/* Several pieces each leave outward from the bone's centre and clear in a few millimetres. */
static void test_pieces_clear_near(void **st)
{
    vol *ct = bone();
    size_t bone_voxels = 0;
    for (size_t i = 0; i < vol_count(ct); i++)
        bone_voxels += ct->data[i] >= 300;
    fracture_params p;
    fracture_defaults(&p);
    for (int pieces = 3; pieces <= 6; pieces++)
        for (uint64_t seed = 2024; seed <= 2026; seed++) {
            p.pieces = pieces;
            p.seed = seed;
            p.bone_loss_mm = seed == 2026 ? 1 : 0;
            fracture_result r;
            if (fracture_make(ct, &p, &r) < 0)
                fail_msg("%d pieces, seed %llu: %s", pieces, (unsigned long long)seed, fn_err_msg());
            check_pieces(&r, bone_voxels, p.displace_mm, 3);
            fracture_result_free(&r);
        }
    vol_free(ct);
}

/* --pieces 10 is made (10 pieces of 10% each never were): each piece keeps 5% of the bone, and
 * the truth restores every one. */
static void test_ten_pieces(void **st)
{
    vol *ct = bone();
    size_t bone_voxels = 0;
    for (size_t i = 0; i < vol_count(ct); i++)
        bone_voxels += ct->data[i] >= 300;
    fracture_params p;
    fracture_defaults(&p);
    p.pieces = 10;
    for (uint64_t seed = 1; seed <= 3; seed++) {
        p.seed = seed;
        fracture_result r;
        if (fracture_make(ct, &p, &r) < 0)
            fail_msg("seed %llu: %s", (unsigned long long)seed, fn_err_msg());
        check_truth(ct, &r);
        for (int id = 1; id <= 10; id++)
            assert_true(count_label(r.cut, id) >= fracture_min_piece(bone_voxels, 10));
        fracture_result_free(&r);
    }
    vol_free(ct);
}

/* `--threshold auto-bone` (and auto), as segment takes it, on data not in HU. */
static void test_cli_threshold_auto(void **st)
{
    char *dir = tu_tmpdir("fracture"), src[4200], cdir[4300], *out;
    snprintf(src, sizeof src, "%s/micro.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/c", dir);
    size_t bone_voxels;
    vol *ct = micro_skeleton(&bone_voxels);
    if (volio_write(ct, src, VOL_U8) < 0)
        fail_msg("%s", fn_err_msg());
    vol_free(ct);
    int rc = tu_run_cli(&out, "fracture '%s' -o '%s' --seed 2 --threshold auto-bone --displace 0.4 "
                              "--roughness 0.3", src, cdir);
    if (rc != 0)
        fail_msg("fracture failed (%d): %s", rc, out);
    free(out);
    planning_case *c = case_load(cdir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    /* Otsu over the brighter class falls between soft tissue (100..119) and bone (200..239). */
    if (!(c->seg.threshold > 119 && c->seg.threshold <= 200))
        fail_msg("auto-bone threshold %g", c->seg.threshold);
    assert_int_equal(c->nfrag, 2);
    for (int i = 0; i < c->nfrag; i++)
        assert_true(c->frag[i].voxels * 10 >= bone_voxels * 9 / 10);
    case_free(c);
    tu_rmtree(cdir);
    /* auto: Otsu over all, air from tissue: the "bone" is the whole body. */
    assert_int_equal(tu_run_cli(&out, "fracture '%s' -o '%s' --seed 2 --threshold auto --displace 0.4",
                                src, cdir), 0);
    free(out);
    assert_int_equal(tu_run_cli(&out, "fracture '%s' -o '%s' --seed 2 --threshold bone", src, cdir), 2);
    assert_non_null(strstr(out, "--threshold: 'bone' is not a number (HU), 'auto' or 'auto-bone'"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "fracture --help"), 0);
    assert_non_null(strstr(out, "--threshold HU|auto|auto-bone"));
    free(out);
    tu_rmtree(dir);
    free(dir);
}

/* FNV-1a over the voxel values of v (integers: labels, or an int16 CT), in index order. */
static uint64_t voxel_digest(const vol *v)
{
    uint64_t h = 0xcbf29ce484222325ull;
    for (size_t i = 0; i < vol_count(v); i++) {
        uint32_t x = (uint32_t)(int32_t)v->data[i];
        for (int b = 0; b < 4; b++) {
            h ^= (x >> (8 * b)) & 0xff;
            h *= 0x100000001b3ull;
        }
    }
    return h;
}

/* The same seed gives the same case on every machine: values recorded once, on x86-64 with gcc,
 * and compared here. Voxels by digest (not gzip bytes, which depend on zlib's version). */
static void test_golden_case(void **st)
{
    static const size_t want_cut[3] = {8612, 7380, 2656}, want_lab[3] = {8612, 7389, 2663};
    static const double want_q[3][4] = {
        {1, 0, 0, 0},
        {0.99939082701909565, 0.016153247879554519, 0.026401623561393164, 0.016124569028412295},
        {0.99939082701909565, -0.01086970055676161, 0.026014573851418414, 0.020568578638868313}};
    static const double want_t[3][3] = {
        {0, 0, 0},
        {-3.3188711784516558, -0.22790415056282212, 2.0808786575625411},
        {-1.1457070648312746, 1.4745691682777016, -1.7512320843967761}};
    /* cut (before displacement), labels (displaced), fractured CT */
    static const uint64_t want_digest[3] = {0x4869b09672cf2da5ull, 0xb56d298a29537174ull, 0xaa00edd0f4180aeaull};
    vol *ct = bone();
    fracture_params p;
    fracture_defaults(&p);
    p.seed = 2026;
    p.pieces = 3;
    p.bone_loss_mm = 1;
    p.rotate_deg = 4;
    fracture_result r;
    if (fracture_make(ct, &p, &r) < 0)
        fail_msg("%s", fn_err_msg());
    uint64_t digest[3] = {voxel_digest(r.cut), voxel_digest(r.labels), voxel_digest(r.ct)};
    int same = 1;
    for (int id = 1; id <= 3; id++) {
        same &= count_label(r.cut, id) == want_cut[id - 1] && count_label(r.labels, id) == want_lab[id - 1];
        for (int a = 0; a < 4; a++)
            same &= fabs(r.truth[id - 1].q[a] - want_q[id - 1][a]) <= 1e-9;
        for (int a = 0; a < 3; a++)
            same &= fabs(r.truth[id - 1].t[a] - want_t[id - 1][a]) <= 1e-9;
    }
    for (int d = 0; d < 3; d++)
        same &= digest[d] == want_digest[d];
    if (!same) {
        printf("cut %zu %zu %zu, labels %zu %zu %zu, digests 0x%016llxull, 0x%016llxull, 0x%016llxull\n",
               count_label(r.cut, 1), count_label(r.cut, 2), count_label(r.cut, 3), count_label(r.labels, 1),
               count_label(r.labels, 2), count_label(r.labels, 3), (unsigned long long)digest[0],
               (unsigned long long)digest[1], (unsigned long long)digest[2]);
        for (int id = 1; id <= 3; id++)
            printf("truth %d: {%.17g, %.17g, %.17g, %.17g}, {%.17g, %.17g, %.17g}\n", id, r.truth[id - 1].q[0],
                   r.truth[id - 1].q[1], r.truth[id - 1].q[2], r.truth[id - 1].q[3], r.truth[id - 1].t[0],
                   r.truth[id - 1].t[1], r.truth[id - 1].t[2]);
        fail_msg("seed 2026 no longer gives the recorded case (actual values above)");
    }
    fracture_result_free(&r);
    vol_free(ct);
}

/* --whole-bone on a CT that holds only the bone (0 outside): the ellipsoid's 1 voxel cortex at
 * 1000 HU holds an interior at -60..90 HU, as fatty cancellous bone. At the threshold the pieces are
 * the shell alone; with whole_bone they are the whole ellipsoid, the truth restores them, and
 * where a moved piece left, 0 (the CT's outside) is written, not 40 HU. */
static void test_whole_bone_pieces(void **st)
{
    (void)st;
    vol *ct = bone();
    size_t inside = 0;
    for (int k = 0; k < 40; k++)
        for (int j = 0; j < 44; j++)
            for (int i = 0; i < 64; i++) {
                double x = (i - 31.5) / 24, y = (j - 21.5) / 15, z = (k - 19.5) / 13;
                double r = sqrt(x * x + y * y + z * z);
                float *v = &ct->data[vol_idx(ct, i, j, k)];
                *v = r > 1 ? 0 : r > 0.9 ? 1000 : (float)(-60 + (i * 7 + j * 13 + k * 3) % 150);
                inside += r <= 1 && *v != 0;
            }
    fracture_params p;
    fracture_defaults(&p);
    p.seed = 7;
    p.displace_mm = 4;
    p.rotate_deg = 5;
    size_t shell = 0, whole = 0;
    for (int w = 0; w < 2; w++) {
        p.whole_bone = w;
        fracture_result r;
        if (fracture_make(ct, &p, &r) < 0)
            fail_msg("whole_bone %d: %s", w, fn_err_msg());
        size_t n = count_label(r.cut, 1) + count_label(r.cut, 2);
        *(w ? &whole : &shell) = n;
        if (w) {
            check_truth(ct, &r);
            size_t zeros = 0, forty = 0;
            for (size_t i = 0; i < vol_count(ct); i++) {
                int left = r.cut->data[i] > 1 && r.labels->data[i] == 0;
                zeros += left && r.ct->data[i] == 0;
                forty += left && r.ct->data[i] == 40;
            }
            assert_true(zeros > 0);
            assert_int_equal((int)forty, 0);
        }
        fracture_result_free(&r);
    }
    print_message("pieces: %zu voxels at the threshold, %zu whole, of %zu non-zero\n", shell, whole, inside);
    assert_true(shell < inside / 2);
    assert_true(whole > inside * 99 / 100 && whole <= inside);
    vol_free(ct);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_truth_restores_pieces),
        cmocka_unit_test(test_touching_pieces_separate),
        cmocka_unit_test(test_surface_is_rough),
        cmocka_unit_test(test_bone_loss_opens_a_gap),
        cmocka_unit_test(test_same_seed_same_case),
        cmocka_unit_test(test_golden_case),
        cmocka_unit_test(test_cli_prints_centroid_shift),
        cmocka_unit_test(test_micro_ct),
        cmocka_unit_test(test_piece_past_edge_grows_grid),
        cmocka_unit_test(test_pieces_clear_near),
        cmocka_unit_test(test_ten_pieces),
        cmocka_unit_test(test_cli_threshold_auto),
        cmocka_unit_test(test_whole_bone_pieces),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
