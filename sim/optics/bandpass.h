/* WFI filters, their bandpasses and the photometry built on them (SPEC §2; docs/SKY.md).
 *
 * A bandpass is a throughput curve T(λ) = A_eff(λ) / A_coll, the effective area divided by
 * the collecting area (3.757e4 cm², SPEC §2), treated as the linear interpolant of its samples
 * and zero outside them. Counting is of photons (the detector counts electrons, one per
 * detected photon, with the QE already inside A_eff):
 *
 *     rate [e-/s] = A_coll ∫ T(λ) f_λ(λ) λ / (h c) dλ
 *
 * so for a source flat in f_ν (AB magnitude m, f_ν = 3631 Jy · 10^(-0.4 m)):
 *
 *     rate = A_coll (f_ν / h) ∫ T(λ) / λ dλ.
 *
 * Zero points, effective and pivot wavelengths are integrals of that interpolant, computed
 * at load time in closed form on every linear piece, so they carry no quadrature error.
 *
 * Two sources of curves:
 *  - data: <data_dir>/roman/Roman_effarea_20210614.txt (GalSim's share/roman file, effective
 *    area in m² against wavelength in µm, one column per filter);
 *  - built-in: a top-hat of unit throughput over the SPEC §2 centre ± width/2. It is
 *    0.24–0.71 mag brighter than the real curve (whose throughput peaks at 0.62–0.80):
 *    good for running without data, not for photometry (docs/SKY.md has the numbers). */
#ifndef WF_BANDPASS_H
#define WF_BANDPASS_H

#include "hal/status.h"

typedef enum wf_filter {
    WF_R062 = 0,
    WF_Z087,
    WF_Y106,
    WF_J129,
    WF_H158,
    WF_F184,
    WF_K213,
    WF_W146, /* also called W149 */
    WF_NFILTER
} wf_filter;

#define WF_COLLECTING_AREA_CM2 3.757e4 /* SPEC §2, GalSim galsim/roman/__init__.py */
#define WF_BANDPASS_MAXN 2048          /* samples kept of one curve */
#define WF_BANDPASS_SOURCE_MAX 1200

/* Name ("R062" ... "W146"; "?" for a value that is not a filter). */
const char *wf_filter_name(wf_filter f);

/* Parses a filter name, case-insensitively; "W149" is accepted for W146. An unknown name is
 * an error that names it and lists the valid ones. */
/* 1 and *out set when name is a filter (W149 = W146), else 0; no error message is
 * recorded, so header scans can try every column name. */
int wf_filter_lookup(const char *name, wf_filter *out);

wf_status wf_filter_parse(const char *name, wf_filter *out);

/* The SPEC §2 filter facts (Wang et al. 2023 §2.1): central wavelength and width, nm. */
wf_status wf_filter_facts(wf_filter f, double *centre_nm, double *width_nm);

typedef struct wf_bandpass {
    wf_filter filter;
    int builtin;            /* 1: top-hat from the filter facts; 0: read from data */
    char source[WF_BANDPASS_SOURCE_MAX]; /* the file read, or why the top-hat was used */
    double area_cm2;        /* collecting area the throughput is relative to */
    int n;                  /* samples in wave_nm / throughput (>= 2) */
    double wave_nm[WF_BANDPASS_MAXN];    /* strictly increasing */
    double throughput[WF_BANDPASS_MAXN]; /* T = A_eff / area, >= 0 */
    /* Derived at load (all integrals of the linear interpolant): */
    double blue_nm, red_nm; /* where T > 0: the first and last samples kept */
    double zp_ab;           /* AB magnitude giving 1 e-/s */
    double zp_photon;       /* AB magnitude giving 1 photon/cm²/s (GalSim's zeropoint) */
    double lambda_eff_nm;   /* ∫λT dλ / ∫T dλ (GalSim's effective_wavelength) */
    double lambda_pivot_nm; /* sqrt(∫λT dλ / ∫T/λ dλ) */
    double int_t;           /* ∫T dλ, nm */
    double int_t_over_lambda; /* ∫T/λ dλ, dimensionless */
} wf_bandpass;

/* Loads the bandpass of filter f. data_dir is a folder laid out as ../shared/data (it holds
 * roman/Roman_effarea_20210614.txt). With data_dir NULL or "" or the file absent, the
 * built-in top-hat is used and out->source says which of those happened; a file that exists
 * but cannot be read or parsed is an error naming file, line and field. */
wf_status wf_bandpass_load(wf_filter f, const char *data_dir, wf_bandpass *out);

/* The built-in top-hat alone (what wf_bandpass_load falls back to). */
wf_status wf_bandpass_tophat(wf_filter f, wf_bandpass *out);

/* T(λ) by linear interpolation; 0 outside the samples. */
double wf_bandpass_throughput(const wf_bandpass *bp, double wave_nm);

/* e-/s from a source of AB magnitude mag with f_ν flat across the band. */
double wf_bandpass_countrate_ab(const wf_bandpass *bp, double mag);

/* AB magnitude of a flat-f_ν source giving rate e-/s; rate must be > 0. */
wf_status wf_bandpass_mag_ab(const wf_bandpass *bp, double rate, double *mag);

/* An SED: f_λ in erg/s/cm²/Å at wavelength wave_nm (observer frame). */
typedef double (*wf_bandpass_sed_fn)(double wave_nm, void *ctx);

/* e-/s from the SED: A_coll ∫ T f_λ λ/(hc) dλ over the bandpass. Composite Simpson on
 * every interval between throughput samples, subdivided to steps of at most 1 nm (the
 * throughput is linear inside an interval, so the only error is the SED's curvature over
 * 1 nm: < 1e-7 relative for smooth spectra). A non-finite f_λ is an error naming the
 * wavelength. */
wf_status wf_bandpass_countrate_sed(const wf_bandpass *bp, wf_bandpass_sed_fn sed, void *ctx,
                                    double *rate);

/* The same with a chosen maximum step (nm, > 0), for callers trading accuracy for time. */
wf_status wf_bandpass_countrate_sed_step(const wf_bandpass *bp, wf_bandpass_sed_fn sed,
                                         void *ctx, double max_step_nm, double *rate);

/* A flat-f_ν source's photons over the band in nl equal slices of [blue_nm, red_nm]: the
 * middle wavelength of each slice and its share ∫ T(λ)/λ dλ over the slice (normalised to sum
 * 1; 200-point midpoint rule per slice). The wavelengths and weights of a chromatic PSF. */
wf_status wf_bandpass_flat_slices(const wf_bandpass *bp, int nl, double *lambda_nm, double *weight);

#endif
