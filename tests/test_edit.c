/* Manual corrections: merge, split, erase, keep/drop, fix, bad ids, and atomic saves. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "err.h"
#include "testutil.h"
#include "volio.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* Three separate blocks on a 1 mm grid (world = index + origin): 1000, 400 and 80 voxels. */
static void write_ct(const char *path)
{
    vol *v = vol_new(40, 30, 20);
    static const double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    double sp[3] = {1, 1, 1}, org[3] = {100, 200, 300};
    vol_set_geometry(v, dir, sp, org);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = -1000;
    for (int k = 2; k < 12; k++)
        for (int j = 2; j < 12; j++)
            for (int i = 2; i < 12; i++)
                v->data[vol_idx(v, i, j, k)] = 1200;
    for (int k = 2; k < 6; k++)
        for (int j = 2; j < 12; j++)
            for (int i = 20; i < 30; i++)
                v->data[vol_idx(v, i, j, k)] = 900;
    for (int k = 14; k < 18; k++)
        for (int j = 20; j < 25; j++)
            for (int i = 30; i < 34; i++)
                v->data[vol_idx(v, i, j, k)] = 500;
    if (volio_write(v, path, VOL_I16) < 0)
        fail_msg("%s", fn_err_msg());
    vol_free(v);
}

struct fixture {
    char *tmp;
    char cdir[4200];
};

static int setup(void **st)
{
    struct fixture *f = calloc(1, sizeof *f);
    f->tmp = tu_tmpdir("edit");
    char src[4200];
    snprintf(src, sizeof src, "%s/ct.nii.gz", f->tmp);
    snprintf(f->cdir, sizeof f->cdir, "%s/case", f->tmp);
    write_ct(src);
    tu_segment(src, f->cdir, "");
    *st = f;
    return 0;
}

static int edit(const struct fixture *f, char **out, const char *args)
{
    return tu_run_cli(out, "edit '%s' %s", f->cdir, args);
}

static void test_merge_and_bad_ids(void **st)
{
    struct fixture *f = *st;
    char *out;
    assert_int_equal(edit(f, &out, "merge 1 3"), 0);
    free(out);
    planning_case *c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 2);
    assert_int_equal((int)c->frag[0].voxels, 1080);
    assert_int_equal(c->frag[1].id, 2);
    case_free(c);
    assert_int_equal(edit(f, &out, "merge 1 9"), 1);
    assert_non_null(strstr(out, "fracnav edit: no fragment 9 (the case has 1, 2)"));
    free(out);
    assert_int_equal(edit(f, &out, "drop 4"), 1);
    free(out);
    assert_int_equal(edit(f, &out, "merge 1"), 2);
    free(out);
    assert_int_equal(edit(f, &out, "shatter 1"), 2);
    free(out);
    assert_int_equal(tu_run_cli(&out, "edit --help"), 0);
    assert_non_null(strstr(out, "erase-sphere"));
    free(out);
}

static void test_split(void **st)
{
    struct fixture *f = *st;
    char *out;
    /* x = 105.5 halves block 1 (x 102..111): the part with x > 105.5 becomes fragment 4. */
    assert_int_equal(edit(f, &out, "split 1 --plane 105.5 0 0 1 0 0"), 0);
    assert_non_null(strstr(out, "fragment 4"));
    free(out);
    planning_case *c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 4);
    int i1 = case_find(c, 1), i4 = case_find(c, 4);
    assert_int_equal((int)c->frag[i1].voxels, 400);
    assert_int_equal((int)c->frag[i4].voxels, 600);
    assert_true(c->frag[i4].centroid[0] > 105.5 && c->frag[i1].centroid[0] < 105.5);
    assert_memory_not_equal(c->frag[i1].rgb, c->frag[i4].rgb, 3);
    case_free(c);
    /* A plane that misses the fragment is refused and changes nothing. */
    assert_int_equal(edit(f, &out, "split 2 --plane 0 0 0 1 0 0"), 1);
    assert_non_null(strstr(out, "one side"));
    free(out);
    c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 4);
    case_free(c);
}

static void test_erase_keep_drop_fix(void **st)
{
    struct fixture *f = *st;
    char *out;
    /* The box x 100..104.9 covers block 1's columns 2..4: 3 x 10 x 10 voxels. */
    assert_int_equal(edit(f, &out, "erase-box 100 200 300 104.9 240 330"), 0);
    assert_non_null(strstr(out, "erased 300 voxels"));
    free(out);
    /* A sphere around block 2's centre, limited to fragment 1: erases nothing there. */
    assert_int_equal(edit(f, &out, "erase-sphere 124.5 206.5 303.5 3 --id 1"), 0);
    assert_non_null(strstr(out, "erased 0 voxels"));
    free(out);
    assert_int_equal(edit(f, &out, "erase-sphere 124.5 206.5 303.5 1.5"), 0);
    assert_non_null(strstr(out, "erased 8 voxels"));
    free(out);
    planning_case *c = tu_case_load(f->cdir);
    assert_int_equal((int)c->frag[0].voxels, 700);
    assert_int_equal((int)c->frag[1].voxels, 392);
    case_free(c);

    assert_int_equal(edit(f, &out, "fix 2"), 0);
    free(out);
    assert_int_equal(edit(f, &out, "drop 3"), 0);
    free(out);
    c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 2);
    assert_int_equal(c->frag[c->fixed].id, 2);
    case_free(c);
    assert_int_equal(edit(f, &out, "keep 1"), 0);
    free(out);
    c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 1);
    assert_int_equal(c->fixed, -1); /* the fixed fragment went with the drop */
    case_free(c);
}

/* Region growing brings a dropped block back, as a new fragment or into an existing one. */
static void test_grow(void **st)
{
    struct fixture *f = *st;
    char *out;
    assert_int_equal(edit(f, &out, "drop 3"), 0);
    free(out);
    assert_int_equal(edit(f, &out, "grow 131 222 315"), 0);
    assert_non_null(strstr(out, "grew fragment 3 to 80 voxels"));
    free(out);
    assert_int_equal(edit(f, &out, "grow 131 222 315"), 1);
    assert_non_null(strstr(out, "belongs to fragment 3 already"));
    free(out);
    assert_int_equal(edit(f, &out, "grow 101 201 301"), 1); /* air at the grid's corner */
    assert_non_null(strstr(out, "under the threshold 300"));
    free(out);
    assert_int_equal(edit(f, &out, "grow 0 0 0"), 1);
    assert_non_null(strstr(out, "outside the volume"));
    free(out);
    assert_int_equal(edit(f, &out, "drop 3"), 0);
    free(out);
    /* A threshold above the block's 500 HU finds nothing to grow from. */
    assert_int_equal(edit(f, &out, "grow 131 222 315 --threshold 600 --into 1"), 1);
    free(out);
    assert_int_equal(edit(f, &out, "grow 131 222 315 --into 1"), 0);
    free(out);
    planning_case *c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 2);
    assert_int_equal((int)c->frag[0].voxels, 1080);
    case_free(c);
    assert_int_equal(edit(f, &out, "grow 131 222"), 2);
    free(out);
}

/* separate from seeds on the command line and from a seed file; the same point given twice is
 * refused, naming it, and nothing is saved. */
static void test_separate_seeds(void **st)
{
    struct fixture *f = *st;
    char *out, seeds[4300];
    assert_int_equal(edit(f, &out, "separate 1 --seeds 105 205 305 105 205 305"), 1);
    if (!strstr(out, "the seeds (105.0, 205.0, 305.0) and (105.0, 205.0, 305.0) mm fall in one voxel"))
        fail_msg("%s", out);
    free(out);
    assert_int_equal(edit(f, &out, "separate 1 --seeds 105 205 305"), 0);
    assert_non_null(strstr(out, "fragment 1 stays one piece (from 1 seed)"));
    free(out);
    snprintf(seeds, sizeof seeds, "%s/seeds.txt", f->tmp);
    const char *bad = "1 103 203 303\n1 104 204 303\nthree 110 210 310\n", *good = "1 103 203 303\n1 104 204 "
                                                                               "303\n2 110 210 310\n";
    tu_write_file(seeds, bad, strlen(bad));
    char args[4400];
    snprintf(args, sizeof args, "separate 1 --seed-file '%s'", seeds);
    assert_int_equal(edit(f, &out, args), 1);
    if (!strstr(out, "seeds.txt: line 3: expected PIECE X Y Z"))
        fail_msg("%s", out);
    free(out);
    planning_case *c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 3);
    case_free(c);
    tu_write_file(seeds, good, strlen(good));
    assert_int_equal(edit(f, &out, args), 0);
    if (!strstr(out, "separated fragment 1 into 2 pieces (new fragments 4; from 3 seeds)"))
        fail_msg("%s", out);
    free(out);
    c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 4);
    assert_int_equal((int)(c->frag[0].voxels + c->frag[3].voxels), 1000);
    case_free(c);
}

/* A save that cannot complete leaves the previous case byte for byte. */
static void test_failed_save_keeps_case(void **st)
{
    struct fixture *f = *st;
    char json[4300], labels[4300], block[4300];
    snprintf(json, sizeof json, "%s/case.json", f->cdir);
    snprintf(labels, sizeof labels, "%s/labels.nii.gz", f->cdir);
    snprintf(block, sizeof block, "%s/labels.prev.nii.gz", f->cdir);
    size_t jn, ln;
    char *j0 = tu_slurp(json, &jn), *l0 = tu_slurp(labels, &ln);
    /* A folder where the previous labels are kept makes the save fail after both files are
     * written aside, before any rename. */
    assert_int_equal(mkdir(block, 0755), 0);
    char *out;
    assert_int_equal(edit(f, &out, "merge 1 2"), 1);
    assert_non_null(strstr(out, "fracnav edit: saving case"));
    free(out);
    size_t jn1, ln1;
    char *j1 = tu_slurp(json, &jn1), *l1 = tu_slurp(labels, &ln1);
    assert_true(jn1 == jn && !memcmp(j0, j1, jn));
    assert_true(ln1 == ln && !memcmp(l0, l1, ln));
    planning_case *c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 3);
    case_free(c);
    rmdir(block);
    assert_int_equal(edit(f, &out, "merge 1 2"), 0);
    free(out);
    c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 2);
    case_free(c);
    free(j0);
    free(l0);
    free(j1);
    free(l1);
}

/* An empty result is an error: an edit that would leave no fragment exits 1, says what it found,
 * and saves nothing (the case stays as it was); an export of a case with no fragment (one the API
 * emptied) exits 1 and writes nothing. Before, both exited 0: an empty case, blank pictures. */
static void test_empty_result_refused(void **st)
{
    struct fixture *f = *st;
    char json[4300], labels[4300], out_dir[4300];
    snprintf(json, sizeof json, "%s/case.json", f->cdir);
    snprintf(labels, sizeof labels, "%s/labels.nii.gz", f->cdir);
    size_t jn, ln;
    char *j0 = tu_slurp(json, &jn), *l0 = tu_slurp(labels, &ln);
    tu_expect_cli(1, "fracnav edit: erase-box would leave no fragment: the case's 3 fragments (1480 voxels) all went",
                  "edit '%s' erase-box 0 0 0 1000 1000 1000", f->cdir);
    tu_expect_cli(1, "fracnav edit: drop would leave no fragment", "edit '%s' drop 1 2 3", f->cdir);
    /* a refused edit says nothing of what it would have made (it printed "0 fragments left") */
    char *said = NULL;
    assert_int_equal(tu_run_cli(&said, "edit '%s' drop 1 2 3", f->cdir), 1);
    if (strstr(said, "fragments left") || strstr(said, "erased"))
        fail_msg("a refused edit said what it made: %s", said);
    free(said);
    size_t jn1, ln1;
    char *j1 = tu_slurp(json, &jn1), *l1 = tu_slurp(labels, &ln1);
    assert_true(jn1 == jn && !memcmp(j0, j1, jn));
    assert_true(ln1 == ln && !memcmp(l0, l1, ln));
    free(j0);
    free(l0);
    free(j1);
    free(l1);

    planning_case *c = tu_case_load(f->cdir);
    int ids[3] = {1, 2, 3};
    assert_int_equal(case_drop(c, ids, 3), 0);
    assert_int_equal(c->nfrag, 0);
    assert_int_equal(case_save(c), 0);
    case_free(c);
    tu_expect_cli(1, "holds no fragment (its labelmap labels no voxel): nothing to fix", "edit '%s' fix 0", f->cdir);
    snprintf(out_dir, sizeof out_dir, "%s/exported", f->tmp);
    tu_expect_cli(1, "holds no fragment (its labelmap labels no voxel): nothing to export",
                  "export '%s' --all '%s'", f->cdir, out_dir);
    assert_int_not_equal(access(out_dir, F_OK), 0);
}

/* The same edits through the API, as other modules use them. */
static void test_api(void **st)
{
    struct fixture *f = *st;
    planning_case *c = tu_case_load(f->cdir);
    double p[3] = {0, 0, 307}, n[3] = {0, 0, 1};
    int id = case_split(c, 1, p, n);
    assert_int_equal(id, 4);
    assert_int_equal((int)c->frag[case_find(c, 4)].voxels, 400);
    assert_int_equal(case_merge(c, 4, 4), FN_EINVAL);
    assert_int_equal(case_merge(c, 1, 4), 0);
    assert_int_equal((int)c->frag[0].voxels, 1000);
    int ids[2] = {1, 3};
    assert_int_equal(case_keep(c, ids, 2), 0);
    assert_int_equal(c->nfrag, 2);
    assert_int_equal(case_fix(c, 2), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "no fragment 2 (the case has 1, 3)"));
    case_free(c);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_merge_and_bad_ids, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_split, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_erase_keep_drop_fix, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_grow, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_separate_seeds, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_failed_save_keeps_case, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_api, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_empty_result_refused, setup, tu_fixture_teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
