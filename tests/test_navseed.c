/* The window's seed mode saves its separation as an undoable edit that survives a crash (issue
 * 25): case_save_undoable / case_undo, and navigate's recovery of a separation that a crash
 * interrupted (CASE/separation, the seeds written before the separation, see navseed.h). */
#include "case.h"
#include "durable.h"
#include "err.h"
#include "frag.h"

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "testutil.h"

/* A two-blocks case (tu_two_blocks_case) and its labels as made, to compare with after an undo. */
typedef struct blocks {
    char *dir;
    char case_dir[4200];
    float *labels;
    size_t n;
    double b[3]; /* block B's centroid (fragment 2) */
} blocks;

static void blocks_make(blocks *k, const char *tag)
{
    k->dir = tu_tmpdir(tag);
    tu_two_blocks_case(k->dir, k->case_dir, sizeof k->case_dir);
    planning_case *c = case_load(k->case_dir);
    assert_non_null(c);
    assert_int_equal(c->nfrag, 2);
    k->n = vol_count(c->labels);
    k->labels = malloc(k->n * sizeof *k->labels);
    memcpy(k->labels, c->labels->data, k->n * sizeof *k->labels);
    memcpy(k->b, c->frag[case_find(c, 2)].centroid, sizeof k->b);
    case_free(c);
}

static void blocks_free(blocks *k)
{
    tu_rmtree(k->dir);
    free(k->dir);
    free(k->labels);
}

/* The case's fragment count, and whether its labels are the ones it was made with. */
static int fragments(const blocks *k, int *as_made)
{
    planning_case *c = case_load(k->case_dir);
    assert_non_null(c);
    int n = c->nfrag;
    *as_made = !memcmp(c->labels->data, k->labels, k->n * sizeof *k->labels);
    case_free(c);
    return n;
}

/* CASE/separation as navseed_separate writes it before it separates: a line naming case.json's
 * sha256 (that of sha_of, a file), then PIECE X Y Z per seed: B's left and right parts. */
static void write_pending(const blocks *k, const char *sha_of)
{
    char sha[65], path[4300], text[512];
    assert_int_equal(durable_file_sha256(sha_of, sha), 0);
    int len = snprintf(text, sizeof text, "# fracnav navigate: a separation of case.json sha256 %s\n"
                       "1 %.3f %.3f %.3f\n2 %.3f %.3f %.3f\n", sha, k->b[0] - 3, k->b[1], k->b[2], k->b[0] + 3,
                       k->b[1], k->b[2]);
    snprintf(path, sizeof path, "%s/separation", k->case_dir);
    tu_write_file(path, text, (size_t)len);
}

/* navigate over the case for a moment, in the terminal view (its stderr into *out). */
static int navigate(const blocks *k, char **out)
{
    return tu_run_cli(out, "navigate '%s' --device keyboard:/dev/null --view terminal --discard-journal "
                      "--duration 0.2 </dev/null", k->case_dir);
}

/* A kill -9 after Enter, once the seeds are written and before the separated case is saved,
 * leaves the case as it was and CASE/separation: the next navigate recovers the separation (B in
 * two), saves it as an undoable edit and removes the file; case_undo then brings the case back as
 * it was made, one fragment for B, and there is nothing more to undo. */
static void test_crash_after_enter_is_recovered_and_undone(void **st)
{
    (void)st;
    blocks k;
    blocks_make(&k, "navseed-recover");
    char json[4300], pending[4300], *out = NULL;
    snprintf(json, sizeof json, "%s/case.json", k.case_dir);
    snprintf(pending, sizeof pending, "%s/separation", k.case_dir);
    write_pending(&k, json);
    int rc = navigate(&k, &out);
    if (rc != 0 || !strstr(out, "recovered a separation interrupted by a crash: 1 new fragment, 3 in all"))
        fail_msg("navigate after a crash past Enter: exit %d: %s", rc, out);
    free(out);
    int as_made;
    assert_int_equal(fragments(&k, &as_made), 3);
    assert_int_not_equal(access(pending, F_OK), 0);
    assert_int_equal(case_undo_steps(k.case_dir), 1);
    assert_int_equal(case_undo(k.case_dir), 1);
    assert_int_equal(fragments(&k, &as_made), 2);
    assert_true(as_made);
    assert_int_equal(case_undo_steps(k.case_dir), 0);
    assert_int_equal(case_undo(k.case_dir), 0);
    blocks_free(&k);
}

/* A kill -9 after the separated case was saved, before CASE/separation was removed: the file
 * names the case.json that was, so the next navigate removes it and separates nothing again. */
static void test_separation_file_of_another_case_json_is_dropped(void **st)
{
    (void)st;
    blocks k;
    blocks_make(&k, "navseed-stale");
    char other[4300], pending[4300], *out = NULL;
    snprintf(other, sizeof other, "%s/blocks.nii.gz", k.dir);
    snprintf(pending, sizeof pending, "%s/separation", k.case_dir);
    write_pending(&k, other);
    int rc = navigate(&k, &out);
    if (rc != 0 || strstr(out, "recovered"))
        fail_msg("navigate with a stale separation file: exit %d: %s", rc, out);
    free(out);
    int as_made;
    assert_int_equal(fragments(&k, &as_made), 2);
    assert_true(as_made);
    assert_int_not_equal(access(pending, F_OK), 0);
    blocks_free(&k);
}

/* A separation file for this case.json whose seed lines do not parse (a hand-edited or hostile
 * file): navigate names the file and the line, opens the case as it is, and keeps the file. */
static void test_garbled_separation_file_is_named_and_kept(void **st)
{
    (void)st;
    blocks k;
    blocks_make(&k, "navseed-garbled");
    char json[4300], sha[65], pending[4300], text[256], *out = NULL;
    snprintf(json, sizeof json, "%s/case.json", k.case_dir);
    snprintf(pending, sizeof pending, "%s/separation", k.case_dir);
    assert_int_equal(durable_file_sha256(json, sha), 0);
    int len = snprintf(text, sizeof text, "# fracnav navigate: a separation of case.json sha256 %s\n"
                       "1 nan-ish 2 3\n", sha);
    tu_write_file(pending, text, (size_t)len);
    int rc = navigate(&k, &out);
    if (rc != 0 || !strstr(out, "not recovered") || !strstr(out, "separation: line 2"))
        fail_msg("navigate with a garbled separation file: exit %d: %s", rc, out);
    free(out);
    int as_made;
    assert_int_equal(fragments(&k, &as_made), 2);
    assert_true(as_made);
    assert_int_equal(access(pending, F_OK), 0);
    blocks_free(&k);
}

/* An undo step equal to the case as it is (what a crash leaves after the step was kept, before
 * the save) is dropped, never applied; a step kept by case_save_undoable before an edit takes that
 * edit back. */
static void test_undo_step_equal_to_the_case_is_dropped(void **st)
{
    (void)st;
    blocks k;
    blocks_make(&k, "navseed-undo");
    char from[4300], to[4400];
    const char *files[] = {"labels.nii.gz", "case.json"};
    for (int i = 0; i < 2; i++) {
        snprintf(from, sizeof from, "%s/%s", k.case_dir, files[i]);
        snprintf(to, sizeof to, "%s/undo.1.%s", k.case_dir, files[i]);
        assert_int_equal(link(from, to), 0);
    }
    assert_int_equal(case_undo_steps(k.case_dir), 0);
    assert_int_not_equal(access(to, F_OK), 0);
    planning_case *c = case_load(k.case_dir);
    assert_non_null(c);
    assert_int_equal(case_merge(c, 1, 2), 0);
    assert_int_equal(case_save_undoable(c), 0);
    case_free(c);
    int as_made;
    assert_int_equal(fragments(&k, &as_made), 1);
    assert_int_equal(case_undo_steps(k.case_dir), 1);
    assert_int_equal(case_undo(k.case_dir), 1);
    assert_int_equal(fragments(&k, &as_made), 2);
    assert_true(as_made);
    blocks_free(&k);
}

/* A separation's undo brings back the case before it: once anything was saved since (poses moved
 * in a later session, an edit, a fit), the separation is no longer undone, so that is never lost. */
static void test_undo_never_loses_a_later_save(void **st)
{
    (void)st;
    blocks k;
    blocks_make(&k, "navseed-later");
    planning_case *c = case_load(k.case_dir);
    assert_non_null(c);
    case_seed seeds[2] = {{{k.b[0] - 3, k.b[1], k.b[2]}, 1}, {{k.b[0] + 3, k.b[1], k.b[2]}, 2}};
    assert_int_equal(case_separate_all(c, seeds, 2), 1);
    assert_int_equal(case_save_undoable(c), 0);
    assert_int_equal(case_undo_steps(k.case_dir), 1);
    c->frag[case_find(c, 3)].pose.t[0] += 5; /* a move, saved */
    assert_int_equal(case_save(c), 0);
    case_free(c);
    assert_int_equal(case_undo_steps(k.case_dir), 0);
    assert_int_equal(case_undo(k.case_dir), 0);
    c = case_load(k.case_dir);
    assert_non_null(c);
    assert_int_equal(c->nfrag, 3);
    assert_true(c->frag[case_find(c, 3)].pose.t[0] != 0);
    case_free(c);
    blocks_free(&k);
}

/* The undo steps lie in the case folder itself, which stays flat: segment --force replaces a case
 * that holds one whole, leaving nothing aside. */
static void test_force_replaces_a_case_with_undo_steps(void **st)
{
    (void)st;
    blocks k;
    blocks_make(&k, "navseed-force");
    planning_case *c = case_load(k.case_dir);
    assert_non_null(c);
    assert_int_equal(case_merge(c, 1, 2), 0);
    assert_int_equal(case_save_undoable(c), 0);
    case_free(c);
    assert_int_equal(case_undo_steps(k.case_dir), 1);
    char *out = NULL;
    int rc = tu_run_cli(&out, "segment '%s/blocks.nii.gz' -o '%s' --force --min-volume 0 --ramp 0", k.dir,
                        k.case_dir);
    if (rc != 0 || strstr(out, "stays in"))
        fail_msg("segment --force over a case with an undo step: exit %d: %s", rc, out);
    free(out);
    assert_int_equal(case_undo_steps(k.case_dir), 0);
    int as_made;
    assert_int_equal(fragments(&k, &as_made), 2);
    blocks_free(&k);
}

/* A real fracture segments to one fragment (the whole bone), which is what the seed mode is for:
 * navigate opens a case of one fragment (it refused one, "steering needs at least two"). */
static void test_navigate_opens_one_fragment(void **st)
{
    (void)st;
    blocks k;
    blocks_make(&k, "navseed-one");
    assert_int_equal(tu_run_cli(NULL, "edit '%s' merge 1 2", k.case_dir), 0);
    char *out = NULL;
    int rc = navigate(&k, &out);
    if (rc != 0)
        fail_msg("navigate over a case of one fragment: exit %d: %s", rc, out);
    free(out);
    blocks_free(&k);
}

/* The live preview shows what Enter makes: after seeds 1 and 2 in block B (the second grown
 * incrementally from the first's growth), its fragments have the ids, colours and voxel counts of
 * case_separate_all's; with seed 2 taken back (a growth anew) it shows the case as it is; a seed
 * on no fragment is refused, naming its point. */
static void test_preview_matches_the_separation(void **st)
{
    (void)st;
    blocks k;
    blocks_make(&k, "navseed-preview");
    planning_case *c = case_load(k.case_dir);
    assert_non_null(c);
    case_seed seeds[3] = {{{k.b[0] - 3, k.b[1], k.b[2]}, 1}, {{k.b[0] + 3, k.b[1], k.b[2]}, 2},
                          {{k.b[0], k.b[1], k.b[2] + 8}, 1}};
    case_preview *p = case_preview_new(c);
    assert_non_null(p);
    const frag *shown;
    assert_int_equal(case_preview_update(p, NULL, seeds, 1, &shown), 2);
    int n = case_preview_update(p, NULL, seeds, 2, &shown);
    assert_int_equal(n, 3);
    planning_case *sep = case_load(k.case_dir);
    assert_non_null(sep);
    assert_int_equal(case_separate_all(sep, seeds, 2), 1);
    assert_int_equal(sep->nfrag, 3);
    for (int i = 0; i < 3; i++) {
        const frag *f = &sep->frag[case_find(sep, shown[i].id)];
        assert_int_equal(shown[i].voxels, f->voxels);
        assert_memory_equal(shown[i].rgb, f->rgb, 3);
    }
    case_free(sep);
    assert_int_equal(case_preview_update(p, NULL, seeds, 1, &shown), 2);
    assert_int_equal(shown[1].voxels, c->frag[1].voxels);
    case_seed off[2] = {seeds[0], seeds[2]};
    assert_int_equal(case_preview_update(p, NULL, off, 2, &shown), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), "on no fragment"));
    /* off the bone (air): the preview says why in Enter's words, not that Enter would grow it */
    char said[1024];
    snprintf(said, sizeof said, "%s", fn_err_msg());
    assert_non_null(strstr(said, "under the case's bone threshold"));
    assert_null(strstr(said, "Enter grows"));
    planning_case *enter = case_load(k.case_dir);
    assert_non_null(enter);
    assert_int_equal(case_separate_all(enter, off, 2), FN_EINVAL);
    assert_non_null(strstr(fn_err_msg(), strstr(said, "and the CT there")));
    case_free(enter);
    case_preview_free(p);
    case_free(c);
    blocks_free(&k);
}

/* What colours the seed mode's marks (navseed_marks): frag_holds tells the previewed piece that
 * holds a seed. Each of the two seeds in block B is held by its own piece of the preview and by
 * no other; a point far off is held by none; a piece moved by its pose holds the point moved
 * with it. */
static void test_each_seed_is_held_by_its_piece(void **st)
{
    (void)st;
    blocks k;
    blocks_make(&k, "navseed-holds");
    planning_case *c = case_load(k.case_dir);
    assert_non_null(c);
    case_seed seeds[2] = {{{k.b[0] - 3, k.b[1], k.b[2]}, 1}, {{k.b[0] + 3, k.b[1], k.b[2]}, 2}};
    case_preview *p = case_preview_new(c);
    assert_non_null(p);
    const frag *shown;
    int n = case_preview_update(p, NULL, seeds, 2, &shown);
    assert_int_equal(n, 3);
    int holder[2] = {-1, -1};
    for (int m = 0; m < 2; m++)
        for (int i = 0; i < n; i++)
            if (frag_holds(&shown[i], seeds[m].at)) {
                if (holder[m] >= 0)
                    fail_msg("seed %d held by pieces %d and %d", m + 1, holder[m], i);
                holder[m] = i;
            }
    if (holder[0] < 0 || holder[1] < 0 || holder[0] == holder[1])
        fail_msg("the two seeds are held by pieces %d and %d", holder[0], holder[1]);
    const double far[3] = {k.b[0], k.b[1], k.b[2] + 500};
    for (int i = 0; i < n; i++)
        assert_false(frag_holds(&shown[i], far));
    frag moved = shown[holder[1]];
    moved.pose = POSE_IDENTITY;
    moved.pose.t[2] = 40;
    const double up[3] = {seeds[1].at[0], seeds[1].at[1], seeds[1].at[2] + 40};
    assert_true(frag_holds(&moved, up));
    assert_false(frag_holds(&moved, seeds[1].at));
    case_preview_free(p);
    case_free(c);
    blocks_free(&k);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_crash_after_enter_is_recovered_and_undone),
        cmocka_unit_test(test_separation_file_of_another_case_json_is_dropped),
        cmocka_unit_test(test_garbled_separation_file_is_named_and_kept),
        cmocka_unit_test(test_undo_step_equal_to_the_case_is_dropped),
        cmocka_unit_test(test_undo_never_loses_a_later_save),
        cmocka_unit_test(test_force_replaces_a_case_with_undo_steps),
        cmocka_unit_test(test_navigate_opens_one_fragment),
        cmocka_unit_test(test_preview_matches_the_separation),
        cmocka_unit_test(test_each_seed_is_held_by_its_piece),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
