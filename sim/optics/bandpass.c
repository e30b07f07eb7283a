/* Filters, bandpasses and photometry: see sim/optics/bandpass.h and docs/SKY.md. */
#include "sim/optics/bandpass.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

/* CGS, exact by the 2019 SI definitions. */
#define H_CGS 6.62607015e-27        /* erg s */
#define C_CGS 2.99792458e10         /* cm / s */
#define AB_FNU0 3631.0e-23          /* erg/s/cm²/Hz: the AB zero point, 3631 Jy */
#define EFFAREA_FILE "roman/Roman_effarea_20210614.txt"
#define LINE_MAX_CHARS 4096
#define MAX_COLUMNS 64

static const char *const filter_names[WF_NFILTER] = {"R062", "Z087", "Y106", "J129",
                                                     "H158", "F184", "K213", "W146"};

/* SPEC §2 (Wang et al. 2023 §2.1), µm: centre and width. */
static const double filter_facts_um[WF_NFILTER][2] = {
    {0.620, 0.280}, {0.869, 0.217}, {1.060, 0.265}, {1.293, 0.323},
    {1.577, 0.394}, {1.842, 0.317}, {2.125, 0.350}, {1.464, 1.030}};

static int filter_valid(wf_filter f) { return (int)f >= 0 && f < WF_NFILTER; }

const char *wf_filter_name(wf_filter f) { return filter_valid(f) ? filter_names[f] : "?"; }

int wf_filter_lookup(const char *name, wf_filter *out)
{
    for (int i = 0; i < WF_NFILTER; i++)
        if (!strcasecmp(name, filter_names[i])) {
            *out = (wf_filter)i;
            return 1;
        }
    /* GalSim and the older literature call the wide filter W149; it is the same element. */
    if (!strcasecmp(name, "W149")) {
        *out = WF_W146;
        return 1;
    }
    return 0;
}

wf_status wf_filter_parse(const char *name, wf_filter *out)
{
    if (!name) return wf_error(WF_ERR_INPUT, "filter: no name given");
    if (wf_filter_lookup(name, out)) return WF_OK;
    return wf_error(WF_ERR_INPUT,
                    "unknown filter '%s' (valid: R062 Z087 Y106 J129 H158 F184 K213 W146; "
                    "W149 means W146)",
                    name);
}

wf_status wf_filter_facts(wf_filter f, double *centre_nm, double *width_nm)
{
    if (!filter_valid(f)) return wf_error(WF_ERR_RANGE, "filter: %d is not a filter", (int)f);
    if (centre_nm) *centre_nm = 1000.0 * filter_facts_um[f][0];
    if (width_nm) *width_nm = 1000.0 * filter_facts_um[f][1];
    return WF_OK;
}

/* Every moment is an integral of the linear interpolant, done exactly piece by piece, so
 * the zero point of a curve does not depend on an integration rule (a trapezoid on the
 * 5 nm grid would differ from it by ~1e-5 mag in R062, less redward). */
static wf_status finish(wf_bandpass *bp)
{
    double it = 0.0, ilt = 0.0, itl = 0.0;
    for (int k = 0; k + 1 < bp->n; k++) {
        double x0 = bp->wave_nm[k], x1 = bp->wave_nm[k + 1], h = x1 - x0;
        double t0 = bp->throughput[k], t1 = bp->throughput[k + 1];
        double s = (t1 - t0) / h;
        it += 0.5 * h * (t0 + t1);
        /* product of two linear functions: exact with the end-point weights 2:1:1:2 */
        ilt += h * (t0 * (2.0 * x0 + x1) + t1 * (x0 + 2.0 * x1)) / 6.0;
        /* ∫ (t0 + s (λ - x0)) / λ dλ = (t0 - s x0) ln(x1/x0) + s h; log1p keeps the
         * logarithm of a ratio near 1 accurate. */
        itl += (t0 - s * x0) * log1p(h / x0) + s * h;
    }
    if (!(it > 0.0) || !(itl > 0.0))
        return wf_error(WF_ERR_INPUT, "bandpass %s (%s): throughput is zero everywhere",
                        wf_filter_name(bp->filter), bp->source);
    bp->int_t = it;
    bp->int_t_over_lambda = itl;
    bp->lambda_eff_nm = ilt / it;
    bp->lambda_pivot_nm = sqrt(ilt / itl);
    bp->blue_nm = bp->wave_nm[0];
    bp->red_nm = bp->wave_nm[bp->n - 1];
    double n0 = bp->area_cm2 * AB_FNU0 / H_CGS * itl; /* e-/s at AB magnitude 0 */
    bp->zp_ab = 2.5 * log10(n0);
    bp->zp_photon = bp->zp_ab - 2.5 * log10(bp->area_cm2);
    return WF_OK;
}

static void tophat_fill(wf_filter f, wf_bandpass *out)
{
    double c = 1000.0 * filter_facts_um[f][0], w = 1000.0 * filter_facts_um[f][1];
    out->filter = f;
    out->builtin = 1;
    out->area_cm2 = WF_COLLECTING_AREA_CM2;
    /* Two samples at throughput 1: the interpolant is 1 between them and 0 outside, which
     * is the top-hat with no invented edge slope. */
    out->n = 2;
    out->wave_nm[0] = c - 0.5 * w;
    out->wave_nm[1] = c + 0.5 * w;
    out->throughput[0] = out->throughput[1] = 1.0;
}

wf_status wf_bandpass_tophat(wf_filter f, wf_bandpass *out)
{
    if (!filter_valid(f)) return wf_error(WF_ERR_RANGE, "bandpass: %d is not a filter", (int)f);
    tophat_fill(f, out);
    snprintf(out->source, sizeof out->source, "built-in top-hat (SPEC §2 centre/width, T = 1)");
    return finish(out);
}

/* Splits a line into numbers; returns the count, or -1 with *bad at the first field that
 * is not a finite number. */
static int parse_numbers(char *line, double *v, int maxv, char **bad)
{
    int n = 0;
    char *save = NULL;
    for (char *tok = strtok_r(line, " \t\r\n,", &save); tok;
         tok = strtok_r(NULL, " \t\r\n,", &save)) {
        char *end;
        errno = 0;
        double x = strtod(tok, &end);
        if (end == tok || *end || errno == ERANGE || !isfinite(x)) {
            *bad = tok;
            return -1;
        }
        if (n < maxv) v[n] = x;
        n++;
    }
    return n;
}

static int blank_or_comment(const char *s)
{
    while (isspace((unsigned char)*s)) s++;
    return *s == '\0' || *s == '#';
}

/* Reads one filter's column. The header ("Wave R062 Z087 ...", an optional leading '#')
 * names the columns, so a file with its columns in another order still loads. */
static wf_status read_effarea(FILE *fp, const char *path, wf_filter f, wf_bandpass *out)
{
    char line[LINE_MAX_CHARS];
    int lineno = 0, col = -1, ncol = 0;
    char names[LINE_MAX_CHARS] = "";

    while (fgets(line, sizeof line, fp)) {
        lineno++;
        if (!strchr(line, '\n') && !feof(fp))
            return wf_error(WF_ERR_INPUT, "%s:%d: line longer than %d characters", path,
                            lineno, LINE_MAX_CHARS - 1);
        char *p = line;
        while (isspace((unsigned char)*p)) p++;
        if (*p == '\0') continue;
        if (*p == '#') p++;
        int i = 0;
        char *save = NULL;
        for (char *tok = strtok_r(p, " \t\r\n,", &save); tok;
             tok = strtok_r(NULL, " \t\r\n,", &save), i++) {
            if (i == 0 && strcasecmp(tok, "Wave") && strcasecmp(tok, "Wavelength"))
                return wf_error(WF_ERR_INPUT,
                                "%s:%d: header must start with 'Wave' (wavelength in µm), "
                                "found '%s'",
                                path, lineno, tok);
            size_t used = strlen(names);
            snprintf(names + used, sizeof names - used, "%s%s", i ? " " : "", tok);
            if (i > 0 && col < 0) {
                wf_filter g;
                if (wf_filter_lookup(tok, &g) && g == f) col = i;
            }
        }
        ncol = i;
        break;
    }
    if (ncol == 0) return wf_error(WF_ERR_INPUT, "%s: empty file (no header line)", path);
    if (col < 0)
        return wf_error(WF_ERR_INPUT, "%s:%d: no column for filter %s (columns: %s)", path,
                        lineno, wf_filter_name(f), names);
    if (ncol > MAX_COLUMNS)
        return wf_error(WF_ERR_INPUT, "%s:%d: %d columns, at most %d supported", path, lineno,
                        ncol, MAX_COLUMNS);

    int n = 0;
    while (fgets(line, sizeof line, fp)) {
        lineno++;
        if (!strchr(line, '\n') && !feof(fp))
            return wf_error(WF_ERR_INPUT, "%s:%d: line longer than %d characters", path,
                            lineno, LINE_MAX_CHARS - 1);
        if (blank_or_comment(line)) continue;
        double v[MAX_COLUMNS];
        char *bad = NULL;
        int got = parse_numbers(line, v, MAX_COLUMNS, &bad);
        if (got < 0)
            return wf_error(WF_ERR_INPUT, "%s:%d: '%s' is not a number", path, lineno, bad);
        if (got != ncol)
            return wf_error(WF_ERR_INPUT, "%s:%d: %d fields, the header names %d", path,
                            lineno, got, ncol);
        if (n == WF_BANDPASS_MAXN)
            return wf_error(WF_ERR_INPUT, "%s:%d: more than %d samples", path, lineno,
                            WF_BANDPASS_MAXN);
        double wave = 1000.0 * v[0], area_m2 = v[col];
        if (!(wave > 0.0))
            return wf_error(WF_ERR_INPUT, "%s:%d: wavelength %g µm is not positive", path,
                            lineno, v[0]);
        if (n > 0 && !(wave > out->wave_nm[n - 1]))
            return wf_error(WF_ERR_INPUT, "%s:%d: wavelength %g µm does not increase", path,
                            lineno, v[0]);
        if (area_m2 < 0.0)
            return wf_error(WF_ERR_INPUT, "%s:%d: %s effective area %g m² is negative", path,
                            lineno, wf_filter_name(f), area_m2);
        out->wave_nm[n] = wave;
        out->throughput[n] = area_m2 * 1.0e4 / out->area_cm2;
        n++;
    }
    if (ferror(fp)) return wf_error(WF_ERR_IO, "%s: read error", path);
    if (n < 2) return wf_error(WF_ERR_INPUT, "%s: %d data lines, need at least 2", path, n);
    out->n = n;
    return WF_OK;
}

/* Keeps the samples where the interpolant is non-zero plus one zero on each side: the
 * integrals are unchanged and every later integral walks only the band. */
static void trim_support(wf_bandpass *bp)
{
    int first = 0, last = bp->n - 1;
    while (first < bp->n && bp->throughput[first] == 0.0) first++;
    while (last >= 0 && bp->throughput[last] == 0.0) last--;
    if (first > last) return; /* all zero: finish() reports it */
    if (first > 0) first--;
    if (last < bp->n - 1) last++;
    int n = last - first + 1;
    memmove(bp->wave_nm, bp->wave_nm + first, (size_t)n * sizeof bp->wave_nm[0]);
    memmove(bp->throughput, bp->throughput + first, (size_t)n * sizeof bp->throughput[0]);
    bp->n = n;
}

wf_status wf_bandpass_load(wf_filter f, const char *data_dir, wf_bandpass *out)
{
    if (!filter_valid(f)) return wf_error(WF_ERR_RANGE, "bandpass: %d is not a filter", (int)f);
    if (!data_dir || !*data_dir) {
        tophat_fill(f, out);
        snprintf(out->source, sizeof out->source,
                 "built-in top-hat (SPEC §2 centre/width, T = 1): no data directory given");
        return finish(out);
    }
    char path[WF_BANDPASS_SOURCE_MAX - 64];
    int len = snprintf(path, sizeof path, "%s/%s", data_dir, EFFAREA_FILE);
    if (len < 0 || (size_t)len >= sizeof path)
        return wf_error(WF_ERR_INPUT, "bandpass: data directory path too long: %s", data_dir);
    FILE *fp = fopen(path, "r");
    if (!fp) {
        if (errno != ENOENT)
            return wf_error(WF_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
        tophat_fill(f, out);
        snprintf(out->source, sizeof out->source,
                 "built-in top-hat (SPEC §2 centre/width, T = 1): %s not found", path);
        return finish(out);
    }
    out->filter = f;
    out->builtin = 0;
    out->area_cm2 = WF_COLLECTING_AREA_CM2;
    wf_status st = read_effarea(fp, path, f, out);
    fclose(fp);
    if (st != WF_OK) return st;
    snprintf(out->source, sizeof out->source, "%s", path);
    trim_support(out);
    return finish(out);
}

/* Index k of the interval [wave[k], wave[k+1]] holding x (caller checks the range). */
static int interval_of(const wf_bandpass *bp, double x)
{
    int lo = 0, hi = bp->n - 1;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (bp->wave_nm[mid] <= x) lo = mid;
        else hi = mid;
    }
    return lo;
}

double wf_bandpass_throughput(const wf_bandpass *bp, double wave_nm)
{
    if (!(wave_nm >= bp->wave_nm[0] && wave_nm <= bp->wave_nm[bp->n - 1])) return 0.0;
    int k = interval_of(bp, wave_nm);
    double x0 = bp->wave_nm[k], x1 = bp->wave_nm[k + 1];
    double u = (wave_nm - x0) / (x1 - x0);
    return bp->throughput[k] + u * (bp->throughput[k + 1] - bp->throughput[k]);
}

double wf_bandpass_countrate_ab(const wf_bandpass *bp, double mag)
{
    return pow(10.0, 0.4 * (bp->zp_ab - mag));
}

wf_status wf_bandpass_mag_ab(const wf_bandpass *bp, double rate, double *mag)
{
    if (!(rate > 0.0) || !isfinite(rate))
        return wf_error(WF_ERR_RANGE, "bandpass %s: count rate %g e-/s has no magnitude",
                        wf_filter_name(bp->filter), rate);
    *mag = bp->zp_ab - 2.5 * log10(rate);
    return WF_OK;
}

wf_status wf_bandpass_countrate_sed_step(const wf_bandpass *bp, wf_bandpass_sed_fn sed,
                                         void *ctx, double max_step_nm, double *rate)
{
    if (!sed) return wf_error(WF_ERR_INPUT, "bandpass: no SED function");
    if (!(max_step_nm > 0.0) || !isfinite(max_step_nm))
        return wf_error(WF_ERR_RANGE, "bandpass: integration step %g nm must be > 0",
                        max_step_nm);
    double sum = 0.0; /* ∫ T f_λ λ dλ, (erg/s/cm²/Å) nm² */
    for (int k = 0; k + 1 < bp->n; k++) {
        double x0 = bp->wave_nm[k], x1 = bp->wave_nm[k + 1];
        double t0 = bp->throughput[k], t1 = bp->throughput[k + 1];
        if (t0 == 0.0 && t1 == 0.0) continue;
        int m = (int)ceil((x1 - x0) / max_step_nm - 1e-9);
        if (m < 1) m = 1;
        double h = (x1 - x0) / m;
        double piece = 0.0, fa = 0.0;
        for (int j = 0; j <= 2 * m; j++) {
            /* nodes at half steps: even j are sub-interval ends, odd j their midpoints */
            double u = (double)j / (2.0 * m);
            double x = j == 2 * m ? x1 : x0 + (x1 - x0) * u;
            double flam = sed(x, ctx);
            if (!isfinite(flam))
                return wf_error(WF_ERR_INPUT,
                                "bandpass %s: SED is not finite (%g) at %.3f nm",
                                wf_filter_name(bp->filter), flam, x);
            double fx = (t0 + (t1 - t0) * u) * flam * x;
            if (j == 0) fa = fx;
            else if (j % 2) piece += 4.0 * fx;
            else {
                piece += fa + fx;
                fa = fx;
            }
        }
        sum += piece * h / 6.0;
    }
    /* f_λ per Å -> per nm (x10); λ in nm -> cm (1e-7) in the photon energy hc/λ. */
    *rate = bp->area_cm2 * sum * 10.0 * 1.0e-7 / (H_CGS * C_CGS);
    return WF_OK;
}

wf_status wf_bandpass_countrate_sed(const wf_bandpass *bp, wf_bandpass_sed_fn sed, void *ctx,
                                    double *rate)
{
    return wf_bandpass_countrate_sed_step(bp, sed, ctx, 1.0, rate);
}

wf_status wf_bandpass_flat_slices(const wf_bandpass *bp, int nl, double *lambda_nm, double *weight)
{
    if (nl < 1) return wf_error(WF_ERR_RANGE, "%s: %d wavelength slices", wf_filter_name(bp->filter), nl);
    double lo = bp->blue_nm, hi = bp->red_nm, width = (hi - lo) / nl, total = 0;
    for (int k = 0; k < nl; k++) {
        double a = lo + k * width, s = 0;
        const int steps = 200;
        for (int t = 0; t < steps; t++) {
            double x = a + (t + 0.5) * width / steps;
            s += wf_bandpass_throughput(bp, x) / x;
        }
        lambda_nm[k] = a + 0.5 * width;
        weight[k] = s * width / steps;
        total += weight[k];
    }
    if (!(total > 0)) return wf_error(WF_ERR_INPUT, "%s: the bandpass has no throughput", wf_filter_name(bp->filter));
    for (int k = 0; k < nl; k++) weight[k] /= total;
    return WF_OK;
}
