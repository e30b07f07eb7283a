/* Profiles (sim/draw/profile*.c): galaxies (de Vaucouleurs bulge + exponential disk + knots) and
 * point sources drawn with the PSF and the pixel.
 *
 * Against GalSim 2.8.4 (../shared/reference/galsim/, skipped when absent):
 *  - the four reference galaxies without PSF (GalSim drew them in real space), and with the
 *    Y106 SCA 1 pupil_bin 8 PSF; every parameter, the knot positions included, is read from
 *    galaxy_stamps.json;
 *  - the point source against GalSim's own pixel-convolved PSF image.
 * Independent of GalSim:
 *  - the de Vaucouleurs Fourier table against brute-force quadrature and its series;
 *  - knots: radial distribution (Kolmogorov-Smirnov), uniform angles, reproducibility;
 *  - stamp sizes: the radius search against a bisection of the closed-form enclosed light,
 *    to ~1e-10 of the radius;
 *  - flux: sums against exact pixel integrals of round profiles (computed here by a 1-D
 *    angular quadrature of the enclosed-flux function, not by the code under test);
 *  - centring, sheared and rotated ellipticity from unweighted moments;
 *  - stiff cases: half-light radius 0.005" and 20", e = 0.7 at six angles, a magnitude-35
 *    flux, the bulge cusp against exact pixel integrals, bad input;
 *  - a stamp drawn in pieces equals the whole, bit for bit;
 *  - the knot lattice against the direct sum over knots; the drawing kernels' scalar and
 *    vector versions give the same bits.
 *
 * The PSF input for the GalSim comparison. GalSim's galaxies were convolved with its own PSF
 * object, of which the reference holds two images: OVER4 (0.0275", no pixel, a 3.52" box
 * holding 97.8% of the light) and NATIVE (0.11", pixel included, 14.08" holding 99.4%). The
 * input here is OVER4 in the centre and NATIVE's wings (each native pixel's light spread over
 * its 4 x 4 sub-samples) out to 7.04" either side, so that the light the 7.04" stamps hold
 * matches; the band limit is 2 pi D / lambda, which removes the ~3% resampling artifacts
 * GalSim's OVER4 holds above the optical cut-off. The two GalSim images are not consistent
 * with each other for Y106: within any box from 0.44" to 3.52" NATIVE holds 0.78% less
 * light than OVER4 (0.04% for H158), a difference of GalSim's two drawing paths
 * (interpolated real-space samples for no_pixel, k-space for the pixel), which no drawer
 * fed with OVER4 can undo. The comparison therefore divides our stamps by the ratio of our
 * point source to GalSim's NATIVE PSF in the same 64 x 64 box (0.99216): that ratio is a
 * property of the PSF files, measured on a point source, not fitted to the galaxies.
 *
 * Image orientation: FITS files are read into pix[row * NAXIS1 + col], col = x - 1,
 * row = y - 1 (1-based FITS pixel centres); our stamps use 0-based centres, so GalSim's
 * "true centre 32.5 + offset" is our 31.5 + offset. */
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "hal/arena.h"
#include "hal/noise.h"
#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"
#include "tests/testutil.h"

#define P 0.11

/* ------------------------------------------------------------------------------ helpers */

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

/* A work (and optionally a prepared PSF) in one malloc'd arena. */
typedef struct ctx {
    void *mem;
    wf_arena arena;
    wf_profile_work work;
    wf_profile_psf psf;
    int has_psf;
} ctx;

static void ctx_open(ctx *c, const wf_profile_accuracy *acc, const wf_psf_image *img)
{
    memset(c, 0, sizeof *c);
    size_t need = 0, pneed = 0, pscratch = 0;
    ck_assert_msg(wf_profile_work_need(acc, &need, NULL) == WF_OK, "%s", wf_error_message());
    if (img)
        ck_assert_msg(wf_profile_psf_need(img, acc, &pneed, &pscratch) == WF_OK, "%s",
                      wf_error_message());
    size_t cap = need + pneed + pscratch + 4096;
    c->mem = malloc(cap);
    ck_assert(c->mem != NULL);
    wf_arena_init(&c->arena, c->mem, cap, "test");
    if (img) {
        ck_assert_msg(wf_profile_psf_init(&c->psf, img, acc, &c->arena, 1) == WF_OK, "%s",
                      wf_error_message());
        c->has_psf = 1;
    }
    ck_assert_msg(wf_profile_work_init(&c->work, acc, &c->arena) == WF_OK, "%s",
                  wf_error_message());
    ck_assert_msg(c->arena.high_water <= cap, "arena need under-reported");
}

static void ctx_close(ctx *c)
{
    wf_profile_work_free(&c->work);
    free(c->mem);
}

static wf_galaxy galaxy(double flux, double bf, double hlr_disk, double hlr_bulge, double e1,
                        double e2)
{
    wf_galaxy g;
    memset(&g, 0, sizeof g);
    g.id = 7;
    g.flux = flux;
    g.bulge_frac = bf;
    g.hlr_disk = hlr_disk;
    g.hlr_bulge = hlr_bulge;
    g.e1 = e1;
    g.e2 = e2;
    return g;
}

/* A stamp with its own pixels; bounds from the caller. */
static wf_stamp stamp_new(int x0, int y0, int nx, int ny)
{
    wf_stamp s;
    memset(&s, 0, sizeof s);
    s.x0 = x0;
    s.y0 = y0;
    s.nx = nx;
    s.ny = ny;
    s.pix = calloc((size_t)nx * ny, sizeof(double));
    ck_assert(s.pix != NULL);
    return s;
}

/* Largest |a - ref| over ref's peak; the stamps have the same bounds. */
static double worst_of_peak(const wf_stamp *a, const wf_stamp *ref)
{
    ck_assert(a->nx == ref->nx && a->ny == ref->ny);
    double worst = 0, peak = 0;
    for (size_t i = 0; i < (size_t)a->nx * a->ny; i++) {
        worst = fmax(worst, fabs(a->pix[i] - ref->pix[i]));
        peak = fmax(peak, ref->pix[i]);
    }
    return worst / peak;
}

static void check_finite_nonneg(const wf_stamp *s, const char *what)
{
    for (size_t i = 0; i < (size_t)s->nx * s->ny; i++)
        ck_assert_msg(isfinite(s->pix[i]) && s->pix[i] >= 0.0, "%s: pixel %zu = %g", what, i,
                      s->pix[i]);
}

/* Unweighted moments about (cx, cy) pixels (NAN: the centroid); returns e1, e2 and the
 * centroid, with the pixel's own p^2/12 taken out of the second moments. */
static void unweighted(const double *pix, int nx, int ny, double *cx, double *cy, double *e1,
                       double *e2)
{
    double s = 0, sx = 0, sy = 0;
    for (int j = 0; j < ny; j++)
        for (int i = 0; i < nx; i++) {
            double v = pix[(size_t)j * nx + i];
            s += v;
            sx += v * i;
            sy += v * j;
        }
    double mx = sx / s, my = sy / s, qxx = 0, qyy = 0, qxy = 0;
    for (int j = 0; j < ny; j++)
        for (int i = 0; i < nx; i++) {
            double v = pix[(size_t)j * nx + i], dx = i - mx, dy = j - my;
            qxx += v * dx * dx;
            qyy += v * dy * dy;
            qxy += v * dx * dy;
        }
    qxx = qxx / s - 1.0 / 12.0;
    qyy = qyy / s - 1.0 / 12.0;
    qxy /= s;
    *cx = mx;
    *cy = my;
    *e1 = (qxx - qyy) / (qxx + qyy);
    *e2 = 2.0 * qxy / (qxx + qyy);
}

/* Adaptive (elliptical Gaussian weight matched to the image) moments, as GalSim's HSM and
 * Bernstein & Jarvis (2002): size det(M)^(1/4) in pixels and distortion (e1, e2). The same
 * estimator on both images makes the comparison like for like; unlike unweighted moments
 * it is not dominated by the PSF's far wings. */
static void adaptive(const double *im, int n, double *sig, double *e1, double *e2)
{
    double mxx = 4, myy = 4, mxy = 0, xc = 0.5 * (n - 1), yc = xc;
    for (int it = 0; it < 300; it++) {
        double det = mxx * myy - mxy * mxy, ixx = myy / det, iyy = mxx / det, ixy = -mxy / det;
        double s = 0, sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0;
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++) {
                double dx = i - xc, dy = j - yc;
                double r2 = ixx * dx * dx + 2 * ixy * dx * dy + iyy * dy * dy;
                if (r2 > 60) continue;
                double w = exp(-0.5 * r2) * im[j * n + i];
                s += w;
                sx += w * dx;
                sy += w * dy;
                sxx += w * dx * dx;
                syy += w * dy * dy;
                sxy += w * dx * dy;
            }
        double ddx = sx / s, ddy = sy / s;
        xc += ddx;
        yc += ddy;
        double nxx = 2 * (sxx / s - ddx * ddx), nyy = 2 * (syy / s - ddy * ddy),
               nxy = 2 * (sxy / s - ddx * ddy);
        double ch = fabs(nxx - mxx) + fabs(nyy - myy) + fabs(nxy - mxy);
        mxx = nxx;
        myy = nyy;
        mxy = nxy;
        if (ch < 1e-12 && fabs(ddx) + fabs(ddy) < 1e-12) break;
    }
    *sig = pow(mxx * myy - mxy * mxy, 0.25);
    *e1 = (mxx - myy) / (mxx + myy);
    *e2 = 2 * mxy / (mxx + myy);
}

/* ---- exact pixel integrals of a round profile from its enclosed-flux function E(r):
 * the light in [0, a] x [0, b] (centre at a corner) is
 *   (1 / 2 pi) [ Int_0^tc E(a / cos t) dt + Int_tc^(pi/2) E(b / sin t) dt ],  tc = atan(b/a),
 * smooth integrands whatever the cusp of the profile at r = 0. */
typedef struct round_profile {
    double fb, re, fd, hlr_d; /* fractions of the flux and half-light radii (arcsec) */
} round_profile;

static double enclosed(const round_profile *rp, double r)
{
    double eb = 0, ed = 0;
    if (rp->fb > 0) ck_assert(wf_profile_enclosed(4, rp->re, r, &eb) == WF_OK);
    if (rp->fd > 0) ck_assert(wf_profile_enclosed(1, rp->hlr_d, r, &ed) == WF_OK);
    return rp->fb * eb + rp->fd * ed;
}

static double gl_x[48], gl_w[48];

static void gl_init(void)
{
    const int n = 48;
    for (int i = 0; i < n; i++) {
        double x = cos(M_PI * (i + 0.75) / (n + 0.5)), dp = 1;
        for (int it = 0; it < 100; it++) {
            double p0 = 1, p1 = x;
            for (int k = 2; k <= n; k++) {
                double p2 = ((2 * k - 1) * x * p1 - (k - 1) * p0) / k;
                p0 = p1;
                p1 = p2;
            }
            dp = n * (x * p1 - p0) / (x * x - 1);
            double dx = p1 / dp;
            x -= dx;
            if (fabs(dx) < 1e-16) break;
        }
        gl_x[i] = x;
        gl_w[i] = 2 / ((1 - x * x) * dp * dp);
    }
}

static double corner_box(const round_profile *rp, double a, double b)
{
    if (a <= 0 || b <= 0) return 0.0;
    double tc = atan2(b, a), sum = 0.0;
    for (int part = 0; part < 4; part++) { /* 4 panels per side for safety */
        double t0 = tc * part / 4, t1 = tc * (part + 1) / 4;
        double u0 = tc + (M_PI / 2 - tc) * part / 4, u1 = tc + (M_PI / 2 - tc) * (part + 1) / 4;
        for (int i = 0; i < 48; i++) {
            double t = 0.5 * (t0 + t1) + 0.5 * (t1 - t0) * gl_x[i];
            double u = 0.5 * (u0 + u1) + 0.5 * (u1 - u0) * gl_x[i];
            sum += 0.5 * (t1 - t0) * gl_w[i] * enclosed(rp, a / cos(t));
            sum += 0.5 * (u1 - u0) * gl_w[i] * enclosed(rp, b / sin(u));
        }
    }
    return sum / (2 * M_PI);
}

static double signed_corner(const round_profile *rp, double x, double y)
{
    double s = (x < 0 ? -1 : 1) * (y < 0 ? -1 : 1);
    return s * corner_box(rp, fabs(x), fabs(y));
}

/* Light of the round profile in [x0, x1] x [y0, y1] arcsec, the centre at the origin. */
static double box_light(const round_profile *rp, double x0, double x1, double y0, double y1)
{
    return signed_corner(rp, x1, y1) - signed_corner(rp, x0, y1) - signed_corner(rp, x1, y0) +
           signed_corner(rp, x0, y0);
}

/* A round Gaussian PSF image (sigma arcsec) at 0.0275", unit sum; smooth and band-limited
 * enough for GalSim-independent tests. */
static double *gaussian_psf(int n, double sigma, wf_psf_image *img)
{
    double *pix = malloc(sizeof(double) * n * n), s = 0, c = 0.5 * (n - 1), h = P / 4;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            double r2 = ((i - c) * (i - c) + (j - c) * (j - c)) * h * h;
            pix[j * n + i] = exp(-0.5 * r2 / (sigma * sigma));
            s += pix[j * n + i];
        }
    for (int i = 0; i < n * n; i++) pix[i] /= s;
    img->n = n;
    img->scale_arcsec = h;
    img->pix = pix;
    img->band_limit = 0.0;
    return pix;
}

/* ------------------------------------------------------------------- reference files */

static double *load_fits(const char *file, const char *extname, long *nx, long *ny,
                         double *lam_nm)
{
    const char *dir = wf_test_reference_dir();
    if (!dir) return NULL;
    char path[4200], ext[72];
    snprintf(path, sizeof path, "%s/%s", dir, file);
    snprintf(ext, sizeof ext, "%s", extname);
    fitsfile *f = NULL;
    int st = 0;
    if (fits_open_file(&f, path, READONLY, &st)) return NULL;
    fits_movnam_hdu(f, IMAGE_HDU, ext, 0, &st);
    long n[2] = {0, 0};
    fits_get_img_size(f, 2, n, &st);
    if (lam_nm) {
        int s2 = 0;
        if (fits_read_key(f, TDOUBLE, "LAM_NM", lam_nm, NULL, &s2)) *lam_nm = NAN;
    }
    ck_assert_msg(st == 0, "%s[%s]: cfitsio status %d", path, ext, st);
    double *a = malloc(sizeof(double) * n[0] * n[1]);
    ck_assert(a != NULL);
    fits_read_img(f, TDOUBLE, 1, n[0] * n[1], NULL, a, NULL, &st);
    fits_close_file(f, &st);
    ck_assert_msg(st == 0, "reading %s[%s]: cfitsio status %d", path, ext, st);
    *nx = n[0];
    *ny = n[1];
    return a;
}

static char *slurp(const char *file)
{
    const char *dir = wf_test_reference_dir();
    if (!dir) return NULL;
    char path[4200];
    snprintf(path, sizeof path, "%s/%s", dir, file);
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *s = malloc((size_t)n + 1);
    ck_assert(s != NULL);
    ck_assert(fread(s, 1, (size_t)n, f) == (size_t)n);
    s[n] = 0;
    fclose(f);
    return s;
}

/* The value after "key": within [from, to); numbers only. */
static double json_num(const char *from, const char *to, const char *key)
{
    char pat[80];
    snprintf(pat, sizeof pat, "\"%s\":", key);
    const char *at = strstr(from, pat);
    ck_assert_msg(at && at < to, "galaxy_stamps.json: no %s", key);
    return strtod(at + strlen(pat), NULL);
}

/* Up to cap numbers of the array after "key" (nested arrays flattened). */
static int json_array(const char *from, const char *to, const char *key, double *out, int cap)
{
    char pat[80];
    snprintf(pat, sizeof pat, "\"%s\":", key);
    const char *at = strstr(from, pat);
    if (!at || at >= to) return -1;
    at = strchr(at, '[');
    int depth = 0, n = 0;
    for (const char *c = at; *c; c++) {
        if (*c == '[') depth++;
        else if (*c == ']') {
            if (--depth == 0) break;
        } else if (*c == '-' || (*c >= '0' && *c <= '9')) {
            char *end;
            double v = strtod(c, &end);
            if (n < cap) out[n] = v;
            n++;
            c = end - 1;
        }
    }
    return n;
}

typedef struct ref_galaxy {
    char name[8];
    wf_galaxy g;
    double ox, oy;
    double knots[2 * 64];
} ref_galaxy;

/* The four galaxies of galaxy_stamps.json; 0 when the reference is absent. */
static int load_galaxies(ref_galaxy *out)
{
    char *js = slurp("galaxy_stamps.json");
    if (!js) return 0;
    for (int k = 0; k < 4; k++) {
        char pat[32];
        snprintf(pat, sizeof pat, "\"GAL%d\"", k + 1);
        const char *a = strstr(js, pat);
        ck_assert_msg(a != NULL, "galaxy_stamps.json: no %s", pat);
        const char *b = strstr(a + 1, "\"name\"");
        if (!b) b = a + strlen(a);
        ref_galaxy *r = &out[k];
        memset(r, 0, sizeof *r);
        snprintf(r->name, sizeof r->name, "GAL%d", k + 1);
        r->g = galaxy(1.0, json_num(a, b, "bulge_frac"), json_num(a, b, "hlr_disk"),
                      json_num(a, b, "hlr_bulge"), json_num(a, b, "e1"), json_num(a, b, "e2"));
        r->g.knot_frac = json_num(a, b, "knot_frac");
        double off[2];
        ck_assert(json_array(a, b, "offset", off, 2) == 2);
        r->ox = off[0];
        r->oy = off[1];
        int nk = json_array(a, b, "knot_points_arcsec_preshear", r->knots, 128);
        if (nk > 0) {
            ck_assert(nk % 2 == 0 && nk <= 128);
            r->g.n_knots = nk / 2;
            r->g.knot_xy = r->knots;
        }
        /* the JSON's reduced shear must be GalSim's g for our distortion */
        double g1, g2;
        wf_profile_shear_from_distortion(r->g.e1, r->g.e2, &g1, &g2);
        ck_assert_msg(fabs(g1 - json_num(a, b, "g1")) < 1e-12 &&
                          fabs(g2 - json_num(a, b, "g2")) < 1e-12,
                      "%s: shear convention differs from the JSON's", r->name);
    }
    free(js);
    return 4;
}

typedef struct cmp {
    double dflux, dpeak, dcore, dmax, dsig, de1, de2;
} cmp;

/* Our 64 x 64 stamp against GalSim's: relative flux, peak and worst pixel (of the 3 x 3 core
 * around GalSim's peak, and of the whole stamp) in units of GalSim's peak, adaptive size
 * (relative) and ellipticity (absolute). */
static cmp compare(const double *ours, const double *ref)
{
    cmp c = {0};
    double so = 0, sr = 0, pk = 0, po = 0;
    int ip = 0;
    for (int i = 0; i < 64 * 64; i++) {
        so += ours[i];
        sr += ref[i];
        if (ref[i] > pk) {
            pk = ref[i];
            ip = i;
        }
        if (ours[i] > po) po = ours[i];
        if (fabs(ours[i] - ref[i]) > c.dmax) c.dmax = fabs(ours[i] - ref[i]);
    }
    int px = ip % 64, py = ip / 64;
    for (int dy = -1; dy <= 1; dy++)
        for (int dx = -1; dx <= 1; dx++) {
            int at = (py + dy) * 64 + px + dx;
            double d = fabs(ours[at] - ref[at]);
            if (d > c.dcore) c.dcore = d;
        }
    double s1, a1, b1, s2, a2, b2;
    adaptive(ours, 64, &s1, &a1, &b1);
    adaptive(ref, 64, &s2, &a2, &b2);
    c.dflux = so / sr - 1;
    c.dpeak = (po - pk) / pk;
    c.dcore /= pk;
    c.dmax /= pk;
    c.dsig = s1 / s2 - 1;
    c.de1 = a1 - a2;
    c.de2 = b1 - b2;
    return c;
}

static void print_cmp(const char *what, const cmp *c, int fft, double ms)
{
    printf("%-11s fft %4d %7.2f ms  flux %+.2e  peak %+.2e  3x3 %.2e  max %.2e  (of peak)  "
           "size %+.2e  e1 %+.1e  e2 %+.1e\n",
           what, fft, ms, c->dflux, c->dpeak, c->dcore, c->dmax, c->dsig, c->de1, c->de2);
}

/* The comparison PSF (see the header comment); NULL when the reference is absent. */
static double *reference_psf(wf_psf_image *img, double **native)
{
    long n1, n2, m1, m2;
    double lam;
    double *over = load_fits("psf_sca01.fits.gz", "Y106_SCA01_PB8_OVER4", &n1, &n2, &lam);
    if (!over) return NULL;
    double *nat = load_fits("psf_sca01.fits.gz", "Y106_SCA01_PB8_NATIVE", &m1, &m2, NULL);
    ck_assert(n1 == 128 && n2 == 128 && m1 == 128 && m2 == 128 && isfinite(lam));
    const int np = 512; /* 14.08" at 0.0275" */
    double *pix = calloc((size_t)np * np, sizeof(double));
    for (int j = 0; j < 128; j++)
        for (int i = 0; i < 128; i++)
            for (int b = 0; b < 4; b++)
                for (int a = 0; a < 4; a++)
                    pix[(4 * j + b) * np + 4 * i + a] = nat[j * 128 + i] / 16.0;
    /* both centres at their array's true centre: OVER4's 63.5 lands on 255.5 */
    for (int j = 0; j < 128; j++)
        for (int i = 0; i < 128; i++) pix[(j + 192) * np + i + 192] = over[j * 128 + i];
    char *facts = slurp("facts.json");
    double diam = facts ? json_num(facts, facts + strlen(facts), "diameter") : 2.36;
    free(facts);
    img->n = np;
    img->scale_arcsec = P / 4;
    img->pix = pix;
    img->band_limit = 2 * M_PI * diam / (lam * 1e-9) * (M_PI / 180 / 3600);
    free(over);
    *native = nat;
    return pix;
}

/* GalSim's Y106 PSF when the reference data are present, else a 0.07" Gaussian (the tests
 * that use it hold for any PSF); *which names it. */
static double *reference_or_gaussian(wf_psf_image *img, double **native, const char **which)
{
    double *pix = reference_psf(img, native);
    *which = "GalSim Y106";
    if (!pix) {
        pix = gaussian_psf(128, 0.07, img);
        *which = "Gaussian 0.07\"";
    }
    return pix;
}

/* ------------------------------------------------------------ de Vaucouleurs transform */

/* Plain composite Gauss-Legendre over panels of a quarter oscillation of J0, no
 * extrapolation: slow and simple. The integrand is below 1e-12 of F(0) beyond s = 45. */
static double hankel_brute(double q)
{
    const double b = wf_sersic4_table()->b;
    double sum = 0.0, s = 0.0;
    while (s < 45.0) {
        double du = 4 * q * pow((s + 0.1) / b, 3) / b; /* d(q (s/b)^4)/ds, a little ahead */
        double h = fmin(0.25, 0.25 * M_PI / fmax(du, 1e-9));
        for (int i = 0; i < 48; i++) {
            double x = s + 0.5 * h * (1 + gl_x[i]);
            double y = x / b;
            sum += 0.5 * h * gl_w[i] * exp(-x + 7 * log(x)) * j0(q * y * y * y * y);
        }
        s += h;
    }
    return sum / 5040.0;
}

START_TEST(test_sersic_transform)
{
    gl_init();
    const wf_sersic_table *t = wf_sersic4_table();
    ck_assert_msg(fabs(t->b - 7.669249442500803) < 1e-12, "b(4) = %.15f", t->b);
    ck_assert_msg(fabs(t->b1 - 1.678346990016661) < 1e-12, "b(1) = %.15f", t->b1);
    /* quadrature with Wynn extrapolation against brute force */
    double worst = 0;
    const double qs[] = {0.003, 0.05, 0.5, 2.0, 3.9};
    for (int i = 0; i < 5; i++) {
        double q = qs[i];
        double d = fabs(wf_sersic4_hankel_direct(q) - hankel_brute(q));
        if (d > worst) worst = d;
    }
    printf("de Vaucouleurs F(q): accelerated quadrature vs brute force: %.2e\n", worst);
    ck_assert_msg(worst < 1e-11, "quadrature differs from brute force by %.3g", worst);
    /* the two evaluations where they meet */
    for (double q = 3.0; q <= 5.0; q += 0.5) {
        double d = fabs(wf_sersic4_hankel_direct(q) - wf_sersic4_hankel_series(q));
        ck_assert_msg(d < 1e-11, "series vs quadrature at q = %g: %.3g", q, d);
    }
    /* the table: interpolation error, monotone fall, small-q law */
    double abs_err = 0, rel_err = 0, prev = 2.0;
    for (int i = 0; i < 2000; i++) {
        /* off the table's nodes: a sinusoidal jitter of 1.3% */
        double q = pow(10.0, -3.5 + 8.0 * i / 2000.0) * (1 + 0.013 * sin(i));
        double exact = q < 4 ? wf_sersic4_hankel_direct(q) : wf_sersic4_hankel_series(q);
        double v = wf_sersic4_eval(t, q * q);
        abs_err = fmax(abs_err, fabs(v - exact));
        rel_err = fmax(rel_err, fabs(v - exact) / exact);
    }
    for (int i = 0; i < 20000; i++) { /* a positive mixture of Gaussians falls monotonically */
        double q = pow(10.0, -4.0 + 9.0 * i / 20000.0), v = wf_sersic4_eval(t, q * q);
        ck_assert_msg(v <= prev, "F not decreasing at q = %g", q);
        prev = v;
    }
    printf("de Vaucouleurs table: max error %.2e of F(0), %.2e relative\n", abs_err, rel_err);
    ck_assert_msg(abs_err < 1e-6 && rel_err < 1e-4, "table error %.3g abs, %.3g rel", abs_err,
                  rel_err);
    double q = 1e-3, slope = (1 - wf_sersic4_eval(t, q * q)) / (q * q);
    ck_assert_msg(fabs(slope / (0.25 * t->r2) - 1) < 1e-3, "small-q slope %g vs <r^2>/4 = %g",
                  slope, 0.25 * t->r2);
}
END_TEST

/* ------------------------------------------------------------------ against GalSim */

START_TEST(test_galsim_nopsf)
{
    ref_galaxy rg[4];
    WF_SKIP_UNLESS(load_galaxies(rg), "GalSim reference galaxy_stamps.json");
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, NULL);
    for (int k = 0; k < 4; k++) {
        char ext[32];
        snprintf(ext, sizeof ext, "GAL%d_NOPSF", k + 1);
        long nx, ny;
        double *ref = load_fits("galaxy_stamps.fits.gz", ext, &nx, &ny, NULL);
        ck_assert(ref && nx == 64 && ny == 64);
        wf_galaxy g = rg[k].g;
        if (g.n_knots) {
            /* GalSim drew these in real space, where its knots (delta functions) have no
             * surface brightness: its stamp lacks their 20% (sum 0.789). Compare without. */
            double knots = (1 - g.bulge_frac) * g.knot_frac;
            g.bulge_frac /= 1 - knots;
            g.flux = 1 - knots;
            g.knot_frac = 0;
            g.n_knots = 0;
        }
        wf_stamp s = stamp_new(0, 0, 64, 64);
        double t0 = now_s();
        ck_assert_msg(wf_profile_draw_galaxy(&c.work, &g, NULL, 31.5 + rg[k].ox,
                                             31.5 + rg[k].oy, &s) == WF_OK,
                      "%s", wf_error_message());
        double ms = 1e3 * (now_s() - t0);
        cmp d = compare(s.pix, ref);
        print_cmp(ext, &d, s.fft, ms);
        /* Both sides integrate the profile over the pixels in real space (GalSim to its
         * realspace_relerr 1e-4): reached 1.4e-6 of the peak, flux 9e-8, moments 5e-7. The
         * asserted 2e-5 is 50x tighter than issue 3 asks and still well above both
         * quadratures' errors. */
        ck_assert_msg(fabs(d.dflux) < 2e-5, "%s flux %+.3g", ext, d.dflux);
        ck_assert_msg(d.dmax < 2e-5 && d.dcore < 2e-5, "%s pixels %.3g", ext, d.dmax);
        ck_assert_msg(fabs(d.dsig) < 2e-5, "%s size %+.3g", ext, d.dsig);
        ck_assert_msg(fabs(d.de1) < 2e-5 && fabs(d.de2) < 2e-5, "%s e %+.3g %+.3g", ext, d.de1,
                      d.de2);
        free(ref);
        free(s.pix);
    }
    ctx_close(&c);
}
END_TEST

START_TEST(test_galsim_psf)
{
    ref_galaxy rg[4];
    WF_SKIP_UNLESS(load_galaxies(rg), "GalSim reference galaxy_stamps.json");
    wf_psf_image img;
    double *native = NULL;
    double *psfpix = reference_psf(&img, &native);
    WF_SKIP_UNLESS(psfpix, "GalSim reference psf_sca01.fits.gz");
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);

    /* the PSF files' own discrepancy, measured on a point source in the 64 x 64 box */
    wf_stamp pt = stamp_new(0, 0, 64, 64);
    ck_assert(wf_profile_draw_point(&c.work, &c.psf, 1.0, 31.5, 31.5, &pt) == WF_OK);
    double nsum = 0;
    for (int j = 0; j < 64; j++)
        for (int i = 0; i < 64; i++) nsum += native[(j + 32) * 128 + i + 32];
    double norm = nsum / pt.sum;
    printf("point source in 64x64: ours %.6f, GalSim NATIVE %.6f: PSF-file ratio %.5f\n",
           pt.sum, nsum, norm);
    ck_assert_msg(fabs(norm - 1) < 0.012, "PSF files differ by %.4f", norm - 1);

    for (int k = 0; k < 4; k++) {
        char ext[32];
        snprintf(ext, sizeof ext, "GAL%d_PSF", k + 1);
        long nx, ny;
        double *ref = load_fits("galaxy_stamps.fits.gz", ext, &nx, &ny, NULL);
        ck_assert(ref && nx == 64 && ny == 64);
        wf_stamp s = stamp_new(0, 0, 64, 64);
        double t0 = now_s();
        ck_assert_msg(wf_profile_draw_galaxy(&c.work, &rg[k].g, &c.psf, 31.5 + rg[k].ox,
                                             31.5 + rg[k].oy, &s) == WF_OK,
                      "%s", wf_error_message());
        double ms = 1e3 * (now_s() - t0);
        cmp raw = compare(s.pix, ref);
        for (int i = 0; i < 64 * 64; i++) s.pix[i] *= norm;
        cmp d = compare(s.pix, ref);
        print_cmp(ext, &d, s.fft, ms);
        printf("%-11s before the PSF-file ratio: flux %+.2e peak %+.2e\n", "", raw.dflux,
               raw.dpeak);
        /* Reached: flux <= 1.7e-4, pixels <= 1.9e-3 of the peak (knots, being point sources,
         * show the PSF files' core differences most), size <= 1.8e-3, e <= 3e-4. Required
         * (issue 3): flux 1e-3, 3x3 core 1e-2 of the peak, moments 1e-2. */
        ck_assert_msg(fabs(d.dflux) < 1e-3, "%s flux %+.3g", ext, d.dflux);
        ck_assert_msg(d.dcore < 5e-3 && d.dmax < 5e-3 && fabs(d.dpeak) < 5e-3,
                      "%s peak %+.3g core %.3g max %.3g", ext, d.dpeak, d.dcore, d.dmax);
        ck_assert_msg(fabs(d.dsig) < 5e-3, "%s size %+.3g", ext, d.dsig);
        ck_assert_msg(fabs(d.de1) < 1e-3 && fabs(d.de2) < 1e-3, "%s e %+.3g %+.3g", ext, d.de1,
                      d.de2);
        free(ref);
        free(s.pix);
    }
    free(pt.pix);
    ctx_close(&c);
    free(psfpix);
    free(native);
}
END_TEST

/* Our point source (PSF x pixel at a sub-pixel position) against GalSim's NATIVE image. */
START_TEST(test_galsim_point)
{
    wf_psf_image img;
    double *native = NULL;
    double *psfpix = reference_psf(&img, &native);
    WF_SKIP_UNLESS(psfpix, "GalSim reference psf_sca01.fits.gz");
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    wf_stamp s = stamp_new(0, 0, 128, 128);
    ck_assert(wf_profile_draw_point(&c.work, &c.psf, 1.0, 63.5, 63.5, &s) == WF_OK);
    double so = 0, sn = 0, pk = 0, worst = 0;
    for (int j = 32; j < 96; j++)
        for (int i = 32; i < 96; i++) {
            so += s.pix[j * 128 + i];
            sn += native[j * 128 + i];
            pk = fmax(pk, native[j * 128 + i]);
        }
    for (int j = 56; j < 72; j++)
        for (int i = 56; i < 72; i++)
            worst = fmax(worst, fabs(s.pix[j * 128 + i] * sn / so - native[j * 128 + i]));
    printf("point source vs GalSim NATIVE (after the PSF-file ratio %.5f): worst core pixel "
           "%.2e of the peak\n", sn / so, worst / pk);
    /* GalSim's NATIVE and OVER4 differ by ~0.3% of the peak even after the ratio; 5e-3
     * leaves room and would catch a half-pixel or pixel-response error (>10%). */
    ck_assert_msg(worst / pk < 5e-3, "point source core differs by %.3g of the peak", worst / pk);
    free(s.pix);
    ctx_close(&c);
    free(psfpix);
    free(native);
}
END_TEST

/* -------------------------------------------------------------------------- knots */

/* Kolmogorov-Smirnov statistic of sorted samples against a CDF. */
static double ks_stat(const double *x, int n, double (*cdf)(double))
{
    double d = 0;
    for (int i = 0; i < n; i++) {
        double f = cdf(x[i]);
        d = fmax(d, fmax(fabs(f - (double)i / n), fabs(f - (double)(i + 1) / n)));
    }
    return d;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double exp_disk_cdf(double x) { return 1 - (1 + x) * exp(-x); }
static double uniform_cdf(double x) { return x; }

START_TEST(test_knots_follow_disk)
{
    const int per = 1000, ngal = 30, n = per * ngal;
    double *r = malloc(sizeof(double) * n), *phi = malloc(sizeof(double) * n);
    double *xy = malloc(sizeof(double) * 2 * per);
    const double hlr = 0.7, r0 = hlr / wf_sersic4_table()->b1;
    for (int k = 0; k < ngal; k++) {
        wf_galaxy g = galaxy(1, 0, hlr, 0, 0, 0);
        g.id = 1000 + k;
        g.knot_seed = 12345;
        g.n_knots = per;
        g.knot_frac = 0.2;
        ck_assert(wf_profile_knots(&g, xy) == WF_OK);
        for (int j = 0; j < per; j++) {
            r[k * per + j] = hypot(xy[2 * j], xy[2 * j + 1]) / r0;
            phi[k * per + j] = (atan2(xy[2 * j + 1], xy[2 * j]) + M_PI) / (2 * M_PI);
        }
    }
    qsort(r, n, sizeof(double), cmp_double);
    qsort(phi, n, sizeof(double), cmp_double);
    double dr = ks_stat(r, n, exp_disk_cdf), dphi = ks_stat(phi, n, uniform_cdf);
    double crit = 1.63 / sqrt(n); /* 1% significance */
    printf("knots: KS D radius %.4f, angle %.4f (1%% critical %.4f, N = %d)\n", dr, dphi, crit, n);
    ck_assert_msg(dr < crit, "knot radii do not follow the disk: D = %.4g", dr);
    ck_assert_msg(dphi < crit, "knot angles not uniform: D = %.4g", dphi);
    /* and a wrong profile is rejected: the same radii against a disk 5% larger */
    double bad = 0;
    for (int i = 0; i < n; i++)
        bad = fmax(bad, fabs(exp_disk_cdf(r[i] / 1.05) - (double)i / n));
    ck_assert_msg(bad > crit, "KS test lacks power (D = %.4g)", bad);
    free(r);
    free(phi);
    free(xy);
}
END_TEST

/* The knots are the stream's construction written out: u1, u2, u3 from wf_rng_uniform53 in
 * turn, radius -r0 ln(u1 u2), angle 2 pi u3 through libm. The drawer's own quarter-turn
 * series may differ from libm by an ulp or two of the angle's sine and cosine (and the 2 pi u
 * product by half an ulp), so positions agree to 1e-15 of the radius; lengths that end a
 * chunk anywhere (1, 127, 128, 129, 1024 knots) and several ids take every word offset. */
START_TEST(test_knots_from_their_stream)
{
    const int lengths[] = {1, 2, 127, 128, 129, WF_PROFILE_MAX_KNOTS};
    static double xy[2 * WF_PROFILE_MAX_KNOTS];
    const double hlr = 0.4, r0 = hlr / wf_sersic4_table()->b1;
    double worst = 0.0;
    for (int li = 0; li < 6; li++)
        for (unsigned id = 7; id < 10; id++) {
            wf_galaxy g = galaxy(1, 0, hlr, 0, 0, 0);
            g.id = id;
            g.knot_seed = 0xabcdef0123ull + id;
            g.n_knots = lengths[li];
            g.knot_frac = 0.2;
            ck_assert(wf_profile_knots(&g, xy) == WF_OK);
            wf_noise stream = {.kind = WF_NOISE_PHILOX, .seed = g.knot_seed};
            wf_rng rng;
            wf_rng_init(&rng, &stream, id, 0, WF_PURPOSE_SCENE);
            for (int j = 0; j < g.n_knots; j++) {
                double u1 = wf_rng_uniform53(&rng), u2 = wf_rng_uniform53(&rng);
                double phi = 2.0 * M_PI * wf_rng_uniform53(&rng), r = -r0 * log(u1 * u2);
                double dx = fabs(xy[2 * j] - r * cos(phi)), dy = fabs(xy[2 * j + 1] - r * sin(phi));
                worst = fmax(worst, fmax(dx, dy) / r);
            }
        }
    printf("knots: worst position difference from libm's %.3g of the radius\n", worst);
    ck_assert_msg(worst < 1e-15, "knot positions off their stream by %.3g of the radius", worst);
}
END_TEST

/* Phase lines against e^{-i u theta} formed directly in long double, for several lines at
 * once with both layouts the drawer uses (separate and interleaved parts), alt's (-1)^u,
 * ranges that do not start at a multiple of 32, and lines longer than the angle buffer (more
 * than 511 anchors: taken in pieces with the same anchors). Within 2e-14: the recurrence
 * runs 31 steps from each anchor. */
START_TEST(test_phase_lines_direct)
{
    const double theta[3] = {0.0123456789, -1.75, 3.0e-3};
    const int los[3] = {-40, 0, -20000}, his[3] = {40, 77, 20011};
    double worst = 0.0;
    for (int r = 0; r < 3; r++)
        for (int alt = 0; alt < 2; alt++)
            for (int inter = 0; inter < 2; inter++) {
                const int len = his[r] - los[r] + 1;
                const size_t st = inter ? 2 : 1, imoff = inter ? 1 : (size_t)len, line = 2 * (size_t)len + 5;
                double *buf = calloc(3 * line, sizeof *buf);
                wf_profile_phase_lines(3, theta, los[r], his[r], buf, line, imoff, st, alt);
                for (int j = 0; j < 3; j++)
                    for (int u = los[r]; u <= his[r]; u++) {
                        long double a = -(long double)u * theta[j], sg = alt && (u & 1) ? -1.0L : 1.0L;
                        const double *re = buf + (size_t)j * line + (size_t)(u - los[r]) * st;
                        worst = fmax(worst, fmax(fabs(re[0] - (double)(sg * cosl(a))), fabs(re[imoff] - (double)(sg * sinl(a)))));
                    }
                free(buf);
            }
    printf("phase lines: worst |error| %.3g\n", worst);
    ck_assert_msg(worst < 2e-14, "phase lines off by %.3g", worst);
}
END_TEST

START_TEST(test_knots_reproducible)
{
    wf_galaxy g = galaxy(1, 0.2, 0.5, 0.25, 0.1, 0.2);
    g.id = 42;
    g.knot_seed = 0x1234567890abcdefull;
    g.n_knots = 50;
    g.knot_frac = 0.25;
    double a[100], b[100], c2[100], d[100];
    ck_assert(wf_profile_knots(&g, a) == WF_OK);
    ck_assert(wf_profile_knots(&g, b) == WF_OK);
    ck_assert_msg(memcmp(a, b, sizeof a) == 0, "same seed and id, different knots");
    g.id = 43;
    ck_assert(wf_profile_knots(&g, c2) == WF_OK);
    g.id = 42;
    g.knot_seed ^= 1;
    ck_assert(wf_profile_knots(&g, d) == WF_OK);
    int same_id = 0, same_seed = 0;
    for (int i = 0; i < 100; i++) {
        same_id += a[i] == c2[i];
        same_seed += a[i] == d[i];
    }
    ck_assert_msg(same_id == 0 && same_seed == 0, "knots do not depend on id (%d) / seed (%d)",
                  same_id, same_seed);
    /* the drawn galaxy is reproducible too, and its knots are where the generator says */
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, NULL);
    g.knot_seed ^= 1;
    wf_stamp s1 = stamp_new(0, 0, 96, 96), s2 = stamp_new(0, 0, 96, 96);
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, NULL, 48.2, 47.9, &s1) == WF_OK);
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, NULL, 48.2, 47.9, &s2) == WF_OK);
    ck_assert(memcmp(s1.pix, s2.pix, sizeof(double) * 96 * 96) == 0);
    /* explicit positions reproduce the generated ones */
    g.knot_xy = a;
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, NULL, 48.2, 47.9, &s2) == WF_OK);
    ck_assert(memcmp(s1.pix, s2.pix, sizeof(double) * 96 * 96) == 0);
    free(s1.pix);
    free(s2.pix);
    ctx_close(&c);
}
END_TEST

/* ------------------------------------------------------------------------ stamp sizes */

/* Light of a round galaxy outside radius r, from the closed-form enclosed fractions. */
static double light_outside(double bf, double hb, double hd, double r)
{
    double eb = 1.0, ed = 1.0;
    if (bf > 0.0) ck_assert(wf_profile_enclosed(4, hb, r, &eb) == WF_OK);
    if (bf < 1.0) ck_assert(wf_profile_enclosed(1, hd, r, &ed) == WF_OK);
    return bf * (1.0 - eb) + (1.0 - bf) * (1.0 - ed);
}

/* The smallest radius leaving at most eps outside, by plain bisection in r to the last
 * bits, and no smaller than the search's floor: 1e-9 of the larger scale length. */
static double radius_by_bisection(double bf, double hb, double hd, double eps)
{
    double rmin = 1e-9 * fmax(bf > 0.0 ? hb : 0.0, bf < 1.0 ? hd / wf_sersic4_table()->b1 : 0.0);
    if (light_outside(bf, hb, hd, rmin) <= eps) return rmin;
    double lo = rmin, hi = 2.0 * rmin;
    while (light_outside(bf, hb, hd, hi) > eps) hi *= 2.0;
    for (int it = 0; it < 200 && hi - lo > 1e-16 * hi; it++) {
        double mid = 0.5 * (lo + hi);
        if (light_outside(bf, hb, hd, mid) <= eps) hi = mid;
        else lo = mid;
    }
    return hi;
}

/* Without a PSF a round galaxy's stamp half-size is ceil(r / p - 1e-9) for the radius r
 * the search returns: never below the root (the smallest radius leaving at most eps =
 * 1 - flux_fraction of the light out), at most 1e-9 of it above (the bisection's last step
 * is 4.7e-10). Each case is scaled twice, putting the root (found here by bisecting
 * wf_profile_enclosed) just above a pixel edge n p, where a radius more than ~1e-9 p below
 * the root gives n instead of n + 1, and 3e-9 of it below the edge, where a radius more
 * than ~3e-9 above the root gives n + 1 instead of n (both looser at eps 1e-12, where
 * 1 - enclosed loses digits). Pure disk and bulge, mixtures, knots (counted with the
 * disk: placed at the centre, so that only their light matters), eps from 1e-12 to 0.1,
 * and eps = 1 (the search's floor). */
START_TEST(test_radius_search)
{
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, NULL);
    const struct {
        double bf, hb, hd, ff;
        int knots;
    } cases[] = {
        {0.0, 0.0, 0.4, 0.995, 0},      /* pure disk */
        {1.0, 0.3, 0.0, 0.995, 0},      /* pure bulge */
        {0.3, 0.2, 0.5, 0.995, 0},      {0.8, 0.6, 0.3, 0.995, 0},
        {1e-3, 0.05, 0.6, 0.995, 0},    /* a trace of bulge */
        {0.4, 0.25, 0.45, 0.995, 1},    /* knots: a quarter of the disk's light */
        {0.0, 0.0, 0.7, 0.9, 0},        {1.0, 0.5, 0.0, 0.9, 0},
        {0.5, 0.3, 0.3, 1 - 1e-6, 0},   {1.0, 0.1, 0.0, 1 - 1e-6, 0},
        {0.2, 0.004, 0.5, 1 - 1e-12, 0}, {0.0, 0.0, 0.3, 1 - 1e-12, 0},
        {0.6, 0.2, 0.4, 1e-300, 0},     /* eps = 1: the floor already leaves it out */
    };
    const int ncases = (int)(sizeof cases / sizeof *cases);
    double knot_xy[2 * 10];
    for (int j = 0; j < 10; j++) {
        knot_xy[2 * j] = 0.002 * cos(j);
        knot_xy[2 * j + 1] = 0.002 * sin(j);
    }
    for (int k = 0; k < ncases; k++)
        for (int above = 0; above < 2; above++) {
            const double bf = cases[k].bf, eps = 1.0 - cases[k].ff;
            ck_assert(wf_profile_work_tune(&c.work, cases[k].ff, acc.folding_threshold,
                                           acc.kvalue_accuracy, acc.wing_tolerance,
                                           acc.knot_accuracy) == WF_OK);
            /* this bisection's own error: 1 - enclosed loses ~1e-16 of the flux */
            double err = 1e-13 + 1e-15 / eps;
            double r0 = radius_by_bisection(bf, cases[k].hb, cases[k].hd, eps);
            double n = fmax(2.0, round(r0 / P));
            double target = above ? n + 2e-9 + 3.0 * n * err : n - 3.0 * n * (1e-9 + err);
            double scale = eps < 1.0 ? target * P / r0 : 1.0;
            double hb = cases[k].hb * scale, hd = cases[k].hd * scale;
            double r = radius_by_bisection(bf, hb, hd, eps);
            int lower = (int)ceil(r * (1.0 - err) / P - 1e-9);
            int upper = (int)ceil(r * (1.0 + 1e-9 + err) / P - 1e-9);
            ck_assert_msg(lower == upper && (eps >= 1.0 || lower == (int)n + above),
                          "case %d: the case does not pin the radius (%d, %d)", k, lower, upper);
            wf_galaxy g = galaxy(100.0, bf, hd, hb, 0, 0);
            if (cases[k].knots) {
                g.n_knots = 10;
                g.knot_frac = 0.25;
                g.knot_xy = knot_xy;
            }
            wf_stamp s;
            double frac;
            ck_assert(wf_profile_galaxy_bounds(&c.work, &g, NULL, 50.0, 60.0, &s, &frac) == WF_OK);
            int h = (s.nx - 1) / 2;
            ck_assert(s.nx == s.ny && s.x0 == 50 - h && s.y0 == 60 - h && frac == cases[k].ff);
            ck_assert_msg(h == lower, "case %d (bulge %g, hlr %.6f, %.6f, eps %g): half-size %d, "
                          "the radius %.12f\" gives %d", k, bf, hb, hd, eps, h, r, lower);
            ck_assert_msg(light_outside(bf, hb, hd, h * P) <= eps, "case %d: %.3g out of %d pixels",
                          k, light_outside(bf, hb, hd, h * P), h);
        }
    printf("radius search: %d cases, each with the radius just above and just below a pixel "
           "edge, match the bisection\n", ncases);
    ctx_close(&c);
}
END_TEST

/* ------------------------------------------------------------------ flux and shape */

/* No PSF: every pixel is the profile's integral over it, so a round galaxy's stamp equals
 * the exact pixel integrals (checked over the central 41 x 41 pixels, from exact corner
 * values), and its sum the exact light of the stamp's square. */
START_TEST(test_flux_exact_pixels)
{
    gl_init();
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, NULL);
    struct {
        double bf, hd, hb, x, y;
    } cases[] = {{0.0, 0.3, 0.15, 20.0, 20.0}, {0.3, 0.5, 0.25, 40.3, 17.8},
                 {1.0, 0.4, 0.2, 10.5, 10.5}, {0.5, 1.5, 0.75, 100.2, 99.6}};
    for (int k = 0; k < 4; k++) {
        wf_galaxy g = galaxy(1000.0, cases[k].bf, cases[k].hd, cases[k].hb, 0, 0);
        wf_stamp s;
        double frac;
        ck_assert(wf_profile_galaxy_bounds(&c.work, &g, NULL, cases[k].x, cases[k].y, &s,
                                           &frac) == WF_OK);
        s.pix = calloc((size_t)s.nx * s.ny, sizeof(double));
        ck_assert(wf_profile_draw_galaxy(&c.work, &g, NULL, cases[k].x, cases[k].y, &s) == WF_OK);
        round_profile rp = {cases[k].bf, cases[k].hb, 1 - cases[k].bf, cases[k].hd};
        double bx0 = (s.x0 - 0.5 - cases[k].x) * P, bx1 = bx0 + s.nx * P;
        double by0 = (s.y0 - 0.5 - cases[k].y) * P, by1 = by0 + s.ny * P;
        double exact = 1000.0 * box_light(&rp, bx0, bx1, by0, by1);
        int h = 20, ci = (int)lround(cases[k].x) - s.x0, cj = (int)lround(cases[k].y) - s.y0;
        double corner[42][42], worst = 0, peak = 0;
        for (int j = 0; j <= 2 * h + 1; j++)
            for (int i = 0; i <= 2 * h + 1; i++)
                corner[j][i] = signed_corner(&rp, bx0 + (ci - h + i) * P, by0 + (cj - h + j) * P);
        for (int j = 0; j <= 2 * h; j++)
            for (int i = 0; i <= 2 * h; i++) {
                int pi = ci - h + i, pj = cj - h + j;
                if (pi < 0 || pj < 0 || pi >= s.nx || pj >= s.ny) continue;
                double e = 1000.0 * (corner[j + 1][i + 1] - corner[j + 1][i] - corner[j][i + 1] +
                                     corner[j][i]);
                peak = fmax(peak, e);
                worst = fmax(worst, fabs(s.pix[pj * s.nx + pi] - e));
            }
        printf("round galaxy %d: stamp %dx%d holds %.7f of the light (exact %.7f, bound %.4f); "
               "worst central pixel %.2e of the peak\n",
               k, s.nx, s.ny, s.sum / 1000.0, exact / 1000.0, frac, worst / peak);
        /* the draw integrates in real space: exact to its quadrature (1e-12 of the flux) */
        ck_assert_msg(fabs(s.sum - exact) / 1000.0 < 1e-8, "case %d: sum %.9f vs %.9f", k,
                      s.sum, exact);
        ck_assert_msg(exact / 1000.0 >= acc.flux_fraction, "case %d: stamp holds %.5f", k,
                      exact / 1000.0);
        ck_assert_msg(worst / peak < 1e-8, "case %d: pixel error %.3g of the peak", k,
                      worst / peak);
        free(s.pix);
    }
    ctx_close(&c);
}
END_TEST

/* With a PSF: the light of a stamp large enough to hold everything equals the flux times
 * the PSF image's sum, and the default stamp holds at least flux_fraction of it. */
START_TEST(test_flux_with_psf)
{
    wf_psf_image img;
    double *psfpix = gaussian_psf(128, 0.08, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    wf_galaxy g = galaxy(500.0, 0.2, 0.4, 0.2, 0.2, -0.1);
    g.n_knots = 12;
    g.knot_frac = 0.2;
    g.knot_seed = 99;
    wf_stamp s;
    double frac;
    ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, 300.3, 200.7, &s, &frac) == WF_OK);
    s.pix = calloc((size_t)s.nx * s.ny, sizeof(double));
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, 300.3, 200.7, &s) == WF_OK);
    check_finite_nonneg(&s, "default stamp");
    printf("galaxy + PSF: default stamp %dx%d holds %.5f (bound %.3f), clipped %.1e\n", s.nx,
           s.ny, s.sum / 500.0, frac, s.clipped / 500.0);
    ck_assert(s.sum / 500.0 >= acc.flux_fraction - 1e-4 && s.sum / 500.0 <= 1 + 1e-4);
    free(s.pix);
    /* everything: a tight folding threshold and a stamp holding all but 1e-9 */
    ck_assert(wf_profile_work_tune(&c.work, 1 - 1e-9, 1e-9, 1e-8, 0.0, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
    ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, 300.3, 200.7, &s, NULL) == WF_OK);
    s.pix = calloc((size_t)s.nx * s.ny, sizeof(double));
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, 300.3, 200.7, &s) == WF_OK);
    printf("galaxy + PSF: %dx%d stamp (fft %d) holds %.8f of the flux\n", s.nx, s.ny, s.fft,
           s.sum / 500.0);
    ck_assert_msg(fabs(s.sum / 500.0 - 1) < 2e-6, "sum %.9f", s.sum / 500.0);
    free(s.pix);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

START_TEST(test_centred_symmetric)
{
    wf_psf_image img;
    double *psfpix = gaussian_psf(128, 0.07, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    const double pos[][2] = {{50.0, 50.0}, {50.5, 50.5}, {50.5, 50.0}};
    for (int k = 0; k < 3; k++)
        for (int with_psf = 0; with_psf < 2; with_psf++) {
            wf_galaxy g = galaxy(1.0, 0.4, 0.5, 0.25, 0, 0);
            wf_stamp s = stamp_new(10, 10, 81 + (pos[k][0] != 50.0), 81 + (pos[k][1] != 50.0));
            ck_assert(wf_profile_draw_galaxy(&c.work, &g, with_psf ? &c.psf : NULL, pos[k][0],
                                             pos[k][1], &s) == WF_OK);
            double cx, cy, e1, e2;
            unweighted(s.pix, s.nx, s.ny, &cx, &cy, &e1, &e2);
            cx += s.x0 - pos[k][0];
            cy += s.y0 - pos[k][1];
            ck_assert_msg(fabs(cx) < 1e-9 && fabs(cy) < 1e-9,
                          "centred profile at (%g, %g), psf %d: first moments %.3g %.3g",
                          pos[k][0], pos[k][1], with_psf, cx, cy);
            /* and the image is mirror-symmetric about the centre, not just balanced */
            double asym = 0;
            for (int j = 0; j < s.ny; j++)
                for (int i = 0; i < s.nx; i++)
                    asym = fmax(asym, fabs(s.pix[j * s.nx + i] -
                                           s.pix[(s.ny - 1 - j) * s.nx + (s.nx - 1 - i)]));
            ck_assert_msg(asym < 1e-12, "not point-symmetric: %.3g", asym);
            free(s.pix);
        }
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* A sheared round profile has the input ellipticity: unweighted moments of a no-PSF draw
 * (pixel variance p^2/12 removed) of an exponential, whose moments converge; e = 0.7 at
 * six angles, through (e1, e2) and through the rotation. */
START_TEST(test_sheared_ellipticity)
{
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, NULL);
    ck_assert(wf_profile_work_tune(&c.work, 1 - 1e-9, 1e-9, 1e-7, 0.0, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
    const double emag[] = {0.3, 0.7, 0.7, 0.7, 0.7, 0.7, 0.7};
    const double beta[] = {-0.3, 0.0, 30.0, 45.0, 60.0, 90.0, 135.0}; /* position angle, deg */
    double worst = 0;
    for (int k = 0; k < 7; k++)
        for (int via_rot = 0; via_rot < 2; via_rot++) {
            double b = beta[k] * M_PI / 180;
            double e1 = emag[k] * cos(2 * b), e2 = emag[k] * sin(2 * b);
            wf_galaxy g = via_rot ? galaxy(1, 0, 0.35, 0, emag[k], 0)
                                  : galaxy(1, 0, 0.35, 0, e1, e2);
            if (via_rot) g.rotation = b;
            wf_stamp s;
            ck_assert(wf_profile_galaxy_bounds(&c.work, &g, NULL, 200.3, 100.6, &s, NULL) == WF_OK);
            s.pix = calloc((size_t)s.nx * s.ny, sizeof(double));
            ck_assert(wf_profile_draw_galaxy(&c.work, &g, NULL, 200.3, 100.6, &s) == WF_OK);
            check_finite_nonneg(&s, "sheared");
            double cx, cy, m1, m2;
            unweighted(s.pix, s.nx, s.ny, &cx, &cy, &m1, &m2);
            double d = fmax(fabs(m1 - e1), fabs(m2 - e2));
            worst = fmax(worst, d);
            /* the pixel-centre moments of a pixelised profile miss the light's position
             * inside each pixel: 4e-5 measured */
            ck_assert_msg(d < 1e-4, "e = %.2f at %.0f deg (%s): measured (%.5f, %.5f) vs "
                          "(%.5f, %.5f)", emag[k], beta[k], via_rot ? "rotation" : "e1, e2",
                          m1, m2, e1, e2);
            ck_assert_msg(fabs(s.sum - 1) < 1e-5, "flux %.7f", s.sum);
            /* pixel-centre moments of a pixelised off-centre profile are not its centroid
             * exactly (the light's position inside each pixel is lost); for the
             * exponential's central kink the difference is ~1e-4 pixel */
            ck_assert_msg(fabs(cx + s.x0 - 200.3) < 1e-3 && fabs(cy + s.y0 - 100.6) < 1e-3,
                          "centroid (%.6f, %.6f)", cx + s.x0, cy + s.y0);
            free(s.pix);
        }
    printf("sheared exponential: worst ellipticity error %.2e (e up to 0.7, 7 angles, via "
           "(e1, e2) and rotation)\n", worst);
    ctx_close(&c);
}
END_TEST

/* ------------------------------------------------------------------------ stiff cases */

START_TEST(test_stiff_tiny_galaxy)
{
    wf_psf_image img;
    double *psfpix = gaussian_psf(128, 0.07, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    wf_galaxy g = galaxy(1.0, 0.5, 0.005, 0.0025, 0.5, 0.3);
    g.n_knots = 5;
    g.knot_frac = 0.25;
    g.knot_seed = 3;
    wf_stamp s, pt;
    ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, 64.2, 63.7, &s, NULL) == WF_OK);
    s.pix = calloc((size_t)s.nx * s.ny, sizeof(double));
    pt = stamp_new(s.x0, s.y0, s.nx, s.ny);
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, 64.2, 63.7, &s) == WF_OK);
    ck_assert(wf_profile_draw_point(&c.work, &c.psf, 1.0, 64.2, 63.7, &pt) == WF_OK);
    check_finite_nonneg(&s, "hlr 0.005\"");
    double worst = 0, peak = 0;
    for (int i = 0; i < s.nx * s.ny; i++) {
        worst = fmax(worst, fabs(s.pix[i] - pt.pix[i]));
        peak = fmax(peak, pt.pix[i]);
    }
    printf("hlr 0.005\": %dx%d stamp, sum %.6f, differs from a point source by %.2e of the "
           "peak\n", s.nx, s.ny, s.sum, worst / peak);
    /* A 0.005" galaxy is nearly a point source to 0.11" pixels and a 0.07" PSF. The peak
     * drops by about its second moment over the PSF's: the de Vaucouleurs tail gives
     * <r^2> = 21.7 Re^2, so <r^2> / 2 = 5.5e-5 arcsec^2 in all against sigma^2 = 4.9e-3:
     * ~1.1%; measured 0.9%. */
    ck_assert_msg(worst / peak < 1.5e-2, "tiny galaxy vs point: %.3g", worst / peak);
    ck_assert(fabs(s.sum - pt.sum) < 1e-4);
    /* without a PSF nearly all of it falls in one pixel */
    wf_stamp n = stamp_new(60, 60, 9, 9);
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, NULL, 64.2, 63.7, &n) == WF_OK);
    check_finite_nonneg(&n, "hlr 0.005\", no PSF");
    printf("hlr 0.005\", no PSF: %.5f in the centre pixel, %.7f in the 9x9 stamp\n", n.pix[40],
           n.sum);
    ck_assert_msg(n.pix[4 * 9 + 4] > 0.99 && fabs(n.sum - 1) < 1e-4, "centre pixel %.4f sum %.5f",
                  n.pix[40], n.sum);
    free(s.pix);
    free(pt.pix);
    free(n.pix);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

START_TEST(test_stiff_huge_galaxy)
{
    gl_init();
    wf_psf_image img;
    double *psfpix = gaussian_psf(128, 0.07, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    const double bf[2] = {0.0, 0.3};
    for (int k = 0; k < 2; k++) {
        wf_galaxy g = galaxy(2e4, bf[k], 20.0, 10.0, 0, 0);
        wf_stamp s;
        double frac;
        ck_assert(wf_profile_galaxy_bounds(&c.work, &g, NULL, 2000.0, 1500.3, &s, &frac) == WF_OK);
        ck_assert_msg(s.nx <= acc.max_fft && s.ny <= acc.max_fft, "stamp %dx%d", s.nx, s.ny);
        s.pix = calloc((size_t)s.nx * s.ny, sizeof(double));
        double t0 = now_s();
        ck_assert_msg(wf_profile_draw_galaxy(&c.work, &g, NULL, 2000.0, 1500.3, &s) == WF_OK,
                      "%s", wf_error_message());
        double ms = 1e3 * (now_s() - t0);
        check_finite_nonneg(&s, "hlr 20\"");
        round_profile rp = {bf[k], 10.0, 1 - bf[k], 20.0};
        double bx0 = (s.x0 - 0.5 - 2000.0) * P, by0 = (s.y0 - 0.5 - 1500.3) * P;
        double exact = box_light(&rp, bx0, bx0 + s.nx * P, by0, by0 + s.ny * P);
        printf("hlr 20\" (bulge %.1f): stamp %dx%d (fft %d, %.0f ms) holds %.5f of the light, "
               "exact %.5f, bound %.4f\n",
               bf[k], s.nx, s.ny, s.fft, ms, s.sum / 2e4, exact, frac);
        /* bounded: the stamp is clamped to max_fft - 1; without a PSF its pixels are exact
         * integrals, so its light is the square's */
        ck_assert_msg(fabs(s.sum / 2e4 - exact) < 1e-3, "huge galaxy: %.5f vs exact %.5f",
                      s.sum / 2e4, exact);
        ck_assert(frac <= exact + 1e-3);
        /* with the PSF (Fourier space): the box's periodic images would wrap 15% of the
         * bulge's light in; it is taken back out in real space, to 2e-4 measured */
        wf_stamp sp = stamp_new(s.x0, s.y0, s.nx, s.ny);
        ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, 2000.0, 1500.3, &sp) == WF_OK);
        check_finite_nonneg(&sp, "hlr 20\" with PSF");
        printf("hlr 20\" (bulge %.1f) with a PSF: fft %d, holds %.5f\n", bf[k], sp.fft,
               sp.sum / 2e4);
        ck_assert_msg(fabs(sp.sum - s.sum) / 2e4 < 1e-3, "with PSF %.5f without %.5f",
                      sp.sum / 2e4, s.sum / 2e4);
        free(s.pix);
        free(sp.pix);
    }
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* Magnitude 35 in Y106 (26.46 gives 1 e-/s): 3.8e-4 e-/s. */
START_TEST(test_stiff_faint)
{
    wf_psf_image img;
    double *psfpix = gaussian_psf(128, 0.07, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    double flux = pow(10.0, -0.4 * (35.0 - 26.46));
    wf_galaxy g = galaxy(flux, 0.3, 0.3, 0.15, 0.2, 0.1);
    g.n_knots = 8;
    g.knot_frac = 0.1;
    wf_stamp s;
    ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, 10.4, 4000.9, &s, NULL) == WF_OK);
    s.pix = calloc((size_t)s.nx * s.ny, sizeof(double));
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, 10.4, 4000.9, &s) == WF_OK);
    check_finite_nonneg(&s, "magnitude 35");
    ck_assert_msg(s.sum / flux > 0.995 && s.sum / flux < 1.0001, "sum %.6g of %.6g", s.sum, flux);
    ck_assert_msg(s.clipped / flux < 1e-4, "clipped %.3g of the flux", s.clipped / flux);
    wf_stamp p = stamp_new(s.x0, s.y0, s.nx, s.ny);
    ck_assert(wf_profile_draw_point(&c.work, &c.psf, flux, 10.4, 4000.9, &p) == WF_OK);
    check_finite_nonneg(&p, "magnitude 35 point");
    /* zero flux: an empty stamp, not an error; its bounds are those it would have */
    g.flux = 0;
    g.bulge_frac = 1;
    wf_stamp z;
    ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, 10.4, 4000.9, &z, NULL) == WF_OK);
    ck_assert(z.nx > 1 && z.nx < 200);
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, 10.4, 4000.9, &s) == WF_OK);
    ck_assert(s.sum == 0.0);
    free(s.pix);
    free(p.pix);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* The bulge's cusp without a PSF, against exact pixel integrals computed here: the drawer
 * integrates in real space (polar fans around the centre), so there is no Fourier series
 * to ring and the pixels are exact to its quadrature. */
START_TEST(test_stiff_cusp)
{
    gl_init();
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, NULL);
    const double hlr[3] = {0.05, 0.1, 0.3};
    for (int k = 0; k < 3; k++) {
        wf_galaxy g = galaxy(1.0, 1.0, 1.0, hlr[k], 0, 0);
        double x = 30.0 + 0.3 * k, y = 30.0 - 0.2 * k;
        wf_stamp s = stamp_new(14, 14, 33, 33);
        ck_assert(wf_profile_draw_galaxy(&c.work, &g, NULL, x, y, &s) == WF_OK);
        round_profile rp = {1.0, hlr[k], 0.0, 1.0};
        double worst = 0, peak = 0;
        for (int j = 0; j < s.ny; j++)
            for (int i = 0; i < s.nx; i++) {
                double x0 = (s.x0 + i - 0.5 - x) * P, y0 = (s.y0 + j - 0.5 - y) * P;
                double e = box_light(&rp, x0, x0 + P, y0, y0 + P);
                peak = fmax(peak, e);
                worst = fmax(worst, fabs(s.pix[j * s.nx + i] - e));
            }
        printf("de Vaucouleurs cusp, hlr %.2f\", no PSF: worst pixel %.2e of the peak\n", hlr[k],
               worst / peak);
        ck_assert_msg(worst / peak < 1e-9, "hlr %g: cusp error %.3g of the peak", hlr[k],
                      worst / peak);
        ck_assert_msg(s.clipped == 0.0, "hlr %g: negative pixels %.3g", hlr[k], s.clipped);
        free(s.pix);
    }
    ctx_close(&c);
}
END_TEST

/* Brute-force real-space convolution for the cusp test: exact light of 1/n-pixel
 * sub-pixels over +-2.5" (the no-PSF drawer at 0.11/n" pixels, itself checked against
 * exact integrals), each spread by the Gaussian PSF widened by a uniform sub-pixel's
 * variance s^2 / 12 and integrated over the 0.11" pixels with error functions. The
 * sub-pixel's light is not uniform near the cusp, so this converges as s^2 (measured:
 * 3.5e-3, 9.1e-4, 2.3e-4 of the peak for n = 8, 16, 32). */
static void cusp_reference(const wf_galaxy *g, double sigma, int n, double x, double y,
                           const wf_stamp *s, double *ref)
{
    wf_profile_accuracy fine;
    wf_profile_accuracy_default(&fine);
    fine.pixel_scale = P / n;
    ctx cf;
    ctx_open(&cf, &fine, NULL);
    int h = (int)(2.5 / (P / n));
    wf_stamp sub = stamp_new(-h, -h, 2 * h + 1, 2 * h + 1);
    ck_assert(wf_profile_draw_galaxy(&cf.work, g, NULL, 0.0, 0.0, &sub) == WF_OK);
    double sg = sqrt(sigma * sigma + (P / n) * (P / n) / 12.0) * sqrt(2.0);
    memset(ref, 0, sizeof(double) * s->nx * s->ny);
    double *ex = malloc(sizeof(double) * s->nx), *ey = malloc(sizeof(double) * s->ny);
    for (int j = 0; j < sub.ny; j++)
        for (int i = 0; i < sub.nx; i++) {
            double l = sub.pix[j * sub.nx + i];
            if (l < 1e-14) continue;
            double sx = x * P + (sub.x0 + i) * P / n, sy = y * P + (sub.y0 + j) * P / n;
            for (int k = 0; k < s->nx; k++) {
                double a = (s->x0 + k - 0.5) * P - sx;
                ex[k] = 0.5 * (erf((a + P) / sg) - erf(a / sg));
            }
            for (int k = 0; k < s->ny; k++) {
                double a = (s->y0 + k - 0.5) * P - sy;
                ey[k] = 0.5 * (erf((a + P) / sg) - erf(a / sg));
            }
            for (int jj = 0; jj < s->ny; jj++) {
                if (ey[jj] < 1e-16) continue;
                for (int ii = 0; ii < s->nx; ii++) ref[jj * s->nx + ii] += l * ey[jj] * ex[ii];
            }
        }
    free(ex);
    free(ey);
    free(sub.pix);
    ctx_close(&cf);
}

/* The cusp through the PSF (the production path, Fourier space) against the brute-force
 * convolution, Richardson-extrapolated from 1/8 and 1/16 sub-pixels (residual ~5e-5 of
 * the peak, from the n = 16, 32 pair). */
START_TEST(test_stiff_cusp_with_psf)
{
    const double sigma = 0.07;
    wf_psf_image img;
    double *psfpix = gaussian_psf(128, sigma, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    wf_galaxy g = galaxy(1.0, 1.0, 1.0, 0.05, 0.1, -0.05);
    const double x = 40.3, y = 39.8;
    wf_stamp s = stamp_new(30, 30, 21, 21);
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, x, y, &s) == WF_OK);
    double r8[21 * 21], r16[21 * 21], worst = 0, peak = 0;
    cusp_reference(&g, sigma, 8, x, y, &s, r8);
    cusp_reference(&g, sigma, 16, x, y, &s, r16);
    for (int i = 0; i < 21 * 21; i++) {
        double ref = r16[i] + (r16[i] - r8[i]) / 3.0;
        peak = fmax(peak, ref);
        worst = fmax(worst, fabs(s.pix[i] - ref));
    }
    printf("de Vaucouleurs cusp (hlr 0.05\") through a 0.07\" PSF: worst pixel %.2e of the "
           "peak against real-space convolution; negative ringing clipped %.1e of the flux\n",
           worst / peak, s.clipped);
    /* No ringing: the PSF band-limits the cusp, and the PSF table is cut where it is
     * below 1e-7 (or tapered at the optical cut-off). */
    ck_assert_msg(worst / peak < 2e-4, "cusp with PSF: %.3g of the peak", worst / peak);
    ck_assert_msg(s.clipped < 1e-6, "ringing %.3g", s.clipped);
    free(s.pix);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* A stamp drawn in row pieces (as the tile renderer does for objects larger than its pool)
 * has bit-identical pixels. */
START_TEST(test_pieces_identical)
{
    wf_psf_image img;
    double *psfpix = gaussian_psf(128, 0.07, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    wf_galaxy g = galaxy(100, 0.3, 0.6, 0.3, 0.1, 0.3);
    g.n_knots = 20;
    g.knot_frac = 0.2;
    g.knot_seed = 77;
    wf_stamp whole;
    ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, 500.7, 800.2, &whole, NULL) == WF_OK);
    whole.pix = calloc((size_t)whole.nx * whole.ny, sizeof(double));
    ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, 500.7, 800.2, &whole) == WF_OK);
    int cut[] = {0, 7, 8, whole.ny / 2, whole.ny - 1, whole.ny};
    for (int k = 0; k + 1 < 6; k++) {
        if (cut[k + 1] <= cut[k]) continue;
        wf_stamp part = stamp_new(whole.x0, whole.y0 + cut[k], whole.nx, cut[k + 1] - cut[k]);
        ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, 500.7, 800.2, &part) == WF_OK);
        ck_assert_msg(memcmp(part.pix, whole.pix + (size_t)cut[k] * whole.nx,
                             sizeof(double) * part.nx * part.ny) == 0,
                      "rows %d..%d differ from the whole stamp", cut[k], cut[k + 1]);
        free(part.pix);
    }
    free(whole.pix);
    /* and an object beyond max_fft, whose wrapped light is taken out in real space */
    wf_galaxy big = galaxy(100, 0.3, 20.0, 10.0, 0.1, 0.1);
    ck_assert(wf_profile_galaxy_bounds(&c.work, &big, &c.psf, 500.7, 800.2, &whole, NULL) ==
              WF_OK);
    whole.pix = calloc((size_t)whole.nx * whole.ny, sizeof(double));
    ck_assert(wf_profile_draw_galaxy(&c.work, &big, &c.psf, 500.7, 800.2, &whole) == WF_OK);
    int bcut[] = {0, 100, 511, 700, whole.ny};
    for (int k = 0; k + 1 < 5; k++) {
        wf_stamp part = stamp_new(whole.x0, whole.y0 + bcut[k], whole.nx, bcut[k + 1] - bcut[k]);
        ck_assert(wf_profile_draw_galaxy(&c.work, &big, &c.psf, 500.7, 800.2, &part) == WF_OK);
        ck_assert_msg(memcmp(part.pix, whole.pix + (size_t)bcut[k] * whole.nx,
                             sizeof(double) * part.nx * part.ny) == 0,
                      "huge galaxy: rows %d..%d differ from the whole stamp", bcut[k],
                      bcut[k + 1]);
        free(part.pix);
    }
    free(whole.pix);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* ------------------------------------------------------------------- core and wing */

/* A PSF with a wing: 90% in a Gaussian of sigma s1, 10% in one of s2 centred 0.25" along x
 * and -0.15" along y (so that a mirrored or transposed wing table shows), n x n samples at
 * P / 4, normalised. */
static double *halo_psf(int n, double s1, double s2, wf_psf_image *img)
{
    double *pix = malloc(sizeof(double) * n * n), s = 0, c = 0.5 * (n - 1), h = P / 4;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            double r2 = ((i - c) * (i - c) + (j - c) * (j - c)) * h * h;
            double dx = (i - c) * h - 0.25, dy = (j - c) * h + 0.15, q2 = dx * dx + dy * dy;
            pix[j * n + i] = 0.9 * exp(-0.5 * r2 / (s1 * s1)) / (s1 * s1) +
                             0.1 * exp(-0.5 * q2 / (s2 * s2)) / (s2 * s2);
            s += pix[j * n + i];
        }
    for (int i = 0; i < n * n; i++) pix[i] /= s;
    img->n = n;
    img->scale_arcsec = h;
    img->pix = pix;
    img->band_limit = 0.0;
    return pix;
}

/* Piece by piece, as the renderer keeps a split galaxy: its core box (box, within the
 * stamp bounds b) plus core `core`'s wing over the stamp must give the whole split draw
 * `whole`, equal wherever nothing was clipped: the only difference is the core's negative
 * ringing, zeroed before the wing is added here and after it in the whole draw. */
static void core_plus_wing(wf_profile_work *work, const wf_profile_psf *psf, const wf_galaxy *g, double x,
                           double y, const wf_stamp *b, const wf_stamp *box, int core, const wf_stamp *whole)
{
    wf_stamp cs = stamp_new(box->x0, box->y0, box->nx, box->ny), sum = stamp_new(b->x0, b->y0, b->nx, b->ny);
    ck_assert(wf_profile_draw_galaxy_core(work, g, psf, x, y, &cs) == WF_OK);
    for (int j = 0; j < box->ny; j++)
        memcpy(sum.pix + (size_t)(box->y0 - b->y0 + j) * b->nx + (box->x0 - b->x0), cs.pix + (size_t)j * box->nx,
               sizeof(double) * box->nx);
    ck_assert(wf_profile_add_wing(psf, core, g->flux, x, y, &sum) == WF_OK);
    double d = 0.0;
    for (int k = 0; k < b->nx * b->ny; k++)
        if (whole->pix[k] > 0.0 && sum.pix[k] > 0.0) d = fmax(d, fabs(sum.pix[k] - whole->pix[k]));
    ck_assert_msg(d <= cs.clipped + 1e-12 * g->flux, "core %d, hlr %g: core + wing differs by %g (clipped %g)", core,
                  g->hlr_disk, d, cs.clipped);
    free(cs.pix);
    free(sum.pix);
}

/* Core and wing (sim/draw/profile.h): the wing table holds exactly the light the core lacks; an
 * object whose wing error bound is not tolerated is drawn bit for bit as without the split;
 * one that takes it keeps its flux, moves no pixel by more than the bound 2 flux wing_max
 * and, when it is nearly a point, matches the unsplit draw closely; pieces are identical. */
START_TEST(test_core_wing)
{
    wf_psf_image img;
    double *psfpix = halo_psf(256, 0.07, 0.8, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx whole, split;
    ctx_open(&whole, &acc, &img);
    acc.core_radius = 1.0;
    ctx_open(&split, &acc, &img);
    const wf_profile_psf *sp = &split.psf;
    const wf_profile_core *co = &sp->core[0];
    ck_assert(sp->ncore == 1 && co->radius == 1.0 && co->wing != NULL);

    /* the wing's pixels at whole-pixel offsets tile the plane: they sum to its flux */
    double wsum = 0.0;
    for (int k = 0; k < sp->wing_np * sp->wing_np; k++) wsum += co->wing[k];
    printf("core and wing: core %.6f of the flux, wing sums to %.6f, max wing pixel %.3g\n",
           co->flux, wsum, co->wing_max);
    ck_assert_msg(fabs(wsum - (1.0 - co->flux)) < 1e-6, "wing %.8f, core %.8f", wsum, co->flux);
    ck_assert(co->flux > 0.9 && co->flux < 0.99);

    const double hlr[] = {0.005, 0.2, 0.5};
    for (int h = 0; h < 3; h++) {
        wf_galaxy g = galaxy(1000.0, 0.3, hlr[h], 0.5 * hlr[h], 0.2, -0.1);
        wf_profile_knot_method(&split.work, WF_KNOTS_AUTO);
        g.n_knots = h ? 30 : 0;
        g.knot_frac = h ? 0.2 : 0.0;
        g.knot_seed = 5;
        double x = 400.3, y = 300.8;
        wf_stamp b;
        ck_assert(wf_profile_galaxy_bounds(&whole.work, &g, &whole.psf, x, y, &b, NULL) == WF_OK);
        /* not tolerated: the same bits as the whole PSF */
        wf_stamp a = stamp_new(b.x0, b.y0, b.nx, b.ny), c = stamp_new(b.x0, b.y0, b.nx, b.ny);
        ck_assert(wf_profile_draw_galaxy(&whole.work, &g, &whole.psf, x, y, &a) == WF_OK);
        ck_assert(wf_profile_draw_galaxy(&split.work, &g, &split.psf, x, y, &c) == WF_OK);
        ck_assert_msg(!memcmp(a.pix, c.pix, sizeof(double) * b.nx * b.ny),
                      "hlr %g: an untolerated split changed the stamp", hlr[h]);
        /* tolerated at the default folding: a smaller box */
        int fft_whole = a.fft;
        ck_assert(wf_profile_work_tune(&split.work, acc.flux_fraction, acc.folding_threshold,
                                       acc.kvalue_accuracy, 1e30, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
        ck_assert(wf_profile_draw_galaxy(&split.work, &g, &split.psf, x, y, &c) == WF_OK);
        /* (the largest galaxy's box is its own, with or without the wing) */
        ck_assert_msg(h == 2 ? c.fft <= fft_whole : c.fft < fft_whole,
                      "hlr %g: the split did not shrink the box (%d, %d)", hlr[h], c.fft,
                      fft_whole);
        int fft_split = c.fft;
        /* tolerated, both with folding 1e-7 so that only the wing differs (the knots summed
         * in the box: a tolerance of 1e30 would also let them be read from the core's knot
         * table at the shortest reach, test_real_knots_galaxy) */
        wf_profile_knot_method(&split.work, WF_KNOTS_DIRECT);
        ck_assert(wf_profile_work_tune(&whole.work, acc.flux_fraction, 1e-7, 1e-7, 0.0, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
        ck_assert(wf_profile_work_tune(&split.work, acc.flux_fraction, 1e-7, 1e-7, 1e30, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
        ck_assert(wf_profile_draw_galaxy(&whole.work, &g, &whole.psf, x, y, &a) == WF_OK);
        ck_assert(wf_profile_draw_galaxy(&split.work, &g, &split.psf, x, y, &c) == WF_OK);
        double peak = 0.0, worst = 0.0;
        for (int k = 0; k < b.nx * b.ny; k++) {
            peak = fmax(peak, a.pix[k]);
            worst = fmax(worst, fabs(a.pix[k] - c.pix[k]));
        }
        double bound = 2.0 * g.flux * co->wing_max;
        printf("core and wing: hlr %.3f: FFT %d -> %d, flux %.6f -> %.6f, worst pixel %.2e of "
               "the peak, %.3f of the bound\n", hlr[h], fft_whole, fft_split, a.sum / g.flux,
               c.sum / g.flux, worst / peak, worst / bound);
        ck_assert_msg(worst <= bound, "hlr %g: %g beyond the bound %g", hlr[h], worst, bound);
        /* the same light in the stamp but for the wing's blur at the stamp's edge, which
         * puts a little more of the true wing outside (4e-5 at hlr 0.2) */
        ck_assert_msg(fabs(c.sum - a.sum) < 1e-4 * g.flux, "hlr %g: flux %.8f vs %.8f", hlr[h],
                      c.sum / g.flux, a.sum / g.flux);
        if (h == 0) /* nearly a point: the split is exact for a point */
            ck_assert_msg(worst < 0.02 * bound, "point-like: %g of the bound", worst / bound);
        /* piece by piece, as the renderer keeps it: the core box, then the wing over the
         * stamp, give the split stamp (equal where nothing was clipped) */
        {
            wf_stamp box, bb;
            int taken = 0;
            ck_assert(wf_profile_galaxy_core(&split.work, &g, &split.psf, x, y, &bb, &box, &taken) == WF_OK);
            ck_assert(bb.x0 == b.x0 && bb.y0 == b.y0 && bb.nx == b.nx && bb.ny == b.ny); /* the stamp's bounds */
            ck_assert_msg(taken && box.x0 >= b.x0 && box.y0 >= b.y0 && box.x0 + box.nx <= b.x0 + b.nx &&
                              box.y0 + box.ny <= b.y0 + b.ny && box.nx <= c.fft && box.ny <= c.fft,
                          "hlr %g: box %dx%d at (%d, %d)", hlr[h], box.nx, box.ny, box.x0, box.y0);
            core_plus_wing(&split.work, &split.psf, &g, x, y, &b, &box, taken, &c);
            /* an untolerated object: the box is the stamp */
            ck_assert(wf_profile_work_tune(&split.work, acc.flux_fraction, 1e-7, 1e-7, 0.0, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
            ck_assert(wf_profile_galaxy_core(&split.work, &g, &split.psf, x, y, &bb, &box, &taken) == WF_OK);
            ck_assert(!taken && box.x0 == b.x0 && box.nx == b.nx && box.y0 == b.y0 && box.ny == b.ny);
            ck_assert(wf_profile_work_tune(&split.work, acc.flux_fraction, 1e-7, 1e-7, 1e30, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
        }
        /* pieces of a split stamp are the same pixels as the whole */
        int cut[] = {0, 5, b.ny / 2, b.ny};
        for (int k = 0; k + 1 < 4; k++) {
            wf_stamp part = stamp_new(b.x0, b.y0 + cut[k], b.nx, cut[k + 1] - cut[k]);
            ck_assert(wf_profile_draw_galaxy(&split.work, &g, &split.psf, x, y, &part) == WF_OK);
            ck_assert_msg(!memcmp(part.pix, c.pix + (size_t)cut[k] * b.nx,
                                  sizeof(double) * part.nx * part.ny),
                          "hlr %g: split rows %d..%d differ", hlr[h], cut[k], cut[k + 1]);
            free(part.pix);
        }
        ck_assert(wf_profile_work_tune(&whole.work, acc.flux_fraction, acc.folding_threshold,
                                       acc.kvalue_accuracy, 0.0, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
        ck_assert(wf_profile_work_tune(&split.work, acc.flux_fraction, acc.folding_threshold,
                                       acc.kvalue_accuracy, 0.0, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
        free(a.pix);
        free(c.pix);
    }
    /* point sources never take the split: nothing to gain */
    wf_stamp b;
    ck_assert(wf_profile_point_bounds(&whole.work, &whole.psf, 10.2, 20.6, &b, NULL) == WF_OK);
    wf_stamp a = stamp_new(b.x0, b.y0, b.nx, b.ny), c = stamp_new(b.x0, b.y0, b.nx, b.ny);
    ck_assert(wf_profile_work_tune(&split.work, acc.flux_fraction, acc.folding_threshold,
                                   acc.kvalue_accuracy, 1e30, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
    ck_assert(wf_profile_draw_point(&whole.work, &whole.psf, 50.0, 10.2, 20.6, &a) == WF_OK);
    ck_assert(wf_profile_draw_point(&split.work, &split.psf, 50.0, 10.2, 20.6, &c) == WF_OK);
    ck_assert(!memcmp(a.pix, c.pix, sizeof(double) * b.nx * b.ny));
    free(a.pix);
    free(c.pix);
    ctx_close(&whole);
    ctx_close(&split);
    free(psfpix);
}
END_TEST

/* Core levels (sim/draw/profile.h): radii halve level by level; the first level's tables are
 * those of a one-core PSF, bit for bit; every wing holds exactly the light its core lacks,
 * and smaller cores leave more in the wing (the premise of taking the smallest allowed). A
 * galaxy takes the smallest core whose bound 2 flux wing_max its tolerance allows, gets a
 * box no larger than with a larger core, stays within that core's bound, and its core box
 * plus that core's wing is its whole split stamp. */
/* The split PSF's tables on 1 to 4 threads (core passes and wings run in parallel on
 * scratch of their own, off the arena's top): every table bit for bit the same; an arena
 * sized for one thread serves a request for four with fewer, and still the same tables. */
static void assert_same_psf(const wf_profile_psf *a, const wf_profile_psf *b, int threads)
{
    ck_assert_msg(a->kr == b->kr && a->ncore == b->ncore && a->wing_np == b->wing_np && a->nee == b->nee,
                  "%d threads: layout differs", threads);
    size_t tab = (size_t)(2 * a->kr + 1) * (size_t)(2 * a->kr + 1);
    size_t wing = (size_t)a->wing_os * a->wing_os * (size_t)a->wing_np * a->wing_np;
    ck_assert_msg(!memcmp(a->re, b->re, tab * sizeof(float)) && !memcmp(a->im, b->im, tab * sizeof(float)) &&
                  !memcmp(a->env, b->env, ((size_t)a->kr + 2) * sizeof(double)) &&
                  !memcmp(a->ee, b->ee, (size_t)a->nee * sizeof(double)), "%d threads: whole table differs", threads);
    ck_assert_msg(a->pixel_max == b->pixel_max && a->kmax == b->kmax, "%d threads: bounds differ", threads);
    ck_assert_msg(a->nalt == b->nalt && a->nalt > 0, "%d threads: %d and %d tables at other periods", threads,
                  a->nalt, b->nalt);
    for (int l = 0; l <= a->ncore; l++) /* the tables at other periods, the whole's and each core's */
        for (int i = 0; i < a->nalt; i++) {
            const wf_profile_table *p = l ? &a->core[l - 1].alt[i] : &a->alt[i];
            const wf_profile_table *q = l ? &b->core[l - 1].alt[i] : &b->alt[i];
            const size_t n = (size_t)(2 * p->kr + 1) * (size_t)(2 * p->kr + 1);
            ck_assert_msg(p->fft == q->fft && p->kr == q->kr && !memcmp(p->re, q->re, n * sizeof(float)) &&
                              !memcmp(p->im, q->im, n * sizeof(float)) && p->steps.n == q->steps.n,
                          "%d threads: pass %d's table at another period differs", threads, l);
        }
    for (int l = 0; l < a->ncore; l++) {
        const wf_profile_core *p = &a->core[l], *q = &b->core[l];
        ck_assert_msg(!memcmp(p->re, q->re, tab * sizeof(float)) && !memcmp(p->im, q->im, tab * sizeof(float)) &&
                      !memcmp(p->env, q->env, ((size_t)a->kr + 2) * sizeof(double)) &&
                      !memcmp(p->wing, q->wing, wing * sizeof(float)) && p->flux == q->flux &&
                      p->wing_max == q->wing_max, "%d threads: core %d differs", threads, l);
        const size_t knot = (size_t)a->knot_os * a->knot_os * (size_t)p->knot_np * p->knot_np;
        ck_assert_msg(p->knot_np == q->knot_np && p->knot_half == q->knot_half &&
                      !memcmp(p->knot, q->knot, knot * sizeof(float)) && p->knot_interp == q->knot_interp &&
                      !memcmp(p->knot_out, q->knot_out, ((size_t)p->knot_half + 1) * sizeof(double)) &&
                      !memcmp(p->knot_miss, q->knot_miss, ((size_t)p->knot_half + 1) * sizeof(double)),
                      "%d threads: core %d's knot table differs", threads, l);
    }
}

/* The halo PSF with the scene's cores (2", 1", 0.5") and, with keep, the arena sizes its
 * tables need; returns the image's pixels, for the caller to free. */
static double *halo_split(wf_psf_image *img, wf_profile_accuracy *acc, size_t *keep, size_t *scratch)
{
    double *pix = halo_psf(256, 0.07, 0.8, img);
    wf_profile_accuracy_default(acc);
    acc->core_radius = 2.0;
    acc->core_levels = 3;
    if (keep) ck_assert(wf_profile_psf_need(img, acc, keep, scratch) == WF_OK);
    return pix;
}

START_TEST(test_psf_tables_threads)
{
    wf_psf_image img;
    wf_profile_accuracy acc;
    size_t keep, scratch;
    double *psfpix = halo_split(&img, &acc, &keep, &scratch);
    wf_profile_psf ref;
    void *rmem = malloc(keep + scratch + 4096);
    wf_arena rar;
    wf_arena_init(&rar, rmem, keep + scratch + 4096, "one thread");
    ck_assert_msg(wf_profile_psf_init(&ref, &img, &acc, &rar, 1) == WF_OK, "%s", wf_error_message());
    ck_assert(rar.capacity == keep + scratch + 4096); /* the split given back */
    for (int t = 2; t <= 4; t++) {
        size_t cap = keep + (size_t)t * (scratch + 64) + 4096;
        void *mem = malloc(cap);
        wf_arena ar;
        wf_arena_init(&ar, mem, cap, "threads");
        wf_profile_psf p;
        ck_assert_msg(wf_profile_psf_init(&p, &img, &acc, &ar, t) == WF_OK, "%s", wf_error_message());
        ck_assert_msg(ar.capacity == cap, "the scratch split off the top was not given back");
        assert_same_psf(&ref, &p, t);
        free(mem);
    }
    /* four asked for, one thread's memory given */
    void *mem = malloc(keep + scratch + 4096);
    wf_arena ar;
    wf_arena_init(&ar, mem, keep + scratch + 4096, "one thread's room");
    wf_profile_psf p;
    ck_assert_msg(wf_profile_psf_init(&p, &img, &acc, &ar, 4) == WF_OK, "%s", wf_error_message());
    assert_same_psf(&ref, &p, 4);
    free(mem);
    free(rmem);
    free(psfpix);
}
END_TEST

/* A core's table is the transform of the image times its taper T(r) (sim/draw/profile.h: 1 within
 * 2/3 of the radius, a raised cosine to 0 at it), which the tables read only within the
 * core's square: the core's flux and its table at low |k| (the pixel's sinc included, below
 * the band's taper) against sums over every sample of the image; the whole image's table
 * first, to pin the convention T(k) = sum w e^{-i k (x - c)}. */
START_TEST(test_core_tables_from_the_whole_image)
{
    wf_psf_image img;
    wf_profile_accuracy acc;
    size_t keep, scratch;
    double *pix = halo_split(&img, &acc, &keep, &scratch);
    void *mem = malloc(keep + scratch + 4096);
    wf_arena ar;
    wf_arena_init(&ar, mem, keep + scratch + 4096, "PSF");
    wf_profile_psf psf;
    ck_assert_msg(wf_profile_psf_init(&psf, &img, &acc, &ar, 1) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(psf.ncore, 3);
    static const int ks[][2] = {{0, 0}, {1, 0}, {0, 2}, {3, -1}, {-2, 5}};
    enum { NK = sizeof ks / sizeof *ks };
    const double c = 0.5 * (img.n - 1), h = img.scale_arcsec, p = acc.pixel_scale;
    const double dkt = 2.0 * M_PI / (acc.psf_table_fft * p);
    const size_t side = 2 * (size_t)psf.kr + 1;
    double total = 0;
    for (int i = 0; i < img.n * img.n; i++) total += pix[i];
    for (int l = -1; l < psf.ncore; l++) {
        const double R = l < 0 ? INFINITY : ldexp(acc.core_radius, -l), r1 = 2.0 * R / 3.0;
        double flux = 0, tr[NK] = {0}, ti[NK] = {0};
        for (int j = 0; j < img.n; j++)
            for (int i = 0; i < img.n; i++) {
                double r = hypot(i - c, j - c) * h;
                double t = r <= r1 ? 1.0 : r >= R ? 0.0 : 0.5 * (1.0 + cos(M_PI * (r - r1) / (R - r1)));
                double w = pix[(size_t)j * img.n + i] * t;
                flux += w;
                for (int q = 0; q < NK; q++) {
                    double ph = -(ks[q][0] * (i - c) + ks[q][1] * (j - c)) * h * dkt;
                    tr[q] += w * cos(ph);
                    ti[q] += w * sin(ph);
                }
            }
        const float *re = l < 0 ? psf.re : psf.core[l].re, *im = l < 0 ? psf.im : psf.core[l].im;
        if (l >= 0)
            ck_assert_msg(fabs(psf.core[l].flux - flux / total) < 1e-12, "core %d: flux %.15g, the image's %.15g",
                          l, psf.core[l].flux, flux / total);
        for (int q = 0; q < NK; q++) {
            int u = ks[q][0], v = ks[q][1];
            double sx = u ? sin(0.5 * u * dkt * p) / (0.5 * u * dkt * p) : 1.0;
            double sy = v ? sin(0.5 * v * dkt * p) / (0.5 * v * dkt * p) : 1.0;
            size_t at = (size_t)(v + psf.kr) * side + (size_t)(u + psf.kr);
            double er = re[at] - tr[q] * sx * sy, ei = im[at] - ti[q] * sx * sy;
            ck_assert_msg(hypot(er, ei) < 1e-6 * flux,
                          "%s %d: table at (%d, %d) is %.9g%+.9gi, the image's %.9g%+.9gi",
                          l < 0 ? "whole image" : "core", l, u, v, re[at], im[at], tr[q] * sx * sy,
                          ti[q] * sx * sy);
        }
    }
    free(mem);
    free(pix);
}
END_TEST

/* A work and a PSF split as the scene splits it (cores of 2", 1", 0.5") over a PSF with a
 * halo; returns the PSF image's pixels, for the caller to free. */
static double *open_split(ctx *c, wf_psf_image *img, wf_profile_accuracy *acc)
{
    double *pix = halo_split(img, acc, NULL, NULL);
    ctx_open(c, acc, img);
    return pix;
}

/* open_split with the work's wing tolerance at 1 (the split PSF's wing drawn) */
static double *open_split_wing(ctx *c, wf_psf_image *img, wf_profile_accuracy *acc)
{
    double *pix = open_split(c, img, acc);
    ck_assert(wf_profile_work_tune(&c->work, acc->flux_fraction, acc->folding_threshold,
                                   acc->kvalue_accuracy, 1.0, acc->knot_accuracy) == WF_OK);
    return pix;
}

/* The tables' copies at the draws' steps hold the table's own samples, and a draw that reads
 * them gives the bits of one that gathers from the table itself. */
/* expect: the steps of the 192 table (period 0: 192 / M for M = 96 .. 16 of the ladder), or of
 * the tables at periods 160 (80, 40, 20), 128 (none: its divisors divide 192) and 112 (56,
 * 28) */
static void assert_steps(const float *re, const float *im, int kr, const wf_profile_steps *s, int period,
                         const char *what)
{
    static const int e192[] = {2, 3, 4, 6, 8, 12}, e160[] = {2, 4, 8}, e112[] = {2, 4};
    const int *expect = period == 160 ? e160 : period == 112 ? e112 : e192;
    const int ne = period == 160 ? 3 : period == 128 ? 0 : period == 112 ? 2 : 6;
    ck_assert_msg(s->n == ne, "%s: %d steps", what, s->n);
    const size_t side = 2 * (size_t)kr + 1;
    for (int i = 0; i < s->n; i++) {
        ck_assert_msg(s->st[i] == expect[i] && s->kr[i] == kr / expect[i], "%s: step %d is %d", what, i, s->st[i]);
        const int kd = s->kr[i], st = s->st[i];
        for (int v = -kd; v <= kd; v++)
            for (int u = -kd; u <= kd; u++) {
                size_t a = (size_t)(v + kd) * (2 * (size_t)kd + 1) + (size_t)(u + kd);
                size_t b = (size_t)(v * st + kr) * side + (size_t)(u * st + kr);
                ck_assert_msg(s->re[i][a] == re[b] && s->im[i][a] == im[b], "%s: step %d at (%d, %d)", what, st, u, v);
            }
    }
}

START_TEST(test_psf_table_steps)
{
    wf_psf_image img;
    wf_profile_accuracy acc;
    ctx c;
    double *psfpix = open_split(&c, &img, &acc);
    const wf_profile_psf *p = &c.psf;
    assert_steps(p->re, p->im, p->kr, &p->steps, 192, "whole");
    for (int l = 0; l < p->ncore; l++) assert_steps(p->core[l].re, p->core[l].im, p->kr, &p->core[l].steps, 192, "core");
    ck_assert_int_eq(p->nalt, 3);
    for (int i = 0; i < p->nalt; i++) { /* the tables at other periods: theirs */
        const int per = p->alt[i].fft;
        assert_steps(p->alt[i].re, p->alt[i].im, p->alt[i].kr, &p->alt[i].steps, per, "whole, other period");
        for (int l = 0; l < p->ncore; l++)
            assert_steps(p->core[l].alt[i].re, p->core[l].alt[i].im, p->core[l].alt[i].kr, &p->core[l].alt[i].steps,
                         per, "core, other period");
    }
    wf_profile_psf gather = *p;
    gather.steps.n = 0;
    for (int l = 0; l < p->ncore; l++) gather.core[l].steps.n = 0;
    for (int i = 0; i < p->nalt; i++) {
        gather.alt[i].steps.n = 0;
        for (int l = 0; l < p->ncore; l++) gather.core[l].alt[i].steps.n = 0;
    }
    /* sizes from a star to a large disk, whole and split (a tolerance that takes the cores) */
    static const double hlr[] = {0.05, 0.2, 0.6, 1.5};
    int stepped = 0;
    for (int split = 0; split < 2; split++) {
        ck_assert(wf_profile_work_tune(&c.work, acc.flux_fraction, acc.folding_threshold, acc.kvalue_accuracy,
                                       split ? 1.0 : 0.0, acc.knot_accuracy) == WF_OK);
        for (int k = 0; k < 4; k++) {
            wf_galaxy g = galaxy(100.0, 0.3, hlr[k], 0.5 * hlr[k], 0.2, -0.1);
            g.n_knots = 40;
            g.knot_frac = 0.2;
            g.knot_seed = 11;
            wf_stamp a = stamp_new(0, 0, 40, 40), b = stamp_new(0, 0, 40, 40);
            ck_assert_msg(wf_profile_draw_galaxy(&c.work, &g, p, 19.3, 20.6, &a) == WF_OK, "%s", wf_error_message());
            ck_assert_msg(wf_profile_draw_galaxy(&c.work, &g, &gather, 19.3, 20.6, &b) == WF_OK, "%s", wf_error_message());
            ck_assert(a.fft == b.fft);
            const int t = wf_profile_psf_period(p, a.fft);
            stepped += t >= 0 && a.fft < (t ? p->alt[t - 1].fft : p->table_fft);
            ck_assert_msg(!memcmp(a.pix, b.pix, sizeof(double) * 40 * 40), "hlr %g split %d (FFT %d): the copy's "
                          "draw differs from the table's", hlr[k], split, a.fft);
            free(a.pix);
            free(b.pix);
        }
    }
    ck_assert_msg(stepped >= 4, "only %d draws read a step copy", stepped);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

START_TEST(test_core_levels)
{
    wf_psf_image img;
    double *psfpix = halo_psf(256, 0.07, 0.8, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx whole, one, three;
    ctx_open(&whole, &acc, &img);
    acc.core_radius = 2.0; /* the scene's default ladder: 2", 1", 0.5" */
    ctx_open(&one, &acc, &img);
    acc.core_levels = 3;
    ctx_open(&three, &acc, &img);
    const wf_profile_psf *p1 = &one.psf, *p3 = &three.psf;
    ck_assert(p1->ncore == 1 && p3->ncore == 3);
    size_t tab = (size_t)(2 * p3->kr + 1) * (size_t)(2 * p3->kr + 1);
    size_t wing = (size_t)p3->wing_os * p3->wing_os * (size_t)p3->wing_np * p3->wing_np;
    ck_assert(p1->kr == p3->kr && p1->wing_np == p3->wing_np);
    ck_assert(!memcmp(p1->core[0].re, p3->core[0].re, tab * sizeof(float)) &&
              !memcmp(p1->core[0].im, p3->core[0].im, tab * sizeof(float)) &&
              !memcmp(p1->core[0].wing, p3->core[0].wing, wing * sizeof(float)));
    for (int l = 0; l < 3; l++) {
        const wf_profile_core *co = &p3->core[l];
        ck_assert(co->radius == ldexp(2.0, -l));
        double wsum = 0.0;
        for (int k = 0; k < p3->wing_np * p3->wing_np; k++) wsum += co->wing[k];
        printf("core levels: radius %.2f\": core %.6f of the flux, wing %.6f, max wing pixel %.3g\n",
               co->radius, co->flux, wsum, co->wing_max);
        ck_assert_msg(fabs(wsum - (1.0 - co->flux)) < 1e-6, "level %d: wing %.8f, core %.8f", l, wsum,
                      co->flux);
        if (l) ck_assert(co->flux < p3->core[l - 1].flux && co->wing_max > p3->core[l - 1].wing_max);
    }
    { /* a ladder reaching under two pixels is refused, with a message */
        wf_profile_accuracy bad = acc;
        bad.core_radius = 0.8;
        size_t keep, scratch;
        ck_assert(wf_profile_psf_need(&img, &bad, &keep, &scratch) == WF_OK);
        void *mem = malloc(keep + scratch + 4096);
        wf_arena ar;
        wf_arena_init(&ar, mem, keep + scratch + 4096, "bad ladder");
        wf_profile_psf bp;
        ck_assert(wf_profile_psf_init(&bp, &img, &bad, &ar, 1) == WF_ERR_RANGE);
        ck_assert(strstr(wf_error_message(), "core_levels") != NULL);
        bad.core_levels = 2; /* 0.8", 0.4": allowed */
        ck_assert(wf_profile_psf_init(&bp, &img, &bad, &ar, 1) == WF_OK && bp.ncore == 2);
        free(mem);
    }
    wf_stamp junk = stamp_new(0, 0, 3, 3);
    ck_assert(wf_profile_add_wing(p3, 0, 1.0, 1.0, 1.0, &junk) != WF_OK);
    ck_assert(wf_profile_add_wing(p3, 4, 1.0, 1.0, 1.0, &junk) != WF_OK);
    ck_assert(wf_profile_add_wing(p1, 2, 1.0, 1.0, 1.0, &junk) != WF_OK);
    free(junk.pix);

    wf_galaxy g = galaxy(1000.0, 0.3, 0.15, 0.1, 0.2, -0.1);
    g.n_knots = 30;
    g.knot_frac = 0.2;
    g.knot_seed = 9;
    const double x = 120.4, y = 88.7;
    wf_stamp b;
    ck_assert(wf_profile_galaxy_bounds(&whole.work, &g, &whole.psf, x, y, &b, NULL) == WF_OK);
    wf_stamp ref = stamp_new(b.x0, b.y0, b.nx, b.ny);
    ck_assert(wf_profile_work_tune(&whole.work, acc.flux_fraction, 1e-7, 1e-7, 0.0, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
    ck_assert(wf_profile_draw_galaxy(&whole.work, &g, &whole.psf, x, y, &ref) == WF_OK);
    int last_fft = 1 << 30, first_fft = 0;
    for (int want = 1; want <= 3; want++) {
        /* a tolerance just above the bound of core `want`, below that of the next */
        double tol = 2.0 * g.flux * p3->core[want - 1].wing_max * 1.01;
        if (want < 3) ck_assert(tol < 2.0 * g.flux * p3->core[want].wing_max);
        ck_assert(wf_profile_work_tune(&three.work, acc.flux_fraction, 1e-7, 1e-7, tol, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
        wf_stamp bb, box;
        int taken = 0;
        ck_assert(wf_profile_galaxy_core(&three.work, &g, p3, x, y, &bb, &box, &taken) == WF_OK);
        ck_assert_int_eq(taken, want);
        wf_stamp c = stamp_new(b.x0, b.y0, b.nx, b.ny);
        /* the box at the default folding (at 1e-7 the galaxy's own light sets it) */
        ck_assert(wf_profile_work_tune(&three.work, acc.flux_fraction, acc.folding_threshold, acc.kvalue_accuracy, tol,
                                       WF_PROFILE_KNOT_ACCURACY) == WF_OK);
        ck_assert(wf_profile_draw_galaxy(&three.work, &g, p3, x, y, &c) == WF_OK);
        ck_assert_msg(c.fft <= last_fft, "core %d: box %d, larger than %d", want, c.fft, last_fft);
        last_fft = c.fft;
        if (want == 1) first_fft = c.fft;
        ck_assert(wf_profile_work_tune(&three.work, acc.flux_fraction, 1e-7, 1e-7, tol, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
        ck_assert(wf_profile_draw_galaxy(&three.work, &g, p3, x, y, &c) == WF_OK);
        double worst = 0.0;
        for (int k = 0; k < b.nx * b.ny; k++) worst = fmax(worst, fabs(c.pix[k] - ref.pix[k]));
        double bound = 2.0 * g.flux * p3->core[want - 1].wing_max;
        printf("core levels: core %d: FFT %d, worst pixel %.3f of the bound\n", want, last_fft, worst / bound);
        ck_assert_msg(worst <= bound, "core %d: %g beyond the bound %g", want, worst, bound);
        /* the core box plus that core's wing */
        core_plus_wing(&three.work, p3, &g, x, y, &b, &box, taken, &c);
        free(c.pix);
    }
    ck_assert_msg(last_fft < first_fft, "the smallest core's box %d is not smaller than the largest's %d",
                  last_fft, first_fft);
    free(ref.pix);
    ctx_close(&whole);
    ctx_close(&one);
    ctx_close(&three);
    free(psfpix);
}
END_TEST

/* ------------------------------------------------------------------ knots in Fourier space */

/* Draws g at (x, y) with the knots summed by `method` into a new stamp of the given bounds. */
static wf_stamp draw_knots(ctx *c, const wf_galaxy *g, double x, double y, const wf_stamp *b,
                           int method)
{
    wf_profile_knot_method(&c->work, method);
    wf_stamp s = stamp_new(b->x0, b->y0, b->nx, b->ny);
    ck_assert_msg(wf_profile_draw_galaxy(&c->work, g, &c->psf, x, y, &s) == WF_OK, "%s",
                  wf_error_message());
    return s;
}

/* The knot lattice (sim/draw/profile_lattice.c) against the direct sum over knots, which
 * it replaces where it is cheaper: the same stamps to its aliasing error, asserted 1e-7 of
 * the peak (reached 2e-9) and 1e-8 of the flux (reached 2e-10); with the planner's choice (some far knots
 * summed directly, the rest on the lattice) and with every knot forced onto the lattice.
 * Cases: the GalSim scene's 100 knots on small, median, large (an interpolated PSF table)
 * and sheared galaxies, all the disk's allowed 25% in knots, a hand-placed far knot, and
 * 1000 knots in a work whose buffers take them in several blocks. */
START_TEST(test_knot_lattice)
{
    wf_psf_image img;
    double *native = NULL;
    const char *which;
    double *psfpix = reference_or_gaussian(&img, &native, &which);
    wf_profile_accuracy acc, small;
    wf_profile_accuracy_default(&acc);
    small = acc;
    small.max_fft = 384;
    ctx c, cs;
    ctx_open(&c, &acc, &img);
    ctx_open(&cs, &small, &img);
    double far_xy[2 * 100];
    struct {
        const char *what;
        double hlr, bf, e1, e2, kf;
        int nk, far, blocks;
        double x, y;
    } cases[] = {
        {"median, 100 knots", 0.32, 0.1, 0.1, -0.05, 0.2, 100, 0, 0, 100.3, 200.6},
        {"small, 100 knots", 0.12, 0.3, 0.0, 0.0, 0.25, 100, 0, 0, 10.5, 10.5},
        {"large, 100 knots", 1.2, 0.3, 0.2, 0.1, 0.15, 100, 0, 0, 500.71, 400.02},
        {"sheared e 0.6, 100 knots", 0.4, 0.2, 0.3, -0.52, 0.2, 100, 0, 0, 33.9, 71.45},
        {"no bulge, 25% in 100 knots", 0.3, 0.0, 0.05, 0.0, 0.25, 100, 0, 0, 7.0, 8.0},
        {"30 knots", 0.5, 0.2, -0.1, 0.2, 0.2, 30, 0, 0, 1000.2, 3000.9},
        {"one knot 2.5\" out", 0.3, 0.1, 0.0, 0.1, 0.2, 100, 1, 0, 64.4, 64.6},
        {"1000 knots, max_fft 384", 0.3, 0.2, 0.1, 0.1, 0.25, 1000, 0, 1, 50.5, 60.25},
    };
    int n = (int)(sizeof cases / sizeof *cases), lattice_used = 0, forced_used = 0;
    double worst_all = 0.0;
    printf("knot lattice against the direct sum, PSF %s:\n", which);
    for (int k = 0; k < n; k++) {
        ctx *cc = cases[k].blocks ? &cs : &c;
        wf_galaxy g = galaxy(1000.0, cases[k].bf, cases[k].hlr, 0.5 * cases[k].hlr,
                             cases[k].e1, cases[k].e2);
        g.id = 100 + (uint32_t)k;
        g.knot_seed = 5;
        g.n_knots = cases[k].nk;
        g.knot_frac = cases[k].kf;
        if (cases[k].far) {
            ck_assert(wf_profile_knots(&g, far_xy) == WF_OK);
            far_xy[0] = 2.5;
            far_xy[1] = -0.4;
            g.knot_xy = far_xy;
        }
        wf_stamp b;
        ck_assert(wf_profile_galaxy_bounds(&cc->work, &g, &cc->psf, cases[k].x, cases[k].y, &b,
                                           NULL) == WF_OK);
        wf_stamp d = draw_knots(cc, &g, cases[k].x, cases[k].y, &b, WF_KNOTS_DIRECT);
        ck_assert(cc->work.knot_last[0] == 0 && cc->work.knot_last[2] == cases[k].nk);
        wf_stamp a = draw_knots(cc, &g, cases[k].x, cases[k].y, &b, WF_KNOTS_AUTO);
        int r = cc->work.knot_last[0], w = cc->work.knot_last[1], nd = cc->work.knot_last[2];
        lattice_used += r > 0;
        wf_stamp f = draw_knots(cc, &g, cases[k].x, cases[k].y, &b, WF_KNOTS_LATTICE);
        /* every knot on the lattice, unless its buffers cannot hold the lattice so fine */
        ck_assert_msg(cc->work.knot_last[0] > 0 ? cc->work.knot_last[2] == 0
                                                : cc->work.knot_last[2] == cases[k].nk,
                      "%s: %d knots left to the direct sum", cases[k].what,
                      cc->work.knot_last[2]);
        forced_used += cc->work.knot_last[0] > 0;
        double peak = 0.0, da = 0.0, df = 0.0;
        for (int i = 0; i < b.nx * b.ny; i++) {
            peak = fmax(peak, d.pix[i]);
            da = fmax(da, fabs(a.pix[i] - d.pix[i]));
            df = fmax(df, fabs(f.pix[i] - d.pix[i]));
        }
        double fa = fabs(a.sum - d.sum) / d.sum, ff = fabs(f.sum - d.sum) / d.sum;
        printf("  %-26s fft %4d: planned r %d w %2d, %2d direct: %.1e of the peak, flux %.1e; "
               "all on the lattice (r %d w %2d, 0: no room): %.1e, %.1e\n",
               cases[k].what, d.fft, r, w, nd, da / peak, fa, cc->work.knot_last[0],
               cc->work.knot_last[1], df / peak, ff);
        ck_assert_msg(a.fft == d.fft && f.fft == d.fft, "%s: FFT sides differ", cases[k].what);
        ck_assert_msg(da < 1e-7 * peak && df < 1e-7 * peak, "%s: %.3g, %.3g of the peak",
                      cases[k].what, da / peak, df / peak);
        ck_assert_msg(fa < 1e-8 && ff < 1e-8, "%s: flux %.3g, %.3g", cases[k].what, fa, ff);
        worst_all = fmax(worst_all, fmax(da, df) / peak);
        free(d.pix);
        free(a.pix);
        free(f.pix);
    }
    printf("  worst %.1e of the peak\n", worst_all);
    /* the planner must take the lattice for the scene's 100-knot galaxies */
    ck_assert_msg(lattice_used >= 6 && forced_used >= 6, "the lattice was taken for %d and %d "
                  "cases only", lattice_used, forced_used);
    wf_profile_knot_method(&c.work, WF_KNOTS_AUTO);
    ctx_close(&c);
    ctx_close(&cs);
    free(psfpix);
    free(native);
}
END_TEST

/* The per-sample kernels in scalar, 2-, 4- and 8-lane versions (as far as the CPU has them)
 * give the same bits: a stamp does not depend on the machine's vector width. */
/* acc.knot_accuracy (the lattice's aliasing e^-E, loosened for faint objects by a scene):
 * against the direct sum, no pixel moves by more than 10 knot_accuracy x the knots' flux, the
 * bound sim/draw/scene.c relies on (measured up to 0.13), and looser settings do use narrower
 * kernels or coarser lattices. */
START_TEST(test_knot_accuracy)
{
    wf_psf_image img;
    double *psfpix = halo_psf(256, 0.07, 0.8, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    const double hlr[] = {0.15, 0.4};
    for (int h = 0; h < 2; h++) {
        wf_galaxy g = galaxy(100.0, 0.3, hlr[h], 0.5 * hlr[h], 0.2, 0.1);
        g.n_knots = 100;
        g.knot_frac = 0.2;
        g.knot_seed = 9;
        const double fk = g.flux * (1 - g.bulge_frac) * g.knot_frac, x = 300.3, y = 200.6;
        wf_stamp b;
        ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, x, y, &b, NULL) == WF_OK);
        wf_stamp ref = draw_knots(&c, &g, x, y, &b, WF_KNOTS_DIRECT);
        int taps_default = 0, step_default = 0;
        const double es[] = {20.0, 10.0, 6.0, 4.7};
        for (int e = 0; e < 4; e++) {
            double ka = exp(-es[e]);
            ck_assert(wf_profile_work_tune(&c.work, acc.flux_fraction, acc.folding_threshold, acc.kvalue_accuracy, 0.0,
                                           ka) == WF_OK);
            wf_stamp t = draw_knots(&c, &g, x, y, &b, WF_KNOTS_LATTICE);
            double worst = 0.0;
            for (int k = 0; k < b.nx * b.ny; k++) worst = fmax(worst, fabs(t.pix[k] - ref.pix[k]));
            printf("knot accuracy e^-%.1f, hlr %.2f: lattice step %d, %d taps: worst pixel %.2e of the knots' flux "
                   "(%.3f of e^-E)\n",
                   es[e], hlr[h], c.work.knot_last[0], c.work.knot_last[1], worst / fk, worst / (fk * ka));
            ck_assert_msg(c.work.knot_last[0] > 0, "no lattice was used");
            ck_assert_msg(worst <= 10.0 * ka * fk, "e^-%g: %g of the knots' flux", es[e], worst / fk);
            if (e == 0) taps_default = c.work.knot_last[1], step_default = c.work.knot_last[0];
            if (e == 3)
                ck_assert_msg(c.work.knot_last[1] < taps_default || c.work.knot_last[0] > step_default,
                              "the loosest setting did not lighten the lattice");
            free(t.pix);
        }
        ck_assert(wf_profile_work_tune(&c.work, acc.flux_fraction, acc.folding_threshold, acc.kvalue_accuracy, 0.0,
                                       acc.knot_accuracy) == WF_OK);
        wf_profile_knot_method(&c.work, WF_KNOTS_AUTO);
        free(ref.pix);
    }
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* psf->pixel_max bounds every pixel of a unit point source wherever it sits, and is close to
 * the brightest one (Y106: 0.6% above; a Gaussian's transform is real and positive, so
 * there it is the centred pixel). Hence a galaxy's knots drawn as the smooth disk (what a
 * scene does when the knots' flux x pixel_max is below its noise tolerance) move no pixel by
 * more than the knots' flux x pixel_max: both images are non-negative and neither exceeds
 * it; and keep the flux. */
START_TEST(test_knots_smooth_bound)
{
    wf_psf_image img;
    double *native = NULL;
    const char *which;
    double *psfpix = reference_or_gaussian(&img, &native, &which);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    const double pmax = c.psf.pixel_max;
    double brightest = 0.0;
    for (int b = 0; b <= 16; b++)
        for (int a = 0; a <= 16; a++) {
            double x = 100.0 + (a - 8) / 16.0, y = 120.0 + (b - 8) / 16.0;
            wf_stamp bd;
            ck_assert(wf_profile_point_bounds(&c.work, &c.psf, x, y, &bd, NULL) == WF_OK);
            wf_stamp s = stamp_new(bd.x0, bd.y0, bd.nx, bd.ny);
            ck_assert_msg(wf_profile_draw_point(&c.work, &c.psf, 1.0, x, y, &s) == WF_OK, "%s", wf_error_message());
            for (int k = 0; k < s.nx * s.ny; k++) brightest = fmax(brightest, s.pix[k]);
            free(s.pix);
        }
    printf("knots smooth (%s): pixel_max %.5f, brightest pixel of a point source on a 1/16-pixel grid %.5f\n",
           which, pmax, brightest);
    ck_assert_msg(brightest <= pmax * (1.0 + 1e-9), "a pixel of %g above the bound %g", brightest, pmax);
    ck_assert_msg(brightest >= 0.98 * pmax, "the bound %g is loose against %g", pmax, brightest);
    const double hlr[] = {0.05, 0.15, 0.4};
    for (int h = 0; h < 3; h++) {
        wf_galaxy g = galaxy(1000.0, 0.2, hlr[h], 0.5 * hlr[h], 0.3, -0.1);
        g.n_knots = 100;
        g.knot_frac = WF_PROFILE_MAX_KNOT_FRAC;
        g.knot_seed = 11;
        const double fk = g.flux * (1 - g.bulge_frac) * g.knot_frac, x = 200.3, y = 150.8;
        wf_stamp b;
        ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, x, y, &b, NULL) == WF_OK);
        wf_stamp kn = stamp_new(b.x0, b.y0, b.nx, b.ny), sm = stamp_new(b.x0, b.y0, b.nx, b.ny);
        ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, x, y, &kn) == WF_OK);
        g.n_knots = 0;
        ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, x, y, &sm) == WF_OK);
        double worst = 0.0;
        for (int k = 0; k < b.nx * b.ny; k++) worst = fmax(worst, fabs(kn.pix[k] - sm.pix[k]));
        printf("knots smooth (%s), hlr %.2f\": worst pixel %.3f of knots x pixel_max, flux %.6f vs %.6f\n", which,
               hlr[h], worst / (fk * pmax), sm.sum, kn.sum);
        ck_assert_msg(worst <= fk * pmax, "hlr %g: %g of the bound", hlr[h], worst / (fk * pmax));
        ck_assert_msg(worst > 0.01 * fk * pmax, "hlr %g: the knots made no difference", hlr[h]);
        ck_assert_msg(fabs(sm.sum - kn.sum) <= 2e-3 * g.flux, "hlr %g: flux %g vs %g", hlr[h], sm.sum, kn.sum);
        free(kn.pix);
        free(sm.pix);
    }
    ctx_close(&c);
    free(psfpix);
    free(native);
}
END_TEST

START_TEST(test_simd_identical)
{
    wf_psf_image img;
    double *native = NULL;
    double *psfpix = reference_psf(&img, &native);
    if (!psfpix) psfpix = gaussian_psf(128, 0.07, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    int full = wf_profile_simd(-1);
    struct {
        double hlr, bf, kf;
        int nk, method;
    } cases[] = {{0.32, 0.1, 0.2, 100, WF_KNOTS_AUTO},   {0.32, 0.1, 0.2, 100, WF_KNOTS_DIRECT},
                 {1.2, 0.3, 0.15, 100, WF_KNOTS_AUTO},   {0.2, 0.5, 0.0, 0, WF_KNOTS_AUTO},
                 {0.05, 0.0, 0.25, 10, WF_KNOTS_AUTO},   {0.0, 0.0, 0.0, -1, WF_KNOTS_AUTO}};
    int n = (int)(sizeof cases / sizeof *cases);
    wf_stamp ref[6];
    static const int widths[] = {0, 2, 4, 8};
    int tried = 0;
    for (int iw = 0; iw < 4; iw++) {
        int used = wf_profile_simd(widths[iw]);
        if (used != widths[iw]) continue; /* not on this CPU */
        tried++;
        for (int k = 0; k < n; k++) {
            wf_stamp s;
            double x = 200.37 + k, y = 100.71;
            wf_galaxy g = galaxy(500.0, cases[k].bf, cases[k].hlr, 0.5 * cases[k].hlr, 0.2, -0.1);
            g.n_knots = cases[k].nk > 0 ? cases[k].nk : 0;
            g.knot_frac = cases[k].kf;
            g.knot_seed = 9;
            if (cases[k].nk < 0)
                ck_assert(wf_profile_point_bounds(&c.work, &c.psf, x, y, &s, NULL) == WF_OK);
            else
                ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, x, y, &s, NULL) == WF_OK);
            s = stamp_new(s.x0, s.y0, s.nx, s.ny);
            wf_profile_knot_method(&c.work, cases[k].method);
            if (cases[k].nk < 0)
                ck_assert(wf_profile_draw_point(&c.work, &c.psf, 500.0, x, y, &s) == WF_OK);
            else
                ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, x, y, &s) == WF_OK);
            if (tried == 1) {
                ref[k] = s;
                continue;
            }
            ck_assert_msg(memcmp(s.pix, ref[k].pix, sizeof(double) * s.nx * s.ny) == 0,
                          "case %d: %d-lane kernels differ from scalar", k, widths[iw]);
            free(s.pix);
        }
    }
    printf("drawing kernels: scalar and %d vector widths up to %d lanes give the same bits\n",
           tried - 1, full);
    for (int k = 0; k < n; k++) free(ref[k].pix);
    wf_profile_simd(8);
    ctx_close(&c);
    free(psfpix);
    free(native);
}
END_TEST

/* The core at offsets (x0 + i - x, y0 + j - y) pixels from a point x, y, i, j < n, from its
 * table by the direct sum (1 / N^2) sum_k T(k) e^{i k X} (the knot table's own definition,
 * without the FFT), the phases by axis. */
static void core_direct(const wf_profile_psf *psf, const wf_profile_core *co, int x0, int y0, int n, double x,
                        double y, double *out)
{
    const int kr = psf->kr, nt = psf->table_fft;
    const size_t side = 2 * (size_t)kr + 1;
    double *cx = malloc(sizeof(double) * side * n * 4), *sx = cx + side * n, *cy = sx + side * n, *sy = cy + side * n;
    ck_assert(cx != NULL);
    for (int i = 0; i < n; i++)
        for (int u = -kr; u <= kr; u++) {
            double px = 2.0 * M_PI * u * (x0 + i - x) / nt, py = 2.0 * M_PI * u * (y0 + i - y) / nt;
            cx[(size_t)i * side + (size_t)(u + kr)] = cos(px), sx[(size_t)i * side + (size_t)(u + kr)] = sin(px);
            cy[(size_t)i * side + (size_t)(u + kr)] = cos(py), sy[(size_t)i * side + (size_t)(u + kr)] = sin(py);
        }
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            double sum = 0.0;
            for (int v = -kr; v <= kr; v++) {
                const float *re = co->re + (size_t)(v + kr) * side, *im = co->im + (size_t)(v + kr) * side;
                const double cv = cy[(size_t)j * side + (size_t)(v + kr)], sv = sy[(size_t)j * side + (size_t)(v + kr)];
                const double *cu = cx + (size_t)i * side, *su = sx + (size_t)i * side;
                double ar = 0.0, ai = 0.0; /* sum_u T e^{i u X} */
                for (size_t u = 0; u < side; u++) {
                    ar += re[u] * cu[u] - im[u] * su[u];
                    ai += re[u] * su[u] + im[u] * cu[u];
                }
                sum += ar * cv - ai * sv;
            }
            out[(size_t)j * n + i] = sum / ((double)nt * nt);
        }
    free(cx);
}

/* Knots read from a core's real-space table (wf_profile_knots_stamp) against the core by the
 * direct sum over its table at every pixel: no pixel is off by more than knot_interp +
 * knot_out[lim] (the bilinear reading's bound from the table and the samples left out), at
 * every core, several reach and sub-pixel positions; and a knot's pixels hold its flux times
 * the core's (the pixel's transform vanishes at every other multiple of 2 pi: whole-pixel
 * shifts of the core sum to its flux). */
START_TEST(test_knot_table_bound)
{
    wf_psf_image img;
    wf_profile_accuracy acc;
    ctx c;
    double *psfpix = open_split(&c, &img, &acc);
    (void)wf_profile_simd(-1);
    const wf_profile_psf *psf = &c.psf;
    /* on a sample, half-way between samples, and within the first 1/16 of a sample, where the
     * fine index wraps to the next pixel's plane */
    static const double pos[][2] = {{0.0, 0.0}, {0.37, -0.21}, {-0.49, 0.5}, {0.0625, 0.8125},
                                    {0.03125, -0.4688}, {-0.9997, 0.0009}};
    enum { NPOS = 6 };
    const size_t side = 2 * (size_t)psf->kr + 1;
    for (int k = 0; k < psf->ncore; k++) {
        const wf_profile_core *co = &psf->core[k];
        const int h = co->knot_half, n = 2 * h + 7;
        const double cflux = co->re[(size_t)psf->kr * side + (size_t)psf->kr];
        ck_assert(co->knot != NULL && co->knot_out != NULL && co->knot_miss != NULL && co->knot_interp > 0.0);
        ck_assert_msg(co->knot_out[h] < 1e-4 * psf->pixel_max, "core %d leaves out %g", k + 1, co->knot_out[h]);
        const int lims[] = {2, h / 2, h};
        double worst_any[3] = {0.0, 0.0, 0.0}; /* of the bound */
        for (int ip = 0; ip < NPOS; ip++) {
            /* exact on the central 13 x 13 pixels and the whole row and column through the
             * knot (out to where the shorter reaches leave light out) */
            const double x = 40.0 + pos[ip][0], y = 50.0 + pos[ip][1], xy[2] = {0.0, 0.0};
            const int x0 = 40 - h - 3, y0 = 50 - h - 3;
            enum { NE = 13 };
            double exact[NE * NE], peak = 0.0;
            double *row = malloc(sizeof(double) * n), *col = malloc(sizeof(double) * n);
            ck_assert(row && col);
            core_direct(psf, co, 34, 44, NE, x, y, exact);
            for (int i = 0; i < n; i++) {
                double v;
                core_direct(psf, co, x0 + i, 50, 1, x, y, &v), row[i] = v;
                core_direct(psf, co, 40, y0 + i, 1, x, y, &v), col[i] = v;
            }
            for (int e = 0; e < NE * NE; e++) peak = fmax(peak, exact[e]);
            for (int li = 0; li < 3; li++) {
                wf_stamp s = stamp_new(x0, y0, n, n);
                wf_profile_knots_stamp(psf, k + 1, lims[li], 1.0, 1, xy, x, y, &s);
                double worst = 0.0, sum = 0.0;
                for (int j = 0; j < s.ny; j++)
                    for (int i = 0; i < s.nx; i++) {
                        double got = s.pix[(size_t)j * s.nx + i];
                        int ie = s.x0 + i - 34, je = s.y0 + j - 44;
                        if (ie >= 0 && ie < NE && je >= 0 && je < NE) worst = fmax(worst, fabs(got - exact[je * NE + ie]));
                        if (s.y0 + j == 50) worst = fmax(worst, fabs(got - row[i]));
                        if (s.x0 + i == 40) worst = fmax(worst, fabs(got - col[j]));
                        sum += got;
                    }
                const double bound = co->knot_interp + co->knot_out[lims[li]], miss = 1.0 - sum / cflux;
                printf("knot table, core %d (%g\"), reach %d, at (%+.4f, %+.4f): worst %.3g of the peak (%.3g of the bound), "
                       "light left out %.3g (bound %.3g)\n", k + 1, co->radius, lims[li], pos[ip][0], pos[ip][1], worst / peak,
                       worst / bound, miss, co->knot_miss[lims[li]]);
                ck_assert_msg(worst <= bound, "core %d reach %d at (%g, %g): off by %g, bound %g", k + 1, lims[li], x, y,
                              worst, bound);
                ck_assert_msg(miss <= co->knot_miss[lims[li]] + 1e-6, "core %d reach %d at (%g, %g): %g of the light left "
                              "out, bound %g", k + 1, lims[li], x, y, miss, co->knot_miss[lims[li]]);
                worst_any[li] = fmax(worst_any[li], worst / bound);
                if (lims[li] == h)
                    ck_assert_msg(fabs(sum - co->flux) < 1e-5 * co->flux, "knot sums to %.8f of %.8f", sum, co->flux);
                free(s.pix);
            }
            free(row);
            free(col);
        }
        /* the interpolation term is reached within a factor of a few half-way between samples */
        ck_assert_msg(worst_any[2] > 0.2, "core %d: off by %g of the bound at most: a bound that cannot fail", k + 1,
                      worst_any[2]);
    }
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* A split galaxy's knots read from the core's table (AUTO, where the bound is tolerated)
 * against the same knots summed in its Fourier box (DIRECT): the smooth part is the same
 * draw, so the stamps differ by the knots alone, by no more than the tolerance (the reading
 * goes out only as far as it allows), plus the Fourier draw's own folding and dropped modes
 * (1e-6 and 1e-9 of the flux here); the light differs by no more than the reading may leave
 * out, (1 - flux_fraction) / 10 of the knots'. With a tolerance under every core's bound for
 * the whole table, the knots stay in the box. */
START_TEST(test_real_knots_galaxy)
{
    wf_psf_image img;
    wf_profile_accuracy acc;
    ctx c;
    double *psfpix = open_split(&c, &img, &acc);
    const wf_profile_psf *psf = &c.psf;
    double least = INFINITY; /* the smallest whole-table bound of any core */
    for (int k = 0; k < psf->ncore; k++)
        least = fmin(least, psf->core[k].knot_interp + psf->core[k].knot_out[psf->core[k].knot_half]);
    const double wing = psf->core[psf->ncore - 1].wing_max;
    for (int h = 0; h < 3; h++)
        for (int pass = 0; pass < 3; pass++) {
            wf_galaxy g = galaxy(200.0, 0.2, 0.1 + 0.05 * h, 0.05, 0.3 - 0.2 * h, 0.1);
            g.n_knots = 40 + 30 * h;
            g.knot_frac = 0.25;
            g.knot_seed = 11 + h;
            const double x = 300.3 + 0.21 * h, y = 200.7 - 0.17 * h;
            const double fk = g.flux * (1.0 - g.bulge_frac) * g.knot_frac;
            /* pass 0: the smallest core just tolerated; 1: a flux fraction of 0.5, so that the
             * light left out allows a reach of 3 (knot_miss[3] ~ 0.02 < 0.05), and the bound at
             * a reach of 3 as the tolerance, so that it sets the reach; 2: under every knot
             * table's bound */
            const wf_profile_core *cs = &psf->core[psf->ncore - 1];
            const double tol = pass == 2 ? 0.5 * fk * least
                               : pass   ? fk * (cs->knot_interp + cs->knot_out[3]) * (1.0 + 1e-12)
                                        : 2.5 * g.flux * wing;
            const double ff = pass == 1 ? 0.5 : acc.flux_fraction;
            ck_assert(wf_profile_work_tune(&c.work, ff, 1e-6, 1e-9, tol, acc.knot_accuracy) == WF_OK);
            wf_stamp b, box;
            int core;
            ck_assert(wf_profile_galaxy_core(&c.work, &g, psf, x, y, &b, &box, &core) == WF_OK);
            ck_assert_msg(pass == 2 || core == psf->ncore, "galaxy %d tolerance %g: core %d taken", h, tol, core);
            wf_stamp a = stamp_new(b.x0, b.y0, b.nx, b.ny), d = stamp_new(b.x0, b.y0, b.nx, b.ny);
            wf_profile_knot_method(&c.work, WF_KNOTS_AUTO);
            ck_assert(wf_profile_draw_galaxy(&c.work, &g, psf, x, y, &a) == WF_OK);
            const int nreal = c.work.knot_last[3], lat = c.work.knot_last[0], direct = c.work.knot_last[2];
            const int reach = c.work.knot_last[4];
            if (pass == 2) {
                ck_assert_msg(nreal == 0 && (lat > 0 || direct > 0), "galaxy %d: knots read from the table beyond their "
                              "tolerance", h);
                free(a.pix);
                free(d.pix);
                continue;
            }
            ck_assert_msg(nreal == g.n_knots, "%d of %d knots read from the table", nreal, g.n_knots);
            wf_profile_knot_method(&c.work, WF_KNOTS_DIRECT);
            ck_assert(wf_profile_draw_galaxy(&c.work, &g, psf, x, y, &d) == WF_OK);
            ck_assert(c.work.knot_last[3] == 0 && c.work.knot_last[2] > 0);
            double worst = 0.0, peak = 0.0, sa = 0.0, sd = 0.0;
            for (int k = 0; k < b.nx * b.ny; k++) {
                worst = fmax(worst, fabs(a.pix[k] - d.pix[k]));
                peak = fmax(peak, d.pix[k]);
                sa += a.pix[k], sd += d.pix[k];
            }
            const double fold = 2e-6 * g.flux, bound = tol + fold;
            printf("real-space knots, galaxy %d, tolerance %.3g, flux fraction %g (core %d, box %d, reach %d): worst pixel "
                   "%.3g of the peak, %.3g of the tolerance; sums %.6f and %.6f\n", h, tol, ff, core, d.fft, reach,
                   worst / peak, worst / tol, sa, sd);
            if (pass == 1) {
                ck_assert(cs->knot_miss[3] <= 0.1 * (1.0 - ff) && cs->knot_out[2] > cs->knot_out[3]);
                ck_assert_msg(reach == 3, "galaxy %d: reach %d where the tolerance allows 3", h, reach);
            }
            ck_assert_msg(worst <= bound, "galaxy %d: knots off by %g, allowed %g", h, worst, bound);
            ck_assert_msg(worst > 1e-6 * peak, "galaxy %d: knots off by only %g of the peak: not read from the table?", h,
                          worst / peak);
            ck_assert_msg(fabs(sa - sd) <= 0.1 * (1.0 - ff) * fk + fold, "galaxy %d: sums %.8f and %.8f", h, sa, sd);
            free(a.pix);
            free(d.pix);
        }
    wf_profile_knot_method(&c.work, WF_KNOTS_AUTO);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* The split PSF's wing, added row by row, is the same bits with every kernel width. */
START_TEST(test_simd_identical_wing)
{
    wf_psf_image img;
    wf_profile_accuracy acc;
    ctx c;
    double *psfpix = open_split_wing(&c, &img, &acc);
    static const int widths[] = {0, 2, 4, 8};
    static const double hlr[] = {0.1, 0.4};
    double *ref[2] = {NULL, NULL};
    int tried = 0;
    for (int iw = 0; iw < 4; iw++) {
        if (wf_profile_simd(widths[iw]) != widths[iw]) continue; /* not on this CPU */
        tried++;
        for (int k = 0; k < 2; k++) {
            wf_galaxy g = galaxy(50.0, 0.3, hlr[k], 0.5 * hlr[k], 0.2, -0.1);
            wf_stamp b, box;
            int core;
            double x = 100.37 + k, y = 90.71; /* odd row lengths: the vector loops' tails too */
            ck_assert(wf_profile_galaxy_core(&c.work, &g, &c.psf, x, y, &b, &box, &core) == WF_OK);
            ck_assert_msg(core > 0, "hlr %g takes no core", hlr[k]);
            wf_stamp s = stamp_new(b.x0, b.y0, b.nx | 1, b.ny);
            ck_assert(wf_profile_add_wing(&c.psf, core, g.flux, x, y, &s) == WF_OK);
            double sum = 0.0;
            for (int i = 0; i < s.nx * s.ny; i++) sum += s.pix[i];
            ck_assert_msg(sum > 0.0, "the wing added nothing");
            if (tried == 1) {
                ref[k] = s.pix;
                continue;
            }
            ck_assert_msg(!memcmp(s.pix, ref[k], sizeof(double) * s.nx * s.ny), "hlr %g: %d-lane wing differs from "
                          "scalar", hlr[k], widths[iw]);
            free(s.pix);
        }
    }
    ck_assert(tried >= 2);
    free(ref[0]);
    free(ref[1]);
    wf_profile_simd(8);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* A stamp's sum and clipped light, against sums written out (long double) over the same
 * pixels: kept (keep_negatives) the stamp is untouched and sums as it is; clipped, each pixel
 * is max(v, 0), clipped is the light of the negatives, and the clipped stamp sums to the kept
 * one's sum plus clipped. A tiny bulge rings, so negatives are there to clip; stamps of odd
 * sizes leave the eight lanes a tail. */
START_TEST(test_stamp_sum_and_clip)
{
    wf_psf_image img;
    wf_profile_accuracy acc;
    ctx c;
    double *psfpix = open_split(&c, &img, &acc);
    static const int side[] = {13, 29, 63};
    int negatives = 0, tail = 0; /* and of those in the lanes' tail */
    for (int k = 0; k < 3; k++) {
        wf_galaxy g = galaxy(100.0, 0.8, 0.02, 0.005, 0.3, 0.1);
        wf_stamp kept = stamp_new(0, 0, side[k], side[k] + 2), cut = stamp_new(0, 0, side[k], side[k] + 2);
        const double x = 2.27, y = 1.61; /* far from the last pixels, where it rings */
        wf_profile_keep_negatives(&c.work, 1);
        ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, x, y, &kept) == WF_OK);
        wf_profile_keep_negatives(&c.work, 0);
        ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, x, y, &cut) == WF_OK);
        long double all = 0.0L, neg = 0.0L, pos = 0.0L;
        const int n = kept.nx * kept.ny;
        for (int i = 0; i < n; i++) {
            double v = kept.pix[i];
            all += v;
            if (v < 0.0) neg -= v, negatives++, tail += i >= n - n % 8;
            ck_assert(cut.pix[i] == (v < 0.0 ? 0.0 : v));
            pos += cut.pix[i];
        }
        ck_assert(kept.clipped == 0.0);
        ck_assert_msg(fabsl(kept.sum - all) <= 1e-13L * g.flux, "kept sum %.17g vs %.17Lg", kept.sum, all);
        ck_assert_msg(fabsl(cut.clipped - neg) <= 1e-13L * g.flux, "clipped %.17g vs %.17Lg", cut.clipped, neg);
        ck_assert_msg(fabsl(cut.sum - pos) <= 1e-13L * g.flux, "clipped sum %.17g vs %.17Lg", cut.sum, pos);
        ck_assert(fabs(cut.sum - (kept.sum + cut.clipped)) <= 1e-12 * g.flux);
        free(kept.pix);
        free(cut.pix);
    }
    printf("stamp sums: %d negative pixels, %d in the tail of the lanes\n", negatives, tail);
    ck_assert_msg(negatives > 0 && tail > 0, "no negative pixels (%d, %d in the tail): the clip was not exercised", negatives, tail);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* acc.cut_tolerance T: the Fourier sum ends where the modes left out move no pixel by more
 * than T (tail_cut's bound), and the cut moves no flux within the FFT box (its k = 0 mode
 * stays; the work keeps negatives, as the scene's do). Against the same draw without the cut:
 * faint to bright (T from 1e-5 to 1e-2 of the flux), small to large galaxies, with knots
 * and without, the whole PSF and the split one. The cut must come in (the saving) for the
 * loose tolerances and never leave the box with its mean alone. */
START_TEST(test_cut_tolerance_bound)
{
    wf_psf_image img;
    wf_profile_accuracy acc;
    ctx c;
    double *psfpix = open_split(&c, &img, &acc);
    wf_profile_keep_negatives(&c.work, 1);
    static const double hd[] = {0.1, 0.3, 1.0};
    static const double tolf[] = {1e-5, 1e-4, 1e-3, 1e-2};
    int engaged = 0, cases = 0;
    double worst = 0.0; /* largest |pixel change| / T */
    for (int split = 0; split < 2; split++)
        for (int k = 0; k < 3; k++)
            for (int kn = 0; kn < 2; kn++) {
                wf_galaxy g = galaxy(40.0, 0.3, hd[k], 0.5 * hd[k], 0.2, -0.1);
                if (kn) {
                    g.n_knots = 20;
                    g.knot_frac = 0.2;
                    g.knot_seed = 11;
                }
                const double x = 100.37, y = 90.71;
                ck_assert(wf_profile_work_tune(&c.work, acc.flux_fraction, acc.folding_threshold,
                                               acc.kvalue_accuracy, split ? 1.0 : 0.0,
                                               acc.knot_accuracy) == WF_OK);
                ck_assert(wf_profile_work_tune_cut(&c.work, 0.0) == WF_OK);
                wf_stamp b;
                ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, x, y, &b, NULL) == WF_OK);
                wf_stamp probe = stamp_new(b.x0, b.y0, b.nx, b.ny);
                ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, x, y, &probe) == WF_OK);
                /* the whole FFT box (and for a split galaxy its wing around it) */
                int m = probe.fft;
                wf_stamp ref = stamp_new((int)lround(x) - m / 2, (int)lround(y) - m / 2, m, m);
                ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, x, y, &ref) == WF_OK);
                ck_assert_int_eq(ref.fft, m);
                const int u_ref = c.work.cut_last[0] > c.work.cut_last[1] ? c.work.cut_last[0] : c.work.cut_last[1];
                for (int t = 0; t < 4; t++) {
                    const double tol = tolf[t] * g.flux;
                    ck_assert(wf_profile_work_tune_cut(&c.work, tol) == WF_OK);
                    wf_stamp cut = stamp_new(ref.x0, ref.y0, m, m);
                    ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, x, y, &cut) == WF_OK);
                    ck_assert_int_eq(cut.fft, m);
                    const int u = c.work.cut_last[0] > c.work.cut_last[1] ? c.work.cut_last[0] : c.work.cut_last[1];
                    ck_assert_msg(u <= u_ref && c.work.cut_last[0] > 0, "extent %d against %d", u, u_ref);
                    engaged += u < u_ref;
                    double d = 0.0, sr = 0.0, sc = 0.0;
                    for (int i = 0; i < m * m; i++) {
                        d = fmax(d, fabs(cut.pix[i] - ref.pix[i]));
                        sr += ref.pix[i];
                        sc += cut.pix[i];
                    }
                    worst = fmax(worst, d / tol);
                    ck_assert_msg(d <= tol * (1.0 + 1e-9) + 1e-12 * g.flux,
                                  "split %d, hlr %g, knots %d, T %g: a pixel moved by %g", split,
                                  hd[k], g.n_knots, tol, d);
                    /* the k = 0 mode is never cut; the knot lattice, whose plan follows the
                     * extent, moves it by up to ~10 e^-E of the knots' flux in each draw */
                    const double fk = g.n_knots ? g.flux * (1.0 - g.bulge_frac) * g.knot_frac : 0.0;
                    ck_assert_msg(fabs(sc - sr) <= 1e-9 * g.flux + 20.0 * acc.knot_accuracy * fk,
                                  "split %d, hlr %g, knots %d, T %g: the box's flux moved by %g", split, hd[k],
                                  g.n_knots, tol, sc - sr);
                    cases++;
                    free(cut.pix);
                }
                ck_assert(wf_profile_work_tune_cut(&c.work, 0.0) == WF_OK);
                free(ref.pix);
                free(probe.pix);
            }
    printf("cut_tolerance: %d of %d draws cut further in, worst pixel change %.3g of T\n", engaged,
           cases, worst);
    ck_assert(engaged >= cases / 2);
    ck_assert_int_eq(wf_profile_work_tune_cut(&c.work, -1.0), WF_ERR_RANGE);
    ck_assert_int_eq(wf_profile_work_tune_cut(&c.work, NAN), WF_ERR_RANGE);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* The renderer's one-pass row of a split galaxy (wf_profile_wing_place, then
 * wf_profile_add_wing_row per row) against the sum it replaces: the box's pixels as float,
 * plus wf_profile_add_wing's wing, clipped at zero, added to what the row held. The same
 * bits at every vector width, with rows the box does not reach, columns beyond it on both
 * sides, and both sides of the clip; and what it refuses. */
START_TEST(test_wing_row_is_box_plus_wing)
{
    wf_psf_image img;
    wf_profile_accuracy acc;
    ctx c;
    double *psfpix = open_split_wing(&c, &img, &acc);
    static const int widths[] = {0, 2, 4, 8};
    int tried = 0, clipped = 0, kept = 0, below = 0;
    for (int iw = 0; iw < 4; iw++) {
        if (wf_profile_simd(widths[iw]) != widths[iw]) continue; /* not on this CPU */
        tried++;
        for (int k = 0; k < 3; k++) { /* the last: a box wider than the wing reaches */
            static const double hd[] = {0.1, 0.4, 3.0};
            wf_galaxy g = galaxy(50.0, 0.3, hd[k], 0.5 * hd[k], 0.2, -0.1);
            wf_stamp b, box;
            int core;
            double x = 100.37 + k, y = 90.71;
            ck_assert(wf_profile_galaxy_core(&c.work, &g, &c.psf, x, y, &b, &box, &core) == WF_OK);
            ck_assert(core > 0);
            wf_stamp bs = stamp_new(box.x0, box.y0, box.nx, box.ny);
            ck_assert(wf_profile_draw_galaxy_core(&c.work, &g, &c.psf, x, y, &bs) == WF_OK);
            float *bf = malloc(sizeof(float) * (size_t)box.nx * box.ny);
            ck_assert_ptr_nonnull(bf);
            for (int i = 0; i < box.nx * box.ny; i++) bf[i] = (float)bs.pix[i];
            /* a footprint one column wider than the stamp each side and rows beyond the box */
            int xa = b.x0 - 1, xb = b.x0 + b.nx + 1, w = xb - xa;
            ck_assert(box.x0 > xa && box.x0 + box.nx < xb);
            wf_stamp want = stamp_new(xa, b.y0 - 2, w, b.ny + 4);
            double *got = malloc(sizeof(double) * (size_t)w * want.ny);
            ck_assert_ptr_nonnull(got);
            wf_profile_wing_at at;
            ck_assert(wf_profile_wing_place(&c.psf, core, g.flux, x, y, &at) == WF_OK);
            if (k == 2) ck_assert_msg(box.nx > at.np && box.ny > at.np, "box %d x %d, wing %d", box.nx, box.ny, at.np);
            double *d = malloc(sizeof(double) * (size_t)w);
            ck_assert_ptr_nonnull(d);
            /* keep 0: box + wing clipped at zero, then added; keep 1 (keep_negatives): the box's
             * pixels added, then wf_profile_add_wing's wing, nothing clipped (the renderer
             * clips the sum of all objects) */
            for (int keep = 0; keep <= 1; keep++) {
                at.keep_negatives = keep;
                for (int i = 0; i < w * want.ny; i++) got[i] = want.pix[i] = 0.25 + 1e-3 * (i % 7);
                for (int j = 0; j < want.ny; j++) {
                    int row = want.y0 + j, by = row - box.y0;
                    const float *brow = by >= 0 && by < box.ny ? bf + (size_t)by * box.nx : NULL;
                    double *wr = want.pix + (size_t)j * w, *into = keep ? wr : d;
                    for (int i = 0; i < w; i++) {
                        int bx = xa + i - box.x0;
                        double bv = brow && bx >= 0 && bx < box.nx ? (double)brow[bx] : 0.0;
                        if (keep) into[i] += bv;
                        else into[i] = bv;
                    }
                    wf_stamp rs = {xa, row, w, 1, into, 0, 0, 0};
                    ck_assert(wf_profile_add_wing(&c.psf, core, g.flux, x, y, &rs) == WF_OK);
                    for (int i = 0; i < w; i++) {
                        if (keep) {
                            below += wr[i] < 0.25 + 1e-3 * ((j * w + i) % 7);
                            continue;
                        }
                        wr[i] += d[i] < 0.0 ? 0.0 : d[i];
                        clipped += d[i] < 0.0;
                        kept += d[i] > 0.0;
                    }
                    ck_assert(wf_profile_add_wing_row(&at, row, xa, xb, brow, box.x0, box.x0 + box.nx,
                                                      got + (size_t)j * w) == WF_OK);
                }
                ck_assert_msg(!memcmp(got, want.pix, sizeof(double) * (size_t)w * want.ny),
                              "hlr %g, %d lanes, keep_negatives %d: the row differs from box + wing",
                              g.hlr_disk, widths[iw], keep);
            }
            at.keep_negatives = 0;
            /* refused: box columns outside the row's, a core the PSF does not have */
            ck_assert_int_eq(wf_profile_add_wing_row(&at, b.y0, box.x0 + 1, xb, bf, box.x0,
                                                     box.x0 + box.nx, got), WF_ERR_INPUT);
            ck_assert_int_eq(wf_profile_wing_place(&c.psf, c.psf.ncore + 1, 1.0, x, y, &at),
                             WF_ERR_INPUT);
            free(d);
            free(got);
            free(want.pix);
            free(bf);
            free(bs.pix);
        }
    }
    ck_assert(tried >= 2);
    ck_assert(clipped > 10 && kept > 10); /* both sides of the clip */
    ck_assert(below > 10);                /* and the unclipped rows kept the negatives */
    wf_profile_simd(8);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* One galaxy drawn under two knob sets (works tuned to flux fraction ff, folding fold and
 * kvalue kv) on an n x n stamp at (x, y), both at FFT side `side`: the first's worst pixel
 * against the second's, of the peak, and (dflux) their flux difference. */
static double table_pair(const wf_profile_accuracy *a1, const wf_profile_accuracy *a2, const wf_psf_image *img,
                         const wf_galaxy *g, int n, double x, double y, double ff, double fold, double kv, int side,
                         double *dflux)
{
    ctx c1, c2;
    ctx_open(&c1, a1, img);
    ctx_open(&c2, a2, img);
    ck_assert(wf_profile_work_tune(&c1.work, ff, fold, kv, 0.0, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
    ck_assert(wf_profile_work_tune(&c2.work, ff, fold, kv, 0.0, WF_PROFILE_KNOT_ACCURACY) == WF_OK);
    wf_stamp s1 = stamp_new(0, 0, n, n), s2 = stamp_new(0, 0, n, n);
    ck_assert(wf_profile_draw_galaxy(&c1.work, g, &c1.psf, x, y, &s1) == WF_OK);
    ck_assert(wf_profile_draw_galaxy(&c2.work, g, &c2.psf, x, y, &s2) == WF_OK);
    ck_assert_msg(s1.fft == side && s2.fft == side, "sides %d %d, not %d", s1.fft, s2.fft, side);
    const double rel = worst_of_peak(&s1, &s2);
    if (dflux) *dflux = s1.sum - s2.sum;
    free(s1.pix);
    free(s2.pix);
    ctx_close(&c1);
    ctx_close(&c2);
    return rel;
}

/* FFT sides that do not divide psf_table_fft read the PSF table through bicubic
 * interpolation: its error, against the same draw with an exact table. */
START_TEST(test_psf_table_interpolation)
{
    wf_psf_image img;
    double *psfpix = gaussian_psf(128, 0.07, &img);
    wf_profile_accuracy a1, a2;
    wf_profile_accuracy_default(&a1);
    a2 = a1;
    a2.psf_table_fft = 256;
    wf_galaxy g = galaxy(1, 0.3, 1.6, 0.8, 0.3, 0.1);
    g.n_knots = 10;
    g.knot_frac = 0.2;
    /* the side from the 201-pixel stamp: 224, above 192 (the PSF with a 256 table reads it
     * exactly, from its extra table at period 224) */
    double dflux;
    double rel = table_pair(&a1, &a2, &img, &g, 201, 100.0, 100.0, 0.9, 0.05, 1e-5, 224, &dflux);
    printf("PSF table interpolation (side 224 from a 192 table): worst pixel %.2e of the "
           "peak, flux %+.1e\n", rel, dflux);
    ck_assert_msg(rel < 1e-3, "interpolated table: %.3g of the peak", rel);
    /* a largest side (128) below the table's that does not divide it and has no table of
     * its own (extra_tables 0): the table is read at 1.5 steps per sample, more columns per
     * row than samples; against a 384 table */
    a1.max_fft = a2.max_fft = 128;
    a1.extra_tables = 0;
    a2.psf_table_fft = 384;
    rel = table_pair(&a1, &a2, &img, &g, 127, 63.0, 63.0, a1.flux_fraction, a1.folding_threshold, a1.kvalue_accuracy,
                     128, NULL);
    printf("PSF table interpolation (side 128 from a 192 table): worst pixel %.2e of the "
           "peak\n", rel);
    ck_assert_msg(rel < 1e-3, "interpolated table: %.3g of the peak", rel);
    free(psfpix);
}
END_TEST

/* Tables at other periods (acc.extra_tables): FFT sides below psf_table_fft that do not
 * divide it (160, 128, 112 and 80 with the default 192) read a table of their own, exactly.
 * Each such table, the whole PSF's and every core's, against the main table where their
 * frequencies meet (period 128 step 2t is period 192 step 3t; 160's 5t is 192's 6t, 112's
 * 7t 192's 12t): the same transform sampled by another FFT of the image folded onto another
 * period, so equal to the floats' rounding; and within the envelope. Then whole draws at
 * those sides against the same draws from a single table whose period they divide (384 for
 * 128, 480 for 160 and 80, 336 for 112; extra_tables 0). */
START_TEST(test_psf_extra_tables)
{
    wf_psf_image img;
    double *psfpix = halo_psf(256, 0.08, 0.4, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    acc.core_radius = 1.0;
    acc.core_levels = 2;
    int per[1 + WF_PROFILE_MAX_ALT];
    ck_assert_int_eq(wf_profile_table_periods(&acc, per), 4);
    ck_assert(per[0] == 192 && per[1] == 160 && per[2] == 128 && per[3] == 112);
    ctx c;
    ctx_open(&c, &acc, &img);
    const wf_profile_psf *ps = &c.psf;
    ck_assert_int_eq(ps->nalt, 3);
    const double dkt = 2.0 * M_PI / (192 * P);
    for (int pass = 0; pass <= ps->ncore; pass++) {
        const float *mre = pass ? ps->core[pass - 1].re : ps->re, *mim = pass ? ps->core[pass - 1].im : ps->im;
        const wf_profile_table *alt = pass ? ps->core[pass - 1].alt : ps->alt;
        const double *env = pass ? ps->core[pass - 1].env : ps->env;
        const int side = 2 * ps->kr + 1;
        const double t0 = mre[(size_t)ps->kr * side + ps->kr];
        for (int i = 0; i < ps->nalt; i++) {
            const wf_profile_table *t = &alt[i];
            int g = t->fft, r = 192; /* gcd: step a of this table is step b of the 192 one */
            while (r) {
                int q = g % r;
                g = r;
                r = q;
            }
            const int a = t->fft / g, b = 192 / g, as = 2 * t->kr + 1;
            ck_assert(t->fft == per[1 + i]);
            double worst = 0.0;
            int met = 0;
            for (int v = -t->kr; v <= t->kr; v++)
                for (int u = -t->kr; u <= t->kr; u++) {
                    size_t at = (size_t)(v + t->kr) * as + (size_t)(u + t->kr);
                    double mag = hypot(t->re[at], t->im[at]), k = hypot(u, v) * 2.0 * M_PI / (t->fft * P);
                    int ring = (int)(k / dkt * (1.0 - 1e-12));
                    if (ring <= ps->kr)
                        ck_assert_msg(mag <= env[ring] * (1.0 + 1e-6) + 1e-30,
                                      "pass %d period %d (%d, %d): %.3g above the envelope %.3g", pass, t->fft,
                                      u, v, mag, env[ring]);
                    if (u % a || v % a || abs(u / a * b) > ps->kr || abs(v / a * b) > ps->kr) continue;
                    size_t m = (size_t)(v / a * b + ps->kr) * side + (size_t)(u / a * b + ps->kr);
                    worst = fmax(worst, fmax(fabs(t->re[at] - mre[m]), fabs(t->im[at] - mim[m])));
                    met++;
                }
            printf("PSF pass %d, table at period %d: %d frequencies shared with the 192 table, worst "
                   "difference %.2e of T(0)\n", pass, t->fft, met, worst / t0);
            ck_assert(met > 100);
            ck_assert_msg(worst <= 3e-7 * t0, "pass %d period %d: %.3g of T(0)", pass, t->fft, worst / t0);
        }
    }
    ctx_close(&c);

    /* draws: a galaxy with knots whose stamp sets the side. The PSF band-limited and no mode
     * cut (kvalue_accuracy 1e-15), so that both draws sum every nonzero sample: a cut
     * found from the two tables' own envelopes may differ by a ring (~1e-6 of the peak) */
    img.band_limit = 40.0; /* rad/arcsec: T ~ 6e-3 there, a raised cosine from 36 */
    wf_galaxy g = galaxy(1, 0.3, 0.3, 0.15, 0.3, 0.1);
    g.n_knots = 10;
    g.knot_frac = 0.2;
    const int sides[4] = {128, 160, 80, 112}, single[4] = {384, 480, 480, 336};
    for (int i = 0; i < 4; i++) {
        wf_profile_accuracy a1, a2;
        wf_profile_accuracy_default(&a1);
        a1.kvalue_accuracy = 1e-15;
        a2 = a1;
        a2.psf_table_fft = single[i];
        a2.extra_tables = 0;
        /* the stamp, not the light, sets the side: a loose flux fraction and folding */
        const int n = sides[i] - 1, h = n / 2;
        const double rel = table_pair(&a1, &a2, &img, &g, n, h + 0.3, h - 0.2, 0.9, 0.05, 1e-15, sides[i], NULL);
        printf("side %d from its own table against a %d table: worst pixel %.2e of the peak\n", sides[i],
               single[i], rel);
        /* the same doubles rounded to floats: equal here (~1e-16), and a float ulp (6e-8) of
         * the largest sample at most where two FFTs' doubles round apart */
        ck_assert_msg(rel < 1e-7, "side %d: %.3g of the peak", sides[i], rel);
    }
    free(psfpix);
}
END_TEST

/* A PSF sampled at a spacing that is not pixel / integer takes the direct-DFT path: the
 * same Gaussian PSF sampled at 0.11/3.7" and at 0.11/4" gives the same stamps. */
START_TEST(test_psf_any_sampling)
{
    const double sigma = 0.07;
    wf_psf_image a, b;
    double *pa = gaussian_psf(96, sigma, &a);
    double h = P / 3.7, c = 0.5 * (96 - 1), sum = 0;
    double *pb = malloc(sizeof(double) * 96 * 96);
    for (int j = 0; j < 96; j++)
        for (int i = 0; i < 96; i++) {
            double r2 = ((i - c) * (i - c) + (j - c) * (j - c)) * h * h;
            pb[j * 96 + i] = exp(-0.5 * r2 / (sigma * sigma));
            sum += pb[j * 96 + i];
        }
    for (int i = 0; i < 96 * 96; i++) pb[i] /= sum;
    b = (wf_psf_image){96, h, pb, 0.0};
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx ca, cb;
    ctx_open(&ca, &acc, &a);
    double t0 = now_s();
    ctx_open(&cb, &acc, &b);
    double ms = 1e3 * (now_s() - t0);
    wf_galaxy g = galaxy(1, 0.3, 0.4, 0.2, 0.2, -0.3);
    wf_stamp s1 = stamp_new(0, 0, 41, 41), s2 = stamp_new(0, 0, 41, 41);
    ck_assert(wf_profile_draw_galaxy(&ca.work, &g, &ca.psf, 20.3, 19.9, &s1) == WF_OK);
    ck_assert(wf_profile_draw_galaxy(&cb.work, &g, &cb.psf, 20.3, 19.9, &s2) == WF_OK);
    double rel = worst_of_peak(&s2, &s1);
    printf("PSF sampled at 0.11/3.7\" (direct DFT, %.0f ms to prepare) vs 0.11/4\": worst "
           "pixel %.2e of the peak\n", ms, rel);
    ck_assert_msg(rel < 1e-6, "sampling-dependent result: %.3g", rel);
    /* an image wider than the transform's period (psf_table_fft 16: 64 samples at 0.11/4",
     * the image 96): folded onto it, as the direct DFT's samples of the same transform */
    ctx_close(&ca);
    ctx_close(&cb);
    acc.psf_table_fft = 16;
    ctx_open(&ca, &acc, &a);
    ctx_open(&cb, &acc, &b);
    ck_assert(wf_profile_draw_galaxy(&ca.work, &g, &ca.psf, 20.3, 19.9, &s1) == WF_OK);
    ck_assert(wf_profile_draw_galaxy(&cb.work, &g, &cb.psf, 20.3, 19.9, &s2) == WF_OK);
    rel = worst_of_peak(&s2, &s1);
    printf("PSF image folded onto a 16-pixel period: worst pixel %.2e of the peak against the "
           "direct DFT\n", rel);
    ck_assert_msg(rel < 1e-6, "folded transform differs: %.3g", rel);
    free(s1.pix);
    free(s2.pix);
    ctx_close(&ca);
    ctx_close(&cb);
    free(pa);
    free(pb);
}
END_TEST

START_TEST(test_bad_input)
{
    wf_psf_image img;
    double *psfpix = gaussian_psf(64, 0.07, &img);
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    ctx_open(&c, &acc, &img);
    wf_stamp s = stamp_new(0, 0, 32, 32);
    wf_galaxy good = galaxy(1, 0.3, 0.3, 0.15, 0.1, 0.1);
    struct {
        const char *what;
        wf_galaxy g;
    } bad[8];
    for (int i = 0; i < 8; i++) bad[i].g = good;
    bad[0].what = "NaN flux", bad[0].g.flux = NAN;
    bad[1].what = "|e| = 1", bad[1].g.e1 = 0.8, bad[1].g.e2 = 0.6;
    bad[2].what = "knot_frac 0.3", bad[2].g.knot_frac = 0.3, bad[2].g.n_knots = 5;
    bad[3].what = "too many knots", bad[3].g.n_knots = WF_PROFILE_MAX_KNOTS + 1;
    bad[4].what = "no bulge size", bad[4].g.hlr_bulge = 0;
    bad[5].what = "negative flux", bad[5].g.flux = -1;
    bad[6].what = "bulge_frac 1.5", bad[6].g.bulge_frac = 1.5;
    bad[7].what = "infinite rotation", bad[7].g.rotation = INFINITY;
    for (int i = 0; i < 8; i++) {
        wf_status st = wf_profile_draw_galaxy(&c.work, &bad[i].g, &c.psf, 16, 16, &s);
        ck_assert_msg(st != WF_OK, "%s accepted", bad[i].what);
        ck_assert_msg(strlen(wf_error_message()) > 10, "%s: no message", bad[i].what);
    }
    ck_assert(wf_profile_draw_galaxy(&c.work, &good, &c.psf, NAN, 16, &s) != WF_OK);
    /* a stamp farther than max_fft / 2 from the object */
    ck_assert(wf_profile_draw_galaxy(&c.work, &good, &c.psf, 16 + acc.max_fft, 16, &s) ==
              WF_ERR_RANGE);
    ck_assert(wf_profile_draw_point(&c.work, &c.psf, -1, 16, 16, &s) != WF_OK);
    wf_stamp none = {0};
    ck_assert(wf_profile_draw_point(&c.work, &c.psf, 1, 16, 16, &none) != WF_OK);
    /* PSF images */
    wf_profile_psf p;
    wf_psf_image bi = img;
    double nanpix[16] = {0, 0, 0, 0, 0, NAN, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
    bi.n = 4;
    bi.pix = nanpix;
    ck_assert(wf_profile_psf_init(&p, &bi, &acc, &c.arena, 1) == WF_ERR_INPUT);
    double zero[16] = {0};
    bi.pix = zero;
    ck_assert(wf_profile_psf_init(&p, &bi, &acc, &c.arena, 1) == WF_ERR_INPUT);
    bi = img;
    bi.scale_arcsec = 0.11; /* undersampled */
    ck_assert(wf_profile_psf_init(&p, &bi, &acc, &c.arena, 1) == WF_ERR_RANGE);
    /* accuracy knobs */
    wf_profile_accuracy a = acc;
    a.flux_fraction = 1.0;
    size_t b;
    ck_assert(wf_profile_work_need(&a, &b, NULL) == WF_ERR_RANGE);
    ck_assert(wf_profile_work_tune(&c.work, 0.9, 0.0, 1e-5, 0.0, WF_PROFILE_KNOT_ACCURACY) == WF_ERR_RANGE);
    /* an arena too small fails cleanly */
    unsigned char small[4096];
    wf_arena tiny;
    wf_arena_init(&tiny, small, sizeof small, "tiny");
    wf_profile_work w;
    ck_assert(wf_profile_work_init(&w, &acc, &tiny) == WF_ERR_NOMEM);
    free(s.pix);
    ctx_close(&c);
    free(psfpix);
}
END_TEST

/* Cost per draw with the reference PSF (or a Gaussian one): printed for the record. */
START_TEST(test_timing)
{
    wf_psf_image img;
    double *native = NULL;
    double *psfpix = reference_psf(&img, &native);
    const char *which = "GalSim Y106 OVER4 + NATIVE wings (14\")";
    if (!psfpix) {
        psfpix = gaussian_psf(128, 0.07, &img);
        which = "Gaussian 0.07\"";
    } else {
        img.n = 128; /* OVER4 alone: the 3.52" image a PSF module would hand over */
        double *core = malloc(sizeof(double) * 128 * 128);
        for (int j = 0; j < 128; j++)
            for (int i = 0; i < 128; i++) core[j * 128 + i] = psfpix[(j + 192) * 512 + i + 192];
        free(psfpix);
        psfpix = core;
        img.pix = core;
        which = "GalSim Y106 OVER4 (3.52\")";
    }
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    ctx c;
    double t0 = now_s();
    ctx_open(&c, &acc, &img);
    printf("timing with PSF %s: work + PSF table %.1f ms\n", which, 1e3 * (now_s() - t0));
    struct {
        const char *what;
        double bf, hd, flux;
        int knots;
    } cases[] = {{"small galaxy (hlr 0.3\", bulge 0.3)", 0.3, 0.3, 100, 0},
                 {"small galaxy + 10 knots", 0.3, 0.3, 100, 10},
                 {"median catalog galaxy (hlr 0.32\", bulge 0.1)", 0.1, 0.32, 100, 10},
                 {"large galaxy (hlr 1.5\", bulge 0.3)", 0.3, 1.5, 100, 10},
                 {"point source", 0, 0, 100, -1}};
    for (int k = 0; k < 5; k++) {
        wf_galaxy g = galaxy(cases[k].flux, cases[k].bf, cases[k].hd, cases[k].hd / 2, 0.2, 0.1);
        g.n_knots = cases[k].knots > 0 ? cases[k].knots : 0;
        g.knot_frac = 0.15;
        wf_stamp s;
        if (cases[k].knots < 0)
            ck_assert(wf_profile_point_bounds(&c.work, &c.psf, 100.3, 100.6, &s, NULL) == WF_OK);
        else
            ck_assert(wf_profile_galaxy_bounds(&c.work, &g, &c.psf, 100.3, 100.6, &s, NULL) ==
                      WF_OK);
        s.pix = calloc((size_t)s.nx * s.ny, sizeof(double));
        int reps = 0;
        t0 = now_s();
        do {
            if (cases[k].knots < 0)
                ck_assert(wf_profile_draw_point(&c.work, &c.psf, 100, 100.3, 100.6, &s) == WF_OK);
            else
                ck_assert(wf_profile_draw_galaxy(&c.work, &g, &c.psf, 100.3, 100.6, &s) == WF_OK);
            reps++;
        } while (now_s() - t0 < 0.2);
        printf("  %-46s stamp %3dx%-3d fft %3d: %.3f ms per draw\n", cases[k].what, s.nx, s.ny,
               s.fft, 1e3 * (now_s() - t0) / reps);
        free(s.pix);
    }
    ctx_close(&c);
    free(psfpix);
    free(native);
}
END_TEST

/* wf_profile_work_need's `dense` bytes are what wf_profile_work_init lays out first and fills:
 * every zero-filled buffer lies inside them, the FFT buffer, knot phases and lattice (touched
 * only as draws reach) beyond them, and the whole fits the need. Without it, a host that puts
 * the dense part on huge pages would make the sparse part resident or fault the dense one. */
START_TEST(test_work_dense_first)
{
    wf_profile_accuracy acc;
    wf_profile_accuracy_default(&acc);
    acc.max_fft = _i ? 384 : 1024;
    size_t need = 0, dense = 0;
    ck_assert_msg(wf_profile_work_need(&acc, &need, &dense) == WF_OK, "%s", wf_error_message());
    ck_assert(dense > 0 && dense < need);
    unsigned char *mem = wf_arena_host_alloc_dense(need, dense);
    ck_assert_ptr_nonnull(mem);
    wf_arena arena;
    wf_arena_init(&arena, mem, need, "dense test");
    wf_profile_work w;
    ck_assert_msg(wf_profile_work_init(&w, &acc, &arena) == WF_OK, "%s", wf_error_message());
    ck_assert_uint_le(arena.high_water, need);
    const void *dense_bufs[] = {w.ex, w.ey, w.ix, w.iy, w.wx, w.wy, w.run, w.knot_pos, w.knot_box, w.ring, w.rim};
    const void *sparse_bufs[] = {w.fft, w.kx, w.ky, w.lat};
    for (size_t i = 0; i < sizeof dense_bufs / sizeof *dense_bufs; i++)
        ck_assert_msg((const unsigned char *)dense_bufs[i] < mem + dense, "dense buffer %zu at %td, past %zu", i,
                      (const unsigned char *)dense_bufs[i] - mem, dense);
    for (size_t i = 0; i < sizeof sparse_bufs / sizeof *sparse_bufs; i++)
        ck_assert_msg((const unsigned char *)sparse_bufs[i] >= mem + dense, "sparse buffer %zu at %td, inside %zu",
                      i, (const unsigned char *)sparse_bufs[i] - mem, dense);
    /* the last dense buffer ends where the sparse ones begin: nothing zero-filled beyond */
    ck_assert_ptr_eq((const unsigned char *)w.rim + wf_arena_cost((size_t)w.cap_line * sizeof(int)), mem + dense);
    wf_profile_work_free(&w);
    free(mem);
}
END_TEST

static Suite *profile_suite(void)
{
    Suite *s = suite_create("profile");
    TCase *ref = tcase_create("galsim");
    tcase_set_timeout(ref, 120);
    tcase_add_test(ref, test_galsim_nopsf);
    tcase_add_test(ref, test_galsim_psf);
    tcase_add_test(ref, test_galsim_point);
    suite_add_tcase(s, ref);
    TCase *ind = tcase_create("independent");
    tcase_set_timeout(ind, 120);
    tcase_add_test(ind, test_sersic_transform);
    tcase_add_test(ind, test_knots_follow_disk);
    tcase_add_test(ind, test_knots_reproducible);
    tcase_add_test(ind, test_knots_from_their_stream);
    tcase_add_test(ind, test_phase_lines_direct);
    tcase_add_test(ind, test_stamp_sum_and_clip);
    tcase_add_test(ind, test_radius_search);
    tcase_add_test(ind, test_flux_exact_pixels);
    tcase_add_test(ind, test_flux_with_psf);
    tcase_add_test(ind, test_centred_symmetric);
    tcase_add_test(ind, test_sheared_ellipticity);
    tcase_add_test(ind, test_pieces_identical);
    tcase_add_test(ind, test_core_wing);
    tcase_add_test(ind, test_knot_table_bound);
    tcase_add_test(ind, test_real_knots_galaxy);
    tcase_add_test(ind, test_core_levels);
    tcase_add_test(ind, test_psf_tables_threads);
    tcase_add_test(ind, test_core_tables_from_the_whole_image);
    tcase_add_test(ind, test_psf_table_steps);
    tcase_add_test(ind, test_psf_table_interpolation);
    tcase_add_test(ind, test_psf_extra_tables);
    tcase_add_test(ind, test_psf_any_sampling);
    tcase_add_test(ind, test_knot_lattice);
    tcase_add_test(ind, test_knot_accuracy);
    tcase_add_test(ind, test_knots_smooth_bound);
    tcase_add_test(ind, test_simd_identical);
    tcase_add_test(ind, test_simd_identical_wing);
    tcase_add_test(ind, test_wing_row_is_box_plus_wing);
    tcase_add_test(ind, test_cut_tolerance_bound);
    tcase_add_loop_test(ind, test_work_dense_first, 0, 2);
    suite_add_tcase(s, ind);
    TCase *stiff = tcase_create("stiff");
    tcase_set_timeout(stiff, 120);
    tcase_add_test(stiff, test_stiff_tiny_galaxy);
    tcase_add_test(stiff, test_stiff_huge_galaxy);
    tcase_add_test(stiff, test_stiff_faint);
    tcase_add_test(stiff, test_stiff_cusp);
    tcase_add_test(stiff, test_stiff_cusp_with_psf);
    tcase_add_test(stiff, test_bad_input);
    suite_add_tcase(s, stiff);
    TCase *t = tcase_create("timing");
    tcase_set_timeout(t, 60);
    tcase_add_test(t, test_timing);
    suite_add_tcase(s, t);
    return s;
}

int main(void) { return wf_test_main(profile_suite()); }
