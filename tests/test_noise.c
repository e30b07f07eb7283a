/* The noise source (hal/noise.c), checked against values derived outside it:
 *  - Philox4x32-10 against the Random123 known-answer vectors (kat_vectors file of the
 *    Random123 distribution, D. E. Shaw Research);
 *  - the documented stream layout (key = seed, counter = {pixel, read, exposure,
 *    SCA<<24 | purpose<<16 | block});
 *  - Poisson and Gaussian draws: sample mean and variance within 4 sigma of theory, and a
 *    chi-square goodness of fit of the Poisson pmf whose p-value is computed here;
 *  - wf_norm_ppf against the inverse of 0.5 erfc(-x / sqrt 2) from libm;
 *  - uniform draws strictly inside (0, 1), including at the extreme generator words.
 * Every draw comes from fixed seeds, so the statistics are deterministic: a failure is
 * reproducible, not flaky. Each sample uses one stream per draw (pixel = draw index), as
 * the firmware does, so it also exercises independence across streams. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hal/noise.h"
#include "hal/vmath.h"
#include "tests/testutil.h"

/* Draws per statistical sample. Release: 1e6 as the statistics were designed. Under
 * AddressSanitizer (detected by __SANITIZE_ADDRESS__ for GCC, __has_feature for Clang) the
 * same tests run with 2.5e5 draws to stay well inside the time budget; the 4-sigma bounds
 * scale with N, so they are the same test, only less sensitive. */
#if defined(__SANITIZE_ADDRESS__)
#define WF_TEST_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define WF_TEST_SANITIZED 1
#endif
#endif
#ifdef WF_TEST_SANITIZED
#define NDRAW 250000
#else
#define NDRAW 1000000
#endif

static wf_noise test_noise(uint64_t seed)
{
    return (wf_noise){WF_NOISE_PHILOX, seed, 11u, 5u};
}

/* ------------------------------------------------------------------ Philox known answers */

typedef struct kat {
    uint32_t ctr[4], key[2], out[4];
} kat;

/* Random123 kat_vectors, lines "philox4x32 10 <ctr0..3> <key0..1> <out0..3>". */
static const kat philox_kats[] = {
    {{0x00000000u, 0x00000000u, 0x00000000u, 0x00000000u},
     {0x00000000u, 0x00000000u},
     {0x6627e8d5u, 0xe169c58du, 0xbc57ac4cu, 0x9b00dbd8u}},
    {{0xffffffffu, 0xffffffffu, 0xffffffffu, 0xffffffffu},
     {0xffffffffu, 0xffffffffu},
     {0x408f276du, 0x41c83b0eu, 0xa20bc7c6u, 0x6d5451fdu}},
    {{0x243f6a88u, 0x85a308d3u, 0x13198a2eu, 0x03707344u},
     {0xa4093822u, 0x299f31d0u},
     {0xd16cfe09u, 0x94fdccebu, 0x5001e420u, 0x24126ea1u}},
};

START_TEST(test_philox_kat)
{
    for (size_t i = 0; i < sizeof philox_kats / sizeof philox_kats[0]; i++) {
        uint32_t out[4];
        wf_philox4x32(philox_kats[i].ctr, philox_kats[i].key, out);
        for (int w = 0; w < 4; w++)
            ck_assert_msg(out[w] == philox_kats[i].out[w],
                          "kat %zu word %d: got %08x, Random123 says %08x", i, w, out[w],
                          philox_kats[i].out[w]);
    }
}
END_TEST

/* The stream is the documented counter layout fed to the (KAT-checked) block function. */
START_TEST(test_stream_layout)
{
    wf_noise n = {WF_NOISE_PHILOX, 0x0123456789abcdefull, 77u, 18u};
    wf_rng rng;
    wf_rng_init(&rng, &n, 4095u * 4096u + 17u, 42u, WF_PURPOSE_READ);
    const uint32_t key[2] = {0x89abcdefu, 0x01234567u};
    for (uint32_t block = 0; block < 3; block++) {
        const uint32_t ctr[4] = {4095u * 4096u + 17u, 42u, 77u,
                                 (18u << 24) | ((uint32_t)WF_PURPOSE_READ << 16) | block};
        uint32_t want[4];
        wf_philox4x32(ctr, key, want);
        for (int w = 0; w < 4; w++) {
            uint32_t got = wf_rng_u32(&rng);
            ck_assert_msg(got == want[w], "block %u word %d: %08x != %08x", block, w, got,
                          want[w]);
        }
    }
}
END_TEST

/* ------------------------------------------------------------------------------ streams */

static void first_words(const wf_noise *n, uint32_t pixel, uint32_t read, wf_purpose purpose,
                        uint32_t out[8])
{
    wf_rng rng;
    wf_rng_init(&rng, n, pixel, read, purpose);
    for (int i = 0; i < 8; i++) out[i] = wf_rng_u32(&rng);
}

START_TEST(test_streams_distinct_and_repeatable)
{
    const wf_noise base = {WF_NOISE_PHILOX, 20240917ull, 3u, 7u};
    uint32_t ref[8], again[8];
    first_words(&base, 1000u, 5u, WF_PURPOSE_PHOTON, ref);

    /* The same key repeats exactly, also after other streams were drawn in between. */
    uint32_t other[8];
    first_words(&base, 1001u, 5u, WF_PURPOSE_PHOTON, other);
    first_words(&base, 1000u, 5u, WF_PURPOSE_PHOTON, again);
    ck_assert_mem_eq(ref, again, sizeof ref);

    /* Changing any one element of (pixel, read, purpose, exposure, SCA, seed) changes the
     * sequence: every one of the 8 words differs (a shared word would be a 2^-32 event). */
    wf_noise v[6];
    uint32_t px[6] = {1000u, 1000u, 1000u, 1000u, 1000u, 1000u};
    uint32_t rd[6] = {5u, 5u, 5u, 5u, 5u, 5u};
    wf_purpose pu[6] = {WF_PURPOSE_PHOTON, WF_PURPOSE_PHOTON, WF_PURPOSE_PHOTON,
                        WF_PURPOSE_PHOTON, WF_PURPOSE_PHOTON, WF_PURPOSE_PHOTON};
    const char *what[6] = {"pixel", "read", "purpose", "exposure", "SCA", "seed"};
    for (int i = 0; i < 6; i++) v[i] = base;
    px[0] = 1001u;
    rd[1] = 6u;
    pu[2] = WF_PURPOSE_READ;
    v[3].exposure = 4u;
    v[4].sca = 8u;
    v[5].seed = base.seed + (1ull << 32); /* only the high key word changes */
    for (int i = 0; i < 6; i++) {
        uint32_t w[8];
        first_words(&v[i], px[i], rd[i], pu[i], w);
        for (int j = 0; j < 8; j++)
            ck_assert_msg(w[j] != ref[j], "changing %s left word %d unchanged", what[i], j);
    }
    /* Low seed word too. */
    wf_noise s2 = base;
    s2.seed = base.seed + 1u;
    uint32_t w[8];
    first_words(&s2, 1000u, 5u, WF_PURPOSE_PHOTON, w);
    ck_assert(memcmp(w, ref, sizeof w) != 0);

    /* Higher-level draws repeat too. */
    wf_rng a, b;
    wf_rng_init(&a, &base, 9u, 2u, WF_PURPOSE_TEST);
    wf_rng_init(&b, &base, 9u, 2u, WF_PURPOSE_TEST);
    for (int i = 0; i < 100; i++) {
        double pa = wf_rng_poisson(&a, 37.5), pb = wf_rng_poisson(&b, 37.5);
        ck_assert(pa == pb);
        double ga = wf_rng_gauss(&a), gb = wf_rng_gauss(&b);
        ck_assert(ga == gb);
    }
}
END_TEST

/* ------------------------------------------------------------------------------ uniform */

START_TEST(test_uniform_open_interval)
{
    /* Extreme generator words, set directly in the (public) stream buffer. */
    wf_rng rng;
    const wf_noise n = test_noise(1);
    wf_rng_init(&rng, &n, 0u, 0u, WF_PURPOSE_TEST);
    const uint32_t words[2] = {0x00000000u, 0xffffffffu};
    for (int i = 0; i < 2; i++) {
        for (int w = 0; w < 4; w++) rng.buf[w] = words[i];
        rng.next = 0;
        double u = wf_rng_uniform(&rng);
        ck_assert_msg(u > 0.0 && u < 1.0, "uniform(%08x) = %.17g", words[i], u);
        rng.next = 0;
        double u53 = wf_rng_uniform53(&rng);
        ck_assert_msg(u53 > 0.0 && u53 < 1.0, "uniform53(%08x x2) = %.17g", words[i], u53);
        rng.next = 0;
        ck_assert(isfinite(wf_rng_gauss(&rng)));
    }

    /* Ordinary draws: strictly inside, and mean 1/2, variance 1/12 within 4 sigma. */
    double s1 = 0.0, s2 = 0.0, t1 = 0.0;
    for (int i = 0; i < NDRAW; i++) {
        wf_rng_init(&rng, &n, (uint32_t)i, 0u, WF_PURPOSE_TEST);
        double u = wf_rng_uniform(&rng), v = wf_rng_uniform53(&rng);
        ck_assert(u > 0.0 && u < 1.0);
        ck_assert(v > 0.0 && v < 1.0);
        s1 += u - 0.5;
        s2 += (u - 0.5) * (u - 0.5);
        t1 += v - 0.5;
    }
    double m = s1 / NDRAW, var = s2 / NDRAW - m * m;
    ck_assert_msg(fabs(m) < 4.0 * sqrt(1.0 / 12.0 / NDRAW), "uniform mean - 1/2 = %g", m);
    ck_assert_msg(fabs(t1 / NDRAW) < 4.0 * sqrt(1.0 / 12.0 / NDRAW), "uniform53 mean - 1/2 = %g",
                  t1 / NDRAW);
    /* mu4 of U(-1/2, 1/2) = 1/80 */
    ck_assert_msg(fabs(var - 1.0 / 12.0) < 4.0 * sqrt((1.0 / 80.0 - 1.0 / 144.0) / NDRAW),
                  "uniform variance %g", var);
}
END_TEST

/* ------------------------------------------------------------------------------ Poisson */

static const double poisson_means[] = {1e-3, 3.0, 9.99, 10.0, 1e3, 1e9};

/* Sample mean and variance of NDRAW draws, accumulated as offsets from mu so that mean 1e9
 * loses nothing to cancellation. */
static void poisson_sample(double mu, uint64_t seed, double *mean, double *var)
{
    const wf_noise n = test_noise(seed);
    double s1 = 0.0, s2 = 0.0;
    for (int i = 0; i < NDRAW; i++) {
        wf_rng rng;
        wf_rng_init(&rng, &n, (uint32_t)i, 1u, WF_PURPOSE_PHOTON);
        double k = wf_rng_poisson(&rng, mu);
        ck_assert_msg(k >= 0.0 && k == floor(k), "draw %d for mean %g: %.17g", i, mu, k);
        double d = k - mu;
        s1 += d;
        s2 += d * d;
    }
    double dm = s1 / NDRAW;
    *mean = mu + dm;
    *var = (s2 - NDRAW * dm * dm) / (NDRAW - 1.0);
}

START_TEST(test_poisson_moments)
{
    const double mu = poisson_means[_i];
    double mean, var;
    poisson_sample(mu, 1000u + (uint64_t)_i, &mean, &var);
    const double N = NDRAW;
    const double sd_mean = sqrt(mu / N);
    /* Poisson: central mu4 = mu (1 + 3 mu); sd of the sample variance ~ sqrt((mu4 - mu^2)/N) */
    const double sd_var = sqrt((mu * (1.0 + 3.0 * mu) - mu * mu) / N);
    printf("poisson mu=%-8g N=%d: mean %+.2f sd, variance %+.2f sd\n", mu, NDRAW,
           (mean - mu) / sd_mean, (var - mu) / sd_var);
    ck_assert_msg(fabs(mean - mu) < 4.0 * sd_mean, "mu %g: sample mean %.10g (sd %g)", mu, mean,
                  sd_mean);
    ck_assert_msg(fabs(var - mu) < 4.0 * sd_var, "mu %g: sample variance %.10g (sd %g)", mu, var,
                  sd_var);
}
END_TEST

/* Regularised upper incomplete gamma Q(a, x) (series below a + 1, Lentz continued fraction
 * above): the chi-square survival function is Q(df/2, chi2/2). */
static double gamma_q(double a, double x)
{
    if (x <= 0.0) return 1.0;
    double lpre = a * log(x) - x - lgamma(a);
    if (x < a + 1.0) {
        double term = 1.0 / a, sum = term;
        for (int n = 1; n < 100000; n++) {
            term *= x / (a + n);
            sum += term;
            if (fabs(term) < fabs(sum) * 1e-16) break;
        }
        return 1.0 - sum * exp(lpre);
    }
    const double tiny = 1e-300;
    double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
    for (int n = 1; n < 100000; n++) {
        double an = -n * (n - a);
        b += 2.0;
        d = an * d + b;
        if (fabs(d) < tiny) d = tiny;
        c = b + an / c;
        if (fabs(c) < tiny) c = tiny;
        d = 1.0 / d;
        double del = d * c;
        h *= del;
        if (fabs(del - 1.0) < 1e-16) break;
    }
    return exp(lpre) * h;
}

static double poisson_pmf(double k, double mu)
{
    return exp(k * log(mu) - mu - lgamma(k + 1.0));
}

static const double gof_means[] = {3.0, 9.99, 10.0, 30.0, 1e3};

START_TEST(test_poisson_chi_square)
{
    const double mu = gof_means[_i];
    const int kmax = (int)(mu + 40.0 * sqrt(mu) + 40.0);
    double *pmf = calloc((size_t)kmax + 1, sizeof *pmf);
    long *count = calloc((size_t)kmax + 2, sizeof *count);
    ck_assert(pmf && count);
    for (int k = 0; k <= kmax; k++) pmf[k] = poisson_pmf(k, mu);

    const wf_noise n = test_noise(2000u + (uint64_t)_i);
    for (int i = 0; i < NDRAW; i++) {
        wf_rng rng;
        wf_rng_init(&rng, &n, (uint32_t)i, 0u, WF_PURPOSE_PHOTON);
        double k = wf_rng_poisson(&rng, mu);
        count[k > kmax ? kmax + 1 : (int)k]++;
    }

    /* Bins: k <= lo, each lo < k < hi, k >= hi, with every expectation >= 5. */
    const double N = NDRAW;
    int lo = 0;
    double cum = pmf[0];
    while (cum * N < 5.0) cum += pmf[++lo];
    int hi = kmax;
    double tail = pmf[kmax]; /* P(k > kmax) < 1e-30 here: neglected */
    while (tail * N < 5.0) tail += pmf[--hi];
    ck_assert_int_lt(lo, hi);

    double chi2 = 0.0, e, o = 0.0;
    for (int k = 0; k <= lo; k++) o += (double)count[k];
    e = cum * N;
    chi2 += (o - e) * (o - e) / e;
    for (int k = lo + 1; k < hi; k++) {
        e = pmf[k] * N;
        o = (double)count[k];
        chi2 += (o - e) * (o - e) / e;
    }
    o = 0.0;
    for (int k = hi; k <= kmax + 1; k++) o += (double)count[k];
    e = tail * N;
    chi2 += (o - e) * (o - e) / e;

    const int bins = hi - lo + 1, df = bins - 1;
    const double p = gamma_q(0.5 * df, 0.5 * chi2);
    printf("poisson mu=%-8g N=%d: chi2 %.1f over %d bins (df %d), p = %.3g\n", mu, NDRAW, chi2,
           bins, df, p);
    ck_assert_msg(p > 1e-4, "mu %g: chi2 %.2f, df %d, p %.3g", mu, chi2, df, p);
    free(pmf);
    free(count);
}
END_TEST

/* The p-value routine itself: chi-square survival values known in closed form. */
START_TEST(test_chi_square_pvalue_routine)
{
    /* df = 2: exp(-x/2). df = 1: erfc(sqrt(x/2)). */
    for (double x = 0.1; x < 80.0; x *= 1.7) {
        ck_assert_double_eq_tol(gamma_q(1.0, x / 2) / exp(-x / 2), 1.0, 1e-12);
        ck_assert_double_eq_tol(gamma_q(0.5, x / 2) / erfc(sqrt(x / 2)), 1.0, 1e-10);
    }
}
END_TEST

START_TEST(test_poisson_edge_cases)
{
    const wf_noise n = test_noise(3);
    wf_rng rng;
    wf_rng_init(&rng, &n, 0u, 0u, WF_PURPOSE_PHOTON);
    const double zero_means[] = {0.0, -0.0, -1.0, -1e9, -INFINITY, NAN};
    for (size_t i = 0; i < sizeof zero_means / sizeof zero_means[0]; i++)
        ck_assert_msg(wf_rng_poisson(&rng, zero_means[i]) == 0.0, "mean %g", zero_means[i]);

    /* WF_NOISE_OFF: every draw is its expectation. */
    const wf_noise off = {WF_NOISE_OFF, 3u, 11u, 5u};
    wf_rng_init(&rng, &off, 0u, 0u, WF_PURPOSE_PHOTON);
    const double means[] = {1e-3, 0.5, 3.7, 9.99, 10.0, 1234.5678, 1e9};
    for (size_t i = 0; i < sizeof means / sizeof means[0]; i++)
        ck_assert(wf_rng_poisson(&rng, means[i]) == means[i]);
    ck_assert(wf_rng_poisson(&rng, -2.0) == 0.0);
    ck_assert(wf_rng_poisson(&rng, NAN) == 0.0);
    ck_assert(wf_rng_gauss(&rng) == 0.0);

    /* The largest uniform the generator can produce must not run the inversion off the end
     * of the summed pmf (whose floating-point sum can stay below 1 by ~1e-15): the draw has
     * to land in the far tail of the distribution, not at an arbitrary cap. The true
     * quantile at 1 - 2^-53 is below 50 for every mean < 10. */
    wf_rng_init(&rng, &n, 0u, 0u, WF_PURPOSE_PHOTON);
    for (double mu = 1e-4; mu < 10.0; mu *= 1.01) {
        for (int w = 0; w < 4; w++) rng.buf[w] = 0xffffffffu;
        rng.next = 0;
        double k = wf_rng_poisson(&rng, mu);
        ck_assert_msg(k <= 60.0, "mean %.17g, largest uniform: %g electrons", mu, k);
    }
}
END_TEST

/* ----------------------------------------------------------------------------- Gaussian */

START_TEST(test_gauss_moments)
{
    const wf_noise n = test_noise(4);
    double s1 = 0.0, s2 = 0.0;
    for (int i = 0; i < NDRAW; i++) {
        wf_rng rng;
        wf_rng_init(&rng, &n, (uint32_t)i, 3u, WF_PURPOSE_READ);
        double g = wf_rng_gauss(&rng);
        s1 += g;
        s2 += g * g;
    }
    const double N = NDRAW, m = s1 / N, var = (s2 - N * m * m) / (N - 1.0);
    printf("gauss N=%d: mean %+.2f sd, variance %+.2f sd\n", NDRAW, m / sqrt(1.0 / N),
           (var - 1.0) / sqrt(2.0 / N));
    ck_assert_msg(fabs(m) < 4.0 * sqrt(1.0 / N), "gauss mean %g", m);
    /* mu4 - sigma^4 = 3 - 1 = 2 */
    ck_assert_msg(fabs(var - 1.0) < 4.0 * sqrt(2.0 / N), "gauss variance %g", var);
}
END_TEST

/* The exact quantile x* near x by Newton steps on the libm CDF, using the tail that is
 * accurate in double: Phi(x) = 0.5 erfc(-x/sqrt2) for p < 1/2, and for p > 1/2 the upper tail
 * 0.5 erfc(x/sqrt2) against q = 1 - p (exact in double for p >= 1/2). */
static double exact_quantile(double p, double x)
{
    for (int it = 0; it < 3; it++) {
        double pdf = exp(-0.5 * x * x) / sqrt(2.0 * M_PI);
        if (p < 0.5)
            x -= (0.5 * erfc(-x / M_SQRT2) - p) / pdf;
        else
            x += (0.5 * erfc(x / M_SQRT2) - (1.0 - p)) / pdf;
    }
    return x;
}

/* hal/vmath.h's log and exp against libm's over their whole ranges: log within 1 ulp
 * (fdlibm's bound), exp within its stated 2 (the 13-term series leaves < 1e-17 of truncation,
 * so the rest is rounding: 1 ulp measured), and exp's stated edges: 0 below -708, 1 at 0. */
static double ulps(double got, double want)
{
    const double a = fabs(want);
    return fabs(got - want) / (nextafter(a, INFINITY) - a);
}

START_TEST(test_vmath_against_libm)
{
    double worst_e = 0.0, worst_l = 0.0;
    for (double x = -708.0; x <= 709.0; x += 0.000713) {
        const double u = ulps(wf_vexp(x), exp(x));
        if (u > worst_e) worst_e = u;
    }
    for (double x = 1e-307; x < 1e307; x *= 1.000713) {
        const double u = ulps(wf_vlog(x), log(x));
        if (u > worst_l) worst_l = u;
    }
    printf("vmath: exp within %.3f ulp, log within %.3f ulp of libm\n", worst_e, worst_l);
    ck_assert(worst_e <= 2.0); /* hal/vmath.h's stated bounds */
    ck_assert(worst_l <= 1.0);
    ck_assert(wf_vexp(0.0) == 1.0);
    ck_assert(wf_vexp(-708.0) > 0.0);
    ck_assert(wf_vexp(-708.5) == 0.0);
    ck_assert(wf_vexp(-1e300) == 0.0);
    ck_assert(wf_vlog(1.0) == 0.0);
}
END_TEST

START_TEST(test_norm_ppf)
{
    ck_assert(wf_norm_ppf(0.0) == -INFINITY);
    ck_assert(wf_norm_ppf(1.0) == INFINITY);
    ck_assert(fabs(wf_norm_ppf(0.5)) < 1e-300);

    double worst = 0.0, worst_p = 0.0;
    int npts = 0;
    /* Log grid on both tails, 1e-12 .. 0.5, and a linear grid through the centre. */
    for (double t = 1e-12; t < 0.5; t *= 1.05) {
        const double ps[2] = {t, 1.0 - t};
        for (int s = 0; s < 2; s++) {
            double x = wf_norm_ppf(ps[s]), xs = exact_quantile(ps[s], x);
            double rel = fabs(x - xs) / fabs(xs);
            if (rel > worst) worst = rel, worst_p = ps[s];
            npts++;
        }
    }
    for (int i = 1; i < 2000; i++) {
        double p = i / 2000.0;
        if (p == 0.5) continue;
        double x = wf_norm_ppf(p), xs = exact_quantile(p, x);
        double rel = fabs(x - xs) / fabs(xs);
        if (rel > worst) worst = rel, worst_p = p;
        npts++;
        /* symmetry */
        ck_assert(fabs(wf_norm_ppf(p) + wf_norm_ppf(1.0 - p)) <= 1e-9 * fabs(x) + 1e-15);
    }
    printf("norm_ppf: %d points, worst relative error %.3g at p = %.6g\n", npts, worst, worst_p);
    ck_assert_msg(worst < 1.2e-9, "norm_ppf relative error %.3g at p = %.17g", worst, worst_p);

    /* Monotone on a fine grid (the two rational pieces meet at 0.02425 and 0.97575). */
    double prev = -INFINITY;
    for (double p = 0.02; p < 0.03; p += 1e-6) {
        double x = wf_norm_ppf(p);
        ck_assert(x > prev);
        prev = x;
    }
}
END_TEST

/* The row-at-a-time generator used by the readout gives the same words as the scalar stream,
 * and its normals are wf_norm_ppf rounded to float, whichever SIMD clone runs. */
START_TEST(test_batch_matches_scalar)
{
    wf_noise noise = {WF_NOISE_PHILOX, 0x123456789abcdefULL, 77, 5};
    enum { N = 1029 };
    static uint32_t w[4][N];
    static float z[N];
    wf_noise_block_row(&noise, 4088u * 100u + 3u, N, 41, WF_PURPOSE_PHOTON, 0, w[0], w[1], w[2], w[3]);
    for (int i = 0; i < N; i++) {
        wf_rng rng;
        wf_rng_init(&rng, &noise, 4088u * 100u + 3u + (uint32_t)i, 41, WF_PURPOSE_PHOTON);
        for (int k = 0; k < 4; k++) ck_assert_uint_eq(w[k][i], wf_rng_u32(&rng));
        /* seeking to block 1 continues the same stream */
        wf_rng again;
        wf_rng_init(&again, &noise, 4088u * 100u + 3u + (uint32_t)i, 41, WF_PURPOSE_PHOTON);
        wf_rng_seek(&again, 1);
        ck_assert_uint_eq(wf_rng_u32(&again), wf_rng_u32(&rng));
    }
    /* a later block of the row batch is that block of each stream */
    wf_noise_block_row(&noise, 17u, N, 3, WF_PURPOSE_RESULTANT, 5, w[0], w[1], w[2], w[3]);
    for (int i = 0; i < N; i++) {
        wf_rng rng;
        wf_rng_init(&rng, &noise, 17u + (uint32_t)i, 3, WF_PURPOSE_RESULTANT);
        wf_rng_seek(&rng, 5);
        for (int k = 0; k < 4; k++) ck_assert_uint_eq(w[k][i], wf_rng_u32(&rng));
    }
    wf_norm_from_u32(w[0], N, z);
    for (int i = 0; i < N; i++)
        ck_assert(z[i] == (float)wf_norm_ppf(((double)w[0][i] + 0.5) / 4294967296.0));
    const uint32_t edge[6] = {0u, 1u, 104152844u, 104152845u, 4190814450u, 0xffffffffu};
    float ze[6];
    wf_norm_from_u32(edge, 6, ze);
    for (int i = 0; i < 6; i++)
        ck_assert(ze[i] == (float)wf_norm_ppf(((double)edge[i] + 0.5) / 4294967296.0));
}
END_TEST

/* A stream's blocks in lanes are the words wf_rng_u32 gives in turn, from any block on, for
 * lengths that leave SIMD tails; the stream's end is refused, not wrapped. */
START_TEST(test_stream_blocks_match_scalar)
{
    wf_noise noise = {WF_NOISE_PHILOX, 0xfedcba9876543210ULL, 3, 11};
    enum { N = 61 };
    uint32_t w[4][N];
    const uint32_t starts[] = {0u, 1u, 7u, 65536u - N};
    for (int s0 = 0; s0 < 4; s0++)
        for (int n = 0; n <= N; n += 15) {
            ck_assert(wf_noise_stream_blocks(&noise, 4321u, 2u, WF_PURPOSE_SCENE, starts[s0], n,
                                             w[0], w[1], w[2], w[3]) == WF_OK);
            wf_rng rng;
            wf_rng_init(&rng, &noise, 4321u, 2u, WF_PURPOSE_SCENE);
            wf_rng_seek(&rng, starts[s0]);
            for (int b = 0; b < n; b++)
                for (int k = 0; k < 4; k++) ck_assert_uint_eq(w[k][b], wf_rng_u32(&rng));
        }
    /* a request that ends at the stream's last block is whole; an empty one at its end too */
    ck_assert(wf_noise_stream_blocks(&noise, 4321u, 2u, WF_PURPOSE_SCENE, 65536u - N, N, w[0], w[1], w[2],
                                     w[3]) == WF_OK);
    {
        wf_rng rng;
        wf_rng_init(&rng, &noise, 4321u, 2u, WF_PURPOSE_SCENE);
        wf_rng_seek(&rng, 65536u - N);
        for (int b = 0; b < N; b++)
            for (int k = 0; k < 4; k++) ck_assert_uint_eq(w[k][b], wf_rng_u32(&rng));
    }
    ck_assert(wf_noise_stream_blocks(&noise, 4321u, 2u, WF_PURPOSE_SCENE, 65536u, 0, w[0], w[1], w[2],
                                     w[3]) == WF_OK);
    ck_assert(wf_noise_stream_blocks(&noise, 1u, 0u, WF_PURPOSE_SCENE, 65536u - 3u, 4, w[0], w[1],
                                     w[2], w[3]) == WF_ERR_RANGE);
    ck_assert(wf_noise_stream_blocks(&noise, 1u, 0u, WF_PURPOSE_SCENE, 0u, -1, w[0], w[1], w[2],
                                     w[3]) == WF_ERR_RANGE);
}
END_TEST

/* Poisson by inversion, written out: the smallest k whose cumulative sum (the terms summed
 * in order, at most 200, a term that no longer moves the sum ending it) reaches u. */
static int invert(uint32_t w, double m)
{
    double u = ((double)w + 0.5) * (1.0 / 4294967296.0), e = exp(-m);
    double p1 = e * m, p2 = p1 * m * 0.5, f0 = e, f1 = f0 + p1, f2 = f1 + p2;
    if (u <= f2) return (u > f0) + (u > f1);
    double p = p2, cdf = f2;
    int k = 2;
    while (u > cdf && k < 200) {
        k++;
        p *= m / k;
        if (cdf + p == cdf) break;
        cdf += p;
    }
    return k;
}

/* The thresholds give inversion's count on both sides of every threshold (the words where
 * the count changes), at the ends of the word range, and hand over exactly the words whose
 * count is above 6; outside (0, 10) every word is handed over. */
START_TEST(test_inversion_thresholds)
{
    /* one row of means, the last five outside (0, 10), so that the SIMD lanes see them all */
    enum { NM = 11, NO = 5 };
    const double means[NM + NO] = {1e-12, 1e-6, 0.01, 0.3, 1.0, 1.1, 2.5, 4.0, 6.0, 9.0, 9.999999,
                                   0.0, -1.0, 10.0, 50.0, NAN};
    double e[NM + NO];
    uint32_t thr_row[6 * (NM + NO)], slow_row[NM + NO];
    for (int i = 0; i < NM + NO; i++) e[i] = exp(-means[i]);
    wf_poisson_inversion_thresholds_row(NM + NO, means, e, thr_row, NM + NO, slow_row);
    for (size_t i = 0; i < NM; i++) {
        double m = means[i];
        uint32_t thr[6], slow = slow_row[i];
        for (int j = 0; j < 6; j++) thr[j] = thr_row[(size_t)j * (NM + NO) + i];
        uint32_t words[32];
        int nw = 0;
        words[nw++] = 0;
        words[nw++] = UINT32_MAX;
        for (int j = 0; j < 6; j++) {
            words[nw++] = thr[j];
            if (thr[j] > 0) words[nw++] = thr[j] - 1;
            if (thr[j] < UINT32_MAX) words[nw++] = thr[j] + 1;
        }
        if (slow > 0) words[nw++] = slow - 1;
        words[nw++] = slow;
        int handed = 0;
        for (int k = 0; k < nw; k++) {
            uint32_t w = words[k];
            int want = invert(w, m);
            if (w >= slow) {
                handed++;
                ck_assert_msg(want > 6 || w == UINT32_MAX, "mean %g, word %u: count %d handed over", m, w, want);
                continue;
            }
            int got = 0;
            for (int j = 0; j < 6; j++) got += w >= thr[j];
            ck_assert_msg(got == want, "mean %g, word %u: %d, inversion %d", m, w, got, want);
        }
        ck_assert(handed >= 1); /* UINT32_MAX at least */
        if (m >= 2.5) { /* a count of 7 is within the words: the hand-over starts there */
            ck_assert_int_eq(invert(slow, m), 7);
            ck_assert_int_eq(invert(slow - 1, m), 6);
        }
    }
    for (int i = NM; i < NM + NO; i++) ck_assert_uint_eq(slow_row[i], 0);
}
END_TEST

static Suite *noise_suite(void)
{
    Suite *s = suite_create("noise");
    TCase *tc = tcase_create("philox");
    tcase_add_test(tc, test_philox_kat);
    tcase_add_test(tc, test_batch_matches_scalar);
    tcase_add_test(tc, test_stream_blocks_match_scalar);
    tcase_add_test(tc, test_stream_layout);
    tcase_add_test(tc, test_streams_distinct_and_repeatable);
    suite_add_tcase(s, tc);

    TCase *st = tcase_create("statistics");
    tcase_set_timeout(st, 120);
    tcase_add_test(st, test_uniform_open_interval);
    tcase_add_loop_test(st, test_poisson_moments, 0,
                        (int)(sizeof poisson_means / sizeof poisson_means[0]));
    tcase_add_test(st, test_chi_square_pvalue_routine);
    tcase_add_loop_test(st, test_poisson_chi_square, 0,
                        (int)(sizeof gof_means / sizeof gof_means[0]));
    tcase_add_test(st, test_poisson_edge_cases);
    tcase_add_test(st, test_inversion_thresholds);
    tcase_add_test(st, test_gauss_moments);
    tcase_add_test(st, test_norm_ppf);
    tcase_add_test(st, test_vmath_against_libm);
    suite_add_tcase(s, st);
    return s;
}

int main(void) { return wf_test_main(noise_suite()); }
