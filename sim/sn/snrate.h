/* Type Ia supernova rates, expected counts, redshifts and peak dates (SPEC §5;
 * docs/SN_POPULATION.md).
 *
 * Rate law: a volumetric rate R(z) = A_i (1+z)^B_i on [zlo_i, zhi_i), in SNe yr⁻¹ Mpc⁻³
 * (rest-frame years), up to WF_SNRATE_MAX_PIECES non-overlapping pieces, zero outside them;
 * a z equal to the largest zhi belongs to that piece (SPEC writes 1 ≤ z ≤ 3). This is
 * SNANA's `DNDZ: POWERLAW2 A B zmin zmax`. The A_i are quoted for H0 = 70 and, as in SNANA,
 * are used unchanged whatever H0 the cosmology has (no h³ rescaling). Default (SPEC §5,
 * Hounsell et al. 2018): 2.5e-5 (1+z)^1.5 for 0 ≤ z < 1, 9.7e-5 (1+z)^−0.5 for 1 ≤ z ≤ 3.
 *
 * Counts (SNANA's SNcount_model): observed-frame density of events per unit z, per sr and
 * per observer year
 *     n(z) = R(z) / (1+z) · dV/dz/dΩ          (1/(1+z): time dilation)
 *     N = Ω · T · ∫_zmin^zmax n(z) dz,
 * with Ω = area_deg2 · (π/180)² sr and T = days / 365.25 (Julian years). The integral is
 * 16-point Gauss–Legendre on panels ≤ 0.002 wide between the rate law's breaks (the
 * integrand is smooth on each): measured 3e-15 relative against composite Simpson and
 * against astropy + scipy quad (tests/test_snrate.c).
 *
 * Redshifts: a table of the cumulative G(z) = ∫_zmin^z n on nodes ≤ 0.002 apart, with the
 * breaks of the law as nodes and the one-sided densities at each node; inside an interval G
 * is the cubic Hermite interpolant of (G, n) at its ends, whose error is ≤ h⁴/384 ·
 * max|n‴|, and a uniform draw u is inverted by safeguarded Newton on that cubic (to 1e-15
 * in the interval's unit). Measured for the SPEC law: |Δz| ≤ 1e-11 against an independent
 * forward CDF (tests/test_snrate.c; the bar is 1e-8). Build: ~1500 intervals, ~10 ms;
 * a draw: ~0.2 µs.
 *
 * Peak dates: uniform in [mjd_start − pad_before, mjd_end + pad_after] with
 *     pad_before = rest_before · (1+zmax),  pad_after = rest_after · (1+zmax),
 * rest_before the model's last rest-frame phase after peak (50 d, SALT3's +50) and
 * rest_after its first phase before peak (20 d, SALT3's −20): any SN at z ≤ zmax whose
 * model light curve overlaps the survey has its peak inside the window (low-z SNe are
 * over-padded, which only adds SNe never seen). T in the count is the padded window's
 * length, so the count scales with it, as SNANA counts over its GENRANGE_PEAKMJD, which
 * users set wider than the survey by the model's phase range in the same way.
 *
 * Randomness: every draw of SN i comes from its own counter-based stream
 *     wf_rng_init(&rng, &(wf_noise){WF_NOISE_PHILOX, seed, 0, 0}, i, which, WF_PURPOSE_SN)
 * (wf_sn_rng), `which` from wf_sn_draw below, so SN i's values do not depend on how many
 * others were drawn or in which order. */
#ifndef WF_SNRATE_H
#define WF_SNRATE_H

#include <stdint.h>

#include "hal/noise.h"
#include "hal/status.h"
#include "sim/sn/cosmology.h"

/* The `read` word of SN i's streams: one stream per kind of draw. Other modules use these
 * exact names; add new kinds at the end, never renumber. */
typedef enum wf_sn_draw {
    WF_SN_DRAW_Z = 0,     /* redshift (sim/sn/snrate.c) */
    WF_SN_DRAW_PEAK = 1,  /* peak MJD (sim/sn/snrate.c) */
    WF_SN_DRAW_POP = 2,   /* x1, c, intrinsic scatter (sim/sn/snpop.c) */
    WF_SN_DRAW_HOST = 3,  /* host galaxy choice */
    WF_SN_DRAW_POS = 4,   /* position within the host */
    WF_SN_DRAW_COUNT = 5  /* the number of SNe: stream of i = 0 only */
} wf_sn_draw;

/* SN i's stream for one kind of draw under a seed. */
void wf_sn_rng(uint64_t seed, uint32_t i, wf_sn_draw which, wf_rng *rng);

#define WF_SNRATE_MAX_PIECES 8
#define WF_SNRATE_DAYS_PER_YEAR 365.25

typedef struct wf_snrate_piece {
    double a;         /* yr⁻¹ Mpc⁻³ at z = 0 (H0 = 70 as quoted) */
    double b;         /* power of (1+z) */
    double zlo, zhi;  /* 0 ≤ zlo < zhi ≤ WF_COSMO_ZMAX */
} wf_snrate_piece;

typedef struct wf_snrate {
    int n;
    wf_snrate_piece p[WF_SNRATE_MAX_PIECES];
} wf_snrate;

/* The SPEC §5 law (two pieces). */
void wf_snrate_default(wf_snrate *r);

/* Empties r, before wf_snrate_add_line calls. */
void wf_snrate_clear(wf_snrate *r);

/* Appends one piece from an SNANA-style line, any of
 *     "DNDZ: POWERLAW2 A B zmin zmax"   "POWERLAW2: A B zmin zmax"   "POWERLAW2 A B zmin zmax"
 * with an optional trailing "# comment". Errors name file:line, the column and the field
 * (A, B, zmin, zmax), and overlaps with pieces already added. file may be NULL ("rate"). */
wf_status wf_snrate_add_line(wf_snrate *r, const char *text, const char *file, int line);

/* At least one piece, each piece finite with A ≥ 0, 0 ≤ zlo < zhi ≤ WF_COSMO_ZMAX, no two
 * overlapping. Errors name the piece (1-based) and field. */
wf_status wf_snrate_validate(const wf_snrate *r);

/* R(z), yr⁻¹ Mpc⁻³ (0 outside every piece). */
wf_status wf_snrate_eval(const wf_snrate *r, double z, double *rate);

/* n(z) = R(z)/(1+z) dV/dz/dΩ: SNe per unit z, per sr, per observer year. */
wf_status wf_snrate_density(const wf_snrate *r, const wf_cosmo *c, double z, double *n);

/* ∫_zmin^zmax n(z) dz, SNe sr⁻¹ yr⁻¹; 0 ≤ zmin < zmax ≤ WF_COSMO_ZMAX. */
wf_status wf_snrate_integral(const wf_snrate *r, const wf_cosmo *c, double zmin, double zmax,
                             double *per_sr_yr);

/* N = Ω T ∫ n dz for area_deg2 (deg²) and days (observer frame, 365.25 d per year). */
wf_status wf_snrate_expected(const wf_snrate *r, const wf_cosmo *c, double zmin, double zmax,
                             double area_deg2, double days, double *n);

/* Cumulative table of n(z) on [zmin, zmax] for drawing redshifts (see top). */
typedef struct wf_snrate_table {
    double zmin, zmax;
    double total;  /* ∫ n dz over [zmin, zmax], SNe sr⁻¹ yr⁻¹ */
    int n;         /* intervals */
    double *z;     /* n+1 nodes */
    double *g;     /* n+1 cumulative values G(z_k), g[0] = 0, g[n] = total */
    double *dl;    /* n: n(z) at the left end of interval k, from inside it */
    double *dr;    /* n: n(z) at the right end of interval k, from inside it */
} wf_snrate_table;

/* Builds the table (malloc; free with wf_snrate_table_free). A law that is zero over the
 * whole range is an error. */
wf_status wf_snrate_table_build(const wf_snrate *r, const wf_cosmo *c, double zmin, double zmax,
                                wf_snrate_table *t);
void wf_snrate_table_free(wf_snrate_table *t);

/* The z with G(z) = u · total, 0 < u < 1 (u = 0 and 1 give the ends). */
wf_status wf_snrate_quantile(const wf_snrate_table *t, double u, double *z);

/* Where and when SNe are generated (defaults: wf_snrate_survey_default). */
typedef struct wf_snrate_survey {
    double area_deg2;               /* generation footprint [1] */
    double mjd_start, mjd_end;      /* survey span [61420, 62150.5]: 730.5 d = 2 Julian yr */
    double zmin, zmax;              /* [0.06, 2.99] (SPEC §5) */
    double rest_before;         /* rest days of padding before mjd_start, × (1+zmax) [50] */
    double rest_after;          /* rest days of padding after mjd_end, × (1+zmax) [20] */
} wf_snrate_survey;

void wf_snrate_survey_default(wf_snrate_survey *s);

/* One generation: the z table, the padded window and the expected count. */
typedef struct wf_snrate_gen {
    wf_snrate_table table;
    wf_snrate_survey survey;
    uint64_t seed;
    double peak_min, peak_max; /* MJD range of peak dates (padded) */
    double days;               /* peak_max − peak_min */
    double area_sr;
    double expected;           /* N = area_sr · days/365.25 · table.total */
} wf_snrate_gen;

/* Validates the law and survey (errors name the field), builds the table. */
wf_status wf_snrate_gen_init(wf_snrate_gen *g, const wf_snrate *law, const wf_cosmo *c,
                             const wf_snrate_survey *s, uint64_t seed);
void wf_snrate_gen_free(wf_snrate_gen *g);

/* The number of SNe: Poisson(expected) from the stream (i = 0, WF_SN_DRAW_COUNT). More than
 * 4e9 expected is an error (SN indices are 32-bit). The same seed gives the same count. */
wf_status wf_snrate_gen_count(const wf_snrate_gen *g, uint32_t *count);

/* SN i's redshift (stream WF_SN_DRAW_Z) and peak MJD (stream WF_SN_DRAW_PEAK). */
wf_status wf_snrate_gen_draw(const wf_snrate_gen *g, uint32_t i, double *z, double *peak_mjd);

#endif
