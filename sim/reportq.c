#include "reportq.h"

#include <poll.h>
#include <string.h>

void reportq_init(reportq *q)
{
    memset(q, 0, sizeof *q);
}

size_t reportq_cut(size_t n, size_t size)
{
    return n < size ? n : size;
}

static void remove_waiter(reportq *q, int i)
{
    q->nwaiting--;
    memmove(&q->waiting[i], &q->waiting[i + 1], (size_t)(q->nwaiting - i) * sizeof *q->waiting);
}

reportq_fate reportq_push(reportq *q, const uint8_t *b, size_t n, reportq_waiter *to)
{
    if (q->dead)
        return REPORTQ_DEAD;
    if (q->nwaiting) {
        *to = q->waiting[0];
        remove_waiter(q, 0);
        return REPORTQ_HANDED;
    }
    if (q->count == REPORTQ_LEN) {
        q->dropped++;
        return REPORTQ_DROPPED;
    }
    int slot = (q->head + q->count++) % REPORTQ_LEN;
    memcpy(q->q[slot], b, n);
    q->qlen[slot] = (uint8_t)n;
    return REPORTQ_QUEUED;
}

reportq_answer reportq_read(reportq *q, void *req, size_t size, int nonblock, uint8_t *buf, size_t *len)
{
    if (q->dead)
        return REPORTQ_EIO;
    if (q->count) {
        int slot = q->head;
        q->head = (q->head + 1) % REPORTQ_LEN;
        q->count--;
        *len = reportq_cut(q->qlen[slot], size);
        memcpy(buf, q->q[slot], *len);
        return REPORTQ_REPORT;
    }
    if (nonblock || q->nwaiting == REPORTQ_WAITERS)
        return REPORTQ_AGAIN;
    q->waiting[q->nwaiting++] = (reportq_waiter){req, size};
    return REPORTQ_WAIT;
}

int reportq_cancel(reportq *q, void *req)
{
    for (int i = 0; i < q->nwaiting; i++)
        if (q->waiting[i].req == req) {
            remove_waiter(q, i);
            return 1;
        }
    return 0;
}

int reportq_take_waiter(reportq *q, reportq_waiter *out)
{
    if (!q->nwaiting)
        return 0;
    *out = q->waiting[0];
    remove_waiter(q, 0);
    return 1;
}

void reportq_kill(reportq *q)
{
    q->dead = 1;
}

unsigned reportq_poll_events(const reportq *q)
{
    unsigned ev = POLLOUT | POLLWRNORM;
    if (q->count)
        ev |= POLLIN | POLLRDNORM;
    if (q->dead)
        ev |= POLLERR | POLLHUP;
    return ev;
}
