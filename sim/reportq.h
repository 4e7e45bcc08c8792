/* reportq: the kernel's report queue of one hidraw reader, as fracnav-sim serve emulates it.
 *
 * Each open of a hidraw node has its own queue of REPORTQ_LEN reports. A report that arrives while
 * a read waits goes to that read at once; else it is queued, and dropped when the queue is full
 * (hidraw drops the new report). A read takes the oldest report, cut to the reader's size; on an
 * empty queue a blocking read waits (at most REPORTQ_WAITERS at a time), a non-blocking one gets
 * EAGAIN. After an unplug the queue is dead: reads fail with EIO and poll says POLLERR | POLLHUP.
 *
 * Pure: no I/O, no allocation. A waiting read is the caller's opaque token (a fuse_req_t); the
 * caller answers it when reportq hands it back. Every push is a wakeup for the reader's poll.
 * Not thread-safe: one thread owns a queue. */
#ifndef FN_REPORTQ_H
#define FN_REPORTQ_H

#include <stddef.h>
#include <stdint.h>

#include "dev.h"

#define REPORTQ_LEN 64
#define REPORTQ_WAITERS 4

typedef struct reportq_waiter {
    void *req;   /* the caller's read request */
    size_t size; /* how much it asked for */
} reportq_waiter;

typedef struct reportq {
    uint8_t q[REPORTQ_LEN][DEV_REPORT_MAX];
    uint8_t qlen[REPORTQ_LEN];
    int head, count;
    reportq_waiter waiting[REPORTQ_WAITERS]; /* oldest first */
    int nwaiting;
    int dead;         /* the device was unplugged while this reader had it open */
    uint64_t dropped; /* reports lost to a full queue */
} reportq;

/* What became of a pushed report. */
typedef enum reportq_fate {
    REPORTQ_HANDED,  /* a waiting read takes it: answer *to with the report (reportq_cut) */
    REPORTQ_QUEUED,  /* queued for the next read */
    REPORTQ_DROPPED, /* the queue was full */
    REPORTQ_DEAD     /* the reader is dead: nobody gets it */
} reportq_fate;

/* What a read gets. */
typedef enum reportq_answer {
    REPORTQ_REPORT, /* a report: *len bytes in buf */
    REPORTQ_WAIT,   /* nothing yet: the request waits for the next push */
    REPORTQ_AGAIN,  /* nothing, and the read must not wait (non-blocking, or too many waiting): EAGAIN */
    REPORTQ_EIO     /* dead: EIO */
} reportq_answer;

void reportq_init(reportq *q);
/* A report of n bytes (n <= DEV_REPORT_MAX) arrives. On REPORTQ_HANDED *to is the read to answer. */
reportq_fate reportq_push(reportq *q, const uint8_t *b, size_t n, reportq_waiter *to);
/* A read of `size` bytes (req = its token): the oldest report cut to size into buf (cap >=
 * DEV_REPORT_MAX), or whether it waits. */
reportq_answer reportq_read(reportq *q, void *req, size_t size, int nonblock, uint8_t *buf, size_t *len);
/* The bytes of a report of n bytes that a read of `size` gets. */
size_t reportq_cut(size_t n, size_t size);
/* A waiting read was interrupted: 1 when it was waiting here (and is no more), else 0. */
int reportq_cancel(reportq *q, void *req);
/* Takes the oldest waiting read (to answer it with an error): 1, or 0 when none waits. */
int reportq_take_waiter(reportq *q, reportq_waiter *out);
/* The device went away: the queue is dead (its waiters are still to be taken and answered). */
void reportq_kill(reportq *q);
/* Poll events now: POLLOUT | POLLWRNORM, POLLIN | POLLRDNORM with a report queued, POLLERR | POLLHUP
 * when dead. */
unsigned reportq_poll_events(const reportq *q);

#endif
