/* SALT2/SALT3 light curves (sim/sn/salt.h). */
#include "sim/sn/salt.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "sim/numeric/quadrature.h"

#define H_CGS 6.62607015e-27 /* erg s, as sim/optics/bandpass.c */
#define C_CGS 2.99792458e10  /* cm / s */
#define SALT_SCALE 1e-12     /* x0 normalisation of the template values (SNANA X0SCALE) */
#define CL_B_AA 4302.57      /* reduced colour-law wavelength 0 ... */
#define CL_V_AA 5428.55      /* ... and 1 (SALT2 code, SNANA B_WAVELENGTH/V_WAVELENGTH) */
#define KEYS_A (-0.5)        /* cubic-convolution kernel parameter of snfit */
#define LINE_MAX_CHARS 4096
#define PATH_CHARS 4200

struct wf_salt_model {
    char name[8];
    int np, nw;
    double *phase; /* np, strictly increasing */
    double *wave;  /* nw, Å, strictly increasing */
    double *m0;    /* np × nw, phase-major, file values (× 1e-12 x0 gives erg/s/cm²/Å) */
    double *m1;
    /* colour law P(x) = Σ_k coef[k] x^(k+1), coef[0] = α = 1 − Σ a */
    int ncoef;
    double coef[WF_SALT_MAX_COLOR_COEFFS + 1];
    double x_lo, x_hi;   /* reduced wavelengths of min_lambda / max_lambda */
    double p_lo, p_hi;   /* P there */
    double dp_lo, dp_hi; /* P' there */
};

struct wf_salt_lc {
    double t0, zp1, zp_ab;
    int covered;
    wf_salt_interp interp;
    int np;
    double *phase; /* np: copy of the model's phases */
    double *core;  /* np: e-/s from wavelengths interpolated by cubic convolution */
    double *edge;  /* np: e-/s from wavelengths in the bilinear edge intervals */
    double *lin;   /* np: e-/s with wavelengths interpolated linearly */
};

/* ------------------------------------------------------------------ colour law */

static double poly_p(const wf_salt_model *m, double x)
{
    double out = 0.0;
    for (int k = m->ncoef - 1; k >= 0; k--) out = x * (m->coef[k] + out);
    return out;
}

static double poly_dp(const wf_salt_model *m, double x)
{
    double out = 0.0;
    for (int k = m->ncoef - 1; k >= 0; k--) out = out * x + (k + 1) * m->coef[k];
    return out;
}

/* P(x) continued linearly outside [x_lo, x_hi]. */
static double color_p(const wf_salt_model *m, double wave_aa)
{
    double x = (wave_aa - CL_B_AA) / (CL_V_AA - CL_B_AA);
    if (x < m->x_lo) return m->p_lo + m->dp_lo * (x - m->x_lo);
    if (x > m->x_hi) return m->p_hi + m->dp_hi * (x - m->x_hi);
    return poly_p(m, x);
}

double wf_salt_colorlaw(const wf_salt_model *m, double rest_wave_aa)
{
    return -color_p(m, rest_wave_aa);
}

/* 10^(−0.4 c CL) = 10^(0.4 c P) */
static double color_factor(const wf_salt_model *m, double c, double wave_aa)
{
    return c == 0.0 ? 1.0 : exp(0.4 * M_LN10 * c * color_p(m, wave_aa));
}

/* ------------------------------------------------------------------ interpolation */

/* Where x falls on one axis and with what weights. */
typedef struct axis_w {
    int i;       /* v[i] <= x <= v[i+1] */
    int cubic;   /* 1: nodes i-1..i+2 with w[0..3]; 0: linear with a */
    double a;    /* (x - v[i]) / (v[i+1] - v[i]) */
    double w[4];
} axis_w;

/* i with v[i] <= x < v[i+1], clamped to 0..n-2 (x at the last node gives n-2). */
static int find_index(const double *v, int n, double x)
{
    if (x < v[0]) return 0;
    if (x >= v[n - 1]) return n - 2;
    int lo = 0, hi = n - 1;
    while (hi - lo > 1) {
        int mid = lo + (hi - lo) / 2;
        if (x >= v[mid]) lo = mid;
        else hi = mid;
    }
    return lo;
}

static double keys_kernel(double s)
{
    s = fabs(s);
    if (s >= 2.0) return 0.0;
    if (s < 1.0) return s * s * ((KEYS_A + 2.0) * s - (KEYS_A + 3.0)) + 1.0;
    return KEYS_A * (-4.0 + s * (8.0 + s * (-5.0 + s)));
}

/* x must lie within [v[0], v[n-1]]. The cubic rule (interior intervals only) is sncosmo's. */
static void axis_weights(const double *v, int n, double x, wf_salt_interp interp, axis_w *out)
{
    int i = find_index(v, n, x);
    double t = (x - v[i]) / (v[i + 1] - v[i]);
    out->i = i;
    out->a = t;
    out->cubic = interp == WF_SALT_INTERP_BICUBIC && n >= 4 && i >= 1 && i <= n - 3;
    if (out->cubic) {
        out->w[0] = keys_kernel(1.0 + t);
        out->w[1] = keys_kernel(t);
        out->w[2] = keys_kernel(1.0 - t);
        out->w[3] = keys_kernel(2.0 - t);
    }
}

/* M0 + x1 M1 at the point described by the phase and wavelength weights. Bilinear in both
 * axes when either is not cubic (snfit's rule, kept for agreement with sncosmo). */
static double grid_eval(const wf_salt_model *m, double x1, const axis_w *pw, const axis_w *ww)
{
    int nw = m->nw;
    if (pw->cubic && ww->cubic) {
        double s0 = 0.0, s1 = 0.0;
        for (int k = 0; k < 4; k++) {
            const double *r0 = m->m0 + (size_t)(pw->i - 1 + k) * nw + (ww->i - 1);
            const double *r1 = m->m1 + (size_t)(pw->i - 1 + k) * nw + (ww->i - 1);
            double a0 = ww->w[0] * r0[0] + ww->w[1] * r0[1] + ww->w[2] * r0[2] + ww->w[3] * r0[3];
            double a1 = ww->w[0] * r1[0] + ww->w[1] * r1[1] + ww->w[2] * r1[2] + ww->w[3] * r1[3];
            s0 += pw->w[k] * a0;
            s1 += pw->w[k] * a1;
        }
        return s0 + x1 * s1;
    }
    size_t i00 = (size_t)pw->i * nw + ww->i, i10 = i00 + nw;
    double ap = pw->a, aw = ww->a;
    double v0 = (1.0 - ap) * ((1.0 - aw) * m->m0[i00] + aw * m->m0[i00 + 1]) +
                ap * ((1.0 - aw) * m->m0[i10] + aw * m->m0[i10 + 1]);
    double v1 = (1.0 - ap) * ((1.0 - aw) * m->m1[i00] + aw * m->m1[i00 + 1]) +
                ap * ((1.0 - aw) * m->m1[i10] + aw * m->m1[i10 + 1]);
    return v0 + x1 * v1;
}

/* ------------------------------------------------------------------ loading */

static int blank_or_comment(const char *s)
{
    while (isspace((unsigned char)*s)) s++;
    return *s == '\0' || *s == '#';
}

static int file_exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 && S_ISREG(st.st_mode);
}

typedef struct grid {
    int np, nw;
    double *phase, *wave, *val;
    size_t cap_p, cap_w, cap_v;
} grid;

static void grid_free(grid *g)
{
    free(g->phase);
    free(g->wave);
    free(g->val);
    memset(g, 0, sizeof *g);
}

static int push(double **arr, size_t *cap, size_t n, double x)
{
    if (n >= *cap) {
        size_t nc = *cap ? 2 * *cap : 1024;
        double *p = realloc(*arr, nc * sizeof *p);
        if (!p) return -1;
        *arr = p;
        *cap = nc;
    }
    (*arr)[n] = x;
    return 0;
}

static const char *const field_names[3] = {"phase", "wavelength", "value"};

/* Reads "phase wavelength value" rows: phases in blocks, every block on the first block's
 * wavelengths. */
static wf_status read_grid(const char *path, grid *g)
{
    memset(g, 0, sizeof *g);
    FILE *fp = fopen(path, "r");
    if (!fp) return wf_error(WF_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
    char line[LINE_MAX_CHARS];
    int lineno = 0, iw = 0; /* iw: index of the next wavelength in the current block */
    size_t nval = 0;
    wf_status st = WF_OK;
    while (fgets(line, sizeof line, fp)) {
        lineno++;
        if (!strchr(line, '\n') && !feof(fp)) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: line longer than %d characters", path, lineno,
                          LINE_MAX_CHARS - 1);
            break;
        }
        if (blank_or_comment(line)) continue;
        double v[3];
        int nf = 0;
        char *save = NULL;
        for (char *tok = strtok_r(line, " \t\r\n", &save); tok;
             tok = strtok_r(NULL, " \t\r\n", &save), nf++) {
            if (nf >= 3) continue;
            char *end;
            errno = 0;
            double x = strtod(tok, &end);
            if (end == tok || *end || errno == ERANGE || !isfinite(x)) {
                st = wf_error(WF_ERR_INPUT, "%s:%d: field %d (%s) '%s' is not a finite number",
                              path, lineno, nf + 1, field_names[nf], tok);
                goto done;
            }
            v[nf] = x;
        }
        if (nf != 3) {
            st = wf_error(WF_ERR_INPUT,
                          "%s:%d: %d fields, expected 3 (phase wavelength value)", path,
                          lineno, nf);
            break;
        }
        int new_block = g->np == 0 || v[0] != g->phase[g->np - 1];
        if (new_block) {
            if (g->np == 1) g->nw = iw; /* the first block sets the wavelengths */
            if (g->np >= 1 && iw != g->nw) {
                st = wf_error(WF_ERR_INPUT,
                              "%s:%d: phase %g has %d wavelengths, the first phase has %d",
                              path, lineno, g->phase[g->np - 1], iw, g->nw);
                break;
            }
            if (g->np >= 1 && !(v[0] > g->phase[g->np - 1])) {
                st = wf_error(WF_ERR_INPUT,
                              "%s:%d: field 1 (phase) %g does not increase (previous phase "
                              "%g); rows must be phase-major",
                              path, lineno, v[0], g->phase[g->np - 1]);
                break;
            }
            if (push(&g->phase, &g->cap_p, (size_t)g->np, v[0])) goto nomem;
            g->np++;
            iw = 0;
        }
        if (g->np == 1) {
            if (iw > 0 && !(v[1] > g->wave[iw - 1])) {
                st = wf_error(WF_ERR_INPUT,
                              "%s:%d: field 2 (wavelength) %g does not increase (previous %g)",
                              path, lineno, v[1], g->wave[iw - 1]);
                break;
            }
            if (push(&g->wave, &g->cap_w, (size_t)iw, v[1])) goto nomem;
        } else if (iw >= g->nw || v[1] != g->wave[iw]) {
            if (iw >= g->nw)
                st = wf_error(WF_ERR_INPUT,
                              "%s:%d: phase %g has more than the %d wavelengths of the first "
                              "phase",
                              path, lineno, v[0], g->nw);
            else
                st = wf_error(WF_ERR_INPUT,
                              "%s:%d: field 2 (wavelength) %g differs from %g, wavelength %d "
                              "of the first phase",
                              path, lineno, v[1], g->wave[iw], iw + 1);
            break;
        }
        if (push(&g->val, &g->cap_v, nval, v[2])) goto nomem;
        nval++;
        iw++;
    }
    if (st == WF_OK && ferror(fp)) st = wf_error(WF_ERR_IO, "%s: read error", path);
    if (st == WF_OK) {
        if (g->np == 1) g->nw = iw;
        if (g->np >= 1 && iw != g->nw)
            st = wf_error(WF_ERR_INPUT, "%s:%d: last phase %g has %d wavelengths, the first %d",
                          path, lineno, g->phase[g->np - 1], iw, g->nw);
        else if (g->np < 2 || g->nw < 2)
            st = wf_error(WF_ERR_INPUT,
                          "%s: %d phases x %d wavelengths; a grid needs at least 2 x 2", path,
                          g->np, g->nw);
    }
    goto done;
nomem:
    st = wf_error(WF_ERR_NOMEM, "%s:%d: out of memory reading the grid", path, lineno);
done:
    fclose(fp);
    if (st != WF_OK) grid_free(g);
    return st;
}

/* Grid of M1 against M0: same phases and wavelengths. Errors point at the M1 row. */
static wf_status same_grid(const grid *a, const char *path_a, const grid *b, const char *path_b)
{
    if (a->np != b->np || a->nw != b->nw)
        return wf_error(WF_ERR_INPUT, "%s: %d phases x %d wavelengths, but %s has %d x %d",
                        path_b, b->np, b->nw, path_a, a->np, a->nw);
    for (int i = 0; i < a->np; i++)
        if (a->phase[i] != b->phase[i])
            return wf_error(WF_ERR_INPUT, "%s:%d: phase %g, but %s has %g there", path_b,
                            i * b->nw + 1, b->phase[i], path_a, a->phase[i]);
    for (int j = 0; j < a->nw; j++)
        if (a->wave[j] != b->wave[j])
            return wf_error(WF_ERR_INPUT, "%s:%d: wavelength %g, but %s has %g there", path_b,
                            j + 1, b->wave[j], path_a, a->wave[j]);
    return WF_OK;
}

/* N, N coefficients, then keyword/value pairs; tokens may be spread over lines. */
static wf_status read_colorlaw(const char *path, wf_salt_model *m)
{
    FILE *fp = fopen(path, "r");
    if (!fp) return wf_error(WF_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
    char line[LINE_MAX_CHARS];
    int lineno = 0, ntok = 0, n = -1, version = -1;
    double a[WF_SALT_MAX_COLOR_COEFFS];
    double lam_lo = 3000.0, lam_hi = 7000.0; /* sncosmo's defaults */
    char key[128] = "";
    int key_line = 0;
    wf_status st = WF_OK;
    while (st == WF_OK && fgets(line, sizeof line, fp)) {
        lineno++;
        if (!strchr(line, '\n') && !feof(fp)) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: line longer than %d characters", path, lineno,
                          LINE_MAX_CHARS - 1);
            break;
        }
        if (blank_or_comment(line)) continue;
        char *save = NULL;
        for (char *tok = strtok_r(line, " \t\r\n", &save); tok && st == WF_OK;
             tok = strtok_r(NULL, " \t\r\n", &save), ntok++) {
            char *end;
            errno = 0;
            if (ntok == 0) {
                long v = strtol(tok, &end, 10);
                if (end == tok || *end || v < 1 || v > WF_SALT_MAX_COLOR_COEFFS)
                    st = wf_error(WF_ERR_INPUT,
                                  "%s:%d: first field '%s' must be the number of colour-law "
                                  "coefficients, 1..%d",
                                  path, lineno, tok, WF_SALT_MAX_COLOR_COEFFS);
                n = (int)v;
                continue;
            }
            if (ntok <= n) {
                double x = strtod(tok, &end);
                if (end == tok || *end || errno == ERANGE || !isfinite(x))
                    st = wf_error(WF_ERR_INPUT,
                                  "%s:%d: colour-law coefficient %d '%s' is not a number", path,
                                  lineno, ntok, tok);
                a[ntok - 1] = x;
                continue;
            }
            if ((ntok - n) % 2 == 1) { /* a keyword */
                snprintf(key, sizeof key, "%s", tok);
                key_line = lineno;
                if (strcmp(key, "Salt2ExtinctionLaw.version") &&
                    strcmp(key, "Salt2ExtinctionLaw.min_lambda") &&
                    strcmp(key, "Salt2ExtinctionLaw.max_lambda"))
                    st = wf_error(WF_ERR_INPUT,
                                  "%s:%d: unknown keyword '%s' (expected "
                                  "Salt2ExtinctionLaw.version, .min_lambda or .max_lambda)",
                                  path, lineno, tok);
                continue;
            }
            double x = strtod(tok, &end);
            if (end == tok || *end || errno == ERANGE || !isfinite(x)) {
                st = wf_error(WF_ERR_INPUT, "%s:%d: value '%s' of %s is not a number", path,
                              lineno, tok, key);
                continue;
            }
            if (!strcmp(key, "Salt2ExtinctionLaw.version")) {
                if (x != 1.0)
                    st = wf_error(WF_ERR_INPUT,
                                  "%s:%d: Salt2ExtinctionLaw.version %s is not supported (only "
                                  "1, the SALT2.2+ law)",
                                  path, lineno, tok);
                version = 1;
            } else if (!strcmp(key, "Salt2ExtinctionLaw.min_lambda")) lam_lo = x;
            else lam_hi = x;
            key[0] = '\0';
        }
    }
    fclose(fp);
    if (st != WF_OK) return st;
    if (n < 0) return wf_error(WF_ERR_INPUT, "%s: empty file (no colour-law coefficients)", path);
    if (ntok < 1 + n)
        return wf_error(WF_ERR_INPUT, "%s:%d: %d colour-law coefficients announced, %d found",
                        path, lineno, n, ntok - 1);
    if (key[0])
        return wf_error(WF_ERR_INPUT, "%s:%d: keyword %s has no value", path, key_line, key);
    if (version != 1)
        return wf_error(WF_ERR_INPUT,
                        "%s: no Salt2ExtinctionLaw.version (the colour-law form is unknown)",
                        path);
    if (!(lam_lo < lam_hi))
        return wf_error(WF_ERR_INPUT,
                        "%s: Salt2ExtinctionLaw.min_lambda %g is not below max_lambda %g", path,
                        lam_lo, lam_hi);
    m->ncoef = n + 1;
    m->coef[0] = 1.0;
    for (int k = 0; k < n; k++) {
        m->coef[k + 1] = a[k];
        m->coef[0] -= a[k];
    }
    m->x_lo = (lam_lo - CL_B_AA) / (CL_V_AA - CL_B_AA);
    m->x_hi = (lam_hi - CL_B_AA) / (CL_V_AA - CL_B_AA);
    m->p_lo = poly_p(m, m->x_lo);
    m->p_hi = poly_p(m, m->x_hi);
    m->dp_lo = poly_dp(m, m->x_lo);
    m->dp_hi = poly_dp(m, m->x_hi);
    return WF_OK;
}

wf_status wf_salt_load(const char *dir, wf_salt_model **out)
{
    if (!out) return wf_error(WF_ERR_INPUT, "salt: no output model");
    *out = NULL;
    if (!dir || !*dir) return wf_error(WF_ERR_INPUT, "salt: no model directory given");
    static const char *const prefixes[2] = {"salt2", "salt3"};
    char path[PATH_CHARS];
    int found = -1;
    for (int k = 0; k < 2; k++) {
        snprintf(path, sizeof path, "%s/%s_template_0.dat", dir, prefixes[k]);
        if (!file_exists(path)) continue;
        if (found >= 0)
            return wf_error(WF_ERR_INPUT,
                            "%s: holds both salt2_template_0.dat and salt3_template_0.dat; "
                            "which model is meant is ambiguous",
                            dir);
        found = k;
    }
    if (found < 0)
        return wf_error(WF_ERR_IO,
                        "%s: no SALT model (neither salt2_template_0.dat nor "
                        "salt3_template_0.dat)",
                        dir);
    const char *pre = prefixes[found];

    wf_salt_model *m = calloc(1, sizeof *m);
    if (!m) return wf_error(WF_ERR_NOMEM, "salt: out of memory");
    snprintf(m->name, sizeof m->name, "%s", pre);
    grid g0, g1;
    char path1[PATH_CHARS];
    snprintf(path, sizeof path, "%s/%s_template_0.dat", dir, pre);
    wf_status st = read_grid(path, &g0);
    if (st != WF_OK) {
        free(m);
        return st;
    }
    snprintf(path1, sizeof path1, "%s/%s_template_1.dat", dir, pre);
    st = read_grid(path1, &g1);
    if (st != WF_OK) {
        grid_free(&g0);
        free(m);
        return st;
    }
    st = same_grid(&g0, path, &g1, path1);
    if (st == WF_OK) {
        snprintf(path, sizeof path, "%s/%s_color_correction.dat", dir, pre);
        st = read_colorlaw(path, m);
    }
    if (st != WF_OK) {
        grid_free(&g0);
        grid_free(&g1);
        free(m);
        return st;
    }
    m->np = g0.np;
    m->nw = g0.nw;
    m->phase = g0.phase;
    m->wave = g0.wave;
    m->m0 = g0.val;
    m->m1 = g1.val;
    free(g1.phase);
    free(g1.wave);
    *out = m;
    return WF_OK;
}

void wf_salt_free(wf_salt_model *m)
{
    if (!m) return;
    free(m->phase);
    free(m->wave);
    free(m->m0);
    free(m->m1);
    free(m);
}

const char *wf_salt_name(const wf_salt_model *m) { return m ? m->name : "?"; }

void wf_salt_phase_range(const wf_salt_model *m, double *min_day, double *max_day)
{
    if (min_day) *min_day = m->phase[0];
    if (max_day) *max_day = m->phase[m->np - 1];
}

void wf_salt_wave_range(const wf_salt_model *m, double *min_aa, double *max_aa)
{
    if (min_aa) *min_aa = m->wave[0];
    if (max_aa) *max_aa = m->wave[m->nw - 1];
}

/* ------------------------------------------------------------------ evaluation */

static wf_status check_params(const wf_salt_params *p)
{
    if (!p) return wf_error(WF_ERR_INPUT, "salt: no SN parameters");
    if (!isfinite(p->z) || p->z < 0.0)
        return wf_error(WF_ERR_RANGE, "salt: parameter z = %g must be finite and >= 0", p->z);
    if (!isfinite(p->t0))
        return wf_error(WF_ERR_RANGE, "salt: parameter t0 = %g must be finite", p->t0);
    if (!isfinite(p->x0) || p->x0 < 0.0)
        return wf_error(WF_ERR_RANGE, "salt: parameter x0 = %g must be finite and >= 0", p->x0);
    if (!isfinite(p->x1))
        return wf_error(WF_ERR_RANGE, "salt: parameter x1 = %g must be finite", p->x1);
    if (!isfinite(p->c))
        return wf_error(WF_ERR_RANGE, "salt: parameter c = %g must be finite", p->c);
    return WF_OK;
}

static wf_status check_interp(wf_salt_interp interp)
{
    if (interp != WF_SALT_INTERP_BICUBIC && interp != WF_SALT_INTERP_LINEAR)
        return wf_error(WF_ERR_RANGE, "salt: interpolation %d is neither BICUBIC (0) nor "
                                      "LINEAR (1)",
                        (int)interp);
    return WF_OK;
}

wf_status wf_salt_flux(const wf_salt_model *m, const wf_salt_params *p, wf_salt_interp interp,
                       double rest_phase, double rest_wave_aa, double *f)
{
    if (!m || !f) return wf_error(WF_ERR_INPUT, "salt: no model or output");
    wf_status st = check_params(p);
    if (st == WF_OK) st = check_interp(interp);
    if (st != WF_OK) return st;
    if (!isfinite(rest_phase) || !isfinite(rest_wave_aa))
        return wf_error(WF_ERR_RANGE, "salt: flux at phase %g, wavelength %g Å: not finite",
                        rest_phase, rest_wave_aa);
    *f = 0.0;
    if (rest_phase < m->phase[0] || rest_phase > m->phase[m->np - 1] ||
        rest_wave_aa < m->wave[0] || rest_wave_aa > m->wave[m->nw - 1])
        return WF_OK;
    axis_w pw, ww;
    axis_weights(m->phase, m->np, rest_phase, interp, &pw);
    axis_weights(m->wave, m->nw, rest_wave_aa, interp, &ww);
    *f = p->x0 * SALT_SCALE * grid_eval(m, p->x1, &pw, &ww) *
         color_factor(m, p->c, rest_wave_aa);
    return WF_OK;
}

/* Out-of-model flags for a band at redshift z (the wavelength rule of sim/sn/salt.h). */
static unsigned wave_flags(const wf_salt_model *m, const wf_bandpass *bp, double zp1)
{
    double lo = 10.0 * bp->blue_nm / zp1, hi = 10.0 * bp->red_nm / zp1;
    return lo < m->wave[0] || hi > m->wave[m->nw - 1] ? WF_SALT_OUT_WAVE : 0u;
}

typedef struct sed_ctx {
    const wf_salt_model *m;
    wf_salt_interp interp;
    axis_w pw;
    double zp1, scale, x1, c;
} sed_ctx;

/* Observer-frame f_λ (erg/s/cm²/Å) at wave_nm, for wf_bandpass_countrate_sed. */
static double salt_sed(double wave_nm, void *vctx)
{
    const sed_ctx *s = vctx;
    const wf_salt_model *m = s->m;
    double lr = 10.0 * wave_nm / s->zp1;
    /* the coverage test used the same expression; the clamp only absorbs rounding */
    if (lr < m->wave[0]) lr = m->wave[0];
    if (lr > m->wave[m->nw - 1]) lr = m->wave[m->nw - 1];
    axis_w ww;
    axis_weights(m->wave, m->nw, lr, s->interp, &ww);
    return s->scale * grid_eval(m, s->x1, &s->pw, &ww) * color_factor(m, s->c, lr);
}

wf_status wf_salt_bandrate(const wf_salt_model *m, const wf_salt_params *p,
                           wf_salt_interp interp, const wf_bandpass *bp, double mjd,
                           double *rate, unsigned *flags)
{
    if (!m || !bp || !rate) return wf_error(WF_ERR_INPUT, "salt: no model, bandpass or output");
    wf_status st = check_params(p);
    if (st == WF_OK) st = check_interp(interp);
    if (st != WF_OK) return st;
    if (!isfinite(mjd)) return wf_error(WF_ERR_RANGE, "salt: date MJD %g is not finite", mjd);
    double zp1 = 1.0 + p->z;
    double phase = (mjd - p->t0) / zp1;
    unsigned fl = wave_flags(m, bp, zp1);
    if (phase < m->phase[0] || phase > m->phase[m->np - 1]) fl |= WF_SALT_OUT_PHASE;
    *rate = 0.0;
    if (fl) {
        if (flags) *flags = fl;
        return WF_OK;
    }
    sed_ctx s = {.m = m, .interp = interp, .zp1 = zp1, .x1 = p->x1, .c = p->c,
                 .scale = p->x0 * SALT_SCALE / zp1};
    axis_weights(m->phase, m->np, phase, interp, &s.pw);
    double r;
    st = wf_bandpass_countrate_sed(bp, salt_sed, &s, &r);
    if (st != WF_OK) return st;
    if (r < 0.0) {
        fl |= WF_SALT_NEG_FLUX;
        r = 0.0;
    }
    *rate = r;
    if (flags) *flags = fl;
    return WF_OK;
}

static double mag_of(double zp_ab, double rate)
{
    return rate > 0.0 ? zp_ab - 2.5 * log10(rate) : WF_SALT_MAG_NONE;
}

wf_status wf_salt_bandmag(const wf_salt_model *m, const wf_salt_params *p,
                          wf_salt_interp interp, const wf_bandpass *bp, double mjd,
                          double *mag_ab, unsigned *flags)
{
    if (!mag_ab) return wf_error(WF_ERR_INPUT, "salt: no output magnitude");
    double rate;
    wf_status st = wf_salt_bandrate(m, p, interp, bp, mjd, &rate, flags);
    if (st != WF_OK) return st;
    *mag_ab = mag_of(bp->zp_ab, rate);
    return WF_OK;
}

/* ------------------------------------------------------------------ fast light curve */

/* Adds weight wq, carried by rest wavelength lr, to the template nodes that interpolate it:
 * to core (cubic rule) or edge (bilinear edge intervals), and to lin (linear scheme). */
static void spread(const wf_salt_model *m, double lr, double wq, double *core, double *edge,
                   double *lin, int *jmin, int *jmax)
{
    axis_w ww;
    axis_weights(m->wave, m->nw, lr, WF_SALT_INTERP_BICUBIC, &ww);
    int j = ww.i;
    lin[j] += wq * (1.0 - ww.a);
    lin[j + 1] += wq * ww.a;
    if (ww.cubic) {
        for (int k = 0; k < 4; k++) core[j - 1 + k] += wq * ww.w[k];
        if (j - 1 < *jmin) *jmin = j - 1;
        if (j + 2 > *jmax) *jmax = j + 2;
    } else {
        edge[j] += wq * (1.0 - ww.a);
        edge[j + 1] += wq * ww.a;
    }
    if (j < *jmin) *jmin = j;
    if (j + 1 > *jmax) *jmax = j + 1;
}

wf_status wf_salt_lc_init(const wf_salt_model *m, const wf_salt_params *p,
                          const wf_bandpass *bp, wf_salt_interp interp, wf_salt_lc **out)
{
    if (!m || !bp || !out) return wf_error(WF_ERR_INPUT, "salt: no model, bandpass or output");
    *out = NULL;
    wf_status st = check_params(p);
    if (st == WF_OK) st = check_interp(interp);
    if (st != WF_OK) return st;
    int np = m->np, nw = m->nw;
    wf_salt_lc *lc = calloc(1, sizeof *lc + 4 * (size_t)np * sizeof(double));
    double *wcore = calloc(3 * (size_t)nw, sizeof(double));
    if (!lc || !wcore) {
        free(lc);
        free(wcore);
        return wf_error(WF_ERR_NOMEM, "salt: out of memory for a light curve");
    }
    double *wedge = wcore + nw, *wlin = wedge + nw;
    lc->phase = (double *)(lc + 1);
    lc->core = lc->phase + np;
    lc->edge = lc->core + np;
    lc->lin = lc->edge + np;
    lc->np = np;
    memcpy(lc->phase, m->phase, (size_t)np * sizeof(double));
    lc->t0 = p->t0;
    lc->zp1 = 1.0 + p->z;
    lc->zp_ab = bp->zp_ab;
    lc->interp = interp;
    lc->covered = wave_flags(m, bp, lc->zp1) == 0;
    if (!lc->covered) {
        free(wcore);
        *out = lc;
        return WF_OK;
    }

    /* Node weights W_j = Σ_q GL weight × T λ × colour factor × (interpolation weight of node
     * j at point q), over pieces between band samples and redshifted template nodes. */
    double zp1 = lc->zp1;
    int jmin = nw, jmax = -1;
    int j = find_index(m->wave, nw, 10.0 * bp->blue_nm / zp1) + 1; /* next node above */
    for (int k = 0; k + 1 < bp->n; k++) {
        double xa = bp->wave_nm[k], xb = bp->wave_nm[k + 1];
        double ta = bp->throughput[k], tb = bp->throughput[k + 1];
        double x = xa;
        while (x < xb) {
            double next = xb;
            while (j < nw && m->wave[j] * zp1 / 10.0 <= x) j++;
            if (j < nw && m->wave[j] * zp1 / 10.0 < xb) next = m->wave[j] * zp1 / 10.0;
            if (ta != 0.0 || tb != 0.0) {
                double half = 0.5 * (next - x), mid = 0.5 * (next + x);
                /* 3 points are exact for the degree-5 polynomial T·λ·M that the integrand is
                 * on every piece (T and λ linear, M cubic), leaving only the smooth colour
                 * factor's variation over ≤ 5 nm */
                const wf_quad_rule *gl = &wf_quad_gl3;
                for (int q = 0; q < gl->n; q++) {
                    double lam = mid + half * gl->x[q];
                    double t = ta + (tb - ta) * (lam - xa) / (xb - xa);
                    double lr = 10.0 * lam / zp1;
                    double wq = gl->w[q] * half * t * lam * color_factor(m, p->c, lr);
                    spread(m, lr, wq, wcore, wedge, wlin, &jmin, &jmax);
                }
            }
            x = next;
        }
    }
    /* e-/s per unit Σ W (M0 + x1 M1): f_λ = x0 1e-12 M / (1+z) per Å; as sim/optics/bandpass.c,
     * ×10 for per nm, 1e-7 for λ in cm inside hc/λ. */
    double k_rate = bp->area_cm2 * 10.0 * 1.0e-7 / (H_CGS * C_CGS) * p->x0 * SALT_SCALE / zp1;
    for (int i = 0; i < np; i++) {
        const double *r0 = m->m0 + (size_t)i * nw, *r1 = m->m1 + (size_t)i * nw;
        double sc = 0.0, se = 0.0, sl = 0.0;
        for (int jj = jmin; jj <= jmax; jj++) {
            double v = r0[jj] + p->x1 * r1[jj];
            sc += wcore[jj] * v;
            se += wedge[jj] * v;
            sl += wlin[jj] * v;
        }
        lc->core[i] = k_rate * sc;
        lc->edge[i] = k_rate * se;
        lc->lin[i] = k_rate * sl;
    }
    free(wcore);
    *out = lc;
    return WF_OK;
}

wf_status wf_salt_lc_rate(const wf_salt_lc *lc, double mjd, double *rate, unsigned *flags)
{
    if (!lc || !rate) return wf_error(WF_ERR_INPUT, "salt: no light curve or output");
    if (!isfinite(mjd)) return wf_error(WF_ERR_RANGE, "salt: date MJD %g is not finite", mjd);
    double phase = (mjd - lc->t0) / lc->zp1;
    unsigned fl = lc->covered ? 0u : WF_SALT_OUT_WAVE;
    if (phase < lc->phase[0] || phase > lc->phase[lc->np - 1]) fl |= WF_SALT_OUT_PHASE;
    double r = 0.0;
    if (!fl) {
        axis_w pw;
        axis_weights(lc->phase, lc->np, phase, lc->interp, &pw);
        int i = pw.i;
        if (pw.cubic)
            r = pw.w[0] * lc->core[i - 1] + pw.w[1] * lc->core[i] + pw.w[2] * lc->core[i + 1] +
                pw.w[3] * lc->core[i + 2] + (1.0 - pw.a) * lc->edge[i] + pw.a * lc->edge[i + 1];
        else r = (1.0 - pw.a) * lc->lin[i] + pw.a * lc->lin[i + 1];
        if (r < 0.0) {
            fl |= WF_SALT_NEG_FLUX;
            r = 0.0;
        }
    }
    *rate = r;
    if (flags) *flags = fl;
    return WF_OK;
}

wf_status wf_salt_lc_mag(const wf_salt_lc *lc, double mjd, double *mag_ab, unsigned *flags)
{
    if (!mag_ab) return wf_error(WF_ERR_INPUT, "salt: no output magnitude");
    double rate;
    wf_status st = wf_salt_lc_rate(lc, mjd, &rate, flags);
    if (st != WF_OK) return st;
    *mag_ab = mag_of(lc->zp_ab, rate);
    return WF_OK;
}

void wf_salt_lc_window(const wf_salt_lc *lc, double *mjd_min, double *mjd_max, int *covered)
{
    if (mjd_min) *mjd_min = lc->t0 + lc->zp1 * lc->phase[0];
    if (mjd_max) *mjd_max = lc->t0 + lc->zp1 * lc->phase[lc->np - 1];
    if (covered) *covered = lc->covered;
}

void wf_salt_lc_free(wf_salt_lc *lc) { free(lc); }
