/* Drawing galaxies and point sources: with a PSF in Fourier space, without one in real
 * space (see sim/profile.h for the method and docs/OPTICS.md "Profiles" for the measured
 * errors and costs).
 *
 * The image of an object on the pixel grid is the pixel-convolved profile sampled at pixel
 * centres. Its transform is F(k) = G(k) P(k) Pix(k) e^{-i k.d}; sampling at pitch p folds
 * every k into the band |k| < pi / p, and an FFT box of M pixels samples the folded transform
 * at dk = 2 pi / (M p), periodising the image with period M p (light beyond the box wraps in:
 * the folding error). So: evaluate F on the fine grid k = (u, v) dk out to the band limit,
 * add each value into bin (u mod M, v mod M) (only the bins of the half plane FFTW's c2r
 * reads), and one inverse FFT gives the M x M pixel values. The box is centred on pixel
 * (ic, jc) nearest the object: the shift by M/2 pixels is the factor (-1)^(u+v).
 *
 * Knots are point sources: their transform is a sum of phases, separable in u and v, added
 * in blocks of WF_PROFILE_KNOT_BLOCK from per-knot phase lines. Without a PSF a knot is a
 * delta function whose pixel integral puts all its light in the pixel holding it. */
#include <fftw3.h>
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "sim/profile.h"
#include "sim/profile_int.h"

static pthread_mutex_t fftw_mutex = PTHREAD_MUTEX_INITIALIZER;
void wf_profile_fftw_lock(void) { pthread_mutex_lock(&fftw_mutex); }
void wf_profile_fftw_unlock(void) { pthread_mutex_unlock(&fftw_mutex); }

void wf_profile_accuracy_default(wf_profile_accuracy *acc)
{
    acc->pixel_scale = WF_PROFILE_PIXEL_SCALE;
    acc->flux_fraction = 0.995;
    acc->folding_threshold = 5e-3;
    acc->kvalue_accuracy = 1e-5;
    acc->min_fft = 16;
    acc->max_fft = 1024;
    acc->psf_table_fft = 192;
}

wf_status wf_profile_check_accuracy(const wf_profile_accuracy *acc)
{
    if (!acc) return wf_error(WF_ERR_INPUT, "profile: no accuracy settings");
    if (!(acc->pixel_scale > 0.0 && acc->pixel_scale < 10.0))
        return wf_error(WF_ERR_RANGE, "profile: pixel scale %g arcsec outside (0, 10)",
                        acc->pixel_scale);
    if (!(acc->flux_fraction > 0.0 && acc->flux_fraction < 1.0))
        return wf_error(WF_ERR_RANGE, "profile: flux_fraction %g outside (0, 1)",
                        acc->flux_fraction);
    if (!(acc->folding_threshold >= 1e-12 && acc->folding_threshold <= 0.5))
        return wf_error(WF_ERR_RANGE, "profile: folding_threshold %g outside [1e-12, 0.5]",
                        acc->folding_threshold);
    if (!(acc->kvalue_accuracy >= 1e-15 && acc->kvalue_accuracy <= 0.1))
        return wf_error(WF_ERR_RANGE, "profile: kvalue_accuracy %g outside [1e-15, 0.1]",
                        acc->kvalue_accuracy);
    if (acc->min_fft < 8 || acc->max_fft < acc->min_fft || acc->max_fft > 16384)
        return wf_error(WF_ERR_RANGE, "profile: FFT sides [%d, %d] not within [8, 16384]",
                        acc->min_fft, acc->max_fft);
    if (acc->psf_table_fft < 16 || acc->psf_table_fft > 4096 || acc->psf_table_fft % 2)
        return wf_error(WF_ERR_RANGE, "profile: psf_table_fft %d not an even number in "
                        "[16, 4096]", acc->psf_table_fft);
    return WF_OK;
}

/* ------------------------------------------------------------------------ work buffers */

static int fft_ladder(const wf_profile_accuracy *acc, int *sizes, int cap)
{
    int n = 0;
    for (int m = 8; m <= acc->max_fft && n < cap; m += 2) {
        int r = m;
        while (r % 2 == 0) r /= 2;
        if (r != 1 && r != 3) continue;
        if (m < acc->min_fft) continue;
        sizes[n++] = m;
    }
    return n;
}

typedef struct work_layout {
    int nsizes, sizes[48], max_m, cap_line;
} work_layout;

static void layout(const wf_profile_accuracy *acc, work_layout *l)
{
    l->nsizes = fft_ladder(acc, l->sizes, 48);
    l->max_m = l->nsizes ? l->sizes[l->nsizes - 1] : 0;
    /* |k| <= WF_PSF_BAND_NYQ pi / p is |u| <= WF_PSF_BAND_NYQ M / 2 steps */
    l->cap_line = 2 * ((int)ceil(0.5 * WF_PSF_BAND_NYQ * l->max_m) + 2) + 1;
}

wf_status wf_profile_work_need(const wf_profile_accuracy *acc, size_t *bytes)
{
    wf_status st = wf_profile_check_accuracy(acc);
    if (st) return st;
    work_layout l;
    layout(acc, &l);
    if (!l.nsizes)
        return wf_error(WF_ERR_RANGE, "profile: no FFT side of the form 2^a or 3 2^a in "
                        "[%d, %d]", acc->min_fft, acc->max_fft);
    size_t m = (size_t)l.max_m, d = sizeof(double);
    *bytes = wf_arena_cost(m * (m + 2) * d) + 2 * wf_arena_cost((size_t)l.cap_line * 2 * d) +
             2 * wf_arena_cost((size_t)WF_PROFILE_KNOT_BLOCK * l.cap_line * 2 * d) +
             2 * wf_arena_cost((size_t)l.cap_line * sizeof(int)) +
             2 * wf_arena_cost((size_t)l.cap_line * 4 * d) + wf_arena_cost((m / 2 + 8) * 2 * d) +
             2 * wf_arena_cost((size_t)WF_PROFILE_MAX_KNOTS * 2 * d);
    return WF_OK;
}

wf_status wf_profile_work_init(wf_profile_work *w, const wf_profile_accuracy *acc,
                               wf_arena *arena)
{
    memset(w, 0, sizeof *w);
    size_t need;
    wf_status st = wf_profile_work_need(acc, &need);
    if (st) return st;
    w->acc = *acc;
    work_layout l;
    layout(acc, &l);
    size_t m = (size_t)l.max_m, d = sizeof(double);
    if ((st = wf_arena_calloc(arena, m * (m + 2), d, "profile FFT", (void **)&w->fft)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line * 2, d, "profile phases",
                              (void **)&w->ex)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line * 2, d, "profile phases",
                              (void **)&w->ey)) ||
        (st = wf_arena_calloc(arena, (size_t)WF_PROFILE_KNOT_BLOCK * l.cap_line * 2, d,
                              "knot phases", (void **)&w->kx)) ||
        (st = wf_arena_calloc(arena, (size_t)WF_PROFILE_KNOT_BLOCK * l.cap_line * 2, d,
                              "knot phases", (void **)&w->ky)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line, sizeof(int), "PSF taps",
                              (void **)&w->ix)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line, sizeof(int), "PSF taps",
                              (void **)&w->iy)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line * 4, d, "PSF weights",
                              (void **)&w->wx)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line * 4, d, "PSF weights",
                              (void **)&w->wy)) ||
        (st = wf_arena_calloc(arena, (m / 2 + 8) * 2, d, "profile run", (void **)&w->run)) ||
        (st = wf_arena_calloc(arena, (size_t)WF_PROFILE_MAX_KNOTS * 2, d, "knot positions",
                              (void **)&w->knot_pos)) ||
        (st = wf_arena_calloc(arena, (size_t)WF_PROFILE_MAX_KNOTS * 2, d, "knot positions",
                              (void **)&w->knot_box)))
        return st;
    w->cap_line = l.cap_line;
    w->sersic = wf_sersic4_table();
    w->nsizes = l.nsizes;
    memcpy(w->sizes, l.sizes, sizeof w->sizes);
    wf_profile_fftw_lock();
    for (int i = 0; i < w->nsizes; i++) {
        int n = w->sizes[i];
        w->plans[i] = fftw_plan_dft_c2r_2d(n, n, (fftw_complex *)w->fft, w->fft, FFTW_ESTIMATE);
        if (!w->plans[i]) {
            wf_profile_fftw_unlock();
            wf_profile_work_free(w);
            return wf_error(WF_ERR_INTERNAL, "profile: FFTW could not plan a %d^2 FFT", n);
        }
    }
    wf_profile_fftw_unlock();
    return WF_OK;
}

void wf_profile_work_free(wf_profile_work *w)
{
    if (!w) return;
    wf_profile_fftw_lock();
    for (int i = 0; i < w->nsizes; i++)
        if (w->plans[i]) fftw_destroy_plan((fftw_plan)w->plans[i]);
    wf_profile_fftw_unlock();
    w->nsizes = 0;
}

/* ------------------------------------------------------------------------ the objects */

/* What a draw needs, in arcsec and absolute flux. A point source is a "galaxy" with only
 * point flux. */
typedef struct job {
    double flux;                 /* total */
    double fb, fd, fk, fpoint;   /* bulge, smooth disk, all knots, point */
    double re, r0;               /* de Vaucouleurs half-light radius, exponential scale */
    wf_shape shape;
    int nk;
    double fknot;                /* flux per knot */
    const double *knots;         /* nk (x, y) after shear and rotation */
    double knot_rmax;            /* farthest knot from the centre */
} job;

static wf_status check_position(double x, double y)
{
    if (!(fabs(x) < 1e8 && fabs(y) < 1e8))
        return wf_error(WF_ERR_RANGE, "profile: position (%g, %g) is not a finite pixel "
                        "position within 1e8", x, y);
    return WF_OK;
}

static wf_status galaxy_job(wf_profile_work *w, const wf_galaxy *g, job *jb)
{
    memset(jb, 0, sizeof *jb);
    if (!g) return wf_error(WF_ERR_INPUT, "profile: no galaxy given");
    unsigned id = g->id;
    if (!(g->flux >= 0.0 && g->flux < 1e30))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: flux %g not in [0, 1e30)", id,
                        g->flux);
    if (!(g->bulge_frac >= 0.0 && g->bulge_frac <= 1.0))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: bulge_frac %g outside [0, 1]", id,
                        g->bulge_frac);
    if (g->bulge_frac > 0.0 && !(g->hlr_bulge > 0.0 && g->hlr_bulge <= 3600.0))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: bulge half-light radius %g arcsec "
                        "outside (0, 3600]", id, g->hlr_bulge);
    if (g->bulge_frac < 1.0 && !(g->hlr_disk > 0.0 && g->hlr_disk <= 3600.0))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: disk half-light radius %g arcsec "
                        "outside (0, 3600]", id, g->hlr_disk);
    if (!(g->knot_frac >= 0.0 && g->knot_frac <= WF_PROFILE_MAX_KNOT_FRAC))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: knot_frac %g outside [0, %g]", id,
                        g->knot_frac, WF_PROFILE_MAX_KNOT_FRAC);
    if (g->n_knots < 0 || g->n_knots > WF_PROFILE_MAX_KNOTS)
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: %d knots outside [0, %d]", id,
                        g->n_knots, WF_PROFILE_MAX_KNOTS);
    wf_status st = wf_profile_shape(g->e1, g->e2, g->rotation, &jb->shape);
    if (st) return wf_error(st, "profile: galaxy %u: %s", id, wf_error_message());

    const wf_sersic_table *t = w->sersic;
    jb->flux = g->flux;
    jb->fb = g->flux * g->bulge_frac;
    double disk = g->flux - jb->fb;
    jb->re = g->bulge_frac > 0.0 ? g->hlr_bulge : 0.0;
    jb->r0 = g->bulge_frac < 1.0 ? g->hlr_disk / t->b1 : 0.0;
    if (g->n_knots > 0 && g->knot_frac > 0.0 && disk > 0.0) {
        if ((st = wf_profile_knots(g, w->knot_pos))) return st;
        jb->nk = g->n_knots;
        jb->fk = disk * g->knot_frac;
        jb->fknot = jb->fk / jb->nk;
        const double(*a)[2] = jb->shape.a;
        for (int j = 0; j < jb->nk; j++) {
            double x = w->knot_pos[2 * j], y = w->knot_pos[2 * j + 1];
            w->knot_pos[2 * j] = a[0][0] * x + a[0][1] * y;
            w->knot_pos[2 * j + 1] = a[1][0] * x + a[1][1] * y;
            double r = hypot(w->knot_pos[2 * j], w->knot_pos[2 * j + 1]);
            if (r > jb->knot_rmax) jb->knot_rmax = r;
        }
        jb->knots = w->knot_pos;
    }
    jb->fd = disk - jb->fk;
    return WF_OK;
}

/* ------------------------------------------------------------------------ stamp sizes */

/* Light of the round galaxy outside radius r (knots counted with the disk they follow),
 * as a fraction of its flux. */
static double galaxy_miss(const job *jb, const wf_sersic_table *t, double r)
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

/* Smallest radius (round profile, arcsec) leaving at most eps of the galaxy's light out. */
static double galaxy_radius(const job *jb, const wf_sersic_table *t, double eps)
{
    double scale = fmax(jb->re, jb->r0);
    double lo = log(1e-9 * scale), hi = log(1e5 * scale);
    if (galaxy_miss(jb, t, exp(lo)) <= eps) return exp(lo);
    for (int it = 0; it < 36; it++) {
        double mid = 0.5 * (lo + hi);
        if (galaxy_miss(jb, t, exp(mid)) <= eps) hi = mid;
        else lo = mid;
    }
    return exp(hi);
}

/* Radius of the PSF image holding all but eps of its light. */
static double psf_radius(const wf_profile_psf *psf, double eps)
{
    for (int i = psf->nee - 1; i >= 0; i--)
        if (1.0 - psf->ee[i] > eps) return (i + 2) * psf->ee_dr;
    return psf->ee_dr;
}

/* A radius holding all but eps of the object's light after the PSF: if the galaxy keeps
 * 1 - eps_g within R_g and the PSF 1 - eps_p within R_p, their convolution keeps at least
 * (1 - eps_g)(1 - eps_p) >= 1 - eps within R_g + R_p when eps_g + eps_p = eps; the split
 * giving the smallest radius is chosen. The sheared galaxy's radius is the round one's
 * times the shear's largest stretch. */
static double object_radius(const job *jb, const wf_sersic_table *t, const wf_profile_psf *psf,
                            double eps)
{
    double r;
    if (jb->fpoint > 0.0 && psf) r = psf_radius(psf, eps);
    else if (jb->fpoint > 0.0) r = 0.0;
    else if (!psf) r = jb->shape.smax * galaxy_radius(jb, t, eps);
    else {
        static const double split[] = {0.2, 0.35, 0.5, 0.65, 0.8};
        r = INFINITY;
        for (int i = 0; i < 5; i++) {
            double c = jb->shape.smax * galaxy_radius(jb, t, eps * split[i]) +
                       psf_radius(psf, eps * (1.0 - split[i]));
            if (c < r) r = c;
        }
    }
    if (jb->nk > 0) {
        double rk = jb->knot_rmax + (psf ? psf_radius(psf, 0.5 * eps) : 0.0);
        if (rk > r) r = rk;
    }
    return r;
}

static int ladder_max(const wf_profile_work *w) { return w->sizes[w->nsizes - 1]; }

static wf_status bounds_for(const wf_profile_work *w, const job *jb, const wf_profile_psf *psf,
                            double x, double y, wf_stamp *stamp, double *fraction)
{
    wf_status st = check_position(x, y);
    if (st) return st;
    const wf_sersic_table *t = w->sersic;
    double p = w->acc.pixel_scale;
    double eps = 1.0 - w->acc.flux_fraction;
    double r = object_radius(jb, t, psf, eps);
    int hmax = ladder_max(w) / 2 - 1;
    double h = ceil(r / p - 1e-9);
    double frac = w->acc.flux_fraction;
    if (!(h <= hmax)) {
        h = hmax;
        /* the light the clamped stamp holds: bisect on eps in log space */
        double lo = log(eps), hi = 0.0;
        for (int it = 0; it < 30; it++) {
            double mid = 0.5 * (lo + hi);
            if (object_radius(jb, t, psf, exp(mid)) <= hmax * p) hi = mid;
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
    job jb;
    wf_status st = galaxy_job(work, &lit, &jb); /* knot positions: scratch in the work */
    if (st) return st;
    return bounds_for(work, &jb, psf, x, y, stamp, fraction);
}

wf_status wf_profile_point_bounds(const wf_profile_work *work, const wf_profile_psf *psf,
                                  double x, double y, wf_stamp *stamp, double *fraction)
{
    job jb;
    memset(&jb, 0, sizeof jb);
    jb.flux = jb.fpoint = 1.0;
    wf_profile_shape(0.0, 0.0, 0.0, &jb.shape);
    return bounds_for(work, &jb, psf, x, y, stamp, fraction);
}

/* ------------------------------------------------------------------------ Fourier cut */

/* With a PSF: |k| beyond which |object(k)| |PSF(k) pixel(k)| stays below kvalue_accuracy
 * of the flux, from the PSF's envelope ring by ring; `part` 0 is the smooth galaxy (or the
 * point source), 1 the knots. */
static double psf_kcut(const job *jb, const wf_sersic_table *t, const wf_profile_psf *psf,
                       double kvalue, int part)
{
    double dkt = 2.0 * M_PI / (psf->table_fft * psf->pixel_scale), tol = kvalue * jb->flux;
    for (int i = psf->kr; i >= 0; i--) {
        double g, k = i * dkt, q2 = (jb->shape.smin * k) * (jb->shape.smin * k);
        if (part == 1) g = jb->fk;
        else if (jb->fpoint > 0.0) g = jb->fpoint;
        else {
            g = 0.0;
            if (jb->fb > 0.0) g += jb->fb * wf_sersic4_eval(t, jb->re * jb->re * q2);
            if (jb->fd > 0.0) {
                double s = 1.0 / (1.0 + jb->r0 * jb->r0 * q2);
                g += jb->fd * s * sqrt(s);
            }
        }
        if (g * psf->env[i] > tol) return (i + 1) * dkt;
    }
    return 0.0;
}

/* ------------------------------------------------------------------------ the draw */

enum { MODE_EXACT, MODE_INTERP };

typedef struct grid {
    int m, half, mode, st, u;
    double dk;
    int ic, jc;
    double dx, dy;       /* arcsec from the centre of pixel (ic, jc) to the object */
    int nk;              /* knots drawn in Fourier space: those inside the FFT box */
    const double *kpos;  /* their (x, y), arcsec from the object */
    size_t ks;           /* entries per knot phase line (2 u + 1, and 8 or more of padding) */
} grid;

/* e^{-i u theta} (-1)^u for u = -n .. n into re[(u + n) st], im[(u + n) st], re-anchored
 * every 32 steps so that the recurrence's rounding stays ~1e-15. */
static void phase_line_to(double theta, int n, double *re, double *im, size_t st)
{
    for (int u0 = -n; u0 <= n; u0 += 32) {
        double a = -u0 * theta, sg = (u0 & 1) ? -1.0 : 1.0;
        double cr = sg * cos(a), ci = sg * sin(a);
        double sr = -cos(theta), si = sin(theta); /* step e^{-i theta} times -1 */
        int u1 = u0 + 32 <= n ? u0 + 32 : n + 1;
        for (int u = u0; u < u1; u++) {
            re[(size_t)(u + n) * st] = cr;
            im[(size_t)(u + n) * st] = ci;
            double nr = cr * sr - ci * si;
            ci = cr * si + ci * sr;
            cr = nr;
        }
    }
}

/* The same, complex interleaved into out[2 (u + n)]. */
static void phase_line(double theta, int n, double *out)
{
    phase_line_to(theta, n, out, out + 1, 2);
}

/* Catmull-Rom taps for reading the PSF table at fractional index t (table steps). */
static void cubic_taps(double t, int kr, int *first, double *wgt)
{
    double f0 = floor(t), f = t - f0;
    *first = (int)f0 - 1 + kr;
    double f2 = f * f, f3 = f2 * f;
    wgt[0] = 0.5 * (-f3 + 2.0 * f2 - f);
    wgt[1] = 0.5 * (3.0 * f3 - 5.0 * f2 + 2.0);
    wgt[2] = 0.5 * (-3.0 * f3 + 4.0 * f2 + f);
    wgt[3] = 0.5 * (f3 - f2);
}

static int floor_div(int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

/* run[i] += sum_j c_j x_j[i] for i < n, complex, split into real and imaginary arrays; knot
 * j's phase line is x_j = kx + 2 j ks (real parts, then ks further the imaginary ones).
 * Four knots at a time and two points at a time, so that the sums stay in registers and
 * the pairs map onto vector instructions. */
#if defined(__GNUC__)
#define KNOT_LOAD(x, p) memcpy(&(x), (p), sizeof(x))
/* Four points at a time in two vectors of NL lanes (type V), all knots into them; returns
 * the first point not done. Lanes never mix, and without fused multiply-adds (ISO C mode
 * contracts nothing) each sum is rounded exactly as the scalar loop's. */
#define KNOT_BODY(V, NL)                                                                   \
    int i0 = 0;                                                                            \
    for (; i0 + 2 * (NL) <= n; i0 += 2 * (NL)) {                                           \
        V sr0, si0, sr1, si1;                                                              \
        KNOT_LOAD(sr0, rr + i0);                                                           \
        KNOT_LOAD(sr1, rr + i0 + (NL));                                                    \
        KNOT_LOAD(si0, ri + i0);                                                           \
        KNOT_LOAD(si1, ri + i0 + (NL));                                                    \
        const double *x = kx + i0;                                                         \
        for (int j = 0; j < nkb; j++, x += 2 * ks) {                                       \
            V xr0, xi0, xr1, xi1;                                                          \
            KNOT_LOAD(xr0, x);                                                             \
            KNOT_LOAD(xr1, x + (NL));                                                      \
            KNOT_LOAD(xi0, x + ks);                                                        \
            KNOT_LOAD(xi1, x + ks + (NL));                                                 \
            const double cr = ckr[j], ci = cki[j];                                         \
            sr0 += cr * xr0 - ci * xi0;                                                    \
            si0 += cr * xi0 + ci * xr0;                                                    \
            sr1 += cr * xr1 - ci * xi1;                                                    \
            si1 += cr * xi1 + ci * xr1;                                                    \
        }                                                                                  \
        memcpy(rr + i0, &sr0, sizeof sr0);                                                 \
        memcpy(rr + i0 + (NL), &sr1, sizeof sr1);                                          \
        memcpy(ri + i0, &si0, sizeof si0);                                                 \
        memcpy(ri + i0 + (NL), &si1, sizeof si1);                                          \
    }                                                                                      \
    return i0;

typedef double knot_v2 __attribute__((vector_size(16)));
static int knot_sum_v2(int n, int nkb, const double *ckr, const double *cki, const double *kx,
                       size_t ks, double *restrict rr, double *restrict ri)
{
    KNOT_BODY(knot_v2, 2)
}

#if defined(__x86_64__) || defined(__i386__)
#define KNOT_AVX 1
typedef double knot_v4 __attribute__((vector_size(32)));
__attribute__((target("avx2"))) static int
knot_sum_v4(int n, int nkb, const double *ckr, const double *cki, const double *kx, size_t ks,
            double *restrict rr, double *restrict ri)
{
    KNOT_BODY(knot_v4, 4)
}
static pthread_once_t knot_once = PTHREAD_ONCE_INIT;
static int knot_avx;
static void knot_probe(void) { knot_avx = __builtin_cpu_supports("avx2") ? 1 : 0; }
#endif
#endif

static void knot_sum(int n, int nkb, const double *ckr, const double *cki, const double *kx,
                     size_t ks, double *restrict rr, double *restrict ri)
{
    int i0 = 0;
#if defined(__GNUC__)
#if defined(KNOT_AVX)
    pthread_once(&knot_once, knot_probe);
    if (knot_avx) i0 = knot_sum_v4(n, nkb, ckr, cki, kx, ks, rr, ri);
#endif
    int i1 = knot_sum_v2(n - i0, nkb, ckr, cki, kx + i0, ks, rr + i0, ri + i0);
    i0 += i1;
#endif
    for (int i = i0; i < n; i++) {
        double sr = rr[i], si = ri[i];
        const double *x = kx + i;
        for (int j = 0; j < nkb; j++, x += 2 * ks) {
            sr += ckr[j] * x[0] - cki[j] * x[ks];
            si += ckr[j] * x[ks] + cki[j] * x[0];
        }
        rr[i] = sr;
        ri[i] = si;
    }
}

/* One pass over the fine grid: rows v, alias runs of u whose bins lie in the half plane.
 * The run buffer receives the object's transform (times phases) for u in [ua, ub]; it is
 * then multiplied by PSF x pixel and added into the bins. The pass adds knots knot0 ..
 * knot0 + nkb - 1, whose phase lines are in w->kx and w->ky (gd->ks entries per line, real
 * parts then imaginary); the smooth part or point source rides with knot0 = 0 (and is
 * alone when nkb = 0). */
static void fold_pass(wf_profile_work *w, const job *jb, const wf_profile_psf *psf,
                      const grid *gd, int us, int knot0, int nkb)
{
    const int m = gd->m, half = gd->half, u_all = gd->u;
    const double dk = gd->dk;
    const wf_sersic_table *t = w->sersic;
    const double *ex = w->ex, *ey = w->ey;
    double *runr = w->run, *runi = w->run + (half + 8);
    const size_t row_len = (size_t)m + 2; /* doubles per row of the in-place buffer */
    const size_t ks = gd->ks;
    const double re2 = jb->re * jb->re, r02 = jb->r0 * jb->r0;
    const double qa = jb->shape.qxx * dk * dk;
    const int side = psf ? 2 * psf->kr + 1 : 0;
    const int smooth = knot0 <= 0;
    const int point = jb->fpoint > 0.0, bulge = jb->fb > 0.0, disk = jb->fd > 0.0;
    double ckr[WF_PROFILE_MAX_KNOTS], cki[WF_PROFILE_MAX_KNOTS];

    for (int v = -u_all; v <= u_all; v++) {
        int umax = (int)floor(sqrt((double)u_all * u_all - (double)v * v));
        int us_max = abs(v) <= us ? (int)floor(sqrt((double)us * us - (double)v * v)) : -1;
        if (nkb == 0 && us_max < 0) continue;
        int by = ((v % m) + m) % m;
        double *crow = w->fft + (size_t)by * row_len;
        double ky = v * dk;
        double qb = 2.0 * jb->shape.qxy * dk * ky, qc = jb->shape.qyy * ky * ky;
        double eyr = ey[2 * (v + u_all)], eyi = ey[2 * (v + u_all) + 1];
        for (int j = 0; j < nkb; j++) { /* knot's y phase times its flux */
            const double *kyj = w->ky + (size_t)j * 2 * ks + (size_t)(v + u_all);
            ckr[j] = jb->fknot * kyj[0];
            cki[j] = jb->fknot * kyj[ks];
        }
        const float *er = NULL, *ei = NULL;
        const int *tix = NULL;
        const double *twx = NULL, *twy = NULL;
        int tiy = 0;
        if (gd->mode == MODE_EXACT) {
            size_t off = (size_t)(v * gd->st + psf->kr) * side + (size_t)psf->kr;
            er = psf->re + off;
            ei = psf->im + off;
        } else if (gd->mode == MODE_INTERP) {
            tix = w->ix + u_all;
            twx = w->wx + 4 * (size_t)u_all;
            tiy = w->iy[v + u_all];
            twy = w->wy + 4 * (size_t)(v + u_all);
        }
        /* the u range this row needs: all of the band with knots, else the smooth disk */
        int ulim = nkb > 0 ? umax : us_max;
        int a0 = floor_div(-ulim, m), a1 = floor_div(ulim, m);
        for (int a = a0; a <= a1; a++) {
            int ua = a * m > -ulim ? a * m : -ulim;
            int ub = a * m + half < ulim ? a * m + half : ulim;
            if (ua > ub) continue;
            int n = ub - ua + 1;
            /* the object's transform, times the centring and sub-pixel phases */
            int sa = ua, sb = ua - 1;
            if (smooth) {
                sa = ua > -us_max ? ua : -us_max;
                sb = ub < us_max ? ub : us_max;
            }
            if (nkb > 0 || sa > ua || sb < ub) {
                memset(runr, 0, (size_t)n * sizeof(double));
                memset(runi, 0, (size_t)n * sizeof(double));
            }
            if (sa <= sb) {
                double *rr = runr - ua, *ri = runi - ua;
                const double *exu = ex + 2 * (ptrdiff_t)u_all;
                if (point) {
                    const double g = jb->fpoint;
                    for (int u = sa; u <= sb; u++) {
                        double pr = exu[2 * u], pi = exu[2 * u + 1];
                        rr[u] = g * (pr * eyr - pi * eyi);
                        ri[u] = g * (pr * eyi + pi * eyr);
                    }
                } else {
                    for (int u = sa; u <= sb; u++) {
                        double q2 = (qa * u + qb) * u + qc;
                        double g = 0.0;
                        if (bulge) g += jb->fb * wf_sersic4_eval(t, re2 * q2);
                        if (disk) {
                            double s = 1.0 / (1.0 + r02 * q2);
                            g += jb->fd * s * sqrt(s);
                        }
                        double pr = exu[2 * u], pi = exu[2 * u + 1];
                        rr[u] = g * (pr * eyr - pi * eyi);
                        ri[u] = g * (pr * eyi + pi * eyr);
                    }
                }
            }
            if (nkb > 0) /* rounded up to whole vectors: the lines and the run have room */
                knot_sum((n + 7) & ~7, nkb, ckr, cki, w->kx + (size_t)(ua + u_all), ks, runr,
                         runi);
            /* times PSF x pixel, into the bins */
            double *bins = crow + 2 * (size_t)(ua - a * m);
            if (gd->mode == MODE_EXACT) {
                const size_t st = (size_t)gd->st;
                const float *erp = er + (ptrdiff_t)ua * gd->st, *eip = ei + (ptrdiff_t)ua * gd->st;
                for (int i = 0; i < n; i++) {
                    double fr = erp[i * st], fi = eip[i * st];
                    double rr = runr[i], ri = runi[i];
                    bins[2 * i] += rr * fr - ri * fi;
                    bins[2 * i + 1] += rr * fi + ri * fr;
                }
            } else {
                for (int i = 0; i < n; i++) {
                    int u = ua + i;
                    const double *wu = twx + 4 * (ptrdiff_t)u;
                    double fr = 0.0, fi = 0.0;
                    for (int b = 0; b < 4; b++) {
                        size_t row = (size_t)(tiy + b) * side + (size_t)tix[u];
                        double sr = 0.0, si = 0.0;
                        for (int c = 0; c < 4; c++) {
                            sr += wu[c] * psf->re[row + c];
                            si += wu[c] * psf->im[row + c];
                        }
                        fr += twy[b] * sr;
                        fi += twy[b] * si;
                    }
                    double rr = runr[i], ri = runi[i];
                    bins[2 * i] += rr * fr - ri * fi;
                    bins[2 * i + 1] += rr * fi + ri * fr;
                }
            }
        }
    }
}

/* Smallest FFT side in the ladder holding `need` pixels; with a PSF, sides up to the PSF
 * table's must divide it (exact table reads). The largest side when none is big enough. */
static int choose_size(const wf_profile_work *w, const wf_profile_psf *psf, double need)
{
    for (int i = 0; i < w->nsizes; i++) {
        int m = w->sizes[i];
        if (m < need) continue;
        if (psf && m <= psf->table_fft && psf->table_fft % m) continue;
        return i;
    }
    return w->nsizes - 1;
}

/* Surface brightness of the smooth galaxy (flux per arcsec^2) at (x, y) arcsec from it. */
static double smooth_density(const job *jb, const wf_sersic_table *t, double x, double y)
{
    const double(*ai)[2] = jb->shape.ainv;
    double r = hypot(ai[0][0] * x + ai[0][1] * y, ai[1][0] * x + ai[1][1] * y), d = 0.0;
    if (jb->fb > 0.0)
        d += jb->fb * t->dev_norm / (jb->re * jb->re) * exp(-t->b * sqrt(sqrt(r / jb->re)));
    if (jb->fd > 0.0) d += jb->fd / (2.0 * M_PI * jb->r0 * jb->r0) * exp(-r / jb->r0);
    return d;
}

#define DEWRAP_NODES 32
#define DEWRAP_MAX_IMAGES 64

/* When the light beyond the largest FFT box exceeds folding_threshold (a galaxy much
 * larger than the PSF: half-light radii of tens of arcsec), the box's periodic images wrap
 * into the stamp. Their light is smooth there (it comes from >= half a box away), so it is
 * computed from the analytic profile, PSF and pixel neglected (relative effect ~(PSF size /
 * galaxy size)^2), on a lattice of DEWRAP_NODES + 1 nodes per side of the FFT box,
 * interpolated bilinearly, and subtracted. The lattice belongs to the box, not to the
 * stamp asked for, so pieces of a stamp get the same pixels. */
static wf_status dewrap(const wf_profile_work *w, const job *jb, const grid *gd, double x,
                        double y, wf_stamp *stamp)
{
    const wf_sersic_table *t = w->sersic;
    const double p = w->acc.pixel_scale, period = gd->m * p;
    double rfar = jb->shape.smax * galaxy_radius(jb, t, 1e-7);
    int nimg = (int)ceil(rfar / period);
    if (nimg < 1) nimg = 1;
    if (nimg > DEWRAP_MAX_IMAGES)
        return wf_error(WF_ERR_RANGE, "profile: object of radius %.0f arcsec wraps %d times "
                        "around the largest FFT box (%.0f arcsec); raise max_fft", rfar, nimg,
                        period);
    const double h = (double)gd->m / DEWRAP_NODES; /* pixels between nodes */
    const long bx = (long)gd->ic - gd->half, by = (long)gd->jc - gd->half; /* node 0 */
    int a0 = (int)floor((stamp->x0 - bx) / h), a1 = (int)floor((stamp->x0 + stamp->nx - 1 - bx) / h) + 1;
    int b0 = (int)floor((stamp->y0 - by) / h), b1 = (int)floor((stamp->y0 + stamp->ny - 1 - by) / h) + 1;
    if (a0 < 0) a0 = 0;
    if (b0 < 0) b0 = 0;
    if (a1 > DEWRAP_NODES) a1 = DEWRAP_NODES;
    if (b1 > DEWRAP_NODES) b1 = DEWRAP_NODES;
    double node[(DEWRAP_NODES + 1) * (DEWRAP_NODES + 1)];
    for (int b = b0; b <= b1; b++)
        for (int a = a0; a <= a1; a++) {
            double px = (bx + a * h - x) * p, py = (by + b * h - y) * p;
            double wsum = 0.0;
            for (int ny = -nimg; ny <= nimg; ny++)
                for (int nx = -nimg; nx <= nimg; nx++)
                    if (nx || ny) wsum += smooth_density(jb, t, px + nx * period, py + ny * period);
            node[b * (DEWRAP_NODES + 1) + a] = wsum * p * p;
        }
    for (int yy = 0; yy < stamp->ny; yy++) {
        double fy = (stamp->y0 + yy - by) / h;
        int b = (int)floor(fy);
        if (b < b0) b = b0;
        if (b > b1 - 1) b = b1 - 1 >= b0 ? b1 - 1 : b0;
        double ty = fy - b;
        for (int xx = 0; xx < stamp->nx; xx++) {
            double fx = (stamp->x0 + xx - bx) / h;
            int a = (int)floor(fx);
            if (a < a0) a = a0;
            if (a > a1 - 1) a = a1 - 1 >= a0 ? a1 - 1 : a0;
            double tx = fx - a;
            const double *n0 = node + b * (DEWRAP_NODES + 1) + a;
            int ra = a + 1 <= a1, rb = b + 1 <= b1;
            double v00 = n0[0], v10 = ra ? n0[1] : v00;
            double v01 = rb ? n0[DEWRAP_NODES + 1] : v00;
            double v11 = ra && rb ? n0[DEWRAP_NODES + 2] : (rb ? v01 : v10);
            double wv = (1 - ty) * ((1 - tx) * v00 + tx * v10) + ty * ((1 - tx) * v01 + tx * v11);
            stamp->pix[(size_t)yy * stamp->nx + xx] -= wv;
        }
    }
    return WF_OK;
}

/* ------------------------------------------------------------ no PSF: real space */

/* Light of the smooth round galaxy within radius r, as a fraction of its flux (bulge and
 * smooth disk only; knots are drawn apart). */
static double smooth_enclosed(const job *jb, const wf_sersic_table *t, double r)
{
    if (!(r < INFINITY)) return jb->fb + jb->fd;
    double e = 0.0;
    if (jb->fb > 0.0) {
        double x = t->b * sqrt(sqrt(r / jb->re)), term = exp(-x), q = 0.0;
        for (int k = 0; k < 8; k++) {
            q += term;
            term *= x / (k + 1);
        }
        e += jb->fb * (1.0 - q);
    }
    if (jb->fd > 0.0) {
        double x = r / jb->r0;
        e += jb->fd * (-expm1(-x) - x * exp(-x));
    }
    return e;
}

static const double gl2[2][2] = {{-0.5773502691896258, 1.0}, {0.5773502691896258, 1.0}};
static const double gl4[4][2] = {{-0.8611363115940526, 0.3478548451374538},
                                 {-0.3399810435848563, 0.6521451548625461},
                                 {0.3399810435848563, 0.6521451548625461},
                                 {0.8611363115940526, 0.3478548451374538}};
static const double gl8[8][2] = {{-0.9602898564975363, 0.1012285362903763},
                                 {-0.7966664774136267, 0.2223810344533745},
                                 {-0.5255324099163290, 0.3137066458778873},
                                 {-0.1834346424956498, 0.3626837833783620},
                                 {0.1834346424956498, 0.3626837833783620},
                                 {0.5255324099163290, 0.3137066458778873},
                                 {0.7966664774136267, 0.2223810344533745},
                                 {0.9602898564975363, 0.1012285362903763}};

typedef struct fan {
    const job *jb;
    const wf_sersic_table *t;
    double d, phi; /* the edge's line: distance from the centre and direction of its foot */
} fan;

static double fan_f(const fan *f, double th)
{
    double c = cos(th - f->phi);
    return c > 0.0 ? smooth_enclosed(f->jb, f->t, f->d / c) : f->jb->fb + f->jb->fd;
}

/* Gauss-Kronrod 7-15 on [a, b]; *err is |K15 - G7|. */
static double gk15(const fan *f, double a, double b, double *err)
{
    static const double xk[8] = {0.991455371120812639, 0.949107912342758525, 0.864864423359769073,
                                 0.741531185599394440, 0.586087235467691130, 0.405845151377397167,
                                 0.207784955007898468, 0.0};
    static const double wk[8] = {0.022935322010529225, 0.063092092629978553, 0.104790010322250184,
                                 0.140653259715525919, 0.169004726639267903, 0.190350578064785410,
                                 0.204432940075298892, 0.209482141084727828};
    static const double wg[4] = {0.129484966168869693, 0.279705391489276668, 0.381830050505118945,
                                 0.417959183673469388};
    double c = 0.5 * (a + b), h = 0.5 * (b - a);
    double f0 = fan_f(f, c), k = wk[7] * f0, g = wg[3] * f0;
    for (int i = 0; i < 7; i++) {
        double v = fan_f(f, c - h * xk[i]) + fan_f(f, c + h * xk[i]);
        k += wk[i] * v;
        if (i % 2) g += wg[i / 2] * v;
    }
    *err = fabs((k - g) * h);
    return k * h;
}

static double gk_adapt(const fan *f, double a, double b, double tol, int depth)
{
    double err, v = gk15(f, a, b, &err);
    if (err <= tol || depth <= 0) return v;
    double m = 0.5 * (a + b), t = fmax(0.5 * tol, 1e-17);
    return gk_adapt(f, a, m, t, depth - 1) + gk_adapt(f, m, b, t, depth - 1);
}

/* Light of the round smooth galaxy in the triangle (centre, P, Q), signed positive when
 * P -> Q turns counter-clockwise: in polar coordinates the radial integral is the
 * enclosed-light function, so the cusp at the centre needs no quadrature at all and the
 * angular integrand E(d / cos(theta - phi)) / (2 pi) is smooth. */
static double fan_triangle(const job *jb, const wf_sersic_table *t, double px, double py,
                           double qx, double qy)
{
    double cross = px * qy - py * qx;
    double ex = qx - px, ey = qy - py, len = hypot(ex, ey);
    /* collinear with the centre (a grid line through it): no area, and no direction to the
     * line's foot */
    if (!(fabs(cross) > 1e-12 * hypot(px, py) * hypot(qx, qy))) return 0.0;
    /* the foot of the perpendicular from the centre to the line: R(theta) = d / cos(theta
     * - phi) along the edge */
    double tx = ex / len, ty = ey / len, along = px * tx + py * ty;
    double fx = px - along * tx, fy = py - along * ty;
    fan f = {jb, t, hypot(fx, fy), atan2(fy, fx)};
    double ta = atan2(py, px), tb = atan2(qy, qx);
    double dth = tb - ta; /* the triangle's angle, in (-pi, pi), signed like cross */
    if (dth > M_PI) dth -= 2.0 * M_PI;
    if (dth < -M_PI) dth += 2.0 * M_PI;
    tb = ta + dth;
    /* keep theta - phi in (-pi/2, pi/2) */
    double mid = 0.5 * (ta + tb);
    while (f.phi - mid > M_PI) f.phi -= 2.0 * M_PI;
    while (mid - f.phi > M_PI) f.phi += 2.0 * M_PI;
    return gk_adapt(&f, ta, tb, 1e-12, 12) / (2.0 * M_PI);
}

/* Light of the smooth galaxy in one pixel (corners in arcsec from the centre). */
static double pixel_light(const job *jb, const wf_sersic_table *t, double x0, double y0,
                          double p, int near)
{
    const double(*ai)[2] = jb->shape.ainv;
    if (near) { /* the pixel's corners in round coordinates, counter-clockwise */
        double cx[4] = {x0, x0 + p, x0 + p, x0}, cy[4] = {y0, y0, y0 + p, y0 + p};
        double rx[4], ry[4], sum = 0.0;
        for (int i = 0; i < 4; i++) {
            rx[i] = ai[0][0] * cx[i] + ai[0][1] * cy[i];
            ry[i] = ai[1][0] * cx[i] + ai[1][1] * cy[i];
        }
        for (int i = 0; i < 4; i++)
            sum += fan_triangle(jb, t, rx[i], ry[i], rx[(i + 1) % 4], ry[(i + 1) % 4]);
        return sum;
    }
    /* smooth over the pixel: tensor Gauss-Legendre, with as many nodes as the profile's
     * steepness across the pixel needs */
    double xc = x0 + 0.5 * p, yc = y0 + 0.5 * p;
    double r = hypot(ai[0][0] * xc + ai[0][1] * yc, ai[1][0] * xc + ai[1][1] * yc);
    double slope = 0.0; /* |d ln I / dr| */
    if (jb->fb > 0.0) slope = fmax(slope, 0.25 * t->b * sqrt(sqrt(r / jb->re)) / r);
    if (jb->fd > 0.0) slope = fmax(slope, 1.0 / jb->r0);
    double v = slope * p * jb->shape.smax;
    const double(*g)[2] = v < 0.05 ? gl2 : v < 0.5 ? gl4 : gl8;
    int n = v < 0.05 ? 2 : v < 0.5 ? 4 : 8;
    double sum = 0.0;
    for (int b = 0; b < n; b++)
        for (int a = 0; a < n; a++)
            sum += g[a][1] * g[b][1] *
                   smooth_density(jb, t, xc + 0.5 * p * g[a][0], yc + 0.5 * p * g[b][0]);
    return sum * 0.25 * p * p;
}

/* Without a PSF every pixel is the profile's integral over it, computed directly: exact to
 * ~1e-10 of the flux, no folding, no ringing. Pixels near the centre (where the cusp and
 * the disk's kink are) use the polar fan; the others Gauss-Legendre. */
static wf_status draw_nopsf(wf_profile_work *w, const job *jb, double x, double y,
                            wf_stamp *stamp)
{
    const wf_sersic_table *t = w->sersic;
    const double p = w->acc.pixel_scale;
    int nearb = 1 + (int)ceil(jb->shape.smax / jb->shape.smin);
    long ic = lround(x), jc = lround(y);
    for (int yy = 0; yy < stamp->ny; yy++) {
        long py = (long)stamp->y0 + yy;
        double y0 = (py - 0.5 - y) * p;
        for (int xx = 0; xx < stamp->nx; xx++) {
            long px = (long)stamp->x0 + xx;
            int near = labs(px - ic) <= nearb && labs(py - jc) <= nearb;
            double v = jb->fb > 0.0 || jb->fd > 0.0
                           ? pixel_light(jb, t, (px - 0.5 - x) * p, y0, p, near)
                           : 0.0;
            stamp->pix[(size_t)yy * stamp->nx + xx] = v;
        }
    }
    double clipped = 0.0;
    for (size_t i = 0; i < (size_t)stamp->nx * stamp->ny; i++)
        if (stamp->pix[i] < 0.0) { /* quadrature rounding only */
            clipped -= stamp->pix[i];
            stamp->pix[i] = 0.0;
        }
    for (int j = 0; j < jb->nk; j++) { /* a delta function's pixel integral */
        long px = lround(x + jb->knots[2 * j] / p), py = lround(y + jb->knots[2 * j + 1] / p);
        if (px >= stamp->x0 && px < (long)stamp->x0 + stamp->nx && py >= stamp->y0 &&
            py < (long)stamp->y0 + stamp->ny)
            stamp->pix[(size_t)(py - stamp->y0) * stamp->nx + (size_t)(px - stamp->x0)] +=
                jb->fknot;
    }
    double sum = 0.0;
    for (size_t i = 0; i < (size_t)stamp->nx * stamp->ny; i++) sum += stamp->pix[i];
    stamp->sum = sum;
    stamp->clipped = clipped;
    stamp->fft = 0;
    return WF_OK;
}

static wf_status draw_job(wf_profile_work *w, const job *jb, const wf_profile_psf *psf,
                          double x, double y, wf_stamp *stamp)
{
    wf_status st = check_position(x, y);
    if (st) return st;
    if (psf && fabs(psf->pixel_scale - w->acc.pixel_scale) > 1e-12 * w->acc.pixel_scale)
        return wf_error(WF_ERR_INPUT, "profile: PSF prepared for %g arcsec pixels, drawing "
                        "at %g", psf->pixel_scale, w->acc.pixel_scale);
    if (!psf) return draw_nopsf(w, jb, x, y, stamp);
    const wf_sersic_table *t = w->sersic;
    const double p = w->acc.pixel_scale;
    grid gd;
    memset(&gd, 0, sizeof gd);
    gd.ic = (int)lround(x);
    gd.jc = (int)lround(y);
    gd.dx = (x - gd.ic) * p;
    gd.dy = (y - gd.jc) * p;

    /* FFT side. The stamp must lie inside the box [ic - M/2, ic + M/2 - 1]; the light
     * beyond the box, which wraps in, must stay below folding_threshold; and the side
     * depends on the object, not on the bounds asked for (unless they reach beyond its own
     * stamp), so that a piece of a stamp has the same pixels as the whole. */
    long hx = (long)gd.ic - stamp->x0, hx1 = (long)stamp->x0 + stamp->nx - gd.ic;
    long hy = (long)gd.jc - stamp->y0, hy1 = (long)stamp->y0 + stamp->ny - gd.jc;
    long need = 2 * (hx > hx1 ? hx : hx1);
    long need_y = 2 * (hy > hy1 ? hy : hy1);
    if (need_y > need) need = need_y;
    if (need > ladder_max(w))
        return wf_error(WF_ERR_RANGE, "profile: stamp %dx%d at (%d, %d) is more than max_fft "
                        "%d / 2 pixels from the object at (%.2f, %.2f)", stamp->nx,
                        stamp->ny, stamp->x0, stamp->y0, ladder_max(w), x, y);
    double rfold = object_radius(jb, t, psf, w->acc.folding_threshold);
    double rown = object_radius(jb, t, psf, 1.0 - w->acc.flux_fraction);
    double need_fold = 2.0 * ceil(fmax(rfold, rown) / p) + 2.0;
    int mi = choose_size(w, psf, fmax((double)need, need_fold));
    gd.m = w->sizes[mi];
    int clamped = gd.m < need_fold;
    gd.half = gd.m / 2;
    gd.dk = 2.0 * M_PI / (gd.m * p);

    /* knots: those inside the box (beyond it they would wrap) */
    double kedge = (gd.half - 1) * p;
    for (int j = 0; j < jb->nk; j++) {
        double kx = jb->knots[2 * j] + gd.dx, ky = jb->knots[2 * j + 1] + gd.dy;
        if (fabs(kx) <= kedge && fabs(ky) <= kedge) {
            w->knot_box[2 * gd.nk] = jb->knots[2 * j];
            w->knot_box[2 * gd.nk + 1] = jb->knots[2 * j + 1];
            gd.nk++;
        }
    }
    gd.kpos = w->knot_box;

    /* Fourier extent: the PSF's band (or the no-PSF cap), and the smooth profile's own */
    double kband = fmin(psf->kmax, WF_PSF_BAND_NYQ * M_PI / p);
    double ksmooth = fmin(kband, psf_kcut(jb, t, psf, w->acc.kvalue_accuracy, 0));
    double kknots = gd.nk ? fmin(kband, psf_kcut(jb, t, psf, w->acc.kvalue_accuracy, 1)) : 0.0;
    int lim;
    if (psf->table_fft % gd.m == 0) {
        gd.mode = MODE_EXACT;
        gd.st = psf->table_fft / gd.m;
        lim = psf->kr / gd.st;
    } else {
        gd.mode = MODE_INTERP;
        lim = (int)floor((psf->kr - 2) * (double)gd.m / psf->table_fft);
    }
    int cap = (w->cap_line - 1) / 2;
    if (lim > cap) lim = cap;
    int us = (int)floor(ksmooth / gd.dk), uk = gd.nk ? (int)floor(kknots / gd.dk) : 0;
    if (us > lim) us = lim;
    if (uk > lim) uk = lim;
    gd.u = us > uk ? us : uk;

    phase_line(gd.dk * gd.dx, gd.u, w->ex);
    phase_line(gd.dk * gd.dy, gd.u, w->ey);
    if (gd.mode == MODE_INTERP) {
        double ratio = (double)psf->table_fft / gd.m;
        for (int u = -gd.u; u <= gd.u; u++) {
            cubic_taps(u * ratio, psf->kr, &w->ix[u + gd.u], &w->wx[4 * (u + gd.u)]);
            cubic_taps(u * ratio, psf->kr, &w->iy[u + gd.u], &w->wy[4 * (u + gd.u)]);
        }
    }

    memset(w->fft, 0, (size_t)gd.m * (gd.m + 2) * sizeof(double));
    if (!gd.nk) {
        fold_pass(w, jb, psf, &gd, us, -1, 0);
    } else {
        /* as many knots per pass as the phase-line buffers hold (all of them but for the
         * largest boxes): each pass multiplies by the PSF once */
        size_t len = 2 * (size_t)gd.u + 1;
        gd.ks = ((len + 3) & ~(size_t)3) + 8; /* room for knot_sum's rounding up */
        size_t room = (size_t)WF_PROFILE_KNOT_BLOCK * (size_t)w->cap_line / gd.ks;
        int per = room > (size_t)WF_PROFILE_MAX_KNOTS ? WF_PROFILE_MAX_KNOTS : (int)room;
        if (per < 1) per = 1;
        for (int k0 = 0; k0 < gd.nk; k0 += per) {
            int nkb = gd.nk - k0 < per ? gd.nk - k0 : per;
            for (int j = 0; j < nkb; j++) {
                const double *kp = gd.kpos + 2 * (size_t)(k0 + j);
                double *lx = w->kx + 2 * (size_t)j * gd.ks, *ly = w->ky + 2 * (size_t)j * gd.ks;
                phase_line_to(gd.dk * (kp[0] + gd.dx), gd.u, lx, lx + gd.ks, 1);
                phase_line_to(gd.dk * (kp[1] + gd.dy), gd.u, ly, ly + gd.ks, 1);
            }
            fold_pass(w, jb, psf, &gd, us, k0, nkb); /* the smooth part rides with pass 0 */
        }
    }
    fftw_execute_dft_c2r((fftw_plan)w->plans[mi], (fftw_complex *)w->fft, w->fft);

    const double norm = 1.0 / ((double)gd.m * gd.m);
    for (int yy = 0; yy < stamp->ny; yy++) {
        const double *src = w->fft + (size_t)(stamp->y0 + yy - gd.jc + gd.half) * (gd.m + 2) +
                            (size_t)(stamp->x0 - gd.ic + gd.half);
        double *dst = stamp->pix + (size_t)yy * stamp->nx;
        for (int xx = 0; xx < stamp->nx; xx++) dst[xx] = src[xx] * norm;
    }
    if (clamped && jb->fpoint == 0.0 && (st = dewrap(w, jb, &gd, x, y, stamp))) return st;
    double clipped = 0.0;
    for (size_t i = 0; i < (size_t)stamp->nx * stamp->ny; i++)
        if (stamp->pix[i] < 0.0) { /* ringing and rounding */
            clipped -= stamp->pix[i];
            stamp->pix[i] = 0.0;
        }
    double sum = 0.0;
    for (size_t i = 0; i < (size_t)stamp->nx * stamp->ny; i++) sum += stamp->pix[i];
    stamp->sum = sum;
    stamp->clipped = clipped;
    stamp->fft = gd.m;
    return WF_OK;
}

wf_status wf_profile_work_tune(wf_profile_work *work, double flux_fraction,
                               double folding_threshold, double kvalue_accuracy)
{
    wf_profile_accuracy acc = work->acc;
    acc.flux_fraction = flux_fraction;
    acc.folding_threshold = folding_threshold;
    acc.kvalue_accuracy = kvalue_accuracy;
    wf_status st = wf_profile_check_accuracy(&acc);
    if (st) return st;
    work->acc = acc;
    return WF_OK;
}

static wf_status check_stamp(const wf_stamp *stamp)
{
    if (!stamp || !stamp->pix || stamp->nx < 1 || stamp->ny < 1 || stamp->nx > 65536 ||
        stamp->ny > 65536)
        return wf_error(WF_ERR_INPUT, "profile: stamp without pixels or with bounds %dx%d",
                        stamp ? stamp->nx : 0, stamp ? stamp->ny : 0);
    return WF_OK;
}

static void clear_stamp(wf_stamp *stamp)
{
    memset(stamp->pix, 0, (size_t)stamp->nx * stamp->ny * sizeof(double));
    stamp->sum = stamp->clipped = 0.0;
    stamp->fft = 0;
}

wf_status wf_profile_draw_galaxy(wf_profile_work *work, const wf_galaxy *g,
                                 const wf_profile_psf *psf, double x, double y,
                                 wf_stamp *stamp)
{
    wf_status st = check_stamp(stamp);
    if (st) return st;
    job jb;
    if ((st = galaxy_job(work, g, &jb)) || (st = check_position(x, y))) return st;
    if (jb.flux == 0.0) {
        clear_stamp(stamp);
        return WF_OK;
    }
    return draw_job(work, &jb, psf, x, y, stamp);
}

wf_status wf_profile_draw_point(wf_profile_work *work, const wf_profile_psf *psf, double flux,
                                double x, double y, wf_stamp *stamp)
{
    wf_status st = check_stamp(stamp);
    if (st || (st = check_position(x, y))) return st;
    if (!(flux >= 0.0 && flux < 1e30))
        return wf_error(WF_ERR_RANGE, "profile: point source flux %g not in [0, 1e30)", flux);
    clear_stamp(stamp);
    if (flux == 0.0) return WF_OK;
    if (!psf) { /* the pixel integral of a delta function */
        long px = lround(x), py = lround(y);
        if (px >= stamp->x0 && px < (long)stamp->x0 + stamp->nx && py >= stamp->y0 &&
            py < (long)stamp->y0 + stamp->ny)
            stamp->pix[(size_t)(py - stamp->y0) * stamp->nx + (size_t)(px - stamp->x0)] = flux;
        stamp->sum = flux;
        return WF_OK;
    }
    job jb;
    memset(&jb, 0, sizeof jb);
    jb.flux = jb.fpoint = flux;
    wf_profile_shape(0.0, 0.0, 0.0, &jb.shape);
    return draw_job(work, &jb, psf, x, y, stamp);
}
