/* sim/numeric/trig.h against long double references: cosl and sinl of the angle formed in long
 * double (64-bit mantissa), so that the reference's own rounding of 2 pi u or of x is ~2000x
 * below the double results' errors being measured. */
#include <check.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "sim/numeric/trig.h"
#include "tests/testutil.h"

#define PI_L 3.141592653589793238462643383279502884L

static double uniform(unsigned long long *state)
{
    *state = *state * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*state >> 11) * 0x1p-53;
}

/* Turns: within 4e-16 of the true values (~2 ulp of 1; the series' truncation is < 1e-19 and
 * the reduction is exact), for |u| up to 1e6, at the octant edges and ties, and for every
 * length up to two vectors (the clones' tails). */
START_TEST(test_turns_against_long_double)
{
    enum { N = 20000 };
    static double u[N], c[N], s[N];
    unsigned long long st = 12345;
    for (int i = 0; i < N; i++) {
        double scale = i < N / 2 ? 1.0 : 1e6;
        u[i] = (2.0 * uniform(&st) - 1.0) * scale;
    }
    const double edge[] = {0.0, -0.0, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0, -0.125, -0.5,
                           0x1.fffffffffffffp-1, 0x1p-60, -0x1p-60, 0.5 - 0x1p-54, 1e6 + 0.25};
    const int ne = (int)(sizeof edge / sizeof edge[0]);
    for (int i = 0; i < ne; i++) u[i] = edge[i];
    wf_trig_sincos_turns(u, N, c, s);
    double worst = 0.0;
    for (int i = 0; i < N; i++) {
        long double a = 2.0L * PI_L * ((long double)u[i] - roundl((long double)u[i]));
        worst = fmax(worst, fmax(fabs(c[i] - (double)cosl(a)), fabs(s[i] - (double)sinl(a))));
    }
    printf("trig: turns, worst |error| %.3g\n", worst);
    ck_assert_msg(worst < 4e-16, "turns: worst error %.3g", worst);
    /* exact values where the series gives them: the quarter turns */
    ck_assert(c[0] == 1.0 && s[0] == 0.0);
    ck_assert(c[3] == 0.0 && s[3] == 1.0);  /* 0.25 */
    ck_assert(c[5] == -1.0 && s[5] == 0.0); /* 0.5 */
    /* NaN and infinities give NaN */
    const double odd[3] = {NAN, INFINITY, -INFINITY};
    double oc[3], os[3];
    wf_trig_sincos_turns(odd, 3, oc, os);
    for (int i = 0; i < 3; i++) ck_assert(isnan(oc[i]) && isnan(os[i]));
    /* any length, any start: the same values as the long call */
    for (int n = 1; n <= 17; n++) {
        double cc[17], ss[17];
        wf_trig_sincos_turns(u + 100 + n, n, cc, ss);
        for (int i = 0; i < n; i++) ck_assert(cc[i] == c[100 + n + i] && ss[i] == s[100 + n + i]);
    }
}
END_TEST

/* Radians: within 4e-16 of the true values for |x| up to 1e5, where Cody and Waite's
 * reduction is exact to the last bits; past 2^20 pi/2, and for NaN and infinities, libm's
 * values, bit for bit. */
START_TEST(test_radians_against_long_double)
{
    enum { N = 20000 };
    static double x[N], c[N], s[N];
    unsigned long long st = 777;
    for (int i = 0; i < N; i++) {
        double scale = i < N / 4 ? 1.0 : i < N / 2 ? 100.0 : 1e5;
        x[i] = (2.0 * uniform(&st) - 1.0) * scale;
    }
    const double edge[] = {0.0, M_PI / 4, M_PI / 2, M_PI, -M_PI, 3 * M_PI / 4, 2 * M_PI, 1e-300, 0.7853981633974483};
    for (int i = 0; i < (int)(sizeof edge / sizeof edge[0]); i++) x[i] = edge[i];
    wf_trig_sincos(x, N, c, s);
    double worst = 0.0;
    for (int i = 0; i < N; i++)
        worst = fmax(worst, fmax(fabs(c[i] - (double)cosl((long double)x[i])),
                                 fabs(s[i] - (double)sinl((long double)x[i]))));
    printf("trig: radians, worst |error| %.3g\n", worst);
    ck_assert_msg(worst < 4e-16, "radians: worst error %.3g", worst);
    const double far[] = {2e6, -3e7, 1e300, INFINITY, -INFINITY, NAN, 1.0};
    double fc[7], fs[7];
    wf_trig_sincos(far, 7, fc, fs);
    for (int i = 0; i < 6; i++) {
        double lc = cos(far[i]), ls = sin(far[i]);
        ck_assert_msg((fc[i] == lc || (isnan(fc[i]) && isnan(lc))) && (fs[i] == ls || (isnan(fs[i]) && isnan(ls))),
                      "x = %g: %g %g against libm's %g %g", far[i], fc[i], fs[i], lc, ls);
    }
    ck_assert(fabs(fc[6] - cos(1.0)) < 4e-16 && fabs(fs[6] - sin(1.0)) < 4e-16);
}
END_TEST

/* The reduction's own edges: up to just below 2^20 pi/2, where k P1 and k P2 are still exact,
 * and at the doubles nearest k pi/2 for large k, where the reduced argument is ~1e-10 and the
 * small component must keep its relative accuracy (the cancellation Cody and Waite avoid).
 * Just past the limit, libm's values. */
START_TEST(test_radians_reduction_edges)
{
    enum { N = 4096 };
    static double x[N], c[N], s[N];
    unsigned long long st = 4242;
    const double lim = 0x1.921fb54442d18p+20;
    for (int i = 0; i < N / 2; i++) x[i] = lim * (1.0 - 1e-3 * uniform(&st)) * (i % 2 ? -1.0 : 1.0);
    for (int i = N / 2; i < N; i++) {
        double k = (double)((1u << 20) - 1u - (unsigned)(uniform(&st) * 1e6)); /* large k below 2^20 */
        x[i] = k * (M_PI / 2) * (i % 2 ? -1.0 : 1.0);
    }
    x[N - 1] = nextafter(lim, 0.0);
    wf_trig_sincos(x, N, c, s);
    double worst = 0.0, worst_rel = 0.0;
    for (int i = 0; i < N; i++) {
        long double lc = cosl((long double)x[i]), ls = sinl((long double)x[i]);
        worst = fmax(worst, fmax(fabs(c[i] - (double)lc), fabs(s[i] - (double)ls)));
        if (i >= N / 2 && i < N - 1) { /* the small one of the two, relative */
            long double small = fabsl(lc) < fabsl(ls) ? lc : ls;
            double got = fabsl(lc) < fabsl(ls) ? c[i] : s[i];
            ck_assert_msg(fabsl(small) < 1e-9L, "x = %.17g is not near k pi/2", x[i]);
            worst_rel = fmax(worst_rel, (double)fabsl(((long double)got - small) / small));
        }
    }
    printf("trig: radians near 2^20 pi/2, worst |error| %.3g; near k pi/2, worst relative %.3g\n", worst, worst_rel);
    ck_assert_msg(worst < 4e-16, "radians near the limit: worst error %.3g", worst);
    ck_assert_msg(worst_rel < 1e-15, "radians near k pi/2: worst relative error %.3g", worst_rel);
    const double past[2] = {lim, -nextafter(lim, INFINITY)};
    double pc[2], ps[2];
    wf_trig_sincos(past, 2, pc, ps);
    for (int i = 0; i < 2; i++) ck_assert(pc[i] == cos(past[i]) && ps[i] == sin(past[i]));
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("trig");
    TCase *tc = tcase_create("trig");
    tcase_add_test(tc, test_turns_against_long_double);
    tcase_add_test(tc, test_radians_against_long_double);
    tcase_add_test(tc, test_radians_reduction_edges);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
