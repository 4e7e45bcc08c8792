/* volio_dicom: a folder of DICOM files, converted by dcm2niix into a private temporary folder,
 * read as NIfTI, then removed. dcm2niix sorts the series, applies rescale slope/intercept and,
 * for gantry tilt, writes a resampled copy (_Tilt_) that is preferred over the sheared one. */
#include "volio_impl.h"

#include "err.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

extern char **environ;

#define PATH_CAP 4096

static int ends_with(const char *s, const char *suffix)
{
    size_t n = strlen(s), m = strlen(suffix);
    return n >= m && !strcmp(s + n - m, suffix);
}

/* Runs dcm2niix with its output in log; returns its exit status, 127 if it could not start. */
static int run_dcm2niix(const char *dir, const char *out, const char *log)
{
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, STDOUT_FILENO, log, O_WRONLY | O_CREAT | O_TRUNC | O_NOFOLLOW, 0600);
    posix_spawn_file_actions_adddup2(&fa, STDOUT_FILENO, STDERR_FILENO);
    /* posix_spawn takes char *const argv[]: give it writable copies rather than casting const away. */
    char prog[] = "dcm2niix", z[] = "-z", b[] = "-b", no[] = "n", o[] = "-o", f[] = "-f", name[] = "vol";
    char outb[4096], dirb[4096];
    if (snprintf(outb, sizeof outb, "%s", out) >= (int)sizeof outb ||
        snprintf(dirb, sizeof dirb, "%s", dir) >= (int)sizeof dirb) {
        posix_spawn_file_actions_destroy(&fa);
        return fn_err_set(FN_EINVAL, "%s: path too long for dcm2niix", dir);
    }
    char *argv[] = {prog, z, no, b, no, o, outb, f, name, dirb, NULL};
    pid_t pid;
    int rc = posix_spawnp(&pid, "dcm2niix", &fa, NULL, argv, environ);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0)
        return 127;
    int st;
    while (waitpid(pid, &st, 0) < 0)
        if (errno != EINTR)
            return 127;
    return WIFEXITED(st) ? WEXITSTATUS(st) : 128;
}

/* The last "Error" line dcm2niix printed, for the error message. */
static void last_line(const char *log, char *buf, size_t cap)
{
    char line[512];
    FILE *f = fopen(log, "r");
    buf[0] = '\0';
    if (!f)
        return;
    while (fgets(line, sizeof line, f)) {
        line[strcspn(line, "\r\n")] = '\0';
        if (!strncmp(line, "Error", 5))
            snprintf(buf, cap, "%.*s", (int)cap - 1, line);
    }
    fclose(f);
}

/* Picks the NIfTI to read: the tilt-corrected one, else the equalized one, else the only one.
 * Returns the number of plain series found (so 0 = none, >1 = ambiguous). */
static int pick_output(const char *out, char *pick, size_t cap)
{
    DIR *d = opendir(out);
    int plain = 0, best = 0; /* best: 3 tilt, 2 equalized, 1 plain */
    struct dirent *e;
    while (d && (e = readdir(d))) {
        if (!ends_with(e->d_name, ".nii"))
            continue;
        int rank = strstr(e->d_name, "_Tilt_") ? 3 : strstr(e->d_name, "_Eq_") ? 2 : 1;
        plain += rank == 1;
        if (rank > best) {
            best = rank;
            snprintf(pick, cap, "%s/%s", out, e->d_name);
        }
    }
    if (d)
        closedir(d);
    return best > 1 ? 1 : plain;
}

static void remove_tree(const char *out)
{
    DIR *d = opendir(out);
    struct dirent *e;
    char p[PATH_CAP + 300];
    while (d && (e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) {
            snprintf(p, sizeof p, "%s/%s", out, e->d_name);
            unlink(p);
        }
    if (d)
        closedir(d);
    rmdir(out);
}

vol *volio__read_dicom(const char *dir)
{
    const char *tmp = getenv("TMPDIR");
    char out[PATH_CAP], log[PATH_CAP + 16], pick[PATH_CAP + 300], why[256];
    snprintf(out, sizeof out, "%s/fracnav-dcm2niix-XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(out)) {
        fn_err_set(FN_EIO, "%s: cannot make a temporary folder %s: %s", dir, out, strerror(errno));
        return NULL;
    }
    snprintf(log, sizeof log, "%s/dcm2niix.log", out);
    int st = run_dcm2niix(dir, out, log);
    vol *v = NULL;
    last_line(log, why, sizeof why);
    int n = st == 127 ? 0 : pick_output(out, pick, sizeof pick);
    if (st == 127)
        fn_err_set(FN_EIO, "%s: cannot run dcm2niix (install the dcm2niix package)", dir);
    else if (n == 0)
        fn_err_set(FN_EFORMAT, "%s: no DICOM series found (dcm2niix exit %d%s%s)", dir, st,
                   why[0] ? ": " : "", why);
    else if (n > 1)
        fn_err_set(FN_EFORMAT, "%s: the folder holds %d DICOM series; give a folder with one", dir, n);
    else if (!(v = volio__read_nifti(pick)))
        fn_err_wrap(FN_EFORMAT, "%s: dcm2niix's output", dir);
    remove_tree(out);
    return v;
}
