/* Internals shared by sim/draw/profile*.c; not part of the public interface (sim/draw/profile.h). */
#ifndef WF_PROFILE_INT_H
#define WF_PROFILE_INT_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "hal/status.h"
#include "sim/draw/profile.h"

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
/* The FFT sides a drawing work uses (2^k, 3 2^k, 5 2^k and 7 2^k from min_fft to max_fft),
 * ascending: up to cap of them into sizes; returns the count. */
int wf_profile_fft_ladder(const struct wf_profile_accuracy *acc, int *sizes, int cap);

/* The periods of a PSF's tables: per[0] = psf_table_fft, then (acc.extra_tables) each of the
 * ladder's sides below it, largest first, that divides none of the periods before it, up to
 * WF_PROFILE_MAX_ALT more. Returns how many. A side m <= psf_table_fft reads the first
 * period it divides exactly, at every (P / m)-th sample; wf_profile_table_of says which (-1:
 * none; such sides are skipped, sides above psf_table_fft interpolate the first). */
int wf_profile_table_periods(const struct wf_profile_accuracy *acc, int *per);
int wf_profile_table_of(const int *per, int n, int m);
/* The same for a prepared PSF (its table_fft, then its alt[]): 0, i + 1 for alt[i], or -1. */
int wf_profile_psf_period(const struct wf_profile_psf *psf, int m);

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

/* Knots in Fourier space (sim/draw/profile_lattice.c). The direct sum costs one complex
 * multiply-add per knot and Fourier sample. The lattice method sums the knots only on a
 * coarse lattice (every r-th sample per axis, which still resolves their transform because
 * they occupy a small part of the FFT box) and interpolates the fine samples with a compact
 * kernel (w taps per axis); each knot's weight is divided by the kernel's transform at its
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

/* ------------------------------------------------------------ between the drawer's files:
 * sim/draw/profile.c drives a draw through the others, profile_size.c (stamp, box and band),
 * profile_lattice.c (the knot lattice), profile_fold.c (the fine grid into the box's bins),
 * profile_kernels.c (their inner loops), profile_wing.c (the split PSF's wing),
 * profile_real.c (no PSF) and profile_work.c (knobs, buffers, plans). */

/* The knot lattice: most kernel taps per axis, coarsest step. */
#define WF_LAT_WMAX 16
#define WF_LAT_RMAX 64

/* What a draw needs, in arcsec and absolute flux. A point source is a "galaxy" with only
 * point flux. */
typedef struct wf_draw_job {
    double flux;                 /* total */
    double fb, fd, fk, fpoint;   /* bulge, smooth disk, all knots, point */
    double re, r0;               /* de Vaucouleurs half-light radius, exponential scale */
    wf_shape shape;
    int nk;
    double fknot;                /* flux per knot */
    const double *knots;         /* nk (x, y) after shear and rotation */
    double knot_rmax;            /* farthest knot from the centre */
} wf_draw_job;

/* One Fourier draw's fine grid: the box's side m, the band's radius u in steps dk, and how
 * the PSF's table is read (WF_GRID_EXACT: every st-th entry, WF_GRID_INTERP: bicubic). */
enum { WF_GRID_EXACT, WF_GRID_INTERP };

typedef struct wf_draw_grid {
    int m, half, mode, st, u;
    const float *tre, *tim; /* WF_GRID_EXACT: the table this side reads (its copy at st when */
    int tkr;                /* there is one, st then 1), |u|, |v| <= tkr */
    double dk;
    int ic, jc;
    double dx, dy;       /* arcsec from the centre of pixel (ic, jc) to the object */
    int nk;              /* knots drawn in Fourier space: those inside the FFT box */
    const double *kpos;  /* their (x, y), arcsec from the object */
    size_t ks;           /* entries per knot phase line (2 u + 1, and 8 or more of padding) */
    struct wf_knot_lattice *lat; /* the knots on a coarse lattice, or NULL (direct sums) */
    const int *rim;      /* rim[|v|] = floor(sqrt(u^2 - v^2)): the row's extent */
    double lat_exp;      /* the knot lattice's E = -ln(knot_accuracy) */
} wf_draw_grid;

/* The knots of one draw on the knot lattice (sim/draw/profile_lattice.c). */
typedef struct wf_knot_lattice {
    int r, w, mh, nh, U;
    int nk;                        /* the knots it holds, (x, y) from the object */
    const double *pos;
    const int *rim;                /* the fine grid's |u| <= rim[|v|] */
    double rho, beta;
    size_t gw;                     /* stored row width: 2 nh + 1 and padding */
    const double *gr, *gi;         /* rows m = 0..mh of g(n, m) at [m gw + n + nh]; rows
                                      m < 0 are conj g(-n, -m) */
    double wt[WF_LAT_RMAX][WF_LAT_WMAX]; /* psi at s = rho / r + w / 2 - 1 - i, rho = u mod r */
    double *ar, *ai;               /* ring of w interpolated rows: row m in slot m mod w,
                                      entries [u + U], padded */
    size_t al;                     /* ring row stride */
    double *tmp;                   /* a mirrored row */
    int next;                      /* next coarse row the ring takes */
} wf_knot_lattice;

/* What the smooth kernel needs of a row (sim/draw/profile_kernels.c). */
typedef struct wf_smooth_par {
    double qa, qb, qc;        /* q2 = |A^T k|^2 = (qa u + qb) u + qc along the row */
    double re2, r02, fb, fd;  /* bulge and disk: F(re2 q2), (1 + r02 q2)^-3/2 */
    double fpoint;            /* > 0: a point source of this flux instead */
    int bulge, disk;
    const wf_sersic_table *t;
    double eyr, eyi;          /* the row's phase */
    const double *exr, *exi;  /* the columns' phases, indexed by u */
} wf_smooth_par;

/* The kernels in use (sim/draw/profile_kernels.c), set by wf_profile_simd only. */
typedef struct wf_fold_kernels {
    void (*smooth)(const wf_smooth_par *, int, int, double *, double *);
    void (*latrow)(const wf_knot_lattice *, const double *, const double *, int, int, double *,
                   double *);
    void (*latadd)(int, int, const double *, const double *const *, const double *const *,
                   int, double *, double *);
    void (*psfmul)(int, const float *, const float *, size_t, const double *, const double *,
                   double *);
    void (*wing)(long, double, double, double, double, const float *, const float *, const float *,
                 const float *, double *);
    void (*wingclip)(long, const double *, const float *const *, const float *, double *);
} wf_fold_kernels;
extern wf_fold_kernels wf_profile_fold_k;

static inline long wf_floor_div_l(long a, long b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }
static inline int wf_floor_div(int a, int b) { return (int)wf_floor_div_l(a, b); }

static inline int wf_profile_ladder_max(const wf_profile_work *w)
{
    return w->sizes[w->nsizes - 1];
}

/* profile.c */
wf_status wf_profile_check_position(double x, double y);
wf_status wf_profile_check_stamp(const wf_stamp *stamp);
wf_status wf_profile_galaxy_job(wf_profile_work *w, const wf_galaxy *g, wf_draw_job *jb);

/* profile_work.c: the plan of the work's side mi (shared by the process's works). */
wf_status wf_profile_draw_plan(wf_profile_work *w, int mi);

/* profile_size.c: radii (arcsec) holding all but eps of the light, the stamp of an object,
 * the Fourier cuts, the FFT side. */
struct wf_radius_hint;
double wf_profile_galaxy_radius(const wf_draw_job *jb, const wf_sersic_table *t, double eps,
                                struct wf_radius_hint *hint);
double wf_profile_object_radius(const wf_draw_job *jb, const wf_sersic_table *t,
                                const wf_profile_psf *psf, double eps, int core);
wf_status wf_profile_bounds(const wf_profile_work *w, const wf_draw_job *jb,
                            const wf_profile_psf *psf, double x, double y, wf_stamp *stamp,
                            double *fraction);
double wf_profile_psf_kcut_from(const wf_draw_job *jb, const wf_sersic_table *t,
                                const wf_profile_psf *psf, double kvalue, int part, int from);
double wf_profile_psf_kcut(const wf_draw_job *jb, const wf_sersic_table *t,
                           const wf_profile_psf *psf, double kvalue, int part);
int wf_profile_tail_cut(const wf_draw_job *jb, const wf_sersic_table *t, const wf_profile_psf *psf,
                        double dk, int m, int lim, double tol, int part);
int wf_profile_choose_size(const wf_profile_work *w, const wf_profile_psf *psf, double need);

/* profile_lattice.c: the plan (0: every knot summed directly), the coarse rows, and coarse
 * row m interpolated along u for a box of side mbox. */
int wf_profile_knot_plan(wf_profile_work *w, wf_draw_grid *gd, double p, wf_knot_lattice *l);
void wf_profile_lat_build(wf_profile_work *w, const wf_draw_job *jb, wf_draw_grid *gd,
                          wf_knot_lattice *l);
void wf_profile_lat_row(const wf_fold_kernels *fk, wf_knot_lattice *l, int m, int mbox);

/* profile_kernels.c */
void wf_profile_knot_sum(int n, int nkb, const double *ckr, const double *cki, const double *kx,
                         size_t ks, double *restrict rr, double *restrict ri);
void wf_profile_box_clipped(const float *box, int ca, int cb, int lo, int hi, int xa,
                            double *acc);

/* profile_fold.c */
void wf_profile_fold_pass(wf_profile_work *w, const wf_draw_job *jb, const wf_profile_psf *psf,
                          const wf_draw_grid *gd, int us, int knot0, int nkb);
wf_status wf_profile_dewrap(const wf_profile_work *w, const wf_draw_job *jb,
                            const wf_draw_grid *gd, double x, double y, wf_stamp *stamp,
                            int box_only);

/* profile_wing.c: stamp += flux x that core's wing at (x, y); stamp += fknot x that core at
 * each of nk knots, (xy[2k], xy[2k + 1]) arcsec from (x, y), read from its knot table out to
 * lim pixels (wf_profile_core.knot_out). */
void wf_profile_wing_stamp(const wf_profile_psf *psf, int core, double flux, double x, double y,
                           wf_stamp *stamp);
void wf_profile_knots_stamp(const wf_profile_psf *psf, int core, int lim, double fknot, int nk,
                            const double *xy, double x, double y, wf_stamp *stamp);

/* profile_real.c: surface brightness (flux / arcsec^2) of the smooth galaxy at (x, y) arcsec
 * from it; the stamp without a PSF. */
double wf_profile_smooth_density(const wf_draw_job *jb, const wf_sersic_table *t, double x,
                                 double y);
wf_status wf_profile_draw_nopsf(wf_profile_work *w, const wf_draw_job *jb, double x, double y,
                                wf_stamp *stamp);

#endif
