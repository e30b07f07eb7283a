/* The single-frame fast path and the row batches under it, checked against the scalar code
 * they replace and against the distributions they must draw:
 *  - the PTRS row batch (its own log, two-step test) against wf_poisson_ptrs_try lane by lane,
 *    and its retries (wf_noise_block_list + wf_poisson_ptrs_row53) against wf_rng_poisson on
 *    the same streams;
 *  - the whole draw (first attempt from a row's words, retries from the stream) against the
 *    Poisson pmf: chi-square at several means;
 *  - the fixed-mean inversion table against inversion summed term by term, on words at
 *    every threshold;
 *  - the normal tails (vectorised log) against wf_norm_ppf on a sample of tail words;
 *  - the Philox spans (SIMD variants and their scalar tails) against the scalar stream;
 *  - the detector row functions against their scalar formulas, bit for bit;
 *  - the readout in single-frame mode: flat-field mean and variance against the exact
 *    moments of Poisson -> reciprocity failure -> dark -> read noise -> ADC, determinism
 *    with a dark mean >= 10 (a stream that goes on after the photon draw), fixed memory. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "firmware/detector.h"
#include "firmware/readout.h"
#include "hal/noise.h"
#include "hal/packet.h"
#include "tests/testutil.h"
#include "tools/expose.h"

/* ------------------------------------------------------------------ PTRS row batches */

static const double ptrs_means[] = {10.0, 10.5, 15.0, 37.5, 120.0, 1000.0, 1e6, 1e9};

START_TEST(ptrs_row_matches_scalar)
{
    const double mu = ptrs_means[_i];
    enum { N = 1 << 17 };
    static uint32_t w[4][N];
    static double mean[N], k[N];
    const wf_noise noise = {WF_NOISE_PHILOX, 0xfeedULL + (uint64_t)_i, 3, 9};
    wf_noise_block_row(&noise, 0, N, 0, WF_PURPOSE_TEST, 0, w[0], w[1], w[2], w[3]);
    for (int i = 0; i < N; i++) mean[i] = mu * (1.0 + 0.25 * (w[0][i] / 4294967296.0));
    mean[0] = 9.999999; /* below PTRS's range: -1, the caller's to draw */
    mean[1] = NAN;
    mean[2] = 0.0;
    wf_poisson_ptrs_row(mean, w[1], w[2], N, k);
    ck_assert(k[0] == -1.0 && k[1] == -1.0 && k[2] == -1.0);
    long differ = 0, accepted = 0;
    for (int i = 3; i < N; i++) {
        double ks;
        if (!wf_poisson_ptrs_try(mean[i], w[1][i], w[2][i], &ks)) ks = -1.0;
        differ += ks != k[i];
        accepted += k[i] >= 0.0;
        ck_assert(k[i] == -1.0 || (k[i] >= 0.0 && k[i] == floor(k[i])));
    }
    printf("ptrs row, mean %g: %ld of %d lanes accepted, %ld differ from the scalar test\n", mu,
           accepted, N - 3, differ);
    /* the tests differ only by roundings (~1e-15): a disagreement is that rare */
    ck_assert_msg(differ <= N / 1000000 + 1, "mean %g: %ld lanes differ", mu, differ);
    ck_assert_msg(accepted > N / 2, "mean %g: only %ld of %d accepted", mu, accepted, N);
}
END_TEST

/* Draws for listed streams from block 1 on, as the readout retries rejected pixels. */
static void retry_draws(const wf_noise *noise, uint32_t *pix, double *mean, int n, double *out)
{
    uint32_t *w[4];
    for (int j = 0; j < 4; j++) w[j] = malloc((size_t)n * sizeof *w[j]);
    int *at = malloc((size_t)n * sizeof *at);
    double *k = malloc((size_t)n * sizeof *k);
    for (int i = 0; i < n; i++) at[i] = i;
    for (uint32_t b = 1; n > 0; b++) {
        wf_noise_block_list(noise, pix, n, 5, WF_PURPOSE_PHOTON, b, w[0], w[1], w[2], w[3]);
        wf_poisson_ptrs_row53(mean, w[0], w[1], w[2], w[3], n, k);
        int left = 0;
        for (int i = 0; i < n; i++) {
            if (k[i] >= 0.0) {
                out[at[i]] = k[i];
                continue;
            }
            at[left] = at[i];
            pix[left] = pix[i];
            mean[left] = mean[i];
            left++;
        }
        n = left;
    }
    for (int j = 0; j < 4; j++) free(w[j]);
    free(at);
    free(k);
}

START_TEST(ptrs_retries_match_stream)
{
    const double mu = ptrs_means[_i];
    enum { N = 20011 };
    static uint32_t pix[N];
    static double mean[N], k[N];
    const wf_noise noise = {WF_NOISE_PHILOX, 77ULL + (uint64_t)_i, 12, 3};
    for (int i = 0; i < N; i++) {
        pix[i] = 0xfffff000u + (uint32_t)i * 7u; /* wraps past 2^32 */
        mean[i] = mu + 0.001 * i;
    }
    retry_draws(&noise, pix, mean, N, k);
    long differ = 0;
    for (int i = 0; i < N; i++) {
        wf_rng rng;
        wf_rng_init(&rng, &noise, 0xfffff000u + (uint32_t)i * 7u, 5, WF_PURPOSE_PHOTON);
        wf_rng_seek(&rng, 1);
        differ += wf_rng_poisson(&rng, mu + 0.001 * i) != k[i];
    }
    ck_assert_msg(differ <= 1, "mean %g: %ld of %d draws differ from wf_rng_poisson", mu, differ, N);
}
END_TEST

/* P(k | mu) in logs (lgamma), for the expectations of the goodness of fit. */
static double pmf(double k, double mu) { return exp(k * log(mu) - mu - lgamma(k + 1.0)); }

/* The readout's draw for a row: first attempt from words 1 and 2 of block 0, retries from the
 * pixel's stream. Chi-square against the pmf; the p-value from the Wilson-Hilferty normal
 * form of the chi-square distribution (enough for a 4.5-sigma bound). */
START_TEST(ptrs_draws_chi_square)
{
    static const double means[] = {10.0, 37.5, 120.0, 3000.0};
    const double mu = means[_i];
    enum { N = 1 << 20 };
    uint32_t *w[4];
    for (int j = 0; j < 4; j++) w[j] = malloc(N * sizeof *w[j]);
    double *mean = malloc(N * sizeof *mean), *k = malloc(N * sizeof *k), *rm = malloc(N * sizeof *rm);
    uint32_t *rp = malloc(N * sizeof *rp);
    int *rx = malloc(N * sizeof *rx);
    const wf_noise noise = {WF_NOISE_PHILOX, 4242ULL + (uint64_t)_i, 1, 1};
    wf_noise_block_row(&noise, 0, N, 5, WF_PURPOSE_PHOTON, 0, w[0], w[1], w[2], w[3]);
    for (int i = 0; i < N; i++) mean[i] = mu;
    wf_poisson_ptrs_row(mean, w[1], w[2], N, k);
    int nr = 0;
    for (int i = 0; i < N; i++)
        if (k[i] < 0.0) {
            rx[nr] = i;
            rp[nr] = (uint32_t)i;
            rm[nr] = mu;
            nr++;
        }
    double *rk = malloc((size_t)(nr ? nr : 1) * sizeof *rk);
    retry_draws(&noise, rp, rm, nr, rk);
    for (int i = 0; i < nr; i++) k[rx[i]] = rk[i];

    const int kmax = (int)(mu + 12.0 * sqrt(mu) + 20.0);
    long *count = calloc((size_t)kmax + 2, sizeof *count);
    for (int i = 0; i < N; i++) {
        ck_assert(k[i] >= 0.0 && k[i] == floor(k[i]));
        count[k[i] > kmax ? kmax + 1 : (int)k[i]]++;
    }
    /* bins: k <= lo, each lo < k < hi, k >= hi, the pooled ends with expectations >= 5 */
    int lo = 0, hi = kmax;
    double cum = pmf(0, mu), tail = pmf(kmax, mu); /* P(k > kmax) < 1e-25: neglected */
    while (cum * N < 5.0) cum += pmf(++lo, mu);
    while (tail * N < 5.0) tail += pmf(--hi, mu);
    ck_assert_int_lt(lo, hi);
    double chi2 = 0.0, o = 0.0, e = cum * N;
    for (int j = 0; j <= lo; j++) o += (double)count[j];
    chi2 += (o - e) * (o - e) / e;
    for (int j = lo + 1; j < hi; j++) {
        e = pmf(j, mu) * N;
        chi2 += ((double)count[j] - e) * ((double)count[j] - e) / e;
    }
    o = 0.0;
    for (int j = hi; j <= kmax + 1; j++) o += (double)count[j];
    e = tail * N;
    chi2 += (o - e) * (o - e) / e;
    const int bins = hi - lo + 1;
    const double df = bins - 1;
    const double z = (cbrt(chi2 / df) - (1.0 - 2.0 / (9.0 * df))) / sqrt(2.0 / (9.0 * df));
    printf("batched PTRS mean %g: %d retried of %d, chi2 %.1f over %d bins, z %.2f\n", mu, nr, N,
           chi2, bins, z);
    ck_assert_msg(z < 4.5 && z > -4.5, "mean %g: chi2 %.1f, df %g, z %.2f", mu, chi2, df, z);
    for (int j = 0; j < 4; j++) free(w[j]);
    free(mean);
    free(k);
    free(rm);
    free(rp);
    free(rx);
    free(rk);
    free(count);
}
END_TEST

/* ------------------------------------------------------------------ fixed-mean inversion */

/* Inversion from one word, the term-by-term sums the table stands for. */
static double invert(uint32_t w, double mean)
{
    double u = ((double)w + 0.5) * (1.0 / 4294967296.0);
    double expm = exp(-mean), p1 = expm * mean, p2 = p1 * mean * 0.5;
    double f0 = expm, f1 = f0 + p1, f2 = f1 + p2;
    if (u <= f2) return (double)((u > f0) + (u > f1));
    double p = p2, cdf = f2, k = 2.0;
    while (u > cdf && k < 200.0) {
        k += 1.0;
        p *= mean / k;
        double next = cdf + p;
        if (next == cdf) break;
        cdf = next;
    }
    return k;
}

START_TEST(table_row_matches_inversion)
{
    static const double means[] = {1e-9, 0.015 * 300.0, 0.5, 3.0, 9.99};
    enum { N = 4096 };
    static uint32_t w[N], s[N];
    static double k[N];
    wf_poisson_table t;
    ck_assert_int_eq(wf_poisson_table_init(&t, 10.0), WF_ERR_RANGE);
    ck_assert_int_eq(wf_poisson_table_init(&t, 0.0), WF_ERR_RANGE);
    const wf_noise noise = {WF_NOISE_PHILOX, 99, 1, 1};
    for (size_t m = 0; m < sizeof means / sizeof means[0]; m++) {
        ck_assert_int_eq(wf_poisson_table_init(&t, means[m]), WF_OK);
        /* every threshold and the words either side, then ordinary words */
        int n = 0;
        w[n++] = 0;
        w[n++] = 0xffffffffu;
        for (int j = 0; j < t.nword && n < N - 3; j++) {
            w[n++] = t.word[j];
            if (t.word[j] > 0) w[n++] = t.word[j] - 1;
            if (t.word[j] < 0xffffffffu) w[n++] = t.word[j] + 1;
        }
        wf_noise_block_row(&noise, (uint32_t)m * N, N, 0, WF_PURPOSE_TEST, 0, s, s, s, s);
        while (n < N) { w[n] = s[n]; n++; }
        wf_poisson_table_row(&t, w, N, k);
        for (int i = 0; i < N; i++)
            ck_assert_msg(k[i] == invert(w[i], means[m]), "mean %g, word %u: %g vs %g", means[m],
                          w[i], k[i], invert(w[i], means[m]));
    }
}
END_TEST

/* ------------------------------------------------------------------ normals, Philox */

START_TEST(norm_tails_match_ppf)
{
    enum { N = 1 << 16 };
    static uint32_t w[N], s[N];
    static float z[N];
    const wf_noise noise = {WF_NOISE_PHILOX, 5, 5, 5};
    const uint32_t lo = 104152845u, hi = 4294967295u - 104152845u;
    for (int rep = 0; rep < 16; rep++) {
        wf_noise_block_row(&noise, (uint32_t)rep * N, N, 0, WF_PURPOSE_TEST, 0, s, s, s, s);
        for (int i = 0; i < N; i++) /* tails only, both sides */
            w[i] = i & 1 ? hi + 1 + s[i] % (0xffffffffu - hi) : s[i] % lo;
        w[0] = 0;
        w[1] = 0xffffffffu;
        w[2] = lo - 1;
        w[3] = hi + 1;
        w[4] = lo; /* central */
        wf_norm_from_u32(w, N - rep, z); /* lengths that leave partial chunks and SIMD tails */
        for (int i = 0; i < N - rep; i++) {
            float ref = (float)wf_norm_ppf(((double)w[i] + 0.5) / 4294967296.0);
            ck_assert_msg(!memcmp(&ref, &z[i], sizeof ref), "word %u: %.9g vs %.9g", w[i], z[i], ref);
        }
    }
}
END_TEST

START_TEST(philox_spans_match_scalar)
{
    enum { N = 4099 };
    static uint32_t w[4][N], pix[N];
    const wf_noise noise = {WF_NOISE_PHILOX, 0x0123456789abcdefULL, 8, 17};
    const int lengths[] = {1, 2, 7, 8, 9, 15, 16, 17, 31, 33, 4088, N};
    for (size_t l = 0; l < sizeof lengths / sizeof lengths[0]; l++) {
        int n = lengths[l];
        uint32_t p0 = 0xfffffff0u - (uint32_t)l; /* runs wrap past 2^32 */
        wf_noise_block_row(&noise, p0, n, 6, WF_PURPOSE_RESULTANT, 3, w[0], w[1], w[2], w[3]);
        for (int i = 0; i < n; i++) {
            wf_rng rng;
            wf_rng_init(&rng, &noise, p0 + (uint32_t)i, 6, WF_PURPOSE_RESULTANT);
            wf_rng_seek(&rng, 3);
            for (int j = 0; j < 4; j++) ck_assert_uint_eq(w[j][i], wf_rng_u32(&rng));
        }
        for (int i = 0; i < n; i++) pix[i] = (uint32_t)(i * 2654435761u);
        wf_noise_block_list(&noise, pix, n, 0, WF_PURPOSE_PHOTON, 7, w[0], w[1], w[2], w[3]);
        for (int i = 0; i < n; i++) {
            wf_rng rng;
            wf_rng_init(&rng, &noise, pix[i], 0, WF_PURPOSE_PHOTON);
            wf_rng_seek(&rng, 7);
            for (int j = 0; j < 4; j++) ck_assert_uint_eq(w[j][i], wf_rng_u32(&rng));
        }
    }
}
END_TEST

/* ------------------------------------------------------------------ detector rows */

/* The single-frame output step as the readout wrote it before it had a row function. */
static float single_ref(const wf_detector *d, double v, double q, float z, uint8_t *sat)
{
    int clipped = d->on.saturation && q >= d->full_well;
    if (d->on.read_noise) v += d->read_noise_e * z;
    double adu = v / d->gain + d->bias_adu;
    if (d->on.quantize) adu = wf_det_quantize(adu);
    if (d->on.saturation) {
        if (adu >= d->adc_max) { adu = d->adc_max; clipped = 1; }
        if (adu < 0.0) adu = 0.0;
    }
    if (clipped) *sat = 0;
    return (float)adu;
}

START_TEST(detector_rows_match_scalar)
{
    enum { N = 1037 };
    static double e[N], q[N], m[N], ipc[N], ref[N], rows[3][N], tab[4096];
    static float z[N], out[N];
    static uint8_t sat[N], satr[N];
    const wf_noise noise = {WF_NOISE_PHILOX, 31, 1, 1};
    static uint32_t s[4][N];
    wf_noise_block_row(&noise, 0, N, 0, WF_PURPOSE_TEST, 0, s[0], s[1], s[2], s[3]);
    wf_norm_from_u32(s[0], N, z);
    for (int i = 0; i < N; i++) {
        e[i] = (s[1][i] / 4294967296.0) * 1.5e5 - 2e3; /* negative to past the ADC */
        q[i] = (s[2][i] / 4294967296.0) * 1.3e5;
    }
    e[0] = 0.5; /* ties of round half to even */
    e[1] = 1.5;
    e[2] = -0.0;
    e[3] = -1000.5;
    for (int c = 0; c < 7; c++) {
        wf_detector d;
        wf_detector_defaults(&d);
        if (c == 1) d.gain = 1.7;
        if (c == 2) d.on.quantize = 0;
        if (c == 3) d.on.saturation = 0;
        if (c == 4) d.on.read_noise = 0;
        if (c == 5) { d.bias_adu = 0.0; d.on.saturation = 0; }
        if (c == 6) { d.adc_max = 30000.0; d.full_well = 5e4; }
        memset(sat, 255, N);
        memset(satr, 255, N);
        wf_det_single_row(&d, e, q, z, N, out, sat);
        for (int i = 0; i < N; i++) {
            float r = single_ref(&d, e[i], q[i], z[i], &satr[i]);
            ck_assert_msg(!memcmp(&r, &out[i], sizeof r), "config %d, pixel %d: %.9g vs %.9g", c,
                          i, out[i], r);
        }
        ck_assert_msg(!memcmp(sat, satr, N), "config %d: saturation flags differ", c);

        /* full well and nonlinearity */
        wf_det_measure_row(&d, q, N, m);
        for (int i = 0; i < N; i++) {
            double v = d.on.saturation && q[i] > d.full_well ? d.full_well : q[i];
            ck_assert(m[i] == wf_det_nonlinearity(v, d.nl_beta));
        }
        /* the same measure, the charge itself held at the full well */
        static double qh[N], mh[N];
        memcpy(qh, q, sizeof qh);
        wf_det_hold_measure_row(&d, qh, N, mh);
        int held = 0;
        for (int i = 0; i < N; i++) {
            ck_assert(mh[i] == m[i]);
            ck_assert(qh[i] == (d.on.saturation && q[i] > d.full_well ? d.full_well : q[i]));
            held += qh[i] != q[i];
        }
        ck_assert(d.on.saturation ? held > 0 : held == 0);
    }

    /* reciprocity on whole counts: the table below 4096, computed above, dark added */
    wf_detector d;
    wf_detector_defaults(&d);
    for (int k = 0; k < 4096; k++) tab[k] = wf_det_reciprocity(k, 300.0, d.recip_alpha, d.recip_f0);
    for (int pass = 0; pass < 2; pass++) {
        for (int i = 0; i < N; i++) m[i] = floor((s[3][i] / 4294967296.0) * (pass ? 4000.0 : 9000.0));
        memcpy(ref, m, sizeof ref);
        wf_det_reciprocity_counts(&d, 300.0, tab, 4096, pass ? e : NULL, N, m);
        for (int i = 0; i < N; i++) {
            double r = wf_det_reciprocity(ref[i], 300.0, d.recip_alpha, d.recip_f0);
            if (pass) r += e[i];
            ck_assert_msg(m[i] == r, "count %g: %.17g vs %.17g", ref[i], m[i], r);
        }
    }

    /* IPC in one pass against three, with and without the rows around */
    for (int a = 0; a < 3; a++)
        for (int i = 0; i < N; i++) rows[a][i] = (s[a + 1][i] / 4294967296.0) * 1e4;
    for (int layout = 0; layout < 4; layout++) {
        const double *up = layout & 1 ? NULL : rows[0], *dn = layout & 2 ? NULL : rows[2];
        for (int n = 1; n <= N; n += n < 8 ? 1 : 515) {
            wf_det_ipc_row(up, rows[1], dn, n, d.ipc, ipc);
            for (int x = 0; x < n; x++) {
                double acc = 0.0;
                const double *in[3] = {up, rows[1], dn};
                for (int r = 0; r < 3; r++) {
                    if (!in[r]) continue;
                    double t = 0.0;
                    if (x == 0 && n == 1) t = d.ipc[r][1] * in[r][0];
                    else if (x == 0) t = d.ipc[r][1] * in[r][0] + d.ipc[r][2] * in[r][1];
                    else if (x == n - 1) t = d.ipc[r][0] * in[r][x - 1] + d.ipc[r][1] * in[r][x];
                    else t = d.ipc[r][0] * in[r][x - 1] + d.ipc[r][1] * in[r][x] + d.ipc[r][2] * in[r][x + 1];
                    acc += t;
                }
                ck_assert_msg(ipc[x] == acc, "IPC layout %d, width %d, column %d", layout, n, x);
            }
        }
    }

    /* rates: exposure and the finiteness check */
    static float rate[N];
    for (int i = 0; i < N; i++) rate[i] = (float)(e[i] * 1e-3);
    wf_det_exposure_row(rate, 139.8, N, m);
    for (int i = 0; i < N; i++) ck_assert(m[i] == (rate[i] > 0.0f ? rate[i] * 139.8 : 0.0));
    ck_assert_int_eq(wf_det_first_nonfinite(rate, N), -1);
    rate[700] = INFINITY;
    rate[900] = NAN;
    ck_assert_int_eq(wf_det_first_nonfinite(rate, N), 700);
    ck_assert_int_eq(wf_det_first_nonfinite(rate + 701, N - 701), 199);
}
END_TEST

/* ------------------------------------------------------------------ the readout */

static float *run_single(const wf_readout_config *cfg, wf_scene_source *src, int threads)
{
    wf_link_memory mem;
    wf_link link;
    wf_link_memory_open(&mem, &link);
    wf_scene_source scenes[2] = {*src, *src};
    wf_expose_job job = {0};
    job.ro = *cfg;
    job.clock.frame_time = WF_FRAME_TIME_DEFAULT;
    ck_assert_int_eq(wf_ma_builtin("4", &job.clock.ma), WF_OK);
    job.noise = (wf_noise){WF_NOISE_PHILOX, cfg->seed, cfg->exposure, cfg->sca};
    job.scenes = scenes;
    job.threads = threads;
    job.link = &link;
    ck_assert_msg(wf_expose_run(&job) == WF_OK, "expose: %s", wf_error_message());
    float *img = calloc((size_t)cfg->ncols * cfg->nrows, sizeof *img);
    FILE *f = fmemopen(mem.data, mem.len, "rb");
    wf_packet_reader rd;
    wf_packet_reader_open(&rd, f, "single stream");
    int eof = 0, rows = 0;
    while (!eof) {
        wf_packet_header h;
        const void *p;
        ck_assert_int_eq(wf_packet_reader_next(&rd, &h, &p, &eof), WF_OK);
        if (!eof && h.kind == WF_PK_SINGLE) {
            memcpy(img + (size_t)h.first_row * cfg->ncols, p, (size_t)h.row_count * h.ncols * sizeof *img);
            rows += (int)h.row_count;
        }
    }
    ck_assert_int_eq(rows, cfg->nrows);
    wf_packet_reader_close(&rd);
    fclose(f);
    wf_link_memory_close(&mem);
    return img;
}

static void single_config(wf_readout_config *cfg, int ncols, int nrows)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->ncols = ncols;
    cfg->nrows = nrows;
    cfg->tile_rows = 32;
    cfg->mode = WF_MODE_SINGLE;
    cfg->exptime = 300.0;
    cfg->exposure = 7;
    cfg->sca = 2;
    cfg->seed = 2024;
    cfg->compress = 0;
    wf_detector_defaults(&cfg->det);
}

/* A flat field through Poisson -> reciprocity failure -> dark Poisson -> read noise -> ADC
 * (no IPC or nonlinearity, so pixels are independent): the mean and variance of the ADU
 * against their exact values, summed over the Poisson pmfs; within 4.5 sigma. Means on both
 * sides of 10 (PTRS and inversion) and a dark mean >= 10. */
START_TEST(single_frame_flat_statistics)
{
    static const double rates[] = {0.4, 0.04, 0.01, 0.4};
    static const double darks[] = {0.015, 0.015, 0.015, 0.05};
    wf_readout_config cfg;
    single_config(&cfg, 256, 256);
    cfg.det.on.ipc = cfg.det.on.nonlinearity = 0;
    cfg.det.dark_current = darks[_i];
    wf_scene_grid g = {256, 256, rates[_i], 0.0, 1.0, 1 << 20};
    wf_scene_source src;
    ck_assert_int_eq(wf_scene_grid_source(&g, &src), WF_OK);
    float *img = run_single(&cfg, &src, 2);
    const double t = cfg.exptime, mu = (double)(float)rates[_i] * t, dm = darks[_i] * t;
    /* E and Var of reciprocity(K), K ~ Poisson(mu) */
    double e1 = 0.0, e2 = 0.0;
    for (int k = 0; k < (int)(mu + 40.0 * sqrt(mu) + 40.0); k++) {
        double r = wf_det_reciprocity(k, t, cfg.det.recip_alpha, cfg.det.recip_f0), p = pmf(k, mu);
        e1 += p * r;
        e2 += p * r * r;
    }
    const double sigma = cfg.det.read_noise_e;
    const double mean = e1 + dm + cfg.det.bias_adu;
    const double var = (e2 - e1 * e1) + dm + sigma * sigma + 1.0 / 12.0; /* + quantization */
    const int n = 256 * 256;
    double s1 = 0.0, s2 = 0.0;
    for (int i = 0; i < n; i++) {
        double d = img[i] - mean;
        s1 += d;
        s2 += d * d;
    }
    const double m = s1 / n, v = s2 / n - m * m;
    printf("single-frame flat, rate %g, dark %g: mean %+.4f, variance %.2f vs %.2f\n", rates[_i],
           darks[_i], m, v, var);
    ck_assert_msg(fabs(m) < 4.5 * sqrt(var / n), "mean off by %g (sd %g)", m, sqrt(var / n));
    /* the spread of a sample variance: sqrt(2/n) var for near-normal data */
    ck_assert_msg(fabs(v - var) < 4.5 * sqrt(2.0 / n) * var, "variance %g vs %g", v, var);
    free(img);
}
END_TEST

/* Byte-identical for any tile height and thread count, also where a draw goes on in the
 * stream after another (dark mean >= 10) and where the sky is drawn by inversion. */
START_TEST(single_frame_tiles_and_threads)
{
    wf_readout_config cfg;
    single_config(&cfg, 70, 61);
    cfg.det.dark_current = 0.05;
    wf_scene_grid g = {70, 61, 0.02, 3e5, 1.2, 20}; /* faint sky, saturating stars */
    wf_scene_source src;
    ck_assert_int_eq(wf_scene_grid_source(&g, &src), WF_OK);
    cfg.tile_rows = 61;
    float *ref = run_single(&cfg, &src, 1);
    const int heights[] = {1, 2, 7, 16};
    for (int h = 0; h < 4; h++)
        for (int threads = 1; threads <= 2; threads++) {
            cfg.tile_rows = heights[h];
            float *img = run_single(&cfg, &src, threads);
            ck_assert_msg(!memcmp(ref, img, 70 * 61 * sizeof *img), "tile height %d, %d threads",
                          heights[h], threads);
            free(img);
        }
    free(ref);
}
END_TEST

START_TEST(single_frame_memory_fixed)
{
    wf_readout_config cfg;
    single_config(&cfg, 4088, 256);
    cfg.tile_rows = 64;
    wf_clock clock = {0};
    clock.frame_time = WF_FRAME_TIME_DEFAULT;
    ck_assert_int_eq(wf_ma_builtin("6", &clock.ma), WF_OK);
    size_t a, b;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &a), WF_OK);
    cfg.nrows = 4088;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &b), WF_OK);
    ck_assert_msg(a == b, "single-frame arena grew with image height: %zu -> %zu", a, b);
    ck_assert_msg(b <= 16u << 20, "single frame at 64-row tiles needs %zu bytes", b);
}
END_TEST

static Suite *single_fast_suite(void)
{
    Suite *s = suite_create("single_fast");
    TCase *tc = tcase_create("batches");
    tcase_set_timeout(tc, 120);
    tcase_add_loop_test(tc, ptrs_row_matches_scalar, 0, (int)(sizeof ptrs_means / sizeof ptrs_means[0]));
    tcase_add_loop_test(tc, ptrs_retries_match_stream, 0, (int)(sizeof ptrs_means / sizeof ptrs_means[0]));
    tcase_add_loop_test(tc, ptrs_draws_chi_square, 0, 4);
    tcase_add_test(tc, table_row_matches_inversion);
    tcase_add_test(tc, norm_tails_match_ppf);
    tcase_add_test(tc, philox_spans_match_scalar);
    tcase_add_test(tc, detector_rows_match_scalar);
    suite_add_tcase(s, tc);
    TCase *ro = tcase_create("readout");
    tcase_set_timeout(ro, 120);
    tcase_add_loop_test(ro, single_frame_flat_statistics, 0, 4);
    tcase_add_test(ro, single_frame_tiles_and_threads);
    tcase_add_test(ro, single_frame_memory_fixed);
    suite_add_tcase(s, ro);
    return s;
}

int main(void) { return wf_test_main(single_fast_suite()); }
