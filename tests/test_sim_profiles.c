/* The simulator's profiles come from the device table: one per hardware row, named by the row's
 * short name (or its name's slug), with the row's USB strings; no second table of ids. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <string.h>

#include "devtab.h"
#include "simdev.h"

/* Every hardware row is a profile, in table order, found by its short name and by vid:pid. */
static void test_one_profile_per_row(void **st)
{
    (void)st;
    size_t n, k = 0;
    const devtab_row *rows = devtab_rows(&n);
    for (size_t i = 0; i < n; i++) {
        if (rows[i].flags & DEVTAB_F_SYNTH)
            continue;
        const sim_profile *p = sim_profile_at(k++);
        assert_non_null(p);
        assert_ptr_equal(p->row, &rows[i]);
        if (rows[i].alias)
            assert_string_equal(p->id, rows[i].alias);
        assert_ptr_equal(sim_profile_find(p->id), p);
        char id[16];
        snprintf(id, sizeof id, "%04x:%04x", rows[i].vid, rows[i].pid);
        assert_ptr_equal(sim_profile_find(id), p);
        for (size_t j = 0; j + 1 < k; j++)
            assert_string_not_equal(sim_profile_at(j)->id, p->id);
    }
    assert_null(sim_profile_at(k));
}

/* The names --as has always taken, and the kernel's name of a device with its own USB strings. */
static void test_short_names_and_usb_strings(void **st)
{
    (void)st;
    const sim_profile *p = sim_profile_find("spacenavigator");
    assert_non_null(p);
    assert_int_equal(p->vid, 0x046d);
    assert_int_equal(p->pid, 0xc626);
    assert_string_equal(p->name, "3Dconnexion SpaceNavigator");
    p = sim_profile_find("spacemouse-wireless");
    assert_int_equal(p->pid, 0xc62e);
    p = sim_profile_find("open-controller");
    assert_int_equal(p->vid, DEVTAB_OPEN_VID);
    assert_string_equal(p->name, "fracnav fracnav open 6-DOF controller");
    p = sim_profile_find("spacemouse-plus-xt-usb"); /* no short name: the slug of its name */
    assert_int_equal(p->pid, 0xc603);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_one_profile_per_row),
        cmocka_unit_test(test_short_names_and_usb_strings),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
