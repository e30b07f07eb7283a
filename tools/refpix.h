/* The ground's reference-pixel correction of up-the-ramp resultants (docs/PACKETS.md, REFROWS
 * and REFCOLS), as the standard "refpix" step makes it, before the ramp fit:
 *   1. each output channel's offset in each resultant: the mean of the channel's pixels in
 *      the eight reference rows (full-frame rows 0-3 and the last four), less the bias;
 *   2. each row's common mode: the mean of its eight side reference pixels (full-frame
 *      columns 0-3 and the last four) less their channels' offsets and the bias.
 * Resultant r of active pixel (x, y) is corrected by subtracting both. The side pixels are
 * read at the row's first four pixel times of every channel (alternating scan directions),
 * so step 2 removes the 1/f shared by the channels that is slow against a row (~1 kHz); no
 * smoothing across rows, which would make a row's correction wait for its neighbours' tiles.
 * Host tools only (malloc). */
#ifndef WF_REFPIX_H
#define WF_REFPIX_H

#include <stdint.h>
#include "hal/status.h"

typedef struct wf_refpix {
    int nres, ncols, nrows, width, nchan;
    double bias;
    double *chan;       /* [nres][nchan] channel offsets, ADU */
    int have_rows;
    uint16_t *rows;     /* [nres][8][width] as received (for the product) */
    uint16_t *side;     /* [nres][nrows][8] as received */
    uint8_t *side_in;   /* [nrows] 1 once the row's side pixels arrived */
} wf_refpix;

wf_status wf_refpix_init(wf_refpix *rp, int nres, int ncols, int nrows, double bias);
void wf_refpix_free(wf_refpix *rp);

/* A REFROWS payload, u16 [nres][8][width] (little-endian bytes). */
void wf_refpix_set_rows(wf_refpix *rp, const unsigned char *payload);

/* A REFCOLS payload for active rows y0 .. y0 + n - 1, u16 [nres][n][8] (little-endian). */
void wf_refpix_set_cols(wf_refpix *rp, uint32_t y0, uint32_t n, const unsigned char *payload);

/* 1 when row y can be corrected (the reference rows and its side pixels are in). */
int wf_refpix_ready(const wf_refpix *rp, uint32_t y);

/* corr[r * ncols + x]: what to subtract from resultant r of active row y, ADU. */
void wf_refpix_correction(const wf_refpix *rp, uint32_t y, double *corr);

#endif
