/* One piece of work in a child process of its own, so that a crash of that work (SIGSEGV, the
 * out-of-memory killer's SIGKILL, abort) loses that work alone: the caller learns which signal
 * ended it and goes on. The child is forked, runs the work, sends back its status, message
 * and result through a pipe and _exit()s (no atexit handler, no MPI_Finalize, no stdio flush
 * of the parent's buffers); it never calls MPI (Open MPI tolerates a fork whose child does
 * not). The child holds only the forking thread: the work starts its own threads, and the
 * locks the work takes that another thread of the parent might hold at the fork (stdout,
 * stderr, FFTW's planner lock) are taken by the forking thread around fork(), so the child
 * never inherits one held. The child's oom_score_adj is raised by 500 (Linux), so that the
 * out-of-memory killer takes the work rather than the process waiting for it, and it dies with
 * the thread that forked it (PR_SET_PDEATHSIG), never left running after its parent. */
#ifndef WF_ISOLATE_H
#define WF_ISOLATE_H

#include <stddef.h>

#include "hal/status.h"
#include "tools/surveyrun.h"

/* The work: fills out (plain bytes, no pointers: they cross a process boundary). */
typedef wf_status (*wf_isolate_fn)(void *arg, void *out);

/* Runs fn(arg, out) in a child process. *crashed = 0: fn's status and message, and out as fn
 * left it (when WF_OK); *crashed = 1: the child died before reporting (a signal, or an exit
 * of its own) and the status is WF_ERR_INTERNAL with a message naming what (the work, e.g.
 * "exposure 17 SCA 7") and the signal or exit status; out is then not to be read (a child
 * killed while sending it may have sent part). */
wf_status wf_isolate_run(const char *what, wf_isolate_fn fn, void *arg, void *out, size_t out_size, int *crashed);

/* What the child gives back besides out, of a size known only there: after fn succeeded,
 * *tail (malloc'd, or NULL) of *size bytes. */
typedef wf_status (*wf_isolate_tail_fn)(void *arg, void **tail, size_t *size);

/* wf_isolate_run, and when fn succeeded and tail_fn gave one, the child's tail: *tail
 * (malloc'd, the caller frees it; NULL when none, or when tail_fn failed in the child, or
 * on any failure) of *tail_size bytes. */
wf_status wf_isolate_run_tail(const char *what, wf_isolate_fn fn, wf_isolate_tail_fn tail_fn, void *arg, void *out,
                              size_t out_size, void **tail, size_t *tail_size, int *crashed);

/* wf_survey_make_item in a child process (the MPI ranks make every item so). The item's input
 * digests are computed in this process first, so that the files' digests stay cached here
 * for later items (the child's cache dies with it); the earlier exposures the child drew for
 * the item's persistence history come back through the pipe into this process's cache, so
 * the next item of the SCA draws only the exposure before it.
 * Test hook: WFISIM_TEST_CRASH_ITEM="E:S" (or "E:S:segv", "E:S:abort") makes the child of
 * exposure E SCA S die by SIGKILL (SIGSEGV, SIGABRT) before it makes the item. */
wf_status wf_survey_make_item_isolated(wf_survey_ctx *ctx, size_t i, wf_survey_item_result *res, int *crashed);

#endif
