/* The Roman entrance pupil and the wavefront over it (SPEC §2, §4.1; docs/OPTICS.md).
 *
 * A pupil is an n × n grid of amplitude samples `dx` metres apart. Sample (i, j) — i along
 * FITS x (pupil u), j along FITS y (pupil v) — sits at
 *
 *     u = (i - n/2) dx,   v = (j - n/2) dx,
 *
 * GalSim's convention for an even-sized pupil image (its centre is the optical axis), so that
 * the Zernike wavefront is evaluated where GalSim evaluates it.
 *
 * Two sources:
 *  - data: GalSim's per-SCA masks (from WebbPSF, Cycle 9), <dir>/roman/RST_WIM_Filter_skinny_
 *    SCA_N.fits.gz for the short-wave group and ..._F184_SCA_N.fits.gz for F184 and K213:
 *    2048² int16 (0 or 255), PIXELSCL = 1.17979 mm per pixel at the entrance pupil;
 *  - analytic: a circle of diameter 2.36 m with a central obscuration and straight struts of
 *    finite width (wf_pupil_geometry), rasterised on the same 2048² grid so that binning
 *    treats both alike.
 * Binning by `bin` (1, 2, 4, 8; GalSim's pupil_bin) follows GalSim: a binned sample is open
 * (amplitude 1) when any of its bin² native samples is open. It dilates the aperture by up
 * to one binned sample at every edge, which is why pupil_bin 8 and 4 PSFs differ by ~1% in
 * peak in GalSim's own outputs; WF_PUPIL_BIN_MEAN (grey amplitude = open fraction) is the
 * alternative that keeps the open area.
 *
 * Aberrations: Noll Zernike coefficients Z1..Z22 in waves at 1293 nm from
 * <dir>/roman/Roman_Cycle-9_WFI_zim_zernikes_082623_NN.txt (5 field points: the SCA centre and
 * four corners), interpolated bilinearly between the corners as GalSim does. Without data the
 * wavefront is flat (no aberrations), which is documented as the no-data default. */
#ifndef WF_PUPIL_H
#define WF_PUPIL_H

#include <stddef.h>
#include "hal/status.h"

#define WF_PUPIL_DIAM 2.36                   /* m, SPEC §2 (GalSim roman.diameter) */
#define WF_PUPIL_OBSCURATION 0.32            /* linear, SPEC §2 */
#define WF_PUPIL_NATIVE_N 2048               /* samples across the mask files */
#define WF_PUPIL_NATIVE_DX 0.00117978731902147 /* m per mask sample (their PIXELSCL) */
#define WF_PUPIL_MAX_STRUTS 8
#define WF_ZERNIKE_MAX 22                    /* Noll indices carried (the data's Z1..Z22) */
#define WF_ABERR_LAMBDA_NM 1293.0            /* wavelength of the coefficients' "waves" */
#define WF_SCA_NPIX 4088                     /* active pixels per side (SPEC §2) */
#define WF_PUPIL_SOURCE_MAX 1100

typedef enum wf_pupil_group {
    WF_PUPIL_SHORT = 0, /* R062 Z087 Y106 J129 H158 W146: the "skinny" mask */
    WF_PUPIL_LONG = 1   /* F184 K213: the long-wave mask (larger cold stop obscuration) */
} wf_pupil_group;

typedef enum wf_pupil_binning {
    WF_PUPIL_BIN_ANY = 0, /* GalSim: open if any native sample is open */
    WF_PUPIL_BIN_MEAN = 1 /* amplitude = open fraction of the native samples */
} wf_pupil_binning;

/* A straight strut: the band of points within width/2 of the line whose direction is
 * angle_deg (counter-clockwise from +u) and whose signed distance from the axis is offset_m
 * (positive to the left of the direction), on the outer side of the obscuration. */
typedef struct wf_pupil_strut {
    double angle_deg;
    double offset_m;
    double width_m;
} wf_pupil_strut;

typedef struct wf_pupil_geometry {
    double diam;        /* outer diameter, m */
    double obscuration; /* central obscuration diameter / diam */
    int nstruts;
    wf_pupil_strut strut[WF_PUPIL_MAX_STRUTS];
} wf_pupil_geometry;

typedef struct wf_pupil {
    int n;              /* samples per side */
    int bin;            /* native samples per side of one sample */
    double dx;          /* m per sample */
    double diam;        /* m: the Zernike unit circle has radius diam/2 */
    float *amp;         /* amp[j * n + i], 0..1 (host malloc) */
    int i0, i1, j0, j1; /* inclusive bounding box of the samples with amp > 0 */
    double open_area;   /* Σ amp² dx², m² */
    int from_data;      /* 1: a mask file; 0: analytic */
    char source[WF_PUPIL_SOURCE_MAX];
} wf_pupil;

typedef struct wf_aberrations {
    double z[WF_ZERNIKE_MAX + 1]; /* z[j]: Noll j = 1..22, waves at lambda_ref_nm; z[0] unused */
    double lambda_ref_nm;
    char source[WF_PUPIL_SOURCE_MAX];
} wf_aberrations;

/* The pupil group of a filter name (case-insensitive; W149 is W146). */
wf_status wf_pupil_group_of_filter(const char *filter, wf_pupil_group *out);

/* The built-in analytic geometry of a group (docs/OPTICS.md gives the values and how they
 * compare with the masks). */
wf_status wf_pupil_geometry_default(wf_pupil_group group, wf_pupil_geometry *out);

/* Loads the mask of (sca, group) from data_dir (a folder laid out as ../shared/data, i.e.
 * holding roman/…, or the roman folder itself) and bins it. Reads `bin` rows at a time, so
 * the memory used is the binned pupil plus bin native rows. */
wf_status wf_pupil_load(const char *data_dir, int sca, wf_pupil_group group, int bin,
                        wf_pupil_binning binning, wf_pupil *out);

/* Rasterises geometry g on the native 2048² grid (a native sample is open when its centre is)
 * and bins it like a mask. */
wf_status wf_pupil_analytic(const wf_pupil_geometry *g, int bin, wf_pupil_binning binning,
                            wf_pupil *out);

void wf_pupil_free(wf_pupil *p);

/* Noll Zernike j (1..WF_ZERNIKE_MAX) at (x, y) in units of the pupil radius, normalised to
 * unit rms over the unit disc (Noll 1976; GalSim's convention: even j cos mφ, odd j sin mφ). */
wf_status wf_pupil_zernike(int j, double x, double y, double *out);

/* The same split for a wavefront's many samples: a term's radial coefficients and
 * normalisation once (wf_pupil_zernike_term, WF_ERR_RANGE for j outside 1..22), then each
 * sample (wf_pupil_zernike_eval, the same bits as wf_pupil_zernike). */
typedef struct wf_zernike_term {
    int m, is_sin, ncoef;
    double coef[12]; /* c_s, the lowest power of ρ² first */
    double norm;
} wf_zernike_term;
wf_status wf_pupil_zernike_term(int j, wf_zernike_term *t);
double wf_pupil_zernike_eval(const wf_zernike_term *t, double x, double y);

/* No aberrations (the no-data default). */
void wf_pupil_aberrations_none(wf_aberrations *out);

/* The aberrations of sca at SCA pixel position (x, y) (GalSim's image coordinates: 1-based,
 * the SCA centre is (2044, 2044)), bilinear between the four corner field points. Z1-Z3
 * (piston, tip, tilt) are set to zero as GalSim does: tip and tilt would only move the PSF
 * away from the object's position. A position off the SCA (an object partly on it) takes the
 * aberrations of the nearest point of the corners' box; a non-finite one is an error. */
wf_status wf_pupil_aberrations_load(const char *data_dir, int sca, double x, double y,
                              wf_aberrations *out);

#endif
