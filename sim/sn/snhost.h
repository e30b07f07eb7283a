/* Supernova host galaxies (SPEC §5 "Hosts"): weights, the choice of a host for a SN of
 * given redshift, and the SN's position on the host's light. docs/SN_HOSTS.md has the
 * derivations, the conventions and the measured test results.
 *
 * Weight (Andersen & Hjorth 2018 as encoded for the Roman host library, Wang et al. §3.1):
 *   w = sSNR × M*,  sSNR = 1.12e-7 · sSFR^0.586 yr⁻¹ M☉⁻¹,  sSFR = SFR / M* in yr⁻¹ clamped to
 *   [1.01e-11, 1.04e-9], from the catalog's logmass and logsfr (log10 M☉, log10 M☉/yr).
 *   w is in SNe Ia per year; only its ratios between galaxies matter for the choice.
 *
 * Choice: the candidates are the galaxies with |z_gal − z_sn| <= dz(z_sn), dz(z) = a0 + a1 z
 *   + a2 z² (SNANA's HOSTLIB_DZTOL polynomial; default a0 = 0.01, a1 = a2 = 0; a negative
 *   value counts as 0), drawn with probability ∝ w. The index sorts galaxies by z and keeps
 *   prefix sums of w, so a choice is two binary searches for the window and one for the
 *   weight: O(log n). No candidate → row −1: the SN is hostless (the caller keeps its own
 *   position and records no host; the tolerance is never widened).
 *
 * Placement (SNANA GEN_SNHOST_POS): the bulge with probability bulge_frac, else the disk;
 *   the enclosed-flux fraction F uniform in [0, fmax] (default 0.99); the radius from the
 *   round Sérsic profile of that component, F = P(2n, b_n (r/r_e)^(1/n)) (P the regularized
 *   lower incomplete gamma function, b_n from P(2n, b_n) = 1/2; n = 1 disk, 4 bulge; r_e the
 *   catalog's circularised half-light radius); an angle φ uniform in [0, 2π) in the round
 *   frame; then the same area-preserving shear (distortion e1, e2) and rotation (pa,
 *   counter-clockwise) the renderer applies to the galaxy (sim/draw/profile.h, sim/draw/scene.c
 *   pixel_shape), in the catalog's sky frame: +u west (decreasing RA), +v north, GalSim's
 *   convention. Uniform φ before the shear puts the SN at the same place SNANA does
 *   (since its Nov 2019 fix, SNANA draws the polar angle of a uniform point in the ellipse
 *   and scales the half-light ellipse's radius in that direction, which is the same map).
 *   Knots follow the exponential disk, so the disk profile stands for them too.
 *   The offset (east = −u, north = v) lies on the tangent plane at the host, turned into RA,
 *   Dec by the WCS's gnomonic inverse, wf_wcs_tangent_deproject (projecting RA, Dec back
 *   returns the offset to ~1e-10″). The angular separation is atan(ρ) ≈ ρ − ρ³/3 for a
 *   planar offset ρ: 8e-9″ short at 10″, 6e-11″ at 2″ (a double RA near 71° resolves
 *   5e-11″); the renderer's shear through the local WCS Jacobian agrees to the same order.
 *
 * Draws: three wf_rng_uniform53 from the stream passed in, in this order: component, F, φ
 * (always three, even when bulge_frac is 0 or 1). The caller keys the stream per SN.
 * cfg may be NULL everywhere: the defaults. */
#ifndef WF_SNHOST_H
#define WF_SNHOST_H

#include <stddef.h>

#include "hal/noise.h"
#include "hal/status.h"
#include "sim/survey/catalog.h"

typedef struct wf_snhost_config {
    double dztol[3];  /* dz(z) = dztol[0] + dztol[1] z + dztol[2] z² [0.01, 0, 0] */
    double fmax;      /* largest enclosed-flux fraction, [0, 1) [0.99] */
    double ssnr_norm; /* sSNR = ssnr_norm · sSFR^ssnr_slope, yr⁻¹ M☉⁻¹ [1.12e-7] */
    double ssnr_slope;                 /* [0.586] */
    double ssfr_min, ssfr_max;         /* clamp of sSFR, yr⁻¹ [1.01e-11, 1.04e-9] */
} wf_snhost_config;

void wf_snhost_config_default(wf_snhost_config *cfg);
/* WF_ERR_RANGE naming the field when a value is unusable. */
wf_status wf_snhost_config_check(const wf_snhost_config *cfg);

/* SN Ia rate of one galaxy, yr⁻¹ (above). */
wf_status wf_snhost_weight(const wf_snhost_config *cfg, double logmass, double logsfr,
                           double *weight);

typedef struct wf_snhost_index wf_snhost_index;

/* Index of the galaxies of gal (it keeps row numbers, not a pointer to gal). Errors: a star catalog; no z, logmass or logsfr column
 * (WF_ERR_INPUT naming the missing column: the caller handles a hostless-only run);
 * a non-finite z, logmass or logsfr (naming the row); more than 2^32 − 1 rows. */
wf_status wf_snhost_index_build(const wf_catalog *gal, const wf_snhost_config *cfg,
                                wf_snhost_index **out);
/* One host for a SN at redshift z_sn from u uniform in [0, 1]: *row is the catalog row or
 * −1 when no galaxy is within dz(z_sn) (hostless); *ncand the number of candidates. Read
 * only: any number of threads may choose from one index. */
wf_status wf_snhost_choose(const wf_snhost_index *idx, double z_sn, double u, long *row,
                           long *ncand);
void wf_snhost_index_free(wf_snhost_index *idx);

typedef struct wf_snhost_position {
    double ra, dec;          /* the SN, degrees (ra in [0, 360)) */
    double d_east, d_north;  /* offset from the host centre on its tangent plane, arcsec */
    double offset;           /* hypot(d_east, d_north), arcsec */
    int component;           /* 0 disk (n = 1), 1 bulge (n = 4) */
    double frac;             /* enclosed-flux fraction F, [0, fmax] */
    double r_circ;           /* radius of F in the round profile (before the shear), arcsec */
    double phi;              /* angle in the round frame, radians, from +u (west) to +v */
} wf_snhost_position;

/* Draws the SN's position on host row of gal (above). */
wf_status wf_snhost_place(const wf_catalog *gal, size_t row, wf_rng *rng,
                          const wf_snhost_config *cfg, wf_snhost_position *out);
/* The same without draws: component 0/1, enclosed fraction frac in [0, 1), angle phi. */
wf_status wf_snhost_place_at(const wf_catalog *gal, size_t row, int component, double frac,
                             double phi, wf_snhost_position *out);

/* The host's semi-major axis for SN isolation (SPEC §8: an SN counts as isolated beyond 1.5x
 * it): the half-light ellipse's semi-major axis, r_e sqrt((1 + |g|) / (1 - |g|)) under the
 * area-preserving shear g of the placement above, of the component holding most of the light
 * (the bulge when bulge_frac > 1/2, else the disk), arcsec. */
wf_status wf_snhost_semimajor(const wf_catalog *gal, size_t row, double *a);

/* Sérsic helpers for whole-number n in [1, 20] (the host model's n = 1 and 4), on the
 * profile code's P(2n, x) and b_n (sim/draw/profile.h); the radius inverts P by bracketed Newton
 * (tests/test_snhost.c: 1e-12 against bisection). */
/* b_n with P(2n, b_n) = 1/2 (b_1 = 1.678347, b_4 = 7.669249). */
wf_status wf_snhost_sersic_bn(double n, double *bn);
/* Fraction of a round Sérsic profile's flux within x = r / r_e. */
wf_status wf_snhost_sersic_enclosed(double n, double x, double *frac);
/* Its inverse: x = r / r_e enclosing frac in [0, 1). */
wf_status wf_snhost_sersic_radius(double n, double frac, double *x);

#endif
