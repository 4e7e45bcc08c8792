/* Shared helpers for the cmocka tests. Include after <cmocka.h> (its fail_msg is replaced below). */
#ifndef FN_TESTUTIL_H
#define FN_TESTUTIL_H

#include <stddef.h>
#include <stdio.h>
#include <sys/types.h>

/* A fresh empty directory under $TMPDIR for this test; removed by tu_rmtree. Returns a static-owned
 * copy the caller must free(). */
char *tu_tmpdir(const char *tag);
void tu_rmtree(const char *dir);
/* A folder for each test, as cmocka setup and teardown functions: tu_dir_setup makes tu_dir (a
 * tu_tmpdir tagged with the test program's name), tu_dir_teardown removes it. tu_in_dir(name) is
 * tu_dir/name in a static buffer that the next call overwrites. */
extern char *tu_dir;
int tu_dir_setup(void **st);
int tu_dir_teardown(void **st);
const char *tu_in_dir(const char *name);
/* A cmocka teardown for a fixture (*st, calloc'd) whose first member is a tu_tmpdir (char *):
 * removes the folder and frees both. */
int tu_fixture_teardown(void **st);
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
/* The same for `fracnav-sim ARGS` (skips the test, saying so, where it is not built: tu_sim). */
int tu_run_sim(char **out, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* Runs `fracnav ARGS` (tu_run_cli) and fails the test, showing the output, unless it exits with
 * rc and its output holds want and no temporary file's name (.fracnav-tmp). */
void tu_expect_cli(int rc, const char *want, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
/* `fracnav segment CT -o CASE_DIR --min-volume 0 EXTRA`; fails the test, showing the output, when
 * it fails. */
void tu_segment(const char *ct, const char *case_dir, const char *extra);
/* Waits for an event: checks cond(arg) every few milliseconds until it holds, for at most max_s
 * seconds (a bound for when the event never comes, never a duration a test relies on). Returns 1
 * when cond held, 0 when max_s passed. */
int tu_wait_for(int (*cond)(void *arg), void *arg, double max_s);
/* tu_wait_for, checking every period_us microseconds (it polls every 5 ms): for an event that
 * lasts only a moment, as a file while it is written. */
int tu_wait_for_every(int (*cond)(void *arg), void *arg, double max_s, long period_us);
/* The usual max_s: 30 s times $FRACNAV_TEST_SLOW (a positive number, default 1), so a broken test
 * fails in tens of seconds. CMake sets the multiplier for sanitizer builds (FRACNAV_TEST_SLOW);
 * set it by hand on a machine loaded far beyond its cores. */
int tu_wait_max_s(void);
#define TU_WAIT_MAX_S tu_wait_max_s()
/* Waits (as tu_wait_for) until the file at path holds text; returns 1 when it does. */
int tu_wait_for_text(const char *path, const char *text, double max_s);

/* ---- Processes: spawn, wait for a file, a node or a line, end ---- */

/* The fracnav under test: $FRACNAV_BIN (ctest sets it). Unset, it fails the test at once, saying
 * what to set. */
const char *tu_fracnav(void);
/* The source tree: $FRACNAV_SRC (ctest sets it). Unset, it fails the test at once, saying what to set. */
const char *tu_src(void);
/* fracnav-sim, built beside fracnav (sim/fracnav-sim); skips the test, saying so, when it was not
 * built (no libfuse3). */
const char *tu_sim(void);
/* In a child just forked from parent (getpid() before the fork): it is killed when the test
 * process ends, however it ends, so nothing a failed test started outlives the test run (and
 * holds ctest's output pipe open). */
void tu_in_child(pid_t parent);
/* Remembers a child the test started itself, for tu_end_all. */
void tu_adopt(pid_t pid);
/* Starts argv[0] with argv, stdin from /dev/null, stdout into the file out (emptied first) (NULL: this
 * test's stdout); stderr into a pipe read through *err (unbuffered, for tu_wait_line; the caller
 * fcloses it) when err is not NULL, else into out too. The child is remembered until tu_end or
 * tu_end_all. */
pid_t tu_spawn(char *const argv[], const char *out, FILE **err);
/* tu_spawn of `fracnav ARGS...` (args ends with NULL). */
pid_t tu_spawn_cli(const char *out, FILE **err, char *const args[]);
/* Waits (TU_WAIT_MAX_S at most) until path exists: a file written, a node served. Returns 1 when it does. */
int tu_wait_path(const char *path);
/* Reads err line by line until a line holds needle (returns 1), the stream ends or TU_WAIT_MAX_S
 * passes without a byte (0); what it read is appended to seen (cap bytes, NUL-terminated). */
int tu_wait_line(FILE *err, const char *needle, char *seen, size_t cap);
/* Sends sig to the child (0: none) and waits for it to end; returns its exit status (128 + signal
 * when a signal ended it). One still running after TU_WAIT_MAX_S is killed and fails the test,
 * named by what. */
int tu_end(pid_t pid, int sig, const char *what);
/* fracnav-sim serve --mount mnt ARGS... (NULL-terminated), its output into log; returns
 * once mnt/hidraw0 is served, or fails the test naming log. */
pid_t tu_serve(const char *mnt, const char *log, ...);
/* Undoes the mounts at mnt (lazily, as often as something is mounted there: a server that mounted
 * over another). */
void tu_unmount(const char *mnt);
/* Kills (SIGKILL) and reaps every child still running: for a teardown, after a failed test. */
void tu_end_all(void);

/* The motion script text (sim/script.h) rendered for the device profile `device`
 * (sim_profile_find: "spacenavigator", ...) and saved as a recording at path; fails the test when
 * it cannot. */
void tu_write_recording(const char *path, const char *device, const char *text);
/* The motion script file at script_path rendered for the device profile `device` (free with
 * fnrec_free); fails the test when it cannot. */
struct fnrec;
struct fnrec *tu_render_script(const char *script_path, const char *device);

/* Whole file into a malloc'd NUL-terminated buffer; NULL if unreadable. */
char *tu_slurp(const char *path, size_t *len);
void tu_write_file(const char *path, const void *data, size_t len);

/* A solid box fragment: dim voxels of 1 mm, every one of probability 1 (255), its first voxel
 * centre at world `at` (home translation), centroid set; f->prob is malloc'd (free it). */
struct frag;
void tu_box_frag(struct frag *f, int id, const int dim[3], const double at[3]);

/* case_load(dir), failing the test with its message when it does not load. */
struct planning_case *tu_case_load(const char *dir);

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

/* cmocka cuts a failure's message at about 1,000 characters, so a command's output shown in a
 * fail_msg lost its end (the error it ended with). This header comes after <cmocka.h>, and its
 * fail_msg prints the whole message (tu_print_failure, to stderr as cmocka does) and then fails
 * (tests/fail_msg_probe.c checks it). */
void tu_print_failure(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
#ifndef fail_msg
#error "include testutil.h after <cmocka.h>: its fail_msg replaces cmocka's"
#else
#undef fail_msg
#define fail_msg(...)                                                                                                 \
    do {                                                                                                              \
        tu_print_failure(__VA_ARGS__);                                                                                \
        fail();                                                                                                       \
    } while (0)
#endif

#endif
