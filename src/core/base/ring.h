/* ring: a lock-free single-producer / single-consumer queue of fixed-size items (C11 atomics).
 *
 * One thread pushes, one other thread pops; neither ever blocks or allocates after ring_new.
 * The capacity is rounded up to a power of two. Items are copied in and out by value.
 * Thread safety: ring_push only from the producer, ring_pop/ring_count only from the consumer
 * (ring_count is also safe, as an estimate, from the producer). ring_new/ring_free from one
 * thread while neither side runs. */
#ifndef FN_RING_H
#define FN_RING_H

#include <stddef.h>

typedef struct ring ring;

/* A ring of at least `capacity` items of `item_size` bytes; NULL (with fn_err) on bad sizes/OOM. */
ring *ring_new(size_t item_size, size_t capacity);
void ring_free(ring *r);
/* Copies item in. Returns 1, or 0 when the ring is full (the item is dropped, counted). */
int ring_push(ring *r, const void *item);
/* Copies the oldest item out. Returns 1, or 0 when empty. */
int ring_pop(ring *r, void *item);
/* Items waiting now. */
size_t ring_count(const ring *r);
size_t ring_capacity(const ring *r);
/* Pushes refused because the ring was full, since ring_new. */
size_t ring_dropped(const ring *r);

#endif
