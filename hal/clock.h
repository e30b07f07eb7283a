/* Clock and read pattern: when the SCA is read and which reads make which resultant.
 * Read i (0-based) happens at t_i = (i + 1) * frame_time after the reset; charge collected
 * over [0, t_i]. A MultiAccum (MA) table lists, per resultant, the reads averaged into it;
 * reads not listed (skipped) still collect charge but are not digitised. Tables are data:
 * built-in Rev F tables 4, 6, 11 (SPEC §3.2) or any table loaded from a text file. */
#ifndef WF_CLOCK_H
#define WF_CLOCK_H

#include "hal/status.h"

#define WF_MA_MAX_RESULTANTS 64
#define WF_MA_MAX_READS 2048 /* reads an exposure takes, skipped ones included */

typedef struct wf_ma_table {
    char name[64];
    int nresultants;
    int nreads;                                /* reads listed in all resultants */
    int first[WF_MA_MAX_RESULTANTS + 1];       /* resultant r uses read[first[r] .. first[r+1]) */
    int read[WF_MA_MAX_READS];                 /* 0-based read indices, strictly increasing */
} wf_ma_table;

typedef struct wf_clock {
    double frame_time; /* s per full-frame read [3.16247, romanisim] */
    wf_ma_table ma;
} wf_clock;

#define WF_FRAME_TIME_DEFAULT 3.16247
/* Physical bounds (docs/CONFIG.md): a frame read at most 100 s (30x the flight's), an
 * exposure (single frame, or the last read of a ramp) at most a day. */
#define WF_FRAME_TIME_MAX 100.0
#define WF_EXPOSURE_TIME_MAX 86400.0

/* A built-in table: "4", "6", "11" (Rev F, SPEC §3.2). */
wf_status wf_ma_builtin(const char *name, wf_ma_table *out);

/* A table from counts of consecutive reads per resultant, e.g. {1,1,2,6,...}. */
wf_status wf_ma_from_counts(const char *name, const int *counts, int n, wf_ma_table *out);

/* A table from a text file: one resultant per line, read numbers (1-based) separated by
 * spaces or commas, ranges as "a-b"; '#' starts a comment. Errors name file and line. */
wf_status wf_ma_load(const char *path, wf_ma_table *out);

/* "4", "6", "11" or a path. */
wf_status wf_ma_resolve(const char *spec, wf_ma_table *out);

/* Reads taken in all (index of the last read + 1). */
int wf_ma_total_reads(const wf_ma_table *ma);

/* Time of read i, and the mean time of the reads in resultant r (t-bar). */
double wf_clock_read_time(const wf_clock *clock, int read);
double wf_clock_resultant_time(const wf_clock *clock, int r);

/* Exposure time: time of the last read (charge integrates from the reset). */
double wf_clock_exposure_time(const wf_clock *clock);

#endif
