/* Fuzzes the journal parser: any bytes give an error or a run of good records that ends where the
 * reported damage starts; every good record is checked (fragment in range, finite unit pose), so
 * recovering them into poses never reads out of range. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "journal.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    journal_scan s;
    if (journal_parse(data, size, "fuzz", &s) < 0) {
        if (s.recs || s.n)
            abort();
        return 0;
    }
    size_t end = size ? JOURNAL_HEADER_SIZE + s.n * JOURNAL_RECORD_SIZE : 0;
    if ((s.damaged_at < 0 && end != size) || (s.damaged_at >= 0 && (size_t)s.damaged_at != end))
        abort();
    pose p[JOURNAL_MAX_FRAGS];
    for (int i = 0; i < JOURNAL_MAX_FRAGS; i++)
        p[i] = POSE_IDENTITY;
    if (journal_final_poses(s.recs, s.n, s.bind.nfrag, p) < 0)
        abort();
    for (int i = 0; i < s.bind.nfrag; i++) {
        double n2 = p[i].q[0] * p[i].q[0] + p[i].q[1] * p[i].q[1] + p[i].q[2] * p[i].q[2] +
                    p[i].q[3] * p[i].q[3];
        if (!(fabs(n2 - 1) <= 1e-6) || !isfinite(p[i].t[0] + p[i].t[1] + p[i].t[2]))
            abort();
    }
    journal_scan_free(&s);
    return 0;
}
