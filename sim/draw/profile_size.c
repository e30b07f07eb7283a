/* How far a draw reaches. In real space: the radius holding all but flux_fraction of an
 * object's light (its stamp) or all but folding_threshold (its FFT box), from the profile's
 * enclosed light and the PSF's encircled energy. In Fourier space: the radius beyond which
 * the object's transform times the PSF's stays below kvalue_accuracy, or what the modes
 * beyond it add stays below cut_tolerance. Each object's bits hang on these sizes. */
#include <math.h>
#include <stddef.h>
#include <string.h>

#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"

/* ------------------------------------------------------------------------ stamp sizes */

/* Light of the round galaxy outside radius r (knots counted with the disk they follow),
 * as a fraction of its flux. */
static double galaxy_miss(const wf_draw_job *jb, const wf_sersic_table *t, double r)
{
    double miss = 0.0;
    if (jb->fb > 0.0) {
        double x = t->b * sqrt(sqrt(r / jb->re)), term = exp(-x), q = 0.0;
        for (int k = 0; k < 8; k++) { /* upper incomplete gamma Q(8, x) */
            q += term;
            term *= x / (k + 1);
        }
        miss += jb->fb * q;
    }
    if (jb->fd + jb->fk > 0.0) {
        double x = r / jb->r0;
        miss += (jb->fd + jb->fk) * exp(-x) * (1.0 + x);
    }
    return miss / jb->flux;
}

/* galaxy_miss at r = e^s, with the first two derivatives of its logarithm in s for
 * galaxy_root's steps. */
static double galaxy_miss_slope(const wf_draw_job *jb, const wf_sersic_table *t, double s,
                                double *slope, double *curv)
{
    double r = exp(s), m = 0.0, m1 = 0.0, m2 = 0.0;
    if (jb->fb > 0.0) {
        double x = t->b * sqrt(sqrt(r / jb->re)), term = exp(-x), q = 0.0;
        for (int k = 0; k < 8; k++) {
            q += term;
            term *= x / (k + 1);
        }
        /* dQ(8, x)/dx = -x^7 e^-x / 7!, dx/ds = x / 4; term = x^8 e^-x / 8! */
        m += jb->fb * q;
        m1 -= 2.0 * jb->fb * term;
        m2 -= 0.5 * jb->fb * term * (8.0 - x);
    }
    if (jb->fd + jb->fk > 0.0) {
        double w = jb->fd + jb->fk, x = r / jb->r0, e = exp(-x);
        m += w * e * (1.0 + x);
        m1 -= w * x * x * e;
        m2 -= w * x * x * e * (2.0 - x);
    }
    *slope = m1 / m;
    *curv = m2 / m - *slope * *slope;
    return m / jb->flux;
}

/* The last root the radius search found: wf_profile_object_radius asks for several eps in a
 * row, and a start extrapolated from the previous root takes 1.5 steps on average instead of
 * 2.8. */
typedef struct wf_radius_hint {
    double s, slope, curv, leps; /* ln r, d ln miss / ds and d2 ln miss / ds2 there, ln eps;
                                  * leps NAN: none yet */
} radius_hint;

/* A cold start: the larger of the two components' radii alone (the root lies beyond
 * both), each from its miss e^-x S(x) = eps / weight, S the partial exponential sum of 8
 * (bulge) or 2 (disk) terms, as x = l + ln S(x) iterated twice. */
static double root_guess(const wf_draw_job *jb, const wf_sersic_table *t, double eps)
{
    double s = -INFINITY;
    double wb = jb->fb / jb->flux, wd = (jb->fd + jb->fk) / jb->flux;
    if (wb > eps) {
        double l = log(wb / eps), x = l + 7.0;
        for (int it = 0; it < 2; it++) {
            double sum = 1.0, term = 1.0;
            for (int k = 1; k < 8; k++) sum += term *= x / k;
            x = l + log(sum);
        }
        s = log(jb->re) + 4.0 * log(x / t->b);
    }
    if (wd > eps) {
        double l = log(wd / eps), x = l + log1p(l + log1p(l));
        s = fmax(s, log(jb->r0 * x));
    }
    return s;
}

/* Root of ln galaxy_miss(e^s) = ln eps in (lo, hi) by Halley's steps (Newton's with the
 * curvature: the error goes as its cube, so a step of 1e-4 leaves ~1e-13), bracketed so
 * that a step leaving the bracket becomes a bisection (a bulge + disk's log miss need not
 * be concave, and far out it underflows). An estimate that is off only costs
 * wf_profile_galaxy_radius its plain bisection. 0: no root found. */
static int galaxy_root(const wf_draw_job *jb, const wf_sersic_table *t, double eps, double lo,
                       double hi, radius_hint *h)
{
    double leps = log(eps), s;
    if (isnan(h->leps)) s = root_guess(jb, t, eps);
    else {
        double step = (leps - h->leps) / h->slope, halley = 1.0 + 0.5 * step * h->curv / h->slope;
        s = h->s + (halley > 0.5 && halley < 2.0 ? step / halley : step);
    }
    if (!(s > lo && s < hi)) s = 0.5 * (lo + hi);
    for (int it = 0; it < 60; it++) {
        double slope, curv, f = galaxy_miss_slope(jb, t, s, &slope, &curv);
        double g = log(f) - leps, step = -g / slope; /* f underflowing: NaN, a bisection */
        if (g > 0.0) lo = s;
        else hi = s;
        double halley = 1.0 + 0.5 * step * curv / slope;
        if (halley > 0.5 && halley < 2.0) step /= halley;
        if (fabs(step) <= 1e-4) {
            *h = (radius_hint){s + step, slope, curv, leps};
            return 1;
        }
        s += step;
        if (!(s > lo && s < hi)) s = 0.5 * (lo + hi);
    }
    return 0;
}

/* Bound on galaxy_miss(exp(s))'s relative error against the exact miss at the real s,
 * with room to spare: the roundings of r and x move x by an ulp or two, which e^-x turns
 * into ~x ulps (x < 708 wherever e^-x is normal: < 1.6e-13), plus tens of ulps for the
 * series and sums (measured against long double: <= 1.4e-13). Misses near eps >= 1e-200
 * are far from underflow. */
#define MISS_RELERR 1e-12

/* Smallest radius (round profile, arcsec) leaving at most eps of the galaxy's light out:
 * the upper end of a 36-step bisection in log r (never below the root, within 4.7e-10 of
 * it). Each object's bits hang on that radius (stamp sides are ceil(r / p - 1e-9), r / p
 * lands anywhere, and the sizes feed the FFT boxes), so the bisection's steps are kept and
 * only its 37 evaluations are saved: with a root from galaxy_root, galaxy_miss is checked
 * above eps (1 + 3 MISS_RELERR) at a and below eps (1 - 3 MISS_RELERR) at b, a < root < b;
 * the exact miss being monotone, galaxy_miss is then above eps at every point left of a
 * and at most eps at every point right of b, which is what the bisection would find there.
 * Points in (a, b) are evaluated as before; (a, b) is a few 1e-11 wide, and the GalSim
 * scene evaluates one in about 18 searches. Anything else (no root, eps < 1e-200, a check
 * failing, (a, b) not inside (lo, hi)) takes the plain bisection: same bits, full cost. */
double wf_profile_galaxy_radius(const wf_draw_job *jb, const wf_sersic_table *t, double eps,
                                radius_hint *hint)
{
    double scale = fmax(jb->re, jb->r0);
    double lo = log(1e-9 * scale), hi = log(1e5 * scale);
    radius_hint cold = {0.0, 0.0, 0.0, NAN}, *h = hint ? hint : &cold;
    if (eps >= 1e-200 && galaxy_root(jb, t, eps, lo, hi, h)) {
        double d = 1e-11 + 8.0 * MISS_RELERR / -h->slope;
        double a = h->s - d, b = h->s + d;
        if (a > lo && b < hi && galaxy_miss(jb, t, exp(a)) > eps * (1.0 + 3.0 * MISS_RELERR) &&
            galaxy_miss(jb, t, exp(b)) < eps * (1.0 - 3.0 * MISS_RELERR)) {
            for (int it = 0; it < 36; it++) { /* lo < a: no early exit */
                double mid = 0.5 * (lo + hi);
                int out = mid >= b ? 1 : mid <= a ? 0 : galaxy_miss(jb, t, exp(mid)) <= eps;
                if (out) hi = mid;
                else lo = mid;
            }
            return exp(hi);
        }
        h->leps = NAN;
    }
    if (galaxy_miss(jb, t, exp(lo)) <= eps) return exp(lo);
    for (int it = 0; it < 36; it++) {
        double mid = 0.5 * (lo + hi);
        if (galaxy_miss(jb, t, exp(mid)) <= eps) hi = mid;
        else lo = mid;
    }
    return exp(hi);
}

/* Radius of the PSF image holding all but eps of its light; for core c > 0 (core index +
 * 1), that core's whole extent (its taper's end, plus half a pixel), so that none of the
 * core's light folds: the box then costs ~2x more samples for a star, and the star has the
 * unsplit draw's accuracy. */
static double psf_radius(const wf_profile_psf *psf, double eps, int core)
{
    if (core > 0) return psf->core[core - 1].radius + 0.5 * psf->pixel_scale;
    for (int i = psf->nee - 1; i >= 0; i--)
        if (1.0 - psf->ee[i] > eps) return (i + 2) * psf->ee_dr;
    return psf->ee_dr;
}

/* A radius holding all but eps of the object's light after the PSF: if the galaxy keeps
 * 1 - eps_g within R_g and the PSF 1 - eps_p within R_p, their convolution keeps at least
 * (1 - eps_g)(1 - eps_p) >= 1 - eps within R_g + R_p when eps_g + eps_p = eps; the split
 * giving the smallest radius is chosen. The sheared galaxy's radius is the round one's
 * times the shear's largest stretch. */
double wf_profile_object_radius(const wf_draw_job *jb, const wf_sersic_table *t,
                                const wf_profile_psf *psf, double eps, int core)
{
    double r;
    if (jb->fpoint > 0.0 && psf) r = psf_radius(psf, eps, core);
    else if (jb->fpoint > 0.0) r = 0.0;
    else if (!psf) r = jb->shape.smax * wf_profile_galaxy_radius(jb, t, eps, NULL);
    else {
        static const double split[] = {0.2, 0.35, 0.5, 0.65, 0.8};
        double rp[5];
        for (int i = 0; i < 5; i++) rp[i] = psf_radius(psf, eps * (1.0 - split[i]), core);
        radius_hint hint = {0.0, 0.0, 0.0, NAN};
        r = INFINITY;
        for (int i = 0; i < 5; i++) {
            /* The galaxy's radius never grows with its eps (the bisection's result is
             * monotone in eps, to the bit), so when the next split has the same PSF radius
             * (a step function of eps, constant with core) its sum is no larger and this
             * one cannot change the minimum: skips half the searches in the GalSim scene. */
            if (i < 4 && rp[i] == rp[i + 1]) continue;
            double rg = wf_profile_galaxy_radius(jb, t, eps * split[i], &hint);
            double c = jb->shape.smax * rg + rp[i];
            if (c < r) r = c;
        }
    }
    if (jb->nk > 0) {
        double rk = jb->knot_rmax + (psf ? psf_radius(psf, 0.5 * eps, core) : 0.0);
        if (rk > r) r = rk;
    }
    return r;
}

wf_status wf_profile_bounds(const wf_profile_work *w, const wf_draw_job *jb,
                            const wf_profile_psf *psf, double x, double y, wf_stamp *stamp,
                            double *fraction)
{
    wf_status st = wf_profile_check_position(x, y);
    if (st) return st;
    const wf_sersic_table *t = w->sersic;
    double p = w->acc.pixel_scale;
    double eps = 1.0 - w->acc.flux_fraction;
    double r = wf_profile_object_radius(jb, t, psf, eps, 0);
    int hmax = wf_profile_ladder_max(w) / 2 - 1;
    double h = ceil(r / p - 1e-9);
    double frac = w->acc.flux_fraction;
    if (!(h <= hmax)) {
        h = hmax;
        /* the light the clamped stamp holds: bisect on eps in log space */
        double lo = log(eps), hi = 0.0;
        for (int it = 0; it < 30; it++) {
            double mid = 0.5 * (lo + hi);
            if (wf_profile_object_radius(jb, t, psf, exp(mid), 0) <= hmax * p) hi = mid;
            else lo = mid;
        }
        frac = 1.0 - exp(hi);
    }
    if (h < 0) h = 0;
    int ic = (int)lround(x), jc = (int)lround(y);
    stamp->x0 = ic - (int)h;
    stamp->y0 = jc - (int)h;
    stamp->nx = stamp->ny = 2 * (int)h + 1;
    if (fraction) *fraction = frac;
    return WF_OK;
}

wf_status wf_profile_galaxy_bounds(wf_profile_work *work, const wf_galaxy *g,
                                   const wf_profile_psf *psf, double x, double y,
                                   wf_stamp *stamp, double *fraction)
{
    if (!g) return wf_error(WF_ERR_INPUT, "profile: no galaxy given");
    wf_galaxy lit = *g;
    if (lit.flux == 0.0) lit.flux = 1.0; /* a dark galaxy's stamp: the size it would have */
    wf_draw_job jb;
    wf_status st = wf_profile_galaxy_job(work, &lit, &jb); /* knot positions: scratch in the work */
    if (st) return st;
    return wf_profile_bounds(work, &jb, psf, x, y, stamp, fraction);
}

wf_status wf_profile_point_bounds(const wf_profile_work *work, const wf_profile_psf *psf,
                                  double x, double y, wf_stamp *stamp, double *fraction)
{
    wf_draw_job jb;
    memset(&jb, 0, sizeof jb);
    jb.flux = jb.fpoint = 1.0;
    wf_profile_shape(0.0, 0.0, 0.0, &jb.shape);
    return wf_profile_bounds(work, &jb, psf, x, y, stamp, fraction);
}

/* ------------------------------------------------------------------------ Fourier cut */

/* |object(k)| along its minor axis (the largest on the ring |k|: both parts fall with |k|);
 * `part` 0 is the smooth galaxy (or the point source), 1 the knots. */
static inline double minor_kvalue(const wf_draw_job *jb, const wf_sersic_table *t, double k,
                                  int part)
{
    if (part == 1) return jb->fk;
    if (jb->fpoint > 0.0) return jb->fpoint;
    double g = 0.0, q2 = (jb->shape.smin * k) * (jb->shape.smin * k);
    if (jb->fb > 0.0) g += jb->fb * wf_sersic4_eval(t, jb->re * jb->re * q2);
    if (jb->fd > 0.0) {
        double s = 1.0 / (1.0 + jb->r0 * jb->r0 * q2);
        g += jb->fd * s * sqrt(s);
    }
    return g;
}

/* With a PSF: |k| beyond which |object(k)| |PSF(k) pixel(k)| stays below kvalue_accuracy
 * of the flux, from the PSF's envelope ring by ring; `part` 0 is the smooth galaxy (or the
 * point source), 1 the knots. */
double wf_profile_psf_kcut_from(const wf_draw_job *jb, const wf_sersic_table *t,
                                const wf_profile_psf *psf, double kvalue, int part, int from)
{
    double dkt = 2.0 * M_PI / (psf->table_fft * psf->pixel_scale), tol = kvalue * jb->flux;
    for (int i = from < psf->kr ? from : psf->kr; i >= 0; i--) {
        if (minor_kvalue(jb, t, i * dkt, part) * psf->env[i] > tol) return (i + 1) * dkt;
    }
    return 0.0;
}

/* From the table's edge; wf_profile_psf_kcut_from may start at a ring known to lie beyond the
 * cut (one whose value exceeds a smaller kvalue: both factors fall with |k|). */
double wf_profile_psf_kcut(const wf_draw_job *jb, const wf_sersic_table *t,
                           const wf_profile_psf *psf, double kvalue, int part)
{
    return wf_profile_psf_kcut_from(jb, t, psf, kvalue, part, psf->kr);
}

/* With a PSF and cut_tolerance tol > 0: the fine-grid radius (in steps dk of a box of side
 * m) beyond which the modes left out of `part` move no pixel by more than tol. A pixel is
 * the sum of the box's fine samples over m^2, so what the samples beyond radius J add is at
 * most sum |object(k)| |PSF(k) pixel(k)| / m^2 over them; on the ring j <= |k| / dk < j + 1
 * that is at most g(j dk) env(j dk), g the object's transform along its minor axis (the
 * largest along the ring: both parts fall with |k|) and env the PSF's envelope, times the
 * ring's lattice points, fewer than pi ((j + 1 + 1/sqrt 2)^2 - (j - 1/sqrt 2)^2). Summed
 * from the band's edge `lim` inwards. Bicubic reads of the table (sides not dividing
 * table_fft) may exceed the envelope by a little; the count's margin covers it. Far below
 * the pointwise cut of kvalue_accuracy for faint objects: that bound counts every sample of
 * the band at the threshold. */
int wf_profile_tail_cut(const wf_draw_job *jb, const wf_sersic_table *t,
                        const wf_profile_psf *psf, double dk, int m, int lim, double tol, int part)
{
    const double dkt = 2.0 * M_PI / (psf->table_fft * psf->pixel_scale);
    const double norm = 1.0 / ((double)m * m);
    double tail = 0.0;
    for (int j = lim; j >= 0; j--) {
        double k = j * dk, g = minor_kvalue(jb, t, k, part);
        int i = (int)(k / dkt);
        double e = i > psf->kr ? 0.0 : psf->env[i];
        double a = j + 1 + M_SQRT1_2, b = j - M_SQRT1_2;
        if (b < 0.0) b = 0.0;
        tail += M_PI * (a * a - b * b) * g * e * norm;
        if (tail > tol) return j + 1;
    }
    return 0;
}

/* Smallest FFT side in the ladder holding `need` pixels; with a PSF, sides up to the PSF
 * table's must divide it (exact table reads). The largest side when none is big enough. */
int wf_profile_choose_size(const wf_profile_work *w, const wf_profile_psf *psf, double need)
{
    for (int i = 0; i < w->nsizes; i++) {
        int m = w->sizes[i];
        if (m < need) continue;
        if (psf && m <= psf->table_fft && wf_profile_psf_period(psf, m) < 0) continue;
        return i;
    }
    return w->nsizes - 1;
}
