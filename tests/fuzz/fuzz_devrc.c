/* Fuzzes the spnavrc reader: any text parses (bad lines counted, never a crash), the resulting
 * calibration keeps its outputs finite, and what it writes reads back without a bad line; and the
 * writer that merges into the user's file: the merged file has no more bad lines than the input
 * and reads back as the same calibration. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "calib.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    calib c, back;
    calib_default(&c);
    char diag[256];
    calib_parse_spnavrc(&c, (const char *)data, size, "fuzz", diag, sizeof diag);
    float in[6] = {1, -1, 0.5f, -0.5f, 0.01f, 0}, out[6];
    calib_apply(&c, in, out);
    for (int i = 0; i < 6; i++)
        if (!isfinite(out[i]))
            abort();
    static char text[16384];
    size_t n = calib_format_spnavrc(&c, text, sizeof text);
    calib_default(&back);
    if (calib_parse_spnavrc(&back, text, n, "written", NULL, 0) != 0)
        abort();
    calib_default(&back);
    int bad = calib_parse_spnavrc(&back, (const char *)data, size, "fuzz", NULL, 0);
    char *merged = NULL;
    size_t m = 0;
    if (calib_merge_spnavrc(&c, (const char *)data, size, &merged, &m))
        return 0; /* out of memory */
    calib_default(&back);
    if (calib_parse_spnavrc(&back, merged, m, "merged", NULL, 0) > bad)
        abort();
    free(merged);
    float again[6];
    calib_apply(&back, in, again);
    for (int i = 0; i < 6; i++)
        if (again[i] != out[i])
            abort();
    return 0;
}
