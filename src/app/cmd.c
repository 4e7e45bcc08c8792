/* cmd: what the subcommands share -- help and usage errors, numbers, the tau and threshold options,
 * the checks of output paths, the example CT's path. */
#include "cmd.h"

#include "case.h"
#include "caselock.h"
#include "case_journal.h"
#include "durable.h"
#include "err.h"
#include "picture.h"
#include "render.h"

#include <jansson.h>

#include <dirent.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

int cmd_wants_help(int argc, char **argv)
{
    for (int i = 1; i < argc; i++)
        if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help"))
            return 1;
    return 0;
}

int cmd_take_flag(int *argc, char **argv, const char *flag)
{
    int n = 0, given = 0;
    for (int i = 0; i < *argc; i++)
        if (i > 0 && !strcmp(argv[i], flag))
            given = 1;
        else
            argv[n++] = argv[i];
    *argc = n;
    return given;
}

int cmd_journal_poses(const char *cmd, planning_case *c, int recover)
{
    if (!recover) {
        size_t n = case_journal_pending(c->dir);
        if (n)
            fprintf(stderr, "fracnav %s: warning: %s/journal holds %zu poses beyond case.json (an "
                            "interrupted session): using case.json's; --recover uses the journal's\n",
                    cmd, c->dir, n);
        return 0;
    }
    journal_rec *recs = NULL;
    size_t n = 0;
    int rc = case_journal_check(c, &recs, &n);
    if (rc >= 0)
        rc = case_journal_apply(c, recs, n);
    free(recs);
    if (rc == 0 && n)
        fprintf(stderr, "fracnav %s: using the %zu poses that %s/journal holds beyond case.json\n", cmd, n,
                c->dir);
    return rc < 0 ? rc : 0;
}

caselock *cmd_lock_case(const char *cmd, const char *dir, int exclusive, int wait)
{
    caselock *l = caselock_take(dir, exclusive, wait);
    if (!l)
        fprintf(stderr, "fracnav %s: %s\n", cmd, fn_err_msg());
    return l;
}

int cmd_number(const char *s, double *out)
{
    if (!s)
        return 0;
    char *end;
    *out = strtod(s, &end);
    return end != s && *end == '\0' && isfinite(*out);
}

int cmd_usage_error(const char *cmd, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "fracnav %s: ", cmd);
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, " (see fracnav %s --help)\n", cmd);
    va_end(ap);
    return 2;
}

int cmd_bad_value(const char *cmd, const char *opt, const char *val, const char *accepted)
{
    if (!val)
        return cmd_usage_error(cmd, "%s needs a value (%s)", opt, accepted);
    return cmd_usage_error(cmd, "%s: '%s' is not %s", opt, val, accepted);
}

int cmd_case_voi(const planning_case *c, double (*voi)[6], int cap)
{
    json_t *frs = json_object_get(json_object_get(c->extra, "reduction"), "fragments");
    int n = 0;
    for (size_t i = 0; i < json_array_size(frs) && n < cap; i++) {
        json_t *v = json_object_get(json_array_get(frs, i), "voi_mm");
        if (json_array_size(v) != 6)
            continue;
        for (int k = 0; k < 6; k++)
            voi[n][k] = json_number_value(json_array_get(v, (size_t)k));
        n++;
    }
    return n;
}

int cmd_tau_option(const char *cmd, const char *a, const char *val, cmd_tau *t, int *rc)
{
    unsigned which = !strcmp(a, "--tau-min") ? 1 : !strcmp(a, "--tau-max") ? 2 : 0;
    double d;
    *rc = 0;
    if (!which)
        return 0;
    if (!cmd_number(val, &d) || d < 0 || d > 1) {
        *rc = cmd_bad_value(cmd, a, val, "a number from 0 to 1");
        return 1;
    }
    if (which == 1)
        t->min = d;
    else
        t->max = d;
    t->given |= which;
    return 1;
}

int cmd_threshold_option(const char *cmd, const char *a, const char *val, double *threshold,
                         int *threshold_auto, int *rc)
{
    *rc = 0;
    if (strcmp(a, "--threshold"))
        return 0;
    if (val && !strcmp(val, "auto"))
        *threshold_auto = 1;
    else if (val && !strcmp(val, "auto-bone"))
        *threshold_auto = 2;
    else if (cmd_number(val, threshold))
        *threshold_auto = 0;
    else
        *rc = cmd_bad_value(cmd, a, val, CMD_THRESHOLD_ACCEPTED);
    return 1;
}

int cmd_tau_apply(const cmd_tau *t, double *tau_min, double *tau_max)
{
    double lo = t->given & 1 ? t->min : *tau_min, hi = t->given & 2 ? t->max : *tau_max;
    if (lo > hi)
        return fn_err_set(FN_EINVAL, "tau_min %g (%s) is above tau_max %g (%s): need tau_min <= tau_max",
                          lo, t->given & 1 ? "--tau-min" : "the case's or the default", hi,
                          t->given & 2 ? "--tau-max" : "the case's or the default");
    *tau_min = lo;
    *tau_max = hi;
    return 0;
}

int cmd_tau_prepare(void *ctx, planning_case *c)
{
    return cmd_tau_apply(ctx, &c->tau_min, &c->tau_max);
}

int cmd_parse_pivot(const char *cmd, int argc, char **argv, int *i, double out[3])
{
    for (int a = 0; a < 3; a++)
        if (*i + 1 + a >= argc || !cmd_number(argv[*i + 1 + a], &out[a]))
            return cmd_usage_error(cmd, "--pivot needs three numbers X Y Z (world mm)");
    *i += 3;
    return 0;
}

int cmd_tau_check(const char *cmd, const cmd_tau *t)
{
    double lo = CASE_TAU_MIN, hi = CASE_TAU_MAX;
    return cmd_tau_apply(t, &lo, &hi) < 0 ? cmd_usage_error(cmd, "%s", fn_err_msg()) : 0;
}

int cmd_case_arg(const char *cmd, int argc, char **argv, int *i, cmd_case_args *c, int *rc)
{
    const char *a = argv[*i], *val = *i + 1 < argc ? argv[*i + 1] : NULL;
    *rc = 0;
    if (!strcmp(a, "--json")) {
        c->json = 1;
        return 1;
    }
    if (!strcmp(a, "--force")) {
        c->force = 1;
        return 1;
    }
    if (!strcmp(a, "--wait")) {
        c->wait = 1;
        return 1;
    }
    if (a[0] != '-') {
        if (c->in)
            *rc = cmd_usage_error(cmd, "unexpected argument '%s'", a);
        c->in = a;
        return 1;
    }
    if (!strcmp(a, "-o") || !strcmp(a, "--output")) {
        if (!val)
            *rc = cmd_bad_value(cmd, a, val, "a folder");
        c->out = val;
    } else if (!cmd_tau_option(cmd, a, val, &c->tau, rc) &&
               !cmd_threshold_option(cmd, a, val, c->threshold, c->threshold_auto, rc)) {
        return 0;
    }
    ++*i;
    return 1;
}

void cmd_warn_replaced_journal(const char *cmd, const char *dir, int force)
{
    size_t n = force ? case_journal_pending(dir) : 0;
    if (n)
        fprintf(stderr, "fracnav %s: warning: %s/journal holds %zu poses not saved in "
                        "case.json; they go with the case this replaces\n", cmd, dir, n);
}

static int is_case_folder(const char *dir)
{
    char json[PATH_MAX + 16];
    snprintf(json, sizeof json, "%s/case.json", dir);
    return access(json, F_OK) == 0;
}

int cmd_out_file(const char *path, const planning_case *in)
{
    struct stat st, src;
    int exists = stat(path, &st) == 0;
    if (exists && S_ISDIR(st.st_mode))
        return fn_err_set(FN_EINVAL, "%s is a folder: name a file", path);
    int rc = durable_out_of_case(path);
    if (rc == 0 && in && exists && stat(in->source, &src) == 0 && st.st_dev == src.st_dev &&
        st.st_ino == src.st_ino)
        rc = fn_err_set(FN_EINVAL, "%s is the source volume of the case %s: choose another file", path,
                        in->dir);
    return rc;
}

int cmd_out_folder(const char *dir, int force)
{
    return cmd_out_folder_own(dir, force, NULL);
}

int cmd_out_folder_own(const char *dir, int force, int (*own)(const char *name))
{
    struct stat st;
    if (stat(dir, &st) != 0)
        return durable_out_of_case(dir);
    if (!S_ISDIR(st.st_mode))
        return fn_err_set(FN_EINVAL, "%s exists and is not a folder", dir);
    if (is_case_folder(dir))
        return fn_err_set(FN_EINVAL, "%s is a case folder: choose another folder", dir);
    int rc = durable_out_of_case(dir);
    DIR *d = rc == 0 && !force ? opendir(dir) : NULL;
    struct dirent *e;
    while (d && rc == 0 && (e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..") && !(own && own(e->d_name)))
            rc = fn_err_set(FN_EINVAL, "%s holds files already (%s): --force writes over those of "
                                       "the same names, or choose another folder", dir, e->d_name);
    if (d)
        closedir(d);
    return rc;
}

/* path with links resolved where only a leading part of it exists: that part resolved (the
 * working folder when none), the rest as written. 0, or -1 when nothing resolves. */
static int resolve_partly(const char *path, char out[PATH_MAX])
{
    char head[PATH_MAX];
    size_t kept = (size_t)snprintf(head, sizeof head, "%s", path); /* head: path's first kept bytes */
    if (kept >= sizeof head)
        return -1;
    while (!realpath(kept ? head : ".", out)) {
        if (!kept)
            return -1;
        char *slash = strrchr(head, '/');
        kept = !slash ? 0 : slash == head ? 1 : (size_t)(slash - head); /* "/x": the root */
        head[kept] = '\0';
    }
    const char *tail = path + kept;
    while (*tail == '/')
        tail++;
    size_t n = strlen(out);
    if (*tail)
        snprintf(out + n, PATH_MAX - n, "%s%s", out[n - 1] == '/' ? "" : "/", tail);
    return 0;
}

/* 1 when path is dir or lies below it (both resolved). */
static int within(const char *path, const char *dir)
{
    size_t n = strlen(dir);
    return !strncmp(path, dir, n) && (path[n] == '\0' || path[n] == '/' || (n == 1 && dir[0] == '/'));
}

int cmd_out_case(const char *out, const char *in)
{
    char ro[PATH_MAX], ri[PATH_MAX];
    if (resolve_partly(out, ro) < 0 || !realpath(in, ri))
        return 0; /* the case's own checks name what is missing */
    if (!strcmp(ro, ri))
        return fn_err_set(FN_EINVAL, "-o %s is the case being read (%s): choose another folder, or "
                                     "drop -o to save in place", out, in);
    if (within(ro, ri))
        return fn_err_set(FN_EINVAL, "-o %s lies inside the case being read (%s): a case is not built "
                                     "in another; choose a folder outside it", out, in);
    if (within(ri, ro))
        return fn_err_set(FN_EINVAL, "-o %s holds the case being read (%s), which it would replace: "
                                     "choose another folder", out, in);
    return 0;
}

int cmd_seg_found(const vol *v, const seg_params *p, const seg_result *r, const char *labels)
{
    if (r->ncomp > 0)
        return 0;
    if (labels)
        return fn_err_set(FN_EINVAL, "%s holds no label over 0: no fragment to make", labels);
    float lo, hi;
    vol_range(v, &lo, &hi);
    if (r->raw_components == 0)
        return fn_err_set(FN_EINVAL, "no bone: the volume's values run from %g to %g, none at or above the "
                                     "threshold %g%s; give another --threshold", (double)lo, (double)hi,
                          r->threshold, p->threshold_auto ? " (Otsu's)" : "");
    return fn_err_set(FN_EINVAL, "no bone: at the threshold %g%s (values run from %g to %g) none of the %d "
                                 "components reaches --min-volume %g ml; lower it or the threshold",
                      r->threshold, p->threshold_auto ? " (Otsu's)" : "", (double)lo, (double)hi,
                      r->raw_components, p->min_volume_ml);
}

int cmd_case_exists(const char *dir)
{
    if (!is_case_folder(dir))
        return fn_err_set(FN_EIO, "%s is not a case: %s/case.json: %s", dir, dir, strerror(errno));
    return 0;
}

const char *cmd_example_ct(void)
{
    static char path[4096];
    const char *d = getenv("FRACNAV_DATA");
    snprintf(path, sizeof path, "%s/Cranium.inv3", d && *d ? d : "/var/cache/fracnav");
    return path;
}

char *cmd_read_seed_file(const char *path)
{
    enum { MAX = 16 << 20 };
    int fd = durable_open_regular(path, "seed file");
    if (fd < 0)
        return NULL;
    char *text = malloc(MAX + 1);
    size_t len = 0;
    ssize_t got = 1;
    while (text && len < MAX && (got = read(fd, text + len, MAX - len)) > 0)
        len += (size_t)got;
    close(fd);
    if (!text || got < 0 || len == MAX) {
        free(text);
        fn_err_set(text ? FN_EIO : FN_ENOMEM, "%s: %s", path, !text ? "out of memory" : got < 0 ? "read failed"
                                                                      : "larger than 16 MiB");
        return NULL;
    }
    text[len] = '\0';
    return text;
}

static int add_seeds(case_seed **seeds, int *n, const case_seed *more, int m)
{
    case_seed *all = *n + m <= 1 << 20 ? realloc(*seeds, (size_t)(*n + m) * sizeof *all) : NULL;
    if (!all)
        return fn_err_set(FN_ENOMEM, "too many seeds");
    memcpy(all + *n, more, (size_t)m * sizeof *all);
    *seeds = all;
    *n += m;
    return 0;
}

int cmd_seeds_option(const char *cmd, int argc, char **argv, int *i, case_seed **seeds, int *n, int *rc)
{
    const char *a = argv[*i];
    *rc = 0;
    if (!strcmp(a, "--seed-file")) {
        const char *path = *i + 1 < argc ? argv[++*i] : NULL;
        if (!path)
            return *rc = cmd_bad_value(cmd, a, NULL, "a seed file (PIECE X Y Z per line)"), 1;
        char *text = cmd_read_seed_file(path);
        case_seed *more = NULL;
        int m = text ? case_seeds_parse(text, path, &more) : -1;
        if (m < 0 || add_seeds(seeds, n, more, m) < 0)
            *rc = 1;
        free(text);
        free(more);
        return 1;
    }
    if (strcmp(a, "--seeds"))
        return 0;
    int k = *i + 1;
    while (k < argc && strncmp(argv[k], "--", 2))
        k++;
    int nv = k - *i - 1;
    if (nv < 3 || nv % 3 || nv / 3 >= 255)
        return *rc = cmd_usage_error(cmd, "--seeds: give X Y Z (world mm) for each piece, up to 254 (got %d "
                                     "numbers)", nv), 1;
    for (int p = 0; p < nv / 3; p++) {
        case_seed s = {.piece = p + 1};
        for (int c = 0; c < 3; c++)
            if (!cmd_number(argv[*i + 1 + 3 * p + c], &s.at[c]))
                return *rc = cmd_usage_error(cmd, "--seeds: '%s' is not a number", argv[*i + 1 + 3 * p + c]), 1;
        if (add_seeds(seeds, n, &s, 1) < 0)
            return *rc = 1, 1;
    }
    *i = k - 1;
    return 1;
}

int cmd_write_png(struct render *r, const char *path, int w, int h)
{
    uint8_t *rgb = malloc((size_t)w * (size_t)h * 3);
    int rc = rgb ? render_read_rgb(r, rgb) : fn_err_set(FN_ENOMEM, "out of memory for a %dx%d picture", w, h);
    if (!rc)
        rc = picture_write_png(path, rgb, w, h);
    free(rgb);
    return rc;
}
