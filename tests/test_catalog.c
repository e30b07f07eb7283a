/* Catalogs (sim/survey/catalog), the synthetic generator (sim/survey/synth) and the spatial index
 * (sim/survey/skyindex):
 *  - readers: files written here by hand (CSV, gzip'd CSV, FITS through cfitsio directly)
 *    read back exactly; every kind of bad input gives its status and a message naming the
 *    file, the row and the column; the writers' files read back bit for bit; the GalSim
 *    benchmark scene is read (skipped when ../shared/reference is absent);
 *  - synthetic catalog: densities within Poisson errors of the model, the H-band counts
 *    against the SPEC §4.3 table, the size-magnitude slope and scatter, the truncated
 *    shape distribution, reproducibility, and cell independence (subsets of cells and
 *    footprint queries give exactly the objects of the whole-field generation);
 *  - spatial index: selections equal a brute-force scan, exactly, on a random field with
 *    patches at both poles and across RA = 0/360; timing for 2.7 million galaxies (printed,
 *    not asserted).
 * Random inputs come from fixed seeds, so failures are reproducible. */
#include <fitsio.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zlib.h>

#include "hal/noise.h"
#include "sim/survey/catalog.h"
#include "sim/survey/skyindex.h"
#include "sim/survey/synth.h"
#include "tests/testutil.h"

#define DEG (M_PI / 180.0)

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

static const char *tmp_path(const char *name)
{
    static _Thread_local char buf[4][4096];
    static _Thread_local int slot;
    const char *dir = wf_test_tmpdir();
    ck_assert_ptr_nonnull(dir);
    char *out = buf[slot++ % 4];
    snprintf(out, sizeof buf[0], "%s/%s", dir, name);
    return out;
}

/* ------------------------------------------------------------------ good files */

/* Three galaxies: header with mixed case, quotes, an unused text column and an unused
 * numeric column; comments, a blank line and CRLF endings. */
static const char GOOD_CSV[] =
    "# a comment before the header\r\n"
    "\"ID\",RA, Dec "
    ",z,mag_Y106,mag_H158,notes,hlr,bulge_frac,knot_frac,e1,e2,pa,logmass,logsfr,extra\r\n"
    "1,70.5,-53.25,0.5,24.5,24.0,first,0.25,0.125,0.0625,0.1,-0.2,30,9.5,0.25,7\r\n"
    "# a comment between rows\r\n"
    "\r\n"
    "2,359.999999999,89.999,1.25,26.75,26.5,second,1.5,1,0.25,-0.5,0.5,-45,10.75,-1.5,8\r\n"
    "9007199254740993,-10.5,-90,3,99,21.5,third,0.0625,0,0,0,0,359,11,2,9\r\n";

static void check_good_galaxies(const wf_catalog *c, const char *path)
{
    ck_assert_int_eq(c->kind, WF_CATALOG_GALAXY);
    ck_assert_uint_eq(c->n, 3);
    ck_assert_int_eq(c->nband, 2);
    ck_assert_str_eq(c->band[0], "Y106");
    ck_assert_str_eq(c->band[1], "H158");
    ck_assert_str_eq(c->source, path);
    ck_assert(c->has_z && c->has_logmass && c->has_logsfr);
    ck_assert(c->id[0] == 1 && c->id[1] == 2 && c->id[2] == INT64_C(9007199254740993));
    ck_assert(c->ra[0] == 70.5 && c->dec[0] == -53.25);
    ck_assert(c->ra[1] == 359.999999999 && c->dec[1] == 89.999);
    ck_assert(c->ra[2] == 360.0 - 10.5 && c->dec[2] == -90.0); /* negative RA wrapped */
    ck_assert(c->z[0] == 0.5f && c->z[1] == 1.25f && c->z[2] == 3.0f);
    ck_assert(c->mag[0][0] == 24.5f && c->mag[1][0] == 24.0f);
    ck_assert(c->mag[0][1] == 26.75f && c->mag[1][1] == 26.5f);
    ck_assert(c->mag[0][2] == 99.0f && c->mag[1][2] == 21.5f);
    ck_assert(c->hlr_disk[0] == 0.25f && c->hlr_bulge[0] == 0.125f); /* bulge = disk / 2 */
    ck_assert(c->hlr_disk[1] == 1.5f && c->hlr_bulge[1] == 0.75f);
    ck_assert(c->bulge_frac[0] == 0.125f && c->bulge_frac[1] == 1.0f && c->bulge_frac[2] == 0.0f);
    ck_assert(c->knot_frac[0] == 0.0625f && c->knot_frac[1] == 0.25f);
    ck_assert(c->e1[0] == 0.1f && c->e2[0] == -0.2f && c->e1[1] == -0.5f && c->e2[1] == 0.5f);
    ck_assert(c->pa[0] == 30.0f && c->pa[1] == -45.0f && c->pa[2] == 359.0f);
    ck_assert(c->logmass[0] == 9.5f && c->logmass[1] == 10.75f && c->logsfr[1] == -1.5f);
    ck_assert(c->logsfr[2] == 2.0f);
    int b = -1;
    ck_assert_int_eq(wf_catalog_band(c, "h158", &b), WF_OK);
    ck_assert_int_eq(b, 1);
    ck_assert_int_eq(wf_catalog_band(c, "mag_Y106", &b), WF_OK);
    ck_assert_int_eq(b, 0);
    ck_assert_int_eq(wf_catalog_band(c, "F184", &b), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), "F184") && strstr(wf_error_message(), path), "%s",
                  wf_error_message());
}

START_TEST(test_csv_good)
{
    const char *path = tmp_path("good.csv");
    write_text(path, GOOD_CSV);
    wf_catalog c;
    ck_assert_msg(wf_catalog_read_galaxies(path, &c) == WF_OK, "%s", wf_error_message());
    check_good_galaxies(&c, path);
    wf_catalog_free(&c);

    /* The same bytes gzip'd. */
    const char *gzpath = tmp_path("good.csv.gz");
    gzFile gz = gzopen(gzpath, "wb");
    ck_assert_ptr_nonnull(gz);
    gzputs(gz, GOOD_CSV);
    gzclose(gz);
    ck_assert_msg(wf_catalog_read_galaxies(gzpath, &c) == WF_OK, "%s", wf_error_message());
    check_good_galaxies(&c, gzpath);
    wf_catalog_free(&c);

    /* FWHM instead of hlr, and an explicit bulge radius; no mass or SFR. */
    const char *fw = tmp_path("fwhm.csv");
    write_text(fw, "id,ra,dec,z,mag_H158,fwhm,hlr_bulge,bulge_frac,knot_frac,e1,e2,pa\n"
                   "5,10,20,1,23,0.5,0.1,0.5,0.1,0,0,0\n");
    ck_assert_msg(wf_catalog_read_galaxies(fw, &c) == WF_OK, "%s", wf_error_message());
    ck_assert(!c.has_logmass && !c.has_logsfr && c.logmass == NULL && c.logsfr == NULL);
    ck_assert(fabs(c.hlr_disk[0] - 0.5 * 1.2106644) < 1e-6);
    ck_assert(c.hlr_bulge[0] == 0.1f);
    wf_catalog_free(&c);

    /* Stars: only id, ra, dec and magnitudes needed; galaxy columns ignored. */
    const char *sp = tmp_path("stars.csv");
    write_text(sp, "id,ra,dec,mag_J129,hlr\n7,1.5,-2.5,18.25,-3\n8,2.5,-3.5,27,0\n");
    ck_assert_msg(wf_catalog_read_stars(sp, &c) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(c.kind, WF_CATALOG_STAR);
    ck_assert_uint_eq(c.n, 2);
    ck_assert(c.id[1] == 8 && c.ra[1] == 2.5 && c.dec[1] == -3.5 && c.mag[0][1] == 27.0f);
    ck_assert(c.hlr_disk == NULL && c.z == NULL);
    wf_catalog_free(&c);

    /* A header and no rows is an empty catalog, not an error. */
    const char *empty = tmp_path("empty.csv");
    write_text(empty, "id,ra,dec,mag_H158\n");
    ck_assert_int_eq(wf_catalog_read_stars(empty, &c), WF_OK);
    ck_assert_uint_eq(c.n, 0);
    wf_catalog_free(&c);
}
END_TEST

static void write_fits_table(const char *path, int bad_kind)
{
    /* bad_kind: 0 good; 1 NaN in E2 row 2; 2 DEC out of range in row 3; 3 no Z column;
     * 4 text column where RA should be */
    remove(path);
    fitsfile *ff;
    int st = 0;
    const char *names[] = {"OBJ_ID",   "RA_DEG", "DEC",        "Z",         "MAG_H158",
                           "MAG_F184", "HLR",    "BULGE_FRAC", "KNOT_FRAC", "E1",
                           "E2",       "PA",     "LOGMASS",    "LOGSFR",    "JUNK"};
    const char *forms[] = {"K", "D", "D", "E", "E", "D", "E", "E",
                           "E", "E", "E", "E", "E", "E", "3A"};
    int ncol = 15;
    char *tt[15], *tf[15];
    for (int k = 0; k < ncol; k++) {
        tt[k] = (char *)names[k];
        tf[k] = (char *)forms[k];
    }
    if (bad_kind == 3) tt[3] = (char *)"ZZZ";
    if (bad_kind == 4) tf[1] = (char *)"8A";
    ck_assert_int_eq(fits_create_file(&ff, path, &st), 0);
    fits_create_tbl(ff, BINARY_TBL, 3, ncol, tt, tf, NULL, "CAT", &st);
    long long id[3] = {11, 12, INT64_C(123456789012345)};
    double ra[3] = {71.123456789012345, 0.0, 359.5}, dec[3] = {-53.5, 10.0, 89.5};
    float z[3] = {0.25f, 1.5f, 2.75f}, mh[3] = {22.5f, 23.25f, 28.0f};
    double mf[3] = {22.0, 23.0, 27.5};
    float hlr[3] = {0.5f, 0.25f, 0.125f}, bt[3] = {0.0f, 0.5f, 1.0f}, kn[3] = {0.0f, 0.125f, 0.25f};
    float e1[3] = {0.0f, 0.25f, -0.5f}, e2[3] = {0.5f, -0.25f, 0.0f}, pa[3] = {0.0f, 90.0f, 179.5f};
    float lm[3] = {9.0f, 10.0f, 11.5f}, ls[3] = {-0.5f, 1.0f, -2.0f};
    char j0[] = "abc", j1[] = "de", j2[] = "f";
    char *junk[3] = {j0, j1, j2};
    if (bad_kind == 1) e2[1] = NAN;
    if (bad_kind == 2) dec[2] = 91.0;
    fits_write_col(ff, TLONGLONG, 1, 1, 1, 3, id, &st);
    if (bad_kind == 4)
        fits_write_col(ff, TSTRING, 2, 1, 1, 3, junk, &st);
    else
        fits_write_col(ff, TDOUBLE, 2, 1, 1, 3, ra, &st);
    fits_write_col(ff, TDOUBLE, 3, 1, 1, 3, dec, &st);
    fits_write_col(ff, TFLOAT, 4, 1, 1, 3, z, &st);
    fits_write_col(ff, TFLOAT, 5, 1, 1, 3, mh, &st);
    fits_write_col(ff, TDOUBLE, 6, 1, 1, 3, mf, &st);
    fits_write_col(ff, TFLOAT, 7, 1, 1, 3, hlr, &st);
    fits_write_col(ff, TFLOAT, 8, 1, 1, 3, bt, &st);
    fits_write_col(ff, TFLOAT, 9, 1, 1, 3, kn, &st);
    fits_write_col(ff, TFLOAT, 10, 1, 1, 3, e1, &st);
    fits_write_col(ff, TFLOAT, 11, 1, 1, 3, e2, &st);
    fits_write_col(ff, TFLOAT, 12, 1, 1, 3, pa, &st);
    fits_write_col(ff, TFLOAT, 13, 1, 1, 3, lm, &st);
    fits_write_col(ff, TFLOAT, 14, 1, 1, 3, ls, &st);
    fits_write_col(ff, TSTRING, 15, 1, 1, 3, junk, &st);
    fits_close_file(ff, &st);
    ck_assert_int_eq(st, 0);
}

START_TEST(test_fits_good)
{
    const char *path = tmp_path("good.fits");
    write_fits_table(path, 0);
    wf_catalog c;
    ck_assert_msg(wf_catalog_read_galaxies(path, &c) == WF_OK, "%s", wf_error_message());
    ck_assert_uint_eq(c.n, 3);
    ck_assert_int_eq(c.nband, 2);
    ck_assert_str_eq(c.band[0], "H158");
    ck_assert_str_eq(c.band[1], "F184");
    ck_assert(c.id[0] == 11 && c.id[2] == INT64_C(123456789012345));
    ck_assert(c.ra[0] == 71.123456789012345 && c.ra[1] == 0.0 && c.ra[2] == 359.5);
    ck_assert(c.dec[0] == -53.5 && c.dec[2] == 89.5);
    ck_assert(c.z[1] == 1.5f && c.mag[0][2] == 28.0f && c.mag[1][2] == 27.5f);
    ck_assert(c.hlr_disk[0] == 0.5f && c.hlr_bulge[0] == 0.25f && c.bulge_frac[2] == 1.0f);
    ck_assert(c.knot_frac[2] == 0.25f && c.e1[2] == -0.5f && c.e2[0] == 0.5f && c.pa[2] == 179.5f);
    ck_assert(c.logmass[2] == 11.5f && c.logsfr[2] == -2.0f);
    wf_catalog_free(&c);
}
END_TEST

/* A header card with bytes outside printable ASCII (FITS headers may hold nothing else) is
 * refused with the file, HDU and card named, before cfitsio reads it: cfitsio 4.2 overflows a
 * buffer on such a TTYPE and aborts the process (found by fuzz/fuzz_catalog_fits.c, the input
 * kept as fuzz/corpus/catalog_fits/regress-ffgtbp-overflow.fit). Behind an image HDU with
 * data, gzip'd, and a good file beside them: the walk sizes the data it skips. */
START_TEST(test_fits_header_not_ascii)
{
    const char *good = tmp_path("ascii-good.fits");
    write_fits_table(good, 0);
    size_t len;
    char *bytes = wf_test_slurp(good, &len);
    ck_assert_ptr_nonnull(bytes);
    char *card = NULL;
    for (size_t off = 0; off + 80 <= len; off += 80)
        if (!strncmp(bytes + off, "TTYPE3  = '", 11)) card = bytes + off;
    ck_assert_ptr_nonnull(card);
    card[12] = (char)0xe9;
    const char *bad = tmp_path("ascii-bad.fits");
    FILE *f = fopen(bad, "wb");
    ck_assert(f && fwrite(bytes, 1, len, f) == len && fclose(f) == 0);
    const char *badgz = tmp_path("ascii-bad.fits.gz");
    gzFile gz = gzopen(badgz, "wb");
    ck_assert(gz && gzwrite(gz, bytes, (unsigned)len) == (int)len && gzclose(gz) == Z_OK);
    /* the same table behind a primary image with data (the damaged card moves to HDU 3) */
    const char *deep = tmp_path("ascii-deep.fits");
    fitsfile *ff;
    int st = 0;
    long nax[2] = {7, 5};
    float pix[35];
    for (int i = 0; i < 35; i++) pix[i] = (float)i * 1.7e-3f;
    fits_create_file(&ff, deep, &st);
    fits_create_img(ff, FLOAT_IMG, 2, nax, &st);
    fits_write_img(ff, TFLOAT, 1, 35, pix, &st);
    fits_create_img(ff, FLOAT_IMG, 2, nax, &st);
    fits_write_img(ff, TFLOAT, 1, 35, pix, &st);
    fits_close_file(ff, &st);
    ck_assert_int_eq(st, 0);
    size_t dlen;
    char *dbytes = wf_test_slurp(deep, &dlen);
    f = fopen(deep, "wb");
    ck_assert(f && fwrite(dbytes, 1, dlen, f) == dlen && fwrite(bytes + 2880, 1, len - 2880, f) == len - 2880 &&
              fclose(f) == 0);
    free(dbytes);
    free(bytes);

    wf_catalog c;
    ck_assert_msg(wf_catalog_read_galaxies(good, &c) == WF_OK, "%s", wf_error_message());
    wf_catalog_free(&c);
    const char *paths[3] = {bad, badgz, deep};
    const char *hdu[3] = {"HDU 2", "HDU 2", "HDU 3"};
    for (int k = 0; k < 3; k++) {
        ck_assert_int_eq(wf_catalog_read_galaxies(paths[k], &c), WF_ERR_INPUT);
        const char *m = wf_error_message();
        ck_assert_msg(strstr(m, paths[k]) && strstr(m, hdu[k]) && strstr(m, "(TTYPE3)") &&
                          strstr(m, "0xe9") && strstr(m, "not printable ASCII"),
                      "%s", m);
    }
    const char *fuzzed = "fuzz/corpus/catalog_fits/regress-ffgtbp-overflow.fit";
    ck_assert_int_eq(wf_catalog_read_galaxies(fuzzed, &c), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), "not printable ASCII"), "%s", wf_error_message());
}
END_TEST

/* The reader finds the first table past any image HDUs, as fits_open_table did; a file
 * without a table, or whose header after the primary is damaged, is refused
 * without losing memory (fits_open_table lost 16 bytes there, which LeakSanitizer reports
 * in the SAN=1 build: found by fuzz/fuzz_catalog_fits.c). */
START_TEST(test_fits_table_search)
{
    const char *good = tmp_path("search_good.fits");
    write_fits_table(good, 0);
    char path[4200];
    snprintf(path, sizeof path, "%s", tmp_path("search_images.fits"));
    remove(path);
    fitsfile *in, *out;
    int st = 0;
    long two[2] = {2, 2};
    fits_create_file(&out, path, &st);
    fits_create_img(out, SHORT_IMG, 2, two, &st);
    fits_create_img(out, FLOAT_IMG, 2, two, &st);
    fits_open_file(&in, good, READONLY, &st);
    fits_movabs_hdu(in, 2, NULL, &st);
    fits_copy_hdu(in, out, 0, &st);
    fits_close_file(in, &st);
    fits_close_file(out, &st);
    ck_assert_int_eq(st, 0);
    wf_catalog c;
    ck_assert_msg(wf_catalog_read_galaxies(path, &c) == WF_OK, "%s", wf_error_message());
    ck_assert_uint_eq(c.n, 3);
    ck_assert(c.id[0] == 11 && c.ra[2] == 359.5);
    wf_catalog_free(&c);

    /* primary only: no table */
    const char *bare = tmp_path("search_bare.fits");
    remove(bare);
    fits_create_file(&out, bare, &st);
    fits_create_img(out, SHORT_IMG, 0, NULL, &st);
    fits_close_file(out, &st);
    ck_assert_int_eq(st, 0);
    ck_assert_int_eq(wf_catalog_read_galaxies(bare, &c), WF_ERR_IO);
    ck_assert_msg(strstr(wf_error_message(), "no table HDU in the file"), "%s", wf_error_message());

    /* the table's header cut short one block in, after a whole primary */
    FILE *f = fopen(good, "rb");
    ck_assert_ptr_nonnull(f);
    unsigned char buf[2880 + 1200];
    ck_assert_uint_eq(fread(buf, 1, sizeof buf, f), sizeof buf);
    fclose(f);
    const char *cut = tmp_path("search_cut.fits");
    f = fopen(cut, "wb");
    ck_assert_ptr_nonnull(f);
    ck_assert_uint_eq(fwrite(buf, 1, sizeof buf, f), sizeof buf);
    fclose(f);
    ck_assert_int_eq(wf_catalog_read_galaxies(cut, &c), WF_ERR_IO);
    ck_assert_msg(strstr(wf_error_message(), "cannot open as a FITS table"), "%s", wf_error_message());
}
END_TEST

/* The writers' files, CSV, gzip'd CSV and FITS, read back bit for bit. */
static void assert_same_catalog(const wf_catalog *a, const wf_catalog *b)
{
    ck_assert_int_eq(a->kind, b->kind);
    ck_assert_uint_eq(a->n, b->n);
    ck_assert_int_eq(a->nband, b->nband);
    size_t n = a->n;
    ck_assert(memcmp(a->id, b->id, n * sizeof *a->id) == 0);
    ck_assert(memcmp(a->ra, b->ra, n * sizeof *a->ra) == 0);
    ck_assert(memcmp(a->dec, b->dec, n * sizeof *a->dec) == 0);
    for (int k = 0; k < a->nband; k++) {
        ck_assert_str_eq(a->band[k], b->band[k]);
        ck_assert(memcmp(a->mag[k], b->mag[k], n * sizeof(float)) == 0);
    }
    if (a->kind != WF_CATALOG_GALAXY) return;
    const float *fa[] = {a->hlr_disk, a->hlr_bulge, a->bulge_frac, a->knot_frac,
                         a->e1,       a->e2,        a->pa};
    const float *fb[] = {b->hlr_disk, b->hlr_bulge, b->bulge_frac, b->knot_frac,
                         b->e1,       b->e2,        b->pa};
    for (size_t k = 0; k < sizeof fa / sizeof *fa; k++)
        ck_assert_msg(memcmp(fa[k], fb[k], n * sizeof(float)) == 0, "galaxy column %zu", k);
    ck_assert(a->has_z == b->has_z && a->has_logmass == b->has_logmass &&
              a->has_logsfr == b->has_logsfr);
    if (a->has_z) ck_assert(memcmp(a->z, b->z, n * sizeof(float)) == 0);
    if (a->has_logmass) ck_assert(memcmp(a->logmass, b->logmass, n * sizeof(float)) == 0);
    if (a->has_logsfr) ck_assert(memcmp(a->logsfr, b->logsfr, n * sizeof(float)) == 0);
}

static wf_synth *small_synth(uint64_t seed, double radius_deg, int clustering)
{
    wf_synth_config cfg;
    wf_synth_defaults(&cfg);
    cfg.seed = seed;
    cfg.radius_deg = radius_deg;
    cfg.clustering = clustering;
    wf_synth *s;
    ck_assert_msg(wf_synth_create(&cfg, &s) == WF_OK, "%s", wf_error_message());
    return s;
}

START_TEST(test_writers_roundtrip)
{
    wf_synth *s = small_synth(5, 0.05, 0);
    wf_catalog gal, stars, back;
    ck_assert_int_eq(wf_synth_generate_all(s, &gal, &stars), WF_OK);
    ck_assert_uint_gt(gal.n, 500);
    ck_assert_uint_gt(stars.n, 10);
    const char *names[] = {"g.csv", "g.csv.gz", "g.fits"};
    for (int k = 0; k < 3; k++) {
        const char *p = tmp_path(names[k]);
        ck_assert_msg((k < 2 ? wf_catalog_write_csv(p, &gal) : wf_catalog_write_fits(p, &gal)) ==
                          WF_OK,
                      "%s", wf_error_message());
        ck_assert_msg(wf_catalog_read_galaxies(p, &back) == WF_OK, "%s", wf_error_message());
        assert_same_catalog(&gal, &back);
        wf_catalog_free(&back);
        const char *q = tmp_path(k < 2 ? "s.csv" : "s.fits");
        ck_assert_int_eq(k < 2 ? wf_catalog_write_csv(q, &stars) : wf_catalog_write_fits(q, &stars),
                         WF_OK);
        ck_assert_msg(wf_catalog_read_stars(q, &back) == WF_OK, "%s", wf_error_message());
        assert_same_catalog(&stars, &back);
        wf_catalog_free(&back);
    }
    /* A subset keeps the columns. */
    uint32_t idx[3] = {7, 0, 3};
    ck_assert_int_eq(wf_catalog_subset(&gal, idx, 3, &back), WF_OK);
    ck_assert(back.n == 3 && back.id[0] == gal.id[7] && back.logsfr[2] == gal.logsfr[3]);
    wf_catalog_free(&back);
    wf_catalog_free(&gal);
    wf_catalog_free(&stars);
    wf_synth_free(s);
}
END_TEST

/* ------------------------------------------------------------------ bad input */

typedef struct bad_case {
    const char *what;
    const char *text; /* CSV body; NULL: FITS variant in fits_kind, or a missing file */
    int fits_kind;
    int star;
    wf_status status;
    const char *row;    /* substring expected in the message, NULL for none */
    const char *column; /* substring expected in the message */
} bad_case;

#define GAL_HDR "id,ra,dec,z,mag_H158,hlr,bulge_frac,knot_frac,e1,e2,pa\n"
#define GAL_ROW "1,71,-53,1,24,0.3,0.2,0.1,0.1,0.1,10\n"

static const bad_case BAD[] = {
    {"missing column",
     "id,ra,dec,mag_H158,hlr,bulge_frac,knot_frac,e1,e2,pa\n1,71,-53,24,0.3,0.2,0.1,0.1,0.1,10\n",
     0, 0, WF_ERR_INPUT, NULL, "'z'"},
    {"missing size",
     "id,ra,dec,z,mag_H158,bulge_frac,knot_frac,e1,e2,pa\n1,71,-53,1,24,0.2,0.1,0.1,0.1,10\n", 0, 0,
     WF_ERR_INPUT, NULL, "'hlr'"},
    {"no magnitude", "id,ra,dec\n1,2,3\n", 0, 1, WF_ERR_INPUT, NULL, "mag_"},
    {"missing id", "ra,dec,mag_H158\n1,2,3\n", 0, 1, WF_ERR_INPUT, NULL, "'id'"},
    {"NaN", GAL_HDR GAL_ROW GAL_ROW "3,71,-53,1,24,0.3,0.2,0.1,nan,0.1,10\n", 0, 0, WF_ERR_INPUT,
     "row 3 (line 4)", "'e1'"},
    {"inf", GAL_HDR GAL_ROW "2,71,-53,1,inf,0.3,0.2,0.1,0.1,0.1,10\n", 0, 0, WF_ERR_INPUT, "row 2",
     "'mag_H158'"},
    {"-inf", GAL_HDR "1,71,-53,-inf,24,0.3,0.2,0.1,0.1,0.1,10\n", 0, 0, WF_ERR_INPUT, "row 1",
     "'z'"},
    {"dec > 90", GAL_HDR GAL_ROW "2,71,95,1,24,0.3,0.2,0.1,0.1,0.1,10\n", 0, 0, WF_ERR_RANGE,
     "row 2", "'dec'"},
    {"ra below -180", GAL_HDR "1,-200,-53,1,24,0.3,0.2,0.1,0.1,0.1,10\n", 0, 0, WF_ERR_RANGE,
     "row 1", "'ra'"},
    {"bulge > 1", GAL_HDR GAL_ROW GAL_ROW GAL_ROW "4,71,-53,1,24,0.3,1.2,0.1,0.1,0.1,10\n", 0, 0,
     WF_ERR_RANGE, "row 4", "'bulge_frac'"},
    {"knots > 0.25", GAL_HDR "1,71,-53,1,24,0.3,0.2,0.3,0.1,0.1,10\n", 0, 0, WF_ERR_RANGE, "row 1",
     "'knot_frac'"},
    {"|e| >= 1", GAL_HDR GAL_ROW "2,71,-53,1,24,0.3,0.2,0.1,0.8,0.7,10\n", 0, 0, WF_ERR_RANGE,
     "row 2", "'e1'"},
    {"e1 = 1", GAL_HDR "1,71,-53,1,24,0.3,0.2,0.1,1,0,10\n", 0, 0, WF_ERR_RANGE, "row 1", "'e1'"},
    {"negative size", GAL_HDR GAL_ROW "2,71,-53,1,24,-0.3,0.2,0.1,0.1,0.1,10\n", 0, 0, WF_ERR_RANGE,
     "row 2", "'hlr'"},
    {"zero size", GAL_HDR "1,71,-53,1,24,0,0.2,0.1,0.1,0.1,10\n", 0, 0, WF_ERR_RANGE, "row 1",
     "'hlr'"},
    {"mass sentinel",
     "id,ra,dec,z,mag_H158,hlr,bulge_frac,knot_frac,e1,e2,pa,logmass\n"
     "1,71,-53,1,24,0.3,0.2,0.1,0.1,0.1,10,-99\n",
     0, 0, WF_ERR_RANGE, "row 1", "'logmass'"},
    {"too few fields", GAL_HDR GAL_ROW "2,71,-53,1,24,0.3,0.2,0.1,0.1,10\n", 0, 0, WF_ERR_INPUT,
     "row 2 (line 3)", "10 fields"},
    {"too many fields", GAL_HDR "1,71,-53,1,24,0.3,0.2,0.1,0.1,0.1,10,5\n", 0, 0, WF_ERR_INPUT,
     "row 1", "12 fields"},
    {"not a number", GAL_HDR GAL_ROW "2,71,-53,1,24,0.3,0.2,0.1,0.1,0.1,ten\n", 0, 0, WF_ERR_INPUT,
     "row 2", "'pa'"},
    {"trailing junk", GAL_HDR "1,71,-53,1,24,0.3x,0.2,0.1,0.1,0.1,10\n", 0, 0, WF_ERR_INPUT,
     "row 1", "'hlr'"},
    {"empty value", GAL_HDR "1,71,,1,24,0.3,0.2,0.1,0.1,0.1,10\n", 0, 0, WF_ERR_INPUT, "row 1",
     "'dec'"},
    {"bad id", GAL_HDR "1.5,71,-53,1,24,0.3,0.2,0.1,0.1,0.1,10\n", 0, 0, WF_ERR_INPUT, "row 1",
     "'id'"},
    {"star NaN", "id,ra,dec,mag_Y106\n1,2,3,20\n2,2,3,NaN\n", 0, 1, WF_ERR_INPUT, "row 2",
     "'mag_Y106'"},
    {"empty file", "# nothing\n", 0, 1, WF_ERR_INPUT, NULL, "header"},
    {"FITS NaN", NULL, 1, 0, WF_ERR_INPUT, "row 2", "'E2'"},
    {"FITS dec", NULL, 2, 0, WF_ERR_RANGE, "row 3", "'DEC'"},
    {"FITS missing", NULL, 3, 0, WF_ERR_INPUT, NULL, "'z'"},
    {"FITS text", NULL, 4, 0, WF_ERR_INPUT, NULL, "'RA_DEG'"},
    {"missing file", NULL, 0, 0, WF_ERR_IO, NULL, NULL},
};
#define N_BAD ((int)(sizeof BAD / sizeof *BAD))

START_TEST(test_bad_input)
{
    const bad_case *b = &BAD[_i];
    char name[64];
    snprintf(name, sizeof name, "bad%02d.%s", _i, b->text ? "csv" : "fits");
    const char *path = tmp_path(name);
    if (b->text)
        write_text(path, b->text);
    else if (b->fits_kind)
        write_fits_table(path, b->fits_kind);
    wf_catalog c;
    memset(&c, 0x5a, sizeof c);
    wf_status st = b->star ? wf_catalog_read_stars(path, &c) : wf_catalog_read_galaxies(path, &c);
    const char *msg = wf_error_message();
    ck_assert_msg(st == b->status, "%s: status %d, expected %d (%s)", b->what, st, b->status, msg);
    ck_assert_msg(strstr(msg, path) != NULL, "%s: message does not name the file: %s", b->what,
                  msg);
    if (b->row)
        ck_assert_msg(strstr(msg, b->row) != NULL, "%s: no '%s' in: %s", b->what, b->row, msg);
    if (b->column)
        ck_assert_msg(strstr(msg, b->column) != NULL, "%s: no '%s' in: %s", b->what, b->column,
                      msg);
    /* Nothing left behind on error. */
    ck_assert(c.n == 0 && c.id == NULL && c.ra == NULL);
    printf("bad input [%s]: %s\n", b->what, msg);
}
END_TEST

/* ------------------------------------------------------------------ GalSim scene */

START_TEST(test_galsim_scene)
{
    const char *ref = wf_test_reference_dir();
    WF_SKIP_UNLESS(ref, "GalSim reference");
    char path[4096];
    snprintf(path, sizeof path, "%s/scene_catalog_sca1_pointingA.csv.gz", ref);
    wf_catalog gal, stars, sne;
    ck_assert_msg(wf_catalog_read_galsim_scene(path, &gal, &stars, &sne) == WF_OK, "%s",
                  wf_error_message());
    ck_assert_uint_eq(gal.n, 8400);
    ck_assert_uint_eq(stars.n, 140);
    ck_assert_uint_eq(sne.n, 5);
    int b;
    ck_assert_int_eq(wf_catalog_band(&gal, "Y106", &b), WF_OK);
    /* First galaxy row: 0,gal,70.8569774682,-52.9789483582,28.9659,0.25434,0.12717,0.10789,
     * 0.17903,1000003,0.00149,-0.00763,... */
    ck_assert(gal.id[0] == 0 && gal.ra[0] == 70.8569774682 && gal.dec[0] == -52.9789483582);
    ck_assert(gal.mag[b][0] == 28.9659f && gal.hlr_disk[0] == 0.25434f &&
              gal.hlr_bulge[0] == 0.12717f);
    ck_assert(gal.bulge_frac[0] == 0.10789f && gal.knot_frac[0] == 0.17903f);
    ck_assert(gal.e1[0] == 0.00149f && gal.e2[0] == -0.00763f && gal.pa[0] == 0.0f);
    ck_assert(!gal.has_z && !gal.has_logmass && !gal.has_logsfr);
    ck_assert(stars.id[0] == 8400 && stars.mag[0][0] == 16.6158f);
    ck_assert(sne.id[0] == 8540 && sne.mag[0][0] == 24.3758f);
    wf_catalog_free(&gal);
    wf_catalog_free(&stars);
    wf_catalog_free(&sne);
}
END_TEST

/* The format is recognised from the columns alone: GalSim's scene format (gzip'd, with its
 * type column), a galaxy catalog in CSV and in FITS, a star catalog; a file that fits none of
 * the accepted formats is refused with the columns found and what each format needs. */
static const char SCENE_CSV[] =
    "id,type,ra_deg,dec_deg,mag_Y106,hlr_disk_arcsec,hlr_bulge_arcsec,bulge_frac,knot_frac_of_disk,"
    "knot_seed,e1,e2,x_sca1,y_sca1\n"
    "0,gal,70.8569774682,-52.9789483582,28.9659,0.25434,0.12717,0.10789,0.17903,1000003,0.00149,"
    "-0.00763,1913.3591,1188.6704\n"
    "1,star,70.9,-52.97,18.5,0,0,0,0,0,0,0,100.0,200.0\n";

static void write_gz(const char *path, const char *text)
{
    gzFile gz = gzopen(path, "wb");
    ck_assert_msg(gz != NULL, "cannot write %s", path);
    ck_assert_int_eq(gzputs(gz, text), (int)strlen(text));
    ck_assert_int_eq(gzclose(gz), Z_OK);
}

START_TEST(test_sniff)
{
    const int objects = WF_CATALOG_FORMAT_GALAXIES | WF_CATALOG_FORMAT_SCENE;
    wf_catalog_format fmt = 0;
    const char *scene = tmp_path("scene.csv.gz");
    write_gz(scene, SCENE_CSV);
    ck_assert_msg(wf_catalog_sniff(scene, objects, &fmt) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(fmt, WF_CATALOG_FORMAT_SCENE);
    /* what the galaxy reader alone said of it: the message users met */
    wf_catalog c;
    ck_assert_int_eq(wf_catalog_read_galaxies(scene, &c), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "missing required column 'z'"));
    /* the scene reader takes it: one galaxy, one star */
    wf_catalog gal, stars, sne;
    ck_assert_msg(wf_catalog_read_galsim_scene(scene, &gal, &stars, &sne) == WF_OK, "%s", wf_error_message());
    ck_assert(gal.n == 1 && stars.n == 1 && sne.n == 0);
    wf_catalog_free(&gal);
    wf_catalog_free(&stars);
    wf_catalog_free(&sne);

    const char *galaxies = tmp_path("galaxies.csv");
    write_text(galaxies, GOOD_CSV);
    ck_assert_msg(wf_catalog_sniff(galaxies, objects, &fmt) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(fmt, WF_CATALOG_FORMAT_GALAXIES);
    const char *fits = tmp_path("galaxies.fits");
    write_fits_table(fits, 0);
    ck_assert_msg(wf_catalog_sniff(fits, objects, &fmt) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(fmt, WF_CATALOG_FORMAT_GALAXIES);
    /* a FITS table without a redshift: neither galaxies nor a scene (no type column) */
    write_fits_table(fits, 3);
    ck_assert_int_eq(wf_catalog_sniff(fits, objects, &fmt), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "galaxy catalog (scene.kind catalog: scene.catalog, --catalog) needs z;"));

    /* a star catalog is one only where stars are accepted */
    const char *star = tmp_path("stars.csv");
    write_text(star, "ID,RA,Dec,mag_Y106\n5,71,-53,20\n");
    ck_assert_msg(wf_catalog_sniff(star, WF_CATALOG_FORMAT_STARS | objects, &fmt) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(fmt, WF_CATALOG_FORMAT_STARS);
    ck_assert_int_eq(wf_catalog_sniff(star, objects, &fmt), WF_ERR_INPUT);
    const char *msg = wf_error_message();
    ck_assert_ptr_nonnull(strstr(msg, "stars.csv: its columns (ID, RA, Dec, mag_Y106) fit no catalog format"));
    ck_assert_ptr_nonnull(strstr(msg, "scene.kind galsim or catalog: scene.catalog, --catalog) needs hlr, hlr_bulge, "
                                      "bulge_frac, knot_frac, e1, e2, type;"));
    ck_assert_ptr_nonnull(strstr(msg, "needs z, bulge_frac, knot_frac, e1, e2, pa, hlr (or fwhm);"));
    ck_assert_ptr_nonnull(strstr(msg, "it has the columns of a star catalog (scene.kind catalog: scene.stars, --stars)"));
    printf("sniff: %s\n", msg);

    /* a scene missing one column is no scene: the message names the column */
    const char *half = tmp_path("half.csv");
    write_text(half, "id,type,ra_deg,dec_deg,mag_Y106,hlr_disk_arcsec,hlr_bulge_arcsec,bulge_frac,e1,e2\n"
                     "0,gal,70.85,-52.97,28.9,0.25,0.12,0.1,0.0,0.0\n");
    ck_assert_int_eq(wf_catalog_sniff(half, objects, &fmt), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "--catalog) needs knot_frac;"));
    /* an empty file and a missing one keep their readers' messages */
    const char *empty = tmp_path("empty.csv");
    write_text(empty, "# nothing\n");
    ck_assert_int_eq(wf_catalog_sniff(empty, objects, &fmt), WF_ERR_INPUT);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "no header row"));
    ck_assert_int_eq(wf_catalog_sniff(tmp_path("absent.csv"), objects, &fmt), WF_ERR_IO);

    const char *ref = wf_test_reference_dir();
    if (!ref) WF_SKIP("GalSim reference not found: the benchmark scene itself not sniffed");
    char path[4096];
    snprintf(path, sizeof path, "%s/scene_catalog_sca1_pointingA.csv.gz", ref);
    ck_assert_msg(wf_catalog_sniff(path, objects, &fmt) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(fmt, WF_CATALOG_FORMAT_SCENE);
}
END_TEST

/* ------------------------------------------------------------------ synthetic catalog */

static double truncated_sigma(double sigma, double cut)
{
    double a = cut / sigma;
    double phi = exp(-0.5 * a * a) / sqrt(2.0 * M_PI);
    return sigma * sqrt(1.0 - 2.0 * a * phi / erf(a / M_SQRT2));
}

START_TEST(test_synth_statistics)
{
    /* ~1800 arcmin² (~270,000 galaxies): bins of the counts table hold 7,000-100,000. */
    wf_synth *s = small_synth(42, 0.4, 0);
    uint32_t *cells;
    size_t ncell;
    ck_assert_int_eq(wf_synth_cells(s, &cells, &ncell), WF_OK);
    double area = 0.0;
    for (size_t k = 0; k < ncell; k++) {
        double a, ra, dec;
        wf_synth_cell_info(s, cells[k], &a, &ra, &dec);
        area += a;
    }
    free(cells);
    double t0 = now_s();
    wf_catalog gal, stars;
    ck_assert_int_eq(wf_synth_generate_all(s, &gal, &stars), WF_OK);
    double dt = now_s() - t0;
    double gd, sd;
    wf_synth_expected_density(s, &gd, &sd);
    printf("synthetic: %.1f arcmin², %zu galaxies (%.2f /arcmin², model %.2f), %zu stars (%.3f "
           "/arcmin², "
           "model %.3f); %.3f s (%.2f us/object)\n",
           area, gal.n, gal.n / area, gd, stars.n, stars.n / area, sd, dt,
           1e6 * dt / (double)(gal.n + stars.n));
    ck_assert_msg(fabs(gd - 150.0) < 0.02 * 150.0, "model density %.2f", gd);
    ck_assert(fabs(sd - 2.5) < 1e-9);
    double mu = gd * area;
    ck_assert_msg(fabs((double)gal.n - mu) < 4.0 * sqrt(mu), "galaxies %zu, expected %.0f", gal.n,
                  mu);
    mu = sd * area;
    ck_assert_msg(fabs((double)stars.n - mu) < 4.0 * sqrt(mu), "stars %zu, expected %.0f", stars.n,
                  mu);

    /* H-band counts against the SPEC table (1-mag bins centred on 20.5 ... 25.5). */
    static const double table[6] = {3.9, 7.4, 13.6, 24.9, 41.8, 55.8};
    long bins[6] = {0};
    int bh;
    ck_assert_int_eq(wf_catalog_band(&gal, "H158", &bh), WF_OK);
    for (size_t i = 0; i < gal.n; i++) {
        int k = (int)floor(gal.mag[bh][i] - 20.0);
        if (k >= 0 && k < 6) bins[k]++;
    }
    for (int k = 0; k < 6; k++) {
        double e = table[k] * area;
        printf("  dN/dm H=%.1f: %.2f /arcmin²/mag (SPEC %.1f, %+.1f sigma)\n", 20.5 + k,
               bins[k] / area, table[k], (bins[k] - e) / sqrt(e));
        ck_assert_msg(fabs(bins[k] - e) < 4.0 * sqrt(e), "bin %d: %ld vs %.0f", k, bins[k], e);
    }
    double slope_model;
    wf_synth_dndm(s, 27.0, &slope_model);
    double n26;
    wf_synth_dndm(s, 26.0, &n26);
    ck_assert(fabs(log10(slope_model / n26) - 0.17) < 1e-9); /* faint extrapolation slope */

    /* Size-magnitude: least squares of log10 r_e on (H - 22.5). */
    double sx = 0, sy = 0, sxx = 0, sxy = 0, n = (double)gal.n;
    for (size_t i = 0; i < gal.n; i++) {
        double x = gal.mag[bh][i] - 22.5, y = log10(gal.hlr_disk[i]);
        sx += x;
        sy += y;
        sxx += x * x;
        sxy += x * y;
        ck_assert(gal.hlr_bulge[i] == (float)(0.5 * (double)gal.hlr_disk[i]) ||
                  fabs(gal.hlr_bulge[i] / gal.hlr_disk[i] - 0.5) < 1e-6);
    }
    double varx = sxx / n - (sx / n) * (sx / n);
    double slope = (sxy / n - sx / n * sy / n) / varx;
    double icpt = sy / n - slope * sx / n;
    double ss = 0;
    for (size_t i = 0; i < gal.n; i++) {
        double r = log10(gal.hlr_disk[i]) - icpt - slope * (gal.mag[bh][i] - 22.5);
        ss += r * r;
    }
    double scatter = sqrt(ss / (n - 2));
    double se_slope = scatter / sqrt(n * varx);
    printf("  size-magnitude: slope %.4f +- %.4f (SPEC -0.07), log r_e(22.5) %.4f (SPEC -0.42), "
           "scatter "
           "%.4f dex (SPEC 0.25)\n",
           slope, se_slope, icpt, scatter);
    ck_assert(fabs(slope + 0.07) < 4.0 * se_slope);
    ck_assert(fabs(icpt + 0.42) < 4.0 * scatter / sqrt(n) + 4.0 * se_slope * fabs(sx / n));
    ck_assert(fabs(scatter - 0.25) < 4.0 * 0.25 / sqrt(2.0 * n));

    /* Shapes: each component N(0, 0.27) truncated at +-0.7. */
    double want = truncated_sigma(0.27, 0.7);
    double s1 = 0, s2 = 0, m1 = 0;
    double emax = 0;
    long edge = 0;
    for (size_t i = 0; i < gal.n; i++) {
        s1 += (double)gal.e1[i] * gal.e1[i];
        s2 += (double)gal.e2[i] * gal.e2[i];
        m1 += gal.e1[i];
        emax = fmax(emax, fmax(fabs(gal.e1[i]), fabs(gal.e2[i])));
        edge += fabs(gal.e1[i]) > 0.65;
        ck_assert(gal.knot_frac[i] >= 0.0f && gal.knot_frac[i] <= 0.25f);
        ck_assert(gal.bulge_frac[i] >= 0.0f && gal.bulge_frac[i] <= 1.0f);
        ck_assert(gal.pa[i] >= 0.0f && gal.pa[i] <= 180.0f);
        ck_assert(gal.z[i] >= 0.0099f && gal.z[i] <= 6.0f);
        ck_assert(gal.logmass[i] >= 4.0f && gal.logmass[i] <= 12.5f);
    }
    double sig1 = sqrt(s1 / n), sig2 = sqrt(s2 / n);
    double p_edge =
        (erf(0.7 / 0.27 / M_SQRT2) - erf(0.65 / 0.27 / M_SQRT2)) / erf(0.7 / 0.27 / M_SQRT2);
    printf("  shapes: sigma(e1) %.4f, sigma(e2) %.4f (truncated N(0, 0.27) at 0.7: %.4f), max "
           "|e_i| %.4f, "
           "|e1| > 0.65: %ld (expected %.0f)\n",
           sig1, sig2, want, emax, edge, p_edge * n);
    ck_assert(fabs(sig1 - want) < 4.0 * want / sqrt(2.0 * n));
    ck_assert(fabs(sig2 - want) < 4.0 * want / sqrt(2.0 * n));
    ck_assert(fabs(m1 / n) < 4.0 * want / sqrt(n));
    ck_assert(emax <= 0.7 && emax > 0.69);
    ck_assert(fabs(edge - p_edge * n) < 4.0 * sqrt(p_edge * n));

    /* Redshift, mass and SFR follow the documented model: median z of 22 <= H < 23 near the
     * library's 0.98; star-forming main sequence (Speagle et al. 2014) for 9.5 < log M < 10. */
    float *zs = malloc(gal.n * sizeof *zs);
    size_t nz = 0;
    double dsum = 0;
    size_t nms = 0;
    for (size_t i = 0; i < gal.n; i++) {
        if (gal.mag[bh][i] >= 22.0f && gal.mag[bh][i] < 23.0f) zs[nz++] = gal.z[i];
        if (gal.logmass[i] > 9.5f && gal.logmass[i] < 10.0f && gal.z[i] > 0.5f && gal.z[i] < 2.0f) {
            double z = gal.z[i];
            double ol = 0.7, th = 977.792 / 70.0;
            double t = 2.0 / (3.0 * sqrt(ol)) * th * asinh(sqrt(ol / 0.3) * pow(1 + z, -1.5));
            double ms = (0.84 - 0.026 * t) * gal.logmass[i] - (6.51 - 0.11 * t);
            dsum += gal.logsfr[i] - ms;
            nms++;
        }
    }
    /* median by bisection on the value (no sort needed for one quantile) */
    double zlo = 0.0, zhi = 6.0;
    for (int it = 0; it < 40; it++) {
        double mid = 0.5 * (zlo + zhi);
        size_t below = 0;
        for (size_t i = 0; i < nz; i++) below += zs[i] < mid;
        if (below < nz / 2)
            zlo = mid;
        else
            zhi = mid;
    }
    printf(
        "  median z (22 <= H < 23): %.3f over %zu; mean log SFR - main sequence (9.5 < log M < 10, "
        "0.5 < z < 2): %+.3f over %zu\n",
        zlo, nz, dsum / (double)nms, nms);
    ck_assert(fabs(zlo - 0.98) < 0.04);
    ck_assert(fabs(dsum / (double)nms) < 0.15);
    free(zs);

    wf_catalog_free(&gal);
    wf_catalog_free(&stars);
    wf_synth_free(s);
}
END_TEST

static int cmp_id(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* Row of cat with the given id (linear map built by the caller: sorted ids + rows). */
typedef struct id_row {
    int64_t id;
    size_t row;
} id_row;

static size_t find_row(const id_row *map, size_t n, int64_t id)
{
    id_row key = {id, 0};
    const id_row *r = bsearch(&key, map, n, sizeof *map, cmp_id);
    ck_assert_msg(r != NULL, "id %lld missing from the full generation", (long long)id);
    return r->row;
}

static id_row *id_map(const wf_catalog *c)
{
    id_row *m = malloc((c->n ? c->n : 1) * sizeof *m);
    for (size_t i = 0; i < c->n; i++) m[i] = (id_row){c->id[i], i};
    qsort(m, c->n, sizeof *m, cmp_id);
    for (size_t i = 1; i < c->n; i++) ck_assert_msg(m[i].id != m[i - 1].id, "duplicate id");
    return m;
}

static void assert_same_row(const wf_catalog *a, size_t i, const wf_catalog *b, size_t j)
{
    ck_assert(a->id[i] == b->id[j] && a->ra[i] == b->ra[j] && a->dec[i] == b->dec[j]);
    for (int k = 0; k < a->nband; k++) ck_assert(a->mag[k][i] == b->mag[k][j]);
    if (a->kind != WF_CATALOG_GALAXY) return;
    ck_assert(a->z[i] == b->z[j] && a->hlr_disk[i] == b->hlr_disk[j] && a->e1[i] == b->e1[j] &&
              a->e2[i] == b->e2[j] && a->pa[i] == b->pa[j] && a->logmass[i] == b->logmass[j] &&
              a->logsfr[i] == b->logsfr[j] && a->bulge_frac[i] == b->bulge_frac[j] &&
              a->knot_frac[i] == b->knot_frac[j]);
}

static void check_cell_independence(int clustering)
{
    wf_synth *s = small_synth(7, 0.12, clustering);
    wf_catalog gal, stars, g2, s2;
    ck_assert_int_eq(wf_synth_generate_all(s, &gal, &stars), WF_OK);
    /* Same seed, new generator: identical, bit for bit. */
    wf_synth *t = small_synth(7, 0.12, clustering);
    ck_assert_int_eq(wf_synth_generate_all(t, &g2, &s2), WF_OK);
    assert_same_catalog(&gal, &g2);
    assert_same_catalog(&stars, &s2);
    wf_catalog_free(&g2);
    wf_catalog_free(&s2);
    wf_synth_free(t);
    /* Another seed: different objects. */
    t = small_synth(8, 0.12, clustering);
    ck_assert_int_eq(wf_synth_generate_all(t, &g2, &s2), WF_OK);
    ck_assert(g2.n != gal.n || memcmp(g2.ra, gal.ra, gal.n * sizeof(double)) != 0);
    wf_catalog_free(&g2);
    wf_catalog_free(&s2);
    wf_synth_free(t);

    /* Any partition of the cells, each part in any order, gives exactly the full run's
     * objects: each object once, identical in every column. */
    uint32_t *cells;
    size_t ncell;
    ck_assert_int_eq(wf_synth_cells(s, &cells, &ncell), WF_OK);
    uint32_t *part[2];
    size_t npart[2] = {0, 0};
    part[0] = malloc(ncell * sizeof **part);
    part[1] = malloc(ncell * sizeof **part);
    for (size_t k = ncell; k-- > 0;) {
        int w = k % 5 == 2;
        part[w][npart[w]++] = cells[k];
    }
    id_row *gm = id_map(&gal), *sm = id_map(&stars);
    char *gseen = calloc(gal.n + 1, 1), *sseen = calloc(stars.n + 1, 1);
    size_t gtot = 0, stot = 0;
    for (int w = 0; w < 2; w++) {
        ck_assert_int_eq(wf_synth_generate(s, part[w], npart[w], &g2, &s2), WF_OK);
        ck_assert_uint_gt(g2.n, 0);
        for (size_t i = 0; i < g2.n; i++) {
            size_t r = find_row(gm, gal.n, g2.id[i]);
            ck_assert(!gseen[r]);
            gseen[r] = 1;
            assert_same_row(&g2, i, &gal, r);
        }
        for (size_t i = 0; i < s2.n; i++) {
            size_t r = find_row(sm, stars.n, s2.id[i]);
            ck_assert(!sseen[r]);
            sseen[r] = 1;
            assert_same_row(&s2, i, &stars, r);
        }
        gtot += g2.n;
        stot += s2.n;
        wf_catalog_free(&g2);
        wf_catalog_free(&s2);
    }
    ck_assert_uint_eq(gtot, gal.n);
    ck_assert_uint_eq(stot, stars.n);
    free(gseen);
    free(sseen);
    free(part[0]);
    free(part[1]);

    /* A footprint query (an SCA-sized square, with margin) equals the whole field filtered. */
    double cra = 71.02, cdec = -52.98, h = 3.75 / 60.0;
    double vra[4], vdec[4];
    double rot = 0.3;
    for (int k = 0; k < 4; k++) {
        double ang = rot + k * M_PI / 2 + M_PI / 4;
        double dx = h * M_SQRT2 * cos(ang), dy = h * M_SQRT2 * sin(ang);
        vra[k] = cra + dx / cos(cdec * DEG);
        vdec[k] = cdec + dy;
    }
    wf_skyregion reg;
    ck_assert_int_eq(wf_skyindex_polygon(vra, vdec, 4, 5.0, &reg), WF_OK);
    double t0 = now_s();
    ck_assert_int_eq(wf_synth_select(s, &reg, &g2, &s2), WF_OK);
    double dt = now_s() - t0;
    size_t j = 0;
    for (size_t i = 0; i < gal.n; i++)
        if (wf_skyindex_contains(&reg, gal.ra[i], gal.dec[i])) {
            ck_assert_uint_lt(j, g2.n);
            assert_same_row(&g2, j, &gal, i);
            j++;
        }
    ck_assert_uint_eq(j, g2.n);
    j = 0;
    for (size_t i = 0; i < stars.n; i++)
        if (wf_skyindex_contains(&reg, stars.ra[i], stars.dec[i]))
            assert_same_row(&s2, j++, &stars, i);
    ck_assert_uint_eq(j, s2.n);
    printf("synthetic%s: field of %zu galaxies; SCA footprint query: %zu galaxies, %zu stars in "
           "%.2f ms\n",
           clustering ? " (clustered)" : "", gal.n, g2.n, s2.n, 1e3 * dt);
    wf_catalog_free(&g2);
    wf_catalog_free(&s2);
    free(gm);
    free(sm);
    free(cells);
    wf_catalog_free(&gal);
    wf_catalog_free(&stars);
    wf_synth_free(s);
}

START_TEST(test_synth_cells_independent) { check_cell_independence(0); }
END_TEST

START_TEST(test_synth_clustered)
{
    check_cell_independence(1);
    /* Clustering keeps the mean density and adds close pairs: for a Neyman-Scott process
     * with a fraction f of galaxies in groups of mean m members, Gaussian radius sigma, the
     * mean number of extra neighbours within r per galaxy is f m (1 - exp(-r²/4sigma²)),
     * against n pi r² for Poisson positions. */
    wf_synth *s0 = small_synth(3, 0.2, 0), *s1 = small_synth(3, 0.2, 1);
    wf_catalog g0, g1;
    ck_assert_int_eq(wf_synth_generate_all(s0, &g0, NULL), WF_OK);
    ck_assert_int_eq(wf_synth_generate_all(s1, &g1, NULL), WF_OK);
    ck_assert_msg(fabs((double)g1.n / g0.n - 1.0) < 0.05, "%zu vs %zu", g1.n, g0.n);
    double per[2] = {0, 0}, pois[2] = {0, 0};
    const wf_catalog *gs[2] = {&g0, &g1};
    const double r = 10.0; /* arcsec */
    /* Galaxies well inside the field (0.2 deg), so that every circle is full; the Poisson
     * expectation uses the density actually realised there. */
    wf_skyregion inner;
    wf_skyindex_circle(71.0, -53.0, 0.18, 0.0, &inner);
    double inner_area = 2.0 * M_PI * (1.0 - cos(0.18 * DEG)) / (DEG * DEG) * 3600.0 * 3600.0;
    for (int k = 0; k < 2; k++) {
        wf_skyindex *ix;
        ck_assert_int_eq(wf_skyindex_build(gs[k]->ra, gs[k]->dec, gs[k]->n, 0.5, &ix), WF_OK);
        wf_selection sel = {0};
        long close = 0, used = 0;
        for (size_t i = 0; i < gs[k]->n; i++) {
            if (!wf_skyindex_contains(&inner, gs[k]->ra[i], gs[k]->dec[i])) continue;
            wf_skyregion reg;
            wf_skyindex_circle(gs[k]->ra[i], gs[k]->dec[i], r / 3600.0, 0.0, &reg);
            wf_skyindex_select(ix, &reg, &sel);
            close += (long)sel.n - 1;
            used++;
        }
        per[k] = (double)close / (double)used;
        pois[k] = (double)used / inner_area * M_PI * r * r;
        wf_skyindex_selection_free(&sel);
        wf_skyindex_free(ix);
    }
    double sig = 10.0;
    double excess = 0.3 * 8.0 * (1.0 - exp(-r * r / (4.0 * sig * sig)));
    printf("clustering: %zu vs %zu galaxies; neighbours within %.0f\": %.3f (Poisson, expected "
           "%.3f) vs %.3f "
           "(groups, expected %.3f)\n",
           g0.n, g1.n, r, per[0], pois[0], per[1], pois[1] + excess);
    ck_assert(fabs(per[0] / pois[0] - 1.0) < 0.01);
    ck_assert(fabs((per[1] - pois[1]) / excess - 1.0) < 0.2);
    wf_catalog_free(&g0);
    wf_catalog_free(&g1);
    wf_synth_free(s0);
    wf_synth_free(s1);

    /* Group radius must fit in a cell. */
    wf_synth_config cfg;
    wf_synth_defaults(&cfg);
    cfg.clustering = 1;
    cfg.cluster_sigma_arcsec = 20.0;
    cfg.cell_arcmin = 1.0;
    wf_synth *bad;
    ck_assert_int_eq(wf_synth_create(&cfg, &bad), WF_ERR_RANGE);
}
END_TEST

/* ------------------------------------------------------------------ spatial index */

/* A uniform point on the sphere within radius_deg of (ra, dec). */
static void cap_point(wf_rng *rng, double ra, double dec, double radius_deg, double *pra,
                      double *pdec)
{
    double cr = cos(radius_deg * DEG);
    double ct = 1.0 - wf_rng_uniform53(rng) * (1.0 - cr), st = sqrt(fmax(0.0, 1.0 - ct * ct));
    double ph = 2.0 * M_PI * wf_rng_uniform53(rng);
    /* point around the z axis, then rotate z -> (ra, dec) */
    double p[3] = {st * cos(ph), st * sin(ph), ct};
    double a = ra * DEG, d = dec * DEG;
    double ex[3] = {-sin(a), cos(a), 0.0};
    double ny[3] = {-sin(d) * cos(a), -sin(d) * sin(a), cos(d)};
    double c[3] = {cos(d) * cos(a), cos(d) * sin(a), sin(d)};
    double q[3];
    for (int k = 0; k < 3; k++) q[k] = p[0] * ex[k] + p[1] * ny[k] + p[2] * c[k];
    double r = atan2(q[1], q[0]) / DEG;
    if (r < 0) r += 360.0;
    if (r >= 360.0) r -= 360.0;
    *pra = r;
    *pdec = atan2(q[2], hypot(q[0], q[1])) / DEG;
}

static void brute(const double *ra, const double *dec, size_t n, const wf_skyregion *reg,
                  wf_selection *out)
{
    out->n = 0;
    for (size_t i = 0; i < n; i++)
        if (wf_skyindex_contains(reg, ra[i], dec[i])) {
            if (out->n == out->cap) {
                out->cap = out->cap ? 2 * out->cap : 1024;
                out->idx = realloc(out->idx, out->cap * sizeof *out->idx);
            }
            out->idx[out->n++] = (uint32_t)i;
        }
}

/* A square of side `side` deg centred on (ra, dec), rotated by rot. */
static void square(double ra, double dec, double side, double rot, double *vra, double *vdec)
{
    double a = ra * DEG, d = dec * DEG;
    double ex[3] = {-sin(a), cos(a), 0.0};
    double ny[3] = {-sin(d) * cos(a), -sin(d) * sin(a), cos(d)};
    double c[3] = {cos(d) * cos(a), cos(d) * sin(a), sin(d)};
    for (int k = 0; k < 4; k++) {
        double ang = rot + M_PI / 4 + k * M_PI / 2;
        double x = tan(side * DEG / M_SQRT2) * cos(ang), y = tan(side * DEG / M_SQRT2) * sin(ang);
        double q[3];
        for (int j = 0; j < 3; j++) q[j] = c[j] + x * ex[j] + y * ny[j];
        double r = atan2(q[1], q[0]) / DEG;
        vra[k] = r < 0 ? r + 360.0 : r;
        vdec[k] = atan2(q[2], hypot(q[0], q[1])) / DEG;
    }
}

START_TEST(test_index_equals_brute_force)
{
    /* Patches: both poles, across RA = 0 on the equator and at -60, the deep field. */
    static const double patch[5][3] = {{0.0, 90.0, 1.5},
                                       {123.0, -90.0, 1.5},
                                       {0.0, 0.0, 1.5},
                                       {359.9, -60.0, 1.5},
                                       {71.0, -53.0, 1.0}};
    const size_t per = 20000;
    size_t n = 5 * per + 6;
    double *ra = malloc(n * sizeof *ra), *dec = malloc(n * sizeof *dec);
    wf_noise nz = {WF_NOISE_PHILOX, 99u, 0u, 0u};
    wf_rng rng;
    wf_rng_init(&rng, &nz, 0, 0, WF_PURPOSE_TEST);
    for (int p = 0; p < 5; p++)
        for (size_t i = 0; i < per; i++)
            cap_point(&rng, patch[p][0], patch[p][1], patch[p][2], &ra[p * per + i],
                      &dec[p * per + i]);
    /* Exact edge values. */
    double edge[6][2] = {{0.0, 90.0},         {0.0, -90.0},   {0.0, 0.0},
                         {359.99999999, 0.0}, {180.0, 89.99}, {0.0, -60.0}};
    for (int k = 0; k < 6; k++) {
        ra[5 * per + k] = edge[k][0];
        dec[5 * per + k] = edge[k][1];
    }
    const double bands[3] = {0.0, 0.37, 7.0};
    wf_selection got = {0}, want = {0};
    long nq = 0, nsel = 0;
    for (int bi = 0; bi < 3; bi++) {
        wf_skyindex *ix;
        ck_assert_msg(wf_skyindex_build(ra, dec, n, bands[bi], &ix) == WF_OK, "%s",
                      wf_error_message());
        wf_rng q;
        wf_rng_init(&q, &nz, 1, (uint32_t)bi, WF_PURPOSE_TEST);
        for (int p = 0; p < 5; p++)
            for (int k = 0; k < 24; k++) {
                double cra, cdec;
                cap_point(&q, patch[p][0], patch[p][1], patch[p][2] * 1.1, &cra, &cdec);
                double margin = 60.0 * wf_rng_uniform(&q);
                wf_skyregion reg;
                if (k % 2 == 0) {
                    double r =
                        (k % 8 == 0) ? 0.3 * wf_rng_uniform(&q) : 0.02 + 0.2 * wf_rng_uniform(&q);
                    ck_assert_int_eq(wf_skyindex_circle(cra, cdec, r, margin, &reg), WF_OK);
                } else {
                    double vra[4], vdec[4];
                    square(cra, cdec, 0.125 + 0.3 * wf_rng_uniform(&q),
                           2 * M_PI * wf_rng_uniform(&q), vra, vdec);
                    ck_assert_msg(wf_skyindex_polygon(vra, vdec, 4, margin, &reg) == WF_OK, "%s",
                                  wf_error_message());
                }
                ck_assert_int_eq(wf_skyindex_select(ix, &reg, &got), WF_OK);
                brute(ra, dec, n, &reg, &want);
                ck_assert_msg(got.n == want.n, "patch %d query %d: %zu vs brute force %zu", p, k,
                              got.n, want.n);
                ck_assert(memcmp(got.idx, want.idx, got.n * sizeof *got.idx) == 0);
                nq++;
                nsel += (long)got.n;
            }
        /* Specials: centred on each pole, a polygon around the pole, squares across RA = 0,
         * a large circle, a zero-radius circle on an object, the whole sky. */
        wf_skyregion sp[9];
        double vra[4], vdec[4];
        ck_assert_int_eq(wf_skyindex_circle(0.0, 90.0, 0.5, 10.0, &sp[0]), WF_OK);
        ck_assert_int_eq(wf_skyindex_circle(17.0, -90.0, 1.2, 0.0, &sp[1]), WF_OK);
        square(45.0, 90.0, 1.0, 0.2, vra, vdec);
        ck_assert_int_eq(wf_skyindex_polygon(vra, vdec, 4, 30.0, &sp[2]), WF_OK);
        square(0.0, 0.0, 0.5, 0.0, vra, vdec);
        ck_assert_int_eq(wf_skyindex_polygon(vra, vdec, 4, 5.0, &sp[3]), WF_OK);
        square(359.95, -60.0, 0.5, 0.7, vra, vdec);
        ck_assert_int_eq(wf_skyindex_polygon(vra, vdec, 4, 5.0, &sp[4]), WF_OK);
        ck_assert_int_eq(wf_skyindex_circle(10.0, 5.0, 40.0, 0.0, &sp[5]), WF_OK);
        ck_assert_int_eq(wf_skyindex_circle(ra[17], dec[17], 0.0, 0.0, &sp[6]), WF_OK);
        ck_assert_int_eq(wf_skyindex_circle(200.0, 10.0, 180.0, 0.0, &sp[7]), WF_OK);
        ck_assert_int_eq(wf_skyindex_circle(359.99, 89.9, 0.3, 0.0, &sp[8]), WF_OK);
        for (int k = 0; k < 9; k++) {
            ck_assert_int_eq(wf_skyindex_select(ix, &sp[k], &got), WF_OK);
            brute(ra, dec, n, &sp[k], &want);
            ck_assert_msg(got.n == want.n, "special %d: %zu vs brute force %zu", k, got.n, want.n);
            ck_assert(memcmp(got.idx, want.idx, got.n * sizeof *got.idx) == 0);
            if (k == 6) ck_assert_uint_ge(got.n, 1);
            if (k == 7) ck_assert_uint_eq(got.n, n);
            if (k == 0 || k == 1 || k == 2) ck_assert_uint_gt(got.n, 100);
            nq++;
        }
        wf_skyindex_free(ix);
    }
    printf("index vs brute force: %ld queries, %ld objects selected, all identical\n", nq, nsel);
    wf_skyindex_selection_free(&got);
    wf_skyindex_selection_free(&want);
    free(ra);
    free(dec);
}
END_TEST

START_TEST(test_region_errors)
{
    wf_skyregion r;
    double bra[4] = {10.0, 10.1, 10.0, 10.1}, bdec[4] = {0.0, 0.0, 0.1, 0.1}; /* bow tie */
    ck_assert_int_eq(wf_skyindex_polygon(bra, bdec, 4, 0.0, &r), WF_ERR_INPUT);
    ck_assert_msg(strstr(wf_error_message(), "convex"), "%s", wf_error_message());
    double dra[3] = {10.0, 10.0, 10.1}, ddec[3] = {0.0, 0.0, 0.1};
    ck_assert_int_eq(wf_skyindex_polygon(dra, ddec, 3, 0.0, &r), WF_ERR_INPUT);
    ck_assert_int_eq(wf_skyindex_polygon(dra, ddec, 2, 0.0, &r), WF_ERR_INPUT);
    double ora[3] = {10.0, 10.1, 10.0}, odec[3] = {95.0, 0.0, 0.1};
    ck_assert_int_eq(wf_skyindex_polygon(ora, odec, 3, 0.0, &r), WF_ERR_RANGE);
    ck_assert_int_eq(wf_skyindex_circle(10.0, 0.0, -1.0, 0.0, &r), WF_ERR_RANGE);
    ck_assert_int_eq(wf_skyindex_circle(NAN, 0.0, 1.0, 0.0, &r), WF_ERR_RANGE);
    /* Either orientation of a valid polygon is the same region. */
    double cra[4] = {10.0, 10.1, 10.1, 10.0}, cdec[4] = {0.0, 0.0, 0.1, 0.1};
    double rra[4] = {10.0, 10.0, 10.1, 10.1}, rdec[4] = {0.0, 0.1, 0.1, 0.0};
    wf_skyregion a, b;
    ck_assert_int_eq(wf_skyindex_polygon(cra, cdec, 4, 0.0, &a), WF_OK);
    ck_assert_int_eq(wf_skyindex_polygon(rra, rdec, 4, 0.0, &b), WF_OK);
    ck_assert(wf_skyindex_contains(&a, 10.05, 0.05) && wf_skyindex_contains(&b, 10.05, 0.05));
    ck_assert(!wf_skyindex_contains(&a, 10.15, 0.05) && !wf_skyindex_contains(&b, 10.15, 0.05));
    /* The margin: 0.05 deg beyond the edge is in with a 200" margin, out with 100". */
    ck_assert_int_eq(wf_skyindex_polygon(cra, cdec, 4, 200.0, &a), WF_OK);
    ck_assert_int_eq(wf_skyindex_polygon(cra, cdec, 4, 100.0, &b), WF_OK);
    ck_assert(wf_skyindex_contains(&a, 10.15, 0.05) && !wf_skyindex_contains(&b, 10.15, 0.05));
    /* ... and around a corner it is a circle: (0.04, 0.04) deg beyond is 204" from it. */
    ck_assert(!wf_skyindex_contains(&a, 10.14, 0.14));
    double bad_ra[2] = {400.0, 1.0}, bad_dec[2] = {0.0, 0.0};
    wf_skyindex *ix;
    ck_assert_int_eq(wf_skyindex_build(bad_ra, bad_dec, 2, 0.0, &ix), WF_ERR_RANGE);
}
END_TEST

/* A point (x east, y north) arcsec from (ra0, dec0), through the tangent plane. */
static void offset_radec(double ra0, double dec0, double x, double y, double *ra, double *dec)
{
    double c[3] = {cos(dec0 * DEG) * cos(ra0 * DEG), cos(dec0 * DEG) * sin(ra0 * DEG), sin(dec0 * DEG)};
    double e[3] = {-sin(ra0 * DEG), cos(ra0 * DEG), 0.0};
    double n[3] = {-sin(dec0 * DEG) * cos(ra0 * DEG), -sin(dec0 * DEG) * sin(ra0 * DEG), cos(dec0 * DEG)};
    double p[3], as = DEG / 3600.0;
    for (int k = 0; k < 3; k++) p[k] = c[k] + x * as * e[k] + y * as * n[k];
    double l = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
    *dec = asin(p[2] / l) / DEG;
    *ra = fmod(atan2(p[1], p[0]) / DEG + 360.0, 360.0);
}

START_TEST(test_region_thin)
{
    /* SCA-wide rectangles one to 16 rows tall (4088 x 0.11" by 0.11" to 1.76"), at random
     * places and angles: a valid footprint of a sub-array readout. The short edges' normals
     * carry rounding of ~eps / their length, which a fixed 1e-12 rad tolerance did not
     * allow (the 16-row synthetic scene failed "not convex"). */
    wf_noise nz = {WF_NOISE_PHILOX, 77, 0, 0};
    wf_rng rng;
    wf_rng_init(&rng, &nz, 0, 0, WF_PURPOSE_TEST);
    const double heights[3] = {0.11, 0.44, 1.76};
    int n = 0;
    for (int t = 0; t < 300; t++) {
        double u[4];
        for (int k = 0; k < 4; k++) u[k] = wf_rng_uniform53(&rng);
        double ra0 = 360.0 * u[0], dec0 = -85.0 + 170.0 * u[1], th = 2.0 * M_PI * u[2];
        double w = 4088 * 0.11 / 2.0, h = heights[t % 3] / 2.0;
        const double lx[4] = {-w, w, w, -w}, ly[4] = {-h, -h, h, h};
        double ra[4], dec[4];
        for (int k = 0; k < 4; k++)
            offset_radec(ra0, dec0, lx[k] * cos(th) - ly[k] * sin(th), lx[k] * sin(th) + ly[k] * cos(th),
                         &ra[k], &dec[k]);
        wf_skyregion reg;
        ck_assert_msg(wf_skyindex_polygon(ra, dec, 4, 0.0, &reg) == WF_OK, "case %d (height %g\"): %s", t,
                      2 * h, wf_error_message());
        double ri, di, ro, dout;
        offset_radec(ra0, dec0, 0.3 * w * cos(th), 0.3 * w * sin(th), &ri, &di);
        offset_radec(ra0, dec0, -(h + 0.5) * sin(th), (h + 0.5) * cos(th), &ro, &dout);
        ck_assert_msg(wf_skyindex_contains(&reg, ri, di), "case %d: a point inside is out", t);
        ck_assert_msg(!wf_skyindex_contains(&reg, ro, dout), "case %d: a point 0.5\" outside is in", t);
        n++;
    }
    ck_assert_int_eq(n, 300);
}
END_TEST

START_TEST(test_index_timing)
{
    /* 2.7 million galaxies over 5 deg² around the deep field: build once, then select the
     * objects of SCA-sized footprints (7.49' square, 5" margin). Timings are printed. */
    const size_t n = 2700000;
    double radius = sqrt(5.0 / M_PI);
    double *ra = malloc(n * sizeof *ra), *dec = malloc(n * sizeof *dec);
    ck_assert(ra && dec);
    wf_noise nz = {WF_NOISE_PHILOX, 7u, 0u, 0u};
    wf_rng rng;
    wf_rng_init(&rng, &nz, 2, 0, WF_PURPOSE_TEST);
    for (size_t i = 0; i < n; i++) cap_point(&rng, 71.0, -53.0, radius, &ra[i], &dec[i]);
    double t0 = now_s();
    wf_skyindex *ix;
    ck_assert_int_eq(wf_skyindex_build(ra, dec, n, 0.0, &ix), WF_OK);
    double tb = now_s() - t0;
    wf_selection sel = {0};
    const int nq = 200;
    double tq = 0, tmax = 0;
    size_t total = 0, examined = 0;
    for (int k = 0; k < nq; k++) {
        double cra, cdec, vra[4], vdec[4];
        cap_point(&rng, 71.0, -53.0, radius * 0.8, &cra, &cdec);
        square(cra, cdec, 4088 * 0.11 / 3600.0, 2 * M_PI * wf_rng_uniform(&rng), vra, vdec);
        wf_skyregion reg;
        ck_assert_int_eq(wf_skyindex_polygon(vra, vdec, 4, 5.0, &reg), WF_OK);
        double t1 = now_s();
        ck_assert_int_eq(wf_skyindex_select(ix, &reg, &sel), WF_OK);
        double dt = now_s() - t1;
        tq += dt;
        tmax = fmax(tmax, dt);
        total += sel.n;
        examined += sel.examined;
        if (k == 0) {
            wf_selection want = {0};
            double t2 = now_s();
            brute(ra, dec, n, &reg, &want);
            double tbf = now_s() - t2;
            ck_assert(want.n == sel.n && memcmp(want.idx, sel.idx, sel.n * sizeof *sel.idx) == 0);
            printf("index timing: brute-force scan of %zu objects: %.1f ms\n", n, 1e3 * tbf);
            wf_skyindex_selection_free(&want);
        }
    }
    printf(
        "index timing: %zu objects over 5 deg²: build %.3f s (%.1f MB index); SCA footprint query "
        "mean %.3f ms, max %.3f ms, %.0f objects selected of %.0f examined\n",
        n, tb, n * 20.0 / 1e6, 1e3 * tq / nq, 1e3 * tmax, (double)total / nq,
        (double)examined / nq);

    /* The synthetic generator at the same footprint size: only the cells under the SCA. */
    wf_synth_config cfg;
    wf_synth_defaults(&cfg);
    wf_synth *s;
    ck_assert_int_eq(wf_synth_create(&cfg, &s), WF_OK);
    double vra[4], vdec[4];
    square(71.0, -53.0, 4088 * 0.11 / 3600.0, 0.5, vra, vdec);
    wf_skyregion reg;
    ck_assert_int_eq(wf_skyindex_polygon(vra, vdec, 4, 5.0, &reg), WF_OK);
    uint32_t *cells;
    size_t ncell;
    ck_assert_int_eq(wf_synth_region_cells(s, &reg, &cells, &ncell), WF_OK);
    free(cells);
    wf_catalog g, st;
    t0 = now_s();
    ck_assert_int_eq(wf_synth_select(s, &reg, &g, &st), WF_OK);
    double ts = now_s() - t0;
    printf("synthetic SCA footprint: %zu cells generated, %zu galaxies + %zu stars kept, %.1f ms\n",
           ncell, g.n, st.n, 1e3 * ts);
    wf_catalog_free(&g);
    wf_catalog_free(&st);
    wf_synth_free(s);
    wf_skyindex_selection_free(&sel);
    wf_skyindex_free(ix);
    free(ra);
    free(dec);
}
END_TEST

static Suite *catalog_suite(void)
{
    Suite *s = suite_create("catalog");
    TCase *tc = tcase_create("catalog");
    tcase_set_timeout(tc, 300); /* sanitizer builds */
    tcase_add_test(tc, test_csv_good);
    tcase_add_test(tc, test_fits_good);
    tcase_add_test(tc, test_fits_table_search);
    tcase_add_test(tc, test_fits_header_not_ascii);
    tcase_add_test(tc, test_writers_roundtrip);
    tcase_add_loop_test(tc, test_bad_input, 0, N_BAD);
    tcase_add_test(tc, test_galsim_scene);
    tcase_add_test(tc, test_sniff);
    tcase_add_test(tc, test_synth_statistics);
    tcase_add_test(tc, test_synth_cells_independent);
    tcase_add_test(tc, test_synth_clustered);
    tcase_add_test(tc, test_index_equals_brute_force);
    tcase_add_test(tc, test_region_errors);
    tcase_add_test(tc, test_region_thin);
    tcase_add_test(tc, test_index_timing);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(catalog_suite()); }
