/* PSF from the pupil (sim/optics/pupil.h, sim/optics/psf.h): closed forms without data (Zernike values
 * and orthonormality, the exact Fourier sum against a brute-force one, an unobstructed
 * circular pupil against the Airy pattern, unit flux over a period, zero first moments of a
 * real pupil, exact pixel integration, chromatic linearity, blurs), the masks and Zernike
 * files of ../shared/data, and GalSim's reference images in ../shared/reference/galsim:
 *  - "as GalSim renders": our PSF put through GalSim's own sampling (Nyquist grid, Quintic
 *    interpolant in real space for no_pixel, its Fourier response for FFT draws) reproduces
 *    every GalSim image to < 1e-4 of the peak: pupil, binning, scale, aberrations,
 *    orientation and normalisation are the same;
 *  - "as wfisim renders" (exact): the differences left are GalSim's interpolation error,
 *    with the tolerances stated at each assertion;
 *  - every filter at one more SCA against an independent PSF (tests/psf_reference.py, numpy),
 *    and GalSim's rendering of it against the peak differences issue 28 measured. */
#include <check.h>
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "sim/optics/bandpass.h"
#include "sim/optics/psf.h"
#include "sim/optics/pupil.h"
#include "tests/testutil.h"
#include "tools/psfcmd.h"

#define PI 3.14159265358979323846
#define ARCSEC_PER_RAD 206264.80624709636
#define REF_N 128

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static void assert_ok(wf_status st)
{
    ck_assert_msg(st == WF_OK, "status %d: %s", st, wf_error_message());
}

static void assert_message_has(const char *what)
{
    const char *msg = wf_error_message();
    ck_assert_msg(strstr(msg, what) != NULL, "message '%s' lacks '%s'", msg, what);
}

/* ---- image statistics -------------------------------------------------------------------- */

typedef struct img_stats {
    double sum, peak;
    int ipeak;
    double sigma; /* adaptive moments: det(M)^(1/4), pixels */
    double g1, g2, xc, yc;
} img_stats;

/* Adaptive (elliptical Gaussian weight) moments iterated to the fixed point M = 2 Mw, the
 * fixed point of GalSim's HSM FindAdaptiveMom; reproduces the summary JSON's values on
 * GalSim's own images (test_moments_reproduce_hsm). */
static void adaptive_moments(const double *im, int nx, int ny, img_stats *s)
{
    double x0 = 0.5 * (nx - 1), y0 = 0.5 * (ny - 1), mxx = 4.0, myy = 4.0, mxy = 0.0;
    for (int it = 0; it < 1000; it++) {
        double det = mxx * myy - mxy * mxy;
        double ixx = myy / det, iyy = mxx / det, ixy = -mxy / det;
        double a = 0, bx = 0, by = 0, cxx = 0, cyy = 0, cxy = 0;
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++) {
                double dx = i - x0, dy = j - y0;
                double r2 = ixx * dx * dx + 2 * ixy * dx * dy + iyy * dy * dy;
                if (r2 > 60.0) continue;
                double w = exp(-0.5 * r2) * im[(size_t)j * nx + i];
                a += w, bx += w * dx, by += w * dy;
                cxx += w * dx * dx, cyy += w * dy * dy, cxy += w * dx * dy;
            }
        bx /= a, by /= a;
        double nxx = 2 * (cxx / a - bx * bx), nyy = 2 * (cyy / a - by * by),
               nxy = 2 * (cxy / a - bx * by);
        double change = fabs(nxx - mxx) + fabs(nyy - myy) + fabs(nxy - mxy) + fabs(bx) + fabs(by);
        x0 += bx, y0 += by, mxx = nxx, myy = nyy, mxy = nxy;
        if (change < 1e-12) break;
    }
    s->sigma = pow(mxx * myy - mxy * mxy, 0.25);
    double e1 = (mxx - myy) / (mxx + myy), e2 = 2 * mxy / (mxx + myy), e = hypot(e1, e2);
    double f = e > 0 ? (1 - sqrt(1 - e * e)) / (e * e) : 0.5; /* g = e / (1 + sqrt(1 - e²)) */
    s->g1 = e1 * f, s->g2 = e2 * f, s->xc = x0, s->yc = y0;
}

static void image_stats(const double *im, int nx, int ny, img_stats *s)
{
    memset(s, 0, sizeof *s);
    for (int i = 0; i < nx * ny; i++) {
        s->sum += im[i];
        if (im[i] > s->peak) s->peak = im[i], s->ipeak = i;
    }
    adaptive_moments(im, nx, ny, s);
}

/* Largest |a - b| over the 3x3 pixels around b's peak, relative to b's peak. */
static double core_diff(const double *a, const double *b, int n, const img_stats *sb)
{
    int pj = sb->ipeak / n, pi = sb->ipeak % n;
    double m = 0;
    for (int j = pj - 1; j <= pj + 1; j++)
        for (int i = pi - 1; i <= pi + 1; i++) {
            double d = fabs(a[j * n + i] - b[j * n + i]);
            if (d > m) m = d;
        }
    return m / sb->peak;
}

static double max_diff(const double *a, const double *b, int n, double peak)
{
    double m = 0;
    for (int i = 0; i < n; i++)
        if (fabs(a[i] - b[i]) > m) m = fabs(a[i] - b[i]);
    return m / peak;
}

/* ---- closed forms ---------------------------------------------------------------------- */

START_TEST(test_zernike_values)
{
    double z, r = 1.0 / sqrt(2.0);
    struct { int j; double x, y, want; } c[] = {
        {1, 0.3, 0.2, 1.0},
        {2, 1, 0, 2.0},                       /* 2ρ cos φ */
        {3, 0, 1, 2.0},                       /* 2ρ sin φ */
        {4, 1, 0, sqrt(3.0)},                 /* √3 (2ρ² - 1) */
        {4, 0, 0, -sqrt(3.0)},
        {5, r, r, sqrt(6.0)},                 /* √6 ρ² sin 2φ */
        {6, 1, 0, sqrt(6.0)},                 /* √6 ρ² cos 2φ */
        {7, 0, 1, sqrt(8.0)},                 /* √8 (3ρ³ - 2ρ) sin φ */
        {8, 1, 0, sqrt(8.0)},
        {9, 0, 1, -sqrt(8.0)},                /* √8 ρ³ sin 3φ at φ = 90° */
        {10, 1, 0, sqrt(8.0)},
        {11, 0, 0, sqrt(5.0)},                /* √5 (6ρ⁴ - 6ρ² + 1) */
        {12, 1, 0, sqrt(10.0)},               /* √10 (4ρ⁴ - 3ρ²) cos 2φ */
        {14, 1, 0, sqrt(10.0)},               /* √10 ρ⁴ cos 4φ */
        {16, 1, 0, sqrt(12.0)},               /* √12 (10ρ⁵ - 12ρ³ + 3ρ) cos φ */
        {21, 0, 1, sqrt(12.0)},               /* √12 ρ⁵ sin 5φ at φ = 90° */
        {22, 0, 0, -sqrt(7.0)},               /* √7 (20ρ⁶ - 30ρ⁴ + 12ρ² - 1) */
    };
    for (size_t k = 0; k < sizeof c / sizeof *c; k++) {
        assert_ok(wf_pupil_zernike(c[k].j, c[k].x, c[k].y, &z));
        ck_assert_msg(fabs(z - c[k].want) < 1e-12, "Z%d(%g,%g) = %.15g, want %.15g", c[k].j,
                      c[k].x, c[k].y, z, c[k].want);
    }
    ck_assert_int_eq(wf_pupil_zernike(0, 0, 0, &z), WF_ERR_RANGE);
    ck_assert_int_eq(wf_pupil_zernike(WF_ZERNIKE_MAX + 1, 0, 0, &z), WF_ERR_RANGE);
}
END_TEST

/* Noll normalisation: <Z_i Z_j> over the unit disc = δ_ij (midpoint rule on a 400² grid). */
START_TEST(test_zernike_orthonormal)
{
    enum { G = 400 };
    double acc[WF_ZERNIKE_MAX + 1][WF_ZERNIKE_MAX + 1] = {{0}};
    double zv[WF_ZERNIKE_MAX + 1];
    long count = 0;
    for (int b = 0; b < G; b++)
        for (int a = 0; a < G; a++) {
            double x = -1 + (a + 0.5) * 2.0 / G, y = -1 + (b + 0.5) * 2.0 / G;
            if (x * x + y * y >= 1) continue;
            count++;
            for (int j = 1; j <= WF_ZERNIKE_MAX; j++) wf_pupil_zernike(j, x, y, &zv[j]);
            for (int i = 1; i <= WF_ZERNIKE_MAX; i++)
                for (int j = i; j <= WF_ZERNIKE_MAX; j++) acc[i][j] += zv[i] * zv[j];
        }
    for (int i = 1; i <= WF_ZERNIKE_MAX; i++)
        for (int j = i; j <= WF_ZERNIKE_MAX; j++) {
            double v = acc[i][j] / count, want = i == j;
            ck_assert_msg(fabs(v - want) < 0.01, "<Z%d Z%d> = %g", i, j, v);
        }
}
END_TEST

START_TEST(test_filter_groups)
{
    wf_pupil_group g;
    const char *shortw[] = {"R062", "z087", "Y106", "J129", "H158", "W146", "W149"};
    for (size_t i = 0; i < sizeof shortw / sizeof *shortw; i++) {
        assert_ok(wf_pupil_group_of_filter(shortw[i], &g));
        ck_assert_int_eq(g, WF_PUPIL_SHORT);
    }
    assert_ok(wf_pupil_group_of_filter("F184", &g));
    ck_assert_int_eq(g, WF_PUPIL_LONG);
    assert_ok(wf_pupil_group_of_filter("k213", &g));
    ck_assert_int_eq(g, WF_PUPIL_LONG);
    ck_assert_int_eq(wf_pupil_group_of_filter("V555", &g), WF_ERR_INPUT);
    assert_message_has("V555");
}
END_TEST

/* The analytic pupil: open area against the closed form, symmetric bounding box, and the
 * binning rules (any-open never loses area, mean keeps it). */
START_TEST(test_pupil_analytic)
{
    wf_pupil_geometry g;
    assert_ok(wf_pupil_geometry_default(WF_PUPIL_SHORT, &g));
    ck_assert_int_eq(g.nstruts, 6);
    wf_pupil p1, p8, m8;
    assert_ok(wf_pupil_analytic(&g, 1, WF_PUPIL_BIN_ANY, &p1));
    assert_ok(wf_pupil_analytic(&g, 8, WF_PUPIL_BIN_ANY, &p8));
    assert_ok(wf_pupil_analytic(&g, 8, WF_PUPIL_BIN_MEAN, &m8));
    ck_assert_int_eq(p1.n, 2048);
    ck_assert_int_eq(p8.n, 256);
    ck_assert_double_eq_tol(p8.dx, 8 * WF_PUPIL_NATIVE_DX, 1e-15);
    /* annulus minus six struts running from the obscuration to the rim: each covers
     * width × (chord from R_o to R along a line 0.2 m off the axis) */
    double R = 1.18, Ro = 0.32 * R, w = 0.0755, off = 0.2;
    double len = sqrt(R * R - off * off) - sqrt(Ro * Ro - off * off);
    double want = PI * (R * R - Ro * Ro) - 6 * w * len;
    ck_assert_msg(fabs(p1.open_area / want - 1) < 0.003, "open area %.5f m², closed form %.5f",
                  p1.open_area, want);
    ck_assert_msg(p8.open_area > p1.open_area, "any-open binning must not lose area");
    double mean_area = 0;
    for (int i = 0; i < m8.n * m8.n; i++) mean_area += m8.amp[i];
    mean_area *= m8.dx * m8.dx;
    /* the same up to rasterisation: each binning centres its native samples on its own axis
     * (half a native sample apart), so the edges fall on slightly different samples */
    ck_assert_msg(fabs(mean_area / p1.open_area - 1) < 2e-3, "mean binning keeps the area: "
                  "%.6f vs %.6f", mean_area, p1.open_area);
    ck_assert_int_eq(p8.i0 + p8.i1, p8.n);  /* symmetric about the axis at n/2 */
    ck_assert_int_eq(p8.j0 + p8.j1, p8.n);
    printf("analytic pupil: open area %.4f m² (bin 1), %.4f (bin 8 any-open, +%.2f%%)\n",
           p1.open_area, p8.open_area, 100 * (p8.open_area / p1.open_area - 1));
    wf_pupil_free(&p1);
    wf_pupil_free(&p8);
    wf_pupil_free(&m8);
    ck_assert_int_eq(wf_pupil_analytic(&g, 3, WF_PUPIL_BIN_ANY, &p1), WF_ERR_RANGE);
    assert_message_has("pupil_bin 3");
}
END_TEST

/* Closed arcs (struts) crossed by a circle of radius r: their mid angles and widths (m). */
static int strut_crossings(const wf_pupil *p, double r, double *mid_deg, double *width_m, int max)
{
    int m = 20000, n = 0, prev = 1;
    double start = 0, a0 = 0;
#define OPEN_AT(a)                                                                             \
    (p->amp[(size_t)lround(r * sin(a) / p->dx + p->n / 2) * p->n +                            \
            lround(r * cos(a) / p->dx + p->n / 2)] > 0)
    while (!OPEN_AT(a0)) a0 += 2 * PI / m; /* start in the open so no arc is split */
    for (int t = 0; t <= m; t++) {
        double a = a0 + 2 * PI * t / m;
        int open = OPEN_AT(a);
        if (!open && prev) start = a;
        if (open && !prev && n < max) {
            mid_deg[n] = fmod(0.5 * (start + a) * 180 / PI, 360.0);
            width_m[n] = (a - start) * r;
            n++;
        }
        prev = open;
    }
#undef OPEN_AT
    return n;
}

/* A pupil mask of our own, written as FITS: its gzip inflated in memory (libdeflate) gives the
 * samples the plain file gives through cfitsio; a truncated gzip fails with the file named. */
static void write_mask(const char *path, int n)
{
    fitsfile *f = NULL;
    int status = 0;
    long naxes[2] = {n, n};
    remove(path);
    ck_assert(!fits_create_file(&f, path, &status));
    ck_assert(!fits_create_img(f, SHORT_IMG, 2, naxes, &status));
    double scale = 2.37 / n;
    ck_assert(!fits_update_key(f, TDOUBLE, "PIXELSCL", &scale, "m", &status));
    short *px = malloc(sizeof *px * (size_t)n * n);
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            double x = i - 0.5 * n + 0.5, y = j - 0.5 * n + 0.7, r = sqrt(x * x + y * y) / (0.5 * n);
            px[(size_t)j * n + i] = (short)(r < 1.0 && r > 0.3 && fabs(y) > 1.0);
        }
    ck_assert(!fits_write_img(f, TSHORT, 1, (LONGLONG)n * n, px, &status));
    ck_assert(!fits_close_file(f, &status));
    free(px);
}

START_TEST(test_pupil_gzip_in_memory)
{
    const char *tmp = wf_test_tmpdir();
    char dz[512], dp[512], dt[512], fits[600], gz[600], plain[600], trunc[600], cmd[8192];
    snprintf(dz, sizeof dz, "%s/pupil_gz", tmp);
    snprintf(dp, sizeof dp, "%s/pupil_plain", tmp);
    snprintf(dt, sizeof dt, "%s/pupil_trunc", tmp);
    snprintf(fits, sizeof fits, "%s/mask.fits", tmp);
    snprintf(gz, sizeof gz, "%s/RST_WIM_Filter_skinny_SCA_3.fits.gz", dz);
    snprintf(plain, sizeof plain, "%s/RST_WIM_Filter_skinny_SCA_3.fits.gz", dp);
    snprintf(trunc, sizeof trunc, "%s/RST_WIM_Filter_skinny_SCA_3.fits.gz", dt);
    write_mask(fits, 256);
    snprintf(cmd, sizeof cmd, "mkdir -p '%s' '%s' '%s' && gzip -c '%s' > '%s' && cp '%s' '%s' && "
             "head -c $(( $(wc -c < '%s') / 2 )) '%s' > '%s'", dz, dp, dt, fits, gz, fits, plain, gz, gz, trunc);
    ck_assert_int_eq(system(cmd), 0);
    wf_pupil a, b;
    assert_ok(wf_pupil_load(dz, 3, WF_PUPIL_SHORT, 2, WF_PUPIL_BIN_MEAN, &a));
    assert_ok(wf_pupil_load(dp, 3, WF_PUPIL_SHORT, 2, WF_PUPIL_BIN_MEAN, &b));
    ck_assert_int_eq(a.n, 128);
    ck_assert_int_eq(b.n, 128);
    ck_assert(!memcmp(a.amp, b.amp, sizeof(float) * 128 * 128));
    ck_assert(a.open_area == b.open_area && a.open_area > 0.0);
    wf_pupil_free(&a);
    wf_pupil_free(&b);
    ck_assert(wf_pupil_load(dt, 3, WF_PUPIL_SHORT, 2, WF_PUPIL_BIN_MEAN, &a) != WF_OK);
    ck_assert_msg(strstr(wf_error_message(), trunc) != NULL, "message does not name the file: %s", wf_error_message());
    printf("truncated pupil mask: %s\n", wf_error_message());
}
END_TEST

/* The analytic struts against the SCA 1 mask: where they cross two circles and how wide. */
START_TEST(test_pupil_mask_geometry)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    wf_pupil mask, ana;
    wf_pupil_geometry g;
    assert_ok(wf_pupil_load(data, 1, WF_PUPIL_SHORT, 1, WF_PUPIL_BIN_ANY, &mask));
    assert_ok(wf_pupil_geometry_default(WF_PUPIL_SHORT, &g));
    assert_ok(wf_pupil_analytic(&g, 1, WF_PUPIL_BIN_ANY, &ana));
    ck_assert_int_eq(mask.n, 2048);
    ck_assert_double_eq_tol(mask.dx, WF_PUPIL_NATIVE_DX, 1e-12);
    long differ = 0;
    for (int i = 0; i < mask.n * mask.n; i++) differ += (mask.amp[i] > 0) != (ana.amp[i] > 0);
    double frac = (double)differ / (mask.open_area / (mask.dx * mask.dx));
    printf("mask vs analytic (SCA 1 short): open area %.4f vs %.4f m², %.1f%% of the open "
           "samples differ\n", mask.open_area, ana.open_area, 100 * frac);
    ck_assert_msg(fabs(ana.open_area / mask.open_area - 1) < 0.04, "areas %.4f vs %.4f",
                  ana.open_area, mask.open_area);
    for (int k = 0; k < 2; k++) {
        double r = k ? 0.9 : 0.65, am[12], aw[12], mm[12], mw[12];
        int na = strut_crossings(&ana, r, am, aw, 12), nm = strut_crossings(&mask, r, mm, mw, 12);
        ck_assert_int_eq(na, 6);
        ck_assert_int_eq(nm, 6);
        for (int a = 0; a < 6; a++) {
            double best = 1e9, bw = 0;
            for (int b = 0; b < 6; b++) {
                double d = fabs(fmod(am[a] - mm[b] + 540.0, 360.0) - 180.0);
                if (d < best) best = d, bw = mw[b];
            }
            printf("  r %.2f m: strut at %6.1f° (mask %+.2f°), arc %.1f mm (mask %.1f)\n", r,
                   am[a], best, 1e3 * aw[a], 1e3 * bw);
            ck_assert_msg(best < 2.5, "strut at %.1f° is %.2f° from the mask's", am[a], best);
            ck_assert_msg(fabs(aw[a] / bw - 1) < 0.2, "strut width %.4f vs %.4f", aw[a], bw);
        }
    }
    wf_pupil_free(&mask);
    wf_pupil_free(&ana);
}
END_TEST

/* The two-FFT Fourier coefficients against |Σ P e^{iφ} e^{2πiθu/λ}|² summed directly, on a
 * small irregular pupil with aberrations, at off-grid angles and any scale. */
START_TEST(test_fourier_sum_exact)
{
    enum { N = 24 };
    wf_pupil p;
    memset(&p, 0, sizeof p);
    p.n = N, p.bin = 1, p.dx = 0.1, p.diam = 2.0;
    p.amp = calloc(N * N, sizeof(float));
    unsigned s = 12345;
    for (int j = 3; j < 21; j++)
        for (int i = 2; i < 22; i++) {
            s = s * 1103515245u + 12345u;
            p.amp[j * N + i] = (s >> 16) % 5 ? (float)(0.5 + 0.5 * ((s >> 8) & 255) / 255.0) : 0.0f;
        }
    p.i0 = N, p.i1 = -1, p.j0 = N, p.j1 = -1;
    double c0 = 0;
    for (int j = 0; j < N; j++)
        for (int i = 0; i < N; i++)
            if (p.amp[j * N + i] > 0) {
                c0 += (double)p.amp[j * N + i] * p.amp[j * N + i];
                if (i < p.i0) p.i0 = i;
                if (i > p.i1) p.i1 = i;
                if (j < p.j0) p.j0 = j;
                if (j > p.j1) p.j1 = j;
            }
    p.open_area = c0 * p.dx * p.dx;
    snprintf(p.source, sizeof p.source, "test");
    wf_aberrations ab;
    wf_pupil_aberrations_none(&ab);
    ab.z[4] = 0.05, ab.z[7] = -0.08, ab.z[9] = 0.03, ab.z[13] = 0.02;
    double lam = 800.0;
    wf_psf *psf;
    assert_ok(wf_psf_build(&p, &ab, &lam, NULL, 1, 0, &psf));
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = 7, d.ny = 5, d.scale = 0.173, d.cx = 2.37, d.cy = 1.61, d.pixel = 0;
    double out[35];
    assert_ok(wf_psf_draw(psf, &d, out));
    double T = lam * 1e-9 / p.dx * ARCSEC_PER_RAD, R = 0.5 * p.diam, want[35], top = 0;
    for (int j = 0; j < d.ny; j++)
        for (int i = 0; i < d.nx; i++) {
            double tx = (i - d.cx) * d.scale / ARCSEC_PER_RAD, ty = (j - d.cy) * d.scale / ARCSEC_PER_RAD;
            double er = 0, ei = 0;
            for (int b = 0; b < N; b++)
                for (int a = 0; a < N; a++) {
                    double amp = p.amp[b * N + a];
                    if (amp <= 0) continue;
                    double u = (a - N / 2) * p.dx, v = (b - N / 2) * p.dx, w = 0, z;
                    for (int k = 4; k <= WF_ZERNIKE_MAX; k++) {
                        wf_pupil_zernike(k, u / R, v / R, &z);
                        w += ab.z[k] * z;
                    }
                    double ph = 2 * PI * w * ab.lambda_ref_nm / lam + 2 * PI * (tx * u + ty * v) / (lam * 1e-9);
                    er += amp * cos(ph), ei += amp * sin(ph);
                }
            want[j * d.nx + i] = (er * er + ei * ei) / (c0 * T * T) * d.scale * d.scale;
            top = fmax(top, want[j * d.nx + i]);
        }
    for (int i = 0; i < d.nx * d.ny; i++)
        ck_assert_msg(fabs(out[i] - want[i]) < 1e-11 * top, "sample %d: %.15g vs direct %.15g", i,
                      out[i], want[i]);
    wf_psf_free(psf);
    free(p.amp);
}
END_TEST

/* An unobstructed circular pupil without aberrations gives the Airy pattern:
 * peak = open area / λ², first dark ring at 1.2197 λ/D, 83.8% encircled there. */
START_TEST(test_airy)
{
    wf_pupil_geometry g = {.diam = WF_PUPIL_DIAM, .obscuration = 0.0, .nstruts = 0};
    wf_pupil p;
    assert_ok(wf_pupil_analytic(&g, 4, WF_PUPIL_BIN_MEAN, &p));
    wf_aberrations ab;
    wf_pupil_aberrations_none(&ab);
    double lam = 1000.0, lod = lam * 1e-9 / WF_PUPIL_DIAM * ARCSEC_PER_RAD;
    wf_psf *psf;
    assert_ok(wf_psf_build(&p, &ab, &lam, NULL, 1, 0, &psf));
    /* peak surface brightness per arcsec²: |Σ P|² / (Σ P² T²) exactly; π D²/(4 λ²) for the
     * continuous disc */
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = 1, d.cx = d.cy = 0, d.scale = 1e-3, d.pixel = 0;
    double v;
    assert_ok(wf_psf_draw(psf, &d, &v));
    double sum_a = 0, sum_a2 = 0;
    for (int i = 0; i < p.n * p.n; i++) sum_a += p.amp[i], sum_a2 += p.amp[i] * p.amp[i];
    double T = lam * 1e-9 / p.dx * ARCSEC_PER_RAD;
    double peak = v / (d.scale * d.scale), exact = sum_a * sum_a / (sum_a2 * T * T);
    double airy = PI * WF_PUPIL_DIAM * WF_PUPIL_DIAM / (4 * lam * lam * 1e-18) /
                  (ARCSEC_PER_RAD * ARCSEC_PER_RAD);
    ck_assert_msg(fabs(peak / exact - 1) < 1e-10, "peak %.12g vs |ΣP|²/(ΣP² T²) %.12g", peak, exact);
    ck_assert_msg(fabs(peak / airy - 1) < 2e-3, "peak %.8g vs π D²/4λ² %.8g", peak, airy);

    /* radial profile along x against [2 J1(x)/x]² and the first minimum */
    enum { M = 801 };
    double row[M];
    d.nx = M, d.ny = 1, d.cx = 0, d.cy = 0, d.scale = 3.0 * lod / (M - 1);
    assert_ok(wf_psf_draw(psf, &d, row));
    double worst = 0;
    int imin = 0;
    for (int i = 1; i < M; i++) {
        double x = PI * i * d.scale / lod, a = 2 * j1(x) / x;
        double want = a * a * row[0];
        if (fabs(row[i] - want) > worst) worst = fabs(row[i] - want);
        if (i * d.scale > lod && i * d.scale < 1.5 * lod && (imin == 0 || row[i] < row[imin])) imin = i;
    }
    /* parabola through the lowest three samples */
    double ym = row[imin - 1], y0 = row[imin], yp = row[imin + 1];
    double rmin = (imin + 0.5 * (ym - yp) / (ym - 2 * y0 + yp)) * d.scale / lod;
    printf("Airy (pupil_bin 4): peak %.6g/arcsec² vs %.6g continuous (%.2e); first dark ring "
           "%.5f λ/D (1.21967); max |profile - Airy| %.2e of peak\n", peak, airy, peak / airy - 1,
           rmin, worst / row[0]);
    ck_assert_msg(fabs(rmin - 1.21967) < 2e-3, "first dark ring at %.5f λ/D", rmin);
    ck_assert_msg(worst < 2e-3 * row[0], "profile differs from Airy by %.2e of peak", worst / row[0]);

    /* encircled energy inside the first dark ring: 1 - J0²(x1) - J1²(x1) at x1 = 3.8317 */
    enum { E = 301 };
    double *img = malloc(sizeof(double) * E * E);
    d.nx = d.ny = E, d.cx = d.cy = (E - 1) / 2.0, d.scale = 2.6 * lod / (E - 1);
    assert_ok(wf_psf_draw(psf, &d, img));
    double ee = 0, r1 = 1.21967 * lod;
    for (int j = 0; j < E; j++)
        for (int i = 0; i < E; i++) {
            /* 8x8 sub-samples of the disc edge keep the boundary error below 1e-4 */
            int in = 0;
            for (int t = 0; t < 8; t++)
                for (int u = 0; u < 8; u++) {
                    double x = (i - d.cx + (u + 0.5) / 8 - 0.5) * d.scale;
                    double y = (j - d.cy + (t + 0.5) / 8 - 0.5) * d.scale;
                    in += x * x + y * y < r1 * r1;
                }
            ee += img[j * E + i] * in / 64.0;
        }
    double x1 = 3.8317059702075123, want_ee = 1 - j0(x1) * j0(x1) - j1(x1) * j1(x1);
    printf("Airy encircled energy at the first dark ring: %.5f (closed form %.5f)\n", ee, want_ee);
    ck_assert_msg(fabs(ee - want_ee) < 2e-3, "EE %.5f vs %.5f", ee, want_ee);
    free(img);
    wf_psf_free(psf);
    wf_pupil_free(&p);
}
END_TEST

/* Unit flux per period: samples spaced T/M over one period sum to c_0 = 1 exactly, with or
 * without the pixel (boxes tiling the period), for the Roman-like analytic pupil. */
START_TEST(test_flux_one_period)
{
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.pupil_bin = 8;
    double lam = 1293.0;
    wf_psf *psf;
    assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
    wf_psf_info info;
    assert_ok(wf_psf_get_info(psf, &info));
    int M = 2 * info.kx + 1;
    if (2 * info.ky + 1 > M) M = 2 * info.ky + 1;
    double *img = malloc(sizeof(double) * M * M);
    for (int pix = 0; pix < 2; pix++) {
        wf_psf_draw_opts d;
        wf_psf_draw_opts_default(&d);
        d.nx = d.ny = M, d.scale = info.period_arcsec / M, d.cx = d.cy = (M - 1) / 2.0;
        d.pixel = pix, d.det_scale = d.scale;
        assert_ok(wf_psf_draw(psf, &d, img));
        double sum = 0;
        for (int i = 0; i < M * M; i++) sum += img[i];
        printf("flux over one period (%dx%d, %s): 1 %+.2e\n", M, M, pix ? "pixel" : "no pixel",
               sum - 1);
        ck_assert_msg(fabs(sum - 1) < 1e-10, "sum %.15g", sum);
    }
    free(img);
    wf_psf_free(psf);
}
END_TEST

/* A real pupil without aberrations has PSF(θ) = PSF(-θ): zero first moments about the
 * centre, whatever the (asymmetric) struts. */
START_TEST(test_first_moments_zero)
{
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.pupil_bin = 8;
    double lam = 1059.5;
    wf_psf *psf;
    assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
    enum { N = 65 };
    double img[N * N];
    for (int over = 0; over < 2; over++) {
        wf_psf_draw_opts d;
        wf_psf_draw_opts_default(&d);
        d.nx = d.ny = N, d.cx = d.cy = (N - 1) / 2.0;
        d.scale = over ? 0.0275 : 0.11, d.pixel = !over;
        assert_ok(wf_psf_draw(psf, &d, img));
        double s = 0, sx = 0, sy = 0;
        for (int j = 0; j < N; j++)
            for (int i = 0; i < N; i++) {
                s += img[j * N + i];
                sx += (i - d.cx) * img[j * N + i];
                sy += (j - d.cy) * img[j * N + i];
            }
        ck_assert_msg(fabs(sx / s) < 1e-11 && fabs(sy / s) < 1e-11, "first moments %g %g px",
                      sx / s, sy / s);
        for (int i = 0; i < N * N; i++)
            ck_assert_msg(fabs(img[i] - img[N * N - 1 - i]) < 1e-14, "not point-symmetric at %d", i);
    }
    wf_psf_free(psf);
}
END_TEST

/* The pixel box is integrated exactly: a 0.11" pixel is the sum of the 4x4 boxes of 0.0275"
 * that tile it, at an arbitrary sub-pixel centre. */
START_TEST(test_pixel_integration_exact)
{
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.pupil_bin = 8;
    double lam = 1579.1;
    wf_psf *psf;
    assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
    enum { N = 15, K = 4 };
    double coarse[N * N], fine[N * K * N * K];
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = N, d.scale = 0.11, d.det_scale = 0.11, d.cx = 7.3, d.cy = 6.85, d.pixel = 1;
    assert_ok(wf_psf_draw(psf, &d, coarse));
    /* fine sample (I, J) centred at ((I + 0.5)/K - 0.5) coarse pixels */
    d.nx = d.ny = N * K, d.scale = 0.11 / K, d.det_scale = 0.11 / K;
    d.cx = (7.3 + 0.5) * K - 0.5, d.cy = (6.85 + 0.5) * K - 0.5;
    assert_ok(wf_psf_draw(psf, &d, fine));
    double worst = 0, peak = 0;
    for (int j = 0; j < N; j++)
        for (int i = 0; i < N; i++) {
            double s = 0;
            for (int t = 0; t < K; t++)
                for (int u = 0; u < K; u++) s += fine[(j * K + t) * N * K + i * K + u];
            worst = fmax(worst, fabs(s - coarse[j * N + i]));
            peak = fmax(peak, coarse[j * N + i]);
        }
    ck_assert_msg(worst < 1e-13, "pixel != sum of its sub-boxes by %g (peak %g)", worst, peak);
    wf_psf_free(psf);
}
END_TEST

/* Chromatic mode is the weighted mean of the monochromatic PSFs; one wavelength is the
 * achromatic PSF. */
START_TEST(test_chromatic_linear)
{
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.pupil_bin = 8;
    double lams[3] = {1000.0, 1100.0, 1250.0}, w[3] = {1.0, 3.0, 0.5};
    wf_psf *mono[3], *chrom;
    for (int k = 0; k < 3; k++) assert_ok(wf_psf_build_optics(&o, &lams[k], NULL, 1, &mono[k]));
    assert_ok(wf_psf_build_optics(&o, lams, w, 3, &chrom));
    wf_psf_info info;
    assert_ok(wf_psf_get_info(chrom, &info));
    ck_assert_int_eq(info.nlambda, 3);
    ck_assert_double_eq_tol(info.weight[1], 3.0 / 4.5, 1e-15);
    ck_assert_double_eq_tol(info.lambda_mean_nm, (1000 + 3300 + 625) / 4.5, 1e-9);
    enum { N = 33 };
    double a[N * N], b[N * N], sum[N * N] = {0};
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = N, d.cx = d.cy = 16.2, d.scale = 0.055;
    for (int k = 0; k < 3; k++) {
        assert_ok(wf_psf_draw(mono[k], &d, a));
        for (int i = 0; i < N * N; i++) sum[i] += w[k] / 4.5 * a[i];
    }
    assert_ok(wf_psf_draw(chrom, &d, b));
    ck_assert_msg(max_diff(b, sum, N * N, 1.0) < 1e-15, "chromatic != weighted mean");
    for (int k = 0; k < 3; k++) wf_psf_free(mono[k]);
    wf_psf_free(chrom);
}
END_TEST

/* Rows shared among threads: the same image, bit for bit, for 1 to 5 threads (chromatic,
 * odd sizes, with the pixel and a blur), since each row's sums keep their order. */
START_TEST(test_draw_threads)
{
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.pupil_bin = 8;
    double lams[2] = {1000.0, 1200.0}, w[2] = {1.0, 2.0};
    wf_psf *psf;
    assert_ok(wf_psf_build_optics(&o, lams, w, 2, &psf));
    enum { NX = 131, NY = 203 };
    double *ref = malloc(sizeof(double) * NX * NY), *img = malloc(sizeof(double) * NX * NY);
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = NX, d.ny = NY, d.cx = 64.3, d.cy = 100.7, d.scale = 0.0275, d.diffusion = 0.1;
    assert_ok(wf_psf_draw(psf, &d, ref));
    for (int t = 2; t <= 5; t++) {
        d.threads = t;
        for (int i = 0; i < NX * NY; i++) img[i] = -1.0;
        assert_ok(wf_psf_draw(psf, &d, img));
        ck_assert_msg(!memcmp(ref, img, sizeof(double) * NX * NY), "%d threads: the image differs", t);
    }
    free(ref);
    free(img);
    wf_psf_free(psf);
}
END_TEST

/* The chirp-z draw is the same Fourier sum as the direct one: two wavelengths, an off-centre,
 * non-square image at the wide PSF's sampling, with and without the pixel and the blurs,
 * and a stamp wider than the period (zeroed alike). Agreement to 1e-12 of the peak (the
 * transforms' round-off, ~1e-15 of Σ|c|). */
START_TEST(test_draw_czt)
{
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.pupil_bin = 8;
    double lams[2] = {1000.0, 1200.0}, w[2] = {1.0, 2.0};
    wf_psf *psf;
    assert_ok(wf_psf_build_optics(&o, lams, w, 2, &psf));
    wf_psf_info info;
    assert_ok(wf_psf_get_info(psf, &info));
    enum { NX = 301, NY = 256 };
    const int wide = (int)(1.3 * info.period_arcsec / 0.11) | 1;
    double *ref = malloc(sizeof(double) * NX * NY), *img = malloc(sizeof(double) * NX * NY);
    double *wref = malloc(sizeof(double) * wide * wide), *wimg = malloc(sizeof(double) * wide * wide);
    for (int c = 0; c < 3; c++) {
        wf_psf_draw_opts d;
        wf_psf_draw_opts_default(&d);
        d.nx = NX, d.ny = NY, d.cx = 150.3, d.cy = 120.8, d.scale = 0.0275, d.pixel = c == 1;
        if (c == 2) d.jitter = WF_PSF_JITTER_SIGMA, d.diffusion = 0.1, d.galsim = 1;
        assert_ok(wf_psf_draw(psf, &d, ref));
        d.czt = 1;
        for (int i = 0; i < NX * NY; i++) img[i] = -1.0;
        assert_ok(wf_psf_draw(psf, &d, img));
        double peak = 0, worst = 0;
        for (int i = 0; i < NX * NY; i++) {
            if (fabs(ref[i]) > peak) peak = fabs(ref[i]);
            if (fabs(img[i] - ref[i]) > worst) worst = fabs(img[i] - ref[i]);
        }
        ck_assert_msg(peak > 1e-3 && worst < 1e-12 * peak, "case %d: chirp-z off by %.3g of the peak", c,
                      worst / peak);
        printf("chirp-z draw, case %d: worst %.2g of the peak\n", c, worst / peak);
    }
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = wide, d.cx = d.cy = (wide - 1) / 2.0;
    assert_ok(wf_psf_draw(psf, &d, wref));
    d.czt = 1;
    assert_ok(wf_psf_draw(psf, &d, wimg));
    double peak = 0, worst = 0;
    for (int i = 0; i < wide * wide; i++) {
        if (fabs(wref[i]) > peak) peak = fabs(wref[i]);
        if (fabs(wimg[i] - wref[i]) > worst) worst = fabs(wimg[i] - wref[i]);
    }
    ck_assert_double_eq(wimg[0], 0.0);
    ck_assert_msg(worst < 1e-12 * peak, "wider than the period: chirp-z off by %.3g of the peak", worst / peak);
    d.czt = 2;
    ck_assert_int_eq(wf_psf_draw(psf, &d, wimg), WF_ERR_RANGE);
    free(ref);
    free(img);
    free(wref);
    free(wimg);
    wf_psf_free(psf);
}
END_TEST

/* Jitter and diffusion are the same Gaussian in different units, and the blurred PSF is the
 * PSF convolved with it (checked at one point against a direct quadrature). */
START_TEST(test_blurs)
{
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.pupil_bin = 8;
    double lam = 1059.5;
    wf_psf *psf;
    assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
    enum { N = 96 };
    double a[N * N], b[N * N], c[N * N];
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = N, d.cx = d.cy = (N - 1) / 2.0, d.scale = 0.0275, d.pixel = 0;
    d.jitter = WF_PSF_JITTER_SIGMA;
    assert_ok(wf_psf_draw(psf, &d, a));
    d.jitter = 0, d.diffusion = WF_PSF_JITTER_SIGMA / d.det_scale;
    assert_ok(wf_psf_draw(psf, &d, b));
    ck_assert_msg(max_diff(a, b, N * N, 1.0) < 1e-15, "jitter and diffusion disagree");
    d.diffusion = 0;
    assert_ok(wf_psf_draw(psf, &d, c));
    img_stats s0, s1;
    image_stats(c, N, N, &s0);
    image_stats(a, N, N, &s1);
    ck_assert_msg(s1.sigma > s0.sigma && s1.peak < s0.peak, "jitter must widen the core");
    /* blurred value at θ0 = Σ over a fine grid of PSF(θ) G(θ0 - θ): the grid (0.005") samples
     * the band-limited PSF far above Nyquist, so the sum is the integral to ~1e-9 */
    double sig = 0.1, th0x = 0.07, th0y = -0.04, h = 0.005, one;
    wf_psf_draw_opts p1;
    wf_psf_draw_opts_default(&p1);
    p1.nx = p1.ny = 1, p1.cx = p1.cy = 0, p1.pixel = 0, p1.scale = 1e-3, p1.jitter = sig;
    p1.cx = -th0x / p1.scale, p1.cy = -th0y / p1.scale;
    assert_ok(wf_psf_draw(psf, &p1, &one));
    int m = 2 * (int)(7 * sig / h) + 1;
    double *fine = malloc(sizeof(double) * m * m), conv = 0;
    p1.nx = p1.ny = m, p1.scale = h, p1.jitter = 0;
    p1.cx = (m - 1) / 2.0 - th0x / h, p1.cy = (m - 1) / 2.0 - th0y / h;
    assert_ok(wf_psf_draw(psf, &p1, fine));
    for (int j = 0; j < m; j++)
        for (int i = 0; i < m; i++) {
            double rx = (i - (m - 1) / 2.0) * h, ry = (j - (m - 1) / 2.0) * h;
            conv += fine[j * m + i] * exp(-0.5 * (rx * rx + ry * ry) / (sig * sig)) / (2 * PI * sig * sig);
        }
    free(fine);
    double direct = one / (1e-3 * 1e-3);
    ck_assert_msg(fabs(direct / conv - 1) < 1e-6, "blurred sb %.12g vs quadrature %.12g", direct,
                  conv);
    printf("jitter 0.014\": adaptive σ %.4f\" -> %.4f\", peak -%.1f%%\n", s0.sigma * d.scale,
           s1.sigma * d.scale, 100 * (1 - s1.peak / s0.peak));
    wf_psf_free(psf);
}
END_TEST

START_TEST(test_bad_input)
{
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    wf_psf *psf = NULL;
    double lam = 1000.0, bad = -5.0, w0 = 0.0;
    o.sca = 19;
    ck_assert_int_eq(wf_psf_build_optics(&o, &lam, NULL, 1, &psf), WF_ERR_RANGE);
    assert_message_has("SCA 19");
    o.sca = 1, o.pupil_bin = 5;
    ck_assert_int_eq(wf_psf_build_optics(&o, &lam, NULL, 1, &psf), WF_ERR_RANGE);
    assert_message_has("pupil_bin 5");
    o.pupil_bin = 8;
    ck_assert_int_eq(wf_psf_build_optics(&o, &bad, NULL, 1, &psf), WF_ERR_RANGE);
    assert_message_has("wavelength");
    ck_assert_int_eq(wf_psf_build_optics(&o, &lam, &w0, 1, &psf), WF_ERR_RANGE);
    assert_message_has("weights");
    ck_assert_int_eq(wf_psf_build_optics(&o, &lam, NULL, 0, &psf), WF_ERR_RANGE);
    ck_assert_ptr_null(psf);
    /* memory bound */
    o.max_bytes = 1 << 20;
    ck_assert_int_eq(wf_psf_build_optics(&o, &lam, NULL, 1, &psf), WF_ERR_NOMEM);
    assert_message_has("bound");
    o.max_bytes = 0;
    /* missing data */
    snprintf(o.data_dir, sizeof o.data_dir, "%s", "/nonexistent/wfisim-data");
    ck_assert_int_eq(wf_psf_build_optics(&o, &lam, NULL, 1, &psf), WF_ERR_IO);
    assert_message_has("RST_WIM_Filter_skinny_SCA_1.fits.gz");
    o.data_dir[0] = '\0';
    assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    double v[4];
    d.nx = 0;
    ck_assert_int_eq(wf_psf_draw(psf, &d, v), WF_ERR_RANGE);
    d.nx = d.ny = 2, d.scale = 0;
    ck_assert_int_eq(wf_psf_draw(psf, &d, v), WF_ERR_RANGE);
    d.scale = 0.11, d.jitter = -1;
    ck_assert_int_eq(wf_psf_draw(psf, &d, v), WF_ERR_RANGE);
    assert_message_has("jitter");
    d.jitter = 0, d.galsim = 2;
    ck_assert_int_eq(wf_psf_draw(psf, &d, v), WF_ERR_RANGE);
    assert_message_has("galsim 2");
    wf_psf_free(psf);
}
END_TEST

START_TEST(test_period_window)
{
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.pupil_bin = 8;
    double lam = 1000.0;
    wf_psf *psf;
    assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
    wf_psf_info info;
    assert_ok(wf_psf_get_info(psf, &info));
    /* a stamp wider than the period is zero beyond ±T/2 instead of repeating the PSF */
    int n = (int)(1.5 * info.period_arcsec / 0.11) | 1;
    double *img = malloc(sizeof(double) * n * n);
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = n, d.cx = d.cy = (n - 1) / 2.0;
    assert_ok(wf_psf_draw(psf, &d, img));
    ck_assert_double_eq(img[0], 0.0);
    ck_assert(img[(n / 2) * n + n / 2] > 0.1);
    free(img);
    wf_psf_free(psf);
}
END_TEST

START_TEST(test_cache)
{
    wf_psf_cache *c;
    assert_ok(wf_psf_cache_create(64 << 20, &c));
    wf_psf_request r;
    memset(&r, 0, sizeof r);
    wf_psf_optics_default(&r.optics);
    r.optics.pupil_bin = 8;
    r.nlambda = 1, r.lambda_nm[0] = 1059.5, r.weight[0] = 1;
    wf_psf_draw_opts_default(&r.draw);
    r.draw.nx = r.draw.ny = 48, r.draw.cx = r.draw.cy = 23.5;
    const wf_psf_table *t1, *t2, *t3;
    assert_ok(wf_psf_cache_get(c, &r, &t1));
    assert_ok(wf_psf_cache_get(c, &r, &t2));
    ck_assert_ptr_eq(t1, t2);
    ck_assert(t1->sum > 0.95 && t1->sum < 1.0);
    r.draw.scale = 0.0275, r.draw.pixel = 0, r.draw.nx = r.draw.ny = 96, r.draw.cx = r.draw.cy = 47.5;
    assert_ok(wf_psf_cache_get(c, &r, &t3));
    ck_assert_ptr_ne(t3, t1);
    wf_psf_cache_stats st;
    wf_psf_cache_get_stats(c, &st);
    ck_assert_int_eq(st.tables, 2);
    ck_assert_int_eq(st.models_built, 1); /* the second table reused the coefficients */
    ck_assert_int_eq(st.requests, 3);
    ck_assert(st.bytes <= st.max_bytes);
    /* t1 stays valid and unchanged while more tables are added */
    double first = t1->data[24 * 48 + 24];
    for (int k = 0; k < 12; k++) {
        r.lambda_nm[0] = 1000.0 + 10 * k;
        assert_ok(wf_psf_cache_get(c, &r, &t3));
    }
    ck_assert_double_eq(t1->data[24 * 48 + 24], first);
    /* the no-pixel, centred, square table is what the profile drawer takes */
    wf_psf_image im;
    ck_assert_int_eq(wf_psf_table_image(t1, &im), WF_ERR_INPUT); /* t1 has the pixel */
    assert_ok(wf_psf_table_image(t3, &im));
    ck_assert_int_eq(im.n, 96);
    ck_assert_double_eq(im.scale_arcsec, 0.0275);
    ck_assert_ptr_eq(im.pix, t3->data);
    wf_psf_cache_destroy(c);

    /* a bound too small for the table itself */
    assert_ok(wf_psf_cache_create(1000, &c));
    ck_assert_int_eq(wf_psf_cache_get(c, &r, &t1), WF_ERR_NOMEM);
    assert_message_has("bound");
    wf_psf_cache_destroy(c);
}
END_TEST

/* ---- data files ------------------------------------------------------------------------- */

START_TEST(test_aberrations_file)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    wf_aberrations c, ll, far;
    assert_ok(wf_pupil_aberrations_load(data, 1, 2044, 2044, &c));
    ck_assert_double_eq(c.z[1], 0.0);
    ck_assert_double_eq(c.z[2], 0.0);
    ck_assert_double_eq(c.z[3], 0.0);
    ck_assert_double_eq(c.lambda_ref_nm, 1293.0);
    /* SCA 1: the low-x, low-y corner is point 2 (x -20.36 mm, y +20.73 mm, y flipped) */
    double x = 0.5 * ((-20.36 - 20.37) / 0.01) + 2044, y = 2044 - 0.5 * (20.73 + 20.73) / 0.01;
    assert_ok(wf_pupil_aberrations_load(data, 1, x, y, &ll));
    ck_assert_double_eq_tol(ll.z[4], -0.00313, 1e-12);
    ck_assert_double_eq_tol(ll.z[22], 0.00098, 1e-12);
    /* off the SCA: the nearest corner's values */
    assert_ok(wf_pupil_aberrations_load(data, 1, -500, -900, &far));
    ck_assert_double_eq_tol(far.z[4], -0.00313, 1e-12);
    /* the centre is the bilinear mean of the corners, not the centre point (-0.01499) */
    ck_assert_msg(fabs(c.z[4] - (-0.00313 - 0.03241 - 0.02681 + 0.00423) / 4) < 5e-4,
                  "Z4 at centre %g", c.z[4]);
    ck_assert_int_eq(wf_pupil_aberrations_load(data, 1, NAN, 5, &c), WF_ERR_RANGE);
    ck_assert_int_eq(wf_pupil_aberrations_load(data, 0, 5, 5, &c), WF_ERR_RANGE);

    /* a malformed file names file, line and column */
    const char *dir = wf_test_tmpdir();
    ck_assert_ptr_nonnull(dir);
    char path[4200];
    snprintf(path, sizeof path, "%s/Roman_Cycle-9_WFI_zim_zernikes_082623_03.txt", dir);
    FILE *f = fopen(path, "w");
    ck_assert_ptr_nonnull(f);
    fputs("1 0 0 0 0 1 2 3\n", f);
    fclose(f);
    ck_assert_int_eq(wf_pupil_aberrations_load(dir, 3, 2044, 2044, &c), WF_ERR_INPUT);
    assert_message_has("_03.txt:1: column 9");
}
END_TEST

/* PSFs move across the SCA and the long-wave group uses its own mask. */
START_TEST(test_field_and_group)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    snprintf(o.data_dir, sizeof o.data_dir, "%s", data);
    o.pupil_bin = 8;
    double lam = 1293.0;
    enum { N = 64 };
    double a[N * N], b[N * N];
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = N, d.cx = d.cy = 31.5;
    img_stats sa, sb;
    wf_psf *psf;
    assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
    assert_ok(wf_psf_draw(psf, &d, a));
    wf_psf_info info;
    assert_ok(wf_psf_get_info(psf, &info));
    ck_assert(strstr(info.pupil_source, "skinny_SCA_1") != NULL);
    wf_psf_free(psf);
    o.x = 10, o.y = 4080;
    assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
    assert_ok(wf_psf_draw(psf, &d, b));
    wf_psf_free(psf);
    image_stats(a, N, N, &sa);
    image_stats(b, N, N, &sb);
    printf("SCA 1 J129 centre vs corner: g1 %+.5f vs %+.5f, g2 %+.5f vs %+.5f\n", sa.g1, sb.g1,
           sa.g2, sb.g2);
    ck_assert(fabs(sa.g1 - sb.g1) + fabs(sa.g2 - sb.g2) > 1e-3);
    o.x = o.y = 2044, o.group = WF_PUPIL_LONG;
    lam = 1841.8;
    assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
    assert_ok(wf_psf_get_info(psf, &info));
    ck_assert(strstr(info.pupil_source, "F184_SCA_1") != NULL);
    wf_psf_free(psf);
}
END_TEST

/* ---- GalSim ------------------------------------------------------------------------------ */

static int read_ref(const char *dir, const char *ext, double *img, double *lam, double *scale)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/psf_sca01.fits.gz", dir);
    fitsfile *f;
    int st = 0;
    if (fits_open_diskfile(&f, path, READONLY, &st)) return st;
    fits_movnam_hdu(f, IMAGE_HDU, (char *)ext, 0, &st);
    fits_read_key_dbl(f, "LAM_NM", lam, NULL, &st);
    fits_read_key_dbl(f, "PIXSCALE", scale, NULL, &st);
    long fp[2] = {1, 1};
    fits_read_pix(f, TDOUBLE, fp, REF_N * REF_N, NULL, img, NULL, &st);
    int s2 = 0;
    fits_close_file(f, &s2);
    return st;
}

/* The number after "field": inside the object "key" of the summary JSON (index-th element
 * when the value is an array). */
static double json_number(const char *text, const char *key, const char *field, int index)
{
    char pat[128];
    snprintf(pat, sizeof pat, "\"%s\"", key);
    const char *p = strstr(text, pat);
    ck_assert_msg(p != NULL, "summary lacks %s", key);
    snprintf(pat, sizeof pat, "\"%s\"", field);
    p = strstr(p, pat);
    ck_assert_msg(p != NULL, "summary %s lacks %s", key, field);
    p = strchr(p, ':') + 1;
    while (*p == ' ' || *p == '\n' || *p == '[') p++;
    for (int i = 0; i < index; i++) p = strchr(p, ',') + 1;
    return strtod(p, NULL);
}

static char *read_text(const char *path)
{
    FILE *f = fopen(path, "r");
    if (!f) return NULL;
    char *buf = calloc(1, 1 << 16);
    size_t n = fread(buf, 1, (1 << 16) - 1, f);
    buf[n] = '\0';
    fclose(f);
    return buf;
}

/* GalSim's Quintic interpolant (its Interpolant.cpp formula); its Fourier response is
 * sim/optics/psf.c's (wf_psf_draw_opts.galsim). */
static double quintic(double x)
{
    x = fabs(x);
    if (x <= 1) return 1 + x * x * x * (-95. / 12 + x * (23. / 2 + x * (-55. / 12)));
    if (x <= 2) return (x - 1) * (x - 2) * (-23. / 4 + x * (29. / 2 + x * (-83. / 8 + x * (55. / 24))));
    if (x <= 3) return (x - 2) * (x - 3) * (x - 3) * (-9. / 4 + x * (25. / 12 + x * (-11. / 24)));
    return 0;
}

/* GalSim's Roman getPSF samples the PSF at λ/(N dx), N = info.galsim_n (sim/optics/psf.h). */
static double galsim_sample_scale(const wf_psf_info *info, double lam)
{
    return lam * 1e-9 / (info->galsim_n * info->pupil_dx) * ARCSEC_PER_RAD;
}

/* GalSim's method='no_pixel' on an OpticalPSF: our PSF sampled on its grid (flux per sample,
 * a sample at the centre), interpolated in real space with the Quintic kernel. */
static void galsim_no_pixel(const wf_psf *psf, double s0, double scale, double *out)
{
    double half = (0.5 * REF_N + 4) * scale;
    int k0 = -(int)ceil(half / s0) - 3, m = 2 * (-k0) + 1;
    double *smp = malloc(sizeof(double) * m * m);
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = m, d.scale = s0, d.cx = d.cy = -k0, d.pixel = 0;
    assert_ok(wf_psf_draw(psf, &d, smp));
    for (int j = 0; j < REF_N; j++)
        for (int i = 0; i < REF_N; i++) {
            double ux = (i - 0.5 * (REF_N - 1)) * scale / s0 - k0;
            double uy = (j - 0.5 * (REF_N - 1)) * scale / s0 - k0;
            int ax = (int)floor(ux) - 2, ay = (int)floor(uy) - 2;
            double wx[6], wy[6], v = 0;
            for (int k = 0; k < 6; k++) wx[k] = quintic(ux - (ax + k)), wy[k] = quintic(uy - (ay + k));
            for (int l = 0; l < 6; l++) {
                double r = 0;
                for (int k = 0; k < 6; k++) r += wx[k] * smp[(ay + l) * m + ax + k];
                v += wy[l] * r;
            }
            out[j * REF_N + i] = v * scale * scale / (s0 * s0);
        }
    free(smp);
}

typedef struct ref_case {
    const char *band;
    int bin;
    int over;           /* 0: *_NATIVE (0.11", pixel), 1: *_OVER4 (0.0275", no pixel) */
    double tol_sum;     /* |Δsum| / sum, wfisim exact vs GalSim */
    double tol_peak, tol_core, tol_sigma, tol_g;
} ref_case;

/* Tolerances of the exact comparison, each a little above what is reached (docs/OPTICS.md):
 *  NATIVE: GalSim's FFT draw multiplies the OTF by its Quintic's response at the Nyquist
 *    sampling (0.54 at the cut-off; wf_psf_draw_opts.galsim), which is the 0.95% (Y) / 0.43% (H) peak and ≤1.17% core
 *    difference; its 192-pixel FFT wrap folds 0.2% more flux into the pupil_bin 4 Y106 stamp
 *    (our sum is the unfolded one).
 *  OVER4: GalSim's real-space Quintic interpolation from samples at exactly Nyquist rings by
 *    up to 5% of the peak (with negative pixels) and moves 0.8% of the Y106 flux into the
 *    stamp. The "as GalSim renders" check below reproduces all of it to < 1e-4. */
static const ref_case ref_cases[] = {
    {"Y106", 8, 0, 0.001, 0.010, 0.0125, 0.010, 0.001},
    {"Y106", 8, 1, 0.010, 0.010, 0.020, 0.020, 0.0015},
    {"Y106", 4, 0, 0.0025, 0.010, 0.0125, 0.010, 0.001},
    {"Y106", 4, 1, 0.010, 0.010, 0.020, 0.020, 0.0015},
    {"H158", 8, 0, 0.001, 0.010, 0.010, 0.010, 0.001},
    {"H158", 8, 1, 0.001, 0.010, 0.050, 0.025, 0.0015},
    {"H158", 4, 0, 0.001, 0.010, 0.010, 0.010, 0.001},
    {"H158", 4, 1, 0.001, 0.010, 0.050, 0.025, 0.0015},
};

START_TEST(test_galsim_reference)
{
    const char *ref = wf_test_reference_dir();
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(ref, "../shared/reference/galsim");
    WF_SKIP_UNLESS(data, "../shared/data");
    char jpath[4200];
    snprintf(jpath, sizeof jpath, "%s/psf_sca01_summary.json", ref);
    char *json = read_text(jpath);
    ck_assert_ptr_nonnull(json);
    double *g = malloc(sizeof(double) * REF_N * REF_N), *o = malloc(sizeof(double) * REF_N * REF_N),
           *e = malloc(sizeof(double) * REF_N * REF_N);
    printf("%-22s %8s %9s %9s %8s %8s %8s %8s | as GalSim: %8s %8s | build+draw\n", "image",
           "sum", "dsum", "dpeak", "dcore", "dsigma", "dg1", "dg2", "maxdiff", "dsum");
    for (size_t c = 0; c < sizeof ref_cases / sizeof *ref_cases; c++) {
        const ref_case *rc = &ref_cases[c];
        char ext[64];
        snprintf(ext, sizeof ext, "%s_SCA01_PB%d_%s", rc->band, rc->bin, rc->over ? "OVER4" : "NATIVE");
        double lam, scale;
        ck_assert_msg(read_ref(ref, ext, g, &lam, &scale) == 0, "cannot read %s", ext);
        ck_assert_double_eq_tol(lam, json_number(json, ext, "lam_nm", 0), 1e-6);

        double t0 = now_s();
        wf_psf_optics opt;
        wf_psf_optics_default(&opt);
        opt.pupil_bin = rc->bin;
        snprintf(opt.data_dir, sizeof opt.data_dir, "%s", data);
        wf_psf *psf;
        assert_ok(wf_psf_build_optics(&opt, &lam, NULL, 1, &psf));
        wf_psf_draw_opts d;
        wf_psf_draw_opts_default(&d);
        d.nx = d.ny = REF_N, d.cx = d.cy = 0.5 * (REF_N - 1); /* GalSim's true centre */
        d.scale = scale, d.pixel = !rc->over;
        assert_ok(wf_psf_draw(psf, &d, o));
        double t1 = now_s();

        /* as GalSim renders it */
        wf_psf_info info;
        assert_ok(wf_psf_get_info(psf, &info));
        double s0 = galsim_sample_scale(&info, lam);
        if (rc->over) {
            galsim_no_pixel(psf, s0, scale, e);
        } else {
            d.galsim = 1;
            assert_ok(wf_psf_draw(psf, &d, e));
        }
        img_stats sg, so, se;
        image_stats(g, REF_N, REF_N, &sg);
        image_stats(o, REF_N, REF_N, &so);
        image_stats(e, REF_N, REF_N, &se);
        double dsum = so.sum / sg.sum - 1, dpeak = so.peak / sg.peak - 1;
        double dcore = core_diff(o, g, REF_N, &sg), dsig = so.sigma / sg.sigma - 1;
        double emax = max_diff(e, g, REF_N * REF_N, sg.peak), esum = se.sum / sg.sum - 1;
        printf("%-22s %8.5f %+9.2e %+8.3f%% %7.3f%% %+7.3f%% %+8.5f %+8.5f | %9.1e %+9.1e | %.3f s\n",
               ext, so.sum, dsum, 100 * dpeak, 100 * dcore, 100 * dsig, so.g1 - sg.g1,
               so.g2 - sg.g2, emax, esum, t1 - t0);

        /* exact rendering against GalSim's */
        ck_assert_msg(fabs(dsum) < rc->tol_sum, "%s: sum %.6f vs %.6f", ext, so.sum, sg.sum);
        ck_assert_msg(fabs(dpeak) < rc->tol_peak, "%s: peak %+.3f%%", ext, 100 * dpeak);
        ck_assert_msg(dcore < rc->tol_core, "%s: 3x3 core differs by %.3f%% of the peak", ext,
                      100 * dcore);
        ck_assert_msg(fabs(dsig) < rc->tol_sigma, "%s: sigma %+.3f%%", ext, 100 * dsig);
        ck_assert_msg(fabs(so.g1 - sg.g1) < rc->tol_g && fabs(so.g2 - sg.g2) < rc->tol_g,
                      "%s: g (%.5f, %.5f) vs (%.5f, %.5f)", ext, so.g1, so.g2, sg.g1, sg.g2);
        ck_assert_msg(fabs(so.xc - sg.xc) < 0.01 && fabs(so.yc - sg.yc) < 0.01,
                      "%s: centroid (%.3f, %.3f) vs (%.3f, %.3f): orientation", ext, so.xc, so.yc,
                      sg.xc, sg.yc);

        /* GalSim's rendering of our PSF is GalSim's image: same optics */
        ck_assert_msg(emax < 1e-4, "%s: as GalSim renders, max |diff| %.2e of the peak", ext, emax);
        ck_assert_msg(fabs(se.peak / sg.peak - 1) < 1e-4, "%s: as GalSim renders, peak", ext);
        ck_assert_msg(fabs(se.sigma / sg.sigma - 1) < 1e-4, "%s: as GalSim renders, sigma", ext);
        ck_assert_msg(fabs(se.g1 - sg.g1) < 1e-5 && fabs(se.g2 - sg.g2) < 1e-5,
                      "%s: as GalSim renders, shape", ext);
        /* the unfolded sum against GalSim's FFT wrap (NATIVE); exact for the real-space draw */
        double sum_tol = rc->over ? 1e-5 : rc->bin == 4 && rc->band[0] == 'Y' ? 0.0025 : 3e-4;
        ck_assert_msg(fabs(esum) < sum_tol, "%s: as GalSim renders, sum %+.2e", ext, esum);
        wf_psf_free(psf);
    }
    free(g), free(o), free(e), free(json);
}
END_TEST

/* Our adaptive moments on GalSim's images give the HSM values of the summary JSON, so the
 * moment comparison above measures what GalSim reports. */
START_TEST(test_moments_reproduce_hsm)
{
    const char *ref = wf_test_reference_dir();
    WF_SKIP_UNLESS(ref, "../shared/reference/galsim");
    char jpath[4200];
    snprintf(jpath, sizeof jpath, "%s/psf_sca01_summary.json", ref);
    char *json = read_text(jpath);
    ck_assert_ptr_nonnull(json);
    double *g = malloc(sizeof(double) * REF_N * REF_N);
    for (size_t c = 0; c < sizeof ref_cases / sizeof *ref_cases; c++) {
        char ext[64];
        snprintf(ext, sizeof ext, "%s_SCA01_PB%d_%s", ref_cases[c].band, ref_cases[c].bin,
                 ref_cases[c].over ? "OVER4" : "NATIVE");
        double lam, scale;
        ck_assert_int_eq(read_ref(ref, ext, g, &lam, &scale), 0);
        img_stats s;
        image_stats(g, REF_N, REF_N, &s);
        ck_assert_msg(fabs(s.sum / json_number(json, ext, "sum", 0) - 1) < 1e-6, "%s sum", ext);
        ck_assert_msg(fabs(s.peak / json_number(json, ext, "peak", 0) - 1) < 1e-6, "%s peak", ext);
        double hs = json_number(json, ext, "hsm_sigma_arcsec", 0);
        ck_assert_msg(fabs(s.sigma * scale / hs - 1) < 2e-4, "%s: σ %.6f vs HSM %.6f", ext,
                      s.sigma * scale, hs);
        ck_assert_msg(fabs(s.g1 - json_number(json, ext, "hsm_g1g2", 0)) < 2e-5 &&
                          fabs(s.g2 - json_number(json, ext, "hsm_g1g2", 1)) < 2e-5,
                      "%s: g vs HSM", ext);
    }
    free(g);
    free(json);
}
END_TEST

/* pupil_bin 8 against 2 (the finest the test budget allows; docs/OPTICS.md has 8 vs 1). */
START_TEST(test_binning_8_vs_2)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    enum { N = 64 };
    double img[2][N * N];
    img_stats s[2];
    int bins[2] = {8, 2};
    double lam = 1059.5116430916528, secs[2];
    for (int k = 0; k < 2; k++) {
        wf_psf_optics o;
        wf_psf_optics_default(&o);
        snprintf(o.data_dir, sizeof o.data_dir, "%s", data);
        o.pupil_bin = bins[k];
        double t0 = now_s();
        wf_psf *psf;
        assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
        wf_psf_draw_opts d;
        wf_psf_draw_opts_default(&d);
        d.nx = d.ny = N, d.cx = d.cy = 31.5;
        assert_ok(wf_psf_draw(psf, &d, img[k]));
        secs[k] = now_s() - t0;
        image_stats(img[k], N, N, &s[k]);
        wf_psf_free(psf);
    }
    double dmax = max_diff(img[0], img[1], N * N, s[1].peak);
    printf("Y106 SCA 1 native 64x64, pupil_bin 8 vs 2: peak %+.2f%%, sigma %+.2f%%, max |diff| "
           "%.2f%% of peak, sum %+.1e; %.2f s vs %.2f s\n", 100 * (s[0].peak / s[1].peak - 1),
           100 * (s[0].sigma / s[1].sigma - 1), 100 * dmax, s[0].sum - s[1].sum, secs[0], secs[1]);
    ck_assert(fabs(s[0].peak / s[1].peak - 1) < 0.03);
    ck_assert(fabs(s[0].sigma / s[1].sigma - 1) < 0.02);
}
END_TEST

/* ---- an independent reference, every filter (issue 28) ----------------------------------- */

typedef struct indep_case {
    const char *band;
    int sca, bin;
    double issue_pct; /* wfisim − GalSim peak reported in issue 28 (%), NAN: not reported */
} indep_case;

/* One more SCA for each filter (SCA 1 has GalSim's own images above); J129, F184, H158 and
 * Z087 at the SCAs and pupil_bin of the issue's comparison. */
static const indep_case indep_cases[] = {
    {"R062", 3, 8, NAN},   {"Z087", 16, 4, +0.5}, {"Y106", 9, 8, NAN},  {"J129", 7, 8, -1.2},
    {"H158", 5, 8, -0.5},  {"F184", 12, 8, +0.7}, {"K213", 18, 8, NAN}, {"W146", 14, 8, NAN},
};

#define INDEP_N 64

/* tests/psf_reference.py's image (NN nodes Gauss-Legendre per pixel, its own pupil, Zernikes
 * and Fourier integral): 1 read, 0 when numpy/astropy are missing (skip), fails otherwise. */
static int read_independent(const char *data, const indep_case *c, double lam, double *img)
{
    char cmd[4400];
    snprintf(cmd, sizeof cmd, "/usr/bin/python3 tests/psf_reference.py '%s' %s %d %d %.17g %d 0.11",
             data, c->band, c->sca, c->bin, lam, INDEP_N);
    FILE *p = popen(cmd, "r");
    ck_assert_msg(p != NULL, "cannot run %s", cmd);
    char head[256] = "";
    if (!fgets(head, sizeof head, p) || !strncmp(head, "NO_NUMPY", 8)) {
        pclose(p);
        return 0;
    }
    ck_assert_msg(!strncmp(head, "# peak", 6), "%s: first line '%s'", cmd, head);
    int n = 0;
    while (n < INDEP_N * INDEP_N && fscanf(p, "%lf", &img[n]) == 1) n++;
    int rc = pclose(p);
    ck_assert_msg(n == INDEP_N * INDEP_N && rc == 0, "%s: %d values, exit %d", cmd, n, rc);
    return 1;
}

/* Every filter at one more SCA against a PSF computed independently (tests/psf_reference.py:
 * numpy, the pupil field's Fourier integral evaluated directly at Gauss-Legendre nodes inside
 * each pixel, GalSim's conventions read from its documentation), 64x64 native with the pixel,
 * centred as GalSim's drawImage centres. wfisim's exact draw equals it to round-off.
 * GalSim's rendering of the same PSF (wf_psf_draw_opts.galsim) moves the peak by the amounts
 * issue 28 measured against GalSim 2.8.4: its peak differences are GalSim's Quintic
 * interpolation of a Nyquist-sampled image, not an optics difference. */
START_TEST(test_independent_reference)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    if (access("/usr/bin/python3", X_OK) != 0) WF_SKIP("/usr/bin/python3 not found");
    double *r = malloc(sizeof(double) * INDEP_N * INDEP_N), *o = malloc(sizeof(double) * INDEP_N * INDEP_N),
           *e = malloc(sizeof(double) * INDEP_N * INDEP_N);
    printf("%-5s %4s %3s %10s %10s %10s %10s %10s | %11s %8s %9s %9s %9s\n", "band", "SCA", "bin",
           "lam_nm", "peak_ref", "dpeak", "maxdiff", "dsum", "GalSim dpk", "issue", "rms", "dcen_adp",
           "dcen_sum");
    for (size_t k = 0; k < sizeof indep_cases / sizeof *indep_cases; k++) {
        const indep_case *c = &indep_cases[k];
        wf_filter f;
        assert_ok(wf_filter_parse(c->band, &f));
        wf_bandpass bp;
        assert_ok(wf_bandpass_load(f, data, &bp));
        double lam = bp.lambda_eff_nm;
        if (!read_independent(data, c, lam, r)) {
            free(r), free(o), free(e);
            WF_SKIP("/usr/bin/python3 with numpy and astropy not available");
        }
        wf_psf_optics opt;
        wf_psf_optics_default(&opt);
        opt.sca = c->sca, opt.pupil_bin = c->bin;
        assert_ok(wf_pupil_group_of_filter(c->band, &opt.group));
        snprintf(opt.data_dir, sizeof opt.data_dir, "%s", data);
        wf_psf *psf;
        assert_ok(wf_psf_build_optics(&opt, &lam, NULL, 1, &psf));
        wf_psf_draw_opts d;
        wf_psf_draw_opts_default(&d);
        d.nx = d.ny = INDEP_N, d.cx = d.cy = 0.5 * (INDEP_N - 1);
        assert_ok(wf_psf_draw(psf, &d, o));
        d.galsim = 1;
        assert_ok(wf_psf_draw(psf, &d, e));
        wf_psf_free(psf);
        img_stats sr, so, se;
        image_stats(r, INDEP_N, INDEP_N, &sr);
        image_stats(o, INDEP_N, INDEP_N, &so);
        image_stats(e, INDEP_N, INDEP_N, &se);
        double dpeak = so.peak / sr.peak - 1, dmax = max_diff(o, r, INDEP_N * INDEP_N, sr.peak);
        double dsum = so.sum / sr.sum - 1, galsim_pct = 100 * (so.peak / se.peak - 1);
        double rms = 0;
        for (int i = 0; i < INDEP_N * INDEP_N; i++) rms += (o[i] - e[i]) * (o[i] - e[i]);
        rms = sqrt(rms / (INDEP_N * INDEP_N)) / se.peak;
        /* centroids: adaptive (HSM's), and the plain first moment of the whole stamp */
        double dcen = fmax(fabs(so.xc - se.xc), fabs(so.yc - se.yc)), m[2][3] = {{0}};
        for (int j = 0; j < INDEP_N; j++)
            for (int i = 0; i < INDEP_N; i++)
                for (int t = 0; t < 2; t++) {
                    double v = (t ? e : o)[j * INDEP_N + i];
                    m[t][0] += v, m[t][1] += v * i, m[t][2] += v * j;
                }
        double dcen1 = fmax(fabs(m[0][1] / m[0][0] - m[1][1] / m[1][0]),
                            fabs(m[0][2] / m[0][0] - m[1][2] / m[1][0]));
        printf("%-5s %4d %3d %10.4f %10.7f %+10.2e %10.2e %+10.2e | %+10.3f%% %+7.1f%% %9.1e %9.1e "
               "%9.1e\n", c->band, c->sca, c->bin, lam, sr.peak, dpeak, dmax, dsum, galsim_pct,
               c->issue_pct, rms, dcen, dcen1);
        /* the issue asks 0.3% of the peak. Both sides are exact; what differs is how the
         * corners' box is taken (the reference: GalSim's min/max of the corner coordinates;
         * wfisim: the mean of the two corners on each side, which differ by 0.01 mm), up to
         * 6e-6 of the peak (1e-7 with the same box). */
        ck_assert_msg(fabs(dpeak) < 2e-5 && dmax < 2e-5 && fabs(dsum) < 1e-6,
                      "%s SCA %d: against the independent PSF peak %+.2e, max |diff| %.2e of the "
                      "peak, sum %+.2e", c->band, c->sca, dpeak, dmax, dsum);
        /* GalSim's rendering: the issue's numbers (one decimal) to their rounding */
        if (!isnan(c->issue_pct))
            ck_assert_msg(fabs(galsim_pct - c->issue_pct) <= 0.05,
                          "%s SCA %d: GalSim's rendering moves the peak by %+.3f%%, issue 28 "
                          "measured %+.1f%%", c->band, c->sca, galsim_pct, c->issue_pct);
        /* it changes the light's distribution, not its amount or centre */
        ck_assert_msg(fabs(se.sum / so.sum - 1) < 1e-4, "%s: GalSim's rendering changes the sum",
                      c->band);
    }
    free(r), free(o), free(e);
}
END_TEST

/* `wfisim psf`: the file holds what wf_psf_draw gives, with its settings in the header; bad
 * usage exits 2 and leaves no file. */
START_TEST(test_command)
{
    const char *dir = wf_test_tmpdir();
    ck_assert_ptr_nonnull(dir);
    const char *data = wf_test_data_dir();
    char out[4200], datarg[4200];
    snprintf(out, sizeof out, "%s/psf.fits", dir);
    snprintf(datarg, sizeof datarg, "%s", data ? data : "none");
    char *argv[] = {"psf", "--filter", "y106", "--sca", "1", "--pupil-bin", "8", "--size", "32",
                    "--x", "2044", "--y", "2044", "--data", datarg, "--out", out};
    int argc = (int)(sizeof argv / sizeof *argv);
    ck_assert_int_eq(wf_cmd_psf(argc, argv), 0);
    fitsfile *f;
    int st = 0;
    ck_assert_int_eq(fits_open_diskfile(&f, out, READONLY, &st), 0);
    double lam = 0, scale = 0, img[32 * 32];
    long bin = 0;
    char filt[FLEN_VALUE] = "";
    int pixresp = 0;
    fits_read_key_dbl(f, "LAM_NM", &lam, NULL, &st);
    fits_read_key_dbl(f, "PIXSCALE", &scale, NULL, &st);
    fits_read_key_lng(f, "PUPILBIN", &bin, NULL, &st);
    fits_read_key_str(f, "FILTER", filt, NULL, &st);
    fits_read_key_log(f, "PIXRESP", &pixresp, NULL, &st);
    long fp[2] = {1, 1};
    fits_read_pix(f, TDOUBLE, fp, 32 * 32, NULL, img, NULL, &st);
    int dataok = 0;
    fits_verify_chksum(f, &dataok, &dataok, &st);
    fits_close_file(f, &st);
    ck_assert_int_eq(st, 0);
    ck_assert_str_eq(filt, "Y106");
    ck_assert_int_eq(bin, 8);
    ck_assert_int_eq(pixresp, 1);
    ck_assert_double_eq(scale, 0.11);
    ck_assert_msg(lam > 1000 && lam < 1120, "effective wavelength %g", lam);
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.pupil_bin = 8;
    if (data) snprintf(o.data_dir, sizeof o.data_dir, "%s", data);
    wf_psf *psf;
    assert_ok(wf_psf_build_optics(&o, &lam, NULL, 1, &psf));
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = 32, d.cx = d.cy = 15.5;
    double want[32 * 32];
    assert_ok(wf_psf_draw(psf, &d, want));
    ck_assert_msg(max_diff(img, want, 32 * 32, 1.0) == 0.0, "file differs from the draw");
    /* --render galsim: the draw with GalSim's rendering, recorded in the header */
    char *argv5[] = {"psf", "--filter", "Y106", "--sca", "1", "--pupil-bin", "8", "--size", "32",
                     "--render", "galsim", "--data", datarg, "--out", out};
    ck_assert_int_eq(wf_cmd_psf((int)(sizeof argv5 / sizeof *argv5), argv5), 0);
    char render[FLEN_VALUE] = "";
    long gsn = 0;
    ck_assert_int_eq(fits_open_diskfile(&f, out, READONLY, &st), 0);
    fits_read_key_str(f, "RENDER", render, NULL, &st);
    fits_read_key_lng(f, "GSPUPILN", &gsn, NULL, &st);
    fits_read_pix(f, TDOUBLE, fp, 32 * 32, NULL, img, NULL, &st);
    fits_close_file(f, &st);
    ck_assert_int_eq(st, 0);
    ck_assert_str_eq(render, "galsim");
    ck_assert_int_eq(gsn, 512); /* 2 x 2.36 m / 9.44 mm = 500.2 -> 512 */
    d.galsim = 1;
    assert_ok(wf_psf_draw(psf, &d, want));
    ck_assert_msg(max_diff(img, want, 32 * 32, 1.0) == 0.0, "--render galsim differs");
    wf_psf_free(psf);

    char bad[4200];
    snprintf(bad, sizeof bad, "%s/bad.fits", dir);
    char *argv2[] = {"--filter", "Y106", "--sca", "19", "--out", bad};
    ck_assert_int_eq(wf_cmd_psf(6, argv2), 2);
    char *argv3[] = {"--filter", "Q999", "--sca", "1", "--out", bad};
    ck_assert_int_eq(wf_cmd_psf(6, argv3), 2);
    char *argv4[] = {"--filter", "Y106", "--sca", "1", "--wavelength", "1000", "--sed", "flat",
                     "--out", bad};
    ck_assert_int_eq(wf_cmd_psf(10, argv4), 2);
    char *argv6[] = {"--filter", "Y106", "--sca", "1", "--render", "quintic", "--out", bad};
    ck_assert_int_eq(wf_cmd_psf(8, argv6), 2);
    FILE *probe = fopen(bad, "r");
    ck_assert_ptr_null(probe);
    char tmp[4300];
    snprintf(tmp, sizeof tmp, "%s.tmp", bad);
    probe = fopen(tmp, "r");
    ck_assert_ptr_null(probe);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("psf");
    TCase *tc = tcase_create("psf");
    tcase_set_timeout(tc, 300);
    tcase_add_test(tc, test_zernike_values);
    tcase_add_test(tc, test_zernike_orthonormal);
    tcase_add_test(tc, test_filter_groups);
    tcase_add_test(tc, test_pupil_analytic);
    tcase_add_test(tc, test_pupil_mask_geometry);
    tcase_add_test(tc, test_pupil_gzip_in_memory);
    tcase_add_test(tc, test_fourier_sum_exact);
    tcase_add_test(tc, test_airy);
    tcase_add_test(tc, test_flux_one_period);
    tcase_add_test(tc, test_first_moments_zero);
    tcase_add_test(tc, test_pixel_integration_exact);
    tcase_add_test(tc, test_chromatic_linear);
    tcase_add_test(tc, test_draw_threads);
    tcase_add_test(tc, test_draw_czt);
    tcase_add_test(tc, test_blurs);
    tcase_add_test(tc, test_bad_input);
    tcase_add_test(tc, test_period_window);
    tcase_add_test(tc, test_cache);
    tcase_add_test(tc, test_aberrations_file);
    tcase_add_test(tc, test_field_and_group);
    tcase_add_test(tc, test_galsim_reference);
    tcase_add_test(tc, test_moments_reproduce_hsm);
    tcase_add_test(tc, test_independent_reference);
    tcase_add_test(tc, test_binning_8_vs_2);
    tcase_add_test(tc, test_command);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
