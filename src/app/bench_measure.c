/* bench: what every benchmark measures -- wall time, the thread's CPU time, peak memory. */
#include "bench.h"

#include "fnclock.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/resource.h>

double bench_now_us(void)
{
    return (double)fnclock_now_ns() * 1e-3;
}

double bench_cpu_us(void)
{
    return (double)fnclock_thread_cpu_ns() * 1e-3;
}

double bench_process_cpu_us(void)
{
    return (double)fnclock_process_cpu_ns() * 1e-3;
}

long bench_peak_rss_kib(void)
{
    struct rusage ru;
    return getrusage(RUSAGE_SELF, &ru) == 0 ? ru.ru_maxrss : 0;
}

void bench_pitch_path(char *path, size_t cap)
{
    const char *src = getenv("FRACNAV_SRC");
    snprintf(path, cap, "%s/tests/data/CT_pitch.nii.gz", src && *src ? src : FRACNAV_SOURCE_DIR);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

double bench_quantile(double *v, int n, double q)
{
    if (n < 1)
        return NAN;
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    double pos = q * (n - 1);
    int i = (int)pos;
    return i + 1 < n ? v[i] + (pos - i) * (v[i + 1] - v[i]) : v[i];
}
