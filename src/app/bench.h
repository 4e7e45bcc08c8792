/* bench: the internal header of `fracnav bench`: the benchmarks (bench_*.c, JSON on stdout with
 * --json) that cmd_bench.c dispatches to, and the measurements they share (bench_measure.c).
 * Benchmarks report numbers; nothing here asserts a timing. */
#ifndef FN_BENCH_H
#define FN_BENCH_H

#include "frag.h"
#include "obb.h"
#include "pose.h"

#include <stddef.h>
#include <stdint.h>

struct json_t;
struct reduce_opts;

int bench_collision(int argc, char **argv);
int bench_build(int argc, char **argv);
int bench_fracture(int argc, char **argv);
int bench_loop(int argc, char **argv);
int bench_reduce(int argc, char **argv);
int bench_render(int argc, char **argv);
int bench_separate(int argc, char **argv);

/* fnclock's monotonic clock in microseconds, with the nanoseconds as the fraction. */
double bench_now_us(void);
/* fnclock's CPU time of the calling thread in microseconds: immune to being descheduled on a busy
 * machine. */
double bench_cpu_us(void);
/* fnclock's CPU time of the whole process (every thread) in microseconds. */
double bench_process_cpu_us(void);
/* Peak resident set size of this process in KiB (0 when unknown). */
long bench_peak_rss_kib(void);
/* CT_pitch ships in the repository's tests/data/: under $FRACNAV_SRC when set, else in the source
 * tree this binary was built from; its path into path. */
void bench_pitch_path(char *path, size_t cap);

/* The q-quantile (0..1, linear between order statistics) of v[0..n-1], which it sorts; NaN when
 * n < 1. */
double bench_quantile(double *v, int n, double q);

/* Real fracture CTs with annotated fragments (bench_separate.c): the NNN_BONE names of DIR's
 * NNN_BONE_mask.nii.gz files (each beside its CT NNN_BONE.nii.gz), sorted, into names (malloc'd;
 * the caller frees them). Their count, or -1 with fn_err. */
#define BENCH_MAX_BONES 256
int bench_list_bones(const char *dir, char **names);

/* bench reduce (bench_start.c): a start off m's true pose, as a hand leaves a piece: turned by
 * deg[0]..deg[1] degrees about its centroid (about a random axis) and moved by mm[0]..mm[1] mm (in a
 * random direction), drawn from *rng (a 64-bit LCG), and drawn again while it collides with f (up
 * to 100 times; then the last one drawn). tf, tm: their hierarchies. */
pose bench_reduce_start(const frag *f, const obb_tree *tf, const frag *m, const obb_tree *tm, const pose *truth,
                        const double mm[2], const double deg[2], uint64_t *rng);

/* bench reduce --labels (bench_reduce_labels.c): the real pieces of dir (as bench_list_bones), each
 * smaller fragment of a fractured bone fitted against the largest from `starts` hand-like starts
 * off its CT pose (3-10 mm, 5-15 degrees) with ro; the JSON object (command "bench reduce"), or NULL
 * with fn_err. verbose: a line per fit on stderr. */
struct json_t *bench_reduce_labels(const char *dir, int starts, const struct reduce_opts *ro, int verbose);
/* The CTs (paths, malloc'd, at most max) of dir's intact bones: those whose mask holds one label.
 * Their count, or -1 with fn_err. */
int bench_labels_intact(const char *dir, char **paths, int max);
/* Where the development set is looked for by default: $FRACNAV_DATA/pelvis-dev (FRACNAV_DATA:
 * /var/cache/fracnav when unset). */
const char *bench_labels_default_dir(void);

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
