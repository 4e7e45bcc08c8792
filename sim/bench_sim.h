/* bench_sim: `fracnav-sim bench`, the virtual device's throughput and timing jitter through FUSE
 * and the real hidapi. Part of the fracnav-sim executable (it starts fracnav-sim serve). */
#ifndef FN_BENCH_SIM_H
#define FN_BENCH_SIM_H

/* Serves on mount (NULL: a temporary directory), measures, prints JSON on stdout. Returns the
 * exit status (0 or 1). */
int bench_sim_run(const char *mount, double seconds);

#endif
