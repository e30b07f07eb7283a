#include "tools/sncmd.h"

#include <ctype.h>
#include <errno.h>
#include <fitsio.h>
#include <inttypes.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <zlib.h>

#include "sim/optics/bandpass.h"
#include "sim/survey/catalog.h"
#include "sim/sn/cosmology.h"
#include "sim/fits/fitsout.h"
#include "sim/sn/hostlib.h"
#include "sim/sn/salt.h"
#include "sim/sn/sncat.h"
#include "sim/sn/snhost.h"
#include "sim/sn/snpop.h"
#include "sim/sn/snrate.h"
#include "sim/survey/survey.h"
#include "sim/survey/synth.h"
#include "tools/config.h"
#include "analysis/plot.h"
#include "tools/sninject.h"
#include "sim/survey/wcs.h"

static const char *sn_usage =
    "usage: wfisim sn generate (--plan plan.fits | --area DEG2 --start MJD --days N [--ra R --dec D])\n"
    "                          [--catalog FILE | --hostless] [--seed S] [--model DIR] [--data DIR]\n"
    "                          [--h0 H --om OM] [--alpha A --beta B --sigma-int S]\n"
    "                          [--dz DZ | --dztol A0,A1,A2]\n"
    "                          [--rate 'A B zmin zmax' ...] [--zmin Z --zmax Z]\n"
    "                          [--config FILE] [--set sn.KEY=VALUE ...] --out sne.fits\n"
    "       wfisim sn lightcurves --sne sne.fits (--plan plan.fits [--window] | --grid START:END:STEP\n"
    "                          [--filters Y106,J129,...]) [--model DIR] [--data DIR] --out lc.fits\n"
    "                          [--plot ID,ID,... [--plot-dir DIR]]\n"
    "       wfisim sn lightcurve --z Z --t0 MJD --band F --mjd M1,M2,... [--x1 X] [--c C]\n"
    "                          [--x0 X0 | --mu MU] [--model DIR] [--data DIR] [--interp bicubic|linear]\n"
    "\n"
    "  generate     the SN Ia sample of SPEC 5 over a plan's footprint (its coverage map beside\n"
    "               it) or a circle of DEG2 about (R, D); hosts from --catalog (FITS/CSV galaxies\n"
    "               with z, logmass, logsfr, or an SNANA HOSTLIB), else the synthetic field\n"
    "  lightcurves  truth light curves (ID, BAND, MJD, MAG, FLUX, FLAG, EXPID, SCA, X, Y): with\n"
    "               --plan, on every image of the plan whose SCA holds the SN inside its model\n"
    "               phase range (--window: on every\n"
    "               plan date in its model window); or on a regular grid in the listed filters\n"
    "  lightcurve   one SN's AB magnitudes and e-/s at given dates (sncosmo's bandmag)\n"
    "\n"
    "  --model DIR  SALT model directory (default sn.model, else DATA/salt3/salt3-k21); --data DIR\n"
    "               Roman data (default paths.data / $WFISIM_DATA; without it the built-in\n"
    "               top-hat bandpasses). Every sn.* key of docs/CONFIG.md can come from --config\n"
    "               or --set; the options above override them.\n";

static int fail(wf_status st)
{
    const char *m = wf_error_message();
    fprintf(stderr, "wfisim sn: %s\n", m[0] ? m : wf_status_name(st));
    return st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
}

static int usage_error(const char *fmt, const char *arg)
{
    fprintf(stderr, "wfisim sn: ");
    fprintf(stderr, fmt, arg);
    fprintf(stderr, "\n\n%s", sn_usage);
    return 2;
}

/* ---- options ------------------------------------------------------------------------- */

#define MAX_RATE_LINES 8

typedef struct opts {
    const char *plan, *out, *catalog, *model, *data, *sne, *grid, *filters, *plot, *plot_dir;
    const char *band, *mjd, *interp, *dztol;
    const char *rate[MAX_RATE_LINES];
    int nrate, hostless, window, have_seed;
    uint64_t seed;
    double area, start, days, ra, dec;
    double h0, om, alpha, beta, sigma_int, dz, zmin, zmax;
    double z, t0, x1, c, x0, mu;
    char model_buf[WF_PATH_MAX + 32];
    double fmax;
    char rate_buf[MAX_RATE_LINES][160];
} opts;

/* The configuration (sn.*, paths.data) the options start from: defaults, then --config FILE,
 * then --set KEY=VALUE; explicit options override it. One per process. */
static wf_config sn_cfg;

static int number(const char *flag, const char *text, double *out)
{
    char *end;
    double v = strtod(text, &end);
    if (end == text || *end || !isfinite(v)) {
        fprintf(stderr, "wfisim sn: %s '%s' is not a finite number\n", flag, text);
        return 2;
    }
    *out = v;
    return 0;
}

/* A seed takes all 64 bits: through a double, seeds above 2^53 would fall onto their
 * neighbours and silently give their samples. */
_Static_assert(ULLONG_MAX == UINT64_MAX, "strtoull covers exactly the seeds");
static int seed_number(const char *flag, const char *text, uint64_t *out)
{
    char *end = NULL;
    unsigned long long v = 0;
    errno = 0;
    /* strtoull would skip blanks and wrap a minus sign around: digits only */
    if (isdigit((unsigned char)text[text[0] == '+'])) v = strtoull(text, &end, 10);
    if (!end || *end) {
        fprintf(stderr, "wfisim sn: %s '%s' is not a non-negative integer\n", flag, text);
        return 2;
    }
    if (errno == ERANGE) {
        fprintf(stderr, "wfisim sn: %s '%s' is out of range (0 to 2^64-1)\n", flag, text);
        return 2;
    }
    *out = v;
    return 0;
}

/* An option's value outside [-limit, limit]. */
static int out_of_range(const char *flag, double v, double limit)
{
    char msg[160];
    snprintf(msg, sizeof msg, "%s %g is out of range (-%g to %g)", flag, v, limit, limit);
    return usage_error("%s", msg);
}

static int parse(int argc, char **argv, opts *o)
{
    memset(o, 0, sizeof *o);
    o->area = o->start = o->days = o->x0 = o->mu = o->z = o->t0 = NAN;
    o->ra = 71.0, o->dec = -53.0;
    o->h0 = o->om = o->fmax = NAN;
    o->alpha = o->beta = o->sigma_int = o->dz = o->zmin = o->zmax = NAN;
    wf_config_defaults(&sn_cfg);
    for (int i = 0; i < argc; i++) /* the file first, wherever it stands */
        if (!strcmp(argv[i], "--config")) {
            if (i + 1 >= argc) return usage_error("%s needs a file", "--config");
            if (wf_config_load(&sn_cfg, argv[i + 1])) return fail(WF_ERR_INPUT);
        }
    static const struct { const char *flag; size_t off; } strs[] = {
        {"--plan", offsetof(opts, plan)},       {"--out", offsetof(opts, out)},
        {"--catalog", offsetof(opts, catalog)}, {"--model", offsetof(opts, model)},
        {"--data", offsetof(opts, data)},       {"--sne", offsetof(opts, sne)},
        {"--grid", offsetof(opts, grid)},       {"--filters", offsetof(opts, filters)},
        {"--plot", offsetof(opts, plot)},       {"--plot-dir", offsetof(opts, plot_dir)},
        {"--band", offsetof(opts, band)},       {"--mjd", offsetof(opts, mjd)},
        {"--interp", offsetof(opts, interp)},   {"--dztol", offsetof(opts, dztol)},
    };
    static const struct { const char *flag; size_t off; } nums[] = {
        {"--area", offsetof(opts, area)},   {"--start", offsetof(opts, start)},
        {"--days", offsetof(opts, days)},   {"--ra", offsetof(opts, ra)},
        {"--dec", offsetof(opts, dec)},
        {"--h0", offsetof(opts, h0)},       {"--om", offsetof(opts, om)},
        {"--alpha", offsetof(opts, alpha)}, {"--beta", offsetof(opts, beta)},
        {"--sigma-int", offsetof(opts, sigma_int)}, {"--dz", offsetof(opts, dz)},
        {"--zmin", offsetof(opts, zmin)},   {"--zmax", offsetof(opts, zmax)},
        {"--z", offsetof(opts, z)},         {"--t0", offsetof(opts, t0)},
        {"--x1", offsetof(opts, x1)},       {"--c", offsetof(opts, c)},
        {"--x0", offsetof(opts, x0)},       {"--mu", offsetof(opts, mu)},
    };
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) { fputs(sn_usage, stdout); exit(0); }
        if (!strcmp(a, "--hostless")) { o->hostless = 1; continue; }
        if (!strcmp(a, "--config")) { i++; continue; }
        if (!strcmp(a, "--set")) {
            if (!val) return usage_error("%s needs KEY=VALUE", a);
            wf_status st = wf_config_set(&sn_cfg, val, "--set");
            if (st) return fail(st);
            i++;
            continue;
        }
        if (!strcmp(a, "--window")) { o->window = 1; continue; }
        int done = 0;
        for (size_t k = 0; k < sizeof strs / sizeof *strs && !done; k++)
            if (!strcmp(a, strs[k].flag)) {
                if (!val) return usage_error("%s needs a value", a);
                *(const char **)((char *)o + strs[k].off) = val;
                done = 1;
            }
        for (size_t k = 0; k < sizeof nums / sizeof *nums && !done; k++)
            if (!strcmp(a, nums[k].flag)) {
                if (!val) return usage_error("%s needs a value", a);
                if (number(a, val, (double *)((char *)o + nums[k].off))) return 2;
                done = 1;
            }
        if (!done && !strcmp(a, "--seed")) {
            if (!val) return usage_error("%s needs a value", a);
            if (seed_number(a, val, &o->seed)) return 2;
            o->have_seed = done = 1;
        }
        if (!done && !strcmp(a, "--rate")) {
            if (!val) return usage_error("%s needs 'A B zmin zmax'", a);
            if (o->nrate == MAX_RATE_LINES) return usage_error("at most 8 %s pieces", a);
            /* 'A B zmin zmax' as SNANA writes it after POWERLAW2 */
            snprintf(o->rate_buf[o->nrate], sizeof o->rate_buf[o->nrate], "%s%s",
                     strstr(val, "POWERLAW2") ? "" : "POWERLAW2 ", val);
            o->rate[o->nrate] = o->rate_buf[o->nrate];
            o->nrate++;
            done = 1;
        }
        if (!done) return usage_error("unknown option '%s'", a);
        i++;
    }
    const wf_config *c = &sn_cfg;
    /* the configuration's seed by default: the synthetic host field is then the one
     * `survey run` draws with the same configuration */
    if (!o->have_seed) o->seed = c->seed;
    if (o->data) {
        wf_status st = wf_config_check_dir("--data", o->data); /* a folder whenever given */
        if (st) return fail(st);
    } else o->data = c->data_dir;
    if (!o->model && c->sn.model[0]) o->model = c->sn.model;
    if (isnan(o->h0)) o->h0 = c->sn.h0;
    if (isnan(o->om)) o->om = c->sn.om;
    if (isnan(o->alpha)) o->alpha = c->sn.alpha;
    else if (!(fabs(o->alpha) <= WF_SNPOP_ALPHA_LIMIT)) return out_of_range("--alpha", o->alpha, WF_SNPOP_ALPHA_LIMIT);
    if (isnan(o->beta)) o->beta = c->sn.beta;
    else if (!(fabs(o->beta) <= WF_SNPOP_BETA_LIMIT)) return out_of_range("--beta", o->beta, WF_SNPOP_BETA_LIMIT);
    if (isnan(o->sigma_int)) o->sigma_int = c->sn.sigma_int;
    if (isnan(o->zmin)) o->zmin = c->sn.zmin;
    if (isnan(o->zmax)) o->zmax = c->sn.zmax;
    if (isnan(o->fmax)) o->fmax = c->sn.fmax;
    if (!o->dztol && isnan(o->dz)) o->dztol = c->sn.dztol;
    o->hostless |= c->sn.hostless;
    if (!o->nrate) { /* the configuration's pieces, ';'-separated */
        const char *p = c->sn.rate;
        while (*p && o->nrate < MAX_RATE_LINES) {
            const char *e = strchr(p, ';');
            size_t len = e ? (size_t)(e - p) : strlen(p);
            if (len >= sizeof o->rate_buf[0]) return usage_error("sn.rate: a piece of '%s' is too long", c->sn.rate);
            memcpy(o->rate_buf[o->nrate], p, len);
            o->rate_buf[o->nrate][len] = '\0';
            o->rate[o->nrate] = o->rate_buf[o->nrate];
            o->nrate++;
            p += len + (e ? 1 : 0);
        }
    }
    if (!o->model) {
        if (!o->data[0]) {
            fprintf(stderr, "wfisim sn: no SALT model: give --model DIR, or a data folder (--data DIR or "
                            "$WFISIM_DATA) holding salt3/salt3-k21\n");
            return 2;
        }
        snprintf(o->model_buf, sizeof o->model_buf, "%s/salt3/salt3-k21", o->data);
        o->model = o->model_buf;
    }
    return 0;
}

/* ---- footprint: a plan's coverage map or a circle ----------------------------------- */

typedef struct footprint {
    int circle;
    double ra0, dec0;           /* tangent point / circle centre, deg */
    double radius;              /* circle: deg */
    int nx, ny;                 /* map */
    double crpix1, crpix2, cd11, cd22;
    unsigned char *covered;     /* [ny][nx] */
    size_t ncovered;
    size_t *cells;              /* indices of covered cells */
    double area;                /* deg^2 */
} footprint;

static void footprint_free(footprint *f)
{
    free(f->covered);
    free(f->cells);
}

static int footprint_contains(const footprint *f, double ra, double dec)
{
    const double d2r = M_PI / 180.0;
    double xi, eta;
    if (wf_wcs_tangent_project(f->ra0 * d2r, f->dec0 * d2r, ra * d2r, dec * d2r, &xi, &eta)) return 0;
    xi /= d2r;
    eta /= d2r;
    if (f->circle) {
        double cosd = sin(f->dec0 * d2r) * sin(dec * d2r) + cos(f->dec0 * d2r) * cos(dec * d2r) * cos((ra - f->ra0) * d2r);
        return cosd >= cos(f->radius * d2r);
    }
    long i = lround(xi / f->cd11 + f->crpix1) - 1, j = lround(eta / f->cd22 + f->crpix2) - 1;
    return i >= 0 && j >= 0 && i < f->nx && j < f->ny && f->covered[(size_t)j * f->nx + i];
}

/* plan.fits -> plan_coverage.fits: covered cells are those any exposure of any filter sees. */
static wf_status footprint_from_plan(const char *plan, footprint *f, double *mjd0, double *mjd1)
{
    memset(f, 0, sizeof *f);
    char path[WF_PATH_MAX + 32];
    size_t len = strlen(plan);
    if (len > 5 && !strcmp(plan + len - 5, ".fits")) snprintf(path, sizeof path, "%.*s_coverage.fits", (int)(len - 5), plan);
    else snprintf(path, sizeof path, "%s_coverage.fits", plan);
    wf_survey_row *rows;
    size_t nrows;
    wf_status st = wf_survey_read_plan(plan, &rows, &nrows);
    if (st) return st;
    *mjd0 = INFINITY, *mjd1 = -INFINITY;
    for (size_t r = 0; r < nrows; r++) {
        double m = rows[r].mjd_start, t = rows[r].exptime;
        if (m < *mjd0) *mjd0 = m;
        if (m + t / 86400.0 > *mjd1) *mjd1 = m + t / 86400.0;
    }
    free(rows);
    if (!nrows) return wf_error(WF_ERR_INPUT, "%s: the PLAN table has no exposures", plan);
    fitsfile *ff;
    int status = 0, cs = 0;
    if (fits_open_diskfile(&ff, path, READONLY, &status))
        return wf_error(WF_ERR_IO, "%s: cannot open the plan's coverage map (written by `wfisim survey plan`)", path);
    int nhdu = 0;
    fits_get_num_hdus(ff, &nhdu, &status);
    int32_t *buf = NULL;
    for (int h = 2; h <= nhdu && !status && !st; h++) {
        int type;
        long naxes[2] = {0, 0};
        fits_movabs_hdu(ff, h, &type, &status);
        fits_get_img_size(ff, 2, naxes, &status);
        if (h == 2) {
            f->nx = (int)naxes[0], f->ny = (int)naxes[1];
            fits_read_key_dbl(ff, "CRVAL1", &f->ra0, NULL, &status);
            fits_read_key_dbl(ff, "CRVAL2", &f->dec0, NULL, &status);
            fits_read_key_dbl(ff, "CRPIX1", &f->crpix1, NULL, &status);
            fits_read_key_dbl(ff, "CRPIX2", &f->crpix2, NULL, &status);
            fits_read_key_dbl(ff, "CD1_1", &f->cd11, NULL, &status);
            fits_read_key_dbl(ff, "CD2_2", &f->cd22, NULL, &status);
            if (status || f->nx <= 0 || f->ny <= 0) break;
            f->covered = calloc((size_t)f->nx * f->ny, 1);
            buf = malloc((size_t)f->nx * f->ny * sizeof *buf);
            if (!f->covered || !buf) { st = wf_error(WF_ERR_NOMEM, "%s: coverage map", path); break; }
        }
        if (naxes[0] != f->nx || naxes[1] != f->ny) { st = wf_error(WF_ERR_INPUT, "%s: HDU %d size differs", path, h); break; }
        fits_read_img(ff, TINT, 1, (LONGLONG)f->nx * f->ny, NULL, buf, NULL, &status);
        for (size_t k = 0; k < (size_t)f->nx * f->ny && !status; k++)
            if (buf[k] > 0) f->covered[k] = 1;
    }
    free(buf);
    fits_close_file(ff, &cs);
    if (!st && (status || !f->covered)) st = wf_error(WF_ERR_INPUT, "%s: not a coverage map (cfitsio status %d)", path, status);
    if (st) { footprint_free(f); return st; }
    for (size_t k = 0; k < (size_t)f->nx * f->ny; k++) f->ncovered += f->covered[k];
    if (!(f->cells = malloc((f->ncovered ? f->ncovered : 1) * sizeof *f->cells))) {
        footprint_free(f);
        return wf_error(WF_ERR_NOMEM, "coverage cells");
    }
    size_t n = 0;
    for (size_t k = 0; k < (size_t)f->nx * f->ny; k++)
        if (f->covered[k]) f->cells[n++] = k;
    /* tangent-plane cell area: the projection stretches areas by 1/cos^3 of the distance
     * from the centre, < 0.2% at the 1.5 deg edge of the deep field */
    f->area = (double)f->ncovered * fabs(f->cd11 * f->cd22);
    return WF_OK;
}

static void footprint_circle(footprint *f, double ra, double dec, double area)
{
    memset(f, 0, sizeof *f);
    f->circle = 1;
    f->ra0 = ra, f->dec0 = dec, f->area = area;
    /* spherical cap of this solid angle: 2 pi (1 - cos r) */
    double sr = area * (M_PI / 180.0) * (M_PI / 180.0);
    f->radius = acos(1.0 - sr / (2.0 * M_PI)) * 180.0 / M_PI;
}

/* A point uniform over the footprint from two uniforms (and a third for the map's cell). */
static void footprint_draw(const footprint *f, wf_rng *rng, double *ra, double *dec)
{
    double u1 = wf_rng_uniform53(rng), u2 = wf_rng_uniform53(rng), u3 = wf_rng_uniform53(rng);
    if (f->circle) {
        double cr = cos(f->radius * M_PI / 180.0);
        double cost = 1.0 - u1 * (1.0 - cr), theta = acos(cost), phi = 2.0 * M_PI * u2;
        /* offset theta in direction phi from the centre, on the sphere */
        double d0 = f->dec0 * M_PI / 180.0;
        double sd = sin(d0) * cos(theta) + cos(d0) * sin(theta) * cos(phi);
        double d = asin(sd);
        double a = atan2(sin(phi) * sin(theta) * cos(d0), cos(theta) - sin(d0) * sd);
        *dec = d * 180.0 / M_PI;
        *ra = fmod(f->ra0 + a * 180.0 / M_PI + 720.0, 360.0);
        (void)u3;
        return;
    }
    size_t k = f->cells[(size_t)(u3 * (double)f->ncovered) < f->ncovered ? (size_t)(u3 * (double)f->ncovered) : f->ncovered - 1];
    double i = (double)(k % (size_t)f->nx) + u1 - 0.5, j = (double)(k / (size_t)f->nx) + u2 - 0.5;
    const double d2r = M_PI / 180.0;
    double r, d;
    wf_wcs_tangent_deproject(f->ra0 * d2r, f->dec0 * d2r, (i + 1.0 - f->crpix1) * f->cd11 * d2r,
                             (j + 1.0 - f->crpix2) * f->cd22 * d2r, &r, &d);
    *ra = fmod(r / d2r + 720.0, 360.0);
    *dec = d / d2r;
}

/* ---- generate ------------------------------------------------------------------------ */

static int is_hostlib(const char *path)
{
    size_t n = strlen(path);
    if ((n > 8 && !strcasecmp(path + n - 8, ".HOSTLIB")) || (n > 11 && !strcasecmp(path + n - 11, ".HOSTLIB.gz")))
        return 1;
    gzFile f = gzopen(path, "rb"); /* plain or gzip'd, as the readers take them */
    if (!f) return 0;
    char line[512];
    int found = 0;
    for (int k = 0; k < 200 && gzgets(f, line, sizeof line); k++)
        if (!strncmp(line, "VARNAMES:", 9) || !strncmp(line, "GAL:", 4)) { found = 1; break; }
    gzclose(f);
    return found;
}

/* Galaxies of the footprint: a file, or the synthetic field with the run's seed. */
static wf_status load_hosts(const opts *o, const footprint *fp, wf_catalog *gal)
{
    wf_status st;
    wf_catalog all;
    if (o->catalog) {
        if (is_hostlib(o->catalog)) st = wf_hostlib_read(o->catalog, &all, NULL);
        else st = wf_catalog_read_galaxies(o->catalog, &all);
        if (st) return st;
    } else {
        wf_synth_config sc;
        wf_synth *syn;
        if ((st = wf_config_synth(&sn_cfg, &sc))) return st;
        sc.seed = o->seed;
        if ((st = wf_synth_create(&sc, &syn))) return st;
        wf_skyregion reg;
        double r = fp->circle ? fp->radius : 0.5 * hypot(fp->nx * fabs(fp->cd11), fp->ny * fabs(fp->cd22));
        st = wf_skyindex_circle(fp->ra0, fp->dec0, r, 0.0, &reg);
        if (!st) st = wf_synth_select(syn, &reg, &all, NULL);
        wf_synth_free(syn);
        if (st) return st;
    }
    uint32_t *keep = malloc((all.n ? all.n : 1) * sizeof *keep);
    if (!keep) { wf_catalog_free(&all); return wf_error(WF_ERR_NOMEM, "host selection"); }
    size_t n = 0;
    for (size_t i = 0; i < all.n; i++)
        if (footprint_contains(fp, all.ra[i], all.dec[i])) keep[n++] = (uint32_t)i;
    st = wf_catalog_subset(&all, keep, n, gal);
    free(keep);
    wf_catalog_free(&all);
    return st;
}

static int cmd_generate(int argc, char **argv)
{
    opts o;
    int rc = parse(argc, argv, &o);
    if (rc) return rc;
    if (!o.out) return usage_error("%s is required", "--out FILE");
    if (!o.plan && !(isfinite(o.area) && isfinite(o.start) && isfinite(o.days)))
        return usage_error("%s", "give --plan plan.fits, or --area DEG2 --start MJD --days N");
    wf_status st;
    wf_cosmo cosmo;
    wf_snrate law;
    wf_snrate_survey sv;
    wf_snpop pop;
    wf_snhost_config hc;
    wf_snrate_survey_default(&sv);
    wf_snpop_default(&pop);
    wf_snhost_config_default(&hc);
    pop.alpha = o.alpha, pop.beta = o.beta, pop.sigma_int = o.sigma_int;
    pop.x1 = (wf_snpop_agauss){sn_cfg.sn.x1[0], sn_cfg.sn.x1[1], sn_cfg.sn.x1[2], sn_cfg.sn.x1[3], sn_cfg.sn.x1[4]};
    pop.c = (wf_snpop_agauss){sn_cfg.sn.c[0], sn_cfg.sn.c[1], sn_cfg.sn.c[2], sn_cfg.sn.c[3], sn_cfg.sn.c[4]};
    hc.fmax = o.fmax;
    if (isfinite(o.dz)) hc.dztol[0] = o.dz, hc.dztol[1] = hc.dztol[2] = 0.0;
    if (o.dztol) { /* SNANA's HOSTLIB_DZTOL: dz(z) = a0 + a1 z + a2 z^2 */
        char *e1, *e2, *e3;
        double a0 = strtod(o.dztol, &e1), a1 = *e1 == ',' ? strtod(e1 + 1, &e2) : NAN, a2 = NAN;
        if (isfinite(a1) && *e2 == ',') a2 = strtod(e2 + 1, &e3);
        if (e1 == o.dztol || !isfinite(a0) || !isfinite(a1) || !isfinite(a2) || *e3)
            return usage_error("--dztol '%s': expected a0,a1,a2 (SNANA HOSTLIB_DZTOL)", o.dztol);
        hc.dztol[0] = a0, hc.dztol[1] = a1, hc.dztol[2] = a2;
    }
    sv.zmin = o.zmin;
    sv.zmax = o.zmax;
    if ((st = wf_cosmo_init(&cosmo, o.h0, o.om))) return fail(st);
    wf_snrate_clear(&law);
    for (int k = 0; k < o.nrate; k++)
        if ((st = wf_snrate_add_line(&law, o.rate[k], "rate", k + 1))) return fail(st);
    if ((st = wf_snpop_validate(&pop)) || (st = wf_snhost_config_check(&hc))) return fail(st);
    wf_salt_model *model = NULL;
    if ((st = wf_salt_load(o.model, &model))) return fail(st);
    double pmin, pmax;
    wf_salt_phase_range(model, &pmin, &pmax);
    sv.rest_before = pmax;
    sv.rest_after = -pmin;
    footprint fp;
    if (o.plan) {
        if ((st = footprint_from_plan(o.plan, &fp, &sv.mjd_start, &sv.mjd_end))) { wf_salt_free(model); return fail(st); }
    } else {
        if (!(o.area > 0) || !(o.days > 0)) { wf_salt_free(model); return usage_error("%s", "--area and --days must be > 0"); }
        footprint_circle(&fp, o.ra, o.dec, o.area);
        sv.mjd_start = o.start;
        sv.mjd_end = o.start + o.days;
    }
    sv.area_deg2 = fp.area;
    wf_snrate_gen gen;
    wf_catalog hosts;
    memset(&hosts, 0, sizeof hosts);
    int have_hosts = 0;
    wf_snhost_index *hix = NULL;
    wf_sn_sample out;
    memset(&out, 0, sizeof out);
    uint32_t count = 0;
    long nhostless = 0;
    st = wf_snrate_gen_init(&gen, &law, &cosmo, &sv, o.seed);
    if (st) goto done;
    if (!o.hostless) {
        if ((st = load_hosts(&o, &fp, &hosts))) goto done;
        have_hosts = 1;
        if ((st = wf_snhost_index_build(&hosts, &hc, &hix))) goto done;
    }
    if ((st = wf_snrate_gen_count(&gen, &count)) || (st = wf_sn_sample_reserve(&out, count ? count : 1))) goto done;
    for (uint32_t i = 0; i < count && !st; i++) {
        size_t r;
        double z, t0, mu;
        if ((st = wf_sn_sample_push(&out, &r)) || (st = wf_snrate_gen_draw(&gen, i, &z, &t0)) ||
            (st = wf_cosmo_distance_modulus(&cosmo, z, &mu)))
            break;
        wf_rng rng;
        wf_sn_rng(o.seed, i, WF_SN_DRAW_POP, &rng);
        wf_sn_params sp;
        if ((st = wf_snpop_draw(&pop, &rng, mu, &sp))) break;
        out.id[r] = (int64_t)i + 1;
        out.z[r] = z, out.t0[r] = t0, out.mu[r] = mu;
        out.x0[r] = sp.x0, out.x1[r] = sp.x1, out.c[r] = sp.c, out.delta[r] = sp.delta;
        long row = -1, ncand = 0;
        if (hix) {
            wf_sn_rng(o.seed, i, WF_SN_DRAW_HOST, &rng);
            if ((st = wf_snhost_choose(hix, z, wf_rng_uniform53(&rng), &row, &ncand))) break;
        }
        wf_sn_rng(o.seed, i, WF_SN_DRAW_POS, &rng);
        if (row >= 0) {
            wf_snhost_position pos;
            if ((st = wf_snhost_place(&hosts, (size_t)row, &rng, &hc, &pos))) break;
            out.host_id[r] = hosts.id[row];
            out.ra[r] = pos.ra, out.dec[r] = pos.dec;
            out.host_offset[r] = pos.offset;
            out.host_comp[r] = pos.component;
            if ((st = wf_snhost_semimajor(&hosts, (size_t)row, &out.host_a[r]))) break;
        } else {
            footprint_draw(&fp, &rng, &out.ra[r], &out.dec[r]);
            out.host_id[r] = -1;
            out.host_comp[r] = -1;
            out.flags[r] = o.hostless ? WF_SN_FLAG_NOHOSTCAT | WF_SN_FLAG_HOSTLESS : WF_SN_FLAG_HOSTLESS;
            nhostless++;
        }
    }
    if (st) goto done;
    {
        const char *base = strrchr(o.model, '/');
        base = base && base[1] ? base + 1 : o.model;
        snprintf(out.model, sizeof out.model, "%s", base);
        int n = snprintf(out.cards, sizeof out.cards,
                         "SEED = %" PRIu64 " / generation seed\n"
                         "H0 = %.6g / [km/s/Mpc] flat LCDM\n"
                         "OMEGAM = %.6g / matter density\n"
                         "ALPHA = %.6g / stretch standardisation\n"
                         "BETA = %.6g / colour standardisation\n"
                         "SIGINT = %.6g / [mag] coherent intrinsic scatter\n"
                         "AREA = %.9g / [deg2] generation footprint\n"
                         "MJDSTART = %.6f / survey start\n"
                         "MJDEND = %.6f / survey end\n"
                         "PEAKMIN = %.6f / earliest peak MJD (padded)\n"
                         "PEAKMAX = %.6f / latest peak MJD (padded)\n"
                         "ZMIN = %.6g / \n"
                         "ZMAX = %.6g / \n"
                         "NEXPECT = %.6f / expected number (rate x volume x time)\n"
                         "NHOSTLSS = %ld / hostless supernovae\n"
                         "DZTOL = '%.6g %.6g %.6g' / host |dz| <= a0 + a1 z + a2 z^2\n"
                         "HOSTFMAX = %.6g / largest enclosed-flux fraction\n",
                         o.seed, o.h0, o.om, pop.alpha, pop.beta, pop.sigma_int, fp.area, sv.mjd_start,
                         sv.mjd_end, gen.peak_min, gen.peak_max, sv.zmin, sv.zmax, gen.expected, nhostless,
                         hc.dztol[0], hc.dztol[1], hc.dztol[2], hc.fmax);
        for (int k = 0; k < law.n && n > 0 && (size_t)n < sizeof out.cards; k++)
            n += snprintf(out.cards + n, sizeof out.cards - (size_t)n, "RATE%d = '%.6g %.6g %.6g %.6g' / A B zmin zmax\n",
                          k + 1, law.p[k].a, law.p[k].b, law.p[k].zlo, law.p[k].zhi);
    }
    st = wf_sn_sample_write(&out, o.out);
    if (!st)
        printf("wfisim sn: %u supernovae (expected %.1f over %.4f deg2 and %.1f days of peak dates), %ld hostless%s; "
               "wrote %s\n", count, gen.expected, fp.area, gen.days, nhostless,
               have_hosts ? "" : " (no host catalog)", o.out);
done:
    wf_sn_sample_free(&out);
    wf_snhost_index_free(hix);
    if (have_hosts) wf_catalog_free(&hosts);
    wf_snrate_gen_free(&gen);
    footprint_free(&fp);
    wf_salt_free(model);
    return st ? fail(st) : 0;
}

/* ---- light curves -------------------------------------------------------------------- */

typedef struct lc_row {
    int64_t id;
    char band[8];
    double mjd, mag, flux;
    double x, y;          /* FITS pixel on the SCA (observed mode), else NaN */
    int32_t flag, expid, sca; /* expid, sca -1 unless observed */
} lc_row;

typedef struct lc_rows {
    size_t n, cap;
    lc_row *v;
} lc_rows;

static wf_status rows_push(lc_rows *r, const lc_row *row)
{
    if (r->n == r->cap) {
        size_t nc = r->cap ? 2 * r->cap : 4096;
        lc_row *p = realloc(r->v, nc * sizeof *p);
        if (!p) return wf_error(WF_ERR_NOMEM, "light curves: %zu rows", nc);
        r->v = p;
        r->cap = nc;
    }
    r->v[r->n++] = *row;
    return WF_OK;
}

static int by_id_mjd(const void *a, const void *b)
{
    const lc_row *x = a, *y = b;
    if (x->id != y->id) return x->id < y->id ? -1 : 1;
    if (x->mjd != y->mjd) return x->mjd < y->mjd ? -1 : 1;
    return (x->sca > y->sca) - (x->sca < y->sca);
}

/* Column by column in chunks: cfitsio takes contiguous arrays. */
static wf_status write_rows(const lc_rows *r, const char *path, const char *sne, int observed)
{
    char tmp[WF_PATH_MAX + 16];
    fitsfile *f;
    int status = 0;
    wf_status st = wf_fits_begin(path, tmp, sizeof tmp, &f);
    if (st) return st;
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    char src[68];
    snprintf(src, sizeof src, "%.66s", sne);
    fits_write_key_str(f, "SNEFILE", src, "the SN sample", &status);
    fits_write_key_str(f, "LCMODE", observed ? "observed" : "dates", observed ? "rows: images whose SCA holds the SN"
                       : "rows: every date asked for", &status);
    char *tt[] = {"ID", "BAND", "MJD", "MAG", "FLUX", "FLAG", "EXPID", "SCA", "X", "Y"};
    char *tf[] = {"1K", "8A", "1D", "1D", "1D", "1J", "1J", "1J", "1D", "1D"};
    char *tu[] = {"", "", "d", "mag(AB)", "electron/s", "", "", "", "pixel", "pixel"};
    fits_create_tbl(f, BINARY_TBL, 0, 10, tt, tf, tu, "LIGHTCURVES", &status);
    fits_write_comment(f, "MAG 99 where FLUX is 0; FLAG bits: 1 phase outside the model, 2 band outside "
                       "its wavelengths, 4 negative band flux set to 0; EXPID, SCA -1 and X, Y NaN for dates "
                       "not tied to an image; X, Y FITS pixels", &status);
    enum { CHUNK = 65536 };
    double *d = malloc(CHUNK * sizeof *d);
    int64_t *id = malloc(CHUNK * sizeof *id);
    int *iv = malloc(CHUNK * sizeof *iv);
    char **names = malloc(CHUNK * sizeof *names);
    if (!d || !id || !iv || !names) status = MEMORY_ALLOCATION;
    for (size_t a = 0; a < r->n && !status; a += CHUNK) {
        size_t m = r->n - a < CHUNK ? r->n - a : CHUNK;
        LONGLONG first = (LONGLONG)a + 1;
        for (size_t k = 0; k < m; k++) id[k] = r->v[a + k].id, names[k] = (char *)r->v[a + k].band;
        fits_write_col(f, TLONGLONG, 1, first, 1, (LONGLONG)m, id, &status);
        fits_write_col(f, TSTRING, 2, first, 1, (LONGLONG)m, names, &status);
        for (int c = 0; c < 5; c++) {
            for (size_t k = 0; k < m; k++) {
                const lc_row *x = &r->v[a + k];
                d[k] = c == 0 ? x->mjd : c == 1 ? x->mag : c == 2 ? x->flux : c == 3 ? x->x : x->y;
            }
            fits_write_col(f, TDOUBLE, c < 3 ? 3 + c : 6 + c, first, 1, (LONGLONG)m, d, &status);
        }
        for (int c = 0; c < 3; c++) {
            for (size_t k = 0; k < m; k++) {
                const lc_row *x = &r->v[a + k];
                iv[k] = c == 0 ? x->flag : c == 1 ? x->expid : x->sca;
            }
            fits_write_col(f, TINT, 6 + c, first, 1, (LONGLONG)m, iv, &status);
        }
    }
    free(d);
    free(id);
    free(iv);
    free(names);
    return wf_fits_finish(f, tmp, path, wf_fits_error(status, tmp, "writing light curves"));
}

typedef struct epoch {
    double mjd, ra, dec, pa;
    int filter, expid;
} epoch;

static int by_mjd(const void *a, const void *b)
{
    double x = ((const epoch *)a)->mjd, y = ((const epoch *)b)->mjd;
    return (x > y) - (x < y);
}

static wf_status plan_epochs(const char *plan, epoch **out, size_t *n)
{
    *out = NULL, *n = 0;
    wf_survey_row *rows;
    size_t nrows;
    wf_status st = wf_survey_read_plan(plan, &rows, &nrows);
    if (st) return st;
    epoch *e = malloc((nrows ? nrows : 1) * sizeof *e);
    if (!e) st = wf_error(WF_ERR_NOMEM, "%s: %zu plan rows", plan, nrows);
    for (size_t r = 0; r < nrows && !st; r++) {
        const wf_survey_row *x = &rows[r];
        wf_filter fl;
        if ((st = wf_filter_parse(x->filter, &fl))) {
            char msg[512];
            snprintf(msg, sizeof msg, "%s", wf_error_message());
            st = wf_error(st, "%s: PLAN row %zu column FILTER: %s", plan, r + 1, msg);
            break;
        }
        e[r] = (epoch){.mjd = x->mjd_mid, .ra = x->ra, .dec = x->dec, .pa = x->pa, .filter = (int)fl, .expid = x->expid};
    }
    free(rows);
    if (st) { free(e); return st; }
    qsort(e, nrows, sizeof *e, by_mjd);
    *out = e;
    *n = nrows;
    return WF_OK;
}

static wf_status grid_epochs(const char *grid, const char *filters, epoch **out, size_t *n)
{
    double a, b, step;
    *out = NULL, *n = 0;
    if (sscanf(grid, "%lf:%lf:%lf", &a, &b, &step) != 3 || !(step > 0) || !(b >= a) || !isfinite(a) || !isfinite(b))
        return wf_error(WF_ERR_INPUT, "--grid '%s': expected START:END:STEP with END >= START, STEP > 0", grid);
    double count = floor((b - a) / step + 1e-9) + 1;
    if (count > 1e7) return wf_error(WF_ERR_RANGE, "--grid '%s': %.0f dates is too many", grid, count);
    int fl[WF_NFILTER], nf = 0;
    char list[256];
    snprintf(list, sizeof list, "%s", filters ? filters : "Y106,J129,H158,F184");
    for (char *tok = strtok(list, ","); tok; tok = strtok(NULL, ",")) {
        wf_filter f;
        wf_status st = wf_filter_parse(tok, &f);
        if (st) return st;
        if (nf < WF_NFILTER) fl[nf++] = (int)f;
    }
    epoch *e = malloc((size_t)count * (size_t)nf * sizeof *e);
    if (!e) return wf_error(WF_ERR_NOMEM, "--grid: %.0f dates", count);
    size_t k = 0;
    for (long i = 0; i < (long)count; i++)
        for (int j = 0; j < nf; j++) e[k++] = (epoch){a + (double)i * step, NAN, NAN, NAN, fl[j], -1};
    *out = e;
    *n = k;
    return WF_OK;
}

static wf_status plot_sn(const lc_rows *r, size_t first, size_t last, int64_t id, double z, const char *dir)
{
    char title[96], path[WF_PATH_MAX + 64];
    snprintf(title, sizeof title, "SN %lld, z = %.3f", (long long)id, z);
    snprintf(path, sizeof path, "%s/lc_%lld.png", dir, (long long)id);
    wf_plot *p;
    wf_status st = wf_plot_create(800, 560, title, "MJD", "AB magnitude", &p);
    if (st) return st;
    wf_plot_invert_y(p, 1);
    size_t n = last - first;
    double *x = malloc((n ? n : 1) * sizeof *x), *y = malloc((n ? n : 1) * sizeof *y);
    if (!x || !y) st = wf_error(WF_ERR_NOMEM, "plot");
    int drawn = 0;
    for (int f = 0; f < WF_NFILTER && !st; f++) {
        int m = 0;
        for (size_t k = first; k < last; k++)
            if (!strcmp(r->v[k].band, wf_filter_name((wf_filter)f)) && r->v[k].flux > 0) {
                x[m] = r->v[k].mjd;
                y[m++] = r->v[k].mag;
            }
        if (m) {
            st = wf_plot_series(p, x, y, NULL, m, wf_filter_name((wf_filter)f), WF_PLOT_LINE | WF_PLOT_MARKERS);
            drawn = 1;
        }
    }
    if (!st && !drawn)
        fprintf(stderr, "wfisim sn: SN %lld has no flux on the dates asked for: no plot\n", (long long)id);
    else if (!st)
        st = wf_plot_write_png(p, path);
    free(x);
    free(y);
    wf_plot_free(p);
    if (!st && drawn) printf("wfisim sn: wrote %s\n", path);
    return st;
}

/* The images of the plan that hold each SN: per exposure and SCA, the SNe of the footprint
 * (the injector's sky index and light curves) whose centre is on the SCA. */
static wf_status observed_rows(const opts *o, const epoch *ep, size_t nep, wf_bandpass **bp, lc_rows *rows)
{
    wf_focal_plane *fp = malloc(sizeof *fp);
    wf_sn_injector *inj = NULL;
    if (!fp) return wf_error(WF_ERR_NOMEM, "focal plane");
    wf_status st = wf_wcs_focal_plane(o->data[0] ? o->data : NULL, fp);
    if (!st) st = wf_sn_injector_open(o->sne, o->model, o->data, &inj);
    for (size_t e = 0; e < nep && !st; e++) {
        for (int sca = 1; sca <= 18 && !st; sca++) {
            wf_wcs w;
            double ra[4], dec[4];
            const double cx[4] = {-0.5, 4087.5, 4087.5, -0.5}, cy[4] = {-0.5, -0.5, 4087.5, 4087.5};
            if ((st = wf_wcs_for_sca(fp, ep[e].ra, ep[e].dec, ep[e].pa, sca, &w))) break;
            for (int k = 0; k < 4 && !st; k++) st = wf_wcs_pix2world(&w, cx[k], cy[k], &ra[k], &dec[k]);
            wf_skyregion reg;
            wf_scene_sn *v = NULL;
            size_t n = 0;
            if (!st) st = wf_skyindex_polygon(ra, dec, 4, 1.0, &reg);
            if (!st) st = wf_sn_injector_select(inj, wf_filter_name((wf_filter)ep[e].filter), ep[e].mjd, &reg, &v, &n);
            for (size_t k = 0; k < n && !st; k++) {
                double x, y;
                if (wf_wcs_world2pix(&w, v[k].ra, v[k].dec, &x, &y) != WF_OK) continue;
                if (x < -0.5 || y < -0.5 || x >= 4087.5 || y >= 4087.5) continue;
                if (v[k].flags & WF_SALT_OUT_PHASE) continue; /* before or after the model: no light */
                lc_row row = {v[k].id, "", ep[e].mjd, v[k].mag,
                              v[k].mag < WF_SALT_MAG_NONE ? wf_bandpass_countrate_ab(bp[ep[e].filter], v[k].mag) : 0.0,
                              x + 1.0, y + 1.0, (int32_t)v[k].flags, ep[e].expid, sca};
                snprintf(row.band, sizeof row.band, "%s", wf_filter_name((wf_filter)ep[e].filter));
                st = rows_push(rows, &row);
            }
            free(v);
        }
    }
    wf_sn_injector_free(inj);
    free(fp);
    return st;
}

/* Every date of ep (in the SN's model window only, with window = 1). */
static wf_status dated_rows(const wf_sn_sample *s, const wf_salt_model *model, const epoch *ep, size_t nep,
                            wf_bandpass **bp, int window, lc_rows *rows)
{
    wf_status st = WF_OK;
    double pmin, pmax;
    wf_salt_phase_range(model, &pmin, &pmax);
    for (size_t i = 0; i < s->n && !st; i++) {
        wf_salt_params p = {s->z[i], s->t0[i], s->x0[i], s->x1[i], s->c[i]};
        wf_salt_lc *lc[WF_NFILTER] = {0};
        double lo = window ? s->t0[i] + (1.0 + s->z[i]) * pmin : -INFINITY;
        double hi = window ? s->t0[i] + (1.0 + s->z[i]) * pmax : INFINITY;
        for (size_t e = 0; e < nep && !st; e++) {
            if (ep[e].mjd < lo || ep[e].mjd > hi) continue;
            int f = ep[e].filter;
            if (!lc[f] && (st = wf_salt_lc_init(model, &p, bp[f], WF_SALT_INTERP_BICUBIC, &lc[f]))) break;
            double rate, mag = WF_SALT_MAG_NONE;
            unsigned flags;
            if ((st = wf_salt_lc_rate(lc[f], ep[e].mjd, &rate, &flags))) break;
            if (rate > 0 && (st = wf_bandpass_mag_ab(bp[f], rate, &mag))) break;
            lc_row row = {s->id[i], "", ep[e].mjd, mag, rate, NAN, NAN, (int32_t)flags, ep[e].expid, -1};
            snprintf(row.band, sizeof row.band, "%s", wf_filter_name((wf_filter)f));
            st = rows_push(rows, &row);
        }
        for (int f = 0; f < WF_NFILTER; f++) wf_salt_lc_free(lc[f]);
    }
    return st;
}

/* The light-curve rows of o's sample (read into *s) at o's epochs, sorted by SN and date. */
static wf_status lightcurve_rows(const opts *o, wf_sn_sample *s, lc_rows *rows)
{
    wf_salt_model *model = NULL;
    epoch *ep = NULL;
    size_t nep = 0;
    wf_bandpass *bp[WF_NFILTER] = {0};
    wf_status st = wf_sn_sample_read(o->sne, s);
    if (st) return st;
    if (!st) st = wf_salt_load(o->model, &model);
    if (!st) st = o->plan ? plan_epochs(o->plan, &ep, &nep) : grid_epochs(o->grid, o->filters, &ep, &nep);
    for (size_t e = 0; e < nep && !st; e++) {
        int f = ep[e].filter;
        if (bp[f]) continue;
        if (!(bp[f] = malloc(sizeof *bp[f]))) st = wf_error(WF_ERR_NOMEM, "bandpass");
        else st = wf_bandpass_load((wf_filter)f, o->data, bp[f]);
    }
    int observed = o->plan && !o->window;
    if (!st) st = observed ? observed_rows(o, ep, nep, bp, rows) : dated_rows(s, model, ep, nep, bp, o->window, rows);
    if (!st && rows->n) qsort(rows->v, rows->n, sizeof *rows->v, by_id_mjd);
    for (int f = 0; f < WF_NFILTER; f++) free(bp[f]);
    free(ep);
    wf_salt_free(model);
    return st;
}

wf_status wf_sn_write_plan_lightcurves(const char *sne, const char *plan, const char *model, const char *data,
                                       const char *out, size_t *npoints)
{
    opts o;
    memset(&o, 0, sizeof o);
    o.sne = sne;
    o.plan = plan;
    o.model = model;
    o.data = data ? data : "";
    wf_sn_sample s;
    lc_rows rows = {0, 0, NULL};
    wf_status st = lightcurve_rows(&o, &s, &rows);
    if (!st) st = write_rows(&rows, out, sne, 1);
    wf_sn_sample_free(&s); /* zeroed by a failed read: freeing is safe either way */
    *npoints = rows.n;
    free(rows.v);
    return st;
}

static int cmd_lightcurves(int argc, char **argv)
{
    opts o;
    int rc = parse(argc, argv, &o);
    if (rc) return rc;
    if (!o.sne || !o.out) return usage_error("%s are required", "--sne FILE and --out FILE");
    if (!o.plan == !o.grid) return usage_error("%s", "give one of --plan plan.fits or --grid START:END:STEP");
    if (o.window && !o.plan) return usage_error("%s goes with --plan", "--window");
    wf_sn_sample s;
    lc_rows rows = {0, 0, NULL};
    int64_t plot_ids[64];
    int nplot = 0;
    if (o.plot) {
        char list[1024];
        snprintf(list, sizeof list, "%s", o.plot);
        for (char *tok = strtok(list, ","); tok && nplot < 64; tok = strtok(NULL, ",")) {
            char *end;
            long long v = strtoll(tok, &end, 10);
            if (end == tok || *end) return usage_error("--plot: '%s' is not an SN id", tok);
            plot_ids[nplot++] = v;
        }
    }
    wf_status st = lightcurve_rows(&o, &s, &rows);
    int observed = o.plan && !o.window;
    int plotted = 0;
    for (int k = 0; k < nplot && !st; k++) {
        size_t i = 0;
        while (i < s.n && s.id[i] != plot_ids[k]) i++;
        if (i == s.n) continue;
        size_t a = 0;
        while (a < rows.n && rows.v[a].id != plot_ids[k]) a++;
        size_t b = a;
        while (b < rows.n && rows.v[b].id == plot_ids[k]) b++;
        st = plot_sn(&rows, a, b, plot_ids[k], s.z[i], o.plot_dir ? o.plot_dir : ".");
        plotted++;
    }
    if (!st && plotted < nplot) st = wf_error(WF_ERR_INPUT, "--plot: %d of the ids are not in %s", nplot - plotted, o.sne);
    if (!st) st = write_rows(&rows, o.out, o.sne, observed);
    if (!st)
        printf("wfisim sn: %zu light-curve points of %zu supernovae (%s); wrote %s\n", rows.n, s.n,
               observed ? "images whose SCA holds the SN" : o.window ? "plan dates in each model window" : "grid dates",
               o.out);
    free(rows.v);
    wf_sn_sample_free(&s);
    return st ? fail(st) : 0;
}

/* The dates of --mjd: every comma-separated entry a finite number, at least one. */
static int mjd_list(const char *text, double **out, size_t *n)
{
    size_t cap = 1;
    for (const char *p = text; *p; p++) cap += *p == ',';
    double *v = malloc(cap * sizeof *v);
    if (!v) return fail(wf_error(WF_ERR_NOMEM, "out of memory for %zu dates", cap));
    size_t k = 0;
    for (const char *p = text;; k++) {
        const char *e = strchr(p, ',');
        size_t len = e ? (size_t)(e - p) : strlen(p);
        char item[64];
        if (!len || len >= sizeof item) {
            fprintf(stderr, "wfisim sn: --mjd '%s': date %zu is %s\n", text, k + 1, len ? "too long" : "empty");
            free(v);
            return 2;
        }
        memcpy(item, p, len);
        item[len] = '\0';
        if (number("--mjd", item, &v[k])) { free(v); return 2; }
        if (!e) break;
        p = e + 1;
    }
    *out = v;
    *n = k + 1;
    return 0;
}

static int cmd_lightcurve(int argc, char **argv)
{
    opts o;
    int rc = parse(argc, argv, &o);
    if (rc) return rc;
    if (!isfinite(o.z) || !isfinite(o.t0) || !o.band || !o.mjd)
        return usage_error("%s are required", "--z, --t0, --band and --mjd");
    if (isfinite(o.x0) && isfinite(o.mu)) return usage_error("%s", "give --x0 or --mu, not both");
    if (!(o.z > 0)) return usage_error("%s must be > 0", "--z");
    /* the bounds of sn.x1.* and sn.c.*: beyond them the Tripp magnitude and the colour law
     * overflow, and x0 or the flux would come out as 0 or inf under another option's name */
    if (!(fabs(o.x1) <= WF_SNPOP_X1_LIMIT)) return out_of_range("--x1", o.x1, WF_SNPOP_X1_LIMIT);
    if (!(fabs(o.c) <= WF_SNPOP_C_LIMIT)) return out_of_range("--c", o.c, WF_SNPOP_C_LIMIT);
    if (isfinite(o.mu) && !(o.mu > 0 && o.mu <= WF_SNPOP_MU_MAX)) {
        char msg[160];
        snprintf(msg, sizeof msg, "--mu %g is out of range (above 0 to %g mag)", o.mu, WF_SNPOP_MU_MAX);
        return usage_error("%s", msg);
    }
    if (isfinite(o.x0) && !(o.x0 > 0)) return usage_error("%s must be > 0", "--x0");
    wf_salt_interp interp = WF_SALT_INTERP_BICUBIC;
    if (o.interp && !strcmp(o.interp, "linear")) interp = WF_SALT_INTERP_LINEAR;
    else if (o.interp && strcmp(o.interp, "bicubic")) return usage_error("--interp '%s': bicubic or linear", o.interp);
    double *mjds = NULL;
    size_t nmjd = 0;
    if ((rc = mjd_list(o.mjd, &mjds, &nmjd))) return rc;
    wf_filter f;
    wf_status st = wf_filter_parse(o.band, &f);
    if (st) { free(mjds); return fail(st); }
    wf_snpop pop;
    wf_snpop_default(&pop);
    pop.alpha = o.alpha, pop.beta = o.beta;
    double x0 = o.x0;
    if (!isfinite(x0)) {
        double mu = o.mu;
        if (!isfinite(mu)) {
            wf_cosmo c;
            if ((st = wf_cosmo_init(&c, o.h0, o.om)) || (st = wf_cosmo_distance_modulus(&c, o.z, &mu))) {
                free(mjds);
                return fail(st);
            }
        }
        /* SPEC 5 / SNANA SALT2x0calc with no intrinsic scatter */
        if ((st = wf_snpop_x0(&pop, mu, o.x1, o.c, 0.0, &x0))) { free(mjds); return fail(st); }
    }
    wf_bandpass bp;
    wf_salt_model *m = NULL;
    if ((st = wf_bandpass_load(f, o.data, &bp)) || (st = wf_salt_load(o.model, &m))) { free(mjds); return fail(st); }
    wf_salt_params p = {o.z, o.t0, x0, o.x1, o.c};
    printf("# model %s, band %s (%s), z %.6g, t0 %.6f, x0 %.8g, x1 %.6g, c %.6g\n", wf_salt_name(m), wf_filter_name(f),
           bp.builtin ? "built-in top-hat" : "data", o.z, o.t0, x0, o.x1, o.c);
    printf("# mjd mag_ab flux_e_per_s flag\n");
    for (size_t i = 0; i < nmjd && !st; i++) {
        double rate, mag;
        unsigned flags;
        st = wf_salt_bandrate(m, &p, interp, &bp, mjds[i], &rate, &flags);
        mag = WF_SALT_MAG_NONE;
        if (!st && rate > 0) st = wf_bandpass_mag_ab(&bp, rate, &mag);
        if (!st) printf("%.6f %.6f %.9g %u\n", mjds[i], mag, rate, flags);
    }
    wf_salt_free(m);
    free(mjds);
    return st ? fail(st) : 0;
}

int wf_cmd_sn(int argc, char **argv)
{
    if (argc < 1) return usage_error("%s", "which sn command?");
    if (!strcmp(argv[0], "--help") || !strcmp(argv[0], "-h") || !strcmp(argv[0], "help")) {
        fputs(sn_usage, stdout);
        return 0;
    }
    if (!strcmp(argv[0], "generate")) return cmd_generate(argc - 1, argv + 1);
    if (!strcmp(argv[0], "lightcurves")) return cmd_lightcurves(argc - 1, argv + 1);
    if (!strcmp(argv[0], "lightcurve")) return cmd_lightcurve(argc - 1, argv + 1);
    return usage_error("unknown sn command '%s'", argv[0]);
}
