/* Fuzzes the journal parser: any bytes give an error or a run of valid records that ends at the
 * reported torn offset, and recovering them into poses never reads out of range. */
#include <stdint.h>
#include <stdlib.h>

#include "journal.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    journal_rec *r;
    size_t n;
    long torn;
    if (journal_parse(data, size, "fuzz", &r, &n, &torn) < 0) {
        if (r || n)
            abort();
        return 0;
    }
    size_t end = n ? JOURNAL_HEADER_SIZE + n * JOURNAL_RECORD_SIZE : (size ? JOURNAL_HEADER_SIZE : 0);
    if ((torn < 0 && end != size) || (torn >= 0 && (size_t)torn != end))
        abort();
    pose p[4] = {POSE_IDENTITY, POSE_IDENTITY, POSE_IDENTITY, POSE_IDENTITY};
    journal_final_poses(r, n, 4, p);
    free(r);
    return 0;
}
