/* `wfisim efficiency`: reads images, detection catalogs and truth tables line by line, pools
 * found / not-found per truth object, and writes the tables, plot, summary and SNANA map.
 * The statistics are analysis/effstats.c. */
#include "analysis/efficiency.h"

#include <errno.h>
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "hal/file.h"
#include "sim/fits/fitscheck.h"
#include "sim/sn/sncat.h"
#include "sim/survey/wcs.h"
#include "analysis/plot.h"
#include "hal/dq.h"

static const char *type_name[WF_EFF_NTYPE] = {"galaxy", "star", "sn"};
static const char *type_hdu[WF_EFF_NTYPE] = {"GALAXIES", "STARS", "SNE"};

void wf_eff_defaults(wf_eff_options *o)
{
    memset(o, 0, sizeof *o);
    o->radius_arcsec = 0.3;
    o->bin = 0.25;
    o->types = (1 << WF_EFF_NTYPE) - 1;
    o->iso_factor = 1.5;
    o->iso_host_mag = 22.0;
}

wf_status wf_eff_parse_types(const char *s, int *types)
{
    int t = 0;
    const char *p = s;
    if (!s || !*s) return wf_error(WF_ERR_INPUT, "--types: empty (give galaxy,star,sn or a part)");
    while (*p) {
        size_t n = strcspn(p, ",");
        int k = -1;
        for (int j = 0; j < WF_EFF_NTYPE; j++) {
            const char *alt = j == WF_EFF_GALAXY ? "galaxies" : j == WF_EFF_STAR ? "stars" : "sne";
            if ((strlen(type_name[j]) == n && !strncmp(p, type_name[j], n)) || (strlen(alt) == n && !strncmp(p, alt, n)))
                k = j;
        }
        if (k < 0) return wf_error(WF_ERR_INPUT, "--types '%s': '%.*s' is not galaxy, star or sn", s, (int)n, p);
        t |= 1 << k;
        p += n;
        if (*p == ',') p++;
    }
    *types = t;
    return WF_OK;
}

/* ---- the list ---- */

/* The message of the error st, prefixed with the list line it came from. */
static wf_status at_line(wf_status st, const char *list_path, int lineno)
{
    char msg[2048];
    snprintf(msg, sizeof msg, "%s", wf_error_message());
    return wf_error(st, "%s:%d: %s", list_path, lineno, msg);
}


typedef struct line {
    int lineno;
    char *image, *cat;
    char **truth;
    int ntruth;
} line;

typedef struct list {
    line *v;
    int n, cap;
} list;

static void list_free(list *l)
{
    for (int i = 0; i < l->n; i++) {
        free(l->v[i].image);
        free(l->v[i].cat);
        for (int k = 0; k < l->v[i].ntruth; k++) free(l->v[i].truth[k]);
        free(l->v[i].truth);
    }
    free(l->v);
}

static wf_status need_file(const char *list_path, int lineno, const char *what, const char *path)
{
    struct stat sb;
    const char *why = stat(path, &sb) ? (errno == ENOENT ? "no such file" : strerror(errno))
                      : !S_ISREG(sb.st_mode) ? "not a regular file"
                      : access(path, R_OK) ? "not readable" : NULL;
    return why ? wf_error(WF_ERR_INPUT, "%s:%d: %s %s: %s", list_path, lineno, what, path, why) : WF_OK;
}

static wf_status read_list(const char *path, list *l)
{
    memset(l, 0, sizeof *l);
    FILE *f = fopen(path, "r");
    if (!f) return wf_error(WF_ERR_INPUT, "%s: cannot open the list: %s", path, strerror(errno));
    char buf[16384];
    int lineno = 0;
    wf_status st = WF_OK;
    while (!st && fgets(buf, sizeof buf, f)) {
        lineno++;
        size_t len = strlen(buf);
        if (len == sizeof buf - 1 && buf[len - 1] != '\n') {
            st = wf_error(WF_ERR_INPUT, "%s:%d: line longer than %zu characters", path, lineno, sizeof buf - 2);
            break;
        }
        char *hash = strchr(buf, '#');
        if (hash) *hash = 0;
        char *field[4] = {0};
        int nf = 0;
        for (char *tok = strtok(buf, " \t\r\n"); tok; tok = strtok(NULL, " \t\r\n")) {
            if (nf < 4) field[nf] = tok;
            nf++;
        }
        if (nf == 0) continue;
        if (nf != 3) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: %d fields; expected IMAGE DETCAT TRUTH[,TRUTH...]", path, lineno, nf);
            break;
        }
        if (l->n == l->cap) {
            int nc = l->cap ? 2 * l->cap : 16;
            line *v = realloc(l->v, (size_t)nc * sizeof *v);
            if (!v) { st = wf_error(WF_ERR_NOMEM, "%s: out of memory", path); break; }
            l->v = v, l->cap = nc;
        }
        line *e = &l->v[l->n++];
        memset(e, 0, sizeof *e);
        e->lineno = lineno;
        e->image = strdup(field[0]);
        e->cat = strdup(field[1]);
        int nt = 1;
        for (const char *c = field[2]; *c; c++) nt += *c == ',';
        e->truth = calloc((size_t)nt, sizeof *e->truth);
        if (!e->image || !e->cat || !e->truth) { st = wf_error(WF_ERR_NOMEM, "%s: out of memory", path); break; }
        for (char *tok = field[2], *next; tok && !st; tok = next) {
            next = strchr(tok, ',');
            if (next) *next++ = 0;
            if (!*tok) st = wf_error(WF_ERR_INPUT, "%s:%d: an empty truth file name in '%s'", path, lineno, field[2]);
            else if (!(e->truth[e->ntruth++] = strdup(tok))) st = wf_error(WF_ERR_NOMEM, "%s: out of memory", path);
        }
        if (!st) st = need_file(path, lineno, "image", e->image);
        if (!st) st = need_file(path, lineno, "catalog", e->cat);
        for (int k = 0; k < e->ntruth && !st; k++) st = need_file(path, lineno, "truth", e->truth[k]);
    }
    if (!st && ferror(f)) st = wf_error(WF_ERR_IO, "%s: read error", path);
    fclose(f);
    if (!st && l->n == 0) st = wf_error(WF_ERR_INPUT, "%s: no image lines (IMAGE DETCAT TRUTH[,TRUTH...])", path);
    if (st) list_free(l);
    return st;
}

/* ---- the image: size, WCS, filter and the pixels detection uses ---- */

typedef struct image {
    int nx, ny;
    wf_wcs wcs;
    char filter[FLEN_VALUE];
    unsigned char *bad; /* 1: a pixel detection does not use */
} image;

static int move_to(fitsfile *f, int type, const char *name)
{
    int status = 0;
    if (fits_movnam_hdu(f, type, (char *)name, 0, &status)) {
        fits_clear_errmsg();
        return 0;
    }
    return 1;
}

/* Opens an outside FITS file read-only, its headers checked first (sim/fits/fitscheck.h). */
static wf_status open_fits(const char *path, const char *what, fitsfile **f)
{
    int status = 0;
    wf_status st = wf_fits_check_headers(path);
    if (st) return st;
    if (fits_open_file(f, path, READONLY, &status)) {
        char text[FLEN_STATUS];
        fits_get_errstatus(status, text);
        fits_clear_errmsg();
        return wf_error(WF_ERR_INPUT, "%s: cannot open the %s: %s", path, what, text);
    }
    return WF_OK;
}

/* Marks the bad pixels of one plane of the current HDU, a block of rows at a time. */
static wf_status mark_plane(fitsfile *f, const char *path, const char *name, image *im, int kind)
{
    int status = 0, naxis = 0;
    long nax[2] = {0, 0};
    if (fits_get_img_dim(f, &naxis, &status) || naxis != 2 || fits_get_img_size(f, 2, nax, &status) ||
        nax[0] != im->nx || nax[1] != im->ny) {
        fits_clear_errmsg();
        return wf_error(WF_ERR_INPUT, "%s: HDU %s is not a %d x %d image like SCI", path, name, im->nx, im->ny);
    }
    enum { ROWS = 64 };
    size_t nrow = (size_t)im->nx * ROWS;
    void *buf = malloc(nrow * (kind == 2 ? sizeof(unsigned) : sizeof(float)));
    if (!buf) return wf_error(WF_ERR_NOMEM, "%s: out of memory reading %s", path, name);
    for (int y0 = 0; y0 < im->ny && !status; y0 += ROWS) {
        int rows = im->ny - y0 < ROWS ? im->ny - y0 : ROWS;
        size_t n = (size_t)im->nx * rows, off = (size_t)im->nx * y0;
        long first[2] = {1, y0 + 1};
        int anynul = 0;
        fits_read_pix(f, kind == 2 ? TUINT : TFLOAT, first, (LONGLONG)n, NULL, buf, &anynul, &status);
        for (size_t i = 0; i < n && !status; i++) {
            int bad;
            if (kind == 0) bad = !isfinite(((float *)buf)[i]);
            else if (kind == 1) bad = !(((float *)buf)[i] > 0) || !isfinite(((float *)buf)[i]);
            else bad = (((unsigned *)buf)[i] & WF_DQ_DO_NOT_USE) != 0;
            im->bad[off + i] |= (unsigned char)bad;
        }
    }
    free(buf);
    if (status) {
        char msg[40];
        snprintf(msg, sizeof msg, "reading %s", name);
        char text[FLEN_STATUS];
        fits_get_errstatus(status, text);
        fits_clear_errmsg();
        return wf_error(WF_ERR_IO, "%s: %s: %s", path, msg, text);
    }
    return WF_OK;
}

static wf_status read_image(const char *path, image *im)
{
    memset(im, 0, sizeof *im);
    fitsfile *f = NULL;
    int status = 0;
    wf_status st = open_fits(path, "image", &f);
    if (st) return st;
    char value[FLEN_VALUE];
    if (!fits_read_key_str(f, "FILTER", value, NULL, &status)) snprintf(im->filter, sizeof im->filter, "%s", value);
    status = 0;
    fits_clear_errmsg();
    if (!move_to(f, ANY_HDU, "SCI")) {
        int naxis = 0;
        fits_movabs_hdu(f, 1, NULL, &status);
        if (status || fits_get_img_dim(f, &naxis, &status) || naxis != 2)
            st = wf_error(WF_ERR_INPUT, "%s: no SCI HDU and the primary HDU is not a 2-d image", path);
        fits_clear_errmsg();
        status = 0;
    }
    long nax[2] = {0, 0};
    if (!st && (fits_get_img_size(f, 2, nax, &status) || nax[0] < 1 || nax[1] < 1 || nax[0] > 100000 || nax[1] > 100000))
        st = wf_error(WF_ERR_INPUT, "%s: SCI is %ld x %ld pixels", path, nax[0], nax[1]);
    if (!st) st = wf_wcs_read_header(f, path, &im->wcs);
    if (!st && !im->filter[0] && !fits_read_key_str(f, "FILTER", value, NULL, &status))
        snprintf(im->filter, sizeof im->filter, "%s", value);
    status = 0;
    fits_clear_errmsg();
    im->nx = (int)nax[0], im->ny = (int)nax[1];
    if (!st && !(im->bad = calloc((size_t)im->nx * im->ny, 1)))
        st = wf_error(WF_ERR_NOMEM, "%s: out of memory for a %d x %d mask", path, im->nx, im->ny);
    if (!st) st = mark_plane(f, path, "SCI", im, 0);
    if (!st && move_to(f, ANY_HDU, "ERR")) st = mark_plane(f, path, "ERR", im, 1);
    if (!st && move_to(f, ANY_HDU, "DQ")) st = mark_plane(f, path, "DQ", im, 2);
    status = 0;
    fits_close_file(f, &status);
    if (st) free(im->bad), im->bad = NULL;
    return st;
}

/* ---- tables ---- */

/* Column `name` of the current table as doubles (n rows); *missing = 1 when absent. */
static wf_status read_column(fitsfile *f, const char *path, const char *hdu, const char *name, long n, double *out,
                             int *missing)
{
    int status = 0, col = 0;
    *missing = 0;
    if (fits_get_colnum(f, CASEINSEN, (char *)name, &col, &status)) {
        fits_clear_errmsg();
        *missing = 1;
        return WF_OK;
    }
    double nan = NAN;
    if (n > 0 && fits_read_col(f, TDOUBLE, col, 1, 1, n, &nan, out, NULL, &status)) {
        char text[FLEN_STATUS];
        fits_get_errstatus(status, text);
        fits_clear_errmsg();
        return wf_error(WF_ERR_INPUT, "%s: %s column %s: %s", path, hdu, name, text);
    }
    return WF_OK;
}

typedef struct detections {
    long n;
    double *ra, *dec;
} detections;

static wf_status read_catalog(const char *path, detections *d)
{
    memset(d, 0, sizeof *d);
    fitsfile *f = NULL;
    int status = 0;
    wf_status st = open_fits(path, "detection catalog", &f);
    if (st) return st;
    if (!move_to(f, BINARY_TBL, "CATALOG"))
        st = wf_error(WF_ERR_INPUT, "%s: no CATALOG table (make it with wfisim detect)", path);
    if (!st && fits_get_num_rows(f, &d->n, &status)) st = wf_error(WF_ERR_INPUT, "%s: CATALOG: cannot count rows", path);
    size_t m = d->n > 0 ? (size_t)d->n : 1;
    if (!st && (!(d->ra = malloc(m * sizeof *d->ra)) || !(d->dec = malloc(m * sizeof *d->dec))))
        st = wf_error(WF_ERR_NOMEM, "%s: out of memory for %ld rows", path, d->n);
    int miss_ra = 0, miss_dec = 0;
    if (!st) st = read_column(f, path, "CATALOG", "RA", d->n, d->ra, &miss_ra);
    if (!st) st = read_column(f, path, "CATALOG", "DEC", d->n, d->dec, &miss_dec);
    if (!st && (miss_ra || miss_dec))
        st = wf_error(WF_ERR_INPUT, "%s: CATALOG has no %s column (a wfisim detect catalog has RA and DEC)", path,
                      miss_ra ? "RA" : "DEC");
    status = 0;
    fits_close_file(f, &status);
    fits_clear_errmsg();
    if (st) free(d->ra), free(d->dec), memset(d, 0, sizeof *d);
    return st;
}

/* The truth objects of one line: ID, position, magnitude and type. */
typedef struct truth {
    long n, cap;
    long long *id;
    double *ra, *dec, *mag;
    double *flux_sum; /* SNe: sum of 10^(-0.4 MAG) over the truth files listing it */
    int *count;
    int *type;
} truth;

static void truth_free(truth *t)
{
    free(t->id), free(t->ra), free(t->dec), free(t->mag), free(t->flux_sum), free(t->count), free(t->type);
    memset(t, 0, sizeof *t);
}

static wf_status truth_grow(truth *t, long need)
{
    if (need <= t->cap) return WF_OK;
    long nc = t->cap ? t->cap : 1024;
    while (nc < need) nc *= 2;
    long long *id = realloc(t->id, (size_t)nc * sizeof *id);
    if (id) t->id = id;
    int ok = id != NULL;
    double **dd[4] = {&t->ra, &t->dec, &t->mag, &t->flux_sum};
    for (int k = 0; k < 4 && ok; k++) {
        double *q = realloc(*dd[k], (size_t)nc * sizeof *q);
        if (q) *dd[k] = q;
        ok = q != NULL;
    }
    int **ii[2] = {&t->count, &t->type};
    for (int k = 0; k < 2 && ok; k++) {
        int *q = realloc(*ii[k], (size_t)nc * sizeof *q);
        if (q) *ii[k] = q;
        ok = q != NULL;
    }
    if (!ok) return wf_error(WF_ERR_NOMEM, "truth: out of memory for %ld objects", nc);
    t->cap = nc;
    return WF_OK;
}

/* A truth row's sort key: deduplication sorts (type, ID, row) and keeps each run's first. */
typedef struct index_entry {
    long long id;
    int type;
    long row;
} index_entry;

static int cmp_entry(const void *a, const void *b)
{
    const index_entry *p = a, *q = b;
    if (p->type != q->type) return p->type < q->type ? -1 : 1;
    if (p->id != q->id) return p->id < q->id ? -1 : 1;
    return (p->row > q->row) - (p->row < q->row);
}

/* Appends the rows of every truth file of the line, then keeps the first row of each
 * galaxy and star ID and merges supernovae by ID (mean flux). */
static wf_status read_truths(const char *list_path, const line *ln, truth *t)
{
    memset(t, 0, sizeof *t);
    wf_status st = WF_OK;
    for (int k = 0; k < ln->ntruth && !st; k++) {
        const char *path = ln->truth[k];
        fitsfile *f = NULL;
        int status = 0;
        if ((st = open_fits(path, "truth file", &f))) {
            st = at_line(st, list_path, ln->lineno);
            break;
        }
        long total = 0;
        for (int ty = 0; ty < WF_EFF_NTYPE && !st; ty++) {
            long n = 0;
            if (!move_to(f, BINARY_TBL, type_hdu[ty])) {
                st = wf_error(WF_ERR_INPUT, "%s:%d: truth %s: no %s table (not a wfisim truth file)", list_path,
                              ln->lineno, path, type_hdu[ty]);
                break;
            }
            if (fits_get_num_rows(f, &n, &status)) {
                fits_clear_errmsg();
                st = wf_error(WF_ERR_INPUT, "%s:%d: truth %s: %s: cannot count rows", list_path, ln->lineno, path,
                              type_hdu[ty]);
                break;
            }
            total += n;
            if (n == 0) continue;
            if ((st = truth_grow(t, t->n + n))) break;
            const char *names[3] = {"RA", "DEC", "MAG"};
            double *dst[3] = {t->ra + t->n, t->dec + t->n, t->mag + t->n};
            int col = 0;
            if (fits_get_colnum(f, CASEINSEN, "ID", &col, &status) ||
                fits_read_col(f, TLONGLONG, col, 1, 1, n, NULL, t->id + t->n, NULL, &status)) {
                fits_clear_errmsg();
                st = wf_error(WF_ERR_INPUT, "%s:%d: truth %s: %s has no readable ID column", list_path, ln->lineno,
                              path, type_hdu[ty]);
            }
            for (int c = 0; c < 3 && !st; c++) {
                int missing = 0;
                st = read_column(f, path, type_hdu[ty], names[c], n, dst[c], &missing);
                if (!st && missing)
                    st = wf_error(WF_ERR_INPUT, "%s:%d: truth %s: %s has no %s column", list_path, ln->lineno, path,
                                  type_hdu[ty], names[c]);
            }
            for (long i = 0; !st && i < n; i++) {
                long r = t->n + i;
                t->type[r] = ty;
                double m = t->mag[r];
                t->flux_sum[r] = isfinite(m) && m < 99.0 ? pow(10.0, -0.4 * m) : 0.0;
                t->count[r] = 1;
            }
            if (!st) t->n += n;
        }
        if (!st && total == 0)
            st = wf_error(WF_ERR_INPUT, "%s:%d: truth %s: empty truth table (no galaxy, star or supernova)", list_path,
                          ln->lineno, path);
        status = 0;
        fits_close_file(f, &status);
        fits_clear_errmsg();
    }
    if (st) { truth_free(t); return st; }
    /* deduplicate: sort (type, id, row); the first row of a run stays, SNe add their flux */
    index_entry *e = malloc((size_t)(t->n > 0 ? t->n : 1) * sizeof *e);
    if (!e) { truth_free(t); return wf_error(WF_ERR_NOMEM, "truth: out of memory"); }
    for (long i = 0; i < t->n; i++) e[i] = (index_entry){t->id[i], t->type[i], i};
    qsort(e, (size_t)t->n, sizeof *e, cmp_entry);
    unsigned char *drop = calloc((size_t)(t->n > 0 ? t->n : 1), 1);
    if (!drop) { free(e); truth_free(t); return wf_error(WF_ERR_NOMEM, "truth: out of memory"); }
    for (long i = 0, start = 0; i < t->n; i++) {
        if (i > 0 && e[i].type == e[start].type && e[i].id == e[start].id) {
            long kept = e[start].row; /* the run's first row: the first truth file's */
            drop[e[i].row] = 1;
            if (e[i].type == WF_EFF_SN) t->flux_sum[kept] += t->flux_sum[e[i].row], t->count[kept]++;
        } else {
            start = i;
        }
    }
    long w = 0;
    for (long i = 0; i < t->n; i++) {
        if (drop[i]) continue;
        t->id[w] = t->id[i], t->ra[w] = t->ra[i], t->dec[w] = t->dec[i], t->type[w] = t->type[i];
        t->count[w] = t->count[i], t->flux_sum[w] = t->flux_sum[i];
        double mean = t->flux_sum[i] / t->count[i];
        t->mag[w] = t->type[i] == WF_EFF_SN ? (mean > 0 ? -2.5 * log10(mean) : 99.0) : t->mag[i];
        w++;
    }
    t->n = w;
    free(e);
    free(drop);
    return WF_OK;
}

/* ---- pooling ---- */

typedef struct pool {
    long n, cap;
    double *mag;
    unsigned char *found;
    int *filter; /* index into the run's filter names */
} pool;

static wf_status pool_add(pool *p, double mag, int found, int filter)
{
    if (p->n == p->cap) {
        long nc = p->cap ? 2 * p->cap : 4096;
        double *m = realloc(p->mag, (size_t)nc * sizeof *m);
        if (m) p->mag = m;
        unsigned char *f = m ? realloc(p->found, (size_t)nc) : NULL;
        if (f) p->found = f;
        int *fi = f ? realloc(p->filter, (size_t)nc * sizeof *fi) : NULL;
        if (fi) p->filter = fi;
        if (!fi) return wf_error(WF_ERR_NOMEM, "efficiency: out of memory for %ld objects", nc);
        p->cap = nc;
    }
    p->mag[p->n] = mag, p->found[p->n] = (unsigned char)(found != 0), p->filter[p->n] = filter;
    p->n++;
    return WF_OK;
}

#define MAX_FILTERS 16

/* An SN of the --isolated sample: its host and its distance from it. */
typedef struct iso_entry {
    long long id, host;
    double off, a;
} iso_entry;

typedef struct run {
    pool pool[WF_EFF_NTYPE];
    char filters[MAX_FILTERS][FLEN_VALUE];
    int nfilters;
    iso_entry *iso; /* sorted by id; NULL without --isolated */
    size_t niso;
} run;

/* Orders iso_entry and gal_mag alike: both begin with their long long id. */
static int cmp_id(const void *a, const void *b)
{
    long long p = *(const long long *)a, q = *(const long long *)b;
    return (p > q) - (p < q);
}

static wf_status read_isolation(const char *path, run *r)
{
    wf_sn_sample s;
    wf_status st = wf_sn_sample_read(path, &s);
    if (st) return wf_error(st, "--isolated: %s", wf_error_message());
    r->iso = malloc((s.n ? s.n : 1) * sizeof *r->iso);
    if (!r->iso) {
        wf_sn_sample_free(&s);
        return wf_error(WF_ERR_NOMEM, "--isolated %s: out of memory", path);
    }
    for (size_t i = 0; i < s.n; i++) r->iso[i] = (iso_entry){s.id[i], s.host_id[i], s.host_offset[i], s.host_a[i]};
    r->niso = s.n;
    wf_sn_sample_free(&s);
    qsort(r->iso, r->niso, sizeof *r->iso, cmp_id);
    return WF_OK;
}

typedef struct gal_mag {
    long long id;
    double mag;
} gal_mag;

/* crowded[i] = 1 for the line's SNe that are not isolated: within iso_factor x HOSTA of their
 * host, or with a host brighter than iso_host_mag in this image's truth (a host absent from
 * the truth is not drawn on the image and leaves no residual). */
static wf_status mark_crowded(const char *list_path, const line *ln, const wf_eff_options *o, const run *r,
                              const truth *t, unsigned char *crowded)
{
    long ng = 0;
    for (long i = 0; i < t->n; i++) ng += t->type[i] == WF_EFF_GALAXY;
    gal_mag *g = malloc((size_t)(ng ? ng : 1) * sizeof *g);
    if (!g) return wf_error(WF_ERR_NOMEM, "efficiency: out of memory");
    ng = 0;
    for (long i = 0; i < t->n; i++)
        if (t->type[i] == WF_EFF_GALAXY) g[ng++] = (gal_mag){t->id[i], t->mag[i]};
    qsort(g, (size_t)ng, sizeof *g, cmp_id);
    wf_status st = WF_OK;
    for (long i = 0; i < t->n && !st; i++) {
        crowded[i] = 0;
        if (t->type[i] != WF_EFF_SN) continue;
        iso_entry key = {.id = t->id[i]};
        const iso_entry *e = bsearch(&key, r->iso, r->niso, sizeof *r->iso, cmp_id);
        if (!e) {
            st = wf_error(WF_ERR_INPUT, "%s:%d: SN %lld of the truth is not in the --isolated sample %s", list_path,
                          ln->lineno, t->id[i], o->isolated);
            break;
        }
        if (e->host < 0) continue; /* hostless */
        gal_mag gk = {.id = e->host};
        const gal_mag *h = bsearch(&gk, g, (size_t)ng, sizeof *g, cmp_id);
        crowded[i] = !(e->off > o->iso_factor * e->a) || (h && !(h->mag > o->iso_host_mag));
    }
    free(g);
    return st;
}

static int filter_index(run *r, const char *name)
{
    for (int i = 0; i < r->nfilters; i++)
        if (!strcmp(r->filters[i], name)) return i;
    if (r->nfilters == MAX_FILTERS) return -1;
    snprintf(r->filters[r->nfilters], sizeof r->filters[0], "%s", name);
    return r->nfilters++;
}

/* One list line: which truth objects the image sees, which detections match them. */
static wf_status score_line(const char *list_path, const line *ln, const wf_eff_options *o, run *r,
                            wf_eff_summary *sum)
{
    image im;
    detections det;
    truth t;
    wf_status st = read_image(ln->image, &im);
    if (st) return at_line(st, list_path, ln->lineno);
    if ((st = read_catalog(ln->cat, &det))) {
        free(im.bad);
        return at_line(st, list_path, ln->lineno);
    }
    if ((st = read_truths(list_path, ln, &t))) {
        free(im.bad), free(det.ra), free(det.dec);
        return st;
    }
    unsigned char *crowded = calloc((size_t)(t.n > 0 ? t.n : 1), 1);
    if (!crowded) st = wf_error(WF_ERR_NOMEM, "efficiency: out of memory");
    if (!st && r->iso) st = mark_crowded(list_path, ln, o, r, &t, crowded);
    int fi = 0;
    if (!st && !im.filter[0] && (o->types & (1 << WF_EFF_SN)))
        st = wf_error(WF_ERR_INPUT, "%s:%d: %s: no FILTER keyword (the SNANA map is per filter)", list_path,
                      ln->lineno, ln->image);
    else if (!st && im.filter[0] && (fi = filter_index(r, im.filter)) < 0)
        st = wf_error(WF_ERR_INPUT, "%s:%d: %s: more than %d filters in one list", list_path, ln->lineno, ln->image,
                      MAX_FILTERS);
    /* the truth objects of the scored types, whether the image sees them or not: an unseen
     * object still owns the detection its light makes at the edge or around a masked pixel;
     * one without light (MAG 99: an SN before explosion) owns none and is not scored */
    long ns = 0;
    for (long i = 0; !st && i < t.n; i++) {
        if (!(o->types & (1 << t.type[i]))) continue;
        if (!(isfinite(t.mag[i]) && t.mag[i] < 99.0)) {
            sum->n_unseen[t.type[i]]++;
            continue;
        }
        t.id[ns] = t.id[i], t.ra[ns] = t.ra[i], t.dec[ns] = t.dec[i], t.mag[ns] = t.mag[i], t.type[ns] = t.type[i];
        crowded[ns] = crowded[i];
        ns++;
    }
    long *t2d = malloc((size_t)(ns > 0 ? ns : 1) * sizeof *t2d);
    long *d2t = malloc((size_t)(det.n > 0 ? det.n : 1) * sizeof *d2t);
    if (!st && (!t2d || !d2t)) st = wf_error(WF_ERR_NOMEM, "efficiency: out of memory");
    if (!st) st = wf_eff_match(t.ra, t.dec, ns, det.ra, det.dec, det.n, o->radius_arcsec / 3600.0, t2d, d2t);
    for (long i = 0; !st && i < ns; i++) {
        double x, y;
        int seen = !wf_wcs_world2pix(&im.wcs, t.ra[i], t.dec[i], &x, &y) && x >= -0.5 && y >= -0.5 &&
                   x < im.nx - 0.5 && y < im.ny - 0.5;
        /* the pixel holding the position: floor(x + 1/2), so -0.5 is pixel 0 */
        if (seen) seen = !im.bad[(size_t)floor(y + 0.5) * im.nx + (size_t)floor(x + 0.5)];
        if (!seen) {
            sum->n_unseen[t.type[i]]++;
            continue;
        }
        if (crowded[i]) { /* it keeps its detection (not false), but is not scored */
            sum->n_not_isolated++;
            continue;
        }
        st = pool_add(&r->pool[t.type[i]], t.mag[i], t2d[i] >= 0, fi);
    }
    fits_clear_errmsg();
    if (!st) {
        sum->n_images++;
        sum->n_det += det.n;
        for (long j = 0; j < det.n; j++) sum->n_false += d2t[j] < 0;
    }
    free(t2d), free(d2t), free(crowded);
    free(im.bad), free(det.ra), free(det.dec);
    truth_free(&t);
    return st;
}

/* ---- binned efficiencies ---- */

typedef struct bins {
    long first, nb; /* bin i covers [(first + i) width, (first + i + 1) width) */
    long *n, *k;
} bins;

static wf_status make_bins(const pool *p, double width, int filter, bins *b)
{
    memset(b, 0, sizeof *b);
    long lo = 0, hi = -1;
    for (long i = 0; i < p->n; i++) {
        if (filter >= 0 && p->filter[i] != filter) continue;
        long j = (long)floor(p->mag[i] / width);
        if (hi < lo) lo = hi = j;
        if (j < lo) lo = j;
        if (j > hi) hi = j;
    }
    if (hi < lo) return WF_OK;
    if (hi - lo >= 100000) return wf_error(WF_ERR_INPUT, "--bin %g: %ld bins over the magnitudes", width, hi - lo + 1);
    b->first = lo, b->nb = hi - lo + 1;
    b->n = calloc((size_t)b->nb, sizeof *b->n);
    b->k = calloc((size_t)b->nb, sizeof *b->k);
    if (!b->n || !b->k) return wf_error(WF_ERR_NOMEM, "efficiency: out of memory for %ld bins", b->nb);
    for (long i = 0; i < p->n; i++) {
        if (filter >= 0 && p->filter[i] != filter) continue;
        long j = (long)floor(p->mag[i] / width) - lo;
        b->n[j]++, b->k[j] += p->found[i];
    }
    return WF_OK;
}

static void bins_free(bins *b)
{
    free(b->n), free(b->k);
    memset(b, 0, sizeof *b);
}

/* ---- outputs, each to a temporary name first ---- */

enum { OUT_CSV, OUT_PNG, OUT_JSON, OUT_SNANA, NOUT };
static const char *out_suffix[NOUT] = {"_efficiency.csv", "_efficiency.png", "_summary.json",
                                       "_SEARCHEFF_PIPELINE_EFF.DAT"};

typedef struct outputs {
    char path[NOUT][4200], tmp[NOUT][4300];
    int made[NOUT];
} outputs;

static wf_status close_text(FILE *f, const char *tmp)
{
    int bad = ferror(f);
    if (fclose(f) || bad) return wf_error(WF_ERR_IO, "%s: write error: %s", tmp, strerror(errno));
    return WF_OK;
}

static wf_status write_csv(const char *tmp, const wf_eff_options *o, const bins *b)
{
    FILE *f = fopen(tmp, "w");
    if (!f) return wf_error(WF_ERR_IO, "%s: cannot create: %s", tmp, strerror(errno));
    fprintf(f, "type,mag_lo,mag_hi,n_true,n_found,eff,eff_lo,eff_hi\n");
    for (int ty = 0; ty < WF_EFF_NTYPE; ty++) {
        if (!(o->types & (1 << ty))) continue;
        for (long i = 0; i < b[ty].nb; i++) {
            if (!b[ty].n[i]) continue;
            double lo, hi;
            wf_eff_wilson(b[ty].k[i], b[ty].n[i], 1.0, &lo, &hi);
            fprintf(f, "%s,%.10g,%.10g,%ld,%ld,%.6f,%.6f,%.6f\n", type_name[ty], (b[ty].first + i) * o->bin,
                    (b[ty].first + i + 1) * o->bin, b[ty].n[i], b[ty].k[i], (double)b[ty].k[i] / b[ty].n[i], lo, hi);
        }
    }
    return close_text(f, tmp);
}

static void json_number(FILE *f, const char *key, int ok, double v)
{
    if (ok && isfinite(v)) fprintf(f, "  \"%s\": %.6f,\n", key, v);
    else fprintf(f, "  \"%s\": null,\n", key);
}

static void json_string(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s; s++) {
        if (*s == '"' || *s == '\\') fprintf(f, "\\%c", *s);
        else if ((unsigned char)*s < 0x20) fprintf(f, "\\u%04x", *s);
        else fputc(*s, f);
    }
    fputc('"', f);
}

static wf_status write_json(const char *tmp, const wf_eff_options *o, const run *r, const wf_eff_summary *s)
{
    FILE *f = fopen(tmp, "w");
    if (!f) return wf_error(WF_ERR_IO, "%s: cannot create: %s", tmp, strerror(errno));
    fprintf(f, "{\n  \"label\": ");
    json_string(f, o->label);
    fprintf(f, ",\n  \"types\": [");
    int first = 1;
    for (int ty = 0; ty < WF_EFF_NTYPE; ty++)
        if (o->types & (1 << ty)) fprintf(f, "%s\"%s\"", first ? "" : ", ", type_name[ty]), first = 0;
    fprintf(f, "],\n  \"filters\": [");
    for (int i = 0; i < r->nfilters; i++) {
        if (i) fprintf(f, ", ");
        json_string(f, r->filters[i]);
    }
    fprintf(f, "],\n  \"radius_arcsec\": %.6g,\n  \"bin\": %.6g,\n", o->radius_arcsec, o->bin);
    for (int ty = 0; ty < WF_EFF_NTYPE; ty++) {
        const wf_eff_fit *ft = &s->fit[ty];
        char key[64];
        const char *t = type_name[ty];
        snprintf(key, sizeof key, "m50_%s", t), json_number(f, key, ft->ok, ft->m50);
        snprintf(key, sizeof key, "m50_err_%s", t), json_number(f, key, ft->ok, ft->m50_err);
        snprintf(key, sizeof key, "width_%s", t), json_number(f, key, ft->ok, ft->width);
        snprintf(key, sizeof key, "plateau_%s", t), json_number(f, key, ft->ok, ft->plateau);
        int scored = (o->types & (1 << ty)) != 0;
        if (scored)
            fprintf(f, "  \"n_true_%s\": %ld,\n  \"n_found_%s\": %ld,\n  \"n_unseen_%s\": %ld,\n", t, s->n_true[ty], t,
                    s->n_found[ty], t, s->n_unseen[ty]);
        else
            fprintf(f, "  \"n_true_%s\": null,\n  \"n_found_%s\": null,\n  \"n_unseen_%s\": null,\n", t, t, t);
    }
    if (o->isolated)
        fprintf(f, "  \"isolated\": true,\n  \"iso_factor\": %.6g,\n  \"iso_host_mag\": %.6g,\n  \"n_not_isolated_sn\": %ld,\n",
                o->iso_factor, o->iso_host_mag, s->n_not_isolated);
    else
        fprintf(f, "  \"isolated\": false,\n");
    fprintf(f, "  \"n_images\": %ld,\n  \"n_det\": %ld,\n  \"n_false\": %ld\n}\n", s->n_images, s->n_det, s->n_false);
    return close_text(f, tmp);
}

static wf_status write_png(const char *tmp, const wf_eff_options *o, const bins *b, const wf_eff_summary *s)
{
    char title[300];
    snprintf(title, sizeof title, "%s: detection efficiency (match %.2g arcsec)", o->label, o->radius_arcsec);
    wf_plot *p = NULL;
    wf_status st = wf_plot_create(900, 600, title, "true magnitude (AB)", "efficiency", &p);
    double lo = INFINITY, hi = -INFINITY;
    for (int ty = 0; ty < WF_EFF_NTYPE; ty++)
        if (b[ty].nb) lo = fmin(lo, b[ty].first * o->bin), hi = fmax(hi, (b[ty].first + b[ty].nb) * o->bin);
    if (!(lo < hi)) lo = 20, hi = 30; /* nothing scored: an empty frame */
    if (!st) st = wf_plot_set_range(p, lo - 0.2, hi + 0.2, -0.03, 1.08);
    for (int ty = 0; ty < WF_EFF_NTYPE && !st; ty++) {
        if (!b[ty].nb) continue;
        /* each bin's Wilson interval drawn as a bar: y its centre, yerr its half-width */
        double *x = malloc((size_t)b[ty].nb * sizeof *x), *y = malloc((size_t)b[ty].nb * sizeof *y);
        double *e = malloc((size_t)b[ty].nb * sizeof *e);
        int n = 0;
        if (!x || !y || !e) st = wf_error(WF_ERR_NOMEM, "efficiency: out of memory for the plot");
        for (long i = 0; !st && i < b[ty].nb; i++) {
            if (!b[ty].n[i]) continue;
            double l, h;
            wf_eff_wilson(b[ty].k[i], b[ty].n[i], 1.0, &l, &h);
            x[n] = (b[ty].first + i + 0.5) * o->bin, y[n] = 0.5 * (l + h), e[n] = 0.5 * (h - l);
            n++;
        }
        char label[120];
        snprintf(label, sizeof label, "%s (68%% interval)", type_name[ty]);
        if (!st) st = wf_plot_series(p, x, y, e, n, label, WF_PLOT_ERRORBARS | WF_PLOT_MARKERS);
        const wf_eff_fit *ft = &s->fit[ty];
        if (!st && ft->ok) {
            enum { NC = 400 };
            double cx[NC], cy[NC];
            for (int i = 0; i < NC; i++) {
                cx[i] = lo - 0.2 + (hi - lo + 0.4) * i / (NC - 1);
                cy[i] = wf_eff_curve(ft, cx[i]);
            }
            snprintf(label, sizeof label, "%s fit: m50 %.2f +- %.2f", type_name[ty], ft->m50, ft->m50_err);
            st = wf_plot_series(p, cx, cy, NULL, NC, label, WF_PLOT_LINE);
        }
        free(x), free(y), free(e);
    }
    if (!st) st = wf_plot_write_png(p, tmp);
    wf_plot_free(p);
    return st;
}

/* SNANA's band letter for a wfisim filter: its first letter (R062 R, Z087 Z, Y106 Y, J129 J,
 * H158 H, F184 F, K213 K, W146 W), as the Roman SNANA simulations name them. */
static char snana_band(const char *filter)
{
    return filter[0] >= 'a' && filter[0] <= 'z' ? (char)(filter[0] - 'a' + 'A') : filter[0];
}

/* One detection map per filter (SNANA sntools_trigger.c readMap_SEARCHEFF_DETECT: MAPNAME_DETECT,
 * FILTER, rows of "MAG: m eff" in increasing m, ENDMAP). SNANA interpolates linearly and holds
 * the end values beyond the rows, so the rows run from the brightest SN to where the fitted
 * curve has fallen below 0.001. The comments avoid SNANA's keywords: it reads every word. */
static wf_status write_snana(const char *tmp, const wf_eff_options *o, const run *r)
{
    FILE *f = fopen(tmp, "w");
    if (!f) return wf_error(WF_ERR_IO, "%s: cannot create: %s", tmp, strerror(errno));
    /* SNANA's documentation block first (what its REQUIRE_DOCANA option asks for) */
    fprintf(f, "DOCUMENTATION:\n  PURPOSE: pipeline detection efficiency of supernovae against their true magnitude\n");
    fprintf(f, "  SOURCE: wfisim efficiency, label %s, detections matched within %.3g arcsec\n", o->label,
            o->radius_arcsec);
    fprintf(f, "  NOTES:\n  - rows are the maximum-likelihood curve plateau / (1 + exp((m - mc) / width))\n");
    fprintf(f, "  - or, where it could not be fitted, the fraction found in bins of %.3g mag\n", o->bin);
    fprintf(f, "DOCUMENTATION_END:\n");
    wf_status st = WF_OK;
    int maps = 0;
    for (int fi = 0; fi < r->nfilters && !st; fi++) {
        const pool *p = &r->pool[WF_EFF_SN];
        pool sub = {0};
        for (long i = 0; i < p->n && !st; i++)
            if (p->filter[i] == fi) st = pool_add(&sub, p->mag[i], p->found[i], fi);
        wf_eff_fit ft;
        if (!st) st = wf_eff_fit_curve(sub.mag, sub.found, sub.n, &ft);
        bins b = {0};
        if (!st) st = make_bins(&sub, o->bin, -1, &b);
        if (!st && sub.n) {
            char band = snana_band(r->filters[fi]);
            fprintf(f, "\n# %s: %ld supernovae, %ld found", r->filters[fi], sub.n, ft.nfound);
            if (ft.ok)
                fprintf(f, "; m50 %.3f +- %.3f, width %.3f, plateau %.4f\n", ft.m50, ft.m50_err, ft.width, ft.plateau);
            else fprintf(f, "; too few to fit, measured fractions\n");
            fprintf(f, "MAPNAME_DETECT: WFISIM_%s_%s\nFILTER: %c\n", o->label, r->filters[fi], band);
            if (ft.ok) {
                double m0 = b.first * o->bin, m1 = ft.m50 + ft.width * log(1000.0 * ft.plateau);
                if (m1 < (b.first + b.nb) * o->bin) m1 = (b.first + b.nb) * o->bin;
                for (double m = m0; m <= m1 + 1e-9; m += o->bin)
                    fprintf(f, "MAG: %8.3f %8.5f\n", m, wf_eff_curve(&ft, m));
            } else {
                for (long i = 0; i < b.nb; i++)
                    if (b.n[i])
                        fprintf(f, "MAG: %8.3f %8.5f\n", (b.first + i + 0.5) * o->bin, (double)b.k[i] / b.n[i]);
            }
            fprintf(f, "ENDMAP:\n");
            maps++;
        }
        bins_free(&b);
        free(sub.mag), free(sub.found), free(sub.filter);
    }
    if (!maps) fprintf(f, "\n# no supernova was seen by any image: no map\n");
    wf_status cs = close_text(f, tmp);
    return st ? st : cs;
}

/* ---- the run ---- */

static wf_status check_options(const wf_eff_options *o)
{
    if (!o->label || !*o->label) return wf_error(WF_ERR_INPUT, "--label: give a name for the output files");
    for (const char *c = o->label; *c; c++)
        if (!((*c >= 'A' && *c <= 'Z') || (*c >= 'a' && *c <= 'z') || (*c >= '0' && *c <= '9') || *c == '_' ||
              *c == '-' || *c == '.'))
            return wf_error(WF_ERR_INPUT, "--label '%s': use letters, digits, '_', '-' and '.' only", o->label);
    if (!o->out_dir || !*o->out_dir) return wf_error(WF_ERR_INPUT, "--out: give the output folder");
    if (!(o->radius_arcsec > 0) || !(o->radius_arcsec < 3600))
        return wf_error(WF_ERR_INPUT, "--radius %g: must be a positive number of arcsec", o->radius_arcsec);
    if (!(o->bin >= 0.001) || !(o->bin <= 10))
        return wf_error(WF_ERR_INPUT, "--bin %g: must be in [0.001, 10] mag", o->bin);
    if (!(o->types & ((1 << WF_EFF_NTYPE) - 1)) || (o->types & ~((1 << WF_EFF_NTYPE) - 1)))
        return wf_error(WF_ERR_INPUT, "--types: no type scored");
    if (o->isolated && !(o->iso_factor >= 0 && isfinite(o->iso_factor)))
        return wf_error(WF_ERR_INPUT, "--iso-factor %g: must be >= 0", o->iso_factor);
    if (o->isolated && isnan(o->iso_host_mag)) return wf_error(WF_ERR_INPUT, "--iso-host-mag: not a number");
    return WF_OK;
}

static wf_status write_outputs(const wf_eff_options *o, const run *r, const bins *b, const wf_eff_summary *s)
{
    outputs out;
    memset(&out, 0, sizeof out);
    struct stat sb;
    if (stat(o->out_dir, &sb)) {
        if (mkdir(o->out_dir, 0777) && errno != EEXIST)
            return wf_error(WF_ERR_IO, "--out %s: cannot create the folder: %s", o->out_dir, strerror(errno));
    } else if (!S_ISDIR(sb.st_mode)) {
        return wf_error(WF_ERR_INPUT, "--out %s: not a folder", o->out_dir);
    }
    int want[NOUT] = {1, 1, 1, (o->types & (1 << WF_EFF_SN)) != 0};
    for (int k = 0; k < NOUT; k++) {
        int n1 = snprintf(out.path[k], sizeof out.path[k], "%s/%s%s", o->out_dir, o->label, out_suffix[k]);
        int n2 = snprintf(out.tmp[k], sizeof out.tmp[k], "%s.tmp", out.path[k]);
        if (n1 < 0 || n2 < 0 || (size_t)n2 >= sizeof out.tmp[k])
            return wf_error(WF_ERR_INPUT, "--out %s: path too long", o->out_dir);
    }
    wf_status st = WF_OK;
    for (int k = 0; k < NOUT && !st; k++) {
        if (!want[k]) continue;
        out.made[k] = 1;
        if (k == OUT_CSV) st = write_csv(out.tmp[k], o, b);
        else if (k == OUT_PNG) st = write_png(out.tmp[k], o, b, s);
        else if (k == OUT_JSON) st = write_json(out.tmp[k], o, r, s);
        else st = write_snana(out.tmp[k], o, r);
    }
    /* all whole: rename them into place together */
    for (int k = 0; k < NOUT && !st; k++)
        if (want[k]) st = wf_file_rename(out.tmp[k], out.path[k]);
    if (st)
        for (int k = 0; k < NOUT; k++)
            if (out.made[k]) unlink(out.tmp[k]);
    return st;
}

wf_status wf_eff_run(const char *list_path, const wf_eff_options *o, wf_eff_summary *sum)
{
    memset(sum, 0, sizeof *sum);
    wf_status st = check_options(o);
    if (st) return st;
    list l;
    if ((st = read_list(list_path, &l))) return st;
    run *r = calloc(1, sizeof *r);
    bins b[WF_EFF_NTYPE];
    memset(b, 0, sizeof b);
    if (!r) st = wf_error(WF_ERR_NOMEM, "efficiency: out of memory");
    if (!st && o->isolated) st = read_isolation(o->isolated, r);
    for (int i = 0; i < l.n && !st; i++) st = score_line(list_path, &l.v[i], o, r, sum);
    for (int ty = 0; ty < WF_EFF_NTYPE && !st; ty++) {
        if (!(o->types & (1 << ty))) continue;
        const pool *p = &r->pool[ty];
        sum->n_true[ty] = p->n;
        for (long i = 0; i < p->n; i++) sum->n_found[ty] += p->found[i];
        st = wf_eff_fit_curve(p->mag, p->found, p->n, &sum->fit[ty]);
        if (!st) st = make_bins(p, o->bin, -1, &b[ty]);
    }
    if (!st) st = write_outputs(o, r, b, sum);
    for (int ty = 0; ty < WF_EFF_NTYPE; ty++) {
        bins_free(&b[ty]);
        if (r) free(r->pool[ty].mag), free(r->pool[ty].found), free(r->pool[ty].filter);
    }
    if (r) free(r->iso);
    free(r);
    list_free(&l);
    return st;
}

/* ---- the command ---- */

static const char *usage =
    "usage: wfisim efficiency --label NAME --out DIR [--radius 0.3] [--bin 0.25] [--types galaxy,star,sn]\n"
    "       [--isolated SNE.fits [--iso-factor 1.5] [--iso-host-mag 22]] LIST\n"
    "  LIST: one image a line, 'IMAGE DETCAT TRUTH[,TRUTH...]' ('#' comments): the image detected\n"
    "  (product, coadd or difference image), its wfisim detect catalog, its truth tables.\n"
    "  Writes DIR/NAME_efficiency.csv, DIR/NAME_efficiency.png, DIR/NAME_summary.json and, when\n"
    "  supernovae are scored, DIR/NAME_SEARCHEFF_PIPELINE_EFF.DAT (docs/ANALYSIS.md).\n"
    "  --radius R   match radius, arcsec [0.3]\n"
    "  --bin B      magnitude bin [0.25]\n"
    "  --types T    types scored: galaxy, star, sn, comma-separated [all]\n"
    "  --isolated SNE.fits  score only the SNe isolated from their hosts (SPEC 8): farther than\n"
    "               --iso-factor [1.5] x the host's semi-major axis HOSTA, host fainter than\n"
    "               --iso-host-mag [22]; the others keep their detections, unscored\n"
    "  --quiet      no summary line\n";

static int usage_error(const char *fmt, const char *a, const char *b)
{
    fprintf(stderr, "wfisim efficiency: ");
    fprintf(stderr, fmt, a, b);
    fprintf(stderr, "\n%s", usage);
    return 2;
}

static int number(const char *opt, const char *v, double *out)
{
    char *end;
    *out = strtod(v, &end);
    if (end == v || *end || !isfinite(*out)) return usage_error("%s '%s': not a number", opt, v);
    return 0;
}

int wf_cmd_efficiency(int argc, char **argv)
{
    wf_eff_options o;
    wf_eff_defaults(&o);
    const char *listp = NULL;
    int rc = 0;
    for (int i = 0; i < argc && !rc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) { fputs(usage, stdout); return 0; }
        if (!strcmp(a, "--quiet")) { o.quiet = 1; continue; }
        if (strncmp(a, "--", 2)) {
            if (listp) return usage_error("unexpected argument '%s'%s", a, " (one LIST)");
            listp = a;
            continue;
        }
        if (i + 1 >= argc) return usage_error("%s needs a value%s", a, "");
        const char *v = argv[++i];
        if (!strcmp(a, "--label")) o.label = v;
        else if (!strcmp(a, "--out")) o.out_dir = v;
        else if (!strcmp(a, "--radius")) rc = number(a, v, &o.radius_arcsec);
        else if (!strcmp(a, "--bin")) rc = number(a, v, &o.bin);
        else if (!strcmp(a, "--isolated")) o.isolated = v;
        else if (!strcmp(a, "--iso-factor")) rc = number(a, v, &o.iso_factor);
        else if (!strcmp(a, "--iso-host-mag")) rc = number(a, v, &o.iso_host_mag);
        else if (!strcmp(a, "--types")) {
            if (wf_eff_parse_types(v, &o.types)) return usage_error("%s%s", wf_error_message(), "");
        } else return usage_error("unknown option '%s'%s", a, "");
    }
    if (rc) return rc;
    if (!o.label) return usage_error("%s is required%s", "--label", "");
    if (!o.out_dir) return usage_error("%s is required%s", "--out", "");
    if (!listp) return usage_error("give the LIST file%s%s", "", "");
    wf_eff_summary s;
    wf_status st = wf_eff_run(listp, &o, &s);
    if (st) {
        fprintf(stderr, "wfisim efficiency: %s\n", wf_error_message()[0] ? wf_error_message() : wf_status_name(st));
        return st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
    }
    if (!o.quiet) {
        fprintf(stderr, "wfisim efficiency: %ld images, %ld detections, %ld false", s.n_images, s.n_det, s.n_false);
        for (int ty = 0; ty < WF_EFF_NTYPE; ty++) {
            if (!(o.types & (1 << ty))) continue;
            fprintf(stderr, "; %s %ld/%ld found", type_name[ty], s.n_found[ty], s.n_true[ty]);
            if (s.fit[ty].ok) fprintf(stderr, ", m50 %.3f +- %.3f", s.fit[ty].m50, s.fit[ty].m50_err);
        }
        if (o.isolated) fprintf(stderr, "; %ld SNe not isolated, unscored", s.n_not_isolated);
        fprintf(stderr, " -> %s/%s_*\n", o.out_dir, o.label);
    }
    return 0;
}
