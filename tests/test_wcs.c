/* Focal plane and TAN-SIP WCS: pixel <-> world round trips, agreement with GalSim's Roman WCS
 * (../shared/reference/galsim/wcs_pointing_A.csv), the built-in focal plane against the data
 * files, the FITS header read back by an independent WCS library (astropy, which wraps
 * wcslib), and bad input. */
#include <errno.h>
#include <fitsio.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>

#include "sim/survey/wcs.h"
#include "tests/testutil.h"

#define RA_A 71.0
#define DEC_A (-53.0)
#define PA_A 30.0
#define GRID 17

/* Largest pixel -> world -> pixel error over a GRID x GRID grid spanning the whole SCA. */
static double round_trip_error(const wf_focal_plane *fp, double ra, double dec, double pa,
                               int sca)
{
    wf_wcs w;
    ck_assert_int_eq(wf_wcs_for_sca(fp, ra, dec, pa, sca, &w), WF_OK);
    double worst = 0;
    for (int j = 0; j < GRID; j++)
        for (int i = 0; i < GRID; i++) {
            double x = -0.5 + WF_WCS_NPIX * i / (GRID - 1.0);
            double y = -0.5 + WF_WCS_NPIX * j / (GRID - 1.0), r, d, x2, y2;
            ck_assert_int_eq(wf_wcs_pix2world(&w, x, y, &r, &d), WF_OK);
            ck_assert_int_eq(wf_wcs_world2pix(&w, r, d, &x2, &y2), WF_OK);
            double e = hypot(x2 - x, y2 - y);
            if (e > worst) worst = e;
        }
    return worst;
}

static void check_round_trips(const wf_focal_plane *fp)
{
    /* The reference pointing, one near the pole and one across RA 0, at odd angles. */
    const double pointings[][3] = {{RA_A, DEC_A, PA_A}, {10.0, 85.0, -73.0}, {359.9, -0.5, 211.0}};
    double worst = 0;
    for (size_t p = 0; p < sizeof pointings / sizeof pointings[0]; p++)
        for (int s = 1; s <= WF_WCS_NSCA; s++) {
            double e = round_trip_error(fp, pointings[p][0], pointings[p][1], pointings[p][2], s);
            ck_assert_msg(e <= 1e-4, "%s: SCA %d pointing %zu: round trip %.3g pixel", fp->source,
                          s, p, e);
            if (e > worst) worst = e;
        }
    printf("round trip (%s focal plane): largest error %.2g pixel over %d points per SCA\n",
           fp->source, worst, GRID * GRID);
}

START_TEST(round_trip_builtin)
{
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    check_round_trips(&fp);
}
END_TEST

START_TEST(round_trip_data)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    wf_focal_plane fp;
    ck_assert_msg(wf_wcs_focal_plane_load(data, &fp) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(fp.sip_order, 4);
    check_round_trips(&fp);
}
END_TEST

/* Every point of GalSim's pointing A through world -> pixel; the largest error per SCA. */
static void compare_reference(const wf_focal_plane *fp, const char *ref, double tol)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/wcs_pointing_A.csv", ref);
    FILE *f = fopen(path, "r");
    ck_assert_msg(f != NULL, "%s: %s", path, strerror(errno));
    char line[512];
    ck_assert_ptr_nonnull(fgets(line, sizeof line, f)); /* header */
    double worst[WF_WCS_NSCA + 1] = {0}, worst_world[WF_WCS_NSCA + 1] = {0};
    int count[WF_WCS_NSCA + 1] = {0}, rows = 0;
    wf_wcs w[WF_WCS_NSCA + 1];
    for (int s = 1; s <= WF_WCS_NSCA; s++)
        ck_assert_int_eq(wf_wcs_for_sca(fp, RA_A, DEC_A, PA_A, s, &w[s]), WF_OK);
    while (fgets(line, sizeof line, f)) {
        char name[8];
        double ra0, dec0, pa, x, y, ra, dec;
        int sca;
        ck_assert_int_eq(sscanf(line, "%7[^,],%lf,%lf,%lf,%d,%lf,%lf,%lf,%lf", name, &ra0, &dec0,
                                &pa, &sca, &x, &y, &ra, &dec), 9);
        ck_assert(ra0 == RA_A && dec0 == DEC_A && pa == PA_A && sca >= 1 && sca <= 18);
        double px, py, r2, d2;
        ck_assert_int_eq(wf_wcs_world2pix(&w[sca], ra, dec, &px, &py), WF_OK);
        /* The reference is in GalSim's 1-based pixels. */
        double e = hypot(px - (x - 1.0), py - (y - 1.0));
        ck_assert_int_eq(wf_wcs_pix2world(&w[sca], x - 1.0, y - 1.0, &r2, &d2), WF_OK);
        double ew = wf_wcs_separation(ra, dec, r2, d2) * 3600.0;
        if (e > worst[sca]) worst[sca] = e;
        if (ew > worst_world[sca]) worst_world[sca] = ew;
        count[sca]++;
        rows++;
    }
    fclose(f);
    ck_assert_int_eq(rows, 720);
    printf("GalSim pointing A (RA 71, Dec -53, PA 30), %s focal plane: largest |pixel error| per "
           "SCA (points):\n", fp->source);
    double all = 0;
    for (int s = 1; s <= WF_WCS_NSCA; s++) {
        printf("  SCA %2d: %.5f px (%.2g arcsec on the sky, %d points)\n", s, worst[s],
               worst_world[s], count[s]);
        ck_assert_int_eq(count[s], 40);
        if (worst[s] > all) all = worst[s];
    }
    printf("  all SCAs: %.5f px\n", all);
    for (int s = 1; s <= WF_WCS_NSCA; s++)
        ck_assert_msg(worst[s] <= tol, "%s: SCA %d differs from GalSim by %.4f pixel", fp->source,
                      s, worst[s]);
}

START_TEST(galsim_pointing_a_data)
{
    const char *ref = wf_test_reference_dir(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(ref, "../shared/reference/galsim");
    WF_SKIP_UNLESS(data, "../shared/data");
    wf_focal_plane fp;
    ck_assert_int_eq(wf_wcs_focal_plane_load(data, &fp), WF_OK);
    compare_reference(&fp, ref, 0.05);
}
END_TEST

START_TEST(galsim_pointing_a_builtin)
{
    const char *ref = wf_test_reference_dir();
    WF_SKIP_UNLESS(ref, "../shared/reference/galsim");
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    compare_reference(&fp, ref, 0.05);
}
END_TEST

/* sca_layout.csv: GalSim's SCA centres (FITS pixel 2044.5, 2044.5) at RA 71, Dec -53, PA 0
 * and the pixel area there; the built-in table must give the same. */
START_TEST(galsim_sca_layout)
{
    const char *ref = wf_test_reference_dir();
    WF_SKIP_UNLESS(ref, "../shared/reference/galsim");
    char path[4200], line[512];
    snprintf(path, sizeof path, "%s/sca_layout.csv", ref);
    FILE *f = fopen(path, "r");
    ck_assert_msg(f != NULL, "%s: %s", path, strerror(errno));
    ck_assert_ptr_nonnull(fgets(line, sizeof line, f));
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    int n = 0;
    double worst = 0, worst_area = 0;
    while (fgets(line, sizeof line, f)) {
        int s;
        double xmm, ymm, ra, dec, dx, dy, area, r, d;
        ck_assert_int_eq(sscanf(line, "%d,%lf,%lf,%lf,%lf,%lf,%lf,%lf", &s, &xmm, &ymm, &ra, &dec,
                                &dx, &dy, &area), 8);
        wf_wcs w;
        ck_assert_int_eq(wf_wcs_for_sca(&fp, RA_A, DEC_A, 0.0, s, &w), WF_OK);
        ck_assert_int_eq(wf_wcs_pix2world(&w, 2043.5, 2043.5, &r, &d), WF_OK);
        double det = fabs(w.cd[0][0] * w.cd[1][1] - w.cd[0][1] * w.cd[1][0]) * 3600.0 * 3600.0;
        worst = fmax(worst, wf_wcs_separation(ra, dec, r, d) * 3600.0);
        worst_area = fmax(worst_area, fabs(det - area));
        n++;
    }
    fclose(f);
    ck_assert_int_eq(n, WF_WCS_NSCA);
    printf("sca_layout.csv (PA 0): built-in SCA centres within %.4f arcsec, pixel areas within "
           "%.1e arcsec2\n", worst, worst_area);
    ck_assert_double_le(worst, 0.005);       /* the CSV's 6 decimals of a degree */
    ck_assert_double_le(worst_area, 1.5e-6); /* and of an arcsec^2 */
}
END_TEST

/* The built-in linear model against the full one over whole SCAs. */
START_TEST(builtin_against_data)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    wf_focal_plane full, lin;
    ck_assert_int_eq(wf_wcs_focal_plane_load(data, &full), WF_OK);
    wf_wcs_focal_plane_builtin(&lin);
    double all = 0;
    for (int s = 1; s <= WF_WCS_NSCA; s++) {
        wf_wcs wf, wl;
        ck_assert_int_eq(wf_wcs_for_sca(&full, RA_A, DEC_A, PA_A, s, &wf), WF_OK);
        ck_assert_int_eq(wf_wcs_for_sca(&lin, RA_A, DEC_A, PA_A, s, &wl), WF_OK);
        for (int j = 0; j < GRID; j++)
            for (int i = 0; i < GRID; i++) {
                double x = -0.5 + WF_WCS_NPIX * i / (GRID - 1.0);
                double y = -0.5 + WF_WCS_NPIX * j / (GRID - 1.0), r, d, x2, y2;
                ck_assert_int_eq(wf_wcs_pix2world(&wf, x, y, &r, &d), WF_OK);
                ck_assert_int_eq(wf_wcs_world2pix(&wl, r, d, &x2, &y2), WF_OK);
                double e = hypot(x2 - x, y2 - y);
                if (e > all) all = e;
            }
    }
    printf("built-in linear focal plane against the data files: largest error %.4f pixel\n", all);
    ck_assert_double_le(all, 0.05);
}
END_TEST

START_TEST(inverse_sip_fit)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    wf_focal_plane fp;
    ck_assert_int_eq(wf_wcs_focal_plane_load(data, &fp), WF_OK);
    double worst = 0;
    for (int s = 1; s <= WF_WCS_NSCA; s++) {
        wf_wcs w;
        double ap[WF_WCS_SIP_N][WF_WCS_SIP_N], bp[WF_WCS_SIP_N][WF_WCS_SIP_N], r;
        ck_assert_int_eq(wf_wcs_for_sca(&fp, RA_A, DEC_A, PA_A, s, &w), WF_OK);
        ck_assert_int_eq(wf_wcs_fit_inverse(&w, 4, ap, bp, &r), WF_OK);
        if (r > worst) worst = r;
    }
    printf("inverse SIP (AP/BP, order 4) least-squares fit: largest residual %.2g pixel\n", worst);
    ck_assert_double_le(worst, 1e-4);
}
END_TEST

/* ---- the header read back by astropy (wcslib inside) ------------------------------------- */

static const char *astropy_script =
    "import sys, warnings\n"
    "import numpy as np\n"
    "from astropy.io import fits\n"
    "from astropy.wcs import WCS\n"
    "warnings.simplefilter('ignore')\n"
    "n = %d\n"
    "worst = -1.0\n"
    "g = -0.5 + 4088.0 * np.arange(n) / (n - 1.0)\n"
    "x, y = [a.ravel() + 1.0 for a in np.meshgrid(g, g)]\n"
    "with fits.open(sys.argv[1]) as hl, open(sys.argv[2], 'w') as out:\n"
    "    for k, h in enumerate(hl):\n"
    "        w = WCS(h.header)\n"
    "        if w.sip is None and h.header['CTYPE1'].endswith('-SIP'):\n"
    "            sys.exit('HDU %%d: SIP not recognised' %% k)\n"
    "        ra, dec = w.all_pix2world(x, y, 1)\n"
    "        for i in range(len(x)):\n"
    "            out.write('%%d %%.12f %%.12f %%.15f %%.15f\\n' %% (k, x[i], y[i], ra[i], dec[i]))\n"
    "        if w.sip is not None:\n"
    "            # world -> pixel through wcslib's TAN and the header's AP/BP alone\n"
    "            fx, fy = w.wcs_world2pix(ra, dec, 1)\n"
    "            u, v = fx - w.wcs.crpix[0], fy - w.wcs.crpix[1]\n"
    "            ap, bp = w.sip.ap, w.sip.bp\n"
    "            du = sum(ap[i, j] * u**i * v**j for i in range(5) for j in range(5 - i))\n"
    "            dv = sum(bp[i, j] * u**i * v**j for i in range(5) for j in range(5 - i))\n"
    "            e = np.hypot(u + du + w.wcs.crpix[0] - x, v + dv + w.wcs.crpix[1] - y).max()\n"
    "            worst = max(worst, e)\n"
    "if worst >= 0:\n"
    "    print('AP/BP inverse read by astropy: largest error %%.2g pixel' %% worst)\n"
    "    sys.exit(1 if worst > 1e-4 else 0)\n";

static void header_roundtrip_astropy(const wf_focal_plane *fp)
{
    if (wf_test_run("/usr/bin/python3 -c 'import astropy.wcs, numpy' 2>/dev/null") != 0)
        WF_SKIP("/usr/bin/python3 with astropy not installed (wcslib-dev is not either)");
    const char *dir = wf_test_tmpdir();
    ck_assert_ptr_nonnull(dir);
    char fits_path[4200], py[4200], out[4200];
    snprintf(fits_path, sizeof fits_path, "%s/wcs.fits", dir);
    snprintf(py, sizeof py, "%s/wcs_check.py", dir);
    snprintf(out, sizeof out, "%s/wcs_check.txt", dir);
    fitsfile *f = NULL;
    int status = 0;
    fits_create_file(&f, fits_path, &status);
    ck_assert_int_eq(status, 0);
    wf_wcs w[WF_WCS_NSCA + 1];
    for (int s = 1; s <= WF_WCS_NSCA; s++) {
        long naxes[2] = {0, 0};
        fits_create_img(f, BYTE_IMG, 0, naxes, &status);
        ck_assert_int_eq(status, 0);
        ck_assert_int_eq(wf_wcs_for_sca(fp, RA_A, DEC_A, PA_A, s, &w[s]), WF_OK);
        ck_assert_msg(wf_wcs_write_header(&w[s], f, fits_path) == WF_OK, "%s", wf_error_message());
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    FILE *p = fopen(py, "w");
    ck_assert_ptr_nonnull(p);
    fprintf(p, astropy_script, GRID);
    fclose(p);
    ck_assert_int_eq(wf_test_run("/usr/bin/python3 %s %s %s", py, fits_path, out), 0);
    FILE *r = fopen(out, "r");
    ck_assert_ptr_nonnull(r);
    int hdu, n = 0;
    double x, y, ra, dec, worst = 0;
    while (fscanf(r, "%d %lf %lf %lf %lf", &hdu, &x, &y, &ra, &dec) == 5) {
        ck_assert(hdu >= 0 && hdu < WF_WCS_NSCA);
        double px, py2;
        ck_assert_int_eq(wf_wcs_world2pix(&w[hdu + 1], ra, dec, &px, &py2), WF_OK);
        double e = hypot(px - (x - 1.0), py2 - (y - 1.0));
        if (e > worst) worst = e;
        n++;
    }
    fclose(r);
    ck_assert_int_eq(n, WF_WCS_NSCA * GRID * GRID);
    printf("FITS header (%s focal plane) read by astropy.wcs: world positions agree within %.2g "
           "pixel (%d points)\n", fp->source, worst, n);
    ck_assert_double_le(worst, 1e-4);
}

START_TEST(header_astropy_data)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    wf_focal_plane fp;
    ck_assert_int_eq(wf_wcs_focal_plane_load(data, &fp), WF_OK);
    header_roundtrip_astropy(&fp);
}
END_TEST

START_TEST(header_astropy_builtin)
{
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    header_roundtrip_astropy(&fp);
}
END_TEST

/* ---- bad input ----------------------------------------------------------------------------- */

/* A data directory whose two files are copies of the real ones with one line replaced
 * (line < 0: unchanged); returns the directory. */
static const char *doctored_data(const char *data, const char *which, int line, const char *text)
{
    const char *dir = wf_test_tmpdir();
    ck_assert_ptr_nonnull(dir);
    static char root[4200];
    snprintf(root, sizeof root, "%s", dir);
    char sub[4300];
    snprintf(sub, sizeof sub, "%s/roman", root);
    ck_assert_int_eq(mkdir(sub, 0755), 0);
    const char *names[2] = {"sca_positions_20210204.txt", "sip_20210204.txt"};
    for (int k = 0; k < 2; k++) {
        char src[4300], dst[4400], buf[512];
        snprintf(src, sizeof src, "%s/roman/%s", data, names[k]);
        snprintf(dst, sizeof dst, "%s/%s", sub, names[k]);
        FILE *in = fopen(src, "r"), *out = fopen(dst, "w");
        ck_assert_ptr_nonnull(in);
        ck_assert_ptr_nonnull(out);
        int n = 0;
        while (fgets(buf, sizeof buf, in)) {
            n++;
            if (!strcmp(which, names[k]) && n == line) {
                if (text) fputs(text, out);
                continue;
            }
            fputs(buf, out);
        }
        fclose(in);
        fclose(out);
    }
    return root;
}

static void expect_load_error(const char *dir, wf_status code, const char *needle)
{
    wf_focal_plane fp;
    memset(&fp, 0x5a, sizeof fp);
    wf_focal_plane before = fp;
    wf_status st = wf_wcs_focal_plane_load(dir, &fp);
    ck_assert_msg(st == code, "expected %s, got %s (%s)", wf_status_name(code), wf_status_name(st),
                  wf_error_message());
    ck_assert_msg(strstr(wf_error_message(), needle), "message '%s' lacks '%s'",
                  wf_error_message(), needle);
    ck_assert_msg(!memcmp(&fp, &before, sizeof fp), "focal plane changed on error");
}

/* The gnomonic pair: closed-form values, a vector construction of the same projection, round
 * trips both ways to 1e-12 deg (across RA 0, near a pole, out to 60 deg), and the refusal at
 * 90 deg. */
START_TEST(tangent_projection)
{
    const double deg = M_PI / 180.0, tol = 1e-12 * deg;
    double xi, eta, ra, dec;
    /* along the equator and along a meridian the offsets are tangents of the angle */
    ck_assert_int_eq(wf_wcs_tangent_project(30 * deg, 0, 50 * deg, 0, &xi, &eta), WF_OK);
    ck_assert_double_eq_tol(xi, tan(20 * deg), 1e-15);
    ck_assert_double_eq_tol(eta, 0.0, 1e-15);
    ck_assert_int_eq(wf_wcs_tangent_project(RA_A * deg, DEC_A * deg, RA_A * deg, (DEC_A + 7) * deg, &xi, &eta), WF_OK);
    ck_assert_double_eq_tol(xi, 0.0, 1e-15);
    ck_assert_double_eq_tol(eta, tan(7 * deg), 1e-15);
    /* about (0, 0): xi = tan(ra), eta = tan(dec) / cos(ra); back: ra = atan(xi),
     * dec = atan(eta / sqrt(1 + xi^2)) */
    ck_assert_int_eq(wf_wcs_tangent_project(0, 0, 25 * deg, -15 * deg, &xi, &eta), WF_OK);
    ck_assert_double_eq_tol(xi, tan(25 * deg), 1e-15);
    ck_assert_double_eq_tol(eta, tan(-15 * deg) / cos(25 * deg), 1e-15);
    wf_wcs_tangent_deproject(0, 0, 0.3, -0.2, &ra, &dec);
    ck_assert_double_eq_tol(ra, atan(0.3), 1e-15);
    ck_assert_double_eq_tol(dec, atan(-0.2 / sqrt(1 + 0.09)), 1e-15);

    const double centres[][2] = {{RA_A, DEC_A}, {0.2, 10.0}, {359.9, -0.5}, {10.0, 85.0}, {200.0, -89.5}};
    const double reach[] = {0.5, 5.0, 60.0}; /* deg from the tangent point */
    double worst_sky = 0, worst_plane = 0;
    for (size_t c = 0; c < sizeof centres / sizeof *centres; c++) {
        double a0 = centres[c][0] * deg, d0 = centres[c][1] * deg;
        /* east, north and the centre as vectors: xi = p.e / p.c, eta = p.n / p.c */
        double cv[3] = {cos(d0) * cos(a0), cos(d0) * sin(a0), sin(d0)};
        double ev[3] = {-sin(a0), cos(a0), 0};
        double nv[3] = {-sin(d0) * cos(a0), -sin(d0) * sin(a0), cos(d0)};
        for (size_t r = 0; r < sizeof reach / sizeof *reach; r++)
            for (int k = 0; k < 24; k++) {
                double rho = tan(reach[r] * deg) * (0.25 + 0.75 * (k % 4) / 3.0), phi = 2 * M_PI * k / 24.0;
                double x0 = rho * cos(phi), y0 = rho * sin(phi);
                wf_wcs_tangent_deproject(a0, d0, x0, y0, &ra, &dec);
                double pv[3] = {cos(dec) * cos(ra), cos(dec) * sin(ra), sin(dec)};
                double pc = pv[0] * cv[0] + pv[1] * cv[1] + pv[2] * cv[2];
                double pe = pv[0] * ev[0] + pv[1] * ev[1], pn = pv[0] * nv[0] + pv[1] * nv[1] + pv[2] * nv[2];
                ck_assert_msg(fabs(pe / pc - x0) <= 1e-14 * (1 + rho) && fabs(pn / pc - y0) <= 1e-14 * (1 + rho),
                              "centre %zu: (%g, %g) deprojects off the vector construction", c, x0, y0);
                ck_assert_int_eq(wf_wcs_tangent_project(a0, d0, ra, dec, &xi, &eta), WF_OK);
                /* an error dx in the plane is dx / (1 + rho^2) radians on the sky */
                double e_plane = hypot(xi - x0, eta - y0) / (1 + rho * rho);
                ck_assert_msg(e_plane <= tol, "centre %zu: plane round trip %.3g deg", c, e_plane / deg);
                /* sky -> plane -> sky from a point off the grid (RA in [0, 360) where it crosses 0) */
                double ra1 = fmod(ra + 0.37 * rho + 4 * M_PI, 2 * M_PI), dec1 = dec - 0.21 * rho * cos(dec), ra2, dec2;
                if (!(wf_wcs_separation(ra1 / deg, dec1 / deg, centres[c][0], centres[c][1]) < 89.0)) continue;
                ck_assert_int_eq(wf_wcs_tangent_project(a0, d0, ra1, dec1, &xi, &eta), WF_OK);
                wf_wcs_tangent_deproject(a0, d0, xi, eta, &ra2, &dec2);
                double e_sky = wf_wcs_separation(ra1 / deg, dec1 / deg, ra2 / deg, dec2 / deg);
                ck_assert_msg(e_sky <= 1e-12, "centre %zu: sky round trip %.3g deg", c, e_sky);
                if (e_sky > worst_sky) worst_sky = e_sky;
                if (e_plane / deg > worst_plane) worst_plane = e_plane / deg;
            }
    }
    printf("tangent projection round trips: sky %.2g deg, plane %.2g deg at most\n", worst_sky, worst_plane);

    /* 90 deg away there is no tangent-plane point */
    xi = eta = 7.0;
    ck_assert_int_eq(wf_wcs_tangent_project(RA_A * deg, DEC_A * deg, (RA_A + 180) * deg, -DEC_A * deg, &xi, &eta),
                     WF_ERR_RANGE);
    ck_assert_int_eq(wf_wcs_tangent_project(0, 0, 90 * deg, 0, &xi, &eta), WF_ERR_RANGE);
    ck_assert_msg(strstr(wf_error_message(), "90 deg or more"), "%s", wf_error_message());
    ck_assert(xi == 7.0 && eta == 7.0);
}
END_TEST

START_TEST(bad_input)
{
    wf_focal_plane fp;
    wf_wcs w;
    wf_wcs_focal_plane_builtin(&fp);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, 71, -53, 0, 0, &w), WF_ERR_RANGE);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, 71, -53, 0, 19, &w), WF_ERR_RANGE);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, 71, 90, 0, 1, &w), WF_ERR_RANGE);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, NAN, -53, 0, 1, &w), WF_ERR_INPUT);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, 71, -53, 0, 1, &w), WF_OK);
    double x, y;
    ck_assert_int_eq(wf_wcs_world2pix(&w, 251.0, 53.0, &x, &y), WF_ERR_RANGE); /* antipode */
    ck_assert_int_eq(wf_wcs_pix2world(&w, INFINITY, 0, &x, &y), WF_ERR_INPUT);

    const char *dir = wf_test_tmpdir();
    expect_load_error(dir, WF_ERR_IO, "sca_positions_20210204.txt");
    expect_load_error("", WF_ERR_INPUT, "no data directory");

    const char *data = wf_test_data_dir();
    if (!data) WF_SKIP("../shared/data not found: doctored-file cases not run");
    expect_load_error(doctored_data(data, "sca_positions_20210204.txt", 5, "  5  x 1 2 3 4 5\n"),
                      WF_ERR_INPUT, "sca_positions_20210204.txt:5: column 2");
    expect_load_error(doctored_data(data, "sca_positions_20210204.txt", 7, NULL), WF_ERR_INPUT,
                      "no row for SCA 7");
    expect_load_error(doctored_data(data, "sca_positions_20210204.txt", 2,
                                    " 1 -0.068 0.46 -22.14 12.15 -0.068 -0.0356\n"),
                      WF_ERR_INPUT, "SCA 1 given twice");
    expect_load_error(doctored_data(data, "sca_positions_20210204.txt", 3, " 3 1 2 3 4\n"),
                      WF_ERR_INPUT, "sca_positions_20210204.txt:3: expected 7 columns");
    expect_load_error(doctored_data(data, "sip_20210204.txt", 12,
                                    "  1 a  1  0 3e-05 nan 0 0\n"),
                      WF_ERR_INPUT, "sip_20210204.txt:12: column 6");
    expect_load_error(doctored_data(data, "sip_20210204.txt", 12, NULL), WF_ERR_INPUT,
                      "no 'a 1' row for SCA 2");
    expect_load_error(doctored_data(data, "sip_20210204.txt", 40, "  3 c  0 0 0 0 0 0\n"),
                      WF_ERR_INPUT, "sip_20210204.txt:40: column 2");
    expect_load_error(doctored_data(data, "sip_20210204.txt", 1, " 18 a  0 0 0 0 0 0\n"),
                      WF_ERR_INPUT, "sip_20210204.txt:1: column 1");
}
END_TEST

static Suite *wcs_suite(void)
{
    Suite *s = suite_create("wcs");
    TCase *tc = tcase_create("wcs");
    tcase_set_timeout(tc, 120); /* sanitizer builds */
    tcase_add_test(tc, round_trip_builtin);
    tcase_add_test(tc, round_trip_data);
    tcase_add_test(tc, galsim_pointing_a_data);
    tcase_add_test(tc, galsim_pointing_a_builtin);
    tcase_add_test(tc, galsim_sca_layout);
    tcase_add_test(tc, builtin_against_data);
    tcase_add_test(tc, inverse_sip_fit);
    tcase_add_test(tc, header_astropy_data);
    tcase_add_test(tc, header_astropy_builtin);
    tcase_add_test(tc, tangent_projection);
    tcase_add_test(tc, bad_input);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(wcs_suite()); }
