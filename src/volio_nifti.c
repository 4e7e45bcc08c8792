/* volio_nifti: placeholder until this format is built. */
#include "volio.h"

#include "err.h"

vol *volio__read_nifti(const char *path)
{
    fn_err_set(FN_EINVAL, "%s: NIfTI reading is not built yet", path);
    return NULL;
}

int volio__write_nifti(const vol *v, const char *path, vol_type type)
{
    return fn_err_set(FN_EINVAL, "%s: NIfTI writing is not built yet", path);
}
