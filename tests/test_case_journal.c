/* A case and its journal through the CLI: a journal is applied only to the case state it extends;
 * an edit does not let journaled poses land on another fragment; damage is located and kept
 * aside; recovered poses are checked; poses already saved are not offered again. And what a
 * session saves: the fragment fixed in it, and a penetrating plan said as such. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case_journal.h"
#include "journal.h"
#include "testutil.h"
#include "vol.h"
#include "volio.h"

#include <jansson.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

struct fixture {
    char *tmp;
    char cdir[4200], idle[4200];
};

/* A SpaceExplorer recording (it has buttons 1-10) of a motion script at path. */
static void record(const char *path, const char *text)
{
    tu_write_recording(path, "spaceexplorer", text);
}

/* Three bone blocks (ids 1, 2, 3 by size; 1 and 2 are 4 mm apart along x), none fixed, and a
 * recording that does nothing. */
static int setup(void **st)
{
    struct fixture *f = calloc(1, sizeof *f);
    f->tmp = tu_tmpdir("casejournal");
    vol *v = vol_new(48, 32, 32);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = -1000;
    for (int k = 6; k < 26; k++)
        for (int j = 6; j < 26; j++) {
            for (int i = 2; i < 14; i++)
                v->data[vol_idx(v, i, j, k)] = 1000;
            for (int i = 18; i < 28; i++)
                v->data[vol_idx(v, i, j, k)] = j < 18 ? 1000 : -1000;
            for (int i = 34; i < 40; i++)
                v->data[vol_idx(v, i, j, k)] = j < 12 ? 1000 : -1000;
        }
    char src[4300];
    snprintf(src, sizeof src, "%s/blocks.nii.gz", f->tmp);
    assert_int_equal(volio_write(v, src, VOL_I16), 0);
    vol_free(v);
    snprintf(f->cdir, sizeof f->cdir, "%s/case", f->tmp);
    tu_segment(src, f->cdir, "--ramp 0");
    snprintf(f->idle, sizeof f->idle, "%s/idle.fnrec", f->tmp);
    record(f->idle, "wait 0.1 s\n");
    *st = f;
    return 0;
}

static pose moved(double x)
{
    pose p = POSE_IDENTITY;
    p.t[0] = x;
    return p;
}

/* A journal of n records (as given, CRCs made good) bound to b: what a killed session leaves. */
static void write_journal(const struct fixture *f, const journal_bind *b, journal_rec *r, size_t n)
{
    for (size_t i = 0; i < n; i++)
        r[i].seq = i + 1;
    char path[4300], aside[4300];
    snprintf(path, sizeof path, "%s/journal", f->cdir);
    tu_write_file(path, "", 0);
    assert_int_equal(journal_set_aside(f->cdir, "scratch", b, r, n, aside, sizeof aside), 0);
    unlink(aside);
}

/* A journal that moves fragment index `frag` of the case as it is now to x mm. */
static void interrupted(const struct fixture *f, int frag, double x)
{
    planning_case *c = tu_case_load(f->cdir);
    journal_bind b;
    case_journal_bind(c, &b);
    case_free(c);
    journal_rec r = {JOURNAL_START, frag, 0, 0, moved(x), 0};
    write_journal(f, &b, &r, 1);
}

static double pose_x(const planning_case *c, int id)
{
    int k = case_find(c, id);
    assert_true(k >= 0);
    return c->frag[k].pose.t[0];
}

static int exists(const struct fixture *f, const char *name, off_t *size)
{
    char path[4300];
    snprintf(path, sizeof path, "%s/%s", f->cdir, name);
    struct stat sb;
    if (stat(path, &sb) != 0)
        return 0;
    if (size)
        *size = sb.st_size;
    return 1;
}

/* The reproducer: a session moving fragment 1 (index 0) is killed; `edit drop 1`; then
 * `replay --recover --save` must not put fragment 1's motion onto fragment 2. */
static void test_edit_never_moves_journaled_poses_to_another_fragment(void **st)
{
    struct fixture *f = *st;
    interrupted(f, 0, 5.5);
    char *out = NULL;
    int rc = tu_run_cli(&out, "edit '%s' drop 1", f->cdir);
    if (rc != 0)
        fail_msg("edit: %s", out);
    assert_non_null(strstr(out, "applied the 1 poses"));
    free(out);
    rc = tu_run_cli(&out, "replay '%s' '%s' --recover --save", f->cdir, f->idle);
    free(out);
    planning_case *c = tu_case_load(f->cdir);
    assert_int_equal(c->nfrag, 2);
    assert_true(pose_x(c, 2) == 0 && pose_x(c, 3) == 0);
    case_free(c);
    (void)rc;
}

/* A journal bound to another case.json is refused with --recover, kept aside, never applied; a
 * plain run says so and starts from case.json. */
static void test_journal_of_another_case_state_is_refused(void **st)
{
    struct fixture *f = *st;
    planning_case *c = tu_case_load(f->cdir);
    journal_bind b;
    case_journal_bind(c, &b);
    case_free(c);
    memset(b.case_sha256, 'a', 64);
    journal_rec r = {JOURNAL_START, 1, 0, 0, moved(3), 0};
    write_journal(f, &b, &r, 1);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "replay '%s' '%s' --recover --save", f->cdir, f->idle), 1);
    assert_non_null(strstr(out, "another state of the case"));
    assert_non_null(strstr(out, "journal.mismatch.1"));
    free(out);
    assert_true(exists(f, "journal.mismatch.1", NULL));
    c = tu_case_load(f->cdir);
    assert_true(pose_x(c, 2) == 0);
    case_free(c);
    write_journal(f, &b, &r, 1);
    assert_int_equal(tu_run_cli(&out, "replay '%s' '%s' --save", f->cdir, f->idle), 0);
    assert_non_null(strstr(out, "journal.mismatch.2"));
    free(out);
    c = tu_case_load(f->cdir);
    assert_true(pose_x(c, 2) == 0);
    case_free(c);
}

/* Killed between the case save and the journal's truncation: the poses are saved, so nothing is
 * offered, and the journal is emptied. */
static void test_poses_already_saved_are_not_offered(void **st)
{
    struct fixture *f = *st;
    interrupted(f, 1, 2.25);
    planning_case *c = tu_case_load(f->cdir);
    c->frag[1].pose = moved(2.25);
    assert_int_equal(case_save(c), 0);
    case_free(c);
    char *out = NULL;
    int rc = tu_run_cli(&out, "replay '%s' '%s'", f->cdir, f->idle);
    if (rc != 0)
        fail_msg("replay: %s", out);
    assert_null(strstr(out, "not saved"));
    assert_non_null(strstr(out, "in case.json already"));
    free(out);
    assert_int_equal(case_journal_pending(f->cdir), 0);
}

/* A bad first record: said where, kept aside whole; the plain replay does not cut it silently. */
static void test_damaged_first_record_is_kept_aside(void **st)
{
    struct fixture *f = *st;
    interrupted(f, 1, 1.5);
    char path[4300];
    snprintf(path, sizeof path, "%s/journal", f->cdir);
    FILE *fp = fopen(path, "r+b");
    fseek(fp, JOURNAL_HEADER_SIZE + 30, SEEK_SET);
    fputc(0x42, fp);
    fclose(fp);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "replay '%s' '%s'", f->cdir, f->idle), 0);
    assert_non_null(strstr(out, "record 1 at offset 256: bad CRC"));
    assert_non_null(strstr(out, "journal.damaged.1"));
    free(out);
    off_t size = 0;
    assert_true(exists(f, "journal.damaged.1", &size));
    assert_int_equal(size, JOURNAL_HEADER_SIZE + JOURNAL_RECORD_SIZE);
}

/* A bad record in the middle: what precedes it is recovered, the rest kept aside; a recovered
 * pose that is not a unit quaternion is damage too, named, and never saved. */
static void test_damage_in_the_middle_recovers_what_precedes(void **st)
{
    struct fixture *f = *st;
    planning_case *c = tu_case_load(f->cdir);
    journal_bind b;
    case_journal_bind(c, &b);
    case_free(c);
    journal_rec r[4] = {{JOURNAL_START, 1, 0, 0, moved(1), 0},
                        {JOURNAL_MOVE, 1, 0, 0, moved(2), 0},
                        {JOURNAL_MOVE, 1, 0, 0, moved(3), 0},
                        {JOURNAL_MOVE, 1, 0, 0, moved(4), 0}};
    r[2].p.q[0] = 1.5; /* a good CRC, a pose that cannot be */
    write_journal(f, &b, r, 4);
    char *out = NULL;
    int rc = tu_run_cli(&out, "replay '%s' '%s' --recover --save", f->cdir, f->idle);
    if (rc != 0)
        fail_msg("replay: %s", out);
    assert_non_null(strstr(out, "record 3 at offset"));
    assert_non_null(strstr(out, "unit length"));
    assert_non_null(strstr(out, "/journal"));
    assert_non_null(strstr(out, "the 2 records before the damage"));
    free(out);
    assert_true(exists(f, "journal.damaged.1", NULL));
    c = tu_case_load(f->cdir); /* the saved case loads, with the last good pose */
    assert_true(pose_x(c, 2) == 2);
    case_free(c);
}

/* Checking off (button 4), fragment 1 pushed 6 mm into fragment 2, checking on, saved: the save
 * says so on the terminal and in the JSON, and case.json records the pair. */
static void test_penetrating_plan_is_said_and_recorded(void **st)
{
    struct fixture *f = *st;
    char rec[4300];
    snprintf(rec, sizeof rec, "%s/push.fnrec", f->tmp);
    record(rec, "press 4\nwait 50 ms\nrelease 4\nwait 50 ms\ntranslate +x 6 mm over 0.5 s\n"
                "wait 50 ms\npress 4\nwait 50 ms\nrelease 4\nwait 50 ms\n");
    char *out = NULL;
    int rc = tu_run_cli(&out, "replay '%s' '%s' --frame world --save --json", f->cdir, rec);
    if (rc != 0)
        fail_msg("replay: %s", out);
    if (!strstr(out, "WARNING: saving a penetrating plan: fragments 1 and 2"))
        fail_msg("no warning: %s", out);
    json_t *j = json_loads(strchr(out, '{'), JSON_DISABLE_EOF_CHECK, NULL);
    assert_non_null(j);
    json_t *pen = json_array_get(json_object_get(j, "penetrating"), 0);
    assert_non_null(pen);
    double ml = json_number_value(json_object_get(pen, "overlap_ml"));
    assert_true(ml > 0.1 && ml < 2);
    json_decref(j);
    free(out);
    char path[4300];
    snprintf(path, sizeof path, "%s/case.json", f->cdir);
    j = json_load_file(path, 0, NULL);
    pen = json_array_get(json_object_get(j, "penetrating"), 0);
    assert_non_null(pen);
    assert_int_equal(json_integer_value(json_array_get(json_object_get(pen, "fragments"), 1)), 2);
    json_decref(j);
    /* Later commands that load the case warn too. */
    assert_int_equal(tu_run_cli(&out, "edit '%s' fix 3", f->cdir), 0);
    assert_non_null(strstr(out, "warning"));
    assert_non_null(strstr(out, "fragments 1 and 2 inside each other"));
    free(out);
}

/* A fragment fixed during the session (button 3) is fixed in the saved case, and a session killed
 * after fixing it gives the fixed fragment back on --recover. */
static void test_fixed_in_session_is_saved(void **st)
{
    struct fixture *f = *st;
    char rec[4300];
    snprintf(rec, sizeof rec, "%s/fix.fnrec", f->tmp);
    record(rec, "press 3\nwait 50 ms\nrelease 3\nwait 50 ms\n");
    char *out = NULL;
    int rc = tu_run_cli(&out, "replay '%s' '%s' --save", f->cdir, rec);
    if (rc != 0)
        fail_msg("replay: %s", out);
    planning_case *c = tu_case_load(f->cdir);
    if (c->fixed != case_find(c, 1))
        fail_msg("fixed %d: %s", c->fixed, out);
    free(out);
    journal_bind b;
    case_journal_bind(c, &b);
    case_free(c);
    /* Fragment 1 freed, fragment 3 fixed, then killed. */
    journal_rec fix[2] = {{JOURNAL_FIX, 0, 0, 0, POSE_IDENTITY, 0},
                          {JOURNAL_FIX, 2, 0, 0, POSE_IDENTITY, 1}};
    write_journal(f, &b, fix, 2);
    rc = tu_run_cli(&out, "replay '%s' '%s' --recover --save", f->cdir, f->idle);
    if (rc != 0)
        fail_msg("replay --recover: %s", out);
    free(out);
    c = tu_case_load(f->cdir);
    assert_int_equal(c->fixed, case_find(c, 3));
    case_free(c);
}

/* --force over a case whose journal holds unsaved poses says that they go, in segment and fracture
 * alike (one shared warning), naming the command. */
static void test_force_warns_of_unsaved_journal(void **st)
{
    struct fixture *f = *st;
    const char *cmds[] = {"segment", "fracture"}, *extra[] = {"--min-volume 0", "--seed 1"};
    for (int k = 0; k < 2; k++) {
        interrupted(f, 0, 5.0);
        char want[4600], *out = NULL;
        snprintf(want, sizeof want, "fracnav %s: warning: %s/journal holds 1 poses not saved in "
                 "case.json; they go with the case this replaces", cmds[k], f->cdir);
        tu_run_cli(&out, "%s '%s/blocks.nii.gz' -o '%s' --force %s", cmds[k], f->tmp, f->cdir,
                   extra[k]);
        if (!strstr(out, want))
            fail_msg("%s --force: wanted \"%s\" in:\n%s", cmds[k], want, out);
        free(out);
    }
}

/* export and render of a case whose journal holds unsaved poses (a killed navigate) say so, as
 * edit does, and use those poses only with --recover; the journal stays for navigate to offer. */
static void test_export_and_render_say_unsaved_poses(void **st)
{
    struct fixture *f = *st;
    interrupted(f, 1, 6.0);
    char *out = NULL, plain[4300], recovered[4300], p[4400];
    snprintf(plain, sizeof plain, "%s/plain", f->tmp);
    snprintf(recovered, sizeof recovered, "%s/recovered", f->tmp);
    assert_int_equal(tu_run_cli(&out, "export '%s' --tfm '%s'", f->cdir, plain), 0);
    assert_non_null(strstr(out, "journal holds 1 poses beyond case.json"));
    assert_non_null(strstr(out, "--recover"));
    free(out);
    assert_int_equal(tu_run_cli(&out, "export '%s' --tfm '%s' --recover", f->cdir, recovered), 0);
    assert_non_null(strstr(out, "using the 1 poses"));
    free(out);
    snprintf(p, sizeof p, "%s/fragment-2.tfm", plain);
    char *t0 = tu_slurp(p, NULL);
    snprintf(p, sizeof p, "%s/fragment-2.tfm", recovered);
    char *t1 = tu_slurp(p, NULL);
    assert_true(t0 && t1);
    assert_non_null(strstr(t0, "Parameters: 1 0 0 0 1 0 0 0 1 ")); /* case.json's pose: none */
    assert_string_not_equal(t0, t1);
    free(t0);
    free(t1);
    assert_int_equal(case_journal_pending(f->cdir), 1);
    assert_int_equal(tu_run_cli(&out, "render '%s' -o '%s/r.png' --size 64x64", f->cdir, f->tmp), 0);
    assert_non_null(strstr(out, "journal holds 1 poses beyond case.json"));
    free(out);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_edit_never_moves_journaled_poses_to_another_fragment,
                                        setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_journal_of_another_case_state_is_refused, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_poses_already_saved_are_not_offered, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_damaged_first_record_is_kept_aside, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_damage_in_the_middle_recovers_what_precedes, setup,
                                        tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_penetrating_plan_is_said_and_recorded, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_fixed_in_session_is_saved, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_force_warns_of_unsaved_journal, setup, tu_fixture_teardown),
        cmocka_unit_test_setup_teardown(test_export_and_render_say_unsaved_poses, setup, tu_fixture_teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
