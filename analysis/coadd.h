/* `wfisim coadd`: drizzle (analysis/drizzle.h) any number of products of one filter onto a
 * TAN grid, pixels flagged in DQ left out, each input weighted by the inverse variance of its
 * sky (1 / median(ERR)^2 over its good pixels: one weight per input, so that a source's own
 * shot noise does not bias its flux).
 *
 * Memory is bounded by the output tile being built, never by the number of inputs: the
 * output is made tile_rows rows at a time; for each tile every input whose footprint meets it
 * is opened, and only the input rows that map into the tile are read, a block at a time
 * (cfitsio's image API: tile-compressed products read the same way). Inputs are processed in
 * a canonical order (MJD, exposure, SCA, path), sums are in double, and every output pixel
 * receives its drops in that order whatever the tile height: the product is bit-identical
 * for any argument order and any tile_rows.
 *
 * Product (FILE.tmp, renamed when whole, CHECKSUM/DATASUM on every HDU):
 *   primary  FILTER, NINPUT, KERNEL, PIXFRAC, PIXSCALE, DQMASK, MJD-BEG/MJD-END
 *   SCI      float32, e-/s per output pixel (flux-conserving: see drizzle.h), 0 where WHT = 0
 *   ERR      float32, e-/s per output pixel, standard deviation of SCI from ERR of inputs
 *   WHT      float32, drizzle's weight sum(input weight x overlap / drop area)
 *   CTX      int32, number of inputs that contributed to the pixel
 *   INPUTS   table: FILE, EXPOSURE, SCA, MJD, FILTER, WEIGHT (0: not on the grid), one row
 *            per input
 * Every image HDU carries the grid's TAN WCS. */
#ifndef WF_COADD_H
#define WF_COADD_H

#include <stdint.h>
#include "hal/status.h"
#include "sim/survey/wcs.h"

#define WF_COADD_PIXSCALE 0.0575 /* arcsec per output pixel */
#define WF_COADD_PIXFRAC 0.7

typedef struct wf_coadd_opts {
    double ra, dec;     /* centre of the output grid, degrees */
    int nx, ny;         /* output pixels */
    double pixscale;    /* arcsec per output pixel */
    double pa;          /* position angle of the output +y axis, degrees east of north */
    double pixfrac;     /* (0, 1] */
    int tile_rows;      /* output rows per tile (memory only, never the result) */
    uint32_t dq_mask;   /* DQ bits that exclude a pixel */
    double mjd_lo, mjd_hi; /* inputs whose MJD-OBS lies outside [lo, hi] are left out (a
                              template of the epochs before or after a date); +-inf: all */
    int quiet;
} wf_coadd_opts;

/* The defaults above, tile_rows 256, dq_mask all bits, every MJD; centre and size unset (0). */
void wf_coadd_opts_default(wf_coadd_opts *o);

/* The output grid: TAN, CRPIX at the centre ((n + 1) / 2, FITS), +y at position angle pa. */
wf_status wf_coadd_grid(const wf_coadd_opts *o, wf_wcs *out);

/* Drizzles the n products at paths into out. Bad input (no product, no WCS, no SCI/ERR/DQ,
 * mixed filters, the same exposure and SCA twice, nothing overlapping the grid, no input
 * within the MJD range) is WF_ERR_INPUT naming the file, and no product is written. Inputs
 * outside the MJD range are read for their header only, and leave no trace in the product. */
wf_status wf_coadd_run(const char *const *paths, int n, const wf_coadd_opts *o, const char *out);

/* The same onto a given grid of nx x ny pixels (o's centre, size, scale and PA unused): any
 * wf_wcs, e.g. a coadd's read back by wf_wcs_read_header (wfisim diff). */
wf_status wf_coadd_run_grid(const char *const *paths, int n, const wf_coadd_opts *o, const wf_wcs *grid,
                            const char *out);

/* argv holds the options after "coadd". Returns 0 done, 1 failure, 2 bad usage or input. */
int wf_cmd_coadd(int argc, char **argv);

#endif
