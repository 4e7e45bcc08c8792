/* Fuzzes the HID report-descriptor reader: any bytes parse or fail cleanly, and what parses is
 * consistent (lengths within the limit, counts within the arrays). */
#include <stdint.h>
#include <stdlib.h>

#include "hiddesc.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static hiddesc d;
    if (hiddesc_parse(data, size, &d) != 0)
        return 0;
    if (d.n > HIDDESC_REPORTS_MAX)
        abort();
    for (size_t i = 0; i < d.n; i++) {
        const hiddesc_report *r = &d.report[i];
        if (r->len > HIDDESC_REPORT_BYTES_MAX || r->n_usages > HIDDESC_USAGES_MAX || r->logical_min > r->logical_max)
            abort();
        if (hiddesc_find(&d, r->kind, r->id) != r)
            abort();
    }
    hiddesc_axis_max(&d);
    return 0;
}
