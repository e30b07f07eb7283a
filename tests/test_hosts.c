/* wfisim hosts (analysis/hosts.c): the directional light radius against hand-computed values
 * for WCSs whose +x is west, east and north; a synthetic scene (image, detection catalog and
 * truth built here) where nearest and DLR disagree by construction, a host that is not
 * detected, a hostless SN, SNe off the image or its coverage, stars and the SN's own detection
 * kept out of the candidates, and the counts by redshift; bad input refused with nothing
 * written. */
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "analysis/detect.h"
#include "analysis/hosts.h"
#include "sim/survey/wcs.h"
#include "tests/testutil.h"

#define DEG (M_PI / 180.0)
#define RA0 71.0
#define DEC0 (-53.0)

/* A plain TAN WCS of nx x ny pixels centred on (RA0, DEC0) whose pixel axes map to the sky
 * through cd (arcsec per pixel; row 0 east, row 1 north). */
static wf_wcs tan_wcs(int nx, int ny, const double cd_arcsec[2][2])
{
    wf_wcs w;
    memset(&w, 0, sizeof w);
    w.nx = nx, w.ny = ny;
    w.crpix[0] = 0.5 * (nx + 1), w.crpix[1] = 0.5 * (ny + 1);
    w.crval[0] = RA0, w.crval[1] = DEC0;
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++) w.cd[i][j] = cd_arcsec[i][j] / 3600.0;
    return w;
}

/* SEP 1.2.0's sep_extract allocates two arrays of its catalog twice and frees one (see
 * tests/test_detect.c): the end-to-end test detects in-process, under this suppression, since
 * `wfisim detect` built with SAN=1 exits 1 on that leak. */
const char *__lsan_default_suppressions(void);
const char *__lsan_default_suppressions(void) { return "leak:libsep.so\n"; }

/* ---- the DLR by hand --------------------------------------------------------------------- */

/* A = 5, B = 2 pixels, THETA = 30 deg counter-clockwise from +x, on three WCSs of 0.11"
 * pixels; the major axis's position angle east of north worked out by hand for each:
 *   +x west, +y north (the usual east-left image): the axis points 0.866 west + 0.5 north,
 *       PA = atan2(-0.866, 0.5) = -60 = 120 deg;
 *   +x east, +y north (mirrored): 0.866 east + 0.5 north, PA = 60 deg;
 *   +x north, +y west: 0.866 north + 0.5 west, PA = atan2(-0.5, 0.866) = -30 = 150 deg.
 * Along the major axis the DLR is A x 0.11", across it B x 0.11", and 30 deg off it
 * A B s / sqrt((A sin 30)^2 + (B cos 30)^2). */
START_TEST(dlr_by_hand)
{
    const double s = 0.11, A = 5, B = 2;
    struct { double cd[2][2]; double pa; const char *what; } cases[3] = {
        {{{-s, 0}, {0, s}}, 120.0, "+x west"},
        {{{s, 0}, {0, s}}, 60.0, "+x east"},
        {{{0, -s}, {s, 0}}, 150.0, "+x north"},
    };
    double general = A * B * s / sqrt(pow(A * sin(30 * DEG), 2) + pow(B * cos(30 * DEG), 2));
    for (int c = 0; c < 3; c++) {
        wf_wcs w = tan_wcs(400, 400, cases[c].cd);
        /* at the reference pixel, and 150 pixels off it where north has turned by the meridians'
         * convergence, dRA sin(Dec) = 1.1e-4 rad against the hand values' north at the
         * reference pixel: off the axes (30 deg) that moves the DLR by up to 1.1e-4 of itself */
        const double at[2][2] = {{200.5, 200.5}, {350.5, 120.5}};
        for (int p = 0; p < 2; p++) {
            double cov[3];
            ck_assert_int_eq(wf_hosts_sky_ellipse(&w, at[p][0], at[p][1], A, B, 30.0, cov), WF_OK);
            const double off[4] = {0, 90, 30, -30};
            const double want[4] = {A * s, B * s, general, general};
            for (int k = 0; k < 4; k++) {
                double pa = (cases[c].pa + off[k]) * DEG;
                for (int sign = -1; sign <= 1; sign += 2) { /* both ends of the axis */
                    double r = wf_hosts_dlr(cov, sign * sin(pa), sign * cos(pa));
                    ck_assert_msg(fabs(r - want[k]) < (p ? 2e-4 : 1e-6) * want[k], "%s, pixel (%g, %g), %g deg off the axis: DLR %.9f, "
                                  "want %.9f", cases[c].what, at[p][0], at[p][1], off[k], r, want[k]);
                }
            }
        }
    }
    /* a round galaxy: the same radius every way; no direction: no DLR */
    double cov[3];
    wf_wcs w = tan_wcs(100, 100, cases[0].cd);
    ck_assert_int_eq(wf_hosts_sky_ellipse(&w, 50, 50, 3, 3, 77.0, cov), WF_OK);
    for (int k = 0; k < 8; k++) ck_assert_double_eq_tol(wf_hosts_dlr(cov, cos(k * 0.7), sin(k * 0.7)), 0.33, 1e-7);
    ck_assert(isnan(wf_hosts_dlr(cov, 0, 0)));
}
END_TEST

/* ---- a synthetic scene ------------------------------------------------------------------- */

#define NX 400
#define NY 400
#define SCALE 0.0575

static const double scene_cd[2][2] = {{0, -SCALE}, {SCALE, 0}}; /* +x north, +y west */

typedef struct src {
    long long id;
    double x, y;         /* FITS pixels */
    double a, b, theta;  /* detections only */
    double z;            /* SNe */
    long long host;
} src;

static void sky(const wf_wcs *w, double x, double y, double *ra, double *dec)
{
    ck_assert_int_eq(wf_wcs_pix2world(w, x - 1, y - 1, ra, dec), WF_OK);
}

/* SCI (and WHT, zero in the corner x, y > 380, when wht) with the WCS, or none at all. */
static void write_image(const char *path, const wf_wcs *w, int with_wcs, int wht)
{
    fitsfile *f;
    int status = 0;
    long nax[2] = {NX, NY};
    float *pix = calloc(NX * NY, sizeof *pix);
    remove(path);
    fits_create_file(&f, path, &status);
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_create_img(f, FLOAT_IMG, 2, nax, &status);
    fits_write_key_str(f, "EXTNAME", "SCI", NULL, &status);
    if (with_wcs) ck_assert_int_eq(wf_wcs_write_header(w, f, path), WF_OK);
    fits_write_img(f, TFLOAT, 1, NX * NY, pix, &status);
    if (wht) {
        for (int y = 0; y < NY; y++)
            for (int x = 0; x < NX; x++) pix[y * NX + x] = x + 1 > 380 && y + 1 > 380 ? 0.0f : 3.0f;
        fits_create_img(f, FLOAT_IMG, 2, nax, &status);
        fits_write_key_str(f, "EXTNAME", "WHT", NULL, &status);
        if (with_wcs) ck_assert_int_eq(wf_wcs_write_header(w, f, path), WF_OK);
        fits_write_img(f, TFLOAT, 1, NX * NY, pix, &status);
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    free(pix);
}

/* A `wfisim detect`-like CATALOG (without THETA when no_theta). */
static void write_catalog(const char *path, const wf_wcs *w, const src *d, int n, int no_theta)
{
    char *ttype[] = {"ID", "X", "Y", "RA", "DEC", "A", "B", "THETA"};
    char *tform[] = {"J", "D", "D", "D", "D", "D", "D", "D"};
    fitsfile *f;
    int status = 0;
    remove(path);
    fits_create_file(&f, path, &status);
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_create_tbl(f, BINARY_TBL, 0, no_theta ? 7 : 8, ttype, tform, NULL, "CATALOG", &status);
    fits_write_key_lng(f, "NAXIS1IM", NX, NULL, &status);
    fits_write_key_lng(f, "NAXIS2IM", NY, NULL, &status);
    for (int i = 0; i < n; i++) {
        double ra, dec, v[7];
        long id = i + 1;
        sky(w, d[i].x, d[i].y, &ra, &dec);
        v[0] = d[i].x, v[1] = d[i].y, v[2] = ra, v[3] = dec, v[4] = d[i].a, v[5] = d[i].b, v[6] = d[i].theta;
        fits_write_col(f, TLONG, 1, i + 1, 1, 1, &id, &status);
        for (int k = 0; k < (no_theta ? 6 : 7); k++) fits_write_col(f, TDOUBLE, k + 2, i + 1, 1, 1, &v[k], &status);
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

static void write_table(fitsfile *f, const char *name, const wf_wcs *w, const src *o, int n, int *status)
{
    char *ttype[] = {"ID", "RA", "DEC", "X", "Y", "MAG", "FLUX", "Z", "HOSTID", "PHASE", "FLAGS"};
    char *tform[] = {"1K", "1D", "1D", "1D", "1D", "1E", "1E", "1D", "1K", "1D", "1J"};
    int sne = !strcmp(name, "SNE");
    fits_create_tbl(f, BINARY_TBL, 0, sne ? 11 : 7, ttype, tform, NULL, (char *)name, status);
    for (int i = 0; i < n; i++) {
        double ra, dec, x = o[i].x, y = o[i].y;
        sky(w, x, y, &ra, &dec);
        fits_write_col(f, TLONGLONG, 1, i + 1, 1, 1, (void *)&o[i].id, status);
        fits_write_col(f, TDOUBLE, 2, i + 1, 1, 1, &ra, status);
        fits_write_col(f, TDOUBLE, 3, i + 1, 1, 1, &dec, status);
        fits_write_col(f, TDOUBLE, 4, i + 1, 1, 1, &x, status);
        fits_write_col(f, TDOUBLE, 5, i + 1, 1, 1, &y, status);
        if (sne) {
            fits_write_col(f, TDOUBLE, 8, i + 1, 1, 1, (void *)&o[i].z, status);
            fits_write_col(f, TLONGLONG, 9, i + 1, 1, 1, (void *)&o[i].host, status);
        }
    }
}

static void write_truth(const char *path, const wf_wcs *w, const src *g, int ng, const src *s, int ns, const src *sn,
                        int nsn)
{
    fitsfile *f;
    int status = 0;
    remove(path);
    fits_create_file(&f, path, &status);
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    write_table(f, "GALAXIES", w, g, ng, &status);
    write_table(f, "STARS", w, s, ns, &status);
    write_table(f, "SNE", w, sn, nsn, &status);
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

/* The scene (FITS pixels of a 400 x 400 image of 0.0575" pixels whose +x is north):
 *  - SN 1 (z 0.3) lies on the major axis of its host 101 (A 20, B 4 px, along +x), 50 px
 *    from its centre: d_DLR 2.5. Galaxy 102 (A = B = 2 px) is 20 px from the SN across the
 *    axis: nearer (1.15") but d_DLR 10. The SN itself is detected too (one-to-one with its
 *    truth, so not a candidate). DLR correct, nearest wrong.
 *  - SN 4 (z 0.1) is 4 px from its host 104 (A 3, B 2); a star's detection sits 2 px from the
 *    SN (0.26" from the galaxy's centre: the galaxy keeps its own detection). Both correct.
 *  - SN 2 (z 0.6): its host 103 is in the truth but not detected; galaxy 105 is 30 px off.
 *  - SN 3 (z 0.9): hostless, nothing within 5". SN 7 (z 1.2): its host 106 is off the image.
 *  - SN 5 is off the image and SN 6 on pixels no input covered (WHT 0): left out. */
static const src dets[] = {
    {0, 200, 200, 20, 4, 0, 0, 0},   /* 101 */
    {0, 250, 220, 2, 2, 0, 0, 0},    /* 102 */
    {0, 250, 200, 1.2, 1.2, 0, 0, 0}, /* SN 1 itself */
    {0, 100, 300, 3, 2, 45, 0, 0},   /* 104 */
    {0, 104, 302, 1.1, 1.0, 0, 0, 0}, /* star 201 */
    {0, 300, 130, 3, 3, 0, 0, 0},    /* 105 */
};
static const src gal_a[] = {{101, 200, 200, 0, 0, 0, 0, 0}, {102, 250, 220, 0, 0, 0, 0, 0},
                            {103, 300, 100, 0, 0, 0, 0, 0}, {104, 100, 300, 0, 0, 0, 0, 0}};
static const src gal_b[] = {{101, 200, 200, 0, 0, 0, 0, 0}, {104, 100, 300, 0, 0, 0, 0, 0},
                            {105, 300, 130, 0, 0, 0, 0, 0}, {106, 430, 100, 0, 0, 0, 0, 0}};
static const src stars[] = {{201, 104, 302, 0, 0, 0, 0, 0}};
static const src sne_a[] = {{1, 250, 200, 0, 0, 0, 0.3, 101}, {2, 303, 100, 0, 0, 0, 0.6, 103},
                            {3, 50, 50, 0, 0, 0, 0.9, -1},     {4, 104, 300, 0, 0, 0, 0.1, 104},
                            {5, -100, 200, 0, 0, 0, 0.4, 101}};
static const src sne_b[] = {{1, 250, 200, 0, 0, 0, 0.3, 101}, {3, 50, 50, 0, 0, 0, 0.9, -1},
                            {6, 390, 390, 0, 0, 0, 0.2, 104}, {7, 395, 100, 0, 0, 0, 1.2, 106}};

typedef struct scene {
    char dir[4096], img[4200], cat[4200], ta[4200], tb[4200], list[4200], out[4200];
    wf_wcs w;
} scene;

static void make_scene(scene *sc)
{
    snprintf(sc->dir, sizeof sc->dir, "%s", wf_test_tmpdir());
    snprintf(sc->img, sizeof sc->img, "%s/coadd.fits", sc->dir);
    snprintf(sc->cat, sizeof sc->cat, "%s/coadd_cat.fits", sc->dir);
    snprintf(sc->ta, sizeof sc->ta, "%s/a_truth.fits", sc->dir);
    snprintf(sc->tb, sizeof sc->tb, "%s/b_truth.fits", sc->dir);
    snprintf(sc->list, sizeof sc->list, "%s/list.txt", sc->dir);
    snprintf(sc->out, sizeof sc->out, "%s/out", sc->dir);
    sc->w = tan_wcs(NX, NY, scene_cd);
    write_image(sc->img, &sc->w, 1, 1);
    write_catalog(sc->cat, &sc->w, dets, 6, 0);
    write_truth(sc->ta, &sc->w, gal_a, 4, stars, 1, sne_a, 5);
    write_truth(sc->tb, &sc->w, gal_b, 4, NULL, 0, sne_b, 4);
    char text[40000];
    snprintf(text, sizeof text, "# one coadd\n\n%s %s %s,%s   # its inputs' truths\n", sc->img, sc->cat, sc->ta, sc->tb);
    write_text(sc->list, text);
}

static double json(const char *text, const char *key)
{
    const char *keys[1] = {key};
    double v = wf_test_json_number(text, keys, 1);
    ck_assert_msg(isfinite(v), "hosts_summary.json has no key %s", key);
    return v;
}

/* The CSV row of SN id (its text after "id,"), NULL when absent. */
static const char *csv_row(const char *text, long id, char *buf, size_t cap)
{
    char key[32];
    snprintf(key, sizeof key, "\n%ld,", id);
    const char *p = strstr(text, key);
    if (!p) return NULL;
    p++;
    const char *e = strchr(p, '\n');
    size_t n = e ? (size_t)(e - p) : strlen(p);
    if (n >= cap) n = cap - 1;
    memcpy(buf, p, n);
    buf[n] = 0;
    return buf;
}

/* Field k (0-based) of a CSV row. */
static void field(const char *row, int k, char *out, size_t cap)
{
    const char *p = row;
    for (int i = 0; i < k && p; i++) p = strchr(p, ',') ? strchr(p, ',') + 1 : NULL;
    ck_assert_ptr_nonnull(p);
    size_t n = strcspn(p, ",");
    if (n >= cap) n = cap - 1;
    memcpy(out, p, n);
    out[n] = 0;
}

START_TEST(synthetic_scene)
{
    scene sc;
    make_scene(&sc);
    wf_hosts_options o;
    wf_hosts_defaults(&o);
    o.quiet = 1;
    wf_hosts_summary s;
    ck_assert_msg(wf_hosts_run(sc.list, sc.out, &o, &s) == WF_OK, "%s", wf_error_message());

    char path[4300];
    snprintf(path, sizeof path, "%s/hosts_summary.json", sc.out);
    char *js = wf_test_slurp(path, NULL);
    ck_assert_ptr_nonnull(js);
    ck_assert_int_eq(json(js, "sne_total"), 5);          /* 1, 2, 3, 4, 7 */
    ck_assert_int_eq(json(js, "hosts_total"), 3);        /* 1, 2, 4 */
    ck_assert_int_eq(json(js, "hosts_correct"), 2);      /* DLR: 1, 4 */
    ck_assert_int_eq(json(js, "hosts_dlr_wrong"), 0);
    ck_assert_int_eq(json(js, "hosts_nearest_correct"), 1); /* 4 */
    ck_assert_int_eq(json(js, "hosts_nearest_wrong"), 1);   /* 1 */
    ck_assert_int_eq(json(js, "hosts_undetected"), 1);      /* 2 */
    ck_assert_int_eq(json(js, "hosts_detected"), 2);
    ck_assert_int_eq(json(js, "hosts_outside"), 1);         /* 7 */
    ck_assert_int_eq(json(js, "sne_hostless"), 1);          /* 3 */
    ck_assert_int_eq(json(js, "hostless_dlr_chosen"), 0);
    ck_assert_int_eq(json(js, "hostless_nearest_chosen"), 0);
    ck_assert_int_eq(json(js, "galaxies_matched"), 4);      /* 101, 102, 104, 105 */
    ck_assert_int_eq(json(js, "detections_excluded"), 2);   /* the star and SN 1 */
    ck_assert_int_eq(json(js, "detections"), 6);
    ck_assert_int_eq(json(js, "images"), 1);
    ck_assert_double_eq(json(js, "dlr_max"), 4);
    free(js);

    snprintf(path, sizeof path, "%s/hosts.csv", sc.out);
    char *csv = wf_test_slurp(path, NULL);
    ck_assert_ptr_nonnull(csv);
    ck_assert_ptr_null(csv_row(csv, 5, (char[8]){0}, 8)); /* off the image */
    ck_assert_ptr_null(csv_row(csv, 6, (char[8]){0}, 8)); /* no coverage */
    char row[1024], v[64];
    /* columns: 0 sn_id 1 z 2 ra 3 dec 4 line 5 true_host_id 6 host_det_id 7 host_sep 8 host_d_dlr
     * 9 dlr_det_id 10 dlr_galaxy_id 11 dlr_sep 12 dlr_d_dlr 13 dlr_outcome 14 nearest_det_id
     * 15 nearest_galaxy_id 16 nearest_sep 17 nearest_d_dlr 18 nearest_outcome */
    ck_assert_ptr_nonnull(csv_row(csv, 1, row, sizeof row));
    field(row, 5, v, sizeof v); ck_assert_str_eq(v, "101");
    field(row, 10, v, sizeof v); ck_assert_str_eq(v, "101");
    field(row, 12, v, sizeof v); ck_assert_double_eq_tol(atof(v), 2.5, 2e-4); /* 50 px / A = 20 px */
    field(row, 13, v, sizeof v); ck_assert_str_eq(v, "correct");
    field(row, 15, v, sizeof v); ck_assert_str_eq(v, "102");
    field(row, 16, v, sizeof v); ck_assert_double_eq_tol(atof(v), 20 * SCALE, 2e-4);
    field(row, 17, v, sizeof v); ck_assert_double_eq_tol(atof(v), 10.0, 2e-3); /* 20 px / 2 px */
    field(row, 18, v, sizeof v); ck_assert_str_eq(v, "wrong");
    field(row, 7, v, sizeof v); ck_assert_double_eq_tol(atof(v), 50 * SCALE, 2e-4);
    ck_assert_ptr_nonnull(csv_row(csv, 4, row, sizeof row));
    field(row, 13, v, sizeof v); ck_assert_str_eq(v, "correct");
    field(row, 18, v, sizeof v); ck_assert_str_eq(v, "correct");
    /* 4 px from galaxy 104 at 45 deg to its axes (A 3, B 2): DLR = 6 / sqrt(4.5 + 2) px */
    field(row, 12, v, sizeof v); ck_assert_double_eq_tol(atof(v), 4.0 / (6.0 / sqrt(6.5)), 2e-4);
    ck_assert_ptr_nonnull(csv_row(csv, 2, row, sizeof row));
    field(row, 6, v, sizeof v); ck_assert_str_eq(v, "");
    field(row, 13, v, sizeof v); ck_assert_str_eq(v, "undetected");
    field(row, 15, v, sizeof v); ck_assert_str_eq(v, "105"); /* 30 px: the nearest rule took it */
    field(row, 9, v, sizeof v); ck_assert_str_eq(v, "");     /* d_DLR 10: the DLR rule did not */
    ck_assert_ptr_nonnull(csv_row(csv, 3, row, sizeof row));
    field(row, 13, v, sizeof v); ck_assert_str_eq(v, "hostless_none");
    ck_assert_ptr_nonnull(csv_row(csv, 7, row, sizeof row));
    field(row, 13, v, sizeof v); ck_assert_str_eq(v, "host_outside");
    free(csv);

    snprintf(path, sizeof path, "%s/hosts_by_z.csv", sc.out);
    char *byz = wf_test_slurp(path, NULL);
    ck_assert_ptr_nonnull(byz);
    /* z_lo,z_hi,hosts,dlr_correct,dlr_wrong,nearest_correct,nearest_wrong,undetected,5 fractions,hostless */
    ck_assert_ptr_nonnull(strstr(byz, "\n0.0000,0.2500,1,1,0,1,0,0,1.000000,0.000000,1.000000,0.000000,0.000000,0\n"));
    ck_assert_ptr_nonnull(strstr(byz, "\n0.2500,0.5000,1,1,0,0,1,0,1.000000,0.000000,0.000000,1.000000,0.000000,0\n"));
    ck_assert_ptr_nonnull(strstr(byz, "\n0.5000,0.7500,1,0,0,0,0,1,0.000000,0.000000,0.000000,0.000000,1.000000,0\n"));
    ck_assert_ptr_nonnull(strstr(byz, "\n0.7500,1.0000,0,0,0,0,0,0,,,,,,1\n"));
    ck_assert_ptr_nonnull(strstr(byz, "\n1.0000,1.2500,0,0,0,0,0,0,,,,,,0\n"));
    free(byz);
    snprintf(path, sizeof path, "%s/hosts.png", sc.out);
    ck_assert_int_eq(wf_test_run("head -c 8 %s | od -An -tx1 | grep -q '89 50 4e 47 0d 0a 1a 0a'", path), 0);

    /* the same image listed twice: each SN once */
    char text[40000];
    snprintf(text, sizeof text, "%s %s %s\n%s %s %s,%s\n", sc.img, sc.cat, sc.ta, sc.img, sc.cat, sc.ta, sc.tb);
    write_text(sc.list, text);
    ck_assert_msg(wf_hosts_run(sc.list, sc.out, &o, &s) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(s.images, 2);
    ck_assert_int_eq(s.sne, 5);
    ck_assert_int_eq(s.duplicates, 4); /* 1, 2, 3, 4 in both lines */
    ck_assert_int_eq(s.total, 3);

    /* --dlr-max 2: SN 1 (d_DLR 2.5) gets no host by DLR; --sep-max 1: SN 1 none by nearest */
    o.dlr_max = 2, o.sep_max = 1;
    ck_assert_msg(wf_hosts_run(sc.list, sc.out, &o, &s) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(s.dlr_correct, 1);
    ck_assert_int_eq(s.dlr_wrong, 1);
    ck_assert_int_eq(s.dlr_none, 1);
    ck_assert_int_eq(s.nearest_none, 1);

    const char *bin = wf_test_program();
    if (bin) { /* the command: the interface make paper calls */
        ck_assert_int_eq(wf_test_run("%s hosts --quiet --out %s/cmd --radius 0.3 --dlr-max 4 --sep-max 5 --zbin 0.25 %s",
                                     bin, sc.dir, sc.list), 0);
        ck_assert_int_eq(wf_test_run("grep -q '\"hosts_correct\": 2,' %s/cmd/hosts_summary.json", sc.dir), 0);
        ck_assert_int_eq(wf_test_run("%s hosts --out %s/cmd --zbin -1 %s 2>/dev/null", bin, sc.dir, sc.list), 2);
    }
}
END_TEST

/* ---- bad input --------------------------------------------------------------------------- */

static void refused(const scene *sc, const char *list_text, const char *want1, const char *want2)
{
    write_text(sc->list, list_text);
    wf_hosts_options o;
    wf_hosts_defaults(&o);
    o.quiet = 1;
    char out[4300];
    snprintf(out, sizeof out, "%s/refused", sc->dir);
    wf_status st = wf_hosts_run(sc->list, out, &o, NULL);
    ck_assert_msg(st == WF_ERR_INPUT, "status %d (%s)", st, wf_error_message());
    ck_assert_msg(strstr(wf_error_message(), want1) && strstr(wf_error_message(), want2),
                  "message '%s' should name '%s' and say '%s'", wf_error_message(), want1, want2);
    ck_assert_int_ne(access(out, F_OK), 0); /* nothing written, not even the folder */
    const char *bin = wf_test_program();
    if (bin) ck_assert_int_eq(wf_test_run("%s hosts --out %s %s 2>/dev/null", bin, out, sc->list), 2);
    ck_assert_int_ne(access(out, F_OK), 0);
}

START_TEST(bad_input)
{
    scene sc;
    make_scene(&sc);
    char text[40000], other[4300], nowcs[4300], empty[4300];
    /* a catalog without THETA */
    snprintf(other, sizeof other, "%s/nothetacat.fits", sc.dir);
    write_catalog(other, &sc.w, dets, 6, 1);
    snprintf(text, sizeof text, "%s %s %s\n", sc.img, other, sc.ta);
    refused(&sc, text, other, "no column THETA");
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "list.txt:1:"));
    /* an image without a WCS */
    snprintf(nowcs, sizeof nowcs, "%s/nowcs.fits", sc.dir);
    write_image(nowcs, &sc.w, 0, 0);
    snprintf(text, sizeof text, "# a comment\n\n%s %s %s\n", nowcs, sc.cat, sc.ta);
    refused(&sc, text, "list.txt:3:", "no WCS");
    /* a missing truth file, on the second line */
    snprintf(text, sizeof text, "%s %s %s\n%s %s %s,%s/missing_truth.fits\n", sc.img, sc.cat, sc.ta, sc.img, sc.cat, sc.ta,
             sc.dir);
    refused(&sc, text, "list.txt:2:", "missing_truth.fits: cannot open");
    /* truth files whose SNE tables are empty */
    snprintf(empty, sizeof empty, "%s/nosne_truth.fits", sc.dir);
    write_truth(empty, &sc.w, gal_a, 4, stars, 1, NULL, 0);
    snprintf(text, sizeof text, "%s %s %s\n", sc.img, sc.cat, empty);
    refused(&sc, text, "list.txt:1:", "SNE tables");
    /* a line without its truth */
    snprintf(text, sizeof text, "%s %s\n", sc.img, sc.cat);
    refused(&sc, text, "list.txt:1:", "IMAGE DETCAT TRUTH");
    /* a catalog of another image */
    snprintf(text, sizeof text, "%s %s %s\n", sc.img, sc.ta, sc.ta);
    refused(&sc, text, "a_truth.fits", "no CATALOG table");
    refused(&sc, "# nothing\n", "list.txt", "no image listed");
}
END_TEST


/* ---- end to end on a real product -------------------------------------------------------- */

/* HOSTOFF (arcsec from the host's centre) of every SN of the sample, by ID. */
static int sample_offsets(const char *path, long long *id, double *off, int max)
{
    fitsfile *f;
    int status = 0, ci, co;
    long n = 0;
    fits_open_file(&f, path, READONLY, &status);
    fits_movnam_hdu(f, BINARY_TBL, "SNE", 0, &status);
    fits_get_num_rows(f, &n, &status);
    ck_assert_int_le(n, max);
    fits_get_colnum(f, CASEINSEN, "ID", &ci, &status);
    fits_get_colnum(f, CASEINSEN, "HOSTOFF", &co, &status);
    fits_read_col(f, TLONGLONG, ci, 1, 1, n, NULL, id, NULL, &status);
    fits_read_col(f, TDOUBLE, co, 1, 1, n, NULL, off, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    return (int)n;
}

/* A 512 x 512 corner of SCA 1 of the plan's first exposure, rendered with SNe whose hosts are
 * the synthetic field's galaxies the run draws (the sample's rate raised 600-fold over a
 * 25" circle so that ~100 fall on it), detected by `wfisim detect`, and associated. Checked
 * against what the pipeline does not compute: each detected host's separation from its SN
 * equals the sample's HOSTOFF (the SN's offset from its host's true centre) to within the
 * matching radius; the counts add up; and each rule's choice is at least as good, by its own
 * measure, as the true host's detection. */
START_TEST(end_to_end)
{
    const char *bin = wf_test_program(), *data = wf_test_data_dir();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    WF_SKIP_UNLESS(data, "the Roman and SALT data");
    const char *d = wf_test_tmpdir();
    char plan[4200], sne[4200], list[9000];
    snprintf(plan, sizeof plan, "%s/plan.fits", d);
    snprintf(sne, sizeof sne, "%s/sne.fits", d);
    ck_assert_int_eq(wf_test_run("%s survey plan --quiet --data %s --set survey.visits=1 --out %s", bin, data, plan), 0);
    double ra, dec, pa, mjd, rc, dc;
    wf_test_plan_row0(plan, &ra, &dec, &pa, &mjd);
    wf_focal_plane fp;
    wf_wcs w;
    ck_assert_int_eq(wf_wcs_focal_plane(data, &fp), 0);
    ck_assert_int_eq(wf_wcs_for_sca(&fp, ra, dec, pa, 1, &w), 0);
    ck_assert_int_eq(wf_wcs_pix2world(&w, 255.5, 255.5, &rc, &dc), 0);
    const double r_deg = 25.0 / 3600.0;
    ck_assert_int_eq(wf_test_run("%s sn generate --data %s --model %s/salt3/salt3-k21 --seed 1 --area %.10g --start %.6f "
                                 "--days 200 --ra %.10f --dec %.10f --rate '1.5e-2 1.5 0.06 2.99' --out %s >/dev/null",
                                 bin, data, data, M_PI * r_deg * r_deg, mjd - 150, rc, dc, sne), 0);
    ck_assert_int_eq(wf_test_run("%s survey run --quiet --seed 1 --data %s --plan %s --exposures 0 --scas 1 --sne %s --model "
                                 "%s/salt3/salt3-k21 --set readout.ncols=512 --set readout.nrows=512 --out %s/run",
                                 bin, data, plan, sne, data, d), 0);
    char img[4300], cat[4300];
    snprintf(img, sizeof img, "%s/run/wfisim_e000000_sca01.fits", d);
    snprintf(cat, sizeof cat, "%s/cat.fits", d);
    wf_detect_options dop;
    wf_detect_summary dsum;
    wf_detect_defaults(&dop);
    snprintf(dop.data_dir, sizeof dop.data_dir, "%s", data);
    ck_assert_msg(wf_detect_file(img, cat, &dop, &dsum) == WF_OK, "%s", wf_error_message());
    /* The catalog's own convention: the point A pixels along THETA from a detection lies on
     * its ellipse, so it lands on the sky ellipse here, in the direction `wfisim detect` gives
     * as PA_SKY (a step along THETA through the WCS), at the distance the WCS puts it.
     * (The sky ellipse's own major axis differs from PA_SKY where Roman's pixels are not
     * square: printed, not asserted.) */
    {
        fitsfile *f;
        int status = 0, col;
        long n = 0;
        fits_open_file(&f, img, READONLY, &status);
        fits_movnam_hdu(f, IMAGE_HDU, "SCI", 0, &status);
        wf_wcs pw;
        ck_assert_int_eq(wf_wcs_read_header(f, img, &pw), WF_OK);
        fits_close_file(f, &status);
        fits_open_table(&f, cat, READONLY, &status);
        fits_get_num_rows(f, &n, &status);
        ck_assert_int_eq(status, 0);
        const char *names[6] = {"X", "Y", "A", "B", "THETA", "PA_SKY"};
        double *c[6];
        for (int k = 0; k < 6; k++) {
            c[k] = malloc((size_t)n * sizeof(double));
            fits_get_colnum(f, CASEINSEN, (char *)names[k], &col, &status);
            fits_read_col(f, TDOUBLE, col, 1, 1, n, NULL, c[k], NULL, &status);
        }
        fits_close_file(f, &status);
        ck_assert_int_eq(status, 0);
        int tested = 0;
        double worst = 0, worst_axis = 0;
        for (long i = 0; i < n; i++) {
            if (!(c[3][i] > 0) || c[2][i] < 1.3 * c[3][i]) continue;
            double cov[3], r0, d0, r1, d1, x = c[0][i] - 1, y = c[1][i] - 1, a = c[2][i], th = c[4][i] * DEG;
            ck_assert_int_eq(wf_hosts_sky_ellipse(&pw, c[0][i], c[1][i], a, c[3][i], c[4][i], cov), WF_OK);
            ck_assert_int_eq(wf_wcs_pix2world(&pw, x, y, &r0, &d0), 0);
            ck_assert_int_eq(wf_wcs_pix2world(&pw, x + a * cos(th), y + a * sin(th), &r1, &d1), 0);
            double want = wf_wcs_separation(r0, d0, r1, d1) * 3600.0, pa_sky = c[5][i] * DEG;
            double got = wf_hosts_dlr(cov, sin(pa_sky), cos(pa_sky));
            ck_assert_msg(fabs(got / want - 1) < 1e-5, "detection %ld: DLR along PA_SKY %.5f\", the WCS puts A along "
                          "THETA at %.5f\"", i + 1, got, want);
            worst = fmax(worst, fabs(got / want - 1));
            double alpha = 0.5 * atan2(2 * cov[1], cov[0] - cov[2]) / DEG; /* from east towards north */
            worst_axis = fmax(worst_axis, fabs(remainder(90.0 - alpha - c[5][i], 180.0)));
            tested++;
        }
        printf("end_to_end: %d elongated detections: DLR along PA_SKY = the WCS's length of A along THETA to %.1e; "
               "the sky ellipse's major axis within %.2f deg of PA_SKY\n", tested, worst, worst_axis);
        ck_assert_int_gt(tested, 10);
        for (int k = 0; k < 6; k++) free(c[k]);
    }
    snprintf(list, sizeof list, "%s/list.txt", d);
    char text[20000];
    snprintf(text, sizeof text, "%s/run/wfisim_e000000_sca01.fits %s/cat.fits %s/run/wfisim_e000000_sca01_truth.fits\n", d,
             d, d);
    write_text(list, text);
    wf_hosts_options o;
    wf_hosts_defaults(&o);
    o.quiet = 1;
    wf_hosts_summary s;
    char out[4200];
    snprintf(out, sizeof out, "%s/hosts", d);
    ck_assert_msg(wf_hosts_run(list, out, &o, &s) == WF_OK, "%s", wf_error_message());
    printf("end_to_end: %ld SNe, %ld with a host in the image, %ld hostless, %ld host outside; DLR %ld correct "
           "%ld wrong, nearest %ld correct %ld wrong, %ld undetected; %ld detections, %ld galaxies matched\n",
           s.sne, s.total, s.hostless, s.host_outside, s.dlr_correct, s.dlr_wrong, s.nearest_correct, s.nearest_wrong,
           s.undetected, s.detections, s.galaxies_matched);
    ck_assert_int_ge(s.total, 20);
    ck_assert_int_eq(s.total + s.hostless + s.host_outside, s.sne);
    ck_assert_int_eq(s.dlr_correct + s.dlr_wrong + s.undetected, s.total);
    ck_assert_int_eq(s.nearest_correct + s.nearest_wrong + s.undetected, s.total);
    ck_assert_int_gt(s.total - s.undetected, 5);

    static long long ids[20000];
    static double offs[20000];
    int nsample = sample_offsets(sne, ids, offs, 20000);
    char path[4300];
    snprintf(path, sizeof path, "%s/hosts.csv", out);
    FILE *f = fopen(path, "r");
    ck_assert_ptr_nonnull(f);
    char line[2048];
    int checked = 0;
    ck_assert_ptr_nonnull(fgets(line, sizeof line, f)); /* header */
    while (fgets(line, sizeof line, f)) {
        char v[19][64];
        for (int k = 0; k < 19; k++) field(line, k, v[k], sizeof v[k]);
        v[18][strcspn(v[18], "\n")] = 0;
        if (!v[6][0]) continue; /* host not detected, outside, or hostless */
        long long sn = atoll(v[0]);
        double off = NAN;
        for (int i = 0; i < nsample; i++)
            if (ids[i] == sn) off = offs[i];
        ck_assert_msg(fabs(atof(v[7]) - off) <= o.radius, "SN %lld: host detection %s\" away, HOSTOFF %g\"", sn, v[7], off);
        /* the rules' choices are the best by their own measure */
        if (v[14][0]) ck_assert_double_le(atof(v[16]), atof(v[7]) + 1e-4);
        if (v[8][0] && atof(v[8]) <= o.dlr_max) {
            ck_assert_msg(v[9][0], "SN %lld: its host has d_DLR %s but the DLR rule chose none", sn, v[8]);
            ck_assert_double_le(atof(v[12]), atof(v[8]) + 1e-4);
        }
        if (!strcmp(v[18], "correct")) ck_assert_str_eq(v[14], v[6]);
        checked++;
    }
    fclose(f);
    ck_assert_int_eq(checked, s.total - s.undetected);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("hosts");
    TCase *tc = tcase_create("all");
    tcase_set_timeout(tc, 300);
    tcase_add_test(tc, dlr_by_hand);
    tcase_add_test(tc, synthetic_scene);
    tcase_add_test(tc, bad_input);
    tcase_add_test(tc, end_to_end);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
