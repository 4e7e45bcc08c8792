/* .ci/setup, run against stub apt/dpkg commands: it fetches the example CT even when every package
 * is installed but the package lists are empty (a fresh image), and does nothing when all is there. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include "testutil.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>

/* Each stub logs its call to $STUB_LOG; apt-cache knows the package only after apt-get update. */
static const char *const stubs[][2] = {
    {"dpkg-query", "echo 'install ok installed'\n"},
    {"id", "echo 0\n"},
    {"apt-cache", "echo \"apt-cache $*\" >>\"$STUB_LOG\"\n"
                  "[ -e \"$STUB_STATE/lists\" ] || { echo 'E: No packages found' >&2; exit 100; }\n"
                  "echo 'Package: invesalius-examples'\n"},
    {"apt-get", "echo \"apt-get $*\" >>\"$STUB_LOG\"\n"
                "case \"$*\" in\n"
                "*update*) touch \"$STUB_STATE/lists\" ;;\n"
                "*download*) [ -e \"$STUB_STATE/lists\" ] || { echo 'E: Unable to locate package' >&2; exit 100; }\n"
                "            touch invesalius-examples_3.1_all.deb ;;\n"
                "esac\n"},
    {"dpkg", "echo \"dpkg $*\" >>\"$STUB_LOG\"\n"
             "d=\"$3/usr/share/doc/invesalius-examples/examples\"\n"
             "mkdir -p \"$d\" && echo 'a CT' >\"$d/Cranium.inv3\"\n"},
};

static int run_setup(const char *dir, char **out)
{
    char cmd[8192];
    const char *src = tu_src();
    snprintf(cmd, sizeof cmd,
             "cd '%s' && PATH='%s/bin':/usr/bin:/bin STUB_LOG='%s/log' STUB_STATE='%s' "
             "FRACNAV_DATA='%s/data' sh '%s/.ci/setup' 2>&1",
             dir, dir, dir, dir, dir, src);
    FILE *f = popen(cmd, "r");
    assert_non_null(f);
    static char buf[8192];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    buf[n] = '\0';
    *out = buf;
    int st = pclose(f);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static void test_empty_lists_all_packages_present(void **st)
{
    char *dir = tu_tmpdir("ci-setup"), path[4300];
    snprintf(path, sizeof path, "%s/bin", dir);
    assert_int_equal(mkdir(path, 0755), 0);
    for (size_t i = 0; i < sizeof stubs / sizeof stubs[0]; i++) {
        snprintf(path, sizeof path, "%s/bin/%s", dir, stubs[i][0]);
        char text[1024];
        snprintf(text, sizeof text, "#!/bin/sh\n%s", stubs[i][1]);
        tu_write_file(path, text, strlen(text));
        assert_int_equal(chmod(path, 0755), 0);
    }
    char *out, *log;
    if (run_setup(dir, &out) != 0)
        fail_msg("setup failed: %s", out);
    snprintf(path, sizeof path, "%s/data/Cranium.inv3", dir);
    struct stat sb;
    assert_int_equal(stat(path, &sb), 0);
    snprintf(path, sizeof path, "%s/log", dir);
    log = tu_slurp(path, NULL);
    char *upd = strstr(log, "apt-get update"), *dl = strstr(log, "apt-get download");
    if (!upd || !dl || upd > dl)
        fail_msg("expected apt-get update before the download, got:\n%s", log);
    free(log);

    /* Everything there: no apt call at all. */
    remove(path);
    if (run_setup(dir, &out) != 0 || !strstr(out, "all packages present"))
        fail_msg("second run: %s", out);
    assert_int_not_equal(stat(path, &sb), 0);

    /* Lists present, CT missing: the download needs no update. */
    snprintf(path, sizeof path, "%s/data/Cranium.inv3", dir);
    remove(path);
    if (run_setup(dir, &out) != 0)
        fail_msg("third run: %s", out);
    snprintf(path, sizeof path, "%s/log", dir);
    log = tu_slurp(path, NULL);
    if (strstr(log, "apt-get update") || !strstr(log, "apt-get download"))
        fail_msg("lists present: expected a download and no update, got:\n%s", log);
    free(log);
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_empty_lists_all_packages_present),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
