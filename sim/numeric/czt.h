/* Chirp-z transform (Bluestein): y[k] = Σ_{m<M} x[m] e^{-2πi α k m} for k < K and any real α,
 * as a convolution with the chirp e^{πi α n²} by FFTs (FFTW3, double) of a fast length
 * L >= M + K - 1: O(L log L) a transform where the direct sum is O(M K). Samples a finite
 * Fourier sum at any spacing, so only the samples wanted are computed (the wide PSF image).
 * The chirps' phases come off whole turns exactly (sim/numeric/trig.h), so the error stays
 * at ~1e-15 of Σ|x| for the sizes used (α k² up to ~1e4 turns).
 *
 * Host side (malloc, the FFTW plan lock). A wf_czt holds its own work buffer: one transform
 * at a time per object; make one per thread. */
#ifndef WF_CZT_H
#define WF_CZT_H

#include "hal/status.h"

typedef struct wf_czt wf_czt;

wf_status wf_czt_create(int m, int k, double alpha, wf_czt **out);

/* x: M complex values, y: K, both interleaved (re, im); they may not overlap. */
void wf_czt_run(wf_czt *z, const double *x, double *y);

void wf_czt_free(wf_czt *z);

#endif
