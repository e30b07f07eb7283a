/* Internals shared by sim/draw/profile*.c; not part of the public interface (sim/draw/profile.h). */
#ifndef WF_PROFILE_INT_H
#define WF_PROFILE_INT_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "hal/status.h"

/* The de Vaucouleurs (Sersic n = 4) profile I(r) ~ exp(-b (r / Re)^(1/4)) has no closed-form
 * Fourier transform. F(q), q = k Re, normalised to F(0) = 1, is tabulated once against
 * w = q^2 (so that callers never take a square root): WF_SERSIC_SUB points per octave of w,
 * octaves 2^WF_SERSIC_EMIN .. 2^WF_SERSIC_EMAX, each row holding nodes i = -1 .. SUB + 1 at
 * w = 2^e (1 + i / SUB) so that a 4-point Lagrange interpolation never leaves its row.
 * Below the table 1 - F = w <r^2> / 4 (exact to 1e-12 there); above it the convergent
 * large-q series is summed directly (slow, reached only by extreme no-PSF draws). */
#define WF_SERSIC_SUB 16
#define WF_SERSIC_EMIN (-26)
#define WF_SERSIC_EMAX 40
#define WF_SERSIC_ROW (WF_SERSIC_SUB + 3)

typedef struct wf_sersic_table {
    double b;        /* exp(-b (r/Re)^(1/4)) holds half the light inside Re */
    double b1;       /* the same for n = 1: half-light radius / scale radius of exp(-r/r0) */
    double dev_norm; /* unit-flux surface brightness at r = 0 times Re^2: b^8 / (8 pi 7!) */
    double r2;       /* <r^2> / Re^2 of the untruncated profile */
    double v[(WF_SERSIC_EMAX - WF_SERSIC_EMIN) * WF_SERSIC_ROW];
} wf_sersic_table;

/* Built once per process (about 10 ms) and read-only afterwards; thread-safe. */
const wf_sersic_table *wf_sersic4_table(void);

/* F(q) from the numerical Hankel transform (slow; used to build and to check the table). */
double wf_sersic4_hankel_direct(double q);
/* F(q) from the large-q series (converges for all q > 0 but loses digits below q ~ 3). */
double wf_sersic4_hankel_series(double q);
double wf_sersic4_eval_slow(const wf_sersic_table *t, double w);

/* F at w = (k Re)^2. */
static inline double wf_sersic4_eval(const wf_sersic_table *t, double w)
{
    uint64_t bits;
    memcpy(&bits, &w, sizeof bits);
    int e = (int)((bits >> 52) & 0x7ff) - 1023;
    if (e < WF_SERSIC_EMIN || e >= WF_SERSIC_EMAX) return wf_sersic4_eval_slow(t, w);
    double m = (double)(bits & 0xfffffffffffffull) * (WF_SERSIC_SUB / 4503599627370496.0);
    int i = (int)m;
    double f = m - i;
    const double *c = t->v + (size_t)(e - WF_SERSIC_EMIN) * WF_SERSIC_ROW + i; /* node i-1 */
    double fm1 = f - 1.0, fm2 = f - 2.0, fp1 = f + 1.0;
    return (-c[0] * f * fm1 * fm2 + c[3] * fp1 * f * fm1) * (1.0 / 6.0) +
           (c[1] * fp1 * fm1 * fm2 - c[2] * fp1 * f * fm2) * 0.5;
}

/* PSF transforms are cut at 8 pixel Nyquist frequencies (8 pi / p): the optical cut-off
 * 2 pi D / lambda stays below it for every lambda > 0.3 um. */
#define WF_PSF_BAND_NYQ 8.0

struct wf_profile_accuracy;
/* The FFT sides a drawing work uses (2^k and 3 2^k from min_fft to max_fft), ascending: up
 * to cap of them into sizes; returns the count. */
int wf_profile_fft_ladder(const struct wf_profile_accuracy *acc, int *sizes, int cap);

/* WF_OK when the knobs are in range, else an error naming the first one out of range. */
wf_status wf_profile_check_accuracy(const struct wf_profile_accuracy *acc);

/* Geometry of a sheared, rotated profile: x_sky = A x_round, A = R(rotation) S(g), with
 * GalSim's area-preserving shear S = [[1 + g1, g2], [g2, 1 - g1]] / sqrt(1 - g^2). The
 * transform of the sheared profile at k is the round one's at A^T k, |A^T k|^2 = k^T Q k. */
typedef struct wf_shape {
    double a[2][2];
    double ainv[2][2];
    double qxx, qxy, qyy; /* Q = A A^T */
    double smax, smin;    /* singular values of A: (1 +- |g|) / sqrt(1 - g^2) */
} wf_shape;

wf_status wf_profile_shape(double e1, double e2, double rotation, wf_shape *out);

/* Knots in Fourier space (sim/draw/profile.c). The direct sum costs one complex multiply-add per
 * knot and Fourier sample. The lattice method sums the knots only on a coarse lattice
 * (every r-th sample per axis, which still resolves their transform because they occupy a
 * small part of the FFT box) and interpolates the fine samples with a compact kernel
 * (w taps per axis); each knot's weight is divided by the kernel's transform at its
 * position, which makes the interpolation exact up to the kernel's aliasing, ~1e-9 of a
 * stamp's peak (tests/test_profile.c bounds it against the direct sum). AUTO takes the
 * lattice, with the few farthest knots summed directly, wherever that costs less; DIRECT
 * is the reference; LATTICE puts every knot on it (when the work's buffers hold it). Each
 * draw records what it did in work->knot_last. */
enum { WF_KNOTS_AUTO, WF_KNOTS_DIRECT, WF_KNOTS_LATTICE };
struct wf_profile_work;
void wf_profile_knot_method(struct wf_profile_work *work, int method);

/* The Fourier-space draw's per-sample kernels come in scalar, 2-, 4- (AVX2) and 8-lane
 * (AVX-512) versions which give the same bits (lanes never mix, no fused multiply-adds);
 * the widest the CPU has is taken. This selects at most `lanes` (< 0: only reports) and
 * returns the lanes in use. For tests and benchmarks: not to be called while drawing. */
int wf_profile_simd(int lanes);

/* Phase lines: e^{-i u theta} (-1)^u (alt) or e^{-i u theta} for u = lo .. hi into
 * re[(u - lo) st] and im[(u - lo) st], for n lines at once, line j (theta[j]) at re0 + j line
 * and its imaginary parts imoff further on. Re-anchored every 32 steps, so that the
 * recurrence's rounding stays ~1e-15. */
void wf_profile_phase_lines(int n, const double *theta, int lo, int hi, double *re0, size_t line,
                            size_t imoff, size_t st, int alt);

/* The lattice kernel psi(s) = I0(beta sqrt(1 - (2 s / w)^2)) - 1 on |s| <= w / 2 (zero at
 * the ends, so its transform falls as 1/x^2), and that transform over w Delta:
 * sinh(z) / z - sin(a) / a, z = sqrt(beta^2 - a^2), valid for |a| < beta. */
double wf_bessel_i0(double x);
double wf_knot_kernel(double s, int w, double beta);
double wf_knot_kernel_ft(double a, double beta);

#endif
