/* volio_nrrd: placeholder until this format is built. */
#include "volio.h"

#include "err.h"

vol *volio__read_nrrd(const char *path)
{
    fn_err_set(FN_EINVAL, "%s: NRRD reading is not built yet", path);
    return NULL;
}

int volio__write_nrrd(const vol *v, const char *path, vol_type type)
{
    return fn_err_set(FN_EINVAL, "%s: NRRD writing is not built yet", path);
}
