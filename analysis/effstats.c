/* Matching, binomial intervals and the completeness-curve fit of `wfisim efficiency`. */
#include "analysis/effstats.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sim/survey/wcs.h"

/* ---- matching ---- */

typedef struct pair {
    double d;
    long a, b;
} pair;

static _Thread_local const double *tl_key; /* qsort has no context argument */

static int cmp_by_key(const void *x, const void *y)
{
    double u = tl_key[*(const long *)x], v = tl_key[*(const long *)y];
    if (u != v) return u < v ? -1 : 1;
    long i = *(const long *)x, j = *(const long *)y;
    return (i > j) - (i < j);
}

static int cmp_pair(const void *x, const void *y)
{
    const pair *p = x, *q = y;
    if (p->d != q->d) return p->d < q->d ? -1 : 1;
    if (p->a != q->a) return p->a < q->a ? -1 : 1;
    return (p->b > q->b) - (p->b < q->b);
}

wf_status wf_eff_match(const double *ra_a, const double *dec_a, long na, const double *ra_b,
                       const double *dec_b, long nb, double radius_deg, long *a_to_b, long *b_to_a)
{
    if (!(radius_deg > 0) || !isfinite(radius_deg))
        return wf_error(WF_ERR_INPUT, "match radius %g deg: must be > 0", radius_deg);
    for (long i = 0; a_to_b && i < na; i++) a_to_b[i] = -1;
    for (long j = 0; b_to_a && j < nb; j++) b_to_a[j] = -1;
    if (na <= 0 || nb <= 0) return WF_OK;
    long *order = malloc((size_t)nb * sizeof *order);
    size_t cap = 1024, np = 0;
    pair *pairs = malloc(cap * sizeof *pairs);
    unsigned char *used_a = calloc((size_t)na, 1), *used_b = calloc((size_t)nb, 1);
    wf_status st = WF_OK;
    if (!order || !pairs || !used_a || !used_b) {
        st = wf_error(WF_ERR_NOMEM, "matching: out of memory for %ld x %ld objects", na, nb);
        goto done;
    }
    /* b sorted by declination: each a looks only at the strip |dDec| <= radius */
    for (long j = 0; j < nb; j++) order[j] = j;
    tl_key = dec_b;
    qsort(order, (size_t)nb, sizeof *order, cmp_by_key);
    for (long i = 0; i < na; i++) {
        if (!isfinite(ra_a[i]) || !isfinite(dec_a[i])) continue;
        long lo = 0, hi = nb; /* first b with dec >= dec_a - radius */
        while (lo < hi) {
            long mid = lo + (hi - lo) / 2;
            if (dec_b[order[mid]] < dec_a[i] - radius_deg) lo = mid + 1;
            else hi = mid;
        }
        for (long k = lo; k < nb && dec_b[order[k]] <= dec_a[i] + radius_deg; k++) {
            long j = order[k];
            if (!isfinite(ra_b[j])) continue;
            double d = wf_wcs_separation(ra_a[i], dec_a[i], ra_b[j], dec_b[j]);
            if (!(d <= radius_deg)) continue;
            if (np == cap) {
                pair *p = realloc(pairs, 2 * cap * sizeof *p);
                if (!p) {
                    st = wf_error(WF_ERR_NOMEM, "matching: out of memory for %zu pairs", 2 * cap);
                    goto done;
                }
                pairs = p, cap *= 2;
            }
            pairs[np++] = (pair){d, i, j};
        }
    }
    qsort(pairs, np, sizeof *pairs, cmp_pair);
    for (size_t k = 0; k < np; k++) {
        long i = pairs[k].a, j = pairs[k].b;
        if (used_a[i] || used_b[j]) continue;
        used_a[i] = used_b[j] = 1;
        if (a_to_b) a_to_b[i] = j;
        if (b_to_a) b_to_a[j] = i;
    }
done:
    free(order);
    free(pairs);
    free(used_a);
    free(used_b);
    return st;
}

/* ---- binomial interval ---- */

void wf_eff_wilson(long k, long n, double z, double *lo, double *hi)
{
    if (n <= 0) {
        *lo = 0.0, *hi = 1.0;
        return;
    }
    double nn = (double)n, p = (double)k / nn, z2 = z * z;
    double centre = (p + z2 / (2 * nn)) / (1 + z2 / nn);
    double half = z / (1 + z2 / nn) * sqrt(p * (1 - p) / nn + z2 / (4 * nn * nn));
    *lo = k == 0 ? 0.0 : centre - half;
    *hi = k == n ? 1.0 : centre + half;
}

/* ---- the curve and its fit ---- */

/* s = 1/(1 + e^t), t = (m - m50)/w + ln(2p - 1): eff = p s. */
static double curve(double m, double m50, double w, double p, double *s_out)
{
    double t = (m - m50) / w + log(2 * p - 1);
    double s = t > 0 ? exp(-t) / (1 + exp(-t)) : 1 / (1 + exp(t));
    if (s_out) *s_out = s;
    return p * s;
}

double wf_eff_curve(const wf_eff_fit *fit, double mag)
{
    return curve(mag, fit->m50, fit->width, fit->plateau, NULL);
}

typedef struct data {
    const double *mag;
    const unsigned char *found;
    long n;
    int free_plateau; /* 0: plateau fixed at 1 */
} data;

#define LW_MIN (-5.3) /* width 0.005 mag: a step, as sharp as magnitudes can tell */
#define LW_MAX 1.6    /* 5 mag */

/* The model's parameters from the search coordinates x = (m50, ln w, u), p = 1/2 + 1/2 logistic(u). */
static void params(const data *d, const double *x, double *m50, double *w, double *p)
{
    *m50 = x[0];
    *w = exp(fmin(fmax(x[1], LW_MIN), LW_MAX));
    *p = d->free_plateau ? 0.5 + 0.5 / (1 + exp(-x[2])) : 1.0;
}

static double nll(const data *d, const double *x)
{
    double m50, w, p, sum = 0;
    params(d, x, &m50, &w, &p);
    if (x[1] < LW_MIN - 1 || x[1] > LW_MAX + 1) return INFINITY; /* keep the simplex in range */
    for (long i = 0; i < d->n; i++) {
        double e = curve(d->mag[i], m50, w, p, NULL);
        e = fmin(fmax(e, 1e-300), 1 - 1e-16);
        sum -= d->found[i] ? log(e) : log1p(-e);
    }
    return sum;
}

/* Nelder-Mead on dim coordinates from x (standard coefficients 1, 2, 1/2, 1/2). */
static double simplex(const data *d, double *x, int dim, const double *step)
{
    double v[4][3], f[4];
    for (int i = 0; i <= dim; i++) {
        memcpy(v[i], x, sizeof v[i]);
        if (i) v[i][i - 1] += step[i - 1];
        f[i] = nll(d, v[i]);
    }
    for (int it = 0; it < 4000; it++) {
        /* order: best first */
        for (int i = 1; i <= dim; i++)
            for (int j = i; j > 0 && f[j] < f[j - 1]; j--) {
                double t = f[j];
                f[j] = f[j - 1], f[j - 1] = t;
                double tv[3];
                memcpy(tv, v[j], sizeof tv), memcpy(v[j], v[j - 1], sizeof tv), memcpy(v[j - 1], tv, sizeof tv);
            }
        if (fabs(f[dim] - f[0]) < 1e-10 * (1 + fabs(f[0]))) break;
        double c[3] = {0, 0, 0}, r[3], e[3], k[3];
        for (int i = 0; i < dim; i++)
            for (int j = 0; j < dim; j++) c[j] += v[i][j] / dim;
        for (int j = 0; j < dim; j++) r[j] = c[j] + (c[j] - v[dim][j]);
        double fr = nll(d, r);
        if (fr < f[0]) {
            for (int j = 0; j < dim; j++) e[j] = c[j] + 2 * (c[j] - v[dim][j]);
            double fe = nll(d, e);
            if (fe < fr) memcpy(v[dim], e, sizeof e), f[dim] = fe;
            else memcpy(v[dim], r, sizeof r), f[dim] = fr;
        } else if (fr < f[dim - 1]) {
            memcpy(v[dim], r, sizeof r), f[dim] = fr;
        } else {
            for (int j = 0; j < dim; j++) k[j] = c[j] + 0.5 * ((fr < f[dim] ? r[j] : v[dim][j]) - c[j]);
            double fk = nll(d, k);
            if (fk < fmin(fr, f[dim])) {
                memcpy(v[dim], k, sizeof k), f[dim] = fk;
            } else { /* shrink towards the best */
                for (int i = 1; i <= dim; i++) {
                    for (int j = 0; j < dim; j++) v[i][j] = v[0][j] + 0.5 * (v[i][j] - v[0][j]);
                    f[i] = nll(d, v[i]);
                }
            }
        }
    }
    int best = 0;
    for (int i = 1; i <= dim; i++)
        if (f[i] < f[best]) best = i;
    memcpy(x, v[best], sizeof v[best]);
    return f[best];
}

/* In-place inverse of a dim x dim symmetric matrix by Gauss-Jordan; 0 when singular. */
static int invert(double a[3][3], int dim)
{
    double inv[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (int c = 0; c < dim; c++) {
        int piv = c;
        for (int r = c + 1; r < dim; r++)
            if (fabs(a[r][c]) > fabs(a[piv][c])) piv = r;
        if (!(fabs(a[piv][c]) > 0) || !isfinite(a[piv][c])) return 0;
        for (int j = 0; j < 3; j++) {
            double t = a[c][j];
            a[c][j] = a[piv][j], a[piv][j] = t;
            t = inv[c][j], inv[c][j] = inv[piv][j], inv[piv][j] = t;
        }
        double q = a[c][c];
        for (int j = 0; j < 3; j++) a[c][j] /= q, inv[c][j] /= q;
        for (int r = 0; r < dim; r++) {
            if (r == c) continue;
            double g = a[r][c];
            for (int j = 0; j < 3; j++) a[r][j] -= g * a[c][j], inv[r][j] -= g * inv[c][j];
        }
    }
    memcpy(a, inv, sizeof inv);
    return 1;
}

/* Fisher information sum_i g g^T / (e (1 - e)), g = d eff / d(m50, w, p), inverted. */
static int covariance(const data *d, double m50, double w, double p, int dim, double cov[3][3])
{
    memset(cov, 0, 9 * sizeof(double));
    for (long i = 0; i < d->n; i++) {
        double s, m = d->mag[i];
        double e = curve(m, m50, w, p, &s);
        double v = e * (1 - e);
        if (!(v > 1e-300)) continue;
        double g[3] = {p * s * (1 - s) / w, p * s * (1 - s) * (m - m50) / (w * w), s - p * s * (1 - s) * 2 / (2 * p - 1)};
        for (int a = 0; a < dim; a++)
            for (int b = 0; b < dim; b++) cov[a][b] += g[a] * g[b] / v;
    }
    return invert(cov, dim);
}

static int cmp_double(const void *a, const void *b)
{
    double u = *(const double *)a, v = *(const double *)b;
    return (u > v) - (u < v);
}

wf_status wf_eff_fit_curve(const double *mag, const unsigned char *found, long n, wf_eff_fit *fit)
{
    memset(fit, 0, sizeof *fit);
    long k = 0;
    for (long i = 0; i < n; i++) k += found[i] != 0;
    fit->n = n, fit->nfound = k;
    if (k < 3 || n - k < 3) return WF_OK;
    double *sorted = malloc((size_t)n * sizeof *sorted);
    if (!sorted) return wf_error(WF_ERR_NOMEM, "efficiency fit: out of memory for %ld objects", n);
    memcpy(sorted, mag, (size_t)n * sizeof *sorted);
    qsort(sorted, (size_t)n, sizeof *sorted, cmp_double);
    double lo = sorted[0], hi = sorted[n - 1];
    /* Start: a step at the k-th brightest magnitude (the step that finds k objects). */
    double start = sorted[k - 1];
    free(sorted);
    data d = {mag, found, n, 0};
    double x1[3] = {start, log(0.3), 0}, step[3] = {0.3, 0.5, 1.0};
    double f1 = simplex(&d, x1, 2, step);
    f1 = simplex(&d, x1, 2, step); /* restart: Nelder-Mead can stall on a ridge */
    d.free_plateau = 1;
    double x3[3] = {x1[0], x1[1], 2.0}; /* plateau 0.94 */
    double f3 = simplex(&d, x3, 3, step);
    f3 = simplex(&d, x3, 3, step);
    double m50, w, p;
    int dim;
    if (f3 < f1 - 1e-6) {
        params(&d, x3, &m50, &w, &p);
        dim = 3;
        fit->loglike = -f3;
    } else {
        d.free_plateau = 0;
        params(&d, x1, &m50, &w, &p);
        dim = 2;
        fit->loglike = -f1;
    }
    if (dim == 3 && p > 0.9999) dim = 2; /* at the boundary the plateau's error means nothing */
    double cov[3][3];
    if (!covariance(&d, m50, w, p, dim, cov)) return WF_OK;
    if (!(m50 > lo - 1 && m50 < hi + 1) || !(cov[0][0] > 0) || !(cov[1][1] > 0)) return WF_OK;
    fit->ok = 1;
    fit->m50 = m50, fit->m50_err = sqrt(cov[0][0]);
    fit->width = w, fit->width_err = sqrt(cov[1][1]);
    fit->plateau = p, fit->plateau_err = dim == 3 && cov[2][2] > 0 ? sqrt(cov[2][2]) : 0.0;
    return WF_OK;
}
