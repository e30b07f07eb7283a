#include "tools/psfcmd.h"

#include <errno.h>
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "sim/optics/bandpass.h"
#include "sim/optics/psf.h"
#include "sim/fits/fitsout.h"
#include "tools/config.h"

static const char *usage =
    "usage: wfisim psf --filter F --sca N [--pupil-bin 1|2|4|8] [--oversample K]\n"
    "                  [--wavelength NM | --sed flat [--nlambda N]] [--size PIX] [--x X --y Y]\n"
    "                  [--jitter ARCSEC] [--diffusion PX] [--pixel on|off] [--data DIR|none]\n"
    "                  [--render exact|galsim] --out FILE\n"
    "  PSF image normalised to unit flux, sampled every 0.11/K arcsec (pixel response when\n"
    "  K = 1), centred on the image centre; SCA position in GalSim pixels [2044 2044];\n"
    "  pupil_bin [4]; size [64 K]; masks and Zernikes from DIR/roman [$WFISIM_DATA].\n"
    "  --render galsim: as GalSim's FFT draw renders getPSF (its Quintic-interpolated\n"
    "  Nyquist image; peak -1.2%..+1.4% off the exact one) [exact].\n";

typedef struct psf_args {
    const char *filter, *out, *data, *sed, *pixel, *render;
    int sca, bin, over, size, nlambda;
    double lambda, x, y, jitter, diffusion;
} psf_args;

static int usage_error(const char *fmt, const char *what)
{
    fprintf(stderr, "wfisim psf: ");
    fprintf(stderr, fmt, what);
    fprintf(stderr, "\n%s", usage);
    return 2;
}

static int parse_long(const char *s, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (end == s || *end || errno || v < lo || v > hi) return -1;
    *out = v;
    return 0;
}

static int parse_double(const char *s, double *out)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (end == s || *end || errno || !isfinite(v)) return -1;
    *out = v;
    return 0;
}

static int parse_args(int argc, char **argv, psf_args *a)
{
    memset(a, 0, sizeof *a);
    a->bin = 4, a->over = 1, a->nlambda = 10, a->lambda = NAN;
    a->x = a->y = WF_SCA_NPIX / 2.0;
    int i0 = argc > 0 && !strcmp(argv[0], "psf") ? 1 : 0, have_x = 0, have_y = 0;
    for (int i = i0; i < argc; i++) {
        const char *k = argv[i];
        if (!strcmp(k, "--help") || !strcmp(k, "-h")) {
            fputs(usage, stdout);
            return -1;
        }
        if (strncmp(k, "--", 2)) return usage_error("unexpected argument '%s'", k);
        if (i + 1 >= argc) return usage_error("%s needs a value", k);
        const char *v = argv[++i];
        long n;
        double d;
        if (!strcmp(k, "--filter")) a->filter = v;
        else if (!strcmp(k, "--out")) a->out = v;
        else if (!strcmp(k, "--data")) a->data = v;
        else if (!strcmp(k, "--sed")) a->sed = v;
        else if (!strcmp(k, "--pixel")) a->pixel = v;
        else if (!strcmp(k, "--render")) a->render = v;
        else if (!strcmp(k, "--sca")) {
            if (parse_long(v, 1, 18, &n)) return usage_error("--sca '%s' is not 1..18", v);
            a->sca = (int)n;
        } else if (!strcmp(k, "--pupil-bin")) {
            if (parse_long(v, 1, 8, &n) || (n != 1 && n != 2 && n != 4 && n != 8))
                return usage_error("--pupil-bin '%s' is not 1, 2, 4 or 8", v);
            a->bin = (int)n;
        } else if (!strcmp(k, "--oversample")) {
            if (parse_long(v, 1, 64, &n)) return usage_error("--oversample '%s' is not 1..64", v);
            a->over = (int)n;
        } else if (!strcmp(k, "--size")) {
            if (parse_long(v, 1, 8192, &n)) return usage_error("--size '%s' is not 1..8192", v);
            a->size = (int)n;
        } else if (!strcmp(k, "--nlambda")) {
            if (parse_long(v, 1, WF_PSF_MAX_LAMBDAS, &n))
                return usage_error("--nlambda '%s' is not 1..64", v);
            a->nlambda = (int)n;
        } else if (!strcmp(k, "--wavelength")) {
            if (parse_double(v, &d) || !(d >= 100.0 && d <= 5000.0))
                return usage_error("--wavelength '%s' is not 100..5000 nm", v);
            a->lambda = d;
        } else if (!strcmp(k, "--x") || !strcmp(k, "--y")) {
            if (parse_double(v, &d) || fabs(d) > 1e5)
                return usage_error("--x/--y '%s' is not a pixel position", v);
            if (k[2] == 'x') a->x = d, have_x = 1;
            else a->y = d, have_y = 1;
        } else if (!strcmp(k, "--jitter")) {
            if (parse_double(v, &d) || d < 0 || d > 10)
                return usage_error("--jitter '%s' is not 0..10 arcsec", v);
            a->jitter = d;
        } else if (!strcmp(k, "--diffusion")) {
            if (parse_double(v, &d) || d < 0 || d > 10)
                return usage_error("--diffusion '%s' is not 0..10 pixels", v);
            a->diffusion = d;
        } else {
            return usage_error("unknown option '%s'", k);
        }
    }
    if (!a->filter) return usage_error("%s", "--filter is required");
    if (!a->sca) return usage_error("%s", "--sca is required");
    if (!a->out) return usage_error("%s", "--out is required");
    if (have_x != have_y) return usage_error("%s", "--x and --y go together");
    if (a->sed && strcmp(a->sed, "flat"))
        return usage_error("--sed '%s': only 'flat' (flat in f_nu) is known", a->sed);
    if (a->sed && !isnan(a->lambda))
        return usage_error("%s", "--wavelength (achromatic) and --sed (chromatic) exclude each other");
    if (a->pixel && strcmp(a->pixel, "on") && strcmp(a->pixel, "off"))
        return usage_error("--pixel '%s' is not on or off", a->pixel);
    if (a->render && strcmp(a->render, "exact") && strcmp(a->render, "galsim"))
        return usage_error("--render '%s' is not exact or galsim", a->render);
    if (!a->size) a->size = 64 * a->over;
    return 0;
}

static int fail(wf_status st)
{
    fprintf(stderr, "wfisim psf: %s\n",
            wf_error_message()[0] ? wf_error_message() : wf_status_name(st));
    return st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
}

static void key_dbl(fitsfile *f, const char *key, double v, const char *comment, int *status)
{
    fits_write_key_dbl(f, key, v, -wf_fits_double_digits(v), comment, status);
}

static void key_str(fitsfile *f, const char *key, const char *v, const char *comment, int *status)
{
    if (strlen(v) > 68) fits_write_key_longstr(f, key, v, comment, status);
    else fits_write_key_str(f, key, v, comment, status);
}

static wf_status write_fits(const psf_args *a, const wf_psf_info *info, const wf_psf_draw_opts *d,
                            const char *lam_source, const double *img, double secs)
{
    char tmp[4200];
    fitsfile *f = NULL;
    int status = 0;
    wf_status st = wf_fits_begin(a->out, tmp, sizeof tmp, &f);
    if (st) return st;
    long naxes[2] = {d->nx, d->ny};
    fits_create_img(f, DOUBLE_IMG, 2, naxes, &status);
    fits_write_key_str(f, "EXTNAME", "PSF", "point-spread function", &status);
    fits_write_key_str(f, "BUNIT", "flux", "fraction of unit flux per sample", &status);
    fits_write_key_str(f, "FILTER", a->filter, "WFI filter", &status);
    fits_write_key_lng(f, "SCA", a->sca, "sensor chip assembly, 1-18", &status);
    key_dbl(f, "SCA_X", a->x, "SCA position x, GalSim pixels (centre 2044)", &status);
    key_dbl(f, "SCA_Y", a->y, "SCA position y, GalSim pixels (centre 2044)", &status);
    fits_write_key_lng(f, "PUPILBIN", a->bin, "pupil_bin (binned mask samples)", &status);
    fits_write_key_str(f, "PUPBINRL", "any-open", "binned sample open if any is (GalSim)", &status);
    key_dbl(f, "PUPILDX", info->pupil_dx, "m per pupil sample", &status);
    fits_write_key_lng(f, "PUPILN", info->pupil_n, "pupil samples per side", &status);
    key_dbl(f, "PUPAREA", info->open_area, "open pupil area, m^2", &status);
    key_str(f, "PUPILSRC", info->pupil_source, "pupil mask or analytic model", &status);
    key_str(f, "ABERSRC", info->aberr_source, "Zernike aberrations", &status);
    for (int j = 4; j <= WF_ZERNIKE_MAX; j++) {
        char key[FLEN_KEYWORD];
        snprintf(key, sizeof key, "ZERN%d", j);
        key_dbl(f, key, info->zernike[j], "Noll Zernike, waves at 1293 nm", &status);
    }
    fits_write_key_lng(f, "OVERSAMP", a->over, "samples per 0.11 arcsec pixel", &status);
    key_dbl(f, "PIXSCALE", d->scale, "arcsec per sample", &status);
    fits_write_key_log(f, "PIXRESP", d->pixel, "integrated over the detector pixel", &status);
    key_dbl(f, "DETSCALE", d->det_scale, "arcsec per detector pixel", &status);
    key_dbl(f, "JITTER", d->jitter, "Gaussian jitter sigma per axis, arcsec", &status);
    key_dbl(f, "DIFFUSN", d->diffusion, "charge diffusion sigma, detector pixels", &status);
    fits_write_key_str(f, "RENDER", d->galsim ? "galsim" : "exact",
                       d->galsim ? "GalSim's Quintic on its Nyquist grid" : "exact Fourier sum",
                       &status);
    if (d->galsim)
        fits_write_key_lng(f, "GSPUPILN", info->galsim_n, "GalSim grid: lambda/(GSPUPILN PUPILDX)",
                           &status);
    key_dbl(f, "CENTERX", d->cx + 1, "FITS x of the PSF centre (1-based)", &status);
    key_dbl(f, "CENTERY", d->cy + 1, "FITS y of the PSF centre (1-based)", &status);
    fits_write_key_str(f, "MODE", info->nlambda > 1 ? "chromatic" : "achromatic",
                       "one wavelength or a weighted sum", &status);
    key_dbl(f, "LAM_NM", info->lambda_mean_nm, "wavelength (weighted mean), nm", &status);
    key_str(f, "LAMSRC", lam_source, "where the wavelength came from", &status);
    fits_write_key_lng(f, "NLAMBDA", info->nlambda, "wavelengths summed", &status);
    if (info->nlambda > 1)
        for (int k = 0; k < info->nlambda; k++) {
            char key[FLEN_KEYWORD];
            snprintf(key, sizeof key, "LAM%d", k + 1);
            key_dbl(f, key, info->lambda_nm[k], "nm", &status);
            snprintf(key, sizeof key, "WGT%d", k + 1);
            key_dbl(f, key, info->weight[k], "weight (sum 1)", &status);
        }
    if (a->sed) fits_write_key_str(f, "SED", a->sed, "flat: flat in f_nu", &status);
    key_dbl(f, "PERIOD", info->period_arcsec, "arcsec: lambda/dx, PSF zero beyond half", &status);
    fits_write_key_lng(f, "FFTNX", info->fft_nx, "FFT grid of the OTF build", &status);
    fits_write_key_lng(f, "FFTNY", info->fft_ny, "FFT grid of the OTF build", &status);
    fits_write_key_str(f, "NORM", "unit flux", "before truncation to the stamp", &status);
    double sum = 0;
    for (long i = 0; i < naxes[0] * naxes[1]; i++) sum += img[i];
    key_dbl(f, "STAMPSUM", sum, "sum of this stamp", &status);
    key_dbl(f, "BUILDSEC", round(secs * 1000) / 1000, "build + draw time, s", &status);
    fits_write_key_str(f, "CREATOR", "wfisim psf", "sim/optics/psf.c, docs/OPTICS.md", &status);
    st = wf_fits_error(status, tmp, "writing the header");
    if (!st) st = wf_fits_reserve_checksum(f, tmp);
    if (!st) {
        long fp[2] = {1, 1};
        fits_write_pix(f, TDOUBLE, fp, (LONGLONG)naxes[0] * naxes[1], (void *)img, &status);
        st = wf_fits_error(status, tmp, "writing the image");
    }
    return wf_fits_finish(f, tmp, a->out, st);
}

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

int wf_cmd_psf(int argc, char **argv)
{
    psf_args a;
    int rc = parse_args(argc, argv, &a);
    if (rc) return rc < 0 ? 0 : rc;

    wf_filter filter;
    wf_status st = wf_filter_parse(a.filter, &filter);
    if (st) return fail(st);
    a.filter = wf_filter_name(filter);
    wf_psf_optics o;
    wf_psf_optics_default(&o);
    o.sca = a.sca, o.pupil_bin = a.bin, o.x = a.x, o.y = a.y;
    if ((st = wf_pupil_group_of_filter(a.filter, &o.group))) return fail(st);
    if (a.data && strcmp(a.data, "none") && (st = wf_config_check_dir("--data", a.data))) return fail(st);
    const char *data = a.data ? a.data : getenv("WFISIM_DATA");
    if (data && *data && strcmp(data, "none")) {
        if (strlen(data) >= sizeof o.data_dir) {
            wf_error(WF_ERR_INPUT, "--data path is longer than %zu bytes", sizeof o.data_dir - 1);
            return fail(WF_ERR_INPUT);
        }
        snprintf(o.data_dir, sizeof o.data_dir, "%s", data);
    }

    double lam[WF_PSF_MAX_LAMBDAS], w[WF_PSF_MAX_LAMBDAS];
    int nl = 1;
    char lam_source[WF_BANDPASS_SOURCE_MAX + 64];
    if (!isnan(a.lambda)) {
        lam[0] = a.lambda, w[0] = 1;
        snprintf(lam_source, sizeof lam_source, "--wavelength");
    } else {
        wf_bandpass *bp = malloc(sizeof *bp);
        if (!bp) {
            wf_error(WF_ERR_NOMEM, "cannot allocate a bandpass");
            return fail(WF_ERR_NOMEM);
        }
        if ((st = wf_bandpass_load(filter, o.data_dir[0] ? o.data_dir : NULL, bp))) {
            free(bp);
            return fail(st);
        }
        if (a.sed) {
            nl = a.nlambda;
            st = wf_bandpass_flat_slices(bp, nl, lam, w);
            snprintf(lam_source, sizeof lam_source, "%d slices of the bandpass, T/lambda: %s", nl,
                     bp->source);
        } else {
            lam[0] = bp->lambda_eff_nm, w[0] = 1;
            snprintf(lam_source, sizeof lam_source, "effective wavelength of %s", bp->source);
        }
        free(bp);
        if (st) return fail(st);
    }

    double t0 = now_s();
    wf_psf *psf;
    if ((st = wf_psf_build_optics(&o, lam, w, nl, &psf))) return fail(st);
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = a.size;
    d.cx = d.cy = 0.5 * (a.size - 1); /* GalSim's drawImage centre */
    d.scale = WF_PSF_PIXEL_SCALE / a.over;
    d.pixel = a.pixel ? !strcmp(a.pixel, "on") : a.over == 1;
    d.jitter = a.jitter, d.diffusion = a.diffusion;
    d.galsim = a.render && !strcmp(a.render, "galsim");
    double *img = malloc((size_t)a.size * a.size * sizeof(double));
    if (!img) {
        wf_psf_free(psf);
        wf_error(WF_ERR_NOMEM, "cannot allocate a %dx%d image", a.size, a.size);
        return fail(WF_ERR_NOMEM);
    }
    st = wf_psf_draw(psf, &d, img);
    double secs = now_s() - t0;
    wf_psf_info info;
    if (!st) st = wf_psf_get_info(psf, &info);
    if (!st) st = write_fits(&a, &info, &d, lam_source, img, secs);
    wf_psf_free(psf);
    free(img);
    if (st) return fail(st);
    fprintf(stderr, "wfisim psf: %s SCA %d %s %.2f nm, %dx%d at %.5g\", pupil_bin %d: %.3f s -> %s\n",
            a.filter, a.sca, info.nlambda > 1 ? "chromatic mean" : "at", info.lambda_mean_nm,
            a.size, a.size, d.scale, a.bin, secs, a.out);
    return 0;
}
