/* The noise of the image SEP thresholds, measured against what ERR predicts for it
 * (`wfisim detect --noise-scale auto`; docs/ANALYSIS.md, "Detection thresholds").
 *
 * SEP's relative threshold compares the filtered image with thresh x ERR. For noise that is
 * independent from pixel to pixel that is thresh / (sqrt(sum k^2) / sum k) sigmas of the
 * filtered image whatever the image. Resampling (drizzle) correlates neighbouring pixels:
 * ERR is still each pixel's sigma, but the filter then averages less noise away, and the same
 * thresh is fewer real sigmas. The ratio measured here, z = sum(k s) / sqrt(sum(k^2 ERR^2))
 * over sky pixels, is 1 for independent noise and the factor the threshold must grow by
 * otherwise. Sources are positive, so the width comes from the negative half of z around the
 * subtracted background: the median of -z over z < 0 is 0.6745 sigma for a normal. */
#include <math.h>
#include <stdlib.h>

#include "analysis/detect.h"
#include "sim/numeric/median.h"

wf_status wf_detect_noise_ratio(const float *sci, const float *err, const unsigned char *mask, int nx, int ny,
                                int filter, double *ratio, long *nsamples)
{
    static const double k3[3] = {1.0, 2.0, 1.0}; /* SExtractor's 3x3 pyramid = k3 x k3 */
    const int h = filter ? 1 : 0;
    *ratio = NAN, *nsamples = 0;
    if (nx < 2 * h + 1 || ny < 2 * h + 1) return wf_error(WF_ERR_INPUT, "noise scale: the image is too small");
    /* every st-th pixel each way: at most ~4 M samples, enough for 0.1% on the width */
    size_t n = (size_t)nx * ny;
    int st = 1;
    while (n / ((size_t)st * st) > 4000000) st++;
    size_t cap = (n / ((size_t)st * st)) / 2 + 64, m = 0;
    long used = 0;
    float *neg = malloc(cap * sizeof *neg);
    if (!neg) return wf_error(WF_ERR_NOMEM, "noise scale: out of memory");
    for (int y = h; y < ny - h; y += st)
        for (int x = h; x < nx - h; x += st) {
            double s = 0.0, v = 0.0;
            int bad = 0;
            for (int j = -h; j <= h && !bad; j++)
                for (int i = -h; i <= h; i++) {
                    size_t q = (size_t)(y + j) * nx + (x + i);
                    if (mask[q]) { bad = 1; break; }
                    double w = filter ? k3[i + 1] * k3[j + 1] : 1.0;
                    s += w * sci[q];
                    v += w * w * (double)err[q] * err[q];
                }
            if (bad || !(v > 0)) continue;
            used++;
            double z = s / sqrt(v);
            if (z < 0 && m < cap) neg[m++] = (float)-z;
        }
    wf_status rc = WF_OK;
    if (m < 100) {
        rc = wf_error(WF_ERR_INPUT, "noise scale: only %zu sky pixels below the background to measure it from", m);
    } else {
        double med = wf_median_float(neg, m);
        *ratio = med / 0.6744897501960817; /* Phi^-1(3/4) */
        *nsamples = used;
    }
    free(neg);
    return rc;
}
