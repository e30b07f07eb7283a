/* Tile-compressed image HDUs for products a survey can keep (docs/SURVEY.md, "Products a
 * survey can keep"). cfitsio stores a compressed image as a binary table whose heap holds
 * one compressed tile per row, appended in the order the tiles are written. An SCA product's
 * HDUs are written side by side, tile by tile and in whatever order the readout threads
 * finish, so each compressed HDU is written into its own part file and appended to the
 * product when complete, its heap laid out again in tile order: the bytes then depend on
 * the pixels alone, not on thread count or tile height. Tiles are one image row (one row of
 * one resultant in a cube), so any run of whole rows is whole tiles. Integer HDUs are Rice
 * coded, losslessly; float HDUs are quantized to a step of (noise / q), where the noise is
 * cfitsio's estimate from the tile's pixel differences, with subtractive dithering whose
 * seed the caller derives from the product's identity, then Rice coded; q = 0 keeps floats
 * exact (GZIP). */
#ifndef WF_FITSCOMP_H
#define WF_FITSCOMP_H

#include <fitsio.h>
#include <stdint.h>
#include "hal/status.h"

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
 * closes the part and removes its file (also on failure). dst_path names dst in messages. */
wf_status wf_fits_part_append(fitsfile *dst, const char *dst_path, fitsfile *part, const char *part_path);

/* Closes and removes a part left over by a failure (f may be NULL). */
void wf_fits_part_discard(fitsfile *f, const char *path);

#endif
