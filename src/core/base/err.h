/* err: the project's error convention.
 *
 * Functions return 0 (or a count) on success and a negative FN_E* code on failure; constructors
 * return NULL. Either way they leave a message in a thread-local buffer that names the cause and
 * where it is (file, field, line or offset). fn_err_msg() never returns NULL; the string belongs to
 * the calling thread and stays valid until its next fn_err_set(). */
#ifndef FN_ERR_H
#define FN_ERR_H

enum {
    FN_OK = 0,
    FN_EIO = -1,      /* a file or device could not be read or written */
    FN_EFORMAT = -2,  /* malformed, truncated or lying input */
    FN_ENOMEM = -3,   /* allocation failed or the memory budget would be exceeded */
    FN_EINVAL = -4,   /* a bad option or argument */
    FN_ENODEV = -5,   /* a device is missing or went away */
    FN_EMISMATCH = -6, /* a case does not match its source (version, checksum) */
    FN_EAGAIN = -7     /* busy now (a queue is full, nothing runs yet): try again later */
};

#if defined(__GNUC__)
#define FN_PRINTF(a, b) __attribute__((format(printf, a, b)))
#else
#define FN_PRINTF(a, b)
#endif

/* Sets the message and returns code, so callers can write `return fn_err_set(FN_EIO, ...)`. */
int fn_err_set(int code, const char *fmt, ...) FN_PRINTF(2, 3);
/* Prefixes the current message with "prefix: " (adds context on the way up). Returns code. */
int fn_err_wrap(int code, const char *fmt, ...) FN_PRINTF(2, 3);
const char *fn_err_msg(void);
void fn_err_clear(void);

#endif
