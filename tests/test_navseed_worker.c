/* The seed mode's preview worker (src/app/navseed.c, compiled into this test): what the window's
 * thread may touch while the worker grows a preview. Two faults this catches, both seen under
 * AddressSanitizer in navigate's window:
 *  - the marks' colours were read from the previewed pieces while the next job was rewriting them
 *    (case_preview_update frees them);
 *  - a job that ended unseen before navseed_free (the window closed for a separation or an undo)
 *    was taken by the next window's first navseed_preview, its pieces freed with the preview.
 * The worker is waited for through its done flag, never a clock. */
#include "case.h"
#include "frag.h"
#include "navseed.h"
#include "render.h"

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "testutil.h"

#define KEY_F10 (RENDER_KEY_F1 + 9)

typedef struct fixture {
    char *dir;
    char case_dir[4200];
    planning_case *c;
    double left[3], right[3]; /* two points in block B (fragment 2), 3 mm either side of its centroid */
} fixture;

static void fixture_make(fixture *x, const char *tag)
{
    x->dir = tu_tmpdir(tag);
    tu_two_blocks_case(x->dir, x->case_dir, sizeof x->case_dir);
    x->c = case_load(x->case_dir);
    assert_non_null(x->c);
    const double *b = x->c->frag[case_find(x->c, 2)].centroid;
    memcpy(x->left, b, sizeof x->left);
    memcpy(x->right, b, sizeof x->right);
    x->left[0] -= 3;
    x->right[0] += 3;
}

static void fixture_free(fixture *x)
{
    case_free(x->c);
    tu_rmtree(x->dir);
    free(x->dir);
}

static int job_done(void *arg)
{
    navseed *s = arg;
    return atomic_load(&s->done);
}

/* Waits for the running job to end (its done flag), then takes it: navseed_preview returns 1. */
static void take_preview(navseed *s, const planning_case *c)
{
    assert_true(s->running);
    if (!tu_wait_for(job_done, s, tu_wait_max_s()))
        fail_msg("the preview's worker did not end in %d s", tu_wait_max_s());
    assert_int_equal(navseed_preview(s, c, NULL, 0), 1);
    /* the pieces are the caller's to upload until the next call: no job may run over them now */
    assert_false(s->running);
}

static int white(const unsigned char rgb[3])
{
    return rgb[0] == 255 && rgb[1] == 255 && rgb[2] == 255;
}

/* A seed's mark takes its piece's colour once a preview shows it; while the next seed's job runs
 * (rewriting the pieces), the first keeps its colour and the new one stays white, without the marks
 * reading the pieces; once that job is taken, each mark has its own piece's colour. */
static void test_marks_keep_their_colour_while_the_next_job_runs(void **st)
{
    (void)st;
    fixture x;
    fixture_make(&x, "navseed-worker-marks");
    navseed s;
    navseed_init(&s);
    assert_int_equal(navseed_key(&s, KEY_F10), 1);
    assert_int_equal(navseed_key(&s, '1'), 1);
    navseed_click(&s, x.left);
    assert_int_equal(navseed_preview(&s, x.c, NULL, 0), 0); /* the job starts */
    take_preview(&s, x.c);
    assert_true(s.npieces >= 2);
    double at[2][3];
    unsigned char rgb[2][3];
    assert_int_equal(navseed_marks(&s, at, rgb, 2), 1);
    assert_false(white(rgb[0]));
    unsigned char first[3];
    memcpy(first, rgb[0], sizeof first);

    assert_int_equal(navseed_key(&s, '2'), 1);
    navseed_click(&s, x.right);
    assert_int_equal(navseed_preview(&s, x.c, NULL, 0), 0); /* the second job starts */
    assert_true(s.running);
    /* while it runs (ThreadSanitizer and AddressSanitizer see any read of the pieces here) */
    assert_int_equal(navseed_marks(&s, at, rgb, 2), 2);
    assert_memory_equal(rgb[0], first, sizeof first);
    assert_true(white(rgb[1]));
    assert_memory_equal(at[1], x.right, sizeof at[1]);

    take_preview(&s, x.c);
    assert_int_equal(s.npieces, 3);
    assert_int_equal(navseed_marks(&s, at, rgb, 2), 2);
    assert_false(white(rgb[0]));
    assert_false(white(rgb[1]));
    assert_memory_not_equal(rgb[0], rgb[1], sizeof rgb[0]);

    /* Backspace and another seed at the same index: white until its own preview */
    assert_int_equal(navseed_key(&s, '\b'), 1);
    double other[3] = {x.right[0], x.right[1] + 1, x.right[2]};
    navseed_click(&s, other);
    assert_int_equal(navseed_marks(&s, at, rgb, 2), 2);
    assert_true(white(rgb[1]));
    navseed_free(&s);
    fixture_free(&x);
}

/* The window closes (a separation accepted, or undo) while a job runs: navseed_free waits for it
 * and drops it with the preview it was made in. The next window's first navseed_preview shows no
 * pieces (those were freed) and starts a new job, whose pieces it then shows, grown at the scene's
 * poses as given (navseed_free had kept the old job's pose count, and the new job then ran with
 * none: the case's own poses, read off the thread that saves them). */
static void test_a_job_unseen_at_free_is_dropped(void **st)
{
    (void)st;
    fixture x;
    fixture_make(&x, "navseed-worker-free");
    navseed s;
    navseed_init(&s);
    navseed_key(&s, KEY_F10);
    navseed_key(&s, '1');
    navseed_click(&s, x.left);
    navseed_key(&s, '2');
    navseed_click(&s, x.right);
    pose scene[2] = {POSE_IDENTITY, POSE_IDENTITY};
    assert_int_equal(x.c->nfrag, 2);
    scene[1].t[2] = 0.5; /* the scene's poses, not the case's */
    assert_int_equal(navseed_preview(&s, x.c, scene, 2), 0);
    assert_true(tu_wait_for(job_done, &s, tu_wait_max_s()));
    navseed_free(&s); /* the job ended, never taken */
    assert_null(s.pieces);
    assert_int_equal(s.npieces, 0);
    s.changed = 1; /* as navigate does: the preview again in the next window */
    assert_int_equal(navseed_preview(&s, x.c, scene, 2), 0);
    assert_int_equal(s.npieces, 0);
    assert_true(s.running); /* a new job over the seeds kept */
    take_preview(&s, x.c);
    assert_int_equal(s.npieces, 3);
    assert_non_null(s.job_poses);
    assert_int_equal(s.job_nposes, 2);
    assert_memory_equal(s.job_poses, scene, sizeof scene);
    double at[2][3];
    unsigned char rgb[2][3];
    assert_int_equal(navseed_marks(&s, at, rgb, 2), 2);
    assert_false(white(rgb[0]));
    assert_false(white(rgb[1]));
    navseed_free(&s);
    fixture_free(&x);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_marks_keep_their_colour_while_the_next_job_runs),
        cmocka_unit_test(test_a_job_unseen_at_free_is_dropped),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
