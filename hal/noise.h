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

#include <stdint.h>

typedef enum {
    WF_PURPOSE_PHOTON = 1,    /* Poisson electrons from sky, objects and dark */
    WF_PURPOSE_READ = 2,      /* read noise */
    WF_PURPOSE_COSMIC = 3,    /* cosmic-ray hits */
    WF_PURPOSE_RESULTANT = 4, /* direct-resultant sampling of the within-group sum */
    WF_PURPOSE_SCENE = 5,     /* scene randomness (knots, positions) */
    WF_PURPOSE_SN = 6,        /* supernova sample: pixel = SN index, read = which draw (sim/sn*.h) */
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

/* Standard normals from 32-bit words: wf_norm_ppf((w + 0.5) / 2^32), rounded to float. */
void wf_norm_from_u32(const uint32_t *w, int n, float *out);

/* The first PTRS attempt for mean >= 10 from two words the caller already has (a row batch):
 * 1 and *k set when accepted (~88% of calls); 0 when rejected, and the caller continues
 * with wf_rng_poisson on the pixel's stream (independent uniforms: still exact). */
int wf_poisson_ptrs_try(double mean, uint32_t wu, uint32_t wv, double *k);

/* Inverse of the standard normal CDF, relative error < 1.2e-9 (Acklam's rational form). */
double wf_norm_ppf(double p);

#endif
