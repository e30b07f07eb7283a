#include "tools/accuracy.h"

#include <errno.h>
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/utsname.h>
#include <time.h>
#include <unistd.h>

#include "hal/arena.h"
#include "hal/dq.h"
#include "hal/file.h"
#include "hal/link.h"
#include "hal/scene.h"
#include "sim/optics/bandpass.h"
#include "sim/survey/catalog.h"
#include "sim/draw/profile.h"
#include "sim/optics/psf.h"
#include "sim/draw/scene.h"
#include "sim/survey/skyindex.h"
#include "sim/survey/synth.h"
#include "sim/survey/wcs.h"
#include "tools/assemble.h"
#include "tools/config.h"
#include "tools/expose.h"
#include "tools/persist.h"
#include "analysis/plot.h"

static const char *usage =
    "usage: wfisim accuracy psf|galaxy|scene|detector|all [--filter F] [--sca N] [--out DIR]\n"
    "                       [--data DIR|none] [--quick]\n"
    "  Sweeps each accuracy knob of the rendering against its highest-fidelity setting and\n"
    "  writes DIR/accuracy_<kind>.csv, DIR/accuracy.md and plots [out/accuracy]; filter [Y106],\n"
    "  SCA [1]; masks and Zernikes from DIR/roman [$WFISIM_DATA]; --quick: a reduced sweep.\n";

#define STAR_N 64   /* the PSF sweep's star box, 7.04": holds all but ~1.5% of the light */
#define STAR_C 31.5 /* the box's true centre, between pixels, as GalSim's reference PSFs: a
                       star on a pixel centre puts most of Roman's undersampled core in one
                       pixel, and adaptive moments collapse onto it */
#define TILE 64     /* rows per fill when rendering a region */
#define BRIGHT_RATE 2.0 /* e-/s, 5x the deep-field sky: "bright" pixels of the sampling
                           comparison, where nonlinearity starts to matter */

typedef struct acc_row {
    char kind[12];
    char tcase[16]; /* what is drawn (docs/ACCURACY.md describes each) */
    char knob[24];
    char value[24];
    int reference;  /* the setting the others are compared with */
    /* relative to the reference unless said: flux, its standard error (sampling only),
     * peak, the worst of the 3x3 core and of all pixels (both / reference peak), adaptive
     * size, and distortion e1, e2 (absolute); NAN where it does not apply */
    double d_flux, d_flux_se, d_peak, d_core, d_max, d_sigma, d_e1, d_e2;
    double cpu_seconds; /* the whole case, setup included */
    double draw_ms;     /* one object's draw, best of repeats; NAN: not applicable */
    char notes[160];
} acc_row;

typedef struct acc_run {
    char filter[16];
    wf_filter filt;
    int sca;
    char out[WF_PATH_MAX];
    char data[WF_PATH_MAX]; /* "" -> analytic pupil, built-in bandpass */
    int quick;
    char command[2048];
    wf_bandpass *bp;
    acc_row *rows;
    size_t n, cap;
} acc_run;

static double cpu_now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

/* ---- rows --------------------------------------------------------------------------------- */

static void row_init(acc_row *r, const char *kind, const char *tcase, const char *knob,
                     const char *value)
{
    memset(r, 0, sizeof *r);
    snprintf(r->kind, sizeof r->kind, "%s", kind);
    snprintf(r->tcase, sizeof r->tcase, "%s", tcase);
    snprintf(r->knob, sizeof r->knob, "%s", knob);
    snprintf(r->value, sizeof r->value, "%s", value);
    r->d_flux = r->d_flux_se = r->d_peak = r->d_core = r->d_max = NAN;
    r->d_sigma = r->d_e1 = r->d_e2 = r->draw_ms = NAN;
}

static wf_status add_row(acc_run *run, const acc_row *r)
{
    if (run->n == run->cap) {
        size_t nc = run->cap ? 2 * run->cap : 64;
        acc_row *p = realloc(run->rows, nc * sizeof *p);
        if (!p) return wf_error(WF_ERR_NOMEM, "accuracy: cannot hold %zu result rows", nc);
        run->rows = p;
        run->cap = nc;
    }
    run->rows[run->n++] = *r;
    fprintf(stderr, "accuracy %s %s %s=%s%s: flux %+.2e peak %+.2e sigma %+.2e, %.4f s\n",
            r->kind, r->tcase, r->knob, r->value, r->reference ? " (ref)" : "", r->d_flux,
            r->d_peak, r->d_sigma, r->cpu_seconds);
    return WF_OK;
}

/* ---- image measures ----------------------------------------------------------------------- */

typedef struct meas {
    double sum, peak;
    long ipeak;
    double sigma, e1, e2; /* adaptive: det(M)^(1/4) pixels, distortion */
} meas;

/* Adaptive (elliptical Gaussian weight) moments at the fixed point M = 2 Mw, HSM's
 * FindAdaptiveMom as tests/test_psf.c uses it: unlike unweighted moments they are not
 * dominated by the far wings, whose share is what the stamp knobs trade. */
static void adaptive(const double *im, int nx, int ny, long ipeak, meas *m)
{
    double xc = (double)(ipeak % nx), yc = (double)(ipeak / nx), mxx = 4, myy = 4, mxy = 0;
    m->sigma = m->e1 = m->e2 = NAN;
    for (int it = 0; it < 500; it++) {
        double det = mxx * myy - mxy * mxy;
        if (!(det > 0)) return;
        double ixx = myy / det, iyy = mxx / det, ixy = -mxy / det;
        /* the weight is below e^-30 outside r^2 = 60, whose ellipse has |dx| <= sqrt(60 Mxx) */
        int hx = (int)ceil(sqrt(60 * mxx)) + 1, hy = (int)ceil(sqrt(60 * myy)) + 1;
        int i0 = (int)floor(xc) - hx, i1 = (int)ceil(xc) + hx;
        int j0 = (int)floor(yc) - hy, j1 = (int)ceil(yc) + hy;
        if (i0 < 0) i0 = 0;
        if (j0 < 0) j0 = 0;
        if (i1 > nx - 1) i1 = nx - 1;
        if (j1 > ny - 1) j1 = ny - 1;
        double a = 0, bx = 0, by = 0, cxx = 0, cyy = 0, cxy = 0;
        for (int j = j0; j <= j1; j++)
            for (int i = i0; i <= i1; i++) {
                double dx = i - xc, dy = j - yc;
                double r2 = ixx * dx * dx + 2 * ixy * dx * dy + iyy * dy * dy;
                if (r2 > 60.0) continue;
                double w = exp(-0.5 * r2) * im[(size_t)j * nx + i];
                a += w, bx += w * dx, by += w * dy;
                cxx += w * dx * dx, cyy += w * dy * dy, cxy += w * dx * dy;
            }
        if (!(a > 0)) return;
        bx /= a, by /= a;
        double nxx = 2 * (cxx / a - bx * bx), nyy = 2 * (cyy / a - by * by),
               nxy = 2 * (cxy / a - bx * by);
        double change = fabs(nxx - mxx) + fabs(nyy - myy) + fabs(nxy - mxy) + fabs(bx) + fabs(by);
        xc += bx, yc += by, mxx = nxx, myy = nyy, mxy = nxy;
        if (change < 1e-12 * (1 + mxx + myy)) break;
    }
    double det = mxx * myy - mxy * mxy;
    if (!(det > 0)) return;
    m->sigma = pow(det, 0.25);
    m->e1 = (mxx - myy) / (mxx + myy);
    m->e2 = 2 * mxy / (mxx + myy);
}

static void measure(const double *im, int nx, int ny, int moments, meas *m)
{
    memset(m, 0, sizeof *m);
    m->peak = -INFINITY;
    for (long i = 0; i < (long)nx * ny; i++) {
        m->sum += im[i];
        if (im[i] > m->peak) m->peak = im[i], m->ipeak = i;
    }
    m->sigma = m->e1 = m->e2 = NAN;
    if (moments) adaptive(im, nx, ny, m->ipeak, m);
}

/* Errors of image a against the reference on the same grid. The same arrays give exact
 * zeros: every measure is a deterministic function of the pixels. */
static void compare(const double *a, const double *ref, int nx, int ny, int moments, acc_row *r)
{
    meas ma, mr;
    measure(a, nx, ny, moments, &ma);
    measure(ref, nx, ny, moments, &mr);
    r->d_flux = ma.sum / mr.sum - 1;
    r->d_peak = ma.peak / mr.peak - 1;
    int px = (int)(mr.ipeak % nx), py = (int)(mr.ipeak / nx);
    double core = 0, worst = 0;
    for (int j = py - 1; j <= py + 1; j++)
        for (int i = px - 1; i <= px + 1; i++)
            if (i >= 0 && j >= 0 && i < nx && j < ny) {
                double d = fabs(a[(size_t)j * nx + i] - ref[(size_t)j * nx + i]);
                if (d > core) core = d;
            }
    for (long i = 0; i < (long)nx * ny; i++)
        if (fabs(a[i] - ref[i]) > worst) worst = fabs(a[i] - ref[i]);
    r->d_core = core / mr.peak;
    r->d_max = worst / mr.peak;
    if (moments) {
        r->d_sigma = ma.sigma / mr.sigma - 1;
        r->d_e1 = ma.e1 - mr.e1;
        r->d_e2 = ma.e2 - mr.e2;
    }
}

/* Stamps of different bounds compared on the union of their bounds (zero outside each). */
static wf_status compare_stamps(const wf_stamp *a, const wf_stamp *ref, acc_row *r)
{
    int x0 = a->x0 < ref->x0 ? a->x0 : ref->x0, y0 = a->y0 < ref->y0 ? a->y0 : ref->y0;
    int x1 = a->x0 + a->nx > ref->x0 + ref->nx ? a->x0 + a->nx : ref->x0 + ref->nx;
    int y1 = a->y0 + a->ny > ref->y0 + ref->ny ? a->y0 + a->ny : ref->y0 + ref->ny;
    int nx = x1 - x0, ny = y1 - y0;
    double *ca = calloc((size_t)nx * ny, sizeof *ca), *cr = calloc((size_t)nx * ny, sizeof *cr);
    if (!ca || !cr) {
        free(ca), free(cr);
        return wf_error(WF_ERR_NOMEM, "accuracy: cannot hold a %dx%d comparison", nx, ny);
    }
    const wf_stamp *s[2] = {a, ref};
    double *c[2] = {ca, cr};
    for (int k = 0; k < 2; k++)
        for (int j = 0; j < s[k]->ny; j++)
            memcpy(c[k] + (size_t)(s[k]->y0 - y0 + j) * nx + (s[k]->x0 - x0),
                   s[k]->pix + (size_t)j * s[k]->nx, (size_t)s[k]->nx * sizeof(double));
    compare(ca, cr, nx, ny, 1, r);
    free(ca), free(cr);
    return WF_OK;
}

/* ---- timing ------------------------------------------------------------------------------- */

typedef wf_status (*timed_fn)(void *ctx);

/* CPU seconds of one call, best of a few batches, each long enough for the clock. */
static wf_status best_time(timed_fn f, void *ctx, int quick, double *best)
{
    const double min_batch = quick ? 0.002 : 0.02;
    const int batches = quick ? 2 : 5;
    long m = 1;
    double dt = 0;
    wf_status st;
    for (;;) {
        double t0 = cpu_now();
        for (long i = 0; i < m; i++)
            if ((st = f(ctx))) return st;
        dt = cpu_now() - t0;
        if (dt >= min_batch || m >= (1L << 20)) break;
        m *= dt > 0 ? (long)fmin(1024.0, ceil(1.5 * min_batch / dt)) + 1 : 8;
    }
    *best = dt / m;
    for (int b = 1; b < batches; b++) {
        double t0 = cpu_now();
        for (long i = 0; i < m; i++)
            if ((st = f(ctx))) return st;
        dt = (cpu_now() - t0) / m;
        if (dt < *best) *best = dt;
    }
    return WF_OK;
}

/* ---- drawing set-up shared by the PSF and galaxy sweeps ----------------------------------- */

typedef struct drawer {
    wf_psf *psf;
    double *pix; /* the PSF image, normalised as the scene does */
    wf_psf_image img;
    void *mem;
    wf_arena arena;
    wf_profile_psf ppsf;
    wf_profile_work work;
    int work_ready;
    double image_sum; /* the image's share of the unit flux before normalising */
} drawer;

static void drawer_free(drawer *d)
{
    if (d->work_ready) wf_profile_work_free(&d->work);
    free(d->mem);
    free(d->pix);
    wf_psf_free(d->psf);
    memset(d, 0, sizeof *d);
}


static wf_status psf_optics(const acc_run *run, int bin, wf_psf_optics *o)
{
    wf_psf_optics_default(o);
    o->sca = run->sca;
    o->pupil_bin = bin;
    snprintf(o->data_dir, sizeof o->data_dir, "%s", run->data);
    return wf_pupil_group_of_filter(run->filter, &o->group);
}

/* nlambda 0: achromatic at the band's effective wavelength (the scene's choice). */
static wf_status wavelengths(const acc_run *run, int nlambda, double *lam, double *w, int *nl)
{
    if (nlambda == 0) {
        lam[0] = run->bp->lambda_eff_nm, w[0] = 1.0, *nl = 1;
        return WF_OK;
    }
    *nl = nlambda;
    return wf_bandpass_flat_slices(run->bp, nlambda, lam, w);
}

/* What the scene does before its first object: the PSF of this SCA and filter, drawn at
 * 0.11/over arcsec on size^2 samples without the pixel, normalised (or left at unit flux per
 * period, the light beyond the image lost), tabulated for the drawer; plus one drawing work
 * at the default knobs. */
static wf_status drawer_open(const acc_run *run, int bin, int over, int size, int nlambda,
                             int normalise, double core_radius, drawer *d)
{
    memset(d, 0, sizeof *d);
    double lam[WF_PSF_MAX_LAMBDAS], w[WF_PSF_MAX_LAMBDAS];
    int nl;
    wf_psf_optics o;
    wf_status st;
    if ((st = wavelengths(run, nlambda, lam, w, &nl)) || (st = psf_optics(run, bin, &o)) ||
        (st = wf_psf_build_optics(&o, lam, w, nl, &d->psf)))
        goto bad;
    if (!(d->pix = malloc((size_t)size * size * sizeof *d->pix))) {
        st = wf_error(WF_ERR_NOMEM, "accuracy: cannot hold a %dx%d PSF image", size, size);
        goto bad;
    }
    wf_psf_draw_opts dopt;
    wf_psf_draw_opts_default(&dopt);
    dopt.nx = dopt.ny = size;
    dopt.scale = WF_PSF_PIXEL_SCALE / over;
    dopt.cx = dopt.cy = 0.5 * (size - 1);
    dopt.pixel = 0; /* the drawer applies the pixel */
    if ((st = wf_psf_draw(d->psf, &dopt, d->pix))) goto bad;
    double sum = 0, lam_min = lam[0];
    for (size_t k = 0; k < (size_t)size * size; k++) sum += d->pix[k];
    if (normalise)
        for (size_t k = 0; k < (size_t)size * size; k++) d->pix[k] /= sum;
    for (int k = 1; k < nl; k++)
        if (lam[k] < lam_min) lam_min = lam[k];
    d->image_sum = sum;
    /* the pupil's cut-off 2 pi D / lambda (rad/arcsec) at the shortest wavelength drawn */
    double band = 2.0 * M_PI * WF_PUPIL_DIAM / (lam_min * 1e-9) * (M_PI / (180.0 * 3600.0));
    d->img = (wf_psf_image){size, dopt.scale, d->pix, band};
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    acc.core_radius = core_radius;
    size_t keep, scratch, wneed;
    if ((st = wf_profile_psf_need(&d->img, &acc, &keep, &scratch)) ||
        (st = wf_profile_work_need(&acc, &wneed, NULL)))
        goto bad;
    size_t cap = keep + scratch + wneed + 8192;
    if (!(d->mem = malloc(cap))) {
        st = wf_error(WF_ERR_NOMEM, "accuracy: cannot reserve %zu bytes for drawing", cap);
        goto bad;
    }
    wf_arena_init(&d->arena, d->mem, cap, "accuracy drawing arena");
    if ((st = wf_profile_psf_init(&d->ppsf, &d->img, &acc, &d->arena, 1)) ||
        (st = wf_profile_work_init(&d->work, &acc, &d->arena)))
        goto bad;
    d->work_ready = 1;
    return WF_OK;
bad:
    drawer_free(d);
    return st;
}

/* ---- psf ---------------------------------------------------------------------------------- */

typedef struct psf_setting {
    int bin, over, size, nlambda;
    int exact;  /* the pixel-integrated PSF drawn directly (wf_psf_draw), no image, no table */
    int unnorm; /* the PSF image not normalised to its own sum */
} psf_setting;

typedef struct star_draw {
    drawer *d;
    wf_stamp stamp;
    const wf_psf *psf;
    wf_psf_draw_opts opt;
} star_draw;

static wf_status star_via_table(void *ctx)
{
    star_draw *s = ctx;
    return wf_profile_draw_point(&s->d->work, &s->d->ppsf, 1.0, STAR_C, STAR_C, &s->stamp);
}

static wf_status star_exact(void *ctx)
{
    star_draw *s = ctx;
    return wf_psf_draw(s->psf, &s->opt, s->stamp.pix);
}

/* One star of unit flux at (STAR_C, STAR_C) in a STAR_N^2 box at 0.11" with the pixel
 * response, as the scene draws it (or exactly); *setup is the CPU time of everything the
 * scene does for it once, *draw that of the star alone. */
static wf_status psf_star(const acc_run *run, const psf_setting *ps, double *img, double *setup,
                          double *draw, char *notes, size_t cap)
{
    double t0 = cpu_now();
    wf_status st;
    star_draw sd;
    memset(&sd, 0, sizeof sd);
    sd.stamp = (wf_stamp){0, 0, STAR_N, STAR_N, img, 0, 0, 0};
    if (ps->exact) {
        double lam[WF_PSF_MAX_LAMBDAS], w[WF_PSF_MAX_LAMBDAS];
        int nl;
        wf_psf_optics o;
        wf_psf *psf = NULL;
        if ((st = wavelengths(run, ps->nlambda, lam, w, &nl)) || (st = psf_optics(run, ps->bin, &o)) ||
            (st = wf_psf_build_optics(&o, lam, w, nl, &psf)))
            return st;
        sd.psf = psf;
        wf_psf_draw_opts_default(&sd.opt);
        sd.opt.nx = sd.opt.ny = STAR_N;
        sd.opt.cx = sd.opt.cy = STAR_C;
        st = star_exact(&sd);
        *setup = cpu_now() - t0;
        if (!st) st = best_time(star_exact, &sd, run->quick, draw);
        snprintf(notes, cap, "wf_psf_draw with the pixel; no PSF image");
        wf_psf_free(psf);
        return st;
    }
    drawer d;
    if ((st = drawer_open(run, ps->bin, ps->over, ps->size, ps->nlambda, !ps->unnorm, 0.0, &d))) return st;
    sd.d = &d;
    st = star_via_table(&sd);
    *setup = cpu_now() - t0;
    if (!st) st = best_time(star_via_table, &sd, run->quick, draw);
    snprintf(notes, cap, "image %.2f arcsec holds %.5f; star FFT %d; clipped %.1e",
             ps->size * d.img.scale_arcsec, d.image_sum, sd.stamp.fft, sd.stamp.clipped);
    drawer_free(&d);
    return st;
}

/* One knob: every setting drawn, then each compared with settings[ref]. */
static wf_status psf_knob(acc_run *run, const char *knob, const psf_setting *set,
                          const char *const *values, int n, int ref)
{
    double *img = malloc(sizeof(double) * STAR_N * STAR_N * (size_t)n);
    acc_row *rows = calloc((size_t)n, sizeof *rows);
    wf_status st = WF_OK;
    if (!img || !rows) {
        st = wf_error(WF_ERR_NOMEM, "accuracy: out of memory");
        goto out;
    }
    for (int k = 0; k < n && !st; k++) {
        acc_row *r = &rows[k];
        row_init(r, "psf", "star", knob, values[k]);
        r->reference = k == ref;
        double best = INFINITY, draw = 0;
        /* cases under a second are repeated, best of three: the machine is shared */
        for (int rep = 0; rep < (run->quick ? 1 : 3) && !st; rep++) {
            double setup;
            st = psf_star(run, &set[k], img + (size_t)k * STAR_N * STAR_N, &setup, &draw, r->notes,
                          sizeof r->notes);
            if (setup < best) best = setup;
            if (setup > 1.0) break;
        }
        r->cpu_seconds = best;
        r->draw_ms = 1e3 * draw;
    }
    for (int k = 0; k < n && !st; k++) {
        compare(img + (size_t)k * STAR_N * STAR_N, img + (size_t)ref * STAR_N * STAR_N, STAR_N,
                STAR_N, 1, &rows[k]);
        st = add_row(run, &rows[k]);
    }
out:
    free(img);
    free(rows);
    return st;
}

static wf_status sweep_psf(acc_run *run)
{
    const int q = run->quick;
    wf_status st;
    { /* pupil_bin: the pupil sampling; bin 1 is the mask itself */
        psf_setting s[4] = {{8, 4, 256, 0, 0, 0}, {4, 4, 256, 0, 0, 0}, {2, 4, 256, 0, 0, 0}, {1, 4, 256, 0, 0, 0}};
        const char *v[4] = {"8", "4", "2", "1"};
        int n = q ? 3 : 4;
        if (q)
            for (int k = 0; k < n; k++) s[k].size = 128;
        if ((st = psf_knob(run, "pupil_bin", s, v, n, n - 1))) return st;
    }
    { /* oversampling of the PSF image at a fixed 7.04" extent */
        psf_setting s[5] = {{8, 2, 128, 0, 0, 0}, {8, 3, 192, 0, 0, 0}, {8, 4, 256, 0, 0, 0},
                            {8, 6, 384, 0, 0, 0}, {8, 8, 512, 0, 0, 0}};
        const char *v[5] = {"2", "3", "4", "6", "8"};
        psf_setting sq[2] = {s[0], s[2]};
        const char *vq[2] = {"2", "4"};
        if ((st = q ? psf_knob(run, "oversample", sq, vq, 2, 1) : psf_knob(run, "oversample", s, v, 5, 4)))
            return st;
    }
    { /* size of the PSF image at 0.0275": how much of the wings it holds before normalising */
        psf_setting s[4] = {{8, 4, 64, 0, 0, 0}, {8, 4, 128, 0, 0, 0}, {8, 4, 256, 0, 0, 0}, {8, 4, 512, 0, 0, 0}};
        const char *v[4] = {"64", "128", "256", "512"};
        int n = q ? 3 : 4;
        if ((st = psf_knob(run, "psf_size", s, v, n, n - 1))) return st;
    }
    { /* achromatic at the effective wavelength against N slices of a flat-f_nu SED */
        psf_setting s[5] = {{8, 4, 256, 0, 0, 0}, {8, 4, 256, 3, 0, 0}, {8, 4, 256, 5, 0, 0},
                            {8, 4, 256, 10, 0, 0}, {8, 4, 256, 20, 0, 0}};
        const char *v[5] = {"achromatic", "3", "5", "10", "20"};
        int n = q ? 3 : 5;
        if (q)
            for (int k = 0; k < n; k++) s[k].size = 128;
        if ((st = psf_knob(run, "nlambda", s, v, n, n - 1))) return st;
    }
    { /* the scene's star (image, normalisation, table) against the exact pixel-integrated
       * PSF; "unnormalised" keeps the image's unit flux per period */
        psf_setting s[3] = {{8, 4, 256, 0, 0, 0}, {8, 4, 256, 0, 0, 1}, {8, 4, 256, 0, 1, 0}};
        const char *v[3] = {"scene", "unnormalised", "exact"};
        if ((st = psf_knob(run, "star_method", s, v, 3, 2))) return st;
    }
    return WF_OK;
}

/* ---- galaxy ------------------------------------------------------------------------------- */

typedef struct gal_case {
    const char *name, *what;
    int star;
    double hlr, bulge_frac, knot_frac;
    int n_knots;
} gal_case;

/* Bulge half-light radius half the disk's, e = (0.2, 0.1), as GalSim's reference galaxies. */
static const gal_case gal_cases[] = {
    {"star", "point source", 1, 0, 0, 0, 0},
    {"small", "hlr 0.15\", bulge 0.3, 10 knots with 15% of the disk", 0, 0.15, 0.3, 0.15, 10},
    {"medium", "hlr 0.32\", bulge 0.3, 10 knots with 15% of the disk (a median catalog galaxy)", 0,
     0.32, 0.3, 0.15, 10},
    {"large", "hlr 1.5\", bulge 0.3, 10 knots with 15% of the disk", 0, 1.5, 0.3, 0.15, 10},
    {"bulge", "bulge-dominated: hlr 0.5\", bulge 0.8, no knots", 0, 0.5, 0.8, 0, 0},
    {"disk", "disk-dominated: hlr 0.5\", pure disk, 20 knots with 20% of the disk", 0, 0.5, 0.0,
     0.2, 20},
};
/* an arbitrary sub-pixel position; the star between pixels (see STAR_C) */
#define GAL_X 200.37
#define GAL_Y 200.71
#define GAL_STAR 200.5

typedef struct gal_setting {
    double ff, fold, kval;
    int knots;
    drawer *d;   /* NULL: the sweep's drawer; else one with a split PSF */
    double wtol; /* wing_tolerance (1e30: every galaxy takes the split) */
} gal_setting;

typedef struct gal_draw {
    drawer *d;
    const gal_case *gc;
    wf_galaxy g;
    double x, y;
    wf_stamp stamp;
} gal_draw;

/* Bounds and draw: what the renderer pays per object. */
static wf_status gal_once(void *ctx)
{
    gal_draw *gd = ctx;
    wf_stamp b;
    wf_status st = gd->gc->star ? wf_profile_point_bounds(&gd->d->work, &gd->d->ppsf, gd->x, gd->y, &b, NULL)
                                : wf_profile_galaxy_bounds(&gd->d->work, &gd->g, &gd->d->ppsf, gd->x, gd->y, &b, NULL);
    if (st) return st;
    if (b.x0 != gd->stamp.x0 || b.y0 != gd->stamp.y0 || b.nx != gd->stamp.nx || b.ny != gd->stamp.ny)
        return wf_error(WF_ERR_INTERNAL, "accuracy: stamp bounds changed between draws");
    return gd->gc->star ? wf_profile_draw_point(&gd->d->work, &gd->d->ppsf, 1.0, gd->x, gd->y, &gd->stamp)
                        : wf_profile_draw_galaxy(&gd->d->work, &gd->g, &gd->d->ppsf, gd->x, gd->y, &gd->stamp);
}

static wf_status gal_knob(acc_run *run, drawer *d, const gal_case *gc, const char *knob,
                          const gal_setting *set, const char *const *values, int n, int ref)
{
    wf_stamp *stamps = calloc((size_t)n, sizeof *stamps);
    acc_row *rows = calloc((size_t)n, sizeof *rows);
    wf_status st = WF_OK;
    if (!stamps || !rows) {
        st = wf_error(WF_ERR_NOMEM, "accuracy: out of memory");
        goto out;
    }
    for (int k = 0; k < n && !st; k++) {
        acc_row *r = &rows[k];
        row_init(r, "galaxy", gc->name, knob, values[k]);
        r->reference = k == ref;
        gal_draw gd;
        memset(&gd, 0, sizeof gd);
        gd.d = set[k].d ? set[k].d : d;
        gd.gc = gc;
        gd.x = gc->star ? GAL_STAR : GAL_X;
        gd.y = gc->star ? GAL_STAR : GAL_Y;
        wf_galaxy *g = &gd.g;
        g->id = 11;
        g->flux = 1.0;
        g->bulge_frac = gc->bulge_frac;
        g->hlr_disk = gc->hlr;
        g->hlr_bulge = 0.5 * gc->hlr;
        g->knot_frac = set[k].knots ? gc->knot_frac : 0.0;
        g->n_knots = set[k].knots ? gc->n_knots : 0;
        g->knot_seed = 5;
        g->e1 = 0.2, g->e2 = 0.1;
        if ((st = wf_profile_work_tune(&gd.d->work, set[k].ff, set[k].fold, set[k].kval, set[k].wtol, WF_PROFILE_KNOT_ACCURACY))) break;
        double fraction = 1;
        st = gc->star ? wf_profile_point_bounds(&gd.d->work, &gd.d->ppsf, gd.x, gd.y, &gd.stamp, &fraction)
                      : wf_profile_galaxy_bounds(&gd.d->work, g, &gd.d->ppsf, gd.x, gd.y, &gd.stamp, &fraction);
        if (st) break;
        if (!(gd.stamp.pix = malloc((size_t)gd.stamp.nx * gd.stamp.ny * sizeof(double)))) {
            st = wf_error(WF_ERR_NOMEM, "accuracy: cannot hold a %dx%d stamp", gd.stamp.nx, gd.stamp.ny);
            break;
        }
        stamps[k] = gd.stamp;
        double t0 = cpu_now();
        if ((st = gal_once(&gd))) break;
        double first = cpu_now() - t0, best;
        if ((st = best_time(gal_once, &gd, run->quick, &best))) break;
        stamps[k] = gd.stamp;
        r->cpu_seconds = best < first ? best : first;
        r->draw_ms = 1e3 * r->cpu_seconds;
        snprintf(r->notes, sizeof r->notes, "stamp %dx%d; FFT %d; bound holds %.5f", gd.stamp.nx,
                 gd.stamp.ny, gd.stamp.fft, fraction);
    }
    for (int k = 0; k < n && !st; k++) {
        if ((st = compare_stamps(&stamps[k], &stamps[ref], &rows[k]))) break;
        st = add_row(run, &rows[k]);
    }
    wf_profile_accuracy def;
    wf_profile_accuracy_default(&def);
    for (int k = 0; k < n; k++) {
        drawer *dk = set[k].d ? set[k].d : d;
        wf_status st2 = wf_profile_work_tune(&dk->work, def.flux_fraction, def.folding_threshold,
                                             def.kvalue_accuracy, 0.0, WF_PROFILE_KNOT_ACCURACY);
        if (!st) st = st2;
    }
out:
    if (stamps)
        for (int k = 0; k < n; k++) free(stamps[k].pix);
    free(stamps);
    free(rows);
    return st;
}

static wf_status sweep_galaxy(acc_run *run)
{
    const int q = run->quick;
    drawer d;
    wf_status st = drawer_open(run, 8, 4, 256, 0, 1, 0.0, &d); /* the scene's default PSF */
    if (st) return st;
    /* the same PSF split into core and wing (psf.core_radius) */
    enum { NCORE = 4 };
    static const double cores[NCORE] = {1.0, 1.5, 2.0, 3.0};
    drawer dc[NCORE];
    memset(dc, 0, sizeof dc);
    for (int i = 0; i < NCORE && !st; i++) st = drawer_open(run, 8, 4, 256, 0, 1, cores[i], &dc[i]);
    wf_profile_accuracy def;
    wf_profile_accuracy_default(&def);
    const double F = def.flux_fraction, T = def.folding_threshold, K = def.kvalue_accuracy;
    for (size_t c = 0; c < sizeof gal_cases / sizeof *gal_cases && !st; c++) {
        const gal_case *gc = &gal_cases[c];
        if (q && strcmp(gc->name, "star") && strcmp(gc->name, "medium")) continue;
        {
            gal_setting s[5] = {{0.9, T, K, 1, NULL, 0.0},   {0.99, T, K, 1, NULL, 0.0},
                                {0.995, T, K, 1, NULL, 0.0}, {0.999, T, K, 1, NULL, 0.0},
                                {0.9999, T, K, 1, NULL, 0.0}};
            const char *v[5] = {"0.9", "0.99", "0.995", "0.999", "0.9999"};
            if ((st = gal_knob(run, &d, gc, "flux_fraction", s, v, 5, 4))) break;
        }
        {
            gal_setting s[6] = {{F, 5e-2, K, 1, NULL, 0.0}, {F, 1e-2, K, 1, NULL, 0.0}, {F, 5e-3, K, 1, NULL, 0.0},
                                {F, 1e-3, K, 1, NULL, 0.0}, {F, 1e-4, K, 1, NULL, 0.0}, {F, 1e-5, K, 1, NULL, 0.0}};
            const char *v[6] = {"5e-2", "1e-2", "5e-3", "1e-3", "1e-4", "1e-5"};
            if ((st = q ? gal_knob(run, &d, gc, "folding_threshold", s + 2, v + 2, 3, 2)
                        : gal_knob(run, &d, gc, "folding_threshold", s, v, 6, 5)))
                break;
        }
        {
            gal_setting s[5] = {{F, T, 1e-3, 1, NULL, 0.0}, {F, T, 1e-4, 1, NULL, 0.0},
                                {F, T, 1e-5, 1, NULL, 0.0}, {F, T, 1e-6, 1, NULL, 0.0},
                                {F, T, 1e-7, 1, NULL, 0.0}};
            const char *v[5] = {"1e-3", "1e-4", "1e-5", "1e-6", "1e-7"};
            if ((st = q ? gal_knob(run, &d, gc, "kvalue_accuracy", s + 1, v + 1, 3, 2)
                        : gal_knob(run, &d, gc, "kvalue_accuracy", s, v, 5, 4)))
                break;
        }
        if (gc->n_knots) {
            gal_setting s[2] = {{F, T, K, 0, NULL, 0.0}, {F, T, K, 1, NULL, 0.0}};
            const char *v[2] = {"off", "on"};
            if ((st = gal_knob(run, &d, gc, "knots", s, v, 2, 1))) break;
        }
        if (!gc->star) { /* every galaxy forced onto the split (a scene takes it only where
                          * the noise hides the bound) */
            gal_setting s[NCORE + 1];
            const char *v[NCORE + 1] = {"1.0", "1.5", "2.0", "3.0", "off"};
            for (int i = 0; i <= NCORE; i++)
                s[i] = (gal_setting){F, T, K, 1, i < NCORE ? &dc[i] : NULL, i < NCORE ? 1e30 : 0.0};
            if ((st = q ? gal_knob(run, &d, gc, "core_radius", s + 2, v + 2, 3, 2)
                        : gal_knob(run, &d, gc, "core_radius", s, v, NCORE + 1, NCORE)))
                break;
        }
    }
    for (int i = 0; i < NCORE; i++) drawer_free(&dc[i]);
    drawer_free(&d);
    return st;
}

/* ---- scene -------------------------------------------------------------------------------- */

typedef struct scene_in {
    wf_config cfg; /* pointing, date, readout and detector defaults */
    wf_catalog gal, stars;
    int have;
    int n; /* the region: SCA pixels [0, n)^2 */
} scene_in;

static void scene_in_free(scene_in *in)
{
    if (in->have) {
        wf_catalog_free(&in->gal);
        wf_catalog_free(&in->stars);
    }
    in->have = 0;
}

/* The synthetic field around the region, widened by the largest stamp reach (70"), as
 * `wfisim expose` selects it for a whole SCA. */
static wf_status scene_inputs(const acc_run *run, int n, scene_in *in)
{
    memset(in, 0, sizeof *in);
    in->n = n;
    wf_config_defaults(&in->cfg);
    wf_focal_plane fp;
    wf_wcs w;
    wf_status st;
    if ((st = wf_wcs_focal_plane(run->data[0] ? run->data : NULL, &fp)) ||
        (st = wf_wcs_for_sca(&fp, in->cfg.ra, in->cfg.dec, in->cfg.pa, run->sca, &w)))
        return st;
    double ra[4], dec[4];
    const double cx[4] = {-0.5, n - 0.5, n - 0.5, -0.5}, cy[4] = {-0.5, -0.5, n - 0.5, n - 0.5};
    for (int k = 0; k < 4; k++)
        if ((st = wf_wcs_pix2world(&w, cx[k], cy[k], &ra[k], &dec[k]))) return st;
    wf_skyregion reg;
    if ((st = wf_skyindex_polygon(ra, dec, 4, 70.0, &reg))) return st;
    wf_synth_config sc;
    wf_synth *syn;
    if ((st = wf_synth_defaults(&sc))) return st;
    sc.seed = in->cfg.seed;
    if ((st = wf_synth_create(&sc, &syn))) return st;
    st = wf_synth_select(syn, &reg, &in->gal, &in->stars);
    wf_synth_free(syn);
    if (!st) in->have = 1;
    return st;
}

/* Noise-free rates (e-/pixel/s) of the region as the renderer hands them to the firmware. */
static wf_status scene_render(const acc_run *run, const scene_in *in, int bin, int over, int size,
                              double ff, int sky, double tol, double core, int levels, float *rate,
                              double *cpu, char *notes, size_t cap)
{
    wf_scene_setup ss;
    wf_scene_setup_default(&ss);
    ss.ra = in->cfg.ra, ss.dec = in->cfg.dec, ss.pa = in->cfg.pa, ss.mjd = in->cfg.mjd;
    ss.sca = run->sca;
    snprintf(ss.filter, sizeof ss.filter, "%s", run->filter);
    snprintf(ss.data_dir, sizeof ss.data_dir, "%s", run->data);
    ss.ncols = ss.nrows = in->n;
    ss.pupil_bin = bin;
    ss.psf_oversample = over;
    ss.psf_size = size;
    ss.flux_fraction = ff;
    ss.sky_on = sky;
    ss.noise_tolerance = tol;
    ss.core_radius = core;
    if (levels > 0) ss.core_levels = levels;
    ss.exptime = in->cfg.ro.exptime;
    ss.threads = 1;
    double t0 = cpu_now();
    wf_scene *sc = NULL;
    wf_scene_source src;
    wf_status st = wf_scene_create(&ss, in->gal.n ? &in->gal : NULL, in->stars.n ? &in->stars : NULL, &sc);
    double t1 = cpu_now();
    if (!st) st = wf_scene_source_for(sc, 0, &src);
    for (int y = 0; y < in->n && !st; y += TILE) {
        int y1 = y + TILE < in->n ? y + TILE : in->n;
        st = wf_scene_fill(&src, y, y1, in->n, rate + (size_t)y * in->n);
    }
    *cpu = cpu_now() - t0;
    if (!st) {
        wf_scene_stats ss2;
        wf_scene_get_stats(sc, &ss2);
        snprintf(notes, cap, "%ld galaxies; %ld stars; set-up %.2f s; PSF image holds %.4f",
                 ss2.galaxies, ss2.stars, t1 - t0, ss2.psf_image_sum);
    }
    wf_scene_destroy(sc);
    return st;
}

typedef struct render_setting {
    int bin, over, size;
    double ff;
    double tol, core; /* scene.noise_tolerance, psf.core_radius (0, 0: every object exact) */
    int sky;          /* 1: rendered on the sky (whose noise tol refers to), then taken off */
    int levels;       /* psf.core_levels (0: the scene's default) */
} render_setting;

static wf_status render_knob(acc_run *run, const scene_in *in, const char *tcase, const char *knob,
                             const render_setting *set, const char *const *values, int n, int ref)
{
    size_t np = (size_t)in->n * in->n;
    float *rate = malloc(np * sizeof *rate * (size_t)n);
    double *a = malloc(np * sizeof *a), *b = malloc(np * sizeof *b);
    acc_row *rows = calloc((size_t)n, sizeof *rows);
    wf_status st = WF_OK;
    if (!rate || !a || !b || !rows) {
        st = wf_error(WF_ERR_NOMEM, "accuracy: cannot hold %d renderings of %dx%d", n, in->n, in->n);
        goto out;
    }
    for (int k = 0; k < n && !st; k++) {
        row_init(&rows[k], "scene", tcase, knob, values[k]);
        rows[k].reference = k == ref;
        st = scene_render(run, in, set[k].bin, set[k].over, set[k].size, set[k].ff, set[k].sky, set[k].tol,
                          set[k].core, set[k].levels, rate + (size_t)k * np, &rows[k].cpu_seconds, rows[k].notes,
                          sizeof rows[k].notes);
        if (!st && set[k].sky) { /* the same sky alone, taken off */
            scene_in empty = *in;
            empty.gal.n = empty.stars.n = 0;
            float *sky = malloc(np * sizeof *sky);
            double c;
            char nn[8];
            if (!sky) st = wf_error(WF_ERR_NOMEM, "accuracy: out of memory");
            else st = scene_render(run, &empty, set[k].bin, set[k].over, set[k].size, set[k].ff, 1, 0.0, 0.0, 0,
                                   sky, &c, nn, sizeof nn);
            for (size_t i = 0; i < np && !st; i++) rate[(size_t)k * np + i] -= sky[i];
            free(sky);
        }
    }
    for (size_t i = 0; i < np && !st; i++) b[i] = rate[(size_t)ref * np + i];
    for (int k = 0; k < n && !st; k++) {
        for (size_t i = 0; i < np; i++) a[i] = rate[(size_t)k * np + i];
        compare(a, b, in->n, in->n, 0, &rows[k]);
        st = add_row(run, &rows[k]);
    }
out:
    free(rate), free(a), free(b), free(rows);
    return st;
}

typedef struct rate_source {
    const float *rate;
    int ncols;
} rate_source;

static wf_status rate_fill(void *ctx, int y0, int y1, int ncols, float *out)
{
    const rate_source *rs = ctx;
    if (ncols != rs->ncols) return wf_error(WF_ERR_INTERNAL, "accuracy: %d columns asked of %d", ncols, rs->ncols);
    memcpy(out, rs->rate + (size_t)y0 * ncols, (size_t)(y1 - y0) * ncols * sizeof *out);
    return WF_OK;
}

static wf_status read_plane(fitsfile *f, const char *path, const char *ext, int type, long n, void *out)
{
    int status = 0;
    long first[2] = {1, 1};
    fits_movnam_hdu(f, IMAGE_HDU, (char *)ext, 0, &status);
    fits_read_pix(f, type, first, n, NULL, out, NULL, &status);
    if (status) {
        char msg[FLEN_STATUS];
        fits_get_errstatus(status, msg);
        return wf_error(WF_ERR_IO, "%s[%s]: %s", path, ext, msg);
    }
    return WF_OK;
}

/* One exposure of the recorded rates through readout, assembly and ramp fit (cosmic rays
 * off: they are not a knob); SCI and DQ (and ERR when asked) of the product, and the CPU
 * seconds of the chain. corr: 0 no correlated read noise, 1 1/f and channel offsets, 2 those
 * and the reference border with its correction (firmware/corrnoise.h). */
static wf_status scene_readout(const acc_run *run, const scene_in *in, const float *rate,
                               wf_mode mode, wf_sampling sampling, int nl, int corr, float *sci,
                               unsigned *dq, float *err, double *cpu)
{
    wf_config cfg = in->cfg;
    cfg.ro.ncols = cfg.ro.nrows = in->n;
    cfg.ro.sca = (uint32_t)run->sca;
    cfg.ro.mode = mode;
    cfg.ro.sampling = sampling;
    cfg.ro.det.on.cosmic_rays = 0;
    cfg.ro.det.on.nonlinearity = nl;
    cfg.ro.det.on.read_1f = cfg.ro.det.on.channel_offsets = corr > 0;
    cfg.ro.det.on.refpix = corr > 1;
    wf_clock clock;
    wf_status st = wf_config_finish(&cfg, &clock);
    if (st) return st;
    rate_source rs = {rate, in->n};
    wf_scene_source src = {&rs, rate_fill, NULL, NULL};
    wf_expose_job job;
    memset(&job, 0, sizeof job);
    job.ro = cfg.ro;
    job.clock = clock;
    job.noise = (wf_noise){WF_NOISE_PHILOX, cfg.seed, cfg.ro.exposure, cfg.ro.sca};
    job.scenes = &src;
    job.threads = 1;
    wf_link_memory mem;
    wf_link link;
    if ((st = wf_link_memory_open(&mem, &link))) return st;
    job.link = &link;
    char dir[WF_PATH_MAX + 32], path[WF_PATH_MAX + 128] = "";
    snprintf(dir, sizeof dir, "%s/.scene-XXXXXX", run->out);
    double t0 = cpu_now();
    st = wf_expose_run(&job);
    if (!st && !mkdtemp(dir)) st = wf_error(WF_ERR_IO, "%s: cannot create a temporary directory: %s", dir, strerror(errno));
    if (!st) {
        FILE *f = fmemopen(mem.data, mem.len, "rb");
        wf_assemble_options opt = {.out_dir = dir, .quiet = 1};
        st = f ? wf_assemble_stream(f, "accuracy readout", &opt, path, sizeof path)
               : wf_error(WF_ERR_IO, "accuracy: cannot read the packet stream back");
        if (f) fclose(f);
    }
    *cpu = cpu_now() - t0;
    wf_link_memory_close(&mem);
    if (!st) {
        fitsfile *f;
        int status = 0;
        if (fits_open_diskfile(&f, path, READONLY, &status)) {
            st = wf_error(WF_ERR_IO, "%s: cannot open the product (cfitsio %d)", path, status);
        } else {
            long np = (long)in->n * in->n;
            st = read_plane(f, path, "SCI", TFLOAT, np, sci);
            if (!st) st = read_plane(f, path, "DQ", TUINT, np, dq);
            if (!st && err) st = read_plane(f, path, "ERR", TFLOAT, np, err);
            status = 0;
            fits_close_file(f, &status);
        }
    }
    if (path[0]) remove(path);
    rmdir(dir);
    return st;
}

/* Mean of a - b (and its standard error) over pixels unflagged in both, where sel says; the
 * pixels' noise is independent between two exposures, so the error is that of the mean of
 * the per-pixel differences. */
static void mean_diff(const float *a, const float *b, const unsigned *dqa, const unsigned *dqb,
                      const float *truth, double lo, long np, double *rel, double *se, long *count)
{
    double s = 0, s2 = 0, ref = 0;
    long c = 0;
    for (long i = 0; i < np; i++) {
        if (dqa[i] || (dqb && dqb[i]) || truth[i] < lo) continue;
        double d = (double)a[i] - b[i];
        s += d, s2 += d * d, ref += b[i], c++;
    }
    *count = c;
    if (c < 2 || !(ref != 0)) {
        *rel = *se = NAN;
        return;
    }
    double m = s / c, var = (s2 - c * m * m) / (c - 1);
    *rel = s / ref;
    *se = sqrt(var / c) / (ref / c);
}

typedef struct sampling_setting {
    const char *value;
    wf_mode mode;
    wf_sampling sampling;
} sampling_setting;

static wf_status sampling_knob(acc_run *run, const scene_in *in, const float *truth, int nl)
{
    enum { NSET = 4 };
    static const sampling_setting set[NSET] = {{"per-read", WF_MODE_RAMP, WF_SAMPLE_PER_READ},
                                               {"direct", WF_MODE_RAMP, WF_SAMPLE_DIRECT},
                                               {"moments", WF_MODE_RAMP, WF_SAMPLE_MOMENTS},
                                               {"single", WF_MODE_SINGLE, WF_SAMPLE_PER_READ}};
    const int n = NSET;
    long np = (long)in->n * in->n;
    float *sci = malloc(sizeof *sci * (size_t)np * NSET);
    unsigned *dq = malloc(sizeof *dq * (size_t)np * NSET);
    float *input = malloc(sizeof *input * (size_t)np);
    wf_status st = WF_OK;
    if (!sci || !dq || !input) {
        st = wf_error(WF_ERR_NOMEM, "accuracy: cannot hold %d exposures of %dx%d", n, in->n, in->n);
        goto out;
    }
    for (long i = 0; i < np; i++) input[i] = truth[i] + (float)in->cfg.ro.det.dark_current;
    acc_row rows[NSET];
    for (int k = 0; k < n && !st; k++) {
        row_init(&rows[k], "scene", nl ? "sampling-nl" : "sampling-lin", "sampling", set[k].value);
        rows[k].reference = k == 0;
        st = scene_readout(run, in, truth, set[k].mode, set[k].sampling, nl, 0, sci + (size_t)k * np,
                           dq + (size_t)k * np, NULL, &rows[k].cpu_seconds);
    }
    for (int k = 0; k < n && !st; k++) {
        acc_row *r = &rows[k];
        const float *a = sci + (size_t)k * np;
        const unsigned *da = dq + (size_t)k * np;
        long call, cbright, c2;
        double peak_se, tall, tall_se, tb, tb_se;
        mean_diff(a, sci, da, dq, truth, -INFINITY, np, &r->d_flux, &r->d_flux_se, &call);
        mean_diff(a, sci, da, dq, truth, BRIGHT_RATE, np, &r->d_peak, &peak_se, &cbright);
        /* against the noise-free input plus dark current, for scale: the fit corrects
         * neither reciprocity failure nor (single frame) nonlinearity */
        mean_diff(a, input, da, NULL, truth, -INFINITY, np, &tall, &tall_se, &c2);
        mean_diff(a, input, da, NULL, truth, BRIGHT_RATE, np, &tb, &tb_se, &c2);
        snprintf(r->notes, sizeof r->notes,
                 "%ld px (%ld above %g e-/s: %+.1e +- %.0e); vs input + dark %+.1e (above %g: %+.1e)", call,
                 cbright, BRIGHT_RATE, r->d_peak, peak_se, tall, BRIGHT_RATE, tb);
        if ((st = add_row(run, r))) break;
    }
out:
    free(sci);
    free(dq);
    free(input);
    return st;
}

/* Correlated read noise (1/f and channel offsets, with and without the reference-pixel
 * correction) against none: the Poisson and white read-noise draws are the same in every
 * run (their keys do not change), so the difference of two products is the effect's alone.
 * A star's photometry: the sum over a 3-pixel-radius aperture, at a grid of places 8 pixels
 * apart (the effect adds to the signal, so where the star is does not matter), its error's
 * rms against the aperture's noise as ERR states it (what the effect adds unannounced). */
#define CORR_AP 3
#define CORR_STEP 8
static wf_status corr_knob(acc_run *run, const scene_in *in, const float *truth)
{
    static const char *value[3] = {"off", "1/f+offsets", "1/f+offsets+refpix"};
    long np = (long)in->n * in->n;
    float *sci = malloc(sizeof *sci * (size_t)np * 3), *err = malloc(sizeof *err * (size_t)np * 3);
    unsigned *dq = malloc(sizeof *dq * (size_t)np * 3);
    wf_status st = WF_OK;
    if (!sci || !dq || !err) {
        st = wf_error(WF_ERR_NOMEM, "accuracy: cannot hold 3 exposures of %dx%d", in->n, in->n);
        goto out;
    }
    acc_row rows[3];
    for (int k = 0; k < 3 && !st; k++) {
        row_init(&rows[k], "scene", "readnoise", "corr_noise", value[k]);
        rows[k].reference = k == 0;
        st = scene_readout(run, in, truth, WF_MODE_RAMP, WF_SAMPLE_PER_READ, 1, k, sci + (size_t)k * np,
                           dq + (size_t)k * np, err + (size_t)k * np, &rows[k].cpu_seconds);
    }
    /* a 25 mag star's rate in this filter (flat f_nu) */
    const double star = run->bp ? wf_bandpass_countrate_ab(run->bp, 25.0) : NAN;
    for (int k = 0; k < 3 && !st; k++) {
        acc_row *r = &rows[k];
        const float *a = sci + (size_t)k * np;
        long call;
        mean_diff(a, sci, dq + (size_t)k * np, dq, truth, -INFINITY, np, &r->d_flux, &r->d_flux_se, &call);
        double s = 0, s2 = 0, white = 0;
        long nap = 0;
        for (int cy = CORR_AP + 1; cy + CORR_AP + 1 < in->n; cy += CORR_STEP)
            for (int cx = CORR_AP + 1; cx + CORR_AP + 1 < in->n; cx += CORR_STEP) {
                double d = 0, w = 0;
                int flagged = 0;
                for (int y = cy - CORR_AP; y <= cy + CORR_AP; y++)
                    for (int x = cx - CORR_AP; x <= cx + CORR_AP; x++) {
                        if ((x - cx) * (x - cx) + (y - cy) * (y - cy) > CORR_AP * CORR_AP) continue;
                        long i = (long)y * in->n + x;
                        flagged |= dq[i] || dq[(size_t)k * np + i];
                        d += (double)a[i] - sci[i];
                        w += (double)err[i] * err[i];
                    }
                if (flagged) continue;
                s += d, s2 += d * d, white += sqrt(w), nap++;
            }
        double rms = nap ? sqrt(s2 / nap) : NAN;
        snprintf(r->notes, sizeof r->notes,
                 "r=%d px aperture (%ld places): rms dflux %.3g e-/s = %.2f x its ERR (%.3g), mean %+.2g; "
                 "%.1f%% of a 25 mag star", CORR_AP, nap, rms, nap ? rms / (white / nap) : NAN, nap ? white / nap : NAN,
                 nap ? s / nap : NAN, 100.0 * rms / star);
        if ((st = add_row(run, r))) break;
    }
out:
    free(sci);
    free(dq);
    free(err);
    return st;
}

static wf_status sweep_scene(acc_run *run)
{
    const int q = run->quick, n = q ? 128 : 512;
    scene_in in;
    wf_status st = scene_inputs(run, n, &in);
    if (st) return st;
    char tcase[16];
    snprintf(tcase, sizeof tcase, "region%d", n);
    {
        render_setting s[4] = {{8, 4, 256, 0.995, 0.0, 0.0, 0, 0}, {4, 4, 256, 0.995, 0.0, 0.0, 0, 0}, {2, 4, 256, 0.995, 0.0, 0.0, 0, 0}, {1, 4, 256, 0.995, 0.0, 0.0, 0, 0}};
        const char *v[4] = {"8", "4", "2", "1"};
        int k = q ? 2 : 4;
        if ((st = render_knob(run, &in, tcase, "pupil_bin", s, v, k, k - 1))) goto out;
    }
    if (!q) { /* at the default 7.04" extent: psf.oversample alone keeps 256 samples */
        render_setting s[3] = {{8, 2, 128, 0.995, 0.0, 0.0, 0, 0}, {8, 4, 256, 0.995, 0.0, 0.0, 0, 0}, {8, 8, 512, 0.995, 0.0, 0.0, 0, 0}};
        const char *v[3] = {"2", "4", "8"};
        if ((st = render_knob(run, &in, tcase, "oversample", s, v, 3, 2))) goto out;
    }
    if (!q) {
        render_setting s[3] = {{8, 4, 128, 0.995, 0.0, 0.0, 0, 0}, {8, 4, 256, 0.995, 0.0, 0.0, 0, 0}, {8, 4, 512, 0.995, 0.0, 0.0, 0, 0}};
        const char *v[3] = {"128", "256", "512"};
        if ((st = render_knob(run, &in, tcase, "psf_size", s, v, 3, 2))) goto out;
    }
    if (!q) {
        render_setting s[4] = {{8, 4, 256, 0.99, 0.0, 0.0, 0, 0}, {8, 4, 256, 0.995, 0.0, 0.0, 0, 0}, {8, 4, 256, 0.999, 0.0, 0.0, 0, 0}, {8, 4, 256, 0.9999, 0.0, 0.0, 0, 0}};
        const char *v[4] = {"0.99", "0.995", "0.999", "0.9999"};
        if ((st = render_knob(run, &in, tcase, "flux_fraction", s, v, 4, 3))) goto out;
    }
    { /* per-object knobs from the sky noise (sim/draw/scene.h), with the default split PSF */
        render_setting s[4] = {{8, 4, 256, 0.995, 3.0, 2.0, 1, 0}, {8, 4, 256, 0.995, 1.0, 2.0, 1, 0},
                               {8, 4, 256, 0.995, 0.3, 2.0, 1, 0}, {8, 4, 256, 0.995, 0.0, 2.0, 1, 0}};
        const char *v[4] = {"3", "1", "0.3", "0"};
        if ((st = render_knob(run, &in, tcase, "noise_tolerance", s, v, 4, 3))) goto out;
    }
    if (!q) { /* the core radius at the default tolerance, one core */
        render_setting s[4] = {{8, 4, 256, 0.995, 1.0, 1.5, 1, 1}, {8, 4, 256, 0.995, 1.0, 2.0, 1, 1},
                               {8, 4, 256, 0.995, 1.0, 3.0, 1, 1}, {8, 4, 256, 0.995, 0.0, 2.0, 1, 1}};
        const char *v[4] = {"1.5", "2", "3", "exact"};
        if ((st = render_knob(run, &in, tcase, "core_radius", s, v, 4, 3))) goto out;
    }
    if (!q) { /* the core levels (radii 2", 1", 0.5", 0.25") at the default tolerance */
        render_setting s[5] = {{8, 4, 256, 0.995, 1.0, 2.0, 1, 1}, {8, 4, 256, 0.995, 1.0, 2.0, 1, 2},
                               {8, 4, 256, 0.995, 1.0, 2.0, 1, 3}, {8, 4, 256, 0.995, 1.0, 2.0, 1, 4},
                               {8, 4, 256, 0.995, 0.0, 2.0, 1, 1}};
        const char *v[5] = {"1", "2", "3", "4", "exact"};
        if ((st = render_knob(run, &in, tcase, "core_levels", s, v, 5, 4))) goto out;
    }
    { /* the readout modes on the default rendering, sky included */
        float *truth = malloc(sizeof *truth * (size_t)n * n);
        double cpu;
        char notes[160];
        if (!truth) {
            st = wf_error(WF_ERR_NOMEM, "accuracy: cannot hold a %dx%d rendering", n, n);
            goto out;
        }
        st = scene_render(run, &in, 8, 4, 256, 0.995, 1, 1.0, 2.0, 0, truth, &cpu, notes, sizeof notes);
        if (!st) st = sampling_knob(run, &in, truth, 1);
        if (!st) st = corr_knob(run, &in, truth);
        if (!st && !q) st = sampling_knob(run, &in, truth, 0);
        free(truth);
    }
out:
    scene_in_free(&in);
    return st;
}

/* ---- detector effects left out ------------------------------------------------------------ */

#define PERSIST_N 33 /* the patch: a Gaussian star (sigma 1 pixel) at its centre */

/* What leaving persistence out does to a faint star's photometry: the star follows, at the
 * same pixels, a saturating star (AB 14, its core at the full well, ~40 pixels above
 * detector.persistence.min_stimulus) that ended dt seconds before. Readout (MA table 6),
 * assembly and ramp fit with photon and read noise off, so the two runs differ only by the
 * released charge: Δflux is the fitted flux in a 3-pixel-radius aperture without persistence
 * against with it, Δpeak the same for the brightest pixel. */
static wf_status persistence_rows(acc_run *run)
{
    const int n = PERSIST_N;
    const long np = (long)n * n;
    scene_in in;
    memset(&in, 0, sizeof in);
    wf_config_defaults(&in.cfg);
    in.n = n;
    in.cfg.ro.det.on.photon_noise = in.cfg.ro.det.on.read_noise = 0;
    wf_clock clock;
    wf_config tmp = in.cfg;
    wf_status st = wf_config_finish(&tmp, &clock);
    if (st) return st;
    const double t = wf_clock_exposure_time(&clock);
    float *rate = malloc(sizeof *rate * (size_t)np), *sci = malloc(sizeof *sci * (size_t)np * 2);
    unsigned *dq = malloc(sizeof *dq * (size_t)np * 2);
    if (!rate || !sci || !dq) {
        free(rate), free(sci), free(dq);
        return wf_error(WF_ERR_NOMEM, "accuracy: persistence patch");
    }
    const double mags[2] = {24.0, 22.0}, dts[4] = {56.0, 406.0, 1800.0, 3600.0};
    wf_scene_grid bright = {n, n, 0.0, wf_bandpass_countrate_ab(run->bp, 14.0), 1.0, n};
    wf_scene_source bsrc;
    if (!st) st = wf_scene_grid_source(&bright, &bsrc);
    for (int m = 0; m < 2 && !st; m++) {
        wf_scene_grid faint = {n, n, 0.0, wf_bandpass_countrate_ab(run->bp, mags[m]), 1.0, n};
        wf_scene_source fsrc;
        if ((st = wf_scene_grid_source(&faint, &fsrc)) || (st = fsrc.fill_rate(fsrc.ctx, 0, n, n, rate))) break;
        in.cfg.ro.persist.source = (wf_persist_source){0};
        double cpu_off;
        if ((st = scene_readout(run, &in, rate, WF_MODE_RAMP, WF_SAMPLE_PER_READ, 1, 0, sci, dq, NULL, &cpu_off))) break;
        for (int k = 0; k < 4 && !st; k++) {
            wf_persist_history *h = NULL;
            st = wf_persist_history_new(n, n, in.cfg.persist.min_stimulus, in.cfg.ro.det.full_well, &h);
            if (!st) st = wf_persist_history_add_source(h, &bsrc, t, dts[k]);
            acc_row r;
            char tcase[16], value[24];
            snprintf(tcase, sizeof tcase, "star%.0f", mags[m]);
            snprintf(value, sizeof value, "off (dt %.0f s)", dts[k]); /* no comma: a CSV field */
            row_init(&r, "detector", tcase, "persistence", value);
            if (!st) {
                wf_persist_history_source(h, &in.cfg.ro.persist.source);
                st = scene_readout(run, &in, rate, WF_MODE_RAMP, WF_SAMPLE_PER_READ, 1, 0, sci + np, dq + np,
                                   NULL, &r.cpu_seconds);
            }
            if (!st) {
                double on = 0, off = 0, pk_on = 0, pk_off = 0, dark = in.cfg.ro.det.dark_current;
                const double c = 0.5 * n; /* the grid's one source, between pixels */
                int marked = 0;
                for (int y = 0; y < n; y++)
                    for (int x = 0; x < n; x++) {
                        long i = (long)y * n + x;
                        marked += (dq[np + i] & WF_DQ_PERSISTENCE) != 0;
                        if ((x + 0.5 - c) * (x + 0.5 - c) + (y + 0.5 - c) * (y + 0.5 - c) > 9.0) continue;
                        on += sci[np + i] - dark;
                        off += sci[i] - dark;
                        if (x == n / 2 && y == n / 2) pk_on = sci[np + i] - dark, pk_off = sci[i] - dark;
                    }
                r.d_flux = off / on - 1.0;
                r.d_peak = pk_off / pk_on - 1.0;
                snprintf(r.notes, sizeof r.notes,
                         "star %.1f e-/s in the aperture; persistence adds %.3f e-/s there; %d pixels DQ PERSISTENCE",
                         off, on - off, marked);
                st = add_row(run, &r);
            }
            in.cfg.ro.persist.source = (wf_persist_source){0};
            wf_persist_history_free(h);
        }
    }
    free(rate);
    free(sci);
    free(dq);
    return st;
}

static wf_status sweep_detector(acc_run *run)
{
    return persistence_rows(run);
}

/* ---- output ------------------------------------------------------------------------------- */

static wf_status make_dir(const char *dir)
{
    char buf[WF_PATH_MAX];
    snprintf(buf, sizeof buf, "%s", dir);
    for (char *p = buf + 1; *p; p++)
        if (*p == '/') {
            *p = '\0';
            if (mkdir(buf, 0777) != 0 && errno != EEXIST)
                return wf_error(WF_ERR_IO, "--out: cannot create directory %s: %s", buf, strerror(errno));
            *p = '/';
        }
    if (mkdir(buf, 0777) != 0 && errno != EEXIST)
        return wf_error(WF_ERR_IO, "--out: cannot create directory %s: %s", buf, strerror(errno));
    return WF_OK;
}

typedef void (*writer_fn)(FILE *f, const acc_run *run, const char *kind);

/* Written to PATH.tmp and renamed, so an interrupted run leaves the previous file. */
static wf_status write_atomic(const acc_run *run, const char *name, writer_fn fn, const char *kind)
{
    char path[WF_PATH_MAX + 64], tmp[WF_PATH_MAX + 80];
    snprintf(path, sizeof path, "%s/%s", run->out, name);
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    FILE *f = fopen(tmp, "w");
    if (!f) return wf_error(WF_ERR_IO, "%s: cannot create: %s", tmp, strerror(errno));
    fn(f, run, kind);
    int bad = ferror(f);
    if (fclose(f) != 0) bad = 1;
    if (bad) {
        remove(tmp);
        return wf_error(WF_ERR_IO, "%s: write failed", tmp);
    }
    return wf_file_rename(tmp, path);
}

static void csv_num(FILE *f, double v)
{
    if (isfinite(v)) fprintf(f, ",%.6e", v);
    else fputs(",", f);
}

static void write_csv(FILE *f, const acc_run *run, const char *kind)
{
    fputs("kind,case,knob,value,reference,d_flux,d_flux_se,d_peak,d_core,d_max,d_sigma,d_e1,d_e2,"
          "cpu_seconds,draw_ms,notes\n", f);
    for (size_t i = 0; i < run->n; i++) {
        const acc_row *r = &run->rows[i];
        if (strcmp(r->kind, kind)) continue;
        fprintf(f, "%s,%s,%s,%s,%d", r->kind, r->tcase, r->knob, r->value, r->reference);
        csv_num(f, r->d_flux);
        csv_num(f, r->d_flux_se);
        csv_num(f, r->d_peak);
        csv_num(f, r->d_core);
        csv_num(f, r->d_max);
        csv_num(f, r->d_sigma);
        csv_num(f, r->d_e1);
        csv_num(f, r->d_e2);
        csv_num(f, r->cpu_seconds);
        csv_num(f, r->draw_ms);
        fprintf(f, ",%s\n", r->notes);
    }
}

/* rows of a readout setting (one table, fitted rates compared): sampling and correlated noise */
static int is_sampling(const acc_row *r) { return !strcmp(r->knob, "sampling") || !strcmp(r->knob, "corr_noise"); }

static void md_num(FILE *f, double v, int reference)
{
    if (reference && isfinite(v)) fputs(" | 0", f);
    else if (isfinite(v)) fprintf(f, " | %+.1e", v);
    else fputs(" | —", f);
}

static void md_abs(FILE *f, double v, int reference)
{
    if (reference && isfinite(v)) fputs(" | 0", f);
    else if (isfinite(v)) fprintf(f, " | %.1e", v);
    else fputs(" | —", f);
}

static void md_header(FILE *f, const acc_run *run)
{
    struct utsname u;
    char cpu[256] = "unknown CPU", date[64] = "";
    if (uname(&u) != 0) memset(&u, 0, sizeof u);
    FILE *ci = fopen("/proc/cpuinfo", "r");
    if (ci) {
        char line[512];
        while (fgets(line, sizeof line, ci))
            if (!strncmp(line, "model name", 10) && strchr(line, ':')) {
                snprintf(cpu, sizeof cpu, "%s", strchr(line, ':') + 2);
                cpu[strcspn(cpu, "\n")] = '\0';
                break;
            }
        fclose(ci);
    }
    time_t now = time(NULL);
    struct tm tmv;
    if (gmtime_r(&now, &tmv)) strftime(date, sizeof date, "%Y-%m-%d %H:%M UTC", &tmv);
    fprintf(f, "# wfisim accuracy: error against CPU time\n\n");
    fprintf(f, "Command: `%s`. %s; %s %s %s, %s, %ld cores online; compiler %s.\n", run->command,
            date, u.sysname, u.release, u.machine, cpu, sysconf(_SC_NPROCESSORS_ONLN),
#ifdef __VERSION__
            __VERSION__
#else
            "unknown"
#endif
    );
    fprintf(f, "Filter %s, SCA %d; pupil and aberrations: %s; bandpass: %s.\n\n", run->filter,
            run->sca, run->data[0] ? run->data : "analytic pupil, no aberrations",
            run->bp ? run->bp->source : "?");
    fprintf(f, "Each knob is swept with the others at their defaults; errors are against the "
               "sweep's **reference** row (its highest-fidelity setting): flux, peak and "
               "adaptive size σ relative, the worst 3×3-core pixel and the worst pixel in units "
               "of the reference peak, e1/e2 (distortion) absolute. CPU seconds are process "
               "CPU time, the best of a few repeats for cases under a second.\n\n");
}

static void md_table(FILE *f, const acc_run *run, const char *kind, int sampling)
{
    int any = 0;
    for (size_t i = 0; i < run->n; i++) {
        const acc_row *r = &run->rows[i];
        if (strcmp(r->kind, kind) || is_sampling(r) != sampling) continue;
        if (!any) {
            if (sampling)
                fputs("| case | setting | Δ mean rate (all pixels) | ± | CPU s | notes |\n"
                      "|---|---|---|---|---|---|\n", f);
            else
                fputs("| case | knob | value | Δflux | Δpeak | 3×3 core | worst pixel | Δσ/σ | Δe1 | "
                      "Δe2 | CPU s | draw ms | notes |\n"
                      "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n", f);
            any = 1;
        }
        if (sampling) {
            fprintf(f, "| %s | %s%s", r->tcase, r->value, r->reference ? " (ref)" : "");
            md_num(f, r->d_flux, r->reference);
            md_abs(f, r->d_flux_se, 0);
            fprintf(f, " | %.3f | %s |\n", r->cpu_seconds, r->notes);
            continue;
        }
        fprintf(f, "| %s | %s | %s%s", r->tcase, r->knob, r->value, r->reference ? " (ref)" : "");
        md_num(f, r->d_flux, r->reference);
        md_num(f, r->d_peak, r->reference);
        md_abs(f, r->d_core, r->reference);
        md_abs(f, r->d_max, r->reference);
        md_num(f, r->d_sigma, r->reference);
        md_num(f, r->d_e1, r->reference);
        md_num(f, r->d_e2, r->reference);
        fprintf(f, " | %.4g", r->cpu_seconds);
        if (isfinite(r->draw_ms)) fprintf(f, " | %.3g", r->draw_ms);
        else fputs(" | —", f);
        fprintf(f, " | %s |\n", r->notes);
    }
    if (any) fputs("\n", f);
}

/* Links to the plots of a kind that exist (a group without a positive error has none). */
static void md_plots(FILE *f, const acc_run *run, const char *kind)
{
    int any = 0;
    for (size_t i = 0; i <= run->n; i++) {
        char name[64], path[WF_PATH_MAX + 64];
        if (i == run->n) {
            if (strcmp(kind, "scene")) break;
            snprintf(name, sizeof name, "accuracy_scene_sampling.png");
        } else {
            const acc_row *r = &run->rows[i];
            if (strcmp(r->kind, kind) || !strcmp(r->knob, "sampling")) continue;
            int first = 1;
            for (size_t j = 0; j < i && first; j++)
                first = strcmp(run->rows[j].kind, kind) || strcmp(run->rows[j].tcase, r->tcase) ||
                        !strcmp(run->rows[j].knob, "sampling");
            if (!first) continue;
            snprintf(name, sizeof name, "accuracy_%s_%s.png", kind, r->tcase);
        }
        snprintf(path, sizeof path, "%s/%s", run->out, name);
        if (access(path, F_OK) != 0) continue;
        fprintf(f, "%s[%s](%s)", any ? ", " : "Plots (error against CPU time): ", name, name);
        any = 1;
    }
    if (any) fputs(".\n\n", f);
}

static int has_kind(const acc_run *run, const char *kind)
{
    for (size_t i = 0; i < run->n; i++)
        if (!strcmp(run->rows[i].kind, kind)) return 1;
    return 0;
}

static void write_md(FILE *f, const acc_run *run, const char *unused)
{
    (void)unused;
    md_header(f, run);
    if (has_kind(run, "psf")) {
        fprintf(f, "## psf\n\nA star of unit flux at the centre (between pixels) of %d×%d pixels at 0.11\" with "
                   "the pixel response, drawn as the scene draws it (PSF image without the pixel, "
                   "normalised, tabulated, Fourier-drawn); defaults pupil_bin 8, oversample 4, "
                   "256² image (7.04\"), achromatic. CPU s: the PSF build, image and table (once "
                   "per scene) and one star; draw ms: one star.\n\n", STAR_N, STAR_N);
        md_table(f, run, "psf", 0);
        md_plots(f, run, "psf");
    }
    if (has_kind(run, "galaxy")) {
        fputs("## galaxy\n\nOne object of unit flux at a sub-pixel position, the scene's default "
              "PSF; cases:\n\n", f);
        for (size_t c = 0; c < sizeof gal_cases / sizeof *gal_cases; c++)
            fprintf(f, "- `%s`: %s\n", gal_cases[c].name, gal_cases[c].what);
        fputs("\nCPU s = draw ms: stamp bounds and draw of one object. Stamps of different sizes "
              "are compared on the union of their bounds.\n\n", f);
        md_table(f, run, "galaxy", 0);
        md_plots(f, run, "galaxy");
    }
    if (has_kind(run, "scene")) {
        fputs("## scene\n\nA corner of the SCA (`regionN`: pixels [0, N)²) with the synthetic "
              "field of the default pointing; noise-free object rates (sky off) compared pixel "
              "by pixel (moments do not apply). `oversample` keeps the PSF image's 7.04\" "
              "extent (64·K samples), `psf_size` is at K = 4. CPU s: scene set-up (PSF, bounds) "
              "and rendering of every row.\n\n", f);
        md_table(f, run, "scene", 0);
        fputs("Ramp sampling: the default rendering with the sky through readout (MA table 6, "
              "cosmic rays off), assembly and ramp fit; the mean fitted rate of each mode against "
              "per-read sampling over pixels unflagged in both (± its standard error, from the "
              "per-pixel differences); `sampling-nl` with nonlinearity on, `sampling-lin` off. "
              "`readnoise` (knob `corr_noise`): per-read sampling with the correlated read noise "
              "(1/f and channel offsets) off, on, and on with the reference-pixel correction; the "
              "mean rate's ± assumes independent pixels, which this noise is not; notes: a "
              "3-pixel-radius aperture's flux error from it (its rms over a grid of places, against "
              "the aperture's noise from ERR, and as a share of a 25 mag star's flux). "
              "CPU s: readout, assembly and fit.\n\n", f);
        md_table(f, run, "scene", 1);
        md_plots(f, run, "scene");
    }
    if (has_kind(run, "detector")) {
        fputs("## detector\n\nWhat leaving a detector effect out does to a star's photometry. "
              "`persistence`: a faint star (`starM`, AB M, Gaussian sigma 1 pixel) at the pixels of a "
              "saturating star (AB 14) that ended dt before, through readout (MA table 6), assembly "
              "and ramp fit with photon and read noise off; Δflux in a 3-pixel-radius aperture and "
              "Δpeak of the star without persistence against with it (negative: the simulation "
              "without it is fainter than the sky would be). CPU s: one exposure with persistence.\n\n", f);
        md_table(f, run, "detector", 0);
    }
}

/* ---- plots -------------------------------------------------------------------------------- */

/* One number per setting for the plots: the largest of the relative flux, peak and size
 * errors. */
static double worst_rel(const acc_row *r)
{
    double v[3] = {r->d_flux, r->d_peak, r->d_sigma}, w = NAN;
    for (int k = 0; k < 3; k++)
        if (isfinite(v[k]) && !(fabs(v[k]) <= w)) w = fabs(v[k]);
    return w;
}

/* The rows of (kind, case) as one series per knob, error against CPU seconds, log-log; the
 * sampling rows as one series per case with their standard errors. Reference rows (error 0)
 * do not appear on log axes. *wrote: 0 when no row had a positive error. */
static wf_status plot_group(const acc_run *run, const char *kind, const char *tcase, int sampling,
                            const char *name, int *wrote)
{
    *wrote = 0;
    double *x = malloc(run->n * sizeof *x), *y = malloc(run->n * sizeof *y),
           *e = malloc(run->n * sizeof *e);
    wf_plot *p = NULL;
    char title[128], path[WF_PATH_MAX + 64];
    snprintf(title, sizeof title, "%s %s: error against CPU time", kind, sampling ? "sampling" : tcase);
    wf_status st = x && y && e ? wf_plot_create(800, 560, title, "CPU seconds",
                                                sampling ? "|mean rate bias| (relative)"
                                                         : "max(|dflux|, |dpeak|, |dsigma/sigma|)",
                                                &p)
                               : wf_error(WF_ERR_NOMEM, "accuracy: out of memory");
    if (!st) st = wf_plot_set_log(p, 1, 1);
    for (size_t i = 0; i < run->n && !st; i++) {
        const acc_row *r = &run->rows[i];
        if (strcmp(r->kind, kind) || is_sampling(r) != sampling) continue;
        if (!sampling && strcmp(r->tcase, tcase)) continue;
        const char *key = sampling ? r->tcase : r->knob;
        int seen = 0; /* series already drawn with an earlier row */
        for (size_t j = 0; j < i && !seen; j++) {
            const acc_row *o = &run->rows[j];
            seen = !strcmp(o->kind, kind) && is_sampling(o) == sampling &&
                   (sampling || !strcmp(o->tcase, tcase)) && !strcmp(sampling ? o->tcase : o->knob, key);
        }
        if (seen) continue;
        int n = 0, pos = 0;
        for (size_t j = i; j < run->n; j++) {
            const acc_row *o = &run->rows[j];
            if (strcmp(o->kind, kind) || is_sampling(o) != sampling) continue;
            if (!sampling && strcmp(o->tcase, tcase)) continue;
            if (strcmp(sampling ? o->tcase : o->knob, key)) continue;
            x[n] = o->cpu_seconds, y[n] = sampling ? fabs(o->d_flux) : worst_rel(o);
            e[n] = sampling ? o->d_flux_se : 0;
            if (y[n] > 0 && x[n] > 0) pos++;
            n++;
        }
        if (!pos) continue;
        st = wf_plot_series(p, x, y, sampling ? e : NULL, n, key,
                            WF_PLOT_LINE | WF_PLOT_MARKERS | (sampling ? WF_PLOT_ERRORBARS : 0));
        *wrote = 1;
    }
    snprintf(path, sizeof path, "%s/%s", run->out, name);
    if (!st && *wrote) st = wf_plot_write_png(p, path);
    wf_plot_free(p);
    free(x), free(y), free(e);
    return st;
}

/* accuracy_<kind>_<case>.png for every case of the kind, and accuracy_scene_sampling.png. */
static wf_status write_plots(acc_run *run, const char *kind)
{
    wf_status st = WF_OK;
    for (size_t i = 0; i < run->n && !st; i++) {
        const acc_row *r = &run->rows[i];
        if (strcmp(r->kind, kind) || !strcmp(r->knob, "sampling")) continue;
        int first = 1;
        for (size_t j = 0; j < i && first; j++)
            first = strcmp(run->rows[j].kind, kind) || strcmp(run->rows[j].tcase, r->tcase) ||
                    !strcmp(run->rows[j].knob, "sampling");
        if (!first) continue;
        char name[64];
        int wrote;
        snprintf(name, sizeof name, "accuracy_%s_%s.png", kind, r->tcase);
        st = plot_group(run, kind, r->tcase, 0, name, &wrote);
    }
    int wrote;
    if (!st && !strcmp(kind, "scene")) st = plot_group(run, kind, NULL, 1, "accuracy_scene_sampling.png", &wrote);
    return st;
}

/* ---- command ------------------------------------------------------------------------------ */

static int usage_error(const char *fmt, const char *what)
{
    fprintf(stderr, "wfisim accuracy: ");
    fprintf(stderr, fmt, what);
    fprintf(stderr, "\n%s", usage);
    return 2;
}

static int fail(wf_status st)
{
    fprintf(stderr, "wfisim accuracy: %s\n",
            wf_error_message()[0] ? wf_error_message() : wf_status_name(st));
    return st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
}

int wf_cmd_accuracy(int argc, char **argv)
{
    acc_run run;
    memset(&run, 0, sizeof run);
    snprintf(run.filter, sizeof run.filter, "Y106");
    snprintf(run.out, sizeof run.out, "out/accuracy");
    run.sca = 1;
    const char *kind = NULL, *data = NULL, *filter = "Y106";
    int len = snprintf(run.command, sizeof run.command, "wfisim accuracy");
    int i0 = argc > 0 && !strcmp(argv[0], "accuracy") ? 1 : 0;
    for (int i = i0; i < argc; i++) {
        if (len < (int)sizeof run.command)
            len += snprintf(run.command + len, sizeof run.command - (size_t)len, " %s", argv[i]);
        const char *k = argv[i];
        if (!strcmp(k, "--help") || !strcmp(k, "-h")) {
            fputs(usage, stdout);
            return 0;
        }
        if (!strcmp(k, "--quick")) {
            run.quick = 1;
            continue;
        }
        if (strncmp(k, "--", 2)) {
            if (kind) return usage_error("unexpected argument '%s'", k);
            kind = k;
            continue;
        }
        if (strcmp(k, "--filter") && strcmp(k, "--sca") && strcmp(k, "--out") && strcmp(k, "--data"))
            return usage_error("unknown option '%s'", k);
        if (i + 1 >= argc) return usage_error("%s needs a value", k);
        const char *v = argv[++i];
        if (len < (int)sizeof run.command)
            len += snprintf(run.command + len, sizeof run.command - (size_t)len, " %s", v);
        if (!strcmp(k, "--filter")) {
            filter = v;
        } else if (!strcmp(k, "--sca")) {
            char *end;
            errno = 0;
            long n = strtol(v, &end, 10);
            if (end == v || *end || errno || n < 1 || n > 18)
                return usage_error("--sca '%s' is not 1..18", v);
            run.sca = (int)n;
        } else if (!strcmp(k, "--out")) {
            if (!*v || strlen(v) >= sizeof run.out - 64) return usage_error("--out '%s': empty or too long", v);
            snprintf(run.out, sizeof run.out, "%s", v);
        } else {
            data = v;
            wf_status st = strcmp(v, "none") ? wf_config_check_dir("--data", v) : WF_OK;
            if (st) return fail(st);
        }
    }
    if (!kind) return usage_error("%s", "give what to sweep: psf, galaxy, scene, detector or all");
    int do_psf = !strcmp(kind, "psf"), do_gal = !strcmp(kind, "galaxy"), do_scene = !strcmp(kind, "scene");
    int do_det = !strcmp(kind, "detector");
    if (!strcmp(kind, "all")) do_psf = do_gal = do_scene = do_det = 1;
    if (!do_psf && !do_gal && !do_scene && !do_det)
        return usage_error("unknown sweep '%s' (psf, galaxy, scene, detector or all)", kind);
    if (wf_filter_parse(filter, &run.filt)) {
        fprintf(stderr, "wfisim accuracy: --filter: %s\n%s", wf_error_message(), usage);
        return 2;
    }
    snprintf(run.filter, sizeof run.filter, "%s", wf_filter_name(run.filt));
    if (!data) data = getenv("WFISIM_DATA");
    if (data && *data && strcmp(data, "none")) {
        if (strlen(data) >= sizeof run.data) return usage_error("--data '%s' is too long", data);
        snprintf(run.data, sizeof run.data, "%s", data);
    }

    wf_status st = make_dir(run.out);
    if (!st && !(run.bp = malloc(sizeof *run.bp))) st = wf_error(WF_ERR_NOMEM, "cannot allocate a bandpass");
    if (!st) st = wf_bandpass_load(run.filt, run.data[0] ? run.data : NULL, run.bp);
    if (!st && do_psf) st = sweep_psf(&run);
    if (!st && do_psf) st = write_atomic(&run, "accuracy_psf.csv", write_csv, "psf");
    if (!st && do_psf) st = write_plots(&run, "psf");
    if (!st && do_gal) st = sweep_galaxy(&run);
    if (!st && do_gal) st = write_atomic(&run, "accuracy_galaxy.csv", write_csv, "galaxy");
    if (!st && do_gal) st = write_plots(&run, "galaxy");
    if (!st && do_scene) st = sweep_scene(&run);
    if (!st && do_scene) st = write_atomic(&run, "accuracy_scene.csv", write_csv, "scene");
    if (!st && do_scene) st = write_plots(&run, "scene");
    if (!st && do_det) st = sweep_detector(&run);
    if (!st && do_det) st = write_atomic(&run, "accuracy_detector.csv", write_csv, "detector");
    if (!st) st = write_atomic(&run, "accuracy.md", write_md, NULL);
    free(run.rows);
    free(run.bp);
    if (st) return fail(st);
    fprintf(stderr, "wfisim accuracy: wrote %s/accuracy.md and the CSV files\n", run.out);
    return 0;
}
