/* The coadd (analysis/coadd.c, analysis/drizzle.c): the square kernel's overlap against
 * hand-computed areas, flux conservation for a constant image and a point source, DQ
 * masking, inverse-variance weighting, products bit-identical whatever the tile height and
 * the order of the inputs, bad input refused with no product, the command's exit status,
 * and STScI's drizzle (python3-drizzle, tests/drizzle_reference.py) on the same inputs;
 * the difference image (analysis/diff.c): an epoch minus its own template is zero with
 * ERR sqrt(2) x the template's, a source added to the epoch keeps its flux, bad input. */
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "analysis/coadd.h"
#include "analysis/diff.h"
#include "analysis/drizzle.h"
#include "sim/fits/fitsout.h"
#include "sim/survey/wcs.h"
#include "tests/testutil.h"

#define IN_SCALE 0.11 /* arcsec per input pixel */
#define RA0 150.0
#define DEC0 2.0

/* ---- the kernel by hand ------------------------------------------------------------------ */

static void square(double x0, double y0, double side, double x[4], double y[4])
{
    x[0] = x0; y[0] = y0;
    x[1] = x0 + side; y[1] = y0;
    x[2] = x0 + side; y[2] = y0 + side;
    x[3] = x0; y[3] = y0 + side;
}

START_TEST(overlap_by_hand)
{
    double x[4], y[4];
    /* a unit square from the centre of pixel 0 to that of pixel 1: half of each */
    square(0.0, -0.5, 1.0, x, y);
    ck_assert_double_eq_tol(wf_drizzle_overlap(x, y, 0, 0), 0.5, 1e-15);
    ck_assert_double_eq_tol(wf_drizzle_overlap(x, y, 1, 0), 0.5, 1e-15);
    ck_assert_double_eq_tol(wf_drizzle_overlap(x, y, 0, 1), 0.0, 1e-15);
    /* offset by (0.7, 0.7) from pixel (0, 0)'s corner: 0.3^2, 0.3 x 0.7, 0.7^2 */
    square(0.2, 0.2, 1.0, x, y);
    ck_assert_double_eq_tol(wf_drizzle_overlap(x, y, 0, 0), 0.09, 1e-15);
    ck_assert_double_eq_tol(wf_drizzle_overlap(x, y, 1, 0), 0.21, 1e-15);
    ck_assert_double_eq_tol(wf_drizzle_overlap(x, y, 0, 1), 0.21, 1e-15);
    ck_assert_double_eq_tol(wf_drizzle_overlap(x, y, 1, 1), 0.49, 1e-15);
    /* a diamond of half-diagonal 0.5 about a pixel corner: area 0.5, an eighth per pixel;
     * listed clockwise, the other orientation */
    double dx[4] = {0.5, 1.0, 0.5, 0.0}, dy[4] = {1.0, 0.5, 0.0, 0.5};
    for (int j = 0; j <= 1; j++)
        for (int i = 0; i <= 1; i++) ck_assert_double_eq_tol(wf_drizzle_overlap(dx, dy, i, j), 0.125, 1e-15);
    /* the same diamond about a pixel centre lies inside it */
    double cx[4] = {0.0, 0.5, 0.0, -0.5}, cy[4] = {0.5, 0.0, -0.5, 0.0};
    ck_assert_double_eq_tol(wf_drizzle_overlap(cx, cy, 0, 0), 0.5, 1e-15);
    ck_assert_double_eq_tol(wf_drizzle_overlap(cx, cy, 1, 0), 0.0, 1e-15);
}
END_TEST

/* One drop covering two output pixels in halves: each gets half its weight and the value
 * spread over the drop's area (d pixfrac^2 / J). */
START_TEST(drop_by_hand)
{
    wf_drizzle_tile t;
    ck_assert_int_eq(wf_drizzle_tile_alloc(&t, 3, 2), WF_OK);
    wf_drizzle_tile_reset(&t, 0, 2);
    /* a 2 x 1 drop (J = 2) from x = 0 to 2 at y in [-0.5, 0.5]: pixel 0 gets 1/4, pixel 1
     * 1/2, pixel 2 1/4 of it */
    double x[4] = {0, 2, 2, 0}, y[4] = {-0.5, -0.5, 0.5, 0.5};
    ck_assert_int_eq(wf_drizzle_drop(&t, x, y, 1.0, 8.0, 4.0, 0.25, 1), 1);
    ck_assert_double_eq_tol(t.wht[0], 4.0 * 0.25, 1e-15);
    ck_assert_double_eq_tol(t.wht[1], 4.0 * 0.5, 1e-15);
    ck_assert_double_eq_tol(t.wht[2], 4.0 * 0.25, 1e-15);
    ck_assert_double_eq_tol(t.sum[1] / t.wht[1], 8.0 / 2.0, 1e-15);
    ck_assert_double_eq_tol(t.var[1], (4.0 * 0.5) * (4.0 * 0.5) * 0.25 / 4.0, 1e-15);
    ck_assert_int_eq(t.ctx[1], 1);
    ck_assert(t.wht[3] == 0); /* row 1 untouched */
    /* the same input again does not count twice in CTX, another does */
    wf_drizzle_drop(&t, x, y, 1.0, 8.0, 4.0, 0.25, 1);
    ck_assert_int_eq(t.ctx[1], 1);
    wf_drizzle_drop(&t, x, y, 1.0, 8.0, 4.0, 0.25, 2);
    ck_assert_int_eq(t.ctx[1], 2);
    wf_drizzle_tile_free(&t);
}
END_TEST

/* ---- synthetic products ------------------------------------------------------------------ */

typedef struct product {
    int nx, ny;
    double ra, dec, rot; /* CRVAL at the image centre, rotation of the pixel axes, deg */
    const char *filter;
    long exposure;
    double mjd;
    float *sci, *err;
    uint32_t *dq;
    int no_wcs;
} product;

static void product_init(product *p, int nx, int ny, double sci, double err)
{
    memset(p, 0, sizeof *p);
    p->nx = nx;
    p->ny = ny;
    p->ra = RA0;
    p->dec = DEC0;
    p->filter = "Y106";
    p->exposure = 1;
    p->mjd = 61000;
    size_t n = (size_t)nx * ny;
    p->sci = malloc(n * sizeof *p->sci);
    p->err = malloc(n * sizeof *p->err);
    p->dq = calloc(n, sizeof *p->dq);
    ck_assert(p->sci && p->err && p->dq);
    for (size_t k = 0; k < n; k++) {
        p->sci[k] = (float)sci;
        p->err[k] = (float)err;
    }
}

static void product_free(product *p)
{
    free(p->sci);
    free(p->err);
    free(p->dq);
}

/* The product's grid: a TAN grid as the coadd makes them, at the input pixel scale. */
static wf_wcs product_wcs(const product *p)
{
    wf_coadd_opts o;
    wf_coadd_opts_default(&o);
    o.ra = p->ra;
    o.dec = p->dec;
    o.nx = p->nx;
    o.ny = p->ny;
    o.pixscale = IN_SCALE;
    o.pa = p->rot;
    wf_wcs w;
    ck_assert_int_eq(wf_coadd_grid(&o, &w), WF_OK);
    w.sca = 1;
    return w;
}

static void write_product(const product *p, const char *path)
{
    fitsfile *f;
    int status = 0;
    unlink(path);
    fits_create_file(&f, path, &status);
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_write_key_str(f, "FILTER", (char *)p->filter, "", &status);
    fits_write_key_lng(f, "EXPOSURE", p->exposure, "", &status);
    fits_write_key_lng(f, "SCA", 1, "", &status);
    fits_write_key_dbl(f, "MJD-OBS", p->mjd, 10, "", &status);
    long naxes[2] = {p->nx, p->ny};
    wf_wcs w = product_wcs(p);
    const char *names[3] = {"SCI", "ERR", "DQ"};
    for (int k = 0; k < 3; k++) {
        fits_create_img(f, k == 2 ? ULONG_IMG : FLOAT_IMG, 2, naxes, &status);
        fits_write_key_str(f, "EXTNAME", (char *)names[k], "", &status);
        ck_assert_int_eq(status, 0);
        if (!p->no_wcs) ck_assert_int_eq(wf_wcs_write_header(&w, f, path), WF_OK);
        if (k == 2) fits_write_img(f, TUINT, 1, (LONGLONG)p->nx * p->ny, p->dq, &status);
        else fits_write_img(f, TFLOAT, 1, (LONGLONG)p->nx * p->ny, k ? p->err : p->sci, &status);
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

static char *tmp_path(const char *name)
{
    static char buf[8][512];
    static int k;
    char *s = buf[k++ % 8];
    snprintf(s, sizeof buf[0], "%s/%s", wf_test_tmpdir(), name);
    return s;
}

/* One plane of a coadd (NULL on failure); n gets the pixel count. */
static void *read_plane(const char *path, const char *hdu, int type, long *nx, long *ny)
{
    fitsfile *f;
    int status = 0;
    long naxes[2] = {0, 0};
    fits_open_file(&f, path, READONLY, &status);
    fits_movnam_hdu(f, ANY_HDU, (char *)hdu, 0, &status);
    fits_get_img_size(f, 2, naxes, &status);
    size_t n = (size_t)naxes[0] * naxes[1];
    void *buf = malloc(n * 8);
    fits_read_img(f, type, 1, (LONGLONG)n, NULL, buf, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_msg(status == 0, "reading %s of %s: cfitsio %d", hdu, path, status);
    *nx = naxes[0];
    *ny = naxes[1];
    return buf;
}

static wf_coadd_opts opts(int nx, int ny)
{
    wf_coadd_opts o;
    wf_coadd_opts_default(&o);
    o.ra = RA0;
    o.dec = DEC0;
    o.nx = nx;
    o.ny = ny;
    o.quiet = 1;
    return o;
}

/* A TAN-SIP WCS written by wf_wcs_write_header reads back with every field and maps pixels
 * to the same sky; a header without CTYPE is refused naming the HDU. */
START_TEST(wcs_header_round_trip)
{
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    wf_wcs w, r;
    ck_assert_int_eq(wf_wcs_for_sca(&fp, 71.0, -53.0, 30.0, 7, &w), WF_OK);
    w.a_order = 3;
    w.a[2][0] = 1.5e-6;
    w.a[1][2] = -2.5e-9;
    w.b[0][2] = 3.25e-6;
    w.b[3][0] = 7e-10;
    const char *path = tmp_path("hdr.fits");
    fitsfile *f;
    int status = 0;
    unlink(path);
    long naxes[2] = {WF_WCS_NPIX, WF_WCS_NPIX};
    fits_create_file(&f, path, &status);
    fits_create_img(f, BYTE_IMG, 2, naxes, &status);
    ck_assert_int_eq(wf_wcs_write_header(&w, f, path), WF_OK);
    ck_assert_int_eq(wf_wcs_read_header(f, path, &r), WF_OK);
    ck_assert_int_eq(r.a_order, 3);
    ck_assert_int_eq(r.sca, 7);
    ck_assert_int_eq(r.nx, WF_WCS_NPIX);
    ck_assert(r.a[2][0] == w.a[2][0] && r.a[1][2] == w.a[1][2] && r.b[0][2] == w.b[0][2] && r.b[3][0] == w.b[3][0]);
    for (int k = 0; k < 4; k++) ck_assert(r.cd[k / 2][k % 2] == w.cd[k / 2][k % 2]);
    ck_assert(r.crval[0] == w.crval[0] && r.crval[1] == w.crval[1] && r.crpix[0] == w.crpix[0]);
    double ra1, dec1, ra2, dec2;
    ck_assert_int_eq(wf_wcs_pix2world(&w, 3000.25, 17.5, &ra1, &dec1), WF_OK);
    ck_assert_int_eq(wf_wcs_pix2world(&r, 3000.25, 17.5, &ra2, &dec2), WF_OK);
    ck_assert(ra1 == ra2 && dec1 == dec2);
    /* no WCS at all */
    fits_create_img(f, BYTE_IMG, 2, naxes, &status);
    fits_write_key_str(f, "EXTNAME", "SCI", "", &status);
    ck_assert_int_eq(wf_wcs_read_header(f, path, &r), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), "SCI has no WCS"), "%s", wf_error_message());
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}
END_TEST

/* ---- conservation ------------------------------------------------------------------------ */

/* A constant image drizzled onto a finer rotated grid inside its footprint: every output
 * pixel is the input's rate times the pixel-area ratio (0.0575 / 0.11)^2, so the flux in
 * any region is conserved, to float32 rounding (1e-6 asked). */
START_TEST(constant_image_flux)
{
    product p;
    product_init(&p, 64, 64, 5.0, 1.0);
    p.rot = 30;
    const char *in = tmp_path("const.fits"), *out = tmp_path("const_coadd.fits");
    write_product(&p, in);
    double ratio2 = (WF_COADD_PIXSCALE / IN_SCALE) * (WF_COADD_PIXSCALE / IN_SCALE);
    for (int pf = 0; pf < 2; pf++) {
        wf_coadd_opts o = opts(60, 50);
        o.pa = -12;
        o.pixfrac = pf ? 1.0 : 0.7;
        const char *const paths[1] = {in};
        ck_assert_int_eq(wf_coadd_run(paths, 1, &o, out), WF_OK);
        long nx, ny;
        float *sci = read_plane(out, "SCI", TFLOAT, &nx, &ny);
        int *ctx = read_plane(out, "CTX", TINT, &nx, &ny);
        double sum = 0, worst = 0;
        for (long k = 0; k < nx * ny; k++) {
            ck_assert_int_eq(ctx[k], 1);
            sum += sci[k];
            worst = fmax(worst, fabs(sci[k] / (5.0 * ratio2) - 1));
        }
        ck_assert_msg(worst < 1e-6, "pixfrac %g: worst relative error %g", o.pixfrac, worst);
        /* the flux in the output: the rate times the area covered, in input pixels */
        double expect = 5.0 * (double)(nx * ny) * ratio2;
        ck_assert_msg(fabs(sum / expect - 1) < 1e-6, "flux %.9g, expected %.9g", sum, expect);
        free(sci);
        free(ctx);
    }
    product_free(&p);
}
END_TEST

/* A point source (one bright pixel on zero) keeps its flux through the drizzle: with
 * pixfrac 1 exactly (each input pixel's weights tile the plane), with 0.7 and a single
 * input only on average over the image, so pixfrac 1 is what is asserted to 1e-6. */
START_TEST(point_source_flux)
{
    product p;
    product_init(&p, 40, 40, 0.0, 1.0);
    p.rot = 17;
    p.sci[20 * 40 + 21] = 1000.0f;
    const char *in = tmp_path("point.fits"), *out = tmp_path("point_coadd.fits");
    write_product(&p, in);
    wf_coadd_opts o = opts(70, 70);
    o.pixfrac = 1.0;
    const char *const paths[1] = {in};
    ck_assert_int_eq(wf_coadd_run(paths, 1, &o, out), WF_OK);
    long nx, ny;
    float *sci = read_plane(out, "SCI", TFLOAT, &nx, &ny);
    double sum = 0, mx = 0, my = 0;
    for (long k = 0; k < nx * ny; k++) {
        sum += sci[k];
        mx += sci[k] * (double)(k % nx);
        my += sci[k] * (double)(k / nx);
    }
    ck_assert_msg(fabs(sum - 1000.0) < 1e-3, "point source flux %.9g of 1000", sum);
    /* its centroid where the two WCSs put the pixel's centre (rotated 17 deg against the
     * output): a square drop sampled by the output pixels is centred to ~0.01 pixel */
    wf_wcs iw = product_wcs(&p), ow;
    ck_assert_int_eq(wf_coadd_grid(&o, &ow), WF_OK);
    double ra, dec, ex, ey;
    ck_assert_int_eq(wf_wcs_pix2world(&iw, 21, 20, &ra, &dec), WF_OK);
    ck_assert_int_eq(wf_wcs_world2pix(&ow, ra, dec, &ex, &ey), WF_OK);
    ck_assert_msg(hypot(mx / sum - ex, my / sum - ey) < 0.02, "centroid (%.4f, %.4f), WCS (%.4f, %.4f)", mx / sum,
                  my / sum, ex, ey);
    free(sci);
    product_free(&p);
}
END_TEST

/* Stars whose ERR carries their own shot noise, as a product's does, keep their flux: the
 * mean over 75 stars at random phases of a 21 x 21 box is 1000 within 4 standard errors at
 * pixfrac 1 and 0.7 (at 1 each star exactly: drops tile the sky). Weighting each pixel by
 * its own 1 / ERR^2 instead lost 28% (pixfrac 1) and 14% (0.7): where a bright and a faint
 * pixel's drops share an output pixel the faint one counted more. */
START_TEST(point_sources_flux)
{
    const int n = 120, step = 12;
    const double sigma = 0.7; /* input pixels: Roman's PSF is undersampled */
    product p;
    product_init(&p, n, n, 0.0, 1.0);
    p.rot = 17;
    double sx[100], sy[100];
    int ns = 0;
    uint64_t key = 7;
    for (int cy = step; cy < n - step / 2; cy += step)
        for (int cx = step; cx < n - step / 2; cx += step) {
            double fx = cx + wf_test_splitmix(&key) / 18446744073709551616.0 - 0.5;
            double fy = cy + wf_test_splitmix(&key) / 18446744073709551616.0 - 0.5;
            double g[11][11], tot = 0;
            for (int y = 0; y < 11; y++)
                for (int x = 0; x < 11; x++) {
                    double dx = cx - 5 + x - fx, dy = cy - 5 + y - fy;
                    tot += g[y][x] = exp(-(dx * dx + dy * dy) / (2 * sigma * sigma));
                }
            for (int y = 0; y < 11; y++)
                for (int x = 0; x < 11; x++) p.sci[(cy - 5 + y) * n + cx - 5 + x] = (float)(1000.0 * g[y][x] / tot);
            sx[ns] = fx;
            sy[ns++] = fy;
        }
    /* sky variance 0.01, plus the source's shot noise over 10 s */
    for (int q = 0; q < n * n; q++) p.err[q] = (float)sqrt(0.01 + p.sci[q] / 10.0);
    const char *in = tmp_path("stars.fits"), *out = tmp_path("stars_coadd.fits");
    write_product(&p, in);
    wf_wcs iw = product_wcs(&p), ow;
    const double pixfracs[2] = {1.0, 0.7};
    for (int k = 0; k < 2; k++) {
        wf_coadd_opts o = opts(240, 240);
        o.pixfrac = pixfracs[k];
        const char *const paths[1] = {in};
        ck_assert_int_eq(wf_coadd_run(paths, 1, &o, out), WF_OK);
        ck_assert_int_eq(wf_coadd_grid(&o, &ow), WF_OK);
        long nx, ny;
        float *sci = read_plane(out, "SCI", TFLOAT, &nx, &ny);
        double s1 = 0, s2 = 0, worst = 0;
        int m = 0;
        for (int i = 0; i < ns; i++) {
            double ra, dec, ex, ey;
            ck_assert_int_eq(wf_wcs_pix2world(&iw, sx[i], sy[i], &ra, &dec), WF_OK);
            ck_assert_int_eq(wf_wcs_world2pix(&ow, ra, dec, &ex, &ey), WF_OK);
            long ix = lround(ex), iy = lround(ey);
            if (ix < 10 || iy < 10 || ix >= nx - 10 || iy >= ny - 10) continue;
            double s = 0;
            for (long y = iy - 10; y <= iy + 10; y++)
                for (long x = ix - 10; x <= ix + 10; x++) s += sci[y * nx + x];
            s1 += s;
            s2 += s * s;
            worst = fmax(worst, fabs(s - 1000.0));
            m++;
        }
        ck_assert_int_ge(m, 60);
        double mean = s1 / m, se = sqrt(fmax(s2 / m - mean * mean, 0) / (m - 1));
        printf("point_sources_flux: pixfrac %.1f, %d stars, box mean %.3f, s.e. %.3f, worst %.3f\n", pixfracs[k], m,
               mean, se, worst);
        if (k == 0) ck_assert_msg(worst < 1e-2, "pixfrac 1: a star off by %g of 1000", worst);
        ck_assert_msg(fabs(mean - 1000.0) < 4 * se + 1e-2, "pixfrac %.1f: stars keep %.3f of 1000 (s.e. %.3f)",
                      pixfracs[k], mean, se);
        free(sci);
    }
    product_free(&p);
}
END_TEST

/* ---- masking and weights ----------------------------------------------------------------- */

/* Pixels flagged in DQ carry no weight: wild values under SATURATED/JUMP_DET leave SCI at
 * the constant; with --dq-mask 0 the same pixels show (so the test can fail). */
START_TEST(dq_masked)
{
    product p;
    product_init(&p, 48, 48, 2.0, 0.5);
    for (int k = 0; k < 6; k++) {
        size_t at = (size_t)(10 + 5 * k) * 48 + (size_t)(12 + 4 * k);
        p.sci[at] = 1e6f;
        p.dq[at] = k % 2 ? 0x2u : 0x4u;
    }
    const char *in = tmp_path("dq.fits"), *out = tmp_path("dq_coadd.fits");
    write_product(&p, in);
    double ratio2 = (WF_COADD_PIXSCALE / IN_SCALE) * (WF_COADD_PIXSCALE / IN_SCALE);
    const char *const paths[1] = {in};
    for (int masked = 1; masked >= 0; masked--) {
        wf_coadd_opts o = opts(80, 80);
        if (!masked) o.dq_mask = 0;
        ck_assert_int_eq(wf_coadd_run(paths, 1, &o, out), WF_OK);
        long nx, ny;
        float *sci = read_plane(out, "SCI", TFLOAT, &nx, &ny);
        float *wht = read_plane(out, "WHT", TFLOAT, &nx, &ny);
        double worst = 0, wmin = INFINITY, wmax = 0;
        for (long k = 0; k < nx * ny; k++) {
            if (!(wht[k] > 0)) continue;
            worst = fmax(worst, fabs(sci[k] / (2.0 * ratio2) - 1));
            wmin = fmin(wmin, wht[k]);
            wmax = fmax(wmax, wht[k]);
        }
        if (masked) {
            ck_assert_msg(worst < 1e-6, "masked pixels leak: %g", worst);
            ck_assert_msg(wmin < 0.9 * wmax, "no weight hole at the masked pixels");
        } else {
            ck_assert_msg(worst > 1e3, "dq_mask 0 should let the flagged values in (%g)", worst);
        }
        free(sci);
        free(wht);
    }
    product_free(&p);
}
END_TEST

/* Two inputs on one grid, rates 1 and 3 with ERR 1 and 2: weights 1 and 1/4 (INPUTS
 * WEIGHT), so SCI is (1 + 3/4) / (1 + 1/4) = 1.4 times the area ratio; ERR is 1 / sqrt(1.25) of an input's
 * ERR on one grid's pixels when the grids coincide, checked through the ratio of two
 * coadds (one input alone, both together) so the drizzle's footprint factors cancel. */
START_TEST(inverse_variance)
{
    product a, b;
    product_init(&a, 40, 40, 1.0, 1.0);
    product_init(&b, 40, 40, 3.0, 2.0);
    b.exposure = 2;
    b.mjd = 61001;
    const char *pa = tmp_path("iva.fits"), *pb = tmp_path("ivb.fits"), *out = tmp_path("iv.fits");
    const char *out1 = tmp_path("iv1.fits");
    write_product(&a, pa);
    write_product(&b, pb);
    double ratio2 = (WF_COADD_PIXSCALE / IN_SCALE) * (WF_COADD_PIXSCALE / IN_SCALE);
    wf_coadd_opts o = opts(60, 60);
    const char *const both[2] = {pa, pb}, *const one[1] = {pa};
    ck_assert_int_eq(wf_coadd_run(both, 2, &o, out), WF_OK);
    ck_assert_int_eq(wf_coadd_run(one, 1, &o, out1), WF_OK);
    long nx, ny;
    float *sci = read_plane(out, "SCI", TFLOAT, &nx, &ny);
    float *err = read_plane(out, "ERR", TFLOAT, &nx, &ny);
    float *err1 = read_plane(out1, "ERR", TFLOAT, &nx, &ny);
    int *ctx = read_plane(out, "CTX", TINT, &nx, &ny);
    for (long k = 0; k < nx * ny; k++) {
        ck_assert_int_eq(ctx[k], 2);
        ck_assert_msg(fabs(sci[k] / (1.4 * ratio2) - 1) < 1e-6, "pixel %ld: %g", k, sci[k] / ratio2);
        ck_assert_msg(fabs(err[k] / err1[k] - 1 / sqrt(1.25)) < 1e-6, "pixel %ld: ERR ratio %g", k, err[k] / err1[k]);
    }
    /* the weights as the INPUTS table records them, in the canonical (MJD) order */
    fitsfile *f;
    int status = 0, col = 0;
    double w[2] = {0, 0};
    fits_open_file(&f, out, READONLY, &status);
    fits_movnam_hdu(f, BINARY_TBL, "INPUTS", 0, &status);
    fits_get_colnum(f, CASEINSEN, "WEIGHT", &col, &status);
    fits_read_col(f, TDOUBLE, col, 1, 1, 2, NULL, w, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_double_eq_tol(w[0], 1.0, 1e-12);
    ck_assert_double_eq_tol(w[1], 0.25, 1e-12);
    free(sci);
    free(err);
    free(err1);
    free(ctx);
    product_free(&a);
    product_free(&b);
}
END_TEST

/* ---- determinism ------------------------------------------------------------------------- */

static void noisy(product *p, unsigned seed)
{
    srand(seed);
    for (int k = 0; k < p->nx * p->ny; k++) {
        p->sci[k] = (float)(rand() / (double)RAND_MAX * 10.0);
        p->err[k] = (float)(0.5 + rand() / (double)RAND_MAX);
        p->dq[k] = rand() % 50 == 0 ? 4u : 0u;
    }
}

START_TEST(tiles_and_order)
{
    product p[3];
    const char *in[3] = {tmp_path("d0.fits"), tmp_path("d1.fits"), tmp_path("d2.fits")};
    for (int i = 0; i < 3; i++) {
        product_init(&p[i], 50, 45, 0, 1);
        noisy(&p[i], 10u + (unsigned)i);
        p[i].exposure = 5 - i;
        p[i].mjd = 61000 + i;
        p[i].ra = RA0 + 0.3 * i / 3600;
        p[i].rot = 7.0 * i;
        write_product(&p[i], in[i]);
    }
    wf_coadd_opts o = opts(90, 83);
    const char *a = tmp_path("t_a.fits"), *b = tmp_path("t_b.fits"), *c = tmp_path("t_c.fits");
    const char *const fwd[3] = {in[0], in[1], in[2]}, *const rev[3] = {in[2], in[0], in[1]};
    ck_assert_int_eq(wf_coadd_run(fwd, 3, &o, a), WF_OK);
    o.tile_rows = 7;
    ck_assert_int_eq(wf_coadd_run(fwd, 3, &o, b), WF_OK);
    o.tile_rows = 1;
    ck_assert_int_eq(wf_coadd_run(rev, 3, &o, c), WF_OK);
    wf_test_assert_same_file(a, b);
    wf_test_assert_same_file(a, c);
    for (int i = 0; i < 3; i++) product_free(&p[i]);
}
END_TEST

/* ---- bad input --------------------------------------------------------------------------- */

static void expect_refused(const char *const *paths, int n, const wf_coadd_opts *o, const char *out,
                           const char *needle)
{
    unlink(out);
    wf_status st = wf_coadd_run(paths, n, o, out);
    ck_assert_int_eq(st, WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), needle), "message '%s' lacks '%s'", wf_error_message(), needle);
    ck_assert_msg(access(out, F_OK) != 0, "%s written despite the error", out);
    char tmp[600];
    snprintf(tmp, sizeof tmp, "%s.tmp", out);
    ck_assert_msg(access(tmp, F_OK) != 0, "%s left behind", tmp);
}

START_TEST(bad_input)
{
    product a, b, c;
    product_init(&a, 30, 30, 1, 1);
    product_init(&b, 30, 30, 1, 1);
    product_init(&c, 30, 30, 1, 1);
    b.filter = "J129";
    b.exposure = 2;
    c.no_wcs = 1;
    c.exposure = 3;
    const char *pa = tmp_path("ba.fits"), *pb = tmp_path("bb.fits"), *pc = tmp_path("bc.fits");
    write_product(&a, pa);
    write_product(&b, pb);
    write_product(&c, pc);
    const char *out = tmp_path("bad_coadd.fits");
    wf_coadd_opts o = opts(40, 40);
    const char *const mixed[2] = {pa, pb}, *const nowcs[2] = {pa, pc}, *const twice[2] = {pa, pa};
    expect_refused(mixed, 2, &o, out, "one filter per coadd");
    expect_refused(nowcs, 2, &o, out, "no WCS");
    expect_refused(twice, 2, &o, out, "both exposure 1 SCA 1");
    wf_coadd_opts far = o;
    far.ra = RA0 + 10;
    const char *const one[1] = {pa};
    expect_refused(one, 1, &far, out, "no input overlaps");
    /* every pixel flagged: nothing to drizzle */
    for (int k = 0; k < 900; k++) a.dq[k] = 1;
    write_product(&a, pa);
    expect_refused(one, 1, &o, out, "no good input pixel");
    product_free(&a);
    product_free(&b);
    product_free(&c);
}
END_TEST

/* --mjd keeps the inputs dated within [A, B]: the product is byte for byte the coadd of
 * those inputs alone; a range holding none is refused with no product; the command reads
 * open sides. */
START_TEST(mjd_range)
{
    product p[3];
    const char *in[3] = {tmp_path("m0.fits"), tmp_path("m1.fits"), tmp_path("m2.fits")};
    for (int i = 0; i < 3; i++) {
        product_init(&p[i], 40, 40, 0, 1);
        noisy(&p[i], 30u + (unsigned)i);
        p[i].exposure = 10 + i;
        p[i].mjd = 61000 + 100 * i;
        p[i].ra = RA0 + 0.2 * i / 3600;
        write_product(&p[i], in[i]);
    }
    wf_coadd_opts o = opts(70, 70);
    const char *all = tmp_path("m_all.fits"), *late = tmp_path("m_late.fits"), *two = tmp_path("m_two.fits");
    const char *const every[3] = {in[0], in[1], in[2]}, *const last2[2] = {in[1], in[2]};
    ck_assert_int_eq(wf_coadd_run(last2, 2, &o, two), WF_OK);
    o.mjd_lo = 61050, o.mjd_hi = 61200;
    ck_assert_int_eq(wf_coadd_run(every, 3, &o, late), WF_OK);
    wf_test_assert_same_file(late, two);
    o.mjd_lo = 61201, o.mjd_hi = 61300;
    expect_refused(every, 3, &o, all, "MJD-OBS within");
    const char *prog = wf_test_program();
    if (prog) {
        const char *log = tmp_path("m.log"), *cmd_out = tmp_path("m_cmd.fits");
        ck_assert_int_eq(wf_test_run("'%s' coadd --quiet --center %g,%g --size 70,70 --mjd 61050: --out '%s' '%s' '%s' '%s' 2>'%s'",
                                     prog, RA0, DEC0, cmd_out, in[0], in[1], in[2], log), 0);
        wf_test_assert_same_file(cmd_out, two);
        ck_assert_int_eq(wf_test_run("'%s' coadd --center %g,%g --size 70,70 --mjd 3:2 --out '%s' '%s' 2>'%s'",
                                     prog, RA0, DEC0, cmd_out, in[0], log), 2);
        ck_assert(wf_test_file_contains(log, "--mjd '3:2'"));
    }
    for (int i = 0; i < 3; i++) product_free(&p[i]);
}
END_TEST

/* The command: exit 2 and a message naming the problem for bad usage and bad input, no file. */
START_TEST(command)
{
    const char *prog = wf_test_program();
    if (!prog) WF_SKIP("wfisim program unknown (set WFISIM_BIN)");
    product a, b;
    product_init(&a, 30, 30, 1, 1);
    product_init(&b, 30, 30, 1, 1);
    b.filter = "H158";
    b.exposure = 2;
    const char *pa = tmp_path("ca.fits"), *pb = tmp_path("cb.fits"), *out = tmp_path("c_out.fits");
    const char *log = tmp_path("c.log"), *list = tmp_path("c.list");
    write_product(&a, pa);
    write_product(&b, pb);
    ck_assert_int_eq(wf_test_run("'%s' coadd --center %g,%g --size 40,40 --out '%s' '%s' '%s' 2>'%s'", prog,
                                 RA0, DEC0, out, pa, pb, log), 2);
    ck_assert(wf_test_file_contains(log, "one filter per coadd"));
    ck_assert(access(out, F_OK) != 0);
    ck_assert_int_eq(wf_test_run("'%s' coadd --size 40,40 --out '%s' '%s' 2>'%s'", prog, out, pa, log), 2);
    ck_assert(wf_test_file_contains(log, "--center is required"));
    ck_assert_int_eq(wf_test_run("'%s' coadd --center %g,%g --size 40,40 --pixfrac 1.5 --out '%s' '%s' 2>'%s'",
                                 prog, RA0, DEC0, out, pa, log), 2);
    ck_assert(wf_test_file_contains(log, "--pixfrac '1.5'"));
    /* a list file works, and the product verifies */
    FILE *l = fopen(list, "w");
    fprintf(l, "# inputs\n%s\n", pa);
    fclose(l);
    ck_assert_int_eq(wf_test_run("'%s' coadd --quiet --center %g,%g --size 40,40 --out '%s' @'%s' 2>'%s'", prog,
                                 RA0, DEC0, out, list, log), 0);
    ck_assert_int_eq(wf_fits_verify_checksums(out, 6), WF_OK);
    product_free(&a);
    product_free(&b);
}
END_TEST

/* ---- STScI's drizzle --------------------------------------------------------------------- */

/* Two dithered inputs with noise, a source and flagged pixels, drizzled by wfisim and by
 * drizzle.cdrizzle.tdriz (square kernel, pixfrac 0.7, weights 1/ERR^2 with flagged pixels
 * 0, pixmap from astropy's WCS): SCI and WHT must agree on every pixel. The axes are not
 * rotated against the output's: Debian's drizzle (C core 1.12) shifts rotated drops
 * (STScI drizzle #82/#83; tests/drizzle_reference.py); rotation is checked by
 * point_source_flux's centroid against the WCS instead. */
START_TEST(stsci_drizzle)
{
    if (access("/usr/bin/python3", X_OK) != 0) WF_SKIP("/usr/bin/python3 not found");
    if (wf_test_run("/usr/bin/python3 -c 'import drizzle.cdrizzle, astropy.wcs' 2>/dev/null") != 0)
        WF_SKIP("python3-drizzle (STScI drizzle) or astropy not installed");
    product p[2];
    const char *in[2] = {tmp_path("s0.fits"), tmp_path("s1.fits")};
    for (int i = 0; i < 2; i++) {
        product_init(&p[i], 60, 55, 0, 1);
        noisy(&p[i], 100u + (unsigned)i);
        p[i].sci[30 * 60 + 29] += 500.0f;
        p[i].exposure = i + 1;
        p[i].ra = RA0 + 0.17 * i / 3600;
        p[i].dec = DEC0 - 0.05 * i / 3600;
        write_product(&p[i], in[i]);
    }
    const char *out = tmp_path("s_coadd.fits"), *log = tmp_path("s.log");
    wf_coadd_opts o = opts(150, 140);
    const char *const paths[2] = {in[0], in[1]};
    ck_assert_int_eq(wf_coadd_run(paths, 2, &o, out), WF_OK);
    int rc = wf_test_run("/usr/bin/python3 tests/drizzle_reference.py '%s' '%s' '%s' >'%s' 2>&1", out, in[0],
                         in[1], log);
    char *text = wf_test_slurp(log, NULL);
    printf("%s", text ? text : "");
    ck_assert_msg(rc == 0, "drizzle_reference.py failed (%d): %s", rc, text ? text : "");
    double dsci = NAN, dwht = NAN;
    const char *at = text ? strstr(text, "max_rel_sci") : NULL;
    ck_assert(at && sscanf(at, "max_rel_sci %lf max_rel_wht %lf", &dsci, &dwht) == 2);
    /* drizzle sums in float32 (SCI as a running weighted mean; measured 1.3e-7): 1e-6 of
     * the largest value is ~10 float32 ulps, far below any kernel or convention difference
     * (a corner off by 0.01 pixel moves WHT by ~1e-2) */
    ck_assert_msg(dsci < 1e-6 && dwht < 1e-6, "wfisim vs STScI drizzle: SCI %g, WHT %g", dsci, dwht);
    free(text);
    for (int i = 0; i < 2; i++) product_free(&p[i]);
}
END_TEST

/* ---- difference images ------------------------------------------------------------------- */

/* An epoch minus a template made of that same epoch with the same kernel (pixfrac 1): zero
 * wherever both have data, ERR sqrt(2) x the template's (two independent errors added). */
START_TEST(diff_of_itself)
{
    product p;
    product_init(&p, 50, 45, 0, 1);
    noisy(&p, 7u);
    p.rot = 21;
    const char *e = tmp_path("de.fits"), *t = tmp_path("dt.fits"), *d = tmp_path("dd.fits");
    write_product(&p, e);
    wf_coadd_opts o = opts(80, 70);
    o.pixfrac = 1.0;
    const char *const paths[1] = {e};
    ck_assert_int_eq(wf_coadd_run(paths, 1, &o, t), WF_OK);
    ck_assert_int_eq(wf_diff_run(t, e, d, 1), WF_OK);
    long nx, ny;
    float *sci = read_plane(d, "SCI", TFLOAT, &nx, &ny);
    float *err = read_plane(d, "ERR", TFLOAT, &nx, &ny);
    float *terr = read_plane(t, "ERR", TFLOAT, &nx, &ny);
    unsigned char *mask = read_plane(d, "MASK", TBYTE, &nx, &ny);
    long good = 0;
    for (long k = 0; k < nx * ny; k++) {
        if (mask[k]) continue;
        good++;
        ck_assert_msg(sci[k] == 0.0f, "pixel %ld: %g", k, sci[k]);
        ck_assert_msg(fabs(err[k] / terr[k] - sqrt(2.0)) < 1e-6, "pixel %ld: ERR ratio %g", k, err[k] / terr[k]);
    }
    ck_assert_msg(good > nx * ny / 2, "only %ld of %ld pixels with data", good, nx * ny);
    ck_assert_int_eq(wf_fits_verify_checksums(d, 4), WF_OK);
    free(sci);
    free(err);
    free(terr);
    free(mask);
    product_free(&p);
}
END_TEST

/* A source of 500 e-/s added to one pixel of a later epoch: the difference holds exactly
 * its flux (uniform ERR and pixfrac 1: the drizzle conserves a point source's flux). */
START_TEST(diff_source_flux)
{
    product a, b;
    product_init(&a, 40, 40, 0, 1);
    product_init(&b, 40, 40, 0, 1);
    srand(3);
    for (int k = 0; k < 1600; k++) a.sci[k] = b.sci[k] = (float)(rand() / (double)RAND_MAX);
    b.sci[18 * 40 + 22] += 500.0f;
    b.exposure = 2;
    b.mjd = 61100;
    a.rot = b.rot = 9;
    const char *pa = tmp_path("fa.fits"), *pb = tmp_path("fb.fits"), *t = tmp_path("ft.fits"), *d = tmp_path("fd.fits");
    write_product(&a, pa);
    write_product(&b, pb);
    wf_coadd_opts o = opts(90, 90);
    o.pixfrac = 1.0;
    const char *const paths[1] = {pa};
    ck_assert_int_eq(wf_coadd_run(paths, 1, &o, t), WF_OK);
    ck_assert_int_eq(wf_diff_run(t, pb, d, 1), WF_OK);
    long nx, ny;
    float *sci = read_plane(d, "SCI", TFLOAT, &nx, &ny);
    double sum = 0;
    for (long k = 0; k < nx * ny; k++) sum += sci[k];
    ck_assert_msg(fabs(sum - 500.0) < 1e-3, "difference flux %.6f of 500", sum);
    free(sci);
    product_free(&a);
    product_free(&b);
}
END_TEST

static void expect_diff_refused(const char *t, const char *e, const char *out, const char *needle)
{
    unlink(out);
    ck_assert_int_eq(wf_diff_run(t, e, out, 1), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), needle), "message '%s' lacks '%s'", wf_error_message(), needle);
    ck_assert_msg(access(out, F_OK) != 0, "%s written despite the error", out);
    char tmp[600];
    snprintf(tmp, sizeof tmp, "%s.tmp", out);
    ck_assert(access(tmp, F_OK) != 0);
    snprintf(tmp, sizeof tmp, "%s.epoch.fits", out);
    ck_assert_msg(access(tmp, F_OK) != 0, "%s left behind", tmp);
}

START_TEST(diff_bad_input)
{
    product a, b;
    product_init(&a, 30, 30, 1, 1);
    product_init(&b, 30, 30, 1, 1);
    b.filter = "J129";
    b.exposure = 2;
    const char *pa = tmp_path("xa.fits"), *pb = tmp_path("xb.fits"), *t = tmp_path("xt.fits");
    const char *far = tmp_path("xfar.fits"), *d = tmp_path("xd.fits");
    write_product(&a, pa);
    write_product(&b, pb);
    wf_coadd_opts o = opts(40, 40);
    const char *const one[1] = {pa};
    ck_assert_int_eq(wf_coadd_run(one, 1, &o, t), WF_OK);
    /* a template elsewhere on the sky: made from a product there */
    product c;
    product_init(&c, 30, 30, 1, 1);
    c.ra = RA0 + 1;
    const char *pc = tmp_path("xc.fits");
    write_product(&c, pc);
    wf_coadd_opts of = o;
    of.ra = RA0 + 1;
    const char *const cfar[1] = {pc};
    ck_assert_int_eq(wf_coadd_run(cfar, 1, &of, far), WF_OK);
    expect_diff_refused(far, pa, d, "overlaps nothing");
    expect_diff_refused(t, pb, d, "filter J129");
    expect_diff_refused(pa, pa, d, "no WHT HDU");
    const char *prog = wf_test_program();
    if (prog) {
        const char *log = tmp_path("xd.log");
        ck_assert_int_eq(wf_test_run("'%s' diff --template '%s' --epoch '%s' --out '%s' 2>'%s'", prog, far, pa, d, log), 2);
        ck_assert(wf_test_file_contains(log, "overlaps nothing"));
        ck_assert(access(d, F_OK) != 0);
        ck_assert_int_eq(wf_test_run("'%s' diff --template '%s' --out '%s' 2>'%s'", prog, t, d, log), 2);
        ck_assert(wf_test_file_contains(log, "--epoch"));
    }
    product_free(&a);
    product_free(&b);
    product_free(&c);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("coadd");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, overlap_by_hand);
    tcase_add_test(tc, drop_by_hand);
    tcase_add_test(tc, wcs_header_round_trip);
    tcase_add_test(tc, constant_image_flux);
    tcase_add_test(tc, point_source_flux);
    tcase_add_test(tc, point_sources_flux);
    tcase_add_test(tc, dq_masked);
    tcase_add_test(tc, inverse_variance);
    tcase_add_test(tc, tiles_and_order);
    tcase_add_test(tc, bad_input);
    tcase_add_test(tc, command);
    tcase_add_test(tc, mjd_range);
    tcase_add_test(tc, stsci_drizzle);
    suite_add_tcase(s, tc);
    TCase *td = tcase_create("diff");
    tcase_set_timeout(td, 120);
    tcase_add_test(td, diff_of_itself);
    tcase_add_test(td, diff_source_flux);
    tcase_add_test(td, diff_bad_input);
    suite_add_tcase(s, td);
    return s;
}

int main(void) { return wf_test_main(suite()); }
