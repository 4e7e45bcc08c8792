/* Fuzzes the NRRD reader (header precheck, teem, geometry) with attached .nrrd files only. An
 * input whose header names a data file is skipped: it would make teem read other files of the
 * fuzzing machine (or /dev/zero), which tests the machine, not the reader. */
#include <ctype.h>

#include "volfuzz.h"

/* 1 if a header line (before the first empty line) starts with "data file" or "datafile". */
static int names_data_file(const uint8_t *data, size_t size)
{
    for (size_t i = 0; i < size;) {
        size_t end = i;
        while (end < size && data[end] != '\n')
            end++;
        if (end == i || (end == i + 1 && data[i] == '\r'))
            return 0;
        char key[10];
        size_t n = 0;
        for (size_t j = i; j < end && n < sizeof key - 1; j++)
            if (data[j] != ' ' && data[j] != '\t')
                key[n++] = (char)tolower(data[j]);
        key[n] = '\0';
        if (!strncmp(key, "datafile", 8))
            return 1;
        i = end + 1;
    }
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (!names_data_file(data, size))
        volfuzz_read(data, size, ".nrrd");
    return 0;
}
