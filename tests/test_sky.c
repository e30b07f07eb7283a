/* Sky background (sim/optics/sky.c), checked against values derived outside it:
 *  - the Sun's longitude at equinoxes and solstices (published instants, UTC), which are
 *    0°, 90°, 180°, 270° of apparent longitude of date by definition;
 *  - the ecliptic rotation at points whose ecliptic coordinates are known exactly (the
 *    equinox, the solstice point, the ecliptic pole) and at the deep field against GalSim;
 *  - with ../shared: zodiacal levels at the deep field (RA 71°, Dec -53°) on the dates of
 *    reference/galsim/facts.json (read here at run time) against GalSim's getSkyLevel, per
 *    filter, with the percentage differences printed; the built-in law against the table;
 *  - positions too close to the Sun, bad dates and bad files: clear errors. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "sim/optics/sky.h"
#include "tests/testutil.h"

#define DEG (M_PI / 180.0)
#define PIXEL_AREA 0.0121 /* 0.11" nominal pixel, as GalSim's facts per pixel */

static const wf_filter all_filters[WF_NFILTER] = {WF_R062, WF_Z087, WF_Y106, WF_J129,
                                                  WF_H158, WF_F184, WF_K213, WF_W146};

/* ------------------------------------------------------------------ small helpers */


static char *load_facts(void)
{
    const char *ref = wf_test_reference_dir();
    if (!ref) return NULL;
    char path[4200];
    snprintf(path, sizeof path, "%s/facts.json", ref);
    return wf_test_slurp(path, NULL);
}

static void copy_dir(char *dst, size_t n, const char *src) { snprintf(dst, n, "%s", src); }

static double angdiff(double a, double b)
{
    double d = fmod(a - b, 360.0);
    if (d > 180.0) d -= 360.0;
    if (d < -180.0) d += 360.0;
    return d;
}

/* RA, Dec of a point on the J2000 ecliptic (latitude 0) at longitude lam_deg. */
static void ecliptic_point(double lam_deg, double *ra, double *dec)
{
    double e = WF_SKY_OBLIQUITY_J2000_DEG * DEG, l = lam_deg * DEG;
    *ra = fmod(atan2(cos(e) * sin(l), cos(l)) / DEG + 360.0, 360.0);
    *dec = asin(sin(e) * sin(l)) / DEG;
}

/* ------------------------------------------------------------------ Sun and ecliptic */

START_TEST(test_sun_equinoxes_solstices)
{
    /* Instants (UTC) of the March equinox, June solstice, ... as published by the USNO /
     * IMCCE: the Sun's apparent longitude of date is then exactly 0, 90, 180, 270 deg. The
     * low-precision formula is good to ~0.01 deg; aberration and nutation (the apparent vs
     * mean difference) add <= 0.011 deg; the bar is 0.02 deg (29 minutes of the Sun's
     * motion). */
    static const struct {
        const char *when;
        double mjd, lon;
    } ev[] = {
        {"2000-03-20 07:35", 51623.315972, 0.0},   {"2000-06-21 01:48", 51716.075000, 90.0},
        {"2024-03-20 03:06", 60389.129167, 0.0},   {"2024-06-20 20:51", 60481.868750, 90.0},
        {"2024-09-22 12:44", 60575.530556, 180.0}, {"2024-12-21 09:20", 60665.388889, 270.0},
    };
    for (size_t i = 0; i < sizeof ev / sizeof ev[0]; i++) {
        double of_date, j2000;
        ck_assert_int_eq(wf_sky_sun_longitude(ev[i].mjd, &of_date, &j2000), WF_OK);
        double d = angdiff(of_date, ev[i].lon);
        printf("  Sun at %s UTC: longitude of date %8.4f deg (expected %5.1f, diff %+.4f); "
               "J2000 %8.4f\n",
               ev[i].when, of_date, ev[i].lon, d, j2000);
        ck_assert_msg(fabs(d) < 0.02, "%s: %.4f vs %.1f", ev[i].when, of_date, ev[i].lon);
        ck_assert(of_date >= 0.0 && of_date < 360.0);
    }
    /* J2000 vs of date: the general precession, 50.29"/yr, i.e. -0.3772 deg at 2027.0 */
    double of_date, j2000;
    ck_assert_int_eq(wf_sky_sun_longitude(61406.0, &of_date, &j2000), WF_OK);
    ck_assert_double_eq_tol(angdiff(j2000, of_date), -5028.796 / 3600.0 * (61406.0 - 51544.5) /
                                                         36525.0, 1e-12);
    ck_assert_double_eq_tol(angdiff(j2000, of_date), -0.3772, 2e-4);
    ck_assert_int_eq(wf_sky_sun_longitude(61406.0, NULL, NULL), WF_OK);
}
END_TEST

START_TEST(test_ecliptic_rotation)
{
    double eps = WF_SKY_OBLIQUITY_J2000_DEG, lon, lat;
    ck_assert_double_eq_tol(eps, 23.4392794, 1e-7);
    ck_assert_int_eq(wf_sky_ecliptic(0.0, 0.0, &lon, &lat), WF_OK);
    ck_assert_double_eq_tol(lon, 0.0, 1e-12);
    ck_assert_double_eq_tol(lat, 0.0, 1e-12);
    ck_assert_int_eq(wf_sky_ecliptic(90.0, eps, &lon, &lat), WF_OK); /* June solstice point */
    ck_assert_double_eq_tol(lon, 90.0, 1e-9);
    ck_assert_double_eq_tol(lat, 0.0, 1e-9);
    ck_assert_int_eq(wf_sky_ecliptic(180.0, 0.0, &lon, &lat), WF_OK);
    ck_assert_double_eq_tol(lon, 180.0, 1e-9);
    ck_assert_double_eq_tol(lat, 0.0, 1e-9);
    ck_assert_int_eq(wf_sky_ecliptic(270.0, 90.0 - eps, &lon, &lat), WF_OK); /* north pole */
    ck_assert_double_eq_tol(lat, 90.0, 1e-6);
    for (double l = 0.0; l < 360.0; l += 37.0) { /* ecliptic points round-trip */
        double ra, dec;
        ecliptic_point(l, &ra, &dec);
        ck_assert_int_eq(wf_sky_ecliptic(ra, dec, &lon, &lat), WF_OK);
        ck_assert_double_eq_tol(angdiff(lon, l), 0.0, 1e-9);
        ck_assert_double_eq_tol(lat, 0.0, 1e-9);
    }
    ck_assert_int_eq(wf_sky_ecliptic(10.0, 91.0, &lon, &lat), WF_ERR_RANGE);
    ck_assert_int_eq(wf_sky_ecliptic(NAN, 0.0, &lon, &lat), WF_ERR_RANGE);

}
END_TEST

/* wf_sky_zodiacal_least is the least level over the dates of a year on which the target is
 * within the field of regard (54-126 degrees from the Sun), found by stepping the date
 * (0.02 day, ~0.02 degree of the Sun's path): for a target near the ecliptic pole (the deep
 * field, always in the field of regard), one on the ecliptic, and one between, both models. */
START_TEST(test_zodiacal_least_over_a_year)
{
    const double pos[3][2] = {{71.0, -53.0}, {150.0, 13.0}, {300.0, -45.0}};
    for (int model = 0; model < 2; model++) {
        wf_sky_model *m = malloc(sizeof *m);
        ck_assert_int_eq(wf_sky_builtin(m), WF_OK);
        if (model == 1) {
            const char *data = wf_test_data_dir();
            if (!data) {
                free(m);
                printf("  zodiacal least: the table is absent, built-in law only\n");
                break;
            }
            ck_assert_int_eq(wf_sky_load(data, m), WF_OK);
            ck_assert_int_eq(m->from_table, 1);
        }
        for (int p = 0; p < 3; p++) {
            double least, brute = INFINITY;
            ck_assert_int_eq(wf_sky_zodiacal_least(m, WF_Y106, pos[p][0], pos[p][1], &least), WF_OK);
            int in = 0;
            for (double mjd = 61000.0; mjd < 61365.25; mjd += 0.02) {
                double el, z;
                ck_assert_int_eq(wf_sky_sun_relative(pos[p][0], pos[p][1], mjd, NULL, NULL, &el), WF_OK);
                if (el < WF_SKY_REGARD_MIN_DEG || el > WF_SKY_REGARD_MAX_DEG) continue;
                ck_assert_int_eq(wf_sky_zodiacal(m, WF_Y106, pos[p][0], pos[p][1], mjd, &z), WF_OK);
                if (z < brute) brute = z;
                in++;
            }
            printf("  zodiacal least (%s) at (%g, %g): %.12g, over the year's dates %.12g (%d in the field of regard)\n",
                   model ? "table" : "law", pos[p][0], pos[p][1], least, brute, in);
            ck_assert_int_gt(in, 100);
            /* The bounds, from the model's steepest slope in dlon over the field of regard (per
             * degree, differences over 0.05 degree): the dates step the Sun by at most 0.0204
             * degree (0.02 day at 1.019 degree a day), so the least over the year lies within
             * slope x 0.0204 below the dates' (at an end of the interval); the table is linear
             * between nodes, so its least is exact and at most the dates'; the law's lies within
             * half a 1/8 degree step of its true least, so at most slope / 16 above the dates'. */
            double lon, lat, slope = 0.0, prev = NAN;
            ck_assert_int_eq(wf_sky_ecliptic(pos[p][0], pos[p][1], &lon, &lat), WF_OK);
            for (double dl = 0.0; dl <= 180.0; dl += 0.05) {
                double ce = cos(lat * M_PI / 180.0) * cos(dl * M_PI / 180.0), z;
                if (ce > cos(WF_SKY_REGARD_MIN_DEG * M_PI / 180.0) || ce < cos(WF_SKY_REGARD_MAX_DEG * M_PI / 180.0)) {
                    prev = NAN;
                    continue;
                }
                ck_assert_int_eq(wf_sky_zodiacal_ecliptic(m, WF_Y106, dl, lat, &z), WF_OK);
                if (prev == prev) slope = fmax(slope, fabs(z - prev) / 0.05);
                prev = z;
            }
            const double below = slope * 0.0204, above = model ? brute * 1e-12 : slope / 16.0;
            printf("  zodiacal least: steepest slope %.4g per degree: bounds -%.3g, +%.3g\n", slope, below, above);
            ck_assert_msg(least <= brute + above, "least %.12g above a date's %.12g", least, brute);
            ck_assert_msg(least >= brute - below, "least %.12g below every date's %.12g by more than %g", least, brute,
                          below);
        }
        free(m);
    }
}
END_TEST

/* The deep field against GalSim (which uses the obliquity of 2025: 0.003 deg less). */
START_TEST(test_ecliptic_deep_field)
{
    double lon, lat;
    ck_assert_int_eq(wf_sky_ecliptic(71.0, -53.0, &lon, &lat), WF_OK);
    char *facts = load_facts();
    if (!facts) WF_SKIP("../shared/reference/galsim (deep-field ecliptic coordinates)");
    const char *kl[] = {"sky_position", "ecliptic_lon_deg_epoch2025"};
    const char *kb[] = {"sky_position", "ecliptic_lat_deg"};
    double glon = wf_test_json_number(facts, kl, 2), glat = wf_test_json_number(facts, kb, 2);
    free(facts);
    printf("  deep field: ecliptic (%.4f, %.4f) deg; GalSim (2025 obliquity) (%.4f, %.4f): "
           "diff (%+.4f, %+.4f)\n",
           lon, lat, glon, glat, lon - glon, lat - glat);
    ck_assert_double_eq_tol(lon, glon, 0.02);
    ck_assert_double_eq_tol(lat, glat, 0.02);
}
END_TEST

START_TEST(test_bad_inputs)
{
    static wf_sky_model m;
    ck_assert_int_eq(wf_sky_builtin(&m), WF_OK);
    double z, r;
    /* a Julian date where an MJD belongs */
    ck_assert_int_eq(wf_sky_zodiacal(&m, WF_Y106, 71.0, -53.0, 2461406.5, &z), WF_ERR_RANGE);
    ck_assert_msg(strstr(wf_error_message(), "Julian") != NULL, "%s", wf_error_message());
    ck_assert_int_eq(wf_sky_zodiacal(&m, WF_Y106, 71.0, -53.0, NAN, &z), WF_ERR_RANGE);
    ck_assert_int_eq(wf_sky_zodiacal(&m, WF_Y106, 71.0, -95.0, 61406.0, &z), WF_ERR_RANGE);
    ck_assert_int_eq(wf_sky_zodiacal(&m, (wf_filter)WF_NFILTER, 71.0, -53.0, 61406.0, &z),
                     WF_ERR_RANGE);
    ck_assert_int_eq(wf_sky_rate(&m, WF_Y106, 71.0, -53.0, 61406.0, 0.0, 1, 1, &r), WF_ERR_RANGE);
    ck_assert_int_eq(wf_sky_rate(&m, WF_Y106, 71.0, -53.0, 61406.0, NAN, 1, 1, &r), WF_ERR_RANGE);
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, WF_Y106, NAN, 0.0, &z), WF_ERR_RANGE);
    ck_assert_int_eq(wf_sky_thermal((wf_filter)-1, &z), WF_ERR_RANGE);
}
END_TEST

/* ------------------------------------------------------------------ built-in model */

START_TEST(test_builtin_rate_composition)
{
    static wf_sky_model m;
    ck_assert_int_eq(wf_sky_load(NULL, &m), WF_OK);
    ck_assert_int_eq(m.from_table, 0);
    ck_assert_msg(strstr(m.source, "no data directory") != NULL, "%s", m.source);
    const char *tmp = wf_test_tmpdir();
    ck_assert_int_eq(wf_sky_load(tmp, &m), WF_OK);
    ck_assert_int_eq(m.from_table, 0);
    ck_assert_msg(strstr(m.source, "not found") && strstr(m.source, tmp), "%s", m.source);

    static const double spec_thermal[WF_NFILTER] = {0, 0, 0, 0, 0.04, 0.17, 4.52, 0.98};
    /* SPEC §2 deep-field values at the law's anchor (|β| 73.55°, 90° from the Sun) */
    static const struct {
        wf_filter f;
        double v;
    } spec_deep[] = {{WF_Y106, 29.7}, {WF_J129, 30.2}, {WF_H158, 29.6}, {WF_F184, 16.9}};
    for (size_t i = 0; i < sizeof spec_deep / sizeof spec_deep[0]; i++) {
        double z;
        ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, spec_deep[i].f, 90.0, -73.55, &z), WF_OK);
        ck_assert_double_eq_tol(z, spec_deep[i].v, 1e-9);
    }
    for (int i = 0; i < WF_NFILTER; i++) {
        wf_filter f = all_filters[i];
        double z, th, r0, r1, r2, r3;
        ck_assert_int_eq(wf_sky_thermal(f, &th), WF_OK);
        ck_assert_double_eq(th, spec_thermal[i]);
        ck_assert_int_eq(wf_sky_zodiacal(&m, f, 71.0, -53.0, 61496.0, &z), WF_OK);
        ck_assert(z > 5.0 && z < 150.0);
        ck_assert_int_eq(wf_sky_rate(&m, f, 71.0, -53.0, 61496.0, 0.0116, 0, 0, &r0), WF_OK);
        ck_assert_int_eq(wf_sky_rate(&m, f, 71.0, -53.0, 61496.0, 0.0116, 1, 0, &r1), WF_OK);
        ck_assert_int_eq(wf_sky_rate(&m, f, 71.0, -53.0, 61496.0, 0.0116, 0, 1, &r2), WF_OK);
        ck_assert_int_eq(wf_sky_rate(&m, f, 71.0, -53.0, 61496.0, 0.0116, 1, 1, &r3), WF_OK);
        ck_assert_double_eq_tol(r0, z * 0.0116, 1e-15);
        ck_assert_double_eq_tol(r1, z * 0.0116 * 1.1, 1e-15);
        ck_assert_double_eq_tol(r2, z * 0.0116 + th, 1e-15);
        ck_assert_double_eq_tol(r3, z * 0.0116 * 1.1 + th, 1e-15);
    }
    /* symmetric in β and Δλ; pole independent of Δλ */
    double a, b;
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, WF_J129, 70.0, 20.0, &a), WF_OK);
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, WF_J129, -70.0, -20.0, &b), WF_OK);
    ck_assert_double_eq_tol(a, b, 1e-12);
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, WF_J129, 0.0, 90.0, &a), WF_OK);
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, WF_J129, 150.0, 90.0, &b), WF_OK);
    ck_assert_double_eq_tol(a, b, 1e-12);
}
END_TEST

/* Pointing at the Sun, and near it, is an error with both models. */
static void check_sun_exclusion(const wf_sky_model *m)
{
    double sun, ra, dec, z;
    ck_assert_int_eq(wf_sky_sun_longitude(61500.3, NULL, &sun), WF_OK);
    ecliptic_point(sun, &ra, &dec);
    ck_assert_int_eq(wf_sky_zodiacal(m, WF_H158, ra, dec, 61500.3, &z), WF_ERR_RANGE);
    const char *msg = wf_error_message();
    ck_assert_msg(strstr(msg, "too close to the Sun") && strstr(msg, "H158") &&
                      strstr(msg, "MJD 61500.300"),
                  "%s", msg);
    printf("  %s: at the Sun -> %s\n", m->from_table ? "table" : "built-in", msg);
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(m, WF_Y106, 10.0, 0.0, &z), WF_ERR_RANGE);
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(m, WF_Y106, -12.0, 5.0, &z), WF_ERR_RANGE);
    /* 30 deg from the Sun on the ecliptic is observable (for the model, not for Roman) */
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(m, WF_Y106, 30.0, 0.0, &z), WF_OK);
    ck_assert(z > 200.0);
    /* the anti-solar point and the poles are edges of the grid, not out of it */
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(m, WF_Y106, 180.0, 0.0, &z), WF_OK);
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(m, WF_Y106, -180.0, -90.0, &z), WF_OK);
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(m, WF_Y106, 0.0, 90.0, &z), WF_OK);
}

START_TEST(test_sun_exclusion_builtin)
{
    static wf_sky_model m;
    ck_assert_int_eq(wf_sky_builtin(&m), WF_OK);
    check_sun_exclusion(&m);
}
END_TEST

/* ------------------------------------------------------------------ table, GalSim */

static int load_table(wf_sky_model *m)
{
    const char *data = wf_test_data_dir();
    if (!data) return 0;
    char dir[4096];
    copy_dir(dir, sizeof dir, data);
    ck_assert_int_eq(wf_sky_load(dir, m), WF_OK);
    ck_assert_int_eq(m->from_table, 1);
    ck_assert_msg(strstr(m->source, "roman_sky_backgrounds.txt") != NULL, "%s", m->source);
    return 1;
}

START_TEST(test_sun_exclusion_table)
{
    static wf_sky_model m;
    if (!load_table(&m)) WF_SKIP("../shared/data not found (set WFISIM_DATA)");
    check_sun_exclusion(&m);
}
END_TEST

START_TEST(test_table_grid)
{
    static wf_sky_model m;
    if (!load_table(&m)) WF_SKIP("../shared/data not found (set WFISIM_DATA)");
    double z, a, b;
    /* on a node the interpolation returns the node */
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, WF_Y106, 88.0, asin(20.0 / 41.0) / DEG, &z),
                     WF_OK);
    ck_assert_double_eq_tol(z, m.table[WF_Y106][22][20], 1e-9);
    /* the pole row of the file is the same for every longitude (checked, not assumed) */
    for (int j = 0; j < WF_SKY_NLON; j++)
        ck_assert_double_eq_tol(m.table[WF_Y106][j][41], m.table[WF_Y106][0][41], 1e-9);
    /* symmetric in β and Δλ */
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, WF_F184, 101.3, 33.3, &a), WF_OK);
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, WF_F184, -101.3, -33.3, &b), WF_OK);
    ck_assert_double_eq_tol(a, b, 1e-12);
    /* Δλ wraps: 200 deg east is 160 deg west */
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, WF_F184, 200.0, 33.3, &a), WF_OK);
    ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&m, WF_F184, 160.0, 33.3, &b), WF_OK);
    ck_assert_double_eq_tol(a, b, 1e-9);
}
END_TEST

START_TEST(test_deep_field_vs_galsim)
{
    static wf_sky_model table, law;
    int have_table = load_table(&table);
    ck_assert_int_eq(wf_sky_builtin(&law), WF_OK);
    char *facts = load_facts();
    if (!facts) WF_SKIP("../shared/reference/galsim not found (set WFISIM_REFERENCE)");

    static const struct {
        const char *key;
        double mjd; /* 0 h UTC of the date; NAN: GalSim's "no date" (Sun at longitude 0) */
    } dates[] = {{"no_date(sun at vernal equinox)", NAN},
                 {"2027-01-01", 61406.0},
                 {"2027-04-01", 61496.0},
                 {"2027-07-01", 61587.0},
                 {"2027-10-01", 61679.0}};
    double worst_table = 0.0, worst_law = 0.0, worst_pix = 0.0;
    printf("  deep field RA 71 Dec -53: zodiacal e-/s/arcsec^2, wfisim vs GalSim getSkyLevel\n");
    printf("  date         filter  GalSim    table    diff%%    built-in  diff%%\n");
    for (size_t d = 0; d < sizeof dates / sizeof dates[0]; d++) {
        for (int i = 0; i < WF_NFILTER; i++) {
            wf_filter f = all_filters[i];
            const char *name = wf_filter_name(f);
            const char *kz[] = {"sky_level", dates[d].key, name, "zodi_e_per_arcsec2_per_s"};
            const char *kp[] = {"sky_level", dates[d].key, name,
                                "zodi_x1.1_stray+thermal_e_per_pix_300s"};
            double g = wf_test_json_number(facts, kz, 4), gpix = wf_test_json_number(facts, kp, 4);
            ck_assert_msg(isfinite(g) && isfinite(gpix), "facts.json lacks %s %s", dates[d].key,
                          name);
            double zt = NAN, zl, dlon, lat;
            if (isnan(dates[d].mjd)) {
                ck_assert_int_eq(wf_sky_ecliptic(71.0, -53.0, &dlon, &lat), WF_OK);
            } else {
                ck_assert_int_eq(wf_sky_sun_relative(71.0, -53.0, dates[d].mjd, &dlon, &lat,
                                                     NULL),
                                 WF_OK);
            }
            if (i == 0)
                printf("  %s: target at dlon %+.3f deg from the Sun, ecliptic lat %.3f deg\n",
                       dates[d].key, dlon, lat);
            ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&law, f, dlon, lat, &zl), WF_OK);
            double el = 100.0 * (zl / g - 1.0), et = NAN;
            if (have_table) {
                ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&table, f, dlon, lat, &zt), WF_OK);
                et = 100.0 * (zt / g - 1.0);
                worst_table = fmax(worst_table, fabs(et));
                ck_assert_msg(fabs(et) < 10.0, "%s %s: table %.3f vs GalSim %.3f (%+.2f%%)",
                              dates[d].key, name, zt, g, et);
                if (!isnan(dates[d].mjd)) {
                    /* the per-pixel composition GalSim's facts give for 300 s */
                    double r;
                    ck_assert_int_eq(wf_sky_rate(&table, f, 71.0, -53.0, dates[d].mjd,
                                                 PIXEL_AREA, 1, 1, &r),
                                     WF_OK);
                    double ep = 100.0 * (300.0 * r / gpix - 1.0);
                    worst_pix = fmax(worst_pix, fabs(ep));
                    ck_assert_msg(fabs(ep) < 10.0, "%s %s per pixel %+.2f%%", dates[d].key,
                                  name, ep);
                }
            }
            worst_law = fmax(worst_law, fabs(el));
            printf("  %-12.12s %s   %7.3f  %7.3f  %+6.2f    %7.3f  %+6.2f\n", dates[d].key, name,
                   g, zt, et, zl, el);
            /* the built-in law is coarse: 15% is its documented bar at the deep field */
            ck_assert_msg(fabs(el) < 15.0, "%s %s: built-in %.3f vs GalSim %.3f (%+.1f%%)",
                          dates[d].key, name, zl, g, el);
        }
    }
    printf("  worst |diff|: table %.2f%%, per pixel with stray+thermal %.2f%%, built-in %.1f%%\n",
           worst_table, worst_pix, worst_law);
    free(facts);
    if (!have_table) WF_SKIP("../shared/data (table model; built-in law was checked)");
}
END_TEST

/* The built-in law against every table node in Roman's field of regard (solar elongation
 * 54-126 deg) and farther out: the accuracy docs/SKY.md states. */
START_TEST(test_builtin_vs_table)
{
    static wf_sky_model table, law;
    if (!load_table(&table)) WF_SKIP("../shared/data not found (set WFISIM_DATA)");
    ck_assert_int_eq(wf_sky_builtin(&law), WF_OK);
    for (int i = 0; i < WF_NFILTER; i++) {
        wf_filter f = all_filters[i];
        double s2[2] = {0, 0}, worst[2] = {0, 0};
        int n[2] = {0, 0};
        for (int j = 0; j < WF_SKY_NLON; j++)
            for (int k = 0; k < WF_SKY_NLAT; k++) {
                double t = table.table[f][j][k];
                if (t < 0.0) continue;
                double lat = asin(k / 41.0) / DEG, dlon = 4.0 * j, z;
                double el = acos(cos(lat * DEG) * cos(dlon * DEG)) / DEG;
                int band = el >= 54.0 && el <= 126.0 ? 0 : el >= 30.0 ? 1 : -1;
                if (band < 0) continue;
                ck_assert_int_eq(wf_sky_zodiacal_ecliptic(&law, f, dlon, lat, &z), WF_OK);
                double e = z / t - 1.0;
                s2[band] += e * e;
                n[band]++;
                worst[band] = fmax(worst[band], fabs(e));
            }
        double rms0 = sqrt(s2[0] / n[0]), rms1 = sqrt(s2[1] / n[1]);
        printf("  %s built-in / table - 1: elongation 54-126: rms %.1f%% worst %.1f%% (%d "
               "nodes); 30-54 and 126-180: rms %.1f%% worst %.1f%% (%d nodes)\n",
               wf_filter_name(f), 100 * rms0, 100 * worst[0], n[0], 100 * rms1, 100 * worst[1],
               n[1]);
        ck_assert_msg(rms0 < 0.10 && worst[0] < 0.35, "%s: rms %.3f worst %.3f",
                      wf_filter_name(f), rms0, worst[0]);
    }
}
END_TEST

/* ------------------------------------------------------------------ bad files */

static const char *fake_sky_dir(const char *text)
{
    static char dir[4096];
    const char *tmp = wf_test_tmpdir();
    ck_assert_ptr_nonnull(tmp);
    snprintf(dir, sizeof dir, "%s", tmp);
    char path[4200];
    snprintf(path, sizeof path, "%s/roman", dir);
    ck_assert_int_eq(mkdir(path, 0755), 0);
    snprintf(path, sizeof path, "%s/roman/roman_sky_backgrounds.txt", dir);
    FILE *fp = fopen(path, "w");
    ck_assert_ptr_nonnull(fp);
    fputs(text, fp);
    fclose(fp);
    return dir;
}

static void expect_sky_error(const char *text, const char *want1, const char *want2)
{
    static wf_sky_model m;
    wf_status st = wf_sky_load(fake_sky_dir(text), &m);
    const char *msg = wf_error_message();
    ck_assert_msg(st == WF_ERR_INPUT, "expected an input error, got %d (%s)", st, msg);
    ck_assert_msg(strstr(msg, "roman_sky_backgrounds.txt") != NULL, "no file name: %s", msg);
    ck_assert_msg(strstr(msg, want1) != NULL, "'%s' not in: %s", want1, msg);
    if (want2) ck_assert_msg(strstr(msg, want2) != NULL, "'%s' not in: %s", want2, msg);
}

START_TEST(test_bad_files)
{
    const char *hdr = "# Latitude Longitude R062 Z087 Y106 J129 H158 F184 W146 K213\n";
    char text[8192];
    snprintf(text, sizeof text, "%s0 0 1 2 3 4 5 6 7 8\n1.3976 0 1 2 3 4 5 6 7 8\n", hdr);
    expect_sky_error(text, "1932", "grid rows");
    snprintf(text, sizeof text, "%s0 0 1 2 3 4 5 6 7 8\n5 0 1 2 3 4 5 6 7 8\n", hdr);
    expect_sky_error(text, ":3:", "latitude 5");
    snprintf(text, sizeof text, "%s0 0 1 2 3 4 5 x 7 8\n", hdr);
    expect_sky_error(text, ":2:", "'x'");
    snprintf(text, sizeof text, "%s0 0 1 2 3\n", hdr);
    expect_sky_error(text, ":2:", "fields");
    expect_sky_error("# Latitude Longitude R062 Z087\n0 0 1 2\n", "no column for filter Y106",
                     NULL);
    expect_sky_error("0 0 1 2\n", ":1:", "header");
    expect_sky_error("", "empty", NULL);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("sky");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, test_sun_equinoxes_solstices);
    tcase_add_test(tc, test_ecliptic_rotation);
    tcase_add_test(tc, test_ecliptic_deep_field);
    tcase_add_test(tc, test_zodiacal_least_over_a_year);
    tcase_add_test(tc, test_bad_inputs);
    tcase_add_test(tc, test_builtin_rate_composition);
    tcase_add_test(tc, test_sun_exclusion_builtin);
    tcase_add_test(tc, test_sun_exclusion_table);
    tcase_add_test(tc, test_table_grid);
    tcase_add_test(tc, test_deep_field_vs_galsim);
    tcase_add_test(tc, test_builtin_vs_table);
    tcase_add_test(tc, test_bad_files);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
