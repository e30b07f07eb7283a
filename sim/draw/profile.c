/* Drawing galaxies and point sources: with a PSF in Fourier space, without one in real
 * space (see sim/draw/profile.h for the method and docs/OPTICS.md "Profiles" for the measured
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
 * Knots are point sources: their transform is a sum of phases, separable in u and v. Summed
 * directly (blocks of WF_PROFILE_KNOT_BLOCK per-knot phase lines) it costs a complex
 * multiply-add per knot and sample; the knot lattice ("knot lattice" below) sums them on a
 * coarser grid and interpolates, to ~1e-9 of the peak, which most galaxies take. Without a
 * PSF a knot is a delta function whose pixel integral puts all its light in the pixel
 * holding it.
 *
 * The per-sample work runs in kernels with scalar and vector versions that give the same
 * bits ("fold kernels" below). */
#include <fftw3.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hal/simd.h"
#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"
#include "sim/numeric/trig.h"
#include "sim/numeric/fftw_lock.h"

/* The knot lattice (see "knot lattice" below): most kernel taps per axis, coarsest step. */
#define LAT_WMAX 16
#define LAT_RMAX 64


void wf_profile_accuracy_default(wf_profile_accuracy *acc)
{
    acc->pixel_scale = WF_PROFILE_PIXEL_SCALE;
    acc->flux_fraction = 0.995;
    acc->folding_threshold = 5e-3;
    acc->kvalue_accuracy = 1e-5;
    acc->min_fft = 16;
    acc->max_fft = 1024;
    acc->psf_table_fft = 192;
    acc->core_radius = 0.0;
    acc->core_levels = 1;
    acc->wing_tolerance = 0.0;
    acc->knot_accuracy = WF_PROFILE_KNOT_ACCURACY;
    acc->cut_tolerance = 0.0;
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
    if (!(acc->core_radius >= 0.0 && acc->core_radius <= 60.0))
        return wf_error(WF_ERR_RANGE, "profile: core_radius %g arcsec outside [0, 60]",
                        acc->core_radius);
    if (acc->core_levels < 1 || acc->core_levels > WF_PROFILE_MAX_CORES)
        return wf_error(WF_ERR_RANGE, "profile: core_levels %d outside [1, %d]",
                        acc->core_levels, WF_PROFILE_MAX_CORES);
    if (!(acc->knot_accuracy >= 1e-15 && acc->knot_accuracy <= 0.01))
        return wf_error(WF_ERR_RANGE, "profile: knot_accuracy %g outside [1e-15, 0.01]",
                        acc->knot_accuracy);
    if (!(acc->wing_tolerance >= 0.0 && acc->wing_tolerance < INFINITY))
        return wf_error(WF_ERR_RANGE, "profile: wing_tolerance %g is not a finite value >= 0",
                        acc->wing_tolerance);
    if (!(acc->cut_tolerance >= 0.0 && acc->cut_tolerance < INFINITY))
        return wf_error(WF_ERR_RANGE, "profile: cut_tolerance %g is not a finite value >= 0",
                        acc->cut_tolerance);
    /* even also because the PSF tables' batched real transforms are planned without
     * buffering (sim/draw/profile_psf.c), which FFTW cannot do for odd lengths past 15 */
    if (acc->psf_table_fft < 16 || acc->psf_table_fft > 4096 || acc->psf_table_fft % 2)
        return wf_error(WF_ERR_RANGE, "profile: psf_table_fft %d not an even number in "
                        "[16, 4096]", acc->psf_table_fft);
    return WF_OK;
}

/* ------------------------------------------------------------------------ work buffers */

int wf_profile_fft_ladder(const wf_profile_accuracy *acc, int *sizes, int cap)
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
    l->nsizes = wf_profile_fft_ladder(acc, l->sizes, 48);
    l->max_m = l->nsizes ? l->sizes[l->nsizes - 1] : 0;
    /* |k| <= WF_PSF_BAND_NYQ pi / p is |u| <= WF_PSF_BAND_NYQ M / 2 steps */
    l->cap_line = 2 * ((int)ceil(0.5 * WF_PSF_BAND_NYQ * l->max_m) + 2) + 1;
}

/* Doubles for the knot lattice: (U / r + w) rows of 2 U / r + w entries, re and im, for
 * U ~ 1.2 M at Y106 and r >= 2, so an eighth of max_m^2 holds every lattice of boxes up to
 * M = 512 and the coarser ones beyond; the others fall back to the direct sum. */
static size_t lattice_cap(const work_layout *l)
{
    size_t m = (size_t)l->max_m;
    return m * m / 8 > 65536 ? m * m / 8 : 65536;
}

/* Doubles for the lattice's interpolated rows (up to LAT_WMAX of them, re and im, 2 U + 9
 * entries each) and one mirrored coarse row: room for U up to half cap_line (~2 M, the
 * band of every filter redder than 0.6 um). */
static size_t lattice_ring(const work_layout *l)
{
    return 2 * (size_t)LAT_WMAX * ((size_t)l->cap_line / 2 + 9) + (size_t)l->cap_line;
}

/* The zero-filled buffers, which wf_profile_work_init lays out first, and the rest, which
 * draws touch only as far as they reach. */
static size_t dense_bytes(const work_layout *l)
{
    size_t m = (size_t)l->max_m, d = sizeof(double);
    return 2 * wf_arena_cost((size_t)l->cap_line * 2 * d) + 2 * wf_arena_cost((size_t)l->cap_line * sizeof(int)) +
           2 * wf_arena_cost((size_t)l->cap_line * 4 * d) + wf_arena_cost((m / 2 + 8) * 4 * d) +
           2 * wf_arena_cost((size_t)WF_PROFILE_MAX_KNOTS * 2 * d) + wf_arena_cost(lattice_ring(l) * d) +
           wf_arena_cost((size_t)l->cap_line * sizeof(int));
}

static size_t sparse_bytes(const work_layout *l)
{
    size_t m = (size_t)l->max_m, d = sizeof(double);
    return wf_arena_cost(m * (m + 2) * d) + 2 * wf_arena_cost((size_t)WF_PROFILE_KNOT_BLOCK * l->cap_line * 2 * d) +
           wf_arena_cost(lattice_cap(l) * d);
}

wf_status wf_profile_work_need(const wf_profile_accuracy *acc, size_t *bytes, size_t *dense)
{
    wf_status st = wf_profile_check_accuracy(acc);
    if (st) return st;
    work_layout l;
    layout(acc, &l);
    if (!l.nsizes)
        return wf_error(WF_ERR_RANGE, "profile: no FFT side of the form 2^a or 3 2^a in "
                        "[%d, %d]", acc->min_fft, acc->max_fft);
    *bytes = dense_bytes(&l) + sparse_bytes(&l);
    if (dense) *dense = dense_bytes(&l);
    return WF_OK;
}

wf_status wf_profile_work_init(wf_profile_work *w, const wf_profile_accuracy *acc,
                               wf_arena *arena)
{
    memset(w, 0, sizeof *w);
    size_t need;
    wf_status st = wf_profile_work_need(acc, &need, NULL);
    if (st) return st;
    w->acc = *acc;
    work_layout l;
    layout(acc, &l);
    size_t m = (size_t)l.max_m, d = sizeof(double);
    /* The zero-filled buffers first (wf_profile_work_need's `dense`: a host may put them on
     * huge pages). The FFT buffer, the knot phase lines and the knot lattice come after and
     * are not zeroed: each draw clears or writes what it reads (the lines' padding lanes only
     * feed unused sums), so pages beyond the largest box drawn are never touched and cost no
     * resident memory. */
    if ((st = wf_arena_calloc(arena, (size_t)l.cap_line * 2, d, "profile phases",
                              (void **)&w->ex)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line * 2, d, "profile phases",
                              (void **)&w->ey)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line, sizeof(int), "PSF taps",
                              (void **)&w->ix)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line, sizeof(int), "PSF taps",
                              (void **)&w->iy)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line * 4, d, "PSF weights",
                              (void **)&w->wx)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line * 4, d, "PSF weights",
                              (void **)&w->wy)) ||
        (st = wf_arena_calloc(arena, (m / 2 + 8) * 4, d, "profile run", (void **)&w->run)) ||
        (st = wf_arena_calloc(arena, (size_t)WF_PROFILE_MAX_KNOTS * 2, d, "knot positions",
                              (void **)&w->knot_pos)) ||
        (st = wf_arena_calloc(arena, (size_t)WF_PROFILE_MAX_KNOTS * 2, d, "knot positions",
                              (void **)&w->knot_box)) ||
        (st = wf_arena_calloc(arena, lattice_ring(&l), d, "knot lattice rows",
                              (void **)&w->ring)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line, sizeof(int), "profile rows",
                              (void **)&w->rim)) ||
        (st = wf_arena_reserve(arena, m * (m + 2) * d, "profile FFT", (void **)&w->fft)) ||
        (st = wf_arena_reserve(arena, (size_t)WF_PROFILE_KNOT_BLOCK * l.cap_line * 2 * d,
                               "knot phases", (void **)&w->kx)) ||
        (st = wf_arena_reserve(arena, (size_t)WF_PROFILE_KNOT_BLOCK * l.cap_line * 2 * d,
                               "knot phases", (void **)&w->ky)) ||
        (st = wf_arena_reserve(arena, lattice_cap(&l) * d, "knot lattice", (void **)&w->lat)))
        return st;
    w->cap_lat = lattice_cap(&l);
    w->cap_line = l.cap_line;
    w->sersic = wf_sersic4_table();
    w->nsizes = l.nsizes;
    memcpy(w->sizes, l.sizes, sizeof w->sizes);
    /* the plans come with the first draw of each side (draw_plan) */
    if ((uintptr_t)w->fft % 16)
        return wf_error(WF_ERR_INTERNAL, "profile: FFT buffer not 16-byte aligned");
    return WF_OK;
}

void wf_profile_work_free(wf_profile_work *w)
{
    if (!w) return;
    memset(w->plans, 0, sizeof w->plans); /* shared: they stay (draw_plan) */
    w->nsizes = 0;
}

/* The drawer's plans: one in-place n x n complex-to-real transform per side, made on first
 * use and shared by every work of the process, as every work's buffer has rows of n + 2 and
 * FFTW's alignment (16 bytes), all new-array execution asks. Planning costs up to ~4 ms a
 * side even with FFTW_ESTIMATE (a 3 x 2^a side the most), per thread when each work made
 * its own for the whole ladder; a scene uses a few sides. FFTW_ESTIMATE reads no array, so
 * a plan may be made while the buffer holds a draw's input. Kept for the process's life. */
static void *shared_plans[2 * 15];

static int side_index(int n)
{
    int odd = n % 3 == 0, m = odd ? n / 3 : n, a = 0;
    while (m > 1) m >>= 1, a++;
    return 2 * a + odd;
}

/* From side 64 up, FFTW_ESTIMATE alone picks plans that copy the 3-point passes through
 * buffers which each execution allocates and frees (malloc, and its consolidation, was ~1.7%
 * of the GalSim scene's samples); FFTW_NO_BUFFERING (fftw3.h's planner flags) leaves them
 * out: 96^2 43 -> 22 us, 192^2 146 -> 107 us, 384^2 555 -> 396 us, 64^2 and 128^2 the same on
 * this machine. At 48^2 buffering is faster (5.4 against 6.1 us), so it stays below 64. The
 * planner still reads no array: the plan is a function of the side, and so are the bits. */
static unsigned draw_plan_flags(int n) { return FFTW_ESTIMATE | (n >= 64 ? FFTW_NO_BUFFERING : 0u); }

static wf_status draw_plan(wf_profile_work *w, int mi)
{
    if (w->plans[mi]) return WF_OK;
    int n = w->sizes[mi], ix = side_index(n);
    if (ix < 0 || ix >= (int)(sizeof shared_plans / sizeof *shared_plans))
        return wf_error(WF_ERR_INTERNAL, "profile: FFT side %d has no plan slot", n);
    wf_fftw_lock();
    if (!shared_plans[ix])
        shared_plans[ix] = fftw_plan_dft_c2r_2d(n, n, (fftw_complex *)w->fft, w->fft, draw_plan_flags(n));
    w->plans[mi] = shared_plans[ix];
    wf_fftw_unlock();
    if (!w->plans[mi]) return wf_error(WF_ERR_INTERNAL, "profile: FFTW could not plan a %d^2 FFT", n);
    return WF_OK;
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
        double r2max = 0.0; /* squares, and one root: hypot only where they overflow */
        for (int j = 0; j < jb->nk; j++) {
            double x = w->knot_pos[2 * j], y = w->knot_pos[2 * j + 1];
            double sx = a[0][0] * x + a[0][1] * y, sy = a[1][0] * x + a[1][1] * y;
            w->knot_pos[2 * j] = sx;
            w->knot_pos[2 * j + 1] = sy;
            double r2 = sx * sx + sy * sy;
            if (r2 > r2max) r2max = r2;
        }
        jb->knot_rmax = sqrt(r2max);
        if (isinf(r2max)) {
            double r = 0.0;
            for (int j = 0; j < jb->nk; j++) r = fmax(r, hypot(w->knot_pos[2 * j], w->knot_pos[2 * j + 1]));
            jb->knot_rmax = r;
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

/* galaxy_miss at r = e^s, with the first two derivatives of its logarithm in s for
 * galaxy_root's steps. */
static double galaxy_miss_slope(const job *jb, const wf_sersic_table *t, double s,
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

/* The last root the radius search found: object_radius asks for several eps in a row, and
 * a start extrapolated from the previous root takes 1.5 steps on average instead of 2.8. */
typedef struct {
    double s, slope, curv, leps; /* ln r, d ln miss / ds and d2 ln miss / ds2 there, ln eps;
                                  * leps NAN: none yet */
} radius_hint;

/* A cold start: the larger of the two components' radii alone (the root lies beyond
 * both), each from its miss e^-x S(x) = eps / weight, S the partial exponential sum of 8
 * (bulge) or 2 (disk) terms, as x = l + ln S(x) iterated twice. */
static double root_guess(const job *jb, const wf_sersic_table *t, double eps)
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
 * galaxy_radius its plain bisection. 0: no root found. */
static int galaxy_root(const job *jb, const wf_sersic_table *t, double eps, double lo,
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
static double galaxy_radius(const job *jb, const wf_sersic_table *t, double eps,
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
static double object_radius(const job *jb, const wf_sersic_table *t, const wf_profile_psf *psf,
                            double eps, int core)
{
    double r;
    if (jb->fpoint > 0.0 && psf) r = psf_radius(psf, eps, core);
    else if (jb->fpoint > 0.0) r = 0.0;
    else if (!psf) r = jb->shape.smax * galaxy_radius(jb, t, eps, NULL);
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
            double c = jb->shape.smax * galaxy_radius(jb, t, eps * split[i], &hint) + rp[i];
            if (c < r) r = c;
        }
    }
    if (jb->nk > 0) {
        double rk = jb->knot_rmax + (psf ? psf_radius(psf, 0.5 * eps, core) : 0.0);
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
    double r = object_radius(jb, t, psf, eps, 0);
    int hmax = ladder_max(w) / 2 - 1;
    double h = ceil(r / p - 1e-9);
    double frac = w->acc.flux_fraction;
    if (!(h <= hmax)) {
        h = hmax;
        /* the light the clamped stamp holds: bisect on eps in log space */
        double lo = log(eps), hi = 0.0;
        for (int it = 0; it < 30; it++) {
            double mid = 0.5 * (lo + hi);
            if (object_radius(jb, t, psf, exp(mid), 0) <= hmax * p) hi = mid;
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

/* |object(k)| along its minor axis (the largest on the ring |k|: both parts fall with |k|);
 * `part` 0 is the smooth galaxy (or the point source), 1 the knots. */
static inline double minor_kvalue(const job *jb, const wf_sersic_table *t, double k, int part)
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
static double psf_kcut_from(const job *jb, const wf_sersic_table *t, const wf_profile_psf *psf,
                            double kvalue, int part, int from)
{
    double dkt = 2.0 * M_PI / (psf->table_fft * psf->pixel_scale), tol = kvalue * jb->flux;
    for (int i = from < psf->kr ? from : psf->kr; i >= 0; i--) {
        if (minor_kvalue(jb, t, i * dkt, part) * psf->env[i] > tol) return (i + 1) * dkt;
    }
    return 0.0;
}

/* From the table's edge; psf_kcut_from may start at a ring known to lie beyond the cut (one
 * whose value exceeds a smaller kvalue: both factors fall with |k|). */
static double psf_kcut(const job *jb, const wf_sersic_table *t, const wf_profile_psf *psf,
                       double kvalue, int part)
{
    return psf_kcut_from(jb, t, psf, kvalue, part, psf->kr);
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
static int tail_cut(const job *jb, const wf_sersic_table *t, const wf_profile_psf *psf,
                    double dk, int m, int lim, double tol, int part)
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
    struct lattice *lat; /* the knots on a coarse lattice, or NULL (direct sums) */
    const int *rim;      /* rim[|v|] = floor(sqrt(u^2 - v^2)): the row's extent */
    double lat_exp;      /* the knot lattice's E = -ln(knot_accuracy) */
} grid;

/* wf_profile_phase_lines (sim/draw/profile_int.h). The step's and the anchors' sines and cosines
 * are taken together in SIMD lanes (sim/numeric/trig.h): one at a time through libm they were ~1.3 M
 * calls over GalSim's scene, most of them two or three per knot. */
#define PHASE_ANGLES 512
void wf_profile_phase_lines(int n, const double *theta, int lo, int hi, double *re0, size_t line,
                            size_t imoff, size_t st, int alt)
{
    const int nb = (hi - lo) / 32 + 1, per = 1 + nb; /* angles per line: the step, the anchors */
    if (per > PHASE_ANGLES) { /* lines longer than the buffer in pieces: the same anchors */
        const int span = 32 * (PHASE_ANGLES - 1);
        for (int l = lo; l <= hi; l += span)
            wf_profile_phase_lines(n, theta, l, hi - l >= span ? l + span - 1 : hi, re0 + (size_t)(l - lo) * st,
                                   line, imoff, st, alt);
        return;
    }
    const int chunk = PHASE_ANGLES / per;
    double ang[PHASE_ANGLES], cs[PHASE_ANGLES], sn[PHASE_ANGLES];
    for (int j0 = 0; j0 < n; j0 += chunk) {
        const int m = n - j0 < chunk ? n - j0 : chunk;
        for (int j = 0; j < m; j++) {
            double th = theta[j0 + j];
            ang[j * per] = th;
            for (int b = 0; b < nb; b++) {
                int u0 = lo + 32 * b;
                ang[j * per + 1 + b] = -u0 * th;
            }
        }
        wf_trig_sincos(ang, m * per, cs, sn);
        for (int j = 0; j < m; j++) {
            double *re = re0 + (size_t)(j0 + j) * line, *im = re + imoff;
            double sr = cs[j * per], si = sn[j * per]; /* step e^{-i theta}, times -1 with alt */
            if (alt) sr = -sr;
            else si = -si;
            for (int b = 0; b < nb; b++) {
                int u0 = lo + 32 * b;
                double sg = alt && (u0 & 1) ? -1.0 : 1.0;
                double cr = sg * cs[j * per + 1 + b], ci = sg * sn[j * per + 1 + b];
                int u1 = u0 + 32 <= hi ? u0 + 32 : hi + 1;
                for (int u = u0; u < u1; u++) {
                    re[(size_t)(u - lo) * st] = cr;
                    im[(size_t)(u - lo) * st] = ci;
                    double nr = cr * sr - ci * si;
                    ci = cr * si + ci * sr;
                    cr = nr;
                }
            }
        }
    }
}

static void phase_line_to(double theta, int n, double *re, double *im, size_t st)
{
    wf_profile_phase_lines(1, &theta, -n, n, re, 0, (size_t)(im - re), st, 1);
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

static long floor_div_l(long a, long b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }
static int floor_div(int a, int b) { return (int)floor_div_l(a, b); }

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
typedef double knot_v8 __attribute__((vector_size(64)));
__attribute__((target("avx512f"))) static int
knot_sum_v8(int n, int nkb, const double *ckr, const double *cki, const double *kx, size_t ks,
            double *restrict rr, double *restrict ri)
{
    KNOT_BODY(knot_v8, 8)
}
static int knot_avx; /* 1: AVX2, 2: AVX-512 (the same sums, lane by lane); wf_profile_simd */
#endif
#endif

static void knot_sum(int n, int nkb, const double *ckr, const double *cki, const double *kx,
                     size_t ks, double *restrict rr, double *restrict ri)
{
    int i0 = 0;
#if defined(__GNUC__)
#if defined(KNOT_AVX)
    if (knot_avx == 2) i0 = knot_sum_v8(n, nkb, ckr, cki, kx, ks, rr, ri);
    if (knot_avx) i0 += knot_sum_v4(n - i0, nkb, ckr, cki, kx + i0, ks, rr + i0, ri + i0);
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

/* ------------------------------------------------------------------------ knot lattice */

/* The knots' transform K(k) = sum_j f_j e^{-i k.x_j} is needed on the fine grid k = (u, v) dk
 * out to the PSF's band, ~2.2 M^2 samples for an FFT box of M pixels, but the knots lie
 * within a few hlr of the object, a small part of the box: sampled on a lattice r times
 * coarser (period L = M p / r, at least X / rho for knots within X of the object) it is
 * still resolved. With a kernel psi of w taps (spacing Delta = r dk) and Phi its transform,
 * sum_n g(n Delta) psi(k / Delta - n), g the sum over knots of f_j Delta / Phi(x_j)
 * e^{-i n Delta x_j}, equals by Poisson's formula K(k) plus the knots' images at x_j + m L
 * (m != 0) weighted by Phi(x_j + m L) / Phi(x_j): with the Kaiser-Bessel shape
 * (sim/draw/profile_int.h) and beta = pi w (1 - rho) that ratio is ~exp(-pi w sqrt(1 - 2 rho)),
 * exp(-E) with E = -ln(acc.knot_accuracy), times a prefactor of order 10: at the default
 * E = 20 the stamps differ from the direct sum's by <= 2e-9 of their peak in
 * tests/test_profile.c, 1e-8 over the GalSim scene (bench/bench_profile.c); a scene lowers E
 * for faint objects (sim/draw/scene.c), down to narrower kernels and coarser lattices. Separable in x and y: g on ~(2 U / r + w)^2 lattice
 * points costs one complex multiply-add per knot (half of them, g being Hermitian); each
 * coarse row is interpolated along u once, each fine sample then takes w real-by-complex
 * multiply-adds from w such rows. Wider kernels allow a larger rho, hence a coarser
 * lattice, for more taps per sample: each draw takes the cheapest. */
typedef struct lattice {
    int r, w, mh, nh, U;
    int nk;                        /* the knots it holds, (x, y) from the object */
    const double *pos;
    const int *rim;                /* the fine grid's |u| <= rim[|v|] */
    double rho, beta;
    size_t gw;                     /* stored row width: 2 nh + 1 and padding */
    const double *gr, *gi;         /* rows m = 0..mh of g(n, m) at [m gw + n + nh]; rows
                                      m < 0 are conj g(-n, -m) */
    double wt[LAT_RMAX][LAT_WMAX]; /* psi at s = rho / r + w / 2 - 1 - i, rho = u mod r */
    double *ar, *ai;               /* ring of w interpolated rows: row m in slot m mod w,
                                      entries [u + U], padded */
    size_t al;                     /* ring row stride */
    double *tmp;                   /* a mirrored row */
    int next;                      /* next coarse row the ring takes */
} lattice;

/* rho for a kernel of w taps: pi w sqrt(1 - 2 rho) = E (negative: w too narrow for E). */
static double lat_rho(int w, double e)
{
    double a = e / (M_PI * w);
    return 0.5 * (1.0 - a * a);
}

/* Largest |u| any fine row served by coarse row m needs (-1: none). Fine row v takes coarse
 * rows floor(v / r) - w/2 + 1 .. floor(v / r) + w/2. */
static int lat_umax(const lattice *l, int m)
{
    long lo = (long)l->r * (m - l->w / 2), hi = (long)l->r * (m + l->w / 2) - 1;
    long vmin = lo > 0 ? lo : hi < 0 ? -hi : 0;
    return vmin > l->U ? -1 : l->rim[vmin];
}

static int lat_nmax(const lattice *l, int m)
{
    int um = lat_umax(l, m);
    return um < 0 ? -1 : um / l->r + l->w / 2;
}

/* Coarse step for knots within x of the object with a kernel of w taps (0: the lattice
 * would not be coarser than the fine grid). */
static int lat_step(const grid *gd, double p, double x, int w)
{
    double rho = lat_rho(w, gd->lat_exp);
    if (!(rho > 0.0)) return 0;
    double r = x > 0.0 ? floor(rho * gd->m * p / x) : LAT_RMAX;
    if (r > LAT_RMAX) r = LAT_RMAX;
    if (r > gd->u / 2) r = gd->u / 2;
    return r >= 2 ? (int)r : 0;
}

/* Relative costs per operation, measured: a complex multiply-add of the coarse sum, a tap
 * of the fine rows, a tap of the u interpolation. */
#define COST_COARSE 1.0
#define COST_FINE 0.8
#define COST_ROW 1.3

/* Sets the lattice's sizes for step r and w taps; 0 when it does not fit the work's
 * buffers. *c0 + *c1 nk is its cost for nk knots (the direct sum's: nk per fine sample). */
static int lat_size(const wf_profile_work *w, const grid *gd, int r, int wd, lattice *l,
                    double *c0, double *c1)
{
    l->r = r;
    l->w = wd;
    l->rho = lat_rho(wd, gd->lat_exp);
    l->U = gd->u;
    l->rim = gd->rim;
    l->mh = gd->u / r + wd / 2;
    l->nh = lat_nmax(l, 0);
    l->gw = 2 * (size_t)l->nh + 1 + 8;
    if (2 * ((size_t)l->mh + 1) * l->gw > w->cap_lat) return 0;
    size_t ks = ((2 * (size_t)l->nh + 1 + 3) & ~(size_t)3) + 8;
    if ((size_t)l->mh + 1 > ks) return 0; /* the y lines share the x lines' stride */
    size_t ring = 2 * (size_t)wd * (2 * (size_t)l->U + 9) + 2 * (2 * (size_t)l->nh + 1);
    if (ring > 2 * (size_t)LAT_WMAX * ((size_t)w->cap_line / 2 + 9) + (size_t)w->cap_line)
        return 0;
    double coarse = 0.0, rows = 0.0;
    for (int m = 0; m <= l->mh; m++) {
        int up = lat_umax(l, m), un = lat_umax(l, -m);
        if (up >= 0) rows += up + 1.0; /* the half of the u range in alias runs */
        if (m && un >= 0) rows += un + 1.0;
        int um = up > un ? up : un;
        if (um >= 0) coarse += 2.0 * (um / r + wd / 2) + 1.0;
    }
    double fine = 0.5 * M_PI * (double)gd->u * gd->u; /* samples in the alias runs */
    *c0 = wd * (COST_FINE * fine + COST_ROW * rows);
    *c1 = COST_COARSE * coarse;
    return 1;
}

/* Kernel weights, knot weights and the coarse rows m >= 0 of g (the knots' phase lines in
 * w->kx and w->ky, free again afterwards). */
static void lat_build(wf_profile_work *w, const job *jb, grid *gd, lattice *l)
{
    const int r = l->r, wd = l->w, nh = l->nh, mh = l->mh;
    const double delta = r * gd->dk;
    l->beta = M_PI * wd * (1.0 - l->rho);
    for (int rho = 0; rho < r; rho++)
        for (int i = 0; i < wd; i++)
            l->wt[rho][i] = wf_knot_kernel((double)rho / r + wd / 2 - 1 - i, wd, l->beta);
    double *gr = w->lat, *gi = w->lat + ((size_t)mh + 1) * l->gw;
    memset(gr, 0, 2 * ((size_t)mh + 1) * l->gw * sizeof(double));
    const size_t ks = ((2 * (size_t)nh + 1 + 3) & ~(size_t)3) + 8;
    size_t room = (size_t)WF_PROFILE_KNOT_BLOCK * (size_t)w->cap_line / ks;
    int per = room > (size_t)WF_PROFILE_MAX_KNOTS ? WF_PROFILE_MAX_KNOTS : (int)room;
    double ckr[WF_PROFILE_MAX_KNOTS], cki[WF_PROFILE_MAX_KNOTS], wk[WF_PROFILE_MAX_KNOTS];
    double thx[WF_PROFILE_MAX_KNOTS], thy[WF_PROFILE_MAX_KNOTS];
    const double half = 0.5 * wd * delta, norm = jb->fknot / ((double)wd * wd);
    for (int k0 = 0; k0 < l->nk; k0 += per) {
        int nkb = l->nk - k0 < per ? l->nk - k0 : per;
        for (int j = 0; j < nkb; j++) {
            const double *kp = l->pos + 2 * (size_t)(k0 + j);
            double x = kp[0] + gd->dx, y = kp[1] + gd->dy;
            thx[j] = delta * x;
            thy[j] = delta * y;
            wk[j] = norm / (wf_knot_kernel_ft(half * x, l->beta) *
                            wf_knot_kernel_ft(half * y, l->beta));
        }
        wf_profile_phase_lines(nkb, thx, -nh, nh, w->kx, 2 * ks, ks, 1, 0);
        wf_profile_phase_lines(nkb, thy, 0, mh, w->ky, 2 * ks, ks, 1, 0);
        for (int m = 0; m <= mh; m++) {
            int ns = lat_nmax(l, m), nn = lat_nmax(l, -m);
            if (nn > ns) ns = nn;
            if (ns < 0) continue;
            for (int j = 0; j < nkb; j++) {
                const double *ly = w->ky + 2 * (size_t)j * ks + (size_t)m;
                ckr[j] = wk[j] * ly[0];
                cki[j] = wk[j] * ly[ks];
            }
            size_t off = (size_t)(nh - ns);
            knot_sum((2 * ns + 1 + 7) & ~7, nkb, ckr, cki, w->kx + off, ks,
                     gr + (size_t)m * l->gw + off, gi + (size_t)m * l->gw + off);
        }
    }
    l->gr = gr;
    l->gi = gi;
    l->al = 2 * (size_t)l->U + 1 + 8;
    l->ar = w->ring;
    l->ai = w->ring + (size_t)wd * l->al;
    l->tmp = w->ring + 2 * (size_t)wd * l->al;
    l->next = floor_div(-l->U, r) - wd / 2 + 1;
}

typedef struct knot_rank {
    double e; /* max(|x|, |y|) from the object */
    int j;
} knot_rank;

static int rank_cmp(const void *pa, const void *pb)
{
    const knot_rank *a = pa, *b = pb;
    if (a->e != b->e) return a->e < b->e ? 1 : -1; /* farthest first */
    return (a->j > b->j) - (a->j < b->j);
}

#define LAT_OUTER_MAX 32

/* Chooses the kernel, how many of the farthest knots to sum directly and the lattice for
 * the rest, by operation count; reorders gd->kpos (the direct ones first, then the
 * lattice's, each in a fixed order). 0: all knots directly. */
static int knot_plan(wf_profile_work *w, grid *gd, double p, lattice *l)
{
    static const int widths[] = {6, 8, 10, 12, 14, 16};
    const int nk = gd->nk, forced = w->knot_method == WF_KNOTS_LATTICE;
    knot_rank rk[WF_PROFILE_MAX_KNOTS];
    for (int j = 0; j < nk; j++) {
        double x = fabs(gd->kpos[2 * j] + gd->dx), y = fabs(gd->kpos[2 * j + 1] + gd->dy);
        rk[j] = (knot_rank){x > y ? x : y, j};
    }
    qsort(rk, (size_t)nk, sizeof *rk, rank_cmp);
    const double fine = 0.5 * M_PI * (double)gd->u * gd->u;
    /* the direct sum unless the lattice saves a fifth: planning and setup are not counted */
    double best = forced ? INFINITY : 0.8 * nk * fine;
    int best_o = -1, best_r = 0, best_w = 0;
    int omax = forced ? 0 : nk - 1 < LAT_OUTER_MAX ? nk - 1 : LAT_OUTER_MAX;
    for (size_t iw = 0; iw < sizeof widths / sizeof *widths; iw++) {
        int last_r = 0;
        double c0 = 0.0, c1 = 0.0;
        for (int no = 0; no <= omax; no++) {
            int r = lat_step(gd, p, rk[no].e, widths[iw]);
            if (!r) continue;
            if (r != last_r) {
                if (!lat_size(w, gd, r, widths[iw], l, &c0, &c1)) continue;
                last_r = r;
            }
            double c = c0 + c1 * (nk - no) + (double)no * fine;
            if (c < best) {
                best = c;
                best_o = no;
                best_r = r;
                best_w = widths[iw];
            }
        }
    }
    double c0, c1;
    if (best_o < 0 || !lat_size(w, gd, best_r, best_w, l, &c0, &c1)) return 0;
    l->nk = nk - best_o;
    /* the direct ones in rank order, then the rest in their own order */
    double tmp[2 * WF_PROFILE_MAX_KNOTS];
    unsigned char outer[WF_PROFILE_MAX_KNOTS];
    memset(outer, 0, (size_t)nk);
    int k = 0;
    for (int i = 0; i < best_o; i++, k++) {
        outer[rk[i].j] = 1;
        tmp[2 * k] = gd->kpos[2 * rk[i].j];
        tmp[2 * k + 1] = gd->kpos[2 * rk[i].j + 1];
    }
    for (int j = 0; j < nk; j++)
        if (!outer[j]) {
            tmp[2 * k] = gd->kpos[2 * j];
            tmp[2 * k + 1] = gd->kpos[2 * j + 1];
            k++;
        }
    memcpy(w->knot_box, tmp, 2 * (size_t)nk * sizeof(double));
    gd->kpos = w->knot_box;
    l->pos = w->knot_box + 2 * (size_t)best_o;
    return 1;
}

/* ------------------------------------------------------------------------ fold kernels */

/* The per-sample work of a fold pass on one alias run of a row, in four kernels: the
 * smooth galaxy (or point source) times the centring and sub-pixel phases; a coarse row of
 * the knot lattice interpolated along u; the fine row from w of those; the product with
 * PSF x pixel added into the bins. A fifth adds a row of the split PSF's wing to a stamp
 * (add_wing). Each has a scalar version and, on x86-64, vector
 * versions of 2, 4 (AVX2) and 8 (AVX-512) lanes, chosen once by wf_profile_simd. Lanes
 * never mix, every operation is the scalar one in the same order (a vector's last lanes
 * may recompute values already written: the same values), and ISO C mode contracts no
 * multiply-add into a fused one, so every version gives the same bits: the CPU a stamp is
 * drawn on does not change it (tests/test_profile.c, test_simd_identical and
 * test_simd_identical_wing). */

typedef struct smooth_par {
    double qa, qb, qc;        /* q2 = |A^T k|^2 = (qa u + qb) u + qc along the row */
    double re2, r02, fb, fd;  /* bulge and disk: F(re2 q2), (1 + r02 q2)^-3/2 */
    double fpoint;            /* > 0: a point source of this flux instead */
    int bulge, disk;
    const wf_sersic_table *t;
    double eyr, eyi;          /* the row's phase */
    const double *exr, *exi;  /* the columns' phases, indexed by u */
} smooth_par;

/* rr[i], ri[i] for u = ua + i, i < n. */
static void smooth_scalar(const smooth_par *sp, int ua, int n, double *rr, double *ri)
{
    const double eyr = sp->eyr, eyi = sp->eyi;
    for (int i = 0; i < n; i++) {
        int u = ua + i;
        double g;
        if (sp->fpoint > 0.0) {
            g = sp->fpoint;
        } else {
            double q2 = (sp->qa * u + sp->qb) * u + sp->qc;
            g = 0.0;
            if (sp->bulge) g += sp->fb * wf_sersic4_eval(sp->t, sp->re2 * q2);
            if (sp->disk) {
                double s = 1.0 / (1.0 + sp->r02 * q2);
                g += sp->fd * s * sqrt(s);
            }
        }
        double pr = sp->exr[u], pi = sp->exi[u];
        rr[i] = g * (pr * eyr - pi * eyi);
        ri[i] = g * (pr * eyi + pi * eyr);
    }
}

/* run[i] += sum_c wy[c] row_c[i] for the lattice's w rows. */
static void latadd_scalar(int n, int nw, const double *wy, const double *const *lr,
                          const double *const *li, int ua, double *runr, double *runi)
{
    for (int i = 0; i < n; i++) {
        double kr = 0.0, ki = 0.0;
        for (int c = 0; c < nw; c++) {
            kr += wy[c] * lr[c][ua + i];
            ki += wy[c] * li[c][ua + i];
        }
        runr[i] += kr;
        runi[i] += ki;
    }
}

/* A coarse row g (pointers at n = 0) interpolated along u at u, times (-1)^u (the box's
 * centring), into ar[u], ai[u]. */
static inline void latrow_one(const lattice *l, const double *gr, const double *gi, int u,
                              double *ar, double *ai)
{
    int t = floor_div(u, l->r), rho = u - t * l->r, h = l->w / 2 - 1;
    const double *wt = l->wt[rho];
    double sr = 0.0, si = 0.0;
    for (int i = 0; i < l->w; i++) {
        sr += wt[i] * gr[t - h + i];
        si += wt[i] * gi[t - h + i];
    }
    double sg = (u & 1) ? -1.0 : 1.0;
    ar[u] = sg * sr;
    ai[u] = sg * si;
}

static void latrow_scalar(const lattice *l, const double *gr, const double *gi, int ua, int ub,
                          double *ar, double *ai)
{
    for (int u = ua; u <= ub; u++) latrow_one(l, gr, gi, u, ar, ai);
}

/* bins (complex interleaved) += run x (fr + i fi), the PSF read at stride st. */
static void psfmul_scalar(int n, const float *fr, const float *fi, size_t st, const double *runr,
                          const double *runi, double *bins)
{
    for (int i = 0; i < n; i++) {
        double pr = fr[i * st], pi = fi[i * st];
        double rr = runr[i], ri = runi[i];
        bins[2 * i] += rr * pr - ri * pi;
        bins[2 * i + 1] += rr * pi + ri * pr;
    }
}

/* dst[k] += w00 r00[k] + w01 r01[k] + w10 r10[k] + w11 r11[k], k < n: a row of the split
 * PSF's wing, bilinear between four of its phase planes (add_wing). */
static void wing_scalar(long n, double w00, double w01, double w10, double w11, const float *r00,
                        const float *r01, const float *r10, const float *r11, double *dst)
{
    for (long k = 0; k < n; k++) dst[k] += w00 * r00[k] + w01 * r01[k] + w10 * r10[k] + w11 * r11[k];
}

/* acc[k] += max(box[k] + wing, 0) (box NULL: no box pixels), the wing read as wing_scalar:
 * the renderer's sum of a split galaxy's box and wing in one pass over the row. */
static void wingclip_scalar(long n, const double *w, const float *const *r, const float *box,
                            double *acc)
{
    for (long k = 0; k < n; k++) {
        double v = w[0] * r[0][k] + w[1] * r[1][k] + w[2] * r[2][k] + w[3] * r[3][k];
        if (box) v = (double)box[k] + v;
        acc[k] += v < 0.0 ? 0.0 : v;
    }
}

#if defined(__GNUC__) && defined(__x86_64__) /* SSE2 arithmetic in the scalar code too */
#include <immintrin.h>
#define FOLD_SIMD 1

#define VLOAD(x, p) memcpy(&(x), (p), sizeof(x))
#define VSTORE(p, x) memcpy((p), &(x), sizeof(x))

/* de Vaucouleurs F at w, lane by lane as wf_sersic4_eval. ANY(mask) tells whether a lane
 * is set, GATHER(ix, c0, c1, c2, c3) loads ck[l] = t->v[ix[l] + k]. */
#define SERSIC_V(V, VI, VS, NL, ANY, GATHER, w, out)                                       \
    do {                                                                                   \
        VI bits_ = (VI)(w);                                                                \
        VS e_ = __builtin_convertvector((bits_ >> 52) & 0x7ff, VS) - 1023;                 \
        VS bad_ = (e_ < WF_SERSIC_EMIN) | (e_ >= WF_SERSIC_EMAX);                          \
        if (ANY(bad_)) {                                                                   \
            for (int l_ = 0; l_ < (NL); l_++) (out)[l_] = sersic_lane(t, (w)[l_]);         \
            break;                                                                         \
        }                                                                                  \
        /* the mantissa as 1.m, minus 1: exactly (double)(bits & mask) 2^-52 */            \
        V m_ = ((V)((bits_ & 0xfffffffffffffLL) | 0x3ff0000000000000LL) - 1.0) *          \
               (double)WF_SERSIC_SUB;                                                      \
        VS i_ = __builtin_convertvector(m_, VS);                                            \
        V f_ = m_ - __builtin_convertvector(i_, V);                                         \
        VS ix_ = (e_ - WF_SERSIC_EMIN) * WF_SERSIC_ROW + i_;                               \
        V c0_, c1_, c2_, c3_;                                                              \
        GATHER(ix_, c0_, c1_, c2_, c3_);                                                   \
        V fm1_ = f_ - 1.0, fm2_ = f_ - 2.0, fp1_ = f_ + 1.0;                               \
        (out) = (-c0_ * f_ * fm1_ * fm2_ + c3_ * fp1_ * f_ * fm1_) * (1.0 / 6.0) +         \
                (c1_ * fp1_ * fm1_ * fm2_ - c2_ * fp1_ * f_ * fm2_) * 0.5;                 \
    } while (0)

#define SMOOTH_BODY(V, VI, VS, NL, SQRT, ZU, ANY, GATHER)                                 \
    const wf_sersic_table *t = sp->t;                                                      \
    const double eyr = sp->eyr, eyi = sp->eyi;                                             \
    V lane;                                                                                \
    for (int l = 0; l < (NL); l++) lane[l] = l;                                            \
    for (int i = 0; i < n; i += (NL)) {                                                    \
        if (i + (NL) > n) { /* the last vector overlaps the one before: same values */     \
            if (n < (NL)) {                                                                \
                ZU();                                                                      \
                smooth_scalar(sp, ua, n, rr, ri);                                          \
                return;                                                                    \
            }                                                                              \
            i = n - (NL);                                                                  \
        }                                                                                  \
        int u0 = ua + i;                                                                   \
        V g = lane * 0.0;                                                                  \
        if (sp->fpoint > 0.0) {                                                            \
            g += sp->fpoint;                                                               \
        } else {                                                                           \
            V uv = (double)u0 + lane;                                                      \
            V q2 = (sp->qa * uv + sp->qb) * uv + sp->qc;                                   \
            if (sp->bulge) {                                                               \
                V wv = sp->re2 * q2, fv;                                                   \
                SERSIC_V(V, VI, VS, NL, ANY, GATHER, wv, fv);                              \
                g += sp->fb * fv;                                                          \
            }                                                                              \
            if (sp->disk) {                                                                \
                V sv = 1.0 / (1.0 + sp->r02 * q2);                                         \
                g += sp->fd * sv * SQRT(sv);                                               \
            }                                                                              \
        }                                                                                  \
        V pr, pi;                                                                          \
        VLOAD(pr, sp->exr + u0);                                                           \
        VLOAD(pi, sp->exi + u0);                                                           \
        V a = g * (pr * eyr - pi * eyi), b = g * (pr * eyi + pi * eyr);                    \
        VSTORE(rr + i, a);                                                                 \
        VSTORE(ri + i, b);                                                                 \
    }                                                                                      \
    ZU();

/* run[i] += ... for whole vectors: n rounded up (the run and the ring rows are padded) */
#define LATADD_BODY(V, NL, ZU)                                                             \
    for (int i = 0; i < n; i += (NL)) {                                                    \
        V kr = {0}, ki = {0}, x;                                                           \
        for (int c = 0; c < nw; c++) {                                                     \
            VLOAD(x, lr[c] + ua + i);                                                      \
            kr += wy[c] * x;                                                               \
            VLOAD(x, li[c] + ua + i);                                                      \
            ki += wy[c] * x;                                                               \
        }                                                                                  \
        V r0, i0;                                                                          \
        VLOAD(r0, runr + i);                                                               \
        VLOAD(i0, runi + i);                                                               \
        r0 += kr;                                                                          \
        i0 += ki;                                                                          \
        VSTORE(runr + i, r0);                                                              \
        VSTORE(runi + i, i0);                                                              \
    }                                                                                      \
    ZU();

/* a coarse row interpolated along u, vector over t (u = r t + rho) for each rho; the last
 * vector of a rho overlaps the one before */
#define LATROW_BODY(V, NL, ZU)                                                             \
    const int r = l->r, wd = l->w, h = wd / 2 - 1;                                         \
    for (int rho = 0; rho < r; rho++) {                                                    \
        int t0 = floor_div(ua - rho + r - 1, r), t1 = floor_div(ub - rho, r);              \
        if (t1 - t0 + 1 < (NL)) {                                                          \
            for (int t = t0; t <= t1; t++) latrow_one(l, gr, gi, r * t + rho, ar, ai);    \
            continue;                                                                      \
        }                                                                                  \
        const double *wt = l->wt[rho];                                                     \
        for (int t = t0; t <= t1; t += (NL)) {                                             \
            if (t + (NL) - 1 > t1) t = t1 - (NL) + 1;                                      \
            V sr = {0}, si = {0}, x;                                                       \
            for (int i = 0; i < wd; i++) {                                                 \
                VLOAD(x, gr + t - h + i);                                                  \
                sr += wt[i] * x;                                                           \
                VLOAD(x, gi + t - h + i);                                                  \
                si += wt[i] * x;                                                           \
            }                                                                              \
            for (int q = 0; q < (NL); q++) {                                               \
                int u = r * (t + q) + rho;                                                 \
                double sg = (u & 1) ? -1.0 : 1.0;                                          \
                ar[u] = sg * sr[q];                                                        \
                ai[u] = sg * si[q];                                                        \
            }                                                                              \
        }                                                                                  \
    }                                                                                      \
    ZU();

/* the products interleaved into the bins: lanes (re 0, im 0, re 1, im 1, ...) */
#define PSFMUL_BODY(V, VF, VI, NL, LO, HI, ZU, PGATHER)                                                 \
    int i = 0;                                                                             \
    for (; i + (NL) <= n; i += (NL)) {                                                     \
        V pr, pi;                                                                          \
        if (st == 1) {                                                                     \
            VF a, b;                                                                       \
            VLOAD(a, fr + i);                                                              \
            VLOAD(b, fi + i);                                                              \
            pr = __builtin_convertvector(a, V);                                            \
            pi = __builtin_convertvector(b, V);                                            \
        } else {                                                                           \
            PGATHER(pr, fr + (size_t)i * st, st);                                          \
            PGATHER(pi, fi + (size_t)i * st, st);                                          \
        }                                                                                  \
        V rr, ri, b0, b1;                                                                  \
        VLOAD(rr, runr + i);                                                               \
        VLOAD(ri, runi + i);                                                               \
        V br = rr * pr - ri * pi, bi = rr * pi + ri * pr;                                  \
        VLOAD(b0, bins + 2 * i);                                                           \
        VLOAD(b1, bins + 2 * i + (NL));                                                    \
        b0 += __builtin_shuffle(br, bi, (VI)LO);                                           \
        b1 += __builtin_shuffle(br, bi, (VI)HI);                                           \
        VSTORE(bins + 2 * i, b0);                                                          \
        VSTORE(bins + 2 * i + (NL), b1);                                                   \
    }                                                                                      \
    ZU();                                                                                  \
    psfmul_scalar(n - i, fr + (size_t)i * st, fi + (size_t)i * st, st, runr + i, runi + i,  \
                  bins + 2 * i);

#define WING_BODY(V, VF, NL, ZU)                                                           \
    long k = 0;                                                                            \
    for (; k + (NL) <= n; k += (NL)) {                                                     \
        VF a, b, c, d;                                                                     \
        V o;                                                                               \
        VLOAD(a, r00 + k);                                                                 \
        VLOAD(b, r01 + k);                                                                 \
        VLOAD(c, r10 + k);                                                                 \
        VLOAD(d, r11 + k);                                                                 \
        VLOAD(o, dst + k);                                                                 \
        o += w00 * __builtin_convertvector(a, V) + w01 * __builtin_convertvector(b, V) +   \
             w10 * __builtin_convertvector(c, V) + w11 * __builtin_convertvector(d, V);    \
        VSTORE(dst + k, o);                                                                \
    }                                                                                      \
    ZU();                                                                                  \
    wing_scalar(n - k, w00, w01, w10, w11, r00 + k, r01 + k, r10 + k, r11 + k, dst + k);

/* the clip as a mask, no branch: about half the far pixels of a faint object are slightly
 * negative */
#define WINGCLIP_LOOP(V, VF, VI, NL)                                                       \
    const V zero_ = {0};                                                                   \
    long k = 0;                                                                            \
    for (; k + (NL) <= n; k += (NL)) {                                                     \
        VF a, b, c, d;                                                                     \
        V o, s_;                                                                           \
        VLOAD(a, r[0] + k);                                                                \
        VLOAD(b, r[1] + k);                                                                \
        VLOAD(c, r[2] + k);                                                                \
        VLOAD(d, r[3] + k);                                                                \
        o = w[0] * __builtin_convertvector(a, V) + w[1] * __builtin_convertvector(b, V) +  \
            w[2] * __builtin_convertvector(c, V) + w[3] * __builtin_convertvector(d, V);   \
        if (box) {                                                                         \
            VLOAD(a, box + k);                                                             \
            o = __builtin_convertvector(a, V) + o;                                         \
        }                                                                                  \
        VLOAD(s_, acc + k);                                                                \
        s_ += (V)((VI)o & ~(VI)(o < zero_));                                               \
        VSTORE(acc + k, s_);                                                               \
    }
#define WINGCLIP_BODY(V, VF, VI, NL, ZU)                                                   \
    WINGCLIP_LOOP(V, VF, VI, NL)                                                           \
    ZU();                                                                                  \
    wingclip_scalar(n - k, w, (const float *const[4]){r[0] + k, r[1] + k, r[2] + k, r[3] + k}, \
                    box ? box + k : NULL, acc + k);

/* Out-of-table arguments, one lane at a time. Not inlined: the vector kernels' callers are
 * built for the baseline ISA, and a call is where the compiler clears the wide registers'
 * upper halves (SSE code running with them dirty is ~3x slower on some x86 cores). */
__attribute__((noinline)) static double sersic_lane(const wf_sersic_table *t, double w)
{
    return wf_sersic4_eval(t, w);
}

static inline void no_zeroupper(void) {}

typedef double fv2 __attribute__((vector_size(16)));
typedef long long fi2 __attribute__((vector_size(16)));
typedef int fs2 __attribute__((vector_size(8)));
typedef float ff2 __attribute__((vector_size(8)));
static inline fv2 sqrt2(fv2 x) { return (fv2)_mm_sqrt_pd((__m128d)x); }
#define ANY2(b) ((b)[0] | (b)[1])
#define GATHER2(ix, c0, c1, c2, c3)                                                        \
    do {                                                                                   \
        const double *p0_ = t->v + (ix)[0], *p1_ = t->v + (ix)[1];                         \
        c0 = (fv2){p0_[0], p1_[0]};                                                        \
        c1 = (fv2){p0_[1], p1_[1]};                                                        \
        c2 = (fv2){p0_[2], p1_[2]};                                                        \
        c3 = (fv2){p0_[3], p1_[3]};                                                        \
    } while (0)
#define PGATHER2(x, p, st) ((x) = (fv2){(p)[0], (p)[st]})
static void smooth_v2(const smooth_par *sp, int ua, int n, double *rr, double *ri)
{
    SMOOTH_BODY(fv2, fi2, fs2, 2, sqrt2, no_zeroupper, ANY2, GATHER2)
}
static void latadd_v2(int n, int nw, const double *wy, const double *const *lr,
                      const double *const *li, int ua, double *runr, double *runi)
{
    LATADD_BODY(fv2, 2, no_zeroupper)
}
static void latrow_v2(const lattice *l, const double *gr, const double *gi, int ua, int ub,
                      double *ar, double *ai)
{
    LATROW_BODY(fv2, 2, no_zeroupper)
}
static void psfmul_v2(int n, const float *fr, const float *fi, size_t st, const double *runr,
                      const double *runi, double *bins)
{
    PSFMUL_BODY(fv2, ff2, fi2, 2, ((fi2){0, 2}), ((fi2){1, 3}), no_zeroupper, PGATHER2)
}
static void wing_v2(long n, double w00, double w01, double w10, double w11, const float *r00,
                    const float *r01, const float *r10, const float *r11, double *dst)
{
    WING_BODY(fv2, ff2, 2, no_zeroupper)
}
static void wingclip_v2(long n, const double *w, const float *const *r,
                           const float *box, double *acc)
{
    WINGCLIP_BODY(fv2, ff2, fi2, 2, no_zeroupper)
}

typedef double fv4 __attribute__((vector_size(32)));
typedef long long fi4 __attribute__((vector_size(32)));
typedef int fs4 __attribute__((vector_size(16)));
typedef float ff4 __attribute__((vector_size(16)));
__attribute__((target("avx2"))) static inline fv4 sqrt4(fv4 x)
{
    return (fv4)_mm256_sqrt_pd((__m256d)x);
}
#define ANY4(b) _mm_movemask_ps((__m128)(b))
/* each lane's 4 table values are adjacent: 4 loads and a 4 x 4 transpose */
#define GATHER4(ix, c0, c1, c2, c3)                                                        \
    do {                                                                                   \
        fv4 r0_, r1_, r2_, r3_;                                                            \
        VLOAD(r0_, t->v + (ix)[0]);                                                        \
        VLOAD(r1_, t->v + (ix)[1]);                                                        \
        VLOAD(r2_, t->v + (ix)[2]);                                                        \
        VLOAD(r3_, t->v + (ix)[3]);                                                        \
        fv4 a_ = __builtin_shufflevector(r0_, r1_, 0, 4, 1, 5);                            \
        fv4 b_ = __builtin_shufflevector(r2_, r3_, 0, 4, 1, 5);                            \
        c0 = __builtin_shufflevector(a_, b_, 0, 1, 4, 5);                                  \
        c1 = __builtin_shufflevector(a_, b_, 2, 3, 6, 7);                                  \
        a_ = __builtin_shufflevector(r0_, r1_, 2, 6, 3, 7);                                \
        b_ = __builtin_shufflevector(r2_, r3_, 2, 6, 3, 7);                                \
        c2 = __builtin_shufflevector(a_, b_, 0, 1, 4, 5);                                  \
        c3 = __builtin_shufflevector(a_, b_, 2, 3, 6, 7);                                  \
    } while (0)
#define PGATHER4(x, p, st)                                                                 \
    ((x) = __builtin_convertvector(                                                        \
         (ff4)_mm_i32gather_ps((p), (__m128i)((fs4){0, 1, 2, 3} * (int)(st)), 4), fv4))
__attribute__((target("avx2"))) static void smooth_v4(const smooth_par *sp, int ua, int n,
                                                      double *rr, double *ri)
{
    SMOOTH_BODY(fv4, fi4, fs4, 4, sqrt4, _mm256_zeroupper, ANY4, GATHER4)
}
__attribute__((target("avx2"))) static void
latadd_v4(int n, int nw, const double *wy, const double *const *lr, const double *const *li,
          int ua, double *runr, double *runi)
{
    LATADD_BODY(fv4, 4, _mm256_zeroupper)
}
__attribute__((target("avx2"))) static void latrow_v4(const lattice *l, const double *gr,
                                                      const double *gi, int ua, int ub,
                                                      double *ar, double *ai)
{
    LATROW_BODY(fv4, 4, _mm256_zeroupper)
}
__attribute__((target("avx2"))) static void psfmul_v4(int n, const float *fr, const float *fi,
                                                      size_t st, const double *runr,
                                                      const double *runi, double *bins)
{
    PSFMUL_BODY(fv4, ff4, fi4, 4, ((fi4){0, 4, 1, 5}), ((fi4){2, 6, 3, 7}), _mm256_zeroupper,
                PGATHER4)
}
__attribute__((target("avx2"))) static void wing_v4(long n, double w00, double w01, double w10,
                                                    double w11, const float *r00, const float *r01,
                                                    const float *r10, const float *r11, double *dst)
{
    WING_BODY(fv4, ff4, 4, _mm256_zeroupper)
}
__attribute__((target("avx2"))) static void wingclip_v4(long n, const double *w, const float *const *r,
                                                           const float *box, double *acc)
{
    WINGCLIP_BODY(fv4, ff4, fi4, 4, _mm256_zeroupper)
}

typedef double fv8 __attribute__((vector_size(64)));
typedef long long fi8 __attribute__((vector_size(64)));
typedef int fs8 __attribute__((vector_size(32)));
typedef float ff8 __attribute__((vector_size(32)));
__attribute__((target("avx512f"))) static inline fv8 sqrt8(fv8 x)
{
    return (fv8)_mm512_sqrt_pd((__m512d)x);
}
#define ANY8(b) _mm256_movemask_ps((__m256)(b))
/* 8 loads of 4 adjacent values and an 8 x 4 transpose */
#define GATHER8(ix, c0, c1, c2, c3)                                                        \
    do {                                                                                   \
        fv4 r_[8];                                                                         \
        for (int l_ = 0; l_ < 8; l_++) VLOAD(r_[l_], t->v + (ix)[l_]);                     \
        fv8 z0_ = __builtin_shufflevector(r_[0], r_[1], 0, 1, 2, 3, 4, 5, 6, 7);           \
        fv8 z1_ = __builtin_shufflevector(r_[2], r_[3], 0, 1, 2, 3, 4, 5, 6, 7);           \
        fv8 z2_ = __builtin_shufflevector(r_[4], r_[5], 0, 1, 2, 3, 4, 5, 6, 7);           \
        fv8 z3_ = __builtin_shufflevector(r_[6], r_[7], 0, 1, 2, 3, 4, 5, 6, 7);           \
        fv8 a_ = __builtin_shufflevector(z0_, z1_, 0, 4, 8, 12, 1, 5, 9, 13);              \
        fv8 b_ = __builtin_shufflevector(z2_, z3_, 0, 4, 8, 12, 1, 5, 9, 13);              \
        c0 = __builtin_shufflevector(a_, b_, 0, 1, 2, 3, 8, 9, 10, 11);                    \
        c1 = __builtin_shufflevector(a_, b_, 4, 5, 6, 7, 12, 13, 14, 15);                  \
        a_ = __builtin_shufflevector(z0_, z1_, 2, 6, 10, 14, 3, 7, 11, 15);                \
        b_ = __builtin_shufflevector(z2_, z3_, 2, 6, 10, 14, 3, 7, 11, 15);                \
        c2 = __builtin_shufflevector(a_, b_, 0, 1, 2, 3, 8, 9, 10, 11);                    \
        c3 = __builtin_shufflevector(a_, b_, 4, 5, 6, 7, 12, 13, 14, 15);                  \
    } while (0)
#define PGATHER8(x, p, st)                                                                 \
    ((x) = __builtin_convertvector(                                                        \
         (ff8)_mm256_i32gather_ps((p), (__m256i)((fs8){0, 1, 2, 3, 4, 5, 6, 7} * (int)(st)), \
                                  4),                                                      \
         fv8))
__attribute__((target("avx512f"))) static void smooth_v8(const smooth_par *sp, int ua, int n,
                                                         double *rr, double *ri)
{
    SMOOTH_BODY(fv8, fi8, fs8, 8, sqrt8, _mm256_zeroupper, ANY8, GATHER8)
}
__attribute__((target("avx512f"))) static void
latadd_v8(int n, int nw, const double *wy, const double *const *lr, const double *const *li,
          int ua, double *runr, double *runi)
{
    LATADD_BODY(fv8, 8, _mm256_zeroupper)
}
__attribute__((target("avx512f"))) static void latrow_v8(const lattice *l, const double *gr,
                                                         const double *gi, int ua, int ub,
                                                         double *ar, double *ai)
{
    LATROW_BODY(fv8, 8, _mm256_zeroupper)
}
__attribute__((target("avx512f"))) static void
psfmul_v8(int n, const float *fr, const float *fi, size_t st, const double *runr,
          const double *runi, double *bins)
{
    PSFMUL_BODY(fv8, ff8, fi8, 8, ((fi8){0, 8, 1, 9, 2, 10, 3, 11}),
                ((fi8){4, 12, 5, 13, 6, 14, 7, 15}), _mm256_zeroupper, PGATHER8)
}
__attribute__((target("avx512f"))) static void wing_v8(long n, double w00, double w01, double w10,
                                                       double w11, const float *r00, const float *r01,
                                                       const float *r10, const float *r11, double *dst)
{
    WING_BODY(fv8, ff8, 8, _mm256_zeroupper)
}
__attribute__((target("avx512f"))) static void wingclip_v8(long n, const double *w, const float *const *r,
                                                              const float *box, double *acc)
{
    WINGCLIP_LOOP(fv8, ff8, fi8, 8)
    if (k < n) { /* the last few columns (a row is ~100 wide) in one masked vector */
        const __mmask16 mf = (__mmask16)((1u << (n - k)) - 1);
        const __mmask8 md = (__mmask8)mf;
#define LOAD8F(p) (fv8) _mm512_cvtps_pd(_mm512_castps512_ps256(_mm512_maskz_loadu_ps(mf, (p))))
        fv8 o = w[0] * LOAD8F(r[0] + k) + w[1] * LOAD8F(r[1] + k) + w[2] * LOAD8F(r[2] + k) +
                w[3] * LOAD8F(r[3] + k);
        if (box) o = LOAD8F(box + k) + o;
#undef LOAD8F
        fv8 s_ = (fv8)_mm512_maskz_loadu_pd(md, acc + k);
        s_ += (fv8)((fi8)o & ~(fi8)(o < zero_));
        _mm512_mask_storeu_pd(acc + k, md, (__m512d)s_);
    }
    _mm256_zeroupper();
}
#endif

typedef struct fold_kernels {
    void (*smooth)(const smooth_par *, int, int, double *, double *);
    void (*latrow)(const lattice *, const double *, const double *, int, int, double *,
                   double *);
    void (*latadd)(int, int, const double *, const double *const *, const double *const *,
                   int, double *, double *);
    void (*psfmul)(int, const float *, const float *, size_t, const double *, const double *,
                   double *);
    void (*wing)(long, double, double, double, double, const float *, const float *, const float *,
                 const float *, double *);
    void (*wingclip)(long, const double *, const float *const *, const float *, double *);
} fold_kernels;

static fold_kernels fold_k = {smooth_scalar, latrow_scalar, latadd_scalar, psfmul_scalar, wing_scalar,
                              wingclip_scalar};
static pthread_once_t simd_once = PTHREAD_ONCE_INIT;
static int simd_lanes;

static int simd_select(int lanes)
{
    fold_k = (fold_kernels){smooth_scalar, latrow_scalar, latadd_scalar, psfmul_scalar, wing_scalar,
                            wingclip_scalar};
    int used = 0;
#if defined(FOLD_SIMD)
    __builtin_cpu_init();
    if (lanes >= 8 && __builtin_cpu_supports("avx512f")) {
        fold_k = (fold_kernels){smooth_v8, latrow_v8, latadd_v8, psfmul_v8, wing_v8,
                                wingclip_v8};
        used = 8;
    } else if (lanes >= 4 && __builtin_cpu_supports("avx2")) {
        fold_k = (fold_kernels){smooth_v4, latrow_v4, latadd_v4, psfmul_v4, wing_v4,
                                wingclip_v4};
        used = 4;
    } else if (lanes >= 2) {
        fold_k = (fold_kernels){smooth_v2, latrow_v2, latadd_v2, psfmul_v2, wing_v2,
                                wingclip_v2};
        used = 2;
    }
#endif
#if defined(KNOT_AVX)
    knot_avx = used == 8 ? 2 : used == 4 ? 1 : 0;
#endif
    return used;
}

static void simd_probe(void) { simd_lanes = simd_select(8); }

int wf_profile_simd(int lanes)
{
    pthread_once(&simd_once, simd_probe);
    if (lanes >= 0) simd_lanes = simd_select(lanes);
    return simd_lanes;
}

/* bins += run x PSF read off the table by bicubic interpolation: the table's 4 rows around
 * this v collapsed first (into pint, room for cap columns re and im), then 4 taps along u;
 * in pieces when the run spans more table columns than pint holds (same values). */
static void psf_interp(const wf_profile_psf *psf, const int *tix, const double *twx, int tiy,
                       const double *twy, int ua, int n, double *pint, int cap,
                       const double *runr, const double *runi, double *bins)
{
    const size_t side = 2 * (size_t)psf->kr + 1;
    for (int i0 = 0; i0 < n;) {
        int i1 = n; /* this piece: i0 .. i1 - 1 */
        while (tix[ua + i1 - 1] + 3 - tix[ua + i0] + 1 > cap) i1 = i0 + (i1 - i0 + 1) / 2;
        int t0 = tix[ua + i0], t1 = tix[ua + i1 - 1] + 3;
        double *cr = pint - t0, *ci = pint + cap - t0;
        for (int tt = t0; tt <= t1; tt++) {
            double sr = 0.0, si = 0.0;
            for (int b = 0; b < 4; b++) {
                size_t at = (size_t)(tiy + b) * side + (size_t)tt;
                sr += twy[b] * psf->re[at];
                si += twy[b] * psf->im[at];
            }
            cr[tt] = sr;
            ci[tt] = si;
        }
        for (int i = i0; i < i1; i++) {
            int u = ua + i;
            const double *wu = twx + 4 * (ptrdiff_t)u;
            const double *pr = cr + tix[u], *pi = ci + tix[u];
            double fr = 0.0, fi = 0.0;
            for (int c = 0; c < 4; c++) {
                fr += wu[c] * pr[c];
                fi += wu[c] * pi[c];
            }
            double rr = runr[i], ri = runi[i];
            bins[2 * i] += rr * fr - ri * fi;
            bins[2 * i + 1] += rr * fi + ri * fr;
        }
        i0 = i1;
    }
}

/* Coarse row m interpolated along u into its ring slot, at the u of the alias runs
 * fold_pass visits. */
static void lat_row(const fold_kernels *fk, lattice *l, int m, int mbox)
{
    const int wd = l->w, nh = l->nh;
    int um = lat_umax(l, m);
    if (um < 0) return;
    int slot = ((m % wd) + wd) % wd;
    double *ar = l->ar + (size_t)slot * l->al + l->U, *ai = l->ai + (size_t)slot * l->al + l->U;
    const double *gr = l->gr + (size_t)(m < 0 ? -m : m) * l->gw + nh;
    const double *gi = l->gi + (size_t)(m < 0 ? -m : m) * l->gw + nh;
    if (m < 0) { /* g(n, m) = conj g(-n, -m) */
        int ns = lat_nmax(l, m), nn = lat_nmax(l, -m);
        if (nn > ns) ns = nn;
        double *tr = l->tmp + ns, *ti = l->tmp + (2 * ns + 1) + ns;
        for (int n = -ns; n <= ns; n++) {
            tr[n] = gr[-n];
            ti[n] = -gi[-n];
        }
        gr = tr;
        gi = ti;
    }
    const int half = mbox / 2;
    for (int a = floor_div(-um, mbox); a <= floor_div(um, mbox); a++) {
        int ua = a * mbox > -um ? a * mbox : -um;
        int ub = a * mbox + half < um ? a * mbox + half : um;
        if (ua <= ub) fk->latrow(l, gr, gi, ua, ub, ar, ai);
    }
}

/* One pass over the fine grid: rows v, alias runs of u whose bins lie in the half plane.
 * The run buffer receives the object's transform (times phases) for u in [ua, ub]; it is
 * then multiplied by PSF x pixel and added into the bins. The pass adds knots knot0 ..
 * knot0 + nkb - 1, whose phase lines are in w->kx and w->ky (gd->ks entries per line, real
 * parts then imaginary); the smooth part or point source, and the knot lattice, ride with
 * knot0 <= 0 (and are alone when nkb = 0). */
static void fold_pass(wf_profile_work *w, const job *jb, const wf_profile_psf *psf,
                      const grid *gd, int us, int knot0, int nkb)
{
    const fold_kernels *fk = &fold_k;
    const int m = gd->m, half = gd->half, u_all = gd->u;
    const double dk = gd->dk;
    const double *ey = w->ey;
    double *runr = w->run, *runi = w->run + (half + 8);
    /* the PSF read by interpolation: the rest of the run buffer */
    double *pint = w->run + 2 * (size_t)(half + 8);
    const int pcap = ladder_max(w) / 2 + 8 + (ladder_max(w) / 2 - half);
    const size_t row_len = (size_t)m + 2; /* doubles per row of the in-place buffer */
    const size_t ks = gd->ks;
    /* the table, or its copy at this grid's step, which reads it contiguously */
    const float *tre = psf ? psf->re : NULL, *tim = psf ? psf->im : NULL;
    int tkr = psf ? psf->kr : 0, tst = gd->st;
    if (psf && gd->mode == MODE_EXACT && tst > 1)
        for (int i = 0; i < psf->steps.n; i++)
            if (psf->steps.st[i] == tst) {
                tre = psf->steps.re[i];
                tim = psf->steps.im[i];
                tkr = psf->steps.kr[i];
                tst = 1;
                break;
            }
    const int side = psf ? 2 * tkr + 1 : 0;
    const int smooth = knot0 <= 0;
    double ckr[WF_PROFILE_MAX_KNOTS], cki[WF_PROFILE_MAX_KNOTS];
    lattice *lat = knot0 <= 0 ? gd->lat : NULL;
    const int knots = nkb > 0 || lat;
    double wy[LAT_WMAX];
    smooth_par sp = {.qa = jb->shape.qxx * dk * dk,
                     .re2 = jb->re * jb->re,
                     .r02 = jb->r0 * jb->r0,
                     .fb = jb->fb,
                     .fd = jb->fd,
                     .fpoint = jb->fpoint,
                     .bulge = jb->fb > 0.0,
                     .disk = jb->fd > 0.0,
                     .t = w->sersic,
                     .exr = w->ex + u_all,
                     .exi = w->ex + w->cap_line + u_all};

    for (int v = -u_all; v <= u_all; v++) {
        int umax = gd->rim[abs(v)];
        int us_max = abs(v) <= us ? (int)floor(sqrt((double)us * us - (double)v * v)) : -1;
        if (!knots && us_max < 0) continue;
        const double *lr[LAT_WMAX], *li[LAT_WMAX];
        if (lat) { /* the w coarse rows this row interpolates, and their weights */
            int tv = floor_div(v, lat->r), m0 = tv - lat->w / 2 + 1;
            for (; lat->next <= m0 + lat->w - 1; lat->next++) lat_row(fk, lat, lat->next, m);
            const double *wt = lat->wt[v - tv * lat->r];
            const double sg = (v & 1) ? -1.0 : 1.0;
            for (int i = 0; i < lat->w; i++) {
                int slot = (((m0 + i) % lat->w) + lat->w) % lat->w;
                lr[i] = lat->ar + (size_t)slot * lat->al + lat->U;
                li[i] = lat->ai + (size_t)slot * lat->al + lat->U;
                wy[i] = sg * wt[i];
            }
        }
        int by = ((v % m) + m) % m;
        double *crow = w->fft + (size_t)by * row_len;
        double ky = v * dk;
        sp.qb = 2.0 * jb->shape.qxy * dk * ky;
        sp.qc = jb->shape.qyy * ky * ky;
        sp.eyr = ey[2 * (v + u_all)];
        sp.eyi = ey[2 * (v + u_all) + 1];
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
            size_t off = (size_t)(v * tst + tkr) * side + (size_t)tkr;
            er = tre + off;
            ei = tim + off;
        } else if (gd->mode == MODE_INTERP) {
            tix = w->ix + u_all;
            twx = w->wx + 4 * (size_t)u_all;
            tiy = w->iy[v + u_all];
            twy = w->wy + 4 * (size_t)(v + u_all);
        }
        /* the u range this row needs: all of the band with knots, else the smooth disk */
        int ulim = knots ? umax : us_max;
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
            if (sa > ua || sb < ub) {
                memset(runr, 0, (size_t)n * sizeof(double));
                memset(runi, 0, (size_t)n * sizeof(double));
            }
            if (sa <= sb) fk->smooth(&sp, sa, sb - sa + 1, runr + (sa - ua), runi + (sa - ua));
            if (nkb > 0) /* rounded up to whole vectors: the lines and the run have room */
                knot_sum((n + 7) & ~7, nkb, ckr, cki, w->kx + (size_t)(ua + u_all), ks, runr,
                         runi);
            if (lat) fk->latadd(n, lat->w, wy, lr, li, ua, runr, runi);
            /* times PSF x pixel, into the bins */
            double *bins = crow + 2 * (size_t)(ua - a * m);
            if (gd->mode == MODE_EXACT) {
                fk->psfmul(n, er + (ptrdiff_t)ua * tst, ei + (ptrdiff_t)ua * tst, (size_t)tst, runr,
                           runi, bins);
            } else {
                psf_interp(psf, tix, twx, tiy, twy, ua, n, pint, pcap, runr, runi, bins);
            }
        }
    }
}

/* stamp += flux x wing at (x, y): bilinear between the table's 1 / wing_os pixel samples.
 * The fractional position is the same for every pixel, so each row reads four contiguous
 * runs of the phase planes. */
/* Where flux x core's wing falls for an object at (x, y): the four phase planes around its
 * fine offset and the bilinear weights (wf_profile_wing_at). */
static void wing_place(const wf_profile_psf *psf, int core, double flux, double x, double y,
                       wf_profile_wing_at *at)
{
    const int K = psf->wing_os, h = psf->wing_half, np = psf->wing_np;
    const long plane = (long)np * np;
    /* fine index of pixel i: K (i - x) + K h = K i + s */
    double sx = K * (h - x), sy = K * (h - y);
    double fx0 = floor(sx), fy0 = floor(sy), fx = sx - fx0, fy = sy - fy0;
    long ax = (long)fx0, ay = (long)fy0;
    int a0 = (int)(ax - floor_div_l(ax, K) * K), a1 = (int)(ax + 1 - floor_div_l(ax + 1, K) * K);
    int b0 = (int)(ay - floor_div_l(ay, K) * K), b1 = (int)(ay + 1 - floor_div_l(ay + 1, K) * K);
    *at = (wf_profile_wing_at){
        .wing = psf->core[core - 1].wing,
        .np = np,
        .plane = {(b0 * K + a0) * plane, (b0 * K + a1) * plane, (b1 * K + a0) * plane,
                  (b1 * K + a1) * plane},
        .ox = {floor_div_l(ax, K), floor_div_l(ax + 1, K)},
        .oy = {floor_div_l(ay, K), floor_div_l(ay + 1, K)},
        .w = {flux * (1.0 - fy) * (1.0 - fx), flux * (1.0 - fy) * fx, flux * fy * (1.0 - fx),
              flux * fy * fx},
    };
}

static void add_wing(const wf_profile_psf *psf, int core, double flux, double x, double y,
                     wf_stamp *stamp)
{
    wf_profile_wing_at at;
    wing_place(psf, core, flux, x, y, &at);
    const long np = at.np;
    long i0 = (long)stamp->x0 > -at.ox[0] ? (long)stamp->x0 : -at.ox[0];
    long i1 = (long)stamp->x0 + stamp->nx - 1 < np - 1 - at.ox[1] ? (long)stamp->x0 + stamp->nx - 1
                                                                 : np - 1 - at.ox[1];
    if (i0 > i1) return;
    for (int yy = 0; yy < stamp->ny; yy++) {
        long j = (long)stamp->y0 + yy, ny0 = j + at.oy[0], ny1 = j + at.oy[1];
        if (ny0 < 0 || ny1 > np - 1) continue;
        /* rows of the four phase planes from the column of pixel i0 on */
        const float *r00 = at.wing + at.plane[0] + ny0 * np + (i0 + at.ox[0]);
        const float *r01 = at.wing + at.plane[1] + ny0 * np + (i0 + at.ox[1]);
        const float *r10 = at.wing + at.plane[2] + ny1 * np + (i0 + at.ox[0]);
        const float *r11 = at.wing + at.plane[3] + ny1 * np + (i0 + at.ox[1]);
        double *dst = stamp->pix + (size_t)yy * stamp->nx + (size_t)(i0 - stamp->x0);
        fold_k.wing(i1 - i0 + 1, at.w[0], at.w[1], at.w[2], at.w[3], r00, r01, r10, r11, dst);
    }
}

/* acc[i - xa] += max(box[i - ca], 0) for the columns i in [lo, hi) within [ca, cb) */
static void box_clipped(const float *box, int ca, int cb, int lo, int hi, int xa, double *acc)
{
    if (lo < ca) lo = ca;
    if (hi > cb) hi = cb;
    if (lo >= hi) return;
    const float *b = box + (lo - ca);
    double *a = acc + (lo - xa);
    int n = hi - lo, i = 0;
#if defined(FOLD_SIMD) /* two at a time, a mask for the clip: the same bits */
    const fv2 zero = {0.0, 0.0};
    for (; i + 2 <= n; i += 2) {
        ff2 bv;
        fv2 av;
        VLOAD(bv, b + i);
        VLOAD(av, a + i);
        fv2 v = __builtin_convertvector(bv, fv2);
        av += (fv2)((fi2)v & ~(fi2)(v < zero));
        VSTORE(a + i, av);
    }
#endif
    for (; i < n; i++) {
        double v = (double)b[i];
        a[i] += v < 0.0 ? 0.0 : v;
    }
}

/* add_wing's wing for one row j, summed with the box's pixels and clipped, into acc[i - xa]
 * for the columns i in [xa, xb): the columns the wing table covers in one kernel, with or
 * without box pixels, the rest box only. */
static void wing_row(const wf_profile_wing_at *at, int j, int xa, int xb, const float *box,
                     int ca, int cb, double *acc)
{
    const int np = at->np;
    const long ny0 = j + at->oy[0], ny1 = j + at->oy[1];
    if (!box) ca = cb = xa;
    /* the wing's columns: [wa, wb) */
    long i0 = xa > -at->ox[0] ? xa : -at->ox[0];
    long i1 = xb - 1 < np - 1 - at->ox[1] ? xb - 1 : np - 1 - at->ox[1];
    int wa = xa, wb = xa;
    if (i0 <= i1 && ny0 >= 0 && ny1 <= np - 1) wa = (int)i0, wb = (int)i1 + 1;
    if (at->keep_negatives) { /* the box's pixels, then the wing's, as they are */
        for (int i = ca > xa ? ca : xa; i < (cb < xb ? cb : xb); i++) acc[i - xa] += (double)box[i - ca];
        if (wa < wb) {
            const long c = wa;
            fold_k.wing(wb - wa, at->w[0], at->w[1], at->w[2], at->w[3],
                        at->wing + (at->plane[0] + ny0 * np + at->ox[0] + c),
                        at->wing + (at->plane[1] + ny0 * np + at->ox[1] + c),
                        at->wing + (at->plane[2] + ny1 * np + at->ox[0] + c),
                        at->wing + (at->plane[3] + ny1 * np + at->ox[1] + c), acc + (wa - xa));
        }
        return;
    }
    box_clipped(box, ca, cb, xa, wa, xa, acc);
    if (wa < wb) {
        /* the four phase planes' entries at column 0 (the columns before wa are never read) */
        const long e[4] = {at->plane[0] + ny0 * np + at->ox[0], at->plane[1] + ny0 * np + at->ox[1],
                           at->plane[2] + ny1 * np + at->ox[0], at->plane[3] + ny1 * np + at->ox[1]};
        int bl = ca > wa ? ca : wa, br = cb < wb ? cb : wb;
        if (bl >= br) bl = br = wb;
        const int cut[4] = {wa, bl, br, wb};
        for (int seg = 0; seg < 3; seg++) {
            int lo = cut[seg], hi = cut[seg + 1];
            if (lo >= hi) continue;
            const float *const r[4] = {at->wing + (e[0] + lo), at->wing + (e[1] + lo),
                                       at->wing + (e[2] + lo), at->wing + (e[3] + lo)};
            fold_k.wingclip(hi - lo, at->w, r, seg == 1 ? box + (lo - ca) : NULL, acc + (lo - xa));
        }
    }
    box_clipped(box, ca, cb, wb, xb, xa, acc);
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
                        double y, wf_stamp *stamp, int box_only)
{
    const wf_sersic_table *t = w->sersic;
    const double p = w->acc.pixel_scale, period = gd->m * p;
    double rfar = jb->shape.smax * galaxy_radius(jb, t, 1e-7, NULL);
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
        /* with a split PSF the stamp reaches beyond the box, where nothing wrapped in */
        if (box_only && (stamp->y0 + yy < by || stamp->y0 + yy >= by + gd->m)) continue;
        double fy = (stamp->y0 + yy - by) / h;
        int b = (int)floor(fy);
        if (b < b0) b = b0;
        if (b > b1 - 1) b = b1 - 1 >= b0 ? b1 - 1 : b0;
        double ty = fy - b;
        for (int xx = 0; xx < stamp->nx; xx++) {
            if (box_only && (stamp->x0 + xx < bx || stamp->x0 + xx >= bx + gd->m)) continue;
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

/* Negatives (ringing and rounding) set to zero, and stamp->sum and ->clipped. Eight partial
 * sums, one per lane, so that the loops run in SIMD lanes without reassociating: a single
 * running sum waits on each add (a split draw's stamp is summed in ~4 cycles a pixel, ~1.5%
 * of the GalSim scene), and about half the far pixels of a faint object are slightly
 * negative, where a branch would mispredict. The sums are diagnostics: their order is free. */
WF_CLONES static void clip_lanes(double *pix, size_t n, int clip, double *sum, double *clipped)
{
    double s[8] = {0.0}, c[8] = {0.0};
    size_t i = 0;
    if (clip) {
#if defined(__GNUC__)
        typedef double cd8 __attribute__((vector_size(64)));
        typedef long long cl8 __attribute__((vector_size(64)));
        const cd8 zero = {0.0};
        cd8 vs = zero, vc = zero;
        for (; i + 8 <= n; i += 8) {
            cd8 v;
            memcpy(&v, pix + i, sizeof v);
            cl8 neg = (cl8)(v < zero);
            cd8 keep = (cd8)((cl8)v & ~neg);
            vc -= (cd8)((cl8)v & neg);
            vs += keep;
            memcpy(pix + i, &keep, sizeof keep);
        }
        memcpy(s, &vs, sizeof vs);
        memcpy(c, &vc, sizeof vc);
#endif
        for (; i < n; i++) {
            double v = pix[i], neg = v < 0.0 ? v : 0.0;
            c[i % 8] -= neg;
            pix[i] = v - neg;
            s[i % 8] += v - neg;
        }
    } else {
        for (; i + 8 <= n; i += 8)
            for (int k = 0; k < 8; k++) s[k] += pix[i + k];
        for (; i < n; i++) s[i % 8] += pix[i];
    }
    *sum = ((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]));
    *clipped = ((c[0] + c[1]) + (c[2] + c[3])) + ((c[4] + c[5]) + (c[6] + c[7]));
}

/* keep_negatives: the renderer clips the sum of every object instead; only the sum here */
static void clip_negatives(wf_stamp *stamp, int keep_negatives)
{
    clip_lanes(stamp->pix, (size_t)stamp->nx * stamp->ny, !keep_negatives, &stamp->sum, &stamp->clipped);
}

/* wing 0 leaves a split draw's wing to the caller (wf_profile_add_wing); plan non-NULL
 * only decides: plan[0] the core taken (0: none, else its index + 1), plan[1] the FFT
 * side; nothing is drawn. */
static wf_status draw_job(wf_profile_work *w, const job *jb, const wf_profile_psf *psf,
                          double x, double y, wf_stamp *stamp, int wing, int *plan)
{
    wf_status st = check_position(x, y);
    if (st) return st;
    if (psf && fabs(psf->pixel_scale - w->acc.pixel_scale) > 1e-12 * w->acc.pixel_scale)
        return wf_error(WF_ERR_INPUT, "profile: PSF prepared for %g arcsec pixels, drawing "
                        "at %g", psf->pixel_scale, w->acc.pixel_scale);
    if (!psf && plan) {
        plan[0] = 0, plan[1] = 0;
        return WF_OK;
    }
    if (!psf) return draw_nopsf(w, jb, x, y, stamp);
    (void)wf_profile_simd(-1); /* the kernels, once per process */
    const wf_sersic_table *t = w->sersic;
    const double p = w->acc.pixel_scale;
    grid gd;
    memset(&gd, 0, sizeof gd);
    gd.ic = (int)lround(x);
    gd.jc = (int)lround(y);
    gd.dx = (x - gd.ic) * p;
    gd.dy = (y - gd.jc) * p;
    gd.lat_exp = -log(w->acc.knot_accuracy);

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
    /* With a split PSF the box of an extended object whose wing error bound is tolerated
     * holds object x core only, whose light ends at the core radius; the stamp's pixels
     * beyond the box get the wing alone. Of the cores it tolerates, the smallest (the
     * smallest box). Other objects take the whole table (a point source would gain nothing:
     * its box is set by the PSF either way). split: the core's index + 1, or 0. */
    wf_profile_psf view;
    int split = 0;
    if (jb->fpoint == 0.0)
        for (int c = psf->ncore; c >= 1 && !split; c--)
            if (2.0 * jb->flux * psf->core[c - 1].wing_max < w->acc.wing_tolerance) split = c;
    if (split) {
        view = *psf;
        view.re = psf->core[split - 1].re;
        view.im = psf->core[split - 1].im;
        view.steps = psf->core[split - 1].steps;
        view.env = psf->core[split - 1].env;
        psf = &view;
    }
    double rfold = object_radius(jb, t, psf, w->acc.folding_threshold, split);
    double rown = split ? 0.0 : object_radius(jb, t, psf, 1.0 - w->acc.flux_fraction, 0);
    double need_fold = 2.0 * ceil(fmax(rfold, rown) / p) + 2.0;
    int mi = choose_size(w, psf, split ? need_fold : fmax((double)need, need_fold));
    gd.m = w->sizes[mi];
    if (plan) {
        plan[0] = split, plan[1] = gd.m;
        return WF_OK;
    }
    if (!wing && !split)
        return wf_error(WF_ERR_INPUT, "profile: a core-only draw of an object that does not take the "
                        "split PSF with these knobs (wf_profile_galaxy_core says which do)");
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
    const double dkt = 2.0 * M_PI / (psf->table_fft * psf->pixel_scale);
    const double kcs = psf_kcut(jb, t, psf, w->acc.kvalue_accuracy, 0);
    const double kck = gd.nk ? psf_kcut(jb, t, psf, w->acc.kvalue_accuracy, 1) : 0.0;
    double ksmooth = fmin(kband, kcs);
    double kknots = gd.nk ? fmin(kband, kck) : 0.0;
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
    if (w->acc.cut_tolerance > 0.0) { /* half the tolerance each when there are knots */
        double tol = (gd.nk ? 0.5 : 1.0) * w->acc.cut_tolerance;
        /* the floor's search starts at the pointwise cut's ring when kvalue_accuracy <=
         * WF_PROFILE_CUT_KEEP (nothing beyond it is above the floor then) */
        const int above = w->acc.kvalue_accuracy <= WF_PROFILE_CUT_KEEP;
        int js = tail_cut(jb, t, psf, gd.dk, gd.m, us, tol, 0);
        if (js < us) {
            int from = above ? (int)lround(kcs / dkt) : psf->kr;
            int keep = (int)floor(psf_kcut_from(jb, t, psf, WF_PROFILE_CUT_KEEP, 0, from) / gd.dk);
            us = js > keep ? js : keep < us ? keep : us;
        }
        if (gd.nk) {
            int jk = tail_cut(jb, t, psf, gd.dk, gd.m, uk, tol, 1);
            if (jk < uk) {
                int from = above ? (int)lround(kck / dkt) : psf->kr;
                int keep = (int)floor(psf_kcut_from(jb, t, psf, WF_PROFILE_CUT_KEEP, 1, from) / gd.dk);
                uk = jk > keep ? jk : keep < uk ? keep : uk;
            }
        }
    }
    gd.u = us > uk ? us : uk;
    w->cut_last[0] = us;
    w->cut_last[1] = uk;

    for (int v = 0; v <= gd.u; v++) w->rim[v] = (int)floor(sqrt((double)gd.u * gd.u - (double)v * v));
    gd.rim = w->rim;
    phase_line_to(gd.dk * gd.dx, gd.u, w->ex, w->ex + w->cap_line, 1);
    phase_line(gd.dk * gd.dy, gd.u, w->ey);
    if (gd.mode == MODE_INTERP) {
        double ratio = (double)psf->table_fft / gd.m;
        for (int u = -gd.u; u <= gd.u; u++) {
            cubic_taps(u * ratio, psf->kr, &w->ix[u + gd.u], &w->wx[4 * (u + gd.u)]);
            cubic_taps(u * ratio, psf->kr, &w->iy[u + gd.u], &w->wy[4 * (u + gd.u)]);
        }
    }

    memset(w->fft, 0, (size_t)gd.m * (gd.m + 2) * sizeof(double));
    /* knots: the inner ones on a lattice where that costs less, the outer few (whose extent
     * would make the lattice fine) and all others summed directly */
    lattice lat;
    int nd = gd.nk; /* summed directly: the first nd of knot_box */
    w->knot_last[0] = w->knot_last[1] = 0;
    if (gd.nk && w->knot_method != WF_KNOTS_DIRECT && knot_plan(w, &gd, p, &lat)) {
        nd = gd.nk - lat.nk;
        lat_build(w, jb, &gd, &lat);
        gd.lat = &lat;
        w->knot_last[0] = lat.r;
        w->knot_last[1] = lat.w;
    }
    w->knot_last[2] = nd;
    if (!nd) {
        fold_pass(w, jb, psf, &gd, us, gd.lat ? 0 : -1, 0);
    } else {
        /* as many knots per pass as the phase-line buffers hold (all of them but for the
         * largest boxes): each pass multiplies by the PSF once */
        size_t len = 2 * (size_t)gd.u + 1;
        gd.ks = ((len + 3) & ~(size_t)3) + 8; /* room for knot_sum's rounding up */
        size_t room = (size_t)WF_PROFILE_KNOT_BLOCK * (size_t)w->cap_line / gd.ks;
        int per = room > (size_t)WF_PROFILE_MAX_KNOTS ? WF_PROFILE_MAX_KNOTS : (int)room;
        if (per < 1) per = 1;
        for (int k0 = 0; k0 < nd; k0 += per) {
            int nkb = nd - k0 < per ? nd - k0 : per;
            double thx[WF_PROFILE_MAX_KNOTS], thy[WF_PROFILE_MAX_KNOTS];
            for (int j = 0; j < nkb; j++) {
                const double *kp = gd.kpos + 2 * (size_t)(k0 + j);
                thx[j] = gd.dk * (kp[0] + gd.dx);
                thy[j] = gd.dk * (kp[1] + gd.dy);
            }
            wf_profile_phase_lines(nkb, thx, -gd.u, gd.u, w->kx, 2 * gd.ks, gd.ks, 1, 1);
            wf_profile_phase_lines(nkb, thy, -gd.u, gd.u, w->ky, 2 * gd.ks, gd.ks, 1, 1);
            /* the smooth part and the lattice ride with pass 0 */
            fold_pass(w, jb, psf, &gd, us, k0, nkb);
        }
    }
    wf_status pst = draw_plan(w, mi);
    if (pst) return pst;
    fftw_execute_dft_c2r((fftw_plan)w->plans[mi], (fftw_complex *)w->fft, w->fft);

    const double norm = 1.0 / ((double)gd.m * gd.m);
    /* the box's pixels within the stamp (all of it unless the PSF is split) */
    long bx0 = (long)gd.ic - gd.half, by0 = (long)gd.jc - gd.half;
    long xa = (long)stamp->x0 > bx0 ? (long)stamp->x0 : bx0;
    long xb = (long)stamp->x0 + stamp->nx < bx0 + gd.m ? (long)stamp->x0 + stamp->nx : bx0 + gd.m;
    for (int yy = 0; yy < stamp->ny; yy++) {
        double *dst = stamp->pix + (size_t)yy * stamp->nx;
        long yb = (long)stamp->y0 + yy - by0;
        if (yb < 0 || yb >= gd.m || xa >= xb) {
            memset(dst, 0, (size_t)stamp->nx * sizeof(double));
            continue;
        }
        const double *src = w->fft + (size_t)yb * (gd.m + 2) + (size_t)(xa - bx0);
        for (long xx = stamp->x0; xx < xa; xx++) dst[xx - stamp->x0] = 0.0;
        for (long xx = xa; xx < xb; xx++) dst[xx - stamp->x0] = src[xx - xa] * norm;
        for (long xx = xb; xx < (long)stamp->x0 + stamp->nx; xx++) dst[xx - stamp->x0] = 0.0;
    }
    if (split && wing) add_wing(psf, split, jb->flux, x, y, stamp);
    if (clamped && jb->fpoint == 0.0 && (st = dewrap(w, jb, &gd, x, y, stamp, split))) return st;
    clip_negatives(stamp, w->keep_negatives);
    stamp->fft = gd.m;
    return WF_OK;
}

void wf_profile_knot_method(wf_profile_work *work, int method) { work->knot_method = method; }

void wf_profile_keep_negatives(wf_profile_work *work, int keep) { work->keep_negatives = keep != 0; }

wf_status wf_profile_work_tune_cut(wf_profile_work *work, double cut_tolerance)
{
    wf_profile_accuracy acc = work->acc;
    acc.cut_tolerance = cut_tolerance;
    wf_status st = wf_profile_check_accuracy(&acc);
    if (st) return st;
    work->acc = acc;
    return WF_OK;
}

wf_status wf_profile_work_tune(wf_profile_work *work, double flux_fraction,
                               double folding_threshold, double kvalue_accuracy,
                               double wing_tolerance, double knot_accuracy)
{
    wf_profile_accuracy acc = work->acc;
    acc.flux_fraction = flux_fraction;
    acc.folding_threshold = folding_threshold;
    acc.kvalue_accuracy = kvalue_accuracy;
    acc.wing_tolerance = wing_tolerance;
    acc.knot_accuracy = knot_accuracy;
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

/* A galaxy's stamp, its split PSF's wing included or (wing 0) left to the caller. */
static wf_status draw_galaxy(wf_profile_work *work, const wf_galaxy *g, const wf_profile_psf *psf,
                             double x, double y, wf_stamp *stamp, int wing)
{
    wf_status st = check_stamp(stamp);
    if (st) return st;
    job jb;
    if ((st = galaxy_job(work, g, &jb)) || (st = check_position(x, y))) return st;
    if (jb.flux == 0.0) {
        clear_stamp(stamp);
        return WF_OK;
    }
    return draw_job(work, &jb, psf, x, y, stamp, wing, NULL);
}

wf_status wf_profile_draw_galaxy(wf_profile_work *work, const wf_galaxy *g,
                                 const wf_profile_psf *psf, double x, double y,
                                 wf_stamp *stamp)
{
    return draw_galaxy(work, g, psf, x, y, stamp, 1);
}

wf_status wf_profile_galaxy_core(wf_profile_work *work, const wf_galaxy *g,
                                 const wf_profile_psf *psf, double x, double y,
                                 wf_stamp *bounds, wf_stamp *box, int *core)
{
    if (!g) return wf_error(WF_ERR_INPUT, "profile: no galaxy given");
    job jb;
    wf_galaxy lit = *g;
    if (lit.flux == 0.0) lit.flux = 1.0; /* as wf_profile_galaxy_bounds */
    wf_status st = galaxy_job(work, &lit, &jb);
    if (st || (st = bounds_for(work, &jb, psf, x, y, bounds, NULL))) return st;
    int plan[2];
    wf_stamp b = *bounds;
    if ((st = draw_job(work, &jb, psf, x, y, &b, 1, plan))) return st;
    *box = *bounds;
    *core = g->flux > 0.0 ? plan[0] : 0;
    if (*core) { /* the FFT box [ic - M/2, ic + M/2) within the bounds */
        long ic = lround(x), jc = lround(y), h = plan[1] / 2;
        long x0 = ic - h > bounds->x0 ? ic - h : bounds->x0;
        long y0 = jc - h > bounds->y0 ? jc - h : bounds->y0;
        long x1 = ic + h < (long)bounds->x0 + bounds->nx ? ic + h : (long)bounds->x0 + bounds->nx;
        long y1 = jc + h < (long)bounds->y0 + bounds->ny ? jc + h : (long)bounds->y0 + bounds->ny;
        box->x0 = (int)x0, box->y0 = (int)y0;
        box->nx = (int)(x1 - x0), box->ny = (int)(y1 - y0);
    }
    return WF_OK;
}

wf_status wf_profile_draw_galaxy_core(wf_profile_work *work, const wf_galaxy *g,
                                      const wf_profile_psf *psf, double x, double y,
                                      wf_stamp *stamp)
{
    return draw_galaxy(work, g, psf, x, y, stamp, 0);
}

/* A wing at (x, y) from that core of the PSF; makes sure the kernels are chosen. */
static wf_status check_wing(const wf_profile_psf *psf, int core, double x, double y)
{
    wf_status st = check_position(x, y);
    if (st) return st;
    if (!psf || core < 1 || core > psf->ncore)
        return wf_error(WF_ERR_INPUT, "profile: core %d: a wing needs a PSF split into that many "
                        "cores (it has %d)", core, psf ? psf->ncore : 0);
    (void)wf_profile_simd(-1); /* the kernels, once per process */
    return WF_OK;
}

wf_status wf_profile_add_wing(const wf_profile_psf *psf, int core, double flux, double x,
                              double y, wf_stamp *stamp)
{
    wf_status st = check_stamp(stamp);
    if (st || (st = check_wing(psf, core, x, y))) return st;
    add_wing(psf, core, flux, x, y, stamp);
    return WF_OK;
}

wf_status wf_profile_wing_place(const wf_profile_psf *psf, int core, double flux, double x,
                                double y, wf_profile_wing_at *at)
{
    wf_status st = check_wing(psf, core, x, y);
    if (st) return st;
    wing_place(psf, core, flux, x, y, at);
    return WF_OK;
}

wf_status wf_profile_add_wing_row(const wf_profile_wing_at *at, int row, int xa, int xb,
                                  const float *box, int ca, int cb, double *acc)
{
    if (!at->wing || xb < xa || (box && (ca < xa || cb > xb || cb < ca)))
        return wf_error(WF_ERR_INPUT, "profile: wing row columns [%d, %d) with box columns "
                        "[%d, %d) not within them, or no wing placed", xa, xb, ca, cb);
    wing_row(at, row, xa, xb, box, ca, cb, acc);
    return WF_OK;
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
    return draw_job(work, &jb, psf, x, y, stamp, 1, NULL);
}
