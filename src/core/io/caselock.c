/* caselock: flock on CASE/.fracnav-lock, with the holder named in the file (see caselock.h). */
#define _GNU_SOURCE /* O_NOFOLLOW, flock */
#include "caselock.h"

#include "durable.h"
#include "err.h"

#include <errno.h>
#include <signal.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

struct caselock {
    int fd; /* -1: a folder that holds no case or cannot hold the lock file, read unlocked */
};

/* "PID COMMAND LINE\n", the command line from /proc/self/cmdline, its program without folder. */
static int holder_line(char *out, size_t cap)
{
    char args[1024] = "";
    ssize_t n = 0;
    int fd = open("/proc/self/cmdline", O_RDONLY | O_CLOEXEC);
    if (fd >= 0) {
        n = read(fd, args, sizeof args - 1);
        close(fd);
    }
    args[n > 0 ? n : 0] = '\0';
    const char *slash = strrchr(args, '/'), *prog = slash ? slash + 1 : args; /* argv[0] ends at a NUL */
    for (ssize_t i = 0; i + 1 < n; i++)
        if (args[i] == '\0' || args[i] == '\n')
            args[i] = ' ';
    int m = snprintf(out, cap, "%ld %s\n", (long)getpid(), *prog ? prog : "fracnav");
    return m < 0 ? 0 : (size_t)m >= cap ? (int)cap - 1 : m;
}

/* Who holds the lock, as its holder wrote it: "`COMMAND` (pid PID)", when that process lives. */
static void describe_holder(int fd, char *out, size_t cap)
{
    char line[1100];
    ssize_t n = pread(fd, line, sizeof line - 1, 0);
    line[n > 0 ? n : 0] = '\0';
    line[strcspn(line, "\n")] = '\0';
    char *end;
    long pid = strtol(line, &end, 10);
    /* The last taker wrote the line; a reader that took the lock after the others may be gone. */
    if (pid > 0 && *end == ' ' && kill((pid_t)pid, 0) == 0)
        snprintf(out, cap, "`%s` (pid %ld)", end + 1, pid);
    else
        snprintf(out, cap, "another fracnav process");
}

/* The lock file's descriptor, or -1 (with *rc 0) where there is no case or no lock file can be. */
static int open_lock(const char *dir, const char *path, int exclusive, int *rc)
{
    char json[4200];
    struct stat sb;
    *rc = 0;
    snprintf(json, sizeof json, "%s/case.json", dir);
    if (lstat(json, &sb) != 0)
        return -1; /* no case to protect: the command's own load (or a new case) says what is wrong */
    int fd = open(path, O_RDWR | O_CREAT | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC, 0644);
    if (fd < 0 && !exclusive && (errno == EACCES || errno == EROFS)) {
        fd = open(path, O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
        if (fd < 0 && (errno == ENOENT || errno == EACCES))
            return -1; /* a read-only folder without a lock file: nobody can write there */
    }
    if (fd < 0 && errno == ELOOP)
        *rc = fn_err_set(FN_EIO, "%s is a symbolic link: fracnav does not lock through one; remove it",
                         path);
    else if (fd < 0)
        *rc = fn_err_set(FN_EIO, "%s: cannot open the case's lock: %s", path, strerror(errno));
    else if (fstat(fd, &sb) != 0 || !S_ISREG(sb.st_mode)) {
        close(fd);
        fd = -1;
        *rc = fn_err_set(FN_EIO, "%s: not a regular file (the case's lock must be one)", path);
    }
    return fd;
}

/* 1 when fd is still the file at path (the folder was not replaced, the file not removed). */
static int still_there(int fd, const char *path)
{
    struct stat a, b;
    return fstat(fd, &a) == 0 && lstat(path, &b) == 0 && a.st_dev == b.st_dev && a.st_ino == b.st_ino;
}

caselock *caselock_take(const char *dir, int exclusive, int wait)
{
    char path[4200];
    int n = snprintf(path, sizeof path, "%s/" CASELOCK_FILE, dir);
    if (n < 0 || (size_t)n >= sizeof path) {
        fn_err_set(FN_EINVAL, "%s: path too long", dir);
        return NULL;
    }
    int op = exclusive ? LOCK_EX : LOCK_SH, said = 0, rc = 0, fd;
    for (;;) {
        fd = open_lock(dir, path, exclusive, &rc);
        if (fd < 0)
            break;
        if (flock(fd, op | LOCK_NB) != 0) {
            int e = errno;
            char who[1200];
            describe_holder(fd, who, sizeof who);
            if (e != EWOULDBLOCK)
                rc = fn_err_set(FN_EIO, "%s: cannot lock: %s", path, strerror(e));
            else if (!wait)
                rc = fn_err_set(FN_EAGAIN, "%s is in use by %s; --wait waits for it", dir, who);
            else if (!said++)
                fprintf(stderr, "fracnav: %s is in use by %s; waiting for it\n", dir, who);
            while (rc == 0 && flock(fd, op) != 0)
                if (errno != EINTR)
                    rc = fn_err_set(FN_EIO, "%s: cannot lock: %s", path, strerror(errno));
        }
        if (rc < 0 || still_there(fd, path))
            break;
        close(fd); /* the case was replaced or its lock removed meanwhile: lock the one there now */
    }
    if (rc < 0) {
        if (fd >= 0)
            close(fd);
        return NULL;
    }
    caselock *l = malloc(sizeof *l);
    if (!l) {
        if (fd >= 0)
            close(fd);
        fn_err_set(FN_ENOMEM, "%s: out of memory", path);
        return NULL;
    }
    l->fd = fd;
    if (fd >= 0) {
        char line[1100];
        int len = holder_line(line, sizeof line);
        /* Best effort: the lock holds whether or not its holder could be named. */
        if (pwrite(fd, line, (size_t)len, 0) == len && ftruncate(fd, len) != 0)
            fprintf(stderr, "fracnav: %s: cannot name the holder: %s\n", path, strerror(errno));
        if (exclusive)
            durable_sweep(dir, 1);
    }
    return l;
}

void caselock_release(caselock *l)
{
    if (!l)
        return;
    if (l->fd >= 0)
        close(l->fd); /* closing the last descriptor releases the flock */
    free(l);
}
