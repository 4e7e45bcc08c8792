/* Fuzzes the spnavrc reader: any text parses (bad lines counted, never a crash), the resulting
 * calibration keeps its outputs finite, and what it writes reads back without a bad line. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

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
    return 0;
}
