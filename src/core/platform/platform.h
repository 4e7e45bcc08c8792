/* platform: the core's seam to the operating system -- real-time scheduling, the loop's pages kept
 * mapped, huge pages for large arrays, and running a helper program. platform_linux.c fills it for
 * Linux; another OS gets its own platform_<os>.c. Only the core's targets see this header.
 * Thread safety: every call acts on the calling thread or the whole process, and may be made from
 * any thread. */
#ifndef FN_PLATFORM_H
#define FN_PLATFORM_H

#include <stddef.h>

/* Puts the calling thread under real-time scheduling (SCHED_FIFO, priority 10) and keeps it on the
 * CPU it runs on. Returns 0, or FN_EINVAL (the message says what was refused) when either is not
 * granted. */
int platform_rt_priority(void);
/* The CPU the calling thread is kept on under real-time scheduling, with its priority in *prio;
 * -1 (and *prio 0) when it runs under ordinary scheduling. */
int platform_rt_cpu(int *prio);
/* Moves the calling thread onto `cpu` under real-time scheduling at priority prio (best effort:
 * nothing changes where it is refused). */
void platform_rt_follow(int cpu, int prio);
/* Puts the calling thread under ordinary scheduling at nice `nice` (0..19; 19 the lowest), free to
 * run on every CPU: a thread inherits its creator's policy and CPU, so one started by a real-time
 * thread would otherwise run under SCHED_FIFO on that thread's CPU. Best effort. */
void platform_background_priority(int nice);
/* on: keeps the process's memory out of khugepaged's reach (counted: the last off gives it back,
 * unless it was kept out before the first on). */
void platform_hold_huge_pages(int on);
/* Maps every page of every loaded object (the program and its libraries) now, so that code and
 * tables reached later take no page fault. */
void platform_prefault_code(void);
/* Asks for transparent huge pages on a large array (4 MiB or more; a hint, never an error). */
void platform_huge_pages(void *p, size_t bytes);
/* glibc's malloc tuned for large, short-lived arrays (a CT's crops, VOI grids, bands, trees): blocks
 * up to 32 MiB come from the heap (not each a fresh mapping whose every page faults when first
 * touched), the heap is never trimmed (what a fit frees, the next metric reuses), and its memory is
 * asked for in transparent huge pages. glibc reads these tunables at a program's start only: where
 * GLIBC_TUNABLES names none of glibc.malloc's (a user's own are left alone), they are added and the
 * program executed again (its path from /proc/self/exe, the same argv; the same process). Returns
 * when nothing was done (another C library, or they are set) or the exec failed. First thing in
 * main, before any thread or open file. */
void platform_tune_malloc(char **argv);
/* Runs the program argv[0] (found in PATH) with argv, its stdout and stderr into the file log,
 * and waits for it. Returns its exit status (128 when a signal ended it), 127 when it could not
 * start. */
int platform_run(char *const argv[], const char *log);

#endif
