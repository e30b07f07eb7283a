/* Correlated read noise (firmware/corrnoise.c) and the reference-pixel correction
 * (tools/refpix.c): the 1/f's spectrum along the readout order against the closed form of
 * its OU sum, the alternating scan, products independent of tiles and threads, the border
 * in the stream and its correction of channel offsets, nothing changed when off, the
 * border written into products. */
#include <fitsio.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "firmware/corrnoise.h"
#include "firmware/readout.h"
#include "hal/packet.h"
#include "tests/testutil.h"
#include "tools/expose.h"
#include "tools/refpix.h"

static wf_arena *arena_new(size_t bytes)
{
    static wf_arena a;
    static void *mem;
    free(mem);
    mem = malloc(bytes);
    ck_assert_ptr_nonnull(mem);
    ck_assert_int_eq(wf_arena_init(&a, mem, bytes, "test"), WF_OK);
    return &a;
}

static void cn_setup(wf_corrnoise *cn, double amp_c, double amp_u, int ncols, int nrows)
{
    wf_detector det;
    wf_detector_defaults(&det);
    det.on.read_1f = 1;
    det.rn1f_corr_e = amp_c;
    det.rn1f_uncorr_e = amp_u;
    wf_noise noise = {WF_NOISE_PHILOX, 99, 1, 3};
    wf_arena *a = arena_new(wf_corrnoise_arena_need(ncols) + 65536);
    ck_assert_int_eq(wf_corrnoise_init(cn, &det, &noise, ncols, nrows, a), WF_OK);
}

/* E[periodogram] of n samples d pixel times apart: sum_|m|<n (1 - |m|/n) acov(m d) cos(2 pi k m / n). */
static double expected_periodogram(int n, double d, int k)
{
    double s = wf_corrnoise_acov(0.0);
    for (int m = 1; m < n; m++) s += 2.0 * (1.0 - (double)m / n) * wf_corrnoise_acov(m * d) * cos(2.0 * M_PI * k * m / n);
    return s;
}

/* |DFT_k|^2 / n of x for k = 0 .. n/2, added to p. */
static void add_periodogram(const double *x, int n, double *p)
{
    for (int k = 0; k <= n / 2; k++) {
        double re = 0.0, im = 0.0;
        for (int i = 0; i < n; i++) {
            double ph = 2.0 * M_PI * k * i / n;
            re += x[i] * cos(ph);
            im -= x[i] * sin(ph);
        }
        p[k] += (re * re + im * im) / n;
    }
}

/* Each read is an independent realisation: the spread of the per-read mean periodograms
 * gives the statistical error of their mean, and every bin (the zero frequency aside) must
 * agree with the model within 4.5 of it; 10% at most, so that the test can tell. */
static void check_spectrum(const char *what, int n, double d, double (*sum)[129], double (*sum2)[129],
                           int reps)
{
    for (int k = 1; k <= n / 2; k++) {
        double m = (*sum)[k] / reps, var = ((*sum2)[k] / reps - m * m) / (reps - 1);
        double se = sqrt(var > 0 ? var : 0), want = expected_periodogram(n, d, k);
        ck_assert_msg(se < 0.1 * want, "%s bin %d: standard error %g of %g: too few reads", what, k, se, want);
        ck_assert_msg(fabs(m - want) < 4.5 * se, "%s bin %d: %g, model %g (standard error %g)", what, k, m, want, se);
    }
}

START_TEST(spectrum_along_the_readout)
{
    enum { NC = 248, NR = 248, W = NC + 8, H = NR + 8, READS = 200 };
    static wf_corrnoise cn;
    cn_setup(&cn, 0.0, 1.0, NC, NR);
    ck_assert_int_eq(cn.nchan, 2);
    double out[W], seg[128], col[H][2];
    static double row_sum[129], row_sum2[129], col_sum[129], col_sum2[129];
    double var = 0.0;
    for (int k = 0; k < READS; k++) {
        double prow[129] = {0}, pcol[129] = {0};
        for (int Y = 0; Y < H; Y++) {
            wf_corrnoise_row(&cn, (uint32_t)k, Y, 1.0, out);
            for (int c = 0; c < 2; c++) {
                for (int X = c * 128; X < c * 128 + 128; X++) seg[wf_corrnoise_position(X)] = out[X];
                add_periodogram(seg, 128, prow);
                col[Y][c] = seg[0];
                for (int i = 0; i < 128; i++) var += seg[i] * seg[i];
            }
        }
        for (int c = 0; c < 2; c++) {
            double x[H];
            for (int Y = 0; Y < H; Y++) x[Y] = col[Y][c];
            add_periodogram(x, H, pcol);
        }
        for (int b = 0; b <= 128; b++) {
            double r = prow[b] / (2 * H), q = pcol[b] / 2;
            if (b <= 64) { row_sum[b] += r; row_sum2[b] += r * r; }
            col_sum[b] += q;
            col_sum2[b] += q * q;
        }
    }
    /* the amplitude: variance 1 per unit amplitude (1% for ~1.3e7 correlated samples) */
    var /= (double)READS * H * W;
    ck_assert_msg(fabs(var - 1.0) < 0.03, "variance %g, model 1", var);
    check_spectrum("within a row (1 pixel time)", 128, 1.0, &row_sum, &row_sum2, READS);
    check_spectrum("row starts (140 pixel times)", H, WF_CN_ROW_TIME, &col_sum, &col_sum2, READS);
}
END_TEST

/* The shared 1/f is one process read by all channels at once, odd channels in the other
 * direction: column X of channel 0 and column 255 - X of channel 1 hold the same value. */
START_TEST(shared_noise_mirrors)
{
    enum { NC = 248, NR = 40, W = NC + 8 };
    static wf_corrnoise cn;
    cn_setup(&cn, 2.0, 0.0, NC, NR);
    double out[W], s2 = 0.0;
    for (int Y = 0; Y < NR + 8; Y++) {
        wf_corrnoise_row(&cn, 5, Y, 1.0, out);
        for (int X = 0; X < 128; X++) {
            ck_assert_msg(out[X] == out[255 - X], "row %d column %d: %g against %g", Y, X, out[X], out[255 - X]);
            s2 += out[X] * out[X];
        }
    }
    ck_assert(s2 > 0.0);
}
END_TEST

/* ---- through the readout ---------------------------------------------------------------- */

typedef struct stream {
    int ncols, nrows, nres, width;
    uint16_t *res;   /* [nres][nrows][ncols] */
    unsigned char *rows, *cols; /* REFROWS payload, REFCOLS [nres][nrows][8] (little-endian) */
    int have_rows;
} stream;

static wf_status dark_fill(void *ctx, int y0, int y1, int ncols, float *rate)
{
    (void)ctx;
    memset(rate, 0, (size_t)(y1 - y0) * ncols * sizeof *rate);
    return WF_OK;
}

static void dark_config(wf_readout_config *cfg, wf_clock *clock)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->ncols = 248;
    cfg->nrows = 96;
    cfg->tile_rows = 16;
    cfg->mode = WF_MODE_RAMP;
    cfg->exposure = 4;
    cfg->sca = 2;
    cfg->seed = 777;
    wf_detector_defaults(&cfg->det);
    cfg->det.on.cosmic_rays = cfg->det.on.dark = 0;
    cfg->det.on.channel_offsets = cfg->det.on.refpix = 1;
    cfg->det.channel_offset_adu = 100.0;
    clock->frame_time = WF_FRAME_TIME_DEFAULT;
    ck_assert_int_eq(wf_ma_builtin("4", &clock->ma), WF_OK);
}

static void run(const wf_readout_config *cfg, const wf_clock *clock, int threads, stream *s)
{
    wf_scene_source sc = {NULL, dark_fill, NULL, NULL};
    size_t len;
    unsigned char *buf = wf_test_expose_stream(cfg, clock, &sc, WF_NOISE_PHILOX, threads, &len);
    memset(s, 0, sizeof *s);
    s->ncols = cfg->ncols;
    s->nrows = cfg->nrows;
    s->nres = clock->ma.nresultants;
    s->width = cfg->ncols + 8;
    s->res = calloc((size_t)s->nres * s->nrows * s->ncols, sizeof *s->res);
    s->rows = calloc((size_t)s->nres * 8 * s->width, 2);
    s->cols = calloc((size_t)s->nres * s->nrows * 8, 2);
    FILE *f = fmemopen(buf, len, "rb");
    wf_packet_reader rd;
    wf_packet_reader_open(&rd, f, "test stream");
    int eof = 0, kinds_after_meta = 0, meta_seen = 0;
    while (!eof) {
        wf_packet_header h;
        const void *p;
        ck_assert_msg(wf_packet_reader_next(&rd, &h, &p, &eof) == WF_OK, "%s", wf_error_message());
        if (eof) break;
        if (meta_seen && !kinds_after_meta++)
            ck_assert_msg(h.kind == WF_PK_REFROWS, "packet %u right after META", h.kind);
        if (h.kind == WF_PK_META) meta_seen = 1;
        if (h.kind == WF_PK_REFROWS) {
            ck_assert(h.ncols == (uint32_t)s->width && h.row_count == 8 && (int)h.nplanes == s->nres);
            memcpy(s->rows, p, h.raw_len);
            s->have_rows = 1;
        } else if (h.kind == WF_PK_REFCOLS) {
            ck_assert(h.ncols == 8);
            for (int r = 0; r < s->nres; r++)
                memcpy(s->cols + 2 * (((size_t)r * s->nrows + h.first_row) * 8),
                       (const unsigned char *)p + 2 * ((size_t)r * h.row_count * 8), (size_t)h.row_count * 16);
        } else if (h.kind == WF_PK_RESULTANTS) {
            const uint16_t *v = p;
            for (int r = 0; r < s->nres; r++)
                memcpy(s->res + ((size_t)r * s->nrows + h.first_row) * s->ncols,
                       v + (size_t)r * h.row_count * h.ncols, (size_t)h.row_count * h.ncols * 2);
        }
    }
    wf_packet_reader_close(&rd);
    fclose(f);
    free(buf);
}

static void stream_free(stream *s)
{
    free(s->res);
    free(s->rows);
    free(s->cols);
}

START_TEST(independent_of_tiles_and_threads)
{
    wf_readout_config cfg;
    wf_clock clock;
    dark_config(&cfg, &clock);
    cfg.det.on.read_1f = 1;
    stream a, b;
    run(&cfg, &clock, 1, &a);
    cfg.tile_rows = 5;
    run(&cfg, &clock, 3, &b);
    size_t n = (size_t)a.nres * a.nrows * a.ncols;
    ck_assert(!memcmp(a.res, b.res, n * 2));
    ck_assert(!memcmp(a.rows, b.rows, (size_t)a.nres * 8 * a.width * 2));
    ck_assert(!memcmp(a.cols, b.cols, (size_t)a.nres * a.nrows * 16));
    /* direct sampling too */
    cfg.sampling = WF_SAMPLE_DIRECT;
    stream c, d;
    run(&cfg, &clock, 2, &c);
    cfg.tile_rows = 32;
    run(&cfg, &clock, 1, &d);
    ck_assert(!memcmp(c.res, d.res, n * 2));
    ck_assert(!memcmp(c.cols, d.cols, (size_t)c.nres * c.nrows * 16));
    /* and moments sampling */
    cfg.sampling = WF_SAMPLE_MOMENTS;
    cfg.tile_rows = 7;
    stream e, f;
    run(&cfg, &clock, 2, &e);
    cfg.tile_rows = 32;
    run(&cfg, &clock, 1, &f);
    ck_assert(!memcmp(e.res, f.res, n * 2));
    ck_assert(!memcmp(e.rows, f.rows, (size_t)e.nres * 8 * e.width * 2));
    ck_assert(!memcmp(e.cols, f.cols, (size_t)e.nres * e.nrows * 16));
    ck_assert_msg(memcmp(e.res, c.res, n * 2), "moments drew direct's resultants");
    stream_free(&a);
    stream_free(&b);
    stream_free(&c);
    stream_free(&d);
    stream_free(&e);
    stream_free(&f);
}
END_TEST

/* Channel offsets as drawn (the model's own draw, wf_corrnoise_init) are in the raw
 * resultants, and the reference-pixel correction takes them out, both to within the noise
 * of the means: sigma_p per pixel and resultant (read noise / sqrt(reads), and the ADC's
 * rounding), over the 1024 reference-row pixels of a channel, the 8 side pixels of each row
 * and the channel's active pixels. */
START_TEST(refpix_removes_channel_offsets)
{
    wf_readout_config cfg;
    wf_clock clock;
    dark_config(&cfg, &clock);
    cfg.det.on.photon_noise = 0;
    stream s;
    run(&cfg, &clock, 2, &s);
    ck_assert(s.have_rows);
    wf_corrnoise cn;
    wf_noise noise = {WF_NOISE_PHILOX, cfg.seed, cfg.exposure, cfg.sca};
    ck_assert_int_eq(wf_corrnoise_init(&cn, &cfg.det, &noise, cfg.ncols, cfg.nrows,
                                       arena_new(wf_corrnoise_arena_need(cfg.ncols) + 65536)),
                     WF_OK);
    wf_refpix rp;
    ck_assert_int_eq(wf_refpix_init(&rp, s.nres, s.ncols, s.nrows, cfg.det.bias_adu), WF_OK);
    wf_refpix_set_rows(&rp, s.rows);
    wf_refpix_set_cols(&rp, 0, (uint32_t)s.nrows, s.cols);
    double *corr = malloc((size_t)s.nres * s.ncols * sizeof *corr);
    double big = 0.0;
    for (int r = 0; r < s.nres; r++) {
        int n = clock.ma.first[r + 1] - clock.ma.first[r];
        double sp = sqrt(cfg.det.read_noise_e * cfg.det.read_noise_e / n + 1.0 / 12.0);
        for (int c = 0; c < 2; c++) {
            int x0 = c ? 124 : 0, x1 = c ? s.ncols : 124; /* active columns of channel c */
            double raw = 0.0, fixed = 0.0, np = (double)(x1 - x0) * s.nrows;
            for (int y = 0; y < s.nrows; y++) {
                wf_refpix_correction(&rp, (uint32_t)y, corr);
                for (int x = x0; x < x1; x++) {
                    double v = s.res[((size_t)r * s.nrows + y) * s.ncols + x];
                    raw += v - cfg.det.bias_adu;
                    fixed += v - corr[(size_t)r * s.ncols + x] - cfg.det.bias_adu;
                }
            }
            raw /= np;
            fixed /= np;
            double truth = cn.offset[c] / cfg.det.gain;
            double s_raw = sp / sqrt(np), s_fix = sp * sqrt(1.0 / 1024 + 1.0 / (8.0 * s.nrows) + 1.0 / np);
            ck_assert_msg(fabs(raw - truth) < 5 * s_raw, "resultant %d channel %d: raw offset %g, drawn %g (sd %g)", r,
                          c, raw, truth, s_raw);
            ck_assert_msg(fabs(fixed) < 5 * s_fix, "resultant %d channel %d: %g ADU left after the correction (sd %g)",
                          r, c, fixed, s_fix);
            if (fabs(truth) > big) big = fabs(truth);
        }
    }
    ck_assert_msg(big > 20.0, "offsets of %g ADU at most: too small to tell", big);
    free(corr);
    wf_refpix_free(&rp);
    stream_free(&s);
}
END_TEST

/* The shared 1/f through the readout (read noise, photons and offsets off): the side pixels
 * are read at positions 0-3 of every channel, so the correction leaves x_i - mean(x_0..x_3) at
 * readout position i, whose variance per read is, from the model's covariance,
 *   g(0) - (1/2) sum_k g(i - k) + (1/16) sum_kl g(k - l),
 * divided by the n reads of a resultant (independent realisations), plus the rounding of the
 * resultants to whole ADU (1/12, and 1/96 from the side mean). The shared 1/f faster than a
 * row stays: the correction takes ~40% of the raw variance here. */
START_TEST(refpix_leaves_the_model_residual)
{
    wf_readout_config cfg;
    wf_clock clock;
    dark_config(&cfg, &clock);
    const double amp = 3.0;
    cfg.det.on.photon_noise = cfg.det.on.read_noise = cfg.det.on.quantize = cfg.det.on.channel_offsets = 0;
    cfg.det.on.read_1f = 1;
    cfg.det.rn1f_corr_e = amp;
    cfg.det.rn1f_uncorr_e = 0.0;
    stream s;
    run(&cfg, &clock, 2, &s);
    wf_refpix rp;
    ck_assert_int_eq(wf_refpix_init(&rp, s.nres, s.ncols, s.nrows, cfg.det.bias_adu), WF_OK);
    wf_refpix_set_rows(&rp, s.rows);
    wf_refpix_set_cols(&rp, 0, (uint32_t)s.nrows, s.cols);
    double v = 0.0, side = 0.0;
    for (int k = 0; k < 4; k++)
        for (int l = 0; l < 4; l++) side += wf_corrnoise_acov(k - l) / 16.0;
    for (int x = 0; x < s.ncols; x++) {
        int i = wf_corrnoise_position(x + 4);
        double c = 0.0;
        for (int k = 0; k < 4; k++) c += wf_corrnoise_acov(i - k) / 2.0;
        v += (wf_corrnoise_acov(0) - c + side) / s.ncols;
    }
    double *corr = malloc((size_t)s.nres * s.ncols * sizeof *corr);
    double got = 0.0, want = 0.0, raw = 0.0, raw_want = 0.0;
    for (int r = 0; r < s.nres; r++) {
        int n = clock.ma.first[r + 1] - clock.ma.first[r];
        double q = 0.0, q_raw = 0.0;
        for (int y = 0; y < s.nrows; y++) {
            wf_refpix_correction(&rp, (uint32_t)y, corr);
            for (int x = 0; x < s.ncols; x++) {
                double d = s.res[((size_t)r * s.nrows + y) * s.ncols + x] - cfg.det.bias_adu;
                double e = d - corr[(size_t)r * s.ncols + x];
                q += e * e;
                q_raw += d * d;
            }
        }
        got += q / ((double)s.nrows * s.ncols);
        raw += q_raw / ((double)s.nrows * s.ncols);
        want += amp * amp * v / n + 1.0 / 12.0 + 1.0 / 96.0;
        raw_want += amp * amp * wf_corrnoise_acov(0) / n + 1.0 / 12.0;
    }
    ck_assert_msg(fabs(got / want - 1.0) < 0.05, "after the correction %g ADU^2, model %g", got, want);
    /* the raw frame holds the slow part too (g(0) / n in expectation; one draw per read of the
     * slowest components, so no tight bound on one exposure) */
    ck_assert_msg(raw > 1.5 * got, "raw %g ADU^2 (model %g) against %g corrected", raw, raw_want, got);
    printf("refpix residual: %.4g ADU^2 against the model's %.4g; raw %.4g (model %.4g)\n", got, want, raw,
           raw_want);
    free(corr);
    wf_refpix_free(&rp);
    stream_free(&s);
}
END_TEST

/* ---- products ----------------------------------------------------------------------------- */

#define SMALL "--set readout.ncols=120 --set readout.nrows=64 --set readout.ma_table=4 --set run.quiet=true"

/* With the effects off, their parameters change no byte (not even the input digest), and the
 * stream has no reference packets. */
START_TEST(off_changes_nothing)
{
    const char *bin = wf_test_program(), *dir = wf_test_tmpdir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    ck_assert_int_eq(wf_test_run("cd %s && %s expose " SMALL " --set run.out=a", dir, bin), 0);
    ck_assert_int_eq(wf_test_run("cd %s && %s expose " SMALL " --set run.out=b --set detector.rn1f_corr=7 "
                                 "--set detector.channel_offset=3 --set products.border=true", dir, bin), 0);
    ck_assert_int_eq(wf_test_run("cmp -s %s/a/wfisim_e000001_sca01.fits %s/b/wfisim_e000001_sca01.fits", dir, dir), 0);
    ck_assert_int_eq(wf_test_run("cd %s && %s expose " SMALL " --set detector.effects.read_1f=true --set run.out=c",
                                 dir, bin), 0);
    ck_assert_int_ne(wf_test_run("cmp -s %s/a/wfisim_e000001_sca01.fits %s/c/wfisim_e000001_sca01.fits", dir, dir), 0);
}
END_TEST

static void image_shape(fitsfile *f, const char *ext, long *naxes)
{
    int status = 0, naxis = 0;
    fits_movnam_hdu(f, IMAGE_HDU, (char *)ext, 0, &status);
    fits_get_img_dim(f, &naxis, &status);
    naxes[2] = 1;
    fits_get_img_size(f, 3, naxes, &status);
    ck_assert_msg(status == 0, "%s: cfitsio status %d", ext, status);
}

START_TEST(border_written_when_asked)
{
    const char *bin = wf_test_program(), *dir = wf_test_tmpdir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *on = "--set detector.effects.refpix=true --set detector.effects.channel_offsets=true";
    ck_assert_int_eq(wf_test_run("cd %s && %s expose " SMALL " %s --set run.out=a", dir, bin, on), 0);
    ck_assert_int_eq(wf_test_run("cd %s && %s expose " SMALL " %s --set run.out=b --set products.border=true", dir,
                                 bin, on), 0);
    char pa[4200], pb[4200];
    snprintf(pa, sizeof pa, "%s/a/wfisim_e000001_sca01.fits", dir);
    snprintf(pb, sizeof pb, "%s/b/wfisim_e000001_sca01.fits", dir);
    fitsfile *fa = NULL, *fb = NULL;
    int status = 0, na = 0, nb = 0;
    fits_open_file(&fa, pa, READONLY, &status);
    fits_open_file(&fb, pb, READONLY, &status);
    ck_assert_int_eq(status, 0);
    fits_get_num_hdus(fa, &na, &status);
    fits_get_num_hdus(fb, &nb, &status);
    ck_assert_int_eq(nb, na + 2);
    long rows[3], cols[3], sci[3];
    image_shape(fb, "REFROWS", rows);
    image_shape(fb, "REFCOLS", cols);
    image_shape(fb, "SCI", sci);
    ck_assert(rows[0] == 128 && rows[1] == 8 && rows[2] == 9); /* MA table 4: 9 resultants */
    ck_assert(cols[0] == 8 && cols[1] == 64 && cols[2] == 9);
    ck_assert(sci[0] == 120 && sci[1] == 64);
    /* the active area's images and their WCS are those of a product without the border */
    const char *keys[] = {"CRPIX1", "CRPIX2", "CRVAL1", "CRVAL2", "CD1_1", "CD2_2"};
    fits_movnam_hdu(fa, IMAGE_HDU, "SCI", 0, &status);
    for (int i = 0; i < 6; i++) {
        double va = 0, vb = 0;
        fits_read_key(fa, TDOUBLE, keys[i], &va, NULL, &status);
        fits_read_key(fb, TDOUBLE, keys[i], &vb, NULL, &status);
        ck_assert_msg(status == 0 && va == vb, "%s: %g against %g (status %d)", keys[i], va, vb, status);
    }
    /* the border's pixels are the bias and offsets: near 1000 ADU, never 0 */
    unsigned short v[128];
    int anynul = 0;
    fits_movnam_hdu(fb, IMAGE_HDU, "REFROWS", 0, &status);
    fits_read_img(fb, TUSHORT, 1, 128, NULL, v, &anynul, &status);
    ck_assert_int_eq(status, 0);
    for (int i = 0; i < 128; i++) ck_assert_msg(v[i] > 500 && v[i] < 1500, "REFROWS pixel %d: %u", i, v[i]);
    fits_close_file(fa, &status);
    fits_close_file(fb, &status);
}
END_TEST

/* The reference packets are not taken in any order: a row fitted before its reference pixels
 * could not be corrected, so such a stream is refused, and no FITS is left. Ramp mode only. */
START_TEST(refused_out_of_order_and_single)
{
    const char *bin = wf_test_program(), *dir = wf_test_tmpdir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *on = "--set detector.effects.refpix=true --set readout.compress=false";
    ck_assert_int_eq(wf_test_run("cd %s && %s expose " SMALL " %s --stream s.bin", dir, bin, on), 0);
    char path[4200];
    snprintf(path, sizeof path, "%s/s.bin", dir);
    size_t len = 0;
    unsigned char *b = (unsigned char *)wf_test_slurp(path, &len);
    ck_assert_ptr_nonnull(b);
    /* packets: 48-byte header, payload_len at byte 32; REFROWS (kind 8) moved just before END */
    unsigned char *out = malloc(len);
    size_t at = 0, o = 0, rr_at = 0, rr_len = 0, end_at = 0;
    while (at + 48 <= len) {
        unsigned k = b[at + 6] | b[at + 7] << 8;
        size_t n = 48 + (size_t)(b[at + 32] | b[at + 33] << 8 | b[at + 34] << 16 | (size_t)b[at + 35] << 24);
        if (k == WF_PK_REFROWS) { rr_at = at; rr_len = n; }
        else if (k == WF_PK_END) end_at = at;
        at += n;
    }
    ck_assert(at == len && rr_len && end_at);
    memcpy(out, b, rr_at);
    o = rr_at;
    memcpy(out + o, b + rr_at + rr_len, end_at - rr_at - rr_len);
    o += end_at - rr_at - rr_len;
    memcpy(out + o, b + rr_at, rr_len);
    o += rr_len;
    memcpy(out + o, b + end_at, len - end_at);
    snprintf(path, sizeof path, "%s/late.bin", dir);
    FILE *f = fopen(path, "wb");
    ck_assert(f && fwrite(out, 1, len, f) == len && fclose(f) == 0);
    ck_assert_int_ne(wf_test_run("cd %s && %s assemble late.bin --out late 2> late.txt", dir, bin), 0);
    snprintf(path, sizeof path, "%s/late.txt", dir);
    ck_assert_msg(wf_test_file_contains(path, "before its reference pixels arrived"), "message of the refusal");
    ck_assert_int_ne(wf_test_run("ls %s/late/*.fits > /dev/null 2>&1", dir), 0);
    ck_assert_int_ne(wf_test_run("cd %s && %s expose " SMALL " %s --set exposure.mode=single 2> single.txt", dir,
                                 bin, on), 0);
    snprintf(path, sizeof path, "%s/single.txt", dir);
    ck_assert_msg(wf_test_file_contains(path, "need exposure.mode ramp"), "message of the refusal");
    free(b);
    free(out);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("corrnoise");
    TCase *t = tcase_create("core");
    tcase_set_timeout(t, 300);
    tcase_add_test(t, spectrum_along_the_readout);
    tcase_add_test(t, shared_noise_mirrors);
    tcase_add_test(t, independent_of_tiles_and_threads);
    tcase_add_test(t, refpix_removes_channel_offsets);
    tcase_add_test(t, refpix_leaves_the_model_residual);
    tcase_add_test(t, off_changes_nothing);
    tcase_add_test(t, border_written_when_asked);
    tcase_add_test(t, refused_out_of_order_and_single);
    suite_add_tcase(s, t);
    return s;
}

int main(void) { return wf_test_main(suite()); }
