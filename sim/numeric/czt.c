#include "sim/numeric/czt.h"

#include <fftw3.h>
#include <math.h>
#include <stdlib.h>

#include "sim/numeric/fftw_lock.h"
#include "sim/numeric/trig.h"

struct wf_czt {
    int m, k, l;
    double *wre, *wim;    /* e^{-πi α n²}, n < max(M, K) */
    fftw_complex *v;      /* FFT of the chirp e^{+πi α n²} (n from 1 - M to K - 1), over L */
    fftw_complex *buf;
    fftw_plan fwd, bwd;
};

/* Smallest 2^a 3^b 5^c 7^d >= n: lengths FFTW transforms fast. */
static int fast_length(int n)
{
    for (int l = n;; l++) {
        int r = l;
        while (r % 2 == 0) r /= 2;
        while (r % 3 == 0) r /= 3;
        while (r % 5 == 0) r /= 5;
        while (r % 7 == 0) r /= 7;
        if (r == 1) return l;
    }
}

void wf_czt_free(wf_czt *z)
{
    if (!z) return;
    wf_fftw_lock();
    if (z->fwd) fftw_destroy_plan(z->fwd);
    if (z->bwd) fftw_destroy_plan(z->bwd);
    wf_fftw_unlock();
    fftw_free(z->v);
    fftw_free(z->buf);
    free(z->wre);
    free(z->wim);
    free(z);
}

wf_status wf_czt_create(int m, int k, double alpha, wf_czt **out)
{
    *out = NULL;
    if (m < 1 || k < 1 || m > (1 << 24) || k > (1 << 24) || !isfinite(alpha))
        return wf_error(WF_ERR_RANGE, "czt: %d inputs, %d outputs, alpha %g", m, k, alpha);
    wf_czt *z = calloc(1, sizeof *z);
    if (!z) return wf_error(WF_ERR_NOMEM, "czt: out of memory");
    z->m = m;
    z->k = k;
    z->l = fast_length(m + k - 1);
    int nw = m > k ? m : k;
    z->wre = malloc((size_t)nw * sizeof *z->wre);
    z->wim = malloc((size_t)nw * sizeof *z->wim);
    double *turns = malloc((size_t)nw * sizeof *turns);
    z->v = fftw_malloc((size_t)z->l * sizeof *z->v);
    z->buf = fftw_malloc((size_t)z->l * sizeof *z->buf);
    if (!z->wre || !z->wim || !turns || !z->v || !z->buf) {
        free(turns);
        wf_czt_free(z);
        return wf_error(WF_ERR_NOMEM, "czt: cannot allocate a transform of length %d", m + k - 1);
    }
    wf_fftw_lock();
    z->fwd = fftw_plan_dft_1d(z->l, z->buf, z->buf, FFTW_FORWARD, FFTW_ESTIMATE);
    z->bwd = fftw_plan_dft_1d(z->l, z->buf, z->buf, FFTW_BACKWARD, FFTW_ESTIMATE);
    wf_fftw_unlock();
    if (!z->fwd || !z->bwd) {
        free(turns);
        wf_czt_free(z);
        return wf_error(WF_ERR_INTERNAL, "czt: FFTW could not plan a transform of length %d", z->l);
    }
    /* k m = (k² + m² - (k - m)²) / 2: e^{-2πi α k m} = w_k w_m / w_{k-m}, w_n = e^{-πi α n²}.
     * n² is exact in double (n < 2^26); the product α n² / 2 carries its whole turns, which
     * the sine and cosine take off exactly. */
    for (int n = 0; n < nw; n++) turns[n] = -0.5 * alpha * ((double)n * (double)n);
    wf_trig_sincos_turns(turns, nw, z->wre, z->wim);
    free(turns);
    const double inv = 1.0 / z->l; /* FFTW's backward transform is unnormalised */
    for (int n = 0; n < z->l; n++) z->v[n][0] = z->v[n][1] = 0.0;
    for (int n = 0; n < k; n++) z->v[n][0] = z->wre[n] * inv, z->v[n][1] = -z->wim[n] * inv;
    for (int n = 1; n < m; n++) z->v[z->l - n][0] = z->wre[n] * inv, z->v[z->l - n][1] = -z->wim[n] * inv;
    fftw_execute_dft(z->fwd, z->v, z->v);
    *out = z;
    return WF_OK;
}

void wf_czt_run(wf_czt *z, const double *x, double *y)
{
    fftw_complex *b = z->buf;
    for (int n = 0; n < z->m; n++) {
        double xr = x[2 * n], xi = x[2 * n + 1], wr = z->wre[n], wi = z->wim[n];
        b[n][0] = xr * wr - xi * wi;
        b[n][1] = xr * wi + xi * wr;
    }
    for (int n = z->m; n < z->l; n++) b[n][0] = b[n][1] = 0.0;
    fftw_execute(z->fwd);
    for (int n = 0; n < z->l; n++) {
        double br = b[n][0], bi = b[n][1], vr = z->v[n][0], vi = z->v[n][1];
        b[n][0] = br * vr - bi * vi;
        b[n][1] = br * vi + bi * vr;
    }
    fftw_execute(z->bwd);
    for (int n = 0; n < z->k; n++) {
        double br = b[n][0], bi = b[n][1], wr = z->wre[n], wi = z->wim[n];
        y[2 * n] = br * wr - bi * wi;
        y[2 * n + 1] = br * wi + bi * wr;
    }
}
