/* Tile-compressed image HDUs for products a survey can keep (docs/SURVEY.md, "Products a
 * survey can keep"). cfitsio stores a compressed image as a binary table whose heap holds
 * one compressed tile per row, appended in the order the tiles are written. An SCA product's
 * HDUs are written side by side, tile by tile and in whatever order the readout threads
 * finish, so each compressed HDU is written into its own part file and appended to the
 * product when complete, its heap laid out again in tile order: the bytes then depend on
 * the pixels alone, not on thread count or tile height. Tiles are one image row (one row of
 * one resultant in a cube), so any run of whole rows is whole tiles. Integer HDUs are Rice
 * coded, losslessly; float HDUs are quantized to a step of (noise / q), the noise measured
 * on each row by wf_fits_row_noise and handed to cfitsio as an absolute step (cfitsio's own
 * estimate takes three medians a tile: half the assembly's CPU), with subtractive dithering
 * whose seed the caller derives from the product's identity, then Rice coded; q = 0 keeps
 * floats exact (GZIP). */
#ifndef WF_FITSCOMP_H
#define WF_FITSCOMP_H

#include <fitsio.h>
#include <stdint.h>
#include "hal/status.h"
#include "sim/fits/fitsout.h"

typedef struct wf_fits_comp {
    double quantize;  /* float HDUs: cfitsio's q, >= 1; 0: lossless (GZIP_2, no quantization) */
    int dither_seed;  /* ZDITHER0, 1..10000 */
} wf_fits_comp;

/* ZDITHER0 of a product: a hash of (seed, exposure, SCA) into 1..10000, so a product's
 * dither is its own and the same on every run. */
int wf_fits_comp_dither_seed(uint64_t seed, uint32_t exposure, uint32_t sca);

/* Creates the part file at path (an old one is replaced) holding an empty primary HDU and
 * one compressed image HDU of the given type and shape, current in *f; the caller writes
 * its header keywords (EXTNAME with fits_update_key: cfitsio writes one of its own) and
 * pixels through cfitsio, in whole rows. */
wf_status wf_fits_part_create(const char *path, const wf_fits_comp *c, int bitpix, int naxis,
                              long *naxes, fitsfile **f);

/* Appends the part's compressed HDU to dst as its new last HDU, heap in tile order, then
 * closes the part and removes its file (also on failure). dst_path names dst in messages.
 * sum (when not NULL) receives the new data unit's checksum, summed as it is written, so
 * that closing the product need not read it back (invalid when that could not be done). */
wf_status wf_fits_part_append(fitsfile *dst, const char *dst_path, fitsfile *part, const char *part_path,
                              wf_fits_datasum *sum);

/* Writes nrows whole rows of ncols pixels from row row0 (0-based) of the part's image,
 * cfitsio's way (returns and sets *status). TFLOAT rows of a quantized part are written one
 * by one, each at a step of wf_fits_row_noise / q: quantized by cfitsio's own
 * fits_quantize_float and, as integer rows (TUSHORT, TSHORT, TUINT, TINT) are, Rice coded by
 * sim/fits/rice.h into the same bytes cfitsio writes, several times faster (a float row with
 * a nonfinite pixel, or that does not quantize, is left to cfitsio). */
int wf_fits_part_write_rows(fitsfile *f, int type, long ncols, LONGLONG row0, long nrows, void *data, int *status);

/* Tiles sim/fits/rice.h has coded in this process (tests check that it is the coder used). */
long wf_fits_own_rice_tiles(void);

/* The noise of a row of n pixels: 0.6052697 x the median of |2 x_i - x_(i-2) - x_(i+2)|,
 * sigma for independent Gaussian pixels (cfitsio's "noise3" estimator, DER_SNR); 0 when
 * there is nothing to measure. scratch holds n floats. */
double wf_fits_row_noise(const float *row, long n, float *scratch);

/* Closes and removes a part left over by a failure (f may be NULL). */
void wf_fits_part_discard(fitsfile *f, const char *path);

#endif
