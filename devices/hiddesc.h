/* hiddesc: a HID report-descriptor reader. Pure function over bytes: walks the short items,
 * tracks the global/local state and produces one entry per (kind, report ID) with its size and the
 * logical range of its fields. Long items are skipped; push/pop are honoured. */
#ifndef FN_HIDDESC_H
#define FN_HIDDESC_H

#include <stddef.h>
#include <stdint.h>

#define HIDDESC_REPORTS_MAX 64
#define HIDDESC_USAGES_MAX 16
#define HIDDESC_REPORT_BYTES_MAX 64 /* per report, ID byte included */

typedef enum hiddesc_kind { HIDDESC_INPUT = 0, HIDDESC_OUTPUT = 1, HIDDESC_FEATURE = 2 } hiddesc_kind;

typedef struct hiddesc_report {
    hiddesc_kind kind;
    uint8_t id;         /* 0 when the descriptor uses no report IDs */
    uint32_t bits;      /* payload bits (without the ID byte) */
    size_t len;         /* bytes on the wire including the ID byte when id != 0 */
    int32_t logical_min, logical_max; /* widest range over the report's variable fields */
    uint16_t usage_page; /* usage page of the first main item */
    uint32_t usages[HIDDESC_USAGES_MAX]; /* usages (page << 16 | id) of its fields, in order */
    size_t n_usages;
} hiddesc_report;

typedef struct hiddesc {
    hiddesc_report report[HIDDESC_REPORTS_MAX];
    size_t n;
    uint16_t top_usage_page, top_usage; /* of the first application collection */
} hiddesc;

/* Parses desc. Returns 0, or FN_EFORMAT with fn_err_set() naming the byte offset (truncated item,
 * unbalanced collection or pop, too many reports, a report over 64 bytes). */
int hiddesc_parse(const uint8_t *desc, size_t len, hiddesc *out);
/* The entry for kind and id, NULL if absent. */
const hiddesc_report *hiddesc_find(const hiddesc *d, hiddesc_kind kind, uint8_t id);
/* Logical maximum of the motion axes (input report 1), 0 if absent. */
int hiddesc_axis_max(const hiddesc *d);
/* "input", "output", "feature". */
const char *hiddesc_kind_name(hiddesc_kind k);

#endif
