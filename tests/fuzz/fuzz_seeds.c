/* Fuzzes the seed file parser (case_seeds_parse): any text gives an error and no seeds, or seeds
 * with a piece 0..254 and finite world coordinates. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "case.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char *text = malloc(size + 1);
    if (!text)
        return 0;
    memcpy(text, data, size);
    text[size] = '\0';
    case_seed *s;
    int n = case_seeds_parse(text, "fuzz", &s);
    free(text);
    if (n <= 0) {
        if (s)
            abort();
        return 0;
    }
    for (int i = 0; i < n; i++)
        if (s[i].piece < 0 || s[i].piece > 254 || !isfinite(s[i].at[0] + s[i].at[1] + s[i].at[2]))
            abort();
    free(s);
    return 0;
}
