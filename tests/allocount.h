/* allocount: counts the heap allocations a test executable makes, to check "allocates nothing".
 *
 * Include in exactly one .c of a test executable. It interposes malloc, calloc, realloc,
 * aligned_alloc and posix_memalign, forwarding to glibc's own allocator, and counts every call
 * made by any thread while counting is on. Under AddressSanitizer or ThreadSanitizer (each owns
 * malloc) it defines nothing and allocount_available() is 0: the checks are then skipped, not faked. */
#ifndef FN_TEST_ALLOCOUNT_H
#define FN_TEST_ALLOCOUNT_H

#include <stdatomic.h>
#include <stddef.h>

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define ALLOCOUNT_ON 0
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define ALLOCOUNT_ON 0
#endif
#endif
#ifndef ALLOCOUNT_ON
#define ALLOCOUNT_ON 1
#endif

static atomic_int allocount_counting;
static atomic_long allocount_calls;
static atomic_llong allocount_bytes_asked; /* bytes asked for by the calls counted */

/* Starts counting from zero. */
static inline void allocount_start(void)
{
    atomic_store(&allocount_calls, 0);
    atomic_store(&allocount_bytes_asked, 0);
    atomic_store(&allocount_counting, 1);
}

/* The bytes asked for by the calls counted since allocount_start() (realloc: the new size). */
static inline long long allocount_bytes(void)
{
    return atomic_load(&allocount_bytes_asked);
}

/* Stops counting; returns the calls counted since allocount_start(). */
static inline long allocount_stop(void)
{
    atomic_store(&allocount_counting, 0);
    return atomic_load(&allocount_calls);
}

static inline int allocount_available(void)
{
    return ALLOCOUNT_ON;
}

#if ALLOCOUNT_ON
#include <errno.h>

extern void *__libc_malloc(size_t);
extern void *__libc_calloc(size_t, size_t);
extern void *__libc_realloc(void *, size_t);
extern void *__libc_memalign(size_t, size_t);

static void allocount_note(size_t bytes)
{
    if (atomic_load_explicit(&allocount_counting, memory_order_relaxed)) {
        atomic_fetch_add(&allocount_calls, 1);
        atomic_fetch_add(&allocount_bytes_asked, (long long)bytes);
    }
}

void *malloc(size_t n)
{
    allocount_note(n);
    return __libc_malloc(n);
}

void *calloc(size_t n, size_t size)
{
    allocount_note(n * size);
    return __libc_calloc(n, size);
}

void *realloc(void *p, size_t n)
{
    allocount_note(n);
    return __libc_realloc(p, n);
}

void *aligned_alloc(size_t align, size_t n)
{
    allocount_note(n);
    return __libc_memalign(align, n);
}

int posix_memalign(void **out, size_t align, size_t n)
{
    allocount_note(n);
    if (align < sizeof(void *) || (align & (align - 1)))
        return EINVAL;
    void *p = __libc_memalign(align, n);
    if (!p)
        return ENOMEM;
    *out = p;
    return 0;
}
#endif

#endif
