/* A parallel loop for the scene's set-up (host side): independent tasks over a few threads.
 * Tasks are handed out in order from a shared counter; `slot` (0 .. threads - 1) names the
 * thread running a task, so that each thread can use scratch of its own. The caller's thread
 * is slot 0. The status returned is the lowest-numbered failing task's, with its message,
 * whatever the timing; with threads <= 1 (or a thread that cannot start) the tasks run on
 * the caller's thread, in order. */
#ifndef WF_PARALLEL_H
#define WF_PARALLEL_H

#include "hal/status.h"

#define WF_PARALLEL_MAX_THREADS 64

typedef wf_status (*wf_parallel_fn)(void *ctx, int task, int slot);

wf_status wf_parallel_for(int ntasks, int threads, wf_parallel_fn fn, void *ctx);

#endif
