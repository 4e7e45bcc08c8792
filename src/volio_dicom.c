/* volio_dicom: placeholder until this format is built. */
#include "volio.h"

#include "err.h"

vol *volio__read_dicom(const char *dir)
{
    fn_err_set(FN_EINVAL, "%s: DICOM reading is not built yet", dir);
    return NULL;
}
