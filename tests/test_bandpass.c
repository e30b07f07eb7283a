/* Filters, bandpasses and photometry (sim/optics/bandpass.c), checked against values derived
 * outside it:
 *  - the top-hat's moments against their closed forms (ln(hi/lo), (lo+hi)/2, ...);
 *  - the SED integrator against the AB closed form for a flat-f_ν spectrum;
 *  - with ../shared: zero points and effective wavelengths against GalSim's
 *    (reference/galsim/facts.json, read here at run time), zero points and pivot
 *    wavelengths against SPEC §2, and the interpolated throughput against GalSim's own
 *    1 nm resampling (bandpass_throughput_1nm.csv);
 *  - bad files and names: errors that name the file, line and field.
 * Measured differences are printed so that the log records them, not only pass/fail. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "sim/optics/bandpass.h"
#include "tests/testutil.h"

#define H_CGS 6.62607015e-27
#define C_AA 2.99792458e18 /* Å / s */

static const wf_filter all_filters[WF_NFILTER] = {WF_R062, WF_Z087, WF_Y106, WF_J129,
                                                  WF_H158, WF_F184, WF_K213, WF_W146};

/* SPEC §2: "AB magnitude giving 1 e-/s" and pivot wavelengths (µm), in wf_filter order. */
static const double spec_zp[WF_NFILTER] = {26.73, 26.40, 26.46, 26.48, 26.51, 26.06, 26.02, 27.71};
static const double spec_pivot_um[WF_NFILTER] = {0.629, 0.870, 1.057, 1.290,
                                                 1.575, 1.839, 2.123, 1.438};

/* ------------------------------------------------------------------ small helpers */


static void write_file(const char *path, const char *text)
{
    FILE *fp = fopen(path, "w");
    ck_assert_msg(fp != NULL, "cannot write %s", path);
    fputs(text, fp);
    fclose(fp);
}

/* A data directory in a fresh temporary folder whose effective-area file holds text. */
static const char *fake_data_dir(const char *text)
{
    static char dir[4096];
    const char *tmp = wf_test_tmpdir();
    ck_assert_ptr_nonnull(tmp);
    snprintf(dir, sizeof dir, "%s", tmp);
    char path[4200];
    snprintf(path, sizeof path, "%s/roman", dir);
    ck_assert_int_eq(mkdir(path, 0755), 0);
    snprintf(path, sizeof path, "%s/roman/Roman_effarea_20210614.txt", dir);
    write_file(path, text);
    return dir;
}

/* ------------------------------------------------------------------ names */

START_TEST(test_filter_names)
{
    for (int i = 0; i < WF_NFILTER; i++) {
        wf_filter f;
        ck_assert_int_eq(wf_filter_parse(wf_filter_name(all_filters[i]), &f), WF_OK);
        ck_assert_int_eq(f, all_filters[i]);
    }
    wf_filter f;
    ck_assert_int_eq(wf_filter_parse("w149", &f), WF_OK);
    ck_assert_int_eq(f, WF_W146);
    ck_assert_str_eq(wf_filter_name(f), "W146");
    ck_assert_int_eq(wf_filter_parse("h158", &f), WF_OK);
    ck_assert_int_eq(f, WF_H158);

    ck_assert_int_eq(wf_filter_parse("Q123", &f), WF_ERR_INPUT);
    const char *msg = wf_error_message();
    ck_assert_msg(strstr(msg, "'Q123'") != NULL, "message does not name the filter: %s", msg);
    for (int i = 0; i < WF_NFILTER; i++)
        ck_assert_msg(strstr(msg, wf_filter_name(all_filters[i])) != NULL,
                      "message does not list %s: %s", wf_filter_name(all_filters[i]), msg);
    ck_assert_int_eq(wf_filter_parse(NULL, &f), WF_ERR_INPUT);
    ck_assert_str_eq(wf_filter_name((wf_filter)99), "?");

    double c, w;
    ck_assert_int_eq(wf_filter_facts(WF_W146, &c, &w), WF_OK);
    ck_assert_double_eq_tol(c, 1464.0, 1e-9);
    ck_assert_double_eq_tol(w, 1030.0, 1e-9);
    ck_assert_int_eq(wf_filter_facts((wf_filter)-1, &c, &w), WF_ERR_RANGE);
}
END_TEST

/* ------------------------------------------------------------------ top-hat */

START_TEST(test_tophat_closed_forms)
{
    static wf_bandpass bp;
    for (int i = 0; i < WF_NFILTER; i++) {
        wf_filter f = all_filters[i];
        ck_assert_int_eq(wf_bandpass_load(f, NULL, &bp), WF_OK);
        ck_assert_int_eq(bp.builtin, 1);
        ck_assert_msg(strstr(bp.source, "no data directory") != NULL, "%s", bp.source);
        double c, w;
        wf_filter_facts(f, &c, &w);
        double lo = c - w / 2, hi = c + w / 2;
        double itl = log(hi / lo);
        double zp = 2.5 * log10(WF_COLLECTING_AREA_CM2 * 3631e-23 / H_CGS * itl);
        double pivot = sqrt(0.5 * (hi * hi - lo * lo) / itl);
        ck_assert_double_eq_tol(bp.int_t, w, 1e-9);
        ck_assert_double_eq_tol(bp.int_t_over_lambda, itl, 1e-14);
        ck_assert_double_eq_tol(bp.zp_ab, zp, 1e-12);
        ck_assert_double_eq_tol(bp.zp_photon, zp - 2.5 * log10(WF_COLLECTING_AREA_CM2), 1e-12);
        ck_assert_double_eq_tol(bp.lambda_eff_nm, c, 1e-9);
        ck_assert_double_eq_tol(bp.lambda_pivot_nm, pivot, 1e-9);
        ck_assert_double_eq(wf_bandpass_throughput(&bp, c), 1.0);
        ck_assert_double_eq(wf_bandpass_throughput(&bp, lo - 1e-6), 0.0);
        ck_assert_double_eq(wf_bandpass_throughput(&bp, hi + 1e-6), 0.0);
    }
    /* an empty data directory name is "no data", a missing file is said to be missing */
    ck_assert_int_eq(wf_bandpass_load(WF_Y106, "", &bp), WF_OK);
    ck_assert_int_eq(bp.builtin, 1);
    const char *tmp = wf_test_tmpdir();
    ck_assert_int_eq(wf_bandpass_load(WF_Y106, tmp, &bp), WF_OK);
    ck_assert_int_eq(bp.builtin, 1);
    ck_assert_msg(strstr(bp.source, "not found") && strstr(bp.source, tmp), "%s", bp.source);
    ck_assert_int_eq(wf_bandpass_load((wf_filter)WF_NFILTER, NULL, &bp), WF_ERR_RANGE);
}
END_TEST

START_TEST(test_ab_rates)
{
    static wf_bandpass bp;
    ck_assert_int_eq(wf_bandpass_tophat(WF_J129, &bp), WF_OK);
    ck_assert_double_eq_tol(wf_bandpass_countrate_ab(&bp, bp.zp_ab), 1.0, 1e-12);
    double r20 = wf_bandpass_countrate_ab(&bp, 20.0), r25 = wf_bandpass_countrate_ab(&bp, 25.0);
    ck_assert_double_eq_tol(r20 / r25, 100.0, 1e-9);
    double m;
    ck_assert_int_eq(wf_bandpass_mag_ab(&bp, r20, &m), WF_OK);
    ck_assert_double_eq_tol(m, 20.0, 1e-12);
    ck_assert_int_eq(wf_bandpass_mag_ab(&bp, 0.0, &m), WF_ERR_RANGE);
    ck_assert_int_eq(wf_bandpass_mag_ab(&bp, -1.0, &m), WF_ERR_RANGE);
    ck_assert_int_eq(wf_bandpass_mag_ab(&bp, NAN, &m), WF_ERR_RANGE);
    /* faint and bright ends stay finite and positive */
    ck_assert(wf_bandpass_countrate_ab(&bp, 35.0) > 0.0);
    ck_assert(isfinite(wf_bandpass_countrate_ab(&bp, 8.0)));
}
END_TEST

/* ------------------------------------------------------------------ SEDs */

typedef struct flat_fnu {
    double mag;
    long calls;
} flat_fnu;

/* f_λ of a flat-f_ν source: f_ν c / λ², per Å. */
static double sed_flat_fnu(double wave_nm, void *ctx)
{
    flat_fnu *s = ctx;
    s->calls++;
    double fnu = 3631e-23 * pow(10.0, -0.4 * s->mag);
    double lam_aa = 10.0 * wave_nm;
    return fnu * C_AA / (lam_aa * lam_aa);
}

static double sed_nan_at_1000(double wave_nm, void *ctx)
{
    (void)ctx;
    return wave_nm > 1000.0 ? NAN : 1e-17;
}

/* f_λ ∝ λ^-4 (a Rayleigh-Jeans-like blue source), whose exact rate through a top-hat is
 * A ∫ k λ^-4 λ/(hc) dλ = A k/(hc) (lo^-2 - hi^-2)/2. */
static double sed_powerlaw(double wave_nm, void *ctx)
{
    (void)ctx;
    return 1e-17 * pow(wave_nm / 1000.0, -4.0);
}

static void check_sed_vs_ab(const wf_bandpass *bp)
{
    flat_fnu s = {21.5, 0};
    double rate;
    ck_assert_int_eq(wf_bandpass_countrate_sed(bp, sed_flat_fnu, &s, &rate), WF_OK);
    double want = wf_bandpass_countrate_ab(bp, 21.5);
    double rel = rate / want - 1.0;
    printf("  %s (%s): flat f_nu through the SED integrator / AB closed form - 1 = %.2e "
           "(%ld SED calls)\n",
           wf_filter_name(bp->filter), bp->builtin ? "top-hat" : "data", rel, s.calls);
    ck_assert_msg(fabs(rel) < 1e-7, "%s: SED rate %.9g vs AB %.9g", wf_filter_name(bp->filter),
                  rate, want);
}

START_TEST(test_sed_integrator)
{
    static wf_bandpass bp;
    for (int i = 0; i < WF_NFILTER; i++) {
        ck_assert_int_eq(wf_bandpass_tophat(all_filters[i], &bp), WF_OK);
        check_sed_vs_ab(&bp);
    }
    ck_assert_int_eq(wf_bandpass_tophat(WF_H158, &bp), WF_OK);
    double c, w, rate;
    wf_filter_facts(WF_H158, &c, &w);
    double lo = (c - w / 2) * 1e-7, hi = (c + w / 2) * 1e-7; /* cm */
    /* f_λ = 1e-17 (λ/1000 nm)^-4 erg/s/cm²/Å = 1e-9 (λ/1e-4 cm)^-4 erg/s/cm²/cm */
    double k = 1e-9 * pow(1e-4, 4.0);
    double want = WF_COLLECTING_AREA_CM2 * k / (H_CGS * 2.99792458e10) * 0.5 *
                  (1.0 / (lo * lo) - 1.0 / (hi * hi));
    ck_assert_int_eq(wf_bandpass_countrate_sed(&bp, sed_powerlaw, NULL, &rate), WF_OK);
    printf("  H158 top-hat, f_lambda ~ lambda^-4: rate / exact - 1 = %.2e\n", rate / want - 1);
    ck_assert_double_eq_tol(rate / want, 1.0, 1e-8);
    /* coarser steps still converge (Simpson, fourth order) */
    double coarse;
    ck_assert_int_eq(wf_bandpass_countrate_sed_step(&bp, sed_powerlaw, NULL, 50.0, &coarse),
                     WF_OK);
    ck_assert_double_eq_tol(coarse / want, 1.0, 1e-5);

    /* an SED undefined beyond 1000 nm is fine for R062 (480-760 nm), an error for Y106 */
    ck_assert_int_eq(wf_bandpass_tophat(WF_R062, &bp), WF_OK);
    ck_assert_int_eq(wf_bandpass_countrate_sed(&bp, sed_nan_at_1000, NULL, &rate), WF_OK);
    ck_assert_int_eq(wf_bandpass_tophat(WF_Y106, &bp), WF_OK);
    ck_assert_int_eq(wf_bandpass_countrate_sed(&bp, sed_nan_at_1000, NULL, &rate), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), "nm") != NULL, "%s", wf_error_message());
    ck_assert_int_eq(wf_bandpass_countrate_sed(&bp, NULL, NULL, &rate), WF_ERR_INPUT);
    ck_assert_int_eq(wf_bandpass_countrate_sed_step(&bp, sed_powerlaw, NULL, 0.0, &rate),
                     WF_ERR_RANGE);
}
END_TEST

/* ------------------------------------------------------------------ against the data */

START_TEST(test_real_vs_galsim_and_spec)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    char datadir[4096];
    snprintf(datadir, sizeof datadir, "%s", data);
    const char *ref = wf_test_reference_dir();
    char *facts = NULL;
    if (ref) {
        char path[4200];
        snprintf(path, sizeof path, "%s/facts.json", ref);
        facts = wf_test_slurp(path, NULL);
    }
    static wf_bandpass bp;
    printf("  filter  zp(1e-/s)  -GalSim   -SPEC   zp(1ph/cm2/s) -GalSim  lam_eff  -GalSim  "
           "pivot  -SPEC  [nm]\n");
    for (int i = 0; i < WF_NFILTER; i++) {
        wf_filter f = all_filters[i];
        const char *name = wf_filter_name(f);
        ck_assert_int_eq(wf_bandpass_load(f, datadir, &bp), WF_OK);
        ck_assert_int_eq(bp.builtin, 0);
        ck_assert_msg(strstr(bp.source, "Roman_effarea_20210614.txt") != NULL, "%s", bp.source);
        double gz = NAN, gzp = NAN, gle = NAN;
        if (facts) {
            const char *k1[] = {"zeropoint_instrumental_1e_per_s", name};
            const char *k2[] = {"zeropoint_AB", name};
            const char *k3[] = {"effective_wavelength_nm", name};
            gz = wf_test_json_number(facts, k1, 2);
            gzp = wf_test_json_number(facts, k2, 2);
            gle = wf_test_json_number(facts, k3, 2);
            ck_assert_msg(isfinite(gz) && isfinite(gzp) && isfinite(gle),
                          "facts.json lacks %s values", name);
        }
        printf("  %s    %8.4f  %+.5f  %+.4f   %8.4f     %+.5f  %7.2f  %+.3f  %7.2f  %+.2f\n",
               name, bp.zp_ab, bp.zp_ab - gz, bp.zp_ab - spec_zp[i], bp.zp_photon,
               bp.zp_photon - gzp, bp.lambda_eff_nm, bp.lambda_eff_nm - gle,
               bp.lambda_pivot_nm, bp.lambda_pivot_nm - 1000.0 * spec_pivot_um[i]);
        /* SPEC quotes two decimals, so 0.005 of rounding is inside the 0.01 bar */
        ck_assert_msg(fabs(bp.zp_ab - spec_zp[i]) < 0.01, "%s zp %.4f vs SPEC %.2f", name,
                      bp.zp_ab, spec_zp[i]);
        ck_assert_msg(fabs(bp.lambda_pivot_nm - 1000.0 * spec_pivot_um[i]) < 1.0,
                      "%s pivot %.2f nm vs SPEC %.3f um", name, bp.lambda_pivot_nm,
                      spec_pivot_um[i]);
        if (facts) {
            ck_assert_msg(fabs(bp.zp_ab - gz) < 0.01, "%s zp %.4f vs GalSim %.4f", name,
                          bp.zp_ab, gz);
            ck_assert_msg(fabs(bp.zp_photon - gzp) < 0.01, "%s zp %.4f vs GalSim %.4f", name,
                          bp.zp_photon, gzp);
            ck_assert_msg(fabs(bp.lambda_eff_nm - gle) < 1.0, "%s lam_eff %.3f vs GalSim %.3f",
                          name, bp.lambda_eff_nm, gle);
        }
        check_sed_vs_ab(&bp);
    }
    if (!facts) WF_SKIP("../shared/reference/galsim (GalSim comparison)");
    free(facts);
}
END_TEST

START_TEST(test_throughput_vs_1nm_csv)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    char datadir[4096];
    snprintf(datadir, sizeof datadir, "%s", data);
    const char *ref = wf_test_reference_dir();
    WF_SKIP_UNLESS(ref, "../shared/reference/galsim");
    char path[4200];
    snprintf(path, sizeof path, "%s/bandpass_throughput_1nm.csv", ref);
    FILE *fp = fopen(path, "r");
    ck_assert_msg(fp != NULL, "cannot open %s", path);

    static wf_bandpass bps[WF_NFILTER];
    for (int i = 0; i < WF_NFILTER; i++)
        ck_assert_int_eq(wf_bandpass_load(all_filters[i], datadir, &bps[i]), WF_OK);
    char line[4096];
    ck_assert_ptr_nonnull(fgets(line, sizeof line, fp));
    int col_of[WF_NFILTER], ncol = 0;
    for (int i = 0; i < WF_NFILTER; i++) col_of[i] = -1;
    char *save = NULL;
    for (char *tok = strtok_r(line, ",\r\n", &save); tok; tok = strtok_r(NULL, ",\r\n", &save)) {
        wf_filter f;
        if (ncol > 0 && wf_filter_parse(tok, &f) == WF_OK) col_of[f] = ncol;
        ncol++;
    }
    for (int i = 0; i < WF_NFILTER; i++) ck_assert_int_ge(col_of[i], 1);

    double maxdiff[WF_NFILTER] = {0}, at[WF_NFILTER] = {0};
    long rows = 0;
    while (fgets(line, sizeof line, fp)) {
        double v[64];
        int n = 0;
        save = NULL;
        for (char *tok = strtok_r(line, ",\r\n", &save); tok && n < 64;
             tok = strtok_r(NULL, ",\r\n", &save))
            v[n++] = strtod(tok, NULL);
        if (n < ncol) continue;
        rows++;
        for (int i = 0; i < WF_NFILTER; i++) {
            double d = fabs(wf_bandpass_throughput(&bps[i], v[0]) - v[col_of[i]]);
            if (d > maxdiff[i]) {
                maxdiff[i] = d;
                at[i] = v[0];
            }
        }
    }
    fclose(fp);
    ck_assert_int_gt(rows, 1000);
    for (int i = 0; i < WF_NFILTER; i++) {
        printf("  %s: max |T - T_GalSim(1 nm csv)| = %.2e at %.0f nm (%ld wavelengths)\n",
               wf_filter_name(all_filters[i]), maxdiff[i], at[i], rows);
        ck_assert_msg(maxdiff[i] < 1e-3, "%s throughput differs by %.3g at %.0f nm",
                      wf_filter_name(all_filters[i]), maxdiff[i], at[i]);
    }
}
END_TEST

/* The built-in top-hats against the real curves: reported, and bounded so that a broken
 * fallback shows. With unit throughput a top-hat must be brighter than the real band (whose
 * throughput is below 1 everywhere); measured 0.24-0.71 mag. */
START_TEST(test_tophat_vs_real)
{
    const char *data = wf_test_data_dir();
    WF_SKIP_UNLESS(data, "../shared/data");
    char datadir[4096];
    snprintf(datadir, sizeof datadir, "%s", data);
    static wf_bandpass real, top;
    printf("  filter  zp top-hat - real [mag]   lam_eff top-hat - real [nm]   pivot [nm]\n");
    for (int i = 0; i < WF_NFILTER; i++) {
        wf_filter f = all_filters[i];
        ck_assert_int_eq(wf_bandpass_load(f, datadir, &real), WF_OK);
        ck_assert_int_eq(wf_bandpass_tophat(f, &top), WF_OK);
        double dzp = top.zp_ab - real.zp_ab;
        printf("  %s    %7.3f - %7.3f = %+.3f      %7.1f - %7.1f = %+6.1f     %+6.1f\n",
               wf_filter_name(f), top.zp_ab, real.zp_ab, dzp, top.lambda_eff_nm,
               real.lambda_eff_nm, top.lambda_eff_nm - real.lambda_eff_nm,
               top.lambda_pivot_nm - real.lambda_pivot_nm);
        ck_assert_msg(dzp > 0.0 && dzp < 0.75, "%s top-hat zp off by %+.3f mag",
                      wf_filter_name(f), dzp);
        ck_assert_msg(fabs(top.lambda_eff_nm - real.lambda_eff_nm) < 20.0,
                      "%s top-hat effective wavelength off by %.1f nm", wf_filter_name(f),
                      top.lambda_eff_nm - real.lambda_eff_nm);
        double peak = 0.0;
        for (int k = 0; k < real.n; k++) peak = fmax(peak, real.throughput[k]);
        ck_assert(peak > 0.3 && peak < 1.0);
    }
}
END_TEST

/* ------------------------------------------------------------------ bad files */

static void expect_load_error(const char *text, wf_filter f, const char *want1,
                              const char *want2)
{
    static wf_bandpass bp;
    const char *dir = fake_data_dir(text);
    wf_status st = wf_bandpass_load(f, dir, &bp);
    const char *msg = wf_error_message();
    ck_assert_msg(st == WF_ERR_INPUT, "expected an input error, got %d (%s)", st, msg);
    ck_assert_msg(strstr(msg, "Roman_effarea_20210614.txt") != NULL, "no file name: %s", msg);
    ck_assert_msg(strstr(msg, want1) != NULL, "'%s' not in: %s", want1, msg);
    if (want2) ck_assert_msg(strstr(msg, want2) != NULL, "'%s' not in: %s", want2, msg);
}

START_TEST(test_bad_files)
{
    expect_load_error("Wave R062 Y106\n0.90 0 0\n0.95 0 1.x\n", WF_Y106, ":3:", "'1.x'");
    expect_load_error("Wave R062 Y106\n0.90 0 0\n0.90 0 1\n", WF_Y106, ":3:", "increase");
    expect_load_error("Wave R062 Y106\n0.90 0 0\n0.95 0\n", WF_Y106, ":3:", "fields");
    expect_load_error("Wave R062 Y106\n0.90 0 0\n0.95 0 -1\n", WF_Y106, ":3:", "negative");
    expect_load_error("Wave R062 Y106\n0.90 0 0\n0.95 0 1\n", WF_H158, "no column for filter H158",
                      "R062 Y106");
    expect_load_error("Wave R062 Y106\n0.90 0 0\n0.95 0 0\n", WF_Y106, "zero everywhere", NULL);
    expect_load_error("Lambda R062\n0.9 1\n", WF_R062, ":1:", "Wave");
    expect_load_error("", WF_R062, "empty", NULL);

    /* the first non-blank line is the header, even behind a '#': a comment there is an
     * error, not silently skipped */
    static wf_bandpass bp;
    const char *dir = fake_data_dir("# a comment where the header belongs\n"
                                    "Wave W149\n0.80 0\n0.85 0\n0.90 0.1\n0.95 0.2\n1.00 0\n"
                                    "1.05 0\n");
    ck_assert_int_eq(wf_bandpass_load(WF_W146, dir, &bp), WF_ERR_INPUT);
    /* a good small file loads (W149 column for W146), its zeros trimmed to one per side */
    dir = fake_data_dir("Wave W149\n0.80 0\n0.85 0\n0.90 0.1\n0.95 0.2\n1.00 0\n1.05 0\n");
    ck_assert_int_eq(wf_bandpass_load(WF_W146, dir, &bp), WF_OK);
    ck_assert_int_eq(bp.n, 4);
    ck_assert_double_eq_tol(bp.blue_nm, 850.0, 1e-9);
    ck_assert_double_eq_tol(bp.red_nm, 1000.0, 1e-9);
    ck_assert_double_eq_tol(wf_bandpass_throughput(&bp, 925.0),
                            0.15 * 1e4 / WF_COLLECTING_AREA_CM2, 1e-15);
    /* ∫T dλ: three trapezoids of 50 nm, effective areas in m² scaled to throughput */
    double s = 1e4 / WF_COLLECTING_AREA_CM2;
    ck_assert_double_eq_tol(bp.int_t, s * (0.5 * 50 * 0.1 + 0.5 * 50 * 0.3 + 0.5 * 50 * 0.2),
                            1e-12);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("bandpass");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, test_filter_names);
    tcase_add_test(tc, test_tophat_closed_forms);
    tcase_add_test(tc, test_ab_rates);
    tcase_add_test(tc, test_sed_integrator);
    tcase_add_test(tc, test_real_vs_galsim_and_spec);
    tcase_add_test(tc, test_throughput_vs_1nm_csv);
    tcase_add_test(tc, test_tophat_vs_real);
    tcase_add_test(tc, test_bad_files);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
