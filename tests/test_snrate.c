/* SN Ia rates, counts and redshift draws (sim/sn/snrate.c), checked against values derived
 * outside it:
 *  - the expected count per deg² over two Julian years (730.5 d) for the SPEC §5 law, by a
 *    composite Simpson rule written here on this file's own H(z) and D_C, and by astropy +
 *    scipy (typed in);
 *  - the padded window and the count's scaling with it, in closed form;
 *  - the redshift quantile against this file's own forward CDF (error in z), a χ² test of
 *    1e5 drawn redshifts, a uniformity test of the peak dates;
 *  - Poisson counts over many seeds; per-SN reproducibility and seed dependence;
 *  - the POWERLAW2 parser and validation errors, which name the field.
 * Measured numbers are printed so that the log records them. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "sim/sn/snrate.h"
#include "tests/testutil.h"

#define C_KMS 299792.458
#define H0 70.0
#define OM 0.315
#define ZMIN 0.06
#define ZMAX 2.99
#define SR_PER_DEG2 (M_PI * M_PI / (180.0 * 180.0))

/* ------------------------------------------------------------------ this file's model */

static double inv_e(double z)
{
    double a = 1.0 + z;
    return 1.0 / sqrt(OM * a * a * a + 1.0 - OM);
}

/* SPEC §5 law, written out again here */
static double spec_rate(double z, int piece)
{
    return piece == 0 ? 2.5e-5 * pow(1 + z, 1.5) : 9.7e-5 * pow(1 + z, -0.5);
}

/* ∫0^z dz/E by Simpson, n even */
static double dc_units(double z, int n)
{
    double h = z / n, s = 0.0;
    for (int k = 0; k <= n; k++) s += inv_e(k * h) * (k == 0 || k == n ? 1 : (k % 2 ? 4 : 2));
    return s * h / 3.0;
}

/* ∫_a^b R/(1+z) dV/dz dz (SNe sr⁻¹ yr⁻¹) for one piece of the law, by composite Simpson with
 * n (even) steps; D_C is carried along the same grid, each step by Simpson on its own
 * midpoint, starting from dc_a (units of c/H0) at a. */
static double count_piece(double a, double b, int piece, double dc_a, int n, double *dc_b)
{
    double dh = C_KMS / H0, h = (b - a) / n, dc = dc_a, s = 0.0;
    for (int k = 0; k <= n; k++) {
        double z = a + k * h;
        if (k > 0) {
            double z0 = z - h;
            dc += h / 6.0 * (inv_e(z0) + 4.0 * inv_e(z0 + 0.5 * h) + inv_e(z));
        }
        double d = dc * dh;
        double f = spec_rate(z, piece) / (1 + z) * dh * d * d * inv_e(z);
        s += f * (k == 0 || k == n ? 1 : (k % 2 ? 4 : 2));
    }
    if (dc_b) *dc_b = dc;
    return s * h / 3.0;
}

/* ∫_ZMIN^z n(z) dz, the law's break at z = 1 taken as a Simpson node */
static double cum_test(double z, int steps_per_unit)
{
    double dc0 = dc_units(ZMIN, 2000), dc1;
    if (z <= 1.0) {
        int n = 2 * (int)ceil((z - ZMIN) * steps_per_unit / 2.0);
        return n ? count_piece(ZMIN, z, 0, dc0, n, NULL) : 0.0;
    }
    int n0 = 2 * (int)ceil((1.0 - ZMIN) * steps_per_unit / 2.0);
    double s = count_piece(ZMIN, 1.0, 0, dc0, n0, &dc1);
    int n1 = 2 * (int)ceil((z - 1.0) * steps_per_unit / 2.0);
    return s + count_piece(1.0, z, 1, dc1, n1, NULL);
}

static double dens_test(double z)
{
    double d = dc_units(z, 2000) * C_KMS / H0;
    return spec_rate(z, z < 1.0 ? 0 : 1) / (1 + z) * C_KMS / H0 * d * d * inv_e(z);
}

/* astropy 5.2.1 FlatLambdaCDM(H0=70, Om0=0.315, Tcmb0=0).differential_comoving_volume times
 * the SPEC law over (1+z), integrated by scipy.integrate.quad (epsrel 1e-13) over 0.06..1 and
 * 1..2.99: SNe per sr per year. */
#define ASTROPY_INTEGRAL 1750668.3793791502

static void setup(wf_cosmo *c, wf_snrate *r)
{
    ck_assert_int_eq(wf_cosmo_init(c, H0, OM), WF_OK);
    wf_snrate_default(r);
    ck_assert_int_eq(wf_snrate_validate(r), WF_OK);
}

/* ------------------------------------------------------------------ law and counts */

START_TEST(test_default_law)
{
    wf_cosmo c;
    wf_snrate r;
    setup(&c, &r);
    double v;
    ck_assert_int_eq(wf_snrate_eval(&r, 0.5, &v), WF_OK);
    ck_assert(fabs(v / (2.5e-5 * pow(1.5, 1.5)) - 1) < 1e-15);
    ck_assert_int_eq(wf_snrate_eval(&r, 1.0, &v), WF_OK); /* [1, 3] belongs to piece 2 */
    ck_assert(fabs(v / (9.7e-5 / sqrt(2.0)) - 1) < 1e-15);
    ck_assert_int_eq(wf_snrate_eval(&r, 3.0, &v), WF_OK); /* closed at the top */
    ck_assert(fabs(v / (9.7e-5 / 2.0) - 1) < 1e-15);
    ck_assert_int_eq(wf_snrate_eval(&r, 3.0001, &v), WF_OK);
    ck_assert(v == 0.0);
    ck_assert_int_eq(wf_snrate_eval(&r, -0.1, &v), WF_ERR_RANGE);
    double n;
    ck_assert_int_eq(wf_snrate_density(&r, &c, 2.0, &n), WF_OK);
    ck_assert(fabs(n / dens_test(2.0) - 1) < 1e-10);
}
END_TEST

START_TEST(test_expected_count)
{
    wf_cosmo c;
    wf_snrate r;
    setup(&c, &r);
    double lib, integral;
    ck_assert_int_eq(wf_snrate_integral(&r, &c, ZMIN, ZMAX, &integral), WF_OK);
    ck_assert_int_eq(wf_snrate_expected(&r, &c, ZMIN, ZMAX, 1.0, 730.5, &lib), WF_OK);
    double simpson = cum_test(ZMAX, 4000) * SR_PER_DEG2 * 2.0;
    double astropy = ASTROPY_INTEGRAL * SR_PER_DEG2 * 2.0;
    printf("snrate: SNe per deg^2 in 730.5 d, 0.06<z<2.99: %.10f (Simpson here %.10f, "
           "astropy+quad %.10f; SPEC ~1070)\n",
           lib, simpson, astropy);
    printf("snrate: relative differences: vs Simpson %.2e, vs astropy %.2e\n",
           fabs(lib / simpson - 1), fabs(lib / astropy - 1));
    ck_assert_msg(fabs(lib / simpson - 1) < 1e-6, "%.12g vs %.12g", lib, simpson);
    ck_assert_msg(fabs(lib / astropy - 1) < 1e-6, "%.12g vs %.12g", lib, astropy);
    ck_assert_msg(fabs(lib / 1070.0 - 1) < 0.01, "SPEC expects ~1070 per deg^2: %g", lib);
    /* linear in area and time */
    double n2;
    ck_assert_int_eq(wf_snrate_expected(&r, &c, ZMIN, ZMAX, 5.0, 365.25, &n2), WF_OK);
    ck_assert(fabs(n2 / (lib * 2.5) - 1) < 1e-14);
    /* the table's total is the same integral on the same intervals */
    wf_snrate_table t;
    ck_assert_int_eq(wf_snrate_table_build(&r, &c, ZMIN, ZMAX, &t), WF_OK);
    ck_assert(fabs(t.total / integral - 1) < 1e-13);
    wf_snrate_table_free(&t);
}
END_TEST

START_TEST(test_window_and_scaling)
{
    wf_cosmo c;
    wf_snrate r;
    setup(&c, &r);
    wf_snrate_survey s;
    wf_snrate_survey_default(&s);
    s.area_deg2 = 2.5;
    wf_snrate_gen g;
    ck_assert_int_eq(wf_snrate_gen_init(&g, &r, &c, &s, 1), WF_OK);
    /* pad before = 50 (1+2.99) = 199.5 d, after = 20 (1+2.99) = 79.8 d */
    ck_assert_double_eq_tol(g.peak_min, 61420.0 - 199.5, 1e-9);
    ck_assert_double_eq_tol(g.peak_max, 61420.0 + 730.5 + 79.8, 1e-9);
    ck_assert_double_eq_tol(g.days, 730.5 + 279.3, 1e-9);
    double want = cum_test(ZMAX, 4000) * SR_PER_DEG2 * 2.5 * (730.5 + 279.3) / 365.25;
    printf("snrate: padded window %.1f d; expected SNe in 2.5 deg^2: %.6f (Simpson here %.6f)\n",
           g.days, g.expected, want);
    ck_assert(fabs(g.expected / want - 1) < 1e-6);
    wf_snrate_gen_free(&g);
}
END_TEST

START_TEST(test_count_poisson)
{
    wf_cosmo c;
    wf_snrate r;
    setup(&c, &r);
    wf_snrate_survey s;
    wf_snrate_survey_default(&s);
    wf_snrate_gen g;
    ck_assert_int_eq(wf_snrate_gen_init(&g, &r, &c, &s, 2024), WF_OK);
    uint32_t n;
    ck_assert_int_eq(wf_snrate_gen_count(&g, &n), WF_OK);
    double mu = g.expected;
    printf("snrate: seed 2024: %u SNe drawn, %.3f expected (%.2f sigma)\n", n, mu,
           (n - mu) / sqrt(mu));
    ck_assert(fabs(n - mu) < 4 * sqrt(mu));
    uint32_t again;
    ck_assert_int_eq(wf_snrate_gen_count(&g, &again), WF_OK);
    ck_assert_uint_eq(n, again);

    /* over 300 seeds: mean within 4σ of μ (σ = sqrt(μ/300)), variance within 4σ of μ
     * (σ of a sample variance of a Poisson ≈ sqrt((μ + 2μ²)/(K-1))) */
    const int K = 300;
    double sum = 0, sum2 = 0;
    for (int k = 0; k < K; k++) {
        g.seed = 1000 + (uint64_t)k; /* same table, another seed */
        ck_assert_int_eq(wf_snrate_gen_count(&g, &n), WF_OK);
        sum += n;
        sum2 += (double)n * n;
    }
    wf_snrate_gen_free(&g);
    double mean = sum / K, var = (sum2 - K * mean * mean) / (K - 1);
    printf("snrate: %d seeds: mean count %.2f, variance %.1f (Poisson %.2f)\n", K, mean, var, mu);
    ck_assert(fabs(mean - mu) < 4 * sqrt(mu / K));
    ck_assert(fabs(var - mu) < 4 * sqrt((mu + 2 * mu * mu) / (K - 1)));

    /* an absurd area is refused rather than wrapped */
    s.area_deg2 = 41000.0;
    s.mjd_end = s.mjd_start + 1e7;
    ck_assert_int_eq(wf_snrate_gen_init(&g, &r, &c, &s, 1), WF_OK);
    ck_assert_int_eq(wf_snrate_gen_count(&g, &n), WF_ERR_RANGE);
    ck_assert(strstr(wf_error_message(), "32-bit") != NULL);
    wf_snrate_gen_free(&g);
}
END_TEST

/* ------------------------------------------------------------------ redshift draws */

START_TEST(test_quantile_accuracy)
{
    wf_cosmo c;
    wf_snrate r;
    setup(&c, &r);
    wf_snrate_table t;
    ck_assert_int_eq(wf_snrate_table_build(&r, &c, ZMIN, ZMAX, &t), WF_OK);
    double total = cum_test(ZMAX, 4000);
    double worst = 0;
    int count = 0;
    wf_rng rng;
    wf_sn_rng(99, 0, WF_SN_DRAW_Z, &rng);
    for (int k = 0; k < 140; k++) {
        double u;
        if (k < 12) {
            static const double fixed[12] = {1e-9, 1e-6, 1e-3, 0.01, 0.1, 0.25,
                                             0.5,  0.75, 0.9,  0.99, 0.999999, 1 - 1e-12};
            u = fixed[k];
        } else {
            u = wf_rng_uniform53(&rng);
        }
        double z;
        ck_assert_int_eq(wf_snrate_quantile(&t, u, &z), WF_OK);
        ck_assert(z >= ZMIN && z <= ZMAX);
        /* error in z = error in the CDF over the density there */
        double dz = fabs(cum_test(z, 4000) / total - u) / (dens_test(z) / total);
        worst = fmax(worst, dz);
        count++;
        ck_assert_msg(dz < 1e-8, "u=%.17g: z=%.15g off by %.3g", u, z, dz);
    }
    printf("snrate: quantile vs Simpson CDF here: %d points, max |dz| %.2e\n", count, worst);
    double z;
    ck_assert_int_eq(wf_snrate_quantile(&t, 0.0, &z), WF_OK);
    ck_assert(z == ZMIN);
    ck_assert_int_eq(wf_snrate_quantile(&t, 1.0, &z), WF_OK);
    ck_assert(z == ZMAX);
    ck_assert_int_eq(wf_snrate_quantile(&t, 1.5, &z), WF_ERR_RANGE);
    ck_assert_int_eq(wf_snrate_quantile(&t, NAN, &z), WF_ERR_RANGE);
    wf_snrate_table_free(&t);
}
END_TEST

START_TEST(test_redshift_histogram)
{
    wf_cosmo c;
    wf_snrate r;
    setup(&c, &r);
    wf_snrate_survey s;
    wf_snrate_survey_default(&s);
    wf_snrate_gen g;
    ck_assert_int_eq(wf_snrate_gen_init(&g, &r, &c, &s, 42), WF_OK);
    enum { NB = 50, NT = 20 };
    const uint32_t ndraw = 100000;
    static long hz[NB], ht[NT];
    memset(hz, 0, sizeof hz);
    memset(ht, 0, sizeof ht);
    double tsum = 0;
    for (uint32_t i = 0; i < ndraw; i++) {
        double z, t;
        ck_assert_int_eq(wf_snrate_gen_draw(&g, i, &z, &t), WF_OK);
        ck_assert(z >= ZMIN && z <= ZMAX);
        ck_assert(t >= g.peak_min && t <= g.peak_max);
        int b = (int)((z - ZMIN) / (ZMAX - ZMIN) * NB);
        hz[b < NB ? b : NB - 1]++;
        double x = (t - g.peak_min) / g.days;
        int bt = (int)(x * NT);
        ht[bt < NT ? bt : NT - 1]++;
        tsum += x;
    }
    /* expected bin contents from this file's own CDF */
    double total = cum_test(ZMAX, 4000), prev = 0, chi2 = 0;
    for (int b = 0; b < NB; b++) {
        double next = b == NB - 1 ? total : cum_test(ZMIN + (b + 1) * (ZMAX - ZMIN) / NB, 4000);
        double e = ndraw * (next - prev) / total;
        chi2 += (hz[b] - e) * (hz[b] - e) / e;
        prev = next;
    }
    double chi2t = 0, e = (double)ndraw / NT;
    for (int b = 0; b < NT; b++) chi2t += (ht[b] - e) * (ht[b] - e) / e;
    double tmean = tsum / ndraw;
    printf("snrate: 1e5 redshifts, 50 bins: chi2 = %.1f (49 dof, threshold 111.1 = "
           "P(>) 1e-6); peak dates, 20 bins: chi2 = %.1f (19 dof, threshold 63.7), mean phase "
           "%.5f (0.5 +- %.5f)\n",
           chi2, chi2t, tmean, sqrt(1.0 / 12 / ndraw));
    ck_assert(chi2 < 111.1359);
    ck_assert(chi2t < 63.677);
    ck_assert(fabs(tmean - 0.5) < 4 * sqrt(1.0 / 12 / ndraw));
    wf_snrate_gen_free(&g);
}
END_TEST

START_TEST(test_reproducible)
{
    wf_cosmo c;
    wf_snrate r;
    setup(&c, &r);
    wf_snrate_survey s;
    wf_snrate_survey_default(&s);
    wf_snrate_gen a, b, other;
    ck_assert_int_eq(wf_snrate_gen_init(&a, &r, &c, &s, 7), WF_OK);
    s.area_deg2 = 9.0; /* a different count must not move SN i */
    ck_assert_int_eq(wf_snrate_gen_init(&b, &r, &c, &s, 7), WF_OK);
    ck_assert_int_eq(wf_snrate_gen_init(&other, &r, &c, &s, 8), WF_OK);
    double za[100], ta[100];
    for (uint32_t i = 0; i < 100; i++)
        ck_assert_int_eq(wf_snrate_gen_draw(&a, i, &za[i], &ta[i]), WF_OK);
    int same_z = 0, same_t = 0;
    for (int i = 99; i >= 0; i--) { /* the other order */
        double z, t;
        ck_assert_int_eq(wf_snrate_gen_draw(&b, (uint32_t)i, &z, &t), WF_OK);
        ck_assert(z == za[i] && t == ta[i]);
        ck_assert_int_eq(wf_snrate_gen_draw(&other, (uint32_t)i, &z, &t), WF_OK);
        same_z += z == za[i];
        same_t += t == ta[i];
    }
    ck_assert_int_eq(same_z, 0);
    ck_assert_int_eq(same_t, 0);
    /* one stream alone gives the same value */
    double z_only;
    ck_assert_int_eq(wf_snrate_gen_draw(&a, 17, &z_only, NULL), WF_OK);
    ck_assert(z_only == za[17]);
    /* the documented key */
    wf_noise noise = {WF_NOISE_PHILOX, 7, 0, 0};
    wf_rng r1, r2;
    wf_rng_init(&r1, &noise, 5, WF_SN_DRAW_HOST, WF_PURPOSE_SN);
    wf_sn_rng(7, 5, WF_SN_DRAW_HOST, &r2);
    for (int k = 0; k < 8; k++) ck_assert_uint_eq(wf_rng_u32(&r1), wf_rng_u32(&r2));
    wf_snrate_gen_free(&a);
    wf_snrate_gen_free(&b);
    wf_snrate_gen_free(&other);
}
END_TEST

START_TEST(test_gap_law)
{
    /* rate only on [0, 0.5) and [1, 2): nothing is drawn in the gap, and the count is the
     * sum of the two pieces */
    wf_cosmo c;
    ck_assert_int_eq(wf_cosmo_init(&c, H0, OM), WF_OK);
    wf_snrate r;
    wf_snrate_clear(&r);
    ck_assert_int_eq(wf_snrate_add_line(&r, "POWERLAW2: 1e-5 1.0 1.0 2.0", "t", 1), WF_OK);
    ck_assert_int_eq(wf_snrate_add_line(&r, "POWERLAW2: 2e-5 0.0 0.0 0.5", "t", 2), WF_OK);
    double all, lo, hi;
    ck_assert_int_eq(wf_snrate_integral(&r, &c, 0.1, 1.8, &all), WF_OK);
    ck_assert_int_eq(wf_snrate_integral(&r, &c, 0.1, 0.5, &lo), WF_OK);
    ck_assert_int_eq(wf_snrate_integral(&r, &c, 1.0, 1.8, &hi), WF_OK);
    ck_assert(fabs(all / (lo + hi) - 1) < 1e-13);
    ck_assert_int_eq(wf_snrate_integral(&r, &c, 0.6, 0.9, &all), WF_OK);
    ck_assert(all == 0.0);
    wf_snrate_table t;
    ck_assert_int_eq(wf_snrate_table_build(&r, &c, 0.1, 1.8, &t), WF_OK);
    wf_rng rng;
    wf_sn_rng(3, 0, WF_SN_DRAW_Z, &rng);
    long below = 0;
    for (int k = 0; k < 20000; k++) {
        double z;
        ck_assert_int_eq(wf_snrate_quantile(&t, wf_rng_uniform53(&rng), &z), WF_OK);
        ck_assert_msg(!(z > 0.5 && z < 1.0), "z = %.17g in the gap", z);
        below += z <= 0.5;
    }
    /* fraction below the gap: binomial, 4σ */
    double p = lo / (lo + hi);
    ck_assert(fabs(below / 20000.0 - p) < 4 * sqrt(p * (1 - p) / 20000));
    wf_snrate_table_free(&t);
    ck_assert_int_eq(wf_snrate_table_build(&r, &c, 0.6, 0.9, &t), WF_ERR_RANGE);
    ck_assert(strstr(wf_error_message(), "zero over") != NULL);
}
END_TEST

/* ------------------------------------------------------------------ parser and errors */

static void expect_error(wf_status st, const char *w1, const char *w2)
{
    const char *msg = wf_error_message();
    ck_assert_msg(st != WF_OK, "expected an error containing '%s'", w1);
    ck_assert_msg(strstr(msg, w1) != NULL, "'%s' not in: %s", w1, msg);
    if (w2) ck_assert_msg(strstr(msg, w2) != NULL, "'%s' not in: %s", w2, msg);
}

START_TEST(test_parser)
{
    wf_snrate r, d;
    wf_snrate_default(&d);
    wf_snrate_clear(&r);
    ck_assert_int_eq(
        wf_snrate_add_line(&r, "DNDZ: POWERLAW2 2.5E-5 1.5 0.0 1.0  # R0(1+z)^Beta", "f", 1),
        WF_OK);
    ck_assert_int_eq(wf_snrate_add_line(&r, "  POWERLAW2: 9.7e-5 -0.5 1 3", "f", 2), WF_OK);
    ck_assert_int_eq(r.n, 2);
    for (int i = 0; i < 2; i++) {
        ck_assert(r.p[i].a == d.p[i].a && r.p[i].b == d.p[i].b);
        ck_assert(r.p[i].zlo == d.p[i].zlo && r.p[i].zhi == d.p[i].zhi);
    }
    ck_assert_int_eq(wf_snrate_validate(&r), WF_OK);

    wf_snrate_clear(&r);
    /* 'x' starts at column 17 */
    expect_error(wf_snrate_add_line(&r, "POWERLAW2: 1e-5 x 0 1", "rates.txt", 3),
                 "rates.txt:3: column 17: field B", "'x'");
    expect_error(wf_snrate_add_line(&r, "POWERLAW2: 1e-5 1.5 0", "rates.txt", 4), "rates.txt:4",
                 "field zmax is missing");
    expect_error(wf_snrate_add_line(&r, "POWERLAW2: 1e-5 1.5 0 1 7", "rates.txt", 5),
                 "column 25", "unexpected '7'");
    expect_error(wf_snrate_add_line(&r, "POWERLAW3: 1e-5 1.5 0 1", NULL, 6), "rate:6: column 1",
                 "unknown rate model 'POWERLAW3:'");
    expect_error(wf_snrate_add_line(&r, "POWERLAW2: -1e-5 1.5 0 1", "r", 7), "r:7: field A", NULL);
    expect_error(wf_snrate_add_line(&r, "POWERLAW2: 1e-5 1.5 2 1", "r", 8), "r:8: field zmax",
                 NULL);
    expect_error(wf_snrate_add_line(&r, "POWERLAW2: 1e-5 1.5 0 12", "r", 9), "field zmax", NULL);
    expect_error(wf_snrate_add_line(&r, "POWERLAW2: 1e-5 1.5 0 1e999", "r", 10), "field zmax",
                 "not a finite number");
    expect_error(wf_snrate_add_line(&r, "# only a comment", "r", 11), "r:11", "empty");
    ck_assert_int_eq(r.n, 0); /* nothing was added by a failing line */
    for (int i = 0; i < WF_SNRATE_MAX_PIECES; i++) {
        char line[80];
        snprintf(line, sizeof line, "POWERLAW2: 1e-5 1 %d %d", i, i + 1);
        ck_assert_int_eq(wf_snrate_add_line(&r, line, "r", 20 + i), WF_OK);
    }
    expect_error(wf_snrate_add_line(&r, "POWERLAW2: 1e-5 1 9 10", "r", 30), "r:30",
                 "more than 8");
    wf_snrate_default(&r);
    expect_error(wf_snrate_add_line(&r, "POWERLAW2: 1e-5 1 0.5 1.5", "r", 31), "r:31",
                 "overlaps the earlier piece 1");

    /* validation of a law built in code names the piece and the field */
    wf_snrate_default(&r);
    r.p[1].zhi = 12.0;
    expect_error(wf_snrate_validate(&r), "piece 2: field zmax", NULL);
    wf_snrate_default(&r);
    r.p[0].b = NAN;
    expect_error(wf_snrate_validate(&r), "piece 1: field B", NULL);
    wf_snrate_default(&r);
    r.p[1].zlo = 0.9;
    expect_error(wf_snrate_validate(&r), "piece 2", "overlaps piece 1");
    r.n = 0;
    expect_error(wf_snrate_validate(&r), "0 pieces", NULL);
}
END_TEST

START_TEST(test_survey_errors)
{
    wf_cosmo c;
    wf_snrate r;
    setup(&c, &r);
    wf_snrate_survey s;
    wf_snrate_gen g;
    wf_snrate_survey_default(&s);
    s.area_deg2 = 0;
    expect_error(wf_snrate_gen_init(&g, &r, &c, &s, 1), "area_deg2 = 0", NULL);
    wf_snrate_survey_default(&s);
    s.mjd_end = s.mjd_start;
    expect_error(wf_snrate_gen_init(&g, &r, &c, &s, 1), "mjd_end", NULL);
    wf_snrate_survey_default(&s);
    s.zmax = 11;
    expect_error(wf_snrate_gen_init(&g, &r, &c, &s, 1), "zmax = 11", NULL);
    wf_snrate_survey_default(&s);
    s.zmin = -0.1;
    expect_error(wf_snrate_gen_init(&g, &r, &c, &s, 1), "zmin = -0.1", NULL);
    wf_snrate_survey_default(&s);
    s.rest_before = NAN;
    expect_error(wf_snrate_gen_init(&g, &r, &c, &s, 1), "rest_before", NULL);
    double n;
    expect_error(wf_snrate_expected(&r, &c, ZMIN, ZMAX, 1.0, -1.0, &n), "duration", NULL);
    expect_error(wf_snrate_expected(&r, &c, 2.0, 1.0, 1.0, 1.0, &n), "zmin 2, zmax 1", NULL);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("snrate");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, test_default_law);
    tcase_add_test(tc, test_expected_count);
    tcase_add_test(tc, test_window_and_scaling);
    tcase_add_test(tc, test_count_poisson);
    tcase_add_test(tc, test_quantile_accuracy);
    tcase_add_test(tc, test_redshift_histogram);
    tcase_add_test(tc, test_reproducible);
    tcase_add_test(tc, test_gap_law);
    tcase_add_test(tc, test_parser);
    tcase_add_test(tc, test_survey_errors);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
