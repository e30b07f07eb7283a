/* The statistics of `wfisim efficiency` (analysis/efficiency.h): one-to-one sky matching,
 * the Wilson binomial interval and the maximum-likelihood fit of a completeness curve to
 * per-object found / not-found data (docs/ANALYSIS.md, "wfisim efficiency"). */
#ifndef WF_EFFSTATS_H
#define WF_EFFSTATS_H

#include "hal/status.h"

/* Pairs objects of set a with objects of set b (RA, Dec in degrees) separated by at most
 * radius_deg, one to one, closest pairs first (ties: lower a index, then lower b index), so
 * that a second detection near an object never takes it from the closer one. a_to_b[i] is
 * the b index paired with a[i] or -1; b_to_a likewise (either may be NULL). */
wf_status wf_eff_match(const double *ra_a, const double *dec_a, long na, const double *ra_b,
                       const double *dec_b, long nb, double radius_deg, long *a_to_b, long *b_to_a);

/* Wilson's score interval for k successes in n trials at z standard deviations (z = 1: the
 * 68.27% interval): the p with |k/n - p| = z sqrt(p(1-p)/n). n = 0 gives [0, 1]. */
void wf_eff_wilson(long k, long n, double z, double *lo, double *hi);

/* eff(m) = plateau / (1 + exp((m - mc) / width)), mc = m50 - width ln(2 plateau - 1), so that
 * eff(m50) = 1/2 exactly; plateau in (1/2, 1], width > 0. */
typedef struct wf_eff_fit {
    int ok;                 /* 0: too few objects or no transition: nothing below is set */
    long n, nfound;         /* objects fitted */
    double m50, m50_err;    /* magnitude of 50% efficiency and its 1-sigma error */
    double width, width_err;
    double plateau, plateau_err; /* plateau_err 0 when the fit sits at plateau 1 */
    double loglike;
} wf_eff_fit;

/* The curve at mag for a fit (ok must be 1). */
double wf_eff_curve(const wf_eff_fit *fit, double mag);

/* Maximum likelihood over the n objects (Bernoulli: found[i] with probability eff(mag[i])),
 * errors from the inverse Fisher information. Needs at least 3 found and 3 missed objects and
 * a 50% point within a magnitude of the data; otherwise fit->ok = 0 and WF_OK. */
wf_status wf_eff_fit_curve(const double *mag, const unsigned char *found, long n, wf_eff_fit *fit);

#endif
