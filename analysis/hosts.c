/* `wfisim hosts`: supernova host association against the truth (analysis/hosts.h,
 * docs/ANALYSIS.md "wfisim hosts"). Reading and association here; the files written are in
 * analysis/hostsout.c. */
#include "analysis/hosts.h"

#include <errno.h>
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "analysis/hosts_int.h"
#include "sim/fits/fitsout.h"

#define DEG (M_PI / 180.0)
#define ARCSEC (DEG / 3600.0)

void wf_hosts_defaults(wf_hosts_options *o)
{
    o->radius = 0.3;
    o->dlr_max = 4.0;
    o->sep_max = 5.0;
    o->zbin = 0.25;
    o->quiet = 0;
}

/* ---- geometry ---------------------------------------------------------------------------- */

wf_status wf_hosts_sky_ellipse(const wf_wcs *w, double x, double y, double a, double b, double theta_deg,
                               double cov[3])
{
    /* The local Jacobian (pixel -> east, north arcsec on the tangent plane at the centre),
     * by central differences of half a pixel: exact for TAN, and for SIP the polynomial's
     * curvature over a pixel is ~1e-7 of the scale. */
    const double h = 0.5;
    double x0 = x - 1.0, y0 = y - 1.0, ra0, dec0, p[4][2];
    wf_status st = wf_wcs_pix2world(w, x0, y0, &ra0, &dec0);
    const double step[4][2] = {{h, 0}, {-h, 0}, {0, h}, {0, -h}};
    for (int k = 0; !st && k < 4; k++) {
        double ra, dec;
        st = wf_wcs_pix2world(w, x0 + step[k][0], y0 + step[k][1], &ra, &dec);
        if (!st) st = wf_wcs_tangent_project(ra0 * DEG, dec0 * DEG, ra * DEG, dec * DEG, &p[k][0], &p[k][1]);
    }
    if (st) return st;
    double j[2][2]; /* j[row: east, north][column: x, y] */
    for (int r = 0; r < 2; r++) {
        j[r][0] = (p[0][r] - p[1][r]) / (2 * h) / ARCSEC;
        j[r][1] = (p[2][r] - p[3][r]) / (2 * h) / ARCSEC;
    }
    double c = cos(theta_deg * DEG), s = sin(theta_deg * DEG), a2 = a * a, b2 = b * b;
    double m[2][2] = {{a2 * c * c + b2 * s * s, (a2 - b2) * c * s}, {(a2 - b2) * c * s, a2 * s * s + b2 * c * c}};
    double t[2][2]; /* j m */
    for (int r = 0; r < 2; r++)
        for (int q = 0; q < 2; q++) t[r][q] = j[r][0] * m[0][q] + j[r][1] * m[1][q];
    cov[0] = t[0][0] * j[0][0] + t[0][1] * j[0][1];
    cov[1] = t[0][0] * j[1][0] + t[0][1] * j[1][1];
    cov[2] = t[1][0] * j[1][0] + t[1][1] * j[1][1];
    return WF_OK;
}

double wf_hosts_dlr(const double cov[3], double east, double north)
{
    double det = cov[0] * cov[2] - cov[1] * cov[1], r2 = east * east + north * north;
    if (!(det > 0) || !(r2 > 0)) return NAN;
    /* u' C^-1 u with u the unit vector towards the SN; the radius is its inverse square root. */
    double q = (east * east * cov[2] - 2 * east * north * cov[1] + north * north * cov[0]) / det;
    return sqrt(r2 / q);
}

/* ---- inputs ------------------------------------------------------------------------------ */

static wf_status need_file(const char *path)
{
    if (access(path, R_OK) != 0) return wf_error(WF_ERR_INPUT, "%s: cannot open: %s", path, strerror(errno));
    return WF_OK;
}

static void image_close(hosts_image *im)
{
    int status = 0;
    if (im->wht) fits_close_file(im->wht, &status);
    im->wht = NULL;
}

/* SCI's size and WCS; the coadd's WHT stays open to tell covered pixels. */
static wf_status image_open(const char *path, hosts_image *im)
{
    memset(im, 0, sizeof *im);
    im->path = path;
    wf_status st = need_file(path);
    if (st) return st;
    fitsfile *f = NULL;
    int status = 0, naxis = 0;
    if (fits_open_file(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening the image");
    if (fits_movnam_hdu(f, IMAGE_HDU, "SCI", 0, &status)) {
        status = 0;
        fits_clear_errmsg();
        if (fits_movabs_hdu(f, 1, NULL, &status) || fits_get_img_dim(f, &naxis, &status) || naxis != 2)
            st = wf_error(WF_ERR_INPUT, "%s: no SCI HDU and the primary HDU is not a 2-d image", path);
    }
    long nax[2] = {0, 0};
    if (!st && fits_get_img_size(f, 2, nax, &status)) st = wf_fits_error(status, path, "reading SCI's size");
    if (!st && (nax[0] < 1 || nax[1] < 1)) st = wf_error(WF_ERR_INPUT, "%s: SCI is %ld x %ld pixels", path, nax[0], nax[1]);
    if (!st) st = wf_wcs_read_header(f, path, &im->wcs);
    if (!st) {
        im->nx = (int)nax[0], im->ny = (int)nax[1];
        /* the CD matrix's singular values, arcsec per pixel */
        double (*cd)[2] = im->wcs.cd;
        double p = cd[0][0] * cd[0][0] + cd[1][0] * cd[1][0], q = cd[0][1] * cd[0][1] + cd[1][1] * cd[1][1];
        double r = cd[0][0] * cd[0][1] + cd[1][0] * cd[1][1], d = sqrt(0.25 * (p - q) * (p - q) + r * r);
        im->scale_min = sqrt(fmax(0.5 * (p + q) - d, 0)) * 3600.0;
        im->scale_max = sqrt(0.5 * (p + q) + d) * 3600.0;
        if (!(im->scale_min > 0)) st = wf_error(WF_ERR_INPUT, "%s: singular CD matrix", path);
    }
    if (!st) st = wf_wcs_pix2world(&im->wcs, 0.5 * (im->nx - 1), 0.5 * (im->ny - 1), &im->ra_c, &im->dec_c);
    im->radius_deg = 0.5 * hypot(im->nx, im->ny) * im->scale_max * 1.2 / 3600.0;
    if (!st && !fits_movnam_hdu(f, IMAGE_HDU, "WHT", 0, &status)) {
        im->wht = f;
        return WF_OK;
    }
    fits_clear_errmsg();
    status = 0;
    fits_close_file(f, &status);
    return st;
}

/* FITS 1-based pixel of (ra, dec) in the image; nonzero when it is far off it. */
static int image_pixel(const hosts_image *im, double ra, double dec, double *x, double *y)
{
    if (wf_wcs_separation(ra, dec, im->ra_c, im->dec_c) > im->radius_deg) return 1;
    if (wf_wcs_world2pix(&im->wcs, ra, dec, x, y)) {
        fits_clear_errmsg();
        return 1;
    }
    *x += 1.0, *y += 1.0;
    return 0;
}

/* Inside SCI and, for a coadd, on a pixel some input covered (WHT > 0). */
static int image_covers(hosts_image *im, double x, double y)
{
    if (!(x >= 0.5 && x < im->nx + 0.5 && y >= 0.5 && y < im->ny + 0.5)) return 0;
    if (!im->wht) return 1;
    long px[2] = {lround(x), lround(y)};
    if (px[0] > im->nx) px[0] = im->nx;
    if (px[1] > im->ny) px[1] = im->ny;
    float v = 0;
    int status = 0, anynul = 0;
    fits_read_pix(im->wht, TFLOAT, px, 1, NULL, &v, &anynul, &status);
    if (status) {
        fits_clear_errmsg();
        return 0;
    }
    return v > 0;
}

static double edge_distance(const hosts_image *im, double x, double y)
{
    double d = fmin(fmin(x - 0.5, im->nx + 0.5 - x), fmin(y - 0.5, im->ny + 0.5 - y));
    return d * im->scale_min;
}

static int column(fitsfile *f, const char *name, int *col)
{
    int status = 0;
    fits_get_colnum(f, CASEINSEN, (char *)name, col, &status);
    if (status) fits_clear_errmsg();
    return status == 0;
}

/* Column `name` of table `hdu` (rows 1..n) as cfitsio type `type` (TDOUBLE, TLONGLONG). */
static wf_status read_column(fitsfile *f, const char *path, const char *hdu, const char *name, int type, long n,
                             void *out)
{
    int col, status = 0;
    if (!column(f, name, &col)) return wf_error(WF_ERR_INPUT, "%s: %s: no column %s", path, hdu, name);
    if (n > 0 && fits_read_col(f, type, col, 1, 1, n, NULL, out, NULL, &status)) {
        char what[128];
        snprintf(what, sizeof what, "reading %s.%s", hdu, name);
        return wf_fits_error(status, path, what);
    }
    return WF_OK;
}

static wf_status objv_push(hosts_objv *v, const hosts_obj *o)
{
    if (v->n == v->cap) {
        size_t nc = v->cap ? 2 * v->cap : 1024;
        hosts_obj *p = realloc(v->v, nc * sizeof *p);
        if (!p) return wf_error(WF_ERR_NOMEM, "hosts: out of memory for %zu truth rows", nc);
        v->v = p, v->cap = nc;
    }
    v->v[v->n++] = *o;
    return WF_OK;
}

static int by_id(const void *a, const void *b)
{
    const hosts_obj *p = a, *q = b;
    return (p->id > q->id) - (p->id < q->id);
}

/* Sorted by ID, one row per ID (a coadd's inputs list the same objects). */
static void objv_unique(hosts_objv *v)
{
    if (!v->n) return;
    qsort(v->v, v->n, sizeof *v->v, by_id);
    size_t k = 1;
    for (size_t i = 1; i < v->n; i++)
        if (v->v[i].id != v->v[k - 1].id) v->v[k++] = v->v[i];
    v->n = k;
    v->unique = k;
}

/* One truth table's rows near the image (within margin pixels of SCI) appended to v. */
static wf_status read_truth_table(fitsfile *f, const char *path, const char *hdu, hosts_image *im, double margin,
                                  hosts_objv *v, long *nrows_out)
{
    int status = 0;
    long n = 0;
    if (fits_movnam_hdu(f, BINARY_TBL, (char *)hdu, 0, &status)) {
        fits_clear_errmsg();
        return wf_error(WF_ERR_INPUT, "%s: no %s table: not a wfisim truth file", path, hdu);
    }
    if (fits_get_num_rows(f, &n, &status)) return wf_fits_error(status, path, "reading the row count");
    *nrows_out = n;
    int sne = !strcmp(hdu, "SNE");
    size_t m = n > 0 ? (size_t)n : 1;
    long long *id = malloc(m * sizeof *id), *host = sne ? malloc(m * sizeof *host) : NULL;
    double *ra = malloc(m * sizeof *ra), *dec = malloc(m * sizeof *dec), *z = sne ? malloc(m * sizeof *z) : NULL;
    wf_status st = id && ra && dec && (!sne || (host && z)) ? WF_OK : wf_error(WF_ERR_NOMEM, "%s: out of memory", path);
    if (!st) st = read_column(f, path, hdu, "ID", TLONGLONG, n, id);
    if (!st) st = read_column(f, path, hdu, "RA", TDOUBLE, n, ra);
    if (!st) st = read_column(f, path, hdu, "DEC", TDOUBLE, n, dec);
    if (!st && sne) st = read_column(f, path, hdu, "Z", TDOUBLE, n, z);
    if (!st && sne) st = read_column(f, path, hdu, "HOSTID", TLONGLONG, n, host);
    for (long i = 0; !st && i < n; i++) {
        hosts_obj o = {id[i], ra[i], dec[i], 0, 0, sne ? z[i] : NAN, sne ? host[i] : -1};
        if (!isfinite(o.ra) || !isfinite(o.dec)) {
            st = wf_error(WF_ERR_INPUT, "%s: %s row %ld: RA/DEC not finite", path, hdu, i + 1);
            break;
        }
        if (sne && !(o.z >= 0)) {
            st = wf_error(WF_ERR_INPUT, "%s: SNE row %ld: Z %g", path, i + 1, o.z);
            break;
        }
        if (image_pixel(im, o.ra, o.dec, &o.x, &o.y)) continue;
        if (o.x < 0.5 - margin || o.x > im->nx + 0.5 + margin || o.y < 0.5 - margin || o.y > im->ny + 0.5 + margin)
            continue;
        st = objv_push(v, &o);
    }
    free(id), free(host), free(ra), free(dec), free(z);
    return st;
}

static wf_status read_truth(const char *path, hosts_image *im, double margin, hosts_line *ln)
{
    wf_status st = need_file(path);
    if (st) return st;
    fitsfile *f = NULL;
    int status = 0;
    if (fits_open_file(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening the truth");
    long ng = 0, ns = 0, nsn = 0;
    st = read_truth_table(f, path, "GALAXIES", im, margin, &ln->gal, &ng);
    if (!st) st = read_truth_table(f, path, "STARS", im, margin, &ln->star, &ns);
    if (!st) st = read_truth_table(f, path, "SNE", im, margin, &ln->sne, &nsn);
    ln->sne_rows += nsn;
    status = 0;
    fits_close_file(f, &status);
    /* Many inputs list the same objects: keep the union small as it grows. */
    hosts_objv *all[3] = {&ln->gal, &ln->star, &ln->sne};
    for (int k = 0; !st && k < 3; k++)
        if (all[k]->n > 2 * all[k]->unique + 65536) objv_unique(all[k]);
    return st;
}

static wf_status read_catalog(const char *path, const hosts_image *im, hosts_line *ln)
{
    wf_status st = need_file(path);
    if (st) return st;
    fitsfile *f = NULL;
    int status = 0;
    long n = 0;
    if (fits_open_file(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening the catalog");
    if (fits_movnam_hdu(f, BINARY_TBL, "CATALOG", 0, &status)) {
        fits_clear_errmsg();
        st = wf_error(WF_ERR_INPUT, "%s: no CATALOG table: not a `wfisim detect` catalog", path);
    }
    static const char *need[] = {"ID", "X", "Y", "RA", "DEC", "A", "B", "THETA"};
    for (int k = 0; !st && k < 8; k++) {
        int col;
        if (!column(f, need[k], &col))
            st = wf_error(WF_ERR_INPUT, "%s: CATALOG has no column %s (host association needs a `wfisim detect` "
                          "catalog: ID, X, Y, RA, DEC and the isophotal ellipse A, B, THETA)", path, need[k]);
    }
    long n1 = 0, n2 = 0;
    if (!st && !fits_read_key_lng(f, "NAXIS1IM", &n1, NULL, &status) && !fits_read_key_lng(f, "NAXIS2IM", &n2, NULL, &status) &&
        (n1 != im->nx || n2 != im->ny))
        st = wf_error(WF_ERR_INPUT, "%s: the catalog is of a %ld x %ld image, %s is %d x %d: not its catalog", path, n1,
                      n2, im->path, im->nx, im->ny);
    status = 0;
    fits_clear_errmsg();
    if (!st && fits_get_num_rows(f, &n, &status)) st = wf_fits_error(status, path, "reading the row count");
    size_t m = n > 0 ? (size_t)n : 1;
    long long *id = malloc(m * sizeof *id);
    double *col[7];
    for (int k = 0; k < 7; k++) col[k] = malloc(m * sizeof(double));
    ln->det = calloc(m, sizeof *ln->det);
    int ok = id && ln->det;
    for (int k = 0; k < 7; k++) ok &= col[k] != NULL;
    if (!st && !ok) st = wf_error(WF_ERR_NOMEM, "%s: out of memory for %ld detections", path, n);
    if (!st) st = read_column(f, path, "CATALOG", "ID", TLONGLONG, n, id);
    for (int k = 0; !st && k < 7; k++) st = read_column(f, path, "CATALOG", need[k + 1], TDOUBLE, n, col[k]);
    for (long i = 0; !st && i < n; i++) {
        hosts_det *d = &ln->det[i];
        d->id = id[i];
        d->x = col[0][i], d->y = col[1][i], d->ra = col[2][i], d->dec = col[3][i];
        d->a = col[4][i], d->b = col[5][i], d->theta = col[6][i];
        d->gal = -1;
        if (!isfinite(d->x) || !isfinite(d->y) || !isfinite(d->ra) || !isfinite(d->dec))
            st = wf_error(WF_ERR_INPUT, "%s: CATALOG row %ld: X, Y, RA or DEC not finite", path, i + 1);
        /* An ellipse the moments could not give (A or B <= 0) gives no DLR; the detection
         * stays a candidate of the nearest rule. */
        d->has_dlr = d->a > 0 && d->b > 0 && isfinite(d->a) && isfinite(d->b) && isfinite(d->theta);
        if (!st && d->has_dlr) st = wf_hosts_sky_ellipse(&im->wcs, d->x, d->y, d->a, d->b, d->theta, d->cov);
        if (d->has_dlr) {
            double tr = 0.5 * (d->cov[0] + d->cov[2]), df = hypot(0.5 * (d->cov[0] - d->cov[2]), d->cov[1]);
            d->amax = sqrt(tr + df);
        }
    }
    ln->ndet = st ? 0 : (size_t)n;
    free(id);
    for (int k = 0; k < 7; k++) free(col[k]);
    status = 0;
    fits_close_file(f, &status);
    return st;
}

/* ---- spatial grid over the detections ---------------------------------------------------- */

#define CELL 32.0

static int clampi(double v, int lo, int hi)
{
    return v < lo ? lo : v > hi ? hi : (int)v;
}

static size_t grid_cell(const hosts_grid *g, double x, double y)
{
    int cx = clampi(floor(x / CELL), 0, g->nx - 1), cy = clampi(floor(y / CELL), 0, g->ny - 1);
    return (size_t)cy * g->nx + cx;
}

/* Cells [box0, box1] x [box2, box3] hold every point within r pixels of (x, y). */
static void grid_box(const hosts_grid *g, double x, double y, double r, int box[4])
{
    box[0] = clampi(floor((x - r) / CELL), 0, g->nx - 1), box[1] = clampi(floor((x + r) / CELL), 0, g->nx - 1);
    box[2] = clampi(floor((y - r) / CELL), 0, g->ny - 1), box[3] = clampi(floor((y + r) / CELL), 0, g->ny - 1);
}

static wf_status grid_build(hosts_grid *g, const hosts_det *d, size_t n, int nx, int ny)
{
    g->nx = (int)ceil((nx + 1) / CELL) + 1, g->ny = (int)ceil((ny + 1) / CELL) + 1;
    size_t nc = (size_t)g->nx * g->ny;
    g->start = calloc(nc + 1, sizeof *g->start);
    g->idx = malloc((n ? n : 1) * sizeof *g->idx);
    size_t *fill = calloc(nc, sizeof *fill);
    if (!g->start || !g->idx || !fill) {
        free(fill);
        return wf_error(WF_ERR_NOMEM, "hosts: out of memory for the grid");
    }
    for (size_t i = 0; i < n; i++) g->start[grid_cell(g, d[i].x, d[i].y) + 1]++;
    for (size_t c = 0; c < nc; c++) g->start[c + 1] += g->start[c];
    for (size_t i = 0; i < n; i++) {
        size_t c = grid_cell(g, d[i].x, d[i].y);
        g->idx[g->start[c] + fill[c]++] = i;
    }
    free(fill);
    return WF_OK;
}

/* ---- one-to-one matching ----------------------------------------------------------------- */

typedef struct pair {
    double sep;
    size_t det, obj;
} pair;

static int by_pair(const void *a, const void *b)
{
    const pair *p = a, *q = b;
    if (p->sep != q->sep) return p->sep < q->sep ? -1 : 1;
    if (p->det != q->det) return p->det < q->det ? -1 : 1;
    return (p->obj > q->obj) - (p->obj < q->obj);
}

/* Pairs of (free detection, object) within radius arcsec taken closest first, each side
 * once. *matched[obj] = detection index or -1; claim(det) is called on every match. */
static wf_status match(hosts_line *ln, const hosts_objv *objs, double radius, int kind, long *nmatched)
{
    pair *pairs = NULL;
    size_t np = 0, cap = 0;
    double rpix = radius / ln->im.scale_min * 1.2 + 0.5;
    wf_status st = WF_OK;
    for (size_t o = 0; o < objs->n && !st; o++) {
        int box[4];
        grid_box(&ln->grid, objs->v[o].x, objs->v[o].y, rpix, box);
        for (int cy = box[2]; cy <= box[3] && !st; cy++)
            for (int cx = box[0]; cx <= box[1] && !st; cx++) {
                size_t c = (size_t)cy * ln->grid.nx + cx;
                for (size_t k = ln->grid.start[c]; k < ln->grid.start[c + 1]; k++) {
                    size_t i = ln->grid.idx[k];
                    const hosts_det *d = &ln->det[i];
                    if (d->gal >= 0 || d->excluded) continue;
                    if (fabs(d->x - objs->v[o].x) > rpix || fabs(d->y - objs->v[o].y) > rpix) continue;
                    double sep = wf_wcs_separation(d->ra, d->dec, objs->v[o].ra, objs->v[o].dec) * 3600.0;
                    if (sep > radius) continue;
                    if (np == cap) {
                        size_t nc = cap ? 2 * cap : 1024;
                        pair *p = realloc(pairs, nc * sizeof *p);
                        if (!p) { st = wf_error(WF_ERR_NOMEM, "hosts: out of memory matching"); break; }
                        pairs = p, cap = nc;
                    }
                    pairs[np++] = (pair){sep, i, o};
                }
            }
    }
    if (!st) qsort(pairs, np, sizeof *pairs, by_pair);
    char *used = st ? NULL : calloc(objs->n ? objs->n : 1, 1);
    if (!st && !used) st = wf_error(WF_ERR_NOMEM, "hosts: out of memory matching");
    long nm = 0;
    for (size_t k = 0; !st && k < np; k++) {
        hosts_det *d = &ln->det[pairs[k].det];
        if (used[pairs[k].obj] || d->gal >= 0 || d->excluded) continue;
        used[pairs[k].obj] = 1;
        if (kind == 0) d->gal = (long)pairs[k].obj, ln->gal_det[pairs[k].obj] = (long)pairs[k].det;
        else d->excluded = kind;
        nm++;
    }
    free(used);
    free(pairs);
    *nmatched = nm;
    return st;
}

/* ---- association ------------------------------------------------------------------------- */

static const hosts_obj *find_galaxy(const hosts_objv *gal, long long id)
{
    hosts_obj key = {.id = id};
    return bsearch(&key, gal->v, gal->n, sizeof *gal->v, by_id);
}

static long long det_galaxy(const hosts_line *ln, long i)
{
    return i >= 0 && ln->det[i].gal >= 0 ? ln->gal.v[ln->det[i].gal].id : -1;
}

/* Separation (arcsec) and d_DLR of SN s from detection d. */
static void measure(const hosts_obj *s, const hosts_det *d, double *sep, double *ddlr)
{
    *sep = wf_wcs_separation(s->ra, s->dec, d->ra, d->dec) * 3600.0;
    *ddlr = NAN;
    if (!d->has_dlr) return;
    if (*sep == 0) { *ddlr = 0; return; }
    double e, n;
    if (wf_wcs_tangent_project(d->ra * DEG, d->dec * DEG, s->ra * DEG, s->dec * DEG, &e, &n)) {
        fits_clear_errmsg();
        return;
    }
    *ddlr = *sep / wf_hosts_dlr(d->cov, e / ARCSEC, n / ARCSEC);
}

static int outcome(long host_det, long chosen)
{
    if (host_det < 0) return HOSTS_UNDETECTED;
    return chosen == host_det ? HOSTS_CORRECT : HOSTS_WRONG;
}

static wf_status associate(hosts_line *ln, const wf_hosts_options *o, int line, hosts_rows *rows)
{
    /* Search far enough for the largest ellipse's d_DLR limit and for the nearest rule. */
    double amax = 0;
    for (size_t i = 0; i < ln->ndet; i++)
        if (ln->det[i].has_dlr && !ln->det[i].excluded && ln->det[i].amax > amax) amax = ln->det[i].amax;
    double rsearch = fmax(o->sep_max, o->dlr_max * amax), rpix = rsearch / ln->im.scale_min * 1.2 + 1.0;
    for (size_t k = 0; k < ln->sne.n; k++) {
        const hosts_obj *s = &ln->sne.v[k];
        if (!image_covers(&ln->im, s->x, s->y)) continue;
        hosts_row r;
        memset(&r, 0, sizeof r);
        r.sn = s->id, r.z = s->z, r.ra = s->ra, r.dec = s->dec, r.line = line, r.host = s->host;
        r.edge = edge_distance(&ln->im, s->x, s->y);
        r.host_det = r.dlr_det = r.near_det = -1;
        r.host_sep = r.host_ddlr = r.dlr_sep = r.dlr_ddlr = r.near_sep = r.near_ddlr = NAN;
        int host_inside = 0;
        if (s->host >= 0) {
            const hosts_obj *g = find_galaxy(&ln->gal, s->host);
            host_inside = g && image_covers(&ln->im, g->x, g->y);
            if (host_inside) r.host_det = ln->gal_det[g - ln->gal.v];
        }
        double best_sep = INFINITY, best_d = INFINITY;
        int box[4];
        grid_box(&ln->grid, s->x, s->y, rpix, box);
        for (int cy = box[2]; cy <= box[3]; cy++)
            for (int cx = box[0]; cx <= box[1]; cx++) {
                size_t c = (size_t)cy * ln->grid.nx + cx;
                for (size_t q = ln->grid.start[c]; q < ln->grid.start[c + 1]; q++) {
                    size_t i = ln->grid.idx[q];
                    const hosts_det *d = &ln->det[i];
                    if (d->excluded) continue;
                    double sep, dd;
                    measure(s, d, &sep, &dd);
                    /* ties go to the lower detection index (catalog order): the same answer
                     * whatever order the grid visits them in */
                    if (sep <= o->sep_max && (sep < best_sep || (sep == best_sep && (long)i < r.near_det)))
                        best_sep = sep, r.near_det = (long)i;
                    if (dd <= o->dlr_max && (dd < best_d || (dd == best_d && (long)i < r.dlr_det)))
                        best_d = dd, r.dlr_det = (long)i;
                }
            }
        if (r.host_det >= 0) measure(s, &ln->det[r.host_det], &r.host_sep, &r.host_ddlr);
        if (r.near_det >= 0) measure(s, &ln->det[r.near_det], &r.near_sep, &r.near_ddlr);
        if (r.dlr_det >= 0) measure(s, &ln->det[r.dlr_det], &r.dlr_sep, &r.dlr_ddlr);
        if (s->host < 0) {
            r.dlr_out = r.dlr_det >= 0 ? HOSTS_HOSTLESS_CHOSEN : HOSTS_HOSTLESS_NONE;
            r.near_out = r.near_det >= 0 ? HOSTS_HOSTLESS_CHOSEN : HOSTS_HOSTLESS_NONE;
        } else if (!host_inside) {
            r.dlr_out = r.near_out = HOSTS_OUTSIDE;
        } else {
            r.dlr_out = outcome(r.host_det, r.dlr_det);
            r.near_out = outcome(r.host_det, r.near_det);
        }
        r.host_det_id = r.host_det >= 0 ? ln->det[r.host_det].id : -1;
        r.dlr_det_id = r.dlr_det >= 0 ? ln->det[r.dlr_det].id : -1;
        r.near_det_id = r.near_det >= 0 ? ln->det[r.near_det].id : -1;
        r.dlr_gal = det_galaxy(ln, r.dlr_det);
        r.near_gal = det_galaxy(ln, r.near_det);
        wf_status st = hosts_rows_push(rows, &r);
        if (st) return st;
    }
    return WF_OK;
}

/* ---- the list ---------------------------------------------------------------------------- */

static void line_free(hosts_line *ln)
{
    image_close(&ln->im);
    free(ln->det);
    free(ln->gal_det);
    free(ln->gal.v), free(ln->star.v), free(ln->sne.v);
    free(ln->grid.start), free(ln->grid.idx);
    memset(ln, 0, sizeof *ln);
}

static wf_status do_line(char *image, char *cat, char *truths, const wf_hosts_options *o, int line, hosts_rows *rows,
                         wf_hosts_summary *sum)
{
    hosts_line ln;
    memset(&ln, 0, sizeof ln);
    wf_status st = image_open(image, &ln.im);
    if (!st) st = read_catalog(cat, &ln.im, &ln);
    double margin = o->radius / ln.im.scale_min * 1.2 + 2.0;
    int nfiles = 0;
    for (char *save = NULL, *t = strtok_r(truths, ",", &save); !st && t; t = strtok_r(NULL, ",", &save)) {
        if (!*t) continue;
        st = read_truth(t, &ln.im, margin, &ln);
        nfiles++;
    }
    if (!st && !nfiles) st = wf_error(WF_ERR_INPUT, "no truth file given");
    if (!st) {
        objv_unique(&ln.gal), objv_unique(&ln.star), objv_unique(&ln.sne);
        if (ln.sne_rows == 0)
            st = wf_error(WF_ERR_INPUT, "the SNE tables of its %d truth file(s) are empty: no supernovae to associate "
                          "(products made without --sne?)", nfiles);
    }
    if (!st) st = grid_build(&ln.grid, ln.det, ln.ndet, ln.im.nx, ln.im.ny);
    if (!st && !(ln.gal_det = malloc((ln.gal.n ? ln.gal.n : 1) * sizeof *ln.gal_det)))
        st = wf_error(WF_ERR_NOMEM, "hosts: out of memory");
    for (size_t g = 0; !st && g < ln.gal.n; g++) ln.gal_det[g] = -1;
    long ng = 0, nx1 = 0, nx2 = 0;
    /* Galaxies first: a star or SN that sits on a galaxy's centre never takes its detection. */
    if (!st) st = match(&ln, &ln.gal, o->radius, 0, &ng);
    if (!st) st = match(&ln, &ln.star, o->radius, 1, &nx1);
    if (!st) st = match(&ln, &ln.sne, o->radius, 2, &nx2);
    if (!st) st = associate(&ln, o, line, rows);
    if (!st) {
        sum->images++;
        sum->detections += (long)ln.ndet;
        sum->galaxies_matched += ng;
        sum->excluded += nx1 + nx2;
    }
    line_free(&ln);
    return st;
}

/* Prefixes the recorded message with LIST:LINE. */
static wf_status at_line(wf_status st, const char *list, int line)
{
    char msg[2048];
    snprintf(msg, sizeof msg, "%s", wf_error_message());
    return wf_error(st, "%s:%d: %s", list, line, msg[0] ? msg : wf_status_name(st));
}

wf_status wf_hosts_run(const char *list_path, const char *out_dir, const wf_hosts_options *o, wf_hosts_summary *sum_out)
{
    wf_hosts_summary sum;
    memset(&sum, 0, sizeof sum);
    if (!(o->radius > 0) || !(o->dlr_max > 0) || !(o->sep_max > 0) || !(o->zbin > 0))
        return wf_error(WF_ERR_INPUT, "--radius, --dlr-max, --sep-max and --zbin must be > 0");
    wf_status st = need_file(list_path);
    if (st) return st;
    FILE *f = fopen(list_path, "r");
    if (!f) return wf_error(WF_ERR_INPUT, "%s: cannot open: %s", list_path, strerror(errno));
    hosts_rows rows;
    memset(&rows, 0, sizeof rows);
    char *buf = NULL;
    size_t cap = 0;
    int line = 0;
    while (!st && getline(&buf, &cap, f) >= 0) {
        line++;
        char *hash = strchr(buf, '#');
        if (hash) *hash = 0;
        char *save = NULL, *w[4];
        int nw = 0;
        for (char *t = strtok_r(buf, " \t\r\n", &save); t && nw < 4; t = strtok_r(NULL, " \t\r\n", &save)) w[nw++] = t;
        if (nw == 0) continue;
        if (nw != 3) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: expected IMAGE DETCAT TRUTH[,TRUTH...] (3 fields), found %d", list_path,
                          line, nw);
            break;
        }
        if ((st = do_line(w[0], w[1], w[2], o, line, &rows, &sum))) st = at_line(st, list_path, line);
    }
    if (!st && ferror(f)) st = wf_error(WF_ERR_IO, "%s: read error", list_path);
    if (!st && sum.images == 0) st = wf_error(WF_ERR_INPUT, "%s: no image listed", list_path);
    fclose(f);
    free(buf);
    if (!st) st = hosts_finish(&rows, o, &sum, out_dir);
    free(rows.v);
    if (sum_out) *sum_out = sum;
    return st;
}
