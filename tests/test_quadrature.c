/* Gauss–Legendre rules and the composite integrator (sim/numeric/quadrature.c), checked against
 * values derived here:
 *  - the tables' shape: ascending nodes, bitwise symmetric, weights summing to 2;
 *  - the nodes and weights computed afresh by Newton's method in long double;
 *  - exactness on every monomial up to degree 2n − 1, and the textbook error at degree 2n
 *    where it is large enough to see (so the exactness check can fail);
 *  - closed-form integrals (∫_0^π sin = 2), reversed limits and the panel count.
 * Measured differences are printed so that the log records them. */
#include <math.h>
#include <stdio.h>

#include "sim/numeric/quadrature.h"
#include "tests/testutil.h"

static const wf_quad_rule *const rules[] = {&wf_quad_gl3, &wf_quad_gl14, &wf_quad_gl16};
#define NRULES (int)(sizeof rules / sizeof rules[0])

START_TEST(test_shape)
{
    for (int r = 0; r < NRULES; r++) {
        const wf_quad_rule *g = rules[r];
        double sum = 0.0;
        for (int i = 0; i < g->n; i++) {
            /* bitwise: callers walk the nodes in ± pairs or in either direction */
            ck_assert_msg(g->x[g->n - 1 - i] == -g->x[i] && g->w[g->n - 1 - i] == g->w[i],
                          "%d-point rule: node %d is not mirrored", g->n, i);
            if (i) ck_assert_msg(g->x[i] > g->x[i - 1], "%d-point rule: nodes not ascending", g->n);
            ck_assert(g->w[i] > 0.0 && fabs(g->x[i]) < 1.0);
            sum += g->w[i];
        }
        ck_assert_msg(fabs(sum - 2.0) < 8 * 2.2e-16, "%d-point weights sum to %.17g", g->n, sum);
    }
}
END_TEST

/* The rule afresh: Newton on P_n (three-term recurrence) in long double, from the
 * textbook guesses, iterated to a fixed point. */
static void rule_afresh(int n, int i, long double *x, long double *w)
{
    long double t = cosl(3.14159265358979323846264338327950288L * (i + 0.75L) / (n + 0.5L)), dp = 1;
    for (int it = 0; it < 200; it++) {
        long double p0 = 1, p1 = t;
        for (int k = 2; k <= n; k++) {
            long double p2 = ((2 * k - 1) * t * p1 - (k - 1) * p0) / k;
            p0 = p1;
            p1 = p2;
        }
        dp = n * (t * p1 - p0) / (t * t - 1);
        long double dx = p1 / dp;
        t -= dx;
        if (dx == 0) break;
    }
    *x = t;
    *w = 2 / ((1 - t * t) * dp * dp);
}

START_TEST(test_vs_afresh)
{
    for (int r = 0; r < NRULES; r++) {
        const wf_quad_rule *g = rules[r];
        double worst_x = 0.0, worst_w = 0.0;
        for (int i = 0; i < g->n; i++) {
            long double x, w;
            rule_afresh(g->n, i, &x, &w); /* descending */
            int j = g->n - 1 - i;
            worst_x = fmax(worst_x, (double)fabsl(g->x[j] - x));
            worst_w = fmax(worst_w, (double)fabsl((g->w[j] - w) / w));
        }
        printf("%2d-point rule vs long double Newton: nodes within %.1e, weights within %.1e relative\n",
               g->n, worst_x, worst_w);
        /* nodes to a few units in the last place; the weights as the tables were made:
         * 3.7e-15 relative for the 14-point rule (derived in double precision), 3.0e-15
         * for numpy's 16-point rule */
        ck_assert_msg(worst_x < 4.5e-16, "%d-point nodes off by %g", g->n, worst_x);
        ck_assert_msg(worst_w < 4e-15, "%d-point weights off by %g relative", g->n, worst_w);
    }
}
END_TEST

static double monomial(double x, void *ctx) { return pow(x, *(const int *)ctx); }

START_TEST(test_polynomials)
{
    for (int r = 0; r < NRULES; r++) {
        const wf_quad_rule *g = rules[r];
        double worst = 0.0;
        for (int d = 0; d <= 2 * g->n - 1; d++) {
            /* on [-1, 1] from the table, and on [0, 1] and [0, 3] through wf_quad_gl */
            double s = 0.0;
            for (int i = 0; i < g->n; i++) s += g->w[i] * pow(g->x[i], d);
            double want = d % 2 ? 0.0 : 2.0 / (d + 1);
            worst = fmax(worst, fabs(s - want) / (2.0 / (d + 1)));
            double one = wf_quad_gl(g, monomial, &d, 0.0, 1.0, 1);
            worst = fmax(worst, fabs(one - 1.0 / (d + 1)) * (d + 1));
            double three = wf_quad_gl(g, monomial, &d, 0.0, 3.0, 3); /* panels [k, k + 1] */
            want = pow(3.0, d + 1) / (d + 1);
            worst = fmax(worst, fabs(three - want) / want);
        }
        printf("%2d-point rule: monomials of degree <= %d exact to %.1e relative\n", g->n,
               2 * g->n - 1, worst);
        ck_assert_msg(worst < 1e-14, "%d-point rule: degree <= %d off by %g", g->n, 2 * g->n - 1,
                      worst);
        /* degree 2n: error (n!)^4 / ((2n + 1) ((2n)!)^2) on [0, 1], the rule's first miss */
        int d = 2 * g->n;
        double lf = 4.0 * lgamma(g->n + 1.0) - log(2.0 * g->n + 1.0) - 2.0 * lgamma(2.0 * g->n + 1.0);
        double err = 1.0 / (d + 1) - wf_quad_gl(g, monomial, &d, 0.0, 1.0, 1);
        if (lf > log(1e-12)) {
            printf("%2d-point rule: degree %d misses by %.6e (theory %.6e)\n", g->n, d, err, exp(lf));
            ck_assert_msg(fabs(err / exp(lf) - 1.0) < 1e-6, "%d-point rule: degree %d error %g, theory %g",
                          g->n, d, err, exp(lf));
        }
    }
}
END_TEST

static double sine(double x, void *ctx)
{
    (void)ctx;
    return sin(x);
}

START_TEST(test_closed_forms)
{
    /* panels enough for each rule's h^(2n) error to fall below 1e-16 */
    static const int panels[] = {200, 1, 1};
    for (int r = 0; r < NRULES; r++) {
        const wf_quad_rule *g = rules[r];
        double v = wf_quad_gl(g, sine, NULL, 0.0, M_PI, panels[r]);
        printf("%2d-point rule, %d panel(s): int_0^pi sin - 2 = %.1e\n", g->n, panels[r], v - 2.0);
        ck_assert_msg(fabs(v - 2.0) < 1e-14, "%d-point rule: int_0^pi sin = %.17g", g->n, v);
        /* reversed limits give the negative */
        double rev = wf_quad_gl(g, sine, NULL, M_PI, 0.0, panels[r]);
        ck_assert_msg(fabs(rev + v) < 1e-15, "%d-point rule: int_pi^0 sin = %.17g", g->n, rev);
    }
    /* fewer than one panel counts as one */
    ck_assert(wf_quad_gl(&wf_quad_gl16, sine, NULL, 0.0, 1.0, 0) ==
              wf_quad_gl(&wf_quad_gl16, sine, NULL, 0.0, 1.0, 1));
    ck_assert_double_eq_tol(wf_quad_gl(&wf_quad_gl16, sine, NULL, 0.0, 1.0, 0), 1.0 - cos(1.0), 1e-15);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("quadrature");
    TCase *tc = tcase_create("core");
    tcase_add_test(tc, test_shape);
    tcase_add_test(tc, test_vs_afresh);
    tcase_add_test(tc, test_polynomials);
    tcase_add_test(tc, test_closed_forms);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
