/* `wfisim detect IMAGE --out CAT.fits [options]`: option parsing for analysis/detect.c. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "analysis/detect.h"

static const char *detect_usage =
    "usage: wfisim detect IMAGE --out CAT.fits [options]   (docs/ANALYSIS.md, \"Detection\")\n"
    "  IMAGE: a wfisim product or coadd (SCI in e-/s with a TAN or TAN-SIP WCS; ERR as the noise\n"
    "  and DQ as a mask when present). Defaults are SExtractor's.\n"
    "  --thresh S            detection threshold, in sigma of ERR [1.5]\n"
    "  --noise-scale S|auto  sigma = ERR x S; auto: S measured on the (filtered) image, for\n"
    "                        resampled images whose ERR leaves out pixel covariance [1]\n"
    "  --minarea N           minimum pixels above the threshold [5]\n"
    "  --back-size N         background mesh cell, pixels [64]\n"
    "  --back-filter N       median filter of the background mesh, cells [3]\n"
    "  --aperture-radius R   FLUX_APER radius: R or Rpx in pixels, Rarcsec in arcsec [2.5px]\n"
    "  --no-filter           threshold the image itself (default: the 3x3 pyramid filter)\n"
    "  --deblend-nthresh N   [32]      --deblend-mincont C   [0.005]\n"
    "  --kron F,RMIN         PHOT_AUTOPARAMS [2.5,3.5]\n"
    "  --data DIR            Roman data for the magnitude zero point [$WFISIM_DATA; none: top-hat]\n"
    "  --quiet               no summary line\n";

static int bad(const char *opt, const char *val, const char *why)
{
    fprintf(stderr, "wfisim detect: %s '%s': %s\n", opt, val ? val : "", why);
    return 2;
}

static int number(const char *opt, const char *val, double *out)
{
    char *end;
    if (!val) return bad(opt, val, "needs a value");
    *out = strtod(val, &end);
    if (end == val || *end || !isfinite(*out)) return bad(opt, val, "not a number");
    return 0;
}

static int integer(const char *opt, const char *val, int *out)
{
    double v;
    int rc = number(opt, val, &v);
    if (rc) return rc;
    if (v != floor(v) || fabs(v) > 1e9) return bad(opt, val, "not an integer");
    *out = (int)v;
    return 0;
}

/* "2.5", "2.5px", "2.5pix" in pixels; "0.3arcsec" or "0.3\"" in arcsec. */
static int radius(const char *val, wf_detect_options *o)
{
    char *end;
    if (!val) return bad("--aperture-radius", val, "needs a value");
    o->aper_radius = strtod(val, &end);
    if (end == val || !isfinite(o->aper_radius)) return bad("--aperture-radius", val, "not a number");
    if (!*end || !strcmp(end, "px") || !strcmp(end, "pix")) o->aper_arcsec = 0;
    else if (!strcmp(end, "arcsec") || !strcmp(end, "\"")) o->aper_arcsec = 1;
    else return bad("--aperture-radius", val, "unit must be px or arcsec");
    return 0;
}

int wf_cmd_detect(int argc, char **argv)
{
    wf_detect_options o;
    wf_detect_defaults(&o);
    const char *env = getenv("WFISIM_DATA");
    if (env) snprintf(o.data_dir, sizeof o.data_dir, "%s", env);
    const char *image = NULL, *out = NULL;
    int quiet = 0, rc = 0;
    for (int i = 0; i < argc && !rc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) { fputs(detect_usage, stdout); return 0; }
        else if (!strcmp(a, "--quiet")) quiet = 1;
        else if (!strcmp(a, "--no-filter")) o.filter = 0;
        else if (!strcmp(a, "--out")) { if (!v) return bad(a, v, "needs a file"); out = v; i++; }
        else if (!strcmp(a, "--thresh")) rc = number(a, v, &o.thresh), i++;
        else if (!strcmp(a, "--noise-scale")) {
            if (v && !strcmp(v, "auto")) o.noise_scale = 0.0, i++;
            else if (!(rc = number(a, v, &o.noise_scale)) && !(o.noise_scale > 0)) rc = bad(a, v, "must be > 0 or auto");
            else i++;
        } else if (!strcmp(a, "--minarea")) rc = integer(a, v, &o.minarea), i++;
        else if (!strcmp(a, "--back-size")) rc = integer(a, v, &o.back_size), i++;
        else if (!strcmp(a, "--back-filter")) rc = integer(a, v, &o.back_filter), i++;
        else if (!strcmp(a, "--aperture-radius")) rc = radius(v, &o), i++;
        else if (!strcmp(a, "--deblend-nthresh")) rc = integer(a, v, &o.deblend_nthresh), i++;
        else if (!strcmp(a, "--deblend-mincont")) rc = number(a, v, &o.deblend_cont), i++;
        else if (!strcmp(a, "--kron")) {
            if (!v || sscanf(v, "%lf,%lf", &o.kron_fact, &o.kron_minrad) != 2) return bad(a, v, "give F,RMIN");
            i++;
        } else if (!strcmp(a, "--data")) {
            if (!v) return bad(a, v, "needs a folder");
            snprintf(o.data_dir, sizeof o.data_dir, "%s", strcmp(v, "none") ? v : "");
            i++;
        } else if (a[0] == '-' && a[1] == '-') {
            fprintf(stderr, "wfisim detect: unknown option '%s'\n%s", a, detect_usage);
            return 2;
        } else if (!image) image = a;
        else { fprintf(stderr, "wfisim detect: unexpected argument '%s'\n", a); return 2; }
    }
    if (rc) return rc;
    if (!image || !out) { fputs(detect_usage, stderr); return 2; }
    wf_detect_summary s;
    wf_status st = wf_detect_file(image, out, &o, &s);
    if (st) {
        fprintf(stderr, "wfisim detect: %s\n", wf_error_message()[0] ? wf_error_message() : wf_status_name(st));
        return st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
    }
    if (!quiet)
        fprintf(stderr, "wfisim detect: %ld objects in %s (%d x %d, background %.4g +- %.3g e-/s, %ld pixels "
                "masked, noise x %.3f) -> %s\n", s.nobj, image, s.nx, s.ny, s.back, s.back_rms, s.masked, s.noise_scale, out);
    return 0;
}
