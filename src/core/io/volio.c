/* volio: dispatch by file name through the format table. */
#include "volio_impl.h"

#include "err.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

static const volio_format formats[] = {
    {".nii", volio__read_nifti, volio__write_nifti},
    {".nii.gz", volio__read_nifti, volio__write_nifti},
    {".nrrd", volio__read_nrrd, volio__write_nrrd},
    {".nhdr", volio__read_nrrd, volio__write_nrrd},
    {".inv3", volio__read_inv3, NULL},
};
#define NFORMATS (sizeof formats / sizeof formats[0])

static int ends_with(const char *s, const char *suffix)
{
    size_t n = strlen(s), m = strlen(suffix);
    return n >= m && strcasecmp(s + n - m, suffix) == 0;
}

static const volio_format *format_of(const char *path)
{
    for (size_t i = 0; i < NFORMATS; i++)
        if (ends_with(path, formats[i].ext))
            return &formats[i];
    return NULL;
}

/* "A, B, C or LAST" over the extensions that read (or write), for the error messages. */
static const char *extensions(int writable, const char *last, char *buf, size_t size)
{
    const char *ext[NFORMATS + 1];
    size_t k = 0;
    for (size_t i = 0; i < NFORMATS; i++)
        if (!writable || formats[i].write)
            ext[k++] = formats[i].ext;
    if (last)
        ext[k++] = last;
    size_t at = 0;
    buf[0] = 0;
    for (size_t i = 0; i < k && at < size; i++)
        at += (size_t)snprintf(buf + at, size - at, "%s%s", i == 0 ? "" : i + 1 < k ? ", " : " or ",
                               ext[i]);
    return buf;
}

/* 1 for a folder, 0 for a regular file, else a negative FN_E* code with fn_err set. */
static int source_kind(const char *path)
{
    struct stat st;
    if (!path || !*path)
        return fn_err_set(FN_EINVAL, "volio: no file name given");
    if (stat(path, &st) != 0)
        return fn_err_set(FN_EIO, "%s: cannot open: %s", path, strerror(errno));
    if (S_ISDIR(st.st_mode)) {
        /* a case folder handed where a volume is wanted: say so, not "no DICOM series found" */
        char cj[4200];
        struct stat cs;
        snprintf(cj, sizeof cj, "%s/case.json", path);
        if (stat(cj, &cs) == 0 && S_ISREG(cs.st_mode))
            return fn_err_set(FN_EINVAL, "%s: a fracnav case folder (it holds case.json), not a volume or a DICOM "
                              "folder: its CT is the source named in case.json (usually %s/source.nii.gz)", path, path);
        return 1;
    }
    if (!S_ISREG(st.st_mode)) /* a FIFO would block the open, /dev/zero would never end */
        return fn_err_set(FN_EINVAL, "%s: not a regular file (a device, FIFO or socket): give a volume "
                          "file", path);
    return 0;
}

vol *volio_read(const char *path)
{
    int kind = source_kind(path);
    if (kind < 0)
        return NULL;
    if (kind == 1)
        return volio__read_dicom(path);
    const volio_format *f = format_of(path);
    if (f)
        return f->read(path);
    char list[128];
    fn_err_set(FN_EINVAL, "%s: unknown volume format (expected %s)", path,
               extensions(0, "a DICOM folder", list, sizeof list));
    return NULL;
}

vol *volio_read_labels(const char *path, volio_segs *segs)
{
    memset(segs, 0, sizeof *segs);
    const volio_format *f = path && *path ? format_of(path) : NULL;
    if (!f || f->read != volio__read_nrrd || source_kind(path) != 0)
        return volio_read(path); /* which names what is wrong with path, if anything */
    return volio__read_nrrd_labels(path, segs);
}

void volio_segs_free(volio_segs *segs)
{
    if (!segs)
        return;
    free(segs->overlap);
    memset(segs, 0, sizeof *segs);
}

int volio_write(const vol *v, const char *path, vol_type type)
{
    if (!v || !v->data || !path || !*path)
        return fn_err_set(FN_EINVAL, "volio: nothing to write");
    if ((unsigned)type > VOL_F64)
        return fn_err_set(FN_EINVAL, "%s: unknown voxel type %d", path, (int)type);
    double m[3][3];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            m[r][c] = v->affine[r][c];
    int rc = volio__check_axes(m, path, "affine");
    if (rc < 0)
        return rc;
    const volio_format *f = format_of(path);
    if (f && f->write)
        return f->write(v, path, type);
    char list[128];
    return fn_err_set(FN_EINVAL, "%s: cannot write this format (use %s)", path,
                      extensions(1, NULL, list, sizeof list));
}
