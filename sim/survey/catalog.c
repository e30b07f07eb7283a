#include "sim/survey/catalog.h"
#include "sim/fits/fitscheck.h"
#include "sim/fits/fitsdisk.h"
#include "hal/file.h"

#include <ctype.h>
#include <errno.h>
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <unistd.h>
#include <zlib.h>

/* ------------------------------------------------------------------ storage */

static int grow_f(float **p, size_t cap)
{
    void *q = realloc(*p, cap * sizeof **p);
    if (!q) return 0;
    *p = q;
    return 1;
}

static int grow_d(double **p, size_t cap)
{
    void *q = realloc(*p, cap * sizeof **p);
    if (!q) return 0;
    *p = q;
    return 1;
}

static int grow_i(int64_t **p, size_t cap)
{
    void *q = realloc(*p, cap * sizeof **p);
    if (!q) return 0;
    *p = q;
    return 1;
}

wf_status wf_catalog_init(wf_catalog *cat, wf_catalog_kind kind, int nband,
                          const char *const *bands, int flags, const char *source)
{
    memset(cat, 0, sizeof *cat);
    if (nband < 0 || nband > WF_CATALOG_MAXBAND)
        return wf_error(WF_ERR_RANGE, "catalog %s: %d bands (at most %d)", source ? source : "",
                        nband, WF_CATALOG_MAXBAND);
    cat->kind = kind;
    cat->nband = nband;
    for (int b = 0; b < nband; b++) {
        if (!bands[b] || !bands[b][0] || strlen(bands[b]) >= WF_CATALOG_BANDLEN)
            return wf_error(WF_ERR_INPUT, "catalog %s: band name %d empty or longer than %d",
                            source ? source : "", b, WF_CATALOG_BANDLEN - 1);
        snprintf(cat->band[b], sizeof cat->band[b], "%s", bands[b]);
    }
    snprintf(cat->source, sizeof cat->source, "%s", source ? source : "");
    if (kind == WF_CATALOG_GALAXY) {
        cat->has_z = !!(flags & WF_CATALOG_HAS_Z);
        cat->has_logmass = !!(flags & WF_CATALOG_HAS_LOGMASS);
        cat->has_logsfr = !!(flags & WF_CATALOG_HAS_LOGSFR);
    }
    return WF_OK;
}

wf_status wf_catalog_reserve(wf_catalog *cat, size_t cap)
{
    if (cap <= cat->cap) return WF_OK;
    int ok = grow_i(&cat->id, cap) && grow_d(&cat->ra, cap) && grow_d(&cat->dec, cap);
    for (int b = 0; ok && b < cat->nband; b++) ok = grow_f(&cat->mag[b], cap);
    if (ok && cat->kind == WF_CATALOG_GALAXY) {
        ok = grow_f(&cat->hlr_disk, cap) && grow_f(&cat->hlr_bulge, cap) &&
             grow_f(&cat->bulge_frac, cap) && grow_f(&cat->knot_frac, cap) &&
             grow_f(&cat->e1, cap) && grow_f(&cat->e2, cap) && grow_f(&cat->pa, cap);
        if (ok && cat->has_z) ok = grow_f(&cat->z, cap);
        if (ok && cat->has_logmass) ok = grow_f(&cat->logmass, cap);
        if (ok && cat->has_logsfr) ok = grow_f(&cat->logsfr, cap);
    }
    if (!ok) return wf_error(WF_ERR_NOMEM, "catalog %s: no memory for %zu rows", cat->source, cap);
    cat->cap = cap;
    return WF_OK;
}

wf_status wf_catalog_push(wf_catalog *cat, size_t *row)
{
    if (cat->n == cat->cap) {
        wf_status st = wf_catalog_reserve(cat, cat->cap < 1024 ? 1024 : 2 * cat->cap);
        if (st) return st;
    }
    *row = cat->n++;
    return WF_OK;
}

void wf_catalog_free(wf_catalog *cat)
{
    if (!cat) return;
    free(cat->id);
    free(cat->ra);
    free(cat->dec);
    for (int b = 0; b < WF_CATALOG_MAXBAND; b++) free(cat->mag[b]);
    free(cat->hlr_disk);
    free(cat->hlr_bulge);
    free(cat->bulge_frac);
    free(cat->knot_frac);
    free(cat->e1);
    free(cat->e2);
    free(cat->pa);
    free(cat->z);
    free(cat->logmass);
    free(cat->logsfr);
    memset(cat, 0, sizeof *cat);
}

static int catalog_flags(const wf_catalog *c)
{
    return (c->has_z ? WF_CATALOG_HAS_Z : 0) | (c->has_logmass ? WF_CATALOG_HAS_LOGMASS : 0) |
           (c->has_logsfr ? WF_CATALOG_HAS_LOGSFR : 0);
}

static wf_status catalog_like(const wf_catalog *src, wf_catalog *out)
{
    const char *bands[WF_CATALOG_MAXBAND];
    for (int b = 0; b < src->nband; b++) bands[b] = src->band[b];
    return wf_catalog_init(out, src->kind, src->nband, bands, catalog_flags(src), src->source);
}

/* Copies row i of src to row j of dst; both have the same columns. */
static void copy_row(wf_catalog *dst, size_t j, const wf_catalog *src, size_t i)
{
    dst->id[j] = src->id[i];
    dst->ra[j] = src->ra[i];
    dst->dec[j] = src->dec[i];
    for (int b = 0; b < src->nband; b++) dst->mag[b][j] = src->mag[b][i];
    if (src->kind != WF_CATALOG_GALAXY) return;
    dst->hlr_disk[j] = src->hlr_disk[i];
    dst->hlr_bulge[j] = src->hlr_bulge[i];
    dst->bulge_frac[j] = src->bulge_frac[i];
    dst->knot_frac[j] = src->knot_frac[i];
    dst->e1[j] = src->e1[i];
    dst->e2[j] = src->e2[i];
    dst->pa[j] = src->pa[i];
    if (src->has_z) dst->z[j] = src->z[i];
    if (src->has_logmass) dst->logmass[j] = src->logmass[i];
    if (src->has_logsfr) dst->logsfr[j] = src->logsfr[i];
}

wf_status wf_catalog_subset(const wf_catalog *src, const uint32_t *idx, size_t n, wf_catalog *out)
{
    wf_status st = catalog_like(src, out);
    if (!st) st = wf_catalog_reserve(out, n ? n : 1);
    if (st) {
        wf_catalog_free(out);
        return st;
    }
    for (size_t k = 0; k < n; k++) {
        if (idx[k] >= src->n) {
            wf_catalog_free(out);
            return wf_error(WF_ERR_RANGE, "catalog %s: subset index %u beyond %zu rows",
                            src->source, (unsigned)idx[k], src->n);
        }
        copy_row(out, k, src, idx[k]);
    }
    out->n = n;
    return WF_OK;
}

wf_status wf_catalog_band(const wf_catalog *cat, const char *band, int *index)
{
    const char *name = strncasecmp(band, "mag_", 4) == 0 ? band + 4 : band;
    for (int b = 0; b < cat->nband; b++)
        if (strcasecmp(cat->band[b], name) == 0) {
            *index = b;
            return WF_OK;
        }
    char have[WF_CATALOG_MAXBAND * (WF_CATALOG_BANDLEN + 1) + 1] = "";
    for (int b = 0; b < cat->nband; b++) {
        strcat(have, b ? " " : "");
        strcat(have, cat->band[b]);
    }
    return wf_error(WF_ERR_INPUT, "catalog %s has no magnitude column for band '%s' (bands: %s)",
                    cat->source, name, cat->nband ? have : "none");
}

/* ------------------------------------------------------------------ column table */

enum {
    F_RA,
    F_DEC,
    F_Z,
    F_HLR,
    F_FWHM,
    F_HLRB,
    F_BULGE,
    F_KNOT,
    F_E1,
    F_E2,
    F_PA,
    F_LOGM,
    F_LOGSFR,
    NFIELD
};

typedef struct field_spec {
    const char *name;    /* canonical: what the writers use */
    const char *aliases; /* '|'-separated, in priority order */
    double lo, hi;
    int lo_open, hi_open;
} field_spec;

/* Ranges are what a physical catalog can hold; they catch unit mix-ups (radians for degrees,
 * percent for fractions) and sentinel values such as -99, not astrophysical rarities. */
static const field_spec FIELDS[NFIELD] = {
    [F_RA] = {"ra", "ra|ra_deg|ra_gal", -180.0, 360.0, 0, 0},
    [F_DEC] = {"dec", "dec|dec_deg|dec_gal", -90.0, 90.0, 0, 0},
    [F_Z] = {"z", "z|redshift|ztrue|z_true", 0.0, 20.0, 0, 0},
    [F_HLR] = {"hlr", "hlr|hlr_arcsec|hlr_disk|hlr_disk_arcsec|size|r_half", 0.0, 600.0, 1, 0},
    [F_FWHM] = {"fwhm", "fwhm|fwhm_arcsec", 0.0, 600.0, 1, 0},
    [F_HLRB] = {"hlr_bulge", "hlr_bulge|hlr_bulge_arcsec", 0.0, 600.0, 1, 0},
    [F_BULGE] = {"bulge_frac", "bulge_frac|bulge_fraction|bt", 0.0, 1.0, 0, 0},
    [F_KNOT] = {"knot_frac", "knot_frac|knot_fraction|knot_frac_of_disk", 0.0, 0.25, 0, 0},
    [F_E1] = {"e1", "e1", -1.0, 1.0, 1, 1},
    [F_E2] = {"e2", "e2", -1.0, 1.0, 1, 1},
    [F_PA] = {"pa", "pa|pa_deg|position_angle", -360.0, 360.0, 0, 0},
    [F_LOGM] = {"logmass", "logmass|log_mass|logmstar|log_mstar", 0.0, 14.0, 0, 0},
    [F_LOGSFR] = {"logsfr", "logsfr|log_sfr", -20.0, 5.0, 0, 0},
};
static const char *const ID_ALIASES = "id|galid|objid|obj_id|object_id|source_id";
static const char *const TYPE_ALIASES = "type|obj_type";
static const double MAG_LO = -5.0, MAG_HI = 99.0;

/* hlr / FWHM of an exponential profile: 1.678347 r_s / (2 ln 2 r_s). */
static const double HLR_PER_FWHM = 1.2106644;

typedef enum { MODE_GALAXY, MODE_STAR, MODE_SCENE } read_mode;

#define NAMELEN 72
#define CHUNK 4096

typedef struct reader {
    const char *path;
    read_mode mode;
    int pos[NFIELD]; /* column index in the file, -1 when absent */
    char name[NFIELD][NAMELEN];
    int id_pos, type_pos;
    char id_name[NAMELEN], type_name[NAMELEN];
    int nband;
    int band_pos[WF_CATALOG_MAXBAND];
    char band_col[WF_CATALOG_MAXBAND][NAMELEN];
    char band[WF_CATALOG_MAXBAND][WF_CATALOG_BANDLEN];
    wf_catalog *gal, *star, *sn;
    /* wf_catalog_sniff: the header's names are kept here and the file is not read further */
    int sniff;
    char found[1024];
    int lacks[3];                 /* per read_mode: how many required columns the file lacks */
    char lacking[3][256];         /*   and their names */
} reader;

typedef struct rowval {
    int64_t id;
    double v[NFIELD];
    double mag[WF_CATALOG_MAXBAND];
    char type[16];
} rowval;

static int field_required(read_mode mode, int f)
{
    switch (mode) {
    case MODE_STAR:
        return f == F_RA || f == F_DEC;
    case MODE_SCENE:
        return f == F_RA || f == F_DEC || f == F_HLR || f == F_HLRB || f == F_BULGE ||
               f == F_KNOT || f == F_E1 || f == F_E2;
    case MODE_GALAXY:
    default:
        return f == F_RA || f == F_DEC || f == F_Z || f == F_BULGE || f == F_KNOT || f == F_E1 ||
               f == F_E2 || f == F_PA;
    }
}

/* Position of the first column matching one of the aliases (alias order wins over column
 * order, so "ra" is preferred to "ra_deg" wherever it sits). */
static int find_column(char *const *names, int ncol, const char *aliases, char *found)
{
    const char *a = aliases;
    while (*a) {
        size_t len = strcspn(a, "|");
        for (int c = 0; c < ncol; c++)
            if (strlen(names[c]) == len && strncasecmp(names[c], a, len) == 0) {
                snprintf(found, NAMELEN, "%s", names[c]);
                return c;
            }
        a += len;
        if (*a == '|') a++;
    }
    return -1;
}

static void alias_list(const char *aliases, char *out, size_t size)
{
    size_t k = 0;
    for (const char *a = aliases; *a && k + 3 < size; a++) {
        if (*a == '|') {
            out[k++] = ',';
            out[k++] = ' ';
        } else {
            out[k++] = *a;
        }
    }
    out[k] = '\0';
}

static wf_status missing(const reader *r, const char *aliases)
{
    char list[256];
    alias_list(aliases, list, sizeof list);
    size_t len = strcspn(aliases, "|");
    return wf_error(WF_ERR_INPUT, "%s: missing required column '%.*s' (accepted names: %s)",
                    r->path, (int)len, aliases, list);
}

static const char *const HLR_OR_FWHM = "hlr|hlr_arcsec|hlr_disk|hlr_disk_arcsec|size|r_half|fwhm|fwhm_arcsec";
static const char *const MAG_ANY = "mag_<band>";

static int has_mag_column(char *const *names, int ncol)
{
    for (int c = 0; c < ncol; c++)
        if (strncasecmp(names[c], "mag_", 4) == 0 && names[c][4]) return 1;
    return 0;
}

/* The required columns a file of these names lacks for `mode`, as their alias lists in the
 * order the reader reports them (miss may be NULL: the count alone). One rule for the
 * readers' messages and for wf_catalog_sniff. */
static int lacking_columns(char *const *names, int ncol, read_mode mode, const char **miss, int cap)
{
    int n = 0;
    char found[NAMELEN];
#define LACK(a)                            \
    do {                                   \
        if (miss && n < cap) miss[n] = (a); \
        n++;                               \
    } while (0)
    for (int f = 0; f < NFIELD; f++)
        if (field_required(mode, f) && find_column(names, ncol, FIELDS[f].aliases, found) < 0) LACK(FIELDS[f].aliases);
    if (mode == MODE_GALAXY && find_column(names, ncol, FIELDS[F_HLR].aliases, found) < 0 &&
        find_column(names, ncol, FIELDS[F_FWHM].aliases, found) < 0)
        LACK(HLR_OR_FWHM);
    if (find_column(names, ncol, ID_ALIASES, found) < 0) LACK(ID_ALIASES);
    if (mode == MODE_SCENE && find_column(names, ncol, TYPE_ALIASES, found) < 0) LACK(TYPE_ALIASES);
    if (!has_mag_column(names, ncol)) LACK(MAG_ANY);
#undef LACK
    return n;
}

static wf_status sniff_columns(reader *r, char *const *names, int ncol);

static wf_status resolve_columns(reader *r, char *const *names, int ncol)
{
    if (r->sniff) return sniff_columns(r, names, ncol);
    const char *miss[1];
    if (lacking_columns(names, ncol, r->mode, miss, 1) > 0) {
        if (miss[0] == MAG_ANY)
            return wf_error(WF_ERR_INPUT,
                            "%s: missing required column 'mag_<band>' (no magnitude column, e.g. "
                            "mag_H158)",
                            r->path);
        return missing(r, miss[0]);
    }
    for (int f = 0; f < NFIELD; f++) r->pos[f] = find_column(names, ncol, FIELDS[f].aliases, r->name[f]);
    r->id_pos = find_column(names, ncol, ID_ALIASES, r->id_name);
    r->type_pos = -1;
    if (r->mode == MODE_SCENE) r->type_pos = find_column(names, ncol, TYPE_ALIASES, r->type_name);
    r->nband = 0;
    for (int c = 0; c < ncol; c++) {
        if (strncasecmp(names[c], "mag_", 4) != 0) continue;
        const char *band = names[c] + 4;
        if (!*band) continue;
        int dup = 0;
        for (int b = 0; b < r->nband; b++) dup |= strcasecmp(r->band[b], band) == 0;
        if (dup) continue; /* the first spelling of a band wins, as for aliases */
        if (strlen(band) >= WF_CATALOG_BANDLEN)
            return wf_error(WF_ERR_INPUT, "%s: column '%s': band name longer than %d characters",
                            r->path, names[c], WF_CATALOG_BANDLEN - 1);
        if (r->nband == WF_CATALOG_MAXBAND)
            return wf_error(WF_ERR_INPUT, "%s: more than %d magnitude columns (mag_<band>)",
                            r->path, WF_CATALOG_MAXBAND);
        r->band_pos[r->nband] = c;
        snprintf(r->band_col[r->nband], NAMELEN, "%s", names[c]);
        snprintf(r->band[r->nband], WF_CATALOG_BANDLEN, "%s", band);
        r->nband++;
    }
    return WF_OK;
}

static wf_status make_catalogs(reader *r)
{
    const char *bands[WF_CATALOG_MAXBAND];
    for (int b = 0; b < r->nband; b++) bands[b] = r->band[b];
    wf_status st = WF_OK;
    if (r->gal) {
        int flags = (r->pos[F_Z] >= 0 ? WF_CATALOG_HAS_Z : 0) |
                    (r->pos[F_LOGM] >= 0 ? WF_CATALOG_HAS_LOGMASS : 0) |
                    (r->pos[F_LOGSFR] >= 0 ? WF_CATALOG_HAS_LOGSFR : 0);
        st = wf_catalog_init(r->gal, WF_CATALOG_GALAXY, r->nband, bands, flags, r->path);
    }
    if (!st && r->star) st = wf_catalog_init(r->star, WF_CATALOG_STAR, r->nband, bands, 0, r->path);
    if (!st && r->sn) st = wf_catalog_init(r->sn, WF_CATALOG_STAR, r->nband, bands, 0, r->path);
    return st;
}

/* The header's names and, for each format, the required columns it lacks (first alias of
 * each); reading stops at the header. */
static wf_status sniff_columns(reader *r, char *const *names, int ncol)
{
    size_t k = 0;
    r->found[0] = '\0';
    for (int c = 0; c < ncol && k + 8 < sizeof r->found; c++)
        k += (size_t)snprintf(r->found + k, sizeof r->found - k, "%s%s", c ? ", " : "", names[c]);
    if (k + 8 >= sizeof r->found) snprintf(r->found + sizeof r->found - 8, 8, ", ...");
    static const read_mode modes[3] = {MODE_GALAXY, MODE_STAR, MODE_SCENE};
    for (int m = 0; m < 3; m++) {
        const char *miss[NFIELD + 4];
        int n = lacking_columns(names, ncol, modes[m], miss, NFIELD + 4);
        r->lacks[m] = n;
        size_t len = 0;
        r->lacking[m][0] = '\0';
        for (int i = 0; i < n && len + 24 < sizeof r->lacking[m]; i++) {
            const char *a = miss[i];
            int alen = (int)strcspn(a, "|");
            len += (size_t)snprintf(r->lacking[m] + len, sizeof r->lacking[m] - len, "%s%.*s%s", i ? ", " : "", alen, a,
                                    a == HLR_OR_FWHM ? " (or fwhm)" : "");
        }
    }
    return WF_OK;
}

/* "file: row 12 (line 15)" — the line only where the file has lines. */
static void where(const reader *r, long row, long line, char *out, size_t size)
{
    if (line > 0)
        snprintf(out, size, "%s: row %ld (line %ld)", r->path, row, line);
    else
        snprintf(out, size, "%s: row %ld", r->path, row);
}

static wf_status check_value(const reader *r, const char *col, double v, double lo, double hi,
                             int lo_open, int hi_open, long row, long line)
{
    char at[600];
    if (isnan(v)) {
        where(r, row, line, at, sizeof at);
        return wf_error(WF_ERR_INPUT, "%s: column '%s': value is NaN", at, col);
    }
    if (isinf(v)) {
        where(r, row, line, at, sizeof at);
        return wf_error(WF_ERR_INPUT, "%s: column '%s': value is infinite (%s)", at, col,
                        v > 0 ? "+inf" : "-inf");
    }
    if (v < lo || v > hi || (lo_open && v == lo) || (hi_open && v == hi)) {
        where(r, row, line, at, sizeof at);
        return wf_error(WF_ERR_RANGE, "%s: column '%s': value %.10g outside %c%g, %g%c", at, col, v,
                        lo_open ? '(' : '[', lo, hi, hi_open ? ')' : ']');
    }
    return WF_OK;
}

static wf_status check_field(const reader *r, const rowval *w, int f, long row, long line)
{
    const field_spec *s = &FIELDS[f];
    return check_value(r, r->name[f], w->v[f], s->lo, s->hi, s->lo_open, s->hi_open, row, line);
}

static wf_catalog *row_target(const reader *r, const rowval *w, long row, long line, wf_status *st)
{
    *st = WF_OK;
    if (r->mode == MODE_GALAXY) return r->gal;
    if (r->mode == MODE_STAR) return r->star;
    if (strcasecmp(w->type, "gal") == 0 || strcasecmp(w->type, "galaxy") == 0) return r->gal;
    if (strcasecmp(w->type, "star") == 0) return r->star;
    if (strcasecmp(w->type, "sn") == 0 || strcasecmp(w->type, "snia") == 0) return r->sn;
    char at[600];
    where(r, row, line, at, sizeof at);
    *st = wf_error(WF_ERR_INPUT, "%s: column '%s': unknown object type '%s' (gal, star or sn)", at,
                   r->type_name, w->type);
    return NULL;
}

static wf_status accept_row(reader *r, const rowval *w, long row, long line)
{
    wf_status st;
    wf_catalog *cat = row_target(r, w, row, line, &st);
    if (st) return st;
    if ((st = check_field(r, w, F_RA, row, line)) || (st = check_field(r, w, F_DEC, row, line)))
        return st;
    for (int b = 0; b < r->nband; b++)
        if ((st = check_value(r, r->band_col[b], w->mag[b], MAG_LO, MAG_HI, 0, 0, row, line)))
            return st;
    int gal = cat->kind == WF_CATALOG_GALAXY;
    double hlr = 0.0, hlrb = 0.0;
    if (gal) {
        static const int always[] = {F_BULGE, F_KNOT, F_E1, F_E2};
        for (size_t k = 0; k < sizeof always / sizeof *always; k++)
            if ((st = check_field(r, w, always[k], row, line))) return st;
        static const int optional[] = {F_HLRB, F_Z, F_PA, F_LOGM, F_LOGSFR};
        for (size_t k = 0; k < sizeof optional / sizeof *optional; k++)
            if (r->pos[optional[k]] >= 0 && (st = check_field(r, w, optional[k], row, line)))
                return st;
        if (r->pos[F_HLR] >= 0) {
            if ((st = check_field(r, w, F_HLR, row, line))) return st;
            hlr = w->v[F_HLR];
        } else {
            if ((st = check_field(r, w, F_FWHM, row, line))) return st;
            hlr = w->v[F_FWHM] * HLR_PER_FWHM;
        }
        hlrb = r->pos[F_HLRB] >= 0 ? w->v[F_HLRB] : 0.5 * hlr;
        double e2sum = w->v[F_E1] * w->v[F_E1] + w->v[F_E2] * w->v[F_E2];
        if (!(e2sum < 1.0)) {
            char at[600];
            where(r, row, line, at, sizeof at);
            return wf_error(WF_ERR_RANGE, "%s: columns '%s', '%s': |e| = %.6g, must be below 1", at,
                            r->name[F_E1], r->name[F_E2], sqrt(e2sum));
        }
    }
    size_t i;
    if ((st = wf_catalog_push(cat, &i))) return st;
    cat->id[i] = w->id;
    double ra = w->v[F_RA];
    if (ra < 0.0) ra += 360.0;
    if (ra >= 360.0) ra -= 360.0;
    cat->ra[i] = ra;
    cat->dec[i] = w->v[F_DEC];
    for (int b = 0; b < r->nband; b++) cat->mag[b][i] = (float)w->mag[b];
    if (gal) {
        cat->hlr_disk[i] = (float)hlr;
        cat->hlr_bulge[i] = (float)hlrb;
        cat->bulge_frac[i] = (float)w->v[F_BULGE];
        cat->knot_frac[i] = (float)w->v[F_KNOT];
        cat->e1[i] = (float)w->v[F_E1];
        cat->e2[i] = (float)w->v[F_E2];
        cat->pa[i] = r->pos[F_PA] >= 0 ? (float)w->v[F_PA] : 0.0f;
        if (cat->has_z) cat->z[i] = (float)w->v[F_Z];
        if (cat->has_logmass) cat->logmass[i] = (float)w->v[F_LOGM];
        if (cat->has_logsfr) cat->logsfr[i] = (float)w->v[F_LOGSFR];
    }
    return WF_OK;
}

/* ------------------------------------------------------------------ CSV */

typedef struct linebuf {
    char *s;
    size_t cap;
} linebuf;

/* One line without its end-of-line characters: 1, or 0 at the end of the file, or -1 on a
 * read error. Lines of any length. */
static int read_line(gzFile gz, linebuf *lb)
{
    size_t n = 0;
    for (;;) {
        if (lb->cap - n < 2) {
            size_t cap = lb->cap ? 2 * lb->cap : 4096;
            char *q = realloc(lb->s, cap);
            if (!q) return -1;
            lb->s = q;
            lb->cap = cap;
        }
        size_t room = lb->cap - n;
        if (room > (size_t)1 << 30) room = (size_t)1 << 30;
        if (!gzgets(gz, lb->s + n, (int)room)) {
            int err;
            gzerror(gz, &err);
            if (err != Z_OK && err != Z_BUF_ERROR) return -1;
            if (n == 0) return 0;
            break;
        }
        n += strlen(lb->s + n);
        if (n > 0 && lb->s[n - 1] == '\n') break;
        if (gzeof(gz)) break;
    }
    while (n > 0 && (lb->s[n - 1] == '\n' || lb->s[n - 1] == '\r')) n--;
    lb->s[n] = '\0';
    return 1;
}

static char *trim(char *s)
{
    while (isspace((unsigned char)*s)) s++;
    size_t n = strlen(s);
    while (n > 0 && isspace((unsigned char)s[n - 1])) s[--n] = '\0';
    if (n >= 2 && s[0] == '"' && s[n - 1] == '"') {
        s[n - 1] = '\0';
        s++;
    }
    return s;
}

static int skip_line(const char *s)
{
    while (isspace((unsigned char)*s)) s++;
    return *s == '\0' || *s == '#';
}

typedef struct fieldbuf {
    char **f;
    int cap;
} fieldbuf;

/* Splits s in place at commas; the number of fields, or -1 when out of memory. */
static int split_fields(char *s, fieldbuf *fb)
{
    int n = 0;
    for (;;) {
        if (n == fb->cap) {
            int cap = fb->cap ? 2 * fb->cap : 64;
            char **q = realloc(fb->f, (size_t)cap * sizeof *q);
            if (!q) return -1;
            fb->f = q;
            fb->cap = cap;
        }
        char *comma = strchr(s, ',');
        if (comma) *comma = '\0';
        fb->f[n++] = trim(s);
        if (!comma) break;
        s = comma + 1;
    }
    return n;
}

static wf_status parse_number(const reader *r, const char *col, const char *text, double *v,
                              long row, long line)
{
    char at[600];
    if (!*text) {
        where(r, row, line, at, sizeof at);
        return wf_error(WF_ERR_INPUT, "%s: column '%s': empty value", at, col);
    }
    char *end;
    errno = 0;
    *v = strtod(text, &end);
    if (end == text || *end != '\0') {
        where(r, row, line, at, sizeof at);
        return wf_error(WF_ERR_INPUT, "%s: column '%s': '%.40s' is not a number", at, col, text);
    }
    return WF_OK;
}

static wf_status parse_id(const reader *r, const char *text, int64_t *id, long row, long line)
{
    char at[600];
    char *end;
    errno = 0;
    long long v = strtoll(text, &end, 10);
    if (!*text || end == text || *end != '\0' || errno == ERANGE) {
        where(r, row, line, at, sizeof at);
        return wf_error(WF_ERR_INPUT, "%s: column '%s': '%.40s' is not a 64-bit integer", at,
                        r->id_name, text);
    }
    *id = (int64_t)v;
    return WF_OK;
}

static wf_status read_csv(reader *r, gzFile gz)
{
    linebuf lb = {0};
    fieldbuf fb = {0};
    wf_status st = WF_OK;
    long line = 0, row = 0;
    int ncol = -1, got;
    while ((got = read_line(gz, &lb)) == 1) {
        line++;
        char *text = lb.s;
        if (line == 1 && strncmp(text, "\xEF\xBB\xBF", 3) == 0) text += 3; /* UTF-8 BOM */
        if (skip_line(text)) continue;
        int nf = split_fields(text, &fb);
        if (nf < 0) {
            st = wf_error(WF_ERR_NOMEM, "%s: line %ld: no memory", r->path, line);
            break;
        }
        if (ncol < 0) {
            ncol = nf;
            if ((st = resolve_columns(r, fb.f, nf)) || (st = make_catalogs(r)) || r->sniff) break;
            continue;
        }
        row++;
        if (nf != ncol) {
            st = wf_error(WF_ERR_INPUT, "%s: row %ld (line %ld): %d fields, the header has %d",
                          r->path, row, line, nf, ncol);
            break;
        }
        rowval w;
        memset(&w, 0, sizeof w);
        if ((st = parse_id(r, fb.f[r->id_pos], &w.id, row, line))) break;
        for (int f = 0; f < NFIELD && !st; f++)
            if (r->pos[f] >= 0)
                st = parse_number(r, r->name[f], fb.f[r->pos[f]], &w.v[f], row, line);
        for (int b = 0; b < r->nband && !st; b++)
            st = parse_number(r, r->band_col[b], fb.f[r->band_pos[b]], &w.mag[b], row, line);
        if (st) break;
        if (r->type_pos >= 0) snprintf(w.type, sizeof w.type, "%s", fb.f[r->type_pos]);
        if ((st = accept_row(r, &w, row, line))) break;
    }
    if (!st && got < 0) st = wf_error(WF_ERR_IO, "%s: read error after line %ld", r->path, line);
    if (!st && ncol < 0) st = wf_error(WF_ERR_INPUT, "%s: no header row (empty file)", r->path);
    free(lb.s);
    free(fb.f);
    return st;
}

/* ------------------------------------------------------------------ FITS */

static wf_status fits_fail(const reader *r, const char *what, int status)
{
    char text[FLEN_STATUS] = "";
    fits_get_errstatus(status, text);
    fits_clear_errmsg();
    return wf_error(WF_ERR_INPUT, "%s: FITS %s: %s (status %d)", r->path, what, text, status);
}

static wf_status fits_check_numeric(const reader *r, fitsfile *ff, int col, const char *name)
{
    int status = 0, typecode;
    long repeat, width;
    if (fits_get_coltype(ff, col + 1, &typecode, &repeat, &width, &status))
        return fits_fail(r, "column type", status);
    if (typecode == TSTRING || typecode < 0)
        return wf_error(WF_ERR_INPUT, "%s: column '%s' does not hold numbers", r->path, name);
    if (repeat != 1)
        return wf_error(WF_ERR_INPUT, "%s: column '%s' is a vector (%ld values per row)", r->path,
                        name, repeat);
    return WF_OK;
}

static wf_status read_fits(reader *r)
{
    fitsfile *ff = NULL;
    int status = 0;
    wf_status st = WF_OK;
    char **names = NULL;
    double *val[NFIELD + WF_CATALOG_MAXBAND] = {0};
    long long *ids = NULL;
    char **types = NULL;
    char *typebuf = NULL;
    int ncol = 0;
    long nrows = 0;

    /* The first table, as fits_open_table finds it; but searched here, because cfitsio 4.2's
     * fits_open_table loses its handle (16 bytes) when the header after the primary is
     * damaged (found by fuzz/fuzz_catalog_fits.c). */
    int hdutype = IMAGE_HDU;
    if ((st = wf_fits_check_headers(r->path))) return st;
    if (!fits_open_file(&ff, r->path, READONLY, &status)) {
        fits_get_hdu_type(ff, &hdutype, &status);
        while (!status && hdutype == IMAGE_HDU) fits_movrel_hdu(ff, 1, &hdutype, &status);
    }
    if (status) {
        char text[FLEN_STATUS] = "no table HDU in the file";
        if (status != END_OF_FILE || !ff) fits_get_errstatus(status, text);
        fits_clear_errmsg();
        int close_status = 0;
        if (ff) fits_close_file(ff, &close_status);
        return wf_error(WF_ERR_IO, "%s: cannot open as a FITS table: %s", r->path, text);
    }
    if (fits_get_num_cols(ff, &ncol, &status) || fits_get_num_rows(ff, &nrows, &status)) {
        st = fits_fail(r, "table size", status);
        goto done;
    }
    names = calloc((size_t)ncol + 1, sizeof *names);
    if (!names) goto nomem;
    for (int c = 0; c < ncol; c++) {
        char key[FLEN_KEYWORD], value[FLEN_VALUE] = "";
        snprintf(key, sizeof key, "TTYPE%d", c + 1);
        int ks = 0;
        if (fits_read_key(ff, TSTRING, key, value, NULL, &ks)) {
            fits_clear_errmsg();
            value[0] = '\0';
        }
        if (!(names[c] = strdup(trim(value)))) goto nomem;
    }
    if ((st = resolve_columns(r, names, ncol)) || (st = make_catalogs(r)) || r->sniff) goto done;

    if ((st = fits_check_numeric(r, ff, r->id_pos, r->id_name))) goto done;
    for (int f = 0; f < NFIELD; f++)
        if (r->pos[f] >= 0 && (st = fits_check_numeric(r, ff, r->pos[f], r->name[f]))) goto done;
    for (int b = 0; b < r->nband; b++)
        if ((st = fits_check_numeric(r, ff, r->band_pos[b], r->band_col[b]))) goto done;
    long typewidth = 0;
    if (r->type_pos >= 0) {
        int typecode;
        long repeat;
        if (fits_get_coltype(ff, r->type_pos + 1, &typecode, &repeat, &typewidth, &status)) {
            st = fits_fail(r, "column type", status);
            goto done;
        }
        if (typecode != TSTRING) {
            st =
                wf_error(WF_ERR_INPUT, "%s: column '%s' does not hold text", r->path, r->type_name);
            goto done;
        }
        typewidth = repeat > typewidth ? repeat : typewidth;
        types = calloc(CHUNK, sizeof *types);
        typebuf = calloc((size_t)CHUNK, (size_t)typewidth + 1);
        if (!types || !typebuf) goto nomem;
        for (int k = 0; k < CHUNK; k++) types[k] = typebuf + (size_t)k * ((size_t)typewidth + 1);
    }
    for (int k = 0; k < NFIELD + r->nband; k++)
        if (!(val[k] = malloc(CHUNK * sizeof *val[k]))) goto nomem;
    if (!(ids = malloc(CHUNK * sizeof *ids))) goto nomem;

    /* Nulls (TNULL, IEEE NaN) read as NaN and are then reported as such. */
    double nulval = NAN;
    long long nulid = 0;
    for (long first = 1; first <= nrows; first += CHUNK) {
        long cnt = nrows - first + 1 < CHUNK ? nrows - first + 1 : CHUNK;
        int anynul = 0;
        fits_read_col(ff, TLONGLONG, r->id_pos + 1, first, 1, cnt, &nulid, ids, &anynul, &status);
        for (int f = 0; f < NFIELD; f++)
            if (r->pos[f] >= 0)
                fits_read_col(ff, TDOUBLE, r->pos[f] + 1, first, 1, cnt, &nulval, val[f], &anynul,
                              &status);
        for (int b = 0; b < r->nband; b++)
            fits_read_col(ff, TDOUBLE, r->band_pos[b] + 1, first, 1, cnt, &nulval, val[NFIELD + b],
                          &anynul, &status);
        if (types)
            fits_read_col_str(ff, r->type_pos + 1, first, 1, cnt, "", types, &anynul, &status);
        if (status) {
            st = fits_fail(r, "read", status);
            goto done;
        }
        for (long k = 0; k < cnt; k++) {
            rowval w;
            memset(&w, 0, sizeof w);
            w.id = (int64_t)ids[k];
            for (int f = 0; f < NFIELD; f++)
                if (r->pos[f] >= 0) w.v[f] = val[f][k];
            for (int b = 0; b < r->nband; b++) w.mag[b] = val[NFIELD + b][k];
            if (types) snprintf(w.type, sizeof w.type, "%s", trim(types[k]));
            if ((st = accept_row(r, &w, first + k, 0))) goto done;
        }
    }
    goto done;
nomem:
    st = wf_error(WF_ERR_NOMEM, "%s: no memory while reading the table", r->path);
done:
    status = 0;
    fits_close_file(ff, &status);
    if (names)
        for (int c = 0; c < ncol; c++) free(names[c]);
    free(names);
    for (int k = 0; k < NFIELD + WF_CATALOG_MAXBAND; k++) free(val[k]);
    free(ids);
    free(types);
    free(typebuf);
    return st;
}

/* ------------------------------------------------------------------ entry points */

static wf_status read_any(reader *r)
{
    for (int f = 0; f < NFIELD; f++) r->pos[f] = -1;
    gzFile gz = gzopen(r->path, "rb");
    if (!gz)
        return wf_error(WF_ERR_IO, "%s: cannot open: %s", r->path,
                        errno ? strerror(errno) : "unknown error");
    gzbuffer(gz, 1 << 17);
    char magic[6] = {0};
    int got = gzread(gz, magic, sizeof magic);
    wf_status st;
    if (got == (int)sizeof magic && memcmp(magic, "SIMPLE", 6) == 0) {
        gzclose(gz);
        st = read_fits(r);
    } else if (got < 0) {
        gzclose(gz);
        st = wf_error(WF_ERR_IO, "%s: read error", r->path);
    } else {
        gzrewind(gz);
        st = read_csv(r, gz);
        gzclose(gz);
    }
    if (st) {
        wf_catalog_free(r->gal);
        wf_catalog_free(r->star);
        wf_catalog_free(r->sn);
    }
    return st;
}

wf_status wf_catalog_read_galaxies(const char *path, wf_catalog *out)
{
    reader r;
    memset(&r, 0, sizeof r);
    memset(out, 0, sizeof *out);
    r.path = path;
    r.mode = MODE_GALAXY;
    r.gal = out;
    return read_any(&r);
}

wf_status wf_catalog_read_stars(const char *path, wf_catalog *out)
{
    reader r;
    memset(&r, 0, sizeof r);
    memset(out, 0, sizeof *out);
    r.path = path;
    r.mode = MODE_STAR;
    r.star = out;
    return read_any(&r);
}

wf_status wf_catalog_read_galsim_scene(const char *path, wf_catalog *gal, wf_catalog *stars,
                                       wf_catalog *sne)
{
    reader r;
    memset(&r, 0, sizeof r);
    memset(gal, 0, sizeof *gal);
    memset(stars, 0, sizeof *stars);
    memset(sne, 0, sizeof *sne);
    r.path = path;
    r.mode = MODE_SCENE;
    r.gal = gal;
    r.star = stars;
    r.sn = sne;
    return read_any(&r);
}

wf_status wf_catalog_sniff(const char *path, int accept, wf_catalog_format *out)
{
    reader r;
    memset(&r, 0, sizeof r);
    r.path = path;
    r.mode = MODE_GALAXY;
    r.sniff = 1;
    wf_status st = read_any(&r);
    if (st) return st;
    /* lacks[] is indexed galaxy, star, scene; a file with a type column and the scene's
     * columns holds several kinds of object, so the scene's reader is preferred to the
     * galaxies' one, and a galaxy catalog's to a star catalog's (which needs the least) */
    static const struct { int m; wf_catalog_format f; const char *what; } order[3] = {
        {2, WF_CATALOG_FORMAT_SCENE, "a GalSim benchmark scene (scene.kind galsim or catalog: scene.catalog, --catalog)"},
        {0, WF_CATALOG_FORMAT_GALAXIES, "a galaxy catalog (scene.kind catalog: scene.catalog, --catalog)"},
        {1, WF_CATALOG_FORMAT_STARS, "a star catalog (scene.kind catalog: scene.stars, --stars)"},
    };
    for (int i = 0; i < 3; i++)
        if ((accept & order[i].f) && r.lacks[order[i].m] == 0) {
            *out = order[i].f;
            return WF_OK;
        }
    char why[1200];
    size_t len = 0;
    for (int i = 0; i < 3; i++) {
        int m = order[i].m;
        if (r.lacks[m]) len += (size_t)snprintf(why + len, sizeof why - len, "%s%s needs %s", i ? "; " : "", order[i].what, r.lacking[m]);
        else len += (size_t)snprintf(why + len, sizeof why - len, "%sit has the columns of %s, which is not read here", i ? "; " : "", order[i].what);
        if (len >= sizeof why) break;
    }
    return wf_error(WF_ERR_INPUT, "%s: its columns (%s) fit no catalog format read here: %s (docs/CATALOGS.md)", path, r.found, why);
}

/* ------------------------------------------------------------------ writers */

static wf_status tmp_name(const char *path, char *tmp, size_t size)
{
    if ((size_t)snprintf(tmp, size, "%s.tmp", path) >= size)
        return wf_error(WF_ERR_INPUT, "%s: path too long", path);
    return WF_OK;
}

wf_status wf_catalog_write_csv(const char *path, const wf_catalog *cat)
{
    char tmp[4096];
    wf_status st = tmp_name(path, tmp, sizeof tmp);
    if (st) return st;
    size_t len = strlen(path);
    int gzip = len > 3 && strcmp(path + len - 3, ".gz") == 0;
    gzFile gz = gzopen(tmp, gzip ? "wb6" : "wbT");
    if (!gz) return wf_error(WF_ERR_IO, "%s: cannot create: %s", tmp, strerror(errno));
    gzbuffer(gz, 1 << 17);
    int gal = cat->kind == WF_CATALOG_GALAXY;
    int bad = gzprintf(gz, "# wfisim %s catalog from %s\nid,ra,dec", gal ? "galaxy" : "star",
                       cat->source) <= 0;
    if (gal && cat->has_z) bad |= gzputs(gz, ",z") < 0;
    for (int b = 0; b < cat->nband; b++) bad |= gzprintf(gz, ",mag_%s", cat->band[b]) <= 0;
    if (gal) {
        bad |= gzputs(gz, ",hlr,hlr_bulge,bulge_frac,knot_frac,e1,e2,pa") < 0;
        if (cat->has_logmass) bad |= gzputs(gz, ",logmass") < 0;
        if (cat->has_logsfr) bad |= gzputs(gz, ",logsfr") < 0;
    }
    bad |= gzputs(gz, "\n") < 0;
    for (size_t i = 0; i < cat->n && !bad; i++) {
        char line[1024];
        int k = snprintf(line, sizeof line, "%lld,%.17g,%.17g", (long long)cat->id[i], cat->ra[i],
                         cat->dec[i]);
        if (gal && cat->has_z) k += snprintf(line + k, sizeof line - (size_t)k, ",%.9g", cat->z[i]);
        for (int b = 0; b < cat->nband; b++)
            k += snprintf(line + k, sizeof line - (size_t)k, ",%.9g", cat->mag[b][i]);
        if (gal) {
            k += snprintf(line + k, sizeof line - (size_t)k, ",%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g",
                          cat->hlr_disk[i], cat->hlr_bulge[i], cat->bulge_frac[i],
                          cat->knot_frac[i], cat->e1[i], cat->e2[i], cat->pa[i]);
            if (cat->has_logmass)
                k += snprintf(line + k, sizeof line - (size_t)k, ",%.9g", cat->logmass[i]);
            if (cat->has_logsfr)
                k += snprintf(line + k, sizeof line - (size_t)k, ",%.9g", cat->logsfr[i]);
        }
        k += snprintf(line + k, sizeof line - (size_t)k, "\n");
        bad |= gzwrite(gz, line, (unsigned)k) != k;
    }
    bad |= gzclose(gz) != Z_OK;
    if (bad) {
        unlink(tmp);
        return wf_error(WF_ERR_IO, "%s: write failed", tmp);
    }
    return wf_file_rename(tmp, path);
}

wf_status wf_catalog_write_fits(const char *path, const wf_catalog *cat)
{
    char tmp[4096];
    wf_status st = tmp_name(path, tmp, sizeof tmp);
    if (st) return st;
    unlink(tmp);
    enum { MAXCOL = 16 + WF_CATALOG_MAXBAND };
    char names[MAXCOL][FLEN_VALUE];
    char *ttype[MAXCOL], *tform[MAXCOL], *tunit[MAXCOL];
    int ncol = 0;
    int gal = cat->kind == WF_CATALOG_GALAXY;
#define ADDCOL(nm, form, unit)                                                                     \
    do {                                                                                           \
        snprintf(names[ncol], FLEN_VALUE, "%s", nm);                                               \
        ttype[ncol] = names[ncol];                                                                 \
        tform[ncol] = (char *)(form);                                                              \
        tunit[ncol] = (char *)(unit);                                                              \
        ncol++;                                                                                    \
    } while (0)
    ADDCOL("ID", "K", "");
    ADDCOL("RA", "D", "deg");
    ADDCOL("DEC", "D", "deg");
    for (int b = 0; b < cat->nband; b++) {
        char nm[FLEN_VALUE];
        snprintf(nm, sizeof nm, "MAG_%s", cat->band[b]);
        ADDCOL(nm, "E", "mag(AB)");
    }
    if (gal) {
        ADDCOL("HLR", "E", "arcsec");
        ADDCOL("HLR_BULGE", "E", "arcsec");
        ADDCOL("BULGE_FRAC", "E", "");
        ADDCOL("KNOT_FRAC", "E", "");
        ADDCOL("E1", "E", "");
        ADDCOL("E2", "E", "");
        ADDCOL("PA", "E", "deg");
        if (cat->has_z) ADDCOL("Z", "E", "");
        if (cat->has_logmass) ADDCOL("LOGMASS", "E", "log(Msun)");
        if (cat->has_logsfr) ADDCOL("LOGSFR", "E", "log(Msun/yr)");
    }
#undef ADDCOL
    fitsfile *ff = NULL;
    int status = 0;
    wf_fitsdisk_create(&ff, tmp, &status); /* the name as given: no cfitsio filename syntax */
    fits_create_tbl(ff, BINARY_TBL, (LONGLONG)cat->n, ncol, ttype, tform, tunit,
                    gal ? "GALAXIES" : "STARS", &status);
    fits_write_key(ff, TSTRING, "WFKIND", gal ? "GALAXY" : "STAR", "wfisim catalog kind", &status);
    char src[FLEN_VALUE];
    snprintf(src, sizeof src, "%.60s", cat->source);
    fits_write_key(ff, TSTRING, "WFSOURCE", src, "where the rows came from", &status);
    if (cat->n > 0) {
        int c = 1;
        fits_write_col(ff, TLONGLONG, c++, 1, 1, (LONGLONG)cat->n, (long long *)cat->id, &status);
        fits_write_col(ff, TDOUBLE, c++, 1, 1, (LONGLONG)cat->n, cat->ra, &status);
        fits_write_col(ff, TDOUBLE, c++, 1, 1, (LONGLONG)cat->n, cat->dec, &status);
        for (int b = 0; b < cat->nband; b++)
            fits_write_col(ff, TFLOAT, c++, 1, 1, (LONGLONG)cat->n, cat->mag[b], &status);
        if (gal) {
            float *cols[] = {cat->hlr_disk, cat->hlr_bulge, cat->bulge_frac, cat->knot_frac,
                             cat->e1,       cat->e2,        cat->pa};
            for (size_t k = 0; k < sizeof cols / sizeof *cols; k++)
                fits_write_col(ff, TFLOAT, c++, 1, 1, (LONGLONG)cat->n, cols[k], &status);
            if (cat->has_z)
                fits_write_col(ff, TFLOAT, c++, 1, 1, (LONGLONG)cat->n, cat->z, &status);
            if (cat->has_logmass)
                fits_write_col(ff, TFLOAT, c++, 1, 1, (LONGLONG)cat->n, cat->logmass, &status);
            if (cat->has_logsfr)
                fits_write_col(ff, TFLOAT, c++, 1, 1, (LONGLONG)cat->n, cat->logsfr, &status);
        }
    }
    fits_write_chksum(ff, &status);
    int close_status = 0;
    if (ff) fits_close_file(ff, &close_status);
    if (status || close_status) {
        char text[FLEN_STATUS] = "";
        fits_get_errstatus(status ? status : close_status, text);
        fits_clear_errmsg();
        unlink(tmp);
        return wf_error(WF_ERR_IO, "%s: FITS write failed: %s", tmp, text);
    }
    return wf_file_rename(tmp, path);
}
