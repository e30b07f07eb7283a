/* The deep-tier plan against every number of SPEC §6: visits, exposures per visit, orients,
 * exposure times, snake order, MJD spacing; the coverage areas; no overlap within a snake;
 * the FITS products; the `survey plan` command; bad parameters. Runs on the built-in focal
 * plane, and also on GalSim's files when ../shared/data is present. */
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "sim/fits/fitsout.h"
#include "sim/survey/survey.h"
#include "sim/survey/wcs.h"
#include "tests/testutil.h"
#include "tools/surveycmd.h"

#define DAY 86400.0
#define NPOINT 16
#define NFILT 4
#define NVISIT 146

static const char *const spec_filters[NFILT] = {"Y106", "J129", "H158", "F184"};
static const double spec_exptime[NFILT] = {300, 300, 300, 900};

/* fps[0] built-in, fps[1] GalSim's files (when present); returns how many. */
static int focal_planes(wf_focal_plane fps[2])
{
    wf_wcs_focal_plane_builtin(&fps[0]);
    const char *data = wf_test_data_dir();
    if (!data) {
        printf("NOTE: ../shared/data absent: survey checks run on the built-in focal plane only\n");
        return 1;
    }
    ck_assert_msg(wf_wcs_focal_plane_load(data, &fps[1]) == WF_OK, "%s", wf_error_message());
    return 2;
}

static void make_plan(const wf_focal_plane *fp, const char *const *sets, wf_survey_plan *plan)
{
    wf_survey_params p;
    wf_survey_defaults(&p);
    for (int i = 0; sets && sets[i]; i++)
        ck_assert_msg(wf_survey_set(&p, sets[i], NULL) == WF_OK, "%s", wf_error_message());
    ck_assert_msg(wf_survey_plan_make(&p, fp, plan) == WF_OK, "%s", wf_error_message());
}

START_TEST(defaults_are_spec)
{
    wf_survey_params p;
    wf_survey_defaults(&p);
    ck_assert_double_eq(p.ra, 71.0);
    ck_assert_double_eq(p.dec, -53.0);
    ck_assert_int_eq(p.visits, NVISIT);
    ck_assert_double_eq(p.visit_interval, 5.0);
    ck_assert_double_eq(p.orient_period, 30.0);
    ck_assert_double_eq(p.orient_step, 30.0);
    ck_assert_int_eq(p.ncolumns, 3);
    ck_assert_int_eq(p.column_count[0], 5);
    ck_assert_int_eq(p.column_count[1], 6);
    ck_assert_int_eq(p.column_count[2], 5);
    ck_assert_double_eq(p.row_step, 24.0);
    ck_assert_double_eq(p.column_step, 49.0);
    ck_assert_int_eq(p.nfilters, NFILT);
    ck_assert_int_eq(p.nexptime, NFILT);
    for (int f = 0; f < NFILT; f++) {
        ck_assert_str_eq(p.filters[f], spec_filters[f]);
        ck_assert_double_eq(p.exptime[f], spec_exptime[f]);
    }
    ck_assert_double_eq(p.slew_time, 50.0);
    ck_assert_double_eq(p.filter_change_time, 50.0);
    ck_assert_int_eq(wf_survey_check(&p), WF_OK);
}
END_TEST

/* The paper's steps are no smaller than the focal plane allows. */
START_TEST(layout_steps_fit_the_focal_plane)
{
    wf_focal_plane fps[2];
    int n = focal_planes(fps);
    for (int k = 0; k < n; k++) {
        double row, col;
        ck_assert_int_eq(wf_survey_min_steps(&fps[k], &row, &col), WF_OK);
        printf("%s focal plane: smallest non-overlapping steps %.3f' within a column, %.3f' "
               "between columns (plan: 24', 49')\n", fps[k].source, row, col);
        ck_assert_double_le(row, 24.0);
        ck_assert_double_ge(row, 23.5);
        ck_assert_double_le(col, 49.0);
        ck_assert_double_ge(col, 47.5);
    }
}
END_TEST

static void check_plan_numbers(const wf_focal_plane *fp)
{
    wf_survey_plan plan;
    make_plan(fp, NULL, &plan);
    const wf_survey_params *p = &plan.par;
    ck_assert_int_eq(plan.npointings, NPOINT);
    ck_assert_uint_eq(plan.nexp, (size_t)NVISIT * NPOINT * NFILT);
    ck_assert_int_eq(plan.norients, 25); /* 725 days / 30, plus the first */

    /* Layout: columns of 5, 6, 5 in snake order. */
    int per_col[3] = {0};
    for (int i = 0; i < NPOINT; i++) per_col[plan.column[i]]++;
    ck_assert(per_col[0] == 5 && per_col[1] == 6 && per_col[2] == 5);

    double last_visit_start = 0, worst_offset = 0;
    for (int v = 0; v < NVISIT; v++) {
        const wf_exposure *x = &plan.exp[(size_t)v * NPOINT * NFILT];
        /* Visits start every 5 days; the orient turns by 30 deg every 30 days. */
        ck_assert_double_eq_tol(x->mjd_start, p->mjd_start + 5.0 * v, 1e-9);
        int orient = (5 * v) / 30;
        for (int k = 0; k < NPOINT * NFILT; k++) {
            const wf_exposure *e = x + k;
            int pass = k / NPOINT, step = k % NPOINT;
            ck_assert_int_eq(e->id, v * NPOINT * NFILT + k);
            ck_assert_int_eq(e->visit, v);
            ck_assert_int_eq(e->orient, orient);
            ck_assert_double_eq_tol(e->orient_pa, fmod(30.0 * orient, 360.0), 1e-9);
            ck_assert_msg(fabs(remainder(e->pa - e->orient_pa, 360.0)) < 2.0,
                          "exposure %d: PA %.3f far from the orient's %.3f", e->id, e->pa,
                          e->orient_pa);
            /* Snake forward in Y and H, backward in J and F. */
            ck_assert_int_eq(e->pass, pass);
            ck_assert_int_eq(e->filter, pass);
            ck_assert_int_eq(e->pointing, pass % 2 == 0 ? step : NPOINT - 1 - step);
            ck_assert_double_eq(e->exptime, spec_exptime[pass]);
            ck_assert_double_eq_tol(e->mjd_mid, e->mjd_start + 0.5 * e->exptime / DAY, 1e-10);
            if (k > 0) {
                /* Exposure + slew (new pointing) or + filter change (same pointing). */
                const wf_exposure *prev = e - 1;
                double gap = (e->mjd_start - prev->mjd_start) * DAY - prev->exptime;
                double want = e->pointing != prev->pointing ? p->slew_time : p->filter_change_time;
                ck_assert_msg(fabs(gap - want) < 1e-3, "exposure %d: %.4f s after the previous "
                              "one ended, expected %.1f", e->id, gap, want);
                ck_assert_int_eq(e->pointing != prev->pointing, step != 0);
            }
            worst_offset = fmax(worst_offset, e->mjd_mid - x->mjd_start);
        }
        last_visit_start = x->mjd_start;
    }
    ck_assert_double_le(last_visit_start - p->mjd_start, 2 * 365.25);
    /* Every orient lasts 6 visits (30 days) except the last, reached after 24 turns. */
    ck_assert_int_eq(plan.exp[6 * NPOINT * NFILT - 1].orient, 0);
    ck_assert_int_eq(plan.exp[6 * NPOINT * NFILT].orient, 1);
    ck_assert_int_eq(plan.exp[plan.nexp - 1].orient, 24);

    /* Spacing on the sky: ~24' within a column, ~49' between the columns. */
    for (int i = 1; i < NPOINT; i++) {
        const wf_exposure *a = &plan.exp[i - 1], *b = &plan.exp[i];
        double sep = wf_wcs_separation(a->ra, a->dec, b->ra, b->dec) * 60.0;
        if (plan.column[i] == plan.column[i - 1])
            ck_assert_msg(fabs(sep - 24.0) < 0.05, "pointings %d-%d %.3f' apart", i - 1, i, sep);
    }
    printf("%s: %zu exposures; visit = %.4f d of exposures, slews and filter changes; "
           "largest exposure mid-time after the visit start %.4f d (%.0f s)\n", fp->source,
           plan.nexp, (plan.exp[63].mjd_start - plan.exp[0].mjd_start) + 900.0 / DAY,
           worst_offset, worst_offset * DAY);
    wf_survey_plan_free(&plan);
}

START_TEST(plan_reproduces_spec)
{
    wf_focal_plane fps[2];
    int n = focal_planes(fps);
    for (int k = 0; k < n; k++) check_plan_numbers(&fps[k]);
}
END_TEST

/* At the orient whose focal-plane v axis points north (observatory PA 240), the snake runs
 * south-east -> north-east, north -> south, south-west -> north-west (SPEC §6). */
START_TEST(snake_directions)
{
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    const char *sets[] = {"survey.pa0=240", "survey.visits=1", NULL};
    wf_survey_plan plan;
    make_plan(&fp, sets, &plan);
    double east[NPOINT], north[NPOINT];
    double d0 = plan.par.dec * M_PI / 180.0;
    for (int i = 0; i < NPOINT; i++) {
        const wf_exposure *e = &plan.exp[i];
        double dra = (e->ra - plan.par.ra) * M_PI / 180.0, d = e->dec * M_PI / 180.0;
        double c = sin(d0) * sin(d) + cos(d0) * cos(d) * cos(dra);
        east[i] = cos(d) * sin(dra) / c;
        north[i] = (cos(d0) * sin(d) - sin(d0) * cos(d) * cos(dra)) / c;
    }
    for (int i = 0; i < NPOINT; i++) {
        if (plan.column[i] == 0) ck_assert(east[i] > 0.01);               /* east column */
        if (plan.column[i] == 2) ck_assert(east[i] < -0.01);              /* west column */
        if (i > 0 && plan.column[i] == plan.column[i - 1]) {
            if (plan.column[i] == 1) ck_assert(north[i] < north[i - 1]);  /* north to south */
            else ck_assert(north[i] > north[i - 1]);                       /* south to north */
        }
    }
    /* Starts at the south-east corner. */
    for (int i = 1; i < 5; i++) ck_assert(north[0] < north[i]);
    wf_survey_plan_free(&plan);
}
END_TEST

START_TEST(no_overlap_within_a_snake)
{
    wf_focal_plane fps[2];
    int n = focal_planes(fps);
    for (int k = 0; k < n; k++) {
        wf_survey_plan plan;
        wf_survey_overlap ov;
        make_plan(&fps[k], NULL, &plan);
        ck_assert_int_eq(wf_survey_check_overlap(&plan, &fps[k], &ov), WF_OK);
        printf("%s: %d snakes (orients), %ld nearby SCA pairs of different pointings, %ld "
               "overlapping; smallest gap %.2f arcsec (orient %d)\n", fps[k].source, ov.orients,
               ov.pairs_checked, ov.overlapping, ov.min_gap, ov.worst_orient);
        ck_assert_int_eq(ov.orients, 25);
        ck_assert_int_eq(ov.overlapping, 0);
        ck_assert(ov.pairs_checked > 1000);
        ck_assert_double_gt(ov.min_gap, 0.0);
        wf_survey_plan_free(&plan);

        /* The check finds overlaps when there are some: columns packed below the minimum. */
        const char *tight[] = {"survey.row_step=23.5", NULL};
        make_plan(&fps[k], tight, &plan);
        ck_assert_int_eq(wf_survey_check_overlap(&plan, &fps[k], &ov), WF_OK);
        ck_assert_msg(ov.overlapping > 0, "23.5' steps should overlap");
        ck_assert_double_eq(ov.min_gap, 0.0);
        wf_survey_plan_free(&plan);
    }
}
END_TEST

START_TEST(coverage_areas)
{
    wf_focal_plane fps[2];
    int n = focal_planes(fps);
    for (int k = 0; k < n; k++) {
        wf_survey_plan plan;
        wf_survey_coverage cov;
        make_plan(&fps[k], NULL, &plan);
        ck_assert_msg(wf_survey_coverage_make(&plan, &fps[k], &cov) == WF_OK, "%s",
                      wf_error_message());
        ck_assert_int_eq(cov.nfilters, NFILT);
        ck_assert_int_eq(cov.threshold[3], 73);
        for (int f = 0; f < NFILT; f++) {
            printf("%s coverage %s (%dx%d cells of %.0f\"): >=1 %.3f deg2, >=10 %.3f, >=100 %.3f, "
                   ">=%d (half the visits) %.3f; max %d exposures\n", fps[k].source,
                   cov.filters[f], cov.nx, cov.ny, cov.pixel * 3600, cov.area[f][0],
                   cov.area[f][1], cov.area[f][2], cov.threshold[3], cov.area[f][3],
                   cov.max_count[f]);
            /* Footprints of one snake do not overlap: a cell is seen at most once per visit. */
            ck_assert_int_le(cov.max_count[f], NVISIT);
            ck_assert_double_eq_tol(cov.area[f][0], cov.area[0][0], 1e-12);
            /* "Well covered" (docs/SURVEY.md): seen in at least half the visits. */
            ck_assert_msg(fabs(cov.area[f][3] - 5.0) <= 0.5, "well-covered area %.3f deg2 is not "
                          "within 10%% of 5", cov.area[f][3]);
            /* Largest extent: the paper quotes ~8 deg2 for the disk the tiling sweeps. */
            ck_assert_double_ge(cov.area[f][0], 6.5);
            ck_assert_double_le(cov.area[f][0], 8.5);
            ck_assert_double_le(cov.area[f][2], cov.area[f][3]);
        }
        wf_survey_coverage_free(&cov);
        wf_survey_plan_free(&plan);
    }
}
END_TEST

/* ---- FITS products and the command -------------------------------------------------------- */

static void check_plan_file(const char *path, long nrows)
{
    fitsfile *f = NULL;
    int status = 0, col;
    long rows = 0, nvisits = 0;
    fits_open_file(&f, path, READONLY, &status);
    ck_assert_msg(status == 0, "%s: cfitsio %d", path, status);
    fits_read_key_lng(f, "NVISITS", &nvisits, NULL, &status);
    fits_movnam_hdu(f, BINARY_TBL, "PLAN", 0, &status);
    fits_get_num_rows(f, &rows, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(rows, nrows);
    int ok = 0, dok = 0;
    fits_verify_chksum(f, &dok, &ok, &status);
    ck_assert_int_eq(ok, 1);
    ck_assert_int_eq(dok, 1);
    fits_get_colnum(f, CASEINSEN, "EXPTIME", &col, &status);
    double t[NPOINT * NFILT];
    fits_read_col(f, TDOUBLE, col, 1, 1, NPOINT * NFILT, NULL, t, NULL, &status);
    char buf[NPOINT * NFILT][9], *names[NPOINT * NFILT];
    for (int i = 0; i < NPOINT * NFILT; i++) names[i] = buf[i];
    fits_get_colnum(f, CASEINSEN, "FILTER", &col, &status);
    fits_read_col(f, TSTRING, col, 1, 1, NPOINT * NFILT, NULL, names, NULL, &status);
    ck_assert_int_eq(status, 0);
    for (int i = 0; i < NPOINT * NFILT; i++) {
        ck_assert_double_eq(t[i], spec_exptime[i / NPOINT]);
        ck_assert_str_eq(names[i], spec_filters[i / NPOINT]);
    }
    fits_movnam_hdu(f, BINARY_TBL, "POINTINGS", 0, &status);
    fits_get_num_rows(f, &rows, &status);
    ck_assert_int_eq(rows, NPOINT);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

static void check_coverage_file(const char *path)
{
    fitsfile *f = NULL;
    int status = 0, nhdu = 0;
    fits_open_file(&f, path, READONLY, &status);
    fits_get_num_hdus(f, &nhdu, &status);
    ck_assert_int_eq(nhdu, 1 + NFILT);
    for (int k = 0; k < NFILT; k++) {
        double area = 0;
        fits_movnam_hdu(f, IMAGE_HDU, (char *)spec_filters[k], 0, &status);
        fits_read_key_dbl(f, "AREAHALF", &area, NULL, &status);
        ck_assert_msg(status == 0, "%s: HDU %s: cfitsio %d", path, spec_filters[k], status);
        ck_assert_double_gt(area, 0);
        int ok = 0, dok = 0;
        fits_verify_chksum(f, &dok, &ok, &status);
        ck_assert(ok == 1 && dok == 1);
    }
    fits_close_file(f, &status);
}

static int exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

START_TEST(fits_products)
{
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    wf_survey_plan plan;
    wf_survey_coverage cov;
    wf_survey_overlap ov;
    const char *sets[] = {"survey.visits=7", NULL};
    make_plan(&fp, sets, &plan);
    ck_assert_int_eq(wf_survey_check_overlap(&plan, &fp, &ov), WF_OK);
    ck_assert_int_eq(wf_survey_coverage_make(&plan, &fp, &cov), WF_OK);
    const char *dir = wf_test_tmpdir();
    char path[4200], cpath[4200], tmp[4300];
    snprintf(path, sizeof path, "%s/plan.fits", dir);
    snprintf(cpath, sizeof cpath, "%s/cov.fits", dir);
    ck_assert_msg(wf_survey_write_plan(&plan, &ov, path) == WF_OK, "%s", wf_error_message());
    ck_assert_msg(wf_survey_write_coverage(&cov, cpath) == WF_OK, "%s", wf_error_message());
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    ck_assert(!exists(tmp));
    check_plan_file(path, 7 * NPOINT * NFILT);
    check_coverage_file(cpath);

    /* An unwritable place: an error naming it, and no file. */
    snprintf(path, sizeof path, "%s/no/such/dir/plan.fits", dir);
    ck_assert_int_eq(wf_survey_write_plan(&plan, &ov, path), WF_ERR_IO);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "no/such/dir/plan.fits"));
    ck_assert(!exists(path));
    wf_survey_coverage_free(&cov);
    wf_survey_plan_free(&plan);
}
END_TEST

/* A copy of the plan at src with one change in its PLAN table, re-checksummed so that only
 * the change is wrong: RA of row 3 NaN (what = 0) or no MJD_START column (what = 1). */
static void altered_plan(const char *src, const char *dst, int what)
{
    size_t len;
    char *bytes = wf_test_slurp(src, &len);
    ck_assert_ptr_nonnull(bytes);
    FILE *out = fopen(dst, "wb");
    ck_assert(out && fwrite(bytes, 1, len, out) == len && fclose(out) == 0);
    free(bytes);
    fitsfile *f;
    int status = 0, col;
    fits_open_file(&f, dst, READWRITE, &status);
    fits_movnam_hdu(f, BINARY_TBL, "PLAN", 0, &status);
    if (what == 0) {
        double nan = NAN;
        fits_get_colnum(f, CASEINSEN, "RA", &col, &status);
        fits_write_col(f, TDOUBLE, col, 3, 1, 1, &nan, &status);
    } else {
        fits_get_colnum(f, CASEINSEN, "MJD_START", &col, &status);
        fits_delete_col(f, col, &status);
    }
    fits_write_chksum(f, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

/* wf_survey_read_plan gives back every exposure as written, and refuses a plan that is
 * missing, damaged, short of a column or holding a non-finite number, naming what. */
START_TEST(plan_read_back)
{
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    wf_survey_plan plan;
    const char *sets[] = {"survey.visits=2", NULL};
    make_plan(&fp, sets, &plan);
    const char *dir = wf_test_tmpdir();
    char path[4200], bad[4200];
    snprintf(path, sizeof path, "%s/plan.fits", dir);
    snprintf(bad, sizeof bad, "%s/bad.fits", dir);
    ck_assert_msg(wf_survey_write_plan(&plan, NULL, path) == WF_OK, "%s", wf_error_message());
    wf_survey_row *rows;
    size_t n;
    ck_assert_msg(wf_survey_read_plan(path, &rows, &n) == WF_OK, "%s", wf_error_message());
    ck_assert_uint_eq(n, plan.nexp);
    for (size_t i = 0; i < n; i++) {
        const wf_exposure *x = &plan.exp[i];
        const wf_survey_row *r = &rows[i];
        ck_assert(r->expid == x->id && r->visit == x->visit && r->orient == x->orient &&
                  r->pointing == x->pointing && r->pass == x->pass);
        ck_assert_str_eq(r->filter, plan.par.filters[x->filter]);
        /* doubles go through the file unchanged: compared exactly */
        ck_assert(r->ra == x->ra && r->dec == x->dec && r->pa == x->pa);
        ck_assert(r->mjd_start == x->mjd_start && r->mjd_mid == x->mjd_mid && r->exptime == x->exptime);
    }
    free(rows);

    snprintf(bad, sizeof bad, "%s/missing.fits", dir);
    ck_assert_int_eq(wf_survey_read_plan(bad, &rows, &n), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "missing.fits"));
    ck_assert_ptr_null(rows);

    /* one bit of the PLAN data flipped: its DATASUM no longer verifies */
    fitsfile *f;
    int status = 0;
    LONGLONG head, data, end;
    fits_open_file(&f, path, READONLY, &status);
    fits_movnam_hdu(f, BINARY_TBL, "PLAN", 0, &status);
    fits_get_hduaddrll(f, &head, &data, &end, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    snprintf(bad, sizeof bad, "%s/damaged.fits", dir);
    size_t len;
    char *bytes = wf_test_slurp(path, &len);
    ck_assert(bytes && (size_t)data + 10 < len);
    bytes[data + 10] ^= 1;
    FILE *out = fopen(bad, "wb");
    ck_assert(out && fwrite(bytes, 1, len, out) == len && fclose(out) == 0);
    free(bytes);
    ck_assert_int_eq(wf_survey_read_plan(bad, &rows, &n), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), "damaged.fits: not a plan whose checksums verify") &&
                  strstr(wf_error_message(), "section 2: DATASUM does not verify"), "%s", wf_error_message());

    snprintf(bad, sizeof bad, "%s/nan.fits", dir);
    altered_plan(path, bad, 0);
    ck_assert_int_eq(wf_survey_read_plan(bad, &rows, &n), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), "nan.fits: PLAN row 3 column RA is not finite"), "%s",
                  wf_error_message());
    ck_assert_ptr_null(rows);

    snprintf(bad, sizeof bad, "%s/short.fits", dir);
    altered_plan(path, bad, 1);
    ck_assert_int_eq(wf_survey_read_plan(bad, &rows, &n), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), "short.fits: PLAN table has no column MJD_START"), "%s",
                  wf_error_message());
    wf_survey_plan_free(&plan);
}
END_TEST

static void write_bytes(const char *path, const char *bytes, size_t len)
{
    FILE *out = fopen(path, "wb");
    ck_assert(out && fwrite(bytes, 1, len, out) == len && fclose(out) == 0);
}

/* Where each HDU of a file starts (head[h], data[h]) and its data ends, 1-based; returns the
 * HDU count cfitsio reports. */
static int hdu_layout(const char *path, LONGLONG head[4], LONGLONG data[4], LONGLONG end[4])
{
    fitsfile *f;
    int status = 0, nhdu = 0;
    fits_open_file(&f, path, READONLY, &status);
    fits_get_num_hdus(f, &nhdu, &status);
    for (int h = 1; h <= nhdu && h < 4; h++) {
        fits_movabs_hdu(f, h, NULL, &status);
        fits_get_hduaddrll(f, &head[h], &data[h], &end[h], &status);
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    return nhdu;
}

static void assert_refused(const char *path, int nhdu, const char *why)
{
    ck_assert_int_eq(wf_fits_verify_checksums(path, nhdu), WF_ERR_CORRUPT);
    ck_assert_msg(strstr(wf_error_message(), path) && strstr(wf_error_message(), why), "%s: got '%s'", why,
                  wf_error_message());
}

/* wf_fits_verify_checksums on a plan (3 sections): an intact file passes; one whose second
 * header cfitsio cannot parse (it then reports 1 section, so checksums alone pass), one cut
 * inside its last section or exactly between sections, or one with bytes appended, is refused
 * naming the file and the section. */
START_TEST(checksums_cover_the_whole_file)
{
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    wf_survey_plan plan;
    const char *sets[] = {"survey.visits=1", NULL};
    make_plan(&fp, sets, &plan);
    const char *dir = wf_test_tmpdir();
    char path[4200], bad[4200];
    snprintf(path, sizeof path, "%s/plan.fits", dir);
    ck_assert_msg(wf_survey_write_plan(&plan, NULL, path) == WF_OK, "%s", wf_error_message());
    wf_survey_plan_free(&plan);
    ck_assert_msg(wf_fits_verify_checksums(path, 0) == WF_OK, "%s", wf_error_message());
    ck_assert_msg(wf_fits_verify_checksums(path, 3) == WF_OK, "%s", wf_error_message());
    assert_refused(path, 4, "3 sections, expected 4");
    LONGLONG head[4], data[4], end[4];
    ck_assert_int_eq(hdu_layout(path, head, data, end), 3);
    size_t len;
    char *bytes = wf_test_slurp(path, &len);
    ck_assert_ptr_nonnull(bytes);
    ck_assert_int_eq((LONGLONG)len, end[3]);
    ck_assert(!memcmp(bytes + head[2], "XTENSION=", 9));

    /* the second section's first card no longer reads XTENSION= */
    snprintf(bad, sizeof bad, "%s/header2.fits", dir);
    memcpy(bytes + head[2], "XTENSIOM=", 9);
    write_bytes(bad, bytes, len);
    memcpy(bytes + head[2], "XTENSION=", 9);
    LONGLONG h2[4], d2[4], e2[4];
    ck_assert_int_eq(hdu_layout(bad, h2, d2, e2), 1); /* the blind spot being closed */
    assert_refused(bad, 0, "trailing bytes after section 1: damaged or truncated");
    wf_survey_row *rows;
    size_t n;
    ck_assert_int_eq(wf_survey_read_plan(bad, &rows, &n), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), "header2.fits: not a plan whose checksums verify") &&
                  strstr(wf_error_message(), "trailing bytes after section 1"), "%s", wf_error_message());

    /* the same in the last section */
    snprintf(bad, sizeof bad, "%s/header3.fits", dir);
    memcpy(bytes + head[3], "GARBAGE!!", 9);
    write_bytes(bad, bytes, len);
    memcpy(bytes + head[3], "XTENSION=", 9);
    assert_refused(bad, 0, "trailing bytes after section 2: damaged or truncated");

    /* cut in the middle of the last section's data */
    snprintf(bad, sizeof bad, "%s/cut.fits", dir);
    write_bytes(bad, bytes, (size_t)(data[3] + end[3]) / 2);
    assert_refused(bad, 0, "section 3 ends at byte");
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "truncated"));

    /* cut in the middle of the last section's header */
    snprintf(bad, sizeof bad, "%s/cuthead.fits", dir);
    write_bytes(bad, bytes, (size_t)head[3] + 100);
    assert_refused(bad, 0, "100 trailing bytes after section 2");

    /* cut exactly between sections 2 and 3: whole sections that verify, only the count tells */
    snprintf(bad, sizeof bad, "%s/cutedge.fits", dir);
    write_bytes(bad, bytes, (size_t)head[3]);
    ck_assert_msg(wf_fits_verify_checksums(bad, 0) == WF_OK, "%s", wf_error_message());
    assert_refused(bad, 3, "2 sections, expected 3");
    ck_assert_int_eq(wf_survey_read_plan(bad, &rows, &n), WF_ERR_INPUT); /* it knows the count */

    /* appended: a few bytes, and a whole block that is not a section */
    char *longer = malloc(len + 2880);
    ck_assert_ptr_nonnull(longer);
    memcpy(longer, bytes, len);
    memset(longer + len, 'x', 2880);
    snprintf(bad, sizeof bad, "%s/tail.fits", dir);
    write_bytes(bad, longer, len + 10);
    assert_refused(bad, 0, "10 trailing bytes after section 3");
    snprintf(bad, sizeof bad, "%s/block.fits", dir);
    write_bytes(bad, longer, len + 2880);
    assert_refused(bad, 3, "2880 trailing bytes after section 3");
    free(longer);

    /* a header damaged where cfitsio still parses it: the CHECKSUM names the section */
    snprintf(bad, sizeof bad, "%s/card.fits", dir);
    char *c = NULL; /* the EXTNAME value of section 3 (the data before it hold NUL bytes) */
    for (LONGLONG i = head[3]; i + 9 <= data[3] && !c; i++)
        if (!memcmp(bytes + i, "POINTINGS", 9)) c = bytes + i;
    ck_assert_ptr_nonnull(c);
    c[0] = 'Q';
    write_bytes(bad, bytes, len);
    assert_refused(bad, 0, "section 3: CHECKSUM does not verify");
    c[0] = 'P';

    snprintf(bad, sizeof bad, "%s/missing.fits", dir);
    ck_assert_int_eq(wf_fits_verify_checksums(bad, 0), WF_ERR_IO);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "missing.fits"));
    free(bytes);
}
END_TEST

START_TEST(survey_command)
{
    const char *dir = wf_test_tmpdir();
    char out[4200], cov[4200];
    snprintf(out, sizeof out, "%s/plan.fits", dir);
    snprintf(cov, sizeof cov, "%s/plan_coverage.fits", dir);
    char *argv[] = {"plan", "--quiet", "--data", "", "--out", out, "--set", "survey.visits=13",
                    NULL};
    ck_assert_int_eq(wf_cmd_survey(8, argv), 0);
    check_plan_file(out, 13 * NPOINT * NFILT);
    check_coverage_file(cov);

    /* Bad input: exit 2, a message, no product. */
    unlink(out);
    unlink(cov);
    char *bad[] = {"plan", "--quiet", "--data", "", "--out", out, "--set",
                   "survey.exptimes=300,300", NULL};
    ck_assert_int_eq(wf_cmd_survey(8, bad), 2);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "survey.exptimes"));
    ck_assert(!exists(out) && !exists(cov));
    char *nodata[] = {"plan", "--quiet", "--data", "/nonexistent", "--out", out, NULL};
    ck_assert_int_eq(wf_cmd_survey(6, nodata), 1);
    ck_assert(!exists(out) && !exists(cov));
    char *noout[] = {"plan", "--quiet", NULL};
    ck_assert_int_eq(wf_cmd_survey(2, noout), 2);
    char *unknown[] = {"frobnicate", NULL};
    ck_assert_int_eq(wf_cmd_survey(1, unknown), 2);
}
END_TEST

/* ---- parameters ------------------------------------------------------------------------------ */

static void expect_set_error(const char *assignment, wf_status code, const char *needle)
{
    wf_survey_params p, before;
    wf_survey_defaults(&p);
    before = p;
    wf_status st = wf_survey_set(&p, assignment, "test");
    ck_assert_msg(st == code, "'%s': expected %s, got %s (%s)", assignment, wf_status_name(code),
                  wf_status_name(st), wf_error_message());
    ck_assert_msg(strstr(wf_error_message(), needle), "'%s': message '%s' lacks '%s'", assignment,
                  wf_error_message(), needle);
    ck_assert_msg(!memcmp(&p, &before, sizeof p), "'%s' changed the parameters", assignment);
}

START_TEST(bad_parameters)
{
    expect_set_error("survey.bogus=1", WF_ERR_INPUT, "unknown survey key 'survey.bogus'");
    expect_set_error("survey.visits", WF_ERR_INPUT, "expected key=value");
    expect_set_error("survey.visits=", WF_ERR_INPUT, "no value");
    expect_set_error("survey.visits=0", WF_ERR_RANGE, "test: survey.visits: 0 is outside");
    expect_set_error("survey.visits=1.5", WF_ERR_INPUT, "not a whole number");
    expect_set_error("survey.visits=12x", WF_ERR_INPUT, "not a number");
    expect_set_error("survey.dec=-90", WF_ERR_RANGE, "survey.dec");
    expect_set_error("survey.ra=360", WF_ERR_RANGE, "[0, 360)");
    expect_set_error("survey.row_step=0", WF_ERR_RANGE, "survey.row_step");
    expect_set_error("survey.exptimes=300,-1", WF_ERR_RANGE, "survey.exptimes");
    expect_set_error("survey.exptimes=300,,900", WF_ERR_INPUT, "entry 2 is empty");
    expect_set_error("survey.filters=Y106,Y106", WF_ERR_INPUT, "listed twice");
    expect_set_error("survey.filters=Y1,J2,H3,F4,K5,W6,R7,Z8,X9", WF_ERR_RANGE, "more than 8");
    expect_set_error("survey.filters=TOOLONGNAME", WF_ERR_INPUT, "longer than 7");
    /* filters are read as every command reads them: a name that is none is refused here,
     * not when the plan is rendered; W149 is W146, so the two are one filter */
    expect_set_error("survey.filters=Y106,Q999", WF_ERR_INPUT, "unknown filter 'Q999'");
    expect_set_error("survey.filters=W146,w149", WF_ERR_INPUT, "'W146' listed twice");
    {
        wf_survey_params q;
        wf_survey_defaults(&q);
        ck_assert_int_eq(wf_survey_set(&q, "survey.filters=w149,y106", NULL), WF_OK);
        ck_assert_int_eq(q.nfilters, 2);
        ck_assert_str_eq(q.filters[0], "W146");
        ck_assert_str_eq(q.filters[1], "Y106");
    }
    expect_set_error("survey.columns=5,0,5", WF_ERR_RANGE, "survey.columns");

    /* Cross-key checks happen when the plan is made. */
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    wf_survey_params p;
    wf_survey_plan plan;
    wf_survey_defaults(&p);
    ck_assert_int_eq(wf_survey_set(&p, "survey.exptimes=300,300,900", NULL), WF_OK);
    ck_assert_int_eq(wf_survey_plan_make(&p, &fp, &plan), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "3 exposure times for 4 filters"));
    wf_survey_defaults(&p);
    ck_assert_int_eq(wf_survey_set(&p, "survey.visit_interval=0.2", NULL), WF_OK);
    ck_assert_int_eq(wf_survey_plan_make(&p, &fp, &plan), WF_ERR_RANGE);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "a visit takes 31950 s"));
    wf_survey_defaults(&p);
    ck_assert_int_eq(wf_survey_set(&p, "survey.columns=40,40,40,40,40,40,40", NULL), WF_OK);
    ck_assert_int_eq(wf_survey_plan_make(&p, &fp, &plan), WF_ERR_RANGE);

    /* Another strategy: 2 filters, 4 pointings, 10 visits, every 2 days. */
    wf_survey_defaults(&p);
    const char *other[] = {"survey.filters=J129,H158", "survey.exptimes=100,200",
                           "survey.columns=2,2", "survey.visits=10", "survey.visit_interval=2",
                           NULL};
    for (int i = 0; other[i]; i++) ck_assert_int_eq(wf_survey_set(&p, other[i], NULL), WF_OK);
    ck_assert_int_eq(wf_survey_plan_make(&p, &fp, &plan), WF_OK);
    ck_assert_uint_eq(plan.nexp, 10 * 4 * 2);
    ck_assert_double_eq_tol(plan.exp[8].mjd_start - plan.exp[0].mjd_start, 2.0, 1e-12);
    ck_assert_int_eq(plan.exp[4].pointing, 3); /* backward in the 2nd filter */
    wf_survey_plan_free(&plan);
}
END_TEST

START_TEST(key_documentation)
{
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    wf_survey_write_doc(f);
    fclose(f);
    const char *keys[] = {"survey.ra", "survey.visits", "survey.columns", "survey.row_step",
                          "survey.exptimes", "survey.slew_time", "survey.filter_change_time"};
    for (size_t i = 0; i < sizeof keys / sizeof keys[0]; i++)
        ck_assert_msg(strstr(buf, keys[i]), "%s missing from the key table", keys[i]);
    free(buf);
}
END_TEST

static Suite *survey_suite(void)
{
    Suite *s = suite_create("survey");
    TCase *tc = tcase_create("survey");
    tcase_set_timeout(tc, 300); /* sanitizer builds */
    tcase_add_test(tc, defaults_are_spec);
    tcase_add_test(tc, layout_steps_fit_the_focal_plane);
    tcase_add_test(tc, plan_reproduces_spec);
    tcase_add_test(tc, snake_directions);
    tcase_add_test(tc, no_overlap_within_a_snake);
    tcase_add_test(tc, coverage_areas);
    tcase_add_test(tc, fits_products);
    tcase_add_test(tc, plan_read_back);
    tcase_add_test(tc, checksums_cover_the_whole_file);
    tcase_add_test(tc, survey_command);
    tcase_add_test(tc, bad_parameters);
    tcase_add_test(tc, key_documentation);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(survey_suite()); }
