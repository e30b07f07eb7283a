/* A FITS file's headers checked before cfitsio reads them. cfitsio 4.2 trusts header cards
 * that the standard forbids: a binary table whose TTYPE card holds bytes outside printable
 * ASCII overflows a fixed buffer in its column parser (ffgtbp) and aborts the process
 * (found by fuzz/fuzz_catalog_fits.c). Every reader of a FITS file from outside (catalogs,
 * plans, SN samples, products given to the analysis) asks this first. */
#ifndef WF_FITSCHECK_H
#define WF_FITSCHECK_H

#include "hal/status.h"

/* Walks the HDUs of path (plain or gzip'd, as cfitsio opens it): every header byte must be
 * printable ASCII (0x20-0x7E, FITS 4.0 section 4.1.1); otherwise WF_ERR_INPUT naming the
 * file, the HDU and the card. Data sections are skipped by their size from the header. What
 * the walk cannot size (a truncated file, a missing or absurd NAXISn) ends the check with
 * WF_OK: cfitsio reports those itself, as the caller's own open reports a file that cannot
 * be opened. */
wf_status wf_fits_check_headers(const char *path);

#endif
