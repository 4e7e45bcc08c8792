/* libFuzzer harness for the .fnrec reader: any bytes give either a recording that obeys the
 * format's rules and survives a write/read round trip unchanged, or a clean error. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "fnrec.h"

static void check_round_trip(const fnrec *r)
{
    char *text = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&text, &len);
    if (!f)
        return;
    fnrec_writer *w = fnrec_writer_stream(f, &r->hdr);
    int ok = w != NULL;
    for (size_t i = 0; ok && i < r->n; i++)
        ok = fnrec_writer_event(w, &r->ev[i]) == 0;
    if (w)
        fnrec_writer_close(w);
    fclose(f);
    fnrec *back = NULL;
    /* A header the writer refuses (a name with a control character is fine, none reaches here
     * with a newline) would be a reader bug. */
    if (!ok || fnrec_parse(text, len, "round-trip", &back) != 0)
        abort();
    if (back->n != r->n || (r->n && memcmp(back->ev, r->ev, r->n * sizeof *r->ev)) ||
        back->hdr.desc_len != r->hdr.desc_len || back->hdr.vid != r->hdr.vid ||
        strcmp(back->hdr.name, r->hdr.name) || strcmp(back->hdr.format, r->hdr.format))
        abort();
    fnrec_free(back);
    free(text);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fnrec *r = NULL;
    int rc = fnrec_parse((const char *)data, size, "fuzz", &r);
    if (rc) {
        if (r || !strstr(fn_err_msg(), "fuzz"))
            abort(); /* an error leaves nothing behind and names the input */
        return 0;
    }
    for (size_t i = 0; i < r->n; i++) {
        const fnrec_event *e = &r->ev[i];
        if (e->len > DEV_REPORT_MAX || (i && e->t_us < r->ev[i - 1].t_us) ||
            (e->dir < FNREC_CONNECT) != (e->len > 0))
            abort();
    }
    if (r->torn_line && !r->torn_why[0])
        abort(); /* a left-out last line says why */
    check_round_trip(r);
    fnrec_free(r);
    return 0;
}
