#include "err.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

static _Thread_local char msg[1024];

int fn_err_set(int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    return code;
}

int fn_err_wrap(int code, const char *fmt, ...)
{
    char prefix[256], old[sizeof msg - sizeof prefix - 2];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(prefix, sizeof prefix, fmt, ap);
    va_end(ap);
    memcpy(old, msg, sizeof old - 1);
    old[sizeof old - 1] = '\0';
    snprintf(msg, sizeof msg, "%s: %s", prefix, old);
    return code;
}

const char *fn_err_msg(void)
{
    return msg[0] ? msg : "no error recorded";
}

void fn_err_clear(void)
{
    msg[0] = '\0';
}
