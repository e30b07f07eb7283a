#include "analysis/diff.h"
#include "analysis/coadd.h"
#include "sim/fits/fitsout.h"
#include "sim/survey/wcs.h"

#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* The planes of a coadd (SCI, ERR, WHT) and its grid and filter. */
typedef struct plane3 {
    wf_wcs wcs;
    char filter[FLEN_VALUE];
    double mjd;
    float *sci, *err, *wht;
} plane3;

static void plane3_free(plane3 *p)
{
    free(p->sci);
    free(p->err);
    free(p->wht);
    memset(p, 0, sizeof *p);
}

static wf_status read_coadd(const char *path, const char *role, plane3 *p)
{
    memset(p, 0, sizeof *p);
    fitsfile *f;
    int status = 0;
    if (fits_open_diskfile(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening");
    wf_status st = WF_OK;
    if (fits_read_key_str(f, "FILTER", p->filter, NULL, &status)) {
        fits_clear_errmsg();
        st = wf_error(WF_ERR_INPUT, "%s: %s has no FILTER in its primary header", path, role);
        goto done;
    }
    const char *names[3] = {"SCI", "ERR", "WHT"};
    float **dst[3] = {&p->sci, &p->err, &p->wht};
    for (int k = 0; k < 3 && !st; k++) {
        if (fits_movnam_hdu(f, ANY_HDU, (char *)names[k], 0, &status)) {
            fits_clear_errmsg();
            st = wf_error(WF_ERR_INPUT, "%s: %s has no %s HDU (make the template with wfisim coadd)", path, role,
                          names[k]);
            break;
        }
        wf_wcs w;
        if ((st = wf_wcs_read_header(f, path, &w))) break;
        if (k == 0) p->wcs = w;
        else if (w.nx != p->wcs.nx || w.ny != p->wcs.ny) {
            st = wf_error(WF_ERR_INPUT, "%s: %s is not the size of SCI", path, names[k]);
            break;
        }
        size_t n = (size_t)w.nx * (size_t)w.ny;
        if (!(*dst[k] = malloc(n * sizeof **dst[k]))) {
            st = wf_error(WF_ERR_NOMEM, "%s: cannot allocate %s", path, names[k]);
            break;
        }
        if (fits_read_img(f, TFLOAT, 1, (LONGLONG)n, NULL, *dst[k], NULL, &status))
            st = wf_fits_error(status, path, "reading an image");
    }
done:
    fits_close_file(f, &status);
    fits_clear_errmsg();
    if (st) plane3_free(p);
    return st;
}

static wf_status epoch_header(const char *path, char *filter, double *mjd)
{
    fitsfile *f;
    int status = 0;
    if (fits_open_diskfile(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening the epoch");
    fits_read_key_str(f, "FILTER", filter, NULL, &status);
    fits_read_key_dbl(f, "MJD-OBS", mjd, NULL, &status);
    wf_status st = WF_OK;
    if (status) st = wf_error(WF_ERR_INPUT, "%s: the epoch has no FILTER or MJD-OBS in its primary header", path);
    status = 0;
    fits_close_file(f, &status);
    fits_clear_errmsg();
    return st;
}

static wf_status write_diff(const char *out, const plane3 *t, const char *tpath, const char *epath, double mjd,
                            float *sci, float *err, unsigned char *mask, long ngood)
{
    char tmp[1100];
    fitsfile *f;
    wf_status st = wf_fits_begin(out, tmp, sizeof tmp, &f);
    if (st) return st;
    int status = 0;
    long naxes[2] = {t->wcs.nx, t->wcs.ny};
    LONGLONG n = (LONGLONG)naxes[0] * naxes[1];
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_write_key_str(f, "FILTER", (char *)t->filter, "optical element", &status);
    fits_write_key_longstr(f, "TEMPLATE", (char *)tpath, "template (a coadd)", &status);
    fits_write_key_longstr(f, "EPOCH", (char *)epath, "epoch product", &status);
    fits_write_key_dbl(f, "MJD-OBS", mjd, -wf_fits_double_digits(mjd), "[d] the epoch's mid-time", &status);
    fits_write_key_lng(f, "NGOOD", ngood, "pixels with data in both", &status);
    fits_write_key_str(f, "PSFMATCH", "none", "no PSF matching (docs/ANALYSIS.md)", &status);
    fits_write_key_str(f, "ORIGIN", "wfisim diff", "software", &status);
    if (status) st = wf_fits_error(status, tmp, "writing the primary header");
    if (!st) st = wf_fits_reserve_checksum(f, tmp);
    const char *names[3] = {"SCI", "ERR", "MASK"};
    const char *comments[3] = {"epoch - template", "sqrt(ERR_epoch^2 + ERR_template^2)",
                               "1: no data in epoch or template"};
    for (int k = 0; k < 3 && !st; k++) {
        fits_create_img(f, k == 2 ? BYTE_IMG : FLOAT_IMG, 2, naxes, &status);
        fits_write_key_str(f, "EXTNAME", (char *)names[k], comments[k], &status);
        if (k < 2) fits_write_key_str(f, "BUNIT", "electron/s", "per template pixel", &status);
        if (status) {
            st = wf_fits_error(status, tmp, "creating an image HDU");
            break;
        }
        if ((st = wf_wcs_write_header(&t->wcs, f, tmp)) || (st = wf_fits_reserve_checksum(f, tmp))) break;
        if (k == 2) fits_write_img(f, TBYTE, 1, n, mask, &status);
        else fits_write_img(f, TFLOAT, 1, n, k ? err : sci, &status);
        if (status) st = wf_fits_error(status, tmp, "writing an image");
    }
    return wf_fits_finish(f, tmp, out, st);
}

wf_status wf_diff_run(const char *template_path, const char *epoch_path, const char *out, int quiet)
{
    plane3 t, e;
    wf_status st = read_coadd(template_path, "the template", &t);
    if (st) return st;
    char filter[FLEN_VALUE] = "";
    double mjd = 0;
    if ((st = epoch_header(epoch_path, filter, &mjd))) {
        plane3_free(&t);
        return st;
    }
    if (strcmp(filter, t.filter)) {
        st = wf_error(WF_ERR_INPUT, "diff: the epoch %s is filter %s but the template %s is %s", epoch_path, filter,
                      template_path, t.filter);
        plane3_free(&t);
        return st;
    }
    /* the epoch on the template's grid, through the coadd with pixfrac 1 */
    char rs[1100];
    if ((size_t)snprintf(rs, sizeof rs, "%s.epoch.fits", out) >= sizeof rs) {
        plane3_free(&t);
        return wf_error(WF_ERR_INPUT, "%s: path too long", out);
    }
    wf_coadd_opts o;
    wf_coadd_opts_default(&o);
    o.pixfrac = 1.0;
    o.quiet = quiet;
    const char *const paths[1] = {epoch_path};
    st = wf_coadd_run_grid(paths, 1, &o, &t.wcs, rs);
    if (st == WF_ERR_INPUT && strstr(wf_error_message(), "no input overlaps"))
        st = wf_error(WF_ERR_INPUT, "diff: the template %s overlaps nothing of the epoch %s", template_path,
                      epoch_path);
    if (!st) st = read_coadd(rs, "the resampled epoch", &e);
    unlink(rs);
    if (st) {
        plane3_free(&t);
        return st;
    }
    size_t n = (size_t)t.wcs.nx * (size_t)t.wcs.ny;
    float *sci = malloc(n * sizeof *sci), *err = malloc(n * sizeof *err);
    unsigned char *mask = malloc(n);
    long ngood = 0;
    if (!sci || !err || !mask) st = wf_error(WF_ERR_NOMEM, "diff: cannot allocate %zu pixels", n);
    for (size_t k = 0; !st && k < n; k++) {
        int good = e.wht[k] > 0 && t.wht[k] > 0;
        sci[k] = good ? e.sci[k] - t.sci[k] : 0.0f;
        err[k] = good ? (float)sqrt((double)e.err[k] * e.err[k] + (double)t.err[k] * t.err[k]) : 0.0f;
        mask[k] = (unsigned char)!good;
        ngood += good;
    }
    if (!st && ngood == 0)
        st = wf_error(WF_ERR_INPUT, "diff: the template %s and the epoch %s share no pixel with data", template_path,
                      epoch_path);
    if (!st) st = write_diff(out, &t, template_path, epoch_path, mjd, sci, err, mask, ngood);
    free(sci);
    free(err);
    free(mask);
    plane3_free(&t);
    plane3_free(&e);
    return st;
}

static const char *usage =
    "usage: wfisim diff --template COADD.fits --epoch PRODUCT.fits --out FILE [--quiet]\n"
    "  epoch minus template on the template's grid, no PSF matching (docs/ANALYSIS.md);\n"
    "  make the template with wfisim coadd (epochs chosen by date)\n";

int wf_cmd_diff(int argc, char **argv)
{
    const char *tpath = NULL, *epath = NULL, *out = NULL;
    int quiet = 0;
    for (int i = 0; i < argc; i++) {
        const char *k = argv[i];
        if (!strcmp(k, "--help") || !strcmp(k, "-h")) {
            fputs(usage, stdout);
            return 0;
        }
        if (!strcmp(k, "--quiet")) {
            quiet = 1;
            continue;
        }
        const char **dst = !strcmp(k, "--template") ? &tpath : !strcmp(k, "--epoch") ? &epath : !strcmp(k, "--out") ? &out : NULL;
        if (!dst) {
            fprintf(stderr, "wfisim diff: unknown argument '%s'\n%s", k, usage);
            return 2;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "wfisim diff: %s needs a value\n%s", k, usage);
            return 2;
        }
        *dst = argv[++i];
    }
    if (!tpath || !epath || !out) {
        fprintf(stderr, "wfisim diff: --template, --epoch and --out are required\n%s", usage);
        return 2;
    }
    wf_status st = wf_diff_run(tpath, epath, out, quiet);
    if (st) {
        fprintf(stderr, "wfisim diff: %s\n", wf_error_message());
        return st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
    }
    if (!quiet) fprintf(stderr, "wfisim diff: %s - %s -> %s\n", epath, tpath, out);
    return 0;
}
