/* One SCA's scene end to end on the host side (no detector): catalog -> WCS -> bandpass ->
 * sky -> PSF -> stamps -> tiles. Fluxes add up, positions land where the WCS says, objects
 * off the SCA are not drawn, the truth lists what is on it, and a magnitude-8 star and a
 * magnitude-35 galaxy are handled. Uses the built-in models, so it runs without ../shared. */
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/optics/bandpass.h"
#include "sim/survey/catalog.h"
#include "sim/draw/profile.h"
#include "sim/optics/psf.h"
#include "sim/optics/pupil.h"
#include "sim/draw/scene.h"
#include "sim/draw/scene_psf.h"
#include "sim/survey/wcs.h"
#include "tests/testutil.h"

#define W 256
#define H 256

/* Writes a CSV catalog of stars or galaxies at given pixel positions of the setup's SCA. */
static void write_catalog(const char *path, const wf_scene_setup *ss, int galaxies, double knot_frac, int n,
                          const double *x, const double *y, const double *mag)
{
    wf_focal_plane fp;
    wf_wcs w;
    wf_wcs_focal_plane(NULL, &fp);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, ss->ra, ss->dec, ss->pa, ss->sca, &w), WF_OK);
    FILE *f = fopen(path, "w");
    if (galaxies)
        fprintf(f, "id,ra,dec,z,mag_Y106,hlr_disk,hlr_bulge,bulge_frac,knot_frac,e1,e2,pa\n");
    else
        fprintf(f, "id,ra,dec,mag_Y106\n");
    for (int i = 0; i < n; i++) {
        double ra, dec;
        ck_assert_int_eq(wf_wcs_pix2world(&w, x[i], y[i], &ra, &dec), WF_OK);
        if (galaxies)
            fprintf(f, "%d,%.12f,%.12f,0.5,%.4f,0.3,0.15,0.3,%.3f,0.2,-0.1,0\n", i + 1, ra, dec, mag[i], knot_frac);
        else
            fprintf(f, "%d,%.12f,%.12f,%.4f\n", i + 1, ra, dec, mag[i]);
    }
    fclose(f);
}

static void setup_small(wf_scene_setup *ss)
{
    wf_scene_setup_default(ss);
    ss->ncols = W;
    ss->nrows = H;
    ss->psf_size = 256;
    ss->sky_on = 0;
}

static float *render(wf_scene *scene)
{
    wf_scene_source src;
    ck_assert_int_eq(wf_scene_source_for(scene, 0, &src), WF_OK);
    float *img = malloc(sizeof(float) * W * H);
    for (int y0 = 0; y0 < H; y0 += 32)
        ck_assert_msg(wf_scene_fill(&src, y0, y0 + 32, W, img + (size_t)y0 * W) == WF_OK, "%s", wf_error_message());
    return img;
}

START_TEST(star_fluxes_and_positions)
{
    wf_scene_setup ss;
    setup_small(&ss);
    const double x[3] = {60.3, 180.75, 128.0}, y[3] = {70.6, 100.2, 200.45}, mag[3] = {18, 19, 20};
    char path[4200];
    snprintf(path, sizeof path, "%s/stars.csv", wf_test_tmpdir());
    write_catalog(path, &ss, 0, 0.0, 3, x, y, mag);
    wf_catalog stars;
    ck_assert_int_eq(wf_catalog_read_stars(path, &stars), WF_OK);
    wf_scene *scene;
    ck_assert_msg(wf_scene_create(&ss, NULL, &stars, &scene) == WF_OK, "%s", wf_error_message());
    float *img = render(scene);
    wf_bandpass bp;
    wf_bandpass_load(WF_Y106, NULL, &bp);
    for (int k = 0; k < 3; k++) {
        double flux = wf_bandpass_countrate_ab(&bp, mag[k]);
        double s = 0, sx = 0, sy = 0;
        int r = 20; /* 2.2": holds > 97% of the PSF */
        for (int j = (int)y[k] - r; j <= (int)y[k] + r; j++)
            for (int i = (int)x[k] - r; i <= (int)x[k] + r; i++) {
                double v = img[j * W + i];
                s += v;
                sx += v * i;
                sy += v * j;
            }
        ck_assert_msg(s > 0.95 * flux && s < 1.0001 * flux, "star %d: %.3f of %.3f e-/s in 41x41", k, s, flux);
        /* the 41x41 window sits on whole pixels, so it cuts the wings off-centre: 0.05 px */
        ck_assert_msg(fabs(sx / s - x[k]) < 0.05 && fabs(sy / s - y[k]) < 0.05,
                      "star %d centroid (%.3f, %.3f) vs (%.3f, %.3f)", k, sx / s, sy / s, x[k], y[k]);
    }
    free(img);
    wf_scene_destroy(scene);
    wf_catalog_free(&stars);
}
END_TEST

START_TEST(galaxies_edges_and_extremes)
{
    wf_scene_setup ss;
    setup_small(&ss);
    /* on the SCA; on a corner; past an edge but reaching it; far off; magnitude 35 */
    const double x[5] = {128, -0.4, W + 3.0, 5000, 64}, y[5] = {128, -0.4, 100, 5000, 192};
    const double mag[5] = {20, 20, 19, 20, 35};
    char path[4200];
    snprintf(path, sizeof path, "%s/gal.csv", wf_test_tmpdir());
    write_catalog(path, &ss, 1, 0.0, 5, x, y, mag);
    wf_catalog gal;
    ck_assert_msg(wf_catalog_read_galaxies(path, &gal) == WF_OK, "%s", wf_error_message());
    wf_scene *scene;
    ck_assert_msg(wf_scene_create(&ss, &gal, NULL, &scene) == WF_OK, "%s", wf_error_message());
    float *img = render(scene);
    double total = 0;
    for (int i = 0; i < W * H; i++) {
        ck_assert_msg(isfinite(img[i]) && img[i] >= 0.0f, "pixel %d: %g", i, img[i]);
        total += img[i];
    }
    wf_bandpass bp;
    wf_bandpass_load(WF_Y106, NULL, &bp);
    double f20 = wf_bandpass_countrate_ab(&bp, 20);
    double centre = 0, corner = 0;
    for (int j = 98; j <= 158; j++)
        for (int i = 98; i <= 158; i++) centre += img[j * W + i];
    for (int j = 0; j < 40; j++)
        for (int i = 0; i < 40; i++) corner += img[j * W + i];
    /* the centre galaxy whole (stamps hold >= 99.5%), a quarter of the corner one */
    ck_assert_msg(centre > 0.99 * f20 && centre < 1.0001 * f20, "centre galaxy %.3f of %.3f e-/s", centre, f20);
    ck_assert_msg(corner > 0.2 * f20 && corner < 0.3 * f20, "corner galaxy %.3f of %.3f e-/s", corner, f20);
    ck_assert(total > centre + corner);
    wf_scene_stats st;
    wf_scene_get_stats(scene, &st);
    ck_assert_int_eq(st.galaxies, 4); /* the far one is not drawn */
    char tpath[4200];
    snprintf(tpath, sizeof tpath, "%s/truth.fits", wf_test_tmpdir());
    ck_assert_int_eq(wf_scene_write_truth(scene, tpath, NULL), WF_OK);
    fitsfile *f;
    int status = 0;
    long rows = 0;
    fits_open_table(&f, tpath, READONLY, &status);
    fits_movnam_hdu(f, BINARY_TBL, "GALAXIES", 0, &status);
    fits_get_num_rows(f, &rows, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(rows, 3); /* centres on the SCA: centre, corner, magnitude 35 */
    free(img);
    wf_scene_destroy(scene);
    wf_catalog_free(&gal);
}
END_TEST

/* scene.noise_tolerance (sim/draw/scene.h): per object, folding, the Fourier cut, the knot
 * lattice and the split PSF's wing are loosened, and knots drawn as the smooth disk, only as
 * far as their error bounds stay below tau x one pixel's sky noise over the exposure.
 * Against the same scene with tau = 0 (galaxies with the disk's largest knot share): no
 * pixel of any object moves by more than the five bounds together (5 tau sigma), compared
 * over both stamps (a smooth disk's stamp may differ from the knots'); faint objects do
 * change (cheaper boxes, smooth knots), a bright one barely (its knot lattice and its Fourier
 * cut's tail loosen);
 * tau = 0 with a split PSF is the unsplit scene bit for bit. */
START_TEST(noise_tolerance_bounds)
{
    enum { N = 12 };
    double x[N], y[N], mag[N];
    for (int i = 0; i < N; i++) {
        x[i] = 40.3 + 17.0 * i;
        y[i] = 60.7 + 13.0 * i;
        mag[i] = 18.0 + i; /* 18 .. 29 */
    }
    wf_scene_setup ss;
    setup_small(&ss);
    char path[4200];
    snprintf(path, sizeof path, "%s/tol.csv", wf_test_tmpdir());
    write_catalog(path, &ss, 1, WF_PROFILE_MAX_KNOT_FRAC, N, x, y, mag);
    wf_catalog gal;
    ck_assert_msg(wf_catalog_read_galaxies(path, &gal) == WF_OK, "%s", wf_error_message());
    const double tau = 1.0;
    /* modes: 0 exact, 1 tolerance tau, 2 exact without the split, 3 as 1 without the sky in
     * the rates but at its noise (sky_noise: a persistence history's objects) */
    double *pix[4][N];
    int x0[4][N], y0[4][N], nx[4][N], ny[4][N];
    double sigma = 0.0;
    for (int m = 0; m < 4; m++) {
        setup_small(&ss);
        ss.sky_on = m != 3;
        ss.sky_noise = m == 3;
        ss.core_radius = m == 2 ? 0.0 : 2.0;
        ss.noise_tolerance = m == 1 || m == 3 ? tau : 0.0;
        wf_scene *scene;
        ck_assert_msg(wf_scene_create(&ss, &gal, NULL, &scene) == WF_OK, "%s", wf_error_message());
        ck_assert_int_eq(wf_scene_object_count(scene), N);
        wf_scene_stats st;
        wf_scene_get_stats(scene, &st);
        sigma = sqrt(st.sky_least * ss.exptime) / ss.exptime; /* e-/s, the stamps' unit */
        printf("noise tolerance: mode %d: of %ld galaxies, %ld drawn with the split PSF, %ld with smooth knots\n", m,
               st.galaxies, st.split, st.knots_smooth);
        if (m == 1 || m == 3) {
            ck_assert_msg(st.split >= 2, "only %ld galaxies took the split", st.split);
            ck_assert_msg(st.knots_smooth >= 2 && st.knots_smooth < N, "%ld galaxies took smooth knots",
                          st.knots_smooth);
        } else {
            ck_assert_int_eq(st.split, 0);
            ck_assert_int_eq(st.knots_smooth, 0);
        }
        for (int k = 0; k < N; k++) {
            wf_scene_object info;
            ck_assert_int_eq(wf_scene_draw_object(scene, (size_t)k, &info, &x0[m][k], &y0[m][k], &nx[m][k], &ny[m][k],
                                                  &pix[m][k]),
                             WF_OK);
        }
        wf_scene_destroy(scene);
    }
    int changed = 0;
    for (int k = 0; k < N; k++) {
        ck_assert(nx[0][k] == nx[2][k] && ny[0][k] == ny[2][k]);
        size_t np = (size_t)nx[0][k] * ny[0][k];
        ck_assert_msg(!memcmp(pix[0][k], pix[2][k], np * sizeof(double)), "object %d: tau 0 is not the unsplit scene", k);
        ck_assert(nx[1][k] == nx[3][k] && ny[1][k] == ny[3][k] && x0[1][k] == x0[3][k] && y0[1][k] == y0[3][k]);
        ck_assert_msg(!memcmp(pix[1][k], pix[3][k], (size_t)nx[1][k] * ny[1][k] * sizeof(double)),
                      "object %d: sky_noise without the sky is not drawn as with it", k);
        /* over the union of the two stamps, zero outside each */
        int ux0 = x0[0][k] < x0[1][k] ? x0[0][k] : x0[1][k], uy0 = y0[0][k] < y0[1][k] ? y0[0][k] : y0[1][k];
        int ux1 = x0[0][k] + nx[0][k] > x0[1][k] + nx[1][k] ? x0[0][k] + nx[0][k] : x0[1][k] + nx[1][k];
        int uy1 = y0[0][k] + ny[0][k] > y0[1][k] + ny[1][k] ? y0[0][k] + ny[0][k] : y0[1][k] + ny[1][k];
        double worst = 0.0;
        for (int yy = uy0; yy < uy1; yy++)
            for (int xx = ux0; xx < ux1; xx++) {
                double v[2];
                for (int m = 0; m < 2; m++) {
                    int in = xx >= x0[m][k] && xx < x0[m][k] + nx[m][k] && yy >= y0[m][k] && yy < y0[m][k] + ny[m][k];
                    v[m] = in ? pix[m][k][(size_t)(yy - y0[m][k]) * nx[m][k] + (xx - x0[m][k])] : 0.0;
                }
                worst = fmax(worst, fabs(v[1] - v[0]));
            }
        printf("noise tolerance: object %d: worst pixel moved by %.3g sky sigma\n", k, worst / sigma);
        ck_assert_msg(worst <= 5.0 * tau * sigma, "object %d: %g sigma", k, worst / sigma);
        if (worst > 0.0) changed++;
        /* magnitude 18: too bright for any knob but the knot lattice's accuracy (measured
         * ~1/100 of its bound) and the Fourier cut's tail bound (acc.cut_tolerance, whose
         * bound adds every dropped mode at its envelope: measured 1/7 of it at most in
         * tests/test_profile.c, 0.016 sigma here) */
        if (k == 0) ck_assert_msg(worst <= 0.1 * tau * sigma, "the magnitude-18 galaxy moved by %g sigma", worst / sigma);
        for (int m = 0; m < 4; m++) free(pix[m][k]);
    }
    ck_assert_msg(changed >= 3, "only %d faint objects took the looser knobs", changed);
    wf_catalog_free(&gal);
}
END_TEST

/* noise_tolerance's scale is the least sky the pointing has on any date, so the objects are
 * drawn alike at two dates whose sky differs (the rates without sky, at its noise, are the
 * same bits); that least sky is below either date's. */
START_TEST(objects_drawn_alike_at_any_date)
{
    enum { N = 12 };
    double x[N], y[N], mag[N];
    for (int i = 0; i < N; i++) {
        x[i] = 30.3 + 17.0 * i;
        y[i] = 50.7 + 15.0 * i;
        mag[i] = 19.0 + 0.8 * i;
    }
    wf_scene_setup ss;
    setup_small(&ss);
    char path[4200];
    snprintf(path, sizeof path, "%s/dates.csv", wf_test_tmpdir());
    write_catalog(path, &ss, 1, 0.2, N, x, y, mag);
    wf_catalog gal;
    ck_assert_msg(wf_catalog_read_galaxies(path, &gal) == WF_OK, "%s", wf_error_message());
    float *img[2];
    double sky_min[2], least[2];
    for (int d = 0; d < 2; d++) {
        setup_small(&ss);
        ss.sky_noise = 1;
        ss.noise_tolerance = 1.0;
        ss.mjd = 61420.0 + 120.0 * d;
        wf_scene *scene;
        ck_assert_msg(wf_scene_create(&ss, &gal, NULL, &scene) == WF_OK, "%s", wf_error_message());
        wf_scene_stats st;
        wf_scene_get_stats(scene, &st);
        sky_min[d] = st.sky_min;
        least[d] = st.sky_least;
        ck_assert_msg(st.knots_smooth > 0 && st.knots_smooth < N, "%ld of %d galaxies with smooth knots",
                      st.knots_smooth, N);
        img[d] = render(scene);
        wf_scene_destroy(scene);
    }
    printf("objects at two dates: least sky %.6f, %.6f; the dates' %.6f, %.6f e-/s\n", least[0], least[1], sky_min[0],
           sky_min[1]);
    ck_assert_msg(fabs(sky_min[1] / sky_min[0] - 1.0) > 0.02, "the two dates' skies differ too little to test");
    ck_assert(least[0] == least[1] && least[0] <= sky_min[0] && least[0] <= sky_min[1]);
    ck_assert_msg(!memcmp(img[0], img[1], sizeof(float) * W * H), "the objects differ between the dates");
    free(img[0]);
    free(img[1]);
    wf_catalog_free(&gal);
}
END_TEST

START_TEST(bright_star_within_budget)
{
    wf_scene_setup ss;
    setup_small(&ss);
    ss.pool_bytes = 4u << 20; /* smaller than the stamp: drawn in pieces */
    const double x[1] = {128.2}, y[1] = {127.7}, mag[1] = {8};
    char path[4200];
    snprintf(path, sizeof path, "%s/bright.csv", wf_test_tmpdir());
    write_catalog(path, &ss, 0, 0.0, 1, x, y, mag);
    wf_catalog stars;
    ck_assert_int_eq(wf_catalog_read_stars(path, &stars), WF_OK);
    wf_scene *scene;
    ck_assert_msg(wf_scene_create(&ss, NULL, &stars, &scene) == WF_OK, "%s", wf_error_message());
    float *img = render(scene);
    wf_bandpass bp;
    wf_bandpass_load(WF_Y106, NULL, &bp);
    double flux = wf_bandpass_countrate_ab(&bp, 8), s = 0;
    for (int i = 0; i < W * H; i++) {
        ck_assert(isfinite(img[i]) && img[i] >= 0.0f);
        s += img[i];
    }
    /* a 28" square holds most of a star's light; the rest is in the wings past the SCA */
    ck_assert_msg(s > 0.97 * flux && s <= 1.0001 * flux, "%.4g of %.4g e-/s", s, flux);
    free(img);
    wf_scene_destroy(scene);
    wf_catalog_free(&stars);
}
END_TEST

/* Set-up runs the drawing works on a helper thread beside the PSF build when there are
 * threads to spare: a bad knob is refused before it starts (with the helper running, the
 * error path joins it), and the same scene comes out whatever the thread count. */
START_TEST(setup_threads)
{
    wf_scene_setup ss;
    setup_small(&ss);
    ss.sky_on = 1;
    ss.threads = 3;
    ss.flux_fraction = 1.5; /* refused by the accuracy check */
    wf_scene *scene = NULL;
    ck_assert_int_ne(wf_scene_create(&ss, NULL, NULL, &scene), WF_OK);
    ck_assert_ptr_null(scene);
    ck_assert_msg(strstr(wf_error_message(), "flux") != NULL, "message: %s", wf_error_message());
    setup_small(&ss);
    ss.threads = 3;
    snprintf(ss.filter, sizeof ss.filter, "Z999"); /* refused once the helper is running */
    ck_assert_int_ne(wf_scene_create(&ss, NULL, NULL, &scene), WF_OK);
    ck_assert_ptr_null(scene);
    ck_assert_msg(strstr(wf_error_message(), "Z999") != NULL, "message: %s", wf_error_message());
    setup_small(&ss);
    ss.sky_on = 1;
    float *img[2];
    for (int k = 0; k < 2; k++) {
        ss.threads = k ? 3 : 1;
        ck_assert_msg(wf_scene_create(&ss, NULL, NULL, &scene) == WF_OK, "%s", wf_error_message());
        img[k] = render(scene);
        wf_scene_destroy(scene);
    }
    ck_assert(memcmp(img[0], img[1], (size_t)W * H * sizeof *img[0]) == 0);
    free(img[0]);
    free(img[1]);
}
END_TEST

/* wf_scene_prepare then wf_scene_populate make wf_scene_create's scene, bit for bit, on one
 * thread and three (the works' helper running across the two steps); a second populate is
 * refused; a scene prepared and never populated, or whose populate failed, is destroyed
 * cleanly (the sanitizers' run checks the helper is joined and nothing leaks). */
START_TEST(prepare_then_populate)
{
    wf_scene_setup ss;
    setup_small(&ss);
    ss.sky_on = 1;
    const double x[3] = {60, 128.3, 200}, y[3] = {70, 128.6, 190}, mag[3] = {19, 20, 21};
    char path[4200];
    snprintf(path, sizeof path, "%s/gal2.csv", wf_test_tmpdir());
    write_catalog(path, &ss, 1, 0.2, 3, x, y, mag);
    wf_catalog gal;
    ck_assert_msg(wf_catalog_read_galaxies(path, &gal) == WF_OK, "%s", wf_error_message());
    for (int th = 1; th <= 3; th += 2) {
        ss.threads = th;
        wf_scene *one = NULL, *two = NULL;
        ck_assert_msg(wf_scene_create(&ss, &gal, NULL, &one) == WF_OK, "%s", wf_error_message());
        ck_assert_msg(wf_scene_prepare(&ss, &two) == WF_OK, "%s", wf_error_message());
        ck_assert_msg(wf_scene_populate(two, &gal, NULL, NULL, 0) == WF_OK, "%s", wf_error_message());
        ck_assert_int_ne(wf_scene_populate(two, &gal, NULL, NULL, 0), WF_OK);
        float *a = render(one), *b = render(two);
        ck_assert(memcmp(a, b, (size_t)W * H * sizeof *a) == 0);
        wf_scene_stats sa, sb;
        wf_scene_get_stats(one, &sa);
        wf_scene_get_stats(two, &sb);
        ck_assert_int_eq(sa.galaxies, 3);
        ck_assert_int_eq(sb.galaxies, 3);
        double total = 0;
        for (int i = 0; i < W * H; i++) total += a[i];
        ck_assert(total > 0);
        free(a);
        free(b);
        wf_scene_destroy(one);
        wf_scene_destroy(two);
        /* prepared and dropped */
        ck_assert_msg(wf_scene_prepare(&ss, &two) == WF_OK, "%s", wf_error_message());
        wf_scene_destroy(two);
    }
    /* a populate that fails (a supernova whose flux slope is not finite) leaves a scene that
     * destroys cleanly */
    wf_scene_sn sn = {0};
    sn.id = 9;
    wf_wcs w;
    wf_focal_plane fp;
    wf_wcs_focal_plane(NULL, &fp);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, ss.ra, ss.dec, ss.pa, ss.sca, &w), WF_OK);
    ck_assert_int_eq(wf_wcs_pix2world(&w, 100.0, 100.0, &sn.ra, &sn.dec), WF_OK);
    sn.mag = 22.0;
    sn.dlnf_dt = NAN;
    wf_scene *bad = NULL;
    ck_assert_msg(wf_scene_prepare(&ss, &bad) == WF_OK, "%s", wf_error_message());
    ck_assert_int_ne(wf_scene_populate(bad, &gal, NULL, &sn, 1), WF_OK);
    ck_assert_msg(strstr(wf_error_message(), "slope") != NULL, "message: %s", wf_error_message());
    wf_scene_destroy(bad);
    /* one that fails before it waits for the works' helper (a noise tolerance it refuses):
     * destroy joins the helper, which may still be writing into the scene */
    ss.threads = 3;
    ss.noise_tolerance = -1.0;
    ck_assert_msg(wf_scene_prepare(&ss, &bad) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(wf_scene_populate(bad, &gal, NULL, NULL, 0), WF_ERR_RANGE);
    ck_assert_msg(strstr(wf_error_message(), "noise_tolerance") != NULL, "message: %s", wf_error_message());
    wf_scene_destroy(bad);
    wf_catalog_free(&gal);
}
END_TEST

START_TEST(empty_scene_is_sky)
{
    wf_scene_setup ss;
    setup_small(&ss);
    ss.sky_on = 1;
    wf_scene *scene;
    ck_assert_msg(wf_scene_create(&ss, NULL, NULL, &scene) == WF_OK, "%s", wf_error_message());
    float *img = render(scene);
    wf_scene_stats st;
    wf_scene_get_stats(scene, &st);
    ck_assert(st.sky_min > 0.2 && st.sky_max < 0.6); /* Y106 near the deep field, SPEC §2 */
    for (int i = 0; i < W * H; i++) ck_assert(img[i] >= st.sky_min - 1e-6 && img[i] <= st.sky_max + 1e-6);
    free(img);
    wf_scene_destroy(scene);
}
END_TEST

/* |DFT| of a stamp at (fx, fy) cycles/pixel. */
static double stamp_dft(const double *pix, int nx, int ny, double fx, double fy)
{
    double re = 0, im = 0;
    for (int j = 0; j < ny; j++)
        for (int i = 0; i < nx; i++) {
            double ph = -2.0 * M_PI * (fx * i + fy * j), v = pix[(size_t)j * nx + i];
            re += v * cos(ph);
            im += v * sin(ph);
        }
    return hypot(re, im);
}

/* One star drawn with the PSF options of the scene: chromatic keeps the flux and changes the
 * profile; jitter and diffusion multiply the transfer function by exp(-2 pi^2 sigma^2 f^2)
 * (Gaussian convolution), checked on the stamp's DFT at low frequency where aliasing of the
 * undersampled PSF is small (tolerance: that aliasing, ~1-2%). */
START_TEST(psf_modes_chromatic_jitter_diffusion)
{
    const double x[1] = {128.3}, y[1] = {127.6}, mag[1] = {18};
    char path[4200];
    wf_scene_setup ss;
    setup_small(&ss);
    ss.flux_fraction = 0.9999;
    snprintf(path, sizeof path, "%s/one.csv", wf_test_tmpdir());
    write_catalog(path, &ss, 0, 0.0, 1, x, y, mag);
    wf_catalog stars;
    ck_assert_int_eq(wf_catalog_read_stars(path, &stars), WF_OK);
    wf_bandpass bp;
    wf_bandpass_load(WF_Y106, NULL, &bp);
    const double flux = wf_bandpass_countrate_ab(&bp, mag[0]);
    double *pix[4];
    int nx[4], ny[4];
    double lam[4];
    for (int m = 0; m < 4; m++) {
        setup_small(&ss);
        ss.flux_fraction = 0.9999;
        if (m == 1) ss.psf_nlambda = 8;
        if (m == 2) ss.jitter = 0.1;
        if (m == 3) ss.diffusion = 1.0;
        wf_scene *scene;
        ck_assert_msg(wf_scene_create(&ss, NULL, &stars, &scene) == WF_OK, "%s", wf_error_message());
        wf_scene_object info;
        int x0, y0;
        ck_assert_int_eq(wf_scene_draw_object(scene, 0, &info, &x0, &y0, &nx[m], &ny[m], &pix[m]), WF_OK);
        wf_scene_stats st;
        wf_scene_get_stats(scene, &st);
        lam[m] = st.psf_lambda_nm;
        double sum = 0;
        for (int k = 0; k < nx[m] * ny[m]; k++) sum += pix[m][k];
        ck_assert_msg(fabs(sum / flux - 1) < 2e-4, "mode %d: stamp holds %.6f of the flux", m, sum / flux);
        wf_scene_destroy(scene);
    }
    /* chromatic: a photon-weighted mean wavelength inside the band, and a different profile */
    ck_assert(lam[1] > bp.blue_nm && lam[1] < bp.red_nm && lam[1] != lam[0]);
    double f0 = stamp_dft(pix[0], nx[0], ny[0], 0.25, 0.0), f1 = stamp_dft(pix[1], nx[1], ny[1], 0.25, 0.0);
    ck_assert_msg(fabs(f1 / f0 - 1) > 1e-4 && fabs(f1 / f0 - 1) < 0.05, "chromatic/achromatic at 0.25 c/px: %.5f", f1 / f0);
    /* jitter 0.1" = 0.909 px; diffusion 1 px (large, so that 0.1 cycles/px shows it while the
     * alias from 0.9 cycles/px stays small) */
    const double sj = 0.1 / 0.11, sd = 1.0;
    for (int a = 0; a < 2; a++) {
        double fx = a ? 0.0 : 0.1, fy = a ? 0.1 : 0.0;
        double r = stamp_dft(pix[2], nx[2], ny[2], fx, fy) / stamp_dft(pix[0], nx[0], ny[0], fx, fy);
        double want = exp(-2 * M_PI * M_PI * sj * sj * 0.01);
        ck_assert_msg(fabs(r - want) < 0.02, "jitter: transfer %.4f, Gaussian %.4f", r, want);
        r = stamp_dft(pix[3], nx[3], ny[3], fx, fy) / stamp_dft(pix[0], nx[0], ny[0], fx, fy);
        want = exp(-2 * M_PI * M_PI * sd * sd * 0.01);
        ck_assert_msg(fabs(r - want) < 0.02, "diffusion: transfer %.4f, Gaussian %.4f", r, want);
    }
    for (int m = 0; m < 4; m++) free(pix[m]);
    wf_catalog_free(&stars);
}
END_TEST

/* A magnitude-10 star with the wide PSF: its stamp reaches past the narrow PSF image's 3.5"
 * and the light in the annulus from 4" to 90% of the stamp's half-width (halo and spikes) is
 * the PSF module's own (a pupil_bin 4 image with the pixel, drawn directly at 0.11", 28"
 * wide) to 5%; without it (psf.bright_mag -99) the annulus stays dark. Flux is kept. */
START_TEST(bright_star_wide_psf)
{
    const double x[1] = {128.3}, y[1] = {127.6}, mag[1] = {10};
    char path[4200];
    wf_scene_setup ss;
    setup_small(&ss);
    snprintf(path, sizeof path, "%s/bright10.csv", wf_test_tmpdir());
    write_catalog(path, &ss, 0, 0.0, 1, x, y, mag);
    wf_catalog stars;
    ck_assert_int_eq(wf_catalog_read_stars(path, &stars), WF_OK);
    wf_bandpass bp;
    wf_bandpass_load(WF_Y106, NULL, &bp);
    const double flux = wf_bandpass_countrate_ab(&bp, mag[0]);
    double ann[2], size[2], rout = 0, build = 0;
    for (int m = 0; m < 2; m++) {
        setup_small(&ss);
        ss.bright_mag = m ? -99.0 : 15.0;
        wf_scene *scene;
        ck_assert_msg(wf_scene_create(&ss, NULL, &stars, &scene) == WF_OK, "%s", wf_error_message());
        wf_scene_stats st;
        wf_scene_get_stats(scene, &st);
        ck_assert_int_eq(st.bright, m ? 0 : 1);
        if (m == 0) build = st.wide_psf_seconds;
        wf_scene_object info;
        int x0, y0, nx, ny;
        double *pix;
        ck_assert_int_eq(wf_scene_draw_object(scene, 0, &info, &x0, &y0, &nx, &ny, &pix), WF_OK);
        double sum = 0, a = 0;
        if (m == 0) rout = 0.9 * 0.5 * (nx < ny ? nx : ny) * 0.11;
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++) {
                double r = hypot(x0 + i - x[0], y0 + j - y[0]) * 0.11, v = pix[(size_t)j * nx + i];
                sum += v;
                if (r >= 4.0 && r < rout) a += v;
            }
        ck_assert_msg(fabs(sum / flux - 1) < 6e-3, "mode %d: stamp holds %.5f of the flux", m, sum / flux);
        ann[m] = a / flux;
        size[m] = nx;
        free(pix);
        wf_scene_destroy(scene);
    }
    /* the same PSF drawn by the PSF module at the detector pixel, 28" wide */
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.sca = 1;
    o.pupil_bin = 4;
    ck_assert_int_eq(wf_pupil_group_of_filter("Y106", &o.group), WF_OK);
    double lam = bp.lambda_eff_nm, w = 1.0;
    wf_psf *psf;
    ck_assert_int_eq(wf_psf_build_optics(&o, &lam, &w, 1, &psf), WF_OK);
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = 256;
    d.cx = d.cy = 127.5;
    double *img = malloc(sizeof(double) * 256 * 256), tot = 0, a = 0;
    ck_assert_int_eq(wf_psf_draw(psf, &d, img), WF_OK);
    for (int j = 0; j < 256; j++)
        for (int i = 0; i < 256; i++) {
            double r = hypot(i - 127.5, j - 127.5) * 0.11, v = img[j * 256 + i];
            tot += v;
            if (r >= 4.0 && r < rout) a += v;
        }
    free(img);
    wf_psf_free(psf);
    ck_assert_msg(size[0] > 2 * 3.5 / 0.11 && size[0] > size[1] && rout > 4.5, "wide stamp %g px, narrow %g px",
                  size[0], size[1]);
    /* same PSF, drawn two ways (the drawer's Fourier table and stamp vs a direct draw with
     * the pixel): a plumbing check of the wide path, measured 0.3% */
    ck_assert_msg(fabs(ann[0] / (a / tot) - 1) < 0.01, "annulus 4\"-%.1f\": scene %.3e of the flux, PSF module %.3e", rout,
                  ann[0], a / tot);
    /* the narrow stamp ends inside 4": the halo is the wide PSF's alone */
    ck_assert_msg(size[1] * 0.11 / 2 < 4.0, "narrow stamp %g px reaches the annulus", size[1]);
    printf("bright star: wide stamp %.0f px (narrow %.0f), annulus 4\"-%.1f\" holds %.3e of the flux (PSF module "
           "%.3e); wide PSF built in %.2f s\n", size[0], size[1], rout, ann[0], a / tot, build);
    wf_catalog_free(&stars);
}
END_TEST


/* The PSF cache: scenes that share an SCA, filter and PSF knobs take one PSF, built once (its
 * wide PSF too), and draw the same bits as scenes that build their own, at another pointing
 * and date as well; a scene of other knobs builds its own and, the cache full, evicts the one
 * a live scene still holds, which keeps drawing from it (the sanitizers' run checks it is
 * freed once, by the last holder). */
START_TEST(psf_cache_shares_the_same_bits)
{
    const double x[3] = {60, 128.3, 200}, y[3] = {70, 128.6, 190}, mag[3] = {19, 20, 21}, smag[1] = {10};
    const double sx[1] = {150.2}, sy[1] = {90.7};
    char gpath[4200], spath[4200];
    wf_scene_setup ss;
    setup_small(&ss);
    ss.sky_on = 1;
    snprintf(gpath, sizeof gpath, "%s/gal_cache.csv", wf_test_tmpdir());
    snprintf(spath, sizeof spath, "%s/star_cache.csv", wf_test_tmpdir());
    write_catalog(gpath, &ss, 1, 0.2, 3, x, y, mag);
    write_catalog(spath, &ss, 0, 0.0, 1, sx, sy, smag);
    wf_catalog gal, stars;
    ck_assert_msg(wf_catalog_read_galaxies(gpath, &gal) == WF_OK, "%s", wf_error_message());
    ck_assert_msg(wf_catalog_read_stars(spath, &stars) == WF_OK, "%s", wf_error_message());
    wf_scene_psf_cache *cache;
    ck_assert_int_eq(wf_scene_psf_cache_new(0, &cache), WF_ERR_RANGE);
    ck_assert_int_eq(wf_scene_psf_cache_new(1, &cache), WF_OK);
    wf_scene_psf_cache_stats cs;
    /* two exposures: the catalog's pointing, then one 1" away a day later */
    for (int e = 0; e < 2; e++) {
        wf_scene_setup es = ss;
        es.dec += e / 3600.0;
        es.mjd += e;
        float *img[2];
        for (int c = 0; c < 2; c++) {
            es.psf_cache = c ? cache : NULL;
            es.threads = c ? 2 : 1; /* the tables are the same for any thread count */
            wf_scene *scene;
            ck_assert_msg(wf_scene_create(&es, &gal, &stars, &scene) == WF_OK, "%s", wf_error_message());
            wf_scene_stats st;
            wf_scene_get_stats(scene, &st);
            ck_assert_int_eq(st.bright, 1);
            ck_assert_int_eq(st.galaxies, 3);
            wf_scene_source src;
            ck_assert_int_eq(wf_scene_source_for(scene, c ? 1 : 0, &src), WF_OK);
            img[c] = malloc(sizeof(float) * W * H);
            for (int y0 = 0; y0 < H; y0 += 32)
                ck_assert_int_eq(wf_scene_fill(&src, y0, y0 + 32, W, img[c] + (size_t)y0 * W), WF_OK);
            wf_scene_destroy(scene);
        }
        ck_assert_msg(memcmp(img[0], img[1], (size_t)W * H * sizeof *img[0]) == 0, "exposure %d differs", e);
        double total = 0;
        for (int i = 0; i < W * H; i++) total += img[1][i];
        ck_assert(total > 0);
        free(img[0]);
        free(img[1]);
        wf_scene_psf_cache_get_stats(cache, &cs);
        ck_assert_int_eq(cs.built, 1);
        ck_assert_int_eq(cs.reused, e);
        ck_assert_int_eq(cs.wide_built, 1);
    }
    /* a scene holds the kept PSF while another SCA's evicts it */
    wf_scene *held, *other;
    ss.psf_cache = cache;
    ck_assert_msg(wf_scene_create(&ss, &gal, NULL, &held) == WF_OK, "%s", wf_error_message());
    wf_scene_setup os = ss;
    os.sca = 2;
    ck_assert_msg(wf_scene_create(&os, NULL, NULL, &other) == WF_OK, "%s", wf_error_message());
    wf_scene_psf_cache_get_stats(cache, &cs);
    ck_assert_int_eq(cs.built, 2);
    ck_assert_int_eq(cs.reused, 2);
    float *a = render(held);
    ss.psf_cache = NULL;
    wf_scene *own;
    ck_assert_msg(wf_scene_create(&ss, &gal, NULL, &own) == WF_OK, "%s", wf_error_message());
    float *b = render(own);
    ck_assert(memcmp(a, b, (size_t)W * H * sizeof *a) == 0);
    free(a);
    free(b);
    wf_scene_destroy(own);
    wf_scene_destroy(held);
    wf_scene_psf_cache_free(cache); /* other's PSF outlives the cache until other goes */
    free(render(other));
    wf_scene_destroy(other);
    wf_catalog_free(&gal);
    wf_catalog_free(&stars);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("scene");
    TCase *tc = tcase_create("scene");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, star_fluxes_and_positions);
    tcase_add_test(tc, psf_modes_chromatic_jitter_diffusion);
    tcase_add_test(tc, galaxies_edges_and_extremes);
    tcase_add_test(tc, bright_star_within_budget);
    tcase_add_test(tc, bright_star_wide_psf);
    tcase_add_test(tc, empty_scene_is_sky);
    tcase_add_test(tc, setup_threads);
    tcase_add_test(tc, prepare_then_populate);
    tcase_add_test(tc, psf_cache_shares_the_same_bits);
    tcase_add_test(tc, noise_tolerance_bounds);
    tcase_add_test(tc, objects_drawn_alike_at_any_date);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
