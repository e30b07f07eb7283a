/* Detector physics of the H4RG SCA: parameters and the closed-form effects.
 * Values default to SPEC §2 (GalSim galsim.roman, romanisim for the cosmic rays).
 * Every effect has a switch; a switched-off effect is skipped, not computed as identity. */
#ifndef WF_DETECTOR_H
#define WF_DETECTOR_H

#include <stddef.h>
#include <stdint.h>
#include <math.h>

typedef struct wf_detector {
    struct {              /* switches (1 on, 0 off) */
        int photon_noise, reciprocity, dark, nonlinearity, ipc, read_noise, quantize,
            saturation, cosmic_rays;
        int read_1f, channel_offsets, refpix; /* off by default (firmware/corrnoise.h) */
    } on;
    double dark_current;   /* e-/pixel/s [0.015] */
    double read_noise_e;   /* e- rms: per read in ramp mode, per exposure in single mode [8.5] */
    double gain;           /* e-/ADU [1.0] */
    double nl_beta;        /* q_meas = q + beta q^2 [-6.0e-7] */
    double recip_alpha;    /* [0.0065] */
    double recip_f0;       /* e-/s [1.0] */
    double ipc[3][3];      /* kernel, normalised to sum 1; ipc[a][b] weighs in[y+a-1][x+b-1] */
    double full_well;      /* e- [1e5] */
    double adc_max;        /* ADU [65535] */
    double bias_adu;       /* ADC offset added to every read, ADU [1000]: keeps read noise on
                              a near-empty pixel from clipping at 0 ADU; the ground subtracts it */
    /* cosmic rays (romanisim cr.py defaults; hit rate at L2) */
    double cr_rate;        /* hits / cm^2 / s [8] */
    double pixel_um;       /* pixel pitch [10] */
    double depth_um;       /* sensitive depth [5] */
    double cr_lmin_um, cr_lmax_um, cr_slope; /* path-length power law [10, 2000, -4.33] */
    double cr_dedx_loc, cr_dedx_scale;       /* Moyal, eV/um [120, 50] */
    double cr_ev_per_e;    /* eV per electron [3.8, romanisim] */
    /* correlated read noise (firmware/corrnoise.h; NGHXRG's JWST values, SPEC gives none) */
    double rn1f_corr_e;    /* e- rms per read of the 1/f shared by all channels [3] */
    double rn1f_uncorr_e;  /* e- rms per read of each channel's own 1/f [1] */
    double channel_offset_adu; /* rms of the per-channel offsets, ADU [20] */
} wf_detector;

/* SPEC §2 values, every effect on but the correlated read noise's (off). */
void wf_detector_defaults(wf_detector *det);

/* The raw GalSim IPC kernel (SPEC §2), normalised to sum 1 into out. */
void wf_detector_ipc_default(double out[3][3]);

/* q + beta q^2 (GalSim NLfunc). */
static inline double wf_det_nonlinearity(double q, double beta) { return q + beta * q * q; }

/* Charge after reciprocity failure, GalSim addReciprocityFailure:
 * q (q / (t f0))^(alpha / ln 10); q <= 0 is left unchanged (GalSim would give NaN). The same
 * lane as the rate form below (within a few ulp of pow's: hal/vmath.h). */
double wf_det_reciprocity(double q, double exptime, double alpha, double f0);

/* The same law on a rate: r (r / f0)^(alpha / ln 10), so q = r t obeys it at every t. */
double wf_det_reciprocity_rate(double rate, double alpha, double f0);

/* A row's expected electrons per frame time from the scene's rates (negative ones as 0):
 * mean = (reciprocity-failed rate + dark current) frame_time, each as det switches them,
 * and expm = exp(-mean) (wf_vexp: 0 beyond a mean of 708). */
void wf_det_expected_row(const wf_detector *det, const float *rate, int n, double frame_time, double *mean,
                         double *expm);

/* One output row of IPC: out[x] = sum_ab K[a][b] in_{a}[x+b-1], in_0 = row above (y-1),
 * in_1 = this row, in_2 = row below (y+1); a NULL row and columns outside [0, ncols) are
 * zero (GalSim's zero padding: a flat image loses charge at the edges). */
void wf_det_ipc_row(const double *above, const double *row, const double *below, int ncols,
                    const double k[3][3], double *out);

/* Round half to even (the ADC's rounding, GalSim quantize): nearbyint in the default
 * rounding mode, which no code here changes; inline for the per-read loop, where it becomes
 * one vector rounding instruction (the build's -fno-math-errno -fno-trapping-math). (The
 * magic-number rounding it replaced, still in detector.c's lanes, left 2^51 <= |x| < 2^52
 * unrounded: far beyond any ADU, which the ADC clamps to 65535.) */
static inline double wf_det_quantize(double adu) { return nearbyint(adu); }

/* Index of the first value that is not finite (a scene's rates), -1 when all are. */
int wf_det_first_nonfinite(const float *v, int n);

/* Expected electrons of a row: rate x exptime, negative rates set to zero first (GalSim). */
void wf_det_exposure_row(const float *rate, double exptime, int n, double *e);

/* Reciprocity failure of whole electron counts q[i] (Poisson draws), in place, then + add[i]
 * (when add is not NULL): table[k] = wf_det_reciprocity(k, exptime, recip_alpha, recip_f0)
 * for k < ntable, tabulated by the caller for the exposure; other values are computed. Same
 * bits as wf_det_reciprocity on every count. */
void wf_det_reciprocity_counts(const wf_detector *det, double exptime, const double *restrict table,
                               int ntable, const double *restrict add, int n, double *restrict q);

/* Full well (when saturation is on) and nonlinearity (when on) of a row of charge: what the
 * read-out would measure; out may be q. */
void wf_det_measure_row(const wf_detector *det, const double *q, int n, double *out);
/* The same, and q itself held at the full well (saturation on): the charge a pixel keeps,
 * in the pass that measures it. */
void wf_det_hold_measure_row(const wf_detector *det, double *q, int n, double *out);

/* One row of single-frame output from the measured charge after IPC, e[x], and the collected
 * charge q[x]: read noise (when on) sigma z[x] with sigma = read_noise_e, gain and bias,
 * quantization (when on, round half to even as wf_det_quantize), the ADC range (when
 * saturation is on), rounded to float; sat[x] = 0 where the pixel reached the full well or
 * the ADC ceiling, untouched elsewhere. The five arrays must not overlap. */
void wf_det_single_row(const wf_detector *det, const double *e, const double *q,
                       const float *z, int n, float *out, uint8_t *sat);

/* One read of an up-the-ramp row, as wf_det_single_row digitises (read noise, gain,
 * quantization, ADC range) but in double: sum[x] += the read's ADU, and the resultant r
 * recorded in first_sat[x] where it is still 255 and the pixel reached the full well (q) or
 * the ADC ceiling (when saturation is on): r < 255, and never below an r of an earlier call
 * for the same row (reads in order). The arrays must not overlap. */
void wf_det_ramp_read_row(const wf_detector *det, const double *e, const double *q,
                          const float *z, int n, uint8_t r, double *sum, uint8_t *first_sat);

/* A resultant's row from its reads' ADU sums: out[x] = sum[x] / nreads rounded half to even
 * into [0, 65535] (NaN: 0), and sum[x] = 0 for the next. */
void wf_det_resultant_row(double *sum, int n, int nreads, uint16_t *out);

/* A resultant drawn at once (the ramp's direct and moments sampling), as one read of
 * wf_det_ramp_read_row with the read noise of the mean of nreads reads, sigma/sqrt(nreads):
 * e the resultant's charge, q the charge at its last read, which saturates the resultant
 * where it reached the full well or, after nonlinearity, the ADC ceiling; out[x] as
 * wf_det_resultant_row rounds. The arrays must not overlap. */
void wf_det_group_row(const wf_detector *det, const double *e, const double *q, const float *z,
                      int n, int nreads, uint8_t r, uint8_t *first_sat, uint16_t *out);

/* Smallest ADU value that means saturated: the lower of the ADC ceiling and the full well
 * after nonlinearity and gain, plus the bias. */
double wf_det_saturation_adu(const wf_detector *det);

#endif
