/* Branch-free log and exp for hot loops: only +, -, *, / and bit moves on 64-bit lanes, so
 * that a loop calling them vectorises (libm's are calls) and every SIMD clone gives the same
 * bits (hal/simd.h). Inputs outside a function's stated range give values the callers mask
 * out, never a trap. */
#ifndef WF_HAL_VMATH_H
#define WF_HAL_VMATH_H

#include <stdint.h>
#include <string.h>

#define WF_VMATH static inline __attribute__((always_inline))

/* ln 2 in two parts (fdlibm's): ln2_hi's low bits are zero, so k ln2_hi is exact for |k| < 2^11 */
#define WF_LN2_HI 6.93147180369123816490e-01
#define WF_LN2_LO 1.90821492927058770002e-10

WF_VMATH uint64_t wf_bits_of(double x)
{
    uint64_t u;
    memcpy(&u, &x, sizeof u);
    return u;
}

WF_VMATH double wf_double_of(uint64_t u)
{
    double x;
    memcpy(&x, &u, sizeof x);
    return x;
}

/* log(x) for finite x > 0, fdlibm's e_log.c algorithm (error < 1 ulp) without its branches
 * for special inputs: x = z 2^e with z in [sqrt(2)/2, sqrt(2)), then log(z) from
 * s = (z-1)/(z+1). No int64 to double conversion, which AVX2 lacks. Zero, negative,
 * subnormal and non-finite x give values the callers mask out. */
WF_VMATH double wf_vlog(double x)
{
    const double Lg1 = 6.666666666666735130e-01, Lg2 = 3.999999999940941908e-01,
                 Lg3 = 2.857142874366239149e-01, Lg4 = 2.222219843214978396e-01,
                 Lg5 = 1.818357216161805012e-01, Lg6 = 1.531383769920937332e-01,
                 Lg7 = 1.479819860511658591e-01;
    const uint64_t off = 0x3fe6a09e667f3bcdull; /* sqrt(2)/2 */
    uint64_t ix = wf_bits_of(x), tmp = ix - off;
    /* the exponent e, a signed 12-bit field, as a double: offset binary in a 2^52 mantissa */
    double dk = wf_double_of(0x4330000000000000ull | ((tmp >> 52) ^ 0x800u)) - 4503599627372544.0;
    double z = wf_double_of(ix - (tmp & 0xfff0000000000000ull));
    double f = z - 1.0, hfsq = 0.5 * f * f, s = f / (2.0 + f), s2 = s * s, w = s2 * s2;
    double t1 = w * (Lg2 + w * (Lg4 + w * Lg6));
    double t2 = s2 * (Lg1 + w * (Lg3 + w * (Lg5 + w * Lg7)));
    return s * (hfsq + (t1 + t2)) + dk * WF_LN2_LO - hfsq + f + dk * WF_LN2_HI;
}

/* exp(x), within 2 ulp, for x in [-708, 709]; below -708 it gives 0 (libm's are subnormals
 * there), above 709 the value at 709. x = k ln2 + r, |r| <= ln2/2, exp(r) by its Taylor series
 * to r^13 (the next term is below 1e-17 of the sum), 2^k put in the exponent's bits. */
WF_VMATH double wf_vexp(double x)
{
    const double magic = 6755399441055744.0; /* 1.5 * 2^52: k lands in the low mantissa bits */
    const double xc = x < -708.0 ? -708.0 : x > 709.0 ? 709.0 : x;
    const double t = xc * 1.44269504088896338700 + magic, k = t - magic;
    const double r = (xc - k * WF_LN2_HI) - k * WF_LN2_LO;
    double p = 1.0 / 6227020800.0;
    p = p * r + 1.0 / 479001600.0;
    p = p * r + 1.0 / 39916800.0;
    p = p * r + 1.0 / 3628800.0;
    p = p * r + 1.0 / 362880.0;
    p = p * r + 1.0 / 40320.0;
    p = p * r + 1.0 / 5040.0;
    p = p * r + 1.0 / 720.0;
    p = p * r + 1.0 / 120.0;
    p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0;
    p = p * r + 0.5;
    p = p * r * r + r; /* exp(r) - 1, its small part kept apart from the 1 */
    const double scale = wf_double_of((wf_bits_of(t) + 1023u) << 52);
    const double e = (1.0 + p) * scale;
    return x < -708.0 ? 0.0 : e;
}

#endif
