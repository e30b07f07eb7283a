/* cfitsio helpers shared by everything on the host side that writes products (sim/, tools/).
 * Products must be byte-identical for the same input (SPEC §9), but cfitsio's own
 * fits_write_chksum stamps the wall-clock time into the CHECKSUM and DATASUM comments; the
 * checksum helpers here write the same values with fixed comments instead. */
#ifndef WF_FITSOUT_H
#define WF_FITSOUT_H

#include <fitsio.h>
#include <stddef.h>
#include <stdint.h>
#include "hal/status.h"

/* Records a message "<path>: <doing>: <cfitsio text> (<error stack>)", clears cfitsio's
 * error stack and returns WF_ERR_IO (WF_OK when status is 0). */
wf_status wf_fits_error(int status, const char *path, const char *doing);

/* Writes placeholder CHECKSUM/DATASUM cards into the current HDU. Call while its header is
 * being written, before any later HDU exists: filling them in at the end then never grows a
 * header, which would shift every later HDU of a multi-gigabyte file. */
wf_status wf_fits_reserve_checksum(fitsfile *f, const char *path);

/* A data unit's FITS checksum summed while its words are written, in any order (the one's
 * complement sum commutes), so that closing a product need not read its pixels back: for an
 * SCA that read is 200 MB. Each word must be added exactly once; `valid` says the sum is
 * whole (a writer that cannot keep it leaves it 0 and the data are read back). */
typedef struct wf_fits_datasum {
    uint64_t hi, lo; /* sums of the big-endian words' upper and lower 16 bits */
    int valid;
} wf_fits_datasum;

/* n 32-bit values in host order (float bit patterns, or unsigned integers with flip =
 * 0x80000000 for cfitsio's BZERO 2^31 storage), each stored as one word. */
void wf_fits_datasum_add32(wf_fits_datasum *s, const void *values, size_t n, uint32_t flip);

/* Writes n 32-bit values in host order into the current image HDU's data unit from element
 * `first` (0-based) on, stored exactly as fits_write_pix stores TFLOAT (flip 0) or TUINT
 * (flip 0x80000000, BZERO 2^31), and adds them to sum. The values are turned into their
 * stored form in place (the caller's copy is lost) and summed in the same pass: cfitsio
 * converts, byte-swaps and copies in separate passes, and the checksum would be another,
 * which for an SCA's three 64 MiB planes was most of the writer's time. The HDU must be an
 * image of 32-bit words whose stored type matches flip (else BAD_DATATYPE) and hold the
 * range (else BAD_ELEM_NUM). cfitsio-style: returns and sets *status, a no-op when it is
 * already > 0. */
int wf_fits_write32(fitsfile *f, LONGLONG first, void *values, size_t n, uint32_t flip,
                    wf_fits_datasum *sum, int *status);

/* n 16-bit values in host order (flip 0x8000 for BZERO 32768), the first being element
 * `first` of the data unit: an even element is a word's upper half, an odd one its lower. */
void wf_fits_datasum_add16(wf_fits_datasum *s, const uint16_t *values, size_t n, uint64_t first,
                           uint16_t flip);

/* n bytes, the first at byte `offset` of the data unit (a byte's place in its 4-byte word). */
void wf_fits_datasum_add_bytes(wf_fits_datasum *s, const unsigned char *bytes, size_t n, uint64_t offset);

/* The DATASUM value (the folded one's complement sum) of s. */
unsigned long wf_fits_datasum_value(const wf_fits_datasum *s);

/* CHECKSUM and DATASUM of every HDU of the file, with fixed comments (no time stamp); leaves
 * the last HDU current. The DATASUM of HDU i (1-based) is sums[i - 1] when i <= nsums and that
 * sum is valid, and is read from the file otherwise (sums may be NULL). */
wf_status wf_fits_checksum_all(fitsfile *f, const char *path, const wf_fits_datasum *sums, int nsums);

/* Proves the FITS file at path is whole, as the resume of `wfisim survey run` and the plan
 * reader rely on: every section (HDU) has a CHECKSUM and DATASUM that verify, and the sections
 * cfitsio finds cover every byte of the file. cfitsio stops counting sections silently at the
 * first header it cannot parse, so checksums alone would pass a file whose later section is
 * damaged; its bytes are then left over after the last section found and the file is refused.
 * A file cut exactly between two sections is caught only by nhdu: when > 0, the file must hold
 * exactly that many sections (0: any number). A file cfitsio cannot open or read (its primary
 * header included) is WF_ERR_IO, any other failure WF_ERR_CORRUPT; the message names the file
 * and the section (1 = the primary HDU). */
wf_status wf_fits_verify_checksums(const char *path, int nhdu);

/* Products are written to "<path>.tmp" and renamed into place only when complete, so a
 * failure never leaves a partial product. wf_fits_begin creates the temporary file (an old
 * one is removed; tmp receives its name); wf_fits_finish checksums every HDU (unless st is
 * already an error), closes, renames onto path, and removes the temporary file on any
 * error. Returns the first error. */
wf_status wf_fits_begin(const char *path, char *tmp, size_t tmp_size, fitsfile **f);
wf_status wf_fits_finish(fitsfile *f, const char *tmp, const char *path, wf_status st);

/* Fewest significant digits (1..17) that print v so that it reads back exactly: with
 * fits_write_key_dbl(..., -digits, ...) a header shows 0.015, not 0.014999999999999999. */
int wf_fits_double_digits(double v);

#endif
