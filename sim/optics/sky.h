/* Sky background: zodiacal light as a function of sky position and date, stray light and
 * the telescope's thermal emission (SPEC §2, §3.1 step 1; docs/SKY.md).
 *
 * Zodiacal light is a function of where the target lies relative to the Sun in ecliptic
 * coordinates: its ecliptic latitude β and its ecliptic longitude minus the Sun's, Δλ. Both
 * are symmetric (|β|, |Δλ| ≤ 180°). Two models:
 *  - table (as GalSim's getSkyLevel): <data_dir>/roman/roman_sky_backgrounds.txt, e-/s/arcsec²
 *    per filter on a grid of 42 values of sin|β| (0, 1/41, ... 1) by 46 values of |Δλ|
 *    (0, 4, ... 180°), from C. Hirata's Roman exposure-time calculator; bilinear in
 *    (sin|β|, |Δλ|). Nodes marked negative are too close to the Sun to observe: a position
 *    whose interpolation touches one is an error.
 *  - built-in (no table): the deep-field values of SPEC §2 scaled by an analytic law in β and
 *    solar elongation. Coarse: 8% rms, 26% worst, against the table over Roman's field of
 *    regard (elongation 54°–126°), worse nearer the Sun; positions within 15.2° of the Sun
 *    are an error.
 *
 * Positions are ICRS/J2000 RA, Dec; the ecliptic is the J2000 mean ecliptic (IAU 2006
 * obliquity 84381.406"); the Sun comes from the Astronomical Almanac's low-precision
 * formula (~0.01° for 1950–2050), referred to the J2000 equinox so that target and Sun share
 * one frame. Dates are MJD (UTC; the 69 s TT-UTC difference moves the Sun by 0.0008°).
 *
 * Per pixel: zodiacal × pixel area × (1 + stray fraction 0.1) + thermal. Thermal emission
 * reaches the detector per physical pixel (10 µm), so it does not scale with the pixel's
 * solid angle. */
#ifndef WF_SKY_H
#define WF_SKY_H

#include "hal/status.h"
#include "sim/optics/bandpass.h"

#define WF_SKY_NLAT 42 /* sin|β| = i / 41 */
#define WF_SKY_NLON 46 /* |Δλ| = 4 j degrees */
#define WF_SKY_SOURCE_MAX 1200
#define WF_SKY_STRAY_FRACTION 0.1                  /* GalSim stray_light_fraction */
#define WF_SKY_OBLIQUITY_J2000_DEG (84381.406 / 3600.0) /* IAU 2006, J2000 */
#define WF_SKY_MIN_ELONGATION_DEG 15.2 /* built-in model: the table's Sun exclusion */

typedef struct wf_sky_model {
    int from_table;                    /* 1: GalSim table; 0: built-in analytic law */
    char source[WF_SKY_SOURCE_MAX];    /* the file read, or why the built-in law is used */
    /* e-/s/arcsec² at [filter][|Δλ| index][sin|β| index]; negative: too close to the Sun */
    double table[WF_NFILTER][WF_SKY_NLON][WF_SKY_NLAT];
} wf_sky_model;

/* Loads the zodiacal table from <data_dir>/roman/roman_sky_backgrounds.txt. With data_dir
 * NULL or "" or the file absent, the built-in law is used and out->source says which; a
 * file that exists but does not parse, or whose grid is not the one above, is an error naming
 * file and line. */
wf_status wf_sky_load(const char *data_dir, wf_sky_model *out);

/* The built-in analytic law alone. */
wf_status wf_sky_builtin(wf_sky_model *out);

/* J2000 RA, Dec (degrees) to J2000 ecliptic longitude in [0, 360) and latitude. */
wf_status wf_sky_ecliptic(double ra_deg, double dec_deg, double *lon_deg, double *lat_deg);

/* Geocentric ecliptic longitude of the Sun at mjd, in [0, 360): referred to the mean
 * equinox of date (0° at the March equinox of that year) and to the J2000 equinox (what the
 * sky model uses). Either pointer may be NULL. MJD must be within 1900–2100 (15020–88069),
 * which also catches a Julian date passed by mistake. */
wf_status wf_sky_sun_longitude(double mjd, double *lon_of_date_deg, double *lon_j2000_deg);

/* The target relative to the Sun: Δλ in (-180, 180], β, and the solar elongation (angle
 * between target and Sun). Any pointer may be NULL. */
wf_status wf_sky_sun_relative(double ra_deg, double dec_deg, double mjd, double *dlon_deg,
                              double *lat_deg, double *elongation_deg);

/* Zodiacal light, e-/s/arcsec², at ecliptic longitude dlon_deg from the Sun and ecliptic
 * latitude lat_deg. (GalSim's getSkyLevel without a date is this with dlon = the target's
 * ecliptic longitude, i.e. the Sun at the March equinox point.) */
wf_status wf_sky_zodiacal_ecliptic(const wf_sky_model *m, wf_filter f, double dlon_deg,
                                   double lat_deg, double *e_per_s_per_arcsec2);

/* Zodiacal light, e-/s/arcsec², toward (ra, dec) at mjd. Too close to the Sun: WF_ERR_RANGE
 * with a message naming the position, date and elongation. */
wf_status wf_sky_zodiacal(const wf_sky_model *m, wf_filter f, double ra_deg, double dec_deg,
                          double mjd, double *e_per_s_per_arcsec2);

/* Roman's field of regard in solar elongation (the angle between target and Sun). */
#define WF_SKY_REGARD_MIN_DEG 54.0
#define WF_SKY_REGARD_MAX_DEG 126.0

/* The least zodiacal light toward (ra, dec), e-/s/arcsec², over the year's positions of the
 * Sun that leave the target within the field of regard: a level that depends on no date
 * (what scales the per-object accuracy knobs of scene.noise_tolerance, so that every
 * exposure of a pointing draws its static objects alike). Quadrature (elongation 90°) is
 * always among them. The minimum over the interval of allowed |Δλ|: its ends and steps of
 * 1/8° (exact for the table, linear in Δλ between its 4° nodes). An exposure at a date that
 * puts the target outside the field of regard (`wfisim expose` allows any date; a plan never
 * does) can have less zodiacal light than this near the ecliptic: its faint objects are then
 * drawn to a tolerance above noise_tolerance x its own sky noise. */
wf_status wf_sky_zodiacal_least(const wf_sky_model *m, wf_filter f, double ra_deg, double dec_deg,
                                double *e_per_s_per_arcsec2);

/* Thermal background of the filter, e-/pixel/s (SPEC §2, GalSim thermal_backgrounds). */
wf_status wf_sky_thermal(wf_filter f, double *e_per_pix_per_s);

/* The sky rate of one pixel, e-/pixel/s: zodiacal × pixel_area_arcsec2 × (1 + 0.1 if
 * include_stray) + thermal if include_thermal. pixel_area_arcsec2 is the pixel's solid
 * angle (0.0121 nominal; the distortion model's local value to follow the WCS). */
wf_status wf_sky_rate(const wf_sky_model *m, wf_filter f, double ra_deg, double dec_deg,
                      double mjd, double pixel_area_arcsec2, int include_stray,
                      int include_thermal, double *e_per_pix_per_s);

#endif
