/* Fuzzes the NRRD reader (header scan, teem, geometry) with attached .nrrd files and detached
 * headers. A header may name data files: the private folder holds slice files s0.raw .. s3.raw
 * (16 bytes each), a FIFO `fifo` and a link `out.raw` to /etc/passwd, so that every form (one
 * name, LIST, numbered) reaches both files it may read and files it must refuse; a refusal that
 * fails shows as a hang on the FIFO or a read outside the folder. */
#include <sys/stat.h>

#include "volfuzz.h"

static const char *const fixtures[] = {"s0.raw", "s1.raw", "s2.raw", "s3.raw", "fifo", "out.raw"};
#define NFIXTURES (sizeof fixtures / sizeof fixtures[0])

static void fixture_path(char *p, size_t size, size_t i)
{
    snprintf(p, size, "%s/%s", volfuzz_dir, fixtures[i]);
}

static void fixtures_remove(void)
{
    char p[4200];
    for (size_t i = 0; i < NFIXTURES; i++) {
        fixture_path(p, sizeof p, i);
        unlink(p);
    }
}

static void fixtures_make(void)
{
    static int made;
    if (made++)
        return;
    volfuzz_init();
    char p[4200];
    for (size_t i = 0; i < 4; i++) {
        unsigned char slice[16];
        for (size_t j = 0; j < sizeof slice; j++)
            slice[j] = (unsigned char)(i * 16 + j);
        fixture_path(p, sizeof p, i);
        FILE *f = fopen(p, "wb");
        if (!f || fwrite(slice, 1, sizeof slice, f) != sizeof slice || fclose(f) != 0)
            abort();
    }
    fixture_path(p, sizeof p, 4);
    if (mkfifo(p, 0600) != 0)
        abort();
    fixture_path(p, sizeof p, 5);
    if (symlink("/etc/passwd", p) != 0)
        abort();
    atexit(fixtures_remove); /* before volfuzz_cleanup removes the folder */
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fixtures_make();
    volfuzz_read(data, size, ".nrrd");
    return 0;
}
