#include "sim/numeric/trig.h"

#include <math.h>

#include "hal/simd.h"

#define ROUNDER 0x1.8p52 /* (v + ROUNDER) - ROUNDER rounds v to an integer, |v| < 2^51 */

/* cos t, sin t for |t| <= pi/4 (a hair more at the rounding ties), turned by q quarter turns
 * (q = 0..3): a quarter turn maps (c, s) to (-s, c). */
static inline void quarter(double t, int q, double *c, double *s)
{
    double t2 = t * t;
    double sn = t + t * t2 * (-1.0 / 6 + t2 * (1.0 / 120 + t2 * (-1.0 / 5040 + t2 * (1.0 / 362880 + t2 * (-1.0 / 39916800 + t2 * (1.0 / 6227020800.0 + t2 * (-1.0 / 1307674368000.0 + t2 * (1.0 / 355687428096000.0))))))));
    double cs = 1.0 + t2 * (-0.5 + t2 * (1.0 / 24 + t2 * (-1.0 / 720 + t2 * (1.0 / 40320 + t2 * (-1.0 / 3628800 + t2 * (1.0 / 479001600 + t2 * (-1.0 / 87178291200.0 + t2 * (1.0 / 20922789888000.0 + t2 * (-1.0 / 6402373705728000.0)))))))));
    double cq = q & 1 ? -sn : cs, sq = q & 1 ? cs : sn;
    double sign = q & 2 ? -1.0 : 1.0;
    *c = sign * cq;
    *s = sign * sq;
}

/* f = u - round(u) and f - q/4 have no rounding: each pair is within a factor 2 of each
 * other (Sterbenz), or the subtrahend is 0. */
WF_CLONES void wf_trig_sincos_turns(const double *u, int n, double *c, double *s)
{
    for (int i = 0; i < n; i++) {
        double f = u[i] - ((u[i] + ROUNDER) - ROUNDER);
        double q = (4.0 * f + ROUNDER) - ROUNDER; /* -2 .. 2; NaN for NaN or infinite u */
        int qi = q >= -2.0 && q <= 2.0 ? (int)q : 0; /* no conversion of a NaN: NaN comes out */
        quarter((f - 0.25 * q) * (2.0 * M_PI), qi & 3, &c[i], &s[i]);
    }
}

/* pi/2 = P1 + P2 + P3 with P1 (31 bits) and P2 (32 bits) short enough that k P1 and k P2 are
 * exact for |k| < 2^21: the reduced argument then loses nothing to the subtraction. */
#define P1 0x1.921fb544p+0
#define P2 0x1.0b4611a6p-34
#define P3 0x1.3198a2e037073p-69
#define TWO_OVER_PI 0x1.45f306dc9c883p-1
#define REDUCE_MAX 0x1.921fb54442d18p+20 /* 2^20 pi/2 */

WF_CLONES void wf_trig_sincos(const double *x, int n, double *c, double *s)
{
    int far = 0;
    for (int i = 0; i < n; i++) {
        double v = x[i];
        int ok = fabs(v) < REDUCE_MAX; /* false for NaN */
        far |= !ok;
        v = ok ? v : 0.0;
        double k = (v * TWO_OVER_PI + ROUNDER) - ROUNDER;
        quarter(((v - k * P1) - k * P2) - k * P3, (int)k & 3, &c[i], &s[i]);
    }
    if (far)
        for (int i = 0; i < n; i++)
            if (!(fabs(x[i]) < REDUCE_MAX)) {
                c[i] = cos(x[i]);
                s[i] = sin(x[i]);
            }
}
