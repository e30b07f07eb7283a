/* The drawing's inner loops: the direct knot sums, the fold pass's per-sample kernels (the
 * smooth profile, the knot lattice's rows, the product with PSF x pixel) and the split PSF's
 * wing added to a stamp or to a row; each in a scalar version and, with GCC on x86-64,
 * vector versions that give the same bits, the widest the CPU has taken once per process
 * (wf_profile_simd). The vector versions use GCC's vector extensions, __builtin_shuffle among
 * them, which clang lacks: the fuzz build compiles this file with gcc (Makefile, FUZZ_GCC). */
#include <math.h>
#include <pthread.h>
#include <stddef.h>
#include <string.h>

#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"

/* ------------------------------------------------------------------------ knot sums */

/* run[i] += sum_j c_j x_j[i] for i < n, complex, split into real and imaginary arrays; knot
 * j's phase line is x_j = kx + 2 j ks (real parts, then ks further the imaginary ones).
 * Four knots at a time and two points at a time, so that the sums stay in registers and
 * the pairs map onto vector instructions. */
#if defined(__GNUC__)
#define KNOT_LOAD(x, p) memcpy(&(x), (p), sizeof(x))
/* Four points at a time in two vectors of NL lanes (type V), all knots into them; returns
 * the first point not done. Lanes never mix, and without fused multiply-adds (ISO C mode
 * contracts nothing) each sum is rounded exactly as the scalar loop's. */
#define KNOT_BODY(V, NL)                                                                   \
    int i0 = 0;                                                                            \
    for (; i0 + 2 * (NL) <= n; i0 += 2 * (NL)) {                                           \
        V sr0, si0, sr1, si1;                                                              \
        KNOT_LOAD(sr0, rr + i0);                                                           \
        KNOT_LOAD(sr1, rr + i0 + (NL));                                                    \
        KNOT_LOAD(si0, ri + i0);                                                           \
        KNOT_LOAD(si1, ri + i0 + (NL));                                                    \
        const double *x = kx + i0;                                                         \
        for (int j = 0; j < nkb; j++, x += 2 * ks) {                                       \
            V xr0, xi0, xr1, xi1;                                                          \
            KNOT_LOAD(xr0, x);                                                             \
            KNOT_LOAD(xr1, x + (NL));                                                      \
            KNOT_LOAD(xi0, x + ks);                                                        \
            KNOT_LOAD(xi1, x + ks + (NL));                                                 \
            const double cr = ckr[j], ci = cki[j];                                         \
            sr0 += cr * xr0 - ci * xi0;                                                    \
            si0 += cr * xi0 + ci * xr0;                                                    \
            sr1 += cr * xr1 - ci * xi1;                                                    \
            si1 += cr * xi1 + ci * xr1;                                                    \
        }                                                                                  \
        memcpy(rr + i0, &sr0, sizeof sr0);                                                 \
        memcpy(rr + i0 + (NL), &sr1, sizeof sr1);                                          \
        memcpy(ri + i0, &si0, sizeof si0);                                                 \
        memcpy(ri + i0 + (NL), &si1, sizeof si1);                                          \
    }                                                                                      \
    return i0;

typedef double knot_v2 __attribute__((vector_size(16)));
static int knot_sum_v2(int n, int nkb, const double *ckr, const double *cki, const double *kx,
                       size_t ks, double *restrict rr, double *restrict ri)
{
    KNOT_BODY(knot_v2, 2)
}

#if defined(__x86_64__) || defined(__i386__)
#define KNOT_AVX 1
typedef double knot_v4 __attribute__((vector_size(32)));
__attribute__((target("avx2"))) static int
knot_sum_v4(int n, int nkb, const double *ckr, const double *cki, const double *kx, size_t ks,
            double *restrict rr, double *restrict ri)
{
    KNOT_BODY(knot_v4, 4)
}
typedef double knot_v8 __attribute__((vector_size(64)));
__attribute__((target("avx512f"))) static int
knot_sum_v8(int n, int nkb, const double *ckr, const double *cki, const double *kx, size_t ks,
            double *restrict rr, double *restrict ri)
{
    KNOT_BODY(knot_v8, 8)
}
static int knot_avx; /* 1: AVX2, 2: AVX-512 (the same sums, lane by lane); wf_profile_simd */
#endif
#endif

void wf_profile_knot_sum(int n, int nkb, const double *ckr, const double *cki, const double *kx,
                         size_t ks, double *restrict rr, double *restrict ri)
{
    int i0 = 0;
#if defined(__GNUC__)
#if defined(KNOT_AVX)
    if (knot_avx == 2) i0 = knot_sum_v8(n, nkb, ckr, cki, kx, ks, rr, ri);
    if (knot_avx) i0 += knot_sum_v4(n - i0, nkb, ckr, cki, kx + i0, ks, rr + i0, ri + i0);
#endif
    int i1 = knot_sum_v2(n - i0, nkb, ckr, cki, kx + i0, ks, rr + i0, ri + i0);
    i0 += i1;
#endif
    for (int i = i0; i < n; i++) {
        double sr = rr[i], si = ri[i];
        const double *x = kx + i;
        for (int j = 0; j < nkb; j++, x += 2 * ks) {
            sr += ckr[j] * x[0] - cki[j] * x[ks];
            si += ckr[j] * x[ks] + cki[j] * x[0];
        }
        rr[i] = sr;
        ri[i] = si;
    }
}

/* ------------------------------------------------------------------------ fold kernels */

/* The per-sample work of a fold pass on one alias run of a row, in four kernels: the
 * smooth galaxy (or point source) times the centring and sub-pixel phases; a coarse row of
 * the knot lattice interpolated along u; the fine row from w of those; the product with
 * PSF x pixel added into the bins. A fifth adds a row of the split PSF's wing to a stamp
 * (wf_profile_wing_stamp). Each has a scalar version and, on x86-64, vector
 * versions of 2, 4 (AVX2) and 8 (AVX-512) lanes, chosen once by wf_profile_simd. Lanes
 * never mix, every operation is the scalar one in the same order (a vector's last lanes
 * may recompute values already written: the same values), and ISO C mode contracts no
 * multiply-add into a fused one, so every version gives the same bits: the CPU a stamp is
 * drawn on does not change it (tests/test_profile.c, test_simd_identical and
 * test_simd_identical_wing). */

/* rr[i], ri[i] for u = ua + i, i < n. */
static void smooth_scalar(const wf_smooth_par *sp, int ua, int n, double *rr, double *ri)
{
    const double eyr = sp->eyr, eyi = sp->eyi;
    for (int i = 0; i < n; i++) {
        int u = ua + i;
        double g;
        if (sp->fpoint > 0.0) {
            g = sp->fpoint;
        } else {
            double q2 = (sp->qa * u + sp->qb) * u + sp->qc;
            g = 0.0;
            if (sp->bulge) g += sp->fb * wf_sersic4_eval(sp->t, sp->re2 * q2);
            if (sp->disk) {
                double s = 1.0 / (1.0 + sp->r02 * q2);
                g += sp->fd * s * sqrt(s);
            }
        }
        double pr = sp->exr[u], pi = sp->exi[u];
        rr[i] = g * (pr * eyr - pi * eyi);
        ri[i] = g * (pr * eyi + pi * eyr);
    }
}

/* run[i] += sum_c wy[c] row_c[i] for the lattice's w rows. */
static void latadd_scalar(int n, int nw, const double *wy, const double *const *lr,
                          const double *const *li, int ua, double *runr, double *runi)
{
    for (int i = 0; i < n; i++) {
        double kr = 0.0, ki = 0.0;
        for (int c = 0; c < nw; c++) {
            kr += wy[c] * lr[c][ua + i];
            ki += wy[c] * li[c][ua + i];
        }
        runr[i] += kr;
        runi[i] += ki;
    }
}

/* A coarse row g (pointers at n = 0) interpolated along u at u, times (-1)^u (the box's
 * centring), into ar[u], ai[u]. */
static inline void latrow_one(const wf_knot_lattice *l, const double *gr, const double *gi,
                              int u, double *ar, double *ai)
{
    int t = wf_floor_div(u, l->r), rho = u - t * l->r, h = l->w / 2 - 1;
    const double *wt = l->wt[rho];
    double sr = 0.0, si = 0.0;
    for (int i = 0; i < l->w; i++) {
        sr += wt[i] * gr[t - h + i];
        si += wt[i] * gi[t - h + i];
    }
    double sg = (u & 1) ? -1.0 : 1.0;
    ar[u] = sg * sr;
    ai[u] = sg * si;
}

static void latrow_scalar(const wf_knot_lattice *l, const double *gr, const double *gi, int ua,
                          int ub, double *ar, double *ai)
{
    for (int u = ua; u <= ub; u++) latrow_one(l, gr, gi, u, ar, ai);
}

/* bins (complex interleaved) += run x (fr + i fi), the PSF read at stride st. */
static void psfmul_scalar(int n, const float *fr, const float *fi, size_t st, const double *runr,
                          const double *runi, double *bins)
{
    for (int i = 0; i < n; i++) {
        double pr = fr[i * st], pi = fi[i * st];
        double rr = runr[i], ri = runi[i];
        bins[2 * i] += rr * pr - ri * pi;
        bins[2 * i + 1] += rr * pi + ri * pr;
    }
}

/* dst[k] += w00 r00[k] + w01 r01[k] + w10 r10[k] + w11 r11[k], k < n: a row of the split
 * PSF's wing, bilinear between four of its phase planes (wf_profile_wing_stamp). */
static void wing_scalar(long n, double w00, double w01, double w10, double w11, const float *r00,
                        const float *r01, const float *r10, const float *r11, double *dst)
{
    for (long k = 0; k < n; k++) dst[k] += w00 * r00[k] + w01 * r01[k] + w10 * r10[k] + w11 * r11[k];
}

/* acc[k] += max(box[k] + wing, 0) (box NULL: no box pixels), the wing read as wing_scalar:
 * the renderer's sum of a split galaxy's box and wing in one pass over the row. */
static void wingclip_scalar(long n, const double *w, const float *const *r, const float *box,
                            double *acc)
{
    for (long k = 0; k < n; k++) {
        double v = w[0] * r[0][k] + w[1] * r[1][k] + w[2] * r[2][k] + w[3] * r[3][k];
        if (box) v = (double)box[k] + v;
        acc[k] += v < 0.0 ? 0.0 : v;
    }
}

#if defined(__GNUC__) && defined(__x86_64__) /* SSE2 arithmetic in the scalar code too */
#include <immintrin.h>
#define FOLD_SIMD 1

#define VLOAD(x, p) memcpy(&(x), (p), sizeof(x))
#define VSTORE(p, x) memcpy((p), &(x), sizeof(x))

/* de Vaucouleurs F at w, lane by lane as wf_sersic4_eval. ANY(mask) tells whether a lane
 * is set, GATHER(ix, c0, c1, c2, c3) loads ck[l] = t->v[ix[l] + k]. */
#define SERSIC_V(V, VI, VS, NL, ANY, GATHER, w, out)                                       \
    do {                                                                                   \
        VI bits_ = (VI)(w);                                                                \
        VS e_ = __builtin_convertvector((bits_ >> 52) & 0x7ff, VS) - 1023;                 \
        VS bad_ = (e_ < WF_SERSIC_EMIN) | (e_ >= WF_SERSIC_EMAX);                          \
        if (ANY(bad_)) {                                                                   \
            for (int l_ = 0; l_ < (NL); l_++) (out)[l_] = sersic_lane(t, (w)[l_]);         \
            break;                                                                         \
        }                                                                                  \
        /* the mantissa as 1.m, minus 1: exactly (double)(bits & mask) 2^-52 */            \
        V m_ = ((V)((bits_ & 0xfffffffffffffLL) | 0x3ff0000000000000LL) - 1.0) *          \
               (double)WF_SERSIC_SUB;                                                      \
        VS i_ = __builtin_convertvector(m_, VS);                                            \
        V f_ = m_ - __builtin_convertvector(i_, V);                                         \
        VS ix_ = (e_ - WF_SERSIC_EMIN) * WF_SERSIC_ROW + i_;                               \
        V c0_, c1_, c2_, c3_;                                                              \
        GATHER(ix_, c0_, c1_, c2_, c3_);                                                   \
        V fm1_ = f_ - 1.0, fm2_ = f_ - 2.0, fp1_ = f_ + 1.0;                               \
        (out) = (-c0_ * f_ * fm1_ * fm2_ + c3_ * fp1_ * f_ * fm1_) * (1.0 / 6.0) +         \
                (c1_ * fp1_ * fm1_ * fm2_ - c2_ * fp1_ * f_ * fm2_) * 0.5;                 \
    } while (0)

#define SMOOTH_BODY(V, VI, VS, NL, SQRT, ZU, ANY, GATHER)                                 \
    const wf_sersic_table *t = sp->t;                                                      \
    const double eyr = sp->eyr, eyi = sp->eyi;                                             \
    V lane;                                                                                \
    for (int l = 0; l < (NL); l++) lane[l] = l;                                            \
    for (int i = 0; i < n; i += (NL)) {                                                    \
        if (i + (NL) > n) { /* the last vector overlaps the one before: same values */     \
            if (n < (NL)) {                                                                \
                ZU();                                                                      \
                smooth_scalar(sp, ua, n, rr, ri);                                          \
                return;                                                                    \
            }                                                                              \
            i = n - (NL);                                                                  \
        }                                                                                  \
        int u0 = ua + i;                                                                   \
        V g = lane * 0.0;                                                                  \
        if (sp->fpoint > 0.0) {                                                            \
            g += sp->fpoint;                                                               \
        } else {                                                                           \
            V uv = (double)u0 + lane;                                                      \
            V q2 = (sp->qa * uv + sp->qb) * uv + sp->qc;                                   \
            if (sp->bulge) {                                                               \
                V wv = sp->re2 * q2, fv;                                                   \
                SERSIC_V(V, VI, VS, NL, ANY, GATHER, wv, fv);                              \
                g += sp->fb * fv;                                                          \
            }                                                                              \
            if (sp->disk) {                                                                \
                V sv = 1.0 / (1.0 + sp->r02 * q2);                                         \
                g += sp->fd * sv * SQRT(sv);                                               \
            }                                                                              \
        }                                                                                  \
        V pr, pi;                                                                          \
        VLOAD(pr, sp->exr + u0);                                                           \
        VLOAD(pi, sp->exi + u0);                                                           \
        V a = g * (pr * eyr - pi * eyi), b = g * (pr * eyi + pi * eyr);                    \
        VSTORE(rr + i, a);                                                                 \
        VSTORE(ri + i, b);                                                                 \
    }                                                                                      \
    ZU();

/* run[i] += ... for whole vectors: n rounded up (the run and the ring rows are padded) */
#define LATADD_BODY(V, NL, ZU)                                                             \
    for (int i = 0; i < n; i += (NL)) {                                                    \
        V kr = {0}, ki = {0}, x;                                                           \
        for (int c = 0; c < nw; c++) {                                                     \
            VLOAD(x, lr[c] + ua + i);                                                      \
            kr += wy[c] * x;                                                               \
            VLOAD(x, li[c] + ua + i);                                                      \
            ki += wy[c] * x;                                                               \
        }                                                                                  \
        V r0, i0;                                                                          \
        VLOAD(r0, runr + i);                                                               \
        VLOAD(i0, runi + i);                                                               \
        r0 += kr;                                                                          \
        i0 += ki;                                                                          \
        VSTORE(runr + i, r0);                                                              \
        VSTORE(runi + i, i0);                                                              \
    }                                                                                      \
    ZU();

/* a coarse row interpolated along u, vector over t (u = r t + rho) for each rho; the last
 * vector of a rho overlaps the one before */
#define LATROW_BODY(V, NL, ZU)                                                             \
    const int r = l->r, wd = l->w, h = wd / 2 - 1;                                         \
    for (int rho = 0; rho < r; rho++) {                                                    \
        int t0 = wf_floor_div(ua - rho + r - 1, r), t1 = wf_floor_div(ub - rho, r);        \
        if (t1 - t0 + 1 < (NL)) {                                                          \
            for (int t = t0; t <= t1; t++) latrow_one(l, gr, gi, r * t + rho, ar, ai);    \
            continue;                                                                      \
        }                                                                                  \
        const double *wt = l->wt[rho];                                                     \
        for (int t = t0; t <= t1; t += (NL)) {                                             \
            if (t + (NL) - 1 > t1) t = t1 - (NL) + 1;                                      \
            V sr = {0}, si = {0}, x;                                                       \
            for (int i = 0; i < wd; i++) {                                                 \
                VLOAD(x, gr + t - h + i);                                                  \
                sr += wt[i] * x;                                                           \
                VLOAD(x, gi + t - h + i);                                                  \
                si += wt[i] * x;                                                           \
            }                                                                              \
            for (int q = 0; q < (NL); q++) {                                               \
                int u = r * (t + q) + rho;                                                 \
                double sg = (u & 1) ? -1.0 : 1.0;                                          \
                ar[u] = sg * sr[q];                                                        \
                ai[u] = sg * si[q];                                                        \
            }                                                                              \
        }                                                                                  \
    }                                                                                      \
    ZU();

/* the products interleaved into the bins: lanes (re 0, im 0, re 1, im 1, ...) */
#define PSFMUL_BODY(V, VF, VI, NL, LO, HI, ZU, PGATHER)                                                 \
    int i = 0;                                                                             \
    for (; i + (NL) <= n; i += (NL)) {                                                     \
        V pr, pi;                                                                          \
        if (st == 1) {                                                                     \
            VF a, b;                                                                       \
            VLOAD(a, fr + i);                                                              \
            VLOAD(b, fi + i);                                                              \
            pr = __builtin_convertvector(a, V);                                            \
            pi = __builtin_convertvector(b, V);                                            \
        } else {                                                                           \
            PGATHER(pr, fr + (size_t)i * st, st);                                          \
            PGATHER(pi, fi + (size_t)i * st, st);                                          \
        }                                                                                  \
        V rr, ri, b0, b1;                                                                  \
        VLOAD(rr, runr + i);                                                               \
        VLOAD(ri, runi + i);                                                               \
        V br = rr * pr - ri * pi, bi = rr * pi + ri * pr;                                  \
        VLOAD(b0, bins + 2 * i);                                                           \
        VLOAD(b1, bins + 2 * i + (NL));                                                    \
        b0 += __builtin_shuffle(br, bi, (VI)LO);                                           \
        b1 += __builtin_shuffle(br, bi, (VI)HI);                                           \
        VSTORE(bins + 2 * i, b0);                                                          \
        VSTORE(bins + 2 * i + (NL), b1);                                                   \
    }                                                                                      \
    ZU();                                                                                  \
    psfmul_scalar(n - i, fr + (size_t)i * st, fi + (size_t)i * st, st, runr + i, runi + i,  \
                  bins + 2 * i);

#define WING_BODY(V, VF, NL, ZU, TAIL)                                                     \
    long k = 0;                                                                            \
    for (; k + (NL) <= n; k += (NL)) {                                                     \
        VF a, b, c, d;                                                                     \
        V o;                                                                               \
        VLOAD(a, r00 + k);                                                                 \
        VLOAD(b, r01 + k);                                                                 \
        VLOAD(c, r10 + k);                                                                 \
        VLOAD(d, r11 + k);                                                                 \
        VLOAD(o, dst + k);                                                                 \
        o += w00 * __builtin_convertvector(a, V) + w01 * __builtin_convertvector(b, V) +   \
             w10 * __builtin_convertvector(c, V) + w11 * __builtin_convertvector(d, V);    \
        VSTORE(dst + k, o);                                                                \
    }                                                                                      \
    ZU();                                                                                  \
    TAIL(n - k, w00, w01, w10, w11, r00 + k, r01 + k, r10 + k, r11 + k, dst + k);

/* the clip as a mask, no branch: about half the far pixels of a faint object are slightly
 * negative */
#define WINGCLIP_LOOP(V, VF, VI, NL)                                                       \
    const V zero_ = {0};                                                                   \
    long k = 0;                                                                            \
    for (; k + (NL) <= n; k += (NL)) {                                                     \
        VF a, b, c, d;                                                                     \
        V o, s_;                                                                           \
        VLOAD(a, r[0] + k);                                                                \
        VLOAD(b, r[1] + k);                                                                \
        VLOAD(c, r[2] + k);                                                                \
        VLOAD(d, r[3] + k);                                                                \
        o = w[0] * __builtin_convertvector(a, V) + w[1] * __builtin_convertvector(b, V) +  \
            w[2] * __builtin_convertvector(c, V) + w[3] * __builtin_convertvector(d, V);   \
        if (box) {                                                                         \
            VLOAD(a, box + k);                                                             \
            o = __builtin_convertvector(a, V) + o;                                         \
        }                                                                                  \
        VLOAD(s_, acc + k);                                                                \
        s_ += (V)((VI)o & ~(VI)(o < zero_));                                               \
        VSTORE(acc + k, s_);                                                               \
    }
#define WINGCLIP_BODY(V, VF, VI, NL, ZU)                                                   \
    WINGCLIP_LOOP(V, VF, VI, NL)                                                           \
    ZU();                                                                                  \
    wingclip_scalar(n - k, w, (const float *const[4]){r[0] + k, r[1] + k, r[2] + k, r[3] + k}, \
                    box ? box + k : NULL, acc + k);

/* Out-of-table arguments, one lane at a time. Not inlined: the vector kernels' callers are
 * built for the baseline ISA, and a call is where the compiler clears the wide registers'
 * upper halves (SSE code running with them dirty is ~3x slower on some x86 cores). */
__attribute__((noinline)) static double sersic_lane(const wf_sersic_table *t, double w)
{
    return wf_sersic4_eval(t, w);
}

static inline void no_zeroupper(void) {}

typedef double fv2 __attribute__((vector_size(16)));
typedef long long fi2 __attribute__((vector_size(16)));
typedef int fs2 __attribute__((vector_size(8)));
typedef float ff2 __attribute__((vector_size(8)));
static inline fv2 sqrt2(fv2 x) { return (fv2)_mm_sqrt_pd((__m128d)x); }
#define ANY2(b) ((b)[0] | (b)[1])
#define GATHER2(ix, c0, c1, c2, c3)                                                        \
    do {                                                                                   \
        const double *p0_ = t->v + (ix)[0], *p1_ = t->v + (ix)[1];                         \
        c0 = (fv2){p0_[0], p1_[0]};                                                        \
        c1 = (fv2){p0_[1], p1_[1]};                                                        \
        c2 = (fv2){p0_[2], p1_[2]};                                                        \
        c3 = (fv2){p0_[3], p1_[3]};                                                        \
    } while (0)
#define PGATHER2(x, p, st) ((x) = (fv2){(p)[0], (p)[st]})
static void smooth_v2(const wf_smooth_par *sp, int ua, int n, double *rr, double *ri)
{
    SMOOTH_BODY(fv2, fi2, fs2, 2, sqrt2, no_zeroupper, ANY2, GATHER2)
}
static void latadd_v2(int n, int nw, const double *wy, const double *const *lr,
                      const double *const *li, int ua, double *runr, double *runi)
{
    LATADD_BODY(fv2, 2, no_zeroupper)
}
static void latrow_v2(const wf_knot_lattice *l, const double *gr, const double *gi, int ua,
                      int ub, double *ar, double *ai)
{
    LATROW_BODY(fv2, 2, no_zeroupper)
}
static void psfmul_v2(int n, const float *fr, const float *fi, size_t st, const double *runr,
                      const double *runi, double *bins)
{
    PSFMUL_BODY(fv2, ff2, fi2, 2, ((fi2){0, 2}), ((fi2){1, 3}), no_zeroupper, PGATHER2)
}
static void wing_v2(long n, double w00, double w01, double w10, double w11, const float *r00,
                    const float *r01, const float *r10, const float *r11, double *dst)
{
    WING_BODY(fv2, ff2, 2, no_zeroupper, wing_scalar)
}
static void wingclip_v2(long n, const double *w, const float *const *r,
                           const float *box, double *acc)
{
    WINGCLIP_BODY(fv2, ff2, fi2, 2, no_zeroupper)
}

typedef double fv4 __attribute__((vector_size(32)));
typedef long long fi4 __attribute__((vector_size(32)));
typedef int fs4 __attribute__((vector_size(16)));
typedef float ff4 __attribute__((vector_size(16)));
__attribute__((target("avx2"))) static inline fv4 sqrt4(fv4 x)
{
    return (fv4)_mm256_sqrt_pd((__m256d)x);
}
#define ANY4(b) _mm_movemask_ps((__m128)(b))
/* each lane's 4 table values are adjacent: 4 loads and a 4 x 4 transpose */
#define GATHER4(ix, c0, c1, c2, c3)                                                        \
    do {                                                                                   \
        fv4 r0_, r1_, r2_, r3_;                                                            \
        VLOAD(r0_, t->v + (ix)[0]);                                                        \
        VLOAD(r1_, t->v + (ix)[1]);                                                        \
        VLOAD(r2_, t->v + (ix)[2]);                                                        \
        VLOAD(r3_, t->v + (ix)[3]);                                                        \
        fv4 a_ = __builtin_shufflevector(r0_, r1_, 0, 4, 1, 5);                            \
        fv4 b_ = __builtin_shufflevector(r2_, r3_, 0, 4, 1, 5);                            \
        c0 = __builtin_shufflevector(a_, b_, 0, 1, 4, 5);                                  \
        c1 = __builtin_shufflevector(a_, b_, 2, 3, 6, 7);                                  \
        a_ = __builtin_shufflevector(r0_, r1_, 2, 6, 3, 7);                                \
        b_ = __builtin_shufflevector(r2_, r3_, 2, 6, 3, 7);                                \
        c2 = __builtin_shufflevector(a_, b_, 0, 1, 4, 5);                                  \
        c3 = __builtin_shufflevector(a_, b_, 2, 3, 6, 7);                                  \
    } while (0)
#define PGATHER4(x, p, st)                                                                 \
    ((x) = __builtin_convertvector(                                                        \
         (ff4)_mm_i32gather_ps((p), (__m128i)((fs4){0, 1, 2, 3} * (int)(st)), 4), fv4))
__attribute__((target("avx2"))) static void smooth_v4(const wf_smooth_par *sp, int ua, int n,
                                                      double *rr, double *ri)
{
    SMOOTH_BODY(fv4, fi4, fs4, 4, sqrt4, _mm256_zeroupper, ANY4, GATHER4)
}
__attribute__((target("avx2"))) static void
latadd_v4(int n, int nw, const double *wy, const double *const *lr, const double *const *li,
          int ua, double *runr, double *runi)
{
    LATADD_BODY(fv4, 4, _mm256_zeroupper)
}
__attribute__((target("avx2"))) static void latrow_v4(const wf_knot_lattice *l,
                                                      const double *gr, const double *gi,
                                                      int ua, int ub, double *ar, double *ai)
{
    LATROW_BODY(fv4, 4, _mm256_zeroupper)
}
__attribute__((target("avx2"))) static void psfmul_v4(int n, const float *fr, const float *fi,
                                                      size_t st, const double *runr,
                                                      const double *runi, double *bins)
{
    PSFMUL_BODY(fv4, ff4, fi4, 4, ((fi4){0, 4, 1, 5}), ((fi4){2, 6, 3, 7}), _mm256_zeroupper,
                PGATHER4)
}
__attribute__((target("avx2"))) static void wing_v4(long n, double w00, double w01, double w10,
                                                    double w11, const float *r00, const float *r01,
                                                    const float *r10, const float *r11, double *dst)
{
    WING_BODY(fv4, ff4, 4, _mm256_zeroupper, wing_scalar)
}
__attribute__((target("avx2"))) static void wingclip_v4(long n, const double *w, const float *const *r,
                                                        const float *box, double *acc)
{
    WINGCLIP_BODY(fv4, ff4, fi4, 4, _mm256_zeroupper)
}

typedef double fv8 __attribute__((vector_size(64)));
typedef long long fi8 __attribute__((vector_size(64)));
typedef int fs8 __attribute__((vector_size(32)));
typedef float ff8 __attribute__((vector_size(32)));
__attribute__((target("avx512f"))) static inline fv8 sqrt8(fv8 x)
{
    return (fv8)_mm512_sqrt_pd((__m512d)x);
}
#define ANY8(b) _mm256_movemask_ps((__m256)(b))
/* 8 loads of 4 adjacent values and an 8 x 4 transpose */
#define GATHER8(ix, c0, c1, c2, c3)                                                        \
    do {                                                                                   \
        fv4 r_[8];                                                                         \
        for (int l_ = 0; l_ < 8; l_++) VLOAD(r_[l_], t->v + (ix)[l_]);                     \
        fv8 z0_ = __builtin_shufflevector(r_[0], r_[1], 0, 1, 2, 3, 4, 5, 6, 7);           \
        fv8 z1_ = __builtin_shufflevector(r_[2], r_[3], 0, 1, 2, 3, 4, 5, 6, 7);           \
        fv8 z2_ = __builtin_shufflevector(r_[4], r_[5], 0, 1, 2, 3, 4, 5, 6, 7);           \
        fv8 z3_ = __builtin_shufflevector(r_[6], r_[7], 0, 1, 2, 3, 4, 5, 6, 7);           \
        fv8 a_ = __builtin_shufflevector(z0_, z1_, 0, 4, 8, 12, 1, 5, 9, 13);              \
        fv8 b_ = __builtin_shufflevector(z2_, z3_, 0, 4, 8, 12, 1, 5, 9, 13);              \
        c0 = __builtin_shufflevector(a_, b_, 0, 1, 2, 3, 8, 9, 10, 11);                    \
        c1 = __builtin_shufflevector(a_, b_, 4, 5, 6, 7, 12, 13, 14, 15);                  \
        a_ = __builtin_shufflevector(z0_, z1_, 2, 6, 10, 14, 3, 7, 11, 15);                \
        b_ = __builtin_shufflevector(z2_, z3_, 2, 6, 10, 14, 3, 7, 11, 15);                \
        c2 = __builtin_shufflevector(a_, b_, 0, 1, 2, 3, 8, 9, 10, 11);                    \
        c3 = __builtin_shufflevector(a_, b_, 4, 5, 6, 7, 12, 13, 14, 15);                  \
    } while (0)
#define PGATHER8(x, p, st)                                                                 \
    ((x) = __builtin_convertvector(                                                        \
         (ff8)_mm256_i32gather_ps((p), (__m256i)((fs8){0, 1, 2, 3, 4, 5, 6, 7} * (int)(st)), \
                                  4),                                                      \
         fv8))
__attribute__((target("avx512f"))) static void smooth_v8(const wf_smooth_par *sp, int ua, int n,
                                                         double *rr, double *ri)
{
    SMOOTH_BODY(fv8, fi8, fs8, 8, sqrt8, _mm256_zeroupper, ANY8, GATHER8)
}
__attribute__((target("avx512f"))) static void
latadd_v8(int n, int nw, const double *wy, const double *const *lr, const double *const *li,
          int ua, double *runr, double *runi)
{
    LATADD_BODY(fv8, 8, _mm256_zeroupper)
}
__attribute__((target("avx512f"))) static void latrow_v8(const wf_knot_lattice *l,
                                                         const double *gr, const double *gi,
                                                         int ua, int ub, double *ar, double *ai)
{
    LATROW_BODY(fv8, 8, _mm256_zeroupper)
}
__attribute__((target("avx512f"))) static void
psfmul_v8(int n, const float *fr, const float *fi, size_t st, const double *runr,
          const double *runi, double *bins)
{
    PSFMUL_BODY(fv8, ff8, fi8, 8, ((fi8){0, 8, 1, 9, 2, 10, 3, 11}),
                ((fi8){4, 12, 5, 13, 6, 14, 7, 15}), _mm256_zeroupper, PGATHER8)
}
__attribute__((target("avx512f"))) static void wing_v8(long n, double w00, double w01, double w10,
                                                       double w11, const float *r00, const float *r01,
                                                       const float *r10, const float *r11, double *dst)
{
    /* a split galaxy's knots read from its core are rows of ~2 reach + 2 pixels: their tails
     * take four lanes, then the scalar code (the same bits, lane for lane) */
    WING_BODY(fv8, ff8, 8, _mm256_zeroupper, wing_v4)
}
__attribute__((target("avx512f"))) static void wingclip_v8(long n, const double *w, const float *const *r,
                                                           const float *box, double *acc)
{
    WINGCLIP_LOOP(fv8, ff8, fi8, 8)
    if (k < n) { /* the last few columns (a row is ~100 wide) in one masked vector */
        const __mmask16 mf = (__mmask16)((1u << (n - k)) - 1);
        const __mmask8 md = (__mmask8)mf;
#define LOAD8F(p) (fv8) _mm512_cvtps_pd(_mm512_castps512_ps256(_mm512_maskz_loadu_ps(mf, (p))))
        fv8 o = w[0] * LOAD8F(r[0] + k) + w[1] * LOAD8F(r[1] + k) + w[2] * LOAD8F(r[2] + k) +
                w[3] * LOAD8F(r[3] + k);
        if (box) o = LOAD8F(box + k) + o;
#undef LOAD8F
        fv8 s_ = (fv8)_mm512_maskz_loadu_pd(md, acc + k);
        s_ += (fv8)((fi8)o & ~(fi8)(o < zero_));
        _mm512_mask_storeu_pd(acc + k, md, (__m512d)s_);
    }
    _mm256_zeroupper();
}
#endif

/* acc[i - xa] += max(box[i - ca], 0) for the columns i in [lo, hi) within [ca, cb): a wing
 * row's columns the wing table does not reach (sim/draw/profile_wing.c). */
void wf_profile_box_clipped(const float *box, int ca, int cb, int lo, int hi, int xa, double *acc)
{
    if (lo < ca) lo = ca;
    if (hi > cb) hi = cb;
    if (lo >= hi) return;
    const float *b = box + (lo - ca);
    double *a = acc + (lo - xa);
    int n = hi - lo, i = 0;
#if defined(FOLD_SIMD) /* two at a time, a mask for the clip: the same bits */
    const fv2 zero = {0.0, 0.0};
    for (; i + 2 <= n; i += 2) {
        ff2 bv;
        fv2 av;
        VLOAD(bv, b + i);
        VLOAD(av, a + i);
        fv2 v = __builtin_convertvector(bv, fv2);
        av += (fv2)((fi2)v & ~(fi2)(v < zero));
        VSTORE(a + i, av);
    }
#endif
    for (; i < n; i++) {
        double v = (double)b[i];
        a[i] += v < 0.0 ? 0.0 : v;
    }
}

wf_fold_kernels wf_profile_fold_k = {smooth_scalar, latrow_scalar, latadd_scalar, psfmul_scalar,
                                     wing_scalar, wingclip_scalar};
static pthread_once_t simd_once = PTHREAD_ONCE_INIT;
static int simd_lanes;

static int simd_select(int lanes)
{
    wf_profile_fold_k = (wf_fold_kernels){smooth_scalar, latrow_scalar, latadd_scalar,
                                          psfmul_scalar, wing_scalar, wingclip_scalar};
    int used = 0;
#if defined(FOLD_SIMD)
    __builtin_cpu_init();
    if (lanes >= 8 && __builtin_cpu_supports("avx512f")) {
        wf_profile_fold_k = (wf_fold_kernels){smooth_v8, latrow_v8, latadd_v8, psfmul_v8,
                                              wing_v8, wingclip_v8};
        used = 8;
    } else if (lanes >= 4 && __builtin_cpu_supports("avx2")) {
        wf_profile_fold_k = (wf_fold_kernels){smooth_v4, latrow_v4, latadd_v4, psfmul_v4,
                                              wing_v4, wingclip_v4};
        used = 4;
    } else if (lanes >= 2) {
        wf_profile_fold_k = (wf_fold_kernels){smooth_v2, latrow_v2, latadd_v2, psfmul_v2,
                                              wing_v2, wingclip_v2};
        used = 2;
    }
#endif
#if defined(KNOT_AVX)
    knot_avx = used == 8 ? 2 : used == 4 ? 1 : 0;
#endif
    return used;
}

static void simd_probe(void) { simd_lanes = simd_select(8); }

int wf_profile_simd(int lanes)
{
    pthread_once(&simd_once, simd_probe);
    if (lanes >= 0) simd_lanes = simd_select(lanes);
    return simd_lanes;
}
