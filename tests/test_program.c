/* The wfisim program end to end, as users run it: in-process and two-process paths give
 * identical FITS; tile height and thread count do not change a byte; bad input exits
 * non-zero with a message naming the file and leaves no product; the FITS opens in astropy. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <math.h>
#include <fitsio.h>
#include <zlib.h>

#include "sim/survey/wcs.h"
#include "tests/testutil.h"
#include "tools/config.h"
#include "tools/pipeline.h"

#define SMALL "--quiet --set scene.kind=grid --set readout.ncols=96 --set readout.nrows=80 --set readout.ma_table=4 " \
              "--set detector.cr_rate=500 --set scene.grid.spacing=20 --set scene.grid.flux=2e4"


static int exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

#define FITS "wfisim_e000001_sca01.fits"

START_TEST(pipe_equals_in_process)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    ck_assert_int_eq(wf_test_run("%s expose " SMALL " --out %s/a", bin, d), 0);
    ck_assert_int_eq(wf_test_run("%s expose " SMALL " --stream - | %s assemble - --quiet --out %s/b", bin, bin, d), 0);
    ck_assert_int_eq(wf_test_run("%s expose " SMALL " --stream %s/s.bin && %s assemble %s/s.bin --quiet --out %s/c",
                         bin, d, bin, d, d), 0);
    char a[4200], b[4200], c[4200];
    snprintf(a, sizeof a, "%s/a/" FITS, d);
    snprintf(b, sizeof b, "%s/b/" FITS, d);
    snprintf(c, sizeof c, "%s/c/" FITS, d);
    wf_test_assert_same_file(a, b);
    wf_test_assert_same_file(a, c);
}
END_TEST

START_TEST(tile_height_and_threads_do_not_matter)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    const char *modes[] = {"ramp --sampling per-read", "ramp --sampling direct", "ramp --sampling moments", "single"};
    for (int m = 0; m < 4; m++) {
        ck_assert_int_eq(wf_test_run("%s expose " SMALL " --mode %s --tile-rows 80 --out %s/ref%d", bin, modes[m], d, m), 0);
        char ref[4200];
        snprintf(ref, sizeof ref, "%s/ref%d/" FITS, d, m);
        const int heights[] = {1, 7, 64};
        for (int i = 0; i < 3; i++)
            for (int t = 1; t <= 2; t++) {
                ck_assert_int_eq(wf_test_run("%s expose " SMALL " --mode %s --tile-rows %d --threads %d --out %s/t%d_%d_%d",
                                     bin, modes[m], heights[i], t, d, m, heights[i], t), 0);
                char p[4200];
                snprintf(p, sizeof p, "%s/t%d_%d_%d/" FITS, d, m, heights[i], t);
                wf_test_assert_same_file(ref, p);
            }
    }
}
END_TEST

START_TEST(bad_config_named_and_no_product)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char cfg[4200], log[4200];
    snprintf(cfg, sizeof cfg, "%s/bad.yaml", d);
    snprintf(log, sizeof log, "%s/err.txt", d);
    FILE *f = fopen(cfg, "w");
    fputs("seed: 3\ndetector:\n  gain: 1.0\n  read_nosie: 5\n", f);
    fclose(f);
    int rc = wf_test_run("%s expose --quiet --config %s --out %s/out 2>%s", bin, cfg, d, log);
    ck_assert_int_ne(rc, 0);
    size_t n;
    char *msg = wf_test_slurp(log, &n);
    ck_assert_msg(strstr(msg, "bad.yaml") && strstr(msg, ":4") && strstr(msg, "read_nosie"),
                  "message does not name file, line and key: %s", msg);
    free(msg);
    char out[4200];
    snprintf(out, sizeof out, "%s/out/" FITS, d);
    ck_assert(!exists(out));
    /* an unknown filter on the command line */
    ck_assert_int_ne(wf_test_run("%s expose --quiet --filter Q999 --out %s/out 2>/dev/null", bin, d), 0);
}
END_TEST

START_TEST(corrupt_stream_leaves_nothing)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    ck_assert_int_eq(wf_test_run("%s expose " SMALL " --stream %s/s.bin", bin, d), 0);
    /* flip one byte in the middle of the stream */
    char path[4200];
    snprintf(path, sizeof path, "%s/s.bin", d);
    size_t n;
    char *buf = wf_test_slurp(path, &n);
    buf[n / 2] ^= 0x40;
    FILE *f = fopen(path, "wb");
    fwrite(buf, 1, n, f);
    fclose(f);
    free(buf);
    ck_assert_int_ne(wf_test_run("%s assemble %s --quiet --out %s/out 2>/dev/null", bin, path, d), 0);
    char out[4200], tmp[4300];
    snprintf(out, sizeof out, "%s/out/" FITS, d);
    snprintf(tmp, sizeof tmp, "%s.tmp", out);
    ck_assert(!exists(out));
    ck_assert(!exists(tmp));
    snprintf(out, sizeof out, "%s/out", d);
    ck_assert_msg(!exists(out), "the folder assemble made is left behind");
}
END_TEST

/* The in-process assembler fails (its file may not grow past 1 MB, the shell's ulimit -f,
 * with SIGXFSZ ignored so the write returns EFBIG): the run stops at once with the
 * assembler's reason, not the readout's "the reader has stopped", and leaves no product. */
START_TEST(assembler_failure_reported)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    ck_assert_int_ne(wf_test_run("sh -c \"trap '' XFSZ; ulimit -f 2000; exec %s expose --quiet --mode single "
                                 "--set scene.kind=grid --out %s/full 2>%s/full.err\"", bin, d, d), 0);
    char err[4200], out[4200], tmp[4300];
    snprintf(err, sizeof err, "%s/full.err", d);
    ck_assert_msg(wf_test_file_contains(err, "File too large"), "the assembler's reason is not reported");
    ck_assert_msg(!wf_test_file_contains(err, "reader has stopped"), "the readout's error masks the assembler's");
    snprintf(out, sizeof out, "%s/full/" FITS, d);
    snprintf(tmp, sizeof tmp, "%s.tmp", out);
    ck_assert(!exists(out));
    ck_assert(!exists(tmp));
}
END_TEST

START_TEST(fits_opens_in_astropy)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    if (wf_test_run("/usr/bin/python3 -c 'import astropy' 2>/dev/null") != 0) WF_SKIP("python3 with astropy not installed");
    const char *d = wf_test_tmpdir();
    ck_assert_int_eq(wf_test_run("%s expose " SMALL " --out %s", bin, d), 0);
    ck_assert_int_eq(wf_test_run("/usr/bin/python3 tests/fits_check.py %s/" FITS, d), 0);
}
END_TEST

/* The whole chain on a flat sky (every effect but cosmic rays on): the mean fitted rate is
 * the reciprocity-corrected sky plus dark current, within 4 sigma of the reported errors.
 * This is what catches a bias anywhere between the photons and the slope (clipping at the
 * ADC floor, averaging, rounding, linearity correction, weights). */
static void flat_sky_unbiased(const char *mode, double sky)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    ck_assert_int_eq(wf_test_run("%s expose --quiet --mode %s --set scene.kind=grid --set readout.ncols=128 --set readout.nrows=128 "
                         "--set detector.effects.cosmic_rays=false --set scene.grid.flux=0 "
                         "--set scene.sky_rate=%g --out %s", bin, mode, sky, d), 0);
    char path[4200];
    snprintf(path, sizeof path, "%s/" FITS, d);
    fitsfile *f;
    int status = 0;
    static float sci[128 * 128], err[128 * 128];
    long first[2] = {1, 1};
    fits_open_file(&f, path, READONLY, &status);
    fits_movnam_hdu(f, IMAGE_HDU, "SCI", 0, &status);
    fits_read_pix(f, TFLOAT, first, 128 * 128, NULL, sci, NULL, &status);
    fits_movnam_hdu(f, IMAGE_HDU, "ERR", 0, &status);
    fits_read_pix(f, TFLOAT, first, 128 * 128, NULL, err, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    double sum = 0, var = 0;
    int n = 0;
    for (int y = 1; y < 127; y++) /* interior: IPC keeps the charge it moves */
        for (int x = 1; x < 127; x++) {
            sum += sci[y * 128 + x];
            var += (double)err[y * 128 + x] * err[y * 128 + x];
            n++;
        }
    double mean = sum / n, sigma = sqrt(var) / n;
    double expect = sky * pow(sky, 0.0065 / log(10.0)) + 0.015;
    ck_assert_msg(fabs(mean - expect) < 4.0 * sigma, "%s: mean rate %.5f, expected %.5f +- %.5f", mode, mean,
                  expect, sigma);
}

START_TEST(flat_sky_ramp) { flat_sky_unbiased("ramp", 0.3953); }
END_TEST
START_TEST(flat_sky_ramp_bright) { flat_sky_unbiased("ramp", 50.0); }
END_TEST
START_TEST(flat_sky_single) { flat_sky_unbiased("single", 0.3953); }
END_TEST

/* The object scene (synthetic field, PSF, stamps, renderer) through the whole chain: tile
 * height and thread count change no byte of the image or the truth. */
START_TEST(object_scene_deterministic)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
#define OBJ "--quiet --set scene.kind=synthetic --set readout.ncols=160 --set readout.nrows=144 " \
            "--set readout.ma_table=4 --set psf.pupil_bin=8"
    ck_assert_int_eq(wf_test_run("%s expose " OBJ " --tile-rows 144 --out %s/ref", bin, d), 0);
    ck_assert_int_eq(wf_test_run("%s expose " OBJ " --tile-rows 7 --threads 2 --out %s/t7", bin, d), 0);
    ck_assert_int_eq(wf_test_run("%s expose " OBJ " --tile-rows 64 --threads 2 --out %s/t64", bin, d), 0);
    const char *names[] = {FITS, "wfisim_e000001_sca01_truth.fits"};
    for (int k = 0; k < 2; k++) {
        char a[4200], b[4200], c[4200];
        snprintf(a, sizeof a, "%s/ref/%s", d, names[k]);
        snprintf(b, sizeof b, "%s/t7/%s", d, names[k]);
        snprintf(c, sizeof c, "%s/t64/%s", d, names[k]);
        wf_test_assert_same_file(a, b);
        wf_test_assert_same_file(a, c);
    }
    /* the WCS rides on the image HDUs */
    char path[4200], ctype[FLEN_VALUE] = "";
    snprintf(path, sizeof path, "%s/ref/" FITS, d);
    fitsfile *f;
    int status = 0;
    fits_open_file(&f, path, READONLY, &status);
    fits_movnam_hdu(f, IMAGE_HDU, "ERR", 0, &status);
    fits_read_key_str(f, "CTYPE1", ctype, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_msg(!strncmp(ctype, "RA---TAN", 8), "CTYPE1 '%s'", ctype);
}
END_TEST

/* A full-width sub-array of 16 rows (the synthetic field's footprint is a thin sky
 * polygon, which the region builder once refused as "not convex"): it runs, the product
 * has the sub-array's shape, and tile height and threads change no byte. */
START_TEST(thin_subarray)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
#define THIN "--quiet --mode single --set scene.kind=synthetic --set readout.nrows=16 --set psf.pupil_bin=8"
    ck_assert_int_eq(wf_test_run("%s expose " THIN " --out %s/thin", bin, d), 0);
    ck_assert_int_eq(wf_test_run("%s expose " THIN " --tile-rows 5 --threads 2 --out %s/thin5", bin, d), 0);
    const char *names[] = {FITS, "wfisim_e000001_sca01_truth.fits"};
    for (int k = 0; k < 2; k++) {
        char a[4200], b[4200];
        snprintf(a, sizeof a, "%s/thin/%s", d, names[k]);
        snprintf(b, sizeof b, "%s/thin5/%s", d, names[k]);
        wf_test_assert_same_file(a, b);
    }
    char path[4200];
    snprintf(path, sizeof path, "%s/thin/" FITS, d);
    fitsfile *f;
    int status = 0, naxis = 0;
    long nax[2] = {0, 0};
    fits_open_file(&f, path, READONLY, &status);
    fits_movnam_hdu(f, IMAGE_HDU, "SCI", 0, &status);
    fits_get_img_dim(f, &naxis, &status);
    fits_get_img_size(f, 2, nax, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_msg(naxis == 2 && nax[0] == 4088 && nax[1] == 16, "SCI is %ld x %ld", nax[0], nax[1]);
}
END_TEST

/* SCA 1 at the demo's pointing (RA 71, Dec -53, PA 30), to place test objects by pixel */
static void demo_wcs(wf_wcs *w)
{
    wf_focal_plane fp;
    wf_wcs_focal_plane(NULL, &fp);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, 71.0, -53.0, 30.0, 1, w), WF_OK);
}

/* A catalog file through the command line: the objects the SCA sees are drawn and listed
 * in the truth, the others (far away, selected out by the sky index) are not. */
START_TEST(catalog_file_on_the_command_line)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    wf_wcs w;
    demo_wcs(&w);
    char path[4200];
    snprintf(path, sizeof path, "%s/gal.csv", d);
    FILE *f = fopen(path, "w");
    fprintf(f, "id,ra,dec,z,mag_Y106,hlr_disk,hlr_bulge,bulge_frac,knot_frac,e1,e2,pa\n");
    const double px[6] = {20, 60, 100, 64, 3000, 500}, py[6] = {30, 90, 110, 64, 3000, 20};
    for (int i = 0; i < 6; i++) { /* the first four lie on a 128 x 128 corner of SCA 1 */
        double ra, dec;
        wf_wcs_pix2world(&w, px[i], py[i], &ra, &dec);
        fprintf(f, "%d,%.10f,%.10f,0.7,21.5,0.4,0.2,0.2,0.1,0.1,0.05,10\n", 101 + i, ra, dec);
    }
    fclose(f);
    ck_assert_int_eq(wf_test_run("%s expose --quiet --catalog %s --set readout.ncols=128 --set readout.nrows=128 "
                         "--set readout.ma_table=4 --out %s/out", bin, path, d), 0);
    char truth[4300];
    snprintf(truth, sizeof truth, "%s/out/wfisim_e000001_sca01_truth.fits", d);
    fitsfile *t;
    int status = 0;
    long rows = 0;
    fits_open_table(&t, truth, READONLY, &status);
    fits_movnam_hdu(t, BINARY_TBL, "GALAXIES", 0, &status);
    fits_get_num_rows(t, &rows, &status);
    long long ids[8] = {0};
    if (rows > 0 && rows <= 8) fits_read_col(t, TLONGLONG, 1, 1, 1, rows, NULL, ids, NULL, &status);
    fits_close_file(t, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(rows, 4);
    for (int i = 0; i < 4; i++) ck_assert(ids[i] >= 101 && ids[i] <= 104);
    /* one object's stamp holds at least scene.flux_fraction of its flux */
    ck_assert_int_eq(wf_test_run("%s stamp --quiet --catalog %s --id 103 --out %s/st", bin, path, d), 0);
    char sp[4300];
    snprintf(sp, sizeof sp, "%s/st/stamp_103.fits", d);
    fitsfile *sf;
    long nax[2] = {0, 0};
    double flux = 0;
    fits_open_file(&sf, sp, READONLY, &status);
    fits_get_img_size(sf, 2, nax, &status);
    fits_read_key_dbl(sf, "FLUX", &flux, NULL, &status);
    double *pix = malloc(sizeof(double) * (size_t)(nax[0] * nax[1] + 1));
    long first[2] = {1, 1};
    fits_read_pix(sf, TDOUBLE, first, nax[0] * nax[1], NULL, pix, NULL, &status);
    fits_close_file(sf, &status);
    ck_assert_int_eq(status, 0);
    double sum = 0;
    for (long k = 0; k < nax[0] * nax[1]; k++) sum += pix[k];
    free(pix);
    ck_assert_msg(sum >= 0.995 * flux * (1 - 1e-6) && sum <= flux * (1 + 1e-6), "stamp %.6g of %.6g e-/s", sum, flux);
    /* a missing column is named, with a non-zero exit and no product */
    f = fopen(path, "w");
    fprintf(f, "id,ra,dec,z,mag_Y106\n1,71.0,-53.0,0.5,20\n");
    fclose(f);
    ck_assert_int_ne(wf_test_run("%s expose --quiet --catalog %s --set readout.ncols=64 --set readout.nrows=64 "
                         "--out %s/bad 2>%s/err.txt", bin, path, d, d), 0);
    char err[4300];
    snprintf(err, sizeof err, "%s/err.txt", d);
    size_t n;
    char *msg = wf_test_slurp(err, &n);
    ck_assert_msg(msg && strstr(msg, "gal.csv") && strstr(msg, "column"), "message: %s", msg ? msg : "");
    char bad[4300];
    snprintf(bad, sizeof bad, "%s/bad/" FITS, d);
    ck_assert(!exists(bad));
    /* with two threads the catalog is read while the optics are built: the same message as
     * one thread's, also when the data folder lacks its files too (the first failure in the
     * order one thread meets them; a folder that does not exist is refused with the options) */
    ck_assert_int_eq(wf_test_run("mkdir %s/nodata", d), 0);
    char nodata[4300];
    snprintf(nodata, sizeof nodata, "--set paths.data=%s/nodata", d);
    for (int both = 0; both < 2; both++) {
        char *m[2] = {NULL, NULL};
        for (int th = 1; th <= 2; th++) {
            ck_assert_int_ne(wf_test_run("%s expose --quiet --catalog %s --set readout.ncols=64 --set readout.nrows=64 "
                                         "--threads %d %s --out %s/bad 2>%s/err2.txt", bin, path, th,
                                         both ? nodata : "", d, d), 0);
            snprintf(err, sizeof err, "%s/err2.txt", d);
            m[th - 1] = wf_test_slurp(err, &n);
            ck_assert(!exists(bad));
        }
        ck_assert_msg(m[0] && m[1] && strcmp(m[0], m[1]) == 0, "%s: one thread\n%s\ntwo threads\n%s",
                      both ? "no data folder" : "bad catalog", m[0] ? m[0] : "", m[1] ? m[1] : "");
        if (!both) ck_assert(strcmp(m[0], msg) == 0);
        free(m[0]);
        free(m[1]);
    }
    free(msg);
    /* the data folder alone: the optics' failure is reported, on two threads as on one */
    f = fopen(path, "w");
    fprintf(f, "id,ra,dec,z,mag_Y106,hlr_disk,hlr_bulge,bulge_frac,knot_frac,e1,e2,pa\n1,71.0,-53.0,0.7,21.5,0.4,0.2,0.2,0.1,0.1,0.05,10\n");
    fclose(f);
    char *m1 = NULL;
    for (int th = 1; th <= 2; th++) {
        ck_assert_int_ne(wf_test_run("%s expose --quiet --catalog %s --set readout.ncols=64 --set readout.nrows=64 "
                                     "--threads %d %s --out %s/bad 2>%s/err3.txt",
                                     bin, path, th, nodata, d, d), 0);
        snprintf(err, sizeof err, "%s/err3.txt", d);
        char *m = wf_test_slurp(err, &n);
        ck_assert_msg(m && strstr(m, "nodata/roman/"), "threads %d: message %s", th, m ? m : "");
        if (th == 1) m1 = m;
        else {
            ck_assert_msg(strcmp(m, m1) == 0, "two threads: %s against %s", m, m1);
            free(m);
        }
        ck_assert(!exists(bad));
    }
    free(m1);
}
END_TEST

/* A product's SCI and ERR: nc x nr, every value finite (ERR > 0); in ramp mode RESULTANTS is
 * nres x nr x nc; every HDU's checksum verifies. SCI and ERR^2 are summed into sum, var. */
static void check_product(const char *path, int nc, int nr, int nres, double *sum, double *var, long *n)
{
    fitsfile *f;
    int status = 0, naxis = 0, hdus = 0;
    long nax[3] = {0, 0, 0};
    fits_open_file(&f, path, READONLY, &status);
    ck_assert_msg(status == 0, "%s does not open", path);
    double *sci = malloc((size_t)nc * nr * sizeof *sci), *err = malloc((size_t)nc * nr * sizeof *err);
    long first[3] = {1, 1, 1};
    const char *names[2] = {"SCI", "ERR"};
    double *vals[2] = {sci, err};
    for (int k = 0; k < 2; k++) {
        fits_movnam_hdu(f, IMAGE_HDU, (char *)names[k], 0, &status);
        fits_get_img_dim(f, &naxis, &status);
        fits_get_img_size(f, 2, nax, &status);
        ck_assert_msg(status == 0 && naxis == 2 && nax[0] == nc && nax[1] == nr, "%d x %d: %s is %ld x %ld (NAXIS %d)",
                      nc, nr, names[k], nax[0], nax[1], naxis);
        fits_read_pix(f, TDOUBLE, first, (long long)nc * nr, NULL, vals[k], NULL, &status);
    }
    ck_assert_int_eq(status, 0);
    for (long i = 0; i < (long)nc * nr; i++) {
        ck_assert_msg(isfinite(sci[i]) && isfinite(err[i]) && err[i] > 0, "%d x %d: pixel %ld: SCI %g ERR %g", nc, nr, i,
                      sci[i], err[i]);
        *sum += sci[i];
        *var += err[i] * err[i];
    }
    *n += (long)nc * nr;
    if (nres) {
        fits_movnam_hdu(f, IMAGE_HDU, "RESULTANTS", 0, &status);
        fits_get_img_dim(f, &naxis, &status);
        fits_get_img_size(f, 3, nax, &status);
        ck_assert_msg(status == 0 && naxis == 3 && nax[0] == nc && nax[1] == nr && nax[2] == nres,
                      "%d x %d: RESULTANTS is %ld x %ld x %ld", nc, nr, nax[0], nax[1], nax[2]);
    }
    fits_get_num_hdus(f, &hdus, &status);
    for (int h = 1; h <= hdus; h++) {
        int dataok = 0, hduok = 0;
        fits_movabs_hdu(f, h, NULL, &status);
        fits_verify_chksum(f, &dataok, &hduok, &status);
        ck_assert_msg(status == 0 && dataok == 1 && hduok == 1, "%d x %d: HDU %d checksum", nc, nr, h);
    }
    fits_close_file(f, &status);
    free(sci);
    free(err);
}

/* Every detector size of the documented range works (readout.ncols, readout.nrows 1..4088):
 * each of 1..16 x 1..16 and odd shapes, in both modes, through the same expose -> assemble
 * path as `wfisim expose` (in-process here, for speed), gives a product of its shape with
 * finite SCI. (The META text was once written into a tile buffer, so a 1 x 1 detector
 * could not describe itself.) The flat sky (IPC off: every pixel of a tiny detector is an
 * edge; nonlinearity off: the single-frame SCI is not linearised) is recovered without bias
 * over all of them, within 5 sigma of the products' own ERR. */
static void shapes_in_mode(const char *mode)
{
    const char *d = wf_test_tmpdir();
    double sky = 5.0, sum = 0, var = 0;
    long n = 0;
    int shapes[256 + 6][2], ns = 0;
    for (int nc = 1; nc <= 16; nc++)
        for (int nr = 1; nr <= 16; nr++) shapes[ns][0] = nc, shapes[ns++][1] = nr;
    const int odd[6][2] = {{1, 300}, {300, 1}, {17, 3}, {3, 17}, {257, 2}, {2, 129}};
    for (int k = 0; k < 6; k++) shapes[ns][0] = odd[k][0], shapes[ns++][1] = odd[k][1];
    for (int k = 0; k < ns; k++) {
        int nc = shapes[k][0], nr = shapes[k][1];
        wf_config cfg;
        wf_clock clock;
        wf_config_defaults(&cfg);
        char set[13][128];
        snprintf(set[0], sizeof set[0], "readout.ncols=%d", nc);
        snprintf(set[1], sizeof set[1], "readout.nrows=%d", nr);
        snprintf(set[2], sizeof set[2], "exposure.mode=%s", mode);
        snprintf(set[3], sizeof set[3], "run.out=%s/p", d);
        snprintf(set[4], sizeof set[4], "scene.sky_rate=%g", sky);
        snprintf(set[5], sizeof set[5], "scene.kind=grid");
        snprintf(set[6], sizeof set[6], "scene.grid.flux=0");
        snprintf(set[7], sizeof set[7], "detector.effects.ipc=false");
        snprintf(set[8], sizeof set[8], "detector.effects.cosmic_rays=false");
        snprintf(set[9], sizeof set[9], "run.quiet=true");
        snprintf(set[12], sizeof set[12], "run.uncached_writes=false");
        /* noise is keyed by pixel position: another seed per shape, or pixel (0, 0) would be
         * the same draw in all of them */
        snprintf(set[10], sizeof set[10], "seed=%d", k + 1);
        /* the single-frame SCI is not linearised (ramp fits are): off, for a bias of 0 */
        snprintf(set[11], sizeof set[11], "detector.effects.nonlinearity=false");
        for (int i = 0; i < 13; i++) ck_assert_int_eq(wf_config_set(&cfg, set[i], "test"), WF_OK);
        ck_assert_int_eq(wf_config_finish(&cfg, &clock), WF_OK);
        wf_pipeline_job job;
        memset(&job, 0, sizeof job);
        job.cfg = &cfg;
        job.clock = &clock;
        job.version = "test";
        wf_status st = wf_pipeline_expose(&job);
        ck_assert_msg(st == WF_OK, "%s %d x %d: %s", mode, nc, nr, wf_error_message());
        check_product(job.image_path, nc, nr, strcmp(mode, "ramp") ? 0 : clock.ma.nresultants, &sum, &var, &n);
    }
    double mean = sum / n, sigma = sqrt(var) / n;
    double expect = sky * pow(sky, 0.0065 / log(10.0)) + 0.015;
    ck_assert_msg(fabs(mean - expect) < 5.0 * sigma, "%s: mean rate %.5f over %ld pixels, expected %.5f +- %.5f",
                  mode, mean, n, expect, sigma);
}

START_TEST(every_small_shape_single) { shapes_in_mode("single"); }
END_TEST
START_TEST(every_small_shape_ramp) { shapes_in_mode("ramp"); }
END_TEST

/* The same through the program, as the issue ran it: the smallest and thinnest detectors
 * in both modes exit 0 with their product. */
START_TEST(small_shapes_through_the_program)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    const int shapes[5][2] = {{1, 1}, {2, 2}, {8, 8}, {1, 300}, {300, 1}};
    for (int m = 0; m < 2; m++)
        for (int k = 0; k < 5; k++) {
            const char *mode = m ? "ramp" : "single";
            ck_assert_msg(wf_test_run("%s expose --quiet --mode %s --ma-table 4 --set scene.kind=grid --set readout.ncols=%d "
                                      "--set readout.nrows=%d --out %s/%s%d", bin, mode, shapes[k][0], shapes[k][1], d,
                                      mode, k) == 0, "%s %d x %d", mode, shapes[k][0], shapes[k][1]);
            char p[4200];
            double s = 0, v = 0;
            long n = 0;
            snprintf(p, sizeof p, "%s/%s%d/" FITS, d, mode, k);
            check_product(p, shapes[k][0], shapes[k][1], m ? 9 : 0, &s, &v, &n); /* table 4: 9 resultants */
        }
}
END_TEST

/* A run that fails after its output folder was made (here: cosmic rays beyond what a tile
 * can count) leaves no folder behind, neither the one asked for nor the parents it made;
 * a folder that was there before stays. */
START_TEST(failed_run_leaves_no_folder)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
#define DOOMED "--quiet --set scene.kind=grid --set readout.ncols=16 --set readout.nrows=16 --set detector.cr_rate=1e30"
    ck_assert_int_eq(wf_test_run("%s expose " DOOMED " --out %s/new/deeper 2>%s/err.txt", bin, d, d), 2);
    char p[4200];
    snprintf(p, sizeof p, "%s/err.txt", d);
    ck_assert_msg(wf_test_file_contains(p, "cosmic rays"), "the reason is not given");
    snprintf(p, sizeof p, "%s/new", d);
    ck_assert_msg(!exists(p), "%s left behind", p);
    ck_assert_int_eq(wf_test_run("mkdir %s/old && %s expose " DOOMED " --out %s/old/deeper 2>/dev/null", d, bin, d), 2);
    snprintf(p, sizeof p, "%s/old/deeper", d);
    ck_assert_msg(!exists(p), "%s left behind", p);
    snprintf(p, sizeof p, "%s/old", d);
    ck_assert_msg(exists(p), "%s was there before and must stay", p);
    /* the same run that succeeds makes them */
    ck_assert_int_eq(wf_test_run("%s expose --quiet --set scene.kind=grid --set readout.ncols=16 --set readout.nrows=16 "
                                 "--out %s/new/deeper", bin, d), 0);
    snprintf(p, sizeof p, "%s/new/deeper/" FITS, d);
    ck_assert(exists(p));
}
END_TEST

/* --stream FILE is written as FILE.tmp and renamed when whole: a run that fails mid-stream
 * (the file may not grow past 40 blocks: ulimit -f, SIGXFSZ ignored, so a write returns EFBIG
 * as on a full disk) exits non-zero and leaves neither FILE nor FILE.tmp, and an older FILE
 * stays as it was; a stream that is not a regular file (a FIFO read by `assemble`, a
 * character device) is written in place, and the FIFO's product is the one of a file. */
START_TEST(stream_file_whole_or_absent)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char s[4200], tmp[4300], err[4200];
    snprintf(s, sizeof s, "%s/s.bin", d);
    snprintf(tmp, sizeof tmp, "%s.tmp", s);
    snprintf(err, sizeof err, "%s/err.txt", d);
    ck_assert_int_eq(wf_test_run("%s expose " SMALL " --stream %s", bin, s), 0);
    ck_assert(exists(s) && !exists(tmp));
    size_t n0, n1;
    char *good = wf_test_slurp(s, &n0);
    ck_assert_msg(n0 > 41 * 1024, "the stream (%zu bytes) must be larger than the limit", n0);
    ck_assert_int_ne(wf_test_run("sh -c \"trap '' XFSZ; ulimit -f 40; exec %s expose " SMALL " --seed 2 --stream %s 2>%s\"",
                                 bin, s, err), 0);
    ck_assert_msg(wf_test_file_contains(err, "File too large"), "the reason is not reported");
    ck_assert_msg(!exists(tmp), "%s left behind", tmp);
    char *after = wf_test_slurp(s, &n1);
    ck_assert_msg(after && n1 == n0 && !memcmp(after, good, n0), "the older stream was changed");
    free(after);
    unlink(s);
    ck_assert_int_ne(wf_test_run("sh -c \"trap '' XFSZ; ulimit -f 40; exec %s expose " SMALL " --stream %s 2>/dev/null\"",
                                 bin, s), 0);
    ck_assert_msg(!exists(s) && !exists(tmp), "a truncated stream is left behind");
    /* not regular files: written in place */
    ck_assert_int_eq(wf_test_run("%s expose " SMALL " --stream /dev/null", bin), 0);
    struct stat sb;
    ck_assert(stat("/dev/null", &sb) == 0 && S_ISCHR(sb.st_mode));
    ck_assert(!exists("/dev/null.tmp"));
    ck_assert_int_eq(wf_test_run("mkfifo %s/fifo && { %s assemble %s/fifo --quiet --out %s/viafifo & "
                                 "%s expose " SMALL " --stream %s/fifo; e=$?; wait $! && [ $e -eq 0 ]; }",
                                 d, bin, d, d, bin, d), 0);
    FILE *f = fopen(s, "wb");
    ck_assert(f && fwrite(good, 1, n0, f) == n0 && fclose(f) == 0);
    ck_assert_int_eq(wf_test_run("%s assemble %s --quiet --out %s/viafile", bin, s, d), 0);
    char a[4200], b[4200];
    snprintf(a, sizeof a, "%s/viafifo/" FITS, d);
    snprintf(b, sizeof b, "%s/viafile/" FITS, d);
    wf_test_assert_same_file(a, b);
    free(good);
}
END_TEST

/* One reading of filter names and of --data for every command: expose takes W149 as W146
 * (as sn, psf and survey plan do) and writes W146; --data must name a folder even when the
 * scene reads nothing from it (the grid scene), for expose, psf, sn and survey plan alike. */
START_TEST(filter_alias_and_data_folder)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    ck_assert_int_eq(wf_test_run("%s expose --quiet --set scene.kind=grid --set readout.ncols=8 --set readout.nrows=8 "
                                 "--filter w149 --out %s/w", bin, d), 0);
    char p[4200], filter[FLEN_VALUE] = "";
    snprintf(p, sizeof p, "%s/w/" FITS, d);
    fitsfile *f;
    int status = 0;
    fits_open_file(&f, p, READONLY, &status);
    fits_read_key_str(f, "FILTER", filter, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_str_eq(filter, "W146");
    char file[4200], err[4200];
    snprintf(file, sizeof file, "%s/afile", d);
    snprintf(err, sizeof err, "%s/err.txt", d);
    FILE *fp = fopen(file, "w");
    fputs("not a folder\n", fp);
    fclose(fp);
    const char *cmds[] = {"expose --quiet --set scene.kind=grid --set readout.ncols=8 --set readout.nrows=8 --out %s/x",
                          "psf --filter Y106 --sca 1 --out %s/x.fits",
                          "sn lightcurve --z 0.5 --t0 61000 --band Y106 --mjd 61000 --model %s",
                          "survey plan --quiet --out %s/plan.fits"};
    for (int k = 0; k < 4; k++) {
        char cmd[4400];
        snprintf(cmd, sizeof cmd, cmds[k], d);
        ck_assert_msg(wf_test_run("%s %s --data %s 2>%s", bin, cmd, file, err) == 2, "%s accepts a file as --data", cmd);
        ck_assert_msg(wf_test_file_contains(err, "is not a directory"), "%s: no reason given", cmd);
    }
    snprintf(p, sizeof p, "%s/x", d);
    ck_assert(!exists(p));
}
END_TEST

static long table_rows(const char *path, const char *ext)
{
    fitsfile *t;
    int status = 0;
    long rows = -1;
    fits_open_file(&t, path, READONLY, &status);
    fits_movnam_hdu(t, BINARY_TBL, (char *)ext, 0, &status);
    fits_get_num_rows(t, &rows, &status);
    fits_close_file(t, &status);
    ck_assert_msg(status == 0, "%s: no table %s", path, ext);
    return rows;
}

/* `--catalog FILE` with a file in GalSim's benchmark-scene format (gzip'd, a type column, no
 * redshift) is recognised by its columns and drawn as `scene.kind=galsim` draws it: the same
 * image and truth, byte for byte. Then GalSim's own scene file, where ../shared has it. */
START_TEST(galsim_scene_recognised_by_its_columns)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    wf_wcs w;
    demo_wcs(&w);
    char path[4200];
    snprintf(path, sizeof path, "%s/scene.csv.gz", d);
    gzFile gz = gzopen(path, "wb");
    ck_assert_ptr_nonnull(gz);
    gzprintf(gz, "id,type,ra_deg,dec_deg,mag_Y106,hlr_disk_arcsec,hlr_bulge_arcsec,bulge_frac,knot_frac_of_disk,"
                 "knot_seed,e1,e2,x_sca1,y_sca1\n");
    /* three galaxies, a star and an SN on a 128 x 128 corner of SCA 1, a galaxy far off it */
    const double px[6] = {20, 60, 100, 64, 90, 3000}, py[6] = {30, 90, 110, 20, 64, 3000};
    const char *type[6] = {"gal", "gal", "gal", "star", "sn", "gal"};
    for (int i = 0; i < 6; i++) {
        double ra, dec;
        wf_wcs_pix2world(&w, px[i], py[i], &ra, &dec);
        int gal = !strcmp(type[i], "gal");
        gzprintf(gz, "%d,%s,%.10f,%.10f,%.2f,%s,%s,%s,%s,%d,%s,%s,%.4f,%.4f\n", 10 + i, type[i], ra, dec,
                 gal ? 21.5 + 0.5 * i : 19.0, gal ? "0.4" : "0", gal ? "0.2" : "0", gal ? "0.3" : "0",
                 gal ? "0.1" : "0", 1000 + i, gal ? "0.1" : "0", gal ? "-0.05" : "0", px[i] + 1, py[i] + 1);
    }
    ck_assert_int_eq(gzclose(gz), Z_OK);
    const char *small = "--quiet --set readout.ncols=128 --set readout.nrows=128 --set readout.ma_table=4";
    ck_assert_int_eq(wf_test_run("%s expose %s --catalog %s --out %s/a", bin, small, path, d), 0);
    ck_assert_int_eq(wf_test_run("%s expose %s --set scene.kind=galsim --set scene.catalog=%s --out %s/b", bin,
                                 small, path, d), 0);
    char a[4300], b[4300];
    snprintf(a, sizeof a, "%s/a/" FITS, d);
    snprintf(b, sizeof b, "%s/b/" FITS, d);
    wf_test_assert_same_file(a, b);
    snprintf(a, sizeof a, "%s/a/wfisim_e000001_sca01_truth.fits", d);
    snprintf(b, sizeof b, "%s/b/wfisim_e000001_sca01_truth.fits", d);
    wf_test_assert_same_file(a, b);
    ck_assert_int_eq(table_rows(a, "GALAXIES"), 3); /* what was drawn: the corner's galaxies */
    ck_assert_int_eq(table_rows(a, "STARS"), 1);
    ck_assert_int_eq(table_rows(a, "SNE"), 1);
    /* a GalSim scene holds its own stars: a star file beside it is refused, not ignored */
    ck_assert_int_ne(wf_test_run("%s expose %s --catalog %s --stars %s --out %s/c 2>/dev/null", bin, small, path,
                                 path, d), 0);
    snprintf(a, sizeof a, "%s/c/" FITS, d);
    ck_assert(!exists(a));

    const char *ref = wf_test_reference_dir();
    if (!ref) WF_SKIP("GalSim reference not found: its scene file not drawn");
    snprintf(path, sizeof path, "%s/scene_catalog_sca1_pointingA.csv.gz", ref);
    const char *corner = "--quiet --mode single --set readout.ncols=1024 --set readout.nrows=1024";
    ck_assert_int_eq(wf_test_run("%s expose %s --catalog %s --out %s/ra", bin, corner, path, d), 0);
    ck_assert_int_eq(wf_test_run("%s expose %s --set scene.kind=galsim --set scene.catalog=%s --out %s/rb", bin,
                                 corner, path, d), 0);
    snprintf(a, sizeof a, "%s/ra/" FITS, d);
    snprintf(b, sizeof b, "%s/rb/" FITS, d);
    wf_test_assert_same_file(a, b);
    snprintf(a, sizeof a, "%s/ra/wfisim_e000001_sca01_truth.fits", d);
    snprintf(b, sizeof b, "%s/rb/wfisim_e000001_sca01_truth.fits", d);
    wf_test_assert_same_file(a, b);
    long ng = table_rows(a, "GALAXIES");
    /* the corner is 1/16 of the SCA, which holds the scene's 8400 galaxies: ~525 */
    ck_assert_msg(ng > 400 && ng < 700, "%ld galaxies drawn on a 1024 x 1024 corner", ng);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("program");
    TCase *tc = tcase_create("program");
    tcase_set_timeout(tc, 600);
    tcase_add_test(tc, pipe_equals_in_process);
    tcase_add_test(tc, tile_height_and_threads_do_not_matter);
    tcase_add_test(tc, bad_config_named_and_no_product);
    tcase_add_test(tc, corrupt_stream_leaves_nothing);
    tcase_add_test(tc, assembler_failure_reported);
    tcase_add_test(tc, fits_opens_in_astropy);
    tcase_add_test(tc, flat_sky_ramp);
    tcase_add_test(tc, flat_sky_ramp_bright);
    tcase_add_test(tc, flat_sky_single);
    tcase_add_test(tc, object_scene_deterministic);
    tcase_add_test(tc, thin_subarray);
    tcase_add_test(tc, catalog_file_on_the_command_line);
    tcase_add_test(tc, galsim_scene_recognised_by_its_columns);
    suite_add_tcase(s, tc);
    TCase *sh = tcase_create("edges"); /* CK_RUN_CASE=edges runs these alone */
    tcase_set_timeout(sh, 600);
    tcase_add_test(sh, every_small_shape_single);
    tcase_add_test(sh, every_small_shape_ramp);
    tcase_add_test(sh, small_shapes_through_the_program);
    tcase_add_test(sh, failed_run_leaves_no_folder);
    tcase_add_test(sh, stream_file_whole_or_absent);
    tcase_add_test(sh, filter_alias_and_data_folder);
    suite_add_tcase(s, sh);
    return s;
}

int main(void) { return wf_test_main(suite()); }
