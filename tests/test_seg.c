/* Segmentation: union-find components, Otsu, filters, probability maps, fragment geometry, and the
 * example CT's fragments. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "bone.h"
#include "case.h"
#include "err.h"
#include "frag.h"
#include "obb.h"
#include "seg.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <float.h>
#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static void set(uint8_t *m, const int d[3], int i, int j, int k)
{
    m[((size_t)k * d[1] + j) * d[0] + i] = 1;
}

static int32_t at(const int32_t *l, const int d[3], int i, int j, int k)
{
    return l[((size_t)k * d[1] + j) * d[0] + i];
}

static void test_components_corners_are_connected(void **st)
{
    int d[3] = {6, 6, 6};
    uint8_t m[216] = {0};
    int32_t lab[216];
    /* A diagonal chain touching only at corners is one 26-connected component. */
    for (int t = 0; t < 4; t++)
        set(m, d, t, t, t);
    /* One voxel apart from the chain in every direction: separate. */
    set(m, d, 5, 0, 0);
    set(m, d, 0, 5, 5);
    assert_int_equal(seg_components(m, d, lab), 3);
    assert_int_equal(at(lab, d, 0, 0, 0), 1);
    assert_int_equal(at(lab, d, 3, 3, 3), 1);
    assert_int_not_equal(at(lab, d, 5, 0, 0), at(lab, d, 0, 5, 5));
    assert_int_equal(at(lab, d, 1, 0, 0), 0);
    /* Edge contact (two coordinates differ) also connects. */
    uint8_t e[216] = {0};
    set(e, d, 2, 2, 2);
    set(e, d, 3, 3, 2);
    set(e, d, 2, 3, 3);
    assert_int_equal(seg_components(e, d, lab), 1);
}

static void test_components_join_late(void **st)
{
    /* A U shape whose arms get different provisional labels and meet only at the far row, and a
     * comb inside it (one voxel away) whose teeth join only through their last row. */
    int d[3] = {9, 9, 3};
    uint8_t m[243] = {0};
    int32_t lab[243];
    for (int j = 0; j < 9; j++) {
        set(m, d, 0, j, 1);
        set(m, d, 8, j, 1);
    }
    for (int i = 0; i < 9; i++)
        set(m, d, i, 8, 1);
    for (int i = 2; i < 7; i += 2)
        for (int j = 0; j < 7; j++)
            set(m, d, i, j, 1);
    for (int i = 2; i < 7; i++)
        set(m, d, i, 6, 1);
    set(m, d, 4, 4, 0); /* below a tooth: joins the comb through a face */
    assert_int_equal(seg_components(m, d, lab), 2);
    assert_int_equal(at(lab, d, 0, 0, 1), at(lab, d, 8, 0, 1));
    assert_int_equal(at(lab, d, 2, 0, 1), at(lab, d, 6, 0, 1));
    assert_int_not_equal(at(lab, d, 0, 0, 1), at(lab, d, 2, 0, 1));
    assert_int_equal(at(lab, d, 4, 4, 0), at(lab, d, 4, 4, 1));
}

static vol *bimodal(void)
{
    vol *v = vol_new(20, 20, 20);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = (float)(i % 7); /* background 0..6 */
    for (int k = 5; k < 15; k++)
        for (int j = 5; j < 15; j++)
            for (int i = 5; i < 15; i++)
                v->data[vol_idx(v, i, j, k)] = 100 + (float)((i + j + k) % 9);
    return v;
}

static void test_otsu_splits_two_classes(void **st)
{
    vol *v = bimodal();
    double t = seg_otsu(v);
    assert_true(t > 6 && t <= 100);
    seg_params p;
    seg_defaults(&p);
    p.threshold_auto = 1;
    p.min_volume_ml = 0;
    seg_result r;
    assert_int_equal(seg_run(v, &p, &r), 0);
    assert_int_equal(r.ncomp, 1);
    assert_int_equal((int)r.comp[0].voxels, 1000);
    assert_int_equal(r.comp[0].lo[0], 5);
    assert_int_equal(r.comp[0].hi[2], 14);
    seg_result_free(&r);
    vol_free(v);
}

/* Three blobs: big and bright, medium and dim (a "head holder"), tiny. */
static vol *three_blobs(void)
{
    vol *v = vol_new(40, 20, 20);
    static const double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    double sp[3] = {2, 2, 2}, org[3] = {0, 0, 0};
    vol_set_geometry(v, dir, sp, org);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = -1000;
    for (int k = 2; k < 12; k++)
        for (int j = 2; j < 12; j++)
            for (int i = 2; i < 14; i++)
                v->data[vol_idx(v, i, j, k)] = i == 7 ? 1500 : 800;
    for (int k = 2; k < 8; k++)
        for (int j = 2; j < 8; j++)
            for (int i = 20; i < 26; i++)
                v->data[vol_idx(v, i, j, k)] = 450;
    v->data[vol_idx(v, 35, 15, 15)] = 900;
    return v;
}

static void test_filters(void **st)
{
    vol *v = three_blobs();
    seg_params p;
    seg_defaults(&p);
    p.min_volume_ml = 0;
    seg_result r;
    assert_int_equal(seg_run(v, &p, &r), 0);
    assert_int_equal(r.ncomp, 3);
    assert_int_equal((int)r.comp[0].voxels, 1200);
    assert_int_equal((int)r.comp[1].voxels, 216);
    assert_true(fabs(r.comp[1].volume_ml - 216 * 8 / 1000.0) < 1e-9);
    assert_true(r.comp[0].peak == 1500);
    /* Labels are 1..n, largest first. */
    assert_true(r.labels->data[vol_idx(v, 3, 3, 3)] == 1);
    assert_true(r.labels->data[vol_idx(v, 21, 3, 3)] == 2);
    seg_result_free(&r);

    p.min_volume_ml = 0.1; /* the lone voxel is 0.008 ml */
    assert_int_equal(seg_run(v, &p, &r), 0);
    assert_int_equal(r.ncomp, 2);
    assert_int_equal(r.raw_components, 3);
    seg_result_free(&r);

    p.exclude_peak = 1;
    p.exclude_below_peak = 1000; /* the dim blob peaks at 450 */
    assert_int_equal(seg_run(v, &p, &r), 0);
    assert_int_equal(r.ncomp, 1);
    assert_true(r.labels->data[vol_idx(v, 21, 3, 3)] == 0);
    seg_result_free(&r);

    p.exclude_peak = 0;
    p.min_volume_ml = 0;
    p.keep = 1;
    assert_int_equal(seg_run(v, &p, &r), 0);
    assert_int_equal(r.ncomp, 1);
    seg_result_free(&r);

    p.keep = -1;
    assert_int_equal(seg_run(v, &p, &r), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "keep"));
    vol_free(v);
}

/* Air, a big block of tissue and a smaller bone inside it: auto splits air from tissue, auto-bone
 * finds the bone. */
static void test_otsu_twice_finds_bone(void **st)
{
    vol *v = vol_new(30, 30, 30);
    for (int k = 0; k < 30; k++)
        for (int j = 0; j < 30; j++)
            for (int i = 0; i < 30; i++) {
                float x = (float)((i + 2 * j + 3 * k) % 5);
                int tissue = i >= 3 && i < 27 && j >= 3 && j < 27 && k >= 3 && k < 27;
                int bone = i >= 10 && i < 16 && j >= 10 && j < 16 && k >= 10 && k < 16;
                v->data[vol_idx(v, i, j, k)] = bone ? 200 + x : tissue ? 80 + x : x;
            }
    seg_params p;
    seg_defaults(&p);
    p.min_volume_ml = 0;
    p.threshold_auto = 1;
    seg_result r;
    assert_int_equal(seg_run(v, &p, &r), 0);
    assert_int_equal((int)r.comp[0].voxels, 24 * 24 * 24);
    seg_result_free(&r);
    p.threshold_auto = 2;
    assert_int_equal(seg_run(v, &p, &r), 0);
    assert_true(r.threshold > 84 && r.threshold <= 200);
    assert_int_equal(r.ncomp, 1);
    assert_int_equal((int)r.comp[0].voxels, 216);
    seg_result_free(&r);
    vol_free(v);
}

/* NaN and infinite voxels are counted and left out: Otsu gives the same split as without them
 * (it used to index its histogram with (int)NaN and crash), and they are never bone. Values near
 * +-3e38 are finite and must not overflow the histogram either. */
static void test_otsu_ignores_nonfinite(void **st)
{
    vol *v = bimodal();
    double clean = seg_otsu(v);
    const float poison[] = {NAN, INFINITY, -INFINITY};
    for (int i = 0; i < 3; i++)
        v->data[i] = poison[i];
    v->data[vol_idx(v, 10, 10, 10)] = NAN; /* inside the bright cube */
    assert_true(fabs(seg_otsu(v) - clean) < 1e-9);
    seg_params p;
    seg_defaults(&p);
    p.min_volume_ml = 0;
    for (int mode = 1; mode <= 2; mode++) {
        p.threshold_auto = mode;
        seg_result r;
        assert_int_equal(seg_run(v, &p, &r), 0);
        assert_int_equal((int)r.nonfinite, 4);
        assert_true(isfinite(r.threshold));
        assert_true(r.ncomp >= 1 && isfinite(r.comp[0].peak));
        if (mode == 1) /* the bright cube less its NaN voxel */
            assert_int_equal((int)r.comp[0].voxels, 999);
        seg_result_free(&r);
    }
    v->data[0] = 3e38f;
    v->data[1] = -3e38f;
    v->data[2] = FLT_MAX;
    for (int mode = 1; mode <= 2; mode++) {
        p.threshold_auto = mode;
        seg_result r;
        assert_int_equal(seg_run(v, &p, &r), 0);
        assert_true(isfinite(r.threshold));
        seg_result_free(&r);
    }
    vol_free(v);
}

/* A volume with no finite voxel has nothing to segment: refused with a message, whatever the
 * threshold mode (it used to give a case whose threshold was NaN, which then failed to load). */
static void test_all_nonfinite_refused(void **st)
{
    vol *v = vol_new(8, 8, 8);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = i % 2 ? NAN : INFINITY;
    seg_params p;
    seg_defaults(&p);
    for (int mode = 0; mode <= 2; mode++) {
        p.threshold_auto = mode;
        seg_result r;
        assert_int_equal(seg_run(v, &p, &r), FN_EFORMAT);
        assert_null(r.labels);
        if (!strstr(fn_err_msg(), "all 512 voxels are NaN or infinite"))
            fail_msg("mode %d: %s", mode, fn_err_msg());
    }
    vol_free(v);
}

/* The CLI: an all-NaN float volume is refused with exit 1 and no case folder; one with a few NaN
 * voxels is segmented, says how many it left out, and the case loads. */
static void test_cli_nonfinite(void **st)
{
    char *dir = tu_tmpdir("seg-nan"), in[4300], out_dir[4300], *out = NULL;
    snprintf(in, sizeof in, "%s/nan.nii", dir);
    snprintf(out_dir, sizeof out_dir, "%s/case", dir);
    vol *v = vol_new(8, 8, 8);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = NAN;
    assert_int_equal(volio_write(v, in, VOL_F32), 0);
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s' --threshold auto", in, out_dir), 1);
    if (!strstr(out, "NaN or infinite"))
        fail_msg("got: %s", out);
    free(out);
    assert_int_equal(access(out_dir, F_OK), -1);
    vol_free(v);
    v = bimodal();
    v->data[0] = NAN;
    v->data[1] = -INFINITY;
    v->data[vol_idx(v, 10, 10, 10)] = INFINITY;
    assert_int_equal(volio_write(v, in, VOL_F32), 0);
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s' --threshold auto-bone --min-volume 0", in,
                                out_dir), 0);
    if (!strstr(out, "3 voxels are NaN or infinite"))
        fail_msg("got: %s", out);
    free(out);
    planning_case *c = case_load(out_dir);
    if (!c)
        fail_msg("the case does not load: %s", fn_err_msg());
    assert_true(isfinite(c->seg.threshold));
    case_free(c);
    vol_free(v);
    tu_rmtree(dir);
    free(dir);
}

/* segment --labels: a labelmap on the CT's grid (NIfTI and NRRD) comes back as the case's
 * labels, label k = fragment k, even where the pieces touch; another grid is refused, named. */
static void test_cli_labels_import(void **st)
{
    char *dir = tu_tmpdir("seg-labels"), ct[4300], lab[4300], out_dir[4300], *out = NULL;
    vol *v = vol_new(24, 16, 12), *l = vol_new(24, 16, 12);
    for (int k = 0; k < 12; k++)
        for (int j = 0; j < 16; j++)
            for (int i = 0; i < 24; i++) {
                int in = i >= 2 && i < 22 && j >= 3 && j < 13 && k >= 2 && k < 10;
                v->data[vol_idx(v, i, j, k)] = in ? 900 : -1000;
                l->data[vol_idx(l, i, j, k)] = in ? (i < 9 ? 1 : i < 15 ? 3 : 2) : 0; /* three touching */
            }
    snprintf(ct, sizeof ct, "%s/ct.nii.gz", dir);
    assert_int_equal(volio_write(v, ct, VOL_I16), 0);
    const char *ext[2] = {"nii.gz", "nrrd"};
    for (int e = 0; e < 2; e++) {
        snprintf(lab, sizeof lab, "%s/labels.%s", dir, ext[e]);
        snprintf(out_dir, sizeof out_dir, "%s/case%d", dir, e);
        assert_int_equal(volio_write(l, lab, VOL_U8), 0);
        int rc = tu_run_cli(&out, "segment '%s' --labels '%s' -o '%s' --min-volume 0", ct, lab, out_dir);
        if (rc != 0)
            fail_msg("segment --labels: %s", out);
        free(out);
        planning_case *c = case_load(out_dir);
        if (!c)
            fail_msg("%s", fn_err_msg());
        assert_int_equal(c->nfrag, 3);
        for (size_t i = 0; i < vol_count(l); i++)
            assert_true(c->labels->data[i] == l->data[i]);
        case_free(c);
    }
    vol *other = vol_new(24, 16, 11);
    assert_int_equal(volio_write(other, lab, VOL_U8), 0);
    snprintf(out_dir, sizeof out_dir, "%s/case-bad", dir);
    assert_int_equal(tu_run_cli(&out, "segment '%s' --labels '%s' -o '%s'", ct, lab, out_dir), 1);
    if (!strstr(out, "grid") || !strstr(out, lab))
        fail_msg("got: %s", out);
    free(out);
    vol_free(other);
    vol_free(v);
    vol_free(l);
    tu_rmtree(dir);
    free(dir);
}

/* A 3D Slicer .seg.nrrd on a 6x5x4 grid of 1 mm at the origin (LPS), u8, raw: `layers` layers
 * (4D when > 1, the layer axis first), the value of layer l at voxel (i, j, k) from val(l, i, j, k),
 * and the header lines `keys` (Segment<N>_...:=...). */
static void write_seg_nrrd(const char *path, int layers, const char *keys, int (*val)(int, int, int, int))
{
    char head[2048];
    snprintf(head, sizeof head,
             "NRRD0004\ntype: unsigned char\ndimension: %d\nspace: left-posterior-superior\n"
             "sizes: %s6 5 4\nspace directions: %s(1,0,0) (0,1,0) (0,0,1)\nkinds: %sdomain domain domain\n"
             "encoding: raw\nspace origin: (0,0,0)\nSegmentation_MasterRepresentation:=Binary labelmap\n%s\n",
             layers > 1 ? 4 : 3, layers > 1 ? (layers == 2 ? "2 " : "3 ") : "", layers > 1 ? "none " : "",
             layers > 1 ? "list " : "", keys);
    size_t hl = strlen(head), n = (size_t)layers * 6 * 5 * 4;
    unsigned char *b = malloc(hl + n);
    memcpy(b, head, hl);
    for (int k = 0, at = 0; k < 4; k++)
        for (int j = 0; j < 5; j++)
            for (int i = 0; i < 6; i++)
                for (int l = 0; l < layers; l++)
                    b[hl + at++] = (unsigned char)val(l, i, j, k);
    tu_write_file(path, b, hl + n);
    free(b);
}

/* Two layers: Segment0 (layer 0, value 1) is the slab i 0..2, Segment2 (layer 0, value 5) the slab
 * i 4..5, Segment1 (layer 1, value 1) the slab i 2..3, overlapping Segment0 at i = 2 (20 voxels). */
static int two_layers(int l, int i, int j, int k)
{
    (void)j, (void)k;
    if (l == 0)
        return i < 3 ? 1 : i >= 4 ? 5 : 0;
    return i >= 2 && i < 4 ? 1 : 0;
}

/* One layer: value 7 (Segment0) at i 0..1, 3 (Segment1) at i 2..4, 9 (no segment's) at i 5. */
static int one_layer(int l, int i, int j, int k)
{
    (void)l, (void)j, (void)k;
    return i < 2 ? 7 : i < 5 ? 3 : 9;
}

#define SEG_KEYS(n, value, layer) "Segment" #n "_ID:=Segment_" #n "\nSegment" #n "_Name:=piece " #n "\n" \
    "Segment" #n "_LabelValue:=" #value "\nSegment" #n "_Layer:=" #layer "\nSegment" #n "_Extent:=0 5 0 4 0 3\n"

/* segment --labels with a 3D Slicer .seg.nrrd: segment N = fragment N + 1 where its layer holds
 * its label value, in a multi-layer (4D) file and in a one-layer one; overlapping voxels go to the
 * first segment, each pair's overlap reported (stderr and --json); a layer out of range and a
 * missing label value are refused naming the file and the key. */
static void test_cli_labels_seg_nrrd(void **st)
{
    char *dir = tu_tmpdir("seg-layers"), ct[4300], lab[4300], out_dir[4300], *out = NULL;
    vol *v = vol_new(6, 5, 4);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = 1000;
    snprintf(ct, sizeof ct, "%s/ct.nii.gz", dir);
    assert_int_equal(volio_write(v, ct, VOL_I16), 0);
    snprintf(lab, sizeof lab, "%s/layers.seg.nrrd", dir);
    write_seg_nrrd(lab, 2, SEG_KEYS(0, 1, 0) SEG_KEYS(1, 1, 1) SEG_KEYS(2, 5, 0), two_layers);

    snprintf(out_dir, sizeof out_dir, "%s/case", dir);
    int rc = tu_run_cli(&out, "segment '%s' --labels '%s' -o '%s'", ct, lab, out_dir);
    if (rc != 0 || !strstr(out, "warning") || !strstr(out, lab) ||
        !strstr(out, "Segment0 and Segment1 overlap in 20 voxels: given to fragment 1 (the first segment), "
                     "not fragment 2") || strstr(out, "Segment2 overlap") || strstr(out, "and Segment2"))
        fail_msg("rc %d: %s", rc, out);
    free(out);
    planning_case *c = case_load(out_dir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(c->nfrag, 3);
    static const size_t want[3] = {60, 20, 40}; /* Segment1 keeps only what Segment0 does not hold */
    for (int f = 0; f < 3; f++) {
        assert_int_equal(c->frag[f].id, f + 1);
        assert_int_equal(c->frag[f].voxels, want[f]);
    }
    for (int i = 0; i < 6; i++) /* fragment by slab: 1 1 1 2 3 3 */
        assert_true(c->labels->data[vol_idx(c->labels, i, 2, 1)] == (i < 3 ? 1 : i < 4 ? 2 : 3));
    case_free(c);

    snprintf(out_dir, sizeof out_dir, "%s/case-json", dir);
    rc = tu_run_cli(&out, "segment '%s' --labels '%s' -o '%s' --json 2>/dev/null", ct, lab, out_dir);
    if (rc != 0 || !strstr(out, "\"overlaps\": [\n    {\n      \"fragment\": 1,\n      \"other_fragment\": 2,\n"
                                "      \"voxels\": 20\n    }\n  ]"))
        fail_msg("rc %d: %s", rc, out);
    free(out);

    /* One layer: by the keys, not by the value (7 -> 1, 3 -> 2); 9 is no segment's. */
    snprintf(lab, sizeof lab, "%s/one.seg.nrrd", dir);
    write_seg_nrrd(lab, 1, SEG_KEYS(0, 7, 0) SEG_KEYS(1, 3, 0), one_layer);
    snprintf(out_dir, sizeof out_dir, "%s/case-one", dir);
    rc = tu_run_cli(&out, "segment '%s' --labels '%s' -o '%s' --json", ct, lab, out_dir);
    if (rc != 0 || !strstr(out, "20 voxels hold a value that no segment's LabelValue lists") ||
        !strstr(out, "\"overlaps\": []"))
        fail_msg("rc %d: %s", rc, out);
    free(out);
    c = case_load(out_dir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(c->nfrag, 2);
    assert_int_equal(c->frag[0].voxels, 40);
    assert_int_equal(c->frag[1].voxels, 60);
    assert_true(c->labels->data[vol_idx(c->labels, 0, 0, 0)] == 1);
    assert_true(c->labels->data[vol_idx(c->labels, 5, 0, 0)] == 0);
    case_free(c);

    /* Refused, naming the file and the key; no case is left. */
    static const struct {
        const char *keys, *want;
    } bad[] = {
        {SEG_KEYS(0, 1, 0) SEG_KEYS(1, 1, 1) SEG_KEYS(2, 5, 2), "Segment2_Layer: '2' is no layer of this file: "
                                                                "it has 2 layers (0..1)"},
        {SEG_KEYS(0, 1, 0) "Segment1_ID:=Segment_1\nSegment1_Layer:=1\n" SEG_KEYS(2, 5, 0),
         "Segment1_LabelValue: missing"},
        {SEG_KEYS(0, 1, 0) SEG_KEYS(1, 1, 1) SEG_KEYS(2, 1, 0), "Segment2_LabelValue: 1 in layer 0 is Segment0's"},
        {"", "dimension: 4 without Segment<N>_ keys: not a 3D Slicer segmentation"},
    };
    snprintf(lab, sizeof lab, "%s/bad.seg.nrrd", dir);
    snprintf(out_dir, sizeof out_dir, "%s/case-bad", dir);
    for (size_t b = 0; b < sizeof bad / sizeof bad[0]; b++) {
        write_seg_nrrd(lab, 2, bad[b].keys, two_layers);
        rc = tu_run_cli(&out, "segment '%s' --labels '%s' -o '%s'", ct, lab, out_dir);
        if (rc != 1 || !strstr(out, lab) || !strstr(out, bad[b].want))
            fail_msg("case %zu: rc %d: %s", b, rc, out);
        free(out);
        assert_int_equal(access(out_dir, F_OK), -1);
    }
    vol_free(v);
    tu_rmtree(dir);
    free(dir);
}

/* segment --fill: a hollow box (a cortex around a dark interior) becomes one solid fragment. */
static void test_cli_fill(void **st)
{
    char *dir = tu_tmpdir("seg-fill"), ct[4300], out_dir[4300], *out = NULL;
    vol *v = vol_new(20, 20, 20);
    size_t solid = 0;
    for (int k = 0; k < 20; k++)
        for (int j = 0; j < 20; j++)
            for (int i = 0; i < 20; i++) {
                int in = i >= 3 && i < 17 && j >= 3 && j < 17 && k >= 3 && k < 17;
                int wall = in && (i < 5 || i >= 15 || j < 5 || j >= 15 || k < 5 || k >= 15);
                v->data[vol_idx(v, i, j, k)] = wall ? 1000 : in ? 40 : -1000;
                solid += in;
            }
    snprintf(ct, sizeof ct, "%s/shell.nii.gz", dir);
    snprintf(out_dir, sizeof out_dir, "%s/case", dir);
    assert_int_equal(volio_write(v, ct, VOL_I16), 0);
    int rc = tu_run_cli(&out, "segment '%s' -o '%s' --min-volume 0 --fill --json", ct, out_dir);
    if (rc != 0 || !strstr(out, "\"filled_voxels\": 1000"))
        fail_msg("rc %d: %s", rc, out);
    free(out);
    planning_case *c = case_load(out_dir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(c->nfrag, 1);
    assert_int_equal(c->frag[0].voxels, solid);
    case_free(c);
    vol_free(v);
    tu_rmtree(dir);
    free(dir);
}

/* segment --whole-bone on a bone cut out of its CT (0 outside): a cortex open on one side (a
 * threshold and --fill leave the interior out) around a 40-70 HU interior is found whole. */
static void test_cli_whole_bone(void **st)
{
    char *dir = tu_tmpdir("seg-whole"), ct[4300], out_dir[4300], *out = NULL;
    vol *v = vol_new(20, 20, 20);
    size_t solid = 0;
    for (int k = 3; k < 17; k++)
        for (int j = 3; j < 17; j++)
            for (int i = 3; i < 17; i++) {
                int wall = i < 5 || j < 5 || j >= 15 || k < 5 || k >= 15; /* open at high i */
                v->data[vol_idx(v, i, j, k)] = wall ? 800 : 40 + (i + j + k) % 31;
                solid++;
            }
    snprintf(ct, sizeof ct, "%s/bone.nii.gz", dir);
    snprintf(out_dir, sizeof out_dir, "%s/case", dir);
    assert_int_equal(volio_write(v, ct, VOL_I16), 0);
    int rc = tu_run_cli(&out, "segment '%s' -o '%s' --min-volume 0 --whole-bone --json", ct, out_dir);
    if (rc != 0)
        fail_msg("rc %d: %s", rc, out);
    free(out);
    planning_case *c = case_load(out_dir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(c->nfrag, 1);
    assert_int_equal(c->frag[0].voxels, solid);
    assert_true(c->seg.min_volume_ml == 0);
    case_free(c);
    /* Without --min-volume, case.json records the bone-only floor that was used, not the full CT's. */
    rc = tu_run_cli(&out, "segment '%s' -o '%s' --force --whole-bone", ct, out_dir);
    if (rc != 0)
        fail_msg("rc %d: %s", rc, out);
    free(out);
    if (!(c = case_load(out_dir)))
        fail_msg("%s", fn_err_msg());
    assert_int_equal(c->nfrag, 1);
    if (c->seg.min_volume_ml != BONE_ONLY_MIN_ML)
        fail_msg("case.json says min_volume_ml %g, the floor used was %g", c->seg.min_volume_ml, BONE_ONLY_MIN_ML);
    case_free(c);
    vol_free(v);
    tu_rmtree(dir);
    free(dir);
}

/* A bone-only CT (0 outside): a bar 2..81 along x, 20 x 20 mm across, a cortex of 900 HU around
 * 60-70 HU, broken by `gaps` 1 mm gaps (none; at x = 42; at x = 28 and 56) but where the pieces
 * touch over 4 x 4 mm, each piece's cortex closed at the gap. */
static vol *broken_blocks(int gaps)
{
    const int at[3][2] = {{-9, -9}, {42, -9}, {28, 56}};
    vol *v = vol_new(84, 30, 30); /* most of it 0: a CT that holds only the bone */
    for (int k = 2; k < 22; k++)
        for (int j = 2; j < 22; j++)
            for (int i = 2; i < 82; i++) {
                int contact = j >= 10 && j < 14 && k >= 10 && k < 14, near = 0, gap = 0;
                for (int g = 0; g < 2; g++) {
                    gap |= i == at[gaps][g];
                    near |= abs(i - at[gaps][g]) <= 2;
                }
                int rim = i < 4 || j < 4 || k < 4 || j >= 20 || k >= 20 || i >= 80 || (near && !gap);
                if (gap && !contact)
                    continue; /* the fracture gap */
                v->data[vol_idx(v, i, j, k)] = rim && !contact ? 900 : 60 + (i < 42 ? 0 : 10);
            }
    return v;
}

/* segment --separate: with one seed per block, two fragments; a seed off the CT is refused naming
 * the point; automatically, the broken blocks split where the gap is, and the whole ones stay one
 * fragment. */
static void test_cli_separate(void **st)
{
    char *dir = tu_tmpdir("seg-separate"), ct[4300], out_dir[4300], *out = NULL;
    snprintf(ct, sizeof ct, "%s/bone.nii.gz", dir);
    snprintf(out_dir, sizeof out_dir, "%s/case", dir);
    vol *v = broken_blocks(1);
    assert_int_equal(volio_write(v, ct, VOL_I16), 0);
    vol_free(v);
    static const char *const how[2] = {"--seeds 20 12 12 60 12 12", ""};
    for (int h = 0; h < 2; h++) {
        int rc = tu_run_cli(&out, "segment '%s' -o '%s' --force --min-volume 0 --separate %s --json", ct, out_dir,
                            how[h]);
        if (rc != 0 || !strstr(out, "\"separated_fragments\": 1"))
            fail_msg("%s: rc %d: %s", how[h], rc, out);
        free(out);
        planning_case *c = case_load(out_dir);
        if (!c)
            fail_msg("%s", fn_err_msg());
        assert_int_equal(c->nfrag, 2);
        const vol *l = c->labels;
        assert_true(l->data[vol_idx(l, 5, 12, 12)] == l->data[vol_idx(l, 39, 5, 5)]);
        assert_true(l->data[vol_idx(l, 45, 5, 5)] == l->data[vol_idx(l, 78, 12, 12)]);
        assert_true(l->data[vol_idx(l, 5, 12, 12)] != l->data[vol_idx(l, 78, 12, 12)]);
        case_free(c);
    }
    int rc = tu_run_cli(&out, "segment '%s' -o '%s' --force --separate --seeds 10 12 12 31 12 99", ct, out_dir);
    if (rc != 1 || !strstr(out, "the seed (31.0, 12.0, 99.0) mm is outside the CT"))
        fail_msg("rc %d: %s", rc, out);
    free(out);
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s' --seeds 1 2 3", ct, out_dir), 2);
    free(out);
    v = broken_blocks(0);
    assert_int_equal(volio_write(v, ct, VOL_I16), 0);
    vol_free(v);
    rc = tu_run_cli(&out, "segment '%s' -o '%s' --force --min-volume 0 --separate --json", ct, out_dir);
    if (rc != 0 || !strstr(out, "\"separated_fragments\": 0"))
        fail_msg("rc %d: %s", rc, out);
    free(out);
    /* two breaks: the split is tried again on each piece it made */
    v = broken_blocks(2);
    assert_int_equal(volio_write(v, ct, VOL_I16), 0);
    vol_free(v);
    rc = tu_run_cli(&out, "segment '%s' -o '%s' --force --min-volume 0 --separate --json", ct, out_dir);
    if (rc != 0 || !strstr(out, "\"separated_fragments\": 2"))
        fail_msg("rc %d: %s", rc, out);
    free(out);
    tu_rmtree(dir);
    free(dir);
}

/* bench separate over a folder of one annotated pair (the broken blocks, label 1 and 2 either side
 * of the gap): the bone and both modes match; without a folder it says to give one. */
static void test_cli_bench_separate(void **st)
{
    char *dir = tu_tmpdir("bench-separate"), path[4300], *out = NULL;
    vol *v = broken_blocks(1), *mask = vol_new(v->dim[0], v->dim[1], v->dim[2]);
    for (int k = 0; k < v->dim[2]; k++)
        for (int j = 0; j < v->dim[1]; j++)
            for (int i = 0; i < v->dim[0]; i++)
                if (v->data[vol_idx(v, i, j, k)] != 0)
                    mask->data[vol_idx(mask, i, j, k)] = i < 42 ? 1 : 2;
    snprintf(path, sizeof path, "%s/001_XX.nii.gz", dir);
    assert_int_equal(volio_write(v, path, VOL_I16), 0);
    snprintf(path, sizeof path, "%s/001_XX_mask.nii.gz", dir);
    assert_int_equal(volio_write(mask, path, VOL_U8), 0);
    int rc = tu_run_cli(&out, "bench separate --json '%s'", dir);
    json_t *j = rc == 0 && strchr(out, '{') ? json_loads(strchr(out, '{'), 0, NULL) : NULL; /* after the progress */
    json_t *bone = json_array_get(json_object_get(j, "bones"), 0);
    if (!bone)
        fail_msg("rc %d: %s", rc, out);
    assert_true(json_real_value(json_object_get(bone, "bone_dice")) == 1.0);
    assert_true(json_real_value(json_object_get(json_object_get(bone, "seeded"), "fragment_dice_min")) >= 0.95);
    assert_int_equal(json_integer_value(json_object_get(json_object_get(bone, "automatic"), "fragments_found")), 2);
    assert_int_equal(json_integer_value(json_object_get(json_object_get(j, "pooled"), "intact_bones")), 0);
    /* the window's click of the second seed was measured (a number, not null) */
    assert_true(json_is_real(json_object_get(bone, "preview_seconds")));
    assert_true(json_real_value(json_object_get(bone, "preview_seconds")) >= 0);
    json_decref(j);
    free(out);
    /* --pelvis: the blocks as two bones of patient 002, each CT holding its own; added into one */
    vol *part = vol_new(v->dim[0], v->dim[1], v->dim[2]), *one = vol_new(v->dim[0], v->dim[1], v->dim[2]);
    for (int b = 0; b < 2; b++) {
        for (size_t i = 0; i < vol_count(v); i++) {
            int mine = (mask->data[i] == 1) == (b == 0) && mask->data[i] != 0;
            part->data[i] = mine ? v->data[i] : 0;
            one->data[i] = mine;
        }
        snprintf(path, sizeof path, "%s/002_%s.nii.gz", dir, b ? "XB" : "XA");
        assert_int_equal(volio_write(part, path, VOL_I16), 0);
        snprintf(path, sizeof path, "%s/002_%s_mask.nii.gz", dir, b ? "XB" : "XA");
        assert_int_equal(volio_write(one, path, VOL_U8), 0);
    }
    rc = tu_run_cli(&out, "bench separate --json --pelvis '%s'", dir);
    j = rc == 0 && strchr(out, '{') ? json_loads(strchr(out, '{'), 0, NULL) : NULL;
    json_t *bones = json_object_get(j, "bones"), *pelvis = json_array_get(bones, 1);
    if (json_array_size(bones) != 2 || !pelvis)
        fail_msg("rc %d: %s", rc, out);
    assert_string_equal(json_string_value(json_object_get(pelvis, "bone")), "002_pelvis");
    assert_int_equal(json_integer_value(json_object_get(pelvis, "fragments_annotated")), 2);
    assert_true(json_real_value(json_object_get(pelvis, "bone_dice")) == 1.0);
    json_t *each = json_object_get(json_object_get(pelvis, "automatic"), "fragment_dice");
    assert_int_equal(json_array_size(each), 2);
    assert_true(json_real_value(json_array_get(each, 1)) >= 0.95);
    json_decref(j);
    free(out);
    vol_free(part);
    vol_free(one);
    assert_int_equal(tu_run_cli(&out, "bench separate --json"), 2);
    assert_non_null(strstr(out, "give the folder of NNN_BONE.nii.gz and NNN_BONE_mask.nii.gz pairs"));
    free(out);
    vol_free(v);
    vol_free(mask);
    tu_rmtree(dir);
    free(dir);
}

static void test_cli_usage(void **st)
{
    char *out;
    assert_int_equal(tu_run_cli(&out, "segment --help"), 0);
    assert_non_null(strstr(out, "--exclude-below-peak"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "segment /nonexistent.nii.gz"), 2);
    assert_non_null(strstr(out, "fracnav segment: needs VOLUME and -o CASE"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "segment x.nii -o y --threshold lots"), 2);
    free(out);
    assert_int_equal(tu_run_cli(&out, "segment /nonexistent.nii.gz -o /tmp/never-made"), 1);
    assert_non_null(strstr(out, "fracnav segment: /nonexistent.nii.gz"));
    free(out);
}

static void test_prob_ramp(void **st)
{
    assert_int_equal(seg_prob(300, 300, 200), 128);
    assert_int_equal(seg_prob(400, 300, 200), 255);
    assert_int_equal(seg_prob(2000, 300, 200), 255);
    assert_int_equal(seg_prob(350, 300, 200), 191);
    assert_int_equal(seg_prob(-1000, 300, 200), 1); /* never 0 inside a fragment */
    assert_int_equal(seg_prob(-1000, 300, 0), 255);
}

static void test_eigen(void **st)
{
    double a[3][3] = {{4, 1, 0.5}, {1, 3, 0.2}, {0.5, 0.2, 1}}, v[3][3], l[3];
    frag_eigen_sym3(a, v, l);
    assert_true(l[0] >= l[1] && l[1] >= l[2]);
    for (int c = 0; c < 3; c++)
        for (int r = 0; r < 3; r++) {
            double av = a[r][0] * v[0][c] + a[r][1] * v[1][c] + a[r][2] * v[2][c];
            assert_true(fabs(av - l[c] * v[r][c]) < 1e-9);
        }
    double det = v[0][0] * (v[1][1] * v[2][2] - v[1][2] * v[2][1]) -
                 v[0][1] * (v[1][0] * v[2][2] - v[1][2] * v[2][0]) +
                 v[0][2] * (v[1][0] * v[2][1] - v[1][1] * v[2][0]);
    assert_true(fabs(det - 1) < 1e-9);
}

/* A bone as a CT that holds only the bone shows it: a 2-voxel cortex at 1000 HU around a cancellous
 * interior at 50 HU, far under the 300 HU threshold, all of it labelled. Every labelled voxel is
 * solid for the collision test at the case's default tau (a probability of at least one half), so
 * a piece pushed into the interior collides. Before, the interior was dropped: the collision test
 * saw the cortex alone, and on a real pelvic piece (005_RI, issue 25) a fit ended overlapping the
 * fixed piece's cancellous bone beyond its tolerance. */
static void test_labelled_interior_is_solid(void **st)
{
    (void)st;
    vol *lab = vol_new(24, 24, 24), *ct = vol_new(24, 24, 24);
    for (int k = 2; k < 22; k++)
        for (int j = 2; j < 22; j++)
            for (int i = 2; i < 22; i++) {
                int shell = i < 4 || j < 4 || k < 4 || i > 19 || j > 19 || k > 19;
                lab->data[vol_idx(lab, i, j, k)] = 1;
                ct->data[vol_idx(ct, i, j, k)] = shell ? 1000 : 50;
            }
    int lo[3] = {2, 2, 2}, hi[3] = {21, 21, 21};
    frag bone, chip;
    assert_int_equal(frag_from_labels(&bone, lab, ct, 1, lo, hi, 300, 200), 0);
    size_t n = (size_t)bone.dim[0] * bone.dim[1] * bone.dim[2], low = 0;
    for (size_t i = 0; i < n; i++)
        if (bone.prob[i]) {
            assert_true(bone.prob[i] >= FRAG_PROB_LABELLED);
            low += bone.prob[i] == FRAG_PROB_LABELLED;
        }
    assert_int_equal((int)bone.voxels, 20 * 20 * 20);
    assert_int_equal((int)low, 16 * 16 * 16); /* the interior, at the floor; the cortex at 255 */
    /* a solid 4^3 chip of its own, moved into the middle of the interior (4 voxels from the cortex) */
    vol_free(lab);
    lab = vol_new(24, 24, 24);
    for (int k = 2; k < 6; k++)
        for (int j = 2; j < 6; j++)
            for (int i = 2; i < 6; i++)
                lab->data[vol_idx(lab, i, j, k)] = 2;
    int clo[3] = {2, 2, 2}, chi[3] = {5, 5, 5};
    assert_int_equal(frag_from_labels(&chip, lab, NULL, 2, clo, chi, 300, 200), 0);
    pose in = POSE_IDENTITY, apart = POSE_IDENTITY;
    in.t[0] = in.t[1] = in.t[2] = 8;     /* voxels 10..13: inside the interior (4..19) */
    apart.t[0] = 30;                      /* beyond the bone */
    obb_params op = {CASE_TAU_MIN, CASE_TAU_MAX};
    obb_tree *tb = obb_tree_build(&bone, &op), *tc = obb_tree_build(&chip, &op);
    assert_non_null(tb);
    assert_non_null(tc);
    pose wb = pose_compose(bone.pose, bone.home), wi = pose_compose(in, chip.home), wa = pose_compose(apart, chip.home);
    obb_result r;
    assert_int_equal(obb_collide(tb, &wb, tc, &wi, NULL, NULL, &r), 0);
    assert_true(r.collides);
    assert_int_equal(obb_collide(tb, &wb, tc, &wa, NULL, NULL, &r), 0);
    assert_false(r.collides);
    obb_tree_free(tb);
    obb_tree_free(tc);
    frag_free(&bone);
    frag_free(&chip);
    vol_free(lab);
    vol_free(ct);
}

/* A fragment from a left-handed, oblique grid: home is a proper rotation, crop voxels land on their
 * source voxels, and the principal axis follows the bar's long side. */
static void test_fragment_geometry(void **st)
{
    vol *lab = vol_new(30, 20, 10);
    double c = sqrt(0.5);
    const double dir[3][3] = {{c, -c, 0}, {c, c, 0}, {0, 0, -1}}; /* det -1 */
    double sp[3] = {0.5, 0.8, 2}, org[3] = {10, -20, 30};
    vol_set_geometry(lab, dir, sp, org);
    for (int k = 3; k < 6; k++)
        for (int j = 5; j < 9; j++)
            for (int i = 2; i < 28; i++)
                lab->data[vol_idx(lab, i, j, k)] = 4;
    vol *ct = vol_new(30, 20, 10);
    for (size_t i = 0; i < vol_count(ct); i++)
        ct->data[i] = 350;
    int lo[3] = {2, 5, 3}, hi[3] = {27, 8, 5};
    frag f;
    assert_int_equal(frag_from_labels(&f, lab, ct, 4, lo, hi, 300, 200), 0);
    assert_int_equal(f.dim[0], 28);
    assert_int_equal(f.origin[0], 1);
    assert_int_equal((int)f.voxels, 26 * 4 * 3);
    assert_int_equal(f.flip[0], 1);
    assert_true(fabs(f.volume_ml - 312 * 0.8 / 1000) < 1e-9);
    double r[3][3];
    pose_to_matrix(&f.home, r);
    double det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) -
                 r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0]) +
                 r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
    assert_true(fabs(det - 1) < 1e-9);
    size_t li = 0, inside = 0;
    for (int k = 0; k < f.dim[2]; k++)
        for (int j = 0; j < f.dim[1]; j++)
            for (int i = 0; i < f.dim[0]; i++, li++) {
                int l[3] = {i, j, k}, s[3];
                double w[3], ws[3], sd[3];
                frag_local_to_source(&f, l, s);
                frag_voxel_world(&f, l, w);
                for (int a = 0; a < 3; a++)
                    sd[a] = s[a];
                vol_index_to_world(lab, sd, ws);
                for (int a = 0; a < 3; a++)
                    assert_true(fabs(w[a] - ws[a]) < 1e-9);
                int in = s[0] >= 0 && s[0] < 30 && s[1] >= 0 && s[1] < 20 && s[2] >= 0 && s[2] < 10 &&
                         lab->data[vol_idx(lab, s[0], s[1], s[2])] == 4;
                assert_int_equal(f.prob[li] != 0, in);
                if (in) {
                    assert_int_equal(f.prob[li], 191);
                    inside++;
                }
            }
    assert_int_equal((int)inside, 312);
    /* Centroid = world of the box centre; main axis = the grid's i direction (up to sign). */
    double mid[3] = {14.5, 6.5, 4}, wm[3];
    vol_index_to_world(lab, mid, wm);
    for (int a = 0; a < 3; a++)
        assert_true(fabs(f.centroid[a] - wm[a]) < 1e-9);
    assert_true(fabs(fabs(f.axes[0][0]) - c) < 1e-9 && fabs(fabs(f.axes[1][0]) - c) < 1e-9);
    double var_i = (26.0 * 26.0 - 1) / 12 * 0.25;
    assert_true(fabs(f.eigval[0] - var_i) < 1e-9);
    frag_free(&f);
    vol_free(lab);
    vol_free(ct);
}

static void test_example_ct_fragments(void **st)
{
    vol *ct = volio_read(tu_example_ct());
    assert_non_null(ct);
    seg_params p;
    seg_defaults(&p);
    seg_result r;
    assert_int_equal(seg_run(ct, &p, &r), 0);
    /* The skull and the two halves of the head holder. */
    assert_int_equal(r.ncomp, 3);
    assert_true(labs((long)r.comp[0].voxels - 403000) < 4000);
    for (int i = 1; i < 3; i++) {
        assert_true(labs((long)r.comp[i].voxels - 18500) < 500);
        assert_true(r.comp[i].peak < 1000 && r.comp[0].peak > 2000);
    }
    seg_result_free(&r);
    /* The holder goes with --exclude-below-peak. */
    p.exclude_peak = 1;
    p.exclude_below_peak = 1000;
    assert_int_equal(seg_run(ct, &p, &r), 0);
    assert_int_equal(r.ncomp, 1);
    assert_true(labs((long)r.comp[0].voxels - 403000) < 4000);
    seg_result_free(&r);
    vol_free(ct);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_components_corners_are_connected),
        cmocka_unit_test(test_components_join_late),
        cmocka_unit_test(test_otsu_splits_two_classes),
        cmocka_unit_test(test_filters),
        cmocka_unit_test(test_otsu_twice_finds_bone),
        cmocka_unit_test(test_otsu_ignores_nonfinite),
        cmocka_unit_test(test_all_nonfinite_refused),
        cmocka_unit_test(test_cli_nonfinite),
        cmocka_unit_test(test_cli_labels_import),
        cmocka_unit_test(test_cli_labels_seg_nrrd),
        cmocka_unit_test(test_cli_fill),
        cmocka_unit_test(test_cli_whole_bone),
        cmocka_unit_test(test_cli_separate),
        cmocka_unit_test(test_cli_bench_separate),
        cmocka_unit_test(test_cli_usage),
        cmocka_unit_test(test_prob_ramp),
        cmocka_unit_test(test_eigen),
        cmocka_unit_test(test_fragment_geometry),
        cmocka_unit_test(test_labelled_interior_is_solid),
        cmocka_unit_test(test_example_ct_fragments),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
