#include "simfile.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"

#define FIRST_CHUNK (1u << 16)

/* Reads f into a buffer that doubles up to cap; *toolong when more than cap bytes are there. */
static char *read_all(FILE *f, size_t cap, size_t *n, int *toolong)
{
    size_t sz = FIRST_CHUNK < cap ? FIRST_CHUNK : cap;
    char *buf = malloc(sz);
    *n = 0;
    while (buf) {
        *n += fread(buf + *n, 1, sz - *n, f);
        if (*n < sz || sz >= cap)
            break;
        size_t next = sz * 2 < cap ? sz * 2 : cap;
        char *nb = realloc(buf, next);
        if (!nb) {
            free(buf);
            return NULL;
        }
        buf = nb;
        sz = next;
    }
    *toolong = buf && *n == sz && fgetc(f) != EOF;
    return buf;
}

int simfile_read(const char *path, size_t cap, const char *too_big, char **buf, size_t *len)
{
    *buf = NULL;
    *len = 0;
    FILE *f = fopen(path, "rb");
    if (!f)
        return fn_err_set(FN_EIO, "%s: cannot open: %s", path, strerror(errno));
    int toolong = 0;
    char *b = read_all(f, cap, len, &toolong);
    int err = ferror(f);
    fclose(f);
    int rc = !b ? fn_err_set(FN_ENOMEM, "%s: out of memory reading it", path)
             : err ? fn_err_set(FN_EIO, "%s: read error", path)
             : toolong ? fn_err_set(FN_EFORMAT, "%s: larger than %s", path, too_big) : 0;
    if (rc)
        free(b);
    else
        *buf = b;
    return rc;
}
