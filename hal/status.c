#include "hal/status.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

static _Thread_local char error_detail[1024];

wf_status wf_error(wf_status code, const char *fmt, ...)
{
    /* formatted aside first: a caller may pass wf_error_message() itself as an argument,
     * to wrap the message it had with context */
    char buf[sizeof error_detail];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    memcpy(error_detail, buf, sizeof buf);
    return code;
}

const char *wf_error_message(void) { return error_detail; }

const char *wf_status_name(wf_status code)
{
    switch (code) {
    case WF_OK: return "ok";
    case WF_ERR_NOMEM: return "out of memory";
    case WF_ERR_INPUT: return "bad input";
    case WF_ERR_RANGE: return "value out of range";
    case WF_ERR_IO: return "input/output error";
    case WF_ERR_CORRUPT: return "corrupt stream";
    case WF_ERR_INTERNAL: return "internal error";
    default: return "unknown error";
    }
}
