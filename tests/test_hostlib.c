/* SNANA HOSTLIB reader (sim/sn/hostlib) and the a_rot convention through the SN placement
 * (sim/sn/snhost):
 *  - the shared library ../shared/data/hosts/Akari_Hosts_subset_SNR_v7.HOSTLIB (skipped when
 *    absent): 5000 rows, RA/Dec/z ranges and the first row against an independent parse of
 *    the text; its WGTMAP against sSNR(AH18) × 10^logmass at every node;
 *  - a small hand-written library (plain and gzip'd): DOCUMENTATION block, comments, unused
 *    text columns, components in either order, a zero-weight component, b > a, RA wrapping;
 *  - bad files (missing column, not a number, NaN, truncated row, GAL: before VARNAMES,
 *    Sérsic index, range, no magnitudes, missing file): status and a message naming the
 *    file, the line and the column;
 *  - a_rot: a SN put on the major and minor axes of a HOSTLIB host lands where SNANA's
 *    GEN_SNHOST_POS formula puts it. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zlib.h>

#include "sim/sn/hostlib.h"
#include "sim/sn/snhost.h"
#include "tests/testutil.h"

#define DEG (M_PI / 180.0)
#define ARCSEC_PER_RAD 206264.80624709636

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void write_text(const char *path, const char *text)
{
    FILE *fp = fopen(path, "w");
    ck_assert_msg(fp != NULL, "cannot write %s", path);
    fputs(text, fp);
    fclose(fp);
}

static int close_to(double a, double b, double rel) { return fabs(a - b) <= rel * fmax(1.0, fabs(b)); }

/* ------------------------------------------------------------------ the shared library */

static const char *shared_hostlib(char *buf, size_t size)
{
    const char *data = wf_test_data_dir();
    if (!data) return NULL;
    snprintf(buf, size, "%s/hosts/Akari_Hosts_subset_SNR_v7.HOSTLIB", data);
    FILE *fp = fopen(buf, "r");
    if (!fp) return NULL;
    fclose(fp);
    return buf;
}

#define MAXTOK 128

/* Whitespace split of a copy of line: the test's own reading of the text. */
static int split(const char *line, char *copy, size_t size, char **tok)
{
    snprintf(copy, size, "%s", line);
    int n = 0;
    for (char *t = strtok(copy, " \t\r\n"); t && n < MAXTOK; t = strtok(NULL, " \t\r\n")) tok[n++] = t;
    return n;
}

static int find(char **tok, int n, const char *name)
{
    for (int k = 0; k < n; k++)
        if (strcmp(tok[k], name) == 0) return k;
    return -1;
}

START_TEST(test_shared_hostlib)
{
    char path[4096];
    const char *p = shared_hostlib(path, sizeof path);
    WF_SKIP_UNLESS(p, "hosts/Akari_Hosts_subset_SNR_v7.HOSTLIB");

    /* independent scan of the text: VARNAMES, first GAL: row, ranges, counts */
    char *text = wf_test_slurp(p, NULL);
    ck_assert_ptr_nonnull(text);
    static char names_copy[8192], row_copy[8192], copy[8192];
    char *names[MAXTOK], *first[MAXTOK], *tok[MAXTOK];
    int nnames = 0, nfirst = 0;
    long ngal = 0, nwgt = 0, zero_w1 = 0;
    double ra_lo = 1e9, ra_hi = -1e9, dec_lo = 1e9, dec_hi = -1e9, z_lo = 1e9, z_hi = -1e9;
    char *save = NULL;
    for (char *line = strtok_r(text, "\n", &save); line; line = strtok_r(NULL, "\n", &save)) {
        if (strncmp(line, "VARNAMES:", 9) == 0) nnames = split(line, names_copy, sizeof names_copy, names);
        if (strncmp(line, "WGT:", 4) == 0) nwgt++;
        if (strncmp(line, "GAL:", 4) != 0) continue;
        ngal++;
        if (nfirst == 0) nfirst = split(line, row_copy, sizeof row_copy, first);
        /* fields after "GAL:" in the file's order: GALID RA_GAL DEC_GAL ZTRUE ... w1 at 12 */
        double v[13];
        int got = sscanf(line, "GAL: %lf %lf %lf %lf %lf %lf %lf %lf %lf %lf %lf %lf", &v[0], &v[1],
                         &v[2], &v[3], &v[4], &v[5], &v[6], &v[7], &v[8], &v[9], &v[10], &v[11]);
        ck_assert_int_eq(got, 12);
        ra_lo = fmin(ra_lo, v[1]);
        ra_hi = fmax(ra_hi, v[1]);
        dec_lo = fmin(dec_lo, v[2]);
        dec_hi = fmax(dec_hi, v[2]);
        z_lo = fmin(z_lo, v[3]);
        z_hi = fmax(z_hi, v[3]);
        zero_w1 += v[11] == 0.0;
    }
    ck_assert_int_eq(nfirst, nnames);
    (void)tok;
    (void)copy;

    double t0 = now_s();
    wf_catalog cat;
    wf_hostlib_info info;
    ck_assert_msg(wf_hostlib_read(p, &cat, &info) == WF_OK, "%s", wf_error_message());
    double t1 = now_s();
    ck_assert_uint_eq(cat.n, 5000);
    ck_assert_int_eq(ngal, 5000);
    ck_assert_uint_eq(info.ngal, 5000);
    ck_assert_int_eq(info.nvarnames, nnames - 1);
    ck_assert_int_eq(cat.kind, WF_CATALOG_GALAXY);
    ck_assert_int_eq(cat.nband, 4);
    ck_assert_str_eq(cat.band[0], "Y106");
    ck_assert_str_eq(cat.band[1], "J129");
    ck_assert_str_eq(cat.band[2], "H158");
    ck_assert_str_eq(cat.band[3], "F184");
    ck_assert(cat.has_z && cat.has_logmass && cat.has_logsfr);
    ck_assert_uint_eq(info.zero_bulge, (size_t)zero_w1);

    double cra_lo = 1e9, cra_hi = -1e9, cdec_lo = 1e9, cdec_hi = -1e9, cz_lo = 1e9, cz_hi = -1e9;
    for (size_t i = 0; i < cat.n; i++) {
        cra_lo = fmin(cra_lo, cat.ra[i]);
        cra_hi = fmax(cra_hi, cat.ra[i]);
        cdec_lo = fmin(cdec_lo, cat.dec[i]);
        cdec_hi = fmax(cdec_hi, cat.dec[i]);
        cz_lo = fmin(cz_lo, cat.z[i]);
        cz_hi = fmax(cz_hi, cat.z[i]);
        ck_assert(cat.hlr_disk[i] > 0.0f && cat.hlr_bulge[i] > 0.0f);
        ck_assert(cat.bulge_frac[i] >= 0.0f && cat.bulge_frac[i] <= 1.0f);
        ck_assert((double)cat.e1[i] * cat.e1[i] + (double)cat.e2[i] * cat.e2[i] < 1.0);
    }
    printf("shared HOSTLIB: %zu galaxies read in %.3f s; RA %.5f..%.5f, Dec %.5f..%.5f, z "
           "%.4f..%.4f; %zu zero-weight bulges, %zu zero-weight disks; WGTMAP %zu nodes\n",
           cat.n, t1 - t0, cra_lo, cra_hi, cdec_lo, cdec_hi, cz_lo, cz_hi, info.zero_bulge,
           info.zero_disk, info.wgtmap.n);
    ck_assert(cra_lo == ra_lo && cra_hi == ra_hi && cdec_lo == dec_lo && cdec_hi == dec_hi);
    ck_assert(cz_lo == (float)z_lo && cz_hi == (float)z_hi);
    /* SOURCE.txt: re-mapped onto the Akari field, RA ~70-72, Dec ~-52..-54 */
    ck_assert(cra_lo > 69.0 && cra_hi < 73.0 && cdec_lo > -55.0 && cdec_hi < -51.5);
    ck_assert(cz_lo > 0.0 && cz_hi < 5.0);

    /* the first row, field by field against the text */
#define COL(name) (atof(first[find(names, nnames, name)]))
    ck_assert(find(names, nnames, "a_rot") > 0 && find(names, nnames, "w1_Sersic") > 0);
    ck_assert(cat.id[0] == atoll(first[find(names, nnames, "GALID")]));
    ck_assert(cat.ra[0] == COL("RA_GAL") && cat.dec[0] == COL("DEC_GAL"));
    ck_assert(cat.z[0] == (float)COL("ZTRUE"));
    ck_assert(cat.mag[0][0] == (float)COL("y_obs") && cat.mag[1][0] == (float)COL("j_obs"));
    ck_assert(cat.mag[2][0] == (float)COL("h_obs") && cat.mag[3][0] == (float)COL("f_obs"));
    ck_assert(cat.logmass[0] == (float)COL("logmass") && cat.logsfr[0] == (float)COL("logsfr"));
    ck_assert(COL("n0_Sersic") == 1.0 && COL("n1_Sersic") == 4.0);
    double a0 = COL("a0_Sersic"), b0 = COL("b0_Sersic"), w0 = COL("w0_Sersic");
    double a1 = COL("a1_Sersic"), b1 = COL("b1_Sersic"), w1 = COL("w1_Sersic");
    double arot = COL("a_rot");
    ck_assert(close_to(cat.hlr_disk[0], sqrt(a0 * b0), 1e-6));
    ck_assert(close_to(cat.hlr_bulge[0], sqrt(a1 * b1), 1e-6));
    ck_assert(close_to(cat.bulge_frac[0], w1 / (w0 + w1), 1e-6));
    double da = w1 > w0 ? a1 : a0, db = w1 > w0 ? b1 : b0;
    double e = (da * da - db * db) / (da * da + db * db);
    ck_assert(close_to(cat.e1[0], e * cos(2.0 * arot * DEG), 1e-6));
    ck_assert(close_to(cat.e2[0], e * sin(2.0 * arot * DEG), 1e-6));
    ck_assert(cat.pa[0] == 0.0f && cat.knot_frac[0] == 0.0f);
#undef COL
    printf("first row: GALID %lld z %.4f hlr_disk %.5f hlr_bulge %.5f B/T %.4f e %.5f a_rot %.3f "
           "-> e1 %.5f e2 %.5f\n",
           (long long)cat.id[0], (double)cat.z[0], (double)cat.hlr_disk[0], (double)cat.hlr_bulge[0],
           (double)cat.bulge_frac[0], e, arot, (double)cat.e1[0], (double)cat.e2[0]);

    /* the weight map as written */
    ck_assert(info.has_wgtmap);
    ck_assert_int_eq((long)info.wgtmap.n, nwgt);
    ck_assert_int_eq(info.wgtmap.nvar, 2);
    ck_assert_str_eq(info.wgtmap.var[0], "logssfr");
    ck_assert_str_eq(info.wgtmap.var[1], "logmass");
    ck_assert(info.wgtmap.has_snmagshift);
    free(text);
    wf_hostlib_info_free(&info);
    wf_catalog_free(&cat);
}
END_TEST

START_TEST(test_shared_wgtmap)
{
    /* The file's WGT should be ∝ sSNR(AH18) × 10^logmass (SOURCE.txt). Compare the weight of
     * sim/sn/snhost at every node, after one scale fixed at the largest node; WGT is printed
     * with 7 decimals, so each may differ by 5e-8 from its exact value. */
    char path[4096];
    const char *p = shared_hostlib(path, sizeof path);
    WF_SKIP_UNLESS(p, "hosts/Akari_Hosts_subset_SNR_v7.HOSTLIB");
    wf_catalog cat;
    wf_hostlib_info info;
    ck_assert_int_eq(wf_hostlib_read(p, &cat, &info), WF_OK);
    const wf_hostlib_wgtmap *m = &info.wgtmap;
    int is = strcasecmp(m->var[0], "logssfr") == 0 ? 0 : 1, im = 1 - is;
    ck_assert_str_eq(m->var[im], "logmass");
    size_t top = 0;
    for (size_t k = 1; k < m->n; k++)
        if (m->wgt[k] > m->wgt[top]) top = k;
    double w;
    ck_assert_int_eq(wf_snhost_weight(NULL, m->x[top * 2 + im], m->x[top * 2 + is] + m->x[top * 2 + im], &w),
                     WF_OK);
    double scale = m->wgt[top] / w;
    double lo = log10(1.01e-11), hi = log10(1.04e-9);
    double worst_in = 0.0, worst_out = 0.0, worst_abs = 0.0;
    long nin = 0, nout = 0, nzero = 0;
    for (size_t k = 0; k < m->n; k++) {
        double lssfr = m->x[k * 2 + is], lm = m->x[k * 2 + im];
        ck_assert_int_eq(wf_snhost_weight(NULL, lm, lssfr + lm, &w), WF_OK);
        double pred = scale * w, d = fabs(m->wgt[k] - pred);
        worst_abs = fmax(worst_abs, d);
        ck_assert_msg(d <= 5.0e-8 + 1e-9 * pred, "node logssfr %g logmass %g: WGT %.7f, predicted %.9f",
                      lssfr, lm, m->wgt[k], pred);
        int inside = lssfr >= lo && lssfr <= hi;
        nin += inside;
        nout += !inside;
        nzero += m->wgt[k] == 0.0;
        if (m->wgt[k] >= 1e-2) {
            double rel = fabs(m->wgt[k] / pred - 1.0);
            if (inside)
                worst_in = fmax(worst_in, rel);
            else
                worst_out = fmax(worst_out, rel);
        }
    }
    printf("WGTMAP: %zu nodes (%ld with sSFR inside the clamp, %ld outside, %ld printed as 0); "
           "WGT = %.6g x sSNR x M*: largest |difference| %.2g (7-decimal rounding: 5e-8); "
           "relative, WGT >= 0.01 (rounding <= 5e-6): %.2g inside the clamp, %.2g outside (the file clamps sSFR "
           "to the same [1.01e-11, 1.04e-9])\n",
           m->n, nin, nout, nzero, scale, worst_abs, worst_in, worst_out);
    wf_hostlib_info_free(&info);
    wf_catalog_free(&cat);
}
END_TEST

/* ------------------------------------------------------------------ a small library */

static const char SMALL[] =
    "# a HOSTLIB written for the test\n"
    "DOCUMENTATION:\n"
    "  PURPOSE: unit test of sim/sn/hostlib\n"
    "  NOTES:\n"
    "  - GAL: a row inside the documentation is not a row\n"
    "DOCUMENTATION_END:\n"
    "\n"
    "NVAR_WGTMAP: 2\n"
    "VARNAMES_WGTMAP: logssfr logmass WGT\n"
    "WGT: -10.0  9.0  0.5\n"
    "WGT: -10.0 10.0  5.0\n"
    "   # an indented comment\n"
    "VARNAMES: GALID RA_GAL DEC_GAL ZTRUE n0_Sersic a0_Sersic b0_Sersic w0_Sersic n1_Sersic "
    "a1_Sersic b1_Sersic w1_Sersic a_rot h_obs f_obs logsfr FIELD\r\n"
    "GAL: 1  70.5 -53.0 0.5  1 2.0 1.0  1.0  4 0 0 0      30.0 22.0 21.5  0.5 deep\r\n"
    "GAL: 2 -10.0 -53.0 1.5  4 0.5 0.25 0.7  1 1.0 1.0 0.3 45.0 23.0 22.5 -1.0 wide # note\n"
    "GAL: 3  71.0 -52.0 2.5  1 1.0 2.0  1.0  4 1.0 1.0 0.0 10.0 24.0 23.0  0.0 deep\n";

static void check_small(const wf_catalog *c, const wf_hostlib_info *info)
{
    ck_assert_uint_eq(c->n, 3);
    ck_assert_int_eq(c->nband, 2);
    ck_assert_str_eq(c->band[0], "H158");
    ck_assert_str_eq(c->band[1], "F184");
    ck_assert(c->has_z && !c->has_logmass && c->has_logsfr);
    /* row 1: bulge of weight 0 and size 0 takes the disk's radius sqrt(2 x 1) */
    ck_assert(close_to(c->hlr_disk[0], sqrt(2.0), 1e-7) && c->hlr_bulge[0] == c->hlr_disk[0]);
    ck_assert(c->bulge_frac[0] == 0.0f);
    ck_assert(close_to(c->e1[0], 0.6 * cos(60 * DEG), 1e-7) && close_to(c->e2[0], 0.6 * sin(60 * DEG), 1e-7));
    /* row 2: components in the other order; the bulge dominates (0.7) and sets the shape:
     * e = (0.25 - 0.0625) / 0.3125 = 0.6 at 45 deg; RA -10 wraps to 350 */
    ck_assert(c->ra[1] == 350.0 && c->z[1] == 1.5f);
    ck_assert(close_to(c->hlr_bulge[1], sqrt(0.125), 1e-7) && c->hlr_disk[1] == 1.0f);
    ck_assert(close_to(c->bulge_frac[1], 0.7, 1e-7));
    ck_assert(fabs(c->e1[1]) < 1e-7 && close_to(c->e2[1], 0.6, 1e-7));
    /* row 3: b > a, e = (1 - 4) / 5 = -0.6 at 10 deg: the major axis at 100 deg */
    ck_assert(close_to(c->e1[2], -0.6 * cos(20 * DEG), 1e-7));
    ck_assert(close_to(c->e2[2], -0.6 * sin(20 * DEG), 1e-7));
    ck_assert(c->mag[0][2] == 24.0f && c->mag[1][2] == 23.0f && c->logsfr[2] == 0.0f);
    ck_assert(c->id[0] == 1 && c->id[1] == 2 && c->id[2] == 3);
    ck_assert_uint_eq(info->zero_bulge, 2);
    ck_assert_uint_eq(info->zero_disk, 0);
    ck_assert(info->has_wgtmap && info->wgtmap.n == 2 && info->wgtmap.nvar == 2);
    ck_assert(!info->wgtmap.has_snmagshift);
    ck_assert(info->wgtmap.x[2] == -10.0 && info->wgtmap.x[3] == 10.0 && info->wgtmap.wgt[1] == 5.0);
}

START_TEST(test_small_hostlib)
{
    const char *dir = wf_test_tmpdir();
    ck_assert_ptr_nonnull(dir);
    char path[4096], gzpath[4096];
    snprintf(path, sizeof path, "%s/small.HOSTLIB", dir);
    snprintf(gzpath, sizeof gzpath, "%s/small.HOSTLIB.gz", dir);
    write_text(path, SMALL);
    gzFile gz = gzopen(gzpath, "wb");
    ck_assert_ptr_nonnull(gz);
    ck_assert_int_eq(gzputs(gz, SMALL), (int)strlen(SMALL));
    gzclose(gz);
    const char *paths[2] = {path, gzpath};
    for (int k = 0; k < 2; k++) {
        wf_catalog cat;
        wf_hostlib_info info;
        ck_assert_msg(wf_hostlib_read(paths[k], &cat, &info) == WF_OK, "%s", wf_error_message());
        ck_assert_str_eq(cat.source, paths[k]);
        check_small(&cat, &info);
        wf_hostlib_info_free(&info);
        wf_catalog_free(&cat);
    }
    /* info is optional */
    wf_catalog cat;
    ck_assert_int_eq(wf_hostlib_read(path, &cat, NULL), WF_OK);
    ck_assert_uint_eq(cat.n, 3);
    wf_catalog_free(&cat);
}
END_TEST

/* ------------------------------------------------------------------ bad files */

#define HEAD "VARNAMES: GALID RA_GAL DEC_GAL ZTRUE n0_Sersic a0_Sersic b0_Sersic w0_Sersic a_rot h_obs\n"

static const struct bad {
    const char *name, *text;
    wf_status status;
    const char *where; /* ":line:" expected after the path, or "" */
    const char *what[2];
} BAD[] = {
    {"nozcol", "VARNAMES: GALID RA_GAL DEC_GAL n0_Sersic a0_Sersic b0_Sersic w0_Sersic a_rot h_obs\n"
               "GAL: 1 70 -53 1 0.5 0.4 1 0 22\n",
     WF_ERR_INPUT, "", {"missing required column 'ZTRUE'", NULL}},
    {"noarot", "VARNAMES: GALID RA_GAL DEC_GAL ZTRUE n0_Sersic a0_Sersic b0_Sersic w0_Sersic h_obs\n",
     WF_ERR_INPUT, "", {"'a_rot'", NULL}},
    {"nomag", "VARNAMES: GALID RA_GAL DEC_GAL ZTRUE n0_Sersic a0_Sersic b0_Sersic w0_Sersic a_rot\n",
     WF_ERR_INPUT, "", {"y_obs", NULL}},
    {"partial1", "VARNAMES: GALID RA_GAL DEC_GAL ZTRUE n0_Sersic a0_Sersic b0_Sersic w0_Sersic a_rot "
                 "h_obs n1_Sersic a1_Sersic w1_Sersic\n",
     WF_ERR_INPUT, "", {"'b1_Sersic'", NULL}},
    {"notnumber", "# comment\n" HEAD "GAL: 1 70 -53 0.5 1 0.5 0.4 1 0 22\nGAL: 2 70 -53 0.5 1 abc 0.4 1 0 22\n",
     WF_ERR_INPUT, ":4:", {"'a0_Sersic'", "'abc' is not a number"}},
    {"nan", HEAD "GAL: 1 70 -53 nan 1 0.5 0.4 1 0 22\n", WF_ERR_INPUT, ":2:", {"'ZTRUE'", "NaN"}},
    {"truncated", HEAD "GAL: 1 70 -53 0.5 1 0.5 0.4 1 0 22\n\nGAL: 2 70 -53 0.5 1 0.5\n",
     WF_ERR_INPUT, ":4:", {"6 values", "names 10"}},
    {"galfirst", "GAL: 1 70 -53 0.5 1 0.5 0.4 1 0 22\n" HEAD, WF_ERR_INPUT, ":1:", {"before VARNAMES", NULL}},
    {"sersic", HEAD "GAL: 1 70 -53 0.5 2.5 0.5 0.4 1 0 22\n", WF_ERR_RANGE, ":2:", {"'n0_Sersic'", "2.5"}},
    {"dec", HEAD "GAL: 1 70 95 0.5 1 0.5 0.4 1 0 22\n", WF_ERR_RANGE, ":2:", {"'DEC_GAL'", "95"}},
    {"size", HEAD "GAL: 1 70 -53 0.5 1 0.5 0 1 0 22\n", WF_ERR_RANGE, ":2:", {"'b0_Sersic'", NULL}},
    {"weights", HEAD "GAL: 1 70 -53 0.5 1 0.5 0.4 0 0 22\n", WF_ERR_RANGE, ":2:", {"sum to 0", NULL}},
    {"wgtrow", "NVAR_WGTMAP: 2\nWGT: 1 2\n" HEAD, WF_ERR_INPUT, ":2:", {"2 values", NULL}},
    {"empty", "# nothing\n", WF_ERR_INPUT, "", {"no VARNAMES", NULL}},
    {"wgtshape", "NVAR_WGTMAP: 2\nWGT: 1 2 1 0\nNVAR_WGTMAP: 3\nWGT: 1 2 3 1\n" HEAD, WF_ERR_INPUT, ":3:",
     {"NVAR_WGTMAP after WGT", NULL}},
    {"comp2", "VARNAMES: GALID RA_GAL DEC_GAL ZTRUE n0_Sersic a0_Sersic b0_Sersic w0_Sersic a_rot "
              "h_obs n2_Sersic\n",
     WF_ERR_INPUT, ":1:", {"'n2_Sersic'", NULL}},
};
#define N_BAD ((int)(sizeof BAD / sizeof *BAD))

START_TEST(test_bad_files)
{
    const struct bad *b = &BAD[_i];
    const char *dir = wf_test_tmpdir();
    ck_assert_ptr_nonnull(dir);
    char path[4096], want[4200];
    snprintf(path, sizeof path, "%s/%s.HOSTLIB", dir, b->name);
    write_text(path, b->text);
    wf_catalog cat;
    wf_hostlib_info info;
    wf_status st = wf_hostlib_read(path, &cat, &info);
    const char *msg = wf_error_message();
    printf("bad file %-9s -> %s\n", b->name, msg);
    ck_assert_msg(st == b->status, "%s: status %d, expected %d (%s)", b->name, st, b->status, msg);
    snprintf(want, sizeof want, "%s%s", path, b->where);
    ck_assert_msg(strstr(msg, want) != NULL, "'%s' should contain '%s'", msg, want);
    for (int k = 0; k < 2; k++)
        if (b->what[k]) ck_assert_msg(strstr(msg, b->what[k]) != NULL, "'%s' should contain '%s'", msg, b->what[k]);
    ck_assert_uint_eq(cat.n, 0);
    ck_assert_ptr_null(cat.ra);
    ck_assert_ptr_null(info.wgtmap.wgt);
}
END_TEST

START_TEST(test_missing_file)
{
    wf_catalog cat;
    ck_assert_int_eq(wf_hostlib_read("/nonexistent/dir/x.HOSTLIB", &cat, NULL), WF_ERR_IO);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "/nonexistent/dir/x.HOSTLIB"));
}
END_TEST

/* ------------------------------------------------------------------ a_rot */

/* x = r / r_e enclosing f for the exponential disk, by bisection on 1 − e^{−y}(1 + y). */
static double disk_radius(double f)
{
    double lo = 0.0, hi = 50.0, b1;
    for (int pass = 0; pass < 2; pass++) {
        double target = pass == 0 ? 0.5 : f;
        lo = 0.0;
        hi = 50.0;
        for (int it = 0; it < 200; it++) {
            double mid = 0.5 * (lo + hi);
            if (1.0 - exp(-mid) * (1.0 + mid) < target)
                lo = mid;
            else
                hi = mid;
        }
        if (pass == 0) b1 = 0.5 * (lo + hi);
    }
    return 0.5 * (lo + hi) / b1;
}

START_TEST(test_arot_convention)
{
    /* One disk host, a = 2", b = 1", a_rot = 30. SNANA GEN_SNHOST_POS puts a point at
     * (a, b) in the ellipse frame at ΔRA cos δ = a cos(rot) + b sin(rot),
     * ΔDec = b cos(rot) − a sin(rot); the point of parameter t on the ellipse of reduced
     * radius R is a = R a_half cos t, b = R b_half sin t. The renderer's round frame has the
     * angle φ from +u (west) to +v (north); since (east, north) and (u, v) have opposite
     * handedness, SNANA's parameter t is φ = a_rot + 180° − t here: +a at φ = a_rot + 180°,
     * +b at φ = a_rot + 90°. With φ uniform both give the same distribution. */
    const char *dir = wf_test_tmpdir();
    ck_assert_ptr_nonnull(dir);
    char path[4096];
    snprintf(path, sizeof path, "%s/arot.HOSTLIB", dir);
    write_text(path,
               "VARNAMES: GALID RA_GAL DEC_GAL ZTRUE n0_Sersic a0_Sersic b0_Sersic w0_Sersic "
               "n1_Sersic a1_Sersic b1_Sersic w1_Sersic a_rot h_obs logmass logsfr\n"
               "GAL: 7 71.0 -53.0 0.8 1 2.0 1.0 1.0 4 0.3 0.3 0.0 30.0 22.0 10.0 0.5\n");
    wf_catalog cat;
    ck_assert_int_eq(wf_hostlib_read(path, &cat, NULL), WF_OK);
    const double rot = 30.0 * DEG, F = 0.7, ahalf = 2.0, bhalf = 1.0;
    double R = disk_radius(F);
    struct {
        double phi, a, b;
    } axes[] = {
        {rot + M_PI, R * ahalf, 0.0},     /* major axis, t = 0 */
        {rot, -R * ahalf, 0.0},           /* its other end, t = 180° */
        {rot + M_PI / 2, 0.0, R * bhalf}, /* minor axis, t = 90° */
        {rot - M_PI / 2, 0.0, -R * bhalf},
        {rot + M_PI - 0.7, R * ahalf * cos(0.7), R * bhalf * sin(0.7)}, /* t = 0.7 rad */
        {rot + M_PI - 4.0, R * ahalf * cos(4.0), R * bhalf * sin(4.0)},
    };
    for (size_t k = 0; k < sizeof axes / sizeof *axes; k++) {
        wf_snhost_position pos;
        ck_assert_int_eq(wf_snhost_place_at(&cat, 0, 0, F, axes[k].phi, &pos), WF_OK);
        double ra_sep = axes[k].a * cos(rot) + axes[k].b * sin(rot);
        double dec_sep = axes[k].b * cos(rot) - axes[k].a * sin(rot);
        /* the same offsets measured back from RA, Dec (gnomonic projection about the host) */
        double a0 = 71.0 * DEG, d0 = -53.0 * DEG, ra = pos.ra * DEG, dec = pos.dec * DEG;
        double cosc = sin(d0) * sin(dec) + cos(d0) * cos(dec) * cos(ra - a0);
        double east = cos(dec) * sin(ra - a0) / cosc * ARCSEC_PER_RAD;
        double north = (cos(d0) * sin(dec) - sin(d0) * cos(dec) * cos(ra - a0)) / cosc * ARCSEC_PER_RAD;
        printf("a_rot 30: phi %6.1f deg -> east %+.6f north %+.6f arcsec; SNANA %+.6f %+.6f\n",
               axes[k].phi / DEG, east, north, ra_sep, dec_sep);
        /* float storage of e1, e2 and the radius limits the agreement to ~1e-7 */
        ck_assert_msg(fabs(east - ra_sep) < 1e-6 && fabs(north - dec_sep) < 1e-6,
                      "phi %g: (%.9f, %.9f) vs SNANA (%.9f, %.9f)", axes[k].phi, east, north, ra_sep,
                      dec_sep);
    }
    wf_catalog_free(&cat);
}
END_TEST

static Suite *hostlib_suite(void)
{
    Suite *s = suite_create("hostlib");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, test_shared_hostlib);
    tcase_add_test(tc, test_shared_wgtmap);
    tcase_add_test(tc, test_small_hostlib);
    tcase_add_loop_test(tc, test_bad_files, 0, N_BAD);
    tcase_add_test(tc, test_missing_file);
    tcase_add_test(tc, test_arot_convention);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(hostlib_suite()); }
