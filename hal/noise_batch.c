/* Row-at-a-time noise for the readout's hot loops: the same Philox blocks, normals and
 * Poisson draws as the scalar stream API (hal/noise.c), computed for a run of pixels so that
 * the lanes spread over SIMD registers. Clones (or hand-written variants) for AVX-512, AVX2
 * and baseline x86-64 are picked at run time; every one gives the same bits (integer
 * arithmetic, and IEEE double operations in the same order: -std=c11 keeps contraction off).
 * no-trapping-math lets a select compute both of its sides; it changes no value. */
#pragma GCC optimize("O3", "no-trapping-math")
#include "hal/noise.h"
#include "hal/philox.h"

#include <math.h>
#include <string.h>

#include "hal/simd.h"
#include "hal/vmath.h"

/* ---- branch-free arithmetic for the row loops ------------------------------------------------
 * Every clone gives the same bits: IEEE +, -, *, /, sqrt only, no contraction under -std=c11,
 * no reassociation, no libm inside the loops. */

#define WF_INLINE static inline __attribute__((always_inline))

/* out[i] = sqrt(max(in[i], lo)) (NaN in gives lo). A separate pass with intrinsics: under
 * -fmath-errno (the default, and `#pragma GCC optimize` cannot lift it) GCC guards every
 * sqrt with an errno branch, which keeps a loop that takes one from vectorising. Hardware
 * sqrt is correctly rounded, as libm's, so the bits do not depend on the variant. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_ADDRESS__)
#include <immintrin.h>
__attribute__((target("avx512f"))) static void sqrt_clamped_avx512(const double *in, double lo, int n, double *out)
{
    int i = 0;
    const __m512d l = _mm512_set1_pd(lo);
    for (; i + 8 <= n; i += 8) /* max_pd(x, lo) returns lo for NaN x */
        _mm512_storeu_pd(out + i, _mm512_sqrt_pd(_mm512_max_pd(_mm512_loadu_pd(in + i), l)));
    for (; i < n; i++) out[i] = sqrt(in[i] >= lo ? in[i] : lo);
}
__attribute__((target("avx2"))) static void sqrt_clamped_avx2(const double *in, double lo, int n, double *out)
{
    int i = 0;
    const __m256d l = _mm256_set1_pd(lo);
    for (; i + 4 <= n; i += 4)
        _mm256_storeu_pd(out + i, _mm256_sqrt_pd(_mm256_max_pd(_mm256_loadu_pd(in + i), l)));
    for (; i < n; i++) out[i] = sqrt(in[i] >= lo ? in[i] : lo);
}
static void sqrt_clamped(const double *in, double lo, int n, double *out)
{
    if (__builtin_cpu_supports("avx512f")) { sqrt_clamped_avx512(in, lo, n, out); return; }
    if (__builtin_cpu_supports("avx2")) { sqrt_clamped_avx2(in, lo, n, out); return; }
    int i = 0;
    const __m128d l = _mm_set1_pd(lo);
    for (; i + 2 <= n; i += 2) _mm_storeu_pd(out + i, _mm_sqrt_pd(_mm_max_pd(_mm_loadu_pd(in + i), l)));
    for (; i < n; i++) out[i] = sqrt(in[i] >= lo ? in[i] : lo);
}
#else
static void sqrt_clamped(const double *in, double lo, int n, double *out)
{
    for (int i = 0; i < n; i++) out[i] = sqrt(in[i] >= lo ? in[i] : lo);
}
#endif

/* floor(x), exactly, from the adding-and-removing 1.5 * 2^52 trick (round to nearest, then
 * one down where that went up): libm's floor is a call in the baseline target. */
WF_INLINE double vfloor(double x)
{
    const double magic = 6755399441055744.0, big = 2251799813685248.0; /* 1.5 * 2^52, 2^51 */
    double r = (x + magic) - magic;
    r = r > x ? r - 1.0 : r;
    return x > -big && x < big ? r : x; /* beyond 2^51 every double is whole */
}

/* log(1 + x) for x > -1 to full relative precision: the rounding of 1 + x is put back. */
WF_INLINE double vlog1p(double x)
{
    double u = 1.0 + x;
    return wf_vlog(u) - ((u - 1.0) - x) / u;
}

/* ---- Philox row batches --------------------------------------------------------------------- */

/* Philox4x32-10 on n counters {pixel, c1, c2, c3 + i step3}, pixel = pix[i] or, when pix is
 * NULL, pixel0 + i (step3 0) or pixel0 (step3 1: the lanes are one stream's blocks). The
 * SIMD variants keep 16 (8) 32-bit lanes in one register and take each
 * 32x32 -> 64-bit product as even lanes and odd lanes (vpmuludq), then blend the halves back:
 * the compiler's own vectorisation of wf_philox_rounds widens every lane to 64 bits and
 * spends more on shuffles than on the multiplies. Integer arithmetic: the same words as the
 * scalar rounds, whichever variant runs. */
static void philox_span_scalar(uint32_t key0, uint32_t key1, const uint32_t *pix, uint32_t pixel0,
                               uint32_t c1in, uint32_t c2in, uint32_t c3in, uint32_t step3, int i,
                               int n, uint32_t *w0, uint32_t *w1, uint32_t *w2, uint32_t *w3)
{
    for (; i < n; i++) {
        uint32_t c0 = pix ? pix[i] : pixel0 + (step3 ? 0u : (uint32_t)i), c1 = c1in, c2 = c2in,
                 c3 = c3in + step3 * (uint32_t)i;
        wf_philox_rounds(&c0, &c1, &c2, &c3, key0, key1);
        w0[i] = c0;
        w1[i] = c1;
        w2[i] = c2;
        w3[i] = c3;
    }
}

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_ADDRESS__)
#define WF_PHILOX_SIMD 1

__attribute__((target("avx512f")))
static void philox_span_avx512(uint32_t key0, uint32_t key1, const uint32_t *pix, uint32_t pixel0,
                               uint32_t c1in, uint32_t c2in, uint32_t c3in, uint32_t step3, int n,
                               uint32_t *w0, uint32_t *w1, uint32_t *w2, uint32_t *w3)
{
    const __m512i m0 = _mm512_set1_epi64(0xD2511F53), m1 = _mm512_set1_epi64(0xCD9E8D57);
    const __m512i lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    const __mmask16 odd = 0xAAAA;
    int i = 0;
    for (; i + 16 <= n; i += 16) {
        __m512i a = pix     ? _mm512_loadu_si512((const void *)(pix + i))
                    : step3 ? _mm512_set1_epi32((int)pixel0)
                            : _mm512_add_epi32(_mm512_set1_epi32((int)(pixel0 + (uint32_t)i)), lane);
        __m512i b = _mm512_set1_epi32((int)c1in), c = _mm512_set1_epi32((int)c2in),
                d = step3 ? _mm512_add_epi32(_mm512_set1_epi32((int)(c3in + (uint32_t)i)), lane)
                          : _mm512_set1_epi32((int)c3in);
        uint32_t k0 = key0, k1 = key1;
        for (int r = 0; r < 10; r++) {
            __m512i pe0 = _mm512_mul_epu32(a, m0), po0 = _mm512_mul_epu32(_mm512_srli_epi64(a, 32), m0);
            __m512i pe1 = _mm512_mul_epu32(c, m1), po1 = _mm512_mul_epu32(_mm512_srli_epi64(c, 32), m1);
            __m512i hi0 = _mm512_mask_blend_epi32(odd, _mm512_srli_epi64(pe0, 32), po0);
            __m512i lo0 = _mm512_mask_blend_epi32(odd, pe0, _mm512_slli_epi64(po0, 32));
            __m512i hi1 = _mm512_mask_blend_epi32(odd, _mm512_srli_epi64(pe1, 32), po1);
            __m512i lo1 = _mm512_mask_blend_epi32(odd, pe1, _mm512_slli_epi64(po1, 32));
            a = _mm512_xor_si512(_mm512_xor_si512(hi1, b), _mm512_set1_epi32((int)k0));
            c = _mm512_xor_si512(_mm512_xor_si512(hi0, d), _mm512_set1_epi32((int)k1));
            b = lo1;
            d = lo0;
            k0 += 0x9E3779B9u;
            k1 += 0xBB67AE85u;
        }
        _mm512_storeu_si512((void *)(w0 + i), a);
        _mm512_storeu_si512((void *)(w1 + i), b);
        _mm512_storeu_si512((void *)(w2 + i), c);
        _mm512_storeu_si512((void *)(w3 + i), d);
    }
    philox_span_scalar(key0, key1, pix, pixel0, c1in, c2in, c3in, step3, i, n, w0, w1, w2, w3);
}

__attribute__((target("avx2")))
static void philox_span_avx2(uint32_t key0, uint32_t key1, const uint32_t *pix, uint32_t pixel0,
                             uint32_t c1in, uint32_t c2in, uint32_t c3in, uint32_t step3, int n,
                             uint32_t *w0, uint32_t *w1, uint32_t *w2, uint32_t *w3)
{
    const __m256i m0 = _mm256_set1_epi64x(0xD2511F53), m1 = _mm256_set1_epi64x(0xCD9E8D57);
    const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    int i = 0;
    for (; i + 8 <= n; i += 8) {
        __m256i a = pix     ? _mm256_loadu_si256((const __m256i *)(pix + i))
                    : step3 ? _mm256_set1_epi32((int)pixel0)
                            : _mm256_add_epi32(_mm256_set1_epi32((int)(pixel0 + (uint32_t)i)), lane);
        __m256i b = _mm256_set1_epi32((int)c1in), c = _mm256_set1_epi32((int)c2in),
                d = step3 ? _mm256_add_epi32(_mm256_set1_epi32((int)(c3in + (uint32_t)i)), lane)
                          : _mm256_set1_epi32((int)c3in);
        uint32_t k0 = key0, k1 = key1;
        for (int r = 0; r < 10; r++) {
            __m256i pe0 = _mm256_mul_epu32(a, m0), po0 = _mm256_mul_epu32(_mm256_srli_epi64(a, 32), m0);
            __m256i pe1 = _mm256_mul_epu32(c, m1), po1 = _mm256_mul_epu32(_mm256_srli_epi64(c, 32), m1);
            __m256i hi0 = _mm256_blend_epi32(_mm256_srli_epi64(pe0, 32), po0, 0xAA);
            __m256i lo0 = _mm256_blend_epi32(pe0, _mm256_slli_epi64(po0, 32), 0xAA);
            __m256i hi1 = _mm256_blend_epi32(_mm256_srli_epi64(pe1, 32), po1, 0xAA);
            __m256i lo1 = _mm256_blend_epi32(pe1, _mm256_slli_epi64(po1, 32), 0xAA);
            a = _mm256_xor_si256(_mm256_xor_si256(hi1, b), _mm256_set1_epi32((int)k0));
            c = _mm256_xor_si256(_mm256_xor_si256(hi0, d), _mm256_set1_epi32((int)k1));
            b = lo1;
            d = lo0;
            k0 += 0x9E3779B9u;
            k1 += 0xBB67AE85u;
        }
        _mm256_storeu_si256((__m256i *)(w0 + i), a);
        _mm256_storeu_si256((__m256i *)(w1 + i), b);
        _mm256_storeu_si256((__m256i *)(w2 + i), c);
        _mm256_storeu_si256((__m256i *)(w3 + i), d);
    }
    philox_span_scalar(key0, key1, pix, pixel0, c1in, c2in, c3in, step3, i, n, w0, w1, w2, w3);
}
#endif

static void philox_span(const wf_noise *noise, const uint32_t *pix, uint32_t pixel0, int n,
                        uint32_t read, wf_purpose purpose, uint32_t block, uint32_t step3,
                        uint32_t *w0, uint32_t *w1, uint32_t *w2, uint32_t *w3)
{
    const uint32_t key0 = (uint32_t)noise->seed, key1 = (uint32_t)(noise->seed >> 32);
    const uint32_t c2 = noise->exposure;
    const uint32_t c3 = ((noise->sca & 0xffu) << 24) | (((uint32_t)purpose & 0xffu) << 16) |
                        (block & 0xffffu);
#ifdef WF_PHILOX_SIMD
    if (__builtin_cpu_supports("avx512f")) {
        philox_span_avx512(key0, key1, pix, pixel0, read, c2, c3, step3, n, w0, w1, w2, w3);
        return;
    }
    if (__builtin_cpu_supports("avx2")) {
        philox_span_avx2(key0, key1, pix, pixel0, read, c2, c3, step3, n, w0, w1, w2, w3);
        return;
    }
#endif
    philox_span_scalar(key0, key1, pix, pixel0, read, c2, c3, step3, 0, n, w0, w1, w2, w3);
}

void wf_noise_block_row(const wf_noise *noise, uint32_t pixel0, int n, uint32_t read,
                        wf_purpose purpose, uint32_t block, uint32_t *w0, uint32_t *w1,
                        uint32_t *w2, uint32_t *w3)
{
    philox_span(noise, NULL, pixel0, n, read, purpose, block, 0, w0, w1, w2, w3);
}

void wf_noise_block_list(const wf_noise *noise, const uint32_t *pixel, int n, uint32_t read,
                         wf_purpose purpose, uint32_t block, uint32_t *w0, uint32_t *w1,
                         uint32_t *w2, uint32_t *w3)
{
    philox_span(noise, pixel, 0, n, read, purpose, block, 0, w0, w1, w2, w3);
}

wf_status wf_noise_stream_blocks(const wf_noise *noise, uint32_t pixel, uint32_t read,
                                 wf_purpose purpose, uint32_t block0, int n, uint32_t *w0,
                                 uint32_t *w1, uint32_t *w2, uint32_t *w3)
{
    /* the block index has 16 bits: past them wf_rng_u32 wraps, and a span would carry */
    if (n < 0 || block0 > 65536u || (uint32_t)n > 65536u - block0)
        return wf_error(WF_ERR_RANGE, "noise: blocks %u + %d of a stream pass its 65536", block0, n);
    philox_span(noise, NULL, pixel, n, read, purpose, block0, 1, w0, w1, w2, w3);
    return WF_OK;
}

/* The tails (p < 0.02425 or p > 0.97575, ~5% of words) of wf_norm_from_u32: wf_norm_ppf's
 * tail formula, q = sqrt(-2 log p) into a rational function, on the words gathered a chunk at
 * a time, so that it runs in SIMD lanes too. Its log is wf_vlog, not libm's; the result, rounded
 * to float, is the same for every one of the 2^32 words (checked exhaustively when this was
 * written, and on a sample by tests/test_single_fast.c). */
_Static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "norm_tails reads its flags' bytes in little-endian order");
#define NORM_CHUNK 2048 /* ~100 tails: enough for whole SIMD iterations; 26 KiB of stack */
WF_INLINE void norm_tails(const uint32_t *w, int n, float *out)
{
    const double c0 = -7.784894002430293e-03, c1 = -3.223964580411365e-01,
                 c2 = -2.400758277161838e+00, c3 = -2.549732539343734e+00,
                 c4 = 4.374664141464968e+00, c5 = 2.938163982698783e+00;
    const double d0 = 7.784695709041462e-03, d1 = 3.224671290700398e-01,
                 d2 = 2.445134137142996e+00, d3 = 3.754408661907416e+00;
    const double plow = 0.02425;
    const uint32_t lo = 104152845u, hi = 4294967295u - 104152845u; /* 0.02425 * 2^32 */
    int at[NORM_CHUNK];
    double t[NORM_CHUNK];
    uint8_t tail[NORM_CHUNK + 8];
    for (int i0 = 0; i0 < n; i0 += NORM_CHUNK) {
        const int len = n - i0 < NORM_CHUNK ? n - i0 : NORM_CHUNK;
        /* the tails' places: flags in SIMD lanes, then read eight at a time, so that a word
         * costs a compare and an eighth of a test (a scalar scan was a third of the call) */
        for (int j = 0; j < len; j++) tail[j] = (uint8_t)((w[i0 + j] < lo) | (w[i0 + j] > hi));
        memset(tail + len, 0, 8);
        int m = 0;
        for (int j = 0; j < len; j += 8) {
            uint64_t f;
            memcpy(&f, tail + j, 8);
            for (; f; f &= f - 1) at[m++] = i0 + j + (__builtin_ctzll(f) >> 3);
        }
        for (int j = 0; j < m; j++) {
            const double p = ((double)w[at[j]] + 0.5) * (1.0 / 4294967296.0);
            t[j] = -2.0 * wf_vlog(p < plow ? p : 1.0 - p);
        }
        sqrt_clamped(t, 0.0, m, t);
        for (int j = 0; j < m; j++) {
            const double p = ((double)w[at[j]] + 0.5) * (1.0 / 4294967296.0), q = t[j];
            const double x = (((((c0 * q + c1) * q + c2) * q + c3) * q + c4) * q + c5) /
                             ((((d0 * q + d1) * q + d2) * q + d3) * q + 1.0);
            out[at[j]] = (float)(p < plow ? x : -x);
        }
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
    norm_tails(w, n, out);
}

/* ---- Poisson row batches ------------------------------------------------------------------ */

/* log k! - (k log k - k) - log(2 pi k) / 2 for k = 1 .. 9 (Stirling's remainder, exact). */
static const double stirling_rest[10] = {
    0.0, 0.08106146679532725821967026, 0.04134069595540929409382208,
    0.02767792568499833914878929, 0.02079067210376509311152277, 0.01664469118982119216319487,
    0.01387612882307074799874573, 0.01189670994589177009505572, 0.01041126526197209649747857,
    0.009255462182712732917728637};

/* PTRS (Hörmann 1993, as hal/noise.c's ptrs_attempt) for mean mu >= 10, smu = sqrt(mu), in
 * two steps so that the costly test runs only where needed: ptrs_quick takes the cheap
 * decisions (accept in the central region, ~68% of attempts at a mean of 120; reject outside
 * the hat's support) and leaves PTRS_UNDECIDED; ptrs_lane decides everything. */
#define PTRS_UNDECIDED -2.0

WF_INLINE double ptrs_quick(double mu, double smu, double u01, double v)
{
    const double b = 0.931 + 2.53 * smu;
    const double a = -0.059 + 0.02483 * b;
    const double vr = 0.9277 - 3.6224 / (b - 2.0);
    const double u = u01 - 0.5;
    const double us = 0.5 - fabs(u);
    const double k = vfloor((2.0 * a / us + b) * u + mu + 0.43);
    /* selects on double compares only: no branches, and masks of one width for the
     * vectoriser (32-bit lanes beside these cannot convert int flags) */
    double r = k < 0.0 ? -1.0 : PTRS_UNDECIDED;
    const double r_tail = v > us ? -1.0 : r;
    r = us < 0.013 ? r_tail : r;
    const double r_quick = v <= vr ? k : r;
    return us >= 0.07 ? r_quick : r;
}

/* The whole attempt: k >= 0 when (u01, v) is accepted, -1 otherwise. The test
 *   log(v inv_alpha / (a / us^2 + b)) <= log P(k | mu)
 * is rearranged so that a lane takes two logs: with
 *   log P = (k - mu) - k log1p((k - mu) / mu) - log(2 pi k) / 2 - R(k)   (k >= 1)
 * and R(k) Stirling's series 1/(12k) - 1/(360k^3) + 1/(1260k^5) (error < 1e-10, as
 * hal/noise.c) from k = 10, exact below, the log(2 pi k) / 2 joins the left side's log (as
 * a factor under a square root); k = 0 has log P = -mu. The arithmetic differs from the
 * scalar test only by roundings (~1e-15), so the accepted distribution is the same. Only
 * lanes ptrs_quick left undecided come here. */
WF_INLINE double ptrs_lane(double mu, double smu, double u01, double v)
{
    const double b = 0.931 + 2.53 * smu;
    const double a = -0.059 + 0.02483 * b;
    const double u = u01 - 0.5;
    const double us = 0.5 - fabs(u);
    const double k = vfloor((2.0 * a / us + b) * u + mu + 0.43);
    const double inv_alpha = 1.1239 + 1.1328 / (b - 3.4);
    const double kk = k >= 1.0 ? k : 1.0;
    /* log(v inv_alpha / (a / us^2 + b)) + log(2 pi k) / 2, in one division */
    const double num = v * inv_alpha * (us * us), den = a + b * (us * us);
    const double lhs = 0.5 * wf_vlog((num * num) * ((2.0 * M_PI) * kk) / (den * den));
    const double ik = 1.0 / kk, ik2 = ik * ik;
    double rest = (1.0 / 12.0 - (1.0 / 360.0 - ik2 * (1.0 / 1260.0)) * ik2) * ik;
#pragma GCC unroll 9
    for (int j = 1; j < 10; j++) rest = k == (double)j ? stirling_rest[j] : rest;
    const double delta = kk - mu;
    double rhs = delta - kk * vlog1p(delta / mu) - rest;
    rhs = k < 1.0 ? 0.9189385332046727417803297 - mu : rhs; /* k = 0: -mu, + log(2 pi)/2 as lhs */
    return lhs <= rhs ? k : -1.0;
}

/* u and v of lane i: from one word each (wide = 0: w0, w1), or 53 bits from two (wide = 1). */
WF_INLINE double ptrs_u(int wide, const uint32_t *w0, const uint32_t *w1, int i)
{
    return wide ? wf_uniform53_words(w0[i], w1[i]) : ((double)w0[i] + 0.5) * (1.0 / 4294967296.0);
}

WF_INLINE double ptrs_v(int wide, const uint32_t *w1, const uint32_t *w2, const uint32_t *w3, int i)
{
    return wide ? wf_uniform53_words(w2[i], w3[i]) : ((double)w1[i] + 0.5) * (1.0 / 4294967296.0);
}

#define PTRS_CHUNK 1024 /* undecided lanes gathered at a time: 28 KiB of stack */

/* One attempt for every lane of a row: k[i] = the draw when accepted, -1 when rejected or
 * mean[i] < 10 (or NaN). The cheap decisions run over the row; the undecided lanes (~32%)
 * are gathered a chunk at a time and take the full test. */
WF_INLINE void ptrs_batch(const double *mean, const uint32_t *w0, const uint32_t *w1,
                          const uint32_t *w2, const uint32_t *w3, int wide, int n, double *k)
{
    sqrt_clamped(mean, 10.0, n, k); /* k holds sqrt(mean) until each lane's draw replaces it */
    for (int i = 0; i < n; i++) {
        const double m = mean[i];
        const double mu = m >= 10.0 ? m : 10.0; /* other lanes (and NaN) compute on a harmless value */
        const double d = ptrs_quick(mu, k[i], ptrs_u(wide, w0, w1, i), ptrs_v(wide, w1, w2, w3, i));
        k[i] = m >= 10.0 ? d : -1.0;
    }
    int at[PTRS_CHUNK];
    double tm[PTRS_CHUNK], ts[PTRS_CHUNK];
    for (int i0 = 0; i0 < n; i0 += PTRS_CHUNK) {
        const int len = n - i0 < PTRS_CHUNK ? n - i0 : PTRS_CHUNK;
        int m = 0;
        for (int j = 0; j < len; j++) { /* compaction without a branch per lane */
            at[m] = i0 + j;
            m += k[i0 + j] == PTRS_UNDECIDED;
        }
        for (int j = 0; j < m; j++) tm[j] = mean[at[j]];
        sqrt_clamped(tm, 10.0, m, ts);
        for (int j = 0; j < m; j++) {
            const int i = at[j];
            ts[j] = ptrs_lane(tm[j], ts[j], ptrs_u(wide, w0, w1, i), ptrs_v(wide, w1, w2, w3, i));
        }
        for (int j = 0; j < m; j++) k[at[j]] = ts[j];
    }
}

WF_CLONES
void wf_poisson_ptrs_row(const double *mean, const uint32_t *wu, const uint32_t *wv, int n,
                         double *k)
{
    ptrs_batch(mean, wu, wv, NULL, NULL, 0, n, k);
}

WF_CLONES
void wf_poisson_ptrs_row53(const double *mean, const uint32_t *w0, const uint32_t *w1,
                           const uint32_t *w2, const uint32_t *w3, int n, double *k)
{
    ptrs_batch(mean, w0, w1, w2, w3, 1, n, k);
}

/* The first word w with (w + 0.5) 2^-32 > c: w >= floor(c 2^32 - 0.5) + 1 (exact for
 * c >= e^-10), as hal/noise.c's first_word_above; 2^32 or more when no word is. */
WF_INLINE double word_above(double c) { return floor(c * 4294967296.0 - 0.5) + 1.0; }

/* The sums as hal/noise.c's inversion_sums forms them (the one-pixel draw's order), without a
 * branch: past a sum that stopped growing the later ones equal it (its terms only shrink). */
WF_CLONES
void wf_poisson_inversion_thresholds_row(int n, const double *restrict m, const double *restrict e,
                                         uint32_t *restrict thr, size_t stride, uint32_t *restrict slow)
{
    for (int i = 0; i < n; i++) {
        const double mi = m[i], ei = e[i];
        const int in = (mi > 0.0) & (mi < 10.0);
        const double p1 = ei * mi;
        double F = ei, p = p1 * mi * 0.5, T[7];
        T[0] = word_above(F);
        F += p1; /* the first three sums are always formed */
        T[1] = word_above(F);
        F += p;
        T[2] = word_above(F);
        int nsum = 3, grow = 1;
        for (int j = 3; j < 7; j++) {
            p *= mi / (double)j;
            const double next = F + p;
            grow &= next != F;
            F = grow ? next : F;
            nsum += grow;
            T[j] = word_above(F);
        }
        uint32_t slow_i = 0;
        for (int j = 0; j < 7; j++) {
            const uint32_t t = in ? (T[j] >= 4294967295.0 ? UINT32_MAX : (uint32_t)T[j]) : 0u;
            if (j < 6) thr[(size_t)j * stride + (size_t)i] = t;
            slow_i = j == (nsum < 7 ? nsum - 1 : 6) ? t : slow_i;
        }
        slow[i] = slow_i;
    }
}

WF_CLONES
void wf_poisson_table_row(const wf_poisson_table *t, const uint32_t *w, int n, double *k)
{
    uint32_t wmax = 0;
    for (int i = 0; i < n; i++) {
        k[i] = 0.0;
        wmax = w[i] > wmax ? w[i] : wmax;
    }
    /* entry-major, so that each pass is one integer compare-and-add across the row; entries
     * past the row's largest word count for no pixel (the table is increasing) */
    for (int j = 0; j < t->nword && wmax >= t->word[j]; j++) {
        const uint32_t first = t->word[j];
        for (int i = 0; i < n; i++) k[i] += w[i] >= first ? 1.0 : 0.0;
    }
}
