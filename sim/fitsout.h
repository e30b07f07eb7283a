/* cfitsio helpers shared by everything on the host side that writes products (sim/, tools/).
 * Products must be byte-identical for the same input (SPEC §9), but cfitsio's own
 * fits_write_chksum stamps the wall-clock time into the CHECKSUM and DATASUM comments; the
 * checksum helpers here write the same values with fixed comments instead. */
#ifndef WF_FITSOUT_H
#define WF_FITSOUT_H

#include <fitsio.h>
#include "hal/status.h"

/* Records a message "<path>: <doing>: <cfitsio text> (<error stack>)", clears cfitsio's
 * error stack and returns WF_ERR_IO (WF_OK when status is 0). */
wf_status wf_fits_error(int status, const char *path, const char *doing);

/* Writes placeholder CHECKSUM/DATASUM cards into the current HDU. Call while its header is
 * being written, before any later HDU exists: filling them in at the end then never grows a
 * header, which would shift every later HDU of a multi-gigabyte file. */
wf_status wf_fits_reserve_checksum(fitsfile *f, const char *path);

/* CHECKSUM and DATASUM of the current HDU with fixed comments (no time stamp). */
wf_status wf_fits_checksum_hdu(fitsfile *f, const char *path);

/* The same for every HDU of the file; leaves the last HDU current. */
wf_status wf_fits_checksum_all(fitsfile *f, const char *path);

/* Fewest significant digits (1..17) that print v so that it reads back exactly: with
 * fits_write_key_dbl(..., -digits, ...) a header shows 0.015, not 0.014999999999999999. */
int wf_fits_double_digits(double v);

#endif
