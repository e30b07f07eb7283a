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
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
