/* Tile-compressed product HDUs (sim/fits/fitscomp.h): integer HDUs round-trip bit for bit, the
 * quantization of float HDUs adds the noise the step predicts and no bias (on pixels and on
 * aperture photometry of point sources), the bytes do not depend on the order or grouping
 * in which rows are written, and checksums verify. */
#include <fitsio.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "sim/fits/fitscomp.h"
#include "sim/fits/fitsout.h"
#include "sim/fits/rice.h"
#include <fitsio2.h>
#include "tests/testutil.h"

#define NX 512
#define NY 512
#define SIGMA 1.0   /* sky noise per pixel */
#define SKY 10.0
#define PSF 1.5     /* Gaussian PSF sigma, pixels */
#define APER 4.5    /* aperture radius, pixels (3 PSF sigma: 99% of the flux) */
#define SPACING 32  /* point sources on a grid */

/* Sky with Gaussian noise plus point sources of flux 200..2000 on a grid. */
static float *noisy_image(void)
{
    float *img = malloc(sizeof *img * NX * NY);
    ck_assert_ptr_nonnull(img);
    uint64_t s = 7;
    for (int y = 0; y < NY; y++)
        for (int x = 0; x < NX; x++) {
            double v = SKY + SIGMA * wf_test_gauss(&s);
            int cx = (x / SPACING) * SPACING + SPACING / 2, cy = (y / SPACING) * SPACING + SPACING / 2;
            double flux = 200.0 + 1800.0 * (double)((cx / SPACING + 3 * (cy / SPACING)) % 16) / 15.0;
            double r2 = (x - cx) * (x - cx) + (y - cy) * (y - cy);
            v += flux * exp(-0.5 * r2 / (PSF * PSF)) / (2 * M_PI * PSF * PSF);
            img[(size_t)y * NX + x] = (float)v;
        }
    return img;
}

/* 1: write_product hands the rows to cfitsio's own fits_write_img (its own Rice coder)
 * instead of wf_fits_part_write_rows */
static int via_cfitsio;

/* A product: empty primary plus one compressed image of bitpix, written `rows` rows at a
 * time from the bottom (reverse = 0) or top (1) down, then checksummed. */
static void write_product(const char *path, int bitpix, int type, int naxis, long *naxes, const void *pix,
                          size_t elem, double q, int seed, int rows, int reverse)
{
    char tmp[4200], part[4300];
    fitsfile *f, *p;
    ck_assert_int_eq(wf_fits_begin(path, tmp, sizeof tmp, &f), WF_OK);
    int status = 0;
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    ck_assert_int_eq(wf_fits_reserve_checksum(f, tmp), WF_OK);
    snprintf(part, sizeof part, "%s.part", tmp);
    wf_fits_comp c = {.quantize = q, .dither_seed = seed};
    ck_assert_msg(wf_fits_part_create(part, &c, bitpix, naxis, naxes, &p) == WF_OK, "%s", wf_error_message());
    fits_update_key_str(p, "EXTNAME", "SCI", "test image", &status);
    ck_assert_int_eq(wf_fits_reserve_checksum(p, part), WF_OK);
    long nrows = naxes[1] * (naxis > 2 ? naxes[2] : 1); /* every plane's rows, in order */
    for (long k = 0; k < nrows; k += rows) {
        long r0 = reverse ? (nrows - k - rows > 0 ? nrows - k - rows : 0) : k;
        long n = reverse ? (nrows - k) - r0 : (k + rows <= nrows ? rows : nrows - k);
        void *at = (void *)((const char *)pix + (size_t)r0 * (size_t)naxes[0] * elem);
        if (via_cfitsio == 2) /* cfitsio quantizes and codes each row at the step wfisim measures */
            for (long r = 0; r < n; r++) {
                float *row = (float *)at + (size_t)r * (size_t)naxes[0], scratch[NX];
                ck_assert(naxes[0] <= NX);
                const double step = wf_fits_row_noise(row, naxes[0], scratch) / q;
                const float level = step > 0 && isfinite(step) ? -(float)step : (float)q;
                fits_set_quantize_level(p, level, &status);
                p->Fptr->quantize_level = level;
                fits_write_img(p, TFLOAT, (LONGLONG)(r0 + r) * naxes[0] + 1, naxes[0], row, &status);
                fits_set_quantize_level(p, (float)q, &status);
                p->Fptr->quantize_level = (float)q;
            }
        else if (via_cfitsio)
            fits_write_img(p, type, (LONGLONG)r0 * naxes[0] + 1, (LONGLONG)n * naxes[0], at, &status);
        else
            wf_fits_part_write_rows(p, type, naxes[0], r0, n, at, &status);
        ck_assert_int_eq(status, 0);
    }
    wf_fits_datasum ds;
    ck_assert_msg(wf_fits_part_append(f, tmp, p, part, &ds) == WF_OK, "%s", wf_error_message());
    ck_assert_int_ne(access(part, F_OK), 0); /* the part is gone */
    ck_assert_msg(wf_fits_finish(f, tmp, path, WF_OK) == WF_OK, "%s", wf_error_message());
    ck_assert_msg(wf_fits_verify_checksums(path, 2) == WF_OK, "%s", wf_error_message());
    /* the data unit's sum taken while appending is the DATASUM cfitsio read back */
    char value[FLEN_VALUE];
    fits_open_diskfile(&f, path, READONLY, &status);
    fits_movabs_hdu(f, 2, NULL, &status);
    fits_read_key_str(f, "DATASUM", value, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_msg(ds.valid && strtoul(value, NULL, 10) == wf_fits_datasum_value(&ds), "DATASUM %s, summed %lu (valid %d)",
                  value, wf_fits_datasum_value(&ds), ds.valid);
}

static void read_back(const char *path, int type, long n, void *out)
{
    fitsfile *f;
    int status = 0, anynul = 0;
    fits_open_diskfile(&f, path, READONLY, &status);
    fits_movabs_hdu(f, 2, NULL, &status);
    int compressed = fits_is_compressed_image(f, &status);
    fits_read_img(f, type, 1, n, NULL, out, &anynul, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_msg(compressed, "%s: HDU 2 is not tile-compressed", path);
    fits_close_file(f, &status);
}

/* The quantization step cfitsio chose for each row (ZSCALE of each one-row tile). */
static void read_steps(const char *path, double *step, long n)
{
    fitsfile *f;
    int status = 0, col = 0, anynul = 0;
    fits_open_diskfile(&f, path, READONLY, &status);
    fits_movabs_hdu(f, 2, NULL, &status);
    fits_get_colnum(f, CASEINSEN, "ZSCALE", &col, &status);
    fits_read_col(f, TDOUBLE, col, 1, 1, n, NULL, step, &anynul, &status);
    ck_assert_msg(status == 0, "%s: no ZSCALE column: cfitsio %d", path, status);
    fits_close_file(f, &status);
}

static unsigned char *slurp(const char *path, size_t *len)
{
    unsigned char *d = (unsigned char *)wf_test_slurp(path, len);
    ck_assert_ptr_nonnull(d);
    return d;
}

static int same_file(const char *a, const char *b)
{
    size_t la, lb;
    unsigned char *da = slurp(a, &la), *db = slurp(b, &lb);
    int same = la == lb && !memcmp(da, db, la);
    free(da);
    free(db);
    return same;
}

START_TEST(test_integers_lossless)
{
    const char *dir = wf_test_tmpdir();
    char path[4096];
    /* a RESULTANTS-like cube with every 16-bit value, and DQ words with every bit */
    enum { NR = 5, W = 300, H = 40 };
    static uint16_t cube[NR * H * W], back16[NR * H * W];
    static uint32_t dq[H * W], back32[H * W];
    uint64_t s = 3;
    for (size_t i = 0; i < NR * H * W; i++) cube[i] = i < 65536 ? (uint16_t)i : (uint16_t)wf_test_splitmix(&s);
    for (size_t i = 0; i < H * W; i++) dq[i] = i < 64 ? (i < 32 ? 1u << i : ~(1u << (i - 32))) : (uint32_t)wf_test_splitmix(&s);
    long ax3[3] = {W, H, NR}, ax2[2] = {W, H};
    snprintf(path, sizeof path, "%s/cube.fits", dir);
    write_product(path, USHORT_IMG, TUSHORT, 3, ax3, cube, 2, 16, 1, 7, 0);
    read_back(path, TUSHORT, NR * H * W, back16);
    ck_assert_msg(!memcmp(cube, back16, sizeof cube), "RESULTANTS-like cube changed");
    snprintf(path, sizeof path, "%s/dq.fits", dir);
    write_product(path, ULONG_IMG, TUINT, 2, ax2, dq, 4, 16, 1, 5, 1);
    read_back(path, TUINT, H * W, back32);
    ck_assert_msg(!memcmp(dq, back32, sizeof dq), "DQ-like words changed");
}
END_TEST

START_TEST(test_float_lossless_at_zero)
{
    const char *dir = wf_test_tmpdir();
    char path[4096];
    float *img = noisy_image(), *back = malloc(sizeof *back * NX * NY);
    long ax[2] = {NX, NY};
    snprintf(path, sizeof path, "%s/q0.fits", dir);
    write_product(path, FLOAT_IMG, TFLOAT, 2, ax, img, 4, 0, 1, 16, 0);
    read_back(path, TFLOAT, NX * NY, back);
    ck_assert_msg(!memcmp(img, back, sizeof *img * NX * NY), "q = 0 must keep floats exact");
    free(img);
    free(back);
}
END_TEST

/* The quantization step is (noise / q) and dithered rounding adds a uniform error on
 * [-step/2, step/2]: rms step / sqrt 12, mean 0. On an aperture sum of N pixels the errors
 * add in quadrature: rms sqrt(N) sigma / (q sqrt 12), i.e. 1 / (q sqrt 12) of the aperture's
 * sky noise, with no bias. */
START_TEST(test_quantization_error)
{
    const char *dir = wf_test_tmpdir();
    float *img = noisy_image(), *back = malloc(sizeof *back * NX * NY);
    ck_assert_ptr_nonnull(back);
    long ax[2] = {NX, NY};
    const double qs[] = {4, 8, 16, 32};
    for (int k = 0; k < 4; k++) {
        const double q = qs[k], predicted = SIGMA / (q * sqrt(12.0));
        char path[4096];
        snprintf(path, sizeof path, "%s/q%g.fits", dir, q);
        write_product(path, FLOAT_IMG, TFLOAT, 2, ax, img, 4, q, 4321, 32, 0);
        read_back(path, TFLOAT, NX * NY, back);
        static double step[NY];
        read_steps(path, step, NY);
        /* pixels between the sources: the step of a row without a source is the sky noise / q
         * (wf_fits_row_noise's estimate of it, exactly), the error's rms step / sqrt 12 */
        double s1 = 0, s2 = 0, p2 = 0;
        long n = 0;
        for (int y = 0; y < NY; y++) {
            int dy = y % SPACING - SPACING / 2;
            if (dy * dy < 100) continue; /* rows through sources: a larger noise estimate */
            /* the estimate (a median of 508 third differences) scatters row to row around sigma */
            ck_assert_msg(step[y] * q / SIGMA > 0.75 && step[y] * q / SIGMA < 1.25, "q %g row %d: step %.4g, sigma / q = %.4g",
                          q, y, step[y], SIGMA / q);
            float scratch[NX];
            const double want = wf_fits_row_noise(img + (size_t)y * NX, NX, scratch) / q;
            ck_assert_msg(fabs(step[y] / want - 1) < 1e-6, "q %g row %d: ZSCALE %.7g, noise / q %.7g", q, y, step[y], want);
            for (int x = 0; x < NX; x++) {
                double d = (double)back[(size_t)y * NX + x] - img[(size_t)y * NX + x];
                s1 += d;
                s2 += d * d;
                p2 += step[y] * step[y] / 12;
                n++;
            }
        }
        double mean = s1 / n, rms = sqrt(s2 / n);
        ck_assert_msg(rms < 1.05 * predicted && fabs(rms / sqrt(p2 / n) - 1) < 0.03,
                      "q %g: pixel rms error %.4g, predicted %.4g (from the steps %.4g)", q, rms, predicted,
                      sqrt(p2 / n));
        ck_assert_msg(fabs(mean) < 5 * rms / sqrt((double)n), "q %g: pixel bias %.3g (rms %.3g, %ld pixels)", q,
                      mean, rms, n);
        /* aperture photometry of every source: the errors of its pixels add in quadrature,
         * each of rms (its row's step) / sqrt 12; rows through a source have a coarser step
         * than the sky's, so the error is set against the photometric noise of the source
         * (sky and its own Poisson noise in e-, the image being in e-) */
        double f1 = 0, f2 = 0, e2 = 0, n2 = 0, npix = 0;
        int nsrc = 0;
        for (int cy = SPACING / 2; cy < NY; cy += SPACING)
            for (int cx = SPACING / 2; cx < NX; cx += SPACING) {
                double d = 0, flux = 0;
                int m = 0;
                for (int y = cy - 5; y <= cy + 5; y++)
                    for (int x = cx - 5; x <= cx + 5; x++)
                        if ((x - cx) * (x - cx) + (y - cy) * (y - cy) <= APER * APER) {
                            d += (double)back[(size_t)y * NX + x] - img[(size_t)y * NX + x];
                            e2 += step[y] * step[y] / 12;
                            flux += img[(size_t)y * NX + x] - SKY;
                            m++;
                        }
                f1 += d;
                f2 += d * d;
                n2 += m * SIGMA * SIGMA + (flux > 0 ? flux : 0);
                npix = m;
                nsrc++;
            }
        double fbias = f1 / nsrc, frms = sqrt(f2 / nsrc), fpred = sqrt(e2 / nsrc), noise = sqrt(n2 / nsrc);
        ck_assert_msg(fabs(frms / fpred - 1) < 0.25, "q %g: aperture flux rms error %.4g, predicted %.4g", q, frms,
                      fpred);
        /* q >= 4: the added error is under a tenth of the photometric noise (< 0.5% in variance) */
        ck_assert_msg(frms < 0.1 * noise * 4 / q, "q %g: aperture flux rms error %.4g of the noise %.4g", q, frms,
                      noise);
        ck_assert_msg(fabs(fbias) < 4 * frms / sqrt((double)nsrc), "q %g: aperture flux bias %.3g (rms %.3g, %d sources)",
                      q, fbias, frms, nsrc);
        printf("q %2g: sky step %.4f sigma; sky pixels rms %.4f sigma (sigma / (q sqrt 12) %.4f), bias %+.5f; aperture of %g px: rms %.4f of the "
               "photometric noise, bias %+.5f\n",
               q, step[0] / SIGMA, rms / SIGMA, predicted / SIGMA, mean / SIGMA, npix, frms / noise, fbias / noise);
    }
    free(img);
    free(back);
}
END_TEST

/* Rows written in any grouping and order (tile heights, threads) give the same bytes. */
START_TEST(test_same_bytes_any_order)
{
    const char *dir = wf_test_tmpdir();
    float *img = noisy_image();
    long ax[2] = {NX, NY};
    char a[4096], b[4096], c[4096], d[4096];
    snprintf(a, sizeof a, "%s/a.fits", dir);
    snprintf(b, sizeof b, "%s/b.fits", dir);
    snprintf(c, sizeof c, "%s/c.fits", dir);
    snprintf(d, sizeof d, "%s/d.fits", dir);
    write_product(a, FLOAT_IMG, TFLOAT, 2, ax, img, 4, 16, 77, 64, 0);
    write_product(b, FLOAT_IMG, TFLOAT, 2, ax, img, 4, 16, 77, 7, 1);
    write_product(c, FLOAT_IMG, TFLOAT, 2, ax, img, 4, 16, 77, 1, 1);
    ck_assert_msg(same_file(a, b) && same_file(a, c), "row order or grouping changed the product");
    write_product(d, FLOAT_IMG, TFLOAT, 2, ax, img, 4, 16, 78, 64, 0);
    ck_assert_msg(!same_file(a, d), "the dither seed must change the quantization");
    free(img);
}
END_TEST

/* The row noise is sigma for Gaussian pixels: a full SCA row (4088 pixels, the median's
 * relative scatter ~1.5%) of sigma 3 on a steep sky gradient plus a bright source reads
 * 3 within 6%; a constant row reads 0 (left to cfitsio); the estimate is a median, so 2% of
 * the pixels made 100 sigma outliers (6% of the differences) move it by under 15%. */
START_TEST(test_row_noise)
{
    enum { N = 4088 };
    static float row[N], scratch[N];
    uint64_t s = 99;
    for (int i = 0; i < N; i++) {
        const double d = i - 2000.0;
        row[i] = (float)(100.0 + 0.05 * i + 5000.0 * exp(-0.5 * d * d / 2.25) + 3.0 * wf_test_gauss(&s));
    }
    double n = wf_fits_row_noise(row, N, scratch);
    ck_assert_msg(fabs(n / 3.0 - 1) < 0.06, "row noise %.4f, sigma 3", n);
    for (int i = 0; i < N; i += 50) row[i] += 300.0f;
    double n2 = wf_fits_row_noise(row, N, scratch);
    ck_assert_msg(n2 > n && n2 < 1.15 * n, "with outliers %.4f, without %.4f", n2, n);
    for (int i = 0; i < N; i++) row[i] = 7.5f;
    ck_assert(wf_fits_row_noise(row, N, scratch) == 0);
    ck_assert(wf_fits_row_noise(row, 4, scratch) == 0);
}
END_TEST

/* The row noise is the same number as a sort's: 0.6052697 x the ((m - 1) / 2)-th smallest of
 * the m finite |2 x_i - x_(i-2) - x_(i+2)| (qsort here). Rows of Gaussian noise at many
 * scales and lengths, negative rows, heavy ties (integer and few-valued rows), zeros, NaN and
 * infinities (left out of the median) and denormals. */
static int by_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

static double row_noise_by_sort(const float *row, long n)
{
    float *d = malloc((size_t)(n > 0 ? n : 1) * sizeof *d);
    long m = 0;
    for (long i = 2; i + 2 < n; i++) {
        float v = fabsf(2.0f * row[i] - row[i - 2] - row[i + 2]);
        if (isfinite(v)) d[m++] = v;
    }
    double r = 0;
    if (m > 0) {
        qsort(d, (size_t)m, sizeof *d, by_float);
        r = 0.6052697 * d[(m - 1) / 2];
    }
    free(d);
    return r;
}

START_TEST(test_row_noise_exact)
{
    enum { N = 4088 };
    static float row[N], scratch[N];
    uint64_t s = 7;
    const long lens[] = {5, 6, 7, 8, 33, 100, 1001, N};
    for (int trial = 0; trial < 400; trial++) {
        const long n = lens[trial % 8];
        const int kind = trial / 8 % 10;
        const double scale = pow(10.0, (trial % 13) - 6.0), base = (trial % 3 - 1) * 1e3 * scale;
        for (long i = 0; i < n; i++) {
            double v = base + scale * wf_test_gauss(&s);
            switch (kind) {
            case 1: v = -fabs(v); break;                          /* all negative */
            case 2: v = floor(v / scale); break;                  /* integers: ties */
            case 3: v = (double)((int)(4 * fabs(wf_test_gauss(&s))) % 3); break; /* three values */
            case 4: if (i % 7 == 0) v = NAN; break;
            case 5: if (i % 11 == 0) v = i % 2 ? INFINITY : -INFINITY; break;
            case 6: v = 1e-42 * wf_test_gauss(&s); break;                 /* denormals */
            case 7: if (i % 3) v = 0.0; break;                    /* mostly zeros */
            case 8: v = i % 2 ? NAN : v; break;                   /* half NaN */
            default: break;
            }
            row[i] = (float)v;
        }
        const double got = wf_fits_row_noise(row, n, scratch), want = row_noise_by_sort(row, n);
        ck_assert_msg(got == want || (isnan(got) && isnan(want)), "trial %d (n %ld, kind %d): %.9g, sort %.9g",
                      trial, n, kind, got, want);
    }
    for (long i = 0; i < N; i++) row[i] = NAN; /* nothing finite: 0 */
    ck_assert(wf_fits_row_noise(row, N, scratch) == 0 && row_noise_by_sort(row, N) == 0);
}
END_TEST

START_TEST(test_dither_seed)
{
    int seen[10001] = {0}, distinct = 0;
    for (uint32_t e = 0; e < 100; e++)
        for (uint32_t s = 1; s <= 18; s++) {
            int v = wf_fits_comp_dither_seed(1, e, s);
            ck_assert(v >= 1 && v <= 10000);
            ck_assert_int_eq(v, wf_fits_comp_dither_seed(1, e, s));
            distinct += !seen[v]++;
        }
    /* 1800 draws from 10000 values: about 1650 distinct if they spread like random ones */
    ck_assert_int_gt(distinct, 1550);
    ck_assert_int_ne(wf_fits_comp_dither_seed(1, 5, 3), wf_fits_comp_dither_seed(2, 5, 3));
    /* a step coarser than the noise is refused, naming the key, and leaves no file */
    char part[4096];
    snprintf(part, sizeof part, "%s/p.part", wf_test_tmpdir());
    fitsfile *f = NULL;
    long ax[2] = {8, 8};
    wf_fits_comp c = {.quantize = 0.5, .dither_seed = 1};
    ck_assert_int_eq(wf_fits_part_create(part, &c, FLOAT_IMG, 2, ax, &f), WF_ERR_RANGE);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "products.quantize_level"));
    ck_assert_int_ne(access(part, F_OK), 0);
}
END_TEST

START_TEST(test_damage_detected)
{
    const char *dir = wf_test_tmpdir();
    float *img = noisy_image();
    long ax[2] = {NX, NY};
    char path[4096];
    snprintf(path, sizeof path, "%s/dmg.fits", dir);
    write_product(path, FLOAT_IMG, TFLOAT, 2, ax, img, 4, 16, 5, 16, 0);
    size_t len;
    unsigned char *d = slurp(path, &len);
    d[len - 20000] ^= 0x10; /* inside the heap of compressed tiles */
    FILE *f = fopen(path, "wb");
    ck_assert_uint_eq(fwrite(d, 1, len, f), len);
    fclose(f);
    free(d);
    wf_status st = wf_fits_verify_checksums(path, 0);
    ck_assert_int_eq(st, WF_ERR_CORRUPT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "section 2"));
    free(img);
}
END_TEST

/* Pixels of one of several kinds: 0 zeros, 1 a constant, 2 noise of sigma around a level,
 * 3 any value, 4 a constant with rare jumps across the whole range (long unary codes), 5 a
 * ramp wrapping around. */
static void pattern(int kind, double sigma, int bytepix, long n, uint64_t *s, void *out)
{
    const uint32_t top = bytepix == 2 ? 0xffffu : 0xffffffffu;
    for (long i = 0; i < n; i++) {
        double g = wf_test_gauss(s);
        uint64_t r = wf_test_splitmix(s);
        uint32_t v = kind == 0 ? 0u
                     : kind == 1 ? 1234u
                     : kind == 2 ? (uint32_t)(int64_t)llround(fmin(fmax(30000.0 + sigma * g, 0.0), (double)top))
                     : kind == 3 ? (uint32_t)r
                     : kind == 4 ? (r % 97 == 0 ? (uint32_t)(r >> 32) : 7u)
                                 : (uint32_t)(i * 977u);
        v &= top;
        if (bytepix == 2) ((uint16_t *)out)[i] = (uint16_t)v;
        else ((uint32_t *)out)[i] = v;
    }
}

/* wfisim's Rice coder writes cfitsio's bytes: every length (short last blocks, one pixel),
 * block size, pixel width and kind of data, unsigned pixels flipped to the stored signed
 * ones as cfitsio flips them. */
START_TEST(test_rice_matches_cfitsio)
{
    enum { MAXN = 4200 };
    static uint32_t pix[MAXN];
    static int ref_in[MAXN];
    static short ref16[MAXN];
    static unsigned char ours[8 * MAXN], theirs[8 * MAXN];
    const long lens[] = {1, 2, 31, 32, 33, 300, 4088};
    const int blocks[] = {32, 16, 7, 1};
    const double sigmas[] = {0.5, 3, 40, 3000, 30000};
    uint64_t s = 99;
    long cases = 0, long_runs = 0;
    for (int bp = 2; bp <= 4; bp += 2)
        for (int li = 0; li < 7; li++)
            for (int bi = 0; bi < 4; bi++)
                for (int kind = 0; kind < 6; kind++)
                    for (int si = 0; si < (kind == 2 ? 5 : 1); si++) {
                        const long n = lens[li];
                        const int block = blocks[bi];
                        const uint32_t flip = (kind & 1) ? (bp == 2 ? 0x8000u : 0x80000000u) : 0u;
                        pattern(kind, sigmas[si], bp, n, &s, pix);
                        size_t len;
                        ck_assert_msg(wf_fits_rice_code(pix, n, bp, flip, block, ours, sizeof ours, &len) == WF_OK,
                                      "%s", wf_error_message());
                        int nref;
                        if (bp == 2) {
                            for (long i = 0; i < n; i++) ref16[i] = (short)(((const uint16_t *)pix)[i] ^ flip);
                            nref = fits_rcomp_short(ref16, (int)n, theirs, (int)sizeof theirs, block);
                        } else {
                            for (long i = 0; i < n; i++) ref_in[i] = (int)(pix[i] ^ flip);
                            nref = fits_rcomp(ref_in, (int)n, theirs, (int)sizeof theirs, block);
                        }
                        ck_assert_msg(nref > 0 && (size_t)nref == len && !memcmp(ours, theirs, len),
                                      "%d-byte pixels, n %ld, block %d, kind %d, sigma %g: %zu bytes against cfitsio's %d",
                                      bp, n, block, kind, sigmas[si], len, nref);
                        /* the coder stores a word's 4 bytes past its output's end as it goes */
                        ck_assert_msg(len + 4 <= wf_fits_rice_bound(n, bp), "n %ld: %zu bytes + 4 over the bound", n, len);
                        long_runs += kind == 4 && n >= 300 && block == 32;
                        cases++;
                    }
    ck_assert(long_runs > 0);
    printf("Rice coder: %ld cases byte-identical to cfitsio's\n", cases);
}
END_TEST

/* Products whose integer HDUs wfisim codes are the bytes cfitsio writes when it codes them. */
START_TEST(test_own_rice_same_product)
{
    const char *dir = wf_test_tmpdir();
    enum { NR = 3, W = 333, H = 24 };
    static uint16_t cube[NR * H * W];
    static uint32_t dq[H * W];
    uint64_t s = 5;
    for (int k = 0; k < NR * H; k++) pattern(k % 6, 40.0, 2, W, &s, cube + (size_t)k * W);
    for (int k = 0; k < H; k++) pattern(k % 6, 3000.0, 4, W, &s, dq + (size_t)k * W);
    long ax3[3] = {W, H, NR}, ax2[2] = {W, H};
    char a[4096], b[4096];
    const struct { int bitpix, type, naxis; long *ax; void *pix; size_t elem; } hd[] = {
        {USHORT_IMG, TUSHORT, 3, ax3, cube, 2}, {SHORT_IMG, TSHORT, 3, ax3, cube, 2},
        {ULONG_IMG, TUINT, 2, ax2, dq, 4}, {LONG_IMG, TINT, 2, ax2, dq, 4}};
    for (int k = 0; k < 4; k++) {
        snprintf(a, sizeof a, "%s/own%d.fits", dir, k);
        snprintf(b, sizeof b, "%s/cfitsio%d.fits", dir, k);
        via_cfitsio = 0;
        const long t0 = wf_fits_own_rice_tiles(), tiles = hd[k].ax[1] * (hd[k].naxis > 2 ? hd[k].ax[2] : 1);
        write_product(a, hd[k].bitpix, hd[k].type, hd[k].naxis, hd[k].ax, hd[k].pix, hd[k].elem, 16, 1, 5, 0);
        ck_assert_msg(wf_fits_own_rice_tiles() - t0 == tiles, "bitpix %d: %ld of %ld tiles coded by wfisim", hd[k].bitpix,
                      wf_fits_own_rice_tiles() - t0, tiles);
        via_cfitsio = 1;
        write_product(b, hd[k].bitpix, hd[k].type, hd[k].naxis, hd[k].ax, hd[k].pix, hd[k].elem, 16, 1, 5, 0);
        via_cfitsio = 0;
        ck_assert_int_eq(wf_fits_own_rice_tiles() - t0, tiles); /* cfitsio's path left to cfitsio */
        ck_assert_msg(same_file(a, b), "bitpix %d: the product differs from cfitsio's", hd[k].bitpix);
    }
}
END_TEST

/* Quantized float HDUs whose tiles wfisim writes (cfitsio's quantizer, wfisim's Rice coder,
 * ZSCALE and ZZERO) are the bytes cfitsio writes given the same steps; rows it leaves to
 * cfitsio (one without noise to measure, one with a NaN) too, and rows with exact zeros
 * (SUBTRACTIVE_DITHER_2 keeps them) are its own. */
START_TEST(test_own_quantized_same_product)
{
    const char *dir = wf_test_tmpdir();
    float *img = noisy_image();
    for (int x = 0; x < NX; x++) img[3 * NX + x] = 10.0f; /* nothing to measure: cfitsio's */
    img[7 * NX + 100] = NAN;                             /* not finite: cfitsio's */
    for (int x = 0; x < NX; x += 7) img[11 * NX + x] = 0.0f;
    long ax[2] = {NX, NY};
    char a[4096], b[4096];
    for (int rows = 1; rows <= 40; rows += 39) {
        snprintf(a, sizeof a, "%s/ownq%d.fits", dir, rows);
        snprintf(b, sizeof b, "%s/cfitsioq%d.fits", dir, rows);
        via_cfitsio = 0;
        const long t0 = wf_fits_own_rice_tiles();
        write_product(a, FLOAT_IMG, TFLOAT, 2, ax, img, sizeof(float), 4.0, 77, rows, 1);
        ck_assert_msg(wf_fits_own_rice_tiles() - t0 == NY - 2, "%ld of %d rows coded by wfisim",
                      wf_fits_own_rice_tiles() - t0, NY - 2);
        via_cfitsio = 2;
        write_product(b, FLOAT_IMG, TFLOAT, 2, ax, img, sizeof(float), 4.0, 77, rows, 1);
        via_cfitsio = 0;
        ck_assert_msg(same_file(a, b), "%d rows at a time: the product differs from cfitsio's", rows);
    }
    free(img);
}
END_TEST

static Suite *fitscomp_suite(void)
{
    Suite *s = suite_create("fitscomp");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, test_integers_lossless);
    tcase_add_test(tc, test_rice_matches_cfitsio);
    tcase_add_test(tc, test_own_rice_same_product);
    tcase_add_test(tc, test_own_quantized_same_product);
    tcase_add_test(tc, test_float_lossless_at_zero);
    tcase_add_test(tc, test_quantization_error);
    tcase_add_test(tc, test_same_bytes_any_order);
    tcase_add_test(tc, test_row_noise);
    tcase_add_test(tc, test_row_noise_exact);
    tcase_add_test(tc, test_dither_seed);
    tcase_add_test(tc, test_damage_detected);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(fitscomp_suite()); }
