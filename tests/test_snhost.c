/* Supernova hosts (sim/sn/snhost):
 *  - weights against the closed form sSNR × M*, with the sSFR clamp at both ends;
 *  - host choice: frequencies against the weight ratio (4σ), the redshift window (fixed and
 *    polynomial), hostless SNe, candidate counts against a brute-force scan of a
 *    million-galaxy catalog (with timings printed);
 *  - Sérsic helpers: P(a, x) against closed forms (integer a, a = 1/2 through erf), b_n
 *    against published values, the inverse against the closed form;
 *  - positions: Kolmogorov–Smirnov tests of the radii of round disks and bulges against the
 *    enclosed-flux law truncated at 0.99, the 0.99 radius never exceeded, an elongated
 *    rotated host whose placements are round once the shear and rotation are undone, and
 *    whose measured distortion is the catalog's; F = 0 at the centre;
 *  - errors naming a missing logmass, logsfr or z column.
 * Expected values are computed here from closed forms, never taken from the code. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "hal/noise.h"
#include "sim/survey/catalog.h"
#include "sim/draw/profile.h"
#include "sim/sn/snhost.h"
#include "tests/testutil.h"

#define ARCSEC_PER_RAD 206264.80624709636
#define DEG (M_PI / 180.0)

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ------------------------------------------------------------------ closed forms */

/* P(k, x) for integer k: e^{−x} Σ_{j>=k} x^j / j! below x = k (no cancellation for small
 * x), 1 − e^{−x} Σ_{j<k} x^j / j! above. */
static double p_int(int k, double x)
{
    if (x <= 0.0) return 0.0;
    double term = 1.0, sum = 1.0;
    if (x < k) {
        for (int j = 1; j <= k; j++) term *= x / j;
        sum = term;
        for (int j = k + 1; term > 1e-18 * sum; j++) {
            term *= x / j;
            sum += term;
        }
        return exp(-x) * sum;
    }
    for (int j = 1; j < k; j++) {
        term *= x / j;
        sum += term;
    }
    return 1.0 - exp(-x) * sum;
}

/* Enclosed fraction of a round Sérsic n = 1 or 4 profile at x = r / r_e, given b_n. */
static double enclosed(int n, double bn, double x) { return p_int(2 * n, bn * pow(x, 1.0 / n)); }

/* Solves P(2n, y) = f by bisection on the closed form. */
static double p_int_solve(int k, double f)
{
    double lo = 0.0, hi = 1.0;
    while (p_int(k, hi) < f) hi *= 2.0;
    for (int it = 0; it < 200; it++) {
        double mid = 0.5 * (lo + hi);
        if (p_int(k, mid) < f)
            lo = mid;
        else
            hi = mid;
    }
    return 0.5 * (lo + hi);
}

static double bn_closed(int n) { return p_int_solve(2 * n, 0.5); }

/* x = r / r_e enclosing f */
static double radius_closed(int n, double f) { return pow(p_int_solve(2 * n, f) / bn_closed(n), n); }

/* Standard gnomonic projection of (ra, dec) about (ra0, dec0): east, north in arcsec. */
static void project(double ra0, double dec0, double ra, double dec, double *east, double *north)
{
    double a0 = ra0 * DEG, d0 = dec0 * DEG, a = ra * DEG, d = dec * DEG;
    double cosc = sin(d0) * sin(d) + cos(d0) * cos(d) * cos(a - a0);
    *east = cos(d) * sin(a - a0) / cosc * ARCSEC_PER_RAD;
    *north = (cos(d0) * sin(d) - sin(d0) * cos(d) * cos(a - a0)) / cosc * ARCSEC_PER_RAD;
}

/* ------------------------------------------------------------------ catalogs */

typedef struct galrow {
    double ra, dec, z, logmass, logsfr;
    double hlr_disk, hlr_bulge, bulge_frac, e1, e2, pa;
} galrow;

static void make_catalog(wf_catalog *cat, const galrow *g, size_t n, int flags)
{
    const char *bands[] = {"H158"};
    ck_assert_int_eq(wf_catalog_init(cat, WF_CATALOG_GALAXY, 1, bands, flags, "test-hosts"), WF_OK);
    ck_assert_int_eq(wf_catalog_reserve(cat, n ? n : 1), WF_OK);
    for (size_t k = 0; k < n; k++) {
        size_t i;
        ck_assert_int_eq(wf_catalog_push(cat, &i), WF_OK);
        cat->id[i] = (int64_t)(k + 1);
        cat->ra[i] = g[k].ra;
        cat->dec[i] = g[k].dec;
        cat->mag[0][i] = 22.0f;
        cat->hlr_disk[i] = (float)g[k].hlr_disk;
        cat->hlr_bulge[i] = (float)g[k].hlr_bulge;
        cat->bulge_frac[i] = (float)g[k].bulge_frac;
        cat->knot_frac[i] = 0.0f;
        cat->e1[i] = (float)g[k].e1;
        cat->e2[i] = (float)g[k].e2;
        cat->pa[i] = (float)g[k].pa;
        if (cat->has_z) cat->z[i] = (float)g[k].z;
        if (cat->has_logmass) cat->logmass[i] = (float)g[k].logmass;
        if (cat->has_logsfr) cat->logsfr[i] = (float)g[k].logsfr;
    }
}

#define ALL_FLAGS (WF_CATALOG_HAS_Z | WF_CATALOG_HAS_LOGMASS | WF_CATALOG_HAS_LOGSFR)

static wf_rng sn_stream(uint32_t sn, uint64_t seed)
{
    wf_noise noise = {WF_NOISE_PHILOX, seed, 0, 0};
    wf_rng rng;
    wf_rng_init(&rng, &noise, sn, 0, WF_PURPOSE_SN);
    return rng;
}

/* ------------------------------------------------------------------ weights */

static double weight_closed(double logmass, double logsfr)
{
    double m = pow(10.0, logmass), ssfr = pow(10.0, logsfr) / m;
    if (ssfr < 1.01e-11) ssfr = 1.01e-11;
    if (ssfr > 1.04e-9) ssfr = 1.04e-9;
    return 1.12e-7 * pow(ssfr, 0.586) * m;
}

START_TEST(test_weights)
{
    /* (logmass, logsfr): inside the clamp, at both edges, below and above it */
    const double cases[][2] = {{10.0, 0.0},   {9.0, -0.5},  {11.5, 1.2},       {8.0, -1.9},
                               {10.0, -3.0},  {10.0, -8.0}, {10.0, 2.0},       {7.0, 3.0},
                               {10.0, log10(1.01e-11) + 10.0}, {10.0, log10(1.04e-9) + 10.0}};
    for (size_t k = 0; k < sizeof cases / sizeof *cases; k++) {
        double w, want = weight_closed(cases[k][0], cases[k][1]);
        ck_assert_int_eq(wf_snhost_weight(NULL, cases[k][0], cases[k][1], &w), WF_OK);
        ck_assert_msg(fabs(w / want - 1.0) < 1e-12, "case %zu: %.17g vs %.17g", k, w, want);
    }
    /* the clamp: far below and just at the lower edge give the same weight, likewise above */
    double lo_far, lo_edge, hi_far, hi_edge;
    ck_assert_int_eq(wf_snhost_weight(NULL, 10.0, -10.0, &lo_far), WF_OK);
    ck_assert_int_eq(wf_snhost_weight(NULL, 10.0, 10.0 + log10(1.01e-11), &lo_edge), WF_OK);
    ck_assert_int_eq(wf_snhost_weight(NULL, 10.0, 5.0, &hi_far), WF_OK);
    ck_assert_int_eq(wf_snhost_weight(NULL, 10.0, 10.0 + log10(1.04e-9), &hi_edge), WF_OK);
    ck_assert(fabs(lo_far / lo_edge - 1.0) < 1e-13);
    ck_assert(fabs(hi_far / hi_edge - 1.0) < 1e-13);
    /* the numbers: 1.12e-7 · 1.01e-11^0.586 · 1e10 and 1.12e-7 · 1.04e-9^0.586 · 1e10 */
    ck_assert(fabs(lo_edge / (1.12e-7 * pow(1.01e-11, 0.586) * 1e10) - 1.0) < 1e-12);
    ck_assert(fabs(hi_edge / (1.12e-7 * pow(1.04e-9, 0.586) * 1e10) - 1.0) < 1e-12);
    printf("weights: sSNR x M* at logM = 10: %.6g (sSFR <= 1.01e-11), %.6g (sSFR >= 1.04e-9)\n",
           lo_edge, hi_edge);
    double w;
    ck_assert_int_eq(wf_snhost_weight(NULL, NAN, 0.0, &w), WF_ERR_INPUT);
    wf_snhost_config cfg;
    wf_snhost_config_default(&cfg);
    cfg.ssfr_min = 2e-9; /* above the maximum */
    ck_assert_int_eq(wf_snhost_weight(&cfg, 10.0, 0.0, &w), WF_ERR_RANGE);
}
END_TEST

/* ------------------------------------------------------------------ choice */

START_TEST(test_choice_frequencies)
{
    /* two galaxies at z = 1: M = 1e10 with sSFR 1e-10 and M = 3e10 with sSFR 2e-11; a third
     * at z = 1.02 (outside 0.01) with a much larger weight; a fourth at z = 0.5 */
    galrow g[4] = {
        {70.0, -53.0, 1.0, 10.0, 0.0, 0.5, 0.2, 0.1, 0, 0, 0},
        {70.1, -53.0, 1.0, log10(3e10), log10(3e10 * 2e-11), 0.5, 0.2, 0.1, 0, 0, 0},
        {70.2, -53.0, 1.02, 11.5, 2.0, 0.5, 0.2, 0.1, 0, 0, 0},
        {70.3, -53.0, 0.5, 10.0, 0.0, 0.5, 0.2, 0.1, 0, 0, 0},
    };
    wf_catalog cat;
    make_catalog(&cat, g, 4, ALL_FLAGS);
    wf_snhost_index *idx;
    ck_assert_int_eq(wf_snhost_index_build(&cat, NULL, &idx), WF_OK);
    double w0 = weight_closed(cat.logmass[0], cat.logsfr[0]);
    double w1 = weight_closed(cat.logmass[1], cat.logsfr[1]);
    double p0 = w0 / (w0 + w1);
    const long N = 100000;
    long count[4] = {0, 0, 0, 0};
    wf_rng rng = sn_stream(0, 7);
    for (long k = 0; k < N; k++) {
        long row, ncand;
        /* SN redshifts within 0.005 of 1: both z = 1 hosts always in the window, z = 1.02 never */
        double zsn = 0.995 + 0.01 * wf_rng_uniform53(&rng);
        ck_assert_int_eq(wf_snhost_choose(idx, zsn, wf_rng_uniform53(&rng), &row, &ncand), WF_OK);
        ck_assert_int_eq(ncand, 2);
        ck_assert(row >= 0 && row < 4);
        count[row]++;
    }
    double sigma = sqrt(N * p0 * (1.0 - p0));
    double pull = (count[0] - N * p0) / sigma;
    printf("choice: %ld of %ld draws on host 0, expected %.1f (p = %.5f), pull %.2f sigma; "
           "host at dz = 0.02: %ld\n",
           count[0], N, N * p0, p0, pull, count[2]);
    ck_assert_msg(fabs(pull) < 4.0, "pull %.2f", pull);
    ck_assert_int_eq(count[2], 0);
    ck_assert_int_eq(count[3], 0);

    /* hostless: no galaxy within 0.01 of z = 2 */
    long row, ncand;
    ck_assert_int_eq(wf_snhost_choose(idx, 2.0, 0.5, &row, &ncand), WF_OK);
    ck_assert_int_eq(row, -1);
    ck_assert_int_eq(ncand, 0);
    /* window edges: z = 1.011 holds the z = 1.02 galaxy only (|dz| = 0.009) */
    ck_assert_int_eq(wf_snhost_choose(idx, 1.011, 0.3, &row, &ncand), WF_OK);
    ck_assert_int_eq(ncand, 1);
    ck_assert_int_eq(row, 2);
    /* u at both ends picks the first and the last candidate in z (then row) order */
    ck_assert_int_eq(wf_snhost_choose(idx, 1.0, 0.0, &row, &ncand), WF_OK);
    ck_assert_int_eq(row, 0);
    ck_assert_int_eq(wf_snhost_choose(idx, 1.0, 1.0, &row, &ncand), WF_OK);
    ck_assert_int_eq(row, 1);
    ck_assert_int_eq(wf_snhost_choose(idx, 1.0, 1.5, &row, &ncand), WF_ERR_RANGE);
    wf_snhost_index_free(idx);

    /* SNANA's HOSTLIB_DZTOL polynomial: dz(z) = 0.03 z reaches the z = 1.02 galaxy from
     * z = 1 (dz = 0.03) but not the z = 0.5 one */
    wf_snhost_config cfg;
    wf_snhost_config_default(&cfg);
    cfg.dztol[0] = 0.0;
    cfg.dztol[1] = 0.03;
    ck_assert_int_eq(wf_snhost_index_build(&cat, &cfg, &idx), WF_OK);
    ck_assert_int_eq(wf_snhost_choose(idx, 1.0, 0.5, &row, &ncand), WF_OK);
    ck_assert_int_eq(ncand, 3);
    ck_assert_int_eq(wf_snhost_choose(idx, 0.5, 0.5, &row, &ncand), WF_OK);
    ck_assert_int_eq(ncand, 1); /* dz(0.5) = 0.015 */
    ck_assert_int_eq(row, 3);
    wf_snhost_index_free(idx);
    /* quadratic term: dz(z) = 0.005 + 0.02 z² = 0.025 at z = 1 */
    cfg.dztol[0] = 0.005;
    cfg.dztol[1] = 0.0;
    cfg.dztol[2] = 0.02;
    ck_assert_int_eq(wf_snhost_index_build(&cat, &cfg, &idx), WF_OK);
    ck_assert_int_eq(wf_snhost_choose(idx, 1.0, 0.5, &row, &ncand), WF_OK);
    ck_assert_int_eq(ncand, 3);
    ck_assert_int_eq(wf_snhost_choose(idx, 0.99, 0.5, &row, &ncand), WF_OK);
    ck_assert_int_eq(ncand, 2); /* dz(0.99) = 0.0246: 1.02 is 0.03 away */
    wf_snhost_index_free(idx);
    wf_catalog_free(&cat);
}
END_TEST

START_TEST(test_index_large)
{
    /* a million galaxies, z uniform in (0, 3): the candidate counts equal a brute-force scan;
     * every chosen host is inside the window; timings printed (the deep field: 2.7 million
     * galaxies, ~4,500 SNe) */
    const size_t n = 1000000;
    galrow proto = {70.0, -53.0, 0, 0, 0, 0.5, 0.2, 0.1, 0, 0, 0};
    wf_catalog cat;
    make_catalog(&cat, &proto, 0, ALL_FLAGS);
    ck_assert_int_eq(wf_catalog_reserve(&cat, n), WF_OK);
    wf_rng rng = sn_stream(1, 11);
    for (size_t k = 0; k < n; k++) {
        size_t i;
        ck_assert_int_eq(wf_catalog_push(&cat, &i), WF_OK);
        cat.id[i] = (int64_t)k;
        cat.ra[i] = 70.0;
        cat.dec[i] = -53.0;
        cat.mag[0][i] = 24.0f;
        cat.hlr_disk[i] = 0.3f;
        cat.hlr_bulge[i] = 0.15f;
        cat.bulge_frac[i] = 0.2f;
        cat.knot_frac[i] = 0.0f;
        cat.e1[i] = cat.e2[i] = cat.pa[i] = 0.0f;
        cat.z[i] = (float)(3.0 * wf_rng_uniform53(&rng));
        cat.logmass[i] = (float)(8.0 + 3.0 * wf_rng_uniform53(&rng));
        cat.logsfr[i] = (float)(-2.0 + 3.0 * wf_rng_uniform53(&rng));
    }
    double t0 = now_s();
    wf_snhost_index *idx;
    ck_assert_int_eq(wf_snhost_index_build(&cat, NULL, &idx), WF_OK);
    double t1 = now_s();
    const int nsn = 4500;
    long nhostless = 0;
    for (int k = 0; k < nsn; k++) {
        long row, ncand;
        double zsn = 0.06 + 2.93 * wf_rng_uniform53(&rng);
        ck_assert_int_eq(wf_snhost_choose(idx, zsn, wf_rng_uniform53(&rng), &row, &ncand), WF_OK);
        if (row < 0) {
            nhostless++;
            continue;
        }
        ck_assert_msg(fabs((double)cat.z[row] - zsn) <= 0.01 + 1e-12, "row %ld at z %g for SN z %g",
                      row, (double)cat.z[row], zsn);
    }
    double t2 = now_s();
    for (int k = 0; k < 60; k++) {
        /* include redshifts at the ends, where the window is cut by z = 0 and z = 3 */
        double zsn = k == 0 ? 0.0 : k == 1 ? 3.005 : k == 2 ? 3.02 : 3.0 * wf_rng_uniform53(&rng);
        long row, ncand, brute = 0;
        ck_assert_int_eq(wf_snhost_choose(idx, zsn, 0.5, &row, &ncand), WF_OK);
        for (size_t i = 0; i < n; i++) brute += fabs((double)cat.z[i] - zsn) <= 0.01;
        /* a galaxy exactly on the window's edge may fall either way by rounding of z ± dz */
        ck_assert_msg(labs(ncand - brute) <= 1, "z %g: %ld candidates, brute force %ld", zsn, ncand,
                      brute);
        ck_assert(brute == 0 ? row == -1 : row >= 0);
    }
    printf("index: %zu galaxies built in %.3f s; %d choices in %.2f ms (%.2f us each), %ld "
           "hostless\n",
           n, t1 - t0, nsn, 1e3 * (t2 - t1), 1e6 * (t2 - t1) / nsn, nhostless);
    wf_snhost_index_free(idx);
    wf_catalog_free(&cat);
}
END_TEST

/* ------------------------------------------------------------------ Sérsic helpers */

START_TEST(test_gamma_p)
{
    double worst = 0.0;
    const double xs[] = {0.0, 1e-8, 1e-3, 0.1, 0.5, 1.0, 1.678, 2.5, 3.0, 5.0, 7.669, 8.0, 9.0,
                         12.0, 20.0, 35.0, 60.0};
    const int ks[] = {1, 2, 3, 8, 10};
    for (size_t i = 0; i < sizeof ks / sizeof *ks; i++)
        for (size_t j = 0; j < sizeof xs / sizeof *xs; j++) {
            double p;
            p = wf_gamma_p_int(ks[i], xs[j]);
            double d = fabs(p - p_int(ks[i], xs[j]));
            if (d > worst) worst = d;
            ck_assert_msg(d < 1e-13, "P(%d, %g) = %.17g, closed form %.17g", ks[i], xs[j], p,
                          p_int(ks[i], xs[j]));
        }
    printf("P(a, x): largest difference from the closed forms %.2g\n", worst);
    double x;
    ck_assert_int_eq(wf_snhost_sersic_radius(2.5, 0.5, &x), WF_ERR_RANGE); /* whole n only */
}
END_TEST

START_TEST(test_sersic_bn_and_inverse)
{
    double b1, b4;
    ck_assert_int_eq(wf_snhost_sersic_bn(1.0, &b1), WF_OK);
    ck_assert_int_eq(wf_snhost_sersic_bn(4.0, &b4), WF_OK);
    printf("b_1 = %.10f (published 1.678347), b_4 = %.10f (published 7.669249)\n", b1, b4);
    /* published to 6 decimals; and exactly the half-light point of the closed form */
    ck_assert(fabs(b1 - 1.678347) < 5e-7);
    ck_assert(fabs(b4 - 7.669249) < 5e-7);
    ck_assert(fabs(p_int(2, b1) - 0.5) < 1e-14);
    ck_assert(fabs(p_int(8, b4) - 0.5) < 1e-14);

    /* the inverse against the closed form, from 1e-12 to 1 − 1e-9 */
    const double fs[] = {1e-12, 1e-6, 1e-3, 0.01, 0.1, 0.25, 0.5, 0.75, 0.9, 0.99, 0.999,
                         1.0 - 1e-6, 1.0 - 1e-9};
    double worst_f = 0.0, worst_x = 0.0;
    for (int n = 1; n <= 4; n += 3) {
        double bn = bn_closed(n);
        for (size_t j = 0; j < sizeof fs / sizeof *fs; j++) {
            double x, f;
            ck_assert_int_eq(wf_snhost_sersic_radius(n, fs[j], &x), WF_OK);
            double back = enclosed(n, bn, x);
            double xr = radius_closed(n, fs[j]);
            worst_f = fmax(worst_f, fabs(back / fs[j] - 1.0));
            if (fs[j] <= 1.0 - 1e-6) worst_x = fmax(worst_x, fabs(x / xr - 1.0));
            ck_assert_msg(fabs(back / fs[j] - 1.0) < 1e-10, "n %d F %g: x %.17g encloses %.17g", n,
                          fs[j], x, back);
            /* near F = 1 the radius is ill-conditioned for any method: a rounding of 1e-16 in
             * F moves x by 1e-16 / (x dF/dx), 4e-9 of x at F = 1 - 1e-9; compare up to
             * F = 1 - 1e-6 (there, and at 0.99, the condition allows 1e-11) */
            if (fs[j] <= 1.0 - 1e-6)
                ck_assert_msg(fabs(x / xr - 1.0) < 1e-10, "n %d F %g: x %.17g, bisection %.17g", n,
                              fs[j], x, xr);
            ck_assert_int_eq(wf_snhost_sersic_enclosed(n, x, &f), WF_OK);
            ck_assert(fabs(f - fs[j]) < 1e-12);
        }
        double x;
        ck_assert_int_eq(wf_snhost_sersic_radius(n, 0.5, &x), WF_OK);
        ck_assert(fabs(x - 1.0) < 1e-12); /* half the light within r_e */
        ck_assert_int_eq(wf_snhost_sersic_radius(n, 0.0, &x), WF_OK);
        ck_assert(x == 0.0);
    }
    printf("Sersic inverse: |P(x(F)) / F - 1| <= %.2g, relative radius error <= %.2g\n", worst_f,
           worst_x);
    double x;
    ck_assert_int_eq(wf_snhost_sersic_radius(1.0, 1.0, &x), WF_ERR_RANGE);
    ck_assert_int_eq(wf_snhost_sersic_radius(1.0, -0.1, &x), WF_ERR_RANGE);
}
END_TEST

/* ------------------------------------------------------------------ positions */

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static void ks_round(int n_sersic)
{
    const double hlr = 0.7, ra0 = 71.0, dec0 = -53.0;
    galrow g = {ra0, dec0, 1.0, 10.0, 0.0, hlr, hlr, n_sersic == 4 ? 1.0 : 0.0, 0, 0, 0};
    wf_catalog cat;
    make_catalog(&cat, &g, 1, ALL_FLAGS);
    const int N = 100000;
    double *x = malloc(N * sizeof *x);
    ck_assert_ptr_nonnull(x);
    double bn = bn_closed(n_sersic), x99 = radius_closed(n_sersic, 0.99);
    double worst_rc = 0.0;
    for (int k = 0; k < N; k++) {
        wf_rng rng = sn_stream((uint32_t)k, (uint64_t)(2024 + n_sersic));
        wf_snhost_position pos;
        ck_assert_int_eq(wf_snhost_place(&cat, 0, &rng, NULL, &pos), WF_OK);
        ck_assert_int_eq(pos.component, n_sersic == 4 ? 1 : 0);
        double e, nn;
        project(ra0, dec0, pos.ra, pos.dec, &e, &nn);
        double r = hypot(e, nn);
        worst_rc = fmax(worst_rc, fabs(r - pos.r_circ));
        x[k] = r / hlr;
    }
    qsort(x, N, sizeof *x, cmp_double);
    double d = 0.0;
    for (int k = 0; k < N; k++) {
        double cdf = enclosed(n_sersic, bn, x[k]) / 0.99;
        d = fmax(d, fmax(cdf - (double)k / N, (double)(k + 1) / N - cdf));
    }
    /* Kolmogorov's asymptotic critical value at alpha = 0.001: sqrt(-ln(alpha / 2) / 2) / sqrt(N) */
    double crit = sqrt(-log(0.0005) / 2.0) / sqrt((double)N);
    printf("KS n = %d: D = %.5f, critical value (alpha = 0.001, N = %d) %.5f; largest radius %.4f "
           "r_e, 0.99 radius %.4f r_e; |projected radius - r_circ| <= %.2g arcsec\n",
           n_sersic, d, N, crit, x[N - 1], x99, worst_rc);
    ck_assert_msg(d < crit, "D = %g, critical %g", d, crit);
    ck_assert_msg(x[N - 1] <= x99 * (1.0 + 1e-9), "radius %.12g beyond the 0.99 radius %.12g",
                  x[N - 1], x99);
    ck_assert(worst_rc < 1e-8);
    free(x);
    wf_catalog_free(&cat);
}

START_TEST(test_positions_ks_disk) { ks_round(1); }
END_TEST

START_TEST(test_positions_ks_bulge) { ks_round(4); }
END_TEST

START_TEST(test_positions_elongated)
{
    /* |e| = 0.5, rotated by pa = 25 deg; 30% of the light in the bulge */
    const double ra0 = 70.5, dec0 = -52.5, e1 = 0.3, e2 = -0.4, pa = 25.0, bf = 0.3;
    galrow g = {ra0, dec0, 1.0, 10.0, 0.0, 1.0, 0.4, bf, e1, e2, pa};
    wf_catalog cat;
    make_catalog(&cat, &g, 1, ALL_FLAGS);
    /* the inverse of the renderer's transform, from e independently: g = e / (1 + sqrt(1 - e²)),
     * with e as the catalog holds it (single precision) */
    double ee = hypot(cat.e1[0], cat.e2[0]), f = 1.0 / (1.0 + sqrt(1.0 - ee * ee));
    double g1 = cat.e1[0] * f, g2 = cat.e2[0] * f, nrm = 1.0 / sqrt(1.0 - g1 * g1 - g2 * g2);
    double c = cos(pa * DEG), s = sin(pa * DEG);
    const int N = 100000;
    double sxx = 0, syy = 0, sxy = 0, qxx = 0, qyy = 0, qxy = 0; /* unsheared, and in u, v */
    double s1sq = 0, s2sq = 0, t1sq = 0, t2sq = 0, worst_r = 0.0;
    long nbulge = 0;
    for (int k = 0; k < N; k++) {
        wf_rng rng = sn_stream((uint32_t)k, 99);
        wf_snhost_position pos;
        ck_assert_int_eq(wf_snhost_place(&cat, 0, &rng, NULL, &pos), WF_OK);
        nbulge += pos.component;
        double east, north;
        project(ra0, dec0, pos.ra, pos.dec, &east, &north);
        double u = -east, v = north; /* the catalog's sky frame: +u west, +v north */
        double xr = c * u + s * v, yr = -s * u + c * v; /* rotate back by -pa */
        double x = nrm * ((1.0 - g1) * xr - g2 * yr), y = nrm * (-g2 * xr + (1.0 + g1) * yr);
        worst_r = fmax(worst_r, fabs(hypot(x, y) - pos.r_circ));
        /* normalise by the component's radius so that both components weigh alike */
        double re = pos.component ? 0.4 : 1.0;
        x /= re;
        y /= re;
        u /= re;
        v /= re;
        sxx += x * x;
        syy += y * y;
        sxy += x * y;
        s1sq += (x * x - y * y) * (x * x - y * y);
        s2sq += 4.0 * x * y * x * y;
        qxx += u * u;
        qyy += v * v;
        qxy += u * v;
        t1sq += (u * u - v * v) * (u * u - v * v);
        t2sq += 4.0 * u * v * u * v;
    }
    /* distortion of the unsheared points: zero within 4 sigma (sigma from the sample) */
    double tr = sxx + syy, d1 = (sxx - syy) / tr, d2 = 2.0 * sxy / tr;
    double sig1 = sqrt(s1sq / N - pow((sxx - syy) / N, 2)) * sqrt((double)N) / tr;
    double sig2 = sqrt(s2sq / N - pow(2.0 * sxy / N, 2)) * sqrt((double)N) / tr;
    /* distortion in u, v: the catalog's e turned by 2 pa */
    double tq = qxx + qyy, m1 = (qxx - qyy) / tq, m2 = 2.0 * qxy / tq;
    double w1 = e1 * cos(2 * pa * DEG) - e2 * sin(2 * pa * DEG);
    double w2 = e1 * sin(2 * pa * DEG) + e2 * cos(2 * pa * DEG);
    double sig3 = sqrt(t1sq / N - pow((qxx - qyy) / N, 2)) * sqrt((double)N) / tq;
    double sig4 = sqrt(t2sq / N - pow(2.0 * qxy / N, 2)) * sqrt((double)N) / tq;
    double pb = (nbulge - N * bf) / sqrt(N * bf * (1.0 - bf));
    printf("elongated host: unsheared distortion (%.4f +- %.4f, %.4f +- %.4f); on the sky (%.4f "
           "+- %.4f, %.4f +- %.4f) vs e rotated by pa (%.4f, %.4f); bulge fraction %.4f (pull "
           "%.2f); |unsheared radius - r_circ| <= %.2g arcsec\n",
           d1, sig1, d2, sig2, m1, sig3, m2, sig4, w1, w2, (double)nbulge / N, pb, worst_r);
    ck_assert_msg(fabs(d1) < 4 * sig1 && fabs(d2) < 4 * sig2, "not round: %g %g", d1, d2);
    ck_assert_msg(fabs(m1 - w1) < 4 * sig3 && fabs(m2 - w2) < 4 * sig4, "shape %g %g vs %g %g", m1,
                  m2, w1, w2);
    ck_assert(fabs(pb) < 4.0);
    ck_assert(worst_r < 1e-8);

    /* F = 0 is the centre, whatever the component and angle */
    wf_snhost_position pos;
    ck_assert_int_eq(wf_snhost_place_at(&cat, 0, 1, 0.0, 1.234, &pos), WF_OK);
    ck_assert(pos.offset == 0.0 && pos.r_circ == 0.0);
    ck_assert(fabs(pos.ra - ra0) < 1e-12 && fabs(pos.dec - dec0) < 1e-12);
    /* and fmax = 0 puts every SN there */
    wf_snhost_config cfg;
    wf_snhost_config_default(&cfg);
    cfg.fmax = 0.0;
    wf_rng rng = sn_stream(5, 5);
    ck_assert_int_eq(wf_snhost_place(&cat, 0, &rng, &cfg, &pos), WF_OK);
    ck_assert(pos.offset == 0.0);
    /* the same stream gives the same position */
    wf_snhost_position p1, p2;
    wf_rng r1 = sn_stream(17, 3), r2 = sn_stream(17, 3);
    ck_assert_int_eq(wf_snhost_place(&cat, 0, &r1, NULL, &p1), WF_OK);
    ck_assert_int_eq(wf_snhost_place(&cat, 0, &r2, NULL, &p2), WF_OK);
    ck_assert(p1.ra == p2.ra && p1.dec == p2.dec);
    ck_assert_int_eq(wf_snhost_place(&cat, 1, &r1, NULL, &p1), WF_ERR_RANGE);
    cfg.fmax = 1.0;
    ck_assert_int_eq(wf_snhost_place(&cat, 0, &r1, &cfg, &p1), WF_ERR_RANGE);
    wf_catalog_free(&cat);
}
END_TEST

/* ------------------------------------------------------------------ errors */

START_TEST(test_missing_columns)
{
    galrow g = {70.0, -53.0, 1.0, 10.0, 0.0, 0.5, 0.2, 0.1, 0, 0, 0};
    struct {
        int flags;
        const char *column;
    } cases[] = {
        {WF_CATALOG_HAS_Z | WF_CATALOG_HAS_LOGSFR, "'logmass'"},
        {WF_CATALOG_HAS_Z | WF_CATALOG_HAS_LOGMASS, "'logsfr'"},
        {WF_CATALOG_HAS_Z, "'logmass'"},
        {WF_CATALOG_HAS_LOGMASS | WF_CATALOG_HAS_LOGSFR, "'z'"},
    };
    for (size_t k = 0; k < sizeof cases / sizeof *cases; k++) {
        wf_catalog cat;
        make_catalog(&cat, &g, 1, cases[k].flags);
        wf_snhost_index *idx = (wf_snhost_index *)1;
        ck_assert_int_eq(wf_snhost_index_build(&cat, NULL, &idx), WF_ERR_INPUT);
        ck_assert_ptr_null(idx);
        const char *msg = wf_error_message();
        ck_assert_msg(strstr(msg, cases[k].column) && strstr(msg, "test-hosts"),
                      "message '%s' should name %s and the catalog", msg, cases[k].column);
        if (k == 0) printf("missing column: %s\n", msg);
        wf_catalog_free(&cat);
    }
    /* a non-finite value names the row */
    wf_catalog cat;
    make_catalog(&cat, &g, 1, ALL_FLAGS);
    cat.logsfr[0] = NAN;
    wf_snhost_index *idx;
    ck_assert_int_eq(wf_snhost_index_build(&cat, NULL, &idx), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "row 1"));
    wf_catalog_free(&cat);
}
END_TEST

/* HOSTA: the half-light ellipse's semi-major axis of the brighter component, checked two ways:
 * the closed form from e (g = e / (1 + sqrt(1 - e^2)), a = r_e sqrt((1 + g) / (1 - g))) and the
 * largest offset of the placements at the half-light fraction over every angle. */
START_TEST(test_semimajor)
{
    galrow g[2] = {{70.5, -52.5, 1.0, 10.0, 0.0, 0.8, 0.3, 0.2, 0.3, -0.4, 25.0},
                   {70.5, -52.5, 1.0, 10.0, 0.0, 0.8, 0.3, 0.7, 0.3, -0.4, 25.0}};
    wf_catalog cat;
    make_catalog(&cat, g, 2, ALL_FLAGS);
    for (int k = 0; k < 2; k++) {
        double a, ee = hypot(cat.e1[k], cat.e2[k]), gg = ee / (1.0 + sqrt(1.0 - ee * ee));
        double re = k ? cat.hlr_bulge[k] : cat.hlr_disk[k];
        ck_assert_int_eq(wf_snhost_semimajor(&cat, (size_t)k, &a), WF_OK);
        ck_assert_double_eq_tol(a, re * sqrt((1.0 + gg) / (1.0 - gg)), 1e-12);
        double far = 0.0;
        for (int j = 0; j < 7200; j++) {
            wf_snhost_position pos;
            ck_assert_int_eq(wf_snhost_place_at(&cat, (size_t)k, k, 0.5, j * (M_PI / 3600.0), &pos), WF_OK);
            far = fmax(far, pos.offset);
        }
        ck_assert_msg(fabs(far / a - 1.0) < 1e-6, "row %d: largest half-light offset %.9f, HOSTA %.9f", k, far, a);
    }
    double a;
    ck_assert_int_eq(wf_snhost_semimajor(&cat, 2, &a), WF_ERR_RANGE);
    wf_catalog_free(&cat);
}
END_TEST

static Suite *snhost_suite(void)
{
    Suite *s = suite_create("snhost");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, test_weights);
    tcase_add_test(tc, test_choice_frequencies);
    tcase_add_test(tc, test_index_large);
    tcase_add_test(tc, test_gamma_p);
    tcase_add_test(tc, test_sersic_bn_and_inverse);
    tcase_add_test(tc, test_positions_ks_disk);
    tcase_add_test(tc, test_positions_ks_bulge);
    tcase_add_test(tc, test_positions_elongated);
    tcase_add_test(tc, test_missing_columns);
    tcase_add_test(tc, test_semimajor);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(snhost_suite()); }
