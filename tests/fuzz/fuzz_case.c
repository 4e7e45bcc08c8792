/* Fuzzes the case reader (case_load: case.json through jansson, with its labels). A small case
 * folder is made once under $TMPDIR (removed at exit): a 12x10x8 source volume with two bone
 * blocks, its labels, a case.json. Each input replaces case.json; "@SRC_SHA@" and "@LABELS_SHA@"
 * in it stand for the sha256 of the source and of the labels, so mutations get past the checksum
 * checks to the fields behind them. An input may bring its own labels: the bytes after a line
 * "@@labels@@" become labels.nii (the sha placeholder then names those bytes). Whatever the input,
 * case_load gives NULL with a message that names a file, or a case whose poses are finite unit
 * quaternions, whose fragment ids are distinct and in its labels, and whose grids agree. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "case.h"
#include "durable.h"
#include "err.h"
#include "seg.h"
#include "vol.h"
#include "volio.h"

#define LABELS_MARK "\n@@labels@@\n"

static char dir[4096], src_sha[65], fixture_labels_sha[65];

static void cleanup(void)
{
    static const char *files[] = {"case.json", "source.nii", "labels.nii.gz", "labels.prev.nii.gz"};
    char p[4200];
    for (size_t i = 0; i < sizeof files / sizeof files[0]; i++) {
        snprintf(p, sizeof p, "%s/%s", dir, files[i]);
        unlink(p);
    }
    rmdir(dir);
}

static void path_of(const char *name, char *out, size_t cap)
{
    snprintf(out, cap, "%s/%s", dir, name);
}

static void die(const char *what)
{
    fprintf(stderr, "fuzz_case: %s: %s\n", what, fn_err_msg());
    abort();
}

/* The case folder every input is read in. */
static void init(void)
{
    if (dir[0])
        return;
    const char *tmp = getenv("TMPDIR");
    snprintf(dir, sizeof dir, "%s/fracnav-casefuzz-XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(dir) || setenv("FRACNAV_MAX_BYTES", "67108864", 1) != 0)
        die("temp folder");
    atexit(cleanup);
    vol *ct = vol_new(12, 10, 8), *lab = vol_new(12, 10, 8);
    static const double axes[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    double sp[3] = {1, 1, 2}, org[3] = {-5, 3, 7};
    vol_set_geometry(ct, axes, sp, org);
    vol_set_geometry(lab, axes, sp, org);
    for (int k = 0; k < 8; k++)
        for (int j = 0; j < 10; j++)
            for (int i = 0; i < 12; i++) {
                int id = j > 1 && j < 8 && k > 1 && k < 6 ? (i > 1 && i < 5 ? 1 : i > 6 && i < 10 ? 2 : 0) : 0;
                ct->data[vol_idx(ct, i, j, k)] = id ? 1000 : -1000;
                lab->data[vol_idx(lab, i, j, k)] = (float)id;
            }
    char src[4200], labels[4200];
    path_of("source.nii", src, sizeof src);
    path_of("labels.nii.gz", labels, sizeof labels);
    if (volio_write(ct, src, VOL_I16) < 0 || durable_file_sha256(src, src_sha) < 0)
        die("source");
    seg_params p;
    seg_defaults(&p);
    planning_case *c = case_create(dir, src, ct, lab, &p);
    if (!c || case_save(c) < 0 || durable_file_sha256(labels, fixture_labels_sha) < 0)
        die("fixture case");
    case_free(c);
}

/* text with every "@SRC_SHA@" and "@LABELS_SHA@" replaced, malloc'd and NUL-terminated. */
static char *expand(const uint8_t *text, size_t len, const char *labels_sha, size_t *out_len)
{
    /* a 9-byte "@SRC_SHA@" becomes 64 characters: at most 8 out per byte in, and the NUL */
    char *out = malloc(len * 8 + 1), *o = out;
    if (!out)
        die("out of memory");
    for (size_t i = 0; i < len;) {
        if (len - i >= 9 && !memcmp(text + i, "@SRC_SHA@", 9)) {
            o += sprintf(o, "%s", src_sha);
            i += 9;
        } else if (len - i >= 12 && !memcmp(text + i, "@LABELS_SHA@", 12)) {
            o += sprintf(o, "%s", labels_sha);
            i += 12;
        } else
            *o++ = (char)text[i++];
    }
    *o = '\0';
    *out_len = (size_t)(o - out);
    return out;
}

static void write_file(const char *name, const void *data, size_t len)
{
    char p[4200];
    path_of(name, p, sizeof p);
    FILE *f = fopen(p, "wb");
    if (!f || fwrite(data, 1, len, f) != len || fclose(f) != 0)
        die(name);
}

/* The fixture's labels, unless the input brought its own (written as labels.nii.gz; 1 then). */
static int put_labels(const uint8_t *lab, size_t len, char sha[65])
{
    if (!lab) {
        static vol *fixture;
        char p[4200];
        path_of("labels.nii.gz", p, sizeof p);
        if (!fixture && !(fixture = volio_read(p)))
            die("fixture labels");
        if (durable_file_sha256(p, sha) < 0 || strcmp(sha, fixture_labels_sha)) {
            if (volio_write(fixture, p, VOL_U16) < 0 || durable_file_sha256(p, sha) < 0)
                die("fixture labels");
            memcpy(fixture_labels_sha, sha, 65);
        }
        return 0;
    }
    write_file("labels.nii.gz", lab, len);
    durable_sha256(lab, len, sha);
    return 1;
}

static void check(const planning_case *c)
{
    for (int i = 0; i < c->nfrag; i++) {
        const pose *p = &c->frag[i].pose;
        double n2 = p->q[0] * p->q[0] + p->q[1] * p->q[1] + p->q[2] * p->q[2] + p->q[3] * p->q[3];
        if (!(fabs(n2 - 1) <= 1e-6) || !isfinite(p->t[0] + p->t[1] + p->t[2]))
            abort();
        for (int j = 0; j < i; j++)
            if (c->frag[j].id == c->frag[i].id)
                abort();
    }
    if (c->fixed < -1 || c->fixed >= c->nfrag)
        abort();
    for (int a = 0; a < 3; a++)
        if (c->labels->dim[a] != c->ct->dim[a])
            abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    init();
    const uint8_t *lab = NULL;
    size_t json_len = size, lab_len = 0;
    for (size_t i = 0; i + strlen(LABELS_MARK) <= size; i++)
        if (!memcmp(data + i, LABELS_MARK, strlen(LABELS_MARK))) {
            json_len = i;
            lab = data + i + strlen(LABELS_MARK);
            lab_len = size - i - strlen(LABELS_MARK);
            break;
        }
    char lsha[65];
    put_labels(lab, lab_len, lsha);
    size_t n;
    char *json = expand(data, json_len, lsha, &n);
    write_file("case.json", json, n);
    free(json);
    planning_case *c = case_load(dir);
    if (c)
        check(c);
    else if (!strstr(fn_err_msg(), dir) && !strstr(fn_err_msg(), "labels") &&
             !strstr(fn_err_msg(), "source")) {
        fprintf(stderr, "fuzz_case: the error names no file: %s\n", fn_err_msg());
        abort();
    }
    case_free(c);
    return 0;
}
