/* `wfisim detect`: SEP's background, extraction and photometry on a wfisim image, written as a
 * FITS catalog. SEP is SExtractor's own code made a library, so what is here is input (reading
 * the planes, the mask, the WCS) and output (the table); the defaults are SExtractor's. */
#include "analysis/detect.h"

#include <fitsio.h>
#include <math.h>
#include <sep.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hal/dq.h"
#include "sim/optics/bandpass.h"
#include "sim/fits/fitsout.h"
#include "sim/survey/wcs.h"

#define DEG (M_PI / 180.0)

void wf_detect_defaults(wf_detect_options *o)
{
    memset(o, 0, sizeof *o);
    o->thresh = 1.5;
    o->noise_scale = 1.0;
    o->minarea = 5;
    o->back_size = 64;
    o->back_filter = 3;
    o->aper_radius = 2.5;
    o->aper_arcsec = 0;
    o->filter = 1;
    o->deblend_nthresh = 32;
    o->deblend_cont = 0.005;
    o->kron_fact = 2.5;
    o->kron_minrad = 3.5;
}

static wf_status check_options(const wf_detect_options *o)
{
    if (!(o->thresh > 0) || !isfinite(o->thresh)) return wf_error(WF_ERR_INPUT, "--thresh %g: must be > 0", o->thresh);
    if (!(o->noise_scale >= 0) || !isfinite(o->noise_scale))
        return wf_error(WF_ERR_INPUT, "--noise-scale %g: must be > 0 or auto", o->noise_scale);
    if (o->minarea < 1) return wf_error(WF_ERR_INPUT, "--minarea %d: must be >= 1", o->minarea);
    if (o->back_size < 1) return wf_error(WF_ERR_INPUT, "--back-size %d: must be >= 1", o->back_size);
    if (o->back_filter < 1) return wf_error(WF_ERR_INPUT, "--back-filter %d: must be >= 1", o->back_filter);
    if (!(o->aper_radius > 0) || !isfinite(o->aper_radius))
        return wf_error(WF_ERR_INPUT, "--aperture-radius %g: must be > 0", o->aper_radius);
    if (o->deblend_nthresh < 1) return wf_error(WF_ERR_INPUT, "--deblend-nthresh %d: must be >= 1", o->deblend_nthresh);
    if (!(o->deblend_cont >= 0 && o->deblend_cont <= 1))
        return wf_error(WF_ERR_INPUT, "--deblend-mincont %g: must be in [0, 1]", o->deblend_cont);
    if (!(o->kron_fact > 0) || !(o->kron_minrad >= 0)) return wf_error(WF_ERR_INPUT, "Kron parameters must be positive");
    return WF_OK;
}

static wf_status sep_fail(int code, const char *path, const char *doing)
{
    char msg[80], detail[600];
    sep_get_errmsg(code, msg);
    sep_get_errdetail(detail);
    return wf_error(code == 1 ? WF_ERR_NOMEM : WF_ERR_INPUT, "%s: %s: SEP: %s%s%s", path, doing, msg,
                    detail[0] ? ": " : "", detail);
}

/* What the catalog header repeats from the image. */
typedef struct image_facts {
    char filter[FLEN_VALUE];
    double exptime, mjd;
    long sca;
} image_facts;

/* Reads the keywords of the current HDU that are there, leaving the others as they are. */
static void read_facts(fitsfile *f, image_facts *k)
{
    int status = 0;
    char s[FLEN_VALUE];
    if (!k->filter[0] && !fits_read_key_str(f, "FILTER", s, NULL, &status)) snprintf(k->filter, sizeof k->filter, "%s", s);
    status = 0;
    if (isnan(k->exptime) && fits_read_key_dbl(f, "EXPTIME", &k->exptime, NULL, &status)) k->exptime = NAN;
    status = 0;
    if (isnan(k->mjd) && fits_read_key_dbl(f, "MJD-OBS", &k->mjd, NULL, &status)) k->mjd = NAN;
    status = 0;
    if (k->sca <= 0 && fits_read_key_lng(f, "SCA", &k->sca, NULL, &status)) k->sca = 0;
    status = 0;
    if (k->sca <= 0 && fits_read_key_lng(f, "SCA_NUM", &k->sca, NULL, &status)) k->sca = 0;
    fits_clear_errmsg();
}

/* Moves to the image HDU called name: 1 found, 0 absent. */
static int goto_hdu(fitsfile *f, const char *name)
{
    int status = 0;
    if (fits_movnam_hdu(f, ANY_HDU, (char *)name, 0, &status)) {
        fits_clear_errmsg();
        return 0;
    }
    return 1;
}

/* One nx x ny plane of the current HDU as type (TFLOAT, TUINT). */
static wf_status read_plane(fitsfile *f, const char *path, const char *name, int nx, int ny, int type, void *buf)
{
    int status = 0, naxis = 0;
    long nax[2] = {0, 0};
    if (fits_get_img_dim(f, &naxis, &status) || naxis != 2 || fits_get_img_size(f, 2, nax, &status)) {
        fits_clear_errmsg();
        return wf_error(WF_ERR_INPUT, "%s: HDU %s is not a 2-d image", path, name);
    }
    if (nax[0] != nx || nax[1] != ny)
        return wf_error(WF_ERR_INPUT, "%s: HDU %s is %ld x %ld, SCI %d x %d", path, name, nax[0], nax[1], nx, ny);
    long first[2] = {1, 1};
    int anynul = 0;
    fits_read_pix(f, type, first, (LONGLONG)nx * ny, NULL, buf, &anynul, &status);
    return wf_fits_error(status, path, name);
}

typedef struct planes {
    int nx, ny;
    float *sci, *err;      /* err: ERR, else SEP's background RMS map */
    unsigned char *mask;   /* 1: ignored */
    int have_err, have_dq;
    wf_wcs wcs;
    image_facts facts;
} planes;

static void planes_free(planes *p)
{
    free(p->sci);
    free(p->err);
    free(p->mask);
}

static wf_status read_image(const char *path, planes *p)
{
    memset(p, 0, sizeof *p);
    p->facts.exptime = p->facts.mjd = NAN;
    fitsfile *f = NULL;
    int status = 0;
    if (fits_open_file(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening the image");
    wf_status st = WF_OK;
    const char *sci_name = "SCI";
    if (!goto_hdu(f, "SCI")) {
        sci_name = "primary";
        int naxis = 0;
        fits_movabs_hdu(f, 1, NULL, &status);
        if (status || fits_get_img_dim(f, &naxis, &status) || naxis != 2) {
            fits_clear_errmsg();
            st = wf_error(WF_ERR_INPUT, "%s: no SCI HDU and the primary HDU is not a 2-d image", path);
        }
    }
    long nax[2] = {0, 0};
    if (!st && fits_get_img_size(f, 2, nax, &status)) st = wf_fits_error(status, path, "reading SCI's size");
    if (!st && (nax[0] < 1 || nax[1] < 1 || nax[0] > 100000 || nax[1] > 100000))
        st = wf_error(WF_ERR_INPUT, "%s: %s is %ld x %ld pixels", path, sci_name, nax[0], nax[1]);
    if (!st) st = wf_wcs_read_header(f, path, &p->wcs);
    size_t n = (size_t)nax[0] * (size_t)nax[1];
    p->nx = (int)nax[0], p->ny = (int)nax[1];
    if (!st) {
        read_facts(f, &p->facts);
        p->sci = malloc(n * sizeof *p->sci);
        p->err = malloc(n * sizeof *p->err);
        p->mask = calloc(n, 1);
        if (!p->sci || !p->err || !p->mask) st = wf_error(WF_ERR_NOMEM, "%s: out of memory for %zu pixels", path, n);
    }
    if (!st) st = read_plane(f, path, sci_name, p->nx, p->ny, TFLOAT, p->sci);
    if (!st && goto_hdu(f, "ERR")) {
        p->have_err = 1;
        st = read_plane(f, path, "ERR", p->nx, p->ny, TFLOAT, p->err);
    }
    if (!st && goto_hdu(f, "DQ")) {
        unsigned int *dq = malloc(n * sizeof *dq);
        if (!dq) st = wf_error(WF_ERR_NOMEM, "%s: out of memory for DQ", path);
        if (!st) st = read_plane(f, path, "DQ", p->nx, p->ny, TUINT, dq);
        for (size_t i = 0; !st && i < n; i++) p->mask[i] = (dq[i] & WF_DQ_DO_NOT_USE) != 0;
        p->have_dq = 1;
        free(dq);
    }
    if (!st) { /* the exposure's facts live in the primary header of a wfisim product */
        status = 0;
        if (!fits_movabs_hdu(f, 1, NULL, &status)) read_facts(f, &p->facts);
        fits_clear_errmsg();
    }
    status = 0;
    fits_close_file(f, &status);
    if (st) planes_free(p);
    return st;
}

/* The position angle (deg east of north, [0, 180)) of the image direction theta (radians
 * counter-clockwise from +x) at pixel (x, y), from a 1-pixel step through the WCS. */
static double sky_angle(const wf_wcs *w, double x, double y, double theta)
{
    double ra0, dec0, ra1, dec1;
    if (wf_wcs_pix2world(w, x, y, &ra0, &dec0) ||
        wf_wcs_pix2world(w, x + cos(theta), y + sin(theta), &ra1, &dec1))
        return NAN;
    double dra = remainder(ra1 - ra0, 360.0) * cos(dec0 * DEG), ddec = dec1 - dec0;
    double pa = atan2(dra, ddec) / DEG;
    pa = fmod(pa + 360.0, 180.0);
    return pa;
}

enum { COL_ID, COL_X, COL_Y, COL_RA, COL_DEC, COL_FAPER, COL_EAPER, COL_MAPER, COL_FAUTO, COL_EAUTO, COL_MAUTO,
       COL_KRON, COL_A, COL_B, COL_THETA, COL_PASKY, COL_AREA, COL_FISO, COL_PEAK, COL_FLAGS, NCOL };

static char *ttype[NCOL] = {"ID", "X", "Y", "RA", "DEC", "FLUX_APER", "FLUXERR_APER", "MAG_APER", "FLUX_AUTO",
                            "FLUXERR_AUTO", "MAG_AUTO", "KRON_RADIUS", "A", "B", "THETA", "PA_SKY", "ISOAREA",
                            "FLUX_ISO", "PEAK", "FLAGS"};
static char *tform[NCOL] = {"J", "D", "D", "D", "D", "D", "D", "D", "D", "D", "D", "D", "D", "D", "D", "D", "J",
                            "D", "D", "J"};
static char *tunit[NCOL] = {"", "pixel", "pixel", "deg", "deg", "electron/s", "electron/s", "mag(AB)",
                            "electron/s", "electron/s", "mag(AB)", "", "pixel", "pixel", "deg", "deg", "pixel",
                            "electron/s", "electron/s", ""};

/* The measured columns, one array per column of doubles (ID, ISOAREA and FLAGS as long). */
typedef struct columns {
    long n;
    double *d[NCOL];
    long *id, *area, *flags;
} columns;

static void columns_free(columns *c)
{
    for (int k = 0; k < NCOL; k++) free(c->d[k]);
    free(c->id);
    free(c->area);
    free(c->flags);
}

static double magnitude(double zp, double flux)
{
    return flux > 0 && isfinite(zp) ? zp - 2.5 * log10(flux) : NAN;
}

static wf_status measure(const char *path, planes *p, const wf_detect_options *o, double zp, double aper_px,
                         columns *c, wf_detect_summary *sum)
{
    size_t n = (size_t)p->nx * p->ny;
    sep_image im;
    memset(&im, 0, sizeof im);
    im.data = p->sci, im.dtype = SEP_TFLOAT;
    im.mask = p->mask, im.mdtype = SEP_TBYTE, im.maskthresh = 0.0;
    im.w = p->nx, im.h = p->ny;
    /* Bad pixels are masked, and given values that cannot poison a sum SEP makes over them. */
    long masked = 0;
    for (size_t i = 0; i < n; i++) {
        int bad = p->mask[i] || !isfinite(p->sci[i]) || (p->have_err && !(p->err[i] > 0 && isfinite(p->err[i])));
        if (bad) p->mask[i] = 1, masked++;
    }
    if ((size_t)masked == n) return wf_error(WF_ERR_INPUT, "%s: every pixel is masked (DQ or non-finite)", path);
    for (size_t i = 0; i < n; i++)
        if (p->mask[i]) p->sci[i] = 0.0f;
    sep_bkg *bkg = NULL;
    int rc = sep_background(&im, o->back_size, o->back_size, o->back_filter, o->back_filter, 0.0, &bkg);
    if (rc) return sep_fail(rc, path, "background");
    sum->back = sep_bkg_global(bkg);
    sum->back_rms = sep_bkg_globalrms(bkg);
    rc = sep_bkg_subarray(bkg, p->sci, SEP_TFLOAT);
    /* Without ERR the noise is the background mesh's RMS, as SExtractor's without a weight map. */
    if (!rc && !p->have_err) rc = sep_bkg_rmsarray(bkg, p->err, SEP_TFLOAT);
    sep_bkg_free(bkg);
    if (rc) return sep_fail(rc, path, "background subtraction");
    for (size_t i = 0; i < n; i++)
        if (p->mask[i]) p->sci[i] = 0.0f, p->err[i] = (float)sum->back_rms;
    sum->masked = masked;
    sum->nx = p->nx, sum->ny = p->ny;

    /* ERR holds the sources' shot noise already, so no gain term is added (SExtractor's GAIN 0
     * with a MAP_RMS weight). At the isophote a source adds ~1.5 sigma to a sky-dominated pixel,
     * so thresholds there are the background's. */
    im.noise = p->err, im.ndtype = SEP_TFLOAT, im.noise_type = SEP_NOISE_STDDEV, im.gain = 0.0;
    sum->noise_scale = o->noise_scale;
    if (o->noise_scale == 0.0) {
        long used;
        wf_status st = wf_detect_noise_ratio(p->sci, p->err, p->mask, p->nx, p->ny, o->filter, &sum->noise_scale, &used);
        if (st) return wf_error(st, "%s: %s", path, wf_error_message());
    }
    static const float pyramid[9] = {1, 2, 1, 2, 4, 2, 1, 2, 1};
    size_t stack = n / 8 > 300000 ? n / 8 : 300000; /* pixels of objects being followed at once */
    sep_set_extract_pixstack(stack);
    sep_catalog *cat = NULL;
    rc = sep_extract(&im, (float)(o->thresh * sum->noise_scale), SEP_THRESH_REL, o->minarea, o->filter ? pyramid : NULL, 3, 3,
                     SEP_FILTER_CONV, o->deblend_nthresh, o->deblend_cont, 1, 1.0, &cat);
    if (rc) return sep_fail(rc, path, "extraction");
    memset(c, 0, sizeof *c);
    c->n = cat->nobj;
    size_t m = cat->nobj > 0 ? (size_t)cat->nobj : 1;
    int ok = 1;
    for (int k = 0; k < NCOL; k++) ok &= (c->d[k] = calloc(m, sizeof(double))) != NULL;
    ok &= (c->id = calloc(m, sizeof(long))) != NULL;
    ok &= (c->area = calloc(m, sizeof(long))) != NULL;
    ok &= (c->flags = calloc(m, sizeof(long))) != NULL;
    /* The segmentation map lets AUTO photometry replace the pixels of neighbours by their
     * mirror image through the object's centre, as SExtractor's MASK_TYPE CORRECT does. */
    int *seg = calloc(n, sizeof *seg);
    ok &= seg != NULL;
    wf_status st = ok ? WF_OK : wf_error(WF_ERR_NOMEM, "%s: out of memory for %d objects", path, cat->nobj);
    for (int i = 0; !st && i < cat->nobj; i++)
        for (int k = 0; k < cat->npix[i]; k++) seg[cat->pix[i][k]] = i + 1;
    sep_image ima = im; /* the same image with the segmentation map */
    ima.segmap = seg, ima.sdtype = SEP_TINT;
    for (int i = 0; !st && i < cat->nobj; i++) {
        double x = cat->x[i], y = cat->y[i], a = cat->a[i], b = cat->b[i], th = cat->theta[i];
        /* SEP's theta is a float: an axis along y comes back as +-1.57079637, past pi/2, which
         * SEP's own ellipse sums refuse and the catalog's (-90, 90] excludes; the same axis
         * half a turn round is inside both. */
        if (th > M_PI / 2) th -= M_PI;
        else if (th < -M_PI / 2) th += M_PI;
        short flag = cat->flag[i], f1 = 0, f2 = 0, f3 = 0;
        double s, se, area, ra, dec;
        c->id[i] = i + 1;
        c->d[COL_X][i] = x + 1.0, c->d[COL_Y][i] = y + 1.0; /* SEP's 0-based -> FITS */
        if ((st = wf_wcs_pix2world(&p->wcs, x, y, &ra, &dec))) break;
        c->d[COL_RA][i] = ra, c->d[COL_DEC][i] = dec;
        rc = sep_sum_circle(&im, x, y, aper_px, 0, 5, 0, &s, &se, &area, &f1);
        if (rc) { st = sep_fail(rc, path, "aperture photometry"); break; }
        c->d[COL_FAPER][i] = s, c->d[COL_EAPER][i] = se, c->d[COL_MAPER][i] = magnitude(zp, s);
        /* AUTO as SExtractor: the first moment of radius within 6 isophotal ellipses gives the
         * Kron radius; the aperture is kron_fact times it, at least kron_minrad. */
        double kr = 0.0, r;
        rc = sep_kron_radius(&ima, x, y, cat->cxx[i], cat->cyy[i], cat->cxy[i], 6.0, i + 1, &kr, &f2);
        if (rc) { st = sep_fail(rc, path, "Kron radius"); break; }
        r = o->kron_fact * kr;
        if (!(r >= o->kron_minrad)) r = o->kron_minrad;
        if (!(a > 0) || !(b > 0)) s = se = NAN;
        else if ((rc = sep_sum_ellipse(&ima, x, y, a, b, th, r, i + 1, 1, 0, &s, &se, &area, &f3))) {
            st = sep_fail(rc, path, "Kron photometry");
            break;
        }
        c->d[COL_FAUTO][i] = s, c->d[COL_EAUTO][i] = se, c->d[COL_MAUTO][i] = magnitude(zp, s);
        c->d[COL_KRON][i] = r; /* SExtractor's KRON_RADIUS: the aperture, in units of a and b */
        c->d[COL_A][i] = a, c->d[COL_B][i] = b, c->d[COL_THETA][i] = th / DEG;
        c->d[COL_PASKY][i] = sky_angle(&p->wcs, x, y, th);
        c->area[i] = cat->tnpix[i];
        c->d[COL_FISO][i] = cat->flux[i];
        c->d[COL_PEAK][i] = cat->peak[i];
        c->flags[i] = flag | f1 | f2 | f3; /* object flags 0x1-0x8, aperture flags 0x10-0x80 */
    }
    sep_catalog_free(cat);
    free(seg);
    if (st) columns_free(c);
    return st;
}

static void key_dbl(fitsfile *f, const char *key, double v, const char *comment, int *status)
{
    if (isfinite(v)) fits_write_key_dbl(f, key, v, -wf_fits_double_digits(v), comment, status);
}

static wf_status write_catalog(const char *out_path, const char *image_path, const planes *p,
                               const wf_detect_options *o, double aper_px, double pixscale, double zp,
                               const char *zp_source, const columns *c, const wf_detect_summary *sum)
{
    char tmp[4200];
    fitsfile *f = NULL;
    wf_status st = wf_fits_begin(out_path, tmp, sizeof tmp, &f);
    if (st) return st;
    int status = 0;
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_create_tbl(f, BINARY_TBL, c->n, NCOL, ttype, tform, tunit, "CATALOG", &status);
    const char *base = strrchr(image_path, '/');
    fits_write_key_longstr(f, "IMAGE", base ? base + 1 : image_path, "image measured", &status);
    fits_write_key_str(f, "ORIGIN", "wfisim detect (SEP)", "software", &status);
    fits_write_key_str(f, "SEPVERS", sep_version_string, "SEP library version", &status);
    if (p->facts.filter[0]) fits_write_key_str(f, "FILTER", p->facts.filter, "optical element", &status);
    key_dbl(f, "EXPTIME", p->facts.exptime, "[s] exposure time", &status);
    key_dbl(f, "MJD-OBS", p->facts.mjd, "[d] exposure mid-time", &status);
    if (p->facts.sca > 0) fits_write_key_lng(f, "SCA", p->facts.sca, "sensor chip assembly", &status);
    fits_write_key_lng(f, "NAXIS1IM", p->nx, "image columns", &status);
    fits_write_key_lng(f, "NAXIS2IM", p->ny, "image rows", &status);
    fits_write_key_log(f, "HAVEERR", p->have_err, "T: noise from ERR; F: background RMS map", &status);
    fits_write_key_log(f, "HAVEDQ", p->have_dq, "T: DQ DO_NOT_USE pixels masked", &status);
    fits_write_key_lng(f, "NMASKED", sum->masked, "pixels masked", &status);
    key_dbl(f, "DETTHR", o->thresh, "[sigma] detection threshold (DETECT_THRESH)", &status);
    key_dbl(f, "NOISESCL", sum->noise_scale, "sigma = ERR x this (measured when AUTONOIS)", &status);
    fits_write_key_log(f, "AUTONOIS", o->noise_scale == 0.0, "T: NOISESCL measured on the image", &status);
    fits_write_key_lng(f, "MINAREA", o->minarea, "[pixel] DETECT_MINAREA", &status);
    fits_write_key_log(f, "FILTERED", o->filter, "T: 3x3 pyramid filter before thresholding", &status);
    fits_write_key_lng(f, "BACKSIZE", o->back_size, "[pixel] background mesh (BACK_SIZE)", &status);
    fits_write_key_lng(f, "BACKFILT", o->back_filter, "[mesh] BACK_FILTERSIZE", &status);
    fits_write_key_lng(f, "DEBNTHR", o->deblend_nthresh, "DEBLEND_NTHRESH", &status);
    key_dbl(f, "DEBMINC", o->deblend_cont, "DEBLEND_MINCONT", &status);
    key_dbl(f, "APERRAD", aper_px, "[pixel] FLUX_APER radius", &status);
    key_dbl(f, "KRONFACT", o->kron_fact, "PHOT_AUTOPARAMS Kron factor", &status);
    key_dbl(f, "KRONMIN", o->kron_minrad, "PHOT_AUTOPARAMS minimum radius", &status);
    key_dbl(f, "PIXSCALE", pixscale, "[arcsec/pixel] from the WCS CD matrix", &status);
    key_dbl(f, "BKG", sum->back, "[electron/s] global background", &status);
    key_dbl(f, "BKGRMS", sum->back_rms, "[electron/s] global background RMS", &status);
    key_dbl(f, "MAGZP", zp, "AB mag of 1 electron/s in FILTER", &status);
    fits_write_key_longstr(f, "MAGZPSRC", zp_source, "bandpass of the zero point", &status);
    fits_write_key_str(f, "PIXCONV", "FITS", "X, Y: 1-based pixel centres, as the truth tables", &status);
    fits_write_comment(f, "THETA: major axis, deg counter-clockwise from image +x (THETA_IMAGE)", &status);
    fits_write_comment(f, "PA_SKY: the major axis's position angle, deg east of north", &status);
    fits_write_comment(f, "FLAGS: SEP object 1 merged 2 truncated 8 singular; aperture 16 truncated 32 "
                          "masked pixels 64 all masked 128 nonpositive", &status);
    if (c->n > 0) {
        fits_write_col(f, TLONG, COL_ID + 1, 1, 1, c->n, c->id, &status);
        for (int k = 0; k < NCOL; k++)
            if (k != COL_ID && k != COL_AREA && k != COL_FLAGS)
                fits_write_colnull(f, TDOUBLE, k + 1, 1, 1, c->n, c->d[k], NULL, &status);
        fits_write_col(f, TLONG, COL_AREA + 1, 1, 1, c->n, c->area, &status);
        fits_write_col(f, TLONG, COL_FLAGS + 1, 1, 1, c->n, c->flags, &status);
    }
    return wf_fits_finish(f, tmp, out_path, wf_fits_error(status, tmp, "writing the catalog"));
}

wf_status wf_detect_file(const char *image_path, const char *out_path, const wf_detect_options *o,
                         wf_detect_summary *sum)
{
    memset(sum, 0, sizeof *sum);
    wf_status st = check_options(o);
    if (st) return st;
    planes p;
    if ((st = read_image(image_path, &p))) return st;
    double pixscale = sqrt(fabs(p.wcs.cd[0][0] * p.wcs.cd[1][1] - p.wcs.cd[0][1] * p.wcs.cd[1][0])) * 3600.0;
    double aper_px = o->aper_arcsec ? o->aper_radius / pixscale : o->aper_radius;
    /* The AB zero point of the image's filter (a coadd or foreign image without FILTER: none). */
    double zp = NAN;
    char zp_source[WF_BANDPASS_SOURCE_MAX] = "none: no FILTER keyword";
    wf_filter filt;
    if (p.facts.filter[0] && wf_filter_lookup(p.facts.filter, &filt)) {
        wf_bandpass *bp = malloc(sizeof *bp);
        if (!bp) st = wf_error(WF_ERR_NOMEM, "out of memory");
        if (!st) st = wf_bandpass_load(filt, o->data_dir[0] ? o->data_dir : NULL, bp);
        if (!st) zp = bp->zp_ab, snprintf(zp_source, sizeof zp_source, "%s", bp->source);
        free(bp);
    }
    columns c;
    memset(&c, 0, sizeof c);
    if (!st) st = measure(image_path, &p, o, zp, aper_px, &c, sum);
    if (!st) {
        sum->nobj = c.n;
        st = write_catalog(out_path, image_path, &p, o, aper_px, pixscale, zp, zp_source, &c, sum);
        columns_free(&c);
    }
    planes_free(&p);
    return st;
}
