/* bench: the internal header of `fracnav bench`: the benchmarks (bench_*.c, JSON on stdout with
 * --json) that cmd_bench.c dispatches to, and the measurements they share (bench_measure.c).
 * Benchmarks report numbers; nothing here asserts a timing. */
#ifndef FN_BENCH_H
#define FN_BENCH_H

#include "frag.h"
#include "obb.h"
#include "pose.h"

#include <stddef.h>

int bench_collision(int argc, char **argv);
int bench_build(int argc, char **argv);
int bench_loop(int argc, char **argv);
int bench_reduce(int argc, char **argv);
int bench_render(int argc, char **argv);
int bench_separate(int argc, char **argv);

/* fnclock's monotonic clock in microseconds, with the nanoseconds as the fraction. */
double bench_now_us(void);
/* fnclock's CPU time of the calling thread in microseconds: immune to being descheduled on a busy
 * machine. */
double bench_cpu_us(void);
/* Peak resident set size of this process in KiB (0 when unknown). */
long bench_peak_rss_kib(void);
/* CT_pitch ships in the repository's tests/data/: under $FRACNAV_SRC when set, else in the source
 * tree this binary was built from; its path into path. */
void bench_pitch_path(char *path, size_t cap);

/* The FCL peer (src/bench_fcl.cpp, built when libfcl-dev is found: FRACNAV_HAVE_FCL). A geometry
 * holds one fragment's voxels whose effective probability (obb_effective_prob) is non-zero:
 * an octomap OcTree at the finest spacing (each voxel box filled), or an OBBRSS mesh BVH of the
 * exposed voxel faces. NULL with fn_err on failure. Not thread-safe. */
typedef struct bench_fcl bench_fcl;
bench_fcl *bench_fcl_octree(const frag *f, const obb_params *p);
bench_fcl *bench_fcl_mesh(const frag *f, const obb_params *p);
/* Octree cells or triangles held. */
size_t bench_fcl_size(const bench_fcl *g);
/* FCL's boolean collision; aw, bw: local mm -> world. 1 collides, 0 apart, <0 error. */
int bench_fcl_collide(const bench_fcl *a, const pose *aw, const bench_fcl *b, const pose *bw);
void bench_fcl_free(bench_fcl *g);

#endif
