/* Row-at-a-time noise for the readout's hot loop: the same Philox blocks and normals as the
 * scalar stream API (hal/noise.c), computed for a run of consecutive pixels so that the
 * compiler can spread the lanes over SIMD registers. Clones for AVX-512, AVX2 and baseline
 * x86-64 are picked at load time; every clone gives the same bits (integer arithmetic, and
 * for the normals the same double-precision formula, rounded to float). */
#pragma GCC optimize("O3")
#include "hal/noise.h"
#include "hal/philox.h"

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_ADDRESS__)
#define WF_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define WF_CLONES
#endif

WF_CLONES
void wf_noise_block_row(const wf_noise *noise, uint32_t pixel0, int n, uint32_t read,
                        wf_purpose purpose, uint32_t block, uint32_t *w0, uint32_t *w1,
                        uint32_t *w2, uint32_t *w3)
{
    const uint32_t key0 = (uint32_t)noise->seed, key1 = (uint32_t)(noise->seed >> 32);
    const uint32_t c2in = noise->exposure;
    const uint32_t c3in = ((noise->sca & 0xffu) << 24) | (((uint32_t)purpose & 0xffu) << 16) |
                          (block & 0xffffu);
    for (int i = 0; i < n; i++) {
        uint32_t c0 = pixel0 + (uint32_t)i, c1 = read, c2 = c2in, c3 = c3in;
        wf_philox_rounds(&c0, &c1, &c2, &c3, key0, key1);
        w0[i] = c0;
        w1[i] = c1;
        w2[i] = c2;
        w3[i] = c3;
    }
}

WF_CLONES
void wf_norm_from_u32(const uint32_t *w, int n, float *out)
{
    /* central region of the rational approximation, branch-free so it vectorises */
    const double a0 = -3.969683028665376e+01, a1 = 2.209460984245205e+02,
                 a2 = -2.759285104469687e+02, a3 = 1.383577518672690e+02,
                 a4 = -3.066479806614716e+01, a5 = 2.506628277459239e+00;
    const double b0 = -5.447609879822406e+01, b1 = 1.615858368580409e+02,
                 b2 = -1.556989798598866e+02, b3 = 6.680131188771972e+01,
                 b4 = -1.328068155288572e+01;
    for (int i = 0; i < n; i++) {
        double p = ((double)w[i] + 0.5) * (1.0 / 4294967296.0);
        double q = p - 0.5, r = q * q;
        double num = (((((a0 * r + a1) * r + a2) * r + a3) * r + a4) * r + a5) * q;
        double den = ((((b0 * r + b1) * r + b2) * r + b3) * r + b4) * r + 1.0;
        out[i] = (float)(num / den);
    }
    /* the tails (p < 0.02425 or p > 0.97575, ~5% of words) take the scalar path */
    const uint32_t lo = 104152845u, hi = 4294967295u - 104152845u; /* 0.02425 * 2^32 */
    for (int i = 0; i < n; i++)
        if (w[i] < lo || w[i] > hi)
            out[i] = (float)wf_norm_ppf(((double)w[i] + 0.5) * (1.0 / 4294967296.0));
}
