/* failalloc: makes the Nth heap allocation of the project's own code fail, as libfido2's
 * fuzz/wrap.c does, so that out-of-memory paths run in tests.
 *
 * Include in exactly one .c of a test executable linked with
 *   -Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc,--wrap=aligned_alloc
 * (tests/CMakeLists.txt does this for test_oom). The linker sends every call to those functions from
 * the objects linked statically (the test and the project's static libraries) to the __wrap_
 * versions below; shared third-party libraries (jansson, nifticlib, teem, zlib) keep the real
 * allocator, so their own out-of-memory handling is not under test here.
 *
 * failalloc_arm(n) makes the nth allocation from now fail (once) and returns it as NULL with
 * errno = ENOMEM; failalloc_disarm() stops and tells whether the failure was injected. Thread-safe
 * (atomics), but the tests call it from one thread. */
#ifndef FN_TEST_FAILALLOC_H
#define FN_TEST_FAILALLOC_H

#include <errno.h>
#include <stdatomic.h>
#include <stddef.h>

void *__real_malloc(size_t n);
void *__real_calloc(size_t n, size_t size);
void *__real_realloc(void *p, size_t n);
void *__real_aligned_alloc(size_t align, size_t n);
void *__wrap_malloc(size_t n);
void *__wrap_calloc(size_t n, size_t size);
void *__wrap_realloc(void *p, size_t n);
void *__wrap_aligned_alloc(size_t align, size_t n);

static atomic_long failalloc_left = -1; /* allocations to let through before the failing one; <0: off */
static atomic_int failalloc_injected;

static inline void failalloc_arm(long n)
{
    atomic_store(&failalloc_injected, 0);
    atomic_store(&failalloc_left, n - 1);
}

/* Stops injecting; returns 1 when the armed failure happened. */
static inline int failalloc_disarm(void)
{
    atomic_store(&failalloc_left, -1);
    return atomic_load(&failalloc_injected);
}

static int failalloc_now(void)
{
    long left = atomic_load(&failalloc_left);
    while (left >= 0) {
        if (atomic_compare_exchange_weak(&failalloc_left, &left, left - 1)) {
            if (left > 0)
                return 0;
            atomic_store(&failalloc_injected, 1);
            errno = ENOMEM;
            return 1;
        }
    }
    return 0;
}

void *__wrap_malloc(size_t n)
{
    return failalloc_now() ? NULL : __real_malloc(n);
}

void *__wrap_calloc(size_t n, size_t size)
{
    return failalloc_now() ? NULL : __real_calloc(n, size);
}

void *__wrap_realloc(void *p, size_t n)
{
    return failalloc_now() ? NULL : __real_realloc(p, n);
}

void *__wrap_aligned_alloc(size_t align, size_t n)
{
    return failalloc_now() ? NULL : __real_aligned_alloc(align, n);
}

#endif
