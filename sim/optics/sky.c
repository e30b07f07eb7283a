/* Sky background: see sim/optics/sky.h and docs/SKY.md. */
#include "sim/optics/sky.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#define SKY_FILE "roman/roman_sky_backgrounds.txt"
#define LINE_MAX_CHARS 4096
#define MAX_COLUMNS 64
#define DEG (M_PI / 180.0)

/* SPEC §2 (GalSim thermal_backgrounds), e-/pixel/s, in wf_filter order. */
static const double thermal_e_per_pix[WF_NFILTER] = {0.0, 0.0, 0.0, 0.0, 0.04, 0.17, 4.52, 0.98};

/* Built-in law, anchored at the deep field as SPEC §2 gives it: |β| = 73.55° (RA 71°,
 * Dec -53°), 90° from the Sun. Y, J, H, F184 are SPEC's values; R062, Z087, W146, K213 are
 * the Y106 value times the band-to-Y106 ratios of GalSim's table far from the Sun; the
 * ratios move by at most 3.5% over the whole grid because the zodiacal spectrum barely
 * changes shape. */
static const double builtin_ref[WF_NFILTER] = {29.9, 27.3, 29.7, 30.2, 29.6, 16.9, 10.1, 89.1};
#define BUILTIN_REF_LAT_DEG 73.55
#define BUILTIN_REF_DLON_DEG 90.0

/* ln Z = c0 + c1 u² + c2 u⁴ + c3 u² ln sin ε + c4 ln sin ε + c5 u² cos Δλ + c6 u² cos² Δλ,
 * u = cos β, cos ε = cos β cos Δλ. Least-squares fit (ours) of ln(table) over the 1 701
 * table nodes with elongation >= 40° (Y106 column; the other bands differ only by the
 * constant ratios above). The u² terms vanish at the ecliptic pole, where Δλ has no
 * meaning; the ln sin ε terms carry the brightening toward the Sun; the u² cos Δλ terms let
 * the latitude profile differ between the sunward and anti-sunward hemispheres and give
 * the gegenschein rise near Δλ = 180°.
 * c0 cancels in the normalisation to the anchor point. */
static const double law_c[7] = {3.43387, -0.477391, 1.49409, 1.03937, -1.04764, 0.909673, 0.678466};

static int filter_ok(wf_filter f) { return (int)f >= 0 && f < WF_NFILTER; }

static double wrap180(double deg)
{
    double x = fmod(deg, 360.0);
    if (x > 180.0) x -= 360.0;
    else if (x <= -180.0) x += 360.0;
    return x;
}

static double wrap360(double deg)
{
    double x = fmod(deg, 360.0);
    if (x < 0.0) x += 360.0;
    return x >= 360.0 ? 0.0 : x; /* -1e-17 + 360 rounds to 360 */
}

wf_status wf_sky_ecliptic(double ra_deg, double dec_deg, double *lon_deg, double *lat_deg)
{
    if (!isfinite(ra_deg) || !(dec_deg >= -90.0 && dec_deg <= 90.0))
        return wf_error(WF_ERR_RANGE, "sky: position RA %g Dec %g is not on the sky", ra_deg,
                        dec_deg);
    double ra = ra_deg * DEG, dec = dec_deg * DEG, eps = WF_SKY_OBLIQUITY_J2000_DEG * DEG;
    double x = cos(dec) * cos(ra), y = cos(dec) * sin(ra), z = sin(dec);
    /* rotation about the equinox direction (x) by the obliquity */
    double ye = cos(eps) * y + sin(eps) * z;
    double ze = -sin(eps) * y + cos(eps) * z;
    if (lon_deg) *lon_deg = wrap360(atan2(ye, x) / DEG);
    if (lat_deg) *lat_deg = asin(fmax(-1.0, fmin(1.0, ze))) / DEG;
    return WF_OK;
}

wf_status wf_sky_sun_longitude(double mjd, double *lon_of_date_deg, double *lon_j2000_deg)
{
    if (!(mjd >= 15020.0 && mjd <= 88069.0))
        return wf_error(WF_ERR_RANGE,
                        "sky: MJD %.10g is outside 1900-2100 (15020-88069); a Julian date is "
                        "MJD + 2400000.5",
                        mjd);
    /* Astronomical Almanac low-precision solar coordinates: mean longitude L and mean
     * anomaly g, days n from J2000.0 (JD 2451545.0 = MJD 51544.5), equation of centre to
     * second order in the eccentricity. */
    double n = mjd - 51544.5;
    double L = 280.460 + 0.9856474 * n;
    double g = (357.528 + 0.9856003 * n) * DEG;
    double lam = L + 1.915 * sin(g) + 0.020 * sin(2.0 * g);
    if (lon_of_date_deg) *lon_of_date_deg = wrap360(lam);
    /* The equinox of date runs ahead of J2000's by the general precession in longitude,
     * 5028.796"/century (IAU 2006): 0.37° by 2027, which is what separates the two frames. */
    double t = n / 36525.0;
    if (lon_j2000_deg) *lon_j2000_deg = wrap360(lam - 5028.796 / 3600.0 * t);
    return WF_OK;
}

static double elongation_deg(double dlon_deg, double lat_deg)
{
    double c = cos(lat_deg * DEG) * cos(dlon_deg * DEG);
    return acos(fmax(-1.0, fmin(1.0, c))) / DEG;
}

wf_status wf_sky_sun_relative(double ra_deg, double dec_deg, double mjd, double *dlon_deg,
                              double *lat_deg, double *elong_deg)
{
    double lon, lat, sun;
    wf_status st = wf_sky_ecliptic(ra_deg, dec_deg, &lon, &lat);
    if (st != WF_OK) return st;
    if ((st = wf_sky_sun_longitude(mjd, NULL, &sun)) != WF_OK) return st;
    double d = wrap180(lon - sun);
    if (dlon_deg) *dlon_deg = d;
    if (lat_deg) *lat_deg = lat;
    if (elong_deg) *elong_deg = elongation_deg(d, lat);
    return WF_OK;
}

/* ------------------------------------------------------------------ built-in law */

static double law_log(double dlon_deg, double lat_deg)
{
    double u = cos(lat_deg * DEG), u2 = u * u;
    double cl = cos(dlon_deg * DEG);
    double ls = log(sin(elongation_deg(dlon_deg, lat_deg) * DEG));
    return law_c[1] * u2 + law_c[2] * u2 * u2 + law_c[3] * u2 * ls + law_c[4] * ls +
           law_c[5] * u2 * cl + law_c[6] * u2 * cl * cl;
}

static wf_status builtin_zodi(wf_filter f, double dlon_deg, double lat_deg, double *out)
{
    double el = elongation_deg(dlon_deg, lat_deg);
    if (el < WF_SKY_MIN_ELONGATION_DEG)
        return wf_error(WF_ERR_RANGE,
                        "sky: %.2f deg from the Sun (ecliptic dlon %.2f, lat %.2f): too close "
                        "to the Sun to observe (built-in zodiacal model needs >= %.1f deg)",
                        el, dlon_deg, lat_deg, WF_SKY_MIN_ELONGATION_DEG);
    double ref = law_log(BUILTIN_REF_DLON_DEG, BUILTIN_REF_LAT_DEG);
    *out = builtin_ref[f] * exp(law_log(dlon_deg, lat_deg) - ref);
    return WF_OK;
}

wf_status wf_sky_builtin(wf_sky_model *out)
{
    out->from_table = 0;
    snprintf(out->source, sizeof out->source,
             "built-in analytic law (SPEC §2 deep-field values; coarse)");
    /* the table is unused; zero it so that a copied model holds no stale numbers */
    memset(out->table, 0, sizeof out->table);
    return WF_OK;
}

/* ------------------------------------------------------------------ table */


static wf_status read_table(FILE *fp, const char *path, wf_sky_model *out)
{
    char line[LINE_MAX_CHARS];
    int lineno = 0, ncol = 0;
    int col[WF_NFILTER];
    for (int i = 0; i < WF_NFILTER; i++) col[i] = -1;

    /* Header: "# Latitude Longitude R062 Z087 ..." names the band columns. */
    while (fgets(line, sizeof line, fp)) {
        lineno++;
        char *p = line;
        while (isspace((unsigned char)*p)) p++;
        if (*p == '\0') continue;
        if (*p != '#')
            return wf_error(WF_ERR_INPUT,
                            "%s:%d: expected a header '# Latitude Longitude <bands...>'", path,
                            lineno);
        p++;
        char *save = NULL;
        int i = 0;
        for (char *tok = strtok_r(p, " \t\r\n,", &save); tok;
             tok = strtok_r(NULL, " \t\r\n,", &save), i++) {
            if ((i == 0 && strcasecmp(tok, "Latitude")) ||
                (i == 1 && strcasecmp(tok, "Longitude")))
                return wf_error(WF_ERR_INPUT,
                                "%s:%d: header column %d is '%s', expected %s", path, lineno,
                                i + 1, tok, i == 0 ? "Latitude" : "Longitude");
            wf_filter f;
            if (i >= 2 && wf_filter_lookup(tok, &f) && col[f] < 0) col[f] = i;
        }
        ncol = i;
        break;
    }
    if (ncol == 0) return wf_error(WF_ERR_INPUT, "%s: empty file (no header line)", path);
    if (ncol > MAX_COLUMNS)
        return wf_error(WF_ERR_INPUT, "%s:%d: %d columns, at most %d supported", path, lineno,
                        ncol, MAX_COLUMNS);
    for (int f = 0; f < WF_NFILTER; f++)
        if (col[f] < 0)
            return wf_error(WF_ERR_INPUT, "%s:%d: no column for filter %s", path, lineno,
                            wf_filter_name((wf_filter)f));

    int k = 0;
    while (fgets(line, sizeof line, fp)) {
        lineno++;
        if (!strchr(line, '\n') && !feof(fp))
            return wf_error(WF_ERR_INPUT, "%s:%d: line longer than %d characters", path,
                            lineno, LINE_MAX_CHARS - 1);
        char *p = line;
        while (isspace((unsigned char)*p)) p++;
        if (*p == '\0' || *p == '#') continue;
        double v[MAX_COLUMNS];
        int n = 0;
        char *save = NULL;
        for (char *tok = strtok_r(p, " \t\r\n,", &save); tok;
             tok = strtok_r(NULL, " \t\r\n,", &save), n++) {
            char *end;
            errno = 0;
            double x = strtod(tok, &end);
            if (end == tok || *end || errno == ERANGE || !isfinite(x))
                return wf_error(WF_ERR_INPUT, "%s:%d: field %d '%s' is not a number", path,
                                lineno, n + 1, tok);
            if (n < MAX_COLUMNS) v[n] = x;
        }
        if (n != ncol)
            return wf_error(WF_ERR_INPUT, "%s:%d: %d fields, the header names %d", path,
                            lineno, n, ncol);
        if (k == WF_SKY_NLAT * WF_SKY_NLON)
            return wf_error(WF_ERR_INPUT, "%s:%d: more than %d grid rows", path, lineno,
                            WF_SKY_NLAT * WF_SKY_NLON);
        /* The grid is implied by the row order (latitude fastest), as GalSim reads it;
         * checking each row's coordinates stops a reordered file from loading silently. */
        int ilat = k % WF_SKY_NLAT, ilon = k / WF_SKY_NLAT;
        double want_lat = asin((double)ilat / (WF_SKY_NLAT - 1)) / DEG;
        double want_lon = 4.0 * ilon;
        if (fabs(v[0] - want_lat) > 0.01 || fabs(v[1] - want_lon) > 0.01)
            return wf_error(WF_ERR_INPUT,
                            "%s:%d: grid row %d is at latitude %g, longitude %g; expected "
                            "%.4f, %g (sin(lat) = %d/41 fastest, longitude 0..180 by 4)",
                            path, lineno, k, v[0], v[1], want_lat, want_lon, ilat);
        for (int f = 0; f < WF_NFILTER; f++) out->table[f][ilon][ilat] = v[col[f]];
        k++;
    }
    if (ferror(fp)) return wf_error(WF_ERR_IO, "%s: read error", path);
    if (k != WF_SKY_NLAT * WF_SKY_NLON)
        return wf_error(WF_ERR_INPUT, "%s: %d grid rows, expected %d (42 x 46)", path, k,
                        WF_SKY_NLAT * WF_SKY_NLON);
    return WF_OK;
}

wf_status wf_sky_load(const char *data_dir, wf_sky_model *out)
{
    if (!data_dir || !*data_dir) {
        wf_sky_builtin(out);
        snprintf(out->source, sizeof out->source,
                 "built-in analytic law (SPEC §2 deep-field values; coarse): no data "
                 "directory given");
        return WF_OK;
    }
    char path[WF_SKY_SOURCE_MAX - 100];
    int len = snprintf(path, sizeof path, "%s/%s", data_dir, SKY_FILE);
    if (len < 0 || (size_t)len >= sizeof path)
        return wf_error(WF_ERR_INPUT, "sky: data directory path too long: %s", data_dir);
    FILE *fp = fopen(path, "r");
    if (!fp) {
        if (errno != ENOENT)
            return wf_error(WF_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
        wf_sky_builtin(out);
        snprintf(out->source, sizeof out->source,
                 "built-in analytic law (SPEC §2 deep-field values; coarse): %s not found",
                 path);
        return WF_OK;
    }
    wf_status st = read_table(fp, path, out);
    fclose(fp);
    if (st != WF_OK) return st;
    out->from_table = 1;
    snprintf(out->source, sizeof out->source, "%s", path);
    return WF_OK;
}

/* Bilinear in (sin|β|, |Δλ|) as GalSim does. A node flagged negative with a non-zero weight
 * is an error. GalSim instead gives flagged nodes the value 1e6 and errors only when the
 * result exceeds the table's maximum, so a flagged node with a weight below max/1e6 (~1e-3)
 * still passes and adds up to that maximum (thousands of e-/s/arcsec²) at the edge of the
 * excluded zone. */
static wf_status table_zodi(const wf_sky_model *m, wf_filter f, double dlon_deg, double lat_deg,
                            double *out)
{
    double x = sin(fabs(lat_deg) * DEG) * (WF_SKY_NLAT - 1);
    double y = fabs(wrap180(dlon_deg)) / 4.0;
    int i = (int)x, j = (int)y;
    if (i > WF_SKY_NLAT - 2) i = WF_SKY_NLAT - 2; /* the pole and Δλ = 180° are grid edges */
    if (j > WF_SKY_NLON - 2) j = WF_SKY_NLON - 2;
    double fx = x - i, fy = y - j;
    const double w[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
    const double v[4] = {m->table[f][j][i], m->table[f][j][i + 1], m->table[f][j + 1][i],
                         m->table[f][j + 1][i + 1]};
    double s = 0.0;
    for (int q = 0; q < 4; q++) {
        if (w[q] == 0.0) continue;
        if (v[q] < 0.0)
            return wf_error(WF_ERR_RANGE,
                            "sky: %.2f deg from the Sun (ecliptic dlon %.2f, lat %.2f): too "
                            "close to the Sun to observe (the zodiacal table has no value "
                            "there)",
                            elongation_deg(dlon_deg, lat_deg), dlon_deg, lat_deg);
        s += w[q] * v[q];
    }
    *out = s;
    return WF_OK;
}

wf_status wf_sky_zodiacal_ecliptic(const wf_sky_model *m, wf_filter f, double dlon_deg,
                                   double lat_deg, double *e_per_s_per_arcsec2)
{
    if (!filter_ok(f)) return wf_error(WF_ERR_RANGE, "sky: %d is not a filter", (int)f);
    if (!isfinite(dlon_deg) || !(lat_deg >= -90.0 && lat_deg <= 90.0))
        return wf_error(WF_ERR_RANGE, "sky: ecliptic dlon %g, lat %g is not on the sky",
                        dlon_deg, lat_deg);
    return m->from_table ? table_zodi(m, f, dlon_deg, lat_deg, e_per_s_per_arcsec2)
                         : builtin_zodi(f, wrap180(dlon_deg), lat_deg, e_per_s_per_arcsec2);
}

wf_status wf_sky_zodiacal(const wf_sky_model *m, wf_filter f, double ra_deg, double dec_deg,
                          double mjd, double *e_per_s_per_arcsec2)
{
    double dlon, lat;
    wf_status st = wf_sky_sun_relative(ra_deg, dec_deg, mjd, &dlon, &lat, NULL);
    if (st != WF_OK) return st;
    st = wf_sky_zodiacal_ecliptic(m, f, dlon, lat, e_per_s_per_arcsec2);
    if (st == WF_ERR_RANGE) {
        /* add what the caller asked for to the geometric message */
        char msg[768];
        snprintf(msg, sizeof msg, "%s", wf_error_message());
        return wf_error(st, "%s %s at RA %.4f Dec %.4f, MJD %.3f: %s", wf_filter_name(f),
                        m->from_table ? "zodiacal table" : "zodiacal law", ra_deg, dec_deg,
                        mjd, msg);
    }
    return st;
}

wf_status wf_sky_zodiacal_least(const wf_sky_model *m, wf_filter f, double ra_deg, double dec_deg,
                                double *e_per_s_per_arcsec2)
{
    double lon, lat;
    wf_status st = wf_sky_ecliptic(ra_deg, dec_deg, &lon, &lat);
    if (st) return st;
    /* the allowed |dlon| form one interval [a, b]: cos(elongation) = cos(lat) cos(dlon) */
    const double cb = cos(lat * DEG);
    const double ca = fmin(1.0, cos(WF_SKY_REGARD_MIN_DEG * DEG) / cb), cz = fmax(-1.0, cos(WF_SKY_REGARD_MAX_DEG * DEG) / cb);
    const double a = acos(ca) / DEG, b = acos(cz) / DEG;
    double best = INFINITY;
    /* its ends, and the steps between (every table node among them: the table is linear in
     * dlon between nodes, so its least is exact) */
    for (int k = -1; k <= 180 * 8 + 1; k++) {
        double dl = k < 0 ? a : k > 180 * 8 ? b : k / 8.0, z;
        if (dl < a || dl > b) continue;
        if ((st = wf_sky_zodiacal_ecliptic(m, f, dl, lat, &z))) return st;
        if (z < best) best = z;
    }
    if (!(best < INFINITY)) /* cannot happen: quadrature, k = 720, is always in */
        return wf_error(WF_ERR_INTERNAL, "sky: no elongation within the field of regard toward RA %.4f Dec %.4f",
                        ra_deg, dec_deg);
    *e_per_s_per_arcsec2 = best;
    return WF_OK;
}

wf_status wf_sky_thermal(wf_filter f, double *e_per_pix_per_s)
{
    if (!filter_ok(f)) return wf_error(WF_ERR_RANGE, "sky: %d is not a filter", (int)f);
    *e_per_pix_per_s = thermal_e_per_pix[f];
    return WF_OK;
}

wf_status wf_sky_rate(const wf_sky_model *m, wf_filter f, double ra_deg, double dec_deg,
                      double mjd, double pixel_area_arcsec2, int include_stray,
                      int include_thermal, double *e_per_pix_per_s)
{
    if (!(pixel_area_arcsec2 > 0.0) || !isfinite(pixel_area_arcsec2))
        return wf_error(WF_ERR_RANGE, "sky: pixel area %g arcsec² must be > 0",
                        pixel_area_arcsec2);
    double z, th = 0.0;
    wf_status st = wf_sky_zodiacal(m, f, ra_deg, dec_deg, mjd, &z);
    if (st != WF_OK) return st;
    if (include_thermal && (st = wf_sky_thermal(f, &th)) != WF_OK) return st;
    double stray = include_stray ? WF_SKY_STRAY_FRACTION : 0.0;
    *e_per_pix_per_s = z * pixel_area_arcsec2 * (1.0 + stray) + th;
    return WF_OK;
}
