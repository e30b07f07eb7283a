/* Detector effects (firmware/detector.c):
 *  - against GalSim 2.8.4 outputs in ../shared/reference/galsim/detector_ref.fits.gz
 *    (skipped when absent): nonlinearity, reciprocity failure at 300 s and 139.8 s, IPC of
 *    a ramp, a delta and a flat image, the chain reciprocity -> NL -> IPC, quantization;
 *  - closed forms that need no reference: IPC charge conservation, the exact edge and
 *    corner losses of a flat image, the kernel orientation on a delta, the NL and
 *    reciprocity laws at chosen points, round half to even, the saturation level;
 *  - the defaults against SPEC §2 and the normalised kernel in facts.json.
 *
 * Image orientation: the FITS files are read with cfitsio into row-major arrays,
 * img[row * NAXIS1 + col], where col = x - 1 (FITS axis 1) and row = y - 1 (FITS axis 2) —
 * numpy's [j][i]. The IPC outputs use these inputs (shapes and values checked below):
 *   IPC_OUT = IPC(RAMP_IN), DELTA_IPC_OUT = IPC(DELTA_IN), FLAT_IPC_OUT = IPC(FLAT_IN),
 *   CHAIN_OUT_300S = IPC(NL(reciprocity(RAMP_IN, 300 s))).
 * GalSim's result is out[row][col] = sum_ab K[a][b] in[row + a - 1][col + b - 1] with the
 * facts.json kernel (K[row][col] = kernel(i, j)) and zeros outside: a delta at (32, 32)
 * puts K[2][2] at (31, 31), K[0][1] at (33, 32), K[1][0] at (32, 33). That is
 * wf_det_ipc_row with in_0 = row above (row - 1). */
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "firmware/detector.h"
#include "hal/noise.h"
#include "hal/vmath.h"
#include "tests/testutil.h"

#define NREF 64

/* ------------------------------------------------------------------------------ helpers */

static void ipc_image(const double *in, int nrows, int ncols, const double k[3][3], double *out)
{
    for (int y = 0; y < nrows; y++)
        wf_det_ipc_row(y > 0 ? in + (size_t)(y - 1) * ncols : NULL, in + (size_t)y * ncols,
                       y + 1 < nrows ? in + (size_t)(y + 1) * ncols : NULL, ncols, k,
                       out + (size_t)y * ncols);
}

/* Largest |got - want| / |want|; where want == 0, got must be exactly 0 (else +inf). */
static double max_rel_diff(const double *got, const double *want, size_t n, size_t *where)
{
    double worst = 0.0;
    for (size_t i = 0; i < n; i++) {
        double d = want[i] == 0.0 ? (got[i] == 0.0 ? 0.0 : INFINITY)
                                   : fabs(got[i] - want[i]) / fabs(want[i]);
        if (!(d <= worst)) {
            worst = d;
            if (where) *where = i;
        }
    }
    return worst;
}

static double max_abs_diff(const double *got, const double *want, size_t n)
{
    double worst = 0.0;
    for (size_t i = 0; i < n; i++) {
        double d = fabs(got[i] - want[i]);
        if (!(d <= worst)) worst = d;
    }
    return worst;
}

/* A 64x64 extension of detector_ref.fits.gz, or NULL when the reference is absent. */
static double *load_ref(const char *extname)
{
    const char *dir = wf_test_reference_dir();
    if (!dir) return NULL;
    char path[4200];
    snprintf(path, sizeof path, "%s/detector_ref.fits.gz", dir);
    fitsfile *f = NULL;
    int st = 0;
    if (fits_open_file(&f, path, READONLY, &st)) return NULL;
    char name[72];
    snprintf(name, sizeof name, "%s", extname);
    fits_movnam_hdu(f, IMAGE_HDU, name, 0, &st);
    int naxis = 0;
    long naxes[2] = {0, 0};
    fits_get_img_dim(f, &naxis, &st);
    fits_get_img_size(f, 2, naxes, &st);
    ck_assert_msg(st == 0, "%s[%s]: cfitsio status %d", path, extname, st);
    ck_assert_msg(naxis == 2 && naxes[0] == NREF && naxes[1] == NREF, "%s: %dD %ldx%ld", extname,
                  naxis, naxes[0], naxes[1]);
    double *img = malloc(sizeof(double) * NREF * NREF);
    ck_assert(img != NULL);
    long fpix[2] = {1, 1};
    fits_read_pix(f, TDOUBLE, fpix, NREF * NREF, NULL, img, NULL, &st);
    fits_close_file(f, &st);
    ck_assert_msg(st == 0, "reading %s[%s]: cfitsio status %d", path, extname, st);
    return img;
}

#define REF_OR_SKIP(var, ext)                                                  \
    double *var = load_ref(ext);                                               \
    WF_SKIP_UNLESS(var, "GalSim reference detector_ref.fits.gz")

/* --------------------------------------------------------------------- against GalSim */

START_TEST(test_galsim_nonlinearity)
{
    REF_OR_SKIP(in, "RAMP_IN");
    double *want = load_ref("NL_OUT");
    wf_detector det;
    wf_detector_defaults(&det);
    double got[NREF * NREF];
    for (int i = 0; i < NREF * NREF; i++) got[i] = wf_det_nonlinearity(in[i], det.nl_beta);
    size_t at = 0;
    double d = max_rel_diff(got, want, NREF * NREF, &at);
    printf("GalSim NL_OUT: max relative difference %.3g (at %zu)\n", d, at);
    ck_assert_msg(d <= 1e-12, "NL: relative difference %.3g at %zu: %.17g vs %.17g", d, at,
                  got[at], want[at]);
    free(in);
    free(want);
}
END_TEST

START_TEST(test_galsim_reciprocity)
{
    REF_OR_SKIP(in, "RAMP_IN");
    const char *ext[2] = {"RECIP_OUT_300S", "RECIP_OUT_139P8S"};
    const double t[2] = {300.0, 139.8};
    wf_detector det;
    wf_detector_defaults(&det);
    for (int e = 0; e < 2; e++) {
        double *want = load_ref(ext[e]);
        double got[NREF * NREF];
        for (int i = 0; i < NREF * NREF; i++)
            got[i] = wf_det_reciprocity(in[i], t[e], det.recip_alpha, det.recip_f0);
        size_t at = 0;
        double d = max_rel_diff(got, want, NREF * NREF, &at);
        printf("GalSim %s: max relative difference %.3g\n", ext[e], d);
        ck_assert_msg(d <= 1e-12, "%s: relative difference %.3g at %zu: %.17g vs %.17g", ext[e],
                      d, at, got[at], want[at]);
        free(want);
    }
    free(in);
}
END_TEST

START_TEST(test_galsim_ipc)
{
    REF_OR_SKIP(ramp, "RAMP_IN");
    const char *in_ext[3] = {"RAMP_IN", "DELTA_IN", "FLAT_IN"};
    const char *out_ext[3] = {"IPC_OUT", "DELTA_IPC_OUT", "FLAT_IPC_OUT"};
    double k[3][3];
    wf_detector_ipc_default(k);
    free(ramp);
    for (int e = 0; e < 3; e++) {
        double *in = load_ref(in_ext[e]);
        double *want = load_ref(out_ext[e]);
        double got[NREF * NREF];
        ipc_image(in, NREF, NREF, k, got);
        size_t at = 0;
        double d = max_rel_diff(got, want, NREF * NREF, &at);
        printf("GalSim %s = IPC(%s): max relative difference %.3g\n", out_ext[e], in_ext[e], d);
        ck_assert_msg(d <= 1e-12, "%s: relative difference %.3g at row %zu col %zu: %.17g vs %.17g",
                      out_ext[e], d, at / NREF, at % NREF, got[at], want[at]);
        free(in);
        free(want);
    }
}
END_TEST

/* The delta response pins the orientation on its own (no summation involved): each
 * neighbour of the delta at (row 32, col 32) holds exactly one kernel element. */
START_TEST(test_galsim_ipc_orientation)
{
    REF_OR_SKIP(in, "DELTA_IN");
    double *out = load_ref("DELTA_IPC_OUT");
    int r0 = -1, c0 = -1, nonzero = 0;
    for (int i = 0; i < NREF * NREF; i++)
        if (in[i] != 0.0) r0 = i / NREF, c0 = i % NREF, nonzero++;
    ck_assert_int_eq(nonzero, 1);
    ck_assert(r0 > 0 && r0 < NREF - 1 && c0 > 0 && c0 < NREF - 1);
    const double amp = in[r0 * NREF + c0];
    double k[3][3];
    wf_detector_ipc_default(k);
    /* out[r0 + dr][c0 + dc] = K[1 - dr][1 - dc] * amp for in[y + a - 1][x + b - 1] weighting */
    double worst = 0.0;
    for (int dr = -1; dr <= 1; dr++)
        for (int dc = -1; dc <= 1; dc++) {
            double want = out[(r0 + dr) * NREF + c0 + dc] / amp;
            double rel = fabs(k[1 - dr][1 - dc] - want) / want;
            if (rel > worst) worst = rel;
        }
    printf("GalSim delta response vs K[1-dr][1-dc]: max relative difference %.3g\n", worst);
    ck_assert_msg(worst <= 1e-12, "kernel orientation differs from GalSim (%.3g)", worst);
    free(in);
    free(out);
}
END_TEST

START_TEST(test_galsim_chain)
{
    REF_OR_SKIP(in, "RAMP_IN");
    double *want = load_ref("CHAIN_OUT_300S");
    wf_detector det;
    wf_detector_defaults(&det);
    double mid[NREF * NREF], got[NREF * NREF];
    for (int i = 0; i < NREF * NREF; i++)
        mid[i] = wf_det_nonlinearity(
            wf_det_reciprocity(in[i], 300.0, det.recip_alpha, det.recip_f0), det.nl_beta);
    ipc_image(mid, NREF, NREF, det.ipc, got);
    size_t at = 0;
    double d = max_rel_diff(got, want, NREF * NREF, &at);
    printf("GalSim CHAIN_OUT_300S: max relative difference %.3g\n", d);
    ck_assert_msg(d <= 1e-12, "chain: relative difference %.3g at %zu: %.17g vs %.17g", d, at,
                  got[at], want[at]);
    free(in);
    free(want);
}
END_TEST

START_TEST(test_galsim_quantize)
{
    REF_OR_SKIP(in, "QUANTIZE_IN");
    double *want = load_ref("QUANTIZE_OUT");
    double got[NREF * NREF];
    int halves = 0;
    for (int i = 0; i < NREF * NREF; i++) {
        got[i] = wf_det_quantize(in[i]);
        if (in[i] - floor(in[i]) == 0.5) halves++;
    }
    double d = max_abs_diff(got, want, NREF * NREF);
    printf("GalSim QUANTIZE_OUT: max absolute difference %g (%d exact halves)\n", d, halves);
    ck_assert_int_gt(halves, 100); /* the reference really exercises the ties */
    ck_assert_msg(d == 0.0, "quantize differs from GalSim by %g", d);
    free(in);
    free(want);
}
END_TEST

/* The nine numbers after "key" in a JSON text (nested arrays flattened). */
static int json_nine(const char *text, const char *key, double out[9])
{
    const char *p = strstr(text, key);
    if (!p) return 0;
    p += strlen(key);
    p = strchr(p, '[');
    if (!p) return 0;
    int n = 0;
    while (n < 9 && *p) {
        if (*p == '-' || (*p >= '0' && *p <= '9')) {
            char *end;
            out[n++] = strtod(p, &end);
            p = end;
        } else {
            p++;
        }
    }
    return n == 9;
}

START_TEST(test_defaults_match_facts)
{
    const char *dir = wf_test_reference_dir();
    WF_SKIP_UNLESS(dir, "GalSim reference facts.json");
    char path[4200];
    snprintf(path, sizeof path, "%s/facts.json", dir);
    FILE *f = fopen(path, "rb");
    WF_SKIP_UNLESS(f, "GalSim reference facts.json");
    fseek(f, 0, SEEK_END);
    long len = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *text = malloc((size_t)len + 1);
    ck_assert(text != NULL);
    ck_assert(fread(text, 1, (size_t)len, f) == (size_t)len);
    text[len] = '\0';
    fclose(f);

    double kn[9], kr[9];
    ck_assert(json_nine(text, "\"ipc_kernel_normalised\"", kn));
    ck_assert(json_nine(text, "\"ipc_kernel_raw\"", kr));
    wf_detector det;
    wf_detector_defaults(&det);
    double worst = 0.0;
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) {
            double d = fabs(det.ipc[a][b] - kn[a * 3 + b]);
            if (d > worst) worst = d;
        }
    printf("facts.json ipc_kernel_normalised: max absolute difference %.3g\n", worst);
    ck_assert_msg(worst <= 1e-12, "IPC kernel differs from facts.json by %.3g", worst);

    /* Centre = 1 / sum(raw), from the raw kernel in the same file. */
    double sum = 0.0;
    for (int i = 0; i < 9; i++) sum += kr[i];
    ck_assert_double_eq_tol(det.ipc[1][1], 1.0 / sum, 1e-12);
    ck_assert_double_eq_tol(kn[4], 1.0 / sum, 1e-12);

    /* Scalar facts. */
    const struct {
        const char *key;
        double value;
    } scal[] = {{"\"read_noise\"", det.read_noise_e},
                {"\"gain\"", det.gain},
                {"\"dark_current\"", det.dark_current},
                {"\"nonlinearity_beta\"", det.nl_beta},
                {"\"reciprocity_alpha\"", det.recip_alpha}};
    for (size_t i = 0; i < sizeof scal / sizeof scal[0]; i++) {
        const char *p = strstr(text, scal[i].key);
        ck_assert_msg(p != NULL, "%s not in facts.json", scal[i].key);
        p = strchr(p, ':');
        ck_assert(p != NULL);
        double v = strtod(p + 1, NULL);
        ck_assert_msg(v == scal[i].value, "%s: facts %.17g, default %.17g", scal[i].key, v,
                      scal[i].value);
    }
    free(text);
}
END_TEST

/* ------------------------------------------------------------------------- closed forms */

START_TEST(test_defaults_spec)
{
    wf_detector det;
    wf_detector_defaults(&det);
    ck_assert(det.read_noise_e == 8.5);
    ck_assert(det.dark_current == 0.015);
    ck_assert(det.gain == 1.0);
    ck_assert(det.nl_beta == -6.0e-7);
    ck_assert(det.recip_alpha == 0.0065);
    ck_assert(det.recip_f0 == 1.0);
    ck_assert(det.full_well == 1e5);
    ck_assert(det.adc_max == 65535.0);
    ck_assert(det.on.photon_noise && det.on.reciprocity && det.on.dark && det.on.nonlinearity &&
              det.on.ipc && det.on.read_noise && det.on.quantize && det.on.saturation);

    /* SPEC §2 raw kernel, normalised here. */
    static const double raw[3][3] = {{0.001269938, 0.015399776, 0.001199862},
                                     {0.013800177, 1.0, 0.015600367},
                                     {0.001270391, 0.016129619, 0.001200137}};
    double rsum = 0.0, ksum = 0.0;
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) rsum += raw[a][b], ksum += det.ipc[a][b];
    ck_assert_double_eq_tol(ksum, 1.0, 1e-15);
    ck_assert_double_eq_tol(det.ipc[1][1], 1.0 / rsum, 1e-15);
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++)
            ck_assert_double_eq_tol(det.ipc[a][b], raw[a][b] / rsum, 1e-16);
    double k[3][3];
    wf_detector_ipc_default(k);
    ck_assert_mem_eq(k, det.ipc, sizeof k);
}
END_TEST

/* Orientation of wf_det_ipc_row on its own terms, with a kernel whose nine entries are all
 * different: out[y][x] = sum K[a][b] in[y+a-1][x+b-1]. */
START_TEST(test_ipc_formula_delta)
{
    enum { R = 5, C = 6 };
    double k[3][3];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) k[a][b] = 1.0 + 3 * a + b; /* 1..9 */
    for (int y0 = 0; y0 < R; y0++)
        for (int x0 = 0; x0 < C; x0++) {
            double in[R * C] = {0}, out[R * C];
            in[y0 * C + x0] = 1.0;
            ipc_image(in, R, C, k, out);
            for (int y = 0; y < R; y++)
                for (int x = 0; x < C; x++) {
                    int a = y0 - y + 1, b = x0 - x + 1; /* in[y+a-1][x+b-1] is the delta */
                    double want = (a >= 0 && a < 3 && b >= 0 && b < 3) ? k[a][b] : 0.0;
                    ck_assert_msg(out[y * C + x] == want, "delta (%d,%d) out (%d,%d) = %g, want %g",
                                  y0, x0, y, x, out[y * C + x], want);
                }
        }
}
END_TEST

START_TEST(test_ipc_small_widths)
{
    double k[3][3];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) k[a][b] = 1.0 + 3 * a + b;
    const double above[2] = {10.0, 20.0}, row[2] = {100.0, 200.0}, below[2] = {1000.0, 2000.0};
    double out[3] = {-7.0, -7.0, -7.0};
    /* one column: only the middle kernel column sees data */
    wf_det_ipc_row(above, row, below, 1, k, out);
    ck_assert(out[0] == k[0][1] * 10.0 + k[1][1] * 100.0 + k[2][1] * 1000.0);
    ck_assert(out[1] == -7.0);
    /* two columns */
    wf_det_ipc_row(above, row, below, 2, k, out);
    ck_assert(out[0] == k[0][1] * 10 + k[0][2] * 20 + k[1][1] * 100 + k[1][2] * 200 +
                            k[2][1] * 1000 + k[2][2] * 2000);
    ck_assert(out[1] == k[0][0] * 10 + k[0][1] * 20 + k[1][0] * 100 + k[1][1] * 200 +
                            k[2][0] * 1000 + k[2][1] * 2000);
    ck_assert(out[2] == -7.0);
    /* zero columns: nothing is read or written (guard cells on both sides) */
    double guard[3] = {-7.0, -7.0, -7.0};
    wf_det_ipc_row(above, row, below, 0, k, guard + 1);
    ck_assert(guard[0] == -7.0 && guard[1] == -7.0 && guard[2] == -7.0);
}
END_TEST

static uint64_t lcg(uint64_t *s)
{
    *s = *s * 6364136223846793005ull + 1442695040888963407ull;
    return *s >> 11;
}

START_TEST(test_ipc_conserves_charge)
{
    enum { R = 40, C = 48 };
    double k[3][3];
    wf_detector_ipc_default(k);
    static double in[R * C], out[R * C];
    /* random source, zero within one pixel of the edges */
    uint64_t s = 12345;
    double sum_in = 0.0;
    for (int y = 0; y < R; y++)
        for (int x = 0; x < C; x++) {
            double v = (y > 0 && y < R - 1 && x > 0 && x < C - 1)
                           ? (double)(lcg(&s) % 1000000) * 0.37
                           : 0.0;
            in[y * C + x] = v;
            sum_in += v;
        }
    ipc_image(in, R, C, k, out);
    double sum_out = 0.0;
    for (int i = 0; i < R * C; i++) sum_out += out[i];
    printf("IPC charge conservation: relative change %.3g\n", fabs(sum_out - sum_in) / sum_in);
    ck_assert_double_eq_tol(sum_out / sum_in, 1.0, 1e-12);
}
END_TEST

START_TEST(test_ipc_flat_edges)
{
    enum { R = 7, C = 9 };
    const double level = 1000.0;
    double k[3][3];
    wf_detector_ipc_default(k);
    double in[R * C], out[R * C];
    for (int i = 0; i < R * C; i++) in[i] = level;
    ipc_image(in, R, C, k, out);
    /* Kernel rows a = 0 (weighs the row above) and columns b = 0 (the column to the left)
     * fall off the top and left edges, a = 2 and b = 2 off the bottom and right. */
    double row_sum[3] = {0}, col_sum[3] = {0};
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) row_sum[a] += k[a][b], col_sum[b] += k[a][b];
    double worst = 0.0;
    for (int y = 0; y < R; y++)
        for (int x = 0; x < C; x++) {
            double lost = 0.0;
            if (y == 0) lost += row_sum[0];
            if (y == R - 1) lost += row_sum[2];
            if (x == 0) lost += col_sum[0];
            if (x == C - 1) lost += col_sum[2];
            /* corners: the corner element was subtracted twice */
            if (y == 0 && x == 0) lost -= k[0][0];
            if (y == 0 && x == C - 1) lost -= k[0][2];
            if (y == R - 1 && x == 0) lost -= k[2][0];
            if (y == R - 1 && x == C - 1) lost -= k[2][2];
            double want = level * (1.0 - lost);
            double d = fabs(out[y * C + x] - want) / want;
            if (d > worst) worst = d;
        }
    printf("IPC flat edges/corners vs kernel sums: max relative difference %.3g\n", worst);
    ck_assert(worst <= 1e-14);
    /* SPEC §3.1: ~1.5% lost along edges, ~3% at corners */
    double edge = 1.0 - out[0 * C + C / 2] / level, corner = 1.0 - out[0] / level;
    ck_assert(edge > 0.01 && edge < 0.02);
    ck_assert(corner > 0.025 && corner < 0.035);
}
END_TEST

START_TEST(test_nonlinearity_points)
{
    const double beta = -6.0e-7;
    ck_assert(wf_det_nonlinearity(0.0, beta) == 0.0);
    ck_assert_double_eq_tol(wf_det_nonlinearity(1e5, beta), 1e5 - 6000.0, 1e-9);
    ck_assert_double_eq_tol(wf_det_nonlinearity(2e5, beta), 176000.0, 1e-9);
    ck_assert_double_eq_tol(wf_det_nonlinearity(1000.0, beta), 999.4, 1e-12);
    /* turnover at -1/(2 beta) */
    const double qt = -1.0 / (2.0 * beta);
    ck_assert(wf_det_nonlinearity(qt, beta) > wf_det_nonlinearity(qt * 0.99, beta));
    ck_assert(wf_det_nonlinearity(qt, beta) > wf_det_nonlinearity(qt * 1.01, beta));
    ck_assert(wf_det_nonlinearity(123.0, 0.0) == 123.0);
}
END_TEST

/* A row of expected electrons is the scalar law, bit for bit, for every switch of reciprocity
 * and dark current: negative, zero, NaN and huge rates included. */
START_TEST(test_expected_row_as_scalar)
{
    enum { N = 37 };
    float rate[N];
    double mean[N], expm[N];
    for (int i = 0; i < N; i++) rate[i] = (float)(pow(10.0, -3.0 + 0.25 * i) * (i % 5 == 3 ? -1.0 : 1.0));
    rate[0] = 0.0f;
    rate[1] = NAN;
    rate[2] = 3e38f;
    for (int c = 0; c < 4; c++) {
        wf_detector d;
        wf_detector_defaults(&d);
        d.on.reciprocity = c & 1;
        d.on.dark = (c >> 1) & 1;
        const double ft = 3.04;
        wf_det_expected_row(&d, rate, N, ft, mean, expm);
        for (int i = 0; i < N; i++) {
            double r = rate[i] > 0.0f ? rate[i] : 0.0;
            if (d.on.reciprocity) r = wf_det_reciprocity_rate(r, d.recip_alpha, d.recip_f0);
            if (d.on.dark) r += d.dark_current;
            ck_assert_msg(mean[i] == r * ft, "case %d pixel %d: %.17g vs %.17g", c, i, mean[i], r * ft);
            ck_assert_msg(expm[i] == wf_vexp(-r * ft), "case %d pixel %d", c, i);
            /* against libm's pow (the law itself, not its lane): within a few ulp */
            double rp = rate[i] > 0.0f ? rate[i] : 0.0;
            if (d.on.reciprocity && rp > 0.0) rp *= pow(rp / d.recip_f0, d.recip_alpha / M_LN10);
            if (d.on.dark) rp += d.dark_current;
            ck_assert_msg(isnan(rp) || fabs(mean[i] - rp * ft) <= 1e-15 * rp * ft, "case %d pixel %d: %.17g vs pow's %.17g",
                          c, i, mean[i], rp * ft);
            /* and exp within an ulp, or 0 past a mean of 708 */
            ck_assert(r * ft > 708.0 ? expm[i] == 0.0 : fabs(expm[i] - exp(-r * ft)) <= 2.3e-16 * exp(-r * ft));
        }
    }
}
END_TEST

START_TEST(test_reciprocity_points)
{
    const double alpha = 0.0065, f0 = 1.0, a = alpha / log(10.0);
    const double times[] = {3.16247, 139.8, 300.0, 977.0};
    for (size_t i = 0; i < sizeof times / sizeof times[0]; i++) {
        const double t = times[i];
        /* identity at q = t f0 */
        ck_assert_double_eq_tol(wf_det_reciprocity(t * f0, t, alpha, f0), t * f0, 1e-13 * t);
        /* ten times the reference charge: factor 10^a = e^alpha */
        ck_assert_double_eq_tol(wf_det_reciprocity(10.0 * t, t, alpha, f0) / (10.0 * t),
                                exp(alpha), 1e-14);
        ck_assert_double_eq_tol(wf_det_reciprocity(0.01 * t, t, alpha, f0) / (0.01 * t),
                                exp(-2.0 * alpha), 1e-14);
        /* rate form and charge form agree */
        for (double r = 1e-3; r < 1e6; r *= 3.7) {
            double q = wf_det_reciprocity(r * t, t, alpha, f0);
            double qr = wf_det_reciprocity_rate(r, alpha, f0) * t;
            ck_assert_msg(fabs(q - qr) <= 1e-14 * q, "r %g t %g: %.17g vs %.17g", r, t, q, qr);
            /* GalSim's own form: x^(a+1) / p0^a */
            double g = pow(r * t, a + 1.0) / pow(t * f0, a);
            ck_assert(fabs(q - g) <= 1e-13 * g);
        }
    }
    /* f0 scales the reference: identity at q = t f0 for f0 = 2.5 */
    ck_assert_double_eq_tol(wf_det_reciprocity(250.0, 100.0, alpha, 2.5), 250.0, 1e-12);
    /* non-positive charge unchanged */
    ck_assert(wf_det_reciprocity(0.0, 300.0, alpha, f0) == 0.0);
    ck_assert(wf_det_reciprocity(-5.0, 300.0, alpha, f0) == -5.0);
    ck_assert(wf_det_reciprocity_rate(0.0, alpha, f0) == 0.0);
}
END_TEST

START_TEST(test_quantize_half_even)
{
    const double in[] = {0.5, 1.5, 2.5, 3.5, -0.5, -1.5, -2.5, 0.49999999999999994, 2.5000000000000004,
                         65534.5, 65535.5, 1e15 + 0.5};
    const double want[] = {0.0, 2.0, 2.0, 4.0, -0.0, -2.0, -2.0, 0.0, 3.0, 65534.0, 65536.0, 1e15};
    for (size_t i = 0; i < sizeof in / sizeof in[0]; i++) {
        double q = wf_det_quantize(in[i]);
        ck_assert_msg(q == want[i], "quantize(%.17g) = %.17g, want %.17g", in[i], q, want[i]);
    }
    ck_assert(signbit(wf_det_quantize(-0.5)));
    ck_assert(!signbit(wf_det_quantize(0.5)));
}
END_TEST

START_TEST(test_saturation_adu)
{
    wf_detector det;
    wf_detector_defaults(&det);
    double want = (1e5 - 6e-7 * 1e10) / det.gain + 1000.0; /* SPEC well after NL, plus bias */
    if (want > 65535.0) want = 65535.0;
    ck_assert(wf_det_saturation_adu(&det) == want);
    /* below the ADC ceiling the full-well term decides */
    det.gain = 2.0;
    ck_assert_double_eq_tol(wf_det_saturation_adu(&det), (1e5 - 6e-7 * 1e10) / 2.0 + 1000.0, 1e-9);
    det.on.nonlinearity = 0;
    ck_assert_double_eq_tol(wf_det_saturation_adu(&det), 1e5 / 2.0 + 1000.0, 1e-9);
}
END_TEST

/* An up-the-ramp read digitised a row at a time: each pixel as the chain defines it (read
 * noise, gain, bias, half-to-even rounding, the ADC's [0, adc_max], a saturation flag where
 * the charge reached the full well or the ADU the ceiling), added to the resultant's sum;
 * the flag keeps the first resultant. Unit and other gains, odd lengths (vector tails). */
START_TEST(test_ramp_read_row)
{
    enum { N = 37 };
    wf_detector det;
    wf_detector_defaults(&det);
    det.adc_max = 65535.0;
    for (int g = 0; g < 2; g++) {
        det.gain = g ? 1.0 : 1.7;
        double e[N], q[N], sum[N], want_sum[N];
        float z[N];
        uint8_t first[N], want_first[N];
        for (int i = 0; i < N; i++) {
            /* negative to beyond the ADC, half-ADU points, charges around the full well */
            e[i] = -3000.0 + 4600.0 * i * det.gain + (i % 3 ? 0.5 * det.gain : 0.0);
            q[i] = det.full_well * (0.9 + 0.01 * i);
            z[i] = (float)(0.37 * (i % 5) - 0.8);
            sum[i] = want_sum[i] = 10.0 * i;
            first[i] = want_first[i] = i % 4 == 0 ? 1 : 255;
        }
        for (uint8_t r = 2; r < 4; r++) {
            wf_det_ramp_read_row(&det, e, q, z, N, r, sum, first);
            for (int i = 0; i < N; i++) {
                double adu = (e[i] + det.read_noise_e * (double)z[i]) / det.gain + det.bias_adu;
                adu = wf_det_quantize(adu);
                int clipped = q[i] >= det.full_well || adu >= det.adc_max;
                if (adu >= det.adc_max) adu = det.adc_max;
                if (adu < 0.0) adu = 0.0;
                want_sum[i] += adu;
                if (clipped && want_first[i] == 255) want_first[i] = r;
            }
            for (int i = 0; i < N; i++) {
                ck_assert_msg(sum[i] == want_sum[i], "gain %g, read %d, pixel %d: %.17g, want %.17g",
                              det.gain, r, i, sum[i], want_sum[i]);
                ck_assert_msg(first[i] == want_first[i], "pixel %d: first %u, want %u", i, first[i], want_first[i]);
            }
        }
        int zero = 0, top = 0;
        for (int i = 0; i < N; i++) zero += want_sum[i] == 10.0 * i, top += want_first[i] != 255;
        ck_assert(zero > 0 && top > 5); /* both ends of the ADC reached */
    }
}
END_TEST

/* Resultants from their reads' sums: rounded half to even, clamped to 16 bits, NaN to 0,
 * and the sums cleared. */
START_TEST(test_resultant_row)
{
    double sum[] = {3.0, 5.0, 7.0, -1.0, 196605.0, 196606.5, 1e300, NAN, 4.5 * 3.0, 0.0, 7.5 * 3.0};
    const uint16_t want[] = {1, 2, 2, 0, 65535, 65535, 65535, 0, 4, 0, 8};
    enum { N = sizeof sum / sizeof sum[0] };
    uint16_t out[N];
    wf_det_resultant_row(sum, N, 3, out);
    for (int i = 0; i < N; i++) {
        ck_assert_msg(out[i] == want[i], "sum %d: %u, want %u", i, out[i], want[i]);
        ck_assert(sum[i] == 0.0);
    }
}
END_TEST

/* A resultant drawn at once: the read noise of the mean of n reads, sigma / sqrt(n), then
 * as one read (gain, bias, half-to-even rounding, the ADC's range) into 16 bits (NaN 0);
 * saturated where its last read was: the charge q at the well or, after nonlinearity, its
 * signal at the ceiling, even when the resultant's own mean is below it. The flag keeps the
 * first resultant. Every switch on and off, exact halves, NaN and infinities. */
static uint16_t word_by_hand(double adu)
{
    double v = nearbyint(adu);
    if (!(v >= 0.0)) return 0; /* NaN too */
    return v > 65535.0 ? 65535 : (uint16_t)v;
}

START_TEST(test_group_row)
{
    enum { N = 48 };
    int by_last = 0, low = 0, high = 0, ties = 0;
    for (int sw = 0; sw < 32; sw++) {
        wf_detector det;
        wf_detector_defaults(&det);
        det.on.read_noise = sw & 1;
        det.on.quantize = (sw >> 1) & 1;
        det.on.saturation = (sw >> 2) & 1;
        det.on.nonlinearity = (sw >> 3) & 1;
        const int unit = (sw >> 4) & 1;
        det.gain = unit ? 1.0 : 1.7;
        det.adc_max = unit ? 65535.0 : 50000.0; /* 1.7: the ceiling below the well's signal */
        if (sw % 3 == 2) det.adc_max -= 0.3; /* a ceiling with a fraction: its word is rounded */
        double e[N], q[N];
        float z[N];
        uint8_t first[N], want_first[N];
        uint16_t out[N];
        for (int i = 0; i < N; i++) {
            /* whole and half ADU (exact ties at unit gain without read noise), charges from
             * below zero to past the well */
            e[i] = -2000.0 + 2300.0 * i * det.gain + (i % 3 ? 0.5 * det.gain : 0.0);
            q[i] = e[i] + det.full_well * 0.03 * (i % 7);
            z[i] = (float)(0.41 * (i % 5) - 0.9);
            first[i] = want_first[i] = i % 6 == 0 ? 1 : 255;
        }
        e[N - 1] = NAN;
        e[N - 2] = INFINITY;
        e[N - 3] = -INFINITY;
        q[N - 4] = NAN;
        for (uint8_t r = 2; r < 4; r++) {
            const int n = 2 * r; /* reads in the group */
            wf_det_group_row(&det, e, q, z, N, n, r, first, out);
            for (int i = 0; i < N; i++) {
                double v = e[i];
                if (det.on.read_noise) v += det.read_noise_e / sqrt((double)n) * (double)z[i];
                double adu = v / det.gain + det.bias_adu;
                if (det.on.quantize) adu = nearbyint(adu);
                ties += !det.on.quantize && adu - floor(adu) == 0.5;
                if (det.on.saturation) {
                    double last = q[i] < det.full_well ? q[i] : det.full_well;
                    if (det.on.nonlinearity) last += det.nl_beta * last * last;
                    const int at_last = q[i] >= det.full_well || last / det.gain + det.bias_adu >= det.adc_max;
                    by_last += at_last && adu < det.adc_max;
                    int clipped = at_last || adu >= det.adc_max;
                    if (adu >= det.adc_max) adu = det.adc_max, high++;
                    if (adu < 0.0) adu = 0.0, low++;
                    if (clipped && want_first[i] == 255) want_first[i] = r;
                }
                ck_assert_msg(out[i] == word_by_hand(adu), "switches %d, group %d, pixel %d: %u, want %u (%.17g)", sw,
                              r, i, out[i], word_by_hand(adu), adu);
                ck_assert_msg(first[i] == want_first[i], "switches %d, pixel %d: first %u, want %u", sw, i, first[i],
                              want_first[i]);
            }
        }
    }
    /* the last-read rule, both ends of the ADC and exact halves all reached */
    ck_assert(by_last > 0 && low > 0 && high > 0 && ties > 0);
}
END_TEST

static wf_detector skip_detector(int sw) /* unit gain or 1.7 (its ceiling below the well), NL off or on */
{
    wf_detector det;
    wf_detector_defaults(&det);
    det.gain = sw & 1 ? 1.7 : 1.0;
    det.adc_max = sw & 1 ? 50000.0 : 65535.0;
    det.on.nonlinearity = sw >> 1;
    return det;
}

/* one pixel of a 4-read group as resultant 3: whether its flag is set, and whether by hand */
static int skip_pixel(const wf_detector *det, double e, double q, float z, int *want)
{
    const double sigma = det->read_noise_e / 2.0;
    uint8_t first = 255;
    uint16_t out;
    wf_det_group_row(det, &e, &q, &z, 1, 4, 3, &first, &out);
    double adu = nearbyint((e + sigma * (double)z) / det->gain + det->bias_adu);
    double last = q < det->full_well ? q : det->full_well;
    if (det->on.nonlinearity) last += det->nl_beta * last * last;
    *want = adu >= det->adc_max || q >= det->full_well || last / det->gain + det->bias_adu >= det->adc_max;
    ck_assert(first == 3 || first == 255);
    return first == 3;
}

/* wf_det_group_row skips its flags' pass in a row no pixel of which could clip: a pixel alone
 * in its row, with the largest normal a word gives (z of 0xffffffff) or a larger one, steps
 * through the ceiling's neighbourhood (signal and charge), and each flag is the hand-made
 * one: the skip's bound never hides a clip. */
START_TEST(test_group_row_skip_bound)
{
    const uint32_t top = 0xffffffffu;
    float zmax;
    wf_norm_from_u32(&top, 1, &zmax);
    int clips = 0, clear = 0, by_charge = 0, want;
    for (int sw = 0; sw < 4; sw++) {
        const wf_detector det = skip_detector(sw);
        const double sigma = det.read_noise_e / 2.0, ceiling_q = (det.adc_max - det.bias_adu) * det.gain;
        for (int zi = 0; zi < 3; zi++) {
            const float z = zi == 0 ? zmax : zi == 1 ? 0.0f : 9.0f;
            const double e0 = ceiling_q - sigma * (double)z;
            for (int k = -40; k <= 40; k++) {
                /* the charge: far from the well; at the last read's ceiling; at the well */
                const double qs[4] = {0.5 * det.full_well, ceiling_q * (1.0 + 1e-4 * k), det.full_well + 0.5 * k, 0.0};
                const int got = skip_pixel(&det, e0 + 0.05 * det.gain * k, qs[(k + 40) % 4], z, &want);
                clips += want;
                clear += !want;
                ck_assert_msg(got == want, "switches %d, z %g, step %d: flag %d", sw, (double)z, k, got);
            }
        }
        /* a faint signal whose charge is at the well, or whose last read is at the ceiling */
        for (int k = -8; k <= 8; k++)
            for (int at = 0; at < 2; at++) {
                const double q = at ? det.full_well + k : ceiling_q * (1.0 + 1e-3 * k);
                const int got = skip_pixel(&det, 100.0, q, 0.5f, &want);
                by_charge += want;
                ck_assert_msg(got == want, "switches %d, charge %.17g: flag %d", sw, q, got);
            }
    }
    ck_assert(clips > 0 && clear > 0 && by_charge > 0);
    printf("group row skip: largest normal %.4f; %d clipped and %d clear pixels at the ceiling, %d by charge\n",
           (double)zmax, clips, clear, by_charge);
}
END_TEST

static Suite *detector_suite(void)
{
    Suite *s = suite_create("detector");
    TCase *ref = tcase_create("galsim");
    tcase_set_timeout(ref, 60);
    tcase_add_test(ref, test_galsim_nonlinearity);
    tcase_add_test(ref, test_galsim_reciprocity);
    tcase_add_test(ref, test_galsim_ipc);
    tcase_add_test(ref, test_galsim_ipc_orientation);
    tcase_add_test(ref, test_galsim_chain);
    tcase_add_test(ref, test_galsim_quantize);
    tcase_add_test(ref, test_defaults_match_facts);
    suite_add_tcase(s, ref);

    TCase *cf = tcase_create("closed-form");
    tcase_set_timeout(cf, 60);
    tcase_add_test(cf, test_defaults_spec);
    tcase_add_test(cf, test_ipc_formula_delta);
    tcase_add_test(cf, test_ipc_small_widths);
    tcase_add_test(cf, test_ipc_conserves_charge);
    tcase_add_test(cf, test_ipc_flat_edges);
    tcase_add_test(cf, test_nonlinearity_points);
    tcase_add_test(cf, test_reciprocity_points);
    tcase_add_test(cf, test_expected_row_as_scalar);
    tcase_add_test(cf, test_quantize_half_even);
    tcase_add_test(cf, test_saturation_adu);
    tcase_add_test(cf, test_ramp_read_row);
    tcase_add_test(cf, test_resultant_row);
    tcase_add_test(cf, test_group_row);
    tcase_add_test(cf, test_group_row_skip_bound);
    suite_add_tcase(s, cf);
    return s;
}

int main(void) { return wf_test_main(detector_suite()); }
