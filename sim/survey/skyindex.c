#include "sim/survey/skyindex.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define DEG (M_PI / 180.0)
#define ARCSEC (DEG / 3600.0)
/* Slack added to every culling bound (rad, ~0.02"): far above the rounding of the bounds
 * themselves, so culling never drops an object the exact test would accept. */
#define PAD 1e-7

struct wf_skyindex {
    size_t n;
    double band_deg;
    int nband;
    uint32_t *start; /* nband + 1 offsets into idx/ra/dec */
    uint32_t *idx;   /* original index, ordered by (band, ra, index) */
    double *ra, *dec;
};

static void unit_vec(double ra_deg, double dec_deg, double p[3])
{
    double a = ra_deg * DEG, d = dec_deg * DEG;
    double cd = cos(d);
    p[0] = cd * cos(a);
    p[1] = cd * sin(a);
    p[2] = sin(d);
}

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void cross3(const double a[3], const double b[3], double c[3])
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

static double chord2(const double a[3], const double b[3])
{
    double dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
    return dx * dx + dy * dy + dz * dz;
}

/* Squared chord of an angle: accurate for small angles, unlike 2 - 2 cos. */
static double chord2_of(double angle)
{
    if (angle >= M_PI) return INFINITY;
    double s = 2.0 * sin(0.5 * angle);
    return s * s;
}

static double angle_between(const double a[3], const double b[3])
{
    double c[3];
    cross3(a, b, c);
    return atan2(sqrt(dot3(c, c)), dot3(a, b));
}

static void to_radec(const double p[3], double *ra_deg, double *dec_deg)
{
    double ra = atan2(p[1], p[0]) / DEG;
    if (ra < 0.0) ra += 360.0;
    if (ra >= 360.0) ra -= 360.0;
    *ra_deg = ra;
    *dec_deg = atan2(p[2], hypot(p[0], p[1])) / DEG;
}

static int bad_position(double ra, double dec)
{
    return !isfinite(ra) || !isfinite(dec) || dec < -90.0 || dec > 90.0;
}

wf_status wf_skyindex_circle(double ra_deg, double dec_deg, double radius_deg,
                             double margin_arcsec, wf_skyregion *out)
{
    memset(out, 0, sizeof *out);
    if (bad_position(ra_deg, dec_deg))
        return wf_error(WF_ERR_RANGE, "sky circle: centre (%g, %g) is not a sky position", ra_deg,
                        dec_deg);
    if (!(radius_deg >= 0.0) || !isfinite(radius_deg) || !(margin_arcsec >= 0.0) ||
        !isfinite(margin_arcsec))
        return wf_error(WF_ERR_RANGE, "sky circle: radius %g deg and margin %g arcsec must be >= 0",
                        radius_deg, margin_arcsec);
    unit_vec(ra_deg, dec_deg, out->centre);
    to_radec(out->centre, &out->ra_c, &out->dec_c);
    out->radius = radius_deg * DEG;
    out->margin = margin_arcsec * ARCSEC;
    out->bound = out->radius + out->margin;
    out->chord2_circle = chord2_of(out->bound);
    out->chord2_bound = out->chord2_circle;
    return WF_OK;
}

wf_status wf_skyindex_polygon(const double *ra_deg, const double *dec_deg, int n,
                              double margin_arcsec, wf_skyregion *out)
{
    memset(out, 0, sizeof *out);
    if (n < 3 || n > WF_SKY_MAXVERT)
        return wf_error(WF_ERR_INPUT, "sky polygon: %d vertices (3 to %d)", n, WF_SKY_MAXVERT);
    if (!(margin_arcsec >= 0.0) || !(margin_arcsec < 90.0 * 3600.0))
        return wf_error(WF_ERR_RANGE, "sky polygon: margin %g arcsec outside [0, 90 deg)",
                        margin_arcsec);
    for (int i = 0; i < n; i++) {
        if (bad_position(ra_deg[i], dec_deg[i]))
            return wf_error(WF_ERR_RANGE, "sky polygon: vertex %d (%g, %g) is not a sky position",
                            i, ra_deg[i], dec_deg[i]);
        unit_vec(ra_deg[i], dec_deg[i], out->v[i]);
    }
    out->nvert = n;
    for (int i = 0; i < n; i++)
        if (chord2(out->v[i], out->v[(i + 1) % n]) < 1e-24)
            return wf_error(WF_ERR_INPUT, "sky polygon: vertices %d and %d coincide", i,
                            (i + 1) % n);
    /* Orient counter-clockwise (interior on the positive side of every edge normal): the
     * vertex sum lies inside a convex polygon smaller than a hemisphere. */
    double sum[3] = {0, 0, 0};
    for (int i = 0; i < n; i++)
        for (int k = 0; k < 3; k++) sum[k] += out->v[i][k];
    double len = sqrt(dot3(sum, sum));
    if (!(len > 1e-9))
        return wf_error(WF_ERR_INPUT, "sky polygon: vertices span a hemisphere or more");
    for (int k = 0; k < 3; k++) out->centre[k] = sum[k] / len;
    double c01[3];
    cross3(out->v[0], out->v[1], c01);
    if (dot3(c01, out->centre) < 0.0)
        for (int i = 0; i < n / 2; i++)
            for (int k = 0; k < 3; k++) {
                double t = out->v[i][k];
                out->v[i][k] = out->v[n - 1 - i][k];
                out->v[n - 1 - i][k] = t;
            }
    double tol[WF_SKY_MAXVERT];
    for (int i = 0; i < n; i++) {
        double c[3];
        cross3(out->v[i], out->v[(i + 1) % n], c);
        double l = sqrt(dot3(c, c));
        for (int k = 0; k < 3; k++) out->nrm[i][k] = c[k] / l;
        /* the cross product of unit vectors carries ~eps of rounding whatever its length l
         * (the sine of the edge), so the normal carries ~eps / l: 1e-11 rad for the 1.8"
         * short edge of a 16-row sub-array */
        tol[i] = 1e-12 + 16.0 * DBL_EPSILON / l;
    }
    /* Convex and simple: every vertex on the inner side of every edge (the tolerance lets
     * collinear vertices of a rectangle's edge pass). */
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++)
            if (dot3(out->nrm[i], out->v[j]) < -tol[i])
                return wf_error(WF_ERR_INPUT,
                                "sky polygon: not convex (vertex %d lies outside edge %d-%d)", j,
                                i, (i + 1) % n);
    double rmax = 0.0;
    for (int i = 0; i < n; i++) {
        double a = angle_between(out->centre, out->v[i]);
        if (a > rmax) rmax = a;
    }
    if (!(rmax < 0.5 * M_PI))
        return wf_error(WF_ERR_INPUT, "sky polygon: larger than a hemisphere");
    to_radec(out->centre, &out->ra_c, &out->dec_c);
    out->margin = margin_arcsec * ARCSEC;
    out->bound = rmax + out->margin;
    out->chord2_bound = chord2_of(out->bound + 1e-9);
    out->chord2_margin = chord2_of(out->margin);
    out->sin_margin = sin(out->margin);
    return WF_OK;
}

int wf_skyindex_contains(const wf_skyregion *reg, double ra_deg, double dec_deg)
{
    double p[3];
    unit_vec(ra_deg, dec_deg, p);
    if (reg->nvert == 0) return chord2(p, reg->centre) <= reg->chord2_circle;
    int inside = 1;
    for (int i = 0; i < reg->nvert && inside; i++) inside = dot3(reg->nrm[i], p) >= 0.0;
    if (inside) return 1;
    if (reg->margin <= 0.0 || chord2(p, reg->centre) > reg->chord2_bound) return 0;
    /* Outside: within the margin of the nearest boundary point, which is either the foot of
     * the perpendicular on an edge the point lies beyond, or a vertex. */
    for (int i = 0; i < reg->nvert; i++) {
        const double *a = reg->v[i], *b = reg->v[(i + 1) % reg->nvert], *nr = reg->nrm[i];
        double s = dot3(nr, p);
        if (s < 0.0 && -s <= reg->sin_margin) {
            double ca[3], cb[3];
            cross3(a, p, ca);
            cross3(p, b, cb);
            if (dot3(ca, nr) >= 0.0 && dot3(cb, nr) >= 0.0) return 1;
        }
        if (chord2(p, a) <= reg->chord2_margin) return 1;
    }
    return 0;
}

/* ------------------------------------------------------------------ index */

typedef struct sort_key {
    double ra;
    uint32_t i;
} sort_key;

static int cmp_key(const void *pa, const void *pb)
{
    const sort_key *a = pa, *b = pb;
    if (a->ra != b->ra) return a->ra < b->ra ? -1 : 1;
    return (a->i > b->i) - (a->i < b->i);
}

static int band_of(const wf_skyindex *ix, double dec)
{
    double f = floor((dec + 90.0) / ix->band_deg);
    if (f < 0.0) return 0;
    if (f >= (double)ix->nband) return ix->nband - 1;
    return (int)f;
}

void wf_skyindex_free(wf_skyindex *ix)
{
    if (!ix) return;
    free(ix->start);
    free(ix->idx);
    free(ix->ra);
    free(ix->dec);
    free(ix);
}

wf_status wf_skyindex_build(const double *ra_deg, const double *dec_deg, size_t n,
                            double band_arcmin, wf_skyindex **out)
{
    *out = NULL;
    if (band_arcmin == 0.0) band_arcmin = 1.0;
    if (!(band_arcmin >= 0.01 && band_arcmin <= 600.0))
        return wf_error(WF_ERR_RANGE, "sky index: band height %g arcmin outside [0.01, 600]",
                        band_arcmin);
    if (n >= UINT32_MAX)
        return wf_error(WF_ERR_RANGE, "sky index: %zu objects (at most %u)", n,
                        (unsigned)UINT32_MAX - 1);
    for (size_t i = 0; i < n; i++)
        if (bad_position(ra_deg[i], dec_deg[i]) || ra_deg[i] < 0.0 || ra_deg[i] >= 360.0)
            return wf_error(WF_ERR_RANGE,
                            "sky index: object %zu at (%g, %g): need ra in [0, 360), dec in "
                            "[-90, 90]",
                            i, ra_deg[i], dec_deg[i]);
    wf_skyindex *ix = calloc(1, sizeof *ix);
    if (!ix) return wf_error(WF_ERR_NOMEM, "sky index: no memory");
    ix->n = n;
    ix->band_deg = band_arcmin / 60.0;
    ix->nband = (int)ceil(180.0 / ix->band_deg);
    size_t m = n ? n : 1;
    ix->start = calloc((size_t)ix->nband + 1, sizeof *ix->start);
    ix->idx = malloc(m * sizeof *ix->idx);
    ix->ra = malloc(m * sizeof *ix->ra);
    ix->dec = malloc(m * sizeof *ix->dec);
    sort_key *keys = malloc(m * sizeof *keys);
    uint32_t *fill = calloc((size_t)ix->nband, sizeof *fill);
    if (!ix->start || !ix->idx || !ix->ra || !ix->dec || !keys || !fill) {
        free(keys);
        free(fill);
        wf_skyindex_free(ix);
        return wf_error(WF_ERR_NOMEM, "sky index: no memory for %zu objects", n);
    }
    /* Counting sort by band (stable, so ascending index within a band), then RA. */
    for (size_t i = 0; i < n; i++) ix->start[band_of(ix, dec_deg[i]) + 1]++;
    for (int b = 0; b < ix->nband; b++) ix->start[b + 1] += ix->start[b];
    for (size_t i = 0; i < n; i++) {
        int b = band_of(ix, dec_deg[i]);
        keys[ix->start[b] + fill[b]++] = (sort_key){ra_deg[i], (uint32_t)i};
    }
    for (int b = 0; b < ix->nband; b++) {
        size_t cnt = ix->start[b + 1] - ix->start[b];
        if (cnt > 1) qsort(keys + ix->start[b], cnt, sizeof *keys, cmp_key);
    }
    for (size_t k = 0; k < n; k++) {
        ix->idx[k] = keys[k].i;
        ix->ra[k] = keys[k].ra;
        ix->dec[k] = dec_deg[keys[k].i];
    }
    free(keys);
    free(fill);
    *out = ix;
    return WF_OK;
}

static int push_sel(wf_selection *sel, uint32_t i)
{
    if (sel->n == sel->cap) {
        size_t cap = sel->cap ? 2 * sel->cap : 4096;
        uint32_t *q = realloc(sel->idx, cap * sizeof *q);
        if (!q) return 0;
        sel->idx = q;
        sel->cap = cap;
    }
    sel->idx[sel->n++] = i;
    return 1;
}

/* Tests objects [k0, k1) of the sorted arrays. */
static int scan(const wf_skyindex *ix, const wf_skyregion *reg, size_t k0, size_t k1,
                wf_selection *sel)
{
    sel->examined += k1 - k0;
    for (size_t k = k0; k < k1; k++)
        if (wf_skyindex_contains(reg, ix->ra[k], ix->dec[k]) && !push_sel(sel, ix->idx[k]))
            return 0;
    return 1;
}

/* Objects of [s, e) with lo <= ra <= hi. */
static int scan_ra(const wf_skyindex *ix, const wf_skyregion *reg, size_t s, size_t e,
                   double lo, double hi, wf_selection *sel)
{
    size_t a = s, b = e;
    while (a < b) {
        size_t mid = a + (b - a) / 2;
        if (ix->ra[mid] < lo)
            a = mid + 1;
        else
            b = mid;
    }
    size_t k1 = a;
    while (k1 < e && ix->ra[k1] <= hi) k1++;
    return scan(ix, reg, a, k1, sel);
}

static int cmp_u32(const void *pa, const void *pb)
{
    uint32_t a = *(const uint32_t *)pa, b = *(const uint32_t *)pb;
    return (a > b) - (a < b);
}

wf_status wf_skyindex_select(const wf_skyindex *ix, const wf_skyregion *reg, wf_selection *sel)
{
    sel->n = 0;
    sel->examined = 0;
    double R = reg->bound + PAD;
    int ok = 1;
    if (R >= 0.5 * M_PI) {
        /* Large regions: the per-band RA bound below assumes R < 90 deg; scan the bands. */
        double dlo = reg->dec_c - R / DEG, dhi = reg->dec_c + R / DEG;
        int b0 = band_of(ix, dlo < -90.0 ? -90.0 : dlo), b1 = band_of(ix, dhi > 90.0 ? 90.0 : dhi);
        ok = scan(ix, reg, ix->start[b0], ix->start[b1 + 1], sel);
    } else {
        double dc = reg->dec_c, ac = reg->ra_c;
        double sdc = sin(dc * DEG), cdc = cos(dc * DEG), cR = cos(R);
        double dlo = dc - R / DEG, dhi = dc + R / DEG;
        if (dlo < -90.0) dlo = -90.0;
        if (dhi > 90.0) dhi = 90.0;
        int b0 = band_of(ix, dlo), b1 = band_of(ix, dhi);
        double sstar = sdc / cR;
        double dstar = fabs(sstar) < 1.0 ? asin(sstar) / DEG : NAN;
        for (int b = b0; b <= b1 && ok; b++) {
            size_t s = ix->start[b], e = ix->start[b + 1];
            if (s == e) continue;
            double lo = -90.0 + b * ix->band_deg - 1e-9, hi = -90.0 + (b + 1) * ix->band_deg + 1e-9;
            if (lo < dlo) lo = dlo;
            if (hi > dhi) hi = dhi;
            int full = lo <= -90.0 + 1e-9 || hi >= 90.0 - 1e-9 || cdc < 1e-12;
            double half = 0.0;
            if (!full) {
                /* At declination d the circle spans |dRA| <= acos(C(d)); C is smallest at the
                 * band edges or where the circle is widest, sin d* = sin dc / cos R. */
                double cmin = INFINITY;
                double ds[3] = {lo, hi, dstar};
                for (int k = 0; k < 3; k++) {
                    double d = ds[k];
                    if (k == 2 && !(d >= lo && d <= hi)) continue;
                    double c = (cR - sin(d * DEG) * sdc) / (cos(d * DEG) * cdc);
                    if (c < cmin) cmin = c;
                }
                if (cmin > 1.0) continue;
                if (cmin <= -1.0) {
                    full = 1;
                } else {
                    half = (acos(cmin) + PAD) / DEG;
                    full = half >= 180.0;
                }
            }
            if (full) {
                ok = scan(ix, reg, s, e, sel);
            } else {
                double rlo = ac - half, rhi = ac + half;
                if (rlo < 0.0)
                    ok = scan_ra(ix, reg, s, e, rlo + 360.0, 360.0, sel) &&
                         scan_ra(ix, reg, s, e, 0.0, rhi, sel);
                else if (rhi >= 360.0)
                    ok = scan_ra(ix, reg, s, e, rlo, 360.0, sel) &&
                         scan_ra(ix, reg, s, e, 0.0, rhi - 360.0, sel);
                else
                    ok = scan_ra(ix, reg, s, e, rlo, rhi, sel);
            }
        }
    }
    if (!ok) return wf_error(WF_ERR_NOMEM, "sky index: no memory for the selection");
    if (sel->n > 1) qsort(sel->idx, sel->n, sizeof *sel->idx, cmp_u32);
    return WF_OK;
}

void wf_skyindex_selection_free(wf_selection *sel)
{
    if (!sel) return;
    free(sel->idx);
    memset(sel, 0, sizeof *sel);
}
