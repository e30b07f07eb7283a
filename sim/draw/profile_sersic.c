/* Fourier transform of the de Vaucouleurs profile, tabulated once.
 *
 * F(q) = (1 / Gamma(8)) Int_0^inf e^-s s^7 J0(q (s / b)^4) ds   (r = Re (s / b)^4)
 * is the normalised Hankel transform; the substitution makes the integrand smooth at the
 * cusp r = 0, which a quadrature in r would not resolve.
 *
 * Two evaluations, joined at q = 4 where both agree to ~1e-13:
 *  - small q: Gauss-Legendre over pieces of length <= 1 in s up to the first zero of J0,
 *    then over half-periods of J0 whose partial sums alternate; Wynn's epsilon algorithm
 *    extrapolates their limit from 30 terms (the tail of the integral converges too slowly
 *    to be summed: at q = 1 the integrand oscillates ~800 times before e^-s s^7 is negligible).
 *  - large q: the Mellin-Barnes residue series. Expanding exp(-b x) with x = (r/Re)^(1/4) and
 *    transforming r^a term by term (Int r^(a+1) J0(kr) dr = 2^(a+1) Gamma(1 + a/2) /
 *    (Gamma(-a/2) k^(a+2))) gives a series in q^(-j/4 - 2) whose terms fall like
 *    Gamma(1 + j/8)^2 / j!, so it converges for every q; below q ~ 3 its large alternating
 *    terms cancel and cost digits, hence the quadrature there.
 * Compared with 1e-15-accurate brute-force quadrature (tests/test_profile.c), the table
 * interpolation is good to ~1e-7 of F(0) everywhere. */
#include <math.h>
#include <pthread.h>

#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"
#include "sim/numeric/quadrature.h"

#define SERSIC_N 4
#define WYNN_TERMS 30
#define S_MAX 60.0 /* e^-60 60^7 / 7! < 1e-17 */
#define SERIES_TERMS 600

double wf_gamma_p_int(int a, double x)
{
    if (!(x > 0.0)) return 0.0;
    if (x < a + 1.0) {
        /* e^-x sum_{k>=a} x^k / k!: no cancellation for small x */
        double term = exp(-x + a * log(x) - lgamma(a + 1.0)), sum = 0.0;
        for (int k = a + 1; k < a + 400 && term > 1e-18 * sum; k++) {
            sum += term;
            term *= x / k;
        }
        return sum + term;
    }
    double term = exp(-x), sum = 0.0;
    for (int k = 0; k < a; k++) {
        sum += term;
        term *= x / (k + 1);
    }
    return 1.0 - sum;
}

double wf_sersic_b(int n)
{
    /* P(2n, b) = 1/2; the median of Gamma(2n) lies near 2n - 1/3. */
    double b = 2.0 * n - 1.0 / 3.0;
    for (int it = 0; it < 60; it++) {
        double a = 2.0 * n;
        double dens = exp(-b + (a - 1.0) * log(b) - lgamma(a));
        double step = (wf_gamma_p_int(2 * n, b) - 0.5) / dens;
        b -= step;
        if (fabs(step) < 1e-15 * b) break;
    }
    return b;
}

/* ---------------------------------------------------------------- quadrature (small q) */

static double quad_piece(double a, double b, double q, double bn)
{
    const wf_quad_rule *gl = &wf_quad_gl14;
    double mid = 0.5 * (a + b), half = 0.5 * (b - a), sum = 0.0;
    /* top node first, the order this sum has always taken: the table keeps its bits */
    for (int i = gl->n - 1; i >= 0; i--) {
        double s = mid + half * gl->x[i];
        double u = s / bn;
        u *= u;
        sum += gl->w[i] * exp(-s + 7.0 * log(s)) * j0(q * u * u);
    }
    return sum * half;
}

static double quad_span(double a, double b, double q, double bn)
{
    double sum = 0.0;
    for (double x = a; x < b;) {
        double xn = fmin(x + 1.0, b);
        sum += quad_piece(x, xn, q, bn);
        x = xn;
    }
    return sum;
}

/* Limit of a slowly converging sequence; the classic epsilon table, last even column. */
static double wynn_epsilon(const double *s, int n)
{
    double prev[WYNN_TERMS + 1], cur[WYNN_TERMS + 1];
    for (int i = 0; i < n; i++) {
        prev[i] = 0.0;
        cur[i] = s[i];
    }
    double best = s[n - 1];
    int len = n;
    for (int k = 1; len > 1; k++) {
        double next[WYNN_TERMS + 1];
        int ok = 1;
        for (int i = 0; i + 1 < len; i++) {
            double d = cur[i + 1] - cur[i];
            if (d == 0.0) {
                ok = 0;
                break;
            }
            next[i] = prev[i + 1] + 1.0 / d;
        }
        if (!ok) break;
        /* eps_{k+1}^(i) = eps_{k-1}^(i+1) + 1 / (eps_k^(i+1) - eps_k^(i)) */
        for (int i = 0; i < len; i++) prev[i] = cur[i];
        for (int i = 0; i + 1 < len; i++) cur[i] = next[i];
        len--;
        if (k % 2 == 0 && isfinite(cur[len - 1])) best = cur[len - 1];
    }
    return best;
}

static double s_at_u(double u, double q, double bn) { return bn * pow(u / q, 1.0 / SERSIC_N); }

static double hankel_quadrature(double q, double bn)
{
    if (q <= 0.0) return 1.0;
    const double j01 = 2.404825557695773;
    double s1 = fmin(s_at_u(j01, q, bn), S_MAX);
    double total = quad_span(0.0, s1, q, bn);
    if (s1 >= S_MAX) return total / 5040.0;
    double partial[WYNN_TERMS];
    int m = 0;
    double u_prev = j01;
    for (int k = 2; m < WYNN_TERMS; k++) {
        /* McMahon: zeros of J0 near (k - 1/4) pi; exactness is not needed, alternation is */
        double z = (k - 0.25) * M_PI;
        z += 1.0 / (8.0 * z);
        double sa = s_at_u(u_prev, q, bn), sb = s_at_u(z, q, bn);
        total += quad_span(sa, fmin(sb, S_MAX), q, bn);
        partial[m++] = total;
        u_prev = z;
        if (sb >= S_MAX) return total / 5040.0;
    }
    return wynn_epsilon(partial, m) / 5040.0;
}

/* ------------------------------------------------------------------- series (large q) */

/* term j = series_c[j] * exp(series_lc[j] - (j/n + 2) ln q): sign and log-magnitude, since
 * the magnitudes span hundreds of decades. Written once under g_once, then read-only. */
static double series_c[SERIES_TERMS];
static double series_lc[SERIES_TERMS];

static void series_init(double bn)
{
    double n = SERSIC_N;
    double log_norm = log(n) + lgamma(2.0 * n) - 2.0 * n * log(bn); /* flux / 2 pi */
    for (int j = 0; j < SERIES_TERMS; j++) {
        double a = j / n, h = 0.5 * a;
        double s = sin(M_PI * h);
        if (j == 0 || fabs(h - round(h)) < 1e-12) {
            series_c[j] = 0.0; /* r^(even integer) is smooth: no large-k term */
            series_lc[j] = 0.0;
            continue;
        }
        /* (-b)^j / j! * 2^(a+1) Gamma(1+h) / Gamma(-h), 1/Gamma(-h) = -sin(pi h) Gamma(1+h)/pi */
        double sign = ((j & 1) ? -1.0 : 1.0) * (s > 0 ? -1.0 : 1.0);
        series_c[j] = sign;
        series_lc[j] = j * log(bn) - lgamma(j + 1.0) + (a + 1.0) * log(2.0) +
                       2.0 * lgamma(1.0 + h) + log(fabs(s) / M_PI) - log_norm;
    }
}

static double hankel_series(double q)
{
    double lq = log(q), sum = 0.0, peak = 0.0;
    for (int j = 1; j < SERIES_TERMS; j++) {
        if (series_c[j] == 0.0) continue;
        double t = series_c[j] * exp(series_lc[j] - (j / (double)SERSIC_N + 2.0) * lq);
        sum += t;
        if (fabs(t) > peak) peak = fabs(t);
        else if (fabs(t) < 1e-18 * fabs(sum)) break;
    }
    return sum;
}

/* ------------------------------------------------------------------------------ table */

static wf_sersic_table g_table;
static pthread_once_t g_once = PTHREAD_ONCE_INIT;

static double hankel_value(double q, double bn)
{
    return q < 4.0 ? hankel_quadrature(q, bn) : hankel_series(q);
}

static void table_build(void)
{
    wf_sersic_table *t = &g_table;
    t->b = wf_sersic_b(SERSIC_N);
    t->b1 = wf_sersic_b(1);
    t->dev_norm = pow(t->b, 8.0) / (8.0 * M_PI * 5040.0);
    /* <r^2> = Gamma(4n) / (Gamma(2n) b^(2n)) Re^2 */
    t->r2 = exp(lgamma(4.0 * SERSIC_N) - lgamma(2.0 * SERSIC_N) - 2.0 * SERSIC_N * log(t->b));
    series_init(t->b);
    for (int e = WF_SERSIC_EMIN; e < WF_SERSIC_EMAX; e++) {
        double *row = t->v + (size_t)(e - WF_SERSIC_EMIN) * WF_SERSIC_ROW;
        for (int i = -1; i <= WF_SERSIC_SUB + 1; i++) {
            double w = ldexp(1.0 + (double)i / WF_SERSIC_SUB, e);
            row[i + 1] = hankel_value(sqrt(w), t->b);
        }
    }
}

const wf_sersic_table *wf_sersic4_table(void)
{
    pthread_once(&g_once, table_build);
    return &g_table;
}

double wf_sersic4_hankel_direct(double q)
{
    const wf_sersic_table *t = wf_sersic4_table();
    return hankel_quadrature(q, t->b);
}

double wf_sersic4_hankel_series(double q)
{
    (void)wf_sersic4_table(); /* coefficients */
    return hankel_series(q);
}

double wf_sersic4_eval_slow(const wf_sersic_table *t, double w)
{
    if (!(w > 0.0)) return 1.0;
    if (w < ldexp(1.0, WF_SERSIC_EMIN)) return 1.0 - 0.25 * t->r2 * w;
    return hankel_series(sqrt(w));
}
