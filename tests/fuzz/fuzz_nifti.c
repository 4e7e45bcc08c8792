/* Fuzzes the NIfTI-1 reader (precheck, nifticlib, data loading). Inputs that start with the gzip
 * magic are named .nii.gz, others .nii, so both of the reader's paths are reached. */
#include "volfuzz.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    int gz = size >= 2 && data[0] == 0x1f && data[1] == 0x8b;
    volfuzz_read(data, size, gz ? ".nii.gz" : ".nii");
    return 0;
}
