#define _GNU_SOURCE /* program_invocation_short_name */
#include "case.h"
#include "err.h"
#include "frag.h"
#include "fnrec.h"
#include "fracture.h"
#include "script.h"
#include "simdev.h"
#include "vol.h"
#include "volio.h"

#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <poll.h>
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "testutil.h" /* after cmocka.h: its fail_msg (see there) */
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

char *tu_tmpdir(const char *tag)
{
    const char *base = getenv("TMPDIR");
    char *p = malloc(4096);
    snprintf(p, 4096, "%s/fracnav-%s-XXXXXX", base && *base ? base : "/tmp", tag);
    if (!mkdtemp(p))
        fail_msg("mkdtemp %s failed", p);
    return p;
}

void tu_rmtree(const char *dir)
{
    char cmd[4200];
    if (!dir || strncmp(dir, "/tmp/", 5) != 0)
        return;
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", dir);
}

char *tu_dir;

int tu_dir_setup(void **st)
{
    (void)st;
    tu_dir = tu_tmpdir(program_invocation_short_name);
    return 0;
}

int tu_dir_teardown(void **st)
{
    (void)st;
    tu_rmtree(tu_dir);
    free(tu_dir);
    tu_dir = NULL;
    return 0;
}

const char *tu_in_dir(const char *name)
{
    static char p[4300];
    snprintf(p, sizeof p, "%s/%s", tu_dir, name);
    return p;
}

int tu_fixture_teardown(void **st)
{
    char **tmp = *st; /* the fixture's first member */
    tu_rmtree(*tmp);
    free(*tmp);
    free(*st);
    return 0;
}

const char *tu_example_ct(void)
{
    static char path[4096];
    const char *d = getenv("FRACNAV_DATA");
    snprintf(path, sizeof path, "%s/Cranium.inv3", d && *d ? d : "/var/cache/fracnav");
    if (access(path, R_OK) == 0)
        return path;
#define NO_CT "example CT %s is missing: run .ci/setup (the README's first command), which extracts " \
              "Cranium.inv3 from Debian's invesalius-examples package into $FRACNAV_DATA (default " \
              "/var/cache/fracnav)"
    if (getenv("CI") && *getenv("CI")) /* CI runs .ci/setup first: there, a missing CT is a failure */
        fail_msg(NO_CT, path);
    print_message(NO_CT "; skipped\n", path);
#undef NO_CT
    skip();
    return NULL;
}

const char *tu_test_data(const char *name)
{
    static char path[4096];
    const char *src = getenv("FRACNAV_SRC");
    if (src && *src)
        snprintf(path, sizeof path, "%s/tests/data/%s", src, name);
    else
        snprintf(path, sizeof path, "%s/%s", FRACNAV_TEST_DATA, name);
    if (access(path, R_OK) != 0)
        fail_msg("test data %s is missing (it ships in the repository's tests/data/)", path);
    return path;
}

void tu_print_failure(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("ERROR: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    fflush(stderr);
    va_end(ap);
}

/* Runs `'prog' ARGS 2>&1` through /bin/sh; the exit status, the output in *out (or dropped). */
static int run_prog(const char *prog, char **out, const char *fmt, va_list ap)
{
    char args[8192], cmd[9000];
    vsnprintf(args, sizeof args, fmt, ap);
    snprintf(cmd, sizeof cmd, "'%s' %s 2>&1", prog, args);
    FILE *f = popen(cmd, "r");
    if (!f)
        return -1;
    size_t cap = 4096, n = 0;
    char *buf = malloc(cap);
    size_t got;
    while ((got = fread(buf + n, 1, cap - n - 1, f)) > 0) {
        n += got;
        if (cap - n < 2)
            buf = realloc(buf, cap *= 2);
    }
    buf[n] = '\0';
    int st = pclose(f);
    if (out)
        *out = buf;
    else
        free(buf);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

int tu_run_cli(char **out, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int rc = run_prog(tu_fracnav(), out, fmt, ap);
    va_end(ap);
    return rc;
}

int tu_run_sim(char **out, const char *fmt, ...)
{
    const char *sim = tu_sim(); /* skips where fracnav-sim is not built */
    va_list ap;
    va_start(ap, fmt);
    int rc = run_prog(sim, out, fmt, ap);
    va_end(ap);
    return rc;
}

void tu_expect_cli(int rc, const char *want, const char *fmt, ...)
{
    char args[8192], *out = NULL;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(args, sizeof args, fmt, ap);
    va_end(ap);
    int got = tu_run_cli(&out, "%s", args);
    if (got != rc || !strstr(out, want) || strstr(out, ".fracnav-tmp"))
        fail_msg("fracnav %s: exit %d (want %d), output lacks \"%s\" or names a temporary file:\n%s", args, got, rc,
                 want, out);
    free(out);
}

void tu_segment(const char *ct, const char *case_dir, const char *extra)
{
    char *out = NULL;
    int rc = tu_run_cli(&out, "segment '%s' -o '%s' --min-volume 0 %s", ct, case_dir, extra);
    if (rc != 0)
        fail_msg("segment %s failed (exit %d): %s", ct, rc, out);
    free(out);
}

int tu_wait_for(int (*cond)(void *arg), void *arg, double max_s)
{
    return tu_wait_for_every(cond, arg, max_s, 5000);
}

int tu_wait_for_every(int (*cond)(void *arg), void *arg, double max_s, long period_us)
{
    struct timespec now, end, poll = {period_us / 1000000, period_us % 1000000 * 1000};
    clock_gettime(CLOCK_MONOTONIC, &end);
    end.tv_sec += (time_t)max_s;
    for (;;) {
        if (cond(arg))
            return 1;
        clock_gettime(CLOCK_MONOTONIC, &now);
        if (now.tv_sec > end.tv_sec || (now.tv_sec == end.tv_sec && now.tv_nsec >= end.tv_nsec))
            return 0;
        nanosleep(&poll, NULL); /* the polling period of the wait, not a wait */
    }
}

typedef struct file_text {
    const char *path, *text;
} file_text;

static int file_has_text(void *arg)
{
    const file_text *ft = arg;
    char *s = tu_slurp(ft->path, NULL);
    int has = s && strstr(s, ft->text);
    free(s);
    return has;
}

int tu_wait_for_text(const char *path, const char *text, double max_s)
{
    return tu_wait_for(file_has_text, &(file_text){path, text}, max_s);
}

int tu_wait_max_s(void)
{
    const char *slow = getenv("FRACNAV_TEST_SLOW");
    double k = slow && *slow ? atof(slow) : 1;
    return (int)(30 * (k > 0 ? k : 1));
}

/* ---- Processes ---- */

#define MAX_CHILDREN 16
static pid_t children[MAX_CHILDREN]; /* started and not yet ended: tu_end_all's */

const char *tu_fracnav(void)
{
    const char *bin = getenv("FRACNAV_BIN");
    if (!bin || !*bin)
        fail_msg("FRACNAV_BIN is not set: run the tests through ctest, or set FRACNAV_BIN to the "
                 "built fracnav (build/fracnav) and FRACNAV_SRC to the source tree");
    return bin;
}

const char *tu_src(void)
{
    const char *src = getenv("FRACNAV_SRC");
    if (!src || !*src)
        fail_msg("FRACNAV_SRC is not set: run the tests through ctest, or set FRACNAV_SRC to the "
                 "source tree and FRACNAV_BIN to the built fracnav (build/fracnav)");
    return src;
}

const char *tu_sim(void)
{
    static char path[4200];
    char copy[4096];
    snprintf(copy, sizeof copy, "%s", tu_fracnav());
    snprintf(path, sizeof path, "%s/sim/fracnav-sim", dirname(copy));
    if (access(path, X_OK)) {
        print_message("%s is not built (no libfuse3): skipped\n", path);
        skip();
    }
    return path;
}

void tu_in_child(pid_t parent)
{
    prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (getppid() != parent) /* it died before the line above */
        _exit(125);
}

void tu_adopt(pid_t pid)
{
    for (int i = 0; i < MAX_CHILDREN; i++)
        if (!children[i]) {
            children[i] = pid;
            return;
        }
}

pid_t tu_spawn(char *const argv[], const char *out, FILE **err)
{
    int fds[2];
    assert_int_equal(pipe(fds), 0);
    fflush(NULL);
    pid_t parent = getpid(), pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        tu_in_child(parent);
        int o = out ? open(out, O_WRONLY | O_CREAT | O_TRUNC | O_APPEND, 0644) : 1;
        if (o < 0 || !freopen("/dev/null", "r", stdin))
            _exit(126);
        dup2(o, 1);
        dup2(err ? fds[1] : o, 2);
        close(fds[0]);
        execv(argv[0], argv);
        _exit(127);
    }
    close(fds[1]);
    if (err) {
        *err = fdopen(fds[0], "r");
        assert_non_null(*err);
        setvbuf(*err, NULL, _IONBF, 0); /* nothing hides in a buffer from tu_wait_line's poll */
    } else {
        close(fds[0]);
    }
    tu_adopt(pid);
    return pid;
}

pid_t tu_spawn_cli(const char *out, FILE **err, char *const args[])
{
    char *argv[32] = {(char *)tu_fracnav()};
    for (int i = 0; args[i]; i++) {
        assert_true(i < 30);
        argv[i + 1] = args[i];
    }
    return tu_spawn(argv, out, err);
}

static int path_exists(void *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

int tu_wait_path(const char *path)
{
    return tu_wait_for(path_exists, (void *)path, TU_WAIT_MAX_S);
}

int tu_wait_line(FILE *err, const char *needle, char *seen, size_t cap)
{
    char line[4096];
    size_t n = 0;
    struct pollfd p = {fileno(err), POLLIN, 0};
    while (poll(&p, 1, TU_WAIT_MAX_S * 1000) > 0) {
        int c = fgetc(err);
        if (c == EOF)
            break;
        if (n < sizeof line - 1)
            line[n++] = (char)c;
        if (c != '\n')
            continue;
        line[n] = '\0';
        size_t len = strlen(seen);
        snprintf(seen + len, cap - len, "%s", line);
        if (strstr(line, needle))
            return 1;
        n = 0;
    }
    line[n] = '\0';
    size_t len = strlen(seen);
    snprintf(seen + len, cap - len, "%s", line);
    return n && strstr(line, needle);
}

typedef struct served {
    pid_t pid;
    char node[4200];
} served;

/* The node is there, or the server ended (left for tu_end to reap). */
static int served_or_ended(void *arg)
{
    served *s = arg;
    siginfo_t info = {0};
    return path_exists(s->node) ||
           (waitid(P_PID, (id_t)s->pid, &info, WEXITED | WNOHANG | WNOWAIT) == 0 && info.si_pid == s->pid);
}

pid_t tu_serve(const char *mnt, const char *log, ...)
{
    char *argv[32] = {(char *)tu_sim(), "serve", "--mount", (char *)mnt};
    int n = 4;
    va_list ap;
    va_start(ap, log);
    for (const char *a = va_arg(ap, const char *); a; a = va_arg(ap, const char *)) {
        assert_true(n < 31);
        argv[n++] = (char *)a;
    }
    va_end(ap);
    served s = {tu_spawn(argv, log, NULL), ""};
    snprintf(s.node, sizeof s.node, "%s/hidraw0", mnt);
    if (!tu_wait_for(served_or_ended, &s, TU_WAIT_MAX_S) || !path_exists(s.node))
        fail_msg("fracnav-sim did not serve %s (see %s)", s.node, log);
    return s.pid;
}

void tu_unmount(const char *mnt)
{
    char cmd[4200];
    snprintf(cmd, sizeof cmd, "fusermount3 -u -z '%s' >/dev/null 2>&1", mnt);
    for (int i = 0; i < 4 && system(cmd) == 0; i++)
        ;
}

typedef struct child {
    pid_t pid;
    int status;
} child;

static int child_ended(void *arg)
{
    child *c = arg;
    return waitpid(c->pid, &c->status, WNOHANG) == c->pid;
}

static void forget(pid_t pid)
{
    for (int i = 0; i < MAX_CHILDREN; i++)
        if (children[i] == pid)
            children[i] = 0;
}

int tu_end(pid_t pid, int sig, const char *what)
{
    child c = {pid, 0};
    forget(pid);
    if (sig)
        kill(pid, sig);
    if (!tu_wait_for(child_ended, &c, TU_WAIT_MAX_S)) {
        kill(pid, SIGKILL);
        waitpid(pid, &c.status, 0);
        fail_msg("%s: still running after %d s (hangs)", what, TU_WAIT_MAX_S);
    }
    return WIFEXITED(c.status) ? WEXITSTATUS(c.status) : 128 + WTERMSIG(c.status);
}

void tu_end_all(void)
{
    for (int i = 0; i < MAX_CHILDREN; i++)
        if (children[i] > 0) {
            kill(children[i], SIGKILL);
            waitpid(children[i], NULL, 0);
            children[i] = 0;
        }
}

void tu_write_recording(const char *path, const char *device, const char *text)
{
    script *s = NULL;
    if (script_parse(text, strlen(text), path, &s) < 0)
        fail_msg("%s: %s", path, fn_err_msg());
    fnrec *r = script_render(s, sim_profile_find(device));
    free(s);
    if (!r || fnrec_save(r, path) < 0)
        fail_msg("%s: %s", path, fn_err_msg());
    fnrec_free(r);
}

fnrec *tu_render_script(const char *script_path, const char *device)
{
    script *s = script_load(script_path);
    fnrec *r = s ? script_render(s, sim_profile_find(device)) : NULL;
    free(s);
    if (!r)
        fail_msg("%s for %s: %s", script_path, device, fn_err_msg());
    return r;
}

char *tu_slurp(const char *path, size_t *len)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *b = malloc((size_t)n + 1);
    if (fread(b, 1, (size_t)n, f) != (size_t)n) {
        free(b);
        fclose(f);
        return NULL;
    }
    b[n] = '\0';
    fclose(f);
    if (len)
        *len = (size_t)n;
    return b;
}

void tu_write_file(const char *path, const void *data, size_t len)
{
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(data, 1, len, f), len);
    fclose(f);
}

void tu_box_frag(frag *f, int id, const int dim[3], const double at[3])
{
    memset(f, 0, sizeof *f);
    f->id = id;
    memcpy(f->dim, dim, sizeof f->dim);
    f->spacing[0] = f->spacing[1] = f->spacing[2] = 1;
    f->home = f->pose = POSE_IDENTITY;
    memcpy(f->home.t, at, sizeof f->home.t);
    size_t n = (size_t)dim[0] * dim[1] * dim[2];
    f->prob = malloc(n);
    assert_non_null(f->prob);
    memset(f->prob, 255, n);
    for (int a = 0; a < 3; a++)
        f->centroid[a] = at[a] + (dim[a] - 1) / 2.0;
}

struct vol *tu_ellipsoid_ct(void)
{
    vol *v = vol_new(80, 48, 42);
    assert_non_null(v);
    const double dir[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    double sp[3] = {1, 1, 1}, org[3] = {-30, 20, 5};
    vol_set_geometry(v, dir, sp, org);
    for (int k = 0; k < 42; k++)
        for (int j = 0; j < 48; j++)
            for (int i = 0; i < 80; i++) {
                double x = (i - 39.5) / 36, y = (j - 23.5) / 21, z = (k - 20.5) / 18;
                int in = x * x + y * y + z * z <= 1;
                v->data[vol_idx(v, i, j, k)] = in ? (float)(700 + (i * 7 + j * 13 + k * 3) % 400) : -50;
            }
    v->src_type = VOL_I16;
    return v;
}

struct planning_case *tu_ellipsoid_fracture(const char *dir, int pieces, unsigned long long seed, double loss_mm)
{
    vol *ct = tu_ellipsoid_ct();
    fracture_params p;
    fracture_defaults(&p);
    p.seed = seed;
    p.pieces = pieces;
    p.bone_loss_mm = loss_mm;
    p.displace_mm = 4;
    p.rotate_deg = 5;
    planning_case *c = fracture_make_case(ct, &p, dir);
    vol_free(ct);
    if (!c)
        fail_msg("%s", fn_err_msg());
    return c;
}

planning_case *tu_case_load(const char *dir)
{
    planning_case *c = case_load(dir);
    if (!c)
        fail_msg("%s", fn_err_msg());
    return c;
}

void tu_two_blocks_case(const char *dir, char *case_dir, size_t cap)
{
    vol *v = vol_new(40, 32, 32);
    for (size_t i = 0; i < vol_count(v); i++)
        v->data[i] = -1000;
    for (int k = 6; k < 26; k++)
        for (int j = 6; j < 26; j++)
            for (int i = 4; i < 16; i++)
                v->data[vol_idx(v, i, j, k)] = 1000;
    for (int k = 10; k < 22; k++)
        for (int j = 10; j < 22; j++)
            for (int i = 18; i < 28; i++)
                v->data[vol_idx(v, i, j, k)] = 1000;
    char path[4200];
    snprintf(path, sizeof path, "%s/blocks.nii.gz", dir);
    assert_int_equal(volio_write(v, path, VOL_I16), 0);
    vol_free(v);
    snprintf(case_dir, cap, "%s/case", dir);
    tu_segment(path, case_dir, "--ramp 0");
    assert_int_equal(tu_run_cli(NULL, "edit '%s' fix 1", case_dir), 0);
}
