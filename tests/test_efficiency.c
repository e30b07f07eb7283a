/* wfisim efficiency (analysis/efficiency.c, analysis/effstats.c): the Wilson interval against
 * closed forms; the curve fit on objects found with a known probability (m50 and its error);
 * one-to-one matching; counts on synthetic images, catalogs and truth tables built here; the
 * SNANA map; bad input; and end to end on a wfisim exposure of a star field, m50 against the
 * depth the image's own ERR and star profiles predict. */
#include <fitsio.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "analysis/detect.h"
#include "analysis/efficiency.h"
#include "sim/sn/sncat.h"
#include "sim/survey/wcs.h"
#include "tests/testutil.h"

/* SEP 1.2.0 leaks 8 bytes per object in sep_extract (see tests/test_detect.c). */
const char *__lsan_default_suppressions(void);
const char *__lsan_default_suppressions(void) { return "leak:libsep.so\n"; }

/* ---- a small deterministic generator (splitmix64) ---- */
static uint64_t rng_state;
static double uniform(void)
{
    uint64_t z = (rng_state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    z ^= z >> 31;
    return (double)(z >> 11) * 0x1.0p-53;
}

/* ---- Wilson interval ---- */

START_TEST(wilson_closed_form)
{
    double lo, hi;
    /* k = 5 of 10 at z = 1: centre 5.5/11 = 1/2, half-width sqrt(2.75)/11 */
    wf_eff_wilson(5, 10, 1.0, &lo, &hi);
    ck_assert_double_eq_tol(lo, 0.5 - sqrt(2.75) / 11, 1e-12);
    ck_assert_double_eq_tol(hi, 0.5 + sqrt(2.75) / 11, 1e-12);
    /* none found: [0, z^2 / (n + z^2)]; all found: [n / (n + z^2), 1] */
    wf_eff_wilson(0, 10, 1.0, &lo, &hi);
    ck_assert_double_eq(lo, 0.0);
    ck_assert_double_eq_tol(hi, 1.0 / 11, 1e-12);
    wf_eff_wilson(40, 40, 2.0, &lo, &hi);
    ck_assert_double_eq_tol(lo, 40.0 / 44, 1e-12);
    ck_assert_double_eq(hi, 1.0);
    wf_eff_wilson(0, 0, 1.0, &lo, &hi);
    ck_assert(lo == 0.0 && hi == 1.0);
    /* the defining property: each end p solves (k/n - p)^2 = z^2 p (1 - p) / n */
    const double zs[3] = {1.0, 1.6448536, 1.959964};
    for (int zi = 0; zi < 3; zi++)
        for (long n = 1; n <= 60; n += 7)
            for (long k = 0; k <= n; k++) {
                wf_eff_wilson(k, n, zs[zi], &lo, &hi);
                double ends[2] = {lo, hi}, f = (double)k / n;
                ck_assert(lo <= f && f <= hi && lo >= 0 && hi <= 1);
                for (int e = 0; e < 2; e++) {
                    double p = ends[e];
                    ck_assert_double_eq_tol((f - p) * (f - p), zs[zi] * zs[zi] * p * (1 - p) / n, 1e-12);
                }
            }
}
END_TEST

/* ---- the curve fit ---- */

static double truth_curve(double m, double m50, double w, double p)
{
    return p / (1 + exp((m - m50) / w + log(2 * p - 1)));
}

static void simulate(long n, double m50, double w, double p, double *mag, unsigned char *found)
{
    for (long i = 0; i < n; i++) {
        mag[i] = 20 + 6 * uniform();
        found[i] = uniform() < truth_curve(mag[i], m50, w, p);
    }
}

/* Objects found with a known probability: the fitted m50 scatters about the truth as its
 * error says (the pulls of 300 samples have mean ~0 and rms ~1), and a large sample lands
 * within 3 sigma of the true m50, width and plateau. */
START_TEST(fit_recovers_m50)
{
    enum { N = 800, REPS = 300 };
    static double mag[40000];
    static unsigned char found[40000];
    const double m50 = 23.4, w = 0.25, p = 0.93;
    rng_state = 12345;
    double sum = 0, sum2 = 0, err_sum = 0;
    for (int r = 0; r < REPS; r++) {
        simulate(N, m50, w, p, mag, found);
        wf_eff_fit fit;
        ck_assert_int_eq(wf_eff_fit_curve(mag, found, N, &fit), WF_OK);
        ck_assert(fit.ok);
        double pull = (fit.m50 - m50) / fit.m50_err;
        sum += pull, sum2 += pull * pull, err_sum += fit.m50_err;
    }
    double mean = sum / REPS, rms = sqrt(sum2 / REPS);
    printf("fit of %d samples of %d objects (m50 %.2f, width %.2f, plateau %.2f): pulls mean %.3f rms %.3f, "
           "mean error %.4f mag\n", REPS, N, m50, w, p, mean, rms, err_sum / REPS);
    /* the mean of 300 unit pulls has sigma 0.058, their rms ~0.04 (400 samples of another
     * seed: mean 0.08, rms 1.045) */
    ck_assert_double_lt(fabs(mean), 0.2);
    ck_assert_double_gt(rms, 0.8);
    ck_assert_double_lt(rms, 1.2);

    simulate(40000, m50, w, p, mag, found);
    wf_eff_fit fit;
    ck_assert_int_eq(wf_eff_fit_curve(mag, found, 40000, &fit), WF_OK);
    ck_assert(fit.ok);
    printf("40000 objects: m50 %.4f +- %.4f, width %.4f +- %.4f, plateau %.4f +- %.4f\n", fit.m50, fit.m50_err,
           fit.width, fit.width_err, fit.plateau, fit.plateau_err);
    ck_assert_double_lt(fabs(fit.m50 - m50), 3 * fit.m50_err);
    ck_assert_double_lt(fabs(fit.width - w), 3 * fit.width_err);
    ck_assert_double_lt(fabs(fit.plateau - p), 3 * fit.plateau_err);
    ck_assert_double_lt(fit.m50_err, 0.02);

    /* plateau 1 (every bright object found): the fit sits at 1 */
    simulate(5000, 24.1, 0.15, 1.0, mag, found);
    ck_assert_int_eq(wf_eff_fit_curve(mag, found, 5000, &fit), WF_OK);
    ck_assert(fit.ok);
    ck_assert_double_gt(fit.plateau, 0.995);
    ck_assert_double_lt(fabs(fit.m50 - 24.1), 3 * fit.m50_err);

    /* nothing to fit: all found, or too few */
    for (int i = 0; i < 50; i++) mag[i] = 20 + 0.1 * i, found[i] = 1;
    ck_assert_int_eq(wf_eff_fit_curve(mag, found, 50, &fit), WF_OK);
    ck_assert(!fit.ok);
    found[0] = found[1] = 0;
    ck_assert_int_eq(wf_eff_fit_curve(mag, found, 50, &fit), WF_OK);
    ck_assert(!fit.ok);
}
END_TEST

/* ---- matching ---- */

START_TEST(match_closest_pairs_first)
{
    const double as = 1.0 / 3600, dec0 = -53.0, c = cos(dec0 * M_PI / 180);
    /* truth 0 with detections 0.1" and 0.2" away (one is left over); truth 1 and 2 0.25"
     * apart with one detection 0.05" from truth 2 and 0.2" from truth 1 (2 takes it);
     * truth 3 with a detection 0.31" away (outside 0.3"). */
    double tra[4] = {71.0, 71.001, 71.001 + 0.25 * as / c, 71.002}, tdec[4] = {dec0, dec0, dec0, dec0};
    double dra[4] = {71.0 + 0.2 * as / c, 71.0 - 0.1 * as / c, 71.001 + 0.2 * as / c, 71.002},
           ddec[4] = {dec0, dec0, dec0, dec0 + 0.31 * as};
    long t2d[4], d2t[4];
    ck_assert_int_eq(wf_eff_match(tra, tdec, 4, dra, ddec, 4, 0.3 * as, t2d, d2t), WF_OK);
    ck_assert_int_eq(t2d[0], 1);
    ck_assert_int_eq(d2t[0], -1);
    ck_assert_int_eq(t2d[1], -1);
    ck_assert_int_eq(t2d[2], 2);
    ck_assert_int_eq(t2d[3], -1);
    ck_assert_int_eq(d2t[3], -1);
    ck_assert_int_eq(d2t[1], 0);
    ck_assert_int_eq(d2t[2], 2);
    /* across RA = 0 and near a pole the separation is the true one */
    double ra2[2] = {359.99999, 0.00001}, dec2[2] = {0, 0};
    ck_assert_int_eq(wf_eff_match(ra2, dec2, 1, ra2 + 1, dec2 + 1, 1, 0.3 * as, t2d, d2t), WF_OK);
    ck_assert_int_eq(t2d[0], 0);
}
END_TEST

/* ---- synthetic files ---- */

#define NX 200
#define NY 160

static wf_wcs test_wcs(void)
{
    wf_wcs w;
    memset(&w, 0, sizeof w);
    w.nx = NX, w.ny = NY;
    w.crpix[0] = 100.5, w.crpix[1] = 80.5;
    w.crval[0] = 71.0, w.crval[1] = -53.0;
    double s = 0.11 / 3600, th = 25 * M_PI / 180;
    w.cd[0][0] = -s * cos(th), w.cd[0][1] = s * sin(th), w.cd[1][0] = s * sin(th), w.cd[1][1] = s * cos(th);
    return w;
}

/* SCI (1), ERR (0.1) and, when dq, DQ with DO_NOT_USE on columns 150..159 (0-based); wcs 0
 * leaves the WCS out. */
static void write_image(const char *path, int wcs, int dq, const char *filter)
{
    fitsfile *f = NULL;
    int status = 0;
    static float pix[NX * NY];
    static unsigned dqv[NX * NY];
    long naxes[2] = {NX, NY};
    unlink(path);
    fits_create_file(&f, path, &status);
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    if (filter) fits_write_key_str(f, "FILTER", (char *)filter, "", &status);
    const char *names[3] = {"SCI", "ERR", "DQ"};
    wf_wcs w = test_wcs();
    for (int k = 0; k < (dq ? 3 : 2); k++) {
        fits_create_img(f, k == 2 ? ULONG_IMG : FLOAT_IMG, 2, naxes, &status);
        fits_write_key_str(f, "EXTNAME", (char *)names[k], "", &status);
        ck_assert_int_eq(status, 0);
        if (wcs) ck_assert_int_eq(wf_wcs_write_header(&w, f, path), WF_OK);
        for (int i = 0; i < NX * NY; i++) {
            pix[i] = k == 0 ? 1.0f : 0.1f;
            dqv[i] = (i % NX) >= 150 && (i % NX) < 160 ? 1u : 0u;
        }
        if (k < 2) fits_write_img(f, TFLOAT, 1, NX * NY, pix, &status);
        else fits_write_img(f, TUINT, 1, NX * NY, dqv, &status);
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

static void pixel_sky(double x, double y, double *ra, double *dec)
{
    wf_wcs w = test_wcs();
    ck_assert_int_eq(wf_wcs_pix2world(&w, x, y, ra, dec), WF_OK);
}

/* A detection table: CATALOG with RA, DEC (radec 0: X, Y only). */
static void write_catalog(const char *path, const double *ra, const double *dec, long n, int radec)
{
    fitsfile *f = NULL;
    int status = 0;
    char *tt[2] = {radec ? "RA" : "X", radec ? "DEC" : "Y"}, *tf[2] = {"D", "D"}, *tu[2] = {"deg", "deg"};
    unlink(path);
    fits_create_file(&f, path, &status);
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_create_tbl(f, BINARY_TBL, n, 2, tt, tf, tu, "CATALOG", &status);
    if (n > 0) {
        fits_write_col(f, TDOUBLE, 1, 1, 1, n, (double *)ra, &status);
        fits_write_col(f, TDOUBLE, 2, 1, 1, n, (double *)dec, &status);
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

typedef struct obj {
    long long id;
    double x, y, mag;
} obj;

/* A truth file: GALAXIES, STARS, SNE with ID, RA, DEC, X, Y, MAG (positions from pixels). */
static void write_truth(const char *path, const obj *const tabs[3], const long n[3])
{
    fitsfile *f = NULL;
    int status = 0;
    const char *hdu[3] = {"GALAXIES", "STARS", "SNE"};
    char *tt[6] = {"ID", "RA", "DEC", "X", "Y", "MAG"}, *tf[6] = {"1K", "1D", "1D", "1D", "1D", "1E"};
    char *tu[6] = {"", "deg", "deg", "pixel", "pixel", "mag(AB)"};
    unlink(path);
    fits_create_file(&f, path, &status);
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    for (int t = 0; t < 3; t++) {
        fits_create_tbl(f, BINARY_TBL, 0, 6, tt, tf, tu, (char *)hdu[t], &status);
        for (long i = 0; i < n[t]; i++) {
            double ra, dec, x = tabs[t][i].x + 1, y = tabs[t][i].y + 1;
            pixel_sky(tabs[t][i].x, tabs[t][i].y, &ra, &dec);
            long long id = tabs[t][i].id;
            float mag = (float)tabs[t][i].mag;
            fits_write_col(f, TLONGLONG, 1, i + 1, 1, 1, &id, &status);
            fits_write_col(f, TDOUBLE, 2, i + 1, 1, 1, &ra, &status);
            fits_write_col(f, TDOUBLE, 3, i + 1, 1, 1, &dec, &status);
            fits_write_col(f, TDOUBLE, 4, i + 1, 1, 1, &x, &status);
            fits_write_col(f, TDOUBLE, 5, i + 1, 1, 1, &y, &status);
            fits_write_col(f, TFLOAT, 6, i + 1, 1, 1, &mag, &status);
        }
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

static void write_text(const char *path, const char *text)
{
    FILE *f = fopen(path, "w");
    ck_assert_ptr_nonnull(f);
    fputs(text, f);
    fclose(f);
}

static double json_value(const char *path, const char *key)
{
    char *text = wf_test_slurp(path, NULL);
    ck_assert_ptr_nonnull(text);
    const char *keys[1] = {key};
    double v = wf_test_json_number(text, keys, 1);
    free(text);
    return v;
}

/* The CSV row of type t whose bin starts at mag_lo: n_true, n_found (0 when absent). */
static int csv_row(const char *path, const char *type, double mag_lo, long *n, long *k, double *eff, double *elo,
                   double *ehi)
{
    FILE *f = fopen(path, "r");
    ck_assert_ptr_nonnull(f);
    char line[512], t[32];
    double lo, hi;
    int found = 0;
    ck_assert_ptr_nonnull(fgets(line, sizeof line, f));
    ck_assert_str_eq(line, "type,mag_lo,mag_hi,n_true,n_found,eff,eff_lo,eff_hi\n");
    while (fgets(line, sizeof line, f))
        if (sscanf(line, "%31[^,],%lf,%lf,%ld,%ld,%lf,%lf,%lf", t, &lo, &hi, n, k, eff, elo, ehi) == 8 &&
            !strcmp(t, type) && fabs(lo - mag_lo) < 1e-9) {
            found = 1;
            break;
        }
    fclose(f);
    return found;
}

/* A field built so that every count is known: galaxies on a grid, found when their index is
 * even, one of them twice (a second detection 0.2" away: one of the two is false), one off the
 * image and one on the DQ-masked columns (neither counted), the first truth file repeating
 * some galaxies of the second (counted once); stars found brighter than 22; one supernova in
 * both truth files at 22 and 23 (counted once, at the magnitude of the mean flux) and found;
 * three detections far from everything (false). */
START_TEST(counts_on_synthetic_files)
{
    const char *d = wf_test_tmpdir();
    char img[4200], cat[4200], t1[4200], t2[4200], lst[4200], out[4200], path[4400];
    snprintf(img, sizeof img, "%s/img.fits", d);
    snprintf(cat, sizeof cat, "%s/cat.fits", d);
    snprintf(t1, sizeof t1, "%s/t1.fits", d);
    snprintf(t2, sizeof t2, "%s/t2.fits", d);
    snprintf(lst, sizeof lst, "%s/list.txt", d);
    snprintf(out, sizeof out, "%s/out", d);
    write_image(img, 1, 1, "Y106");
    static obj gal[64], star[16], sn[3], gal_rep[8];
    long ng = 0, ns = 0;
    static double dra[200], ddec[200];
    long nd = 0;
    for (int j = 0; j < 5; j++)
        for (int i = 0; i < 8; i++, ng++) {
            gal[ng] = (obj){1000 + ng, 10 + 16.0 * i + 0.3, 10 + 30.0 * j + 0.4, 20.0 + 0.1 * ng};
            if (ng % 2 == 0) pixel_sky(gal[ng].x + 0.5, gal[ng].y, &dra[nd], &ddec[nd]), nd++; /* 0.055" */
        }
    /* galaxy 0 gets a second detection 0.2" (1.8 px) away */
    pixel_sky(gal[0].x - 1.8, gal[0].y, &dra[nd], &ddec[nd]), nd++;
    gal[ng++] = (obj){2000, -3.0, 50.0, 21.0};  /* off the image */
    gal[ng++] = (obj){2001, 155.0, 50.0, 21.0}; /* on masked columns */
    for (int i = 0; i < 12; i++, ns++) {
        star[ns] = (obj){5000 + ns, 20 + 10.0 * i, 150.0, 19.0 + 0.5 * i};
        if (star[ns].mag < 22) pixel_sky(star[ns].x, star[ns].y - 0.3, &dra[nd], &ddec[nd]), nd++;
    }
    sn[0] = (obj){9000, 60.0, 25.0, 22.0};
    sn[1] = (obj){9000, 60.0, 25.0, 23.0};
    /* an SN without light (MAG 99) on galaxy 2's detection: not scored, and it takes nothing */
    sn[2] = (obj){9001, gal[2].x + 0.5, gal[2].y, 99.0};
    pixel_sky(sn[0].x + 0.2, sn[0].y, &dra[nd], &ddec[nd]), nd++;
    for (int k = 0; k < 3; k++) pixel_sky(185.0, 20.0 + 40 * k, &dra[nd], &ddec[nd]), nd++;
    for (int i = 0; i < 8; i++) gal_rep[i] = gal[3 * i];
    write_catalog(cat, dra, ddec, nd, 1);
    const obj *tabs1[3] = {gal_rep, star, sn};
    const long n1[3] = {8, ns, 1};
    write_truth(t1, tabs1, n1);
    const obj *tabs2[3] = {gal, star, sn + 1};
    const long n2[3] = {ng, ns, 2};
    write_truth(t2, tabs2, n2);
    char text[40000];
    snprintf(text, sizeof text, "# a comment line\n\n%s %s %s,%s   # trailing comment\n", img, cat, t1, t2);
    write_text(lst, text);

    wf_eff_options o;
    wf_eff_defaults(&o);
    o.label = "syn", o.out_dir = out, o.bin = 0.5;
    wf_eff_summary s;
    ck_assert_msg(wf_eff_run(lst, &o, &s) == WF_OK, "%s", wf_error_message());
    /* 40 grid galaxies counted, 20 found; stars 12 seen, 6 found (19.0..21.5) */
    ck_assert_int_eq(s.n_images, 1);
    ck_assert_int_eq(s.n_true[WF_EFF_GALAXY], 40);
    ck_assert_int_eq(s.n_found[WF_EFF_GALAXY], 20);
    ck_assert_int_eq(s.n_unseen[WF_EFF_GALAXY], 2);
    ck_assert_int_eq(s.n_true[WF_EFF_STAR], 12);
    ck_assert_int_eq(s.n_found[WF_EFF_STAR], 6);
    ck_assert_int_eq(s.n_true[WF_EFF_SN], 1);
    ck_assert_int_eq(s.n_found[WF_EFF_SN], 1);
    ck_assert_int_eq(s.n_unseen[WF_EFF_SN], 1);
    ck_assert_int_eq(s.n_det, nd);
    ck_assert_int_eq(s.n_false, 4); /* the second detection of galaxy 0 and the three far ones */
    snprintf(path, sizeof path, "%s/syn_summary.json", out);
    ck_assert_double_eq(json_value(path, "n_false"), 4);
    ck_assert_double_eq(json_value(path, "n_det"), (double)nd);
    ck_assert_double_eq(json_value(path, "n_images"), 1);
    ck_assert_double_eq(json_value(path, "n_true_galaxy"), 40);
    ck_assert(wf_test_file_contains(path, "\"m50_sn\": null")); /* one SN: nothing to fit */
    /* the CSV: galaxies 20.0..20.4 in bin [20, 20.5): 5 of them, 3 found (0, 2, 4) */
    snprintf(path, sizeof path, "%s/syn_efficiency.csv", out);
    long n = 0, k = 0;
    double eff, elo, ehi;
    ck_assert(csv_row(path, "galaxy", 20.0, &n, &k, &eff, &elo, &ehi));
    ck_assert_int_eq(n, 5);
    ck_assert_int_eq(k, 3);
    ck_assert_double_eq_tol(eff, 0.6, 1e-6);
    double wlo, whi;
    wf_eff_wilson(3, 5, 1.0, &wlo, &whi);
    ck_assert_double_eq_tol(elo, wlo, 1e-6);
    ck_assert_double_eq_tol(ehi, whi, 1e-6);
    /* the SN counted once at -2.5 log10((10^-8.8 + 10^-9.2) / 2) = 22.4347 */
    ck_assert(csv_row(path, "sn", 22.0, &n, &k, &eff, &elo, &ehi));
    ck_assert_int_eq(n, 1);
    ck_assert_int_eq(k, 1);
    ck_assert(!csv_row(path, "sn", 22.5, &n, &k, &eff, &elo, &ehi));
    snprintf(path, sizeof path, "%s/syn_efficiency.png", out);
    ck_assert_int_eq(access(path, F_OK), 0);
    snprintf(path, sizeof path, "%s/syn_SEARCHEFF_PIPELINE_EFF.DAT", out);
    ck_assert(wf_test_file_contains(path, "MAPNAME_DETECT: WFISIM_syn_Y106\nFILTER: Y\n"));
    ck_assert(wf_test_file_contains(path, "ENDMAP:"));

    /* --types galaxy: stars and the SN take no detection, so the stars' 6 detections and the
     * SN's become false; no SNANA map */
    o.types = 1 << WF_EFF_GALAXY, o.label = "gal";
    ck_assert_msg(wf_eff_run(lst, &o, &s) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(s.n_false, 4 + 6 + 1);
    ck_assert_int_eq(s.n_true[WF_EFF_STAR], 0);
    snprintf(path, sizeof path, "%s/gal_summary.json", out);
    ck_assert(wf_test_file_contains(path, "\"m50_star\": null"));
    ck_assert(wf_test_file_contains(path, "\"n_true_star\": null"));
    snprintf(path, sizeof path, "%s/gal_SEARCHEFF_PIPELINE_EFF.DAT", out);
    ck_assert_int_ne(access(path, F_OK), 0);
}
END_TEST

/* --isolated (SPEC §8): six SNe, all detected, each with a known host and distance from it.
 * Scored: a far SN on a faint host (HOSTOFF 2 > 1.5 x HOSTA 1, host 23), a hostless one, and
 * one whose host is not on this image; not scored: one at 1.4 HOSTA, one exactly at 1.5 (not
 * beyond it) and one far from a host of 21.5 (brighter than 22). The unscored keep their
 * detections: none becomes false. */
START_TEST(isolated_supernovae)
{
    const char *d = wf_test_tmpdir();
    char img[4200], cat[4200], tr[4200], lst[4200], out[4200], sne[4200], bad[4200];
    snprintf(img, sizeof img, "%s/img.fits", d);
    snprintf(cat, sizeof cat, "%s/cat.fits", d);
    snprintf(tr, sizeof tr, "%s/truth.fits", d);
    snprintf(lst, sizeof lst, "%s/list.txt", d);
    snprintf(out, sizeof out, "%s/out", d);
    snprintf(sne, sizeof sne, "%s/sne.fits", d);
    snprintf(bad, sizeof bad, "%s/sne_short.fits", d);
    write_image(img, 1, 0, "Y106");
    obj gal[3] = {{100, 20, 20, 23.0}, {101, 60, 20, 21.5}, {102, 100, 20, 24.0}};
    obj sn[6];
    const long long host[6] = {100, -1, 999, 100, 102, 101};
    const double off[6] = {2.0, 0.0, 5.0, 1.4, 1.5, 3.0}, a[6] = {1.0, 0.0, 0.5, 1.0, 1.0, 1.0};
    double dra[6], ddec[6];
    for (int i = 0; i < 6; i++) {
        sn[i] = (obj){7000 + i, 20.0 + 20.0 * i, 100.0, 23.0 + 0.1 * i};
        pixel_sky(sn[i].x + 0.3, sn[i].y, &dra[i], &ddec[i]);
    }
    write_catalog(cat, dra, ddec, 6, 1);
    const obj *tabs[3] = {gal, sn, sn};
    const long n[3] = {3, 0, 6};
    write_truth(tr, tabs, n);
    wf_sn_sample smp;
    memset(&smp, 0, sizeof smp);
    for (int i = 0; i < 6; i++) {
        size_t r;
        ck_assert_int_eq(wf_sn_sample_push(&smp, &r), WF_OK);
        smp.id[r] = sn[i].id, smp.host_id[r] = host[i], smp.host_offset[r] = off[i], smp.host_a[r] = a[i];
        smp.z[r] = 0.5, smp.x0[r] = 1e-5, smp.host_comp[r] = host[i] < 0 ? -1 : 0;
        pixel_sky(sn[i].x, sn[i].y, &smp.ra[r], &smp.dec[r]);
        if (i == 4) ck_assert_int_eq(wf_sn_sample_write(&smp, bad), WF_OK); /* the first five */
    }
    ck_assert_int_eq(wf_sn_sample_write(&smp, sne), WF_OK);
    wf_sn_sample_free(&smp);
    char text[20000];
    snprintf(text, sizeof text, "%s %s %s\n", img, cat, tr);
    write_text(lst, text);
    wf_eff_options o;
    wf_eff_defaults(&o);
    o.label = "all", o.out_dir = out, o.types = 1 << WF_EFF_SN;
    wf_eff_summary s;
    ck_assert_msg(wf_eff_run(lst, &o, &s) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(s.n_true[WF_EFF_SN], 6);
    ck_assert_int_eq(s.n_not_isolated, 0);
    o.label = "iso", o.isolated = sne;
    ck_assert_msg(wf_eff_run(lst, &o, &s) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(s.n_true[WF_EFF_SN], 3);
    ck_assert_int_eq(s.n_found[WF_EFF_SN], 3);
    ck_assert_int_eq(s.n_not_isolated, 3);
    ck_assert_int_eq(s.n_false, 0);
    char path[4400];
    snprintf(path, sizeof path, "%s/iso_summary.json", out);
    ck_assert_double_eq(json_value(path, "n_not_isolated_sn"), 3);
    ck_assert_double_eq(json_value(path, "iso_factor"), 1.5);
    /* a looser rule (beyond 1.2 HOSTA, hosts brighter than 21 excluded): the SNe at 1.4 and
     * 1.5 HOSTA are beyond 1.2 and the 21.5 host is fainter than 21, so all six are scored */
    o.label = "loose", o.iso_factor = 1.2, o.iso_host_mag = 21.0;
    ck_assert_msg(wf_eff_run(lst, &o, &s) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(s.n_true[WF_EFF_SN], 6);
    ck_assert_int_eq(s.n_not_isolated, 0);
    /* an SN of the truth missing from the sample: refused, naming it */
    o.label = "short", o.isolated = bad, o.iso_factor = 1.5, o.iso_host_mag = 22.0;
    ck_assert_int_eq(wf_eff_run(lst, &o, &s), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "SN 7005"));
    snprintf(path, sizeof path, "%s/short_summary.json", out);
    ck_assert_int_ne(access(path, F_OK), 0);
    o.isolated = sne, o.iso_factor = -1;
    ck_assert_int_eq(wf_eff_run(lst, &o, &s), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "--iso-factor"));
}
END_TEST

/* The SNANA map on supernovae found with a known curve: rows in increasing magnitude, values
 * the fitted curve (through 1/2 at the fitted m50, within the statistical error of the truth),
 * falling below 0.001 on the last row. Pooling two image lines doubles the counts. */
START_TEST(snana_map_of_known_curve)
{
    const char *d = wf_test_tmpdir();
    char img[4200], cat[4200], tr[4200], lst[4200], path[4400];
    snprintf(img, sizeof img, "%s/diff.fits", d);
    snprintf(cat, sizeof cat, "%s/cat.fits", d);
    snprintf(tr, sizeof tr, "%s/truth.fits", d);
    snprintf(lst, sizeof lst, "%s/list", d);
    write_image(img, 1, 0, "H158");
    enum { NSN = 1500 };
    static obj sn[NSN];
    static double dra[NSN], ddec[NSN];
    long nd = 0;
    rng_state = 777;
    for (int i = 0; i < NSN; i++) {
        sn[i] = (obj){i + 1, 3 + (i % 50) * 3.9, 3 + (i / 50) * 5.1, 22 + 5 * uniform()};
        if (uniform() < truth_curve(sn[i].mag, 25.0, 0.3, 0.9)) pixel_sky(sn[i].x, sn[i].y, &dra[nd], &ddec[nd]), nd++;
    }
    write_catalog(cat, dra, ddec, nd, 1);
    const obj *tabs[3] = {NULL, NULL, sn};
    const long n[3] = {0, 0, NSN};
    write_truth(tr, tabs, n);
    char text[40000];
    snprintf(text, sizeof text, "%s %s %s\n%s %s %s\n", img, cat, tr, img, cat, tr);
    write_text(lst, text);
    wf_eff_options o;
    wf_eff_defaults(&o);
    o.label = "sn", o.out_dir = d, o.types = 1 << WF_EFF_SN;
    wf_eff_summary s;
    ck_assert_msg(wf_eff_run(lst, &o, &s) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(s.n_true[WF_EFF_SN], 2 * NSN);
    ck_assert_int_eq(s.n_found[WF_EFF_SN], 2 * nd);
    ck_assert(s.fit[WF_EFF_SN].ok);
    /* the same objects twice: the error is that of NSN objects over sqrt(2) */
    ck_assert_double_lt(fabs(s.fit[WF_EFF_SN].m50 - 25.0), 3 * sqrt(2) * s.fit[WF_EFF_SN].m50_err);
    snprintf(path, sizeof path, "%s/sn_SEARCHEFF_PIPELINE_EFF.DAT", d);
    FILE *f = fopen(path, "r");
    ck_assert_ptr_nonnull(f);
    char line[256];
    int rows = 0, maps = 0;
    double last_m = -1, last_e = 2, first_e = -1;
    ck_assert_ptr_nonnull(fgets(line, sizeof line, f));
    ck_assert_str_eq(line, "DOCUMENTATION:\n"); /* SNANA's DOCANA block first */
    while (fgets(line, sizeof line, f)) {
        double m, e;
        if (!strncmp(line, "MAPNAME_DETECT:", 15)) maps++;
        if (sscanf(line, "MAG: %lf %lf", &m, &e) != 2) continue;
        ck_assert_double_gt(m, last_m);
        ck_assert_double_le(e, last_e + 1e-12); /* the curve falls */
        ck_assert_double_eq_tol(e, wf_eff_curve(&s.fit[WF_EFF_SN], m), 1e-5);
        if (!rows) first_e = e;
        last_m = m, last_e = e, rows++;
    }
    fclose(f);
    ck_assert_int_eq(maps, 1);
    ck_assert_int_gt(rows, 10);
    ck_assert_double_gt(first_e, 0.85);
    ck_assert_double_lt(last_e, 0.001);
    ck_assert(wf_test_file_contains(path, "FILTER: H\n"));
}
END_TEST

/* ---- bad input ---- */

static void expect_refused(const char *list, const char *out_dir, const char *needle1, const char *needle2)
{
    wf_eff_options o;
    wf_eff_defaults(&o);
    o.label = "bad", o.out_dir = out_dir;
    wf_eff_summary s;
    ck_assert_int_eq(wf_eff_run(list, &o, &s), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), needle1) && strstr(wf_error_message(), needle2), "message: %s",
                  wf_error_message());
    ck_assert_int_ne(access(out_dir, F_OK), 0); /* nothing written, not even the folder */
    const char *bin = wf_test_program();
    if (bin) {
        char err[4300];
        snprintf(err, sizeof err, "%s.err", list);
        ck_assert_int_eq(wf_test_run("%s efficiency --label bad --out %s %s 2>%s", bin, out_dir, list, err), 2);
        ck_assert(wf_test_file_contains(err, needle1));
        ck_assert_int_ne(access(out_dir, F_OK), 0);
    }
}

START_TEST(bad_input_is_refused)
{
    const char *d = wf_test_tmpdir();
    char img[4200], nowcs[4200], cat[4200], nora[4200], tr[4200], empty[4200], lst[4200], out[4200], text[40000];
    snprintf(img, sizeof img, "%s/img.fits", d);
    snprintf(nowcs, sizeof nowcs, "%s/nowcs.fits", d);
    snprintf(cat, sizeof cat, "%s/cat.fits", d);
    snprintf(nora, sizeof nora, "%s/nora.fits", d);
    snprintf(tr, sizeof tr, "%s/truth.fits", d);
    snprintf(empty, sizeof empty, "%s/empty_truth.fits", d);
    snprintf(lst, sizeof lst, "%s/list", d);
    snprintf(out, sizeof out, "%s/out", d);
    write_image(img, 1, 1, "Y106");
    write_image(nowcs, 0, 1, "Y106");
    double ra = 71, dec = -53;
    write_catalog(cat, &ra, &dec, 1, 1);
    write_catalog(nora, &ra, &dec, 1, 0);
    static obj g[1] = {{1, 50, 50, 21}};
    const obj *tabs[3] = {g, NULL, NULL};
    const long n1[3] = {1, 0, 0}, n0[3] = {0, 0, 0};
    write_truth(tr, tabs, n1);
    write_truth(empty, tabs, n0);

    snprintf(text, sizeof text, "%s %s %s\n%s %s %s\n", img, cat, tr, img, cat, empty);
    write_text(lst, text);
    expect_refused(lst, out, "list:2", "empty truth table");
    snprintf(text, sizeof text, "%s %s %s\n%s %s\n", img, cat, tr, img, cat);
    write_text(lst, text);
    expect_refused(lst, out, "list:2", "2 fields");
    snprintf(text, sizeof text, "%s %s %s,%s/missing.fits\n", img, cat, tr, d);
    write_text(lst, text);
    expect_refused(lst, out, "list:1", "missing.fits: no such file");
    snprintf(text, sizeof text, "%s %s %s\n", img, nora, tr);
    write_text(lst, text);
    expect_refused(lst, out, "nora.fits", "no RA column");
    snprintf(text, sizeof text, "%s %s %s\n", nowcs, cat, tr);
    write_text(lst, text);
    expect_refused(lst, out, "nowcs.fits", "no WCS");
    write_text(lst, "# only a comment\n");
    expect_refused(lst, out, "list", "no image lines");
    /* options */
    wf_eff_options o;
    wf_eff_defaults(&o);
    o.label = "a/b", o.out_dir = out;
    wf_eff_summary s;
    ck_assert_int_eq(wf_eff_run(lst, &o, &s), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "--label"));
    int types;
    ck_assert_int_eq(wf_eff_parse_types("galaxy,sne", &types), WF_OK);
    ck_assert_int_eq(types, (1 << WF_EFF_GALAXY) | (1 << WF_EFF_SN));
    ck_assert_int_eq(wf_eff_parse_types("galaxy,quasar", &types), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "quasar"));
    const char *bin = wf_test_program();
    if (bin) {
        ck_assert_int_eq(wf_test_run("%s efficiency --label x --out %s --radius -1 %s 2>/dev/null", bin, out, lst), 2);
        ck_assert_int_eq(wf_test_run("%s efficiency --label x --out %s --types quasar %s 2>/dev/null", bin, out, lst), 2);
        ck_assert_int_eq(wf_test_run("%s efficiency --out %s %s 2>/dev/null", bin, out, lst), 2);
    }
}
END_TEST

/* ---- end to end on a wfisim exposure ---- */

#define SMALL "--set readout.ncols=512 --set readout.nrows=512 --quiet"
#define GRID 20
#define NCAL 20 /* the first row: bright stars whose pixels give the PSF */

/* GRID x GRID stars 25 px apart at the default pointing (SCA 1, the built-in WCS: the truth
 * table holds the pixel positions the renderer used, whatever focal plane the program reads):
 * the first row at Y106 21, the others spread evenly over 23.5..28 in a shuffled order. */
static void write_star_field(const char *path)
{
    wf_focal_plane fp;
    wf_wcs w;
    wf_wcs_focal_plane_builtin(&fp);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, 71.0, -53.0, 30.0, 1, &w), WF_OK);
    FILE *f = fopen(path, "w");
    ck_assert_ptr_nonnull(f);
    fprintf(f, "id,ra,dec,mag_Y106\n");
    int nf = GRID * GRID - NCAL;
    for (int k = 0; k < GRID * GRID; k++) {
        double x = 18 + 25 * (k % GRID) + 0.37 * ((k * 3) % 7) / 7.0;
        double y = 18 + 25 * (k / GRID) + 0.29 * ((k * 5) % 11) / 11.0;
        double ra, dec, mag = 21.0;
        if (k >= NCAL) mag = 23.5 + 4.5 * (double)(((k - NCAL) * 149) % nf) / (nf - 1);
        ck_assert_int_eq(wf_wcs_pix2world(&w, x, y, &ra, &dec), WF_OK);
        fprintf(f, "%d,%.10f,%.10f,%.4f\n", k + 1, ra, dec, mag);
    }
    fclose(f);
}

static int cmp_desc(const void *a, const void *b)
{
    double u = *(const double *)a, v = *(const double *)b;
    return (u < v) - (u > v);
}

static void read_plane(fitsfile *f, const char *name, float *buf, long n)
{
    int status = 0;
    fits_movnam_hdu(f, IMAGE_HDU, (char *)name, 0, &status);
    fits_read_img(f, TFLOAT, 1, n, NULL, buf, NULL, &status);
    ck_assert_int_eq(status, 0);
}

/* The magnitude at which detection should find half of the stars, from the image alone:
 * detection thresholds the image filtered by the normalised 3x3 pyramid at 1.5 ERR and needs
 * 5 connected pixels above it, so a star of flux F is found about half the time when the
 * 5th brightest pixel of its filtered profile, F q5, sits at the threshold 1.5 sigma
 * (noise is symmetric about it): F50 = 1.5 sigma / q5. sigma is the median ERR; q5 comes from
 * the bright stars' own pixels (sky-subtracted, divided by their true flux), so the PSF and
 * the pixel phases are the image's. Also the 5-sigma PSF-fit depth, 5 sigma sqrt(N_eff). */
static void expected_depth(const char *product, const char *truth, double *m50, double *m5)
{
    enum { N = 512 };
    static float sci[N * N], err[N * N], work[N * N];
    fitsfile *f = NULL;
    int status = 0;
    fits_open_file(&f, product, READONLY, &status);
    ck_assert_int_eq(status, 0);
    read_plane(f, "SCI", sci, (long)N * N);
    read_plane(f, "ERR", err, (long)N * N);
    fits_close_file(f, &status);
    static double v[N * N];
    for (int i = 0; i < N * N; i++) v[i] = err[i];
    qsort(v, N * N, sizeof *v, cmp_desc);
    double sigma = v[N * N / 2];
    for (int i = 0; i < N * N; i++) v[i] = sci[i];
    qsort(v, N * N, sizeof *v, cmp_desc);
    double sky = v[N * N / 2];
    (void)work;
    /* the truth of the bright stars */
    double x[NCAL], y[NCAL], flux[NCAL], mag[NCAL];
    fits_open_table(&f, truth, READONLY, &status);
    int col;
    const char *names[4] = {"X", "Y", "FLUX", "MAG"};
    double *dst[4] = {x, y, flux, mag};
    for (int c = 0; c < 4; c++) {
        fits_get_colnum(f, CASEINSEN, (char *)names[c], &col, &status);
        fits_read_col(f, TDOUBLE, col, 1, 1, NCAL, NULL, dst[c], NULL, &status);
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    double q5[NCAL], neff[NCAL], zp = mag[0] + 2.5 * log10(flux[0]);
    for (int s = 0; s < NCAL; s++) {
        ck_assert_double_lt(mag[s], 21.5);
        int cx = (int)lround(x[s] - 1), cy = (int)lround(y[s] - 1);
        double st[11][11], filt[81], sum2 = 0;
        for (int j = 0; j < 11; j++)
            for (int i = 0; i < 11; i++) {
                st[j][i] = (sci[(cy - 5 + j) * N + cx - 5 + i] - sky) / flux[s];
                sum2 += st[j][i] * st[j][i];
            }
        static const double k3[3][3] = {{1, 2, 1}, {2, 4, 2}, {1, 2, 1}};
        for (int j = 1; j < 10; j++)
            for (int i = 1; i < 10; i++) {
                double a = 0;
                for (int dj = -1; dj <= 1; dj++)
                    for (int di = -1; di <= 1; di++) a += k3[dj + 1][di + 1] / 16.0 * st[j + dj][i + di];
                filt[(j - 1) * 9 + i - 1] = a;
            }
        qsort(filt, 81, sizeof *filt, cmp_desc);
        q5[s] = filt[4], neff[s] = 1 / sum2;
    }
    qsort(q5, NCAL, sizeof *q5, cmp_desc);
    qsort(neff, NCAL, sizeof *neff, cmp_desc);
    double q = 0.5 * (q5[NCAL / 2 - 1] + q5[NCAL / 2]), ne = 0.5 * (neff[NCAL / 2 - 1] + neff[NCAL / 2]);
    *m50 = zp - 2.5 * log10(1.5 * sigma / q);
    *m5 = zp - 2.5 * log10(5 * sigma * sqrt(ne));
    printf("image: sky %.4f e-/s, median ERR %.4f e-/s, AB zero point %.4f; bright stars: 5th filtered pixel "
           "%.4f of the flux, N_eff %.2f px; expected m50 %.3f, 5-sigma PSF depth %.3f\n", sky, sigma, zp, q, ne,
           *m50, *m5);
}

/* wfisim expose of a star field, detection (wf_detect_file), wfisim efficiency: every bright star found,
 * no false detections to speak of, and the fitted m50 where the image's noise and PSF put it. */
START_TEST(end_to_end_star_field)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char stars[4200], product[4300], truth[4300], cat[4300], lst[4300], text[20000], path[4400];
    snprintf(stars, sizeof stars, "%s/stars.csv", d);
    write_star_field(stars);
    ck_assert_int_eq(wf_test_run("%s expose " SMALL " --set scene.kind=catalog --set scene.stars=%s --out %s", bin,
                                 stars, d), 0);
    snprintf(product, sizeof product, "%s/wfisim_e000001_sca01.fits", d);
    snprintf(truth, sizeof truth, "%s/wfisim_e000001_sca01_truth.fits", d);
    snprintf(cat, sizeof cat, "%s/cat.fits", d);
    /* detection in this process: SEP's known leak (above) is suppressed here, not in a
     * sanitized wfisim program */
    wf_detect_options dopt;
    wf_detect_summary dsum;
    wf_detect_defaults(&dopt);
    ck_assert_msg(wf_detect_file(product, cat, &dopt, &dsum) == WF_OK, "%s", wf_error_message());
    snprintf(lst, sizeof lst, "%s/single.list", d);
    snprintf(text, sizeof text, "# IMAGE DETCAT TRUTH\n%s %s %s\n", product, cat, truth);
    write_text(lst, text);
    ck_assert_int_eq(wf_test_run("%s efficiency --label single --out %s/eff --types star %s", bin, d, lst), 0);
    snprintf(path, sizeof path, "%s/eff/single_summary.json", d);
    double m50 = json_value(path, "m50_star"), err = json_value(path, "m50_err_star");
    double n_true = json_value(path, "n_true_star"), n_false = json_value(path, "n_false");
    double det = json_value(path, "n_det");
    char tstars[4400];
    snprintf(tstars, sizeof tstars, "%s[STARS]", truth);
    double expect, m5;
    expected_depth(product, tstars, &expect, &m5);
    printf("efficiency: %.0f stars, %.0f detections, %.0f false; m50 %.3f +- %.3f (expected %.3f)\n", n_true, det,
           n_false, m50, err, expect);
    ck_assert_double_eq(n_true, GRID * GRID);
    ck_assert(isfinite(m50) && err > 0 && err < 0.1);
    snprintf(path, sizeof path, "%s/eff/single_efficiency.csv", d);
    long n, k;
    double eff, lo, hi;
    ck_assert(csv_row(path, "star", 21.0, &n, &k, &eff, &lo, &hi));
    ck_assert_int_eq(n, NCAL);
    ck_assert_int_eq(k, NCAL);
    ck_assert_double_lt(fabs(m50 - expect), 0.35 + 3 * err);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("efficiency");
    TCase *tc = tcase_create("all");
    tcase_set_timeout(tc, 600);
    tcase_add_test(tc, wilson_closed_form);
    tcase_add_test(tc, fit_recovers_m50);
    tcase_add_test(tc, match_closest_pairs_first);
    tcase_add_test(tc, counts_on_synthetic_files);
    tcase_add_test(tc, snana_map_of_known_curve);
    tcase_add_test(tc, isolated_supernovae);
    tcase_add_test(tc, bad_input_is_refused);
    tcase_add_test(tc, end_to_end_star_field);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
