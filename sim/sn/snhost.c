#include "sim/sn/snhost.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sim/draw/profile.h"
#include "sim/survey/wcs.h"

/* ------------------------------------------------------------------ configuration */

void wf_snhost_config_default(wf_snhost_config *cfg)
{
    cfg->dztol[0] = 0.01;
    cfg->dztol[1] = 0.0;
    cfg->dztol[2] = 0.0;
    cfg->fmax = 0.99;
    cfg->ssnr_norm = 1.12e-7;
    cfg->ssnr_slope = 0.586;
    cfg->ssfr_min = 1.01e-11;
    cfg->ssfr_max = 1.04e-9;
}

wf_status wf_snhost_config_check(const wf_snhost_config *cfg)
{
    if (!cfg) return WF_OK;
    for (int k = 0; k < 3; k++)
        if (!isfinite(cfg->dztol[k]))
            return wf_error(WF_ERR_RANGE, "snhost: dztol[%d] = %g is not finite", k, cfg->dztol[k]);
    if (!(cfg->fmax >= 0.0 && cfg->fmax < 1.0))
        return wf_error(WF_ERR_RANGE, "snhost: fmax = %g outside [0, 1)", cfg->fmax);
    if (!(cfg->ssnr_norm > 0.0 && isfinite(cfg->ssnr_norm)))
        return wf_error(WF_ERR_RANGE, "snhost: ssnr_norm = %g must be positive", cfg->ssnr_norm);
    if (!isfinite(cfg->ssnr_slope))
        return wf_error(WF_ERR_RANGE, "snhost: ssnr_slope = %g is not finite", cfg->ssnr_slope);
    if (!(cfg->ssfr_min > 0.0 && cfg->ssfr_max >= cfg->ssfr_min && isfinite(cfg->ssfr_max)))
        return wf_error(WF_ERR_RANGE, "snhost: sSFR clamp [%g, %g] must satisfy 0 < min <= max",
                        cfg->ssfr_min, cfg->ssfr_max);
    return WF_OK;
}

static const wf_snhost_config *config_or_default(const wf_snhost_config *cfg,
                                                 wf_snhost_config *store)
{
    if (cfg) return cfg;
    wf_snhost_config_default(store);
    return store;
}

/* ------------------------------------------------------------------ weights */

/* In log10 so that a 1e12 M☉ galaxy and a dwarf keep full relative precision. */
static double log10_weight(const wf_snhost_config *c, double logmass, double logsfr)
{
    double lo = log10(c->ssfr_min), hi = log10(c->ssfr_max);
    double lssfr = logsfr - logmass;
    if (lssfr < lo) lssfr = lo;
    if (lssfr > hi) lssfr = hi;
    return log10(c->ssnr_norm) + c->ssnr_slope * lssfr + logmass;
}

wf_status wf_snhost_weight(const wf_snhost_config *cfg, double logmass, double logsfr,
                           double *weight)
{
    wf_snhost_config def;
    const wf_snhost_config *c = config_or_default(cfg, &def);
    wf_status st = wf_snhost_config_check(c);
    if (st) return st;
    if (!isfinite(logmass) || !isfinite(logsfr))
        return wf_error(WF_ERR_INPUT, "snhost: weight of logmass %g, logsfr %g: not finite", logmass,
                        logsfr);
    *weight = pow(10.0, log10_weight(c, logmass, logsfr));
    return WF_OK;
}

/* ------------------------------------------------------------------ index */

struct wf_snhost_index {
    wf_snhost_config cfg;
    size_t n;
    double *z;     /* ascending */
    uint32_t *row; /* catalog row of each sorted entry */
    double *cum;   /* n + 1 prefix sums of the weights in z order, cum[0] = 0 */
};

typedef struct zrow {
    double z;
    uint32_t row;
} zrow;

static int cmp_zrow(const void *pa, const void *pb)
{
    const zrow *a = pa, *b = pb;
    if (a->z < b->z) return -1;
    if (a->z > b->z) return 1;
    return (a->row > b->row) - (a->row < b->row);
}

void wf_snhost_index_free(wf_snhost_index *idx)
{
    if (!idx) return;
    free(idx->z);
    free(idx->row);
    free(idx->cum);
    free(idx);
}

wf_status wf_snhost_index_build(const wf_catalog *gal, const wf_snhost_config *cfg,
                                wf_snhost_index **out)
{
    *out = NULL;
    wf_snhost_config def;
    const wf_snhost_config *c = config_or_default(cfg, &def);
    wf_status st = wf_snhost_config_check(c);
    if (st) return st;
    if (gal->kind != WF_CATALOG_GALAXY)
        return wf_error(WF_ERR_INPUT, "snhost: catalog '%s' holds stars, not galaxies", gal->source);
    if (!gal->has_z)
        return wf_error(WF_ERR_INPUT,
                        "snhost: galaxy catalog '%s' has no column 'z': hosts are chosen by "
                        "redshift",
                        gal->source);
    if (!gal->has_logmass || !gal->has_logsfr)
        return wf_error(WF_ERR_INPUT,
                        "snhost: galaxy catalog '%s' has no column '%s': host weights need log "
                        "stellar mass and log SFR (run with hostless supernovae only instead)",
                        gal->source, !gal->has_logmass ? "logmass" : "logsfr");
    if (gal->n >= UINT32_MAX)
        return wf_error(WF_ERR_RANGE, "snhost: catalog '%s': %zu galaxies (at most %u)", gal->source,
                        gal->n, UINT32_MAX - 1);
    wf_snhost_index *idx = calloc(1, sizeof *idx);
    zrow *zr = malloc((gal->n ? gal->n : 1) * sizeof *zr);
    if (idx) {
        idx->cfg = *c;
        idx->n = gal->n;
        idx->z = malloc((gal->n ? gal->n : 1) * sizeof *idx->z);
        idx->row = malloc((gal->n ? gal->n : 1) * sizeof *idx->row);
        idx->cum = malloc((gal->n + 1) * sizeof *idx->cum);
    }
    if (!idx || !zr || !idx->z || !idx->row || !idx->cum) {
        free(zr);
        wf_snhost_index_free(idx);
        return wf_error(WF_ERR_NOMEM, "snhost: no memory to index %zu galaxies", gal->n);
    }
    for (size_t i = 0; i < gal->n; i++) {
        if (!isfinite(gal->z[i]) || !isfinite(gal->logmass[i]) || !isfinite(gal->logsfr[i])) {
            free(zr);
            wf_snhost_index_free(idx);
            return wf_error(WF_ERR_INPUT,
                            "snhost: catalog '%s' row %zu (id %lld): z %g, logmass %g, logsfr %g "
                            "must be finite",
                            gal->source, i + 1, (long long)gal->id[i], (double)gal->z[i],
                            (double)gal->logmass[i], (double)gal->logsfr[i]);
        }
        zr[i].z = gal->z[i];
        zr[i].row = (uint32_t)i;
    }
    qsort(zr, gal->n, sizeof *zr, cmp_zrow);
    /* Neumaier-compensated running sum: each stored prefix is the correctly rounded sum, so
     * the weight of a narrow z window (a difference of two prefixes) keeps its precision. */
    double s = 0.0, comp = 0.0;
    idx->cum[0] = 0.0;
    for (size_t k = 0; k < gal->n; k++) {
        uint32_t i = zr[k].row;
        idx->z[k] = zr[k].z;
        idx->row[k] = i;
        double w = pow(10.0, log10_weight(c, gal->logmass[i], gal->logsfr[i]));
        double t = s + w;
        comp += fabs(s) >= fabs(w) ? (s - t) + w : (w - t) + s;
        s = t;
        idx->cum[k + 1] = s + comp;
    }
    free(zr);
    *out = idx;
    return WF_OK;
}

/* First k in [lo, hi) with a[k] > x (strict) or >= x, else hi. */
static size_t search(const double *a, size_t lo, size_t hi, double x, int strict)
{
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        int right = strict ? a[mid] <= x : a[mid] < x;
        if (right)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

wf_status wf_snhost_choose(const wf_snhost_index *idx, double z_sn, double u, long *row,
                           long *ncand)
{
    *row = -1;
    *ncand = 0;
    if (!isfinite(z_sn)) return wf_error(WF_ERR_RANGE, "snhost: SN redshift %g is not finite", z_sn);
    if (!(u >= 0.0 && u <= 1.0)) return wf_error(WF_ERR_RANGE, "snhost: u = %g outside [0, 1]", u);
    const double *a = idx->cfg.dztol;
    double dz = a[0] + z_sn * (a[1] + z_sn * a[2]);
    if (dz < 0.0) dz = 0.0;
    size_t lo = search(idx->z, 0, idx->n, z_sn - dz, 0);
    size_t hi = search(idx->z, lo, idx->n, z_sn + dz, 1);
    *ncand = (long)(hi - lo);
    if (hi == lo) return WF_OK;
    double t = idx->cum[lo] + u * (idx->cum[hi] - idx->cum[lo]);
    /* the entry k whose interval [cum[k], cum[k+1]) holds t; u = 1 or rounding past the
     * window's end falls on the last candidate */
    size_t j = search(idx->cum, lo + 1, hi + 1, t, 1);
    size_t k = j > hi ? hi - 1 : j - 1;
    if (k < lo) k = lo;
    *row = (long)idx->row[k];
    return WF_OK;
}

/* ------------------------------------------------------------------ Sérsic profiles */

/* The Sérsic orders of the host model are n = 1 (disk) and 4 (bulge): the integer-order P and
 * b_n of the profile code (sim/draw/profile.h) serve; only the inverse is needed here. */
static double gamma_p(double a, double x) { return wf_gamma_p_int((int)a, x); }

/* dP/dx */
static double gamma_density(double a, double x)
{
    return x > 0.0 ? exp(-x + (a - 1.0) * log(x) - lgamma(a)) : (a == 1.0 ? 1.0 : 0.0);
}

/* y with P(a, y) = f, 0 < f < 1: Newton steps kept inside a bracket that every step
 * narrows (bisection when a step would leave it), from the Wilson–Hilferty start. */
static double gamma_p_inverse(double a, double f)
{
    double zq = wf_norm_ppf(f), c = 1.0 / (9.0 * a);
    double y = a * pow(1.0 - c + zq * sqrt(c), 3.0);
    double small = exp((log(f) + lgamma(a + 1.0)) / a); /* P ≈ y^a / Γ(a + 1) near 0 */
    if (!(y > 0.0) || f < 1e-3) y = small;
    double lo = 0.0, hi = INFINITY;
    for (int it = 0; it < 400; it++) {
        double p = gamma_p(a, y);
        double r = p - f;
        if (r == 0.0) break;
        if (r < 0.0)
            lo = y;
        else
            hi = y;
        double dens = gamma_density(a, y);
        double next = dens > 0.0 ? y - r / dens : NAN;
        if (!(next > lo && next < hi)) next = isinf(hi) ? (lo > 0.0 ? 2.0 * lo : 1.0) : 0.5 * (lo + hi);
        if (fabs(next - y) <= 1e-15 * y || (isfinite(hi) && hi - lo <= 1e-15 * hi)) {
            y = next;
            break;
        }
        y = next;
    }
    return y;
}

static double sersic_bn(double n) { return wf_sersic_b((int)n); }

static wf_status check_n(double n)
{
    if (!(n >= 1.0 && n <= 20.0) || n != floor(n))
        return wf_error(WF_ERR_RANGE, "snhost: Sérsic index %g is not a whole number in [1, 20]", n);
    return WF_OK;
}

wf_status wf_snhost_sersic_bn(double n, double *bn)
{
    wf_status st = check_n(n);
    if (st) return st;
    *bn = sersic_bn(n);
    return WF_OK;
}

wf_status wf_snhost_sersic_enclosed(double n, double x, double *frac)
{
    wf_status st = check_n(n);
    if (st) return st;
    if (!(x >= 0.0)) return wf_error(WF_ERR_RANGE, "snhost: radius %g / r_e is negative", x);
    *frac = isinf(x) ? 1.0 : gamma_p(2.0 * n, sersic_bn(n) * pow(x, 1.0 / n));
    return WF_OK;
}

wf_status wf_snhost_sersic_radius(double n, double frac, double *x)
{
    wf_status st = check_n(n);
    if (st) return st;
    if (!(frac >= 0.0 && frac < 1.0))
        return wf_error(WF_ERR_RANGE, "snhost: enclosed fraction %g outside [0, 1)", frac);
    if (frac == 0.0) {
        *x = 0.0;
        return WF_OK;
    }
    *x = pow(gamma_p_inverse(2.0 * n, frac) / sersic_bn(n), n);
    return WF_OK;
}

/* ------------------------------------------------------------------ placement */

wf_status wf_snhost_semimajor(const wf_catalog *gal, size_t row, double *a)
{
    *a = NAN;
    if (gal->kind != WF_CATALOG_GALAXY)
        return wf_error(WF_ERR_INPUT, "snhost: catalog '%s' holds stars, not galaxies", gal->source);
    if (row >= gal->n)
        return wf_error(WF_ERR_RANGE, "snhost: host row %zu beyond the %zu rows of '%s'", row, gal->n, gal->source);
    double re = gal->bulge_frac[row] > 0.5 ? gal->hlr_bulge[row] : gal->hlr_disk[row], g1, g2;
    wf_status st = wf_profile_shear_from_distortion(gal->e1[row], gal->e2[row], &g1, &g2);
    if (st) return st;
    double g = hypot(g1, g2);
    *a = re * sqrt((1.0 + g) / (1.0 - g));
    return WF_OK;
}

wf_status wf_snhost_place_at(const wf_catalog *gal, size_t row, int component, double frac,
                             double phi, wf_snhost_position *out)
{
    memset(out, 0, sizeof *out);
    if (gal->kind != WF_CATALOG_GALAXY)
        return wf_error(WF_ERR_INPUT, "snhost: catalog '%s' holds stars, not galaxies", gal->source);
    if (row >= gal->n)
        return wf_error(WF_ERR_RANGE, "snhost: host row %zu beyond the %zu rows of '%s'", row, gal->n,
                        gal->source);
    if (component != 0 && component != 1)
        return wf_error(WF_ERR_RANGE, "snhost: component %d (0 disk, 1 bulge)", component);
    if (!isfinite(phi)) return wf_error(WF_ERR_RANGE, "snhost: angle %g is not finite", phi);
    double re = component ? gal->hlr_bulge[row] : gal->hlr_disk[row];
    if (!(re > 0.0))
        return wf_error(WF_ERR_RANGE, "snhost: '%s' row %zu (id %lld): %s half-light radius %g",
                        gal->source, row + 1, (long long)gal->id[row], component ? "bulge" : "disk",
                        re);
    double x;
    wf_status st = wf_snhost_sersic_radius(component ? 4.0 : 1.0, frac, &x);
    if (st) return st;
    double g1, g2;
    if ((st = wf_profile_shear_from_distortion(gal->e1[row], gal->e2[row], &g1, &g2))) return st;
    double r = x * re;
    /* round frame -> shear (GalSim's area-preserving matrix for reduced shear g) -> rotation
     * by pa counter-clockwise: the transform sim/draw/scene.c gives the renderer */
    double px = r * cos(phi), py = r * sin(phi);
    double norm = 1.0 / sqrt(1.0 - g1 * g1 - g2 * g2);
    double sx = norm * ((1.0 + g1) * px + g2 * py);
    double sy = norm * (g2 * px + (1.0 - g1) * py);
    double th = gal->pa[row] * (M_PI / 180.0), cs = cos(th), sn = sin(th);
    double du = cs * sx - sn * sy, dv = sn * sx + cs * sy;
    double xi = -du / 206264.80624709636, eta = dv / 206264.80624709636; /* east, north, rad */
    double ra, dec;
    wf_wcs_tangent_deproject(gal->ra[row] * (M_PI / 180.0), gal->dec[row] * (M_PI / 180.0), xi, eta, &ra, &dec);
    ra *= 180.0 / M_PI;
    if (ra < 0.0) ra += 360.0;
    if (ra >= 360.0) ra -= 360.0;
    out->ra = ra;
    out->dec = dec * (180.0 / M_PI);
    out->d_east = -du;
    out->d_north = dv;
    out->offset = hypot(du, dv);
    out->component = component;
    out->frac = frac;
    out->r_circ = r;
    out->phi = phi;
    return WF_OK;
}

wf_status wf_snhost_place(const wf_catalog *gal, size_t row, wf_rng *rng,
                          const wf_snhost_config *cfg, wf_snhost_position *out)
{
    wf_snhost_config def;
    const wf_snhost_config *c = config_or_default(cfg, &def);
    wf_status st = wf_snhost_config_check(c);
    if (st) return st;
    if (gal->kind != WF_CATALOG_GALAXY || row >= gal->n)
        return wf_snhost_place_at(gal, row, 0, 0.0, 0.0, out); /* its error message */
    double uc = wf_rng_uniform53(rng), uf = wf_rng_uniform53(rng), up = wf_rng_uniform53(rng);
    int comp = uc < gal->bulge_frac[row] ? 1 : 0;
    return wf_snhost_place_at(gal, row, comp, uf * c->fmax, 2.0 * M_PI * up, out);
}
