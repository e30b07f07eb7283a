/* Correlated read noise of the H4RG's 32 output channels: 1/f noise along each channel's
 * readout order and per-channel offsets, on the whole 4096-wide frame including the 4-pixel
 * reference border (docs/ARCHITECTURE.md, "Correlated read noise").
 *
 * Geometry: full-frame column X = x + 4, row Y = y + 4 for active pixel (x, y); channel
 * c = X / 128 reads its 128 columns in parallel with the others, even channels left to right,
 * odd channels right to left (the HxRG's alternating scan, so both side reference columns
 * are read at the same times); a row takes 128 + 12 pixel times (the overhead of a new row,
 * NGHXRG's value) and a frame 4096 rows, so a pixel time is frame_time / (4096 x 140).
 *
 * 1/f noise: a sum of WF_CN_NCOMP Ornstein-Uhlenbeck processes with equal variances and
 * corner frequencies log-spaced from one per frame to the pixel Nyquist frequency, one
 * realisation shared by all channels (amplitude det->rn1f_corr_e) plus one per channel
 * (det->rn1f_uncorr_e), independent from read to read. No value depends on state carried
 * between rows: a row's start value comes from a dyadic OU bridge over the frame's rows whose
 * every node is drawn from its own key, and the row's pixels are OU bridge steps from there
 * to the next row's start. So a row is the same whichever tile or thread asks for it. */
#ifndef WF_CORRNOISE_H
#define WF_CORRNOISE_H

#include <stddef.h>
#include <stdint.h>
#include "firmware/detector.h"
#include "hal/arena.h"
#include "hal/noise.h"

#define WF_CN_BORDER 4          /* reference pixels on each side */
#define WF_CN_CHANNEL_COLS 128  /* columns per output channel */
#define WF_CN_ROW_TIME 140      /* pixel times per row: 128 + 12 overhead */
#define WF_CN_FRAME_ROWS 4096   /* rows of a full frame, for the frame's duration */
#define WF_CN_NCOMP 12          /* OU processes in the 1/f sum */
#define WF_CN_MAX_LEVELS 13     /* dyadic bridge depth: 2^13 > 4096 + 8 rows */

typedef struct wf_corrnoise {
    wf_noise noise;
    int width, height;  /* full frame: ncols + 8, nrows + 8 */
    int nchan;          /* channels (the last may be narrower than 128 on a small SCA) */
    int levels;         /* 2^levels >= height */
    double amp_c, amp_u;               /* e- rms of the shared and per-channel 1/f */
    double lambda[WF_CN_NCOMP];        /* OU rates, per pixel time */
    double sd;                         /* each component's stationary rms per unit amplitude */
    double step[WF_CN_NCOMP][WF_CN_CHANNEL_COLS][3]; /* bridge step into position i:
                                                        a x_(i-1) + b x_end, rms c (unit sd) */
    double mid[WF_CN_MAX_LEVELS][WF_CN_NCOMP][3]; /* bridge midpoint of a level's interval */
    double frame_end[WF_CN_NCOMP][2];   /* the frame's far end from its start: r, rms */
    double *offset;     /* [nchan]: the channel offsets, e- */
    double *x0, *x1;    /* [nchan + 1][comp]: values at this row's start and the next's */
    uint32_t *w;        /* [4][(nchan + 1) x 128] noise words */
    float *z;           /* [comp][(nchan + 1) x 128] normals, by channel and readout position */
    double *path;       /* [nchan + 1][128] one row's processes by readout position */
    int have_row;       /* x1 holds row next_row's start for key next_key */
    int next_row;
    uint32_t next_key;
} wf_corrnoise;

/* Arena bytes for a readout of ncols active columns. */
size_t wf_corrnoise_arena_need(int ncols);

/* Sets up the model for an SCA of ncols x nrows active pixels, for the effects det turns on
 * (read_1f: the 1/f amplitudes; channel_offsets: the per-channel offsets, drawn once). */
wf_status wf_corrnoise_init(wf_corrnoise *cn, const wf_detector *det, const wf_noise *noise, int ncols,
                            int nrows, wf_arena *arena);

/* out[X], X in [0, width): the correlated noise of full-frame row Y in one read, e-: 1/f
 * times scale (1 for a read; 1/sqrt(n) for the mean of n reads drawn at once, exact for
 * independent reads) plus the channel offsets. key names the realisation (the read, or the
 * resultant in direct sampling with the high bit set). */
void wf_corrnoise_row(wf_corrnoise *cn, uint32_t key, int Y, double scale, double *out);

/* Standard normals for the white read noise of reference pixels X0 .. X0 + n - 1 of row Y
 * (the active pixels' come from their photon streams), into z[0 .. n - 1]. */
void wf_corrnoise_ref_normals(wf_corrnoise *cn, uint32_t key, int Y, int X0, int n, float *z);

/* Readout position of full-frame column X within its channel (0 first read). */
static inline int wf_corrnoise_position(int X)
{
    int c = X / WF_CN_CHANNEL_COLS, j = X % WF_CN_CHANNEL_COLS;
    return c & 1 ? WF_CN_CHANNEL_COLS - 1 - j : j;
}

/* The model's 1/f rates per pixel time and the rms of each component per unit amplitude. */
void wf_corrnoise_components(double lambda[WF_CN_NCOMP], double *sd);

/* Expected autocovariance of the 1/f (unit amplitude) at a lag of k pixel times:
 * sum_j sd^2 exp(-lambda_j |k|); with amplitude a, multiply by a^2. */
double wf_corrnoise_acov(double k);

#endif
