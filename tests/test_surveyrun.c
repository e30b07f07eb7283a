/* `wfisim survey run` end to end on a one-visit plan and a small SCA: each product carries its
 * plan row's pointing, filter, time and read pattern; a second run skips what verifies and
 * redoes what is damaged (data, or a header cfitsio cannot parse), byte for byte; a product
 * does not depend on which others were run. */
#include <fitsio.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "sim/fitsout.h"
#include "tests/testutil.h"
#include "tools/surveyrun.h"

#define SMALL "--set readout.ncols=128 --set readout.nrows=96 --set detector.cr_rate=0"

static void assert_same_file(const char *a, const char *b)
{
    size_t la, lb;
    char *x = wf_test_slurp(a, &la), *y = wf_test_slurp(b, &lb);
    ck_assert_msg(x && y, "%s or %s missing", a, b);
    ck_assert_msg(la == lb && !memcmp(x, y, la), "%s and %s differ", a, b);
    free(x);
    free(y);
}

/* The plan row of an EXPID, read independently of the program's reader. */
static void plan_row(const char *plan, int expid, double *ra, double *pa, double *mjd, double *exptime, char *filter)
{
    fitsfile *f;
    int status = 0, c;
    fits_open_file(&f, plan, READONLY, &status);
    fits_movnam_hdu(f, BINARY_TBL, "PLAN", 0, &status);
    long row = expid + 1; /* the plan lists exposures in EXPID order from 0 */
    int id = -1;
    fits_get_colnum(f, CASEINSEN, "EXPID", &c, &status);
    fits_read_col(f, TINT, c, row, 1, 1, NULL, &id, NULL, &status);
    ck_assert_int_eq(id, expid);
    fits_get_colnum(f, CASEINSEN, "RA", &c, &status);
    fits_read_col(f, TDOUBLE, c, row, 1, 1, NULL, ra, NULL, &status);
    fits_get_colnum(f, CASEINSEN, "PA", &c, &status);
    fits_read_col(f, TDOUBLE, c, row, 1, 1, NULL, pa, NULL, &status);
    fits_get_colnum(f, CASEINSEN, "MJD_MID", &c, &status);
    fits_read_col(f, TDOUBLE, c, row, 1, 1, NULL, mjd, NULL, &status);
    fits_get_colnum(f, CASEINSEN, "EXPTIME", &c, &status);
    fits_read_col(f, TDOUBLE, c, row, 1, 1, NULL, exptime, NULL, &status);
    fits_get_colnum(f, CASEINSEN, "FILTER", &c, &status);
    char *fp = filter;
    fits_read_col(f, TSTRING, c, row, 1, 1, NULL, &fp, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

static void header(const char *path, const char *key, char *value)
{
    fitsfile *f;
    int status = 0;
    fits_open_file(&f, path, READONLY, &status);
    fits_read_keyword(f, key, value, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_msg(status == 0, "%s: no %s", path, key);
}

START_TEST(run_resume_and_independence)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    ck_assert_int_eq(wf_test_run("%s survey plan --quiet --set survey.visits=1 --out %s/plan.fits", bin, d), 0);
    /* exposures 15 and 16: the last Y106 pointing of the snake and the first J129 */
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s/plan.fits --exposures 15:16 --scas 3,7 " SMALL
                         " --out %s/a", bin, d, d), 0);
    const int ids[2] = {15, 16}, scas[2] = {3, 7};
    char plan[4200];
    snprintf(plan, sizeof plan, "%s/plan.fits", d);
    for (int i = 0; i < 2; i++)
        for (int k = 0; k < 2; k++) {
            char img[4200], truth[4200], v[FLEN_VALUE];
            snprintf(img, sizeof img, "%s/a/wfisim_e%06d_sca%02d.fits", d, ids[i], scas[k]);
            snprintf(truth, sizeof truth, "%s/a/wfisim_e%06d_sca%02d_truth.fits", d, ids[i], scas[k]);
            ck_assert_msg(wf_survey_product_ok(img), "%s does not verify", img);
            ck_assert_msg(wf_survey_product_ok(truth), "%s does not verify", truth);
            double ra, pa, mjd, exptime;
            char filter[16];
            plan_row(plan, ids[i], &ra, &pa, &mjd, &exptime, filter);
            header(img, "RA_PNT", v);
            ck_assert_double_eq_tol(atof(v), ra, 1e-9);
            header(img, "PA_PNT", v);
            ck_assert_double_eq_tol(atof(v), pa, 1e-9);
            header(img, "MJD-OBS", v);
            ck_assert_double_eq_tol(atof(v), mjd, 1e-7);
            header(img, "FILTER", v);
            ck_assert_msg(strstr(v, filter) != NULL, "FILTER %s, plan says %s", v, filter);
            /* the planned time travels with the product; 300 s takes Rev F table 6 (~294 s), the
             * nearest of 4 (139 s), 6 and 11 (977 s) */
            header(img, "PLANEXPT", v);
            ck_assert_double_eq_tol(atof(v), exptime, 1e-6);
            ck_assert_double_eq_tol(exptime, 300.0, 1e-9);
            header(img, "MA_TABLE", v);
            ck_assert_msg(atoi(v + (v[0] == '\'')) == 6, "MA table %s for a 300 s exposure", v);
        }
    /* survey products are tile-compressed by default (products.compress auto), RESULTANTS kept */
    {
        char img[4200];
        snprintf(img, sizeof img, "%s/a/wfisim_e000015_sca03.fits", d);
        fitsfile *f;
        int status = 0, nhdu = 0, compressed[4];
        fits_open_file(&f, img, READONLY, &status);
        fits_get_num_hdus(f, &nhdu, &status);
        for (int h = 0; h < 4; h++) {
            fits_movabs_hdu(f, h + 2, NULL, &status);
            compressed[h] = fits_is_compressed_image(f, &status);
        }
        fits_close_file(f, &status);
        ck_assert_int_eq(status, 0);
        ck_assert_int_eq(nhdu, 6);
        ck_assert_msg(compressed[0] && compressed[1] && compressed[2] && compressed[3], "%s: image HDUs not compressed", img);
    }
    /* again: everything verifies, nothing is rendered */
    char log[4200];
    snprintf(log, sizeof log, "%s/log2", d);
    ck_assert_int_eq(wf_test_run("%s survey run --plan %s --exposures 15:16 --scas 3,7 " SMALL " --out %s/a 2>%s",
                         bin, plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "0 products rendered") && wf_test_file_contains(log, "4 already done"), "second run redid work");
    /* damage one image's data: it is redone, to the same bytes */
    char img[4200], keep[4200];
    snprintf(img, sizeof img, "%s/a/wfisim_e000016_sca07.fits", d);
    snprintf(keep, sizeof keep, "%s/keep.fits", d);
    ck_assert_int_eq(wf_test_run("cp %s %s", img, keep), 0);
    FILE *f = fopen(img, "r+b");
    ck_assert_ptr_nonnull(f);
    fseek(f, -3000, SEEK_END);
    int ch = fgetc(f);
    fseek(f, -3000, SEEK_END);
    fputc(ch ^ 0x5a, f);
    fclose(f);
    ck_assert(!wf_survey_product_ok(img));
    snprintf(log, sizeof log, "%s/log3", d);
    ck_assert_int_eq(wf_test_run("%s survey run --plan %s --exposures 15:16 --scas 3,7 " SMALL " --out %s/a 2>%s",
                         bin, plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "1 products rendered (1 replacing damaged ones), 3 already done"), "damage not redone");
    assert_same_file(img, keep);
    /* the second section's header of another image no longer parses: cfitsio then sees one
     * section whose checksums verify, but the file is not whole */
    snprintf(img, sizeof img, "%s/a/wfisim_e000015_sca03.fits", d);
    ck_assert_msg(wf_fits_verify_checksums(img, 0) == WF_OK, "%s", wf_error_message());
    char keep15[4200];
    snprintf(keep15, sizeof keep15, "%s/keep15.fits", d);
    ck_assert_int_eq(wf_test_run("cp %s %s", img, keep15), 0);
    f = fopen(img, "r+b");
    ck_assert_ptr_nonnull(f);
    char card[9];
    ck_assert(fseek(f, 2880, SEEK_SET) == 0);
    while (fread(card, 1, 9, f) == 9 && memcmp(card, "XTENSION=", 9)) fseek(f, 2880 - 9, SEEK_CUR);
    ck_assert_msg(!memcmp(card, "XTENSION=", 9), "%s has no second section", img);
    fseek(f, -9, SEEK_CUR);
    fputs("XTENSIOM=", f);
    fclose(f);
    ck_assert_int_eq(wf_fits_verify_checksums(img, 0), WF_ERR_CORRUPT);
    ck_assert_msg(strstr(wf_error_message(), "trailing bytes after section 1: damaged or truncated"), "%s",
                  wf_error_message());
    /* ... so the resume redoes it, to the same bytes */
    ck_assert(!wf_survey_product_ok(img));
    snprintf(log, sizeof log, "%s/log4", d);
    ck_assert_int_eq(wf_test_run("%s survey run --plan %s --exposures 15:16 --scas 3,7 " SMALL " --out %s/a 2>%s",
                         bin, plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "1 products rendered (1 replacing damaged ones), 3 already done"),
                  "damaged header not redone");
    assert_same_file(img, keep15);
    /* the survey-level record names the plan, its checksum, the seed and the catalogs */
    char man[4200];
    snprintf(man, sizeof man, "%s/a/survey_run.txt", d);
    ck_assert(wf_test_file_contains(man, plan) && wf_test_file_contains(man, "plan.datasum = ") &&
              wf_test_file_contains(man, "synthetic field of seed 1") && wf_test_file_contains(man, "exposures = 15:16"));
    /* one product alone, in a fresh folder: the same bytes as in the range run */
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s --exposures 16 --scas 7 " SMALL " --out %s/b", bin, plan,
                         d), 0);
    char alone[4200];
    snprintf(alone, sizeof alone, "%s/b/wfisim_e000016_sca07.fits", d);
    assert_same_file(alone, keep);
    /* products.resultants drop, uncompressed: SCI, ERR, DQ, COSMICRAYS, the truth beside */
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s --exposures 16 --scas 7 " SMALL
                                 " --set products.compress=none --set products.resultants=drop --out %s/c",
                                 bin, plan, d), 0);
    snprintf(alone, sizeof alone, "%s/c/wfisim_e000016_sca07.fits", d);
    ck_assert_msg(wf_survey_product_ok(alone), "%s", wf_error_message());
    fitsfile *f2;
    int status = 0, nhdu = 0;
    fits_open_file(&f2, alone, READONLY, &status);
    fits_get_num_hdus(f2, &nhdu, &status);
    fits_movnam_hdu(f2, ANY_HDU, "SCI", 0, &status);
    ck_assert_int_eq(fits_is_compressed_image(f2, &status), 0);
    fits_movnam_hdu(f2, ANY_HDU, "RESULTANTS", 0, &status);
    ck_assert_int_eq(status, BAD_HDU_NUM);
    status = 0;
    fits_close_file(f2, &status);
    ck_assert_int_eq(nhdu, 5);
    snprintf(alone, sizeof alone, "%s/c/wfisim_e000016_sca07_truth.fits", d);
    ck_assert(wf_survey_product_ok(alone));
}
END_TEST

/* Six small single-frame items: exposures 15 (Y106) and 16 (J129) at one pointing, 17 at the
 * next, SCAs 3 and 7 (about 0.45 deg apart). */
#define SIX "--exposures 15:17 --scas 3,7 " SMALL " --mode single"

static const int six_ids[3] = {15, 16, 17}, six_scas[2] = {3, 7};

static void product_path(char *buf, size_t cap, const char *dir, int expid, int sca, int truth)
{
    snprintf(buf, cap, "%s/wfisim_e%06d_sca%02d%s.fits", dir, expid, sca, truth ? "_truth" : "");
}

static int exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

/* The sky position of FITS pixel (x, y) of an image's SCI section through its header's linear
 * TAN part (CRVAL, CRPIX, CD; the SIP terms move positions by < 0.015 pixel): the test's own
 * inverse gnomonic projection. */
static void sci_pixel_to_sky(const char *path, double x, double y, double *ra, double *dec)
{
    fitsfile *f;
    int status = 0;
    double v[8];
    const char *keys[8] = {"CRVAL1", "CRVAL2", "CRPIX1", "CRPIX2", "CD1_1", "CD1_2", "CD2_1", "CD2_2"};
    fits_open_file(&f, path, READONLY, &status);
    fits_movnam_hdu(f, IMAGE_HDU, "SCI", 0, &status);
    for (int k = 0; k < 8; k++) fits_read_key_dbl(f, keys[k], &v[k], NULL, &status);
    fits_close_file(f, &status);
    ck_assert_msg(status == 0, "%s: no linear WCS", path);
    const double r = M_PI / 180.0;
    double xi = (v[4] * (x - v[2]) + v[5] * (y - v[3])) * r, eta = (v[6] * (x - v[2]) + v[7] * (y - v[3])) * r;
    double a0 = v[0] * r, d0 = v[1] * r, den = cos(d0) - eta * sin(d0);
    *ra = fmod((a0 + atan2(xi, den)) / r + 360.0, 360.0);
    *dec = atan2(sin(d0) + eta * cos(d0), hypot(xi, den)) / r;
}

static double sky_distance(double ra1, double dec1, double ra2, double dec2)
{
    const double r = M_PI / 180.0;
    double s = sin((dec2 - dec1) * r / 2), t = sin((ra2 - ra1) * r / 2);
    return 2 * asin(sqrt(s * s + cos(dec1 * r) * cos(dec2 * r) * t * t)) / r;
}

START_TEST(index_and_area)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char plan[4200], a[4200], path[4300], keep[4300];
    snprintf(plan, sizeof plan, "%s/plan.fits", d);
    snprintf(a, sizeof a, "%s/a", d);
    ck_assert_int_eq(wf_test_run("%s survey plan --quiet --set survey.visits=1 --out %s", bin, plan), 0);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s " SIX " --out %s", bin, plan, a), 0);
    /* the index: one row per product in (exposure, SCA) order, with the plan's filter and time */
    snprintf(path, sizeof path, "%s/survey_index.csv", a);
    FILE *f = fopen(path, "r");
    ck_assert_ptr_nonnull(f);
    char line[1024];
    ck_assert_ptr_nonnull(fgets(line, sizeof line, f));
    ck_assert_msg(!strncmp(line, "expid,sca,filter,mjd_mid,", 25), "index header: %s", line);
    int rows = 0;
    while (fgets(line, sizeof line, f)) {
        int expid, sca;
        char filter[16], file[64], planfilter[16];
        double mjd, ra, pa, pmjd, exptime;
        ck_assert_int_eq(sscanf(line, "%d,%d,%15[^,],%lf", &expid, &sca, filter, &mjd), 4);
        ck_assert_int_eq(expid, six_ids[rows / 2]);
        ck_assert_int_eq(sca, six_scas[rows % 2]);
        plan_row(plan, expid, &ra, &pa, &pmjd, &exptime, planfilter);
        ck_assert_str_eq(filter, planfilter);
        ck_assert_double_eq_tol(mjd, pmjd, 1e-8);
        snprintf(file, sizeof file, "wfisim_e%06d_sca%02d.fits,", expid, sca);
        ck_assert_msg(strstr(line, file) != NULL, "row %d names no %s", rows, file);
        rows++;
    }
    fclose(f);
    ck_assert_int_eq(rows, 6);
    snprintf(path, sizeof path, "%s/survey_index.fits", a);
    ck_assert_msg(wf_fits_verify_checksums(path, 2) == WF_OK, "%s", wf_error_message());
    /* rebuilt from the products' headers alone: the same bytes */
    snprintf(keep, sizeof keep, "%s/index.csv", d);
    ck_assert_int_eq(wf_test_run("cp %s/survey_index.csv %s && rm %s/survey_index.* && %s survey index %s >/dev/null",
                                 a, keep, a, bin, a), 0);
    snprintf(path, sizeof path, "%s/survey_index.csv", a);
    assert_same_file(path, keep);
    /* --area: a 0.01 deg circle about the centre of exposure 15's SCA 3 (128 x 96 pixels, 0.0024 deg
     * from centre to corner) takes that SCA at that pointing, in both filters, and nothing else */
    double ra0, dec0;
    product_path(path, sizeof path, a, 15, 3, 0);
    sci_pixel_to_sky(path, 64.5, 48.5, &ra0, &dec0);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s " SIX " --area %.8f,%.8f,0.01 --out %s/c", bin, plan,
                                 ra0, dec0, d), 0);
    char c[4200];
    snprintf(c, sizeof c, "%s/c", d);
    int outside = 0;
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 2; k++) {
            double ra, dec;
            product_path(path, sizeof path, a, six_ids[i], six_scas[k], 0);
            sci_pixel_to_sky(path, 64.5, 48.5, &ra, &dec);
            int want = sky_distance(ra, dec, ra0, dec0) < 0.01 + 0.0024;
            product_path(keep, sizeof keep, c, six_ids[i], six_scas[k], 0);
            ck_assert_msg(exists(keep) == want, "%s: made %d, overlaps the area %d", keep, exists(keep), want);
            if (want) assert_same_file(path, keep);
            outside += !want;
        }
    ck_assert_int_eq(outside, 4);
    snprintf(path, sizeof path, "%s/survey_run.txt", c);
    ck_assert(wf_test_file_contains(path, "products.outside_area = 4"));
    /* an area that no SCA reaches is an error, not an empty release */
    snprintf(path, sizeof path, "%s/log", d);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s " SIX " --area %.8f,%.8f,0.01 --out %s/e 2>%s", bin,
                                 plan, ra0 + 5.0, dec0, d, path), 2);
    ck_assert(wf_test_file_contains(path, "--area"));
}
END_TEST

/* bin/wfisim-mpi under mpirun: the same bytes as one process, and a failed item redone alone. */
START_TEST(mpi_matches_one_process)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *mpi = getenv("WFISIM_MPI_BIN");
    if (!mpi || !exists(mpi) || wf_test_run("command -v mpirun >/dev/null 2>&1"))
        WF_SKIP("Open MPI (mpirun) and bin/wfisim-mpi ($WFISIM_MPI_BIN, make MPI=1) not installed");
    /* CI runs as root; leak checking (SAN=1) stops at Open MPI's own allocations */
#define MPIRUN "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 ASAN_OPTIONS=detect_leaks=0 " \
               "mpirun --oversubscribe -np 3"
    const char *d = wf_test_tmpdir();
    char plan[4200], log[4200];
    snprintf(plan, sizeof plan, "%s/plan.fits", d);
    snprintf(log, sizeof log, "%s/log", d);
    ck_assert_int_eq(wf_test_run("%s survey plan --quiet --set survey.visits=1 --out %s", bin, plan), 0);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s " SIX " --out %s/a", bin, plan, d), 0);
    ck_assert_int_eq(wf_test_run(MPIRUN " %s survey run --plan %s " SIX " --out %s/b 2>%s", mpi, plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "6 products rendered"), "MPI run did not make six products");
    char x[4300], y[4300];
    static const char *const run_files[] = {"survey_index.csv", "survey_index.fits", "survey_run.txt"};
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 2; k++)
            for (int t = 0; t < 2; t++) {
                product_path(x, sizeof x, "a", six_ids[i], six_scas[k], t);
                char ax[4400], bx[4400];
                snprintf(ax, sizeof ax, "%s/%s", d, x);
                product_path(y, sizeof y, "b", six_ids[i], six_scas[k], t);
                snprintf(bx, sizeof bx, "%s/%s", d, y);
                assert_same_file(ax, bx);
            }
    for (int k = 0; k < 3; k++) {
        snprintf(x, sizeof x, "%s/a/%s", d, run_files[k]);
        snprintf(y, sizeof y, "%s/b/%s", d, run_files[k]);
        assert_same_file(x, y);
    }
    /* the last item cannot be written (a folder stands at its temporary name): the run fails
     * naming it, the five others are whole; once the obstacle is gone a rerun makes only it */
    ck_assert_int_eq(wf_test_run("mkdir -p %s/c/wfisim_e000017_sca07.fits.tmp/x", d), 0);
    ck_assert_int_ne(wf_test_run(MPIRUN " %s survey run --plan %s " SIX " --out %s/c >%s 2>&1", mpi, plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "exposure 17 SCA 7"), "the failed item is not named");
    char c[4200];
    snprintf(c, sizeof c, "%s/c", d);
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 2; k++) {
            product_path(x, sizeof x, c, six_ids[i], six_scas[k], 0);
            int last = i == 2 && k == 1;
            ck_assert_msg(exists(x) == !last, "%s: exists %d after the failed run", x, exists(x));
            if (!last) ck_assert(wf_survey_product_ok(x));
        }
    ck_assert_int_eq(wf_test_run("rm -r %s/c/wfisim_e000017_sca07.fits.tmp", d), 0);
    ck_assert_int_eq(wf_test_run(MPIRUN " %s survey run --plan %s " SIX " --out %s/c 2>%s", mpi, plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "1 products rendered (0 replacing damaged ones), 5 already done"),
                  "the rerun did not make exactly the missing item");
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 2; k++) {
            char ax[4400];
            product_path(x, sizeof x, "a", six_ids[i], six_scas[k], 0);
            snprintf(ax, sizeof ax, "%s/%s", d, x);
            product_path(y, sizeof y, c, six_ids[i], six_scas[k], 0);
            assert_same_file(ax, y);
        }
    snprintf(x, sizeof x, "%s/a/survey_index.csv", d);
    snprintf(y, sizeof y, "%s/c/survey_index.csv", d);
    assert_same_file(x, y);
#undef MPIRUN
}
END_TEST

START_TEST(bad_arguments)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char log[4200];
    snprintf(log, sizeof log, "%s/log", d);
    ck_assert_int_ne(wf_test_run("%s survey run --quiet --plan %s/missing.fits --out %s/x 2>%s", bin, d, d, log), 0);
    ck_assert(wf_test_file_contains(log, "missing.fits"));
    ck_assert_int_eq(wf_test_run("%s survey plan --quiet --set survey.visits=1 --out %s/plan.fits", bin, d), 0);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s/plan.fits --scas 1,19 --out %s/x 2>%s", bin, d, d, log), 2);
    ck_assert(wf_test_file_contains(log, "--scas"));
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s/plan.fits --exposures 9:3 --out %s/x 2>%s", bin, d, d, log), 2);
    ck_assert(wf_test_file_contains(log, "--exposures"));
    ck_assert_int_ne(wf_test_run("%s survey run --quiet --plan %s/plan.fits --exposures 100000: --out %s/x 2>%s", bin, d, d, log), 0);
    ck_assert(wf_test_file_contains(log, "no exposure in the range"));
}
END_TEST

START_TEST(parse_lists)
{
    int s[WF_NSCA], n;
    ck_assert_int_eq(wf_survey_parse_scas("1,2,5-7", s, &n), 0);
    ck_assert_int_eq(n, 5);
    ck_assert_int_eq(s[4], 7);
    ck_assert_int_ne(wf_survey_parse_scas("3,3", s, &n), 0);
    ck_assert_int_ne(wf_survey_parse_scas("0", s, &n), 0);
    ck_assert_int_ne(wf_survey_parse_scas("2-x", s, &n), 0);
    long a, b;
    ck_assert_int_eq(wf_survey_parse_range("4:9", &a, &b), 0);
    ck_assert(a == 4 && b == 9);
    ck_assert_int_eq(wf_survey_parse_range("4:", &a, &b), 0);
    ck_assert(a == 4 && b == -1);
    ck_assert_int_eq(wf_survey_parse_range("12", &a, &b), 0);
    ck_assert(a == 12 && b == 12);
    ck_assert_int_ne(wf_survey_parse_range("x", &a, &b), 0);
    wf_survey_run_options o;
    memset(&o, 0, sizeof o);
    ck_assert_int_eq(wf_survey_parse_area("-10,-53.5,0.25", &o), 0);
    ck_assert(o.area && o.area_ra == 350.0 && o.area_dec == -53.5 && o.area_radius == 0.25);
    ck_assert_int_ne(wf_survey_parse_area("71,-53", &o), 0);
    ck_assert_int_ne(wf_survey_parse_area("71,-53,0", &o), 0);
    ck_assert_int_ne(wf_survey_parse_area("71,-93,1", &o), 0);
    ck_assert_int_ne(wf_survey_parse_area("71,-53,1x", &o), 0);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("surveyrun");
    TCase *tc = tcase_create("all");
    tcase_set_timeout(tc, 300);
    tcase_add_test(tc, run_resume_and_independence);
    tcase_add_test(tc, bad_arguments);
    tcase_add_test(tc, parse_lists);
    tcase_add_test(tc, index_and_area);
    tcase_add_test(tc, mpi_matches_one_process);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
