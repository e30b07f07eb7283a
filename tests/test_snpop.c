/* SN Ia population (sim/sn/snpop.c), checked against values derived outside it:
 *  - sample mean and variance of x1, c and δ over 2e5 SNe against the moments of the
 *    truncated asymmetric Gaussian, computed here by Simpson integration of the density
 *    (4σ, σ from the 4th central moment for the variance);
 *  - every draw inside its range, and the edges reached where the density there is not
 *    negligible (the default x1 lower edge; both edges of a narrow test population);
 *  - x0 in closed form at x1 = c = δ = 0 and its x1, c, δ dependence (10^(0.4 α) etc.);
 *  - reproducibility per SN stream, the WF_NOISE_OFF limit, and errors naming the field.
 * Measured numbers are printed so that the log records them. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "sim/sn/snpop.h"
#include "sim/sn/snrate.h"
#include "tests/testutil.h"

#define NDRAW 200000

typedef struct moments {
    double mean, var, m4;
} moments;

/* Moments of the asymmetric Gaussian truncated to [lo, hi], by Simpson on each side of the
 * peak separately (the density has a kink there). */
static void simpson_side(const wf_snpop_agauss *g, double a, double b, double k[5])
{
    const int n = 20000;
    double h = (b - a) / n;
    for (int i = 0; i <= n; i++) {
        double x = a + i * h;
        /* evaluate the side's own branch at the shared end point */
        double s = a < g->peak ? g->sigma_minus : g->sigma_plus, d = (x - g->peak) / s;
        double w = (i == 0 || i == n ? 1.0 : (i % 2 ? 4.0 : 2.0)) * h / 3.0 * exp(-0.5 * d * d);
        for (int p = 0; p < 5; p++) k[p] += w * pow(x, p);
    }
}

static moments agauss_moments(const wf_snpop_agauss *g)
{
    double k[5] = {0, 0, 0, 0, 0};
    if (g->peak > g->lo) simpson_side(g, g->lo, g->peak, k);
    if (g->hi > g->peak) simpson_side(g, g->peak, g->hi, k);
    double m1 = k[1] / k[0], m2 = k[2] / k[0], m3 = k[3] / k[0], m4 = k[4] / k[0];
    moments m;
    m.mean = m1;
    m.var = m2 - m1 * m1;
    m.m4 = m4 - 4 * m1 * m3 + 6 * m1 * m1 * m2 - 3 * m1 * m1 * m1 * m1;
    return m;
}

typedef struct sample {
    double sum, sum2, min, max;
    long n;
} sample;

static void add(sample *s, double x)
{
    if (s->n == 0) s->min = s->max = x;
    s->sum += x;
    s->sum2 += x * x;
    s->min = fmin(s->min, x);
    s->max = fmax(s->max, x);
    s->n++;
}

static void check_moments(const char *name, const sample *s, moments m)
{
    double mean = s->sum / s->n, var = (s->sum2 - s->n * mean * mean) / (s->n - 1);
    double smean = sqrt(m.var / s->n), svar = sqrt((m.m4 - m.var * m.var) / s->n);
    printf("snpop: %-6s mean %.5f (want %.5f +- %.5f, %+.2f sigma), var %.6f (want %.6f +- "
           "%.6f, %+.2f sigma), range [%.4f, %.4f]\n",
           name, mean, m.mean, smean, (mean - m.mean) / smean, var, m.var, svar,
           (var - m.var) / svar, s->min, s->max);
    ck_assert_msg(fabs(mean - m.mean) < 4 * smean, "%s mean %.6f vs %.6f", name, mean, m.mean);
    ck_assert_msg(fabs(var - m.var) < 4 * svar, "%s variance %.6f vs %.6f", name, var, m.var);
}

START_TEST(test_defaults)
{
    wf_snpop p;
    wf_snpop_default(&p);
    ck_assert_int_eq(wf_snpop_validate(&p), WF_OK);
    /* SPEC §5 */
    ck_assert(p.c.peak == -0.054 && p.c.sigma_minus == 0.043 && p.c.sigma_plus == 0.101);
    ck_assert(p.c.lo == -0.3 && p.c.hi == 0.5);
    ck_assert(p.x1.peak == 0.973 && p.x1.sigma_minus == 1.472 && p.x1.sigma_plus == 0.222);
    ck_assert(p.x1.lo == -3.0 && p.x1.hi == 2.0);
    ck_assert(p.alpha == 0.14 && p.beta == 3.1 && p.sigma_int == 0.10);
}
END_TEST

START_TEST(test_default_moments)
{
    wf_snpop p;
    wf_snpop_default(&p);
    sample sx = {0}, sc = {0}, sd = {0};
    for (uint32_t i = 0; i < NDRAW; i++) {
        wf_rng rng;
        wf_sn_rng(11, i, WF_SN_DRAW_POP, &rng);
        wf_sn_params s;
        ck_assert_int_eq(wf_snpop_draw(&p, &rng, 40.0, &s), WF_OK);
        ck_assert(s.x1 >= -3.0 && s.x1 <= 2.0);
        ck_assert(s.c >= -0.3 && s.c <= 0.5);
        add(&sx, s.x1);
        add(&sc, s.c);
        add(&sd, s.delta);
    }
    check_moments("x1", &sx, agauss_moments(&p.x1));
    check_moments("c", &sc, agauss_moments(&p.c));
    double s2 = p.sigma_int * p.sigma_int;
    check_moments("delta", &sd, (moments){0.0, s2, 3 * s2 * s2});
    /* the truncation at x1 = -3 (2.7 σ−) is populated: ~120 of 2e5 expected in [-3, -2.95] */
    ck_assert_msg(sx.min < -2.95, "x1 min %.4f", sx.min);
}
END_TEST

START_TEST(test_narrow_truncation)
{
    /* a range that cuts deep into both sides: the redraw must renormalise, and both edges
     * are reached (~2e5 · 0.4 · 1e-3 draws expected within 1e-3 of each edge) */
    wf_snpop p;
    wf_snpop_default(&p);
    p.x1 = (wf_snpop_agauss){0.2, 1.0, 0.5, -0.6, 0.7};
    p.c = (wf_snpop_agauss){0.0, 0.1, 0.3, -0.05, 0.05};
    ck_assert_int_eq(wf_snpop_validate(&p), WF_OK);
    sample sx = {0}, sc = {0};
    for (uint32_t i = 0; i < NDRAW; i++) {
        wf_rng rng;
        wf_sn_rng(12, i, WF_SN_DRAW_POP, &rng);
        wf_sn_params s;
        ck_assert_int_eq(wf_snpop_draw(&p, &rng, 40.0, &s), WF_OK);
        add(&sx, s.x1);
        add(&sc, s.c);
    }
    check_moments("x1 cut", &sx, agauss_moments(&p.x1));
    check_moments("c cut", &sc, agauss_moments(&p.c));
    ck_assert(sx.min >= -0.6 && sx.max <= 0.7 && sc.min >= -0.05 && sc.max <= 0.05);
    ck_assert(sx.min < -0.6 + 1e-3 && sx.max > 0.7 - 1e-3);
    ck_assert(sc.min < -0.05 + 1e-4 && sc.max > 0.05 - 1e-4);
    /* a peak on the lower edge: only the upper half remains */
    p.x1 = (wf_snpop_agauss){0.0, 1.0, 0.5, 0.0, 3.0};
    sample sh = {0};
    for (uint32_t i = 0; i < 50000; i++) {
        wf_rng rng;
        wf_sn_rng(13, i, WF_SN_DRAW_POP, &rng);
        double x;
        ck_assert_int_eq(wf_snpop_agauss_draw(&p.x1, &rng, &x), WF_OK);
        add(&sh, x);
    }
    check_moments("x1 half", &sh, agauss_moments(&p.x1));
}
END_TEST

START_TEST(test_x0)
{
    wf_snpop p;
    wf_snpop_default(&p);
    double mu = 43.2, x0, ref;
    ck_assert_int_eq(wf_snpop_x0(&p, mu, 0, 0, 0, &ref), WF_OK);
    ck_assert(fabs(ref / (pow(10.0, -0.4 * mu) / 1e-12) - 1) < 1e-14);
    ck_assert_int_eq(wf_snpop_x0(&p, mu, 1.0, 0, 0, &x0), WF_OK);
    ck_assert(fabs(x0 / ref / pow(10.0, 0.4 * 0.14) - 1) < 1e-14); /* wider: brighter */
    ck_assert_int_eq(wf_snpop_x0(&p, mu, 0, 0.1, 0, &x0), WF_OK);
    ck_assert(fabs(x0 / ref / pow(10.0, -0.4 * 3.1 * 0.1) - 1) < 1e-14); /* redder: fainter */
    ck_assert_int_eq(wf_snpop_x0(&p, mu, 0, 0, 0.2, &x0), WF_OK);
    ck_assert(fabs(x0 / ref / pow(10.0, -0.08) - 1) < 1e-14);
    ck_assert_int_eq(wf_snpop_x0(&p, mu + 5.0, 0, 0, 0, &x0), WF_OK);
    ck_assert(fabs(x0 / ref - 0.01) < 1e-16);
    /* drawn SNe: x0 from their own x1, c, δ */
    for (uint32_t i = 0; i < 100; i++) {
        wf_rng rng;
        wf_sn_rng(5, i, WF_SN_DRAW_POP, &rng);
        wf_sn_params s;
        ck_assert_int_eq(wf_snpop_draw(&p, &rng, mu, &s), WF_OK);
        double want = 1.0 / (1e-12 * pow(10.0, 0.4 * (mu - 0.14 * s.x1 + 3.1 * s.c + s.delta)));
        ck_assert(fabs(s.x0 / want - 1) < 1e-14);
        ck_assert(s.mu == mu);
    }
    ck_assert_int_eq(wf_snpop_x0(&p, NAN, 0, 0, 0, &x0), WF_ERR_RANGE);
}
END_TEST

START_TEST(test_streams)
{
    wf_snpop p;
    wf_snpop_default(&p);
    wf_rng a, b;
    wf_sn_params sa, sb;
    wf_sn_rng(77, 3, WF_SN_DRAW_POP, &a);
    wf_sn_rng(77, 3, WF_SN_DRAW_POP, &b);
    ck_assert_int_eq(wf_snpop_draw(&p, &a, 41.0, &sa), WF_OK);
    ck_assert_int_eq(wf_snpop_draw(&p, &b, 41.0, &sb), WF_OK);
    ck_assert(memcmp(&sa, &sb, sizeof sa) == 0);
    wf_sn_rng(78, 3, WF_SN_DRAW_POP, &b);
    ck_assert_int_eq(wf_snpop_draw(&p, &b, 41.0, &sb), WF_OK);
    ck_assert(sa.x1 != sb.x1 && sa.c != sb.c && sa.delta != sb.delta);
    /* WF_NOISE_OFF: Gaussians return 0, so the peaks and δ = 0 */
    wf_noise off = {WF_NOISE_OFF, 1, 0, 0};
    wf_rng o;
    wf_rng_init(&o, &off, 0, WF_SN_DRAW_POP, WF_PURPOSE_SN);
    ck_assert_int_eq(wf_snpop_draw(&p, &o, 41.0, &sa), WF_OK);
    ck_assert(sa.x1 == 0.973 && sa.c == -0.054 && sa.delta == 0.0);
}
END_TEST

static void expect_error(const wf_snpop *p, const char *want)
{
    wf_status st = wf_snpop_validate(p);
    const char *msg = wf_error_message();
    ck_assert_msg(st == WF_ERR_RANGE, "expected a range error naming '%s', got %d", want, st);
    ck_assert_msg(strstr(msg, want) != NULL, "'%s' not in: %s", want, msg);
    wf_rng rng;
    wf_sn_rng(1, 0, WF_SN_DRAW_POP, &rng);
    wf_sn_params s;
    ck_assert_int_eq(wf_snpop_draw(p, &rng, 40.0, &s), WF_ERR_RANGE);
}

START_TEST(test_errors)
{
    wf_snpop p;
    wf_snpop_default(&p);
    p.x1.sigma_minus = -1;
    expect_error(&p, "x1.sigma_minus = -1");
    wf_snpop_default(&p);
    p.c.sigma_plus = NAN;
    expect_error(&p, "c.sigma_plus = nan");
    wf_snpop_default(&p);
    p.c.sigma_plus = p.c.sigma_minus = 0;
    expect_error(&p, "both zero");
    wf_snpop_default(&p);
    p.c.lo = 0.6;
    expect_error(&p, "c.lo = 0.6");
    wf_snpop_default(&p);
    p.x1.peak = 2.5;
    expect_error(&p, "x1.peak = 2.5");
    wf_snpop_default(&p);
    p.x1 = (wf_snpop_agauss){0.0, 1.0, 1.0, 0.0, 1e-5}; /* ~4e-6 of the mass in range */
    expect_error(&p, "widen the range");
    wf_snpop_default(&p);
    p.alpha = INFINITY;
    expect_error(&p, "alpha = inf");
    wf_snpop_default(&p);
    p.beta = NAN;
    expect_error(&p, "beta");
    wf_snpop_default(&p);
    p.sigma_int = -0.1;
    expect_error(&p, "sigma_int = -0.1");
    wf_snpop_default(&p);
    wf_rng rng;
    wf_sn_rng(1, 0, WF_SN_DRAW_POP, &rng);
    wf_sn_params s;
    ck_assert_int_eq(wf_snpop_draw(&p, &rng, NAN, &s), WF_ERR_RANGE);
    ck_assert(strstr(wf_error_message(), "mu") != NULL);
    /* zero intrinsic scatter and a one-sided law are allowed */
    p.sigma_int = 0;
    p.c.sigma_minus = 0;
    ck_assert_int_eq(wf_snpop_draw(&p, &rng, 40.0, &s), WF_OK);
    ck_assert(s.delta == 0.0 && s.c >= -0.054);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("snpop");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, test_defaults);
    tcase_add_test(tc, test_default_moments);
    tcase_add_test(tc, test_narrow_truncation);
    tcase_add_test(tc, test_x0);
    tcase_add_test(tc, test_streams);
    tcase_add_test(tc, test_errors);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
