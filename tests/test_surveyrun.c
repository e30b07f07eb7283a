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

#include "sim/fits/fitsout.h"
#include "sim/sn/sncat.h"
#include "sim/survey/survey.h"
#include "sim/survey/wcs.h"
#include "tests/testutil.h"
#include "tools/surveyrun.h"

#define SMALL "--set readout.ncols=128 --set readout.nrows=96 --set detector.cr_rate=0"

/* The plan row of an EXPID, read independently of the program's reader. */
/* A one-visit plan at d/plan.fits (plan, cap bytes, its path). */
static void one_visit_plan(const char *bin, const char *d, char *plan, size_t cap)
{
    snprintf(plan, cap, "%s/plan.fits", d);
    ck_assert_int_eq(wf_test_run("%s survey plan --quiet --set survey.visits=1 --out %s", bin, plan), 0);
}

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

/* A string keyword's value without its quotes and trailing blanks. */
static void header_str(const char *path, const char *key, char *value)
{
    char raw[FLEN_VALUE];
    header(path, key, raw);
    ck_assert_msg(raw[0] == '\'', "%s: %s is not a string", path, key);
    size_t n = 0;
    for (const char *p = raw + 1; *p && *p != '\''; p++) value[n++] = *p;
    while (n && value[n - 1] == ' ') n--;
    value[n] = '\0';
}

static long long mtime_ns(const char *path)
{
    struct stat sb;
    ck_assert_msg(stat(path, &sb) == 0, "%s missing", path);
    return (long long)sb.st_mtim.tv_sec * 1000000000LL + sb.st_mtim.tv_nsec;
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
    ck_assert_msg(wf_test_file_contains(log, "1 products rendered (1 replacing damaged ones, 0 made from other inputs), 3 already done"), "damage not redone");
    wf_test_assert_same_file(img, keep);
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
    ck_assert_msg(wf_test_file_contains(log, "1 products rendered (1 replacing damaged ones, 0 made from other inputs), 3 already done"),
                  "damaged header not redone");
    wf_test_assert_same_file(img, keep15);
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
    wf_test_assert_same_file(alone, keep);
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

/* CI runs as root; leak checking (SAN=1) stops at Open MPI's own allocations */
#define MPIRUN "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 ASAN_OPTIONS=detect_leaks=0 " \
               "mpirun --oversubscribe -np 3"

/* bin/wfisim-mpi ($WFISIM_MPI_BIN) when it and mpirun are installed, else NULL. */
static const char *mpi_program(void)
{
    const char *mpi = getenv("WFISIM_MPI_BIN");
    return mpi && exists(mpi) && !wf_test_run("command -v mpirun >/dev/null 2>&1") ? mpi : NULL;
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
    snprintf(a, sizeof a, "%s/a", d);
    one_visit_plan(bin, d, plan, sizeof plan);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s " SIX " --out %s", bin, plan, a), 0);
    /* the index: one row per product in (exposure, SCA) order, with the plan's filter and time */
    snprintf(path, sizeof path, "%s/survey_index.csv", a);
    FILE *f = fopen(path, "r");
    ck_assert_ptr_nonnull(f);
    char line[1024];
    ck_assert_ptr_nonnull(fgets(line, sizeof line, f));
    ck_assert_msg(!strncmp(line, "expid,sca,filter,mjd_mid,", 25) && strstr(line, ",datasum,wfdigest\n"),
                  "index header: %s", line);
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
        /* the last column: the WFDIGEST of the product's header */
        char digest[FLEN_VALUE], tail[80];
        product_path(path, sizeof path, a, expid, sca, 0);
        header_str(path, "WFDIGEST", digest);
        snprintf(tail, sizeof tail, ",%s\n", digest);
        ck_assert_msg(strlen(digest) == 64 && strlen(line) > strlen(tail) &&
                      !strcmp(line + strlen(line) - strlen(tail), tail), "row %d: no WFDIGEST %s", rows, digest);
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
    wf_test_assert_same_file(path, keep);
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
            if (want) wf_test_assert_same_file(path, keep);
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

/* The six products of SIX, the index and the run's record: the same bytes in d/a and d/b. */
static void assert_same_six(const char *d, const char *a, const char *b)
{
    char x[4400], y[4400], name[64];
    static const char *const run_files[] = {"survey_index.csv", "survey_index.fits", "survey_run.txt"};
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 2; k++)
            for (int t = 0; t < 2; t++) {
                product_path(name, sizeof name, ".", six_ids[i], six_scas[k], t);
                snprintf(x, sizeof x, "%s/%s/%s", d, a, name + 2);
                snprintf(y, sizeof y, "%s/%s/%s", d, b, name + 2);
                wf_test_assert_same_file(x, y);
            }
    for (int k = 0; k < 3; k++) {
        snprintf(x, sizeof x, "%s/%s/%s", d, a, run_files[k]);
        snprintf(y, sizeof y, "%s/%s/%s", d, b, run_files[k]);
        wf_test_assert_same_file(x, y);
    }
}

/* bin/wfisim-mpi under mpirun: the same bytes as one process, and a failed item redone alone. */
START_TEST(mpi_matches_one_process)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *mpi = mpi_program();
    if (!mpi) WF_SKIP("Open MPI (mpirun) and bin/wfisim-mpi ($WFISIM_MPI_BIN, make MPI=1) not installed");
    const char *d = wf_test_tmpdir();
    char plan[4200], log[4200];
    snprintf(log, sizeof log, "%s/log", d);
    one_visit_plan(bin, d, plan, sizeof plan);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s " SIX " --out %s/a", bin, plan, d), 0);
    ck_assert_int_eq(wf_test_run(MPIRUN " %s survey run --plan %s " SIX " --out %s/b 2>%s", mpi, plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "6 products rendered"), "MPI run did not make six products");
    assert_same_six(d, "a", "b");
    char x[4300], y[4300];
    /* the last item cannot be written (a folder stands at its temporary name): the run fails
     * naming it, the five others are whole; once the obstacle is gone a rerun makes only it */
    ck_assert_int_eq(wf_test_run("mkdir -p %s/c/wfisim_e000017_sca07.fits.tmp/x", d), 0);
    ck_assert_int_ne(wf_test_run(MPIRUN " %s survey run --plan %s " SIX " --out %s/c >%s 2>&1", mpi, plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "exposure 17 SCA 7"), "the failed item is not named");
    snprintf(x, sizeof x, "%s/c/survey_run.txt", d);
    ck_assert_msg(wf_test_file_contains(x, "status = failed: rank ") &&
                  wf_test_file_contains(x, "product wfisim_e000017_sca07.fits missing\n"),
                  "the record does not say the run failed");
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
    ck_assert_msg(wf_test_file_contains(log, "1 products rendered (0 replacing damaged ones, 0 made from other inputs), "
                                             "5 already done"),
                  "the rerun did not make exactly the missing item");
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 2; k++) {
            char ax[4400];
            product_path(x, sizeof x, "a", six_ids[i], six_scas[k], 0);
            snprintf(ax, sizeof ax, "%s/%s", d, x);
            product_path(y, sizeof y, c, six_ids[i], six_scas[k], 0);
            wf_test_assert_same_file(ax, y);
        }
    snprintf(x, sizeof x, "%s/a/survey_index.csv", d);
    snprintf(y, sizeof y, "%s/c/survey_index.csv", d);
    wf_test_assert_same_file(x, y);
    /* other inputs: rank 0's check refuses before any rank renders, naming the first product
     * in plan order as one process does (once: the other ranks stay silent), nothing written */
    snprintf(x, sizeof x, "%s/b/survey_run.txt", d);
    long long t_run = mtime_ns(x);
    ck_assert_int_eq(wf_test_run(MPIRUN " %s survey run --plan %s " SIX " --seed 2 --out %s/b 2>%s", mpi, plan, d, log),
                     2);
    char *said = wf_test_slurp(log, NULL);
    ck_assert_ptr_nonnull(said);
    int times = 0;
    for (const char *q = said; (q = strstr(q, "wfisim_e000015_sca03.fits was made with seed 1, this run has seed 2; "
                                              "use --on-change redo to remake it (6 products of the run")); q++)
        times++;
    ck_assert_msg(times == 1, "the refusal is said %d times (once expected):\n%.3000s", times, said);
    ck_assert_msg(!strstr(said, "did not start the run"), "the other ranks are not silent:\n%.3000s", said);
    free(said);
    ck_assert(mtime_ns(x) == t_run);
    assert_same_six(d, "a", "b");
    /* --on-change redo: every item remade from the new inputs, the same bytes as one process,
     * the record's digests included */
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s " SIX " --seed 2 --on-change redo --out %s/a", bin, plan,
                                 d), 0);
    ck_assert_int_eq(wf_test_run(MPIRUN " %s survey run --plan %s " SIX " --seed 2 --on-change redo --out %s/b 2>%s", mpi,
                                 plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "6 products rendered (0 replacing damaged ones, 6 made from other inputs)"),
                  "MPI redo did not remake the six");
    assert_same_six(d, "a", "b");
    ck_assert(wf_test_file_contains(x, "seed = 2\n") && wf_test_file_contains(x, "status = complete\n"));
}
END_TEST

/* The products of SIX in d/b (and the index, when index) against d/a: the same bytes, except
 * the item skip (expid, sca), absent when absent is 1. */
static void assert_six_but(const char *d, const char *b, int skip_id, int skip_sca, int absent, int index)
{
    char x[4400], y[4400], name[64];
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 2; k++)
            for (int t = 0; t < 2; t++) {
                product_path(name, sizeof name, ".", six_ids[i], six_scas[k], t);
                snprintf(x, sizeof x, "%s/a/%s", d, name + 2);
                snprintf(y, sizeof y, "%s/%s/%s", d, b, name + 2);
                if (six_ids[i] == skip_id && six_scas[k] == skip_sca)
                    ck_assert_msg(exists(y) == !absent, "%s: exists %d", y, exists(y));
                else wf_test_assert_same_file(x, y);
            }
    static const char *const files[] = {"survey_index.csv", "survey_index.fits"};
    for (int k = 0; k < 2; k++) {
        snprintf(x, sizeof x, "%s/a/%s", d, files[k]);
        snprintf(y, sizeof y, "%s/%s/%s", d, b, files[k]);
        if (index) wf_test_assert_same_file(x, y);
        else ck_assert_msg(!exists(y), "%s written by a run that lost an item", y);
    }
}

/* After a run of SIX into d/b that lost item (expid, sca) alone: the run's exit and messages,
 * the record, the five others the bytes one process makes, no index; then leaves there what
 * a crash mid-write leaves (the item's temporary file, cut short), for the rerun to replace. */
static void check_lost_then_rerun(const char *d, const char *b, const char *log, int expid, int sca, const char *signal)
{
    char x[4400], want[256];
    snprintf(want, sizeof want, "exposure %d SCA %d: its process was killed by %s", expid, sca, signal);
    ck_assert_msg(wf_test_file_contains(log, want), "the crash is not reported: %s", want);
    snprintf(want, sizeof want, "1 of 6 items lost (their process crashed; a rerun makes them): exposure %d SCA %d\n",
             expid, sca);
    char *said = wf_test_slurp(log, NULL);
    ck_assert_ptr_nonnull(said);
    const char *q = strstr(said, want);
    ck_assert_msg(q && !strstr(q + 1, want), "the lost item is not listed once:\n%.3000s", said);
    free(said);
    snprintf(x, sizeof x, "%s/%s/survey_run.txt", d, b);
    snprintf(want, sizeof want, "product wfisim_e%06d_sca%02d.fits missing\n", expid, sca);
    ck_assert_msg(wf_test_file_contains(x, "status = failed: 1 of 6 items lost") && wf_test_file_contains(x, want),
                  "the record does not say what was lost");
    assert_six_but(d, b, expid, sca, 1, 0);
    snprintf(x, sizeof x, "%s/%s/wfisim_e%06d_sca%02d.fits.tmp", d, b, expid, sca);
    FILE *f = fopen(x, "w");
    ck_assert_ptr_nonnull(f);
    fputs("SIMPLE  =                    T / cut short by a crash", f);
    fclose(f);
}

/* --isolate in one process: the item whose process dies is lost alone, the run goes on and
 * fails at the end naming it; a rerun makes it alone. */
START_TEST(isolate_crashed_item_lost_alone)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char plan[4200], log[4200];
    snprintf(log, sizeof log, "%s/log", d);
    one_visit_plan(bin, d, plan, sizeof plan);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s " SIX " --out %s/a", bin, plan, d), 0);
    ck_assert_int_eq(wf_test_run("WFISIM_TEST_CRASH_ITEM=15:3:segv %s survey run --isolate --plan %s " SIX
                                 " --out %s/b 2>%s", bin, plan, d, log), 1);
    check_lost_then_rerun(d, "b", log, 15, 3, "signal 11 (SIGSEGV");
    /* without --isolate the hook is never read: the crash would be the run's own */
    ck_assert_int_eq(wf_test_run("WFISIM_TEST_CRASH_ITEM=15:3 %s survey run --plan %s " SIX " --out %s/b 2>%s", bin,
                                 plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "1 products rendered (0 replacing damaged ones, 0 made from other inputs), "
                                             "5 already done"), "the rerun did not make exactly the lost item");
    assert_six_but(d, "b", 0, 0, 0, 1);
    snprintf(log, sizeof log, "%s/b/wfisim_e000015_sca03.fits.tmp", d);
    ck_assert(!exists(log));
}
END_TEST

/* Under mpirun, an item whose process is killed (the OOM killer's SIGKILL) is lost alone:
 * rank 0 hands out the others, which are the bytes one process makes; the job fails naming
 * it; a rerun makes it alone. */
START_TEST(mpi_crashed_item_lost_alone)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *mpi = mpi_program();
    if (!mpi) WF_SKIP("Open MPI (mpirun) and bin/wfisim-mpi ($WFISIM_MPI_BIN, make MPI=1) not installed");
    const char *d = wf_test_tmpdir();
    char plan[4200], log[4200];
    snprintf(log, sizeof log, "%s/log", d);
    one_visit_plan(bin, d, plan, sizeof plan);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --plan %s " SIX " --out %s/a", bin, plan, d), 0);
    ck_assert_int_ne(wf_test_run("WFISIM_TEST_CRASH_ITEM=16:7 " MPIRUN " %s survey run --plan %s " SIX
                                 " --out %s/b >%s 2>&1", mpi, plan, d, log), 0);
    check_lost_then_rerun(d, "b", log, 16, 7, "signal 9 (SIGKILL");
    ck_assert_msg(wf_test_file_contains(log, "[5/6] "), "the five others were not all made");
    ck_assert_int_eq(wf_test_run(MPIRUN " %s survey run --plan %s " SIX " --out %s/b 2>%s", mpi, plan, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "1 products rendered (0 replacing damaged ones, 0 made from other inputs), "
                                             "5 already done"), "the rerun did not make exactly the lost item");
    assert_six_but(d, "b", 0, 0, 0, 1);
    snprintf(log, sizeof log, "%s/b/wfisim_e000016_sca07.fits.tmp", d);
    ck_assert(!exists(log));
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

/* ---- resume: a product is done only if it was made from the same inputs ---------------- */

/* Products made without a data folder whatever the environment says; small and single frame. */
#define NODATA "env -u WFISIM_DATA "
#define TINY "--mode single --set readout.ncols=128 --set readout.nrows=96 --set detector.cr_rate=0"

/* The first n hex digits of the SHA-256 of text, by the system's sha256sum (independent of
 * the program's own SHA-256). */
static void sha256sum_of(const char *d, const char *text, char *hex, int n)
{
    char in[4200], out[4200];
    snprintf(in, sizeof in, "%s/sha_in", d);
    snprintf(out, sizeof out, "%s/sha_out", d);
    FILE *f = fopen(in, "wb");
    ck_assert_ptr_nonnull(f);
    fputs(text, f);
    fclose(f);
    ck_assert_int_eq(wf_test_run("sha256sum < %s > %s", in, out), 0);
    char *got = wf_test_slurp(out, NULL);
    ck_assert_ptr_nonnull(got);
    snprintf(hex, (size_t)n + 1, "%s", got);
    free(got);
}

START_TEST(resume_same_inputs_only)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char plan[4200], log[4200], img0[4200], img1[4200], truth0[4200], man[4200], keep0[4200], keep1[4200],
        keepman[4200];
    snprintf(log, sizeof log, "%s/log", d);
    snprintf(img0, sizeof img0, "%s/run/wfisim_e000000_sca01.fits", d);
    snprintf(img1, sizeof img1, "%s/run/wfisim_e000001_sca01.fits", d);
    snprintf(truth0, sizeof truth0, "%s/run/wfisim_e000000_sca01_truth.fits", d);
    snprintf(man, sizeof man, "%s/run/survey_run.txt", d);
    snprintf(keep0, sizeof keep0, "%s/keep0.fits", d);
    snprintf(keep1, sizeof keep1, "%s/keep1.fits", d);
    snprintf(keepman, sizeof keepman, "%s/keep_run.txt", d);
    one_visit_plan(bin, d, plan, sizeof plan);
#define RUN(extra) \
    wf_test_run(NODATA "%s survey run --plan %s --exposures 0:1 --scas 1 " TINY " %s --out %s/run 2>%s", bin, plan, extra, d, log)
    ck_assert_int_eq(RUN(""), 0);
    ck_assert_int_eq(wf_test_run("cp %s %s && cp %s %s && cp %s %s && cp %s %s/keep_truth0.fits", img0, keep0, img1, keep1,
                                 man, keepman, truth0, d), 0);
    long long t0 = mtime_ns(img0), t1 = mtime_ns(truth0), tm = mtime_ns(man);

    /* the digest parts are SHA-256 of documented texts: the seed's checked with sha256sum, and
     * the whole is the digest of the parts as the header holds them */
    static const char *const parts[6][2] = {{"config", "WFDCONF"}, {"seed", "WFDSEED"}, {"data", "WFDDATA"},
                                            {"catalogs", "WFDCAT"}, {"sne", "WFDSNE"}, {"version", "WFDVERS"}};
    char v[FLEN_VALUE], hex[80], whole[1024] = "";
    header_str(img0, "WFDSEED", v);
    sha256sum_of(d, "seed = 1\n", hex, 32);
    ck_assert_str_eq(v, hex);
    header_str(img0, "WFDDATA", v);
    sha256sum_of(d, "data: built-in values (no paths.data)\n", hex, 32);
    ck_assert_str_eq(v, hex);
    for (int p = 0; p < 6; p++) {
        header_str(img0, parts[p][1], v);
        ck_assert_int_eq((int)strlen(v), 32);
        snprintf(whole + strlen(whole), sizeof whole - strlen(whole), "%s %s\n", parts[p][0], v);
    }
    sha256sum_of(d, whole, hex, 64);
    header_str(img0, "WFDIGEST", v);
    ck_assert_str_eq(v, hex);
    char digest_seed1[80];
    snprintf(digest_seed1, sizeof digest_seed1, "%s", v);
    header_str(truth0, "WFDIGEST", v); /* the truth names the image's inputs */
    ck_assert_str_eq(v, digest_seed1);
    /* the record lists the product with the digest its header holds */
    char line[200];
    snprintf(line, sizeof line, "product wfisim_e000000_sca01.fits %s this run's inputs", digest_seed1);
    ck_assert_msg(wf_test_file_contains(man, line), "record lacks '%s'", line);

    /* the same inputs: skipped, the files untouched; other thread counts and tile heights
     * cannot change a byte, so they do not remake anything either */
    ck_assert_int_eq(RUN(""), 0);
    ck_assert_msg(wf_test_file_contains(log, "0 products rendered") && wf_test_file_contains(log, "2 already done"),
                  "same inputs redone");
    ck_assert_int_eq(RUN("--threads 2 --tile-rows 16 --set run.uncached_writes=false"), 0);
    ck_assert_msg(wf_test_file_contains(log, "2 already done"), "threads / tile rows forced a redo");
    wf_test_assert_same_file(img0, keep0);
    wf_test_assert_same_file(img1, keep1);
    ck_assert(mtime_ns(img0) == t0 && mtime_ns(truth0) == t1);

    /* another seed: refused, naming the seed, and nothing written (record included) */
    long long tm2 = mtime_ns(man);
    ck_assert_int_eq(wf_test_run("cp %s %s", man, keepman), 0);
    ck_assert_int_eq(RUN("--seed 2"), 2);
    ck_assert_msg(wf_test_file_contains(log, "wfisim_e000000_sca01.fits was made with seed 1, this run has seed 2; "
                                             "use --on-change redo to remake it"), "refusal does not name the seed");
    ck_assert(mtime_ns(img0) == t0 && mtime_ns(truth0) == t1 && mtime_ns(man) == tm2);
    wf_test_assert_same_file(img0, keep0);
    ck_assert(tm2 >= tm);
    /* a changed --set key is named with both values; a key back to its default too */
    ck_assert_int_eq(RUN("--set detector.gain=1.5"), 2);
    ck_assert_msg(wf_test_file_contains(log, "a different configuration: detector.gain = the default, this run has 1.5"),
                  "changed key not named");
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --plan %s --exposures 0:1 --scas 1 --mode single --set "
                                 "readout.ncols=128 --set readout.nrows=96 --out %s/run 2>%s", bin, plan, d, log), 2);
    ck_assert_msg(wf_test_file_contains(log, "detector.cr_rate = 0, this run has the default"), "key back to default not named");
    ck_assert_int_eq(RUN("--on-change sometimes"), 2);
    ck_assert(wf_test_file_contains(log, "--on-change 'sometimes'"));
    wf_test_assert_same_file(man, keepman);
    ck_assert(mtime_ns(img0) == t0 && mtime_ns(man) == tm2);

    /* redo: remade from the new inputs, the products differ and carry the new digest */
    ck_assert_int_eq(RUN("--seed 2 --on-change redo"), 0);
    ck_assert_msg(wf_test_file_contains(log, "2 products rendered (0 replacing damaged ones, 2 made from other inputs)"),
                  "redo did not remake both");
    size_t la, lb;
    char *x = wf_test_slurp(img0, &la), *y = wf_test_slurp(keep0, &lb);
    ck_assert(x && y && (la != lb || memcmp(x, y, la)));
    free(x);
    free(y);
    ck_assert(wf_survey_product_ok(img0) && wf_survey_product_ok(truth0));
    header_str(img0, "WFDSEED", v);
    sha256sum_of(d, "seed = 2\n", hex, 32);
    ck_assert_str_eq(v, hex);
    header_str(img0, "WFDIGEST", v);
    ck_assert_str_ne(v, digest_seed1);
    snprintf(line, sizeof line, "product wfisim_e000000_sca01.fits %s this run's inputs", v);
    ck_assert_msg(wf_test_file_contains(man, line) && wf_test_file_contains(man, "seed = 2\n") &&
                      wf_test_file_contains(man, "status = complete"), "record does not describe the remade products");
    ck_assert_int_eq(RUN("--seed 2"), 0);
    ck_assert(wf_test_file_contains(log, "2 already done"));
    /* a whole truth from other inputs beside the image: the pair is redone */
    ck_assert_int_eq(wf_test_run("cp %s/keep_truth0.fits %s", d, truth0), 0);
    ck_assert(wf_survey_product_ok(truth0));
    ck_assert_int_eq(RUN("--seed 2"), 0);
    ck_assert_msg(wf_test_file_contains(log, "1 products rendered (1 replacing damaged ones, 0 made from other inputs)"),
                  "a truth from other inputs was kept");
    header_str(truth0, "WFDIGEST", v);
    char img_digest[80];
    header_str(img0, "WFDIGEST", img_digest);
    ck_assert_str_eq(v, img_digest);

    /* a digest card damaged in the file is damage (the checksums fail): redone, not refused */
    char keep2[4200];
    snprintf(keep2, sizeof keep2, "%s/keep2.fits", d);
    ck_assert_int_eq(wf_test_run("cp %s %s", img0, keep2), 0);
    char *bytes = wf_test_slurp(img0, &la);
    char *card = bytes ? strstr(bytes, "WFDIGEST= '") : NULL;
    ck_assert_ptr_nonnull(card);
    FILE *f0 = fopen(img0, "r+b");
    ck_assert_ptr_nonnull(f0);
    fseek(f0, (long)(card - bytes) + 11, SEEK_SET);
    fputc(card[11] == '0' ? '1' : '0', f0);
    fclose(f0);
    free(bytes);
    ck_assert_int_eq(RUN("--seed 2"), 0);
    ck_assert_msg(wf_test_file_contains(log, "1 products rendered (1 replacing damaged ones, 0 made from other inputs)"),
                  "damaged digest card not taken as damage");
    wf_test_assert_same_file(img0, keep2);

    /* a product of an older wfisim (no digest) counts as made from other inputs */
    fitsfile *f;
    int status = 0;
    fits_open_file(&f, img1, READWRITE, &status);
    fits_delete_key(f, "WFDIGEST", &status);
    fits_write_chksum(f, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    ck_assert(wf_survey_product_ok(img1));
    ck_assert_int_eq(RUN("--seed 2"), 2);
    ck_assert_msg(wf_test_file_contains(log, "wfisim_e000001_sca01.fits was made with a wfisim that recorded no input digest"),
                  "digest-less product not refused");
    /* a product of this folder outside the range is listed with the parts that differ */
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 2 --scas 1 " TINY " --out %s/run",
                                 bin, plan, d), 0);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 2 --scas 1 " TINY
                                 " --seed 2 --on-change redo --out %s/run", bin, plan, d), 0);
    ck_assert_msg(wf_test_file_contains(man, "wfisim_e000001_sca01.fits (no digest: inputs unknown)"), "old product not listed");
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 2 --scas 1 " TINY
                                 " --seed 3 --on-change redo --out %s/run", bin, plan, d), 0);
    ck_assert_msg(wf_test_file_contains(man, "other wfisim_e000000_sca01.fits") &&
                  wf_test_file_contains(man, " differs: seed\n"), "outside product's differing seed not recorded");
#undef RUN
}
END_TEST

/* With and without paths.data: the data part differs (the SIP distortion, pupils, bandpasses)
 * and the refusal says so; the data folder counts by content, not by path. */
START_TEST(resume_data_folder)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the data folder");
    const char *d = wf_test_tmpdir();
    char plan[4200], log[4200];
    snprintf(log, sizeof log, "%s/log", d);
    one_visit_plan(bin, d, plan, sizeof plan);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 0 --scas 1 " TINY " --out %s/run",
                                 bin, plan, d), 0);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --plan %s --exposures 0 --scas 1 " TINY " --data %s --out %s/run 2>%s",
                                 bin, plan, data, d, log), 2);
    ck_assert_msg(wf_test_file_contains(log, "was made with the built-in values (no paths.data), this run reads the data files of"),
                  "data change not named");
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 0 --scas 1 " TINY
                                 " --data %s --on-change redo --out %s/run", bin, plan, data, d), 0);
    /* a copy of roman/ elsewhere is the same data; one byte changed in one file is not */
    ck_assert_int_eq(wf_test_run("mkdir -p %s/copy && cp -r %s/roman %s/copy/", d, data, d), 0);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --plan %s --exposures 0 --scas 1 " TINY " --data %s/copy --out %s/run 2>%s",
                                 bin, plan, d, d, log), 0);
    ck_assert(wf_test_file_contains(log, "1 already done"));
    ck_assert_int_eq(wf_test_run("printf '\\n' >> %s/copy/roman/sca_positions_20210204.txt", d), 0);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --plan %s --exposures 0 --scas 1 " TINY " --data %s/copy --out %s/run 2>%s",
                                 bin, plan, d, d, log), 2);
    ck_assert_msg(wf_test_file_contains(log, "data files other than this run's, this run reads the data files of"),
                  "changed data file not detected");
}
END_TEST

/* One hostless SN Ia at (ra, dec) peaking at mjd, redshift z. */
static void write_sample(const char *path, double ra, double dec, double mjd, double z)
{
    wf_sn_sample s;
    memset(&s, 0, sizeof s);
    snprintf(s.model, sizeof s.model, "salt3-k21");
    size_t r;
    ck_assert_int_eq(wf_sn_sample_push(&s, &r), 0);
    s.id[r] = 1;
    s.host_id[r] = -1;
    s.host_comp[r] = -1;
    s.flags[r] = WF_SN_FLAG_HOSTLESS;
    s.z[r] = z;
    s.t0[r] = mjd;
    s.x1[r] = 0.3;
    s.c[r] = -0.05;
    s.mu[r] = 42.27;
    s.x0[r] = 1.0;
    s.ra[r] = ra;
    s.dec[r] = dec;
    ck_assert_int_eq(wf_sn_sample_write(&s, path), 0);
    wf_sn_sample_free(&s);
}

/* Catalog files and the SN sample count by their bytes: moved, the same; changed, named. */
START_TEST(resume_catalogs_and_sne)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the data folder (SALT model)");
    const char *d = wf_test_tmpdir();
    char plan[4200], log[4200], stars[4200], sne[4200];
    snprintf(log, sizeof log, "%s/log", d);
    snprintf(stars, sizeof stars, "%s/stars.csv", d);
    snprintf(sne, sizeof sne, "%s/sne.fits", d);
    one_visit_plan(bin, d, plan, sizeof plan);
    double ra, pa, mjd, exptime;
    char filter[16];
    plan_row(plan, 0, &ra, &pa, &mjd, &exptime, filter);
    FILE *f = fopen(stars, "w");
    ck_assert_ptr_nonnull(f);
    fprintf(f, "id,ra,dec,mag_Y106\n1,%.6f,-53,20\n", fmod(ra + 20.0, 360.0));
    fclose(f);
    write_sample(sne, 71.0, -53.0, mjd, 0.5);
#define RUNC(files) \
    wf_test_run("%s survey run --plan %s --exposures 0 --scas 1 " TINY " --data %s --model %s/salt3/salt3-k21 " \
                "--set scene.kind=catalog %s --out %s/run 2>%s", bin, plan, data, data, files, d, log)
    char files[9000];
    snprintf(files, sizeof files, "--stars %s --sne %s", stars, sne);
    ck_assert_int_eq(RUNC(files), 0);
    /* the same bytes under other names: done */
    ck_assert_int_eq(wf_test_run("cp %s %s/moved.csv && cp %s %s/moved.fits", stars, d, sne, d), 0);
    snprintf(files, sizeof files, "--stars %s/moved.csv --sne %s/moved.fits", d, d);
    ck_assert_int_eq(RUNC(files), 0);
    ck_assert_msg(wf_test_file_contains(log, "1 already done"), "moved files remade the product");
    /* one more star (off the SCA: the image would not even change, its inputs did) */
    ck_assert_int_eq(wf_test_run("printf '2,%.6f,-50,21\n' >> %s/moved.csv", fmod(ra + 20.0, 360.0), d), 0);
    ck_assert_int_eq(RUNC(files), 2);
    ck_assert_msg(wf_test_file_contains(log, "was made with other scene catalogs than this run's"), "catalog change not named");
    /* another SN sample */
    write_sample(sne, 71.0, -53.0, mjd, 0.6);
    snprintf(files, sizeof files, "--stars %s --sne %s", stars, sne);
    ck_assert_int_eq(RUNC(files), 2);
    ck_assert_msg(wf_test_file_contains(log, "was made with another SN sample than this run's"), "SN change not named");
    snprintf(files, sizeof files, "--stars %s --sne %s --on-change redo", stars, sne);
    ck_assert_int_eq(RUNC(files), 0);
    ck_assert(wf_test_file_contains(log, "1 made from other inputs"));
#undef RUNC
}
END_TEST

/* `wfisim expose` products carry the same keywords, and the digest does not depend on the
 * thread count or tile height (nor, then, do the bytes) */
START_TEST(expose_digest)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    ck_assert_int_eq(wf_test_run(NODATA "%s expose --quiet " TINY " --set scene.kind=grid --out %s/a", bin, d), 0);
    ck_assert_int_eq(wf_test_run(NODATA "%s expose --quiet " TINY " --set scene.kind=grid --threads 3 --tile-rows 8 --out %s/b",
                                 bin, d), 0);
    char a[4200], b[4200], va[FLEN_VALUE], vb[FLEN_VALUE], hex[80];
    snprintf(a, sizeof a, "%s/a/wfisim_e000001_sca01.fits", d);
    snprintf(b, sizeof b, "%s/b/wfisim_e000001_sca01.fits", d);
    header_str(a, "WFDIGEST", va);
    header_str(b, "WFDIGEST", vb);
    ck_assert_str_eq(va, vb);
    wf_test_assert_same_file(a, b);
    header_str(a, "WFDDATA", va); /* the grid scene reads no data */
    sha256sum_of(d, "data: not read (grid or replayed scene)\n", hex, 32);
    ck_assert_str_eq(va, hex);
    ck_assert_int_eq(wf_test_run("%s --version | grep -q '+src\\.'", bin), 0);
}
END_TEST

/* ---- persistence histories through the run's cache ---------------------------------- */

#define HIST "--exposures 0:5 --scas 3,7 --mode single " SMALL " --set scene.kind=catalog"

/* A plan and a star catalog with a saturating star (AB 16) on SCA 3 in each of exposures 0..5,
 * so that the histories hold pixels. */
static void history_inputs(const char *bin, const char *d, char *plan, char *stars, size_t cap, int visits)
{
    snprintf(plan, cap, "%s/plan.fits", d);
    snprintf(stars, cap, "%s/stars.csv", d);
    ck_assert_int_eq(wf_test_run("%s survey plan --quiet --set survey.visits=%d --out %s", bin, visits, plan), 0);
    wf_survey_row *rows;
    size_t nrows;
    ck_assert_int_eq(wf_survey_read_plan(plan, &rows, &nrows), WF_OK);
    wf_focal_plane fp;
    ck_assert_int_eq(wf_wcs_focal_plane(NULL, &fp), WF_OK);
    FILE *f = fopen(stars, "w");
    ck_assert_ptr_nonnull(f);
    fprintf(f, "id,ra,dec,mag_Y106,mag_J129,mag_H158,mag_F184\n");
    for (int e = 0; e <= 5; e++) {
        wf_wcs w;
        double ra, dec;
        ck_assert_int_eq(rows[e].expid, e);
        ck_assert_int_eq(wf_wcs_for_sca(&fp, rows[e].ra, rows[e].dec, rows[e].pa, 3, &w), WF_OK);
        ck_assert_int_eq(wf_wcs_pix2world(&w, 20 + 15 * e, 48, &ra, &dec), WF_OK);
        fprintf(f, "%d,%.10f,%.10f,16,16,16,16\n", e, ra, dec);
    }
    fclose(f);
    free(rows);
}

/* history_inputs in a fresh folder *d, and the path of a run's log there. */
static void history_setup(const char *bin, const char **d, char *plan, char *stars, char *log, size_t cap)
{
    *d = wf_test_tmpdir();
    history_inputs(bin, *d, plan, stars, cap, 1);
    snprintf(log, cap, "%s/log", *d);
}

/* From the products' headers alone: U, the earlier exposures of every history (PERSISTN
 * summed), and the distinct (EXPID, SCA) among them, what a cache that never loses one of a
 * run in plan order draws. */
static void history_counts(const char *dir, long *used, long *distinct)
{
    long seen[64];
    int nseen = 0;
    *used = 0;
    for (int e = 0; e <= 5; e++)
        for (int k = 0; k < 2; k++) {
            int sca = k ? 7 : 3;
            char path[4400], v[FLEN_VALUE], key[32];
            snprintf(path, sizeof path, "%s/wfisim_e%06d_sca%02d.fits", dir, e, sca);
            header(path, "PERSISTN", v);
            int n = atoi(v);
            *used += n;
            for (int j = 1; j <= n; j++) {
                snprintf(key, sizeof key, "PERSEX%d", j);
                header(path, key, v);
                long id = atol(v) * 100 + sca;
                int old = 0;
                for (int q = 0; q < nseen; q++) old |= seen[q] == id;
                if (!old && nseen < 64) seen[nseen++] = id;
            }
        }
    *distinct = nseen;
}

/* The numbers of a run's log line that begins with format's text up to its first '%':
 * format's conversions, n of them, into a and b. */
static void logged(const char *log, const char *format, int n, long *a, long *b)
{
    size_t len;
    char *text = wf_test_slurp(log, &len);
    ck_assert_ptr_nonnull(text);
    char head[64];
    snprintf(head, sizeof head, "%.*s", (int)strcspn(format, "%"), format);
    const char *at = strstr(text, head);
    ck_assert_msg(at != NULL, "%s: no line \"%s\"", log, head);
    ck_assert_int_eq(sscanf(at, format, a, b), n);
    free(text);
}

/* "persistence histories: U earlier exposures, D of them drawn" from a run's log. */
static void logged_counts(const char *log, long *used, long *drawn)
{
    logged(log, "persistence histories: %ld earlier exposures, %ld of them drawn", 2, used, drawn);
}

/* From the products' FILTER keys: the PSFs a process builds that makes each SCA's exposures
 * in plan order keeping its last PSF, one per run of an SCA's exposures in one filter. */
static long psf_runs(const char *dir)
{
    long runs = 0;
    for (int k = 0; k < 2; k++) {
        char last[FLEN_VALUE] = "";
        for (int e = 0; e <= 5; e++) {
            char path[4400], v[FLEN_VALUE];
            snprintf(path, sizeof path, "%s/wfisim_e%06d_sca%02d.fits", dir, e, k ? 7 : 3);
            header(path, "FILTER", v);
            runs += strcmp(v, last) != 0;
            snprintf(last, sizeof last, "%s", v);
        }
    }
    return runs;
}

/* "PSFs: N built" from a run's log. */
static long logged_psfs(const char *log)
{
    long n = -1;
    logged(log, "PSFs: %ld built", 1, &n, NULL);
    return n;
}

static void assert_same_history_products(const char *d, const char *a, const char *b)
{
    for (int e = 0; e <= 5; e++)
        for (int k = 0; k < 2; k++)
            for (int t = 0; t < 2; t++) {
                char x[4300], y[4300];
                snprintf(x, sizeof x, "%s/%s/wfisim_e%06d_sca%02d%s.fits", d, a, e, k ? 7 : 3, t ? "_truth" : "");
                snprintf(y, sizeof y, "%s/%s/wfisim_e%06d_sca%02d%s.fits", d, b, e, k ? 7 : 3, t ? "_truth" : "");
                wf_test_assert_same_file(x, y);
            }
}

/* The images and truth of SCA 3, exposures e0..e1, the same bytes in d/a and d/b. */
static void assert_same_sca3(const char *d, const char *a, const char *b, int e0, int e1)
{
    for (int e = e0; e <= e1; e++)
        for (int t = 0; t < 2; t++) {
            char x[4400], y[4400];
            snprintf(x, sizeof x, "%s/%s/wfisim_e%06d_sca03%s.fits", d, a, e, t ? "_truth" : "");
            snprintf(y, sizeof y, "%s/%s/wfisim_e%06d_sca03%s.fits", d, b, e, t ? "_truth" : "");
            wf_test_assert_same_file(x, y);
        }
}

/* The cache of histories changes no byte, only what is drawn: with it off
 * (WFISIM_TEST_PERSIST_CACHE=off) every earlier exposure of every history is drawn (D = U);
 * with it on an exposure the run makes gives its own slot as it is drawn (tools/persist.h,
 * the layer), so here, where every history's exposures are items of the run, none is drawn
 * (D = 0; each distinct one drawn once, D = 10, before the layer), in one process and with
 * each item in a process of its own (--isolate); under MPI a walk's first item draws its
 * history, whose exposures another rank made (0 < D < U). The items of an SCA and filter
 * share one PSF: one process builds one per run of an SCA's exposures in one filter
 * (isolated, the parent builds it before the fork); MPI's ranks at least as many, each for
 * its own walks, and fewer than the items. */
START_TEST(history_cache_any_process)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d;
    char plan[4200], stars[4200], log[4200];
    history_setup(bin, &d, plan, stars, log, sizeof plan);
    long u, dist, lu, ld;
    ck_assert_int_eq(wf_test_run("WFISIM_TEST_PERSIST_CACHE=off %s survey run --plan %s " HIST " --set scene.stars=%s "
                                 "--out %s/off 2>%s", bin, plan, stars, d, log), 0);
    logged_counts(log, &lu, &ld);
    char dir[4300];
    snprintf(dir, sizeof dir, "%s/off", d);
    history_counts(dir, &u, &dist);
    ck_assert_int_gt(u, 0);
    ck_assert_int_lt(dist, u);
    ck_assert_int_eq(lu, u);
    ck_assert_int_eq(ld, u);
    char x[4300], v[FLEN_VALUE];
    snprintf(x, sizeof x, "%s/off/wfisim_e000005_sca03.fits", d);
    header(x, "PERSISTN", v); /* exposure 5 of SCA 3 holds earlier exposures' stars */
    ck_assert_int_ge(atoi(v), 2);
    ck_assert_int_eq(wf_test_run("%s survey run --plan %s " HIST " --set scene.stars=%s --out %s/on 2>%s", bin, plan,
                                 stars, d, log), 0);
    logged_counts(log, &lu, &ld);
    ck_assert_int_eq(lu, u);
    ck_assert_int_eq(ld, 0);
    assert_same_history_products(d, "off", "on");
    const long runs = psf_runs(dir);
    ck_assert_int_ge(runs, 2);
    ck_assert_int_lt(runs, 12); /* else nothing to share */
    ck_assert_int_eq(logged_psfs(log), runs);
    /* each item in a child: what the children drew comes back to the parent's cache */
    ck_assert_int_eq(wf_test_run("%s survey run --isolate --plan %s " HIST " --set scene.stars=%s --out %s/iso 2>%s",
                                 bin, plan, stars, d, log), 0);
    logged_counts(log, &lu, &ld);
    ck_assert_int_eq(lu, u);
    ck_assert_int_eq(ld, 0);
    assert_same_history_products(d, "off", "iso");
    ck_assert_int_eq(logged_psfs(log), runs);
    /* under MPI, ranks make walks of an SCA's items: the same bytes, and ranks draw less
     * than every history whole (each walk draws its first item's history, then one a step).
     * Without the scene cache: with it, a walk's first item reads the exposures another rank
     * made from their scenes' entries when that rank stored them first, so D depends on the
     * ranks' timing (scene_cache_same_bytes tests reading histories from it) */
    const char *mpi = mpi_program();
    if (!mpi) return; /* CI has it */
    ck_assert_int_eq(wf_test_run(MPIRUN " %s survey run --plan %s " HIST " --set scene.stars=%s --set run.scene_cache=none "
                                 "--out %s/mpi 2>%s", mpi, plan, stars, d, log), 0);
    logged_counts(log, &lu, &ld);
    ck_assert_int_eq(lu, u);
    ck_assert_int_gt(ld, 0);
    ck_assert_int_lt(ld, u);
    assert_same_history_products(d, "off", "mpi");
    ck_assert_int_ge(logged_psfs(log), runs);
    ck_assert_int_lt(logged_psfs(log), 12);
    /* with it, the same bytes, and fewer drawn than every history whole (at most each walk's
     * first item's, fewer as the ranks' entries come in first) */
    ck_assert_int_eq(wf_test_run(MPIRUN " %s survey run --plan %s " HIST " --set scene.stars=%s --out %s/mpic 2>%s", mpi,
                                 plan, stars, d, log), 0);
    logged_counts(log, &lu, &ld);
    ck_assert_int_eq(lu, u);
    ck_assert_int_lt(ld, u);
    assert_same_history_products(d, "off", "mpic");
    ck_assert_int_ge(logged_psfs(log), runs);
    ck_assert_int_lt(logged_psfs(log), 12);
}
END_TEST

/* The scene cache (run.scene_cache): a plan's second visit takes the static scenes its first
 * one stored instead of drawing them, in one process, with each item in a process of its own
 * (--isolate) and under MPI, and the products are those of a run without it, persistence
 * included (exposure 65's history holds exposure 64's saturating star, from the stored
 * layer); an item alone reads its history's exposures from the cache instead of drawing
 * them. */
START_TEST(scene_cache_same_bytes)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char plan[4200], stars[4200], log[4200];
    history_inputs(bin, d, plan, stars, sizeof plan, 2);
    snprintf(log, sizeof log, "%s/log", d);
    wf_survey_row *rows;
    size_t nrows;
    ck_assert_int_eq(wf_survey_read_plan(plan, &rows, &nrows), WF_OK);
    ck_assert_int_gt(nrows, 65);
    for (int e = 0; e <= 1; e++) /* the same pointing, PA and filter a visit later */
        ck_assert(rows[e].ra == rows[e + 64].ra && rows[e].pa == rows[e + 64].pa && !strcmp(rows[e].filter, rows[e + 64].filter) &&
                  rows[e].mjd_mid < rows[e + 64].mjd_mid - 1.0);
    free(rows);
#define CACHED "--scas 3 --mode single " SMALL " --set scene.kind=catalog --set scene.stars=%s"
    long found, made;
    /* stored by two threads in 7-row tiles, read by one in 32-row tiles */
    ck_assert_int_eq(wf_test_run("%s survey run --plan %s --exposures 0:1 " CACHED " --set run.scene_cache=%s/cache "
                                 "--threads 2 --set readout.tile_rows=7 --out %s/first 2>%s", bin, plan, stars, d, d, log), 0);
    logged(log, "static scenes: %ld of the %ld", 2, &found, &made);
    ck_assert(found == 0 && made == 2);
    ck_assert_int_eq(wf_test_run("%s survey run --plan %s --exposures 64:65 " CACHED " --set run.scene_cache=none "
                                 "--out %s/none 2>%s", bin, plan, stars, d, log), 0);
    logged(log, "static scenes: %ld of the %ld", 2, &found, &made);
    ck_assert(found == 0 && made == 2);
    char x[4300], y[4300], v[FLEN_VALUE];
    snprintf(x, sizeof x, "%s/none/wfisim_e000065_sca03.fits", d);
    header(x, "PERSISTN", v);
    ck_assert_int_eq(atoi(v), 1);
    /* exposure 65 alone: its history, exposure 64, is read from the layer its scene's entry
     * holds (the first visit's exposure 0) instead of drawn; without the cache it is drawn */
    long used, drawn;
    for (int k = 0; k < 2; k++) {
        ck_assert_int_eq(wf_test_run("%s survey run --plan %s --exposures 65 " CACHED " --set run.scene_cache=%s%s "
                                     "--out %s/alone%d 2>%s", bin, plan, stars, k ? d : "none", k ? "/cache" : "", d, k, log), 0);
        logged_counts(log, &used, &drawn);
        ck_assert_int_eq(used, 1);
        ck_assert_int_eq(drawn, k ? 0 : 1);
        snprintf(y, sizeof y, "%s/alone%d/wfisim_e000065_sca03.fits", d, k);
        wf_test_assert_same_file(x, y);
    }
    const char *how[3] = {"", "--isolate", NULL};
    const char *mpi = mpi_program();
    for (int k = 0; k < 3; k++) {
        if (k == 2 && !mpi) break; /* CI has it */
        char cmd[600];
        snprintf(cmd, sizeof cmd, "%s%s survey run %s", k == 2 ? MPIRUN " " : "", k == 2 ? mpi : bin, how[k] ? how[k] : "");
        ck_assert_int_eq(wf_test_run("%s --plan %s --exposures 64:65 " CACHED " --set run.scene_cache=%s/cache "
                                     "--out %s/again%d 2>%s", cmd, plan, stars, d, d, k, log), 0);
        logged(log, "static scenes: %ld of the %ld", 2, &found, &made);
        ck_assert_msg(found == 2 && made == 2, "%s: %ld of %ld from the cache", cmd, found, made);
        char again[16];
        snprintf(again, sizeof again, "again%d", k);
        assert_same_sca3(d, "none", again, 64, 65);
    }
#undef CACHED
}
END_TEST

/* The scene cache with supernovae: a second visit's SN, the exposure's variable object, is
 * drawn on the first visit's stored plane, and the products are those of a run without the
 * cache (the SN at its own flux and phase in each exposure). */
START_TEST(scene_cache_with_supernovae)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the data folder (SALT model)");
    const char *d = wf_test_tmpdir();
    char plan[4200], stars[4200], log[4200], sne[4200];
    history_inputs(bin, d, plan, stars, sizeof plan, 2);
    snprintf(log, sizeof log, "%s/log", d);
    snprintf(sne, sizeof sne, "%s/sne.fits", d);
    wf_survey_row *rows;
    size_t nrows;
    ck_assert_int_eq(wf_survey_read_plan(plan, &rows, &nrows), WF_OK);
    ck_assert_int_gt(nrows, 65);
    wf_focal_plane fp;
    wf_wcs w;
    double ra, dec;
    ck_assert_int_eq(wf_wcs_focal_plane(NULL, &fp), WF_OK);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, rows[64].ra, rows[64].dec, rows[64].pa, 3, &w), WF_OK);
    ck_assert_int_eq(wf_wcs_pix2world(&w, 64.0, 30.0, &ra, &dec), WF_OK);
    write_sample(sne, ra, dec, rows[64].mjd_mid, 0.3); /* at peak on the second visit, rising on the first */
    free(rows);
#define SNRUN(range, cache, out)                                                                                   \
    wf_test_run("%s survey run --plan %s --exposures " range " --scas 3 --mode single " SMALL                       \
                " --set scene.kind=catalog --set scene.stars=%s --data %s --model %s/salt3/salt3-k21 --sne %s "     \
                "--set run.scene_cache=%s --out %s/" out " 2>%s", bin, plan, stars, data, data, sne, cache, d, log)
    char cache[4300];
    snprintf(cache, sizeof cache, "%s/cache", d);
    long found, made, n;
    ck_assert_int_eq(SNRUN("0:1", cache, "first"), 0);
    ck_assert_int_eq(SNRUN("64:65", "none", "none"), 0);
    logged(log, "static scenes: %ld of the %ld", 2, &found, &made);
    ck_assert(found == 0 && made == 2);
    ck_assert_int_eq(SNRUN("64:65", cache, "again"), 0);
    logged(log, "static scenes: %ld of the %ld", 2, &found, &made);
    ck_assert_msg(found == 2 && made == 2, "%ld of %ld from the cache", found, made);
    char *text = wf_test_slurp(log, NULL);
    ck_assert_ptr_nonnull(text);
    const char *at = strstr(text, "already done; ");
    ck_assert(at && sscanf(at, "already done; %ld supernova images", &n) == 1);
    free(text);
    ck_assert_msg(n == 1, "the SN is on %ld of the 2 images, not on exposure 64's alone (65 points elsewhere)", n);
#undef SNRUN
    assert_same_sca3(d, "none", "again", 64, 65);
}
END_TEST

/* A scene cache that cannot keep a plane (a file-size limit, as a full disk: the plane's file
 * cannot grow to its 100 KB while the 55 KB products can) fails no product: they are those of
 * a run without the cache, and the run warns, naming the file and the reason. */
START_TEST(scene_cache_cannot_keep)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char plan[4200], log[4200];
    snprintf(log, sizeof log, "%s/log", d);
    one_visit_plan(bin, d, plan, sizeof plan);
#define LIMITED(cache, out)                                                                                       \
    wf_test_run("ulimit -f 150; trap '' XFSZ; %s survey run --plan %s --exposures 0:1 --scas 3 --mode single " SMALL \
                " --set run.scene_cache=%s --out %s/" out " 2>%s", bin, plan, cache, d, log)
    ck_assert_int_eq(LIMITED("none", "none"), 0);
    ck_assert_msg(!wf_test_file_contains(log, "warning"), "a run without the cache warns");
    ck_assert_int_eq(LIMITED("auto", "full"), 0);
#undef LIMITED
    ck_assert_msg(wf_test_file_contains(log, "could not keep the scenes of 2 products"), "no warning");
    ck_assert_msg(wf_test_file_contains(log, "File too large"), "the warning does not say why");
    assert_same_sca3(d, "none", "full", 0, 1);
    char cmd[4400];
    snprintf(cmd, sizeof cmd, "test -z \"$(ls %s/full/scene_cache)\"", d); /* no file left behind */
    ck_assert_int_eq(system(cmd), 0);
}
END_TEST

/* A run that begins mid-plan (a job array's task; an MPI walk) draws its first item's whole
 * history and then none: each later item of the SCA finds the earlier exposures the first
 * one drew, and the one before it made, in the cache (at the default depth, 8, the cache's
 * size per SCA, which a least-recently-used eviction emptied of the newest ones: 22 of 24
 * drawn). The products are those of a run with the cache off. */
START_TEST(history_cache_mid_plan)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d;
    char plan[4200], stars[4200], log[4200];
    history_setup(bin, &d, plan, stars, log, sizeof plan);
#define MID "--exposures 12:14 --scas 3 --mode single " SMALL " --set scene.kind=catalog " \
            "--set detector.persistence.depth=8 --set detector.persistence.window=3600"
    long lu, ld;
    ck_assert_int_eq(wf_test_run("%s survey run --plan %s " MID " --set scene.stars=%s --out %s/mid 2>%s", bin, plan,
                                 stars, d, log), 0);
    logged_counts(log, &lu, &ld);
    ck_assert_int_eq(lu, 3 * 8);
    ck_assert_int_eq(ld, 8);
    ck_assert_int_eq(wf_test_run("WFISIM_TEST_PERSIST_CACHE=off %s survey run --plan %s " MID " --set scene.stars=%s "
                                 "--out %s/midoff 2>%s", bin, plan, stars, d, log), 0);
    logged_counts(log, &lu, &ld);
    ck_assert_int_eq(lu, 3 * 8);
    ck_assert_int_eq(ld, 3 * 8);
#undef MID
    assert_same_sca3(d, "mid", "midoff", 12, 14);
}
END_TEST

/* The walks: every item once, each walk one SCA's items in plan order, at most
 * ceil(items / (2 workers)) of them (the MPI program's), or all of them (0 workers: a
 * one-process run's), and walks listed by their first item. */
START_TEST(walks_cover_items)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char plan[4200];
    one_visit_plan(bin, d, plan, sizeof plan);
    wf_config cfg;
    wf_config_defaults(&cfg);
    wf_survey_run_options opt;
    memset(&opt, 0, sizeof opt);
    opt.plan_path = plan;
    opt.first = 3;
    opt.last = 12;
    opt.nscas = 3;
    opt.scas[0] = 7;
    opt.scas[1] = 3;
    opt.scas[2] = 12;
    wf_survey_ctx *ctx;
    size_t n;
    ck_assert_int_eq(wf_survey_begin(&cfg, &opt, &ctx, &n), WF_OK);
    ck_assert_uint_eq(n, 30);
    size_t workers[] = {1, 2, 4, 100, 0}; /* 0: one walk per SCA (a one-process run's order) */
    for (int q = 0; q < 5; q++) {
        size_t *order, *start, nwalks, len = workers[q] ? (n + 2 * workers[q] - 1) / (2 * workers[q]) : n;
        ck_assert_int_eq(wf_survey_walks(ctx, workers[q], &order, &start, &nwalks), WF_OK);
        ck_assert_uint_eq(start[0], 0);
        ck_assert_uint_eq(start[nwalks], n);
        ck_assert_uint_eq(nwalks, 3 * ((10 + len - 1) / len)); /* each SCA's 10 items cut by len */
        int seen[30] = {0};
        for (size_t w = 0; w < nwalks; w++) {
            ck_assert_uint_gt(start[w + 1], start[w]);
            ck_assert_uint_le(start[w + 1] - start[w], len);
            if (w) ck_assert_uint_gt(order[start[w]], order[start[w - 1]]);
            int e0 = -1, s0 = -1;
            for (size_t k = start[w]; k < start[w + 1]; k++) {
                char name[64];
                int e, sca;
                seen[order[k]]++;
                wf_survey_item_name(ctx, order[k], name, sizeof name);
                ck_assert_int_eq(sscanf(name, "exposure %d SCA %d", &e, &sca), 2);
                if (k > start[w]) {
                    ck_assert_int_eq(sca, s0);
                    ck_assert_int_eq(e, e0 + 1); /* the next exposure: consecutive in the plan */
                }
                e0 = e;
                s0 = sca;
            }
        }
        for (int i = 0; i < 30; i++) ck_assert_int_eq(seen[i], 1);
        free(order);
        free(start);
    }
    wf_survey_free(ctx);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("surveyrun");
    TCase *tc = tcase_create("all");
    tcase_set_timeout(tc, 300);
    tcase_add_test(tc, run_resume_and_independence);
    tcase_add_test(tc, resume_same_inputs_only);
    tcase_add_test(tc, resume_data_folder);
    tcase_add_test(tc, resume_catalogs_and_sne);
    tcase_add_test(tc, expose_digest);
    tcase_add_test(tc, bad_arguments);
    tcase_add_test(tc, parse_lists);
    tcase_add_test(tc, index_and_area);
    tcase_add_test(tc, mpi_matches_one_process);
    tcase_add_test(tc, isolate_crashed_item_lost_alone);
    tcase_add_test(tc, mpi_crashed_item_lost_alone);
    tcase_add_test(tc, history_cache_any_process);
    tcase_add_test(tc, walks_cover_items);
    tcase_add_test(tc, history_cache_mid_plan);
    tcase_add_test(tc, scene_cache_same_bytes);
    tcase_add_test(tc, scene_cache_with_supernovae);
    tcase_add_test(tc, scene_cache_cannot_keep);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
