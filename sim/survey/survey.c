#include "sim/survey/survey.h"

#include <ctype.h>
#include <errno.h>
#include <fitsio.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "sim/optics/bandpass.h"
#include "sim/fits/fitscheck.h"
#include "sim/fits/fitsout.h"

#define DEG (M_PI / 180.0)
#define DAY 86400.0
#define MAX_OFFSET_DEG 10.0       /* the layout must stay where a tangent plane is adequate */
#define MAX_COVERAGE_CELLS 200000000L
#define OVERLAP_TOL 1e-3          /* arcsec^2: below this two footprints only touch */
#define GAP_SEARCH 60.0           /* arcsec: pairs farther apart than this are not measured */

/* ---- parameters ------------------------------------------------------------------------- */

typedef enum { SK_DOUBLE, SK_INT, SK_INTLIST, SK_FILTERS, SK_DOUBLELIST } skind;

typedef struct skey {
    const char *name;
    skind kind;
    const char *unit;
    const char *def;
    double lo, hi;                /* bounds of each number */
    int lo_open;                  /* lo itself not allowed */
    size_t off;
    const char *doc;
} skey;

#define OFF(f) offsetof(wf_survey_params, f)

/* One table drives the defaults, --set and the documentation, so they cannot disagree.
 * Defaults: SPEC §6 / Wang et al. 2023 §2.3 unless said otherwise (docs/SURVEY.md). */
static const skey keys[] = {
    {"survey.ra", SK_DOUBLE, "deg", "71", 0, 360, 0, OFF(ra),
     "field centre RA (Akari Deep Field South)"},
    {"survey.dec", SK_DOUBLE, "deg", "-53", -88, 88, 0, OFF(dec), "field centre Dec"},
    {"survey.mjd_start", SK_DOUBLE, "d", "61420", 0, 1e6, 0, OFF(mjd_start),
     "MJD of the first exposure (2027-01-15, the date of GalSim's reference pointing; the "
     "paper's start date is not used by anything here)"},
    {"survey.visits", SK_INT, "", "146", 1, 100000, 0, OFF(visits),
     "number of visits (two years every 5 days)"},
    {"survey.visit_interval", SK_DOUBLE, "d", "5", 0, 3650, 1, OFF(visit_interval),
     "days between visit starts"},
    {"survey.orient_period", SK_DOUBLE, "d", "30", 0, 36500, 1, OFF(orient_period),
     "days per telescope orient"},
    {"survey.orient_step", SK_DOUBLE, "deg", "30", -360, 360, 0, OFF(orient_step),
     "turn of the orient from one period to the next"},
    {"survey.pa0", SK_DOUBLE, "deg", "0", -360, 360, 0, OFF(pa0),
     "observatory position angle of the first orient at the field centre (GalSim getWCS PA)"},
    {"survey.columns", SK_INTLIST, "", "5,6,5", 1, 64, 0, OFF(column_count),
     "pointings per column, columns in snake order"},
    {"survey.row_step", SK_DOUBLE, "arcmin", "24", 0, 600, 1, OFF(row_step),
     "spacing of pointings within a column (focal-plane short axis)"},
    {"survey.column_step", SK_DOUBLE, "arcmin", "49", 0, 600, 1, OFF(column_step),
     "spacing of columns (focal-plane long axis)"},
    {"survey.filters", SK_FILTERS, "", "Y106,J129,H158,F184", 0, 0, 0, OFF(filters),
     "filter sequence of a visit (snake forward in the 1st, backward in the 2nd, ...)"},
    {"survey.exptimes", SK_DOUBLELIST, "s", "300,300,300,900", 0, 1e5, 1, OFF(exptime),
     "exposure time per filter, in the order of survey.filters"},
    {"survey.slew_time", SK_DOUBLE, "s", "50", 0, 1e5, 0, OFF(slew_time),
     "slew and settle between pointings (Rubin et al. 2023, arXiv:2306.17222, assume 50 s of "
     "overheads per visit of a field in a filter)"},
    {"survey.filter_change_time", SK_DOUBLE, "s", "50", 0, 1e5, 0, OFF(filter_change_time),
     "filter change at one pointing (the same 50 s overhead assumption)"},
    {"survey.coverage_pixel", SK_DOUBLE, "arcsec", "36", 1, 3600, 0, OFF(coverage_pixel),
     "cell of the coverage map"},
};
#define NKEYS (sizeof keys / sizeof keys[0])

static const skey *find_key(const char *name, size_t len)
{
    for (size_t i = 0; i < NKEYS; i++)
        if (strlen(keys[i].name) == len && !strncmp(keys[i].name, name, len)) return &keys[i];
    return NULL;
}

int wf_survey_is_key(const char *assignment)
{
    return !strncmp(assignment, "survey.", 7);
}

static wf_status parse_number(const skey *k, const char *text, double *v, const char *origin)
{
    char *end;
    errno = 0;
    *v = strtod(text, &end);
    while (isspace((unsigned char)*end)) end++;
    if (end == text || *end || errno == ERANGE || !isfinite(*v))
        return wf_error(WF_ERR_INPUT, "%s: %s: '%s' is not a number", origin, k->name, text);
    if (k->kind == SK_INT || k->kind == SK_INTLIST) {
        if (*v != floor(*v))
            return wf_error(WF_ERR_INPUT, "%s: %s: '%s' is not a whole number", origin, k->name,
                            text);
    }
    if ((k->lo_open ? !(*v > k->lo) : !(*v >= k->lo)) || !(*v <= k->hi))
        return wf_error(WF_ERR_RANGE, "%s: %s: %s is outside %s%g, %g]", origin, k->name, text,
                        k->lo_open ? "(" : "[", k->lo, k->hi);
    if (k->kind == SK_DOUBLE && k->off == OFF(ra) && *v >= 360.0)
        return wf_error(WF_ERR_RANGE, "%s: %s: %s is outside [0, 360)", origin, k->name, text);
    return WF_OK;
}

/* Splits a comma-separated list in place; returns the item count or -1 when over max. */
static int split_list(char *text, char **items, int max)
{
    int n = 0;
    char *p = text;
    for (;;) {
        char *comma = strchr(p, ',');
        if (comma) *comma = '\0';
        while (isspace((unsigned char)*p)) p++;
        char *e = p + strlen(p);
        while (e > p && isspace((unsigned char)e[-1])) *--e = '\0';
        if (n == max) return -1;
        items[n++] = p;
        if (!comma) break;
        p = comma + 1;
    }
    return n;
}

static wf_status set_value(wf_survey_params *p, const skey *k, char *value, const char *origin)
{
    char *base = (char *)p + k->off;
    double v;
    wf_status st;
    switch (k->kind) {
    case SK_DOUBLE:
        if ((st = parse_number(k, value, &v, origin))) return st;
        *(double *)base = v;
        return WF_OK;
    case SK_INT:
        if ((st = parse_number(k, value, &v, origin))) return st;
        *(int *)base = (int)v;
        return WF_OK;
    case SK_INTLIST:
    case SK_DOUBLELIST:
    case SK_FILTERS: {
        int max = k->kind == SK_INTLIST ? WF_SURVEY_MAX_COLUMNS : WF_SURVEY_MAX_FILTERS;
        char *items[WF_SURVEY_MAX_COLUMNS + 1];
        double nums[WF_SURVEY_MAX_COLUMNS];
        int n = split_list(value, items, max);
        if (n < 0)
            return wf_error(WF_ERR_RANGE, "%s: %s: more than %d entries", origin, k->name, max);
        for (int i = 0; i < n; i++) {
            if (!*items[i])
                return wf_error(WF_ERR_INPUT, "%s: %s: entry %d is empty", origin, k->name,
                                i + 1);
            if (k->kind == SK_FILTERS) {
                size_t len = strlen(items[i]);
                if (len >= WF_SURVEY_FILTER_LEN)
                    return wf_error(WF_ERR_INPUT, "%s: %s: filter name '%s' longer than %d "
                                    "characters", origin, k->name, items[i],
                                    WF_SURVEY_FILTER_LEN - 1);
                for (size_t c = 0; c < len; c++)
                    if (!isalnum((unsigned char)items[i][c]) && items[i][c] != '_')
                        return wf_error(WF_ERR_INPUT, "%s: %s: filter name '%s' has a character "
                                        "other than letters, digits and '_'", origin, k->name,
                                        items[i]);
                /* a plan's filters are rendered by name (exposure.filter): read them as
                 * every command does, and keep each under its one name (W149 is W146) */
                wf_filter f;
                if ((st = wf_filter_parse(items[i], &f))) {
                    char msg[256];
                    snprintf(msg, sizeof msg, "%s", wf_error_message());
                    return wf_error(st, "%s: %s: %s", origin, k->name, msg);
                }
                items[i] = (char *)wf_filter_name(f);
                for (int j = 0; j < i; j++)
                    if (!strcmp(items[j], items[i]))
                        return wf_error(WF_ERR_INPUT, "%s: %s: filter '%s' listed twice", origin,
                                        k->name, items[i]);
                continue;
            }
            if ((st = parse_number(k, items[i], &nums[i], origin))) return st;
        }
        /* Only a list valid throughout replaces the old one. */
        for (int i = 0; i < n; i++) {
            if (k->kind == SK_FILTERS)
                snprintf(p->filters[i], WF_SURVEY_FILTER_LEN, "%s", items[i]);
            else if (k->kind == SK_INTLIST)
                p->column_count[i] = (int)nums[i];
            else
                p->exptime[i] = nums[i];
        }
        if (k->kind == SK_INTLIST) p->ncolumns = n;
        else if (k->kind == SK_FILTERS) p->nfilters = n;
        else p->nexptime = n;
        return WF_OK;
    }
    }
    return wf_error(WF_ERR_INTERNAL, "%s: %s: unknown key type", origin, k->name);
}

wf_status wf_survey_set(wf_survey_params *p, const char *assignment, const char *origin)
{
    if (!origin || !*origin) origin = "--set";
    const char *eq = strchr(assignment, '=');
    if (!eq) return wf_error(WF_ERR_INPUT, "%s: '%.80s': expected key=value", origin, assignment);
    size_t klen = (size_t)(eq - assignment);
    while (klen && isspace((unsigned char)assignment[klen - 1])) klen--;
    const char *name = assignment;
    while (isspace((unsigned char)*name) && klen) { name++; klen--; }
    const skey *k = find_key(name, klen);
    if (!k) {
        char list[1024];
        size_t len = 0;
        for (size_t i = 0; i < NKEYS && len < sizeof list; i++)
            len += (size_t)snprintf(list + len, sizeof list - len, "%s%s", i ? ", " : "",
                                    keys[i].name);
        return wf_error(WF_ERR_INPUT, "%s: unknown survey key '%.*s' (known: %s)", origin,
                        (int)klen, name, list);
    }
    char value[512];
    const char *v = eq + 1;
    while (isspace((unsigned char)*v)) v++;
    if (strlen(v) >= sizeof value)
        return wf_error(WF_ERR_INPUT, "%s: %s: value longer than %zu characters", origin,
                        k->name, sizeof value - 1);
    snprintf(value, sizeof value, "%s", v);
    size_t vl = strlen(value);
    while (vl && isspace((unsigned char)value[vl - 1])) value[--vl] = '\0';
    if (!*value) return wf_error(WF_ERR_INPUT, "%s: %s: no value given", origin, k->name);
    wf_survey_params tmp = *p;
    wf_status st = set_value(&tmp, k, value, origin);
    if (!st) *p = tmp;
    return st;
}

void wf_survey_defaults(wf_survey_params *p)
{
    memset(p, 0, sizeof *p);
    for (size_t i = 0; i < NKEYS; i++) {
        char buf[256];
        snprintf(buf, sizeof buf, "%s=%s", keys[i].name, keys[i].def);
        wf_status st = wf_survey_set(p, buf, "default");
        (void)st; /* the table's defaults are checked by tests/test_survey.c */
    }
}

static double visit_duration(const wf_survey_params *p, int npointings)
{
    double t = 0;
    for (int f = 0; f < p->nfilters; f++) t += npointings * p->exptime[f];
    t += p->nfilters * (npointings - 1) * p->slew_time + (p->nfilters - 1) * p->filter_change_time;
    return t;
}

wf_status wf_survey_check(const wf_survey_params *p)
{
    if (p->nfilters < 1) return wf_error(WF_ERR_INPUT, "survey.filters: no filter given");
    if (p->nexptime != p->nfilters)
        return wf_error(WF_ERR_INPUT, "survey.exptimes: %d exposure times for %d filters "
                        "(survey.filters)", p->nexptime, p->nfilters);
    if (p->ncolumns < 1) return wf_error(WF_ERR_INPUT, "survey.columns: no column given");
    int np = 0, maxcol = 0;
    for (int c = 0; c < p->ncolumns; c++) {
        np += p->column_count[c];
        if (p->column_count[c] > maxcol) maxcol = p->column_count[c];
    }
    if (np > WF_SURVEY_MAX_POINTINGS)
        return wf_error(WF_ERR_RANGE, "survey.columns: %d pointings, more than %d", np,
                        WF_SURVEY_MAX_POINTINGS);
    double half_u = 0.5 * (p->ncolumns - 1) * p->column_step / 60.0;
    double half_v = 0.5 * (maxcol - 1) * p->row_step / 60.0;
    if (half_u > MAX_OFFSET_DEG || half_v > MAX_OFFSET_DEG)
        return wf_error(WF_ERR_RANGE, "survey.columns/row_step/column_step: the layout reaches "
                        "%.1f deg from the field centre, more than %.0f", fmax(half_u, half_v),
                        MAX_OFFSET_DEG);
    double nexp = (double)p->visits * np * p->nfilters;
    if (nexp > WF_SURVEY_MAX_EXPOSURES)
        return wf_error(WF_ERR_RANGE, "survey.visits: %.0f exposures, more than %d", nexp,
                        WF_SURVEY_MAX_EXPOSURES);
    double dur = visit_duration(p, np);
    if (p->visits > 1 && dur > p->visit_interval * DAY)
        return wf_error(WF_ERR_RANGE, "survey.visit_interval: a visit takes %.0f s (exposures, "
                        "slews, filter changes), longer than the %.0f s between visits", dur,
                        p->visit_interval * DAY);
    return WF_OK;
}

void wf_survey_write_doc(FILE *out)
{
    fprintf(out, "| key | unit | default | meaning |\n|---|---|---|---|\n");
    for (size_t i = 0; i < NKEYS; i++)
        fprintf(out, "| `%s` | %s | %s | %s |\n", keys[i].name, keys[i].unit, keys[i].def,
                keys[i].doc);
}

/* ---- geometry ---------------------------------------------------------------------------- */

typedef struct vec3 {
    double x, y, z;
} vec3;

static vec3 v_add(vec3 a, double s, vec3 b) { return (vec3){a.x + s * b.x, a.y + s * b.y, a.z + s * b.z}; }
static vec3 v_scale(double s, vec3 a) { return (vec3){s * a.x, s * a.y, s * a.z}; }
static double v_dot(vec3 a, vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

static vec3 v_radec(double ra, double dec)
{
    return (vec3){cos(dec) * cos(ra), cos(dec) * sin(ra), sin(dec)};
}

static vec3 v_east(double ra) { return (vec3){-sin(ra), cos(ra), 0}; }
static vec3 v_north(double ra, double dec)
{
    return (vec3){-sin(dec) * cos(ra), -sin(dec) * sin(ra), cos(dec)};
}

static double wrap360(double deg)
{
    double r = fmod(deg, 360.0);
    if (r < 0) r += 360.0;
    if (r >= 360.0) r -= 360.0;
    return r;
}

/* Boresight and GalSim PA of the pointing reached from the field-centre attitude (orient PA
 * pa_deg) by turning about the focal-plane v axis by du, then about the new u axis by dv:
 * the eigen-axis slews of the snake, which keep the inertial roll. */
static void place_pointing(const wf_survey_params *p, double theta_fpa, double pa_deg,
                           double du, double dv, double *ra, double *dec, double *pa)
{
    double ra0 = p->ra * DEG, dec0 = p->dec * DEG, paf = (pa_deg + theta_fpa) * DEG;
    vec3 c = v_radec(ra0, dec0), e = v_east(ra0), n = v_north(ra0, dec0);
    /* GalSim's +u is west: at focal-plane PA 0 the u axis is -east. */
    vec3 au = v_add(v_scale(-cos(paf), e), sin(paf), n);
    vec3 av = v_add(v_scale(sin(paf), e), cos(paf), n);
    double cu = cos(du * DEG), su = sin(du * DEG), cv = cos(dv * DEG), sv = sin(dv * DEG);
    vec3 c1 = v_add(v_scale(cu, c), su, au);
    vec3 c2 = v_add(v_scale(cv, c1), sv, av);
    vec3 av2 = v_add(v_scale(cv, av), -sv, c1);
    double r = atan2(c2.y, c2.x), d = atan2(c2.z, hypot(c2.x, c2.y));
    double pf = atan2(v_dot(av2, v_east(r)), v_dot(av2, v_north(r, d)));
    *ra = wrap360(r / DEG);
    *dec = d / DEG;
    *pa = wrap360(pf / DEG - theta_fpa);
}

/* Corner of each SCA (pixel edges) in the tangent plane of (ra0, dec0), degrees, east = +x. */
static wf_status sca_corners(const wf_focal_plane *fp, double ra, double dec, double pa,
                             double ra0, double dec0, double q[WF_WCS_NSCA][4][2])
{
    const double e0 = -0.5, e1 = WF_WCS_NPIX - 0.5;
    const double px[4] = {e0, e1, e1, e0}, py[4] = {e0, e0, e1, e1};
    double s0 = sin(dec0 * DEG), c0 = cos(dec0 * DEG);
    for (int s = 0; s < WF_WCS_NSCA; s++) {
        wf_wcs w;
        wf_status st = wf_wcs_for_sca(fp, ra, dec, pa, s + 1, &w);
        if (st) return st;
        for (int k = 0; k < 4; k++) {
            double r, d;
            if ((st = wf_wcs_pix2world(&w, px[k], py[k], &r, &d))) return st;
            double dra = (r - ra0) * DEG, sd = sin(d * DEG), cd = cos(d * DEG);
            double cosc = s0 * sd + c0 * cd * cos(dra);
            if (!(cosc > 0.1))
                return wf_error(WF_ERR_RANGE, "survey: SCA %d lies more than 84 deg from the "
                                "field centre", s + 1);
            q[s][k][0] = cd * sin(dra) / cosc / DEG;
            q[s][k][1] = (c0 * sd - s0 * cd * cos(dra)) / cosc / DEG;
        }
    }
    return WF_OK;
}

wf_status wf_survey_min_steps(const wf_focal_plane *fp, double *row_min, double *column_min)
{
    /* Focal-plane PA 0 at the equator: the tangent plane's (-x, y) is the frame (u, v). */
    double q[WF_WCS_NSCA][4][2];
    wf_status st = sca_corners(fp, 0.0, 0.0, -fp->theta_fpa_deg, 0.0, 0.0, q);
    if (st) return st;
    double umin[WF_WCS_NSCA], umax[WF_WCS_NSCA], vmin[WF_WCS_NSCA], vmax[WF_WCS_NSCA];
    double lo = INFINITY, hi = -INFINITY;
    for (int s = 0; s < WF_WCS_NSCA; s++) {
        umin[s] = vmin[s] = INFINITY;
        umax[s] = vmax[s] = -INFINITY;
        for (int k = 0; k < 4; k++) {
            double u = -q[s][k][0], v = q[s][k][1];
            umin[s] = fmin(umin[s], u);
            umax[s] = fmax(umax[s], u);
            vmin[s] = fmin(vmin[s], v);
            vmax[s] = fmax(vmax[s], v);
        }
        lo = fmin(lo, umin[s]);
        hi = fmax(hi, umax[s]);
    }
    /* A copy shifted by +step along v clears SCA j of the original when every SCA i that
     * shares u with it starts above j's top. */
    double row = 0;
    for (int i = 0; i < WF_WCS_NSCA; i++)
        for (int j = 0; j < WF_WCS_NSCA; j++)
            if (umin[i] < umax[j] && umin[j] < umax[i]) row = fmax(row, vmax[j] - vmin[i]);
    *row_min = row * 60.0;
    *column_min = (hi - lo) * 60.0;
    return WF_OK;
}

/* ---- the plan ------------------------------------------------------------------------------ */

void wf_survey_plan_free(wf_survey_plan *plan)
{
    if (!plan) return;
    free(plan->exp);
    plan->exp = NULL;
    plan->nexp = 0;
}

wf_status wf_survey_plan_make(const wf_survey_params *p, const wf_focal_plane *fp,
                              wf_survey_plan *out)
{
    wf_status st = wf_survey_check(p);
    if (st) return st;
    wf_survey_plan plan;
    memset(&plan, 0, sizeof plan);
    plan.par = *p;
    memcpy(plan.fp_source, fp->source, sizeof plan.fp_source);

    /* The focal plane's SCAs are centred ~4' off the boresight along v; offsetting every
     * pointing by that centroid centres the survey footprint on the field. */
    for (int s = 0; s < WF_WCS_NSCA; s++) {
        plan.fpa_du += fp->u0[s] / WF_WCS_NSCA;
        plan.fpa_dv += fp->v0[s] / WF_WCS_NSCA;
    }
    int np = 0;
    for (int c = 0; c < p->ncolumns; c++) {
        double uc = (c - 0.5 * (p->ncolumns - 1)) * p->column_step / 60.0;
        int n = p->column_count[c];
        for (int k = 0; k < n; k++) {
            int row = c % 2 == 0 ? k : n - 1 - k; /* snake: up, down, up, ... */
            plan.column[np] = c;
            plan.du[np] = uc - plan.fpa_du;
            plan.dv[np] = (row - 0.5 * (n - 1)) * p->row_step / 60.0 - plan.fpa_dv;
            np++;
        }
    }
    plan.npointings = np;

    double last_start = p->mjd_start + (p->visits - 1) * p->visit_interval;
    plan.norients = (int)floor((last_start - p->mjd_start) / p->orient_period + 1e-9) + 1;
    size_t nplace = (size_t)plan.norients * (size_t)np;
    double *place = malloc(nplace * 3 * sizeof *place);
    plan.nexp = (size_t)p->visits * (size_t)np * (size_t)p->nfilters;
    plan.exp = calloc(plan.nexp, sizeof *plan.exp);
    if (!place || !plan.exp) {
        free(place);
        free(plan.exp);
        return wf_error(WF_ERR_NOMEM, "survey: no memory for %zu exposures", plan.nexp);
    }
    for (int o = 0; o < plan.norients; o++)
        for (int i = 0; i < np; i++) {
            double *q = place + 3 * ((size_t)o * np + i);
            place_pointing(p, fp->theta_fpa_deg, p->pa0 + o * p->orient_step, plan.du[i],
                           plan.dv[i], &q[0], &q[1], &q[2]);
        }

    size_t e = 0;
    for (int v = 0; v < p->visits; v++) {
        double start = p->mjd_start + v * p->visit_interval;
        int orient = (int)floor((start - p->mjd_start) / p->orient_period + 1e-9);
        double t = 0; /* seconds since the visit's first exposure began */
        int prev_pointing = -1;
        for (int pass = 0; pass < p->nfilters; pass++)
            for (int k = 0; k < np; k++) {
                int i = pass % 2 == 0 ? k : np - 1 - k;
                if (prev_pointing >= 0)
                    t += i != prev_pointing ? p->slew_time : p->filter_change_time;
                wf_exposure *x = &plan.exp[e];
                const double *q = place + 3 * ((size_t)orient * np + i);
                x->id = (int)e;
                x->visit = v;
                x->orient = orient;
                x->pointing = i;
                x->pass = pass;
                x->filter = pass;
                x->ra = q[0];
                x->dec = q[1];
                x->pa = q[2];
                x->orient_pa = wrap360(p->pa0 + orient * p->orient_step);
                x->exptime = p->exptime[pass];
                x->mjd_start = start + t / DAY;
                x->mjd_mid = start + (t + 0.5 * x->exptime) / DAY;
                t += x->exptime;
                prev_pointing = i;
                e++;
            }
    }
    free(place);
    *out = plan;
    return WF_OK;
}

/* ---- coverage ------------------------------------------------------------------------------ */

void wf_survey_coverage_free(wf_survey_coverage *cov)
{
    if (!cov) return;
    free(cov->count);
    cov->count = NULL;
}

wf_status wf_survey_coverage_make(const wf_survey_plan *plan, const wf_focal_plane *fp,
                                  wf_survey_coverage *out)
{
    const wf_survey_params *p = &plan->par;
    wf_survey_coverage cov;
    memset(&cov, 0, sizeof cov);
    cov.nfilters = p->nfilters;
    cov.ra0 = p->ra;
    cov.dec0 = p->dec;
    cov.pixel = p->coverage_pixel / 3600.0;
    cov.threshold[0] = 1;
    cov.threshold[1] = 10;
    cov.threshold[2] = 100;
    cov.threshold[3] = (p->visits + 1) / 2;
    for (int f = 0; f < p->nfilters; f++) memcpy(cov.filters[f], p->filters[f], WF_SURVEY_FILTER_LEN);

    /* Exposures of one (orient, pointing) share their footprint: rasterise each once. */
    int np = plan->npointings;
    size_t nkey = (size_t)plan->norients * np;
    int *nper = calloc(nkey * p->nfilters, sizeof *nper);
    double *where = malloc(nkey * 3 * sizeof *where);
    if (!nper || !where) {
        free(nper);
        free(where);
        return wf_error(WF_ERR_NOMEM, "survey coverage: out of memory");
    }
    double reach = 0;
    for (size_t e = 0; e < plan->nexp; e++) {
        const wf_exposure *x = &plan->exp[e];
        size_t key = (size_t)x->orient * np + x->pointing;
        nper[key * p->nfilters + x->filter]++;
        where[3 * key] = x->ra;
        where[3 * key + 1] = x->dec;
        where[3 * key + 2] = x->pa;
        reach = fmax(reach, wf_wcs_separation(p->ra, p->dec, x->ra, x->dec));
    }
    /* The farthest SCA corner is under 0.6 deg from the boresight. */
    double half = tan((reach + 0.7) * DEG) / DEG;
    int h = (int)ceil(half / cov.pixel);
    cov.nx = cov.ny = 2 * h + 1;
    if ((double)cov.nx * cov.ny * cov.nfilters > MAX_COVERAGE_CELLS) {
        free(nper);
        free(where);
        return wf_error(WF_ERR_RANGE, "survey.coverage_pixel: %g arcsec needs %d x %d cells per "
                        "filter; choose a larger cell", p->coverage_pixel, cov.nx, cov.ny);
    }
    size_t plane = (size_t)cov.nx * cov.ny;
    cov.count = calloc(plane * cov.nfilters, sizeof *cov.count);
    if (!cov.count) {
        free(nper);
        free(where);
        return wf_error(WF_ERR_NOMEM, "survey coverage: no memory for %d x %d cells", cov.nx,
                        cov.ny);
    }
    const double ra0 = p->ra * DEG, dec0 = p->dec * DEG;
    wf_status st = WF_OK;
    for (size_t key = 0; key < nkey && !st; key++) {
        const int *n = nper + key * p->nfilters;
        int any = 0;
        for (int f = 0; f < p->nfilters; f++) any |= n[f] > 0;
        if (!any) continue;
        const double *q = where + 3 * key;
        double corner[WF_WCS_NSCA][4][2];
        if ((st = sca_corners(fp, q[0], q[1], q[2], p->ra, p->dec, corner))) break;
        for (int s = 0; s < WF_WCS_NSCA && !st; s++) {
            wf_wcs w;
            if ((st = wf_wcs_for_sca(fp, q[0], q[1], q[2], s + 1, &w))) break;
            double xmin = INFINITY, xmax = -INFINITY, ymin = INFINITY, ymax = -INFINITY;
            for (int k = 0; k < 4; k++) {
                xmin = fmin(xmin, corner[s][k][0]);
                xmax = fmax(xmax, corner[s][k][0]);
                ymin = fmin(ymin, corner[s][k][1]);
                ymax = fmax(ymax, corner[s][k][1]);
            }
            /* Cell i is at xi = (h - i) * pixel (east to the left), eta = (j - h) * pixel. */
            int i0 = (int)floor(h - xmax / cov.pixel) - 1, i1 = (int)ceil(h - xmin / cov.pixel) + 1;
            int j0 = (int)floor(h + ymin / cov.pixel) - 1, j1 = (int)ceil(h + ymax / cov.pixel) + 1;
            if (i0 < 0) i0 = 0;
            if (j0 < 0) j0 = 0;
            if (i1 >= cov.nx) i1 = cov.nx - 1;
            if (j1 >= cov.ny) j1 = cov.ny - 1;
            for (int j = j0; j <= j1 && !st; j++)
                for (int i = i0; i <= i1; i++) {
                    double xi = (h - i) * cov.pixel * DEG, eta = (j - h) * cov.pixel * DEG, ra, dec;
                    wf_wcs_tangent_deproject(ra0, dec0, xi, eta, &ra, &dec);
                    ra /= DEG;
                    dec /= DEG;
                    double px, py;
                    if (wf_wcs_world2pix(&w, ra, dec, &px, &py)) continue; /* far off: outside */
                    if (px < -0.5 || px >= WF_WCS_NPIX - 0.5 || py < -0.5 || py >= WF_WCS_NPIX - 0.5)
                        continue;
                    size_t cell = (size_t)j * cov.nx + i;
                    for (int f = 0; f < p->nfilters; f++) cov.count[f * plane + cell] += n[f];
                }
        }
    }
    free(nper);
    free(where);
    if (st) {
        free(cov.count);
        return st;
    }
    for (int j = 0; j < cov.ny; j++)
        for (int i = 0; i < cov.nx; i++) {
            double xi = (h - i) * cov.pixel * DEG, eta = (j - h) * cov.pixel * DEG;
            /* Solid angle of a gnomonic cell shrinks as (1 + r^2)^(-3/2). */
            double area = cov.pixel * cov.pixel / pow(1.0 + xi * xi + eta * eta, 1.5);
            size_t cell = (size_t)j * cov.nx + i;
            for (int f = 0; f < cov.nfilters; f++) {
                int c = cov.count[f * plane + cell];
                if (c > cov.max_count[f]) cov.max_count[f] = c;
                for (int t = 0; t < WF_SURVEY_NTHRESH; t++)
                    if (c >= cov.threshold[t]) cov.area[f][t] += area;
            }
        }
    *out = cov;
    return WF_OK;
}

/* ---- overlap within a snake ------------------------------------------------------------------ */

typedef struct quad {
    double p[4][2];
    double xmin, xmax, ymin, ymax;
} quad;

static double poly_area(const double (*p)[2], int n)
{
    double a = 0;
    for (int i = 0; i < n; i++) {
        int j = (i + 1) % n;
        a += p[i][0] * p[j][1] - p[j][0] * p[i][1];
    }
    return 0.5 * a;
}

/* Area shared by two convex counter-clockwise polygons (Sutherland-Hodgman clipping). */
static double shared_area(const quad *a, const quad *b)
{
    double poly[16][2], next[16][2];
    int n = 4;
    memcpy(poly, a->p, sizeof a->p);
    for (int e = 0; e < 4 && n > 0; e++) {
        const double *p0 = b->p[e], *p1 = b->p[(e + 1) % 4];
        double ex = p1[0] - p0[0], ey = p1[1] - p0[1];
        int m = 0;
        for (int i = 0; i < n; i++) {
            const double *s = poly[i], *t = poly[(i + 1) % n];
            double ds = ex * (s[1] - p0[1]) - ey * (s[0] - p0[0]);
            double dt = ex * (t[1] - p0[1]) - ey * (t[0] - p0[0]);
            if (ds >= 0) {
                next[m][0] = s[0];
                next[m][1] = s[1];
                m++;
            }
            if ((ds >= 0) != (dt >= 0) && m < 16) {
                double r = ds / (ds - dt);
                next[m][0] = s[0] + r * (t[0] - s[0]);
                next[m][1] = s[1] + r * (t[1] - s[1]);
                m++;
            }
        }
        n = m;
        memcpy(poly, next, sizeof(double) * 2 * (size_t)n);
    }
    return n >= 3 ? fabs(poly_area((const double(*)[2])poly, n)) : 0.0;
}

static double point_segment(const double *q, const double *a, const double *b)
{
    double ex = b[0] - a[0], ey = b[1] - a[1];
    double t = ((q[0] - a[0]) * ex + (q[1] - a[1]) * ey) / (ex * ex + ey * ey);
    t = t < 0 ? 0 : t > 1 ? 1 : t;
    return hypot(q[0] - a[0] - t * ex, q[1] - a[1] - t * ey);
}

/* Distance between two disjoint convex polygons: a vertex of one to an edge of the other. */
static double gap(const quad *a, const quad *b)
{
    double d = INFINITY;
    for (int i = 0; i < 4; i++)
        for (int k = 0; k < 4; k++) {
            d = fmin(d, point_segment(a->p[i], b->p[k], b->p[(k + 1) % 4]));
            d = fmin(d, point_segment(b->p[i], a->p[k], a->p[(k + 1) % 4]));
        }
    return d;
}

wf_status wf_survey_check_overlap(const wf_survey_plan *plan, const wf_focal_plane *fp,
                                  wf_survey_overlap *out)
{
    const wf_survey_params *p = &plan->par;
    int np = plan->npointings;
    wf_survey_overlap r = {0};
    r.min_gap = INFINITY;
    r.worst_orient = -1;
    quad *q = malloc((size_t)np * WF_WCS_NSCA * sizeof *q);
    char *done = calloc((size_t)plan->norients, 1);
    if (!q || !done) {
        free(q);
        free(done);
        return wf_error(WF_ERR_NOMEM, "survey overlap: out of memory");
    }
    wf_status st = WF_OK;
    for (size_t e = 0; e < plan->nexp && !st; e++) {
        int o = plan->exp[e].orient;
        if (done[o]) continue;
        done[o] = 1;
        r.orients++;
        /* All pointings of this orient, from the first exposure of each. */
        for (int i = 0; i < np && !st; i++) {
            const wf_exposure *x = NULL;
            for (size_t k = e; k < plan->nexp && k < e + (size_t)np * p->nfilters; k++)
                if (plan->exp[k].orient == o && plan->exp[k].pointing == i) {
                    x = &plan->exp[k];
                    break;
                }
            if (!x) {
                st = wf_error(WF_ERR_INTERNAL, "survey overlap: orient %d lacks pointing %d", o, i);
                break;
            }
            double c[WF_WCS_NSCA][4][2];
            if ((st = sca_corners(fp, x->ra, x->dec, x->pa, p->ra, p->dec, c))) break;
            for (int s = 0; s < WF_WCS_NSCA; s++) {
                quad *u = &q[i * WF_WCS_NSCA + s];
                memcpy(u->p, c[s], sizeof u->p);
                if (poly_area((const double(*)[2])u->p, 4) < 0)
                    for (int k = 0; k < 2; k++) { /* make it counter-clockwise */
                        double t0 = u->p[k][0], t1 = u->p[k][1];
                        u->p[k][0] = u->p[3 - k][0];
                        u->p[k][1] = u->p[3 - k][1];
                        u->p[3 - k][0] = t0;
                        u->p[3 - k][1] = t1;
                    }
                u->xmin = fmin(fmin(u->p[0][0], u->p[1][0]), fmin(u->p[2][0], u->p[3][0]));
                u->xmax = fmax(fmax(u->p[0][0], u->p[1][0]), fmax(u->p[2][0], u->p[3][0]));
                u->ymin = fmin(fmin(u->p[0][1], u->p[1][1]), fmin(u->p[2][1], u->p[3][1]));
                u->ymax = fmax(fmax(u->p[0][1], u->p[1][1]), fmax(u->p[2][1], u->p[3][1]));
            }
        }
        if (st) break;
        const double m = GAP_SEARCH / 3600.0;
        for (int a = 0; a < np * WF_WCS_NSCA; a++)
            for (int b = a + 1; b < np * WF_WCS_NSCA; b++) {
                if (a / WF_WCS_NSCA == b / WF_WCS_NSCA) continue; /* same pointing */
                const quad *qa = &q[a], *qb = &q[b];
                if (qa->xmax + m < qb->xmin || qb->xmax + m < qa->xmin || qa->ymax + m < qb->ymin ||
                    qb->ymax + m < qa->ymin)
                    continue;
                r.pairs_checked++;
                double area = shared_area(qa, qb) * 3600.0 * 3600.0;
                if (area > OVERLAP_TOL) {
                    r.overlapping++;
                    if (area > r.max_overlap) {
                        r.max_overlap = area;
                        r.worst_orient = o;
                    }
                    r.min_gap = 0;
                } else {
                    double g = gap(qa, qb) * 3600.0;
                    if (g < r.min_gap) {
                        r.min_gap = g;
                        if (!r.overlapping) r.worst_orient = o;
                    }
                }
            }
    }
    free(q);
    free(done);
    if (st) return st;
    *out = r;
    return WF_OK;
}

/* ---- FITS products --------------------------------------------------------------------------- */

/* Shortest exact digits, but never fewer than the integer part needs: 61420, not 6.142E+04. */
static int key_digits(double v)
{
    int d = wf_fits_double_digits(v);
    int whole = fabs(v) >= 1.0 ? (int)floor(log10(fabs(v))) + 1 : 1;
    return whole > d && whole <= 17 ? whole : d;
}

static void key_d(fitsfile *f, const char *name, double v, const char *comment, int *status)
{
    fits_write_key_dbl(f, name, v, -key_digits(v), comment, status);
}

static void join_list(char *buf, size_t size, const wf_survey_params *p, int which)
{
    size_t len = 0;
    int n = which == 0 ? p->ncolumns : which == 1 ? p->nfilters : p->nexptime;
    buf[0] = '\0';
    for (int i = 0; i < n && len < size; i++) {
        if (which == 0)
            len += (size_t)snprintf(buf + len, size - len, "%s%d", i ? "," : "", p->column_count[i]);
        else if (which == 1)
            len += (size_t)snprintf(buf + len, size - len, "%s%s", i ? "," : "", p->filters[i]);
        else
            len += (size_t)snprintf(buf + len, size - len, "%s%.*G", i ? "," : "",
                                    key_digits(p->exptime[i]), p->exptime[i]);
    }
}

wf_status wf_survey_write_plan(const wf_survey_plan *plan, const wf_survey_overlap *overlap,
                               const char *path)
{
    const wf_survey_params *p = &plan->par;
    char tmp[4200], list[256];
    fitsfile *f = NULL;
    wf_status st = wf_fits_begin(path, tmp, sizeof tmp, &f);
    if (st) return st;
    int status = 0;
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_write_key_str(f, "ORIGIN", "wfisim", "survey plan (SPEC 6)", &status);
    key_d(f, "FIELDRA", p->ra, "[deg] field centre RA", &status);
    key_d(f, "FIELDDEC", p->dec, "[deg] field centre Dec", &status);
    key_d(f, "MJDSTART", p->mjd_start, "[d] start of the first visit", &status);
    fits_write_key_lng(f, "NVISITS", p->visits, "visits", &status);
    key_d(f, "VISITDT", p->visit_interval, "[d] between visit starts", &status);
    key_d(f, "ORIENTDT", p->orient_period, "[d] per orient", &status);
    key_d(f, "ORIENTST", p->orient_step, "[deg] orient turn per period", &status);
    key_d(f, "PA0", p->pa0, "[deg] first orient PA at field centre", &status);
    fits_write_key_lng(f, "NORIENTS", plan->norients, "orients used", &status);
    join_list(list, sizeof list, p, 0);
    fits_write_key_str(f, "COLUMNS", list, "pointings per column, snake order", &status);
    key_d(f, "ROWSTEP", p->row_step, "[arcmin] within a column", &status);
    key_d(f, "COLSTEP", p->column_step, "[arcmin] between columns", &status);
    key_d(f, "FPADU", plan->fpa_du, "[deg] SCA centroid from boresight, u", &status);
    key_d(f, "FPADV", plan->fpa_dv, "[deg] SCA centroid from boresight, v", &status);
    fits_write_key_lng(f, "NPOINT", plan->npointings, "pointings per snake", &status);
    join_list(list, sizeof list, p, 1);
    fits_write_key_str(f, "FILTERS", list, "filter passes of a visit", &status);
    join_list(list, sizeof list, p, 2);
    fits_write_key_str(f, "EXPTIMES", list, "[s] exposure time per filter", &status);
    key_d(f, "SLEWTIME", p->slew_time, "[s] slew + settle between pointings", &status);
    key_d(f, "FILTTIME", p->filter_change_time, "[s] filter change", &status);
    fits_write_key_lng(f, "NEXPOSUR", (long)plan->nexp, "exposures", &status);
    char src[72];
    snprintf(src, sizeof src, "%.60s", plan->fp_source);
    fits_write_key_str(f, "FPSOURCE", src, "focal plane (built-in or data dir)", &status);
    if (overlap) {
        fits_write_key_lng(f, "OVERLAPS", overlap->overlapping,
                           "SCA pairs of one snake sharing area", &status);
        key_d(f, "MINGAP", isfinite(overlap->min_gap) ? overlap->min_gap : -1,
              "[arcsec] smallest gap between pointings", &status);
    }
    fits_write_comment(f, "PA: GalSim galsim.roman.getWCS observatory position angle at the "
                       "boresight (deg E of N)", &status);
    if ((st = wf_fits_error(status, tmp, "writing the primary header"))) return wf_fits_finish(f, tmp, path, st);

    char *ttype[] = {"EXPID", "VISIT", "ORIENT", "POINTING", "PASS", "FILTER", "RA", "DEC", "PA",
                     "ORIENTPA", "MJD_START", "MJD_MID", "EXPTIME"};
    char *tform[] = {"1J", "1J", "1J", "1J", "1J", "8A", "1D", "1D", "1D", "1D", "1D", "1D", "1D"};
    char *tunit[] = {"", "", "", "", "", "", "deg", "deg", "deg", "deg", "d", "d", "s"};
    fits_create_tbl(f, BINARY_TBL, 0, 13, ttype, tform, tunit, "PLAN", &status);
    if (!status) st = wf_fits_reserve_checksum(f, tmp);
    size_t n = plan->nexp;
    int *ib = malloc(n * sizeof *ib);
    double *db = malloc(n * sizeof *db);
    char **names = malloc(n * sizeof *names);
    if (!ib || !db || !names) {
        free(ib);
        free(db);
        free(names);
        return wf_fits_finish(f, tmp, path, wf_error(WF_ERR_NOMEM, "%s: out of memory", tmp));
    }
    for (int col = 1; col <= 13 && !status && !st; col++) {
        for (size_t i = 0; i < n; i++) {
            const wf_exposure *x = &plan->exp[i];
            switch (col) {
            case 1: ib[i] = x->id; break;
            case 2: ib[i] = x->visit; break;
            case 3: ib[i] = x->orient; break;
            case 4: ib[i] = x->pointing; break;
            case 5: ib[i] = x->pass; break;
            case 6: names[i] = (char *)p->filters[x->filter]; break;
            case 7: db[i] = x->ra; break;
            case 8: db[i] = x->dec; break;
            case 9: db[i] = x->pa; break;
            case 10: db[i] = x->orient_pa; break;
            case 11: db[i] = x->mjd_start; break;
            case 12: db[i] = x->mjd_mid; break;
            default: db[i] = x->exptime; break;
            }
        }
        if (col <= 5) fits_write_col(f, TINT, col, 1, 1, (LONGLONG)n, ib, &status);
        else if (col == 6) fits_write_col(f, TSTRING, col, 1, 1, (LONGLONG)n, names, &status);
        else fits_write_col(f, TDOUBLE, col, 1, 1, (LONGLONG)n, db, &status);
    }
    free(ib);
    free(db);
    free(names);
    if (!st) st = wf_fits_error(status, tmp, "writing the PLAN table");
    if (st) return wf_fits_finish(f, tmp, path, st);

    char *pt[] = {"POINTING", "COLUMN", "DU", "DV"};
    char *pf[] = {"1J", "1J", "1D", "1D"};
    char *pu[] = {"", "", "deg", "deg"};
    fits_create_tbl(f, BINARY_TBL, 0, 4, pt, pf, pu, "POINTINGS", &status);
    fits_write_comment(f, "DU, DV: boresight offset from the field centre along the focal-plane "
                       "u, v axes (turns about v, then u)", &status);
    if (!status) st = wf_fits_reserve_checksum(f, tmp);
    for (int i = 0; i < plan->npointings && !status && !st; i++) {
        int idx = i;
        fits_write_col(f, TINT, 1, i + 1, 1, 1, &idx, &status);
        fits_write_col(f, TINT, 2, i + 1, 1, 1, (void *)&plan->column[i], &status);
        fits_write_col(f, TDOUBLE, 3, i + 1, 1, 1, (void *)&plan->du[i], &status);
        fits_write_col(f, TDOUBLE, 4, i + 1, 1, 1, (void *)&plan->dv[i], &status);
    }
    if (!st) st = wf_fits_error(status, tmp, "writing the POINTINGS table");
    return wf_fits_finish(f, tmp, path, st);
}

wf_status wf_survey_write_coverage(const wf_survey_coverage *cov, const char *path)
{
    char tmp[4200];
    fitsfile *f = NULL;
    wf_status st = wf_fits_begin(path, tmp, sizeof tmp, &f);
    if (st) return st;
    int status = 0;
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_write_key_str(f, "ORIGIN", "wfisim", "survey coverage map", &status);
    fits_write_comment(f, "one image per filter: exposures covering each cell (all 18 SCAs)",
                       &status);
    st = wf_fits_error(status, tmp, "writing the primary header");
    size_t plane = (size_t)cov->nx * cov->ny;
    for (int fi = 0; fi < cov->nfilters && !st; fi++) {
        long naxes[2] = {cov->nx, cov->ny};
        fits_create_img(f, LONG_IMG, 2, naxes, &status);
        fits_write_key_str(f, "EXTNAME", cov->filters[fi], "filter", &status);
        fits_write_key_str(f, "BUNIT", "exposures", "", &status);
        fits_write_key_str(f, "CTYPE1", "RA---TAN", "", &status);
        fits_write_key_str(f, "CTYPE2", "DEC--TAN", "", &status);
        fits_write_key_str(f, "RADESYS", "ICRS", "", &status);
        key_d(f, "CRPIX1", (cov->nx + 1) / 2.0, "", &status);
        key_d(f, "CRPIX2", (cov->ny + 1) / 2.0, "", &status);
        key_d(f, "CRVAL1", cov->ra0, "[deg] field centre", &status);
        key_d(f, "CRVAL2", cov->dec0, "[deg] field centre", &status);
        key_d(f, "CD1_1", -cov->pixel, "[deg] east to the left", &status);
        key_d(f, "CD1_2", 0.0, "", &status);
        key_d(f, "CD2_1", 0.0, "", &status);
        key_d(f, "CD2_2", cov->pixel, "", &status);
        for (int t = 0; t < WF_SURVEY_NTHRESH; t++) {
            char name[16], comment[64];
            /* The last threshold can equal one of the fixed ones; it gets its own name. */
            if (t == WF_SURVEY_NTHRESH - 1)
                snprintf(name, sizeof name, "AREAHALF");
            else
                snprintf(name, sizeof name, "AREA%d", cov->threshold[t]);
            snprintf(comment, sizeof comment, "[deg2] covered by >= %d exposures",
                     cov->threshold[t]);
            key_d(f, name, cov->area[fi][t], comment, &status);
        }
        fits_write_key_lng(f, "HALFVIS", cov->threshold[WF_SURVEY_NTHRESH - 1],
                           "exposures for AREAHALF: half the visits", &status);
        fits_write_key_lng(f, "MAXCOUNT", cov->max_count[fi], "most exposures on a cell", &status);
        if (!status) st = wf_fits_reserve_checksum(f, tmp);
        if (!st)
            fits_write_img(f, TINT, 1, (LONGLONG)plane, (void *)(cov->count + fi * plane), &status);
        if (!st) st = wf_fits_error(status, tmp, "writing a coverage image");
    }
    return wf_fits_finish(f, tmp, path, st);
}

/* ---- reading a plan back ------------------------------------------------------------------- */

static const struct {
    const char *name;
    int type;                     /* TINT, TSTRING or TDOUBLE */
    size_t off;
} plan_columns[] = {
    {"EXPID", TINT, offsetof(wf_survey_row, expid)},
    {"VISIT", TINT, offsetof(wf_survey_row, visit)},
    {"ORIENT", TINT, offsetof(wf_survey_row, orient)},
    {"POINTING", TINT, offsetof(wf_survey_row, pointing)},
    {"PASS", TINT, offsetof(wf_survey_row, pass)},
    {"FILTER", TSTRING, offsetof(wf_survey_row, filter)},
    {"RA", TDOUBLE, offsetof(wf_survey_row, ra)},
    {"DEC", TDOUBLE, offsetof(wf_survey_row, dec)},
    {"PA", TDOUBLE, offsetof(wf_survey_row, pa)},
    {"MJD_START", TDOUBLE, offsetof(wf_survey_row, mjd_start)},
    {"MJD_MID", TDOUBLE, offsetof(wf_survey_row, mjd_mid)},
    {"EXPTIME", TDOUBLE, offsetof(wf_survey_row, exptime)},
};
#define PLAN_NCOLS (sizeof plan_columns / sizeof *plan_columns)
#define PLAN_HDUS 3               /* wf_survey_write_plan: primary, PLAN, POINTINGS */
#define FILTER_READ_MAX 31        /* widest FILTER column read (the text is then cut to 15) */

static wf_status read_plan_close(fitsfile *f, wf_survey_row *rows, wf_status st)
{
    int cs = 0;
    fits_close_file(f, &cs);
    fits_clear_errmsg();
    if (st) free(rows);
    return st;
}

wf_status wf_survey_read_plan(const char *path, wf_survey_row **rows, size_t *n)
{
    *rows = NULL;
    *n = 0;
    wf_status hst = wf_fits_check_headers(path);
    if (hst) return hst;
    if (wf_fits_verify_checksums(path, PLAN_HDUS)) {
        char why[1024]; /* copied: wf_error rewrites the buffer wf_error_message points to */
        const char *m = wf_error_message();
        size_t len = strlen(path);
        if (!strncmp(m, path, len) && !strncmp(m + len, ": ", 2)) m += len + 2; /* path said once */
        snprintf(why, sizeof why, "%s", m);
        return wf_error(WF_ERR_INPUT, "%s: not a plan whose checksums verify (write one with `wfisim survey plan`): %s",
                        path, why);
    }
    fitsfile *f;
    int status = 0;
    if (fits_open_diskfile(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening");
    if (fits_movnam_hdu(f, BINARY_TBL, "PLAN", 0, &status))
        return read_plan_close(f, NULL, wf_error(WF_ERR_INPUT, "%s: no PLAN table", path));
    int col[PLAN_NCOLS];
    for (size_t c = 0; c < PLAN_NCOLS; c++) {
        if (fits_get_colnum(f, CASEINSEN, (char *)plan_columns[c].name, &col[c], &status))
            return read_plan_close(f, NULL, wf_error(WF_ERR_INPUT, "%s: PLAN table has no column %s", path,
                                                     plan_columns[c].name));
        int type = 0;
        long repeat = 0;
        if (plan_columns[c].type == TSTRING &&
            (fits_get_coltype(f, col[c], &type, &repeat, NULL, &status) || type != TSTRING || repeat > FILTER_READ_MAX))
            return read_plan_close(f, NULL, wf_error(WF_ERR_INPUT, "%s: PLAN column %s is not text of at most %d "
                                                     "characters", path, plan_columns[c].name, FILTER_READ_MAX));
    }
    long nrows = 0;
    fits_get_num_rows(f, &nrows, &status);
    wf_survey_row *out = calloc((size_t)(nrows > 0 ? nrows : 1), sizeof *out);
    if (!out) return read_plan_close(f, NULL, wf_error(WF_ERR_NOMEM, "%s: %ld plan rows", path, nrows));
    for (long r = 1; r <= nrows && !status; r++) {
        wf_survey_row *x = &out[r - 1];
        for (size_t c = 0; c < PLAN_NCOLS && !status; c++) {
            void *dst = (char *)x + plan_columns[c].off;
            if (plan_columns[c].type == TSTRING) {
                char text[FILTER_READ_MAX + 1] = "", *tp = text;
                fits_read_col(f, TSTRING, col[c], r, 1, 1, NULL, &tp, NULL, &status);
                snprintf(x->filter, sizeof x->filter, "%s", text);
                continue;
            }
            fits_read_col(f, plan_columns[c].type, col[c], r, 1, 1, NULL, dst, NULL, &status);
            if (!status && plan_columns[c].type == TDOUBLE && !isfinite(*(double *)dst))
                return read_plan_close(f, out, wf_error(WF_ERR_INPUT, "%s: PLAN row %ld column %s is not finite",
                                                        path, r, plan_columns[c].name));
        }
    }
    if (status) return read_plan_close(f, out, wf_fits_error(status, path, "reading the PLAN table"));
    read_plan_close(f, out, WF_OK);
    *rows = out;
    *n = (size_t)nrows;
    return WF_OK;
}
