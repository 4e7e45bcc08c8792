/* Fuzzes the report parser: byte 0 picks a device-table row, then a stream of [length][report]
 * records goes through devparse_report and devparse_merge; the whole input is also tried as each
 * open-controller feature report. Checks the invariants a caller relies on. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "devparse.h"

static void check(const dev_event *ev)
{
    for (int i = 0; i < 6; i++)
        if (!(ev->axis[i] >= -1.0f && ev->axis[i] <= 1.0f))
            abort();
    if (ev->dt_us < 0 || ev->dt_us > DEV_DT_MAX_US || ev->battery > 100)
        abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    size_t nrows;
    const devtab_row *rows = devtab_rows(&nrows);
    devparse_state st;
    devparse_init(&st, size ? &rows[data[0] % nrows] : NULL, size > 1 ? data[1] : 0);
    dev_event acc, ev;
    int have = 0;
    int64_t t = 0;
    for (size_t i = 2; i < size;) {
        size_t len = data[i++];
        if (len > size - i)
            len = size - i;
        t += data[i - 1] * 1000;
        if (devparse_report(&st, data + i, len, t, &ev)) {
            check(&ev);
            if (have)
                devparse_merge(&acc, &ev);
            else
                acc = ev;
            have = 1;
            check(&acc);
        }
        i += len;
    }
    devparse_open_info info;
    devparse_open_settings set;
    int16_t zero[6];
    devparse_open_info_parse(data, size, &info);
    devparse_open_settings_parse(data, size, &set);
    if (devparse_open_zero_parse(data, size, zero) == 0)
        for (int i = 0; i < 6; i++)
            if (zero[i] < -350 || zero[i] > 350)
                abort();
    return 0;
}
