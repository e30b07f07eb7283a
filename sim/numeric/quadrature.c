/* Gauss–Legendre rules and the composite integrator: see sim/numeric/quadrature.h.
 *
 * The digits are those each rule had when its module carried it, so that sharing the
 * tables changed no result: every literal (17 significant digits, or the shortest form that
 * reads back the same) is the double the module used. The nodes are within 1.1e-16 of the
 * true ones; the weights within 3.7e-15 relative (the 14-point ones, rounding in their
 * double-precision derivation) and 3.0e-15 (numpy's 16-point ones), far inside what the
 * callers need (1e-14 and looser). tests/test_quadrature.c checks every rule against a
 * long-double computation and against polynomials of degree up to 2n − 1. */
#include "sim/numeric/quadrature.h"

/* 3 points: ±sqrt(3/5) and 0, weights 5/9 and 8/9. */
static const double x3[3] = {-0.7745966692414834, 0.0, 0.7745966692414834};
static const double w3[3] = {0.5555555555555556, 0.8888888888888888, 0.5555555555555556};

/* 14 points: Newton's method on the Legendre three-term recurrence in double precision, from
 * the Chebyshev-like guesses cos(pi (i + 3/4) / (n + 1/2)). */
static const double x14[14] = {
    -0.98628380869681231, -0.92843488366357363, -0.82720131506976502, -0.68729290481168548,
    -0.5152486363581541,  -0.31911236892788974, -0.10805494870734365, 0.10805494870734365,
    0.31911236892788974,  0.5152486363581541,   0.68729290481168548,  0.82720131506976502,
    0.92843488366357363,  0.98628380869681231,
};
static const double w14[14] = {
    0.035119460331751992, 0.080158087159760374, 0.12151857068790312, 0.1572031671581936,
    0.18553839747793785,  0.20519846372129549,  0.21526385346315777, 0.21526385346315777,
    0.20519846372129549,  0.18553839747793785,  0.1572031671581936,  0.12151857068790312,
    0.080158087159760374, 0.035119460331751992,
};

/* 16 points: numpy.polynomial.legendre.leggauss(16). */
static const double x16[16] = {
    -0.98940093499164994, -0.9445750230732326,  -0.86563120238783176, -0.755404408355003,
    -0.61787624440264377, -0.45801677765722737, -0.28160355077925892, -0.095012509837637454,
    0.095012509837637454, 0.28160355077925892,  0.45801677765722737,  0.61787624440264377,
    0.755404408355003,    0.86563120238783176,  0.9445750230732326,   0.98940093499164994,
};
static const double w16[16] = {
    0.027152459411754037, 0.062253523938647706, 0.095158511682492591, 0.12462897125553403,
    0.14959598881657676,  0.16915651939500262,  0.18260341504492361,  0.18945061045506859,
    0.18945061045506859,  0.18260341504492361,  0.16915651939500262,  0.14959598881657676,
    0.12462897125553403,  0.095158511682492591, 0.062253523938647706, 0.027152459411754037,
};

const wf_quad_rule wf_quad_gl3 = {3, x3, w3};
const wf_quad_rule wf_quad_gl14 = {14, x14, w14};
const wf_quad_rule wf_quad_gl16 = {16, x16, w16};

double wf_quad_gl(const wf_quad_rule *rule, double (*f)(double x, void *ctx), void *ctx,
                  double a, double b, int panels)
{
    const int n = rule->n, h = n / 2; /* x[n - h + k], k < h: the positive nodes, inner first */
    const double *x = rule->x + (n - h), *w = rule->w + (n - h);
    if (panels < 1) panels = 1;
    double step = (b - a) / panels, sum = 0.0;
    for (int p = 0; p < panels; p++) {
        /* the last panel ends exactly at b, so no rounding drift reaches the end point */
        double lo = a + p * step, hi = p == panels - 1 ? b : a + (p + 1) * step;
        double mid = 0.5 * (lo + hi), half = 0.5 * (hi - lo);
        double s = n % 2 ? rule->w[h] * f(mid, ctx) : 0.0;
        for (int k = 0; k < h; k++)
            s += w[k] * (f(mid - half * x[k], ctx) + f(mid + half * x[k], ctx));
        sum += half * s;
    }
    return sum;
}
