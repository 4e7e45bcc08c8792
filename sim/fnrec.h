/* fnrec: the .fnrec recording format (see sim/FNREC.md): a versioned, line-oriented text file that
 * holds a device's identity, its report descriptor and every report with its timestamp.
 *
 * The reader is a pure function over bytes (fuzzed); its errors name the file, the line and what is
 * wrong. The writer flushes each line, so an interrupted recording loses at most the last line.
 * Not thread-safe per object; distinct objects may be used from distinct threads. */
#ifndef FN_FNREC_H
#define FN_FNREC_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "dev.h"

#define FNREC_VERSION 1
/* A recording holds at most this many events (about 2.5 h at 125 reports/s). */
#define FNREC_MAX_EVENTS (1u << 20)
/* Consecutive events (and the first event and t = 0) are at most this far apart: a timestamp far in
 * the future would hold a real-time replay for that long. The recorder never writes a longer gap. */
#define FNREC_MAX_GAP_US (3600LL * 1000000)

typedef enum fnrec_dir {
    FNREC_IN = 0,     /* input report, device -> host */
    FNREC_OUT,        /* output report, host -> device (e.g. the LED, report 4) */
    FNREC_FEATURE,    /* a feature report's contents at that time: as read (get) or as set and
                         accepted (set); fracnav-sim --log writes both */
    FNREC_CONNECT,    /* the device appeared; no bytes */
    FNREC_DISCONNECT  /* the device went away; no bytes */
} fnrec_dir;

typedef struct fnrec_event {
    int64_t t_us; /* microseconds since the recording started; never decreases */
    fnrec_dir dir;
    uint8_t len;  /* bytes in data, report ID first; 0 for connect/disconnect */
    uint8_t data[DEV_REPORT_MAX];
} fnrec_event;

typedef struct fnrec_header {
    int version;       /* FNREC_VERSION */
    uint16_t vid, pid;
    char name[128];    /* product name, UTF-8, no newline */
    char format[16];   /* "split" or "combined" (the motion report layout) */
    char source[128];  /* where it was recorded: "virtual:..." for the simulator, "hidraw:PATH" ... */
    uint8_t desc[DEV_DESC_MAX];
    size_t desc_len;
} fnrec_header;

/* A whole recording in memory. */
typedef struct fnrec {
    fnrec_header hdr;
    fnrec_event *ev; /* owned */
    size_t n;
    int torn_line;      /* a last line cut by an interrupted write, left out (0: none) */
    char torn_why[160]; /* what was wrong with it */
} fnrec;

/* Parses a recording from bytes. name is used in messages only ("FILE:LINE: ..."). Returns 0 and a
 * new recording in *out (free with fnrec_free), or FN_EFORMAT / FN_ENOMEM with *out = NULL.
 * A last event line without its newline is kept when it is whole; when it does not parse, or is an
 * input report shorter than the descriptor declares, it is a torn write: left out, and named in
 * torn_line / torn_why (not an error). */
int fnrec_parse(const char *text, size_t len, const char *name, fnrec **out);
/* Reads and parses a file. Returns NULL on failure (fn_err_msg names the file and line). A torn
 * last line is left out with a warning on stderr that names it. */
fnrec *fnrec_load(const char *path);
void fnrec_free(fnrec *r);

/* An empty recording with this header, to be filled with fnrec_append. NULL on allocation failure. */
fnrec *fnrec_new(const fnrec_header *hdr);
/* Appends a copy of e. FN_EINVAL if time goes backwards or len is too long, FN_ENOMEM when full. */
int fnrec_append(fnrec *r, const fnrec_event *e);

/* Writer: creates path (truncating) and writes the header; NULL on failure. */
typedef struct fnrec_writer fnrec_writer;
fnrec_writer *fnrec_writer_open(const char *path, const fnrec_header *hdr);
/* The same over an open stream (not closed by fnrec_writer_close). */
fnrec_writer *fnrec_writer_stream(FILE *f, const fnrec_header *hdr);
/* Writes and flushes one event line. 0 or FN_EIO / FN_EINVAL. */
int fnrec_writer_event(fnrec_writer *w, const fnrec_event *e);
/* Flushes, closes (fsync for files) and frees. 0 or FN_EIO. */
int fnrec_writer_close(fnrec_writer *w);
/* Writes a whole recording to path. */
int fnrec_save(const fnrec *r, const char *path);

/* "in", "out", "feature", "connect", "disconnect". */
const char *fnrec_dir_name(fnrec_dir d);

#endif
