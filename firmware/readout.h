/* The SCA readout: a streaming, fixed-memory pipeline over tiles of rows.
 *
 * Up-the-ramp mode (default): for every tile, for every read, Poisson electrons from the
 * reciprocity-corrected rate and from dark current (and cosmic-ray charge) accumulate as
 * integers; each digitised read is passed through the full well, nonlinearity, IPC, read
 * noise, gain and a 16-bit ADC, and averaged into its resultant (rounded half to even to
 * uint16, as the flight electronics' averaging). The tile's resultants, its saturation map
 * and the truth of cosmic rays starting in it go out as packets.
 *
 * Single-frame mode: GalSim's allDetectorEffects order for one exposure (SPEC §3.1), output
 * in ADU as float32.
 *
 * Every pixel's random numbers are keyed by its absolute position, so the IPC halo rows a
 * tile recomputes are the same numbers its neighbour draws: products do not depend on tile
 * height or on which instance runs a tile. All memory comes from the arena, reserved in
 * wf_readout_create and sized by tile height and MA table only. */
#ifndef WF_READOUT_H
#define WF_READOUT_H

#include <stdint.h>
#include "firmware/detector.h"
#include "firmware/persistence.h"
#include "hal/arena.h"
#include "hal/clock.h"
#include "hal/link.h"
#include "hal/noise.h"
#include "hal/scene.h"

typedef enum { WF_MODE_RAMP = 0, WF_MODE_SINGLE = 1 } wf_mode;

/* Per-read: every read drawn and digitised. Direct: each resultant drawn at once, exact in
 * distribution for a linear pixel (the Poisson electrons of each read interval, weighted by
 * the reads of the group that see them, and the group's mean read noise N(0, sigma^2/n));
 * it skips the per-read nonlinearity, IPC and ADC, so with nonlinearity on it applies it to
 * the group's mean charge (error measured in docs/BENCHMARKS.md), and reads are not
 * quantised one by one. */
/* Moments: each resultant's group mean drawn with the exact mean and covariance of the
 * per-read process (the charge before the group, the group's total increment and its group
 * mean given that total: three draws and the read noise, whatever the group's length), so
 * it is statistically equivalent to per-read sampling to second order and costs one noise
 * block per resultant. Nonlinearity takes the group mean plus its second-order correction
 * from the within-group spread of the charge (firmware/readout.c, "moments"). */
typedef enum { WF_SAMPLE_PER_READ = 0, WF_SAMPLE_DIRECT = 1, WF_SAMPLE_MOMENTS = 2 } wf_sampling;

/* "per-read", "direct" or "moments" (the exposure.sampling choice, the META and the FITS
 * SAMPLING keyword); "unknown" outside the enum. A name, like wf_filter_name: nothing can
 * fail that a status would report. */
const char *wf_sampling_name(wf_sampling s);

typedef struct wf_readout_config {
    int ncols, nrows;    /* active pixels of the SCA [4088, 4088] */
    int tile_rows;       /* rows per tile [64] */
    wf_mode mode;
    wf_sampling sampling;
    double exptime;      /* single-frame mode exposure time, s; ramp mode takes the MA table's */
    uint32_t exposure;   /* exposure id (noise key, packet header) */
    uint32_t sca;        /* 1..18 */
    uint64_t seed;
    int compress;        /* deflate packet payloads */
    int time_variable;   /* up the ramp: follow the scene's fill_slope (hal/scene.h); reserves
                          * two more halo planes. Single frame needs nothing: a linear rate
                          * integrates to its mid-time value times the exposure time. */
    wf_detector det;
    wf_persist_config persist; /* persistence: off unless on and given a history */
    int portable;        /* 1: the portable kernels only, never a hand-written AVX-512 one
                          * (the same bits: tests compare the two) */
} wf_readout_config;

typedef struct wf_readout wf_readout;

/* Bytes of META text at most: its own lines (at most ~16 KiB, with an MA table of 2048
 * separate reads) and the host's extra lines (tools/pipeline.c keeps them to half of it). */
#define WF_READOUT_META_MAX ((size_t)128 * 1024)

/* Arena bytes one instance needs: depends on ncols, tile_rows and the MA table, not nrows. */
wf_status wf_readout_arena_need(const wf_readout_config *cfg, const wf_clock *clock,
                                size_t *bytes);

wf_status wf_readout_create(const wf_readout_config *cfg, const wf_clock *clock,
                            const wf_scene_source *scene, const wf_noise *noise,
                            const wf_link *link, wf_arena *arena, wf_readout **out);

int wf_readout_tile_count(const wf_readout *ro);

/* Simulates tile `tile` (rows [tile*tile_rows, ...)) and sends its packets. */
wf_status wf_readout_run_tile(wf_readout *ro, int tile);

/* The META packet (once per exposure, first): shape, mode, MA table, detector values, then
 * `extra` lines ("hdr.KEY = value / comment" become FITS keywords). */
wf_status wf_readout_send_meta(wf_readout *ro, const char *extra);

/* The END packet (once, last). */
wf_status wf_readout_send_end(wf_readout *ro);

void wf_readout_destroy(wf_readout *ro);

#endif
