/* `wfisim sn generate | lightcurves | lightcurve` as users run them: the count against the rate
 * law, positions inside the footprint, hosts within the redshift tolerance and inside their
 * 99% light ellipse, reproducibility by seed (all 64 bits of it), light curves consistent
 * between the commands, and bad input named. */
#include <fitsio.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/survey/catalog.h"
#include "sim/sn/cosmology.h"
#include "sim/sn/hostlib.h"
#include "sim/sn/sncat.h"
#include "sim/sn/snhost.h"
#include "sim/sn/snrate.h"
#include "tests/testutil.h"

static double header_double(const char *path, const char *key)
{
    fitsfile *f;
    int status = 0;
    double v = NAN;
    fits_open_file(&f, path, READONLY, &status);
    fits_read_key_dbl(f, key, &v, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_msg(status == 0, "%s: no %s", path, key);
    return v;
}

START_TEST(generate_circle_hostless)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the SALT model data");
    const char *d = wf_test_tmpdir();
    const double area = 0.5, days = 100.0;
    for (int k = 0; k < 3; k++)
        ck_assert_int_eq(wf_test_run("%s sn generate --data %s --area %g --start 61420 --days %g --hostless --seed %d "
                             "--out %s/g%d.fits >/dev/null", bin, data, area, days, k == 2 ? 6 : 5, d, k), 0);
    char a[4200], b[4200], c[4200];
    snprintf(a, sizeof a, "%s/g0.fits", d);
    snprintf(b, sizeof b, "%s/g1.fits", d);
    snprintf(c, sizeof c, "%s/g2.fits", d);
    size_t la, lb, lc;
    char *x = wf_test_slurp(a, &la), *y = wf_test_slurp(b, &lb), *z = wf_test_slurp(c, &lc);
    ck_assert_msg(la == lb && !memcmp(x, y, la), "same seed, different sample");
    ck_assert_msg(la != lc || memcmp(x, z, la), "another seed, same sample");
    free(x), free(y), free(z);

    /* expected count: the SPEC law over the window padded by the model's phase range (SALT3:
     * -20..+50 rest days) stretched by 1 + zmax */
    wf_snrate law;
    wf_cosmo cosmo;
    wf_snrate_default(&law);
    ck_assert_int_eq(wf_cosmo_init(&cosmo, 70.0, 0.315), 0);
    double padded = days + (50.0 + 20.0) * (1.0 + 2.99), expect;
    ck_assert_int_eq(wf_snrate_expected(&law, &cosmo, 0.06, 2.99, area, padded, &expect), 0);
    ck_assert_double_eq_tol(header_double(a, "NEXPECT"), expect, 1e-6 * expect);
    wf_sn_sample s;
    ck_assert_int_eq(wf_sn_sample_read(a, &s), 0);
    ck_assert_msg(fabs((double)s.n - expect) < 4.0 * sqrt(expect), "%zu SNe, %.1f expected", s.n, expect);
    /* cap of solid angle `area` about (71, -53) */
    double r = acos(1.0 - area * pow(M_PI / 180.0, 2) / (2.0 * M_PI));
    const double d2r = M_PI / 180.0;
    for (size_t i = 0; i < s.n; i++) {
        double cosd = sin(-53 * d2r) * sin(s.dec[i] * d2r) + cos(-53 * d2r) * cos(s.dec[i] * d2r) * cos((s.ra[i] - 71) * d2r);
        ck_assert_msg(acos(fmin(1.0, cosd)) <= r * (1 + 1e-9), "SN %zu outside the circle", i);
        ck_assert(s.z[i] >= 0.06 && s.z[i] <= 2.99);
        ck_assert(s.t0[i] >= 61420 - 50 * 3.99 - 1e-6 && s.t0[i] <= 61520 + 20 * 3.99 + 1e-6);
        ck_assert(s.host_id[i] == -1 && (s.flags[i] & WF_SN_FLAG_HOSTLESS) && (s.flags[i] & WF_SN_FLAG_NOHOSTCAT));
        double mu;
        ck_assert_int_eq(wf_cosmo_distance_modulus(&cosmo, s.z[i], &mu), 0);
        ck_assert_double_eq_tol(s.mu[i], mu, 1e-9);
        double x0 = pow(10.0, -0.4 * (mu - 0.14 * s.x1[i] + 3.1 * s.c[i] + s.delta[i])) / 1e-12;
        ck_assert_double_eq_tol(s.x0[i] / x0, 1.0, 1e-12);
    }
    wf_sn_sample_free(&s);
}
END_TEST

START_TEST(generate_with_hostlib)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the host library and SALT data");
    const char *d = wf_test_tmpdir();
    char hostlib[4200], out[4200];
    snprintf(hostlib, sizeof hostlib, "%s/hosts/Akari_Hosts_subset_SNR_v7.HOSTLIB", data);
    snprintf(out, sizeof out, "%s/h.fits", d);
    ck_assert_int_eq(wf_test_run("%s survey plan --quiet --data %s --set survey.visits=2 --out %s/plan.fits", bin, data, d), 0);
    ck_assert_int_eq(wf_test_run("%s sn generate --data %s --plan %s/plan.fits --catalog %s --seed 9 --out %s >/dev/null", bin,
                         data, d, hostlib, out), 0);
    wf_catalog gal;
    ck_assert_int_eq(wf_hostlib_read(hostlib, &gal, NULL), 0);
    wf_sn_sample s;
    ck_assert_int_eq(wf_sn_sample_read(out, &s), 0);
    ck_assert(s.n > 100);
    size_t hosted = 0;
    for (size_t i = 0; i < s.n; i++) {
        if (s.host_id[i] < 0) {
            ck_assert(s.flags[i] & WF_SN_FLAG_HOSTLESS);
            ck_assert_double_eq(s.host_a[i], 0.0);
            continue;
        }
        hosted++;
        size_t h = 0;
        while (h < gal.n && gal.id[h] != s.host_id[i]) h++;
        ck_assert_msg(h < gal.n, "host %lld is not in the library", (long long)s.host_id[i]);
        ck_assert_msg(fabs(s.z[i] - gal.z[h]) <= 0.01 + 1e-6, "SN z %.4f, host z %.4f", s.z[i], gal.z[h]);
        /* inside the 99% ellipse of its component: the round 99% radius (3.9553 r_e disk,
         * 18.9437 r_e bulge) stretched by the shear's major axis 1/sqrt(q) */
        double e = hypot(gal.e1[h], gal.e2[h]), q = sqrt((1 - e) / (1 + e));
        double r99 = s.host_comp[i] ? 18.9437 * gal.hlr_bulge[h] : 3.9553 * gal.hlr_disk[h];
        ck_assert_msg(s.host_offset[i] <= r99 / sqrt(q) * (1 + 1e-6) + 1e-9, "SN %zu: offset %.4f\" beyond %.4f\"", i,
                      s.host_offset[i], r99 / sqrt(q));
        /* HOSTA: the brighter component's half-light radius stretched the same way */
        double re = gal.bulge_frac[h] > 0.5 ? gal.hlr_bulge[h] : gal.hlr_disk[h];
        ck_assert_msg(fabs(s.host_a[i] / (re / sqrt(q)) - 1) < 1e-9, "SN %zu: HOSTA %.6f, expected %.6f", i,
                      s.host_a[i], re / sqrt(q));
    }
    ck_assert(hosted > 0);
    wf_sn_sample_free(&s);
    wf_catalog_free(&gal);
}
END_TEST

START_TEST(host_catalog_without_mass_is_named)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the SALT model data");
    const char *d = wf_test_tmpdir();
    char cat[4200], log[4200];
    snprintf(cat, sizeof cat, "%s/gal.csv", d);
    snprintf(log, sizeof log, "%s/log", d);
    FILE *f = fopen(cat, "w");
    ck_assert_ptr_nonnull(f);
    fprintf(f, "id,ra,dec,mag_Y106,hlr_disk,hlr_bulge,bulge_frac,knot_frac,e1,e2,pa,z,logsfr\n1,71.0,-53.0,22,0.3,0.1,0.2,0.1,0,0,0,0.5,0.1\n");
    fclose(f);
    ck_assert_int_ne(wf_test_run("%s sn generate --data %s --area 0.1 --start 61420 --days 30 --catalog %s --out %s/x.fits 2>%s",
                         bin, data, cat, d, log), 0);
    ck_assert_msg(wf_test_file_contains(log, "logmass"), "the message does not name the missing column");
    ck_assert_int_eq(wf_test_run("%s sn generate --data %s --area 0.1 --start 61420 --days 30 --hostless --out %s/x.fits "
                         ">/dev/null", bin, data, d), 0);
}
END_TEST

START_TEST(lightcurves_agree_with_lightcurve)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the SALT model data");
    const char *d = wf_test_tmpdir();
    char sne[4200], lc[4200], png[4200], txt[4200];
    snprintf(sne, sizeof sne, "%s/s.fits", d);
    snprintf(lc, sizeof lc, "%s/lc.fits", d);
    snprintf(txt, sizeof txt, "%s/one.txt", d);
    ck_assert_int_eq(wf_test_run("%s sn generate --data %s --area 0.05 --start 61420 --days 60 --hostless --seed 2 --out %s "
                         ">/dev/null", bin, data, sne), 0);
    wf_sn_sample s;
    ck_assert_int_eq(wf_sn_sample_read(sne, &s), 0);
    ck_assert(s.n > 3);
    /* the lowest-z SN: bright and covered by J129 (z >= 0.39 for the whole band) or not */
    size_t k = 0;
    for (size_t i = 0; i < s.n; i++)
        if (s.z[i] > 0.45 && (s.z[k] <= 0.45 || s.z[i] < s.z[k])) k = i;
    ck_assert(s.z[k] > 0.45);
    double t0 = s.t0[k];
    ck_assert_int_eq(wf_test_run("%s sn lightcurves --data %s --sne %s --grid %.6f:%.6f:5 --filters Y106,J129 --out %s "
                         "--plot %lld --plot-dir %s >/dev/null", bin, data, sne, t0 - 20, t0 + 30, lc,
                         (long long)s.id[k], d), 0);
    snprintf(png, sizeof png, "%s/lc_%lld.png", d, (long long)s.id[k]);
    size_t plen;
    char *p = wf_test_slurp(png, &plen);
    ck_assert_msg(p && plen > 8 && !memcmp(p, "\x89PNG\r\n\x1a\n", 8), "no PNG plot");
    free(p);
    fitsfile *f;
    int status = 0, cid, cb, cm, cmag;
    long nrows;
    fits_open_file(&f, lc, READONLY, &status);
    fits_movnam_hdu(f, BINARY_TBL, "LIGHTCURVES", 0, &status);
    fits_get_num_rows(f, &nrows, &status);
    ck_assert_int_eq(nrows, (long)s.n * 11 * 2);
    fits_get_colnum(f, CASEINSEN, "ID", &cid, &status);
    fits_get_colnum(f, CASEINSEN, "BAND", &cb, &status);
    fits_get_colnum(f, CASEINSEN, "MJD", &cm, &status);
    fits_get_colnum(f, CASEINSEN, "MAG", &cmag, &status);
    /* the same SN's J129 points through `wfisim sn lightcurve` (the direct 2-D path) */
    ck_assert_int_eq(wf_test_run("%s sn lightcurve --data %s --z %.17g --t0 %.17g --x0 %.17g --x1 %.17g --c %.17g --band J129 "
                         "--mjd %.6f,%.6f,%.6f > %s", bin, data, s.z[k], t0, s.x0[k], s.x1[k], s.c[k], t0 - 10, t0, t0 + 20,
                         txt), 0);
    char *t = wf_test_slurp(txt, NULL);
    ck_assert_ptr_nonnull(t);
    int matched = 0;
    for (long r = 1; r <= nrows && !status; r++) {
        long long id;
        char band[16], *bp = band;
        double mjd, mag;
        fits_read_col(f, TLONGLONG, cid, r, 1, 1, NULL, &id, NULL, &status);
        fits_read_col(f, TSTRING, cb, r, 1, 1, NULL, &bp, NULL, &status);
        fits_read_col(f, TDOUBLE, cm, r, 1, 1, NULL, &mjd, NULL, &status);
        fits_read_col(f, TDOUBLE, cmag, r, 1, 1, NULL, &mag, NULL, &status);
        if (id != s.id[k] || strcmp(band, "J129")) continue;
        for (const char *line = t; line && *line; line = strchr(line, '\n') ? strchr(line, '\n') + 1 : NULL) {
            double m2, g2, fl;
            unsigned fg;
            if (line[0] == '#' || sscanf(line, "%lf %lf %lf %u", &m2, &g2, &fl, &fg) != 4) continue;
            if (fabs(m2 - mjd) < 1e-5) {
                ck_assert_msg(fabs(g2 - mag) < 1e-4, "MJD %.3f: lightcurves %.6f, lightcurve %.6f", mjd, mag, g2);
                matched++;
            }
        }
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(matched, 3);
    free(t);
    wf_sn_sample_free(&s);
}
END_TEST

START_TEST(lightcurve_command)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the SALT model data");
    const char *d = wf_test_tmpdir();
    char out[4200];
    snprintf(out, sizeof out, "%s/o.txt", d);
    /* x0 from mu (SPEC 5) at x1 = c = 0; a date 200 days after peak is outside the model */
    ck_assert_int_eq(wf_test_run("%s sn lightcurve --data %s --z 0.7 --t0 61500 --mu 43.0 --band H158 --mjd 61500,61700 > %s",
                         bin, data, out), 0);
    char *t = wf_test_slurp(out, NULL);
    ck_assert_ptr_nonnull(t);
    const char *x0s = strstr(t, "x0 ");
    ck_assert_ptr_nonnull(x0s);
    ck_assert_double_eq_tol(atof(x0s + 3) / (pow(10.0, -0.4 * 43.0) / 1e-12), 1.0, 1e-7);
    ck_assert_msg(strstr(t, "61700.000000 99.000000 0 1") != NULL, "out-of-model date: %s", t);
    free(t);
    ck_assert_int_eq(wf_test_run("%s sn lightcurve --data %s --z 0.7 --t0 61500 --band Q999 --mjd 61500 2>%s", bin, data, out), 2);
    ck_assert(wf_test_file_contains(out, "Q999"));
    ck_assert_int_eq(wf_test_run("%s sn lightcurve --data %s --z 0.7 --t0 61500 --band H158 --mjd 61500,abc 2>%s >/dev/null", bin,
                         data, out), 2);
    ck_assert(wf_test_file_contains(out, "abc"));
    /* no dates at all, or an empty one, is an error before anything is printed */
    const char *empty[] = {",,,", "", "61500,,61700", "61500,"};
    for (int k = 0; k < 4; k++) {
        char so[4300];
        snprintf(so, sizeof so, "%s.stdout", out);
        ck_assert_msg(wf_test_run("%s sn lightcurve --data %s --z 0.7 --t0 61500 --band H158 --mjd '%s' 2>%s >%s", bin,
                                  data, empty[k], out, so) == 2, "--mjd '%s' accepted", empty[k]);
        ck_assert_msg(wf_test_file_contains(out, "is empty"), "--mjd '%s': no reason", empty[k]);
        size_t n = 1;
        free(wf_test_slurp(so, &n));
        ck_assert_msg(n == 0, "--mjd '%s': %zu bytes printed", empty[k], n);
    }
    /* an out-of-range value is named as given, not as the x0 it would have made */
    const struct { const char *opts, *named; } bad[] = {
        {"--x1 1e300 --c 1e300", "--x1 1e+300 is out of range"}, {"--c 1e300", "--c 1e+300 is out of range"},
        {"--x1 -10.5", "--x1 -10.5 is out of range"},          {"--mu 1e300", "--mu 1e+300 is out of range"},
        {"--alpha 1e300", "--alpha 1e+300 is out of range"},   {"--beta -21", "--beta -21 is out of range"},
        {"--x0 0", "--x0 must be > 0"}};
    for (size_t k = 0; k < sizeof bad / sizeof *bad; k++) {
        ck_assert_msg(wf_test_run("%s sn lightcurve --data %s --z 0.7 --t0 61500 --band H158 --mjd 61500 %s 2>%s >/dev/null",
                                  bin, data, bad[k].opts, out) == 2, "%s accepted", bad[k].opts);
        ck_assert_msg(wf_test_file_contains(out, bad[k].named), "%s: not named", bad[k].opts);
        char *msg = wf_test_slurp(out, NULL); /* its first line: the usage text that follows names every option */
        ck_assert_ptr_nonnull(msg);
        if (strchr(msg, '\n')) *strchr(msg, '\n') = '\0';
        ck_assert_msg(strstr(bad[k].opts, "--x0") || !strstr(msg, "--x0"), "%s: blames --x0: %s", bad[k].opts, msg);
        free(msg);
    }
    /* the ends of the ranges are taken, and W149 is W146 here as in expose */
    ck_assert_int_eq(wf_test_run("%s sn lightcurve --data %s --z 0.7 --t0 61500 --band W149 --mjd 61500 --x1 10 --c -2 "
                                 "--alpha 10 --beta 20 > %s", bin, data, out), 0);
    ck_assert(wf_test_file_contains(out, "band W146"));
}
END_TEST

/* SPEC 5's extreme cases through the single-SN command: the lowest redshift (every WFI band
 * lies beyond SALT3's red end: no flux, flag 2), the highest, the ends of the x1 and c ranges
 * at the model's first and last phases (finite, non-negative), and dates far outside. */
START_TEST(extreme_parameters)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the SALT model data");
    const char *d = wf_test_tmpdir();
    char out[4200];
    snprintf(out, sizeof out, "%s/x.txt", d);
    struct { double z, x1, c; const char *band; int covered; } cases[] = {
        {0.06, 0.0, 0.0, "Y106", 0}, {2.99, 0.0, 0.0, "F184", 1}, {2.99, 0.0, 0.0, "Y106", 1},
        {1.0, -3.0, 0.5, "J129", 1}, {1.0, 2.0, -0.3, "J129", 1}, {0.5, -3.0, -0.3, "Y106", 1}};
    for (size_t k = 0; k < sizeof cases / sizeof *cases; k++) {
        double zp1 = 1.0 + cases[k].z, t0 = 61500.0;
        /* just inside the first and last model phases (-20, +50 rest days; the edges themselves
         * are tests/test_salt.c's), then far outside */
        ck_assert_int_eq(wf_test_run("%s sn lightcurve --data %s --z %g --t0 %g --x1 %g --c %g --band %s "
                             "--mjd %.9f,%.9f,%.9f,%.9f > %s", bin, data, cases[k].z, t0, cases[k].x1, cases[k].c,
                             cases[k].band, t0 - 19.999 * zp1, t0 + 49.999 * zp1, t0 - 1e5, t0 + 1e6, out), 0);
        char *t = wf_test_slurp(out, NULL);
        ck_assert_ptr_nonnull(t);
        int line = 0;
        for (const char *p = t; p && *p; p = strchr(p, '\n') ? strchr(p, '\n') + 1 : NULL) {
            double mjd, mag, flux;
            unsigned flag;
            if (*p == '#' || sscanf(p, "%lf %lf %lf %u", &mjd, &mag, &flux, &flag) != 4) continue;
            ck_assert_msg(isfinite(mag) && isfinite(flux) && flux >= 0, "z %g %s: mag %g flux %g", cases[k].z,
                          cases[k].band, mag, flux);
            if (line >= 2) ck_assert_msg(flag & 1u, "z %g: date %.1f outside the model not flagged", cases[k].z, mjd);
            else if (!cases[k].covered) ck_assert_msg(flag == 2u && mag == 99.0 && flux == 0.0, "z %g %s: flag %u",
                                                      cases[k].z, cases[k].band, flag);
            else /* at the first and last phases M0 + x1 M1 may go negative for extreme x1: then
                  * flag 4 with flux 0 and mag 99 (documented); a normal SN has light there */
                ck_assert_msg((flag == 0u && flux > 0 && mag < 99.0) ||
                                  (cases[k].x1 != 0.0 && flag == 4u && flux == 0.0 && mag == 99.0),
                              "z %g %s x1 %g c %g: flag %u flux %g at a model edge", cases[k].z, cases[k].band,
                              cases[k].x1, cases[k].c, flag, flux);
            line++;
        }
        ck_assert_int_eq(line, 4);
        free(t);
    }
}
END_TEST

/* sn.* keys from a configuration file and --set: a rate law with both pieces doubled doubles
 * the expected count; a narrower x1 range holds every drawn x1; a wrong key is named. */
START_TEST(configuration_keys)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the SALT model data");
    const char *d = wf_test_tmpdir();
    char yaml[4200], a[4200], b[4200], log[4200];
    snprintf(yaml, sizeof yaml, "%s/sn.yaml", d);
    snprintf(a, sizeof a, "%s/a.fits", d);
    snprintf(b, sizeof b, "%s/b.fits", d);
    snprintf(log, sizeof log, "%s/log", d);
    FILE *f = fopen(yaml, "w");
    ck_assert_ptr_nonnull(f);
    fprintf(f, "sn:\n  rate: \"POWERLAW2 5.0e-5 1.5 0 1; POWERLAW2 19.4e-5 -0.5 1 3\"\n  x1:\n    max: 1.0\n");
    fclose(f);
    const char *common = "--area 0.2 --start 61420 --days 100 --hostless";
    ck_assert_int_eq(wf_test_run("%s sn generate --data %s %s --out %s >/dev/null", bin, data, common, a), 0);
    ck_assert_int_eq(wf_test_run("%s sn generate --data %s %s --config %s --set sn.x1.min=-1.5 --out %s >/dev/null", bin, data,
                         common, yaml, b), 0);
    ck_assert_double_eq_tol(header_double(b, "NEXPECT") / header_double(a, "NEXPECT"), 2.0, 1e-9);
    wf_sn_sample s;
    ck_assert_int_eq(wf_sn_sample_read(b, &s), 0);
    ck_assert(s.n > 50);
    for (size_t i = 0; i < s.n; i++) ck_assert_msg(s.x1[i] >= -1.5 && s.x1[i] <= 1.0, "x1 %g outside [-1.5, 1]", s.x1[i]);
    wf_sn_sample_free(&s);
    ck_assert_int_eq(wf_test_run("%s sn generate --data %s %s --set sn.x1.maxx=1 --out %s 2>%s", bin, data, common, b, log), 2);
    ck_assert(wf_test_file_contains(log, "sn.x1.maxx"));
}
END_TEST

/* The sample drawn with a seed: its redshifts and peak dates (the header's SEED card would
 * tell two files apart even when the draws were the same). */
static int same_draws(const char *a, const char *b)
{
    wf_sn_sample x, y;
    ck_assert_int_eq(wf_sn_sample_read(a, &x), 0);
    ck_assert_int_eq(wf_sn_sample_read(b, &y), 0);
    ck_assert(x.n > 3 && y.n > 3);
    int same = x.n == y.n && !memcmp(x.z, y.z, x.n * sizeof *x.z) && !memcmp(x.t0, y.t0, x.n * sizeof *x.t0);
    wf_sn_sample_free(&x);
    wf_sn_sample_free(&y);
    return same;
}

static unsigned long long header_seed(const char *path)
{
    fitsfile *f;
    int status = 0;
    unsigned long long v = 0;
    fits_open_file(&f, path, READONLY, &status);
    fits_read_key(f, TULONGLONG, "SEED", &v, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_msg(status == 0, "%s: no SEED", path);
    return v;
}

/* --seed takes all 64 bits: 2^53 and 2^53 + 1 are one double, but two samples; the largest
 * seed is kept exactly in the header; anything else is refused, naming the option. The
 * configuration's seed (--set seed=) reaches the draws unrounded too. */
START_TEST(seed_takes_64_bits)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the SALT model data");
    const char *d = wf_test_tmpdir();
    const char *common = "--area 0.05 --start 61420 --days 60 --hostless";
    static const char *const seeds[] = {"9007199254740992", "9007199254740993", "18446744073709551615"};
    char path[4][4200], log[4200];
    for (int k = 0; k < 3; k++) {
        snprintf(path[k], sizeof path[k], "%s/s%d.fits", d, k);
        ck_assert_int_eq(wf_test_run("%s sn generate --data %s %s --seed %s --out %s >/dev/null", bin, data, common,
                                     seeds[k], path[k]), 0);
        ck_assert_msg(header_seed(path[k]) == strtoull(seeds[k], NULL, 10), "SEED %llu, asked for %s",
                      header_seed(path[k]), seeds[k]);
    }
    ck_assert_msg(!same_draws(path[0], path[1]), "seeds 2^53 and 2^53 + 1 drew the same sample");
    snprintf(path[3], sizeof path[3], "%s/s3.fits", d);
    ck_assert_int_eq(wf_test_run("%s sn generate --data %s %s --set seed=9007199254740993 --out %s >/dev/null", bin,
                                 data, common, path[3]), 0);
    ck_assert_msg(same_draws(path[1], path[3]), "--set seed=2^53+1 and --seed 2^53+1 differ");

    snprintf(log, sizeof log, "%s/log", d);
    static const struct { const char *arg, *why; } bad[] = {
        {"18446744073709551616", "out of range"}, {"-1", "non-negative integer"},
        {"1e3", "non-negative integer"},          {"12x", "non-negative integer"},
        {"' 5'", "non-negative integer"},         {"''", "non-negative integer"},
    };
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        ck_assert_int_eq(wf_test_run("%s sn generate --data %s %s --seed %s --out %s/x.fits >/dev/null 2>%s", bin, data,
                                     common, bad[k].arg, d, log), 2);
        ck_assert_msg(wf_test_file_contains(log, "--seed") && wf_test_file_contains(log, bad[k].why),
                      "--seed %s: the message does not say '--seed ... %s'", bad[k].arg, bad[k].why);
    }
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("sncmd");
    TCase *tc = tcase_create("all");
    tcase_set_timeout(tc, 300);
    tcase_add_test(tc, generate_circle_hostless);
    tcase_add_test(tc, generate_with_hostlib);
    tcase_add_test(tc, host_catalog_without_mass_is_named);
    tcase_add_test(tc, lightcurves_agree_with_lightcurve);
    tcase_add_test(tc, lightcurve_command);
    tcase_add_test(tc, extreme_parameters);
    tcase_add_test(tc, configuration_keys);
    tcase_add_test(tc, seed_takes_64_bits);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
