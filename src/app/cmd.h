/* cmd: the CLI's subcommands. Each takes argv with argv[0] = its name, prints its own --help,
 * and returns the process exit status (0 success, 1 runtime failure, 2 usage error). */
#ifndef FN_CMD_H
#define FN_CMD_H

/* The lower layers' types its helpers take, by pointer: a command includes their headers itself. */
typedef struct planning_case planning_case; /* case.h */
typedef struct case_seed case_seed;
typedef struct caselock caselock;           /* caselock.h */
typedef struct vol vol;                     /* vol.h */
typedef struct seg_params seg_params;       /* seg.h */
typedef struct seg_result seg_result;

#define CMD_LIST(X)                                                                          \
    X(demo, "run the built-in demo on the example CT")                                      \
    X(info, "print a volume's dimensions, type, spacing, geometry and range")                \
    X(segment, "segment a CT into bone fragments and save a case")                           \
    X(edit, "correct a case: merge, split, erase, grow, keep or drop fragments")                   \
    X(fracture, "make a synthetic fracture with ground truth from a CT")                     \
    X(devices, "list connected 6-DOF controllers")                                           \
    X(device_test, "live view of a controller's axes and buttons")                           \
    X(record, "record raw reports from a controller to a .fnrec file")                       \
    X(replay, "replay a .fnrec recording through the navigation loop")                      \
    X(navigate, "steer fragments with a 6-DOF controller, collision-checked")               \
    X(reduce, "fit fragments back together: pre-alignment, then PRAXIS (or Powell) on the VOI") \
    X(render, "draw a case's fragments at their poses into a PNG (OpenGL 4.5)")              \
    X(export, "write the plan for 3D Slicer, ITK and printers (tfm, seg.nrrd, NIfTI, STL), and a report") \
    X(bench, "benchmarks with JSON output: collision, build, loop, reduce, render")

#define CMD_DECLARE(name, help) int cmd_##name(int argc, char **argv);
CMD_LIST(CMD_DECLARE)
#undef CMD_DECLARE

/* True when argv holds -h or --help. */
int cmd_wants_help(int argc, char **argv);
/* A flag (--wait, which every command that opens a case takes; --recover): removed from argv
 * (anywhere after the command's name, *argc lowered); 1 when it was there. */
int cmd_take_flag(int *argc, char **argv, const char *flag);
#define CMD_WAIT_HELP                                                                             \
    "  --wait                     when another command holds the case, wait for it (else that\n" \
    "                             is an error at once, naming the command and its pid)\n"
/* The case's lock (caselock.h: exclusive for a command that writes the case), or NULL after
 * printing "fracnav CMD: why" on stderr. */
caselock *cmd_lock_case(const char *cmd, const char *dir, int exclusive, int wait);
/* The frame r has just drawn (w x h) read back and written to path as a PNG (atomically). 0 or
 * FN_E* naming the path. */
struct render;
int cmd_write_png(struct render *r, const char *path, int w, int h);

/* For a command that reads a case (export, render): the poses its journal holds beyond case.json
 * (an interrupted navigate or replay). With recover they are applied to c (edit's reconciliation:
 * case_journal_check, which may set a bad journal aside, so the caller holds the case exclusively);
 * without, c keeps case.json's poses and a warning says how many the journal holds and that
 * --recover uses them. Said on stderr. 0, or FN_E* with fn_err. */
int cmd_journal_poses(const char *cmd, planning_case *c, int recover);
#define CMD_RECOVER_HELP                                                                          \
    "  --recover                  use the poses that CASE/journal holds beyond case.json (left by\n" \
    "                             an interrupted navigate or replay; without it they are only\n"   \
    "                             counted in a warning)\n"
/* Parses the whole of s as a finite number (NULL or trailing text: 0). 1 on success. */
int cmd_number(const char *s, double *out);
/* Prints "fracnav CMD: MESSAGE (see fracnav CMD --help)" on stderr; returns 2, the usage exit. */
int cmd_usage_error(const char *cmd, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* The usage error for option opt's value val (NULL: it had none): "OPT: 'VAL' is not ACCEPTED"
 * or "OPT needs a value (ACCEPTED)", e.g. accepted = "a number (HU), 'auto' or 'auto-bone'".
 * Returns 2. */
int cmd_bad_value(const char *cmd, const char *opt, const char *val, const char *accepted);
/* The VOI boxes of the case's reduction (case.json's reduction.fragments[].voi_mm: lo x y z, hi x
 * y z, world mm), up to cap of them, into voi. Returns how many (0: reduce has defined none). */
int cmd_case_voi(const planning_case *c, double (*voi)[6], int cap);
/* --tau-min T / --tau-max T, the OBB hierarchy's thresholds (obb.h), for every command that
 * builds one. given: bit 0 --tau-min, bit 1 --tau-max were on the command line. */
typedef struct cmd_tau {
    double min, max;
    unsigned given;
} cmd_tau;
#define CMD_TAU_HELP                                                                              \
    "  --tau-min T, --tau-max T   hierarchy thresholds, 0 <= T_min <= T_max <= 1 (a new case:\n" \
    "                             0.5 and 0.95): cells whose collision probability stays under\n" \
    "                             T_min are dropped, cells above T_max are solid\n"
/* When a is --tau-min or --tau-max: parses val (a number from 0 to 1) into t and returns 1 with
 * *rc 0, or with *rc 2 after printing a usage error that names the option. Other a: 0. */
int cmd_tau_option(const char *cmd, const char *a, const char *val, cmd_tau *t, int *rc);
/* After parsing: the values given over a new case's (CASE_TAU_MIN, CASE_TAU_MAX) must keep
 * tau_min <= tau_max. 0, or 2 after printing a usage error naming the options. */
int cmd_tau_check(const char *cmd, const cmd_tau *t);
/* Puts the values given over *tau_min and *tau_max (defaults, or a case's), then checks
 * tau_min <= tau_max. 0, or FN_EINVAL with a message naming the options. */
int cmd_tau_apply(const cmd_tau *t, double *tau_min, double *tau_max);

/* --threshold as segment and fracture take it (seg.h's threshold and threshold_auto). */
#define CMD_THRESHOLD_ACCEPTED "a number (HU), 'auto' or 'auto-bone'"
#define CMD_THRESHOLD_HELP                                                                        \
    "  --threshold HU|auto|auto-bone  bone threshold (default 300 HU); for data not in\n"        \
    "                             HU: auto = Otsu (splits the two main classes: in a\n"         \
    "                             head CT, air from tissue), auto-bone = Otsu again over\n"      \
    "                             the brighter class (tissue from bone)\n"
/* When a is --threshold: parses val into *threshold (a number) or *threshold_auto (1 'auto',
 * 2 'auto-bone'; 0 for a number) and returns 1 with *rc 0, or with *rc 2 after printing a usage
 * error that names the option. Other a: 0. */
int cmd_threshold_option(const char *cmd, const char *a, const char *val, double *threshold,
                         int *threshold_auto, int *rc);

/* The arguments of a command that makes a new case from a volume (segment, fracture): VOLUME,
 * -o/--output CASE, --force, --wait, --json, --threshold and --tau-min/--tau-max. The caller points
 * threshold and threshold_auto at its own parameters. */
typedef struct cmd_case_args {
    const char *in, *out;
    int json, force, wait;
    double *threshold;
    int *threshold_auto;
    cmd_tau tau;
} cmd_case_args;
/* When argv[*i] is one of those: takes it (and the value after it, advancing *i), and returns 1
 * with *rc 0, or with *rc 2 after printing a usage error that names it. Else 0: the command's
 * own option. */
int cmd_case_arg(const char *cmd, int argc, char **argv, int *i, cmd_case_args *c, int *rc);
/* --force replaces a case with its journal: warns on stderr when the journal in dir holds poses
 * that case.json does not, which go with the case. */
void cmd_warn_replaced_journal(const char *cmd, const char *dir, int force);

/* --tau-min/--tau-max over a case's own values, as a session's prepare hook (session_params):
 * ctx is the cmd_tau. 0 or FN_EINVAL (cmd_tau_apply). */
int cmd_tau_prepare(void *ctx, planning_case *c);

/* --pivot X Y Z (world mm): argv[*i] is --pivot; parses the three numbers after it into out and
 * moves *i past them. 0, or a usage error for `cmd` (returns 2). */
int cmd_parse_pivot(const char *cmd, int argc, char **argv, int *i, double out[3]);
/* A seed file's text (at most 16 MiB), NUL-terminated and malloc'd; NULL with fn_err. */
char *cmd_read_seed_file(const char *path);
/* Seeds for a seeded separation (edit separate, segment --separate): when argv[*i] is --seeds
 * (X Y Z world mm per point, each point a piece of its own: 1, 2, ... in order) or --seed-file
 * PATH (case_seeds_parse's format), appends them to *seeds (malloc'd; *n counts them), moves *i
 * past them and returns 1 with *rc 0, or with *rc 2 (usage) or 1 (unreadable file, fn_err set).
 * Other options: 0. */
int cmd_seeds_option(const char *cmd, int argc, char **argv, int *i, case_seed **seeds, int *n, int *rc);
#define CMD_SEEDS_HELP                                                                                  \
    "  --seeds X Y Z [X Y Z ...]  one point per piece (world LPS mm)\n"                            \
    "  --seed-file PATH           labelled points, one per line: PIECE X Y Z (PIECE 1, 2, ...\n"  \
    "                             or none: not bone); several points per piece\n"

/* Output paths, checked before any work. No output lands in a case folder (one that holds
 * case.json: its files are written by the case's own saves alone) or on the source volume of the
 * case in use (in, may be NULL); links are followed to where they lead. Both return 0, or FN_EINVAL
 * with a message that names the path and why. */
/* A file: not a folder, in a folder that exists. */
int cmd_out_file(const char *path, const planning_case *in);
/* A folder a command fills with files: missing (made later), empty, or holding files only with
 * force (those of the names written are replaced), and never a case folder. */
int cmd_out_folder(const char *dir, int force);
/* cmd_out_folder, where a folder holding only entries that own(name) accepts (what this command
 * itself writes there: an earlier run's output, which a run replaces) counts as empty. */
int cmd_out_folder_own(const char *dir, int force, int (*own)(const char *name));
/* A new case (-o) made from the case folder in: neither that folder, nor inside it, nor holding it
 * (the new case is built beside its path and put in place: it would land in the case being read,
 * or replace it). */
int cmd_out_case(const char *out, const char *in);

/* An empty segmentation is an error: 0 when r kept a fragment, else FN_EINVAL saying what was
 * found (v's range, the threshold used, the components dropped by --min-volume); labels: the
 * --labels file r came from, or NULL. */
int cmd_seg_found(const vol *v, const seg_params *p, const seg_result *r, const char *labels);

/* 0 when dir holds a case (a case.json), else FN_EIO naming dir and why: a check before anything
 * slow (opening a device) that a missing case makes pointless. */
int cmd_case_exists(const char *dir);

/* Path of the example CT that .ci/setup caches: $FRACNAV_DATA/Cranium.inv3, else
 * /var/cache/fracnav/Cranium.inv3 (a static buffer). */
const char *cmd_example_ct(void);

#endif
