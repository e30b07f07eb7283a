#include "tools/rampfit.h"

#include <math.h>
#include <stddef.h>

#include "hal/simd.h"

/* One fitted stretch of consecutive resultants [start, end]. The Poisson variance is kept per
 * unit rate so that segments can be combined before the rate it is evaluated at is known. */
typedef struct seg_fit {
    int start, end;
    double slope;
    double var_read;
    double pois_coef; /* Var_poisson = rate * pois_coef */
} seg_fit;

static void derive_tables(wf_rampfit_setup *s);

/* max(v, 0), 0 for NaN, as fmax(v, 0.0) but inline: fmax is a call (its signed zeros are
 * not the compiler's to choose), which keeps the lanes' loops scalar. Both paths use it. */
static inline double pos(double v)
{
    return v > 0.0 ? v : 0.0;
}

wf_status wf_rampfit_setup_init(const wf_clock *clock, double read_noise_e,
                                wf_rampfit_setup *out)
{
    if (!clock || !out)
        return wf_error(WF_ERR_INPUT, "wf_rampfit_setup_init: NULL argument");
    const wf_ma_table *ma = &clock->ma;
    if (!(clock->frame_time > 0.0) || !isfinite(clock->frame_time))
        return wf_error(WF_ERR_INPUT, "ramp fit: frame time %g s is not positive", clock->frame_time);
    if (!(read_noise_e >= 0.0) || !isfinite(read_noise_e))
        return wf_error(WF_ERR_INPUT, "ramp fit: read noise %g e- is not >= 0", read_noise_e);
    if (ma->nresultants < 1 || ma->nresultants > WF_MA_MAX_RESULTANTS)
        return wf_error(WF_ERR_INPUT, "ramp fit: MA table '%s' has %d resultants (allowed 1..%d)",
                        ma->name, ma->nresultants, WF_MA_MAX_RESULTANTS);
    wf_rampfit_setup s = {0};
    s.nres = ma->nresultants;
    s.read_noise = read_noise_e;
    s.detect_jumps = 1;
    s.jump_threshold = 0.0;
    int last = -1;
    for (int r = 0; r < s.nres; r++) {
        int a = ma->first[r], b = ma->first[r + 1], n = b - a;
        if (n < 1 || a < 0 || b > ma->nreads || b > WF_MA_MAX_READS)
            return wf_error(WF_ERR_INPUT, "ramp fit: MA table '%s' resultant %d has no reads",
                            ma->name, r + 1);
        double sum_t = 0.0, sum_min = 0.0;
        for (int k = 0; k < n; k++) {
            if (ma->read[a + k] <= last)
                return wf_error(WF_ERR_INPUT, "ramp fit: MA table '%s' reads do not increase at resultant %d",
                                ma->name, r + 1);
            last = ma->read[a + k];
            double t = wf_clock_read_time(clock, ma->read[a + k]);
            sum_t += t;
            /* With reads in time order, min(t_a, t_b) over all ordered pairs counts read k
             * once as (k, k) and twice for each later read: 2(n-k)-1 times. */
            sum_min += (2.0 * (n - k) - 1.0) * t;
        }
        s.nreads[r] = n;
        s.tbar[r] = sum_t / n;
        s.tau[r] = sum_min / ((double)n * n);
    }
    derive_tables(&s);
    *out = s;
    return WF_OK;
}

static wf_status check_setup(const wf_rampfit_setup *s)
{
    if (s->nres < 1 || s->nres > WF_MA_MAX_RESULTANTS)
        return wf_error(WF_ERR_INPUT, "ramp fit: setup has %d resultants (allowed 1..%d)", s->nres,
                        WF_MA_MAX_RESULTANTS);
    if (!(s->read_noise >= 0.0) || !isfinite(s->read_noise))
        return wf_error(WF_ERR_INPUT, "ramp fit: read noise %g e- is not >= 0", s->read_noise);
    if (isnan(s->jump_threshold))
        return wf_error(WF_ERR_INPUT, "ramp fit: jump threshold is NaN");
    for (int r = 0; r < s->nres; r++) {
        if (s->nreads[r] < 1 || !(s->tbar[r] > 0.0) || !isfinite(s->tbar[r]) ||
            !(s->tau[r] >= 0.0) || !isfinite(s->tau[r]))
            return wf_error(WF_ERR_INPUT,
                            "ramp fit: setup resultant %d has nreads %d, tbar %g s, tau %g s",
                            r + 1, s->nreads[r], s->tbar[r], s->tau[r]);
        /* Strictly increasing tbar is what makes every 2+ resultant fit well-posed. */
        if (r > 0 && !(s->tbar[r] > s->tbar[r - 1]))
            return wf_error(WF_ERR_INPUT, "ramp fit: setup tbar does not increase at resultant %d",
                            r + 1);
        if (r > 0 && (s->pair_dt[r - 1] != s->tbar[r] - s->tbar[r - 1] ||
                      s->pair_tau[r - 1] != s->tau[r - 1] + s->tau[r] - 2.0 * s->tbar[r - 1]))
            return wf_error(WF_ERR_INPUT, "ramp fit: setup resultant %d changed after wf_rampfit_setup_init",
                            r + 1);
    }
    return WF_OK;
}

/* Casertano et al. (2022) Table 2: the power of |t - t_mid| in the weights, by S/N; level 0
 * (power 0) is the unweighted fit. */
static const double cas22_powers[WF_RAMPFIT_POWER_LEVELS] = {0.0, 0.4, 1.0, 3.0, 6.0, 10.0};

static int cas22_level(double snr)
{
    if (snr < 5.0) return 0;
    if (snr < 10.0) return 1;
    if (snr < 20.0) return 2;
    if (snr < 50.0) return 3;
    if (snr < 100.0) return 4;
    return 5;
}

/* Slope coefficients c_i (sum c_i = 0, sum c_i tbar_i = 1) for the weights w. Times are
 * centred on the weighted mean first: the textbook f0 f2 - f1^2 form cancels catastrophically
 * once tbar ~ 1e3 s and the power-law weights span many decades. Returns 0 when the weights
 * leave fewer than two distinct times. */
static int slope_coeffs(const double *tbar, const double *w, int m, double *c)
{
    double f0 = 0.0, f1 = 0.0;
    for (int i = 0; i < m; i++) {
        f0 += w[i];
        f1 += w[i] * tbar[i];
    }
    if (!(f0 > 0.0))
        return 0;
    double tw = f1 / f0, d = 0.0;
    for (int i = 0; i < m; i++)
        d += w[i] * (tbar[i] - tw) * (tbar[i] - tw);
    double span = tbar[m - 1] - tbar[0];
    /* Relative to the spread of times, d below this means one time carries all the weight. */
    if (!(d > 1e-300) || !(d > 1e-24 * f0 * span * span))
        return 0;
    for (int i = 0; i < m; i++)
        c[i] = w[i] * (tbar[i] - tw) / d;
    return 1;
}

/* Generalised least squares slope at an assumed rate, used only to choose the power.
 * Differences D_i = R_{i+1} - R_i remove the intercept and have a tridiagonal covariance
 * (neighbours share one resultant's reads; others share nothing), so GLS costs O(m):
 *   Var(D_i)          = rn^2 (1/n_i + 1/n_{i+1}) + rate (tau_i + tau_{i+1} - 2 tbar_i)
 *   Cov(D_i, D_{i+1}) = rate (tbar_{i+1} - tau_{i+1}) - rn^2 / n_{i+1}.
 * Why not choose the power from a plain first-pass slope: the chosen power then correlates
 * with the noise, and switching between two unbiased estimators on a noisy statistic biases
 * the mean (measured -0.01 sigma per pixel at Casertano's S/N boundaries). The minimum-
 * variance estimate is uncorrelated with the difference of any two unbiased estimators, so
 * choosing on it leaves no first-order bias. Returns 0 when the covariance is singular. */
static int gls_slope(const wf_rampfit_setup *su, int start, const double *R, int m, double rn2,
                     double rate, double *slope)
{
    const int k = m - 1;
    const int *n = su->nreads + start;
    const double *pn = su->pair_inv_n + start, *pt = su->pair_tau + start, *dt = su->pair_dt + start;
    const double *po = su->pair_off + start;
    double cdiag[WF_MA_MAX_RESULTANTS], x[WF_MA_MAX_RESULTANTS];
    double prev_off = 0.0, num = 0.0, den = 0.0;
    /* Thomas algorithm for C x = dt (C symmetric positive definite: no pivoting needed). */
    for (int i = 0; i < k; i++) {
        double diag = rn2 * pn[i] + rate * pt[i];
        double off = i + 1 < k ? rate * po[i] - rn2 / n[i + 1] : 0.0;
        double piv = diag - (i > 0 ? prev_off * cdiag[i - 1] : 0.0);
        if (!(piv > 1e-12 * diag))
            return 0; /* no read noise and no signal: nothing to weight by */
        const double inv = 1.0 / piv; /* one division a step (the fit's were half its time) */
        cdiag[i] = off * inv;
        x[i] = (dt[i] - (i > 0 ? prev_off * x[i - 1] : 0.0)) * inv;
        prev_off = off;
    }
    for (int i = k - 2; i >= 0; i--)
        x[i] -= cdiag[i] * x[i + 1];
    for (int i = 0; i < k; i++) {
        num += x[i] * (R[i + 1] - R[i]);
        den += x[i] * dt[i];
    }
    if (!(den > 0.0) || !isfinite(num / den))
        return 0;
    *slope = num / den;
    return 1;
}

/* The slope coefficients over m resultants for the weights of a power level: the unweighted
 * ones (weight n_i: every read counted once) at level 0, and where the power-law weights
 * leave fewer than two distinct times. */
static void level_coeffs(const double *t, const int *n, int m, int level, double *c)
{
    double w[WF_MA_MAX_RESULTANTS] = {0}, cw[WF_MA_MAX_RESULTANTS] = {0};
    for (int i = 0; i < m; i++)
        w[i] = n[i];
    (void)slope_coeffs(t, w, m, c); /* cannot fail: tbar strictly increasing, m >= 2 */
    if (level == 0)
        return;
    const double power = cas22_powers[level];
    double tmid = 0.5 * (t[0] + t[m - 1]), tscale = 0.5 * (t[m - 1] - t[0]);
    for (int i = 0; i < m; i++) {
        /* Casertano Eq. 45; scaled by tscale so |x|^10 stays within double range. */
        double x = fabs(t[i] - tmid) / tscale;
        w[i] = (1.0 + power) * n[i] / (1.0 + power * n[i]) * pow(x, power);
    }
    if (slope_coeffs(t, w, m, cw))
        for (int i = 0; i < m; i++)
            c[i] = cw[i];
}

/* Read and Poisson variance of the estimator sum c_i R_i, per unit read variance and per
 * unit rate: Var = sum_i c_i^2 tau_i + 2 sum_{i<j} c_i c_j tbar_i per unit rate, since
 * Cov(R_i, R_j) = rate * tbar_i for i < j; suffix holds sum_{j>i} c_j. */
static void coeff_variances(const double *c, const double *t, const double *tau, const int *n,
                            int m, double *cr, double *cp)
{
    double r = 0.0, p = 0.0, suffix = 0.0;
    for (int i = m - 1; i >= 0; i--) {
        r += c[i] * c[i] / n[i];
        p += c[i] * c[i] * tau[i] + 2.0 * c[i] * t[i] * suffix;
        suffix += c[i];
    }
    *cr = r;
    *cp = p;
}

/* The per-pair factors, and the whole ramp's coefficients for every power level, depend on
 * the MA table alone: made once here, not per pixel (the pow calls alone were a tenth of an
 * up-the-ramp exposure). */
static void derive_tables(wf_rampfit_setup *s)
{
    for (int i = 0; i + 1 < s->nres; i++) {
        s->pair_inv_n[i] = 1.0 / s->nreads[i] + 1.0 / s->nreads[i + 1];
        s->pair_tau[i] = s->tau[i] + s->tau[i + 1] - 2.0 * s->tbar[i];
        s->pair_dt[i] = s->tbar[i + 1] - s->tbar[i];
        s->pair_off[i] = s->tbar[i + 1] - s->tau[i + 1];
    }
    s->full_nres = 0;
    if (s->nres < 2)
        return;
    for (int l = 0; l < WF_RAMPFIT_POWER_LEVELS; l++) {
        level_coeffs(s->tbar, s->nreads, s->nres, l, s->full_c[l]);
        coeff_variances(s->full_c[l], s->tbar, s->tau, s->nreads, s->nres, &s->full_cr[l], &s->full_cp[l]);
    }
    s->full_nres = s->nres;
}

static void fit_segment(const wf_rampfit_setup *su, const double *res, int start, int end,
                        seg_fit *out)
{
    const int m = end - start + 1;
    const double *t = su->tbar + start, *R = res + start, *tau = su->tau + start;
    const int *n = su->nreads + start;
    const double rn2 = su->read_noise * su->read_noise;
    const int full = start == 0 && end == su->nres - 1 && su->full_nres == su->nres;
    double cu[WF_MA_MAX_RESULTANTS], cl[WF_MA_MAX_RESULTANTS];

    /* Unweighted first pass for the rate at which the GLS covariance is evaluated; GLS
     * weights vary slowly with rate, so this suffices. */
    const double *c = full ? su->full_c[0] : cu;
    if (!full)
        level_coeffs(t, n, m, 0, cu);
    double slope0 = 0.0;
    for (int i = 0; i < m; i++)
        slope0 += c[i] * R[i];
    double snr_slope = slope0;
    (void)gls_slope(su, start, R, m, rn2, pos(slope0), &snr_slope);

    /* Casertano Eq. 44 with the signal over this segment (as stcal: a segment after a jump
     * should not inherit the charge collected before it). */
    double signal = pos(snr_slope) * (t[m - 1] - t[0]);
    double noise = sqrt(rn2 + signal);
    int level = cas22_level(noise > 0.0 ? signal / noise : 0.0);

    double cr, cp;
    if (full) {
        c = su->full_c[level];
        cr = su->full_cr[level];
        cp = su->full_cp[level];
    } else {
        if (level > 0) {
            level_coeffs(t, n, m, level, cl);
            c = cl;
        }
        coeff_variances(c, t, tau, n, m, &cr, &cp);
    }
    double slope = 0.0;
    for (int i = m - 1; i >= 0; i--)
        slope += c[i] * R[i];
    out->start = start;
    out->end = end;
    out->slope = slope;
    out->var_read = rn2 * cr;
    out->pois_coef = pos(cp); /* a variance: only rounding can make it negative */
}

static double jump_threshold(const wf_rampfit_setup *su, double slope)
{
    if (su->jump_threshold > 0.0)
        return su->jump_threshold;
    double s = fmin(fmax(slope, 1.0), 1e4);
    return 5.5 - log10(s) / 3.0;
}

/* The largest standardized excess of a consecutive-resultant difference over the fitted
 * slope, one-sided because charge deposits only add. Its variance is that of the raw
 * difference (ignoring that the slope came from the same data), which is slightly larger
 * than the residual's, so the test errs against false jumps. Returns the index i of the
 * pair (i, i+1), or -1 when no difference has a positive variance. */
static int worst_difference(const wf_rampfit_setup *su, const double *res, const seg_fit *f,
                            double *stat)
{
    const double rn2 = su->read_noise * su->read_noise, rate = pos(f->slope);
    int best = -1;
    double best_stat = 0.0;
    for (int i = f->start; i < f->end; i++) {
        double d = res[i + 1] - res[i] - f->slope * su->pair_dt[i];
        double v = rn2 * su->pair_inv_n[i] + rate * su->pair_tau[i];
        if (!(v > 0.0))
            continue;
        double z = d / sqrt(v);
        if (best < 0 || z > best_stat) {
            best = i;
            best_stat = z;
        }
    }
    *stat = best_stat;
    return best;
}

/* Inverse-variance mean of independent segments: they share no reads (and so no Poisson
 * increments or read noise), which makes the combined variances exact sums. The Poisson part
 * of each weight is taken at one common rate, never at the segment's own slope, which would
 * down-weight segments that happened to fluctuate high and bias the mean low. */
static void combine(const seg_fit *f, int nf, wf_rampfit_result *out)
{
    double w[2 * WF_MA_MAX_RESULTANTS];
    double rate = 0.0;
    for (int pass = 0; pass < 2; pass++) {
        int all_read = 1;
        for (int k = 0; k < nf; k++)
            if (!(f[k].var_read > 0.0)) all_read = 0;
        double sw = 0.0, sr = 0.0;
        for (int k = 0; k < nf; k++) {
            double v;
            if (pass == 0)
                v = all_read ? f[k].var_read : f[k].pois_coef; /* no read noise: Poisson shape */
            else
                v = f[k].var_read + pos(rate) * f[k].pois_coef;
            w[k] = v > 0.0 ? 1.0 / v : 1.0;
            sw += w[k];
            sr += w[k] * f[k].slope;
        }
        rate = sr / sw;
    }
    double sw = 0.0, vr = 0.0, vp = 0.0;
    for (int k = 0; k < nf; k++)
        sw += w[k];
    for (int k = 0; k < nf; k++) {
        double a = w[k] / sw;
        vr += a * a * f[k].var_read;
        vp += a * a * f[k].pois_coef;
    }
    out->rate = rate;
    out->var_read = vr;
    out->poisson_coef = vp;
    out->var_poisson = pos(rate) * vp;
}

/* Rate from one resultant against a zero reset level (true in simulation; a real detector
 * would need the reset read). */
static void single_resultant(const wf_rampfit_setup *su, const double *res, int r,
                             wf_rampfit_result *out)
{
    double t = su->tbar[r];
    out->rate = res[r] / t;
    out->var_read = su->read_noise * su->read_noise / (su->nreads[r] * t * t);
    out->poisson_coef = su->tau[r] / (t * t);
    out->var_poisson = pos(out->rate) * out->poisson_coef;
}

static wf_status fit_pixel(const wf_rampfit_setup *setup, const double *resultants,
                           int first_saturated, wf_rampfit_result *out);

wf_status wf_rampfit_pixel(const wf_rampfit_setup *setup, const double *resultants,
                           int first_saturated, wf_rampfit_result *out)
{
    if (!setup || !resultants || !out)
        return wf_error(WF_ERR_INPUT, "wf_rampfit_pixel: NULL argument");
    wf_status st = check_setup(setup);
    if (st != WF_OK)
        return st;
    return fit_pixel(setup, resultants, first_saturated, out);
}

/* The whole ramp of up to RF_LANES pixels at once, for pixels whose every resultant is usable
 * and in range: fit_segment, the jump test of worst_difference and combine of one segment,
 * with the same operations in the same order on each pixel, so the same bits as
 * wf_rampfit_pixel. Pixel after pixel, the GLS's Thomas recursion is a chain of dependent
 * divisions, and the power level, the jump test and the combination are branches and
 * calls (~130 ns a pixel); here every step runs on all lanes at once in vector registers (two
 * chains of 8 side by side hide the divisions' latency), with lanes past L repeating lane 0
 * and dropped. A pixel whose ramp needs more (a difference near the jump threshold; a
 * singular covariance is not one: it keeps the first-pass slope as fit_segment does) is
 * marked for the one-pixel path. rn2_n[i] = rn2 / n_i. */
#define RF_LANES 16
_Static_assert(WF_RAMPFIT_POWER_LEVELS == 6, "level_pick picks one of six levels");

/* t[level] as a chain of selects (level a double 0..5): a blend in vector lanes, not a gather.
 * All six are loaded first: a load under a condition is control flow to the vectoriser (GCC
 * 12 left the loops that pick scalar, ~15% of this function). */
static inline double level_pick(double level, const double *t)
{
    const double t0 = t[0], t1 = t[1], t2 = t[2], t3 = t[3], t4 = t[4], t5 = t[5];
    double v = level == 4 ? t4 : t5;
    v = level == 3 ? t3 : v;
    v = level == 2 ? t2 : v;
    v = level == 1 ? t1 : v;
    return level == 0 ? t0 : v;
}

WF_CLONES static void fit_full_lanes(const wf_rampfit_setup *su, const double *const *R, int L,
                                     const double *rn2_n, wf_rampfit_result *out, int *redo)
{
    enum { NL = RF_LANES };
    const int m = su->nres, k = m - 1;
    const double rn2 = su->read_noise * su->read_noise, span = su->tbar[m - 1] - su->tbar[0];
    const double *pn = su->pair_inv_n, *pt = su->pair_tau, *dt = su->pair_dt, *po = su->pair_off;
    double r[WF_MA_MAX_RESULTANTS][NL]; /* resultants, lane fastest */
    double cdiag[WF_MA_MAX_RESULTANTS][NL], x[WF_MA_MAX_RESULTANTS][NL];
    double snr[NL], rate[NL], prev_off[NL], off[NL], piv[NL], num[NL], den[NL];
    double slope[NL], var_read[NL], pois[NL];
    double level[NL]; /* the power level, a double: its compares then mask doubles */
    int ok[NL], hit[NL];
    for (int i = 0; i < m; i++)
        for (int l = 0; l < NL; l++)
            r[i][l] = R[l < L ? l : 0][i];
    for (int l = 0; l < NL; l++) {
        snr[l] = 0.0;
        ok[l] = 1;
        prev_off[l] = num[l] = den[l] = 0.0;
    }
    /* fit_segment's unweighted first pass */
    for (int i = 0; i < m; i++)
        for (int l = 0; l < NL; l++)
            snr[l] += su->full_c[0][i] * r[i][l];
    for (int l = 0; l < NL; l++)
        rate[l] = pos(snr[l]);
    /* gls_slope */
    for (int i = 0; i < k; i++) {
        for (int l = 0; l < NL; l++)
            off[l] = i + 1 < k ? rate[l] * po[i] - rn2_n[i + 1] : 0.0;
        for (int l = 0; l < NL; l++) {
            const double diag = rn2 * pn[i] + rate[l] * pt[i];
            piv[l] = diag - (i > 0 ? prev_off[l] * cdiag[i > 0 ? i - 1 : 0][l] : 0.0);
            ok[l] &= piv[l] > 1e-12 * diag; /* a lane that fails keeps the first pass */
        }
        for (int l = 0; l < NL; l++) {
            const double inv = 1.0 / piv[l];
            cdiag[i][l] = off[l] * inv;
            x[i][l] = (dt[i] - (i > 0 ? prev_off[l] * x[i > 0 ? i - 1 : 0][l] : 0.0)) * inv;
            prev_off[l] = off[l];
        }
    }
    for (int i = k - 2; i >= 0; i--)
        for (int l = 0; l < NL; l++)
            x[i][l] -= cdiag[i][l] * x[i + 1][l];
    for (int i = 0; i < k; i++)
        for (int l = 0; l < NL; l++) {
            num[l] += x[i][l] * (r[i + 1][l] - r[i][l]);
            den[l] += x[i][l] * dt[i];
        }
    /* the power level (cas22_level: NaN, as there, takes the last), the slope and its
     * variances at that level; each lane's coefficients picked by blends, not gathers */
    for (int l = 0; l < NL; l++) {
        const double q = num[l] / den[l];
        snr[l] = (ok[l] & (den[l] > 0.0) & (isfinite(q) != 0)) ? q : snr[l];
        const double signal = pos(snr[l]) * span, noise = sqrt(rn2 + signal);
        const double s2n = noise > 0.0 ? signal / noise : 0.0;
        level[l] = (double)(!(s2n < 5.0) + !(s2n < 10.0) + !(s2n < 20.0) + !(s2n < 50.0) + !(s2n < 100.0));
        slope[l] = 0.0;
        var_read[l] = rn2 * level_pick(level[l], su->full_cr);
        pois[l] = pos(level_pick(level[l], su->full_cp));
    }
    for (int i = m - 1; i >= 0; i--) {
        const double c[WF_RAMPFIT_POWER_LEVELS] = {su->full_c[0][i], su->full_c[1][i], su->full_c[2][i],
                                                   su->full_c[3][i], su->full_c[4][i], su->full_c[5][i]};
        for (int l = 0; l < NL; l++)
            slope[l] += level_pick(level[l], c) * r[i][l];
    }
    /* worst_difference's z = d / sqrt(v) exceeds the (positive) threshold only where d > 0
     * and d^2 > thr^2 v. The threshold is at least its value at the top rate, so with a margin
     * far above rounding a pixel none of whose differences passes that one cannot have a jump;
     * any other (a few in 10^5 without a jump) goes the one-pixel way, which decides it
     * exactly (and no log10, a call, runs here). */
    for (int l = 0; l < NL; l++)
        hit[l] = 0;
    if (su->detect_jumps && m >= 3) {
        const double lo = jump_threshold(su, 1e4), lo2 = lo * lo * (1.0 - 1e-9);
        for (int i = 0; i < k; i++)
            for (int l = 0; l < NL; l++) {
                const double d = r[i + 1][l] - r[i][l] - slope[l] * dt[i];
                const double v = rn2 * pn[i] + pos(slope[l]) * pt[i];
                hit[l] |= (d > 0.0) & (d * d > lo2 * v);
            }
    }
    /* combine of the one segment, pass by pass as there */
    double w[NL], rt[NL];
    for (int l = 0; l < NL; l++) {
        const double v = var_read[l] > 0.0 ? var_read[l] : pois[l];
        w[l] = v > 0.0 ? 1.0 / v : 1.0;
        rt[l] = (0.0 + w[l] * slope[l]) / (0.0 + w[l]);
    }
    for (int l = 0; l < NL; l++) {
        const double v = var_read[l] + pos(rt[l]) * pois[l];
        w[l] = v > 0.0 ? 1.0 / v : 1.0;
        rt[l] = (0.0 + w[l] * slope[l]) / (0.0 + w[l]);
    }
    for (int l = 0; l < L; l++) {
        redo[l] = hit[l];
        if (hit[l]) continue;
        const double a = w[l] / (0.0 + w[l]), vp = 0.0 + a * a * pois[l];
        out[l] = (wf_rampfit_result){.rate = rt[l], .var_read = 0.0 + a * a * var_read[l],
                                     .var_poisson = pos(rt[l]) * vp, .poisson_coef = vp};
    }
}

wf_status wf_rampfit_pixels(const wf_rampfit_setup *setup, const double *resultants, int stride,
                            const int *first_saturated, int n, wf_rampfit_result *out, int *bad)
{
    if (bad)
        *bad = -1;
    if (!setup || (n > 0 && (!resultants || !first_saturated || !out)))
        return wf_error(WF_ERR_INPUT, "wf_rampfit_pixels: NULL argument");
    wf_status st = check_setup(setup);
    if (st != WF_OK)
        return st;
    const int m = setup->nres;
    if (stride < m)
        return wf_error(WF_ERR_INPUT, "wf_rampfit_pixels: stride %d below %d resultants", stride, m);
    const double rn2 = setup->read_noise * setup->read_noise;
    double rn2_n[WF_MA_MAX_RESULTANTS];
    for (int i = 0; i < m; i++)
        rn2_n[i] = rn2 / setup->nreads[i];
    const int lanes_ok = m >= 2 && setup->full_nres == m;
    const double *lane[RF_LANES];
    int idx[RF_LANES], redo[RF_LANES], L = 0;
    for (int p = 0; p <= n; p++) {
        if (p < n) {
            const double *R = resultants + (size_t)p * (size_t)stride;
            /* finite and within 1e30 (NaN fails the comparison): no branch per resultant */
            int plain = lanes_ok && first_saturated[p] >= m;
            for (int r = 0; r < m; r++)
                plain &= fabs(R[r]) <= 1e30;
            if (plain) {
                lane[L] = R;
                idx[L++] = p;
                if (L < RF_LANES)
                    continue;
            } else if ((st = fit_pixel(setup, R, first_saturated[p], &out[p]))) {
                if (bad)
                    *bad = p;
                return st;
            } else if (L < RF_LANES) {
                continue;
            }
        }
        if (!L)
            continue;
        wf_rampfit_result tmp[RF_LANES];
        fit_full_lanes(setup, lane, L, rn2_n, tmp, redo);
        for (int l = 0; l < L; l++) {
            if (!redo[l])
                out[idx[l]] = tmp[l];
            else if ((st = fit_pixel(setup, lane[l], m, &out[idx[l]]))) {
                if (bad)
                    *bad = idx[l];
                return st;
            }
        }
        L = 0;
    }
    return WF_OK;
}

static wf_status fit_pixel(const wf_rampfit_setup *setup, const double *resultants,
                           int first_saturated, wf_rampfit_result *out)
{
    if (first_saturated < 0)
        return wf_error(WF_ERR_INPUT, "ramp fit: first saturated resultant %d is negative",
                        first_saturated);
    const int usable = first_saturated < setup->nres ? first_saturated : setup->nres;
    const int checked = usable > 0 ? usable : 1;
    for (int r = 0; r < checked; r++) {
        if (!isfinite(resultants[r]))
            return wf_error(WF_ERR_INPUT, "ramp fit: resultant %d is not finite (%g)", r + 1,
                            resultants[r]);
        /* Far beyond any full well (1e5 e-), and low enough that no intermediate overflows. */
        if (fabs(resultants[r]) > 1e30)
            return wf_error(WF_ERR_RANGE, "ramp fit: resultant %d is %g e-", r + 1, resultants[r]);
    }

    wf_rampfit_result res = {0};
    if (usable < setup->nres)
        res.dq |= WF_DQ_SATURATED;
    if (usable <= 1) {
        single_resultant(setup, resultants, 0, &res);
        if (usable == 0)
            res.dq |= WF_DQ_DO_NOT_USE;
        *out = res;
        return WF_OK;
    }

    /* Segments still to examine (a stack) and segments accepted. Every split makes strictly
     * shorter pieces, so at most usable - 1 splits happen and both arrays stay bounded. */
    int pend_s[WF_MA_MAX_RESULTANTS], pend_e[WF_MA_MAX_RESULTANTS], npend = 0;
    seg_fit done[WF_MA_MAX_RESULTANTS];
    int ndone = 0, first_clean = 1;
    pend_s[npend] = 0;
    pend_e[npend++] = usable - 1;
    while (npend > 0) {
        npend--;
        int s = pend_s[npend], e = pend_e[npend];
        if (e - s + 1 < 2)
            continue; /* one resultant carries no slope once the intercept is free */
        seg_fit f;
        fit_segment(setup, resultants, s, e, &f);
        if (setup->detect_jumps && e - s + 1 >= 3) {
            double z;
            int i = worst_difference(setup, resultants, &f, &z);
            if (i >= 0 && z > jump_threshold(setup, f.slope)) {
                res.njumps++;
                res.dq |= WF_DQ_JUMP_DET;
                /* The jump lies after the first read of R_i and by the last read of R_{i+1}:
                 * a resultant averaging several reads may hold it part-way, so drop it; a
                 * single read is wholly before or wholly after and is kept. */
                int lo_end = setup->nreads[i] > 1 ? i - 1 : i;
                int hi_start = setup->nreads[i + 1] > 1 ? i + 2 : i + 1;
                if (lo_end < 0)
                    first_clean = 0;
                if (npend + 2 > WF_MA_MAX_RESULTANTS)
                    return wf_error(WF_ERR_INTERNAL, "ramp fit: segment stack overflow");
                if (hi_start <= e) {
                    pend_s[npend] = hi_start;
                    pend_e[npend++] = e;
                }
                if (lo_end >= s) {
                    pend_s[npend] = s;
                    pend_e[npend++] = lo_end;
                }
                continue;
            }
        }
        if (ndone >= WF_MA_MAX_RESULTANTS)
            return wf_error(WF_ERR_INTERNAL, "ramp fit: too many segments");
        done[ndone++] = f;
    }

    if (ndone > 0) {
        combine(done, ndone, &res);
    } else if (first_clean) {
        /* Jumps left no two neighbouring clean resultants but the first is clean: fall back
         * to the one-resultant estimate, as for a ramp saturated after one resultant. */
        single_resultant(setup, resultants, 0, &res);
    } else {
        /* Nothing clean: report the plain fit of all usable resultants, not to be trusted. */
        seg_fit f;
        fit_segment(setup, resultants, 0, usable - 1, &f);
        combine(&f, 1, &res);
        res.dq |= WF_DQ_DO_NOT_USE;
    }
    *out = res;
    return WF_OK;
}
