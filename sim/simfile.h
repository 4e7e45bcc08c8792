/* simfile: reads a whole text file the simulator loads (a recording, a script) into memory, with a
 * size limit, so fnrec_load and script_load share one skeleton and one set of errors. */
#ifndef FN_SIMFILE_H
#define FN_SIMFILE_H

#include <stddef.h>

/* Reads path into *buf (malloc'd, not NUL-terminated; free it) and its length into *len. A file
 * larger than cap bytes is refused: "PATH: larger than TOO_BIG". Returns 0, or FN_EIO (cannot open,
 * read error), FN_ENOMEM, FN_EFORMAT (too large) with fn_err_msg() naming the path; *buf is then
 * NULL. */
int simfile_read(const char *path, size_t cap, const char *too_big, char **buf, size_t *len);

#endif
