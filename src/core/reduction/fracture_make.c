/* fracture_make: the entry to the fracture models (fracture.c's model 1, fracture_model2.c's
 * model 2), and the fracture saved as a case. */
#include "fracture.h"
#include "fracture_impl.h"

#include "bone.h"
#include "case.h"
#include "err.h"
#include "seg.h"
#include "volio.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

int fracture_make(const vol *ct, const fracture_params *p, fracture_result *out)
{
    fracture_params q = *p;
    if (q.whole_bone && bone_kind_of(ct) == BONE_ONLY_CT)
        q.fill = 0; /* such a CT's outside: a gap that is not bone to segment --whole-bone */
    return q.model == 2 ? fracture_model2(ct, &q, out) : fracture__model1(ct, &q, out);
}

planning_case *fracture_make_case(const vol *ct, const fracture_params *p, const char *dir)
{
    fracture_result r;
    if (fracture_make(ct, p, &r) < 0)
        return NULL;
    char src[4200];
    snprintf(src, sizeof src, "%s/source.nii.gz", dir);
    vol_type t = ct->src_type == VOL_F64 ? VOL_F32 : ct->src_type;
    planning_case *c = NULL;
    if (mkdir(dir, 0755) != 0 && errno != EEXIST)
        fn_err_set(FN_EIO, "%s: cannot create the case folder: %s", dir, strerror(errno));
    else if (volio_write(r.ct, src, t) == 0) {
        seg_params sp;
        seg_defaults(&sp);
        sp.threshold = r.threshold;
        sp.min_volume_ml = 0;
        c = case_create(dir, src, r.ct, r.labels, &sp);
        r.ct = r.labels = NULL;
    }
    if (c) {
        /* Fragment ids are piece numbers; a piece pushed off the grid entirely has no fragment. */
        c->has_truth = 1;
        for (int i = 0; i < c->nfrag; i++)
            c->truth[i] = r.truth[c->frag[i].id - 1];
        c->fixed = case_find(c, 1);
        c->tau_min = p->tau_min;
        c->tau_max = p->tau_max;
        if (case_save(c) < 0) {
            case_free(c);
            c = NULL;
        }
    }
    fracture_result_free(&r);
    return c;
}
