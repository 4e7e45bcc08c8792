/* The one file-loading skeleton of the simulator (simfile.h) behind fnrec_load and script_load:
 * whole files read, the size limit, and errors that name the file. */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "fnrec.h"
#include "script.h"
#include "simfile.h"
#include "testutil.h"

/* Files around the size of a chunk and of the limit: read whole, or refused when over the limit. */
static void test_sizes(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("simfile"), path[512];
    snprintf(path, sizeof path, "%s/f", dir);
    const size_t sizes[] = {0, 1, 65535, 65536, 65537, 200000};
    char *data = malloc(200001);
    for (size_t i = 0; i < 200001; i++)
        data[i] = (char)('a' + i % 26);
    for (size_t k = 0; k < sizeof sizes / sizeof *sizes; k++) {
        tu_write_file(path, data, sizes[k]);
        char *buf;
        size_t n;
        assert_int_equal(simfile_read(path, 200000, "the limit", &buf, &n), 0);
        assert_int_equal(n, sizes[k]);
        assert_memory_equal(buf, data, n);
        free(buf);
        assert_int_equal(simfile_read(path, sizes[k] + 1, "the limit", &buf, &n), 0);
        free(buf);
        if (sizes[k]) {
            assert_int_equal(simfile_read(path, sizes[k] - 1, "the limit", &buf, &n), FN_EFORMAT);
            assert_null(buf);
            assert_non_null(strstr(fn_err_msg(), "larger than the limit"));
        }
    }
    free(data);
    tu_rmtree(dir);
    free(dir);
}

/* A missing file: both loaders name it and the cause. */
static void test_missing(void **st)
{
    (void)st;
    char *buf = (char *)1;
    size_t n;
    assert_int_equal(simfile_read("/nonexistent/x.fnrec", 100, "x", &buf, &n), FN_EIO);
    assert_null(buf);
    assert_null(fnrec_load("/nonexistent/x.fnrec"));
    assert_non_null(strstr(fn_err_msg(), "/nonexistent/x.fnrec: cannot open"));
    assert_null(script_load("/nonexistent/x.script"));
    assert_non_null(strstr(fn_err_msg(), "/nonexistent/x.script: cannot open"));
}

/* A script over 1 MiB is refused with the limit named. */
static void test_script_limit(void **st)
{
    (void)st;
    char *dir = tu_tmpdir("simfile"), path[512];
    snprintf(path, sizeof path, "%s/big.script", dir);
    size_t len = (1 << 20) + 1;
    char *text = malloc(len);
    memset(text, '\n', len);
    tu_write_file(path, text, len);
    free(text);
    assert_null(script_load(path));
    assert_non_null(strstr(fn_err_msg(), "larger than 1 MiB"));
    tu_rmtree(dir);
    free(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sizes),
        cmocka_unit_test(test_missing),
        cmocka_unit_test(test_script_limit),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
