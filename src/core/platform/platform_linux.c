/* platform on Linux: SCHED_FIFO and CPU affinity, prctl's THP switch, dl_iterate_phdr with
 * MADV_POPULATE_READ, MADV_HUGEPAGE, posix_spawn. */
#define _GNU_SOURCE /* CPU affinity: sched_getcpu, pthread_setaffinity_np; syscall */
#include "platform.h"

#include "err.h"

#include <errno.h>
#include <fcntl.h>
#include <link.h>
#include <pthread.h>
#include <sched.h>
#include <spawn.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

extern char **environ;

int platform_rt_priority(void)
{
    struct sched_param sp = {.sched_priority = 10};
    int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
    if (rc != 0)
        return fn_err_set(FN_EINVAL, "real-time priority not granted: %s", strerror(rc));
    int cpu = sched_getcpu();
    cpu_set_t one;
    CPU_ZERO(&one);
    if (cpu >= 0)
        CPU_SET(cpu, &one);
    if (cpu < 0 || (rc = pthread_setaffinity_np(pthread_self(), sizeof one, &one)) != 0)
        return fn_err_set(FN_EINVAL, "real-time priority granted, but the thread cannot be kept on "
                                     "CPU %d: %s", cpu, strerror(cpu < 0 ? errno : rc));
    return 0;
}

int platform_rt_cpu(int *prio)
{
    int policy = SCHED_OTHER;
    struct sched_param sp = {0};
    int on = pthread_getschedparam(pthread_self(), &policy, &sp) == 0 && policy == SCHED_FIFO;
    *prio = on ? sp.sched_priority : 0;
    return on ? sched_getcpu() : -1;
}

void platform_rt_follow(int cpu, int prio)
{
    cpu_set_t one;
    CPU_ZERO(&one);
    CPU_SET(cpu, &one);
    struct sched_param sp = {.sched_priority = prio};
    if (pthread_setaffinity_np(pthread_self(), sizeof one, &one) == 0)
        pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
}

void platform_background_priority(int nice)
{
    struct sched_param sp = {.sched_priority = 0};
    pthread_setschedparam(pthread_self(), SCHED_OTHER, &sp);
    cpu_set_t all;
    CPU_ZERO(&all);
    for (int c = 0; c < CPU_SETSIZE; c++)
        CPU_SET(c, &all); /* the kernel keeps those the process may use */
    pthread_setaffinity_np(pthread_self(), sizeof all, &all);
    setpriority(PRIO_PROCESS, (id_t)syscall(SYS_gettid), nice < 0 ? 0 : nice > 19 ? 19 : nice);
}

/* khugepaged, when it merges a process's pages into a huge page, takes the range away while it
 * copies it: a real-time thread that reads there waits for it (a page fault of milliseconds). */
static pthread_mutex_t thp_lock = PTHREAD_MUTEX_INITIALIZER;
static int thp_holds, thp_was_off;

void platform_hold_huge_pages(int on)
{
    pthread_mutex_lock(&thp_lock);
    if (on && thp_holds++ == 0) {
        thp_was_off = prctl(PR_GET_THP_DISABLE, 0, 0, 0, 0) == 1;
        if (!thp_was_off)
            prctl(PR_SET_THP_DISABLE, 1, 0, 0, 0);
    } else if (!on && --thp_holds == 0 && !thp_was_off) {
        prctl(PR_SET_THP_DISABLE, 0, 0, 0, 0);
    }
    pthread_mutex_unlock(&thp_lock);
}

/* Maps every page of one loaded object (the program, libm, libc, zlib, ...) into the page
 * tables. Where the kernel lacks MADV_POPULATE_READ (before 5.14), readable pages are read. */
static int prefault_object(struct dl_phdr_info *info, size_t size, void *unused)
{
    (void)size;
    (void)unused;
    uintptr_t page = (uintptr_t)sysconf(_SC_PAGESIZE);
    for (int i = 0; i < info->dlpi_phnum; i++) {
        const ElfW(Phdr) *ph = &info->dlpi_phdr[i];
        if (ph->p_type != PT_LOAD || ph->p_memsz == 0)
            continue;
        uintptr_t lo = (info->dlpi_addr + ph->p_vaddr) & ~(page - 1);
        uintptr_t hi = info->dlpi_addr + ph->p_vaddr + ph->p_memsz;
        if (madvise((void *)lo, hi - lo, MADV_POPULATE_READ) == 0 || errno != EINVAL ||
            !(ph->p_flags & PF_R))
            continue;
        for (uintptr_t a = lo; a < hi; a += page)
            (void)*(volatile const unsigned char *)a;
    }
    return 0;
}

void platform_prefault_code(void)
{
    dl_iterate_phdr(prefault_object, NULL);
}

void platform_huge_pages(void *p, size_t bytes)
{
#ifdef MADV_HUGEPAGE
    uintptr_t page = 4096, lo = ((uintptr_t)p + page - 1) & ~(page - 1);
    uintptr_t hi = ((uintptr_t)p + bytes) & ~(page - 1);
    if (p && bytes >= (4u << 20) && hi > lo)
        madvise((void *)lo, hi - lo, MADV_HUGEPAGE);
#else
    (void)p, (void)bytes;
#endif
}

void platform_tune_malloc(char **argv)
{
#ifdef __GLIBC__
    static const char tuned[] = "glibc.malloc.hugetlb=1:glibc.malloc.mmap_threshold=33554432:"
                                "glibc.malloc.trim_threshold=4294967295";
    const char *have = getenv("GLIBC_TUNABLES");
    if (have && strstr(have, "glibc.malloc."))
        return;
    char value[4096], self[4096];
    int n = snprintf(value, sizeof value, "%s%s%s", have && *have ? have : "", have && *have ? ":" : "", tuned);
    /* the program's own path, so that its name stays (ps, top, pgrep), not "exe" */
    ssize_t len = readlink("/proc/self/exe", self, sizeof self - 1);
    if (n < 0 || (size_t)n >= sizeof value || len <= 0 || (size_t)len >= sizeof self - 1)
        return;
    self[len] = '\0';
    if (setenv("GLIBC_TUNABLES", value, 1) != 0)
        return;
    execv(self, argv);
    /* not executed again: on as it is; the variable stays for the programs it runs */
#else
    (void)argv;
#endif
}

int platform_run(char *const argv[], const char *log)
{
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, STDOUT_FILENO, log, O_WRONLY | O_CREAT | O_TRUNC | O_NOFOLLOW, 0600);
    posix_spawn_file_actions_adddup2(&fa, STDOUT_FILENO, STDERR_FILENO);
    pid_t pid;
    int rc = posix_spawnp(&pid, argv[0], &fa, NULL, argv, environ);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0)
        return 127;
    int st;
    while (waitpid(pid, &st, 0) < 0)
        if (errno != EINTR)
            return 127;
    return WIFEXITED(st) ? WEXITSTATUS(st) : 128;
}
