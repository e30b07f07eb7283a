#include "firmware/readout.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "firmware/corrnoise.h"
#include "firmware/cosmic.h"
#include "hal/packet.h"
#include "hal/simd.h"
#include "hal/size.h"


/* Moments sampling's per-resultant constants, fixed by the MA table (see ramp_grouped). */
typedef struct moments_group {
    double abar;   /* E[A | T] / T: the group mean's share of the group's total increment */
    double cvar;   /* Var[A | T] / T */
    double vu;     /* E[S | T] = vu T^2 + bs T: the within-group spread of the charge */
    double bs;
} moments_group;

/* Poisson inversion's 1/k, so the moments draws multiply rather than divide (k < 200) */
#define INV_K_MAX 200
#define MOMENTS_ROWS 8 /* moments_row's scratch rows */

struct wf_readout {
    wf_readout_config cfg;
    wf_clock clock;
    wf_scene_source scene;
    wf_noise noise;
    wf_link link;
    wf_arena *arena;               /* for the META text, reserved and given back */
    int ntiles, halo_cap;          /* rows the halo block can hold: tile_rows + 2 */
    int total_reads;
    int16_t resultant_of_read[WF_MA_MAX_READS]; /* -1: read not digitised */
    float *rate;                   /* halo block, e-/pixel/s from the scene */
    double *mean;                  /* halo block, expected e- per frame time */
    double *charge;                /* halo block, collected e- */
    double *meas;                  /* halo block, measured e- at this read */
    double *expm;                  /* halo block, exp(-mean) for one-frame Poisson inversion */
    float *slope;                  /* halo block, d rate / dt (time_variable only) */
    double *dmean;                 /* halo block, d mean / dt: e- per frame per second */
    int slope_any;                 /* this tile has a nonzero slope */
    double t_mid;                  /* s after the reset: the time the rates are for */
    float *gauss;                  /* tile rows, this read's standard normal for read noise */
    uint32_t *words;               /* [4][ncols]: first Philox block of each pixel's stream */
    int noise_off;                 /* WF_NOISE_OFF: draws are expectations */
    double *row;                   /* one row after IPC */
    double *sum;                   /* tile rows, ADU summed over the resultant's reads */
    uint16_t *res_out;             /* [nres][tile_rows][ncols] */
    uint8_t *slow;                 /* ramp: one row, 1 where poisson_word draws the count */
    uint32_t *thr;                 /* ramp per read: [7][halo block] in the packet buffer
                                      (thresholds_bytes), wf_poisson_inversion_thresholds */
    float *single_out;             /* [tile_rows][ncols] */
    double *recip;                 /* single frame: reciprocity failure of 0 .. RECIP_TABLE-1 e- */
    int recip_ready;               /* recip filled (Poisson counts are whole numbers) */
    wf_poisson_table dark;         /* single frame: dark-current inversion (mean in (0, 10)) */
    int dark_table;                /* dark holds the table */
    double *expect;                /* one row: expected photo-electrons */
    double *dark_e;                /* one row: dark electrons */
    uint32_t *retry_x, *retry_px;  /* one row: columns (and pixel ids) whose PTRS draw goes on */
    double *retry_mean, *retry_k;  /*   their means and draws */
    uint16_t *next_block;          /* one row: where each photon stream stopped (dark >= 10) */
    uint8_t *sat;                  /* [tile_rows][ncols] */
    wf_cosmic cosmic;
    int cosmic_on;
    wf_persist persist;            /* nhit 0 (nothing done) unless a history reaches the tile */
    wf_packer packer;
    /* correlated read noise and reference pixels (NULL / 0 when off: firmware/corrnoise.h) */
    wf_corrnoise *cn;
    double *cn_row;                /* [ncols + 8] one full-frame row's correlated noise, e- */
    double *cn_v;                  /* [ncols] an active row's signal plus it */
    int refpix;                    /* the border is simulated and sent */
    double *side_sum;              /* [tile_rows][8] ADU summed over the resultant's reads */
    uint16_t *side_out;            /* [nres][tile_rows][8] */
    double *zero;                  /* [ncols + 8] no charge (reference pixels), then scratch */
    float *ref_z;                  /* [ncols + 8] reference pixels' read-noise normals */
    uint8_t *ref_sat;              /* [ncols + 8] saturation flags nobody reads */
    /* moments sampling (NULL / unused otherwise) */
    double *spread;                /* halo block: E[S | T] of the group, for the nonlinearity */
    double *mrow;                  /* [MOMENTS_ROWS][ncols]: one row's means, starts and draws */
    float *mz;                     /* [3][ncols]: one row's normals from words 1-3 */
    moments_group mgroup[WF_MA_MAX_RESULTANTS];
    double inv_k[INV_K_MAX + 1];
};

const char *wf_sampling_name(wf_sampling s)
{
    switch (s) {
    case WF_SAMPLE_PER_READ: return "per-read";
    case WF_SAMPLE_DIRECT: return "direct";
    case WF_SAMPLE_MOMENTS: return "moments";
    }
    return "unknown";
}

static int corr_on(const wf_readout_config *cfg)
{
    const wf_detector *d = &cfg->det;
    return d->on.read_1f || d->on.channel_offsets || d->on.refpix;
}

static int nres_of(const wf_readout_config *cfg, const wf_clock *clock)
{
    return cfg->mode == WF_MODE_RAMP ? clock->ma.nresultants : 1;
}

static double exposure_time(const wf_readout_config *cfg, const wf_clock *clock)
{
    return cfg->mode == WF_MODE_RAMP ? wf_clock_exposure_time(clock) : cfg->exptime;
}

/* The packet buffer carries the META text too (uncompressed when the link is not deflated):
 * however small the tile, it holds WF_READOUT_META_MAX bytes. */
static size_t tile_payload_max(const wf_readout_config *cfg, const wf_clock *clock)
{
    size_t px = wf_size_mul((size_t)cfg->tile_rows, (size_t)cfg->ncols);
    size_t res = wf_size_mul3(px, sizeof(uint16_t), (size_t)nres_of(cfg, clock));
    size_t single = wf_size_mul(px, sizeof(float));
    size_t n = res > single ? res : single;
    return n > WF_READOUT_META_MAX ? n : WF_READOUT_META_MAX;
}

/* Up-the-ramp per-read sampling keeps a tile's Poisson thresholds (7 words per pixel of the
 * halo block, wf_poisson_inversion_thresholds) in the packet buffer, idle until the tile is
 * sent: the buffer is made large enough for them, rather than taking them beside it (at MA
 * table 6 the resultant tile is the larger, so they cost nothing). */
static size_t thresholds_bytes(const wf_readout_config *cfg)
{
    if (cfg->mode != WF_MODE_RAMP || cfg->sampling != WF_SAMPLE_PER_READ) return 0;
    return wf_size_mul3(7 * sizeof(uint32_t), (size_t)cfg->tile_rows + 2, (size_t)cfg->ncols);
}

/* Cosmic rays' arena bytes and the largest COSMIC payload a tile sends (0, 0 when off). */
static wf_status cosmic_need(const wf_readout_config *cfg, const wf_clock *clock, size_t *bytes,
                             size_t *truth)
{
    *bytes = *truth = 0;
    if (!cfg->det.on.cosmic_rays || cfg->mode != WF_MODE_RAMP) return WF_OK;
    return wf_cosmic_arena_need(&cfg->det, cfg->ncols, cfg->tile_rows, exposure_time(cfg, clock), bytes,
                                truth);
}

/* The packet buffer's raw capacity: the largest payload of any packet a tile sends (its
 * resultants or single frame, its cosmic-ray truth, the META text), or the thresholds. */
static size_t packet_buffer_raw(const wf_readout_config *cfg, const wf_clock *clock, size_t cosmic_truth)
{
    size_t n = tile_payload_max(cfg, clock), t = thresholds_bytes(cfg);
    if (t > n) n = t;
    if (cfg->det.on.refpix) { /* the REFROWS packet */
        size_t rr = wf_size_mul3((size_t)nres_of(cfg, clock) * 2 * WF_CN_BORDER, (size_t)cfg->ncols + 2 * WF_CN_BORDER,
                                 sizeof(uint16_t));
        if (rr > n) n = rr;
    }
    return cosmic_truth > n ? cosmic_truth : n;
}

static int direct_blocks(const wf_ma_table *ma);

/* Single frame: reciprocity failure is tabulated for the Poisson counts below this (512 KiB
 * of doubles per instance; counts above, only in bright stars, take pow). */
#define RECIP_TABLE 65536

/* Noise blocks per row the mode needs at once: one (per-read, moments), or enough for a
 * whole group (direct). */
static int words_blocks(const wf_readout_config *cfg, const wf_clock *clock)
{
    return cfg->mode == WF_MODE_RAMP && cfg->sampling == WF_SAMPLE_DIRECT ? direct_blocks(&clock->ma) : 1;
}

/* ro->words: the blocks, and a few words more for per-read sampling's pairs (row_noise_pairs) */
static size_t words_count(const wf_readout_config *cfg, const wf_clock *clock)
{
    return 4 * (size_t)words_blocks(cfg, clock) * (size_t)cfg->ncols + 4;
}

static wf_status check_config(const wf_readout_config *cfg, const wf_clock *clock)
{
    if (cfg->ncols < 1 || cfg->nrows < 1 || cfg->ncols > 65536 || cfg->nrows > 65536)
        return wf_error(WF_ERR_RANGE, "readout: SCA of %d x %d pixels", cfg->ncols, cfg->nrows);
    if (cfg->tile_rows < 1)
        return wf_error(WF_ERR_RANGE, "readout: tile_rows %d < 1", cfg->tile_rows);
    if (cfg->mode == WF_MODE_RAMP && clock->ma.nresultants < 1)
        return wf_error(WF_ERR_INPUT, "readout: MA table has no resultants");
    if (cfg->mode == WF_MODE_RAMP && (clock->ma.nresultants > WF_MA_MAX_RESULTANTS ||
                                      wf_ma_total_reads(&clock->ma) > WF_MA_MAX_READS))
        return wf_error(WF_ERR_RANGE, "readout: MA table %s has %d resultants over %d reads (at most %d over %d)",
                        clock->ma.name, clock->ma.nresultants, wf_ma_total_reads(&clock->ma),
                        WF_MA_MAX_RESULTANTS, WF_MA_MAX_READS);
    if (!(clock->frame_time > 0.0 && clock->frame_time <= WF_FRAME_TIME_MAX))
        return wf_error(WF_ERR_RANGE, "readout: frame time %g s is outside (0, %g] s", clock->frame_time,
                        WF_FRAME_TIME_MAX);
    double t = exposure_time(cfg, clock);
    if (!(t > 0.0 && t <= WF_EXPOSURE_TIME_MAX))
        return wf_error(WF_ERR_RANGE, "readout: exposure time %g s is outside (0, %g] s", t,
                        WF_EXPOSURE_TIME_MAX);
    if (cfg->sampling != WF_SAMPLE_PER_READ && cfg->sampling != WF_SAMPLE_DIRECT &&
        cfg->sampling != WF_SAMPLE_MOMENTS)
        return wf_error(WF_ERR_RANGE, "readout: sampling %d is none of per-read, direct, moments", (int)cfg->sampling);
    if (!(cfg->det.gain > 0.0))
        return wf_error(WF_ERR_RANGE, "readout: gain %g e-/ADU must be > 0", cfg->det.gain);
    if (corr_on(cfg) && cfg->mode != WF_MODE_RAMP)
        return wf_error(WF_ERR_INPUT, "readout: detector.effects read_1f, channel_offsets and refpix "
                        "need exposure.mode ramp (single-frame mode is GalSim's chain)");
    return WF_OK;
}

/* The single-frame mode's own buffers: the reciprocity table and rows of scratch. */
static size_t single_arena_need(const wf_readout_config *cfg)
{
    size_t nc = (size_t)cfg->ncols;
    size_t n = 4 * wf_arena_cost(nc * sizeof(double)) + 2 * wf_arena_cost(nc * sizeof(uint32_t)) +
               wf_arena_cost(nc * sizeof(uint16_t));
    if (cfg->det.on.reciprocity) n += wf_arena_cost(RECIP_TABLE * sizeof(double));
    return n;
}

wf_status wf_readout_arena_need(const wf_readout_config *cfg, const wf_clock *clock,
                                size_t *bytes)
{
    wf_status st = check_config(cfg, clock);
    if (st) return st;
    size_t cr, cr_truth;
    if ((st = cosmic_need(cfg, clock, &cr, &cr_truth))) return st;
    size_t nc = (size_t)cfg->ncols;
    size_t halo = wf_size_mul((size_t)cfg->tile_rows + 2, nc);
    size_t tile = wf_size_mul((size_t)cfg->tile_rows, nc);
#define ADD(b) n = wf_size_add(n, wf_arena_cost(b))
    size_t n = 0;
    ADD(sizeof(wf_readout));
    ADD(wf_size_mul(halo, sizeof(float)));
    for (int i = 0; i < (cfg->mode == WF_MODE_RAMP ? 4 : 2); i++) ADD(wf_size_mul(halo, sizeof(double)));
    if (cfg->mode == WF_MODE_RAMP && cfg->time_variable) {
        ADD(wf_size_mul(halo, sizeof(float)));
        ADD(wf_size_mul(halo, sizeof(double)));
    }
    if (cfg->mode == WF_MODE_RAMP && cfg->sampling == WF_SAMPLE_MOMENTS) {
        ADD(wf_size_mul(halo, sizeof(double)));
        ADD(wf_size_mul3(MOMENTS_ROWS, nc, sizeof(double)));
        ADD(wf_size_mul3(3, nc, sizeof(float)));
    }
    ADD(wf_size_mul(tile, sizeof(float)));
    ADD(wf_size_mul(words_count(cfg, clock), sizeof(uint32_t)));
    ADD(wf_size_mul(nc, sizeof(double)));
    ADD(wf_size_mul(tile, sizeof(double)));
    if (cfg->mode == WF_MODE_RAMP) {
        ADD(wf_size_mul3(tile, sizeof(uint16_t), (size_t)clock->ma.nresultants));
        ADD(nc);
    } else {
        ADD(wf_size_mul(tile, sizeof(float)));
        n = wf_size_add(n, single_arena_need(cfg));
    }
    ADD(tile);
    if (corr_on(cfg)) {
        size_t w = nc + 2 * WF_CN_BORDER;
        ADD(sizeof(wf_corrnoise));
        n = wf_size_add(n, wf_corrnoise_arena_need(cfg->ncols));
        ADD(w * sizeof(double));
        ADD(nc * sizeof(double));
        ADD(w * sizeof(double));
        ADD(w * sizeof(float));
        ADD(w);
        if (cfg->det.on.refpix) {
            ADD(wf_size_mul((size_t)cfg->tile_rows, 2 * WF_CN_BORDER * sizeof(double)));
            ADD(wf_size_mul3((size_t)cfg->tile_rows, 2 * WF_CN_BORDER * sizeof(uint16_t), (size_t)nres_of(cfg, clock)));
            /* reference rows, taken while they are sent (send_refrows) */
            ADD(wf_size_mul(2 * WF_CN_BORDER * sizeof(double), w));
            ADD(wf_size_mul3((size_t)nres_of(cfg, clock) * 2 * WF_CN_BORDER, w, sizeof(uint16_t)));
        }
    }
    n = wf_size_add(n, wf_packer_arena_need(packet_buffer_raw(cfg, clock, cr_truth), cfg->compress));
    n = wf_size_add(n, cr);
    n = wf_size_add(n, wf_persist_arena_need(&cfg->persist, cfg->ncols, cfg->tile_rows));
    ADD(WF_READOUT_META_MAX); /* wf_readout_send_meta's text, released after it is sent */
#undef ADD
    n = wf_size_add(n, 4096); /* alignment of the block itself */
    if (n == WF_SIZE_OVERFLOW)
        return wf_error(WF_ERR_RANGE, "readout: the buffers of a %d x %d tile do not fit the address space",
                        cfg->ncols, cfg->tile_rows);
    *bytes = n;
    return WF_OK;
}

#define TAKE(ptr, count, what)                                                        \
    do {                                                                              \
        void *p_;                                                                     \
        st = wf_arena_calloc(arena, (size_t)(count), sizeof *(ptr), what, &p_);       \
        if (st) return st;                                                            \
        (ptr) = p_;                                                                   \
    } while (0)

/* Single-frame buffers (single_arena_need) and the tables fixed for the exposure. */
static wf_status single_init(wf_readout *ro, wf_arena *arena)
{
    const wf_readout_config *cfg = &ro->cfg;
    const wf_detector *d = &cfg->det;
    size_t nc = (size_t)cfg->ncols;
    wf_status st;
    TAKE(ro->expect, nc, "expected photo-electrons row");
    TAKE(ro->dark_e, nc, "dark electrons row");
    TAKE(ro->retry_mean, nc, "PTRS retry means");
    TAKE(ro->retry_k, nc, "PTRS retry draws");
    TAKE(ro->retry_x, nc, "PTRS retry columns");
    TAKE(ro->retry_px, nc, "PTRS retry pixels");
    TAKE(ro->next_block, nc, "photon stream positions");
    int photons = d->on.photon_noise && !ro->noise_off;
    if (d->on.reciprocity) {
        TAKE(ro->recip, RECIP_TABLE, "reciprocity table");
        /* exactly the values wf_det_reciprocity gives the whole counts it will be asked for */
        if (photons) {
            for (int k = 0; k < RECIP_TABLE; k++)
                ro->recip[k] = wf_det_reciprocity((double)k, cfg->exptime, d->recip_alpha, d->recip_f0);
            ro->recip_ready = 1;
        }
    }
    double dark = d->dark_current * cfg->exptime;
    ro->dark_table = photons && d->on.dark && dark > 0.0 && dark < 10.0;
    if (ro->dark_table && (st = wf_poisson_table_init(&ro->dark, dark))) return st;
    return WF_OK;
}

/* Moments sampling's constants, once per exposure (the derivation is at ramp_grouped).
 * Group r's reads sit at u_i = (t_i - t_0) / (t_(n-1) - t_0) of its span in frames, the
 * n - 1 intervals between them at fractions p_j = u_j - u_(j-1), interval j seen by the
 * n - j reads from j on (weight w_j = (n - j) / n). */
static void moments_init(wf_readout *ro)
{
    const wf_ma_table *ma = &ro->clock.ma;
    for (int k = 1; k <= INV_K_MAX; k++) ro->inv_k[k] = 1.0 / k;
    for (int r = 0; r < ma->nresultants; r++) {
        const int *reads = ma->read + ma->first[r];
        const int n = ma->first[r + 1] - ma->first[r];
        moments_group *g = &ro->mgroup[r];
        memset(g, 0, sizeof *g);
        const double span = reads[n - 1] - reads[0];
        if (n < 2 || !(span > 0.0)) continue; /* one read: no increment within the group */
        double s1 = 0.0, s2 = 0.0;
        for (int j = 1; j < n; j++) {
            double p = (reads[j] - reads[j - 1]) / span, w = (double)(n - j) / n;
            s1 += w * p;
            s2 += w * w * p;
        }
        g->abar = s1;
        g->cvar = s2 - s1 * s1;
        double ubar = 0.0, uu = 0.0, c = 0.0, cross = 0.0;
        for (int i = 0; i < n; i++) {
            double u = (reads[i] - reads[0]) / span;
            ubar += u;
            uu += u * u;
            c += u * (1.0 - u);
            for (int k = 0; k < n; k++) {
                double v = (reads[k] - reads[0]) / span;
                cross += (u < v ? u : v) * (1.0 - (u < v ? v : u));
            }
        }
        ubar /= n;
        g->vu = uu / n - ubar * ubar;
        g->bs = c / n - cross / ((double)n * n);
    }
}

wf_status wf_readout_create(const wf_readout_config *cfg, const wf_clock *clock,
                            const wf_scene_source *scene, const wf_noise *noise,
                            const wf_link *link, wf_arena *arena, wf_readout **out)
{
    *out = NULL;
    wf_status st = check_config(cfg, clock);
    if (st) return st;
    wf_readout *ro;
    TAKE(ro, 1, "readout state");
    ro->cfg = *cfg;
    ro->clock = *clock;
    ro->scene = *scene;
    ro->noise = *noise;
    ro->link = *link;
    ro->arena = arena;
    ro->ntiles = (cfg->nrows + cfg->tile_rows - 1) / cfg->tile_rows;
    ro->halo_cap = cfg->tile_rows + 2;
    size_t halo = (size_t)ro->halo_cap * (size_t)cfg->ncols;
    size_t tile = (size_t)cfg->tile_rows * (size_t)cfg->ncols;
    TAKE(ro->rate, halo, "rate rows");
    if (cfg->mode == WF_MODE_RAMP) {
        TAKE(ro->mean, halo, "expected electrons");
        TAKE(ro->expm, halo, "Poisson inversion start");
        if (cfg->time_variable) {
            TAKE(ro->slope, halo, "rate slopes");
            TAKE(ro->dmean, halo, "expected-electron slopes");
        }
        ro->t_mid = 0.5 * wf_clock_exposure_time(clock);
        if (cfg->sampling == WF_SAMPLE_MOMENTS) {
            TAKE(ro->spread, halo, "within-group spread");
            TAKE(ro->mrow, MOMENTS_ROWS * (size_t)cfg->ncols, "moments rows");
            TAKE(ro->mz, 3 * (size_t)cfg->ncols, "moments normals");
            moments_init(ro);
        }
    }
    TAKE(ro->charge, halo, "collected charge");
    TAKE(ro->meas, halo, "measured charge");
    TAKE(ro->gauss, tile, "read-noise normals");
    TAKE(ro->words, words_count(cfg, clock), "noise words");
    ro->noise_off = noise->kind == WF_NOISE_OFF;
    TAKE(ro->row, cfg->ncols, "IPC row");
    TAKE(ro->sum, tile, "resultant sums");
    if (cfg->mode == WF_MODE_RAMP) {
        TAKE(ro->res_out, tile * (size_t)clock->ma.nresultants, "resultant tile");
        TAKE(ro->slow, cfg->ncols, "Poisson slow-draw flags");
        ro->total_reads = wf_ma_total_reads(&clock->ma);
        for (int i = 0; i < WF_MA_MAX_READS; i++) ro->resultant_of_read[i] = -1;
        for (int r = 0; r < clock->ma.nresultants; r++)
            for (int j = clock->ma.first[r]; j < clock->ma.first[r + 1]; j++)
                ro->resultant_of_read[clock->ma.read[j]] = (int16_t)r;
    } else {
        TAKE(ro->single_out, tile, "single-frame tile");
        if ((st = single_init(ro, arena))) return st;
    }
    TAKE(ro->sat, tile, "saturation map");
    size_t cr, cr_truth;
    if ((st = cosmic_need(cfg, clock, &cr, &cr_truth))) return st;
    st = wf_packer_init(&ro->packer, arena, packet_buffer_raw(cfg, clock, cr_truth), cfg->compress);
    if (st) return st;
    ro->cosmic_on = cfg->det.on.cosmic_rays && cfg->mode == WF_MODE_RAMP && cfg->det.cr_rate > 0;
    if (ro->cosmic_on) {
        st = wf_cosmic_init(&ro->cosmic, &ro->cfg.det, noise, cfg->ncols, cfg->nrows,
                            cfg->tile_rows, exposure_time(cfg, clock), clock->frame_time,
                            ro->total_reads, arena);
        if (st) return st;
    }
    if (corr_on(cfg)) {
        size_t w = (size_t)cfg->ncols + 2 * WF_CN_BORDER;
        TAKE(ro->cn, 1, "correlated noise");
        if ((st = wf_corrnoise_init(ro->cn, &cfg->det, noise, cfg->ncols, cfg->nrows, arena))) return st;
        TAKE(ro->cn_row, w, "correlated-noise row");
        TAKE(ro->cn_v, cfg->ncols, "signal and correlated-noise row");
        TAKE(ro->zero, w, "reference pixels' charge");
        TAKE(ro->ref_z, w, "reference pixels' normals");
        TAKE(ro->ref_sat, w, "reference pixels' saturation");
        ro->refpix = cfg->det.on.refpix;
        if (ro->refpix) {
            TAKE(ro->side_sum, (size_t)cfg->tile_rows * 2 * WF_CN_BORDER, "side reference sums");
            TAKE(ro->side_out, (size_t)cfg->tile_rows * 2 * WF_CN_BORDER * (size_t)nres_of(cfg, clock),
                 "side reference resultants");
        }
    }
    st = wf_persist_init(&ro->persist, &cfg->persist, noise, cfg->det.on.photon_noise && !ro->noise_off,
                         cfg->mode == WF_MODE_SINGLE, cfg->ncols, cfg->tile_rows, arena);
    if (st) return st;
    *out = ro;
    return WF_OK;
}

int wf_readout_tile_count(const wf_readout *ro) { return ro->ntiles; }

void wf_readout_destroy(wf_readout *ro)
{
    if (ro) wf_packer_close(&ro->packer);
}

static wf_status send_cols(wf_readout *ro, wf_packet_kind kind, int y0, int rows, int ncols, int nplanes,
                           const void *payload, size_t len)
{
    wf_packet_header h = {0};
    h.kind = (uint16_t)kind;
    h.exposure = ro->cfg.exposure;
    h.sca = (uint16_t)ro->cfg.sca;
    h.first_row = (uint32_t)y0;
    h.row_count = (uint32_t)rows;
    h.ncols = (uint32_t)ncols;
    h.nplanes = (uint32_t)nplanes;
    return wf_packer_send(&ro->packer, &ro->link, &h, payload, len);
}

static wf_status send(wf_readout *ro, wf_packet_kind kind, int y0, int rows, int nplanes,
                      const void *payload, size_t len)
{
    return send_cols(ro, kind, y0, rows, ro->cfg.ncols, nplanes, payload, len);
}

/* ---- shared per-pixel steps ------------------------------------------------------------ */

/* Expected electrons per frame time from the scene rate: reciprocity failure acts on the
 * rate (q = r t obeys the same law at every t), dark current is added after it. */
static void expected_per_frame(wf_readout *ro, int npix)
{
    const wf_detector *d = &ro->cfg.det;
    double ft = ro->clock.frame_time;
    wf_det_expected_row(d, ro->rate, npix, ft, ro->mean, ro->expm);
    if (!ro->slope_any) return;
    for (int i = 0; i < npix; i++) {
        /* reciprocity failure scales a source by f(r)/r at its mid-time rate; the slope rides
         * with the same factor */
        double r = ro->rate[i] > 0.0f ? ro->rate[i] : 0.0, g = ro->slope[i];
        if (d->on.reciprocity && r > 0.0) g *= wf_det_reciprocity_rate(r, d->recip_alpha, d->recip_f0) / r;
        ro->dmean[i] = g * ft;
    }
}

/* Expected electrons of a pixel over `frames` frame times centred tau seconds from the
 * mid-time: the mean rate over the interval times its length, for a rate linear in time
 * (never below zero: a source cannot give negative light). */
static inline double interval_mean(const wf_readout *ro, size_t i, double frames, double tau)
{
    double m = ro->mean[i];
    if (ro->slope_any) m += ro->dmean[i] * tau;
    return m > 0.0 ? m * frames : 0.0;
}

/* Each (pixel, read) has one stream. Its first block, computed a row at a time by
 * wf_noise_block_row, serves the common case: word 0 is the read-noise normal, words 1-3
 * the uniforms of Poisson draws by inversion. Draws that need more (PTRS above a mean of
 * 10) continue the same stream after the blocks the batch took, created on first use
 * (per-read sampling takes its two words from a block of two pixels, row_noise_pairs, and
 * continues at block 1 of the pixel's own stream all the same). */
typedef struct more_noise {
    wf_rng rng;
    int ready;
    const wf_noise *noise;
    uint32_t pixel, read;
    wf_purpose purpose;
    uint32_t first_block; /* the blocks before it were taken by the row batch */
} more_noise;

static inline wf_rng *more(more_noise *m)
{
    if (!m->ready) {
        wf_rng_init(&m->rng, m->noise, m->pixel, m->read, m->purpose);
        wf_rng_seek(&m->rng, m->first_block ? m->first_block : 1);
        m->ready = 1;
    }
    return &m->rng;
}

/* w feeds inversion below a mean of 10; above, w and *w2 feed the first PTRS attempt when
 * the caller has a second unused word (w2 != NULL), else the stream does it all. */
static inline double poisson_word(uint32_t w, const uint32_t *w2, double mean, double expm,
                                  more_noise *mn)
{
    if (!(mean > 0.0)) return 0.0;
    if (mean >= 10.0) {
        double k;
        if (w2 && wf_poisson_ptrs_try(mean, w, *w2, &k)) return k;
        return wf_rng_poisson(more(mn), mean);
    }
    double u = ((double)w + 0.5) * (1.0 / 4294967296.0);
    /* k = 0, 1, 2 without a division or an unpredictable branch: most sky pixels stop here */
    double p1 = expm * mean, p2 = p1 * mean * 0.5;
    double f0 = expm, f1 = f0 + p1, f2 = f1 + p2;
    if (u <= f2) return (double)((u > f0) + (u > f1));
    double p = p2, cdf = f2, k = 2.0;
    while (u > cdf && k < 200.0) { /* stop where the terms no longer move the sum */
        k += 1.0;
        p *= mean / k;
        double next = cdf + p;
        if (next == cdf) break;
        cdf = next;
    }
    return k;
}

/* Row loops in SIMD lanes (the callers are not cloned themselves). */
WF_CLONES static void clamp_row(int n, double *restrict c, double top)
{
    for (int x = 0; x < n; x++) c[x] = c[x] > top ? top : c[x];
}

/* Moments: a group's nonlinearity spread, beta x E[S | T], added where the pixel is not at
 * the full well (sat: the full well is on). */
WF_CLONES static void spread_row(int n, double *restrict meas, const double *restrict spread,
                                 const double *restrict charge, double beta, double fw, int sat)
{
    for (int x = 0; x < n; x++) meas[x] = sat && charge[x] >= fw ? meas[x] : meas[x] + beta * spread[x];
}

/* Moments: a row's lead and group means, for pixels of constant rate. */
WF_CLONES static void moments_means(int n, const double *restrict m, double lead, double span, double *restrict lm,
                                    double *restrict mu)
{
    for (int x = 0; x < n; x++) {
        lm[x] = m[x] * lead;
        mu[x] = m[x] * span;
    }
}

/* Columns of a[0 .. n) at or above v. */
WF_CLONES static int count_at_least(int n, const double *restrict a, double v)
{
    int c = 0;
    for (int x = 0; x < n; x++) c += a[x] >= v;
    return c;
}

/* The first column at or after x whose flag is set (n when none): the few a row's batch
 * left to draw, found eight flags at a time. */
static int next_flag(const uint8_t *flag, int x, int n)
{
    for (; x + 8 <= n; x += 8) {
        uint64_t v;
        memcpy(&v, flag + x, sizeof v);
        if (v) break;
    }
    for (; x < n && !flag[x]; x++) {
    }
    return x;
}

/* The counts of a row whose thresholds are thr[j][x] (stride apart) and slow[x], from the
 * words w, added to q[x] where flag[x] is 0; flag[x] = 1 where the caller must draw with
 * poisson_word (q[x] + 0.0 there: unchanged, q holds no -0). */
WF_CLONES static void poisson_row_small(int n, const uint32_t *restrict w,
                                        const uint32_t *restrict thr, size_t stride,
                                        const uint32_t *restrict slow, double *restrict q,
                                        uint8_t *restrict flag)
{
    for (int x = 0; x < n; x++) {
        const uint32_t v = w[x];
        int c = (v >= thr[x]) + (v >= thr[stride + x]) + (v >= thr[2 * stride + x]) +
                (v >= thr[3 * stride + x]) + (v >= thr[4 * stride + x]) + (v >= thr[5 * stride + x]);
        const int more = v >= slow[x];
        q[x] += more ? 0.0 : (double)c;
        flag[x] = (uint8_t)more;
    }
}

/* Fills the first `blocks` noise blocks of row y for (read, purpose), word k of column x at
 * words[k * ncols + x], and for tile rows the normals from word 0. */
static void row_noise(wf_readout *ro, int y, uint32_t read, wf_purpose purpose, int blocks, float *z)
{
    size_t nc = (size_t)ro->cfg.ncols;
    for (int b = 0; b < blocks; b++) {
        uint32_t *w = ro->words + 4 * (size_t)b * nc;
        wf_noise_block_row(&ro->noise, (uint32_t)y * (uint32_t)nc, (int)nc, read, purpose, (uint32_t)b,
                           w, w + nc, w + 2 * nc, w + 3 * nc);
    }
    if (z) wf_norm_from_u32(ro->words, (int)nc, z);
}

/* Per-read sampling needs two words a pixel and read (the read-noise normal and the Poisson
 * word), so one Philox block serves two pixels of a row, x and x + h with h = ceil(ncols / 2):
 * block 0 of (pixel y h + x, read, WF_PURPOSE_PHOTON_PAIR) gives words 0-1 to the first and
 * 2-3 to the second. The halves of the row land where they belong, with no unpacking. A draw
 * that needs more (PTRS above a mean of 10) takes the pixel's own stream (more_noise). Row
 * y's words of one read: the normals' at ro->words, the Poisson words at row_words_poisson,
 * and for tile rows the normals in z. */
static uint32_t *row_words_poisson(const wf_readout *ro)
{
    return ro->words + ro->cfg.ncols + 1; /* one word apart: an odd row's last block writes one past */
}

static void row_noise_pairs(wf_readout *ro, int y, uint32_t read, float *z)
{
    const int nc = ro->cfg.ncols, h = (nc + 1) / 2;
    uint32_t *zw = ro->words, *pw = row_words_poisson(ro); /* up to words[2 nc + 2] */
    wf_noise_block_row(&ro->noise, (uint32_t)y * (uint32_t)h, h, read, WF_PURPOSE_PHOTON_PAIR, 0, zw, pw, zw + h,
                       pw + h);
    if (z) wf_norm_from_u32(zw, nc, z);
}

/* IPC for tile row y (absolute) from the measured halo block that starts at row h0. */
static const double *ipc_row(wf_readout *ro, int y, int h0, int h1)
{
    int nc = ro->cfg.ncols;
    const double *mid = ro->meas + (size_t)(y - h0) * nc;
    if (!ro->cfg.det.on.ipc) return mid;
    const double *above = y - 1 >= h0 ? mid - nc : NULL;
    const double *below = y + 1 < h1 ? mid + nc : NULL;
    wf_det_ipc_row(above, mid, below, nc, ro->cfg.det.ipc, ro->row);
    return ro->row;
}

static uint32_t pixel_id(const wf_readout *ro, int y, int x)
{
    return (uint32_t)y * (uint32_t)ro->cfg.ncols + (uint32_t)x;
}

/* ---- correlated read noise and the reference border (firmware/corrnoise.h) ------------- */

/* The realisation of a read (per-read sampling) or of a resultant drawn at once. */
static uint32_t corr_key(int index, int direct)
{
    return direct ? 0x80000000u | (uint32_t)index : (uint32_t)index;
}

/* Active row y's signal v plus the correlated noise of its full-frame row (left in cn_row). */
static const double *corr_row(wf_readout *ro, const double *v, int y, uint32_t key, double scale)
{
    const int nc = ro->cfg.ncols;
    wf_corrnoise_row(ro->cn, key, y + WF_CN_BORDER, scale, ro->cn_row);
    const double *c = ro->cn_row + WF_CN_BORDER;
    for (int x = 0; x < nc; x++) ro->cn_v[x] = v[x] + c[x];
    return ro->cn_v;
}

/* Row y's side reference pixels after corr_row: no charge, the correlated noise in e8, their
 * read-noise normals in z8 (left four, right four). */
static void side_pixels(wf_readout *ro, int y, uint32_t key, double *e8, float *z8)
{
    const int W = ro->cn->width, B = WF_CN_BORDER;
    wf_corrnoise_ref_normals(ro->cn, key, y + B, 0, B, z8);
    wf_corrnoise_ref_normals(ro->cn, key, y + B, W - B, B, z8 + B);
    for (int i = 0; i < B; i++) {
        e8[i] = ro->cn_row[i];
        e8[B + i] = ro->cn_row[W - B + i];
    }
}

/* One read of row y's side reference pixels, summed as the active pixels' (resultant r). */
static void side_read(wf_readout *ro, int y, int y0, int rows, uint32_t key, int r, int last, int nreads)
{
    enum { S = 2 * WF_CN_BORDER };
    double e8[S], q8[S] = {0};
    float z8[S];
    uint8_t sat8[S];
    side_pixels(ro, y, key, e8, z8);
    memset(sat8, 255, sizeof sat8);
    double *s = ro->side_sum + (size_t)(y - y0) * S;
    wf_det_ramp_read_row(&ro->cfg.det, e8, q8, z8, S, (uint8_t)r, s, sat8);
    if (last) wf_det_resultant_row(s, S, nreads, ro->side_out + ((size_t)r * rows + (size_t)(y - y0)) * S);
}

/* Resultant r of row y's side reference pixels drawn at once (n reads). */
static void side_direct(wf_readout *ro, int y, int y0, int rows, int r, int n)
{
    enum { S = 2 * WF_CN_BORDER };
    double e8[S], q8[S] = {0};
    float z8[S];
    uint8_t sat8[S]; /* no charge: never set, and not kept */
    side_pixels(ro, y, corr_key(r, 1), e8, z8);
    memset(sat8, 255, sizeof sat8);
    uint16_t *out = ro->side_out + ((size_t)r * rows + (size_t)(y - y0)) * S;
    wf_det_group_row(&ro->cfg.det, e8, q8, z8, S, n, (uint8_t)r, sat8, out);
}

/* The eight reference rows (full-frame rows 0-3 and the last four) of every resultant, as
 * one REFROWS packet: they hold no charge, so no tile is needed to make them. */
static wf_status send_refrows(wf_readout *ro)
{
    const wf_detector *d = &ro->cfg.det;
    const wf_ma_table *ma = &ro->clock.ma;
    const int W = ro->cn->width, B = WF_CN_BORDER, H = ro->cn->height, nres = ma->nresultants;
    const int direct = ro->cfg.sampling != WF_SAMPLE_PER_READ; /* resultants drawn at once */
    size_t mark = wf_arena_mark(ro->arena);
    void *p;
    wf_status st = wf_arena_calloc(ro->arena, 2 * B * (size_t)W, sizeof(double), "reference row sums", &p);
    if (st) return st;
    double *sum = p;
    if ((st = wf_arena_calloc(ro->arena, (size_t)nres * 2 * B * (size_t)W, sizeof(uint16_t), "reference rows", &p))) {
        wf_arena_release(ro->arena, mark);
        return st;
    }
    uint16_t *out = p;
    memset(ro->zero, 0, (size_t)W * sizeof *ro->zero);
    for (int i = 0; i < 2 * B; i++) {
        const int Y = i < B ? i : H - 2 * B + i;
        for (int r = 0; direct && r < nres; r++) {
            const int n = ma->first[r + 1] - ma->first[r];
            const uint32_t key = corr_key(r, 1);
            wf_corrnoise_row(ro->cn, key, Y, 1.0 / sqrt((double)n), ro->cn_row);
            wf_corrnoise_ref_normals(ro->cn, key, Y, 0, W, ro->ref_z);
            uint16_t *o = out + ((size_t)r * 2 * B + (size_t)i) * W;
            memset(ro->ref_sat, 255, (size_t)W); /* no charge: the flags are not kept */
            wf_det_group_row(d, ro->cn_row, ro->zero, ro->ref_z, W, n, (uint8_t)r, ro->ref_sat, o);
        }
        for (int k = 0; !direct && k < ro->total_reads; k++) {
            const int r = ro->resultant_of_read[k];
            if (r < 0) continue;
            wf_corrnoise_row(ro->cn, corr_key(k, 0), Y, 1.0, ro->cn_row);
            wf_corrnoise_ref_normals(ro->cn, corr_key(k, 0), Y, 0, W, ro->ref_z);
            memset(ro->ref_sat, 255, (size_t)W);
            wf_det_ramp_read_row(d, ro->cn_row, ro->zero, ro->ref_z, W, (uint8_t)r, sum + (size_t)i * W, ro->ref_sat);
            if (ma->read[ma->first[r + 1] - 1] == k)
                wf_det_resultant_row(sum + (size_t)i * W, W, ma->first[r + 1] - ma->first[r],
                                     out + ((size_t)r * 2 * B + (size_t)i) * W);
        }
    }
    st = send_cols(ro, WF_PK_REFROWS, 0, 2 * B, W, nres, out, (size_t)nres * 2 * B * (size_t)W * sizeof *out);
    wf_arena_release(ro->arena, mark);
    return st;
}

/* ---- up-the-ramp, read by read --------------------------------------------------------- */

/* Read k's charge of halo row y (Poisson, or the means without photon noise) and, for tile
 * rows, its read-noise normals. */
static void per_read_charge_row(wf_readout *ro, int y, int y0, int y1, int h0, int h1, int k, double frames,
                                double tau)
{
    const wf_detector *d = &ro->cfg.det;
    const int nc = ro->cfg.ncols, hn = (h1 - h0) * nc;
    const size_t row0 = (size_t)(y - h0) * nc;
    double *q = ro->charge + row0;
    const double *m = ro->mean + row0, *em = ro->expm + row0;
    float *z = y >= y0 && y < y1 ? ro->gauss + (size_t)(y - y0) * nc : NULL;
    const int photons = d->on.photon_noise && !ro->noise_off;
    if (photons || (z && d->on.read_noise && !ro->noise_off)) {
        row_noise_pairs(ro, y, (uint32_t)k, z && d->on.read_noise ? z : NULL);
    } else if (z) {
        memset(z, 0, (size_t)nc * sizeof *z);
    }
    if (!photons) {
        if (ro->slope_any)
            for (int x = 0; x < nc; x++) q[x] += interval_mean(ro, row0 + (size_t)x, frames, tau);
        else
            for (int x = 0; x < nc; x++) q[x] += m[x] * frames;
        return;
    }
    const uint32_t *w1 = row_words_poisson(ro);
    if (frames == 1.0 && !ro->slope_any) { /* the common read: the tile's thresholds */
        uint8_t *slow = ro->slow;
        poisson_row_small(nc, w1, ro->thr + row0, (size_t)hn, ro->thr + 6 * (size_t)hn + row0, q, slow);
        for (int x = next_flag(slow, 0, nc); x < nc; x = next_flag(slow, x + 1, nc)) {
            more_noise mn = {.noise = &ro->noise, .pixel = pixel_id(ro, y, x), .read = (uint32_t)k,
                             .purpose = WF_PURPOSE_PHOTON};
            q[x] += poisson_word(w1[x], NULL, m[x], em[x], &mn);
        }
        return;
    }
    for (int x = 0; x < nc; x++) {
        more_noise mn = {.noise = &ro->noise, .pixel = pixel_id(ro, y, x), .read = (uint32_t)k,
                         .purpose = WF_PURPOSE_PHOTON};
        if (ro->slope_any) {
            double mean = interval_mean(ro, row0 + (size_t)x, frames, tau);
            q[x] += poisson_word(w1[x], NULL, mean, exp(-mean), &mn);
            continue;
        }
        double mean = m[x] * frames;
        q[x] += poisson_word(w1[x], NULL, mean, frames == 1.0 ? em[x] : exp(-mean), &mn);
    }
}

/* Read k of tile row y from the measured rows around it: IPC, correlated noise, read noise,
 * ADC, into the resultant's sum (and the resultant when it is the group's last read). */
static void per_read_digitise_row(wf_readout *ro, int y, int y0, int y1, int h0, int h1, int k, int r, int last,
                                  int nreads)
{
    const wf_detector *d = &ro->cfg.det;
    const int nc = ro->cfg.ncols, rows = y1 - y0;
    const double *v = ipc_row(ro, y, h0, h1);
    if (ro->cn) v = corr_row(ro, v, y, corr_key(k, 0), 1.0);
    const double *q = ro->charge + (size_t)(y - h0) * nc;
    double *s = ro->sum + (size_t)(y - y0) * nc;
    uint8_t *sat = ro->sat + (size_t)(y - y0) * nc;
    uint16_t *out = ro->res_out + ((size_t)r * rows + (size_t)(y - y0)) * nc;
    const float *z = ro->gauss + (size_t)(y - y0) * nc;
    wf_det_ramp_read_row(d, v, q, z, nc, (uint8_t)r, s, sat);
    if (last) wf_det_resultant_row(s, nc, nreads, out);
    if (ro->refpix) side_read(ro, y, y0, rows, corr_key(k, 0), r, last, nreads);
}

/* Read by read, and within a read row by row down the tile: a row's charge (Poisson, then
 * its cosmic-ray hits and persistence, in that order as every pixel always had them), its
 * full well and measure, then the row above it digitised, whose IPC needed this one. So a
 * row's arrays are still in cache when they are used again: passes over the whole tile
 * waited on memory. */
static wf_status ramp_per_read(wf_readout *ro, int y0, int y1, int h0, int h1)
{
    const wf_detector *d = &ro->cfg.det;
    const int nc = ro->cfg.ncols, hn = (h1 - h0) * nc;
    int next_dep = 0, prev_read = -1;
    size_t scratch;
    ro->thr = wf_packer_scratch(&ro->packer, &scratch); /* no packet goes out until the tile's */
    if (scratch < 7 * (size_t)hn * sizeof *ro->thr)
        return wf_error(WF_ERR_INTERNAL, "readout: packet buffer of %zu bytes holds no %d-pixel "
                        "thresholds", scratch, hn);
    if (d->on.photon_noise && !ro->noise_off && !ro->slope_any)
        wf_poisson_inversion_thresholds_row(hn, ro->mean, ro->expm, ro->thr, (size_t)hn, ro->thr + 6 * (size_t)hn);
    for (int k = 0; k < ro->total_reads; k++) {
        int r = ro->resultant_of_read[k];
        if (r < 0) continue; /* charge of skipped reads is drawn with the next digitised one */
        double frames = k - prev_read;
        /* the interval's centre, relative to the mid-time the rates are for */
        double t1 = wf_clock_read_time(&ro->clock, prev_read), t2 = wf_clock_read_time(&ro->clock, k);
        double tau = 0.5 * (t1 + t2) - ro->t_mid;
        prev_read = k;
        int dep_end = next_dep; /* this read's cosmic-ray hits: [next_dep, dep_end) */
        while (ro->cosmic_on && dep_end < ro->cosmic.ndeposits && (int)ro->cosmic.deposits[dep_end].read <= k)
            dep_end++;
        const int last = ro->clock.ma.read[ro->clock.ma.first[r + 1] - 1] == k;
        const int nreads = ro->clock.ma.first[r + 1] - ro->clock.ma.first[r];
        for (int y = h0; y < h1; y++) {
            const uint32_t lo = (uint32_t)(y - h0) * (uint32_t)nc, hi = lo + (uint32_t)nc;
            per_read_charge_row(ro, y, y0, y1, h0, h1, k, frames, tau);
            for (int j = next_dep; j < dep_end; j++)
                if (ro->cosmic.deposits[j].pixel >= lo && ro->cosmic.deposits[j].pixel < hi)
                    ro->charge[ro->cosmic.deposits[j].pixel] += ro->cosmic.deposits[j].electrons;
            wf_persist_release(&ro->persist, k, t1, t2, lo, hi, ro->charge, NULL, 0.0);
            wf_det_hold_measure_row(d, ro->charge + lo, nc, ro->meas + lo);
            if (y - 1 >= y0 && y - 1 < y1) per_read_digitise_row(ro, y - 1, y0, y1, h0, h1, k, r, last, nreads);
        }
        if (h1 == y1) per_read_digitise_row(ro, y1 - 1, y0, y1, h0, h1, k, r, last, nreads); /* no row below */
        next_dep = dep_end;
    }
    return WF_OK;
}

/* ---- up-the-ramp, resultants drawn directly -------------------------------------------- */

/* Words for direct sampling come from the first blocks of the (pixel, resultant) stream:
 * word 0 is the read-noise normal, then one word per Poisson draw by inversion (two for
 * the first PTRS attempt above a mean of 10). A group of n reads needs at most 2n + 1. */
static int direct_blocks(const wf_ma_table *ma)
{
    int nmax = 1;
    for (int r = 0; r < ma->nresultants; r++)
        if (ma->first[r + 1] - ma->first[r] > nmax) nmax = ma->first[r + 1] - ma->first[r];
    return (2 * nmax + 1 + 3) / 4;
}

/* Poisson draw from the row's words at cursor *c (advanced), for one pixel column x. */
static inline double draw_at(const uint32_t *words, size_t nc, int x, int *c, double mean,
                             double expm, more_noise *mn)
{
    if (mean >= 10.0) {
        double k = poisson_word(words[(size_t)*c * nc + x], &words[(size_t)(*c + 1) * nc + x], mean, expm, mn);
        *c += 2;
        return k;
    }
    return poisson_word(words[(size_t)(*c)++ * nc + x], NULL, mean, expm, mn);
}

/* ---- moments: a group's mean from three draws ------------------------------------------
 *
 * Within group r (n reads at frames t_0 < ... < t_(n-1), span s = t_(n-1) - t_0), let D_j be
 * the electrons of interval j (t_(j-1), t_j], independent Poisson of means mu_j (mu_j = lambda
 * (t_j - t_(j-1)) at a constant rate lambda per frame), T = sum_j D_j the group's total increment
 * and A = sum_j w_j D_j, w_j = (n - j)/n, the group mean of the accumulated charge above the
 * charge Q_0 at its first read. Given T, (D_j) is multinomial(T, p_j = mu_j / mu), mu = sum mu_j:
 *     E[A | T] = T abar,               abar = sum_j w_j p_j
 *     Var[A | T] = T (sum_j w_j^2 p_j - abar^2)
 * exactly, so that, with E[T] = Var[T] = mu,
 *     E[A] = mu abar, Var[A] = mu sum_j w_j^2 p_j, Cov(A, T) = mu abar,
 * the per-read process's moments (Var[A] = E Var[A|T] + Var E[A|T] = mu (s2 - abar^2) + mu abar^2).
 * n consecutive reads: abar = 1/2, Var[A | T] = T (n - 2)/(12 n), Var[A] = mu (2n - 1)/(6n),
 * Cov(A, T) = mu/2 (Var[A] - Cov^2/Var[T] = mu (n-1)(n-2)/(12n) with mu = (n-1) lambda).
 * These hold whatever law T has with mean and variance mu, so each draw is:
 *  - the lead (the charge up to t_0) and T: Poisson by inversion of one word below a mean of
 *    10, N(mu, mu) above (clamped at 0: P < 1e-3 at 10). Above 10 the Poisson's skewness
 *    1/sqrt(mu) < 0.32 is all the normal drops, a third-moment effect this mode does not
 *    claim, and one word replaces PTRS's rejection loop; below, the normal would put
 *    visible mass below zero and miss the discreteness that faint pixels show;
 *  - A = T abar + sqrt(T cvar) N(0, 1), normal with the exact conditional mean and variance
 *    (not clamped to [0, T], so that both moments stay exact; the read noise of the mean,
 *    N(0, sigma^2/n), is far wider than what leaves that range).
 * Word 0 of the (pixel, resultant, WF_PURPOSE_MOMENTS) block is the read-noise normal, words
 * 1-3 the lead, T and A: one block per resultant whatever n.
 *
 * Nonlinearity f(q) = q + beta q^2 acts on each read before the average, so the resultant
 * holds (1/n) sum_i f(Q_i) = f(Qbar) + beta S with S = (1/n) sum_i (Q_i - Qbar)^2 the spread
 * of the group's charge: exact for the quadratic, and the term 1/2 f''(Qbar) S of
 * E[f(Q)] ~ f(E Q) + 1/2 f''(E Q) Var(Q) taken over the group's reads. S is replaced by its
 * expectation given T: with u_i = (t_i - t_0)/s, Cov(N_i, N_k | T) = T u_i (1 - u_k) for
 * u_i <= u_k (N_i the increment to read i), so
 *     E[S | T] = vu T^2 + bs T,  vu = (1/n) sum_i (u_i - ubar)^2,
 *     bs = (1/n) sum_i u_i (1 - u_i) - (1/n^2) sum_i sum_k min(u_i,u_k) (1 - max(u_i,u_k)),
 * which makes the mean resultant exact for the quadratic (E over T of E[S | T] is E[S]);
 * noiseless, S is the deterministic ramp's vu T^2. A saturated group (its last charge at the
 * full well) gets no correction: its reads are clipped, and the resultant is flagged. */

/* Moments' draws of a row's chunk: out[x] = Poisson(mean[x]) by inversion of the word w[x]
 * below a mean of 10 (from its start e0[x] = exp(-mean[x])), N(mean, mean) from the normal
 * z[x] above, clamped at 0 (see above); big: whether any mean reaches 10 (else z is not
 * read). The inversion runs the pixels in lockstep, one
 * term of every pixel's sum per pass, so that it vectorises: a pixel's count is the number of
 * partial sums below its uniform, the smallest k with u <= F_k, as a scalar search gives.
 * A pixel whose uniform is no longer above its sum is done (the sums only grow); the passes
 * run over the whole chunk to its largest count (~mean + 3.5 sqrt(mean) over 256 pixels),
 * at most 200 terms. (Packing the pixels still going cost more than the passes it saved: its
 * scalar, mispredicted copy was half of the chunk's time.) */
enum { MOMENTS_CHUNK = 256 };

/* Passes over the pixels at [0, n), terms 1, 2, ..., until none still counts or term
 * INV_K_MAX is done: one term of every pixel per pass, through memory. */
WF_CLONES static void moments_passes_lockstep(int n, const double *restrict u, double *restrict p,
                                              double *restrict cdf, double *restrict cnt,
                                              const double *restrict mean, const double *restrict inv_k)
{
    int k = 1, na;
    do {
        na = 0;
        for (int x = 0; x < n; x++) {
            const int above = u[x] > cdf[x];
            cnt[x] += above ? 1.0 : 0.0; /* a masked add: an int converted to double cost more */
            na += above;
            p[x] *= mean[x] * inv_k[k];
            cdf[x] += p[x];
        }
        k++;
    } while (k <= INV_K_MAX && na > 0);
}

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_ADDRESS__)
#include <immintrin.h>
#define MOMENTS_PASSES_AVX512 1
enum { MOMENTS_BLOCKS = 2 }; /* vectors of 8 in flight: their chains' latencies overlap */
/* The counts of the pixels at [0, n) from their words, means and starts, 16 at a time (what
 * is left over, below 16, is not done: the count returned is of those done). Two blocks of 8
 * pixels' uniforms, terms, sums and counts stay in registers through all their terms, and
 * stop at their own largest count, not the chunk's (the sums only grow, so a block none of
 * whose pixels counts at a term is done). The same operations in the same order on each
 * pixel as moments_counts_lockstep: the same counts. */
__attribute__((target("avx512f"))) static int moments_counts_avx512(int n, const uint32_t *w, const double *mean,
                                                                     const double *e0, const double *inv_k,
                                                                     double *cnt)
{
    const __m512d one = _mm512_set1_pd(1.0), zero = _mm512_setzero_pd(), ten = _mm512_set1_pd(10.0);
    const __m512d half = _mm512_set1_pd(0.5), scale = _mm512_set1_pd(1.0 / 4294967296.0);
    int x = 0;
    for (; x + 8 * MOMENTS_BLOCKS <= n; x += 8 * MOMENTS_BLOCKS) {
        __m512d vu[MOMENTS_BLOCKS], vm[MOMENTS_BLOCKS], vp[MOMENTS_BLOCKS], vc[MOMENTS_BLOCKS], vn[MOMENTS_BLOCKS];
        for (int j = 0; j < MOMENTS_BLOCKS; j++) {
            const __m512d mx = _mm512_loadu_pd(mean + x + 8 * j), ex = _mm512_loadu_pd(e0 + x + 8 * j);
            const __m256i wx = _mm256_loadu_si256((const __m256i *)(w + x + 8 * j));
            const __m512d ux = _mm512_mul_pd(_mm512_add_pd(_mm512_cvtepu32_pd(wx), half), scale);
            const __mmask8 small = _mm512_cmp_pd_mask(mx, zero, _CMP_GT_OQ) & _mm512_cmp_pd_mask(mx, ten, _CMP_LT_OQ);
            vu[j] = _mm512_maskz_mov_pd(small, ux); /* 0: never counts */
            vp[j] = vc[j] = _mm512_mask_blend_pd(small, one, ex);
            vm[j] = _mm512_maskz_mov_pd(small, mx);
            vn[j] = zero;
        }
        for (int k = 1; k <= INV_K_MAX; k++) {
            const __m512d ik = _mm512_set1_pd(inv_k[k]);
            unsigned any = 0;
            for (int j = 0; j < MOMENTS_BLOCKS; j++) {
                const __mmask8 above = _mm512_cmp_pd_mask(vu[j], vc[j], _CMP_GT_OQ);
                any |= above;
                vn[j] = _mm512_mask_add_pd(vn[j], above, vn[j], one);
                vp[j] = _mm512_mul_pd(vp[j], _mm512_mul_pd(vm[j], ik));
                vc[j] = _mm512_add_pd(vc[j], vp[j]);
            }
            if (!any) break;
        }
        for (int j = 0; j < MOMENTS_BLOCKS; j++) _mm512_storeu_pd(cnt + x + 8 * j, vn[j]);
    }
    return x;
}
#endif

/* The counts of the pixels at [0, n) (n <= MOMENTS_CHUNK) from their words, means and
 * starts, by the lockstep passes. */
WF_CLONES static void moments_counts_lockstep(int n, const uint32_t *restrict w, const double *restrict mean,
                                              const double *restrict e0, const double *restrict inv_k,
                                              double *restrict cnt)
{
    /* per pixel: uniform, term, partial sum, mean */
    double pu[MOMENTS_CHUNK], pp[MOMENTS_CHUNK], pc[MOMENTS_CHUNK], pm[MOMENTS_CHUNK];
    /* every comparison and load made whatever the branch: a conditional one (a possible
     * trap, to the compiler) keeps these loops scalar */
    for (int x = 0; x < n; x++) {
        const double mx = mean[x], ex = e0[x], ux = ((double)w[x] + 0.5) * (1.0 / 4294967296.0);
        const int small = (mx > 0.0) & (mx < 10.0);
        pu[x] = small ? ux : 0.0; /* 0: never counts */
        pp[x] = pc[x] = small ? ex : 1.0;
        cnt[x] = 0.0;
        pm[x] = small ? mx : 0.0; /* so a negative mean's sums stay at 1: it counts 0 */
    }
    for (int x = n; x < MOMENTS_CHUNK; x++) { /* never read; set so that no compiler doubts it */
        pu[x] = pm[x] = 0.0;
        pp[x] = pc[x] = 1.0;
    }
    moments_passes_lockstep(n, pu, pp, pc, cnt, pm, inv_k);
}

WF_CLONES static void moments_poisson_chunk(int n, const uint32_t *restrict w, const float *restrict z, int big,
                                            const double *restrict mean, const double *restrict e0,
                                            const double *restrict inv_k, int simd, double *restrict out)
{
    double cnt[MOMENTS_CHUNK];
    int done = 0;
#ifdef MOMENTS_PASSES_AVX512
    if (simd && __builtin_cpu_supports("avx512f")) done = moments_counts_avx512(n, w, mean, e0, inv_k, cnt);
#else
    (void)simd;
#endif
    if (done < n) moments_counts_lockstep(n - done, w + done, mean + done, e0 + done, inv_k, cnt + done);
    if (!big) { /* no mean reaches 10 (z was not made): the counts, 0 for a mean <= 0 or NaN */
        memcpy(out, cnt, (size_t)n * sizeof *out);
        return;
    }
    for (int x = 0; x < n; x++) {
        const double g = mean[x] + sqrt(mean[x] > 0.0 ? mean[x] : 0.0) * (double)z[x];
        const double gc = g > 0.0 ? g : 0.0;
        out[x] = mean[x] < 10.0 ? cnt[x] : gc;
    }
}

/* exp(-m k) as exp(-m)^k for k = lead and span, by squaring (a 32-read group's span of 31
 * takes 8 multiplies, not 31): within a few ulp, and multiplies that vectorise; a chunk at
 * a time, so that the passes stay in L1 */
WF_CLONES static void moments_powers(int nc, const double *restrict em, int lead, int span, double *restrict le,
                                     double *restrict me)
{
    double sq[MOMENTS_CHUNK];
    for (int x0 = 0; x0 < nc; x0 += MOMENTS_CHUNK) {
        const int c = nc - x0 < MOMENTS_CHUNK ? nc - x0 : MOMENTS_CHUNK;
        for (int o = 0; o < 2; o++) {
            double *restrict out = (o ? me : le) + x0;
            for (int x = 0; x < c; x++) {
                out[x] = 1.0;
                sq[x] = em[x0 + x];
            }
            for (int b = o ? span : lead; b; b >>= 1) {
                if (b & 1)
                    for (int x = 0; x < c; x++) out[x] *= sq[x];
                if (b > 1)
                    for (int x = 0; x < c; x++) sq[x] *= sq[x];
            }
        }
    }
}

/* The group's draws into the charge q, the group mean a and the spread sp (moments_row);
 * grows: 0 for a one-read group, which has no increment within it. ab and cv: each pixel's
 * shape (a pixel whose rate changes in time has its own), or NULL for the group's abar and
 * cvar everywhere (then no row of them is written or read). */
static inline __attribute__((always_inline)) void moments_finish_body(
    int nc, int grows, const double *restrict ld, const double *restrict t, const double *restrict ab,
    const double *restrict cv, double abar, double cvar, const float *restrict z3, double vu, double bs,
    double *restrict q, double *restrict a, double *restrict sp, int per_pixel)
{
    for (int x = 0; x < nc; x++) {
        const double tc = grows ? t[x] : 0.0, abx = per_pixel ? ab[x] : abar, v = tc * (per_pixel ? cv[x] : cvar);
        q[x] += ld[x];
        a[x] = q[x] + tc * abx + (v > 0.0 ? sqrt(v) : 0.0) * (double)z3[x];
        q[x] += tc;
        sp[x] = tc * (tc * vu + bs);
    }
}

WF_CLONES static void moments_finish(int nc, int grows, const double *restrict ld, const double *restrict t,
                                     const double *restrict ab, const double *restrict cv, double abar,
                                     double cvar, const float *restrict z3, double vu, double bs,
                                     double *restrict q, double *restrict a, double *restrict sp)
{
    if (ab) moments_finish_body(nc, grows, ld, t, ab, cv, abar, cvar, z3, vu, bs, q, a, sp, 1);
    else moments_finish_body(nc, grows, ld, t, ab, cv, abar, cvar, z3, vu, bs, q, a, sp, 0);
}

/* Group r of row y by moments (photon noise on): the lead, then A and T as above, from the
 * row's words (ro->words: word 0 read noise, 1 lead, 2 T, 3 A). A pixel whose rate changes
 * in time takes its interval means, and with them its own abar and cvar; the others the
 * group's. Adds the lead and T to q, sets a (the group's mean charge) and sp (E[S | T]). */
static void moments_row(wf_readout *ro, int r, size_t row0, double lead, double tau_lead, double *q, double *a,
                        double *sp)
{
    const wf_ma_table *ma = &ro->clock.ma;
    const wf_clock *ck = &ro->clock;
    const int *reads = ma->read + ma->first[r];
    const int n = ma->first[r + 1] - ma->first[r], nc = ro->cfg.ncols;
    const int span = reads[n - 1] - reads[0];
    const moments_group *g = &ro->mgroup[r];
    const double *m = ro->mean + row0, *em = ro->expm + row0;
    const uint32_t *w = ro->words;
    double *lm = ro->mrow, *le = lm + nc, *ld = le + nc, *mu = ld + nc, *me = mu + nc, *t = me + nc, *ab = t + nc,
           *cv = ab + nc;
    float *z1 = ro->mz, *z2 = z1 + nc, *z3 = z2 + nc;
    /* A's normal only where the group grows: a one-read group (as MA tables start) has none */
    if (n > 1) wf_norm_from_u32(w + 3 * (size_t)nc, nc, z3);
    else memset(z3, 0, (size_t)nc * sizeof *z3);
    const double abar = g->abar, cvar = g->cvar; /* copies: g could alias the stores */
    moments_means(nc, m, lead, span, lm, mu);
    moments_powers(nc, em, (int)lead, span, le, me);
    for (int x = 0; ro->slope_any && x < nc; x++) { /* the group's shape, but where the rate changes */
        ab[x] = abar;
        cv[x] = cvar;
        if (ro->dmean[row0 + (size_t)x] == 0.0) continue;
        const size_t i = row0 + (size_t)x;
        lm[x] = interval_mean(ro, i, lead, tau_lead);
        le[x] = exp(-lm[x]);
        double s1 = 0.0, s2 = 0.0, sum = 0.0;
        for (int j = 1; j < n; j++) {
            double tj = 0.5 * (wf_clock_read_time(ck, reads[j - 1]) + wf_clock_read_time(ck, reads[j])) - ro->t_mid;
            double mj = interval_mean(ro, i, reads[j] - reads[j - 1], tj), wj = (double)(n - j) / n;
            sum += mj;
            s1 += wj * mj;
            s2 += wj * wj * mj;
        }
        mu[x] = sum;
        me[x] = exp(-sum);
        ab[x] = sum > 0.0 ? s1 / sum : 0.0;
        cv[x] = sum > 0.0 ? s2 / sum - ab[x] * ab[x] : 0.0;
    }
    for (int x0 = 0; x0 < nc; x0 += MOMENTS_CHUNK) {
        const int c = nc - x0 < MOMENTS_CHUNK ? nc - x0 : MOMENTS_CHUNK;
        /* the normals of the lead and T only where a mean reaches 10 (a bright pixel) */
        const int big1 = count_at_least(c, lm + x0, 10.0), big2 = count_at_least(c, mu + x0, 10.0);
        if (big1) wf_norm_from_u32(w + nc + x0, c, z1 + x0);
        if (big2) wf_norm_from_u32(w + 2 * (size_t)nc + x0, c, z2 + x0);
        moments_poisson_chunk(c, w + nc + x0, z1 + x0, big1, lm + x0, le + x0, ro->inv_k, !ro->cfg.portable, ld + x0);
        moments_poisson_chunk(c, w + 2 * (size_t)nc + x0, z2 + x0, big2, mu + x0, me + x0, ro->inv_k, !ro->cfg.portable, t + x0);
    }
    moments_finish(nc, n > 1, ld, t, ro->slope_any ? ab : NULL, cv, abar, cvar, z3, g->vu, g->bs, q, a, sp);
}

/* Resultant r (a group of n reads) of tile row y from the measured rows around it: IPC,
 * correlated noise, read noise of the mean, ADC. A resultant holds a saturated read when its
 * last read did: the charge at that read reached the well, or its measured signal the ADC
 * ceiling. */
static void grouped_digitise_row(wf_readout *ro, int y, int y0, int y1, int h0, int h1, int r, int n)
{
    const int nc = ro->cfg.ncols, rows = y1 - y0;
    const double *v = ipc_row(ro, y, h0, h1);
    if (ro->cn) {
        v = corr_row(ro, v, y, corr_key(r, 1), 1.0 / sqrt((double)n));
        if (ro->refpix) side_direct(ro, y, y0, rows, r, n);
    }
    const double *q = ro->charge + (size_t)(y - h0) * nc;
    uint8_t *sat = ro->sat + (size_t)(y - y0) * nc;
    uint16_t *out = ro->res_out + ((size_t)r * rows + (size_t)(y - y0)) * nc;
    const float *z = ro->gauss + (size_t)(y - y0) * nc;
    wf_det_group_row(&ro->cfg.det, v, q, z, nc, n, (uint8_t)r, sat, out);
}

/* Direct and moments sampling: each resultant drawn at once. They differ only in how a
 * pixel's group is drawn (every interval, or three draws); the rest (persistence, cosmic
 * rays, full well, nonlinearity, IPC, read noise, gain, ADC, saturation) is this one path.
 * A group at a time, and within it row by row down the tile, as ramp_per_read: a row's
 * draws, persistence, cosmic rays, full well, measure, then the row above it digitised. */
static wf_status ramp_grouped(wf_readout *ro, int y0, int y1, int h0, int h1)
{
    const wf_detector *d = &ro->cfg.det;
    const wf_ma_table *ma = &ro->clock.ma;
    const int nc = ro->cfg.ncols;
    const int moments = ro->cfg.sampling == WF_SAMPLE_MOMENTS;
    const int nblocks = moments ? 1 : direct_blocks(ma);
    const wf_purpose purpose = moments ? WF_PURPOSE_MOMENTS : WF_PURPOSE_RESULTANT;
    double *avg = ro->meas; /* reused: average charge of the group, then measured */
    int next_dep = 0, prev_read = -1;
    for (int r = 0; r < ma->nresultants; r++) {
        const int *reads = ma->read + ma->first[r];
        int n = ma->first[r + 1] - ma->first[r];
        double lead = reads[0] - prev_read, span = reads[n - 1] - reads[0];
        const wf_clock *ck = &ro->clock;
        double tau_lead = 0.5 * (wf_clock_read_time(ck, prev_read) + wf_clock_read_time(ck, reads[0])) - ro->t_mid;
        const int lead_from = prev_read;
        prev_read = reads[n - 1];
        const moments_group *g = &ro->mgroup[r];
        int dep_end = next_dep; /* the group's cosmic-ray hits: [next_dep, dep_end) */
        while (ro->cosmic_on && dep_end < ro->cosmic.ndeposits && (int)ro->cosmic.deposits[dep_end].read <= reads[n - 1])
            dep_end++;
        double seen = 0.0; /* frames of charge each read of the group adds, averaged */
        for (int j = 1; j < n; j++) seen += (reads[j] - reads[j - 1]) * (double)(n - j) / n;
        for (int y = h0; y < h1; y++) {
            double *q = ro->charge + (size_t)(y - h0) * nc;
            double *a = avg + (size_t)(y - h0) * nc;
            const double *m = ro->mean + (size_t)(y - h0) * nc;
            const double *em = ro->expm + (size_t)(y - h0) * nc;
            double *sp = moments ? ro->spread + (size_t)(y - h0) * nc : NULL;
            float *z = y >= y0 && y < y1 ? ro->gauss + (size_t)(y - y0) * nc : NULL;
            int photons = d->on.photon_noise && !ro->noise_off;
            if (photons || (z && d->on.read_noise && !ro->noise_off)) {
                row_noise(ro, y, (uint32_t)r, purpose, photons ? nblocks : 1,
                          z && d->on.read_noise ? z : NULL);
            } else if (z) {
                memset(z, 0, (size_t)nc * sizeof *z);
            }
            const size_t row0 = (size_t)(y - h0) * nc;
            if (moments && photons) moments_row(ro, r, row0, lead, tau_lead, q, a, sp);
            for (int x = 0; !(moments && photons) && x < nc; x++) {
                if (!photons && ro->slope_any) { /* each interval at its own mean rate */
                    q[x] += interval_mean(ro, row0 + (size_t)x, lead, tau_lead);
                    double within = 0.0, total = 0.0;
                    for (int j = 1; j < n; j++) {
                        double tj = 0.5 * (wf_clock_read_time(ck, reads[j - 1]) + wf_clock_read_time(ck, reads[j])) - ro->t_mid;
                        double dj = interval_mean(ro, row0 + (size_t)x, reads[j] - reads[j - 1], tj);
                        within += dj * (double)(n - j);
                        total += dj;
                    }
                    a[x] = q[x] + within / n;
                    q[x] += total;
                    if (moments) sp[x] = total * total * g->vu; /* the ramp's own spread */
                    continue;
                }
                if (!photons) {
                    q[x] += m[x] * lead;
                    a[x] = q[x] + m[x] * seen;
                    q[x] += m[x] * span;
                    if (moments) sp[x] = m[x] * span * m[x] * span * g->vu;
                    continue;
                }
                more_noise mn = {.noise = &ro->noise, .pixel = pixel_id(ro, y, x), .read = (uint32_t)r,
                                 .purpose = WF_PURPOSE_RESULTANT, .first_block = (uint32_t)nblocks};
                /* Exact for a linear pixel: the charge before the group's first read, then
                 * each interval's Poisson electrons, seen by the n - j reads from j on. */
                int c = 1;
                const int var = ro->slope_any;
                double lm = var ? interval_mean(ro, row0 + (size_t)x, lead, tau_lead) : m[x] * lead;
                q[x] += draw_at(ro->words, (size_t)nc, x, &c, lm, lead == 1.0 && !var ? em[x] : exp(-lm), &mn);
                double within = 0.0, total = 0.0;
                for (int j = 1; j < n; j++) {
                    int gap = reads[j] - reads[j - 1];
                    double mj = m[x] * gap;
                    if (var) {
                        double tj = 0.5 * (wf_clock_read_time(ck, reads[j - 1]) + wf_clock_read_time(ck, reads[j])) - ro->t_mid;
                        mj = interval_mean(ro, row0 + (size_t)x, gap, tj);
                    }
                    double dj = draw_at(ro->words, (size_t)nc, x, &c, mj, gap == 1 && !var ? em[x] : exp(-mj), &mn);
                    within += dj * (double)(n - j);
                    total += dj;
                }
                a[x] = q[x] + within / n;
                q[x] += total;
            }
            /* the same intervals, and draws, as read by read: the lead seen by every read of
             * the group, interval j by the n - j reads from j on */
            const uint32_t lo = (uint32_t)row0, hi = lo + (uint32_t)nc;
            wf_persist_release(&ro->persist, reads[0], wf_clock_read_time(ck, lead_from),
                               wf_clock_read_time(ck, reads[0]), lo, hi, ro->charge, avg, 1.0);
            for (int j = 1; j < n; j++)
                wf_persist_release(&ro->persist, reads[j], wf_clock_read_time(ck, reads[j - 1]),
                                   wf_clock_read_time(ck, reads[j]), lo, hi, ro->charge, avg, (double)(n - j) / n);
            for (int i = next_dep; i < dep_end; i++) {
                const wf_cr_deposit *dp = &ro->cosmic.deposits[i];
                if (dp->pixel < lo || dp->pixel >= hi) continue;
                int later = 0; /* reads of the group that see the hit */
                for (int j = 0; j < n; j++) later += reads[j] >= (int)dp->read;
                ro->charge[dp->pixel] += dp->electrons;
                avg[dp->pixel] += dp->electrons * later / n;
            }
            if (d->on.saturation) clamp_row(nc, q, d->full_well);
            wf_det_measure_row(d, a, nc, a); /* in place (avg is ro->meas), at the full well too */
            if (moments && d->on.nonlinearity) spread_row(nc, a, sp, q, d->nl_beta, d->full_well, d->on.saturation);
            if (y - 1 >= y0 && y - 1 < y1) grouped_digitise_row(ro, y - 1, y0, y1, h0, h1, r, n);
        }
        if (h1 == y1) grouped_digitise_row(ro, y1 - 1, y0, y1, h0, h1, r, n); /* no row below */
        next_dep = dep_end;
    }
    return WF_OK;
}

/* ---- single frame (GalSim allDetectorEffects order) ------------------------------------ */

/* One PTRS attempt for each of the n pixels listed in ro->retry_x (columns), retry_px (their
 * streams' pixels) and retry_mean, from block b of its stream, as wf_rng_poisson makes them:
 * an accepted draw is added to q[column] (and next_block, when given, set to b + 1), the
 * rejected pixels are packed to the front of the lists for block b + 1. Returns how many are
 * left. The row's words are spent. */
static int ptrs_round(wf_readout *ro, uint32_t b, int n, double *q, uint16_t *next_block)
{
    const int nc = ro->cfg.ncols;
    uint32_t *rx = ro->retry_x, *rpx = ro->retry_px;
    double *rm = ro->retry_mean, *rk = ro->retry_k;
    uint32_t *b0 = ro->words, *b1 = b0 + nc, *b2 = b1 + nc, *b3 = b2 + nc;
    wf_noise_block_list(&ro->noise, rpx, n, 0, WF_PURPOSE_PHOTON, b, b0, b1, b2, b3);
    wf_poisson_ptrs_row53(rm, b0, b1, b2, b3, n, rk);
    int left = 0;
    for (int i = 0; i < n; i++) {
        if (rk[i] >= 0.0) {
            q[rx[i]] += rk[i];
            if (next_block) next_block[rx[i]] = (uint16_t)(b + 1);
            continue;
        }
        rx[left] = rx[i];
        rpx[left] = rpx[i];
        rm[left] = rm[i];
        left++;
    }
    return left;
}

/* Photon electrons of row y from their expectations e (>= 0), into q. Each pixel's stream
 * (pixel, read 0, photon) is used as before this path was batched: words 1 and 2 of its first
 * block give inversion below a mean of 10 or the first PTRS attempt above; a rejected attempt
 * goes on at block 1, 2, ... (two 53-bit uniforms per block, as wf_rng_poisson would draw
 * them). The first attempt and the retries run a row at a time (wf_poisson_ptrs_row,
 * wf_poisson_ptrs_row53); the retries, ~15% at a mean of 120, are compacted between rounds
 * and overwrite ro->words. next_block (when asked for) is where each stream stopped, for a
 * dark draw that goes on. */
static void single_photons(wf_readout *ro, int y, const double *e, double *q, uint16_t *next_block)
{
    const int nc = ro->cfg.ncols;
    const uint32_t *w1 = ro->words + nc, *w2 = ro->words + 2 * nc;
    uint32_t *rx = ro->retry_x, *rpx = ro->retry_px;
    double *rm = ro->retry_mean;
    wf_poisson_ptrs_row(e, w1, w2, nc, q);
    int nl = 0, nr = 0;
    for (int x = 0; x < nc; x++) { /* the columns left over, without a branch per column */
        rx[nl] = (uint32_t)x;
        nl += q[x] < 0.0;
    }
    for (int i = 0; i < nl; i++) {
        int x = (int)rx[i];
        double m = e[x];
        if (m < 10.0) { /* inversion from word 1 (no further stream); mean 0 gives 0 */
            more_noise unused = {0};
            q[x] = poisson_word(w1[x], NULL, m, exp(-m), &unused);
        } else { /* i >= nr: the list compacts onto itself */
            rx[nr] = (uint32_t)x;
            rpx[nr] = pixel_id(ro, y, x);
            rm[nr] = m;
            nr++;
        }
    }
    if (next_block)
        for (int x = 0; x < nc; x++) next_block[x] = 1;
    for (int i = 0; i < nr; i++) q[rx[i]] = 0.0; /* the retries' draws are added to it */
    for (uint32_t b = 1; nr > 0; b++) nr = ptrs_round(ro, b, nr, q, next_block);
}

/* Dark electrons of mean dark >= 10 for row y, each pixel's draw on from the block where
 * its photon draw left the stream (next_block): wf_rng_poisson's PTRS attempts, one block
 * each, a row batch at a time (as single_photons' retries). A pixel joins when the blocks
 * reach its own; a rejected one tries the next block. The words of the row are spent. */
static void single_dark(wf_readout *ro, int y, double dark, double *q)
{
    const int nc = ro->cfg.ncols;
    const uint16_t *nb = ro->next_block;
    uint32_t *rx = ro->retry_x, *rpx = ro->retry_px;
    double *rm = ro->retry_mean;
    uint32_t last = 0;
    for (int x = 0; x < nc; x++) last = nb[x] > last ? nb[x] : last;
    int n = 0; /* the pixels at block b */
    for (uint32_t b = 1; b < 65536 && (n > 0 || b <= last); b++) {
        const int had = n;
        for (int x = 0; b <= last && x < nc; x++) { /* those whose stream resumes here join */
            rx[n] = (uint32_t)x;
            n += nb[x] == b;
        }
        for (int i = had; i < n; i++) {
            rpx[i] = pixel_id(ro, y, (int)rx[i]);
            rm[i] = dark;
        }
        if (n) n = ptrs_round(ro, b, n, q, NULL);
    }
}

/* Row y (a halo row) up to its measured charge: Poisson of rate x t (negative rates set to
 * zero first), reciprocity failure on the counts, dark current (Poisson), full well,
 * nonlinearity. Tile rows also get their read-noise normals. */
static void single_charge_row(wf_readout *ro, int y, int y0, int y1, int h0)
{
    const wf_detector *d = &ro->cfg.det;
    const int nc = ro->cfg.ncols;
    const double t = ro->cfg.exptime;
    const float *rate = ro->rate + (size_t)(y - h0) * nc;
    double *q = ro->charge + (size_t)(y - h0) * nc;
    double *e = ro->expect;
    float *z = y >= y0 && y < y1 ? ro->gauss + (size_t)(y - y0) * nc : NULL;
    const int photons = d->on.photon_noise && !ro->noise_off;
    if (photons || (z && d->on.read_noise && !ro->noise_off)) {
        row_noise(ro, y, 0, WF_PURPOSE_PHOTON, 1, z && d->on.read_noise ? z : NULL);
    } else if (z) {
        memset(z, 0, (size_t)nc * sizeof *z);
    }
    wf_det_exposure_row(rate, t, nc, e);
    const double dark = d->dark_current * t;
    /* a dark mean >= 10 draws on from where the photon draw left the stream */
    const int dark_more = photons && d->on.dark && dark >= 10.0;
    if (d->on.dark && ro->dark_table) /* from word 3, before the photon retries reuse the words */
        wf_poisson_table_row(&ro->dark, ro->words + 3 * nc, nc, ro->dark_e);
    if (photons)
        single_photons(ro, y, e, q, dark_more ? ro->next_block : NULL);
    else
        memcpy(q, e, (size_t)nc * sizeof *q);
    int dark_done = 0;
    if (d->on.reciprocity) {
        if (ro->recip_ready) { /* whole counts; the dark electrons added on the way */
            dark_done = d->on.dark && ro->dark_table;
            wf_det_reciprocity_counts(d, t, ro->recip, RECIP_TABLE, dark_done ? ro->dark_e : NULL, nc, q);
        } else {
            for (int x = 0; x < nc; x++) q[x] = wf_det_reciprocity(q[x], t, d->recip_alpha, d->recip_f0);
        }
    }
    if (d->on.dark && !dark_done) {
        if (ro->dark_table) {
            for (int x = 0; x < nc; x++) q[x] += ro->dark_e[x];
        } else if (dark_more) {
            single_dark(ro, y, dark, q);
        } else if (!photons) { /* with photons on, a dark mean of 0 draws no electrons */
            for (int x = 0; x < nc; x++) q[x] += dark;
        }
    }
    wf_persist_single_row(&ro->persist, y, t, q);
    wf_det_measure_row(d, q, nc, ro->meas + (size_t)(y - h0) * nc);
}

/* Output row y: IPC from the measured rows around it, then read noise, gain, ADC. */
static void single_out_row(wf_readout *ro, int y, int y0, int h0, int h1)
{
    const int nc = ro->cfg.ncols;
    wf_det_single_row(&ro->cfg.det, ipc_row(ro, y, h0, h1), ro->charge + (size_t)(y - h0) * nc,
                      ro->gauss + (size_t)(y - y0) * nc, nc, ro->single_out + (size_t)(y - y0) * nc,
                      ro->sat + (size_t)(y - y0) * nc);
}

/* Row by row, so that a row's planes are still in cache when IPC and the ADC take it: each
 * output row goes out as soon as the row below it is measured. */
static wf_status single_frame(wf_readout *ro, int y0, int y1, int h0, int h1)
{
    for (int y = h0; y < h1; y++) {
        single_charge_row(ro, y, y0, y1, h0);
        if (y - 1 >= y0 && y - 1 < y1) single_out_row(ro, y - 1, y0, h0, h1);
    }
    if (h1 == y1) single_out_row(ro, y1 - 1, y0, h0, h1); /* the SCA's last row: none below */
    return WF_OK;
}

wf_status wf_readout_run_tile(wf_readout *ro, int tile)
{
    const wf_readout_config *cfg = &ro->cfg;
    if (tile < 0 || tile >= ro->ntiles)
        return wf_error(WF_ERR_RANGE, "readout: tile %d outside 0..%d", tile, ro->ntiles - 1);
    int y0 = tile * cfg->tile_rows;
    int y1 = y0 + cfg->tile_rows < cfg->nrows ? y0 + cfg->tile_rows : cfg->nrows;
    int h0 = y0 > 0 ? y0 - 1 : 0, h1 = y1 < cfg->nrows ? y1 + 1 : cfg->nrows;
    int nc = cfg->ncols, rows = y1 - y0, hn = (h1 - h0) * nc;
    wf_status st = wf_scene_fill(&ro->scene, h0, h1, nc, ro->rate);
    if (st) return st;
    int bad = wf_det_first_nonfinite(ro->rate, hn);
    if (bad >= 0)
        return wf_error(WF_ERR_INPUT, "scene: rate at row %d, column %d is not finite",
                        h0 + bad / nc, bad % nc);
    if (cfg->mode == WF_MODE_RAMP) { /* single frame writes every charge and sums nothing */
        memset(ro->charge, 0, (size_t)hn * sizeof *ro->charge);
        memset(ro->sum, 0, (size_t)rows * nc * sizeof *ro->sum);
        if (ro->refpix) memset(ro->side_sum, 0, (size_t)rows * 2 * WF_CN_BORDER * sizeof *ro->side_sum);
    }
    memset(ro->sat, 255, (size_t)rows * nc);
    if ((st = wf_persist_tile(&ro->persist, h0, h1))) return st;
    if (cfg->mode == WF_MODE_SINGLE) {
        if ((st = single_frame(ro, y0, y1, h0, h1))) return st;
        wf_persist_mark(&ro->persist, y0, y1, ro->sat, WF_SAT_PERSISTENCE);
        if ((st = send(ro, WF_PK_SINGLE, y0, rows, 1, ro->single_out, (size_t)rows * nc * sizeof(float))))
            return st;
    } else {
        ro->slope_any = 0;
        if (ro->slope && ro->scene.fill_slope) {
            if ((st = ro->scene.fill_slope(ro->scene.ctx, h0, h1, nc, ro->slope, &ro->slope_any))) return st;
            bad = ro->slope_any ? wf_det_first_nonfinite(ro->slope, hn) : -1;
            if (bad >= 0)
                return wf_error(WF_ERR_INPUT, "scene: rate slope at row %d, column %d is not finite", h0 + bad / nc,
                                bad % nc);
        }
        expected_per_frame(ro, hn);
        if (ro->cosmic_on && (st = wf_cosmic_tile(&ro->cosmic, h0, h1, y0, y1))) return st;
        st = cfg->sampling == WF_SAMPLE_PER_READ ? ramp_per_read(ro, y0, y1, h0, h1)
                                                 : ramp_grouped(ro, y0, y1, h0, h1);
        if (st) return st;
        wf_persist_mark(&ro->persist, y0, y1, ro->sat, WF_SAT_PERSISTENCE);
        /* SATURATION ahead of its RESULTANTS: the assembler then fits each row from the
         * resultants' packet as it arrives, and holds nothing of the tile after it */
        if ((st = send(ro, WF_PK_SATURATION, y0, rows, 1, ro->sat, (size_t)rows * nc))) return st;
        int nres = ro->clock.ma.nresultants; /* planes are packed [nres][rows][nc] */
        if (ro->refpix && (st = send_cols(ro, WF_PK_REFCOLS, y0, rows, 2 * WF_CN_BORDER, nres, ro->side_out,
                                          (size_t)nres * rows * 2 * WF_CN_BORDER * sizeof *ro->side_out)))
            return st;
        if ((st = send(ro, WF_PK_RESULTANTS, y0, rows, nres, ro->res_out,
                       (size_t)nres * rows * nc * sizeof(uint16_t))))
            return st;
        if (ro->cosmic_on && ro->cosmic.ntruth > 0 &&
            (st = send(ro, WF_PK_COSMIC, y0, rows, ro->cosmic.ntruth, ro->cosmic.truth,
                       (size_t)ro->cosmic.ntruth * sizeof(wf_cosmic_record))))
            return st;
        return WF_OK;
    }
    return send(ro, WF_PK_SATURATION, y0, rows, 1, ro->sat, (size_t)rows * nc);
}

static int append(char *buf, size_t cap, size_t *len, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

static int append(char *buf, size_t cap, size_t *len, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(buf + *len, *len < cap ? cap - *len : 0, fmt, ap);
    va_end(ap);
    if (n < 0 || *len + (size_t)n >= cap) return -1;
    *len += (size_t)n;
    return 0;
}

wf_status wf_readout_send_meta(wf_readout *ro, const char *extra)
{
    const wf_readout_config *c = &ro->cfg;
    const wf_detector *d = &c->det;
    /* The text's own room, counted in the arena need and given back once it is sent: the
     * META does not depend on the detector's size, so no tile buffer is the right size for
     * it (a 1 x 1 SCA's are a few bytes). */
    size_t mark = wf_arena_mark(ro->arena), cap = WF_READOUT_META_MAX, len = 0;
    void *text;
    wf_status st = wf_arena_reserve(ro->arena, cap, "META text", &text);
    if (st) return st;
    char *buf = text;
    int bad = 0;
    bad |= append(buf, cap, &len,
                  "ncols = %d\nnrows = %d\nmode = %s\nsampling = %s\nexposure = %u\nsca = %u\n"
                  "seed = %llu\nframe_time = %.17g\nexptime = %.17g\n",
                  c->ncols, c->nrows, c->mode == WF_MODE_RAMP ? "ramp" : "single",
                  wf_sampling_name(c->sampling), c->exposure, c->sca,
                  (unsigned long long)c->seed, ro->clock.frame_time, exposure_time(c, &ro->clock));
    if (c->mode == WF_MODE_RAMP) {
        const wf_ma_table *ma = &ro->clock.ma;
        bad |= append(buf, cap, &len, "ma_table = %s\nma_reads = ", ma->name);
        for (int r = 0; r < ma->nresultants; r++) {
            int a = ma->read[ma->first[r]] + 1, prev = a;
            bad |= append(buf, cap, &len, "%s%d", r ? "|" : "", a);
            for (int j = ma->first[r] + 1; j <= ma->first[r + 1]; j++) {
                int v = j < ma->first[r + 1] ? ma->read[j] + 1 : -1;
                if (v == prev + 1) { prev = v; continue; }
                if (prev != a) bad |= append(buf, cap, &len, "-%d", prev);
                if (v > 0) { bad |= append(buf, cap, &len, ",%d", v); a = prev = v; }
            }
        }
        bad |= append(buf, cap, &len, "\n");
    }
    if (corr_on(c)) /* only then: products of a run without them keep their bytes */
        bad |= append(buf, cap, &len, "rn1f_corr = %.17g\nrn1f_uncorr = %.17g\nchannel_offset = %.17g\n",
                      d->on.read_1f ? d->rn1f_corr_e : 0.0, d->on.read_1f ? d->rn1f_uncorr_e : 0.0,
                      d->on.channel_offsets ? d->channel_offset_adu : 0.0);
    bad |= append(buf, cap, &len,
                  "gain = %.17g\nread_noise = %.17g\ndark_current = %.17g\nfull_well = %.17g\n"
                  "adc_max = %.17g\nbias = %.17g\nsaturation_adu = %.17g\nnl_beta = %.17g\neffects = ",
                  d->gain, d->read_noise_e, d->dark_current, d->full_well, d->adc_max, d->bias_adu,
                  wf_det_saturation_adu(d), d->nl_beta);
    const char *names[] = {"photon", "reciprocity", "dark", "nonlinearity", "ipc", "read_noise",
                           "quantize", "saturation", "cosmic", "read_1f", "channel_offsets", "refpix",
                           "persistence"};
    const int on[] = {d->on.photon_noise, d->on.reciprocity, d->on.dark, d->on.nonlinearity,
                      d->on.ipc, d->on.read_noise, d->on.quantize, d->on.saturation,
                      d->on.cosmic_rays && c->mode == WF_MODE_RAMP, d->on.read_1f, d->on.channel_offsets,
                      d->on.refpix, wf_persist_active(&c->persist)};
    int first = 1;
    for (int i = 0; i < (int)(sizeof on / sizeof on[0]); i++)
        if (on[i]) { bad |= append(buf, cap, &len, "%s%s", first ? "" : ",", names[i]); first = 0; }
    bad |= append(buf, cap, &len, "\n%s", extra ? extra : "");
    st = bad ? wf_error(WF_ERR_RANGE, "readout: META text longer than %zu bytes (extra lines: %zu bytes)", cap,
                        extra ? strlen(extra) : (size_t)0)
             : send(ro, WF_PK_META, 0, 0, 0, buf, len);
    wf_arena_release(ro->arena, mark);
    if (!st && ro->refpix) st = send_refrows(ro);
    return st;
}

wf_status wf_readout_send_end(wf_readout *ro)
{
    return send(ro, WF_PK_END, 0, ro->cfg.nrows, 0, NULL, 0);
}
