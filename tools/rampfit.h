/* Ramp fitting on the ground side: slope per pixel from unevenly spaced, averaged resultants.
 * Weighted least squares in the resultants' mean times t-bar with Casertano et al. (2022)
 * S/N-dependent power-law weights (as stcal's ols_cas22), read and Poisson variance of that
 * estimator in closed form, jump detection on resultant differences with the stcal threshold
 * 5.5 - log10(slope)/3 (slope clipped to [1, 1e4] e-/s), refitting around each jump
 * (segments combined by inverse variance), and fits only of unsaturated resultants.
 * Rates are e-/s; resultants are given in electrons (ADU x gain). */
#ifndef WF_RAMPFIT_H
#define WF_RAMPFIT_H

#include <stdint.h>
#include "hal/clock.h"
#include "hal/dq.h"
#include "hal/status.h"

#define WF_RAMPFIT_POWER_LEVELS 6 /* Casertano's powers 0, 0.4, 1, 3, 6, 10 */

typedef struct wf_rampfit_setup {
    int nres;
    int nreads[WF_MA_MAX_RESULTANTS];
    double tbar[WF_MA_MAX_RESULTANTS]; /* mean read time of each resultant, s */
    double tau[WF_MA_MAX_RESULTANTS];  /* Poisson variance time: Var(R_i) = rate * tau_i */
    double read_noise;                 /* e- per read */
    int detect_jumps;                  /* [1] */
    double jump_threshold;             /* <= 0: stcal's slope-dependent threshold [0] */
    /* Made by wf_rampfit_setup_init from the MA table's fields above (changing those needs
     * init again: a fit refuses times that no longer match, changed nreads go unseen; the
     * other fields may change):
     * the whole ramp's slope coefficients for each Casertano power level, with their read
     * and Poisson variance factors. */
    int full_nres; /* the nres they are for (0: none, fit without them) */
    double full_c[WF_RAMPFIT_POWER_LEVELS][WF_MA_MAX_RESULTANTS];
    double full_cr[WF_RAMPFIT_POWER_LEVELS], full_cp[WF_RAMPFIT_POWER_LEVELS];
    /* and per pair of neighbours (i, i + 1): 1/n_i + 1/n_{i+1}, tau_i + tau_{i+1} - 2 tbar_i,
     * tbar_{i+1} - tbar_i, tbar_{i+1} - tau_{i+1} */
    double pair_inv_n[WF_MA_MAX_RESULTANTS], pair_tau[WF_MA_MAX_RESULTANTS];
    double pair_dt[WF_MA_MAX_RESULTANTS], pair_off[WF_MA_MAX_RESULTANTS];
} wf_rampfit_setup;

typedef struct wf_rampfit_result {
    double rate;        /* e-/s */
    double var_read;    /* (e-/s)^2 */
    double var_poisson; /* (e-/s)^2, at the fitted rate (clipped at 0) */
    double poisson_coef; /* var_poisson = max(rate, 0) * poisson_coef, (e-/s)^2 per e-/s: lets
                          * a caller evaluate the Poisson term at a less noisy rate, since the
                          * clip at 0 overstates it where fitted rates are often negative */
    uint32_t dq;        /* WF_DQ_* */
    int njumps;
} wf_rampfit_result;

wf_status wf_rampfit_setup_init(const wf_clock *clock, double read_noise_e,
                                wf_rampfit_setup *out);

/* Fits one pixel. resultants[nres] in electrons; first_saturated = index of the first
 * resultant holding a saturated read (nres or more: none).
 * Defined results for short ramps: 2+ usable resultants -> fit with intercept; exactly 1 ->
 * rate = R0 / tbar0 (the reset level is zero in simulation); 0 usable (saturated in the
 * first resultant) -> rate = R0 / tbar0 as a lower bound, DQ SATURATED | DO_NOT_USE.
 * Variances are always those of the estimator returned. When jumps leave no two adjacent
 * clean resultants, the one-resultant estimate is used if R0 is clean (DQ JUMP_DET), else
 * the fit ignoring jumps (DQ JUMP_DET | DO_NOT_USE). The power of the Casertano weights is
 * chosen from the S/N of a GLS slope, not a first-pass OLS one (see rampfit.c). Returns
 * WF_ERR_INPUT for NULL pointers, an invalid setup, first_saturated < 0 or a non-finite
 * resultant among those used; WF_ERR_RANGE for one beyond 1e30 e-. */
wf_status wf_rampfit_pixel(const wf_rampfit_setup *setup, const double *resultants,
                           int first_saturated, wf_rampfit_result *out);

/* wf_rampfit_pixel on n pixels, with the same results: pixel p's resultants at
 * resultants[p * stride ...], its first saturated resultant first_saturated[p]. The setup is
 * checked once, and unsaturated ramps are fitted several at a time. On an error *bad (when
 * not NULL) is the pixel's index, else -1. */
wf_status wf_rampfit_pixels(const wf_rampfit_setup *setup, const double *resultants, int stride,
                            const int *first_saturated, int n, wf_rampfit_result *out, int *bad);

#endif
