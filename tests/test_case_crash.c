/* Killed while writing a case: `segment` and `fracture` are killed with SIGKILL at the moment they
 * write a file of the case (watched for, not timed), and what is left at the case's path must be
 * the old case or the new one, never a mix or a half-made folder. An existing case is replaced only
 * with --force, also one that another process saved while this one worked on a new case. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "case.h"
#include "caselock.h"
#include "durable.h"
#include "err.h"
#include "testutil.h"
#include "volio.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

/* A bone block big enough that writing its files takes a while, on a 1 mm grid. */
static void write_ct(const char *path)
{
    vol *v = vol_new(160, 140, 90);
    static const double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    double sp[3] = {1, 1, 1}, org[3] = {0, 0, 0};
    vol_set_geometry(v, dir, sp, org);
    for (int k = 0; k < 90; k++)
        for (int j = 0; j < 140; j++)
            for (int i = 0; i < 160; i++) {
                int bone = i >= 30 && i < 130 && j >= 30 && j < 110 && k >= 20 && k < 70;
                /* texture, so the gzip of the volume is not trivially small */
                v->data[vol_idx(v, i, j, k)] = bone ? 1000 + (float)((i * 7 + j * 13 + k * 5) % 97)
                                                    : -1000 + (float)((i * 3 + j * 11 + k) % 31);
            }
    if (volio_write(v, path, VOL_I16) < 0)
        fail_msg("%s", fn_err_msg());
    vol_free(v);
}

/* `fracnav ARGS` (a shell word list, quoted as for tu_run_cli) started through tu_spawn. */
static pid_t spawn(const char *args)
{
    char cmd[9400];
    snprintf(cmd, sizeof cmd, "exec '%s' %s", tu_fracnav(), args);
    return tu_spawn((char *[]){"/bin/sh", "-c", cmd, NULL}, "/dev/null", NULL);
}

/* 1 when folder holds `name`, or a temporary of it (durable.h: .fracnav-tmp-PID-N-NAME), that is
 * not empty. */
static int holds(const char *folder, const char *name)
{
    DIR *d = opendir(folder);
    if (!d)
        return 0;
    struct dirent *e;
    int hit = 0;
    size_t n = strlen(name), tl = strlen(DURABLE_TMP_TAG);
    char p[8400];
    struct stat sb;
    while (!hit && (e = readdir(d))) {
        size_t len = strlen(e->d_name);
        int tmp = !strncmp(e->d_name, DURABLE_TMP_TAG, tl) && len > n && e->d_name[len - n - 1] == '-' &&
                  !strcmp(e->d_name + len - n, name);
        if (tmp || !strcmp(e->d_name, name)) {
            snprintf(p, sizeof p, "%s/%s", folder, e->d_name);
            hit = stat(p, &sb) == 0 && sb.st_size > 0;
        }
    }
    closedir(d);
    return hit;
}

/* The file `name` is being written: in the case folder (other than `old`, when given) or in a
 * staged sibling folder of it, under its name or as a temporary of it. */
static int written(const char *parent, const char *base, const char *name, const struct stat *old)
{
    char p[8400];
    struct stat sb;
    snprintf(p, sizeof p, "%s/%s/%s", parent, base, name);
    if (old && stat(p, &sb) == 0 &&
        (sb.st_ino != old->st_ino || sb.st_size != old->st_size ||
         sb.st_mtim.tv_sec != old->st_mtim.tv_sec || sb.st_mtim.tv_nsec != old->st_mtim.tv_nsec))
        return 1;
    snprintf(p, sizeof p, "%s/%s", parent, base);
    if (!old && holds(p, name))
        return 1;
    DIR *d = opendir(parent);
    if (!d)
        return 0;
    struct dirent *e;
    int hit = 0;
    size_t n = strlen(base);
    while (!hit && (e = readdir(d)))
        if (e->d_name[0] == '.' && !strncmp(e->d_name + 1, base, n) && e->d_name[n + 1] == '.') {
            snprintf(p, sizeof p, "%s/%s", parent, e->d_name);
            hit = holds(p, name);
        }
    closedir(d);
    return hit;
}

/* 1 when some process holds a flock on the file at path: a non-blocking shared flock of it is
 * refused (one that is granted is let go at once). */
static int lock_is_held(const char *path)
{
    int fd = open(path, O_RDONLY | O_NOFOLLOW | O_CLOEXEC);
    if (fd < 0)
        return 0;
    int held = flock(fd, LOCK_SH | LOCK_NB) != 0 && errno == EWOULDBLOCK;
    close(fd); /* releases a lock granted */
    return held;
}

/* What a kill waits for: in folder `parent`, the step named by the condition. */
typedef struct watch {
    const char *parent, *base, *name;
    const struct stat *old;
    pid_t pid;
} watch;

static int is_written(const watch *w)
{
    return written(w->parent, w->base, w->name, w->old);
}

/* A temporary (durable.h: .fracnav-tmp-PID-N-NAME) is in folder w->parent: the child's own (its
 * pid in the name) when w->pid is set, else anyone's. */
static int temporary_in(const watch *w)
{
    char tag[64];
    if (w->pid)
        snprintf(tag, sizeof tag, DURABLE_TMP_TAG "%ld-", (long)w->pid);
    else
        snprintf(tag, sizeof tag, DURABLE_TMP_TAG);
    DIR *d = opendir(w->parent);
    if (!d)
        return 0;
    struct dirent *e;
    int hit = 0;
    while (!hit && (e = readdir(d)))
        hit = !strncmp(e->d_name, tag, strlen(tag));
    closedir(d);
    return hit;
}

/* The child holds the case's lock: the lock file in w->parent names its pid (the holder writes it
 * once it has the lock), and a non-blocking flock of the file from here is refused. */
static int lock_taken(const watch *w)
{
    char p[4400], want[32];
    snprintf(p, sizeof p, "%s/" CASELOCK_FILE, w->parent);
    snprintf(want, sizeof want, "%ld ", (long)w->pid);
    char *s = tu_slurp(p, NULL);
    int named = s && !strncmp(s, want, strlen(want));
    free(s);
    return named && lock_is_held(p);
}

typedef struct kill_watch {
    int (*cond)(const watch *);
    const watch *w;
} kill_watch;

/* 1 when the child has ended by itself (left to be reaped). */
static int ended(pid_t pid)
{
    siginfo_t info = {0};
    return waitid(P_PID, (id_t)pid, &info, WEXITED | WNOHANG | WNOWAIT) == 0 && info.si_pid == pid;
}

/* The child at the step: seen there, then stopped (SIGSTOP, waited for) and seen there again, so
 * that it cannot move past the step before the kill. 1 with the child stopped; 0 with it running
 * on (or ended). */
static int stopped_at_step(const kill_watch *k)
{
    if (!k->cond(k->w))
        return 0;
    pid_t pid = k->w->pid;
    siginfo_t info = {0};
    if (kill(pid, SIGSTOP) != 0 || waitid(P_PID, (id_t)pid, &info, WSTOPPED | WEXITED | WNOWAIT) != 0 ||
        info.si_code != CLD_STOPPED)
        return 0; /* it ended meanwhile */
    if (k->cond(k->w))
        return 1;
    kill(pid, SIGCONT);
    return 0;
}

/* The child stopped at the step, or ended by itself. */
static int reached_or_ended(void *arg)
{
    const kill_watch *k = arg;
    return stopped_at_step(k) || ended(k->w->pid);
}

/* Waits until the child is at the step (then kills it there: returns 1) or ends by itself
 * (returns 0), looking every 0.1 ms. */
static int kill_when(int (*cond)(const watch *), watch *w)
{
    kill_watch k = {cond, w};
    if (!tu_wait_for_every(reached_or_ended, &k, TU_WAIT_MAX_S, 100))
        fail_msg("the child neither reached the step nor ended");
    int hit = !ended(w->pid);
    tu_end(w->pid, hit ? SIGKILL : 0, "fracnav, killed at a step of a save");
    return hit;
}

/* Waits until the child writes `name` (then kills it: returns 1) or ends by itself (returns 0). */
static int kill_when_written(pid_t pid, const char *parent, const char *base, const char *name,
                             const struct stat *old)
{
    watch w = {parent, base, name, old, pid};
    return kill_when(is_written, &w);
}

static void test_segment_refuses_existing_and_leaves_no_half_folder(void **st)
{
    char *dir = tu_tmpdir("casecrash"), src[4200], cdir[4200];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    write_ct(src);

    /* Killed while writing its labels into a new folder: no folder, or a whole case. */
    char args[9000];
    snprintf(args, sizeof args, "segment '%s' -o '%s'", src, cdir);
    int killed = kill_when_written(spawn(args), dir, "case", "labels.nii.gz", NULL);
    struct stat sb;
    int whole = 0;
    if (stat(cdir, &sb) == 0) {
        planning_case *c = case_load(cdir);
        if (!c)
            fail_msg("killed=%d: a half-made case folder is left: %s", killed, fn_err_msg());
        case_free(c);
        whole = 1; /* the save was done before the kill (or the child ended before the watch saw it) */
    }
    /* What was left is no obstacle: a staging folder is swept; a whole case needs --force, as any. */
    char *out = NULL;
    int rc = tu_run_cli(&out, "%s%s", args, whole ? " --force" : "");
    if (rc != 0)
        fail_msg("killed=%d, whole case left=%d: segment again: exit %d: %s", killed, whole, rc, out);
    free(out);
    planning_case *c = case_load(cdir);
    assert_non_null(c);
    char before[65];
    memcpy(before, c->json_sha256, sizeof before);
    case_free(c);

    /* An existing case is not overwritten without --force. */
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s' --threshold 1050", src, cdir), 1);
    assert_non_null(strstr(out, "--force"));
    free(out);
    c = case_load(cdir);
    assert_string_equal(c->json_sha256, before);
    case_free(c);
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s' --threshold 1050 --force", src, cdir), 0);
    free(out);
    c = case_load(cdir);
    assert_non_null(c);
    assert_string_not_equal(c->json_sha256, before);
    case_free(c);
    tu_rmtree(dir);
    free(dir);
}

/* fracture -o EXISTING --force, killed as it writes source.nii.gz: the old case still loads, and
 * the next run cleans up what the killed one left. */
static void test_fracture_killed_keeps_old_case(void **st)
{
    char *dir = tu_tmpdir("casecrash"), src[4200], cdir[4200], srcfile[4300];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    snprintf(srcfile, sizeof srcfile, "%s/source.nii.gz", cdir);
    write_ct(src);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "fracture '%s' -o '%s' --seed 1", src, cdir), 0);
    free(out);
    planning_case *c = case_load(cdir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    char before[65];
    memcpy(before, c->json_sha256, sizeof before);
    case_free(c);

    assert_int_equal(tu_run_cli(&out, "fracture '%s' -o '%s' --seed 2", src, cdir), 1);
    assert_non_null(strstr(out, "--force"));
    free(out);

    struct stat sb;
    assert_int_equal(stat(srcfile, &sb), 0);
    char args[9000];
    snprintf(args, sizeof args, "fracture '%s' -o '%s' --seed 2 --force", src, cdir);
    int killed = kill_when_written(spawn(args), dir, "case", "source.nii.gz", &sb);
    c = case_load(cdir);
    if (!c)
        fail_msg("killed=%d: the case no longer loads: %s", killed, fn_err_msg());
    if (killed)
        assert_string_equal(c->json_sha256, before);
    case_free(c);

    assert_int_equal(tu_run_cli(&out, "%s", args), 0);
    free(out);
    c = case_load(cdir);
    assert_non_null(c);
    assert_string_not_equal(c->json_sha256, before);
    case_free(c);
    /* Nothing staged is left beside the case. */
    DIR *d = opendir(dir);
    struct dirent *e;
    while ((e = readdir(d)))
        if (!strncmp(e->d_name, ".case.", 6))
            fail_msg("left behind: %s", e->d_name);
    closedir(d);
    tu_rmtree(dir);
    free(dir);
}

/* No temporary left in folder. */
static void assert_no_temporary(const char *folder)
{
    watch w = {folder, NULL, NULL, NULL, 0};
    if (temporary_in(&w))
        fail_msg("a temporary is left in %s", folder);
}

/* edit killed at the lock's step and at its temporaries' step: the case loads as it was saved,
 * the lock died with its holder (the next edit needs no --wait), and the next edit removes what
 * the killed one left. */
static void test_edit_killed_at_lock_and_temporaries(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("casecrash"), src[4200], cdir[4200], args[9000];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    write_ct(src);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s'", src, cdir), 0);
    free(out);
    planning_case *c = case_load(cdir);
    assert_non_null(c);
    char before[65];
    memcpy(before, c->json_sha256, sizeof before);
    case_free(c);
    snprintf(args, sizeof args, "edit '%s' erase-sphere 80 70 45 12", cdir);
    static int (*const steps[2])(const watch *) = {lock_taken, temporary_in};
    static const char *const step_name[2] = {"holding the case's lock", "writing a temporary"};
    char lock[4300];
    snprintf(lock, sizeof lock, "%s/" CASELOCK_FILE, cdir);
    for (int k = 0; k < 2; k++) {
        watch w = {cdir, NULL, NULL, NULL, spawn(args)};
        if (!kill_when(steps[k], &w))
            fail_msg("edit ended by itself before it was seen %s: the kill tested nothing", step_name[k]);
        /* killed there: the lock went with it, its temporary stays until the next writer */
        assert_false(lock_is_held(lock));
        if (k == 1 && !temporary_in(&w))
            fail_msg("edit killed while writing a temporary left none in %s", cdir);
        c = case_load(cdir);
        if (!c)
            fail_msg("killed %s: the case no longer loads: %s", step_name[k], fn_err_msg());
        assert_string_equal(c->json_sha256, before);
        case_free(c);
    }
    assert_int_equal(tu_run_cli(&out, "edit '%s' fix 1", cdir), 0);
    free(out);
    assert_no_temporary(cdir);
    tu_rmtree(dir);
    free(dir);
}

/* export killed while its temporary is in the output folder: the next export removes it. */
static void test_export_killed_leftover_removed(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("casecrash"), src[4200], cdir[4200], odir[4200], args[9000];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/case", dir);
    snprintf(odir, sizeof odir, "%s/out", dir);
    write_ct(src);
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "segment '%s' -o '%s'", src, cdir), 0);
    free(out);
    assert_int_equal(mkdir(odir, 0755), 0);
    snprintf(args, sizeof args, "export '%s' --nifti '%s/planned.nii.gz'", cdir, odir);
    watch w = {odir, NULL, NULL, NULL, spawn(args)};
    if (!kill_when(temporary_in, &w))
        fail_msg("export ended by itself before it was seen writing a temporary: the kill tested nothing");
    if (!temporary_in(&w))
        fail_msg("export killed while writing a temporary left none in %s", odir);
    assert_int_equal(tu_run_cli(&out, "%s", args), 0);
    free(out);
    assert_no_temporary(odir);
    tu_rmtree(dir);
    free(dir);
}

/* The child's staged folder of the new case w->base is made: it found no case there. */
static int staged(const watch *w)
{
    char p[4400];
    struct stat sb;
    snprintf(p, sizeof p, "%s/.%s.new-%ld", w->parent, w->base, (long)w->pid);
    return stat(p, &sb) == 0;
}

/* Two `fracture -o NEW` at once, without --force: the first is stopped once it has found no case
 * there (its staged folder made), the second saves the case meanwhile; the first, let go on, is
 * refused, saying so, and the second's case is kept. */
static void test_two_writers_of_a_new_case(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("casecrash"), src[4200], cdir[4200], log[4200], cmd[9400];
    snprintf(src, sizeof src, "%s/ct.nii.gz", dir);
    snprintf(cdir, sizeof cdir, "%s/nc", dir);
    snprintf(log, sizeof log, "%s/first.out", dir);
    write_ct(src);
    snprintf(cmd, sizeof cmd, "exec '%s' fracture '%s' -o '%s' --seed 1", tu_fracnav(), src, cdir);
    watch w = {dir, "nc", NULL, NULL, tu_spawn((char *[]){"/bin/sh", "-c", cmd, NULL}, log, NULL)};
    kill_watch k = {staged, &w};
    if (!tu_wait_for_every(reached_or_ended, &k, TU_WAIT_MAX_S, 100) || ended(w.pid))
        fail_msg("the first fracture ended before it was seen staging the new case");
    struct stat sb;
    assert_int_equal(stat(cdir, &sb), -1); /* stopped before its case was put in place */
    char *out = NULL;
    assert_int_equal(tu_run_cli(&out, "fracture '%s' -o '%s' --seed 2", src, cdir), 0);
    free(out);
    planning_case *c = tu_case_load(cdir);
    char second[65];
    memcpy(second, c->json_sha256, sizeof second);
    case_free(c);
    kill(w.pid, SIGCONT);
    int rc = tu_end(w.pid, 0, "the first fracture");
    out = tu_slurp(log, NULL);
    if (rc != 1 || !strstr(out, "another process saved a case there") || !strstr(out, "--force"))
        fail_msg("the first fracture: exit %d, expected its refusal: %s", rc, out ? out : "");
    free(out);
    c = tu_case_load(cdir);
    assert_string_equal(c->json_sha256, second);
    case_free(c);
    assert_false(staged(&w)); /* the refused one removed its staged folder */
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_segment_refuses_existing_and_leaves_no_half_folder),
        cmocka_unit_test(test_fracture_killed_keeps_old_case),
        cmocka_unit_test(test_edit_killed_at_lock_and_temporaries),
        cmocka_unit_test(test_export_killed_leftover_removed),
        cmocka_unit_test(test_two_writers_of_a_new_case),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
