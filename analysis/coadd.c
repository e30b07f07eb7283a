#include "analysis/coadd.h"
#include "analysis/drizzle.h"
#include "sim/fits/fitsout.h"
#include "sim/numeric/median.h"

#include <errno.h>
#include <fitsio.h>
#include <glob.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define DEG (M_PI / 180.0)
#define BLOCK_ROWS 32 /* input rows read and mapped at a time */
#define EDGE_STEP 8    /* pixels between the samples of a boundary mapped to the other grid */
#define MARGIN 2.0     /* pixels added around a mapped boundary: the drop's half width + slack */
#define WEIGHT_ROWS 64 /* input rows sampled for an input's weight */

typedef struct input {
    char path[1024];
    long exposure;
    int sca;
    double mjd;
    char filter[FLEN_VALUE];
    wf_wcs wcs;
    int hdu_sci, hdu_err, hdu_dq;
    double weight; /* 1 / its sky's ERR^2 (input_weight) */
    double box[4]; /* its footprint on the output grid: xmin, xmax, ymin, ymax; NaN: none */
} input;

void wf_coadd_opts_default(wf_coadd_opts *o)
{
    memset(o, 0, sizeof *o);
    o->pixscale = WF_COADD_PIXSCALE;
    o->pixfrac = WF_COADD_PIXFRAC;
    o->tile_rows = 256;
    o->dq_mask = 0xffffffffu;
    o->mjd_lo = -INFINITY;
    o->mjd_hi = INFINITY;
}

wf_status wf_coadd_grid(const wf_coadd_opts *o, wf_wcs *out)
{
    if (o->nx < 1 || o->ny < 1)
        return wf_error(WF_ERR_INPUT, "coadd: output size %d x %d is not positive", o->nx, o->ny);
    if (!(o->pixscale > 0) || !isfinite(o->pixscale))
        return wf_error(WF_ERR_INPUT, "coadd: pixel scale %g is not positive", o->pixscale);
    if (!isfinite(o->ra) || !(fabs(o->dec) < 90.0) || !isfinite(o->pa))
        return wf_error(WF_ERR_INPUT, "coadd: centre (%g, %g) or PA %g out of range", o->ra, o->dec, o->pa);
    wf_wcs w;
    memset(&w, 0, sizeof w);
    w.nx = o->nx;
    w.ny = o->ny;
    w.crpix[0] = 0.5 * (o->nx + 1);
    w.crpix[1] = 0.5 * (o->ny + 1);
    w.crval[0] = fmod(fmod(o->ra, 360.0) + 360.0, 360.0);
    w.crval[1] = o->dec;
    double s = o->pixscale / 3600.0, c = cos(o->pa * DEG), n = sin(o->pa * DEG);
    /* +y at PA east of north, +x towards the west at PA 0 (east to the left, north up) */
    w.cd[0][0] = -s * c;
    w.cd[0][1] = s * n;
    w.cd[1][0] = s * n;
    w.cd[1][1] = s * c;
    w.pa_sca_deg = o->pa;
    *out = w;
    return WF_OK;
}

/* Input pixel (x, y) -> output pixel; NaN where the sky position is not on both grids. */
static void map_point(const wf_wcs *from, const wf_wcs *to, double x, double y, double *ox, double *oy)
{
    double ra, dec;
    if (wf_wcs_pix2world(from, x, y, &ra, &dec) || wf_wcs_world2pix(to, ra, dec, ox, oy)) {
        *ox = *oy = NAN;
        return;
    }
}

/* The bounding box, on grid `to`, of the rectangle [x0, x1] x [y0, y1] of grid `from`
 * (pixel edges), from samples of its boundary: a smooth one-to-one map takes a rectangle's
 * boundary to the boundary of its image. box[0] is NaN when no sample maps. */
static void map_box(const wf_wcs *from, const wf_wcs *to, double x0, double x1, double y0, double y1,
                    double box[4])
{
    box[0] = box[2] = INFINITY;
    box[1] = box[3] = -INFINITY;
    int nxs = (int)ceil((x1 - x0) / EDGE_STEP), nys = (int)ceil((y1 - y0) / EDGE_STEP);
    if (nxs < 1) nxs = 1;
    if (nys < 1) nys = 1;
    for (int side = 0; side < 4; side++) {
        int n = side < 2 ? nxs : nys;
        for (int k = 0; k <= n; k++) {
            double t = (double)k / n, x, y, ox, oy;
            if (side < 2) {
                x = x0 + t * (x1 - x0);
                y = side ? y1 : y0;
            } else {
                x = side == 3 ? x1 : x0;
                y = y0 + t * (y1 - y0);
            }
            map_point(from, to, x, y, &ox, &oy);
            if (!isfinite(ox) || !isfinite(oy)) continue;
            box[0] = fmin(box[0], ox);
            box[1] = fmax(box[1], ox);
            box[2] = fmin(box[2], oy);
            box[3] = fmax(box[3], oy);
        }
    }
    if (!(box[0] <= box[1])) box[0] = box[1] = box[2] = box[3] = NAN;
}

static wf_status find_hdu(fitsfile *f, const char *path, const char *name, int *hdu)
{
    int status = 0;
    if (fits_movnam_hdu(f, ANY_HDU, (char *)name, 0, &status)) {
        fits_clear_errmsg();
        return wf_error(WF_ERR_INPUT, "%s: no %s HDU (not a wfisim product?)", path, name);
    }
    fits_get_hdu_num(f, hdu);
    return WF_OK;
}

static wf_status read_input(const char *path, input *in)
{
    memset(in, 0, sizeof *in);
    if ((size_t)snprintf(in->path, sizeof in->path, "%s", path) >= sizeof in->path)
        return wf_error(WF_ERR_INPUT, "%s: path too long", path);
    fitsfile *f;
    int status = 0;
    if (fits_open_diskfile(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening an input");
    wf_status st = WF_OK;
    char filter[FLEN_VALUE] = "";
    fits_read_key_str(f, "FILTER", filter, NULL, &status);
    fits_read_key_lng(f, "EXPOSURE", &in->exposure, NULL, &status);
    long sca = 0;
    fits_read_key_lng(f, "SCA", &sca, NULL, &status);
    fits_read_key_dbl(f, "MJD-OBS", &in->mjd, NULL, &status);
    if (status) {
        st = wf_fits_error(status, path, "reading FILTER, EXPOSURE, SCA and MJD-OBS from the primary header");
        st = WF_ERR_INPUT;
        goto done;
    }
    in->sca = (int)sca;
    snprintf(in->filter, sizeof in->filter, "%s", filter);
    if ((st = find_hdu(f, path, "SCI", &in->hdu_sci)) || (st = find_hdu(f, path, "ERR", &in->hdu_err)) ||
        (st = find_hdu(f, path, "DQ", &in->hdu_dq)))
        goto done;
    int hdus[3] = {in->hdu_sci, in->hdu_err, in->hdu_dq};
    for (int k = 0; k < 3 && !st; k++) {
        wf_wcs w;
        if (fits_movabs_hdu(f, hdus[k], NULL, &status)) {
            st = wf_fits_error(status, path, "moving to an image HDU");
            break;
        }
        if ((st = wf_wcs_read_header(f, path, &w))) break;
        if (k == 0) in->wcs = w;
        else if (w.nx != in->wcs.nx || w.ny != in->wcs.ny)
            st = wf_error(WF_ERR_INPUT, "%s: %s is %d x %d but SCI is %d x %d", path, k == 1 ? "ERR" : "DQ",
                          w.nx, w.ny, in->wcs.nx, in->wcs.ny);
    }
done:
    fits_close_file(f, &status);
    fits_clear_errmsg();
    return st;
}

static int cmp_input(const void *pa, const void *pb)
{
    const input *a = pa, *b = pb;
    if (a->mjd != b->mjd) return a->mjd < b->mjd ? -1 : 1;
    if (a->exposure != b->exposure) return a->exposure < b->exposure ? -1 : 1;
    if (a->sca != b->sca) return a->sca < b->sca ? -1 : 1;
    return strcmp(a->path, b->path);
}

/* Scratch for one input block, grown as needed. */
typedef struct scratch {
    size_t cap, mcap;
    float *sci, *err;
    uint32_t *dq;
    double *ox, *oy;
} scratch;

static wf_status grow(scratch *s, size_t n, size_t m)
{
    if (n > s->cap) {
        float *a = realloc(s->sci, n * sizeof *a), *b = a ? realloc(s->err, n * sizeof *b) : NULL;
        if (a) s->sci = a;
        if (b) s->err = b;
        uint32_t *c = b ? realloc(s->dq, n * sizeof *c) : NULL;
        if (c) s->dq = c;
        if (!c) return wf_error(WF_ERR_NOMEM, "coadd: cannot allocate an input block of %zu pixels", n);
        s->cap = n;
    }
    if (m > s->mcap) {
        double *a = realloc(s->ox, m * sizeof *a), *b = a ? realloc(s->oy, m * sizeof *b) : NULL;
        if (a) s->ox = a;
        if (b) s->oy = b;
        if (!b) return wf_error(WF_ERR_NOMEM, "coadd: cannot allocate a map of %zu points", m);
        s->mcap = m;
    }
    return WF_OK;
}

static void scratch_free(scratch *s)
{
    free(s->sci);
    free(s->err);
    free(s->dq);
    free(s->ox);
    free(s->oy);
}

static wf_status read_rect(fitsfile *f, const input *in, int hdu, int type, long x0, long x1, long y0,
                           long y1, void *buf)
{
    int status = 0, anynul = 0;
    long fp[2] = {x0 + 1, y0 + 1}, lp[2] = {x1 + 1, y1 + 1}, inc[2] = {1, 1};
    fits_movabs_hdu(f, hdu, NULL, &status);
    fits_read_subset(f, type, fp, lp, inc, NULL, buf, &anynul, &status);
    return wf_fits_error(status, in->path, "reading input pixels");
}

/* An input's weight: 1 / ERR^2 of its sky, the median of ERR over the good pixels of
 * WEIGHT_ROWS rows spread over the image. One weight for all its pixels, not 1 / ERR^2 of
 * each: a source's own shot noise is in its pixels' ERR, so per-pixel weights favour the
 * fainter pixels wherever drops of a source overlap, and a star would lose 28% of its flux at
 * pixfrac 1 and 14% at 0.7 (tests/test_coadd.c, point_sources_flux). Between inputs the
 * weights still follow their depth (exposure time, sky), as romancal's read-noise and
 * AstroDrizzle's background-only inverse-variance maps do. Sets weight 0 when no sampled
 * pixel is good (the input then adds nothing). */
static wf_status input_weight(input *in, uint32_t dq_mask)
{
    const wf_wcs *w = &in->wcs;
    int step = w->ny / WEIGHT_ROWS > 1 ? w->ny / WEIGHT_ROWS : 1;
    size_t cap = (size_t)w->nx * (size_t)((w->ny + step - 1) / step);
    float *err = malloc(cap * sizeof *err), *row = malloc((size_t)w->nx * sizeof *row);
    uint32_t *dq = malloc((size_t)w->nx * sizeof *dq);
    if (!err || !row || !dq) {
        free(err);
        free(row);
        free(dq);
        return wf_error(WF_ERR_NOMEM, "coadd: cannot allocate %zu ERR samples", cap);
    }
    fitsfile *f;
    int status = 0;
    wf_status st = WF_OK;
    size_t n = 0;
    if (fits_open_diskfile(&f, in->path, READONLY, &status)) {
        st = wf_fits_error(status, in->path, "opening an input");
    } else {
        for (long y = step / 2; y < w->ny && !st; y += step) {
            if ((st = read_rect(f, in, in->hdu_err, TFLOAT, 0, w->nx - 1, y, y, row)) ||
                (st = read_rect(f, in, in->hdu_dq, TUINT, 0, w->nx - 1, y, y, dq)))
                break;
            for (int x = 0; x < w->nx; x++)
                if (!(dq[x] & dq_mask) && isfinite(row[x]) && row[x] > 0) err[n++] = row[x];
        }
        fits_close_file(f, &status);
        fits_clear_errmsg();
    }
    in->weight = 0;
    if (!st && n) {
        double m = wf_median_float(err, n);
        in->weight = 1.0 / (m * m);
    }
    free(err);
    free(row);
    free(dq);
    return st;
}

/* Drops the rows of input `in` that map into tile t. */
static wf_status add_input(wf_drizzle_tile *t, const wf_wcs *grid, const input *in, int32_t id,
                           const wf_coadd_opts *o, scratch *s, long *drops)
{
    const wf_wcs *iw = &in->wcs;
    /* the tile's part of the input's footprint, mapped back onto the input */
    double bx0 = fmax(-0.5, in->box[0] - MARGIN), bx1 = fmin(t->nx - 0.5, in->box[1] + MARGIN);
    double by0 = fmax(t->y0 - 0.5, in->box[2] - MARGIN), by1 = fmin(t->y0 + t->ny - 0.5, in->box[3] + MARGIN);
    if (!(bx0 < bx1 && by0 < by1) || !(in->weight > 0)) return WF_OK;
    double ib[4];
    map_box(grid, iw, bx0, bx1, by0, by1, ib);
    if (isnan(ib[0])) return WF_OK;
    long x0 = (long)floor(fmax(0, ib[0] - MARGIN)), x1 = (long)ceil(fmin(iw->nx - 1, ib[1] + MARGIN));
    long y0 = (long)floor(fmax(0, ib[2] - MARGIN)), y1 = (long)ceil(fmin(iw->ny - 1, ib[3] + MARGIN));
    if (x0 > x1 || y0 > y1) return WF_OK;
    int nc = (int)(x1 - x0 + 1);
    fitsfile *f;
    int status = 0;
    if (fits_open_diskfile(&f, in->path, READONLY, &status)) return wf_fits_error(status, in->path, "opening an input");
    wf_status st = WF_OK;
    for (long r0 = y0; r0 <= y1 && !st; r0 += BLOCK_ROWS) {
        long r1 = r0 + BLOCK_ROWS - 1 < y1 ? r0 + BLOCK_ROWS - 1 : y1;
        int nr = (int)(r1 - r0 + 1);
        /* the columns of the block that can reach the tile, from the output rows of
         * its corners every EDGE_STEP columns (near-affine: extremes at the corners) */
        int ca = nc, cb = -1;
        for (int c = 0; c < nc; c += EDGE_STEP) {
            int ce = c + EDGE_STEP < nc ? c + EDGE_STEP : nc;
            double lo = INFINITY, hi = -INFINITY;
            for (int k = 0; k < 4; k++) {
                double ox, oy;
                map_point(iw, grid, (double)(x0 + (k & 1 ? ce : c - 1)), (double)(r0 + (k & 2 ? nr : -1)), &ox, &oy);
                if (!isfinite(oy)) lo = -INFINITY, hi = INFINITY; /* unknown: keep */
                lo = fmin(lo, oy);
                hi = fmax(hi, oy);
            }
            if (hi + MARGIN < t->y0 - 0.5 || lo - MARGIN > t->y0 + t->ny - 0.5) continue;
            if (c < ca) ca = c;
            cb = ce - 1;
        }
        if (cb < ca) continue;
        int mc = cb - ca + 1;
        if ((st = grow(s, (size_t)nr * mc, (size_t)(nr + 2) * (mc + 2)))) break;
        if ((st = read_rect(f, in, in->hdu_sci, TFLOAT, x0 + ca, x0 + cb, r0, r1, s->sci)) ||
            (st = read_rect(f, in, in->hdu_err, TFLOAT, x0 + ca, x0 + cb, r0, r1, s->err)) ||
            (st = read_rect(f, in, in->hdu_dq, TUINT, x0 + ca, x0 + cb, r0, r1, s->dq)))
            break;
        for (int r = -1; r <= nr; r++)
            for (int c = -1; c <= mc; c++) {
                size_t k = (size_t)(r + 1) * (mc + 2) + (size_t)(c + 1);
                map_point(iw, grid, (double)(x0 + ca + c), (double)(r0 + r), &s->ox[k], &s->oy[k]);
            }
        wf_drizzle_block b = {nr, mc, mc, s->sci, s->err, s->dq, s->ox, s->oy, in->weight};
        *drops += wf_drizzle_add(t, &b, o->pixfrac, o->dq_mask, id);
    }
    fits_close_file(f, &status);
    fits_clear_errmsg();
    return st;
}

static int key_dbl(fitsfile *f, const char *k, double v, const char *c, int *status)
{
    return fits_write_key_dbl(f, k, v, -wf_fits_double_digits(v), c, status);
}

static wf_status create_product(fitsfile *f, const char *tmp, const wf_wcs *grid, const input *in, int n,
                                const wf_coadd_opts *o)
{
    int status = 0;
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_write_key_str(f, "FILTER", in[0].filter, "optical element of every input", &status);
    fits_write_key_lng(f, "NINPUT", n, "inputs drizzled (table INPUTS)", &status);
    fits_write_key_str(f, "KERNEL", "square", "drizzle kernel (Fruchter & Hook 2002)", &status);
    key_dbl(f, "PIXFRAC", o->pixfrac, "drop size / input pixel size", &status);
    key_dbl(f, "PIXSCALE", o->pixscale, "[arcsec] output pixel size", &status);
    fits_write_key_lng(f, "DQMASK", (long)o->dq_mask, "input DQ bits left out", &status);
    key_dbl(f, "MJD-BEG", in[0].mjd, "[d] earliest input mid-time", &status);
    key_dbl(f, "MJD-END", in[n - 1].mjd, "[d] latest input mid-time", &status);
    fits_write_key_str(f, "WEIGHT", "sky-ivm", "each input: 1/median(ERR)^2, its sky", &status);
    fits_write_key_str(f, "ORIGIN", "wfisim coadd", "software", &status);
    if (status) return wf_fits_error(status, tmp, "writing the primary header");
    wf_status st = wf_fits_reserve_checksum(f, tmp);
    static const struct {
        const char *name;
        int bitpix;
        const char *bunit, *comment;
    } planes[4] = {
        {"SCI", FLOAT_IMG, "electron/s", "drizzled rate per output pixel"},
        {"ERR", FLOAT_IMG, "electron/s", "1-sigma of SCI, output pixels taken independently"},
        {"WHT", FLOAT_IMG, "s2/electron2", "drizzle weight: sum of overlap/drop area x weight"},
        {"CTX", LONG_IMG, NULL, "number of inputs contributing"},
    };
    long naxes[2] = {grid->nx, grid->ny};
    for (int k = 0; k < 4 && !st; k++) {
        fits_create_img(f, planes[k].bitpix, 2, naxes, &status);
        fits_write_key_str(f, "EXTNAME", planes[k].name, planes[k].comment, &status);
        if (planes[k].bunit) fits_write_key_str(f, "BUNIT", planes[k].bunit, "physical unit of the data", &status);
        if (status) return wf_fits_error(status, tmp, "creating an image HDU");
        if ((st = wf_wcs_write_header(grid, f, tmp))) break;
        st = wf_fits_reserve_checksum(f, tmp);
    }
    if (st) return st;
    char *ttype[] = {"FILE", "EXPOSURE", "SCA", "MJD", "FILTER", "WEIGHT"};
    char *tform[] = {"256A", "1J", "1I", "1D", "16A", "1D"};
    char *tunit[] = {"", "", "", "d", "", "s2/electron2"};
    fits_create_tbl(f, BINARY_TBL, n, 6, ttype, tform, tunit, "INPUTS", &status);
    for (int i = 0; i < n && !status; i++) {
        char *file = (char *)in[i].path, *filt = (char *)in[i].filter;
        long e = in[i].exposure;
        int sca = in[i].sca;
        double mjd = in[i].mjd;
        fits_write_col(f, TSTRING, 1, i + 1, 1, 1, &file, &status);
        fits_write_col(f, TLONG, 2, i + 1, 1, 1, &e, &status);
        fits_write_col(f, TINT, 3, i + 1, 1, 1, &sca, &status);
        fits_write_col(f, TDOUBLE, 4, i + 1, 1, 1, &mjd, &status);
        fits_write_col(f, TSTRING, 5, i + 1, 1, 1, &filt, &status);
        fits_write_col(f, TDOUBLE, 6, i + 1, 1, 1, (void *)&in[i].weight, &status);
    }
    return wf_fits_error(status, tmp, "writing the INPUTS table");
}

static wf_status write_tile(fitsfile *f, const char *tmp, const wf_drizzle_tile *t, float *fbuf, int32_t *ibuf)
{
    size_t n = (size_t)t->nx * (size_t)t->ny;
    LONGLONG first = (LONGLONG)t->y0 * t->nx + 1;
    int status = 0;
    for (int k = 0; k < 3 && !status; k++) {
        for (size_t p = 0; p < n; p++) {
            double w = t->wht[p];
            fbuf[p] = k == 2 ? (float)w : !(w > 0) ? 0.0f : k == 0 ? (float)(t->sum[p] / w) : (float)(sqrt(t->var[p]) / w);
        }
        fits_movabs_hdu(f, 2 + k, NULL, &status);
        fits_write_img(f, TFLOAT, first, (LONGLONG)n, fbuf, &status);
    }
    memcpy(ibuf, t->ctx, n * sizeof *ibuf);
    fits_movabs_hdu(f, 5, NULL, &status);
    fits_write_img(f, TINT, first, (LONGLONG)n, ibuf, &status);
    return wf_fits_error(status, tmp, "writing output rows");
}

wf_status wf_coadd_run(const char *const *paths, int n, const wf_coadd_opts *o, const char *out)
{
    wf_wcs grid;
    wf_status st = wf_coadd_grid(o, &grid);
    return st ? st : wf_coadd_run_grid(paths, n, o, &grid, out);
}

wf_status wf_coadd_run_grid(const char *const *paths, int n, const wf_coadd_opts *o, const wf_wcs *grid_in,
                            const char *out)
{
    if (n < 1) return wf_error(WF_ERR_INPUT, "coadd: no input products");
    if (!(o->pixfrac > 0 && o->pixfrac <= 1))
        return wf_error(WF_ERR_INPUT, "coadd: pixfrac %g is not in (0, 1]", o->pixfrac);
    if (o->tile_rows < 1) return wf_error(WF_ERR_INPUT, "coadd: tile rows %d is not positive", o->tile_rows);
    wf_wcs grid = *grid_in;
    wf_status st = WF_OK;
    input *in = calloc((size_t)n, sizeof *in);
    if (!in) return wf_error(WF_ERR_NOMEM, "coadd: cannot allocate %d inputs", n);
    int kept = 0;
    for (int i = 0; i < n && !st; i++) {
        if ((st = read_input(paths[i], &in[kept]))) break;
        if (!(in[kept].mjd >= o->mjd_lo && in[kept].mjd <= o->mjd_hi)) continue;
        if (strcmp(in[kept].filter, in[0].filter))
            st = wf_error(WF_ERR_INPUT, "coadd: %s is filter %s but %s is %s: one filter per coadd", paths[i],
                          in[kept].filter, in[0].path, in[0].filter);
        kept++;
    }
    if (!st && kept == 0)
        st = wf_error(WF_ERR_INPUT, "coadd: none of the %d inputs (%s, ...) has MJD-OBS within %.6f:%.6f", n,
                      paths[0], o->mjd_lo, o->mjd_hi);
    n = kept;
    int any = 0;
    if (!st) {
        qsort(in, (size_t)n, sizeof *in, cmp_input);
        for (int i = 0; i < n && !st; i++) {
            if (i && in[i].exposure == in[i - 1].exposure && in[i].sca == in[i - 1].sca)
                st = wf_error(WF_ERR_INPUT, "coadd: %s and %s are both exposure %ld SCA %d", in[i - 1].path,
                              in[i].path, in[i].exposure, in[i].sca);
            const wf_wcs *w = &in[i].wcs;
            map_box(w, &grid, -0.5, w->nx - 0.5, -0.5, w->ny - 0.5, in[i].box);
            if (!isnan(in[i].box[0]) && in[i].box[1] > -0.5 && in[i].box[0] < grid.nx - 0.5 &&
                in[i].box[3] > -0.5 && in[i].box[2] < grid.ny - 0.5) {
                any = 1;
                if (!st) st = input_weight(&in[i], o->dq_mask);
            }
        }
        if (!st && !any)
            st = wf_error(WF_ERR_INPUT, "coadd: no input overlaps the %d x %d output grid at (%.6f, %.6f)", grid.nx,
                          grid.ny, grid.crval[0], grid.crval[1]);
    }
    if (st) {
        free(in);
        return st;
    }
    int rows = o->tile_rows < grid.ny ? o->tile_rows : grid.ny;
    wf_drizzle_tile t;
    scratch s = {0};
    float *fbuf = NULL;
    int32_t *ibuf = NULL;
    fitsfile *f = NULL;
    char tmp[1100];
    long drops = 0;
    if ((st = wf_drizzle_tile_alloc(&t, grid.nx, rows))) goto done;
    fbuf = malloc((size_t)grid.nx * rows * sizeof *fbuf);
    ibuf = malloc((size_t)grid.nx * rows * sizeof *ibuf);
    if (!fbuf || !ibuf) {
        st = wf_error(WF_ERR_NOMEM, "coadd: cannot allocate output rows");
        goto done;
    }
    if ((st = wf_fits_begin(out, tmp, sizeof tmp, &f))) {
        f = NULL;
        goto done;
    }
    st = create_product(f, tmp, &grid, in, n, o);
    for (int y0 = 0; y0 < grid.ny && !st; y0 += rows) {
        int ny = grid.ny - y0 < rows ? grid.ny - y0 : rows;
        wf_drizzle_tile_reset(&t, y0, ny);
        for (int i = 0; i < n && !st; i++) st = add_input(&t, &grid, &in[i], i + 1, o, &s, &drops);
        if (!st) st = write_tile(f, tmp, &t, fbuf, ibuf);
        if (!st && !o->quiet) fprintf(stderr, "\rcoadd: rows %d/%d", y0 + ny, grid.ny);
    }
    if (!o->quiet) fputc('\n', stderr);
    if (!st && drops == 0)
        st = wf_error(WF_ERR_INPUT, "coadd: no good input pixel lands on the output grid (all masked or outside)");
    st = wf_fits_finish(f, tmp, out, st);
    f = NULL;
done:
    if (f) {
        int status = 0;
        fits_close_file(f, &status);
        unlink(tmp);
    }
    wf_drizzle_tile_free(&t);
    scratch_free(&s);
    free(fbuf);
    free(ibuf);
    free(in);
    return st;
}

/* ---- command ---------------------------------------------------------------------------- */

static const char *usage =
    "usage: wfisim coadd --center RA,DEC --size NX,NY --out FILE [options] PRODUCT...|@LIST\n"
    "  drizzle products of one filter onto a TAN grid (docs/ANALYSIS.md)\n"
    "  --center RA,DEC   grid centre, degrees\n"
    "  --size NX,NY      output pixels\n"
    "  --pixscale S      arcsec per output pixel [0.0575]\n"
    "  --pa DEG          position angle of the output +y axis, east of north [0]\n"
    "  --pixfrac F       drop size in input pixels, (0, 1] [0.7]\n"
    "  --dq-mask BITS    DQ bits that exclude a pixel [0xffffffff: any flag]\n"
    "  --tile-rows N     output rows per tile: memory only, never the result [256]\n"
    "  --mjd A:B         only the inputs whose MJD-OBS lies in [A, B] (either side may be\n"
    "                    empty: open); a template from the epochs before or after a date\n"
    "  --quiet           no progress\n"
    "  PRODUCT           a wfisim_e*_sca*.fits file or a quoted glob; @LIST a file of paths,\n"
    "                    one per line\n";

static int usage_error(const char *fmt, const char *what)
{
    fprintf(stderr, "wfisim coadd: ");
    fprintf(stderr, fmt, what);
    fprintf(stderr, "\n%s", usage);
    return 2;
}

static int parse_pair(const char *s, double *a, double *b)
{
    char *end;
    errno = 0;
    *a = strtod(s, &end);
    if (end == s || *end != ',') return -1;
    const char *t = end + 1;
    *b = strtod(t, &end);
    return end == t || *end || errno || !isfinite(*a) || !isfinite(*b) ? -1 : 0;
}

static int parse_num(const char *s, double *v)
{
    char *end;
    errno = 0;
    *v = strtod(s, &end);
    return end == s || *end || errno || !isfinite(*v) ? -1 : 0;
}

/* "A:B", "A:" or ":B" (an empty side is open), A <= B. */
static int parse_range(const char *s, double *lo, double *hi)
{
    const char *colon = strchr(s, ':');
    if (!colon) return -1;
    char a[64];
    size_t n = (size_t)(colon - s);
    if (n >= sizeof a) return -1;
    memcpy(a, s, n);
    a[n] = '\0';
    *lo = -INFINITY, *hi = INFINITY;
    if (n && parse_num(a, lo)) return -1;
    if (colon[1] && parse_num(colon + 1, hi)) return -1;
    return *lo <= *hi ? 0 : -1;
}

typedef struct paths {
    char **v;
    int n, cap;
} paths;

static int push(paths *p, const char *s)
{
    if (p->n == p->cap) {
        int cap = p->cap ? 2 * p->cap : 64;
        char **v = realloc(p->v, (size_t)cap * sizeof *v);
        if (!v) return -1;
        p->v = v;
        p->cap = cap;
    }
    if (!(p->v[p->n] = strdup(s))) return -1;
    p->n++;
    return 0;
}

/* A path, a glob (expanded here so lists longer than the shell's argument limit work), or
 * @LIST. Returns 0, or 2 after printing the problem. */
static int add_arg(paths *p, const char *a)
{
    if (a[0] == '@') {
        FILE *in = fopen(a + 1, "r");
        if (!in) {
            fprintf(stderr, "wfisim coadd: %s: %s\n", a + 1, strerror(errno));
            return 2;
        }
        char line[1100];
        int rc = 0;
        while (!rc && fgets(line, sizeof line, in)) {
            line[strcspn(line, "\r\n")] = '\0';
            if (line[0] && line[0] != '#' && push(p, line)) rc = 1;
        }
        fclose(in);
        return rc;
    }
    if (strpbrk(a, "*?[") && access(a, F_OK) != 0) {
        glob_t g;
        int rc = glob(a, 0, NULL, &g);
        if (rc == GLOB_NOMATCH) {
            fprintf(stderr, "wfisim coadd: no file matches '%s'\n", a);
            return 2;
        }
        for (size_t i = 0; rc == 0 && i < g.gl_pathc; i++)
            if (push(p, g.gl_pathv[i])) rc = 1;
        globfree(&g);
        return rc ? 1 : 0;
    }
    return push(p, a) ? 1 : 0;
}

int wf_cmd_coadd(int argc, char **argv)
{
    wf_coadd_opts o;
    wf_coadd_opts_default(&o);
    const char *out = NULL;
    int have_center = 0, have_size = 0, rc = 0;
    paths p = {0};
    for (int i = 0; i < argc && !rc; i++) {
        const char *k = argv[i];
        if (!strcmp(k, "--help") || !strcmp(k, "-h")) {
            fputs(usage, stdout);
            goto end;
        }
        if (!strcmp(k, "--quiet")) {
            o.quiet = 1;
            continue;
        }
        if (strncmp(k, "--", 2)) {
            rc = add_arg(&p, k);
            continue;
        }
        if (i + 1 >= argc) {
            rc = usage_error("%s needs a value", k);
            break;
        }
        const char *v = argv[++i];
        double a, b;
        if (!strcmp(k, "--center")) {
            if (parse_pair(v, &o.ra, &o.dec) || !(fabs(o.dec) < 90)) rc = usage_error("--center '%s' is not RA,DEC in degrees", v);
            have_center = 1;
        } else if (!strcmp(k, "--size")) {
            if (parse_pair(v, &a, &b) || a < 1 || b < 1 || a > 1e6 || b > 1e6 || a != floor(a) || b != floor(b))
                rc = usage_error("--size '%s' is not NX,NY (positive integers)", v);
            o.nx = (int)a;
            o.ny = (int)b;
            have_size = 1;
        } else if (!strcmp(k, "--pixscale")) {
            if (parse_num(v, &o.pixscale) || !(o.pixscale > 0)) rc = usage_error("--pixscale '%s' is not a positive number of arcsec", v);
        } else if (!strcmp(k, "--pa")) {
            if (parse_num(v, &o.pa)) rc = usage_error("--pa '%s' is not a number of degrees", v);
        } else if (!strcmp(k, "--pixfrac")) {
            if (parse_num(v, &o.pixfrac) || !(o.pixfrac > 0 && o.pixfrac <= 1)) rc = usage_error("--pixfrac '%s' is not in (0, 1]", v);
        } else if (!strcmp(k, "--tile-rows")) {
            if (parse_num(v, &a) || a < 1 || a > 1e6 || a != floor(a)) rc = usage_error("--tile-rows '%s' is not a positive integer", v);
            o.tile_rows = (int)a;
        } else if (!strcmp(k, "--dq-mask")) {
            char *end;
            errno = 0;
            unsigned long m = strtoul(v, &end, 0);
            if (end == v || *end || errno || m > 0xffffffffUL) rc = usage_error("--dq-mask '%s' is not a 32-bit number", v);
            o.dq_mask = (uint32_t)m;
        } else if (!strcmp(k, "--mjd")) {
            if (parse_range(v, &o.mjd_lo, &o.mjd_hi)) rc = usage_error("--mjd '%s' is not A:B (MJD, A <= B; a side may be empty)", v);
        } else if (!strcmp(k, "--out")) {
            out = v;
        } else {
            rc = usage_error("unknown option '%s'", k);
        }
    }
    if (!rc && !out) rc = usage_error("%s is required", "--out");
    if (!rc && !have_center) rc = usage_error("%s is required", "--center");
    if (!rc && !have_size) rc = usage_error("%s is required", "--size");
    if (!rc && p.n == 0) rc = usage_error("%s", "no input products given");
    if (!rc) {
        wf_status st = wf_coadd_run((const char *const *)p.v, p.n, &o, out);
        if (st) {
            fprintf(stderr, "wfisim coadd: %s\n", wf_error_message());
            rc = st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
        } else if (!o.quiet) {
            fprintf(stderr, "wfisim coadd: %d inputs%s -> %s\n", p.n, isinf(o.mjd_lo) && isinf(o.mjd_hi) ? "" : " (those within --mjd drizzled)", out);
        }
    }
end:
    for (int i = 0; i < p.n; i++) free(p.v[i]);
    free(p.v);
    return rc;
}
