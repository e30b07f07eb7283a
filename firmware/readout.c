#include "firmware/readout.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "firmware/cosmic.h"
#include "hal/packet.h"


struct wf_readout {
    wf_readout_config cfg;
    wf_clock clock;
    wf_scene_source scene;
    wf_noise noise;
    wf_link link;
    int ntiles, halo_cap;          /* rows the halo block can hold: tile_rows + 2 */
    int total_reads;
    int16_t resultant_of_read[WF_MA_MAX_READS]; /* -1: read not digitised */
    float *rate;                   /* halo block, e-/pixel/s from the scene */
    double *mean;                  /* halo block, expected e- per frame time */
    double *charge;                /* halo block, collected e- */
    double *meas;                  /* halo block, measured e- at this read */
    double *expm;                  /* halo block, exp(-mean) for one-frame Poisson inversion */
    float *gauss;                  /* tile rows, this read's standard normal for read noise */
    uint32_t *words;               /* [4][ncols]: first Philox block of each pixel's stream */
    int noise_off;                 /* WF_NOISE_OFF: draws are expectations */
    double *row;                   /* one row after IPC */
    double *sum;                   /* tile rows, ADU summed over the resultant's reads */
    uint16_t *res_out;             /* [nres][tile_rows][ncols] */
    float *single_out;             /* [tile_rows][ncols] */
    uint8_t *sat;                  /* [tile_rows][ncols] */
    wf_cosmic cosmic;
    int cosmic_on;
    wf_packer packer;
};

static int nres_of(const wf_readout_config *cfg, const wf_clock *clock)
{
    return cfg->mode == WF_MODE_RAMP ? clock->ma.nresultants : 1;
}

static double exposure_time(const wf_readout_config *cfg, const wf_clock *clock)
{
    return cfg->mode == WF_MODE_RAMP ? wf_clock_exposure_time(clock) : cfg->exptime;
}

static size_t tile_payload_max(const wf_readout_config *cfg, const wf_clock *clock)
{
    size_t px = (size_t)cfg->tile_rows * (size_t)cfg->ncols;
    size_t res = px * sizeof(uint16_t) * (size_t)nres_of(cfg, clock);
    size_t single = px * sizeof(float);
    return res > single ? res : single;
}

static int direct_blocks(const wf_ma_table *ma);

/* Noise blocks per row the mode needs at once: one, or enough for a whole group. */
static int words_blocks(const wf_readout_config *cfg, const wf_clock *clock)
{
    return cfg->mode == WF_MODE_RAMP && cfg->sampling == WF_SAMPLE_DIRECT ? direct_blocks(&clock->ma) : 1;
}

static wf_status check_config(const wf_readout_config *cfg, const wf_clock *clock)
{
    if (cfg->ncols < 1 || cfg->nrows < 1 || cfg->ncols > 65536 || cfg->nrows > 65536)
        return wf_error(WF_ERR_RANGE, "readout: SCA of %d x %d pixels", cfg->ncols, cfg->nrows);
    if (cfg->tile_rows < 1)
        return wf_error(WF_ERR_RANGE, "readout: tile_rows %d < 1", cfg->tile_rows);
    if (cfg->mode == WF_MODE_RAMP && clock->ma.nresultants < 1)
        return wf_error(WF_ERR_INPUT, "readout: MA table has no resultants");
    if (cfg->mode == WF_MODE_SINGLE && !(cfg->exptime > 0.0))
        return wf_error(WF_ERR_RANGE, "readout: exposure time %g s must be > 0", cfg->exptime);
    if (!(clock->frame_time > 0.0))
        return wf_error(WF_ERR_RANGE, "readout: frame time %g s must be > 0", clock->frame_time);
    if (!(cfg->det.gain > 0.0))
        return wf_error(WF_ERR_RANGE, "readout: gain %g e-/ADU must be > 0", cfg->det.gain);
    return WF_OK;
}

wf_status wf_readout_arena_need(const wf_readout_config *cfg, const wf_clock *clock,
                                size_t *bytes)
{
    wf_status st = check_config(cfg, clock);
    if (st) return st;
    size_t halo = (size_t)(cfg->tile_rows + 2) * (size_t)cfg->ncols;
    size_t tile = (size_t)cfg->tile_rows * (size_t)cfg->ncols;
    size_t n = wf_arena_cost(sizeof(wf_readout));
    n += wf_arena_cost(halo * sizeof(float));
    n += 4 * wf_arena_cost(halo * sizeof(double));
    n += wf_arena_cost(tile * sizeof(float));
    n += wf_arena_cost(4 * (size_t)words_blocks(cfg, clock) * (size_t)cfg->ncols * sizeof(uint32_t));
    n += wf_arena_cost((size_t)cfg->ncols * sizeof(double));
    n += wf_arena_cost(tile * sizeof(double));
    if (cfg->mode == WF_MODE_RAMP)
        n += wf_arena_cost(tile * sizeof(uint16_t) * (size_t)clock->ma.nresultants);
    else
        n += wf_arena_cost(tile * sizeof(float));
    n += wf_arena_cost(tile);
    n += wf_packer_arena_need(tile_payload_max(cfg, clock), cfg->compress);
    if (cfg->det.on.cosmic_rays && cfg->mode == WF_MODE_RAMP) {
        size_t cr;
        wf_cosmic_arena_need(&cfg->det, cfg->ncols, cfg->tile_rows, exposure_time(cfg, clock), &cr);
        n += cr;
    }
    *bytes = n + 4096; /* alignment of the block itself */
    return WF_OK;
}

#define TAKE(ptr, count, what)                                                        \
    do {                                                                              \
        void *p_;                                                                     \
        st = wf_arena_calloc(arena, (size_t)(count), sizeof *(ptr), what, &p_);       \
        if (st) return st;                                                            \
        (ptr) = p_;                                                                   \
    } while (0)

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
    ro->ntiles = (cfg->nrows + cfg->tile_rows - 1) / cfg->tile_rows;
    ro->halo_cap = cfg->tile_rows + 2;
    size_t halo = (size_t)ro->halo_cap * (size_t)cfg->ncols;
    size_t tile = (size_t)cfg->tile_rows * (size_t)cfg->ncols;
    TAKE(ro->rate, halo, "rate rows");
    TAKE(ro->mean, halo, "expected electrons");
    TAKE(ro->charge, halo, "collected charge");
    TAKE(ro->meas, halo, "measured charge");
    TAKE(ro->expm, halo, "Poisson inversion start");
    TAKE(ro->gauss, tile, "read-noise normals");
    TAKE(ro->words, 4 * (size_t)words_blocks(cfg, clock) * (size_t)cfg->ncols, "noise words");
    ro->noise_off = noise->kind == WF_NOISE_OFF;
    TAKE(ro->row, cfg->ncols, "IPC row");
    TAKE(ro->sum, tile, "resultant sums");
    if (cfg->mode == WF_MODE_RAMP) {
        TAKE(ro->res_out, tile * (size_t)clock->ma.nresultants, "resultant tile");
        ro->total_reads = wf_ma_total_reads(&clock->ma);
        for (int i = 0; i < WF_MA_MAX_READS; i++) ro->resultant_of_read[i] = -1;
        for (int r = 0; r < clock->ma.nresultants; r++)
            for (int j = clock->ma.first[r]; j < clock->ma.first[r + 1]; j++)
                ro->resultant_of_read[clock->ma.read[j]] = (int16_t)r;
    } else {
        TAKE(ro->single_out, tile, "single-frame tile");
    }
    TAKE(ro->sat, tile, "saturation map");
    st = wf_packer_init(&ro->packer, arena, tile_payload_max(cfg, clock), cfg->compress);
    if (st) return st;
    ro->cosmic_on = cfg->det.on.cosmic_rays && cfg->mode == WF_MODE_RAMP && cfg->det.cr_rate > 0;
    if (ro->cosmic_on) {
        st = wf_cosmic_init(&ro->cosmic, &ro->cfg.det, noise, cfg->ncols, cfg->nrows,
                            cfg->tile_rows, exposure_time(cfg, clock), clock->frame_time,
                            ro->total_reads, arena);
        if (st) return st;
    }
    *out = ro;
    return WF_OK;
}

int wf_readout_tile_count(const wf_readout *ro) { return ro->ntiles; }

void wf_readout_destroy(wf_readout *ro)
{
    if (ro) wf_packer_close(&ro->packer);
}

static wf_status send(wf_readout *ro, wf_packet_kind kind, int y0, int rows, int nplanes,
                      const void *payload, size_t len)
{
    wf_packet_header h = {0};
    h.kind = (uint16_t)kind;
    h.exposure = ro->cfg.exposure;
    h.sca = (uint16_t)ro->cfg.sca;
    h.first_row = (uint32_t)y0;
    h.row_count = (uint32_t)rows;
    h.ncols = (uint32_t)ro->cfg.ncols;
    h.nplanes = (uint32_t)nplanes;
    return wf_packer_send(&ro->packer, &ro->link, &h, payload, len);
}

/* ---- shared per-pixel steps ------------------------------------------------------------ */

/* Expected electrons per frame time from the scene rate: reciprocity failure acts on the
 * rate (q = r t obeys the same law at every t), dark current is added after it. */
static void expected_per_frame(wf_readout *ro, int npix)
{
    const wf_detector *d = &ro->cfg.det;
    double ft = ro->clock.frame_time;
    for (int i = 0; i < npix; i++) {
        double r = ro->rate[i] > 0.0f ? ro->rate[i] : 0.0;
        if (d->on.reciprocity) r = wf_det_reciprocity_rate(r, d->recip_alpha, d->recip_f0);
        if (d->on.dark) r += d->dark_current;
        ro->mean[i] = r * ft;
        ro->expm[i] = exp(-ro->mean[i]);
    }
}

/* Each (pixel, read) has one stream. Its first block, computed a row at a time by
 * wf_noise_block_row, serves the common case: word 0 is the read-noise normal, words 1-3
 * the uniforms of Poisson draws by inversion. Draws that need more (PTRS above a mean of
 * 10) continue the same stream after the blocks the batch took, created on first use. */
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

/* Full well and nonlinearity: what the read-out would measure from the charge. */
static void measure(wf_readout *ro, const double *charge, int npix)
{
    const wf_detector *d = &ro->cfg.det;
    for (int i = 0; i < npix; i++) {
        double q = charge[i];
        if (d->on.saturation && q > d->full_well) q = d->full_well;
        if (d->on.nonlinearity) q = wf_det_nonlinearity(q, d->nl_beta);
        ro->meas[i] = q;
    }
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

/* Read noise, gain, ADC. Returns ADU; sets *clipped when the ADC saturated. */
static inline double digitise(const wf_detector *d, double e, double noise_sigma, double z,
                              int *clipped)
{
    if (d->on.read_noise) e += noise_sigma * z;
    double adu = e / d->gain + d->bias_adu;
    if (d->on.quantize) adu = wf_det_quantize(adu);
    if (d->on.saturation) {
        if (adu >= d->adc_max) { adu = d->adc_max; *clipped = 1; }
        if (adu < 0.0) adu = 0.0;
    }
    return adu;
}

static uint32_t pixel_id(const wf_readout *ro, int y, int x)
{
    return (uint32_t)y * (uint32_t)ro->cfg.ncols + (uint32_t)x;
}

static uint16_t to_u16(double v)
{
    v = nearbyint(v);
    if (v < 0.0) return 0;
    if (v > 65535.0) return 65535;
    return (uint16_t)v;
}

/* ---- up-the-ramp, read by read --------------------------------------------------------- */

static wf_status ramp_per_read(wf_readout *ro, int y0, int y1, int h0, int h1)
{
    const wf_detector *d = &ro->cfg.det;
    const int nc = ro->cfg.ncols, rows = y1 - y0, hn = (h1 - h0) * nc;
    const size_t plane = (size_t)rows * nc;
    int next_dep = 0, prev_read = -1;
    for (int k = 0; k < ro->total_reads; k++) {
        int r = ro->resultant_of_read[k];
        if (r < 0) continue; /* charge of skipped reads is drawn with the next digitised one */
        double frames = k - prev_read;
        prev_read = k;
        for (int y = h0; y < h1; y++) {
            double *q = ro->charge + (size_t)(y - h0) * nc;
            const double *m = ro->mean + (size_t)(y - h0) * nc;
            const double *em = ro->expm + (size_t)(y - h0) * nc;
            float *z = y >= y0 && y < y1 ? ro->gauss + (size_t)(y - y0) * nc : NULL;
            int photons = d->on.photon_noise && !ro->noise_off;
            if (photons || (z && d->on.read_noise && !ro->noise_off)) {
                row_noise(ro, y, (uint32_t)k, WF_PURPOSE_PHOTON, 1, z && d->on.read_noise ? z : NULL);
            } else if (z) {
                memset(z, 0, (size_t)nc * sizeof *z);
            }
            if (!photons) {
                for (int x = 0; x < nc; x++) q[x] += m[x] * frames;
                continue;
            }
            const uint32_t *w1 = ro->words + nc, *w2 = ro->words + 2 * nc;
            for (int x = 0; x < nc; x++) {
                double mean = m[x] * frames;
                more_noise mn = {.noise = &ro->noise, .pixel = pixel_id(ro, y, x), .read = (uint32_t)k,
                                 .purpose = WF_PURPOSE_PHOTON};
                q[x] += poisson_word(w1[x], &w2[x], mean, frames == 1.0 ? em[x] : exp(-mean), &mn);
            }
        }
        if (ro->cosmic_on)
            for (; next_dep < ro->cosmic.ndeposits && (int)ro->cosmic.deposits[next_dep].read <= k; next_dep++)
                ro->charge[ro->cosmic.deposits[next_dep].pixel] += ro->cosmic.deposits[next_dep].electrons;
        if (d->on.saturation)
            for (int i = 0; i < hn; i++)
                if (ro->charge[i] > d->full_well) ro->charge[i] = d->full_well;
        measure(ro, ro->charge, hn);
        int last_of_resultant = ro->clock.ma.read[ro->clock.ma.first[r + 1] - 1] == k;
        int nreads = ro->clock.ma.first[r + 1] - ro->clock.ma.first[r];
        for (int y = y0; y < y1; y++) {
            const double *v = ipc_row(ro, y, h0, h1);
            const double *q = ro->charge + (size_t)(y - h0) * nc;
            double *s = ro->sum + (size_t)(y - y0) * nc;
            uint8_t *sat = ro->sat + (size_t)(y - y0) * nc;
            uint16_t *out = ro->res_out + (size_t)r * plane + (size_t)(y - y0) * nc;
            const float *z = ro->gauss + (size_t)(y - y0) * nc;
            for (int x = 0; x < nc; x++) {
                int clipped = d->on.saturation && q[x] >= d->full_well;
                s[x] += digitise(d, v[x], d->read_noise_e, z[x], &clipped);
                if (clipped && sat[x] == 255) sat[x] = (uint8_t)r;
                if (last_of_resultant) {
                    out[x] = to_u16(s[x] / nreads);
                    s[x] = 0.0;
                }
            }
        }
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

static wf_status ramp_direct(wf_readout *ro, int y0, int y1, int h0, int h1)
{
    const wf_detector *d = &ro->cfg.det;
    const wf_ma_table *ma = &ro->clock.ma;
    const int nc = ro->cfg.ncols, rows = y1 - y0, hn = (h1 - h0) * nc;
    const size_t plane = (size_t)rows * nc;
    const int nblocks = direct_blocks(ma);
    double *avg = ro->meas; /* reused: average charge of the group, then measured */
    int next_dep = 0, prev_read = -1;
    for (int r = 0; r < ma->nresultants; r++) {
        const int *reads = ma->read + ma->first[r];
        int n = ma->first[r + 1] - ma->first[r];
        double lead = reads[0] - prev_read, span = reads[n - 1] - reads[0];
        prev_read = reads[n - 1];
        double seen = 0.0; /* frames of charge each read of the group adds, averaged */
        for (int j = 1; j < n; j++) seen += (reads[j] - reads[j - 1]) * (double)(n - j) / n;
        for (int y = h0; y < h1; y++) {
            double *q = ro->charge + (size_t)(y - h0) * nc;
            double *a = avg + (size_t)(y - h0) * nc;
            const double *m = ro->mean + (size_t)(y - h0) * nc;
            const double *em = ro->expm + (size_t)(y - h0) * nc;
            float *z = y >= y0 && y < y1 ? ro->gauss + (size_t)(y - y0) * nc : NULL;
            int photons = d->on.photon_noise && !ro->noise_off;
            if (photons || (z && d->on.read_noise && !ro->noise_off)) {
                row_noise(ro, y, (uint32_t)r, WF_PURPOSE_RESULTANT, photons ? nblocks : 1,
                          z && d->on.read_noise ? z : NULL);
            } else if (z) {
                memset(z, 0, (size_t)nc * sizeof *z);
            }
            for (int x = 0; x < nc; x++) {
                if (!photons) {
                    q[x] += m[x] * lead;
                    a[x] = q[x] + m[x] * seen;
                    q[x] += m[x] * span;
                    continue;
                }
                more_noise mn = {.noise = &ro->noise, .pixel = pixel_id(ro, y, x), .read = (uint32_t)r,
                                 .purpose = WF_PURPOSE_RESULTANT, .first_block = (uint32_t)nblocks};
                /* Exact for a linear pixel: the charge before the group's first read, then
                 * each interval's Poisson electrons, seen by the n - j reads from j on. */
                int c = 1;
                double lm = m[x] * lead;
                q[x] += draw_at(ro->words, (size_t)nc, x, &c, lm, lead == 1.0 ? em[x] : exp(-lm), &mn);
                double within = 0.0, total = 0.0;
                for (int j = 1; j < n; j++) {
                    int gap = reads[j] - reads[j - 1];
                    double mj = m[x] * gap;
                    double dj = draw_at(ro->words, (size_t)nc, x, &c, mj, gap == 1 ? em[x] : exp(-mj), &mn);
                    within += dj * (double)(n - j);
                    total += dj;
                }
                a[x] = q[x] + within / n;
                q[x] += total;
            }
        }
        if (ro->cosmic_on)
            for (; next_dep < ro->cosmic.ndeposits && (int)ro->cosmic.deposits[next_dep].read <= reads[n - 1]; next_dep++) {
                const wf_cr_deposit *dp = &ro->cosmic.deposits[next_dep];
                int later = 0; /* reads of the group that see the hit */
                for (int j = 0; j < n; j++) later += reads[j] >= (int)dp->read;
                ro->charge[dp->pixel] += dp->electrons;
                avg[dp->pixel] += dp->electrons * later / n;
            }
        for (int i = 0; i < hn; i++) {
            if (d->on.saturation && ro->charge[i] > d->full_well) ro->charge[i] = d->full_well;
            if (d->on.saturation && avg[i] > d->full_well) avg[i] = d->full_well;
        }
        measure(ro, avg, hn);
        for (int y = y0; y < y1; y++) {
            const double *v = ipc_row(ro, y, h0, h1);
            const double *q = ro->charge + (size_t)(y - h0) * nc;
            uint8_t *sat = ro->sat + (size_t)(y - y0) * nc;
            uint16_t *out = ro->res_out + (size_t)r * plane + (size_t)(y - y0) * nc;
            const float *z = ro->gauss + (size_t)(y - y0) * nc;
            for (int x = 0; x < nc; x++) {
                /* A resultant holds a saturated read when its last read did: the charge at
                 * that read reached the well, or its measured signal the ADC ceiling. */
                int clipped = 0;
                if (d->on.saturation) {
                    double last = q[x] < d->full_well ? q[x] : d->full_well;
                    if (d->on.nonlinearity) last = wf_det_nonlinearity(last, d->nl_beta);
                    clipped = q[x] >= d->full_well || last / d->gain + d->bias_adu >= d->adc_max;
                }
                /* the mean of n reads' independent read noise is N(0, sigma^2 / n) */
                double adu = digitise(d, v[x], d->read_noise_e / sqrt((double)n), z[x], &clipped);
                if (clipped && sat[x] == 255) sat[x] = (uint8_t)r;
                out[x] = to_u16(adu);
            }
        }
    }
    return WF_OK;
}

/* ---- single frame (GalSim allDetectorEffects order) ------------------------------------ */

static wf_status single_frame(wf_readout *ro, int y0, int y1, int h0, int h1)
{
    const wf_detector *d = &ro->cfg.det;
    const int nc = ro->cfg.ncols;
    const double t = ro->cfg.exptime;
    for (int y = h0; y < h1; y++) {
        const float *rate = ro->rate + (size_t)(y - h0) * nc;
        double *q = ro->charge + (size_t)(y - h0) * nc;
        float *z = y >= y0 && y < y1 ? ro->gauss + (size_t)(y - y0) * nc : NULL;
        int photons = d->on.photon_noise && !ro->noise_off;
        if (photons || (z && d->on.read_noise && !ro->noise_off)) {
            row_noise(ro, y, 0, WF_PURPOSE_PHOTON, 1, z && d->on.read_noise ? z : NULL);
        } else if (z) {
            memset(z, 0, (size_t)nc * sizeof *z);
        }
        const uint32_t *w1 = ro->words + nc, *w2 = ro->words + 2 * nc, *w3 = ro->words + 3 * nc;
        const double dark = d->dark_current * t, edark = exp(-dark);
        for (int x = 0; x < nc; x++) {
            double e = rate[x] > 0.0f ? rate[x] * t : 0.0; /* negative set to zero before Poisson */
            more_noise mn = {.noise = &ro->noise, .pixel = pixel_id(ro, y, x), .read = 0,
                             .purpose = WF_PURPOSE_PHOTON};
            if (photons) e = poisson_word(w1[x], &w2[x], e, e < 10.0 ? exp(-e) : 0.0, &mn);
            if (d->on.reciprocity) e = wf_det_reciprocity(e, t, d->recip_alpha, d->recip_f0);
            if (d->on.dark) e += photons ? poisson_word(w3[x], NULL, dark, edark, &mn) : dark;
            q[x] = e;
        }
    }
    measure(ro, ro->charge, (h1 - h0) * nc);
    for (int y = y0; y < y1; y++) {
        const double *v = ipc_row(ro, y, h0, h1);
        const double *q = ro->charge + (size_t)(y - h0) * nc;
        float *out = ro->single_out + (size_t)(y - y0) * nc;
        uint8_t *sat = ro->sat + (size_t)(y - y0) * nc;
        const float *z = ro->gauss + (size_t)(y - y0) * nc;
        for (int x = 0; x < nc; x++) {
            int clipped = d->on.saturation && q[x] >= d->full_well;
            out[x] = (float)digitise(d, v[x], d->read_noise_e, z[x], &clipped);
            if (clipped) sat[x] = 0;
        }
    }
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
    for (int i = 0; i < hn; i++)
        if (!isfinite(ro->rate[i]))
            return wf_error(WF_ERR_INPUT, "scene: rate at row %d, column %d is not finite",
                            h0 + i / nc, i % nc);
    memset(ro->charge, 0, (size_t)hn * sizeof *ro->charge);
    memset(ro->sum, 0, (size_t)rows * nc * sizeof *ro->sum);
    memset(ro->sat, 255, (size_t)rows * nc);
    if (cfg->mode == WF_MODE_SINGLE) {
        if ((st = single_frame(ro, y0, y1, h0, h1))) return st;
        if ((st = send(ro, WF_PK_SINGLE, y0, rows, 1, ro->single_out, (size_t)rows * nc * sizeof(float))))
            return st;
    } else {
        expected_per_frame(ro, hn);
        if (ro->cosmic_on && (st = wf_cosmic_tile(&ro->cosmic, h0, h1, y0, y1))) return st;
        st = cfg->sampling == WF_SAMPLE_DIRECT ? ramp_direct(ro, y0, y1, h0, h1)
                                               : ramp_per_read(ro, y0, y1, h0, h1);
        if (st) return st;
        int nres = ro->clock.ma.nresultants; /* planes are packed [nres][rows][nc] */
        if ((st = send(ro, WF_PK_RESULTANTS, y0, rows, nres, ro->res_out,
                       (size_t)nres * rows * nc * sizeof(uint16_t))))
            return st;
        if (ro->cosmic_on && ro->cosmic.ntruth > 0 &&
            (st = send(ro, WF_PK_COSMIC, y0, rows, ro->cosmic.ntruth, ro->cosmic.truth,
                       (size_t)ro->cosmic.ntruth * sizeof(wf_cosmic_record))))
            return st;
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
    /* The resultant tile buffer is idle between tiles and large enough for the text. */
    char *buf = (char *)ro->sum;
    size_t cap = (size_t)c->tile_rows * c->ncols * sizeof(double), len = 0;
    int bad = 0;
    bad |= append(buf, cap, &len,
                  "ncols = %d\nnrows = %d\nmode = %s\nsampling = %s\nexposure = %u\nsca = %u\n"
                  "seed = %llu\nframe_time = %.17g\nexptime = %.17g\n",
                  c->ncols, c->nrows, c->mode == WF_MODE_RAMP ? "ramp" : "single",
                  c->sampling == WF_SAMPLE_DIRECT ? "direct" : "per-read", c->exposure, c->sca,
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
    bad |= append(buf, cap, &len,
                  "gain = %.17g\nread_noise = %.17g\ndark_current = %.17g\nfull_well = %.17g\n"
                  "adc_max = %.17g\nbias = %.17g\nsaturation_adu = %.17g\nnl_beta = %.17g\neffects = ",
                  d->gain, d->read_noise_e, d->dark_current, d->full_well, d->adc_max, d->bias_adu,
                  wf_det_saturation_adu(d), d->nl_beta);
    const char *names[] = {"photon", "reciprocity", "dark", "nonlinearity", "ipc", "read_noise",
                           "quantize", "saturation", "cosmic"};
    const int on[] = {d->on.photon_noise, d->on.reciprocity, d->on.dark, d->on.nonlinearity,
                      d->on.ipc, d->on.read_noise, d->on.quantize, d->on.saturation,
                      d->on.cosmic_rays && c->mode == WF_MODE_RAMP};
    int first = 1;
    for (int i = 0; i < 9; i++)
        if (on[i]) { bad |= append(buf, cap, &len, "%s%s", first ? "" : ",", names[i]); first = 0; }
    bad |= append(buf, cap, &len, "\n%s", extra ? extra : "");
    if (bad)
        return wf_error(WF_ERR_RANGE, "readout: META text longer than %zu bytes", cap);
    return send(ro, WF_PK_META, 0, 0, 0, buf, len);
}

wf_status wf_readout_send_end(wf_readout *ro)
{
    return send(ro, WF_PK_END, 0, ro->cfg.nrows, 0, NULL, 0);
}
