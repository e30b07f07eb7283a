/* The PSF image's Fourier transform times the pixel's, tabulated once per PSF.
 *
 * The table's k spacing is dk_t = 2 pi / (table_fft * pixel): an FFT box of M pixels with M
 * dividing table_fft reads it at every (table_fft / M)-th entry, exactly. Sampling the
 * transform at dk_t is the same as periodising the image with period table_fft * pixel, so
 * the samples are exact whatever the image's size: with the image sampled at pixel / os
 * (integer os), one real FFT of side os * table_fft of the image folded onto that period
 * gives them (the fast path); any other sampling uses a direct separable DFT (slow, once).
 *
 * The table stops at the image's band_limit (the optical transform is zero beyond 2 pi D /
 * lambda; what an image holds beyond is resampling artifact, truncation ripple and float32
 * rounding) or, without one, where |PSF(k) pixel(k)| falls below WF_PSF_KFLOOR of the flux. */
#include <fftw3.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"
#include "sim/numeric/fftw_lock.h"
#include "sim/numeric/parallel.h"

#define WF_PSF_KFLOOR 1e-7
#define WF_PSF_TAPER 0.1
/* The wing table's samples per pixel: bilinear reads of the pixel-convolved wing, whose
 * strongest frequencies (~1.2 cycles per pixel at Y106, already damped ~10x by the pixel)
 * then lose ~10% of their small amplitude. */
#define WING_OS 8

/* 1 below (1 - WF_PSF_TAPER) band, 0 beyond band, a raised cosine between. A hard cut where
 * an image's transform still holds ~1e-3 (GalSim's OVER4: resampling artifacts) rings at
 * ~1e-6 of the peak across the stamp, and clipping that ringing adds 2e-4 (63^2 stamp) to
 * 1e-3 (511^2) of the flux; the taper brings it to 7e-5 .. 1e-4 and moves the comparison
 * with GalSim's stamps by < 1e-4 of the peak. */
static double band_taper(double k, double band)
{
    double k1 = (1.0 - WF_PSF_TAPER) * band;
    if (k <= k1) return 1.0;
    if (k >= band) return 0.0;
    return 0.5 * (1.0 + cos(M_PI * (k - k1) / (band - k1)));
}

static double sinc(double x) { return fabs(x) < 1e-4 ? 1.0 - x * x / 6.0 : sin(x) / x; }

/* os when the image is sampled at pixel / os for an integer os, else 0. */
static int integer_oversampling(double pixel, double scale)
{
    double os = pixel / scale;
    double r = round(os);
    return r >= 1.0 && fabs(os - r) < 1e-9 * os && r <= 64.0 ? (int)r : 0;
}

static wf_status check_image(const wf_psf_image *img, double *sum)
{
    if (!img || !img->pix)
        return wf_error(WF_ERR_INPUT, "profile: no PSF image given");
    if (img->n < 2 || img->n > 16384)
        return wf_error(WF_ERR_RANGE, "profile: PSF image side %d outside [2, 16384]", img->n);
    if (!(img->band_limit >= 0.0) || !isfinite(img->band_limit))
        return wf_error(WF_ERR_RANGE, "profile: PSF band limit %g is not >= 0", img->band_limit);
    if (!(img->scale_arcsec > 0.0) || !isfinite(img->scale_arcsec))
        return wf_error(WF_ERR_RANGE, "profile: PSF sample spacing %g arcsec is not positive",
                        img->scale_arcsec);
    double s = 0.0;
    size_t nn = (size_t)img->n * (size_t)img->n;
    for (size_t i = 0; i < nn; i++) {
        if (!isfinite(img->pix[i]))
            return wf_error(WF_ERR_INPUT, "profile: PSF image sample %zu is not finite", i);
        s += img->pix[i];
    }
    if (!(s > 0.0))
        return wf_error(WF_ERR_INPUT, "profile: PSF image sums to %g, not a positive flux", s);
    *sum = s;
    return WF_OK;
}

/* Half-width of the raw transform the sampling supports, in table steps. */
static int sampling_kr(const wf_psf_image *img, const wf_profile_accuracy *acc)
{
    double dkt = 2.0 * M_PI / (acc->psf_table_fft * acc->pixel_scale);
    double knyq = M_PI / img->scale_arcsec;
    double kcap = WF_PSF_BAND_NYQ * M_PI / acc->pixel_scale; /* what the draws can use */
    int kr = (int)floor(fmin(knyq, kcap) / dkt);
    int os = integer_oversampling(acc->pixel_scale, img->scale_arcsec);
    if (os) {
        int half = os * acc->psf_table_fft / 2 - 1;
        if (kr > half) kr = half;
    }
    return kr;
}

static size_t ee_count(const wf_psf_image *img)
{
    return (size_t)(0.5 * img->n * 1.4142135623730951 * 2.0) + 4; /* bins of scale / 2 */
}

/* Core and wing (sim/draw/profile.h). The wing lies within the image (plus half a pixel), so
 * its transform needs samples only every q-th table step: period lw = table_fft / q pixels
 * at least twice its extent; one c2r FFT of side WING_OS lw gives it every 1/WING_OS pixel. */
typedef struct split_geom {
    int h, np, q, lw, nfft;
} split_geom;

/* A real-space table of half-width h pixels, os samples a pixel (the wing's or a core's
 * knot table): np samples a row, and its c2r from every q-th table step, the largest q whose
 * period lw = table_fft / q holds it twice and 8 pixels more. */
static void table_layout(const wf_profile_accuracy *acc, int h, int os, split_geom *g)
{
    g->h = h;
    g->np = 2 * h + 2;
    g->q = 1;
    for (int q = acc->psf_table_fft / 2; q > 1; q--)
        if (acc->psf_table_fft % q == 0 && acc->psf_table_fft / q >= 2 * h + 8) {
            g->q = q;
            break;
        }
    g->lw = acc->psf_table_fft / g->q;
    g->nfft = os * g->lw;
}

static void split_layout(const wf_psf_image *img, const wf_profile_accuracy *acc, split_geom *g)
{
    double p = acc->pixel_scale;
    table_layout(acc, (int)ceil((0.5 * (img->n - 1) * img->scale_arcsec + 0.5 * p) / p) + 1, WING_OS, g);
}

/* The core's own real-space table (knots), KNOT_OS samples a pixel: its light ends at the
 * radius (taper), widened by the pixel's half; one pixel more for the bilinear reading's
 * second sample. */
#define KNOT_OS 16
static void knot_layout(const wf_profile_accuracy *acc, double radius, split_geom *g)
{
    table_layout(acc, (int)ceil(radius / acc->pixel_scale + 0.5) + 1, KNOT_OS, g);
}

/* The bilinear reading of e^{i theta t} between t = 0 and 1 (samples 1 / KNOT_OS pixel apart)
 * is off by at most theta^2 t (1 - t) / 2 <= theta^2 / 8: the error g has g(0) = g(1) = 0 and
 * |g''| = theta^2 (the interpolation's Green's function is >= 0 and integrates to
 * t (1 - t) / 2), which holds for complex values too. A 2-D reading of e^{i(a x + b y)} is off
 * by at most e(a) + e(b), since each axis's reading has modulus <= 1. */
static double bilinear_err(int u, int table_fft)
{
    double theta = 2.0 * M_PI * u / ((double)table_fft * KNOT_OS);
    return fmin(theta * theta / 8.0, 2.0);
}

/* 1 within 2/3 of the core radius, a raised cosine to 0 at it: smooth, so the core's
 * transform spreads little beyond the PSF's band. */
static double core_taper(double r, double rc)
{
    double r1 = rc * (2.0 / 3.0);
    if (r <= r1) return 1.0;
    if (r >= rc) return 0.0;
    return 0.5 * (1.0 + cos(M_PI * (r - r1) / (rc - r1)));
}

/* The steps st > 1 at which the draws read table `which` (of wf_profile_table_periods) exactly:
 * P / M for the ladder's sides M below its period P that read it, ascending. */
static int table_steps(const wf_profile_accuracy *acc, int which, int *st)
{
    int sizes[48], n = wf_profile_fft_ladder(acc, sizes, 48), k = 0;
    int per[1 + WF_PROFILE_MAX_ALT], np = wf_profile_table_periods(acc, per);
    for (int i = n - 1; i >= 0 && k < WF_PROFILE_MAX_STEPS; i--)
        if (sizes[i] < per[which] && wf_profile_table_of(per, np, sizes[i]) == which)
            st[k++] = per[which] / sizes[i];
    return k;
}

/* Arena bytes of one table's copies at its steps, for a table of |k| <= kr steps. */
static size_t steps_bytes(const wf_profile_accuracy *acc, int which, int kr)
{
    int st[WF_PROFILE_MAX_STEPS], n = table_steps(acc, which, st);
    size_t bytes = 0;
    for (int i = 0; i < n; i++) {
        size_t side = 2 * (size_t)(kr / st[i]) + 1;
        bytes += 2 * wf_arena_cost(side * side * sizeof(float));
    }
    return bytes;
}

static wf_status steps_alloc(wf_arena *arena, const wf_profile_accuracy *acc, int which, int kr, wf_profile_steps *s)
{
    s->n = table_steps(acc, which, s->st);
    for (int i = 0; i < s->n; i++) {
        s->kr[i] = kr / s->st[i];
        size_t side = 2 * (size_t)s->kr[i] + 1;
        wf_status st;
        if ((st = wf_arena_reserve(arena, side * side * sizeof(float), "PSF table step copy", (void **)&s->re[i])) ||
            (st = wf_arena_reserve(arena, side * side * sizeof(float), "PSF table step copy", (void **)&s->im[i])))
            return st;
    }
    return WF_OK;
}

/* The half-width in its own steps of the table at period P that holds what the main one's
 * kr steps (less its 2 steps of room for the bicubic taps) hold; within the sampling. It may
 * reach ~1.4 main steps past kr, beyond the envelope's last ring: samples there are below
 * WF_PSF_KFLOOR (kr was found from where they end), which the cuts treat as zero. */
static int alt_kr(const wf_psf_image *img, const wf_profile_accuracy *acc, int P, int kr)
{
    wf_profile_accuracy a = *acc;
    a.psf_table_fft = P;
    int k = (int)ceil((kr - 2) * (double)P / acc->psf_table_fft) + 1, ks = sampling_kr(img, &a);
    return k < ks ? k : ks;
}

/* Arena bytes of one pass's tables at the other periods, |k| <= kr main steps. */
static size_t alt_bytes(const wf_psf_image *img, const wf_profile_accuracy *acc, int kr)
{
    int per[1 + WF_PROFILE_MAX_ALT], np = wf_profile_table_periods(acc, per);
    size_t bytes = 0;
    for (int i = 1; i < np; i++) {
        int k = alt_kr(img, acc, per[i], kr);
        size_t side = 2 * (size_t)k + 1;
        bytes += 2 * wf_arena_cost(side * side * sizeof(float)) + steps_bytes(acc, i, k);
    }
    return bytes;
}

static wf_status alt_alloc(wf_arena *arena, const wf_psf_image *img, const wf_profile_accuracy *acc, int kr,
                           wf_profile_table *alt)
{
    int per[1 + WF_PROFILE_MAX_ALT], np = wf_profile_table_periods(acc, per);
    for (int i = 1; i < np; i++) {
        wf_profile_table *t = &alt[i - 1];
        t->fft = per[i];
        t->kr = alt_kr(img, acc, per[i], kr);
        size_t side = 2 * (size_t)t->kr + 1;
        wf_status st;
        if ((st = wf_arena_reserve(arena, side * side * sizeof(float), "PSF table at another period", (void **)&t->re)) ||
            (st = wf_arena_reserve(arena, side * side * sizeof(float), "PSF table at another period", (void **)&t->im)) ||
            (st = steps_alloc(arena, acc, i, t->kr, &t->steps)))
            return st;
    }
    return WF_OK;
}

/* Every copy filled from its table (|k| <= kr steps). */
static void steps_fill(const float *re, const float *im, int kr, wf_profile_steps *s)
{
    const size_t side = 2 * (size_t)kr + 1;
    for (int i = 0; i < s->n; i++) {
        const int st = s->st[i], kd = s->kr[i];
        const size_t sd = 2 * (size_t)kd + 1;
        for (int v = -kd; v <= kd; v++)
            for (int u = -kd; u <= kd; u++) {
                size_t from = (size_t)(v * st + kr) * side + (size_t)(u * st + kr);
                size_t to = (size_t)(v + kd) * sd + (size_t)(u + kd);
                s->re[i][to] = re[from];
                s->im[i][to] = im[from];
            }
    }
}

static size_t transform_fft_bytes(int n, int np, int kr); /* below, with transform_fft */

wf_status wf_profile_psf_need(const wf_psf_image *img, const wf_profile_accuracy *acc,
                              size_t *bytes, size_t *scratch)
{
    double sum;
    wf_status st = wf_profile_check_accuracy(acc);
    if (st || (st = check_image(img, &sum))) return st;
    int kr = sampling_kr(img, acc);
    size_t side = 2 * (size_t)kr + 1;
    /* an upper bound: the table is trimmed to the PSF's band once it is known */
    *bytes = 2 * wf_arena_cost(side * side * sizeof(float)) + steps_bytes(acc, 0, kr) + alt_bytes(img, acc, kr) +
             wf_arena_cost(ee_count(img) * sizeof(double)) +
             wf_arena_cost(((size_t)kr + 2) * sizeof(double));
    /* the transform and the pixel's sinc line */
    *scratch = wf_arena_cost(side * side * 2 * sizeof(double)) + wf_arena_cost(side * sizeof(double));
    if (acc->core_radius > 0.0) {
        split_geom g;
        split_layout(img, acc, &g);
        *bytes += (size_t)acc->core_levels *
                  (2 * wf_arena_cost(side * side * sizeof(float)) + steps_bytes(acc, 0, kr) + alt_bytes(img, acc, kr) +
                   wf_arena_cost(((size_t)kr + 2) * sizeof(double)) +
                   wf_arena_cost((size_t)WING_OS * WING_OS * (size_t)g.np * (size_t)g.np *
                                 sizeof(float)));
        split_geom kg; /* the largest core's */
        knot_layout(acc, acc->core_radius, &kg);
        *bytes += (size_t)acc->core_levels *
                  (wf_arena_cost((size_t)KNOT_OS * KNOT_OS * (size_t)kg.np * (size_t)kg.np * sizeof(float)) +
                   2 * wf_arena_cost((size_t)kg.np * sizeof(double)));
        /* the tapered image while the core is transformed, the wing's FFT while the whole
         * is */
        size_t taper = wf_arena_cost((size_t)img->n * (size_t)img->n * sizeof(double));
        const size_t nf = (size_t)(g.nfft > kg.nfft ? g.nfft : kg.nfft);
        size_t fft = wf_arena_cost(nf * (nf + 2) * sizeof(double)) +
                     wf_arena_cost(((size_t)kg.np + 1) * ((size_t)kg.np + 1) * sizeof(double));
        *scratch += taper > fft ? taper : fft;
    }
    int os = integer_oversampling(acc->pixel_scale, img->scale_arcsec);
    if (os) {
        *scratch += transform_fft_bytes(img->n, os * acc->psf_table_fft, kr);
    } else {
        *scratch += wf_arena_cost((size_t)img->n * side * 2 * sizeof(double)) +
                    wf_arena_cost(side * 2 * sizeof(double));
    }
    return WF_OK;
}

/* Raw transform R[v][u] (complex, side x side, centred) of the image folded onto np x np,
 * np = os table_fft. Only |u|, |v| <= kr of the np^2 frequencies are wanted (kr ~ np / 6 at
 * Y106) and only the image's n rows can be nonzero (n < np), so the 2-D transform is taken
 * as its two passes, pruned: each nonzero row's r2c, of which u = 0..kr is kept, then the
 * kept columns' c2c, of which |v| <= kr is kept; RB rows and CB columns at a time, so the
 * scratch is the kept rows (n (kr + 1) complex) and two small blocks instead of the full
 * np^2 plane (19 MB at Y106, fresh memory for every thread slot). */
enum { TRANSFORM_RB = 16, TRANSFORM_CB = 16 };

/* The image's samples [i0, i1) x [j0, j1) (columns x rows) outside which it is zero. */
typedef struct support {
    int i0, i1, j0, j1;
} support;

static size_t transform_fft_bytes(int n, int np, int kr)
{
    size_t nz = (size_t)(n < np ? n : np), half = (size_t)np / 2 + 1;
    return wf_arena_cost(nz * ((size_t)kr + 1) * 2 * sizeof(double)) +
           wf_arena_cost((size_t)TRANSFORM_RB * 2 * half * sizeof(double)) +
           wf_arena_cost((size_t)np * TRANSFORM_CB * 2 * sizeof(double)) +
           wf_arena_cost((2 * (size_t)kr + 1) * 2 * sizeof(double));
}

static wf_status transform_fft(const wf_psf_image *img, const support *sp, int os, int table_fft, int kr,
                               wf_arena *arena, double *out)
{
    const int np = os * table_fft, n = img->n, nz = n < np ? n : np;
    /* only the support's samples are read; an image no wider than the period folds no rows,
     * so a block of rows outside the support is zero, and so are its transforms */
    const int fold = n > np, j0s = fold ? 0 : sp->j0, j1s = fold ? nz : sp->j1;
    const size_t half = (size_t)np / 2 + 1, rowlen = 2 * half, ku = (size_t)kr + 1;
    if (kr > np / 2 - 1) return wf_error(WF_ERR_INTERNAL, "profile: PSF window %d beyond %d / 2", kr, np);
    double *a, *rows, *cols;
    wf_status st;
    if ((st = wf_arena_reserve(arena, (size_t)nz * ku * 2 * sizeof(double), "PSF transform rows", (void **)&a)) ||
        (st = wf_arena_reserve(arena, (size_t)TRANSFORM_RB * rowlen * sizeof(double), "PSF transform row block",
                               (void **)&rows)) ||
        (st = wf_arena_reserve(arena, (size_t)np * TRANSFORM_CB * 2 * sizeof(double), "PSF transform column block",
                               (void **)&cols)))
        return st;
    const int len[1] = {np};
    /* no buffered passes, whose buffers each execution allocates (as the draws' plans,
     * sim/draw/profile_work.c's draw_plan_flags) */
    wf_fftw_lock();
    fftw_plan pr = fftw_plan_many_dft_r2c(1, len, TRANSFORM_RB, rows, NULL, 1, (int)rowlen, (fftw_complex *)rows,
                                          NULL, 1, (int)half, FFTW_ESTIMATE | FFTW_NO_BUFFERING);
    fftw_plan pc = fftw_plan_many_dft(1, len, TRANSFORM_CB, (fftw_complex *)cols, NULL, TRANSFORM_CB, 1,
                                      (fftw_complex *)cols, NULL, TRANSFORM_CB, 1, FFTW_FORWARD, FFTW_ESTIMATE | FFTW_NO_BUFFERING);
    wf_fftw_unlock();
    if (!pr || !pc) {
        wf_fftw_lock();
        if (pr) fftw_destroy_plan(pr);
        if (pc) fftw_destroy_plan(pc);
        wf_fftw_unlock();
        return wf_error(WF_ERR_INTERNAL, "profile: FFTW could not plan %d-point transforms", np);
    }
    /* rows: image row j and its images j + np, j + 2 np, ... folded onto row j mod np */
    for (int j0 = 0; j0 < nz; j0 += TRANSFORM_RB) {
        if (j0 + TRANSFORM_RB <= j0s || j0 >= j1s) {
            for (int r = 0; r < TRANSFORM_RB && j0 + r < nz; r++)
                memset(a + (size_t)(j0 + r) * ku * 2, 0, ku * 2 * sizeof(double));
            continue;
        }
        for (int r = 0; r < TRANSFORM_RB; r++) {
            double *row = rows + (size_t)r * rowlen;
            for (int i = 0; i < np; i++) row[i] = 0.0;
            for (int jj = j0 + r; jj < n && j0 + r < nz; jj += np) {
                if (jj < sp->j0 || jj >= sp->j1) continue;
                const double *src = img->pix + (size_t)jj * n;
                int i = sp->i0;
                for (; i < sp->i1 && i < np; i++) row[i] += src[i];
                for (; i < sp->i1; i++) row[i % np] += src[i];
            }
        }
        fftw_execute(pr);
        for (int r = 0; r < TRANSFORM_RB && j0 + r < nz; r++)
            memcpy(a + (size_t)(j0 + r) * ku * 2, rows + (size_t)r * rowlen, ku * 2 * sizeof(double));
    }
    /* columns u = 0..kr: rows v with |v| <= kr, into out at (v, u) and, by F(-u, -v) =
     * conj F(u, v), at (-v, -u) */
    const size_t side = 2 * (size_t)kr + 1;
    for (int u0 = 0; u0 <= kr; u0 += TRANSFORM_CB) {
        for (int v = 0; v < np; v++)
            for (int c = 0; c < TRANSFORM_CB; c++) {
                double *o = cols + 2 * ((size_t)v * TRANSFORM_CB + (size_t)c);
                int u = u0 + c;
                if (v < nz && u <= kr) {
                    o[0] = a[2 * ((size_t)v * ku + (size_t)u)];
                    o[1] = a[2 * ((size_t)v * ku + (size_t)u) + 1];
                } else
                    o[0] = o[1] = 0.0;
            }
        fftw_execute(pc);
        for (int c = 0; c < TRANSFORM_CB && u0 + c <= kr; c++) {
            int u = u0 + c;
            for (int v = -kr; v <= kr; v++) {
                const double *f = cols + 2 * ((size_t)((v % np + np) % np) * TRANSFORM_CB + (size_t)c);
                double *o = out + 2 * ((size_t)(v + kr) * side + (size_t)(u + kr));
                o[0] = f[0];
                o[1] = f[1];
                if (u > 0) {
                    double *m = out + 2 * ((size_t)(-v + kr) * side + (size_t)(-u + kr));
                    m[0] = f[0];
                    m[1] = -f[1];
                }
            }
        }
    }
    wf_fftw_lock();
    fftw_destroy_plan(pr);
    fftw_destroy_plan(pc);
    wf_fftw_unlock();
    /* The DFT puts sample i at i * scale; the image centre c = (n-1)/2 is the PSF's origin,
     * so multiply by exp(+i k c scale). k = m dk_t and scale = pixel / os, so the phase per
     * step is 2 pi c / (os table_fft) = 2 pi c / np. */
    double c = 0.5 * (img->n - 1);
    /* the phase is separable, e^{i a (u + v)}: one line of it (the tables are built for
     * every core, and side^2 sincos calls would cost more than the FFT) */
    double *line;
    wf_status st2 = wf_arena_calloc(arena, 2 * side, sizeof(double), "PSF phase line", (void **)&line);
    if (st2) return st2;
    for (int u = -kr; u <= kr; u++) {
        double ph = 2.0 * M_PI * c * u / np;
        line[2 * (u + kr)] = cos(ph);
        line[2 * (u + kr) + 1] = sin(ph);
    }
    for (int v = -kr; v <= kr; v++) {
        const double pvr = line[2 * (v + kr)], pvi = line[2 * (v + kr) + 1];
        for (int u = -kr; u <= kr; u++) {
            double *o = out + 2 * ((size_t)(v + kr) * side + (size_t)(u + kr));
            const double re = o[0], im = o[1];
            const double pur = line[2 * (u + kr)], pui = line[2 * (u + kr) + 1];
            double cr = pur * pvr - pui * pvi, ci = pur * pvi + pui * pvr;
            o[0] = re * cr - im * ci;
            o[1] = re * ci + im * cr;
        }
    }
    return WF_OK;
}

/* The same by a direct separable DFT: any sampling, O(n^2 side + n side^2). */
static wf_status transform_direct(const wf_psf_image *img, const support *sp, double dkt, int kr,
                                  wf_arena *arena, double *out)
{
    int n = img->n;
    size_t side = 2 * (size_t)kr + 1;
    double *a, *ph;
    wf_status st = wf_arena_calloc(arena, (size_t)n * side * 2, sizeof(double), "PSF DFT rows",
                                   (void **)&a);
    if (st) return st;
    st = wf_arena_calloc(arena, side * 2, sizeof(double), "PSF DFT phases", (void **)&ph);
    if (st) return st;
    double c = 0.5 * (n - 1), s = img->scale_arcsec;
    for (int i = sp->i0; i < sp->i1; i++) {
        for (int u = -kr; u <= kr; u++) {
            double p = -u * dkt * (i - c) * s;
            ph[2 * (u + kr)] = cos(p);
            ph[2 * (u + kr) + 1] = sin(p);
        }
        for (int j = sp->j0; j < sp->j1; j++) {
            double w = img->pix[(size_t)j * n + i];
            if (w == 0.0) continue;
            double *row = a + (size_t)j * side * 2;
            for (size_t k = 0; k < side; k++) {
                row[2 * k] += w * ph[2 * k];
                row[2 * k + 1] += w * ph[2 * k + 1];
            }
        }
    }
    memset(out, 0, side * side * 2 * sizeof(double));
    for (int j = sp->j0; j < sp->j1; j++) {
        const double *row = a + (size_t)j * side * 2;
        for (int v = -kr; v <= kr; v++) {
            double p = -v * dkt * (j - c) * s;
            double cr = cos(p), ci = sin(p);
            double *o = out + (size_t)(v + kr) * side * 2;
            for (size_t k = 0; k < side; k++) {
                o[2 * k] += cr * row[2 * k] - ci * row[2 * k + 1];
                o[2 * k + 1] += cr * row[2 * k + 1] + ci * row[2 * k];
            }
        }
    }
    return WF_OK;
}

/* The raw transform times the pixel's, in scratch at the arena's top: side_s^2 complex. Only
 * the samples in `sp` are read (the image is zero beyond it); NULL: the whole image. */
static wf_status pixel_transform(const wf_psf_image *img, const support *sp, const wf_profile_accuracy *acc,
                                 int kr_s, wf_arena *arena, double **out)
{
    size_t side_s = 2 * (size_t)kr_s + 1;
    double dkt = 2.0 * M_PI / (acc->psf_table_fft * acc->pixel_scale);
    double *raw;
    /* every sample is written by either transform: not zeroed */
    wf_status st = wf_arena_reserve(arena, side_s * side_s * 2 * sizeof(double), "PSF transform",
                                    (void **)&raw);
    if (st) return st;
    int os = integer_oversampling(acc->pixel_scale, img->scale_arcsec);
    const support whole = {0, img->n, 0, img->n};
    if (!sp) sp = &whole;
    st = os ? transform_fft(img, sp, os, acc->psf_table_fft, kr_s, arena, raw)
            : transform_direct(img, sp, dkt, kr_s, arena, raw);
    if (st) return st;
    double p = acc->pixel_scale, *sx;
    if ((st = wf_arena_calloc(arena, side_s, sizeof(double), "PSF pixel line", (void **)&sx))) return st;
    for (int u = -kr_s; u <= kr_s; u++) sx[u + kr_s] = sinc(0.5 * u * dkt * p);
    for (int v = -kr_s; v <= kr_s; v++) {
        double sy = sx[v + kr_s];
        for (int u = -kr_s; u <= kr_s; u++) {
            double *o = raw + 2 * ((size_t)(v + kr_s) * side_s + (size_t)(u + kr_s));
            double w = sy * sx[u + kr_s];
            o[0] *= w;
            o[1] *= w;
        }
    }
    *out = raw;
    return WF_OK;
}

/* What the passes of wf_profile_psf_init share: each pass (the whole image's table, then
 * each core's) and each wing is a task of its own, run on the thread slot's scratch arena. */
typedef struct init_job {
    wf_profile_psf *psf;
    const wf_psf_image *img;
    const wf_profile_accuracy *acc;
    wf_arena *slot;             /* scratch arena per thread slot */
    int kr_s, kr, nalt;
    double dkt, band, sum, c;
    split_geom g;
    float *re, *im;
    double *env;
    double pixel_max[1 + WF_PROFILE_MAX_CORES];
} init_job;

/* sqrt(a^2 + b^2) without hypot's guard against overflow, which these loops over every
 * sample of the tables and images (values of order 1, or integers whose squares add exactly)
 * do not need and which costs several times more. */
static inline double rad(double a, double b) { return sqrt(a * a + b * b); }

/* Table `which` (0 the main one, i + 1 alt[i]), envelope and pixel bound of one pass from its
 * raw transform at that table's period: (2 kr_s + 1)^2 complex, kr_s >= the table's kr. The
 * envelope's rings are the main table's steps whatever the period, so that it bounds every
 * sample a draw reads. */
static void fill_table(init_job *j, int pass, int which, const double *raw, int kr_s)
{
    wf_profile_psf *psf = j->psf;
    wf_profile_core *co = pass ? &psf->core[pass - 1] : NULL;
    wf_profile_table *at = which ? (pass ? &co->alt[which - 1] : &psf->alt[which - 1]) : NULL;
    const int kr = which ? at->kr : j->kr, P = which ? at->fft : j->acc->psf_table_fft;
    const double dk = 2.0 * M_PI / (P * j->acc->pixel_scale), to_ring = (double)j->acc->psf_table_fft / P;
    const size_t side = 2 * (size_t)kr + 1, side_s = 2 * (size_t)kr_s + 1;
    float *tr = which ? at->re : pass ? co->re : j->re, *ti = which ? at->im : pass ? co->im : j->im;
    double *te = pass ? co->env : j->env, sabs = 0.0;
    for (int v = -kr; v <= kr; v++)
        for (int u = -kr; u <= kr; u++) {
            const double *o = raw + 2 * ((size_t)(v + kr_s) * side_s + (size_t)(u + kr_s));
            size_t idx = (size_t)(v + kr) * side + (size_t)(u + kr);
            double rk = rad(u, v);
            double wt = band_taper(dk * rk, j->band);
            tr[idx] = (float)(wt * o[0]);
            ti[idx] = (float)(wt * o[1]);
            int ring = (int)(rk * to_ring);
            double mag = wt * rad(o[0], o[1]);
            if (ring <= j->kr) te[ring] = fmax(te[ring], mag);
            sabs += mag;
        }
    /* the image (pixel included) periodised with the samples' period of N = table_fft
     * pixels is (1 / N^2) sum_k T(k) e^{i k.X} at any X, and not below the image: no pixel
     * exceeds sum |T| / N^2 (at Y106 0.477, 0.6% above the brightest pixel found by a
     * 1/16-pixel search: the transform is nearly real and positive). The other periods'
     * sums bound their own (more folded) images, no tighter: the main one's is kept. */
    if (!which) j->pixel_max[pass] = sabs / ((double)P * P * j->sum); /* the main period's: the draws' */
    for (int i = j->kr; i > 0; i--) te[i - 1] = fmax(te[i - 1], te[i]);
    steps_fill(tr, ti, kr, which ? &at->steps : pass ? &co->steps : &psf->steps);
}

/* Pass `pass`'s tables at the other periods: the (pass's) image transformed at each. */
static wf_status fill_alt(init_job *j, int pass, const wf_psf_image *img, const support *sp, wf_arena *arena)
{
    const wf_profile_table *alt = pass ? j->psf->core[pass - 1].alt : j->psf->alt;
    for (int i = 0; i < j->nalt; i++) {
        wf_profile_accuracy a = *j->acc;
        a.psf_table_fft = alt[i].fft;
        size_t mark = wf_arena_mark(arena);
        double *raw;
        wf_status st = pixel_transform(img, sp, &a, alt[i].kr, arena, &raw);
        if (st) return st;
        fill_table(j, pass, i + 1, raw, alt[i].kr);
        wf_arena_release(arena, mark);
    }
    return WF_OK;
}

/* Core `task`: the image times its taper, transformed. */
static wf_status core_pass(void *ctx, int task, int slot)
{
    init_job *j = ctx;
    const wf_psf_image *img = j->img;
    wf_profile_core *co = &j->psf->core[task];
    wf_arena *arena = &j->slot[slot];
    size_t mark = wf_arena_mark(arena);
    double *tapered, *raw;
    wf_status st = wf_arena_reserve(arena, (size_t)img->n * (size_t)img->n * sizeof(double),
                                    "PSF core image", (void **)&tapered);
    if (!st) {
        /* the taper ends at the core's radius: the samples within it, a square of ~2 rc / scale
         * (148 of 256 at Y106 for 2"), are all the transform reads; the rest would add zeros */
        const int lo = (int)ceil(j->c - co->radius / img->scale_arcsec) - 1;
        const int hi = (int)floor(j->c + co->radius / img->scale_arcsec) + 2;
        const support sp = {lo < 0 ? 0 : lo, hi > img->n ? img->n : hi, lo < 0 ? 0 : lo, hi > img->n ? img->n : hi};
        for (int jj = sp.j0; jj < sp.j1; jj++)
            for (int i = sp.i0; i < sp.i1; i++) {
                double r = rad(i - j->c, jj - j->c) * img->scale_arcsec;
                size_t at = (size_t)jj * img->n + i;
                tapered[at] = img->pix[at] * core_taper(r, co->radius);
                co->flux += tapered[at];
            }
        wf_psf_image src = *img;
        src.pix = tapered;
        /* only the table's window: the band, found from the whole image's transform, is
         * known by now (each sample is computed as in the full plane, so the same bits) */
        size_t mark1 = wf_arena_mark(arena);
        if (!(st = pixel_transform(&src, &sp, j->acc, j->kr, arena, &raw))) {
            fill_table(j, task + 1, 0, raw, j->kr);
            wf_arena_release(arena, mark1);
            st = fill_alt(j, task + 1, &src, &sp, arena);
        }
    }
    wf_arena_release(arena, mark);
    return st;
}

/* The c2r's output (period nfl fine samples, K per pixel) as K^2 phase planes of np^2
 * samples at offsets n - h + a / K pixels; the largest |sample| kept into *max and, when out
 * is non-NULL, out[l] (l = 0 .. h) the largest at l - 1 pixels or more from the centre along
 * x or y, and *far the largest at h + 2 or more. */
static void to_planes(const double *buf, long nfl, int K, double norm, int h, int np, float *planes,
                      double *max, double *out, double *far)
{
    const size_t row_len = (size_t)nfl + 2;
    for (int b = 0; b < K; b++)
        for (int a = 0; a < K; a++) {
            float *plane = planes + ((size_t)b * K + (size_t)a) * (size_t)np * np;
            for (int ny = 0; ny < np; ny++) {
                long J = (long)b + (long)K * (ny - h);
                size_t row = (size_t)(((J % nfl) + nfl) % nfl) * row_len;
                for (int nx = 0; nx < np; nx++) {
                    long I = (long)a + (long)K * (nx - h);
                    float v = (float)(norm * buf[row + (size_t)(((I % nfl) + nfl) % nfl)]);
                    plane[(size_t)ny * np + nx] = v;
                    if (fabs(v) > *max) *max = fabs(v);
                }
            }
        }
    if (!out) return;
    /* by whole pixels of distance c = max(|ox|, |oy|) first, then out[l] = max over c >= l - 1 */
    for (int l = 0; l <= h; l++) out[l] = 0.0;
    *far = 0.0;
    for (long J = 0; J < nfl; J++) {
        long oy = labs(J < nfl / 2 ? J : J - nfl);
        for (long I = 0; I < nfl; I++) {
            long ox = labs(I < nfl / 2 ? I : I - nfl);
            long c = (ox > oy ? ox : oy) / K;
            double v = fabs(norm * buf[(size_t)J * row_len + (size_t)I]);
            if (c >= h + 2 && v > *far) *far = v;
            if (c > h) c = h;
            if (v > out[c]) out[c] = v;
        }
    }
    for (int c = h - 1; c >= 0; c--) out[c] = fmax(out[c], out[c + 1]);
    /* a reading out to l pixels reads every pixel within l of the point along both axes, so
     * what it leaves out lies beyond l, between samples l - 1 / K or more away */
    for (int l = h; l >= 1; l--) out[l] = out[l - 1];
}

/* buf = the table (minus the core's when whole) at every q-th step, as a c2r of side nfft
 * wants it. */
static void load_table(const init_job *j, const wf_profile_core *co, int whole, int q, int nfft, double *buf)
{
    const int kr = j->kr, kq = kr / q;
    const size_t side = 2 * (size_t)kr + 1, nf = (size_t)nfft, half = nf / 2 + 1;
    memset(buf, 0, nf * (nf + 2) * sizeof(double));
    for (int vq = -kq; vq <= kq; vq++)
        for (int uq = 0; uq <= kq; uq++) {
            size_t at = (size_t)(vq * q + kr) * side + (size_t)(uq * q + kr);
            double *bb = buf + 2 * ((size_t)((vq % nfft + nfft) % nfft) * half + (size_t)uq);
            bb[0] = whole ? (double)j->re[at] - (double)co->re[at] : (double)co->re[at];
            bb[1] = whole ? (double)j->im[at] - (double)co->im[at] : (double)co->im[at];
        }
}

/* One c2r of side nfft on buf (in place). */
static wf_status c2r(int nfft, double *buf)
{
    wf_fftw_lock();
    fftw_plan plan = fftw_plan_dft_c2r_2d(nfft, nfft, (fftw_complex *)buf, buf, FFTW_ESTIMATE | FFTW_NO_BUFFERING);
    wf_fftw_unlock();
    if (!plan) return wf_error(WF_ERR_INTERNAL, "profile: FFTW could not plan a %d^2 FFT", nfft);
    fftw_execute(plan);
    wf_fftw_lock();
    fftw_destroy_plan(plan);
    wf_fftw_unlock();
    return WF_OK;
}

/* Core `task`'s wing: (whole - core table) at every q-th step, c2r; then the core alone, its
 * knot table, and the bounds on reading it. */
static wf_status wing_pass(void *ctx, int task, int slot)
{
    init_job *j = ctx;
    const split_geom *g = &j->g;
    wf_profile_core *co = &j->psf->core[task];
    wf_arena *arena = &j->slot[slot];
    size_t mark = wf_arena_mark(arena);
    split_geom kg;
    knot_layout(j->acc, co->radius, &kg);
    const size_t nf = (size_t)(g->nfft > kg.nfft ? g->nfft : kg.nfft);
    double *buf, kmax = 0.0, knot_far = 0.0;
    wf_status st = wf_arena_reserve(arena, nf * (nf + 2) * sizeof(double), "PSF wing FFT", (void **)&buf);
    /* e(X) = (1 / lw^2) sum_k T(k) e^{i k X} for the draws' convention (sim/draw/profile.c) */
    if (!st) load_table(j, co, 1, g->q, g->nfft, buf);
    if (!st && !(st = c2r(g->nfft, buf)))
        to_planes(buf, (long)g->nfft, WING_OS, 1.0 / ((double)g->lw * g->lw), g->h, g->np, co->wing, &co->wing_max, NULL,
                  NULL);
    if (!st) load_table(j, co, 0, kg.q, kg.nfft, buf);
    if (!st && !(st = c2r(kg.nfft, buf)))
        to_planes(buf, (long)kg.nfft, KNOT_OS, 1.0 / ((double)kg.lw * kg.lw), co->knot_half, co->knot_np, co->knot, &kmax,
                  co->knot_out, &knot_far);
    if (st) {
        wf_arena_release(arena, mark);
        return st;
    }
    /* the reading's bound from the whole table (N = table_fft), plus what is left out */
    const int kr = j->kr, n = j->acc->psf_table_fft;
    const size_t side = 2 * (size_t)kr + 1;
    double interp = 0.0;
    for (int v = -kr; v <= kr; v++) {
        const double ev = bilinear_err(v, n);
        for (int u = -kr; u <= kr; u++) {
            size_t at = (size_t)(v + kr) * side + (size_t)(u + kr);
            interp += rad(co->re[at], co->im[at]) * (bilinear_err(u, n) + ev);
        }
    }
    /* plus the table's own errors: its floats (half an ulp of its largest sample) and the
     * period lw it is folded with, whose copies reach a reading from beyond h + 2 pixels
     * (taken as the largest sample there, which the taper makes ~1e-7 of the peak) */
    co->knot_interp = interp / ((double)n * n) + kmax * 0x1p-24 + knot_far;
    /* What a reading out to l leaves out. Along an axis a plane is read over samples
     * h - l .. h + l + 1, but where the fine index wraps to the next pixel (the first plane
     * read at the last phase, the second at phase 0 one sample on) the two planes' windows are
     * h - l .. h + l and h - l + 1 .. h + l + 1: every window holds one of those two of
     * 2 l + 1 samples, so the least light of those in any plane bounds what a reading keeps
     * (the light it reads is the bilinear weights' mean of its planes' windows). The windows
     * are summed from each plane's running sums; the core's flux is the table's centre. */
    const int h = co->knot_half, np = co->knot_np;
    const double cflux = co->re[(size_t)kr * side + (size_t)kr];
    double *run = NULL;
    if ((st = wf_arena_reserve(arena, (size_t)(np + 1) * (size_t)(np + 1) * sizeof(double), "PSF knot sums",
                               (void **)&run))) {
        wf_arena_release(arena, mark);
        return st;
    }
    for (int l = 0; l <= h; l++) co->knot_miss[l] = 0.0;
    const size_t w = (size_t)np + 1;
    for (int pl = 0; pl < KNOT_OS * KNOT_OS; pl++) {
        const float *plane = co->knot + (size_t)pl * np * np;
        for (int i = 0; i <= np; i++) run[i] = 0.0;
        for (int ny = 0; ny < np; ny++) { /* run[(y) w + x]: the samples below row y, left of column x */
            double rowsum = 0.0;
            run[(size_t)(ny + 1) * w] = 0.0;
            for (int nx = 0; nx < np; nx++) {
                rowsum += plane[(size_t)ny * np + nx];
                run[(size_t)(ny + 1) * w + (size_t)(nx + 1)] = run[(size_t)ny * w + (size_t)(nx + 1)] + rowsum;
            }
        }
        for (int l = 0; l <= h; l++)
            for (int sy = 0; sy < 2 && h + l + sy < np; sy++)
                for (int sx = 0; sx < 2 && h + l + sx < np; sx++) {
                    const size_t y0 = (size_t)(h - l + sy), y1 = (size_t)(h + l + sy + 1);
                    const size_t x0 = (size_t)(h - l + sx), x1 = (size_t)(h + l + sx + 1);
                    const double in = run[y1 * w + x1] - run[y0 * w + x1] - run[y1 * w + x0] + run[y0 * w + x0];
                    co->knot_miss[l] = fmax(co->knot_miss[l], 1.0 - in / cflux);
                }
    }
    wf_arena_release(arena, mark);
    return WF_OK;
}

wf_status wf_profile_psf_init(wf_profile_psf *psf, const wf_psf_image *img,
                              const wf_profile_accuracy *acc, wf_arena *arena, int threads)
{
    memset(psf, 0, sizeof *psf);
    double sum;
    size_t keep_bound, scratch;
    wf_status st = wf_profile_psf_need(img, acc, &keep_bound, &scratch);
    if (st) return st;
    (void)check_image(img, &sum);
    if (img->scale_arcsec > 0.5 * acc->pixel_scale)
        return wf_error(WF_ERR_RANGE,
                        "profile: PSF sampled at %g arcsec, coarser than half the %g arcsec "
                        "pixel; an undersampled PSF image cannot be resampled",
                        img->scale_arcsec, acc->pixel_scale);
    init_job j = {.psf = psf, .img = img, .acc = acc, .sum = sum};
    j.kr_s = sampling_kr(img, acc);
    {
        int per[1 + WF_PROFILE_MAX_ALT];
        j.nalt = wf_profile_table_periods(acc, per) - 1;
    }
    const int kr_s = j.kr_s;
    j.dkt = 2.0 * M_PI / (acc->psf_table_fft * acc->pixel_scale);
    j.band = img->band_limit > 0.0 ? img->band_limit : INFINITY;
    j.c = 0.5 * (img->n - 1);
    const int ncore = acc->core_radius > 0.0 ? acc->core_levels : 0;
    if (ncore) {
        split_layout(img, acc, &j.g);
        double edge = 0.5 * (img->n - 1) * img->scale_arcsec;
        if (!(acc->core_radius < edge))
            return wf_error(WF_ERR_RANGE, "profile: core_radius %g arcsec reaches the PSF image's edge "
                            "(%g arcsec): there would be no wing", acc->core_radius, edge);
        /* a core under two pixels is never taken (its wing holds most of the PSF's peak)
         * and its transform reaches far past the table's band */
        double smallest = ldexp(acc->core_radius, 1 - ncore);
        if (!(smallest >= 2.0 * acc->pixel_scale))
            return wf_error(WF_ERR_RANGE, "profile: core_radius %g arcsec with %d core_levels makes a "
                            "%g arcsec core, under two %g arcsec pixels; use fewer levels",
                            acc->core_radius, ncore, smallest, acc->pixel_scale);
        /* the wing table's period must hold it without overlap */
        if (j.g.lw < j.g.np)
            return wf_error(WF_ERR_RANGE, "profile: a %d-sample PSF image (%g arcsec) is wider than "
                            "psf_table_fft %d pixels allows for its wing table; raise psf_table_fft",
                            img->n, 2.0 * edge, acc->psf_table_fft);
    }
    /* Scratch per thread slot off the arena's top, the tables from its bottom: the whole
     * image's transform, which gives the band, then stays in slot 0 for its own table (the
     * tables are trimmed to the band, so they can be reserved only once it is known). As
     * many slots as the arena holds, up to `threads`; passes and wings run in parallel. */
    size_t room = arena->capacity - arena->used;
    size_t slot_bytes = scratch + 64; /* a slot's own alignment pad */
    int T = threads < 1 ? 1 : threads;
    if (T > (ncore ? ncore : 1)) T = ncore ? ncore : 1; /* pass 0 runs alone, then a core per task */
    if (T > WF_PROFILE_MAX_CORES) T = WF_PROFILE_MAX_CORES;
    while (T > 1 && keep_bound + (size_t)T * slot_bytes + 64 > room) T--; /* + the split's pad */
    wf_arena top, slots[WF_PROFILE_MAX_CORES];
    if ((st = wf_arena_split(arena, T == 1 && slot_bytes > room ? room : (size_t)T * slot_bytes,
                             "PSF table scratch", &top)))
        return st;
    for (int t = 0; t < T; t++) {
        size_t part = top.capacity / (size_t)T;
        wf_arena_init(&slots[t], top.base + (size_t)t * part, t == T - 1 ? top.capacity - (size_t)t * part : part,
                      "PSF table scratch");
    }
    j.slot = slots;
    double *raw;
    const size_t mark0 = wf_arena_mark(&slots[0]);
    /* Only samples within the band count below, and max(|u|, |v|) <= |k| / dkt, so the
     * table never reaches past floor(band / dkt) + 2 steps: the whole image's transform is
     * taken out to that window, not to the image's Nyquist (at Y106 463^2 samples instead of
     * 1535^2, 3.4 instead of 38 MB of fresh memory; each sample as in the full plane). */
    int kw = kr_s;
    if (j.band < INFINITY) {
        double kb = floor(j.band / j.dkt) + 2.0;
        if (kb < kw) kw = (int)kb;
    }
    const size_t side_w = 2 * (size_t)kw + 1;
    if ((st = pixel_transform(img, NULL, acc, kw, &slots[0], &raw))) goto out;
    int kr = 0;
    double kmax = 0.0;
    for (int v = -kw; v <= kw; v++)
        for (int u = -kw; u <= kw; u++) {
            const double *o = raw + 2 * ((size_t)(v + kw) * side_w + (size_t)(u + kw));
            const double k = j.dkt * rad(u, v);
            if (k <= j.band && rad(o[0], o[1]) >= WF_PSF_KFLOOR * sum) {
                int r = abs(u) > abs(v) ? abs(u) : abs(v);
                if (r > kr) kr = r;
                if (k > kmax) kmax = k;
            }
        }
    kr += 2; /* room for the bicubic interpolation's outer taps */
    if (kr > kw) kr = kw;
    j.kr = kr;
    const size_t side = 2 * (size_t)kr + 1;

    double *ee;
    size_t nee = ee_count(img);
    /* the tables and wings are written whole (fill_table, wing_pass): not zeroed */
    if ((st = wf_arena_reserve(arena, side * side * sizeof(float), "PSF table", (void **)&j.re)) ||
        (st = wf_arena_reserve(arena, side * side * sizeof(float), "PSF table", (void **)&j.im)) ||
        (st = wf_arena_calloc(arena, nee, sizeof(double), "PSF encircled energy", (void **)&ee)) ||
        (st = wf_arena_calloc(arena, (size_t)kr + 2, sizeof(double), "PSF envelope", (void **)&j.env)) ||
        (st = steps_alloc(arena, acc, 0, kr, &psf->steps)) || (st = alt_alloc(arena, img, acc, kr, psf->alt)))
        goto out;
    for (int l = 0; l < ncore; l++) {
        wf_profile_core *co = &psf->core[l];
        split_geom kg;
        co->radius = ldexp(acc->core_radius, -l);
        if ((st = wf_arena_reserve(arena, (size_t)WING_OS * WING_OS * (size_t)j.g.np * (size_t)j.g.np * sizeof(float),
                                   "PSF wing", (void **)&co->wing)) ||
            (knot_layout(acc, co->radius, &kg), co->knot_half = kg.h, co->knot_np = kg.np,
             st = wf_arena_reserve(arena, (size_t)KNOT_OS * KNOT_OS * (size_t)kg.np * (size_t)kg.np * sizeof(float),
                                   "PSF core knot table", (void **)&co->knot)) ||
            (st = wf_arena_reserve(arena, ((size_t)co->knot_half + 1) * sizeof(double), "PSF core knot bounds",
                                   (void **)&co->knot_out)) ||
            (st = wf_arena_reserve(arena, ((size_t)co->knot_half + 1) * sizeof(double), "PSF core knot bounds",
                                   (void **)&co->knot_miss)) ||
            (st = wf_arena_reserve(arena, side * side * sizeof(float), "PSF core table", (void **)&co->re)) ||
            (st = wf_arena_reserve(arena, side * side * sizeof(float), "PSF core table", (void **)&co->im)) ||
            (st = wf_arena_calloc(arena, (size_t)kr + 2, sizeof(double), "PSF core envelope",
                                  (void **)&co->env)) ||
            (st = steps_alloc(arena, acc, 0, kr, &co->steps)) || (st = alt_alloc(arena, img, acc, kr, co->alt)))
            goto out;
    }
    /* encircled energy about the image centre, for stamp sizes */
    const double dr = 0.5 * img->scale_arcsec;
    for (int jj = 0; jj < img->n; jj++)
        for (int i = 0; i < img->n; i++) {
            size_t bin = (size_t)(rad(i - j.c, jj - j.c) * img->scale_arcsec / dr);
            ee[bin < nee ? bin : nee - 1] += img->pix[(size_t)jj * img->n + i];
        }
    /* the whole image's table from the transform in hand; then each core's (the tapered
     * image), and each core's wing, which needs both tables */
    fill_table(&j, 0, 0, raw, kw);
    wf_arena_release(&slots[0], mark0);
    if ((st = fill_alt(&j, 0, img, NULL, &slots[0]))) goto out;
    if ((st = wf_parallel_for(ncore, T, core_pass, &j)) || (st = wf_parallel_for(ncore, T, wing_pass, &j)))
        goto out;
    for (int pass = 0; pass <= ncore; pass++) psf->pixel_max = fmax(psf->pixel_max, j.pixel_max[pass]);
    double run = 0.0;
    for (size_t bin = 0; bin < nee; bin++) {
        run += ee[bin];
        ee[bin] = run / sum;
    }
    for (int l = 0; l < ncore; l++) psf->core[l].flux /= sum;
    psf->ncore = ncore;
    if (ncore) {
        psf->wing_os = WING_OS;
        psf->knot_os = KNOT_OS;
        psf->wing_half = j.g.h;
        psf->wing_np = j.g.np;
    }

    psf->pixel_scale = acc->pixel_scale;
    psf->scale = img->scale_arcsec;
    psf->flux = sum;
    psf->table_fft = acc->psf_table_fft;
    psf->nalt = j.nalt;
    psf->kr = kr;
    psf->re = j.re;
    psf->im = j.im;
    psf->kmax = kmax + j.dkt;
    psf->nee = (int)nee;
    psf->ee_dr = dr;
    psf->ee = ee;
    psf->env = j.env;
out:
    for (int t = 0; t < T; t++) { /* the slots' high water, for the arena's own */
        size_t hw = (size_t)(slots[t].base - top.base) + slots[t].high_water;
        if (hw > top.high_water) top.high_water = hw;
    }
    wf_arena_join(arena, &top);
    return st;
}
