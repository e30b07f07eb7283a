/* Star-forming knots, shapes and sizes.
 *
 * Knots follow the disk: GalSim's RandomKnots shoots its points from the profile it is given,
 * so points from the exponential disk have radii r = r0 x with x ~ Gamma(2) (density x e^-x,
 * the sum of two unit exponentials) and uniform angles. Each knot takes three uniforms from a
 * Philox stream keyed by (knot_seed, object id, purpose SCENE) and nothing else: a galaxy has
 * the same knots in every exposure, SCA, tile and thread. GalSim's own Mersenne-Twister
 * stream cannot be reproduced, so comparisons with GalSim pass its positions in knot_xy. */
#include <math.h>

#include "hal/noise.h"
#include "hal/simd.h"
#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"
#include "sim/numeric/trig.h"

/* Knots made a chunk at a time: their stream's blocks in SIMD lanes, then the arithmetic in
 * loops the compiler vectorises; only the log stays libm's. */
#define KNOT_CHUNK 128

/* Word k of the chunk's stream is word k % 4 of block k / 4. Knot j's three uniforms are
 * words (6j, 6j+1), (6j+2, 6j+3), (6j+4, 6j+5), as wf_rng_uniform53 takes them in turn:
 * prod = u1 u2 (its radius is -r0 ln prod), cyc = u3 (its angle in turns). */
WF_CLONES static void knot_uniforms(uint32_t w[4][KNOT_CHUNK * 3 / 2], int m, double *prod, double *cyc)
{
    for (int j = 0; j < m; j++) {
        int b = 3 * (j / 2) + j % 2, o = 2 * (j % 2); /* knot j starts at word 6j = 4b + o */
        double u1 = wf_uniform53_words(w[o][b], w[o + 1][b]);
        double u2 = wf_uniform53_words(w[(o + 2) % 4][b + (o + 2) / 4], w[(o + 3) % 4][b + (o + 3) / 4]);
        double u3 = wf_uniform53_words(w[(o + 4) % 4][b + (o + 4) / 4], w[(o + 5) % 4][b + (o + 5) / 4]);
        prod[j] = u1 * u2;
        cyc[j] = u3;
    }
}

/* (r cos 2 pi u, r sin 2 pi u): the angle from its turns in SIMD lanes (sim/numeric/trig.h), not
 * libm's sincos, which was most of a knot's cost at ~35 ns a call */
static void knot_place(const double *r, const double *cyc, int m, double *xy)
{
    double c[KNOT_CHUNK], s[KNOT_CHUNK];
    wf_trig_sincos_turns(cyc, m, c, s);
    for (int j = 0; j < m; j++) {
        xy[2 * j] = r[j] * c[j];
        xy[2 * j + 1] = r[j] * s[j];
    }
}

wf_status wf_profile_knots(const wf_galaxy *g, double *xy)
{
    if (!g || !xy) return wf_error(WF_ERR_INPUT, "profile: knots: no galaxy or output");
    if (g->n_knots < 0 || g->n_knots > WF_PROFILE_MAX_KNOTS)
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: %d knots outside [0, %d]", g->id,
                        g->n_knots, WF_PROFILE_MAX_KNOTS);
    if (g->knot_xy) {
        for (int j = 0; j < 2 * g->n_knots; j++) {
            if (!isfinite(g->knot_xy[j]))
                return wf_error(WF_ERR_INPUT, "profile: galaxy %u: knot %d is not finite",
                                g->id, j / 2);
            xy[j] = g->knot_xy[j];
        }
        return WF_OK;
    }
    if (g->n_knots > 0 && !(g->hlr_disk > 0.0))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: knots need a disk (hlr_disk %g)",
                        g->id, g->hlr_disk);
    double r0 = g->hlr_disk / wf_sersic4_table()->b1;
    wf_noise stream = {.kind = WF_NOISE_PHILOX, .seed = g->knot_seed, .exposure = 0, .sca = 0};
    for (int j0 = 0; j0 < g->n_knots; j0 += KNOT_CHUNK) {
        int m = g->n_knots - j0 < KNOT_CHUNK ? g->n_knots - j0 : KNOT_CHUNK;
        uint32_t w[4][KNOT_CHUNK * 3 / 2];
        /* knot j takes words 6j .. 6j+5 of the stream: blocks 3j/2 on (j0 is even) */
        wf_status st = wf_noise_stream_blocks(&stream, g->id, 0, WF_PURPOSE_SCENE, (uint32_t)(3 * j0 / 2),
                                              (3 * m + 1) / 2, w[0], w[1], w[2], w[3]);
        if (st) return wf_error(st, "profile: galaxy %u: %s", g->id, wf_error_message());
        double prod[KNOT_CHUNK], cyc[KNOT_CHUNK];
        knot_uniforms(w, m, prod, cyc);
        for (int j = 0; j < m; j++) prod[j] = -r0 * log(prod[j]); /* Gamma(2) radius */
        knot_place(prod, cyc, m, xy + 2 * j0);
    }
    return WF_OK;
}

wf_status wf_profile_shear_from_distortion(double e1, double e2, double *g1, double *g2)
{
    double e = hypot(e1, e2);
    if (!(e < 1.0))
        return wf_error(WF_ERR_RANGE, "profile: distortion |e| = %g is not below 1", e);
    double f = 1.0 / (1.0 + sqrt(1.0 - e * e));
    *g1 = e1 * f;
    *g2 = e2 * f;
    return WF_OK;
}

wf_status wf_profile_shape(double e1, double e2, double rotation, wf_shape *out)
{
    double g1, g2;
    if (!isfinite(rotation))
        return wf_error(WF_ERR_INPUT, "profile: rotation %g is not finite", rotation);
    wf_status st = wf_profile_shear_from_distortion(e1, e2, &g1, &g2);
    if (st) return st;
    double g = hypot(g1, g2), n = 1.0 / sqrt((1.0 - g) * (1.0 + g));
    double s[2][2] = {{(1.0 + g1) * n, g2 * n}, {g2 * n, (1.0 - g1) * n}};
    double c = cos(rotation), sn = sin(rotation);
    double r[2][2] = {{c, -sn}, {sn, c}};
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++) out->a[i][j] = r[i][0] * s[0][j] + r[i][1] * s[1][j];
    /* A^-1 = S^-1 R^T, and S^-1 is S with g -> -g (det S = 1) */
    double si[2][2] = {{(1.0 - g1) * n, -g2 * n}, {-g2 * n, (1.0 + g1) * n}};
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++) out->ainv[i][j] = si[i][0] * r[j][0] + si[i][1] * r[j][1];
    out->qxx = out->a[0][0] * out->a[0][0] + out->a[0][1] * out->a[0][1];
    out->qxy = out->a[0][0] * out->a[1][0] + out->a[0][1] * out->a[1][1];
    out->qyy = out->a[1][0] * out->a[1][0] + out->a[1][1] * out->a[1][1];
    out->smax = (1.0 + g) * n;
    out->smin = (1.0 - g) * n;
    return WF_OK;
}

wf_status wf_profile_hlr_from_fwhm(int sersic_n, double fwhm, double *hlr)
{
    if (!(fwhm > 0.0) || !isfinite(fwhm))
        return wf_error(WF_ERR_RANGE, "profile: FWHM %g is not a positive size", fwhm);
    const wf_sersic_table *t = wf_sersic4_table();
    /* I(r) = exp(-b (r / hlr)^(1/n)) is at half its peak where b (r / hlr)^(1/n) = ln 2 */
    if (sersic_n == 1) *hlr = 0.5 * fwhm * t->b1 / M_LN2;
    else if (sersic_n == 4) *hlr = 0.5 * fwhm * pow(t->b / M_LN2, 4.0);
    else return wf_error(WF_ERR_RANGE, "profile: Sersic index %d (only 1 and 4)", sersic_n);
    return WF_OK;
}

wf_status wf_profile_enclosed(int sersic_n, double hlr, double r, double *fraction)
{
    if (sersic_n != 1 && sersic_n != 4)
        return wf_error(WF_ERR_RANGE, "profile: Sersic index %d (only 1 and 4)", sersic_n);
    if (!(hlr > 0.0) || !(r >= 0.0))
        return wf_error(WF_ERR_RANGE, "profile: enclosed light of hlr %g within %g", hlr, r);
    const wf_sersic_table *t = wf_sersic4_table();
    if (sersic_n == 1) {
        double x = r / hlr * t->b1;
        *fraction = x < INFINITY ? -expm1(-x) - x * exp(-x) : 1.0;
    } else {
        *fraction = wf_gamma_p_int(8, t->b * pow(r / hlr, 0.25));
    }
    return WF_OK;
}

double wf_bessel_i0(double x)
{
    /* the power series: every term positive, so no cancellation at any x */
    double q = 0.25 * x * x, term = 1.0, sum = 1.0;
    for (int k = 1; k < 500 && term > 1e-18 * sum; k++) {
        term *= q / ((double)k * k);
        sum += term;
    }
    return sum;
}

double wf_knot_kernel(double s, int w, double beta)
{
    double t = 2.0 * s / w, t2 = 1.0 - t * t;
    return t2 > 0.0 ? wf_bessel_i0(beta * sqrt(t2)) - 1.0 : 0.0;
}

double wf_knot_kernel_ft(double a, double beta)
{
    double z = sqrt((beta - a) * (beta + a));
    double sinc = fabs(a) < 1e-4 ? 1.0 - a * a / 6.0 : sin(a) / a;
    return sinh(z) / z - sinc;
}
