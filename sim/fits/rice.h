/* Rice coding of one tile of integer pixels, as the FITS tiled-image convention defines
 * RICE_1 (Pence, White & Seaman 2010; FITS tile compression 2.3 section 6.1): the first pixel
 * raw, then per block of pixels a code of the split k followed by each difference from the
 * previous pixel, mapped to an unsigned value and written as (value >> k) in unary and its k
 * low bits. The split is chosen by the rule cfitsio's coder uses, so a tile's bytes are
 * cfitsio's own (tests/test_fitscomp.c compares them), at a few times its speed: cfitsio's
 * coder took 12% of an up-the-ramp product (the RESULTANTS cube) in the profile. */
#ifndef WF_RICE_H
#define WF_RICE_H

#include <stddef.h>
#include <stdint.h>
#include "hal/status.h"

/* Bytes that always hold the code of n pixels of bytepix (2 or 4) bytes. */
size_t wf_fits_rice_bound(long n, int bytepix);

/* Codes n >= 1 pixels of bytepix bytes (uint16_t or uint32_t), each XORed with flip first
 * (0x8000 or 0x80000000 turns unsigned pixels into the signed values a FITS file with BZERO
 * 2^15 or 2^31 stores; 0 for signed ones), in blocks of `block` pixels (cfitsio writes 32),
 * into out (cap bytes, at least wf_fits_rice_bound); *len the bytes written. */
wf_status wf_fits_rice_code(const void *pix, long n, int bytepix, uint32_t flip, int block,
                            unsigned char *out, size_t cap, size_t *len);

#endif
