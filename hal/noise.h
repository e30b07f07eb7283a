/* Noise source: a counter-based generator (Philox4x32-10, Salmon et al. 2011).
 * Every draw is a pure function of (seed, exposure, SCA, pixel, read, purpose, draw index):
 *   key     = seed (64 bits)
 *   counter = { pixel, read, exposure, SCA<<24 | purpose<<16 | block }
 * so a pixel gets the same numbers whichever tile, thread or process computes it. That is what
 * makes products independent of tile height and lets halo rows be recomputed by both tiles.
 *
 * The hot path needs inline draws, so the interface is a value type (wf_noise) and a stream
 * (wf_rng) rather than a table of function pointers; WF_NOISE_OFF is the second
 * implementation: every draw returns its expectation (Poisson -> mean, Gaussian -> 0), which
 * gives noiseless images for closed-form tests. */
#ifndef WF_NOISE_H
#define WF_NOISE_H

#include <stddef.h>
#include <stdint.h>
#include "hal/status.h"

typedef enum {
    WF_PURPOSE_PHOTON = 1,    /* Poisson electrons from sky, objects and dark */
    WF_PURPOSE_READ = 2,      /* read noise */
    WF_PURPOSE_COSMIC = 3,    /* cosmic-ray hits */
    WF_PURPOSE_RESULTANT = 4, /* direct-resultant sampling of the within-group sum */
    WF_PURPOSE_SCENE = 5,     /* scene randomness (knots, positions) */
    WF_PURPOSE_SN = 6,        /* supernova sample: pixel = SN index, read = which draw (sim/sn/) */
    WF_PURPOSE_PERSIST = 7,   /* persistence: electrons released over the interval ending at read */
    WF_PURPOSE_1F_TREE = 8,   /* correlated read noise: bridge nodes, channel offsets (firmware/corrnoise.c) */
    WF_PURPOSE_1F_STEP = 9,   /* correlated read noise: steps along a row, reference pixels' read noise */
    WF_PURPOSE_MOMENTS = 10,  /* moments sampling: one block per (pixel, resultant) (firmware/readout.c) */
    WF_PURPOSE_PHOTON_PAIR = 11, /* per-read sampling: one block per read for pixels x and x + ncols/2 of a row */
    WF_PURPOSE_TEST = 15
} wf_purpose;

typedef enum { WF_NOISE_PHILOX = 0, WF_NOISE_OFF = 1 } wf_noise_kind;

typedef struct wf_noise {
    wf_noise_kind kind;
    uint64_t seed;
    uint32_t exposure;
    uint32_t sca;
} wf_noise;

typedef struct wf_rng {
    uint32_t key[2];
    uint32_t ctr[4];
    uint32_t buf[4];
    unsigned next; /* index into buf; 4 = empty */
    int off;       /* WF_NOISE_OFF: draws return expectations */
} wf_rng;

/* One Philox4x32-10 block. */
void wf_philox4x32(const uint32_t ctr[4], const uint32_t key[2], uint32_t out[4]);

/* A stream for one (pixel, read, purpose). pixel = y * ncols + x on the full SCA. */
void wf_rng_init(wf_rng *rng, const wf_noise *noise, uint32_t pixel, uint32_t read,
                 wf_purpose purpose);

uint32_t wf_rng_u32(wf_rng *rng);
double wf_rng_uniform(wf_rng *rng);   /* (0, 1), 32-bit resolution */
double wf_rng_uniform53(wf_rng *rng); /* (0, 1), 53-bit resolution */

/* wf_rng_uniform53 from its two words in turn, for code that has the words in a batch:
 * 27 + 26 bits, each part exact in a double, so the sum is the integer the scalar code
 * converts. Above 2^52, x + 0.5 rounds to even, and x = 2^53 - 1 would give exactly 1.0: the
 * interval stays open with the largest double below 1. */
static inline double wf_uniform53_words(uint32_t w0, uint32_t w1)
{
    double u = ((double)(w0 >> 5) * 67108864.0 + (double)(w1 >> 6) + 0.5) * (1.0 / 9007199254740992.0);
    return u < 1.0 ? u : 0x1.fffffffffffffp-1;
}
double wf_rng_gauss(wf_rng *rng);     /* N(0, 1) */
/* Poisson(mean): exact inversion below 10, Hörmann's PTRS rejection above (exact in
 * distribution; log-probabilities via a Stirling form accurate to ~1e-10 up to 1e9 and
 * beyond). mean <= 0 or NaN gives 0, as GalSim sets negative values to zero. */
double wf_rng_poisson(wf_rng *rng, double mean);

/* Positions a stream at block `block` (0 is where wf_rng_init starts): lets code that took
 * the first block from wf_noise_block_row continue the same stream. */
void wf_rng_seek(wf_rng *rng, uint32_t block);

/* Block `block` (4 words) of the streams of pixels pixel0 .. pixel0+n-1 at one read, for one
 * purpose: identical to wf_rng_init + wf_rng_seek(block) + 4 x wf_rng_u32, a row at a time. */
void wf_noise_block_row(const wf_noise *noise, uint32_t pixel0, int n, uint32_t read,
                        wf_purpose purpose, uint32_t block, uint32_t *w0, uint32_t *w1,
                        uint32_t *w2, uint32_t *w3);

/* Blocks block0 .. block0 + n - 1 of the stream of (pixel, read, purpose): word j of block
 * block0 + b in wj[b], the words wf_rng_u32 gives after wf_rng_seek(block0), for a stream
 * that takes many at once. WF_ERR_RANGE when the blocks pass the stream's 65536. */
wf_status wf_noise_stream_blocks(const wf_noise *noise, uint32_t pixel, uint32_t read,
                                 wf_purpose purpose, uint32_t block0, int n, uint32_t *w0,
                                 uint32_t *w1, uint32_t *w2, uint32_t *w3);

/* Standard normals from 32-bit words: wf_norm_ppf((w + 0.5) / 2^32), rounded to float. */
void wf_norm_from_u32(const uint32_t *w, int n, float *out);

/* The first PTRS attempt for mean >= 10 from two words the caller already has (a row batch):
 * 1 and *k set when accepted (~88% of calls); 0 when rejected, and the caller continues
 * with wf_rng_poisson on the pixel's stream (independent uniforms: still exact). */
int wf_poisson_ptrs_try(double mean, uint32_t wu, uint32_t wv, double *k);

/* Inverse of the standard normal CDF, relative error < 1.2e-9 (Acklam's rational form). */
double wf_norm_ppf(double p);

/* ---- row batches of Poisson draws (hal/noise_batch.c) ------------------------------------
 * The same draws as the scalar calls above, a row at a time, so that a whole row's
 * arithmetic runs in SIMD lanes and only the rare leftovers take a scalar path. */

/* The first PTRS attempt of wf_poisson_ptrs_try for a row: k[i] = the draw when mean[i] >= 10
 * and (wu[i], wv[i]) is accepted; -1 when it is rejected, and for mean[i] < 10 or NaN (not
 * PTRS's range: the caller draws those). The log-likelihood test uses its own branch-free
 * log (< 1 ulp) in place of libm's, so a decision can differ from wf_poisson_ptrs_try only
 * where the two sides agree to ~1e-15: the accepted distribution is the same. */
void wf_poisson_ptrs_row(const double *mean, const uint32_t *wu, const uint32_t *wv, int n,
                         double *k);

/* Poisson inversion of n means as thresholds on their words, for means drawn many times
 * (a pixel at every read of a tile): with u = (w + 0.5) / 2^32 and the cumulative sums
 * F_0 = e, F_1 = F_0 + e m, F_2 = F_1 + e m^2 / 2, F_j = F_(j-1) + p_(j-1) m / j summed in
 * that order (e = exp(-m) as the caller has it), the count is the smallest k with u <= F_k,
 * and u > F_j exactly when w >= thr[j] (mean i's thr[j] at thr[j * stride + i]). For
 * w < slow[i] the count is the number of j < 6 with w >= thr[j]; from slow[i] on the caller
 * draws otherwise: a count above 6, a sum that stopped growing, a mean outside (0, 10)
 * (slow 0). Thresholds are clamped to 2^32 - 1, whose word is then always slow. In SIMD
 * lanes. */
void wf_poisson_inversion_thresholds_row(int n, const double *m, const double *e, uint32_t *thr, size_t stride,
                                         uint32_t *slow);

/* wf_noise_block_row for a list of pixels (stream pixel[i], at one read and purpose). */
void wf_noise_block_list(const wf_noise *noise, const uint32_t *pixel, int n, uint32_t read,
                         wf_purpose purpose, uint32_t block, uint32_t *w0, uint32_t *w1,
                         uint32_t *w2, uint32_t *w3);

/* A PTRS attempt from a whole block per draw, as wf_rng_poisson makes them: u and v at 53 bits
 * from words (w0, w1) and (w2, w3) (wf_rng_uniform53's construction); k[i] = the draw for
 * mean[i] >= 10 when accepted, -1 when rejected or mean[i] < 10. With the blocks of a
 * stream from wf_rng_seek's position on (wf_noise_block_list), attempts on the streams still
 * rejected give wf_rng_poisson's draws (same test as wf_poisson_ptrs_row). */
void wf_poisson_ptrs_row53(const double *mean, const uint32_t *w0, const uint32_t *w1,
                           const uint32_t *w2, const uint32_t *w3, int n, double *k);

/* Inversion for one fixed mean m in (0, 10) from 32-bit words, with the cumulative sums
 * built once: c0 = e^-m, c1 = c0 + p1, c2 = c1 + p2 with p1 = c0 m, p2 = p1 m 0.5, then
 * c_k = c_{k-1} + p_k, p_k = p_{k-1} (m / k), kept while a term still moves the sum and for
 * k < 200 (the readout's inversion from a word, firmware/readout.c, sums exactly these).
 * A draw is the count of entries below the uniform (w + 0.5) / 2^32: the first k with
 * u <= c_k, or the table length past its end. */
#define WF_POISSON_TABLE_MAX 200
typedef struct wf_poisson_table {
    double mean;
    int n;                              /* entries used */
    double cdf[WF_POISSON_TABLE_MAX];   /* strictly increasing */
    /* u > cdf[j] exactly when w >= word[j] (u = (w + 0.5) / 2^32 is exact in a double); past
     * the largest word an entry is never passed, and the table ends there */
    uint32_t word[WF_POISSON_TABLE_MAX];
    int nword;
} wf_poisson_table;

/* WF_ERR_RANGE unless 0 < mean < 10. */
wf_status wf_poisson_table_init(wf_poisson_table *t, double mean);

/* k[i] = Poisson(t->mean) by inversion of (w[i] + 0.5) / 2^32. */
void wf_poisson_table_row(const wf_poisson_table *t, const uint32_t *w, int n, double *k);

#endif
