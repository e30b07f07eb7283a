/* Persistence history: how the firmware learns what earlier exposures of this SCA left in
 * its pixels (SPEC §3.1 step 5). The history is fixed for an exposure: up to
 * WF_PERSIST_DEPTH_MAX earlier exposures ("slots", most recent first), each with the time
 * from its end to this exposure's reset, and per pixel and slot the charge it collected
 * there, as a 16-bit code of WF_PERSIST_UNIT e- (0: below the host's threshold, no release).
 * A code of 2 e- (rounding: +-1 e-) moves the released current by < 2e-4 of itself at the
 * 5000 e- threshold (< 2e-5 above the half well) and keeps a pixel's history to 2 bytes a
 * slot (a 66-row tile of 4088 columns, depth 8: 4.3 MB). */
#ifndef WF_PERSIST_H
#define WF_PERSIST_H

#include <stdint.h>
#include "hal/status.h"

#define WF_PERSIST_DEPTH_MAX 8
#define WF_PERSIST_UNIT 2.0 /* e- per code step */

typedef struct wf_persist_source {
    void *ctx;
    int depth;                          /* slots in use, 0 .. WF_PERSIST_DEPTH_MAX */
    double dt[WF_PERSIST_DEPTH_MAX];    /* s from the end of slot j's exposure to this reset */
    /* Codes of rows [y0, y1): code[((y - y0) * ncols + x) * depth + j]. A row's codes must
     * not depend on the range asked for (neighbouring tiles both ask for halo rows); every
     * readout thread calls it on the same ctx, so it only reads ctx. */
    wf_status (*fill)(void *ctx, int y0, int y1, int ncols, uint16_t *code);
} wf_persist_source;

#endif
