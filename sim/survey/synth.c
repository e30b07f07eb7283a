#include "sim/survey/synth.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "hal/noise.h"

#define DEG (M_PI / 180.0)
#define ARCMIN (DEG / 60.0)
#define ARCSEC (DEG / 3600.0)
#define PAD 1e-7 /* rad: slack on cell culling, as in sim/survey/skyindex.c */

/* Stream layout (hal/noise.h counter {pixel, read, exposure, SCA|purpose|block}):
 * pixel = cell, exposure = STREAM_TAG | kind, read = object number. The tag keeps these
 * streams apart from any exposure's scene streams (exposure numbers are far below it). */
#define STREAM_TAG 0xCA7A0000u
enum { S_COUNTS = 0, S_GALAXY = 1, S_STAR = 2, S_PARENT = 3, S_MEMBER = 4 };
enum { ID_GALAXY = 0, ID_STAR = 1, ID_MEMBER = 2 };
#define MAX_MEMBERS 4095
#define MAX_PARENTS 65535

static const char *const BANDS[WF_SYNTH_NBAND] = {"Y106", "J129", "H158", "F184"};
enum { B_Y, B_J, B_H, B_F };

/* ------------------------------------------------------------------ number counts */

/* dN/dm through nodes, log-linear between them and beyond them with given end slopes. */
typedef struct counts_model {
    int nnode;
    double m[8], logn[8];
    double slope_lo, slope_hi;
} counts_model;

static double counts_eval(const counts_model *c, double m)
{
    int k = c->nnode;
    if (m <= c->m[0]) return pow(10.0, c->logn[0] + c->slope_lo * (m - c->m[0]));
    if (m >= c->m[k - 1]) return pow(10.0, c->logn[k - 1] + c->slope_hi * (m - c->m[k - 1]));
    int i = 0;
    while (m > c->m[i + 1]) i++;
    double t = (m - c->m[i]) / (c->m[i + 1] - c->m[i]);
    return pow(10.0, c->logn[i] + t * (c->logn[i + 1] - c->logn[i]));
}

/* The same function cut to [lo, hi] as exactly integrable log-linear pieces. */
typedef struct counts_sampler {
    int nseg;
    double a[10], b[10], n0[10], s[10], cum[11];
} counts_sampler;

static double piece_integral(double n0, double s, double w)
{
    double x = s * w * M_LN10;
    return fabs(x) < 1e-9 ? n0 * w : n0 * expm1(x) / (s * M_LN10);
}

static double counts_integral(const counts_model *c, double lo, double hi)
{
    double cuts[10];
    int nc = 0;
    cuts[nc++] = lo;
    for (int k = 0; k < c->nnode; k++)
        if (c->m[k] > lo && c->m[k] < hi) cuts[nc++] = c->m[k];
    cuts[nc++] = hi;
    double sum = 0.0;
    for (int i = 0; i + 1 < nc; i++) {
        double a = cuts[i], b = cuts[i + 1];
        double na = counts_eval(c, a), nb = counts_eval(c, b);
        sum += piece_integral(na, log10(nb / na) / (b - a), b - a);
    }
    return sum;
}

static void sampler_build(const counts_model *c, double lo, double hi, counts_sampler *sp)
{
    double cuts[10];
    int nc = 0;
    cuts[nc++] = lo;
    for (int k = 0; k < c->nnode; k++)
        if (c->m[k] > lo && c->m[k] < hi) cuts[nc++] = c->m[k];
    cuts[nc++] = hi;
    sp->nseg = nc - 1;
    sp->cum[0] = 0.0;
    for (int i = 0; i < sp->nseg; i++) {
        double a = cuts[i], b = cuts[i + 1];
        double na = counts_eval(c, a), nb = counts_eval(c, b);
        sp->a[i] = a;
        sp->b[i] = b;
        sp->n0[i] = na;
        sp->s[i] = log10(nb / na) / (b - a);
        sp->cum[i + 1] = sp->cum[i] + piece_integral(na, sp->s[i], b - a);
    }
}

static double sampler_draw(const counts_sampler *sp, double u)
{
    double t = u * sp->cum[sp->nseg];
    int i = 0;
    while (i + 1 < sp->nseg && t > sp->cum[i + 1]) i++;
    double w = sp->b[i] - sp->a[i];
    double piece = sp->cum[i + 1] - sp->cum[i];
    double f = piece > 0.0 ? (t - sp->cum[i]) / piece : 0.0;
    if (f < 0.0) f = 0.0;
    if (f > 1.0) f = 1.0;
    double x = sp->s[i] * w * M_LN10;
    double m =
        fabs(x) < 1e-9 ? sp->a[i] + f * w : sp->a[i] + log1p(f * expm1(x)) / (sp->s[i] * M_LN10);
    return m < sp->b[i] ? m : sp->b[i];
}

/* SPEC §4.3: 3D-HST COSMOS H160 counts per arcmin² per mag in 1-mag bins centred here. */
static const double H_TABLE_M[6] = {20.5, 21.5, 22.5, 23.5, 24.5, 25.5};
static const double H_TABLE_N[6] = {3.9, 7.4, 13.6, 24.9, 41.8, 55.8};

/* Nodes such that every 1-mag bin integrates to its tabulated count (counts are bin
 * averages, and a curve through the bin centres would overshoot the convex bins by ~2%). */
static void galaxy_counts(double faint_slope, counts_model *c)
{
    c->nnode = 6;
    for (int k = 0; k < 6; k++) {
        c->m[k] = H_TABLE_M[k];
        c->logn[k] = log10(H_TABLE_N[k]);
    }
    c->slope_hi = faint_slope;
    for (int it = 0; it < 200; it++) {
        c->slope_lo = c->logn[1] - c->logn[0];
        double worst = 0.0;
        double next[6];
        for (int k = 0; k < 6; k++) {
            double in = counts_integral(c, c->m[k] - 0.5, c->m[k] + 0.5);
            next[k] = c->logn[k] + log10(H_TABLE_N[k] / in);
            worst = fmax(worst, fabs(in / H_TABLE_N[k] - 1.0));
        }
        memcpy(c->logn, next, sizeof next);
        if (worst < 1e-13) break;
    }
    c->slope_lo = c->logn[1] - c->logn[0];
}

/* Star counts in V (per arcmin² per mag, shape only; normalised to the configured density
 * over 12 <= V <= 27): steep where disk stars dominate, ~0.1 dex/mag where the halo does. */
static void star_counts(counts_model *c)
{
    static const double v[5] = {12.0, 16.0, 20.0, 24.0, 27.0};
    static const double n[5] = {0.003, 0.03, 0.15, 0.35, 0.5};
    c->nnode = 5;
    for (int k = 0; k < 5; k++) {
        c->m[k] = v[k];
        c->logn[k] = log10(n[k]);
    }
    c->slope_lo = (c->logn[1] - c->logn[0]) / 4.0;
    c->slope_hi = (c->logn[4] - c->logn[3]) / 3.0;
}

/* ------------------------------------------------------------------ model pieces */

#define NZTAB 1201
#define ZTAB_STEP 0.005 /* z in [0, 6] */
#define H0 70.0
#define OMEGA_M 0.3
#define C_KMS 299792.458
#define Z_MIN 0.01
#define Z_MAX 6.0

struct wf_synth {
    wf_synth_config cfg;
    double c0[3], east[3], north[3]; /* tangent-plane basis at the field centre */
    double cell;                     /* cell side in tangent-plane units */
    double tan_radius;
    int nhalf;
    counts_model gal_model, star_model;
    counts_sampler gal_counts, star_counts;
    double gal_density, star_density;     /* per arcmin², over the configured ranges */
    double field_density, parent_density; /* per arcmin² */
    double star_scale;
    double sigma_plane; /* group radius in tangent-plane units */
    double zmed_per_z0;
    double dm[NZTAB]; /* distance modulus */
    wf_noise noise;
};

/* Median redshift against H158 of the CANDELS/3D-HST-derived host library in
 * ../shared/data/hosts (medians in 1-mag bins), +0.2 per mag beyond its depth. */
static double zmed_of_h(double h)
{
    static const double hm[7] = {18.5, 19.5, 20.5, 21.5, 22.5, 23.5, 24.5};
    static const double zm[7] = {0.32, 0.52, 0.66, 0.78, 0.98, 1.17, 1.39};
    double z;
    if (h <= hm[0])
        z = zm[0] + 0.2 * (h - hm[0]);
    else if (h >= hm[6])
        z = zm[6] + 0.2 * (h - hm[6]);
    else {
        int i = (int)floor(h - hm[0]);
        if (i > 5) i = 5;
        double t = h - hm[i];
        z = zm[i] + t * (zm[i + 1] - zm[i]);
    }
    return z > 0.05 ? z : 0.05;
}

static double dm_of_z(const wf_synth *s, double z)
{
    double x = z / ZTAB_STEP;
    int i = (int)x;
    if (i >= NZTAB - 1) i = NZTAB - 2;
    if (i < 1) i = 1; /* dm(0) is -inf: extrapolate from the first finite interval */
    double t = x - i;
    return s->dm[i] + t * (s->dm[i + 1] - s->dm[i]);
}

/* Age of a flat LCDM universe at z, Gyr. */
static double age_gyr(double z)
{
    double ol = 1.0 - OMEGA_M;
    double hubble_time = 977.792 / H0; /* Gyr */
    return 2.0 / (3.0 * sqrt(ol)) * hubble_time * asinh(sqrt(ol / OMEGA_M) * pow(1.0 + z, -1.5));
}

static void cosmology_table(wf_synth *s)
{
    /* Comoving distance by the trapezoid rule on 50 sub-steps per table step. */
    double dc = 0.0;
    s->dm[0] = -INFINITY;
    for (int i = 1; i < NZTAB; i++) {
        const int sub = 50;
        double z0 = (i - 1) * ZTAB_STEP, h = ZTAB_STEP / sub;
        for (int k = 0; k < sub; k++) {
            double za = z0 + k * h, zb = za + h;
            double ea = sqrt(OMEGA_M * pow(1 + za, 3) + 1 - OMEGA_M);
            double eb = sqrt(OMEGA_M * pow(1 + zb, 3) + 1 - OMEGA_M);
            dc += 0.5 * h * (1 / ea + 1 / eb);
        }
        double z = i * ZTAB_STEP;
        double dl_mpc = (1 + z) * dc * C_KMS / H0;
        s->dm[i] = 5.0 * log10(dl_mpc) + 25.0;
    }
}

/* Median colours (AB) of star-forming and quiescent galaxies against z. Up to z ~ 2 (SF to
 * 3.25) from the host library's medians in bins of 0.5; quiescent colours beyond z ~ 2 are
 * set by hand to follow the 4000 A break through J and H (see docs/CATALOGS.md). */
#define NZC 7
static const double ZC[NZC] = {0.25, 0.75, 1.25, 1.75, 2.25, 2.75, 3.25};
static const double SF_YH[NZC] = {0.16, 0.25, 0.40, 0.64, 0.72, 0.56, 0.33};
static const double SF_JH[NZC] = {0.08, 0.10, 0.15, 0.18, 0.29, 0.34, 0.29};
static const double SF_HF[NZC] = {0.04, 0.09, 0.13, 0.13, 0.22, 0.22, 0.26};
static const double Q_YH[NZC] = {0.36, 0.55, 0.92, 1.51, 1.70, 1.80, 1.80};
static const double Q_JH[NZC] = {0.13, 0.19, 0.25, 0.33, 0.55, 0.80, 0.90};
static const double Q_HF[NZC] = {0.06, 0.20, 0.28, 0.31, 0.35, 0.40, 0.55};
static const double SIG_YH = 0.15, SIG_JH = 0.08, SIG_HF = 0.08;

static double interp_z(const double *tab, double z)
{
    if (z <= ZC[0]) return tab[0];
    if (z >= ZC[NZC - 1]) return tab[NZC - 1];
    int i = 0;
    while (z > ZC[i + 1]) i++;
    double t = (z - ZC[i]) / (ZC[i + 1] - ZC[i]);
    return tab[i] + t * (tab[i + 1] - tab[i]);
}

/* Main-sequence dwarf colours (Vega) against V-K, rounded from published dwarf colour
 * tables (e.g. Pecaut & Mamajek 2013): J-H and H-Ks. */
#define NVK 10
static const double VK[NVK] = {0.8, 1.2, 1.6, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0};
static const double VK_JH[NVK] = {0.12, 0.22, 0.30, 0.40, 0.50, 0.58, 0.62, 0.62, 0.58, 0.58};
static const double VK_HK[NVK] = {0.03, 0.04, 0.06, 0.08, 0.10, 0.12, 0.15, 0.19, 0.26, 0.32};

static double interp_vk(const double *tab, double vk)
{
    if (vk <= VK[0]) return tab[0];
    if (vk >= VK[NVK - 1]) return tab[NVK - 1];
    int i = 0;
    while (vk > VK[i + 1]) i++;
    double t = (vk - VK[i]) / (VK[i + 1] - VK[i]);
    return tab[i] + t * (tab[i + 1] - tab[i]);
}

/* ------------------------------------------------------------------ objects */

static double truncated_shape(wf_rng *rng)
{
    for (int k = 0; k < 1000; k++) {
        double e = 0.27 * wf_rng_gauss(rng);
        if (fabs(e) <= 0.7) return e;
    }
    return 0.0; /* unreachable in practice: P(|e| > 0.7) = 0.0095 per try */
}

typedef struct galaxy {
    double mag[WF_SYNTH_NBAND];
    double z, logm, logsfr, hlr, bt, knot, e1, e2, pa;
} galaxy;

/* One galaxy's intrinsic properties from its own stream. zfix > 0 fixes the redshift
 * (group members). The order of draws is part of the reproducibility contract. */
static void draw_galaxy(const wf_synth *s, wf_rng *rng, double zfix, galaxy *g)
{
    double h = sampler_draw(&s->gal_counts, wf_rng_uniform53(rng));
    double z = zfix;
    if (!(zfix > 0.0)) {
        /* n(z) ∝ z² exp(-(z/z0)^1.5): (z/z0)^1.5 is Gamma(2, 1), a sum of two exponentials. */
        double z0 = zmed_of_h(h) / s->zmed_per_z0;
        z = -1.0;
        for (int k = 0; k < 100 && !(z >= Z_MIN && z <= Z_MAX); k++) {
            double u = -log(wf_rng_uniform(rng) * wf_rng_uniform(rng));
            z = z0 * pow(u, 2.0 / 3.0);
        }
        if (!(z >= Z_MIN && z <= Z_MAX)) z = fmin(fmax(z, Z_MIN), Z_MAX);
    }
    /* Stellar mass from the K-corrected (flat f_nu) absolute H magnitude: least-squares fits
     * to the host library, separately for star-forming and quiescent galaxies; the type is
     * chosen first from the star-forming estimate. */
    double x = -0.4 * (h - dm_of_z(s, z) + 2.5 * log10(1.0 + z));
    double m_sf = 0.20 + 1.139 * x;
    double fq = 1.0 / (1.0 + exp(-(m_sf - (10.6 + 0.35 * z)) / 0.4));
    int q = wf_rng_uniform(rng) < fq;
    double logm = q ? 1.09 + 1.077 * x + 0.15 * wf_rng_gauss(rng) : m_sf + 0.30 * wf_rng_gauss(rng);
    logm = fmin(fmax(logm, 4.0), 12.5);
    /* Star-forming main sequence of Speagle et al. (2014) at the age of the universe. */
    double t = age_gyr(z);
    double ms = (0.84 - 0.026 * t) * logm - (6.51 - 0.11 * t);
    double logsfr = q ? ms - 1.5 + 0.4 * wf_rng_gauss(rng) : ms + 0.25 * wf_rng_gauss(rng);
    logsfr = fmin(fmax(logsfr, -6.0), 4.0);
    /* Colours: one shared deviate (the SED shape) and one per colour. */
    double gc = wf_rng_gauss(rng);
    double g1 = wf_rng_gauss(rng), g2 = wf_rng_gauss(rng), g3 = wf_rng_gauss(rng);
    double yh = interp_z(q ? Q_YH : SF_YH, z) + SIG_YH * (0.8 * gc + 0.6 * g1);
    double jh = interp_z(q ? Q_JH : SF_JH, z) + SIG_JH * (0.8 * gc + 0.6 * g2);
    double hf = interp_z(q ? Q_HF : SF_HF, z) + SIG_HF * (0.8 * gc + 0.6 * g3);
    g->mag[B_Y] = h + yh;
    g->mag[B_J] = h + jh;
    g->mag[B_H] = h;
    g->mag[B_F] = h - hf;
    /* SPEC §4.3 size-magnitude relation. */
    g->hlr = pow(10.0, -0.42 - 0.07 * (h - 22.5) + 0.25 * wf_rng_gauss(rng));
    double ub = wf_rng_uniform(rng);
    g->bt = q ? 0.5 + 0.5 * ub : 0.5 * ub * ub;
    double uk = wf_rng_uniform(rng);
    g->knot = q ? 0.0 : 0.25 * uk;
    g->e1 = truncated_shape(rng);
    g->e2 = truncated_shape(rng);
    g->pa = 180.0 * wf_rng_uniform(rng);
    g->z = z;
    g->logm = logm;
    g->logsfr = logsfr;
}

/* Pivot wavelengths (um) of the catalog bands and of the Johnson/2MASS bands they are
 * interpolated from. */
static const double LAM_BAND[WF_SYNTH_NBAND] = {1.057, 1.290, 1.575, 1.839};
static const double LAM_VJHK[4] = {0.551, 1.235, 1.662, 2.159};

static void draw_star(const wf_synth *s, wf_rng *rng, double mag[WF_SYNTH_NBAND])
{
    double v = sampler_draw(&s->star_counts, wf_rng_uniform53(rng));
    double vk;
    if (wf_rng_uniform(rng) < 0.3) {
        vk = 3.5 + 2.5 * wf_rng_uniform(rng); /* M dwarfs */
    } else {
        vk = 1.7;
        for (int k = 0; k < 100; k++) {
            double t = 1.7 + 0.35 * wf_rng_gauss(rng);
            if (t >= 0.8 && t <= 3.5) {
                vk = t;
                break;
            }
        }
    }
    double kmag = v - vk;
    double hmag = kmag + interp_vk(VK_HK, vk);
    double jmag = hmag + interp_vk(VK_JH, vk);
    /* Vega to AB (Blanton & Roweis 2007): V +0.02, J +0.91, H +1.39, Ks +1.85. */
    double ab[4] = {v + 0.02, jmag + 0.91, hmag + 1.39, kmag + 1.85};
    for (int b = 0; b < WF_SYNTH_NBAND; b++) {
        double l = log(LAM_BAND[b]);
        int i = 0;
        while (i < 2 && l > log(LAM_VJHK[i + 1])) i++;
        double t = (l - log(LAM_VJHK[i])) / (log(LAM_VJHK[i + 1]) - log(LAM_VJHK[i]));
        mag[b] = ab[i] + t * (ab[i + 1] - ab[i]);
    }
}

/* ------------------------------------------------------------------ geometry */

static void unit_vec(double ra_deg, double dec_deg, double p[3])
{
    double a = ra_deg * DEG, d = dec_deg * DEG;
    p[0] = cos(d) * cos(a);
    p[1] = cos(d) * sin(a);
    p[2] = sin(d);
}

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double angle_between(const double a[3], const double b[3])
{
    double c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    return atan2(sqrt(dot3(c, c)), dot3(a, b));
}

static void plane_to_vec(const wf_synth *s, double x, double y, double p[3])
{
    double q[3];
    for (int k = 0; k < 3; k++) q[k] = s->c0[k] + x * s->east[k] + y * s->north[k];
    double l = sqrt(dot3(q, q));
    for (int k = 0; k < 3; k++) p[k] = q[k] / l;
}

static void plane_to_radec(const wf_synth *s, double x, double y, double *ra, double *dec)
{
    double p[3];
    plane_to_vec(s, x, y, p);
    double a = atan2(p[1], p[0]) / DEG;
    if (a < 0.0) a += 360.0;
    if (a >= 360.0) a -= 360.0;
    *ra = a;
    *dec = atan2(p[2], hypot(p[0], p[1])) / DEG;
}

static uint32_t cell_id(int ix, int iy)
{
    return ((uint32_t)(iy + 32768) << 16) | (uint32_t)(ix + 32768);
}

static void cell_xy(uint32_t c, int *ix, int *iy)
{
    *ix = (int)(c & 0xffffu) - 32768;
    *iy = (int)(c >> 16) - 32768;
}

static int in_field(const wf_synth *s, int ix, int iy)
{
    if (ix < -s->nhalf || ix >= s->nhalf || iy < -s->nhalf || iy >= s->nhalf) return 0;
    double x = (ix + 0.5) * s->cell, y = (iy + 0.5) * s->cell;
    return hypot(x, y) <= s->tan_radius;
}

/* Solid angle of a tangent-plane rectangle (exact for the gnomonic projection). */
static double rect_solid_angle(double x1, double x2, double y1, double y2)
{
#define F(x, y) atan((x) * (y) / sqrt(1.0 + (x) * (x) + (y) * (y)))
    return F(x2, y2) - F(x1, y2) - F(x2, y1) + F(x1, y1);
#undef F
}

static double cell_area_arcmin2(const wf_synth *s, int ix, int iy)
{
    double x1 = ix * s->cell, y1 = iy * s->cell;
    return rect_solid_angle(x1, x1 + s->cell, y1, y1 + s->cell) / (ARCMIN * ARCMIN);
}

/* A point uniform on the sphere within cell (ix, iy): uniform in the plane, thinned by the
 * projection's area factor (1 + r²)^(-3/2) relative to its largest value in the cell. */
static void draw_position(const wf_synth *s, wf_rng *rng, int ix, int iy, double *x, double *y)
{
    double x1 = ix * s->cell, y1 = iy * s->cell, x2 = x1 + s->cell, y2 = y1 + s->cell;
    double nx = x1 > 0 ? x1 : (x2 < 0 ? x2 : 0.0), ny = y1 > 0 ? y1 : (y2 < 0 ? y2 : 0.0);
    double wmax = pow(1.0 + nx * nx + ny * ny, -1.5);
    for (int k = 0; k < 1000; k++) {
        *x = x1 + s->cell * wf_rng_uniform53(rng);
        *y = y1 + s->cell * wf_rng_uniform53(rng);
        double w = pow(1.0 + *x * *x + *y * *y, -1.5) / wmax;
        if (wf_rng_uniform(rng) <= w) return;
    }
}

/* ------------------------------------------------------------------ setup */

wf_status wf_synth_defaults(wf_synth_config *cfg)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->seed = 1;
    cfg->ra0 = 71.0;
    cfg->dec0 = -53.0;
    cfg->radius_deg = 1.6;
    cfg->cell_arcmin = 1.0;
    cfg->h_bright = 15.0;
    cfg->h_faint = 26.0;
    cfg->faint_slope = 0.17;
    cfg->star_density = 2.5;
    cfg->star_v_bright = 12.0;
    cfg->star_v_faint = 27.0;
    cfg->clustering = 0;
    cfg->cluster_fraction = 0.3;
    cfg->cluster_members = 8.0;
    cfg->cluster_sigma_arcsec = 10.0;
    return WF_OK;
}

wf_status wf_synth_bands(const char *const **bands)
{
    *bands = BANDS;
    return WF_OK;
}

#define CHECK(cond, ...)                                                                           \
    do {                                                                                           \
        if (!(cond)) return wf_error(WF_ERR_RANGE, __VA_ARGS__);                                   \
    } while (0)

wf_status wf_synth_create(const wf_synth_config *cfg, wf_synth **out)
{
    *out = NULL;
    CHECK(isfinite(cfg->ra0) && cfg->dec0 >= -90.0 && cfg->dec0 <= 90.0,
          "synthetic catalog: field centre (%g, %g) is not a sky position", cfg->ra0, cfg->dec0);
    CHECK(cfg->radius_deg > 0.0 && cfg->radius_deg <= 30.0,
          "synthetic catalog: field radius %g deg outside (0, 30]", cfg->radius_deg);
    CHECK(cfg->cell_arcmin >= 0.1 && cfg->cell_arcmin <= 60.0,
          "synthetic catalog: cell size %g arcmin outside [0.1, 60]", cfg->cell_arcmin);
    CHECK(cfg->h_bright >= 10.0 && cfg->h_faint <= 32.0 && cfg->h_bright < cfg->h_faint,
          "synthetic catalog: galaxy H range [%g, %g] must lie in [10, 32]", cfg->h_bright,
          cfg->h_faint);
    CHECK(cfg->faint_slope >= 0.0 && cfg->faint_slope <= 0.6,
          "synthetic catalog: faint-end slope %g dex/mag outside [0, 0.6]", cfg->faint_slope);
    CHECK(cfg->star_density >= 0.0 && cfg->star_density <= 1000.0,
          "synthetic catalog: star density %g per arcmin² outside [0, 1000]", cfg->star_density);
    CHECK(cfg->star_v_bright >= 5.0 && cfg->star_v_faint <= 32.0 &&
              cfg->star_v_bright < cfg->star_v_faint,
          "synthetic catalog: star V range [%g, %g] must lie in [5, 32]", cfg->star_v_bright,
          cfg->star_v_faint);
    if (cfg->clustering) {
        CHECK(cfg->cluster_fraction >= 0.0 && cfg->cluster_fraction <= 1.0,
              "synthetic catalog: cluster fraction %g outside [0, 1]", cfg->cluster_fraction);
        CHECK(cfg->cluster_members >= 1.0 && cfg->cluster_members <= 1000.0,
              "synthetic catalog: mean group members %g outside [1, 1000]", cfg->cluster_members);
        CHECK(cfg->cluster_sigma_arcsec > 0.0 &&
                  4.0 * cfg->cluster_sigma_arcsec <= 60.0 * cfg->cell_arcmin,
              "synthetic catalog: group radius %g arcsec: 4 sigma must fit in a cell (%g arcmin)",
              cfg->cluster_sigma_arcsec, cfg->cell_arcmin);
    }
    double tan_r = tan(cfg->radius_deg * DEG), cell = tan(cfg->cell_arcmin * ARCMIN);
    int nhalf = (int)ceil(tan_r / cell) + 1;
    CHECK(nhalf < 32000, "synthetic catalog: %g deg / %g arcmin cells is too many cells",
          cfg->radius_deg, cfg->cell_arcmin);

    wf_synth *s = calloc(1, sizeof *s);
    if (!s) return wf_error(WF_ERR_NOMEM, "synthetic catalog: no memory");
    s->cfg = *cfg;
    s->cfg.ra0 = fmod(cfg->ra0, 360.0);
    if (s->cfg.ra0 < 0.0) s->cfg.ra0 += 360.0;
    double a = s->cfg.ra0 * DEG, d = cfg->dec0 * DEG;
    unit_vec(s->cfg.ra0, cfg->dec0, s->c0);
    s->east[0] = -sin(a);
    s->east[1] = cos(a);
    s->east[2] = 0.0;
    s->north[0] = -sin(d) * cos(a);
    s->north[1] = -sin(d) * sin(a);
    s->north[2] = cos(d);
    s->cell = cell;
    s->tan_radius = tan_r;
    s->nhalf = nhalf;

    galaxy_counts(cfg->faint_slope, &s->gal_model);
    sampler_build(&s->gal_model, cfg->h_bright, cfg->h_faint, &s->gal_counts);
    s->gal_density = s->gal_counts.cum[s->gal_counts.nseg];
    star_counts(&s->star_model);
    double shape = counts_integral(&s->star_model, 12.0, 27.0);
    s->star_scale = cfg->star_density / shape;
    sampler_build(&s->star_model, cfg->star_v_bright, cfg->star_v_faint, &s->star_counts);
    s->star_density = s->star_scale * s->star_counts.cum[s->star_counts.nseg];
    double f = cfg->clustering ? cfg->cluster_fraction : 0.0;
    s->field_density = (1.0 - f) * s->gal_density;
    s->parent_density = cfg->clustering ? f * s->gal_density / cfg->cluster_members : 0.0;
    s->sigma_plane = cfg->cluster_sigma_arcsec * ARCSEC;
    s->zmed_per_z0 = pow(1.6783469900166608, 2.0 / 3.0); /* median of Gamma(2, 1) */
    cosmology_table(s);
    s->noise = (wf_noise){WF_NOISE_PHILOX, cfg->seed, 0u, 0u};
    *out = s;
    return WF_OK;
}

void wf_synth_free(wf_synth *s) { free(s); }

wf_status wf_synth_expected_density(const wf_synth *s, double *galaxies, double *stars)
{
    *galaxies = s->gal_density;
    *stars = s->star_density;
    return WF_OK;
}

wf_status wf_synth_dndm(const wf_synth *s, double h, double *dndm)
{
    *dndm = counts_eval(&s->gal_model, h);
    return WF_OK;
}

wf_status wf_synth_cell_info(const wf_synth *s, uint32_t cell, double *area_arcmin2, double *ra_deg,
                             double *dec_deg)
{
    int ix, iy;
    cell_xy(cell, &ix, &iy);
    *area_arcmin2 = cell_area_arcmin2(s, ix, iy);
    plane_to_radec(s, (ix + 0.5) * s->cell, (iy + 0.5) * s->cell, ra_deg, dec_deg);
    return WF_OK;
}

/* ------------------------------------------------------------------ cells */

wf_status wf_synth_cells(const wf_synth *s, uint32_t **cells, size_t *ncell)
{
    size_t cap = (size_t)(2 * s->nhalf) * (size_t)(2 * s->nhalf), n = 0;
    uint32_t *c = malloc(cap * sizeof *c);
    if (!c) return wf_error(WF_ERR_NOMEM, "synthetic catalog: no memory for %zu cells", cap);
    for (int iy = -s->nhalf; iy < s->nhalf; iy++)
        for (int ix = -s->nhalf; ix < s->nhalf; ix++)
            if (in_field(s, ix, iy)) c[n++] = cell_id(ix, iy);
    *cells = c;
    *ncell = n;
    return WF_OK;
}

wf_status wf_synth_region_cells(const wf_synth *s, const wf_skyregion *reg, uint32_t **cells,
                                size_t *ncell)
{
    *cells = NULL;
    *ncell = 0;
    double R = reg->bound + PAD;
    double theta = angle_between(s->c0, reg->centre);
    if (theta + R >= 80.0 * DEG)
        return wf_error(WF_ERR_RANGE,
                        "synthetic catalog: region at (%g, %g) reaches %g deg from the field "
                        "centre (the tangent-plane cells end at 80 deg)",
                        reg->ra_c, reg->dec_c, (theta + R) / DEG);
    /* The region's cap maps into a disc of radius R sec²(theta + R) around the image of its
     * centre (the projection stretches lengths by at most sec² of the distance from the
     * tangent point, and maps the cap's geodesics to straight lines). */
    double w = dot3(reg->centre, s->c0);
    double xu = dot3(reg->centre, s->east) / w, yu = dot3(reg->centre, s->north) / w;
    double cr = cos(theta + R);
    double D = R / (cr * cr) * (1.0 + 1e-9) + PAD;
    int ix0 = (int)floor((xu - D) / s->cell), ix1 = (int)floor((xu + D) / s->cell);
    int iy0 = (int)floor((yu - D) / s->cell), iy1 = (int)floor((yu + D) / s->cell);
    if (ix0 < -s->nhalf) ix0 = -s->nhalf;
    if (iy0 < -s->nhalf) iy0 = -s->nhalf;
    if (ix1 > s->nhalf - 1) ix1 = s->nhalf - 1;
    if (iy1 > s->nhalf - 1) iy1 = s->nhalf - 1;
    if (ix0 > ix1 || iy0 > iy1) return WF_OK;
    size_t cap = (size_t)(ix1 - ix0 + 1) * (size_t)(iy1 - iy0 + 1), n = 0;
    uint32_t *c = malloc(cap * sizeof *c);
    if (!c) return wf_error(WF_ERR_NOMEM, "synthetic catalog: no memory for %zu cells", cap);
    for (int iy = iy0; iy <= iy1; iy++)
        for (int ix = ix0; ix <= ix1; ix++) {
            if (!in_field(s, ix, iy)) continue;
            double cc[3], corner[3], rc = 0.0;
            plane_to_vec(s, (ix + 0.5) * s->cell, (iy + 0.5) * s->cell, cc);
            for (int k = 0; k < 4; k++) {
                plane_to_vec(s, (ix + (k & 1)) * s->cell, (iy + (k >> 1)) * s->cell, corner);
                rc = fmax(rc, angle_between(cc, corner));
            }
            if (angle_between(cc, reg->centre) <= R + rc + PAD) c[n++] = cell_id(ix, iy);
        }
    *cells = c;
    *ncell = n;
    return WF_OK;
}

/* ------------------------------------------------------------------ generation */

static wf_status put_galaxy(wf_catalog *cat, int64_t id, double ra, double dec, const galaxy *g)
{
    size_t i;
    wf_status st = wf_catalog_push(cat, &i);
    if (st) return st;
    cat->id[i] = id;
    cat->ra[i] = ra;
    cat->dec[i] = dec;
    for (int b = 0; b < WF_SYNTH_NBAND; b++) cat->mag[b][i] = (float)g->mag[b];
    cat->z[i] = (float)g->z;
    cat->logmass[i] = (float)g->logm;
    cat->logsfr[i] = (float)g->logsfr;
    cat->hlr_disk[i] = (float)g->hlr;
    cat->hlr_bulge[i] = (float)(0.5 * g->hlr);
    cat->bulge_frac[i] = (float)g->bt;
    cat->knot_frac[i] = (float)g->knot;
    cat->e1[i] = (float)g->e1;
    cat->e2[i] = (float)g->e2;
    cat->pa[i] = (float)g->pa;
    return WF_OK;
}

static int64_t make_id(uint32_t cell, int kind, uint32_t index)
{
    return (int64_t)(((uint64_t)cell << 31) | ((uint64_t)kind << 28) | (index & 0x0fffffffu));
}

static void stream(const wf_synth *s, wf_rng *rng, uint32_t cell, int kind, uint32_t read)
{
    wf_noise nz = s->noise;
    nz.exposure = STREAM_TAG | (uint32_t)kind;
    wf_rng_init(rng, &nz, cell, read, WF_PURPOSE_SCENE);
}

static uint32_t cell_count(const wf_synth *s, uint32_t cell, int which, double mean)
{
    wf_rng rng;
    stream(s, &rng, cell, S_COUNTS, (uint32_t)which);
    double n = wf_rng_poisson(&rng, mean);
    return n > 0x0fffffff ? 0x0fffffffu : (uint32_t)n;
}

/* Group members that land in cell (ix, iy), from the groups centred in it and its eight
 * neighbours (a member lies within 4 sigma <= one cell of its centre). */
static wf_status cell_members(const wf_synth *s, int ix, int iy, wf_catalog *gal)
{
    for (int dy = -1; dy <= 1; dy++)
        for (int dx = -1; dx <= 1; dx++) {
            int px = ix + dx, py = iy + dy;
            uint32_t pc = cell_id(px, py);
            uint32_t np = cell_count(s, pc, 2, s->parent_density * cell_area_arcmin2(s, px, py));
            if (np > MAX_PARENTS) np = MAX_PARENTS;
            for (uint32_t j = 0; j < np; j++) {
                wf_rng rng;
                stream(s, &rng, pc, S_PARENT, j);
                double xp, yp;
                draw_position(s, &rng, px, py, &xp, &yp);
                galaxy proto;
                draw_galaxy(s, &rng, 0.0, &proto);
                double nm = wf_rng_poisson(&rng, s->cfg.cluster_members);
                uint32_t nmem = nm > MAX_MEMBERS ? MAX_MEMBERS : (uint32_t)nm;
                for (uint32_t k = 0; k < nmem; k++) {
                    wf_rng mr;
                    stream(s, &mr, pc, S_MEMBER, (j << 12) | k);
                    double ox = 0.0, oy = 0.0;
                    for (int t = 0; t < 1000; t++) {
                        ox = s->sigma_plane * wf_rng_gauss(&mr);
                        oy = s->sigma_plane * wf_rng_gauss(&mr);
                        if (ox * ox + oy * oy <= 16.0 * s->sigma_plane * s->sigma_plane) break;
                    }
                    double x = xp + ox, y = yp + oy;
                    if ((int)floor(x / s->cell) != ix || (int)floor(y / s->cell) != iy) continue;
                    /* Members share the group's redshift up to a ~500 km/s velocity spread. */
                    double z = proto.z + 0.0017 * (1.0 + proto.z) * wf_rng_gauss(&mr);
                    galaxy g;
                    draw_galaxy(s, &mr, fmax(z, Z_MIN), &g);
                    double ra, dec;
                    plane_to_radec(s, x, y, &ra, &dec);
                    wf_status st =
                        put_galaxy(gal, make_id(pc, ID_MEMBER, (j << 12) | k), ra, dec, &g);
                    if (st) return st;
                }
            }
        }
    return WF_OK;
}

static wf_status generate_cell(const wf_synth *s, uint32_t cell, wf_catalog *gal, wf_catalog *stars)
{
    int ix, iy;
    cell_xy(cell, &ix, &iy);
    if (!in_field(s, ix, iy))
        return wf_error(WF_ERR_RANGE, "synthetic catalog: cell %u (%d, %d) is outside the field",
                        (unsigned)cell, ix, iy);
    double area = cell_area_arcmin2(s, ix, iy);
    wf_status st;
    if (gal) {
        uint32_t n = cell_count(s, cell, 0, s->field_density * area);
        for (uint32_t j = 0; j < n; j++) {
            wf_rng rng;
            stream(s, &rng, cell, S_GALAXY, j);
            double x, y, ra, dec;
            draw_position(s, &rng, ix, iy, &x, &y);
            galaxy g;
            draw_galaxy(s, &rng, 0.0, &g);
            plane_to_radec(s, x, y, &ra, &dec);
            if ((st = put_galaxy(gal, make_id(cell, ID_GALAXY, j), ra, dec, &g))) return st;
        }
        if (s->parent_density > 0.0 && (st = cell_members(s, ix, iy, gal))) return st;
    }
    if (stars) {
        uint32_t n = cell_count(s, cell, 1, s->star_density * area);
        for (uint32_t j = 0; j < n; j++) {
            wf_rng rng;
            stream(s, &rng, cell, S_STAR, j);
            double x, y, ra, dec, mag[WF_SYNTH_NBAND];
            draw_position(s, &rng, ix, iy, &x, &y);
            draw_star(s, &rng, mag);
            plane_to_radec(s, x, y, &ra, &dec);
            size_t i;
            if ((st = wf_catalog_push(stars, &i))) return st;
            stars->id[i] = make_id(cell, ID_STAR, j);
            stars->ra[i] = ra;
            stars->dec[i] = dec;
            for (int b = 0; b < WF_SYNTH_NBAND; b++) stars->mag[b][i] = (float)mag[b];
        }
    }
    return WF_OK;
}

static wf_status init_outputs(wf_catalog *gal, wf_catalog *stars)
{
    wf_status st = WF_OK;
    if (gal)
        st = wf_catalog_init(gal, WF_CATALOG_GALAXY, WF_SYNTH_NBAND, BANDS,
                             WF_CATALOG_HAS_Z | WF_CATALOG_HAS_LOGMASS | WF_CATALOG_HAS_LOGSFR,
                             "synthetic");
    if (!st && stars)
        st = wf_catalog_init(stars, WF_CATALOG_STAR, WF_SYNTH_NBAND, BANDS, 0, "synthetic");
    return st;
}

wf_status wf_synth_generate(const wf_synth *s, const uint32_t *cells, size_t ncell, wf_catalog *gal,
                            wf_catalog *stars)
{
    wf_status st = init_outputs(gal, stars);
    for (size_t k = 0; k < ncell && !st; k++) st = generate_cell(s, cells[k], gal, stars);
    if (st) {
        if (gal) wf_catalog_free(gal);
        if (stars) wf_catalog_free(stars);
    }
    return st;
}

wf_status wf_synth_generate_all(const wf_synth *s, wf_catalog *gal, wf_catalog *stars)
{
    uint32_t *cells;
    size_t n;
    wf_status st = wf_synth_cells(s, &cells, &n);
    if (st) return st;
    st = wf_synth_generate(s, cells, n, gal, stars);
    free(cells);
    return st;
}

/* Keeps the rows of *cat inside the region, in order. */
static wf_status keep_inside(wf_catalog *cat, const wf_skyregion *reg)
{
    uint32_t *idx = malloc((cat->n ? cat->n : 1) * sizeof *idx);
    if (!idx) return wf_error(WF_ERR_NOMEM, "synthetic catalog: no memory");
    size_t n = 0;
    for (size_t i = 0; i < cat->n; i++)
        if (wf_skyindex_contains(reg, cat->ra[i], cat->dec[i])) idx[n++] = (uint32_t)i;
    wf_catalog kept;
    wf_status st = wf_catalog_subset(cat, idx, n, &kept);
    free(idx);
    if (st) return st;
    wf_catalog_free(cat);
    *cat = kept;
    return WF_OK;
}

wf_status wf_synth_select(const wf_synth *s, const wf_skyregion *reg, wf_catalog *gal,
                          wf_catalog *stars)
{
    uint32_t *cells;
    size_t n;
    wf_status st = wf_synth_region_cells(s, reg, &cells, &n);
    if (st) return st;
    st = wf_synth_generate(s, cells, n, gal, stars);
    free(cells);
    if (st) return st;
    if (gal) st = keep_inside(gal, reg);
    if (!st && stars) st = keep_inside(stars, reg);
    if (st) {
        if (gal) wf_catalog_free(gal);
        if (stars) wf_catalog_free(stars);
    }
    return st;
}
