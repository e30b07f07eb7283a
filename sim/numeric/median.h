/* The median of float samples: the middle value, or the mean (in double) of the two middle
 * values when the count is even, as numpy.median. Sorts the samples in place; NaN for none.
 * Used where a robust level is read off samples (analysis/coadd.c's input weights,
 * analysis/detect_noise.c's noise scale); the values must not be NaN. */
#ifndef WF_MEDIAN_H
#define WF_MEDIAN_H

#include <stddef.h>

double wf_median_float(float *v, size_t n);

#endif
