#include "sim/survey/wcs.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/fits/fitsout.h"

#define DEG (M_PI / 180.0)
#define NEWTON_TOL 1e-9     /* pixels */
#define NEWTON_MAX_ITER 50

/* ---- built-in focal plane ------------------------------------------------------------- */

/* GalSim share/roman (GalSim-developers/GalSim, BSD-3; numbers from J. Kruk, NASA/GSFC, design
 * 20210204): SCA centres (u0, v0) in degrees are columns 6-7 of sca_positions_20210204.txt
 * (also sca_layout.csv in ../shared/reference/galsim rotated to PA 0); the pixel matrix in
 * arcsec/pixel is the linear part of each SCA's polynomial in sip_20210204.txt (a_1_0, a_0_1,
 * b_1_0, b_0_1) to 7 significant digits. SCAs 3, 6, 9, 12, 15, 18 are read out rotated by 180
 * degrees, which is why their diagonal is negative. */
static const struct {
    double u0, v0, a10, a01, b10, b01;
} builtin_sca[WF_WCS_NSCA] = {
    {-0.0680, -0.0356, 0.1099245, -0.0003535556, -0.0002934149, 0.1078535},
    {-0.0679, 0.1108, 0.1091514, -0.0002397514, -0.0006254469, 0.1055585},
    {-0.0678, 0.2417, -0.1082713, 0.0007932553, 0.0002292139, -0.1029891},
    {-0.2037, -0.0627, 0.1094872, -0.001060737, -0.0007277882, 0.1080489},
    {-0.2037, 0.0840, 0.1086895, -0.001252838, -0.001133554, 0.1058071},
    {-0.2036, 0.2146, -0.1078414, 0.001320331, 0.001557356, -0.1033314},
    {-0.3390, -0.1283, 0.1085688, -0.001271842, -0.001252184, 0.1084507},
    {-0.3393, 0.0191, 0.1079442, -0.001921727, -0.001575402, 0.1065221},
    {-0.3403, 0.1486, -0.107156, 0.002071569, 0.002293838, -0.1042894},
    {0.0678, -0.0356, 0.1099514, 0.0004466477, 0.0001422721, 0.1078856},
    {0.0678, 0.1108, 0.109119, 0.0003049177, 0.0005013906, 0.1055343},
    {0.0677, 0.2417, -0.1082047, -0.0004298909, -0.0005174521, -0.1029295},
    {0.2034, -0.0627, 0.1094968, 0.0008540596, 0.0009048671, 0.1080445},
    {0.2036, 0.0840, 0.1087283, 0.001204447, 0.001129278, 0.1058106},
    {0.2035, 0.2146, -0.1078499, -0.001361953, -0.001441547, -0.1033343},
    {0.3388, -0.1284, 0.1086705, 0.001402799, 0.001079761, 0.1085025},
    {0.3392, 0.0191, 0.1079819, 0.001633703, 0.001819845, 0.1065216},
    {0.3403, 0.1486, -0.1072484, -0.001938082, -0.002368409, -0.1043486},
};

/* GalSim's rotation of the WFI local axes from observatory +Y (roman_wcs.py, 20210204). */
#define THETA_FPA_DEG 120.0

void wf_wcs_focal_plane_builtin(wf_focal_plane *fp)
{
    memset(fp, 0, sizeof *fp);
    snprintf(fp->source, sizeof fp->source, "built-in");
    fp->theta_fpa_deg = THETA_FPA_DEG;
    fp->sip_order = 0;
    for (int s = 0; s < WF_WCS_NSCA; s++) {
        fp->u0[s] = builtin_sca[s].u0;
        fp->v0[s] = builtin_sca[s].v0;
        fp->a[s][1][0] = builtin_sca[s].a10 / 3600.0;
        fp->a[s][0][1] = builtin_sca[s].a01 / 3600.0;
        fp->b[s][1][0] = builtin_sca[s].b10 / 3600.0;
        fp->b[s][0][1] = builtin_sca[s].b01 / 3600.0;
    }
}

/* ---- data files ------------------------------------------------------------------------- */

/* Splits a line into at most max whitespace-separated tokens; returns the count. */
static int split(char *line, char **tok, int max)
{
    int n = 0;
    char *save = NULL;
    for (char *p = strtok_r(line, " \t\r\n", &save); p; p = strtok_r(NULL, " \t\r\n", &save)) {
        if (n == max) return max + 1;
        tok[n++] = p;
    }
    return n;
}

static int parse_double(const char *s, double *v)
{
    char *end;
    errno = 0;
    *v = strtod(s, &end);
    return *end == '\0' && end != s && errno == 0 && isfinite(*v);
}

static int parse_int(const char *s, long *v)
{
    char *end;
    errno = 0;
    *v = strtol(s, &end, 10);
    return *end == '\0' && end != s && errno == 0;
}

/* The next line of a whitespace table that holds fields, split into at most maxtok + 1
 * tokens ('#' starts a comment); *n = 0 at the end of the file. */
static wf_status next_fields(FILE *f, const char *path, char *line, size_t cap, int *lineno,
                             char **tok, int maxtok, int *n)
{
    *n = 0;
    while (fgets(line, (int)cap, f)) {
        (*lineno)++;
        if (!strchr(line, '\n') && !feof(f))
            return wf_error(WF_ERR_INPUT, "%s:%d: line longer than %zu characters", path, *lineno,
                            cap - 2);
        char *hash = strchr(line, '#');
        if (hash) *hash = '\0';
        if ((*n = split(line, tok, maxtok)) > 0) return WF_OK;
    }
    return WF_OK;
}

static wf_status read_positions(const char *path, wf_focal_plane *fp)
{
    FILE *f = fopen(path, "r");
    if (!f) return wf_error(WF_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
    int seen[WF_WCS_NSCA] = {0};
    char line[1024];
    int lineno = 0;
    wf_status st = WF_OK;
    char *tok[8];
    int n;
    while (!(st = next_fields(f, path, line, sizeof line, &lineno, tok, 7, &n)) && n > 0) {
        if (n != 7) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: expected 7 columns (sca, field x, y, fpa x, y, u, v), "
                          "found %s", path, lineno, n > 7 ? "more" : "fewer");
            break;
        }
        long id;
        double v[6];
        if (!parse_int(tok[0], &id) || id < 1 || id > WF_WCS_NSCA) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: column 1 (sca): '%s' is not an SCA number 1..%d",
                          path, lineno, tok[0], WF_WCS_NSCA);
            break;
        }
        for (int c = 0; c < 6 && !st; c++)
            if (!parse_double(tok[c + 1], &v[c]))
                st = wf_error(WF_ERR_INPUT, "%s:%d: column %d: '%s' is not a finite number", path,
                              lineno, c + 2, tok[c + 1]);
        if (st) break;
        if (seen[id - 1]) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: SCA %ld given twice", path, lineno, id);
            break;
        }
        if (fabs(v[4]) > 5.0 || fabs(v[5]) > 5.0) {
            st = wf_error(WF_ERR_RANGE, "%s:%d: SCA %ld: centre (%g, %g) deg is not in the field",
                          path, lineno, id, v[4], v[5]);
            break;
        }
        seen[id - 1] = 1;
        fp->u0[id - 1] = v[4];
        fp->v0[id - 1] = v[5];
    }
    fclose(f);
    for (int s = 0; !st && s < WF_WCS_NSCA; s++)
        if (!seen[s]) st = wf_error(WF_ERR_INPUT, "%s: no row for SCA %d", path, s + 1);
    return st;
}

static wf_status read_sip(const char *path, wf_focal_plane *fp)
{
    FILE *f = fopen(path, "r");
    if (!f) return wf_error(WF_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
    unsigned char seen[WF_WCS_NSCA][2][WF_WCS_SIP_N] = {{{0}}};
    char line[1024];
    int lineno = 0;
    wf_status st = WF_OK;
    char *tok[9];
    int n;
    while (!(st = next_fields(f, path, line, sizeof line, &lineno, tok, 8, &n)) && n > 0) {
        if (n != 8) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: expected 8 columns (sca-1, a|b, row, 5 "
                          "coefficients), found %s", path, lineno, n > 8 ? "more" : "fewer");
            break;
        }
        long s, i;
        if (!parse_int(tok[0], &s) || s < 0 || s >= WF_WCS_NSCA) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: column 1 (sca-1): '%s' is not 0..%d", path, lineno,
                          tok[0], WF_WCS_NSCA - 1);
            break;
        }
        int ab = !strcmp(tok[1], "a") ? 0 : !strcmp(tok[1], "b") ? 1 : -1;
        if (ab < 0) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: column 2: '%s' is neither 'a' nor 'b'", path,
                          lineno, tok[1]);
            break;
        }
        if (!parse_int(tok[2], &i) || i < 0 || i >= WF_WCS_SIP_N) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: column 3 (power of x): '%s' is not 0..%d", path,
                          lineno, tok[2], WF_WCS_SIP_N - 1);
            break;
        }
        if (seen[s][ab][i]) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: SCA %ld %s row %ld given twice", path, lineno,
                          s + 1, tok[1], i);
            break;
        }
        seen[s][ab][i] = 1;
        for (int j = 0; j < WF_WCS_SIP_N && !st; j++) {
            double v;
            if (!parse_double(tok[3 + j], &v))
                st = wf_error(WF_ERR_INPUT, "%s:%d: column %d: '%s' is not a finite number", path,
                              lineno, 4 + j, tok[3 + j]);
            else if (ab == 0)
                fp->a[s][i][j] = v;
            else
                fp->b[s][i][j] = v;
        }
        if (st) break; /* the loop condition would overwrite it */
    }
    fclose(f);
    for (int s = 0; !st && s < WF_WCS_NSCA; s++)
        for (int ab = 0; !st && ab < 2; ab++)
            for (int i = 0; !st && i < WF_WCS_SIP_N; i++)
                if (!seen[s][ab][i])
                    st = wf_error(WF_ERR_INPUT, "%s: no '%c %d' row for SCA %d (file row %d)",
                                  path, ab ? 'b' : 'a', i, s + 1, s);
    for (int s = 0; !st && s < WF_WCS_NSCA; s++) {
        double det = fp->a[s][1][0] * fp->b[s][0][1] - fp->a[s][0][1] * fp->b[s][1][0];
        double scale = sqrt(fabs(det)) * 3600.0;
        if (!(scale > 0.01 && scale < 10.0))
            st = wf_error(WF_ERR_RANGE, "%s: SCA %d: linear terms give %g arcsec/pixel, not a "
                          "pixel scale", path, s + 1, scale);
    }
    return st;
}

wf_status wf_wcs_focal_plane_load(const char *data_dir, wf_focal_plane *fp)
{
    if (!data_dir || !*data_dir)
        return wf_error(WF_ERR_INPUT, "focal plane: no data directory given");
    wf_focal_plane *tmp = calloc(1, sizeof *tmp);
    if (!tmp) return wf_error(WF_ERR_NOMEM, "focal plane: out of memory");
    char path[WF_WCS_SOURCE_MAX + 64];
    wf_status st = WF_OK;
    if (strlen(data_dir) >= WF_WCS_SOURCE_MAX)
        st = wf_error(WF_ERR_INPUT, "focal plane: data directory name longer than %d characters",
                      WF_WCS_SOURCE_MAX - 1);
    if (!st) {
        snprintf(tmp->source, sizeof tmp->source, "%s", data_dir);
        tmp->theta_fpa_deg = THETA_FPA_DEG;
        tmp->sip_order = WF_WCS_SIP_N - 1; /* GalSim writes A_ORDER 4 whatever the values */
        snprintf(path, sizeof path, "%s/roman/sca_positions_20210204.txt", data_dir);
        st = read_positions(path, tmp);
    }
    if (!st) {
        snprintf(path, sizeof path, "%s/roman/sip_20210204.txt", data_dir);
        st = read_sip(path, tmp);
    }
    if (!st) memcpy(fp, tmp, sizeof *fp);
    free(tmp);
    return st;
}

wf_status wf_wcs_focal_plane(const char *data_dir, wf_focal_plane *fp)
{
    if (!data_dir || !*data_dir) {
        wf_wcs_focal_plane_builtin(fp);
        return WF_OK;
    }
    return wf_wcs_focal_plane_load(data_dir, fp);
}

/* ---- spherical helpers ------------------------------------------------------------------ */

void wf_wcs_tangent_deproject(double ra0, double dec0, double xi, double eta, double *ra, double *dec)
{
    double sd = sin(dec0), cd = cos(dec0);
    double den = cd - eta * sd;
    *ra = ra0 + atan2(xi, den);
    *dec = atan2(sd + eta * cd, hypot(xi, den));
}

wf_status wf_wcs_tangent_project(double ra0, double dec0, double ra, double dec, double *xi, double *eta)
{
    double sd0 = sin(dec0), cd0 = cos(dec0), sd = sin(dec), cd = cos(dec);
    double dra = ra - ra0, cdra = cos(dra);
    double cosc = sd0 * sd + cd0 * cd * cdra;
    if (!(cosc > 1e-12))
        return wf_error(WF_ERR_RANGE, "wcs: (%.6f, %.6f) is 90 deg or more from the tangent point (%.6f, %.6f)",
                        ra / DEG, dec / DEG, ra0 / DEG, dec0 / DEG);
    *xi = cd * sin(dra) / cosc;
    *eta = (cd0 * sd - sd0 * cd * cdra) / cosc;
    return WF_OK;
}

/* Position angle (east of north) at point 1 of the great circle towards point 2, radians. */
static double position_angle(double ra1, double dec1, double ra2, double dec2)
{
    double dra = ra2 - ra1;
    return atan2(sin(dra) * cos(dec2), cos(dec1) * sin(dec2) - sin(dec1) * cos(dec2) * cos(dra));
}

double wf_wcs_separation(double ra1, double dec1, double ra2, double dec2)
{
    /* Vincenty's form: accurate at every separation, unlike acos of the dot product. */
    double p1 = dec1 * DEG, p2 = dec2 * DEG, dl = (ra2 - ra1) * DEG;
    double num = hypot(cos(p2) * sin(dl), cos(p1) * sin(p2) - sin(p1) * cos(p2) * cos(dl));
    double den = sin(p1) * sin(p2) + cos(p1) * cos(p2) * cos(dl);
    return atan2(num, den) / DEG;
}

static double wrap360(double deg)
{
    double r = fmod(deg, 360.0);
    if (r < 0) r += 360.0;
    if (r >= 360.0) r -= 360.0; /* fmod of a tiny negative number rounds up to 360 */
    return r;
}

/* ---- WCS -------------------------------------------------------------------------------- */

wf_status wf_wcs_for_sca(const wf_focal_plane *fp, double ra, double dec, double pa, int sca,
                         wf_wcs *out)
{
    if (sca < 1 || sca > WF_WCS_NSCA)
        return wf_error(WF_ERR_RANGE, "wcs: SCA %d is not 1..%d", sca, WF_WCS_NSCA);
    if (!isfinite(ra) || !isfinite(dec) || !isfinite(pa))
        return wf_error(WF_ERR_INPUT, "wcs: pointing (%g, %g, PA %g) is not finite", ra, dec, pa);
    if (!(fabs(dec) < 90.0))
        return wf_error(WF_ERR_RANGE, "wcs: Dec %g is not inside (-90, 90)", dec);
    int s = sca - 1;
    wf_wcs w;
    memset(&w, 0, sizeof w);
    w.sca = sca;
    w.nx = w.ny = WF_WCS_NPIX;
    w.crpix[0] = w.crpix[1] = WF_WCS_NPIX / 2; /* GalSim: n_pix/2 in FITS numbering */

    /* The SCA centre: its focal-plane offset rotated by the focal-plane position angle and
     * laid on the sky through the boresight's tangent plane (GalSim's u points west). */
    double pa_fpa = (pa + fp->theta_fpa_deg) * DEG;
    double c = cos(pa_fpa), sn = sin(pa_fpa);
    double u = (fp->u0[s] * c - fp->v0[s] * sn) * DEG;
    double v = (fp->u0[s] * sn + fp->v0[s] * c) * DEG;
    double ra0 = ra * DEG, dec0 = dec * DEG, cra, cdec, pra, pdec;
    wf_wcs_tangent_deproject(ra0, dec0, -u, v, &cra, &cdec);

    /* North of the boresight's tangent plane is not north at the SCA: the meridians converge.
     * GalSim measures that turn with a point one degree up the tangent plane's v axis. */
    wf_wcs_tangent_deproject(ra0, dec0, -u, v + 1.0 * DEG, &pra, &pdec);
    double pa_sca = pa_fpa + position_angle(cra, cdec, pra, pdec);
    double cs = cos(pa_sca), ss = sin(pa_sca);
    double a10 = fp->a[s][1][0], a01 = fp->a[s][0][1], b10 = fp->b[s][1][0], b01 = fp->b[s][0][1];
    w.cd[0][0] = cs * a10 + ss * b10;
    w.cd[0][1] = cs * a01 + ss * b01;
    w.cd[1][0] = -ss * a10 + cs * b10;
    w.cd[1][1] = -ss * a01 + cs * b01;
    w.crval[0] = wrap360(cra / DEG);
    w.crval[1] = cdec / DEG;
    w.pa_sca_deg = pa_sca / DEG;
    w.a_order = fp->sip_order;
    for (int i = 0; i < WF_WCS_SIP_N; i++)
        for (int j = 0; j < WF_WCS_SIP_N; j++)
            if (i + j >= 2 && i + j <= w.a_order) {
                w.a[i][j] = fp->a[s][i][j];
                w.b[i][j] = fp->b[s][i][j];
            }
    *out = w;
    return WF_OK;
}

/* Polynomial sum_{2<=i+j<=order} c[i][j] u^i v^j and its two partial derivatives. */
static void sip_eval(const double c[WF_WCS_SIP_N][WF_WCS_SIP_N], int order, double u, double v,
                     double *f, double *fu, double *fv)
{
    double pu[WF_WCS_SIP_N], pv[WF_WCS_SIP_N];
    pu[0] = pv[0] = 1.0;
    for (int k = 1; k < WF_WCS_SIP_N; k++) {
        pu[k] = pu[k - 1] * u;
        pv[k] = pv[k - 1] * v;
    }
    double s = 0, su = 0, sv = 0;
    for (int i = 0; i <= order; i++)
        for (int j = 0; i + j <= order; j++) {
            if (i + j < 2) continue;
            double k = c[i][j];
            s += k * pu[i] * pv[j];
            if (i) su += k * i * pu[i - 1] * pv[j];
            if (j) sv += k * j * pu[i] * pv[j - 1];
        }
    *f = s;
    if (fu) *fu = su;
    if (fv) *fv = sv;
}

wf_status wf_wcs_pix2world(const wf_wcs *w, double x, double y, double *ra, double *dec)
{
    if (!isfinite(x) || !isfinite(y))
        return wf_error(WF_ERR_INPUT, "wcs: pixel (%g, %g) is not finite", x, y);
    double u = x + 1.0 - w->crpix[0], v = y + 1.0 - w->crpix[1];
    double fu = 0, gv = 0;
    if (w->a_order >= 2) {
        sip_eval(w->a, w->a_order, u, v, &fu, NULL, NULL);
        sip_eval(w->b, w->a_order, u, v, &gv, NULL, NULL);
    }
    double U = u + fu, V = v + gv;
    double xi = (w->cd[0][0] * U + w->cd[0][1] * V) * DEG;
    double eta = (w->cd[1][0] * U + w->cd[1][1] * V) * DEG;
    double r, d;
    wf_wcs_tangent_deproject(w->crval[0] * DEG, w->crval[1] * DEG, xi, eta, &r, &d);
    *ra = wrap360(r / DEG);
    *dec = d / DEG;
    return WF_OK;
}

wf_status wf_wcs_world2pix(const wf_wcs *w, double ra, double dec, double *x, double *y)
{
    if (!isfinite(ra) || !isfinite(dec))
        return wf_error(WF_ERR_INPUT, "wcs: position (%g, %g) is not finite", ra, dec);
    double xi, eta;
    if (wf_wcs_tangent_project(w->crval[0] * DEG, w->crval[1] * DEG, ra * DEG, dec * DEG, &xi, &eta))
        return wf_error(WF_ERR_RANGE, "wcs: (%.6f, %.6f) is 90 deg or more from SCA %d's centre",
                        ra, dec, w->sca);
    xi /= DEG;
    eta /= DEG;
    double det = w->cd[0][0] * w->cd[1][1] - w->cd[0][1] * w->cd[1][0];
    double U = (w->cd[1][1] * xi - w->cd[0][1] * eta) / det;
    double V = (-w->cd[1][0] * xi + w->cd[0][0] * eta) / det;
    double u = U, v = V;
    if (w->a_order >= 2) {
        int done = 0;
        for (int it = 0; it < NEWTON_MAX_ITER && !done; it++) {
            double f, fu, fv, g, gu, gv;
            sip_eval(w->a, w->a_order, u, v, &f, &fu, &fv);
            sip_eval(w->b, w->a_order, u, v, &g, &gu, &gv);
            double r1 = u + f - U, r2 = v + g - V;
            double j11 = 1 + fu, j12 = fv, j21 = gu, j22 = 1 + gv;
            double jd = j11 * j22 - j12 * j21;
            if (!(fabs(jd) > 1e-12)) break;
            double du = (j22 * r1 - j12 * r2) / jd, dv = (-j21 * r1 + j11 * r2) / jd;
            u -= du;
            v -= dv;
            if (!isfinite(u) || !isfinite(v)) break;
            done = fabs(du) < NEWTON_TOL && fabs(dv) < NEWTON_TOL;
        }
        if (!done)
            return wf_error(WF_ERR_RANGE, "wcs: SIP inverse did not converge for (%.6f, %.6f) on "
                            "SCA %d (too far off the detector?)", ra, dec, w->sca);
    }
    *x = u + w->crpix[0] - 1.0;
    *y = v + w->crpix[1] - 1.0;
    return WF_OK;
}

/* ---- inverse SIP by least squares ------------------------------------------------------- */

#define FIT_GRID 33
#define FIT_TERMS 15 /* i + j <= 4 */

/* Solves the symmetric positive definite n x n system m x = r in place (Cholesky). */
static int cholesky_solve(double *m, double *r, int n)
{
    for (int j = 0; j < n; j++) {
        double d = m[j * n + j];
        for (int k = 0; k < j; k++) d -= m[j * n + k] * m[j * n + k];
        if (!(d > 0)) return 0;
        d = sqrt(d);
        m[j * n + j] = d;
        for (int i = j + 1; i < n; i++) {
            double s = m[i * n + j];
            for (int k = 0; k < j; k++) s -= m[i * n + k] * m[j * n + k];
            m[i * n + j] = s / d;
        }
    }
    for (int i = 0; i < n; i++) {
        double s = r[i];
        for (int k = 0; k < i; k++) s -= m[i * n + k] * r[k];
        r[i] = s / m[i * n + i];
    }
    for (int i = n - 1; i >= 0; i--) {
        double s = r[i];
        for (int k = i + 1; k < n; k++) s -= m[k * n + i] * r[k];
        r[i] = s / m[i * n + i];
    }
    return 1;
}

wf_status wf_wcs_fit_inverse(const wf_wcs *w, int ap_order, double ap[WF_WCS_SIP_N][WF_WCS_SIP_N],
                             double bp[WF_WCS_SIP_N][WF_WCS_SIP_N], double *max_resid)
{
    if (ap_order < 1 || ap_order >= WF_WCS_SIP_N)
        return wf_error(WF_ERR_RANGE, "wcs: inverse SIP order %d is not 1..%d", ap_order,
                        WF_WCS_SIP_N - 1);
    int pi[FIT_TERMS], pj[FIT_TERMS], nt = 0;
    for (int i = 0; i <= ap_order; i++)
        for (int j = 0; i + j <= ap_order; j++) {
            pi[nt] = i;
            pj[nt] = j;
            nt++;
        }
    /* Powers of ~2000-pixel offsets span 13 decades; fitting in units of the half size keeps
     * the normal equations well conditioned. */
    const double scale = 0.5 * w->nx;
    double m[FIT_TERMS * FIT_TERMS] = {0}, ru[FIT_TERMS] = {0}, rv[FIT_TERMS] = {0};
    double basis[FIT_TERMS];
    for (int gy = 0; gy < FIT_GRID; gy++)
        for (int gx = 0; gx < FIT_GRID; gx++) {
            double x = -0.5 + w->nx * gx / (FIT_GRID - 1.0);
            double y = -0.5 + w->ny * gy / (FIT_GRID - 1.0);
            double u = x + 1.0 - w->crpix[0], v = y + 1.0 - w->crpix[1], f = 0, g = 0;
            if (w->a_order >= 2) {
                sip_eval(w->a, w->a_order, u, v, &f, NULL, NULL);
                sip_eval(w->b, w->a_order, u, v, &g, NULL, NULL);
            }
            double U = (u + f) / scale, V = (v + g) / scale;
            for (int t = 0; t < nt; t++) basis[t] = pow(U, pi[t]) * pow(V, pj[t]);
            for (int t = 0; t < nt; t++) {
                ru[t] += basis[t] * (-f);
                rv[t] += basis[t] * (-g);
                for (int k = 0; k < nt; k++) m[t * nt + k] += basis[t] * basis[k];
            }
        }
    double m2[FIT_TERMS * FIT_TERMS];
    memcpy(m2, m, sizeof m2);
    if (!cholesky_solve(m, ru, nt) || !cholesky_solve(m2, rv, nt))
        return wf_error(WF_ERR_INTERNAL, "wcs: inverse SIP normal equations are singular");
    memset(ap, 0, sizeof(double) * WF_WCS_SIP_N * WF_WCS_SIP_N);
    memset(bp, 0, sizeof(double) * WF_WCS_SIP_N * WF_WCS_SIP_N);
    for (int t = 0; t < nt; t++) {
        double sc = pow(scale, pi[t] + pj[t]);
        ap[pi[t]][pj[t]] = ru[t] / sc;
        bp[pi[t]][pj[t]] = rv[t] / sc;
    }
    if (max_resid) {
        /* Judge the fit on a finer grid than it was made on. */
        double worst = 0;
        const int n = 2 * FIT_GRID + 1;
        for (int gy = 0; gy < n; gy++)
            for (int gx = 0; gx < n; gx++) {
                double x = -0.5 + w->nx * gx / (n - 1.0), y = -0.5 + w->ny * gy / (n - 1.0);
                double u = x + 1.0 - w->crpix[0], v = y + 1.0 - w->crpix[1], f = 0, g = 0;
                if (w->a_order >= 2) {
                    sip_eval(w->a, w->a_order, u, v, &f, NULL, NULL);
                    sip_eval(w->b, w->a_order, u, v, &g, NULL, NULL);
                }
                double U = u + f, V = v + g, du = 0, dv = 0, pu = 1;
                for (int i = 0; i <= ap_order; i++, pu *= U) {
                    double pv = 1;
                    for (int j = 0; i + j <= ap_order; j++, pv *= V) {
                        du += ap[i][j] * pu * pv;
                        dv += bp[i][j] * pu * pv;
                    }
                }
                double e = hypot(U + du - u, V + dv - v);
                if (e > worst) worst = e;
            }
        *max_resid = worst;
    }
    return WF_OK;
}

/* ---- FITS header -------------------------------------------------------------------------- */

/* Shortest exact digits, but never fewer than the integer part needs: 2044, not 2.044E+03. */
static int key_digits(double v)
{
    int d = wf_fits_double_digits(v);
    int whole = fabs(v) >= 1.0 ? (int)floor(log10(fabs(v))) + 1 : 1;
    return whole > d && whole <= 17 ? whole : d;
}

static void key_dbl(fitsfile *f, const char *name, double v, const char *comment, int *status)
{
    fits_update_key_dbl(f, name, v, -key_digits(v), comment, status);
}

wf_status wf_wcs_write_header(const wf_wcs *w, fitsfile *f, const char *path)
{
    int sip = w->a_order >= 2;
    double ap[WF_WCS_SIP_N][WF_WCS_SIP_N], bp[WF_WCS_SIP_N][WF_WCS_SIP_N];
    if (sip) {
        wf_status st = wf_wcs_fit_inverse(w, w->a_order, ap, bp, NULL);
        if (st) return st;
    }
    int status = 0;
    char name[32];
    fits_update_key_lng(f, "WCSAXES", 2, "number of World Coordinate System axes", &status);
    const char *proj = sip ? "gnomonic projection, SIP distortion" : "gnomonic projection";
    fits_update_key_str(f, "CTYPE1", sip ? "RA---TAN-SIP" : "RA---TAN", proj, &status);
    fits_update_key_str(f, "CTYPE2", sip ? "DEC--TAN-SIP" : "DEC--TAN", proj, &status);
    fits_update_key_str(f, "CUNIT1", "deg", "unit of CRVAL1 and CD1_j", &status);
    fits_update_key_str(f, "CUNIT2", "deg", "unit of CRVAL2 and CD2_j", &status);
    fits_update_key_str(f, "RADESYS", "ICRS", "celestial reference frame", &status);
    key_dbl(f, "CRPIX1", w->crpix[0], "reference pixel x (FITS, first pixel is 1)", &status);
    key_dbl(f, "CRPIX2", w->crpix[1], "reference pixel y (FITS, first pixel is 1)", &status);
    key_dbl(f, "CRVAL1", w->crval[0], "[deg] RA at the reference pixel", &status);
    key_dbl(f, "CRVAL2", w->crval[1], "[deg] Dec at the reference pixel", &status);
    key_dbl(f, "CD1_1", w->cd[0][0], "[deg/pixel] d(RA axis)/dx", &status);
    key_dbl(f, "CD1_2", w->cd[0][1], "[deg/pixel] d(RA axis)/dy", &status);
    key_dbl(f, "CD2_1", w->cd[1][0], "[deg/pixel] d(Dec axis)/dx", &status);
    key_dbl(f, "CD2_2", w->cd[1][1], "[deg/pixel] d(Dec axis)/dy", &status);
    key_dbl(f, "LONPOLE", 180.0, "[deg] native longitude of the celestial pole", &status);
    key_dbl(f, "ORIENTAT", w->pa_sca_deg, "[deg] position angle of the image +y axis", &status);
    if (w->sca > 0) fits_update_key_lng(f, "SCA_NUM", w->sca, "SCA number (1-18)", &status);
    if (sip) {
        fits_update_key_lng(f, "A_ORDER", w->a_order, "SIP forward order, x", &status);
        fits_update_key_lng(f, "B_ORDER", w->a_order, "SIP forward order, y", &status);
        for (int i = 0; i <= w->a_order; i++)
            for (int j = 0; i + j <= w->a_order; j++) {
                if (i + j < 2) continue;
                snprintf(name, sizeof name, "A_%d_%d", i, j);
                key_dbl(f, name, w->a[i][j], "", &status);
                snprintf(name, sizeof name, "B_%d_%d", i, j);
                key_dbl(f, name, w->b[i][j], "", &status);
            }
        fits_update_key_lng(f, "AP_ORDER", w->a_order, "SIP inverse order (least squares)",
                            &status);
        fits_update_key_lng(f, "BP_ORDER", w->a_order, "SIP inverse order (least squares)",
                            &status);
        for (int i = 0; i <= w->a_order; i++)
            for (int j = 0; i + j <= w->a_order; j++) {
                snprintf(name, sizeof name, "AP_%d_%d", i, j);
                key_dbl(f, name, ap[i][j], "", &status);
                snprintf(name, sizeof name, "BP_%d_%d", i, j);
                key_dbl(f, name, bp[i][j], "", &status);
            }
    }
    return wf_fits_error(status, path, "writing the WCS keywords");
}

/* ---- reading a header ------------------------------------------------------------------- */

static int read_dbl(fitsfile *f, const char *name, double *v, int *status)
{
    if (*status) return *status;
    fits_read_key_dbl(f, name, v, NULL, status);
    return *status;
}

wf_status wf_wcs_read_header(fitsfile *f, const char *path, wf_wcs *out)
{
    wf_wcs w;
    memset(&w, 0, sizeof w);
    int status = 0, naxis = 0;
    long naxes[2] = {0, 0};
    char hdu[FLEN_VALUE] = "";
    if (fits_read_key_str(f, "EXTNAME", hdu, NULL, &status)) {
        status = 0;
        fits_clear_errmsg();
        snprintf(hdu, sizeof hdu, "HDU");
    }
    if (fits_get_img_dim(f, &naxis, &status) || fits_get_img_size(f, 2, naxes, &status))
        return wf_fits_error(status, path, "reading the image size");
    if (naxis != 2 || naxes[0] < 1 || naxes[1] < 1)
        return wf_error(WF_ERR_INPUT, "%s: %s: not a 2-D image (NAXIS %d)", path, hdu, naxis);
    w.nx = (int)naxes[0];
    w.ny = (int)naxes[1];
    char c1[FLEN_VALUE] = "", c2[FLEN_VALUE] = "";
    fits_read_key_str(f, "CTYPE1", c1, NULL, &status);
    fits_read_key_str(f, "CTYPE2", c2, NULL, &status);
    if (status == KEY_NO_EXIST) {
        fits_clear_errmsg();
        return wf_error(WF_ERR_INPUT, "%s: %s has no WCS (CTYPE1/CTYPE2 missing)", path, hdu);
    }
    if (status) return wf_fits_error(status, path, "reading CTYPE1/CTYPE2");
    int sip = 0;
    if (!strcmp(c1, "RA---TAN-SIP") && !strcmp(c2, "DEC--TAN-SIP")) sip = 1;
    else if (strcmp(c1, "RA---TAN") || strcmp(c2, "DEC--TAN"))
        return wf_error(WF_ERR_INPUT, "%s: %s: CTYPE '%s'/'%s' is not RA---TAN(-SIP)/DEC--TAN(-SIP), "
                        "the only projection read", path, hdu, c1, c2);
    read_dbl(f, "CRPIX1", &w.crpix[0], &status);
    read_dbl(f, "CRPIX2", &w.crpix[1], &status);
    read_dbl(f, "CRVAL1", &w.crval[0], &status);
    read_dbl(f, "CRVAL2", &w.crval[1], &status);
    read_dbl(f, "CD1_1", &w.cd[0][0], &status);
    read_dbl(f, "CD1_2", &w.cd[0][1], &status);
    read_dbl(f, "CD2_1", &w.cd[1][0], &status);
    read_dbl(f, "CD2_2", &w.cd[1][1], &status);
    if (status == KEY_NO_EXIST) {
        char msg[FLEN_ERRMSG] = "";
        fits_read_errmsg(msg);
        fits_clear_errmsg();
        return wf_error(WF_ERR_INPUT, "%s: %s: incomplete WCS (CRPIXi, CRVALi and CDi_j are all "
                        "needed): %s", path, hdu, msg);
    }
    if (status) return wf_fits_error(status, path, "reading the WCS");
    double lonpole = 180.0;
    if (fits_read_key_dbl(f, "LONPOLE", &lonpole, NULL, &status) == KEY_NO_EXIST) {
        status = 0;
        fits_clear_errmsg();
    }
    if (status) return wf_fits_error(status, path, "reading LONPOLE");
    if (lonpole != 180.0)
        return wf_error(WF_ERR_INPUT, "%s: %s: LONPOLE %g (only 180, the TAN default, is read)", path, hdu, lonpole);
    double det = w.cd[0][0] * w.cd[1][1] - w.cd[0][1] * w.cd[1][0];
    if (!(fabs(det) > 0) || !isfinite(det) || !isfinite(w.crval[0]) || !(fabs(w.crval[1]) < 90.0))
        return wf_error(WF_ERR_INPUT, "%s: %s: degenerate WCS (CD determinant %g, CRVAL %g %g)", path,
                        hdu, det, w.crval[0], w.crval[1]);
    if (sip) {
        long ao = 0, bo = 0;
        fits_read_key_lng(f, "A_ORDER", &ao, NULL, &status);
        fits_read_key_lng(f, "B_ORDER", &bo, NULL, &status);
        if (status) return wf_fits_error(status, path, "reading A_ORDER/B_ORDER of a TAN-SIP WCS");
        if (ao < 0 || ao >= WF_WCS_SIP_N || bo < 0 || bo >= WF_WCS_SIP_N)
            return wf_error(WF_ERR_INPUT, "%s: %s: SIP order %ld/%ld is not 0..%d", path, hdu, ao, bo,
                            WF_WCS_SIP_N - 1);
        w.a_order = (int)(ao > bo ? ao : bo);
        char name[32];
        for (int i = 0; i <= w.a_order; i++)
            for (int j = 0; i + j <= w.a_order; j++) {
                if (i + j < 2) continue;
                for (int ab = 0; ab < 2; ab++) {
                    double *c = ab ? &w.b[i][j] : &w.a[i][j];
                    if (i + j > (ab ? bo : ao)) continue;
                    snprintf(name, sizeof name, "%c_%d_%d", ab ? 'B' : 'A', i, j);
                    if (fits_read_key_dbl(f, name, c, NULL, &status) == KEY_NO_EXIST) {
                        status = 0; /* an absent term is zero (SIP convention) */
                        fits_clear_errmsg();
                        *c = 0;
                    }
                }
            }
        if (status) return wf_fits_error(status, path, "reading the SIP coefficients");
        if (w.a_order < 2) w.a_order = 0;
    }
    long sca = 0;
    if (fits_read_key_lng(f, "SCA_NUM", &sca, NULL, &status) == KEY_NO_EXIST) {
        status = 0;
        fits_clear_errmsg();
    }
    w.sca = (int)sca;
    /* the position angle of +y: the direction of the CD matrix's second column */
    w.pa_sca_deg = atan2(w.cd[0][1], w.cd[1][1]) / DEG;
    if (fits_read_key_dbl(f, "ORIENTAT", &w.pa_sca_deg, NULL, &status) == KEY_NO_EXIST) {
        status = 0;
        fits_clear_errmsg();
    }
    if (status) return wf_fits_error(status, path, "reading SCA_NUM/ORIENTAT");
    *out = w;
    return WF_OK;
}
