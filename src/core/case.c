#include "case.h"

#include "durable.h"
#include "err.h"

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

#define LABEL_MAX 65535

/* ---- fragments ---- */

int case_find(const planning_case *c, int id)
{
    for (int i = 0; i < c->nfrag; i++)
        if (c->frag[i].id == id)
            return i;
    return -1;
}

static int check_labels(const vol *labels)
{
    size_t n = vol_count(labels);
    for (size_t i = 0; i < n; i++) {
        float v = labels->data[i];
        if (!(v >= 0 && v <= LABEL_MAX) || v != floorf(v)) {
            size_t x = i % (size_t)labels->dim[0], rest = i / (size_t)labels->dim[0];
            return fn_err_set(FN_EFORMAT, "labels: voxel (%zu,%zu,%zu) holds %g, not a label 0..%d",
                              x, rest % (size_t)labels->dim[1], rest / (size_t)labels->dim[1],
                              (double)v, LABEL_MAX);
        }
    }
    return 0;
}

/* Bounding boxes of every label 1..LABEL_MAX: lo/hi have LABEL_MAX+1 rows; hi[l][0] < 0 = absent. */
static void label_boxes(const vol *labels, int (*lo)[3], int (*hi)[3])
{
    for (int l = 0; l <= LABEL_MAX; l++)
        for (int a = 0; a < 3; a++) {
            lo[l][a] = INT_MAX;
            hi[l][a] = -1;
        }
    size_t idx = 0;
    for (int k = 0; k < labels->dim[2]; k++)
        for (int j = 0; j < labels->dim[1]; j++)
            for (int i = 0; i < labels->dim[0]; i++, idx++) {
                int l = (int)labels->data[idx];
                if (!l)
                    continue;
                int ijk[3] = {i, j, k};
                for (int a = 0; a < 3; a++) {
                    if (ijk[a] < lo[l][a])
                        lo[l][a] = ijk[a];
                    if (ijk[a] > hi[l][a])
                        hi[l][a] = ijk[a];
                }
            }
}

static void inherit(frag *f, pose *truth, const planning_case *old, int from_id, int keep_looks)
{
    int i = case_find(old, from_id);
    if (i < 0)
        return;
    f->pose = old->frag[i].pose;
    if (keep_looks) {
        memcpy(f->name, old->frag[i].name, sizeof f->name);
        memcpy(f->rgb, old->frag[i].rgb, sizeof f->rgb);
    }
    if (old->has_truth)
        *truth = old->truth[i];
}

int case_rebuild(planning_case *c, int new_id, int parent_id)
{
    int rc = check_labels(c->labels);
    if (rc < 0)
        return rc;
    int(*lo)[3] = malloc((LABEL_MAX + 1) * sizeof *lo);
    int(*hi)[3] = malloc((LABEL_MAX + 1) * sizeof *hi);
    frag *nf = NULL;
    pose *nt = NULL;
    if (!lo || !hi) {
        rc = fn_err_set(FN_ENOMEM, "case: out of memory");
        goto done;
    }
    label_boxes(c->labels, lo, hi);
    int n = 0;
    for (int l = 1; l <= LABEL_MAX; l++)
        n += hi[l][0] >= 0;
    nf = calloc(n ? (size_t)n : 1, sizeof *nf);
    nt = calloc(n ? (size_t)n : 1, sizeof *nt);
    if (!nf || !nt) {
        rc = fn_err_set(FN_ENOMEM, "case: out of memory for %d fragments", n);
        goto done;
    }
    int fixed_id = c->fixed >= 0 && c->fixed < c->nfrag ? c->frag[c->fixed].id : -1, built = 0;
    for (int l = 1; l <= LABEL_MAX && rc == 0; l++) {
        if (hi[l][0] < 0)
            continue;
        rc = frag_from_labels(&nf[built], c->labels, c->ct, l, lo[l], hi[l], c->seg.threshold,
                              c->seg.ramp);
        if (rc < 0)
            break;
        nt[built] = POSE_IDENTITY;
        if (l == new_id)
            inherit(&nf[built], &nt[built], c, parent_id, 0);
        else
            inherit(&nf[built], &nt[built], c, l, 1);
        built++;
    }
    if (rc < 0) {
        for (int i = 0; i < built; i++)
            frag_free(&nf[i]);
        goto done;
    }
    for (int i = 0; i < c->nfrag; i++)
        frag_free(&c->frag[i]);
    free(c->frag);
    free(c->truth);
    c->frag = nf;
    c->truth = nt;
    c->nfrag = n;
    nf = NULL;
    nt = NULL;
    c->fixed = case_find(c, fixed_id);
done:
    free(lo);
    free(hi);
    free(nf);
    free(nt);
    return rc;
}

planning_case *case_create(const char *dir, const char *source, vol *ct, vol *labels, const seg_params *sp)
{
    planning_case *c = calloc(1, sizeof *c);
    if (!c) {
        vol_free(ct);
        vol_free(labels);
        fn_err_set(FN_ENOMEM, "case: out of memory");
        return NULL;
    }
    c->ct = ct;
    c->labels = labels;
    c->fixed = -1;
    c->tau_min = CASE_TAU_MIN;
    c->tau_max = CASE_TAU_MAX;
    c->seg = *sp;
    if (strlen(dir) >= sizeof c->dir || strlen(source) >= sizeof c->source) {
        fn_err_set(FN_EINVAL, "case: folder or source path too long");
        case_free(c);
        return NULL;
    }
    strcpy(c->dir, dir);
    strcpy(c->source, source);
    for (int a = 0; a < 3; a++)
        if (ct->dim[a] != labels->dim[a]) {
            fn_err_set(FN_EINVAL, "case: labels are %dx%dx%d but %s is %dx%dx%d", labels->dim[0],
                       labels->dim[1], labels->dim[2], source, ct->dim[0], ct->dim[1], ct->dim[2]);
            case_free(c);
            return NULL;
        }
    if (durable_file_sha256(source, c->sha256) < 0 || case_rebuild(c, 0, 0) < 0) {
        case_free(c);
        return NULL;
    }
    return c;
}

void case_free(planning_case *c)
{
    if (!c)
        return;
    for (int i = 0; i < c->nfrag; i++)
        frag_free(&c->frag[i]);
    free(c->frag);
    free(c->truth);
    vol_free(c->ct);
    vol_free(c->labels);
    json_decref(c->extra);
    free(c);
}
