/* durable: the one layer that writes files which must survive a kill or a crash, in the manner of
 * SQLite's VFS: every save of the project (case, journal, exports, pictures, calibration) goes
 * through it, so the rules for not losing data, and for not being redirected, live here.
 *
 * An atomic replace of PATH:
 *   1. durable_create makes a temporary beside it, DIR/.fracnav-tmp-PID-N-NAME (N counts per
 *      process, so two threads or two processes never share one; NAME keeps PATH's extension for
 *      writers that choose a format by it), opened O_CREAT|O_EXCL|O_NOFOLLOW: a name planted there
 *      (a link, a file) is never written through, the create fails instead. It first removes the
 *      temporaries that dead processes left in DIR (durable_sweep).
 *   2. The caller writes it: through f->fd (durable_write_all, durable_stream), or by its name
 *      f->tmp for a library that only takes a name (nifticlib, teem).
 *   3. durable_seal checks that f->tmp is still the regular file that step 1 created (a link or
 *      another file put there meanwhile is refused), then fsyncs and closes it.
 *   4. durable_rename refuses a PATH that is a symbolic link or not a regular file (so a link is
 *      never replaced silently nor written through) and renames the temporary over PATH.
 *   5. durable_sync_path fsyncs the folder, so the rename itself is on disk.
 * durable_replace does the five steps for one file. A file that exists already (a case's undo step)
 * takes steps 1 to 3 at once by durable_link; a file renamed within its folder (a journal set aside,
 * the previous labels put back) goes by durable_move, which checks and syncs as steps 4 and 5 do.
 * A kill at any step leaves PATH as it was or as it was meant to be, and at most a temporary, which
 * durable_sweep removes once its process is gone.
 *
 * Reading: durable_open_regular opens a regular file without blocking on a FIFO; durable_sha256
 * and durable_file_sha256 give the checksums that bind a case to its files.
 *
 * Every function returns 0 (or a descriptor) or a negative FN_E* code with a message naming the
 * path (err.h). Thread-safe: no state but an atomic counter. */
#ifndef FN_DURABLE_H
#define FN_DURABLE_H

#include <stddef.h>
#include <stdio.h>
#include <sys/types.h>

#define DURABLE_TMP_TAG ".fracnav-tmp-" /* every temporary's name starts so: DIR/.fracnav-tmp-PID-N-NAME */

typedef struct durable_file {
    char tmp[4352]; /* the temporary's path */
    int fd;         /* open for writing until durable_seal; -1 after */
    dev_t dev;      /* what durable_create made, checked again by durable_seal */
    ino_t ino;
} durable_file;

/* Step 1: creates the temporary for path (see above). */
int durable_create(durable_file *f, const char *path);
/* Writes n bytes at the temporary's current offset. */
int durable_write_all(durable_file *f, const void *p, size_t n);
/* A stdio stream on the temporary (its own descriptor; fclose it before durable_seal, and count a
 * failed fclose as a failed write). NULL with fn_err when out of memory. */
FILE *durable_stream(durable_file *f);
/* Step 3: still our regular file, fsync, close. */
int durable_seal(durable_file *f);
/* Step 4: refuses a link or non-regular path, and a temporary that is no longer the file step 1
 * made (or durable_link linked), and renames the sealed temporary over it. */
int durable_rename(durable_file *f, const char *path);
/* Steps 1 to 3 for a file that exists already (a case's undo step): the temporary for path is a
 * hard link to src, a regular file (a link there is refused, never followed), made by link(2)
 * under durable_create's name, so a name planted there fails it. Nothing to write or seal: next
 * durable_rename, then durable_sync_path. */
int durable_link(durable_file *f, const char *src, const char *path);
/* After a failure at any step: closes and removes the temporary (only if it is still ours). */
void durable_abort(durable_file *f);
/* Step 5, and for files already written (a staged case folder): fsyncs a file or a folder (a file
 * system that cannot sync a folder is no error). */
int durable_sync_path(const char *path);

/* Renames from, a regular file (never a link), to the name to in the same folder, which must be
 * missing or a regular file (a link there is refused, never replaced), then fsyncs the folder: a
 * file set aside (a journal), or a kept copy put back (a case's previous labels). */
int durable_move(const char *from, const char *to);

/* The five steps for one file: write(f, ctx) fills the temporary. Refuses a path that is a link or
 * not a regular file before writing anything. */
int durable_replace(const char *path, int (*write)(durable_file *f, void *ctx), void *ctx);
/* durable_replace of n bytes. */
int durable_replace_bytes(const char *path, const void *p, size_t n);

/* Opens path for appending records in place (a journal): created when missing, never through a
 * link (O_NOFOLLOW), and refused when it is not a regular file. The descriptor (O_WRONLY). */
int durable_open_log(const char *path);

/* Removes the temporaries that interrupted writers left in folder dir: those whose process is
 * gone, or, when all (the caller holds the folder's exclusive lock, so nobody else writes there),
 * every one but this process's own. Says each removal on stderr. Returns how many were removed. */
int durable_sweep(const char *dir, int all);

/* A case folder is one that holds this file (the io layer's case.json): only the case's own saves
 * write there. */
#define DURABLE_CASE_FILE "case.json"
/* Checks an output path of a command, other than the case's own files (an export, a picture, a
 * recording: fracnav's and fracnav-sim's), before anything is written: 0, or FN_EINVAL naming the
 * path when the folder that holds it (links resolved) is a case folder or does not exist. */
int durable_out_of_case(const char *path);

/* Opens a regular file for reading (never blocks on a FIFO); what, if not NULL, is added to the
 * message. The descriptor, or FN_EIO naming the path. */
int durable_open_regular(const char *path, const char *what);
/* sha256 (FIPS 180-4) as 64 hex digits: of bytes, and of a regular file's content (FN_EIO for a
 * file that is not regular: a FIFO or a device would never end or never start). */
void durable_sha256(const void *data, size_t len, char hex[65]);
int durable_file_sha256(const char *path, char hex[65]);
/* For tests: durable_sha256 by the portable rounds alone, where the processor's SHA extensions would
 * otherwise be used. */
void durable__sha256_portable(const void *data, size_t len, char hex[65]);

#endif
