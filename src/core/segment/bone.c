#include "bone.h"

#include "err.h"

#include <math.h>
#include <stdlib.h>

bone_kind bone_kind_of(const vol *v)
{
    size_t n = vol_count(v), zero = 0, air = 0;
    for (size_t i = 0; i < n; i++) {
        zero += v->data[i] == 0;
        air += v->data[i] < -200;
    }
    return 2 * zero >= n && 1000 * air < n ? BONE_ONLY_CT : BONE_FULL_CT;
}

int bone_find(const vol *v, double threshold, uint8_t *mask)
{
    size_t n = vol_count(v);
    bone_kind kind = bone_kind_of(v);
    if (kind == BONE_FULL_CT) {
        for (size_t i = 0; i < n; i++)
            mask[i] = isfinite(v->data[i]) && v->data[i] >= threshold;
        return kind;
    }
    int32_t *lab = malloc(n * sizeof *lab);
    if (!lab)
        return fn_err_set(FN_ENOMEM, "bone: out of memory for %zu voxels", n);
    for (size_t i = 0; i < n; i++)
        mask[i] = isfinite(v->data[i]) && v->data[i] != 0;
    int ncomp = seg_components(mask, v->dim, lab);
    uint8_t *cortex = ncomp >= 0 ? calloc((size_t)ncomp + 1, 1) : NULL;
    if (!cortex) {
        free(lab);
        return ncomp < 0 ? ncomp : fn_err_set(FN_ENOMEM, "bone: out of memory");
    }
    for (size_t i = 0; i < n; i++)
        if (lab[i] && v->data[i] >= threshold)
            cortex[lab[i]] = 1;
    for (size_t i = 0; i < n; i++)
        mask[i] = cortex[lab[i]] && lab[i];
    free(cortex);
    free(lab);
    return kind;
}

int bone_segment(const vol *v, const seg_params *p, seg_result *out)
{
    uint8_t *mask = malloc(vol_count(v));
    if (!mask)
        return fn_err_set(FN_ENOMEM, "bone: out of memory for the bone mask");
    int rc = bone_find(v, seg_threshold(v, p), mask);
    seg_params q = *p;
    if (rc == BONE_ONLY_CT)
        q.min_volume_ml = p->min_volume_bone_only_ml;
    if (rc >= 0)
        rc = seg_run_mask(v, mask, &q, out);
    free(mask);
    return rc;
}
