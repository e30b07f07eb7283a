/* Status codes and error messages shared by every layer.
 * Every public function that can fail returns a wf_status (WF_OK == 0) and writes its results
 * through out-parameters. The failing function records a human message (naming the file,
 * line, key or rows at fault) in a thread-local buffer; the caller that gives up prints it. */
#ifndef WF_STATUS_H
#define WF_STATUS_H

typedef int wf_status;

enum {
    WF_OK = 0,          /* must be zero */
    WF_ERR_NOMEM = 1,   /* arena or host allocation refused */
    WF_ERR_INPUT = 2,   /* malformed config, catalog, option or argument */
    WF_ERR_RANGE = 3,   /* value outside its allowed range */
    WF_ERR_IO = 4,      /* file or stream could not be read or written */
    WF_ERR_CORRUPT = 5, /* packet stream damaged: CRC, duplicate, missing rows, truncation */
    WF_ERR_INTERNAL = 6 /* a broken invariant: a bug */
};

/* Records the message for this thread and returns code, so that callers write
 * `return wf_error(WF_ERR_INPUT, "%s:%d: unknown key '%s'", file, line, key);` */
wf_status wf_error(wf_status code, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

/* The last message recorded on this thread ("" when none). */
const char *wf_error_message(void);

/* A short name for a code ("out of memory", "bad input", ...). */
const char *wf_status_name(wf_status code);

#endif
