/* firmware-spec is machine-checked: the open controller's descriptor bytes (the file the spec
 * includes) declare exactly the reports the parser accepts; the HID descriptor reader itself. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <ctype.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "devparse.h"
#include "devtab.h"
#include "err.h"
#include "hiddesc.h"
#include "testutil.h"

/* Hex bytes of text, '#' to end of line ignored. */
static size_t hex_bytes(const char *text, size_t len, uint8_t *out, size_t cap)
{
    size_t n = 0;
    for (size_t i = 0; i < len; i++) {
        if (text[i] == '#') {
            while (i < len && text[i] != '\n')
                i++;
            continue;
        }
        if (isxdigit((unsigned char)text[i])) {
            assert_true(i + 1 < len && isxdigit((unsigned char)text[i + 1]));
            char two[3] = {text[i], text[i + 1], 0};
            assert_true(n < cap);
            out[n++] = (uint8_t)strtoul(two, NULL, 16);
            i++;
        }
    }
    return n;
}

static size_t spec_descriptor(uint8_t *out, size_t cap)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/firmware-spec/open-controller.desc.hex", tu_src());
    size_t len;
    char *text = tu_slurp(path, &len);
    assert_non_null(text);
    size_t n = hex_bytes(text, len, out, cap);
    free(text);
    return n;
}

static void test_open_descriptor_matches_parser(void **s)
{
    uint8_t desc[512];
    size_t n = spec_descriptor(desc, sizeof desc);
    assert_true(n > 50);
    hiddesc d;
    assert_int_equal(hiddesc_parse(desc, n, &d), 0);
    assert_int_equal(d.top_usage_page, 1);
    assert_int_equal(d.top_usage, 8); /* multi-axis controller */
    const devtab_row *row = devtab_find(DEVTAB_OPEN_VID, DEVTAB_OPEN_PID);
    devparse_spec want[16];
    size_t nw = devparse_reports(row, want, 16);
    assert_int_equal(d.n, nw);
    for (size_t i = 0; i < nw; i++) {
        const hiddesc_report *r = hiddesc_find(&d, (hiddesc_kind)want[i].kind, want[i].id);
        if (!r)
            fail_msg("descriptor lacks %s report 0x%02x", hiddesc_kind_name((hiddesc_kind)want[i].kind), want[i].id);
        if (r->len != want[i].len)
            fail_msg("%s report 0x%02x: descriptor says %zu bytes, parser wants %zu",
                     hiddesc_kind_name(r->kind), r->id, r->len, want[i].len);
    }
    assert_int_equal(hiddesc_axis_max(&d), 350);
    const hiddesc_report *m = hiddesc_find(&d, HIDDESC_INPUT, 1);
    assert_int_equal(m->logical_min, -350);
    assert_int_equal(m->n_usages, 6);
    for (int i = 0; i < 6; i++)
        assert_int_equal(m->usages[i], 0x00010030u + (uint32_t)i); /* X Y Z Rx Ry Rz in HID order */
    /* Every input report the descriptor declares is accepted by the parser at that length, and
     * rejected one byte longer. */
    devparse_state st;
    devparse_init(&st, row, hiddesc_axis_max(&d));
    for (size_t i = 0; i < d.n; i++) {
        if (d.report[i].kind != HIDDESC_INPUT)
            continue;
        uint8_t rep[64] = {d.report[i].id};
        dev_event ev;
        assert_int_equal(devparse_report(&st, rep, d.report[i].len, 0, &ev), 1);
        assert_int_equal(devparse_report(&st, rep, d.report[i].len + 1, 0, &ev), d.report[i].id == 3);
    }
}

/* The spec document shows the same bytes as the file. */
static void test_spec_document_lists_the_file(void **s)
{
    uint8_t file[512], doc[512];
    size_t nf = spec_descriptor(file, sizeof file);
    char path[4096];
    snprintf(path, sizeof path, "%s/firmware-spec/open-controller.md", tu_src());
    size_t len;
    char *text = tu_slurp(path, &len);
    assert_non_null(text);
    const char *a = strstr(text, "```hid-descriptor\n");
    assert_non_null(a);
    a += strlen("```hid-descriptor\n");
    const char *b = strstr(a, "```");
    assert_non_null(b);
    size_t nd = hex_bytes(a, (size_t)(b - a), doc, sizeof doc);
    free(text);
    assert_int_equal(nd, nf);
    assert_memory_equal(doc, file, nf);
}

/* A SpaceNavigator-like descriptor (split reports) read with push/pop and a long item. */
static void test_reader_split_descriptor(void **s)
{
    static const uint8_t desc[] = {
        0x05, 0x01, 0x09, 0x08, 0xA1, 0x01,                   /* GD, multi-axis, application */
        0xA1, 0x00, 0x85, 0x01, 0x16, 0xA2, 0xFE, 0x26, 0x5E, 0x01, 0x09, 0x30, 0x09, 0x31, 0x09, 0x32,
        0x75, 0x10, 0x95, 0x03, 0x81, 0x06, 0xC0,             /* ID1: x y z */
        0xA4,                                                 /* push */
        0xA1, 0x00, 0x85, 0x02, 0x09, 0x33, 0x09, 0x34, 0x09, 0x35, 0x75, 0x10, 0x95, 0x03, 0x81, 0x06, 0xC0,
        0xB4,                                                 /* pop (ID back to 1... then set 3) */
        0xFE, 0x02, 0x10, 0xAA, 0xBB,                         /* a long item, skipped */
        0x85, 0x03, 0x05, 0x09, 0x19, 0x01, 0x29, 0x02, 0x15, 0x00, 0x25, 0x01, 0x75, 0x01, 0x95, 0x02,
        0x81, 0x02, 0x95, 0x0E, 0x81, 0x03,                   /* 2 buttons + 14 bits padding */
        0x85, 0x04, 0x05, 0x08, 0x09, 0x4B, 0x95, 0x01, 0x75, 0x01, 0x91, 0x02, 0x95, 0x01, 0x75, 0x07, 0x91, 0x03,
        0xC0};
    hiddesc d;
    assert_int_equal(hiddesc_parse(desc, sizeof desc, &d), 0);
    assert_int_equal(d.n, 4);
    assert_int_equal(hiddesc_find(&d, HIDDESC_INPUT, 1)->len, 7);
    assert_int_equal(hiddesc_find(&d, HIDDESC_INPUT, 2)->len, 7);
    assert_int_equal(hiddesc_find(&d, HIDDESC_INPUT, 2)->logical_max, 350);
    assert_int_equal(hiddesc_find(&d, HIDDESC_INPUT, 3)->len, 3);
    assert_int_equal(hiddesc_find(&d, HIDDESC_INPUT, 3)->usages[1], 0x00090002u);
    assert_int_equal(hiddesc_find(&d, HIDDESC_OUTPUT, 4)->len, 2);
    assert_null(hiddesc_find(&d, HIDDESC_FEATURE, 4));
}

static void test_reader_errors_name_offset(void **s)
{
    hiddesc d;
    static const uint8_t truncated[] = {0x05, 0x01, 0x26, 0x5E};
    assert_int_equal(hiddesc_parse(truncated, sizeof truncated, &d), FN_EFORMAT);
    assert_non_null(strstr(fn_err_msg(), "offset 2"));
    static const uint8_t unclosed[] = {0x05, 0x01, 0x09, 0x08, 0xA1, 0x01};
    assert_int_equal(hiddesc_parse(unclosed, sizeof unclosed, &d), FN_EFORMAT);
    static const uint8_t extra_end[] = {0xC0};
    assert_int_equal(hiddesc_parse(extra_end, sizeof extra_end, &d), FN_EFORMAT);
    assert_non_null(strstr(fn_err_msg(), "offset 0"));
    static const uint8_t pop[] = {0xB4};
    assert_int_equal(hiddesc_parse(pop, sizeof pop, &d), FN_EFORMAT);
    static const uint8_t huge[] = {0x85, 0x01, 0x75, 0x20, 0x96, 0xFF, 0x00, 0x81, 0x02}; /* 255 x 32 bits */
    assert_int_equal(hiddesc_parse(huge, sizeof huge, &d), FN_EFORMAT);
    assert_non_null(strstr(fn_err_msg(), "longer than 64 bytes"));
    static const uint8_t id0[] = {0x85, 0x00};
    assert_int_equal(hiddesc_parse(id0, sizeof id0, &d), FN_EFORMAT);
    assert_int_equal(hiddesc_parse(NULL, 0, &d), 0);
    assert_int_equal(d.n, 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_open_descriptor_matches_parser),
        cmocka_unit_test(test_spec_document_lists_the_file),
        cmocka_unit_test(test_reader_split_descriptor),
        cmocka_unit_test(test_reader_errors_name_offset),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
