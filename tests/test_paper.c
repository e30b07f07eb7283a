/* make paper (scripts/paper.sh) end to end on a tiny survey: four visits 60 days apart, one
 * SCA each, every stage of the real run. The numbers of summary.json are checked against what
 * they must be whatever the code computes: the coadd of N epochs is deeper than one epoch on
 * the same grid by about 1.25 log10 N for point sources, a difference image is shallower than
 * one epoch on that grid by the template's noise, and the host counts add up. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "tests/testutil.h"

static const char *const required[] = {
    "galaxy_m50_single", "galaxy_m50_coadd",   "star_m50_single",     "star_m50_coadd",  "sn_m50_diff",
    "hosts_total",       "hosts_correct",      "hosts_nearest_wrong", "hosts_undetected",
};

static double num(const char *json, const char *key)
{
    const char *const k[1] = {key};
    return wf_test_json_number(json, k, 1);
}

START_TEST(tiny_survey)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the Roman and SALT data");
#if defined(__SANITIZE_ADDRESS__)
    /* the whole chain on four full SCAs takes over 12 minutes under ASan (rendering and SEP
     * through the instrumented program): more than CI's whole budget. Its stages are each
     * checked under the sanitizers by their own tests (test_surveyrun, test_coadd, test_detect,
     * test_efficiency, test_hosts); this one runs in the plain build. */
    WF_SKIP("the end-to-end script under AddressSanitizer (run in the plain build)");
#endif
    const char *d = wf_test_tmpdir();
    char out[4200], path[4300];
    snprintf(out, sizeof out, "%s/paper", d);
    /* the template windows (5 days) hold one epoch each at either end */
    ck_assert_int_eq(wf_test_run("WFISIM='%s' sh scripts/paper.sh --data '%s' --out '%s' --visits 4 "
                                 "--set survey.visit_interval=60 --template-days 5 --singles 2 > '%s/log' 2>&1",
                                 bin, data, out, d),
                     0);
    snprintf(path, sizeof path, "%s/summary.json", out);
    char *j = wf_test_slurp(path, NULL);
    ck_assert_msg(j, "no %s", path);
    snprintf(path, sizeof path, "%s/summary.json.tmp", out);
    ck_assert_int_ne(access(path, F_OK), 0);
    for (size_t i = 0; i < sizeof required / sizeof *required; i++)
        ck_assert_msg(isfinite(num(j, required[i])), "%s is not a number in summary.json", required[i]);
    const char *pngs[4] = {"single_efficiency.png", "coadd_efficiency.png", "diff_efficiency.png", "hosts.png"};
    for (int i = 0; i < 4; i++) {
        snprintf(path, sizeof path, "%s/%s", out, pngs[i]);
        size_t len = 0;
        char *png = wf_test_slurp(path, &len);
        ck_assert_msg(png && len > 8 && !memcmp(png, "\x89PNG\r\n\x1a\n", 8), "%s is not a PNG", path);
        free(png);
    }
    /* the plan: 4 visits; at this centre every visit puts the circle on one SCA */
    double n = num(j, "coadd_inputs");
    ck_assert_double_eq(num(j, "products"), 4);
    ck_assert_double_eq(n, 4);
    ck_assert_double_eq(num(j, "diffs"), 4);
    /* one epoch: the star 50% point near the 26.25-26.6 measured on single exposures
     * (docs/ANALYSIS.md), galaxies (extended) brighter than stars */
    double ss = num(j, "star_m50_single"), gs = num(j, "galaxy_m50_single");
    ck_assert_msg(ss > 25.7 && ss < 27.0, "star m50 single %.3f", ss);
    ck_assert_msg(gs > 24.0 && gs < ss, "galaxy m50 single %.3f (stars %.3f)", gs, ss);
    /* the same epochs drizzled alone onto the 0.0575" grid the coadds and the differences are
     * detected on: the reference for both (docs/ANALYSIS.md, "Depth on the drizzled grid") */
    double sr = num(j, "star_m50_resampled"), esr = num(j, "star_m50_resampled_err");
    double gr = num(j, "galaxy_m50_resampled");
    ck_assert_msg(isfinite(sr) && isfinite(esr) && isfinite(gr), "no resampled single depth");
    ck_assert_msg(gr < sr, "resampled: galaxies %.3f, stars %.3f", gr, sr);
    /* the coadd: sqrt(N) less noise for a point source, 1.25 log10 N magnitudes deeper than
     * one epoch on the same grid (both thresholds 1.5 of the measured sigma) */
    double gain = 1.25 * log10(n), sc = num(j, "star_m50_coadd"), gc = num(j, "galaxy_m50_coadd");
    double esc = num(j, "star_m50_coadd_err");
    ck_assert_msg(fabs(sc - sr - gain) < 0.3 + 3 * hypot(esc, esr), "stars: coadd %.3f resampled single %.3f, "
                  "expected +%.3f", sc, sr, gain);
    /* galaxies gain too, by no more than a point source (their light is spread over more
     * pixels, each of which gains sqrt(N)) */
    ck_assert_msg(gc - gr > 0.15 && gc - gr < gain + 0.3, "galaxies: coadd %.3f resampled single %.3f (point gain "
                  "%.3f)", gc, gr, gain);
    /* the measured noise scales of detection (docs/ANALYSIS.md, "Detection thresholds"):
     * drizzle's covariance is positive, so the filtered sky's sigma exceeds what ERR says,
     * by less than Fruchter & Hook's large-aperture ratio R = r / (1 - 1/(3r)), r = pixfrac /
     * (0.0575 / 0.11): the coadds' and resampled singles' pixfrac 0.7, a difference's epoch
     * resampled with pixfrac 1 */
    double rs = 0.0575 / 0.11, r7 = 0.7 / rs, r1 = 1.0 / rs;
    double cn = num(j, "coadd_noise_scale"), dn = num(j, "diff_noise_scale"), rn = num(j, "resampled_noise_scale");
    ck_assert_msg(cn > 1.02 && cn < r7 / (1 - 1 / (3 * r7)), "coadd noise scale %.3f", cn);
    ck_assert_msg(rn > 1.02 && rn < r7 / (1 - 1 / (3 * r7)), "resampled single noise scale %.3f", rn);
    ck_assert_msg(dn > 1.02 && dn < r1 / (1 - 1 / (3 * r1)), "difference noise scale %.3f", dn);
    /* an SN on a difference image: one epoch's noise plus a template of one epoch (sqrt 2),
     * 1.25 log10 2 = 0.38 mag shallower than a star in one epoch on the same grid, within the
     * fit's errors and the template's SN light */
    double sd = num(j, "sn_m50_diff"), esd = num(j, "sn_m50_diff_err");
    double expect = sr - 1.25 * log10(2.0);
    fprintf(stderr, "tiny survey: stars single %.3f +- %.3f resampled %.3f +- %.3f coadd %.3f +- %.3f (gain %.3f "
                    "expected %.3f); galaxies single %.3f resampled %.3f coadd %.3f; SN diff %.3f +- %.3f (expected "
                    "%.3f); noise scales resampled %.3f coadd %.3f diff %.3f\n",
            ss, num(j, "star_m50_single_err"), sr, esr, sc, esc, sc - sr, gain, gs, gr, gc, sd, esd, expect, rn, cn, dn);
    ck_assert_msg(fabs(sd - expect) < 0.3 + 3 * hypot(esd, esr), "SN m50 on differences %.3f +- %.3f, expected %.3f",
                  sd, esd, expect);
    /* isolated SNe (SPEC 8) are a subset of the SNe scored on the differences */
    ck_assert_double_le(num(j, "sn_n_true_diff_isolated") + num(j, "sn_n_not_isolated_diff"), num(j, "sn_n_true_diff"));
    /* the hosts: every SN with a host in the coadd is one of correct, wrong, undetected,
     * by either rule; every host is in the truth (the renderer and sn generate drew the same
     * extended synthetic field) */
    double tot = num(j, "hosts_total"), und = num(j, "hosts_undetected");
    ck_assert_double_gt(tot, 20);
    ck_assert_double_eq(tot, num(j, "hosts_correct") + num(j, "hosts_dlr_wrong") + und);
    ck_assert_double_eq(tot, num(j, "hosts_nearest_correct") + num(j, "hosts_nearest_wrong") + und);
    ck_assert_double_eq(num(j, "hosts_outside"), 0);
    ck_assert_double_eq(num(j, "sne_total"), tot + num(j, "sne_hostless"));
    /* time by stage, every stage */
    const char *stages[] = {"plan", "sne", "render", "coadd", "resample", "diff", "detect", "efficiency", "hosts"};
    for (int i = 0; i < 9; i++) {
        const char *k[2] = {"seconds", stages[i]};
        ck_assert_msg(wf_test_json_number(j, k, 2) >= 0, "no time for stage %s", stages[i]);
    }
    free(j);
}
END_TEST

/* Bad usage stops before anything is made: exit 2, the problem named. */
START_TEST(bad_usage)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char log[4200];
    snprintf(log, sizeof log, "%s/err", d);
    ck_assert_int_eq(wf_test_run("WFISIM='%s' sh scripts/paper.sh --out '%s/p' --frobnicate 1 2>'%s'", bin, d, log), 2);
    ck_assert(wf_test_file_contains(log, "unknown option --frobnicate"));
    ck_assert_int_eq(wf_test_run("WFISIM_DATA= WFISIM='%s' sh scripts/paper.sh --out '%s/p' 2>'%s'", bin, d, log), 2);
    ck_assert(wf_test_file_contains(log, "no data folder"));
    ck_assert_int_eq(wf_test_run("WFISIM='%s' sh scripts/paper.sh --data . --area 71 --out '%s/p' 2>'%s'", bin, d, log),
                     2);
    ck_assert(wf_test_file_contains(log, "--area wants RA,DEC,R"));
    char p[4300];
    snprintf(p, sizeof p, "%s/p", d);
    ck_assert_int_ne(access(p, F_OK), 0);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("paper");
    TCase *tc = tcase_create("all");
    tcase_set_timeout(tc, 1800);
    tcase_add_test(tc, tiny_survey);
    tcase_add_test(tc, bad_usage);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
