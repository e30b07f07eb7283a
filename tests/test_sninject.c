/* Supernova injection end to end: SNe placed on known pixels of a plan's exposure are drawn
 * through the survey run with every detector effect and the sky off; the image holds the flux
 * of the magnitude the light curve gives at the exposure's mid-time (computed here by the
 * model's direct 2-D path, not the injector's fast one), and each SN is in the truth of the
 * SCA it falls on and of no other. */
#include <fitsio.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/optics/bandpass.h"
#include "sim/sn/salt.h"
#include "sim/sn/sncat.h"
#include "sim/survey/wcs.h"
#include "tools/sninject.h"
#include "tests/testutil.h"

#define NOEFFECTS                                                                                    \
    "--set detector.effects.photon_noise=false --set detector.effects.reciprocity=false "           \
    "--set detector.effects.dark=false --set detector.effects.nonlinearity=false "                  \
    "--set detector.effects.ipc=false --set detector.effects.read_noise=false "                     \
    "--set detector.effects.quantize=false --set detector.effects.cosmic_rays=false "               \
    "--set scene.sky=false --set scene.flux_fraction=0.9999 "                                         \
    "--mode single"

/* A one-visit plan in d (*plan), the SALT model's folder (*model) and exposure 0's pointing. */
static void one_visit(const char *bin, const char *data, const char *d, char *plan, char *model, size_t cap,
                      double *ra, double *dec, double *pa, double *mjd)
{
    snprintf(plan, cap, "%s/plan.fits", d);
    snprintf(model, cap, "%s/salt3/salt3-k21", data);
    ck_assert_int_eq(wf_test_run("%s survey plan --quiet --data %s --set survey.visits=1 --out %s", bin, data, plan), 0);
    wf_test_plan_row0(plan, ra, dec, pa, mjd);
}

static double image_sum(const char *path)
{
    fitsfile *f;
    int status = 0;
    fits_open_file(&f, path, READONLY, &status);
    fits_movnam_hdu(f, IMAGE_HDU, "SCI", 0, &status);
    long n[2] = {0, 0};
    fits_get_img_size(f, 2, n, &status);
    float *pix = malloc((size_t)(n[0] * n[1]) * sizeof *pix);
    fits_read_img(f, TFLOAT, 1, n[0] * n[1], NULL, pix, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    double s = 0;
    for (long i = 0; i < n[0] * n[1]; i++) s += pix[i];
    free(pix);
    return s;
}

/* The SNE rows of a truth file: ids, and MAG and FLUX of the first. */
static int truth_sne(const char *path, long long *ids, int max, double *mag, double *flux)
{
    fitsfile *f;
    int status = 0, c;
    long n = 0;
    fits_open_file(&f, path, READONLY, &status);
    fits_movnam_hdu(f, BINARY_TBL, "SNE", 0, &status);
    fits_get_num_rows(f, &n, &status);
    ck_assert_int_eq(status, 0);
    for (long r = 1; r <= n && r <= max; r++) {
        fits_get_colnum(f, CASEINSEN, "ID", &c, &status);
        fits_read_col(f, TLONGLONG, c, r, 1, 1, NULL, &ids[r - 1], NULL, &status);
    }
    if (n > 0) {
        fits_get_colnum(f, CASEINSEN, "MAG", &c, &status);
        fits_read_col(f, TDOUBLE, c, 1, 1, 1, NULL, mag, NULL, &status);
        fits_get_colnum(f, CASEINSEN, "FLUX", &c, &status);
        fits_read_col(f, TDOUBLE, c, 1, 1, 1, NULL, flux, NULL, &status);
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    return (int)n;
}

START_TEST(injected_flux_and_truth)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the Roman and SALT data");
    const char *d = wf_test_tmpdir();
    char plan[4200], model[4200], sne[4200], stars[4200];
    double ra, dec, pa, mjd; /* exposure 0: Y106 */
    one_visit(bin, data, d, plan, model, sizeof plan, &ra, &dec, &pa, &mjd);
    snprintf(sne, sizeof sne, "%s/sne.fits", d);
    snprintf(stars, sizeof stars, "%s/stars.csv", d);

    /* SN 41 on SCA 1 at pixel (60.3, 50.6) (0-based), SN 42 on SCA 2 at (20.7, 90.2) */
    wf_focal_plane fp;
    wf_wcs w1, w2;
    ck_assert_int_eq(wf_wcs_focal_plane(data, &fp), 0);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, ra, dec, pa, 1, &w1), 0);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, ra, dec, pa, 2, &w2), 0);
    wf_sn_sample s;
    memset(&s, 0, sizeof s);
    snprintf(s.model, sizeof s.model, "salt3-k21");
    const double z[2] = {0.5, 0.9}, dt[2] = {3.0, -12.0};
    for (int k = 0; k < 2; k++) {
        size_t r;
        ck_assert_int_eq(wf_sn_sample_push(&s, &r), 0);
        s.id[r] = 41 + k;
        s.host_id[r] = -1;
        s.host_comp[r] = -1;
        s.flags[r] = WF_SN_FLAG_HOSTLESS;
        s.z[r] = z[k];
        s.t0[r] = mjd + dt[k];
        s.x1[r] = 0.3;
        s.c[r] = -0.05;
        s.mu[r] = k ? 43.85 : 42.27;
        s.x0[r] = pow(10.0, -0.4 * (s.mu[r] - 0.14 * 0.3 + 3.1 * -0.05)) / 1e-12;
        ck_assert_int_eq(wf_wcs_pix2world(k ? &w2 : &w1, k ? 20.7 : 60.3, k ? 90.2 : 50.6, &s.ra[r], &s.dec[r]), 0);
    }
    ck_assert_int_eq(wf_sn_sample_write(&s, sne), 0);
    /* the scene's only catalog object lies far off every SCA */
    FILE *f = fopen(stars, "w");
    ck_assert_ptr_nonnull(f);
    fprintf(f, "id,ra,dec,mag_Y106,mag_J129,mag_H158,mag_F184\n1,%.6f,%.6f,20,20,20,20\n", fmod(ra + 20.0, 360.0), dec);
    fclose(f);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --data %s --plan %s --exposures 0 --scas 1,2,3 --sne %s --model %s "
                         "--set scene.kind=catalog --stars %s " NOEFFECTS " --set readout.ncols=128 --set readout.nrows=128 --out %s/out",
                         bin, data, plan, sne, model, stars, d), 0);

    /* the magnitude by the model's direct path at the exposure's mid-time */
    wf_salt_model *m;
    wf_bandpass bp;
    ck_assert_int_eq(wf_salt_load(model, &m), 0);
    ck_assert_int_eq(wf_bandpass_load(WF_Y106, data, &bp), 0);
    for (int k = 0; k < 2; k++) {
        wf_salt_params p = {s.z[k], s.t0[k], s.x0[k], s.x1[k], s.c[k]};
        double mag, rate;
        unsigned flags;
        ck_assert_int_eq(wf_salt_bandmag(m, &p, WF_SALT_INTERP_BICUBIC, &bp, mjd, &mag, &flags), 0);
        ck_assert_int_eq(flags, 0);
        rate = wf_bandpass_countrate_ab(&bp, mag);
        char img[4200], truth[4200];
        snprintf(img, sizeof img, "%s/out/wfisim_e000000_sca%02d.fits", d, k + 1);
        snprintf(truth, sizeof truth, "%s/out/wfisim_e000000_sca%02d_truth.fits", d, k + 1);
        long long ids[4];
        double tmag = NAN, tflux = NAN;
        ck_assert_int_eq(truth_sne(truth, ids, 4, &tmag, &tflux), 1);
        ck_assert_int_eq(ids[0], 41 + k);
        ck_assert_double_eq_tol(tmag, mag, 1e-4);
        ck_assert_double_eq_tol(tflux / rate, 1.0, 1e-4);
        double sum = image_sum(img);
        /* the stamp holds >= 99.99% of the light; the SN is > 30 px from every edge */
        /* the stamp holds 99.99%; SN 42 sits 20 px from the image's edge, past which its PSF
         * wings (1.6e-3 of the light, measured) fall off the image */
        ck_assert_msg(fabs(sum / rate - 1.0) < (k ? 2.5e-3 : 5e-4), "SN %d: image holds %.6g e-/s, light curve %.6g", 41 + k, sum,
                      rate);
    }
    /* SCA 3 holds neither */
    char truth3[4200];
    snprintf(truth3, sizeof truth3, "%s/out/wfisim_e000000_sca03_truth.fits", d);
    long long ids[4];
    double tmag, tflux;
    ck_assert_int_eq(truth_sne(truth3, ids, 4, &tmag, &tflux), 0);

    /* the observed light curves list the same (SN, image) pairs for exposure 0 */
    char lc[4200];
    snprintf(lc, sizeof lc, "%s/lc.fits", d);
    ck_assert_int_eq(wf_test_run("%s sn lightcurves --data %s --sne %s --model %s --plan %s --out %s >/dev/null", bin, data, sne,
                         model, plan, lc), 0);
    fitsfile *ff;
    int status = 0, ce, cs, ci;
    long nrows = 0;
    fits_open_file(&ff, lc, READONLY, &status);
    fits_movnam_hdu(ff, BINARY_TBL, "LIGHTCURVES", 0, &status);
    fits_get_num_rows(ff, &nrows, &status);
    fits_get_colnum(ff, CASEINSEN, "EXPID", &ce, &status);
    fits_get_colnum(ff, CASEINSEN, "SCA", &cs, &status);
    fits_get_colnum(ff, CASEINSEN, "ID", &ci, &status);
    int seen = 0;
    for (long r = 1; r <= nrows && !status; r++) {
        int e, sca;
        long long id;
        fits_read_col(ff, TINT, ce, r, 1, 1, NULL, &e, NULL, &status);
        fits_read_col(ff, TINT, cs, r, 1, 1, NULL, &sca, NULL, &status);
        fits_read_col(ff, TLONGLONG, ci, r, 1, 1, NULL, &id, NULL, &status);
        if (e != 0) continue;
        ck_assert_msg((id == 41 && sca == 1) || (id == 42 && sca == 2), "exposure 0: SN %lld on SCA %d", id, sca);
        seen |= id == 41 ? 1 : 2;
    }
    fits_close_file(ff, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(seen, 3);
    wf_salt_free(m);
    wf_sn_sample_free(&s);
}
END_TEST

/* The IDs of one table of a FITS file (0 when it has none); *ids malloc'd. */
static long table_ids(const char *path, const char *table, long long **ids)
{
    fitsfile *f;
    int status = 0, c;
    long n = 0;
    *ids = NULL;
    fits_open_file(&f, path, READONLY, &status);
    ck_assert_msg(status == 0, "%s: cannot open", path);
    if (fits_movnam_hdu(f, BINARY_TBL, (char *)table, 0, &status)) {
        status = 0;
        fits_close_file(f, &status);
        return 0;
    }
    fits_get_num_rows(f, &n, &status);
    fits_get_colnum(f, CASEINSEN, "ID", &c, &status);
    *ids = malloc((size_t)(n ? n : 1) * sizeof **ids);
    if (n) fits_read_col(f, TLONGLONG, c, 1, 1, n, NULL, *ids, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_msg(status == 0, "%s[%s]: cannot read ID", path, table);
    return n;
}

static int cmp_ll(const void *a, const void *b)
{
    long long x = *(const long long *)a, y = *(const long long *)b;
    return (x > y) - (x < y);
}

/* `survey run --sne` over an area writes the release: every object in any product's truth is
 * in the input catalogs, every SN in sne.fits, the light curves are those `wfisim sn
 * lightcurves` writes for the plan, and the index lists the products. */
START_TEST(release_layout)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the Roman and SALT data");
    const char *d = wf_test_tmpdir();
    char plan[4200], model[4200], sne[4200], out[4200], path[4400], lc[4200];
    double ra, dec, pa, mjd;
    one_visit(bin, data, d, plan, model, sizeof plan, &ra, &dec, &pa, &mjd);
    snprintf(sne, sizeof sne, "%s/sample.fits", d);
    snprintf(out, sizeof out, "%s/release", d);
    wf_focal_plane fp;
    wf_wcs w;
    ck_assert_int_eq(wf_wcs_focal_plane(data, &fp), 0);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, ra, dec, pa, 1, &w), 0);
    wf_sn_sample s;
    memset(&s, 0, sizeof s);
    snprintf(s.model, sizeof s.model, "salt3-k21");
    size_t r;
    ck_assert_int_eq(wf_sn_sample_push(&s, &r), 0);
    s.id[r] = 77;
    s.host_id[r] = -1;
    s.host_comp[r] = -1;
    s.flags[r] = WF_SN_FLAG_HOSTLESS;
    s.z[r] = 0.4;
    s.t0[r] = mjd;
    s.x1[r] = 0.0;
    s.c[r] = 0.0;
    s.mu[r] = 41.6;
    s.x0[r] = pow(10.0, -0.4 * s.mu[r]) / 1e-12;
    ck_assert_int_eq(wf_wcs_pix2world(&w, 60.0, 70.0, &s.ra[r], &s.dec[r]), 0);
    ck_assert_int_eq(wf_sn_sample_write(&s, sne), 0);
    wf_sn_sample_free(&s);
    /* the area: 0.02 deg about the small SCA 1's centre at exposure 0's pointing */
    double ara, adec;
    ck_assert_int_eq(wf_wcs_pix2world(&w, 63.5, 63.5, &ara, &adec), 0);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --data %s --plan %s --exposures 0:4 --scas 1,2 --sne %s --model %s "
                                 "--area %.8f,%.8f,0.02 --mode single --set readout.ncols=128 --set readout.nrows=128 "
                                 "--set detector.cr_rate=0 --out %s", bin, data, plan, sne, model, ara, adec, out), 0);
    /* the index lists every product made, and exposure 0's SCA 1 is one of them */
    snprintf(path, sizeof path, "%s/survey_index.csv", out);
    char *idx = wf_test_slurp(path, NULL);
    ck_assert_ptr_nonnull(idx);
    ck_assert_msg(strstr(idx, "\n0,1,Y106,") != NULL, "exposure 0 SCA 1 not indexed:\n%s", idx);
    int rows = -1;
    for (const char *p = idx; *p; p++) rows += *p == '\n';
    free(idx);
    ck_assert_int_eq(wf_test_run("test $(ls %s | grep -c '^wfisim_e.*_sca.._truth.fits$') -eq %d", out, rows), 0);
    ck_assert_int_eq(wf_test_run("test ! -e %s/wfisim_e000000_sca02.fits", out), 0); /* SCA 2 is off the area */
    /* every object of every truth table is in the catalogs of the release */
    long long *gal, *stars, *sn;
    char gpath[4400], spath[4400], npath[4400];
    snprintf(gpath, sizeof gpath, "%s/input_galaxies.fits", out);
    snprintf(spath, sizeof spath, "%s/input_stars.fits", out);
    snprintf(npath, sizeof npath, "%s/sne.fits", out);
    long ngal = table_ids(gpath, "GALAXIES", &gal), nstars = table_ids(spath, "STARS", &stars), nsn = table_ids(npath, "SNE", &sn);
    ck_assert_msg(ngal > 0 && ngal < 1000000, "%ld galaxies in the release catalog", ngal);
    ck_assert_int_eq(nsn, 1);
    qsort(gal, (size_t)ngal, sizeof *gal, cmp_ll);
    qsort(stars, (size_t)nstars, sizeof *stars, cmp_ll);
    long checked = 0, sne_seen = 0;
    for (int e = 0; e <= 4; e++)
        for (int sca = 1; sca <= 2; sca++) {
            snprintf(path, sizeof path, "%s/wfisim_e%06d_sca%02d_truth.fits", out, e, sca);
            FILE *probe = fopen(path, "rb");
            if (!probe) continue;
            fclose(probe);
            const char *tables[3] = {"GALAXIES", "STARS", "SNE"};
            for (int t = 0; t < 3; t++) {
                long long *ids;
                long n = table_ids(path, tables[t], &ids);
                for (long i = 0; i < n; i++) {
                    long long *list = t == 0 ? gal : t == 1 ? stars : sn;
                    long len = t == 0 ? ngal : t == 1 ? nstars : nsn;
                    ck_assert_msg(bsearch(&ids[i], list, (size_t)len, sizeof *list, cmp_ll) != NULL,
                                  "%s: %s %lld is not in the release's catalogs", path, tables[t], ids[i]);
                    checked++;
                    sne_seen += t == 2;
                }
                free(ids);
            }
        }
    ck_assert_msg(checked > 10 && sne_seen >= 1, "%ld objects, %ld SNe in the truth tables", checked, sne_seen);
    free(gal);
    free(stars);
    free(sn);
    /* the light curves: those of `wfisim sn lightcurves` for the same sample and plan */
    snprintf(lc, sizeof lc, "%s/lc.fits", d);
    ck_assert_int_eq(wf_test_run("%s sn lightcurves --data %s --sne %s --model %s --plan %s --out %s >/dev/null", bin, data,
                                 sne, model, plan, lc), 0);
    snprintf(path, sizeof path, "%s/sn_lightcurves.fits", out);
    ck_assert_int_eq(wf_test_run("cmp -s %s %s", lc, path), 0);
    snprintf(path, sizeof path, "%s/survey_run.txt", out);
    ck_assert(wf_test_file_contains(path, "release.sne = sne.fits, sn_lightcurves.fits"));
}
END_TEST

/* The injector's light-curve slope (for the up-the-ramp reads) against the model's direct
 * path: d ln f / dt = -0.4 ln 10 dm/dt, dm/dt by a central difference over +-0.5 d. */
START_TEST(injector_slope)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "the Roman and SALT data");
    const char *d = wf_test_tmpdir();
    char model[4200], sne[4200];
    snprintf(model, sizeof model, "%s/salt3/salt3-k21", data);
    snprintf(sne, sizeof sne, "%s/one.fits", d);
    wf_sn_sample s;
    memset(&s, 0, sizeof s);
    size_t r;
    ck_assert_int_eq(wf_sn_sample_push(&s, &r), 0);
    s.id[r] = 1, s.host_id[r] = -1, s.z[r] = 0.6, s.t0[r] = 61500.0, s.x1[r] = 0.5, s.c[r] = 0.02;
    s.x0[r] = 2e-5, s.ra[r] = 71.0, s.dec[r] = -53.0;
    ck_assert_int_eq(wf_sn_sample_write(&s, sne), 0);
    wf_sn_injector *inj;
    ck_assert_int_eq(wf_sn_injector_open(sne, model, data, &inj), 0);
    wf_skyregion reg;
    ck_assert_int_eq(wf_skyindex_circle(71.0, -53.0, 0.01, 0.0, &reg), 0);
    wf_salt_model *m;
    wf_bandpass bp;
    ck_assert_int_eq(wf_salt_load(model, &m), 0);
    ck_assert_int_eq(wf_bandpass_load(WF_J129, data, &bp), 0);
    wf_salt_params p = {0.6, 61500.0, 2e-5, 0.5, 0.02};
    const double dates[3] = {61480.0, 61500.0, 61510.0}; /* rising, peak, fading (before the
                                                          * rest-frame I secondary maximum) */
    for (int k = 0; k < 3; k++) {
        wf_scene_sn *v;
        size_t n;
        ck_assert_int_eq(wf_sn_injector_select(inj, "J129", dates[k], &reg, &v, &n), 0);
        ck_assert_uint_eq(n, 1);
        double m1, m2;
        unsigned f1, f2;
        ck_assert_int_eq(wf_salt_bandmag(m, &p, WF_SALT_INTERP_BICUBIC, &bp, dates[k] - 0.5, &m1, &f1), 0);
        ck_assert_int_eq(wf_salt_bandmag(m, &p, WF_SALT_INTERP_BICUBIC, &bp, dates[k] + 0.5, &m2, &f2), 0);
        double want = -0.4 * log(10.0) * (m2 - m1) / 86400.0;
        ck_assert_msg(fabs(v[0].dlnf_dt - want) < 0.05 * fabs(want) + 1e-9,
                      "MJD %.0f: slope %.4g /s, the model's %.4g /s", dates[k], v[0].dlnf_dt, want);
        if (k == 0) ck_assert(v[0].dlnf_dt > 0); /* rising */
        if (k == 2) ck_assert(v[0].dlnf_dt < 0); /* fading */
        free(v);
    }
    wf_salt_free(m);
    wf_sn_injector_free(inj);
    wf_sn_sample_free(&s);
}
END_TEST

/* 3,000 SNe on one 256² SCA (the same injection path as one SN): every one is in the truth,
 * and the image holds the sum of their light-curve fluxes. */
START_TEST(thousands_on_one_sca)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the Roman and SALT data");
    const char *d = wf_test_tmpdir();
    char model[4200], sne[4200], stars[4200], truth[4200], img[4200];
    snprintf(model, sizeof model, "%s/salt3/salt3-k21", data);
    snprintf(sne, sizeof sne, "%s/many.fits", d);
    snprintf(stars, sizeof stars, "%s/stars.csv", d);
    const double ra0 = 71.0, dec0 = -53.0, pa = 30.0, mjd = 61500.0;
    wf_focal_plane fp;
    wf_wcs w;
    ck_assert_int_eq(wf_wcs_focal_plane(data, &fp), 0);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, ra0, dec0, pa, 1, &w), 0);
    wf_sn_sample s;
    memset(&s, 0, sizeof s);
    enum { NSN = 3000 };
    unsigned seed = 7;
    for (int k = 0; k < NSN; k++) {
        size_t r;
        ck_assert_int_eq(wf_sn_sample_push(&s, &r), 0);
        seed = seed * 1103515245u + 12345u;
        double x = 8 + 240.0 * ((seed >> 8) & 0xffff) / 65536.0;
        seed = seed * 1103515245u + 12345u;
        double y = 8 + 240.0 * ((seed >> 8) & 0xffff) / 65536.0;
        s.id[r] = k + 1, s.host_id[r] = -1, s.z[r] = 0.3 + 0.5 * k / NSN, s.t0[r] = mjd - 5 + 10.0 * k / NSN;
        s.x0[r] = 1e-4, s.x1[r] = 0, s.c[r] = 0;
        ck_assert_int_eq(wf_wcs_pix2world(&w, x, y, &s.ra[r], &s.dec[r]), 0);
    }
    ck_assert_int_eq(wf_sn_sample_write(&s, sne), 0);
    FILE *f = fopen(stars, "w");
    ck_assert_ptr_nonnull(f);
    fprintf(f, "id,ra,dec,mag_Y106\n1,%.6f,%.6f,20\n", fmod(ra0 + 20.0, 360.0), dec0);
    fclose(f);
    ck_assert_int_eq(wf_test_run("%s expose --quiet --data %s --sne %s --model %s --ra %g --dec %g --pa %g --mjd %g --sca 1 "
                         "--filter Y106 --set scene.kind=catalog --stars %s " NOEFFECTS " --set readout.ncols=256 "
                         "--set readout.nrows=256 --set scene.flux_fraction=0.995 --out %s/out", bin, data, sne, model,
                         ra0, dec0, pa, mjd, stars, d), 0);
    snprintf(truth, sizeof truth, "%s/out/wfisim_e000001_sca01_truth.fits", d);
    snprintf(img, sizeof img, "%s/out/wfisim_e000001_sca01.fits", d);
    fitsfile *ff;
    int status = 0, cf;
    long nrows = 0;
    fits_open_file(&ff, truth, READONLY, &status);
    fits_movnam_hdu(ff, BINARY_TBL, "SNE", 0, &status);
    fits_get_num_rows(ff, &nrows, &status);
    fits_get_colnum(ff, CASEINSEN, "FLUX", &cf, &status);
    double total = 0;
    for (long r = 1; r <= nrows && !status; r++) {
        double fl;
        fits_read_col(ff, TDOUBLE, cf, r, 1, 1, NULL, &fl, NULL, &status);
        total += fl;
    }
    fits_close_file(ff, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(nrows, NSN);
    /* each stamp keeps >= 99.5% of its SN; those within a stamp radius of an edge lose some of
     * that stamp to the edge, so the image holds a little less */
    double sum = image_sum(img);
    printf("3000 SNe: the image holds %.5f of their flux\n", sum / total);
    ck_assert_msg(sum / total > 0.98 && sum / total <= 1.0 + 1e-4, "image %.6g e-/s, truth %.6g", sum, total);
    wf_sn_sample_free(&s);
}
END_TEST

START_TEST(sample_roundtrip_and_bad_values)
{
    const char *d = wf_test_tmpdir();
    char path[4200];
    snprintf(path, sizeof path, "%s/s.fits", d);
    wf_sn_sample s, t;
    memset(&s, 0, sizeof s);
    for (int k = 0; k < 3; k++) {
        size_t r;
        ck_assert_int_eq(wf_sn_sample_push(&s, &r), 0);
        s.id[r] = 7 + k, s.z[r] = 0.1 * (k + 1), s.x0[r] = 1e-5, s.ra[r] = 71, s.dec[r] = -53 + 0.01 * k;
        s.host_id[r] = k == 1 ? -1 : 1000 + k;
    }
    ck_assert_int_eq(wf_sn_sample_write(&s, path), 0);
    ck_assert_int_eq(wf_sn_sample_read(path, &t), 0);
    ck_assert_uint_eq(t.n, 3);
    for (int k = 0; k < 3; k++) {
        ck_assert(t.id[k] == s.id[k] && t.host_id[k] == s.host_id[k]);
        ck_assert(t.z[k] == s.z[k] && t.dec[k] == s.dec[k]);
    }
    wf_sn_sample_free(&t);
    s.z[2] = -0.5;
    ck_assert_int_eq(wf_sn_sample_write(&s, path), 0);
    ck_assert_int_ne(wf_sn_sample_read(path, &t), 0);
    ck_assert_msg(strstr(wf_error_message(), "row 3") != NULL, "%s", wf_error_message());
    s.z[2] = NAN;
    ck_assert_int_eq(wf_sn_sample_write(&s, path), 0);
    ck_assert_int_ne(wf_sn_sample_read(path, &t), 0);
    ck_assert_msg(strstr(wf_error_message(), "Z") != NULL, "%s", wf_error_message());
    wf_sn_sample_free(&s);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("sninject");
    TCase *tc = tcase_create("all");
    tcase_set_timeout(tc, 300);
    tcase_add_test(tc, injected_flux_and_truth);
    tcase_add_test(tc, sample_roundtrip_and_bad_values);
    tcase_add_test(tc, injector_slope);
    tcase_add_test(tc, thousands_on_one_sca);
    tcase_add_test(tc, release_layout);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
