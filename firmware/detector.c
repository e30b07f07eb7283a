/* The row functions are the readout's hot loops: O3 and SIMD clones so they vectorise, and
 * no-trapping-math so that a select may compute both sides. No clone changes a bit: -std=c11
 * keeps floating-point contraction off and nothing here reassociates, so every lane does the
 * scalar operations in the same order. */
#pragma GCC optimize("O3", "no-trapping-math")
#include "firmware/detector.h"

#include <math.h>
#include <string.h>

#include "hal/simd.h"
#include "hal/vmath.h"

/* SPEC §2 (GalSim ipc_kernel), before normalisation. */
static const double ipc_raw[3][3] = {{0.001269938, 0.015399776, 0.001199862},
                                     {0.013800177, 1.0, 0.015600367},
                                     {0.001270391, 0.016129619, 0.001200137}};

void wf_detector_ipc_default(double out[3][3])
{
    double sum = 0.0;
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) sum += ipc_raw[a][b];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) out[a][b] = ipc_raw[a][b] / sum;
}

void wf_detector_defaults(wf_detector *det)
{
    memset(det, 0, sizeof *det);
    det->on.photon_noise = det->on.reciprocity = det->on.dark = det->on.nonlinearity = 1;
    det->on.ipc = det->on.read_noise = det->on.quantize = det->on.saturation = 1;
    det->on.cosmic_rays = 1;
    det->dark_current = 0.015;
    det->read_noise_e = 8.5;
    det->gain = 1.0;
    det->nl_beta = -6.0e-7;
    det->recip_alpha = 0.0065;
    det->recip_f0 = 1.0;
    wf_detector_ipc_default(det->ipc);
    det->full_well = 1.0e5;
    det->adc_max = 65535.0;
    det->bias_adu = 1000.0;
    det->cr_rate = 8.0;
    det->pixel_um = 10.0;
    det->depth_um = 5.0;
    det->cr_lmin_um = 10.0;
    det->cr_lmax_um = 2000.0;
    det->cr_slope = -4.33;
    det->cr_dedx_loc = 120.0;
    det->cr_dedx_scale = 50.0;
    det->cr_ev_per_e = 3.8; /* romanisim cr.py "gain" of 3.8 eV per count */
    det->rn1f_corr_e = 3.0;
    det->rn1f_uncorr_e = 1.0;
    det->channel_offset_adu = 20.0;
}

/* x (x / x0)^a, x <= 0 (and NaN) as it is, by hal/vmath.h's log and exp (within a few ulp of
 * pow's), so that a row of it vectorises: libm's pow and exp were 3% of an up-the-ramp
 * product, once a pixel each. The charge form and the rate form are this one law. */
static inline double recip_rate_lane(double x, double a, double x0)
{
    return x > 0.0 ? x * wf_vexp(a * wf_vlog(x / x0)) : x;
}

double wf_det_reciprocity(double q, double exptime, double alpha, double f0)
{
    return recip_rate_lane(q, alpha / M_LN10, exptime * f0);
}

double wf_det_reciprocity_rate(double rate, double alpha, double f0)
{
    return recip_rate_lane(rate, alpha / M_LN10, f0);
}

WF_CLONES
void wf_det_expected_row(const wf_detector *det, const float *rate, int n, double frame_time, double *mean,
                         double *expm)
{
    const int recip = det->on.reciprocity;
    const double a = det->recip_alpha / M_LN10, f0 = det->recip_f0;
    const double dark = det->on.dark ? det->dark_current : 0.0; /* r + 0 is r: r >= 0 */
    for (int i = 0; i < n; i++) {
        const double r = rate[i] > 0.0f ? (double)rate[i] : 0.0;
        const double m = ((recip ? recip_rate_lane(r, a, f0) : r) + dark) * frame_time;
        mean[i] = m;
        expm[i] = wf_vexp(-m);
    }
}

WF_CLONES
void wf_det_ipc_row(const double *above, const double *row, const double *below, int ncols,
                    const double k[3][3], double *out)
{
    const double *in[3] = {above, row, below};
    if (ncols <= 0)
        return; /* the edge terms below would touch out[0], out[-1] and r[1] */
    if (above && below && ncols >= 3) {
        /* one pass, summed in the order of the three passes below (0 + row above + row +
         * row below), so the bits are theirs */
        const double a0 = k[0][0], a1 = k[0][1], a2 = k[0][2], b0 = k[1][0], b1 = k[1][1],
                     b2 = k[1][2], c0 = k[2][0], c1 = k[2][1], c2 = k[2][2];
        const double *u = above, *m = row, *d = below;
        for (int x = 1; x < ncols - 1; x++)
            out[x] = ((0.0 + (a0 * u[x - 1] + a1 * u[x] + a2 * u[x + 1])) +
                      (b0 * m[x - 1] + b1 * m[x] + b2 * m[x + 1])) +
                     (c0 * d[x - 1] + c1 * d[x] + c2 * d[x + 1]);
        const int e = ncols - 1;
        out[0] = ((0.0 + (a1 * u[0] + a2 * u[1])) + (b1 * m[0] + b2 * m[1])) + (c1 * d[0] + c2 * d[1]);
        out[e] = ((0.0 + (a0 * u[e - 1] + a1 * u[e])) + (b0 * m[e - 1] + b1 * m[e])) +
                 (c0 * d[e - 1] + c1 * d[e]);
        return;
    }
    for (int x = 0; x < ncols; x++) out[x] = 0.0;
    for (int a = 0; a < 3; a++) {
        const double *r = in[a];
        if (!r) continue;
        const double k0 = k[a][0], k1 = k[a][1], k2 = k[a][2];
        /* interior: all three columns exist */
        for (int x = 1; x < ncols - 1; x++)
            out[x] += k0 * r[x - 1] + k1 * r[x] + k2 * r[x + 1];
        if (ncols == 1) {
            out[0] += k1 * r[0];
            continue;
        }
        out[0] += k1 * r[0] + k2 * r[1];
        out[ncols - 1] += k0 * r[ncols - 2] + k1 * r[ncols - 1];
    }
}

/* held: where q is held at the full well too (q itself, or NULL) */
static inline __attribute__((always_inline)) void measure_body(const wf_detector *det, const double *q,
                                                               double *held, int n, double *out)
{
    const double fw = det->full_well, beta = det->nl_beta;
    const int sat = det->on.saturation, nl = det->on.nonlinearity;
    for (int i = 0; i < n; i++) {
        double v = q[i];
        if (sat) v = v > fw ? fw : v;
        if (sat && held) held[i] = v;
        if (nl) v = wf_det_nonlinearity(v, beta);
        out[i] = v;
    }
}

WF_CLONES
void wf_det_measure_row(const wf_detector *det, const double *q, int n, double *out)
{
    measure_body(det, q, NULL, n, out);
}

WF_CLONES
void wf_det_hold_measure_row(const wf_detector *det, double *restrict q, int n, double *restrict out)
{
    measure_body(det, q, q, n, out);
}

WF_CLONES
int wf_det_first_nonfinite(const float *v, int n)
{
    int bad = 0;
    for (int i = 0; i < n; i++) { /* no early exit, so that it vectorises: all finite is the rule */
        uint32_t u;
        memcpy(&u, &v[i], sizeof u);
        bad |= (u & 0x7f800000u) == 0x7f800000u;
    }
    if (!bad) return -1;
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) return i;
    return -1;
}

WF_CLONES
void wf_det_exposure_row(const float *rate, double exptime, int n, double *e)
{
    for (int i = 0; i < n; i++) e[i] = rate[i] > 0.0f ? rate[i] * exptime : 0.0;
}

WF_CLONES
void wf_det_reciprocity_counts(const wf_detector *det, double exptime, const double *restrict table,
                               int ntable, const double *restrict add, int n, double *restrict q)
{
    const double top = (double)(ntable - 1);
    int beyond = 0;
    for (int i = 0; i < n; i++) beyond |= !(q[i] >= 0.0 && q[i] <= top);
    if (beyond) { /* a bright star in the row: the row goes one pixel at a time */
        for (int i = 0; i < n; i++) {
            double r = q[i] >= 0.0 && q[i] <= top
                           ? table[(int)q[i]]
                           : wf_det_reciprocity(q[i], exptime, det->recip_alpha, det->recip_f0);
            q[i] = add ? r + add[i] : r;
        }
        return;
    }
    if (add)
        for (int i = 0; i < n; i++) q[i] = table[(int)q[i]] + add[i];
    else
        for (int i = 0; i < n; i++) q[i] = table[(int)q[i]];
}

/* The electronics after the charge, per pixel, shared by the single-frame and the ramp's
 * rows: read noise, gain, bias, rounding (as wf_det_quantize, by adding and removing
 * 1.5 * 2^52, which GCC never folds unless told -fassociative-math: SSE2's default clone has
 * no rounding instruction, and a select keeps the row branch-free),
 * the ADC's [0, adc_max]; *clipped where the full well (q) or the ceiling was reached
 * (saturation on). The detector's numbers come in a local copy, so the loops' stores cannot
 * alias them and they vectorise. */
typedef struct adc_par {
    double sigma, gain, bias, fw, adc;
    int rn, quant, satur;
} adc_par;

static adc_par adc_par_of(const wf_detector *det)
{
    return (adc_par){det->read_noise_e, det->gain, det->bias_adu, det->full_well, det->adc_max,
                     det->on.read_noise, det->on.quantize, det->on.saturation};
}

static inline __attribute__((always_inline)) double adc_lane(const adc_par *p, double v, double q,
                                                             float z, int unit_gain, uint8_t *clipped)
{
    const double magic = 6755399441055744.0, big = 2251799813685248.0; /* 1.5 * 2^52, 2^51 */
    if (p->rn) v += p->sigma * (double)z;
    double adu = (unit_gain ? v : v / p->gain) + p->bias;
    if (p->quant) {
        double r = __builtin_copysign((adu + magic) - magic, adu);
        adu = (adu > -big) & (adu < big) ? r : adu;
    }
    *clipped = 0;
    if (p->satur) {
        *clipped = (uint8_t)((q >= p->fw) | (adu >= p->adc));
        adu = adu >= p->adc ? p->adc : adu;
        adu = adu < 0.0 ? 0.0 : adu;
    }
    return adu;
}

/* The body of wf_det_single_row with the unit gain known at compile time: v / 1.0 is v, so
 * the division (the loop's costliest step) goes without changing a bit. */
static inline __attribute__((always_inline)) void single_row_body(
    const wf_detector *det, const double *restrict e, const double *restrict q,
    const float *restrict z, int n, float *restrict out, uint8_t *restrict sat, int unit_gain)
{
    const adc_par p = adc_par_of(det);
    for (int i = 0; i < n; i++) {
        uint8_t clipped;
        double adu = adc_lane(&p, e[i], q[i], z[i], unit_gain, &clipped);
        /* a mask, not a select: a select on the 8-bit store stops the vectoriser */
        if (p.satur) sat[i] = (uint8_t)(sat[i] & (uint8_t)(clipped - 1u));
        out[i] = (float)adu;
    }
}

WF_CLONES
void wf_det_single_row(const wf_detector *det, const double *e, const double *q,
                       const float *z, int n, float *out, uint8_t *sat)
{
    if (det->gain == 1.0)
        single_row_body(det, e, q, z, n, out, sat, 1);
    else
        single_row_body(det, e, q, z, n, out, sat, 0);
}

static inline __attribute__((always_inline)) void ramp_read_body(
    const wf_detector *det, const double *restrict e, const double *restrict q,
    const float *restrict z, int n, uint8_t r, double *restrict sum, uint8_t *restrict first,
    int unit_gain)
{
    const adc_par p = adc_par_of(det);
    for (int i = 0; i < n; i++) {
        uint8_t clipped;
        double adu = adc_lane(&p, e[i], q[i], z[i], unit_gain, &clipped);
        /* first[i] is 255 or an earlier resultant (the reads come in order), so the first
         * one keeps the min; a mask, not a select, as single_row_body */
        uint8_t cand = (uint8_t)(r | (uint8_t)(clipped - 1u)); /* r, else 255 */
        if (p.satur) first[i] = first[i] < cand ? first[i] : cand;
        sum[i] += adu;
    }
}

WF_CLONES
void wf_det_ramp_read_row(const wf_detector *det, const double *e, const double *q,
                          const float *z, int n, uint8_t r, double *sum, uint8_t *first_sat)
{
    if (det->gain == 1.0)
        ramp_read_body(det, e, q, z, n, r, sum, first_sat, 1);
    else
        ramp_read_body(det, e, q, z, n, r, sum, first_sat, 0);
}

/* A whole ADU value (or NaN, or beyond 2^51) to the 16-bit word: into [0, 65535], NaN to 0 */
static inline __attribute__((always_inline)) uint16_t u16_whole_lane(double v)
{
    v = v >= 0.0 ? v : 0.0; /* NaN too */
    v = v > 65535.0 ? 65535.0 : v;
    return (uint16_t)v;
}

/* ADU to the 16-bit word: rounded half to even into [0, 65535], NaN to 0 */
static inline __attribute__((always_inline)) uint16_t u16_lane(double v)
{
    const double magic = 6755399441055744.0, big = 2251799813685248.0;
    double rr = __builtin_copysign((v + magic) - magic, v); /* nearbyint, half to even */
    return u16_whole_lane((v > -big) & (v < big) ? rr : v);
}

WF_CLONES
void wf_det_resultant_row(double *sum, int n, int nreads, uint16_t *out)
{
    for (int i = 0; i < n; i++) {
        out[i] = u16_lane(sum[i] / nreads);
        sum[i] = 0.0;
    }
}

/* Whether a group's last read, its charge q clipped at the well and made nonlinear (beta 0
 * without nonlinearity), reaches the ADC's ceiling. */
static inline __attribute__((always_inline)) int last_at_ceiling(const adc_par *p, double beta, double q)
{
    double last = q < p->fw ? q : p->fw;
    last = last + beta * last * last;
    return last / p->gain + p->bias >= p->adc;
}

static inline __attribute__((always_inline)) void group_row_body(
    const wf_detector *det, const double *restrict e, const double *restrict q,
    const float *restrict z, int n, int nreads, uint8_t r, uint8_t *restrict first,
    uint16_t *restrict out, int unit_gain)
{
    adc_par p = adc_par_of(det);
    p.sigma = det->read_noise_e / sqrt((double)nreads);
    /* 0 without nonlinearity: last + 0 last^2 is last (last <= fw is never +inf) */
    const double beta = det->on.nonlinearity ? det->nl_beta : 0.0;
    /* two passes, the flags and the words, as each vectorises alone and together do not.
     * The flags' pass only where a pixel of the row could clip: a charge at the well or whose
     * last read reaches the ceiling (as below), or a signal within the read noise's reach of
     * it. A normal from a 32-bit word is below 6.37 (a larger z, from elsewhere, counts as
     * a clip), and rounding adds at most 1/2, so e < (adc - bias - 1) gain - 6.5 sigma keeps
     * adu below adc - 1/2. Most rows hold no such pixel, and this check is half the pass. */
    int maybe = 0;
    if (p.satur) {
        const double ethr = (p.adc - p.bias - 1.0) * p.gain - (p.rn ? p.sigma * 6.5 : 0.0);
        for (int i = 0; i < n; i++)
            maybe |= (q[i] >= p.fw) | last_at_ceiling(&p, beta, q[i]) | (e[i] >= ethr) | (z[i] > 6.5f);
    }
    if (maybe)
        for (int i = 0; i < n; i++) {
            /* a charge whose last read reaches the ceiling counts as the full well's */
            const double qs = last_at_ceiling(&p, beta, q[i]) ? p.fw : q[i];
            uint8_t clipped;
            (void)adc_lane(&p, e[i], qs, z[i], unit_gain, &clipped);
            uint8_t cand = (uint8_t)(r | (uint8_t)(clipped - 1u)); /* r, else 255 */
            first[i] = first[i] < cand ? first[i] : cand;
        }
    /* adc_lane rounded, and clipped at a whole ceiling: u16_lane's rounding would give each
     * value back (a ceiling with a fraction, which the config allows, is rounded there) */
    if (p.quant && (!p.satur || floor(p.adc) == p.adc))
        for (int i = 0; i < n; i++) {
            uint8_t clipped;
            out[i] = u16_whole_lane(adc_lane(&p, e[i], q[i], z[i], unit_gain, &clipped));
        }
    else
        for (int i = 0; i < n; i++) {
            uint8_t clipped;
            out[i] = u16_lane(adc_lane(&p, e[i], q[i], z[i], unit_gain, &clipped));
        }
}

WF_CLONES
void wf_det_group_row(const wf_detector *det, const double *e, const double *q, const float *z,
                      int n, int nreads, uint8_t r, uint8_t *first_sat, uint16_t *out)
{
    if (det->gain == 1.0)
        group_row_body(det, e, q, z, n, nreads, r, first_sat, out, 1);
    else
        group_row_body(det, e, q, z, n, nreads, r, first_sat, out, 0);
}

double wf_det_saturation_adu(const wf_detector *det)
{
    double fw = det->full_well;
    if (det->on.nonlinearity) fw = wf_det_nonlinearity(fw, det->nl_beta);
    double adu = fw / det->gain + det->bias_adu;
    return adu < det->adc_max ? adu : det->adc_max;
}
