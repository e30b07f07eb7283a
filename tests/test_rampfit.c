/* Ramp fitting: closed-form variances, exact slopes on noiseless ramps, the documented
 * short-ramp and saturation cases, and Monte Carlo ramps simulated read by read here (Poisson
 * increments, Gaussian read noise, reads averaged into resultants) whose fitted rates must be
 * unbiased and scatter as much as the fitter says they do. */
#include "tests/testutil.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "hal/clock.h"
#include "hal/noise.h"
#include "tools/rampfit.h"

#define READ_NOISE 8.5
#define NPIX 20000

static wf_clock make_clock(const char *table)
{
    wf_clock clk;
    clk.frame_time = WF_FRAME_TIME_DEFAULT;
    ck_assert_int_eq(wf_ma_builtin(table, &clk.ma), WF_OK);
    return clk;
}

static wf_clock clock_from_counts(const int *counts, int n, double frame_time)
{
    wf_clock clk;
    clk.frame_time = frame_time;
    ck_assert_int_eq(wf_ma_from_counts("test", counts, n, &clk.ma), WF_OK);
    return clk;
}

/* One pixel's ramp: charge grows by Poisson(rate * frame_time) each read, cr_e electrons
 * arrive at read cr_read (none when negative), every digitised read gets its own read noise,
 * and the reads of each resultant are averaged. */
static void simulate_ramp(const wf_clock *clk, const wf_noise *noise, uint32_t pixel, double rate,
                          double read_noise, int cr_read, double cr_e, double *res)
{
    const wf_ma_table *ma = &clk->ma;
    const int total = wf_ma_total_reads(ma);
    double charge = 0.0;
    int r = 0, j = 0;
    double sum = 0.0;
    for (int k = 0; k < total; k++) {
        wf_rng rng;
        wf_rng_init(&rng, noise, pixel, (uint32_t)k, WF_PURPOSE_TEST);
        charge += wf_rng_poisson(&rng, rate * clk->frame_time);
        if (k == cr_read)
            charge += cr_e;
        if (j < ma->nreads && ma->read[j] == k) {
            sum += charge + read_noise * wf_rng_gauss(&rng);
            j++;
            if (j == ma->first[r + 1]) {
                res[r] = sum / (ma->first[r + 1] - ma->first[r]);
                sum = 0.0;
                r++;
            }
        }
    }
}

typedef struct mc_stats {
    double mean, sample_var;
    double mean_var;       /* mean reported total variance */
    double mean_var_read;  /* mean reported read variance */
    double mean_pcoef;     /* mean Poisson variance per unit rate */
    double mean_exact;     /* mean variance of the estimator used at the true rate */
    double frac_negative;  /* fraction of fitted rates below zero */
    int njump_pixels;
} mc_stats;

/* NPIX pixels at a constant rate, each hit by cr_e electrons at some read when cr_e != 0. */
static mc_stats run_mc(const char *table, double rate, uint32_t exposure, double cr_e)
{
    wf_clock clk = make_clock(table);
    wf_rampfit_setup su;
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, READ_NOISE, &su), WF_OK);
    ck_assert_int_eq(su.detect_jumps, 1);
    wf_noise noise = {.kind = WF_NOISE_PHILOX, .seed = 20240611u, .exposure = exposure, .sca = 1};
    const int total = wf_ma_total_reads(&clk.ma);
    double *rates = malloc(NPIX * sizeof *rates);
    ck_assert_ptr_nonnull(rates);
    double res[WF_MA_MAX_RESULTANTS];
    mc_stats s = {0};
    double sum = 0.0, sum_var = 0.0, sum_var_read = 0.0, sum_pcoef = 0.0, sum_exact = 0.0;
    int nneg = 0;
    for (int p = 0; p < NPIX; p++) {
        /* Spread hits over every read but the first, where a hit is only an offset. */
        int cr_read = cr_e == 0.0 ? -1 : 1 + (int)((unsigned)p * 7919u % (unsigned)(total - 1));
        simulate_ramp(&clk, &noise, (uint32_t)p, rate, READ_NOISE, cr_read, cr_e, res);
        wf_rampfit_result fit;
        ck_assert_int_eq(wf_rampfit_pixel(&su, res, su.nres, &fit), WF_OK);
        ck_assert(isfinite(fit.rate) && isfinite(fit.var_read) && isfinite(fit.var_poisson));
        ck_assert(!(fit.dq & (WF_DQ_SATURATED | WF_DQ_DO_NOT_USE)));
        ck_assert_double_eq_tol(fit.var_poisson, fmax(fit.rate, 0.0) * fit.poisson_coef,
                                1e-12 * (fit.var_poisson + 1e-300));
        rates[p] = fit.rate;
        sum += fit.rate;
        sum_var += fit.var_read + fit.var_poisson;
        sum_var_read += fit.var_read;
        sum_pcoef += fit.poisson_coef;
        sum_exact += fit.var_read + rate * fit.poisson_coef;
        nneg += fit.rate < 0.0;
        if (fit.dq & WF_DQ_JUMP_DET)
            s.njump_pixels++;
    }
    s.mean = sum / NPIX;
    double ss = 0.0;
    for (int p = 0; p < NPIX; p++)
        ss += (rates[p] - s.mean) * (rates[p] - s.mean);
    s.sample_var = ss / (NPIX - 1);
    s.mean_var = sum_var / NPIX;
    s.mean_var_read = sum_var_read / NPIX;
    s.mean_pcoef = sum_pcoef / NPIX;
    s.mean_exact = sum_exact / NPIX;
    s.frac_negative = (double)nneg / NPIX;
    free(rates);
    return s;
}

static const char *const mc_tables[] = {"4", "6", "11"};
static const double mc_rates[] = {0.01, 1.0, 100.0, 1e4};
#define N_MC_CASES 12

/* E[max(X, 0)] for X ~ N(mu, sigma^2). */
static double mean_clipped_gauss(double mu, double sigma)
{
    double z = mu / sigma;
    return mu * 0.5 * erfc(-z / sqrt(2.0)) + sigma * exp(-0.5 * z * z) / sqrt(2.0 * M_PI);
}

START_TEST(test_mc_constant_rate)
{
    const char *table = mc_tables[_i % 3];
    double rate = mc_rates[_i / 3];
    mc_stats s = run_mc(table, rate, 100u + (uint32_t)_i, 0.0);
    double sigma = sqrt(s.mean_var / NPIX);
    double ratio = s.sample_var / s.mean_var;
    /* The reported Poisson term is evaluated at max(fitted rate, 0). Where fitted rates are
     * often negative (low S/N) that overstates it on average by P (E[max(r, 0)] - rate),
     * predicted here for Gaussian scatter of the exact width; elsewhere this is 1 to < 1e-4. */
    double emax = mean_clipped_gauss(rate, sqrt(s.mean_exact));
    double predicted = s.mean_exact / (s.mean_var_read + s.mean_pcoef * emax);
    printf("MC table %-2s rate %-6g: bias %+.2f sigma, sample/reported var %.4f (predicted %.4f), "
           "sample/exact %.4f, read share %.3f, negative %.3f, false-jump pixels %d\n",
           table, rate, (s.mean - rate) / sigma, ratio, predicted, s.sample_var / s.mean_exact,
           s.mean_var_read / s.mean_var, s.frac_negative, s.njump_pixels);
    fflush(stdout);
    ck_assert_msg(fabs(s.mean - rate) < 3.0 * sigma, "table %s rate %g: mean %.8g, bias %.2f sigma",
                  table, rate, s.mean, (s.mean - rate) / sigma);
    /* The variance formulas themselves, for the coefficients each pixel used. */
    ck_assert_msg(fabs(s.sample_var / s.mean_exact - 1.0) < 0.05,
                  "table %s rate %g: sample/exact variance %.4f", table, rate,
                  s.sample_var / s.mean_exact);
    /* What a user sees: the reported variance against the scatter. */
    ck_assert_msg(fabs(ratio - predicted) < 0.05,
                  "table %s rate %g: sample/reported variance %.4f, predicted %.4f", table, rate,
                  ratio, predicted);
    /* Under the null each pixel makes ~10-15 one-sided tests at >= 4.2 sigma. */
    ck_assert_msg(s.njump_pixels < NPIX / 200, "table %s rate %g: %d pixels with false jumps",
                  table, rate, s.njump_pixels);
}
END_TEST

START_TEST(test_mc_cosmic_ray)
{
    const double rate = 10.0, cr = 500.0;
    mc_stats s = run_mc("6", rate, 900u, cr);
    double sigma = sqrt(s.mean_var / NPIX);
    printf("CR table 6 rate %g +%g e-: mean %.6g bias %+.2f sigma, var ratio %.4f, "
           "jump pixels %d/%d\n",
           rate, cr, s.mean, (s.mean - rate) / sigma, s.sample_var / s.mean_var, s.njump_pixels,
           NPIX);
    fflush(stdout);
    ck_assert_int_eq(s.njump_pixels, NPIX);
    ck_assert_msg(fabs(s.mean - rate) < 3.0 * sigma, "CR: mean %.8g, bias %.2f sigma", s.mean,
                  (s.mean - rate) / sigma);
    /* Segments share no reads, so their inverse-variance mean has exactly the variance
     * reported; dropping resultants around the hit must not make it optimistic. */
    ck_assert_msg(fabs(s.sample_var / s.mean_var - 1.0) < 0.05, "CR: sample/reported variance %.4f",
                  s.sample_var / s.mean_var);
}
END_TEST

/* A jump in one known pixel is flagged, counted once, and removed from the slope. */
START_TEST(test_single_jump_noiseless)
{
    wf_clock clk = make_clock("6");
    wf_rampfit_setup su;
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, READ_NOISE, &su), WF_OK);
    wf_noise off = {.kind = WF_NOISE_OFF};
    double res[WF_MA_MAX_RESULTANTS];
    simulate_ramp(&clk, &off, 0, 5.0, 0.0, 40, 1000.0, res);
    wf_rampfit_result fit;
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, su.nres, &fit), WF_OK);
    ck_assert_uint_eq(fit.dq, WF_DQ_JUMP_DET);
    ck_assert_int_eq(fit.njumps, 1);
    ck_assert_double_eq_tol(fit.rate, 5.0, 1e-9);

    su.detect_jumps = 0;
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, su.nres, &fit), WF_OK);
    ck_assert_uint_eq(fit.dq, 0);
    ck_assert(fit.rate > 5.5);
}
END_TEST

/* tbar and tau against their definitions summed pair by pair. */
START_TEST(test_setup_tau)
{
    wf_clock clk = make_clock("11");
    wf_rampfit_setup su;
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, READ_NOISE, &su), WF_OK);
    ck_assert_int_eq(su.nres, 15);
    ck_assert_double_eq(su.read_noise, READ_NOISE);
    for (int r = 0; r < su.nres; r++) {
        int a = clk.ma.first[r], n = clk.ma.first[r + 1] - a;
        ck_assert_int_eq(su.nreads[r], n);
        double tb = 0.0, tau = 0.0;
        for (int i = 0; i < n; i++) {
            tb += (clk.ma.read[a + i] + 1) * clk.frame_time / n;
            for (int j = 0; j < n; j++)
                tau += fmin(clk.ma.read[a + i] + 1, clk.ma.read[a + j] + 1) * clk.frame_time;
        }
        tau /= (double)n * n;
        ck_assert_double_eq_tol(su.tbar[r], tb, 1e-9 * tb);
        ck_assert_double_eq_tol(su.tau[r], tau, 1e-9 * tau);
        ck_assert_double_eq_tol(su.tbar[r], wf_clock_resultant_time(&clk, r), 1e-9 * tb);
    }
    /* n consecutive reads starting at read k0 (0-based): tau = dt (k0 + (n+1)(2n+1)/(6n)). */
    int k0 = clk.ma.read[clk.ma.first[3]], n = su.nreads[3];
    ck_assert_double_eq_tol(su.tau[3], clk.frame_time * (k0 + (n + 1.0) * (2.0 * n + 1.0) / (6.0 * n)),
                            1e-9 * su.tau[3]);
}
END_TEST

/* Equal single-read resultants and no signal: the fit is plain OLS, whose slope variance is
 * 12 sigma^2 / (dt^2 n (n^2 - 1)); the Poisson term vanishes at rate 0. */
START_TEST(test_ols_closed_form)
{
    int counts[20];
    for (int n = 3; n <= 20; n++) {
        for (int i = 0; i < n; i++)
            counts[i] = 1;
        const double dt = 2.5, sig = 7.0;
        wf_clock clk = clock_from_counts(counts, n, dt);
        wf_rampfit_setup su;
        ck_assert_int_eq(wf_rampfit_setup_init(&clk, sig, &su), WF_OK);
        double res[20];
        for (int i = 0; i < n; i++)
            res[i] = 42.0; /* a bias level only */
        wf_rampfit_result fit;
        ck_assert_int_eq(wf_rampfit_pixel(&su, res, n, &fit), WF_OK);
        double expect = 12.0 * sig * sig / (dt * dt * n * ((double)n * n - 1.0));
        ck_assert_double_eq_tol(fit.rate, 0.0, 1e-12);
        ck_assert_double_eq_tol(fit.var_read, expect, 1e-12 * expect);
        /* The fitted rate is zero up to rounding of the bias level. */
        ck_assert(fit.var_poisson <= 1e-12 * expect);
        ck_assert_uint_eq(fit.dq, 0);
        ck_assert_int_eq(fit.njumps, 0);
    }
}
END_TEST

/* Two single-read resultants: slope = difference / dt; read variance 2 sigma^2 / dt^2;
 * Poisson variance rate / dt (the charge between the reads is Poisson(rate dt)). */
START_TEST(test_two_resultants)
{
    const int counts[] = {1, 1};
    const double dt = 3.0, sig = 5.0;
    wf_clock clk = clock_from_counts(counts, 2, dt);
    wf_rampfit_setup su;
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, sig, &su), WF_OK);
    const double res[2] = {100.0, 160.0};
    wf_rampfit_result fit;
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, 2, &fit), WF_OK);
    ck_assert_double_eq_tol(fit.rate, 20.0, 1e-12);
    ck_assert_double_eq_tol(fit.var_read, 2.0 * sig * sig / (dt * dt), 1e-12);
    ck_assert_double_eq_tol(fit.var_poisson, 20.0 / dt, 1e-12);
    ck_assert_uint_eq(fit.dq, 0);

    /* Negative fitted rate: the Poisson term is evaluated at zero. */
    const double neg[2] = {160.0, 100.0};
    ck_assert_int_eq(wf_rampfit_pixel(&su, neg, 2, &fit), WF_OK);
    ck_assert_double_eq_tol(fit.rate, -20.0, 1e-12);
    ck_assert_double_eq(fit.var_poisson, 0.0);
}
END_TEST

/* Two multi-read resultants: the Poisson variance of (R1 - R0)/dtbar from the covariance
 * model written out by hand, read variance sigma^2 (1/n0 + 1/n1) / dtbar^2. */
START_TEST(test_two_averaged_resultants)
{
    const int counts[] = {3, 4};
    const double dt = 2.0, sig = 6.0, rate = 7.0;
    wf_clock clk = clock_from_counts(counts, 2, dt);
    wf_rampfit_setup su;
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, sig, &su), WF_OK);
    /* Reads at 2,4,6 | 8,10,12,14 s: tbar 4, 11; tau0 = (2*5+4*3+6)/9 = 28/9,
     * tau1 = (8*7+10*5+12*3+14)/16 = 156/16. */
    double t0 = 4.0, t1 = 11.0, tau0 = 28.0 / 9.0, tau1 = 156.0 / 16.0, d = t1 - t0;
    ck_assert_double_eq_tol(su.tau[0], tau0, 1e-12);
    ck_assert_double_eq_tol(su.tau[1], tau1, 1e-12);
    const double res[2] = {10.0 + rate * t0, 10.0 + rate * t1};
    wf_rampfit_result fit;
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, 2, &fit), WF_OK);
    ck_assert_double_eq_tol(fit.rate, rate, 1e-12);
    ck_assert_double_eq_tol(fit.var_read, sig * sig * (1.0 / 3 + 1.0 / 4) / (d * d), 1e-12);
    ck_assert_double_eq_tol(fit.var_poisson, rate * (tau0 + tau1 - 2.0 * t0) / (d * d), 1e-12);
}
END_TEST

/* A noiseless linear ramp with any intercept gives the rate exactly whatever power the S/N
 * selects, and the reported variances are those of the same coefficients. */
START_TEST(test_noiseless_exact)
{
    const double rates[] = {0.0, 0.05, 0.3, 1.0, 3.0, 30.0, 300.0, 1e4, 1e6};
    for (int tab = 0; tab < 3; tab++) {
        wf_clock clk = make_clock(mc_tables[tab]);
        wf_rampfit_setup su;
        ck_assert_int_eq(wf_rampfit_setup_init(&clk, READ_NOISE, &su), WF_OK);
        for (size_t k = 0; k < sizeof rates / sizeof *rates; k++) {
            double res[WF_MA_MAX_RESULTANTS];
            for (int r = 0; r < su.nres; r++)
                res[r] = -321.0 + rates[k] * su.tbar[r];
            wf_rampfit_result fit;
            ck_assert_int_eq(wf_rampfit_pixel(&su, res, su.nres, &fit), WF_OK);
            ck_assert_double_eq_tol(fit.rate, rates[k], 1e-9 * (1.0 + rates[k]));
            ck_assert_uint_eq(fit.dq, 0);
            ck_assert(fit.var_read > 0.0 && isfinite(fit.var_read));
            ck_assert(fit.var_poisson >= 0.0 && isfinite(fit.var_poisson));
            /* No estimator beats the last-minus-first Poisson bound rate/(T_last - t_first)
             * by more than the averaging of the end resultants allows; a gross error in the
             * covariance sum would break this sandwich. */
            if (rates[k] > 0.0) {
                double lo = 0.5 * rates[k] / (su.tbar[su.nres - 1] - su.tbar[0]);
                ck_assert(fit.var_poisson > lo);
                ck_assert(fit.var_poisson < 100.0 * lo);
            }
        }
    }
}
END_TEST

START_TEST(test_short_ramps)
{
    wf_rampfit_result fit;
    /* A one-resultant table. */
    const int one[] = {4};
    wf_clock clk1 = clock_from_counts(one, 1, 3.0);
    wf_rampfit_setup su1;
    ck_assert_int_eq(wf_rampfit_setup_init(&clk1, 8.0, &su1), WF_OK);
    /* Reads at 3,6,9,12: tbar 7.5, tau (3*7+6*5+9*3+12)/16 = 90/16. */
    const double r1[1] = {150.0};
    ck_assert_int_eq(wf_rampfit_pixel(&su1, r1, 1, &fit), WF_OK);
    ck_assert_double_eq_tol(fit.rate, 20.0, 1e-12);
    ck_assert_double_eq_tol(fit.var_read, 64.0 / 4.0 / (7.5 * 7.5), 1e-12);
    ck_assert_double_eq_tol(fit.var_poisson, 20.0 * (90.0 / 16.0) / (7.5 * 7.5), 1e-12);
    ck_assert_uint_eq(fit.dq, 0);
    /* Saturated in its only resultant: a lower bound, not to be used. */
    ck_assert_int_eq(wf_rampfit_pixel(&su1, r1, 0, &fit), WF_OK);
    ck_assert_double_eq_tol(fit.rate, 20.0, 1e-12);
    ck_assert_uint_eq(fit.dq, WF_DQ_SATURATED | WF_DQ_DO_NOT_USE);

    wf_clock clk = make_clock("6");
    wf_rampfit_setup su;
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, READ_NOISE, &su), WF_OK);
    double res[WF_MA_MAX_RESULTANTS];
    const double rate = 400.0;
    for (int r = 0; r < su.nres; r++)
        res[r] = rate * su.tbar[r];
    for (int r = 5; r < su.nres; r++)
        res[r] = 1e5; /* flat at the full well: would drag a fit down */

    /* Partially saturated: fit only the resultants before the first saturated one. */
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, 5, &fit), WF_OK);
    ck_assert_double_eq_tol(fit.rate, rate, 1e-9 * rate);
    ck_assert_uint_eq(fit.dq, WF_DQ_SATURATED);
    ck_assert_int_eq(fit.njumps, 0);

    /* Two usable resultants: the two-point slope. */
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, 2, &fit), WF_OK);
    ck_assert_double_eq_tol(fit.rate, rate, 1e-9 * rate);
    double d = su.tbar[1] - su.tbar[0];
    ck_assert_double_eq_tol(fit.var_read, 2.0 * READ_NOISE * READ_NOISE / (d * d), 1e-12);
    ck_assert_double_eq_tol(fit.var_poisson, rate / d, 1e-9);
    ck_assert_uint_eq(fit.dq, WF_DQ_SATURATED);

    /* One usable resultant: R0 / tbar0 against the zero reset level. */
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, 1, &fit), WF_OK);
    ck_assert_double_eq_tol(fit.rate, rate, 1e-9 * rate);
    ck_assert_double_eq_tol(fit.var_read, READ_NOISE * READ_NOISE / (su.tbar[0] * su.tbar[0]), 1e-12);
    ck_assert_double_eq_tol(fit.var_poisson, rate / su.tbar[0], 1e-9);
    ck_assert_uint_eq(fit.dq, WF_DQ_SATURATED);

    /* Saturated from the first resultant on. */
    for (int r = 0; r < su.nres; r++)
        res[r] = 1e5;
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, 0, &fit), WF_OK);
    ck_assert_double_eq_tol(fit.rate, 1e5 / su.tbar[0], 1e-6);
    ck_assert_uint_eq(fit.dq, WF_DQ_SATURATED | WF_DQ_DO_NOT_USE);
    ck_assert(isfinite(fit.var_read) && isfinite(fit.var_poisson));

    /* first_saturated beyond the ramp means none saturated. */
    for (int r = 0; r < su.nres; r++)
        res[r] = rate * su.tbar[r];
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, 1000, &fit), WF_OK);
    ck_assert_uint_eq(fit.dq, 0);
    ck_assert_double_eq_tol(fit.rate, rate, 1e-9 * rate);
}
END_TEST

/* Jumps that leave no two clean neighbouring resultants fall back to the documented cases. */
START_TEST(test_jump_fallbacks)
{
    const int counts[] = {1, 1, 1};
    wf_clock clk = clock_from_counts(counts, 3, 3.0);
    wf_rampfit_setup su;
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, 5.0, &su), WF_OK);
    /* Jump between R1 and R2 of single reads: segment {R0, R1} stays. */
    const double a[3] = {30.0, 60.0, 5090.0};
    wf_rampfit_result fit;
    ck_assert_int_eq(wf_rampfit_pixel(&su, a, 3, &fit), WF_OK);
    ck_assert_uint_eq(fit.dq, WF_DQ_JUMP_DET);
    ck_assert_int_eq(fit.njumps, 1);
    ck_assert_double_eq_tol(fit.rate, 10.0, 1e-12);

    /* Averaged resultants around the jump are dropped; R0 alone is left. */
    const int c2[] = {1, 2, 2};
    clk = clock_from_counts(c2, 3, 3.0);
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, 5.0, &su), WF_OK);
    const double b[3] = {30.0, 1575.0, 3135.0}; /* +3000 e- at the 3rd read (9 s) */
    ck_assert_int_eq(wf_rampfit_pixel(&su, b, 3, &fit), WF_OK);
    ck_assert(fit.dq & WF_DQ_JUMP_DET);
    ck_assert(isfinite(fit.rate) && isfinite(fit.var_read) && isfinite(fit.var_poisson));
    ck_assert_double_eq_tol(fit.rate, 10.0, 1e-12);
    ck_assert_uint_eq(fit.dq, WF_DQ_JUMP_DET);

    /* A fixed threshold overrides stcal's: a 3 sigma excess then counts as a jump. */
    const int c3[] = {1, 1, 1, 1, 1, 1};
    clk = clock_from_counts(c3, 6, 1.0);
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, 10.0, &su), WF_OK);
    double r[6] = {0, 0, 0, 60, 60, 60};
    ck_assert_int_eq(wf_rampfit_pixel(&su, r, 6, &fit), WF_OK);
    ck_assert_uint_eq(fit.dq & WF_DQ_JUMP_DET, 0);
    su.jump_threshold = 2.0;
    ck_assert_int_eq(wf_rampfit_pixel(&su, r, 6, &fit), WF_OK);
    ck_assert_uint_eq(fit.dq & WF_DQ_JUMP_DET, WF_DQ_JUMP_DET);
    ck_assert_double_eq_tol(fit.rate, 0.0, 1e-12);
}
END_TEST

START_TEST(test_bad_arguments)
{
    wf_clock clk = make_clock("4");
    wf_rampfit_setup su;
    wf_rampfit_result fit;
    double res[WF_MA_MAX_RESULTANTS] = {0};
    ck_assert_int_eq(wf_rampfit_setup_init(NULL, 1.0, &su), WF_ERR_INPUT);
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, 1.0, NULL), WF_ERR_INPUT);
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, -1.0, &su), WF_ERR_INPUT);
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, NAN, &su), WF_ERR_INPUT);
    wf_clock bad = clk;
    bad.frame_time = 0.0;
    ck_assert_int_eq(wf_rampfit_setup_init(&bad, 1.0, &su), WF_ERR_INPUT);
    bad = clk;
    bad.ma.nresultants = 0;
    ck_assert_int_eq(wf_rampfit_setup_init(&bad, 1.0, &su), WF_ERR_INPUT);
    ck_assert(strlen(wf_error_message()) > 0);

    ck_assert_int_eq(wf_rampfit_setup_init(&clk, 1.0, &su), WF_OK);
    ck_assert_int_eq(wf_rampfit_pixel(NULL, res, su.nres, &fit), WF_ERR_INPUT);
    ck_assert_int_eq(wf_rampfit_pixel(&su, NULL, su.nres, &fit), WF_ERR_INPUT);
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, su.nres, NULL), WF_ERR_INPUT);
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, -1, &fit), WF_ERR_INPUT);
    wf_rampfit_setup s2 = su;
    s2.nres = 0;
    ck_assert_int_eq(wf_rampfit_pixel(&s2, res, 9, &fit), WF_ERR_INPUT);
    s2.nres = WF_MA_MAX_RESULTANTS + 1;
    ck_assert_int_eq(wf_rampfit_pixel(&s2, res, 9, &fit), WF_ERR_INPUT);
    s2 = su;
    s2.tbar[3] = s2.tbar[2];
    ck_assert_int_eq(wf_rampfit_pixel(&s2, res, 9, &fit), WF_ERR_INPUT);
    s2 = su;
    s2.nreads[1] = 0;
    ck_assert_int_eq(wf_rampfit_pixel(&s2, res, 9, &fit), WF_ERR_INPUT);
    /* a setup whose times changed after init (still increasing): its derived tables no
     * longer match, an error rather than a fit with stale coefficients */
    s2 = su;
    s2.tbar[2] += 1e-3 * (s2.tbar[3] - s2.tbar[2]);
    ck_assert_int_eq(wf_rampfit_pixel(&s2, res, 9, &fit), WF_ERR_INPUT);
    s2 = su;
    s2.tau[4] *= 1.0 + 1e-9;
    ck_assert_int_eq(wf_rampfit_pixel(&s2, res, 9, &fit), WF_ERR_INPUT);
    res[4] = 1e300;
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, su.nres, &fit), WF_ERR_RANGE);
    res[4] = NAN;
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, su.nres, &fit), WF_ERR_INPUT);
    /* ...but a NaN in a saturated resultant is never read. */
    ck_assert_int_eq(wf_rampfit_pixel(&su, res, 4, &fit), WF_OK);
    ck_assert(isfinite(fit.rate));
}
END_TEST

/* Finite garbage in, finite numbers out: huge, tiny and alternating resultants. */
START_TEST(test_no_nan)
{
    wf_clock clk = make_clock("11");
    wf_rampfit_setup su;
    ck_assert_int_eq(wf_rampfit_setup_init(&clk, 0.0, &su), WF_OK); /* no read noise */
    double res[WF_MA_MAX_RESULTANTS];
    const double scales[] = {0.0, 1e-300, 1.0, 1e6, 1e15};
    for (size_t k = 0; k < sizeof scales / sizeof *scales; k++) {
        for (int pattern = 0; pattern < 4; pattern++) {
            for (int r = 0; r < su.nres; r++) {
                double v = pattern == 0 ? 0.0
                         : pattern == 1 ? (r % 2 ? 1.0 : -1.0)
                         : pattern == 2 ? (r == su.nres / 2 ? 1.0 : 0.0)
                                        : (double)(su.nres - r);
                res[r] = scales[k] * v;
            }
            for (int first_sat = 0; first_sat <= su.nres; first_sat++) {
                wf_rampfit_result fit;
                ck_assert_int_eq(wf_rampfit_pixel(&su, res, first_sat, &fit), WF_OK);
                ck_assert(isfinite(fit.rate) && isfinite(fit.var_read) &&
                          isfinite(fit.var_poisson));
                ck_assert(fit.var_read >= 0.0 && fit.var_poisson >= 0.0);
            }
        }
    }
}
END_TEST

/* The whole ramp's coefficients made once by wf_rampfit_setup_init give the same bits as
 * computing them for each pixel (full_nres 0 turns them off): rates from far below the first
 * Casertano S/N boundary to far above the last, so that every power level is taken, with
 * cosmic rays (segments that are not the whole ramp) and saturation. */
START_TEST(test_full_ramp_coefficients)
{
    const char *tables[] = {"4", "6", "11"};
    for (int k = 0; k < 3; k++) {
        wf_clock clk = make_clock(tables[k]);
        wf_rampfit_setup su, plain;
        ck_assert_int_eq(wf_rampfit_setup_init(&clk, READ_NOISE, &su), WF_OK);
        ck_assert_int_eq(su.full_nres, su.nres);
        plain = su;
        plain.full_nres = 0;
        wf_noise noise = {.kind = WF_NOISE_PHILOX, .seed = 77u, .exposure = (uint32_t)k, .sca = 1};
        /* the lowest and highest rates have S/N below 5 and above 100 over the whole ramp,
         * the S/N as fit_segment forms it (signal / sqrt(rn^2 + signal)), so every level is
         * chosen somewhere between; and the six levels' coefficients all differ */
        double span = su.tbar[su.nres - 1] - su.tbar[0];
        ck_assert(1e-2 * span / sqrt(READ_NOISE * READ_NOISE + 1e-2 * span) < 5.0);
        ck_assert(3e3 * span / sqrt(READ_NOISE * READ_NOISE + 3e3 * span) > 100.0);
        for (int l = 1; l < WF_RAMPFIT_POWER_LEVELS; l++)
            ck_assert(memcmp(su.full_c[l], su.full_c[l - 1], (size_t)su.nres * sizeof(double)));
        for (int p = 0; p < 400; p++) {
            double rate = 1e-2 * pow(10.0, 5.5 * (p % 100) / 99.0), res[WF_MA_MAX_RESULTANTS];
            int cr_read = p >= 200 ? p % wf_ma_total_reads(&clk.ma) : -1;
            simulate_ramp(&clk, &noise, (uint32_t)p, rate, READ_NOISE, cr_read, 500.0, res);
            int first_sat = p % 7 == 3 ? su.nres - 1 - p % 3 : su.nres;
            wf_rampfit_result a, b;
            ck_assert_int_eq(wf_rampfit_pixel(&su, res, first_sat, &a), WF_OK);
            ck_assert_int_eq(wf_rampfit_pixel(&plain, res, first_sat, &b), WF_OK);
            ck_assert_msg(!memcmp(&a, &b, sizeof a), "table %s pixel %d (rate %g): %.17g vs %.17g", tables[k], p,
                          rate, a.rate, b.rate);
        }
    }
}
END_TEST


/* wf_rampfit_pixels against wf_rampfit_pixel, bit for bit: rates from none to saturating,
 * cosmic rays from below to far above the jump threshold (so that the batch's prefilter meets
 * jumps just under and just over it), saturated pixels between plain ones, in batches of
 * every length from 1 to past the lane count; then a bad pixel's index. Table 6 also with a
 * fixed jump threshold, without jump detection and fitted without read noise (the lanes'
 * other branches). */
START_TEST(test_pixels_match_pixel)
{
    const char *tables[6] = {"4", "6", "11", "6", "6", "6"};
    for (int k = 0; k < 6; k++) {
        wf_clock clk = make_clock(tables[k]);
        wf_rampfit_setup su;
        ck_assert_int_eq(wf_rampfit_setup_init(&clk, k == 5 ? 0.0 : READ_NOISE, &su), WF_OK);
        if (k == 3) su.jump_threshold = 4.5;
        if (k == 4) su.detect_jumps = 0;
        const int m = su.nres, npix = 997, stride = m + 3;
        const int total = wf_ma_total_reads(&clk.ma);
        wf_noise noise = {.kind = WF_NOISE_PHILOX, .seed = 77u, .exposure = (uint32_t)k, .sca = 2};
        double *res = calloc((size_t)npix * stride, sizeof *res);
        int *first = malloc(npix * sizeof *first);
        wf_rampfit_result *a = malloc(npix * sizeof *a), *b = malloc(npix * sizeof *b);
        ck_assert(res && first && a && b);
        int jumps = 0;
        for (int p = 0; p < npix; p++) {
            double rate = p % 5 == 0 ? 0.0 : 0.3 * pow(10.0, (p % 37) / 9.0);
            /* charges around the threshold: 5 sigma of a difference is tens of e- here */
            double cr = p % 3 == 0 ? 10.0 * (p % 29) : 0.0;
            int cr_read = cr > 0.0 ? 1 + (p * 31) % (total - 1) : -1;
            simulate_ramp(&clk, &noise, (uint32_t)p, rate, READ_NOISE, cr_read, cr, res + (size_t)p * stride);
            first[p] = p % 11 == 4 ? (p / 11) % (m + 1) : m + (p % 2);
        }
        for (int p = 0; p < npix; p++) {
            ck_assert_int_eq(wf_rampfit_pixel(&su, res + (size_t)p * stride, first[p], &a[p]), WF_OK);
            jumps += a[p].njumps > 0;
        }
        if (k == 4)
            ck_assert_int_eq(jumps, 0);
        else
            ck_assert_int_gt(jumps, npix / 20);
        for (int len = 1; len <= 19; len += 3) {
            memset(b, 0xff, npix * sizeof *b);
            for (int p0 = 0; p0 < npix; p0 += len) {
                int n = npix - p0 < len ? npix - p0 : len, bad = 7;
                ck_assert_int_eq(wf_rampfit_pixels(&su, res + (size_t)p0 * stride, stride, first + p0, n, b + p0, &bad),
                                 WF_OK);
                ck_assert_int_eq(bad, -1);
            }
            for (int p = 0; p < npix; p++)
                ck_assert_msg(!memcmp(&a[p], &b[p], sizeof a[p]), "table %s pixel %d batch %d: %.17g vs %.17g",
                              tables[k], p, len, a[p].rate, b[p].rate);
        }
        /* the first bad pixel is named, plain or not */
        res[(size_t)13 * stride + 2] = NAN;
        first[13] = m;
        int bad = -1;
        ck_assert_int_eq(wf_rampfit_pixels(&su, res, stride, first, 20, b, &bad), WF_ERR_INPUT);
        ck_assert_int_eq(bad, 13);
        ck_assert_int_eq(wf_rampfit_pixels(&su, res, m - 1, first, 20, b, &bad), WF_ERR_INPUT);
        free(res);
        free(first);
        free(a);
        free(b);
    }
}
END_TEST

static Suite *rampfit_suite(void)
{
    Suite *s = suite_create("rampfit");
    TCase *tc = tcase_create("closed_form");
    tcase_add_test(tc, test_setup_tau);
    tcase_add_test(tc, test_ols_closed_form);
    tcase_add_test(tc, test_two_resultants);
    tcase_add_test(tc, test_two_averaged_resultants);
    tcase_add_test(tc, test_noiseless_exact);
    tcase_add_test(tc, test_short_ramps);
    tcase_add_test(tc, test_single_jump_noiseless);
    tcase_add_test(tc, test_jump_fallbacks);
    tcase_add_test(tc, test_bad_arguments);
    tcase_add_test(tc, test_no_nan);
    tcase_add_test(tc, test_full_ramp_coefficients);
    tcase_add_test(tc, test_pixels_match_pixel);
    suite_add_tcase(s, tc);

    TCase *mc = tcase_create("monte_carlo");
    /* Sanitizer builds run the simulation several times slower than -O2. */
    tcase_set_timeout(mc, 600);
    tcase_add_loop_test(mc, test_mc_constant_rate, 0, N_MC_CASES);
    tcase_add_test(mc, test_mc_cosmic_ray);
    suite_add_tcase(s, mc);
    return s;
}

int main(void) { return wf_test_main(rampfit_suite()); }
