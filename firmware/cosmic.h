/* Cosmic rays at L2 (romanisim cr.py model, SPEC §3.2): hits per cm^2 per s, uniform start
 * on the SCA, isotropic direction on the surface, path length from a power law
 * l^slope on [lmin, lmax] um, energy loss from a Moyal law (truncated to [10, 1e4] eV/um,
 * as romanisim's grid), charge = Poisson(dE/dx * 3-D chord in each pixel / eV-per-electron).
 *
 * Hits are generated per fixed band of WF_CR_BAND rows, keyed by band and hit index, so any
 * tile can regenerate exactly the hits that reach it: memory does not grow with the SCA and
 * output does not depend on tile height. */
#ifndef WF_COSMIC_H
#define WF_COSMIC_H

#include <stdint.h>
#include "firmware/detector.h"
#include "hal/arena.h"
#include "hal/noise.h"
#include "hal/packet.h"

#define WF_CR_BAND 64

typedef struct wf_cr_deposit {
    uint32_t pixel; /* index within the tile's halo block */
    uint32_t read;  /* first read that sees it */
    float electrons;
} wf_cr_deposit;

typedef struct wf_cosmic {
    const wf_detector *det;
    wf_noise noise;
    int ncols, nrows;
    double exptime;           /* hits arrive uniformly over [0, exptime] */
    double frame_time;
    int total_reads;
    int max_reach_rows;       /* the longest track in rows, to find bands that reach a tile */
    double len_a, len_b;      /* lmin^(s+1), lmax^(s+1): the track-length law's ends */
    wf_cr_deposit *deposits;  /* sorted by read after wf_cosmic_tile */
    int ndeposits, cap_deposits;
    wf_cosmic_record *truth;  /* hits starting in the tile's own rows */
    int ntruth, cap_truth;
} wf_cosmic;

/* Capacity planning from expectations with a wide margin (> 10 sigma); exceeding it is an
 * error, never a silent drop. *truth_bytes: the largest COSMIC packet payload a tile sends.
 * WF_ERR_RANGE when the expectations (rate x area x exposure time) exceed what an int counts. */
wf_status wf_cosmic_arena_need(const wf_detector *det, int ncols, int tile_rows,
                               double exptime, size_t *bytes, size_t *truth_bytes);
wf_status wf_cosmic_init(wf_cosmic *cr, const wf_detector *det, const wf_noise *noise,
                         int ncols, int nrows, int tile_rows, double exptime, double frame_time,
                         int total_reads, wf_arena *arena);

/* Regenerates every hit that touches rows [h0, h1) (a tile with its halo); deposits hold
 * pixel indices relative to row h0. Truth is kept for hits starting in [own0, own1). */
wf_status wf_cosmic_tile(wf_cosmic *cr, int h0, int h1, int own0, int own1);

/* Expected hits on the whole SCA during the exposure. */
double wf_cosmic_expected_hits(const wf_detector *det, int ncols, int nrows, double exptime);

#endif
