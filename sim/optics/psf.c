#include "sim/optics/psf.h"
#include "sim/numeric/trig.h"
#include "sim/numeric/czt.h"
#include "sim/numeric/parallel.h"
#include "sim/numeric/fftw_lock.h"
#include "hal/arena.h"

#include <fftw3.h>
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#define PI 3.14159265358979323846
#define ARCSEC_PER_RAD 206264.80624709636
#define ROW_BLOCK 64           /* output rows per pass of the Fourier sum: bounds the scratch */
#define COEF_FLOOR 1e-13       /* |c| below this (c_0 = 1) is FFT round-off outside the support */

/* FFTW's planner is not thread-safe; execution of an existing plan is. */

typedef struct mono {
    double lambda_nm, weight; /* weight normalised over the set */
    double period;            /* λ/dx in arcsec */
    double *cre, *cim;        /* [kx][2 ky - 1]: Δx = 0..kx-1, Δy = -(ky-1)..ky-1 */
    int *lo, *hi;             /* per Δx: Δy index range holding |c| >= COEF_FLOOR */
} mono;

struct wf_psf {
    int nlambda;
    int kx, ky;
    mono m[WF_PSF_MAX_LAMBDAS];
    wf_psf_info info;
};

void wf_psf_optics_default(wf_psf_optics *o)
{
    memset(o, 0, sizeof *o);
    o->sca = 1;
    o->group = WF_PUPIL_SHORT;
    o->pupil_bin = 4;
    o->binning = WF_PUPIL_BIN_ANY;
    o->x = WF_SCA_NPIX / 2.0;
    o->y = WF_SCA_NPIX / 2.0;
    o->max_bytes = WF_PSF_DEFAULT_MAX_BYTES;
}

void wf_psf_draw_opts_default(wf_psf_draw_opts *d)
{
    memset(d, 0, sizeof *d);
    d->nx = d->ny = 64;
    d->scale = WF_PSF_PIXEL_SCALE;
    d->cx = d->cy = 0.5 * (64 - 1);
    d->pixel = 1;
    d->det_scale = WF_PSF_PIXEL_SCALE;
    d->threads = 1;
}

/* Smallest 2^a 3^b 5^c 7^d >= n: sizes FFTW transforms fast. */
static int good_fft_size(int n)
{
    for (int m = n > 1 ? n : 1;; m++) {
        int r = m;
        static const int f[4] = {2, 3, 5, 7};
        for (int k = 0; k < 4; k++)
            while (r % f[k] == 0) r /= f[k];
        if (r == 1) return m;
    }
}

/* GalSim's Aperture pads a pupil image to good_fft_size(ceil(2 D / dx)) samples (its
 * oversampling 1, which galsim.roman leaves at the default): the smallest 2^k or 3·2^k. */
static int galsim_pupil_n(double diam, double dx)
{
    int need = (int)ceil(2.0 * diam / dx), p2 = 2, p3 = 3;
    while (p2 < need) p2 *= 2;
    while (p3 < need) p3 *= 2;
    return p2 < p3 ? p2 : p3;
}

static void grid_sizes(const wf_pupil *p, int *mx, int *my, int *nxf, int *nyf)
{
    *mx = p->i1 - p->i0 + 1;
    *my = p->j1 - p->j0 + 1;
    /* 2m - 1 samples hold every lag of the autocorrelation without wrapping. */
    *nxf = good_fft_size(2 * *mx - 1);
    *nyf = good_fft_size(2 * *my - 1);
}

static size_t mono_bytes(int kx, int ky)
{
    return (size_t)kx * (size_t)(2 * ky - 1) * 2 * sizeof(double) + 2 * (size_t)kx * sizeof(int);
}

wf_status wf_psf_build_need(const wf_pupil *pupil, int nlambda, size_t *bytes)
{
    if (!pupil || !pupil->amp || pupil->i1 < pupil->i0)
        return wf_error(WF_ERR_INPUT, "psf: empty pupil");
    if (nlambda < 1 || nlambda > WF_PSF_MAX_LAMBDAS)
        return wf_error(WF_ERR_RANGE, "psf: %d wavelengths (1..%d)", nlambda, WF_PSF_MAX_LAMBDAS);
    int mx, my, nxf, nyf;
    grid_sizes(pupil, &mx, &my, &nxf, &nyf);
    size_t field = (size_t)nxf * nyf * sizeof(fftw_complex);
    size_t power = (size_t)nyf * (size_t)(nxf / 2 + 1) * sizeof(fftw_complex);
    size_t wave = (size_t)mx * my * sizeof(double);
    *bytes = field + power + wave + (size_t)nlambda * mono_bytes(mx, my) + sizeof(wf_psf);
    return WF_OK;
}

void wf_psf_free(wf_psf *psf)
{
    if (!psf) return;
    for (int k = 0; k < psf->nlambda; k++) {
        free(psf->m[k].cre); /* cim shares its block */
        free(psf->m[k].lo);
        free(psf->m[k].hi);
    }
    free(psf);
}

/* Wavefront (nm) over the pupil's bounding box: physical length, so one array serves every
 * wavelength. Z1-Z3 are skipped whatever the caller passed (they only shift the PSF). */
static void wavefront_nm(const wf_pupil *p, const wf_aberrations *ab, double *w, int *any)
{
    int mx = p->i1 - p->i0 + 1, my = p->j1 - p->j0 + 1;
    *any = 0;
    for (int j = 4; j <= WF_ZERNIKE_MAX; j++)
        if (ab->z[j] != 0.0) *any = 1;
    if (!*any) return;
    double R = 0.5 * p->diam;
    /* the terms' coefficients once, not at every sample (factorials cost more than a term) */
    wf_zernike_term t[WF_ZERNIKE_MAX + 1];
    for (int j = 4; j <= WF_ZERNIKE_MAX; j++) (void)wf_pupil_zernike_term(j, &t[j]);
    for (int b = 0; b < my; b++)
        for (int a = 0; a < mx; a++) {
            int i = p->i0 + a, jj = p->j0 + b;
            double sum = 0.0;
            if (p->amp[(size_t)jj * p->n + i] > 0.0f) {
                double x = (i - p->n / 2) * p->dx / R, y = (jj - p->n / 2) * p->dx / R;
                for (int j = 4; j <= WF_ZERNIKE_MAX; j++) {
                    if (ab->z[j] == 0.0) continue;
                    sum += ab->z[j] * wf_pupil_zernike_eval(&t[j], x, y);
                }
            }
            w[(size_t)b * mx + a] = sum * ab->lambda_ref_nm;
        }
}

wf_status wf_psf_build(const wf_pupil *pupil, const wf_aberrations *ab, const double *lambda_nm,
                       const double *weight, int nlambda, size_t max_bytes, wf_psf **out)
{
    *out = NULL;
    size_t need;
    wf_status st = wf_psf_build_need(pupil, nlambda, &need);
    if (st) return st;
    if (!(pupil->dx > 0.0) || !isfinite(pupil->dx) || !(pupil->diam > 0.0))
        return wf_error(WF_ERR_RANGE, "psf: pupil sample %g m / diameter %g m not positive",
                        pupil->dx, pupil->diam);
    wf_aberrations flat;
    if (!ab) {
        wf_pupil_aberrations_none(&flat);
        ab = &flat;
    }
    if (!max_bytes) max_bytes = WF_PSF_DEFAULT_MAX_BYTES;
    if (need > max_bytes)
        return wf_error(WF_ERR_NOMEM,
                        "psf: building at pupil_bin %d with %d wavelengths needs %zu MB, over the "
                        "%zu MB bound (raise max_bytes or pupil_bin)",
                        pupil->bin, nlambda, need >> 20, max_bytes >> 20);
    double wsum = 0.0;
    for (int k = 0; k < nlambda; k++) {
        if (!(lambda_nm[k] > 0.0) || !isfinite(lambda_nm[k]) || lambda_nm[k] > 1e5)
            return wf_error(WF_ERR_RANGE, "psf: wavelength %d = %g nm is not in (0, 1e5]", k,
                            lambda_nm[k]);
        double w = weight ? weight[k] : 1.0;
        if (!(w >= 0.0) || !isfinite(w))
            return wf_error(WF_ERR_RANGE, "psf: weight %d = %g is not a finite value >= 0", k, w);
        wsum += w;
    }
    if (!(wsum > 0.0)) return wf_error(WF_ERR_RANGE, "psf: the wavelength weights sum to zero");

    int mx, my, nxf, nyf;
    grid_sizes(pupil, &mx, &my, &nxf, &nyf);
    wf_psf *psf = calloc(1, sizeof *psf);
    /* large and filled whole: huge pages (hal/arena.h), which FFTW's alignment needs no more
     * than fftw_malloc's */
    fftw_complex *field = wf_arena_host_realloc(NULL, 0, (size_t)nxf * nyf * sizeof(fftw_complex));
    int hx = nxf / 2 + 1;
    fftw_complex *power = wf_arena_host_realloc(NULL, 0, (size_t)nyf * hx * sizeof(fftw_complex));
    double *wave = wf_arena_host_realloc(NULL, 0, (size_t)mx * my * sizeof(double));
    fftw_plan fwd = NULL, r2c = NULL;
    if (!psf || !field || !power || !wave) {
        st = wf_error(WF_ERR_NOMEM, "psf: cannot allocate %zu MB for the build", need >> 20);
        goto done;
    }
    wf_fftw_lock();
    fwd = fftw_plan_dft_2d(nyf, nxf, field, field, FFTW_FORWARD, FFTW_ESTIMATE);
    r2c = fftw_plan_dft_r2c_2d(nyf, nxf, (double *)power, power, FFTW_ESTIMATE);
    wf_fftw_unlock();
    if (!fwd || !r2c) {
        st = wf_error(WF_ERR_INTERNAL, "psf: FFTW could not plan %dx%d transforms", nxf, nyf);
        goto done;
    }
    int any_aberr = 0;
    wavefront_nm(pupil, ab, wave, &any_aberr);

    psf->nlambda = nlambda;
    psf->kx = mx;
    psf->ky = my;
    int nyc = 2 * my - 1;
    double *rpow = (double *)power;
    size_t rstride = 2 * (size_t)hx; /* in-place r2c pads each real row */
    for (int k = 0; k < nlambda; k++) {
        mono *m = &psf->m[k];
        m->lambda_nm = lambda_nm[k];
        m->weight = (weight ? weight[k] : 1.0) / wsum;
        m->period = lambda_nm[k] * 1e-9 / pupil->dx * ARCSEC_PER_RAD;
        /* one block: each half is about 1 MiB, too little for a huge page of its own */
        m->cre = wf_arena_host_realloc(NULL, 0, 2 * (size_t)mx * nyc * sizeof(double));
        m->cim = m->cre ? m->cre + (size_t)mx * nyc : NULL;
        m->lo = malloc((size_t)mx * sizeof(int));
        m->hi = malloc((size_t)mx * sizeof(int));
        if (!m->cre || !m->cim || !m->lo || !m->hi) {
            psf->nlambda = k + 1;
            st = wf_error(WF_ERR_NOMEM, "psf: cannot allocate the coefficients at %g nm",
                          lambda_nm[k]);
            goto done;
        }
        /* P e^{iφ}, φ = 2π W/λ (GalSim's sign), anywhere in the grid: the autocorrelation
         * does not depend on where the pupil sits. */
        memset(field, 0, (size_t)nxf * nyf * sizeof(fftw_complex));
        double kphase = 2.0 * PI / lambda_nm[k];
        for (int b = 0; b < my; b++)
            for (int a = 0; a < mx; a++) {
                double amp = pupil->amp[(size_t)(pupil->j0 + b) * pupil->n + pupil->i0 + a];
                if (amp <= 0.0) continue;
                double ph = any_aberr ? kphase * wave[(size_t)b * mx + a] : 0.0;
                field[(size_t)b * nxf + a][0] = amp * cos(ph);
                field[(size_t)b * nxf + a][1] = amp * sin(ph);
            }
        fftw_execute(fwd);
        for (int y = 0; y < nyf; y++)
            for (int x = 0; x < nxf; x++) {
                const double *e = field[(size_t)y * nxf + x];
                rpow[(size_t)y * rstride + x] = e[0] * e[0] + e[1] * e[1];
            }
        fftw_execute(r2c);
        /* The forward transform of |FFT(P)|² is N²·C(-Δ), C the autocorrelation of P e^{iφ}.
         * Taking c(Δ) = G(Δ)/G(0) = C(-Δ)/C(0) evaluates |Σ P e^{+2πi θ·u/λ}|²: that sign
         * is the one that reproduces the orientation of GalSim's getPSF images (their
         * centroid and 3x3 core; the other sign is the same PSF turned by 180°). */
        double g0 = power[0][0];
        if (!(g0 > 0.0)) {
            psf->nlambda = k + 1;
            st = wf_error(WF_ERR_INTERNAL, "psf: zero total power at %g nm", lambda_nm[k]);
            goto done;
        }
        for (int dxi = 0; dxi < mx; dxi++) {
            int lo = nyc, hi = -1;
            for (int t = 0; t < nyc; t++) {
                int dy = t - (my - 1);
                const double *g = power[(size_t)((dy + nyf) % nyf) * hx + dxi];
                double re = g[0] / g0, im = g[1] / g0;
                m->cre[(size_t)dxi * nyc + t] = re;
                m->cim[(size_t)dxi * nyc + t] = im;
                if (fabs(re) >= COEF_FLOOR || fabs(im) >= COEF_FLOOR) {
                    if (t < lo) lo = t;
                    hi = t;
                }
            }
            m->lo[dxi] = lo;
            m->hi[dxi] = hi;
        }
    }

    wf_psf_info *in = &psf->info;
    in->nlambda = nlambda;
    double lmean = 0.0, pmin = INFINITY;
    for (int k = 0; k < nlambda; k++) {
        in->lambda_nm[k] = psf->m[k].lambda_nm;
        in->weight[k] = psf->m[k].weight;
        lmean += psf->m[k].weight * psf->m[k].lambda_nm;
        if (psf->m[k].period < pmin) pmin = psf->m[k].period;
    }
    in->lambda_mean_nm = lmean;
    in->period_arcsec = pmin;
    in->fft_nx = nxf;
    in->fft_ny = nyf;
    in->galsim_n = galsim_pupil_n(pupil->diam, pupil->dx);
    in->kx = mx;
    in->ky = my;
    in->pupil_dx = pupil->dx;
    in->pupil_n = pupil->n;
    in->pupil_bin = pupil->bin;
    in->open_area = pupil->open_area;
    in->bytes = sizeof *psf + (size_t)nlambda * mono_bytes(mx, my);
    in->build_bytes = need;
    for (int j = 0; j <= WF_ZERNIKE_MAX; j++) in->zernike[j] = j >= 4 ? ab->z[j] : 0.0;
    snprintf(in->pupil_source, sizeof in->pupil_source, "%s", pupil->source);
    snprintf(in->aberr_source, sizeof in->aberr_source, "%s", ab->source);
done:
    wf_fftw_lock();
    if (fwd) fftw_destroy_plan(fwd);
    if (r2c) fftw_destroy_plan(r2c);
    wf_fftw_unlock();
    free(field);
    free(power);
    free(wave);
    if (st) {
        wf_psf_free(psf);
        return st;
    }
    *out = psf;
    return WF_OK;
}

wf_status wf_psf_build_optics(const wf_psf_optics *o, const double *lambda_nm,
                              const double *weight, int nlambda, wf_psf **out)
{
    *out = NULL;
    wf_pupil pupil;
    wf_aberrations ab;
    wf_status st;
    if (o->data_dir[0]) {
        st = wf_pupil_load(o->data_dir, o->sca, o->group, o->pupil_bin, o->binning, &pupil);
        if (st) return st;
        st = wf_pupil_aberrations_load(o->data_dir, o->sca, o->x, o->y, &ab);
    } else {
        wf_pupil_geometry g;
        if (o->sca < 1 || o->sca > 18)
            return wf_error(WF_ERR_RANGE, "psf: SCA %d is not 1..18", o->sca);
        if ((st = wf_pupil_geometry_default(o->group, &g))) return st;
        st = wf_pupil_analytic(&g, o->pupil_bin, o->binning, &pupil);
        if (st) return st;
        wf_pupil_aberrations_none(&ab);
    }
    if (!st) st = wf_psf_build(&pupil, &ab, lambda_nm, weight, nlambda, o->max_bytes, out);
    wf_pupil_free(&pupil);
    return st;
}

wf_status wf_psf_get_info(const wf_psf *psf, wf_psf_info *out)
{
    if (!psf) return wf_error(WF_ERR_INPUT, "psf: no PSF");
    *out = psf->info;
    return WF_OK;
}

static wf_status check_draw(const wf_psf_draw_opts *d)
{
    if (d->nx < 1 || d->ny < 1 || d->nx > 32768 || d->ny > 32768 ||
        (size_t)d->nx * (size_t)d->ny > ((size_t)1 << 28))
        return wf_error(WF_ERR_RANGE, "psf draw: %d x %d samples (1..32768 each, 2^28 in all)",
                        d->nx, d->ny);
    if (!(d->scale > 0.0) || !isfinite(d->scale))
        return wf_error(WF_ERR_RANGE, "psf draw: scale %g arcsec is not positive", d->scale);
    if (!isfinite(d->cx) || !isfinite(d->cy))
        return wf_error(WF_ERR_RANGE, "psf draw: centre (%g, %g) is not finite", d->cx, d->cy);
    if ((d->pixel || d->diffusion > 0.0) && (!(d->det_scale > 0.0) || !isfinite(d->det_scale)))
        return wf_error(WF_ERR_RANGE, "psf draw: detector pixel %g arcsec is not positive",
                        d->det_scale);
    if (d->czt != 0 && d->czt != 1)
        return wf_error(WF_ERR_RANGE, "psf draw: czt %d is not 0 (direct sum) or 1 (chirp-z)", d->czt);
    if (d->galsim != 0 && d->galsim != 1)
        return wf_error(WF_ERR_RANGE, "psf draw: galsim %d is not 0 (exact) or 1 (GalSim's "
                        "rendering)", d->galsim);
    if (!(d->jitter >= 0.0) || !isfinite(d->jitter))
        return wf_error(WF_ERR_RANGE, "psf draw: jitter %g arcsec is not >= 0", d->jitter);
    if (!(d->diffusion >= 0.0) || !isfinite(d->diffusion))
        return wf_error(WF_ERR_RANGE, "psf draw: diffusion %g px is not >= 0", d->diffusion);
    return WF_OK;
}

/* Fourier response of GalSim's Quintic interpolant at u cycles per sample (its kValue). */
static double quintic_response(double u)
{
    if (u == 0.0) return 1.0;
    double s = sin(PI * u) / (PI * u), c = cos(PI * u), p2 = PI * PI * u * u, s2 = s * s;
    return s * s2 * s2 * (s * (55.0 - 19.0 * p2) + 2.0 * c * (p2 - 27.0));
}

/* Per-axis factor of coefficient Δ (frequency f = Δ/T cycles per arcsec): the sample area
 * (no pixel) or the pixel box (sinc), times the Gaussian blurs. galsim_n > 0: GalSim's
 * Quintic at its sample λ/(galsim_n dx) = T/galsim_n, i.e. at Δ/galsim_n cycles per sample
 * whatever the wavelength. */
static double axis_gain(const wf_psf_draw_opts *d, double period, int delta, int galsim_n)
{
    double f = delta / period, g;
    if (d->pixel) {
        double a = PI * f * d->det_scale;
        g = d->det_scale / period * (a == 0.0 ? 1.0 : sin(a) / a);
    } else {
        g = d->scale / period;
    }
    if (d->mtf) g *= d->mtf(fabs(f), d->mtf_ctx);
    if (galsim_n > 0) g *= quintic_response((double)delta / galsim_n);
    double s2 = d->jitter * d->jitter;
    if (d->diffusion > 0.0) s2 += (d->diffusion * d->det_scale) * (d->diffusion * d->det_scale);
    if (s2 > 0.0) g *= exp(-2.0 * PI * PI * s2 * f * f);
    return g;
}

/* gain e^{-2πi θ_k Δ/T} for θ_k = (k0 + k - c) scale, k = 0 .. n - 1: the phase in cycles,
 * whose whole turns come off exactly (sim/numeric/trig.h), so large Δθ keep precision; a row at a
 * time in SIMD lanes (libm's sin and cos were ~450 k calls per PSF image). */
#define PHASOR_CHUNK 256
static void phasor_row(int k0, int n, double c, double scale, int delta, double period, double gain,
                       double *re, double *im)
{
    double cyc[PHASOR_CHUNK], cs[PHASOR_CHUNK], sn[PHASOR_CHUNK];
    for (int a = 0; a < n; a += PHASOR_CHUNK) {
        int m = n - a < PHASOR_CHUNK ? n - a : PHASOR_CHUNK;
        for (int k = 0; k < m; k++) cyc[k] = (k0 + a + k - c) * scale * (double)delta / period;
        wf_trig_sincos_turns(cyc, m, cs, sn);
        for (int k = 0; k < m; k++) {
            re[a + k] = gain * cs[k];
            im[a + k] = -(gain * sn[k]);
        }
    }
}

/* The discrete pupil makes the PSF periodic; only the central period is the PSF. */
static void zero_outside_period(const wf_psf *psf, const wf_psf_draw_opts *d, int ja, int jend, double *out)
{
    double half = 0.5 * psf->info.period_arcsec;
    for (int j = ja; j < jend; j++) {
        double ty = fabs((j - d->cy) * d->scale);
        for (int i = 0; i < d->nx; i++)
            if (ty > half || fabs((i - d->cx) * d->scale) > half) out[(size_t)j * d->nx + i] = 0.0;
    }
}

typedef struct draw_job {
    const wf_psf *psf;
    const wf_psf_draw_opts *d;
    double *out;
    int ntasks;
} draw_job;

/* Output rows of task `task` (a contiguous share of them: the column phasors are made once
 * per wavelength and share). Each row's sums run in the same order whatever the share, so the
 * image does not depend on the thread count. */
static wf_status draw_rows(void *ctx, int task, int slot)
{
    (void)slot;
    const draw_job *jb = ctx;
    const wf_psf *psf = jb->psf;
    const wf_psf_draw_opts *d = jb->d;
    int nx = d->nx, ny = d->ny, kx = psf->kx, ky = psf->ky, nyc = 2 * ky - 1;
    int gn = d->galsim ? psf->info.galsim_n : 0;
    int ja = (int)((long)ny * task / jb->ntasks), jend = (int)((long)ny * (task + 1) / jb->ntasks);
    if (jend <= ja) return WF_OK;
    int nb = jend - ja < ROW_BLOCK ? jend - ja : ROW_BLOCK;
    size_t n_ax = (size_t)kx * nx, n_ay = (size_t)nyc * nb, n_b = (size_t)kx * nb;
    double *buf = wf_arena_host_realloc(NULL, 0, (2 * n_ax + 2 * n_ay + 2 * n_b) * sizeof(double));
    if (!buf)
        return wf_error(WF_ERR_NOMEM, "psf draw: cannot allocate %zu MB of scratch",
                        ((2 * n_ax + 2 * n_ay + 2 * n_b) * sizeof(double)) >> 20);
    double *axr = buf, *axi = axr + n_ax, *ayr = axi + n_ax, *ayi = ayr + n_ay;
    double *br = ayi + n_ay, *bi = br + n_b;
    double *out = jb->out;
    memset(out + (size_t)ja * nx, 0, (size_t)(jend - ja) * nx * sizeof(double));

    for (int k = 0; k < psf->nlambda; k++) {
        const mono *m = &psf->m[k];
        double T = m->period;
        /* Δx > 0 stands for ±Δx (Hermitian c, even gains): weight 2, Δx = 0 weight 1. */
        for (int a = 0; a < kx; a++) {
            double g = axis_gain(d, T, a, gn) * m->weight * (a ? 2.0 : 1.0);
            phasor_row(0, nx, d->cx, d->scale, a, T, g, &axr[(size_t)a * nx], &axi[(size_t)a * nx]);
        }
        for (int j0 = ja; j0 < jend; j0 += nb) {
            int nr = jend - j0 < nb ? jend - j0 : nb;
            for (int t = 0; t < nyc; t++) {
                int dy = t - (ky - 1);
                double g = axis_gain(d, T, dy, gn);
                phasor_row(j0, nr, d->cy, d->scale, dy, T, g, &ayr[(size_t)t * nb], &ayi[(size_t)t * nb]);
            }
            /* B[Δx][row] = Σ_Δy c[Δx][Δy] Ay[Δy][row] */
            for (int a = 0; a < kx; a++) {
                double *bra = br + (size_t)a * nb, *bia = bi + (size_t)a * nb;
                for (int r = 0; r < nr; r++) bra[r] = bia[r] = 0.0;
                const double *cr = m->cre + (size_t)a * nyc, *ci = m->cim + (size_t)a * nyc;
                for (int t = m->lo[a]; t <= m->hi[a]; t++) {
                    double c0 = cr[t], c1 = ci[t];
                    const double *yr = ayr + (size_t)t * nb, *yi = ayi + (size_t)t * nb;
                    for (int r = 0; r < nr; r++) {
                        bra[r] += c0 * yr[r] - c1 * yi[r];
                        bia[r] += c0 * yi[r] + c1 * yr[r];
                    }
                }
            }
            /* out[row][i] += Re Σ_Δx Ax[Δx][i] B[Δx][row] */
            for (int r = 0; r < nr; r++) {
                double *o = out + (size_t)(j0 + r) * nx;
                for (int a = 0; a < kx; a++) {
                    double b0 = br[(size_t)a * nb + r], b1 = bi[(size_t)a * nb + r];
                    const double *xr = axr + (size_t)a * nx, *xi = axi + (size_t)a * nx;
                    for (int i = 0; i < nx; i++) o[i] += xr[i] * b0 - xi[i] * b1;
                }
            }
        }
    }
    free(buf);
    zero_outside_period(psf, d, ja, jend, out);
    return WF_OK;
}

/* x[m] *= e^{2πi t0 m} (t0 in turns): moves a transform's origin to the centre. */
static void shift_phase(double *x, int n, double t0, double *tmp)
{
    double *u = tmp, *c = tmp + n, *s = tmp + 2 * n;
    for (int m = 0; m < n; m++) u[m] = t0 * m;
    wf_trig_sincos_turns(u, n, c, s);
    for (int m = 0; m < n; m++) {
        double xr = x[2 * m], xi = x[2 * m + 1];
        x[2 * m] = xr * c[m] - xi * s[m];
        x[2 * m + 1] = xr * s[m] + xi * c[m];
    }
}

/* The draw_rows sum by chirp-z transforms, per wavelength: first over Δy for each Δx (B of
 * draw_rows, every output row at once), then over Δx for each output row. Sample k of an axis
 * sits at θ = (k - c) scale, so with α = scale / T the phase of lag Δ = m + d0 is
 * -α (k - c)(m + d0) turns: the input takes e^{2πi α c m}, the output e^{-2πi α (k - c) d0}. */
static wf_status draw_czt(const wf_psf *psf, const wf_psf_draw_opts *d, double *out)
{
    int nx = d->nx, ny = d->ny, kx = psf->kx, ky = psf->ky, nyc = 2 * ky - 1;
    int gn = d->galsim ? psf->info.galsim_n : 0;
    int nmax = nx > ny ? nx : ny;
    if (nyc > nmax) nmax = nyc;
    if (kx > nmax) nmax = kx;
    size_t nb = (size_t)kx * ny * 2;
    double *b = malloc(nb * sizeof *b), *x = malloc((size_t)nmax * 2 * sizeof *x);
    double *y = malloc((size_t)nmax * 2 * sizeof *y), *tmp = malloc((size_t)nmax * 3 * sizeof *tmp);
    double *gy = malloc((size_t)nyc * sizeof *gy), *gx = malloc((size_t)kx * sizeof *gx);
    double *post = malloc((size_t)ny * 2 * sizeof *post);
    wf_czt *zy = NULL, *zx = NULL;
    wf_status st = WF_OK;
    if (!b || !x || !y || !tmp || !gy || !gx || !post) {
        st = wf_error(WF_ERR_NOMEM, "psf draw: cannot allocate %zu MB for the chirp-z sums", (nb * sizeof *b) >> 20);
        goto done;
    }
    memset(out, 0, (size_t)nx * ny * sizeof *out);
    for (int k = 0; k < psf->nlambda && !st; k++) {
        const mono *m = &psf->m[k];
        double T = m->period, alpha = d->scale / T;
        wf_czt_free(zy);
        wf_czt_free(zx);
        zy = zx = NULL;
        if ((st = wf_czt_create(nyc, ny, alpha, &zy)) || (st = wf_czt_create(kx, nx, alpha, &zx))) break;
        for (int t = 0; t < nyc; t++) gy[t] = axis_gain(d, T, t - (ky - 1), gn);
        for (int a = 0; a < kx; a++) gx[a] = axis_gain(d, T, a, gn) * m->weight * (a ? 2.0 : 1.0);
        /* B[Δx][row] = Σ_Δy c[Δx][Δy] gain(Δy) e^{-2πi θ_row Δy / T} */
        const int d0 = -(ky - 1);
        for (int j = 0; j < ny; j++) y[j] = -alpha * (j - d->cy) * d0;
        wf_trig_sincos_turns(y, ny, post, post + ny); /* e^{-2πi α (j - cy) d0}: cos, sin */
        for (int a = 0; a < kx; a++) {
            const double *cr = m->cre + (size_t)a * nyc, *ci = m->cim + (size_t)a * nyc;
            for (int t = 0; t < nyc; t++) x[2 * t] = x[2 * t + 1] = 0.0;
            for (int t = m->lo[a]; t <= m->hi[a]; t++) {
                x[2 * t] = cr[t] * gy[t];
                x[2 * t + 1] = ci[t] * gy[t];
            }
            shift_phase(x, nyc, alpha * d->cy, tmp);
            double *ba = b + (size_t)a * ny * 2;
            wf_czt_run(zy, x, ba);
            for (int j = 0; j < ny; j++) {
                double br = ba[2 * j], bi = ba[2 * j + 1], c = post[j], s = post[ny + j];
                ba[2 * j] = br * c - bi * s;
                ba[2 * j + 1] = br * s + bi * c;
            }
        }
        /* out[row][i] += Re Σ_Δx gain(Δx) B[Δx][row] e^{-2πi θ_i Δx / T} */
        for (int j = 0; j < ny; j++) {
            for (int a = 0; a < kx; a++) {
                x[2 * a] = gx[a] * b[((size_t)a * ny + j) * 2];
                x[2 * a + 1] = gx[a] * b[((size_t)a * ny + j) * 2 + 1];
            }
            shift_phase(x, kx, alpha * d->cx, tmp);
            wf_czt_run(zx, x, y);
            double *o = out + (size_t)j * nx;
            for (int i = 0; i < nx; i++) o[i] += y[2 * i];
        }
    }
    if (!st) zero_outside_period(psf, d, 0, ny, out);
done:
    wf_czt_free(zy);
    wf_czt_free(zx);
    free(b);
    free(x);
    free(y);
    free(tmp);
    free(gy);
    free(gx);
    free(post);
    return st;
}

wf_status wf_psf_draw(const wf_psf *psf, const wf_psf_draw_opts *d, double *out)
{
    if (!psf) return wf_error(WF_ERR_INPUT, "psf draw: no PSF");
    wf_status st = check_draw(d);
    if (st) return st;
    if (d->czt) return draw_czt(psf, d, out);
    /* no more shares than ROW_BLOCK-row blocks: with thinner ones the column phasors each
     * share makes would dominate */
    int T = d->threads > 1 ? d->threads : 1, most = (d->ny + ROW_BLOCK - 1) / ROW_BLOCK;
    if (T > most) T = most;
    draw_job jb = {psf, d, out, T};
    return wf_parallel_for(T, T, draw_rows, &jb);
}

/* ---- cache ----------------------------------------------------------------------------- */

typedef struct table_entry {
    wf_psf_request req;
    wf_psf_table table;
    double *data;
} table_entry;

typedef struct model_entry {
    wf_psf_request req; /* optics and wavelengths; draw unused */
    wf_psf *psf;
    size_t bytes;
    long last_use;
} model_entry;

struct wf_psf_cache {
    pthread_mutex_t lock;
    size_t max_bytes, bytes, high_water;
    table_entry **tables; /* entries are handed out by pointer: each is its own allocation */
    int ntables, cap_tables;
    model_entry *models;
    int nmodels, cap_models;
    long clock;
    wf_psf_cache_stats stats;
};

wf_status wf_psf_cache_create(size_t max_bytes, wf_psf_cache **out)
{
    *out = NULL;
    if (max_bytes == 0) return wf_error(WF_ERR_RANGE, "psf cache: a zero-byte bound");
    wf_psf_cache *c = calloc(1, sizeof *c);
    if (!c) return wf_error(WF_ERR_NOMEM, "psf cache: cannot allocate");
    pthread_mutex_init(&c->lock, NULL);
    c->max_bytes = max_bytes;
    *out = c;
    return WF_OK;
}

void wf_psf_cache_destroy(wf_psf_cache *c)
{
    if (!c) return;
    for (int i = 0; i < c->ntables; i++) {
        free(c->tables[i]->data);
        free(c->tables[i]);
    }
    for (int i = 0; i < c->nmodels; i++) wf_psf_free(c->models[i].psf);
    free(c->tables);
    free(c->models);
    pthread_mutex_destroy(&c->lock);
    free(c);
}

static int same_optics(const wf_psf_request *a, const wf_psf_request *b)
{
    const wf_psf_optics *p = &a->optics, *q = &b->optics;
    if (p->sca != q->sca || p->group != q->group || p->pupil_bin != q->pupil_bin ||
        p->binning != q->binning || strcmp(p->data_dir, q->data_dir) || a->nlambda != b->nlambda)
        return 0;
    /* Without data the position changes nothing (flat wavefront). */
    if (p->data_dir[0] && (p->x != q->x || p->y != q->y)) return 0;
    for (int k = 0; k < a->nlambda; k++)
        if (a->lambda_nm[k] != b->lambda_nm[k] || a->weight[k] != b->weight[k]) return 0;
    return 1;
}

static int same_draw(const wf_psf_draw_opts *p, const wf_psf_draw_opts *q)
{
    return p->nx == q->nx && p->ny == q->ny && p->scale == q->scale && p->cx == q->cx &&
           p->cy == q->cy && p->pixel == q->pixel && p->det_scale == q->det_scale &&
           p->jitter == q->jitter && p->diffusion == q->diffusion && p->mtf == q->mtf &&
           p->mtf_ctx == q->mtf_ctx && p->galsim == q->galsim && p->czt == q->czt;
}

static void drop_models(wf_psf_cache *c, size_t need, const wf_psf *keep)
{
    /* Least recently used first; coefficient sets can always be rebuilt. */
    while (c->bytes + need > c->max_bytes) {
        int victim = -1;
        for (int i = 0; i < c->nmodels; i++)
            if (c->models[i].psf != keep &&
                (victim < 0 || c->models[i].last_use < c->models[victim].last_use))
                victim = i;
        if (victim < 0) return;
        c->bytes -= c->models[victim].bytes;
        wf_psf_free(c->models[victim].psf);
        c->models[victim] = c->models[--c->nmodels];
        c->stats.models_dropped++;
    }
}

static wf_status cache_get_locked(wf_psf_cache *c, const wf_psf_request *req,
                                  const wf_psf_table **out)
{
    c->stats.requests++;
    c->clock++;
    for (int i = 0; i < c->ntables; i++)
        if (same_optics(&c->tables[i]->req, req) &&
            same_draw(&c->tables[i]->req.draw, &req->draw)) {
            *out = &c->tables[i]->table;
            return WF_OK;
        }
    wf_status st = check_draw(&req->draw);
    if (st) return st;
    if (req->nlambda < 1 || req->nlambda > WF_PSF_MAX_LAMBDAS)
        return wf_error(WF_ERR_RANGE, "psf cache: %d wavelengths (1..%d)", req->nlambda,
                        WF_PSF_MAX_LAMBDAS);
    size_t tbytes = (size_t)req->draw.nx * req->draw.ny * sizeof(double);
    if (tbytes > c->max_bytes)
        return wf_error(WF_ERR_NOMEM, "psf cache: a %dx%d table (%zu kB) exceeds the %zu kB bound",
                        req->draw.nx, req->draw.ny, tbytes >> 10, c->max_bytes >> 10);

    model_entry *model = NULL;
    for (int i = 0; i < c->nmodels; i++)
        if (same_optics(&c->models[i].req, req)) model = &c->models[i];
    wf_psf *fresh = NULL;
    if (!model) {
        if ((st = wf_psf_build_optics(&req->optics, req->lambda_nm, req->weight, req->nlambda,
                                      &fresh)))
            return st;
        c->stats.models_built++;
    }
    const wf_psf *psf = model ? model->psf : fresh;
    if (model) model->last_use = c->clock;

    drop_models(c, tbytes, psf);
    if (c->bytes + tbytes > c->max_bytes) {
        wf_psf_free(fresh);
        return wf_error(WF_ERR_NOMEM, "psf cache: %d tables hold %zu kB; another %zu kB table "
                        "exceeds the %zu kB bound", c->ntables, c->bytes >> 10, tbytes >> 10,
                        c->max_bytes >> 10);
    }
    if (c->ntables == c->cap_tables) {
        int cap = c->cap_tables ? 2 * c->cap_tables : 8;
        table_entry **t = realloc(c->tables, (size_t)cap * sizeof *t);
        if (!t) {
            wf_psf_free(fresh);
            return wf_error(WF_ERR_NOMEM, "psf cache: cannot grow the table list");
        }
        c->tables = t;
        c->cap_tables = cap;
    }
    double *data = malloc(tbytes);
    table_entry *e = calloc(1, sizeof *e);
    if (!data || !e) {
        free(data);
        free(e);
        wf_psf_free(fresh);
        return wf_error(WF_ERR_NOMEM, "psf cache: cannot allocate a %zu kB table", tbytes >> 10);
    }
    if ((st = wf_psf_draw(psf, &req->draw, data))) {
        free(data);
        free(e);
        wf_psf_free(fresh);
        return st;
    }
    c->tables[c->ntables++] = e;
    e->req = *req;
    e->data = data;
    e->table.draw = req->draw;
    e->table.data = data;
    double sum = 0.0;
    for (size_t i = 0; i < (size_t)req->draw.nx * req->draw.ny; i++) sum += data[i];
    e->table.sum = sum;
    const wf_psf_info info = psf->info;
    e->table.lambda_mean_nm = info.lambda_mean_nm;
    c->bytes += tbytes;
    c->stats.tables_built++;

    if (fresh) {
        /* Keep the coefficients for other draws of the same optics when they fit. */
        size_t mb = info.bytes;
        drop_models(c, mb, NULL);
        int room = c->bytes + mb <= c->max_bytes;
        if (room && c->nmodels == c->cap_models) {
            int cap = c->cap_models ? 2 * c->cap_models : 8;
            model_entry *mm = realloc(c->models, (size_t)cap * sizeof *mm);
            if (mm) {
                c->models = mm;
                c->cap_models = cap;
            } else {
                room = 0;
            }
        }
        if (room) {
            model_entry *me = &c->models[c->nmodels++];
            me->req = *req;
            me->psf = fresh;
            me->bytes = mb;
            me->last_use = c->clock;
            c->bytes += mb;
        } else {
            wf_psf_free(fresh);
        }
    }
    if (c->bytes > c->high_water) c->high_water = c->bytes;
    *out = &e->table;
    return WF_OK;
}

wf_status wf_psf_cache_get(wf_psf_cache *c, const wf_psf_request *req, const wf_psf_table **out)
{
    *out = NULL;
    if (!c || !req) return wf_error(WF_ERR_INPUT, "psf cache: no cache or request");
    pthread_mutex_lock(&c->lock);
    wf_status st = cache_get_locked(c, req, out);
    pthread_mutex_unlock(&c->lock);
    return st;
}

wf_status wf_psf_table_image(const wf_psf_table *t, wf_psf_image *out)
{
    memset(out, 0, sizeof *out);
    if (!t || !t->data) return wf_error(WF_ERR_INPUT, "psf table: none given");
    const wf_psf_draw_opts *d = &t->draw;
    if (d->nx != d->ny || d->pixel || d->cx != 0.5 * (d->nx - 1) || d->cy != 0.5 * (d->ny - 1))
        return wf_error(WF_ERR_INPUT,
                        "psf table: %dx%d, centre (%g, %g), pixel %s: the profile drawer takes a "
                        "square table centred at (n-1)/2 without the pixel response",
                        d->nx, d->ny, d->cx, d->cy, d->pixel ? "on" : "off");
    out->n = d->nx;
    out->scale_arcsec = d->scale;
    out->pix = t->data;
    return WF_OK;
}

void wf_psf_cache_get_stats(wf_psf_cache *c, wf_psf_cache_stats *out)
{
    pthread_mutex_lock(&c->lock);
    *out = c->stats;
    out->bytes = c->bytes;
    out->high_water = c->high_water;
    out->max_bytes = c->max_bytes;
    out->tables = c->ntables;
    out->models = c->nmodels;
    pthread_mutex_unlock(&c->lock);
}
