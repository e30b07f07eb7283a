/* Source detection and photometry on a wfisim image (`wfisim detect`), through SEP: the C
 * library of Source Extractor's background mesh, matched filter, thresholding, deblending and
 * aperture sums (docs/ANALYSIS.md, "Detection").
 *
 * Input: a FITS file with an image HDU "SCI" (else a 2-d primary image) in e-/s and a
 * celestial TAN or TAN-SIP WCS on it; "ERR" (1-sigma, same unit) is the per-pixel noise and
 * "DQ" a mask (DO_NOT_USE pixels are ignored) when present. Tile-compressed HDUs are read
 * through cfitsio's image API like plain ones.
 * Output: a FITS binary table "CATALOG", one row per object (columns in docs/ANALYSIS.md):
 * X, Y are FITS 1-based pixel centres like the truth tables and SExtractor (PIXCONV), theta
 * is degrees counter-clockwise from the image +x axis (SExtractor's THETA_IMAGE), PA_SKY the
 * same axis's position angle east of north. */
#ifndef WF_DETECT_H
#define WF_DETECT_H

#include "hal/status.h"

typedef struct wf_detect_options {
    double thresh;          /* detection threshold in units of ERR (sigma) [1.5] */
    double noise_scale;     /* ERR's sigma times this is the threshold's unit [1, SExtractor's];
                             * 0: measured (auto, wf_detect_noise_ratio) */
    int minarea;            /* minimum pixels above threshold [5] */
    int back_size;          /* background mesh cell, pixels [64] */
    int back_filter;        /* median filter of the mesh, cells [3] */
    double aper_radius;     /* circular aperture radius [2.5 pixels: SExtractor's 5-px diameter] */
    int aper_arcsec;        /* 1: aper_radius is in arcsec (converted by the WCS pixel scale) */
    int filter;             /* 1: convolve with SExtractor's default 3x3 pyramid before thresholding */
    int deblend_nthresh;    /* [32] */
    double deblend_cont;    /* [0.005] */
    double kron_fact;       /* PHOT_AUTOPARAMS: Kron factor [2.5] */
    double kron_minrad;     /* and minimum radius, in units of a and b [3.5] */
    char data_dir[1024];    /* Roman data for the bandpass zero point ("": built-in top-hat) */
} wf_detect_options;

typedef struct wf_detect_summary {
    long nobj;              /* rows written */
    int nx, ny;             /* image size */
    double back, back_rms;  /* SEP's global background and its RMS, e-/s */
    long masked;            /* pixels masked (DQ DO_NOT_USE, non-finite SCI or ERR, ERR <= 0) */
    double noise_scale;     /* the unit of the threshold in ERR's sigma (given or measured) */
} wf_detect_summary;

/* SExtractor's defaults (above). */
void wf_detect_defaults(wf_detect_options *o);

/* Detects and measures the objects of image_path and writes the catalog to out_path (through
 * out_path.tmp, with CHECKSUM). An image without a celestial WCS, a missing HDU or a bad
 * option is WF_ERR_INPUT naming the file and what is wrong, and nothing is written. */
wf_status wf_detect_file(const char *image_path, const char *out_path, const wf_detect_options *o,
                         wf_detect_summary *sum);

/* The measured noise of the (filtered, when filter) background-subtracted image sci over
 * what err predicts for it were pixels independent: 1 for independent noise, above 1 where
 * resampling correlated them. Masked pixels (and neighbours touching them) are left out;
 * nsamples counts the pixels used. WF_ERR_INPUT when too few are left. */
wf_status wf_detect_noise_ratio(const float *sci, const float *err, const unsigned char *mask, int nx, int ny,
                                int filter, double *ratio, long *nsamples);

/* `wfisim detect IMAGE --out CAT.fits [options]`: argv holds what follows "detect". Returns
 * the exit status: 0 done, 1 failure (I/O, memory), 2 bad usage or input. */
int wf_cmd_detect(int argc, char **argv);

#endif
