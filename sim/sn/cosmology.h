/* Distances in a flat ΛCDM universe (SPEC §5; docs/SN_POPULATION.md).
 *
 * Model: E(z) = H(z)/H0 = sqrt(Ωm (1+z)³ + ΩΛ), ΩΛ = 1 − Ωm, no curvature and no radiation.
 * Neglecting radiation (photons and neutrinos) changes D_C by −9e-5 at z = 1, −2.1e-4 at
 * z = 3 and −4.3e-4 at z = 10 relative to astropy's FlatLambdaCDM(70, 0.315, Tcmb0=2.7255):
 * the project compares with SNANA-style inputs that ignore it, and the tests compare with
 * Tcmb0 = 0. Defaults H0 = 70 km/s/Mpc, Ωm = 0.315 (SPEC §5).
 *
 * Units: distances in Mpc, c = 299792.458 km/s, the volume element dV/dz/dΩ in Mpc³ sr⁻¹
 * per unit redshift, the distance modulus μ = 5 log10(D_L / 10 pc) in mag.
 *
 * Method: D_C = (c/H0) ∫0^z dz'/E(z'). With u = (1+z)^(−1/2) the integrand becomes
 * 2 / sqrt(Ωm + ΩΛ u⁶) du on [(1+z)^(−1/2), 1], constant for Ωm = 1 and 2/(√ΩΛ u³) for
 * Ωm = 0, and smooth in between; it is integrated by 16-point Gauss–Legendre on panels of
 * width ≤ 0.1 in u (at most 7 panels up to z = 10). The complex singularities of the
 * integrand stay at least ~0.1 from the real interval for every Ωm in [0, 1], so the rule's
 * error is below 1e-15 relative. Measured (tests/test_cosmology.c): ≤ 6e-16 against the
 * Ωm = 0 and 1 closed forms, ≤ 2e-14 against composite Simpson for 0.0005 ≤ Ωm ≤ 0.999 up
 * to z = 10, ≤ 3e-14 against astropy (Tcmb0 = 0) for z ≥ 0.01. The panel ends are placed
 * without cancellation, so the relative accuracy holds down to z → 0 (1e-12 checked against
 * the series at z = 1e-12).
 *
 * Accepted: 0 ≤ z ≤ WF_COSMO_ZMAX, finite (z = 0 gives zero distances and volume; the
 * distance modulus needs z > 0). Parameters: 1 ≤ H0 ≤ 1000 km/s/Mpc (a value below 1 is
 * most likely h rather than H0), 0 ≤ Ωm ≤ 1 (ΩΛ ≥ 0). */
#ifndef WF_COSMOLOGY_H
#define WF_COSMOLOGY_H

#include "hal/status.h"

#define WF_COSMO_C_KMS 299792.458  /* speed of light, km/s */
#define WF_COSMO_H0_DEFAULT 70.0   /* km/s/Mpc, SPEC §5 */
#define WF_COSMO_OM_DEFAULT 0.315  /* SPEC §5 */
#define WF_COSMO_ZMAX 10.0         /* radiation, neglected here, matters beyond */

typedef struct wf_cosmo {
    double h0;  /* km/s/Mpc */
    double om;  /* Ωm */
    double ol;  /* ΩΛ = 1 − Ωm */
    double dh;  /* Hubble distance c/H0, Mpc */
} wf_cosmo;

/* Flat ΛCDM with H0 (km/s/Mpc) and Ωm; a value out of range (above) is an error naming it. */
wf_status wf_cosmo_init(wf_cosmo *c, double h0, double om);

/* H(z) in km/s/Mpc. */
wf_status wf_cosmo_hubble(const wf_cosmo *c, double z, double *km_s_mpc);

/* Line-of-sight comoving distance D_C (= transverse comoving distance, flat), Mpc. */
wf_status wf_cosmo_comoving_distance(const wf_cosmo *c, double z, double *mpc);

/* D_L = (1+z) D_C, Mpc. */
wf_status wf_cosmo_luminosity_distance(const wf_cosmo *c, double z, double *mpc);

/* μ = 5 log10(D_L / Mpc) + 25; z must be > 0. */
wf_status wf_cosmo_distance_modulus(const wf_cosmo *c, double z, double *mu);

/* Comoving volume element dV/dz/dΩ = (c/H0) D_C² / E(z), Mpc³ sr⁻¹. */
wf_status wf_cosmo_dvdz(const wf_cosmo *c, double z, double *mpc3_per_sr);


#endif
