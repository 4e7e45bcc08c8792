/* case_journal: a case and its journal reconciled. A journal extends one state of its case (the
 * case.json it is bound to, see journal.h); before any command uses or changes a case it checks:
 *   - damage (a bad header, a bad record anywhere): the whole journal is kept aside as
 *     CASE/journal.damaged.N, and the good records before the damage stay as CASE/journal;
 *   - a journal bound to this case.json: its records are pending (recover or discard them);
 *   - a journal bound to another case.json whose poses the case already holds (a save that ended
 *     before the journal was emptied): emptied, nothing is lost;
 *   - any other journal (the case was edited, segmented anew, or restored since): never applied,
 *     kept aside as CASE/journal.mismatch.N.
 * Every such step is said on stderr, naming the files. */
#ifndef FN_CASE_JOURNAL_H
#define FN_CASE_JOURNAL_H

#include "case.h"
#include "journal.h"

/* The binding of a journal that extends c as loaded or last saved. */
void case_journal_bind(const planning_case *c, journal_bind *b);

/* Reconciles c->dir's journal with c as above. recs, n: the pending records (malloc'd, caller
 * frees; none: NULL, 0). Returns 0, 1 when a journal was refused and kept aside (its poses not
 * applied), or FN_E* (an unreadable journal). */
int case_journal_check(const planning_case *c, journal_rec **recs, size_t *n);

/* Pending records of DIR/journal bound to DIR/case.json as it is now (0 when none, unreadable,
 * damaged or bound elsewhere): what an interrupted session left to recover. Reads no volume. */
size_t case_journal_pending(const char *dir);

/* The journal's pending records applied to c's poses (edit does this before it changes the case).
 * 0 or FN_EFORMAT. */
int case_journal_apply(planning_case *c, const journal_rec *recs, size_t n);

/* Removes c->dir's journal once c (saved) holds its poses. 0 or FN_EIO. */
int case_journal_remove(const planning_case *c);

#endif
