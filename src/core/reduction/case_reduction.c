/* The case's record of an automatic reduction: "reduction" in case.json's other members (c->extra;
 * see planning_case.extra and case_set_reduction). */
#include "case.h"

#include "err.h"
#include "reduce.h"

#include <jansson.h>
#include <stdint.h>
#include <stdlib.h>

static json_t *pose_obj(const pose *p)
{
    json_t *q = json_array(), *t = json_array();
    for (int i = 0; i < 4; i++)
        json_array_append_new(q, json_real(p->q[i]));
    for (int i = 0; i < 3; i++)
        json_array_append_new(t, json_real(p->t[i]));
    return json_pack("{s:o,s:o}", "q", q, "t", t);
}

static json_t *result_obj(const reduce_result *r)
{
    json_t *voi = json_array(), *h = json_array();
    for (int i = 0; i < 6; i++)
        json_array_append_new(voi, json_real(i < 3 ? r->voi.lo[i] : r->voi.hi[i - 3]));
    for (int i = 0; i < r->nhistory; i++)
        json_array_append_new(h, json_real(r->history[i]));
    return json_pack("{s:i,s:o,s:b,s:o,s:o,s:o,s:i,s:i,s:f,s:f,s:f,s:f,s:b,s:o}", "id", r->id, "voi_mm", voi,
                     "prealigned", r->prealigned, "placed", pose_obj(&r->placed), "start", pose_obj(&r->start),
                     "end", pose_obj(&r->end), "iterations", r->iterations, "evaluations", r->evaluations,
                     "seconds", r->seconds, "metric_start", r->metric_start, "metric_end", r->metric_end,
                     "push_mm", r->push_mm, "collides", r->collides, "history", h);
}

int case_set_reduction(planning_case *c, int fixed, const reduce_opts *o, const reduce_result *r, int n)
{
    json_t *extra = c->extra ? c->extra : json_object(), *frs = json_array();
    json_t *rec = json_pack("{s:s,s:s,s:i,s:b,s:f,s:f,s:o}", "method", reduce_method_name(o->method), "counting",
                            o->count == REDUCE_NEAREST ? "nearest" : "trilinear", "fixed", c->frag[fixed].id,
                            "prealign", o->prealign, "tolerance_mm", o->tolerance_mm, "gap_mm", o->gap_mm,
                            "fragments", frs);
    int ok = extra && rec && frs;
    for (int i = 0; i < n && ok; i++) {
        json_t *ro = result_obj(&r[i]);
        ok = ro && json_array_append_new(frs, ro) == 0;
    }
    if (ok)
        ok = json_object_set_new(extra, "reduction", rec) == 0;
    else
        json_decref(rec);
    if (!c->extra)
        c->extra = extra;
    if (!ok)
        return fn_err_set(FN_ENOMEM, "case: out of memory for the reduction record");
    /* the pairs the fitted poses leave inside each other, within the fit's tolerance */
    size_t npairs = (size_t)c->nfrag * (size_t)c->nfrag / 2 + 1;
    uint8_t *fitted = calloc((size_t)c->nfrag + 1, 1);
    case_overlap *pen = malloc(npairs * sizeof *pen);
    int rc = fitted && pen ? 0 : fn_err_set(FN_ENOMEM, "case: out of memory for the reduction record");
    for (int i = 0; i < n && rc == 0; i++) {
        int k = case_find(c, r[i].id);
        if (k >= 0)
            fitted[k] = 1;
    }
    if (rc == 0 && (rc = case_penetrating(c, fitted, pen, (int)npairs)) >= 0)
        rc = case_record_penetrating(c, pen, rc);
    free(fitted);
    free(pen);
    return rc;
}
