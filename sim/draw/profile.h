/* Object profiles drawn into pixel stamps (SPEC §4.2, issue 3 item 4): galaxies made of a
 * de Vaucouleurs bulge, an exponential disk and star-forming knots, and point sources; each
 * convolved with the PSF and the 0.11" square pixel.
 *
 * Method (measurements in docs/OPTICS.md "Profiles").
 *  - With a PSF, in Fourier space. The product profile(k) x PSF(k) x pixel(k) x shift(k) is
 *    evaluated analytically (exponential: (1 + k^2 r0^2)^-3/2; de Vaucouleurs: its Hankel
 *    transform, tabulated once; knots: sums of phases, most of them on a coarse lattice
 *    and interpolated; PSF x pixel: a table made once per PSF image) on the fine k grid of
 *    the FFT box out to the PSF's band limit, folded into the box's Nyquist band (which
 *    samples the pixel-convolved image exactly although Roman's PSF is undersampled by
 *    0.11" pixels), and inverse-FFT'd once (FFTW). Flux, sub-pixel position and shear are
 *    exact; the errors are the light from beyond the FFT box that wraps in (knob
 *    folding_threshold), the Fourier modes dropped below kvalue_accuracy (or beyond the
 *    radius cut_tolerance allows), and the knot lattice's interpolation (~1e-9 of the
 *    peak). Stamps do not depend on the CPU's vector
 *    width.
 *  - Without a PSF (psf NULL: tests, the GalSim no-PSF references), in real space: each
 *    pixel is the exact integral of the profile over it (polar fans around the cusp,
 *    Gauss-Legendre elsewhere), ~1e-10 of the flux; a Fourier series of the bare cusp would
 *    converge as k^-2.25 and ring.
 *
 * Coordinates: SCA pixels, 0-based, pixel (i, j) centred at (i, j) and covering
 * [i - 1/2, i + 1/2) x [j - 1/2, j + 1/2); x along columns, y along rows. Add -1 to GalSim's
 * 1-based FITS positions. Angles and sizes are in arcsec in the same x, y axes (the caller
 * rotates sky-frame shapes by the local WCS; see wf_galaxy.rotation).
 *
 * Memory: every buffer comes from an arena the caller owns (hal/arena.h); FFTW plans are
 * made once in wf_profile_work_init (the only call that takes a process-wide lock, because
 * FFTW's planner is not thread-safe) and executed with new arrays, which FFTW allows from
 * any thread. One wf_profile_work per thread; wf_profile_psf is read-only once made and may
 * be shared by threads. */
#ifndef WF_PROFILE_H
#define WF_PROFILE_H

#include <stddef.h>
#include <stdint.h>

#include "hal/arena.h"
#include "hal/status.h"
#include "sim/optics/psfimage.h"

#define WF_PROFILE_PIXEL_SCALE 0.11 /* arcsec, Roman WFI */
#define WF_PROFILE_MAX_KNOTS 1024
#define WF_PROFILE_MAX_KNOT_FRAC 0.25 /* SPEC §4.2: knots hold at most 25% of the disk */
#define WF_PROFILE_KNOT_ACCURACY 2.0611536224385579e-09 /* e^-20, the default knot_accuracy */
#define WF_PROFILE_MAX_CORES 4

/* Accuracy knobs; wf_profile_accuracy_default gives the values in brackets. */
typedef struct wf_profile_accuracy {
    double pixel_scale;       /* arcsec [0.11] */
    double flux_fraction;     /* the stamp holds at least this fraction of the flux [0.995] */
    double folding_threshold; /* flux allowed outside the FFT box, which wraps in [5e-3] */
    double kvalue_accuracy;   /* Fourier modes below this fraction of the flux are dropped [1e-5] */
    int min_fft;              /* smallest FFT side [16] */
    int max_fft;              /* largest FFT side: bounds memory and time per object [1024] */
    int psf_table_fft;        /* FFT sides dividing this read the PSF table exactly, larger
                                 ones interpolate it (bicubic) [192] */
    int extra_tables;         /* 1: every FFT side below psf_table_fft reads a table exactly,
                                 those that do not divide it one more table at the largest
                                 side they divide (wf_profile_table_periods; up to
                                 WF_PROFILE_MAX_ALT of them); 0: such sides are skipped [1] */
    double core_radius;       /* arcsec; > 0 splits the PSF into core and wing ("Core and
                                 wing" below) [0: one PSF, the reference] */
    int core_levels;          /* core radii: core_radius halved at each level, up to
                                 WF_PROFILE_MAX_CORES; an object takes the smallest its
                                 wing tolerance allows [1] */
    double wing_tolerance;    /* with a split PSF, extended objects whose wing error bound
                                 2 flux wing_max (that core's) stays below this (flux per
                                 pixel) take the smallest such core; their knots are drawn
                                 in real space from that core's knot table where the
                                 knots' flux x (knot_interp + knot_out[l]) stays below it
                                 too, each read out to the least reach l that allows and
                                 whose knot_miss is <= (1 - flux_fraction) / 10 [0: none] */
    double knot_accuracy;     /* the knot lattice's aliasing, e^-E: a pixel moves by ~10 e^-E
                                 of the knots' flux at most [e^-20 = 2.1e-9] */
    double cut_tolerance;     /* with a PSF, > 0 also ends the Fourier sum where the modes left
                                 out move no pixel by more than this (flux per pixel), from
                                 the bound sum |object| env / M^2 over the fine samples beyond
                                 the cut (WF_PROFILE_CUT_KEEP below) [0: kvalue_accuracy alone] */
} wf_profile_accuracy;

/* cut_tolerance never drops a mode above this fraction of the flux (object x PSF envelope):
 * the faintest objects keep their shape instead of becoming the box's flat mean. */
#define WF_PROFILE_CUT_KEEP 1e-2

void wf_profile_accuracy_default(wf_profile_accuracy *acc);

/* A galaxy: bulge (de Vaucouleurs) + disk (exponential) whose disk light is split between a
 * smooth part and knots. Sizes are half-light radii of the round profiles before the shear;
 * the shear preserves area (GalSim's shear), so they stay the geometric-mean radii. */
typedef struct wf_galaxy {
    uint32_t id;          /* object id: keys the knot stream together with knot_seed */
    double flux;          /* total flux (any unit; the stamp is in that unit per pixel) */
    double bulge_frac;    /* [0, 1] */
    double hlr_bulge;     /* arcsec, > 0 when bulge_frac > 0 */
    double hlr_disk;      /* arcsec, > 0 when bulge_frac < 1 */
    double knot_frac;     /* fraction of the disk flux in knots, [0, 0.25] */
    int n_knots;          /* [0, WF_PROFILE_MAX_KNOTS]; 0 puts all the disk light in the disk */
    uint64_t knot_seed;   /* knot positions = f(knot_seed, id) only: the same in every
                             exposure, SCA and tile */
    const double *knot_xy; /* NULL: knots from the seed; else n_knots (x, y) pairs in arcsec,
                              before shear and rotation (as GalSim's RandomKnots.points) */
    double e1, e2;        /* distortion e = (a^2 - b^2) / (a^2 + b^2), |e| < 1; e1 along x */
    double rotation;      /* radians counter-clockwise (x towards y), after the shear */
} wf_galaxy;

/* A stamp in SCA pixel coordinates. The bounds are set by wf_profile_*_bounds or by the
 * caller; pix is the caller's (nx * ny doubles, row-major: pix[(y - y0) * nx + (x - x0)]). */
typedef struct wf_stamp {
    int x0, y0, nx, ny;
    double *pix;
    /* written by the draw: */
    double sum;     /* sum of pix */
    double clipped; /* negative ringing set to zero (sum of the magnitudes; ~1e-7 of flux) */
    int fft;        /* FFT side used */
} wf_stamp;

/* A table read at every st-th sample (the FFT sides that divide table_fft at st > 1), kept
 * as its own contiguous copy: entry (u, v) of copy i is the table's (st u, st v), |u|, |v|
 * <= kr[i]. The draws then load whole vectors instead of gathering one sample per cache
 * line. */
#define WF_PROFILE_MAX_STEPS 16
typedef struct wf_profile_steps {
    int n;
    int st[WF_PROFILE_MAX_STEPS], kr[WF_PROFILE_MAX_STEPS];
    float *re[WF_PROFILE_MAX_STEPS], *im[WF_PROFILE_MAX_STEPS];
} wf_profile_steps;

/* The PSF x pixel transform sampled at another period P (k step 2 pi / (P pixel_scale)), for
 * the FFT sides below table_fft that divide P but not table_fft: |u|, |v| <= kr, laid out as
 * the main table, and its copies at those sides' steps. */
#define WF_PROFILE_MAX_ALT 3
typedef struct wf_profile_table {
    int fft, kr;
    float *re, *im;
    wf_profile_steps steps;
} wf_profile_table;

/* One core of a split PSF (wf_profile_psf below). */
typedef struct wf_profile_core {
    double radius;             /* arcsec */
    float *re, *im;            /* the core's table, laid out as the whole one */
    wf_profile_steps steps;    /* and its copies at the draws' steps */
    wf_profile_table alt[WF_PROFILE_MAX_ALT]; /* at the other periods, as the whole one's */
    double *env;               /* its envelope, as env */
    double flux;               /* the core's share of the image's flux */
    double wing_max;           /* largest |wing| pixel value, per unit flux */
    float *wing;               /* wing_os^2 phase planes, plane (b, a) at (b wing_os + a)
                                  wing_np^2: entry [n_y][n_x] is the wing's pixel value at
                                  offset (n_x - wing_half + a / wing_os, n_y - wing_half +
                                  b / wing_os) pixels from the object */
    float *knot;               /* the core itself in real space, laid out as the wing but
                                  with knot_os, knot_half and knot_np: where a knot's light
                                  falls (a knot is a point, so knot x core is the core at its
                                  position) */
    int knot_half, knot_np;
    double knot_interp;        /* bound on |core at any position - its bilinear reading from
                                  knot|, per unit flux, from the table: sum |T(k)| (e(k_x) +
                                  e(k_y)) / N^2, plus the floats' rounding and the largest
                                  sample beyond knot_half + 2 (the table's period folds the
                                  core's tail back by that much) */
    double *knot_out;          /* [l], l = 0 .. knot_half: the largest |sample| l - 1
                                  pixels or more from the centre along x or y, per unit
                                  flux: left out by a reading out to l pixels only (no pixel
                                  is then off by more than knot_interp + knot_out[l]) */
    double *knot_miss;         /* [l]: the most of the core's light (a fraction) a reading out
                                  to l pixels leaves out, wherever the knot sits: the least
                                  any plane holds in a window of 2 l + 1 samples each way
                                  that a reading's windows contain */
} wf_profile_core;

/* A PSF prepared for drawing: its Fourier transform times the pixel's, once. */
typedef struct wf_profile_psf {
    double pixel_scale, scale; /* stamp pixel and PSF sample spacing, arcsec */
    double flux;               /* sum of the PSF image */
    int table_fft;             /* the table's k spacing is 2 pi / (table_fft * pixel_scale) */
    int kr;                    /* the table holds |kx|, |ky| <= kr steps */
    float *re, *im;            /* (2 kr + 1)^2, row (ky) major, k = 0 at [kr][kr] */
    wf_profile_steps steps;    /* its copies at the draws' steps */
    int nalt;                  /* tables at other periods (acc.extra_tables) */
    wf_profile_table alt[WF_PROFILE_MAX_ALT];
    double kmax;               /* rad/arcsec beyond which |PSF(k) pixel(k)| < 1e-7 flux */
    double pixel_max;          /* bound on any pixel of the image per unit flux, for any
                                  position, whole or through any core: sum |table| / N^2
                                  (the main table's, N = table_fft) */
    int nee;                   /* encircled energy of the image, for stamp sizes: */
    double ee_dr;              /* radius step, arcsec */
    double *ee;                /* ee[i]: fraction of the image's flux within (i + 1) ee_dr */
    double *env;               /* env[i]: max |PSF(k) pixel(k)| over |k| >= i table steps (the
                                  samples of every period), for cutting each draw where
                                  object x PSF < kvalue_accuracy */
    /* Core and wing (acc.core_radius > 0; else ncore 0). A core is the image times a taper
     * T(r) (1 within 2/3 of its radius, a raised cosine to 0 at it); its wing is the rest,
     * exactly: the inverse transform of (whole table - core table), in real space, pixel
     * included. A compact object is drawn as object x core in a Fourier box sized by the
     * core, plus flux x wing at its position. That is exact for a point source, but an
     * extended object's wing misses the object's own blur, which moves no pixel by more
     * than 2 flux wing_max: so an object takes a core only when that bound is below
     * acc.wing_tolerance, and of those the smallest (a scene sets the tolerance from the sky
     * noise, so faint galaxies take small boxes; errors and costs: docs/ACCURACY.md). Point
     * sources gain nothing and never take one. Such an object's knots, points, are each the
     * core at its own position: read from the core's real-space table (bilinear, every
     * 1 / knot_os pixel) where their error bound allows, so that the box holds only the
     * smooth light, whose transform ends far sooner than a point's. */
    int ncore;                 /* cores, by radius halving from core[0] (acc.core_levels) */
    wf_profile_core core[WF_PROFILE_MAX_CORES];
    int wing_os, wing_half;    /* wing samples every 1 / wing_os pixel, offsets up to
                                  wing_half (+ 1) pixels each way */
    int wing_np;               /* samples per row of one phase plane */
    int knot_os;               /* the cores' knot tables: samples every 1 / knot_os pixel */
} wf_profile_psf;

struct wf_sersic_table;

/* Per-thread drawing state (opaque in use; fields are for the implementation). */
typedef struct wf_profile_work {
    wf_profile_accuracy acc;
    int nsizes;
    int sizes[48];         /* FFT sides, ascending (see wf_profile_work_init) */
    void *plans[48];       /* fftw_plan: in-place complex-to-real, one per side, made on
                              first use and shared by every work (not freed) */
    double *fft;           /* in-place buffer for the largest side */
    double *ex, *ey;       /* per-draw phase lines, cap_line entries: ex real parts then
                              imaginary ones cap_line further, ey complex interleaved */
    int cap_line;
    double *kx, *ky;       /* knot phase lines: WF_PROFILE_KNOT_BLOCK x cap_line entries */
    int *ix, *iy;          /* bicubic taps for FFT sides above psf_table_fft (or, without
                              extra_tables, a largest side that divides no period) */
    double *wx, *wy;       /* their weights, 4 per entry */
    double *run;           /* one alias run of a row: complex, max_fft / 2 + 1 entries */
    double *knot_pos;      /* 2 x WF_PROFILE_MAX_KNOTS, arcsec after shear and rotation */
    double *knot_box;      /* the knots of one draw that lie inside its FFT box */
    double *lat;           /* the knots' coarse lattice (sim/draw/profile_lattice.c), cap_lat doubles */
    size_t cap_lat;
    double *ring;          /* its rows interpolated along u, and a mirrored row */
    int *rim;              /* per draw: the extent of each row of the fine grid */
    int knot_method;       /* WF_KNOTS_* (sim/draw/profile_int.h) */
    int knot_last[5];      /* the last draw's knots: lattice step (0: none), its taps, the
                              knots summed directly, those read from a core's knot table
                              instead (real space), and that reading's reach in pixels */
    int cut_last[2];       /* the last draw's Fourier extent in fine-grid steps: the smooth
                              part's (or point source's) and the knots' (0: none) */
    int keep_negatives;    /* 1: draws leave negative ringing in (wf_profile_keep_negatives) */
    const struct wf_sersic_table *sersic;
} wf_profile_work;
#define WF_PROFILE_KNOT_BLOCK 16

/* Bytes the work buffers take from an arena for these knobs (15.7 MB at the defaults,
 * most of it the max_fft^2 FFT buffer), and (dense, may be NULL) how many of them, from the
 * start of what wf_profile_work_init takes, it fills whole (~2 MB); the rest is touched only
 * as far as the draws reach. FFT sides are 2^a, 3 * 2^a, 5 * 2^a and 7 * 2^a from min_fft to max_fft;
 * with a PSF, sides up to psf_table_fft are used only if they read one of its tables exactly
 * (they divide its period: psf_table_fft, or with extra_tables one more). */
wf_status wf_profile_work_need(const wf_profile_accuracy *acc, size_t *bytes, size_t *dense);
wf_status wf_profile_work_init(wf_profile_work *work, const wf_profile_accuracy *acc,
                               wf_arena *arena);
/* Forgets the work's plans (they are the process's); the arena memory is the caller's to
 * release. */
void wf_profile_work_free(wf_profile_work *work);
/* Changes the per-object knobs between draws (e.g. looser for faint objects, a larger
 * flux_fraction for bright stars); the others fix the buffers and stay. */
wf_status wf_profile_work_tune(wf_profile_work *work, double flux_fraction,
                               double folding_threshold, double kvalue_accuracy,
                               double wing_tolerance, double knot_accuracy);

/* Sets acc.cut_tolerance for the draws that follow (a per-object knob, as those above). */
wf_status wf_profile_work_tune_cut(wf_profile_work *work, double cut_tolerance);
/* keep 1: draws leave negative ringing in their stamps (stamp->clipped 0), so that the
 * Fourier cut adds no flux, for a renderer that sums objects and clips the sum at zero
 * (sim/draw/render.c); 0 (the default) sets it to zero. */
void wf_profile_keep_negatives(wf_profile_work *work, int keep);

/* Bytes wf_profile_psf_init keeps at most (*bytes) and the scratch each of its threads needs
 * while running (*scratch). */
wf_status wf_profile_psf_need(const wf_psf_image *img, const wf_profile_accuracy *acc,
                              size_t *bytes, size_t *scratch);
/* Tabulates the PSF's transform times the pixel's: the whole image's table, then each core's
 * and its wing on up to `threads` threads (the same tables for any count), as many as the
 * arena holds *bytes + threads x (*scratch + 64) + 64 for (one thread at least: *bytes +
 * *scratch + 128 is always enough; the tables are trimmed, so often less). Scratch is
 * taken from the arena's top and given back, so call it before reserving anything that must
 * outlive it. */
wf_status wf_profile_psf_init(wf_profile_psf *psf, const wf_psf_image *img,
                              const wf_profile_accuracy *acc, wf_arena *arena, int threads);

/* Stamp bounds around (x, y) holding acc.flux_fraction of the object's light (the PSF image's
 * sum counting as the whole PSF); psf NULL means no PSF (pixel response only). Stamps are
 * odd-sized and centred on the nearest pixel; when the light needs more than max_fft pixels
 * the stamp is max_fft - 1 wide and *fraction says how much it holds. fraction may be NULL. */
wf_status wf_profile_galaxy_bounds(wf_profile_work *work, const wf_galaxy *g,
                                   const wf_profile_psf *psf, double x, double y,
                                   wf_stamp *stamp, double *fraction);
wf_status wf_profile_point_bounds(const wf_profile_work *work, const wf_profile_psf *psf,
                                  double x, double y, wf_stamp *stamp, double *fraction);

/* Draw into stamp->pix over the stamp's bounds (overwritten, not added), in flux per pixel.
 * The object is centred at (x, y); the bounds may be anything within max_fft / 2 pixels of
 * it. The FFT side depends on the object and the knobs only, so a piece of a stamp (say
 * some of its rows) comes out bit-identical to the same pixels of the whole. Negative
 * ringing is set to zero and its magnitude returned in stamp->clipped (unless the work keeps
 * negatives). */
wf_status wf_profile_draw_galaxy(wf_profile_work *work, const wf_galaxy *g,
                                 const wf_profile_psf *psf, double x, double y,
                                 wf_stamp *stamp);
wf_status wf_profile_draw_point(wf_profile_work *work, const wf_profile_psf *psf, double flux,
                                double x, double y, wf_stamp *stamp);

/* The split PSF piece by piece, for a renderer that keeps only the core box of a stamp:
 * wf_profile_galaxy_core gives, with the work's current knobs, the galaxy's stamp bounds (as
 * wf_profile_galaxy_bounds) and which core its draw takes (*core: 0 none, else the core's
 * index + 1) and then its FFT box within them (else *box = *bounds);
 * wf_profile_draw_galaxy_core draws it without the wing (pixels beyond the box are zero;
 * negatives clipped), and wf_profile_add_wing adds flux x that core's wing at (x, y) to any
 * stamp (rows of it: the same pixels). Core plus wing is wf_profile_draw_galaxy's stamp but
 * for the clipping, done there on the sum. */
wf_status wf_profile_galaxy_core(wf_profile_work *work, const wf_galaxy *g,
                                 const wf_profile_psf *psf, double x, double y,
                                 wf_stamp *bounds, wf_stamp *box, int *core);
wf_status wf_profile_draw_galaxy_core(wf_profile_work *work, const wf_galaxy *g,
                                      const wf_profile_psf *psf, double x, double y,
                                      wf_stamp *stamp);
wf_status wf_profile_add_wing(const wf_profile_psf *psf, int core, double flux, double x,
                              double y, wf_stamp *stamp);
/* A renderer's rows of a split galaxy, each in one pass. wf_profile_wing_place fixes where
 * flux x that core's wing falls for an object at (x, y) (as wf_profile_add_wing: once per
 * object, not per row); wf_profile_add_wing_row then adds, for the columns i in [xa, xb) of
 * pixel row `row`, acc[i - xa] += max(b_i + wing, 0), b_i the box's pixel box[i - ca] for
 * i in [ca, cb) (within [xa, xb)) and 0 elsewhere or when box is NULL: the same bits as the
 * box row plus wf_profile_add_wing's, clipped and added. With keep_negatives set (by the
 * caller, after placing), acc[i - xa] += b_i, then += wing: no clip. */
typedef struct wf_profile_wing_at {
    const float *wing; /* the core's phase planes */
    int np;
    long plane[4];     /* the four planes read, (b0, a0), (b0, a1), (b1, a0), (b1, a1) */
    long ox[2], oy[2]; /* wing column of pixel column i: i + ox (row: j + oy) */
    double w[4];       /* flux x the bilinear weights */
    int keep_negatives; /* 0 from wf_profile_wing_place */
} wf_profile_wing_at;
wf_status wf_profile_wing_place(const wf_profile_psf *psf, int core, double flux, double x,
                                double y, wf_profile_wing_at *at);
wf_status wf_profile_add_wing_row(const wf_profile_wing_at *at, int row, int xa, int xb,
                                  const float *box, int ca, int cb, double *acc);

/* Knot positions (x, y) in arcsec before shear and rotation, as the draw uses them: from
 * g->knot_xy when given, else from the counter-based stream (knot_seed, id,
 * WF_PURPOSE_SCENE); radii follow the exponential disk of hlr_disk, angles are uniform. */
wf_status wf_profile_knots(const wf_galaxy *g, double *xy);

/* Shapes and sizes. */
/* GalSim's reduced shear g for a distortion e: g = e / (1 + sqrt(1 - |e|^2)). */
wf_status wf_profile_shear_from_distortion(double e1, double e2, double *g1, double *g2);
/* Half-light radius of the round exponential (n = 1) or de Vaucouleurs (n = 4) profile with
 * this full width at half maximum. */
wf_status wf_profile_hlr_from_fwhm(int sersic_n, double fwhm, double *hlr);
/* Fraction of a round exponential (n = 1) or de Vaucouleurs (n = 4) profile's flux within
 * radius r (arcsec) for half-light radius hlr. */
wf_status wf_profile_enclosed(int sersic_n, double hlr, double r, double *fraction);

/* Sérsic helpers, shared with the SN host placement (sim/sn/snhost.c): the regularised lower
 * incomplete gamma P(a, x) for integer a >= 1 (the enclosed flux of a Sérsic n profile is
 * P(2n, b_n (r/r_e)^(1/n))), and b_n, from P(2n, b_n) = 1/2. */
double wf_gamma_p_int(int a, double x);
double wf_sersic_b(int n);

#endif
