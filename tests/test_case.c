/* The case folder: save/load round trip, relative source paths, and the errors for a case that
 * no longer matches its files or is damaged. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "durable.h"
#include "err.h"
#include "obb.h"
#include "testutil.h"
#include "volio.h"

#include <jansson.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* Two bone blocks on an oblique 1.5 mm grid, written to path as int16 NIfTI. */
static void write_ct(const char *path, float bone)
{
    vol *v = vol_new(24, 16, 12);
    double c = 0.8, s = 0.6;
    const double dir[3][3] = {{c, -s, 0}, {s, c, 0}, {0, 0, 1}};
    double sp[3] = {1.5, 1.5, 1.5}, org[3] = {-10, 5, 20};
    vol_set_geometry(v, dir, sp, org);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = -1000;
    for (int k = 2; k < 10; k++)
        for (int j = 2; j < 14; j++) {
            for (int i = 2; i < 10; i++)
                v->data[vol_idx(v, i, j, k)] = bone;
            for (int i = 13; i < 21; i++)
                v->data[vol_idx(v, i, j, k)] = bone + 200;
        }
    if (volio_write(v, path, VOL_I16) < 0)
        fail_msg("%s", fn_err_msg());
    vol_free(v);
}

static planning_case *make_case(const char *dir, const char *src)
{
    vol *ct = volio_read(src);
    assert_non_null(ct);
    seg_params p;
    seg_defaults(&p);
    seg_result r;
    assert_int_equal(seg_run(ct, &p, &r), 0);
    assert_int_equal(r.ncomp, 2);
    vol *labels = r.labels;
    r.labels = NULL;
    seg_result_free(&r);
    planning_case *c = case_create(dir, src, ct, labels, &p);
    assert_non_null(c);
    return c;
}

/* A labelmap whose voxel is no whole label 0..65535 (1.5, -1, NaN, 70000) makes no case: the error
 * names the voxel and its value; a whole label past the background's plain zeros is taken. */
static void test_labels_not_whole_are_refused(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("case_badlabel"), src[4200], cdir[4300];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    write_ct(src, 1000);
    const float bad[] = {1.5f, -1.0f, NAN, 70000.0f};
    for (int b = 0; b < 5; b++) {
        vol *ct = volio_read(src), *labels = vol_new(ct->dim[0], ct->dim[1], ct->dim[2]);
        memcpy(labels->affine, ct->affine, sizeof labels->affine); /* the CT's grid */
        memcpy(labels->spacing, ct->spacing, sizeof labels->spacing);
        for (int k = 2; k < 10; k++)
            for (int j = 2; j < 14; j++)
                for (int i = 2; i < 10; i++)
                    labels->data[vol_idx(labels, i, j, k)] = 1;
        labels->data[vol_idx(labels, 5, 7, 3)] = b < 4 ? bad[b] : 2;
        seg_params p;
        seg_defaults(&p);
        snprintf(cdir, sizeof cdir, "%s/case%d", dir, b);
        planning_case *c = case_create(cdir, src, ct, labels, &p);
        if (b == 4) {
            if (!c)
                fail_msg("a whole label 2: %s", fn_err_msg());
            assert_int_equal(c->nfrag, 2);
            case_free(c);
            continue;
        }
        if (c)
            fail_msg("label %g was taken", (double)bad[b]);
        if (!strstr(fn_err_msg(), "voxel (5,7,3) holds") || !strstr(fn_err_msg(), "not a label 0..65535"))
            fail_msg("label %g: %s", (double)bad[b], fn_err_msg());
    }
    tu_rmtree(dir);
    free(dir);
}

static void test_round_trip(void **st)
{
    char *dir = tu_tmpdir("case"), src[4200], cdir[4200];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    write_ct(src, 700);
    planning_case *c = make_case(cdir, src);
    assert_int_equal(c->nfrag, 2);
    double ax[3] = {0, 0, 1};
    c->frag[1].pose = pose_from_axis_angle(ax, 0.3);
    c->frag[1].pose.t[0] = 4.25;
    snprintf(c->frag[0].name, sizeof c->frag[0].name, "occiput");
    c->fixed = 0;
    c->has_truth = 1;
    c->truth[1] = pose_inverse(c->frag[1].pose);
    c->tau_min = 0.25;
    assert_int_equal(case_save(c), 0);

    planning_case *d = case_load(cdir);
    if (!d)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(d->nfrag, 2);
    assert_string_equal(d->sha256, c->sha256);
    assert_string_equal(d->frag[0].name, "occiput");
    assert_int_equal(d->fixed, 0);
    assert_int_equal(d->nfixed_also, 0);
    assert_int_equal(d->has_truth, 1);
    assert_true(d->tau_min == 0.25);
    for (int i = 0; i < 2; i++) {
        assert_int_equal(d->frag[i].id, c->frag[i].id);
        assert_int_equal((int)d->frag[i].voxels, (int)c->frag[i].voxels);
        assert_memory_equal(d->frag[i].rgb, c->frag[i].rgb, 3);
        assert_memory_equal(d->frag[i].prob, c->frag[i].prob, (size_t)c->frag[i].dim[0] *
                                                                   c->frag[i].dim[1] * c->frag[i].dim[2]);
        assert_true(pose_angle_between(d->frag[i].pose, c->frag[i].pose) < 1e-9);
        assert_true(pose_distance(d->frag[i].pose, c->frag[i].pose) < 1e-9);
        assert_true(pose_distance(d->truth[i], c->truth[i]) < 1e-9);
        for (int a = 0; a < 3; a++)
            assert_true(fabs(d->frag[i].centroid[a] - c->frag[i].centroid[a]) < 1e-9);
    }
    /* Members other modules add to case.json survive a load and a save. */
    assert_non_null(d->extra);
    json_object_set_new(d->extra, "voi", json_pack("{s:[iii]}", "min", 1, 2, 3));
    json_object_set_new(d->extra, "version", json_integer(99)); /* not theirs: ignored */
    assert_int_equal(case_save(d), 0);
    planning_case *e = case_load(cdir);
    if (!e)
        fail_msg("%s", fn_err_msg());
    json_t *voi = json_object_get(e->extra, "voi");
    assert_int_equal(json_integer_value(json_array_get(json_object_get(voi, "min"), 2)), 3);
    /* both fixed: "fixed" lists them, the case's own first, and comes back so */
    uint8_t both[2] = {1, 1};
    case_set_fixed(e, both);
    assert_int_equal(case_save(e), 0);
    case_free(e);
    e = case_load(cdir);
    assert_non_null(e);
    assert_int_equal(e->fixed, 0);
    assert_true(case_is_fixed(e, 0) && case_is_fixed(e, 1));
    assert_int_equal(e->nfixed_also, 1);
    assert_int_equal(e->fixed_also[0], e->frag[1].id);
    case_free(e);
    /* The brighter block is 2 (same size, later in scan order), its probabilities saturate. */
    assert_int_equal(d->frag[1].prob[d->frag[1].dim[0] * d->frag[1].dim[1] + d->frag[1].dim[0] + 1], 255);
    case_free(c);
    case_free(d);
    tu_rmtree(dir);
    free(dir);
}

/* A source inside the case folder is stored relative, so the folder can move. */
static void test_folder_moves(void **st)
{
    char *dir = tu_tmpdir("case"), src[4200], cdir[4200], moved[4200];
    snprintf(cdir, sizeof cdir, "%s/a", dir);
    snprintf(src, sizeof src, "%s/a/ct.nii", dir);
    snprintf(moved, sizeof moved, "%s/b", dir);
    assert_int_equal(mkdir(cdir, 0755), 0);
    write_ct(src, 700);
    planning_case *c = make_case(cdir, src);
    assert_int_equal(case_save(c), 0);
    case_free(c);
    char *text = tu_slurp(strcat(strcpy(moved, cdir), "/case.json"), NULL);
    assert_non_null(strstr(text, "\"path\": \"ct.nii\""));
    free(text);
    snprintf(moved, sizeof moved, "%s/b", dir);
    assert_int_equal(rename(cdir, moved), 0);
    planning_case *d = case_load(moved);
    if (!d)
        fail_msg("%s", fn_err_msg());
    assert_int_equal(d->nfrag, 2);
    case_free(d);
    tu_rmtree(dir);
    free(dir);
}

/* Saves a case, applies `damage` to its case.json (as a jansson tree), and checks the load error. */
static void expect_load_error(void (*damage)(json_t *), int code, const char *want1, const char *want2)
{
    char *dir = tu_tmpdir("case"), src[4200], cdir[4200], json[4300];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    snprintf(json, sizeof json, "%s/case.json", cdir);
    write_ct(src, 700);
    planning_case *c = make_case(cdir, src);
    assert_int_equal(case_save(c), 0);
    case_free(c);
    json_t *root = json_load_file(json, 0, NULL);
    assert_non_null(root);
    damage(root);
    assert_int_equal(json_dump_file(root, json, JSON_INDENT(2)), 0);
    json_decref(root);
    assert_null(case_load(cdir));
    const char *msg = fn_err_msg();
    if (!strstr(msg, want1) || (want2 && !strstr(msg, want2)))
        fail_msg("error '%s' should mention '%s' and '%s'", msg, want1, want2 ? want2 : "");
    (void)code;
    tu_rmtree(dir);
    free(dir);
}

static void newer_version(json_t *r)
{
    json_object_set_new(r, "version", json_integer(CASE_VERSION + 1));
}

static void bad_quaternion(json_t *r)
{
    json_t *f = json_array_get(json_object_get(r, "fragments"), 1);
    json_object_set_new(json_object_get(f, "pose"), "q", json_string("identity"));
}

static void unit_quaternion_broken(json_t *r)
{
    json_t *f = json_array_get(json_object_get(r, "fragments"), 0);
    json_object_set_new(json_object_get(f, "pose"), "q", json_pack("[ffff]", 2.0, 0.0, 0.0, 0.0));
}

static void missing_tau(json_t *r)
{
    json_object_del(r, "tau_max");
}

static void unknown_fragment(json_t *r)
{
    json_t *f = json_array_get(json_object_get(r, "fragments"), 0);
    json_object_set_new(f, "id", json_integer(9));
}

static void wrong_geometry(json_t *r)
{
    json_t *aff = json_object_get(json_object_get(r, "source"), "affine");
    json_array_set_new(json_array_get(aff, 0), 3, json_real(-11));
}

static void duplicate_id(json_t *r)
{
    json_t *f = json_array_get(json_object_get(r, "fragments"), 1);
    json_object_set_new(f, "id", json_integer(1));
}

static void negative_ramp(json_t *r)
{
    json_object_set_new(json_object_get(r, "segmentation"), "ramp", json_real(-1));
}

static void long_source_path(json_t *r)
{
    char *p = malloc(5000);
    memset(p, 'a', 4999);
    p[0] = '/';
    p[4999] = '\0';
    json_object_set_new(json_object_get(r, "source"), "path", json_string(p));
    free(p);
}

static void long_relative_source_path(json_t *r)
{
    char *p = malloc(4081); /* fits alone, not after the case folder */
    for (int i = 0; i < 4080; i++)
        p[i] = i % 2 ? '/' : 'a';
    p[4080] = '\0';
    json_object_set_new(json_object_get(r, "source"), "path", json_string(p));
    free(p);
}

static void source_dev_zero(json_t *r)
{
    json_object_set_new(json_object_get(r, "source"), "path", json_string("/dev/zero"));
}

static void fixed_unknown(json_t *r)
{
    json_object_set_new(r, "fixed", json_pack("[ii]", 1, 9));
}

static void fixed_empty(json_t *r)
{
    json_object_set_new(r, "fixed", json_array());
}

static void fixed_not_ids(json_t *r)
{
    json_object_set_new(r, "fixed", json_pack("[is]", 1, "two"));
}

static void test_damaged_fields(void **st)
{
    expect_load_error(fixed_unknown, FN_EFORMAT, "field fixed", "names a fragment the case does not have");
    expect_load_error(fixed_empty, FN_EFORMAT, "field fixed", "array of 1..64");
    expect_load_error(fixed_not_ids, FN_EFORMAT, "field fixed", "integers in 1..65535");
    expect_load_error(duplicate_id, FN_EFORMAT, "fragments[1].id", "listed twice");
    expect_load_error(negative_ramp, FN_EFORMAT, "segmentation.ramp", ">= 0");
    expect_load_error(long_source_path, FN_EFORMAT, "source.path", "too long");
    expect_load_error(long_relative_source_path, FN_EFORMAT, "source.path", "too long");
    expect_load_error(source_dev_zero, FN_EIO, "/dev/zero", "not a regular file");
    expect_load_error(newer_version, FN_EMISMATCH, "version 2", "reads version 1");
    expect_load_error(bad_quaternion, FN_EFORMAT, "case.json", "fragments[1].pose.q");
    expect_load_error(unit_quaternion_broken, FN_EFORMAT, "fragments[0].pose.q", "unit");
    expect_load_error(missing_tau, FN_EFORMAT, "tau_max", "missing");
    expect_load_error(unknown_fragment, FN_EMISMATCH, "fragments[0].id", "not in labels");
    expect_load_error(wrong_geometry, FN_EMISMATCH, "affine [0][3]", "case.json");
}

static void test_changed_files(void **st)
{
    char *dir = tu_tmpdir("case"), src[4200], cdir[4200], path[4300];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    write_ct(src, 700);
    planning_case *c = make_case(cdir, src);
    assert_int_equal(case_save(c), 0);

    /* The source volume was replaced: the sha256 check says so and names it. */
    write_ct(src, 900);
    assert_null(case_load(cdir));
    assert_non_null(strstr(fn_err_msg(), "sha256"));
    assert_non_null(strstr(fn_err_msg(), "ct.nii.gz"));
    assert_non_null(strstr(fn_err_msg(), "changed"));
    write_ct(src, 700);
    planning_case *ok = case_load(cdir);
    assert_non_null(ok);
    case_free(ok);

    /* labels.nii.gz replaced behind the case's back (or an interrupted save). */
    snprintf(path, sizeof path, "%s/labels.nii.gz", cdir);
    c->labels->data[0] = 1;
    assert_int_equal(volio_write(c->labels, path, VOL_U16), 0);
    assert_null(case_load(cdir));
    assert_non_null(strstr(fn_err_msg(), "labels.nii.gz"));

    /* A truncated case.json: the parser's line and column, and the file. */
    snprintf(path, sizeof path, "%s/case.json", cdir);
    size_t len;
    char *text = tu_slurp(path, &len);
    tu_write_file(path, text, len / 2);
    free(text);
    assert_null(case_load(cdir));
    assert_non_null(strstr(fn_err_msg(), "case.json: line"));

    /* Not a case at all. */
    assert_null(case_load(dir));
    assert_non_null(strstr(fn_err_msg(), "not a case folder"));
    /* case.json a folder, the source a FIFO: refused at once, never read (or waited on). */
    char fifo[4300];
    snprintf(fifo, sizeof fifo, "%s/fifo", dir);
    assert_int_equal(mkfifo(fifo, 0600), 0);
    assert_int_equal(durable_file_sha256(fifo, path), FN_EIO);
    assert_non_null(strstr(fn_err_msg(), "not a regular file"));
    snprintf(path, sizeof path, "%s/case.json", cdir);
    unlink(path);
    assert_int_equal(mkdir(path, 0755), 0);
    assert_null(case_load(cdir));
    assert_non_null(strstr(fn_err_msg(), "not a regular file"));
    assert_null(strstr(fn_err_msg(), "expected"));
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* A crash between a save's two renames leaves the new labels beside the old case.json and the
 * labels that save kept: the case loads with the old, consistent pair, and labels.nii.gz is put
 * back. */
static void test_interrupted_save_recovers(void **st)
{
    char *dir = tu_tmpdir("case"), src[4200], cdir[4200], lab[4300], prev[4300];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    snprintf(lab, sizeof lab, "%s/labels.nii.gz", cdir);
    snprintf(prev, sizeof prev, "%s/labels.prev.nii.gz", cdir);
    write_ct(src, 700);
    planning_case *c = make_case(cdir, src);
    assert_int_equal(case_save(c), 0);
    assert_int_equal(case_save(c), 0);
    struct stat sb;
    assert_int_not_equal(stat(prev, &sb), 0); /* a finished save keeps nothing behind */

    size_t n;
    char *old = tu_slurp(lab, &n);
    tu_write_file(prev, old, n);
    size_t i0 = vol_idx(c->labels, 3, 3, 3);
    assert_true(c->labels->data[i0] != 0);
    c->labels->data[i0] = 0; /* the edit whose save was cut short */
    assert_int_equal(volio_write(c->labels, lab, VOL_U16), 0);

    planning_case *d = case_load(cdir);
    if (!d)
        fail_msg("%s", fn_err_msg());
    assert_true(d->labels->data[i0] != 0);
    assert_int_equal(d->nfrag, 2);
    case_free(d);
    size_t m;
    char *now = tu_slurp(lab, &m);
    assert_true(m == n && !memcmp(now, old, n));
    assert_int_not_equal(stat(prev, &sb), 0);
    free(now);

    /* Kept labels that match neither: refused as before, naming the file. */
    assert_int_equal(volio_write(c->labels, lab, VOL_U16), 0);
    assert_int_equal(volio_write(c->labels, prev, VOL_U16), 0);
    assert_null(case_load(cdir));
    assert_non_null(strstr(fn_err_msg(), "save was interrupted"));
    free(old);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* Truncations and byte changes all over case.json: never a crash, and every refusal names the file
 * it is about. */
static void test_corruption_battery(void **st)
{
    char *dir = tu_tmpdir("case"), src[4200], cdir[4200], json[4300];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    snprintf(json, sizeof json, "%s/case.json", cdir);
    write_ct(src, 700);
    planning_case *c = make_case(cdir, src);
    assert_int_equal(case_save(c), 0);
    case_free(c);
    size_t len;
    char *orig = tu_slurp(json, &len);
    char *buf = malloc(len);
    static const char subst[] = "x9\"}-[";
    int refused = 0, loaded = 0;
    for (size_t off = 0; off < len; off += 23) {
        for (int v = 0; v <= (int)strlen(subst); v++) {
            memcpy(buf, orig, len);
            size_t n = len;
            if (v == (int)strlen(subst))
                n = off;
            else
                buf[off] = subst[v];
            tu_write_file(json, buf, n);
            planning_case *d = case_load(cdir);
            if (d) {
                loaded++;
                case_free(d);
                continue;
            }
            refused++;
            const char *m = fn_err_msg();
            if (!strstr(m, "case.json") && !strstr(m, "labels") && !strstr(m, "ct.nii.gz"))
                fail_msg("offset %zu: error names no file: %s", off, m);
        }
    }
    assert_true(refused > 60);
    tu_write_file(json, orig, len);
    planning_case *d = case_load(cdir);
    assert_non_null(d);
    case_free(d);
    free(orig);
    free(buf);
    tu_rmtree(dir);
    free(dir);
}

/* The inode of path (0 when it cannot be read). */
static ino_t inode_of(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0 ? sb.st_ino : 0;
}

/* A save whose labels are unchanged writes case.json alone (labels.nii.gz stays the same file);
 * labels changed in memory, even without a rebuild, or a labels file changed behind the case's
 * back, or another folder, get their labels written, and each loads as saved. */
static void test_unchanged_labels_are_not_written(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("case_keep"), src[4200], cdir[4200], lab[4300], other[4300];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    snprintf(lab, sizeof lab, "%s/labels.nii.gz", cdir);
    write_ct(src, 700);
    planning_case *c = make_case(cdir, src);
    assert_int_equal(case_save(c), 0);
    ino_t first = inode_of(lab);
    assert_true(first != 0);
    c->frag[1].pose.t[0] = 2.5; /* a pose: only case.json changes */
    assert_int_equal(case_save(c), 0);
    assert_true(inode_of(lab) == first);
    planning_case *d = case_load(cdir);
    if (!d)
        fail_msg("%s", fn_err_msg());
    assert_true(d->frag[1].pose.t[0] == 2.5);
    d->frag[1].pose.t[1] = -1; /* a loaded case keeps its labels file too */
    assert_int_equal(case_save(d), 0);
    assert_true(inode_of(lab) == first);
    case_free(d);

    /* One voxel changed in memory, with no rebuild: written. */
    size_t i0 = vol_idx(c->labels, 3, 3, 3);
    assert_true(c->labels->data[i0] != 0);
    c->labels->data[i0] = 0;
    assert_int_equal(case_save(c), 0);
    assert_true(inode_of(lab) != first);
    d = case_load(cdir);
    if (!d)
        fail_msg("%s", fn_err_msg());
    assert_true(d->labels->data[i0] == 0);
    case_free(d);

    /* The file replaced behind the case's back (its sha256 is no longer the one saved): the save
     * writes the case's labels over it, and the case loads as saved. */
    c->labels->data[i0] = c->labels->data[vol_idx(c->labels, 3, 3, 4)];
    assert_int_equal(volio_write(c->labels, lab, VOL_U16), 0);
    c->labels->data[i0] = 0;
    assert_int_equal(case_save(c), 0);
    d = case_load(cdir);
    if (!d)
        fail_msg("%s", fn_err_msg());
    assert_true(d->labels->data[i0] == 0);
    case_free(d);

    /* Another folder: its labels are written there. */
    snprintf(c->dir, sizeof c->dir, "%s/moved", dir);
    snprintf(other, sizeof other, "%s/moved/labels.nii.gz", dir);
    assert_int_equal(case_save(c), 0);
    assert_true(inode_of(other) != 0);
    d = case_load(c->dir);
    if (!d)
        fail_msg("%s", fn_err_msg());
    assert_true(d->labels->data[i0] == 0);
    case_free(d);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* The overlap as a plain count over every voxel of a: 27 samples each, nearest voxel of b. */
static double overlap_every_voxel(const planning_case *c, int a, int b)
{
    const frag *A = &c->frag[a], *B = &c->frag[b];
    obb_params op = {c->tau_min, c->tau_max};
    pose rel = pose_compose(pose_inverse(pose_compose(B->pose, B->home)), pose_compose(A->pose, A->home));
    double R[3][3];
    pose_to_matrix(&rel, R);
    long hits = 0;
    for (int k = 0; k < A->dim[2]; k++)
        for (int j = 0; j < A->dim[1]; j++)
            for (int i = 0; i < A->dim[0]; i++) {
                if (!obb_effective_prob(A->prob[((size_t)k * A->dim[1] + j) * A->dim[0] + i], &op))
                    continue;
                for (int s = 0; s < 27; s++) {
                    double l[3] = {(i + (s % 3 - 1) / 3.0) * A->spacing[0], (j + (s / 3 % 3 - 1) / 3.0) * A->spacing[1],
                                   (k + (s / 9 - 1) / 3.0) * A->spacing[2]};
                    long v[3];
                    int in = 1;
                    for (int r = 0; r < 3; r++) {
                        v[r] = lround((R[r][0] * l[0] + R[r][1] * l[1] + R[r][2] * l[2] + rel.t[r]) / B->spacing[r]);
                        in &= v[r] >= 0 && v[r] < B->dim[r];
                    }
                    hits += in && obb_effective_prob(B->prob[(v[2] * B->dim[1] + v[1]) * B->dim[0] + v[0]], &op);
                }
            }
    return hits * A->spacing[0] * A->spacing[1] * A->spacing[2] * 1e-3 / 27;
}

/* The two blocks' case (write_ct at 700 HU, make_case) in a new tu_tmpdir tagged tag (*dir, to
 * remove and free). */
static planning_case *blocks_case(const char *tag, char **dir)
{
    char src[4200], cdir[4200];
    *dir = tu_tmpdir(tag);
    snprintf(src, sizeof src, "%s/ct.nii.gz", *dir);
    snprintf(cdir, sizeof cdir, "%s/case", *dir);
    write_ct(src, 700);
    return make_case(cdir, src);
}

/* The axes the overlap tests turn block 2 about. */
static const double turn_axes[4][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {0.6, -0.48, 0.64}};

/* case_overlap_ml looks only where b can be: at poses that push one block into the other, turned
 * about each axis, it counts what a count over every voxel counts. */
static void test_overlap_counts_every_voxel(void **st)
{
    (void)st;
    char *dir;
    planning_case *c = blocks_case("case_overlap", &dir);
    int some = 0;
    for (int p = 0; p < 12; p++) {
        c->frag[1].pose = pose_from_axis_angle(turn_axes[p % 4], (p - 6) * 0.11);
        /* block 2 lies 4.5 mm along the CT's i axis from block 1 (13-10 voxels apart, 1.5 mm) */
        c->frag[1].pose.t[0] = -(c->frag[1].centroid[0] - c->frag[0].centroid[0]) * (0.3 + 0.1 * p);
        c->frag[1].pose.t[1] = -(c->frag[1].centroid[1] - c->frag[0].centroid[1]) * (0.3 + 0.1 * p);
        for (int a = 0; a < 2; a++) {
            double want = overlap_every_voxel(c, a, 1 - a), got = case_overlap_ml(c, a, 1 - a);
            if (fabs(want - got) > 1e-12)
                fail_msg("pose %d, fragment %d in %d: %.9f ml, every voxel counted %.9f", p, a, 1 - a, got, want);
            some += want > 0;
        }
    }
    assert_true(some >= 12);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* The penetration check after a fit builds hierarchies of the parts of each fragment that can reach
 * the other: it answers as hierarchies of the whole fragments do, pose by pose (apart, touching,
 * inside each other), turned about four axes. */
static void test_penetrating_as_whole_trees(void **st)
{
    (void)st;
    char *dir;
    planning_case *c = blocks_case("case_pen", &dir);
    obb_params op = {c->tau_min, c->tau_max};
    obb_tree *t0 = obb_tree_build(&c->frag[0], &op), *t1 = obb_tree_build(&c->frag[1], &op);
    assert_non_null(t0);
    assert_non_null(t1);
    int hits = 0, misses = 0;
    for (int p = 0; p < 40; p++) {
        c->frag[1].pose = pose_from_axis_angle(turn_axes[p % 4], (p % 9 - 4) * 0.07);
        double f = 0.05 * p - 0.5; /* from inside block 1 to well apart */
        for (int a = 0; a < 3; a++)
            c->frag[1].pose.t[a] = -(c->frag[1].centroid[a] - c->frag[0].centroid[a]) * f;
        pose w0 = pose_compose(c->frag[0].pose, c->frag[0].home), w1 = pose_compose(c->frag[1].pose, c->frag[1].home);
        obb_result r;
        assert_int_equal(obb_collide(t0, &w0, t1, &w1, NULL, NULL, &r), 0);
        int got = case_penetrating(c, NULL, NULL, 0);
        assert_true(got >= 0);
        if (got != r.collides)
            fail_msg("pose %d: the parts' hierarchies say %d, the whole fragments' %d", p, got, r.collides);
        hits += r.collides != 0;
        misses += !r.collides;
    }
    assert_true(hits >= 5 && misses >= 5);
    obb_tree_free(t0);
    obb_tree_free(t1);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_round_trip),
        cmocka_unit_test(test_labels_not_whole_are_refused),
        cmocka_unit_test(test_folder_moves),
        cmocka_unit_test(test_damaged_fields),
        cmocka_unit_test(test_changed_files),
        cmocka_unit_test(test_corruption_battery),
        cmocka_unit_test(test_interrupted_save_recovers),
        cmocka_unit_test(test_unchanged_labels_are_not_written),
        cmocka_unit_test(test_overlap_counts_every_voxel),
        cmocka_unit_test(test_penetrating_as_whole_trees),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
