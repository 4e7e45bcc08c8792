/* journal: the append-only record of every accepted pose, CASE/journal, for crash recovery.
 *
 * File format (binary, little-endian, documented here and nowhere else):
 *   header, 256 bytes: "FNJOURNAL2\n" (11 bytes), 1 byte 0, u32 record size (88), then what the
 *     journal is bound to -- the case state its records extend: 64 bytes the sha256 of case.json
 *     (hex), u32 the number of fragments (<= JOURNAL_MAX_FRAGS), u16 ids[JOURNAL_MAX_FRAGS] (the
 *     fragment ids in the case's order, unused ones 0), zeros up to byte 252, u32 CRC-32 (zlib)
 *     of the 252 bytes before it;
 *   records, 88 bytes each:
 *     u32 kind (JOURNAL_MOVE 1: a move; JOURNAL_START 4: the first move of a gesture, so undo
 *     returns to the fragment's pose before it; JOURNAL_UNDO 2, JOURNAL_REDO 3: the pose an undo
 *     or redo restored; JOURNAL_FIX 5: the fragment was fixed or freed, its pose unchanged),
 *     i32 fragment index (0-based, the case's order, below the header's count), u64 sequence
 *     number (one more than the record before), i64 report time (us), f64 q[4] (w x y z, unit
 *     length within 1e-6 as case.json's poses), f64 t[3] (mm, finite): the fragment's pose (home
 *     world -> current world), u32 flag (JOURNAL_FIX: 1 fixed, 0 freed; 0 for the other kinds),
 *     u32 CRC-32 (zlib) of the 84 bytes before it.
 * Readers stop at the first record that breaks any of these rules and say which record, at which
 * offset, and why (journal_scan.damage); what precedes it is good. A reader never reads more
 * records than the memory budget holds (vol_budget), whatever the file's size.
 *
 * Appends are buffered and written out (write(2), no fsync) whenever the oldest buffered record is
 * JOURNAL_FLUSH_US old (50 ms): a killed process loses the poses of about the last 50 ms (at
 * 1 kHz, up to 50 poses), plus however long a busy machine kept the loop thread from its next
 * tick (tests/killtable.py measured 27-93 ms on a loaded 2-core machine); the loop calls
 * journal_tick every tick, so the bound holds while it is idle too. A power cut can lose what the system had not yet written to disk: journal_sync fsyncs.
 * After the case is saved, journal_rebind names the new case.json and journal_truncate empties the
 * journal: it only ever holds poses newer than the case.json it is bound to.
 *
 * Not thread-safe: one thread appends (the loop's). journal_append never allocates. */
#ifndef FN_JOURNAL_H
#define FN_JOURNAL_H

#include "pose.h"

#include <stddef.h>
#include <stdint.h>

#define JOURNAL_RECORD_SIZE 88
#define JOURNAL_HEADER_SIZE 256
#define JOURNAL_MAX_FRAGS 64
#define JOURNAL_FLUSH_US 50000 /* buffered records are written out at this age */

enum { JOURNAL_MOVE = 1, JOURNAL_UNDO = 2, JOURNAL_REDO = 3, JOURNAL_START = 4, JOURNAL_FIX = 5 };

typedef struct journal_rec {
    uint32_t kind;
    int32_t frag;
    uint64_t seq;
    int64_t t_us;
    pose p;
    uint32_t flag; /* JOURNAL_FIX: 1 fixed, 0 freed */
} journal_rec;

/* The case state a journal extends. */
typedef struct journal_bind {
    char case_sha256[65]; /* of case.json, hex */
    int nfrag;
    uint16_t ids[JOURNAL_MAX_FRAGS];
} journal_bind;

/* A journal as read: its binding, its good records, and what is wrong after them. */
typedef struct journal_scan {
    journal_bind bind;
    journal_rec *recs; /* malloc'd (journal_scan_free), NULL when none */
    size_t n;
    long damaged_at;   /* byte offset of the first bad byte, -1 when the journal is whole */
    char damage[4400]; /* when damaged_at >= 0: "FILE: record K at offset X: why" */
} journal_scan;

typedef struct journal journal;

/* Opens (creating if needed) DIR/journal for appending, bound to b. Existing records are kept
 * and numbering continues after them; they must be whole and bound to b (FN_EFORMAT naming the
 * damage, FN_EMISMATCH otherwise: resolve that first, see case_journal_check). A journal with no
 * record gets b's header. NULL with fn_err naming the file. */
journal *journal_open(const char *case_dir, const journal_bind *b);
/* Writes out what is buffered and closes. Returns 0 or FN_EIO from the final write. */
int journal_close(journal *j);
/* Buffers one record (seq is assigned). now_us is a monotonic clock that drives the flush. */
int journal_append(journal *j, uint32_t kind, int frag, int64_t t_us, const pose *p, int64_t now_us);
/* Buffers a JOURNAL_FIX record: fragment frag (at pose p) was fixed (1) or freed (0). */
int journal_append_fix(journal *j, int frag, int64_t t_us, const pose *p, int fixed, int64_t now_us);
/* Flushes when the oldest buffered record is JOURNAL_FLUSH_US old; call it while idle too. */
int journal_tick(journal *j, int64_t now_us);
/* write(2)s the buffer now. */
int journal_flush(journal *j);
/* Flush, then fsync. */
int journal_sync(journal *j);
/* What the next journal_truncate binds the journal to (the case.json just saved). Call it before
 * the appending thread truncates (e.g. before the event that tells it to). */
void journal_rebind(journal *j, const journal_bind *b);
/* Empties the journal (after a successful case save), binding it anew. */
int journal_truncate(journal *j);
/* Records appended through this handle plus those found at open. */
uint64_t journal_count(const journal *j);

/* Parses a journal's bytes (pure; name is for messages) into *s. Damage after a good header is
 * not an error: s->n counts the good records before it, s->damaged_at and s->damage say where and
 * what. FN_EFORMAT for a bad header (s is then empty), FN_ENOMEM. */
int journal_parse(const uint8_t *buf, size_t len, const char *name, journal_scan *s);
/* Reads DIR/journal as journal_parse does, streaming: it reads only up to the first damage and at
 * most the records the memory budget holds. A missing file is 0 records and an unbound *s
 * (case_sha256 ""). FN_EFORMAT for a bad header (its message names the file and offset 0). */
int journal_read(const char *case_dir, journal_scan *s);
void journal_scan_free(journal_scan *s);
/* 1 when two bindings name the same case.json and the same fragment ids. */
int journal_bind_equal(const journal_bind *a, const journal_bind *b);
/* Moves DIR/journal aside to DIR/journal.TAG.N (the first free N) and, when n > 0, writes a new
 * DIR/journal bound to b holding recs[0..n-1] (written aside, fsynced, renamed). The path the old
 * journal went to is left in aside. 0 or FN_EIO. */
int journal_set_aside(const char *case_dir, const char *tag, const journal_bind *b,
                      const journal_rec *recs, size_t n, char *aside, size_t cap);
/* Applies the records in order to poses[0..nfrag-1] (each record sets its fragment's pose; a
 * JOURNAL_FIX record's pose is the one the fragment has).
 * Returns 0, or FN_EFORMAT when a record names a fragment outside 0..nfrag-1 (the message names
 * the record). */
int journal_final_poses(const journal_rec *recs, size_t n, int nfrag, pose *poses);

#endif
