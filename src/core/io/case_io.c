/* case_save / case_load: case.json through jansson, labels.nii.gz through volio. */
#include "case.h"

#include "durable.h"
#include "err.h"
#include "volio.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <jansson.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define CASE_FORMAT "fracnav-case"
#define LABELS_FILE "labels.nii.gz"
#define LABELS_PREV "labels.prev.nii.gz" /* the labels the on-disk case.json names, during a save */
#define JSON_FILE "case.json"
#define UNDO_PREFIX "undo." /* CASE/undo.N.*: the case before an undoable edit (case_save_undoable) */
#define LABELS_AFTER "labels.after.nii.gz" /* in a step: the case its edit saved */
#define JSON_AFTER "case.after.json"
#define JSON_MAX_BYTES (64 << 20) /* 64 MiB: ~100,000 fragments */

/* ---- writing ---- */

static json_t *num_array(const double *v, int n)
{
    json_t *a = json_array();
    for (int i = 0; i < n; i++)
        json_array_append_new(a, json_real(v[i]));
    return a;
}

static json_t *int_array(const int *v, int n)
{
    json_t *a = json_array();
    for (int i = 0; i < n; i++)
        json_array_append_new(a, json_integer(v[i]));
    return a;
}

static json_t *pose_json(const pose *p)
{
    json_t *o = json_object();
    json_object_set_new(o, "q", num_array(p->q, 4));
    json_object_set_new(o, "t", num_array(p->t, 3));
    return o;
}

static json_t *frag_json(const frag *f, const pose *truth)
{
    json_t *o = json_object();
    json_object_set_new(o, "id", json_integer(f->id));
    json_object_set_new(o, "name", json_string(f->name));
    int rgb[3] = {f->rgb[0], f->rgb[1], f->rgb[2]};
    json_object_set_new(o, "colour", int_array(rgb, 3));
    json_object_set_new(o, "voxels", json_integer((json_int_t)f->voxels));
    json_object_set_new(o, "volume_ml", json_real(f->volume_ml));
    /* The label's own box in source voxel indices (the crop adds one voxel of padding). */
    int lo[3], hi[3];
    for (int a = 0; a < 3; a++) {
        lo[a] = f->origin[a] + 1;
        hi[a] = f->origin[a] + f->dim[a] - 2;
    }
    json_t *bb = json_object();
    json_object_set_new(bb, "min_ijk", int_array(lo, 3));
    json_object_set_new(bb, "max_ijk", int_array(hi, 3));
    json_object_set_new(o, "bbox", bb);
    json_object_set_new(o, "centroid", num_array(f->centroid, 3));
    json_t *axes = json_array();
    for (int c = 0; c < 3; c++) {
        double col[3] = {f->axes[0][c], f->axes[1][c], f->axes[2][c]};
        json_array_append_new(axes, num_array(col, 3));
    }
    json_object_set_new(o, "axes", axes);
    json_object_set_new(o, "eigenvalues", num_array(f->eigval, 3));
    json_object_set_new(o, "pose", pose_json(&f->pose));
    if (truth)
        json_object_set_new(o, "truth", pose_json(truth));
    return o;
}

/* The source path as stored: relative when it lies inside the case folder. */
static void stored_source(const planning_case *c, char *out, size_t cap)
{
    char rdir[PATH_MAX], rsrc[PATH_MAX];
    if (realpath(c->dir, rdir) && realpath(c->source, rsrc)) {
        size_t n = strlen(rdir);
        if (!strncmp(rsrc, rdir, n) && rsrc[n] == '/') {
            snprintf(out, cap, "%s", rsrc + n + 1);
            return;
        }
        snprintf(out, cap, "%s", rsrc);
        return;
    }
    snprintf(out, cap, "%s", c->source);
}

/* "fixed": null, the fixed fragment's id, or (several fixed) their ids, c->fixed's first. */
static json_t *fixed_json(const planning_case *c)
{
    if (c->fixed < 0)
        return json_null();
    if (!c->nfixed_also)
        return json_integer(c->frag[c->fixed].id);
    json_t *a = json_array();
    json_array_append_new(a, json_integer(c->frag[c->fixed].id));
    for (int k = 0; k < c->nfixed_also; k++)
        json_array_append_new(a, json_integer(c->fixed_also[k]));
    return a;
}

static json_t *case_json(const planning_case *c, const char *labels_sha)
{
    json_t *root = json_object();
    json_object_set_new(root, "format", json_string(CASE_FORMAT));
    json_object_set_new(root, "version", json_integer(CASE_VERSION));
    char src[PATH_MAX];
    stored_source(c, src, sizeof src);
    json_t *s = json_object();
    json_object_set_new(s, "path", json_string(src));
    json_object_set_new(s, "sha256", json_string(c->sha256));
    json_object_set_new(s, "dim", int_array(c->ct->dim, 3));
    json_object_set_new(s, "spacing", num_array(c->ct->spacing, 3));
    json_t *aff = json_array();
    for (int r = 0; r < 3; r++)
        json_array_append_new(aff, num_array(c->ct->affine[r], 4));
    json_object_set_new(s, "affine", aff);
    json_object_set_new(root, "source", s);
    json_t *l = json_object();
    json_object_set_new(l, "path", json_string(LABELS_FILE));
    json_object_set_new(l, "sha256", json_string(labels_sha));
    json_object_set_new(root, "labels", l);
    json_t *sg = json_object();
    json_object_set_new(sg, "threshold", json_real(c->seg.threshold));
    static const char *modes[] = {"value", "auto", "auto-bone"};
    json_object_set_new(sg, "threshold_mode", json_string(modes[c->seg.threshold_auto % 3]));
    json_object_set_new(sg, "min_volume_ml", json_real(c->seg.min_volume_ml));
    json_object_set_new(sg, "exclude_below_peak",
                        c->seg.exclude_peak ? json_real(c->seg.exclude_below_peak) : json_null());
    json_object_set_new(sg, "keep", json_integer(c->seg.keep));
    json_object_set_new(sg, "ramp", json_real(c->seg.ramp));
    json_object_set_new(root, "segmentation", sg);
    json_object_set_new(root, "tau_min", json_real(c->tau_min));
    json_object_set_new(root, "tau_max", json_real(c->tau_max));
    json_object_set_new(root, "fixed", fixed_json(c));
    json_object_set_new(root, "has_truth", json_boolean(c->has_truth));
    json_t *fr = json_array();
    for (int i = 0; i < c->nfrag; i++)
        json_array_append_new(fr, frag_json(&c->frag[i], c->has_truth ? &c->truth[i] : NULL));
    json_object_set_new(root, "fragments", fr);
    const char *key;
    json_t *val;
    json_object_foreach((json_t *)c->extra, key, val)
        if (!json_object_get(root, key))
            json_object_set(root, key, val);
    return root;
}

static void join(char *out, size_t cap, const char *dir, const char *name)
{
    snprintf(out, cap, "%s/%s", dir, name);
}

/* Keeps the labels that the current case.json names as LABELS_PREV (a hard link, no copy), so a
 * crash between the two renames of a save leaves a consistent pair that case_load can fall back to. */
static int keep_previous_labels(const char *lfin, const char *lprev, const char *dir)
{
    if (unlink(lprev) != 0 && errno != ENOENT)
        return fn_err_set(FN_EIO, "%s: cannot remove: %s", lprev, strerror(errno));
    if (link(lfin, lprev) != 0) {
        /* No previous labels (a first save), or a file system without hard links: save as before. */
        if (errno == ENOENT || errno == EPERM || errno == ENOTSUP || errno == EOPNOTSUPP)
            return 0;
        return fn_err_set(FN_EIO, "%s: cannot link to %s: %s", lprev, lfin, strerror(errno));
    }
    return durable_sync_path(dir);
}

/* case.json's text for labels of sha256 lsha, with a final newline; NULL with fn_err. */
static char *case_text(const planning_case *c, const char *lsha, const char *jfin)
{
    json_t *root = case_json(c, lsha);
    char *text = json_dumps(root, JSON_INDENT(2) | JSON_REAL_PRECISION(17));
    json_decref(root);
    if (!text) {
        fn_err_set(FN_ENOMEM, "%s: cannot serialise the case", jfin);
        return NULL;
    }
    size_t n = strlen(text);
    char *nl = realloc(text, n + 2);
    if (nl) {
        text = nl;
        strcpy(text + n, "\n");
    }
    return text;
}

/* A checksum of the labelmap's values: two independent multiply-xorshift mixes over its 8-byte
 * words, each in four lanes (word 4q + r into lane r, so the lanes' chains run side by side), the
 * lanes folded in order at the end. What case_save compares to know the labels unchanged since
 * the file was made; kept in memory only. */
static void labels_checksum(const vol *l, uint64_t sum[2])
{
    const unsigned char *b = (const unsigned char *)l->data;
    size_t n = vol_count(l) * sizeof *l->data, words = n / 8, q = 0;
    uint64_t h0[4], h1[4];
    for (int r = 0; r < 4; r++) {
        h0[r] = (0x243f6a8885a308d3ull + 0x9e3779b97f4a7c15ull * (uint64_t)r) ^ n;
        h1[r] = (0x13198a2e03707344ull + 0xc2b2ae3d27d4eb4full * (uint64_t)r) ^ (n * 31);
    }
    for (; q + 4 <= words; q += 4)
        for (int r = 0; r < 4; r++) {
            uint64_t w;
            memcpy(&w, b + 8 * (q + (size_t)r), 8);
            h0[r] = (h0[r] ^ w) * 0x9e3779b97f4a7c15ull;
            h0[r] ^= h0[r] >> 29;
            h1[r] = (h1[r] + w) * 0xc2b2ae3d27d4eb4full;
            h1[r] ^= h1[r] >> 31;
        }
    uint64_t g0 = h0[0], g1 = h1[0];
    for (int r = 1; r < 4; r++) {
        g0 = (g0 ^ h0[r]) * 0x9e3779b97f4a7c15ull;
        g0 ^= g0 >> 29;
        g1 = (g1 + h1[r]) * 0xc2b2ae3d27d4eb4full;
        g1 ^= g1 >> 31;
    }
    for (size_t i = 8 * q; i < n; i++) {
        g0 = (g0 ^ b[i]) * 0x9e3779b97f4a7c15ull;
        g1 = (g1 + b[i]) * 0xc2b2ae3d27d4eb4full;
    }
    sum[0] = g0 ^ (g0 >> 32);
    sum[1] = g1 ^ (g1 >> 33);
}

/* Whether c's labels are those of the labels file in the case folder: c->labels_sha256 is that
 * file's sha256 now, and the labels' values still have the checksum they had when it was read or
 * written. */
static int labels_on_disk(const planning_case *c, const char *lfin)
{
    char now[65];
    uint64_t sum[2];
    if (!c->labels_sha256[0] || durable_file_sha256(lfin, now) < 0 || strcmp(now, c->labels_sha256))
        return 0;
    labels_checksum(c->labels, sum);
    return sum[0] == c->labels_sum[0] && sum[1] == c->labels_sum[1];
}

/* c's labels written aside of lfin (durable_create, sealed) into *lt, their sha256 into lsha. */
static int labels_aside(const planning_case *c, durable_file *lt, const char *lfin, char lsha[65])
{
    int rc = durable_create(lt, lfin);
    if (rc == 0)
        rc = volio_write(c->labels, lt->tmp, VOL_U16);
    if (rc == 0)
        rc = durable_seal(lt);
    return rc == 0 ? durable_file_sha256(lt->tmp, lsha) : rc;
}

/* Writes both files aside (durable.h), then renames labels then case.json; the previous labels stay
 * linked until both are in place. Labels unchanged since the folder's file was read or written are
 * not written again: case.json alone is, naming that file. */
int case_save(planning_case *c)
{
    if (mkdir(c->dir, 0755) != 0 && errno != EEXIST)
        return fn_err_set(FN_EIO, "%s: cannot create the case folder: %s", c->dir, strerror(errno));
    char lfin[4200], jfin[4200], lprev[4200], lsha[65], jsha[65];
    join(lprev, sizeof lprev, c->dir, LABELS_PREV);
    join(lfin, sizeof lfin, c->dir, LABELS_FILE);
    join(jfin, sizeof jfin, c->dir, JSON_FILE);
    durable_file lt = {.fd = -1}, jt = {.fd = -1};
    int keep = labels_on_disk(c, lfin), rc = keep ? 0 : labels_aside(c, &lt, lfin, lsha);
    if (keep)
        memcpy(lsha, c->labels_sha256, sizeof lsha);
    if (rc == 0)
        rc = durable_create(&jt, jfin);
    if (rc == 0) {
        char *text = case_text(c, lsha, jfin);
        rc = text ? durable_write_all(&jt, text, strlen(text)) : FN_ENOMEM;
        if (rc == 0)
            durable_sha256(text, strlen(text), jsha);
        free(text);
    }
    if (rc == 0)
        rc = durable_seal(&jt);
    if (rc == 0 && !keep && (rc = keep_previous_labels(lfin, lprev, c->dir)) == 0)
        rc = durable_rename(&lt, lfin);
    if (rc == 0)
        rc = durable_rename(&jt, jfin);
    if (rc == 0)
        rc = durable_sync_path(c->dir);
    durable_abort(&lt);
    durable_abort(&jt);
    if (rc < 0)
        return fn_err_wrap(rc, "saving case %s", c->dir);
    if (!keep) {
        unlink(lprev); /* a leftover is harmless: the next save replaces it */
        memcpy(c->labels_sha256, lsha, sizeof lsha);
        labels_checksum(c->labels, c->labels_sum);
    }
    memcpy(c->json_sha256, jsha, sizeof jsha);
    return 0;
}

/* ---- undo ---- */

/* The newest undo step of dir (the largest N of its files UNDO_PREFIX N.case.json): its files'
 * common start, DIR/undo.N., into step; 0 when none. The steps' files lie in the case folder
 * itself, which stays flat (case_stage replaces only such folders). */
static int newest_step(const char *dir, char *step, size_t cap)
{
    DIR *d = opendir(dir);
    int newest = 0;
    size_t plen = strlen(UNDO_PREFIX);
    for (struct dirent *e; d && (e = readdir(d));) {
        char *end = "";
        long n = strncmp(e->d_name, UNDO_PREFIX, plen) ? 0 : strtol(e->d_name + plen, &end, 10);
        if (n > newest && n < INT_MAX && !strcmp(end, "." JSON_FILE))
            newest = (int)n;
    }
    if (d)
        closedir(d);
    snprintf(step, cap, "%s/" UNDO_PREFIX "%d.", dir, newest);
    return newest;
}

/* A file of a step (newest_step's prefix). */
static void step_file(char *out, size_t cap, const char *step, const char *name)
{
    snprintf(out, cap, "%s%s", step, name);
}

/* Whether files a and b hold the same bytes (by sha256; both must be readable). */
static int same_file(const char *a, const char *b)
{
    char ha[65], hb[65];
    return durable_file_sha256(a, ha) == 0 && durable_file_sha256(b, hb) == 0 && !strcmp(ha, hb);
}

static int remove_step(const char *dir, const char *step)
{
    const char *names[] = {LABELS_FILE, LABELS_AFTER, JSON_AFTER, JSON_FILE}; /* case.json, which names
                                                                              * the step, last */
    char f[4400];
    for (int i = 0; i < 4; i++) {
        step_file(f, sizeof f, step, names[i]);
        if (unlink(f) != 0 && errno != ENOENT)
            return fn_err_set(FN_EIO, "%s: cannot remove: %s", f, strerror(errno));
    }
    return durable_sync_path(dir);
}

/* The newest step that differs from the case as it is (one equal to it is what a crash left
 * between keeping it and the save, or after an undo's renames: dropped). 0 when none. */
static int live_step(const char *dir, char *step, size_t cap)
{
    char jfin[4200], sj[4400];
    join(jfin, sizeof jfin, dir, JSON_FILE);
    for (int n; (n = newest_step(dir, step, cap)) > 0;) {
        step_file(sj, sizeof sj, step, JSON_FILE);
        if (!same_file(sj, jfin))
            return n;
        int rc = remove_step(dir, step);
        if (rc < 0)
            return rc;
    }
    return 0;
}

/* The newest step when the case is still as its edit saved it (nothing saved since, which an
 * undo would lose), else 0. */
static int undoable_step(const char *dir, char *step, size_t cap)
{
    char lfin[4200], jfin[4200], lafter[4400], jafter[4400];
    int n = live_step(dir, step, cap);
    join(lfin, sizeof lfin, dir, LABELS_FILE);
    join(jfin, sizeof jfin, dir, JSON_FILE);
    step_file(lafter, sizeof lafter, step, LABELS_AFTER);
    step_file(jafter, sizeof jafter, step, JSON_AFTER);
    return n > 0 && !(same_file(lafter, lfin) && same_file(jafter, jfin)) ? 0 : n;
}

int case_undo_steps(const char *dir)
{
    char step[4300];
    return undoable_step(dir, step, sizeof step);
}

/* Links from to to (to replaced). */
static int link_over(const char *from, const char *to)
{
    if ((unlink(to) != 0 && errno != ENOENT) || link(from, to) != 0)
        return fn_err_set(FN_EIO, "%s: cannot link to %s: %s (the undo step needs hard links)", to, from,
                          strerror(errno));
    return 0;
}

int case_save_undoable(planning_case *c)
{
    char step[4300], f[4400], jfin[4200], lfin[4200];
    join(jfin, sizeof jfin, c->dir, JSON_FILE);
    join(lfin, sizeof lfin, c->dir, LABELS_FILE);
    int n = live_step(c->dir, step, sizeof step);
    if (n < 0)
        return n;
    snprintf(step, sizeof step, "%s/" UNDO_PREFIX "%d.", c->dir, n + 1);
    step_file(f, sizeof f, step, LABELS_FILE);
    int rc = link_over(lfin, f);
    step_file(f, sizeof f, step, JSON_FILE); /* last: it makes the step */
    if (rc == 0)
        rc = link_over(jfin, f);
    if (rc == 0)
        rc = durable_sync_path(c->dir);
    if (rc < 0)
        return fn_err_wrap(rc, "keeping case %s for undo", c->dir);
    if ((rc = case_save(c)) < 0)
        return rc;
    step_file(f, sizeof f, step, LABELS_AFTER); /* a crash before these links leaves the step unoffered */
    if ((rc = link_over(lfin, f)) == 0) {
        step_file(f, sizeof f, step, JSON_AFTER);
        rc = link_over(jfin, f);
    }
    return rc ? rc : durable_sync_path(c->dir);
}

int case_undo(const char *dir)
{
    char step[4300], sj[4400], sl[4400], jfin[4200], lfin[4200], lprev[4200];
    int n = undoable_step(dir, step, sizeof step);
    if (n <= 0)
        return n;
    step_file(sj, sizeof sj, step, JSON_FILE);
    step_file(sl, sizeof sl, step, LABELS_FILE);
    join(jfin, sizeof jfin, dir, JSON_FILE);
    join(lfin, sizeof lfin, dir, LABELS_FILE);
    join(lprev, sizeof lprev, dir, LABELS_PREV);
    /* As case_save: the labels, then case.json, the labels case.json names kept until both are in
     * place; the step's files are linked in under temporaries of their own (durable_link: never a
     * name planted there), so a crash keeps the step whole until it is done. */
    durable_file lt = {.fd = -1}, jt = {.fd = -1};
    int rc = durable_link(&lt, sl, lfin);
    if (rc == 0)
        rc = durable_link(&jt, sj, jfin);
    if (rc == 0)
        rc = durable_sync_path(dir);
    if (rc == 0)
        rc = keep_previous_labels(lfin, lprev, dir);
    if (rc == 0)
        rc = durable_rename(&lt, lfin);
    if (rc == 0)
        rc = durable_rename(&jt, jfin);
    if (rc == 0)
        rc = durable_sync_path(dir);
    durable_abort(&lt);
    durable_abort(&jt);
    if (rc < 0)
        return fn_err_wrap(rc, "undoing the last edit of case %s", dir);
    unlink(lprev);
    rc = remove_step(dir, step);
    return rc < 0 ? rc : 1;
}

/* ---- reading ---- */

struct reader {
    const char *file;
    char field[160];
};

static int bad(const struct reader *r, const char *what)
{
    return fn_err_set(FN_EFORMAT, "%s: field %s: %s", r->file, r->field, what);
}


static json_t *get(struct reader *r, json_t *obj, const char *prefix, const char *key)
{
    snprintf(r->field, sizeof r->field, "%s%s", prefix, key);
    json_t *v = json_is_object(obj) ? json_object_get(obj, key) : NULL;
    if (!v)
        bad(r, "missing");
    return v;
}

static int get_num(struct reader *r, json_t *obj, const char *prefix, const char *key, double *out)
{
    json_t *v = get(r, obj, prefix, key);
    if (!v)
        return FN_EFORMAT;
    if (!json_is_number(v) || !isfinite(json_number_value(v)))
        return bad(r, "expected a finite number");
    *out = json_number_value(v);
    return 0;
}

static int get_int(struct reader *r, json_t *obj, const char *prefix, const char *key, long lo,
                   long hi, long *out)
{
    json_t *v = get(r, obj, prefix, key);
    if (!v)
        return FN_EFORMAT;
    if (!json_is_integer(v) || json_integer_value(v) < lo || json_integer_value(v) > hi) {
        char msg[80];
        snprintf(msg, sizeof msg, "expected an integer in %ld..%ld", lo, hi);
        return bad(r, msg);
    }
    *out = (long)json_integer_value(v);
    return 0;
}

/* "fixed" as fixed_json writes it: null, one id (the older form), or an array of ids. */
static int read_fixed(struct reader *r, json_t *root, planning_case *c)
{
    json_t *fixed = get(r, root, "", "fixed"), *v;
    if (!fixed)
        return FN_EFORMAT;
    if (json_is_null(fixed))
        return 0;
    json_t *one = json_is_array(fixed) ? NULL : fixed;
    size_t n = one ? 1 : json_array_size(fixed);
    if (!n || n > CASE_FIXED_MAX)
        return bad(r, "expected a fragment id, null, or an array of 1..64 fragment ids");
    int idx[CASE_FIXED_MAX];
    for (size_t k = 0; k < n; k++) {
        v = one ? one : json_array_get(fixed, k);
        if (!json_is_integer(v) || json_integer_value(v) < 1 || json_integer_value(v) > 65535)
            return bad(r, "expected fragment ids, integers in 1..65535");
        if ((idx[k] = case_find(c, (int)json_integer_value(v))) < 0)
            return bad(r, "names a fragment the case does not have");
    }
    c->fixed = idx[0];
    c->nfixed_also = 0;
    for (size_t k = 1; k < n; k++)
        c->fixed_also[c->nfixed_also++] = c->frag[idx[k]].id;
    return 0;
}

static int get_nums(struct reader *r, json_t *obj, const char *prefix, const char *key, double *out,
                    int n)
{
    json_t *v = get(r, obj, prefix, key);
    if (!v)
        return FN_EFORMAT;
    char msg[64];
    snprintf(msg, sizeof msg, "expected an array of %d finite numbers", n);
    if (!json_is_array(v) || (int)json_array_size(v) != n)
        return bad(r, msg);
    for (int i = 0; i < n; i++) {
        json_t *e = json_array_get(v, (size_t)i);
        if (!json_is_number(e) || !isfinite(json_number_value(e)))
            return bad(r, msg);
        out[i] = json_number_value(e);
    }
    return 0;
}

static const char *get_str(struct reader *r, json_t *obj, const char *prefix, const char *key)
{
    json_t *v = get(r, obj, prefix, key);
    if (!v)
        return NULL;
    if (!json_is_string(v)) {
        bad(r, "expected a string");
        return NULL;
    }
    return json_string_value(v);
}

static int get_pose(struct reader *r, json_t *obj, const char *prefix, const char *key, pose *p)
{
    char pre[128];
    snprintf(pre, sizeof pre, "%s%s.", prefix, key);
    json_t *o = get(r, obj, prefix, key);
    if (!o)
        return FN_EFORMAT;
    if (get_nums(r, o, pre, "q", p->q, 4) < 0 || get_nums(r, o, pre, "t", p->t, 3) < 0)
        return FN_EFORMAT;
    double n2 = p->q[0] * p->q[0] + p->q[1] * p->q[1] + p->q[2] * p->q[2] + p->q[3] * p->q[3];
    if (fabs(n2 - 1) > 1e-6) {
        snprintf(r->field, sizeof r->field, "%sq", pre);
        return bad(r, "the quaternion is not of unit length");
    }
    return 0;
}

static int read_seg(struct reader *r, json_t *root, seg_params *sp)
{
    json_t *sg = get(r, root, "", "segmentation");
    if (!sg)
        return FN_EFORMAT;
    const char *p = "segmentation.";
    long keep;
    if (get_num(r, sg, p, "threshold", &sp->threshold) < 0 ||
        get_num(r, sg, p, "min_volume_ml", &sp->min_volume_ml) < 0 ||
        get_int(r, sg, p, "keep", 0, 1000000, &keep) < 0 || get_num(r, sg, p, "ramp", &sp->ramp) < 0)
        return FN_EFORMAT;
    if (sp->ramp < 0)
        return bad(r, "must be >= 0");
    sp->keep = (int)keep;
    const char *mode = get_str(r, sg, p, "threshold_mode");
    if (!mode)
        return FN_EFORMAT;
    if (!strcmp(mode, "value") || !strcmp(mode, "auto") || !strcmp(mode, "auto-bone"))
        sp->threshold_auto = mode[0] == 'v' ? 0 : strlen(mode) > 4 ? 2 : 1;
    else
        return bad(r, "expected \"value\", \"auto\" or \"auto-bone\"");
    json_t *e = get(r, sg, p, "exclude_below_peak");
    if (!e)
        return FN_EFORMAT;
    sp->exclude_peak = !json_is_null(e);
    if (sp->exclude_peak && get_num(r, sg, p, "exclude_below_peak", &sp->exclude_below_peak) < 0)
        return FN_EFORMAT;
    return 0;
}

/* Source geometry recorded in case.json against the volume read now. */
static int check_geometry(struct reader *r, json_t *src, const vol *ct, const char *what)
{
    double dim[3], aff[3][4];
    if (get_nums(r, src, "source.", "dim", dim, 3) < 0)
        return FN_EFORMAT;
    json_t *a = get(r, src, "source.", "affine");
    if (!a)
        return FN_EFORMAT;
    if (!json_is_array(a) || json_array_size(a) != 3)
        return bad(r, "expected 3 rows of 4 numbers");
    for (int row = 0; row < 3; row++) {
        char key[16];
        snprintf(key, sizeof key, "%d", row);
        json_t *wrap = json_pack("{s:O}", key, json_array_get(a, (size_t)row));
        int rc = get_nums(r, wrap, "source.affine.", key, aff[row], 4);
        json_decref(wrap);
        if (rc < 0)
            return rc;
    }
    for (int i = 0; i < 3; i++)
        if (dim[i] != ct->dim[i])
            return fn_err_set(FN_EMISMATCH, "%s is %dx%dx%d voxels but %s records %gx%gx%g", what,
                              ct->dim[0], ct->dim[1], ct->dim[2], r->file, dim[0], dim[1], dim[2]);
    for (int row = 0; row < 3; row++)
        for (int col = 0; col < 4; col++)
            if (fabs(aff[row][col] - ct->affine[row][col]) > 1e-3)
                return fn_err_set(FN_EMISMATCH, "%s: index-to-world affine [%d][%d] is %g but %s "
                                                "records %g", what, row, col,
                                  ct->affine[row][col], r->file, aff[row][col]);
    return 0;
}

static int same_grid(const vol *a, const vol *b, const char *what)
{
    for (int i = 0; i < 3; i++)
        if (a->dim[i] != b->dim[i])
            return fn_err_set(FN_EMISMATCH, "%s is %dx%dx%d but the source is %dx%dx%d", what,
                              a->dim[0], a->dim[1], a->dim[2], b->dim[0], b->dim[1], b->dim[2]);
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++)
            if (fabs(a->affine[r][c] - b->affine[r][c]) > 1e-3)
                return fn_err_set(FN_EMISMATCH, "%s: its grid is placed differently from the "
                                                "source's (affine [%d][%d])", what, r, c);
    return 0;
}

/* Names, colours, poses and truth from the fragments array; ids must match the labels, each once. */
static int read_fragment_list(struct reader *r, json_t *fr, planning_case *c, uint8_t *seen)
{
    for (int i = 0; i < c->nfrag; i++) {
        json_t *o = json_array_get(fr, (size_t)i);
        char pre[48];
        snprintf(pre, sizeof pre, "fragments[%d].", i);
        long id = 0, rgb[3];
        if (get_int(r, o, pre, "id", 1, 65535, &id) < 0)
            return FN_EFORMAT;
        int k = case_find(c, (int)id);
        if (k < 0)
            return fn_err_set(FN_EMISMATCH, "%s: field %sid: fragment %ld is not in labels.nii.gz",
                              r->file, pre, id);
        if (seen[k])
            return fn_err_set(FN_EFORMAT, "%s: field %sid: fragment %ld is listed twice", r->file,
                              pre, id);
        seen[k] = 1;
        frag *f = &c->frag[k];
        const char *name = get_str(r, o, pre, "name");
        if (!name || get_pose(r, o, pre, "pose", &f->pose) < 0)
            return FN_EFORMAT;
        snprintf(f->name, sizeof f->name, "%s", name);
        json_t *col = get(r, o, pre, "colour");
        if (!col || !json_is_array(col) || json_array_size(col) != 3)
            return col ? bad(r, "expected [r, g, b]") : FN_EFORMAT;
        for (int a = 0; a < 3; a++) {
            json_t *e = json_array_get(col, (size_t)a);
            rgb[a] = json_is_integer(e) ? (long)json_integer_value(e) : -1;
            if (rgb[a] < 0 || rgb[a] > 255)
                return bad(r, "expected [r, g, b] of integers 0..255");
            f->rgb[a] = (uint8_t)rgb[a];
        }
        if (c->has_truth && get_pose(r, o, pre, "truth", &c->truth[k]) < 0)
            return FN_EFORMAT;
    }
    return 0;
}

static int read_fragments(struct reader *r, json_t *root, planning_case *c)
{
    json_t *fr = get(r, root, "", "fragments");
    if (!fr)
        return FN_EFORMAT;
    if (!json_is_array(fr))
        return bad(r, "expected an array");
    if ((int)json_array_size(fr) != c->nfrag)
        return fn_err_set(FN_EMISMATCH, "%s lists %zu fragments but labels.nii.gz holds %d",
                          r->file, json_array_size(fr), c->nfrag);
    uint8_t *seen = calloc((size_t)c->nfrag + 1, 1);
    if (!seen)
        return fn_err_set(FN_ENOMEM, "case: out of memory");
    int rc = read_fragment_list(r, fr, c, seen);
    free(seen);
    return rc;
}

/* Top-level members this module does not own, kept for the modules that do. */
static int keep_extra(json_t *root, planning_case *c)
{
    static const char *own[] = {"format", "version", "source", "labels", "segmentation", "tau_min",
                                "tau_max", "fixed", "has_truth", "fragments"};
    c->extra = json_deep_copy(root);
    if (!c->extra)
        return fn_err_set(FN_ENOMEM, "case: out of memory");
    for (size_t i = 0; i < sizeof own / sizeof own[0]; i++)
        json_object_del(c->extra, own[i]);
    return 0;
}

/* The labels file whose sha256 is lsha: labels.nii.gz, or after a save interrupted between its two
 * renames, the previous labels it kept, which are put back in place (said on stderr). */
static int find_labels(const char *dir, const char *json, const char *lsha, char *lpath, size_t cap)
{
    char lprev[4200], lnow[65], pnow[65];
    join(lpath, cap, dir, LABELS_FILE);
    join(lprev, sizeof lprev, dir, LABELS_PREV);
    int rc = durable_file_sha256(lpath, lnow);
    if (rc < 0 || !strcmp(lnow, lsha))
        return rc;
    if (durable_file_sha256(lprev, pnow) < 0 || strcmp(pnow, lsha))
        return fn_err_set(FN_EMISMATCH, "%s has sha256 %.12s..., but %s expects %.12s...: it was "
                                        "changed or a save was interrupted", lpath, lnow, json, lsha);
    /* moved also when only the folder's sync failed: the previous labels are in place then */
    int moved = durable_move(lprev, lpath) == 0 || access(lprev, F_OK) != 0;
    fprintf(stderr, "fracnav: %s: a save was interrupted; %s the previous labels, %s, which match %s\n",
            dir, moved ? "restored" : "using", LABELS_PREV, json);
    if (!moved)
        snprintf(lpath, cap, "%s", lprev);
    return 0;
}

/* A plan saved with fragments inside each other (the session records "penetrating"): every command
 * that loads it says so. */
static void warn_penetrating(const struct reader *r, json_t *root)
{
    json_t *pen = json_object_get(root, "penetrating"), *e;
    size_t i;
    json_array_foreach(pen, i, e) {
        json_t *ids = json_object_get(e, "fragments");
        if (json_is_true(json_object_get(e, "within_fit_tolerance")))
            continue; /* where a fit left them: not a plan to warn of */
        fprintf(stderr, "fracnav: warning: %s: the saved poses put fragments %lld and %lld inside "
                        "each other (%.3f ml)\n", r->file,
                (long long)json_integer_value(json_array_get(ids, 0)),
                (long long)json_integer_value(json_array_get(ids, 1)),
                json_number_value(json_object_get(e, "overlap_ml")));
    }
}

static int read_case(struct reader *r, json_t *root, planning_case *c)
{
    const char *fmt = get_str(r, root, "", "format");
    if (!fmt)
        return FN_EFORMAT;
    if (strcmp(fmt, CASE_FORMAT))
        return bad(r, "not a fracnav case");
    long version;
    if (get_int(r, root, "", "version", 0, 1000000, &version) < 0)
        return FN_EFORMAT;
    if (version != CASE_VERSION)
        return fn_err_set(FN_EMISMATCH, "%s: version %ld, this fracnav reads version %d", r->file,
                          version, CASE_VERSION);
    json_t *src = get(r, root, "", "source");
    const char *path = src ? get_str(r, src, "source.", "path") : NULL;
    const char *sha = path ? get_str(r, src, "source.", "sha256") : NULL;
    json_t *lab = sha ? get(r, root, "", "labels") : NULL;
    const char *lsha = lab ? get_str(r, lab, "labels.", "sha256") : NULL;
    if (!lsha)
        return FN_EFORMAT;
    size_t len = path[0] == '/' ? strlen(path) : strlen(c->dir) + 1 + strlen(path);
    if (len < sizeof c->source)
        snprintf(c->source, sizeof c->source, path[0] == '/' ? "%s%s" : "%s/%s",
                 path[0] == '/' ? "" : c->dir, path);
    else {
        snprintf(r->field, sizeof r->field, "source.path");
        return bad(r, "path too long");
    }
    int rc = read_seg(r, root, &c->seg);
    if (rc < 0 || (rc = get_num(r, root, "", "tau_min", &c->tau_min)) < 0 ||
        (rc = get_num(r, root, "", "tau_max", &c->tau_max)) < 0)
        return rc;
    json_t *truth = get(r, root, "", "has_truth");
    if (!truth || !json_is_boolean(truth))
        return truth ? bad(r, "expected true or false") : FN_EFORMAT;
    c->has_truth = json_is_true(truth);
    /* The source must be the very file the case was made from. */
    if ((rc = durable_file_sha256(c->source, c->sha256)) < 0)
        return fn_err_wrap(rc, "%s: source.path", r->file);
    if (strcmp(c->sha256, sha))
        return fn_err_set(FN_EMISMATCH, "source %s has sha256 %.12s..., but %s expects %.12s...: "
                                        "the volume changed since the case was made",
                          c->source, c->sha256, r->file, sha);
    char lpath[4200];
    if ((rc = find_labels(c->dir, r->file, lsha, lpath, sizeof lpath)) < 0)
        return rc;
    if (!(c->ct = volio_read(c->source)))
        return FN_EIO;
    if ((rc = check_geometry(r, src, c->ct, c->source)) < 0)
        return rc;
    if (!(c->labels = volio_read(lpath)))
        return FN_EIO;
    if ((rc = same_grid(c->labels, c->ct, lpath)) < 0)
        return rc;
    if ((rc = case_rebuild(c, 0, 0)) < 0)
        return fn_err_wrap(rc, "%s", lpath);
    snprintf(c->labels_sha256, sizeof c->labels_sha256, "%s", lsha);
    labels_checksum(c->labels, c->labels_sum);
    if ((rc = read_fixed(r, root, c)) < 0)
        return rc;
    if ((rc = read_fragments(r, root, c)) < 0)
        return rc;
    warn_penetrating(r, root);
    return keep_extra(root, c);
}

/* case.json's bytes (a regular file, at most JSON_MAX_BYTES), malloc'd and NUL-terminated. */
static char *read_json_file(const char *path, size_t *len)
{
    int fd = durable_open_regular(path, "(not a case folder?)");
    if (fd < 0)
        return NULL;
    struct stat sb;
    char *buf = NULL;
    if (fstat(fd, &sb) != 0 || sb.st_size > JSON_MAX_BYTES)
        fn_err_set(FN_EFORMAT, "%s: %lld bytes, more than a case.json can hold (%d)", path,
                   (long long)sb.st_size, JSON_MAX_BYTES);
    else if (!(buf = malloc((size_t)sb.st_size + 1)))
        fn_err_set(FN_ENOMEM, "%s: out of memory", path);
    size_t done = 0;
    while (buf && done < (size_t)sb.st_size) {
        ssize_t n = read(fd, buf + done, (size_t)sb.st_size - done);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0) {
            fn_err_set(FN_EIO, "%s: read error: %s", path, n ? strerror(errno) : "file shrank");
            free(buf);
            buf = NULL;
            break;
        }
        done += (size_t)n;
    }
    close(fd);
    if (buf)
        buf[done] = '\0';
    *len = done;
    return buf;
}

planning_case *case_load(const char *dir)
{
    planning_case *c = calloc(1, sizeof *c);
    if (!c) {
        fn_err_set(FN_ENOMEM, "case: out of memory");
        return NULL;
    }
    c->fixed = -1;
    snprintf(c->dir, sizeof c->dir, "%s", dir);
    char jpath[4200];
    join(jpath, sizeof jpath, dir, JSON_FILE);
    size_t len;
    char *text = read_json_file(jpath, &len);
    if (!text) {
        case_free(c);
        return NULL;
    }
    durable_sha256(text, len, c->json_sha256);
    json_error_t je;
    json_t *root = json_loadb(text, len, JSON_REJECT_DUPLICATES, &je);
    free(text);
    if (!root) {
        fn_err_set(FN_EFORMAT, "%s: line %d, column %d: %s", jpath, je.line, je.column, je.text);
        case_free(c);
        return NULL;
    }
    struct reader r = {.file = jpath};
    int rc = json_is_object(root) ? read_case(&r, root, c) : bad(&r, "the top level is not an object");
    json_decref(root);
    if (rc < 0) {
        case_free(c);
        return NULL;
    }
    return c;
}
