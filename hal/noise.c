#include "hal/noise.h"
#include "hal/philox.h"

#include <math.h>
#include <string.h>

void wf_philox4x32(const uint32_t in[4], const uint32_t key_in[2], uint32_t out[4])
{
    uint32_t c0 = in[0], c1 = in[1], c2 = in[2], c3 = in[3];
    wf_philox_rounds(&c0, &c1, &c2, &c3, key_in[0], key_in[1]);
    out[0] = c0; out[1] = c1; out[2] = c2; out[3] = c3;
}

void wf_rng_init(wf_rng *rng, const wf_noise *noise, uint32_t pixel, uint32_t read,
                 wf_purpose purpose)
{
    rng->key[0] = (uint32_t)noise->seed;
    rng->key[1] = (uint32_t)(noise->seed >> 32);
    rng->ctr[0] = pixel;
    rng->ctr[1] = read;
    rng->ctr[2] = noise->exposure;
    rng->ctr[3] = ((noise->sca & 0xffu) << 24) | (((uint32_t)purpose & 0xffu) << 16);
    rng->next = 4;
    rng->off = noise->kind == WF_NOISE_OFF;
}

uint32_t wf_rng_u32(wf_rng *rng)
{
    if (rng->next >= 4) {
        wf_philox4x32(rng->ctr, rng->key, rng->buf);
        /* The block index lives in the low 16 bits of ctr[3]; 65536 blocks (262144 words)
         * per stream is far beyond any draw sequence here (PTRS accepts in ~1.1 tries). */
        rng->ctr[3] = (rng->ctr[3] & 0xffff0000u) | ((rng->ctr[3] + 1u) & 0xffffu);
        rng->next = 0;
    }
    return rng->buf[rng->next++];
}

void wf_rng_seek(wf_rng *rng, uint32_t block)
{
    rng->ctr[3] = (rng->ctr[3] & 0xffff0000u) | (block & 0xffffu);
    rng->next = 4;
}

double wf_rng_uniform(wf_rng *rng)
{
    return ((double)wf_rng_u32(rng) + 0.5) * (1.0 / 4294967296.0);
}

double wf_rng_uniform53(wf_rng *rng)
{
    uint32_t w0 = wf_rng_u32(rng);
    uint32_t w1 = wf_rng_u32(rng);
    return wf_uniform53_words(w0, w1);
}

double wf_norm_ppf(double p)
{
    static const double a[6] = {-3.969683028665376e+01, 2.209460984245205e+02,
                                -2.759285104469687e+02, 1.383577518672690e+02,
                                -3.066479806614716e+01, 2.506628277459239e+00};
    static const double b[5] = {-5.447609879822406e+01, 1.615858368580409e+02,
                                -1.556989798598866e+02, 6.680131188771972e+01,
                                -1.328068155288572e+01};
    static const double c[6] = {-7.784894002430293e-03, -3.223964580411365e-01,
                                -2.400758277161838e+00, -2.549732539343734e+00,
                                4.374664141464968e+00, 2.938163982698783e+00};
    static const double d[4] = {7.784695709041462e-03, 3.224671290700398e-01,
                                2.445134137142996e+00, 3.754408661907416e+00};
    const double plow = 0.02425;
    if (p <= 0.0) return -INFINITY;
    if (p >= 1.0) return INFINITY;
    if (p < plow || p > 1.0 - plow) {
        double q = sqrt(-2.0 * log(p < plow ? p : 1.0 - p));
        double x = (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
                   ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
        return p < plow ? x : -x;
    }
    double q = p - 0.5, r = q * q;
    return (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
           (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0);
}

double wf_rng_gauss(wf_rng *rng)
{
    if (rng->off)
        return 0.0;
    return wf_norm_ppf(wf_rng_uniform(rng));
}

/* log(k!) - (k log k - k): Stirling's series, truncation error < 1e-10 for k >= 10 (6e-11 at 10). */
static double stirling_tail(double k)
{
    double k2 = k * k;
    return 0.5 * log(2.0 * M_PI * k) + (1.0 / 12.0 - (1.0 / 360.0 - 1.0 / (1260.0 * k2)) / k2) / k;
}

/* log P(k | mu) = k log mu - mu - log k!, written so that the large terms cancel
 * analytically (log1p) instead of numerically: accurate at mu ~ 1e9 where the naive
 * form loses ~6 digits. */
static double poisson_logpmf(double k, double mu)
{
    if (k < 10.0)
        return k * log(mu) - mu - lgamma(k + 1.0);
    double delta = k - mu;
    return delta - k * log1p(delta / mu) - stirling_tail(k);
}

/* One attempt of Hörmann's PTRS: returns k >= 0 when (u, v) is accepted, -1 otherwise. */
static double ptrs_attempt(double mu, double u01, double v)
{
    const double smu = sqrt(mu);
    const double b = 0.931 + 2.53 * smu;
    const double a = -0.059 + 0.02483 * b;
    const double vr = 0.9277 - 3.6224 / (b - 2.0);
    double u = u01 - 0.5;
    double us = 0.5 - fabs(u);
    double k = floor((2.0 * a / us + b) * u + mu + 0.43);
    if (us >= 0.07 && v <= vr)
        return k;
    if (k < 0.0 || (us < 0.013 && v > us))
        return -1.0;
    const double inv_alpha = 1.1239 + 1.1328 / (b - 3.4);
    if (log(v) + log(inv_alpha) - log(a / (us * us) + b) <= poisson_logpmf(k, mu))
        return k;
    return -1.0;
}

static double poisson_ptrs(wf_rng *rng, double mu)
{
    for (;;) {
        double u = wf_rng_uniform53(rng);
        double v = wf_rng_uniform53(rng);
        double k = ptrs_attempt(mu, u, v);
        if (k >= 0.0)
            return k;
    }
}

int wf_poisson_ptrs_try(double mean, uint32_t wu, uint32_t wv, double *k)
{
    double u = ((double)wu + 0.5) * (1.0 / 4294967296.0);
    double v = ((double)wv + 0.5) * (1.0 / 4294967296.0);
    *k = ptrs_attempt(mean, u, v);
    return *k >= 0.0;
}

double wf_rng_poisson(wf_rng *rng, double mean)
{
    if (!(mean > 0.0))
        return 0.0;
    if (rng->off)
        return mean;
    if (mean >= 10.0)
        return poisson_ptrs(rng, mean);
    double u = wf_rng_uniform53(rng);
    double p = exp(-mean), cdf = p;
    double k = 0.0;
    /* The summed CDF can stay below 1 by ~1e-15 in floating point, so u may lie above all
     * of it: stop once the terms no longer change the sum (u is then in the far tail, and k
     * is there) instead of running on to the cap, which would return 200 electrons. */
    while (u > cdf && k < 200.0) {
        k += 1.0;
        p *= mean / k;
        double next = cdf + p;
        if (next == cdf)
            break;
        cdf = next;
    }
    return k;
}

/* The first word w with (w + 0.5) 2^-32 > c: w > c 2^32 - 0.5, i.e. w >= floor(c 2^32 - 0.5)
 * + 1, where c 2^32 and c 2^32 - 0.5 are exact for c >= e^-10 (0.5 stays a multiple of their
 * last place). A double: 2^32 or more when no word is. */
static double first_word_above(double c) { return floor(ldexp(c, 32) - 0.5) + 1.0; }

/* Poisson(m) inversion's cumulative sums as the readout's one-pixel draw forms them
 * (firmware/readout.c): F_0 = e = exp(-m), F_1 = F_0 + e m, F_2 = F_1 + e m^2 / 2, then
 * F_k = F_(k-1) + p_k with p_k = p_(k-1) (m / k), up to cap sums (cap >= 3) or the first term
 * that no longer changes the sum (that draw stops there). Returns how many were formed. */
static int inversion_sums(double m, double e, double *F, int cap)
{
    double p1 = e * m, p = p1 * m * 0.5;
    F[0] = e;
    F[1] = F[0] + p1;
    F[2] = F[1] + p;
    int n = 3;
    for (double k = 3.0; n < cap; k += 1.0) {
        p *= m / k;
        double next = F[n - 1] + p;
        if (next == F[n - 1]) break;
        F[n++] = next;
    }
    return n;
}

wf_status wf_poisson_table_init(wf_poisson_table *t, double mean)
{
    if (!(mean > 0.0 && mean < 10.0))
        return wf_error(WF_ERR_RANGE, "noise: Poisson table for mean %g outside (0, 10)", mean);
    t->mean = mean;
    int n = inversion_sums(mean, exp(-mean), t->cdf, WF_POISSON_TABLE_MAX);
    t->n = n;
    t->nword = 0;
    for (int j = 0; j < n; j++) {
        double first = first_word_above(t->cdf[j]);
        if (first > 4294967295.0) break;
        t->word[t->nword++] = (uint32_t)first;
    }
    return WF_OK;
}
