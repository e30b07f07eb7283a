/* `wfisim diff`: a difference image, epoch minus template, on the template's grid.
 *
 * The template is a coadd (`wfisim coadd` of the epochs chosen by date, or of one epoch taken
 * after the SN faded); the epoch, a product, is drizzled onto the template's grid with
 * pixfrac 1 (analysis/coadd.h: the same kernel, its SCI and ERR) and the template is
 * subtracted. No PSF matching (Roman's PSF is stable between epochs) and no scene model:
 * docs/ANALYSIS.md says what that leaves and measures it.
 *
 * Product (FILE.tmp, renamed when whole, CHECKSUMs): primary FILTER, TEMPLATE, EPOCH,
 * MJD-OBS (the epoch's), NGOOD; SCI = epoch - template (e-/s per template pixel), ERR =
 * sqrt(ERR_epoch^2 + ERR_template^2) (each output pixel's own sigma: resampling correlates
 * neighbouring pixels, which this leaves out), MASK (uint8, 1 where either has no weight,
 * SCI and ERR 0 there); the template's WCS on every image HDU. */
#ifndef WF_DIFF_H
#define WF_DIFF_H

#include "hal/status.h"

/* Bad input (no WCS, another filter, an epoch the template does not overlap) is
 * WF_ERR_INPUT naming the file; no product is written. */
wf_status wf_diff_run(const char *template_path, const char *epoch_path, const char *out, int quiet);

/* argv holds the options after "diff". Returns 0 done, 1 failure, 2 bad usage or input. */
int wf_cmd_diff(int argc, char **argv);

#endif
