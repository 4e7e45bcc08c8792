/* udev/70-fracnav.rules covers every device-table row on hidraw and usb, for the seat's user only. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "devtab.h"
#include "testutil.h"

static char *rules(void)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/udev/70-fracnav.rules", tu_src());
    char *text = tu_slurp(path, NULL);
    assert_non_null(text);
    return text;
}

/* The non-comment line that contains needle, or NULL. */
static const char *rule_line(const char *text, const char *needle)
{
    for (const char *p = strstr(text, needle); p; p = strstr(p + 1, needle)) {
        const char *bol = p;
        while (bol > text && bol[-1] != '\n')
            bol--;
        if (*bol != '#')
            return bol;
    }
    return NULL;
}

static void test_every_row_on_both_subsystems(void **s)
{
    char *text = rules();
    size_t n;
    const devtab_row *rows = devtab_rows(&n);
    for (size_t i = 0; i < n; i++) {
        if (rows[i].flags & DEVTAB_F_SYNTH)
            continue;
        char hid[64], usb[128];
        snprintf(hid, sizeof hid, "SUBSYSTEM==\"hidraw\", KERNELS==\"*:%04X:%04X.*\", TAG+=\"uaccess\"", rows[i].vid,
                 rows[i].pid);
        snprintf(usb, sizeof usb, "ATTR{idVendor}==\"%04x\", ATTR{idProduct}==\"%04x\", TAG+=\"uaccess\"", rows[i].vid,
                 rows[i].pid);
        if (!rule_line(text, hid))
            fail_msg("no hidraw rule for %s (%04x:%04x)", rows[i].name, rows[i].vid, rows[i].pid);
        const char *u = rule_line(text, usb);
        if (!u || strncmp(u, "SUBSYSTEM==\"usb\"", 16))
            fail_msg("no usb rule for %s (%04x:%04x)", rows[i].name, rows[i].vid, rows[i].pid);
    }
    free(text);
}

static void test_no_world_access(void **s)
{
    char *text = rules();
    assert_null(rule_line(text, "MODE="));
    assert_null(rule_line(text, "GROUP="));
    free(text);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_every_row_on_both_subsystems),
        cmocka_unit_test(test_no_world_access),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
