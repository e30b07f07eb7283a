/* SALT2/SALT3 Type Ia supernova light curves and their synthetic photometry (SPEC §5;
 * docs/SN_LIGHTCURVES.md has the measurements behind every number below).
 *
 * Model files (standard SALT format, as SNANA and sncosmo read them), in one directory:
 *   <p>_template_0.dat, <p>_template_1.dat   M0, M1: "phase[d] wavelength[Å] value" rows on a
 *       rectangular grid, phase-major (both files on the same grid); p is "salt2" or "salt3";
 *   <p>_color_correction.dat   N, then N coefficients a_1..a_N, then keyword/value pairs
 *       Salt2ExtinctionLaw.version (must be 1), .min_lambda, .max_lambda (Å; default
 *       3000/7000 when absent, as sncosmo).
 *
 * Rest-frame flux, erg/s/cm²/Å (phase p in days from B maximum, λ in Å):
 *   F(p, λ) = x0 · 1e-12 · [M0(p, λ) + x1 M1(p, λ)] · 10^(−0.4 c CL(λ))
 * CL(λ) = −P(x) with x = (λ − 4302.57)/(5428.55 − 4302.57) and P(x) = α x + Σ a_k x^(k+1),
 * α = 1 − Σ a_k (so CL = 0 at B, −1 at V: c is a B−V colour excess). Between min_lambda and
 * max_lambda P is the polynomial; outside it is continued by its tangent at the nearer edge
 * (linear in x). This is the SPEC §5 formula, whose 10^(+0.4 c P) equals 10^(−0.4 c CL): a
 * larger c makes the SN fainter blueward of B (P < 0 there) and brighter redward.
 *
 * Observer frame at redshift z, date t (MJD): f(t, λ) = F((t − t0)/(1+z), λ/(1+z)) / (1+z).
 * Band count rate [e-/s] = A_coll ∫ T(λ) f(λ) λ/(hc) dλ over the bandpass (sim/optics/bandpass.h).
 *
 * Interpolation of M0, M1 between grid nodes (wf_salt_interp):
 *  - BICUBIC: snfit's Grid2DFunction as sncosmo's BicubicInterpolator implements it: cubic
 *    convolution (Keys kernel, a = −0.5) in phase and wavelength, except that a point in the
 *    first interval or the last two intervals of either axis is interpolated bilinearly in
 *    both axes. This is what sncosmo's SALT2Source/SALT3Source do;
 *  - LINEAR: bilinear everywhere.
 * Both reproduce the node values exactly; between nodes the spectra differ by up to 0.5% and
 * band magnitudes by up to 0.002 mag (SALT2 and SALT3, Y106–F184).
 *
 * Outside the model (never NaN, never negative, always flagged):
 *  - phase: a rest phase outside [first, last] grid phase (−20…+50 d for both shipped models,
 *    ends included) gives rate 0 and WF_SALT_OUT_PHASE;
 *  - wavelength: a band is covered when its whole sampled range [blue_nm, red_nm] (where
 *    T > 0, plus the one zero sample kept at each end) divided by 1+z lies inside the model's
 *    [first, last] grid wavelength — the rule sncosmo applies (it raises an error instead).
 *    An uncovered band gives rate 0 and WF_SALT_OUT_WAVE at every date, with no partial
 *    integral;
 *  - negative flux: M0 + x1 M1 is negative at some template edges; the band integral
 *    includes those parts as sncosmo does, and a band rate that comes out below zero is
 *    returned as 0 with WF_SALT_NEG_FLUX. wf_salt_flux alone returns the signed model value.
 * A rate of 0 has magnitude WF_SALT_MAG_NONE (99).
 *
 * Two evaluation paths, which agree to 3e-6 mag (their wavelength quadratures differ; both
 * agree with sncosmo to 2e-6 mag):
 *  - wf_salt_bandrate: the 2-D interpolant integrated by wf_bandpass_countrate_sed (Simpson,
 *    ≤ 1 nm steps), ~60–100 µs a call: for checks and single points;
 *  - wf_salt_lc_*: one object per (model, SN, band). Because the integrand is linear in the
 *    template values, ∫ T f λ dλ at any phase is the same phase weights applied to band
 *    integrals of the template's phase rows; init (~40–60 µs) computes those (3-point
 *    Gauss–Legendre on every piece between band samples and redshifted template nodes), and
 *    a date then costs a phase search and ≤ 6 multiply-adds (~25 ns). This is the 2-D
 *    scheme exactly, cubic in phase with its bilinear edge rule, not an approximation of it.
 *
 * The model and light-curve objects are read-only after creation: any number of threads may
 * use them at once. */
#ifndef WF_SALT_H
#define WF_SALT_H

#include "hal/status.h"
#include "sim/optics/bandpass.h"

#define WF_SALT_MAG_NONE 99.0 /* magnitude reported for a rate of 0 */
#define WF_SALT_MAX_COLOR_COEFFS 10

/* Flag bits of a band evaluation. */
enum {
    WF_SALT_OUT_PHASE = 1u, /* rest phase outside the model's phase range */
    WF_SALT_OUT_WAVE = 2u,  /* band, redshifted to rest, not inside the model's wavelengths */
    WF_SALT_NEG_FLUX = 4u   /* band integral was negative, returned as 0 */
};

typedef enum wf_salt_interp {
    WF_SALT_INTERP_BICUBIC = 0, /* sncosmo / snfit (the default) */
    WF_SALT_INTERP_LINEAR = 1
} wf_salt_interp;

typedef struct wf_salt_model wf_salt_model; /* grids and colour law, opaque */

/* One supernova: redshift (>= 0), date of B maximum t0 (MJD), amplitude x0 (>= 0),
 * stretch x1, colour c. SPEC §5 / SNANA: x0 = 1 / (1e-12 · 10^(0.4 (μ − α x1 + β c))). */
typedef struct wf_salt_params {
    double z, t0, x0, x1, c;
} wf_salt_params;

/* Reads the model in dir (which must hold exactly one of the salt2_ / salt3_ file sets).
 * Errors name the file, line and field at fault. */
wf_status wf_salt_load(const char *dir, wf_salt_model **out);
void wf_salt_free(wf_salt_model *m);

/* "salt2" or "salt3" (the file prefix found). */
const char *wf_salt_name(const wf_salt_model *m);
/* Rest-frame phase range (days) and wavelength range (Å) of the grid, ends included. */
void wf_salt_phase_range(const wf_salt_model *m, double *min_day, double *max_day);
void wf_salt_wave_range(const wf_salt_model *m, double *min_aa, double *max_aa);
/* CL(λ) in magnitudes for c = 1 (sncosmo's colorlaw): 0 at 4302.57 Å, −1 at 5428.55 Å. */
double wf_salt_colorlaw(const wf_salt_model *m, double rest_wave_aa);

/* Rest-frame F(p, λ) in erg/s/cm²/Å (z and t0 unused); 0 outside the grid; may be negative
 * where M0 + x1 M1 is. */
wf_status wf_salt_flux(const wf_salt_model *m, const wf_salt_params *p, wf_salt_interp interp,
                       double rest_phase, double rest_wave_aa, double *f);

/* Count rate [e-/s] through bp at date mjd, by the 2-D interpolant; flags as above (may be
 * NULL). */
wf_status wf_salt_bandrate(const wf_salt_model *m, const wf_salt_params *p,
                           wf_salt_interp interp, const wf_bandpass *bp, double mjd,
                           double *rate, unsigned *flags);
/* The same as an AB magnitude (bp's zero point); WF_SALT_MAG_NONE when the rate is 0. */
wf_status wf_salt_bandmag(const wf_salt_model *m, const wf_salt_params *p,
                          wf_salt_interp interp, const wf_bandpass *bp, double mjd,
                          double *mag_ab, unsigned *flags);

/* ---- fast per-SN light curve in one band ---- */
typedef struct wf_salt_lc wf_salt_lc; /* self-contained: outlives model and bandpass */

wf_status wf_salt_lc_init(const wf_salt_model *m, const wf_salt_params *p,
                          const wf_bandpass *bp, wf_salt_interp interp, wf_salt_lc **out);
wf_status wf_salt_lc_rate(const wf_salt_lc *lc, double mjd, double *rate, unsigned *flags);
wf_status wf_salt_lc_mag(const wf_salt_lc *lc, double mjd, double *mag_ab, unsigned *flags);
/* Observer-frame dates [t0 + (1+z) p_min, t0 + (1+z) p_max] inside the model; *covered is 0
 * when the band is outside the model's wavelengths (WF_SALT_OUT_WAVE at every date). */
void wf_salt_lc_window(const wf_salt_lc *lc, double *mjd_min, double *mjd_max, int *covered);
void wf_salt_lc_free(wf_salt_lc *lc);

#endif
