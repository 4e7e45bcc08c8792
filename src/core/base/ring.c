#include "ring.h"

#include "err.h"

#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* head and tail live on their own cache lines so the two threads do not share one. */
struct ring {
    _Alignas(64) atomic_size_t head; /* next slot to write; written by the producer */
    _Alignas(64) atomic_size_t tail; /* next slot to read; written by the consumer */
    _Alignas(64) atomic_size_t dropped;
    size_t mask, item_size;
    unsigned char *slots;
};

ring *ring_new(size_t item_size, size_t capacity)
{
    if (item_size == 0 || item_size > 4096 || capacity == 0 || capacity > ((size_t)1 << 24)) {
        fn_err_set(FN_EINVAL, "ring: item size %zu or capacity %zu out of range", item_size, capacity);
        return NULL;
    }
    size_t cap = 1;
    while (cap < capacity)
        cap <<= 1;
    ring *r = aligned_alloc(64, sizeof *r);
    unsigned char *slots = malloc(cap * item_size);
    if (!r || !slots) {
        free(r);
        free(slots);
        fn_err_set(FN_ENOMEM, "ring: out of memory for %zu items of %zu bytes", cap, item_size);
        return NULL;
    }
    memset(r, 0, sizeof *r);
    atomic_init(&r->head, 0);
    atomic_init(&r->tail, 0);
    atomic_init(&r->dropped, 0);
    r->mask = cap - 1;
    r->item_size = item_size;
    r->slots = slots;
    /* Write every page now: a first-touch page fault in ring_push would stall the producer
     * between a report's arrival and the loop's wake-up. */
    for (size_t i = 0; i < cap * item_size; i += 4096)
        ((volatile unsigned char *)slots)[i] = 0;
    return r;
}

void ring_free(ring *r)
{
    if (!r)
        return;
    free(r->slots);
    free(r);
}

int ring_push(ring *r, const void *item)
{
    size_t head = atomic_load_explicit(&r->head, memory_order_relaxed);
    size_t tail = atomic_load_explicit(&r->tail, memory_order_acquire);
    if (head - tail > r->mask) {
        atomic_fetch_add_explicit(&r->dropped, 1, memory_order_relaxed);
        return 0;
    }
    memcpy(r->slots + (head & r->mask) * r->item_size, item, r->item_size);
    atomic_store_explicit(&r->head, head + 1, memory_order_release);
    return 1;
}

int ring_pop(ring *r, void *item)
{
    size_t tail = atomic_load_explicit(&r->tail, memory_order_relaxed);
    size_t head = atomic_load_explicit(&r->head, memory_order_acquire);
    if (head == tail)
        return 0;
    memcpy(item, r->slots + (tail & r->mask) * r->item_size, r->item_size);
    atomic_store_explicit(&r->tail, tail + 1, memory_order_release);
    return 1;
}

size_t ring_count(const ring *r)
{
    size_t head = atomic_load_explicit(&r->head, memory_order_acquire);
    size_t tail = atomic_load_explicit(&r->tail, memory_order_acquire);
    return head - tail;
}

size_t ring_capacity(const ring *r)
{
    return r->mask + 1;
}

size_t ring_dropped(const ring *r)
{
    return atomic_load_explicit(&r->dropped, memory_order_relaxed);
}
