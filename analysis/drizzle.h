/* The drizzle kernel (Fruchter & Hook 2002), square: every input pixel's "drop" is the
 * pixel shrunk by pixfrac about its centre and mapped onto the output grid, where it adds to
 * each output pixel in proportion to the exact area of their overlap.
 *
 * Conventions (those of STScI's drizzle, cdrizzle's square kernel, so the two compare):
 *  - output pixel (i, j), 0-based, is the square [i - 0.5, i + 0.5] x [j - 0.5, j + 0.5];
 *  - a drop's corners are the input-to-output map bilinearly interpolated between pixel
 *    centres at (x +- pixfrac/2, y +- pixfrac/2), as drizzle interpolates its pixmap;
 *  - a drop of value d (e-/s in its input pixel) and weight w adds, to each output pixel it
 *    overlaps by area a (output pixels), weight c = w a / J to WHT and c v to the weighted
 *    sum, where J is the drop's area and v = d pixfrac^2 / J: the input pixel's flux spread
 *    over the area it covers, i.e. e-/s per output pixel. STScI's drizzle multiplies by one
 *    global (output/input scale)^2 instead of the local pixfrac^2 / J; the two agree where
 *    the map is affine and differ by the pixel-area variation (SIP distortion) elsewhere,
 *    where the local area is the one that conserves flux.
 *  - The output is SCI = sum(c v) / sum(c), WHT = sum(c), and ERR = sqrt(sum(c^2 var(v))) /
 *    sum(c): each output pixel's own standard deviation for independent input pixels (it
 *    leaves out the covariance between neighbouring output pixels that drizzling creates). */
#ifndef WF_DRIZZLE_H
#define WF_DRIZZLE_H

#include <stdint.h>
#include "hal/status.h"

/* Area of the overlap between the convex quadrilateral (x[k], y[k]), k = 0..3 in order
 * around it (either direction), and output pixel (i, j). */
double wf_drizzle_overlap(const double x[4], const double y[4], int i, int j);

/* The accumulators of output rows [y0, y0 + ny), all nx columns, in double. */
typedef struct wf_drizzle_tile {
    int nx, y0, ny;
    double *sum;   /* sum of c v */
    double *wht;   /* sum of c */
    double *var;   /* sum of c^2 var(v) */
    int32_t *ctx;  /* inputs with c > 0 */
    int32_t *last; /* the last input counted in ctx (id), so each counts once */
} wf_drizzle_tile;

wf_status wf_drizzle_tile_alloc(wf_drizzle_tile *t, int nx, int max_rows);
void wf_drizzle_tile_reset(wf_drizzle_tile *t, int y0, int ny);
void wf_drizzle_tile_free(wf_drizzle_tile *t);

/* One block of an input: nr rows by nc columns of SCI, ERR and DQ (row-major, rows `stride`
 * elements apart), and the output position of every pixel centre of the block with a one-pixel border:
 * ox/oy[(r + 1) * (nc + 2) + (c + 1)] for r = -1..nr, c = -1..nc. */
typedef struct wf_drizzle_block {
    int nr, nc, stride;
    const float *sci, *err;
    const uint32_t *dq;
    const double *ox, *oy;
    double weight; /* every pixel's: one per input (its sky's 1/ERR^2, analysis/coadd.h) */
} wf_drizzle_block;

/* Drops every good pixel of the block (DQ & dq_mask == 0, SCI finite, ERR finite and > 0)
 * onto the tile with the block's weight and ERR^2 as its variance. id identifies the input
 * for CTX (> 0, one per input).
 * Returns the number of drops that landed on the tile. */
long wf_drizzle_add(wf_drizzle_tile *t, const wf_drizzle_block *b, double pixfrac,
                    uint32_t dq_mask, int32_t id);

/* One drop: corners (x[4], y[4]) in order, value d, weight w, variance of d. */
int wf_drizzle_drop(wf_drizzle_tile *t, const double x[4], const double y[4], double pixfrac,
                    double d, double w, double var_d, int32_t id);

#endif
