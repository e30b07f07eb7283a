/* Host driver of one exposure: reserves an arena per readout instance, runs tiles on
 * `threads` threads (instance t starts with the t-th contiguous run of tiles, and one done
 * early takes the back half of the longest run left), sends META first
 * and END last on the shared link, and shows progress on a terminal. Output does not depend on the thread
 * count: tiles are keyed by position, and the assembler places rows by their header. */
#ifndef WF_EXPOSE_H
#define WF_EXPOSE_H

#include <stddef.h>
#include "firmware/readout.h"

typedef struct wf_expose_job {
    wf_readout_config ro;
    wf_clock clock;
    wf_noise noise;
    const wf_scene_source *scenes; /* one per thread (a source need not be thread-safe) */
    int threads;
    int progress;                  /* 1: print rows done, rate, time left on stderr */
    const wf_link *link;
    const char *meta_extra;        /* extra META lines ("hdr.KEY = value / comment") */
    size_t arena_bytes;            /* out: bytes reserved per instance */
    size_t arena_high_water;       /* out: most any instance used */
} wf_expose_job;

wf_status wf_expose_run(wf_expose_job *job);

#endif
