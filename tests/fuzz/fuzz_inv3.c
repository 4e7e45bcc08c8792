/* Fuzzes the InVesalius reader (tar walk, plist parser, matrix). The input is the .inv3 file as
 * is, not gzip-compressed here: zlib's gzopen reads a file without the gzip magic as plain bytes,
 * so an uncompressed tar reaches the tar and plist parsers directly (the corpus has those), while
 * gzip'd inputs still exercise the damaged-gzip paths. */
#include "volfuzz.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    volfuzz_read(data, size, ".inv3");
    return 0;
}
