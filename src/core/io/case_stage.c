/* case_stage_*: a whole case folder written aside and put in place in one rename, so that a kill
 * at any moment leaves the old case or the new one at its path, never a mix of the two or a
 * half-made folder. */
#define _GNU_SOURCE /* renameat2 */
#include "case.h"

#include "durable.h"
#include "err.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define STAGE_TAG ".new-" /* a staged folder: PARENT/.NAME.new-PID */

/* dir split into its parent and its last component, trailing slashes dropped. */
static int split_dir(const char *dir, char *parent, size_t pcap, char *base, size_t bcap)
{
    char d[4096];
    size_t n = strlen(dir);
    while (n > 1 && dir[n - 1] == '/')
        n--;
    if (n == 0 || n >= sizeof d)
        return fn_err_set(FN_EINVAL, "case folder '%s': empty or too long", dir);
    memcpy(d, dir, n);
    d[n] = '\0';
    char *slash = strrchr(d, '/');
    const char *b = slash ? slash + 1 : d;
    if (!strcmp(b, ".") || !strcmp(b, "..") || !strcmp(d, "/"))
        return fn_err_set(FN_EINVAL, "case folder '%s': name a folder, not . or .. or /", dir);
    if (slash == d)
        snprintf(parent, pcap, "/");
    else if (slash) {
        *slash = '\0';
        snprintf(parent, pcap, "%s", d);
    } else
        snprintf(parent, pcap, ".");
    if (strlen(b) >= bcap)
        return fn_err_set(FN_EINVAL, "case folder '%s': name too long", dir);
    memcpy(base, b, strlen(b) + 1);
    return 0;
}

/* Removes a folder's plain files, then the folder; a folder inside it is left alone (a case holds
 * none), and so is the folder then. 0, or -1 when something stayed. */
static int remove_flat(const char *path)
{
    DIR *d = opendir(path);
    if (!d)
        return errno == ENOENT ? 0 : -1;
    struct dirent *e;
    char p[8400];
    while ((e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) {
            snprintf(p, sizeof p, "%s/%s", path, e->d_name);
            unlink(p);
        }
    closedir(d);
    return rmdir(path) == 0 ? 0 : -1;
}

/* Staged folders of `base` left by a process that is gone (killed mid-write) are removed; an old
 * case set aside by exchange()'s fallback goes back in place when nothing took it. */
static void remove_stale(const char *parent, const char *base, const char *dir)
{
    char prefix[4200];
    snprintf(prefix, sizeof prefix, ".%s" STAGE_TAG, base);
    size_t plen = strlen(prefix);
    DIR *d = opendir(parent);
    if (!d)
        return;
    struct dirent *e;
    char p[8400];
    while ((e = readdir(d))) {
        if (strncmp(e->d_name, prefix, plen))
            continue;
        char *end;
        long pid = strtol(e->d_name + plen, &end, 10);
        int old = !strcmp(end, ".old");
        if ((*end && !old) || pid <= 0 || kill((pid_t)pid, 0) == 0 || errno != ESRCH)
            continue;
        snprintf(p, sizeof p, "%s/%s", parent, e->d_name);
        if (old && access(dir, F_OK) != 0 && rename(p, dir) == 0)
            fprintf(stderr, "fracnav: put back %s, the case an interrupted run had set aside in %s\n",
                    dir, p);
        else if (remove_flat(p) == 0)
            fprintf(stderr, "fracnav: removed %s, left by an interrupted run\n", p);
    }
    closedir(d);
}

static int folder_is_empty(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d)
        return 0;
    struct dirent *e;
    int empty = 1;
    while (empty && (e = readdir(d)))
        empty = !strcmp(e->d_name, ".") || !strcmp(e->d_name, "..");
    closedir(d);
    return empty;
}

/* 1 when path (a file) lies inside dir. */
static int inside(const char *path, const char *dir)
{
    char rp[4096], rd[4096];
    if (!realpath(path, rp) || !realpath(dir, rd))
        return 0;
    size_t n = strlen(rd);
    return !strncmp(rp, rd, n) && rp[n] == '/';
}

int case_stage_begin(const char *dir, int force, const char *keep, char *tmp, size_t cap)
{
    char parent[4096], base[1024];
    int rc = split_dir(dir, parent, sizeof parent, base, sizeof base);
    if (rc < 0)
        return rc;
    remove_stale(parent, base, dir);
    struct stat sb;
    if (stat(dir, &sb) == 0) {
        char json[4200];
        snprintf(json, sizeof json, "%s/case.json", dir);
        if (!S_ISDIR(sb.st_mode))
            return fn_err_set(FN_EINVAL, "%s exists and is not a folder", dir);
        if (!folder_is_empty(dir) && access(json, F_OK) != 0)
            return fn_err_set(FN_EINVAL, "%s is a folder with files but no case.json: choose "
                                         "another folder for the case", dir);
        if (!folder_is_empty(dir) && !force)
            return fn_err_set(FN_EINVAL, "%s holds a case already; --force replaces it (with its "
                                         "journal)", dir);
        if (keep && inside(keep, dir))
            return fn_err_set(FN_EINVAL, "%s lies inside %s, which would be replaced: copy it "
                                         "elsewhere first", keep, dir);
    }
    int n = snprintf(tmp, cap, "%s/.%s" STAGE_TAG "%ld", parent, base, (long)getpid());
    if (n < 0 || (size_t)n >= cap)
        return fn_err_set(FN_EINVAL, "case folder '%s': path too long", dir);
    remove_flat(tmp);
    if (mkdir(tmp, 0755) != 0)
        return fn_err_set(FN_EIO, "%s: cannot create: %s", tmp, strerror(errno));
    return 0;
}

/* Every file of the staged folder on disk before the folder is put in place. */
static int sync_folder(const char *tmp)
{
    DIR *d = opendir(tmp);
    if (!d)
        return fn_err_set(FN_EIO, "%s: cannot open: %s", tmp, strerror(errno));
    struct dirent *e;
    char p[8400];
    int rc = 0;
    while (rc == 0 && (e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) {
            snprintf(p, sizeof p, "%s/%s", tmp, e->d_name);
            rc = durable_sync_path(p);
        }
    closedir(d);
    return rc == 0 ? durable_sync_path(tmp) : rc;
}

/* dir holds a case: the staged folder and dir trade places in one step, the old case is removed. */
static int exchange(const char *tmp, const char *dir)
{
    if (renameat2(AT_FDCWD, tmp, AT_FDCWD, dir, RENAME_EXCHANGE) == 0)
        return 0;
    if (errno != EINVAL && errno != ENOSYS)
        return fn_err_set(FN_EIO, "%s: cannot put %s in its place: %s", dir, tmp, strerror(errno));
    /* A file system without exchange: the old case steps aside under a name of its own first. */
    char old[4300];
    snprintf(old, sizeof old, "%s.old", tmp);
    if (rename(dir, old) != 0)
        return fn_err_set(FN_EIO, "%s: cannot move aside: %s", dir, strerror(errno));
    if (rename(tmp, dir) != 0) {
        int e = errno;
        rename(old, dir);
        return fn_err_set(FN_EIO, "%s: cannot put %s in its place: %s", dir, tmp, strerror(e));
    }
    return rename(old, tmp) == 0 ? 0 : fn_err_set(FN_EIO, "%s: %s", old, strerror(errno));
}

/* A case that another process saved at dir after case_stage_begin found none there. */
static int appeared(const char *dir)
{
    return fn_err_set(FN_EINVAL, "%s: another process saved a case there while this one worked; it "
                                 "is kept (--force replaces it)", dir);
}

int case_stage_commit(const char *tmp, const char *dir, int force)
{
    char parent[4096], base[1024];
    int rc = split_dir(dir, parent, sizeof parent, base, sizeof base);
    if (rc == 0)
        rc = sync_folder(tmp);
    if (rc < 0)
        return rc;
    struct stat sb;
    int replace = stat(dir, &sb) == 0 && !folder_is_empty(dir);
    if (replace && !force)
        return appeared(dir); /* begin found none: a second writer of one new case */
    if (replace)
        rc = exchange(tmp, dir);
    else if (rename(tmp, dir) != 0) /* never over a folder that filled meanwhile (ENOTEMPTY) */
        rc = errno == ENOTEMPTY || errno == EEXIST
                 ? appeared(dir)
                 : fn_err_set(FN_EIO, "%s: cannot rename %s to it: %s", dir, tmp, strerror(errno));
    if (rc == 0)
        rc = durable_sync_path(parent);
    if (rc == 0 && replace && remove_flat(tmp) != 0)
        fprintf(stderr, "fracnav: the replaced case stays in %s (it holds a folder); remove it by "
                        "hand\n", tmp);
    return rc;
}

void case_stage_abort(const char *tmp)
{
    if (tmp[0])
        remove_flat(tmp);
}
