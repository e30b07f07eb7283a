/* Roman WFI point-spread function from the pupil (SPEC §4.1; docs/OPTICS.md).
 *
 *     PSF_λ(θ) ∝ |Σ_u P(u) e^{2πi W(u)/λ} e^{2πi θ·u/λ}|²
 *
 * with P the pupil amplitude (sim/optics/pupil.h), u the pupil sample positions and W the wavefront
 * in nm from the Zernike aberrations (a physical length, so the phase scales as 1/λ: GalSim's
 * scaling of the 1293 nm coefficients). The signs give GalSim's image orientation. The pupil
 * is sampled every dx metres, so the PSF is a trigonometric polynomial of period T = λ/dx in
 * each axis:
 *
 *     PSF(θ) = Σ_Δ c_Δ exp(-2πi θ·Δ / T),   c_Δ = autocorrelation of P e^{iφ} at lag -Δ (OTF),
 *
 * Building (host side, malloc): c is computed exactly by two FFTs (FFTW3, double) of a grid
 * at least twice the pupil's open extent, so the circular autocorrelation equals the linear
 * one; c is normalised to c_0 = 1, i.e. unit flux per period before any truncation.
 *
 * Drawing evaluates that finite Fourier sum at the centres of the requested output pixels
 * (separable matrix Fourier transform), so any scale and centre is exact: there is no
 * interpolation and no FFT-grid scale constraint (the FFT grid's own scale λ/(N dx) never
 * reaches the output). Pixel response (a box of the detector pixel, with or without
 * oversampling), Gaussian jitter and charge diffusion multiply c by sinc and Gaussian
 * factors, exactly, in the same sum. Undersampling therefore aliases nothing: a native-scale
 * image with the pixel is the pixel-integrated PSF sampled at pixel centres. The model's own
 * approximation is the pupil sampling (pupil_bin), which also fixes the period T; samples
 * farther than T/2 from the centre are set to zero, as GalSim's single-period image does.
 *
 * Memory: the build allocates (host malloc, before any firmware runs) at most
 * wf_psf_build_need() bytes and refuses above max_bytes: about 6 MB at pupil_bin 8, 25 MB at
 * 4, 100 MB at 2 and 400 MB at 1. A built wf_psf holds only the c coefficients (2 MB at
 * pupil_bin 8 per wavelength). Drawing allocates O((nx + ny) × extent) scratch.
 *
 * Thread safety: wf_psf_draw on a shared wf_psf is safe; builds may run in several threads
 * (FFTW planning is serialised internally). */
#ifndef WF_PSF_H
#define WF_PSF_H

#include <stddef.h>
#include "hal/status.h"
#include "sim/optics/psfimage.h"
#include "sim/optics/pupil.h"

#define WF_PSF_PIXEL_SCALE 0.11          /* arcsec per detector pixel (SPEC §2) */
#define WF_PSF_JITTER_SIGMA 0.014        /* arcsec rms per axis, when jitter is on (SPEC §2) */
#define WF_PSF_DIFFUSION_SIGMA 0.1       /* detector pixels, when diffusion is on (SPEC §2) */
#define WF_PSF_MAX_LAMBDAS 64
#define WF_PSF_DEFAULT_MAX_BYTES ((size_t)1 << 30)

typedef struct wf_psf wf_psf;

/* Where on the focal plane and how finely: everything that fixes the c coefficients. */
typedef struct wf_psf_optics {
    int sca;                  /* 1..18 */
    wf_pupil_group group;     /* mask group (from the filter) */
    int pupil_bin;            /* 1, 2, 4, 8 */
    wf_pupil_binning binning; /* WF_PUPIL_BIN_ANY (GalSim) by default */
    double x, y;              /* SCA position, GalSim pixel coordinates; centre (2044, 2044) */
    char data_dir[1024];      /* "" → analytic pupil, flat wavefront */
    size_t max_bytes;         /* build memory bound; 0 → WF_PSF_DEFAULT_MAX_BYTES */
} wf_psf_optics;

/* How to sample: output grid, pixel response, blurs. */
typedef struct wf_psf_draw_opts {
    int nx, ny;       /* output samples */
    double scale;     /* arcsec per output sample */
    double cx, cy;    /* 0-based output coordinates of the PSF centre ((n-1)/2: true centre) */
    int pixel;        /* 1: integrate over a detector pixel (box det_scale wide) */
    double det_scale; /* arcsec per detector pixel: the box and the diffusion unit */
    double jitter;    /* Gaussian sigma per axis, arcsec (0: off; WF_PSF_JITTER_SIGMA) */
    double diffusion; /* Gaussian sigma per axis, detector pixels (0: off) */
    /* Optional extra separable transfer function, even in frequency: the coefficient at
     * (fx, fy) cycles/arcsec is multiplied by mtf(|fx|) mtf(|fy|). For a measured detector
     * MTF, or an interpolant's response when reproducing another code's rendering (the
     * GalSim comparison in tests/test_psf.c). NULL: none. */
    double (*mtf)(double freq, void *ctx);
    void *mtf_ctx;
    /* 1: render as GalSim's FFT draw of galsim.roman.getPSF does (drawImage's default with the
     * pixel): its OpticalPSF is an image sampled at λ/(N_g dx), exactly Nyquist (N_g =
     * galsim_n below), read through a Quintic interpolant, which multiplies coefficient Δ by
     * the Quintic's response at Δ/N_g. Changes the native peak by -1.2% … +1.4% with the
     * filter (docs/OPTICS.md "Agreement with GalSim"); for comparisons with GalSim only,
     * 0 (exact) otherwise. GalSim's no_pixel draws interpolate in real space instead. */
    int galsim;
    int threads;      /* rows shared among this many threads (same image for any count) [1] */
    /* 1: the same sum by chirp-z transforms (sim/numeric/czt.h), O(n log n) a row instead of
     * O(n k): for large images (the scene's wide PSF); agrees with the direct sum to ~1e-13
     * of the peak, not bit for bit. One thread. [0] */
    int czt;
} wf_psf_draw_opts;

typedef struct wf_psf_info {
    int nlambda;
    double lambda_nm[WF_PSF_MAX_LAMBDAS];
    double weight[WF_PSF_MAX_LAMBDAS]; /* normalised to sum 1 */
    double lambda_mean_nm;             /* weight-averaged wavelength */
    double period_arcsec;              /* smallest λ/dx: the valid field is ± half of it */
    int fft_nx, fft_ny;                /* FFT grid of the build */
    int galsim_n;                      /* GalSim's pupil array for this dx: 2^k or 3·2^k >= 2D/dx */
    int kx, ky;                        /* Fourier coefficients kept per axis (|Δ| < k) */
    double pupil_dx;                   /* m */
    int pupil_n, pupil_bin;
    double open_area;                  /* m² */
    size_t bytes;                      /* held by the wf_psf */
    size_t build_bytes;                /* peak host memory of the build */
    double zernike[WF_ZERNIKE_MAX + 1]; /* waves at 1293 nm used */
    char pupil_source[WF_PUPIL_SOURCE_MAX];
    char aberr_source[WF_PUPIL_SOURCE_MAX];
} wf_psf_info;

/* Defaults: SCA 1, short group, pupil_bin 4 (GalSim's default), any-open binning, the SCA
 * centre, no data, default memory bound. */
void wf_psf_optics_default(wf_psf_optics *o);

/* Defaults: 64 × 64 at 0.11", centred at the true centre, pixel on, no jitter/diffusion. */
void wf_psf_draw_opts_default(wf_psf_draw_opts *d);

/* Peak host bytes a build of this pupil at nlambda wavelengths needs. */
wf_status wf_psf_build_need(const wf_pupil *pupil, int nlambda, size_t *bytes);

/* Builds from a given pupil and aberrations (NULL: none): achromatic with nlambda = 1 (the
 * caller passes the band's effective wavelength), chromatic otherwise:
 * PSF = Σ w_k PSF_λk / Σ w_k (the caller's weights carry bandpass × SED, photon counting;
 * weight NULL: equal weights). */
wf_status wf_psf_build(const wf_pupil *pupil, const wf_aberrations *ab, const double *lambda_nm,
                       const double *weight, int nlambda, size_t max_bytes, wf_psf **out);

/* Loads pupil and aberrations for `o` (data or analytic) and builds. */
wf_status wf_psf_build_optics(const wf_psf_optics *o, const double *lambda_nm,
                              const double *weight, int nlambda, wf_psf **out);

/* Draws into out[ny * nx] (row-major, y slow): flux per output sample for a unit-flux PSF. */
wf_status wf_psf_draw(const wf_psf *psf, const wf_psf_draw_opts *d, double *out);

wf_status wf_psf_get_info(const wf_psf *psf, wf_psf_info *out);

void wf_psf_free(wf_psf *psf);

/* ---- Cache: the renderer asks, and only what the scene draws is built. ---------------- */

typedef struct wf_psf_request {
    wf_psf_optics optics;
    int nlambda;
    double lambda_nm[WF_PSF_MAX_LAMBDAS];
    double weight[WF_PSF_MAX_LAMBDAS];
    wf_psf_draw_opts draw;
} wf_psf_request;

typedef struct wf_psf_table {
    wf_psf_draw_opts draw;
    const double *data; /* ny * nx, as wf_psf_draw writes it */
    double sum;         /* Σ data: the stamp's fraction of the unit flux */
    double lambda_mean_nm;
} wf_psf_table;

/* The table as the profile drawer takes it (sim/optics/psfimage.h): it must be square, centred on
 * its true centre ((n-1)/2) and drawn without the pixel response. */
wf_status wf_psf_table_image(const wf_psf_table *t, wf_psf_image *out);

typedef struct wf_psf_cache_stats {
    long requests, tables_built, models_built, models_dropped;
    size_t bytes, high_water, max_bytes;
    int tables, models;
} wf_psf_cache_stats;

typedef struct wf_psf_cache wf_psf_cache;

/* A cache bounded to max_bytes (tables plus the c coefficients it keeps for reuse). */
wf_status wf_psf_cache_create(size_t max_bytes, wf_psf_cache **out);

/* The table for req, built on first request. A table stays valid until the cache is
 * destroyed; coefficient sets are dropped when room is needed and rebuilt when asked again.
 * A table that cannot fit even then is WF_ERR_NOMEM naming its size and the bound.
 * Thread-safe (one lock; builds are serialised). */
wf_status wf_psf_cache_get(wf_psf_cache *c, const wf_psf_request *req, const wf_psf_table **out);

void wf_psf_cache_get_stats(wf_psf_cache *c, wf_psf_cache_stats *out);
void wf_psf_cache_destroy(wf_psf_cache *c);

#endif
