/* caselock: the lock on a case folder, so that two commands never write one case at once.
 *
 * A flock(2) on CASE/.fracnav-lock (created O_NOFOLLOW, a regular file): shared for commands that
 * only read the case (render, export), exclusive for those that write it (edit, reduce, navigate
 * for its whole session, replay when it keeps a journal, segment and fracture replacing a case).
 * The holder writes its pid and command line into the file, so that a command refused can say who
 * holds the case: "CASE is in use by `fracnav navigate CASE` (pid 1234); --wait waits for it".
 * Whoever takes the exclusive lock removes what interrupted writers left in the folder
 * (durable_sweep). The lock goes with the process: a killed holder releases it.
 *
 * A case folder replaced while a waiter waited (segment --force swaps the whole folder) is noticed:
 * the waiter takes the lock of the folder now at the path. Where there is no case (no folder, or
 * no case.json: a new case, or a path the command's own load will refuse) and where a read-only
 * folder cannot hold the lock file, the handle holds no lock: there is nothing to protect, or a
 * write there fails anyway. */
#ifndef FN_CASELOCK_H
#define FN_CASELOCK_H

#define CASELOCK_FILE ".fracnav-lock"

typedef struct caselock caselock;

/* Takes dir's lock, exclusive or shared. When another process holds it in a mode that excludes
 * this one: waits for it when wait, else fails at once with FN_EAGAIN and a message naming the
 * case, the holder's command and pid, and --wait. Waiting is said once on stderr. Other failures
 * (the lock file a link or not a regular file) are FN_EIO naming the path. The lock, or NULL with fn_err. */
caselock *caselock_take(const char *dir, int exclusive, int wait);
/* Releases the lock (NULL: nothing). */
void caselock_release(caselock *l);

#endif
