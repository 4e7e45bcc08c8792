/* fracnav edit: manual corrections of a case, each saved atomically. */
#include "cmd.h"

#include "case.h"
#include "caselock.h"
#include "case_journal.h"
#include "err.h"
#include "jsonw.h"
#include "morph.h"

#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void usage(FILE *out)
{
    fprintf(out,
            "usage: fracnav edit CASE OPERATION ARGS [--json]\n\n"
            "Correct a case's segmentation; the case is saved atomically after the edit (a failed\n"
            "save leaves it as it was). Coordinates are world LPS mm (see case.json's centroids).\n"
            "Poses that CASE/journal holds beyond case.json (an interrupted navigate or replay) are\n"
            "applied first and saved with the edit, so none lands on another fragment after it; a\n"
            "journal that does not extend case.json is kept aside, never applied.\n\n"
            "operations:\n"
            "  merge A B                           fragment B joins fragment A\n"
            "  split ID --plane PX PY PZ NX NY NZ  voxels of ID on the side the normal N points to\n"
            "                                      (plane through P) become a new fragment\n"
            "  erase-box X0 Y0 Z0 X1 Y1 Z1 [--id ID]  erase voxels inside the box (of ID only)\n"
            "  erase-sphere CX CY CZ R [--id ID]   erase voxels within R mm of C (of ID only)\n"
            "  grow X Y Z [--threshold HU] [--into ID]  unlabelled voxels >= HU (default: the\n"
            "                                      case's threshold) connected to the seed become\n"
            "                                      a new fragment (or join ID)\n"
            "  keep IDS                            keep only these fragments (IDS: 1,3 or 1 3)\n"
            "  drop IDS                            remove these fragments\n"
            "  fix ID                              make ID the fixed fragment (0: none)\n"
            "  fill ID [--slices]                  the interior enclosed by ID (cancellous bone\n"
            "                                      under the threshold) joins it: enclosed in 3D,\n"
            "                                      and with --slices also in every slice along\n"
            "                                      each axis (a canal open at its ends; not for a\n"
            "                                      skull, whose slices enclose the brain)\n"
            "  separate ID [--erode MM]            split pieces that touch: erode until ID splits\n"
            "                                      (or by MM), then grow the cores back inside ID\n"
            "                                      (a watershed on the distance map); the largest\n"
            "                                      piece keeps ID, the others become new fragments\n"
            "  separate ID --seeds X Y Z [X Y Z ...] | --seed-file PATH\n"
            "                                      the same from seeds: one point per piece, or a\n"
            "                                      file of labelled points (PIECE X Y Z per line,\n"
            "                                      PIECE 1, 2, ... or none: not bone); the pieces\n"
            "                                      grow from them competing, following the CT's\n"
            "                                      intensities; a seed on bone that ID missed\n"
            "                                      grows ID over it first\n\n"
            "  --json   one JSON object on stdout (the text line goes to stderr): command, case,\n"
            "           operation, what it made (fragment, new_fragment, erased_voxels,\n"
            "           filled_voxels, or new_fragments and erode_mm), the\n"
            "           fragments after the edit (id, voxels, volume_ml) and fixed_fragment\n"
            CMD_WAIT_HELP
            "  --help   this text\n");
}

static int integer(const char *s, int *out)
{
    char *end;
    long v = strtol(s, &end, 10);
    *out = (int)v;
    return end != s && *end == '\0' && v >= 0 && v <= 65535;
}

static int numbers(char **argv, int n, double *out)
{
    for (int i = 0; i < n; i++)
        if (!cmd_number(argv[i], &out[i]))
            return 0;
    return 1;
}

/* IDS as "1,3" and/or separate arguments. Returns the count, or -1. */
static int id_list(int argc, char **argv, int *ids, int cap)
{
    int n = 0;
    for (int i = 0; i < argc; i++) {
        char buf[256];
        snprintf(buf, sizeof buf, "%s", argv[i]);
        for (char *tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
            if (n == cap || !integer(tok, &ids[n]) || ids[n] == 0)
                return -1;
            n++;
        }
    }
    return n ? n : -1;
}

/* `--id ID` after the positional numbers of op, or none (0). Returns 0, or 2 after a usage error. */
static int optional_id(const char *op, int argc, char **argv, int *id)
{
    *id = 0;
    if (argc == 0)
        return 0;
    if (strcmp(argv[0], "--id"))
        return cmd_usage_error("edit", "%s: unknown option or extra argument '%s'", op, argv[0]);
    if (argc > 2)
        return cmd_usage_error("edit", "%s: extra argument '%s'", op, argv[2]);
    if (argc != 2 || !integer(argv[1], id))
        return cmd_bad_value("edit", "--id", argc > 1 ? argv[1] : NULL, "a fragment id (0..65535)");
    return 0;
}

/* What an edit made: its line of text on msg, its figure as res[key] (res NULL: no --json). */
static void made(FILE *msg, json_t *res, const char *key, long value, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
static void made(FILE *msg, json_t *res, const char *key, long value, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vfprintf(msg, fmt, ap);
    va_end(ap);
    if (res && key)
        json_object_set_new(res, key, json_integer(value));
}

/* edit grow X Y Z [--threshold HU] [--into ID]: as apply. */
static int edit_grow(planning_case *c, int argc, char **argv, FILE *msg, json_t *res)
{
    double v[3];
    int id;
    double thr = c->seg.threshold;
    int into = 0;
    if (argc < 3 || !numbers(argv, 3, v))
        return cmd_usage_error("edit", "grow needs X Y Z [--threshold HU] [--into ID]");
    for (int i = 3; i < argc; i += 2) {
        const char *val = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(argv[i], "--threshold")) {
            if (!cmd_number(val, &thr))
                return cmd_bad_value("edit", argv[i], val, "a number (HU)");
        } else if (!strcmp(argv[i], "--into")) {
            if (!val || !integer(val, &into))
                return cmd_bad_value("edit", argv[i], val, "a fragment id (0..65535)");
        } else
            return cmd_usage_error("edit", "grow: unknown option '%s'", argv[i]);
    }
    if ((id = case_grow(c, v, thr, into)) < 0)
        return 1;
    made(msg, res, "fragment", id, "grew fragment %d to %zu voxels\n", id, c->frag[case_find(c, id)].voxels);
    return 0;
}

/* edit fill ID [--slices]: as apply. */
static int edit_fill(planning_case *c, int argc, char **argv, FILE *msg, json_t *res)
{
    int id;
    long rc;
    int mode = MORPH_FILL_3D;
    if (argc < 1 || !integer(argv[0], &id))
        return cmd_usage_error("edit", "fill needs ID [--slices]");
    for (int i = 1; i < argc; i++)
        if (!strcmp(argv[i], "--slices"))
            mode |= MORPH_FILL_SLICES;
        else
            return cmd_usage_error("edit", "fill: unknown option '%s'", argv[i]);
    if ((rc = case_fill(c, id, mode)) < 0)
        return 1;
    made(msg, res, "filled_voxels", rc, "filled %ld voxels of fragment %d's interior\n", rc, id);
    return 0;
}

/* separate's line of text and figures: rc new fragments news, from nseeds seeds or eroded used mm. */
static void separated(int id, long rc, const int *news, int nseeds, double used, FILE *msg, json_t *res)
{
    if (res) {
        json_t *arr = json_array();
        for (long i = 0; i < rc; i++)
            json_array_append_new(arr, json_integer(news[i]));
        jsonw_set(res, "new_fragments", arr);
        jsonw_set(res, "erode_mm", nseeds ? json_null() : jsonw_measure(used));
    }
    if (rc == 0)
        fprintf(msg, "fragment %d stays one piece (from %d seed%s)\n", id, nseeds, nseeds == 1 ? "" : "s");
    else
        fprintf(msg, "separated fragment %d into %ld pieces (new fragments", id, rc + 1);
    for (long i = 0; i < rc; i++)
        fprintf(msg, " %d", news[i]);
    if (rc && nseeds)
        fprintf(msg, "; from %d seeds)\n", nseeds);
    else if (rc)
        fprintf(msg, "; eroded %.2f mm)\n", used);
}

/* edit separate ID [--erode MM] [--seeds X Y Z ...] [--seed-file PATH]: as apply. */
static int edit_separate(planning_case *c, int argc, char **argv, FILE *msg, json_t *res)
{
    int id;
    long rc;
    double erode = 0;
    case_seed *seeds = NULL;
    int nseeds = 0, news[256];
    if (argc < 1 || !integer(argv[0], &id))
        return cmd_usage_error("edit", "separate needs ID [--erode MM] [--seeds X Y Z ...] [--seed-file PATH]");
    for (int i = 1; i < argc; i++) {
        const char *val = i + 1 < argc ? argv[i + 1] : NULL;
        int bad;
        if (cmd_seeds_option("edit", argc, argv, &i, &seeds, &nseeds, &bad)) {
            if (bad) {
                free(seeds);
                return bad;
            }
        } else if (!strcmp(argv[i], "--erode")) {
            if (!cmd_number(val, &erode) || !(erode > 0 && erode < 1000)) {
                free(seeds);
                return cmd_bad_value("edit", argv[i], val, "a distance in mm > 0");
            }
            i++;
        } else {
            free(seeds);
            return cmd_usage_error("edit", "separate: unknown option '%s'", argv[i]);
        }
    }
    if (nseeds && erode > 0) {
        free(seeds);
        return cmd_usage_error("edit", "%s", "separate: --erode or seeds, not both");
    }
    double used = 0;
    rc = nseeds ? case_separate_seeds(c, id, seeds, nseeds, news) : case_separate(c, id, erode, news, &used);
    free(seeds);
    if (rc < 0)
        return 1;
    separated(id, rc, news, nseeds, used, msg, res);
    return 0;
}

/* Applies the operation; returns 0, 2 (usage) or 1 (runtime, fn_err set). The line that says what
 * it did goes to msg; with --json, res gets its figures. */
static int apply(planning_case *c, const char *op, int argc, char **argv, FILE *msg, json_t *res)
{
    double v[6];
    int a, b, id, ids[256], n;
    long rc;
    if (!strcmp(op, "merge")) {
        if (argc != 2 || !integer(argv[0], &a) || !integer(argv[1], &b))
            return cmd_usage_error("edit", "merge needs two fragment ids");
        if ((rc = case_merge(c, a, b)) < 0)
            return 1;
        made(msg, res, "fragment", a, "merged fragment %d into %d\n", b, a);
    } else if (!strcmp(op, "split")) {
        if (argc != 8 || !integer(argv[0], &id) || strcmp(argv[1], "--plane") || !numbers(argv + 2, 6, v))
            return cmd_usage_error("edit", "split needs ID --plane PX PY PZ NX NY NZ");
        if (!(v[3] * v[3] + v[4] * v[4] + v[5] * v[5] > 0))
            return cmd_usage_error("edit", "split --plane: the normal NX NY NZ ('%s %s %s') is zero; give "
                                   "the direction the new fragment lies in", argv[5], argv[6], argv[7]);
        if ((rc = case_split(c, id, v, v + 3)) < 0)
            return 1;
        made(msg, res, "new_fragment", rc, "split fragment %d: the part in front of the plane is fragment %ld\n",
             id, rc);
    } else if (!strcmp(op, "erase-box")) {
        if (argc < 6 || !numbers(argv, 6, v))
            return cmd_usage_error("edit", "erase-box needs X0 Y0 Z0 X1 Y1 Z1 [--id ID]");
        if (optional_id(op, argc - 6, argv + 6, &id))
            return 2;
        if ((rc = case_erase_box(c, v, v + 3, id)) < 0)
            return 1;
        made(msg, res, "erased_voxels", rc, "erased %ld voxels\n", rc);
    } else if (!strcmp(op, "erase-sphere")) {
        if (argc < 4 || !numbers(argv, 4, v))
            return cmd_usage_error("edit", "erase-sphere needs CX CY CZ R [--id ID]");
        if (optional_id(op, argc - 4, argv + 4, &id))
            return 2;
        if (!(v[3] > 0))
            return cmd_bad_value("edit", "erase-sphere R", argv[3], "a radius > 0 mm");
        if ((rc = case_erase_sphere(c, v, v[3], id)) < 0)
            return 1;
        made(msg, res, "erased_voxels", rc, "erased %ld voxels\n", rc);
    } else if (!strcmp(op, "grow")) {
        return edit_grow(c, argc, argv, msg, res);
    } else if (!strcmp(op, "keep") || !strcmp(op, "drop")) {
        if ((n = id_list(argc, argv, ids, 256)) < 0)
            return cmd_usage_error("edit", "keep/drop need fragment ids (1,3 or 1 3)");
        if ((!strcmp(op, "keep") ? case_keep(c, ids, n) : case_drop(c, ids, n)) < 0)
            return 1;
        made(msg, NULL, NULL, 0, "%d fragment%s left\n", c->nfrag, c->nfrag == 1 ? "" : "s");
    } else if (!strcmp(op, "fill")) {
        return edit_fill(c, argc, argv, msg, res);
    } else if (!strcmp(op, "separate")) {
        return edit_separate(c, argc, argv, msg, res);
    } else if (!strcmp(op, "fix")) {
        if (argc != 1 || !integer(argv[0], &id))
            return cmd_usage_error("edit", "fix needs one fragment id (0: none)");
        if (case_fix(c, id) < 0)
            return 1;
        if (id)
            made(msg, NULL, NULL, 0, "fragment %d is fixed\n", id);
        else
            made(msg, NULL, NULL, 0, "no fixed fragment\n");
    } else {
        fprintf(stderr, "fracnav edit: unknown operation '%s' (see fracnav edit --help)\n", op);
        return 2;
    }
    return 0;
}

/* An edit that leaves no fragment is refused (1, fn_err set), saying what it found: nothing is
 * saved, so the case stays as it was. */
static int left_empty(const planning_case *c, const char *op, int nfrag_before, int64_t voxels_before)
{
    if (c->nfrag > 0)
        return 0;
    if (nfrag_before == 0)
        fn_err_set(FN_EINVAL, "%s holds no fragment (its labelmap labels no voxel): nothing to %s", c->dir, op);
    else
        fn_err_set(FN_EINVAL, "%s would leave no fragment: the case's %d fragment%s (%lld voxels) all "
                   "went; refused, %s is left as it was", op, nfrag_before, nfrag_before == 1 ? "" : "s",
                   (long long)voxels_before, c->dir);
    return 1;
}

/* The case after the edit: its fragments and the fixed one. */
static int print_json(const planning_case *c, const char *dir, const char *op, json_t *res)
{
    json_t *o = jsonw_object("edit"), *frags = json_array();
    for (int i = 0; i < c->nfrag; i++)
        json_array_append_new(frags, json_pack("{s:i,s:I,s:o}", "id", c->frag[i].id, "voxels",
                                               (json_int_t)c->frag[i].voxels, "volume_ml",
                                               jsonw_measure(c->frag[i].volume_ml)));
    if (o) {
        jsonw_set(o, "case", jsonw_string(dir));
        jsonw_set(o, "operation", json_string(op));
        json_object_update(o, res);
        jsonw_set(o, "fragments", frags);
        jsonw_set(o, "fixed_fragment", c->fixed >= 0 ? json_integer(c->frag[c->fixed].id) : json_null());
    } else
        json_decref(frags);
    return jsonw_print(o, stdout);
}

/* Takes --json out of argv (anywhere after the command); returns the new argc. */
static int take_json(int argc, char **argv, int *json)
{
    int n = 0;
    for (int i = 0; i < argc; i++)
        if (i > 0 && !strcmp(argv[i], "--json"))
            *json = 1;
        else
            argv[n++] = argv[i];
    return n;
}

int cmd_edit(int argc, char **argv)
{
    if (cmd_wants_help(argc, argv)) {
        usage(stdout);
        return 0;
    }
    int json = 0;
    argc = take_json(argc, argv, &json);
    int wait = cmd_take_flag(&argc, argv, "--wait");
    if (argc < 3)
        return cmd_usage_error("edit", "needs CASE and an operation");
    caselock *lock = cmd_lock_case("edit", argv[1], 1, wait);
    planning_case *c = lock ? case_load(argv[1]) : NULL;
    if (!c) {
        if (lock)
            fprintf(stderr, "fracnav edit: %s\n", fn_err_msg());
        caselock_release(lock);
        return 1;
    }
    journal_rec *recs;
    size_t n;
    FILE *msg = json ? stderr : stdout;
    int rc = case_journal_check(c, &recs, &n) < 0 || case_journal_apply(c, recs, n) < 0 ? 1 : 0;
    free(recs);
    if (rc == 0 && n)
        fprintf(msg, "applied the %zu poses that %s/journal held beyond case.json\n", n, c->dir);
    json_t *res = json ? json_object() : NULL;
    int nfrag_before = c->nfrag;
    int64_t voxels_before = 0;
    for (int i = 0; i < c->nfrag; i++)
        voxels_before += (int64_t)c->frag[i].voxels;
    /* What the operation made is said once it is saved: an edit refused after it ("0 fragments
     * left", then "would leave no fragment") or a failed save says nothing of what it did. */
    char *said = NULL;
    size_t nsaid = 0;
    FILE *ops = open_memstream(&said, &nsaid);
    if (rc == 0)
        rc = apply(c, argv[2], argc - 3, argv + 3, ops ? ops : msg, res);
    if (ops)
        fclose(ops);
    if (rc == 0)
        rc = left_empty(c, argv[2], nfrag_before, voxels_before);
    if (rc == 0 && (case_save(c) < 0 || case_journal_remove(c) < 0))
        rc = 1;
    if (rc == 0 && said)
        fputs(said, msg);
    free(said);
    if (rc == 0 && json && print_json(c, argv[1], argv[2], res) < 0)
        rc = 1;
    if (rc == 1)
        fprintf(stderr, "fracnav edit: %s\n", fn_err_msg());
    json_decref(res);
    case_free(c);
    caselock_release(lock);
    return rc;
}
