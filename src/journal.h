/* journal: the append-only record of every accepted pose, CASE/journal, for crash recovery.
 *
 * File format (binary, little-endian, documented here and nowhere else):
 *   header, 16 bytes: "FNJOURNAL1\n" (11 bytes), 1 byte 0, u32 record size (88);
 *   records, 88 bytes each:
 *     u32 kind (JOURNAL_MOVE 1: a move; JOURNAL_START 4: the first move of a gesture, so undo
 *     returns to the fragment's pose before it; JOURNAL_UNDO 2, JOURNAL_REDO 3: the pose an undo
 *     or redo restored), i32 fragment index (0-based,
 *     the case's order), u64 sequence number (1, 2, ...), i64 report time (us),
 *     f64 q[4] (w x y z), f64 t[3] (mm): the fragment's pose (home world -> current world),
 *     u32 reserved 0, u32 CRC-32 (zlib) of the 84 bytes before it.
 * A crash can tear only the last record; readers stop at the first record whose size or CRC is
 * wrong and say where. Appends are buffered and written out (write(2), no fsync) whenever the
 * oldest buffered record is flush_us old (default 50 ms), so a killed process loses at most the
 * last 50-100 ms; journal_sync also fsyncs. After the case is saved, journal_truncate empties it:
 * the journal only ever holds poses newer than case.json.
 *
 * Not thread-safe: one thread appends (the loop's). journal_append never allocates. */
#ifndef FN_JOURNAL_H
#define FN_JOURNAL_H

#include "pose.h"

#include <stddef.h>
#include <stdint.h>

#define JOURNAL_RECORD_SIZE 88
#define JOURNAL_HEADER_SIZE 16

enum { JOURNAL_MOVE = 1, JOURNAL_UNDO = 2, JOURNAL_REDO = 3, JOURNAL_START = 4 };

typedef struct journal_rec {
    uint32_t kind;
    int32_t frag;
    uint64_t seq;
    int64_t t_us;
    pose p;
} journal_rec;

typedef struct journal journal;

/* Opens (creating if needed) DIR/journal for appending. Existing valid records are kept and
 * numbering continues after them; a torn tail is cut off. NULL with fn_err naming the file. */
journal *journal_open(const char *case_dir);
/* Writes out what is buffered and closes. Returns 0 or FN_EIO from the final write. */
int journal_close(journal *j);
/* Buffers one record (seq is assigned). now_us is a monotonic clock that drives the flush. */
int journal_append(journal *j, uint32_t kind, int frag, int64_t t_us, const pose *p, int64_t now_us);
/* Flushes when the oldest buffered record is flush_us old; call it while idle too. */
int journal_tick(journal *j, int64_t now_us);
/* write(2)s the buffer now. */
int journal_flush(journal *j);
/* Flush, then fsync. */
int journal_sync(journal *j);
/* Empties the journal (after a successful case save). */
int journal_truncate(journal *j);
/* Records appended through this handle plus those found at open. */
uint64_t journal_count(const journal *j);
/* Flush interval (microseconds). */
void journal_set_flush_us(journal *j, int64_t flush_us);

/* Parses a journal's bytes (pure; name is for messages): *recs (malloc'd, caller frees; NULL when
 * none) and *n. A torn or corrupt tail is not an error: *n counts the valid records before it and
 * *torn_at (if not NULL) gets its byte offset (-1 when clean). FN_EFORMAT for a bad header. */
int journal_parse(const uint8_t *buf, size_t len, const char *name, journal_rec **recs, size_t *n,
                  long *torn_at);
/* Reads and parses DIR/journal (size checked against vol_budget). A missing file is 0 records.
 * A torn or corrupt tail is not an error: *n counts the valid records before it and *torn_at
 * (if not NULL) gets its byte offset (-1 when clean). FN_EFORMAT for a bad header. */
int journal_read(const char *case_dir, journal_rec **recs, size_t *n, long *torn_at);
/* Applies the records in order to poses[0..nfrag-1] (each record sets its fragment's pose).
 * Returns 0, or FN_EFORMAT when a record names a fragment outside 0..nfrag-1 (the message names
 * the record). */
int journal_final_poses(const journal_rec *recs, size_t n, int nfrag, pose *poses);

#endif
