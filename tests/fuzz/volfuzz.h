/* Shared by the volume-reader harnesses (fuzz_nifti.c, fuzz_nrrd.c, fuzz_inv3.c): volio_read takes
 * a path, so each input is written to a file in a private folder under $TMPDIR (made on the first
 * call, removed at exit), read back, checked and removed. The memory budget is lowered to 64 MiB
 * so a header that lies about its size cannot make the fuzzer allocate much; the replay runner
 * calls no LLVMFuzzerInitialize, so this is done on the first input. Every volume read is also
 * given to Otsu's histogram (src/core/segment/seg.c), which reads whatever voxel values a file holds.
 * A NRRD is also read as a labelmap (volio_read_labels: 3D Slicer .seg.nrrd, multi-layer too). */
#ifndef FN_VOLFUZZ_H
#define FN_VOLFUZZ_H

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "err.h"
#include "seg.h"
#include "vol.h"
#include "volio.h"

static char volfuzz_dir[4096];
static volatile float volfuzz_sink;

static void volfuzz_cleanup(void)
{
    rmdir(volfuzz_dir);
}

static void volfuzz_init(void)
{
    if (volfuzz_dir[0])
        return;
    const char *tmp = getenv("TMPDIR");
    snprintf(volfuzz_dir, sizeof volfuzz_dir, "%s/fracnav-volfuzz-XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(volfuzz_dir) || setenv("FRACNAV_MAX_BYTES", "67108864", 1) != 0) {
        perror("volfuzz: temp folder");
        abort();
    }
    atexit(volfuzz_cleanup);
}

/* A volume that was read must be usable: positive dims, data, finite positive spacing and a
 * finite affine. A refusal must leave a message naming the file. */
static void volfuzz_check(const vol *v, const char *path)
{
    if (!v) {
        if (!strstr(fn_err_msg(), path)) {
            fprintf(stderr, "volfuzz: error does not name the file: %s\n", fn_err_msg());
            abort();
        }
        return;
    }
    if (!v->data || v->dim[0] < 1 || v->dim[1] < 1 || v->dim[2] < 1)
        abort();
    for (int r = 0; r < 3; r++) {
        if (!(isfinite(v->spacing[r]) && v->spacing[r] > 0))
            abort();
        for (int c = 0; c < 4; c++)
            if (!isfinite(v->affine[r][c]))
                abort();
    }
    for (size_t i = 0, n = vol_count(v); i < n; i++)
        volfuzz_sink = v->data[i]; /* touch every voxel, so ASan sees a short buffer */
    /* Otsu reads every voxel a file can hold (NaN, +-Inf, +-3e38): its histogram must hold too. */
    double t = seg_otsu(v);
    if (isfinite(t))
        volfuzz_sink = (float)seg_otsu_above(v, t);
}

/* A labelmap volio_read_labels returned: a usable volume of fragment labels (whole numbers
 * 0..65535; 1..segments for a .seg.nrrd) and overlaps between its fragments. */
static void volfuzz_check_labels(const vol *v, const volio_segs *s, const char *path)
{
    volfuzz_check(v, path);
    if (!v)
        return;
    for (size_t i = 0, n = vol_count(v); i < n && s->segments; i++)
        if (!(v->data[i] >= 0 && v->data[i] <= s->segments && v->data[i] == floorf(v->data[i])))
            abort();
    for (int i = 0; i < s->noverlap; i++)
        if (s->overlap[i].fragment < 1 || s->overlap[i].fragment >= s->overlap[i].other ||
            s->overlap[i].other > s->segments || s->overlap[i].voxels == 0)
            abort();
}

/* Writes the input as "in" + ext, reads it with volio_read and checks the result. */
static void volfuzz_read(const uint8_t *data, size_t size, const char *ext)
{
    volfuzz_init();
    char path[4200];
    snprintf(path, sizeof path, "%s/in%s", volfuzz_dir, ext);
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(data, 1, size, f) != size || fclose(f) != 0) {
        perror(path);
        abort();
    }
    fn_err_clear();
    vol *v = volio_read(path);
    volfuzz_check(v, path);
    vol_free(v);
    if (strstr(ext, "nrrd")) {
        volio_segs s;
        fn_err_clear();
        v = volio_read_labels(path, &s);
        volfuzz_check_labels(v, &s, path);
        vol_free(v);
        volio_segs_free(&s);
    }
    unlink(path);
}

#endif
