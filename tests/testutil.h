/* Shared helpers for the cmocka tests. Include after <cmocka.h>'s prerequisites. */
#ifndef FN_TESTUTIL_H
#define FN_TESTUTIL_H

#include <stddef.h>
#include <stdio.h>
#include <sys/types.h>

/* A fresh empty directory under $TMPDIR for this test; removed by tu_rmtree. Returns a static-owned
 * copy the caller must free(). */
char *tu_tmpdir(const char *tag);
void tu_rmtree(const char *dir);
/* Path of the example CT (Cranium.inv3): $FRACNAV_DATA/Cranium.inv3, else
 * /var/cache/fracnav/Cranium.inv3. When missing, the test is skipped (cmocka skip()) with a message
 * saying how to get it (.ci/setup); under CI (the CI variable set) it fails instead. Call it before
 * allocating anything. */
const char *tu_example_ct(void);
/* tests/data/NAME, shipped in the repository: under $FRACNAV_SRC when set, else under the source
 * tree the test was built from. Fails the test when missing. */
const char *tu_test_data(const char *name);
/* Runs `fracnav ARGS` (the built CLI) through /bin/sh, capturing stdout+stderr into out (malloc'd,
 * NUL-terminated; may be NULL). Returns the exit status (or -1). */
int tu_run_cli(char **out, const char *fmt, ...);
/* Starts `fracnav ARGS...` (the built CLI; args ends with NULL, at most 18) with stdin from
 * /dev/null, its stderr readable through *err, its stdout into the file out (NULL: inherited).
 * Without err, stderr goes into out too. Returns its pid (tu_wait_exit ends it). */
pid_t tu_start_cli(FILE **err, const char *out, char *const args[]);
/* Waits for an event: checks cond(arg) every few milliseconds until it holds, for at most max_s
 * seconds (a bound for when the event never comes, never a duration a test relies on). Returns 1
 * when cond held, 0 when max_s passed. */
int tu_wait_for(int (*cond)(void *arg), void *arg, double max_s);
/* The usual max_s: long enough for a machine loaded far beyond its cores (the suite passes at
 * nice 19 beside busy loops), so that only an event that never comes reaches it. */
#define TU_WAIT_MAX_S 900
/* Waits (as tu_wait_for) until the file at path holds text; returns 1 when it does. */
int tu_wait_for_text(const char *path, const char *text, double max_s);
/* Waits for child pid to end and returns its exit status (128 + signal when killed); one still
 * running after TU_WAIT_MAX_S is killed and fails the test, named by what. */
int tu_wait_exit(int pid, const char *what);
/* Whole file into a malloc'd NUL-terminated buffer; NULL if unreadable. */
char *tu_slurp(const char *path, size_t *len);
void tu_write_file(const char *path, const void *data, size_t len);

/* A solid box fragment: dim voxels of 1 mm, every one of probability 1 (255), its first voxel
 * centre at world `at` (home translation), centroid set; f->prob is malloc'd (free it). */
struct frag;
void tu_box_frag(struct frag *f, int id, const int dim[3], const double at[3]);

/* Two bone blocks 2 mm apart along x, A (12x20x20 mm, x 4..15) and B (10x12x12 mm, x 18..27), as
 * an int16 NIfTI in dir, segmented by the CLI into dir/case (its path into case_dir), A (the
 * larger, id 1) fixed. */
void tu_two_blocks_case(const char *dir, char *case_dir, size_t cap);

/* A textured ellipsoidal "bone" CT (semi-axes 36, 21, 18 mm) on a 1 mm grid, solid, int16:
 * 80x48x42 voxels, for synthetic fractures (fracture_make_case). Free with vol_free. */
struct vol;
struct vol *tu_ellipsoid_ct(void);
/* tu_ellipsoid_ct fractured (fracture_make_case: `pieces` pieces, seed, loss_mm of bone lost at
 * each cut, the pieces moved 4 mm and turned 5 degrees off, as a hand leaves them) and saved as a
 * case in dir. Fails the test when it cannot. Free with case_free. */
struct planning_case;
struct planning_case *tu_ellipsoid_fracture(const char *dir, int pieces, unsigned long long seed, double loss_mm);

#endif
