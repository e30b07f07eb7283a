#include "sim/sn/hostlib.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <zlib.h>

/* ------------------------------------------------------------------ columns */

enum {
    C_ID, C_RA, C_DEC, C_Z,
    C_N0, C_A0, C_B0, C_W0,
    C_N1, C_A1, C_B1, C_W1,
    C_AROT,
    C_Y, C_J, C_H, C_F,
    C_LOGM, C_LOGSFR,
    NCOL
};

/* Aliases in priority order, '|'-separated: the first one the file has is used. */
static const char *const ALIASES[NCOL] = {
    [C_ID] = "GALID",
    [C_RA] = "RA_GAL|RA_HOST|RA",
    [C_DEC] = "DEC_GAL|DEC_HOST|DEC",
    [C_Z] = "ZTRUE",
    [C_N0] = "n0_Sersic", [C_A0] = "a0_Sersic", [C_B0] = "b0_Sersic", [C_W0] = "w0_Sersic",
    [C_N1] = "n1_Sersic", [C_A1] = "a1_Sersic", [C_B1] = "b1_Sersic", [C_W1] = "w1_Sersic",
    [C_AROT] = "a_rot",
    [C_Y] = "y_obs", [C_J] = "j_obs", [C_H] = "h_obs", [C_F] = "f_obs",
    [C_LOGM] = "logmass|LOGMASS_TRUE",
    [C_LOGSFR] = "logsfr|LOGSFR_TRUE",
};

static const int BAND_COL[4] = {C_Y, C_J, C_H, C_F};
static const char *const BAND_NAME[4] = {"Y106", "J129", "H158", "F184"};

/* Ranges as the catalog readers (docs/CATALOGS.md), so a HOSTLIB row is a valid catalog row. */
#define MAG_LO -5.0
#define MAG_HI 99.0
#define HLR_MAX 600.0

/* ------------------------------------------------------------------ lines */

typedef struct reader {
    const char *path;
    gzFile gz;
    long line;
    char *buf;
    size_t cap;
    char **tok;
    int ntok, captok;
} reader;

/* Next physical line into r->buf (any length, newline and CR stripped): 1, or 0 at the end. */
static int next_line(reader *r, wf_status *st)
{
    size_t len = 0;
    *st = WF_OK;
    for (;;) {
        if (r->cap - len < 2) {
            size_t cap = r->cap ? 2 * r->cap : 4096;
            char *p = realloc(r->buf, cap);
            if (!p) {
                *st = wf_error(WF_ERR_NOMEM, "%s:%ld: no memory for a line", r->path, r->line + 1);
                return 0;
            }
            r->buf = p;
            r->cap = cap;
        }
        if (!gzgets(r->gz, r->buf + len, (int)(r->cap - len > 1u << 30 ? 1u << 30 : r->cap - len))) {
            int err;
            const char *msg = gzerror(r->gz, &err);
            if (err != Z_OK && err != Z_STREAM_END) {
                *st = wf_error(WF_ERR_IO, "%s:%ld: read error: %s", r->path, r->line + 1,
                               err == Z_ERRNO ? strerror(errno) : msg);
                return 0;
            }
            if (len == 0) return 0;
            break;
        }
        len += strlen(r->buf + len);
        if (len > 0 && r->buf[len - 1] == '\n') break;
    }
    r->line++;
    while (len > 0 && (r->buf[len - 1] == '\n' || r->buf[len - 1] == '\r')) r->buf[--len] = '\0';
    return 1;
}

/* Splits r->buf on blanks; a word starting with '#' ends the line. */
static wf_status tokenize(reader *r)
{
    r->ntok = 0;
    char *s = r->buf;
    for (;;) {
        while (*s == ' ' || *s == '\t' || *s == '\v' || *s == '\f') s++;
        if (!*s || *s == '#') break;
        if (r->ntok == r->captok) {
            int cap = r->captok ? 2 * r->captok : 64;
            char **p = realloc(r->tok, (size_t)cap * sizeof *p);
            if (!p) return wf_error(WF_ERR_NOMEM, "%s:%ld: no memory", r->path, r->line);
            r->tok = p;
            r->captok = cap;
        }
        r->tok[r->ntok++] = s;
        while (*s && *s != ' ' && *s != '\t' && *s != '\v' && *s != '\f') s++;
        if (*s) *s++ = '\0';
    }
    return WF_OK;
}

static int is_keyword(const char *t)
{
    size_t n = strlen(t);
    return n > 1 && t[n - 1] == ':';
}

static int keyword_is(const char *t, const char *key) { return strcasecmp(t, key) == 0; }

/* ------------------------------------------------------------------ values */

static wf_status parse_number(const reader *r, const char *col, int field, const char *text,
                              double *v)
{
    char *end;
    errno = 0;
    double x = strtod(text, &end);
    if (end == text || *end != '\0')
        return wf_error(WF_ERR_INPUT, "%s:%ld: column '%s' (field %d): '%s' is not a number",
                        r->path, r->line, col, field, text);
    if (isnan(x))
        return wf_error(WF_ERR_INPUT, "%s:%ld: column '%s' (field %d): value is NaN", r->path,
                        r->line, col, field);
    if (isinf(x) || (errno == ERANGE && fabs(x) > 1.0))
        return wf_error(WF_ERR_INPUT, "%s:%ld: column '%s' (field %d): value '%s' is infinite",
                        r->path, r->line, col, field, text);
    *v = x;
    return WF_OK;
}

static wf_status check_range(const reader *r, const char *col, double v, double lo, double hi,
                             int lo_open)
{
    if (v < lo || v > hi || (lo_open && v == lo))
        return wf_error(WF_ERR_RANGE, "%s:%ld: column '%s': value %.10g outside %c%g, %g]",
                        r->path, r->line, col, v, lo_open ? '(' : '[', lo, hi);
    return WF_OK;
}

/* ------------------------------------------------------------------ weight map */

typedef struct wgt_state {
    int nvar_key;   /* NVAR_WGTMAP, -1 when not given */
    int nnames;     /* names before "WGT" in VARNAMES_WGTMAP, -1 when not given */
    char names[WF_HOSTLIB_MAXWGTVAR][WF_HOSTLIB_NAMELEN];
    int ncols;      /* values per WGT: row, fixed by the first row */
    size_t cap;
} wgt_state;

static int wgt_nvar(const wgt_state *w) { return w->nvar_key >= 0 ? w->nvar_key : w->nnames; }

static wf_status wgt_row(reader *r, wgt_state *w, wf_hostlib_wgtmap *m, char **val, int nval)
{
    int nvar = w->ncols ? m->nvar : wgt_nvar(w); /* the first row fixes the map's shape */
    if (nvar < 0)
        return wf_error(WF_ERR_INPUT, "%s:%ld: WGT: row before NVAR_WGTMAP or VARNAMES_WGTMAP",
                        r->path, r->line);
    if (nvar == 0)
        return wf_error(WF_ERR_INPUT, "%s:%ld: WGT: row of a weight map without variables",
                        r->path, r->line);
    if (w->ncols == 0) {
        if (nval != nvar + 1 && nval != nvar + 2)
            return wf_error(WF_ERR_INPUT,
                            "%s:%ld: WGT: row has %d values; the map has %d variables, so %d "
                            "(WGT) or %d (WGT SNMAGSHIFT) were expected",
                            r->path, r->line, nval, nvar, nvar + 1, nvar + 2);
        w->ncols = nval;
        m->nvar = nvar;
        m->has_snmagshift = nval == nvar + 2;
        for (int k = 0; k < nvar; k++) {
            if (w->nnames > k)
                snprintf(m->var[k], sizeof m->var[k], "%s", w->names[k]);
            else
                snprintf(m->var[k], sizeof m->var[k], "var%d", k);
        }
    } else if (nval != w->ncols) {
        return wf_error(WF_ERR_INPUT, "%s:%ld: WGT: row has %d values, the first WGT: row had %d",
                        r->path, r->line, nval, w->ncols);
    }
    if (m->n == w->cap) {
        size_t cap = w->cap ? 2 * w->cap : 256;
        double *x = realloc(m->x, cap * (size_t)nvar * sizeof *x);
        if (x) m->x = x;
        double *g = x ? realloc(m->wgt, cap * sizeof *g) : NULL;
        if (g) m->wgt = g;
        double *s = g ? realloc(m->snmagshift, cap * sizeof *s) : NULL;
        if (s) m->snmagshift = s;
        if (!s) return wf_error(WF_ERR_NOMEM, "%s:%ld: no memory for the weight map", r->path, r->line);
        w->cap = cap;
    }
    double v[WF_HOSTLIB_MAXWGTVAR + 2];
    for (int k = 0; k < nval; k++) {
        const char *col = k < nvar ? m->var[k] : k == nvar ? "WGT" : "SNMAGSHIFT";
        wf_status st = parse_number(r, col, k + 1, val[k], &v[k]);
        if (st) return st;
    }
    if (v[nvar] < 0.0)
        return wf_error(WF_ERR_RANGE, "%s:%ld: column 'WGT': negative weight %g", r->path, r->line,
                        v[nvar]);
    for (int k = 0; k < nvar; k++) m->x[m->n * (size_t)nvar + (size_t)k] = v[k];
    m->wgt[m->n] = v[nvar];
    m->snmagshift[m->n] = m->has_snmagshift ? v[nvar + 1] : 0.0;
    m->n++;
    return WF_OK;
}

static wf_status wgt_names(reader *r, wgt_state *w, char **val, int nval)
{
    int n = 0;
    while (n < nval && strcasecmp(val[n], "WGT") != 0) n++;
    if (n > WF_HOSTLIB_MAXWGTVAR)
        return wf_error(WF_ERR_INPUT, "%s:%ld: VARNAMES_WGTMAP: %d variables (at most %d)",
                        r->path, r->line, n, WF_HOSTLIB_MAXWGTVAR);
    for (int k = 0; k < n; k++) snprintf(w->names[k], sizeof w->names[k], "%s", val[k]);
    w->nnames = n;
    return WF_OK;
}

static wf_status wgt_nvar_key(reader *r, wgt_state *w, char **val, int nval)
{
    if (w->ncols)
        return wf_error(WF_ERR_INPUT, "%s:%ld: NVAR_WGTMAP after WGT: rows: the map's shape is already fixed",
                        r->path, r->line);
    char *end;
    long n = nval >= 1 ? strtol(val[0], &end, 10) : -1;
    if (nval < 1 || *end != '\0' || n < 1 || n > WF_HOSTLIB_MAXWGTVAR)
        return wf_error(WF_ERR_INPUT, "%s:%ld: NVAR_WGTMAP: '%s' is not a count of 1 to %d",
                        r->path, r->line, nval >= 1 ? val[0] : "", WF_HOSTLIB_MAXWGTVAR);
    w->nvar_key = (int)n;
    return WF_OK;
}

/* ------------------------------------------------------------------ header */

typedef struct header {
    int nvar;            /* names on the VARNAMES line */
    long line;           /* where it was */
    int pos[NCOL];       /* field index of each quantity, -1 when absent */
    char name[NCOL][WF_HOSTLIB_NAMELEN];
    int ncomp;           /* Sérsic components: 1 or 2 */
    int nband;
    int band_col[4];     /* C_Y.. of the bands present, in Y J H F order */
} header;

static wf_status read_varnames(reader *r, header *h, char **val, int nval)
{
    if (h->nvar > 0)
        return wf_error(WF_ERR_INPUT, "%s:%ld: second VARNAMES (the first is on line %ld)", r->path,
                        r->line, h->line);
    if (nval < 1) return wf_error(WF_ERR_INPUT, "%s:%ld: VARNAMES names no column", r->path, r->line);
    h->nvar = nval;
    h->line = r->line;
    for (int c = 0; c < NCOL; c++) {
        h->pos[c] = -1;
        const char *a = ALIASES[c];
        while (*a && h->pos[c] < 0) {
            size_t len = strcspn(a, "|");
            for (int k = 0; k < nval; k++)
                if (strlen(val[k]) == len && strncasecmp(val[k], a, len) == 0) {
                    h->pos[c] = k;
                    snprintf(h->name[c], sizeof h->name[c], "%s", val[k]);
                    break;
                }
            a += len;
            if (*a == '|') a++;
        }
    }
    for (int k = 0; k < nval; k++)
        if (strlen(val[k]) == 9 && (val[k][0] == 'n' || val[k][0] == 'N') && val[k][1] >= '2' &&
            val[k][1] <= '9' && strcasecmp(val[k] + 2, "_Sersic") == 0)
            return wf_error(WF_ERR_INPUT,
                            "%s:%ld: column '%s': Sérsic components beyond 0 and 1 are not "
                            "supported (the renderer draws one disk, n = 1, and one bulge, n = 4)",
                            r->path, r->line, val[k]);
    static const int required[] = {C_ID, C_RA, C_DEC, C_Z, C_N0, C_A0, C_B0, C_W0, C_AROT};
    for (size_t k = 0; k < sizeof required / sizeof *required; k++)
        if (h->pos[required[k]] < 0)
            return wf_error(WF_ERR_INPUT,
                            "%s: missing required column '%.*s' (accepted names: %s; VARNAMES "
                            "on line %ld)",
                            r->path, (int)strcspn(ALIASES[required[k]], "|"), ALIASES[required[k]],
                            ALIASES[required[k]], r->line);
    int second = 0;
    for (int c = C_N1; c <= C_W1; c++) second += h->pos[c] >= 0;
    if (second > 0 && second < 4) {
        for (int c = C_N1; c <= C_W1; c++)
            if (h->pos[c] < 0)
                return wf_error(WF_ERR_INPUT,
                                "%s: missing required column '%s' (the file has part of Sérsic "
                                "component 1; VARNAMES on line %ld)",
                                r->path, ALIASES[c], r->line);
    }
    h->ncomp = second == 4 ? 2 : 1;
    h->nband = 0;
    for (int b = 0; b < 4; b++)
        if (h->pos[BAND_COL[b]] >= 0) h->band_col[h->nband++] = b;
    if (h->nband == 0)
        return wf_error(WF_ERR_INPUT,
                        "%s: missing magnitude columns: at least one of y_obs, j_obs, h_obs, f_obs "
                        "(VARNAMES on line %ld)",
                        r->path, r->line);
    return WF_OK;
}

/* ------------------------------------------------------------------ rows */

static wf_status gal_row(reader *r, const header *h, wf_catalog *cat, wf_hostlib_info *info,
                         char **val, int nval)
{
    if (h->nvar == 0)
        return wf_error(WF_ERR_INPUT, "%s:%ld: GAL: row before VARNAMES", r->path, r->line);
    if (nval != h->nvar)
        return wf_error(WF_ERR_INPUT, "%s:%ld: GAL: row has %d values, VARNAMES (line %ld) names %d",
                        r->path, r->line, nval, h->line, h->nvar);
    double v[NCOL];
    wf_status st;
    for (int c = 0; c < NCOL; c++) {
        v[c] = 0.0;
        if (h->pos[c] < 0 || c == C_ID) continue;
        if ((st = parse_number(r, h->name[c], h->pos[c] + 1, val[h->pos[c]], &v[c]))) return st;
    }
    /* GALID: an integer; SNANA writes plain integers, but accept an integral float */
    const char *idt = val[h->pos[C_ID]];
    char *end;
    errno = 0;
    long long id = strtoll(idt, &end, 10);
    if (end == idt || *end != '\0' || errno == ERANGE) {
        double x;
        if ((st = parse_number(r, h->name[C_ID], h->pos[C_ID] + 1, idt, &x))) return st;
        if (x != floor(x) || fabs(x) > 9007199254740992.0)
            return wf_error(WF_ERR_INPUT, "%s:%ld: column '%s' (field %d): '%s' is not an integer",
                            r->path, r->line, h->name[C_ID], h->pos[C_ID] + 1, idt);
        id = (long long)x;
    }
    if ((st = check_range(r, h->name[C_RA], v[C_RA], -180.0, 360.0, 0)) ||
        (st = check_range(r, h->name[C_DEC], v[C_DEC], -90.0, 90.0, 0)) ||
        (st = check_range(r, h->name[C_Z], v[C_Z], 0.0, 20.0, 0)))
        return st;
    for (int b = 0; b < h->nband; b++) {
        int c = BAND_COL[h->band_col[b]];
        if ((st = check_range(r, h->name[c], v[c], MAG_LO, MAG_HI, 0))) return st;
    }
    if (h->pos[C_LOGM] >= 0 && (st = check_range(r, h->name[C_LOGM], v[C_LOGM], 0.0, 14.0, 0)))
        return st;
    if (h->pos[C_LOGSFR] >= 0 &&
        (st = check_range(r, h->name[C_LOGSFR], v[C_LOGSFR], -20.0, 5.0, 0)))
        return st;

    /* Sérsic components: index by n; disk n = 1 (slot 0), bulge n = 4 (slot 1) */
    double w[2] = {0.0, 0.0}, a[2] = {0.0, 0.0}, b[2] = {0.0, 0.0};
    int have[2] = {0, 0};
    int comp_col[2] = {-1, -1}; /* first column (n) of the file's component in each slot */
    for (int j = 0; j < h->ncomp; j++) {
        int c0 = j == 0 ? C_N0 : C_N1;
        double n = v[c0];
        int slot = n == 1.0 ? 0 : n == 4.0 ? 1 : -1;
        if (slot < 0)
            return wf_error(WF_ERR_RANGE,
                            "%s:%ld: column '%s': Sérsic index %g; only 1 (disk) and 4 (bulge) "
                            "can be drawn",
                            r->path, r->line, h->name[c0], n);
        if (have[slot])
            return wf_error(WF_ERR_RANGE, "%s:%ld: columns '%s', '%s': both components have n = %g",
                            r->path, r->line, h->name[comp_col[slot]], h->name[c0], n);
        have[slot] = 1;
        comp_col[slot] = c0;
        a[slot] = v[c0 + 1];
        b[slot] = v[c0 + 2];
        w[slot] = v[c0 + 3];
        if ((st = check_range(r, h->name[c0 + 3], w[slot], 0.0, INFINITY, 0))) return st;
    }
    if (!(w[0] + w[1] > 0.0))
        return wf_error(WF_ERR_RANGE, "%s:%ld: the Sérsic weights (%s%s%s) sum to 0", r->path,
                        r->line, h->name[C_W0], h->ncomp > 1 ? ", " : "",
                        h->ncomp > 1 ? h->name[C_W1] : "");
    double hlr[2] = {0.0, 0.0};
    int usable[2];
    for (int s = 0; s < 2; s++) {
        usable[s] = have[s] && a[s] > 0.0 && b[s] > 0.0 && a[s] <= HLR_MAX && b[s] <= HLR_MAX;
        if (w[s] > 0.0 && !usable[s]) {
            int c0 = comp_col[s];
            double bad = a[s] > 0.0 && a[s] <= HLR_MAX ? b[s] : a[s];
            const char *col = a[s] > 0.0 && a[s] <= HLR_MAX ? h->name[c0 + 2] : h->name[c0 + 1];
            return wf_error(WF_ERR_RANGE, "%s:%ld: column '%s': value %.10g outside (0, %g]",
                            r->path, r->line, col, bad, HLR_MAX);
        }
        if (usable[s]) hlr[s] = sqrt(a[s] * b[s]);
    }
    /* a component without light still needs a radius > 0 for the catalog: the other's */
    for (int s = 0; s < 2; s++)
        if (!usable[s]) hlr[s] = hlr[1 - s];
    if (w[0] == 0.0) info->zero_disk++;
    if (w[1] == 0.0) info->zero_bulge++;
    int dom = w[1] > w[0] ? 1 : 0;
    double e = (a[dom] * a[dom] - b[dom] * b[dom]) / (a[dom] * a[dom] + b[dom] * b[dom]);
    double beta = v[C_AROT] * (M_PI / 180.0);
    float e1 = (float)(e * cos(2.0 * beta)), e2 = (float)(e * sin(2.0 * beta));
    if (!((double)e1 * e1 + (double)e2 * e2 < 1.0))
        return wf_error(WF_ERR_RANGE,
                        "%s:%ld: columns '%s', '%s': axis ratio %g gives |e| = 1 in single precision",
                        r->path, r->line, h->name[comp_col[dom] + 1], h->name[comp_col[dom] + 2],
                        b[dom] / a[dom]);

    size_t i;
    if ((st = wf_catalog_push(cat, &i))) return st;
    cat->id[i] = (int64_t)id;
    double ra = v[C_RA];
    if (ra < 0.0) ra += 360.0;
    if (ra >= 360.0) ra -= 360.0;
    cat->ra[i] = ra;
    cat->dec[i] = v[C_DEC];
    for (int k = 0; k < h->nband; k++) cat->mag[k][i] = (float)v[BAND_COL[h->band_col[k]]];
    cat->hlr_disk[i] = (float)hlr[0];
    cat->hlr_bulge[i] = (float)hlr[1];
    cat->bulge_frac[i] = (float)(w[1] / (w[0] + w[1]));
    cat->knot_frac[i] = 0.0f;
    cat->e1[i] = e1;
    cat->e2[i] = e2;
    cat->pa[i] = 0.0f;
    cat->z[i] = (float)v[C_Z];
    if (cat->has_logmass) cat->logmass[i] = (float)v[C_LOGM];
    if (cat->has_logsfr) cat->logsfr[i] = (float)v[C_LOGSFR];
    return WF_OK;
}

/* ------------------------------------------------------------------ driver */

void wf_hostlib_info_free(wf_hostlib_info *info)
{
    if (!info) return;
    free(info->wgtmap.x);
    free(info->wgtmap.wgt);
    free(info->wgtmap.snmagshift);
    memset(info, 0, sizeof *info);
}

wf_status wf_hostlib_read(const char *path, wf_catalog *out, wf_hostlib_info *info_out)
{
    memset(out, 0, sizeof *out);
    wf_hostlib_info info;
    memset(&info, 0, sizeof info);
    if (info_out) memset(info_out, 0, sizeof *info_out);
    reader r = {.path = path};
    r.gz = gzopen(path, "rb");
    if (!r.gz) return wf_error(WF_ERR_IO, "%s: cannot open: %s", path, strerror(errno));
    gzbuffer(r.gz, 1 << 16);

    header h;
    memset(&h, 0, sizeof h);
    wgt_state ws = {.nvar_key = -1, .nnames = -1};
    int in_doc = 0, cat_ready = 0;
    wf_status st = WF_OK;
    while (!st && next_line(&r, &st)) {
        if ((st = tokenize(&r))) break;
        for (int k = 0; k < r.ntok && !st;) {
            const char *key = r.tok[k];
            int j = k + 1;
            while (j < r.ntok && !is_keyword(r.tok[j])) j++;
            char **val = r.tok + k + 1;
            int nval = j - k - 1;
            k = j;
            if (in_doc) {
                if (keyword_is(key, "DOCUMENTATION_END:")) in_doc = 0;
                continue;
            }
            if (!is_keyword(key)) break; /* free text: not HOSTLIB content */
            if (keyword_is(key, "DOCUMENTATION:")) {
                in_doc = 1;
            } else if (keyword_is(key, "VARNAMES:")) {
                if ((st = read_varnames(&r, &h, val, nval))) break;
                const char *bands[4];
                for (int b = 0; b < h.nband; b++) bands[b] = BAND_NAME[h.band_col[b]];
                int flags = WF_CATALOG_HAS_Z | (h.pos[C_LOGM] >= 0 ? WF_CATALOG_HAS_LOGMASS : 0) |
                            (h.pos[C_LOGSFR] >= 0 ? WF_CATALOG_HAS_LOGSFR : 0);
                if ((st = wf_catalog_init(out, WF_CATALOG_GALAXY, h.nband, bands, flags, path))) break;
                cat_ready = 1;
                info.nvarnames = h.nvar;
            } else if (keyword_is(key, "GAL:")) {
                if ((st = gal_row(&r, &h, out, &info, val, nval))) break;
                info.ngal++;
            } else if (keyword_is(key, "NVAR_WGTMAP:")) {
                st = wgt_nvar_key(&r, &ws, val, nval);
            } else if (keyword_is(key, "VARNAMES_WGTMAP:")) {
                st = wgt_names(&r, &ws, val, nval);
            } else if (keyword_is(key, "WGT:")) {
                st = wgt_row(&r, &ws, &info.wgtmap, val, nval);
            }
            /* any other keyword (NVAR:, SNPAR:, ...) is not needed here */
        }
    }
    gzclose(r.gz);
    free(r.buf);
    free(r.tok);
    if (!st && h.nvar == 0)
        st = wf_error(WF_ERR_INPUT, "%s: no VARNAMES line: not a HOSTLIB (or an empty one)", path);
    if (!st && ws.nvar_key >= 0 && ws.nnames >= 0 && ws.nnames != ws.nvar_key)
        st = wf_error(WF_ERR_INPUT, "%s: NVAR_WGTMAP is %d but VARNAMES_WGTMAP names %d variables",
                      path, ws.nvar_key, ws.nnames);
    if (st) {
        if (cat_ready) wf_catalog_free(out);
        memset(out, 0, sizeof *out);
        wf_hostlib_info_free(&info);
        return st;
    }
    info.has_wgtmap = info.wgtmap.n > 0;
    if (info_out)
        *info_out = info;
    else
        wf_hostlib_info_free(&info);
    return WF_OK;
}
