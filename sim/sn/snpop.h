/* SN Ia population: SALT stretch x1, colour c, intrinsic scatter and amplitude x0 (SPEC §5;
 * docs/SN_POPULATION.md).
 *
 * x1 and c follow asymmetric Gaussians (Scolnic & Kessler 2016, "G10 high-z"): density
 * ∝ exp(−(x−peak)²/2σ−²) below the peak and exp(−(x−peak)²/2σ+²) above, truncated to
 * [lo, hi]. Sampling as SNANA does: the lower side with probability σ−/(σ− + σ+), then
 * x = peak − |N(0,1)| σ− or peak + |N(0,1)| σ+ (this is exactly the density above, which is
 * continuous at the peak); a value outside [lo, hi] is redrawn from the start (side and
 * value), which gives the truncated density renormalised.
 *
 * Standardisation (Tripp): the SN's distance-modulus-equivalent magnitude offset is
 *     μ − α x1 + β c + δ,   δ ~ N(0, σ_int²)  (coherent intrinsic scatter, mag)
 * and its SALT amplitude (SNANA SALT2x0calc with the SPEC's normalisation, M_B ≈ −19.365):
 *     x0 = 1 / (1e-12 · 10^(0.4 (μ − α x1 + β c + δ))).
 * δ enters only through x0 (x0 scaled by 10^(−0.4 δ)): it is grey, the simple option of SPEC
 * §5 (SNANA's G10 chromatic scatter is a refinement not modelled here).
 *
 * Randomness: wf_snpop_draw consumes the caller's stream, normally SN i's
 * wf_sn_rng(seed, i, WF_SN_DRAW_POP, ...) (sim/sn/snrate.h), in the order x1, c, δ. With a
 * WF_NOISE_OFF stream (Gaussians return 0) it gives x1 and c at their peaks and δ = 0. */
#ifndef WF_SNPOP_H
#define WF_SNPOP_H

#include "hal/noise.h"
#include "hal/status.h"

/* Smallest fraction of an asymmetric Gaussian that its [lo, hi] may hold: below it the
 * redraw loop would stall, and the validation refuses the parameters. */
#define WF_SNPOP_MIN_ACCEPT 1e-3

/* The largest |x1| and |c| any SN may have (sn.x1.*, sn.c.*, `sn lightcurve --x1 --c`): twice
 * the widest SALT training ranges, so that the Tripp magnitude and the model's colour law
 * stay finite numbers. */
#define WF_SNPOP_X1_LIMIT 10.0
#define WF_SNPOP_C_LIMIT 2.0
/* |alpha|, |beta| (sn.alpha, sn.beta, --alpha, --beta) and the distance modulus
 * (`sn lightcurve --mu`; z = 10, WF_COSMO_ZMAX, is mu ~ 52): within these x0 stays a
 * positive finite number whatever x1 and c are. */
#define WF_SNPOP_ALPHA_LIMIT 10.0
#define WF_SNPOP_BETA_LIMIT 20.0
#define WF_SNPOP_MU_MAX 100.0

typedef struct wf_snpop_agauss {
    double peak;
    double sigma_minus, sigma_plus; /* ≥ 0, not both 0 */
    double lo, hi;                  /* lo < hi, lo ≤ peak ≤ hi */
} wf_snpop_agauss;

typedef struct wf_snpop {
    wf_snpop_agauss x1; /* [peak 0.973, σ− 1.472, σ+ 0.222, range −3 … 2] */
    wf_snpop_agauss c;  /* [peak −0.054, σ− 0.043, σ+ 0.101, range −0.3 … 0.5] */
    double alpha;       /* [0.14] */
    double beta;        /* [3.1] */
    double sigma_int;   /* mag, ≥ 0 [0.10] */
} wf_snpop;

typedef struct wf_sn_params {
    double x1, c;
    double delta; /* intrinsic magnitude offset, mag */
    double mu;    /* distance modulus the amplitude was computed for, mag */
    double x0;    /* SALT amplitude */
} wf_sn_params;

/* SPEC §5 values (G10 high-z, α = 0.14, β = 3.1, σ_int = 0.10). */
void wf_snpop_default(wf_snpop *p);

/* Every field finite and in range; errors name the field ("x1.sigma_minus", "c.lo", ...). */
wf_status wf_snpop_validate(const wf_snpop *p);

/* One draw from a truncated asymmetric Gaussian (parameters assumed valid). */
wf_status wf_snpop_agauss_draw(const wf_snpop_agauss *g, wf_rng *rng, double *x);

/* x0 for given x1, c, δ at distance modulus mu. */
wf_status wf_snpop_x0(const wf_snpop *p, double mu, double x1, double c, double delta,
                      double *x0);

/* x1, c, δ from rng, and x0 at mu. */
wf_status wf_snpop_draw(const wf_snpop *p, wf_rng *rng, double mu, wf_sn_params *out);

#endif
